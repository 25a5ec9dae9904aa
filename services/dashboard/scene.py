"""What Foxglove shows of an execution, derived from its telemetry alone (the live server and the exported MCAP build
the same messages from the same rows, so a recorded run looks like the live one):

- the robot: the iiwa URDF the simulator loads (PyBullet's ``kuka_iiwa/model.urdf``) with the flange and the tool
  appended, its meshes as ``package://kuka_iiwa/meshes/*.stl`` (served by the live server's asset handler, and found
  by Foxglove desktop in a ROS package path); its joint angles, which the telemetry does not carry, solved from the
  measured tool pose by inverse kinematics (:class:`JointSolver`): the arm drawn is an IK solution of the tool pose,
  the tool pose itself is exact;
- the compliant frame the controller used at each step, recovered EXACTLY from the two wrenches the worker records
  (``wrench_cf = [R^T f, R^T m]`` of ``wrench_world = [f, m]``, ``sim_worker/executor.py``): two non-parallel
  vectors known in both frames fix ``R`` (:func:`cf_rotations`); where the wrench is zero (free space with the ideal
  sensor) the last recovered frame is kept;
- markers: the reference path (the taught path as placed and offset, what the controller followed), the executed
  tool path, CF triads along it, and the touched surface (a thin plate under every stretch of contact, normal to
  the CF z there): the work piece as the tool found it.

Frames: one tree that agrees with the URDF. ``world`` is the root; the URDF's root link ``lbr_iiwa_link_0`` (the
robot base) sits at its origin, and every link of the URDF hangs off its parent link by its joint
(:func:`urdf_joints`, :func:`link_transforms`: ``lbr_iiwa_link_1`` .. ``lbr_iiwa_link_7``, ``flange``,
``tool_link``); frames the URDF does not have are children of ``world``: ``tool`` (the measured tool point, exact),
``reference`` and ``cf`` (at the tool point, the compliance centre, with the CF's axes). SI units, quaternions
``[x, y, z, w]``.
"""

from __future__ import annotations

import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skills.quaternions import matrix_from_quaternion, quaternion_exp, quaternion_from_matrix, quaternion_product

WORLD_FRAME, TOOL_FRAME, REFERENCE_FRAME, CF_FRAME, FLANGE_FRAME = "world", "tool", "reference", "cf", "flange"
ROBOT_BASE_LINK = "lbr_iiwa_link_0"
"""The URDF's root link, at the world origin (the simulator loads the arm with its base there)."""
TOOL_LINK_NAME = f"{TOOL_FRAME}_link"
"""The URDF's tool (shaft and ball, its origin at the tool point): where the arm's joints put the tool, within the IK's
residual of the measured ``tool`` frame."""
JOINT_NAMES = [f"lbr_iiwa_joint_{k}" for k in range(1, 8)]
LINK7_TO_FLANGE_M = 0.045
LINK7_TO_TOOL_POINT_M = 0.125
"""Along link 7's z: the flange, and the tool point of the simulated tool (shaft 70 mm + ball 10 mm beyond the
flange; ``sim_worker/robot_model.py``, which ``services`` may not import: tests/test_foxglove.py holds the two
equal)."""
HOME_JOINTS = (0.0, 0.5325, 0.0, -1.6083, 0.0, 1.0008, 0.0)
"""The IK's first seed, rad (the arm's home posture); each later solve starts from the previous solution."""
ROBOT_PACKAGE = "kuka_iiwa"
MESH_URI = f"package://{ROBOT_PACKAGE}/meshes/"
REACH_TOLERANCE_M = 0.005
"""How far from a wanted tool pose an inverse kinematics solution may leave link 7 and still count as reaching it, m."""
MIN_WRENCH_N = 1e-9
"""Below this force or moment magnitude (N, N·m) a sample does not fix the CF (it is kept from the last one)."""


def _robot_data() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / ROBOT_PACKAGE


def robot_description() -> str:
    """The URDF Foxglove draws: the simulator's iiwa, STL meshes by ``package://`` URI, a ``flange`` link and a
    ``tool`` link (shaft and ball, the tool point at its origin) on fixed joints of link 7."""
    text = (_robot_data() / "model.urdf").read_text(encoding="utf-8")
    text = text.replace('filename="meshes/', f'filename="{MESH_URI}').replace('.obj"', '.stl"')  # Foxglove: STL
    shaft = LINK7_TO_TOOL_POINT_M - LINK7_TO_FLANGE_M
    extra = f"""
  <joint name="flange_joint" type="fixed">
    <parent link="lbr_iiwa_link_7"/><child link="{FLANGE_FRAME}"/><origin xyz="0 0 {LINK7_TO_FLANGE_M}" rpy="0 0 0"/>
  </joint>
  <link name="{FLANGE_FRAME}"/>
  <joint name="tool_joint" type="fixed">
    <parent link="{FLANGE_FRAME}"/><child link="{TOOL_LINK_NAME}"/><origin xyz="0 0 {shaft:.6f}" rpy="0 0 0"/>
  </joint>
  <link name="{TOOL_LINK_NAME}">
    <visual><origin xyz="0 0 {-shaft / 2:.6f}" rpy="0 0 0"/><geometry><cylinder radius="0.008" length="{shaft:.6f}"/>
      </geometry><material name="Grey"><color rgba="0.6 0.6 0.6 1"/></material></visual>
    <visual><origin xyz="0 0 -0.01" rpy="0 0 0"/><geometry><sphere radius="0.01"/></geometry>
      <material name="Orange"><color rgba="1 0.5 0 1"/></material></visual>
  </link>
"""
    return text.replace("</robot>", extra + "</robot>")


