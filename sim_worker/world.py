"""The simulated world in PyBullet at 1 kHz: the robot of ``robot_model`` (iiwa + ball tool) among the static
solids of ``geometry`` (table, ramp, contour objects, rebuilt work pieces), stepped under torque control, with the
tool's contact wrench sensed through ``sensor``.

Conventions (docs/CONVENTIONS.md): SI units, world frame, quaternions ``[x, y, z, w]``, 6-vectors
``[x, y, z, rx, ry, rz]``; the contact wrench is the wrench the TOOL APPLIES TO THE ENVIRONMENT,
at the tool point, in the world frame.

Contact model
    Rigid PyBullet contact at 1 kHz chatters (0-50 N around a 15 N target), so the tool link is made
    compliant: ``contactStiffness = 3e4 N/m, contactDamping = 300 N·s/m`` (a stiff polishing pad; at 15 N
    the pad compresses 0.5 mm; measured 15 N ± 0.7 N at 1 kHz). Bullet combines the friction
    coefficients of the two bodies by product: the environment bodies get ``lateralFriction = 1`` and the
    tool ``WorldConfig.lateral_friction`` (0.2), so every tool contact has μ = 0.2. Rolling and spinning
    friction are zero.

Torque control
    The default velocity motors are disabled once (``VELOCITY_CONTROL``, force 0); ``step()`` sends
    ``TORQUE_CONTROL`` before every ``stepSimulation``. The URDF joint damping (0.5 N·m·s/rad) and the
    default link damping (0.04) are zeroed, so ``gravity_coriolis_torques()`` alone holds the arm still.
    Torques are clipped to the iiwa 14 limits ``skills.control.IIWA_TORQUE_LIMITS_NM`` (320, 320, 176, 176, 110, 40,
    40 N·m);
    ``last_step_clipped`` says whether the last ``step()`` clipped. Joint limits are NOT enforced by
    PyBullet in torque mode (the executor checks them).

Measured PyBullet 3.2.7 facts this module relies on
    - The tool pose, Jacobian, gravity/Coriolis torques and mass matrix come from the arm's compiled model
      (``sim_worker.arm_model``, read from this multibody), equal to ``getLinkState`` (the COM pose, double; its
      link-frame pose is float32), ``calculateJacobian``, ``calculateInverseDynamics`` and ``calculateMassMatrix``
      to round-off (``tests/test_world.py``), without a PyBullet round trip per query.
    - ``getContactPoints`` with the tool as body A: ``contactNormalOnB`` points from the environment to the
      tool, and ``lateralFriction1/2`` along ``lateralFrictionDir1/2`` are forces ON THE TOOL too; the
      applied wrench is minus their sum.
    - The multibody solver uses fixed friction directions with a circular friction cone: while sliding
      the friction magnitude is exactly μ·N, but its direction can be ~15° off the slip direction
      (depends on the arm's mobility); the normal part is exact (``contact_forces()`` separates them).
    - Explicit damping must respect the light wrist: joint 7 + tool have ~1e-3 kg·m², so a Cartesian
      rotational damping of 3 N·m·s/rad is unstable at 1 kHz (D·dt/I > 2); 0.3 N·m·s/rad is fine.

Geometry for ground truth
    ``sim_worker.geometry.WorldGeometry`` (pure numpy) holds the exact shapes the PyBullet bodies are built from.
"""

from __future__ import annotations

import contextlib
import math
import operator
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numba
import numpy as np
import pybullet
from numpy.typing import ArrayLike, NDArray

from sim_worker.arm_model import arm_mass_matrix, arm_model_from_pybullet, arm_state, workspace_size
from sim_worker.geometry import BoxSolid, ConvexSolid, CurvedBlockSolid, CylinderSolid, WorldGeometry
from sim_worker.robot_model import N_JOINTS, Q_HOME, TOOL_LINK, robot_urdf
from sim_worker.sensor import WrenchSensor
from sim_worker.world_config import WorldConfig
from skills.control import (
    ROBOT_BIAS,
    ROBOT_JACOBIAN,
    ROBOT_POSITION,
    ROBOT_Q,
    ROBOT_QD,
    ROBOT_QUAT,
    ROBOT_ROTATION,
    ROBOT_STATE_SIZE,
)
from skills.frames import matrix_from_axis_angle, rotation_vector_from_matrix
from skills.quaternions import quaternion_from_matrix

