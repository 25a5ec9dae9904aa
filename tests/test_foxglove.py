"""The live execution in Foxglove and the exported MCAP, against the REAL stack (`contact-skills up`: embedded Zenoh
router, the API, a PyBullet sim worker on 127.0.0.1).

A WebSocket client speaking Foxglove's protocol and offering only its original name, ``foxglove.websocket.v1`` (the
SDK's server knows it as ``foxglove.sdk.v1``; serverInfo, advertise, subscribe, binary message data, fetchAsset)
connects to the URL
``/health`` gives, subscribes to every channel and records an execution. The messages must decode as their
advertised ROS 2 types and agree with physics and with each other: the ``cf`` frame of ``/tf`` turns the CF wrench
into the world wrench of the same step, the joint states put the arm's tool point where ``/tf`` says the tool is
(forward kinematics), the URDF's meshes are served, ``/force/true`` and ``/contact`` are the stored telemetry's true
normal force and contact of the same step. The exported MCAP of the same run (read with the ``mcap``
reader) holds ``/joint_states``, the URDF and the ``cf`` frame, with the same agreement. ``/tf`` is one tree that
agrees with the URDF, live and exported. A skill's MCAP shows the robot (for a demonstration the simulator recorded)
and the LEARNED compliant frames along the demonstrated path, read back against the skill."""

from __future__ import annotations

import asyncio
import io
import json
import re
import struct
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zenoh")
websockets = pytest.importorskip("websockets")

from test_service import RECORD, running_stack  # noqa: E402

from services.dashboard.ros_scene import TRUTH_TOPICS, truth_messages  # noqa: E402
from services.dashboard.scene import LINK7_TO_FLANGE_M, LINK7_TO_TOOL_POINT_M, robot_description  # noqa: E402
from services.local_processes import free_port  # noqa: E402
from services.telemetry_export import execution_topics  # noqa: E402
from skills.quaternions import matrix_from_quaternion  # noqa: E402

PROTOCOLS = ["foxglove.websocket.v1"]
"""The WebSocket subprotocols the client offers: only the protocol's original name, as older Foxglove Studio releases
do (the SDK's server accepts only ``foxglove.sdk.v1``, the same messages under a new name: the product's origin gate
answers this one; tests/test_floods.py checks both names against the origin rule)."""
MESSAGE_DATA, FETCH_ASSET_RESPONSE = 0x01, 0x04
PORT = free_port()


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("foxglove"), workers=1,
                             env={"CONTACT_SKILLS_FOXGLOVE_PORT": str(PORT)})  # fmt: skip


@pytest.fixture(scope="module")
def skill_id(stack) -> str:
    demo = stack.post("/demonstrations/record", RECORD, 201)
    return stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "auto"}, 201)["id"]


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


