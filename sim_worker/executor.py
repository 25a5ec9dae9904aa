"""Execute a learned skill in the simulated world with the hybrid controller (the paper's section 6).

``execute_skill(skill, world_config, settings)`` builds a ``SimWorld`` (the taught world plus the
known and the unknown offset of the work piece), puts the robot at the skill's start (IK +
settle) and runs the segments at 1 kHz:

- **free** segment: position and orientation DMPs rolled out from the CURRENT tool pose to the
  (known-offset-shifted) goal, ``S = I``. A free segment followed by a contact segment ends
  ``approach_clearance_m`` before the taught contact point (back along CF z) and is guarded: a
  contact force along the next CF z ends it early.
- **tare** (``tare_sensor``, a non-ideal sensor): at the end of the settle at the start pose, and in a 0.2 s still
  hold at the pre-contact point before each later approach, the wrist sensor is tared with its mean reading
  (tool frame), so a sensor offset does not read as a touch-down in free space.
- **approach** (before a contact segment that follows a free one): the reference moves along
  +CF z at ``approach_speed_m_s`` (impedance, ``S = I``) until the measured CF-z force exceeds
  the contact threshold (abort "contact not found" after ``approach_max_distance_m``); then,
  with the contact segment's frame and selection, the desired force ramps from the measured
  one to the segment's first desired force over ``force_ramp_s`` while the tool holds its place.
- **contact** segment: slide: the position DMP runs in the (shifted) CF x-y plane from the
  current CF x-y position, the force is the learned constant; contour: the position DMP runs in
  the world, the CF is the stored frame series slerped by time fraction and shifted, the force
  is the rolled-out force DMP. Consecutive contact segments follow each other directly, the
  desired force ramping between their levels over ``force_ramp_s``.
- **retreat**: after a contact segment followed by a free one (or the end), the desired force
  ramps down to zero over ``force_release_s`` before the free segment lifts off.

The reference CF-z coordinate of a slide path is where the surface was FOUND (hybrid kinds; it
only matters for ``hybrid_world_z``, whose motion axes are world x-y) or where it was TAUGHT
(``impedance``, which presses only through its reference).

Every control step is recorded as one row of a float array (see :data:`schemas.execution.TELEMETRY_COLUMNS`) and
handed to ``on_sample`` in batches of ``telemetry_batch`` rows (a :class:`Telemetry` view).
Aborts (force limit, torque limit, joint limit, contact not found, non-finite values, ``should_abort()``)
stop the loop cleanly and are reported in the metrics; nothing is ever NaN.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numba
import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import Demonstration
from schemas.execution import (
    PHASE_CODES,
    TELEMETRY_COLUMNS,
    TELEMETRY_WIDTH,
    ControllerKind,
    ExecutionMetrics,
    ExecutionPhase,
    ExecutionSettings,
    NullSpaceProjection,
    Pace,
    SurfaceWindowAction,
)
from schemas.skill import Segment, SegmentKind, Skill
from sim_worker.contact_detection import (
    IDEAL_WINDOW_STEPS,
    WINDOW_STEPS,
    ContactGuard,
    contact_guard_from_readings,
    turned_offset_bound_n,
)
from sim_worker.execution_world import ExecutionWorld
from sim_worker.metrics import ExecutionLog, compute_metrics, reference_force
from sim_worker.plans import PhasePlan, PhasePlanner, first_force, smooth_ramp
from sim_worker.telemetry import Telemetry
from sim_worker.world import SimWorld
from sim_worker.world_config import WorldConfig
from skills.control import (
    LAW_OUTPUT_SIZE,
    LAW_TAU,
    REFERENCE_FORCE,
    REFERENCE_TWIST,
    ROBOT_POSITION,
    ControlFrame,
    HybridController,
)
from skills.frames import rotation_from_vectors
from skills.job_estimate import SURFACE_WINDOW_MIN_M, TARE_HOLD_S, TOUCHDOWN_SPEED_MIN_M_S
from skills.normal_tracking import SurfaceNormalTracker
from skills.quaternions import matrix_from_quaternion

NULL_SPACE_UPDATE_STEPS = 20
"""The null-space projector (and the mass matrix it needs) is refreshed every this many steps."""
TOUCHDOWN_IMPACT_FRACTION = 0.8
"""The touch-down speed keeps the impact below this fraction of the first target force: the impact comes before the
desired force ramps up, so the touch-down peak is then the target itself."""
TARE_AVERAGE_S = 0.1
"""The tare is the mean reading over the last this long of the still hold (``TARE_HOLD_S``), s."""
NOISE_WINDOW_S = 0.15
"""The sensor's noise along the next approach is measured over the last this long of a still hold, s (its first
moments still carry the deceleration the tool's inertia shows)."""
CONTACT_LOSS_TRAVEL_M = 0.01
"""In a contact phase, the tool out of contact and this far beyond its reference along CF z has lost the surface
(an edge, a hole): it stops pressing into nothing, retracts and the execution aborts with the reason, m."""
CONTACT_LOSS_RETRACT_M = 0.05
"""How far the tool backs off along -CF z after losing the surface, m (over ``CONTACT_LOSS_RETRACT_S``)."""
CONTACT_LOSS_RETRACT_S = 1.0
CREASE_IMPACT_FRACTION = 0.1
"""The impact at a crease, as a fraction of the press, that sets the speed to pass it (see ``_crease_speed``)."""
CREASE_MIN_ANGLE_RAD = math.radians(3.0)
"""Segments whose CF z differ by less are passed at full speed."""
NORMAL_TRACKING_STEPS = 10
"""With ``follow_surface_normal``, the CF follows the estimated normal every this many steps."""
REALTIME_CHECK_STEPS = 10
"""With pace realtime, the loop sleeps to follow the wall clock every this many steps."""


