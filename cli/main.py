"""Entry point of the `contact-skills` console script.

Subcommands import their dependencies lazily, so ``contact-skills --help`` stays fast.
Errors a user can fix (bad file, bad column, invalid field, a demonstration that cannot give
the skill) print one line per problem to stderr and exit with code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from cli import bus_commands, demo_command, export_command, service_commands, sweep_command
from cli.help import polish
from cli.import_options import LazyArgumentsParser, add_import_arguments, import_demonstration
from services.datasets import DATA_ENV, KULEUVEN_IMPORT, data_directory, kuleuven_recordings
from services.demonstration_files import SUPPORTED_FILES

EXIT_USAGE = 2
"""Exit code for bad input (as argparse uses for bad arguments)."""


# --------------------------------------------------------------------------- errors


class UserError(Exception):
    """An error the user can fix: ``problems`` are printed one per line, exit code 2."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems


def _user_problems(exc: BaseException) -> list[str] | None:
    """The printable problems of a user-fixable error, or None for a bug (which keeps its traceback)."""
    from pydantic import ValidationError

    from services.importing import DemonstrationImportError, validation_problems

    if isinstance(exc, UserError | DemonstrationImportError):
        return exc.problems
    if isinstance(exc, ValidationError):
        return validation_problems(exc)
    if isinstance(exc, OSError):
        return [f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": ")]
    learning = sys.modules.get("skills.parameterize")  # loaded when it raised: not imported for the help
    if learning is not None and isinstance(exc, learning.SkillCheckError):
        return [f"--strict: the skill fails its check {c.name.value}: {c.message}" for c in exc.checks]
    if learning is not None and isinstance(exc, learning.LearningError):
        return str(exc).splitlines()
    return None


def _report_user_error(command: str, exc: BaseException) -> int:
    problems = _user_problems(exc)
    if problems is None:
        raise exc
    for problem in problems:
        print(f"contact-skills {command}: error: {problem}", file=sys.stderr)
    return EXIT_USAGE


# --------------------------------------------------------------------------- learn


def _add_learn_arguments(parser: LazyArgumentsParser) -> None:
    parser.add_argument(
        "file",
        type=Path,
        help=f"demonstration: {SUPPORTED_FILES}",
    )
    parser.add_argument(
        "--type",
        dest="skill_type",
        choices=["slide", "contour", "auto"],
        default="auto",
        help="the skill to learn; auto chooses slide or contour from the contact's geometry (default auto)",
    )
    parser.add_argument(
        "--basis", type=int, default=50, metavar="N", help="fewest DMP basis functions per segment (long ones get more)"
    )
    parser.add_argument(
        "--strict",
        action="store_true",
        help="refuse a skill that fails any of its checks against the demonstration (exit 2 giving each); by default "
        "it is written and the failed checks are printed as warnings",
    )
    parser.add_argument("-o", "--output", type=Path, required=True, help="skill JSON to write")
    parser.add_argument("--figure", type=Path, help="learning figure to write (PNG)")
    add_import_arguments(parser)


def learn_and_report(demonstration, options, output: Path, figure: Path | None) -> None:
    """Learn the skill from ``demonstration`` with ``options`` (`schemas.LearnOptions`), write it (and the figure),
    print the summary with its checks' warnings."""
    import time

    from threadpoolctl import threadpool_limits

    from skills.parameterize import learn_skill

    started = time.perf_counter()
    with threadpool_limits(1):  # one BLAS thread: a busy core makes a multi-threaded BLAS several times slower
        skill = learn_skill(demonstration, options)
    elapsed = time.perf_counter() - started
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(skill.model_dump_json(indent=1))
    for line in summary_lines(demonstration, skill):
        print(line)
    print(f"learned in {elapsed:.2f} s; skill written to {output}")
    if figure is not None:
        from services.figures import write_learning_figure

        figure.parent.mkdir(parents=True, exist_ok=True)
        write_learning_figure(demonstration, skill, figure)
        print(f"figure written to {figure}")


def _vector(v) -> str:
    return "[" + ", ".join(f"{x:+.3f}" for x in v) + "]"


