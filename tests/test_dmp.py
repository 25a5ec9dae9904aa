"""Tests of skills/dmp.py: reproduction accuracy, generalization, guards, wire round trip, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from corpus.synthetic import minimum_jerk, reach_pose_trajectory
from schemas.skill import DMPParameters
from skills.dmp import AMPLITUDE_SCALING_MIN_FRACTION, DMP
from skills.quaternion_dmp import QuaternionDMP
from skills.quaternions import (
    quaternion_angle_between,
    quaternion_exp,
    quaternion_product,
    quaternions_slerp,
)

N_SAMPLES = 2000
DURATION_S = 4.0


def _pose_trajectory() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reach of :func:`corpus.synthetic.reach_pose_trajectory` at this module's size."""
    return reach_pose_trajectory(N_SAMPLES, DURATION_S)


@pytest.fixture(scope="module")
def demo() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return _pose_trajectory()


@pytest.fixture(scope="module")
def position_dmp(demo) -> DMP:
    t, position, _ = demo
    return DMP.fit(t, position, n_basis=50)


@pytest.fixture(scope="module")
def orientation_dmp(demo) -> QuaternionDMP:
    t, _, q = demo
    return QuaternionDMP.fit(t, q, n_basis=50)


def _rms_distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


def _rms_angle_deg(p: np.ndarray, q: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(quaternion_angle_between(p, q) ** 2))))


# --------------------------------------------------------------------------- reproduction


def test_position_reproduction_under_0_3_mm(demo, position_dmp):
    t, position, _ = demo
    rollout = position_dmp.rollout(t[1] - t[0])
    assert rollout.y.shape == position.shape
    np.testing.assert_allclose(rollout.t, t - t[0], atol=1e-12)
    assert _rms_distance(rollout.y, position) < 0.3e-3
    np.testing.assert_array_equal(rollout.yd[0], 0.0)  # starts at rest


def test_orientation_reproduction_under_0_03_deg(demo, orientation_dmp):
    t, _, q = demo
    assert np.degrees(quaternion_angle_between(q, q[0]).max()) > 30.0  # the demo really rotates
    rollout = orientation_dmp.rollout(t[1] - t[0])
    assert rollout.q.shape == q.shape
    assert rollout.omega.shape == (N_SAMPLES, 3)
    assert _rms_angle_deg(rollout.q, q) < 0.03


def test_orientation_rollout_unit_norm_and_world_angular_velocity(orientation_dmp):
    dt = 0.001
    rollout = orientation_dmp.rollout(dt)
    np.testing.assert_allclose(np.linalg.norm(rollout.q, axis=1), 1.0, atol=1e-12)
    # q_{k+1} = exp(dt/2 omega_{k+1}) * q_k: omega is the world-frame angular velocity in rad/s.
    predicted = quaternion_product(quaternion_exp(0.5 * dt * rollout.omega[1:]), rollout.q[:-1])
    np.testing.assert_allclose(predicted, rollout.q[1:], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rollout.omega[0], 0.0)


def test_rollout_at_another_dt_agrees_to_order_dt(demo, position_dmp, orientation_dmp):
    t, position, q = demo
    errors = []
    for dt in (0.001, 0.01):
        rollout = position_dmp.rollout(dt)
        reference = np.stack([np.interp(rollout.t, t, position[:, i]) for i in range(3)], axis=1)
        errors.append(_rms_distance(rollout.y, reference))
        q_rollout = orientation_dmp.rollout(dt)
        assert _rms_angle_deg(q_rollout.q, quaternions_slerp(q_rollout.t, t, q)) < 0.2
    assert errors[0] < 0.1e-3
    assert errors[1] < 0.5e-3
    assert errors[1] > errors[0]  # first order: a coarser step is worse


# --------------------------------------------------------------------------- generalization


def test_position_new_start_and_goal(demo, position_dmp):
    t, position, _ = demo
    start = position[0] + [-0.03, 0.02, 0.01]
    goal = position[-1] + [0.05, -0.05, 0.05]
    rollout = position_dmp.rollout(t[1] - t[0], start=start, goal=goal)
    np.testing.assert_array_equal(rollout.y[0], start)
    assert np.abs(rollout.y[-1] - goal).max() < 1e-5
    # Scaled dimensions are the demonstration stretched by s about the start, exactly (linear system).
    scaled = position_dmp.amplitude_scaling
    assert scaled.tolist() == [True, True, False]  # z only bumps: start == goal
    s = (goal - start)[scaled] / (position[-1] - position[0])[scaled]
    reproduction = position_dmp.rollout(t[1] - t[0]).y
    expected_from_rollout = start[scaled] + s * (reproduction[:, scaled] - position[0, scaled])
    np.testing.assert_allclose(rollout.y[:, scaled], expected_from_rollout, rtol=0, atol=1e-9)
    expected = start[scaled] + s * (position[:, scaled] - position[0, scaled])
    assert _rms_distance(rollout.y[:, scaled], expected) < 0.5e-3