# Telemetry columns (schemas.execution.TELEMETRY_COLUMNS) and arm state entries, as plain ints for the compiled step.
_C_T, _C_PHASE, _C_SEGMENT = (TELEMETRY_COLUMNS[c].start for c in ("t", "phase", "segment_index"))
_C_POSE = TELEMETRY_COLUMNS["tool_position"].start  # position then orientation
_C_REFERENCE = TELEMETRY_COLUMNS["reference_position"].start  # position then orientation
_C_WRENCH, _C_WRENCH_CF = TELEMETRY_COLUMNS["wrench_world"].start, TELEMETRY_COLUMNS["wrench_cf"].start
_C_DESIRED, _C_CONTACT = TELEMETRY_COLUMNS["desired_force_cf_z_n"].start, TELEMETRY_COLUMNS["in_contact"].start
_C_TRUE_NORMAL = TELEMETRY_COLUMNS["normal_force_true_n"].start  # force then the normal (3)
_R_POSE = ROBOT_POSITION.start  # position then quaternion


@numba.njit(cache=True)
def _record_row(
    robot, reference, wrench, cf_rotation, in_contact, normal, rows, n, t, phase, segment
):  # pragma: no cover - compiled
    """Telemetry row ``n`` of ``rows`` for one control step, in one compiled call (:data:`TELEMETRY_COLUMNS`: the
    state measured before the step, its reference and desired force, the measured wrench in world and CF axes
    (``R^T f``, ``R^T m``, ``cf_rotation`` (9,) by rows), the true normal force and direction ``normal`` (4,)).
    Returns the control law's contact flag: the CF-z force above half the desired one, at most 0.5 N."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
        cf_rotation[0], cf_rotation[1], cf_rotation[2], cf_rotation[3], cf_rotation[4], cf_rotation[5],
        cf_rotation[6], cf_rotation[7], cf_rotation[8],
    )  # fmt: skip
    fx, fy, fz, mx, my, mz = wrench[0], wrench[1], wrench[2], wrench[3], wrench[4], wrench[5]
    row = rows[n]
    row[_C_T], row[_C_PHASE], row[_C_SEGMENT] = t, phase, segment
    for i in range(7):  # tool pose (position, quaternion); reference pose, the same layout
        row[_C_POSE + i] = robot[_R_POSE + i]
        row[_C_REFERENCE + i] = reference[i]
    for i in range(6):
        row[_C_WRENCH + i] = wrench[i]
    cf = _C_WRENCH_CF
    row[cf] = fx * r00 + fy * r10 + fz * r20
    row[cf + 1] = fx * r01 + fy * r11 + fz * r21
    row[cf + 2] = fx * r02 + fy * r12 + fz * r22
    row[cf + 3] = mx * r00 + my * r10 + mz * r20
    row[cf + 4] = mx * r01 + my * r11 + mz * r21
    row[cf + 5] = mx * r02 + my * r12 + mz * r22
    f_des = reference[REFERENCE_FORCE]
    row[_C_DESIRED] = f_des
    row[_C_CONTACT] = 1.0 if in_contact else 0.0
    for i in range(4):  # the true normal force and the normal
        row[_C_TRUE_NORMAL + i] = normal[i]
    return row[cf + 2] > min(0.5, 0.5 * f_des)


class PlanEnd(Enum):
    """How a phase plan ended (:meth:`_Execution.run_plan`)."""

    done = "done"
    """It ran to its last step."""
    contact = "contact"
    """A guarded phase met a surface (:class:`ContactGuard`)."""


class ContactLostError(Exception):
    """Raised inside the loop when the tool lost the surface in a contact phase (it is retracted, then aborted)."""


class ExecutionAbortError(Exception):
    """Raised inside the loop to stop the execution with a reason."""

    def __init__(self, reason: str, phase: ExecutionPhase = ExecutionPhase.aborted) -> None:
        super().__init__(reason)
        self.reason = reason
        self.phase = phase


@dataclass
class ExecutionResult:
    """What ``execute_skill`` returns: the metrics, the recorded telemetry and how long things took."""

    metrics: ExecutionMetrics
    telemetry: Telemetry
    world_config: WorldConfig
    """The simulated world (the taught one plus the known and unknown offsets)."""
    setup_s: float
    """Wall time to build the world, solve IK and precompute before the loop, s."""
    loop_wall_s: float
    """Wall time of the control loop, s."""
    loop_cpu_s: float = 0.0
    """CPU time of the control loop's thread, s (on a loaded machine the wall time also counts other processes')."""
    timings_us: dict[str, float] = field(default_factory=dict)
    """Mean per-step wall time of the loop's parts, µs (physics, sensing, dynamics, control, telemetry, ...)."""

    @property
    def phase(self) -> ExecutionPhase:
        return self.metrics.phase

    @property
    def abort_reason(self) -> str | None:
        return self.metrics.abort_reason


