"""Skill selection (beyond the paper): slide or contour, decided from what separates them physically.

A slide presses on planes: one normal per plane. A contour follows a curved surface: its normal
turns along the path. The evidence, measured per plane candidate (each slide segment: a stroke,
or the part of one between creases), all free of friction (which turns the applied force with the
wiping direction on any surface):

- **turning** (both ways) — the angular range of the friction-free normal along the segment: the
  largest angle between the mean normals of its consecutive parts of ``TURNING_WINDOW_S`` (a curve
  may turn out and back). Hand-wiped planes: up to ~9° (a hand leans, tremor); curved parts: 22-95°;
  the real KU Leuven contours 27-35°.
- **tool following** (towards contour only) — the share of that turning the tool's own rotation
  takes up: the normal's turning seen in the TOOL frame against the world frame. A person who
  follows a curved surface turns the tool with it (the KU Leuven trials: 40-80 %); on a plane the
  tool wobbles on its own (0 %). A tool that does not turn proves nothing (a ball tip need not).
- **planarity** (mostly towards contour) — how far the contact positions leave the best pressed
  plane (`skills.surface`, tilt from the mean normal at most ``MAX_PLANE_TILT_DEG``): a path that
  leaves every plane is on a curve, and counts fully. A path IN one plane proves little: an edge is
  traced as a planar curve while the normal turns along it (the real contour trials lie within
  ~6 mm of one). It counts towards slide at a quarter of the steepness and at most
  ``PLANARITY_SLIDE_CAP`` (odds 4.5:1), so it can tip a turning near even odds (a simulator's
  misdirected friction turns a plane's normal by up to ~16°) but never outweighs a clear one.

Each gives log-odds for contour; a segment's log-odds are their sum, and the skill's the mean
over segments weighted by duration. Confidence = max(p, 1 − p). Below ``MIXED_CONFIDENCE`` the
evidence is MIXED: then contour is chosen, because its frames follow the measured force at every
sample, which is right on a plane as on a curve, while one slide plane is wrong on a curve; the
reason says so. Segments too short or too still to measure carry no evidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skills.quaternions import matrix_from_quaternion
from skills.segmentation import SegmentBounds
from skills.surface import pressed_surface

TURNING_AT_EVEN_ODDS_DEG = 18.0
"""Turning of the normal within a segment (deg) at which slide and contour are equally likely.

Between the planes' largest (hand-wiped ~9°, a simulator's misdirected high friction ~16°) and the curves'
smallest (~22°)."""

STEEPNESS = 4.0
"""Log-odds per unit of log-ratio: a turning 2x past its even-odds value gives odds of 16:1."""

PLANE_RMS_AT_EVEN_ODDS_M = 0.006
"""Planarity residual (m) at which it says nothing (planes: < 3.5 mm, curves: 6-19 mm, planar curves: ~5 mm)."""

PLANARITY_SLIDE_STEEPNESS = 1.0
"""Log-odds per unit of log-ratio with which a planar path counts towards slide (a quarter of ``STEEPNESS``)."""

PLANARITY_SLIDE_CAP = 1.5
"""Most log-odds a planar path counts towards slide (odds 4.5:1)."""

FOLLOWING_LOG_ODDS = 2.0
"""Log-odds for contour of a tool that turns fully with the normal (odds 7:1), in proportion to the share it follows."""

TURNING_WINDOW_S = 0.75
"""Duration of the consecutive parts whose mean normals are compared for the turning, s (2 to 6 parts)."""

MAX_PLANE_TILT_DEG = 8.0
"""Largest tilt (deg) of a fitted plane from the mean friction-free normal: that normal's uncertainty."""

MIN_MEASURED_SAMPLES = 10
"""A segment needs at least this many samples moving in contact to be measured."""

MIXED_CONFIDENCE = 0.75
"""Below this confidence the evidence is reported as mixed and contour is chosen (see the module docstring)."""


@dataclass(frozen=True)
class SegmentGeometry:
    """What one slide segment's contact looks like.

    ``plane_rms_m`` planarity residual (m); ``turning_deg`` the friction-free normal's turning in
    the world (deg); ``tool_turning_deg`` the same in the tool frame (deg); ``duration_s`` (s).
    """

    plane_rms_m: float
    turning_deg: float
    tool_turning_deg: float
    duration_s: float

    @property
    def following(self) -> float:
        """Share (0-1) of the normal's turning that the tool's rotation takes up; 0 where the normal hardly turns."""
        if self.turning_deg < 0.5 * TURNING_AT_EVEN_ODDS_DEG:
            return 0.0
        return float(np.clip(1.0 - self.tool_turning_deg / self.turning_deg, 0.0, 1.0))

    def log_odds_contour(self) -> NDArray[np.float64]:
        """Return the log-odds for contour from (turning, tool following, planarity)."""
        plane_ratio = np.log(max(self.plane_rms_m, 1e-6) / PLANE_RMS_AT_EVEN_ODDS_M)
        planarity = (
            STEEPNESS * plane_ratio
            if plane_ratio > 0
            else max(PLANARITY_SLIDE_STEEPNESS * plane_ratio, -PLANARITY_SLIDE_CAP)
        )
        return np.array(
            [
                STEEPNESS * np.log(max(self.turning_deg, 1e-3) / TURNING_AT_EVEN_ODDS_DEG),
                FOLLOWING_LOG_ODDS * self.following,
                planarity,
            ]
        )


