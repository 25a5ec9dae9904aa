"""The surface normal estimated online from the applied force and the motion, for a compliant frame that follows it.

The paper's CF is fixed from the demonstration. When the surface is tilted or curved differently than taught, the
force pressed along the learned CF z is no longer normal to it. While sliding, the force the tool applies is the
normal press plus friction along the motion: removing its component along the sliding direction leaves the normal
(the pressing direction, into the surface). Standing still, friction can point anywhere in its cone, so the force's
own direction is the normal only within the friction angle (``atan μ``, 11° at μ = 0.2): a first estimate, refined
once the tool slides. :class:`SurfaceNormalTracker` low-passes the estimate and turns the CF z towards it at a bounded
rate, never more than a bounded angle from the learned z (which a contour's frames turn along the path). World frame,
N, m/s, rad.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skills.frames import rotation_from_vectors


class SurfaceNormalTracker:
    """Follows the pressing direction (CF z, into the surface) from the applied force and the velocity.

    ``update`` is called every ``period_s``; the normal estimate is low-passed with ``time_constant_s``; the CF z
    turns by at most ``max_rate_rad_s`` and stays within ``max_deviation_rad`` of the learned z (``z0``, or the
    ``learned_z`` given to ``update``: a contour's taught z where the path is now). Below ``min_force_n`` of press the
    estimate does not move; sliding slower than ``min_speed_m_s`` (friction direction unknown) it does not move
    either, unless ``static_estimate``: then the normal is known to lie within ``static_cone_rad`` (the friction
    angle, 17° up to μ = 0.3) of the force's direction, and the CF z turns only when it lies outside that cone, to
    its nearest edge.
    """

    def __init__(
        self,
        z0: ArrayLike,
        period_s: float,
        time_constant_s: float = 0.1,
        max_rate_rad_s: float = math.radians(60.0),
        max_deviation_rad: float = math.radians(40.0),
        min_force_n: float = 1.0,
        min_speed_m_s: float = 0.005,
        static_estimate: bool = False,
        static_cone_rad: float = math.radians(17.0),
    ) -> None:
        self.z0 = np.asarray(z0, dtype=float) / np.linalg.norm(z0)
        self.z = self.z0.copy()
        self._period = period_s
        self.base_response = (time_constant_s, max_rate_rad_s)
        """The low-pass time constant (s) and the turn rate bound (rad/s) it was made with."""
        self.respond(*self.base_response)
        self._max_deviation = max_deviation_rad
        self._min_force = min_force_n
        self._min_speed = min_speed_m_s
        self._static = static_estimate
        self.static_cone_rad = static_cone_rad
        self._normal: NDArray[np.float64] | None = None

    def update(self, force: ArrayLike, velocity: ArrayLike, learned_z: ArrayLike | None = None) -> NDArray[np.float64]:
        """The CF z (3,) after this step's applied force (3,) N and tool velocity (3,) m/s; ``learned_z`` (3,) the
        learned CF z to stay within ``max_deviation_rad`` of (default ``z0``)."""
        f = np.asarray(force, dtype=float)
        v = np.asarray(velocity, dtype=float)
        speed = float(np.linalg.norm(v - (v @ self.z) * self.z))  # sliding: the motion in the surface, not into it
        if f @ self.z < self._min_force or (speed < self._min_speed and not self._static):
            return self.z
        if speed < self._min_speed:  # still: the normal lies within the friction cone about the force
            along = f / np.linalg.norm(f)
            if math.acos(float(np.clip(along @ self.z, -1.0, 1.0))) <= self.static_cone_rad:
                return self.z  # the z in use is one the force allows: no evidence to turn it
            normal = _towards(along, self.z, self.static_cone_rad)  # the nearest direction the force allows
        else:
            sliding = v / float(np.linalg.norm(v))
            normal = f - (f @ sliding) * sliding  # friction acts along the sliding direction
            normal /= np.linalg.norm(normal)
        self._normal = normal if self._normal is None else self._normal + self._alpha * (normal - self._normal)
        target = self._normal / np.linalg.norm(self._normal)
        z_learned = self.z0 if learned_z is None else np.asarray(learned_z, dtype=float)
        off = math.acos(float(np.clip(target @ z_learned, -1.0, 1.0)))
        if off > self._max_deviation:  # the farthest allowed from the learned z, towards the estimate
            target = _towards(z_learned, target, self._max_deviation)
        self.z = _towards(self.z, target, self._max_step)
        return self.z

    def respond(self, time_constant_s: float, max_rate_rad_s: float) -> None:
        """Follow with the low-pass time constant ``time_constant_s`` (s) and at most ``max_rate_rad_s`` (rad/s) from
        now on (quicker at a crease, where the normal turns at once; steadier elsewhere, where the estimate is
        noise)."""
        self._alpha = self._period / (self._period + time_constant_s)
        self._max_step = max_rate_rad_s * self._period

    def turned(self, rotation: NDArray[np.float64]) -> NDArray[np.float64]:
        """``rotation`` (3, 3, a learned CF, world from CF) turned by the least rotation that takes its z to the
        tracked one."""
        return rotation_from_vectors(rotation[:, 2], self.z) @ rotation


def _towards(a: NDArray[np.float64], b: NDArray[np.float64], max_angle: float) -> NDArray[np.float64]:
    """Unit vector ``a`` turned towards ``b`` by at most ``max_angle`` (rad)."""
    angle = math.acos(float(np.clip(a @ b, -1.0, 1.0)))
    if angle <= max_angle:
        return b
    axis = np.cross(a, b)
    axis /= np.linalg.norm(axis)
    c, s = math.cos(max_angle), math.sin(max_angle)
    return a * c + np.cross(axis, a) * s + axis * (axis @ a) * (1 - c)
