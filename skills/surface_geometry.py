"""What the contact positions say about the surface, pooled over every stroke that presses on it.

A tool point sliding on a surface stays ON it, so wherever the path spans an area (passes side by side, a
spiral, a zig-zag's legs) the positions alone give the surface's normal there; along a single line they give
nothing about the tilt across it (a line lies in every surface that contains it). The friction-free force
(`skills.friction`) gives a normal at every sample, but it carries whatever the sensor gets wrong: a hand's
lean, a wrench estimated from joint torques (tens of degrees that change with the arm's configuration), a
powered tool's side force. So geometry decides where it can see, and the force only where it cannot:

- **Surfaces, pooled.** Contact segments whose positions lie on one surface are fitted together
  (`surface_groups`): strokes side by side over a part are one area even when each is a line.
- **Local geometry** (`local_geometry`): at every contact sample, a weighted plane through the group's
  positions within ``LOCAL_RADIUS_M`` (all passes, any time): its normal, its WIDTH (how far the positions
  spread across the local path direction: the second principal extent, m) and its depth scatter (m). A line
  has no width; passes side by side have the lane spacing.
- **How far each is trusted** (`geometry_weights`): the geometric normal's tilt across the path is known to
  about ``depth / width`` (rad); the force's to ``force_sigma`` (its direction's uncertainty). Inverse
  variance: ``width² / (width² + (depth / tan(force_sigma))²)``. The force's uncertainty is MEASURED where the
  geometry is sure (`force_direction_sigma_deg`): a good wrist sensor agrees with a plane to a few degrees, an
  estimated wrench to tens; never below ``FORCE_SIGMA_MIN_DEG``.
- **The force bounds the geometry**: a geometric normal more than the friction cone (``FRICTION_CONE_DEG``,
  μ 0.9) from the force does not describe the surface pressed (an edge traced as a planar curve) and gets no
  weight.

Inputs are world-frame arrays, SI: positions (N, 3) m of the tool point, unit normals pointing INTO the surface
(along the force the tool applies).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from skills.friction import unit_rows
from skills.pressed_normals import angles_deg

LOCAL_RADIUS_M = 0.025
"""Radius (m) of the neighbourhood a local plane is fitted over: wide enough to reach the next lane of a wipe
(8-20 mm apart), narrow enough that a curved part's normal turns little within it (±14° on a 10 cm radius)."""

DECIMATION_M = 0.002
"""The positions a local plane is fitted to are taken every this many metres of path (m): a resting tool's
thousand samples at one point would otherwise outweigh the path around it."""

NEIGHBOURS_MAX = 96
"""Most neighbours a local plane is fitted to, the nearest first (the work is bounded by this times the positions)."""

CENTRES_PER_CHUNK = 2048
"""Local planes fitted at a time (the memory is bounded by this times ``NEIGHBOURS_MAX``)."""

DEPTH_NOISE_MIN_M = 3.0e-4
"""Least depth scatter (m) a local plane is credited with: tremor and a part's unevenness."""

FORCE_SIGMA_MIN_DEG = 5.0
"""Least uncertainty (deg) of the friction-free force's direction: a hand's lean across the motion."""

FORCE_SIGMA_MAX_DEG = 30.0
"""Most uncertainty (deg) credited to the force's direction (an estimated wrench off by tens of degrees)."""

FRICTION_CONE_DEG = float(np.degrees(np.arctan(0.9)))
"""Half angle (deg) of the widest friction cone (μ 0.9): a surface normal farther than this from the applied force
cannot be the one pressed."""

SURE_WEIGHT = 0.8
"""Samples whose geometry would outweigh a force of ``FORCE_SIGMA_MAX_DEG`` by this much measure the force's error."""

MIN_SURE_SHARE = 0.15
"""The force's uncertainty is measured only when at least this share of the samples is sure."""

AREA_WEIGHT = 0.5
"""A sample lies in the AREA of its surface where its geometry outweighs the force (weight at least this)."""

AREA_SHARE = 0.5
"""A surface is an area (its plane seen by geometry, the force only bounding it) when this share of its samples is."""

