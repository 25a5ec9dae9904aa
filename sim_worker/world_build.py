"""Building a world in PyBullet: the robot (``robot_model``'s URDF, under torque control) and the static solids of
``geometry`` (table, ramp, contour objects, work pieces) as bodies with their meshes and contact parameters.

Conventions (docs/CONVENTIONS.md): SI units, world frame, quaternions ``[x, y, z, w]``.

Contact model
    Rigid PyBullet contact at 1 kHz chatters (0-50 N around a 15 N target), so the tool link is made compliant:
    ``ContactConfig.stiffness_n_m = 3e4 N/m, damping_n_s_m = 300 N·s/m`` (a stiff polishing pad; at 15 N the pad
    compresses 0.5 mm; measured 15 N ± 0.7 N at 1 kHz). Bullet combines the friction coefficients of the two bodies
    by product: the environment bodies get ``lateralFriction = 1`` and the tool ``ContactConfig.lateral_friction``
    (0.2), so every tool contact has μ = 0.2. Rolling and spinning friction are zero. A work piece whose parts
    overlap in ``layers`` makes each part's contact softer so that the surface keeps the tool's stiffness and
    damping (springs in series, dampers added: Bullet's rules for two bodies that both set them).

Torque control
    The default velocity motors are disabled once (``VELOCITY_CONTROL``, force 0). The URDF joint damping
    (0.5 N·m·s/rad) and the default link damping (0.04) are zeroed, so the gravity/Coriolis torques alone hold the
    arm still. Joint limits are NOT enforced by PyBullet in torque mode (the executor checks them).
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np
import pybullet
from numpy.typing import NDArray

from schemas.dashboard import WorkPieceMesh
from schemas.world import WorldConfig
from sim_worker.geometry import BoxSolid, ConvexSolid, CurvedBlockSolid, CylinderSolid, WorldGeometry
from sim_worker.robot_model import N_JOINTS, TOOL_LINK, robot_urdf
from skills.frames import matrix_from_axis_angle
from skills.quaternions import quaternion_from_matrix

_RIGID = 1e18
"""A body's own contact stiffness when only the tool's should count (Bullet's default for bodies without one)."""


@dataclass(frozen=True)
class Robot:
    """The loaded robot: its PyBullet body id and joint limits (7,) rad from the URDF."""

    body: int
    joint_lower: NDArray[np.float64]
    joint_upper: NDArray[np.float64]


def load_robot(client: int, config: WorldConfig, layers: int) -> Robot:
    """Load the iiwa with ``config.tool`` into ``client`` (fixed base), damping zeroed, the tool link compliant as
    ``config.contact`` (its damping shared among ``layers`` overlapping work piece parts), velocity motors off."""
    fd, path = tempfile.mkstemp(suffix=".urdf", prefix="iiwa_tool_")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(robot_urdf(config.tool))
        body = pybullet.loadURDF(
            path, useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client
        )
    finally:
        os.unlink(path)
    info = [pybullet.getJointInfo(body, j, physicsClientId=client) for j in range(N_JOINTS)]
    for link in range(-1, TOOL_LINK + 1):
        pybullet.changeDynamics(
            body, link, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0, physicsClientId=client
        )
    contact = config.contact
    pybullet.changeDynamics(
        body,
        TOOL_LINK,
        contactStiffness=contact.stiffness_n_m,
        contactDamping=contact.damping_n_s_m / layers,
        lateralFriction=contact.lateral_friction,
        rollingFriction=0.0,
        spinningFriction=0.0,
        physicsClientId=client,
    )
    pybullet.setJointMotorControlArray(
        body, list(range(N_JOINTS)), pybullet.VELOCITY_CONTROL, forces=[0.0] * N_JOINTS, physicsClientId=client
    )
    return Robot(body, np.array([i[8] for i in info]), np.array([i[9] for i in info]))


def work_piece_layers(geometry: WorldGeometry) -> dict[str, int]:
    """How many overlapping parts each work piece part's surface lies in, by body name (1 without work pieces)."""
    pieces = geometry.config.work_pieces
    names = geometry.work_piece_names() if pieces else []
    return {name: piece.layers for name, piece in zip(names, pieces, strict=True)}


def build_environment(client: int, geometry: WorldGeometry) -> dict[str, int]:
    """Create the static bodies of ``geometry``'s solids in ``client``; their body ids by name."""
    layers = work_piece_layers(geometry)
    builder = _Builder(client, geometry.config, layers, max(layers.values(), default=1))
    for name, solid in geometry.solids.items():
        if isinstance(solid, BoxSolid):
            shape = pybullet.createCollisionShape(
                pybullet.GEOM_BOX, halfExtents=solid.half.tolist(), physicsClientId=client
            )
            visual = pybullet.createVisualShape(
                pybullet.GEOM_BOX, halfExtents=solid.half.tolist(), rgbaColor=[0.6, 0.5, 0.4, 1], physicsClientId=client
            )
            builder.add(name, shape, visual, solid.R, solid.p)
        elif isinstance(solid, ConvexSolid):
            vertices = solid.vertices.tolist()
            shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices, physicsClientId=client)
            visual = pybullet.createVisualShape(
                pybullet.GEOM_MESH,
                vertices=vertices,
                indices=_hull_indices(solid.vertices),
                rgbaColor=[0.8, 0.6, 0.3, 1],
                physicsClientId=client,
            )
            builder.add(name, shape, visual, solid.R, solid.p)
        elif isinstance(solid, CylinderSolid):
            # PyBullet cylinders and capsules lie along their local z; ours along the body y axis. The cylinder is
            # simulated as a capsule whose straight part is the cylinder (its ends are rounded, and never touched):
            # Bullet computes a ball on a capsule in closed form, but a ball on a cylinder by GJK/EPA, whose depth is
            # exact only to some micrometres as the contact point moves, ±10 N on a 1e6 N/m pad (measured: a contour
            # at 64 % max error with the cylinder, 4.1 % with the capsule; docs/EXECUTION.md).
            R = solid.R @ matrix_from_axis_angle((1.0, 0.0, 0.0), -math.pi / 2)
            shape = pybullet.createCollisionShape(
                pybullet.GEOM_CAPSULE, radius=solid.radius, height=solid.length, physicsClientId=client
            )
            visual = pybullet.createVisualShape(
                pybullet.GEOM_CAPSULE,
                radius=solid.radius,
                length=solid.length,
                rgbaColor=[0.3, 0.5, 0.8, 1],
                physicsClientId=client,
            )
            builder.add(name, shape, visual, R, solid.p)
        elif isinstance(solid, CurvedBlockSolid):
            profile = _block_profile(solid, geometry.config.block.mesh_segments)
            vertices = _block_vertices(solid, profile)
            shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices, physicsClientId=client)
            visual = pybullet.createVisualShape(
                pybullet.GEOM_MESH,
                vertices=vertices,
                indices=_block_indices(profile.shape[0]),
                rgbaColor=[0.4, 0.7, 0.4, 1],
                physicsClientId=client,
            )
            builder.add(name, shape, visual, solid.R, solid.p)
    return builder.bodies


