"""ROS 2 and ROS 1 bags in (services/bag_import.py): real bags written by ``rosbags`` (tests/rosbag_files.py) from
analytic demonstrations with known truth, imported and learned as ``contact-skills learn BAG`` and ``POST
/demonstrations/bag`` do: topics chosen, header stamps (not bag time), frames (world, tool, a sensor fixed by
/tf_static, a /tf chain) and two asynchronous topics on one time base, checked sample by sample and on the learned
normal and force. Any other file gets one message on every interface; the import options are one model for the
command line and the forms."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import zipfile
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from rosbag_files import POSE_EVERY, STAMP_BASE_NS, storage_file, write_bag

pytest.importorskip("rosbags")

from corpus import synthetic
from schemas import Skill, SkillType
from schemas.import_options import BagImportOptions
from schemas.skill import SegmentKind
from services.bag_import import BagImportError, demonstration_from_bag
from skills.quaternions import matrix_from_quaternion

REPO = Path(__file__).resolve().parents[1]
TILT_15 = (np.sin(np.radians(15.0)), 0.0, -np.cos(np.radians(15.0)))
MEASURED = {"wrench_convention": "measured-on-tool"}
TF_PAIR = {"tf_parent": "world", "tf_child": "tool"}


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


def _assert_the_truth(demo, truth: synthetic.SyntheticDemo) -> None:
    """Every sample of ``demo`` (imported without tare) is the truth: position and orientation in the world, the wrench
    the tool applies at the tool point in the world, on one 1 kHz time base from 250 Hz poses stamped 1 ms off the
    wrench (the shared span starts at the first pose, one wrench sample in)."""
    a = demo.arrays()
    rows = np.arange(1, 1 + a.t.size)  # the shared span starts at the first pose, one wrench sample in
    np.testing.assert_allclose(a.t, truth.t[rows] - truth.t[1], atol=1e-9)
    at_pose = np.arange(0, a.t.size, POSE_EVERY)  # grid samples where a pose message was stamped
    np.testing.assert_allclose(a.positions[at_pose], truth.positions[rows[at_pose]], atol=1e-9)
    np.testing.assert_allclose(a.positions, truth.positions[rows], atol=2e-4)  # between poses: cubic, tremor
    alignment = np.abs(np.sum(a.orientations * truth.orientations[rows], axis=1))
    assert np.all(alignment > 1 - 1e-9)
    np.testing.assert_allclose(a.wrenches, truth.wrenches[rows], atol=1e-5)
    assert demo.metadata.wrench_convention_on_import == "measured-on-tool"
    assert demo.metadata.extra["bag"]["start_stamp_ns"] == STAMP_BASE_NS + 1_000_000


@pytest.mark.parametrize(
    ("storage", "wrench_frame", "pose", "options"),
    [
        ("mcap", "tool", "pose_stamped", {"tool_frame": "tool"}),
        ("mcap", "world", "pose_stamped", {}),
        ("sqlite3", "ft_sensor", "tf", TF_PAIR),
        ("ros1", "tool", "pose_stamped", {"tool_frame": "tool"}),
        ("ros1", "ft_sensor", "tf", TF_PAIR),
    ],
)
def test_bag_samples_are_the_truth_in_the_conventions(tmp_path, storage, wrench_frame, pose, options):
    """ROS 2 (MCAP, sqlite3) and ROS 1 alike: imported without tare, every sample is the truth (`_assert_the_truth`)."""
    truth = _slide()
    bag = _bag(tmp_path, truth, "bag", storage=storage, wrench_frame=wrench_frame, pose=pose)
    demo = demonstration_from_bag(bag, BagImportOptions(**MEASURED, **options, tare=False))
    _assert_the_truth(demo, truth)
    frames = demo.metadata.extra["bag"]["frames"]
    assert frames["world"] == "world" and frames["wrench"] == wrench_frame
    ros = 1 if storage == "ros1" else 2
    assert demo.metadata.source == f"bag:{bag.name}" and demo.metadata.extra["bag"]["ros"] == ros
    assert demo.metadata.extra["import_notes"][0].startswith(f"ROS {ros} bag: wrench /ft_sensor/wrench")


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
    demo = demonstration_from_bag(bag, BagImportOptions(**MEASURED, **TF_PAIR))
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
        demonstration_from_bag(bag, BagImportOptions(**MEASURED, tool_frame="tool"))
    assert caught.value.problems[0].startswith("wrench_topic: 2 geometry_msgs/msg/WrenchStamped topics")
    assert "/ft_sensor/wrench_filtered" in str(caught.value) and "--wrench-topic" in str(caught.value)
    chosen = demonstration_from_bag(
        bag, BagImportOptions(**MEASURED, tool_frame="tool", wrench_topic="/ft_sensor/wrench_filtered")
    )
    assert chosen.metadata.extra["bag"]["wrench_topic"] == "/ft_sensor/wrench_filtered"

    with pytest.raises(BagImportError, match=r"wrench_frame: the wrench's frame_id is 'tool'.*--wrench-frame"):
        demonstration_from_bag(bag, BagImportOptions(**MEASURED, wrench_topic="/ft_sensor/wrench"))  # tool unknown
    with pytest.raises(BagImportError, match="wrench_topic: no topic '/nope'"):
        demonstration_from_bag(bag, BagImportOptions(wrench_topic="/nope"))
    with pytest.raises(BagImportError, match="pose_topic: topic '/ft_sensor/wrench' holds"):
        demonstration_from_bag(bag, BagImportOptions(wrench_topic="/ft_sensor/wrench", pose_topic="/ft_sensor/wrench"))
    tf_bag = _bag(tmp_path, truth, "tf", pose="tf", wrench_frame="ft_sensor")
    with pytest.raises(BagImportError, match="tf: /tf does not connect 'world' to 'gripper'"):
        demonstration_from_bag(tf_bag, BagImportOptions(tf_parent="world", tf_child="gripper"))
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\nnot a bag")  # an MCAP's magic, then nothing an MCAP holds
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


# --------------------------------------------------------------------------- ROS 1, every file, one options model

ROS1_FLAGS = ["--wrench", "measured-on-tool", "--tool-frame", "tool", "--no-tare", "--name", "ros1_demo"]
ROS1_FORM = {"wrench": "measured-on-tool", "tool_frame": "tool", "tare": "false", "name": "ros1_demo"}
"""The same options as ``contact-skills learn`` flags and as ``POST /demonstrations/bag`` form fields."""


def _in_process(argv: list[str]) -> tuple[int, str, str]:
    """``contact-skills ARGV`` run in this process: (exit code, stdout, stderr)."""
    from cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _api(tmp_path: Path):
    from conftest import api_settings, loopback_client

    from services.app import create_app

    return loopback_client(create_app(api_settings(tmp_path), bus=None))


def test_a_ros1_bag_imports_to_the_truth_through_the_cli_and_the_api(tmp_path):
    """``contact-skills learn demo.bag`` and ``POST /demonstrations/bag`` with the same options import a ROS 1 bag (the
    wrench in the tool frame, the sensor's reaction) to the truth, the same samples both ways; learn finds the plane."""
    from cli.import_options import import_demonstration
    from cli.main import build_parser

    truth = _slide()
    bag = _bag(tmp_path, truth, "demo", storage="ros1")
    args = build_parser().parse_args(["learn", str(bag), *ROS1_FLAGS, "-o", str(tmp_path / "skill.json")])
    from_cli = import_demonstration(bag, args)
    _assert_the_truth(from_cli, truth)
    assert from_cli.metadata.name == "ros1_demo" and from_cli.metadata.extra["bag"]["ros"] == 1
    with _api(tmp_path) as client:
        created = client.post("/demonstrations/bag", files={"file": (bag.name, bag.read_bytes())}, data=ROS1_FORM)
        assert created.status_code == 201, created.text
        assert created.json()["import_notes"][0].startswith("ROS 1 bag: wrench /ft_sensor/wrench (8000 messages)")
        stored = client.get(f"/demonstrations/{created.json()['id']}").json()["demonstration"]
    assert stored == from_cli.model_dump(mode="json")

    code, stdout, stderr = _in_process(["learn", str(bag), *ROS1_FLAGS, "-o", str(tmp_path / "skill.json")])
    assert code == 0, stderr
    assert "  import: ROS 1 bag: wrench /ft_sensor/wrench" in stdout
    contact = _contact(Skill.model_validate_json((tmp_path / "skill.json").read_text()))
    z = matrix_from_quaternion(contact.compliant_frames.orientations[0])[:, 2]
    assert _angle_deg(z, truth.normals[0]) < 1.0
    assert contact.force_constant_n == pytest.approx(truth.target_force_n, rel=0.02)
    code, _, stderr = _in_process(["learn", str(bag), "--columns", "t=time", "--dt", "0.01", "-o", str(tmp_path / "x")])
    assert code == 2 and stderr == (
        f"contact-skills learn: error: --columns, --dt: not an option of this file: {bag} is a ROS 1 bag\n"
    )


def _zip_bytes() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("demo.csv", "t,x\n0,1\n")
    return buffer.getvalue()


def test_any_other_file_gets_one_message_on_every_interface(tmp_path):
    """A PNG, a zip, random bytes named .bag and text named .mcap: the command line, both upload routes and the client
    say the same words, naming what IS read; a readable file sent to the other route is told where it goes."""
    from services.client import Client
    from services.demonstration_files import unsupported_file

    others = {
        "picture.png": b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)),
        "archive.zip": _zip_bytes(),
        "noise.bag": np.random.default_rng(0).bytes(4096),
        "notes.mcap": b"t,x\n0,1\n",
    }
    with _api(tmp_path) as api, Client("http://127.0.0.1:9") as client:  # the client refuses before sending
        for name, data in others.items():
            path = tmp_path / name
            path.write_bytes(data)
            message = unsupported_file(name)
            assert "CSV recording" in message and "ROS 2 bag" in message and "ROS 1 bag (.bag)" in message
            code, _, stderr = _in_process(["learn", str(path), "-o", str(tmp_path / "s.json")])
            assert code == 2 and stderr == f"contact-skills learn: error: {message}\n", name
            for route in ("/demonstrations/csv", "/demonstrations/bag"):
                answer = api.post(route, files={"file": (name, data)})
                assert answer.status_code == 422, (name, route)
                assert [(e["loc"], e["msg"]) for e in answer.json()["detail"]] == [(["body", "file"], message)]
            with pytest.raises(ValueError) as caught:
                client.upload(path)
            assert str(caught.value) == message
        bag = storage_file(_bag(tmp_path, _slide(), "wrong_route"))
        answer = api.post("/demonstrations/csv", files={"file": (bag.name, bag.read_bytes())})
        assert answer.json()["detail"][0]["msg"] == (
            f"{bag.name!r} is a ROS 2 bag, not a CSV recording (POST /demonstrations/bag takes it)"
        )