# ---------------------------------------------------------------------------------------------------------------
# World and skill geometry
# ---------------------------------------------------------------------------------------------------------------


def shifted_world_config(config: WorldConfig, offset: list[float] | NDArray[np.float64]) -> WorldConfig:
    """Return ``config`` with its work piece moved by ``offset`` [dx, dy, dz] (m, world).

    The work piece is the rebuilt one (``work_pieces``) when the world has one, else the contour object(s)
    (cylinder, curved block) when it has any, else the table (with its ramp): the table centre and height move,
    so the table top plane moves by ``offset``. The pivot of an unknown tilt moves with it.
    """
    d = np.asarray(offset, dtype=float)
    if not np.any(d):
        return config
    config = config.replace(work_piece_tilt_pivot_m=tuple((np.asarray(config.work_piece_tilt_pivot_m) + d).tolist()))
    if config.work_pieces:
        moved = [{**piece, "vertices": (np.asarray(piece["vertices"]) + d).tolist()} for piece in config.work_pieces]
        return config.replace(work_pieces=moved)
    if config.cylinder_enabled or config.block_enabled:
        changes = {}
        if config.cylinder_enabled:
            changes["cylinder_offset_m"] = tuple((np.asarray(config.cylinder_offset_m) + d).tolist())
        if config.block_enabled:
            changes["block_offset_m"] = tuple((np.asarray(config.block_offset_m) + d).tolist())
        return config.replace(**changes)
    cx, cy = config.table_center_xy
    return config.replace(table_center_xy=(cx + d[0], cy + d[1]), table_height_m=config.table_height_m + d[2])


# ---------------------------------------------------------------------------------------------------------------
# The executor
# ---------------------------------------------------------------------------------------------------------------


