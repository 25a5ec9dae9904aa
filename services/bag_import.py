"""Importing ROS bags with ``rosbags``, no ROS needed: ROS 2 (MCAP or sqlite3 storage, a bag directory or its storage
file) and ROS 1 (a ``.bag`` file), told apart by their content.

A demonstration in a bag is a ``geometry_msgs/msg/WrenchStamped`` topic and the tool pose, either a
``geometry_msgs/msg/PoseStamped`` topic or a parent/child pair of ``/tf`` (with ``/tf_static``); a ROS 1 bag's types
(``geometry_msgs/WrenchStamped``, from the definitions the bag carries) read as the same ROS 2 names, and from there
on both are one import. Steps of :func:`demonstration_from_bag`, in order:

1. **Topics.** Chosen automatically when unambiguous (one WrenchStamped topic; one PoseStamped topic, else
   one moving ``/tf`` pair); otherwise the options name them (``wrench_topic``, ``pose_topic``,
   ``tf_frames``) and the error lists the candidates.
2. **Time.** Each message's ``header.stamp`` (the time of the measurement), not the bag's receive time
   (used only for a message whose stamp is zero, with a note); ``t`` counts from the first sample.
3. **Frames.** The world is the pose's reference frame (PoseStamped ``header.frame_id``, the ``/tf``
   parent); the tool is the pose's child frame (the ``/tf`` child, or ``tool_frame`` for a PoseStamped).
   A ``/tf`` pair may be a chain: transforms along the path are composed, moving ones interpolated onto
   the busiest one's stamps. The wrench's ``header.frame_id`` decides its frame: the world, the tool, or a
   sensor frame fixed to the tool by ``/tf_static``, whose wrench is moved to the tool point and tool axes
   (``F_tool = Adg(T_tool<-sensor) F_sensor``). ``wrench_frame`` overrides it.
4. **One time base.** The pose and wrench streams are asynchronous: each is sorted by stamp (equal stamps
   averaged) and both are interpolated onto one uniform grid over the span they share
   (`skills.preprocess.recording_from_groups`: positions C1 cubic, orientations slerp, wrenches linear;
   default rate: the faster stream's median rate).
5. The rest is every importer's (`services.import_steps.demonstration_from_samples`): offset given or
   windowed, tool frame -> world, measured-on-tool -> applied-by-tool, tare over the free-space stretches,
   validation.

Problems raise :class:`BagImportError`, each line starting with the option it is about (``wrench_topic:``,
``pose_topic:``, ``tf:``, ``wrench_frame:``) or ``file:``; a file that is no bag gets the message every importer
gives (`services.demonstration_files.unsupported_file`). The options are one
`schemas.import_options.BagImportOptions`.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np
from scipy.spatial.transform import Rotation

from schemas import Demonstration, DemonstrationMetadata, QuaternionOrder, WrenchFrame
from schemas.demonstration import MAX_DEMONSTRATION_SAMPLES
from schemas.import_options import BagImportOptions
from services.cdr import POSE_TYPE, TF_TYPE, WRENCH_TYPE, pose_stamped, wrench_stamped
from services.demonstration_files import (
    BAGS,
    HEAD_BYTES,
    DemonstrationFile,
    bag_storage_suffix,
    other_kind,
    path_kind,
    unsupported_file,
)
from services.import_steps import (
    DemonstrationImportError,
    RecordingSamples,
    demonstration_from_samples,
    sampling_rate_hz,
)
from skills import preprocess
from skills.frames import wrench_adjoint_from_transform

TF_TOPICS = ("/tf", "/tf_static")


class BagImportError(DemonstrationImportError):
    """A ROS bag could not be imported (unreadable, ambiguous or missing topics, frames that do not connect)."""


def _check_bag(path: Path, shown: str, told: DemonstrationFile | None) -> None:
    """Raise :class:`BagImportError` unless the file at ``path`` is a bag (``shown``: its name in the message): by
    ``told``, what the caller has told it holds, or else by its content."""
    try:
        kind = path_kind(path) if told is None else told
    except OSError as exc:
        raise BagImportError(f"file: cannot read {shown!r}: {exc.strerror or exc}") from None
    if kind is None:
        raise BagImportError(unsupported_file(shown))
    if kind not in BAGS:
        raise BagImportError(other_kind(shown, kind, "a ROS bag"))


@contextlib.contextmanager
def _readable_bag(path: Path) -> Iterator[Path]:
    """``path`` (a bag) as ``rosbags`` reads it: a rosbag2 directory as it is; a storage file under the suffix its
    content calls for (``rosbags`` tells MCAP, sqlite3 and ROS 1 apart by the suffix), linked under that name if it
    has another."""
    with contextlib.ExitStack() as stack:
        if path.is_file():
            with path.open("rb") as file:
                suffix = bag_storage_suffix(file.read(HEAD_BYTES))
            if path.suffix.lower() != suffix:
                link = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="cskills-bag-"))) / f"bag{suffix}"
                link.symlink_to(path.resolve())
                path = link
        yield path


# --------------------------------------------------------------------------- reading


@dataclass
class _Stream:
    """The messages of one topic: stamps (ns, header or log time), values, the frames named in the headers."""

    stamps_ns: list[int] = field(default_factory=list)
    values: list[list[float]] = field(default_factory=list)
    frames: set[str] = field(default_factory=set)
    log_time_used: int = 0


@dataclass
class _Transforms:
    """Every transform of ``/tf`` and ``/tf_static``: (parent, child) -> stamps (ns) and [x, y, z, qx, qy, qz, qw]."""

    edges: dict[tuple[str, str], _Stream] = field(default_factory=dict)
    static: set[tuple[str, str]] = field(default_factory=set)

    def add(self, parent: str, child: str, stamp_ns: int, value: list[float], static: bool) -> None:
        stream = self.edges.setdefault((parent.lstrip("/"), child.lstrip("/")), _Stream())
        stream.stamps_ns.append(stamp_ns)
        stream.values.append(value)
        if static:
            self.static.add((parent.lstrip("/"), child.lstrip("/")))

    def is_fixed(self, edge: tuple[str, str]) -> bool:
        """A static transform, or one that never changes."""
        values = np.asarray(self.edges[edge].values)
        return edge in self.static or bool(np.all(values == values[0]))

    def moving_pairs(self) -> list[tuple[str, str]]:
        return sorted(edge for edge in self.edges if not self.is_fixed(edge))

    def path(self, source: str, target: str, fixed_only: bool = False) -> list[tuple[str, str, bool]] | None:
        """The edges from frame ``source`` to ``target`` as (parent, child, forward), or None if not connected."""
        neighbours: dict[str, list[tuple[str, tuple[str, str, bool]]]] = {}
        for parent, child in self.edges:
            if fixed_only and not self.is_fixed((parent, child)):
                continue
            neighbours.setdefault(parent, []).append((child, (parent, child, True)))
            neighbours.setdefault(child, []).append((parent, (parent, child, False)))
        previous: dict[str, tuple[str, tuple[str, str, bool]] | None] = {source: None}
        queue = deque([source])
        while queue:
            frame = queue.popleft()
            if frame == target:
                steps = []
                while previous[frame] is not None:
                    frame, step = previous[frame]  # type: ignore[misc]
                    steps.append(step)
                return steps[::-1]
            for other, step in neighbours.get(frame, []):
                if other not in previous:
                    previous[other] = (frame, step)
                    queue.append(other)
        return None


def _vector(v) -> list[float]:
    return [float(v.x), float(v.y), float(v.z)]


def _quaternion(q) -> list[float]:
    return [float(q.x), float(q.y), float(q.z), float(q.w)]


@dataclass(frozen=True)
class _BagContents:
    ros: int
    """1 or 2."""
    topics: dict[str, str]
    """Topic -> message type."""
    counts: dict[str, int]
    wrench_topic: str
    wrench: _Stream
    pose_topic: str | None
    pose: _Stream | None
    """None: the pose comes from /tf."""
    transforms: _Transforms


def _topic_choice(
    topics: dict[str, str], given: str | None, msgtype: str, option: str, allow_none: bool = False
) -> str | None:
    """The topic ``given`` (checked) or the only topic of ``msgtype``; None when there is none and ``allow_none``."""
    if given is not None:
        if given not in topics:
            raise BagImportError(f"{option}: no topic {given!r} in the bag (topics: {_listed(topics)})")
        if topics[given] != msgtype:
            raise BagImportError(f"{option}: topic {given!r} holds {topics[given]}, not {msgtype}")
        return given
    candidates = sorted(name for name, kind in topics.items() if kind == msgtype)
    if len(candidates) == 1:
        return candidates[0]
    flag = "--" + option.replace("_", "-")
    if len(candidates) > 1:
        raise BagImportError(
            f"{option}: {len(candidates)} {msgtype} topics ({', '.join(candidates)}): choose one with {flag} "
            f"(API form field {option})"
        )
    if allow_none:
        return None
    raise BagImportError(f"{option}: no {msgtype} topic in the bag (topics: {_listed(topics)})")


def _listed(topics: dict[str, str]) -> str:
    return ", ".join(f"{name} [{kind}]" for name, kind in sorted(topics.items())) or "none"


def _read_bag(path: Path, shown: str, wrench_topic: str | None, pose_topic: str | None, use_tf: bool) -> _BagContents:
    """Read the chosen topics (and ``/tf``, ``/tf_static``) of the bag at ``path`` in one pass (``shown``: the bag's
    name in the messages)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:  # rosbags is in the service extra
        raise BagImportError(
            f"file: reading ROS bags needs the service extra (pip install -e '.[service]'): {exc}"
        ) from None

    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own error types for every unreadable bag
        raise BagImportError(f"file: cannot read the bag {shown!r}: {exc}") from None
    try:
        topics = {name: info.msgtype or "?" for name, info in reader.topics.items()}
        counts = {name: int(info.msgcount) for name, info in reader.topics.items()}
        wrench_name = _topic_choice(topics, wrench_topic, WRENCH_TYPE, "wrench_topic")
        assert wrench_name is not None
        pose_name = None if use_tf else _topic_choice(topics, pose_topic, POSE_TYPE, "pose_topic", allow_none=True)
        wanted = {wrench_name, pose_name} | {t for t in TF_TOPICS if topics.get(t) == TF_TYPE}
        raw_messages: dict[str, tuple[list[int], list[bytes]]] = {wrench_name: ([], []), pose_name or "": ([], [])}
        transforms = _Transforms()
        connections = [c for c in reader.connections if c.topic in wanted]
        for connection, log_time_ns, raw in reader.messages(connections=connections):
            if connection.topic in raw_messages:  # decoded below, all at once
                raw_messages[connection.topic][0].append(log_time_ns)
                raw_messages[connection.topic][1].append(raw)
            else:
                message = reader.deserialize(raw, connection.msgtype)
                for tf in message.transforms:
                    stamp = int(tf.header.stamp.sec) * 1_000_000_000 + int(tf.header.stamp.nanosec) or log_time_ns
                    value = _vector(tf.transform.translation) + _quaternion(tf.transform.rotation)
                    transforms.add(
                        tf.header.frame_id, tf.child_frame_id, stamp, value, connection.topic == "/tf_static"
                    )
        wrench = _stream(reader, WRENCH_TYPE, *raw_messages[wrench_name])
        pose = None if pose_name is None else _stream(reader, POSE_TYPE, *raw_messages[pose_name])
    except BagImportError:
        raise
    except Exception as exc:
        raise BagImportError(f"file: cannot read the messages of {shown!r}: {exc}") from None
    finally:
        reader.close()
    return _BagContents(2 if reader.is2 else 1, topics, counts, wrench_name, wrench, pose_name, pose, transforms)


