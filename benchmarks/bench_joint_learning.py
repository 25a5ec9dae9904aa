"""Benchmark: one skill from several demonstrations (`skills.joint_learning`, issue 42), leave-one-out against truth.

Run from the repository root::

    .venv/bin/python benchmarks/bench_joint_learning.py [--tuned-tasks 0 1 2 3] [--held-out-tasks 4 5 6 7]

Sets of trials of ONE task with known truth (`experiments.joint_trials`): the corpus's repeated human-like trials
(`corpus.families.human_trials`: a straight stroke on a tilted plane, where a single trial's tilt about the line is the
hand's lean; a contour across a cylinder), four trials per task; and the four KU Leuven recordings (two per
configuration), each moved onto the object where ``contour_b_1``'s registration found it. For every trial: the skill
learned from the others, its force band held against the left-out trial's TRUE normal force (the issue's target:
>= 90 % of its contact samples), and the joint skill's CF error against the truth next to the best single trial's.
Then: a trial of another task among them (named, not averaged in), and what learning N trials costs against one.

The split, stated honestly: the joint learner's constants were chosen while looking at tasks 0-3 of both corpus
kinds and at the KU Leuven recordings; tasks 4-7 were not run before this report. Writes its section of
docs/LEARNING.md and the cost's of docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import (
    LEARNING_MD,
    add_smoke_argument,
    machine_line,
    median_time,
    pin_blas_threads,
    write_section,
)

pin_blas_threads()

from benchmarks.bench_corpus import within  # noqa: E402
from corpus.families import TRIAL_KINDS, human_trials  # noqa: E402
from experiments.joint_trials import (  # noqa: E402
    CadExecuted,
    LeftOut,
    corpus_leave_one_out,
    executed_comparison,
    kuleuven_cad_comparison,
    kuleuven_leave_one_out,
    read_csv,
)
from schemas.skill import SegmentKind  # noqa: E402
from skills.joint_learning import learn_joint_skill  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402

SECTION = "joint"
COST_SECTION = "joint-cost"
COMMAND = ".venv/bin/python benchmarks/bench_joint_learning.py"
TRIALS = 4
"""Trials per corpus task: each left out once, learned from the other three."""
IN_BAND_TARGET = 0.9
"""The issue's target share of a left-out trial's contact samples within the band."""


def _pct(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.0f}"


def loo_rows(results: list[LeftOut]) -> list[str]:
    """One table row per left-out trial."""
    rows = []
    for r in results:
        singles = " / ".join(f"{e:.1f}" for e in r.single_errors_deg)
        no_worse = "yes" if r.joint_error_deg <= r.best_single_deg + 1e-9 else "no"
        right = "" if r.joint_right is None else ("right" if r.joint_right else "wrong")
        warned = f"{len(r.warnings)} warning(s)" if r.warnings else "no warning"
        singles_state = (
            ", ".join(
                ("right" if ok else "wrong") + (" warned" if w else "")
                for ok, w in zip(r.singles_right, r.singles_warned, strict=True)
            )
            or "—"
        )
        rows.append(
            f"| {r.left_out} | {_pct(r.share_in_band)} | {r.joint_error_deg:.1f} | {singles} | {no_worse} | "
            f"{right} {warned} | {singles_state} | {', '.join(r.misfits) or '—'} |"
        )
    return rows


LOO_HEADER = [
    "| left out | its contact in the band % | joint CF error ° | each single's ° | joint ≤ best single | joint skill "
    "| singles | left out by the learner |",
    "|---|--:|--:|---|---|---|---|---|",
]


def summary_line(label: str, results: list[LeftOut]) -> str:
    """How many left-out trials met each target."""
    shares = [r.share_in_band for r in results if r.share_in_band is not None]
    in_band = sum(s >= IN_BAND_TARGET for s in shares)
    no_worse = sum(r.joint_error_deg <= r.best_single_deg + 1e-9 for r in results)
    line = (
        f"{label}: {len(results)} left out; the band holds >= {100 * IN_BAND_TARGET:.0f} % of the left-out contact for "
        f"{in_band} of {len(shares)} (median {100 * statistics.median(shares):.0f} %, least "
        f"{100 * min(shares):.0f} %); the joint CF error is no larger than the best single trial's for {no_worse} of "
        f"{len(results)} (joint median {statistics.median(r.joint_error_deg for r in results):.2f}°, best single "
        f"median {statistics.median(r.best_single_deg for r in results):.2f}°, worst single median "
        f"{statistics.median(max(r.single_errors_deg) for r in results):.2f}°)"
    )
    graded = [r for r in results if r.joint_right is not None]
    if graded:
        wandered = [r for r in graded if not all(r.singles_right) or any(r.singles_warned)]
        fixed = sum(bool(r.joint_right) and not r.warnings for r in wandered)
        line += (
            f". Sets where a single trial is wrong or warned: {len(wandered)} of {len(graded)}; learned together, "
            f"right without a warning: {fixed} of them (right at all: {sum(bool(r.joint_right) for r in wandered)})"
        )
    return line + "."


def another_task_rows(tasks: list[int]) -> list[str]:
    """For each task: three of its trials with a trial of the other kind among them: named, and the joint skill's
    segments the same as without it."""
    rows = []
    for kind in TRIAL_KINDS:
        other_kind = next(k for k in TRIAL_KINDS if k != kind)
        for task in tasks:
            cases = human_trials(kind, task, 3)
            stranger = human_trials(other_kind, task, 1)[0]
            demonstrations = [case.demonstration(read_csv) for case in cases]
            sources = [case.name for case in cases]
            alone = learn_joint_skill(demonstrations, sources=sources)
            mixed = learn_joint_skill(
                [*demonstrations, stranger.demonstration(read_csv)], sources=[*sources, stranger.name]
            )
            use = (mixed.demonstrations or [])[-1]
            same = [s.model_dump() for s in mixed.segments] == [s.model_dump() for s in alone.segments]
            named = "—" if use.misfit is None else f"{use.misfit.value}: {use.reason}"
            rows.append(
                f"| {kind} task {task} + {stranger.name} | {named} | {use.weight:.2f} | {'yes' if same else 'no'} |"
            )
    return rows


EXECUTED = {"slide_tilted": {}, "contour_cylinder": {}}
"""The scripted teacher's scenarios executed, single-trial skills against the joint one (full run; with overrides)."""
EXECUTED_SMOKE = {"slide_flat": {"move_duration_s": 2.0}}
"""The smoke run's: a 2 s flat slide."""
EXECUTED_SEEDS = (0, 1, 2)
"""The seeds (hands) of the executed comparison; the smoke run's first two."""


