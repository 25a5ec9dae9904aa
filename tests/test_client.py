"""The typed client (services/client.py) against the REAL stack: `contact-skills up` (embedded Zenoh router, the API,
two sim workers) on free loopback ports. record / upload (CSV, JSON, a ROS 2 bag) -> learn -> execute -> live
telemetry over Zenoh while it runs, pause (the API reports ``paused``) and resume -> wait -> telemetry as numpy
arrays equal to what was streamed; every error a typed exception carrying the API's message."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")

from rosbag_files import storage_file, write_bag  # noqa: E402
from test_service import RECORD, running_stack  # noqa: E402
from waiting import wait_for  # noqa: E402

from corpus.synthetic import plane_slide  # noqa: E402
from schemas import Demonstration  # noqa: E402
from schemas.execution import Verdict  # noqa: E402
from services.client import (  # noqa: E402
    Client,
    ConflictError,
    InvalidRequestError,
    NotFoundError,
    UnavailableError,
)
from services.csv_import import demonstration_csv_text  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("client"))


@pytest.fixture(scope="module")
def client(stack):
    with Client(stack.url) as c:
        yield c


def test_upload_every_kind_of_file_and_learn(client, tmp_path):
    truth = plane_slide(seed=1)
    demonstration = Demonstration.from_arrays(truth.t, truth.positions, truth.orientations, truth.wrenches)
    (tmp_path / "demo.json").write_text(demonstration.model_dump_json())
    (tmp_path / "demo.csv").write_text(demonstration_csv_text(demonstration))
    bag = write_bag(
        tmp_path / "bag", truth.t, truth.positions, truth.orientations, truth.wrenches, wrench_frame="world"
    )
    from_json = client.upload(tmp_path / "demo.json")
    from_csv = client.upload(tmp_path / "demo.csv", tare=False)
    from_bag = client.upload(bag, wrench="measured-on-tool", tare=False)  # the directory: its storage file is sent
    from_file = client.upload(storage_file(bag), wrench="measured-on-tool")
    ros1 = write_bag(tmp_path / "demo", truth.t, truth.positions, truth.orientations, truth.wrenches,
                     wrench_frame="world", storage="ros1")  # fmt: skip
    from_ros1 = client.upload(ros1, wrench="measured-on-tool", tare=False)  # a ROS 1 bag: to the bag route too
    assert from_json.summary.n_samples == from_csv.summary.n_samples == truth.t.size
    assert from_bag.source == f"bag:{storage_file(bag).name}" and from_bag.summary.n_samples == truth.t.size - 3
    assert from_bag.summary.max_force_n == pytest.approx(from_csv.summary.max_force_n, rel=0.02)
    assert from_ros1.source == "bag:demo.bag" and from_ros1.import_notes[0].startswith("ROS 1 bag: wrench")
    ros1_samples, ros2_samples = (client.demonstration(d.id).arrays() for d in (from_ros1, from_bag))
    np.testing.assert_allclose(ros1_samples.wrenches, truth.wrenches[1 : 1 + ros1_samples.t.size], atol=1e-9)
    np.testing.assert_array_equal(ros1_samples.positions, ros2_samples.positions)
    assert any("sensor offset" in note for note in from_file.import_notes)
    stored = client.demonstration(from_json.id)
    np.testing.assert_allclose(stored.arrays().positions, truth.positions)
    assert {d.id for d in client.demonstrations()} >= {from_json.id, from_csv.id, from_bag.id}
    skill = client.learn(from_bag.id, skill_type="auto")
    assert skill.demonstration_id == from_bag.id and skill.skill.skill_type.value == "slide"
    [contact] = [s for s in skill.skill.segments if s.kind.value == "contact"]
    assert contact.force_constant_n == pytest.approx(truth.target_force_n, rel=0.02)
    assert client.skill(skill.id).skill == skill.skill
    assert skill.id in {s.id for s in client.skills()}


def test_record_learn_execute_live_and_telemetry(client, stack):
    demo = client.record(RECORD["scenario"], seed=0, **RECORD["overrides"])
    assert demo.source == "teacher:slide_flat" and demo.extra["ground_truth"]["scenario"] == "slide_flat"
    skill = client.learn(demo.id)
    execution = client.execute(skill.id, unknown_offset=[0.0, 0.0, 0.01], pace="realtime")
    assert execution.created is not None and execution.created.telemetry_key.endswith(f"{execution.id}/telemetry")
    streamed, states = [], []
    for batch in execution.live(timeout_s=120):
        streamed.append(batch)
        if not states and batch.t[-1] > 2.0:  # pause: the API reports it, then resume
            execution.pause()
            states.append(wait_for(lambda: execution.status().status.value == "paused" and "paused", 10, "paused"))
            execution.resume()
            states.append(wait_for(lambda: execution.status().status.value == "running" and "running", 10, "resumed"))
    view = execution.wait(timeout_s=120)
    assert states == ["paused", "running"]
    assert view.status.value == "done" and view.metrics is not None and view.metrics.contact_ratio > 0.9
    # The verdict against the tolerances: the list's word and the checks behind it (1 cm moved: inside the window).
    assert view.verdict is Verdict.passed and view.metrics.verdict.verdict is Verdict.passed
    assert {c.name.value for c in view.metrics.verdict.checks} >= {"true_force_rms", "contact_ratio", "surface_found"}
    telemetry = execution.telemetry()
    assert len(telemetry) == view.metrics.steps == view.telemetry_samples
    assert telemetry.wrench_cf.shape == (len(telemetry), 6) and telemetry.phase.dtype.kind == "U"
    assert "contact" in set(telemetry.phase)
    # What streamed live is what was stored, sample for sample.
    live_t = np.concatenate([b.t for b in streamed])
    live_fz = np.concatenate([np.asarray(b.wrench_cf)[:, 2] for b in streamed])
    assert live_t.size > 0.8 * len(telemetry)
    rows = np.searchsorted(telemetry.t, live_t)
    np.testing.assert_array_equal(telemetry.t[rows], live_t)
    np.testing.assert_array_equal(telemetry.wrench_cf[rows, 2], live_fz)
    window = execution.telemetry(t0=1.0, t1=2.0, every=10)
    assert (
        window.t[0] >= 1.0
        and window.t[-1] <= 2.0
        and len(window) == int(((telemetry.t >= 1) & (telemetry.t <= 2)).sum() + 9) // 10
    )
    assert list(execution.live()) == []  # finished: nothing live any more
    watch = [sys.executable, "-m", "cli.main", "watch", execution.id, "--url", stack.url]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    watched = subprocess.run(watch, env=env, capture_output=True, text=True, timeout=60)
    assert watched.returncode == 0 and f"{execution.id} done" in watched.stdout and "force error RMS" in watched.stdout
    assert "verdict: pass" in watched.stdout
    with pytest.raises(ConflictError, match=f"execution {execution.id} has already finished"):
        execution.abort()


def test_errors_are_typed_and_carry_the_api_message(client, tmp_path):
    with pytest.raises(NotFoundError, match="404: no demonstration with id 'demo_000000000000'") as caught:
        client.learn("demo_000000000000")
    assert caught.value.status == 404
    with pytest.raises(InvalidRequestError) as caught:
        client.execute("skill_x", controller="pid")
    assert any(loc == "body.controller" for loc, _ in caught.value.problems)
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,y,z\n0,1,2,3\n")
    with pytest.raises(InvalidRequestError, match="missing column for qx") as caught:
        client.upload(bad)
    assert caught.value.problems[0][0] == "body.file"
    with pytest.raises(NotFoundError, match="no execution with id"):
        client.execution("exec_000000000000").wait()
    with Client("http://127.0.0.1:9") as nobody, pytest.raises(UnavailableError, match="does not answer"):
        nobody.health()


def _readme_block(language: str, marker: str) -> str:
    import re

    readme = (REPO / "README.md").read_text()
    [block] = [b for b in re.findall(rf"^```{language}\n(.*?)^```", readme, flags=re.M | re.S) if marker in b]
    return block


def test_the_readme_client_example_runs(stack, tmp_path, monkeypatch):
    """The README's Python client block, run as written against the stack (its URL substituted)."""
    monkeypatch.chdir(tmp_path)
    block = _readme_block("python", "from services.client import Client")
    namespace: dict = {}
    exec(compile(block.replace("http://127.0.0.1:8000", stack.url), "README", "exec"), namespace)
    assert namespace["view"].status.value == "done"
    assert (tmp_path / "scratch" / "run.mcap").stat().st_size > 100_000