def test_position_new_duration(demo, position_dmp):
    _, position, _ = demo
    reproduction = position_dmp.rollout(0.002)
    # Twice the duration at twice the step (same dt / tau): exactly the same samples, half the speed.
    slow = position_dmp.rollout(0.004, duration_s=8.0)
    assert slow.t[-1] == pytest.approx(8.0)
    np.testing.assert_allclose(slow.y, reproduction.y, rtol=0, atol=1e-12)
    np.testing.assert_allclose(slow.yd, 0.5 * reproduction.yd, rtol=0, atol=1e-9)
    # Twice the duration at the demonstration's step: the same path to O(dt).
    fine = position_dmp.rollout(0.002, duration_s=8.0)
    assert fine.t[-1] == pytest.approx(8.0)
    assert _rms_distance(fine.y[::2], reproduction.y) < 0.1e-3
    assert np.abs(fine.y[-1] - position[-1]).max() < 0.1e-3


def test_orientation_new_start_and_goal(demo, orientation_dmp):
    t, _, q = demo
    start = (Rotation.from_rotvec([-0.2, 0.1, 0.2]) * Rotation.from_quat(q[0])).as_quat()
    goal = (Rotation.from_rotvec([0.3, -0.2, 0.4]) * Rotation.from_quat(q[-1])).as_quat()
    rollout = orientation_dmp.rollout(t[1] - t[0], start=start, goal=goal)
    assert quaternion_angle_between(rollout.q[0], start) < 1e-12
    assert np.degrees(quaternion_angle_between(rollout.q[-1], goal)) < 0.05
    np.testing.assert_allclose(np.linalg.norm(rollout.q, axis=1), 1.0, atol=1e-12)