def executed_rows(scenarios: dict[str, dict], seeds: tuple[int, ...]) -> list[str]:
    """One row per scenario: each seed's single-trial skill and the joint one, executed."""
    rows = []
    for scenario, overrides in scenarios.items():
        e = executed_comparison(scenario, seeds, **overrides)
        singles = " / ".join(f"{r:.2f}" for r in e.single_rms_pct)
        best = min(e.single_rms_pct)
        rows.append(
            f"| {scenario} | {singles} | {', '.join(e.single_verdicts)} | {e.joint_rms_pct:.2f} / "
            f"{e.joint_max_pct:.1f} | {e.joint_verdict} | {_pct(e.joint_in_band)} | "
            f"{'yes' if e.joint_rms_pct <= best else 'no'} |"
        )
    return rows


def cad_rows(executed: list[CadExecuted]) -> list[str]:
    """One row per KU Leuven skill and CF x-y stiffness executed on the CAD, then per stiffness whether the joint
    skill's true force RMS is no larger than the best single skill's."""
    rows = []
    for e in executed:
        for run in e.runs:
            m = run.metrics
            face = "—" if run.on_face is None else f"{100 * run.on_face:.1f}"
            verdict = m.verdict.verdict.value if m.verdict else "—"
            rows.append(
                f"| {e.skill} | {run.lateral_stiffness_n_per_m:.0f} | {m.true_force_rms_error_pct:.2f} | "
                f"{m.true_force_max_error_pct:.1f} | {face} | {_pct(m.true_force_in_band)} | {verdict} |"
            )
    *singles, joint = executed
    lines = []
    for k, run in enumerate(joint.runs):
        best = min(singles, key=lambda e: e.runs[k].metrics.true_force_rms_error_pct)
        best_rms = best.runs[k].metrics.true_force_rms_error_pct
        rms = run.metrics.true_force_rms_error_pct
        lines.append(
            f"CF x-y stiffness {run.lateral_stiffness_n_per_m:.0f} N/m: the joint skill's true force RMS {rms:.2f} % "
            f"against the best single skill's {best_rms:.2f} % ({best.skill}): "
            f"{'no larger' if rms <= best_rms else 'larger'}."
        )
    return [*rows, "", *lines]


