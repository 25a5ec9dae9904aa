"""Where a tool pressed against where it was taught, told by surface normals (unit, into the surface, world frame).

Normals do not move when a part is moved, so they say WHERE on a part a tool pressed whatever its place: a contour
taught over -50°..+50° of a cylinder and run over -70°..+30° of it covered 80 % of its taught region, wherever the
cylinder stood. Three comparisons, each between a normal the tool pressed on (measured) and one it was taught:

- **a normal against the taught one**: the angle between them (``angles_deg``);
- **a switch between two surfaces**: how far the normal pressed turned across it, about the axis of the taught crease
  (:func:`crease_turn_deg`): a part tilted as a whole turns as taught, a steeper surface turns more, a surface that
  is not there (a ramp removed) turns nothing;
- **a contour's region**: the normals taught along a contour turn about one axis; each normal's angle about it
  (:class:`TurnPlane`) places it on the part, and the share of the taught span of angles the pressed span covers is
  the region covered (:func:`span_deg`, :func:`region_coverage`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

MIN_TURN_DEG = 10.0
"""A contour whose taught normals turn less than this has no region to cover along its turn (it is a slide's), deg."""
REGION_PERCENTILE = 2.0
"""A region spans its normals' angles from this percentile to 100 minus it, %."""


def unit_mean(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """The mean direction (3,) of ``vectors`` (N, 3), unit length (the mean of the unit vectors, normalized)."""
    v = vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
    mean = v.mean(axis=0)
    return mean / np.linalg.norm(mean)


def angles_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles between the unit vectors ``a`` and ``b`` ((N, 3) or (3,), broadcast), deg."""
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def mean_angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """The angle between the mean directions (:func:`unit_mean`) of the unit vectors ``a`` and ``b`` ((N, 3) each),
    deg."""
    return float(angles_deg(unit_mean(a), unit_mean(b)))


def crease_turn_deg(
    pressed_before: NDArray[np.float64],
    pressed_after: NDArray[np.float64],
    taught_before: NDArray[np.float64],
    taught_after: NDArray[np.float64],
) -> float:
    """How far (deg) the normal pressed turned across a switch, from ``pressed_before`` to ``pressed_after`` (unit),
    about the axis the taught crease turns about (from ``taught_before`` to ``taught_after``, unit; positive: the
    taught way). A part tilted as a whole turns as taught; a surface that is not there turns nothing; a steeper one
    turns more."""
    axis = np.cross(taught_before, taught_after)
    axis /= np.linalg.norm(axis)
    before = pressed_before - (pressed_before @ axis) * axis
    after = pressed_after - (pressed_after @ axis) * axis
    return float(np.degrees(np.arctan2(np.cross(before, after) @ axis, before @ after)))


@dataclass(frozen=True)
class TurnPlane:
    """The plane a contour's taught normals turn in: its ``axis`` (3,) and a ``reference`` normal in it (3,, angle
    0)."""

    axis: NDArray[np.float64]
    reference: NDArray[np.float64]

    def angles_deg(self, normals: NDArray[np.float64]) -> NDArray[np.float64]:
        """The angle (N,) of each of ``normals`` (N, 3) about the axis, from the reference, deg (its part out of the
        plane ignored)."""
        across = np.cross(self.axis, self.reference)
        return np.degrees(np.arctan2(normals @ across, normals @ self.reference))


def turn_plane(taught: NDArray[np.float64]) -> TurnPlane | None:
    """The plane the taught normals (M, 3) turn in, or None where they turn less than ``MIN_TURN_DEG`` (no region
    along a turn). The axis is the direction the normals least extend along (a great circle's pole); the reference,
    the middle normal's direction in the plane."""
    if float(angles_deg(taught[:, None, :], taught[None, :, :]).max()) < MIN_TURN_DEG:
        return None
    axis = np.linalg.svd(taught, full_matrices=False)[2][-1]
    middle = taught[len(taught) // 2]
    reference = middle - (middle @ axis) * axis
    return TurnPlane(axis, reference / np.linalg.norm(reference))


def span_deg(
    plane: TurnPlane, normals: NDArray[np.float64], trim_pct: float = REGION_PERCENTILE
) -> tuple[float, float]:
    """The span of the angles of ``normals`` (N, 3) about ``plane``'s axis, from the ``trim_pct`` percentile to 100
    minus it, deg: a few rows of chatter at a touch-down or a lift-off do not widen the pressed span. The taught span
    is taken whole (``trim_pct`` 0): where a skill's frames overshoot what was demonstrated, the region check is
    stricter than the part, never laxer (trimmed like the pressed one, it let a cylinder moved 4 cm pass at 85 % where
    the true region was covered 84 %)."""
    angles = plane.angles_deg(normals)
    low, high = np.percentile(angles, [trim_pct, 100.0 - trim_pct])
    return float(low), float(high)


def region_coverage(taught_span: tuple[float, float], pressed_span: tuple[float, float]) -> float:
    """The share (0..1) of the taught span of angles (deg) that the pressed span covers."""
    overlap = min(taught_span[1], pressed_span[1]) - max(taught_span[0], pressed_span[0])
    return max(0.0, overlap) / max(taught_span[1] - taught_span[0], 1e-9)
