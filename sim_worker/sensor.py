"""The force/torque sensor model: what the controller reads instead of the exact contact wrench.

The exact wrench is the one the tool applies to the environment at the tool point, world frame (N, N·m;
docs/CONVENTIONS.md). The sensor adds white Gaussian noise (``WorldConfig.wrench_noise_*``) and then a
first-order low-pass (``WorldConfig.wrench_filter_cutoff_hz``), once per control step. With neither set it is
ideal: the controller reads the exact wrench.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from sim_worker.world_config import WorldConfig


class WrenchSensor:
    """A noisy, low-pass filtered wrench sensor; ``measure`` is called once per control step."""

    def __init__(self, config: WorldConfig) -> None:
        self.config = config
        self._std = np.array([config.wrench_noise_force_std_n] * 3 + [config.wrench_noise_torque_std_nm] * 3)
        self._noisy = bool(np.any(self._std > 0.0))
        self._cutoff_hz = config.wrench_filter_cutoff_hz
        self._rng = np.random.default_rng(config.seed)
        self._filtered: NDArray[np.float64] | None = None

    @property
    def ideal(self) -> bool:
        """True when the sensor reports the exact wrench (no noise, no filter)."""
        return not self._noisy and self._cutoff_hz is None

    def reset(self) -> None:
        """Forget the filter state (the next measurement starts it again)."""
        self._filtered = None

    def measure(self, exact: NDArray[np.float64]) -> NDArray[np.float64]:
        """The reading (6,) for this step's exact wrench (6,): noise added, then low-pass filtered."""
        raw = exact + self._rng.normal(0.0, 1.0, 6) * self._std if self._noisy else exact.copy()
        if self._cutoff_hz is None:
            return raw
        if self._filtered is None:
            self._filtered = raw
        else:
            dt = self.config.time_step_s
            alpha = dt / (dt + 1.0 / (2.0 * math.pi * self._cutoff_hz))
            self._filtered = self._filtered + alpha * (raw - self._filtered)
        return self._filtered.copy()
