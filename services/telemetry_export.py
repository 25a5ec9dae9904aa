"""Demonstrations and execution telemetry out: CSV, and MCAP with ROS 2 message types that Foxglove and PlotJuggler
open without configuration.

MCAP (profile ``ros2``, schemas ``ros2msg``, messages CDR-encoded with the ``rosbags`` type store for ROS 2 Humble,
zstd chunks, written with the ``mcap`` library). Every message is stamped ``start + t`` (ns since the epoch;
``start`` the record's creation time) in its header and as its log and publish time. Topics:

- ``/tool/pose`` (``geometry_msgs/msg/PoseStamped``, ``world``): the tool point and orientation;
- ``/reference/pose`` (PoseStamped, ``world``): the controller's reference (executions);
- ``/wrench/world`` (``geometry_msgs/msg/WrenchStamped``, ``world``): the wrench the tool applies, world axes,
  moment about the TOOL POINT (the project's convention);
- ``/wrench/cf`` (WrenchStamped, ``cf``): the same wrench in the compliant frame, force z into the surface
  (executions);
- ``/force/desired`` (WrenchStamped, ``cf``): the desired CF force on force z, zero elsewhere (executions);
- ``/phase`` (``std_msgs/msg/String``) and ``/segment`` (``std_msgs/msg/Int32``): at the start and at every
  change (executions);
- ``/tf`` (``tf2_msgs/msg/TFMessage``): ``world -> tool`` (and, for an execution, ``world -> reference``, ``cf``
  and the robot's base link ``lbr_iiwa_link_0``, and at each joint state the URDF's joints, link to link down to
  ``flange`` and ``tool_link``: one tree that agrees with the URDF), for the 3D panels;
- executions also: ``/joint_states`` (``sensor_msgs/msg/JointState``), ``/robot_description`` (the URDF,
  ``std_msgs/msg/String``) and ``/markers`` (``visualization_msgs/msg/MarkerArray``: reference and executed paths,
  CF triads, the touched surface): the scene the live Foxglove server streams, built by the same code
  (``services.dashboard.ros_scene``), so a recorded run looks in Foxglove as the live one did.

A skill's plan for a real cell (``schemas.skill_plan.SkillPlan``, docs/REAL_CELL.md) as MCAP (:func:`plan_mcap`):
every sample stamped ``t`` (ns from 0, the plan's start) on ``/reference/pose`` (PoseStamped, ``world``: the reference
tool pose), ``/reference/twist`` (``geometry_msgs/msg/TwistStamped``, ``world`` axes), ``/cf/pose`` (PoseStamped,
``world``: the compliant frame, world from CF), ``/force/desired`` (WrenchStamped, ``cf``: the desired force on force
z); ``/phase``, ``/segment`` and ``/selection`` (``std_msgs/msg/Int32MultiArray``, the diagonal of S in the CF) at the
start and at every change; ``/tf`` ``world -> reference`` and ``world -> cf``; the plan's other fields (format,
version, skill, controller, gains, placement, control period, every, touch-down speed) as JSON in the metadata record
``contact_skills`` (``plan``).

A demonstration's MCAP is also a bag ``contact-skills learn`` reads back (the wrench is in ``world``, the pose
frame). CSV: one row per sample, the columns named in :data:`EXECUTION_CSV_COLUMNS` (an execution) or the
importer's own columns (a demonstration: `services.csv_import.demonstration_csv_text`).

An execution's telemetry is read a page at a time (:func:`telemetry_page`: at most a fixed number of samples from a
cursor on, in a time window, decimated), and its JSON and CSV are produced in chunks of rows
(:func:`execution_json_chunks`, :func:`execution_csv_chunks`), so a reply is streamed, never built whole.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.demonstration import DemonstrationArrays
from schemas.execution import PHASE_CODES, STREAMED_TELEMETRY_WIDTH
from schemas.skill import Skill
from schemas.skill_plan import SkillPlan
from schemas.telemetry_rows import telemetry_column
from services.cdr import (
    POSE_TYPE,
    TF_TYPE,
    TWIST_TYPE,
    WRENCH_TYPE,
    pose_stamped,
    tf_message,
    twist_stamped,
    wrench_stamped,
)
from services.dashboard.scene import CF_FRAME, REFERENCE_FRAME, TOOL_FRAME, WORLD_FRAME
from services.store import TELEMETRY_LAYOUT

PHASE_NAMES = {code: phase.value for phase, code in PHASE_CODES.items()}
MCAP_MEDIA_TYPE = "application/octet-stream"
CSV_MEDIA_TYPE = "text/csv"
CONVENTIONS = (
    "SI units; quaternions [x, y, z, w]; /wrench/world is the wrench the tool applies, world axes, moment about the "
    "tool point; /wrench/cf the same in the compliant frame (force z into the surface); stamps = start + t"
)
"""Stored in the file's metadata record ``contact_skills``."""
CHUNK_ROWS = 2000
"""Rows per chunk of a streamed JSON or CSV reply (~1 MB of text)."""
_NON_FINITE_JSON = re.compile(r"-?Infinity|NaN")