QUADRIC_POINTS = 2000
"""Most positions a pooling test fits its quadric to (evenly taken: a surface, not every sample)."""

POOL_NORMAL_DEG = 25.0
"""Two contact segments whose mean friction-free normals differ by more than this (deg) press different surfaces."""

POOL_RESIDUAL_FACTOR = 1.5
POOL_RESIDUAL_M = 5.0e-4
"""Two contact segments are one surface when their union leaves the best quadric surface by at most
``POOL_RESIDUAL_FACTOR`` times the worse of the two alone plus this (m, RMS): a step of a few millimetres between two
tables, or two faces of a fold, is two surfaces."""


@dataclass(frozen=True)
class LocalGeometry:
    """The surface around each contact sample as its positions show it (module docstring).

    ``tilts`` (N,) the surface's slope across the path relative to the force normal: depth (m, along the normal)
    per metre across; ``across`` (N, 3) unit, the direction across the path in the plane across the force normal;
    ``widths_m`` (N,) how far the neighbouring positions spread across the path BEYOND what one pass's own curve
    explains (m, RMS): 0 on a single line or curve, the lane spacing on a wipe that covers an area;
    ``along_tilts`` (N,), ``along`` (N, 3) and ``lengths_m`` (N,) the same along the path (its slope there, the
    path's direction, how far the neighbours spread along it: geometry always sees along a moving path);
    ``depth_m`` (N,) their RMS depth about the local surface, m.
    """

    tilts: NDArray[np.float64]
    across: NDArray[np.float64]
    widths_m: NDArray[np.float64]
    along_tilts: NDArray[np.float64]
    along: NDArray[np.float64]
    lengths_m: NDArray[np.float64]
    depth_m: NDArray[np.float64]


def arc_decimated(positions: NDArray[np.float64], step_m: float = DECIMATION_M) -> NDArray[np.int_]:
    """Return the indices (K,) of ``positions`` (N, 3) m taken every ``step_m`` of path (first and last included)."""
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))))
    bins = np.floor(arc / step_m).astype(np.int64)
    first = np.flatnonzero(np.diff(bins, prepend=-1))
    return np.unique(np.concatenate([first, [positions.shape[0] - 1]]))


def _weighted_fit(
    rows: NDArray[np.int_], weights: NDArray[np.float64], design: NDArray[np.float64], target: NDArray[np.float64],
    count: int,
) -> NDArray[np.float64]:  # fmt: skip
    """Per row (``count`` of them) the weighted least-squares coefficients (count, P) of ``target`` (M,) on
    ``design`` (M, P), over the pairs of that row (``rows`` (M,), ``weights`` (M,)); a tiny ridge keeps a
    direction the pairs do not span at 0."""
    p = design.shape[1]
    outer = design[:, :, None] * design[:, None, :] * weights[:, None, None]
    normal = np.stack([np.bincount(rows, outer[:, i, j], minlength=count) for i in range(p) for j in range(p)], 1)
    rhs = np.stack([np.bincount(rows, design[:, i] * target * weights, minlength=count) for i in range(p)], 1)
    normal = normal.reshape(count, p, p)
    scale = np.maximum(np.trace(normal, axis1=1, axis2=2), 1e-300) / p
    return np.linalg.solve(normal + 1e-9 * scale[:, None, None] * np.eye(p), rhs[:, :, None])[:, :, 0]


