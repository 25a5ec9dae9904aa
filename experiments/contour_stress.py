"""Contours, and the crease between two slides, when the part is not where or not what it was taught.

One skill each, learned from the scripted teacher (``contour_cylinder``: over a cylinder of radius 8 cm, ±50° around
its top at 12 N; ``slide_two_planes``: across the crease between the table and a 20° ramp at 15 N), executed on
parts changed in ways the controller is not told: the cylinder 8 cm higher or lower, 5 cm across its axis, turned
by 10°, of radius 6 or 12 cm (its crown where it was taught), a pad of 3e3 to 1e6 N/m, the ramp's crease 2 cm before
or after where it was taught. Every case runs with every controller, and ``hybrid_cf`` twice: with the paper's
fixed frames and following the surface (``follow_surface_normal``, ``execution.surface_following``).

Ground truth: the simulator's normal force at the contact against the desired force (the metrics' true RMS and
largest steady error, % of the reference force), the share of the contact phase in contact, the verdict.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from execution.telemetry import Telemetry
from schemas import LearnOptions
from schemas.execution import PHASE_CODES, ControllerKind, ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.skill import Skill
from schemas.sweep import SweepParameter
from schemas.verdict import Verdict
from schemas.world import WorldConfig, WorldOverrides
from sim_worker.execution_world import execution_world
from sim_worker.executor import run_skill
from sim_worker.teacher import record_demonstration
from skills.parameterize import learn_skill
from skills.sweeps import trial_world_overrides

CONTOUR, CREASE = "contour_cylinder", "slide_two_planes"
RESULTS_SECTION = "contour-stress"
"""The section of docs/RESULTS.md the table is written into (``benchmarks/bench_contours.py``; the demo keeps it)."""
APPROACH_MAX_DISTANCE_M = 0.25
"""The guarded approach's reach in these runs: a cylinder 8 cm lower, approached along the taught normal 50° from
the vertical, is met 15.5 cm from the pre-contact point (the default 0.15 m does not reach it)."""


@dataclass(frozen=True)
class StressCase:
    """One unknown change of the part: its name, what it is, the scenario whose skill runs, the environment change
    (``EnvironmentChange`` fields) and the taught world's fields it changes (from the taught world dict)."""

    name: str
    description: str
    scenario: str
    environment: Mapping[str, Any] = field(default_factory=dict)
    world: Callable[[Mapping[str, Any]], WorldOverrides] | None = None


def _cylinder(parameter: SweepParameter, value: float) -> Callable[[Mapping[str, Any]], WorldOverrides]:
    return lambda world: trial_world_overrides(world, {parameter: value})


CASES: tuple[StressCase, ...] = (
    StressCase("as taught", "the cylinder as taught", CONTOUR),
    StressCase("8 cm higher", "the cylinder 8 cm higher", CONTOUR, {"unknown_offset": [0.0, 0.0, 0.08]}),
    StressCase("8 cm lower", "the cylinder 8 cm lower", CONTOUR, {"unknown_offset": [0.0, 0.0, -0.08]}),
    StressCase("5 cm across +", "the cylinder 5 cm across its axis", CONTOUR, {"unknown_offset": [0.0, 0.05, 0.0]}),
    StressCase("5 cm across -", "the cylinder 5 cm across its axis", CONTOUR, {"unknown_offset": [0.0, -0.05, 0.0]}),
    StressCase("radius 6 cm", "radius 6 cm, not 8", CONTOUR, world=_cylinder(SweepParameter.cylinder_radius_m, 0.06)),
    StressCase("radius 12 cm", "radius 12 cm, not 8", CONTOUR, world=_cylinder(SweepParameter.cylinder_radius_m, 0.12)),
    StressCase("yaw +10°", "the axis turned by 10°", CONTOUR, world=_cylinder(SweepParameter.cylinder_yaw_deg, 10.0)),
    StressCase("yaw -10°", "the axis turned by -10°", CONTOUR, world=_cylinder(SweepParameter.cylinder_yaw_deg, -10.0)),
    StressCase("pad 3e3 N/m", "a pad of 3e3 N/m", CONTOUR, {"contact_stiffness_n_m": 3e3}),
    StressCase("pad 3e5 N/m", "a pad of 3e5 N/m", CONTOUR, {"contact_stiffness_n_m": 3e5}),
    StressCase("pad 1e6 N/m", "a pad of 1e6 N/m", CONTOUR, {"contact_stiffness_n_m": 1e6}),
    StressCase("crease as taught", "the ramp's crease as taught", CREASE),
    StressCase("crease 2 cm early", "the crease 2 cm before", CREASE, world=lambda w: {"ramp": {"crease_x_m": -0.02}}),
    StressCase("crease 2 cm late", "the crease 2 cm after", CREASE, world=lambda w: {"ramp": {"crease_x_m": 0.02}}),
)


