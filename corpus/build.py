"""Building blocks of the corpus's demonstrations: pieces on one time grid, free moves, force envelopes, the
assembly that adds a person and a pad, surfaces and the timing of paths along them.

World frame, z up, SI units (m, s, N, rad), quaternions scalar-last ``[x, y, z, w]`` world-from-tool; the
wrench is the one the TOOL APPLIES, world frame, at the tool point; normals point INTO the surface.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import cumulative_trapezoid
from scipy.ndimage import distance_transform_edt, gaussian_filter1d
from scipy.spatial import cKDTree

from corpus.kinesthetic import _slow_wander
from corpus.synthetic import minimum_jerk
from skills.frames import matrix_from_axis_angle, rotation_from_vectors
from skills.friction import FRICTION_SPEED_M_S
from skills.quaternions import quaternion_from_matrix, quaternions_sign_continuous

TREMOR_FADE_S = 0.2
"""Time over which the hand's tremor across the surface fades in after a lift-off (and out before a touch-down), s."""
UP = np.array([0.0, 0.0, 1.0])
"""World z, m/m."""
Speed = Callable[[NDArray[np.float64], float], NDArray[np.float64]]
"""Speed (m/s) along a path at arc lengths ``s`` (m) of a path of the given length (m)."""


# --------------------------------------------------------------------------- pieces of a demonstration


@dataclass(frozen=True)
class Piece:
    """A stretch of a demonstration on the case's time grid.

    ``points`` (M, 3) m: the noise-free path (surface points while touching, the tool point in free space);
    ``held_axis`` (M, 3): where the hand aims the tool z; ``normals`` (M, 3) inward unit normals while
    touching (None in free space); ``force`` (M,) the normal force before the hand's slow wander, N (None in
    free space); ``plateau`` (M,) the stroke each sample's plateau belongs to, -1 outside plateaus (ramps, dips);
    ``stroke``: the contact counts as stroke(s) (False: a brush that is no stroke); ``edge``: the tool rides an
    edge, so tremor moves it only along the path.
    """

    points: NDArray[np.float64]
    held_axis: NDArray[np.float64]
    normals: NDArray[np.float64] | None = None
    force: NDArray[np.float64] | None = None
    plateau: NDArray[np.int_] | None = None
    stroke: bool = True
    edge: bool = False


def hermite(
    p0: NDArray[np.float64], v0: NDArray[np.float64], p1: NDArray[np.float64], v1: NDArray[np.float64], s: NDArray
) -> NDArray[np.float64]:
    """Cubic Hermite curve (M, 3) m from ``p0`` with velocity ``v0`` to ``p1`` with ``v1`` (m per unit ``s``)."""
    s = s[:, None]
    return (2 * s**3 - 3 * s**2 + 1) * p0 + (s**3 - 2 * s**2 + s) * v0 + (3 * s**2 - 2 * s**3) * p1 + (s**3 - s**2) * v1


def approach(contact: Piece, duration_s: float, height_m: float, dt: float, descent_m_s: float = 0.02) -> Piece:
    """Free approach (``duration_s``, from rest) ending where ``contact`` touches down.

    It starts ``height_m`` out along the surface normal and ends moving as the contact starts (tangentially)
    while descending at ``descent_m_s`` along the normal: the tool touches down already moving.
    """
    n = contact.normals[0]
    velocity = (contact.points[1] - contact.points[0]) / dt
    tangential = velocity - np.dot(velocity, n) * n
    start = contact.points[0] - height_m * n - 0.5 * duration_s * tangential
    s = np.arange(round(duration_s / dt)) * dt / duration_s
    path = hermite(start, np.zeros(3), contact.points[0], duration_s * (tangential + descent_m_s * n), s)
    return Piece(path, np.broadcast_to(contact.held_axis[0], path.shape))


def retreat(contact: Piece, duration_s: float, height_m: float, dt: float, ascent_m_s: float = 0.02) -> Piece:
    """Free retreat (``duration_s``, to rest) leaving where ``contact`` lifts off, moving on as it moved."""
    n = contact.normals[-1]
    velocity = (contact.points[-1] - contact.points[-2]) / dt
    tangential = velocity - np.dot(velocity, n) * n
    end = contact.points[-1] - height_m * n + 0.5 * duration_s * tangential
    s = np.arange(1, round(duration_s / dt) + 1) * dt / duration_s
    path = hermite(contact.points[-1], duration_s * (tangential - ascent_m_s * n), end, np.zeros(3), s)
    return Piece(path, np.broadcast_to(contact.held_axis[-1], path.shape))


