"""The robot interface of an execution (``execution.robot``): PyBullet's world is a ``SimulatedRobot``, and a
controller driven through the interface alone (state in, torques out, the wrist sensor, the clock) presses on the
table with the force asked for, as the simulator's own contact says (no mocked physics)."""

from __future__ import annotations

import numpy as np

from execution.robot import Robot, SimulatedRobot
from schemas.skill import SELECTION_CONTACT
from sim_mujoco.robot import MujocoRobot
from sim_worker.world import SimWorld
from skills.control import HybridController
from skills.control.layouts import REFERENCE_FORCE, REFERENCE_POSITION, REFERENCE_QUAT, REFERENCE_SIZE, REFERENCE_TWIST

PRESS_N = 15.0
DESCENT_M = 0.2
"""The reference descends this far, into the table under the tool: the force loop presses on it."""
STEPS = 3000
MODEL_UPDATE_STEPS = 20


def pressed(robot: Robot, steps: int) -> None:
    """Drive ``robot`` through its interface only: a hybrid controller pressing ``PRESS_N`` along world -z (force
    control on CF z) while its reference descends ``DESCENT_M`` over two thirds of ``steps`` (a slow touch-down)."""
    dt = robot.time_step_s
    controller = HybridController(posture=robot.joint_state()[0], torque_limits=robot.torque_limits, dt=dt)
    frame = controller.frame(np.diag([1.0, -1.0, -1.0]), SELECTION_CONTACT)
    p, q = robot.tool_pose()
    descent = np.minimum(np.arange(steps) / (2 * steps // 3), 1.0) * DESCENT_M
    reference = np.zeros(REFERENCE_SIZE)
    reference[REFERENCE_QUAT], reference[REFERENCE_FORCE] = q, PRESS_N
    for k in range(steps):
        reference[REFERENCE_POSITION] = p - [0.0, 0.0, descent[k]]
        reference[REFERENCE_TWIST][2] = -(descent[min(k + 1, steps - 1)] - descent[k]) / dt
        update = k % MODEL_UPDATE_STEPS == 0
        mass = robot.mass_matrix() if update else None
        wrench = robot.contact_wrench()
        pressing = -wrench[2] > 0.5  # the force integral runs in contact only (CF z is world -z)
        out = controller.step(frame, robot.robot_state(), reference, wrench, pressing, mass, update)
        assert out.abort_reason is None, out.abort_reason
        robot.step(out.tau)


def test_pybullets_world_presses_through_the_robot_interface_as_its_true_contact_says() -> None:
    with SimWorld() as world:
        assert isinstance(world, SimulatedRobot) and isinstance(world, Robot)
        pressed(world, STEPS)
        assert world.step_count == STEPS
        force, normal = world.true_normal_force()
        assert abs(force - PRESS_N) < 0.5, force  # the true normal force is the one asked for
        np.testing.assert_allclose(normal, [0.0, 0.0, -1.0], atol=1e-6)  # into the table
        np.testing.assert_allclose(world.contact_wrench(), world.true_contact_wrench())  # the ideal sensor
        assert abs(world.contact_wrench()[2] + PRESS_N) < 0.5


def test_mujocos_robot_presses_through_the_same_interface_as_its_true_contact_says() -> None:
    robot = MujocoRobot()
    assert isinstance(robot, SimulatedRobot) and isinstance(robot, Robot)
    pressed(robot, STEPS)
    assert robot.step_count == STEPS
    force, normal = robot.true_normal_force()
    assert abs(force - PRESS_N) < 0.5, force  # MuJoCo's contact force along its normal is the one asked for
    np.testing.assert_allclose(normal, [0.0, 0.0, -1.0], atol=1e-6)  # into the table
    np.testing.assert_allclose(robot.contact_wrench(), robot.true_contact_wrench())  # the ideal sensor
    q_now = robot.joint_state()[0]
    p, quat = robot.tool_pose()
    target = p + np.array([0.05, -0.03, 0.08])  # inverse kinematics on MuJoCo's kinematics reaches another pose ...
    solution = robot.inverse_kinematics(target, quat)
    np.testing.assert_allclose(robot.joint_state()[0], q_now)  # ... and leaves the state as it was
    robot.set_joint_positions(solution)
    reached, reached_quat = robot.tool_pose()
    np.testing.assert_allclose(reached, target, atol=1e-4)
    assert abs(float(reached_quat @ quat)) > 1.0 - 1e-6
