"""Execute a learned skill on a robot with the hybrid controller (the paper's section 6), apart from any engine.

:class:`Execution` sequences the phases of one execution on an ``execution.robot.Robot`` through the engine's
1 kHz loop (an ``execution.runner.PhaseRunner``; ``sim_worker.executor.execute_skill`` builds PyBullet's: the taught
world plus the known and the unknown offset of the work piece). It puts the robot at the skill's start (IK + settle)
and runs the segments:

- **free** segment: position and orientation DMPs rolled out from the CURRENT tool pose to the
  (known-offset-shifted) goal, ``S = I``. A free segment followed by a contact segment ends
  ``approach_clearance_m`` before the taught contact point (back along CF z) and is guarded: a
  contact force along the next CF z ends it early; the tool then touches down again at the touch-down speed from
  where it met the surface.
- **tare** (``tare_sensor``, a non-ideal sensor): at the end of the settle at the start pose, and in a 0.2 s still
  hold at the pre-contact point before each later approach, the wrist sensor is tared with its mean reading
  (tool frame), so a sensor offset does not read as a touch-down in free space.
- **approach** (before a contact segment that follows a free one): the reference moves along
  +CF z at ``approach_speed_m_s``, then at the touch-down speed (``execution.impacts``; impedance, ``S = I``)
  until the measured CF-z force exceeds
  the contact threshold (abort "contact not found" after ``approach_max_distance_m``); then,
  with the contact segment's frame and selection, the desired force ramps from the measured
  one to the segment's first desired force over ``force_ramp_s`` while the tool holds its place.
- **contact** segment: slide: the position DMP runs in the (shifted) CF x-y plane from the
  current CF x-y position, the force is the learned constant; contour: the position DMP runs in
  the world, the CF is the stored frame series slerped by time fraction and shifted, the force
  is the rolled-out force DMP. Consecutive contact segments follow each other directly, the
  desired force ramping between their levels over ``force_ramp_s``.
- **following the surface** (``follow_surface_normal``, ``hybrid_cf``; ``execution.surface_following``): the
  contact phases turn their CF to the normal estimated online, a contour's references are rewritten from where the
  tool is (re-anchored where the surface was found), a contour touched down at another place of its path is
  relocated by the part's move (release, retract, transfer, touch down again: ``metrics.contour_relocations_m``),
  and consecutive contact segments switch where the next surface is met (a slide carried on past its taught end
  until then).
- **retreat**: after a contact segment followed by a free one (or the end), the desired force
  ramps down to zero over ``force_release_s`` before the free segment lifts off.

The reference CF-z coordinate of a slide path is where the surface was FOUND (hybrid kinds; it
only matters for ``hybrid_world_z``, whose motion axes are world x-y) or where it was TAUGHT
(``impedance``, which presses only through its reference).

The phases run in ``sim_worker.control_loop.ControlLoop``: every control step is recorded as one row of a float
array (see :data:`schemas.execution.TELEMETRY_COLUMNS`) and handed to ``on_sample`` in batches of
``telemetry_batch`` rows (a :class:`Telemetry` view).
Aborts (force limit, torque limit, joint limit, contact not found, non-finite values, ``should_abort()``)
stop the loop cleanly and are reported in the metrics; nothing is ever NaN.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from execution.contact_detection import CONTACT_THRESHOLD_RANGE_N, ContactGuard
from execution.execution_log import ExecutionLog
from execution.impacts import ImpactPlanner
from execution.metrics import reference_force
from execution.plans import CREASE_HOLD_DISTANCE_M, PhasePlan, PhasePlanner, first_force
from execution.relocation import CONFIRM_LIFT_M, ContourRelocation
from execution.robot import Robot
from execution.runner import ContactLostError, ExecutionAbortError, PhaseRunner, PlanEnd
from execution.surface_following import phase_follower, run_tracker
from execution.tare import FreeSpaceSensor
from schemas.execution import ControllerKind, ExecutionPhase, ExecutionSettings, SurfaceWindowAction
from schemas.skill import Segment, SegmentKind, Skill
from skills.control import HybridController
from skills.job_estimate import LIFT_OFF_M, LIFT_OFF_S, TARE_HOLD_S, surface_window_m
from skills.normal_tracking import SurfaceNormalTracker

LIFT_OFF_SPEED_M_S = 1.5 * LIFT_OFF_M / LIFT_OFF_S
"""The lift-off's mean speed (away from the surface: no impact to plan for; ``PhasePlanner.transfer`` takes
1.5 × the distance over the speed), m/s; the confirming touch lifts at it too."""


def follows_surface(skill: Skill, settings: ExecutionSettings) -> bool:
    """Whether an execution of ``skill`` follows the surface it finds (``hybrid_cf`` only): as
    ``settings.follow_surface_normal`` says, by default where every contact segment is a slide (one compliant frame).
    Measured (``benchmarks/bench_verdicts.py``): following costs slides nothing and holds a tilted part the fixed frame
    cannot; a contour re-anchored where a moved part was met covers less of its taught region than the fixed frames
    do, so contours keep them unless asked."""
    if ControllerKind(settings.controller) is not ControllerKind.hybrid_cf:
        return False
    if settings.follow_surface_normal is not None:
        return settings.follow_surface_normal
    frames = [s.compliant_frames for s in skill.segments if s.kind is SegmentKind.contact]
    return all(f is not None and len(f.t) == 1 for f in frames)


class Execution:
    """One execution of ``skill`` with ``settings`` on ``robot`` (module docstring): the controller, the phase plans,
    the contact guard, the impacts planned for ``contact`` (the contact stiffness N/m and damping N·s/m to plan for
    when the settings do not say: a simulator's own), and the engine's loop, ``make_loop(controller, capacity_s)``
    (a :class:`PhaseRunner` with room for ``capacity_s`` of telemetry at first). :meth:`outcome` runs it."""

    def __init__(
        self,
        skill: Skill,
        settings: ExecutionSettings,
        robot: Robot,
        make_loop: Callable[[HybridController, float], PhaseRunner],
        contact: tuple[float, float],
    ) -> None:
        self.skill = skill
        self.settings = settings
        self.offset = np.asarray(settings.environment.offset, dtype=float)
        self.robot = robot
        self.dt = float(robot.time_step_s)
        gains = settings.gains
        self.kind = ControllerKind(settings.controller)
        self.controller = HybridController(self.kind, gains, dt=self.dt, torque_limits=robot.torque_limits)
        self.reference_force = reference_force(skill, self.dt)
        if gains.contact_force_threshold_n is not None:
            self.contact_threshold = float(gains.contact_force_threshold_n)
        else:
            self.contact_threshold = float(np.clip(0.1 * self.reference_force, *CONTACT_THRESHOLD_RANGE_N))
        self.planner = PhasePlanner(skill, settings, self.controller, self.offset, self.dt)
        self.geometry = self.planner.geometry
        self._selection = {s.index: s.selection for s in skill.segments}
        self.follows_surface = follows_surface(skill, settings)
        """Contact phases follow the surface found (``execution.surface_following``)."""
        self._tracker: SurfaceNormalTracker | None = None
        """The surface normal tracked over the current contact run (with ``follows_surface``)."""
        self.impacts = ImpactPlanner(robot, settings, self.contact_threshold, self.dt, contact)
        self.contact_offsets: list[float] = []
        self.next_surface_found: dict[int, bool] = {}
        """Following the surface: per contact segment entered across a crease, whether its surface was met."""
        self.exit_axis: NDArray[np.float64] | None = None
        """The normal the tool lifted off along after its last contact: the way out is guarded along it."""
        # Room for the segments and a few seconds of settle, approach and retreat, so the rows rarely grow.
        self.loop = make_loop(self.controller, sum(segment.position_dmp.duration_s for segment in skill.segments) + 5.0)
        tares = settings.tare_sensor and not robot.sensor_ideal
        self.sensor = FreeSpaceSensor(robot, self.loop, tares, self.contact_threshold)
        """Tared in the still holds, the guard of the approaches (``execution.tare``)."""
        self.relocation = ContourRelocation(robot, self.loop, self.dt, settings.approach_max_distance_m)

    def _run(self, plan: PhasePlan, guard: ContactGuard | None = None) -> PlanEnd:
        """Run ``plan`` in the loop, guarded by ``guard`` (default: the approaches', ``self.sensor.guard``), with a
        follower when it follows the surface."""
        references = plan.reference_rows()
        follower = phase_follower(plan, references, self._tracker, self.controller, self._selection, self.dt)
        return self.loop.run_plan(plan, guard or self.sensor.guard, references, follower)

    def retract(self, axis: NDArray[np.float64] | None = None, segment: int = -1) -> None:
        """Back off ``CONTACT_LOSS_RETRACT_M`` along -``axis`` (world, unit; default: CF z of the frame in use) from
        the current pose with motion control on every axis (``PhasePlanner.retraction``), the force integral
        cleared."""
        p, q = self.robot.tool_pose()
        plan = self.planner.retraction(segment, p, q, self.loop.cf_rotation[:, 2] if axis is None else axis)
        self.controller.reset_integral()
        self.loop.run_plan(plan)

    def _release(self, segment: Segment, press_n: float, ref_q: NDArray[np.float64]) -> None:
        """Ramp the force ``press_n`` (N) down to zero over ``force_release_s``, the tool held where it is."""
        self._run(self.planner.release(segment, self.robot.tool_pose()[0], press_n, ref_q, self.loop.cf_rotation))

    def _touch_again(self, segment: Segment, press_n: float, ref_q: NDArray[np.float64]) -> None:
        """A second touch where the first one was: release ``press_n`` (N), lift ``CONFIRM_LIFT_M`` off along the
        direction pressed, approach again at the touch-down speed and ramp back to ``press_n``."""
        self._release(segment, press_n, ref_q)
        z = self.loop.cf_rotation[:, 2].copy()
        p, q = self.robot.tool_pose()
        self._run(
            self.planner.transfer(
                segment.index, p, q, p - CONFIRM_LIFT_M * z, ref_q, None, ExecutionPhase.approach, LIFT_OFF_SPEED_M_S
            )
        )
        speed = self.impacts.touchdown_speed(segment, self.geometry[segment.index].first_rotation[:, 2])
        self.loop.touched = False
        self._run(self.planner.approach(segment, self.robot.tool_pose()[0], ref_q, speed, fast=False))
        self._ramp_up(segment, press_n, ref_q)

    def _ramp_up(self, segment: Segment, press_n: float, ref_q: NDArray[np.float64]) -> None:
        """After a touch-down: ramp the desired force from the force found (never from an impact above the target)
        to ``press_n`` (N) over ``force_ramp_s``, the tool held where it touched, in the segment's first frame."""
        found = float(np.clip(self.loop.found_force or 0.0, 0.0, press_n))
        ramp = self.planner.hold(
            segment,
            ExecutionPhase.approach,
            self.robot.tool_pose()[0],
            found,
            press_n,
            self.settings.gains.force_ramp_s,
            ref_q,
            self.geometry[segment.index].first_rotation,
        )
        ramp.follows_surface = self.follows_surface
        self._run(ramp)

    def _relocated(self, segment: Segment, press_n: float, ref_q: NDArray[np.float64]) -> bool:
        """Whether a contour that follows the surface was met at another place of its path than its start
        (``ContourRelocation.touch_shift``), CONFIRMED by a second touch there (:meth:`_touch_again`) whose shift
        agrees within ``RELOCATION_AGREEMENT_M``, and was relocated: the force ``press_n`` (N) is released, the tool
        retracts, and the plans are rebuilt with the mean of the two shifts added to the known offset
        (``self.offset``). The caller moves to the new pre-contact point and touches down again. Not confirmed: the
        contour goes on from the second touch, and the log keeps the shift it did not believe (the verdict warns)."""
        geo = self.geometry[segment.index]
        if not self.follows_surface or geo.t.size < 2:
            return False
        cone_rad = None if self._tracker is None else self._tracker.static_cone_rad
        first = self.relocation.touch_shift(segment, geo, self.offset, cone_rad)
        if first is None:
            return False
        self._touch_again(segment, press_n, ref_q)
        shift = self.relocation.confirmed(first, self.relocation.touch_shift(segment, geo, self.offset, cone_rad))
        if shift is None:
            return False
        self._release(segment, press_n, ref_q)
        self.retract()
        self.offset = self.offset + shift
        self.relocation.relocations.append(shift.tolist())
        self.planner = PhasePlanner(self.skill, self.settings, self.controller, self.offset, self.dt)
        self.geometry = self.planner.geometry
        return True

    def _lift_off(self, segment_index: int, ref_q: NDArray[np.float64]) -> None:
        """Lift the tool off the surface along the normal it last pressed along (the CF z in use: the found one when
        following the surface) by ``LIFT_OFF_M`` over ``LIFT_OFF_S``, before the way out; the way out is then
        guarded along that normal (``self.exit_axis``): a hit there is an exit collision, not a touch-down."""
        z = self.loop.cf_rotation[:, 2].copy()
        p, q = self.robot.tool_pose()
        lift = self.planner.transfer(
            segment_index, p, q, p - LIFT_OFF_M * z, ref_q, None, ExecutionPhase.retreat, LIFT_OFF_SPEED_M_S
        )
        self._run(lift)
        self.exit_axis = z

    def _record_contact_offset(self, segment: Segment) -> None:
        """Record where the surface was found along CF z from where it was taught; outside the expected window,
        go on (the verdict's surface check fails) or abort (``surface_outside_window``)."""
        geo = self.geometry[segment.index]
        z = geo.first_rotation[:, 2]
        p, _ = self.robot.tool_pose()
        offset = float((p - geo.start_world) @ z)
        self.contact_offsets.append(offset)
        window = surface_window_m(self.settings)
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
            p_start = self.planner.pre_contact(first.index)
        else:
            p_start = np.asarray(first.position_dmp.start, dtype=float) + self.offset
        q_joints = self.robot.inverse_kinematics(p_start, q_start_ref)
        self.robot.reset(q_joints)
        self.controller.reset(posture=q_joints)
        self.loop.wall_start = time.perf_counter()
        settle_s = max(s.settle_s, TARE_HOLD_S) if self.sensor.tares else s.settle_s
        self._run(self.planner.still(ExecutionPhase.settle, -1, p_start, q_start_ref, settle_s))
        first_contact = next((seg.index for seg in segments if seg.kind is SegmentKind.contact), None)
        self.sensor.after_still_hold(
            None if first_contact is None else self.geometry[first_contact].first_rotation[:, 2]
        )
        last_ref_q = q_start_ref
        in_contact_run = False
        f_last: float | None = None
        found_early = False
        crease_out: float | None = None
        planner, tool_pose = self.planner, self.robot.tool_pose
        for i, segment in enumerate(segments):
            nxt = segments[i + 1] if i + 1 < len(segments) else None
            if segment.kind is SegmentKind.free:
                if nxt is not None and nxt.kind is SegmentKind.contact:
                    z = self.geometry[nxt.index].first_rotation[:, 2]
                    goal = planner.pre_contact(nxt.index)
                    plan = planner.free(segment, *tool_pose(), goal, stop_axis=z)
                    self.loop.touched = False
                    found_early = self._run(plan, self.sensor.free_guard(plan)) is PlanEnd.contact
                else:
                    dmp = segment.position_dmp
                    exit_axis = self.exit_axis if i > 0 and segments[i - 1].kind is SegmentKind.contact else None
                    if exit_axis is None:
                        goal = np.asarray(dmp.goal, float) + self.offset
                    else:  # the way out as taught from where the contact ended, not to a goal fixed in the world (a
                        # part found moved or tilted would put that goal in the part)
                        goal = tool_pose()[0] + np.asarray(dmp.goal, float) - np.asarray(dmp.start, float)
                    plan = planner.free(segment, *tool_pose(), goal, exit_axis)
                    if exit_axis is None:
                        found_early = self._run(plan) is PlanEnd.contact
                    elif (
                        self._run(plan, self.sensor.free_guard(plan)) is PlanEnd.contact
                    ):  # hit the part on the way out:
                        self.retract(exit_axis, segment.index)  # back off the way it lifted; the way out ends
                        found_early = False
                last_ref_q = plan.ref_q[-1]
                continue
            # Contact segment.
            if not in_contact_run:
                self.controller.reset_integral()
                if not found_early and self.sensor.tares and i > 0:  # (the settle tared at the first pre-contact point)
                    hold = planner.still(ExecutionPhase.approach, segment.index, goal, last_ref_q, TARE_HOLD_S)
                    self._run(hold)
                    self.sensor.after_still_hold(self.geometry[segment.index].first_rotation[:, 2])
                for attempt in range(2):  # a second touch-down where a relocated contour starts
                    # A surface met early (the part is nearer than taught) is touched down on again at the touch-down
                    # speed: the faster motion's impact may have bounced the tool off it.
                    speed = self.impacts.touchdown_speed(segment, self.geometry[segment.index].first_rotation[:, 2])
                    if not found_early:  # (else the free segment's record of what it touched stands)
                        self.loop.touched = False
                    self._run(planner.approach(segment, tool_pose()[0], last_ref_q, speed, fast=not found_early))
                    self._record_contact_offset(segment)
                    if self.follows_surface:  # a new contact run: the normal is tracked from the learned one
                        self._tracker = run_tracker(self.geometry[segment.index], self.dt)
                    f_first = first_force(segment)
                    self._ramp_up(segment, f_first, last_ref_q)
                    if attempt or not self._relocated(segment, f_first, last_ref_q):
                        break
                    planner = self.planner
                    goal = planner.pre_contact(segment.index)
                    z = self.geometry[segment.index].first_rotation[:, 2]
                    transfer = planner.transfer(segment.index, *tool_pose(), goal, last_ref_q, z)
                    self.loop.touched = False
                    found_early = self._run(transfer, self.sensor.free_guard(transfer)) is PlanEnd.contact
                f_last = None
            crease_in = crease_out if f_last is not None else None  # the crease the previous segment ended at
            next_contact = nxt is not None and nxt.kind is SegmentKind.contact
            crease_out = None
            if next_contact:
                z_before = self.geometry[segment.index].rotations[-1][:, 2]
                crease_out = self.impacts.crease_speed(z_before, nxt, self.geometry[nxt.index].first_rotation[:, 2])
            plan = planner.contact(segment, *tool_pose(), f_last, crease_in, crease_out, self.follows_surface)
            window = s.approach_slow_distance_m + CREASE_HOLD_DISTANCE_M  # how far from the switch a crease may be met
            if self.follows_surface and (crease_in is not None or crease_out is not None):
                plan.quick_steps = planner.crease_zone(
                    plan, window if crease_in is not None else -1.0, window if crease_out is not None else -1.0
                )
            if self.follows_surface and crease_out is not None:  # switch where the next surface is met
                plan.next_z = self.geometry[nxt.index].first_rotation[:, 2]
            end = self._run(plan)
            if end is PlanEnd.done and plan.next_z is not None:  # not there yet: carry on to the crease
                carry = planner.extension(segment, tool_pose()[0], plan, crease_out, window)
                carry.next_z = plan.next_z
                carry.quick_steps = np.ones(carry.steps, dtype=bool)
                end = self._run(carry)
            if plan.next_z is not None:
                self.next_surface_found[nxt.index] = end is PlanEnd.next_surface
            in_contact_run = True
            f_last = float(plan.force[-1])
            last_ref_q = plan.ref_q[-1]
            last_cf = plan.learned_rotations[-1] if plan.learned_rotations is not None else plan.frame.cf_rotation
            found_early = False
            if nxt is None or nxt.kind is SegmentKind.free:
                release = planner.release(segment, tool_pose()[0], f_last, last_ref_q, last_cf, at_end=True)
                release.follows_surface = self.follows_surface
                self._run(release)
                self._lift_off(segment.index, last_ref_q)
                in_contact_run = False
                f_last = None

    def outcome(self) -> tuple[ExecutionPhase, str | None]:
        """Run the execution (:meth:`run`); return how it ended and why: done, aborted with the reason (a contact lost
        is retracted first), or failed with the error (a bug or an unreachable pose: reported, never raised)."""
        try:
            try:
                self.run()
            except ContactLostError as lost:
                self.retract()
                raise ExecutionAbortError(str(lost)) from None
        except ExecutionAbortError as abort:
            return abort.phase, abort.reason
        except Exception as exc:  # a bug or an unreachable pose: report, do not crash the worker
            return ExecutionPhase.failed, f"{type(exc).__name__}: {exc}"
        return ExecutionPhase.done, None

    def log(self, work_piece: str | None) -> ExecutionLog:
        """What the phases found, for the metrics (``work_piece``: where the robot's work piece came from)."""
        return ExecutionLog(
            contact_offsets_m=self.contact_offsets,
            relocations_m=self.relocation.relocations,
            unconfirmed_relocations_m=self.relocation.unconfirmed,
            frame_log=self.loop.frame_log,
            contact_guard=self.sensor.guard if self.geometry else None,  # (a skill without contact guards nothing)
            surface_window_m=surface_window_m(self.settings),
            work_piece=work_piece,
            next_surface_found=self.next_surface_found,
        )