def _stream(reader, msgtype: str, log_times_ns: list[int], raws: list[bytes]) -> _Stream:
    """A WrenchStamped or PoseStamped topic: stamps (the bag's log time where a header stamp is zero), values
    ([f, m] or [p, q]) and frames; a ROS 2 bag's CDR decoded all at once when every message has the first one's
    layout (`services.cdr`), else (and a ROS 1 bag's) one by one."""
    if not raws:
        return _Stream()
    first = reader.deserialize(raws[0], msgtype)
    layout, field = (wrench_stamped, "wrench") if msgtype == WRENCH_TYPE else (pose_stamped, "pose")
    decoded = layout(first.header.frame_id).decoded(raws) if reader.is2 else None
    if decoded is not None:
        stamps, values, frames = decoded["stamp"], decoded[field], {first.header.frame_id.lstrip("/")}
    else:
        messages = [reader.deserialize(raw, msgtype) for raw in raws]
        stamps = np.array([int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec) for m in messages])
        values = np.array([_message_values(m) for m in messages])
        frames = {m.header.frame_id.lstrip("/") for m in messages}
    unset = stamps == 0
    return _Stream(
        stamps_ns=np.where(unset, np.asarray(log_times_ns, dtype=np.int64), stamps).tolist(),
        values=values.tolist(),
        frames=frames,
        log_time_used=int(unset.sum()),
    )