def _expanded(name: str, width: int) -> list[str]:
    suffixes = {
        3: ["x", "y", "z"],
        4: ["qx", "qy", "qz", "qw"],
        6: ["fx", "fy", "fz", "mx", "my", "mz"],
    }
    return [name] if width == 1 else [f"{name}_{suffix}" for suffix in suffixes[width]]


EXECUTION_CSV_COLUMNS = [c for name, (a, b) in TELEMETRY_LAYOUT.items() for c in _expanded(name, b - a)]
"""Columns of an execution's CSV: t (s), phase (name), segment_index, each vector's components (SI, [x, y, z, w])."""


def window_mask(t: np.ndarray, t0: float | None, t1: float | None) -> np.ndarray:
    """The samples with ``t0 <= t <= t1`` (s; None: unbounded)."""
    mask = np.ones(t.shape, dtype=bool)
    if t0 is not None:
        mask &= t >= t0
    if t1 is not None:
        mask &= t <= t1
    return mask


# --------------------------------------------------------------------------- pages


@dataclass(frozen=True)
class TelemetryPage:
    """One page of an execution's stored telemetry."""

    rows: np.ndarray
    """The samples picked, rows of the store's matrix (:data:`services.store.TELEMETRY_LAYOUT`)."""
    next_cursor: int | None
    """The stream index of the next page's first sample (None: this page is the last)."""


def telemetry_page(
    blocks: Iterable[tuple[int, np.ndarray]], cursor: int, every: int, t0: float | None, t1: float | None, limit: int
) -> TelemetryPage:
    """At most ``limit`` samples of ``blocks`` (``Store.telemetry_blocks``: (stream index of the first row, rows))
    from stream index ``cursor`` on: those with ``t0 <= t <= t1`` (s), every ``every``-th of them from the first.
    The next page, from its ``next_cursor``, goes on where this one stopped as if there were one page."""
    picked: list[np.ndarray] = []
    taken, skip = 0, 0
    for first, block in blocks:
        index = first + np.arange(block.shape[0])
        windowed = np.flatnonzero((index >= cursor) & window_mask(block[:, 0], t0, t1))
        picks = windowed[skip::every]
        skip += every * picks.size - windowed.size  # windowed samples still to pass before the next pick
        if picks.size > limit - taken:
            picked.append(block[picks[: limit - taken]])
            return TelemetryPage(np.concatenate(picked), int(first + picks[limit - taken]))
        picked.append(block[picks])
        taken += picks.size
        if t1 is not None and block.shape[0] and block[-1, 0] > t1:
            break  # time increases along the stream: nothing further is in the window
    rows = np.concatenate(picked) if picked else np.empty((0, STREAMED_TELEMETRY_WIDTH))
    return TelemetryPage(rows, None)


