"""Real ROS 2 and ROS 1 bags written with ``rosbags`` (no ROS) from a demonstration with known truth, as robots record
them.

The truth is a demonstration in the project's conventions (t, tool point position and orientation in the world,
wrench applied by the tool at the tool point in the world). The bag holds what a robot would log instead, the same
in a ROS 2 bag (MCAP or sqlite3 storage, CDR) and a ROS 1 bag (its own serialization, headers with a ``seq``):

- ``/ft_sensor/wrench`` (WrenchStamped) at the truth's rate, the sensor's REACTION (``measured-on-tool``) in the
  frame asked for: ``world``, the ``tool`` frame, or ``ft_sensor``, a sensor fixed on the flange by ``/tf_static``
  away from the tool point (so its moment differs by ``p x f``);
- the tool pose at a quarter of the rate, stamped one sample LATER than the wrench's quarter grid (asynchronous
  topics): a PoseStamped ``/tool_pose`` in ``world``, or ``/tf`` where only ``base -> flange`` moves, with
  ``world -> base`` and ``flange -> tool`` in ``/tf_static``;
- every message logged 0-30 ms after its header stamp, in log-time order: importing by bag time would be wrong;
- optionally a second WrenchStamped topic (an ambiguity the importer must refuse to guess).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from skills.frames import transform_inverse, wrench_adjoint_from_transform

STAMP_BASE_NS = 1_700_000_000_000_000_000
"""Header stamp of the first truth sample (ns since the epoch)."""
WORLD_FROM_BASE = (Rotation.from_euler("z", 90, degrees=True), np.array([0.1, 0.2, 0.0]))
FLANGE_FROM_TOOL = (Rotation.from_euler("x", 180, degrees=True), np.array([0.0, 0.0, 0.12]))
FLANGE_FROM_SENSOR = (Rotation.from_euler("zx", [30, 10], degrees=True), np.array([0.01, -0.02, 0.04]))
POSE_EVERY = 4
"""The pose is logged at 1/POSE_EVERY of the wrench rate."""


def tool_from_sensor() -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of the sensor frame in the tool frame (maps sensor coordinates into tool coordinates)."""
    r_ft, p_ft = FLANGE_FROM_TOOL
    r_fs, p_fs = FLANGE_FROM_SENSOR
    r_tf, p_tf = r_ft.inv(), -r_ft.inv().apply(p_ft)
    return (r_tf * r_fs).as_matrix(), r_tf.apply(p_fs) + p_tf


TF_MESSAGE = "tf2_msgs/msg/TFMessage"
STORAGES = ("mcap", "sqlite3", "ros1")
"""What :func:`write_bag` writes: a ROS 2 bag directory (MCAP or sqlite3 storage) or a ROS 1 ``.bag``."""


def _header(types, stamp_ns: int, frame: str):
    time = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    header = types["std_msgs/msg/Header"]
    seq = {"seq": 0} if "seq" in header.__dataclass_fields__ else {}  # ROS 1 headers count their messages
    return header(stamp=time, frame_id=frame, **seq)


def _vector3(types, v):
    return types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _transform(types, stamp_ns: int, parent: str, child: str, rotation: Rotation, translation):
    q = rotation.as_quat()
    transform = types["geometry_msgs/msg/Transform"](
        translation=_vector3(types, translation),
        rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
    )
    return types["geometry_msgs/msg/TransformStamped"](
        header=_header(types, stamp_ns, parent), child_frame_id=child, transform=transform
    )


