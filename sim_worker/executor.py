"""Execute a learned skill in the simulated world with the hybrid controller (DESIGN.md "The method" 6-7).

``execute_skill(skill, world_config, settings)`` builds a ``SimWorld`` (the taught world plus the
known and the unknown offset of the work piece), puts the robot at the skill's start (IK +
settle) and runs the segments at 1 kHz:

- **free** segment: position and orientation DMPs rolled out from the CURRENT tool pose to the
  (known-offset-shifted) goal, ``S = I``. A free segment followed by a contact segment ends
  ``approach_clearance_m`` before the taught contact point (back along CF z) and is guarded: a
  contact force along the next CF z ends it early.
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

Every control step is recorded as one row of a float array (see :data:`TELEMETRY_COLUMNS`) and
handed to ``on_sample`` in batches of ``telemetry_batch`` rows (a :class:`Telemetry` view).
Aborts (force limit, torque limit, joint limit, contact not found, non-finite values, ``should_abort()``)
stop the loop cleanly and are reported in the metrics; nothing is ever NaN.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import Demonstration
from schemas.execution import (
    PHASE_CODES,
    ControllerKind,
    ExecutionMetrics,
    ExecutionPhase,
    ExecutionSettings,
    NullSpaceProjection,
    Pace,
    TelemetryBatch,
    TelemetrySample,
)
from schemas.skill import SELECTION_FREE, Segment, SegmentKind, Skill
from sim_worker.teacher import scenario_of_name
from sim_worker.world import SimWorld, WorldConfig
from skills.control import ControlFrame, ControlFrameSeries, HybridController
from skills.dmp import DMP, QuaternionDMP
from skills.quaternions import matrix_from_quaternion, quaternions_sign_continuous, quaternions_slerp

STEADY_CONTACT_DELAY_S = 0.2
"""The steady contact phase starts this long after contact (and after each force ramp), s."""
NULL_SPACE_UPDATE_STEPS = 20
"""The null-space projector (and the mass matrix it needs) is refreshed every this many steps."""
MAX_CONTOUR_FRAMES = 2000
"""Most control frames precomputed per contour segment (the series is indexed at a coarser stride)."""
REALTIME_CHECK_STEPS = 10
"""With pace realtime, the loop sleeps to follow the wall clock every this many steps."""

TELEMETRY_COLUMNS: dict[str, slice] = {
    "t": slice(0, 1),
    "phase": slice(1, 2),
    "segment_index": slice(2, 3),
    "tool_position": slice(3, 6),
    "tool_orientation": slice(6, 10),
    "reference_position": slice(10, 13),
    "reference_orientation": slice(13, 17),
    "wrench_world": slice(17, 23),
    "wrench_cf": slice(23, 29),
    "desired_force_cf_z_n": slice(29, 30),
    "in_contact": slice(30, 31),
}
"""Columns of one telemetry row: t (s), phase code (``PHASE_CODES``), segment (-1 settling), tool and
reference pose (world, m, xyzw), measured wrench applied by the tool (world; CF axes), desired CF-z force
(N), in contact (1/0, the simulator's contact points)."""
TELEMETRY_WIDTH = 31
_PHASES = list(ExecutionPhase)


class ExecutionAbortError(Exception):
    """Raised inside the loop to stop the execution with a reason."""

    def __init__(self, reason: str, phase: ExecutionPhase = ExecutionPhase.aborted) -> None:
        super().__init__(reason)
        self.reason = reason
        self.phase = phase


# ---------------------------------------------------------------------------------------------------------------
# Telemetry
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Telemetry:
    """Recorded control steps, one row each (``data`` (N, 31), columns :data:`TELEMETRY_COLUMNS`).

    The properties are views: ``t`` (N,), ``phase_codes`` (N,), ``segment_index`` (N,),
    ``tool_position`` (N, 3), ``tool_orientation`` (N, 4), ``reference_position``,
    ``reference_orientation``, ``wrench_world`` (N, 6), ``wrench_cf`` (N, 6),
    ``desired_force`` (N,), ``in_contact`` (N,) bool.
    """

    data: NDArray[np.float64]

    def _col(self, name: str) -> NDArray[np.float64]:
        return self.data[:, TELEMETRY_COLUMNS[name]]

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def t(self) -> NDArray[np.float64]:
        return self.data[:, 0]

    @property
    def phase_codes(self) -> NDArray[np.int_]:
        return self.data[:, 1].astype(int)

    @property
    def phases(self) -> list[ExecutionPhase]:
        return [_PHASES[c] for c in self.phase_codes]

    @property
    def segment_index(self) -> NDArray[np.int_]:
        return self.data[:, 2].astype(int)

    @property
    def tool_position(self) -> NDArray[np.float64]:
        return self._col("tool_position")

    @property
    def tool_orientation(self) -> NDArray[np.float64]:
        return self._col("tool_orientation")

    @property
    def reference_position(self) -> NDArray[np.float64]:
        return self._col("reference_position")

    @property
    def reference_orientation(self) -> NDArray[np.float64]:
        return self._col("reference_orientation")

    @property
    def wrench_world(self) -> NDArray[np.float64]:
        return self._col("wrench_world")

    @property
    def wrench_cf(self) -> NDArray[np.float64]:
        return self._col("wrench_cf")

    @property
    def desired_force(self) -> NDArray[np.float64]:
        return self.data[:, 29]

    @property
    def in_contact(self) -> NDArray[np.bool_]:
        return self.data[:, 30] > 0.5

    def to_batch(self, execution_id: str = "") -> TelemetryBatch:
        """Return the rows as the columnar wire payload (``schemas.TelemetryBatch``)."""
        return TelemetryBatch(
            execution_id=execution_id,
            t=self.t.tolist(),
            phase=self.phases,
            segment_index=self.segment_index.tolist(),
            tool_position=self.tool_position.tolist(),
            tool_orientation=self.tool_orientation.tolist(),
            reference_position=self.reference_position.tolist(),
            reference_orientation=self.reference_orientation.tolist(),
            wrench_world=self.wrench_world.tolist(),
            wrench_cf=self.wrench_cf.tolist(),
            desired_force_cf_z_n=self.desired_force.tolist(),
        )

    def samples(self, every: int = 1) -> list[TelemetrySample]:
        """Return every ``every``-th row as ``schemas.TelemetrySample`` (slow: for REST answers, not the loop)."""
        rows = range(0, len(self), max(1, int(every)))
        phases = self.phases
        return [
            TelemetrySample(
                t=float(self.t[k]),
                phase=phases[k],
                segment_index=int(self.segment_index[k]),
                tool_position=self.tool_position[k].tolist(),
                tool_orientation=self.tool_orientation[k].tolist(),
                reference_position=self.reference_position[k].tolist(),
                reference_orientation=self.reference_orientation[k].tolist(),
                wrench_world=self.wrench_world[k].tolist(),
                wrench_cf=self.wrench_cf[k].tolist(),
                desired_force_cf_z_n=float(self.desired_force[k]),
            )
            for k in rows
        ]


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

    The work piece is the contour object(s) (cylinder, curved block) when the world has any, else the
    table (with its ramp): the table centre and height move, so the table top plane moves by ``offset``.
    """
    d = np.asarray(offset, dtype=float)
    if not np.any(d):
        return config
    if config.cylinder_enabled or config.block_enabled:
        changes = {}
        if config.cylinder_enabled:
            changes["cylinder_offset_m"] = tuple((np.asarray(config.cylinder_offset_m) + d).tolist())
        if config.block_enabled:
            changes["block_offset_m"] = tuple((np.asarray(config.block_offset_m) + d).tolist())
        return config.replace(**changes)
    cx, cy = config.table_center_xy
    return config.replace(table_center_xy=(cx + d[0], cy + d[1]), table_height_m=config.table_height_m + d[2])


def scenario_of_skill(skill: Skill) -> str | None:
    """The teacher scenario a skill was learned in, read from its demonstration's name, or None."""
    return scenario_of_name(skill.demonstration.name)


@dataclass
class _ContactGeometry:
    """A contact segment's frames, shifted by the known offset: rotations (K, 3, 3), origins (K, 3), times (K,)."""

    t: NDArray[np.float64]
    rotations: NDArray[np.float64]
    origins: NDArray[np.float64]
    start_world: NDArray[np.float64]
    """The taught contact start point (shifted), m."""

    @property
    def first_rotation(self) -> NDArray[np.float64]:
        return self.rotations[0]

    def rotations_at(self, fractions: NDArray[np.float64]) -> NDArray[np.float64]:
        """CF rotations (M, 3, 3) at time fractions (0..1) of the segment, slerped."""
        if self.t.size == 1:
            return np.broadcast_to(self.rotations[0], (fractions.size, 3, 3))
        quats = quaternions_sign_continuous(_quaternions(self.rotations))
        q = quaternions_slerp(fractions * self.t[-1], self.t, quats)
        return matrix_from_quaternion(q)


def _quaternions(R: NDArray[np.float64]) -> NDArray[np.float64]:
    from skills.quaternions import quaternion_from_matrix

    return quaternion_from_matrix(R)


def _contact_geometry(segment: Segment, offset: NDArray[np.float64]) -> _ContactGeometry:
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"contact segment {segment.index} has no compliant frame")
    quats = quaternions_sign_continuous(np.asarray(frames.orientations, dtype=float))
    rotations = matrix_from_quaternion(quats).reshape(-1, 3, 3)
    origins = np.asarray(frames.origins, dtype=float).reshape(-1, 3) + offset
    start = np.asarray(segment.position_dmp.start, dtype=float)
    in_cf = segment.position_dmp.frame == "cf"
    start_world = origins[0] + rotations[0][:, :2] @ start[:2] if in_cf else start + offset
    return _ContactGeometry(np.asarray(frames.t, dtype=float), rotations, origins, start_world)