def summary_lines(demonstration, skill) -> list[str]:
    """The learn summary: import notes, type, segments, CF axes, learned force, DMP reproduction errors."""
    import numpy as np

    from schemas import DemonstrationSummary, SegmentKind
    from services.figures import compliant_frame_axes

    d = DemonstrationSummary.of(demonstration)
    arrays = demonstration.arrays()  # once: each segment reads its own rows of them
    meta = demonstration.metadata
    lines = [f"demonstration {d.name or '(unnamed)'}: {d.n_samples} samples, {d.duration_s:.2f} s, "
             f"{d.mean_rate_hz:.0f} Hz, max |f| {d.max_force_n:.1f} N (source {meta.source})"]  # fmt: skip
    lines += [f"  import: {note}" for note in meta.extra.get("import_notes", [])]
    if skill.auto_selection is not None:
        auto = skill.auto_selection
        lines.append(f"skill type: {skill.skill_type.value} (auto, confidence {auto.confidence:.2f}: {auto.reason})")
    else:
        lines.append(f"skill type: {skill.skill_type.value} (as asked)")
    lines.append(f"segments: {len(skill.segments)}")
    for s in skill.segments:
        q = s.quality
        lines.append(
            f"  {s.index} {s.kind.value:7s} {s.t_start:7.3f} - {s.t_end:7.3f} s"
            f"  (starts: {s.start_reason}, ends: {s.end_reason})"
        )
        if s.kind == SegmentKind.contact and s.compliant_frames is not None:
            axes = compliant_frame_axes(arrays, s)
            if len(s.compliant_frames.t) == 1:
                lines.append(f"    CF normal (z) in world {_vector(axes.mean_world)}")
            else:
                lines.append(
                    f"    CF z mean in world {_vector(axes.mean_world)}, in tool {_vector(axes.mean_tool)} "
                    f"(RMS {axes.tool_spread_deg:.1f} deg about it in the tool frame)"
                )
        if s.force_constant_n is not None:
            lines.append(f"    force: constant {s.force_constant_n:.2f} N along CF z")
            if q.force_measured_percentiles_n is not None:
                p10, p50, p90 = q.force_measured_percentiles_n
                lines.append(
                    f"    measured along CF z: median {p50:.2f} N, 10-90 % {p10:.2f}-{p90:.2f} N "
                    f"(std {q.force_std_low_variance_n:.2f} N in the steady part the constant comes from)"
                )
        elif s.force_dmp is not None:
            from services.figures import learned_force_curve

            _, f = learned_force_curve(s, 1.0 / skill.sample_rate_hz)
            lines.append(f"    force profile (DMP): min {f.min():.1f} / mean {f.mean():.1f} / max {f.max():.1f} N")
        errors = f"position {q.position_rms_m * 1e3:.2f} mm, orientation {np.degrees(q.orientation_rms_rad):.2f} deg"
        if q.force_rms_n is not None:
            errors += f", force {q.force_rms_n:.2f} N"
        lines.append(f"    DMP reproduction RMS: {errors}")
    warnings = skill.warnings()
    lines.append(f"checks against the demonstration: {len(skill.checks) - len(warnings)} of {len(skill.checks)} passed")
    lines += [f"  WARNING: {warning}" for warning in warnings]
    return lines


def cmd_learn(args: argparse.Namespace) -> int:
    """``contact-skills learn``: import a recording, learn the skill, write it, print the summary."""
    try:
        demonstration = import_demonstration(args)
        from schemas import LearnOptions

        options = LearnOptions(skill_type=args.skill_type, n_basis=args.basis, strict=args.strict)
        learn_and_report(demonstration, options, args.output, args.figure)
    except Exception as exc:
        return _report_user_error("learn", exc)
    return 0


