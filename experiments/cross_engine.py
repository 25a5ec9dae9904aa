"""The scripted teacher's slides and contours, taught in PyBullet, executed on both engines (issue 44): the same skill,
settings and controller (``hybrid_cf``) on PyBullet and on MuJoCo (``ExecutionSettings.engine``), judged each by its
own engine's contact (the true normal force, the contact, the touch-down; ``execution.metrics``).

A case is a teacher scenario (seed 0, the skill type it teaches) and an environment change: as taught, the work piece
moved WITHOUT telling the controller (``unknown_offset``), or moved with the skill (``offset``, the paper's contour
trials). Beside them: the robustness perturbations of ``experiments/verdict_truth.py`` (moved, tilted, resized,
swapped and missing parts, stiff and soft pads, friction, sensor faults) on both engines, each run's verdict and the
judge's finding (``judge_run``) per engine (:class:`VerdictPair`); and the KU Leuven recordings' skills on their
rebuilt work piece and on the object's CAD (:class:`KuleuvenCase`). ``benchmarks/bench_engines.py`` prints the tables
and writes them into docs/RESULTS.md (section :data:`CROSS_ENGINE_SECTION`; the demo keeps it).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from execution.telemetry import Telemetry
from experiments.kuleuven_cad import cad_world
from experiments.verdict_truth import Judgement, Perturbation, Taught, run_judged
from schemas.execution import PHASE_CODES, Engine, ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.skill import LearnOptions, Skill
from schemas.verdict import Verdict
from services.kuleuven_object import KuleuvenGroundTruth, kuleuven_ground_truth
from sim_worker.execution_world import ExecutionWorld, execution_world
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


class KuleuvenWorkPiece(StrEnum):
    """Where a KU Leuven skill runs: the work piece rebuilt from its own demonstration, or the object's CAD placed as
    the rebuilt one is (``experiments/kuleuven_cad.py``)."""

    rebuilt = "rebuilt"
    cad = "CAD"


@dataclass(frozen=True)
class KuleuvenCase:
    """One execution of a KU Leuven recording's skill (learned ``auto``, placed in reach as every real recording is):
    its name, the recording (a ``contour_*.csv``), the work piece, the environment change."""

    name: str
    recording: Path
    work_piece: KuleuvenWorkPiece
    environment: Mapping[str, Any] = field(default_factory=dict)


KULEUVEN_UNKNOWN_OFFSET_M = (0.0, 0.0, 0.02)
"""The KU Leuven rows' unknown shift of the rebuilt work piece, m (as ``benchmarks/bench_real_skills.py``'s)."""


def kuleuven_cases(recordings: Iterable[Path]) -> list[KuleuvenCase]:
    """Per recording: its skill on the rebuilt work piece as placed, 2 cm higher without telling the controller, and
    on the object's CAD."""
    cases = []
    for path in recordings:
        cases += [
            KuleuvenCase(f"KU {path.stem}, rebuilt, as placed", path, KuleuvenWorkPiece.rebuilt),
            KuleuvenCase(
                f"KU {path.stem}, rebuilt 2 cm higher (unknown)",
                path,
                KuleuvenWorkPiece.rebuilt,
                {"unknown_offset": list(KULEUVEN_UNKNOWN_OFFSET_M)},
            ),
            KuleuvenCase(f"KU {path.stem}, CAD, as placed", path, KuleuvenWorkPiece.cad),
        ]
    return cases


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

    case: EngineCase | KuleuvenCase
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


def _engine_run(case: EngineCase | KuleuvenCase, world: ExecutionWorld, settings: ExecutionSettings) -> EngineRun:
    result = run_skill(world, settings)
    return EngineRun(case, settings.engine, result.metrics, worst_step(result.telemetry))


def run_case(case: EngineCase, engine: Engine, skills: Mapping[str, tuple[TeacherRecording, Skill]]) -> EngineRun:
    """Execute ``case``'s skill on ``engine`` in its taught world changed as the case says (pace fast)."""
    recording, skill = skills[case.scenario]
    settings = ExecutionSettings(engine=engine, environment=dict(case.environment), pace="fast")
    world = execution_world(skill, settings.environment, demonstration=recording.demonstration)
    return _engine_run(case, world, settings)


def kuleuven_skills(cases: Iterable[KuleuvenCase]) -> dict[Path, tuple[KuleuvenGroundTruth, Skill]]:
    """The ground truth (the import, the registered CAD) of every recording ``cases`` run, and the skill learned from
    it (``auto``, as ``benchmarks/bench_real_skills.py`` learns it)."""
    truths = {path: kuleuven_ground_truth(path) for path in dict.fromkeys(case.recording for case in cases)}
    return {path: (truth, learn_skill(truth.demonstration)) for path, truth in truths.items()}


def run_kuleuven_case(
    case: KuleuvenCase, engine: Engine, skills: Mapping[Path, tuple[KuleuvenGroundTruth, Skill]]
) -> EngineRun:
    """Execute ``case``'s skill on ``engine`` (``hybrid_cf``, the wrist sensor, pace fast): placed on the work piece
    rebuilt from its demonstration, or on the CAD placed as the rebuilt one (the placement does not depend on the
    engine, so both engines run the same world)."""
    truth, skill = skills[case.recording]
    settings = ExecutionSettings(engine=engine, environment=dict(case.environment), pace="fast")
    world = execution_world(skill, settings.environment)
    if case.work_piece is KuleuvenWorkPiece.cad:
        assert world.placement is not None  # a real recording carries no world: it is always placed
        world = execution_world(world.skill, settings.environment, world=cad_world(truth, world.placement))
    return _engine_run(case, world, settings)


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


