"""How a phase runs, seen from the phase sequencing (``execution.executor``): the engine's 1 kHz loop is a
:class:`PhaseRunner` (``sim_worker.control_loop.ControlLoop`` for PyBullet, ``sim_mujoco.loop.MujocoLoop`` for
MuJoCo), a phase ends as :class:`PlanEnd` says or by :class:`ExecutionAbortError` / :class:`ContactLostError`.
What every engine's loop shares (the telemetry rows and their batches, the loop's constants, the reasons a phase
stops) is :class:`RecordingLoop`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from enum import Enum
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from execution.contact_detection import CONTACT_THRESHOLD_RANGE_N, ContactGuard
from execution.plans import CONTACT_LOSS_RETRACT_M, PhasePlan
from execution.robot import Robot
from execution.surface_following import SurfaceFollower
from execution.telemetry import Telemetry
from schemas.execution import TELEMETRY_WIDTH, ExecutionPhase, Pace
from skills.control import ControlFrame, HybridController

NULL_SPACE_UPDATE_STEPS = 20
"""The null-space projector (and the mass matrix it needs) is refreshed every this many steps."""
CONTACT_LOSS_TRAVEL_M = 0.01
"""In a contact phase, the tool out of contact and this far beyond its reference along CF z has lost the surface
(an edge, a hole): it stops pressing into nothing, retracts and the execution aborts with the reason, m. Only while
the phase commands a press of at least :data:`CONTACT_LOSS_MIN_PRESS_N`: a press faded below it (a contact phase's
end, its force ramped down) leaves the surface because it lifts off, not because the surface is gone."""
CONTACT_LOSS_MIN_PRESS_N = CONTACT_THRESHOLD_RANGE_N[0]
"""The least commanded press along CF z (N) a contact can be lost under: the least force that counts as contact."""
UNGUARDED = ContactGuard(math.inf)
"""The guard of a phase without a stop axis (it reads nothing; a contact phase names the approaches' guard in its
reasons)."""
REALTIME_CHECK_STEPS = 10
"""With pace realtime, the loop sleeps to follow the wall clock every this many steps."""


class PlanEnd(Enum):
    """How a phase plan ended (``PhaseRunner.run_plan``)."""

    done = "done"
    """It ran to its last step."""
    contact = "contact"
    """A guarded phase met a surface (:class:`ContactGuard`)."""
    next_surface = "next_surface"
    """A phase that follows the surface found itself on the next segment's surface (a crease, met early)."""


class ContactLostError(Exception):
    """Raised inside the loop when the tool lost the surface in a contact phase (it is retracted, then aborted)."""


class ExecutionAbortError(Exception):
    """Raised inside the loop to stop the execution with a reason."""

    def __init__(self, reason: str, phase: ExecutionPhase = ExecutionPhase.aborted) -> None:
        super().__init__(reason)
        self.reason = reason
        self.phase = phase


class PhaseRunner(Protocol):
    """Runs one phase plan at a time on a robot with a controller at the robot's time step, recording every step as a
    telemetry row (``sim_worker.control_loop.ControlLoop``)."""

    cf_rotation: NDArray[np.float64]
    """The CF rotation (3, 3) of the control frame in use, world from CF."""
    touched: bool
    """Whether the tool has touched anything since the caller last cleared it."""
    found_force: float | None
    """The windowed reading along the stop axis when the last guarded phase met a surface, N."""
    frame_log: list[tuple[int, float, float, float]]
    """(telemetry row, CF z) each time the controller took a new control frame."""
    wall_start: float
    """When the loop began (a realtime pace follows the wall clock from here), s (``time.perf_counter``)."""

    def run_plan(
        self,
        plan: PhasePlan,
        guard: ContactGuard = ...,
        references: NDArray[np.float64] | None = None,
        follower: SurfaceFollower | None = None,
    ) -> PlanEnd:
        """Run ``plan`` and say how it ended (``ControlLoop.run_plan``)."""
        ...

    def recent(self, duration_s: float) -> Telemetry:
        """The rows of the last ``duration_s`` (s) recorded."""
        ...

    def telemetry(self, copy: bool = True) -> Telemetry:
        """The rows recorded so far."""
        ...

    def emit(self, final: bool = False) -> None:
        """Hand the rows recorded since the last batch to the listener."""
        ...