def test_the_readme_curl_flow_runs(stack, tmp_path):
    """The README's curl + jq block, run by bash against the stack: ids travel in shell variables."""
    block = _readme_block("bash", "jq -r .id").replace("localhost:8000", f"127.0.0.1:{stack.port}")
    truth = plane_slide(seed=2)
    bag = write_bag(
        tmp_path / "bag", truth.t, truth.positions, truth.orientations, truth.wrenches, wrench_frame="world"
    )
    storage_file(bag).rename(tmp_path / "demo.mcap")
    (tmp_path / ".venv").symlink_to(REPO / ".venv", target_is_directory=True)
    env = {**os.environ, "CONTACT_SKILLS_ZENOH_ENDPOINTS": stack.endpoint, "PYTHONPATH": str(REPO)}
    script = "set -euo pipefail\n" + block + '\necho "ids $DEMO $SKILL $EXEC"\n'
    result = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    ids = result.stdout.strip().splitlines()[-1].split()[1:]
    assert [i.split("_")[0] for i in ids] == ["demo", "skill", "exec"]
    assert '"status": "done"' in result.stdout
    assert (tmp_path / "run.mcap").stat().st_size > 100_000
    assert (tmp_path / "window.csv").read_text().splitlines()[0].startswith("t,phase,segment_index")
    assert "ROS 2 bag: wrench /ft_sensor/wrench" in result.stdout


