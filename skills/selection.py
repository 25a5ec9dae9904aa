"""Skill selection (beyond the paper): slide or contour, decided from the geometry of the contact, per stroke.

A slide presses on planes; a contour follows a curved surface. Two measures of each slide
segment (a plane candidate: a stroke, or a part of one between creases) tell them apart, both
free of friction (which turns the applied force with the wiping direction on any surface):

- **planarity** — how far the contact positions leave the best plane through them that is
  pressed on: the RMS residual of the depth along the mean friction-free normal after fitting it
  linearly over the surface and the press (a compliant pad sinks with the force), the plane's
  tilt from that normal bounded by ``MAX_PLANE_TILT_DEG`` (a steeper plane could hold an arc
  drawn in a vertical plane, but nobody presses on it).
  Hand-wiped planes: 0.3-3.4 mm (pad compliance, tremor); curved parts: 5.8-19 mm.
- **turning** — the angular range of the friction-free normal (the force with its component
  along the motion removed) along the segment: the largest angle between the mean normals of
  its ``TURNING_WINDOWS`` consecutive parts (a curve may turn out and back). Planes: a few
  degrees; curves: tens of degrees.

Each measure gives log-odds for contour, ``STEEPNESS`` · ln(value / even-odds value); a
segment's evidence is their mean (they measure one thing twice, so they are not added), weighted
by the segment's duration over all segments. When the two measures disagree the log-odds
cancel and the confidence stays near 0.5: the reason says which measure points where.
Segments too short or too still to measure carry no evidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skills.segmentation import SegmentBounds
from skills.surface import pressed_surface

PLANE_RMS_AT_EVEN_ODDS_M = 0.006
"""Planarity residual (m) at which slide and contour are equally likely."""

TURNING_AT_EVEN_ODDS_DEG = 12.0
"""Turning of the normal within a segment (deg) at which slide and contour are equally likely."""

STEEPNESS = 4.0
"""Log-odds per unit of log-ratio: a measure 2x past its even-odds value gives odds of 16:1."""

TURNING_WINDOWS = 6
"""Consecutive parts of a segment whose mean normals are compared for the turning."""

MAX_PLANE_TILT_DEG = 8.0
"""Largest tilt (deg) of a fitted plane from the mean friction-free normal: that normal's uncertainty."""

MIN_MEASURED_SAMPLES = 10
"""A segment needs at least this many samples moving in contact to be measured."""


@dataclass(frozen=True)
class SegmentGeometry:
    """What one slide segment's contact looks like: planarity residual (m), turning (deg), duration (s)."""

    plane_rms_m: float
    turning_deg: float
    duration_s: float


@dataclass(frozen=True)
class SkillClassification:
    """Outcome of the slide/contour classification: the choice, its confidence (0.5-1) and why."""

    is_slide: bool
    confidence: float
    turning_within_planes_deg: float
    """Largest turning of the normal within one slide segment, deg."""
    plane_rms_m: float
    """Largest planarity residual of one slide segment, m."""
    reason: str


def segment_geometry(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    directions: NDArray[np.float64],
    segment: SegmentBounds,
    rate_hz: float,
) -> SegmentGeometry | None:
    """Return planarity and turning of one contact segment, or None when it has too few moving samples.

    ``positions`` (N, 3) m; ``forces`` (N, 3) N applied; ``directions`` (N, 3) friction-free
    normals (zero where unknown).
    """
    rows = slice(segment.start, segment.end)
    p, d = positions[rows], directions[rows]
    valid = np.flatnonzero(np.linalg.norm(d, axis=1) > 0.5)
    if valid.size < MIN_MEASURED_SAMPLES:
        return None
    normal = d[valid].mean(axis=0)
    normal /= np.linalg.norm(normal)
    surface = pressed_surface(p[valid], forces[rows][valid] @ normal, normal, max_tilt_deg=MAX_PLANE_TILT_DEG)
    rms = surface.residual_rms_m
    parts = np.array_split(d[valid], min(TURNING_WINDOWS, valid.size // 2))
    means = np.array([part.mean(axis=0) for part in parts])
    means /= np.linalg.norm(means, axis=1, keepdims=True)
    turning = float(np.degrees(np.arccos(np.clip(np.min(means @ means.T), -1.0, 1.0))))
    return SegmentGeometry(rms, turning, (segment.end - segment.start) / rate_hz)


def _log_odds_contour(geometry: SegmentGeometry) -> tuple[float, float]:
    """Return the log-odds for contour from planarity and from turning of one segment."""
    from_plane = STEEPNESS * np.log(max(geometry.plane_rms_m, 1e-6) / PLANE_RMS_AT_EVEN_ODDS_M)
    from_turning = STEEPNESS * np.log(max(geometry.turning_deg, 1e-3) / TURNING_AT_EVEN_ODDS_DEG)
    return float(from_plane), float(from_turning)


def classify_skill(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    directions: NDArray[np.float64],
    slide_segments: list[SegmentBounds],
    rate_hz: float,
) -> SkillClassification:
    """Classify from the contact geometry of the slide segmentation's contact segments.

    Raises ValueError when no contact segment has enough moving samples to be measured.
    """
    candidates = [segment_geometry(positions, forces, directions, s, rate_hz) for s in slide_segments if s.contact]
    candidates = [segment_geometry(positions, forces, directions, s, rate_hz) for s in slide_segments if s.contact]
    measured = [g for g in candidates if g is not None]
    if not measured:
        raise ValueError("the tool never slides in contact long enough: slide or contour cannot be told")
    weights = np.array([g.duration_s for g in measured])
    odds = np.array([_log_odds_contour(g) for g in measured])
    per_measure = weights @ odds / weights.sum()
    total = float(per_measure.mean())
    p_contour = 1.0 / (1.0 + np.exp(-total))
    is_slide = p_contour < 0.5
    confidence = float(max(p_contour, 1.0 - p_contour))
    rms_mm = max(g.plane_rms_m for g in measured) * 1000.0
    turning = max(g.turning_deg for g in measured)
    n = len(measured)
    planes_say = "contour" if per_measure[0] > 0 else "slide"
    turning_says = "contour" if per_measure[1] > 0 else "slide"
    facts = (
        f"contact leaves its plane by up to {rms_mm:.1f} mm RMS and its normal turns up to {turning:.1f} deg "
        f"within {n} plane candidate(s)"
    )
    if planes_say != turning_says:
        reason = f"mixed evidence: {facts}; planarity says {planes_say}, turning says {turning_says}"
    elif is_slide:
        reason = f"planar: {facts}"
    else:
        reason = f"curved: {facts}"
    return SkillClassification(is_slide, confidence, turning, max(g.plane_rms_m for g in measured), reason)