def cmd_demo_learn(args: argparse.Namespace) -> int:
    """``contact-skills demo-learn``: learn a contour skill from the first KU Leuven recording."""
    try:
        recordings = kuleuven_recordings()
        if not recordings:
            raise UserError([f"no KU Leuven recordings (contour_*.csv) under {data_directory()}; set {DATA_ENV}"])
        from schemas.import_options import CsvImportOptions
        from services.csv_import import demonstration_from_csv

        print(f"importing {recordings[0]}")
        demonstration = demonstration_from_csv(recordings[0], CsvImportOptions(**KULEUVEN_IMPORT))
        out = args.out_dir
        from schemas import LearnOptions

        learn_and_report(demonstration, LearnOptions(skill_type="contour"), out / "skill.json", out / "learn.png")
    except Exception as exc:
        return _report_user_error("demo-learn", exc)
    return 0


# --------------------------------------------------------------------------- simulate


def _add_simulate_parser(commands) -> None:
    """Register ``contact-skills simulate``."""
    sim = commands.add_parser(
        "simulate",
        help="execute a learned skill in the PyBullet world with the hybrid controller",
        description=_run_simulate.__doc__,
    )
    sim.add_argument("skill", type=Path, help="skill JSON (from `contact-skills learn` or POST /skills)")
    world = sim.add_mutually_exclusive_group()
    world.add_argument("--scenario", help="run in this teacher scenario's world instead of the skill's own")
    world.add_argument("--world", type=Path,
                       help="run in this world: a WorldConfig JSON or the file `record --truth` writes")  # fmt: skip
    sim.add_argument("--work-piece", choices=["auto", "taught", "measured", "rebuilt"], default="auto",
                     help="taught: the world a simulator recording carries; measured: surfaces fitted to what the "
                          "--demonstration measured; rebuilt: surfaces rebuilt from the skill (planes under slides, "
                          "strips along contours); auto: taught if known, else measured if --demonstration is "
                          "given")  # fmt: skip
    sim.add_argument("--placement", type=float, nargs="+", metavar="V",
                     help="where the skill and its rebuilt work piece go in the robot's world: X Y Z (m), "
                          "X Y Z YAW_DEG, or X Y Z QX QY QZ QW (default: chosen to be in reach)")  # fmt: skip
    sim.add_argument("--offset", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("DX", "DY", "DZ"),
                     help="KNOWN work piece shift, m (applied to the skill and the world)")  # fmt: skip
    sim.add_argument("--unknown-offset", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("DX", "DY", "DZ"),
                     help="UNKNOWN work piece shift, m (applied to the world only)")  # fmt: skip
    sim.add_argument("--friction", type=float, metavar="MU", help="tool-surface friction (default 0.2)")
    sim.add_argument("--contact-stiffness", type=float, metavar="N_PER_M", help="contact stiffness (default 3e4)")
    sim.add_argument("--sensor", choices=["wrist", "ideal"], default="wrist",
                     help="force/torque sensor the controller reads: a realistic wrist sensor (noise, drift, 2 ms "
                          "delay, 200 Hz filter, tool inertia) or the exact contact wrench")  # fmt: skip
    sim.add_argument("--controller", choices=["hybrid_cf", "impedance", "impedance_found_surface", "hybrid_world_z"],
                     default="hybrid_cf", help="ours (hybrid_cf) or a baseline (see docs/CONVENTIONS.md)")  # fmt: skip
    sim.add_argument(
        "--pace",
        choices=["fast", "realtime"],
        default="fast",
        help="fast: as fast as it runs; realtime: simulated time follows the clock (default fast)",
    )
    sim.add_argument("--demonstration", type=Path,
                     help="demonstration JSON the skill was learned from: the path the path error refers to, and "
                          "the surface the work piece is measured from")  # fmt: skip
    sim.add_argument("--figure", type=Path, help="force-tracking figure to write (PNG)")
    sim.add_argument("--scene", type=Path, help="3-D figure of the work piece, learned and executed paths (PNG)")
    sim.add_argument("--json", type=Path, help="metrics JSON to write")
    sim.set_defaults(run=_run_simulate)


def _placement_of(values: list[float] | None) -> dict | None:
    """``--placement`` numbers as a ``Placement`` dict: X Y Z, X Y Z YAW_DEG or X Y Z QX QY QZ QW."""
    if values is None:
        return None
    if len(values) == 3:
        return {"translation_m": values}
    if len(values) == 4:
        half = math.radians(values[3]) / 2
        return {"translation_m": values[:3], "rotation": [0.0, 0.0, math.sin(half), math.cos(half)]}
    if len(values) == 7:
        return {"translation_m": values[:3], "rotation": values[3:]}
    raise UserError([f"placement: give 3, 4 or 7 numbers (X Y Z [YAW_DEG | QX QY QZ QW]), not {len(values)}"])