def differences(runs: list[EngineRun]) -> list[tuple[EngineCase | KuleuvenCase, float | None, float | None, bool]]:
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


@dataclass(frozen=True)
class VerdictPair:
    """One robustness perturbation (``experiments/verdict_truth.py``) run on both engines with the product's default
    following (``follow_surface_normal`` unset: slides follow, contours keep the taught frames), each judged."""

    perturbation: Perturbation
    runs: Mapping[Engine, Judgement]

    @property
    def verdicts_agree(self) -> bool:
        return self.runs[Engine.pybullet].verdict_passed == self.runs[Engine.mujoco].verdict_passed

    @property
    def judges_agree(self) -> bool:
        return self.runs[Engine.pybullet].job_done == self.runs[Engine.mujoco].job_done


def verdict_pairs(perturbations: Iterable[Perturbation], teachings: Mapping[str, Taught]) -> list[VerdictPair]:
    """Every perturbation on PyBullet and on MuJoCo (``verdict_truth.run_judged``, following as the product's
    default), in order."""
    pairs = []
    for perturbation in perturbations:
        runs = {engine: run_judged(perturbation, None, teachings, engine) for engine in Engine}
        for engine, j in runs.items():
            print(f"{perturbation.scenario}, {perturbation.name} on {engine.value}: {_verdict_cell(j)}")
        pairs.append(VerdictPair(perturbation, runs))
    return pairs


def _verdict_cell(j: Judgement) -> str:
    """The true RMS (or how the run ended) and the verdict with its failed checks."""
    m = j.metrics
    rms = f"{m.true_force_rms_error_pct:.2f} %" if m.true_force_rms_error_pct is not None else m.phase.value
    if j.verdict_passed:
        return f"{rms}, pass"
    return f"{rms}, **fail** ({', '.join(sorted(c.value for c in j.failed_checks))})"


def _judge_cell(j: Judgement) -> str:
    return "done" if j.job_done else "not done: " + "; ".join(j.faults.values())


def _check_difference(pair: VerdictPair) -> str:
    """The checks that failed on one engine only, each with both engines' measured values against its limit."""
    checks = {
        e: {c.name: c for c in j.metrics.verdict.checks} if j.metrics.verdict else {} for e, j in pair.runs.items()
    }
    failed = {e: j.failed_checks for e, j in pair.runs.items()}
    names = sorted(failed[Engine.pybullet] ^ failed[Engine.mujoco])
    if not names:
        return "—"
    texts = []
    for name in names:
        values = []
        for engine in Engine:
            check = checks[engine].get(name)
            value = "—" if check is None or check.value is None else f"{check.value:.3g}"
            values.append(f"{engine.value} {value}")
        limit = next((c.limit for e in Engine if (c := checks[e].get(name)) is not None and c.limit is not None), None)
        texts.append(f"{name.value}: {', '.join(values)}" + ("" if limit is None else f" (limit {limit:.3g})"))
    return "; ".join(texts)


def verdict_pair_table(pairs: list[VerdictPair]) -> list[str]:
    """The markdown table: per perturbation both engines' verdicts, whether they agree, the judge on each, and the
    checks that failed on one engine only with their measured values."""
    lines = [
        "| skill | perturbation | PyBullet: true RMS, verdict | MuJoCo: true RMS, verdict | verdicts agree | "
        "judge, PyBullet | judge, MuJoCo | checks failed on one engine only (value per engine) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for pair in pairs:
        p, bullet, mujoco = pair.perturbation, pair.runs[Engine.pybullet], pair.runs[Engine.mujoco]
        lines.append(
            f"| {p.scenario} | {p.name} | {_verdict_cell(bullet)} | {_verdict_cell(mujoco)} | "
            f"{'yes' if pair.verdicts_agree else '**no**'} | {_judge_cell(bullet)} | {_judge_cell(mujoco)} | "
            f"{_check_difference(pair)} |"
        )
    return lines


def verdict_pair_counts(pairs: list[VerdictPair]) -> list[str]:
    """The counts: verdicts agreeing between the engines, the judge agreeing, and each engine's verdict against its
    own judge (a false pass: the verdict passed a job the judge found not done; a false fail: the converse)."""
    m = len(pairs)
    lines = [
        f"Verdicts agree between the engines on {sum(p.verdicts_agree for p in pairs)} of {m} perturbations; the "
        f"judge's finding (job done or not) agrees on {sum(p.judges_agree for p in pairs)} of {m}.",
        "",
        "| engine | verdict passed | job done (judge) | false pass | false fail |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for engine in Engine:
        runs = [p.runs[engine] for p in pairs]
        lines.append(
            f"| {engine.value} | {sum(j.verdict_passed for j in runs)} | {sum(j.job_done for j in runs)} | "
            f"{sum(j.verdict_passed and not j.job_done for j in runs)} | "
            f"{sum(not j.verdict_passed and j.job_done for j in runs)} |"
        )
    return lines
