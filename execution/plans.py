"""Phase plans: the per-step references of one execution phase, precomputed before the phase runs.

A plan holds, for every 1 kHz control step of a phase, the reference pose and twist (world frame, m, m/s,
quaternions ``[x, y, z, w]``, rad/s), the desired force along CF z (N) and the control frame(s) with their
selection. :class:`PhasePlanner` builds them from the skill's segments and the tool pose at the moment the phase
starts (see ``execution.executor`` for the order of the phases; docs/CONVENTIONS.md for the frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.execution import ControllerKind, ExecutionPhase, ExecutionSettings
from schemas.skill import SELECTION_FREE, Segment, SegmentKind, Skill
from skills.control import ControlFrame, ControlFrameSeries, HybridController
from skills.dmp import DMP
from skills.gain_schedule import scheduled_stiffness
from skills.quaternion_dmp import QuaternionDMP
from skills.quaternions import (
    matrix_from_quaternion,
    quaternion_from_matrix,
    quaternions_sign_continuous,
    quaternions_slerp,
)

MAX_CONTOUR_FRAMES = 2000
"""Most control frames precomputed per contour segment (the series is indexed at a coarser stride)."""
CREASE_HOLD_DISTANCE_M = 0.006
"""Path length on each side of a crease travelled at the crease speed, m (covers where the tool meets the next
surface before the taught switch: ~3 mm for our 1 cm ball on a 20° crease, plus a margin)."""
CREASE_DECELERATION_M_S2 = 0.08
"""Tangential deceleration into (and acceleration out of) the crease speed, m/s²."""
CONTACT_LOSS_RETRACT_M = 0.05
"""How far the tool backs off along -CF z after losing the surface, m (over ``CONTACT_LOSS_RETRACT_S``)."""
CONTACT_LOSS_RETRACT_S = 1.0


@dataclass
class ContactGeometry:
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
        quats = quaternions_sign_continuous(quaternion_from_matrix(self.rotations))
        q = quaternions_slerp(fractions * self.t[-1], self.t, quats)
        return matrix_from_quaternion(q)


def contact_geometry(segment: Segment, offset: NDArray[np.float64]) -> ContactGeometry:
    """The frames of a contact ``segment`` moved by ``offset`` (3,) m, world."""
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"contact segment {segment.index} has no compliant frame")
    quats = quaternions_sign_continuous(np.asarray(frames.orientations, dtype=float))
    rotations = matrix_from_quaternion(quats).reshape(-1, 3, 3)
    origins = np.asarray(frames.origins, dtype=float).reshape(-1, 3) + offset
    start = np.asarray(segment.position_dmp.start, dtype=float)
    in_cf = segment.position_dmp.frame == "cf"
    start_world = origins[0] + rotations[0][:, :2] @ start[:2] if in_cf else start + offset
    return ContactGeometry(np.asarray(frames.t, dtype=float), rotations, origins, start_world)


@dataclass
class PhasePlan:
    """One phase's references, one row per control step."""

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
    learned_rotations: NDArray[np.float64] | None = None
    """A contour's learned CF rotations (M, 3, 3), one every ``stride`` steps (``series`` holds their frames)."""
    follows_surface: bool = False
    """The frame follows the surface normal estimated online (``execution.surface_following``)."""
    quick_steps: NDArray[np.bool_] | None = None
    """With ``follows_surface``: per step, whether it is near a crease, where the normal is followed quickly."""
    next_z: NDArray[np.float64] | None = None
    """With ``follows_surface``: the next contact segment's learned CF z; the phase ends when the tracked normal says
    the tool is on that surface (a crease met before the taught time)."""
    stiffness: NDArray[np.float64] | None = None
    """A gain schedule's CF stiffness diagonal (M, 6), N/m and N·m/rad, one row every ``stride`` steps
    (``skills.gain_schedule``); its frames are ``series`` (or the follower's). None: the gains' own."""

    @property
    def steps(self) -> int:
        return int(self.ref_p.shape[0])

    @property
    def held_frame(self) -> ControlFrame | None:
        """The control frame a loop holds for the whole phase (without a follower); None: it steps through
        ``series`` (a contour's frames, or a slide's one frame under a gain schedule)."""
        return self.frame if self.series is None else None

    def reference_rows(self) -> NDArray[np.float64]:
        """One row per step in the control law's reference layout (``skills.control.REFERENCE_*``: position,
        quaternion, twist, desired force), a new array the loop (and a follower) may rewrite."""
        return np.concatenate((self.ref_p, self.ref_q, self.ref_twist, self.force[:, None]), axis=1)


