"""The PyBullet world (real PyBullet DIRECT): torque control, contact wrench sign and size, kinematics, geometry."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pybullet
import pytest

from schemas.world import (
    IIWA_TORQUE_LIMITS_NM,
    BlockConfig,
    CylinderConfig,
    RampConfig,
    SensorConfig,
    SensorModel,
    TableConfig,
    WorkPiece,
    WorldConfig,
)
from sim_worker.geometry import WorldGeometry
from sim_worker.robot_model import Q_HOME, TOOL_LINK
from sim_worker.world import SimWorld
from skills.frames import matrix_from_axis_angle, rotation_vector_from_matrix
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix

R_DOWN = np.diag([-1.0, 1.0, -1.0])


@pytest.fixture(scope="module")
def world():
    w = SimWorld()
    yield w
    w.close()


def _press(world: SimWorld, force_n: float, steps: int, slide_velocity=None):
    """Hold the tool on the table pushing ``force_n`` down with tau = g + J^T F (+ damping, lateral motion).

    Returns the recorded contact wrenches (steps, 6) and tool twists (steps, 6).
    """
    start = np.array([0.6, 0.0, world.config.table.height_m + 0.003])
    world.reset(world.inverse_kinematics(start, quaternion_from_matrix(R_DOWN), Q_HOME))
    p_d = start.copy()
    wrenches, twists = [], []
    for k in range(steps):
        state = world.read_state()
        v = state.twist
        F = np.zeros(6)
        v_d = np.zeros(3)
        if slide_velocity is not None and k > steps // 3:
            v_d = np.asarray(slide_velocity, dtype=float)
            p_d = p_d + v_d * world.config.time_step_s
            F[:2] = 2000.0 * (p_d[:2] - state.position[:2]) + 100.0 * (v_d[:2] - v[:2])
        else:
            F[:2] = -100.0 * v[:2]
            p_d = state.position.copy()
        F[2] = -force_n - 50.0 * v[2]
        F[3:] = 30.0 * rotation_vector_from_matrix(R_DOWN @ state.rotation.T) - 0.3 * v[3:]
        world.step(state.gravity_coriolis + state.jacobian.T @ F - 0.5 * state.qd)
        wrenches.append(world.contact_wrench())
        twists.append(world.tool_twist())
    return np.asarray(wrenches), np.asarray(twists)


def test_gravity_compensation_alone_holds_the_arm_still(world):
    q0 = np.array(Q_HOME) + np.array([0.3, -0.2, 0.4, 0.3, -0.5, 0.2, 0.7])
    world.reset(q0)
    p0, _ = world.tool_pose()
    for _ in range(1000):
        world.step(world.gravity_coriolis_torques())
    p1, _ = world.tool_pose()
    q1, qd1 = world.joint_state()
    assert np.linalg.norm(p1 - p0) < 1e-3
    assert np.abs(q1 - q0).max() < 1e-4
    assert np.abs(qd1).max() < 1e-3
    assert not world.in_contact()


def test_without_compensation_the_arm_falls(world):
    world.reset()
    p0, _ = world.tool_pose()
    for _ in range(200):
        world.step(np.zeros(7))
    assert world.tool_pose()[0][2] < p0[2] - 0.01  # torque mode really is on: velocity motors are off


def test_pressing_the_table_gives_the_applied_wrench_with_correct_sign_and_magnitude(world):
    wrenches, _ = _press(world, 15.0, 1500)
    steady = wrenches[700:]
    assert world.in_contact()
    # The tool pushes DOWN on a horizontal table: fz < 0 in world.
    assert steady[:, 2].mean() == pytest.approx(-15.0, rel=0.02)
    assert steady[:, 2].std() < 0.7  # documented band (compliant contact, 1 kHz)
    assert np.abs(steady[:, :2]).max() < 0.3
    assert np.abs(steady[:, 3:]).max() < 0.01  # contact at the tool point: no moment
    normal, friction = world.contact_forces()
    assert normal[2] == pytest.approx(world.true_contact_wrench()[2] - friction[2])
    assert normal / np.linalg.norm(normal) == pytest.approx([0.0, 0.0, -1.0], abs=1e-6)
    # The pad compresses by about F / k = 0.5 mm.
    assert world.tool_pose()[0][2] == pytest.approx(world.config.table.height_m - 15.0 / 3e4, abs=2e-4)


def test_in_a_crease_the_compiled_summary_sums_both_surfaces_contact_points() -> None:
    """The ball pressed into the crease between the table and the 20° ramp touches both: the applied wrench, the true
    normal force and its direction (the compiled one-pass summary of PyBullet's contact points) equal the sums over
    the points written out here with numpy, and the pressing force balances the push."""
    with SimWorld(WorldConfig(ramp=RampConfig(enabled=True))) as world:
        world.reset(world.inverse_kinematics([0.596, 0.0, 0.101], quaternion_from_matrix(R_DOWN), Q_HOME))
        push = np.array([3.0, 0.0, -15.0])
        for _ in range(1500):
            s = world.read_state()
            wrench = np.zeros(6)
            wrench[:3] = push - 50.0 * s.twist[:3]
            wrench[1] = -100.0 * s.twist[1]
            wrench[3:] = 30.0 * rotation_vector_from_matrix(R_DOWN @ s.rotation.T) - 0.3 * s.twist[3:]
            world.step(s.gravity_coriolis + s.jacobian.T @ wrench - 0.5 * s.qd)
        points = pybullet.getContactPoints(bodyA=world.robot, linkIndexA=TOOL_LINK, physicsClientId=world.client_id)
        assert {c["body"] for c in world.contacts()} == {"table", "ramp"}
        p = world.tool_pose()[0]
        normal = [-c[9] * np.array(c[7]) for c in points]
        applied = [n - c[10] * np.array(c[11]) - c[12] * np.array(c[13]) for n, c in zip(normal, points, strict=True)]
        moment = sum(np.cross(np.array(c[5]) - p, f) for c, f in zip(points, applied, strict=True))
        np.testing.assert_allclose(world.true_contact_wrench(), np.r_[sum(applied), moment], rtol=0, atol=1e-12)
        force, direction = world.true_normal_force()
        assert force == pytest.approx(np.linalg.norm(sum(normal)), abs=1e-12)
        np.testing.assert_allclose(direction, sum(normal) / force, rtol=0, atol=1e-12)
        np.testing.assert_allclose(world.true_contact_wrench()[:3], push, atol=0.05)


def test_sliding_drags_the_table_along_the_tool_velocity_with_coulomb_friction(world):
    wrenches, twists = _press(world, 15.0, 2400, slide_velocity=(0.05, 0.0, 0.0))
    steady, v = wrenches[1800:], twists[1800:]
    assert v[:, 0].mean() == pytest.approx(0.05, rel=0.05)
    fx, fz = steady[:, 0].mean(), steady[:, 2].mean()
    assert fx > 0  # the force the TOOL applies to the table points along the tool's motion
    assert fx / -fz == pytest.approx(world.config.contact.lateral_friction, rel=0.03)
    assert fz == pytest.approx(-15.0, rel=0.03)


def test_torques_are_clipped_to_the_iiwa_limits(world):
    world.reset()
    assert np.allclose(world.torque_limits, IIWA_TORQUE_LIMITS_NM)
    q0, _ = world.joint_state()
    g = world.gravity_coriolis_torques()
    world.step(g)
    assert not world.last_step_clipped
    huge = g + np.array([1000.0, -1000.0, 500.0, -500.0, 300.0, -100.0, 100.0])
    world.reset(q0)
    world.step(huge)
    assert world.last_step_clipped and world.clip_count == 1
    q_huge, qd_huge = world.joint_state()
    world.reset(q0)
    world.step(np.clip(huge, -world.torque_limits, world.torque_limits))
    q_clip, qd_clip = world.joint_state()
    assert np.allclose(qd_huge, qd_clip) and np.allclose(q_huge, q_clip)


def test_jacobian_matches_finite_differences_of_the_tool_pose(world):
    q0 = np.array(Q_HOME) + np.array([0.2, 0.1, -0.3, 0.2, 0.4, -0.2, 0.5])
    world.reset(q0)
    J = world.jacobian()
    p0, _ = world.tool_pose()
    R0 = world.tool_rotation()
    h = 1e-6
    J_fd = np.zeros((6, 7))
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        world.set_joint_positions(q0 + dq)
        J_fd[:3, j] = (world.tool_pose()[0] - p0) / h
        J_fd[3:, j] = rotation_vector_from_matrix(world.tool_rotation() @ R0.T) / h
    assert np.abs(J - J_fd).max() < 1e-5
    # The twist is J qd at the tool point: compare with the pose change over one small step.
    world.set_joint_positions(q0, qd=np.full(7, 0.1))
    twist = world.tool_twist()
    world.set_joint_positions(q0 + 1e-5 * np.full(7, 1.0))
    assert (world.tool_pose()[0] - p0) / 1e-4 == pytest.approx(twist[:3], abs=1e-4)


def test_mass_matrix_and_inverse_dynamics_agree(world):
    world.reset(np.array(Q_HOME) + 0.1)
    q, _ = world.joint_state()
    M = world.mass_matrix()
    assert np.allclose(M, M.T) and np.all(np.linalg.eigvalsh(M) > 0)
    qdd = np.linspace(-1.0, 1.0, 7)
    tau = np.asarray(
        pybullet.calculateInverseDynamics(
            world.robot, q.tolist(), [0.0] * 7, qdd.tolist(), physicsClientId=world.client_id
        )
    )
    assert tau - world.gravity_coriolis_torques() == pytest.approx(M @ qdd, abs=1e-9)


def test_the_compiled_arm_model_equals_pybullets_own_queries(world):
    """The world's pose, Jacobian, gravity/Coriolis torques and mass matrix (sim_worker.arm_model) are PyBullet's
    getLinkState, calculateJacobian, calculateInverseDynamics and calculateMassMatrix to round-off, at random joint
    positions and velocities; the quaternion with PyBullet's sign."""
    rng = np.random.default_rng(3)
    cid, robot = world.client_id, world.robot
    for _ in range(50):
        q = rng.uniform(world.joint_lower, world.joint_upper)
        qd = rng.normal(0.0, 1.5, 7)
        world.set_joint_positions(q, qd)
        com = pybullet.getLinkState(robot, TOOL_LINK, computeForwardKinematics=1, physicsClientId=cid)
        lin, ang = pybullet.calculateJacobian(robot, TOOL_LINK, [0.0] * 3, q.tolist(), [0.0] * 7, [0.0] * 7,
                                              physicsClientId=cid)  # fmt: skip
        bias = pybullet.calculateInverseDynamics(robot, q.tolist(), qd.tolist(), [0.0] * 7, physicsClientId=cid)
        mass = pybullet.calculateMassMatrix(robot, q.tolist(), physicsClientId=cid)
        p, quat = world.tool_pose()
        # the tool's inertial frame is its link frame shifted along z (robot_model): the COM pose gives the tool point
        R = np.asarray(pybullet.getMatrixFromQuaternion(com[1])).reshape(3, 3)
        np.testing.assert_allclose(p, np.asarray(com[0]) - R @ np.asarray(com[2]), rtol=0, atol=1e-14)
        np.testing.assert_allclose(quat, com[1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(world.tool_rotation(), R, rtol=0, atol=1e-14)
        np.testing.assert_allclose(world.jacobian(), np.array(lin + ang), rtol=0, atol=1e-14)
        np.testing.assert_allclose(world.gravity_coriolis_torques(), bias, rtol=1e-13, atol=1e-12)
        np.testing.assert_allclose(world.mass_matrix(), mass, rtol=1e-13, atol=1e-14)
    world.reset()


@pytest.mark.parametrize(
    ("position", "tilt_deg"),
    [((0.6, 0.0, 0.12), 0.0), ((0.5, 0.2, 0.25), 20.0), ((0.7, -0.15, 0.18), -35.0), ((0.45, 0.0, 0.4), 50.0)],
)
def test_inverse_kinematics_reaches_targets(world, position, tilt_deg):
    world.reset()
    q_before, _ = world.joint_state()
    R = matrix_from_axis_angle((1.0, 0.0, 0.0), math.radians(tilt_deg)) @ R_DOWN
    q = world.inverse_kinematics(position, quaternion_from_matrix(R), Q_HOME)
    assert np.allclose(world.joint_state()[0], q_before)  # the simulated state is restored
    p, quat = world.forward_kinematics(q)
    assert np.linalg.norm(p - np.asarray(position)) < 1e-4
    assert np.linalg.norm(rotation_vector_from_matrix(matrix_from_quaternion(quat) @ R.T)) < 1e-3
    assert np.all(q >= world.joint_lower) and np.all(q <= world.joint_upper)


def test_inverse_kinematics_refuses_unreachable_targets(world):
    with pytest.raises(ValueError, match="did not converge"):
        world.inverse_kinematics([2.0, 0.0, 0.5], quaternion_from_matrix(R_DOWN), Q_HOME, max_iterations=50)


def test_tool_point_is_the_lowest_point_of_the_ball(world):
    world.reset()
    p, _ = world.tool_pose()
    aabb_min, _ = pybullet.getAABB(world.robot, TOOL_LINK, physicsClientId=world.client_id)
    assert p[2] == pytest.approx(aabb_min[2], abs=2e-3)  # tool pointing down: the ball bottom is the lowest point
    assert world.tool_rotation()[:, 2] == pytest.approx([0.0, 0.0, -1.0], abs=2e-3)


def test_geometry_normals_of_every_surface():
    config = WorldConfig(
        ramp=RampConfig(enabled=True, crease_x_m=0.15, tilt_deg=20.0),
        cylinder=CylinderConfig(enabled=True, xy_m=(-0.1, 0.25)),
        block=BlockConfig(enabled=True, xy_m=(-0.1, -0.2), yaw_deg=90.0),
    )
    g = WorldGeometry(config)
    # Table: straight up, 5 cm above reads 0.05.
    assert g.surface_normal_at([0.55, 0.0, 0.15]) == pytest.approx([0.0, 0.0, 1.0])
    assert g.signed_distance([0.55, 0.0, 0.15]) == pytest.approx(0.05)
    # Ramp: rises towards +x by 20 degrees.
    a = math.radians(20.0)
    assert g.surface_normal_at(g.ramp_point(0.1, 0.0) + 0.01 * g.ramp_normal) == pytest.approx(
        [-math.sin(a), 0.0, math.cos(a)]
    )
    # Cylinder: radial.
    cyl = g.solids["cylinder"]
    point = cyl.p + (cyl.radius + 0.01) * np.array([math.sin(0.6), 0.0, math.cos(0.6)])
    assert g.surface_normal_at(point) == pytest.approx([math.sin(0.6), 0.0, math.cos(0.6)], abs=1e-9)
    assert g.signed_distance(point) == pytest.approx(0.01)
    # Block (yawed 90 degrees: the profile runs along world y): the ellipse normal.
    block = g.solids["block"]
    phi = 1.0
    x, z = block.profile_point(phi)
    nx, nz = block.profile_normal(phi)
    surface = block.p + block.R @ np.array([x, 0.0, z])
    normal = block.R @ np.array([nx, 0.0, nz])
    assert abs(normal[0]) < 1e-12
    assert g.surface_normal_at(surface + 0.005 * normal) == pytest.approx(normal, abs=1e-9)
    assert g.signed_distance(surface + 0.005 * normal) == pytest.approx(0.005, abs=1e-9)
    assert g.signed_distance(surface - 0.002 * normal) == pytest.approx(-0.002, abs=1e-9)


def test_tilted_table_and_shifted_objects_follow_the_config():
    g = WorldGeometry(WorldConfig(table=TableConfig(tilt_deg=15.0, height_m=0.2)))
    assert g.table_normal == pytest.approx([0.0, -math.sin(math.radians(15.0)), math.cos(math.radians(15.0))])
    assert g.table_point(0.0, 0.0)[2] == pytest.approx(0.2)
    base = WorldGeometry(WorldConfig(cylinder=CylinderConfig(enabled=True))).solids["cylinder"].p
    moved = WorldGeometry(WorldConfig(cylinder=CylinderConfig(enabled=True, offset_m=(0.02, -0.01, 0.03)))).solids[
        "cylinder"
    ]
    assert moved.p - base == pytest.approx([0.02, -0.01, 0.03])


def test_worlds_are_independent_and_the_config_round_trips():
    config = WorldConfig(table=TableConfig(height_m=0.15), cylinder=CylinderConfig(enabled=True, yaw_deg=90.0))
    assert WorldConfig.from_dict(config.to_dict()) == config
    with SimWorld(config) as a, SimWorld(WorldConfig(table=TableConfig(height_m=0.05))) as b:
        assert a.client_id != b.client_id
        assert set(a.bodies) == {"table", "cylinder"} and set(b.bodies) == {"table"}
        aabb_a = pybullet.getAABB(a.bodies["table"], physicsClientId=a.client_id)
        aabb_b = pybullet.getAABB(b.bodies["table"], physicsClientId=b.client_id)
        assert aabb_a[1][2] == pytest.approx(0.15, abs=2e-3) and aabb_b[1][2] == pytest.approx(0.05, abs=2e-3)
        a.step(a.gravity_coriolis_torques())
        assert a.step_count == 1 and b.step_count == 0


def test_a_world_left_to_the_interpreters_exit_is_closed_silently() -> None:
    """A world still bound to a module global when Python exits (closed by its ``with`` block, or never closed) is
    finalized after the modules' globals are gone: no "Exception ignored" on stderr."""
    script = (  # a compiled function of the script's own, held with its entry, decides the order of the teardown
        "import numba\n"
        "from skills.compiled import compiled_entry\n"
        "from sim_worker.world import SimWorld\n"
        "@numba.njit\n"
        "def first(model):\n"
        "    return model[0]\n"
        "with SimWorld() as closed:\n"
        "    entry = compiled_entry(first, (closed.loop_handles().model,))\n"
        "still_open = SimWorld()\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[1])  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "Exception ignored" not in done.stderr, done.stderr


def test_sensor_noise_and_filter_are_off_by_default_and_seeded_when_on():
    with SimWorld(WorldConfig(sensor=SensorConfig(noise_force_std_n=0.5, seed=3))) as noisy:
        noisy.step(noisy.gravity_coriolis_torques())
        first = noisy.contact_wrench()
        assert first is not None and np.all(noisy.true_contact_wrench() == 0.0)
        assert np.abs(first[:3]).max() > 0 and first == pytest.approx(noisy.contact_wrench())  # once per step
    with SimWorld(WorldConfig(sensor=SensorConfig(noise_force_std_n=0.5, filter_cutoff_hz=5.0, seed=3))) as filtered:
        values = []
        for _ in range(200):
            filtered.step(filtered.gravity_coriolis_torques())
            values.append(filtered.contact_wrench()[2])
        assert np.std(values[50:]) < 0.2  # 5 Hz first-order low-pass of 0.5 N white noise


def test_the_wrist_sensor_reads_the_contact_wrench_with_the_tool_weight_compensated() -> None:
    """A force/torque sensor between flange and tool: pressing with a lateral push, its compensated reading equals
    the exact contact wrench (force and moment at the tool point); hanging free it reads nothing."""
    from sim_worker.world import SimWorld

    with SimWorld(WorldConfig(sensor=SensorConfig(model=SensorModel.wrist))) as world:
        for _ in range(200):
            world.step(world.gravity_coriolis_torques())
        np.testing.assert_allclose(world.wrist_wrench(), np.zeros(6), atol=1e-6)
        _, q = world.tool_pose()
        world.reset(world.inverse_kinematics([0.55, 0.0, 0.0997], q))
        push = np.array([0.5, 0.3, -10.0, 0.0, 0.0, 0.0])
        for _ in range(500):
            world.step(world.gravity_coriolis_torques() + world.jacobian().T @ push)
        np.testing.assert_allclose(world.wrist_wrench(), world.true_contact_wrench(), atol=2e-3)
        assert world.true_contact_wrench()[2] == pytest.approx(-10.0, abs=0.05)


def test_the_sensor_model_delays_drifts_adds_noise_and_filters_as_configured() -> None:
    from sim_worker.sensor import WRIST_SENSOR, WrenchSensor

    config = WRIST_SENSOR.model_copy(update={"filter_cutoff_hz": None, "bias_drift_n_per_sqrt_s": 0.0})
    dt = WorldConfig().time_step_s
    sensor = WrenchSensor(config, dt)
    steps = np.zeros((4000, 6))
    steps[1000:, 2] = 10.0  # a step of 10 N at step 1000
    readings = np.array([sensor.measure(w) for w in steps])
    first = int(np.argmax(readings[:, 2] > 5.0))
    assert first == 1000 + round(WRIST_SENSOR.delay_s / dt)  # 2 ms late
    assert np.std(readings[2000:, 0]) == pytest.approx(WRIST_SENSOR.noise_force_std_n, rel=0.1)
    quiet = {"noise_force_std_n": 0.0, "noise_torque_std_nm": 0.0}
    drifting = WrenchSensor(config.model_copy(update={"bias_drift_n_per_sqrt_s": 0.02, **quiet}), dt)
    ends = [np.array([drifting.measure(np.zeros(6)) for _ in range(1000)])[-1, :3] for _ in range(100)]
    assert np.std(np.diff(np.array(ends), axis=0)) == pytest.approx(0.02, rel=0.25)  # the increment over 1 s
    filtered = WrenchSensor(config.model_copy(update={"filter_cutoff_hz": 20.0, "delay_s": 0.0, **quiet}), dt)
    response = np.array([filtered.measure(w) for w in steps])[:, 2]
    k63 = int(np.argmax(response > 10.0 * (1 - np.exp(-1)))) - 1000
    assert k63 == pytest.approx(1000 / (2 * np.pi * 20.0), abs=1.5)  # time constant 1 / (2 pi fc), in steps


def test_the_sensor_composes_bias_delay_and_filter_in_the_documented_order() -> None:
    """The compiled sensor against the model written out: reading = low-pass(delay(source + bias)), the delay line
    filled with the first reading at the start, the filter starting from it."""
    from sim_worker.sensor import WrenchSensor

    config = SensorConfig(model=SensorModel.wrist, bias_n=(0.5, -0.2, 1.0), delay_s=0.003, filter_cutoff_hz=50.0)
    dt = WorldConfig().time_step_s
    source = np.random.default_rng(3).normal(0.0, 5.0, (300, 6))
    sensor = WrenchSensor(config, dt)
    readings = np.array([sensor.measure(w) for w in source])
    raw = source + np.array([0.5, -0.2, 1.0, 0.0, 0.0, 0.0])
    delayed = raw[np.maximum(np.arange(300) - 3, 0)]
    alpha = dt / (dt + 1.0 / (2.0 * np.pi * 50.0))
    expected = np.empty_like(delayed)
    expected[0] = delayed[0]
    for k in range(1, 300):
        expected[k] = expected[k - 1] + alpha * (delayed[k] - expected[k - 1])
    np.testing.assert_allclose(readings, expected, rtol=0, atol=1e-12)
    sensor.reset()  # a new run empties the delay line and restarts the filter
    np.testing.assert_allclose(sensor.measure(source[0]), raw[0], rtol=0, atol=1e-12)


def test_a_tare_removes_an_offset_in_the_tool_frame_so_a_world_fixed_one_returns_as_the_tool_turns() -> None:
    """``tare_sensor(offset)`` removes ``offset`` (tool frame) turned into the world at every reading. A bias fixed in
    the world ``b`` (``SensorConfig.bias_n``; the source the exact wrench: zero in free space), tared in pose ``R_a``,
    reads zero there, from the reading already sampled on (the step after a tare must not see the old offset: it
    once took it for a touch-down in the air), and ``b - R_b R_aᵀ b`` in a turned pose ``R_b``; ``reset()`` clears the
    tare; the ideal sensor refuses one."""
    bias = np.array([0.3, -0.2, -0.8])
    with SimWorld(WorldConfig(sensor=SensorConfig(bias_n=tuple(bias)))) as world:
        np.testing.assert_allclose(world.contact_wrench(), np.r_[bias, 0, 0, 0], rtol=0, atol=1e-12)
        R_a = world.tool_rotation()
        world.tare_sensor(np.r_[R_a.T @ bias, 0, 0, 0])
        np.testing.assert_allclose(world.contact_wrench(), np.zeros(6), rtol=0, atol=1e-12)  # this reading too
        world.set_joint_positions(Q_HOME)
        np.testing.assert_allclose(world.contact_wrench(), np.zeros(6), rtol=0, atol=1e-12)
        turned = np.array(Q_HOME) + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.9])
        world.set_joint_positions(turned)
        R_b = world.tool_rotation()
        assert np.linalg.norm(R_b - R_a) > 0.5
        np.testing.assert_allclose(world.contact_wrench()[:3], bias - R_b @ R_a.T @ bias, rtol=0, atol=1e-12)
        world.reset(turned)
        np.testing.assert_allclose(world.contact_wrench(), np.r_[bias, 0, 0, 0], rtol=0, atol=1e-12)
    with SimWorld(WorldConfig()) as world, pytest.raises(ValueError, match="nothing to tare"):
        world.tare_sensor(np.zeros(6))


def _stiffness_under(config: WorldConfig, x: float) -> float:
    """The surface's stiffness (N/m) under the ball at world (x, 0): 10 N over how much deeper it sinks at 15 N than
    at 5 N (a difference: the mesh's collision margin cancels)."""
    heights = []
    with SimWorld(config) as world:
        _, q = world.tool_pose()
        for force_n in (5.0, 15.0):
            world.reset(world.inverse_kinematics([x, 0.0, 0.101], q))
            push = np.array([0.0, 0.0, -force_n, 0.0, 0.0, 0.0])
            for _ in range(1500):
                world.step(world.gravity_coriolis_torques() + world.jacobian().T @ push)
            assert world.true_contact_wrench()[2] == pytest.approx(-force_n, abs=0.02)
            heights.append(world.tool_pose()[0][2])
    return 10.0 / (heights[0] - heights[1])


def test_layered_work_pieces_have_the_configured_stiffness_where_they_overlap() -> None:
    """Two pieces covering the same spot (a rebuilt strip's pieces overlap by half, ``layers=2``) touch the ball
    as two springs: each is made half as stiff, so the surface there is as stiff as one body. Without the layer
    count the same overlap is twice as stiff (the seams of the old strips)."""

    def slab(x0: float, x1: float) -> list[list[float]]:
        return [[x, y, z] for x in (x0, x1) for y in (-0.1, 0.1) for z in (0.06, 0.10)]

    config = WorldConfig()
    k = config.contact.stiffness_n_m
    one = config.with_only_work_pieces([WorkPiece(name="a", vertices=slab(0.45, 0.65))])
    assert _stiffness_under(one, 0.55) == pytest.approx(k, rel=0.03)
    pieces = [WorkPiece(name="a", vertices=slab(0.45, 0.60)), WorkPiece(name="b", vertices=slab(0.50, 0.65))]
    layered = config.with_only_work_pieces([p.model_copy(update={"layers": 2}) for p in pieces])
    assert _stiffness_under(layered, 0.55) == pytest.approx(k, rel=0.03)  # in the overlap: two half springs
    assert _stiffness_under(config.with_only_work_pieces(pieces), 0.55) == pytest.approx(2 * k, rel=0.03)