class _Execution:
    def __init__(
        self,
        skill: Skill,
        world_config: WorldConfig,
        settings: ExecutionSettings,
        on_sample: Callable[[Telemetry], None] | None,
        should_abort: Callable[[], bool] | None,
        should_pause: Callable[[], bool] | None = None,
    ) -> None:
        self.skill = skill
        self.settings = settings
        self.on_sample = on_sample
        self.should_abort = should_abort
        self.should_pause = should_pause
        env = settings.environment
        self.offset = np.asarray(env.offset, dtype=float)
        self.world_config = shifted_world_config(world_config, self.offset + np.asarray(env.unknown_offset, float))
        self.world = SimWorld(self.world_config)
        self.dt = float(self.world_config.time_step_s)
        gains = settings.gains
        self.kind = ControllerKind(settings.controller)
        self.controller = HybridController(self.kind, gains, dt=self.dt, torque_limits=self.world.torque_limits)
        self._dynamic_null = gains.null_space is NullSpaceProjection.dynamic
        self.reference_force = reference_force(skill, self.dt)
        if gains.contact_force_threshold_n is not None:
            self.contact_threshold = float(gains.contact_force_threshold_n)
        else:
            self.contact_threshold = float(np.clip(0.1 * self.reference_force, 1.0, 3.0))
        self.tares = settings.tare_sensor and not self.world.sensor.ideal
        """Whether the sensor is tared in free space before the guarded approaches (an ideal sensor has no offset)."""
        window = IDEAL_WINDOW_STEPS if self.world.sensor.ideal else WINDOW_STEPS[0]
        self.guard = ContactGuard(self.contact_threshold, window)
        """When a guarded approach has met the surface; set from the noise measured in each still hold."""
        self.tare_rotation = np.eye(3)
        """The tool's orientation (world from tool) at the last tare."""
        self.found_force: float | None = None
        """The windowed reading along the stop axis when the last guarded phase met a surface, N."""
        self.touched = False
        """Whether the tool has touched anything (the simulator's contact) since the last guarded approach began."""
        self.frame_log: list[tuple[int, float, float, float]] = []
        """(telemetry row, CF z) each time the controller took a new control frame: the frames it actually used."""
        self.planner = PhasePlanner(skill, settings, self.controller, self.offset, self.dt)
        self.geometry = self.planner.geometry
        self._cf_rotation = np.eye(3)
        self._selection = {s.index: s.selection for s in skill.segments}
        """The CF rotation of the control frame in use (world from CF)."""
        # Recording.
        # Room for the segments and a few seconds of settle, approach and retreat, so the rows rarely grow.
        planned_s = sum(segment.position_dmp.duration_s for segment in skill.segments) + 5.0
        self.capacity = max(4096, round(planned_s / self.dt))
        self.rows = np.zeros((self.capacity, TELEMETRY_WIDTH))
        self.n = 0
        self.emitted = 0
        self.step_count = 0
        self.contact_offsets: list[float] = []
        self.timing = [0.0] * 5  # sensing, dynamics, control law, physics step, telemetry (s, summed)

    # -------------------------------------------------------------------------------------- the loop

    def _grow(self) -> None:
        self.capacity *= 2
        rows = np.zeros((self.capacity, TELEMETRY_WIDTH))
        rows[: self.n] = self.rows[: self.n]
        self.rows = rows

    def _emit(self, final: bool = False) -> None:
        pending = self.n - self.emitted
        if self.on_sample is not None and pending > 0 and (final or pending >= self.settings.telemetry_batch):
            self.on_sample(Telemetry(self.rows[self.emitted : self.n].copy()))
            self.emitted = self.n

    def run_plan(self, plan: PhasePlan, guard: ContactGuard | None = None) -> PlanEnd:
        """Run a phase; return how it ended (a guarded phase ends on contact: ``guard``, default ``self.guard``, on
        the readings along the plan's stop axis). Raises ExecutionAbortError.

        One control step: sensing (``SimWorld.sense``: the joint state and the contact points, two PyBullet
        queries; tool pose, Jacobian and gravity/Coriolis from the arm's compiled model into the world's arm
        state array, used without copies), the mass matrix on model-update steps, the control law (one compiled
        call on the arm state and the plan's packed reference row, ``HybridController.step``), one telemetry
        row, the physics step; each part is timed (``self.timing``). The loop is written for the 1 kHz budget,
        where each numpy call on a 3- to 7-vector costs ~0.5 µs of overhead: the wrench in CF axes and the
        telemetry row are plain float arithmetic, written into the row array in one assignment.
        """
        world = self.world
        sense, dynamics, step = world.sense, world.dynamics, world.step
        # The arm state and the true normal force: the world's arrays, the same every step, updated by sense().
        robot, true_normal = world.robot_state(), world.true_normal_state()
        controller = self.controller
        step_into = controller.step_into
        out = np.zeros(LAW_OUTPUT_SIZE)
        tau = out[LAW_TAU]
        perf = time.perf_counter
        dt = self.dt
        phase_code = float(PHASE_CODES[plan.phase])
        guard_loss = plan.phase is ExecutionPhase.contact
        loss_travel = CONTACT_LOSS_TRAVEL_M
        seg = float(plan.segment)
        ts = td = tc = tp = tt = 0.0
        batch = self.settings.telemetry_batch if self.on_sample is not None else math.inf  # no one to hand rows to
        realtime = self.settings.pace is Pace.realtime
        guard = guard or self.guard
        window = guard.window_steps
        window_threshold = guard.threshold_n * window  # on the sum of the last `window` readings
        window_readings, window_sum, window_slot = [0.0] * window, 0.0, 0
        touched = self.touched
        frame_log = self.frame_log
        stop_axis = None if plan.stop_axis is None else plan.stop_axis.tolist()
        if stop_axis is not None:
            self.found_force = None
        single = plan.frame
        series, stride = plan.series, plan.stride
        ref_p = plan.ref_p
        # One row per step in the law's reference layout (position, quaternion, twist, desired force).
        references = np.concatenate((plan.ref_p, plan.ref_q, plan.ref_twist, plan.force[:, None]), axis=1)
        dynamic_null = self._dynamic_null
        q_lower, q_upper = world.joint_lower, world.joint_upper
        should_abort, should_pause = self.should_abort, self.should_pause
        frame: ControlFrame | None = None
        current = single
        next_frame_step = 0  # the step at which the series' next frame is due (indexing it costs ~0.3 µs)
        cf_rotation = np.eye(3).ravel()
        r02 = r12 = r22 = 0.0
        tracker = self._normal_tracker(plan)
        p_tracked: list[float] | None = None
        try:
            k, steps = 0, plan.steps
            while k < steps:
                # Paused: hold the current reference (zero reference twist), keep controlling, do not advance.
                paused = should_pause is not None and should_pause()
                t0 = perf()
                q, _, p, _, w, touching = sense()
                t1 = perf()
                update_null = self.step_count % NULL_SPACE_UPDATE_STEPS == 0
                M = dynamics(True).mass_matrix if update_null and dynamic_null else None
                if update_null and ((q < q_lower).any() or (q > q_upper).any()):
                    raise ExecutionAbortError(self._joint_limit_reason(q))
                t2 = perf()
                if single is not None:
                    current = single
                elif k >= next_frame_step:
                    current = series[k // stride]
                    next_frame_step = (k // stride + 1) * stride
                new_frame = current is not frame
                if new_frame:  # a new control frame: its CF rotation by rows, for the CF wrench
                    frame = current
                    self._cf_rotation = frame.cf_rotation
                    cf_rotation = np.ascontiguousarray(frame.cf_rotation).ravel()
                    r02, r12, r22 = frame.cf_z.tolist()
                    frame_log.append((self.n, r02, r12, r22))
                reference = references[k]
                if paused:
                    reference = reference.copy()
                    reference[REFERENCE_TWIST] = 0.0
                # One compiled call records the telemetry row (the state measured before the step, its reference and
                # desired force, the CF wrench), one runs the law (its model and gain updates on a model step or a
                # new frame).
                if self.n >= self.capacity:
                    self._grow()
                pressing = _record_row(
                    robot, reference, w, cf_rotation, touching, true_normal, self.rows, self.n, self.step_count * dt,
                    phase_code, seg,
                )  # fmt: skip
                self.n += 1
                reason = step_into(frame, robot, reference, w, pressing, M, update_null, out)
                t3 = perf()
                if self.n - self.emitted >= batch:
                    self._emit()
                t4 = perf()
                if reason is not None:
                    raise ExecutionAbortError(reason)
                if stop_axis is not None or tracker is not None:
                    fx, fy, fz = w[:3].tolist()  # this step's reading: the step below overwrites w
                step(tau)
                self.step_count += 1
                t5 = perf()
                ts += t1 - t0
                td += t2 - t1
                tc += t3 - t2
                tt += t4 - t3
                tp += t5 - t4
                if should_abort is not None and should_abort():  # every step: stops within one control cycle
                    raise ExecutionAbortError("aborted on request")
                if touching:
                    touched = True
                if stop_axis is not None:  # the mean of the last `window` readings along the axis over the threshold
                    along = fx * stop_axis[0] + fy * stop_axis[1] + fz * stop_axis[2]
                    window_sum += along - window_readings[window_slot]
                    window_readings[window_slot] = along
                    window_slot = (window_slot + 1) % window
                    if window_sum > window_threshold:
                        self.found_force = window_sum / window
                        return PlanEnd.contact
                if tracker is not None and k % NORMAL_TRACKING_STEPS == 0:
                    p_now = p.tolist()
                    if p_tracked is not None:
                        span = NORMAL_TRACKING_STEPS * dt
                        velocity = [(a - b) / span for a, b in zip(p_now, p_tracked, strict=True)]
                        z_new = tracker.update([fx, fy, fz], velocity)
                        if z_new @ frame.cf_rotation[:, 2] < 1.0 - 1e-10:
                            turned = rotation_from_vectors(frame.cf_rotation[:, 2], z_new) @ frame.cf_rotation
                            single = self.controller.frame(turned, self._selection[plan.segment])
                    p_tracked = p_now
                if guard_loss and not touching:  # pressing into nothing? its travel beyond the reference along CF z
                    rx, ry, rz = ref_p[k].tolist()
                    px, py, pz = p.tolist()
                    beyond = (px - rx) * r02 + (py - ry) * r12 + (pz - rz) * r22
                    if beyond > loss_travel:
                        raise ContactLostError(self._loss_reason(plan.segment, beyond, touched))
                if realtime and self.step_count % REALTIME_CHECK_STEPS == 0:
                    lag = self.step_count * dt - (perf() - self.wall_start)
                    if lag > 0:
                        time.sleep(lag)
                if not paused:
                    k += 1
        finally:
            self.touched = touched
            timing = self.timing
            timing[0] += ts
            timing[1] += td
            timing[2] += tc
            timing[3] += tp
            timing[4] += tt
        if plan.exhausted_reason is not None:
            guarded = "" if stop_axis is None else f": the sensor never read above {guard.describe()}"
            raise ExecutionAbortError(plan.exhausted_reason + guarded)
        return PlanEnd.done

    def _loss_reason(self, segment: int, beyond_m: float, touched: bool) -> str:
        """Why a contact phase stopped pressing into nothing ``beyond_m`` past its reference: the surface was lost,
        or, when the tool never touched anything since its guarded approach began, never made (the approach took a
        reading for the surface)."""
        t = f"t = {self.step_count * self.dt:.3f} s"
        retracted = f"the tool stopped pressing and retracted {CONTACT_LOSS_RETRACT_M * 1e3:.0f} mm"
        if not touched:
            found = "" if self.found_force is None else f" (it read {self.found_force:.2f} N)"
            return (
                f"no contact made in segment {segment} at {t}: the guarded approach stopped on a reading of the "
                f"sensor above {self.guard.describe()}{found} without touching anything (a sensor offset or noise "
                f"the tare did not remove?), and the tool found nothing {beyond_m * 1e3:.0f} mm beyond; {retracted}"
            )
        return (
            f"contact lost in segment {segment} at {t}: no contact {beyond_m * 1e3:.0f} mm beyond the surface along "
            f"CF z (an edge or a hole?); {retracted}"
        )

    def _after_still_hold(self, axis: NDArray[np.float64] | None) -> None:
        """At the end of a still hold in free space: tare the sensor (``self.tares``) and set the contact guard of the
        next guarded approach along ``axis`` (world, unit; None: no approach follows) from the noise its readings
        showed over the last ``NOISE_WINDOW_S`` (a non-ideal sensor; the ideal one keeps the base threshold)."""
        if self.tares:
            self._tare_sensor()
        if axis is not None and not self.world.sensor.ideal:
            rows = self.rows[max(0, self.n - round(NOISE_WINDOW_S / self.dt)) : self.n]
            readings = rows[:, _C_WRENCH : _C_WRENCH + 3] @ axis
            self.guard = contact_guard_from_readings(readings, self.contact_threshold)

    def _tare_sensor(self) -> None:
        """Tare the wrist sensor with its mean reading over the last ``TARE_AVERAGE_S`` of telemetry (the tool held
        still in free space), taken in the TOOL frame where a sensor offset lives: the readings there carry the
        previous tare removed, so it is added back. The current reading is tared too (``SimWorld.tare_sensor``)."""
        rows = self.rows[max(0, self.n - round(TARE_AVERAGE_S / self.dt)) : self.n]
        rotations = matrix_from_quaternion(rows[:, _C_POSE + 3 : _C_POSE + 7])  # world from tool
        wrench = rows[:, _C_WRENCH : _C_WRENCH + 6]
        force = np.einsum("nji,nj->i", rotations, wrench[:, :3]) / len(rows)
        moment = np.einsum("nji,nj->i", rotations, wrench[:, 3:]) / len(rows)
        self.world.tare_sensor(self.world.sensor_tare + np.concatenate((force, moment)))
        self.tare_rotation = rotations[-1]

    def _free_guard(self, plan: PhasePlan) -> ContactGuard:
        """The guard of a free segment that may meet the next surface early: the approach's, raised by what a tared
        offset fixed in the world can read once the plan has turned the tool away from the tare's orientation."""
        if not self.tares:
            return self.guard
        rotations = matrix_from_quaternion(plan.ref_q)
        return self.guard.raised_by(turned_offset_bound_n(self.world.sensor_tare[:3], self.tare_rotation, rotations))

    def surface_window_m(self) -> float:
        """How far from where it was taught a guarded approach may find the surface, m (either way along CF z)."""
        s = self.settings
        window = s.tolerances.surface_window_m
        return window if window is not None else max(s.approach_slow_distance_m, SURFACE_WINDOW_MIN_M)

    def _touchdown_speed(self, segment: Segment) -> float:
        """The speed (m/s) at which the tool meets the surface: given, or ``TOUCHDOWN_IMPACT_FRACTION`` of the first
        target force (at least the contact threshold: the approach runs on until the force passes it, so a softer
        impact buys nothing but time) over the contact's impedance ``max(sqrt(k m), c)`` (``k`` and ``c`` the contact
        stiffness and damping, ``m`` the arm's apparent mass along CF z now), clipped to
        ``[TOUCHDOWN_SPEED_MIN_M_S, approach_speed_m_s]``.

        A tool of apparent mass m meeting a spring k at speed v peaks at ``v sqrt(k m)`` above the press it is
        commanded to (measured here: 2.2 kN·s/m on 1e6 N/m, 0.4 kN·s/m on 3e4 N/m); a damper c above
        ``sqrt(k m)`` raises that to ``c v`` (see :meth:`_contact_impedance`)."""
        s = self.settings
        if s.touchdown_speed_m_s is not None:
            return float(s.touchdown_speed_m_s)
        z = self.geometry[segment.index].first_rotation[:, 2]
        impact_n = TOUCHDOWN_IMPACT_FRACTION * max(first_force(segment), self.contact_threshold)
        speed = impact_n / self._contact_impedance(z)
        return float(np.clip(speed, TOUCHDOWN_SPEED_MIN_M_S, s.approach_speed_m_s))

    def _contact_impedance(self, z: NDArray[np.float64]) -> float:
        """The touch-down peak per unit impact speed (N·s/m) of a contact along the world direction ``z``:
        ``max(sqrt(k m), c)``, ``k`` and ``c`` the contact's stiffness and damping as planned for (the settings'
        ``planned_contact_*``, else the simulated world's), ``m`` the arm's apparent mass along ``z`` in its pose now.

        A mass ``m`` meeting a spring ``k`` and a damper ``c`` side by side at speed ``v`` peaks at
        ``v sqrt(k m) g(ζ)``, ``ζ = c / (2 sqrt(k m))``: ``g`` stays at or below 1 up to ``ζ = 1/2`` (the damper takes
        off some of the spring's peak) and is ``2ζ`` above it (the damper's ``c v`` at the first instant is the peak;
        worked out from the closed-form motion). The maximum of the two bounds both."""
        J, _, M = self.world.dynamics(True)
        mobility = J[:3] @ np.linalg.solve(M, J[:3].T)  # Λ^-1, translational block
        mass = 1.0 / max(float(z @ mobility @ z), 1e-9)
        s, config = self.settings, self.world_config
        k = config.contact_stiffness if s.planned_contact_stiffness_n_m is None else s.planned_contact_stiffness_n_m
        c = config.contact_damping if s.planned_contact_damping_n_s_m is None else s.planned_contact_damping_n_s_m
        return max(math.sqrt(k * mass), c)

    def _crease_speed(self, before: Segment, after: Segment) -> float | None:
        """The tangential speed (m/s) at which to pass the crease between two contact segments, or None when their
        CF z differ by less than ``CREASE_MIN_ANGLE_RAD``: the next surface is met at ``v sin θ`` along its normal,
        an impact of about ``v sin θ`` times :meth:`_contact_impedance` on top of the press, kept to
        ``CREASE_IMPACT_FRACTION`` of it."""
        z_before = self.geometry[before.index].rotations[-1][:, 2]
        z_after = self.geometry[after.index].first_rotation[:, 2]
        sin_angle = float(np.linalg.norm(np.cross(z_before, z_after)))
        if sin_angle < math.sin(CREASE_MIN_ANGLE_RAD):
            return None
        press = max(first_force(after), self.contact_threshold)
        speed = CREASE_IMPACT_FRACTION * press / self._contact_impedance(z_after) / sin_angle
        return max(speed, TOUCHDOWN_SPEED_MIN_M_S)

    def _normal_tracker(self, plan: PhasePlan) -> SurfaceNormalTracker | None:
        """A tracker of the surface normal for a slide contact phase of ``hybrid_cf`` when asked for, else None."""
        if not (
            self.settings.follow_surface_normal
            and self.kind is ControllerKind.hybrid_cf
            and plan.phase is ExecutionPhase.contact
            and plan.frame is not None
        ):
            return None
        return SurfaceNormalTracker(plan.frame.cf_rotation[:, 2], NORMAL_TRACKING_STEPS * self.dt)

    def retract(self) -> None:
        """Back off ``CONTACT_LOSS_RETRACT_M`` along -CF z from the current pose with motion control on every axis."""
        p, q = self.world.tool_pose()
        z = self._cf_rotation[:, 2]
        n = max(1, round(CONTACT_LOSS_RETRACT_S / self.dt))
        ref_p = p - smooth_ramp(0.0, CONTACT_LOSS_RETRACT_M, n)[:, None] * z
        twist = np.zeros((n, 6))
        twist[1:, :3] = np.diff(ref_p, axis=0) / self.dt
        plan = PhasePlan(ExecutionPhase.retreat, -1, ref_p, np.broadcast_to(q, (n, 4)), twist, np.zeros(n),
                         frame=self.planner.identity_frame)  # fmt: skip
        self.controller.reset_integral()
        self.run_plan(plan)

    def _joint_limit_reason(self, q: NDArray[np.float64]) -> str:
        """Name the joint outside its URDF limits (PyBullet does not enforce them in torque mode)."""
        lower, upper = self.world.joint_lower, self.world.joint_upper
        j = int(np.argmax(np.maximum(lower - q, q - upper)))
        return f"joint limit: joint {j + 1} at {q[j]:.3f} rad outside [{lower[j]:.3f}, {upper[j]:.3f}] rad"

    def _record_contact_offset(self, segment: Segment) -> None:
        """Record where the surface was found along CF z from where it was taught; outside the expected window,
        go on (the verdict's surface check fails) or abort (``surface_outside_window``)."""
        geo = self.geometry[segment.index]
        z = geo.first_rotation[:, 2]
        p, _ = self.world.tool_pose()
        offset = float((p - geo.start_world) @ z)
        self.contact_offsets.append(offset)
        window = self.surface_window_m()
        if abs(offset) > window and self.settings.surface_outside_window is SurfaceWindowAction.abort:
            where = "before" if offset < 0 else "beyond"
            self.retract()
            raise ExecutionAbortError(
                f"surface outside its window in segment {segment.index}: found {abs(offset) * 1e3:.0f} mm {where} "
                f"where it was taught, outside the expected ±{window * 1e3:.0f} mm (another surface, or the part "
                "moved?)"
            )

    def run(self) -> None:
        s = self.settings
        segments = self.skill.segments
        first = segments[0]
        # Start pose: the first segment's start (shifted), before a contact segment the pre-contact point.
        q_start_ref = np.asarray(first.orientation_dmp.start, dtype=float)
        if first.kind is SegmentKind.contact:
            geo = self.geometry[first.index]
            p_start = geo.start_world - s.approach_clearance_m * geo.first_rotation[:, 2]
        else:
            p_start = np.asarray(first.position_dmp.start, dtype=float) + self.offset
        q_joints = self.world.inverse_kinematics(p_start, q_start_ref)
        self.world.reset(q_joints)
        self.controller.reset(posture=q_joints)
        self.wall_start = time.perf_counter()
        settle_s = max(s.settle_s, TARE_HOLD_S) if self.tares else s.settle_s
        self.run_plan(self.planner.still(ExecutionPhase.settle, -1, p_start, q_start_ref, settle_s))
        first_contact = next((seg.index for seg in segments if seg.kind is SegmentKind.contact), None)
        self._after_still_hold(None if first_contact is None else self.geometry[first_contact].first_rotation[:, 2])
        last_ref_q = q_start_ref
        in_contact_run = False
        f_last: float | None = None
        found_early = False
        crease_out: float | None = None
        planner, tool_pose = self.planner, self.world.tool_pose
        for i, segment in enumerate(segments):
            nxt = segments[i + 1] if i + 1 < len(segments) else None
            if segment.kind is SegmentKind.free:
                if nxt is not None and nxt.kind is SegmentKind.contact:
                    geo = self.geometry[nxt.index]
                    z = geo.first_rotation[:, 2]
                    goal = geo.start_world - s.approach_clearance_m * z
                    plan = planner.free(segment, *tool_pose(), goal, stop_axis=z)
                    self.touched = False
                    found_early = self.run_plan(plan, self._free_guard(plan)) is PlanEnd.contact
                else:
                    goal = np.asarray(segment.position_dmp.goal, float) + self.offset
                    plan = planner.free(segment, *tool_pose(), goal, None)
                    found_early = self.run_plan(plan) is PlanEnd.contact
                last_ref_q = plan.ref_q[-1]
                continue
            # Contact segment.
            if not in_contact_run:
                self.controller.reset_integral()
                if not found_early:
                    if self.tares and i > 0:  # (the settle tared at the first segment's pre-contact point)
                        hold = planner.still(ExecutionPhase.approach, segment.index, goal, last_ref_q, TARE_HOLD_S)
                        self.run_plan(hold)
                        self._after_still_hold(self.geometry[segment.index].first_rotation[:, 2])
                    speed = self._touchdown_speed(segment)
                    self.touched = False
                    self.run_plan(planner.approach(segment, tool_pose()[0], last_ref_q, speed))
                self._record_contact_offset(segment)
                first_cf = self.geometry[segment.index].first_rotation
                f_found = self.found_force if self.found_force is not None else 0.0
                f_first = first_force(segment)
                ramp = planner.hold(  # from the target, never from an impact above it
                    segment,
                    ExecutionPhase.approach,
                    tool_pose()[0],
                    float(np.clip(f_found, 0.0, f_first)),
                    f_first,
                    s.gains.force_ramp_s,
                    last_ref_q,
                    first_cf,
                )
                self.run_plan(ramp)
                f_last = None
            crease_in = crease_out if f_last is not None else None  # the crease the previous segment ended at
            next_contact = nxt is not None and nxt.kind is SegmentKind.contact
            crease_out = self._crease_speed(segment, nxt) if next_contact else None
            plan = planner.contact(segment, *tool_pose(), f_last, crease_in, crease_out)
            self.run_plan(plan)
            in_contact_run = True
            f_last = float(plan.force[-1])
            last_ref_q = plan.ref_q[-1]
            last_cf = (plan.frame or plan.series[len(plan.series) - 1]).cf_rotation
            found_early = False
            if nxt is None or nxt.kind is SegmentKind.free:
                release = planner.hold(
                    segment,
                    ExecutionPhase.retreat,
                    tool_pose()[0],
                    f_last,
                    0.0,
                    s.gains.force_release_s,
                    last_ref_q,
                    last_cf,
                    at_end=True,
                )
                self.run_plan(release)
                in_contact_run = False
                f_last = None

    def close(self) -> None:
        self.world.close()


# ---------------------------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------------------------


def execute_skill(
    skill: Skill,
    world_config: WorldConfig,
    settings: ExecutionSettings | None = None,
    *,
    on_sample: Callable[[Telemetry], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
    should_pause: Callable[[], bool] | None = None,
    demonstration: Demonstration | None = None,
) -> ExecutionResult:
    """Execute ``skill`` in ``world_config`` and return metrics and telemetry (:func:`run_skill` chooses the world).

    ``settings`` (an ``ExecutionSettings`` or an ``ExecutionRequest``) gives the environment change,
    controller kind, gains, guarded approach and pace. ``on_sample(telemetry)`` gets every recorded step,
    in batches of ``settings.telemetry_batch`` rows (a :class:`Telemetry`; the last batch may be shorter).
    ``should_abort()`` is polled after every control step; True stops the execution ("aborted on request")
    before the next step, so at most one more step is recorded after the flag is raised.
    ``should_pause()`` is polled before every control step; while True the controller holds the current
    reference (zero reference twist, desired force held) and the loop keeps running (simulated time and
    telemetry go on; the plan does not advance). With pace ``fast`` the caller should throttle while paused.
    ``demonstration``, if given, is the path the path metric compares with (else the nominal DMP path).
    Never raises for a failed execution: the metrics say ``aborted`` / ``failed`` and why.
    """
    settings = settings or ExecutionSettings()
    t_setup = time.perf_counter()
    execution = _Execution(skill, world_config, settings, on_sample, should_abort, should_pause)
    setup_s = time.perf_counter() - t_setup
    phase, reason = ExecutionPhase.done, None
    execution.wall_start = time.perf_counter()
    cpu_start = time.thread_time()
    try:
        try:
            execution.run()
        except ContactLostError as lost:
            execution.retract()
            raise ExecutionAbortError(str(lost)) from None
    except ExecutionAbortError as abort:
        phase, reason = abort.phase, abort.reason
    except Exception as exc:  # a bug or an unreachable pose: report, do not crash the worker
        phase, reason = ExecutionPhase.failed, f"{type(exc).__name__}: {exc}"
    loop_wall_s = time.perf_counter() - execution.wall_start
    loop_cpu_s = time.thread_time() - cpu_start
    execution._emit(final=True)
    execution.close()
    tel = Telemetry(execution.rows[: execution.n].copy())
    steps = max(execution.step_count, 1)
    timing = [v * 1e6 / steps for v in execution.timing]
    total = loop_wall_s * 1e6 / steps
    timings = {
        "sensing": float(timing[0]),
        "dynamics": float(timing[1]),
        "control_law": float(timing[2]),
        "telemetry": float(timing[4]),
        "physics_step": float(timing[3]),
        "total": float(total),
    }
    timings["other"] = max(0.0, total - sum(v for k, v in timings.items() if k != "total"))
    log = ExecutionLog(
        contact_offsets_m=execution.contact_offsets,
        frame_log=execution.frame_log,
        contact_guard=execution.guard if execution.geometry else None,  # (a skill without contact guards nothing)
        surface_window_m=execution.surface_window_m(),
    )
    metrics = compute_metrics(skill, tel, settings, phase, reason, loop_wall_s, log, demonstration, execution.dt)
    return ExecutionResult(
        metrics=metrics,
        telemetry=tel,
        world_config=execution.world_config,
        setup_s=setup_s,
        loop_wall_s=loop_wall_s,
        loop_cpu_s=loop_cpu_s,
        timings_us=timings,
    )


def run_skill(
    world: ExecutionWorld,
    settings: ExecutionSettings | None = None,
    *,
    on_sample: Callable[[Telemetry], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
    should_pause: Callable[[], bool] | None = None,
) -> ExecutionResult:
    """Execute a resolved :class:`ExecutionWorld` (``sim_worker.execution_world.execution_world``): its placed skill
    in its world, the metrics saying which work piece and placement it ran on (else as :func:`execute_skill`)."""
    result = execute_skill(
        world.skill,
        world.config,
        settings,
        on_sample=on_sample,
        should_abort=should_abort,
        should_pause=should_pause,
        demonstration=world.demonstration,
    )
    result.metrics = result.metrics.model_copy(update={"work_piece": world.source, "placement": world.placement})
    return result
