"""The work piece of a skill whose recording carries no simulated world: MEASURED from its demonstration when that is
given, else REBUILT from what the skill learned. Both are convex solids (``WorldConfig.work_pieces``: PyBullet
collides convex shapes), world frame, m; CF z and normals point into the surface (docs/CONVENTIONS.md); friction and
contact stiffness are the world's. The contact point is where the SIMULATED ball tool touches when its tool point
(the tip of the ball along the tool z axis) is at ``p``: ball centre ``p - r z_tool``, contact ``centre + r n``.

Measured (``measured_work_pieces``)
-----------------------------------
From what the demonstration measured, whatever type of skill was learned from it: per pass (a stroke's stretch of
contact), the surface at rest under the contact point and the friction-free force's direction ``n``
(`skills.measured_surface`), over the samples pressing at least ``FIRM_PRESS_FRACTION`` of the pass's median press
(at a touch-down or a lift-off a hand's push outweighs the press and turns the force anywhere). One smooth surface
per pass, no seams:

- a **plane** where the plane the pass's points span (`skills.compliant_frames.slide_frame`: the path's geometry
  where it spans a plane, the force across a straight stroke) holds them within ``PLANE_DEPTH_M``, a pad's sink
  with the press allowed (`skills.surface`), and the measured normals lean from it by a median of at most
  ``PLANE_NORMAL_DEG`` (a hand's lean; a curved surface turns its normal along the path even where the path is drawn
  in one plane, as round a rim): ONE slab, its top the plane at the pass's median press, the path's extent plus
  ``WORK_PIECE_MARGIN_M``: the table itself;
- otherwise a **curved strip**: cross-sections every ``HULL_SECTION_M`` of path (points and normals smoothed over
  ``HULL_SMOOTHING_M``), up to ``HULL_HALF_WIDTHS_M`` to each side of the path and ``WORK_PIECE_THICKNESS_M`` deep
  along the normal, extended ``WORK_PIECE_MARGIN_M`` past both ends along the end tangents (narrower, and without
  the ends' margins, where they would cover the path: a rim's turns), and their ONE convex hull.
  Bullet collides a convex hull as a whole: the ball's depth in it is continuous as it rolls over an edge between
  facets, so there is no seam. It is right wherever the surface is convex from the tool's side (a cylinder, a
  sphere, a rim, an edge of the corpus): the path then lies on the hull. Where the hull buries the path deeper than
  ``CONVEX_TOLERANCE_M`` (a hollow; a saddle, as the twisted crease of the KU Leuven recordings, whose measured
  normal leans about within the crease's normal cone), the pass is split at its deepest buried section, each part
  its own hull: seams, where one smooth convex piece would not be what was measured.

Passes whose contact points lie on or in another pass's piece (within ``OVERLAP_TOLERANCE_M``) touch the same
surface and are measured together: no two pieces stack on one surface.

Measured (``benchmarks/bench_work_piece.py``, docs/LEARNING.md section 10): on flat strokes the slab adds at most
0.02 % RMS to the ideal table's true-force error; on contours across cylinders the hull adds 0.4-0.7 % RMS against
the simulator's own cylinder (its facets; a hull of the exact cylinder's points adds 0.6-1.3 %), where overlapping
pieces add 1.8-6.4 % (2-8 layers) and a PyBullet heightfield 12-21 %.

Rebuilt from the learned skill (``rebuilt_work_pieces``, no demonstration given)
--------------------------------------------------------------------------------
A skill holds what it touched:

- a **slide** segment: its plane (the CF). The rebuilt part is a slab under it, ``WORK_PIECE_THICKNESS_M``
  thick, bounded by the path's extent in the CF x-y plane plus ``WORK_PIECE_MARGIN_M``. Where two slide
  segments meet at a CONVEX crease (each path lies inside the other's half-space) each slab is cut by the other
  plane, so neither sticks out past the crease; at a concave crease the union of the slabs is already right.
- a **contour** segment: its contact path with the per-sample CF z (the friction-free force direction, i.e. the
  surface normal). The rebuilt part is a strip ``2 STRIP_HALF_WIDTH_M`` wide through the contact points, its
  normal following the learned one, cut every ``STRIP_PIECE_LENGTH_M`` of path into convex pieces and extended
  ``WORK_PIECE_MARGIN_M`` past both ends. Each piece reaches halfway into both neighbours, so every point of the
  strip lies in exactly two pieces (``layers=2``).

Why two layers: PyBullet's compliant contact is one spring per touching body. With pieces butted or slightly
overlapped the tool meets one piece here and two near a seam, the stiffness doubling and halving every few
centimetres, and the force spikes at every seam (the KU Leuven strips: true force max error 40-77 %, RMS 4.8-8.2 %).
Two layers everywhere, each piece's contact made half as stiff (``sim_worker.world``: in series with the tool's),
give the configured stiffness all along, and the surface felt is the mean of two neighbouring facets: smoother than
either. A single concave triangle mesh was tried and is worse (the flat table as a mesh of 2 or 800 triangles:
2.6 % and 7.2 % RMS against 1.4 % for the box; Bullet collides each triangle on its own). The seams still cost: on
flat strokes learned as contours the strip adds 2-15 % RMS to the ideal table's error.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import Demonstration
from schemas.skill import Segment, SegmentKind, Skill
from schemas.world import WorkPiece, WorldConfig
from skills.compliant_frames import compliant_frame_rotations, slide_frame
from skills.measured_surface import MeasuredPass, measured_passes
from skills.placement import segment_positions
from skills.quaternion_dmp import QuaternionDMP
from skills.quaternions import matrix_from_quaternion
from skills.surface import pressed_surface

WORK_PIECE_MARGIN_M = 0.05
"""How far a rebuilt part extends beyond the learned path, m."""
WORK_PIECE_THICKNESS_M = 0.04
"""Thickness of a rebuilt part below its surface, m."""
STRIP_HALF_WIDTH_M = 0.03
"""Half width of a rebuilt contour strip across the path, m."""
STRIP_PIECE_LENGTH_M = 0.03
"""Longest path length of one convex piece of a contour strip, m ..."""
STRIP_PIECE_TURN_DEG = 2.0
"""... and the most its normal turns over one piece, deg (facets follow the learned normal within half of it)."""
STRIP_LAYERS = 2
"""How many pieces cover each point of a contour strip (each reaches halfway into both neighbours)."""
PIECE_ROLLOUT_STEP_S = 0.005
"""Time step of the rollouts the surfaces are built from, s."""


def _contact_points(segment: Segment, tool_radius_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the ball tool touches along the segment (M, 3) and the CF z there (M, 3)."""
    p = segment_positions(segment, PIECE_ROLLOUT_STEP_S)
    q = QuaternionDMP.from_parameters(segment.orientation_dmp).rollout(PIECE_ROLLOUT_STEP_S).q
    n = min(len(p), len(q))
    p, z_tool = p[:n], matrix_from_quaternion(q[:n])[:, :, 2]
    fractions = np.linspace(0.0, 1.0, n)
    z_cf = compliant_frame_rotations(segment, fractions * (segment.t_end - segment.t_start))[:, :, 2]
    return p - tool_radius_m * z_tool + tool_radius_m * z_cf, z_cf