def execution_json_chunks(head: Mapping[str, object], matrix: np.ndarray) -> Iterator[str]:
    """A JSON object of ``head``'s (JSON-able) members then the columns of ``matrix`` (the store's rows;
    `TelemetryBatch` fields, phases as names), in chunks of :data:`CHUNK_ROWS` rows (a non-finite value, never
    expected, as null)."""
    yield "{" + ",".join(f"{json.dumps(key)}:{json.dumps(value)}" for key, value in head.items())
    for name in TELEMETRY_LAYOUT:
        yield f",{json.dumps(name)}:["
        separator = ""  # none before the first value (a column not recorded has none)
        for a in range(0, matrix.shape[0], CHUNK_ROWS):
            if text := json.dumps(telemetry_column(matrix[a : a + CHUNK_ROWS], name))[1:-1]:
                yield separator + _NON_FINITE_JSON.sub("null", text)
                separator = ","
        yield "]"
    yield "}"


# --------------------------------------------------------------------------- CSV


def execution_csv(matrix: np.ndarray) -> str:
    """An execution's telemetry (rows of the store's matrix, :data:`services.store.TELEMETRY_LAYOUT`) as CSV text."""
    return "".join(execution_csv_chunks(matrix))


def execution_csv_chunks(matrix: np.ndarray) -> Iterator[str]:
    """:func:`execution_csv` in chunks: the header row, then :data:`CHUNK_ROWS` rows at a time."""
    yield ",".join(EXECUTION_CSV_COLUMNS) + "\n"
    for a in range(0, matrix.shape[0], CHUNK_ROWS):
        chunk = matrix[a : a + CHUNK_ROWS]
        numbers = np.delete(chunk, TELEMETRY_LAYOUT["phase"][0], axis=1)  # t, segment_index, the vectors
        lines = [
            ",".join([repr(float(row[0])), phase, str(int(row[1])), *(repr(float(v)) for v in row[2:])])
            for phase, row in zip(telemetry_column(chunk, "phase"), numbers, strict=True)
        ]
        yield "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- MCAP


class _McapOut:
    """An MCAP file in memory with ROS 2 schemas (``ros2msg``) and CDR messages."""

    def __init__(self, start_ns: int, metadata: dict[str, str]) -> None:
        from mcap.writer import CompressionType, Writer
        from rosbags.typesys import Stores, get_typestore

        self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        self.start_ns = start_ns
        self.buffer = io.BytesIO()
        self.writer = Writer(self.buffer, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="contact-skills")
        self.writer.add_metadata("contact_skills", metadata)
        self._schemas: dict[str, int] = {}

    def stamps(self, t: np.ndarray) -> np.ndarray:
        """Nanoseconds since the epoch of times ``t`` (s from the start)."""
        return self.start_ns + np.round(np.asarray(t) * 1e9).astype(np.int64)

    def write(self, topic: str, msgtype: str, stamps_ns: np.ndarray, payloads: Sequence[bytes]) -> None:
        """CDR ``payloads`` of ``msgtype`` on ``topic``, logged and published at ``stamps_ns``."""
        if msgtype not in self._schemas:
            definition = self.typestore.generate_msgdef(msgtype, ros_version=2)[0]
            self._schemas[msgtype] = self.writer.register_schema(msgtype, "ros2msg", definition.encode())
        channel = self.writer.register_channel(topic, "cdr", self._schemas[msgtype])
        add = self.writer.add_message
        for sequence, (stamp, data) in enumerate(zip(stamps_ns.tolist(), payloads, strict=True)):
            add(channel, stamp, data, stamp, sequence)

    def finish(self) -> bytes:
        self.writer.finish()
        return self.buffer.getvalue()


@dataclass(frozen=True)
class McapExport:
    """An exported MCAP file and what it holds."""

    data: bytes
    messages: int
    topics: list[str]


