"""The 1 kHz control loop of an execution: one phase plan at a time, every step sensed, controlled, recorded and
stepped in the simulated world (``execution.executor`` sequences the phases; ``execution.plans`` builds them).

:class:`ControlLoop` owns what every phase shares: the world and the controller, the telemetry rows (one float row
per step, :data:`schemas.execution.TELEMETRY_COLUMNS`, handed to ``on_sample`` in batches), the step count, the
control frames the controller took, and what the last guarded phase found. A phase ends at its last step, on contact
(guarded), on the next surface (a follower), or by an exception: an abort with its reason (force, torque or joint
limit, non-finite values, ``should_abort()``) or a contact lost (pressing into nothing).
World frame, SI units (docs/CONVENTIONS.md).

One control step, flat, for the 1 kHz budget (each Python call and each compiled call's dispatch costs ~0.1-1 µs, as
much as the arithmetic): the world's PyBullet calls made from compiled code through its C API
(``SimWorld.loop_handles``, ``sim_worker.bullet_client``): the joint states and contact points with the arm state, the
contact summary and, for a sampling sensor, its reading in one compiled call (``contact_sensing.sense_client`` at the
top of the step; with a sampling sensor ``sample_client`` right after the physics step, as ``SimWorld.step`` samples
every state), one compiled call for the telemetry row, the law and the world's torque limits
(:func:`_record_and_control`, the law on the phase's ``skills.control.LawKernel``'s buffer), and one for the torque
command and the physics step (``bullet_client.send_torques_and_step``); all through their compiled specializations
(``skills.compiled.compiled_entry``: the arguments' types are the same every step). On a model update (every
:data:`NULL_SPACE_UPDATE_STEPS` steps) and on a new control frame, the kernel refreshes the law first
(``LawKernel.refresh``): the mass matrix and the null-space model in compiled calls with no Python between (a third
one fusing them with the step costs every worker ~9 MB of compiled code for ~1 µs per update), except the update in
``skills.control.DAMPING_UPDATE_EVERY`` that also rebuilds the adaptive damping, and a new frame's gain rows, which
the controller makes in Python.
"""

from __future__ import annotations

import math

import numba
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
from sim_worker.arm_model import arm_mass_matrix
from sim_worker.compiled_calls import state_reader, stepper
from sim_worker.contact_sensing import CONTACT_APPLIED, CONTACT_MEASURED, CONTACT_NORMAL
from sim_worker.world import SimWorld
from skills.compiled import compiled_entry
from skills.control import law_step_packed, layouts

# Layout of the loop's own state array (ControlLoop.run_plan), read and written by its compiled step: the law's output
# (the torque first), the CF rotation of the frame in use (by rows), the torque limits the world clips to, the time
# step, the phase code and segment of the rows.
_S_OUT = 0
_S_CF = _S_OUT + layouts.LAW_OUTPUT_SIZE
_S_LIMITS = _S_CF + 9
_S_DT = _S_LIMITS + 7
_S_PHASE = _S_DT + 1
_S_SEGMENT = _S_PHASE + 1
_S_SIZE = _S_SEGMENT + 1
_NORMAL0 = CONTACT_NORMAL.start
_TWIST0, _TWIST1 = layouts.REFERENCE_TWIST.start, layouts.REFERENCE_TWIST.stop
_FORCE = layouts.REFERENCE_FORCE


@numba.njit(cache=True)
def _record(
    robot, contact, reading_at, touching, state, rows, references, k, paused, n, step_count
):  # pragma: no cover - compiled
    """Telemetry row ``n`` of step ``step_count`` (``execution.telemetry.record_row``) from the arm state ``robot``,
    the contact buffer ``contact`` (its reading at ``reading_at``, the true normal) and the plan's reference row ``k``
    (its twist zero when ``paused``); returns the law's contact flag."""
    reference = references[k]
    if paused:  # hold the reference: zero reference twist
        reference = reference.copy()
        reference[_TWIST0:_TWIST1] = 0.0
    return record_row(
        robot, reference, contact[reading_at : reading_at + 6], state[_S_CF : _S_CF + 9], touching,
        contact[_NORMAL0 : _NORMAL0 + 4], rows, n, step_count * state[_S_DT], state[_S_PHASE], state[_S_SEGMENT],
    )  # fmt: skip


