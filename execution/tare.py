"""The wrist sensor between contacts during one execution (``execution.executor``): tared with its mean reading at
the end of each still hold in free space, and the contact guard of the next guarded approach set from the noise it
showed there (``execution.contact_detection``)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from execution.contact_detection import (
    IDEAL_WINDOW_STEPS,
    WINDOW_STEPS,
    ContactGuard,
    contact_guard_from_readings,
    turned_offset_bound_n,
)
from execution.plans import PhasePlan
from execution.robot import Robot
from execution.runner import PhaseRunner
from skills.quaternions import matrix_from_quaternion

TARE_AVERAGE_S = 0.1
"""The tare is the mean reading over the last this long of the still hold (``TARE_HOLD_S``), s."""
NOISE_WINDOW_S = 0.15
"""The sensor's noise along the next approach is measured over the last this long of a still hold, s (its first
moments still carry the deceleration the tool's inertia shows)."""


class FreeSpaceSensor:
    """The sensor of ``robot`` in free space, read in the telemetry of ``loop``: tared in the still holds when
    ``tares``, the contact guard from ``contact_threshold_n`` (N) and the noise measured in those holds."""

    def __init__(self, robot: Robot, loop: PhaseRunner, tares: bool, contact_threshold_n: float) -> None:
        self.robot, self.loop = robot, loop
        self.tares = tares
        """Whether the sensor is tared in free space before the guarded approaches (an ideal sensor has no offset)."""
        self.contact_threshold = contact_threshold_n
        window = IDEAL_WINDOW_STEPS if robot.sensor_ideal else WINDOW_STEPS[0]
        self.guard = ContactGuard(contact_threshold_n, window)
        """When a guarded approach has met the surface; set from the noise measured in each still hold."""
        self.tare_rotation = np.eye(3)
        """The tool's orientation (world from tool) at the last tare."""

    def after_still_hold(self, axis: NDArray[np.float64] | None) -> None:
        """At the end of a still hold in free space: tare the sensor (``self.tares``) and set the
        contact guard of the next guarded approach along ``axis`` (world, unit; None: no approach follows) from the
        noise its readings showed over the last ``NOISE_WINDOW_S`` (a non-ideal sensor; the ideal one keeps the base
        threshold)."""
        if self.tares:
            self._tare()
        if axis is not None and not self.robot.sensor_ideal:
            readings = self.loop.recent(NOISE_WINDOW_S).wrench_world[:, :3] @ axis
            self.guard = contact_guard_from_readings(readings, self.contact_threshold)

    def _tare(self) -> None:
        """Tare the wrist sensor with its mean reading over the last ``TARE_AVERAGE_S`` of telemetry (the tool held
        still in free space), taken in the TOOL frame where a sensor offset lives: the readings there carry the
        previous tare removed, so it is added back. The current reading is tared too (``SimWorld.tare_sensor``)."""
        held = self.loop.recent(TARE_AVERAGE_S)
        rotations = matrix_from_quaternion(held.tool_orientation)  # world from tool
        wrench = held.wrench_world
        force = np.einsum("nji,nj->i", rotations, wrench[:, :3]) / len(held)
        moment = np.einsum("nji,nj->i", rotations, wrench[:, 3:]) / len(held)
        self.robot.tare_sensor(self.robot.sensor_tare + np.concatenate((force, moment)))
        self.tare_rotation = rotations[-1]

    def free_guard(self, plan: PhasePlan) -> ContactGuard:
        """The guard of a free segment that may meet the next surface early: the approach's, raised by what a tared
        offset fixed in the world can read once the plan has turned the tool away from the tare's orientation."""
        if not self.tares:
            return self.guard
        rotations = matrix_from_quaternion(plan.ref_q)
        return self.guard.raised_by(turned_offset_bound_n(self.robot.sensor_tare[:3], self.tare_rotation, rotations))
