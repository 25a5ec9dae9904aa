"""The work piece rebuilt from what a skill learned, for skills whose recording carries no simulated world.

A skill holds what it touched (world frame, m; CF z points into the surface, docs/CONVENTIONS.md):

- a **slide** segment: its plane (the CF). The rebuilt part is a slab under it, ``WORK_PIECE_THICKNESS_M``
  thick, bounded by the path's extent in the CF x-y plane plus ``WORK_PIECE_MARGIN_M``. Where two slide
  segments meet at a CONVEX crease (each path lies inside the other's half-space) each slab is cut by the other
  plane, so neither sticks out past the crease; at a concave crease the union of the slabs is already right.
- a **contour** segment: its contact path with the per-sample CF z (the friction-free force direction, i.e. the
  surface normal). The rebuilt part is a strip ``2 STRIP_HALF_WIDTH_M`` wide through the contact points, its
  normal following the learned one, cut every ``STRIP_PIECE_LENGTH_M`` of path into convex pieces (PyBullet
  collides convex shapes) and extended ``WORK_PIECE_MARGIN_M`` past both ends. Each piece reaches halfway into
  both neighbours, so every point of the strip lies in exactly two pieces (``"layers": 2``).

Why two layers: PyBullet's compliant contact is one spring per touching body. With pieces butted or slightly
overlapped the tool meets one piece here and two near a seam, the stiffness doubling and halving every few
centimetres, and the force spikes at every seam (the KU Leuven strips: true force max error 40-77 %, RMS 4.8-8.2 %).
Two layers everywhere, each piece's contact made half as stiff (``sim_worker.world``: in series with the tool's),
give the configured stiffness all along, and the surface felt is the mean of two neighbouring facets: smoother than
either. A single concave triangle mesh was tried and is worse (the flat table as a mesh of 2 or 800 triangles:
2.6 % and 7.2 % RMS against 1.4 % for the box; Bullet collides each triangle on its own).

The contact point is where the SIMULATED ball tool touches when its tool point follows the learned path with
the learned orientation: ball centre ``p - r z_tool``, contact ``centre + r z_cf`` (the tool point itself when
the tool is held along the normal). The parts are convex solids (``WorldConfig.work_pieces``); friction and
contact stiffness are the world's (defaults, overridable per execution).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from schemas.skill import Segment, SegmentKind, Skill
from sim_worker.world_config import WorldConfig
from skills.compliant_frames import compliant_frame_rotations
from skills.dmp import QuaternionDMP
from skills.placement import segment_positions
from skills.quaternions import matrix_from_quaternion

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
ROLLOUT_STEP_S = 0.005
"""Time step of the rollouts the surfaces are built from, s."""


def _contact_points(segment: Segment, tool_radius_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the ball tool touches along the segment (M, 3) and the CF z there (M, 3)."""
    p = segment_positions(segment, ROLLOUT_STEP_S)
    q = QuaternionDMP.from_parameters(segment.orientation_dmp).rollout(ROLLOUT_STEP_S).q
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


def _smoothed_along(p: NDArray[np.float64], n: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Points (K, 3) and unit normals (K, 3), ~``STRIP_SAMPLE_M`` apart, Gaussian-smoothed along the path."""
    from scipy.ndimage import gaussian_filter1d

    sigma = STRIP_SMOOTHING_M / STRIP_SAMPLE_M
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


def rebuilt_work_pieces(skill: Skill, tool_radius_m: float) -> list[dict[str, Any]]:
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
        {"name": f"work_piece_s{index}_{n}", "vertices": np.round(v, 9).tolist(), "layers": layers}
        for n, (index, v, layers) in enumerate(parts)
    ]


def rebuilt_world_config(skill: Skill, base: WorldConfig | None = None) -> WorldConfig:
    """``base`` (default: the default world) without its table, with the work piece rebuilt from ``skill``."""
    base = base or WorldConfig()
    pieces = rebuilt_work_pieces(skill, base.tool_radius_m)
    return base.replace(
        table_enabled=False, ramp_enabled=False, cylinder_enabled=False, block_enabled=False, work_pieces=pieces
    )
