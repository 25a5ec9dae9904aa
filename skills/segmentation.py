"""Segmentation of a demonstration into contiguous contact and free segments (paper sec. 4, Fig. 2).

What decides what (docs/LEARNING.md has the figure of a real recording):

- **Contact vs free** is decided by `skills.contact` from force AND kinematics; the time between
  contacts is free.
- **Strokes as a person sees them**: a contact is cut where the press dips between two pressing
  stretches (below ``DIP_FRACTION`` of the weaker) that go another way (``DIRECTION_CHANGE_DEG``)
  or press on another surface (``NORMAL_SPLIT_DEG``) — two strokes without a clean lift-off (a
  back-and-forth wipe at a steady press is one stroke: nothing lies between its passes) — and a
  path going round is cut after each full turn of its heading (one segment per pass). A brief light contact (under
  ``BRUSH_MAX_S``, pressing less than ``BRUSH_FRACTION`` of the strongest stroke) is a brush, not a
  stroke: it is free.
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

Contour keeps each stroke whole (its frames follow the force along it). Every segment records what
decided its ends (`schemas.skill.BoundaryReason`). Inputs are world-frame
arrays: ``positions`` (N, 3) m and ``forces`` (N, 3) N applied by the tool, uniformly sampled.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt, gaussian_filter1d, uniform_filter1d

from schemas.skill import BoundaryReason
from skills.contact import ContactAnalysis, mask_runs

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

PRESSING_FRACTION = 0.5
"""A contact's pressing stretches press with at least this fraction of its 90th-percentile force."""

DIP_FRACTION = 0.3
"""Between two pressing stretches, a press below this fraction of the weaker one's median is a dip between strokes."""

DIRECTION_CHANGE_DEG = 90.0
"""Least change of the path's direction across a dip (deg) that makes the two sides two strokes."""

BRUSH_FRACTION = 0.5
"""A contact segment pressing less than this fraction of the strongest one is light: a brush if also brief."""

BRUSH_MAX_S = 1.5
"""A light contact segment shorter than this (s) is a brush (the hand sliding the tool to the start): free."""

WINDING_SMOOTHING_S = 0.1
"""Standard deviation of the Gaussian smoothing of positions before the heading's winding is measured, s."""

MIN_LAST_TURN = 0.25
"""A path going round is cut after each full turn only while at least this fraction of a turn remains after it."""


@dataclass(frozen=True)
class SegmentBounds:
    """A contiguous range of samples ``[start, end)``, whether the tool was in contact, and what decided its ends."""

    start: int
    end: int
    contact: bool
    start_reason: BoundaryReason = BoundaryReason.recording
    end_reason: BoundaryReason = BoundaryReason.recording


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
    # Imported here: scikit-learn is ~30 MB resident, and a sim worker imports this module (through the checks of a
    # work piece built from a demonstration) without segmenting.
    from sklearn.cluster import AgglomerativeClustering
    from sklearn.neighbors import kneighbors_graph

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
    arc_length: NDArray[np.float64],
    start: int,
    end: int,
    min_samples: int,
) -> list[int]:
    """Return the cuts (sample indices) between the planes of one slide stroke ``[start, end)``.

    ``arc_length`` (N,) m is the distance travelled along the whole path; only the stroke's own rows are read.
    """
    path = positions[start:end]
    extent = float(np.max(np.ptp(path, axis=0))) or 1.0
    # Features: the normal (one unit = the split angle) weighs most; position keeps parts compact.
    # Where the tool rests the normal is unknown: it rests on the plane it last (or next) slid on.
    normals = directions[start:end].copy()
    unknown = np.linalg.norm(normals, axis=1) < 0.5
    if unknown.any() and not unknown.all():
        nearest = distance_transform_edt(unknown, return_distances=False, return_indices=True)[0]
        normals = normals[nearest]
    features = np.hstack([normals / np.sin(np.radians(NORMAL_SPLIT_DEG)), 0.5 * (path - path[0]) / extent])
    pending, cuts = [(start, end)], []
    while pending and len(cuts) < MAX_PLANES_PER_STROKE - 1:
        a, b = pending.pop()
        cut = _ward_cut(features[a - start : b - start], min_samples)
        if cut is None or not _is_crease(directions, arc_length, a, a + cut, b):
            continue
        cuts.append(a + cut)
        pending.extend([(a, a + cut), (a + cut, b)])
    return sorted(cuts)