def transfer(start: NDArray, end: NDArray, held_axis: NDArray, duration_s: float, dt: float, lift_m: float) -> Piece:
    """Free move from rest at ``start`` to rest at ``end`` (minimum jerk), arching ``lift_m`` up on the way."""
    g = minimum_jerk(np.arange(1, round(duration_s / dt) + 1) * dt / duration_s)
    path = start + (end - start) * g[:, None]
    path[:, 2] += lift_m * np.sin(np.pi * g)
    return Piece(path, np.broadcast_to(held_axis, path.shape))


def rest(point: NDArray, held_axis: NDArray, duration_s: float, dt: float) -> Piece:
    """The tool held still (up to tremor) at ``point`` for ``duration_s``."""
    path = np.repeat(point[None], round(duration_s / dt), axis=0)
    return Piece(path, np.broadcast_to(held_axis, path.shape))


def envelope(
    t: NDArray[np.float64], ramp_s: float, dips: tuple[tuple[float, float, float, float], ...] = ()
) -> NDArray[np.float64]:
    """Force envelope (M,) in [0, 1] over a contact sampled at ``t`` (s since touch-down, ending at lift-off).

    Minimum-jerk ramps of ``ramp_s`` at both ends; each dip ``(centre_s, fall_s, hold_s, depth)`` falls to
    ``depth`` over ``fall_s``, holds for ``hold_s`` around ``centre_s`` and rises again over ``fall_s``.
    """
    shape = minimum_jerk(t / ramp_s) * minimum_jerk((t[-1] - t) / ramp_s)
    for centre, fall, hold, depth in dips:
        reach = 0.5 * hold + fall
        down = minimum_jerk((t - centre + reach) / fall) * minimum_jerk((centre + reach - t) / fall)
        shape = shape * (1.0 - (1.0 - depth) * down)
    return shape


def plateau_ids(shape: NDArray[np.float64], t: NDArray[np.float64], dip_centres: tuple[float, ...] = ()) -> NDArray:
    """The stroke (0, 1, ...) of each sample where ``shape`` is at its plateau (== 1), -1 elsewhere."""
    stroke = np.searchsorted(np.asarray(dip_centres), t)
    return np.where(shape > 1.0 - 1e-9, stroke, -1)


# --------------------------------------------------------------------------- assembly


@dataclass(frozen=True)
class Assembled:
    """A demonstration assembled from pieces: the case arrays (see `CorpusCase`) and what the truth needs.

    ``path`` (N, 3) m the noise-free path; ``contact_id`` (N,) the stroke contact each sample belongs to, -1
    elsewhere (free space, a brush); ``plateau_id`` (N,) the stroke of each plateau sample, -1 elsewhere.
    """

    t: NDArray[np.float64]
    path: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]
    wrenches: NDArray[np.float64]
    touching: NDArray[np.bool_]
    normals: NDArray[np.float64]
    normal_force: NDArray[np.float64]
    contact_id: NDArray[np.int_]
    plateau_id: NDArray[np.int_]


def tool_orientations(held_axis: NDArray, t: NDArray, touching: NDArray, rng: np.random.Generator) -> NDArray:
    """World-from-tool quaternions (N, 4): tool z along ``held_axis`` turned over ~0.15 s, a slow wobble of
    ~3 deg in contact (~6 deg in free space) and a slow turn about the tool axis."""
    dt = float(t[1] - t[0])
    axis = gaussian_filter1d(held_axis, 0.15 / dt, axis=0, mode="nearest")
    amplitude = gaussian_filter1d(np.where(touching, 0.05, 0.1), 0.2 / dt, mode="nearest")[:, None]
    tool_z = axis / np.linalg.norm(axis, axis=1, keepdims=True) + amplitude * _slow_wander(t, rng, 0.05, 0.3, 3)
    yaw = 0.3 * _slow_wander(t, rng, 0.02, 0.1)[:, 0]
    c, s, zero = np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)
    twist = np.stack([np.stack([c, -s, zero], 1), np.stack([s, c, zero], 1), np.tile([0.0, 0.0, 1.0], (t.size, 1))], 1)
    R = rotation_from_vectors(np.array([0.0, 0.0, -1.0]), tool_z) @ np.diag([1.0, -1.0, -1.0]) @ twist
    return quaternions_sign_continuous(quaternion_from_matrix(R))


