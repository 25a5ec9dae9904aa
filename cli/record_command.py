"""``contact-skills record``: a scripted teacher demonstration, or (``--style kinesthetic``) a hand-guided wiping
recording, from the PyBullet world.

A kinesthetic recording is written as a real kinesthetic recording file holds it (100 Hz, no time column, w-first
quaternions, the raw wrist-sensor reading: sensor frame, measured on the tool, with its offset), the ground
truth as JSON and, if asked, the ``WorldConfig`` JSON of the world (for ``contact-skills simulate --world``).
numpy and PyBullet load only when the command runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cli.errors import UserError, report_user_error
from services.quiet_imports import import_pybullet_quietly


def _vector(values, digits: int = 2) -> str:
    return "[" + ", ".join(f"{x:+.{digits}f}" for x in values) + "]"


def run_kinesthetic_record(args: argparse.Namespace) -> int:
    """Record ``args.scenario`` (a kinesthetic scenario) with ``args.seed``, ``args.strokes``, ``args.friction``;
    write ``args.output`` (CSV), ``args.truth`` and ``args.world`` (JSON, optional); print the summary."""
    try:
        from corpus.kinesthetic import recording_csv_text
        from sim_worker.kinesthetic_teacher import (
            KINESTHETIC_SCENARIOS,
            LEARN_IMPORT_OPTIONS,
            kinesthetic_truth_dict,
            record_kinesthetic,
        )

        problems = []
        if args.scenario not in KINESTHETIC_SCENARIOS:
            problems.append(f"scenario: unknown kinesthetic scenario {args.scenario!r}; choose one of "
                            f"{', '.join(KINESTHETIC_SCENARIOS)}")  # fmt: skip
        if args.output.suffix.lower() != ".csv":
            problems.append(f"output: {args.output} must end in .csv (a kinesthetic recording file)")
        if args.strokes is not None and not 1 <= args.strokes <= 6:
            problems.append(f"strokes: {args.strokes} is not in 1..6")
        if args.friction is not None and not 0.0 <= args.friction <= 1.0:
            problems.append(f"friction: {args.friction} is not in [0, 1]")
        if problems:
            raise UserError(problems)
        demo = record_kinesthetic(args.scenario, seed=args.seed, n_strokes=args.strokes, friction=args.friction)
    except Exception as exc:
        return report_user_error("record", exc)
    truth = demo.truth
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(recording_csv_text(demo))
    print(f"recorded {args.scenario} (kinesthetic, seed {args.seed}): {len(truth.strokes)} strokes, friction "
          f"{truth.friction:.3f}, {demo.t.size} samples at 100 Hz, {demo.simulated_s:.1f} s simulated in "
          f"{demo.wall_time_s:.1f} s -> {args.output}")  # fmt: skip
    for k, stroke in enumerate(truth.strokes, start=1):
        turn = f", normal turns {stroke.normal_turn_deg:.1f} deg" if stroke.normal is None else ""
        print(f"  stroke {k}: contact {stroke.t_on:.3f} - {stroke.t_off:.3f} s ({stroke.t_off - stroke.t_on:.2f} s), "
              f"plateau {stroke.plateau_force_n:.1f} N{turn}")  # fmt: skip
    offset = truth.sensor_offset
    print(f"  sensor offset (sensor frame, measured on the tool, as in the file): force {_vector(offset[:3])} N, "
          f"moment {_vector(offset[3:], 3)} N·m")  # fmt: skip
    print(f"  largest free-space hand force {truth.operator_force_max_n:.1f} N")
    if args.truth is not None:
        args.truth.parent.mkdir(parents=True, exist_ok=True)
        args.truth.write_text(json.dumps(kinesthetic_truth_dict(demo)))
        print(f"ground truth -> {args.truth}")
    if args.world is not None and demo.world_config is not None:
        args.world.parent.mkdir(parents=True, exist_ok=True)
        args.world.write_text(json.dumps(demo.world_config.to_dict(), indent=1))
        print(f"world -> {args.world} (contact-skills simulate SKILL --world {args.world})")
    print(f"learn it with: contact-skills learn {args.output} {LEARN_IMPORT_OPTIONS} -o skill.json")
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``record`` to the `contact-skills` parser."""
    from_scenarios = "slide_flat, slide_tilted, slide_two_planes, contour_cylinder, contour_block"
    kinesthetic_scenarios = "wipe_flat, wipe_tilted, wipe_curved"  # kinesthetic_teacher.KINESTHETIC_SCENARIOS
    record = commands.add_parser(
        "record",
        help="record a scripted or kinesthetic (hand-guided) teacher demonstration in the simulated world",
        description=f"{_run_record.__doc__} Scenarios: {from_scenarios} (--style scripted); "
        f"{kinesthetic_scenarios} (--style kinesthetic: 1-4 wiping strokes as a person guiding the arm makes them, "
        "written as a real recording file: 100 Hz, no time column, w-first quaternions, raw wrist-sensor wrench).",
    )
    record.add_argument("scenario", help="teacher scenario name")
    record.add_argument(
        "-o", "--output", type=Path, required=True, help="demo.json (a Demonstration) or demo.csv; kinesthetic: .csv"
    )
    record.add_argument(
        "--style",
        choices=["scripted", "kinesthetic"],
        default="scripted",
        help="scripted: one clean stroke at 1 kHz; kinesthetic: a hand-guided wiping recording",
    )
    record.add_argument("--strokes", type=int, metavar="N", help="kinesthetic: number of strokes 1-6 (default: seed)")
    record.add_argument(
        "--friction",
        type=float,
        metavar="MU",
        help="kinesthetic: tool-surface friction coefficient (default: from the seed, 0.2-0.4)",
    )
    record.add_argument("--seed", type=int, default=0, help="seed of the teacher's human-like imperfection")
    record.add_argument(
        "--truth", type=Path, help="also write the ground truth (normals, force, contact times) as JSON"
    )
    record.add_argument("--world", type=Path, help="also write the world's WorldConfig JSON (for simulate --world)")
    record.set_defaults(run=_run_record)