def build_report(
    tuned: list[int],
    held_out: list[int],
    kuleuven: bool,
    stranger_tasks: list[int],
    executed: dict[str, dict],
    seeds: tuple[int, ...],
) -> str:
    started = time.perf_counter()
    parts = [
        f"Command: `{COMMAND}`. Leave-one-out: every trial of a set left out in turn, the skill learned from the "
        "others (`skills.joint_learning.learn_joint_skill`, `skill_type=auto`). *its contact in the band*: the share "
        "of the left-out trial's contact samples (its own contact segments, aligned to the joint skill's by dynamic "
        "time warping) whose TRUE normal force lies in the joint skill's force band (target >= 90 %). *CF error*: "
        "corpus, `corpus.scoring` normal error (slide: CF z against the plane's normal; contour: time-weighted mean "
        "angle to the true normal); KU Leuven, the median angle of CF z from the crease's cone bisector (the ~90° cone "
        "holds every learned CF z; the bisector is not the true normal, the person leans 5-6° from it by choice). "
        "*right*: within `bench_corpus`'s tolerances against the task's truth (the trials' mean press).",
        "",
    ]
    everything: dict[str, list[LeftOut]] = {}
    for label, tasks in (("Tuned on", tuned), ("Held out", held_out)):
        for kind in TRIAL_KINDS:
            results = []
            for task in tasks:
                results += corpus_leave_one_out(f"{kind} task {task}", human_trials(kind, task, TRIALS), within)
            if not results:
                continue
            everything[f"{label}, {kind}"] = results
            parts += [
                f"**{label}: {kind}** (tasks {', '.join(map(str, tasks))}, {TRIALS} trials each)",
                "",
                *LOO_HEADER,
            ]
            parts += [*loo_rows(results), "", summary_line(f"{label}, {kind}", results), ""]
    if kuleuven:
        results = kuleuven_leave_one_out()
        everything["KU Leuven"] = results
        parts += ["**KU Leuven** (four recordings on the reference's placement of the object)", "", *LOO_HEADER]
        parts += [*loo_rows(results), "", summary_line("KU Leuven", results), ""]
    if stranger_tasks:
        parts += [
            "**A trial of another task among three of one** (a contour across a cylinder among strokes on a plane, and "
            "the reverse): how it is named, its weight, and whether the joint skill's segments are those learned "
            "without it (not averaged in).",
            "",
            "| set | named | weight | segments unchanged |",
            "|---|---|--:|---|",
            *another_task_rows(stranger_tasks),
            "",
        ]
    if executed:
        parts += [
            f"**Executed** (scripted teacher, seeds {', '.join(map(str, seeds))}: the same world, another hand each; "
            "every skill run with `hybrid_cf` on the true world with the table 2 cm higher than taught, not told): "
            "true normal force error in % of the reference force.",
            "",
            "| scenario | singles' RMS % | singles' verdicts | joint RMS / max % | joint verdict | joint's contact in "
            "its band % | joint ≤ best single |",
            "|---|---|---|---|---|--:|---|",
            *executed_rows(executed, seeds),
            "",
        ]
    if kuleuven:
        parts += [
            "**Executed on the KU Leuven object's CAD** (`experiments.joint_trials.kuleuven_cad_comparison`: the four "
            "recordings on the reference's placement of the object, each recording's own skill and the skill learned "
            "from all four, placed in reach and run with `hybrid_cf` and the wrist sensor on the registered CAD, "
            "`experiments.kuleuven_cad.cad_runs`, with the default CF x-y stiffness and the stiffer one that keeps "
            "the ball on the crease; [RESULTS.md](RESULTS.md)): true force error in % of the reference force.",
            "",
            "| skill | CF x-y stiffness (N/m) | true RMS % | true max % | ball on one face % | its contact in its "
            "band % | verdict |",
            "|---|--:|--:|--:|--:|--:|---|",
            *cad_rows(kuleuven_cad_comparison()),
            "",
        ]
    seconds = time.perf_counter() - started
    parts += [f"Run in {seconds:.0f} s.", "", machine_line()]
    return "\n".join(parts)


