"""A skill learned from several demonstrations executed in PyBullet (real physics at 1 kHz): its force band goes into
the execution's metrics and verdict (`execution.metrics`), judged on the simulator's TRUE normal force."""

from __future__ import annotations

import numpy as np
import pytest

from schemas.execution import ExecutionSettings
from schemas.skill import SegmentKind
from schemas.verdict import ExecutionTolerances, Verdict, VerdictCheckName
from sim_worker.executor import execute_skill
from sim_worker.teacher import TeacherRecording, record_demonstration
from skills.joint_learning import learn_joint_skill
from skills.placement import placed_skill

SHORT = {"move_duration_s": 2.0}
"""A slide whose stroke lasts 2 s: an execution of about 6 s simulated."""


@pytest.fixture(scope="module")
def taught() -> tuple[list[TeacherRecording], object]:
    """Two demonstrations of the flat slide (two hands: seeds 0 and 1) and the skill learned from both."""
    recordings = [record_demonstration("slide_flat", seed=seed, **SHORT) for seed in (0, 1)]
    return recordings, learn_joint_skill([r.demonstration for r in recordings])


def _force_in_band(metrics):
    return next(check for check in metrics.verdict.checks if check.name is VerdictCheckName.force_in_band)


def test_an_execution_presses_within_the_demonstrated_band_and_the_verdict_says_so(taught):
    recordings, skill = taught
    world = recordings[0].world_config
    run = execute_skill(skill, world, ExecutionSettings(pace="fast"), demonstration=recordings[0].demonstration)
    assert run.metrics.true_force_in_band is not None and run.metrics.true_force_in_band >= 0.9
    check = _force_in_band(run.metrics)
    assert check.passed and check.warning_only  # reported; judged only when asked

    # The skill edited to press twice as hard as taught (its band as demonstrated): the true force leaves the band,
    # and a verdict asked to judge the band fails on it.
    harder = skill.model_copy(
        update={
            "segments": [
                s.model_copy(update={"force_constant_n": 2 * s.force_constant_n}) if s.force_constant_n else s
                for s in skill.segments
            ]
        }
    )
    judged = ExecutionSettings(
        pace="fast",
        tolerances=ExecutionTolerances(force_in_band=0.9, true_force_rms_pct=1000.0, true_force_max_pct=1000.0),
    )
    pressed = execute_skill(harder, world, judged, demonstration=recordings[0].demonstration)
    assert pressed.metrics.true_force_in_band is not None and pressed.metrics.true_force_in_band < 0.5
    check = _force_in_band(pressed.metrics)
    assert not check.passed and not check.warning_only and pressed.metrics.verdict.verdict is Verdict.failed


def test_a_placement_moves_the_band_with_the_skill(taught):
    _, skill = taught
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = placed_skill(skill, turn, [0.1, 0.0, 0.05])
    for before, after in zip(skill.segments, moved.segments, strict=True):
        if before.kind is SegmentKind.contact:
            assert before.force_band is not None and after.force_band is not None
            expected = np.asarray(before.force_band.positions) @ turn.T + [0.1, 0.0, 0.05]
            np.testing.assert_allclose(after.force_band.positions, expected, atol=1e-12)
            assert after.force_band.mean_n == before.force_band.mean_n