PHASE_TYPE, SEGMENT_TYPE = "std_msgs/msg/String", "std_msgs/msg/Int32"
_POSE, _WRENCH_WORLD, _WRENCH_CF = pose_stamped(WORLD_FRAME), wrench_stamped(WORLD_FRAME), wrench_stamped(CF_FRAME)


def execution_topics() -> dict[str, str]:
    """Every topic of an execution (MCAP export and live Foxglove) and its ROS 2 message type."""
    from services.dashboard.ros_scene import SCENE_TOPICS, TRUTH_TOPICS

    return {"/tool/pose": POSE_TYPE, "/reference/pose": POSE_TYPE, "/wrench/world": WRENCH_TYPE,
            "/wrench/cf": WRENCH_TYPE, "/force/desired": WRENCH_TYPE, "/phase": PHASE_TYPE, "/segment": SEGMENT_TYPE,
            **SCENE_TOPICS, **TRUTH_TOPICS}  # fmt: skip


class ExecutionMessages:
    """The CDR messages of an execution's telemetry, block after block (the whole run for an export, each new batch
    live): per topic of :func:`execution_topics`, (stamps ns, payloads). ``start_ns``: the execution's start, ns since
    the epoch; ``solver``: the IK of the scene's joint states (`services.dashboard.scene.JointSolver`)."""

    def __init__(self, start_ns: int, solver: Any = None) -> None:
        from rosbags.typesys import Stores, get_typestore

        from services.dashboard.ros_scene import SceneStream

        self.scene = SceneStream(start_ns, solver)
        self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        self.last: dict[str, str | int] = {}  # /phase (its name), /segment (its index): the value last sent

    def messages(self, matrix: np.ndarray, final: bool = False) -> dict[str, tuple[np.ndarray, list[bytes]]]:
        """The messages of ``matrix`` (the store's rows, following those given before); ``final``: the run's end."""
        if not matrix.shape[0]:
            return {}
        column = {name: matrix[:, a:b] for name, (a, b) in TELEMETRY_LAYOUT.items()}
        stamps = self.scene.stamps(column["t"][:, 0])
        tool = np.hstack([column["tool_position"], column["tool_orientation"]])
        reference = np.hstack([column["reference_position"], column["reference_orientation"]])
        desired = np.zeros((matrix.shape[0], 6))
        desired[:, 2] = column["desired_force_cf_z_n"][:, 0]
        out = {
            "/tool/pose": (stamps, _POSE.messages(stamp=stamps, pose=tool)),
            "/reference/pose": (stamps, _POSE.messages(stamp=stamps, pose=reference)),
            "/wrench/world": (stamps, _WRENCH_WORLD.messages(stamp=stamps, wrench=column["wrench_world"])),
            "/wrench/cf": (stamps, _WRENCH_CF.messages(stamp=stamps, wrench=column["wrench_cf"])),
            "/force/desired": (stamps, _WRENCH_CF.messages(stamp=stamps, wrench=desired)),
        }
        phases = [PHASE_NAMES.get(int(code), "failed") for code in column["phase"][:, 0]]
        out["/phase"] = self._changes("/phase", PHASE_TYPE, stamps, phases)
        segments = [int(v) for v in column["segment_index"][:, 0]]
        out["/segment"] = self._changes("/segment", SEGMENT_TYPE, stamps, segments)
        from services.dashboard.ros_scene import truth_messages

        return {**out, **self.scene.messages(matrix, final), **truth_messages(matrix, stamps)}

    def _changes(
        self, topic: str, msgtype: str, stamps: np.ndarray, values: Sequence[str | int]
    ) -> tuple[np.ndarray, list]:
        """``values`` as ``std_msgs`` messages (``data``) where the value differs from the one before (the first
        value of a stream included)."""
        kept = []
        for k, value in enumerate(values):
            if topic not in self.last or value != self.last[topic]:
                kept.append(k)
                self.last[topic] = value
        message = self.typestore.types[msgtype]
        payloads = [bytes(self.typestore.serialize_cdr(message(data=values[k]), msgtype)) for k in kept]
        return stamps[kept], payloads


