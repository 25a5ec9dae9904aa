"""The MuJoCo model of the cell PyBullet simulates (``sim_worker.world``): the same iiwa and tool, loaded from the
same URDF (``sim_worker.robot_model.robot_urdf``) through MuJoCo's URDF compiler, among the same static solids
(``sim_worker.geometry.WorldGeometry`` of the same ``WorldConfig``: table, ramp, cylinder, curved block, rebuilt,
measured and CAD work pieces), with the tool's compliant contact matched to the pad's stiffness and damping, and a
force/torque sensor at the tool point.

Conventions (docs/CONVENTIONS.md): SI units, world frame; MuJoCo's own quaternions are scalar-FIRST ``[w, x, y, z]``
and never leave this package. How each PyBullet parameter maps and what could not be matched: docs/ENGINES.md.

The robot
    The URDF's masses, inertias (``balanceinertia`` off: as PyBullet's ``URDF_USE_INERTIA_FROM_FILE``), joint axes
    and origins as they are; the fixed tool joint kept as its own body (``fusestatic`` off), so the wrist sensor sits
    between flange and tool as PyBullet's tool joint reaction does. As ``sim_worker.world_build`` does in PyBullet:
    joint damping zeroed, no armature, joint limits NOT enforced (the executor checks them; their values are kept in
    :attr:`MujocoCell.joint_lower` / ``joint_upper``), no self-collision.

Contact
    MuJoCo's contact is a soft constraint: with the negative ``solref = (-S, -B)`` and a constant impedance ``d``
    (``solimp = (d, d, ...)``), a static press compresses the contact by ``r = (1 - d) Â F / S`` and the contact's
    damping is ``B / ((1 - d) Â)``, where ``Â`` is MuJoCo's diagonal approximation of the contact's inverse mass, a
    constant of the model (the tool body's translational inverse weight at ``qpos0``, ``body_invweight0``: 0.624 1/kg
    here). :func:`pad_solref` therefore scales PyBullet's pad stiffness ``k`` (N/m) and damping ``c`` (N·s/m) by
    ``(1 - d) Â``: the same spring and damper whatever :data:`PAD_IMPEDANCE` (the unscaled ``(-k, -c)`` would need
    ``(1 - d) Â = 1``, impossible with ``Â < 1``). The tool's geoms carry the contact
    parameters (``priority`` above the environment's, whose parameters MuJoCo then ignores), friction ``μ`` of
    ``ContactConfig.lateral_friction`` with an elliptic (circular) cone as PyBullet's, no torsional or rolling friction
    (``condim = 3``). A work piece whose parts overlap in ``layers`` has priority over the tool with ``k / layers``,
    ``c / layers`` (parallel contacts add up to the pad's).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import NDArray

from schemas.world import WorldConfig
from sim_worker.cad_work_piece import CONVEX_MARGIN_M
from sim_worker.geometry import BoxSolid, ConvexSolid, CurvedBlockSolid, CylinderSolid, WorldGeometry
from sim_worker.robot_model import N_JOINTS, robot_urdf
from skills.frames import matrix_from_axis_angle
from skills.quaternions import quaternion_from_matrix

log = logging.getLogger("contact_skills.mujoco")

TOOL_BODY = "tool_link"
"""The tool's body (the URDF's ``tool_link``): its frame origin is the tool point (``sim_worker.robot_model``)."""
TOOL_SITE = "tool_point"
"""The site at the tool point, tool frame axes, where the wrist sensor measures."""
WRIST_FORCE_SENSOR = "wrist_force"
WRIST_TORQUE_SENSOR = "wrist_torque"
ARM_FRICTION = 0.5
"""The friction coefficient of the arm's links with the environment: PyBullet's default link friction (0.5) times the
environment bodies' 1 (Bullet multiplies them)."""
_ENVIRONMENT_CONTYPE, _ROBOT_CONAFFINITY = 1, 1
"""Collision bits: environment geoms collide with robot geoms only (contype 1, conaffinity 0 against contype 0,
conaffinity 1), so the static solids never collide with each other and the robot not with itself (as PyBullet's
``loadURDF`` without self-collision)."""
_TOOL_PRIORITY, _LAYERED_PRIORITY = 1, 2
_URDF_COMPILER = (
    '<mujoco><compiler fusestatic="false" discardvisual="true" balanceinertia="false" strippath="false"/></mujoco>'
)
"""MuJoCo's URDF extension: keep the fixed tool link a body, drop the visual meshes, keep the inertias as written and
the mesh paths absolute (``robot_urdf`` writes them so)."""
PAD_IMPEDANCE = 0.1
"""solimp's constant impedance ``d`` of the tool's contacts (0 < d < 1). The static spring does not depend on it
(:func:`pad_solref` scales solref by ``1 - d``); the transient does: MuJoCo's constraint adds an apparent mass
``d / ((1 - d) Â)`` along the normal (0.18 kg at 0.1, 1.6 kg at 0.5). A joint impedance touching down from 1 cm peaks
at 51.2 N with 0.1, 45.4 N with 0.5, 33.4 N with 0.9, 52.9 N with 0.01, against PyBullet's 52.0 N (measured,
``tests/test_mujoco.py``; docs/ENGINES.md)."""
FRICTION_IMPRATIO = 1.0
"""MuJoCo's ratio of the friction rows' impedance to the normal's (``opt.impratio``, elliptic cones; 1 is MuJoCo's
default). Below the cone MuJoCo's soft friction is not a stick but a damper of ``impratio · c`` N·s/m (``c`` the pad's
damping): a tool pushed sideways with half of μ N creeps at ``F_t / (impratio c)``, 4.6 mm in 1 s at μ 0.2 (1.5 N)
and 20 mm at μ 0.9 (6.75 N) with 1, 0.05 mm with 100, where PyBullet's stick holds 0.03 mm. 1, not 100: the
product's skills slide, and at 100 (stiff friction rows against the normal's) a slide at μ 0.6 or 0.9 chatters, its
normal force oscillating at 40-300 Hz until the tool leaves the surface (``slide_flat`` at μ 0.9: true RMS 47.1 %
at 100, 29.6 % at 3, 7.8 % at 1; measured, docs/ENGINES.md, *Friction: sliding, not sticking*)."""
IMPEDANCE_WIDTH_M = 1.0
"""solimp's width (m): irrelevant with ``dmin = dmax`` (the impedance is constant), kept wide."""
MIN_TIME_CONSTANT_STEPS = 2.0
"""MuJoCo's floor on a constraint's time constant, in time steps: below it the soft constraint is not resolved by
the integrator (MuJoCo's docs; it clamps a ``solref`` given as a time constant there unless ``mjDSBL_REFSAFE``, but
not the direct ``(-stiffness, -damping)`` form :func:`pad_solref` writes, so a stiffer pad stays as stiff as
configured and is flagged instead: :func:`pad_time_constant_s`)."""


