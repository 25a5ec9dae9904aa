"""Segmentation of a demonstration into contiguous contact and free segments (paper sec. 4, Fig. 2).

What decides what (docs/LEARNING.md has the figure of a real recording):

- **Contact vs free** is decided by `skills.contact` from force AND kinematics: each contact
  interval (a stroke) is one contact segment to begin with; the time between strokes is free.
- **Where a stroke changes surface** (slide only: a second plane, a crease) is found by the
  paper's clustering: Ward agglomerative clustering with a k-nearest-neighbour graph over TIME
  as connectivity (so clusters are time intervals), over per-sample features of pose and of the
  friction-free force direction (the surface normal). The tree's top split is the best place to
  cut the stroke in two; the cut is KEPT only where the surface really changes there: the two
  parts' normals differ by at least ``NORMAL_SPLIT_DEG``, so do the normals just before and just
  after the cut (``JUMP_DISTANCE_M`` of path each), AND that jump is ``CREASE_CONTRAST`` times the turn on
  either side of it — a crease between planes, not a smooth curve turning steadily. Each kept
  part is split again the same way.
- **Short stretches** (under ``min_segment_duration_s``) are never segments of their own: they
  are absorbed into a neighbour.

Contour keeps each stroke whole (its frames follow the force along it). Inputs are world-frame
arrays: ``positions`` (N, 3) m and ``forces`` (N, 3) N applied by the tool, uniformly sampled.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt, uniform_filter1d
from sklearn.cluster import AgglomerativeClustering
from sklearn.neighbors import kneighbors_graph

from skills.contact import ContactAnalysis

CLUSTERING_SAMPLES = 600
"""Samples one clustering works on: a stroke is block-averaged down to about this many."""

NORMAL_SPLIT_DEG = 10.0
"""Least change of the surface normal (deg) between two planes, and least jump at the cut between them.

Below it a slide keeps one plane: the force control along CF z absorbs the difference, while
PyBullet's friction (misdirected by up to ~15°) wobbles the normal by up to ~6°, and the arm's
inertia that a hand works against when it turns a wipe (m·a across the motion, in the surface)
tilts it by up to ~11° for a moment.
"""

JUMP_DISTANCE_M = 0.02
"""Length of path just before and just after a cut whose normals make the jump, m."""

CREASE_CONTRAST = 3.0
"""A cut is a crease when the normal jumps across it this many times more than it turns on either side."""

MAX_PLANES_PER_STROKE = 6
"""Most slide segments one stroke is cut into."""


@dataclass(frozen=True)
class SegmentBounds:
    """A contiguous range of samples ``[start, end)`` and whether the tool was in contact."""

    start: int
    end: int
    contact: bool


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Return the angle between two (not necessarily unit) vectors, deg."""
    cos = np.dot(a, b) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def mean_direction(directions: NDArray[np.float64], start: int, end: int) -> NDArray[np.float64] | None:
    """Return the mean friction-free normal over ``[start, end)``, or None where it is undetermined.

    Undetermined: fewer than 20 % of the samples (or 5) carry a direction, i.e. the tool
    mostly rested (pressing before it moves, releasing after it stopped).
    """
    rows = directions[start:end]
    valid = np.linalg.norm(rows, axis=1) > 0.5
    if valid.sum() < max(5, 0.2 * valid.size):
        return None
    return rows[valid].mean(axis=0)


