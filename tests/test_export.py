"""Export (services/telemetry_export.py, GET .../telemetry?format=, contact-skills export): a real execution of a
learned skill in PyBullet, stored as the API stores telemetry, exported as MCAP, CSV and JSON with time windows, and
read back — MCAP with the ``mcap`` library and the ROS 2 decoder of ``mcap-ros2-support`` (not our writer's code) —
against the stored telemetry; a demonstration's MCAP imported again as a bag gives the same samples."""

from __future__ import annotations

import csv
import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap_ros2")

from fastapi.testclient import TestClient
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from schemas import ExecutionSettings
from services.app import create_app
from services.local_processes import free_port, stop_process, wait_for_port
from services.settings import ServiceSettings
from services.store import TELEMETRY_LAYOUT, Store
from services.telemetry_export import EXECUTION_CSV_COLUMNS

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A store holding a recorded demonstration and a real execution of the skill learned from it."""
    from sim_worker.executor import execute_skill
    from sim_worker.teacher import record_demonstration
    from skills.parameterize import learn_skill

    recording = record_demonstration("slide_flat", seed=0, move_duration_s=2.0)
    skill = learn_skill(recording.demonstration)
    result = execute_skill(skill, recording.world_config, ExecutionSettings())
    assert result.metrics.phase.value == "done"
    path = tmp_path_factory.mktemp("export") / "export.db"
    store = Store(path)
    demo = store.demonstrations.add(recording.demonstration)
    execution = store.executions.add({"skill_id": None}, None)
    assert store.telemetry.add(execution.id, result.telemetry.to_batch(execution.id))
    yield {"path": path, "store": store, "demo": demo, "execution": store.executions.get(execution.id)}
    store.close()


@pytest.fixture(scope="module")
def client(stored):
    app = create_app(ServiceSettings(db_path=stored["path"]), bus=None, store=stored["store"])
    with TestClient(app, base_url="http://127.0.0.1") as c:  # a loopback API answers loopback names only
        yield c


def _mcap_messages(data: bytes) -> dict[str, list[tuple[int, object]]]:
    """Topic -> [(log time ns, decoded ROS 2 message)] read with mcap + mcap-ros2-support."""
    found: dict[str, list] = {}
    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()])
    for schema, channel, message, decoded in reader.iter_decoded_messages():
        assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
        found.setdefault(channel.topic, []).append((message.log_time, decoded))
    return found


def _stamp(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def test_execution_mcap_holds_the_stored_telemetry(client, stored):
    execution = stored["execution"]
    matrix = stored["store"].telemetry.rows(execution.id)
    column = {name: matrix[:, a:b] for name, (a, b) in TELEMETRY_LAYOUT.items()}
    response = client.get(f"/executions/{execution.id}/telemetry", params={"format": "mcap"})
    assert response.status_code == 200 and f"{execution.id}.mcap" in response.headers["content-disposition"]
    topics = _mcap_messages(response.content)
    n = matrix.shape[0]
    scene = ("/phase", "/segment", "/joint_states", "/robot_description", "/markers")  # tests/test_foxglove.py
    assert {t: len(m) for t, m in topics.items() if t not in scene} == {
        t: n
        for t in ("/tool/pose", "/reference/pose", "/wrench/world", "/wrench/cf", "/force/desired", "/tf",
                  "/force/true", "/contact")
    }  # fmt: skip
    start = round(execution.created * 1e9)
    stamps = np.array([_stamp(m.header) for _, m in topics["/tool/pose"]])
    np.testing.assert_allclose((stamps - start) * 1e-9, column["t"][:, 0], atol=1e-9)
    assert [log for log, _ in topics["/tool/pose"]] == stamps.tolist()
    pose = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z, m.pose.orientation.x,
                      m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w]
                     for _, m in topics["/tool/pose"]])  # fmt: skip
    np.testing.assert_array_equal(pose, np.hstack([column["tool_position"], column["tool_orientation"]]))

    def wrenches(topic: str) -> np.ndarray:
        return np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x,
                          m.wrench.torque.y, m.wrench.torque.z] for _, m in topics[topic]])  # fmt: skip

    np.testing.assert_array_equal(wrenches("/wrench/world"), column["wrench_world"])
    np.testing.assert_array_equal(wrenches("/wrench/cf"), column["wrench_cf"])
    np.testing.assert_array_equal(wrenches("/force/desired")[:, 2], column["desired_force_cf_z_n"][:, 0])
    assert {m.header.frame_id for _, m in topics["/wrench/cf"]} == {"cf"}
    # The simulator's truth, as in the live view: the true normal force and the contact of every sample.
    assert [m.data for _, m in topics["/force/true"]] == column["normal_force_true_n"][:, 0].tolist()
    assert [m.data for _, m in topics["/contact"]] == (column["in_contact"][:, 0] > 0.5).tolist()
    assert [log for log, _ in topics["/force/true"]] == stamps.tolist()
    tf = {t.child_frame_id: t for t in topics["/tf"][n // 2][1].transforms}
    assert tf["tool"].header.frame_id == tf["reference"].header.frame_id == "world"
    assert tf["tool"].transform.translation.x == column["tool_position"][n // 2, 0]
    assert tf["reference"].transform.translation.y == column["reference_position"][n // 2, 1]
    # Phases: a message at the start and at every change, the same sequence as stored.
    json_phases = client.get(f"/executions/{execution.id}/telemetry").json()["phase"]
    changes = [p for k, p in enumerate(json_phases) if k == 0 or p != json_phases[k - 1]]
    assert [m.data for _, m in topics["/phase"]] == changes and "contact" in changes
    assert next(m.data for _, m in topics["/segment"]) == int(column["segment_index"][0, 0])


def test_execution_csv_and_time_window(client, stored):
    execution = stored["execution"]
    matrix = stored["store"].telemetry.rows(execution.id)
    params = {"format": "csv", "t0": 2.0, "t1": 4.0, "every": 10}
    response = client.get(f"/executions/{execution.id}/telemetry", params=params)
    assert response.status_code == 200 and response.headers["content-type"].startswith("text/csv")
    rows = list(csv.reader(io.StringIO(response.text)))
    assert rows[0] == EXECUTION_CSV_COLUMNS
    t = matrix[:, 0]
    expected = matrix[(t >= 2.0) & (t <= 4.0)][::10]
    assert len(rows) - 1 == expected.shape[0] and float(rows[1][0]) >= 2.0 and float(rows[-1][0]) <= 4.0
    values = np.array([[float(v) for k, v in enumerate(row) if k != 1] for row in rows[1:]])
    np.testing.assert_array_equal(values, np.delete(expected, 1, axis=1))
    window = client.get(f"/executions/{execution.id}/telemetry", params={"t0": 2.0, "t1": 4.0}).json()
    assert window["n_samples"] == int(((t >= 2.0) & (t <= 4.0)).sum()) and window["t"][0] >= 2.0
    mcap = _mcap_messages(
        client.get(f"/executions/{execution.id}/telemetry", params={**params, "format": "mcap"}).content
    )
    assert len(mcap["/wrench/cf"]) == expected.shape[0]
    bad = client.get(f"/executions/{execution.id}/telemetry", params={"t0": 4.0, "t1": 2.0})
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"] == ["query", "t1"]
    assert client.get("/executions/exec_nope/telemetry", params={"format": "mcap"}).status_code == 404
    assert client.get(f"/executions/{execution.id}/telemetry", params={"format": "xml"}).status_code == 422


def test_demonstration_mcap_is_a_bag_that_imports_to_the_same_samples(client, stored, tmp_path):
    from schemas.import_options import BagImportOptions
    from services.bag_import import demonstration_from_bag

    demo_id = stored["demo"].id
    original = stored["store"].demonstrations.get(demo_id).arrays()
    response = client.get(f"/demonstrations/{demo_id}/telemetry", params={"format": "mcap"})
    assert response.status_code == 200
    topics = _mcap_messages(response.content)
    assert sorted(topics) == ["/tf", "/tool/pose", "/wrench/world"]
    assert len(topics["/wrench/world"]) == original.t.size
    path = tmp_path / "demo.mcap"
    path.write_bytes(response.content)
    again = demonstration_from_bag(path, BagImportOptions(tare=False)).arrays()
    np.testing.assert_allclose(again.t, original.t - original.t[0], atol=1e-9)
    np.testing.assert_allclose(again.positions, original.positions, atol=1e-12)
    np.testing.assert_allclose(again.wrenches, original.wrenches, atol=1e-12)
    window = client.get(f"/demonstrations/{demo_id}/telemetry", params={"format": "csv", "t0": 1, "t1": 2})
    rows = list(csv.reader(io.StringIO(window.text)))
    inside = (original.t >= 1) & (original.t <= 2)
    assert len(rows) - 1 == inside.sum() and np.isclose(float(rows[1][0]), original.t[inside][0])
    columns = client.get(f"/demonstrations/{demo_id}/telemetry", params={"t1": 0.5}).json()
    assert columns["n_samples"] == (original.t <= 0.5).sum() == len(columns["wrenches"])


def test_the_export_command_fetches_from_the_api_and_converts_local_files(stored, tmp_path):
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    log = (tmp_path / "api.log").open("w")
    api = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "api", "--no-bus", "--port", str(port), "--db", str(stored["path"])],
        env=env, stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        wait_for_port(port, 60)
        url = f"http://127.0.0.1:{port}"

        def export(*args: str) -> subprocess.CompletedProcess:
            argv = [sys.executable, "-m", "cli.main", "export", *args, "--url", url]
            return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)

        execution_id = stored["execution"].id
        done = export(execution_id, "-o", str(tmp_path / "run.mcap"))
        assert done.returncode == 0, done.stderr
        assert (
            len(_mcap_messages((tmp_path / "run.mcap").read_bytes())["/wrench/cf"])
            == stored["store"].telemetry.counts(execution_id)[1]
        )
        windowed = export(stored["demo"].id, "-o", str(tmp_path / "demo.csv"), "--t0", "1", "--t1", "2")
        assert windowed.returncode == 0, windowed.stderr
        assert (tmp_path / "demo.csv").read_text().splitlines()[0].startswith("t,x,y,z,qx")
        missing = export("exec_000000000000", "-o", str(tmp_path / "x.mcap"))
        assert missing.returncode == 2 and "no execution with id 'exec_000000000000'" in missing.stderr
    finally:
        stop_process(api)
        log.close()
    demonstration = stored["store"].demonstrations.get(stored["demo"].id)
    local = tmp_path / "demo.json"
    local.write_text(demonstration.model_dump_json())
    offline = subprocess.run(
        [sys.executable, "-m", "cli.main", "export", str(local), "-o", str(tmp_path / "local.mcap")],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert offline.returncode == 0, offline.stderr
    assert len(_mcap_messages((tmp_path / "local.mcap").read_bytes())["/tool/pose"]) == demonstration.n_samples


def test_the_vectorized_cdr_is_byte_identical_to_rosbags():
    """services.telemetry_export.CdrLayout writes what rosbags' serializer writes, for every message it builds."""
    from rosbags.typesys import Stores, get_typestore

    from services.cdr import pose_stamped, tf_message, wrench_stamped

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    rng = np.random.default_rng(0)
    stamps = np.array([0, 1_700_000_000_123_456_789, 2_000_000_000_999_999_999])
    values = rng.normal(size=(3, 7))

    def header(stamp, frame):
        time = types["builtin_interfaces/msg/Time"](sec=int(stamp // 10**9), nanosec=int(stamp % 10**9))
        return types["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def vector(v):
        return types["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2])

    def quaternion(q):
        return types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])

    for frame in ("world", "cf", "a_longer_frame"):  # string lengths move the alignment of what follows
        poses = pose_stamped(frame).messages(stamp=stamps, pose=values)
        wrenches = wrench_stamped(frame).messages(stamp=stamps, wrench=values[:, :6])
        tfs = tf_message([(frame, "tool"), (frame, "reference")]).messages(
            stamp_tool=stamps, stamp_reference=stamps, tool=values, reference=values[::-1]
        )
        for k, stamp in enumerate(stamps):
            v, r = values[k], values[::-1][k]
            pose = types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](*v[:3]),
                                                   orientation=quaternion(v[3:]))  # fmt: skip
            expected = store.serialize_cdr(types["geometry_msgs/msg/PoseStamped"](header(stamp, frame), pose),
                                           "geometry_msgs/msg/PoseStamped")  # fmt: skip
            assert poses[k] == bytes(expected)
            wrench = types["geometry_msgs/msg/Wrench"](force=vector(v[:3]), torque=vector(v[3:6]))
            expected = store.serialize_cdr(types["geometry_msgs/msg/WrenchStamped"](header(stamp, frame), wrench),
                                           "geometry_msgs/msg/WrenchStamped")  # fmt: skip
            assert wrenches[k] == bytes(expected)
            transforms = [
                types["geometry_msgs/msg/TransformStamped"](
                    header(stamp, frame), child, types["geometry_msgs/msg/Transform"](vector(x[:3]), quaternion(x[3:]))
                )
                for child, x in (("tool", v), ("reference", r))
            ]
            expected = store.serialize_cdr(types["tf2_msgs/msg/TFMessage"](transforms), "tf2_msgs/msg/TFMessage")
            assert tfs[k] == bytes(expected)