_RIGID = 1e18
"""A body's own contact stiffness when only the tool's should count (Bullet's default for bodies without one)."""
CONTACT_DISTANCE_M = 0.0
"""A contact point counts as contact when its distance is at or below this (m) or it carries force."""
_ARM_JOINTS = slice(ROBOT_Q.start, ROBOT_QD.stop)
"""The joint positions and velocities in the arm state (one assignment per step)."""
_JOINT_POSITION, _JOINT_VELOCITY = operator.itemgetter(0), operator.itemgetter(1)
"""The position and velocity of one of ``getJointStates``' tuples."""


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
    treat them as read-only; the next ``step()`` overwrites them in place (copy what must outlive the step).
    ``q``, ``qd`` (7,) rad, rad/s;
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


def _quat_from_matrix(R: NDArray[np.float64]) -> list[float]:
    """Scalar-last quaternion of a rotation matrix, as a list for PyBullet."""
    return quaternion_from_matrix(R).tolist()


def _hull_indices(vertices: NDArray[np.float64]) -> list[int]:
    """Triangle indices of the convex hull of ``vertices`` (K, 3), wound counter-clockwise seen from outside."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(vertices)
    triangles = hull.simplices.copy()
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) < 0
    triangles[inward] = triangles[inward][:, ::-1]
    return triangles.ravel().tolist()


_ROTATION = ROBOT_ROTATION.start


@numba.njit(cache=True)
def _wrist_wrench(reaction, arm, weight, com_z, out):  # pragma: no cover - compiled
    """:meth:`SimWorld.wrist_wrench` from the tool joint's ``reaction`` (the flange's force on the tool, tool frame,
    and its moment about the tool's centre of mass, which lies on the tool axis at ``com_z``), the tool orientation
    in ``arm`` (``ROBOT_ROTATION``, world from tool by rows) and the tool's ``weight`` (world, N), into ``out``."""
    fx, fy, fz, mx, my, mz = reaction
    r = arm[_ROTATION : _ROTATION + 9]
    gx, gy, gz = weight
    wx = r[0] * gx + r[3] * gy + r[6] * gz  # the weight in the tool frame: R^T m g
    wy = r[1] * gx + r[4] * gy + r[7] * gz
    wz = r[2] * gx + r[5] * gy + r[8] * gz
    fx, fy, fz = fx + wx, fy + wy, fz + wz
    mx, my = mx - com_z * fy, my + com_z * fx  # M_c + c x F, c = (0, 0, com_z)
    out[0] = r[0] * fx + r[1] * fy + r[2] * fz
    out[1] = r[3] * fx + r[4] * fy + r[5] * fz
    out[2] = r[6] * fx + r[7] * fy + r[8] * fz
    out[3] = r[0] * mx + r[1] * my + r[2] * mz
    out[4] = r[3] * mx + r[4] * my + r[5] * mz
    out[5] = r[6] * mx + r[7] * my + r[8] * mz


@numba.njit(cache=True)
def _remove_tare(wrench, arm, tare):  # pragma: no cover - compiled
    """Subtract the sensor's ``tare`` (6,: force, moment, TOOL frame) turned into the world with the tool orientation
    in ``arm`` (``ROBOT_ROTATION``, world from tool by rows) from ``wrench`` (6,, world), in place."""
    r = arm[_ROTATION : _ROTATION + 9]
    for i in range(3):
        wrench[i] -= r[3 * i] * tare[0] + r[3 * i + 1] * tare[1] + r[3 * i + 2] * tare[2]
        wrench[3 + i] -= r[3 * i] * tare[3] + r[3 * i + 1] * tare[4] + r[3 * i + 2] * tare[5]


