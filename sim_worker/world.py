"""The simulated world: a KUKA LBR iiwa with a ball-tipped tool, a table (tiltable, with an optional ramp)
and contour objects (a cylinder lying on the table, a curved block), in PyBullet at 1 kHz.

Conventions (DESIGN.md): SI units, world frame, quaternions ``[x, y, z, w]``, 6-vectors
``[x, y, z, rx, ry, rz]``; the contact wrench is the wrench the TOOL APPLIES TO THE ENVIRONMENT,
at the tool point, in the world frame.

Tool and tool point
    A rigid tool is part of the robot URDF, built at run time: a shaft (radius 8 mm, 70 mm long)
    on the iiwa flange (45 mm beyond the link-7 frame) ending in a ball of radius
    ``WorldConfig.tool_radius_m`` (10 mm). It is a separate link (``tool_link``, index 7) on a FIXED
    joint, so it has an exact link frame and Jacobian. The TOOL POINT (the origin of that link frame)
    is the ball's lowest point along the tool axis, i.e. ball centre + radius along the tool's z axis,
    125 mm from the link-7 frame. The tool frame's z axis points out of the flange, along the tool:
    when the tool is held perpendicular to a surface, the tool point is the contact point and the tool
    z axis points INTO the surface, along the force the tool applies (like the compliant frame).

Contact model
    Rigid PyBullet contact at 1 kHz chatters (0-50 N around a 15 N target), so the tool link is made
    compliant: ``contactStiffness = 3e4 N/m, contactDamping = 300 N·s/m`` (a stiff polishing pad; at 15 N
    the pad compresses 0.5 mm; DESIGN.md measured 15 N ± 0.7 N at 1 kHz). Bullet combines the friction
    coefficients of the two bodies by product: the environment bodies get ``lateralFriction = 1`` and the
    tool ``WorldConfig.lateral_friction`` (0.2), so every tool contact has μ = 0.2. Rolling and spinning
    friction are zero.

Torque control
    The default velocity motors are disabled once (``VELOCITY_CONTROL``, force 0); ``step()`` sends
    ``TORQUE_CONTROL`` before every ``stepSimulation``. The URDF joint damping (0.5 N·m·s/rad) and the
    default link damping (0.04) are zeroed, so ``gravity_coriolis_torques()`` alone holds the arm still.
    Torques are clipped to the iiwa 14 limits ``TORQUE_LIMITS_NM`` (320, 320, 176, 176, 110, 40, 40 N·m);
    ``last_step_clipped`` says whether the last ``step()`` clipped. Joint limits are NOT enforced by
    PyBullet in torque mode (the executor checks them).

Measured PyBullet 3.2.7 facts this module relies on
    - ``calculateJacobian``'s ``localPosition`` is relative to the URDF LINK frame (not the COM frame the docs
      name): with ``[0, 0, 0]`` the Jacobian matches finite differences of the tool point to 1e-7.
    - ``getLinkState``'s link-frame pose (entries 4, 5) is float32; the COM pose (0, 1) is double, so the tool
      pose is computed from the COM frame and the known inertial offset (finite differences need it).
    - ``getContactPoints`` with the tool as body A: ``contactNormalOnB`` points from the environment to the
      tool, and ``lateralFriction1/2`` along ``lateralFrictionDir1/2`` are forces ON THE TOOL too; the
      applied wrench is minus their sum.
    - The multibody solver uses fixed friction directions with a circular friction cone: while sliding
      the friction magnitude is exactly μ·N, but its direction can be ~15° off the slip direction
      (depends on the arm's mobility); the normal part is exact (``contact_forces()`` separates them).
    - Explicit damping must respect the light wrist: joint 7 + tool have ~1e-3 kg·m², so a Cartesian
      rotational damping of 3 N·m·s/rad is unstable at 1 kHz (D·dt/I > 2); 0.3 N·m·s/rad is fine.

Geometry for ground truth
    ``WorldGeometry`` (pure numpy, no PyBullet) holds the exact shapes: each object is a convex solid
    with an exact signed distance; the world is their union, so outside the objects the distance to the
    world is the minimum over the objects and the outward normal is that of the nearest one.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from typing import Any, NamedTuple

import numpy as np
import pybullet
import pybullet_data
from numpy.typing import ArrayLike, NDArray

N_JOINTS = 7
TOOL_LINK = 7
"""Link index of the tool (fixed joint on link 7); its frame origin is the tool point."""

TORQUE_LIMITS_NM = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)
"""Joint torque limits of the KUKA LBR iiwa 14 R820 (N·m), joints 1-7."""

FLANGE_OFFSET_M = 0.045
"""Distance of the iiwa flange from the link-7 frame along its z axis (the link-7 mesh ends there)."""

Q_HOME = (0.0, 0.5325, 0.0, -1.6083, 0.0, 1.0008, 0.0)
"""Home posture (rad): tool pointing straight down (tool x = -world x), tool point at (0.55, 0, 0.30) m."""

CONTACT_DISTANCE_M = 0.0
"""A contact point counts as contact when its distance is at or below this (m) or it carries force."""


@dataclass
class RobotState:
    """A snapshot of the robot for a controller: joints, tool pose, Jacobian at the tool point, twist, gravity."""

    q: NDArray[np.float64]
    qd: NDArray[np.float64]
    position: NDArray[np.float64]
    quat: NDArray[np.float64]
    rotation: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    twist: NDArray[np.float64]
    gravity_coriolis: NDArray[np.float64]


class Sensing(NamedTuple):
    """One step's measurements for a control loop (:meth:`SimWorld.sense`).

    The world's cached arrays of the current step, NOT copies (a 1 kHz loop cannot afford the copies):
    treat them as read-only; the next ``step()`` replaces them. ``q``, ``qd`` (7,) rad, rad/s;
    ``position`` (3,) and ``quat`` (4,) ``[x, y, z, w]`` the tool pose; ``wrench`` (6,) as
    :meth:`SimWorld.contact_wrench`; ``in_contact`` as :meth:`SimWorld.in_contact`.
    """

    q: NDArray[np.float64]
    qd: NDArray[np.float64]
    position: NDArray[np.float64]
    quat: NDArray[np.float64]
    wrench: NDArray[np.float64]
    in_contact: bool


class Dynamics(NamedTuple):
    """One step's model queries for a control loop (:meth:`SimWorld.dynamics`); cached arrays, read-only as
    :class:`Sensing`: ``jacobian`` (6, 7) of the tool point, ``gravity_coriolis`` (7,) N·m, ``mass_matrix``
    (7, 7) or None when not asked for."""

    jacobian: NDArray[np.float64]
    gravity_coriolis: NDArray[np.float64]
    mass_matrix: NDArray[np.float64] | None


def _rotation_about(axis: ArrayLike, angle_rad: float) -> NDArray[np.float64]:
    """Rotation matrix of ``angle_rad`` about the unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * K + (1.0 - math.cos(angle_rad)) * (K @ K)