def test_one_options_model_for_the_command_line_and_the_forms():
    """Every field of the options models has a flag (all given here), and the flags give the model the form fields
    give: enums, numbers, number lists ('0,0.5' in a form, two values on the command line), a switch, the /tf pair."""
    from cli.import_options import options_from_args
    from cli.main import build_parser
    from schemas.import_options import CsvImportOptions

    shared_flags = ["--wrench", "measured-on-tool", "--wrench-frame", "tool", "--rate", "250", "--no-tare",
                    "--tare-window", "0", "0.5", "--force-offset", "1", "2", "3", "--name", "demo"]  # fmt: skip
    shared_form = {"wrench": "measured-on-tool", "wrench_frame": "tool", "rate": "250", "tare": "false",
                   "tare_window": "0,0.5", "force_offset": "1,2,3", "name": "demo", "file": "the upload"}  # fmt: skip
    kinds = [
        (BagImportOptions, ["--wrench-topic", "/ft", "--pose-topic", "/pose", "--tf", "world", "tool0",
                            "--tool-frame", "tool0"],
         {"wrench_topic": "/ft", "pose_topic": "/pose", "tf_parent": "world", "tf_child": "tool0",
          "tool_frame": "tool0"}),
        (CsvImportOptions, ["--columns", "t=time", "--quaternion-order", "wxyz", "--dt", "0.004"],
         {"columns": "t=time", "quaternion_order": "wxyz", "dt": "0.004"}),
    ]  # fmt: skip
    parser = build_parser()
    for model, flags, form in kinds:
        args = parser.parse_args(["learn", "demo", *shared_flags, *flags, "-o", "skill.json"])
        from_cli = options_from_args(args, model, "demo")
        assert from_cli.model_fields_set == set(model.model_fields)
        assert from_cli == model.model_validate(shared_form | form)
        assert from_cli.tare_window_s == (0.0, 0.5) and from_cli.force_offset == (1.0, 2.0, 3.0)
    assert from_cli.dt_s == 0.004 and BagImportOptions(**TF_PAIR).tf_frames == ("world", "tool")