def test_a_skill_no_placement_reaches_runs_one_stroke_at_a_time_on_the_service(client, tmp_path):
    """Two strokes on tables 1.2 m apart (the tool lifted 40 cm between them): no placement reaches both. Through the
    service the worker runs them one after the other, each placed on its own on the piece measured from the stored
    recording: one execution, its telemetry continuous in time and segment numbers, its metrics combining both
    strokes' (each kept) and its verdict theirs."""
    from corpus.families import two_tables_case

    demo = two_tables_case().demonstration()
    (tmp_path / "two_tables.json").write_text(demo.model_dump_json())
    skill = client.learn(client.upload(tmp_path / "two_tables.json").id)
    view = client.execute(skill.id).wait(timeout_s=180)
    m = view.metrics
    assert view.status.value == "done" and m is not None and m.strokes is not None and len(m.strokes) == 2, view
    assert m.work_piece == "measured" and all(s.work_piece == "measured" for s in m.strokes)
    assert view.verdict is Verdict.passed and all(s.verdict.verdict is Verdict.passed for s in m.strokes)
    assert m.steps == sum(s.steps for s in m.strokes)
    assert m.true_force_rms_error_pct == pytest.approx(
        np.sqrt(sum(s.steady_contact_s * s.true_force_rms_error_pct**2 for s in m.strokes) / m.steady_contact_s)
    )
    assert max(s.true_force_rms_error_pct for s in m.strokes) < 3.0
    telemetry = client.execution(view.id).telemetry()
    assert len(telemetry) == m.steps and np.all(np.diff(telemetry.t) > 0)  # one run in time, no restart
    contact_segments = sorted(set(telemetry.segment_index[telemetry.phase == "contact"].tolist()))
    assert contact_segments == [0, 1]  # the second stroke's segment numbered after the first's