def _quat_from_matrix(R: NDArray[np.float64]) -> list[float]:
    """Scalar-last quaternion of a rotation matrix (via PyBullet-free Shepperd's method)."""
    from skills.quaternions import quaternion_from_matrix

    return quaternion_from_matrix(R).tolist()


@dataclass
class WorldConfig:
    """Everything that defines a world; JSON-able via ``to_dict`` / ``from_dict``.

    The table top is a plane through ``(table_center_xy, table_height_m)``, tilted by ``table_tilt_deg``
    about the horizontal ``table_tilt_axis`` through that point. The ramp (the second plane) starts at a
    crease line on the table top, parallel to the table's y axis at table-x ``ramp_crease_x_m`` (relative to
    the table centre), and rises towards +x by ``ramp_tilt_deg`` relative to the table. The cylinder and the
    curved block lie on the table top at table-frame ``(x, y)`` positions, turned by a yaw about the table
    normal; their ``*_offset_m`` shifts them (world frame) away from lying on the table, e.g. to move a
    contour object for execution.
    """

    time_step_s: float = 1e-3
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    # Table: a box, top surface through (center, height).
    table_height_m: float = 0.10
    table_center_xy: tuple[float, float] = (0.60, 0.0)
    table_size_xy: tuple[float, float] = (0.60, 0.80)
    table_thickness_m: float = 0.04
    table_tilt_deg: float = 0.0
    table_tilt_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    # Ramp: the second plane ("two planes" scenario).
    ramp_enabled: bool = False
    ramp_tilt_deg: float = 20.0
    ramp_crease_x_m: float = 0.0
    ramp_length_m: float = 0.20
    ramp_thickness_m: float = 0.04
    # Cylinder lying on the table, axis along the table y axis turned by the yaw.
    cylinder_enabled: bool = False
    cylinder_radius_m: float = 0.08
    cylinder_length_m: float = 0.30
    cylinder_xy_m: tuple[float, float] = (0.0, 0.0)
    cylinder_yaw_deg: float = 0.0
    cylinder_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Curved block: a base slab of height block_base_height_m capped by a half-ellipse of semi-axes
    # (block_half_length_m along the block x, block_cap_height_m up), extruded over block_width_m.
    block_enabled: bool = False
    block_half_length_m: float = 0.15
    block_cap_height_m: float = 0.06
    block_base_height_m: float = 0.02
    block_width_m: float = 0.16
    block_xy_m: tuple[float, float] = (0.0, 0.0)
    block_yaw_deg: float = 0.0
    block_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    block_mesh_segments: int = 180
    # Contact model and tool.
    contact_stiffness: float = 3.0e4
    contact_damping: float = 300.0
    lateral_friction: float = 0.2
    tool_radius_m: float = 0.010
    tool_shaft_length_m: float = 0.070
    tool_shaft_radius_m: float = 0.008
    tool_mass_kg: float = 0.2
    # Robot.
    torque_limits_nm: tuple[float, ...] = TORQUE_LIMITS_NM
    # Wrench sensor model (both off by default).
    wrench_noise_force_std_n: float = 0.0
    wrench_noise_torque_std_nm: float = 0.0
    wrench_filter_cutoff_hz: float | None = None
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples become lists)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WorldConfig:
        """Inverse of ``to_dict``; unknown keys raise ``TypeError``."""
        kwargs = {}
        for f in fields(cls):
            if f.name in data:
                value = data[f.name]
                kwargs[f.name] = tuple(value) if isinstance(value, list) else value
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise TypeError(f"unknown WorldConfig fields: {sorted(unknown)}")
        return cls(**kwargs)

    def replace(self, **changes: Any) -> WorldConfig:
        """A copy with ``changes`` applied."""
        data = self.to_dict()
        data.update(changes)
        return WorldConfig.from_dict(data)


