"""The MuJoCo cell (``sim_mujoco``) against PyBullet's (``sim_worker.world``) and against physics: the same arm
dynamics, the same solids, the pad's stiffness, the true contact and the wrist sensor, and a joint-space impedance
written here (no product controller) pressing on the table with the force it commands."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from schemas.world import WorkPiece, WorldConfig
from sim_mujoco.model import FRICTION_IMPRATIO, cell_model
from sim_mujoco.robot import MujocoRobot
from sim_worker.geometry import WorldGeometry
from sim_worker.robot_model import Q_HOME
from sim_worker.world import SimWorld

DOWN = (1.0, 0.0, 0.0, 0.0)
"""The tool pointing straight down (``[x, y, z, w]``)."""
PRESS_XY = (0.6, 0.0)
CONFIGURATIONS = (
    Q_HOME,
    (0.3, -0.4, 0.5, -1.2, 0.7, 0.9, -0.4),
    (-0.8, 0.9, -0.3, -0.5, -1.1, 1.4, 0.6),
)


@pytest.fixture(scope="module")
def pybullet_world():
    with SimWorld(WorldConfig()) as world:
        yield world


def pose_above_table(world: SimWorld, depth_m: float) -> np.ndarray:
    """Joint positions (PyBullet's inverse kinematics) putting the tool point ``depth_m`` below the table top at
    :data:`PRESS_XY`, pointing down, in the elbow-up posture of ``Q_HOME``."""
    top = world.config.table.height_m
    return world.inverse_kinematics([*PRESS_XY, top - depth_m], DOWN, q_seed=Q_HOME)


def press(robot: MujocoRobot, q_d: np.ndarray, force_n: float, steps: int, stiffness: float = 100.0) -> None:
    """Hold ``q_d`` with a joint-space impedance (``M (K e - D qd)``, MuJoCo's own bias compensated) and push the tool
    down with ``force_n`` (N, through ``J^T``) for ``steps`` steps."""
    push = np.array([0.0, 0.0, -force_n, 0.0, 0.0, 0.0])
    damping = 2.0 * np.sqrt(stiffness)
    for _ in range(steps):
        q, qd = robot.joint_state()
        tau = robot.gravity_coriolis_torques() + robot.mass_matrix() @ (stiffness * (q_d - q) - damping * qd)
        robot.step(tau + robot.jacobian().T @ push)


def test_the_arm_has_pybullets_mass_matrix_gravity_tool_pose_and_limits(pybullet_world):
    """M(q), g(q) and the tool point's pose equal PyBullet's at three configurations (measured: 1e-15 relative), and
    the joint limits are the URDF's."""
    robot = MujocoRobot()
    for q in CONFIGURATIONS:
        robot.reset(q)
        pybullet_world.set_joint_positions(q)
        M, g = pybullet_world.mass_matrix(), pybullet_world.gravity_coriolis_torques()
        assert np.abs(robot.mass_matrix() - M).max() <= 1e-6 * np.abs(M).max()
        assert np.abs(robot.gravity_coriolis_torques() - g).max() <= 1e-6 * np.abs(g).max()
        position, quat = robot.tool_pose()
        bullet_position, bullet_quat = pybullet_world.tool_pose()
        np.testing.assert_allclose(position, bullet_position, atol=1e-9)
        assert abs(abs(float(quat @ bullet_quat)) - 1.0) < 1e-9
        np.testing.assert_allclose(robot.jacobian(), pybullet_world.jacobian(), atol=1e-9)
    np.testing.assert_allclose(robot.cell.joint_lower, pybullet_world.joint_lower)
    np.testing.assert_allclose(robot.cell.joint_upper, pybullet_world.joint_upper)


def test_the_solids_are_where_the_world_geometry_puts_them():
    """Table, ramp, cylinder (a capsule), block and a convex work piece: MuJoCo's rays from above hit each solid's
    exact surface (``WorldGeometry``; a ray sees the hull itself, its contacts start PyBullet's margin out)."""
    import mujoco

    piece = WorkPiece(name="plate", vertices=[(x, y, z) for x in (0.2, 0.3) for y in (0.3, 0.4) for z in (0.1, 0.12)])
    config = WorldConfig().replace(
        ramp={"enabled": True, "crease_x_m": 0.2},
        cylinder={"enabled": True, "xy_m": (-0.15, 0.25)},
        block={"enabled": True, "xy_m": (-0.15, -0.2)},
        work_pieces=[piece.model_dump()],
    )
    cell = cell_model(config)
    data = mujoco.MjData(cell.model)
    mujoco.mj_forward(cell.model, data)
    geometry = WorldGeometry(config)
    solids = geometry.solids
    targets = {
        "ramp": geometry.ramp_point(0.1, 0.0),
        "cylinder": solids["cylinder"].p + np.array([0.0, 0.0, 0.08]),
        "block": solids["block"].p + np.array([0.0, 0.0, 0.08]),
        "plate": np.array([0.25, 0.35, 0.12]),
        "table": geometry.table_point(0.2, -0.3),
    }
    hit = np.zeros(1, dtype=np.int32)
    for name, point in targets.items():
        start = point + np.array([0.0, 0.0, 0.3])
        distance = mujoco.mj_ray(cell.model, data, start, np.array([0.0, 0.0, -1.0]), None, 1, -1, hit)
        assert cell.environment[int(hit[0])] == name
        assert start[2] - distance == pytest.approx(point[2], abs=2e-5), name


@pytest.mark.parametrize("force_n", [5.0, 15.0, 30.0])
def test_a_static_press_compresses_the_pad_by_force_over_its_stiffness(pybullet_world, force_n):
    """The tool pressed on the table with a known force settles at the force (true normal force) and compresses the
    pad by F / k, k the pad's 3e4 N/m (measured: 15.0007 N and 0.50002 mm at 15 N), the normal up out of the
    table."""
    k = WorldConfig().contact.stiffness_n_m
    robot = MujocoRobot(q=pose_above_table(pybullet_world, force_n / k))
    press(robot, robot.joint_state()[0], force_n, 1500, stiffness=20.0)
    truth = robot.true_contact()
    depth = WorldConfig().table.height_m - robot.tool_pose()[0][2]
    assert truth.in_contact
    assert truth.normal_force_n == pytest.approx(force_n, rel=0.01)
    assert depth == pytest.approx(force_n / k, rel=0.02)
    np.testing.assert_allclose(truth.normal, [0.0, 0.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(truth.wrench[:3], [0.0, 0.0, -force_n], atol=0.01 * force_n)


def test_a_layered_work_piece_keeps_the_pads_stiffness(pybullet_world):
    """Two overlapping plates, each in 2 layers (as a rebuilt strip's pieces), press like one: F / k again."""
    top = WorldConfig().table.height_m
    plate = [(x, y, z) for x in (0.5, 0.7) for y in (-0.1, 0.1) for z in (top - 0.02, top)]
    pieces = [WorkPiece(name=f"plate_{k}", vertices=plate, layers=2).model_dump() for k in range(2)]
    config = WorldConfig().with_only_work_pieces([WorkPiece.model_validate(p) for p in pieces])
    k, force = config.contact.stiffness_n_m, 15.0
    # The plates' faces lie out by the hull margin PyBullet adds: press from there.
    margin = cell_model(config).model.geom_margin.max()
    robot = MujocoRobot(config, q=pose_above_table(pybullet_world, force / k - margin))
    press(robot, robot.joint_state()[0], force, 1500, stiffness=20.0)
    depth = top + margin - robot.tool_pose()[0][2]
    assert robot.true_contact().normal_force_n == pytest.approx(force, rel=0.01)
    assert depth == pytest.approx(force / k, rel=0.03)


SETTLE_ON_RIDGE_STEPS = 150


def test_both_engines_press_the_kuleuven_cad_crease_alike():
    """The KU Leuven object's CAD pieces (every 2.5 mm, in 4 layers: 345 mesh geoms), turned so that the crease's
    bisector points up under the tool, pressed with 15 N by the same weak joint impedance in both engines: the same
    force along the same normal, the tool at the same height after 0.15 s (measured: 14.953 and 14.970 N, normals
    0.23° apart, heights 0.010 mm apart: PyBullet's own offset, docs/ENGINES.md). Not longer: the ridge's balance is
    unstable, Bullet's stick holds the ball on it, MuJoCo's friction (a damper below the cone, ``FRICTION_IMPRATIO``)
    lets it creep off under this weak hold (0.47 mm across and the normal 2.8° turned after 0.6 s)."""
    from conftest import KULEUVEN_DATA

    from services.kuleuven_object import kuleuven_ground_truth
    from sim_worker.cad_work_piece import cad_world_config
    from skills.frames import rotation_from_vectors

    contour = kuleuven_ground_truth(KULEUVEN_DATA / "contour_a_1.csv").kuleuven_object
    k = len(contour.crease.outward) // 2
    bisector = contour.crease.outward[k].sum(axis=0)
    rotation = rotation_from_vectors(bisector, [0.0, 0.0, 1.0])
    apex = np.array([*PRESS_XY, 0.15])
    translation = apex - rotation @ contour.crease.points[k : k + 2].mean(axis=0)
    config = cad_world_config(contour.mesh, contour.crease, rotation, translation, spacing_m=0.0025, layers=4)
    force = 15.0
    with SimWorld(config) as world:
        q_d = world.inverse_kinematics(apex - [0.0, 0.0, force / config.contact.stiffness_n_m], DOWN, q_seed=Q_HOME)
        world.set_joint_positions(q_d)
        push = np.array([0.0, 0.0, -force, 0.0, 0.0, 0.0])
        for _ in range(SETTLE_ON_RIDGE_STEPS):
            q, qd = world.joint_state()
            tau = world.gravity_coriolis_torques() + world.jacobian().T @ push
            world.step(tau + world.mass_matrix() @ (20.0 * (q_d - q) - 2.0 * np.sqrt(20.0) * qd))
        bullet_force, bullet_normal = world.true_normal_force()
        bullet_height = world.tool_pose()[0][2]
    robot = MujocoRobot(config, q=q_d)
    press(robot, q_d, force, SETTLE_ON_RIDGE_STEPS, stiffness=20.0)
    truth = robot.true_contact()
    assert truth.normal_force_n == pytest.approx(force, rel=0.01)
    assert truth.normal_force_n == pytest.approx(bullet_force, rel=0.005)
    assert np.degrees(np.arccos(np.clip(truth.normal @ bullet_normal, -1.0, 1.0))) < 0.5
    assert robot.tool_pose()[0][2] == pytest.approx(bullet_height, abs=3e-5)


def test_the_wrist_sensor_reads_the_contact_wrench_with_the_tool_weight_compensated(pybullet_world):
    """Hanging still: the wrist reads nothing (the tool's weight compensated); pressing: the true contact wrench."""
    config = WorldConfig().replace(sensor={"model": "wrist"})
    robot = MujocoRobot(config)
    robot.step(robot.gravity_coriolis_torques())
    np.testing.assert_allclose(robot.contact_wrench(), np.zeros(6), atol=1e-6)
    robot.reset(pose_above_table(pybullet_world, 15.0 / config.contact.stiffness_n_m))
    press(robot, robot.joint_state()[0], 15.0, 1000)
    np.testing.assert_allclose(robot.contact_wrench(), robot.true_contact().wrench, atol=0.02)
    assert robot.contact_wrench()[2] == pytest.approx(-15.0, rel=0.01)


def hold_still(engine: MujocoRobot | SimWorld) -> np.ndarray:
    """One step of either engine under its gravity and Coriolis torques; the sensor's reading after it."""
    engine.step(engine.gravity_coriolis_torques())
    return engine.contact_wrench()


def test_the_sensor_model_reads_as_pybullets_with_bias_offset_and_tare():
    """The wrist sensor with a world-fixed bias and its own offset in the tool frame, the arm held still at two poses,
    then tared: both engines read the same (within 1e-4 N), before and right after the tare and a step later."""
    config = WorldConfig().replace(sensor={"model": "wrist", "bias_n": (0.3, -0.2, 0.5), "offset_tool_n": (0.4, 0, 0)})
    robot = MujocoRobot(config)
    readings: dict[str, list[np.ndarray]] = {"mujoco": [], "pybullet": []}
    with SimWorld(config) as world:
        for q in CONFIGURATIONS[:2]:
            for name, engine in (("mujoco", robot), ("pybullet", world)):
                engine.reset(q)
                readings[name].append(hold_still(engine))
                engine.tare_sensor([0.4, 0.0, 0.0, 0.0, 0.0, 0.0])
                readings[name] += [engine.contact_wrench(), hold_still(engine)]
    for mujoco_reading, bullet_reading in zip(readings["mujoco"], readings["pybullet"], strict=True):
        np.testing.assert_allclose(mujoco_reading, bullet_reading, atol=1e-4)
    # Untared, the reading is the bias plus the offset turned with the tool; tared, the bias alone.
    assert np.linalg.norm(readings["mujoco"][0][:3] - [0.3, -0.2, 0.5]) == pytest.approx(0.4, abs=1e-4)
    np.testing.assert_allclose(readings["mujoco"][5][:3], [0.3, -0.2, 0.5], atol=1e-4)
    with pytest.raises(ValueError, match="ideal sensor"):
        MujocoRobot().tare_sensor(np.zeros(6))


def test_a_malformed_torque_command_is_refused_naming_tau():
    robot = MujocoRobot()
    for bad in (np.zeros(6), [0.0] * 6 + [float("nan")]):
        with pytest.raises(ValueError, match="tau: expected 7 finite joint torques"):
            robot.command_torques(bad)


def test_a_joint_impedance_comes_down_from_above_and_presses_with_its_force(pybullet_world):
    """A joint-space impedance (written here, MuJoCo's bias compensated) starting 1 cm above the table, its target
    the pose the pad would take at 10 N, pushing down with 10 N: touches down and settles at 10 N (true normal force,
    within 2 %), and the realistic wrist sensor reads it within 0.5 N."""
    from sim_worker.sensor import WRIST_SENSOR

    config = WorldConfig().replace(sensor=WRIST_SENSOR.model_dump())
    force = 10.0
    q_d = pose_above_table(pybullet_world, force / config.contact.stiffness_n_m)
    robot = MujocoRobot(config, q=pose_above_table(pybullet_world, -0.01))
    assert not robot.true_contact().in_contact
    press(robot, q_d, force, 1500)
    truth = robot.true_contact()
    assert truth.in_contact and robot.time_s == pytest.approx(1.5)
    assert truth.normal_force_n == pytest.approx(force, rel=0.02)
    assert robot.contact_wrench()[2] == pytest.approx(-force, abs=0.5)


def test_touch_down_peaks_as_in_pybullet(pybullet_world):
    """The same joint impedance, from 1 cm above the table, in both engines: the tool touches down at the same step and
    the impact's peak force agrees within 5 % (measured: PyBullet 52.0 N, MuJoCo 51.2 N with ``PAD_IMPEDANCE`` 0.1;
    45.4 N at 0.5 and 33.4 N at 0.9, whose constraint adds more apparent mass)."""
    config = WorldConfig()
    target = pose_above_table(pybullet_world, 15.0 / config.contact.stiffness_n_m)
    above = pose_above_table(pybullet_world, -0.01)
    robot = MujocoRobot(config, q=above)
    pybullet_world.set_joint_positions(above)
    push = np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])
    forces: dict[str, list[float]] = {"mujoco": [], "pybullet": []}
    for _ in range(300):
        press(robot, target, 15.0, 1)
        forces["mujoco"].append(robot.true_contact().normal_force_n)
        q, qd = pybullet_world.joint_state()
        tau = pybullet_world.gravity_coriolis_torques() + pybullet_world.jacobian().T @ push
        pybullet_world.step(tau + pybullet_world.mass_matrix() @ (100.0 * (target - q) - 20.0 * qd))
        forces["pybullet"].append(pybullet_world.true_normal_force()[0])
    mujoco, bullet = np.array(forces["mujoco"]), np.array(forces["pybullet"])
    assert np.argmax(mujoco > 0.0) == np.argmax(bullet > 0.0) > 0
    assert mujoco.max() == pytest.approx(bullet.max(), rel=0.05)


def test_the_tool_slides_with_mu_times_the_normal_force(pybullet_world):
    """Pressed with 15 N while a stiff impedance's target moves 5 cm along x in 0.5 s: the tool slides and the
    friction force is μ (``ContactConfig.lateral_friction``, 0.2) times the normal force (measured: 0.2000)."""
    config = WorldConfig()
    depth = 15.0 / config.contact.stiffness_n_m
    start = pose_above_table(pybullet_world, depth)
    end = pybullet_world.inverse_kinematics(
        [PRESS_XY[0] + 0.05, PRESS_XY[1], config.table.height_m - depth], DOWN, q_seed=start
    )
    robot = MujocoRobot(config, q=start)
    press(robot, start, 15.0, 200)
    ratios = []
    for s in np.linspace(0.0, 1.0, 500):
        press(robot, (1.0 - s) * start + s * end, 15.0, 1, stiffness=400.0)
        truth = robot.true_contact()
        ratios.append(np.linalg.norm(truth.wrench[:2]) / truth.normal_force_n)
    assert robot.tool_pose()[0][0] > PRESS_XY[0] + 0.02
    np.testing.assert_allclose(ratios[250:], config.contact.lateral_friction, rtol=0.01)


def test_below_the_cone_mujocos_friction_is_a_damper_where_pybullets_sticks(pybullet_world):
    """Pressed with 15 N and pushed sideways with 1.5 N (half of μ N) for 1 s against a soft joint impedance: PyBullet's
    tool stays within 0.1 mm (measured 0.03 mm); MuJoCo's creeps, its friction below the cone a damper of
    ``FRICTION_IMPRATIO`` times the pad's damping: over the last 0.5 s the friction force over the creep speed is
    ``impratio c`` (measured: 4.4 mm/s, 299.7 N·s/m; 0.05 mm in 1 s with impratio 100, the stick it used
    to match)."""
    config = WorldConfig()
    start = pose_above_table(pybullet_world, 15.0 / config.contact.stiffness_n_m)
    push = np.array([1.5, 0.0, -15.0, 0.0, 0.0, 0.0])
    robot = MujocoRobot(config, q=start)
    pybullet_world.set_joint_positions(start)
    paths, friction = [], []
    for engine in (robot, pybullet_world):
        x = []
        for _ in range(1000):
            q, qd = engine.joint_state()
            tau = engine.gravity_coriolis_torques() + engine.mass_matrix() @ (100.0 * (start - q) - 20.0 * qd)
            engine.step(tau + engine.jacobian().T @ push)
            x.append(engine.tool_pose()[0][0])
            if engine is robot:
                friction.append(robot.true_contact().wrench[0])  # the friction the tool drags the table with, along +x
        paths.append(np.array(x))
    mujoco_path, bullet_path = paths
    creep_speed = (mujoco_path[-1] - mujoco_path[500]) / (499 * config.time_step_s)
    damper = float(np.mean(friction[500:])) / creep_speed
    assert damper == pytest.approx(FRICTION_IMPRATIO * config.contact.damping_n_s_m, rel=0.05)
    assert abs(bullet_path[-1] - bullet_path[0]) < 1e-4


def drag(robot: MujocoRobot, q_hold: np.ndarray, speed_m_s: float, steps: int, force_n: float) -> np.ndarray:
    """Press down with ``force_n`` (N) and drag the tool along x at ``speed_m_s`` (m/s) with a stiff Cartesian
    spring-damper for ``steps`` steps, the other directions held by a joint impedance about ``q_hold``; per step the
    true normal force (N) and the friction's share of it (|F_t| / F_n)."""
    x0 = robot.tool_pose()[0][0]
    rows = []
    for k in range(steps):
        q, qd = robot.joint_state()
        jacobian = robot.jacobian()
        x, vx = robot.tool_pose()[0][0], (jacobian @ qd)[0]
        fx = 2.0e4 * (x0 + speed_m_s * k * robot.time_step_s - x) + 400.0 * (speed_m_s - vx)
        tau = robot.gravity_coriolis_torques() + robot.mass_matrix() @ (100.0 * (q_hold - q) - 20.0 * qd)
        robot.step(tau + jacobian.T @ np.array([fx, 0.0, -force_n, 0.0, 0.0, 0.0]))
        truth = robot.true_contact()
        rows.append((truth.normal_force_n, np.linalg.norm(truth.wrench[:2]) / max(truth.normal_force_n, 1e-9)))
    return np.array(rows)


@pytest.mark.parametrize(("speed_m_s", "friction_share"), [(0.03, None), (0.05, 0.9)])
def test_at_mu_0_9_the_friction_is_the_damper_until_the_cone_then_mu_n(pybullet_world, speed_m_s, friction_share):
    """Dragged at a steady speed under 15 N with μ 0.9: slower than ``μ N / (impratio c)`` (45 mm/s) MuJoCo's friction
    is the damper ``impratio c v`` (30 mm/s: 9 N, a share of 0.61, measured 0.605), faster it slides at μ N (60 mm/s:
    0.900); the normal force steady either way (measured: standard deviation 0.06 N and 0.15 N)."""
    config = WorldConfig().replace(contact={"lateral_friction": 0.9})
    start = pose_above_table(pybullet_world, 15.0 / config.contact.stiffness_n_m)
    robot = MujocoRobot(config, q=start)
    press(robot, start, 15.0, 200)
    rows = drag(robot, start, speed_m_s, 500, 15.0)[250:]
    normal, share = rows[:, 0], rows[:, 1]
    damper = FRICTION_IMPRATIO * config.contact.damping_n_s_m * speed_m_s / normal
    expected = damper if friction_share is None else np.full_like(share, friction_share)
    np.testing.assert_allclose(share, expected, rtol=0.02)
    assert normal.min() > 14.0 and normal.std() < 0.3


def test_a_pad_stiffer_than_the_step_resolves_is_as_stiff_as_configured_and_flagged(pybullet_world, caplog):
    """A 1e6 N/m pad: MuJoCo does not clamp the direct ``solref`` (the pad compresses by F / k, 15 µm at 15 N,
    measured 14.9 µm), and the cell flags (and logs) that its contact's time constant (1.33 ms) is under two 1 ms
    steps; the nominal 3e4 N/m pad (7.7 ms) is not flagged."""
    k = 1.0e6
    config = WorldConfig().replace(contact={"stiffness_n_m": k})
    with caplog.at_level(logging.WARNING, logger="contact_skills.mujoco"):
        robot = MujocoRobot(config, q=pose_above_table(pybullet_world, 15.0 / k))
    assert "time constant of 1.33 ms, under 2 time steps" in caplog.text
    press(robot, robot.joint_state()[0], 15.0, 1000, stiffness=20.0)
    depth = config.table.height_m - robot.tool_pose()[0][2]
    assert robot.true_contact().normal_force_n == pytest.approx(15.0, rel=0.01)
    assert depth == pytest.approx(15.0 / k, rel=0.02)
    assert robot.cell.pad_time_constant_s == pytest.approx(1.33e-3, rel=0.01)
    assert not robot.cell.pad_resolved
    assert cell_model(WorldConfig()).pad_resolved


def test_the_tools_contacts_take_the_pads_friction_coefficient(pybullet_world):
    """Pressing on the table, every tool contact MuJoCo made has the pad's μ (``ContactConfig.lateral_friction``, 0.2,
    the tool's priority over the environment's geoms) and no torsional or rolling friction (condim 3)."""
    config = WorldConfig().replace(contact={"lateral_friction": 0.35})
    robot = MujocoRobot(config, q=pose_above_table(pybullet_world, 15.0 / config.contact.stiffness_n_m))
    press(robot, robot.joint_state()[0], 15.0, 100)
    contacts = [robot.data.contact[i] for i in range(robot.data.ncon)]
    assert contacts and all(c.geom1 in robot.cell.tool_geoms or c.geom2 in robot.cell.tool_geoms for c in contacts)
    assert [(c.friction[0], c.dim) for c in contacts] == [(0.35, 3)] * len(contacts)
