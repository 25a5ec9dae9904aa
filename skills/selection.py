"""Skill selection (beyond the paper): classify a demonstration as slide or contour, with a confidence.

Idea: a slide presses on one or a few planes, so the direction of the applied normal force
(friction removed, see `segmentation.normal_directions`) is constant on each plane; a
contour follows a curved shape, so that direction keeps turning along the path. We take the
slide segmentation (one contact segment per plane) and measure how far the normal direction
turns WITHIN each segment, between its averaged beginning and end: near zero for planes
(noise averages out), tens of degrees for contours. Jumps between planes fall on segment
boundaries and do not count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skills.segmentation import SegmentBounds

TURNING_AT_EVEN_ODDS_DEG = 12.0
"""Turning within planes (deg) at which slide and contour are equally likely.

Measured: planes 0.3-7.4 deg in PyBullet (its friction is misdirected by up to ~15 deg, which
leaks into the friction-free direction), 0.3-1 deg synthetic; contours 30-60 deg (PyBullet
cylinder and block), 60-110 deg (the real KU Leuven recordings), 66 deg synthetic cylinder.
"""

EDGE_MARGIN_S = 0.1
"""Time left out at each end of a segment (transitions between planes), s; at most 10 % of the segment."""

END_WINDOW_S = 0.3
"""Length of the windows averaged at the beginning and the end of a segment, s; at most 25 % of the segment."""

MIN_WINDOW_SAMPLES = 5
"""Fewest samples an end window may average."""


@dataclass(frozen=True)
class SkillClassification:
    """Outcome of the slide/contour classification: the choice, its confidence (0.5-1) and why."""

    is_slide: bool
    confidence: float
    turning_within_planes_deg: float
    reason: str


def turning_within_segments_deg(
    directions: NDArray[np.float64], segments: list[SegmentBounds], rate_hz: float
) -> float:
    """Return the summed angle (deg) the normal direction turns inside each contact segment.

    Per contact segment, over the samples that carry a direction (the tool moving in contact),
    the angle between the mean direction of the first and of the last ``END_WINDOW_S`` worth of
    them (after ``EDGE_MARGIN_S`` worth) is added up. Short segments use shorter windows, so a
    contour that the slide segmentation chopped into many short pieces still counts; rests at
    the ends of a segment carry no direction and are skipped.
    """
    total = 0.0
    for segment in segments:
        if not segment.contact:
            continue
        rows = directions[segment.start : segment.end]
        moving = rows[np.linalg.norm(rows, axis=1) > 0.5]
        margin = min(round(EDGE_MARGIN_S * rate_hz), len(moving) // 10)
        window = min(round(END_WINDOW_S * rate_hz), len(moving) // 4)
        if window < MIN_WINDOW_SAMPLES:
            continue
        first = moving[margin : margin + window].mean(axis=0)
        last = moving[len(moving) - margin - window : len(moving) - margin].mean(axis=0)
        cos = np.dot(first, last) / (np.linalg.norm(first) * np.linalg.norm(last))
        total += float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return total


def classify_skill(
    directions: NDArray[np.float64], slide_segments: list[SegmentBounds], rate_hz: float
) -> SkillClassification:
    """Classify from the per-sample normal ``directions`` (N, 3; zero where unknown) and the slide segmentation."""
    turning = turning_within_segments_deg(directions, slide_segments, rate_hz)
    p_contour = 1.0 / (1.0 + (TURNING_AT_EVEN_ODDS_DEG / max(turning, 1e-6)) ** 3)
    is_slide = p_contour < 0.5
    n_planes = sum(s.contact for s in slide_segments)
    if is_slide:
        reason = (
            f"the normal force keeps its direction on each of {n_planes} plane(s) (turns {turning:.1f} deg within them)"
        )
    else:
        reason = f"the normal force turns {turning:.1f} deg along the path where planes would keep it constant"
    return SkillClassification(is_slide, float(max(p_contour, 1.0 - p_contour)), turning, reason)