# ---------------------------------------------------------------------------------------------------------------
# Exact geometry (numpy only): convex solids with signed distance and outward normal.
# ---------------------------------------------------------------------------------------------------------------


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
    """A finite cylinder, axis = body y axis through ``p``, of ``radius`` and ``length``."""

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
class SurfaceQuery:
    """The nearest surface to points: distance (N,), outward normal (N, 3), solid name per point."""

    distance: NDArray[np.float64]
    normal: NDArray[np.float64]
    name: list[str]


class WorldGeometry:
    """Exact shapes of a ``WorldConfig`` (no PyBullet): the table, ramp, cylinder and block as convex solids."""

    def __init__(self, config: WorldConfig):
        c = config
        self.config = c
        self.table_R = _rotation_about(c.table_tilt_axis, math.radians(c.table_tilt_deg))
        self.table_origin = np.array([c.table_center_xy[0], c.table_center_xy[1], c.table_height_m])
        self.solids: dict[str, Solid] = {}
        half = np.array([0.5 * c.table_size_xy[0], 0.5 * c.table_size_xy[1], 0.5 * c.table_thickness_m])
        self.solids["table"] = BoxSolid(
            "table", self.table_R, self.table_origin - self.table_R @ np.array([0.0, 0.0, half[2]]), half
        )
        if c.ramp_enabled:
            buried = 0.05
            R = self.table_R @ _rotation_about((0.0, 1.0, 0.0), -math.radians(c.ramp_tilt_deg))
            half_r = np.array([0.5 * (c.ramp_length_m + buried), half[1], 0.5 * c.ramp_thickness_m])
            crease = self.table_point(c.ramp_crease_x_m, 0.0)
            centre = crease - R @ np.array([-half_r[0] + buried, 0.0, half_r[2]])
            self.solids["ramp"] = BoxSolid("ramp", R, centre, half_r)
        if c.cylinder_enabled:
            R = self.table_R @ _rotation_about((0.0, 0.0, 1.0), math.radians(c.cylinder_yaw_deg))
            centre = (
                self.table_point(*c.cylinder_xy_m)
                + self.table_normal * c.cylinder_radius_m
                + np.asarray(c.cylinder_offset_m)
            )
            self.solids["cylinder"] = CylinderSolid(
                "cylinder", R, centre, radius=c.cylinder_radius_m, length=c.cylinder_length_m
            )
        if c.block_enabled:
            R = self.table_R @ _rotation_about((0.0, 0.0, 1.0), math.radians(c.block_yaw_deg))
            origin = self.table_point(*c.block_xy_m) + np.asarray(c.block_offset_m)
            self.solids["block"] = CurvedBlockSolid(
                "block",
                R,
                origin,
                a=c.block_half_length_m,
                cap=c.block_cap_height_m,
                base=c.block_base_height_m,
                width=c.block_width_m,
            )

    @property
    def table_normal(self) -> NDArray[np.float64]:
        """Outward (up) unit normal of the table top."""
        return self.table_R[:, 2].copy()

    def table_point(self, x: float, y: float) -> NDArray[np.float64]:
        """World point of the table top at table-frame coordinates ``(x, y)`` (relative to the table centre)."""
        return self.table_origin + self.table_R @ np.array([x, y, 0.0])

    @property
    def ramp_normal(self) -> NDArray[np.float64]:
        """Outward unit normal of the ramp top (requires ``ramp_enabled``)."""
        return self.solids["ramp"].R[:, 2].copy()

    def ramp_point(self, s: float, y: float) -> NDArray[np.float64]:
        """World point on the ramp top ``s`` m up the slope from the crease, ``y`` along the crease."""
        ramp = self.solids["ramp"]
        crease = self.table_point(self.config.ramp_crease_x_m, 0.0)
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


# ---------------------------------------------------------------------------------------------------------------
# The PyBullet world.
# ---------------------------------------------------------------------------------------------------------------


def _robot_urdf(config: WorldConfig) -> str:
    """The iiwa URDF with absolute mesh paths and the tool link appended on a fixed joint."""
    data = pybullet_data.getDataPath()
    with open(os.path.join(data, "kuka_iiwa", "model.urdf"), encoding="utf-8") as handle:
        text = handle.read()
    text = text.replace('filename="meshes/', f'filename="{os.path.join(data, "kuka_iiwa", "meshes")}/')
    r = config.tool_radius_m
    L = config.tool_shaft_length_m
    rs = config.tool_shaft_radius_m
    m = config.tool_mass_kg
    tip = FLANGE_OFFSET_M + L + r  # link-7 frame to tool point
    com = -(0.5 * L + r)  # shaft centre in the tool frame
    ixx = m * (3 * rs * rs + L * L) / 12.0
    izz = 0.5 * m * rs * rs
    tool = f"""
  <joint name="tool_joint" type="fixed">
    <parent link="lbr_iiwa_link_7"/>
    <child link="tool_link"/>
    <origin rpy="0 0 0" xyz="0 0 {tip:.6f}"/>
  </joint>
  <link name="tool_link">
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 {com:.6f}"/>
      <mass value="{m:.6f}"/>
      <inertia ixx="{ixx:.8f}" ixy="0" ixz="0" iyy="{ixx:.8f}" iyz="0" izz="{izz:.8f}"/>
    </inertial>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 {-(r + 0.5 * L):.6f}"/>
      <geometry><cylinder radius="{rs:.6f}" length="{L:.6f}"/></geometry>
      <material name="Grey"/>
    </visual>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 {-r:.6f}"/>
      <geometry><sphere radius="{r:.6f}"/></geometry>
      <material name="Orange"/>
    </visual>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {-(r + 0.5 * L):.6f}"/>
      <geometry><cylinder radius="{rs:.6f}" length="{L:.6f}"/></geometry>
    </collision>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {-r:.6f}"/>
      <geometry><sphere radius="{r:.6f}"/></geometry>
    </collision>
  </link>
"""
    return text.replace("</robot>", tool + "</robot>")


