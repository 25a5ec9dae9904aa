"""Force profiles (paper Tables 1-2): the constant slide force and the contour force magnitude.

A slide presses one constant, as the paper does, only where the person's press was STEADY (`press_steadiness`):
then it is the mean of the steady press. A press that ramps (2 -> 20 N along a stroke) or wobbles (12 ± 5 N at
3 Hz) has no one value to stand for it (the old rule averaged its top half: 14.7 N for a 2 -> 20 N ramp), so such a
slide segment keeps its profile as a force DMP, as a contour does.

Forces are in N; the CF-z force of a sample is the applied force projected on its CF z axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from skills.segmentation import moving_std

LOW_VARIANCE_WINDOW_S = 0.2
"""Window of the moving standard deviation that finds the low-variance region, s."""

LOW_VARIANCE_FACTOR = 1.5
"""A sample is in the low-variance region when its moving std is below this times the median moving std."""

STEADY_SPREAD = 0.5
"""A press is steady while its 10th-90th percentile spread over the body of the segment is at most this fraction of
its median (a hand's slow ±20 % swing spreads 0.38; a ±5 N wobble on 12 N 0.79, a 2 -> 20 N ramp ~1)."""

STEADY_TREND = 0.5
"""...and its linear trend over the body changes it by at most this fraction of its median (a hand's slow ±20 %
swing over a 3.5 s stroke changed it by 0.42; a 2 -> 20 N ramp by ~1.2)."""

BODY_FRACTION = 0.5
"""The body of a segment's press: from where it first reaches this fraction of its median to where it last does
(the feet of the touch-down and lift-off ramps left out)."""

STEADY_BODY_FRACTION = 0.8
"""Steadiness is judged over the body above this fraction of the median (the ramps all left out: a short stroke's
ramps are half of it)."""

MIN_BODY_S = 0.3
"""A press whose body is shorter than this (s) is too short to show a ramp or a wobble: steady."""

STEADINESS_SMOOTHING_S = 0.02
"""The press is smoothed over this (s, Gaussian sigma) before its steadiness is judged: sensor noise, not a wobble."""

PLATEAU_FRACTION = 0.6
"""Samples pressing with less than this fraction of the segment's 90th-percentile force are ramps (or a dip between
strokes), not the plateau: a press swinging ±20 % stays above it, a short stroke's long ramps do not."""


@dataclass(frozen=True)
class ConstantForce:
    """The slide force: mean CF-z force (N) over the low-variance region, its std (N), and the region mask."""

    value_n: float
    std_n: float
    region: NDArray[np.bool_]


def cf_z_forces(forces: NDArray[np.float64], cf_z_axes: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the CF-z force per sample (N): applied forces (N, 3) projected on the CF z axes ((3,) or (N, 3))."""
    return np.sum(forces * cf_z_axes, axis=-1)


def plateau_mask(press: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Return where a segment's ``press`` (N,) N is on its plateau: at least ``PLATEAU_FRACTION`` of its 90th
    percentile."""
    return press >= PLATEAU_FRACTION * np.percentile(press, 90)


def constant_force(cf_z_force: NDArray[np.float64], rate_hz: float) -> ConstantForce:
    """Return the CF-z force of a slide contact segment: the mean over its low-variance region (paper 4.1).

    The region is where the moving standard deviation (``LOW_VARIANCE_WINDOW_S``) is below
    ``LOW_VARIANCE_FACTOR`` times its median and the force is on the plateau (`plateau_mask`): it
    leaves out the ramps at touch-down and lift-off (steep in the middle, nearly flat at their
    feet), a dip between strokes and bursts, and keeps the steady pressing the skill should
    reproduce.
    """
    window = max(3, round(LOW_VARIANCE_WINDOW_S * rate_hz))
    spread = moving_std(cf_z_force, window)
    region = (spread <= LOW_VARIANCE_FACTOR * np.median(spread)) & plateau_mask(cf_z_force)
    values = cf_z_force[region]
    return ConstantForce(float(values.mean()), float(values.std()), region)


@dataclass(frozen=True)
class PressSteadiness:
    """How steady a segment's press was: ``spread`` its 10th-90th percentile spread and ``trend`` the change its
    linear trend makes over the body of the segment, both over its median (module constants); ``steady`` both
    within their limits."""

    spread: float
    trend: float

    @property
    def steady(self) -> bool:
        """Whether one constant stands for the press (``STEADY_SPREAD``, ``STEADY_TREND``)."""
        return self.spread <= STEADY_SPREAD and abs(self.trend) <= STEADY_TREND


def press_body(press: NDArray[np.float64], fraction: float = BODY_FRACTION) -> slice:
    """The body of a segment's ``press`` (N,) N: from where it first reaches ``fraction`` of its median to where it
    last does."""
    reached = np.flatnonzero(press >= fraction * np.median(press))
    return slice(int(reached[0]), int(reached[-1]) + 1) if reached.size else slice(0, press.size)


def press_steadiness(cf_z_force: NDArray[np.float64], rate_hz: float) -> PressSteadiness:
    """Return how steady the CF-z press (N,) N of a contact segment sampled at ``rate_hz`` was over its body."""
    smoothed = gaussian_filter1d(cf_z_force, max(1.0, STEADINESS_SMOOTHING_S * rate_hz), mode="nearest")
    body = smoothed[press_body(smoothed, STEADY_BODY_FRACTION)]
    if body.size < max(3, MIN_BODY_S * rate_hz):
        return PressSteadiness(spread=0.0, trend=0.0)
    median = max(float(np.median(body)), 1e-9)
    low, high = np.percentile(body, [10, 90])
    slope = np.polyfit(np.arange(body.size) / rate_hz, body, 1)[0]
    return PressSteadiness(spread=float((high - low) / median), trend=float(slope * body.size / rate_hz / median))