CYLINDER_SIDES = 48
"""Sides of a cylinder's drawn mesh (its simulated shape is exact: a capsule)."""


def work_piece_meshes(geometry: WorldGeometry) -> list[WorkPieceMesh]:
    """``geometry``'s solids as the triangle meshes the dashboard draws (world frame, m), the same shapes
    :func:`build_environment` gives PyBullet (a cylinder as a prism of :data:`CYLINDER_SIDES` sides)."""
    meshes = []
    for name, solid in geometry.solids.items():
        if isinstance(solid, BoxSolid):
            local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * solid.half
            triangles = _hull_indices(local)
        elif isinstance(solid, ConvexSolid):
            local, triangles = solid.vertices, _hull_indices(solid.vertices)
        elif isinstance(solid, CylinderSolid):  # along the body y axis
            angle = np.linspace(0.0, 2 * math.pi, CYLINDER_SIDES, endpoint=False)
            ring = np.stack([solid.radius * np.cos(angle), np.zeros_like(angle), solid.radius * np.sin(angle)], axis=1)
            local = np.concatenate([ring + np.array([0.0, y, 0.0]) for y in (-0.5 * solid.length, 0.5 * solid.length)])
            triangles = _hull_indices(local)
        elif isinstance(solid, CurvedBlockSolid):
            profile = _block_profile(solid, geometry.config.block.mesh_segments)
            local, triangles = np.array(_block_vertices(solid, profile)), _block_indices(profile.shape[0])
        else:
            continue
        vertices = np.asarray(local, dtype=float) @ solid.R.T + solid.p
        meshes.append(WorkPieceMesh(name=name, vertices=vertices.round(6).tolist(),
                                    triangles=np.reshape(triangles, (-1, 3)).tolist()))  # fmt: skip
    return meshes