def execution_mcap(matrix: np.ndarray, start_unix_s: float, execution_id: str) -> McapExport:
    """An execution's telemetry (the store's matrix rows) as MCAP (see the module docstring for the topics)."""
    out = _McapOut(int(start_unix_s * 1e9), {"execution_id": execution_id, "conventions": CONVENTIONS})
    topics = execution_topics()
    for topic, (stamps, payloads) in ExecutionMessages(out.start_ns).messages(matrix, final=True).items():
        out.write(topic, topics[topic], stamps, payloads)
    return _finished(out)


def _write_samples(out: _McapOut, a: DemonstrationArrays) -> np.ndarray:
    """A demonstration's ``/tool/pose`` and ``/wrench/world`` into ``out``; returns their stamps (ns)."""
    stamps = out.stamps(a.t)
    tool = np.hstack([a.positions, a.orientations])
    out.write("/tool/pose", POSE_TYPE, stamps, _POSE.messages(stamp=stamps, pose=tool))
    out.write("/wrench/world", WRENCH_TYPE, stamps, _WRENCH_WORLD.messages(stamp=stamps, wrench=a.wrenches))
    return stamps


def demonstration_mcap(a: DemonstrationArrays, name: str, start_unix_s: float) -> McapExport:
    """A demonstration's samples (``name``: the demonstration's) as MCAP: ``/tool/pose``, ``/wrench/world``, ``/tf``."""
    out = _McapOut(int(start_unix_s * 1e9), {"demonstration": name, "conventions": CONVENTIONS})
    stamps = _write_samples(out, a)
    tool = np.hstack([a.positions, a.orientations])
    transforms = tf_message([(WORLD_FRAME, TOOL_FRAME)]).messages(stamp_tool=stamps, tool=tool)
    out.write("/tf", "tf2_msgs/msg/TFMessage", stamps, transforms)
    return _finished(out)


def skill_mcap(a: DemonstrationArrays, skill: Skill, skill_id: str, start_unix_s: float) -> McapExport:
    """A skill along the demonstration it was learned from (``a``: its samples, stamped ``start + t``) as MCAP: the
    demonstration's ``/tool/pose`` and ``/wrench/world``, and its scene
    (``services.dashboard.ros_scene.skill_scene_messages``): ``/tf`` with the LEARNED compliant frame ``cf`` through
    every contact segment, ``/markers`` with the path and a triad at each learned CF; and the robot (``/joint_states``
    solved from the tool pose, ``/robot_description``, the URDF's joints in ``/tf``) when the demonstration was recorded
    in the robot's world (``skill.taught_world``: the simulator's). An imported recording is in a frame of its own,
    where no arm was modelled: its MCAP shows the tool frame, the path, the wrench and the learned frames."""
    from services.dashboard.ros_scene import SCENE_TOPICS, skill_scene_messages
    from services.dashboard.scene import JointSolver

    robot = skill.taught_world is not None
    metadata = {"skill_id": skill_id, "demonstration": skill.demonstration.name, "robot": str(robot).lower(),
                "conventions": CONVENTIONS}  # fmt: skip
    out = _McapOut(int(start_unix_s * 1e9), metadata)
    _write_samples(out, a)
    solver = JointSolver() if robot else None
    try:
        scene = skill_scene_messages(out.start_ns, a, skill, solver)
    finally:
        if solver is not None:
            solver.close()
    for topic, (stamps, payloads) in scene.items():
        out.write(topic, SCENE_TOPICS[topic], stamps, payloads)
    return _finished(out)


