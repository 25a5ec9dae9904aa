"""Compliant frame (CF) extraction (paper 4.1-4.2). The CF z axis points along the force the tool applies.

- slide: one CF per contact segment from all the evidence (`slide_frame`): the plane the path
  spans where it spans one (a pressed plane with a pad's sink), the friction-free force where it
  does not (a straight stroke lies in every plane that contains it) or where the two disagree
  beyond a hand's lean; z signed along the applied force; x = dominant motion direction.
- contour: one CF per sample; z = the normalized, smoothed applied force with its friction
  part (the component along the motion) removed, i.e. the surface normal; x, y from the
  Möller-Hughes minimal rotation that takes the segment's mean direction to z, applied to a
  reference frame, so the frames are unique and vary continuously.

Inputs are world-frame arrays (positions m, forces N applied by the tool); rotations are
world-from-CF matrices whose columns are the CF axes in world.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import correlate1d, distance_transform_edt, gaussian_filter1d

from schemas.skill import Segment
from skills.frames import rotation_from_vectors
from skills.friction import blended_friction_free, friction_coefficient, friction_free, unit_rows
from skills.quaternions import matrix_from_quaternion, quaternions_sign_continuous, quaternions_slerp
from skills.surface import pressed_surface
from skills.surface_geometry import DEPTH_NOISE_MIN_M, FORCE_SIGMA_MIN_DEG, FRICTION_CONE_DEG

PLANE_FORCE_TOLERANCE_DEG = 15.0
"""Largest angle (deg) between the plane a single path spans and the friction-free force for that plane to be the
surface, where the contact covers no area (a line, a circle, a curve: the plane is one candidate among many).

