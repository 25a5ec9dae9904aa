"""The ROS 2 messages (CDR) of an execution's 3-D scene, built from its telemetry rows: what the live Foxglove server
streams and the exported MCAP holds (``services.telemetry_export``), so both look the same in Foxglove.

:class:`SceneStream` takes the store's rows (:data:`services.store.TELEMETRY_LAYOUT`) a block at a time (the whole
run for an export, each new batch live) and returns, per topic, the messages of those rows:

- ``/tf`` (``tf2_msgs/msg/TFMessage``), one tree that agrees with the URDF: per row ``world`` -> ``lbr_iiwa_link_0``
  (the URDF's root, identity), ``tool``, ``reference``, ``cf`` (at the tool point with the CF's axes,
  :func:`services.dashboard.scene.cf_rotations`) (:data:`SCENE_TRANSFORMS`: frames the URDF does not have); at the
  joint states' rows also every joint of the URDF, parent link -> child link, as ``robot_state_publisher`` sends them
  (:func:`services.dashboard.scene.link_transforms`: ``lbr_iiwa_link_0`` .. ``_7``, ``flange``, ``tool_link``);
- ``/joint_states`` (``sensor_msgs/msg/JointState``): the iiwa's joints (IK of the tool pose), at most
  :data:`JOINT_STATE_HZ`;
- ``/robot_description`` (``std_msgs/msg/String``): the URDF, once at the start;
- ``/markers`` (``visualization_msgs/msg/MarkerArray``): reference path, executed path, CF triads, touched surface
  (the work piece as found), every :data:`MARKER_PERIOD_S` of execution time and at the last row.

:func:`truth_messages` gives, of the same rows, what the simulator knows of the contact (:data:`TRUTH_TOPICS`): the
true normal force (``/force/true``, ``std_msgs/msg/Float64``, N) and whether the tool touches anything
(``/contact``, ``std_msgs/msg/Bool``), one message per row; rows stored before these columns were streamed (NaN)
give none.

:func:`skill_scene_messages` gives the same scene for a skill along the demonstration it was learned from: the robot
(when the demonstration was recorded in the robot's world), the demonstrated path and the LEARNED compliant frames.

Stamps: ns since the epoch, ``start + t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import DemonstrationArrays
from schemas.execution import PHASE_CODES, ExecutionPhase
from schemas.skill import Skill
from services.cdr import TF_TYPE, CdrLayout, tf_message
from services.dashboard.scene import (
    CF_FRAME,
    JOINT_NAMES,
    REFERENCE_FRAME,
    ROBOT_BASE_LINK,
    TOOL_FRAME,
    WORLD_FRAME,
    JointSolver,
    cf_quaternions,
    link_transforms,
    robot_description,
    urdf_joints,
)
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix

TF, JOINT_STATES, ROBOT_DESCRIPTION, MARKERS = "/tf", "/joint_states", "/robot_description", "/markers"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
STRING_TYPE, MARKER_ARRAY_TYPE = "std_msgs/msg/String", "visualization_msgs/msg/MarkerArray"
SCENE_TOPICS = {TF: TF_TYPE, JOINT_STATES: JOINT_STATE_TYPE, ROBOT_DESCRIPTION: STRING_TYPE, MARKERS: MARKER_ARRAY_TYPE}
"""The scene's topics and their ROS 2 message types."""
TRUE_FORCE, CONTACT = "/force/true", "/contact"
FLOAT64_TYPE, BOOL_TYPE = "std_msgs/msg/Float64", "std_msgs/msg/Bool"
TRUTH_TOPICS = {TRUE_FORCE: FLOAT64_TYPE, CONTACT: BOOL_TYPE}
"""The simulator's truth about the contact (:func:`truth_messages`) and their ROS 2 message types. Unstamped
``std_msgs`` (ROS 2 has no stamped scalar): a message's log time is its stamp."""
SCENE_TRANSFORMS = [(WORLD_FRAME, child) for child in (ROBOT_BASE_LINK, TOOL_FRAME, REFERENCE_FRAME, CF_FRAME)]
"""The (parent, child) transforms of every ``/tf`` message: the URDF's root link and the frames the URDF does not
have, all children of ``world``."""
JOINT_STATE_HZ = 50.0
"""Joint states per second of execution time (an IK solve each; the arm moves smoothly at this rate)."""
MARKER_PERIOD_S = 0.5
"""Markers (the paths so far) every this much execution time, s."""
PATH_STEP_M = 0.002
"""A path marker takes a point once the tool moved this far from the last one, m."""
TRIAD_STEP_M = 0.02
"""A CF triad every this much path in contact, m; its axes are :data:`TRIAD_LENGTH_M` long."""
TRIAD_LENGTH_M = 0.03
PLATE_STEP_M = 0.01
"""A plate of the touched surface every this much path in contact, m: :data:`PLATE_SIZE_M` square, 3 mm thick."""
PLATE_SIZE_M = 0.025
CONTACT_CODE = PHASE_CODES[ExecutionPhase.contact]

