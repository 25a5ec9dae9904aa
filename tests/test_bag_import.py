"""ROS 2 bags in (services/bag_import.py): real bags written by ``rosbags`` (tests/rosbag_files.py) from analytic
demonstrations with known truth, imported and learned as ``contact-skills learn BAG`` and ``POST /demonstrations/bag``
do: topics chosen, header stamps (not bag time), frames (world, tool, a sensor fixed by /tf_static, a /tf chain)
and two asynchronous topics on one time base, checked sample by sample and on the learned normal and force."""

from __future__ import annotations

import os
import subprocess
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from rosbag_files import POSE_EVERY, STAMP_BASE_NS, storage_file, write_bag

pytest.importorskip("rosbags")

from corpus import synthetic
from schemas import Skill, SkillType
from schemas.skill import SegmentKind
from services.bag_import import BagImportError, demonstration_from_bag
from skills.quaternions import matrix_from_quaternion

REPO = Path(__file__).resolve().parents[1]
TILT_15 = (np.sin(np.radians(15.0)), 0.0, -np.cos(np.radians(15.0)))
MEASURED = {"wrench_convention": "measured-on-tool"}


@cache
def _slide() -> synthetic.SyntheticDemo:
    return synthetic.plane_slide(normal=TILT_15, seed=0)


@cache
def _contour() -> synthetic.SyntheticDemo:
    return synthetic.cylinder_contour(seed=0)


def _bag(tmp: Path, demo: synthetic.SyntheticDemo, name: str, **options) -> Path:
    return write_bag(tmp / name, demo.t, demo.positions, demo.orientations, demo.wrenches, **options)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize(
    ("storage", "wrench_frame", "pose", "options"),
    [
        ("mcap", "tool", "pose_stamped", {"tool_frame": "tool"}),
        ("mcap", "world", "pose_stamped", {}),
        ("sqlite3", "ft_sensor", "tf", {"tf_frames": ("world", "tool")}),
    ],
)
def test_bag_samples_are_the_truth_in_the_conventions(tmp_path, storage, wrench_frame, pose, options):
    """Imported without tare, every sample is the truth: position and orientation in the world, the wrench the tool
    applies at the tool point in the world, on one 1 kHz time base from 250 Hz poses stamped 1 ms off the wrench."""
    truth = _slide()
    bag = _bag(tmp_path, truth, "bag", storage=storage, wrench_frame=wrench_frame, pose=pose)
    demo = demonstration_from_bag(bag, **MEASURED, **options, tare=False)
    a = demo.arrays()
    rows = np.arange(1, 1 + a.t.size)  # the shared span starts at the first pose, one wrench sample in
    np.testing.assert_allclose(a.t, truth.t[rows] - truth.t[1], atol=1e-9)
    at_pose = np.arange(0, a.t.size, POSE_EVERY)  # grid samples where a pose message was stamped
    np.testing.assert_allclose(a.positions[at_pose], truth.positions[rows[at_pose]], atol=1e-9)
    np.testing.assert_allclose(a.positions, truth.positions[rows], atol=2e-4)  # between poses: cubic, tremor
    alignment = np.abs(np.sum(a.orientations * truth.orientations[rows], axis=1))
    assert np.all(alignment > 1 - 1e-9)
    np.testing.assert_allclose(a.wrenches, truth.wrenches[rows], atol=1e-5)
    frames = demo.metadata.extra["bag"]["frames"]
    assert frames["world"] == "world" and frames["wrench"] == wrench_frame
    assert (
        demo.metadata.source == "bag:bag" and demo.metadata.extra["bag"]["start_stamp_ns"] == STAMP_BASE_NS + 1_000_000
    )


def test_the_bag_is_logged_out_of_stamp_order(tmp_path):
    """The premise of the test above: importing by the bag's log time would misplace samples by up to 30 ms."""
    from rosbags.highlevel import AnyReader

    bag = _bag(tmp_path, _slide(), "bag")
    with AnyReader([bag]) as reader:
        [connection] = [c for c in reader.connections if c.topic == "/ft_sensor/wrench"]
        pairs = [
            (log, (m := reader.deserialize(raw, connection.msgtype)).header.stamp.sec * 10**9 + m.header.stamp.nanosec)
            for _, log, raw in reader.messages(connections=[connection])
        ]
    stamps = np.array([stamp for _, stamp in pairs])
    delays = np.array([log - stamp for log, stamp in pairs]) * 1e-9
    assert np.any(np.diff(stamps) < 0) and delays.max() > 0.02


def _contact(skill: Skill):
    [contact] = [s for s in skill.segments if s.kind is SegmentKind.contact]
    return contact


def test_learn_a_slide_from_an_mcap_bag_with_the_cli(tmp_path):
    """``contact-skills learn demo.mcap``: the storage file alone, tared, learned; normal and force against truth."""
    truth = _slide()
    bag = storage_file(_bag(tmp_path, truth, "slide", storage="mcap", wrench_frame="tool"))
    out = tmp_path / "skill.json"
    env = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"}
    argv = [sys.executable, "-m", "cli.main", "learn", str(bag), "--wrench", "measured-on-tool", "--tool-frame", "tool",
            "-o", str(out)]  # fmt: skip
    result = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "ROS 2 bag: wrench /ft_sensor/wrench" in result.stdout
    skill = Skill.model_validate_json(out.read_text())
    assert skill.skill_type is SkillType.slide
    contact = _contact(skill)
    z = matrix_from_quaternion(contact.compliant_frames.orientations[0])[:, 2]
    assert _angle_deg(z, truth.normals[0]) < 1.0
    assert contact.force_constant_n == pytest.approx(truth.target_force_n, rel=0.02)
    assert abs(contact.t_start - (truth.contact_on_s - truth.t[1])) < 0.05


