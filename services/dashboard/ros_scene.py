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

Stamps: ns since the epoch, ``start + t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from schemas.execution import PHASE_CODES, ExecutionPhase
from services.cdr import CdrLayout, tf_message
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
from skills.quaternions import matrix_from_quaternion

TF, JOINT_STATES, ROBOT_DESCRIPTION, MARKERS = "/tf", "/joint_states", "/robot_description", "/markers"
TF_TYPE, JOINT_STATE_TYPE = "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/JointState"
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

_TF = tf_message(SCENE_TRANSFORMS)
_FLOAT64 = CdrLayout().floats("data", 1)
_BOOL = {value: b"\x00\x01\x00\x00" + bytes([value]) for value in (False, True)}
"""``std_msgs/msg/Bool`` in CDR: the little-endian encapsulation header and one byte."""
_JOINTS = CdrLayout().stamp("stamp").string("").count(len(JOINT_NAMES))
for _name in JOINT_NAMES:
    _JOINTS.string(_name)
_JOINTS.count(len(JOINT_NAMES)).floats("position", len(JOINT_NAMES)).count(0).count(0)


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
def _tf_with_arm() -> CdrLayout:
    """The ``/tf`` of a joint state's row: :data:`SCENE_TRANSFORMS` and every joint of the URDF."""
    return tf_message(SCENE_TRANSFORMS + [(joint.parent, joint.child) for joint in urdf_joints()])


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
        self.store = _typestore()

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
            text = _default(self.store, STRING_TYPE, data=robot_description())
            out[ROBOT_DESCRIPTION] = (stamps[:1], [bytes(self.store.serialize_cdr(text, STRING_TYPE))])
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
        transforms = _TF.messages(**poses, **{f"stamp_{child}": stamps for _, child in SCENE_TRANSFORMS})
        joint_rows = self._joint_rows(t)
        if joint_rows.size:
            q = self.solver.solve(tool_p[joint_rows], tool_q[joint_rows])
            out[JOINT_STATES] = (stamps[joint_rows], _JOINTS.messages(stamp=stamps[joint_rows], position=q))
            arm = {**{name: pose[joint_rows] for name, pose in poses.items()}, **link_transforms(q)}
            with_arm = _tf_with_arm().messages(**arm, **{f"stamp_{child}": stamps[joint_rows] for child in arm})
            for k, payload in zip(joint_rows.tolist(), with_arm, strict=True):
                transforms[k] = payload
        out[TF] = (stamps, transforms)
        self._accumulate(tool_p, col["reference_position"], cf_q, col["phase"][:, 0])
        marker_rows = self._marker_rows(t, final)
        if marker_rows:
            payload = self.markers(stamps[marker_rows[-1]])
            out[MARKERS] = (stamps[marker_rows], [payload] * len(marker_rows))
        return out

    def _joint_rows(self, t: NDArray[np.float64]) -> NDArray[np.intp]:
        picked = []
        for k, time in enumerate(t.tolist()):
            if time >= self.next_joint_t:
                picked.append(k)
                self.next_joint_t = time + 1.0 / JOINT_STATE_HZ
        return np.asarray(picked, dtype=np.intp)

    def _marker_rows(self, t: NDArray[np.float64], final: bool) -> list[int]:
        picked = []
        for k, time in enumerate(t.tolist()):
            if time >= self.next_marker_t:
                picked.append(k)
                self.next_marker_t = time + MARKER_PERIOD_S
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
        s, p = self.store, self.paths
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
        markers = [
            marker("reference_path", 0, 4, scale=line, color=color(0.2, 0.4, 1.0), points=[point(q) for q in
                   p.reference]),
            marker("executed_path", 0, 4, scale=line, color=color(1.0, 0.5, 0.0), points=[point(q) for q in
                   p.executed]),
        ]  # fmt: skip
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
