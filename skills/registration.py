"""Ground truth of a contour from its CAD model: the object's edge registered to a contact path, and the normal cone
of the convex crease the tool rides on.

Frames: the CAD frame (the model's own axes, m) and the world frame of a recording (m). A registration is the rigid
transform world-from-CAD ``(R, p)``, ``x_world = R x_cad + p`` (docs/CONVENTIONS.md). A triangle mesh is wound
counter-clockwise seen from outside (STL), so ``(v1 - v0) × (v2 - v0)`` is its OUTWARD normal; "inward" is the
opposite, into the material: the direction a tool presses.

The normal cone. Where two faces with inward normals ``n_a``, ``n_b`` meet at a convex crease, any positive
combination ``α n_a + β n_b`` is a possible contact normal: a rigid tool resting on the crease can press along any of
them. Friction may add a component along the crease tangent ``t ∝ n_a × n_b``, which the cone leaves free; so a force
direction is judged by its component across the crease (in the plane spanned by ``n_a`` and ``n_b``), see
:func:`angles_about_crease` and :func:`angle_outside_cone`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skills.frames import matrix_from_axis_angle, skew

PARALLEL_NORMALS_SIN = 1e-6
"""Two normals whose cross product is shorter than this (sine of their angle) span no crease: no tangent."""
ALONG_CREASE_ONLY = 1e-9
"""A direction whose part across the crease is shorter than this fraction of it lies along the crease: angle 0."""


# --------------------------------------------------------------------------- meshes and polylines


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """An indexed triangle mesh: ``vertices`` (V, 3) in its frame's units, ``faces`` (T, 3) vertex indices, wound
    counter-clockwise seen from outside."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]

    @property
    def outward_normals(self) -> NDArray[np.float64]:
        """Outward unit normal of every face (T, 3), from the winding."""
        v = self.vertices[self.faces]
        normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        return normal / np.linalg.norm(normal, axis=1, keepdims=True)

    @property
    def signed_volume(self) -> float:
        """Enclosed volume (units³): positive when the faces are wound outward, negative when inward."""
        v = self.vertices[self.faces]
        return float(np.sum(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2]))) / 6.0)


def welded_mesh(triangles: ArrayLike) -> TriangleMesh:
    """The indexed mesh of a triangle soup (T, 3, 3) (an STL's triangles): corners with equal coordinates become one
    vertex, so neighbouring faces share their edges."""
    corners = np.asarray(triangles, dtype=float).reshape(-1, 3)
    vertices, index = np.unique(corners, axis=0, return_inverse=True)
    return TriangleMesh(vertices=vertices, faces=index.reshape(-1, 3).astype(np.int64))


@dataclass(frozen=True, eq=False)
class PolylineProjection:
    """Closest points of N query points on a polyline: ``points`` (N, 3) on the polyline, ``segments`` (N,) index k
    of the segment ``[polyline[k], polyline[k + 1]]`` they lie on, ``fractions`` (N,) where along it (0 at its start,
    1 at its end), ``distances`` (N,) from the query points (units of the inputs)."""

    points: NDArray[np.float64]
    segments: NDArray[np.int64]
    fractions: NDArray[np.float64]
    distances: NDArray[np.float64]


def closest_points_on_polyline(points: ArrayLike, polyline: ArrayLike) -> PolylineProjection:
    """Project ``points`` (N, 3) onto the polyline through ``polyline`` (K, 3), K ≥ 2 (same frame and units)."""
    q = np.asarray(points, dtype=float)
    line = np.asarray(polyline, dtype=float)
    start, step = line[:-1], np.diff(line, axis=0)
    length2 = np.maximum(np.einsum("ij,ij->i", step, step), 1e-300)
    along = np.clip(np.einsum("nkj,kj->nk", q[:, None, :] - start[None], step) / length2, 0.0, 1.0)
    nearest = start[None] + along[..., None] * step[None]
    distance2 = np.sum((q[:, None, :] - nearest) ** 2, axis=2)
    segment = np.argmin(distance2, axis=1)
    rows = np.arange(len(q))
    return PolylineProjection(
        nearest[rows, segment], segment.astype(np.int64), along[rows, segment], np.sqrt(distance2[rows, segment])
    )


