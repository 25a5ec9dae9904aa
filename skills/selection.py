"""Skill selection (beyond the paper): slide or contour, decided from what separates them physically.

A slide presses on planes: one normal per plane. A contour follows a curved surface: its normal
turns along the path. The evidence, measured per plane candidate (each slide segment: a stroke,
or the part of one between creases), from the normals of `skills.surface_evidence` — the contact
geometry where the contact covers an area of its surface (passes side by side), the friction-free
force where it does not (a line, a single curve), so that a force direction that wobbles over a
plane (a hand, a wrench estimated from joint torques) is not taken for curvature:

- **turning** (both ways) — the angular range of the normal along the segment: the largest angle
  between the mean normals of its consecutive parts of ``TURNING_WINDOW_S`` (3 to 6 parts; a curve
  may turn out and back). Hand-wiped planes: up to ~9° (a hand leans, tremor); curved parts: 22-95°;
  the real KU Leuven contours 27-35°.
- **tool following** (towards contour only) — the share of that turning the tool's own rotation
  takes up: the normal's turning seen in the TOOL frame against the world frame. A person who
  follows a curved surface turns the tool with it (the KU Leuven trials: 40-80 %); on a plane the
  tool wobbles on its own (0 %). A tool that does not turn proves nothing (a ball tip need not).
- **planarity** — how far the contact positions leave a pressed plane (`skills.surface`). Towards
  contour: a path that leaves every plane the force could press on (tilted from the mean normal by up
  to the friction cone, μ 0.9) is on a curve, and counts fully. Towards slide: a path in the plane the
  force presses on (tilted by at most a hand's lean, ``PRESSED_PLANE_TILT_DEG``; where the contact covers
  an AREA of its surface, any plane in the friction cone: the geometry then shows the surface itself)
  proves little — an edge is traced as a planar curve while its normal turns — so it counts at a quarter
  of the steepness and at most ``PLANARITY_SLIDE_CAP``: it can tip a turning near even odds (a
  simulator's misdirected friction turns a plane's normal by up to ~16°), never outweigh a clear one.
  Neither bound fits a plane to the force and then judges the force by it: a flat path pressed with a
  13° lean leaves the hand's-lean plane, not the friction cone's, so it counts as no curve.

Each gives log-odds for contour; a segment's log-odds are their sum, and the skill's the mean
over segments weighted by duration. Confidence = max(p, 1 − p); the more likely type is chosen.
Below ``MIXED_CONFIDENCE`` the evidence is MIXED: the reason says so and the skill's
``type_evidence`` check warns (contour frames are not right on a plane by default: on real wipes
recorded with an estimated wrench they were 12-22° off). Segments too short or too still to measure
carry no evidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from skills.quaternions import matrix_from_quaternion
from skills.segmentation import SegmentBounds
from skills.surface import pressed_surface
from skills.surface_geometry import AREA_SHARE, FRICTION_CONE_DEG

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

PRESSED_PLANE_TILT_DEG = 8.0
"""Largest tilt (deg) from the mean normal of the plane a path counts as pressed in, towards slide: a hand's lean."""

MIN_TURNING_PARTS = 3
"""Fewest consecutive parts the turning compares: a quick wipe of 1.2 s still shows most of its turn."""

MIN_MEASURED_SAMPLES = 10
"""A segment needs at least this many samples moving in contact to be measured."""

REPEAT_RADIUS_M = 0.003
"""Two samples of different passes within this (m) lie at the same place of the surface."""

REPEAT_MIN_ARC_M = 0.03
"""Two samples farther apart than this along the path (m) belong to different passes."""

REPEAT_SHARE = 0.3
"""A path that comes back to where it was over at least this share of it shows whether its normal repeats."""

REPEAT_SAMPLES = 2000
"""Most samples of a segment the repetition is judged on (evenly taken)."""

MIXED_CONFIDENCE = 0.75
"""Below this confidence the evidence is reported as mixed (see the module docstring)."""