def test_a_bag_with_a_stretch_of_no_messages_records_the_gap_on_the_demonstrations_time_axis(tmp_path):
    """0.5 s of no message on either topic in the middle of the contact: the import notes it and records it relative
    to the demonstration's first sample, as its segments are; the skill fails ``unmeasured_contact`` for it."""
    from skills.parameterize import learn_skill

    truth = _slide()
    middle = 0.5 * (truth.contact_on_s + truth.contact_off_s)
    keep = (truth.t < middle) | (truth.t > middle + 0.5)
    bag = write_bag(tmp_path / "gap", truth.t[keep], truth.positions[keep], truth.orientations[keep],
                    truth.wrenches[keep])  # fmt: skip
    demo = demonstration_from_bag(bag, BagImportOptions(**MEASURED, tool_frame="tool", tare=False))
    [[start, end]] = demo.metadata.unmeasured_intervals_s
    t_kept = truth.t[keep] - truth.t[1]  # the demonstration starts at the first pose, one wrench sample in
    last_pose_before = t_kept[1::POSE_EVERY][t_kept[1::POSE_EVERY] < middle - truth.t[1]][-1]
    assert start == pytest.approx(last_pose_before, abs=1e-6) and end > middle + 0.5 - truth.t[1]
    assert any(
        note.startswith("no measurement of the pose or the wrench") for note in demo.metadata.extra["import_notes"]
    )
    [check] = [c for c in learn_skill(demo).checks if c.name.value == "unmeasured_contact"]
    assert not check.passed and check.value == pytest.approx(end - start)


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture]
)
@given(
    storage=st.sampled_from(["mcap", "ros1"]),
    start_ns=st.integers(min_value=0, max_value=1_800_000_000 * 10**9),
    rows=st.integers(min_value=100, max_value=1500),
    rate=st.floats(min_value=50.0, max_value=1000.0),
    jitter=st.floats(min_value=0.0, max_value=0.3),
    seed=st.integers(min_value=0, max_value=2**16),
)
@example(storage="mcap", start_ns=1_899_000_000, rows=801, rate=1000.0, jitter=0.0, seed=0)  # issue 41's offset
@example(storage="ros1", start_ns=100_123_000_000, rows=201, rate=1000.0, jitter=0.0, seed=0)
def test_a_bag_imports_whatever_its_first_stamp_rows_rate_and_jitter(
    tmp_path_factory, storage: str, start_ns: int, rows: int, rate: float, jitter: float, seed: int
) -> None:
    """Property (issue 41, as the CSV's in tests/test_import.py): a ROS 1 or ROS 2 bag whose header stamps start
    anywhere from 0 to Unix-epoch nanoseconds, 100-1500 wrench messages at 50-1000 Hz with jitter up to 0.3 periods
    (poses at a quarter of that rate), imports with every sample finite, its time axis from 0 and never past the
    span the two topics share."""
    rng = np.random.default_rng(seed)
    truth = synthetic.plane_slide(seed=0)
    nominal = np.arange(rows) / rate
    nominal[1:-1] += rng.uniform(-jitter, jitter, rows - 2) / rate
    along = np.linspace(0.0, 1.0, rows)  # the slide's samples spread over the new clock: its path and its press
    source = np.linspace(0.0, 1.0, truth.t.size)
    index = np.minimum(np.searchsorted(source, along), truth.t.size - 1)
    bag = write_bag(
        tmp_path_factory.mktemp("bag") / "bag", nominal, truth.positions[index], truth.orientations[index],
        truth.wrenches[index], storage=storage, stamp_base_ns=start_ns, seed=seed,
    )  # fmt: skip
    demo = demonstration_from_bag(bag, BagImportOptions(**MEASURED, tool_frame="tool", tare=False))
    a = demo.arrays()
    assert np.all(np.isfinite(a.positions)) and np.all(np.isfinite(a.wrenches)) and np.all(np.isfinite(a.orientations))
    assert a.t[0] == 0.0 and np.all(np.diff(a.t) > 0)
    assert a.t[-1] <= nominal[-1] - nominal[0] + 1e-6 and a.t.size >= rows // 2


def test_the_kind_told_by_the_dispatcher_is_passed_on_not_read_again(tmp_path):
    """`services.importing` tells a file's kind once and the bag importer takes it: a bag told as one imports as the
    truth (the same samples as one whose kind the importer reads itself), and a kind told is the one the importer's
    message names, even where the content would say otherwise (it is not read again to tell)."""
    from services.demonstration_files import DemonstrationFile
    from services.importing import demonstration_file, demonstration_from_file

    truth = _slide()
    bag = _bag(tmp_path, truth, "slide", storage="mcap")
    kind = demonstration_file(bag)
    assert kind is DemonstrationFile.ros2_bag
    options = BagImportOptions(**MEASURED, tool_frame="tool", tare=False)
    told = demonstration_from_file(bag, options, kind)
    _assert_the_truth(told, truth)
    read = demonstration_from_bag(bag, options)
    np.testing.assert_array_equal(told.wrenches, read.wrenches)
    with pytest.raises(BagImportError, match=r"'slide' is a CSV recording, not a ROS bag"):
        demonstration_from_bag(bag, kind=DemonstrationFile.csv)
