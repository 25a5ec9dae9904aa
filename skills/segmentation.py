"""Segmentation of a demonstration into contiguous contact and free segments (paper Fig. 2).

Method: agglomerative (Ward) clustering of per-sample features of pose and force, with a
k-nearest-neighbour graph over TIME as connectivity, so that every cluster is contiguous in
time. The tree is cut at a generous number of clusters (candidate boundaries); then adjacent
clusters that the skill cannot tell apart are merged (same contact state and, for slide, the
same surface normal within ``NORMAL_SPLIT_DEG``), and segments shorter than the minimum
duration are merged into a neighbour. That makes the number of segments automatic and
deterministic. Contact vs free is labelled from the applied force; contact boundaries are
then refined at full rate to the force-threshold crossing.

All inputs are world-frame arrays: ``t`` (N,) s, uniform; ``positions`` (N, 3) m; ``forces``
(N, 3) N applied by the tool.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d, label, median_filter, uniform_filter1d
from sklearn.cluster import AgglomerativeClustering
from sklearn.neighbors import kneighbors_graph

CLUSTERING_SAMPLES = 1200
"""Samples the clustering works on: the demonstration is block-averaged down to about this many."""

NORMAL_SPLIT_DEG = 6.0
"""Adjacent slide contact segments whose normals differ by less than this (deg) are one segment."""

MAX_CANDIDATE_CLUSTERS = 24
"""Most clusters the Ward tree is cut into before the physical merge decides the final count."""


@dataclass(frozen=True)
class SegmentBounds:
    """A contiguous range of samples ``[start, end)`` and whether the tool was in contact."""

    start: int
    end: int
    contact: bool


def contact_threshold(force_magnitude: NDArray[np.float64]) -> float:
    """Return the force magnitude (N) above which a sample is taken as in contact.

    Adaptive: 15 % of the robust peak (95th percentile), but at least 1 N so that sensor
    noise in free space (after tare) never counts as contact.
    """
    return float(max(1.0, 0.15 * np.percentile(force_magnitude, 95)))


def contact_mask(forces: NDArray[np.float64], rate_hz: float, threshold_n: float | None = None) -> NDArray[np.bool_]:
    """Return the per-sample contact flag from the applied forces (N, 3), N, by hysteresis.

    A contact is detected where the 20 ms median of |f| exceeds the contact threshold, and
    extends in both directions for as long as |f| stays above the free-space noise floor
    (median + 4 robust standard deviations of the non-contact samples, at least 0.2 N), so
    contact on/off are the times the force leaves / returns to the noise, not the times it
    crosses an arbitrary level.
    """
    magnitude = np.linalg.norm(forces, axis=1)
    window = max(1, round(0.02 * rate_hz) | 1)
    smoothed = median_filter(magnitude, size=window, mode="nearest")
    threshold = contact_threshold(smoothed) if threshold_n is None else threshold_n
    detected = smoothed > threshold
    free = smoothed[~detected]
    if free.size < window:
        return detected
    floor = float(np.median(free))
    noise = 1.4826 * float(np.median(np.abs(free - floor)))
    above_floor = smoothed > min(threshold, floor + max(4.0 * noise, 0.2))
    runs, _ = label(above_floor)
    touching = np.unique(runs[detected & above_floor])
    return np.isin(runs, touching[touching > 0])


def normal_directions(
    forces: NDArray[np.float64], velocities: NDArray[np.float64], in_contact: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """Return per-sample unit directions of the applied force with the friction part removed.

    Friction acts along the motion, so the component of the force along the velocity is
    removed; what is left is the surface normal direction into the surface. Where the tool
    rests (speed < 5 mm/s) static friction can point anywhere in the friction cone, and where
    the force is below a third of the median contact force (touching down, lifting off) noise
    and transients dominate: there the direction says nothing about the normal and is zero,
    as where not in contact.
    """
    speed = np.linalg.norm(velocities, axis=1, keepdims=True)
    magnitude = np.linalg.norm(forces, axis=1, keepdims=True)
    typical = float(np.median(magnitude[in_contact])) if in_contact.any() else 0.0
    moving = (speed > 5e-3) & (magnitude > typical / 3.0)
    v_hat = np.where(moving, velocities / np.maximum(speed, 1e-12), 0.0)
    normal_part = forces - np.sum(forces * v_hat, axis=1, keepdims=True) * v_hat
    norm = np.linalg.norm(normal_part, axis=1, keepdims=True)
    directions = np.where(norm > 1e-9, normal_part / np.maximum(norm, 1e-12), 0.0)
    return directions * (in_contact[:, None] & moving)


def _block_means(values: NDArray[np.float64], stride: int) -> NDArray[np.float64]:
    """Return the means of consecutive blocks of ``stride`` rows (the last block may be shorter)."""
    n_blocks = -(-values.shape[0] // stride)
    padded_len = n_blocks * stride
    pad = padded_len - values.shape[0]
    if pad:
        values = np.concatenate([values, np.repeat(values[-1:], pad, axis=0)])
    return values.reshape(n_blocks, stride, -1).mean(axis=1)


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Return the angle between two (not necessarily unit) vectors, deg."""
    cos = np.dot(a, b) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _runs(labels: NDArray[np.int_]) -> list[tuple[int, int]]:
    """Return ``[start, end)`` of each run of equal consecutive labels."""
    change = np.flatnonzero(np.diff(labels)) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [labels.size]))
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