async def _record_live(url: str, start, finished) -> tuple[list[dict], dict[str, list], bytes | None, str]:
    """Connect to the Foxglove server at ``url``, subscribe to every channel, call ``start()`` (-> execution id), and
    collect the messages until ``finished(id)`` and a second more; fetch the first mesh of the URDF (waited for).
    Returns the advertised channels, the decoded messages per topic (and their log times, ns, under
    ``"log_time:" + topic``), the mesh and its URI."""
    store = _typestore()
    channels: dict[int, dict] = {}
    frames: list[bytes] = []
    mesh, mesh_uri = None, ""
    async with websockets.connect(url, subprotocols=PROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol == PROTOCOLS[0]
        info = json.loads(await ws.recv())
        assert info["op"] == "serverInfo" and "assets" in info.get("capabilities", []), info
        while not channels:
            message = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if message["op"] == "advertise":
                channels.update({c["id"]: c for c in message["channels"]})
        by_subscription = dict(enumerate(channels.values()))
        subscriptions = [{"id": k, "channelId": c["id"]} for k, c in by_subscription.items()]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        execution_id = await asyncio.to_thread(start)
        # The receive loop only keeps frames (decoded after): a client slower than the stream loses messages (the
        # server drops the oldest of a full backlog); the status is polled beside it, not once per frame.
        done = asyncio.Event()

        async def poll_finished() -> None:
            while not await asyncio.to_thread(finished, execution_id):
                await asyncio.sleep(0.25)
            done.set()

        poller = asyncio.create_task(poll_finished())
        loop = asyncio.get_running_loop()
        deadline, done_at = loop.time() + 120, None
        while done_at is None or loop.time() - done_at < 1.0 or mesh is None:  # the mesh may come after the data
            assert loop.time() < deadline, f"execution {execution_id} or its mesh did not come within 120 s"
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                frame = None
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                frames.append(frame)
                channel = by_subscription[struct.unpack_from("<I", frame, 1)[0]]
                if not mesh_uri and channel["topic"] == "/robot_description":
                    description = store.deserialize_cdr(frame[13:], channel["schemaName"]).data
                    mesh_uri = ET.fromstring(description).find(".//mesh").get("filename")
                    await ws.send(json.dumps({"op": "fetchAsset", "uri": mesh_uri, "requestId": 7}))
            elif isinstance(frame, bytes) and frame[0] == FETCH_ASSET_RESPONSE:
                _, status, error_length = struct.unpack_from("<IBI", frame, 1)
                assert status == 0, frame[10 : 10 + error_length]
                mesh = frame[10 + error_length :]
            if done_at is None and done.is_set():
                done_at = loop.time()
        await poller
    received: dict[str, list] = defaultdict(list)
    for frame in frames:
        subscription, log_time = struct.unpack_from("<IQ", frame, 1)
        channel = by_subscription[subscription]
        received[channel["topic"]].append(store.deserialize_cdr(frame[13:], channel["schemaName"]))
        received["log_time:" + channel["topic"]].append(log_time)
    return list(channels.values()), {"execution": execution_id, **received}, mesh, mesh_uri


def _stamp(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def _check_cf_turns_the_cf_wrench_into_the_world_wrench(tf: list, world: list, cf: list) -> int:
    """Every step with a force (> 1 N): R_cf (from /tf ``cf``) times the CF force is the world force of the same
    stamp, to 1e-6 N. Returns how many steps were checked."""
    rotation = {}
    for message in tf:
        for transform in message.transforms:
            if transform.child_frame_id == "cf":
                q = transform.transform.rotation
                rotation[_stamp(transform.header)] = matrix_from_quaternion([q.x, q.y, q.z, q.w])
    world_force = {_stamp(m.header): [m.wrench.force.x, m.wrench.force.y, m.wrench.force.z] for m in world}
    checked = 0
    for message in cf:
        stamp = _stamp(message.header)
        f_cf = np.array([message.wrench.force.x, message.wrench.force.y, message.wrench.force.z])
        if stamp in rotation and stamp in world_force and np.linalg.norm(f_cf) > 1.0:
            np.testing.assert_allclose(rotation[stamp] @ f_cf, world_force[stamp], atol=1e-6)
            checked += 1
    return checked


def _pose(transform) -> np.ndarray:
    """The 4x4 homogeneous matrix of a ``geometry_msgs/msg/Transform``."""
    p, q = transform.translation, transform.rotation
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = matrix_from_quaternion([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z]
    return out


def _check_tf_is_the_urdfs_tree(tf: list, description: str) -> int:
    """``/tf`` is one tree that agrees with the URDF ``description``: every transform's parent is its child's parent in
    the URDF (a frame the URDF does not have, and the URDF's root link, hang off ``world``), no frame ever has two
    parents, every joint of the URDF is published; and where a message carries the whole arm, composing its
    transforms from ``world`` down the URDF's joints puts the URDF's tool link within 2 mm (the IK's residual) of
    the measured ``tool`` of the same message, with the same axes. Returns how many such messages were checked."""
    robot = ET.fromstring(description)
    urdf_parent = {j.find("child").get("link"): j.find("parent").get("link") for j in robot.findall("joint")}
    (root,) = {link.get("name") for link in robot.findall("link")} - set(urdf_parent)
    tool_link = next(child for child, parent in urdf_parent.items() if parent == "flange")
    parents: dict[str, set[str]] = defaultdict(set)
    checked = 0
    for message in tf:
        poses = {}
        for transform in message.transforms:
            parents[transform.child_frame_id].add(transform.header.frame_id)
            poses[transform.child_frame_id] = (transform.header.frame_id, _pose(transform.transform))
        if tool_link not in poses:
            continue
        chain, frame = np.eye(4), tool_link
        while frame != "world":  # up the tree the message carries, from the tool link to the world
            parent, pose = poses[frame]
            chain, frame = pose @ chain, parent
        measured = poses["tool"][1]
        assert np.linalg.norm(chain[:3, 3] - measured[:3, 3]) < 0.002
        np.testing.assert_allclose(chain[:3, :3], measured[:3, :3], atol=0.01)
        checked += 1
    assert {child: frames for child, frames in parents.items() if len(frames) > 1} == {}
    expected = {**urdf_parent, **dict.fromkeys([root, "tool", "reference", "cf"], "world")}
    assert {child: frames.pop() for child, frames in parents.items()} == {c: expected.get(c) for c in parents}
    assert set(urdf_parent) | {root} <= set(parents)  # every joint of the URDF, and its root
    return checked


def _check_joint_states_put_the_tool_where_tf_says(joint_states: list, tf: list) -> int:
    """Forward kinematics of every joint state (PyBullet, the simulator's iiwa) puts the tool point within 2 mm of
    ``/tf``'s tool at that stamp (where that ``/tf`` arrived: the server drops messages a slow client cannot take).
    Returns how many were checked."""
    import pybullet
    import pybullet_data

    tool = {}
    for message in tf:
        for transform in message.transforms:
            if transform.child_frame_id == "tool":
                p = transform.transform.translation
                tool[_stamp(transform.header)] = np.array([p.x, p.y, p.z])
    client = pybullet.connect(pybullet.DIRECT)
    try:
        robot = pybullet.loadURDF(f"{pybullet_data.getDataPath()}/kuka_iiwa/model.urdf", useFixedBase=True,
                                  physicsClientId=client)  # fmt: skip
        checked = 0
        for message in joint_states:
            assert list(message.name) == [f"lbr_iiwa_joint_{k}" for k in range(1, 8)]
            if _stamp(message.header) not in tool:
                continue
            for k, angle in enumerate(message.position):
                pybullet.resetJointState(robot, k, float(angle), physicsClientId=client)
            state = pybullet.getLinkState(robot, 6, computeForwardKinematics=True, physicsClientId=client)
            tip = np.array(state[4]) + matrix_from_quaternion(state[5])[:, 2] * LINK7_TO_TOOL_POINT_M
            assert np.linalg.norm(tip - tool[_stamp(message.header)]) < 0.002
            checked += 1
        return checked
    finally:
        pybullet.disconnect(client)


def _check_truth_is_the_stored_telemetry(stack, received: dict[str, list]) -> int:
    """Every ``/force/true`` and ``/contact`` message is the stored telemetry's true normal force (exactly) and
    contact at the step its log time stamps (start + t); they are sent at the poses' steps (the server may drop some
    messages of any channel for a client that lags, so the steps are compared where all were received); the tool
    pressed (> 1 N) at some of them. Returns how many steps were checked."""
    execution = stack.execution(received["execution"])
    body = stack.http.get(f"/executions/{execution['id']}/telemetry").json()
    start_ns = int(execution["created"] * 1e9)
    stored = {start_ns + round(t * 1e9): (force, contact) for t, force, contact in
              zip(body["t"], body["normal_force_true_n"], body["in_contact"], strict=True)}  # fmt: skip
    forces = dict(zip(received["log_time:/force/true"], (m.data for m in received["/force/true"]), strict=True))
    contacts = dict(zip(received["log_time:/contact"], (m.data for m in received["/contact"]), strict=True))
    for stamp, force in forces.items():
        assert force == stored[stamp][0]
    for stamp, contact in contacts.items():
        assert contact == stored[stamp][1]
    assert len(forces.keys() & contacts.keys() & {_stamp(m.header) for m in received["/wrench/cf"]}) > 50
    assert max(forces.values()) > 1.0 and any(contacts.values()) and not all(contacts.values())
    return len(forces)


def test_the_truth_messages_encode_as_rosbags_does_and_skip_what_was_not_recorded():
    from services.store import TELEMETRY_LAYOUT

    store = _typestore()
    rows = np.zeros((6, max(b for _, b in TELEMETRY_LAYOUT.values())))
    force, contact = TELEMETRY_LAYOUT["normal_force_true_n"][0], TELEMETRY_LAYOUT["in_contact"][0]
    rows[:, force] = [0.0, 3.5, 14.25, 15.0, np.nan, np.nan]  # the last two: stored before the columns were streamed
    rows[:, contact] = [0.0, 1.0, 1.0, 1.0, np.nan, np.nan]
    stamps = np.arange(6, dtype=np.int64) * 1_000_000
    out = truth_messages(rows, stamps)
    assert set(out) == set(TRUTH_TOPICS)
    for topic, (kept, payloads) in out.items():
        assert kept.tolist() == stamps[:4].tolist()
        values = rows[:4, force] if topic == "/force/true" else rows[:4, contact] > 0.5
        expected = [store.serialize_cdr(store.types[TRUTH_TOPICS[topic]](data=v), TRUTH_TOPICS[topic])
                    for v in values.tolist()]  # fmt: skip
        assert payloads == [bytes(e) for e in expected]
    assert truth_messages(rows[4:], stamps[4:]) == {}


def test_the_live_server_streams_a_run_that_decodes_and_agrees_with_physics(stack, skill_id):
    health = stack.http.get("/health").json()
    assert health["foxglove_url"] == f"ws://127.0.0.1:{PORT}"

    def start() -> str:
        return stack.post("/executions", {"skill_id": skill_id, "environment": {"unknown_offset": [0, 0, 0.01]}},
                          202)["id"]  # fmt: skip

    def finished(execution_id: str) -> bool:
        return stack.execution(execution_id)["status"] in ("done", "aborted", "failed")

    channels, received, mesh, mesh_uri = asyncio.run(_record_live(health["foxglove_url"], start, finished))
    advertised = {c["topic"]: c for c in channels}
    assert set(execution_topics()) | set(TRUTH_TOPICS) | {"/execution"} <= set(advertised)
    for topic, msgtype in {**execution_topics(), **TRUTH_TOPICS}.items():
        assert (advertised[topic]["encoding"], advertised[topic]["schemaEncoding"]) == ("cdr", "ros2msg")
        assert advertised[topic]["schemaName"] == msgtype and received[topic], f"nothing received on {topic}"
    assert received["/execution"][-1].data == received["execution"]
    assert _check_truth_is_the_stored_telemetry(stack, received) > 50
    assert _check_tf_is_the_urdfs_tree(received["/tf"], received["/robot_description"][-1].data) > 20
    assert _check_cf_turns_the_cf_wrench_into_the_world_wrench(received["/tf"], received["/wrench/world"],
                                                               received["/wrench/cf"]) > 50  # fmt: skip
    assert _check_joint_states_put_the_tool_where_tf_says(received["/joint_states"], received["/tf"]) > 20
    namespaces = {m.ns for m in received["/markers"][-1].markers}
    assert namespaces == {"reference_path", "executed_path", "cf_triads", "work_piece"}
    import pybullet_data

    assert mesh_uri.startswith("package://kuka_iiwa/meshes/") and mesh_uri.endswith(".stl")
    expected = pybullet_data.getDataPath() + "/kuka_iiwa/meshes/" + mesh_uri.rsplit("/", 1)[1]
    assert mesh == open(expected, "rb").read()  # noqa: SIM115


def test_the_exported_mcap_holds_joint_states_the_urdf_and_the_cf_frame(stack, skill_id):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    execution_id = stack.post("/executions", {"skill_id": skill_id}, 202)["id"]
    view = stack.finished(execution_id)
    data = stack.http.get(f"/executions/{execution_id}/telemetry", params={"format": "mcap"}).content
    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()])
    topics: dict[str, list] = defaultdict(list)
    for _, channel, _, message in reader.iter_decoded_messages():
        topics[channel.topic].append(message)
    assert set(execution_topics()) == set(topics)
    assert len(topics["/tf"]) == view["telemetry_samples"]  # one per control step, as the poses
    assert "<robot" in topics["/robot_description"][0].data
    assert _check_tf_is_the_urdfs_tree(topics["/tf"], topics["/robot_description"][0].data) == len(
        topics["/joint_states"]) > 100  # fmt: skip
    assert _check_cf_turns_the_cf_wrench_into_the_world_wrench(topics["/tf"], topics["/wrench/world"],
                                                               topics["/wrench/cf"]) > 1000  # fmt: skip
    assert _check_joint_states_put_the_tool_where_tf_says(topics["/joint_states"], topics["/tf"]) > 100


def test_the_live_view_listens_where_the_api_does_and_names_a_loopback_url_for_all_interfaces(tmp_path) -> None:
    """The Foxglove server binds the API's address (``ServiceSettings.host``): loopback by default, the container's
    interfaces in docker-compose, whose published port then reaches it from the host. A second loopback address shows
    it is the API's, not a fixed one; on all interfaces the URL names the loopback address a local client uses."""
    import socket

    from services.foxglove_live import client_url, live_view
    from services.settings import ServiceSettings
    from services.store import Store

    store = Store(tmp_path / "api.db")
    view = live_view(store, ServiceSettings(host="127.0.0.2", foxglove_port="0"))
    assert view is not None and view.url is None
    view.start()
    try:
        port = view.gate.port
        assert view.url == f"ws://127.0.0.2:{port}"
        with socket.create_connection(("127.0.0.2", port), timeout=5):
            pass
        with pytest.raises(OSError), socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # not on the default loopback address: the API's own
    finally:
        view.close()
    # on every interface (not bound in a test): the URL a local client uses
    assert client_url("0.0.0.0", 8765) == "ws://127.0.0.1:8765" and client_url("::", 8765) == "ws://[::1]:8765"


def test_the_urdf_foxglove_draws_is_the_simulators_arm_and_tool():
    """``services`` may not import the simulator (tests/test_layers.py): its copy of the tool geometry is held equal
    here, and the arm's joints are the simulator's."""
    from schemas.world import ToolConfig
    from sim_worker.robot_model import FLANGE_OFFSET_M, robot_urdf

    simulated = ET.fromstring(robot_urdf(ToolConfig()))
    drawn = ET.fromstring(robot_description())
    tip = simulated.find("joint[@name='tool_joint']/origin").get("xyz").split()
    assert LINK7_TO_FLANGE_M == FLANGE_OFFSET_M and float(tip[2]) == pytest.approx(LINK7_TO_TOOL_POINT_M)

    def joints(robot: ET.Element) -> list[tuple]:
        return [(j.get("name"), j.find("origin").attrib, j.find("axis").attrib) for j in robot.findall("joint")
                if j.get("type") == "revolute"]  # fmt: skip

    assert joints(drawn) == joints(simulated) and len(joints(drawn)) == 7
    meshes = [m.get("filename") for m in drawn.iter("mesh")]
    assert meshes and all(m.startswith("package://kuka_iiwa/meshes/") and m.endswith(".stl") for m in meshes)


def test_the_layout_users_load_shows_only_topics_the_server_and_the_export_have():
    layout = json.loads((Path(__file__).resolve().parents[1] / "docs" / "foxglove_layout.json").read_text())
    text = json.dumps(layout["configById"])
    named = set(re.findall(r'"(/[a-z_/]+?)(?:\.[a-z_.]+)?"', text)) - {"/move_base_simple/goal", "/clicked_point",
                                                                       "/initialpose"}  # fmt: skip
    served = set(execution_topics()) | set(TRUTH_TOPICS) | {"/execution"}
    assert named and named <= served, named - served
    # Every series on the receive time: the unstamped /force/true and /contact have no other, and a panel that mixed
    # it with header stamps would shift them live (Foxglove's receive time is the arrival; in an MCAP the log time).
    for panel, config in layout["configById"].items():
        assert {path["timestampMethod"] for path in config.get("paths", [])} <= {"receiveTime"}, panel
    assert "3D!scene" in json.dumps(layout["layout"]) and "/robot_description" in text


def _mcap_topics(data: bytes) -> tuple[dict[str, list], dict[str, str]]:
    """The decoded messages of an MCAP per topic, and its ``contact_skills`` metadata."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()])
    topics: dict[str, list] = defaultdict(list)
    for _, channel, _, message in reader.iter_decoded_messages():
        topics[channel.topic].append(message)
    metadata = next(m.metadata for m in reader.iter_metadata() if m.name == "contact_skills")
    return topics, metadata


def _check_the_learned_frames_are_the_skills(topics: dict[str, list], skill: dict, start_ns: int) -> int:
    """The ``cf`` of ``/tf`` is, at every sample of a contact segment and only there, at the demonstrated tool point
    with the axes of the skill's compliant frame in force (its one frame; for a series, the stored frame of the same
    time, 0.5° between them); every triad of ``/markers`` is one of the skill's frames (origin, axes), and every contact
    segment has one. ``start_ns``: the stamp of the demonstration's t = 0. Returns how many ``cf`` were checked."""
    tool = {_stamp(m.header): [m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in topics["/tool/pose"]}
    segments = [s for s in skill["segments"] if s["compliant_frames"] is not None]
    checked = 0
    for message in topics["/tf"]:
        for transform in message.transforms:
            if transform.child_frame_id != "cf":
                continue
            stamp = _stamp(transform.header)
            t = (stamp - start_ns) * 1e-9
            (segment,) = [s for s in segments if s["t_start"] - 1e-6 <= t <= s["t_end"] + 1e-6]
            frames = segment["compliant_frames"]
            k = int(np.argmin(np.abs(np.asarray(frames["t"]) + segment["t_start"] - t)))
            learned = matrix_from_quaternion(frames["orientations"][k])
            pose = _pose(transform.transform)
            np.testing.assert_allclose(pose[:3, 3], tool[stamp], atol=1e-12)
            tolerance = 1e-9 if len(frames["t"]) == 1 else np.radians(0.5)
            np.testing.assert_allclose(pose[:3, :3], learned, atol=tolerance)
            checked += 1
    (array,) = topics["/markers"]
    triads = next(m for m in array.markers if m.ns == "cf_triads")
    frames = [
        (np.asarray(o), matrix_from_quaternion(q))
        for s in segments
        for o, q in zip(s["compliant_frames"]["origins"], s["compliant_frames"]["orientations"], strict=True)
    ]
    origins_drawn = set()
    for k in range(0, len(triads.points), 6):  # a triad: x, y, z axes, two points each
        origin = np.array([triads.points[k].x, triads.points[k].y, triads.points[k].z])
        match = [R for o, R in frames if np.allclose(o, origin, atol=1e-12)]
        assert match, origin
        for axis in range(3):
            tip = triads.points[k + 2 * axis + 1]
            np.testing.assert_allclose((np.array([tip.x, tip.y, tip.z]) - origin) / 0.03, match[0][:, axis], atol=1e-9)
        origins_drawn.add(tuple(origin))
    for segment in segments:
        assert tuple(segment["compliant_frames"]["origins"][0]) in origins_drawn
    return checked


def test_a_skills_mcap_shows_the_robot_and_the_learned_frames_along_the_taught_path(stack, skill_id):
    """A skill learned from the simulator's teacher: its demonstration was recorded in the robot's world, so the MCAP
    has the arm (joint states whose forward kinematics put the tool on the demonstrated pose, the URDF, one /tf tree
    that agrees with it) and the learned compliant frames."""
    skill = stack.http.get(f"/skills/{skill_id}").json()
    demonstration = stack.http.get(f"/demonstrations/{skill['demonstration_id']}").json()
    response = stack.http.get(f"/skills/{skill_id}/mcap")
    assert response.status_code == 200, response.text
    topics, metadata = _mcap_topics(response.content)
    assert set(topics) == {"/tool/pose", "/wrench/world", "/tf", "/joint_states", "/robot_description", "/markers"}
    assert metadata["robot"] == "true" and metadata["skill_id"] == skill_id
    assert len(topics["/tool/pose"]) == len(topics["/tf"]) == len(demonstration["demonstration"]["t"])
    start_ns = _stamp(topics["/tool/pose"][0].header) - round(demonstration["demonstration"]["t"][0] * 1e9)
    assert _check_tf_is_the_urdfs_tree(topics["/tf"], topics["/robot_description"][0].data) == len(
        topics["/joint_states"]) > 50  # fmt: skip
    assert _check_joint_states_put_the_tool_where_tf_says(topics["/joint_states"], topics["/tf"]) > 50
    assert _check_the_learned_frames_are_the_skills(topics, skill["skill"], start_ns) > 500


def test_an_imported_skills_mcap_shows_the_tool_and_the_learned_frames_and_no_arm(stack):
    """A contour recorded elsewhere (the teacher's samples posted as plain JSON: no world, no robot): its skill's MCAP
    shows the tool frame, the path and the learned frames (a series, slerped), and no arm, whose joints it cannot know;
    a skill learned from an inline demonstration has none stored to show it along: 409 saying so."""
    recorded = stack.post("/demonstrations/record", {"scenario": "contour_cylinder", "seed": 1,
                                                     "overrides": {"move_duration_s": 2.0}}, 201)  # fmt: skip
    samples = stack.http.get(f"/demonstrations/{recorded['id']}").json()["demonstration"]
    imported = {name: samples[name] for name in ("t", "positions", "orientations", "wrenches")}
    demo = stack.post("/demonstrations", {**imported, "metadata": {"name": "elsewhere"}}, 201)
    skill = stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "contour"}, 201)
    assert skill["skill"]["taught_world"] is None
    response = stack.http.get(f"/skills/{skill['id']}/mcap")
    assert response.status_code == 200, response.text
    topics, metadata = _mcap_topics(response.content)
    assert set(topics) == {"/tool/pose", "/wrench/world", "/tf", "/markers"} and metadata["robot"] == "false"
    assert {(t.header.frame_id, t.child_frame_id) for m in topics["/tf"] for t in m.transforms} == {
        ("world", "tool"), ("world", "cf")}  # fmt: skip
    start_ns = _stamp(topics["/tool/pose"][0].header) - round(imported["t"][0] * 1e9)
    assert _check_the_learned_frames_are_the_skills(topics, skill["skill"], start_ns) > 500
    triads = next(m for m in topics["/markers"][0].markers if m.ns == "cf_triads")
    assert len(triads.points) // 6 > 5  # a contour's series, along the path
    inline = stack.post("/skills", {"demonstration": imported, "skill_type": "contour"}, 201)
    refused = stack.http.get(f"/skills/{inline['id']}/mcap")
    assert refused.status_code == 409 and "inline demonstration" in refused.json()["detail"]