@dataclass
class _Builder:
    """Adds static bodies to a client with the environment's contact parameters."""

    client: int
    config: WorldConfig
    layers: dict[str, int]
    most_layers: int

    def __post_init__(self) -> None:
        self.bodies: dict[str, int] = {}

    def add(self, name: str, shape: int, visual: int, R: NDArray[np.float64], p: NDArray[np.float64]) -> None:
        """A static body of ``shape`` at pose ``(R, p)`` (body into world, m)."""
        body = pybullet.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=shape,
            baseVisualShapeIndex=visual,
            basePosition=p.tolist(),
            baseOrientation=quaternion_from_matrix(R).tolist(),
            physicsClientId=self.client,
        )
        pybullet.changeDynamics(
            body, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0, physicsClientId=self.client
        )
        if self.most_layers > 1:  # each contact's spring in series with the tool's, dampers added (Bullet's rules)
            layers = self.layers.get(name, 1)
            contact = self.config.contact
            pybullet.changeDynamics(
                body,
                -1,
                contactStiffness=contact.stiffness_n_m / (layers - 1) if layers > 1 else _RIGID,
                contactDamping=contact.damping_n_s_m * (1.0 / layers - 1.0 / self.most_layers),
                physicsClientId=self.client,
            )
        self.bodies[name] = body


def _hull_indices(vertices: NDArray[np.float64]) -> list[int]:
    """Triangle indices of the convex hull of ``vertices`` (K, 3), wound counter-clockwise seen from outside."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(vertices)
    triangles = hull.simplices.copy()
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) < 0
    triangles[inward] = triangles[inward][:, ::-1]
    return triangles.ravel().tolist()


def _block_profile(solid: CurvedBlockSolid, segments: int) -> NDArray[np.float64]:
    """The block's closed (x, z) profile in its body frame (m): the cap in ``segments`` steps, then the base."""
    phi = np.linspace(0.0, math.pi, segments + 1)
    x, z = solid.profile_point(phi)
    return np.concatenate([np.stack([x, z], axis=1), [[-solid.a, 0.0], [solid.a, 0.0]]])


def _block_vertices(solid: CurvedBlockSolid, profile: NDArray[np.float64]) -> list[list[float]]:
    """The profile extruded over the block's width: both end faces' vertices (body frame, m)."""
    w = 0.5 * solid.width
    return [[x, y, z] for y in (-w, w) for x, z in profile]


def _block_indices(n: int) -> list[int]:
    """Triangles of the extruded profile of ``n`` points: the sides between consecutive points and the end caps."""
    idx: list[int] = []
    for i in range(n):  # sides between consecutive profile points (closed polygon)
        j = (i + 1) % n
        idx += [i, j, n + j, i, n + j, n + i]
    for i in range(1, n - 1):  # end caps (fan)
        idx += [0, i + 1, i, n, n + i, n + i + 1]
    return idx
