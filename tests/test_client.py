"""The typed client (services/client.py) against the REAL stack: `contact-skills up` (embedded Zenoh router, the API,
two sim workers) on free loopback ports. record / upload (CSV, JSON, ROS 1 and ROS 2 bags, told by their content)
-> learn -> execute -> live telemetry over Zenoh while it runs, pause (the API reports ``paused``) and resume -> wait
-> telemetry as numpy arrays equal to what was streamed; a finished run replayed from its start at the clock's pace;
sweeps; every error a typed exception carrying the API's message. The README's service flows (curl, the client, the
Zenoh snippet) run here as written, finding the stack by ``CONTACT_SKILLS_URL`` alone."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")

from docs_commands import PAGES, Check, python_blocks, steps  # noqa: E402
from rosbag_files import storage_file, write_bag  # noqa: E402
from test_service import RECORD, running_stack  # noqa: E402
from waiting import wait_for  # noqa: E402

from corpus.synthetic import plane_slide  # noqa: E402
from schemas import Demonstration  # noqa: E402
from schemas.execution import ControllerKind, ExecutionPhase, Pace  # noqa: E402
from schemas.sweep import ParameterRange, SweepParameter, SweepState  # noqa: E402
from schemas.verdict import Verdict  # noqa: E402
from services.client import (  # noqa: E402
    Client,
    ConflictError,
    InvalidRequestError,
    NotFoundError,
    Telemetry,
    UnavailableError,
)
from services.csv_import import demonstration_csv_text  # noqa: E402
from services.quiet_imports import PYBULLET_BANNER  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHORT_RECORD = {"seed": 0, **RECORD["overrides"]}
"""A slide with a 2 s stroke: an execution of about 5 s simulated."""


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("client"))


@pytest.fixture(scope="module")
def client(stack):
    with Client(stack.url) as c:
        yield c


@pytest.fixture(scope="module")
def short_skill(client):
    """A learned slide of a short recording."""
    return client.learn(client.record(RECORD["scenario"], **SHORT_RECORD).id)


def _env(stack) -> dict[str, str]:
    """A process environment that names the stack by ``CONTACT_SKILLS_URL`` only (no Zenoh endpoint)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CONTACT_SKILLS_")}
    return {**env, "CONTACT_SKILLS_URL": stack.url, "PYTHONPATH": str(REPO)}


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
    # By content, not by name: a ROS 1 bag named .csv goes to the bag route, a JSON file named .txt to the JSON one.
    misnamed_bag, misnamed_json = ros1.rename(tmp_path / "ros1.csv"), tmp_path / "demo.txt"
    misnamed_json.write_text(demonstration.model_dump_json())
    from_misnamed_bag = client.upload(misnamed_bag, wrench="measured-on-tool", tare=False)
    from_misnamed_json = client.upload(misnamed_json)
    assert from_misnamed_bag.source == "bag:ros1.csv"
    assert from_misnamed_bag.summary.n_samples == from_ros1.summary.n_samples
    assert from_misnamed_bag.summary.max_force_n == from_ros1.summary.max_force_n
    assert from_misnamed_json.summary.n_samples == from_json.summary.n_samples
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
    joint = client.learn([from_json.id, from_csv.id])  # a list of ids: learned together into one skill
    assert [use.source for use in joint.skill.demonstrations or []] == [from_json.id, from_csv.id]
    assert joint.demonstration_id in (from_json.id, from_csv.id)


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
    assert telemetry.wrench_cf.shape == (len(telemetry), 6) and telemetry.segment_index.dtype.kind == "i"
    assert {type(p) for p in telemetry.phase} == {ExecutionPhase} and ExecutionPhase.contact in set(telemetry.phase)
    # What streamed live is what was stored, sample for sample.
    live = Telemetry.of_batches(streamed)  # the same types as the stored telemetry: compared as they are
    assert len(live) > 0.8 * len(telemetry)
    rows = np.searchsorted(telemetry.t, live.t)
    np.testing.assert_array_equal(telemetry.t[rows], live.t)
    np.testing.assert_array_equal(telemetry.wrench_cf[rows], live.wrench_cf)
    np.testing.assert_array_equal(telemetry.phase[rows], live.phase)
    window = execution.telemetry(t0=1.0, t1=2.0, every=10)
    assert (
        window.t[0] >= 1.0
        and window.t[-1] <= 2.0
        and len(window) == int(((telemetry.t >= 1) & (telemetry.t <= 2)).sum() + 9) // 10
    )
    assert list(execution.live()) == []  # finished: nothing live any more
    watch = [sys.executable, "-m", "cli.main", "watch", execution.id]  # the stack named by CONTACT_SKILLS_URL
    watched = subprocess.run(watch, env=_env(stack), capture_output=True, text=True, timeout=60)
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