def local_geometry(
    positions: NDArray[np.float64],
    force_normals: NDArray[np.float64],
    press: NDArray[np.float64],
    sliding: NDArray[np.bool_] | None = None,
    radius_m: float = LOCAL_RADIUS_M,
) -> LocalGeometry:
    """Return what the positions show of the surface around each of ``positions`` (N, 3) m (one surface's contact
    samples, in time order), across the path.

    ``force_normals`` (N, 3) unit (the friction-free force's direction: the frame the tilt is measured in),
    ``press`` (N,) N the force along them (a pad sinks with it). Around each position taken every ``DECIMATION_M``
    of path (one per ``DECIMATION_M`` cube: a pass retraced a hundred times adds nothing the first did not show),
    its nearest ``NEIGHBOURS_MAX`` neighbours within ``radius_m`` (any pass, Gaussian weights of ``radius_m / 2``)
    are put in the frame (s along the path, l across it, h along the force normal): the lateral offset a single
    pass's curve explains (l on 1, s, s²) is taken out, what is left is the WIDTH, and the depth fitted on (1, s, s²,
    what is left, press) gives the TILT across. Each sample takes the fit of the nearest such position. Only the
    positions where the tool SLIDES (``sliding`` (N,), default all) are fitted: a tool settling onto the surface moves
    across its path and into the surface at once, which would look like a tilted plane. The work is bounded by the
    positions kept times ``NEIGHBOURS_MAX``, done ``CENTRES_PER_CHUNK`` at a time.
    """
    usable = np.flatnonzero(sliding) if sliding is not None and sliding.sum() >= 2 else np.arange(len(positions))
    kept = usable[arc_decimated(positions[usable])]
    _, first = np.unique(np.floor(positions[kept] / DECIMATION_M).astype(np.int64), axis=0, return_index=True)
    kept = kept[np.sort(first)]
    points, normal = positions[kept], force_normals[kept]
    count = len(points)
    heading = np.gradient(positions, axis=0)[kept] if len(positions) > 1 else np.zeros_like(points)
    tangent = unit_rows(heading - np.sum(heading * normal, axis=1, keepdims=True) * normal)
    across = unit_rows(np.cross(normal, tangent))
    tree = cKDTree(points)
    fits = [np.zeros((count, k)) for k in (5, 1, 1, 1)]  # coefficients, width, scatter, length
    neighbours = min(NEIGHBOURS_MAX, count)
    for start in range(0, count, CENTRES_PER_CHUNK):
        centres = np.arange(start, min(count, start + CENTRES_PER_CHUNK))
        distance, found = tree.query(points[centres], k=neighbours, distance_upper_bound=radius_m)
        distance, found = distance.reshape(len(centres), -1), found.reshape(len(centres), -1)
        valid = np.isfinite(distance)
        rows = np.repeat(np.arange(len(centres)), valid.sum(axis=1))  # chunk-local centre of each pair
        cols = found[valid]
        weight = np.exp(-0.5 * (distance[valid] / (0.5 * radius_m)) ** 2)
        at = centres[rows]
        offset = points[cols] - points[at]
        s = np.sum(offset * tangent[at], axis=1)
        lateral = np.sum(offset * across[at], axis=1)
        depth = np.sum(offset * normal[at], axis=1)
        curve = np.column_stack([np.ones_like(s), s, s * s])
        n = len(centres)
        left = lateral - np.sum(curve * _weighted_fit(rows, weight, curve, lateral, n)[rows], axis=1)
        total = np.bincount(rows, weight, minlength=n)
        surface = np.column_stack([curve, left, press[kept][cols] - press[kept][at]])
        coefficients = _weighted_fit(rows, weight, surface, depth, n)
        residual = depth - np.sum(surface * coefficients[rows], axis=1)
        mean_s = np.bincount(rows, weight * s, minlength=n) / total
        fits[0][centres] = coefficients
        fits[1][centres, 0] = np.sqrt(np.bincount(rows, weight * left**2, minlength=n) / total)
        fits[2][centres, 0] = np.sqrt(np.bincount(rows, weight * residual**2, minlength=n) / total)
        spread = np.bincount(rows, weight * s * s, minlength=n) / total - mean_s**2
        fits[3][centres, 0] = np.sqrt(np.maximum(spread, 0.0))
    coefficients, width, scatter, length = fits[0], fits[1][:, 0], fits[2][:, 0], fits[3][:, 0]
    nearest = tree.query(positions)[1]  # each sample takes the fit of the nearest kept position
    return LocalGeometry(
        tilts=coefficients[nearest, 3],
        across=across[nearest],
        widths_m=width[nearest],
        along_tilts=coefficients[nearest, 1],
        along=tangent[nearest],
        lengths_m=length[nearest],
        depth_m=scatter[nearest],
    )


