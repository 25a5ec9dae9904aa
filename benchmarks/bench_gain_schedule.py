"""Benchmark: the gain schedule from the demonstrations' spread (`skills.gain_schedule`, issue 42 item 4), measured.

Run from the repository root::

    .venv/bin/python benchmarks/bench_gain_schedule.py [--scenarios slide_flat slide_tilted contour_cylinder]

For each of the scripted teacher's scenarios: three hands (seeds 0, 1, 2) record it in the same world, one skill is
learned from all three (`skills.joint_learning`), and that skill is executed with ``gains.gain_schedule`` constant and
from_spread, on the true world with the table moved (2 cm higher, the controller not told, as the joint comparison
of docs/LEARNING.md section 11), and again with a disturbance along the motion axes: the tool-surface friction three
times the taught one (0.6 against 0.2), unknown to the controller, which drags the tool back along its path. Per run:
the true normal force's RMS error (% of the reference), the executed path's RMS distance to the taught one on the
motion axes (CF x-y, mm), the verdict, and the scheduled CF x-y stiffness (least and median over the contact phases,
N/m; constant: the configured 3000). Writes its section of docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import add_smoke_argument, machine_line, pin_blas_threads, write_section

pin_blas_threads()

import numpy as np  # noqa: E402

from schemas.execution import ControllerGains, EnvironmentChange, ExecutionSettings, GainSchedule  # noqa: E402
from schemas.skill import SegmentKind, Skill  # noqa: E402

SECTION = "gain-schedule"
SCENARIOS = {"slide_flat": {}, "slide_tilted": {}, "contour_cylinder": {}}
"""The scripted teacher's scenarios of the full run, with their overrides."""
SMOKE_SCENARIOS = {"slide_flat": {"move_duration_s": 2.0}}
"""The smoke run's: a 2 s flat slide."""
SEEDS = (0, 1, 2)
"""The hands of the full run; the smoke run's first two."""
UNKNOWN_OFFSET_M = [0.0, 0.0, 0.02]
"""The table 2 cm higher than taught, unknown to the controller (every run)."""
DISTURBED_FRICTION = 0.6
"""The disturbance: the tool-surface friction coefficient, three times the taught world's 0.2."""


@dataclass(frozen=True)
class Run:
    """One execution of a scenario's joint skill: its condition, gain schedule and what it measured."""

    scenario: str
    condition: str
    schedule: GainSchedule
    stiffness_min: float
    stiffness_median: float
    force_rms_pct: float
    path_rms_mm: float
    verdict: str


def scheduled_xy_stiffness(skill: Skill, gains: ControllerGains) -> tuple[float, float]:
    """The least and the median CF x-y stiffness (N/m) the schedule gives over the skill's contact segments (on 201
    phase points each; constant: the configured)."""
    from skills.gain_schedule import scheduled_stiffness

    values = []
    for segment in skill.segments:
        if segment.kind is SegmentKind.contact:
            k = scheduled_stiffness(segment, gains, np.linspace(0.0, 1.0, 201))
            values.append(np.asarray(gains.translational_stiffness_n_per_m[:2])[None] if k is None else k[:, :2])
    flat = np.concatenate(values).ravel()
    return float(flat.min()), float(np.median(flat))


def scenario_runs(scenario: str, seeds: tuple[int, ...], **overrides: object) -> list[Run]:
    """Record ``scenario`` with each of ``seeds``, learn them together, and execute the joint skill under each
    condition with each gain schedule."""
    from sim_worker.executor import execute_skill
    from sim_worker.teacher import record_demonstration
    from skills.joint_learning import learn_joint_skill

    recordings = [record_demonstration(scenario, seed=seed, **overrides) for seed in seeds]
    joint = learn_joint_skill([r.demonstration for r in recordings], sources=[str(seed) for seed in seeds])
    reference = recordings[next(use.index for use in joint.demonstrations or [] if use.reference)]
    world = reference.world_config
    disturbed = world.model_copy(
        update={"contact": world.contact.model_copy(update={"lateral_friction": DISTURBED_FRICTION})}
    )
    conditions = {"table 2 cm higher": world, f"and friction {DISTURBED_FRICTION:g}": disturbed}
    environment = EnvironmentChange(unknown_offset=UNKNOWN_OFFSET_M)
    runs = []
    for condition, config in conditions.items():
        for schedule in GainSchedule:
            gains = ControllerGains(gain_schedule=schedule)
            settings = ExecutionSettings(pace="fast", environment=environment, gains=gains)
            m = execute_skill(joint, config, settings, demonstration=reference.demonstration).metrics
            least, median = scheduled_xy_stiffness(joint, gains)
            runs.append(
                Run(
                    scenario,
                    condition,
                    schedule,
                    least,
                    median,
                    m.true_force_rms_error_pct if m.true_force_rms_error_pct is not None else float("nan"),
                    1e3 * m.path_rms_m if m.path_rms_m is not None else float("nan"),
                    m.verdict.verdict.value if m.verdict else m.phase.value,
                )
            )
    return runs


def build_report(scenarios: dict[str, dict], seeds: tuple[int, ...]) -> str:
    """The section: the runs' table, then the machine line."""
    rows = [
        f"| {r.scenario} | {r.condition} | {r.schedule.value} | {r.stiffness_min:.0f} / {r.stiffness_median:.0f} | "
        f"{r.force_rms_pct:.2f} | {r.path_rms_mm:.2f} | {r.verdict} |"
        for scenario, overrides in scenarios.items()
        for r in scenario_runs(scenario, seeds, **overrides)
    ]
    return "\n".join(
        [
            "## Gain schedule from the demonstrations' spread: constant against from_spread (issue 42)",
            "",
            "`.venv/bin/python benchmarks/bench_gain_schedule.py`: the scripted teacher's scenarios, each recorded by "
            f"the hands of seeds {', '.join(map(str, seeds))} and learned together; the joint skill executed with "
            "`gains.gain_schedule` constant and from_spread, the table 2 cm higher than taught (unknown), then also "
            f"with the friction at {DISTURBED_FRICTION:g} (taught 0.2, unknown): a drag along the motion axes. True "
            "force RMS error in % of the reference force; path RMS: the executed path's distance to the taught one "
            "on the CF motion axes (x-y), mm. The CF x-y stiffness: least / median the schedule gives over the "
            "contact (N/m).",
            "",
            "| scenario | condition | gain schedule | CF x-y stiffness least / median N/m | true force RMS % | "
            "path RMS mm | verdict |",
            "|---|---|---|--:|--:|--:|---|",
            *rows,
            "",
            machine_line(),
        ]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), help="the teacher's scenarios to run")
    parser.add_argument("--no-write", action="store_true", help="only print the report")
    add_smoke_argument(parser, "a 2 s flat slide recorded by two hands")
    args = parser.parse_args(argv)
    if args.smoke:
        report = build_report(SMOKE_SCENARIOS, SEEDS[:2])
    else:
        report = build_report({name: SCENARIOS.get(name, {}) for name in args.scenarios}, SEEDS)
    print(report)
    if not (args.smoke or args.no_write):
        write_section(SECTION, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