class SimWorld:
    """One PyBullet DIRECT world (own client): iiwa + tool, table, optional ramp, cylinder and block.

    Several worlds can live in one process; call ``close()`` (or use ``with``) to free the client.
    State queries are cached until the next ``step()``/``set_joint_positions()``/``reset()``; the accessors
    return copies, ``sense()`` and ``dynamics()`` (for a control loop) the cached arrays themselves.
    """

    def __init__(self, config: WorldConfig | None = None):
        self.config = config or WorldConfig()
        self.geometry = WorldGeometry(self.config)
        c = self.config
        self._cid = pybullet.connect(pybullet.DIRECT)
        cid = self._cid
        pybullet.setGravity(*c.gravity, physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            fixedTimeStep=c.time_step_s, numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=cid
        )
        urdf = _robot_urdf(c)
        fd, path = tempfile.mkstemp(suffix=".urdf", prefix="iiwa_tool_")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as handle:
                handle.write(urdf)
            self.robot = pybullet.loadURDF(
                path, useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid
            )
        finally:
            os.unlink(path)
        self._joints = list(range(N_JOINTS))
        info = [pybullet.getJointInfo(self.robot, j, physicsClientId=cid) for j in self._joints]
        self.joint_lower = np.array([i[8] for i in info])
        self.joint_upper = np.array([i[9] for i in info])
        for link in range(-1, TOOL_LINK + 1):
            pybullet.changeDynamics(
                self.robot, link, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0, physicsClientId=cid
            )
        pybullet.changeDynamics(
            self.robot,
            TOOL_LINK,
            contactStiffness=c.contact_stiffness,
            contactDamping=c.contact_damping,
            lateralFriction=c.lateral_friction,
            rollingFriction=0.0,
            spinningFriction=0.0,
            physicsClientId=cid,
        )
        pybullet.setJointMotorControlArray(
            self.robot, self._joints, pybullet.VELOCITY_CONTROL, forces=[0.0] * N_JOINTS, physicsClientId=cid
        )
        self.torque_limits = np.asarray(c.torque_limits_nm, dtype=float)
        self._torque_limits_list = self.torque_limits.tolist()
        # calculateJacobian's localPosition is measured (pybullet 3.2.7) relative to the URDF LINK frame, not the
        # COM frame as documented; the tool point is that frame's origin. getLinkState's link-frame pose is float32,
        # so the tool pose is computed in double precision from the COM frame and the inertial offset.
        self._tool_point_in_link = [0.0, 0.0, 0.0]
        dyn = pybullet.getDynamicsInfo(self.robot, TOOL_LINK, physicsClientId=cid)
        R_inertial = np.asarray(pybullet.getMatrixFromQuaternion(dyn[4])).reshape(3, 3)
        self._link_in_com_R = R_inertial.T  # link frame orientation in the COM frame
        self._link_origin_in_com = tuple((-R_inertial.T @ np.asarray(dyn[3])).tolist())  # link origin, COM frame
        self._identity_inertial = bool(np.allclose(R_inertial, np.eye(3)))
        self.bodies: dict[str, int] = {}
        self._build_environment()
        self._zeros = [0.0] * N_JOINTS
        self._rng = np.random.default_rng(c.seed)
        self.last_step_clipped = False
        self.clip_count = 0
        self.step_count = 0
        self._version = 0
        self._cache: dict[str, Any] = {}
        self._filtered: NDArray[np.float64] | None = None
        self.reset()

    # -- construction --------------------------------------------------------------------------------------------

    def _static_body(self, name: str, shape: int, visual: int, R: NDArray[np.float64], p: NDArray[np.float64]):
        body = pybullet.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=shape,
            baseVisualShapeIndex=visual,
            basePosition=p.tolist(),
            baseOrientation=_quat_from_matrix(R),
            physicsClientId=self._cid,
        )
        pybullet.changeDynamics(
            body, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0, physicsClientId=self._cid
        )
        self.bodies[name] = body

    def _build_environment(self) -> None:
        cid = self._cid
        for name, solid in self.geometry.solids.items():
            if isinstance(solid, BoxSolid):
                shape = pybullet.createCollisionShape(
                    pybullet.GEOM_BOX, halfExtents=solid.half.tolist(), physicsClientId=cid
                )
                visual = pybullet.createVisualShape(
                    pybullet.GEOM_BOX,
                    halfExtents=solid.half.tolist(),
                    rgbaColor=[0.6, 0.5, 0.4, 1],
                    physicsClientId=cid,
                )
                self._static_body(name, shape, visual, solid.R, solid.p)
            elif isinstance(solid, CylinderSolid):
                # PyBullet cylinders lie along their local z; ours along the body y axis.
                R = solid.R @ _rotation_about((1.0, 0.0, 0.0), -math.pi / 2)
                shape = pybullet.createCollisionShape(
                    pybullet.GEOM_CYLINDER, radius=solid.radius, height=solid.length, physicsClientId=cid
                )
                visual = pybullet.createVisualShape(
                    pybullet.GEOM_CYLINDER,
                    radius=solid.radius,
                    length=solid.length,
                    rgbaColor=[0.3, 0.5, 0.8, 1],
                    physicsClientId=cid,
                )
                self._static_body(name, shape, visual, R, solid.p)
            elif isinstance(solid, CurvedBlockSolid):
                vertices = self._block_vertices(solid)
                shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices, physicsClientId=cid)
                visual = pybullet.createVisualShape(
                    pybullet.GEOM_MESH,
                    vertices=vertices,
                    indices=self._block_indices(solid),
                    rgbaColor=[0.4, 0.7, 0.4, 1],
                    physicsClientId=cid,
                )
                self._static_body(name, shape, visual, solid.R, solid.p)

    def _block_profile(self, solid: CurvedBlockSolid) -> NDArray[np.float64]:
        phi = np.linspace(0.0, math.pi, self.config.block_mesh_segments + 1)
        x, z = solid.profile_point(phi)
        return np.concatenate([np.stack([x, z], axis=1), [[-solid.a, 0.0], [solid.a, 0.0]]])

    def _block_vertices(self, solid: CurvedBlockSolid) -> list[list[float]]:
        prof = self._block_profile(solid)
        w = 0.5 * solid.width
        return [[x, y, z] for y in (-w, w) for x, z in prof]

    def _block_indices(self, solid: CurvedBlockSolid) -> list[int]:
        n = self._block_profile(solid).shape[0]
        idx: list[int] = []
        for i in range(n):  # sides between consecutive profile points (closed polygon)
            j = (i + 1) % n
            idx += [i, j, n + j, i, n + j, n + i]
        for i in range(1, n - 1):  # end caps (fan)
            idx += [0, i + 1, i, n, n + i, n + i + 1]
        return idx

    # -- lifecycle -----------------------------------------------------------------------------------------------

    @property
    def client_id(self) -> int:
        """The PyBullet physics client id of this world."""
        return self._cid

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self._cid is not None and self._cid >= 0:
            with contextlib.suppress(pybullet.error):
                pybullet.disconnect(physicsClientId=self._cid)
            self._cid = -1

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def _invalidate(self) -> None:
        self._version += 1
        self._cache.clear()

    def reset(self, q: ArrayLike | None = None) -> None:
        """Set the joints to ``q`` (default ``Q_HOME``: tool pointing down above the table) at rest."""
        self.set_joint_positions(Q_HOME if q is None else q)
        self._filtered = None
        self.last_step_clipped = False
        self.clip_count = 0
        self.step_count = 0

    def set_joint_positions(self, q: ArrayLike, qd: ArrayLike | None = None) -> None:
        """Teleport the joints to ``q`` with velocities ``qd`` (default zero)."""
        q = np.asarray(q, dtype=float)
        qd = np.zeros(N_JOINTS) if qd is None else np.asarray(qd, dtype=float)
        for j in self._joints:
            pybullet.resetJointState(self.robot, j, float(q[j]), float(qd[j]), physicsClientId=self._cid)
        self._invalidate()

    # -- state ---------------------------------------------------------------------------------------------------

    def _joints_raw(self) -> tuple[list[float], list[float], NDArray[np.float64], NDArray[np.float64]]:
        cached = self._cache.get("joints")
        if cached is None:
            states = pybullet.getJointStates(self.robot, self._joints, physicsClientId=self._cid)
            q = [s[0] for s in states]
            qd = [s[1] for s in states]
            cached = self._cache["joints"] = (q, qd, np.array(q), np.array(qd))
        return cached

    def joint_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Joint positions (rad) and velocities (rad/s), shape (7,) each."""
        cached = self._joints_raw()
        return cached[2].copy(), cached[3].copy()

    def _com_frame(self) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """The tool link's COM frame in double precision: position, quaternion, rotation matrix (9 floats, by rows)."""
        cached = self._cache.get("com")
        if cached is None:
            state = pybullet.getLinkState(self.robot, TOOL_LINK, computeForwardKinematics=1, physicsClientId=self._cid)
            cached = self._cache["com"] = (state[0], state[1], pybullet.getMatrixFromQuaternion(state[1]))
        return cached

    def _pose_raw(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool point position and tool quaternion: the link origin ``c + R_com o`` (plain floats: numpy costs more
        than it computes on 3-vectors) and, for the usual identity inertial frame, the COM quaternion as is."""
        cached = self._cache.get("pose")
        if cached is None:
            (cx, cy, cz), quat_com, r = self._com_frame()
            ox, oy, oz = self._link_origin_in_com
            p = np.array(
                [
                    cx + (r[0] * ox + r[1] * oy + r[2] * oz),
                    cy + (r[3] * ox + r[4] * oy + r[5] * oz),
                    cz + (r[6] * ox + r[7] * oy + r[8] * oz),
                ]
            )
            if self._identity_inertial:
                quat = np.array(quat_com)
            else:
                quat = np.asarray(_quat_from_matrix(self._rotation_raw()))
            cached = self._cache["pose"] = (p, quat)
        return cached

    def _rotation_raw(self) -> NDArray[np.float64]:
        cached = self._cache.get("rotation")
        if cached is None:
            R_com = np.array(self._com_frame()[2]).reshape(3, 3)
            cached = self._cache["rotation"] = R_com if self._identity_inertial else R_com @ self._link_in_com_R
        return cached

    def tool_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool point position (3,) and tool orientation quaternion ``[x, y, z, w]`` (4,) in world."""
        cached = self._pose_raw()
        return cached[0].copy(), cached[1].copy()

    def tool_rotation(self) -> NDArray[np.float64]:
        """Tool orientation as a (3, 3) rotation matrix (tool frame into world)."""
        return self._rotation_raw().copy()

    def _jacobian_raw(self) -> NDArray[np.float64]:
        cached = self._cache.get("jacobian")
        if cached is None:
            q = self._joints_raw()[0]
            lin, ang = pybullet.calculateJacobian(
                self.robot,
                TOOL_LINK,
                self._tool_point_in_link,
                q,
                self._zeros,
                self._zeros,
                physicsClientId=self._cid,
            )
            cached = self._cache["jacobian"] = np.array(lin + ang)
        return cached

    def jacobian(self) -> NDArray[np.float64]:
        """Geometric Jacobian (6, 7) of the tool point in world: ``[v; ω] = J qd``."""
        return self._jacobian_raw().copy()

    def tool_twist(self) -> NDArray[np.float64]:
        """Tool point twist ``[v, ω]`` (6,) in world (m/s, rad/s)."""
        return self._jacobian_raw() @ self._joints_raw()[3]

    def _gravity_coriolis_raw(self) -> NDArray[np.float64]:
        cached = self._cache.get("gc")
        if cached is None:
            q, qd, _, _ = self._joints_raw()
            cached = self._cache["gc"] = np.array(
                pybullet.calculateInverseDynamics(self.robot, q, qd, self._zeros, physicsClientId=self._cid)
            )
        return cached

    def gravity_coriolis_torques(self) -> NDArray[np.float64]:
        """Joint torques (7,) that cancel gravity and Coriolis/centrifugal terms (inverse dynamics, qdd = 0)."""
        return self._gravity_coriolis_raw().copy()

    def _mass_matrix_raw(self) -> NDArray[np.float64]:
        cached = self._cache.get("mass")
        if cached is None:
            q = self._joints_raw()[0]
            cached = self._cache["mass"] = np.array(
                pybullet.calculateMassMatrix(self.robot, q, physicsClientId=self._cid)
            )
        return cached

    def mass_matrix(self) -> NDArray[np.float64]:
        """Joint-space mass matrix (7, 7)."""
        return self._mass_matrix_raw().copy()

    def sense(self) -> Sensing:
        """Joint state, tool pose, measured wrench and contact flag of this step in one call, without copies.

        For a control loop: one PyBullet query each (shared with the other accessors' caches), the arrays
        returned as cached (read-only by contract, see :class:`Sensing`).
        """
        _, _, q, qd = self._joints_raw()
        p, quat = self._pose_raw()
        return Sensing(q, qd, p, quat, self._measured_wrench(), self._contact_summary()[1])

    def dynamics(self, with_mass_matrix: bool = False) -> Dynamics:
        """Jacobian, gravity/Coriolis torques and (if asked) the mass matrix of this step, without copies.

        The model queries of a control loop, as :meth:`sense`: cached arrays, read-only by contract.
        """
        return Dynamics(
            self._jacobian_raw(),
            self._gravity_coriolis_raw(),
            self._mass_matrix_raw() if with_mass_matrix else None,
        )

    def read_state(self) -> RobotState:
        """Everything a controller reads in one call (one PyBullet query each, shared caches)."""
        _, _, q_arr, qd_arr = self._joints_raw()
        p, quat = self._pose_raw()
        R = self._rotation_raw()
        J = self._jacobian_raw()
        return RobotState(
            q=q_arr.copy(),
            qd=qd_arr.copy(),
            position=p.copy(),
            quat=quat.copy(),
            rotation=R.copy(),
            jacobian=J.copy(),
            twist=J @ qd_arr,
            gravity_coriolis=self.gravity_coriolis_torques(),
        )

    # -- stepping ------------------------------------------------------------------------------------------------

    def step(self, torque: ArrayLike) -> None:
        """Apply joint torques (7,) for one time step: clip to the limits, TORQUE_CONTROL, stepSimulation.

        Sets ``last_step_clipped`` (and counts ``clip_count``) when any torque was clipped.
        """
        tau = np.asarray(torque, dtype=float)
        forces = tau.tolist()
        clipped = any(abs(f) > limit for f, limit in zip(forces, self._torque_limits_list, strict=True))
        if clipped:
            limits = self.torque_limits
            forces = np.clip(tau, -limits, limits).tolist()
            self.clip_count += 1
        self.last_step_clipped = clipped
        pybullet.setJointMotorControlArray(
            self.robot, self._joints, pybullet.TORQUE_CONTROL, forces=forces, physicsClientId=self._cid
        )
        pybullet.stepSimulation(physicsClientId=self._cid)
        self.step_count += 1
        self._invalidate()
        if self.config.wrench_filter_cutoff_hz is not None:
            self._update_filter()

    # -- contact -------------------------------------------------------------------------------------------------

    def _contact_points(self) -> list:
        cached = self._cache.get("contacts")
        if cached is None:
            cached = self._cache["contacts"] = pybullet.getContactPoints(
                bodyA=self.robot, linkIndexA=TOOL_LINK, physicsClientId=self._cid
            )
        return cached

    def in_contact(self) -> bool:
        """Whether the tool touches anything (a contact point at zero or negative distance, or carrying force)."""
        return self._contact_summary()[1]

    def contacts(self) -> list[dict[str, Any]]:
        """The tool's contact points: body name, position on the tool, normal force (N), distance (m)."""
        names = {v: k for k, v in self.bodies.items()}
        return [
            {
                "body": names.get(c[2], str(c[2])),
                "position": np.asarray(c[5]),
                "normal_into_environment": -np.asarray(c[7]),
                "normal_force_n": c[9],
                "distance_m": c[8],
            }
            for c in self._contact_points()
        ]

    def true_contact_wrench(self) -> NDArray[np.float64]:
        """Exact wrench (6,) the tool applies to the environment, at the tool point, world frame (no sensor model).

        Sum over the tool's contact points of the normal and both friction forces. PyBullet reports, with the tool
        as body A, ``contactNormalOnB`` pointing from the environment (B) to the tool (A) and the friction forces
        along ``lateralFrictionDir1/2`` as forces on the environment's side, so the force the tool applies is
        ``-normalForce * n_B + f1 * d1 + f2 * d2`` (sign verified by tests: pressing a table gives ``fz < 0``,
        sliding drags the table along the tool velocity). Moments about the tool point from the contact positions.
        """
        return self._contact_summary()[0].copy()

    def _contact_summary(self) -> tuple[NDArray[np.float64], bool]:
        """The exact applied wrench (see :meth:`true_contact_wrench`) and the contact flag, in one pass over the
        contact points (cached until the next step)."""
        cached = self._cache.get("contact")
        if cached is None:
            points = self._contact_points()
            if not points:
                cached = (np.zeros(6), False)
            else:
                px, py, pz = self._pose_raw()[0].tolist()
                fx = fy = fz = mx = my = mz = 0.0
                touching = False
                for c in points:  # plain floats: ~1 µs per contact point instead of ~10 with numpy
                    fn, f1, f2 = c[9], c[10], c[12]
                    n, d1, d2, r = c[7], c[11], c[13], c[5]
                    touching = touching or c[8] <= CONTACT_DISTANCE_M or fn > 0.0
                    ax = -(fn * n[0] + f1 * d1[0] + f2 * d2[0])
                    ay = -(fn * n[1] + f1 * d1[1] + f2 * d2[1])
                    az = -(fn * n[2] + f1 * d1[2] + f2 * d2[2])
                    rx, ry, rz = r[0] - px, r[1] - py, r[2] - pz
                    fx += ax
                    fy += ay
                    fz += az
                    mx += ry * az - rz * ay
                    my += rz * ax - rx * az
                    mz += rx * ay - ry * ax
                cached = (np.array([fx, fy, fz, mx, my, mz]), touching)
            self._cache["contact"] = cached
        return cached

    def contact_forces(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The tool's applied contact force split into its normal part and its friction part (3,) each, world frame.

        Their sum is ``true_contact_wrench()[:3]``. Note: PyBullet's multibody solver uses fixed friction directions
        with a circular cone, so the friction force has magnitude μ·N while sliding but can point up to ~15° away
        from the slip direction (measured here); the normal part is exact.
        """
        normal = np.zeros(3)
        friction = np.zeros(3)
        for c in self._contact_points():
            normal -= c[9] * np.asarray(c[7])
            friction -= c[10] * np.asarray(c[11]) + c[12] * np.asarray(c[13])
        return normal, friction

    def _noise(self) -> NDArray[np.float64]:
        c = self.config
        if c.wrench_noise_force_std_n <= 0.0 and c.wrench_noise_torque_std_nm <= 0.0:
            return np.zeros(6)
        std = np.array([c.wrench_noise_force_std_n] * 3 + [c.wrench_noise_torque_std_nm] * 3)
        return self._rng.normal(0.0, 1.0, 6) * std

    def _update_filter(self) -> None:
        raw = self.true_contact_wrench() + self._noise()
        if self._filtered is None:
            self._filtered = raw
        else:
            dt = self.config.time_step_s
            alpha = dt / (dt + 1.0 / (2.0 * math.pi * self.config.wrench_filter_cutoff_hz))
            self._filtered = self._filtered + alpha * (raw - self._filtered)
        self._cache["measured"] = self._filtered.copy()

    def contact_wrench(self) -> NDArray[np.float64]:
        """Wrench (6,) the tool applies to the environment at the tool point, world frame, as the sensor reports it.

        With the default config (no noise, no filter) this is ``true_contact_wrench()``; otherwise Gaussian noise
        (``wrench_noise_*``) and a first-order low-pass (``wrench_filter_cutoff_hz``) are applied, once per step.
        """
        return self._measured_wrench().copy()

    def _measured_wrench(self) -> NDArray[np.float64]:
        c = self.config
        if c.wrench_filter_cutoff_hz is None and c.wrench_noise_force_std_n <= 0 and c.wrench_noise_torque_std_nm <= 0:
            return self._contact_summary()[0]
        cached = self._cache.get("measured")
        if cached is None:
            if c.wrench_filter_cutoff_hz is not None:
                self._update_filter()
            else:
                self._cache["measured"] = self.true_contact_wrench() + self._noise()
            cached = self._cache["measured"]
        return cached

    # -- kinematics ----------------------------------------------------------------------------------------------

    def forward_kinematics(self, q: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool pose at joint positions ``q`` (the simulated state is restored afterwards)."""
        q_save, qd_save = self.joint_state()
        try:
            self.set_joint_positions(q)
            return self.tool_pose()
        finally:
            self.set_joint_positions(q_save, qd_save)

    def inverse_kinematics(
        self,
        position: ArrayLike,
        quat: ArrayLike,
        q_seed: ArrayLike | None = None,
        *,
        position_tolerance_m: float = 1e-5,
        orientation_tolerance_rad: float = 1e-4,
        max_iterations: int = 300,
        null_gain: float = 0.05,
    ) -> NDArray[np.float64]:
        """Joint positions (7,) putting the tool point at ``position`` with orientation ``quat`` (xyzw).

        Damped least squares on this world's Jacobian with set-and-check forward kinematics, a null-space pull
        towards ``q_seed`` (default: the current posture) and joint limits. The simulated state is restored.
        Raises ``ValueError`` when the target is not reached within 0.1 mm and 1 mrad.
        """
        target_p = np.asarray(position, dtype=float)
        from skills.quaternions import matrix_from_quaternion

        target_R = matrix_from_quaternion(np.asarray(quat, dtype=float))
        q_save, qd_save = self.joint_state()
        q = q_save.copy() if q_seed is None else np.asarray(q_seed, dtype=float).copy()
        q_rest = q.copy()
        margin = 1e-3
        lo, hi = self.joint_lower + margin, self.joint_upper - margin
        err_p = err_o = np.inf
        try:
            for _ in range(max_iterations):
                self.set_joint_positions(q)
                p = self.tool_pose()[0]
                R = self.tool_rotation()
                err = np.empty(6)
                err[:3] = target_p - p
                err[3:] = _rotation_vector(target_R @ R.T)
                err_p, err_o = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
                if err_p < position_tolerance_m and err_o < orientation_tolerance_rad:
                    break
                J = self.jacobian()
                step = err.copy()
                step[:3] = np.clip(step[:3], -0.05, 0.05)
                damping = 1e-4 + 1e-2 * min(err_p, 0.05)
                JJt = J @ J.T + damping * np.eye(6)
                J_pinv = J.T @ np.linalg.inv(JJt)
                dq = J_pinv @ step + null_gain * (np.eye(N_JOINTS) - J_pinv @ J) @ (q_rest - q)
                q = np.clip(q + dq, lo, hi)
        finally:
            self.set_joint_positions(q_save, qd_save)
        if err_p > 1e-4 or err_o > 1e-3:
            raise ValueError(
                f"inverse kinematics did not converge: position error {err_p * 1e3:.3f} mm, "
                f"orientation error {math.degrees(err_o):.3f} deg (target unreachable or near a joint limit)"
            )
        return q

    # -- geometry (ground truth) ---------------------------------------------------------------------------------

    def surface_normal_at(self, point: ArrayLike) -> NDArray[np.float64]:
        """Outward unit normal of the nearest surface (table, ramp, cylinder, block) at ``point`` (3,) or (N, 3)."""
        return self.geometry.surface_normal_at(point)

    # -- diagnostics ---------------------------------------------------------------------------------------------

    def measure_costs(self, n: int = 500) -> dict[str, float]:
        """Mean cost (µs) of the per-step calls, measured on this world (it is stepped with gravity torques)."""
        tau = self.gravity_coriolis_torques()
        timings: dict[str, Callable[[], Any]] = {
            "step": lambda: self.step(tau),
            "joint_state": self.joint_state,
            "tool_pose": self.tool_pose,
            "jacobian": self.jacobian,
            "gravity_coriolis_torques": self.gravity_coriolis_torques,
            "mass_matrix": self.mass_matrix,
            "contact_wrench": self.contact_wrench,
            "sense": self.sense,
            "dynamics": self.dynamics,
        }
        result: dict[str, float] = {}
        for name, fn in timings.items():
            total = 0.0
            for _ in range(n):
                if name != "step":
                    self._invalidate()
                t0 = time.perf_counter()
                fn()
                total += time.perf_counter() - t0
            result[name] = 1e6 * total / n
        return result


def _rotation_vector(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vector (axis * angle, rad) of a rotation matrix, robust near 0 and pi (fast closed form below 170°)."""
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    if c > -0.985:
        w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        s = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        if s < 1e-12:
            return w
        return w * (math.atan2(s, c) / s)
    from skills.quaternions import quaternion_from_matrix, quaternion_log

    return 2.0 * quaternion_log(quaternion_from_matrix(R))
