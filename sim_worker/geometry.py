"""Exact geometry of a world (numpy only, no PyBullet): the ground truth the simulator's contact is judged by.

Each object is a convex solid with an exact signed distance; the world is their union, so outside the objects the
distance to the world is the minimum over the objects and the outward normal is that of the nearest one.
World frame, metres (docs/CONVENTIONS.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.world import WorldConfig
from skills.frames import matrix_from_axis_angle


@dataclass
class Solid:
    """A convex solid at pose ``(R, p)`` (body frame into world) with an exact signed distance."""

    name: str
    R: NDArray[np.float64]
    p: NDArray[np.float64]

    def _local(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        return (points - self.p) @ self.R

    def signed_distance(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return (distance (N,), outward unit normal (N, 3) in world) for points (N, 3); negative inside."""
        local = self._local(np.atleast_2d(np.asarray(points, dtype=float)))
        d, n_local = self._sdf_local(local)
        return d, n_local @ self.R.T

    def _sdf_local(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        raise NotImplementedError

    def outward_normal(self, point: NDArray[np.float64]) -> NDArray[np.float64]:
        """Outward unit normal (3,) of the nearest surface point to one ``point`` (3,) outside or near the solid."""
        return self.signed_distance(point[None, :])[1][0]


def _box_sdf(x: NDArray[np.float64], half: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Signed distance and gradient of an axis-aligned box of half extents ``half`` at the origin."""
    q = np.abs(x) - half
    outside = np.maximum(q, 0.0)
    out_norm = np.linalg.norm(outside, axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    d = out_norm + inside
    grad = np.zeros_like(x)
    is_out = out_norm > 0
    grad[is_out] = outside[is_out] / out_norm[is_out, None]
    k = np.argmax(q[~is_out], axis=1)
    grad_in = np.zeros((k.size, 3))
    grad_in[np.arange(k.size), k] = 1.0
    grad[~is_out] = grad_in
    return d, grad * np.where(x < 0, -1.0, 1.0)


def _extrude_sdf(
    d2: NDArray[np.float64], g2: NDArray[np.float64], y: NDArray[np.float64], half_width: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Combine a 2-D (x, z) signed distance with a slab |y| <= half_width into a 3-D one (exact)."""
    dy = np.abs(y) - half_width
    a = np.maximum(d2, 0.0)
    b = np.maximum(dy, 0.0)
    out = np.hypot(a, b)
    d = out + np.minimum(np.maximum(d2, dy), 0.0)
    grad = np.zeros((d2.size, 3))
    sy = np.where(y < 0, -1.0, 1.0)
    is_out = out > 0
    grad[is_out, 0] = g2[is_out, 0] * a[is_out] / out[is_out]
    grad[is_out, 2] = g2[is_out, 1] * a[is_out] / out[is_out]
    grad[is_out, 1] = sy[is_out] * b[is_out] / out[is_out]
    use_2d = ~is_out & (d2 >= dy)
    grad[use_2d, 0] = g2[use_2d, 0]
    grad[use_2d, 2] = g2[use_2d, 1]
    use_y = ~is_out & ~use_2d
    grad[use_y, 1] = sy[use_y]
    return d, grad


@dataclass
class BoxSolid(Solid):
    """A box of half extents ``half`` centred at ``p``."""

    half: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def _sdf_local(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return _box_sdf(x, self.half)


@dataclass
class CylinderSolid(Solid):
    """A finite cylinder, axis = body y axis through ``p``, of ``radius`` and ``length``. The simulator collides with a
    capsule of the same axis, radius and straight length (``sim_worker.world_build``): the same surface everywhere a
    skill touches it, rounded beyond its ends."""

    radius: float = 0.0
    length: float = 0.0

    def _sdf_local(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        r = np.hypot(x[:, 0], x[:, 2])
        safe = np.maximum(r, 1e-12)
        d2 = r - self.radius
        g2 = np.stack([x[:, 0] / safe, x[:, 2] / safe], axis=1)
        g2[r < 1e-12] = (0.0, 1.0)
        return _extrude_sdf(d2, g2, x[:, 1], 0.5 * self.length)

    def outward_normal(self, point: NDArray[np.float64]) -> NDArray[np.float64]:
        """Radial outward normal (fast path for points beside the lateral surface)."""
        x = (point - self.p) @ self.R
        if abs(x[1]) > 0.5 * self.length:
            return super().outward_normal(point)
        r = math.hypot(x[0], x[2])
        return self.R @ np.array([x[0] / r, 0.0, x[2] / r])

    @property
    def axis(self) -> NDArray[np.float64]:
        """Unit axis direction in world."""
        return self.R[:, 1].copy()


def nearest_on_ellipse(px: ArrayLike, pz: ArrayLike, a: float, b: float, iterations: int = 8):
    """Nearest points ``(x, z)`` on the ellipse ``(x/a)² + (z/b)² = 1`` to points ``(px, pz)`` (vectorized).

    Curvature-centre iteration (converges for points inside and outside); returns arrays x, z.
    """
    px = np.asarray(px, dtype=float)
    pz = np.asarray(pz, dtype=float)
    ax, az = np.abs(px), np.abs(pz)
    tx = np.full_like(ax, math.sqrt(0.5))
    tz = np.full_like(az, math.sqrt(0.5))
    for _ in range(iterations):
        x, z = a * tx, b * tz
        ex = (a * a - b * b) * tx**3 / a
        ez = (b * b - a * a) * tz**3 / b
        rx, rz = x - ex, z - ez
        qx, qz = ax - ex, az - ez
        r = np.hypot(rx, rz)
        q = np.maximum(np.hypot(qx, qz), 1e-15)
        tx = np.clip((qx * r / q + ex) / a, 0.0, 1.0)
        tz = np.clip((qz * r / q + ez) / b, 0.0, 1.0)
        t = np.maximum(np.hypot(tx, tz), 1e-15)
        tx, tz = tx / t, tz / t
    return np.copysign(a * tx, px), np.copysign(b * tz, pz)


def _nearest_on_ellipse_scalar(px: float, pz: float, a: float, b: float, iterations: int = 8) -> tuple[float, float]:
    """Scalar version of ``nearest_on_ellipse`` (plain floats, ~10x faster for one point)."""
    ax, az = abs(px), abs(pz)
    tx = tz = math.sqrt(0.5)
    for _ in range(iterations):
        x, z = a * tx, b * tz
        ex = (a * a - b * b) * tx**3 / a
        ez = (b * b - a * a) * tz**3 / b
        r = math.hypot(x - ex, z - ez)
        qx, qz = ax - ex, az - ez
        q = max(math.hypot(qx, qz), 1e-15)
        tx = min(1.0, max(0.0, (qx * r / q + ex) / a))
        tz = min(1.0, max(0.0, (qz * r / q + ez) / b))
        t = max(math.hypot(tx, tz), 1e-15)
        tx, tz = tx / t, tz / t
    return math.copysign(a * tx, px), math.copysign(b * tz, pz)


@dataclass
class CurvedBlockSolid(Solid):
    """A slab ``|x| <= a, 0 <= z <= base`` capped by the upper half-ellipse of semi-axes (a, cap) centred at
    ``(0, base)``, extruded over ``|y| <= width / 2``; body frame origin on the table top under the block centre.
    """

    a: float = 0.0
    cap: float = 0.0
    base: float = 0.0
    width: float = 0.0

    def profile_point(self, phi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Body-frame (x, z) of the cap at ellipse angle ``phi`` (rad, 0 = +x end, pi/2 = top)."""
        phi = np.asarray(phi, dtype=float)
        return self.a * np.cos(phi), self.base + self.cap * np.sin(phi)

    def profile_normal(self, phi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Body-frame outward unit normal (x, z) of the cap at ellipse angle ``phi``."""
        phi = np.asarray(phi, dtype=float)
        nx, nz = np.cos(phi) / self.a, np.sin(phi) / self.cap
        norm = np.hypot(nx, nz)
        return nx / norm, nz / norm

    def outward_normal(self, point: NDArray[np.float64]) -> NDArray[np.float64]:
        """Ellipse normal (fast path for points outside the cap, above the base, within the width); else exact."""
        x = (point - self.p) @ self.R
        outside_cap = (x[0] / self.a) ** 2 + ((x[2] - self.base) / self.cap) ** 2 >= 1.0
        if x[2] <= self.base or abs(x[1]) > 0.5 * self.width or abs(x[0]) > self.a or not outside_cap:
            return super().outward_normal(point)
        ex, ez = _nearest_on_ellipse_scalar(float(x[0]), float(x[2]) - self.base, self.a, self.cap)
        gx, gz = ex / self.a**2, ez / self.cap**2
        g = math.hypot(gx, gz)
        return self.R @ np.array([gx / g, 0.0, gz / g])

    def _sdf_local(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        px, pz = x[:, 0], x[:, 2]
        # Rectangle [-a, a] x [0, base].
        centre = np.array([0.0, 0.5 * self.base])
        rect_pts = np.stack([px, np.zeros_like(px), pz - centre[1]], axis=1)
        d_rect, g_rect3 = _box_sdf(rect_pts, np.array([self.a, 1.0, 0.5 * self.base]))
        g_rect = g_rect3[:, [0, 2]]
        # Cap: ellipse intersected with z >= base.
        ex, ez = nearest_on_ellipse(px, pz - self.base, self.a, self.cap)
        dist = np.hypot(px - ex, pz - self.base - ez)
        inside = (px / self.a) ** 2 + ((pz - self.base) / self.cap) ** 2 < 1.0
        d_ell = np.where(inside, -dist, dist)
        gx, gz = ex / self.a**2, ez / self.cap**2
        gn = np.maximum(np.hypot(gx, gz), 1e-15)
        g_ell = np.stack([gx / gn, gz / gn], axis=1)
        d_half = self.base - pz
        use_half = d_half > d_ell
        d_cap = np.where(use_half, d_half, d_ell)
        g_cap = np.where(use_half[:, None], np.array([0.0, -1.0]), g_ell)
        use_rect = d_rect < d_cap
        d2 = np.where(use_rect, d_rect, d_cap)
        g2 = np.where(use_rect[:, None], g_rect, g_cap)
        return _extrude_sdf(d2, g2, x[:, 1], 0.5 * self.width)


@dataclass
class ConvexSolid(Solid):
    """The convex hull of ``vertices`` (K, 3) (world frame; ``R``, ``p`` the identity): a rebuilt work piece part.

    Its faces are the half-spaces ``n·x + d <= 0`` of the hull; the signed distance is the largest ``n·x + d``:
    exact inside and over each face, a lower bound beyond the edges and corners (the contact happens over a
    face).
    """

    vertices: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))

    def __post_init__(self) -> None:
        from scipy.spatial import ConvexHull

        self.equations = ConvexHull(self.vertices).equations  # (F, 4): unit outward normal, offset

    def _sdf_local(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        heights = x @ self.equations[:, :3].T + self.equations[:, 3]
        face = np.argmax(heights, axis=1)
        return heights[np.arange(x.shape[0]), face], self.equations[face, :3]


@dataclass
class SurfaceQuery:
    """The nearest surface to points: distance (N,), outward normal (N, 3), solid name per point."""

    distance: NDArray[np.float64]
    normal: NDArray[np.float64]
    name: list[str]


class WorldGeometry:
    """Exact shapes of a ``WorldConfig`` (no PyBullet): table, ramp, cylinder, block and work pieces as solids."""

    def __init__(self, config: WorldConfig):
        self.config = config
        table, ramp, cylinder, block = config.table, config.ramp, config.cylinder, config.block
        self.table_R = matrix_from_axis_angle(table.tilt_axis, math.radians(table.tilt_deg))
        self.table_origin = np.array([table.center_xy[0], table.center_xy[1], table.height_m])
        self.solids: dict[str, Solid] = {}
        half = np.array([0.5 * table.size_xy[0], 0.5 * table.size_xy[1], 0.5 * table.thickness_m])
        if table.enabled:
            self.solids["table"] = BoxSolid(
                "table", self.table_R, self.table_origin - self.table_R @ np.array([0.0, 0.0, half[2]]), half
            )
        if ramp.enabled:
            buried = 0.05
            R = self.table_R @ matrix_from_axis_angle((0.0, 1.0, 0.0), -math.radians(ramp.tilt_deg))
            half_r = np.array([0.5 * (ramp.length_m + buried), half[1], 0.5 * ramp.thickness_m])
            crease = self.table_point(ramp.crease_x_m, 0.0)
            centre = crease - R @ np.array([-half_r[0] + buried, 0.0, half_r[2]])
            self.solids["ramp"] = BoxSolid("ramp", R, centre, half_r)
        if cylinder.enabled:
            R = self.table_R @ matrix_from_axis_angle((0.0, 0.0, 1.0), math.radians(cylinder.yaw_deg))
            centre = (
                self.table_point(*cylinder.xy_m) + self.table_normal * cylinder.radius_m + np.asarray(cylinder.offset_m)
            )
            self.solids["cylinder"] = CylinderSolid(
                "cylinder", R, centre, radius=cylinder.radius_m, length=cylinder.length_m
            )
        if block.enabled:
            R = self.table_R @ matrix_from_axis_angle((0.0, 0.0, 1.0), math.radians(block.yaw_deg))
            origin = self.table_point(*block.xy_m) + np.asarray(block.offset_m)
            self.solids["block"] = CurvedBlockSolid(
                "block",
                R,
                origin,
                a=block.half_length_m,
                cap=block.cap_height_m,
                base=block.base_height_m,
                width=block.width_m,
            )
        pieces = config.work_pieces
        for name, piece in zip(self.work_piece_names() if pieces else [], pieces, strict=True):
            self.solids[name] = ConvexSolid(name, np.eye(3), np.zeros(3), np.asarray(piece.vertices, dtype=float))
        if any(config.work_piece_tilt.deg):
            self._tilt_work_piece()

    def work_piece_names(self) -> list[str]:
        """The solids that make the work piece (what an offset or a tilt moves): the rebuilt pieces if any, else the
        contour objects if any, else the table and its ramp (as ``sim_worker.executor.shifted_world_config``)."""
        c = self.config
        if c.work_pieces:
            return [p.name or f"work_piece_{k}" for k, p in enumerate(c.work_pieces)]
        contour = [n for n in ("cylinder", "block") if n in self.solids]
        return contour or [n for n in ("table", "ramp") if n in self.solids]

    def _tilt_work_piece(self) -> None:
        """Rotate the work piece's solids about world x then world y by ``work_piece_tilt.deg`` through
        ``work_piece_tilt.pivot_m``: ``x' = R (x - pivot) + pivot``."""
        tx, ty = (math.radians(a) for a in self.config.work_piece_tilt.deg)
        R = matrix_from_axis_angle((0.0, 1.0, 0.0), ty) @ matrix_from_axis_angle((1.0, 0.0, 0.0), tx)
        pivot = np.asarray(self.config.work_piece_tilt.pivot_m, dtype=float)
        for name in self.work_piece_names():
            solid = self.solids[name]
            solid.R = R @ solid.R
            solid.p = R @ (solid.p - pivot) + pivot

    @property
    def table_normal(self) -> NDArray[np.float64]:
        """Outward (up) unit normal of the table top."""
        return self.table_R[:, 2].copy()

    def table_point(self, x: float, y: float) -> NDArray[np.float64]:
        """World point of the table top at table-frame coordinates ``(x, y)`` (relative to the table centre)."""
        return self.table_origin + self.table_R @ np.array([x, y, 0.0])

    @property
    def ramp_normal(self) -> NDArray[np.float64]:
        """Outward unit normal of the ramp top (requires ``ramp.enabled``)."""
        return self.solids["ramp"].R[:, 2].copy()

    def ramp_point(self, s: float, y: float) -> NDArray[np.float64]:
        """World point on the ramp top ``s`` m up the slope from the crease, ``y`` along the crease."""
        ramp = self.solids["ramp"]
        crease = self.table_point(self.config.ramp.crease_x_m, 0.0)
        return crease + ramp.R @ np.array([s, y, 0.0])

    def query(self, points: ArrayLike) -> SurfaceQuery:
        """Nearest surface of the union of all solids to ``points`` (3,) or (N, 3)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        best_d = np.full(pts.shape[0], np.inf)
        best_n = np.zeros((pts.shape[0], 3))
        best_name = np.array([""] * pts.shape[0], dtype=object)
        for name, solid in self.solids.items():
            d, n = solid.signed_distance(pts)
            better = d < best_d
            best_d[better] = d[better]
            best_n[better] = n[better]
            best_name[better] = name
        return SurfaceQuery(best_d, best_n, list(best_name))

    def surface_normal_at(self, points: ArrayLike) -> NDArray[np.float64]:
        """Outward unit normal of the nearest surface: (3,) for one point, (N, 3) for N points."""
        n = self.query(points).normal
        return n[0] if np.asarray(points).ndim == 1 else n

    def signed_distance(self, points: ArrayLike) -> NDArray[np.float64] | float:
        """Signed distance (m) of points to the union of all solids (negative inside)."""
        d = self.query(points).distance
        return float(d[0]) if np.asarray(points).ndim == 1 else d