@dataclass(frozen=True)
class Column:
    """A controller as it runs: its name in the table and the execution settings it changes."""

    name: str
    settings: Mapping[str, Any]


COLUMNS: tuple[Column, ...] = (
    Column("hybrid_cf following", {"controller": ControllerKind.hybrid_cf, "follow_surface_normal": True}),
    Column("hybrid_cf (paper)", {"controller": ControllerKind.hybrid_cf, "follow_surface_normal": False}),
    Column("hybrid_world_z", {"controller": ControllerKind.hybrid_world_z}),
    Column("impedance_found_surface", {"controller": ControllerKind.impedance_found_surface}),
    Column("impedance", {"controller": ControllerKind.impedance}),
)


@dataclass(frozen=True)
class StressRun:
    """One case with one controller: its metrics, how long its guarded approaches took (simulated, s), the wall time
    of the run (s), its telemetry and the world it ran in."""

    case: StressCase
    column: Column
    metrics: ExecutionMetrics
    approach_s: float
    wall_s: float
    telemetry: Telemetry
    world: WorldConfig


def stress_skills(scenarios: Iterable[str] = (CONTOUR, CREASE), seed: int = 0, **overrides: Any) -> dict[str, Skill]:
    """The skills the cases run: each scenario's teacher recording (``seed``; ``overrides`` as
    `sim_worker.teacher.record_demonstration` takes them), learned with the default options."""
    recordings = {name: record_demonstration(name, seed=seed, **overrides) for name in scenarios}
    return {name: learn_skill(r.demonstration, LearnOptions()) for name, r in recordings.items()}


def run_case(case: StressCase, column: Column, skills: Mapping[str, Skill]) -> StressRun:
    """Execute ``case``'s skill with ``column``'s controller on the changed part (ground truth: the metrics)."""
    skill = skills[case.scenario]
    settings = ExecutionSettings(
        environment=dict(case.environment), approach_max_distance_m=APPROACH_MAX_DISTANCE_M, **column.settings
    )
    world = execution_world(skill, settings.environment, scenario=case.scenario)
    if case.world is not None:
        world = replace(world, config=world.config.replace(**case.world(world.config.to_dict())))
    start = time.perf_counter()
    result = run_skill(world, settings)
    approach = result.telemetry.phase_codes == PHASE_CODES[ExecutionPhase.approach]
    approach_s = float(approach.sum()) * world.config.time_step_s
    wall_s = time.perf_counter() - start
    return StressRun(case, column, result.metrics, approach_s, wall_s, result.telemetry, result.world_config)


def _cell(m: ExecutionMetrics) -> str:
    """``RMS / max %, contact %`` and the verdict, or how the run ended."""
    if m.phase is not ExecutionPhase.done or m.true_force_rms_error_pct is None:
        return f"{m.phase.value}: {(m.abort_reason or '').split(':')[0]}"
    verdict = "pass" if m.verdict is not None and m.verdict.verdict is Verdict.passed else "**fail**"
    return (
        f"{m.true_force_rms_error_pct:.1f} / {m.true_force_max_error_pct or 0.0:.1f} %, "
        f"{100.0 * (m.contact_ratio or 0.0):.0f} % ({verdict})"
    )


def stress_table(runs: list[StressRun]) -> str:
    """The markdown table: a row per case, a column per controller."""
    columns = list(dict.fromkeys(r.column.name for r in runs))
    cases = list(dict.fromkeys(r.case.name for r in runs))
    cells = {(r.case.name, r.column.name): _cell(r.metrics) for r in runs}
    lines = ["| unknown change | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    lines += [f"| {c} | " + " | ".join(cells.get((c, k), "") for k in columns) + " |" for c in cases]
    return "\n".join(lines)


def worst_of(runs: list[StressRun], column: str, cases: Iterable[str]) -> tuple[int, float, float, float]:
    """Over ``cases`` run with the controller ``column``: how many finished (``done``), and over those the worst true
    RMS (%), the largest steady error (%) and the lowest contact ratio (NaN when none finished)."""
    chosen = {*cases}
    done = [r.metrics for r in runs if r.column.name == column and r.case.name in chosen]
    done = [m for m in done if m.phase is ExecutionPhase.done and m.true_force_rms_error_pct is not None]
    if not done:
        return 0, np.nan, np.nan, np.nan
    return (
        len(done),
        max(float(m.true_force_rms_error_pct or 0.0) for m in done),
        max(float(m.true_force_max_error_pct or 0.0) for m in done),
        min(float(m.contact_ratio or 0.0) for m in done),
    )