def smooth_ramp(a: float, b: float, n: int) -> NDArray[np.float64]:
    """``n`` values from a towards b along a smoothstep, the last equal to b."""
    if n <= 0:
        return np.zeros(0)
    x = np.arange(1, n + 1) / n
    s = x * x * (3.0 - 2.0 * x)
    return a + (b - a) * s


def crease_speed_caps(
    arc_m: NDArray[np.float64], crease_speed_m_s: float, towards_end: bool, hold_m: float = CREASE_HOLD_DISTANCE_M
) -> NDArray[np.float64]:
    """Speed limits (m/s) along a path of arc lengths ``arc_m`` (N,) m so that the tool passes the crease at its
    start (``towards_end`` False) or end at ``crease_speed_m_s``: held for ``hold_m`` (m), reached at
    ``CREASE_DECELERATION_M_S2`` from farther away."""
    distance = arc_m[-1] - arc_m if towards_end else arc_m - arc_m[0]
    beyond = np.maximum(distance - hold_m, 0.0)
    return np.sqrt(crease_speed_m_s**2 + 2.0 * CREASE_DECELERATION_M_S2 * beyond)


def slowed_times(speed_m_s: NDArray[np.float64], cap_m_s: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """The plan times (s) to sample, one per control step of ``dt`` s, so that a path whose step-k speed is
    ``speed_m_s[k]`` never runs faster than ``cap_m_s[k]``: time runs at the rate ``min(1, cap / speed)`` and the
    plan lasts longer by what the slowing costs. Returns (M,) times in ``[0, (N - 1) dt]``, M >= N."""
    rate = np.minimum(1.0, cap_m_s / np.maximum(speed_m_s, 1e-12))
    t = np.arange(speed_m_s.size) * dt
    t_new = np.concatenate([[0.0], np.cumsum(dt / rate[:-1])])  # when each original sample is reached, s
    return np.interp(np.arange(int(t_new[-1] / dt) + 1) * dt, t_new, t)


def slowed_references(
    ref_p: NDArray[np.float64],
    ref_q: NDArray[np.float64],
    twist: NDArray[np.float64],
    force: NDArray[np.float64],
    crease_in_m_s: float | None,
    crease_out_m_s: float | None,
    window_m: float,
    dt: float,
) -> tuple[NDArray[np.float64], ...]:
    """A contact plan's references, one row per control step of ``dt`` (s), resampled so that it passes its creases
    at the given speeds (m/s): the plan times of its control steps (s), positions, quaternions, twists (scaled by the
    slowing), forces. The crease it ends at may come ``window_m`` (m) before its end."""
    n = ref_p.shape[0]
    speed = np.linalg.norm(twist[:, :3], axis=1)
    arc = np.concatenate([[0.0], np.cumsum(speed[:-1])]) * dt
    cap = np.full(n, np.inf)
    if crease_in_m_s is not None:
        cap = np.minimum(cap, crease_speed_caps(arc, crease_in_m_s, towards_end=False))
    if crease_out_m_s is not None:
        hold = CREASE_HOLD_DISTANCE_M + window_m
        cap = np.minimum(cap, crease_speed_caps(arc, crease_out_m_s, towards_end=True, hold_m=hold))
    t = np.arange(n) * dt
    times = slowed_times(speed, cap, dt)
    rate = np.interp(times, t, np.minimum(1.0, cap / np.maximum(speed, 1e-12)))
    ref_p = np.column_stack([np.interp(times, t, ref_p[:, i]) for i in range(3)])
    twist = np.column_stack([np.interp(times, t, twist[:, i]) for i in range(6)]) * rate[:, None]
    return times, ref_p, quaternions_slerp(times, t, ref_q), twist, np.interp(times, t, force)


def first_force(segment: Segment) -> float:
    """The desired CF-z force at the start of a contact segment, N (never negative)."""
    if segment.force_constant_n is not None:
        return max(0.0, float(segment.force_constant_n))
    if segment.force_dmp is not None:
        return max(0.0, float(segment.force_dmp.start[0]))
    return 0.0


def force_profile(segment: Segment, n: int, dt: float) -> NDArray[np.float64]:
    """The desired CF-z force of a contact segment at its first ``n`` control steps of ``dt`` (s), as executed: the
    force DMP rolled out (held at its last value beyond it) or the learned constant, N (never negative)."""
    if segment.force_dmp is None:
        return np.full(n, max(0.0, float(segment.force_constant_n or 0.0)))
    rollout = DMP.from_parameters(segment.force_dmp).rollout(dt, duration_s=segment.position_dmp.duration_s)
    force = np.maximum(rollout.y[:n, 0], 0.0)
    return np.concatenate([force, np.full(n - force.size, force[-1])]) if force.size < n else force


def force_after(segment: Segment, t_s: float, dt: float) -> float:
    """The desired CF-z force ``t_s`` (s) into a contact segment, as executed at the control step ``dt`` (s), N."""
    return float(force_profile(segment, round(t_s / dt) + 1, dt)[-1])


class PhasePlanner:
    """Builds the phase plans of one execution of ``skill`` (its contact frames moved by the known ``offset``)."""

    def __init__(
        self,
        skill: Skill,
        settings: ExecutionSettings,
        controller: HybridController,
        offset: NDArray[np.float64],
        dt: float,
    ) -> None:
        self.settings = settings
        self.controller = controller
        self.kind = ControllerKind(settings.controller)
        self.offset = offset
        self.dt = dt
        self.geometry = {s.index: contact_geometry(s, offset) for s in skill.segments if s.kind is SegmentKind.contact}
        self.identity_frame = controller.frame(np.eye(3), SELECTION_FREE)

    def still(self, phase: ExecutionPhase, segment_index: int, p: NDArray, q: NDArray, duration_s: float) -> PhasePlan:
        """Hold the tool pose ``(p, q)`` (m, scalar-last quaternion, world) still in free space for ``duration_s``
        (at least one step), motion control on every axis: the settle at the start pose, the tare before a guarded
        approach."""
        n = max(1, round(duration_s / self.dt))
        return PhasePlan(
            phase,
            segment_index,
            np.broadcast_to(p, (n, 3)),
            np.broadcast_to(q, (n, 4)),
            np.zeros((n, 6)),
            np.zeros(n),
            frame=self.identity_frame,
        )

    def pre_contact(self, segment_index: int) -> NDArray[np.float64]:
        """Where the guarded approach of contact segment ``segment_index`` starts: ``approach_clearance_m`` back along
        its first CF z from its taught (shifted) contact start, m, world."""
        geo = self.geometry[segment_index]
        return geo.start_world - self.settings.approach_clearance_m * geo.first_rotation[:, 2]

    def retraction(self, segment_index: int, p: NDArray, q: NDArray, axis: NDArray[np.float64]) -> PhasePlan:
        """Back off ``CONTACT_LOSS_RETRACT_M`` along -``axis`` (world, unit) from the tool pose ``(p, q)`` over
        ``CONTACT_LOSS_RETRACT_S``, motion control on every axis: a retreat of segment ``segment_index``."""
        n = max(1, round(CONTACT_LOSS_RETRACT_S / self.dt))
        ref_p = p - smooth_ramp(0.0, CONTACT_LOSS_RETRACT_M, n)[:, None] * axis
        twist = np.zeros((n, 6))
        twist[1:, :3] = np.diff(ref_p, axis=0) / self.dt
        return PhasePlan(ExecutionPhase.retreat, segment_index, ref_p, np.broadcast_to(q, (n, 4)), twist, np.zeros(n),
                         frame=self.identity_frame)  # fmt: skip

    def free(
        self, segment: Segment, p: NDArray, q: NDArray, goal: NDArray[np.float64], stop_axis: NDArray | None
    ) -> PhasePlan:
        """A free segment from the tool pose ``(p, q)`` to ``goal`` (m), guarded along ``stop_axis`` if given."""
        pos = DMP.from_parameters(segment.position_dmp)
        ori = QuaternionDMP.from_parameters(segment.orientation_dmp)
        duration = segment.position_dmp.duration_s
        rp = pos.rollout(self.dt, start=p, goal=goal, duration_s=duration)
        rq = ori.rollout(self.dt, start=q, duration_s=duration)
        n = min(len(rp.t), len(rq.t))
        twist = np.hstack([rp.yd[:n], rq.omega[:n]])
        return PhasePlan(
            ExecutionPhase.free,
            segment.index,
            rp.y[:n],
            rq.q[:n],
            twist,
            np.zeros(n),
            frame=self.identity_frame,
            stop_axis=stop_axis,
        )

    def approach(
        self, segment: Segment, p: NDArray, ref_q: NDArray[np.float64], touchdown_speed_m_s: float, fast: bool = True
    ) -> PhasePlan:
        """The guarded approach from ``p`` along the segment's first CF z: at the approach speed until
        ``approach_slow_distance_m`` before the taught contact point (not at all without ``fast``: a surface was
        just met), then at ``touchdown_speed_m_s`` (m/s) for the rest of ``approach_max_distance_m``; the speed
        blends over 10 ms."""
        s = self.settings
        geo = self.geometry[segment.index]
        z = geo.first_rotation[:, 2]
        v_fast, v_slow = s.approach_speed_m_s, min(touchdown_speed_m_s, s.approach_speed_m_s)
        before = (geo.start_world - p) @ z - s.approach_slow_distance_m if fast else 0.0
        fast_m = float(np.clip(before, 0.0, s.approach_max_distance_m))
        fast_steps = round(fast_m / v_fast / self.dt)
        slow_steps = math.ceil((s.approach_max_distance_m - fast_m) / v_slow / self.dt) + 1
        speed = np.concatenate([np.full(fast_steps, v_fast), np.full(slow_steps, v_slow)])
        blend = min(10, fast_steps)
        if blend:
            speed[fast_steps - blend : fast_steps] = np.linspace(v_fast, v_slow, blend + 2)[1:-1]
        n = speed.size
        travel = np.concatenate([[0.0], np.cumsum(speed[:-1])]) * self.dt
        ref_p = p + travel[:, None] * z
        twist = np.zeros((n, 6))
        twist[:, :3] = speed[:, None] * z
        frame = self.controller.frame(geo.first_rotation, SELECTION_FREE)
        return PhasePlan(
            ExecutionPhase.approach,
            segment.index,
            ref_p,
            np.broadcast_to(ref_q, (n, 4)),
            twist,
            np.zeros(n),
            frame=frame,
            stop_axis=z,
            exhausted_reason=(
                f"contact not found: nothing met within {s.approach_max_distance_m:.3f} m of guarded approach along "
                f"CF z (segment {segment.index})"
            ),
        )

    def surface_reference(self, segment: Segment, p: NDArray[np.float64], at_end: bool = False) -> NDArray[np.float64]:
        """The reference point for tool position ``p`` in a contact segment: where the surface was FOUND (hybrid
        kinds, ``impedance_found_surface``) or where it was TAUGHT (``impedance``, which presses only through its
        reference and is not told that the surface moved): ``p`` moved along CF z onto the taught surface at the
        segment's start, or at its end (``at_end``: a contour's last frame)."""
        if self.kind is not ControllerKind.impedance:
            return p
        geo = self.geometry[segment.index]
        z = geo.rotations[-1 if at_end else 0][:, 2]
        on_surface = geo.origins[-1] if at_end else geo.start_world
        return p - z * float((p - on_surface) @ z)

    def hold(
        self,
        segment: Segment,
        phase: ExecutionPhase,
        p: NDArray,
        f_from: float,
        f_to: float,
        duration: float,
        ref_q: NDArray,
        cf_rotation: NDArray[np.float64],
        at_end: bool = False,
    ) -> PhasePlan:
        """Hold the place at ``p`` in the frame ``cf_rotation`` while the desired force ramps ``f_from`` -> ``f_to``
        (on the taught surface at the segment's start, or its end with ``at_end``, for ``impedance``)."""
        n = max(1, round(duration / self.dt))
        ref = self.surface_reference(segment, p, at_end)
        return PhasePlan(
            phase,
            segment.index,
            np.broadcast_to(ref, (n, 3)),
            np.broadcast_to(ref_q, (n, 4)),
            np.zeros((n, 6)),
            smooth_ramp(f_from, f_to, n),
            frame=self.controller.frame(cf_rotation, segment.selection),
        )

    def release(
        self, segment: Segment, p: NDArray, press_n: float, ref_q: NDArray, cf_rotation: NDArray, at_end: bool = False
    ) -> PhasePlan:
        """The retreat's :meth:`hold`: the force ``press_n`` (N) ramped down to zero over ``force_release_s``."""
        release_s = self.settings.gains.force_release_s
        return self.hold(segment, ExecutionPhase.retreat, p, press_n, 0.0, release_s, ref_q, cf_rotation, at_end)

    def contact(
        self,
        segment: Segment,
        p: NDArray,
        q: NDArray,
        f_previous: float | None,
        crease_in_m_s: float | None = None,
        crease_out_m_s: float | None = None,
        follows_surface: bool = False,
    ) -> PhasePlan:
        """A contact segment from the tool pose ``(p, q)``; ``f_previous`` (N) ramps in from the previous segment.

        ``crease_in_m_s`` / ``crease_out_m_s``: the segment starts / ends at a crease with another contact segment,
        passed at this tangential speed (m/s; the plan is slowed there, see :func:`crease_speed_caps`).
        ``follows_surface``: the frame follows the surface found (``execution.surface_following``); the crease may
        then be met up to ``approach_slow_distance_m`` before the taught one (the slow-down before it starts that
        much earlier), and a contour keeps its learned rotations for the follower instead of a frame series."""
        geo = self.geometry[segment.index]
        duration = segment.position_dmp.duration_s
        pos = DMP.from_parameters(segment.position_dmp)
        ori = QuaternionDMP.from_parameters(segment.orientation_dmp)
        rq = ori.rollout(self.dt, start=q, duration_s=duration)
        p_ref0 = self.surface_reference(segment, p)
        if segment.position_dmp.frame == "cf":
            R, o = geo.rotations[0], geo.origins[0]
            xy0 = (p_ref0 - o) @ R[:, :2]
            z0 = float((p_ref0 - o) @ R[:, 2])
            rp = pos.rollout(self.dt, start=xy0, duration_s=duration)
            n = min(len(rp.t), len(rq.t))
            ref_p = o + rp.y[:n, :2] @ R[:, :2].T + z0 * R[:, 2]
            v = rp.yd[:n, :2] @ R[:, :2].T
        else:  # the goal moves with the surface as found along the first CF z (not at all for ``impedance``)
            z = geo.first_rotation[:, 2]
            found = z * float((p_ref0 - geo.start_world) @ z)
            goal = np.asarray(segment.position_dmp.goal, dtype=float) + self.offset + found
            rp = pos.rollout(self.dt, start=p_ref0, goal=goal, duration_s=duration)
            n = min(len(rp.t), len(rq.t))
            ref_p, v = rp.y[:n], rp.yd[:n]
        force = force_profile(segment, n, self.dt)
        ref_q, twist = rq.q[:n], np.hstack([v, rq.omega[:n]])
        times = np.arange(n) * self.dt  # the plan time of each control step, s
        if crease_in_m_s is not None or crease_out_m_s is not None:
            window = self.settings.approach_slow_distance_m if follows_surface else 0.0
            times, ref_p, ref_q, twist, force = slowed_references(
                ref_p, ref_q, twist, force, crease_in_m_s, crease_out_m_s, window, self.dt
            )
            n = times.size
        if f_previous is not None:  # contact -> contact: ramp between the levels
            k = min(n, round(self.settings.gains.force_ramp_s / self.dt))
            if k > 0:
                blend = smooth_ramp(0.0, 1.0, k)
                force[:k] = f_previous + blend * (force[:k] - f_previous)
        plan = PhasePlan(ExecutionPhase.contact, segment.index, ref_p, ref_q, twist, force)
        plan.follows_surface = follows_surface
        stride = max(1, math.ceil(n / MAX_CONTOUR_FRAMES))
        fractions = np.minimum(times[::stride] / max(times[-1], self.dt), 1.0)
        plan.stiffness = scheduled_stiffness(segment, self.settings.gains, fractions)
        if geo.t.size == 1:
            plan.frame = self.controller.frame(geo.rotations[0], segment.selection)
            if plan.stiffness is not None:  # the one frame with the schedule's stiffness every `stride` steps
                plan.stride = stride
                if not follows_surface:
                    rotations = np.broadcast_to(geo.rotations[0], (fractions.size, 3, 3))
                    plan.series = self.controller.frames(rotations, segment.selection, plan.stiffness)
        else:
            plan.learned_rotations = geo.rotations_at(fractions)
            plan.stride = stride
            if not follows_surface:
                plan.series = self.controller.frames(plan.learned_rotations, segment.selection, plan.stiffness)
        return plan

    def transfer(
        self,
        segment_index: int,
        p: NDArray,
        q: NDArray,
        goal: NDArray[np.float64],
        goal_q: NDArray[np.float64],
        stop_axis: NDArray[np.float64] | None,
        phase: ExecutionPhase = ExecutionPhase.free,
        speed_m_s: float | None = None,
    ) -> PhasePlan:
        """A straight move in free space from the tool pose ``(p, q)`` to ``(goal, goal_q)`` (m, world; scalar-last
        quaternions) at ``speed_m_s`` (default: the approach speed) on average (smoothstep in time, at least 0.5 s),
        guarded along ``stop_axis`` if given: to the pre-contact point of a relocated contour, or off the surface
        before the way out (``phase`` retreat)."""
        distance = float(np.linalg.norm(goal - p))
        speed = speed_m_s if speed_m_s is not None else self.settings.approach_speed_m_s
        n = max(round(0.5 / self.dt), math.ceil(1.5 * distance / speed / self.dt))
        x = smooth_ramp(0.0, 1.0, n)
        ref_p = p + x[:, None] * (goal - p)
        quats = quaternions_sign_continuous(np.stack((q, goal_q)))
        ref_q = quaternions_slerp(x, np.array([0.0, 1.0]), quats)
        twist = np.zeros((n, 6))
        twist[1:, :3] = np.diff(ref_p, axis=0) / self.dt
        return PhasePlan(
            phase,
            segment_index,
            ref_p,
            ref_q,
            twist,
            np.zeros(n),
            frame=self.identity_frame,
            stop_axis=stop_axis,
        )

    def crease_zone(self, plan: PhasePlan, from_start_m: float, from_end_m: float) -> NDArray[np.bool_]:
        """Per step of ``plan``, whether the tool is within ``from_start_m`` of path from its start or within
        ``from_end_m`` of its end (m; a crease at either end)."""
        speed = np.linalg.norm(plan.ref_twist[:, :3], axis=1)
        arc = np.concatenate([[0.0], np.cumsum(speed[:-1])]) * self.dt
        return (arc <= from_start_m) | (arc[-1] - arc <= from_end_m)

    def extension(
        self, segment: Segment, p: NDArray, previous: PhasePlan, speed_m_s: float, distance_m: float
    ) -> PhasePlan:
        """The slide ``segment`` (its last plan ``previous``) carried on beyond its taught end from the tool position
        ``p``, along its last direction of motion at ``speed_m_s`` for at most ``distance_m`` (m), pressing its last
        force in its frame: a crease that was taught here has not been met yet (the follower ends it when it is)."""
        direction = previous.ref_twist[-1, :3]
        direction = direction / max(float(np.linalg.norm(direction)), 1e-12)
        n = max(1, math.ceil(distance_m / max(speed_m_s, 1e-6) / self.dt))
        ref_p = p + (np.arange(n) * speed_m_s * self.dt)[:, None] * direction
        twist = np.zeros((n, 6))
        twist[:, :3] = speed_m_s * direction
        plan = PhasePlan(
            ExecutionPhase.contact,
            segment.index,
            ref_p,
            np.broadcast_to(previous.ref_q[-1], (n, 4)),
            twist,
            np.full(n, previous.force[-1]),
            frame=previous.frame,
        )
        plan.follows_surface = True
        return plan
