"""The joint CF z of matched contact segments of several demonstrations (docs/LEARNING.md, section 11, step 3): a
slide's plane from their contact points and friction-free forces pooled (`skills.compliant_frames.slide_frame`:
strokes side by side span the plane a single line cannot); a contour's normals as the mean, at the same place, of each
one's fused normals (a normal that turns at the same place in every trial is kept, one hand's wander is averaged
down). World frame, SI units."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from schemas.skill import SkillType
from skills.compliant_frames import PlaneFit, plane_along, slide_frame
from skills.friction import unit_rows
from skills.joint_alignment import ALIGNMENT_POINTS, Stroke, angles_deg
from skills.joint_correspondence import SAME_PLACE_M
from skills.parameterize import LearnedSegment, LearnedTrial
from skills.surface_geometry import FORCE_SIGMA_MIN_DEG

AGREEMENT_DEG = 2.0
"""A demonstration whose contour normals lie this far (deg, median) from the others' mean weighs half as much as
one that agrees with it exactly (`_normals_by_place`)."""


def _pooled_plane(strokes: list[Stroke], trials: list[LearnedTrial], positions: NDArray) -> PlaneFit:
    """The slide CF of matched segments from their contact points and forces pooled, its x and origin along the mean
    path ``positions`` (M, 3) m."""
    r = [t.recording for t in trials]
    pooled = {
        "positions": np.concatenate([ri.positions[s.rows] for ri, s in zip(r, strokes, strict=True)]),
        "forces": np.concatenate([ri.forces[s.rows] for ri, s in zip(r, strokes, strict=True)]),
        "directions": np.concatenate([ri.contact.directions[s.rows] for ri, s in zip(r, strokes, strict=True)]),
    }
    groups = [ri.surfaces.group(s.rows.start, s.rows.stop) for ri, s in zip(r, strokes, strict=True)]
    known = [g for g in groups if g is not None]
    sigma = float(np.median([g.force_sigma_deg for g in known])) if known else FORCE_SIGMA_MIN_DEG
    area = any(g.is_area for g in known)
    fit = slide_frame(**pooled, force_sigma_deg=sigma, area=area)
    return plane_along(fit, positions)


def _normals_by_place(
    positions: NDArray[np.float64], trials: list[LearnedTrial], items: list[LearnedSegment]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The joint contour normals (G, 3) at the reference's path ``positions`` (G, 3) m, and each demonstration's
    weight (T,) in them. Each demonstration's CF z at its contact sample nearest each point (a normal turns at the
    same PLACE in every trial, whenever each got there; farther than `SAME_PLACE_M` it does not count there), their
    mean, then again weighted by how far each one agrees with that mean (its median angle to it, against
    `AGREEMENT_DEG`): one hand's lean does not pull the others' surface."""
    own, near = [], []
    for trial, item in zip(trials, items, strict=True):
        points = trial.recording.positions[item.segment.start_index : item.segment.end_index]
        distance, nearest = cKDTree(points).query(positions)
        own.append(np.asarray(item.cf_z)[nearest])
        near.append(distance <= SAME_PLACE_M)
    normals, counts = np.array(own), np.array(near, dtype=float)
    mean = unit_rows(np.einsum("tg,tgd->gd", counts, normals))
    angles = [
        np.median(angles_deg(n[c > 0], mean[c > 0])) if c.any() else 0.0 for n, c in zip(normals, counts, strict=True)
    ]
    weights = 1.0 / (1.0 + (np.asarray(angles) / AGREEMENT_DEG) ** 2)
    weights /= weights.sum()
    return unit_rows(np.einsum("t,tg,tgd->gd", weights, counts, normals)), weights


def joint_normals(
    skill_type: SkillType,
    strokes: list[Stroke],
    trials: list[LearnedTrial],
    items: list[LearnedSegment],
    reference_positions: NDArray[np.float64],
    mean_positions: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], PlaneFit | None]:
    """The joint CF z of matched segments on the alignment points (G, 3), each demonstration's weight in it (T,),
    and a slide's plane (None for a contour): a slide's from their evidence pooled (`_pooled_plane`, its x and
    origin along the mean path ``mean_positions`` (M, 3) m), a contour's by place along the reference's path
    ``reference_positions`` (G, 3) m (`_normals_by_place`)."""
    if skill_type is SkillType.slide:
        plane = _pooled_plane(strokes, trials, mean_positions)
        normals = np.broadcast_to(plane.rotation[:, 2], (ALIGNMENT_POINTS, 3))
        return normals, np.full(len(trials), 1.0 / len(trials)), plane
    normals, weights = _normals_by_place(reference_positions, trials, items)
    return normals, weights, None
