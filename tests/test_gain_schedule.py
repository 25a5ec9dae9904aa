"""A gain schedule from the spread of several demonstrations (`skills.gain_schedule`, issue 42 item 4): the spread
kept per phase against a known one, the schedule stiffer where the trials agree, an execution with it on the scripted
teacher's trials against the true force, and a skill of one demonstration refused."""

from __future__ import annotations

import numpy as np
import pytest

from schemas.execution import ControllerGains, EnvironmentChange, ExecutionPhase, ExecutionSettings, GainSchedule
from schemas.skill import SegmentKind, Skill
from sim_worker.executor import execute_skill
from sim_worker.teacher import TeacherRecording, record_demonstration
from skills.control import HybridController
from skills.gain_schedule import STIFFNESS_FLOOR, missing_spread, motion_spread, stiffness_schedule
from skills.joint_learning import learn_joint_skill
from skills.parameterize import learn_skill

POINTS = 201
"""Phase points of the synthetic trials (the joint learner's alignment points are as many)."""
AGREE_M, VARY_M = 0.0005, 0.004
"""The known lateral spread of the synthetic trials over the first and the second half of their stroke, m."""


def _trials_with_a_known_spread(tilt: np.ndarray) -> list[np.ndarray]:
    """Five aligned straight strokes in the plane of CF ``tilt`` (3, 3), world from CF: along CF x, apart along CF y
    by offsets whose standard deviation (n - 1) is exactly `AGREE_M` over the first half and `VARY_M` over the
    second, and 3 mm apart along CF z (the force axis: no part of the motion spread)."""
    unit = np.array([-2.0, -1.0, 0.0, 1.0, 2.0]) / np.std([-2.0, -1.0, 0.0, 1.0, 2.0], ddof=1)
    phase = np.linspace(0.0, 1.0, POINTS)
    lateral = np.where(phase < 0.5, AGREE_M, VARY_M)
    trials = []
    for k, u in enumerate(unit):
        cf = np.column_stack([0.2 * phase, u * lateral, np.full(POINTS, 0.003 * (k - 2))])
        trials.append(np.array([0.5, 0.1, 0.3]) + cf @ tilt.T)
    return trials


def test_the_spread_is_the_trials_own_along_the_cf_motion_axes_and_the_schedule_is_stiffest_where_they_agree() -> None:
    c, s = np.cos(0.3), np.sin(0.3)
    tilt = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # a plane tilted 17° about world y
    spread = motion_spread(_trials_with_a_known_spread(tilt), tilt)
    sigma = np.asarray(spread.spread_m)
    assert spread.demonstrations == 5 and sigma.shape == (POINTS, 2)
    assert np.max(sigma[:, 0]) < 1e-9  # every trial at the same place along the path
    # Away from the step (the pooling blurs it over ~5 % of the segment), the spread is the known one.
    assert sigma[20:80, 1] == pytest.approx(AGREE_M, rel=1e-6)
    assert sigma[120:180, 1] == pytest.approx(VARY_M, rel=1e-6)

    configured = [3000.0, 2000.0, 1500.0]
    k = stiffness_schedule(spread, configured, np.array([0.25, 0.75]))
    assert k[:, 2] == pytest.approx([1500.0, 1500.0])  # CF z: the force axis keeps its stiffness
    assert k[0, 0] == pytest.approx(3000.0) and k[1, 0] == pytest.approx(3000.0)  # x: they agree everywhere
    # y where they agree: the variance with the resolution added, (0.5 mm)² + (0.5 mm)², twice the least (x's, the
    # resolution alone): half the configured stiffness.
    assert k[0, 1] == pytest.approx(0.5 * 2000.0, rel=1e-4)
    # Where they vary (8x the spread: 1/64 of the variance ratio, below the floor) y is as compliant as allowed.
    assert k[1, 1] == pytest.approx(STIFFNESS_FLOOR * 2000.0)


def test_a_control_frame_with_the_gains_stiffness_is_the_frame_without_one_bit_for_bit() -> None:
    controller = HybridController()
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    selection = [1.0, 1.0, 0.0, 1.0, 1.0, 1.0]
    plain = controller.frame(rotation, selection)
    given = controller.frame(rotation, selection, stiffness=[3000.0, 3000.0, 3000.0, 40.0, 40.0, 40.0])
    for name in ("omega", "task_gain", "law_rows", "stiffness", "damping"):
        assert np.array_equal(getattr(plain, name), getattr(given, name)), name
    softer = controller.frame(rotation, selection, stiffness=[750.0, 3000.0, 3000.0, 40.0, 40.0, 40.0])
    # CF x is world y here: a 1 mm error along it is held by 0.75 N, along world x (CF y) by 3 N.
    assert softer.omega[:2, :2] @ np.array([1e-3, 0.0]) == pytest.approx([3.0, 0.0])
    assert softer.omega[:2, :2] @ np.array([0.0, 1e-3]) == pytest.approx([0.0, 0.75])
    assert softer.damping[0] == pytest.approx(plain.damping[0] / 2.0)  # 2 ζ sqrt(k m): a quarter k, half d


@pytest.fixture(scope="module")
def trials() -> list[TeacherRecording]:
    """Three hands (seeds) of the scripted teacher's 2 s flat slide, in the same world."""
    return [record_demonstration("slide_flat", seed=seed, move_duration_s=2.0) for seed in (0, 1, 2)]


@pytest.fixture(scope="module")
def joint(trials: list[TeacherRecording]) -> Skill:
    return learn_joint_skill([r.demonstration for r in trials], sources=["0", "1", "2"])


def _settings(schedule: GainSchedule) -> ExecutionSettings:
    return ExecutionSettings(
        pace="fast",
        environment=EnvironmentChange(unknown_offset=[0.0, 0.0, 0.02]),
        gains=ControllerGains(gain_schedule=schedule),
    )


def test_an_execution_with_the_schedule_presses_the_true_force_within_tolerance(
    trials: list[TeacherRecording], joint: Skill
) -> None:
    contact = [s for s in joint.segments if s.kind is SegmentKind.contact]
    assert all(s.motion_spread is not None and s.motion_spread.demonstrations == 3 for s in contact)
    reference = trials[next(u.index for u in joint.demonstrations or [] if u.reference)]
    metrics = execute_skill(
        joint, reference.world_config, _settings(GainSchedule.from_spread), demonstration=reference.demonstration
    ).metrics
    assert metrics.abort_reason is None
    assert metrics.true_force_rms_error_pct is not None and metrics.true_force_rms_error_pct < 15.0
    assert metrics.path_rms_m is not None and metrics.path_rms_m < 0.005
    assert metrics.verdict is not None and metrics.verdict.verdict.value == "pass"


def test_a_skill_of_one_demonstration_with_the_schedule_is_refused_naming_the_field(
    trials: list[TeacherRecording],
) -> None:
    single = learn_skill(trials[0].demonstration)
    reason = missing_spread(single)
    assert reason is not None and reason.startswith("gains.gain_schedule:")
    # Run anyway (a worker refuses it before, `tests/test_bus.py`): it fails naming the field, never runs constant.
    metrics = execute_skill(single, trials[0].world_config, _settings(GainSchedule.from_spread)).metrics
    assert metrics.phase is ExecutionPhase.failed
    assert metrics.abort_reason is not None and "gains.gain_schedule: from_spread" in metrics.abort_reason