def _inverse_variance(
    spread_m: NDArray[np.float64], depth_m: NDArray[np.float64], force_sigma_deg: float
) -> NDArray[np.float64]:
    """The weight (0-1) of a geometric tilt over positions spread ``spread_m`` (m) with depth scatter ``depth_m``
    (m, at least ``DEPTH_NOISE_MIN_M``) against a force direction uncertain by ``force_sigma_deg``."""
    equal = np.maximum(depth_m, DEPTH_NOISE_MIN_M) / np.tan(np.radians(force_sigma_deg))
    return spread_m**2 / (spread_m**2 + equal**2)


def geometry_weights(local: LocalGeometry, force_sigma_deg: float) -> NDArray[np.float64]:
    """Return per sample (N,) the weight (0-1) of the geometric tilt across the path against the force's direction.

    Inverse variance of the two tilts: the geometry's ``depth / width`` (rad, depth at least ``DEPTH_NOISE_MIN_M``)
    against the force's ``force_sigma_deg``; 0 where the geometry tilts beyond the friction cone
    (``FRICTION_CONE_DEG``): that is not the surface pressed.
    """
    weights = _inverse_variance(local.widths_m, local.depth_m, force_sigma_deg)
    return np.where(np.abs(local.tilts) <= np.tan(np.radians(FRICTION_CONE_DEG)), weights, 0.0)


def along_weights(local: LocalGeometry, force_sigma_deg: float) -> NDArray[np.float64]:
    """Return per sample (N,) the weight (0-1) of the geometric tilt ALONG the path (`geometry_weights`, over the
    neighbours' spread along it; 0 beyond the friction cone)."""
    weights = _inverse_variance(local.lengths_m, local.depth_m, force_sigma_deg)
    return np.where(np.abs(local.along_tilts) <= np.tan(np.radians(FRICTION_CONE_DEG)), weights, 0.0)


def force_direction_sigma_deg(trusted: NDArray[np.bool_], local: LocalGeometry) -> tuple[float, int]:
    """Return the uncertainty (deg) of the friction-free force's direction, and how many samples measured it.

    ``trusted`` (N,) where the force's direction is known (the tool slides). Where the geometry is sure even
    against the least trustworthy force (weight ``SURE_WEIGHT`` at ``FORCE_SIGMA_MAX_DEG``), the RMS of its tilt
    across the path from the force is the force's error; with too few such samples (under ``MIN_SURE_SHARE``: a
    line, a single curve) nothing measures it and it is ``FORCE_SIGMA_MIN_DEG``. Clipped to
    [``FORCE_SIGMA_MIN_DEG``, ``FORCE_SIGMA_MAX_DEG``].
    """
    sure = trusted & (geometry_weights(local, FORCE_SIGMA_MAX_DEG) >= SURE_WEIGHT)
    if sure.sum() < max(10, MIN_SURE_SHARE * max(int(trusted.sum()), 1)):
        return FORCE_SIGMA_MIN_DEG, 0
    rms = float(np.degrees(np.sqrt(np.mean(np.arctan(local.tilts[sure]) ** 2))))
    return float(np.clip(rms, FORCE_SIGMA_MIN_DEG, FORCE_SIGMA_MAX_DEG)), int(sure.sum())


@dataclass(frozen=True)
class FusedNormals:
    """Per-sample normals from geometry where it sees and the force where it does not (module docstring).

    ``normals`` (N, 3) unit into the surface; ``weights`` (N,) the geometry's share (0: the force alone);
    ``force_sigma_deg`` the force direction's uncertainty used, measured over ``sure_samples`` (0: the prior).
    """

    normals: NDArray[np.float64]
    weights: NDArray[np.float64]
    force_sigma_deg: float
    sure_samples: int