SELECTION_TYPE = "std_msgs/msg/Int32MultiArray"
PLAN_TOPICS: dict[str, str] = {
    "/reference/pose": POSE_TYPE,
    "/reference/twist": TWIST_TYPE,
    "/cf/pose": POSE_TYPE,
    "/force/desired": WRENCH_TYPE,
    "/phase": PHASE_TYPE,
    "/segment": SEGMENT_TYPE,
    "/selection": SELECTION_TYPE,
    "/tf": TF_TYPE,
}
"""Every topic of a plan's MCAP (:func:`plan_mcap`) and its ROS 2 message type."""
PLAN_CONVENTIONS = (
    "SI units; quaternions [x, y, z, w]; world frame; stamps = t from the plan's start (ns from 0); /cf/pose is world "
    "from CF (z into the surface); /force/desired the force the tool applies along CF z; /selection the diagonal of S "
    "in the CF (1 motion, 0 force), /phase, /segment and /selection sent at the start and at every change"
)
"""Stored in a plan MCAP's metadata record ``contact_skills``, beside the plan's other fields (``plan``)."""


def plan_mcap(plan: SkillPlan) -> McapExport:
    """A skill's plan as MCAP (the topics of :data:`PLAN_TOPICS`, the module docstring): what the JSON plan holds,
    the samples as ROS 2 messages, the rest as JSON in the metadata (``plan``: every field but ``samples``)."""
    from rosbags.typesys import Stores, get_typestore

    samples = plan.samples
    header = plan.model_dump_json(exclude={"samples"})
    out = _McapOut(0, {"plan": header, "conventions": PLAN_CONVENTIONS})
    stamps = out.stamps(np.asarray(samples.t, dtype=float))
    reference = np.hstack([np.asarray(samples.position_m, float), np.asarray(samples.orientation, float)])
    cf = np.hstack([np.asarray(samples.cf_origin_m, float), np.asarray(samples.cf_orientation, float)])
    force = np.zeros((len(stamps), 6))
    force[:, 2] = samples.force_n
    out.write("/reference/pose", POSE_TYPE, stamps, _POSE.messages(stamp=stamps, pose=reference))
    twist = twist_stamped(WORLD_FRAME).messages(stamp=stamps, twist=np.asarray(samples.twist, float))
    out.write("/reference/twist", TWIST_TYPE, stamps, twist)
    out.write("/cf/pose", POSE_TYPE, stamps, _POSE.messages(stamp=stamps, pose=cf))
    out.write("/force/desired", WRENCH_TYPE, stamps, _WRENCH_CF.messages(stamp=stamps, wrench=force))
    transforms = tf_message([(WORLD_FRAME, REFERENCE_FRAME), (WORLD_FRAME, CF_FRAME)])
    tf = transforms.messages(**{f"stamp_{REFERENCE_FRAME}": stamps, REFERENCE_FRAME: reference,
                                f"stamp_{CF_FRAME}": stamps, CF_FRAME: cf})  # fmt: skip
    out.write("/tf", TF_TYPE, stamps, tf)
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    types = typestore.types
    changes = {
        "/phase": ([p.value for p in samples.phase], lambda v: types[PHASE_TYPE](data=v)),
        "/segment": (samples.segment, lambda v: types[SEGMENT_TYPE](data=v)),
        "/selection": ([tuple(s) for s in samples.selection], lambda v: types[SELECTION_TYPE](
            layout=types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0), data=np.asarray(v, np.int32))),
    }  # fmt: skip
    for topic, (values, message) in changes.items():
        kept = [k for k, value in enumerate(values) if k == 0 or value != values[k - 1]]
        payloads = [bytes(typestore.serialize_cdr(message(values[k]), PLAN_TOPICS[topic])) for k in kept]
        out.write(topic, PLAN_TOPICS[topic], stamps[kept], payloads)
    return _finished(out)


def _finished(out: _McapOut) -> McapExport:
    data = out.finish()
    from mcap.reader import make_reader

    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None and summary.statistics is not None
    topics = sorted(channel.topic for channel in summary.channels.values())
    return McapExport(data, summary.statistics.message_count, topics)