@dataclass(frozen=True)
class MujocoCell:
    """The compiled model of one ``WorldConfig`` and what the robot reads from it: the tool's body and geoms (ids),
    the wrist sensor's addresses in ``sensordata`` (force (3,) N and torque (3,) N·m at the tool point, tool frame),
    the URDF's joint limits (7,) rad, the environment's geom names by id (table, ramp, ``work_piece_<k>`` ...), the
    time constant of the tool's contact on the pad (s, :func:`pad_time_constant_s`)."""

    model: mujoco.MjModel
    config: WorldConfig
    tool_body: int
    tool_geoms: frozenset[int]
    force_address: int
    torque_address: int
    joint_lower: NDArray[np.float64]
    joint_upper: NDArray[np.float64]
    environment: dict[int, str]
    pad_time_constant_s: float

    @property
    def pad_resolved(self) -> bool:
        """Whether the pad's contact is slow enough for the time step (:data:`MIN_TIME_CONSTANT_STEPS`): a stiffer pad
        is simulated with its configured stiffness, but its bounce is not the pad's (docs/ENGINES.md, *A stiff pad
        against the 1 ms step*)."""
        return self.pad_time_constant_s >= MIN_TIME_CONSTANT_STEPS * self.config.time_step_s


def robot_spec(config: WorldConfig) -> mujoco.MjSpec:
    """The iiwa with ``config.tool`` as a MuJoCo spec, from the same URDF PyBullet loads (module docstring)."""
    text = re.sub(r"(<robot[^>]*>)", lambda match: match.group(1) + _URDF_COMPILER, robot_urdf(config.tool), count=1)
    spec = mujoco.MjSpec.from_string(text)
    for joint in spec.joints:
        joint.damping = [0.0, 0.0, 0.0]
        joint.armature = 0.0
        joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    return spec