@dataclass(frozen=True)
class SkillClassification:
    """Outcome of the slide/contour classification: the choice, its confidence (0.5-1), the evidence and why.

    ``log_odds`` (3,) the duration-weighted log-odds for contour of (turning, tool following,
    planarity); the geometry fields are the largest over the measured segments.
    """

    is_slide: bool
    confidence: float
    mixed: bool
    turning_within_planes_deg: float
    """Largest turning of the normal within one slide segment, deg."""
    tool_following: float
    """Largest share of a segment's turning that the tool followed, 0-1."""
    plane_rms_m: float
    """Largest planarity residual of one slide segment, m."""
    log_odds: NDArray[np.float64]
    reason: str


def _turning_deg(directions: NDArray[np.float64], rate_hz: float) -> float:
    """Return the largest angle (deg) between the mean unit ``directions`` (M, 3) of consecutive parts.

    The parts last ``TURNING_WINDOW_S`` (of the samples given; 2 to 6 parts).
    """
    parts = int(np.clip(round(len(directions) / rate_hz / TURNING_WINDOW_S), 2, 6))
    means = np.array([part.mean(axis=0) for part in np.array_split(directions, min(parts, len(directions)))])
    means /= np.linalg.norm(means, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip(np.min(means @ means.T), -1.0, 1.0))))


def segment_geometry(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    directions: NDArray[np.float64],
    quaternions: NDArray[np.float64],
    segment: SegmentBounds,
    rate_hz: float,
) -> SegmentGeometry | None:
    """Return planarity, turning and the tool's turning of one contact segment, or None when too few samples move.

    ``positions`` (N, 3) m; ``forces`` (N, 3) N applied; ``directions`` (N, 3) friction-free
    normals (zero where unknown); ``quaternions`` (N, 4) world-from-tool, scalar-last.
    """
    rows = slice(segment.start, segment.end)
    p, d = positions[rows], directions[rows]
    valid = np.flatnonzero(np.linalg.norm(d, axis=1) > 0.5)
    if valid.size < MIN_MEASURED_SAMPLES:
        return None
    normal = d[valid].mean(axis=0)
    normal /= np.linalg.norm(normal)
    surface = pressed_surface(p[valid], forces[rows][valid] @ normal, normal, max_tilt_deg=MAX_PLANE_TILT_DEG)
    in_tool = np.einsum("nji,nj->ni", matrix_from_quaternion(quaternions[rows][valid]), d[valid])
    return SegmentGeometry(
        plane_rms_m=surface.residual_rms_m,
        turning_deg=_turning_deg(d[valid], rate_hz),
        tool_turning_deg=_turning_deg(in_tool, rate_hz),
        duration_s=(segment.end - segment.start) / rate_hz,
    )


def classify_skill(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    directions: NDArray[np.float64],
    quaternions: NDArray[np.float64],
    slide_segments: list[SegmentBounds],
    rate_hz: float,
) -> SkillClassification:
    """Classify from the contact geometry of the slide segmentation's contact segments (arrays as `segment_geometry`).

    Raises ValueError when no contact segment has enough moving samples to be measured.
    """
    candidates = [
        segment_geometry(positions, forces, directions, quaternions, s, rate_hz) for s in slide_segments if s.contact
    ]
    measured = [g for g in candidates if g is not None]
    if not measured:
        raise ValueError("the tool never slides in contact long enough: slide or contour cannot be told")
    weights = np.array([g.duration_s for g in measured])
    log_odds = weights @ np.array([g.log_odds_contour() for g in measured]) / weights.sum()
    p_contour = float(1.0 / (1.0 + np.exp(-log_odds.sum())))
    confidence = max(p_contour, 1.0 - p_contour)
    mixed = confidence < MIXED_CONFIDENCE
    is_slide = p_contour < 0.5 and not mixed
    turning = max(g.turning_deg for g in measured)
    following = max(g.following for g in measured)
    rms_mm = max(g.plane_rms_m for g in measured) * 1000.0
    facts = (
        f"the friction-free normal turns up to {turning:.1f} deg within a stroke (even odds at "
        f"{TURNING_AT_EVEN_ODDS_DEG:.0f} deg), the tool turns with {100 * following:.0f} % of it, and the contact "
        f"leaves its best pressed plane by up to {rms_mm:.1f} mm RMS, over {len(measured)} plane candidate(s)"
    )
    if mixed:
        leaning = "contour" if p_contour >= 0.5 else "slide"
        reason = (
            f"mixed evidence (leaning {leaning}): {facts}; contour chosen because its frames follow the measured force "
            "at every sample, right on a plane as on a curve, while one slide plane is wrong on a curve"
        )
    else:
        reason = f"{'planar' if is_slide else 'curved'}: {facts}"
    return SkillClassification(
        is_slide=is_slide,
        confidence=confidence,
        mixed=mixed,
        turning_within_planes_deg=turning,
        tool_following=following,
        plane_rms_m=rms_mm / 1000.0,
        log_odds=log_odds,
        reason=reason,
    )
