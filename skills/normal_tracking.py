"""The surface normal estimated online from the applied force and the motion, for a compliant frame that follows it.

The paper's CF is fixed from the demonstration. When the surface is tilted differently than taught, the force
pressed along the learned CF z is no longer normal to it. While sliding, the force the tool applies is the normal
press plus friction along the motion: removing its component along the sliding direction leaves the normal (the
pressing direction, into the surface). :class:`SurfaceNormalTracker` low-passes that estimate and turns the CF z
towards it at a bounded rate, never more than a bounded angle from the learned z. World frame, N, m/s, rad.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


class SurfaceNormalTracker:
    """Follows the pressing direction (CF z, into the surface) of a slide from the applied force and the velocity.

    ``update`` is called every ``period_s``; the force estimate is low-passed with ``time_constant_s``; the CF z
    turns by at most ``max_rate_rad_s`` and stays within ``max_deviation_rad`` of the learned ``z0``. Below
    ``min_force_n`` of press or while sliding slower than ``min_speed_m_s`` (friction direction unknown) the
    estimate does not move.
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
    ) -> None:
        self.z0 = np.asarray(z0, dtype=float) / np.linalg.norm(z0)
        self.z = self.z0.copy()
        self._alpha = period_s / (period_s + time_constant_s)
        self._max_step = max_rate_rad_s * period_s
        self._max_deviation = max_deviation_rad
        self._min_force = min_force_n
        self._min_speed = min_speed_m_s
        self._normal: NDArray[np.float64] | None = None

    def update(self, force: ArrayLike, velocity: ArrayLike) -> NDArray[np.float64]:
        """The CF z (3,) after this step's applied force (3,) N and tool velocity (3,) m/s."""
        f = np.asarray(force, dtype=float)
        v = np.asarray(velocity, dtype=float)
        speed = float(np.linalg.norm(v))
        if speed < self._min_speed or f @ self.z < self._min_force:
            return self.z
        sliding = v / speed
        normal = f - (f @ sliding) * sliding  # friction acts along the sliding direction
        normal /= np.linalg.norm(normal)
        self._normal = normal if self._normal is None else self._normal + self._alpha * (normal - self._normal)
        target = self._normal / np.linalg.norm(self._normal)
        off = math.acos(float(np.clip(target @ self.z0, -1.0, 1.0)))
        if off > self._max_deviation:  # the farthest allowed from the learned z, towards the estimate
            target = _towards(self.z0, target, self._max_deviation)
        self.z = _towards(self.z, target, self._max_step)
        return self.z


def _towards(a: NDArray[np.float64], b: NDArray[np.float64], max_angle: float) -> NDArray[np.float64]:
    """Unit vector ``a`` turned towards ``b`` by at most ``max_angle`` (rad)."""
    angle = math.acos(float(np.clip(a @ b, -1.0, 1.0)))
    if angle <= max_angle:
        return b
    axis = np.cross(a, b)
    axis /= np.linalg.norm(axis)
    c, s = math.cos(max_angle), math.sin(max_angle)
    return a * c + np.cross(axis, a) * s + axis * (axis @ a) * (1 - c)