def _message_values(message) -> list[float]:
    """[f, m] of a WrenchStamped, [p, q] of a PoseStamped."""
    if hasattr(message, "wrench"):
        return _vector(message.wrench.force) + _vector(message.wrench.torque)
    return _vector(message.pose.position) + _quaternion(message.pose.orientation)


# --------------------------------------------------------------------------- poses and frames


@dataclass(frozen=True)
class _Poses:
    stamps_ns: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    world: str
    tool: str | None
    source: str


def _checked(values: np.ndarray, what: str) -> np.ndarray:
    """``values`` (N, 7 or 6) with every row finite and quaternion columns near unit norm, else a problem."""
    bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1))
    if bad.size:
        raise BagImportError(f"file: {what}, message {bad[0]}: not finite (NaN or inf); {bad.size} such messages")
    if values.shape[1] == 7:
        deviation = preprocess.quaternion_norm_deviations(values[:, 3:])
        wrong = np.flatnonzero(deviation > preprocess.MAX_QUATERNION_NORM_DEVIATION)
        if wrong.size:
            k = int(wrong[0])
            raise BagImportError(
                f"file: {what}, message {k}: orientation norm {np.linalg.norm(values[k, 3:]):.4g} is not 1; "
                f"{wrong.size} such messages"
            )
        values = values.copy()
        values[:, 3:] = preprocess.quaternions_unit_continuous(values[:, 3:])
    return values