def _reference_force(skill: Skill, dt: float = 1e-3) -> float:
    """The force the % errors refer to: the largest learned constant, or the peak of the force profile
    rolled out at the control step ``dt`` (s), as executed (N)."""
    values = [s.force_constant_n for s in skill.segments if s.force_constant_n is not None]
    for s in skill.segments:
        if s.force_dmp is not None:
            values.append(float(np.max(DMP.from_parameters(s.force_dmp).rollout(dt).y)))
    return max(values) if values else 0.0


# ---------------------------------------------------------------------------------------------------------------
# Phase plans: per-step references precomputed before a phase runs
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class _Plan:
    phase: ExecutionPhase
    segment: int
    ref_p: NDArray[np.float64]
    ref_q: NDArray[np.float64]
    ref_twist: NDArray[np.float64]
    force: NDArray[np.float64]
    frame: ControlFrame | None = None
    series: ControlFrameSeries | None = None
    stride: int = 1
    stop_axis: NDArray[np.float64] | None = None
    """Guarded: end the phase when the measured force along this axis exceeds the contact threshold."""
    exhausted_reason: str | None = None
    """Abort with this reason if the phase runs to its end (the guarded approach found nothing)."""

    @property
    def steps(self) -> int:
        return int(self.ref_p.shape[0])


