"""How fast the tool may meet a surface: at a touch-down, and at a crease between two contact segments.

A tool of apparent mass ``m`` meeting a contact of stiffness ``k`` and damping ``c`` at speed ``v`` peaks at about
``v max(sqrt(k m), c)`` above the press it is commanded to (measured here: 2.2 kN·s/m on 1e6 N/m, 0.4 kN·s/m on
3e4 N/m). :class:`ImpactPlanner` keeps that impact to a fraction of the press: the touch-down speed of a guarded
approach, the tangential speed at which a crease is passed. World frame, SI units.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from execution.metrics import STEADY_CONTACT_DELAY_S
from execution.plans import first_force, force_after
from execution.robot import Robot
from schemas.execution import ExecutionSettings
from schemas.skill import Segment
from skills.control.layouts import ROBOT_JACOBIAN
from skills.job_estimate import TOUCHDOWN_SPEED_MIN_M_S

TOUCHDOWN_IMPACT_FRACTION = 0.8
"""The touch-down speed keeps the impact below this fraction of the press that follows (the desired force where the
steady contact begins, the touch-down check's reference): the impact comes before the desired force ramps up, so the
touch-down peak is then the target itself."""
CREASE_IMPACT_FRACTION = 0.1
"""The impact at a crease, as a fraction of the press, that sets the speed to pass it (``crease_speed``)."""
CREASE_MIN_ANGLE_RAD = math.radians(3.0)
"""Segments whose CF z differ by less are passed at full speed."""


class ImpactPlanner:
    """The impact speeds of one execution on ``robot`` (its arm; its contact as planned for by ``settings``, else the
    ``contact`` stiffness N/m and damping N·s/m, a simulator's own), for a contact threshold of
    ``contact_threshold_n`` (N) at the control step ``dt`` (s)."""

    def __init__(
        self,
        robot: Robot,
        settings: ExecutionSettings,
        contact_threshold_n: float,
        dt: float,
        contact: tuple[float, float],
    ) -> None:
        self.robot = robot
        self.contact = contact
        self.settings = settings
        self.contact_threshold_n = contact_threshold_n
        self.dt = dt

    def contact_impedance(self, z: NDArray[np.float64]) -> float:
        """The touch-down peak per unit impact speed (N·s/m) of a contact along the world direction ``z``:
        ``max(sqrt(k m), c)``, ``k`` and ``c`` the contact's stiffness and damping as planned for (the settings'
        ``planned_contact_*``, else the simulator's ``contact``), ``m`` the arm's apparent mass along ``z`` in its pose
        now.

        A mass ``m`` meeting a spring ``k`` and a damper ``c`` side by side at speed ``v`` peaks at
        ``v sqrt(k m) g(ζ)``, ``ζ = c / (2 sqrt(k m))``: ``g`` stays at or below 1 up to ``ζ = 1/2`` (the damper takes
        off some of the spring's peak) and is ``2ζ`` above it (the damper's ``c v`` at the first instant is the peak;
        worked out from the closed-form motion). The maximum of the two bounds both."""
        J = self.robot.robot_state()[ROBOT_JACOBIAN].reshape(6, 7)
        mobility = J[:3] @ np.linalg.solve(self.robot.mass_matrix(), J[:3].T)  # Λ^-1, translational block
        mass = 1.0 / max(float(z @ mobility @ z), 1e-9)
        s, (k, c) = self.settings, self.contact
        k = k if s.planned_contact_stiffness_n_m is None else s.planned_contact_stiffness_n_m
        c = c if s.planned_contact_damping_n_s_m is None else s.planned_contact_damping_n_s_m
        return max(math.sqrt(k * mass), c)

    def touchdown_speed(self, segment: Segment, z: NDArray[np.float64]) -> float:
        """The speed (m/s) at which the tool meets the surface of ``segment`` along ``z`` (its first CF z, world):
        given, or ``TOUCHDOWN_IMPACT_FRACTION`` of the press that follows, the desired force where the steady contact
        begins (at least the contact threshold: the approach runs on until the force passes it, so a softer impact
        buys nothing but time) over :meth:`contact_impedance`, clipped to ``[TOUCHDOWN_SPEED_MIN_M_S,
        approach_speed_m_s]``. A contour's force profile may start far below its press (0.9 N, 8 N 0.25 s later):
        planning the impact for its first force made the approach crawl."""
        s = self.settings
        if s.touchdown_speed_m_s is not None:
            return float(s.touchdown_speed_m_s)
        settled = force_after(segment, max(STEADY_CONTACT_DELAY_S, s.gains.force_ramp_s), self.dt)
        impact_n = TOUCHDOWN_IMPACT_FRACTION * max(first_force(segment), settled, self.contact_threshold_n)
        speed = impact_n / self.contact_impedance(z)
        return float(np.clip(speed, TOUCHDOWN_SPEED_MIN_M_S, s.approach_speed_m_s))

    def crease_speed(self, z_before: NDArray[np.float64], after: Segment, z_after: NDArray[np.float64]) -> float | None:
        """The tangential speed (m/s) at which to pass the crease from a surface of normal ``z_before`` onto the one
        of the contact segment ``after`` (normal ``z_after``), or None when they differ by less than
        ``CREASE_MIN_ANGLE_RAD``: the next surface is met at ``v sin θ`` along its normal, an impact of about
        ``v sin θ`` times :meth:`contact_impedance` on top of the press, kept to ``CREASE_IMPACT_FRACTION`` of it."""
        sin_angle = float(np.linalg.norm(np.cross(z_before, z_after)))
        if sin_angle < math.sin(CREASE_MIN_ANGLE_RAD):
            return None
        press = max(first_force(after), self.contact_threshold_n)
        speed = CREASE_IMPACT_FRACTION * press / self.contact_impedance(z_after) / sin_angle
        return max(speed, TOUCHDOWN_SPEED_MIN_M_S)