# ---------------------------------------------------------------------------------------------------------------
# The PyBullet world.
# ---------------------------------------------------------------------------------------------------------------


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
        urdf = robot_urdf(c)
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
        names = self.geometry.work_piece_names() if c.work_pieces else []
        self._layers = {name: int(p.get("layers", 1)) for name, p in zip(names, c.work_pieces, strict=True)}
        self._most_layers = max(self._layers.values(), default=1)
        pybullet.changeDynamics(
            self.robot,
            TOOL_LINK,
            contactStiffness=c.contact_stiffness,
            contactDamping=c.contact_damping / self._most_layers,
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
        # The arm's kinematics and dynamics come from its compiled model (sim_worker.arm_model), read from this
        # multibody: equal to calculateJacobian / calculateInverseDynamics / calculateMassMatrix / getLinkState to
        # round-off, without their 2-5 µs round trips per step.
        self._model = arm_model_from_pybullet(self.robot, TOOL_LINK, c.gravity, cid)
        self._arm = np.zeros(ROBOT_STATE_SIZE)
        self._arm_work = np.empty(workspace_size(self._model))
        """The arm state of the current step, overwritten in place by the next one (the raw accessors' views)."""
        self._contact_state = np.zeros(10)
        """The summary of ``_points``, written in one assignment (zeros without points): the two views below."""
        self._applied = self._contact_state[:6]
        """The exact wrench the tool applies this step (see :meth:`true_contact_wrench`), overwritten in place."""
        self._measured = np.zeros(6)
        """The sensor's reading this step (a non-ideal sensor's; the ideal one reads ``_applied``)."""
        self._source = np.zeros(6)
        """The wrist sensor's source wrench this step (see :meth:`wrist_wrench`)."""
        self._tare = np.zeros(6)
        """The offset a tare removes from every reading (see :meth:`tare_sensor`), tool frame, N and N·m."""
        self._tared = False
        self._mass = np.zeros((N_JOINTS, N_JOINTS))
        self._points: tuple = ()
        self._touching = False
        self._true_normal = self._contact_state[6:]
        """The force along the true surface normal (N) and that normal (3,), see :meth:`true_normal_force`."""
        self._arm_q, self._arm_qd = self._arm[ROBOT_Q], self._arm[ROBOT_QD]
        self._arm_position, self._arm_quat = self._arm[ROBOT_POSITION], self._arm[ROBOT_QUAT]
        self._arm_rotation = self._arm[ROBOT_ROTATION].reshape(3, 3)
        self._arm_jacobian = self._arm[ROBOT_JACOBIAN].reshape(6, N_JOINTS)
        self._arm_bias = self._arm[ROBOT_BIAS]
        self.bodies: dict[str, int] = {}
        self._build_environment()
        self.sensor = WrenchSensor(c)
        self._tool_offset = -self.sensor.tool_offset if np.any(self.sensor.tool_offset) else None
        self._wrist = c.sensor_model == "wrist"
        if self._wrist:  # the fixed tool joint reports the flange's force on the tool (its origin: the tool point)
            pybullet.enableJointForceTorqueSensor(self.robot, TOOL_LINK, True, physicsClientId=cid)
        wrench = self._applied if self.sensor.ideal else self._measured
        self._sensing = tuple(
            Sensing(self._arm_q, self._arm_qd, self._arm_position, self._arm_quat, wrench, touching)
            for touching in (False, True)
        )
        """What :meth:`sense` returns, without and with contact: the same arrays every step, overwritten in place."""
        self._queried_joints = [*self._joints, TOOL_LINK] if self._wrist else self._joints
        """The joints read each step: the arm's, and the tool joint's reaction with the wrist sensor (one query)."""
        self._tool_reaction: tuple[float, ...] = (0.0,) * 6
        """The tool joint's reaction of this step (wrist sensor), read with the arm's joints."""
        self._tool_com = (0.0, 0.0, -(0.5 * c.tool_shaft_length_m + c.tool_radius_m))
        """The tool's centre of mass in the tool frame (the tool model the weight is compensated with), m."""
        self._tool_weight = tuple(c.tool_mass_kg * g for g in c.gravity)
        """The tool's weight in the world, N."""
        self.last_step_clipped = False
        self.clip_count = 0
        self.step_count = 0
        self._invalidate()
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
        if self._most_layers > 1:  # each contact's spring in series with the tool's, dampers added (Bullet's rules)
            layers = self._layers.get(name, 1)
            pybullet.changeDynamics(
                body,
                -1,
                contactStiffness=self.config.contact_stiffness / (layers - 1) if layers > 1 else _RIGID,
                contactDamping=self.config.contact_damping * (1.0 / layers - 1.0 / self._most_layers),
                physicsClientId=self._cid,
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
            elif isinstance(solid, ConvexSolid):
                vertices = solid.vertices.tolist()
                shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices, physicsClientId=cid)
                visual = pybullet.createVisualShape(
                    pybullet.GEOM_MESH,
                    vertices=vertices,
                    indices=_hull_indices(solid.vertices),
                    rgbaColor=[0.8, 0.6, 0.3, 1],
                    physicsClientId=cid,
                )
                self._static_body(name, shape, visual, solid.R, solid.p)
            elif isinstance(solid, CylinderSolid):
                # PyBullet cylinders lie along their local z; ours along the body y axis.
                R = solid.R @ matrix_from_axis_angle((1.0, 0.0, 0.0), -math.pi / 2)
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
        """The simulated state changed: every per-step quantity is read again when next asked for. Four flags, not
        one, because reading contacts or the sensor has a cost (and the sensor a state) a kinematic query must not
        pay (inverse kinematics teleports the arm hundreds of times)."""
        self._arm_fresh = self._contact_fresh = self._measured_fresh = self._mass_fresh = False

    def reset(self, q: ArrayLike | None = None) -> None:
        """Set the joints to ``q`` (default ``Q_HOME``: tool pointing down above the table) at rest."""
        self.set_joint_positions(Q_HOME if q is None else q)
        self.sensor.reset()
        self._tare[:] = 0.0
        self._tared = False
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

    def _joints_raw(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Joint positions and velocities (7,) each of this step: views of the arm state."""
        self._arm_raw()
        return self._arm_q, self._arm_qd

    def _arm_raw(self) -> NDArray[np.float64]:
        """This step's arm state (``skills.control.ROBOT_*`` layout): joints (one PyBullet query), tool pose, Jacobian,
        gravity/Coriolis (the compiled model)."""
        if not self._arm_fresh:
            states = pybullet.getJointStates(self.robot, self._queried_joints, physicsClientId=self._cid)
            if self._wrist:
                self._tool_reaction = states[N_JOINTS][2]
                states = states[:N_JOINTS]
            self._arm[_ARM_JOINTS] = [*map(_JOINT_POSITION, states), *map(_JOINT_VELOCITY, states)]  # C loops
            arm_state(self._model, self._arm, self._arm_work, True)
            self._arm_fresh = True
        return self._arm

    def joint_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Joint positions (rad) and velocities (rad/s), shape (7,) each."""
        q, qd = self._joints_raw()
        return q.copy(), qd.copy()

    def _pose_raw(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool point position (3,) and tool quaternion (4,), views of this step's arm state."""
        self._arm_raw()
        return self._arm_position, self._arm_quat

    def _rotation_raw(self) -> NDArray[np.float64]:
        self._arm_raw()
        return self._arm_rotation

    def tool_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool point position (3,) and tool orientation quaternion ``[x, y, z, w]`` (4,) in world."""
        cached = self._pose_raw()
        return cached[0].copy(), cached[1].copy()

    def tool_rotation(self) -> NDArray[np.float64]:
        """Tool orientation as a (3, 3) rotation matrix (tool frame into world)."""
        return self._rotation_raw().copy()

    def _jacobian_raw(self) -> NDArray[np.float64]:
        self._arm_raw()
        return self._arm_jacobian

    def jacobian(self) -> NDArray[np.float64]:
        """Geometric Jacobian (6, 7) of the tool point in world: ``[v; ω] = J qd``."""
        return self._jacobian_raw().copy()

    def tool_twist(self) -> NDArray[np.float64]:
        """Tool point twist ``[v, ω]`` (6,) in world (m/s, rad/s)."""
        return self._jacobian_raw() @ self._joints_raw()[1]

    def _gravity_coriolis_raw(self) -> NDArray[np.float64]:
        self._arm_raw()
        return self._arm_bias

    def gravity_coriolis_torques(self) -> NDArray[np.float64]:
        """Joint torques (7,) that cancel gravity and Coriolis/centrifugal terms (inverse dynamics, qdd = 0)."""
        return self._gravity_coriolis_raw().copy()

    def _mass_matrix_raw(self) -> NDArray[np.float64]:
        if not self._mass_fresh:
            self._mass = arm_mass_matrix(self._model, self._joints_raw()[0])
            self._mass_fresh = True
        return self._mass

    def mass_matrix(self) -> NDArray[np.float64]:
        """Joint-space mass matrix (7, 7)."""
        return self._mass_matrix_raw().copy()

    def sense(self) -> Sensing:
        """Joint state, tool pose, measured wrench and contact flag of this step in one call, without copies.

        For a control loop: one PyBullet query each (shared with the other accessors' caches), the arrays
        returned as cached (read-only by contract, see :class:`Sensing`): the same arrays every step, and with them
        the arrays of :meth:`robot_state` and :meth:`true_normal_state`, brought up to date in place.
        """
        self._arm_raw()
        self._measured_wrench()
        self._contact_summary()
        return self._sensing[self._touching]

    def robot_state(self) -> NDArray[np.float64]:
        """This step's arm state as the control law reads it (``skills.control.ROBOT_*`` layout: joints, tool pose,
        Jacobian, gravity/Coriolis torques), the cached array itself: read-only by contract, as :meth:`sense`, and
        the same array every step (a loop may hold it: :meth:`sense` updates it)."""
        return self._arm_raw()

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
        q_arr, qd_arr = self._joints_raw()
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
        forces = torque.tolist() if isinstance(torque, np.ndarray) else [float(v) for v in torque]
        clipped = any(map(operator.gt, map(abs, forces), self._torque_limits_list))  # C loops: ~4x a generator
        if clipped:
            limits = self.torque_limits
            forces = np.clip(forces, -limits, limits).tolist()
            self.clip_count += 1
        self.last_step_clipped = clipped
        pybullet.setJointMotorControlArray(
            self.robot, self._joints, pybullet.TORQUE_CONTROL, forces=forces, physicsClientId=self._cid
        )
        pybullet.stepSimulation(physicsClientId=self._cid)
        self.step_count += 1
        self._invalidate()
        if not self.sensor.ideal:  # the sensor samples every step, read or not (its filter runs on)
            self._measured_wrench()

    # -- contact -------------------------------------------------------------------------------------------------

    def _contact_points(self) -> tuple:
        self._contact_summary()
        return self._points

    def in_contact(self) -> bool:
        """Whether the tool touches anything (a contact point at zero or negative distance, or carrying force)."""
        self._contact_summary()
        return self._touching

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
        self._contact_summary()
        return self._applied.copy()

    def _contact_summary(self) -> None:
        """Read the contact points (one PyBullet query) and sum them in one pass: the exact applied wrench
        (``_applied``, see :meth:`true_contact_wrench`), the contact flag, the normal force and its direction (see
        :meth:`true_normal_force`), kept until the next step (nothing to do when this step's are read)."""
        if self._contact_fresh:
            return
        previous = self._points
        points = self._points = pybullet.getContactPoints(
            bodyA=self.robot, linkIndexA=TOOL_LINK, physicsClientId=self._cid
        )
        self._contact_fresh = True
        if not points:
            if previous:  # the summary of no points is zeros: written once, when the contact ends
                self._contact_state[:] = 0.0
            self._touching = False
        else:
            px, py, pz = self._pose_raw()[0].tolist()
            fx = fy = fz = mx = my = mz = 0.0
            nx = ny = nz = 0.0
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
                nx -= fn * n[0]
                ny -= fn * n[1]
                nz -= fn * n[2]
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if norm > 0.0:
                self._contact_state[:] = (fx, fy, fz, mx, my, mz, norm, nx / norm, ny / norm, nz / norm)
            else:
                self._contact_state[:] = (fx, fy, fz, mx, my, mz, 0.0, 0.0, 0.0, 0.0)
            self._touching = touching

    def true_normal_force(self) -> tuple[float, tuple[float, float, float]]:
        """The exact force (N) the tool presses with along the TRUE surface normal, and that normal (unit, into the
        surface, world frame; zeros without contact).

        The magnitude of the vector sum of the contact points' normal forces, each along its own contact normal (the
        collision geometry's surface normal), so it holds whatever the learned frame or the sensor say; its
        direction is the normal (on one surface its normal; in a corner, e.g. a ball pressing on both planes of a
        crease, the direction the two press along together). Friction is not part of it.
        """
        force, nx, ny, nz = self.true_normal_state().tolist()
        return force, (nx, ny, nz)

    def true_normal_state(self) -> NDArray[np.float64]:
        """:meth:`true_normal_force` as the array (4,) ``[force, nx, ny, nz]`` of this step, for a control loop's
        telemetry (the array itself, read-only as :class:`Sensing` and, as :meth:`robot_state`, the same array every
        step; ground truth, not a measurement)."""
        self._contact_summary()
        return self._true_normal

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

    def contact_wrench(self) -> NDArray[np.float64]:
        """Wrench (6,) the tool applies to the environment at the tool point, world frame, as the sensor reports it.

        With the default config (ideal sensor) this is ``true_contact_wrench()``; otherwise the sensor model of
        ``sim_worker.sensor`` (a wrist sensor, drift, noise, delay, low-pass), once per step.
        """
        return self._measured_wrench().copy()

    def wrist_wrench(self) -> NDArray[np.float64]:
        """What a wrist force/torque sensor between flange and tool reports, weight-compensated and turned into the
        convention of :meth:`true_contact_wrench` (applied by the tool, at the tool point, world frame), noise-free.

        The fixed tool joint's reaction is the force ``F`` the flange exerts on the tool, in the tool frame, and its
        moment ``M_c`` about the tool's centre of mass ``c`` (measured with PyBullet 3.2.7: ``-m g`` along the
        tool z when it hangs pointing down; a lateral force at the tool point gives ``M_c = F × c``). Tool
        equilibrium gives the applied wrench at the tool point, ``F + m g`` and ``M_c + c × (F + m g)``, minus
        the tool's inertial terms, which a real integration does not know either.
        """
        return self._wrist_wrench_into(np.empty(6))

    def _wrist_wrench_into(self, out: NDArray[np.float64]) -> NDArray[np.float64]:
        """:meth:`wrist_wrench` written into ``out`` (6,); returns it."""
        self._arm_raw()  # reads the tool joint's reaction too
        _wrist_wrench(self._tool_reaction, self._arm, self._tool_weight, self._tool_com[2], out)
        return out

    def _measured_wrench(self) -> NDArray[np.float64]:
        """This step's sensor reading (the array itself): the sensor samples once per simulated state."""
        if self.sensor.ideal:
            self._contact_summary()
            return self._applied
        if not self._measured_fresh:
            if self._wrist:
                source = self._wrist_wrench_into(self._source)
            else:
                self._contact_summary()
                source = self._applied
            self.sensor.measure_into(source, self._measured)
            if self._tool_offset is not None:  # the sensor's own offset turns with it: R_tool b (adding -(-b))
                _remove_tare(self._measured, self._arm_raw(), self._tool_offset)
            if self._tared:
                _remove_tare(self._measured, self._arm_raw(), self._tare)
            self._measured_fresh = True
        return self._measured

    @property
    def sensor_tare(self) -> NDArray[np.float64]:
        """The offset the last :meth:`tare_sensor` removes from every reading (6,), tool frame, N and N·m (a copy)."""
        return self._tare.copy()

    def tare_sensor(self, offset: ArrayLike) -> None:
        """Tare the force/torque sensor, as a real driver's bias command does: from the next reading on, ``offset``
        (6,: force N, moment N·m, in the TOOL frame: the sensor turns with the tool) is removed from every reading,
        turned into the world with the tool's orientation at that reading. ``reset()`` clears it.

        An offset that turns with the sensor (its own bias, its drift) is removed in any pose; one that is fixed in
        the world (a misestimated tool weight, ``WorldConfig.wrench_bias_n``) only in the orientation of the tare.
        The reading of the current state, which the sensor sampled at the last :meth:`step`, is tared too: the step
        after a tare reads the tared force (a phase starting right after the tare must not see the old offset).
        The ideal sensor reads the exact wrench and is never tared (ValueError)."""
        if self.sensor.ideal:
            raise ValueError("the ideal sensor reads the exact contact wrench: there is nothing to tare")
        tare = np.asarray(offset, dtype=float)
        if tare.shape != (6,) or not np.all(np.isfinite(tare)):
            raise ValueError(f"tare: expected 6 finite numbers (force N, moment N·m, tool frame), got {offset!r}")
        if self._measured_fresh:  # this state's reading was sampled before the tare: it is the first tared one
            _remove_tare(self._measured, self._arm_raw(), tare - self._tare)
        self._tare[:] = tare
        self._tared = bool(np.any(tare != 0.0))

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
                err[3:] = rotation_vector_from_matrix(target_R @ R.T)
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