def cost_report(repeats: int) -> str:
    """What learning N trials costs against one: median wall time over ``repeats`` runs."""
    rows = []
    for kind in TRIAL_KINDS:
        demonstrations = [case.demonstration(read_csv) for case in human_trials(kind, 0, TRIALS)]
        one, _ = median_time(lambda d=demonstrations[0]: learn_skill(d), repeats)
        singles = statistics.mean(median_time(lambda d=d: learn_skill(d), repeats)[0] for d in demonstrations)
        for n in range(2, TRIALS + 1):
            joint, skill = median_time(lambda n=n, d=demonstrations: learn_joint_skill(d[:n]), repeats)
            samples = sum(len(d.t) for d in demonstrations[:n])
            contact = sum(s.kind is SegmentKind.contact for s in skill.segments)
            rows.append(
                f"| {kind} | {n} | {samples} | {contact} | {1000 * one:.0f} | {1000 * singles:.0f} | "
                f"{1000 * joint:.0f} | {joint / (n * singles):.2f} |"
            )
    return "\n".join(
        [
            "## Joint learning: N demonstrations of one task together, against one (issue 42)",
            "",
            f"Command: `{COMMAND}` (its cost part; `--smoke` runs one repeat). Median wall time of "
            f"{repeats} runs, one BLAS thread. *per trial*: the mean over the {TRIALS} trials of learning each alone.",
            "",
            "| trials of | N | samples in all | contact segments | one trial ms | per trial ms | N together ms | "
            "together / (N × per trial) |",
            "|---|--:|--:|--:|--:|--:|--:|--:|",
            *rows,
            "",
            machine_line(),
        ]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuned-tasks", type=int, nargs="+", default=[0, 1, 2, 3], help="corpus tasks tuned on")
    parser.add_argument("--held-out-tasks", type=int, nargs="+", default=[4, 5, 6, 7], help="held-out corpus tasks")
    parser.add_argument("--repeats", type=int, default=5, help="timing repeats of the cost table")
    parser.add_argument("--no-write", action="store_true", help="only print the report")
    add_smoke_argument(
        parser,
        "task 0 of each kind, no held-out tasks, no KU Leuven, a 2 s flat slide of two seeds executed, one "
        "timing repeat",
    )
    args = parser.parse_args(argv)
    if args.smoke:
        report = build_report(
            [0], [], kuleuven=False, stranger_tasks=[0], executed=EXECUTED_SMOKE, seeds=EXECUTED_SEEDS[:2]
        )
        cost = cost_report(1)
    else:
        report = build_report(
            args.tuned_tasks,
            args.held_out_tasks,
            kuleuven=True,
            stranger_tasks=args.held_out_tasks,
            executed=EXECUTED,
            seeds=EXECUTED_SEEDS,
        )
        cost = cost_report(args.repeats)
    print(report)
    print(cost)
    if not (args.smoke or args.no_write):
        write_section(SECTION, report, LEARNING_MD)
        write_section(COST_SECTION, cost)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