def test_quaternion_sign_flips_give_identical_result(demo, orientation_dmp):
    t, _, q = demo
    flipped = q.copy()
    rng = np.random.default_rng(0)
    flip = rng.permutation(N_SAMPLES)[: N_SAMPLES // 2]
    flipped[flip] *= -1.0
    assert flip.size == N_SAMPLES // 2
    dmp = QuaternionDMP.fit(t, flipped, n_basis=50)
    np.testing.assert_allclose(dmp.dynamics.weights, orientation_dmp.dynamics.weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dmp.start, orientation_dmp.start, rtol=0, atol=1e-15)
    np.testing.assert_allclose(dmp.goal, orientation_dmp.goal, rtol=0, atol=1e-15)
    dt = t[1] - t[0]
    np.testing.assert_allclose(dmp.rollout(dt).q, orientation_dmp.rollout(dt).q, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- start == goal guard


def test_closed_loop_start_equals_goal_is_reproduced_and_goal_change_does_not_blow_up():
    t = np.linspace(0.0, DURATION_S, N_SAMPLES)
    phase = 2 * np.pi * minimum_jerk(t / DURATION_S)
    # A circle of radius 0.1 m that returns to its start; z drifts by only 1 µm (0.001 % of the motion).
    loop = np.stack([0.1 * np.sin(phase), 0.1 * (1 - np.cos(phase)), 1e-6 * phase / (2 * np.pi)], axis=1)
    loop += [0.5, 0.0, 0.2]
    dmp = DMP.fit(t, loop)
    assert dmp.amplitude_scaling.tolist() == [False, False, False]
    dt = t[1] - t[0]
    assert _rms_distance(dmp.rollout(dt).y, loop) < 0.3e-3

    shift = np.array([0.05, 0.05, 0.05])
    moved = dmp.rollout(dt, goal=loop[-1] + shift)
    assert np.all(np.isfinite(moved.y))
    # Unscaled: the loop keeps its shape and size; the trajectory departs from it by at most the goal shift.
    assert np.abs(moved.y - loop).max() <= shift.max() + 1e-6
    assert np.abs(moved.y[-1] - (loop[-1] + shift)).max() < 1e-5
    # The classic (g - y0) scaling would have multiplied the z forcing term by 0.05 / 1e-6 = 50 000.
    assert abs(shift[2] / (loop[-1, 2] - loop[0, 2])) > 1e4


def test_amplitude_scaling_threshold_is_relative_to_the_largest_motion():
    t = np.linspace(0.0, 2.0, 500)
    mj = minimum_jerk(t / 2.0)
    noise = 1e-3 * np.sin(7 * np.pi * t / 2.0) ** 2  # 1 mm of jitter that nets 0.5 mm
    y = np.stack([0.2 * mj, noise + 0.5e-3 * mj, 0.05 * mj], axis=1)
    dmp = DMP.fit(t, y)
    # x moves 20 cm, z moves 5 cm (25 %): scaled; y's 0.5 mm net is below 10 % of 20 cm: not scaled.
    assert AMPLITUDE_SCALING_MIN_FRACTION == 0.1
    assert dmp.amplitude_scaling.tolist() == [True, False, True]
    np.testing.assert_allclose(dmp.amplitude_factors(y[0], y[-1] + [0.2, 0.1, 0.05]), [2.0, 1.0, 2.0])


# --------------------------------------------------------------------------- force DMP, rollout, round trips


def test_force_dmp_round_trip():
    t = np.linspace(0.0, 3.0, 1500)
    s = t / 3.0
    force = 15.0 + 5.0 * minimum_jerk(s) + 2.0 * np.sin(6 * np.pi * s) * np.sin(np.pi * s) ** 2  # N
    dmp = DMP.fit(t, force, kind="force", frame="cf")
    assert dmp.n_dims == 1
    rollout = dmp.rollout(t[1] - t[0])
    assert np.sqrt(np.mean((rollout.y[:, 0] - force) ** 2)) < 0.01  # N
    params = dmp.to_parameters()
    assert params.kind == "force"
    assert params.frame == "cf"
    assert params.amplitude_scaling == [True]
    again = DMP.from_parameters(DMPParameters.model_validate_json(params.model_dump_json()))
    np.testing.assert_array_equal(again.rollout(0.001).y, dmp.rollout(0.001).y)
    assert np.abs(again.rollout(0.001, goal=[25.0]).y[-1, 0] - 25.0) < 1e-3


@pytest.mark.parametrize(
    ("dt", "kwargs"),
    [
        (0.002, {}),
        (0.0037, {"start": [0.3, 0.0, 0.25], "goal": [0.8, 0.2, 0.35], "duration_s": 5.0}),
        (0.0001, {}),
    ],
)
def test_lfilter_rollout_equals_loop_rollout(position_dmp, dt, kwargs):
    fast = position_dmp.rollout(dt, **kwargs)
    loop = position_dmp.rollout_loop(dt, **kwargs)
    np.testing.assert_array_equal(fast.t, loop.t)
    np.testing.assert_allclose(fast.y, loop.y, rtol=0, atol=1e-8)  # m, 40 000 steps at dt = 0.1 ms
    np.testing.assert_allclose(fast.yd, loop.yd, rtol=0, atol=1e-5)  # m/s


def test_a_rollout_too_long_to_keep_its_basis_builds_none_and_agrees_to_round_off(
    position_dmp, orientation_dmp, monkeypatch
):
    """A long segment's forcing term is evaluated block by block, its design matrix never built whole nor kept (a
    worker's memory: a minute at 1 kHz with 300 bases would be 134 MB): the rollouts are those of the kept matrix to
    round-off, and the same to the bit when rolled out again (which way depends on the size alone)."""
    import skills.dmp as dmp

    dt, duration = 0.001, 9.0  # 9000 steps x 50 bases: 3.6 MB, kept at the default size
    kept = (position_dmp.rollout(dt, duration_s=duration), orientation_dmp.rollout(dt, duration_s=duration))
    assert any(f.shape == (9000, 50) for f in dmp._features_cache.values())
    dmp._features_cache.clear()
    monkeypatch.setattr(dmp, "ROLLOUT_FEATURES_CACHE_BYTES", 8 * 1024 * 1024 // 8)  # 128 kB: 3.6 MB is too large
    blocks = (position_dmp.rollout(dt, duration_s=duration), orientation_dmp.rollout(dt, duration_s=duration))
    assert not dmp._features_cache
    np.testing.assert_allclose(blocks[0].y, kept[0].y, rtol=0, atol=1e-12)  # m
    np.testing.assert_allclose(blocks[1].q, kept[1].q, rtol=0, atol=1e-12)
    again = position_dmp.rollout(dt, duration_s=duration)
    np.testing.assert_array_equal(again.y, blocks[0].y)


def test_the_rollout_filter_is_scipys_lfilter_to_the_bit():
    """The position rollout's filter (compiled here, so a worker need not import ``scipy.signal``) gives exactly what
    ``scipy.signal.lfilter`` gives, for the DMP's coefficients over steps, durations and scales."""
    from scipy.signal import lfilter

    from skills.dmp import _second_order_filter

    rng = np.random.default_rng(3)
    for _ in range(40):
        a, az = rng.uniform(1e-4, 1e-2) / rng.uniform(0.5, 60.0), 25.0
        den = [1.0, -(2.0 - a * az - a * a * az * az / 4), 1.0 - a * az]
        v = rng.normal(size=(int(rng.integers(2, 5000)), int(rng.integers(1, 4)))) * rng.uniform(0.1, 1e3)
        np.testing.assert_array_equal(_second_order_filter(a * a, den[1], den[2], v),
                                      lfilter([0.0, a * a], den, v, axis=0))  # fmt: skip


def test_parameters_json_round_trip_is_lossless(demo, position_dmp, orientation_dmp):
    dt = demo[0][1] - demo[0][0]
    params = position_dmp.to_parameters()
    assert params.kind == "position"
    assert len(params.weights) == 50
    assert len(params.weights[0]) == 3
    again = DMP.from_parameters(DMPParameters.model_validate_json(params.model_dump_json()))
    for name in ("weights", "centers", "widths"):
        np.testing.assert_array_equal(getattr(again.dynamics, name), getattr(position_dmp.dynamics, name))
    for name in ("start", "goal", "amplitude_scaling"):
        np.testing.assert_array_equal(getattr(again, name), getattr(position_dmp, name))
    np.testing.assert_array_equal(again.rollout(dt).y, position_dmp.rollout(dt).y)

    q_params = orientation_dmp.to_parameters()
    assert q_params.kind == "quaternion"
    assert q_params.amplitude_scaling == [False, False, False]
    q_again = QuaternionDMP.from_parameters(DMPParameters.model_validate_json(q_params.model_dump_json()))
    np.testing.assert_array_equal(q_again.dynamics.weights, orientation_dmp.dynamics.weights)
    np.testing.assert_array_equal(q_again.rollout(dt).q, orientation_dmp.rollout(dt).q)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("t", "y", "message"),
    [
        (np.array([0.0, 1.0]), np.zeros((2, 3)), "too few samples"),
        (np.linspace(0, 1, 10), np.zeros((11, 3)), "mismatched"),
        (np.linspace(0, 1, 10), np.zeros((10, 3, 1)), r"shape \(N, D\)"),
        (np.linspace(0, 1, 10)[::-1], np.zeros((10, 3)), "strictly increasing"),
        (np.array([0.0, 0.1, 0.2, 0.5, 0.6]), np.zeros((5, 3)), "uniformly"),
        (np.linspace(0, 1, 10), np.full((10, 3), np.nan), "NaN"),
        (np.array([0.0, np.inf, 1.0]), np.zeros((3, 1)), "NaN or inf"),
    ],
)
def test_bad_position_input_raises(t, y, message):
    with pytest.raises(ValueError, match=message):
        DMP.fit(t, y)


def test_bad_quaternion_and_parameter_input_raises(demo, position_dmp, orientation_dmp):
    t, _, q = demo
    with pytest.raises(ValueError, match="unit quaternions"):
        QuaternionDMP.fit(t, 2.0 * q)
    with pytest.raises(ValueError, match=r"shape \(N, 4\)"):
        QuaternionDMP.fit(t, q[:, :3])
    with pytest.raises(ValueError, match="mismatched"):
        QuaternionDMP.fit(t[:-1], q)
    with pytest.raises(ValueError, match="n_basis"):
        DMP.fit(t, q[:, :3], n_basis=1)
    with pytest.raises(ValueError, match="QuaternionDMP"):
        DMP.from_parameters(orientation_dmp.to_parameters())
    with pytest.raises(ValueError, match="kind 'quaternion'"):
        QuaternionDMP.from_parameters(position_dmp.to_parameters())
    broken = position_dmp.to_parameters().model_copy(update={"start": [0.0, 0.0]})
    with pytest.raises(ValueError, match="start must have shape"):
        DMP.from_parameters(broken)
    with pytest.raises(ValueError, match="goal must have shape"):
        position_dmp.rollout(0.01, goal=[1.0, 2.0])
    with pytest.raises(ValueError, match="dt must be"):
        position_dmp.rollout(0.0)
    with pytest.raises(ValueError, match="unit quaternions"):
        orientation_dmp.rollout(0.01, goal=[0.0, 0.0, 0.0, 2.0])