def test_learn_a_contour_from_a_sqlite3_bag_with_tf_and_a_sensor_frame(tmp_path):
    """A bag directory (sqlite3), the pose as a /tf chain, the wrench in a sensor frame off the tool point."""
    from skills.parameterize import learn_skill

    truth = _contour()
    bag = _bag(tmp_path, truth, "contour", storage="sqlite3", wrench_frame="ft_sensor", pose="tf")
    demo = demonstration_from_bag(bag, **MEASURED, tf_frames=("world", "tool"))
    skill = learn_skill(demo)
    assert skill.skill_type is SkillType.contour
    contact = _contact(skill)
    frames = contact.compliant_frames
    rows = contact.start_index + np.round(np.asarray(frames.t) * skill.sample_rate_hz).astype(int)
    truth_rows = rows + 1  # the imported grid starts one truth sample in
    pressing = truth.normal_force_true[truth_rows] > 0.1 * truth.target_force_n
    outward = truth.positions[truth_rows] - np.array([0.5, 0.0, 0.1])
    outward[:, 1] = 0.0
    errors = _angle_deg(matrix_from_quaternion(frames.orientations)[:, :, 2], -outward)[pressing]
    assert errors.max() < 3.0, f"CF z off the cylinder's normal by up to {errors.max():.2f} deg"
    assert contact.quality.force_rms_n < 0.05 * truth.target_force_n


def test_ambiguous_topics_and_unknown_frames_name_the_option(tmp_path):
    truth = _slide()
    bag = _bag(tmp_path, truth, "two", second_wrench_topic=True)
    with pytest.raises(BagImportError) as caught:
        demonstration_from_bag(bag, **MEASURED, tool_frame="tool")
    assert caught.value.problems[0].startswith("wrench_topic: 2 geometry_msgs/msg/WrenchStamped topics")
    assert "/ft_sensor/wrench_filtered" in str(caught.value) and "--wrench-topic" in str(caught.value)
    chosen = demonstration_from_bag(bag, **MEASURED, tool_frame="tool", wrench_topic="/ft_sensor/wrench_filtered")
    assert chosen.metadata.extra["bag"]["wrench_topic"] == "/ft_sensor/wrench_filtered"

    with pytest.raises(BagImportError, match=r"wrench_frame: the wrench's frame_id is 'tool'.*--wrench-frame"):
        demonstration_from_bag(bag, **MEASURED, wrench_topic="/ft_sensor/wrench")  # no --tool-frame: tool unknown
    with pytest.raises(BagImportError, match="wrench_topic: no topic '/nope'"):
        demonstration_from_bag(bag, wrench_topic="/nope")
    with pytest.raises(BagImportError, match="pose_topic: topic '/ft_sensor/wrench' holds"):
        demonstration_from_bag(bag, wrench_topic="/ft_sensor/wrench", pose_topic="/ft_sensor/wrench")
    tf_bag = _bag(tmp_path, truth, "tf", pose="tf", wrench_frame="ft_sensor")
    with pytest.raises(BagImportError, match="tf: /tf does not connect 'world' to 'gripper'"):
        demonstration_from_bag(tf_bag, tf_frames=("world", "gripper"))
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a bag")
    with pytest.raises(BagImportError, match=r"file: cannot read the bag 'broken\.mcap'"):
        demonstration_from_bag(broken)


def test_upload_a_bag_to_the_api(tmp_path):
    from fastapi.testclient import TestClient

    from services.app import create_app
    from services.settings import ServiceSettings

    truth = _slide()
    bag = storage_file(_bag(tmp_path, truth, "up", storage="sqlite3", second_wrench_topic=True))
    form = {"wrench": "measured-on-tool", "tool_frame": "tool", "wrench_topic": "/ft_sensor/wrench"}
    app = create_app(ServiceSettings(db_path=tmp_path / "api.db"), bus=None)
    with TestClient(app, base_url="http://127.0.0.1") as client:  # a loopback API answers loopback names only
        files = {"file": (bag.name, bag.read_bytes())}
        created = client.post("/demonstrations/bag", files=files, data=form)
        assert created.status_code == 201, created.text
        body = created.json()
        assert body["source"] == f"bag:{bag.name}" and body["summary"]["n_samples"] == truth.t.size - 3
        assert any("sensor offset removed" in note for note in body["import_notes"])
        stored = client.get(f"/demonstrations/{body['id']}").json()["demonstration"]
        assert stored["metadata"]["extra"]["bag"]["frames"]["tool"] == "tool"

        ambiguous = client.post("/demonstrations/bag", files=files, data={"tool_frame": "tool"})
        assert ambiguous.status_code == 422 and ambiguous.json()["detail"][0]["loc"] == ["body", "wrench_topic"]
        text = client.post("/demonstrations/bag", files={"file": ("demo.txt", b"x")})
        assert text.status_code == 422 and text.json()["detail"][0]["loc"] == ["body", "file"]
        half = client.post("/demonstrations/bag", files=files, data={"tf_parent": "world"})
        assert half.status_code == 422 and "tf_child" in half.text
        unknown = client.post("/demonstrations/bag", files=files, data={"colour": "red"})
        assert unknown.status_code == 422 and unknown.json()["detail"][0]["loc"] == ["body", "colour"]