def _run_simulate(args: argparse.Namespace) -> int:
    """``contact-skills simulate``: run a skill in simulation, print the metrics and the verdict (exit 1 if it aborted,
    4 if its verdict failed).

    Any skill runs with no other argument: a skill recorded in the simulator runs in the world it carries; any
    other (a real recording) runs on a work piece measured from its --demonstration (else rebuilt from what it
    learned), placed in the robot's reach.
    """
    try:
        import json

        from schemas import Demonstration, ExecutionSettings, Skill
        from sim_worker.execution_world import execution_worlds
        from sim_worker.executor import run_skill

        skill = Skill.model_validate_json(args.skill.read_text())
        demonstration = (
            Demonstration.model_validate_json(args.demonstration.read_text()) if args.demonstration else None
        )
        settings = ExecutionSettings(
            controller=args.controller,
            environment={
                "offset": args.offset,
                "unknown_offset": args.unknown_offset,
                "work_piece": args.work_piece,
                "placement": _placement_of(args.placement),
                "friction": args.friction,
                "contact_stiffness_n_m": args.contact_stiffness,
                "sensor": args.sensor,
            },
            pace=args.pace,
        )
        world_file = json.loads(args.world.read_text()) if args.world is not None else None
        try:
            worlds = execution_worlds(
                skill,
                settings.environment,
                scenario=args.scenario,
                world=world_file,
                demonstration=demonstration,
                approach_clearance_m=settings.approach_clearance_m,
            )
        except ValueError as exc:  # unknown scenario or world field, a skill out of reach: the message says why
            raise UserError([str(exc)]) from None
        if len(worlds) > 1:
            print(f"no placement reaches all {len(worlds)} strokes: each stroke runs on its own, placed on its own")
        codes, metrics = [], []
        for k, world in enumerate(worlds):
            print(("" if len(worlds) == 1 else f"stroke {k + 1} of {len(worlds)}: ") + _world_line(world))
            result = run_skill(world, settings)
            metrics.append(result.metrics)
            codes.append(bus_commands.exit_code(result.metrics.phase.value == "done", result.metrics))
            _print_execution(result)
            suffix = "" if len(worlds) == 1 else f"_stroke{k + 1}"
            _write_execution_figures(args, world, result, suffix)
    except Exception as exc:
        return _report_user_error("simulate", exc)
    if args.json is not None:
        documents = [m.model_dump(mode="json") for m in metrics]
        args.json.write_text(json.dumps(documents[0] if len(documents) == 1 else documents, indent=1))
    return next((code for code in codes if code), 0)


def _print_execution(result) -> None:
    """The metrics and the verdict of one execution, as ``simulate`` prints them."""
    m = result.metrics
    print(f"controller {m.controller.value}: {m.phase.value}" + (f" ({m.abort_reason})" if m.abort_reason else ""))
    if m.true_force_rms_error_n is not None:
        print(f"  true normal force error over {m.steady_contact_s:.2f} s of steady contact: RMS "
              f"{m.true_force_rms_error_n:.3f} N ({m.true_force_rms_error_pct:.2f} %), "
              f"max {m.true_force_max_error_n:.3f} N ({m.true_force_max_error_pct:.2f} %) "
              f"of {m.force_reference_n:.2f} N")  # fmt: skip
        print(f"  CF-z force error (the controller's view): RMS {m.force_rms_error_n:.3f} N "
              f"({m.force_rms_error_pct:.2f} %), max {m.force_max_error_n:.3f} N "
              f"({m.force_max_error_pct:.2f} %)")  # fmt: skip
    if m.touchdown_peak_n is not None:
        settle = f", settled within 5 % after {m.settle_time_s:.2f} s" if m.settle_time_s is not None else ""
        print(f"  touch-down peak {m.touchdown_peak_n:.2f} N ({m.touchdown_peak_ratio or 0:.2f} x the target){settle}")
    if m.cf_normal_angle_deg is not None:
        print(f"  CF z (as the controller used it) vs true surface normal: mean {m.cf_normal_angle_deg:.2f} deg, "
              f"max {m.cf_normal_angle_max_deg:.2f} deg")  # fmt: skip
    if m.path_rms_m is not None:
        print(f"  path RMS (CF x-y) {m.path_rms_m * 1e3:.2f} mm; contact ratio {m.contact_ratio * 100:.2f} %")
    for found in m.contact_found_offsets_m:
        print(f"  guarded approach: surface found {found * 1e3:+.1f} mm along CF z from where it was taught")
    print(f"  peak force {m.peak_force_n:.2f} N; {m.duration_s:.2f} s simulated in {result.loop_wall_s:.2f} s "
          f"(real-time factor {m.real_time_factor:.1f})")  # fmt: skip
    for line in m.verdict.lines():
        print(line)