def assemble(
    pieces: list[Piece],
    dt: float,
    rng: np.random.Generator,
    pad_stiffness_n_m: float,
    friction: float,
    tremor_m: float,
    force_wander: float,
) -> Assembled:
    """Concatenate ``pieces`` on a uniform grid of step ``dt`` (s) and add the person and the pad.

    The normal force swings slowly by ``force_wander`` (relative, 0.1-0.5 Hz); the tool point sinks into the
    pad by force / ``pad_stiffness_n_m`` along the normal; the hand trembles by ``tremor_m`` (4-9 Hz),
    tangentially while touching (along the path on an edge), in every direction away from the surface; the
    applied force is the normal force along the inward normal plus Coulomb friction (``friction`` × normal
    force) along the sliding direction; the true moment at the tool point is zero.
    """
    path = np.concatenate([p.points for p in pieces])
    n = len(path)
    t = np.arange(n) * dt
    touching = np.concatenate([np.full(len(p.points), p.force is not None) for p in pieces])
    level = np.concatenate([p.force if p.force is not None else np.zeros(len(p.points)) for p in pieces])
    held = np.concatenate([np.broadcast_to(p.held_axis, p.points.shape) for p in pieces])
    edge = np.concatenate([np.full(len(p.points), p.edge) for p in pieces])
    counts = [p.force is not None and p.stroke for p in pieces]
    contact_id = np.concatenate(
        [np.full(len(p.points), k if c else -1) for p, c, k in zip(pieces, counts, np.cumsum(counts) - 1, strict=True)]
    )
    offsets = np.cumsum([0] + [int(p.plateau.max()) + 1 if p.plateau is not None else 0 for p in pieces])
    plateau_id = np.concatenate(
        [
            np.where(p.plateau >= 0, p.plateau + offset, -1) if p.plateau is not None else np.full(len(p.points), -1)
            for p, offset in zip(pieces, offsets[:-1], strict=True)
        ]
    )
    # Free space: the normal of the nearest traced surface point.
    touched = np.concatenate([p.normals for p in pieces if p.normals is not None])
    nearest = cKDTree(path[touching]).query(path)[1]
    normals = touched[nearest]

    normal_force = level * (1.0 + force_wander * _slow_wander(t, rng, 0.1, 0.5)[:, 0])
    tangent = np.gradient(path, dt, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    tremor = tremor_m * _slow_wander(t, rng, 4.0, 9.0, 3)
    along_normal = np.sum(tremor * normals, axis=1, keepdims=True) * normals
    along_path = np.sum(tremor * tangent, axis=1, keepdims=True) * tangent
    # On the surface the tremor slides the tool (along an edge: along it); leaving it, the hand's full tremor
    # fades in over TREMOR_FADE_S, so the tool neither jumps nor dips into the surface at touch-down or lift-off.
    free_s, nearest = distance_transform_edt(~touching, return_indices=True)
    constrained = np.where(edge[nearest[0]][:, None], along_path, tremor - along_normal)
    tremor = constrained + minimum_jerk(free_s * dt / TREMOR_FADE_S)[:, None] * (tremor - constrained)
    positions = path + (normal_force / pad_stiffness_n_m)[:, None] * normals + tremor

    velocity = np.gradient(gaussian_filter1d(positions, max(1.0, 0.005 / dt), axis=0, mode="nearest"), dt, axis=0)
    sliding = velocity - np.sum(velocity * normals, axis=1, keepdims=True) * normals
    speed = np.linalg.norm(sliding, axis=1, keepdims=True)
    slip = np.tanh(speed / FRICTION_SPEED_M_S) * sliding / np.maximum(speed, 1e-9)
    wrenches = np.zeros((n, 6))
    wrenches[:, :3] = normal_force[:, None] * (normals + friction * slip)
    return Assembled(
        t=t,
        path=path,
        positions=positions,
        orientations=tool_orientations(held, t, touching, rng),
        wrenches=wrenches,
        touching=touching,
        normals=normals,
        normal_force=normal_force,
        contact_id=contact_id,
        plateau_id=plateau_id,
    )


def rotated(vector: NDArray[np.float64], axis: NDArray[np.float64], angle_rad: float) -> NDArray[np.float64]:
    """``vector`` turned by ``angle_rad`` about ``axis`` (right hand)."""
    return matrix_from_axis_angle(axis, angle_rad) @ vector


# --------------------------------------------------------------------------- paths and their timing


def speed_profile(touch: float, cruise: float, lift: float, slow: Sequence[tuple[float, float, float]] = ()) -> Speed:
    """Speed (m/s) along a path of arc length ``s`` (m): ``touch`` at the start, ``cruise`` after 3 cm, ``lift``
    at the end, slowed to a ``factor`` around each ``(s_centre, factor, width_m)`` of ``slow`` (a corner)."""

    def speed(s: NDArray[np.float64], length: float) -> NDArray[np.float64]:
        v = touch + (cruise - touch) * minimum_jerk(s / 0.03)
        v = lift + (v - lift) * minimum_jerk((length - s) / 0.03)
        for centre, factor, width in slow:
            v = v * (1.0 - (1.0 - factor) * np.exp(-0.5 * ((s - centre) / width) ** 2))
        return v

    return speed


def timed(param: NDArray, points: NDArray, dt: float, speed: Speed) -> tuple[NDArray, NDArray]:
    """Time a densely sampled path (``points`` (K, 3) at parameters ``param`` (K,)) by ``speed`` along its arc
    length; return the sample times (s from the start, step ``dt``) and the parameter at each."""
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(step)])
    v = speed(s, float(s[-1]))
    t_dense = np.concatenate([[0.0], np.cumsum(step / (0.5 * (v[1:] + v[:-1])))])
    t = np.arange(0.0, t_dense[-1], dt)
    return t, np.interp(t, t_dense, param)