@dataclass(frozen=True)
class UrdfJoint:
    """A joint of the URDF: ``child`` in ``parent`` is the joint's origin (``xyz`` m, ``quaternion`` ``[x, y, z, w]``)
    then, for a revolute joint, the rotation by its angle about ``axis`` (the child's frame)."""

    name: str
    parent: str
    child: str
    revolute: bool
    xyz: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    axis: tuple[float, float, float]


def _quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """``[x, y, z, w]`` of a URDF ``rpy`` (rad): about the fixed x, then y, then z (``Rz(yaw) Ry(pitch) Rx(roll)``)."""
    about = [quaternion_exp(np.eye(3)[k] * angle / 2) for k, angle in enumerate((roll, pitch, yaw))]
    return quaternion_product(about[2], quaternion_product(about[1], about[0]))


@cache
def urdf_joints() -> tuple[UrdfJoint, ...]:
    """The joints of the URDF Foxglove draws (:func:`robot_description`), in the file's order (each parent before its
    children)."""
    joints = []
    for joint in ET.fromstring(robot_description()).findall("joint"):
        origin, axis = joint.find("origin"), joint.find("axis")
        xyz = [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
        rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
        joints.append(UrdfJoint(
            name=joint.get("name", ""), parent=joint.find("parent").get("link"), child=joint.find("child").get("link"),
            revolute=joint.get("type") in ("revolute", "continuous"), xyz=(xyz[0], xyz[1], xyz[2]),
            quaternion=tuple(_quaternion_from_rpy(*rpy).tolist()),
            axis=tuple(float(v) for v in (axis.get("xyz") if axis is not None else "1 0 0").split()),
        ))  # fmt: skip
    return tuple(joints)


def link_transforms(joint_angles: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """Per child link of :func:`urdf_joints`: (N, 7) its pose in its parent link, translation m + ``[x, y, z, w]``, for
    (N, 7) angles (rad) of :data:`JOINT_NAMES` (what ``robot_state_publisher`` publishes on ``/tf``)."""
    q = np.asarray(joint_angles, dtype=float).reshape(-1, len(JOINT_NAMES))
    angle = dict(zip(JOINT_NAMES, q.T, strict=True))
    out = {}
    for joint in urdf_joints():
        rotation = np.tile(joint.quaternion, (len(q), 1))
        if joint.revolute:
            turn = quaternion_exp(np.outer(angle[joint.name] / 2, np.asarray(joint.axis) / np.linalg.norm(joint.axis)))
            rotation = quaternion_product(rotation, turn)
        out[joint.child] = np.hstack([np.tile(joint.xyz, (len(q), 1)), rotation])
    return out


def robot_asset(uri: str) -> bytes | None:
    """The mesh a ``package://kuka_iiwa/meshes/NAME.stl`` URI names, or None (another URI, a path out of the folder)."""
    if not uri.startswith(MESH_URI):
        return None
    name = uri[len(MESH_URI) :]
    if "/" in name or "\\" in name or name.startswith(".") or not name.endswith(".stl"):
        return None
    path = _robot_data() / "meshes" / name
    return path.read_bytes() if path.is_file() else None


class JointSolver:
    """Joint angles (rad) of the simulated iiwa for tool poses, by PyBullet's inverse kinematics (DIRECT, its own
    physics client), each solve seeded by the previous one so a stream gives a continuous arm. Thread-safe."""

    def __init__(self) -> None:
        import pybullet

        self._p = pybullet
        self._lock = threading.RLock()  # re-entered by reached(), which solves and reads the pose in one hold
        self._client = pybullet.connect(pybullet.DIRECT)
        self._robot = pybullet.loadURDF(
            str(_robot_data() / "model.urdf"), useFixedBase=True, physicsClientId=self._client
        )
        self.reset()

    def reset(self) -> None:
        """Seed the next solve with the home posture (a new execution)."""
        with self._lock:
            for k, q in enumerate(HOME_JOINTS):
                self._p.resetJointState(self._robot, k, q, physicsClientId=self._client)

    def solve(self, tool_positions: NDArray[np.float64], tool_orientations: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 7) joint angles, rad, for tool points (N, 3) m and orientations (N, 4) ``[x, y, z, w]``, world."""
        R = matrix_from_quaternion(tool_orientations).reshape(-1, 3, 3)
        link7 = tool_positions - R[:, :, 2] * LINK7_TO_TOOL_POINT_M  # link 7's origin, back along the tool axis
        out = np.empty((len(tool_positions), len(JOINT_NAMES)))
        p, cid = self._p, self._client
        with self._lock:
            for k, (position, orientation) in enumerate(zip(link7.tolist(), tool_orientations.tolist(), strict=True)):
                q = p.calculateInverseKinematics(self._robot, 6, position, orientation, maxNumIterations=100,
                                                 residualThreshold=1e-6, physicsClientId=cid)  # fmt: skip
                for j, angle in enumerate(q):
                    p.resetJointState(self._robot, j, angle, physicsClientId=cid)  # the next solve's seed
                out[k] = q
        return out

    def reached(self, tool_position: NDArray[np.float64], tool_orientation: NDArray[np.float64]) -> list[float] | None:
        """The 7 joint angles (rad) that put the tool at ``tool_position`` (3,) m with ``tool_orientation`` (4,)
        ``[x, y, z, w]``, world; None when the arm does not reach it (its solution's tool point further than
        :data:`REACH_TOLERANCE_M` from it: a recording made away from the robot, before a placement). Solved from
        the home posture."""
        with self._lock:
            self.reset()
            joints = self.solve(tool_position[None], tool_orientation[None])[0]
            link7 = np.array(self._p.getLinkState(self._robot, 6, computeForwardKinematics=True,
                                                  physicsClientId=self._client)[4])  # fmt: skip
        wanted = tool_position - matrix_from_quaternion(tool_orientation)[:, 2] * LINK7_TO_TOOL_POINT_M
        return joints.tolist() if np.linalg.norm(link7 - wanted) <= REACH_TOLERANCE_M else None

    def close(self) -> None:
        with self._lock:
            if self._client >= 0:
                self._p.disconnect(physicsClientId=self._client)
                self._client = -1


def _triad(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3, 3) orthonormal bases (columns) from vectors ``a`` and ``b`` (N, 3): a, a x b, a x (a x b)."""
    e1 = a / np.linalg.norm(a, axis=1, keepdims=True)
    c = np.cross(a, b)
    e2 = c / np.linalg.norm(c, axis=1, keepdims=True)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=2)


def cf_rotations(wrench_world: NDArray[np.float64], wrench_cf: NDArray[np.float64],
                 initial: NDArray[np.float64] | None = None) -> NDArray[np.float64]:  # fmt: skip
    """(N, 3, 3) world-from-CF rotations the controller used: ``R`` with ``f_world = R f_cf`` and ``m_world = R m_cf``
    (force and moment of each (N, 6) wrench). Where force or moment is below :data:`MIN_WRENCH_N` or they are
    parallel, the previous sample's (``initial`` before the first; identity if None) is kept."""
    fw, mw, fc, mc = wrench_world[:, :3], wrench_world[:, 3:], wrench_cf[:, :3], wrench_cf[:, 3:]
    scale = np.linalg.norm(fw, axis=1) * np.linalg.norm(mw, axis=1)
    ok = (np.linalg.norm(fw, axis=1) > MIN_WRENCH_N) & (np.linalg.norm(mw, axis=1) > MIN_WRENCH_N)
    ok &= np.linalg.norm(np.cross(fw, mw), axis=1) > 1e-6 * np.where(scale > 0, scale, 1.0)
    out = np.empty((len(fw), 3, 3))
    if ok.any():
        out[ok] = _triad(fw[ok], mw[ok]) @ np.transpose(_triad(fc[ok], mc[ok]), (0, 2, 1))
    last = np.eye(3) if initial is None else initial
    for k in np.flatnonzero(~ok):  # carry the last recovered frame forward
        out[k] = out[k - 1] if k > 0 else last
    return out


def cf_quaternions(wrench_world: NDArray[np.float64], wrench_cf: NDArray[np.float64],
                   initial: NDArray[np.float64] | None = None) -> NDArray[np.float64]:  # fmt: skip
    """(N, 4) ``[x, y, z, w]`` of :func:`cf_rotations`, sign-continuous."""
    q = np.asarray(quaternion_from_matrix(cf_rotations(wrench_world, wrench_cf, initial))).reshape(-1, 4)
    flip = np.sign(np.einsum("ij,ij->i", q[1:], q[:-1]))
    q[1:] *= np.where(np.cumprod(np.where(flip == 0, 1, flip)) < 0, -1.0, 1.0)[:, None]
    return q
