"""A CAD object as PyBullet collision geometry: the solid along a convex crease of a triangle mesh (the KU Leuven
contour's L-profile ridge, `skills.registration.Crease`), cut into overlapping convex pieces
(``WorldConfig.work_pieces``), placed in the world.

The pieces. Stations every ``spacing_m`` along the crease, continued along its end tangents to the object's ends; at
each station the plane across the crease (normal: the crease's tangent there) cuts the triangles of the crease's two
faces (`skills.mesh_geometry.plane_section_segments`). Near the crease (within :data:`CREASE_BAND_M` on both faces)
a piece is the convex hull of the cuts at two stations ``layers`` stations apart, and a piece starts at every
station: every point of the crease lies in ``layers`` pieces, and the world makes each contact ``layers`` times
softer (``sim_worker.world``), so the object keeps the configured contact stiffness. The hull of a cut fills the
inside of the L (the tool rides the outside, from where the solid is the object). Beyond the band each face has its
own butted slabs (the tool does not reach there; they keep the object whole for the tool's shaft).

Why these sizes (measured; ``benchmarks/bench_kuleuven_cad.py`` reruns the convex ones). A ball pressed 15 N along
the bisector of a straight 90° ridge while sliding along it at 0.1 m/s (``hybrid_cf``, wrist sensor): true force RMS
0.81 % (max 4.4 %) on one exact convex prism; butted 5 mm pieces 27 %: every seam is a second touching body, the
force doubles there. Overlapping pieces soften the seams as they get more and shorter: 10 mm pieces 2.5 mm apart (4
layers) 3.1 %, 20 mm pieces 1.25 mm apart (16 layers) 1.3 %, 10 mm pieces 0.625 mm apart (16 layers) 1.25 %
(max 5.9 %). A concave triangle mesh (``GEOM_MESH`` with indices, static) is exact with two triangles a face (0.81 %)
but every triangle collides on its own: with 15 mm triangles, as the STL's, 13.6 % (9.4 % with
``GEOM_CONCAVE_INTERNAL_EDGE``). On the KU object itself (contour_a_1, CF x-y stiffness 6000 N/m): these pieces 3.0 %
(max 12.8 %), the STL as a concave mesh 12.2 % (max 105 %; 10.7 % with the internal-edge flag), V-HACD's 48 hulls
(``pybullet.vhacd``, resolution 10^6) 7.2 % (max 58 %). Short pieces also follow
the object: a hull spanning a length of the crease bridges the faces' twist and the STL's concave folds (a twisted
quad triangulated the concave way, up to 9° between its triangles), by up to 0.37 mm within 2 mm of the crease with
10 mm pieces and 0.77 mm with 20 mm ones.

Cost: every static body costs PyBullet time at every step; with the KU object's 1030 pieces a step of the world costs
about 0.6-1 ms against 30 µs for the table (measured on the shared 2-core machine), so its executions run at 0.3-0.5x
real time.

PyBullet's margin. PyBullet inflates a convex hull built from vertices by a collision margin of
:data:`CONVEX_MARGIN_M` (measured: a ball rests 1 mm above the hull's top, and touches a hull's edge 1 mm out along
the edge's bisector). Every piece is therefore built shrunk by it (its faces moved inward): inflated again, its faces
lie on the object's faces and its convex edges are rounded with a radius of the margin (the crease's corner lies
``CONVEX_MARGIN_M (1 / sin(θ/2) - 1)`` inside, 0.4 mm for the 90° crease).

Frames: the mesh and crease in the CAD frame (m); ``rotation``, ``translation`` map it into the world,
``x_world = R x_cad + t`` (a registration composed with a placement, docs/CONVENTIONS.md).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection

from schemas.world import WorkPiece, WorldConfig
from skills.mesh_geometry import plane_section_segments
from skills.registration import Crease, TriangleMesh, closest_points_on_polyline

CONVEX_MARGIN_M = 0.001
"""The collision margin PyBullet 3.2.7 puts around a convex hull shape built from vertices (``GEOM_MESH`` with
``vertices``), m (measured with ``getClosestPoints``)."""
CAD_STATION_SPACING_M = 0.000625
"""Distance between the cross-sections the pieces near the crease are built from, along the crease, m ..."""
CAD_LAYERS = 16
"""... and how many of them cover each point of the crease (a piece spans this many station intervals: 10 mm)."""
CREASE_BAND_M = 0.015
"""The pieces holding the crease reach this far from it on both faces (the ball tool touches within a few mm), m;
beyond it each face has its own pieces."""
MIN_PIECE_LENGTH_M = 0.003
"""The shortest piece near the crease, m: a piece must stay thicker than twice the margin (the end pieces)."""
FAR_SPACING_M = 0.01
"""Length of the pieces of the faces beyond the crease band, m."""
LEG_THICKNESS_M = 0.004
"""Thickness of the pieces of a face beyond the crease band, m (the KU Leuven object's sheet is 5 mm)."""
SIDE_FACE_DEG = 35.0
"""A triangle belongs to a face of the crease when its normal lies within this of the face's normal at the crease
(the faces twist and are faceted: 10-15° over 60 mm), deg."""
END_TOLERANCE_M = 5e-4
"""Mesh vertices within this distance of a crease's end tangent line continue the crease to the object's end, m."""
END_INSET_M = 5e-5
"""The first and last stations lie this far inside the object's ends, m (a plane on an end face cuts nothing)."""


def _extended_crease(mesh: TriangleMesh, crease: Crease) -> NDArray[np.float64]:
    """The crease's points (K + 3, 3), continued along its end tangents to the last mesh vertices on them (the mesh
    edge the crease continues along beyond the edge polyline it was found near)."""
    points = crease.points
    ends = []
    for end, inner in ((points[0], points[1]), (points[-1], points[-2])):
        outward = (end - inner) / np.linalg.norm(end - inner)
        offset = mesh.vertices - end
        along = offset @ outward
        off_line = np.linalg.norm(offset - along[:, None] * outward, axis=1)
        reach = float(along[off_line <= END_TOLERANCE_M].max(initial=0.0))
        ends.append(end + (max(reach, 0.0) - END_INSET_M) * outward)
    return np.vstack([ends[0], points, ends[1]])


def crease_stations(
    mesh: TriangleMesh, crease: Crease, spacing_m: float = CAD_STATION_SPACING_M
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points (S, 3) evenly spaced by at most ``spacing_m`` along the crease extended to the object's ends, and the
    crease's unit tangent (S, 3) there (the chord over one spacing either side: the polyline's kinks smoothed)."""
    line = _extended_crease(mesh, crease)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], math.ceil(arc[-1] / spacing_m) + 1)

    def at(arcs: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.column_stack([np.interp(np.clip(arcs, 0.0, arc[-1]), arc, line[:, j]) for j in range(3)])

    chord = at(s + spacing_m) - at(s - spacing_m)
    return at(s), chord / np.linalg.norm(chord, axis=1, keepdims=True)


def crease_side_faces(mesh: TriangleMesh, crease: Crease) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The mesh triangles (indices) of the crease's face a and face b: those whose outward normal lies within
    :data:`SIDE_FACE_DEG` of the face's normal at the nearest crease segment (the object's outer faces on either
    side; its inner faces, leg tips and ends face elsewhere)."""
    corners = mesh.vertices[mesh.faces]
    nearest = closest_points_on_polyline(corners.mean(axis=1), crease.points).segments
    alignment = np.einsum("ij,ikj->ik", mesh.outward_normals, crease.outward[nearest])
    side = alignment >= math.cos(math.radians(SIDE_FACE_DEG))
    return np.flatnonzero(side[:, 0] & ~side[:, 1]), np.flatnonzero(side[:, 1] & ~side[:, 0])


def _split_at_radius(
    segments: NDArray[np.float64], centre: NDArray[np.float64], radius: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """The parts of ``segments`` (S, 2, 3) inside and outside the sphere of ``radius`` about ``centre``, as their end
    points: inside (P, 3), outside (Q, 3) and the segment each outside point lies on (Q,)."""
    a, b = segments[:, 0] - centre, segments[:, 1] - centre
    d = b - a
    # The segment a + s d, s in [0, 1], meets the sphere where |a + s d| = radius.
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    ad = np.einsum("ij,ij->i", a, d)
    disc = ad**2 - dd * (np.einsum("ij,ij->i", a, a) - radius**2)
    root = np.sqrt(np.maximum(disc, 0.0))
    low = np.where(disc > 0.0, np.clip((-ad - root) / dd, 0.0, 1.0), 1.0)
    high = np.where(disc > 0.0, np.clip((-ad + root) / dd, 0.0, 1.0), 1.0)
    rows = np.arange(len(segments))
    has_inside, before, after = high > low, low > 0.0, high < 1.0
    inside = centre + np.vstack(
        [a[has_inside] + low[has_inside, None] * d[has_inside], a[has_inside] + high[has_inside, None] * d[has_inside]]
    )
    outside = centre + np.vstack(
        [a[before], a[before] + low[before, None] * d[before], a[after] + high[after, None] * d[after], b[after]]
    )
    index = np.concatenate([rows[before], rows[before], rows[after], rows[after]])
    return inside, outside, index


def margin_shrunk_hull(points: ArrayLike, margin_m: float = CONVEX_MARGIN_M) -> NDArray[np.float64]:
    """Vertices of the convex hull of ``points`` (K, 3) with every face moved ``margin_m`` inward: the piece whose
    PyBullet collision shape (inflated by the margin) is that hull, edges rounded. Raises ``ValueError`` when nothing
    is left."""
    points = np.asarray(points, dtype=float)
    hull = ConvexHull(points)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3] + margin_m
    # An interior point of the shrunk hull: the mean of the hull's vertices where it is one (nearly always, and 100x
    # cheaper), else the centre of the largest ball inside (Chebyshev centre, a linear program).
    centre = points[hull.vertices].mean(axis=0)
    if np.max(normals @ centre + offsets) >= 0.0:
        ball = linprog(
            np.r_[np.zeros(3), -1.0],
            A_ub=np.c_[normals, np.ones(len(normals))],
            b_ub=-offsets,
            bounds=[(None, None)] * 3 + [(0.0, None)],
        )
        if not ball.success or ball.x[3] <= 0.0:
            raise ValueError(f"a piece is thinner than twice the margin ({margin_m * 1e3:.1f} mm)")
        centre = ball.x[:3]
    vertices = HalfspaceIntersection(np.c_[normals, offsets], centre).intersections
    return np.unique(np.round(vertices, 9), axis=0)


@dataclass(frozen=True)
class _Section:
    """One station's cut through the crease's faces (mesh frame, m): ``near`` the points within the crease band (the
    crease point first), ``far`` the points of face a and of face b beyond it, ``far_inward`` their faces' inward
    normals."""

    near: NDArray[np.float64]
    far: tuple[NDArray[np.float64], NDArray[np.float64]]
    far_inward: tuple[NDArray[np.float64], NDArray[np.float64]]


def _sections(mesh: TriangleMesh, crease: Crease, spacing_m: float, band_m: float) -> list[_Section]:
    """The cut at every station of :func:`crease_stations`."""
    stations, tangents = crease_stations(mesh, crease, spacing_m)
    sides = crease_side_faces(mesh, crease)
    triangles = [mesh.vertices[mesh.faces[f]] for f in sides]
    inward = [-mesh.outward_normals[f] for f in sides]
    sections = []
    for point, tangent in zip(stations, tangents, strict=True):
        near, far, far_inward = [point[None]], [], []
        for corners, normals in zip(triangles, inward, strict=True):
            height = (corners - point) @ tangent
            cut = (height.min(axis=1) < 0.0) & (height.max(axis=1) >= 0.0)
            inside, outside, index = _split_at_radius(
                plane_section_segments(corners[cut], point, tangent), point, band_m
            )
            near.append(inside)
            far.append(outside)
            far_inward.append(normals[cut][index])
        sections.append(_Section(np.vstack(near), (far[0], far[1]), (far_inward[0], far_inward[1])))
    return sections


def crease_pieces(
    mesh: TriangleMesh,
    crease: Crease,
    spacing_m: float = CAD_STATION_SPACING_M,
    layers: int = CAD_LAYERS,
    band_m: float = CREASE_BAND_M,
    margin_m: float = CONVEX_MARGIN_M,
) -> tuple[tuple[NDArray[np.float64], int], ...]:
    """The convex pieces (vertices (K, 3) each, mesh frame, shrunk by ``margin_m``, see the module) of the solid
    along ``crease``, each with the number of pieces covering its points (built once per mesh, crease and sizes:
    a few seconds).

    Near the crease: the hull of both faces' cuts within ``band_m`` of the crease at stations ``max(j, 0)`` and
    ``min(j + layers, S - 1)``, so every interval between stations lies in ``layers`` pieces (within ``layers``
    stations of the object's ends fewer: no piece is shorter than :data:`MIN_PIECE_LENGTH_M`, or the margin would
    leave nothing of it). Beyond the band, each face: the hull of its cuts at stations :data:`FAR_SPACING_M` apart,
    :data:`LEG_THICKNESS_M` thick, butted (one layer)."""
    return _crease_pieces(mesh, crease, spacing_m, layers, band_m, margin_m)


@lru_cache(maxsize=4)
def _crease_pieces(
    mesh: TriangleMesh, crease: Crease, spacing_m: float, layers: int, band_m: float, margin_m: float
) -> tuple[tuple[NDArray[np.float64], int], ...]:
    if layers < 1:
        raise ValueError(f"layers must be at least 1, got {layers}")
    sections = _sections(mesh, crease, spacing_m, band_m)
    last = len(sections) - 1
    shortest = min(math.ceil(MIN_PIECE_LENGTH_M / spacing_m), layers, last)
    pieces = [
        (
            margin_shrunk_hull(np.vstack([sections[max(j, 0)].near, sections[min(j + layers, last)].near]), margin_m),
            layers,
        )
        for j in range(shortest - layers, last - shortest + 1)
    ]
    far_stations = np.unique(np.round(np.linspace(0, last, math.ceil(last * spacing_m / FAR_SPACING_M) + 1)))
    for first, second in itertools.pairwise(sections[int(k)] for k in far_stations):
        for side in (0, 1):
            outer = np.vstack([first.far[side], second.far[side]])
            if len(outer) >= 4:
                inward = np.vstack([first.far_inward[side], second.far_inward[side]])
                pieces.append((margin_shrunk_hull(np.vstack([outer, outer + LEG_THICKNESS_M * inward]), margin_m), 1))
    return tuple(pieces)


def cad_work_pieces(
    mesh: TriangleMesh,
    crease: Crease,
    rotation: ArrayLike,
    translation: ArrayLike,
    spacing_m: float = CAD_STATION_SPACING_M,
    layers: int = CAD_LAYERS,
) -> list[WorkPiece]:
    """The ``WorldConfig.work_pieces`` entries of the object along ``crease`` placed at ``x_world = R x_cad + t``
    (``rotation`` (3, 3), ``translation`` (3,) m): :func:`crease_pieces`."""
    R = np.asarray(rotation, dtype=float)
    t = np.asarray(translation, dtype=float)
    return [
        WorkPiece(name=f"cad_{k}", vertices=np.round(v @ R.T + t, 9).tolist(), layers=count)
        for k, (v, count) in enumerate(crease_pieces(mesh, crease, spacing_m, layers))
    ]


def cad_world_config(
    mesh: TriangleMesh,
    crease: Crease,
    rotation: ArrayLike,
    translation: ArrayLike,
    base: WorldConfig | None = None,
    spacing_m: float = CAD_STATION_SPACING_M,
    layers: int = CAD_LAYERS,
) -> WorldConfig:
    """``base`` (default: the default world) without its table, ramp, cylinder and block, holding the object along
    ``crease`` placed by ``rotation``, ``translation`` (:func:`cad_work_pieces`)."""
    base = base or WorldConfig()
    return base.with_only_work_pieces(cad_work_pieces(mesh, crease, rotation, translation, spacing_m, layers))