def _heading_winding_deg(positions: NDArray[np.float64], normal: NDArray[np.float64], rate_hz: float) -> NDArray:
    """Return the cumulative turn (deg, from 0) of the path's heading in the plane across ``normal`` per sample.

    The heading is that of the velocity smoothed over ``WINDING_SMOOTHING_S``; where the tool moves
    slower than a fifth of its median speed the heading is held (a pause turns nothing), and a jump of
    the heading by more than 90° between two moving samples (the tool stopped and went back) turns
    nothing either: only a path that really goes round winds.
    """
    smoothed = gaussian_filter1d(positions, max(1.0, WINDING_SMOOTHING_S * rate_hz), axis=0, mode="nearest")
    velocity = np.gradient(smoothed, axis=0)
    basis = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    planar = velocity @ basis
    speed = np.linalg.norm(planar, axis=1)
    moving = np.flatnonzero(speed > 0.2 * np.median(speed))
    if moving.size < 2:
        return np.zeros(len(positions))
    heading = np.arctan2(planar[moving, 1], planar[moving, 0])
    steps = np.angle(np.exp(1j * np.diff(heading)))
    steps[np.abs(steps) > 0.5 * np.pi] = 0.0
    winding = np.concatenate(([0.0], np.cumsum(steps)))
    held = winding[np.clip(np.searchsorted(moving, np.arange(len(positions)), side="right") - 1, 0, None)]
    return np.degrees(held)


def _turn_cuts(positions: NDArray[np.float64], normal: NDArray[np.float64], start: int, end: int, rate_hz: float):
    """Return the samples (absolute) where a path going round completes each full turn, keeping a last part of
    at least ``MIN_LAST_TURN`` of a turn (so a circle closed with a little overlap is one pass)."""
    winding = np.abs(_heading_winding_deg(positions[start:end], normal, rate_hz))
    turns = int(np.floor(winding.max() / 360.0 - MIN_LAST_TURN))
    return [start + int(np.argmax(winding >= 360.0 * k)) for k in range(1, turns + 1)]