def _edge_values(transforms: _Transforms, edge: tuple[str, str], stamps_ns: np.ndarray) -> np.ndarray:
    """The transform ``edge`` at ``stamps_ns`` (N, 7): a fixed one repeated, a moving one interpolated (held
    at its ends)."""
    stream = transforms.edges[edge]
    values = _checked(np.asarray(stream.values, dtype=float), f"/tf {edge[0]} -> {edge[1]}")
    if transforms.is_fixed(edge):
        return np.repeat(values[-1:], stamps_ns.size, axis=0)
    group = preprocess.stream_samples(np.asarray(stream.stamps_ns, dtype=float), values, slice(3, 7))
    t = np.clip(stamps_ns.astype(float), group.t[0], group.t[-1])
    return np.hstack([
        preprocess.values_linearly_resampled(t, group.t, group.values[:, :3]),
        preprocess.quaternions_slerp(t, group.t, preprocess.quaternions_unit_continuous(group.values[:, 3:])),
    ])  # fmt: skip


def _composed(transforms: _Transforms, path: list[tuple[str, str, bool]], stamps_ns: np.ndarray):
    """Rotation and translation of the chain ``path`` (parent-most first) at ``stamps_ns``."""
    rotation = Rotation.identity(stamps_ns.size)
    translation = np.zeros((stamps_ns.size, 3))
    for parent, child, forward in path:
        values = _edge_values(transforms, (parent, child), stamps_ns)
        step_r, step_p = Rotation.from_quat(values[:, 3:]), values[:, :3]
        if not forward:
            step_r = step_r.inv()
            step_p = -step_r.apply(step_p)
        translation = translation + rotation.apply(step_p)
        rotation = rotation * step_r
    return rotation, translation


