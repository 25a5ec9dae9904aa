"""Geometry of a closed triangle mesh (`skills.registration.TriangleMesh`, wound outward): its cross-section by a
plane, and the closest point of its surface to given points.

Everything is in the mesh's frame and units (a registered CAD model: m, its own frame, or turned into the world
first); normals are unit and outward.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from skills.registration import TriangleMesh


def plane_section_segments(triangles: ArrayLike, origin: ArrayLike, normal: ArrayLike) -> NDArray[np.float64]:
    """The segments (S, 2, 3) where the plane through ``origin`` (3,) with ``normal`` (3,) cuts ``triangles``
    (T, 3, 3): one per triangle with corners on both sides of it (a corner on the plane counts as in front: a
    triangle touching the plane at a corner or an edge only gives no segment)."""
    corners = np.asarray(triangles, dtype=float)
    height = (corners - np.asarray(origin, dtype=float)) @ np.asarray(normal, dtype=float)
    behind = height < 0.0
    cut = behind.any(axis=1) & ~behind.all(axis=1)
    corners, height, behind = corners[cut], height[cut], behind[cut]
    # The lone corner (the one on its own side) and the two edges from it that cross the plane.
    lone = np.argmax(behind != (behind.sum(axis=1, keepdims=True) == 2), axis=1)
    rows = np.arange(len(corners))
    ends = []
    for step in (1, 2):
        other = (lone + step) % 3
        fraction = height[rows, lone] / (height[rows, lone] - height[rows, other])
        ends.append(corners[rows, lone] + fraction[:, None] * (corners[rows, other] - corners[rows, lone]))
    return np.stack(ends, axis=1)


@dataclass(frozen=True, eq=False)
class MeshProjection:
    """Closest points of N query points on a mesh's surface: ``points`` (N, 3), the ``faces`` (N,) they lie on,
    their ``distances`` (N,) from the query points (mesh units) and the ``normals`` (N, 3) of those faces
    (outward)."""

    points: NDArray[np.float64]
    faces: NDArray[np.int64]
    distances: NDArray[np.float64]
    normals: NDArray[np.float64]


def _closest_on_segments(p: NDArray, a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """Closest points (M, 3) of ``p`` on the segments ``a``-``b`` (M, 3 each)."""
    step = b - a
    along = np.einsum("ij,ij->i", p - a, step) / np.maximum(np.einsum("ij,ij->i", step, step), 1e-300)
    return a + np.clip(along, 0.0, 1.0)[:, None] * step


def _closest_on_triangles(p: NDArray, corners: NDArray, normals: NDArray) -> NDArray[np.float64]:
    """Closest points (M, 3) of ``p`` (M, 3) on the triangles ``corners`` (M, 3, 3) with unit ``normals`` (M, 3):
    the projection onto the plane where it falls inside, else the nearest point of the three edges."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    projected = p - np.einsum("ij,ij->i", p - a, normals)[:, None] * normals
    inside = np.ones(len(p), dtype=bool)
    for start, end in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(end - start, projected - start), normals) >= 0.0
    on_edges = np.stack([_closest_on_segments(p, s, e) for s, e in ((a, b), (b, c), (c, a))], axis=1)
    nearest_edge = np.argmin(np.sum((on_edges - p[:, None]) ** 2, axis=2), axis=1)
    return np.where(inside[:, None], projected, on_edges[np.arange(len(p)), nearest_edge])


def closest_points_on_mesh(points: ArrayLike, mesh: TriangleMesh) -> MeshProjection:
    """The closest point of the surface of ``mesh`` to each of ``points`` (N, 3) (same frame and units).

    Exact: the nearest vertex bounds the distance from above, and every triangle whose bounding sphere (about its
    centroid) comes that close is tested (a k-d tree finds them), so no nearer triangle is missed.
    """
    q = np.asarray(points, dtype=float).reshape(-1, 3)
    corners = mesh.vertices[mesh.faces]
    centroids = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroids[:, None], axis=2).max(axis=1)
    bound = cKDTree(mesh.vertices).query(q)[0]
    near = cKDTree(centroids).query_ball_point(q, bound + radius.max())
    rows = np.repeat(np.arange(len(q)), [len(n) for n in near])
    faces = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
    keep = np.linalg.norm(centroids[faces] - q[rows], axis=1) - radius[faces] <= bound[rows]
    rows, faces = rows[keep], faces[keep]
    normals = mesh.outward_normals
    closest = _closest_on_triangles(q[rows], corners[faces], normals[faces])
    distance = np.linalg.norm(closest - q[rows], axis=1)
    order = np.lexsort((distance, rows))  # per query point, nearest first
    first = order[np.concatenate([[True], rows[order][1:] != rows[order][:-1]])]
    return MeshProjection(
        points=closest[first], faces=faces[first], distances=distance[first], normals=normals[faces[first]]
    )