@dataclass(frozen=True)
class SegmentGeometry:
    """What one slide segment's contact looks like.

    ``plane_rms_m`` the residual (m) about the plane the force presses on (module docstring, towards slide);
    ``curved_rms_m`` about the best plane in the friction cone (towards contour); ``turning_deg`` the normal's
    turning in the world (deg); ``tool_turning_deg`` the same in the tool frame (deg); ``duration_s`` (s);
    ``area_share`` (0-1) how much of the segment's surface the contact covers as an area
    (`skills.surface_evidence.SurfaceGroup.area_share`).
    """

    plane_rms_m: float
    curved_rms_m: float
    turning_deg: float
    tool_turning_deg: float
    duration_s: float
    area_share: float = 0.0
    repeat_share: float = 0.0
    repeat_disagreement_deg: float = 0.0

    @property
    def repeating_turning_deg(self) -> float:
        """The turning that repeats (deg): where the path comes back to where it was (``REPEAT_SHARE`` of it), the
        part of the turning the normals at the same place on different passes do not disagree by; else all of it."""
        if self.repeat_share < REPEAT_SHARE:
            return self.turning_deg
        return self.turning_deg * float(np.clip(1.0 - self.repeat_disagreement_deg / max(self.turning_deg, 1e-9), 0, 1))

    @property
    def following(self) -> float:
        """Share (0-1) of the normal's turning that the tool's rotation takes up; 0 where the normal hardly turns."""
        if self.turning_deg < 0.5 * TURNING_AT_EVEN_ODDS_DEG:
            return 0.0
        return float(np.clip(1.0 - self.tool_turning_deg / self.turning_deg, 0.0, 1.0))

    def log_odds_contour(self) -> NDArray[np.float64]:
        """Return the log-odds for contour from (turning, tool following, planarity)."""
        curved_ratio = np.log(max(self.curved_rms_m, 1e-6) / PLANE_RMS_AT_EVEN_ODDS_M)
        plane_ratio = np.log(max(self.plane_rms_m, 1e-6) / PLANE_RMS_AT_EVEN_ODDS_M)
        planarity = (
            STEEPNESS * curved_ratio
            if curved_ratio > 0
            else max(PLANARITY_SLIDE_STEEPNESS * min(plane_ratio, 0.0), -PLANARITY_SLIDE_CAP)
        )
        return np.array(
            [
                STEEPNESS * np.log(max(self.repeating_turning_deg, 1e-3) / TURNING_AT_EVEN_ODDS_DEG),
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

    The parts last ``TURNING_WINDOW_S`` (of the samples given; ``MIN_TURNING_PARTS`` to 6 parts).
    """
    parts = int(np.clip(round(len(directions) / rate_hz / TURNING_WINDOW_S), MIN_TURNING_PARTS, 6))
    means = np.array([part.mean(axis=0) for part in np.array_split(directions, min(parts, len(directions)))])
    means /= np.linalg.norm(means, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip(np.min(means @ means.T), -1.0, 1.0))))


def segment_geometry(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    normals: NDArray[np.float64],
    quaternions: NDArray[np.float64],
    segment: SegmentBounds,
    rate_hz: float,
    area_share: float = 0.0,
) -> SegmentGeometry | None:
    """Return planarity, turning and the tool's turning of one contact segment, or None when too few samples move.

    ``positions`` (N, 3) m; ``forces`` (N, 3) N applied; ``normals`` (N, 3) unit normals into the surface where
    the tool slides (`skills.surface_evidence`; zero where unknown); ``quaternions`` (N, 4) world-from-tool,
    scalar-last; ``area_share`` of the segment's surface (`SegmentGeometry`).
    """
    rows = slice(segment.start, segment.end)
    p, d = positions[rows], normals[rows]
    valid = np.flatnonzero(np.linalg.norm(d, axis=1) > 0.5)
    if valid.size < MIN_MEASURED_SAMPLES:
        return None
    normal = d[valid].mean(axis=0)
    normal /= np.linalg.norm(normal)
    press = forces[rows][valid] @ normal
    curved = pressed_surface(p[valid], press, normal, max_tilt_deg=FRICTION_CONE_DEG).residual_rms_m
    if area_share >= AREA_SHARE:
        planar = curved  # the geometry shows the surface itself: any plane the force could press on
    else:
        planar = pressed_surface(p[valid], press, normal, max_tilt_deg=PRESSED_PLANE_TILT_DEG).residual_rms_m
    in_tool = np.einsum("nji,nj->ni", matrix_from_quaternion(quaternions[rows][valid]), d[valid])
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))))[valid]
    repeats, disagreement = repeated_normals(p[valid], d[valid], arc)
    return SegmentGeometry(
        plane_rms_m=planar,
        curved_rms_m=curved,
        turning_deg=_turning_deg(d[valid], rate_hz),
        tool_turning_deg=_turning_deg(in_tool, rate_hz),
        duration_s=(segment.end - segment.start) / rate_hz,
        area_share=area_share,
        repeat_share=repeats,
        repeat_disagreement_deg=disagreement,
    )


def repeated_normals(
    positions: NDArray[np.float64], normals: NDArray[np.float64], arc_m: NDArray[np.float64]
) -> tuple[float, float]:
    """Return how much of a path comes back to where it was (the share of its samples with a sample of ANOTHER pass
    within ``REPEAT_RADIUS_M``: farther than ``REPEAT_MIN_ARC_M`` along the path) and how far the normals there
    disagree (deg, median over such pairs; 0 without any). ``positions`` (M, 3) m, unit ``normals`` (M, 3) and the
    distance travelled ``arc_m`` (M,) m, of one segment's measured samples (at most ``REPEAT_SAMPLES`` evenly
    taken). A surface's normal is the same at the same place on every pass; a hand's wobble, or an error that
    follows the motion, is not."""
    taken = np.unique(np.linspace(0, len(positions) - 1, min(len(positions), REPEAT_SAMPLES)).round().astype(int))
    p, n, arc = positions[taken], normals[taken], arc_m[taken]
    pairs = cKDTree(p).query_pairs(REPEAT_RADIUS_M, output_type="ndarray")
    if pairs.size == 0:
        return 0.0, 0.0
    other_pass = np.abs(arc[pairs[:, 0]] - arc[pairs[:, 1]]) > REPEAT_MIN_ARC_M
    pairs = pairs[other_pass]
    if pairs.size == 0:
        return 0.0, 0.0
    share = len(np.unique(pairs)) / len(p)
    angles = np.degrees(np.arccos(np.clip(np.sum(n[pairs[:, 0]] * n[pairs[:, 1]], axis=1), -1.0, 1.0)))
    return float(share), float(np.median(angles))


def classify_skill(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    normals: NDArray[np.float64],
    quaternions: NDArray[np.float64],
    slide_segments: list[SegmentBounds],
    rate_hz: float,
    area_shares: list[float] | None = None,
) -> SkillClassification:
    """Classify from the contact geometry of the slide segmentation's contact segments (arrays as `segment_geometry`;
    ``area_shares`` one per contact segment, default 0).

    Raises ValueError when no contact segment has enough moving samples to be measured.
    """
    contacts = [s for s in slide_segments if s.contact]
    shares = area_shares or [0.0] * len(contacts)
    candidates = [
        segment_geometry(positions, forces, normals, quaternions, s, rate_hz, share)
        for s, share in zip(contacts, shares, strict=True)
    ]
    measured = [g for g in candidates if g is not None]
    if not measured:
        raise ValueError("the tool never slides in contact long enough: slide or contour cannot be told")
    weights = np.array([g.duration_s for g in measured])
    log_odds = weights @ np.array([g.log_odds_contour() for g in measured]) / weights.sum()
    p_contour = float(1.0 / (1.0 + np.exp(-log_odds.sum())))
    confidence = max(p_contour, 1.0 - p_contour)
    mixed = confidence < MIXED_CONFIDENCE
    is_slide = p_contour < 0.5
    turning = max(g.turning_deg for g in measured)
    following = max(g.following for g in measured)
    rms_mm = max(g.plane_rms_m for g in measured) * 1000.0
    repeating = [g for g in measured if g.repeat_share >= REPEAT_SHARE]
    repeats = (
        f" ({max(g.repeating_turning_deg for g in repeating):.1f} deg of it repeating at the same place on other "
        "passes)"
        if repeating
        else ""
    )
    facts = (
        f"the normal turns up to {turning:.1f} deg within a stroke{repeats} (even odds at "
        f"{TURNING_AT_EVEN_ODDS_DEG:.0f} deg), the tool turns with {100 * following:.0f} % of it, and the contact "
        f"leaves its best pressed plane by up to {rms_mm:.1f} mm RMS, over {len(measured)} plane candidate(s)"
    )
    if mixed:
        chosen = "slide" if is_slide else "contour"
        reason = f"mixed evidence, {chosen} the more likely: {facts}"
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