def fused_normals(
    force_normals: NDArray[np.float64], trusted: NDArray[np.bool_], local: LocalGeometry, along: bool = False
) -> FusedNormals:
    """Return the normals (N, 3) of one surface's samples: each force normal (unit, into the surface) tilted across
    the path toward the geometry by the geometry's weight (`geometry_weights`, with the force's MEASURED
    uncertainty, `force_direction_sigma_deg`); ``trusted`` (N,): where the force's direction is known.

    ``along``: tilt it along the path too (`along_weights`: a moving path always shows its slope along itself).
    The friction-free force is across the motion by construction, so along the path it is only as right as the
    judgement of where the tool slides and where it settles (`skills.friction.blended_friction_free`); these
    normals are the reference that judgement is made against, not the final ones (a curve's one-sided
    neighbourhood at the end of a stroke bends its geometric slope by a few degrees)."""
    sigma, sure = force_direction_sigma_deg(trusted, local)
    weights = geometry_weights(local, sigma)
    tilt = (weights * local.tilts)[:, None] * local.across
    if along:
        tilt = tilt + (along_weights(local, sigma) * local.along_tilts)[:, None] * local.along
    return FusedNormals(
        normals=unit_rows(force_normals - tilt), weights=weights, force_sigma_deg=sigma, sure_samples=sure
    )


def quadric_residual_m(positions: NDArray[np.float64], normal: NDArray[np.float64]) -> float:
    """Return the RMS depth (m) of ``positions`` (N, 3) m about the best quadric height field over the plane across
    unit ``normal`` (a plane bent along both axes: what a cylinder or sphere of a part looks like over a stroke), over
    at most ``QUADRIC_POINTS`` of them, evenly taken."""
    positions = positions[:: max(1, len(positions) // QUADRIC_POINTS)]
    basis = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    centred = positions - positions.mean(axis=0)
    u, w = (centred @ basis).T
    design = np.column_stack([np.ones_like(u), u, w, u * u, u * w, w * w])
    depth = centred @ normal
    coefficients, *_ = np.linalg.lstsq(design, depth, rcond=1e-6)
    return float(np.sqrt(np.mean((depth - design @ coefficients) ** 2)))


def surface_groups(
    positions: NDArray[np.float64], normals: list[NDArray[np.float64] | None], spans: list[slice]
) -> list[list[int]]:
    """Return the contact segments (indices into ``spans``) pooled by the surface they press on, each group in time
    order, the groups in order of their first segment.

    ``spans`` the contact segments' sample ranges of ``positions`` (N, 3) m; ``normals`` their mean friction-free
    normals (unit; None where unknown: never pooled). Segments are taken in time order; each joins the first group
    whose normal is within ``POOL_NORMAL_DEG`` of its own, whose union with it leaves its best quadric
    (`quadric_residual_m` about the union's mean normal) by little more than the worse of the two alone (each about
    its own normal; ``POOL_RESIDUAL_FACTOR``, ``POOL_RESIDUAL_M``), and whose union's best plane (where the union spans
    one) is within ``POOL_NORMAL_DEG`` of the force: strokes side by side on one part, not two faces of a fold or two
    tables at different heights.
    """
    members = [positions[s][arc_decimated(positions[s])] for s in spans]
    groups: list[list[int]] = []
    group_normals: list[NDArray[np.float64] | None] = []
    residuals: list[float] = []  # each group's quadric residual about its own normal, kept as it grows
    for k, normal in enumerate(normals):
        own = quadric_residual_m(members[k], normal) if normal is not None else 0.0
        for g, group in enumerate(groups):
            known = group_normals[g]
            if normal is None or known is None or angles_deg(normal, known) > POOL_NORMAL_DEG:
                continue
            union = np.concatenate([*(members[j] for j in group), members[k]])
            union_normal = unit_rows(len(group) * known + normal)
            residual = quadric_residual_m(union, union_normal)
            if residual > POOL_RESIDUAL_FACTOR * max(residuals[g], own) + POOL_RESIDUAL_M:
                continue
            singular, plane = np.linalg.svd(union - union.mean(axis=0), full_matrices=False)[1:]
            spans_plane = singular[1] > 10.0 * max(singular[2], DEPTH_NOISE_MIN_M * np.sqrt(len(union)))
            if spans_plane and min(angles_deg(plane[2], union_normal), angles_deg(-plane[2], union_normal)) > (
                POOL_NORMAL_DEG
            ):
                continue
            group.append(k)
            group_normals[g] = unit_rows(sum(normals[j] for j in group))
            residuals[g] = residual
            break
        else:
            groups.append([k])
            group_normals.append(normal)
            residuals.append(own)
    return groups