def pad_solref(stiffness_n_m: float, damping_n_s_m: float, tool_inverse_weight: float) -> list[float]:
    """MuJoCo's negative ``solref`` (with the impedance :data:`PAD_IMPEDANCE`) that makes a contact of the tool the
    spring ``stiffness_n_m`` (N/m) and damper ``damping_n_s_m`` (N·s/m) of the pad: both scaled by ``(1 - d) Â``,
    ``Â`` the tool's translational inverse weight (1/kg, ``body_invweight0``; module docstring)."""
    scale = (1.0 - PAD_IMPEDANCE) * tool_inverse_weight
    return [-stiffness_n_m * scale, -damping_n_s_m * scale]


def pad_time_constant_s(stiffness_n_m: float, tool_inverse_weight: float) -> float:
    """The time constant (s) of the tool's contact on a pad of ``stiffness_n_m`` (N/m): ``1 / ω``, ``ω`` the contact
    mode's natural frequency with the tool's mass and the constraint's apparent mass, ``1 / ((1 - d) Â)`` kg
    (:data:`PAD_IMPEDANCE`, ``Â`` the tool's inverse weight, 1/kg). It is the time constant MuJoCo's own
    ``solref = (timeconst, 1)`` would give the same spring: 7.7 ms at the nominal 3e4 N/m, 1.3 ms at 1e6 N/m."""
    return 1.0 / math.sqrt(stiffness_n_m * (1.0 - PAD_IMPEDANCE) * tool_inverse_weight)


def cell_model(config: WorldConfig | None = None) -> MujocoCell:
    """The MuJoCo model of ``config``'s cell (module docstring), compiled."""
    config = config or WorldConfig()
    spec = robot_spec(config)
    spec.option.timestep = config.time_step_s
    spec.option.gravity = list(config.gravity)
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = FRICTION_IMPRATIO
    tool = spec.body(TOOL_BODY)
    tool.add_site(name=TOOL_SITE, pos=[0.0, 0.0, 0.0])
    spec.add_sensor(name=WRIST_FORCE_SENSOR, type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname=TOOL_SITE)  # fmt: skip
    spec.add_sensor(name=WRIST_TORQUE_SENSOR, type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE,
                    objname=TOOL_SITE)  # fmt: skip
    tool_geoms = [geom for geom in spec.geoms if geom.parent.name == TOOL_BODY]
    for geom in spec.geoms:  # the robot's: collide with the environment only
        geom.contype, geom.conaffinity = 0, _ROBOT_CONAFFINITY
        geom.friction = [ARM_FRICTION, 0.0, 0.0]
        geom.condim = 3
    for geom in tool_geoms:
        geom.priority = _TOOL_PRIORITY
        geom.friction = [config.contact.lateral_friction, 0.0, 0.0]
    layers = _add_environment(spec, WorldGeometry(config))
    # The tool's inverse weight at qpos0, of the robot alone: the world's static geoms do not change it, and the arm
    # compiles in milliseconds where a world of a thousand meshes takes a second.
    arm = robot_spec(config).compile()
    inverse_weight = float(arm.body_invweight0[arm.body(TOOL_BODY).id, 0])
    solimp = [PAD_IMPEDANCE, PAD_IMPEDANCE, IMPEDANCE_WIDTH_M, 0.5, 2.0]
    contact = config.contact
    for geom, count in [(geom, 1) for geom in tool_geoms] + layers:
        geom.solref = pad_solref(contact.stiffness_n_m / count, contact.damping_n_s_m / count, inverse_weight)
        geom.solimp = solimp
    model = spec.compile()
    lower, upper = model.jnt_range[:N_JOINTS].T
    cell = MujocoCell(
        model=model,
        config=config,
        tool_body=model.body(TOOL_BODY).id,
        tool_geoms=frozenset(g.id for g in tool_geoms),
        force_address=int(model.sensor_adr[model.sensor(WRIST_FORCE_SENSOR).id]),
        torque_address=int(model.sensor_adr[model.sensor(WRIST_TORQUE_SENSOR).id]),
        joint_lower=lower.copy(),
        joint_upper=upper.copy(),
        environment={g: model.geom(g).name for g in range(model.ngeom) if model.geom_bodyid[g] == 0},
        pad_time_constant_s=pad_time_constant_s(contact.stiffness_n_m, inverse_weight),
    )
    if not cell.pad_resolved:
        log.warning(
            "MuJoCo: the pad's contact (%.3g N/m) has a time constant of %.2f ms, under %g time steps of %.2f ms: "
            "simulated as stiff as configured, but its bounce is the integrator's, not the pad's (docs/ENGINES.md)",
            contact.stiffness_n_m, 1e3 * cell.pad_time_constant_s, MIN_TIME_CONSTANT_STEPS, 1e3 * config.time_step_s,
        )  # fmt: skip
    return cell