def test_the_readme_client_example_runs(stack, tmp_path, monkeypatch, capfd):
    """The README's Python client block, run as written, the stack named by ``CONTACT_SKILLS_URL`` alone: the fast
    run replayed from its start at the clock's pace (one line per simulated second), its sweep finished, and no
    library banner printed."""
    monkeypatch.chdir(tmp_path)
    for name in [k for k in os.environ if k.startswith("CONTACT_SKILLS_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("CONTACT_SKILLS_URL", stack.url)
    [block, _] = python_blocks("README.md")
    namespace: dict = {}
    started = time.monotonic()
    exec(compile(block, "README", "exec"), namespace)
    view, telemetry = namespace["view"], namespace["telemetry"]
    assert view.status.value == "done" and view.verdict is Verdict.passed
    assert time.monotonic() - started > telemetry.t[-1]  # the replay took at least the run's simulated time
    printed = capfd.readouterr()
    assert PYBULLET_BANNER not in printed.out + printed.err  # the MCAP export's PyBullet, imported without its banner
    seconds = [line for line in printed.out.splitlines() if line.startswith("t=")]
    assert len(seconds) == int(telemetry.t[-1]) + 1, seconds  # t = 0 included
    assert (tmp_path / "scratch" / "run.mcap").stat().st_size > 100_000
    assert PYBULLET_BANNER not in stack.log_path.read_text()  # nor in the output of `up` (its API and workers)
    with Client(stack.url) as client:  # the block's own client is closed
        assert client.sweep(namespace["sweep"].id).status().status is SweepState.done


def _bash(script: str, stack, cwd: Path) -> subprocess.CompletedProcess:
    """``script`` run by bash (``-euo pipefail``) in ``cwd``, the stack named by ``CONTACT_SKILLS_URL`` alone."""
    if not (cwd / ".venv").exists():
        (cwd / ".venv").symlink_to(REPO / ".venv", target_is_directory=True)
    return subprocess.run(["bash", "-c", "set -euo pipefail\n" + script], cwd=cwd, env=_env(stack),
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def test_the_readme_curl_flow_runs_as_written(stack, tmp_path):
    """The README's curl + jq block run by bash as written, the stack named by ``CONTACT_SKILLS_URL`` alone
    (``watch`` finds the Zenoh router from ``/health``): ids travel in shell variables, the realtime run is watched to
    its end, the run and the skill are exported as MCAP, the recording too and imported back as a bag; ``export``
    finds the stack the same way.
    A curl block of a docs page runs after it, as written."""
    [flow] = [step.command for step in steps(("README.md",))[0] if step.check is Check.service]
    result = _bash(flow + '\necho "ids $DEMO $SKILL $EXEC"\n', stack, tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    ids = result.stdout.strip().splitlines()[-1].split()[1:]
    assert [i.split("_")[0] for i in ids] == ["demo", "skill", "exec"]
    assert f"{ids[2]} done" in result.stdout and '"status": "done"' in result.stdout  # watch, then the view
    assert (tmp_path / "run.mcap").stat().st_size > 100_000
    assert (tmp_path / "skill.mcap").stat().st_size > 100_000  # the robot and the learned frames (test_foxglove.py)
    assert (tmp_path / "window.csv").read_text().splitlines()[0].startswith("t,phase,segment_index")
    assert "ROS 2 bag: wrench /wrench/world" in result.stdout  # demo.mcap imported back
    export = [sys.executable, "-m", "cli.main", "export", ids[0], "-o", "demo.csv"]
    exported = subprocess.run(export, cwd=tmp_path, env=_env(stack), capture_output=True, text=True, timeout=60)
    assert exported.returncode == 0 and f"from {stack.url}" in exported.stdout, exported.stderr
    for other in [step for step in steps(PAGES)[0] if step.check is Check.service and step.page != "README.md"]:
        result = _bash(flow + "\n" + other.command, stack, tmp_path)  # a docs page's flow may use the README's ids
        assert result.returncode == 0, f"{other.page}:\n{other.command}\n{result.stdout}{result.stderr}"


def test_the_readme_zenoh_snippet_prints_a_run(stack, short_skill, tmp_path):
    """The README's Zenoh snippet, run as written in its own process: it asks the API (``CONTACT_SKILLS_URL``) for
    the endpoint, then prints the telemetry and the statuses of the next run until it ends."""
    [_, snippet] = python_blocks("README.md")
    (tmp_path / "snippet.py").write_text(snippet)
    process = subprocess.Popen([sys.executable, "snippet.py"], cwd=tmp_path, env=_env(stack), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        time.sleep(2.0)  # its session and subscriptions
        with Client(stack.url) as client:
            view = client.execute(short_skill.id).wait(timeout_s=120)
        out, err = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert f"status: {view.id} done" in out and f"{view.id} t=" in out and "Fz=" in out


def test_live_replays_a_fast_run_from_its_start_at_the_pace_of_the_clock(client, stack, short_skill):
    """A run at the default fast pace is over long before its simulated time; ``live(pace=realtime, from_start=True)``
    started at once yields every sample from sample 0, once and in order (the stored part first, then the live
    one), exactly the stored telemetry, and takes at least the run's simulated time. Replayed again after its end, at
    the fast pace: the same samples, at once; ``contact-skills watch --from-start`` counts every one of them."""
    execution = client.execute(short_skill.id, controller=ControllerKind.hybrid_cf, pace=Pace.fast)
    started = time.monotonic()
    replayed = Telemetry.of_batches(list(execution.live(pace=Pace.realtime, from_start=True, timeout_s=120)))
    paced_s = time.monotonic() - started
    stored = execution.telemetry()
    assert len(replayed) == len(stored) == execution.wait().metrics.steps
    for name in Telemetry.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(replayed, name), getattr(stored, name), err_msg=name)
    assert paced_s >= stored.t[-1] - stored.t[0]
    started = time.monotonic()
    again = Telemetry.of_batches(list(execution.live(from_start=True)))
    assert time.monotonic() - started < 0.5 * paced_s  # unpaced: faster than the paced replay just measured
    np.testing.assert_array_equal(again.t, stored.t)
    watch = [sys.executable, "-m", "cli.main", "watch", execution.id, "--from-start"]  # the same from the CLI
    watched = subprocess.run(watch, env=_env(stack), capture_output=True, text=True, timeout=60)
    assert watched.returncode == 0, watched.stdout + watched.stderr
    assert f"| {len(stored)} samples" in watched.stdout and "verdict: pass" in watched.stdout


def test_a_sweep_through_the_client(client, short_skill):
    """``run_sweep`` with enums for its closed sets: 3 trials x 2 controllers, all finished, each trial's execution
    within the range asked for; the list and the handle agree."""
    sweep = client.run_sweep(
        short_skill.id,
        controllers=[ControllerKind.hybrid_cf, ControllerKind.hybrid_world_z],
        vary={SweepParameter.offset_z_m: ParameterRange(low=-0.01, high=0.01)},
        trials=3,
    )
    view = sweep.wait(timeout_s=300)
    assert view.status is SweepState.done and view.counts.finished == view.counts.total == 6
    trials = sweep.trials()
    assert len(trials) == 6
    assert {t.controller for t in trials} == {ControllerKind.hybrid_cf, ControllerKind.hybrid_world_z}
    assert all(-0.01 <= t.parameters[SweepParameter.offset_z_m] <= 0.01 for t in trials)
    assert sweep.id in {s.id for s in client.sweeps()}


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
    # where each stroke pressed is kept in the combined metrics, one contact segment per stroke
    assert [s.segment for s in m.surfaces_pressed] == [p.segment for s in m.strokes for p in s.surfaces_pressed]
    assert len(m.surfaces_pressed) == 2
    telemetry = client.execution(view.id).telemetry()
    assert len(telemetry) == m.steps and np.all(np.diff(telemetry.t) > 0)  # one run in time, no restart
    contact_segments = sorted(set(telemetry.segment_index[telemetry.phase == "contact"].tolist()))
    assert contact_segments == [0, 1]  # the second stroke's segment numbered after the first's