@numba.njit(cache=True)
def _control(
    robot, contact, reading_at, law_buffer, state, references, k, paused, pressing
):  # pragma: no cover - compiled
    """The control law of the step (:func:`law_step_packed`, into the state's output) and the world's torque limits:
    returns the law's code and whether a torque was clipped (the torque clipped in place, as ``SimWorld.step``
    clips what it sends)."""
    reference = references[k]
    if paused:
        reference = reference.copy()
        reference[_TWIST0:_TWIST1] = 0.0
    out = state[_S_OUT : _S_OUT + layouts.LAW_OUTPUT_SIZE]
    code = law_step_packed(law_buffer, robot, reference, contact[reading_at : reading_at + 6], pressing, out)
    clipped = False
    for j in range(7):
        if abs(out[j]) > state[_S_LIMITS + j]:
            clipped = True
    if clipped:
        for j in range(7):
            limit = state[_S_LIMITS + j]
            out[j] = min(max(out[j], -limit), limit)
    return code, clipped


@numba.njit(cache=True)
def _record_and_control(
    robot, contact, reading_at, touching, law_buffer, state, rows, references, k, paused, n, step_count
):  # pragma: no cover - compiled
    """:func:`_record`, then :func:`_control`: a step on the model and frame in use in one compiled call; returns the
    law's contact flag, its code and whether a torque was clipped."""
    pressing = _record(robot, contact, reading_at, touching, state, rows, references, k, paused, n, step_count)
    code, clipped = _control(robot, contact, reading_at, law_buffer, state, references, k, paused, pressing)
    return pressing, code, clipped


@numba.njit(cache=True)
def _outside_limits(q, lower, upper):  # pragma: no cover - compiled
    """Whether a joint of ``q`` is outside [``lower``, ``upper``] (one compiled call: four numpy calls cost ~3 µs)."""
    return (q < lower).any() or (q > upper).any()


class _PhaseState:
    """What the steps of one phase share, set up before its first (:meth:`ControlLoop.run_plan`): the world's handles
    and the views of the arrays the compiled calls write (the same every step), the controller's kernel for the phase,
    the compiled specializations of the step's calls (the same argument types every step: rows grow as the same
    type), the references, the control frame to start from, the guard's window and the phase's checks."""

    def __init__(
        self,
        loop: ControlLoop,
        plan: PhasePlan,
        guard: ContactGuard,
        references: NDArray[np.float64] | None,
        follower: SurfaceFollower | None,
    ) -> None:
        handles, state = loop.handles, loop.state
        self.ids, self.joint_rows = handles.bullet.ids, handles.bullet.joint_rows
        self.model, self.arm, self.contact, self.sensor = handles.model, handles.arm, handles.contact, handles.sensor
        self.ideal, self.draw = handles.ideal, handles.draw
        self.reading_at = CONTACT_APPLIED.start if self.ideal else CONTACT_MEASURED.start
        self.read, self.advance = state_reader(handles), stepper(handles)  # PyBullet from compiled code
        self.robot = self.arm[: layouts.ROBOT_STATE_SIZE]
        self.q, self.p = self.robot[layouts.ROBOT_Q], self.robot[layouts.ROBOT_POSITION]
        self.w = self.contact[self.reading_at : self.reading_at + 6]
        self.out = state[_S_OUT : _S_OUT + layouts.LAW_OUTPUT_SIZE]
        self.tau = self.out[layouts.LAW_TAU]
        self.cf_rows = state[_S_CF : _S_CF + 9].reshape(3, 3)
        state[_S_PHASE], state[_S_SEGMENT] = PHASE_CODES[plan.phase], plan.segment
        self.kernel = loop.controller.kernel(self.robot)
        self.refresh = self.kernel.refresh
        self.references = plan.reference_rows() if references is None else references
        self.batch = loop.telemetry_batch if loop.on_sample is not None else math.inf  # no one to hand rows to
        self.window = guard.window_steps
        self.window_threshold = guard.threshold_n * self.window  # on the sum of the last `window` readings
        self.stop_axis = None if plan.stop_axis is None else plan.stop_axis.tolist()
        if self.stop_axis is not None:
            loop.found_force = None
        self.single = plan.held_frame if follower is None else follower.first_frame()
        self.next_surface = plan.next_z is not None
        self.guard_loss = plan.phase is ExecutionPhase.contact
        self.q_lower, self.q_upper = loop.world.joint_lower, loop.world.joint_upper
        # The arm, contact and reading of the state the loop starts in (a sampling sensor: sampled once, if not yet).
        self.sampled_touching = False if self.ideal else loop.world.sense().in_contact
        self.record_and_control = compiled_entry(
            _record_and_control,
            (self.arm, self.contact, self.reading_at, False, self.kernel.buffer, state, loop.rows, self.references, 0,
             False, loop.n, loop.step_count),
        )  # fmt: skip
        self.mass_of = compiled_entry(arm_mass_matrix, (self.model, self.q))