A hand leans across the motion by up to ~12° (real contour trials), friction is removed; beyond it the path was
drawn on something else (an edge's curve in its own plane), and the force decides. Where the contact covers an area
the plane IS the surface, and the force only bounds it, by the friction cone (`skills.surface_geometry`)."""

CONTOUR_FORCE_SMOOTHING_S = 0.1
"""Standard deviation of the zero-phase Gaussian smoothing of the force for contour frames, s.

It removes sensor noise and the 4-12 Hz jitter hand tremor puts into the friction direction
(attenuated to < 1 % at 5 Hz) while following turns of the surface normal slower than ~1 Hz.
"""

LINEAR_SUPPORT = 0.75
"""`weighted_smoothing` fits a line where the weighted support is at least this fraction of its median (else a mean)."""

MIN_DIRECTION_SAMPLES = 10
"""A segment's force normal is the mean of its per-sample friction-free directions when it has at least this many."""


class NormalSource(StrEnum):
    """What decided a slide segment's CF z (see `slide_frame`)."""

    plane = "plane"
    """The path spans a plane across its motion and the force agrees with it: the plane."""
    force = "force"
    """The path is (nearly) a line: the friction-free force decides the tilt about it."""
    force_over_plane = "force over plane"
    """The path spans a plane the force does not press on (beyond its limit, see `slide_frame`): the force."""


@dataclass(frozen=True)
class PlaneFit:
    """A slide CF and the evidence it came from (world frame, SI).

    ``rotation`` (3, 3) world-from-CF; ``origin`` (3,) m, the path's centroid; ``residual_rms_m``
    the path's RMS depth along CF z about the centroid; ``force_normal`` (3,) the mean friction-free
    force direction; ``across_width_m`` the RMS extent of the path across its main direction;
    ``equal_width_m`` the width at which the path's plane and the force are equally sure of that
    tilt;
    ``plane_force_angle_deg`` the angle between the plane the path spans and the force (None: the
    path is too narrow to span one) and ``plane_force_limit_deg`` how far it may be (the friction cone where the
    contact covers an area, else a hand's lean); ``force_sigma_deg`` the force direction's uncertainty it was
    weighed with; ``source`` what decided CF z; ``force_samples`` how many sliding
    samples gave the force normal (0: the mean force stood in for it).
    """

    rotation: NDArray[np.float64]
    origin: NDArray[np.float64]
    residual_rms_m: float
    force_normal: NDArray[np.float64]
    across_width_m: float
    equal_width_m: float
    plane_force_angle_deg: float | None
    plane_force_limit_deg: float
    force_sigma_deg: float
    source: NormalSource
    force_samples: int


def frame_from_z_and_x(z: NDArray[np.float64], x_hint: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the world-from-frame rotation with z axis ``z`` and x axis ``x_hint`` made orthogonal to z.

    Falls back to the Möller-Hughes rotation of world z onto ``z`` when ``x_hint`` is (nearly)
    parallel to ``z``.
    """
    z = z / np.linalg.norm(z)
    x = x_hint - np.dot(x_hint, z) * z
    if np.linalg.norm(x) < 1e-6:
        return rotation_from_vectors(np.array([0.0, 0.0, 1.0]), z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _force_normal(
    positions: NDArray[np.float64], forces: NDArray[np.float64], directions: NDArray[np.float64] | None
) -> tuple[NDArray[np.float64], int]:
    """Return the unit mean friction-free force direction of a segment (into the surface), and its sample count.

    From the per-sample ``directions`` (N, 3) where known (unit; zero where not), else (count 0)
    from the mean force with its component along the path's main direction removed (friction acts
    along it).
    """
    if directions is not None:
        known = np.linalg.norm(directions, axis=1) > 0.5
        if known.sum() >= MIN_DIRECTION_SAMPLES:
            return unit_rows(directions[known].mean(axis=0)), int(known.sum())
    mean_force = forces.mean(axis=0)
    motion = np.linalg.svd(positions - positions.mean(axis=0), full_matrices=False)[2][0]
    return unit_rows(mean_force - np.dot(mean_force, motion) * motion), 0


def slide_frame(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    directions: NDArray[np.float64] | None = None,
    *,
    force_sigma_deg: float = FORCE_SIGMA_MIN_DEG,
    area: bool = False,
) -> PlaneFit:
    """Return the slide CF of one contact segment from ALL the evidence of its surface: geometry and force.

    ``positions`` (N, 3) m, ``forces`` (N, 3) N applied, ``directions`` (N, 3) the friction-free force directions
    per sample (`skills.contact`, zero where unknown; None: from the mean force): a segment's own, or those of every
    contact segment on its surface, pooled (`skills.surface_evidence`; `plane_along` then gives each segment its
    own CF x and origin).

    A path lies in the surface it slides on, so the surface's tilt along a direction the path spans widely is
    known from the geometry; across a straight stroke it is not (a line lies in every plane that contains it),
    and there the friction-free force decides. So, in the basis (e1 along the path's main direction, e2 across
    it, both across the force normal), the pressed surface (`skills.surface`: plane plus a pad's sink with the
    press) gives the geometric tilt per axis, each weighted by ``width² / (width² + w0²)``, with ``w0`` the width
    at which geometry and force are equally sure (depth noise over the tangent of ``force_sigma_deg``, the force
    direction's uncertainty as measured against the geometry). Where the plane the path spans is farther from
    the force than it may be, the path was drawn on something else and the force decides alone: for a path that
    covers an AREA of its surface (``area``) the plane is the surface and the force only bounds it by the friction
    cone (`skills.surface_geometry.FRICTION_CONE_DEG`); for a single line or curve, by
    ``PLANE_FORCE_TOLERANCE_DEG``. z is signed along the applied force; x is the segment's main direction in the
    plane, pointing the way the tool travelled.
    """
    centroid = positions.mean(axis=0)
    centred = positions - centroid
    force_normal, force_samples = _force_normal(positions, forces, directions)
    across_force = centred - np.outer(centred @ force_normal, force_normal)
    e1 = np.linalg.svd(across_force, full_matrices=False)[2][0]
    basis = np.column_stack([e1, np.cross(force_normal, e1)])
    surface = pressed_surface(positions, forces @ force_normal, force_normal, basis=basis)
    widths = (centred @ basis).std(axis=0)
    equal_width = max(surface.residual_rms_m, DEPTH_NOISE_MIN_M) / np.tan(np.radians(force_sigma_deg))
    weights = widths**2 / (widths**2 + equal_width**2)
    plane_normal = unit_rows(force_normal - basis @ surface.slope)
    plane_force_angle = float(np.degrees(np.arccos(np.clip(plane_normal @ force_normal, -1.0, 1.0))))
    spans_plane = bool(widths[1] >= equal_width)
    tolerance = FRICTION_CONE_DEG if area else PLANE_FORCE_TOLERANCE_DEG
    if spans_plane and plane_force_angle > tolerance:
        normal, source = force_normal, NormalSource.force_over_plane
    else:
        normal = unit_rows(force_normal - basis @ (weights * surface.slope))
        source = NormalSource.plane if spans_plane else NormalSource.force
    if np.dot(normal, forces.mean(axis=0)) < 0:
        normal = -normal
    fit = PlaneFit(
        rotation=frame_from_z_and_x(normal, e1),
        origin=centroid,
        residual_rms_m=float(np.sqrt(np.mean((centred @ normal) ** 2))),
        force_normal=force_normal,
        across_width_m=float(widths[1]),
        equal_width_m=float(equal_width),
        plane_force_angle_deg=plane_force_angle if spans_plane else None,
        plane_force_limit_deg=tolerance,
        force_sigma_deg=force_sigma_deg,
        source=source,
        force_samples=force_samples,
    )
    return plane_along(fit, positions)


def plane_along(fit: PlaneFit, positions: NDArray[np.float64]) -> PlaneFit:
    """Return the slide CF ``fit`` with its x along the main direction of ``positions`` (M, 3) m in its plane,
    pointing the way they travelled, and its origin at their centroid (a segment on a pooled surface)."""
    normal = fit.rotation[:, 2]
    centroid = positions.mean(axis=0)
    centred = positions - centroid
    in_plane = centred - np.outer(centred @ normal, normal)
    motion = np.linalg.svd(in_plane, full_matrices=False)[2][0] if len(positions) > 1 else fit.rotation[:, 0]
    motion = motion if np.dot(motion, positions[-1] - positions[0]) >= 0 else -motion
    return replace(fit, rotation=frame_from_z_and_x(normal, motion), origin=centroid)


def tool_velocities(positions: NDArray[np.float64], rate_hz: float) -> NDArray[np.float64]:
    """Return tool-point velocities (N, 3) m/s of uniformly sampled ``positions`` (N, 3) m, smoothed over 20 ms."""
    smoothed = gaussian_filter1d(positions, sigma=max(1.0, 0.02 * rate_hz), axis=0, mode="nearest")
    return np.gradient(smoothed, 1.0 / rate_hz, axis=0)


def weighted_smoothing(
    values: NDArray[np.float64], weights: NDArray[np.float64], sigma_samples: float
) -> NDArray[np.float64]:
    """Return ``values`` (N, D) smoothed by a zero-phase Gaussian local-linear fit that counts each sample by its
    weight (N,).

    At each sample, the weighted least-squares line through its neighbours (Gaussian weights of
    ``sigma_samples`` times the samples' own) is evaluated there: samples of weight 0 take what their
    neighbours say instead of counting as zeros, and a value that changes steadily is followed without the
    lag a plain average has at the ends of a segment. Where the weighted support is thin (below
    ``LINEAR_SUPPORT`` of its median) the line fades into the weighted mean, which does not extrapolate; where
    no weighted sample lies within reach (support below 1e-3 of its largest value) a sample takes the value of
    the nearest one that has it.
    """
    radius = max(1, int(np.ceil(4.0 * sigma_samples)))
    offsets = np.arange(-radius, radius + 1, dtype=float)
    kernel = np.exp(-0.5 * (offsets / sigma_samples) ** 2)
    # correlate1d evaluates sum_j k[j] x[i + j - radius]: the kernels are indexed by offset j - radius.
    moments = [kernel * offsets**power for power in range(3)]

    def correlated(signal: NDArray[np.float64], k: int) -> NDArray[np.float64]:
        return correlate1d(signal, moments[k], axis=0, mode="constant")

    weighted = values * weights[:, None]
    s0, s1, s2 = (correlated(weights, k) for k in range(3))
    t0, t1 = correlated(weighted, 0), correlated(weighted, 1)
    constant = t0 / np.maximum(s0, 1e-12)[:, None]
    determinant = s0 * s2 - s1**2
    solvable = determinant > 1e-9 * np.maximum(s0 * s2, 1e-300)
    linear = (s2[:, None] * t0 - s1[:, None] * t1) / np.where(solvable, determinant, 1.0)[:, None]
    # The line is trusted where the weighted samples are dense around a sample (half the typical support: the
    # end of a segment the tool slid through); across a stretch of little weight (a tool settling before it
    # slides) it would extrapolate a noisy slope, and the weighted mean holds what the nearest samples say.
    typical = float(np.median(s0[s0 > 0])) if np.any(s0 > 0) else 1.0
    trust = np.where(solvable, np.clip(s0 / (LINEAR_SUPPORT * typical), 0.0, 1.0), 0.0)[:, None]
    smoothed = trust * linear + (1.0 - trust) * constant
    known = s0 > 1e-3 * max(float(s0.max()), 1e-12)
    if not known.any():
        return values.copy()
    if not known.all():
        nearest = distance_transform_edt(~known, return_distances=False, return_indices=True)[0]
        smoothed = smoothed[nearest]
    return smoothed


def contour_normals(
    forces: NDArray[np.float64],
    velocities: NDArray[np.float64],
    rate_hz: float,
    segment: slice,
    estimate: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Return the unit surface normals (M, 3) into the surface along the contour contact ``segment``.

    ``forces`` (N, 3) N and ``velocities`` (N, 3) m/s (`tool_velocities`) are the whole
    demonstration. Two passes of the
    friction-free force (`skills.friction`) smoothed over ``CONTOUR_FORCE_SMOOTHING_S``, counting
    each sample by how far its direction can be trusted (`weighted_smoothing`): the first turns the
    force back by the segment's friction angle, which needs no normal speed, so a tool settling onto
    the surface while it starts to slide turns nothing; the second, knowing the normal, removes all
    of the force along the velocity where the tool slides (friction, and whatever else drags along
    the motion) and keeps the first's turn where it settles (`blended_friction_free`). ``estimate`` (M, 3) unit:
    a better normal than the first pass's (the surface's geometry, `skills.surface_evidence`) to tell sliding
    from settling by: a force that errs along the motion would otherwise make the motion look like settling.
    """
    rows = np.zeros(len(forces), dtype=bool)
    rows[segment] = True
    sigma = CONTOUR_FORCE_SMOOTHING_S * rate_hz
    mu = friction_coefficient(forces, velocities, rows)
    if estimate is None:
        turned_back = friction_free(forces, velocities, mu)
        estimate = weighted_smoothing(turned_back.forces, turned_back.weights * rows, sigma)
    else:
        full = np.zeros_like(forces)
        full[segment] = estimate
        estimate = full
    blended = blended_friction_free(forces, velocities, mu, normals=estimate)
    return unit_rows(weighted_smoothing(blended.forces, blended.weights * rows, sigma)[segment])


def contour_frames(
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    rate_hz: float,
    segment: slice,
    velocities: NDArray[np.float64] | None = None,
    normals: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Return per-sample world-from-CF rotations (M, 3, 3) of the contour contact ``segment``.

    ``positions`` (N, 3) m, ``forces`` (N, 3) N and ``velocities`` (N, 3) m/s (default:
    `tool_velocities` of the positions) are the whole demonstration. z_k is ``normals`` (M, 3) (unit, into the
    surface: the segment's fused normals, `skills.surface_evidence`) where given, else the force's
    `contour_normals`. The reference frame has z along the segment's mean normal and x along the dominant motion;
    each sample's frame is that reference turned by the Möller-Hughes minimal rotation from the mean normal to z_k.
    """
    if normals is None:
        if velocities is None:
            velocities = tool_velocities(positions, rate_hz)
        normals = contour_normals(forces, velocities, rate_hz, segment)
    z = normals
    mean_direction = z.mean(axis=0)
    mean_direction /= np.linalg.norm(mean_direction)
    path = positions[segment]
    _, _, vt = np.linalg.svd(path - path.mean(axis=0), full_matrices=False)
    motion = vt[0] if np.dot(vt[0], path[-1] - path[0]) >= 0 else -vt[0]
    reference = frame_from_z_and_x(mean_direction, motion)
    return rotation_from_vectors(mean_direction, z) @ reference


def compliant_frame_rotations(segment: Segment, t_since_start: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return world-from-CF rotation matrices ``(M, 3, 3)`` of a contact segment at times since its start (s).

    One stored frame (slide) is constant; a series (contour) is slerped, clamped at its ends.
    """
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"segment {segment.index} ({segment.kind.value}) has no compliant frame")
    q = np.asarray(frames.orientations, dtype=float)
    if len(frames.t) == 1:
        return np.broadcast_to(matrix_from_quaternion(q[0]), (len(t_since_start), 3, 3)).copy()
    return matrix_from_quaternion(quaternions_slerp(t_since_start, frames.t, quaternions_sign_continuous(q)))
