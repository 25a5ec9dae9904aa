"""Touch-down detection as a real integration does it: from the TARED force, with a threshold set from the noise
measured while the tool held still, and a required persistence.

A guarded motion ends when the mean of the last ``window_steps`` force readings along the approach axis (N, the
tool pushing along +axis) exceeds ``threshold_n``. One reading over a fixed threshold is what a noisy sensor fakes:
with 0.7 N of unfiltered noise a 1.5 N threshold is crossed in the air within a second. The window and the threshold
come from the readings of the tare hold (:func:`contact_guard_from_readings`): the shortest window whose mean's noise
stays ``NOISE_SIGMAS`` standard deviations under the skill's base threshold, else the longest window and a threshold
raised to ``NOISE_SIGMAS`` of its noise. A sensor's offset fixed in the world (a misestimated tool weight) is tared
only in the orientation of the tare; a guarded free segment that turns the tool adds what that offset can show
after turning (:func:`turned_offset_bound_n`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

NOISE_SIGMAS = 6.0
"""The detection threshold stays this many standard deviations of the windowed mean's noise above zero (a false
touch-down per step is then below 1e-9 for Gaussian noise; the noise estimate from 0.1 s of readings is rough)."""
WINDOW_STEPS = (2, 3, 5, 10, 20)
"""The persistence windows tried, steps (1 kHz): the shortest one whose noise allows the base threshold is used (a
longer one delays the touch-down by half its length, and the tool presses on meanwhile)."""
IDEAL_WINDOW_STEPS = 1
"""The exact contact wrench needs no persistence."""
CONTACT_THRESHOLD_RANGE_N = (1.0, 3.0)
"""The force along the approach that counts as contact unless the gains set one, N: a tenth of the skill's press,
within this range (`execution.executor`). Below its lower end a sensor cannot tell a touch from none, so a contact
phase commanding less presses nothing it could lose (`execution.runner.CONTACT_LOSS_TRAVEL_M`)."""


@dataclass(frozen=True)
class ContactGuard:
    """When a guarded motion has met a surface: the mean of the last ``window_steps`` readings along the approach
    axis above ``threshold_n`` (N)."""

    threshold_n: float
    window_steps: int = IDEAL_WINDOW_STEPS
    noise_std_n: float = 0.0
    """Standard deviation of one reading along the axis, measured during the hold, N (0: not measured)."""

    def raised_by(self, extra_n: float) -> ContactGuard:
        """The same guard with its threshold raised by ``extra_n`` (N)."""
        return ContactGuard(self.threshold_n + extra_n, self.window_steps, self.noise_std_n)

    def describe(self) -> str:
        """``"2.4 N over 5 ms"``, for messages (a 1 kHz loop)."""
        return f"{self.threshold_n:.1f} N over {self.window_steps} ms"


def contact_guard_from_readings(readings_n: NDArray[np.float64], base_threshold_n: float) -> ContactGuard:
    """The guard for readings ``readings_n`` (K,) along the approach axis taken while the tool held still (N, one per
    control step): the noise of each candidate window's running mean is measured on them (the sensor's filter makes
    neighbouring readings correlated, so the mean of ``w`` readings is noisier than ``std / sqrt(w)``)."""
    readings = np.asarray(readings_n, dtype=float)
    noise = float(np.std(readings))
    if readings.size < 2 * max(WINDOW_STEPS) or noise == 0.0:
        return ContactGuard(base_threshold_n, WINDOW_STEPS[0], noise)
    sums = np.concatenate([[0.0], np.cumsum(readings - readings.mean())])
    for window in WINDOW_STEPS:
        means = (sums[window:] - sums[:-window]) / window
        # Never below the uncorrelated value: 0.1 s of readings can underestimate a correlated mean's spread.
        spread = max(float(np.std(means)), noise / math.sqrt(window))
        if NOISE_SIGMAS * spread <= base_threshold_n:
            return ContactGuard(base_threshold_n, window, noise)
    return ContactGuard(NOISE_SIGMAS * spread, WINDOW_STEPS[-1], noise)


def turned_offset_bound_n(tare_force_n: NDArray[np.float64], tare_rotation: NDArray, rotations: NDArray) -> float:
    """The most a tared offset fixed in the WORLD can read after the tool turns from ``tare_rotation`` (3, 3) to
    each of ``rotations`` (N, 3, 3) (world from tool), N: the tare removed ``tare_force_n`` (3,) (tool frame) in
    the tare's orientation; turned by ``θ`` it leaves ``2 |f| sin(θ / 2)``. An offset that turns with the sensor
    (its own bias) leaves nothing, but the reading cannot tell the two apart."""
    magnitude = float(np.linalg.norm(tare_force_n))
    if magnitude == 0.0 or len(rotations) == 0:
        return 0.0
    relative = np.einsum("ji,njk->nik", tare_rotation, rotations)  # tare from now
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return 2.0 * magnitude * float(np.sin(np.arccos(cosine.min()) / 2.0))