def polyline_resampled(polyline: ArrayLike, spacing: float) -> NDArray[np.float64]:
    """Points (M, 3) evenly spaced by (at most) ``spacing`` along the polyline (K, 3), both ends included."""
    line = np.asarray(polyline, dtype=float)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], max(2, math.ceil(arc[-1] / spacing) + 1))
    return np.column_stack([np.interp(s, arc, line[:, j]) for j in range(3)])


# --------------------------------------------------------------------------- registration


def rigid_transform_between(source: ArrayLike, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The proper rigid transform ``(R, p)`` (det R = +1) that best maps ``source`` (N, 3) onto ``target`` (N, 3),
    ``target ≈ R source + p`` in least squares (Kabsch)."""
    a = np.asarray(source, dtype=float)
    b = np.asarray(target, dtype=float)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((b - cb).T @ (a - ca))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ d @ vt
    return R, cb - R @ ca


@dataclass(frozen=True, eq=False)
class Registration:
    """The CAD model placed in a recording's world: ``rotation`` (3, 3) and ``translation_m`` (3,) world-from-CAD,
    and the distances (m) of the contact path to the registered edge, RMS and largest."""

    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    rms_distance_m: float
    max_distance_m: float

    def to_cad(self, positions: ArrayLike) -> NDArray[np.float64]:
        """World positions (N, 3) m in the CAD frame (m)."""
        return (np.asarray(positions, dtype=float) - self.translation_m) @ self.rotation

    def to_world(self, positions: ArrayLike) -> NDArray[np.float64]:
        """CAD positions (N, 3) m in the world frame (m)."""
        return np.asarray(positions, dtype=float) @ self.rotation.T + self.translation_m


ICP_ITERATIONS = 200
"""Most iterations of ICP (point to polyline) from one start."""
ICP_TOLERANCE_M = 1e-8
"""ICP stops when the RMS distance changes by less than this (m) in one iteration."""
START_ANGLES = 12
"""Starts of the registration per side of the path's plane: turns of the edge about that plane's normal, evenly
spaced over a full turn (the principal axes' own two flips are among them)."""
START_SAMPLES = 300
"""Path samples (evenly picked) ICP uses from each start; the distinct results are refined on every sample."""
EVEN_EDGE_POINTS = 1000
"""The edge's principal axes are those of this many points evenly spaced along it (not of its own vertices)."""
SAME_POSE_RAD = math.radians(1.0)
SAME_POSE_M = 0.001
"""Two registrations closer than this in rotation (rad) and translation (m) are the same local optimum."""


def _principal_axes(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centroid (3,) and principal axes (3, 3) (columns, largest spread first, right-handed) of ``points`` (N, 3)."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    axes = vt.T
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return centroid, axes


def _closest_on_placed_edge(
    path: NDArray[np.float64], edge: NDArray[np.float64], R: NDArray[np.float64], p: NDArray[np.float64]
) -> PolylineProjection:
    """The path's (world) closest points on the edge placed by world-from-CAD ``(R, p)``, in the CAD frame."""
    return closest_points_on_polyline((path - p) @ R, edge)


def _gauss_newton_step(
    path: NDArray[np.float64],
    edge: NDArray[np.float64],
    R: NDArray[np.float64],
    p: NDArray[np.float64],
    closest: PolylineProjection,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One Gauss-Newton step of the squared distances of the path to the placed edge: each residual is the path
    sample's offset from its closest edge point without the part along that point's segment (it slides along the
    edge for free), or all of it where the closest point is a segment's end. The small motion ``(v, ω)`` moves the
    placed edge about its centroid in the world."""
    points = closest.points @ R.T + p
    centre = points.mean(axis=0)
    tangent = np.diff(edge, axis=0)[closest.segments] @ R.T
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    interior = (closest.fractions > 0.0) & (closest.fractions < 1.0)
    projector = np.eye(3) - interior[:, None, None] * tangent[:, :, None] * tangent[:, None, :]
    jacobian = np.concatenate([np.broadcast_to(np.eye(3), (len(path), 3, 3)), -skew(points - centre)], axis=2)
    weighted = projector @ jacobian
    normal = np.einsum("nji,njk->ik", jacobian, weighted)
    rhs = np.einsum("nji,nj->i", weighted, path - points)
    motion = np.linalg.lstsq(normal, rhs, rcond=None)[0]
    turn = matrix_from_axis_angle(motion[3:], float(np.linalg.norm(motion[3:]))) if np.any(motion[3:]) else np.eye(3)
    return turn @ R, turn @ (p - centre) + centre + motion[:3]


def _icp(
    path: NDArray[np.float64], edge: NDArray[np.float64], R: NDArray[np.float64], p: NDArray[np.float64]
) -> Registration:
    """Minimize the RMS distance of the path (world) to the edge polyline (CAD) placed by world-from-CAD ``(R, p)``,
    from that start: closest points, then a Gauss-Newton step point to line (:func:`_gauss_newton_step`), or the
    rigid fit of the closest points onto the path (point to point, Kabsch) where that step would not reduce the RMS,
    until the RMS settles."""
    closest = _closest_on_placed_edge(path, edge, R, p)
    rms = float(np.sqrt(np.mean(closest.distances**2)))
    for _ in range(ICP_ITERATIONS):
        R_next, p_next = _gauss_newton_step(path, edge, R, p, closest)
        moved = _closest_on_placed_edge(path, edge, R_next, p_next)
        if np.sqrt(np.mean(moved.distances**2)) >= rms:
            R_next, p_next = rigid_transform_between(closest.points, path)
            moved = _closest_on_placed_edge(path, edge, R_next, p_next)
        previous, rms_next = rms, float(np.sqrt(np.mean(moved.distances**2)))
        if rms_next > previous:
            break
        R, p, closest, rms = R_next, p_next, moved, rms_next
        if previous - rms < ICP_TOLERANCE_M:
            break
    return Registration(R, p, rms, float(closest.distances.max()))


def _same_pose(a: Registration, b: Registration) -> bool:
    cos_angle = np.clip((np.trace(a.rotation.T @ b.rotation) - 1.0) / 2.0, -1.0, 1.0)
    moved = np.linalg.norm(a.translation_m - b.translation_m)
    return bool(math.acos(cos_angle) < SAME_POSE_RAD and moved < SAME_POSE_M)


def edge_registrations(path: ArrayLike, edge: ArrayLike) -> list[Registration]:
    """Every distinct rigid placement of the ``edge`` polyline (K, 3) m, CAD frame, that ICP finds on the contact
    ``path`` (N, 3) m, world frame; best (smallest RMS distance of the path to the placed edge) first.

    Starts: the edge's principal axes turned onto the path's, with the edge's plane normal along either side of the
    path's plane and :data:`START_ANGLES` turns about it (centroids matched); from each, ICP point to polyline on
    :data:`START_SAMPLES` path samples, then the distinct optima refined on the whole path. A planar edge with a
    mirror symmetry in its plane (the KU Leuven contour's) fits a path equally well turned half a turn about its
    symmetry axis: the shape alone cannot tell those two apart, the caller must (:func:`registration_pressed_into`).
    """
    path = np.asarray(path, dtype=float)
    edge = np.asarray(edge, dtype=float)
    edge = edge[np.concatenate([[True], np.any(np.diff(edge, axis=0) != 0.0, axis=1)])]  # no zero-length segment
    length = float(np.linalg.norm(np.diff(edge, axis=0), axis=1).sum())
    even_edge = polyline_resampled(edge, length / EVEN_EDGE_POINTS)
    edge_centroid, edge_axes = _principal_axes(even_edge)
    path_centroid, path_axes = _principal_axes(path)
    sparse = path[np.linspace(0, len(path) - 1, min(len(path), START_SAMPLES)).astype(int)]
    found: list[Registration] = []
    for side in (np.eye(3), np.diag([1.0, -1.0, -1.0])):
        for k in range(START_ANGLES):
            turn = matrix_from_axis_angle(path_axes[:, 2], 2.0 * math.pi * k / START_ANGLES)
            R = turn @ path_axes @ side @ edge_axes.T
            local = _icp(sparse, edge, R, path_centroid - R @ edge_centroid)
            if not any(_same_pose(local, other) for other in found):
                found.append(local)
    refined: list[Registration] = []
    for local in found:
        result = _icp(path, edge, local.rotation, local.translation_m)
        if not any(_same_pose(result, other) for other in refined):
            refined.append(result)
    return sorted(refined, key=lambda r: r.rms_distance_m)


# --------------------------------------------------------------------------- the crease and its normal cone


CREASE_DISTANCE = 0.003
"""Default for :func:`crease_along_edge`: a mesh edge belongs to the crease when both its ends lie within this
distance (m) of the edge polyline."""
CREASE_MIN_OPENING_RAD = math.radians(30.0)
"""Default for :func:`crease_along_edge`: a crease's faces' normals differ by at least this (rad); smaller turns
are the facets of a curved surface."""


@dataclass(frozen=True, eq=False)
class Crease:
    """A convex crease of a triangle mesh, as a chain of mesh edges, in the mesh's frame.

    ``points`` (K + 1, 3): the chain's vertices in order along the edge polyline it was found along; segment k joins
    ``points[k]`` and ``points[k + 1]``. ``faces`` (K, 2): the mesh triangles on either side of segment k, ordered so
    that ``outward[k, 0] × outward[k, 1]`` points along the segment; ``outward`` (K, 2, 3): their outward unit
    normals. Face 0 is "face a", face 1 "face b" all along the chain.
    """

    points: NDArray[np.float64]
    faces: NDArray[np.int64]
    outward: NDArray[np.float64]

    @property
    def openings_rad(self) -> NDArray[np.float64]:
        """Angle between the two faces' normals along each segment (K,), rad: the opening of the normal cone (π minus
        the angle between the faces inside the material)."""
        return np.arccos(np.clip(np.sum(self.outward[:, 0] * self.outward[:, 1], axis=1), -1.0, 1.0))


def crease_along_edge(
    mesh: TriangleMesh,
    edge: ArrayLike,
    max_distance: float = CREASE_DISTANCE,
    min_opening_rad: float = CREASE_MIN_OPENING_RAD,
) -> Crease:
    """The convex crease of ``mesh`` that follows the polyline ``edge`` (K, 3) (mesh frame and units; the default
    ``max_distance`` is for a mesh in m).

    Its segments are the mesh edges with both ends within ``max_distance`` of ``edge`` whose two faces' normals
    differ by at least ``min_opening_rad`` and meet convexly (each face's far corner lies behind the other face's
    plane). Raises ``ValueError`` when the mesh is wound inward, when a mesh edge near ``edge`` does not have exactly
    two faces (not a manifold there), or when the segments do not join into one chain along ``edge``.
    """
    if mesh.signed_volume <= 0.0:
        raise ValueError("the mesh's faces are wound inward (negative volume): outward normals would point inside")
    line = np.asarray(edge, dtype=float)
    near = closest_points_on_polyline(mesh.vertices, line).distances <= max_distance
    corners = mesh.faces
    # Every directed edge (i -> j) of every face, with the face and its corner opposite the edge.
    start = corners.reshape(-1)
    end = np.roll(corners, -1, axis=1).reshape(-1)
    opposite = np.roll(corners, -2, axis=1).reshape(-1)
    face = np.repeat(np.arange(len(corners)), 3)
    candidate = near[start] & near[end]
    key = np.sort(np.column_stack([start, end])[candidate], axis=1)
    edges, inverse, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    if np.any(count != 2):
        bad = edges[count != 2][0]
        raise ValueError(f"mesh edge between vertices {bad[0]} and {bad[1]} has {count[count != 2][0]} faces, not 2")
    order = np.argsort(inverse.reshape(-1), kind="stable")
    pair_faces = face[candidate][order].reshape(-1, 2)
    pair_opposite = opposite[candidate][order].reshape(-1, 2)
    normals = mesh.outward_normals[pair_faces]
    opening = np.arccos(np.clip(np.sum(normals[:, 0] * normals[:, 1], axis=1), -1.0, 1.0))
    a = mesh.vertices[edges[:, 0]]
    behind_0 = np.sum((mesh.vertices[pair_opposite[:, 1]] - a) * normals[:, 0], axis=1) < 0.0
    behind_1 = np.sum((mesh.vertices[pair_opposite[:, 0]] - a) * normals[:, 1], axis=1) < 0.0
    keep = (opening >= min_opening_rad) & behind_0 & behind_1
    edges, pair_faces, normals = edges[keep], pair_faces[keep], normals[keep]
    if len(edges) == 0:
        raise ValueError(f"no convex crease of at least {math.degrees(min_opening_rad):.0f} deg along the edge")
    # Order the segments along the edge polyline and orient each one along it.
    arc = _arc_positions(mesh.vertices[edges], line)
    forward = arc[:, 1] >= arc[:, 0]
    edges = np.where(forward[:, None], edges, edges[:, ::-1])
    sequence = np.argsort(arc.mean(axis=1))
    edges, pair_faces, normals = edges[sequence], pair_faces[sequence], normals[sequence]
    gaps = np.flatnonzero(edges[1:, 0] != edges[:-1, 1])
    if gaps.size:
        k = gaps[0]
        raise ValueError(f"the crease breaks between vertices {edges[k, 1]} and {edges[k + 1, 0]}: not one chain")
    points = mesh.vertices[np.append(edges[:, 0], edges[-1, 1])]
    direction = np.diff(points, axis=0)
    swap = np.sum(np.cross(normals[:, 0], normals[:, 1]) * direction, axis=1) < 0.0
    pair_faces = np.where(swap[:, None], pair_faces[:, ::-1], pair_faces)
    normals = np.where(swap[:, None, None], normals[:, ::-1], normals)
    return Crease(points=points, faces=pair_faces, outward=normals)


def _arc_positions(points: NDArray[np.float64], polyline: NDArray[np.float64]) -> NDArray[np.float64]:
    """Arc length along ``polyline`` (K, 3) of the closest point of each of ``points`` (..., 3), same shape (...)."""
    flat = points.reshape(-1, 3)
    closest = closest_points_on_polyline(flat, polyline)
    step = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(step)])[closest.segments] + closest.fractions * step[closest.segments]
    return arc.reshape(points.shape[:-1])


@dataclass(frozen=True, eq=False)
class NormalCone:
    """The normal cone of the crease nearest each of M positions, world frame.

    ``inward_a``, ``inward_b`` (M, 3): inward unit normals (into the material, the way a tool presses) of the crease's
    face a and face b (:class:`Crease`); ``faces`` (M, 2): those faces' mesh triangle indices; ``crease_points`` (M, 3)
    m: the nearest point of the crease; ``distances_m`` (M,): the positions' distance from it.
    """

    inward_a: NDArray[np.float64]
    inward_b: NDArray[np.float64]
    faces: NDArray[np.int64]
    crease_points: NDArray[np.float64]
    distances_m: NDArray[np.float64]

    @property
    def bisectors(self) -> NDArray[np.float64]:
        """Unit bisectors of the cone (M, 3), world: the direction halfway between the two faces' inward normals."""
        return cone_bisectors(self.inward_a, self.inward_b)

    @property
    def openings_rad(self) -> NDArray[np.float64]:
        """Opening of the cone (M,), rad: the angle between ``inward_a`` and ``inward_b``."""
        return np.arccos(np.clip(np.sum(self.inward_a * self.inward_b, axis=1), -1.0, 1.0))


def normal_cones_at(positions: ArrayLike, crease: Crease, registration: Registration) -> NormalCone:
    """The normal cone of the registered ``crease`` (CAD frame, m) nearest each of ``positions`` (M, 3) m, world
    frame: the two faces of the crease segment closest to the position, their normals turned into the world."""
    closest = closest_points_on_polyline(registration.to_cad(positions), crease.points)
    inward = -crease.outward[closest.segments] @ registration.rotation.T
    return NormalCone(
        inward_a=inward[:, 0],
        inward_b=inward[:, 1],
        faces=crease.faces[closest.segments],
        crease_points=registration.to_world(closest.points),
        distances_m=closest.distances,
    )


SHAPE_TIE_M = 0.002
"""Placements whose RMS distance to the path exceeds the best one's by less than this (m) fit it equally well as far
as the shape can tell: a tracker's noise, the tool's wobble on the crease and the part's tolerance are ~1 mm each."""


def bisector_angles_of_placements(
    candidates: Sequence[Registration], crease: Crease, positions: ArrayLike, forces: ArrayLike
) -> NDArray[np.float64]:
    """For each candidate placement (C,), the median angle (rad) between the applied ``forces`` (N, 3) N, world
    frame, at ``positions`` (N, 3) m and the bisector of the normal cone that placement puts there."""
    force = np.asarray(forces, dtype=float)
    unit = force / np.maximum(np.linalg.norm(force, axis=1, keepdims=True), 1e-12)
    return np.array(
        [
            np.median(np.arccos(np.clip(np.sum(unit * normal_cones_at(positions, crease, r).bisectors, 1), -1, 1)))
            for r in candidates
        ]
    )


def registration_pressed_into(
    candidates: Sequence[Registration],
    crease: Crease,
    positions: ArrayLike,
    forces: ArrayLike,
    tie_m: float = SHAPE_TIE_M,
) -> Registration:
    """The placement, among ``candidates`` (:func:`edge_registrations`, best fit first) that fit the path within
    ``tie_m`` (m) of the best, whose crease the applied ``forces`` (N, 3) N, world frame, press into: the smallest
    median angle between force and cone bisector at ``positions`` (N, 3) m (:func:`bisector_angles_of_placements`).

    A tool presses into the material, so the force tells apart placements the edge's shape cannot (a symmetric edge
    half a turn about its symmetry axis puts the material on the other side). It is one binary choice between poses
    whose cones lie far apart; it does not fit the cone to the force.
    """
    tied = [r for r in candidates if r.rms_distance_m < candidates[0].rms_distance_m + tie_m]
    return tied[int(np.argmin(bisector_angles_of_placements(tied, crease, positions, forces)))]


# --------------------------------------------------------------------------- directions against the cone


def cone_bisectors(n_a: ArrayLike, n_b: ArrayLike) -> NDArray[np.float64]:
    """Unit bisectors (M, 3) of the cones spanned by the unit normals ``n_a``, ``n_b`` (M, 3), any frame."""
    total = np.asarray(n_a, dtype=float) + np.asarray(n_b, dtype=float)
    return total / np.linalg.norm(total, axis=-1, keepdims=True)


def angles_about_crease(directions: ArrayLike, n_a: ArrayLike, n_b: ArrayLike) -> NDArray[np.float64]:
    """Signed angle (M,), rad, of each direction across the crease: measured about the crease tangent
    ``t = n_a × n_b / |n_a × n_b|`` from ``n_a``, positive towards ``n_b`` (so ``n_b`` is at the cone's opening
    angle, the bisector at half of it), in (-π, π].

    ``directions`` (M, 3) (any norm) and the unit normals ``n_a``, ``n_b`` (M, 3) share one frame. Only the
    direction's component across the crease counts (its component along ``t`` is removed first: friction along
    the crease); a direction along ``t`` itself has no angle across and gives 0. Raises ``ValueError`` where
    ``n_a`` and ``n_b`` are parallel (no crease).
    """
    d = np.asarray(directions, dtype=float)
    a = np.asarray(n_a, dtype=float)
    axis = np.cross(a, np.asarray(n_b, dtype=float))
    length = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(length < PARALLEL_NORMALS_SIN):
        raise ValueError("n_a and n_b are parallel at some sample: no crease, no tangent to measure about")
    t = axis / length
    across = d - np.sum(d * t, axis=-1, keepdims=True) * t
    none_across = np.linalg.norm(across, axis=-1) <= ALONG_CREASE_ONLY * np.linalg.norm(d, axis=-1)
    angle = np.arctan2(np.sum(np.cross(a, across) * t, axis=-1), np.sum(a * across, axis=-1))
    return np.where(none_across, 0.0, angle)


def angle_outside_cone(directions: ArrayLike, n_a: ArrayLike, n_b: ArrayLike) -> NDArray[np.float64]:
    """Angle (M,), rad, by which each direction lies outside the normal cone spanned by ``n_a`` and ``n_b``: 0 when
    it is a positive combination of them plus any component along the crease tangent, else the angle to the
    nearer of the two.

    Measured across the crease, after the component along the tangent ``t ∝ n_a × n_b`` is removed
    (:func:`angles_about_crease`): a force along the crease is friction, which the cone leaves free, and so the
    angle depends only on the direction of the force's part across the crease, not on how much friction comes with
    it (the full 3-D angle to the set would shrink as friction grows, to 0 for a pure pull off the edge with enough
    friction). Inputs (M, 3) in one frame, directions of any norm, normals unit.
    """
    phi = angles_about_crease(directions, n_a, n_b)
    opening = np.arccos(np.clip(np.sum(np.asarray(n_a, dtype=float) * np.asarray(n_b, dtype=float), axis=-1), -1, 1))
    to_a = np.abs(phi)
    to_b = np.abs(np.mod(phi - opening + math.pi, 2.0 * math.pi) - math.pi)
    return np.where((phi >= 0.0) & (phi <= opening), 0.0, np.minimum(to_a, to_b))
