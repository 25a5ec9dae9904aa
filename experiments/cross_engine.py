"""The scripted teacher's slides and contours, taught in PyBullet, executed on both engines (issue 44): the same skill,
settings and controller (``hybrid_cf``) on PyBullet and on MuJoCo (``ExecutionSettings.engine``), judged each by its
own engine's contact (the true normal force, the contact, the touch-down; ``execution.metrics``).

A case is a teacher scenario (seed 0, the skill type it teaches) and an environment change: as taught, the work piece
moved WITHOUT telling the controller (``unknown_offset``), or moved with the skill (``offset``, the paper's contour
trials). ``benchmarks/bench_engines.py`` prints the table and writes it into docs/RESULTS.md (section
:data:`CROSS_ENGINE_SECTION`; the demo keeps it).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from execution.telemetry import Telemetry
from schemas.execution import PHASE_CODES, Engine, ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.skill import LearnOptions, Skill
from schemas.verdict import Verdict
from sim_worker.execution_world import execution_world
from sim_worker.executor import run_skill
from sim_worker.teacher import TeacherRecording, record_demonstration
from skills.parameterize import learn_skill

CROSS_ENGINE_SECTION = "cross-engine"
"""The section of docs/RESULTS.md the table is written into (``benchmarks/bench_engines.py``; the demo keeps it)."""
RMS_AGREEMENT_POINTS = 2.0
"""Issue 44: a case's true-force RMS (% of the reference force) on MuJoCo within this many points of PyBullet's."""


@dataclass(frozen=True)
class EngineCase:
    """One execution of a teacher scenario's skill: its name, the scenario, the skill type taught, the environment
    change (``EnvironmentChange`` fields)."""

    name: str
    scenario: str
    skill_type: str
    environment: Mapping[str, Any] = field(default_factory=dict)


_UP_2CM, _DOWN_2CM, _UP_1CM = [0.0, 0.0, 0.02], [0.0, 0.0, -0.02], [0.0, 0.0, 0.01]
ENGINE_CASES: tuple[EngineCase, ...] = (
    EngineCase("slide, flat table, as taught", "slide_flat", "slide"),
    EngineCase("slide, flat table 2 cm higher (unknown)", "slide_flat", "slide", {"unknown_offset": _UP_2CM}),
    EngineCase("slide, flat table 2 cm lower (unknown)", "slide_flat", "slide", {"unknown_offset": _DOWN_2CM}),
    EngineCase("slide, 15° tilted table, as taught", "slide_tilted", "slide"),
    EngineCase("slide, 15° tilted table 1 cm higher (unknown)", "slide_tilted", "slide", {"unknown_offset": _UP_1CM}),
    EngineCase("slide across the table-ramp crease, as taught", "slide_two_planes", "slide"),
    EngineCase("contour over the cylinder, as taught", "contour_cylinder", "contour"),
    EngineCase("contour, cylinder +8 cm z (known: trial 1)", "contour_cylinder", "contour", {"offset": [0, 0, 0.08]}),
    EngineCase("contour, cylinder 1 cm higher (unknown)", "contour_cylinder", "contour", {"unknown_offset": _UP_1CM}),
    EngineCase("contour along the curved block, as taught", "contour_block", "contour"),
)
"""The cases of the full table; ``--smoke`` runs the first."""


@dataclass(frozen=True)
class WorstStep:
    """The contact step with the largest true normal force error of a run: when (s), the error (N), how much the
    true normal force changed from the step before (N) and how far the true normal turned from the step before (°):
    a new contact appearing (a crease) shows as a jump in one step along a turned normal."""

    t_s: float
    error_n: float
    jump_n: float
    turn_deg: float


def worst_step(telemetry: Telemetry) -> WorstStep | None:
    """The :class:`WorstStep` of the contact phase's steps in ``telemetry`` (None without any)."""
    steps = np.flatnonzero(telemetry.phase_codes == PHASE_CODES[ExecutionPhase.contact])
    steps = steps[steps > 0]
    if steps.size == 0:
        return None
    error = telemetry.normal_force_true[steps] - telemetry.desired_force[steps]
    k = int(steps[np.argmax(np.abs(error))])
    force, normal = telemetry.normal_force_true, telemetry.contact_normal
    cosine = float(np.clip(normal[k] @ normal[k - 1], -1.0, 1.0))
    worst_error = float(error[np.argmax(np.abs(error))])
    return WorstStep(
        float(telemetry.t[k]), worst_error, float(force[k] - force[k - 1]), float(np.degrees(np.arccos(cosine)))
    )


@dataclass(frozen=True)
class EngineRun:
    """One case on one engine: its metrics (the engine's own truth) and its worst contact step."""

    case: EngineCase
    engine: Engine
    metrics: ExecutionMetrics
    worst: WorstStep | None

    @property
    def passed(self) -> bool:
        return self.metrics.verdict is not None and self.metrics.verdict.verdict is Verdict.passed


def taught(cases: Iterable[EngineCase], seed: int = 0) -> dict[str, tuple[TeacherRecording, Skill]]:
    """The teacher's recording (PyBullet, ``seed``) of every scenario ``cases`` run, and the skill learned from it."""
    kinds = {case.scenario: case.skill_type for case in cases}
    recordings = {scenario: record_demonstration(scenario, seed=seed) for scenario in kinds}
    return {
        scenario: (r, learn_skill(r.demonstration, LearnOptions(skill_type=kinds[scenario])))
        for scenario, r in recordings.items()
    }