class ControlLoop(RecordingLoop):
    """Runs phase plans on PyBullet's ``world`` (a ``SimWorld``) with ``controller`` at the world's time step,
    recording every step (the arguments: ``execution.runner.RecordingLoop``)."""

    world: SimWorld

    def _engine_state(self, robot: Robot) -> None:
        """The world and the compiled step's own state."""
        assert isinstance(robot, SimWorld), robot
        self.world = world = robot
        self.handles = world.loop_handles()
        self.state = np.zeros(_S_SIZE)
        """The compiled step's own state (layout ``_S_*``): the law's output, the CF rotation in use, the world's torque
        limits, the time step, the phase and segment recorded."""
        self.state[_S_LIMITS : _S_LIMITS + 7] = self.handles.torque_limits
        self.state[_S_DT] = self.dt

    def run_plan(
        self,
        plan: PhasePlan,
        guard: ContactGuard = UNGUARDED,
        references: NDArray[np.float64] | None = None,
        follower: SurfaceFollower | None = None,
    ) -> PlanEnd:
        """Run a phase (its steps as the module docstring says) and return how it ended: a guarded phase on contact
        (``guard`` on the readings along the plan's stop axis), one with a ``follower`` maybe on the next surface.
        ``references``: the rows of ``plan.reference_rows()``, which the follower rewrites (made when not given).
        Raises ExecutionAbortError, or ContactLostError in a contact phase pressing into nothing."""
        ph = _PhaseState(self, plan, guard, references, follower)
        kernel, references, refresh, read_state, advance = ph.kernel, ph.references, ph.refresh, ph.read, ph.advance
        ids, model, joint_rows, arm, contact, sensor = ph.ids, ph.model, ph.joint_rows, ph.arm, ph.contact, ph.sensor
        robot, q, p, w, tau, reading_at, ideal = ph.robot, ph.q, ph.p, ph.w, ph.tau, ph.reading_at, ph.ideal
        law_buffer, state, record_and_control, mass_of = kernel.buffer, self.state, ph.record_and_control, ph.mass_of
        stop_axis, window, window_threshold = ph.stop_axis, ph.window, ph.window_threshold
        window_readings, window_sum, window_slot = [0.0] * window, 0.0, 0
        touched, frame_log, realtime = self.touched, self.frame_log, self.realtime
        single = current = ph.single
        series, stride, next_frame_step, frame = plan.series, plan.stride, 0, None
        should_abort, should_pause = self.should_abort, self.should_pause
        r02 = r12 = r22 = 0.0
        clipped, sampled_touching, self._tracked = False, ph.sampled_touching, None
        n, rows, capacity, step_count = self.n, self.rows, self.capacity, self.step_count
        first_step, clipped_steps, next_emit = step_count, 0, self.emitted + ph.batch
        try:
            k, steps = 0, plan.steps
            while k < steps:
                # Paused: hold the current reference (zero reference twist), keep controlling, do not advance.
                paused = should_pause is not None and bool(should_pause())  # a bool for the compiled calls
                # This state's arm and contact (a sampling sensor read them after the last step).
                touching = read_state(ids, model, joint_rows, arm, contact) if ideal else sampled_touching
                update_null = step_count % NULL_SPACE_UPDATE_STEPS == 0
                if update_null and _outside_limits(q, ph.q_lower, ph.q_upper):
                    raise ExecutionAbortError(self._joint_limit_reason(q))
                if single is not None:
                    current = single
                elif k >= next_frame_step:  # the series' next frame is due (indexing it costs ~0.3 µs)
                    current = series[k // stride]
                    next_frame_step = (k // stride + 1) * stride
                new_frame = current is not frame
                if new_frame:  # a new control frame: its CF rotation by rows, for the CF wrench
                    frame = current
                    self.cf_rotation = ph.cf_rows[:] = frame.cf_rotation
                    r02, r12, r22 = frame.cf_z.tolist()
                    frame_log.append((n, r02, r12, r22))
                if n >= capacity:
                    rows, capacity = self._grow(n)
                reason = M = None
                if update_null or new_frame:  # the law's model and gains, before the step's row and law
                    M = mass_of(model, q) if update_null and self.dynamic_null else None
                    reason = refresh(frame, robot, references[k], w, M, update_null)
                if reason is None:
                    pressing, code, clipped = record_and_control(
                        arm, contact, reading_at, touching, law_buffer, state, rows, references, k, paused, n,
                        step_count,
                    )  # fmt: skip
                    if code:
                        reason = kernel.abort_reason(code, ph.out, robot, references[k], w, M)
                else:  # the step is recorded, its law not run
                    pressing = _record(robot, contact, reading_at, touching, state, rows, references, k, paused, n,
                                       step_count)  # fmt: skip
                n += 1
                if n >= next_emit:
                    self.n = n
                    self.emit()
                    next_emit = self.emitted + ph.batch
                if reason is not None:
                    raise ExecutionAbortError(reason)
                if stop_axis is not None or follower is not None:
                    fx, fy, fz = w[:3].tolist()  # this step's reading: a sampling sensor overwrites w below
                advance(ids, tau)
                step_count += 1
                clipped_steps += clipped
                if not ideal:  # the sensor samples every state (SimWorld.step): the next state's arm, contact, reading
                    ph.draw()
                    sampled_touching = read_state(ids, model, joint_rows, arm, contact, sensor)
                if should_abort is not None and should_abort():  # every step: stops within one control cycle
                    raise ExecutionAbortError("aborted on request")
                touched = touched or touching
                if stop_axis is not None:  # the mean of the last `window` readings along the axis over the threshold
                    along = fx * stop_axis[0] + fy * stop_axis[1] + fz * stop_axis[2]
                    window_sum += along - window_readings[window_slot]
                    window_readings[window_slot] = along
                    window_slot = (window_slot + 1) % window
                    if window_sum > window_threshold:
                        self.found_force = window_sum / window
                        return PlanEnd.contact
                if follower is not None and follower.due(k):
                    single = self._follow(follower, k, [fx, fy, fz], p.tolist(), step_count, pressing, references)
                    if ph.next_surface and follower.on_next_surface:
                        return PlanEnd.next_surface
                if ph.guard_loss and not touching and references[k, _FORCE] >= CONTACT_LOSS_MIN_PRESS_N:
                    # pressing into nothing? its travel beyond the reference along CF z
                    rx, ry, rz = references[k, :3].tolist()
                    px, py, pz = p.tolist()
                    beyond = (px - rx) * r02 + (py - ry) * r12 + (pz - rz) * r22
                    if beyond > CONTACT_LOSS_TRAVEL_M:
                        self.step_count = step_count
                        raise ContactLostError(self._loss_reason(plan.segment, beyond, touched, guard))
                if realtime and step_count % REALTIME_CHECK_STEPS == 0:
                    self._keep_pace(step_count)
                if not paused:
                    k += 1
        finally:
            self.n, self.step_count = n, step_count
            self.world.loop_ended(step_count - first_step, clipped_steps, clipped)
            self.touched = touched
        return self._ran_to_the_end(plan, guard)