def _tf_poses(transforms: _Transforms, tf_frames: tuple[str, str] | None) -> _Poses:
    """The pose of the tool (child) in the world (parent) from ``/tf``, on the stamps of the busiest moving link."""
    moving = transforms.moving_pairs()
    if tf_frames is None:
        if len(moving) != 1:
            shown = ", ".join(f"{p} -> {c}" for p, c in moving) or "none"
            raise BagImportError(
                f"pose_topic: no {POSE_TYPE} topic, and /tf has {len(moving)} moving transforms ({shown}): name the "
                "tool pose with --pose-topic or --tf PARENT CHILD (API form fields pose_topic or tf_parent, tf_child)"
            )
        tf_frames = moving[0]
    parent, child = (frame.lstrip("/") for frame in tf_frames)
    path = transforms.path(parent, child)
    if path is None:
        frames = sorted({f for edge in transforms.edges for f in edge})
        raise BagImportError(
            f"tf: /tf does not connect {parent!r} to {child!r} (frames: {', '.join(frames) or 'none'})"
        )
    links = [(p, c) for p, c, _ in path if (p, c) in moving]
    if not links:
        raise BagImportError(f"tf: the transform {parent} -> {child} never moves: it is not a demonstration")
    busiest = max(links, key=lambda edge: len(transforms.edges[edge].stamps_ns))
    stamps = np.unique(np.asarray(transforms.edges[busiest].stamps_ns, dtype=np.int64))
    rotation, translation = _composed(transforms, path, stamps)
    return _Poses(stamps, translation, rotation.as_quat(), parent, child, f"/tf {parent} -> {child}")


@dataclass(frozen=True)
class _WrenchFrameChoice:
    frame: WrenchFrame
    adjoint: np.ndarray | None
    """Maps a wrench in the sensor frame (at its origin) to the tool frame at the tool point (6, 6), if needed."""
    note: str


def _wrench_frame_choice(
    header_frame: str, poses: _Poses, transforms: _Transforms, given: WrenchFrame | None
) -> _WrenchFrameChoice:
    """Decide the wrench's frame from its header (see the module docstring), unless ``given``."""
    if given is not None:
        shown = f"'{header_frame}'" if header_frame else "(empty)"
        return _WrenchFrameChoice(
            given, None, f"wrench frame {given.value} as given (header frame_id {shown} not used)"
        )
    if header_frame and header_frame == poses.world:
        return _WrenchFrameChoice(WrenchFrame.world, None, f"wrench in '{header_frame}', the world (pose) frame")
    if header_frame and header_frame == poses.tool:
        return _WrenchFrameChoice(WrenchFrame.tool, None, f"wrench in '{header_frame}', the tool frame")
    if header_frame and poses.tool is not None:
        path = transforms.path(poses.tool, header_frame, fixed_only=True)
        if path is not None:
            rotation, translation = _composed(transforms, path, np.zeros(1, dtype=np.int64))
            adjoint = wrench_adjoint_from_transform(rotation.as_matrix().reshape(3, 3), translation[0])
            offset = ", ".join(f"{v * 1e3:+.1f}" for v in translation[0])
            return _WrenchFrameChoice(
                WrenchFrame.tool,
                adjoint,
                f"wrench in '{header_frame}', fixed on the tool '{poses.tool}' by /tf_static (origin at [{offset}] mm "
                "in the tool frame): moved to the tool point and tool axes",
            )
    tool = f"'{poses.tool}'" if poses.tool else "unknown (give --tool-frame for a PoseStamped)"
    shown = f"'{header_frame}'" if header_frame else "empty"
    raise BagImportError(
        f"wrench_frame: the wrench's frame_id is {shown}: neither the world frame '{poses.world}' nor the tool "
        f"frame {tool}, and /tf_static does not fix it to the tool; pass --wrench-frame world|tool "
        "(API form field wrench_frame)"
    )


