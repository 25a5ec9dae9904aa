"""A skill taught in PyBullet, executed on MuJoCo through the product's path (``sim_worker.executor.run_skill`` with
``engine = mujoco``): the same phases, controller and telemetry, judged by MuJoCo's own contact against the teacher's
ground truth (no mocked physics)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from schemas.execution import PHASE_CODES, Engine, ExecutionPhase, ExecutionSettings
from schemas.skill import LearnOptions, Skill
from sim_worker.execution_world import execution_world
from sim_worker.executor import ExecutionResult, run_skill
from sim_worker.teacher import TeacherRecording, record_demonstration
from skills.parameterize import learn_skill

FORCE_TOLERANCE_N = 0.75
"""The steady true normal force's median and RMS error from the force the teacher pressed with stay within this, N
(5 % of 15 N; measured on MuJoCo with the default wrist sensor: RMS 0.23 N, the largest error 1.0 N)."""
NORMAL_TOLERANCE_DEG = 1.0
"""The true normal the tool pressed along is the table's, within this, degrees."""
STEADY_AFTER_S = 0.25
"""The steady contact starts this long after the first contact step, s (as the metrics' steady window)."""


@pytest.fixture(scope="module")
def taught_slide() -> tuple[TeacherRecording, Skill]:
    recording = record_demonstration("slide_flat", seed=0)
    return recording, learn_skill(recording.demonstration, LearnOptions(skill_type="slide"))


def run_on_mujoco(taught: tuple[TeacherRecording, Skill], environment: dict[str, Any]) -> ExecutionResult:
    """The taught slide executed on MuJoCo (pace fast) in its taught world changed by ``environment``."""
    recording, skill = taught
    settings = ExecutionSettings(engine=Engine.mujoco, pace="fast", environment=environment)
    return run_skill(execution_world(skill, settings.environment, demonstration=recording.demonstration), settings)


@pytest.fixture(scope="module")
def slide_on_mujoco(taught_slide) -> tuple[TeacherRecording, ExecutionResult]:
    return taught_slide[0], run_on_mujoco(taught_slide, {})


def test_a_slide_on_mujoco_presses_the_taught_force_along_the_true_normal(slide_on_mujoco) -> None:
    recording, result = slide_on_mujoco
    metrics, tel = result.metrics, result.telemetry
    assert metrics.phase is ExecutionPhase.done, metrics.abort_reason
    assert metrics.engine is Engine.mujoco
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    steady = contact & (tel.t > tel.t[contact][0] + STEADY_AFTER_S)
    assert steady.sum() > 1000  # seconds of steady sliding were judged
    force = tel.normal_force_true[steady]  # MuJoCo's contact forces along their normals
    error = force - recording.target_force_n
    assert abs(float(np.median(error))) < FORCE_TOLERANCE_N, np.median(error)
    assert float(np.sqrt(np.mean(error**2))) < FORCE_TOLERANCE_N
    assert tel.in_contact[contact].all()  # MuJoCo's contact never lost in the contact phase
    table_normal = np.array([0.0, 0.0, -1.0])  # into the table
    angles = np.degrees(np.arccos(np.clip(tel.contact_normal[steady] @ table_normal, -1.0, 1.0)))
    assert angles.max() < NORMAL_TOLERANCE_DEG, angles.max()
    assert metrics.verdict is not None and not metrics.verdict.reasons, metrics.verdict.reasons


def test_a_slide_at_friction_0_6_on_mujoco_slides_on_the_table_and_passes(taught_slide) -> None:
    """The same slide on a table of μ 0.6 (three times the taught 0.2, not told to the controller): MuJoCo's friction
    slides at μ N without chattering, the tool never leaves the table and the verdict passes with PyBullet's true
    RMS within 2 points (measured: MuJoCo 2.10 %, PyBullet 2.24 %; with ``impratio`` 100, the stick MuJoCo used to
    match, 16.7 %: the normal force chattered and the ball left the table, docs/ENGINES.md)."""
    result = run_on_mujoco(taught_slide, {"friction": 0.6})
    metrics, tel = result.metrics, result.telemetry
    assert metrics.phase is ExecutionPhase.done, metrics.abort_reason
    assert tel.in_contact[tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]].all()
    assert metrics.true_force_rms_error_pct is not None and metrics.true_force_rms_error_pct < 4.0
    assert metrics.verdict is not None and not metrics.verdict.reasons, metrics.verdict.reasons


def test_a_press_faded_at_a_contour_s_end_lifts_off_and_is_not_a_lost_contact() -> None:
    """The verdict-truth perturbation "radius 6 cm" (the teacher's contour, taught on a larger cylinder, run on one of
    6 cm radius without telling the controller): at the contour's end its force ramps down while the taught path runs
    past the smaller surface, and MuJoCo's contact opens on the contact phase's last rows with the press faded to
    0.66 N (PyBullet's 3 ms later). Leaving the surface there is lifting off, not losing it: the run ends done on both
    engines (it was aborted "contact lost" on MuJoCo only, and its verdict disagreed with PyBullet's), and the judge,
    which knows the world, finds the job done on both."""
    from experiments.verdict_truth import PERTURBATIONS, run_judged, taught

    perturbation = next(p for p in PERTURBATIONS if p.name == "radius 6 cm")
    teachings = {perturbation.scenario: taught(perturbation.scenario)}
    runs = {engine: run_judged(perturbation, None, teachings, engine) for engine in Engine}
    for engine, run in runs.items():
        assert run.metrics.phase is ExecutionPhase.done, (engine, run.metrics.abort_reason)
        assert run.job_done, (engine, run.faults)
    assert runs[Engine.pybullet].verdict_passed == runs[Engine.mujoco].verdict_passed