class RecordingLoop:
    """What every engine's 1 kHz loop shares (a :class:`PhaseRunner`'s state apart from its stepping): ``robot`` and
    ``controller`` run at the robot's time step ``dt`` (s), the telemetry rows (one float row per step,
    :data:`schemas.execution.TELEMETRY_COLUMNS`, room for ``capacity_s`` at first, doubling when full) handed to
    ``on_sample`` in batches of ``telemetry_batch``, ``pace`` realtime following the wall clock, ``dynamic_null``
    refreshing the mass matrix for the null-space projector, ``should_abort()`` polled after every step and
    ``should_pause()`` before, the step count, the contact the guarded phases found, the control frames taken, and
    the reasons a phase stops (the robot's joint limits, a contact lost). An engine's loop adds its own state in
    :meth:`_engine_state`."""

    def __init__(
        self,
        robot: Robot,
        controller: HybridController,
        capacity_s: float,
        telemetry_batch: int,
        pace: Pace,
        dynamic_null: bool,
        on_sample: Callable[[Telemetry], None] | None,
        should_abort: Callable[[], bool] | None,
        should_pause: Callable[[], bool] | None,
    ) -> None:
        self.controller = controller
        self.dt = float(robot.time_step_s)
        self.telemetry_batch = telemetry_batch
        self.realtime = pace is Pace.realtime
        self.dynamic_null = dynamic_null
        self.on_sample = on_sample
        self.should_abort = should_abort
        self.should_pause = should_pause
        self.joint_lower, self.joint_upper = robot.joint_lower, robot.joint_upper
        self.capacity = max(4096, round(capacity_s / self.dt))
        self.rows = np.zeros((self.capacity, TELEMETRY_WIDTH))
        self.n = 0
        """Rows recorded."""
        self.emitted = 0
        self.step_count = 0
        self.wall_start = time.perf_counter()
        """When the loop began (the realtime pace follows the wall clock from here), s."""
        self.found_force: float | None = None
        """The windowed reading along the stop axis when the last guarded phase met a surface, N."""
        self.touched = False
        """Whether the tool has touched anything (the simulator's contact) since the caller last cleared it."""
        self.frame_log: list[tuple[int, float, float, float]] = []
        """(telemetry row, CF z) each time the controller took a new control frame: the frames it actually used."""
        self.cf_rotation = np.eye(3)
        """The CF rotation of the control frame in use (world from CF)."""
        self._tracked: tuple[list[float], int] | None = None
        """The tool position (m, world) and the step of the follower's last update in this phase."""
        self._engine_state(robot)

    def _engine_state(self, robot: Robot) -> None:
        """An engine's loop keeps ``robot`` and its own buffers here (called last by ``__init__``)."""

    def telemetry(self, copy: bool = True) -> Telemetry:
        """The rows recorded so far: a copy, or (``copy`` False, for the caller that is done with the loop) a view of
        the loop's own rows, which the next recorded row would change (no second copy of a minute's 17 MB; the rows
        allocated beyond them were never written, so not resident)."""
        rows = self.rows[: self.n]
        return Telemetry(rows.copy() if copy else rows)

    def recent(self, duration_s: float) -> Telemetry:
        """The rows of the last ``duration_s`` (s) recorded (a view: read it before the loop runs on)."""
        return Telemetry(self.rows[max(0, self.n - round(duration_s / self.dt)) : self.n])

    def _grow(self, n: int) -> tuple[NDArray[np.float64], int]:
        """Double the rows allocated, the ``n`` recorded kept; return the new rows and capacity."""
        self.n = n
        self.capacity *= 2
        rows = np.zeros((self.capacity, TELEMETRY_WIDTH))
        rows[: self.n] = self.rows[: self.n]
        self.rows = rows
        return rows, self.capacity

    def emit(self, final: bool = False) -> None:
        """Hand the rows recorded since the last batch to ``on_sample`` (a full batch, or whatever is left when
        ``final``)."""
        pending = self.n - self.emitted
        if self.on_sample is not None and pending > 0 and (final or pending >= self.telemetry_batch):
            self.on_sample(Telemetry(self.rows[self.emitted : self.n].copy()))
            self.emitted = self.n

    def _follow(
        self,
        follower: SurfaceFollower,
        k: int,
        force: list[float],
        position: list[float],
        step_count: int,
        pressing: bool,
        references: NDArray[np.float64],
    ) -> ControlFrame | None:
        """The follower's update at the plan's step ``k`` (``SurfaceFollower.update``) with this step's reading
        ``force`` (3,) N and tool ``position`` (3,) m, world, and the tool's velocity since its last update in this
        phase (zero at the first; the caller clears ``_tracked`` when a phase starts): the frame to hold, or None."""
        velocity = [0.0, 0.0, 0.0]
        if self._tracked is not None:
            before, step_before = self._tracked
            span = (step_count - step_before) * self.dt
            velocity = [(a - b) / span for a, b in zip(position, before, strict=True)]
        frame = follower.update(k, force, velocity, position, pressing, references)
        self._tracked = (position, step_count)
        return frame

    def _keep_pace(self, step_count: int) -> None:
        """With pace realtime: sleep until the wall clock since ``wall_start`` catches up with ``step_count`` steps."""
        lag = step_count * self.dt - (time.perf_counter() - self.wall_start)
        if lag > 0:
            time.sleep(lag)

    def _ran_to_the_end(self, plan: PhasePlan, guard: ContactGuard) -> PlanEnd:
        """How a phase that ran all its steps ended: done, or (a plan that must not run out, such as a guarded approach
        that met nothing) aborted with its reason, naming the guard a guarded phase's readings stayed under."""
        if plan.exhausted_reason is not None:
            guarded = "" if plan.stop_axis is None else f": the sensor never read above {guard.describe()}"
            raise ExecutionAbortError(plan.exhausted_reason + guarded)
        return PlanEnd.done

    def _loss_reason(self, segment: int, beyond_m: float, touched: bool, guard: ContactGuard) -> str:
        """Why a contact phase stopped pressing into nothing ``beyond_m`` past its reference: the surface was lost,
        or, when the tool never touched anything since its guarded approach began, never made (the approach took a
        reading for the surface)."""
        t = f"t = {self.step_count * self.dt:.3f} s"
        retracted = f"the tool stopped pressing and retracted {CONTACT_LOSS_RETRACT_M * 1e3:.0f} mm"
        if not touched:
            found = "" if self.found_force is None else f" (it read {self.found_force:.2f} N)"
            return (
                f"no contact made in segment {segment} at {t}: the guarded approach stopped on a reading of the "
                f"sensor above {guard.describe()}{found} without touching anything (a sensor offset or noise "
                f"the tare did not remove?), and the tool found nothing {beyond_m * 1e3:.0f} mm beyond; {retracted}"
            )
        return (
            f"contact lost in segment {segment} at {t}: no contact {beyond_m * 1e3:.0f} mm beyond the surface along "
            f"CF z (an edge or a hole?); {retracted}"
        )

    def _joint_limit_reason(self, q: NDArray[np.float64]) -> str:
        """Name the joint outside its URDF limits (neither engine enforces them in torque mode)."""
        lower, upper = self.joint_lower, self.joint_upper
        j = int(np.argmax(np.maximum(lower - q, q - upper)))
        return f"joint limit: joint {j + 1} at {q[j]:.3f} rad outside [{lower[j]:.3f}, {upper[j]:.3f}] rad"