# --------------------------------------------------------------------------- import


def demonstration_from_bag(
    path: str | os.PathLike[str], options: BagImportOptions | None = None, kind: DemonstrationFile | None = None
) -> Demonstration:
    """Import a ROS bag as a `schemas.Demonstration`: ROS 2 (a rosbag2 directory, or its MCAP or sqlite3 storage
    file) or ROS 1 (a ``.bag`` file), told apart by the content.

    ``options`` (`schemas.import_options.BagImportOptions`, default all defaults): ``wrench_topic`` (a
    WrenchStamped topic), ``pose_topic`` (a PoseStamped topic) or ``tf_parent``/``tf_child`` (a pair in
    ``/tf``): default, the only candidate. ``tool_frame``: the frame a PoseStamped is the pose of (lets a wrench
    in that frame be recognised as the tool's). ``wrench_frame``: 'world' or 'tool' overrides what the wrench's
    header says. ``wrench_convention``, ``rate_hz`` (Hz, the uniform rate of the result; default the faster
    stream's median rate), ``tare``, ``tare_window_s`` (s from the first sample), ``force_offset`` (N, N·m, as
    the messages read it) and ``name`` as for `services.csv_import.demonstration_from_csv`. See the module
    docstring for the steps. ``kind``: what the file holds when the caller has told it already
    (`services.importing.demonstration_file`), so that it is not read again to tell it. Raises
    :class:`BagImportError` naming the option and the reason.
    """
    path = Path(path)
    if not path.exists():
        raise BagImportError(f"file: {str(path)!r} does not exist")
    return _imported(path, path.name, options or BagImportOptions(), kind)