def heading_path(headings: Sequence[float], legs: Sequence[float], turn_m: float) -> tuple[NDArray, NDArray]:
    """A planar path (arc length (K,) m, chart points (K, 2) m from the origin) of straight ``legs`` (m) at
    ``headings`` (rad), each corner rounded by turning over ``turn_m`` of path."""
    corners = np.cumsum(legs)[:-1]
    s = np.arange(0.0, sum(legs), 1e-4)
    heading = np.full_like(s, headings[0])
    for corner, before, after in zip(corners, headings[:-1], headings[1:], strict=True):
        heading += (after - before) * minimum_jerk((s - corner) / turn_m + 0.5)
    xy = cumulative_trapezoid(np.stack([np.cos(heading), np.sin(heading)], axis=1), s, axis=0, initial=0.0)
    return s, xy


def circle_path(radius: Callable[[NDArray], NDArray], turns: float) -> tuple[NDArray, NDArray]:
    """A planar path (turn angle (K,) rad, chart points (K, 2) m) winding ``turns`` times round the origin
    at ``radius(angle)`` (m), shifted to start at the origin, heading along +y."""
    angle = np.linspace(0.0, 2 * np.pi * turns, round(2e4 * turns))
    xy = radius(angle)[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    return angle, xy - xy[0]


class Fold:
    """A plane folded down by ``fold_rad`` (rad; 0: a plane) over a convex edge rounded with ``radius_m`` (m).

    Chart ``(u, v)`` m: ``u`` arc length across the edge (at u = 0, face A for u < 0, along ``e_u`` in it),
    ``v`` along the edge ``e_v``; face A's outward normal is ``e_u × e_v``.
    """

    def __init__(self, origin: NDArray, e_u: NDArray, e_v: NDArray, fold_rad: float, radius_m: float) -> None:
        self.origin, self.e_u, self.e_v = origin, e_u, e_v
        self.out = np.cross(e_u, e_v)
        self.fold, self.radius = fold_rad, radius_m

    def _angle(self, u: NDArray) -> NDArray:
        return np.clip(u / self.radius, 0.0, self.fold)

    def points(self, u: NDArray, v: NDArray) -> NDArray[np.float64]:
        """Surface points (M, 3) m at chart coordinates ``u``, ``v`` (M,)."""
        phi = self._angle(u)[:, None]
        beyond = np.maximum(u - self.radius * self.fold, 0.0)[:, None]
        tangent_b = np.cos(self.fold) * self.e_u - np.sin(self.fold) * self.out
        bent = self.radius * (np.sin(phi) * self.e_u + (np.cos(phi) - 1.0) * self.out) + beyond * tangent_b
        return self.origin + v[:, None] * self.e_v + np.where(u[:, None] <= 0.0, u[:, None] * self.e_u, bent)

    def inward(self, u: NDArray) -> NDArray[np.float64]:
        """Inward unit normals (M, 3) at chart coordinate ``u`` (M,)."""
        phi = self._angle(u)[:, None]
        return -(np.sin(phi) * self.e_u + np.cos(phi) * self.out)


def tilted_plane(tilt_deg: float, rng: np.random.Generator, fold_rad: float = 0.0, radius_m: float = 0.008) -> Fold:
    """A plane through ~(0.5, 0, 0.15) m tilted by ``tilt_deg`` about a random horizontal axis, its chart axes
    turned by a random yaw (optionally folded down by ``fold_rad`` over an edge along ``e_v`` rounded with
    ``radius_m``)."""
    tilt_axis = rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    up = rotated(UP, tilt_axis, np.radians(tilt_deg))
    yaw = rng.uniform(-np.pi, np.pi)
    R = rotation_from_vectors(UP, up)
    origin = np.array([0.5 + rng.uniform(-0.05, 0.05), rng.uniform(-0.1, 0.1), 0.15])
    e_u = R @ np.array([np.cos(yaw), np.sin(yaw), 0.0])
    return Fold(origin, e_u, np.cross(up, e_u), fold_rad, radius_m)


def contact_piece(
    points: NDArray,
    normals: NDArray,
    t: NDArray,
    force_n: NDArray | float,
    ramp_s: float,
    dips: tuple[tuple[float, float, float, float], ...] = (),
    held_axis: NDArray | None = None,
    stroke: bool = True,
    edge: bool = False,
) -> Piece:
    """A contact sampled at ``t`` (s since touch-down) pressing ``force_n`` (N) shaped by `envelope` (ramps of
    ``ramp_s``, ``dips``); the hand aims the tool along ``held_axis`` (default: the normals). ``stroke``,
    ``edge``: see `Piece`."""
    shape = envelope(t, ramp_s, dips)
    plateau = plateau_ids(shape, t, tuple(d[0] for d in dips))
    held = normals if held_axis is None else np.broadcast_to(held_axis, normals.shape)
    return Piece(points, held, normals, np.asarray(force_n) * shape, plateau, stroke, edge)


def fillet(edge: NDArray, into_part: NDArray, elevation: NDArray, radius_m: float) -> tuple[NDArray, NDArray]:
    """Contact points and inward normals on a convex 90 deg crease (a horizontal top face over a vertical side)
    rounded with ``radius_m``: ``edge`` (M, 3) the sharp edge, ``into_part`` (M, 3) horizontal unit vectors
    across it into the part, ``elevation`` (M,) rad the pressed normal's angle below horizontal."""
    c, s = np.cos(elevation)[:, None], np.sin(elevation)[:, None]
    points = edge + radius_m * ((1.0 - c) * into_part + (s - 1.0) * UP)
    return points, c * into_part - s * UP


# --------------------------------------------------------------------------- contacts in the air


def through_the_air(
    contacts: list[Piece],
    rng: np.random.Generator,
    dt: float,
    height_m: tuple[float, float],
    move_s: tuple[float, float],
    rest_axes: Sequence[NDArray[np.float64] | None] | None = None,
    rest_s: tuple[float, float] = (1.0, 1.5),
) -> list[Piece]:
    """``contacts`` in the air: a rest of ``rest_s`` (s) held still, a free approach from ``height_m`` out along the
    normal (``move_s`` s; both drawn per move), each contact, a retreat as far, between contacts a move from rest to
    rest, and a last rest. ``rest_axes`` (len(contacts) + 1, default all None): the tool axis the hand holds in the
    rest before each contact and after the last (None: the contact's own; between contacts None means no pause)."""
    axes = list(rest_axes) if rest_axes is not None else [None] * (len(contacts) + 1)
    pieces: list[Piece] = []
    for k, contact in enumerate(contacts):
        down = approach(contact, rng.uniform(*move_s), rng.uniform(*height_m), dt)
        if k == 0:
            axis = contact.held_axis[0] if axes[0] is None else axes[0]
            pieces.append(rest(down.points[0], axis, rng.uniform(*rest_s), dt))
        else:
            if axes[k] is not None:
                pieces.append(rest(pieces[-1].points[-1], axes[k], rng.uniform(*rest_s), dt))
            # From the rest where the last retreat ended to the rest where this approach starts, arching 1 cm up.
            move = transfer(
                pieces[-1].points[-1], down.points[0], contact.held_axis[0], rng.uniform(0.6, 0.9), dt, 0.01
            )
            pieces.append(move)
        pieces += [down, contact, retreat(contact, rng.uniform(*move_s), rng.uniform(*height_m), dt)]
    last = contacts[-1].held_axis[-1] if axes[-1] is None else axes[-1]
    pieces.append(rest(pieces[-1].points[-1], last, rng.uniform(*rest_s), dt))
    return pieces
