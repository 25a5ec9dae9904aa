"""``contact-skills learn`` (a recording: import, learn, write, summary) and ``demo-learn`` (the first KU Leuven
recording)."""

from __future__ import annotations

import argparse
import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

from cli.errors import UserError, report_user_error
from cli.import_options import LazyArgumentsParser, add_import_arguments, import_demonstration
from services.datasets import DATA_ENV, KULEUVEN_IMPORT, data_directory, kuleuven_recordings
from services.demonstration_files import SUPPORTED_FILES
from services.local_processes import THREAD_LIMIT_ENV


def _add_learn_arguments(parser: LazyArgumentsParser) -> None:
    # The first of the parser's lazy steps, before add_import_arguments' step (it imports numpy to build its options):
    # the thread limit must be in the environment before numpy loads its BLAS, which happens while `learn` is parsed.
    parser.add_lazily(lambda _: _thread_limit_environment())
    parser.add_argument(
        "files",
        type=Path,
        nargs="+",
        metavar="file",
        help=f"demonstration: {SUPPORTED_FILES}; several files of the same task are learned together into ONE skill "
        "(docs/LEARNING.md section 11), each imported with the same options",
    )
    parser.add_argument(
        "--misfit",
        choices=["leave_out", "refuse"],
        default="leave_out",
        help="several files: leave out one that does not fit the others (named with its reason), or refuse to learn "
        "(exit 2 naming it) (default leave_out)",
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


def _thread_limit_environment() -> None:
    """Put `THREAD_LIMIT_ENV` (one BLAS/OpenMP thread) into this process's environment, where the user's own setting
    wins: a BLAS reads its thread count from there when it loads, so this works only before numpy is imported."""
    for variable, value in THREAD_LIMIT_ENV.items():
        os.environ.setdefault(variable, value)


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with one BLAS/OpenMP thread, as `contact-skills up` runs its processes: a multi-threaded BLAS is
    3.5x slower with one of two cores busy, 12x under heavier load. A BLAS not loaded yet gets it from the environment
    (`_thread_limit_environment`); one already loaded (an in-process caller) is limited through threadpoolctl for the
    block."""
    _thread_limit_environment()
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        yield


def learn_and_report(demonstrations, sources: list[str], options, output: Path, figure: Path | None) -> None:
    """Learn the skill from ``demonstrations`` (one, or several of one task given as ``sources``) with ``options``
    (`schemas.LearnOptions`), write it (and the figure of the reference demonstration), print the summary with its
    checks' warnings. Callers run it in `one_blas_thread`."""
    import time

    from skills.joint_learning import learn_joint_skill

    started = time.perf_counter()
    skill = learn_joint_skill(demonstrations, options, sources)
    elapsed = time.perf_counter() - started
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(skill.model_dump_json(indent=1))
    uses = skill.demonstrations or []
    reference = next((demonstrations[use.index] for use in uses if use.reference), demonstrations[0])
    for line in joint_lines(skill) + summary_lines(reference, skill):
        print(line)
    print(f"learned in {elapsed:.2f} s; skill written to {output}")
    if figure is not None:
        from services.figures import write_learning_figure

        figure.parent.mkdir(parents=True, exist_ok=True)
        write_learning_figure(reference, skill, figure)
        print(f"figure written to {figure}")


def joint_lines(skill) -> list[str]:
    """What a skill learned from several demonstrations says about each (none for one)."""
    uses = skill.demonstrations or []
    lines = (
        [f"learned from {sum(use.weight > 0 for use in uses)} of {len(uses)} demonstrations together:"] if uses else []
    )
    for use in uses:
        if use.misfit is not None:
            lines.append(f"  {use.source}: LEFT OUT ({use.misfit.value}): {use.reason}")
            continue
        # Judged against the skill learned from the others (leave-one-out); with one other, no band to judge by.
        band = (
            ""
            if use.share_in_band is None
            else f"{100 * use.share_in_band:.0f} % of its contact in the others' force band, "
        )
        agreement = (
            f"{band}its own CF z {use.normal_angle_deg:.1f} deg from the others' joint one"
            if use.normal_angle_deg is not None
            else "not aligned"
        )
        role = ", the reference" if use.reference else ""
        lines.append(f"  {use.source}: weight {use.weight:.2f}{role}; {agreement}")
    return lines


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
    """``contact-skills learn``: import a recording (or several of the same task, learned together into one skill),
    learn the skill, write it, print the summary."""
    try:
        with one_blas_thread():
            demonstrations = [import_demonstration(file, args) for file in args.files]
            from schemas import LearnOptions

            options = LearnOptions(
                skill_type=args.skill_type, n_basis=args.basis, strict=args.strict, misfit=args.misfit
            )
            learn_and_report(demonstrations, [str(f) for f in args.files], options, args.output, args.figure)
    except Exception as exc:
        return report_user_error("learn", exc)
    return 0


def cmd_demo_learn(args: argparse.Namespace) -> int:
    """``contact-skills demo-learn``: learn a contour skill from the first KU Leuven recording."""
    try:
        recordings = kuleuven_recordings()
        if not recordings:
            raise UserError([f"no KU Leuven recordings (contour_*.csv) under {data_directory()}; set {DATA_ENV}"])
        with one_blas_thread():
            from schemas.import_options import CsvImportOptions
            from services.csv_import import demonstration_from_csv

            print(f"importing {recordings[0]}")
            demonstration = demonstration_from_csv(recordings[0], CsvImportOptions(**KULEUVEN_IMPORT))
            out = args.out_dir
            from schemas import LearnOptions

            learn_and_report(
                [demonstration],
                [str(recordings[0])],
                LearnOptions(skill_type="contour"),
                out / "skill.json",
                out / "learn.png",
            )
    except Exception as exc:
        return report_user_error("demo-learn", exc)
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``learn`` and ``demo-learn`` to the `contact-skills` parser."""
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
