"""The normal at every contact sample from ALL the evidence: the pooled contact geometry and the force.

`surface_evidence` pools the contact segments of the slide segmentation by the surface they press on
(`skills.surface_geometry.surface_groups`), fits each surface's local geometry, measures how far its force's
direction can be trusted against it, and fuses the two per sample (`skills.surface_geometry.fused_normals`). The
learner then reads every normal from here: a slide's plane is fitted to its whole surface, a contour's frames
follow the fused normals, and the type is decided from how those turn — so a force direction that wobbles where
the geometry shows a plane (a hand, a wrench estimated from joint torques) is not taken for curvature.

Inputs are the uniformly sampled demonstration in the world frame, SI: positions (N, 3) m, forces (N, 3) N applied
by the tool, velocities (N, 3) m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skills.compliant_frames import contour_normals
from skills.contact import ContactAnalysis
from skills.friction import unit_rows
from skills.segmentation import SegmentBounds, mean_direction
from skills.surface_geometry import (
    AREA_SHARE,
    AREA_WEIGHT,
    FusedNormals,
    fused_normals,
    local_geometry,
    surface_groups,
)

FORCE_NORMAL_RATE_HZ = 200.0
"""Rate (Hz) the friction-free force's normals are worked out at (interpolated to the demonstration's)."""


@dataclass(frozen=True)
class SurfaceGroup:
    """One surface and the contact segments that press on it.

    ``index`` its place in `SurfaceEvidence.groups`; ``segments`` the slide segmentation's contact segments on it, in
    time order; ``rows`` (M,) their samples;
    ``force_sigma_deg`` the uncertainty of the force's direction measured against its geometry (the prior where
    nothing measured it: ``sure_samples`` 0); ``area_share`` the share of its samples where the geometry outweighs
    the force (`AREA_WEIGHT`).
    """

    index: int
    segments: list[SegmentBounds]
    rows: NDArray[np.int_]
    force_sigma_deg: float
    sure_samples: int
    area_share: float

    @property
    def is_area(self) -> bool:
        """Whether the contact spans an area of this surface (``AREA_SHARE`` of it): geometry decides its normal."""
        return self.area_share >= AREA_SHARE


@dataclass(frozen=True)
class SurfaceEvidence:
    """Per sample (N,) of the demonstration: ``normals`` (N, 3) fused, unit into the surface (zero outside the
    contact segments); ``force_normals`` (N, 3) the smoothed friction-free force's (`contour_normals`);
    ``weights`` (N,) the geometry's share in each fused normal; ``group_of`` (N,) the surface group of each contact
    sample (-1 elsewhere); ``groups`` the surfaces."""

    normals: NDArray[np.float64]
    force_normals: NDArray[np.float64]
    weights: NDArray[np.float64]
    group_of: NDArray[np.int_]
    groups: list[SurfaceGroup]

    def group(self, start: int, end: int) -> SurfaceGroup | None:
        """The surface the samples ``[start, end)`` (a contact segment of any segmentation) press on most, or None
        (no contact sample there)."""
        owners = self.group_of[start:end]
        owners = owners[owners >= 0]
        return self.groups[int(np.bincount(owners).argmax())] if owners.size else None


def _force_normals(
    forces: NDArray[np.float64],
    velocities: NDArray[np.float64],
    rate_hz: float,
    estimate: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """The friction-free force's normals (M, 3) of one segment's samples (`contour_normals`; ``estimate`` (M, 3) the
    normal it judges sliding against), worked out at ``FORCE_NORMAL_RATE_HZ`` at most and interpolated back: their
    smoothing over 0.1 s needs no more, and at 1 kHz it cost five times the rest of the surface's evidence."""
    step = max(1, int(rate_hz // FORCE_NORMAL_RATE_HZ))
    if step == 1 or len(forces) < 4 * step:
        return contour_normals(forces, velocities, rate_hz, slice(None), estimate)
    taken = np.arange(0, len(forces), step)
    coarse = contour_normals(
        forces[taken], velocities[taken], rate_hz / step, slice(None), None if estimate is None else estimate[taken]
    )
    index = np.arange(len(forces))
    return unit_rows(np.column_stack([np.interp(index, taken, coarse[:, k]) for k in range(3)]))


def _fused(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    force_normals: NDArray[np.float64],
    trusted: NDArray[np.bool_],
    along: bool,
) -> FusedNormals:
    """The fused normals of one surface's samples (arrays (M, ...) of its rows, in time order; ``along``: see
    `skills.surface_geometry.fused_normals`)."""
    press = np.sum(forces * force_normals, axis=1)
    return fused_normals(force_normals, trusted, local_geometry(positions, force_normals, press, trusted), along)


def surface_evidence(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    velocities: NDArray[np.float64],
    contact: ContactAnalysis,
    segments: list[SegmentBounds],
) -> SurfaceEvidence:
    """Return the fused normals of a demonstration's contact samples (module docstring).

    ``segments`` the slide segmentation (`skills.segmentation.segment_demonstration` with normal splits): its
    contact segments are the plane candidates that are pooled into surfaces.
    """
    n = positions.shape[0]
    rate_hz = contact.rate_hz
    force_normals = np.zeros((n, 3))
    contacts = [s for s in segments if s.contact]
    means: list[NDArray[np.float64] | None] = []
    for s in contacts:
        rows = slice(s.start, s.end)
        force_normals[rows] = _force_normals(forces[rows], velocities[rows], rate_hz)
        mean = mean_direction(contact.directions, s.start, s.end)
        means.append(None if mean is None else unit_rows(mean))
    normals, weights = force_normals.copy(), np.zeros(n)
    group_of = np.full(n, -1)
    groups = []
    pooled = surface_groups(positions, means, [slice(s.start, s.end) for s in contacts])
    for g, members in enumerate(pooled):
        rows = np.concatenate([np.arange(contacts[k].start, contacts[k].end) for k in members])
        trusted = np.linalg.norm(contact.directions[rows], axis=1) > 0.5
        reference = _fused(positions[rows], forces[rows], force_normals[rows], trusted, along=True)
        # The friction comes off again about the geometry's normals: judged against the force's own normal, a force
        # that errs along the motion makes the motion look like the tool settling, and keeps its error.
        for k in members:
            own = slice(contacts[k].start, contacts[k].end)
            estimate = reference.normals[np.searchsorted(rows, contacts[k].start) :][: own.stop - own.start]
            force_normals[own] = _force_normals(forces[own], velocities[own], rate_hz, estimate)
        fused = _fused(positions[rows], forces[rows], force_normals[rows], trusted, along=False)
        normals[rows], weights[rows], group_of[rows] = fused.normals, fused.weights, g
        groups.append(
            SurfaceGroup(
                index=g,
                segments=[contacts[k] for k in members],
                rows=rows,
                force_sigma_deg=fused.force_sigma_deg,
                sure_samples=fused.sure_samples,
                area_share=float(np.mean(fused.weights >= AREA_WEIGHT)),
            )
        )
    return SurfaceEvidence(
        normals=normals, force_normals=force_normals, weights=weights, group_of=group_of, groups=groups
    )
