"""Contact segments of several demonstrations of one task put on common points and aligned in time (docs/LEARNING.md,
section 11, step 2): every contact segment resampled to `ALIGNMENT_POINTS` points evenly in time and aligned to the
reference's by dynamic time warping (`warping_path`, vectorized over anti-diagonals) on its path about its centroid
and its press: place along the path first, the press's ramps second. World frame, SI units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.distance import cdist

from schemas.skill import SegmentKind
from skills.friction import unit_rows
from skills.parameterize import LearnedSegment, LearnedTrial

ALIGNMENT_POINTS = 100
"""Points, evenly in time, each demonstration's contact segment is aligned and averaged on (the band's phases)."""

RUN_POINTS = 200
"""Points a run judged against a band (a left-out demonstration, an execution) is resampled to before alignment."""

PRESS_ALIGNMENT_SCALE_M = 0.02
"""The press, over its median, weighs in the time alignment as a path of this length (m): a 2 cm path counts as
much as the press doubling."""

WOBBLE_SMOOTHING_S = 0.2
"""A demonstration's own wobble is its press's RMS about the press smoothed over this (s)."""


@dataclass(frozen=True)
class Stroke:
    """One contact segment of one demonstration on `ALIGNMENT_POINTS` points evenly in time (world, SI): its path
    (G, 3) m, tool orientations (G, 4), applied forces (G, 3) N, CF z (G, 3), press along its own CF z (G,) N and
    its wobble (G,) N; ``rows`` its samples in the demonstration."""

    positions: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    forces: NDArray[np.float64]
    normals: NDArray[np.float64]
    press: NDArray[np.float64]
    wobble: NDArray[np.float64]
    rows: slice


def resampled(values: NDArray[np.float64], n_points: int) -> NDArray[np.float64]:
    """Return ``values`` (M, ...) linearly interpolated at ``n_points`` points evenly spread from the first to the
    last sample."""
    m = len(values)
    x = np.linspace(0.0, m - 1.0, n_points)
    lo = np.minimum(np.floor(x).astype(int), m - 1)
    hi = np.minimum(lo + 1, m - 1)
    frac = (x - lo).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - frac) * values[lo] + frac * values[hi]


def warping_path(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
    """Return the dynamic-time-warping path (i, j) between feature rows ``a`` (N, D) and ``b`` (M, D), Euclidean
    cost, steps (1, 0), (0, 1), (1, 1); from (0, 0) to (N - 1, M - 1). The cumulative cost is filled one
    anti-diagonal at a time (every cell of one depends only on the two before it)."""
    n, m = len(a), len(b)
    cost = cdist(a, b)
    total = np.full((n + 1, m + 1), np.inf)
    total[0, 0] = 0.0
    for s in range(2, n + m + 1):
        i = np.arange(max(1, s - m), min(n, s - 1) + 1)
        j = s - i
        best = np.minimum(np.minimum(total[i - 1, j - 1], total[i - 1, j]), total[i, j - 1])
        total[i, j] = cost[i - 1, j - 1] + best
    # Backtrack along the cheapest predecessor of each cell (0: diagonal, 1: from above, 2: from the left).
    came_from = np.argmin(np.stack([total[:-1, :-1], total[:-1, 1:], total[1:, :-1]]), axis=0)
    steps = ((-1, -1), (-1, 0), (0, -1))
    i, j, path = n, m, [(n - 1, m - 1)]
    while i > 1 or j > 1:
        if i == 1:
            j -= 1
        elif j == 1:
            i -= 1
        else:
            di, dj = steps[came_from[i - 1, j - 1]]
            i, j = i + di, j + dj
        path.append((i - 1, j - 1))
    pairs = np.array(path[::-1])
    return pairs[:, 0], pairs[:, 1]


def alignment_features(positions: NDArray[np.float64], press: NDArray[np.float64]) -> NDArray[np.float64]:
    """Alignment features (G, 4): the path about its centroid (m) and the press over its median, scaled to a path."""
    scale = max(float(np.median(np.abs(press))), 1e-6)
    centred = positions - positions.mean(axis=0)
    return np.column_stack([centred, PRESS_ALIGNMENT_SCALE_M * press / scale])


def on_reference(
    reference: NDArray[np.float64], features: NDArray[np.float64], values: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Return ``values`` (M, D) of a run with ``features`` (M, F) on the reference's points (G, F): at each, the mean
    of the run's values the warping path matches to it."""
    i, j = warping_path(reference, features)
    sums = np.zeros((len(reference), values.shape[1]))
    np.add.at(sums, i, values[j])
    return sums / np.bincount(i, minlength=len(reference))[:, None]


def _wobble(press: NDArray[np.float64], rate_hz: float) -> NDArray[np.float64]:
    """The press's local RMS (N) about itself smoothed over `WOBBLE_SMOOTHING_S`."""
    sigma = max(WOBBLE_SMOOTHING_S * rate_hz, 1.0)
    residual = press - gaussian_filter1d(press, sigma, mode="nearest")
    return np.sqrt(gaussian_filter1d(residual**2, sigma, mode="nearest"))


def contact_segments(learned: LearnedTrial) -> list[LearnedSegment]:
    return [item for item in learned.learned if item.segment.kind is SegmentKind.contact]


def aligned_stroke(learned: LearnedTrial, item: LearnedSegment) -> Stroke:
    """One contact segment of a demonstration on the alignment points."""
    r, segment = learned.recording, item.segment
    rows = slice(segment.start_index, segment.end_index)
    assert item.cf_z is not None and item.measured_force_n is not None
    g = ALIGNMENT_POINTS
    return Stroke(
        positions=resampled(r.positions[rows], g),
        quaternions=resampled(r.quaternions[rows], g),
        forces=resampled(r.forces[rows], g),
        normals=unit_rows(resampled(np.asarray(item.cf_z), g)),
        press=resampled(item.measured_force_n, g),
        wobble=resampled(_wobble(item.measured_force_n, r.contact.rate_hz), g),
        rows=rows,
    )


def angles_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.degrees(np.arccos(np.clip(np.sum(unit_rows(a) * unit_rows(b), axis=-1), -1.0, 1.0)))