def _block_means(values: NDArray[np.float64], stride: int) -> NDArray[np.float64]:
    """Return the means of consecutive blocks of ``stride`` rows (the last block may be shorter)."""
    n_blocks = -(-values.shape[0] // stride)
    pad = n_blocks * stride - values.shape[0]
    if pad:
        values = np.concatenate([values, np.repeat(values[-1:], pad, axis=0)])
    return values.reshape(n_blocks, stride, -1).mean(axis=1)


def _ward_cut(features: NDArray[np.float64], min_samples: int) -> int | None:
    """Return the sample where the Ward tree (time-connected) splits ``features`` in two, or None.

    None when either part would be shorter than ``min_samples``.
    """
    n = features.shape[0]
    stride = max(1, -(-n // CLUSTERING_SAMPLES))
    reduced = _block_means(features, stride)
    if reduced.shape[0] < 4:
        return None
    # Each block is linked to its two neighbours in time, so both clusters are time intervals.
    time_index = np.arange(reduced.shape[0], dtype=float)[:, None]
    connectivity = kneighbors_graph(time_index, n_neighbors=2, include_self=False)
    labels = AgglomerativeClustering(n_clusters=2, connectivity=connectivity, linkage="ward").fit_predict(reduced)
    cut = int(np.flatnonzero(np.diff(labels))[0] + 1) * stride
    return cut if min_samples <= cut <= n - min_samples else None


def _is_crease(
    directions: NDArray[np.float64], arc_length: NDArray[np.float64], start: int, cut: int, end: int
) -> bool:
    """Return True when the surface normal jumps at ``cut`` (a crease) rather than turning steadily.

    ``arc_length`` (N,) m is the distance travelled along the path. A crease: the two parts'
    normals differ by at least ``NORMAL_SPLIT_DEG``, the normals over the ``JUMP_DISTANCE_M`` of
    path just before and just after the cut do too, and that jump is ``CREASE_CONTRAST`` times
    the turn over the next ``JUMP_DISTANCE_M`` on either side: planes on either side, not a curve
    that turns as much on its way to the cut as across it. Windows are measured along the path,
    not in time, so a fast pass over a curve is no crease.
    """
    here = arc_length[cut]
    bounds = np.searchsorted(arc_length[start:end], here + JUMP_DISTANCE_M * np.array([-2, -1, 1, 2])) + start
    edges = [bounds[0], bounds[1], cut, bounds[2], bounds[3]]
    means = [mean_direction(directions, a, b) if b > a else None for a, b in itertools.pairwise(edges)]
    first, second = mean_direction(directions, start, cut), mean_direction(directions, cut, end)
    if any(m is None for m in means) or first is None or second is None:
        return False  # a side too short (or too still) to show it is a plane
    jump, change = _angle_deg(means[1], means[2]), _angle_deg(first, second)
    within = max(_angle_deg(means[0], means[1]), _angle_deg(means[2], means[3]))
    return min(jump, change) >= NORMAL_SPLIT_DEG and jump >= CREASE_CONTRAST * within


def _planes_of_stroke(
    positions: NDArray[np.float64],
    directions: NDArray[np.float64],
    start: int,
    end: int,
    min_samples: int,
) -> list[int]:
    """Return the cuts (sample indices) between the planes of one slide stroke ``[start, end)``."""
    extent = float(np.max(np.ptp(positions[start:end], axis=0))) or 1.0
    # Features: the normal (one unit = the split angle) weighs most; position keeps parts compact.
    # Where the tool rests the normal is unknown: it rests on the plane it last (or next) slid on.
    normals = directions.copy()
    unknown = np.linalg.norm(normals, axis=1) < 0.5
    if unknown.any() and not unknown.all():
        nearest = distance_transform_edt(unknown, return_distances=False, return_indices=True)[0]
        normals = normals[nearest]
    features = np.hstack(
        [normals / np.sin(np.radians(NORMAL_SPLIT_DEG)), 0.5 * (positions - positions[start]) / extent]
    )
    arc_length = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))))
    pending, cuts = [(start, end)], []
    while pending and len(cuts) < MAX_PLANES_PER_STROKE - 1:
        a, b = pending.pop()
        cut = _ward_cut(features[a:b], min_samples)
        if cut is None or not _is_crease(directions, arc_length, a, a + cut, b):
            continue
        cuts.append(a + cut)
        pending.extend([(a, a + cut), (a + cut, b)])
    return sorted(cuts)


def segment_demonstration(
    positions: NDArray[np.float64],
    contact: ContactAnalysis,
    split_on_normal: bool,
    min_segment_duration_s: float = 0.25,
) -> list[SegmentBounds]:
    """Return the segments of a demonstration, in time order, covering every sample once.

    ``split_on_normal`` is the skill's segmentation attribute: slide cuts a stroke where the
    surface changes (another plane), contour keeps each stroke whole.
    """
    n = positions.shape[0]
    min_samples = max(1, round(min_segment_duration_s * contact.rate_hz))
    edges: list[tuple[int, bool]] = []  # (start sample, contact) of each piece
    cursor = 0
    for interval in contact.intervals:
        if interval.start > cursor:
            edges.append((cursor, False))
        edges.append((interval.start, True))
        if split_on_normal:
            cuts = _planes_of_stroke(positions, contact.directions, interval.start, interval.end, min_samples)
            edges.extend((cut, True) for cut in cuts)
        cursor = interval.end
    if cursor < n:
        edges.append((cursor, False))
    ends = [start for start, _ in edges[1:]] + [n]
    segments = [SegmentBounds(start, end, c) for (start, c), end in zip(edges, ends, strict=True)]
    return _absorb_short(segments, min_samples)


def _absorb_short(segments: list[SegmentBounds], min_samples: int) -> list[SegmentBounds]:
    """Absorb segments shorter than ``min_samples`` into a neighbour (prefer the same contact state)."""
    segments = list(segments)
    while len(segments) > 1:
        lengths = np.array([s.end - s.start for s in segments])
        k = int(np.argmin(lengths))
        if lengths[k] >= min_samples:
            break
        neighbours = [j for j in (k - 1, k + 1) if 0 <= j < len(segments)]
        j = max(neighbours, key=lambda j: (segments[j].contact == segments[k].contact, lengths[j]))
        a, b = sorted((k, j))
        segments[a : b + 1] = [SegmentBounds(segments[a].start, segments[b].end, segments[j].contact)]
    return segments


def moving_std(values: NDArray[np.float64], window: int) -> NDArray[np.float64]:
    """Return the centred moving standard deviation of a 1-D signal over ``window`` samples."""
    mean = uniform_filter1d(values, window, mode="nearest")
    mean_sq = uniform_filter1d(values**2, window, mode="nearest")
    return np.sqrt(np.maximum(mean_sq - mean**2, 0.0))
