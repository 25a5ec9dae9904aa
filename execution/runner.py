"""How a phase runs, seen from the phase sequencing (``execution.executor``): the engine's 1 kHz loop is a
:class:`PhaseRunner` (``sim_worker.control_loop.ControlLoop`` for PyBullet), a phase ends as :class:`PlanEnd` says or
by :class:`ExecutionAbortError` / :class:`ContactLostError`.
"""

from __future__ import annotations

from enum import Enum
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from execution.contact_detection import ContactGuard
from execution.plans import PhasePlan
from execution.surface_following import SurfaceFollower
from execution.telemetry import Telemetry
from schemas.execution import ExecutionPhase


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