_FLOAT64 = CdrLayout().floats("data", 1)
_BOOL = {value: b"\x00\x01\x00\x00" + bytes([value]) for value in (False, True)}
"""``std_msgs/msg/Bool`` in CDR: the little-endian encapsulation header and one byte."""
_JOINT_STATE = CdrLayout().stamp("stamp").string("").count(len(JOINT_NAMES))
for _name in JOINT_NAMES:
    _JOINT_STATE.string(_name)
_JOINT_STATE.count(len(JOINT_NAMES)).floats("position", len(JOINT_NAMES)).count(0).count(0)


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def truth_messages(rows: NDArray[np.float64], stamps: NDArray[np.int64]) -> dict[str, tuple[NDArray[np.int64], list]]:
    """Per topic of :data:`TRUTH_TOPICS`: (stamps ns, CDR payloads) of ``rows`` (the store's columns) stamped
    ``stamps``; the rows where the column is NaN (not recorded) are left out."""
    from services.store import TELEMETRY_LAYOUT

    force = rows[:, TELEMETRY_LAYOUT["normal_force_true_n"][0]]
    contact = rows[:, TELEMETRY_LAYOUT["in_contact"][0]]
    out: dict[str, tuple[NDArray[np.int64], list]] = {}
    if (known := np.isfinite(force)).any():
        out[TRUE_FORCE] = (stamps[known], _FLOAT64.messages(data=force[known]))
    if (known := np.isfinite(contact)).any():
        out[CONTACT] = (stamps[known], [_BOOL[bool(v > 0.5)] for v in contact[known].tolist()])
    return out


@cache
def frame_parents() -> dict[str, str]:
    """Each frame's parent in the one tree ``/tf`` publishes: the URDF's links' by its joints, and ``world`` for the
    frames of :data:`SCENE_TRANSFORMS`."""
    return {**{child: parent for parent, child in SCENE_TRANSFORMS}, **{j.child: j.parent for j in urdf_joints()}}


@cache
def _tf_layout(transforms: tuple[tuple[str, str], ...]) -> CdrLayout:
    return tf_message(transforms)


def tf_payloads(stamps: NDArray[np.int64], poses: dict[str, NDArray[np.float64]], parents: dict[str, str]) -> list:
    """One ``/tf`` message per stamp (CDR): the transforms ``parents[child] -> child`` of ``poses[child]`` ((N, 7)
    translation m + ``[x, y, z, w]``; a NaN row: that transform is not in that message), in ``poses``' order."""
    present = np.column_stack([np.isfinite(pose[:, 0]) for pose in poses.values()])
    out: list = [b""] * len(stamps)
    for mask in np.unique(present, axis=0):
        rows = np.flatnonzero((present == mask).all(axis=1))
        children = [child for child, kept in zip(poses, mask.tolist(), strict=True) if kept]
        layout = _tf_layout(tuple((parents[child], child) for child in children))
        values = {child: poses[child][rows] for child in children} | {f"stamp_{c}": stamps[rows] for c in children}
        for k, payload in zip(rows.tolist(), layout.messages(**values), strict=True):
            out[k] = payload
    return out


