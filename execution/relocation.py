"""Where a contour that follows the surface was met, when not at its start (``execution.executor``): how far its part
moved from one touch-down (``execution.surface_following.relocation_offset`` on the pressing direction), and whether
a second touch confirms it, with the record of the moves believed and of those not."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from execution.plans import ContactGeometry
from execution.robot import Robot
from execution.runner import PhaseRunner
from execution.surface_following import relocation_offset
from schemas.skill import Segment
from skills.dmp import DMP

CONFIRM_LIFT_M = 0.01
"""Before a contour is relocated, the tool lifts this far off where it touched down and touches down again, m."""
RELOCATION_AGREEMENT_M = 0.01
"""... and the second touch must find the part moved as the first did within this, m."""
RELOCATION_SAMPLES = 101
"""Places along a contour whose taught normal a touch-down's pressing direction is matched against."""
RELOCATION_MIN_FORCE_N = 0.5
"""Below this mean press a touch-down's force direction is not trusted to locate it (a contour's force profile may
start below the contact threshold), N."""
RELOCATION_AVERAGE_S = 0.05
"""The pressing direction at a touch-down is the mean force over the last this long of the force ramp, s."""


class ContourRelocation:
    """The moves of a contour's part found by touch-downs in ``loop`` on ``robot`` (control step ``dt``, s), no
    farther than ``max_shift_m`` (the approach's reach, m): :attr:`relocations` those confirmed (and relocated),
    :attr:`unconfirmed` those a second touch did not confirm (m, world)."""

    def __init__(self, robot: Robot, loop: PhaseRunner, dt: float, max_shift_m: float) -> None:
        self.robot, self.loop, self.dt, self.max_shift_m = robot, loop, dt, max_shift_m
        self.relocations: list[list[float]] = []
        """The offsets (m, world) by which contours were found moved and relocated."""
        self.unconfirmed: list[list[float]] = []
        """The moves of the part a touch-down suggested and a second touch did not confirm (m, world)."""

    def touch_shift(
        self, segment: Segment, geometry: ContactGeometry, offset: NDArray[np.float64], cone_rad: float | None
    ) -> NDArray[np.float64] | None:
        """How far the part moved, from the touch-down just made on contact ``segment`` (its frames ``geometry``,
        moved by the known ``offset``, m): the direction the tool presses in over the last ``RELOCATION_AVERAGE_S``
        (the normal lies within the friction cone ``cone_rad`` about it; None: no surface tracked) farther than the
        friction angle from the taught normal at the start and within it of the taught normal somewhere else along the
        path ``s*``: the part moved by ``p - p_taught(s*)``. None: met where taught, a press too light to tell, or a
        move beyond the approach's reach."""
        force = self.loop.recent(RELOCATION_AVERAGE_S).wrench_world[:, :3].mean(axis=0)
        if cone_rad is None or float(np.linalg.norm(force)) < RELOCATION_MIN_FORCE_N:
            return None
        fractions = np.linspace(0.0, 1.0, RELOCATION_SAMPLES)
        path = DMP.from_parameters(segment.position_dmp).rollout(self.dt).y + offset
        shift = relocation_offset(
            geometry.rotations_at(fractions)[:, :, 2],
            path,
            force / np.linalg.norm(force),
            self.robot.tool_pose()[0],
            cone_rad,
        )
        if shift is None or float(np.linalg.norm(shift)) > self.max_shift_m:
            return None
        return shift

    def confirmed(self, first: NDArray[np.float64], second: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
        """The part's move when a second touch's shift ``second`` agrees with the first's ``first`` within
        ``RELOCATION_AGREEMENT_M``: the mean of the two (the caller records it in :attr:`relocations` once relocated),
        else None (``first`` recorded as not confirmed)."""
        if second is None or float(np.linalg.norm(second - first)) > RELOCATION_AGREEMENT_M:
            self.unconfirmed.append(first.tolist())
            return None
        return 0.5 * (first + second)