def _stroke_cuts(
    positions: NDArray[np.float64],
    press: NDArray[np.float64],
    directions: NDArray[np.float64],
    arc_length: NDArray[np.float64],
    start: int,
    end: int,
) -> list[int]:
    """Return the samples (absolute) between two strokes of one contact ``[start, end)`` that never lifted off.

    Between two pressing stretches (``press`` (N,) N at least ``PRESSING_FRACTION`` of the contact's
    90th percentile) the press dips below ``DIP_FRACTION`` of the weaker one's median, and the two go
    different ways (the path's direction over ``JUMP_DISTANCE_M`` before and after the dip differs by at
    least ``DIRECTION_CHANGE_DEG``) or press on different surfaces (their mean friction-free normals
    differ by at least ``NORMAL_SPLIT_DEG``). The cut is in the middle of the dip.
    """
    local = press[start:end]
    pressing = local >= PRESSING_FRACTION * np.percentile(local, 90)
    runs = mask_runs(pressing)
    cuts = []
    for (a0, a1), (b0, b1) in itertools.pairwise(runs):
        level = min(np.median(local[a0:a1]), np.median(local[b0:b1]))
        gap = local[a1:b0]
        if gap.size == 0 or gap.min() >= DIP_FRACTION * level:
            continue
        before, after = start + a1, start + b0
        back = int(np.searchsorted(arc_length, arc_length[before] - JUMP_DISTANCE_M))
        ahead = int(np.searchsorted(arc_length, arc_length[after] + JUMP_DISTANCE_M))
        turned = _angle_deg(positions[before] - positions[back], positions[min(ahead, end - 1)] - positions[after])
        first, second = mean_direction(directions, start + a0, before), mean_direction(directions, after, start + b1)
        other_surface = first is not None and second is not None and _angle_deg(first, second) >= NORMAL_SPLIT_DEG
        if turned >= DIRECTION_CHANGE_DEG or other_surface:
            dipping = np.flatnonzero(gap < DIP_FRACTION * level)
            cuts.append(start + a1 + (int(dipping[0]) + int(dipping[-1])) // 2)
    return cuts


def segment_demonstration(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    contact: ContactAnalysis,
    split_on_normal: bool,
    min_segment_duration_s: float = 0.25,
) -> list[SegmentBounds]:
    """Return the segments of a demonstration, in time order, covering every sample once.

    Each contact is cut into strokes as a person sees them (`_stroke_cuts`: a dip of the press with
    a change of direction or surface; `_turn_cuts`: one pass per full turn of a path going round).
    ``split_on_normal`` is the skill's segmentation attribute: slide also cuts a stroke where the
    surface changes (another plane), contour keeps each stroke whole. ``forces`` (N, 3) N applied.
    """
    n = positions.shape[0]
    min_samples = max(1, round(min_segment_duration_s * contact.rate_hz))
    press = gaussian_filter1d(np.linalg.norm(forces, axis=1), max(1.0, 0.02 * contact.rate_hz))
    arc_length = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))))
    edges: list[tuple[int, bool, BoundaryReason]] = []  # (start sample, contact, why it starts there)
    cursor = 0
    for interval in contact.intervals:
        if interval.start > cursor:
            edges.append((cursor, False, BoundaryReason.recording if cursor == 0 else BoundaryReason.contact))
        edges.append((interval.start, True, interval.start_reason))
        stroke_cuts = _stroke_cuts(positions, press, contact.directions, arc_length, interval.start, interval.end)
        strokes = [interval.start, *stroke_cuts, interval.end]
        for a, b in itertools.pairwise(strokes):
            if a > interval.start:
                edges.append((a, True, BoundaryReason.stroke))
            normal = mean_direction(contact.directions, a, b)
            if normal is not None:
                normal = normal / np.linalg.norm(normal)
                turns = _turn_cuts(positions, normal, a, b, contact.rate_hz)
                edges.extend((cut, True, BoundaryReason.turn) for cut in turns)
            if split_on_normal:
                cuts = _planes_of_stroke(positions, contact.directions, arc_length, a, b, min_samples)
                edges.extend((cut, True, BoundaryReason.crease) for cut in cuts)
        edges.sort(key=lambda edge: edge[0])
        cursor = interval.end
    if cursor < n:
        edges.append((cursor, False, BoundaryReason.contact))
    end_reasons = {interval.end: interval.end_reason for interval in contact.intervals}
    segments = []
    for (start, in_contact, start_reason), following in zip(edges, [*edges[1:], None], strict=True):
        end = n if following is None else following[0]
        if following is None:
            end_reason = end_reasons.get(end, BoundaryReason.recording) if in_contact else BoundaryReason.recording
        elif in_contact:
            end_reason = end_reasons.get(end, following[2])
        else:
            end_reason = BoundaryReason.contact
        segments.append(SegmentBounds(start, end, in_contact, start_reason, end_reason))
    return _absorb_short(_without_brushes(segments, press, contact.rate_hz), min_samples)


def _without_brushes(segments: list[SegmentBounds], press: NDArray[np.float64], rate_hz: float) -> list[SegmentBounds]:
    """Return ``segments`` with every brush made free and joined to the free segments next to it.

    A brush is a contact segment shorter than ``BRUSH_MAX_S`` whose press (90th percentile of
    ``press`` (N,) N) is below ``BRUSH_FRACTION`` of the strongest contact segment's: the hand sliding
    the tool to the start, not a stroke.
    """
    presses = {k: float(np.percentile(press[s.start : s.end], 90)) for k, s in enumerate(segments) if s.contact}
    if not presses:
        return segments
    strongest = max(presses.values())
    brushes = {
        k
        for k, p in presses.items()
        if p < BRUSH_FRACTION * strongest and segments[k].end - segments[k].start < BRUSH_MAX_S * rate_hz
    }
    marked = [
        SegmentBounds(s.start, s.end, False, BoundaryReason.contact, BoundaryReason.contact) if k in brushes else s
        for k, s in enumerate(segments)
    ]
    joined: list[SegmentBounds] = []
    for segment in marked:
        if joined and not segment.contact and not joined[-1].contact:
            last = joined[-1]
            joined[-1] = SegmentBounds(last.start, segment.end, False, last.start_reason, segment.end_reason)
        else:
            joined.append(segment)
    return joined


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
        first, last = segments[a], segments[b]
        segments[a : b + 1] = [
            SegmentBounds(first.start, last.end, segments[j].contact, first.start_reason, last.end_reason)
        ]
    return segments


def moving_std(values: NDArray[np.float64], window: int) -> NDArray[np.float64]:
    """Return the centred moving standard deviation of a 1-D signal over ``window`` samples."""
    mean = uniform_filter1d(values, window, mode="nearest")
    mean_sq = uniform_filter1d(values**2, window, mode="nearest")
    return np.sqrt(np.maximum(mean_sq - mean**2, 0.0))