def _ramp(a: float, b: float, n: int) -> NDArray[np.float64]:
    """``n`` values from a towards b along a smoothstep, the last equal to b."""
    if n <= 0:
        return np.zeros(0)
    x = np.arange(1, n + 1) / n
    s = x * x * (3.0 - 2.0 * x)
    return a + (b - a) * s


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
        self.reference_force = _reference_force(skill, self.dt)
        if gains.contact_force_threshold_n is not None:
            self.contact_threshold = float(gains.contact_force_threshold_n)
        else:
            self.contact_threshold = float(np.clip(0.1 * self.reference_force, 1.0, 3.0))
        self.geometry = {
            s.index: _contact_geometry(s, self.offset) for s in skill.segments if s.kind is SegmentKind.contact
        }
        self.identity_frame = self.controller.frame(np.eye(3), SELECTION_FREE)
        # Recording.
        self.capacity = 4096
        self.rows = np.zeros((self.capacity, TELEMETRY_WIDTH))
        self.n = 0
        self.emitted = 0
        self.step_count = 0
        self.contact_offsets: list[float] = []
        self.timing = [0.0] * 5  # sensing, dynamics, control law, physics step, telemetry (s, summed)

    # -------------------------------------------------------------------------------------- state helpers

    def _tool(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self.world.tool_pose()

    def _contact_force_along(self, axis: NDArray[np.float64]) -> float:
        return float(self.world.contact_wrench()[:3] @ axis)

    # -------------------------------------------------------------------------------------- plans

    def _free_plan(self, segment: Segment, goal: NDArray[np.float64], stop_axis: NDArray | None) -> _Plan:
        p, q = self._tool()
        pos = DMP.from_parameters(segment.position_dmp)
        ori = QuaternionDMP.from_parameters(segment.orientation_dmp)
        duration = segment.position_dmp.duration_s
        rp = pos.rollout(self.dt, start=p, goal=goal, duration_s=duration)
        rq = ori.rollout(self.dt, start=q, duration_s=duration)
        n = min(len(rp.t), len(rq.t))
        twist = np.hstack([rp.yd[:n], rq.omega[:n]])
        return _Plan(
            ExecutionPhase.free,
            segment.index,
            rp.y[:n],
            rq.q[:n],
            twist,
            np.zeros(n),
            frame=self.identity_frame,
            stop_axis=stop_axis,
        )

    def _approach_plan(self, segment: Segment, ref_q: NDArray[np.float64]) -> _Plan:
        s = self.settings
        geo = self.geometry[segment.index]
        z = geo.first_rotation[:, 2]
        p, _ = self._tool()
        n = math.ceil(s.approach_max_distance_m / s.approach_speed_m_s / self.dt) + 1
        travel = np.arange(n) * self.dt * s.approach_speed_m_s
        ref_p = p + travel[:, None] * z
        twist = np.zeros((n, 6))
        twist[:, :3] = s.approach_speed_m_s * z
        frame = self.controller.frame(geo.first_rotation, SELECTION_FREE)
        return _Plan(
            ExecutionPhase.approach,
            segment.index,
            ref_p,
            np.broadcast_to(ref_q, (n, 4)),
            twist,
            np.zeros(n),
            frame=frame,
            stop_axis=z,
            exhausted_reason=(
                f"contact not found: no contact force above {self.contact_threshold:.1f} N within "
                f"{s.approach_max_distance_m:.3f} m of guarded approach along CF z (segment {segment.index})"
            ),
        )

    def _surface_reference(self, segment: Segment, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The reference point for tool position ``p`` in a contact segment: found or taught surface (see module)."""
        if self.kind is not ControllerKind.impedance:
            return p
        geo = self.geometry[segment.index]
        z = geo.first_rotation[:, 2]
        return p - z * float((p - geo.start_world) @ z)

    def _first_force(self, segment: Segment) -> float:
        if segment.force_constant_n is not None:
            return max(0.0, float(segment.force_constant_n))
        if segment.force_dmp is not None:
            return max(0.0, float(segment.force_dmp.start[0]))
        return 0.0

    def _hold_plan(
        self, segment: Segment, phase: ExecutionPhase, f_from: float, f_to: float, duration: float, ref_q
    ) -> _Plan:
        p, _ = self._tool()
        n = max(1, round(duration / self.dt))
        geo = self.geometry[segment.index]
        ref = self._surface_reference(segment, p)
        frame = self.controller.frame(
            geo.first_rotation if phase is not ExecutionPhase.retreat else self._last_cf, segment.selection
        )
        return _Plan(
            phase,
            segment.index,
            np.broadcast_to(ref, (n, 3)),
            np.broadcast_to(ref_q, (n, 4)),
            np.zeros((n, 6)),
            _ramp(f_from, f_to, n),
            frame=frame,
        )

    def _contact_plan(self, segment: Segment, f_previous: float | None) -> _Plan:
        geo = self.geometry[segment.index]
        p, q = self._tool()
        duration = segment.position_dmp.duration_s
        pos = DMP.from_parameters(segment.position_dmp)
        ori = QuaternionDMP.from_parameters(segment.orientation_dmp)
        rq = ori.rollout(self.dt, start=q, duration_s=duration)
        p_ref0 = self._surface_reference(segment, p)
        if segment.position_dmp.frame == "cf":
            R, o = geo.rotations[0], geo.origins[0]
            xy0 = (p_ref0 - o) @ R[:, :2]
            z0 = float((p_ref0 - o) @ R[:, 2])
            rp = pos.rollout(self.dt, start=xy0, duration_s=duration)
            n = min(len(rp.t), len(rq.t))
            ref_p = o + rp.y[:n, :2] @ R[:, :2].T + z0 * R[:, 2]
            v = rp.yd[:n, :2] @ R[:, :2].T
        else:
            goal = np.asarray(segment.position_dmp.goal, dtype=float) + self.offset
            rp = pos.rollout(self.dt, start=p_ref0, goal=goal, duration_s=duration)
            n = min(len(rp.t), len(rq.t))
            ref_p, v = rp.y[:n], rp.yd[:n]
        if segment.force_dmp is not None:
            force = DMP.from_parameters(segment.force_dmp).rollout(self.dt, duration_s=duration).y[:, 0]
            force = np.maximum(force[:n], 0.0)
            if force.size < n:
                force = np.concatenate([force, np.full(n - force.size, force[-1])])
        else:
            force = np.full(n, max(0.0, float(segment.force_constant_n or 0.0)))
        if f_previous is not None:  # contact -> contact: ramp between the levels
            k = min(n, round(self.settings.gains.force_ramp_s / self.dt))
            if k > 0:
                blend = _ramp(0.0, 1.0, k)
                force[:k] = f_previous + blend * (force[:k] - f_previous)
        twist = np.hstack([v, rq.omega[:n]])
        plan = _Plan(ExecutionPhase.contact, segment.index, ref_p, rq.q[:n], twist, force)
        if geo.t.size == 1:
            plan.frame = self.controller.frame(geo.rotations[0], segment.selection)
        else:
            stride = max(1, math.ceil(n / MAX_CONTOUR_FRAMES))
            fractions = np.arange(0, n, stride) / max(n - 1, 1)
            plan.series = self.controller.frames(geo.rotations_at(np.minimum(fractions, 1.0)), segment.selection)
            plan.stride = stride
        return plan

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

    def run_plan(self, plan: _Plan) -> str:
        """Run a phase; return "done" or "contact" (a guarded phase met the surface). Raises ExecutionAbortError.

        One control step: sensing and the model queries (``SimWorld.sense`` / ``dynamics``: one PyBullet
        query each, the world's cached arrays used without copies), the control law, one telemetry row,
        the physics step; each part is timed (``self.timing``). The loop is written for the 1 kHz budget,
        where each numpy call on a 3- to 7-vector costs ~0.5 µs of overhead: the plan's references are
        read as lists of floats, and the wrench in CF axes and the telemetry row are plain float
        arithmetic, written into the row array in one assignment.
        """
        world = self.world
        sense, dynamics, step = world.sense, world.dynamics, world.step
        compute = self.controller.compute
        perf = time.perf_counter
        dt = self.dt
        phase_code = float(PHASE_CODES[plan.phase])
        seg = float(plan.segment)
        ts = td = tc = tp = tt = 0.0
        batch = self.settings.telemetry_batch
        realtime = self.settings.pace is Pace.realtime
        threshold = self.contact_threshold
        stop_axis = None if plan.stop_axis is None else plan.stop_axis.tolist()
        single = plan.frame
        series, stride = plan.series, plan.stride
        ref_p, ref_q, force = plan.ref_p.tolist(), plan.ref_q.tolist(), plan.force.tolist()
        ref_tw = plan.ref_twist
        dynamic_null = self._dynamic_null
        q_lower, q_upper = world.joint_lower, world.joint_upper
        should_abort, should_pause = self.should_abort, self.should_pause
        hold_twist = np.zeros(6)
        frame: ControlFrame | None = None
        try:
            k = 0
            while k < plan.steps:
                # Paused: hold the current reference (zero reference twist), keep controlling, do not advance.
                paused = should_pause is not None and should_pause()
                t0 = perf()
                q, qd, p, quat, w, touching = sense()
                t1 = perf()
                update_null = self.step_count % NULL_SPACE_UPDATE_STEPS == 0
                J, h, M = dynamics(update_null and dynamic_null)
                if update_null and ((q < q_lower).any() or (q > q_upper).any()):
                    raise ExecutionAbortError(self._joint_limit_reason(q))
                t2 = perf()
                current = single if single is not None else series[k // stride]
                if current is not frame:  # a new control frame: its CF rotation as floats, for the CF wrench
                    frame = current
                    r00, r01, r02, r10, r11, r12, r20, r21, r22 = frame.cf_rotation.ravel().tolist()
                f_des = force[k]
                wl = w.tolist()
                fx, fy, fz, mx, my, mz = wl
                w_cf = [  # the measured wrench in CF axes: R^T f, R^T m
                    fx * r00 + fy * r10 + fz * r20,
                    fx * r01 + fy * r11 + fz * r21,
                    fx * r02 + fy * r12 + fz * r22,
                    mx * r00 + my * r10 + mz * r20,
                    mx * r01 + my * r11 + mz * r21,
                    mx * r02 + my * r12 + mz * r22,
                ]
                out = compute(
                    frame=frame,
                    jacobian=J,
                    q=q,
                    qd=qd,
                    bias_torques=h,
                    tool_position=p,
                    tool_quaternion=quat,
                    reference_position=ref_p[k],
                    reference_quaternion=ref_q[k],
                    reference_twist=hold_twist if paused else ref_tw[k],
                    wrench=w,
                    desired_force=f_des,
                    in_contact=w_cf[2] > min(0.5, 0.5 * f_des),
                    mass_matrix=M,
                    update_null_space=update_null,
                )
                t3 = perf()
                # Record the step (state measured before it, reference and desired force of it).
                if self.n >= self.capacity:
                    self._grow()
                self.rows[self.n] = [
                    self.step_count * dt,
                    phase_code,
                    seg,
                    *p.tolist(),
                    *quat.tolist(),
                    *ref_p[k],
                    *ref_q[k],
                    *wl,
                    *w_cf,
                    f_des,
                    1.0 if touching else 0.0,
                ]
                self.n += 1
                if self.n - self.emitted >= batch:
                    self._emit()
                t4 = perf()
                if out.abort_reason is not None:
                    raise ExecutionAbortError(out.abort_reason)
                step(out.tau)
                self.step_count += 1
                t5 = perf()
                ts += t1 - t0
                td += t2 - t1
                tc += t3 - t2
                tt += t4 - t3
                tp += t5 - t4
                if should_abort is not None and should_abort():  # every step: stops within one control cycle
                    raise ExecutionAbortError("aborted on request")
                if stop_axis is not None and fx * stop_axis[0] + fy * stop_axis[1] + fz * stop_axis[2] > threshold:
                    return "contact"
                if realtime and self.step_count % REALTIME_CHECK_STEPS == 0:
                    lag = self.step_count * dt - (perf() - self.wall_start)
                    if lag > 0:
                        time.sleep(lag)
                if not paused:
                    k += 1
        finally:
            timing = self.timing
            timing[0] += ts
            timing[1] += td
            timing[2] += tc
            timing[3] += tp
            timing[4] += tt
        if plan.exhausted_reason is not None:
            raise ExecutionAbortError(plan.exhausted_reason)
        return "done"

    def _joint_limit_reason(self, q: NDArray[np.float64]) -> str:
        """Name the joint outside its URDF limits (PyBullet does not enforce them in torque mode)."""
        lower, upper = self.world.joint_lower, self.world.joint_upper
        j = int(np.argmax(np.maximum(lower - q, q - upper)))
        return f"joint limit: joint {j + 1} at {q[j]:.3f} rad outside [{lower[j]:.3f}, {upper[j]:.3f}] rad"

    def _record_contact_offset(self, segment: Segment) -> None:
        geo = self.geometry[segment.index]
        z = geo.first_rotation[:, 2]
        p, _ = self._tool()
        self.contact_offsets.append(float((p - geo.start_world) @ z))

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
        self._last_cf = np.eye(3)
        self.wall_start = time.perf_counter()
        n_settle = max(1, round(s.settle_s / self.dt))
        settle = _Plan(
            ExecutionPhase.settle,
            -1,
            np.broadcast_to(p_start, (n_settle, 3)),
            np.broadcast_to(q_start_ref, (n_settle, 4)),
            np.zeros((n_settle, 6)),
            np.zeros(n_settle),
            frame=self.identity_frame,
        )
        self.run_plan(settle)
        last_ref_q = q_start_ref
        in_contact_run = False
        f_last: float | None = None
        found_early = False
        for i, segment in enumerate(segments):
            nxt = segments[i + 1] if i + 1 < len(segments) else None
            if segment.kind is SegmentKind.free:
                if nxt is not None and nxt.kind is SegmentKind.contact:
                    geo = self.geometry[nxt.index]
                    z = geo.first_rotation[:, 2]
                    goal = geo.start_world - s.approach_clearance_m * z
                    plan = self._free_plan(segment, goal, stop_axis=z)
                else:
                    plan = self._free_plan(segment, np.asarray(segment.position_dmp.goal, float) + self.offset, None)
                found_early = self.run_plan(plan) == "contact"
                last_ref_q = plan.ref_q[-1]
                continue
            # Contact segment.
            if not in_contact_run:
                self.controller.reset_integral()
                if not found_early:
                    self.run_plan(self._approach_plan(segment, last_ref_q))
                self._record_contact_offset(segment)
                f_found = self._contact_force_along(self.geometry[segment.index].first_rotation[:, 2])
                ramp = self._hold_plan(
                    segment,
                    ExecutionPhase.approach,
                    max(f_found, 0.0),
                    self._first_force(segment),
                    s.gains.force_ramp_s,
                    last_ref_q,
                )
                self.run_plan(ramp)
                f_last = None
            plan = self._contact_plan(segment, f_last)
            self.run_plan(plan)
            in_contact_run = True
            f_last = float(plan.force[-1])
            last_ref_q = plan.ref_q[-1]
            self._last_cf = (plan.frame or plan.series[len(plan.series) - 1]).cf_rotation
            found_early = False
            if nxt is None or nxt.kind is SegmentKind.free:
                release = self._hold_plan(
                    segment, ExecutionPhase.retreat, f_last, 0.0, s.gains.force_release_s, last_ref_q
                )
                self.run_plan(release)
                in_contact_run = False
                f_last = None

    def close(self) -> None:
        self.world.close()


# ---------------------------------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------------------------------


def _steady_mask(tel: Telemetry, ramp_s: float) -> NDArray[np.bool_]:
    """Contact-phase rows at least max(0.2 s, the force ramp) after the start of their contact segment."""
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    mask = np.zeros(len(tel), dtype=bool)
    if not contact.any():
        return mask
    seg = tel.segment_index
    t = tel.t
    delay = max(STEADY_CONTACT_DELAY_S, ramp_s)
    for s in np.unique(seg[contact]):
        rows = contact & (seg == s)
        t0 = t[rows][0]
        mask |= rows & (t >= t0 + delay - 1e-9)
    return mask


def _demonstrated_path(
    skill: Skill, segment: Segment, offset: NDArray[np.float64], demonstration: Demonstration | None, dt: float
) -> NDArray[np.float64]:
    """The demonstrated tool path of a contact segment (K, 3), shifted by the known offset (world, m)."""
    if demonstration is not None:
        a = demonstration.arrays()
        rows = (a.t >= segment.t_start - 1e-9) & (a.t <= segment.t_end + 1e-9)
        if rows.sum() >= 2:
            return a.positions[rows] + offset
    geo = _contact_geometry(segment, offset)
    y = DMP.from_parameters(segment.position_dmp).rollout(dt).y
    if segment.position_dmp.frame == "cf":
        return geo.origins[0] + y[:, :2] @ geo.rotations[0][:, :2].T
    return y + offset


def _path_rms(
    skill: Skill,
    tel: Telemetry,
    offset: NDArray[np.float64],
    demonstration: Demonstration | None,
    dt: float,
) -> float | None:
    """RMS distance, in the motion subspace (CF x-y), of the executed contact path to the demonstrated one (m)."""
    from scipy.spatial import cKDTree

    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    if not contact.any():
        return None
    squared: list[NDArray[np.float64]] = []
    segs = {s.index: s for s in skill.segments}
    for index in np.unique(tel.segment_index[contact]):
        segment = segs[int(index)]
        rows = contact & (tel.segment_index == index)
        executed = tel.tool_position[rows]
        demo = _demonstrated_path(skill, segment, offset, demonstration, dt)
        geo = _contact_geometry(segment, offset)
        if geo.t.size == 1:  # one CF: distances in its x-y plane
            R = geo.rotations[0]
            tree = cKDTree((demo - geo.origins[0]) @ R[:, :2])
            d, _ = tree.query((executed - geo.origins[0]) @ R[:, :2])
            squared.append(d**2)
        else:  # a CF series: nearest demonstrated point, error without its component along that point's CF z
            tree = cKDTree(demo)
            _, nearest = tree.query(executed)
            err = executed - demo[nearest]
            frac = nearest / max(len(demo) - 1, 1)
            z = geo.rotations_at(frac)[:, :, 2]
            err_tangent = err - np.sum(err * z, axis=1, keepdims=True) * z
            squared.append(np.sum(err_tangent**2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(squared))))


def compute_metrics(
    skill: Skill,
    tel: Telemetry,
    settings: ExecutionSettings,
    phase: ExecutionPhase,
    abort_reason: str | None,
    loop_wall_s: float,
    contact_offsets: list[float],
    demonstration: Demonstration | None = None,
    dt: float = 1e-3,
) -> ExecutionMetrics:
    """Compute DESIGN.md "Measures" from the recorded telemetry of one execution."""
    reference = _reference_force(skill, dt)
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    steady = _steady_mask(tel, settings.gains.force_ramp_s)
    f_meas = tel.wrench_cf[:, 2]
    metrics: dict = {}
    if steady.any():
        err = f_meas[steady] - tel.desired_force[steady]
        rms = float(np.sqrt(np.mean(err**2)))
        worst = float(np.max(np.abs(err)))
        metrics.update(force_rms_error_n=rms, force_max_error_n=worst)
        if reference > 0:
            metrics.update(force_rms_error_pct=100.0 * rms / reference, force_max_error_pct=100.0 * worst / reference)
    if contact.any():
        metrics["contact_ratio"] = float(np.mean(tel.in_contact[contact]))
        metrics["path_rms_m"] = _path_rms(skill, tel, np.asarray(settings.environment.offset, float), demonstration, dt)
    duration = float(len(tel) * dt)
    forces = np.linalg.norm(tel.wrench_world[:, :3], axis=1) if len(tel) else np.zeros(1)
    return ExecutionMetrics(
        controller=ControllerKind(settings.controller),
        phase=phase,
        force_reference_n=reference if reference > 0 else None,
        real_time_factor=duration / loop_wall_s if loop_wall_s > 0 else 0.0,
        duration_s=duration,
        steps=len(tel),
        peak_force_n=float(forces.max()),
        contact_found_offsets_m=contact_offsets,
        steady_contact_s=float(steady.sum() * dt),
        abort_reason=abort_reason,
        **metrics,
    )


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
    """Execute ``skill`` in ``world_config`` (the world it was taught in) and return metrics and telemetry.

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
    try:
        execution.run()
    except ExecutionAbortError as abort:
        phase, reason = abort.phase, abort.reason
    except Exception as exc:  # a bug or an unreachable pose: report, do not crash the worker
        phase, reason = ExecutionPhase.failed, f"{type(exc).__name__}: {exc}"
    loop_wall_s = time.perf_counter() - execution.wall_start
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
    metrics = compute_metrics(
        skill, tel, settings, phase, reason, loop_wall_s, execution.contact_offsets, demonstration, execution.dt
    )
    return ExecutionResult(
        metrics=metrics,
        telemetry=tel,
        world_config=execution.world_config,
        setup_s=setup_s,
        loop_wall_s=loop_wall_s,
        timings_us=timings,
    )