def write_bag(
    path: Path,
    t: np.ndarray,
    positions: np.ndarray,
    orientations: np.ndarray,
    wrenches: np.ndarray,
    *,
    storage: str = "mcap",
    wrench_frame: str = "tool",
    pose: str = "pose_stamped",
    second_wrench_topic: bool = False,
    pose_every: int = POSE_EVERY,
    seed: int = 0,
    stamp_base_ns: int = STAMP_BASE_NS,
) -> Path:
    """Write the truth (``t`` s, ``positions`` m, ``orientations`` [x, y, z, w], ``wrenches`` applied by the tool at
    the tool point in the world) as a bag at ``path``: a rosbag2 directory (``storage`` 'mcap' or 'sqlite3') or a
    ROS 1 bag file (``storage`` 'ros1', ``path`` with the suffix ``.bag`` added if it has none); see the module
    docstring for what it holds (``pose_every``: the pose at 1/pose_every of the wrench rate; ``t`` = 0 is stamped
    ``stamp_base_ns`` ns since the epoch); returns the bag."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    typestore = get_typestore(Stores.ROS1_NOETIC if storage == "ros1" else Stores.ROS2_HUMBLE)
    if storage == "ros1":  # the noetic store has no tf2_msgs: its definition, as a ROS 1 bag carries it
        typestore.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))
    types = typestore.types
    rng = np.random.default_rng(seed)
    stamps = stamp_base_ns + np.round(np.asarray(t) * 1e9).astype(np.int64)
    tool = Rotation.from_quat(orientations)
    measured = -np.asarray(wrenches, dtype=float)  # the sensor's reaction
    if wrench_frame in ("tool", "ft_sensor"):
        inverse = tool.inv()
        measured = np.hstack([inverse.apply(measured[:, :3]), inverse.apply(measured[:, 3:])])
    if wrench_frame == "ft_sensor":
        measured = measured @ wrench_adjoint_from_transform(*transform_inverse(*tool_from_sensor())).T
    messages: list[tuple[int, str, object]] = []  # (log time, topic, message)
    kind = {"wrench": "geometry_msgs/msg/WrenchStamped", "pose": "geometry_msgs/msg/PoseStamped"}
    for k, stamp in enumerate(stamps):
        wrench = types["geometry_msgs/msg/Wrench"](
            force=_vector3(types, measured[k, :3]), torque=_vector3(types, measured[k, 3:])
        )
        message = types[kind["wrench"]](header=_header(types, int(stamp), wrench_frame), wrench=wrench)
        messages.append((int(stamp + rng.integers(0, 30_000_000)), "/ft_sensor/wrench", message))
        if second_wrench_topic:
            messages.append((int(stamp), "/ft_sensor/wrench_filtered", message))
    pose_rows = np.arange(1, len(t), pose_every)
    if pose == "pose_stamped":
        for k in pose_rows:
            q = orientations[k]
            body = types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=positions[k, 0], y=positions[k, 1], z=positions[k, 2]),
                orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            message = types[kind["pose"]](header=_header(types, int(stamps[k]), "world"), pose=body)
            messages.append((int(stamps[k] + rng.integers(0, 30_000_000)), "/tool_pose", message))
    else:  # /tf: world -> base (static), base -> flange (moving), flange -> tool (static), flange -> ft_sensor
        r_wb, p_wb = WORLD_FROM_BASE
        r_ft, p_ft = FLANGE_FROM_TOOL
        r_wt, p_wt = tool[pose_rows], positions[pose_rows]
        r_wf = r_wt * r_ft.inv()
        p_wf = p_wt - r_wf.apply(p_ft)
        r_bf, p_bf = r_wb.inv() * r_wf, r_wb.inv().apply(p_wf - p_wb)
        for j, k in enumerate(pose_rows):
            tf = _transform(types, int(stamps[k]), "base", "flange", r_bf[j], p_bf[j])
            messages.append((int(stamps[k] + rng.integers(0, 30_000_000)), "/tf", types[TF_MESSAGE]([tf])))
        static = [
            _transform(types, int(stamps[0]), "world", "base", r_wb, p_wb),
            _transform(types, int(stamps[0]), "flange", "tool", r_ft, p_ft),
            _transform(types, int(stamps[0]), "flange", "ft_sensor", *FLANGE_FROM_SENSOR),
        ]
        messages.append((int(stamps[0]), "/tf_static", types[TF_MESSAGE](static)))
    messages.sort(key=lambda item: item[0])
    if storage == "ros1":
        from rosbags.rosbag1 import Writer as Ros1Writer

        path = path if path.suffix == ".bag" else path.with_name(path.name + ".bag")
        writer, serialize = Ros1Writer(path), typestore.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), typestore.serialize_cdr
    with writer:
        connections = {}
        for topic in sorted({topic for _, topic, _ in messages}):
            msgtype = next(m for _, name, m in messages if name == topic).__msgtype__
            connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
        for log_time, topic, message in messages:
            writer.write(connections[topic], log_time, serialize(message, message.__msgtype__))
    return path


def storage_file(bag: Path) -> Path:
    """The storage file inside a rosbag2 directory (what an upload sends); a ROS 1 bag is its own."""
    if bag.is_file():
        return bag
    [found] = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    return found
