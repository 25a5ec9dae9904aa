"""A skill changed for a robustness trial: its force level scaled, and the point an unknown tilt turns the work piece
about. Pure functions on `schemas.skill.Skill` (world frame, SI units; docs/CONVENTIONS.md)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from schemas.skill import DMPParameters, SegmentKind, Skill


def _scaled_force_dmp(p: DMPParameters, scale: float) -> DMPParameters:
    """The force DMP whose rollout is ``scale`` times the original: the transformation system is linear in
    (y, z, g, f), so start, goal and forcing weights scale together (the amplitude factor stays 1)."""
    return p.model_copy(
        update={
            "start": [scale * v for v in p.start],
            "goal": [scale * v for v in p.goal],
            "weights": [[scale * v for v in row] for row in p.weights],
        }
    )


def force_scaled_skill(skill: Skill, scale: float) -> Skill:
    """``skill`` with every desired CF-z force multiplied by ``scale`` (slide constants, contour force DMPs)."""
    if scale == 1.0:
        return skill
    segments = []
    for segment in skill.segments:
        update: dict = {}
        if segment.force_constant_n is not None:
            update["force_constant_n"] = scale * segment.force_constant_n
        if segment.force_dmp is not None:
            update["force_dmp"] = _scaled_force_dmp(segment.force_dmp, scale)
        segments.append(segment.model_copy(update=update))
    return skill.model_copy(update={"segments": segments})


def contact_centre(skill: Skill) -> NDArray[np.float64]:
    """The mean compliant-frame origin over the skill's contact segments (world, m): where the tool presses, the
    point an unknown tilt of the work piece turns about. A skill without frames gives its first position goal."""
    origins = [
        np.asarray(s.compliant_frames.origins, dtype=float)
        for s in skill.segments
        if s.kind is SegmentKind.contact and s.compliant_frames is not None
    ]
    if origins:
        return np.concatenate(origins).mean(axis=0)
    return np.asarray(skill.segments[0].position_dmp.goal, dtype=float)