def _add_environment(spec: mujoco.MjSpec, geometry: WorldGeometry) -> list[tuple[mujoco.MjsGeom, int]]:
    """Add ``geometry``'s solids to the world body as PyBullet's ``world_build.build_environment`` shapes them; the
    geoms of work pieces whose parts overlap, with their ``layers``."""
    layers = dict(zip(geometry.work_piece_names(), (p.layers for p in geometry.config.work_pieces), strict=False))
    config = geometry.config
    layered = []
    for name, solid in geometry.solids.items():
        R, p = solid.R, solid.p
        margin = 0.0
        if isinstance(solid, BoxSolid):
            kind, size, mesh = mujoco.mjtGeom.mjGEOM_BOX, solid.half, None
        elif isinstance(solid, CylinderSolid):  # a capsule, as PyBullet's (world_build): along the body y axis
            kind, size, mesh = mujoco.mjtGeom.mjGEOM_CAPSULE, [solid.radius, 0.5 * solid.length, 0.0], None
            R = R @ matrix_from_axis_angle((1.0, 0.0, 0.0), -math.pi / 2)
        elif isinstance(solid, ConvexSolid | CurvedBlockSolid):
            # PyBullet inflates a convex hull built from vertices by its collision margin (cad_work_piece): a geom
            # margin shifts MuJoCo's contact surface out by as much.
            kind, size, margin = mujoco.mjtGeom.mjGEOM_MESH, [0.0, 0.0, 0.0], CONVEX_MARGIN_M
            vertices = solid.vertices if isinstance(solid, ConvexSolid) else block_vertices(solid, config)
            mesh = spec.add_mesh(name=f"{name}_mesh", uservert=np.asarray(vertices, dtype=float).ravel().tolist())
        else:
            continue
        quat = quaternion_from_matrix(R)
        geom = spec.worldbody.add_geom(
            name=name,
            type=kind,
            size=list(size),
            pos=p.tolist(),
            quat=[quat[3], quat[0], quat[1], quat[2]],
            contype=_ENVIRONMENT_CONTYPE,
            conaffinity=0,
            condim=3,
            margin=margin,
            friction=[config.contact.lateral_friction, 0.0, 0.0],
        )
        if mesh is not None:
            geom.meshname = mesh.name
        if layers.get(name, 1) > 1:
            geom.priority = _LAYERED_PRIORITY
            layered.append((geom, layers[name]))
    return layered


def block_vertices(solid: CurvedBlockSolid, config: WorldConfig) -> NDArray[np.float64]:
    """The curved block's vertices (body frame, m): its (x, z) profile, the cap in ``config.block.mesh_segments``
    steps and the base's two corners, at both ends of its width (the hull PyBullet builds the block from)."""
    x, z = solid.profile_point(np.linspace(0.0, math.pi, config.block.mesh_segments + 1))
    profile = np.concatenate([np.stack([x, z], axis=1), [[-solid.a, 0.0], [solid.a, 0.0]]])
    w = 0.5 * solid.width
    return np.array([[px, y, pz] for y in (-w, w) for px, pz in profile])