def _write_execution_figures(args: argparse.Namespace, world, result, suffix: str) -> None:
    """``--figure`` and ``--scene`` of one execution (``suffix`` added to their names: a stroke's)."""
    if args.figure is not None:
        from services.figures import write_execution_figure

        figure = args.figure.with_name(args.figure.stem + suffix + args.figure.suffix)
        figure.parent.mkdir(parents=True, exist_ok=True)
        write_execution_figure(result, figure)
        print(f"figure written to {figure}")
    if args.scene is not None:
        from services.figures import write_scene_figure

        scene = args.scene.with_name(args.scene.stem + suffix + args.scene.suffix)
        scene.parent.mkdir(parents=True, exist_ok=True)
        pieces = [piece["vertices"] for piece in result.world_config.work_pieces]
        write_scene_figure(world.skill, result.telemetry, pieces, scene, title=_world_line(world))
        print(f"scene figure written to {scene}")


def _world_line(world) -> str:
    """One line: which world a skill runs in, and where it was placed."""
    if world.placement is None:
        return f"work piece: {world.source} world"
    t = ", ".join(f"{v:+.3f}" for v in world.placement.translation_m)
    q = ", ".join(f"{v:+.3f}" for v in world.placement.rotation)
    origin = "measured from the demonstration" if world.source == "measured" else "rebuilt from the skill"
    return (f"work piece: {origin} ({len(world.config.work_pieces)} parts); placement "
            f"({world.placement_reason}): translation [{t}] m, rotation [{q}] (xyzw)")  # fmt: skip


def _add_record_parser(commands) -> None:
    """Register ``contact-skills record``."""
    from_scenarios = "slide_flat, slide_tilted, slide_two_planes, contour_cylinder, contour_block"
    kinesthetic_scenarios = "wipe_flat, wipe_tilted, wipe_curved"  # sim_worker.kinesthetic_teacher.SCENARIOS
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
    if args.style == "kinesthetic":
        from cli.record_command import run_kinesthetic_record

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
        return _report_user_error("record", exc)
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


# --------------------------------------------------------------------------- main


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of all subcommands."""
    from services.settings import package_version

    parser = argparse.ArgumentParser(prog="contact-skills", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"contact-skills {package_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=LazyArgumentsParser)
    learn = commands.add_parser(
        "learn",
        help="learn a skill from a recorded demonstration (CSV, JSON, ROS 1 or ROS 2 bag)",
        description=cmd_learn.__doc__,
    )
    _add_learn_arguments(learn)
    learn.set_defaults(run=cmd_learn)
    demo = commands.add_parser(
        "demo-learn", help="learn a contour skill from a real KU Leuven recording", description=cmd_demo_learn.__doc__
    )
    demo.add_argument("--out-dir", type=Path, default=Path("out"), help="where to write skill.json and learn.png")
    demo.set_defaults(run=cmd_demo_learn)
    _add_record_parser(commands)
    _add_simulate_parser(commands)
    bus_commands.register(commands)
    service_commands.register(commands)
    demo_command.register(commands)
    export_command.register(commands)
    sweep_command.register(commands)
    polish(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen subcommand; returns the process exit code."""
    args = build_parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