def _imported(path: Path, shown: str, options: BagImportOptions, kind: DemonstrationFile | None) -> Demonstration:
    """:func:`demonstration_from_bag` of the bag at ``path``, named ``shown`` in the messages and the metadata
    (``kind``: what it holds, if told)."""
    if options.pose_topic is not None and options.tf_frames is not None:
        raise BagImportError("pose_topic: give either a pose topic or a /tf pair (--tf), not both")
    rate = sampling_rate_hz(options.rate_hz, None, BagImportError)
    _check_bag(path, shown, kind)
    with _readable_bag(path) as readable:
        bag = _read_bag(readable, shown, options.wrench_topic, options.pose_topic, use_tf=options.tf_frames is not None)
    wrench_name = bag.wrench_topic
    notes = []
    if bag.pose is not None and bag.pose_topic is not None:
        pose_name = bag.pose_topic
        if len(bag.pose.frames) != 1:
            raise BagImportError(f"pose_topic: {pose_name} changes its frame_id ({', '.join(sorted(bag.pose.frames))})")
        values = _checked(np.asarray(bag.pose.values, dtype=float).reshape(-1, 7), pose_name)
        poses = _Poses(
            np.asarray(bag.pose.stamps_ns, dtype=np.int64), values[:, :3], values[:, 3:],
            next(iter(bag.pose.frames)), options.tool_frame.lstrip("/") if options.tool_frame else None, pose_name,
        )  # fmt: skip
        if bag.pose.log_time_used:
            notes.append(f"{pose_name}: {bag.pose.log_time_used} messages without a header stamp: bag time used")
    else:
        poses = _tf_poses(bag.transforms, options.tf_frames)
    if len(bag.wrench.frames) != 1:
        raise BagImportError(
            f"wrench_topic: {wrench_name} changes its frame_id ({', '.join(sorted(bag.wrench.frames))})"
        )
    if bag.wrench.log_time_used:
        notes.append(f"{wrench_name}: {bag.wrench.log_time_used} messages without a header stamp: bag time used")
    choice = _wrench_frame_choice(next(iter(bag.wrench.frames)), poses, bag.transforms, options.wrench_frame)
    wrenches = _checked(np.asarray(bag.wrench.values, dtype=float).reshape(-1, 6), wrench_name)
    if choice.adjoint is not None:
        wrenches = wrenches @ choice.adjoint.T
    notes.append(choice.note)

    t0 = int(min(poses.stamps_ns.min(initial=2**62), min(bag.wrench.stamps_ns, default=2**62)))
    pose_group = preprocess.stream_samples(
        (poses.stamps_ns - t0) * 1e-9, np.hstack([poses.positions, poses.orientations]), slice(3, 7)
    )
    wrench_group = preprocess.stream_samples((np.asarray(bag.wrench.stamps_ns, dtype=np.int64) - t0) * 1e-9, wrenches)
    try:
        resampled = preprocess.recording_from_groups(
            pose_group, wrench_group, rate, max_samples=MAX_DEMONSTRATION_SAMPLES
        )
    except preprocess.TooManySamples as exc:  # bounded like the CSV import: the grid is never built
        raise BagImportError(f"{'rate' if rate is not None else 'file'}: {exc}") from None
    except ValueError as exc:
        raise BagImportError(f"file: cannot align the pose and the wrench on one time base: {exc}") from None
    recording = RecordingSamples(
        t=resampled.t - resampled.t[0],
        positions=resampled.positions,
        orientations=resampled.orientations,
        wrenches=resampled.wrenches,
        rate_hz=resampled.rate_hz,
        notes=[
            f"ROS {bag.ros} bag: wrench {wrench_name} ({len(bag.wrench.stamps_ns)} messages), pose {poses.source} "
            f"({poses.stamps_ns.size} samples), header stamps, world frame '{poses.world}'",
            *resampled.notes,
        ],
        unmeasured_s=resampled.unmeasured - resampled.t[0],
    )
    return demonstration_from_samples(
        recording,
        options,
        wrench_frame=choice.frame,
        metadata=DemonstrationMetadata(
            name=options.name or Path(shown).stem,
            source=f"bag:{shown}",
            quaternion_order_on_import=QuaternionOrder.xyzw,
        ),
        extra={
            "bag": {
                "ros": bag.ros,
                "wrench_topic": wrench_name,
                "pose": poses.source,
                "frames": {"world": poses.world, "tool": poses.tool, "wrench": next(iter(bag.wrench.frames))},
                "messages": bag.counts,
                "start_stamp_ns": t0 + round(resampled.t[0] * 1e9),
            }
        },
        notes=notes,
        error=BagImportError,
    )


def demonstration_from_bag_upload(
    data: bytes, filename: str, options: BagImportOptions | None = None, kind: DemonstrationFile | None = None
) -> Demonstration:
    """Import an uploaded bag given as bytes: a ROS 2 bag's storage file (the ``.mcap`` or ``.db3`` inside a rosbag2
    directory) or a ROS 1 ``.bag``, told apart by the content; ``filename`` names it in the metadata and the
    messages (never on disk). ``options`` and ``kind`` as for :func:`demonstration_from_bag`."""
    with tempfile.TemporaryDirectory(prefix="cskills-bag-") as folder:
        path = Path(folder) / f"upload{bag_storage_suffix(data[:HEAD_BYTES]) or ''}"
        path.write_bytes(data)
        return _imported(path, PurePosixPath(filename).name or "upload", options or BagImportOptions(), kind)
