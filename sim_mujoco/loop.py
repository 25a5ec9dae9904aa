"""The 1 kHz control loop of an execution on MuJoCo (:class:`MujocoLoop`, an ``execution.runner.PhaseRunner``): one
phase plan at a time on a :class:`~sim_mujoco.robot.MujocoRobot`, every step sensed, controlled, recorded and stepped,
as PyBullet's ``sim_worker.control_loop.ControlLoop`` does it, in plain Python (docs/ENGINES.md, "Speed").

The same law through the same door: the phase's ``skills.control.LawKernel`` (``HybridController.kernel``) refreshed
on a model update (every ``NULL_SPACE_UPDATE_STEPS`` steps, the mass matrix with the dynamic null space) and on a new
control frame, then ``skills.control.law_step_packed`` on its buffer with the robot state in the law's layout
(``MujocoRobot.robot_state``); the same telemetry row (``execution.telemetry.record_row``), with the same truth: the
true normal force and normal, and the contact flag, of MuJoCo's contacts of the forces that drove the last step
(``sim_mujoco.sensing.true_contact``, computed as PyBullet's from its contact points). The same phase ends: the guarded
approach's window on the reading along the stop axis, the follower's next surface, the contact lost in a contact phase,
the joint limits, ``should_abort()`` after every step, ``should_pause()`` before. World frame, SI units
(docs/CONVENTIONS.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from execution.contact_detection import ContactGuard
from execution.plans import PhasePlan
from execution.robot import Robot
from execution.runner import (
    CONTACT_LOSS_MIN_PRESS_N,
    CONTACT_LOSS_TRAVEL_M,
    NULL_SPACE_UPDATE_STEPS,
    REALTIME_CHECK_STEPS,
    UNGUARDED,
    ContactLostError,
    ExecutionAbortError,
    PlanEnd,
    RecordingLoop,
)
from execution.surface_following import SurfaceFollower
from execution.telemetry import record_row
from schemas.execution import PHASE_CODES, ExecutionPhase
from sim_mujoco.robot import MujocoRobot
from skills.control import law_step_packed
from skills.control.layouts import LAW_OUTPUT_SIZE, LAW_TAU, REFERENCE_FORCE, REFERENCE_TWIST, ROBOT_POSITION, ROBOT_Q


class MujocoLoop(RecordingLoop):
    """Runs phase plans on MuJoCo's ``robot`` (a ``MujocoRobot``) with ``controller`` at the robot's time step,
    recording every step (the arguments: ``execution.runner.RecordingLoop``, as PyBullet's ``ControlLoop``)."""

    robot: MujocoRobot

    def _engine_state(self, robot: Robot) -> None:
        """The robot and the step's buffers."""
        assert isinstance(robot, MujocoRobot), robot
        self.robot = robot
        self._out = np.zeros(LAW_OUTPUT_SIZE)
        """The law's output of the step (the torque first)."""
        self._cf_rows = np.zeros(9)
        """The CF rotation in use by rows, for the row's CF wrench."""
        self._truth = np.zeros(4)
        """The true normal force (N) and normal of the step, for its row."""

    def run_plan(
        self,
        plan: PhasePlan,
        guard: ContactGuard = UNGUARDED,
        references: NDArray[np.float64] | None = None,
        follower: SurfaceFollower | None = None,
    ) -> PlanEnd:
        """Run a phase and return how it ended (as ``ControlLoop.run_plan``): a guarded phase on contact (``guard`` on
        the readings along the plan's stop axis), one with a ``follower`` maybe on the next surface. ``references``:
        the rows of ``plan.reference_rows()``, which the follower rewrites (made when not given). Raises
        ExecutionAbortError, or ContactLostError in a contact phase pressing into nothing."""
        robot, out, truth, cf_rows, dt = self.robot, self._out, self._truth, self._cf_rows, self.dt
        state = robot.robot_state()  # the same array every step
        kernel = self.controller.kernel(state)
        references = plan.reference_rows() if references is None else references
        phase_code, segment = float(PHASE_CODES[plan.phase]), float(plan.segment)
        batch = self.telemetry_batch if self.on_sample is not None else np.inf
        stop_axis = None if plan.stop_axis is None else np.asarray(plan.stop_axis, dtype=float)
        if stop_axis is not None:
            self.found_force = None
        window = guard.window_steps
        window_readings, window_sum, window_slot = np.zeros(window), 0.0, 0
        window_threshold = guard.threshold_n * window  # on the sum of the last `window` readings
        single = current = plan.held_frame if follower is None else follower.first_frame()
        series, stride, next_frame_step, frame = plan.series, plan.stride, 0, None
        guard_loss, next_surface = plan.phase is ExecutionPhase.contact, plan.next_z is not None
        cf_z = np.zeros(3)
        self._tracked = None
        n, step_count, touched = self.n, self.step_count, self.touched
        next_emit = self.emitted + batch
        try:
            k = 0
            while k < plan.steps:
                paused = self.should_pause is not None and bool(self.should_pause())
                state = robot.robot_state()
                wrench = robot.contact_wrench()
                contact = robot.true_contact()
                touching = contact.in_contact
                update = step_count % NULL_SPACE_UPDATE_STEPS == 0
                q = state[ROBOT_Q]
                if update and ((q < self.joint_lower).any() or (q > self.joint_upper).any()):
                    raise ExecutionAbortError(self._joint_limit_reason(q))
                if single is not None:
                    current = single
                elif k >= next_frame_step:  # the series' next frame is due
                    current = series[k // stride]
                    next_frame_step = (k // stride + 1) * stride
                new_frame = current is not frame
                if new_frame:  # a new control frame: its CF rotation by rows, for the CF wrench
                    frame = current
                    self.cf_rotation = frame.cf_rotation
                    cf_rows[:] = frame.cf_rotation.ravel()
                    cf_z[:] = frame.cf_z
                    self.frame_log.append((n, *cf_z.tolist()))
                if n >= self.capacity:
                    self._grow(n)
                reference = references[k]
                if paused:  # hold the current reference: zero reference twist
                    reference = reference.copy()
                    reference[REFERENCE_TWIST] = 0.0
                reason = mass = None
                if update or new_frame:  # the law's model and gains, before the step's row and law
                    mass = robot.mass_matrix() if update and self.dynamic_null else None
                    reason = kernel.refresh(frame, state, references[k], wrench, mass, update)
                truth[0], truth[1:] = contact.normal_force_n, contact.normal
                pressing = record_row(state, reference, wrench, cf_rows, touching, truth, self.rows, n,
                                      step_count * dt, phase_code, segment)  # fmt: skip
                if reason is None:
                    code = law_step_packed(kernel.buffer, state, reference, wrench, pressing, out)
                    if code:
                        reason = kernel.abort_reason(code, out, state, references[k], wrench, mass)
                n += 1
                if n >= next_emit:
                    self.n = n
                    self.emit()
                    next_emit = self.emitted + batch
                if reason is not None:
                    raise ExecutionAbortError(reason)
                position = state[ROBOT_POSITION].copy()  # this step's, before the robot moves on
                robot.step(out[LAW_TAU])
                step_count += 1
                if self.should_abort is not None and self.should_abort():  # stops within one control cycle
                    raise ExecutionAbortError("aborted on request")
                touched = touched or touching
                if stop_axis is not None:  # the mean of the last `window` readings along the axis over the threshold
                    along = float(wrench[:3] @ stop_axis)
                    window_sum += along - window_readings[window_slot]
                    window_readings[window_slot] = along
                    window_slot = (window_slot + 1) % window
                    if window_sum > window_threshold:
                        self.found_force = window_sum / window
                        return PlanEnd.contact
                if follower is not None and follower.due(k):
                    force, p_now = wrench[:3].tolist(), position.tolist()
                    single = self._follow(follower, k, force, p_now, step_count, pressing, references)
                    if next_surface and follower.on_next_surface:
                        return PlanEnd.next_surface
                if guard_loss and not touching and references[k, REFERENCE_FORCE] >= CONTACT_LOSS_MIN_PRESS_N:
                    # pressing into nothing? its travel beyond the reference along CF z
                    beyond = float((position - references[k, :3]) @ cf_z)
                    if beyond > CONTACT_LOSS_TRAVEL_M:
                        self.step_count = step_count
                        raise ContactLostError(self._loss_reason(plan.segment, beyond, touched, guard))
                if self.realtime and step_count % REALTIME_CHECK_STEPS == 0:
                    self._keep_pace(step_count)
                if not paused:
                    k += 1
        finally:
            self.n, self.step_count, self.touched = n, step_count, touched
        return self._ran_to_the_end(plan, guard)