@dataclass(frozen=True)
class ContactAnalysis:
    """Per-sample contact flags and friction-free normal directions (zero where unknown) of a demonstration."""

    rate_hz: float
    in_contact: NDArray[np.bool_]
    directions: NDArray[np.float64]


def analyse_contact(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    contact_threshold_n: float | None = None,
) -> ContactAnalysis:
    """Return contact flags and normal directions of a uniformly sampled demonstration (s, m, N, world)."""
    rate_hz = (t.size - 1) / (t[-1] - t[0])
    in_contact = contact_mask(forces, rate_hz, contact_threshold_n)
    # Velocities from positions smoothed over ~20 ms: differentiating raw tracker noise at 1 kHz is noise.
    smoothed = gaussian_filter1d(positions, sigma=max(1.0, 0.02 * rate_hz), axis=0, mode="nearest")
    velocities = np.gradient(smoothed, t, axis=0)
    return ContactAnalysis(rate_hz, in_contact, normal_directions(forces, velocities, in_contact))


def segment_demonstration(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    contact: ContactAnalysis,
    split_on_normal: bool,
    min_segment_duration_s: float = 0.25,
) -> list[SegmentBounds]:
    """Return the segments of a demonstration, in time order, covering every sample once.

    ``split_on_normal`` is the skill's segmentation attribute: slide splits a contact where
    the surface normal changes (another plane), contour keeps a continuous contact whole.
    """
    n = positions.shape[0]
    rate_hz, in_contact, directions = contact.rate_hz, contact.in_contact, contact.directions

    # Features, each scaled so that one unit is a difference the skill cares about.
    magnitude = np.linalg.norm(forces, axis=1)
    force_scale = max(float(np.median(magnitude[in_contact])) if in_contact.any() else 1.0, 1.0)
    extent = float(np.max(np.ptp(positions, axis=0))) or 1.0
    features = [
        4.0 * in_contact[:, None].astype(float),
        magnitude[:, None] / force_scale,
        0.5 * positions / extent,
    ]
    if split_on_normal:
        features.append(directions / np.sin(np.radians(NORMAL_SPLIT_DEG)))
    feature_matrix = np.hstack(features)

    stride = max(1, -(-n // CLUSTERING_SAMPLES))
    reduced = _block_means(feature_matrix, stride)
    min_blocks = max(1, round(min_segment_duration_s * rate_hz / stride))
    n_clusters = int(min(MAX_CANDIDATE_CLUSTERS, max(1, reduced.shape[0] // min_blocks)))
    if n_clusters > 1:
        # Each block is linked to its two neighbours in time, so every cluster is a time interval.
        time_index = np.arange(reduced.shape[0], dtype=float)[:, None]
        connectivity = kneighbors_graph(time_index, n_neighbors=2, include_self=False)
        clustering = AgglomerativeClustering(n_clusters=n_clusters, connectivity=connectivity, linkage="ward")
        labels = clustering.fit_predict(reduced)
    else:
        labels = np.zeros(reduced.shape[0], dtype=int)

    # Candidate boundaries at full rate: cluster changes and contact-flag changes.
    full_labels = np.repeat(labels, stride)[:n]
    boundaries = {start for start, _ in _runs(full_labels)}
    boundaries |= {start for start, _ in _runs(in_contact.astype(int))}
    edges = sorted(boundaries | {n})
    pieces = [(a, b) for a, b in itertools.pairwise(edges) if b > a]

    min_samples = max(1, round(min_segment_duration_s * rate_hz))
    return _merge_pieces(pieces, in_contact, directions, split_on_normal, min_samples)


def _mean_direction(directions: NDArray[np.float64], start: int, end: int) -> NDArray[np.float64] | None:
    """Return the mean normal direction over ``[start, end)``, or None where it is undetermined.

    Undetermined: fewer than 20 % of the samples (or 10) carry a direction, i.e. the tool
    mostly rested (pressing before it moves, releasing after it stopped).
    """
    rows = directions[start:end]
    valid = np.linalg.norm(rows, axis=1) > 0.5
    if valid.sum() < max(10, 0.2 * valid.size):
        return None
    return rows[valid].mean(axis=0)


def _merge_pieces(
    pieces: list[tuple[int, int]],
    in_contact: NDArray[np.bool_],
    directions: NDArray[np.float64],
    split_on_normal: bool,
    min_samples: int,
) -> list[SegmentBounds]:
    """Merge candidate pieces into segments: same contact state and normal -> one; too short -> absorbed."""
    segments = [SegmentBounds(a, b, bool(in_contact[a:b].mean() > 0.5)) for a, b in pieces]

    def same(a: SegmentBounds, b: SegmentBounds) -> bool:
        if a.contact != b.contact:
            return False
        if not (a.contact and split_on_normal):
            return True
        normal_a = _mean_direction(directions, a.start, a.end)
        normal_b = _mean_direction(directions, b.start, b.end)
        # A stretch at rest has no normal of its own: it belongs to the plane it rests on.
        return normal_a is None or normal_b is None or _angle_deg(normal_a, normal_b) < NORMAL_SPLIT_DEG

    def merged(a: SegmentBounds, b: SegmentBounds, contact: bool) -> SegmentBounds:
        return SegmentBounds(a.start, b.end, contact)

    # 1. Absorb pieces that are too short into the neighbour they resemble most (shortest first).
    while len(segments) > 1:
        lengths = np.array([s.end - s.start for s in segments])
        k = int(np.argmin(lengths))
        if lengths[k] >= min_samples:
            break
        neighbours = [j for j in (k - 1, k + 1) if 0 <= j < len(segments)]
        # Prefer a neighbour in the same contact state, then the longer one.
        j = max(neighbours, key=lambda j: (segments[j].contact == segments[k].contact, lengths[j]))
        a, b = sorted((k, j))
        segments[a : b + 1] = [merged(segments[a], segments[b], segments[j].contact)]

    # 2. Merge adjacent segments the skill cannot tell apart.
    changed = True
    while changed:
        changed = False
        for k in range(len(segments) - 1):
            if same(segments[k], segments[k + 1]):
                segments[k : k + 2] = [merged(segments[k], segments[k + 1], segments[k].contact)]
                changed = True
                break
    return _refined_contact_edges(segments, in_contact)


def _refined_contact_edges(segments: list[SegmentBounds], in_contact: NDArray[np.bool_]) -> list[SegmentBounds]:
    """Move each contact/free boundary to the nearest contact-flag change (full rate)."""
    flips = np.flatnonzero(np.diff(in_contact.astype(int))) + 1
    if flips.size == 0:
        return segments
    refined = list(segments)
    for k in range(len(refined) - 1):
        a, b = refined[k], refined[k + 1]
        if a.contact == b.contact:
            continue
        edge = int(flips[np.argmin(np.abs(flips - a.end))])
        if a.start < edge < b.end:
            refined[k] = SegmentBounds(a.start, edge, a.contact)
            refined[k + 1] = SegmentBounds(edge, b.end, b.contact)
    return refined


def moving_std(values: NDArray[np.float64], window: int) -> NDArray[np.float64]:
    """Return the centred moving standard deviation of a 1-D signal over ``window`` samples."""
    mean = uniform_filter1d(values, window, mode="nearest")
    mean_sq = uniform_filter1d(values**2, window, mode="nearest")
    return np.sqrt(np.maximum(mean_sq - mean**2, 0.0))