def arm_poses(n: int, rows: NDArray[np.intp], joint_angles: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """Per child link of the URDF's joints: (n, 7) its pose in its parent link at ``rows`` (their ``joint_angles``,
    (len(rows), 7) rad), NaN at the other rows (for :func:`tf_payloads`)."""
    out = {}
    for child, pose in link_transforms(joint_angles).items():
        out[child] = np.full((n, 7), np.nan)
        out[child][rows] = pose
    return out


def robot_description_message() -> bytes:
    """The URDF (:func:`services.dashboard.scene.robot_description`) as a ``std_msgs/msg/String``, CDR."""
    store = _typestore()
    return bytes(store.serialize_cdr(_default(store, STRING_TYPE, data=robot_description()), STRING_TYPE))


def rows_every(t: NDArray[np.float64], next_t: float, period_s: float) -> tuple[NDArray[np.intp], float]:
    """The rows of times ``t`` (s) at or after ``next_t`` and then one every ``period_s`` (s) at most, and the time
    the next pick is due."""
    picked = []
    for k, time in enumerate(t.tolist()):
        if time >= next_t:
            picked.append(k)
            next_t = time + period_s
    return np.asarray(picked, dtype=np.intp), next_t


def message_definition(msgtype: str) -> str:
    """The ``ros2msg`` schema text of ``msgtype`` (with its dependencies), as MCAP and Foxglove's protocol carry it."""
    return _typestore().generate_msgdef(msgtype, ros_version=2)[0]


def _default(store: Any, msgtype: str, **fields: Any) -> Any:
    """A ``msgtype`` message: ``fields`` as given, every other field zero / empty (recursively)."""
    from rosbags.typesys.base import Nodetype

    values = {}
    for name, (kind, detail) in store.fielddefs[msgtype][1]:
        if name in fields:
            values[name] = fields[name]
        elif kind == Nodetype.NAME:
            values[name] = _default(store, detail)
        elif kind == Nodetype.BASE:
            values[name] = "" if detail[0] == "string" else (False if detail[0] == "bool" else 0)
        else:  # sequences and arrays: empty (numbers as numpy arrays, as rosbags takes them)
            element = detail[0]
            numeric = element[0] == Nodetype.BASE and element[1][0] != "string"
            values[name] = np.zeros(0, dtype=np.dtype(element[1][0]) if numeric else None) if numeric else []
    return store.types[msgtype](**values)


@dataclass
class _Paths:
    """What the markers accumulate over a run, decimated by distance (m)."""

    executed: list[list[float]] = field(default_factory=list)
    reference: list[list[float]] = field(default_factory=list)
    triads: list[tuple[list[float], NDArray[np.float64]]] = field(default_factory=list)  # (origin, R)
    plates: list[tuple[list[float], list[float], list[float]]] = field(default_factory=list)  # (centre, q, tool)


def _far(last: list[float] | None, point: list[float], step: float) -> bool:
    """Whether ``point`` is at least ``step`` (m) from ``last`` (None: nothing yet)."""
    return last is None or math.dist(point, last) >= step


class SceneStream:
    """The scene messages of one execution's telemetry, block after block (see the module docstring); ``start_ns``:
    the execution's start, ns since the epoch; ``solver``: the IK to use (one per stream: it keeps its seed)."""

    def __init__(self, start_ns: int, solver: JointSolver | None = None) -> None:
        self.start_ns = start_ns
        self.solver = solver or JointSolver()
        self.solver.reset()
        self.paths = _Paths()
        self.last_cf: NDArray[np.float64] | None = None
        self.next_joint_t = -np.inf
        self.next_marker_t = 0.0
        self.described = False

    def stamps(self, t: NDArray[np.float64]) -> NDArray[np.int64]:
        return self.start_ns + np.round(np.asarray(t) * 1e9).astype(np.int64)

    def messages(self, rows: NDArray[np.float64], final: bool = False) -> dict[str, tuple[NDArray[np.int64], list]]:
        """Per scene topic: (stamps ns, CDR payloads) of ``rows`` (the store's columns); ``final``: the run's last
        rows (the markers are sent at the last row too)."""
        from services.store import TELEMETRY_LAYOUT

        out: dict[str, tuple[NDArray[np.int64], list]] = {}
        if not len(rows):
            return out
        col = {name: rows[:, a:b] for name, (a, b) in TELEMETRY_LAYOUT.items()}
        t = col["t"][:, 0]
        stamps = self.stamps(t)
        if not self.described:
            out[ROBOT_DESCRIPTION] = (stamps[:1], [robot_description_message()])
            self.described = True
        tool_p, tool_q = col["tool_position"], col["tool_orientation"]
        cf_q = cf_quaternions(col["wrench_world"], col["wrench_cf"], self.last_cf)
        self.last_cf = matrix_from_quaternion(cf_q[-1])
        identity = np.tile([0.0, 0, 0, 0, 0, 0, 1], (len(t), 1))
        poses = {
            ROBOT_BASE_LINK: identity,
            TOOL_FRAME: np.hstack([tool_p, tool_q]),
            REFERENCE_FRAME: np.hstack([col["reference_position"], col["reference_orientation"]]),
            CF_FRAME: np.hstack([tool_p, cf_q]),
        }
        joint_rows, self.next_joint_t = rows_every(t, self.next_joint_t, 1.0 / JOINT_STATE_HZ)
        if joint_rows.size:
            q = self.solver.solve(tool_p[joint_rows], tool_q[joint_rows])
            out[JOINT_STATES] = (stamps[joint_rows], _JOINT_STATE.messages(stamp=stamps[joint_rows], position=q))
            poses |= arm_poses(len(t), joint_rows, q)
        out[TF] = (stamps, tf_payloads(stamps, poses, frame_parents()))
        self._accumulate(tool_p, col["reference_position"], cf_q, col["phase"][:, 0])
        marker_rows = self._marker_rows(t, final)
        if marker_rows:
            payload = self.markers(stamps[marker_rows[-1]])
            out[MARKERS] = (stamps[marker_rows], [payload] * len(marker_rows))
        return out

    def _marker_rows(self, t: NDArray[np.float64], final: bool) -> list[int]:
        rows, self.next_marker_t = rows_every(t, self.next_marker_t, MARKER_PERIOD_S)
        picked = rows.tolist()
        if final and (not picked or picked[-1] != len(t) - 1):
            picked.append(len(t) - 1)
        return picked

    def _accumulate(self, tool: NDArray, reference: NDArray, cf_q: NDArray, phase: NDArray) -> None:
        p = self.paths
        for k, (point, target, code) in enumerate(zip(tool.tolist(), reference.tolist(), phase.tolist(), strict=True)):
            if _far(p.executed[-1] if p.executed else None, point, PATH_STEP_M):
                p.executed.append(point)
            if _far(p.reference[-1] if p.reference else None, target, PATH_STEP_M):
                p.reference.append(target)
            if int(code) != CONTACT_CODE:
                continue
            if _far(p.triads[-1][0] if p.triads else None, point, TRIAD_STEP_M):
                p.triads.append((point, matrix_from_quaternion(cf_q[k])))
            if _far(p.plates[-1][2] if p.plates else None, point, PLATE_STEP_M):
                R = matrix_from_quaternion(cf_q[k])
                centre = tool[k] + R[:, 2] * 0.0015  # the plate's top face at the tool point, into the surface
                p.plates.append((centre.tolist(), cf_q[k].tolist(), point))

    def markers(self, stamp_ns: int) -> bytes:
        """The MarkerArray of everything accumulated so far, CDR."""
        return markers_payload(self.paths, stamp_ns)


def markers_payload(p: _Paths, stamp_ns: int, path_name: str = "executed_path") -> bytes:
    """The MarkerArray (CDR) of ``p``: the reference path (when it has points), the tool's path (namespace
    ``path_name``), the CF triads and the plates of the touched surface, stamped ``stamp_ns``."""
    s = _typestore()
    header = _default(s, "std_msgs/msg/Header", frame_id=WORLD_FRAME,
                      stamp=_default(s, "builtin_interfaces/msg/Time", sec=int(stamp_ns // 10**9),
                                     nanosec=int(stamp_ns % 10**9)))  # fmt: skip

    def point(xyz: list[float]) -> Any:
        return _default(s, "geometry_msgs/msg/Point", x=xyz[0], y=xyz[1], z=xyz[2])

    def color(r: float, g: float, b: float, a: float = 1.0) -> Any:
        return _default(s, "std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a)

    def marker(ns: str, ident: int, kind: int, **fields: Any) -> Any:
        unit = _default(s, "geometry_msgs/msg/Quaternion", w=1.0)
        fields.setdefault("pose", _default(s, "geometry_msgs/msg/Pose", orientation=unit))
        return _default(s, "visualization_msgs/msg/Marker", header=header, ns=ns, id=ident, type=kind,
                        action=0, **fields)  # fmt: skip

    line = _default(s, "geometry_msgs/msg/Vector3", x=0.002, y=0.002, z=0.002)
    markers = [marker(path_name, 0, 4, scale=line, color=color(1.0, 0.5, 0.0), points=[point(q) for q in p.executed])]
    if p.reference:
        markers.append(marker("reference_path", 0, 4, scale=line, color=color(0.2, 0.4, 1.0),
                              points=[point(q) for q in p.reference]))  # fmt: skip
    axes, colors = [], []
    for origin, R in p.triads:
        for j, rgb in enumerate(((1.0, 0.0, 0.0), (0.0, 0.8, 0.0), (0.0, 0.3, 1.0))):
            axes += [point(origin), point((np.asarray(origin) + R[:, j] * TRIAD_LENGTH_M).tolist())]
            colors += [color(*rgb), color(*rgb)]
    markers.append(marker("cf_triads", 0, 5, scale=line, color=color(1, 1, 1), points=axes, colors=colors))
    plate = _default(s, "geometry_msgs/msg/Vector3", x=PLATE_SIZE_M, y=PLATE_SIZE_M, z=0.003)
    for k, (centre, q, _) in enumerate(p.plates):
        pose = _default(
            s,
            "geometry_msgs/msg/Pose",
            position=point(centre),
            orientation=_default(s, "geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        markers.append(marker("work_piece", k, 1, pose=pose, scale=plate, color=color(0.55, 0.55, 0.6, 0.8)))
    array = _default(s, MARKER_ARRAY_TYPE, markers=markers)
    return bytes(s.serialize_cdr(array, MARKER_ARRAY_TYPE))


def skill_scene_messages(
    start_ns: int, a: DemonstrationArrays, skill: Skill, solver: JointSolver | None
) -> dict[str, tuple[NDArray[np.int64], list]]:
    """The scene of ``skill`` along the demonstration it was learned from (``a``, its samples; stamps ``start_ns +
    t``), per topic (stamps ns, CDR payloads):

    - ``/tf``: ``world`` -> ``tool`` (the demonstrated tool point) and, through each contact segment, ``cf``: the
      LEARNED compliant frame in force at that sample (the segment's frame, or its series slerped,
      ``skills.compliant_frames.compliant_frame_rotations``), at the tool point as in an execution's scene;
    - with a ``solver`` (a demonstration recorded in the robot's world, the simulator's): the robot, as for an
      execution: ``world`` -> ``lbr_iiwa_link_0`` and, at each joint state, the URDF's joints; ``/joint_states`` (IK
      of the demonstrated tool pose, :data:`JOINT_STATE_HZ`); ``/robot_description``;
    - ``/markers``, once: the demonstrated path (``demonstrated_path``) and a triad at the origin of each learned CF
      (``cf_triads``: each contact segment's first, then one every :data:`TRIAD_STEP_M` along its series)."""
    from skills.compliant_frames import compliant_frame_rotations

    n = len(a.t)
    stamps = start_ns + np.round(a.t * 1e9).astype(np.int64)
    cf, paths = np.full((n, 7), np.nan), _Paths()
    for segment in skill.segments:
        if (frames := segment.compliant_frames) is None:
            continue
        rows = np.flatnonzero((a.t >= segment.t_start) & (a.t <= segment.t_end))
        rotations = compliant_frame_rotations(segment, a.t[rows] - segment.t_start)
        cf[rows] = np.hstack([a.positions[rows], np.reshape(quaternion_from_matrix(rotations), (-1, 4))])
        first = len(paths.triads)
        for origin, q in zip(frames.origins, frames.orientations, strict=True):
            if len(paths.triads) == first or _far(paths.triads[-1][0], origin, TRIAD_STEP_M):
                paths.triads.append((list(origin), matrix_from_quaternion(q)))
    for point in a.positions.tolist():
        if _far(paths.executed[-1] if paths.executed else None, point, PATH_STEP_M):
            paths.executed.append(point)
    poses = {TOOL_FRAME: np.hstack([a.positions, a.orientations]), CF_FRAME: cf}
    out: dict[str, tuple[NDArray[np.int64], list]] = {}
    if solver is not None:
        solver.reset()
        joint_rows, _ = rows_every(a.t, -np.inf, 1.0 / JOINT_STATE_HZ)
        q = solver.solve(a.positions[joint_rows], a.orientations[joint_rows])
        out[JOINT_STATES] = (stamps[joint_rows], _JOINT_STATE.messages(stamp=stamps[joint_rows], position=q))
        out[ROBOT_DESCRIPTION] = (stamps[:1], [robot_description_message()])
        poses = {ROBOT_BASE_LINK: np.tile([0.0, 0, 0, 0, 0, 0, 1], (n, 1)), **poses, **arm_poses(n, joint_rows, q)}
    out[TF] = (stamps, tf_payloads(stamps, poses, frame_parents()))
    out[MARKERS] = (stamps[:1], [markers_payload(paths, int(stamps[0]), "demonstrated_path")])
    return out