def run_case(case: EngineCase, engine: Engine, skills: Mapping[str, tuple[TeacherRecording, Skill]]) -> EngineRun:
    """Execute ``case``'s skill on ``engine`` in its taught world changed as the case says (pace fast)."""
    recording, skill = skills[case.scenario]
    settings = ExecutionSettings(engine=engine, environment=dict(case.environment), pace="fast")
    world = execution_world(skill, settings.environment, demonstration=recording.demonstration)
    result = run_skill(world, settings)
    return EngineRun(case, engine, result.metrics, worst_step(result.telemetry))


def _number(value: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "—" if value is None else f"{value * scale:.{digits}f}"


def verdict_text(metrics: ExecutionMetrics) -> str:
    """``pass`` or ``FAIL: <reasons>`` (an aborted run: its reason)."""
    if metrics.verdict is None:
        return metrics.phase.value
    if metrics.verdict.verdict is Verdict.passed:
        return "pass"
    return "FAIL: " + "; ".join(metrics.verdict.reasons)


def engine_table(runs: list[EngineRun]) -> list[str]:
    """The markdown table: one row per case and engine, then the case's MuJoCo - PyBullet difference in points."""
    lines = [
        "| case | engine | final | true RMS (%) | true max (%) | touch-down (x target) | contact (%) | verdict | "
        "real-time × |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | --- | ---: |",
    ]
    for run in runs:
        m = run.metrics
        lines.append(
            f"| {run.case.name} | {run.engine.value} | {m.phase.value} | {_number(m.true_force_rms_error_pct)} | "
            f"{_number(m.true_force_max_error_pct)} | {_number(m.touchdown_peak_ratio)} | "
            f"{_number(m.contact_ratio, 100.0)} | {verdict_text(m)} | {m.real_time_factor:.1f} |"
        )
    return lines


def differences(runs: list[EngineRun]) -> list[tuple[EngineCase, float | None, float | None, bool]]:
    """Per case run on both engines: MuJoCo's true RMS minus PyBullet's and the same for the true max (points of the
    reference force; None when either has none) and whether the verdicts agree."""
    by_case: dict[str, dict[Engine, EngineRun]] = {}
    for run in runs:
        by_case.setdefault(run.case.name, {})[run.engine] = run
    found = []
    for pair in by_case.values():
        if len(pair) < 2:
            continue
        bullet, mujoco = pair[Engine.pybullet].metrics, pair[Engine.mujoco].metrics
        rms = max_ = None
        if bullet.true_force_rms_error_pct is not None and mujoco.true_force_rms_error_pct is not None:
            rms = mujoco.true_force_rms_error_pct - bullet.true_force_rms_error_pct
        if bullet.true_force_max_error_pct is not None and mujoco.true_force_max_error_pct is not None:
            max_ = mujoco.true_force_max_error_pct - bullet.true_force_max_error_pct
        found.append(
            (pair[Engine.pybullet].case, rms, max_, pair[Engine.pybullet].passed == pair[Engine.mujoco].passed)
        )
    return found


def difference_table(runs: list[EngineRun]) -> list[str]:
    """The markdown table of :func:`differences`, each case within :data:`RMS_AGREEMENT_POINTS` or not."""
    lines = [
        "| case | Δ true RMS (points, MuJoCo − PyBullet) | Δ true max (points) | within 2 points | verdicts agree |",
        "| --- | ---: | ---: | --- | --- |",
    ]
    for case, rms, max_, agree in differences(runs):
        within = "—" if rms is None else ("yes" if abs(rms) <= RMS_AGREEMENT_POINTS else "**no**")
        lines.append(
            f"| {case.name} | {_number(rms, digits=2)} | {_number(max_, digits=2)} | {within} | "
            f"{'yes' if agree else '**no**'} |"
        )
    return lines


def _worst_text(run: EngineRun) -> str:
    w = run.worst
    if w is None:
        return f"{run.engine.value}: no contact step"
    return (
        f"{run.engine.value} {w.error_n:+.2f} N at t = {w.t_s:.3f} s, where the true normal force changed by "
        f"{w.jump_n:+.2f} N in one step and its normal turned {w.turn_deg:.1f}°"
    )


def why_they_differ(runs: list[EngineRun]) -> list[str]:
    """A sentence per case whose true RMS or true max differ by more than :data:`RMS_AGREEMENT_POINTS` between the
    engines: where each engine's largest error was and what the contact did in that step (:class:`WorstStep`)."""
    by_case: dict[str, dict[Engine, EngineRun]] = {}
    for run in runs:
        by_case.setdefault(run.case.name, {})[run.engine] = run
    lines = []
    for case, rms, max_, _ in differences(runs):
        if rms is None or max_ is None or max(abs(rms), abs(max_)) <= RMS_AGREEMENT_POINTS:
            continue  # (an aborted run has no steady error: the verdicts' column says it)
        pair = by_case[case.name]
        lines.append(
            f"- **{case.name}**: the largest steady error differs by {max_:+.1f} points (RMS {rms:+.2f}): "
            f"{_worst_text(pair[Engine.mujoco])}; {_worst_text(pair[Engine.pybullet])}."
        )
    return lines