def _run_record(args: argparse.Namespace) -> int:
    """``contact-skills record``: the teacher guides the simulated robot and the recording is written."""
    import_pybullet_quietly()
    if args.style == "kinesthetic":
        return run_kinesthetic_record(args)
    try:
        import json

        from services.csv_import import demonstration_csv_text
        from sim_worker.teacher import SCENARIOS, record_demonstration

        if args.scenario not in SCENARIOS:
            raise UserError([f"scenario: unknown {args.scenario!r}; choose one of {', '.join(SCENARIOS)}"])
        if args.output.suffix.lower() not in (".json", ".csv"):
            raise UserError([f"output: {args.output} must end in .json or .csv"])
        if args.strokes is not None or args.friction is not None:
            raise UserError(["--strokes and --friction go with --style kinesthetic"])
        recording = record_demonstration(args.scenario, seed=args.seed)
    except Exception as exc:
        return report_user_error("record", exc)
    demonstration = recording.demonstration
    args.output.parent.mkdir(parents=True, exist_ok=True)
    if args.output.suffix.lower() == ".csv":
        args.output.write_text(demonstration_csv_text(demonstration))
    else:
        args.output.write_text(demonstration.model_dump_json())
    intervals = ", ".join(f"{on:.3f}-{off:.3f} s" for on, off in recording.contact_intervals)
    print(f"recorded {args.scenario} (seed {args.seed}): {demonstration.n_samples} samples, contact {intervals}, "
          f"target force {recording.target_force_n:.1f} N -> {args.output}")  # fmt: skip
    if args.truth is not None:
        args.truth.write_text(json.dumps(recording.ground_truth_dict(), indent=1))
        print(f"ground truth -> {args.truth}")
    if args.world is not None:
        args.world.write_text(json.dumps(recording.world_config.to_dict(), indent=1))
        print(f"world -> {args.world}")
    return 0
