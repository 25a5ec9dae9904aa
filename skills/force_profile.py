"""Force profiles (paper Tables 1-2): the constant slide force and the contour force magnitude.

Forces are in N; the CF-z force of a sample is the applied force projected on its CF z axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skills.segmentation import moving_std

LOW_VARIANCE_WINDOW_S = 0.2
"""Window of the moving standard deviation that finds the low-variance region, s."""

LOW_VARIANCE_FACTOR = 1.5
"""A sample is in the low-variance region when its moving std is below this times the median moving std."""

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
