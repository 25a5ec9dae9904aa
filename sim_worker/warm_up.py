"""Compile (or load from numba's on-disk cache) every compiled function of the control loop once.

Run as ``contact-skills warm-up`` after installing or changing the code (``make run``, ``make test`` and the Docker
image do; the command imports PyBullet without its banner first): the first compile takes tens of seconds and holds
the interpreter, so a worker or learner process that met it inside a request would miss its deadline; afterwards each
new process loads the compiled code from the cache in well under a second.
"""

from __future__ import annotations

import time

import numpy as np

from execution.plans import PhasePlan
from execution.telemetry import record_row
from schemas.execution import PHASE_CODES, TELEMETRY_WIDTH, ExecutionPhase, Pace
from schemas.skill import SELECTION_CONTACT
from schemas.world import WorldConfig
from sim_worker.control_loop import ControlLoop
from sim_worker.sensor import WRIST_SENSOR
from sim_worker.world import SimWorld
from skills.control import HybridController, damping_matrix, pose_error
from skills.control.layouts import REFERENCE_SIZE, ROBOT_POSITION, ROBOT_QUAT
from skills.dmp import DMP
from skills.quaternion_dmp import QuaternionDMP


def warm_up() -> float:
    """Run each compiled function once on a real world (arm model, contact summary, control law, model update, the
    loop's step, the wrist sensor, the orientation and position DMPs' rollouts); return the seconds it took."""
    start = time.perf_counter()
    for config in (WorldConfig(), WorldConfig(sensor=WRIST_SENSOR)):  # 7 joints read; the wrist's 8 and its sampling
        with SimWorld(config) as world:
            _hold(world)
    with SimWorld(WorldConfig(sensor=WRIST_SENSOR)) as world:  # the wrist sensor's compiled parts too
        world.contact_wrench()
        robot = world.robot_state()
        mass = world.mass_matrix()
        controller = HybridController(posture=world.joint_state()[0], torque_limits=world.torque_limits)
        frame = controller.frame(np.diag([1.0, -1.0, -1.0]), SELECTION_CONTACT)
        reference = np.zeros(REFERENCE_SIZE)
        reference[:7] = robot[ROBOT_POSITION.start : ROBOT_QUAT.stop]  # hold the current pose
        controller.step(frame, robot, reference, np.zeros(6), True, mass, True)
        controller.step(frame, robot, reference, np.zeros(6), True, None, True)
        rows = np.zeros((1, TELEMETRY_WIDTH))
        phase = float(PHASE_CODES[ExecutionPhase.contact])
        record_row(robot, reference, np.zeros(6), np.eye(3).ravel(), True, np.zeros(4), rows, 0, 0.0, phase, 0.0)
    quaternions = np.tile([0.0, 0.0, 0.0, 1.0], (11, 1))
    QuaternionDMP.fit(np.arange(11) * 0.01, quaternions).rollout(0.01)
    DMP.fit(np.arange(11) * 0.01, np.zeros((11, 3))).rollout(0.01)
    pose_error(np.zeros(3), [0.0, 0.0, 0.0, 1.0], np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    damping_matrix(np.eye(6), np.eye(6), 1.0)
    return time.perf_counter() - start


HOLD_STEPS = 50
"""Control steps of :func:`_hold`: past a model update (every 20), so each compiled call of a step runs."""


def _hold(world: SimWorld) -> None:
    """Run the control loop on ``world`` for :data:`HOLD_STEPS` steps holding the tool where it is: the loop's own
    compiled calls (``ControlLoop.run_plan``: the arm and contact read from PyBullet's tuples, the row, the law and
    the limits, a sampling sensor's reading)."""
    controller = HybridController(posture=world.joint_state()[0], torque_limits=world.torque_limits)
    frame = controller.frame(np.eye(3), np.ones(6))
    p, q = world.tool_pose()
    plan = PhasePlan(ExecutionPhase.free, -1, np.tile(p, (HOLD_STEPS, 1)), np.tile(q, (HOLD_STEPS, 1)),
                     np.zeros((HOLD_STEPS, 6)), np.zeros(HOLD_STEPS), frame=frame)  # fmt: skip
    ControlLoop(world, controller, 1.0, 100, Pace.fast, True, None, None, None).run_plan(plan)