def _slab_halfspaces(segment: Segment, points: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
    """Half-spaces ``A x <= b`` of a slide segment's slab, its plane normal (into the material) and a surface point."""
    frames = segment.compliant_frames
    assert frames is not None
    R = matrix_from_quaternion(np.asarray(frames.orientations[0], dtype=float))
    local = (points - np.asarray(frames.origins[0], dtype=float)) @ R
    top = float(np.median(local[:, 2]))
    lo = local[:, :2].min(axis=0) - WORK_PIECE_MARGIN_M
    hi = local[:, :2].max(axis=0) + WORK_PIECE_MARGIN_M
    x, y, z = R[:, 0], R[:, 1], R[:, 2]
    o = np.asarray(frames.origins[0], dtype=float)
    A = np.array([x, -x, y, -y, z, -z])
    b = np.array([hi[0], -lo[0], hi[1], -lo[1], top + WORK_PIECE_THICKNESS_M, -top]) + A @ o
    surface_point = o + R @ np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), top])
    return A, b, surface_point


def _vertices_of(A: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Vertices of the bounded convex polyhedron ``A x <= b``."""
    from scipy.optimize import linprog
    from scipy.spatial import HalfspaceIntersection

    # An interior point: the centre of the largest ball inside (Chebyshev centre), by a linear program.
    norms = np.linalg.norm(A, axis=1)
    res = linprog(np.r_[np.zeros(3), -1.0], A_ub=np.c_[A, norms], b_ub=b, bounds=[(None, None)] * 3 + [(1e-6, None)])
    if not res.success:
        raise ValueError("a rebuilt work piece part is empty (its cuts leave nothing)")
    return HalfspaceIntersection(np.c_[A, -b], res.x[:3]).intersections


def _slabs(segments: list[Segment], points: list[NDArray[np.float64]]) -> list[NDArray[np.float64]]:
    """Vertices of the slabs under consecutive slide segments, cut at convex creases."""
    spaces = [_slab_halfspaces(s, p) for s, p in zip(segments, points, strict=True)]
    parts = []
    for k, (A, b, _) in enumerate(spaces):
        cuts_A, cuts_b = [A], [b]
        for j in (k - 1, k + 1):
            if not 0 <= j < len(spaces) or segments[j].index != segments[k].index + (j - k):
                continue  # only neighbours in direct contact succession share a crease
            A_j, b_j, _ = spaces[j]
            z_j = A_j[4]
            depth = points[k] @ z_j - (-b_j[5])  # depth of this path below the neighbour's surface
            if np.median(depth) > 0.0:  # convex crease: keep only what lies inside the neighbour's material
                cuts_A.append(-z_j[None, :])
                cuts_b.append(np.array([b_j[5]]))
        parts.append(_vertices_of(np.vstack(cuts_A), np.concatenate(cuts_b)))
    return parts


STRIP_SAMPLE_M = 0.001
"""A contour path is kept every this much of TANGENTIAL travel (motion along the normal, pressing or lifting, is
not travel over the surface), m."""
STRIP_SMOOTHING_M = 0.01
"""The contact points and normals of a contour are smoothed along the path over this length (Gaussian sigma): the
learned normal carries the hand's tremor, a real surface does not (a washboard strip would shake the tool), m."""
STRIP_REVERSAL_DEG = 100.0
"""Where the path turns back by more than this over the surface, a new strip starts (its own pieces), deg."""


def _tangential_runs(points: NDArray[np.float64], z_cf: NDArray[np.float64]) -> list[NDArray[np.int_]]:
    """Indices of the samples kept along the surface, split where the path turns back: monotone runs."""
    kept = [0]
    for k in range(1, len(points)):
        d = points[k] - points[kept[-1]]
        n = z_cf[k]
        if np.linalg.norm(d - (d @ n) * n) >= STRIP_SAMPLE_M:
            kept.append(k)
    runs: list[list[int]] = [[kept[0]]]
    previous: NDArray[np.float64] | None = None
    for a, b in itertools.pairwise(kept):
        d = points[b] - points[a]
        d -= (d @ z_cf[b]) * z_cf[b]
        d /= max(float(np.linalg.norm(d)), 1e-12)
        if previous is not None and d @ previous < np.cos(np.radians(STRIP_REVERSAL_DEG)):
            runs.append([a])
        runs[-1].append(b)
        previous = d
    return [np.asarray(run) for run in runs]


def _smoothed_along(
    p: NDArray[np.float64], n: NDArray[np.float64], smoothing_m: float = STRIP_SMOOTHING_M
) -> tuple[NDArray, NDArray]:
    """Points (K, 3) and unit normals (K, 3), ~``STRIP_SAMPLE_M`` apart, Gaussian-smoothed along the path over
    ``smoothing_m`` (sigma, m)."""
    from scipy.ndimage import gaussian_filter1d

    sigma = smoothing_m / STRIP_SAMPLE_M
    p = gaussian_filter1d(p, sigma, axis=0, mode="nearest")
    n = gaussian_filter1d(n, sigma, axis=0, mode="nearest")
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


def _plate(points: NDArray[np.float64], z_cf: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """A square plate under the mean point (the tool hardly moved over the surface)."""
    n = z_cf.mean(axis=0)
    n /= np.linalg.norm(n)
    helper = np.eye(3)[np.argmin(np.abs(n))]
    t = np.cross(n, helper)
    t /= np.linalg.norm(t)
    centre = points.mean(axis=0)
    ends = np.array([centre - STRIP_HALF_WIDTH_M * t, centre + STRIP_HALF_WIDTH_M * t])
    return _strip_pieces(ends, np.array([n, n]), np.array([t, t]))


def _strip(points: NDArray[np.float64], z_cf: NDArray[np.float64]) -> list[tuple[NDArray[np.float64], int]]:
    """The convex pieces of the strips through ``points`` (M, 3) with inward normals ``z_cf`` (M, 3): vertices and
    how many pieces cover each point of it (:data:`STRIP_LAYERS` in a strip, 1 for a lone plate)."""
    pieces: list[NDArray[np.float64]] = []
    for run in _tangential_runs(points, z_cf):
        if run.size < 2:
            continue
        p, n = _smoothed_along(points[run], z_cf[run])
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        if s[-1] < STRIP_PIECE_LENGTH_M:
            continue
        grid = [0]
        for k in range(1, s.size):  # a new cross-section where the piece gets too long or its normal turns too far
            turn = np.degrees(np.arccos(np.clip(n[k] @ n[grid[-1]], -1.0, 1.0)))
            if s[k] - s[grid[-1]] >= STRIP_PIECE_LENGTH_M or turn >= STRIP_PIECE_TURN_DEG or k == s.size - 1:
                grid.append(k)
        P, N = p[grid], n[grid]
        T = np.gradient(P, axis=0)
        T -= np.sum(T * N, axis=1, keepdims=True) * N
        T /= np.maximum(np.linalg.norm(T, axis=1, keepdims=True), 1e-12)
        # Past both ends, along the end tangents, with the end normals.
        P = np.vstack([P[0] - WORK_PIECE_MARGIN_M * T[0], P, P[-1] + WORK_PIECE_MARGIN_M * T[-1]])
        N = np.vstack([N[0], N, N[-1]])
        T = np.vstack([T[0], T, T[-1]])
        pieces += _strip_pieces(P, N, T)
    if not pieces:
        return [(v, 1) for v in _plate(points, z_cf)]
    return [(v, STRIP_LAYERS) for v in pieces]


def _strip_pieces(P: NDArray, N: NDArray, T: NDArray) -> list[NDArray[np.float64]]:
    """Convex pieces between consecutive cross-sections: points ``P``, inward normals ``N``, tangents ``T``. Piece
    ``k`` spans sections ``k`` to ``k + 1`` extended along its own chord by half of each neighbour's length, so that
    with more than one piece every point between the end pieces' outer halves lies in exactly two pieces."""
    B = np.cross(T, N)
    B /= np.linalg.norm(B, axis=1, keepdims=True)
    top = np.stack([P + STRIP_HALF_WIDTH_M * B, P - STRIP_HALF_WIDTH_M * B], axis=1)  # (K, 2, 3)
    bottom = top + WORK_PIECE_THICKNESS_M * N[:, None, :]
    section = np.concatenate([top, bottom], axis=1)  # (K, 4, 3)
    chords = np.diff(P, axis=0)
    lengths = np.linalg.norm(chords, axis=1)
    pieces = []
    for k in range(len(P) - 1):
        unit = chords[k] / max(float(lengths[k]), 1e-12)
        back = 0.5 * lengths[k - 1] if k > 0 else 0.0
        ahead = 0.5 * lengths[k + 1] if k + 1 < len(lengths) else 0.0
        pieces.append(np.vstack([section[k] - back * unit, section[k + 1] + ahead * unit]))
    return pieces


def rebuilt_work_pieces(skill: Skill, tool_radius_m: float) -> list[WorkPiece]:
    """The convex parts (``WorldConfig.work_pieces`` entries) of the work piece a skill touched (world frame)."""
    contact = [s for s in skill.segments if s.kind is SegmentKind.contact and s.compliant_frames is not None]
    if not contact:
        raise ValueError("the skill has no contact segment: there is no work piece to rebuild")
    points = [_contact_points(s, tool_radius_m) for s in contact]
    parts: list[tuple[int, NDArray[np.float64], int]] = []
    slides = [k for k, s in enumerate(contact) if s.compliant_frames is not None and len(s.compliant_frames.t) == 1]
    slabs = _slabs([contact[k] for k in slides], [points[k][0] for k in slides])
    parts += [(contact[k].index, v, 1) for k, v in zip(slides, slabs, strict=True)]
    for k, segment in enumerate(contact):
        if k not in slides:
            parts += [(segment.index, v, layers) for v, layers in _strip(*points[k])]
    return [
        WorkPiece(name=f"work_piece_s{index}_{n}", vertices=np.round(v, 9).tolist(), layers=layers)
        for n, (index, v, layers) in enumerate(parts)
    ]


def rebuilt_world_config(skill: Skill, base: WorldConfig | None = None) -> WorldConfig:
    """``base`` (default: the default world) without its table, with the work piece rebuilt from ``skill``."""
    base = base or WorldConfig()
    return base.with_only_work_pieces(rebuilt_work_pieces(skill, base.tool.radius_m))


# --------------------------------------------------------------------------------------------- measured


FIRM_PRESS_FRACTION = 0.5
"""The samples that measure a pass's surface press at least this fraction of its median press."""
PLANE_DEPTH_M = 1.0e-3
"""A pass is a plane when its contact points (99th percentile) leave the pressed plane by at most this, m ..."""
PLANE_NORMAL_DEG = 8.0
"""... and its measured normals lean from that plane's normal by a median of at most this, deg (planes: under 3°,
a hand-wiped one's included; curved passes: 11° and more, a crease traced as a planar curve included)."""
HULL_SECTION_M = 0.005
"""Path length between the cross-sections of a curved strip, m (of 1, 2, 5 and 10 mm, 5 held the force best)."""
HULL_SMOOTHING_M = 0.005
"""The contact points and normals of a curved pass are smoothed along the path over this length (sigma), m."""
HULL_HALF_WIDTHS_M = (0.03, 0.02, 0.01)
"""Half widths of a curved strip across the path, widest first, m: the widest whose wings bury none of the path is
taken (wings straight across the path rise off a surface curving across it; of 1-4 cm on a cylinder, 3 held the
force best)."""
CONVEX_TOLERANCE_M = 2.0e-3
"""A curved pass whose sections lie deeper than this in its strip's hull, even with the narrowest wings and no end
margins, is not convex there: it is split at the deepest, m (a hand's tremor and a tracker's noise stay under it)."""
OVERLAP_TOLERANCE_M = 1.0e-3
"""A pass whose contact points come this close to another pass's piece (or lie in it) touches the same surface, m."""


@dataclass(frozen=True)
class _Contact:
    """The firm samples of one or more passes (world, m): surface points (M, 3), inward normals (M, 3), press (M,) N,
    and each pass's samples in time order (index arrays into them)."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    press_n: NDArray[np.float64]
    passes: tuple[NDArray[np.int_], ...]

    @classmethod
    def of(cls, measured: MeasuredPass) -> _Contact:
        firm = measured.press_n >= FIRM_PRESS_FRACTION * float(np.median(measured.press_n))
        n = int(firm.sum())
        return cls(measured.surface_points[firm], measured.normals[firm], measured.press_n[firm], (np.arange(n),))

    def joined(self, other: _Contact) -> _Contact:
        offset = len(self.points)
        return _Contact(
            np.vstack([self.points, other.points]),
            np.vstack([self.normals, other.normals]),
            np.concatenate([self.press_n, other.press_n]),
            self.passes + tuple(rows + offset for rows in other.passes),
        )


def _plane_slab(contact: _Contact) -> NDArray[np.float64] | None:
    """The slab (8 vertices) under a planar contact, or None when the contact is not a plane (module docstring)."""
    fit = slide_frame(contact.points, contact.normals * contact.press_n[:, None], contact.normals)
    R = fit.rotation
    z = R[:, 2]
    surface = pressed_surface(contact.points, contact.press_n, z, basis=R[:, :2])
    leaning = np.degrees(np.arccos(np.clip(contact.normals @ z, -1.0, 1.0)))
    residual = contact.points @ z - surface.depth_at(contact.points, contact.press_n)
    if np.percentile(np.abs(residual), 99) > PLANE_DEPTH_M or np.median(leaning) > PLANE_NORMAL_DEG:
        return None
    # The top where the tool was at the median press: a soft pad then sinks as much as the skill will press.
    press = contact.press_n - np.median(contact.press_n)
    top = float(np.median(contact.points @ z - surface.compliance_m_n * press))
    local = contact.points @ R[:, :2]
    lo, hi = local.min(axis=0) - WORK_PIECE_MARGIN_M, local.max(axis=0) + WORK_PIECE_MARGIN_M
    corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    face = corners @ R[:, :2].T + top * z
    return np.vstack([face, face + WORK_PIECE_THICKNESS_M * z])


def _sections(points: NDArray[np.float64], normals: NDArray[np.float64]) -> list[tuple[NDArray, NDArray]]:
    """The cross-sections (points (K, 3), unit normals (K, 3)) of one pass's strip: per run over the surface (split
    where the path turns back), smoothed along it over ``HULL_SMOOTHING_M`` and ``HULL_SECTION_M`` apart."""
    sections = []
    for run in _tangential_runs(points, normals):
        p, n = _smoothed_along(points[run], normals[run], HULL_SMOOTHING_M)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        keep = np.unique(np.r_[np.searchsorted(s, np.arange(0.0, s[-1], HULL_SECTION_M)), s.size - 1])
        sections.append((p[keep], n[keep]))
    return sections


def _strip_corners(
    P: NDArray[np.float64], N: NDArray[np.float64], margin_m: float, half_width_m: float
) -> NDArray[np.float64]:
    """The corners (4 (K + 2), 3) of a strip through sections ``P`` with inward normals ``N`` (K, 3): ``half_width_m``
    to each side, ``WORK_PIECE_THICKNESS_M`` deep, extended ``margin_m`` past both ends along the end tangents (a tool
    that hardly moved, one section, gets a ``WORK_PIECE_MARGIN_M`` plate to land on)."""
    T = np.gradient(P, axis=0) if len(P) > 1 else np.cross(N, np.eye(3)[np.argmin(np.abs(N[0]))])
    T = T - np.sum(T * N, axis=1, keepdims=True) * N
    T /= np.maximum(np.linalg.norm(T, axis=1, keepdims=True), 1e-12)
    margin = margin_m if len(P) > 1 else WORK_PIECE_MARGIN_M
    P = np.vstack([P[0] - margin * T[0], P, P[-1] + margin * T[-1]])
    N, T = np.vstack([N[0], N, N[-1]]), np.vstack([T[0], T, T[-1]])
    B = np.cross(T, N)
    B /= np.linalg.norm(B, axis=1, keepdims=True)
    top = np.vstack([P + half_width_m * B, P - half_width_m * B])
    return np.vstack([top, top + WORK_PIECE_THICKNESS_M * np.vstack([N, N])])


def _buried_depths(vertices: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """How deep ``points`` (M, 3) lie inside the convex hull of ``vertices`` (m; negative: outside, by at least
    that much)."""
    from scipy.spatial import ConvexHull

    equations = ConvexHull(vertices, qhull_options="QJ").equations  # joggled: degenerate input is not an error
    return -np.max(points @ equations[:, :3].T + equations[:, 3], axis=1)


def _hull(sections: list[tuple[NDArray, NDArray]]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The corners of the strips through ``sections`` (one convex hull), with the end margins and the widest wings that
    bury none of their sections deeper than ``CONVEX_TOLERANCE_M`` (else the narrowest, without margins), and how
    deep each section lies in it (m). A path going round (a rim) has its ends inside the turns, which end margins would
    cover; wings straight across the path rise off a surface curving across it."""
    centres = np.vstack([P for P, _ in sections])
    for margin, width in itertools.product((WORK_PIECE_MARGIN_M, 0.0), HULL_HALF_WIDTHS_M):
        corners = np.vstack([_strip_corners(P, N, margin, width) for P, N in sections])
        depths = _buried_depths(corners, centres)
        if depths.max() <= CONVEX_TOLERANCE_M:
            break
    return corners, depths


def _run_hulls(P: NDArray[np.float64], N: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """The hull(s) of one run's strip: one where it buries none of the run (`_hull`), else split at the deepest buried
    section (a hollow, or a saddle such as a twisted crease), each side again."""
    corners, depths = _hull([(P, N)])
    if len(P) <= 2 or depths.max() <= CONVEX_TOLERANCE_M:
        return [corners]
    k = int(np.clip(np.argmax(depths), 1, len(P) - 2))
    return _run_hulls(P[: k + 1], N[: k + 1]) + _run_hulls(P[k:], N[k:])


def _measured_pieces(contact: _Contact) -> list[NDArray[np.float64]]:
    """The convex pieces (vertices) of a contact's surface: its slab where it is a plane, else the hull of its strips,
    split where the surface is not convex (module docstring)."""
    from scipy.spatial import ConvexHull

    slab = _plane_slab(contact)
    if slab is not None:
        return [slab]
    sections = [s for rows in contact.passes for s in _sections(contact.points[rows], contact.normals[rows])]
    corners, depths = _hull(sections)
    pieces = [corners] if depths.max() <= CONVEX_TOLERANCE_M else [h for P, N in sections for h in _run_hulls(P, N)]
    return [v[ConvexHull(v).vertices] for v in pieces]


def _touches(a: tuple[_Contact, list[NDArray]], b: tuple[_Contact, list[NDArray]]) -> bool:
    """Whether either contact's points lie on or in the other's pieces (within ``OVERLAP_TOLERANCE_M``)."""
    return any(
        _buried_depths(v, other.points).max() >= -OVERLAP_TOLERANCE_M
        for (_, pieces), (other, _) in ((a, b), (b, a))
        for v in pieces
    )


def measured_work_pieces(
    skill: Skill, demonstration: Demonstration, tool_radius_m: float, contact_stiffness_n_m: float
) -> list[WorkPiece]:
    """The convex parts (``WorldConfig.work_pieces`` entries, world frame) of the surface ``demonstration`` measured
    under the passes of ``skill`` (learned from it, placed with it), for a ball tool of ``tool_radius_m`` (m) in a
    world of ``contact_stiffness_n_m`` (N/m); see the module. Raises ValueError when the skill has no contact or the
    demonstration is not its own."""
    passes = measured_passes(demonstration, skill, tool_radius_m, contact_stiffness_n_m)
    if not passes:
        raise ValueError("the skill has no contact segment: there is no work piece to measure")
    groups = [(contact, _measured_pieces(contact)) for contact in map(_Contact.of, passes)]
    merging = True
    while merging:  # passes on the same surface become one piece (few passes: pairs are cheap)
        merging = False
        for i, j in itertools.combinations(range(len(groups)), 2):
            if _touches(groups[i], groups[j]):
                contact = groups[i][0].joined(groups[j][0])
                groups[i] = (contact, _measured_pieces(contact))
                del groups[j]
                merging = True
                break
    return [
        WorkPiece(name=f"measured_{g}_{k}", vertices=np.round(v, 9).tolist())
        for g, (_, pieces) in enumerate(groups)
        for k, v in enumerate(pieces)
    ]


def measured_world_config(skill: Skill, demonstration: Demonstration, base: WorldConfig | None = None) -> WorldConfig:
    """``base`` (default: the default world) without its table, with the work piece ``demonstration`` measured under
    the passes of ``skill``, for ``base``'s tool and contact stiffness."""
    base = base or WorldConfig()
    pieces = measured_work_pieces(skill, demonstration, base.tool.radius_m, base.contact.stiffness_n_m)
    return base.with_only_work_pieces(pieces)
