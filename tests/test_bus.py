"""The Zenoh bus with REAL processes: a router and sim workers started as `contact-skills` subprocesses on
127.0.0.1 (a free port per module), the API-side ``BusClient`` and independent Zenoh subscribers in this process.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")

from schemas import ExecutionRequest, LearnOptions, RecordRequest  # noqa: E402
from schemas.bus import ExecutionStatus, KeyExpressions, StartExecution, StartReply, session_config  # noqa: E402
from schemas.demonstration import Demonstration  # noqa: E402
from schemas.execution import ControllerGains, Engine, ExecutionPhase, TelemetryBatch  # noqa: E402
from services.bus import BusClient, BusRequestError, BusSettings, NoWorkerAvailable  # noqa: E402
from services.local_processes import free_port as _free_port  # noqa: E402
from services.local_processes import spawn_cli, wait_for_port  # noqa: E402
from services.local_processes import stop_process as _stop  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DT = 1e-3
WAIT_S = 30.0

README_SNIPPET = """
import json, threading, zenoh

config = zenoh.Config.from_json5(
    '{mode: "client", connect: {endpoints: ["ENDPOINT"]}, scouting: {multicast: {enabled: false}}}')
finished = threading.Event()
def on_telemetry(sample):
    b = json.loads(sample.payload.to_bytes())
    print(f"{b['execution_id']} t={b['t'][-1]:.3f} s {b['phase'][-1]} Fz={b['wrench_cf'][-1][2]:.2f} N")
def on_status(sample):
    s = json.loads(sample.payload.to_bytes())
    print("status:", s["execution_id"], s["phase"], s["message"])
    if s["phase"] in ("done", "aborted", "failed"): finished.set()
with zenoh.open(config) as session:
    session.declare_subscriber("cskills/exec/*/telemetry", on_telemetry)
    session.declare_subscriber("cskills/exec/*/status", on_status)
    finished.wait()
"""
"""The README's "watch from any Python process" snippet, run as is (endpoint substituted)."""


# ---------------------------------------------------------------------------------------------------------------
# Processes
# ---------------------------------------------------------------------------------------------------------------


def _wait(predicate, timeout: float = WAIT_S, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise TimeoutError(f"timed out waiting for {what}")


class Recorder:
    """BusClient callbacks that keep everything, per execution (thread-safe)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.statuses: dict[str, list[ExecutionStatus]] = defaultdict(list)
        self.telemetry: dict[str, list[TelemetryBatch]] = defaultdict(list)
        self.lost: list[tuple[str, float]] = []

    def on_status(self, status: ExecutionStatus) -> None:
        with self.lock:
            self.statuses[status.execution_id].append(status)

    def on_telemetry(self, batch: TelemetryBatch) -> None:
        with self.lock:
            self.telemetry[batch.execution_id].append(batch)

    def on_worker_lost(self, worker_id: str) -> None:
        with self.lock:
            self.lost.append((worker_id, time.monotonic()))

    def final(self, execution_id: str, timeout: float = WAIT_S) -> ExecutionStatus:
        def done():
            with self.lock:
                finals = [s for s in self.statuses[execution_id] if s.final]
            return finals[0] if finals else None

        return _wait(done, timeout, f"the end of {execution_id}")

    def samples(self, execution_id: str) -> int:
        with self.lock:
            return sum(len(b.t) for b in self.telemetry[execution_id])


class Subscriber:
    """An independent Zenoh session subscribed to one execution's telemetry (not the BusClient's)."""

    def __init__(self, endpoint: str, execution_id: str, prefix: str = "cskills") -> None:
        config = zenoh.Config.from_json5(json.dumps(session_config("client", connect=[endpoint])))
        self.session = zenoh.open(config)
        self.batches: list[TelemetryBatch] = []
        self.received_unix_s: list[float] = []
        key = KeyExpressions(prefix).telemetry(execution_id)
        self.subscriber = self.session.declare_subscriber(key, self._on)

    def _on(self, sample) -> None:
        now = time.time()
        self.batches.append(TelemetryBatch.model_validate_json(sample.payload.to_bytes()))
        self.received_unix_s.append(now)

    def t(self) -> np.ndarray:
        return np.concatenate([b.t for b in self.batches]) if self.batches else np.zeros(0)

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()


@pytest.fixture(scope="module")
def bus(tmp_path_factory):
    """A router and two workers (w-a, w-b) as subprocesses; yields (endpoint, log directory)."""
    logs = tmp_path_factory.mktemp("bus")
    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    processes = [spawn_cli(["router", "--listen", endpoint], logs / "router.log", cwd=REPO)]
    try:
        wait_for_port(port, WAIT_S)
        for name in ("w-a", "w-b"):
            processes.append(spawn_cli(["worker", "--connect", endpoint, "--id", name], logs / f"{name}.log", cwd=REPO))
        yield endpoint, logs
    finally:
        for process in reversed(processes):
            _stop(process)


@pytest.fixture(scope="module")
def client(bus):
    endpoint, _ = bus
    recorder = Recorder()
    bus_client = BusClient(
        BusSettings(endpoints=[endpoint]), recorder.on_status, recorder.on_telemetry, recorder.on_worker_lost
    )
    bus_client.recorder = recorder  # type: ignore[attr-defined]
    try:
        _wait(lambda: len(bus_client.workers()) == 2, what="two workers")
        yield bus_client
    finally:
        bus_client.close()


@pytest.fixture(scope="module")
def recorded(client):
    """A short slide_flat demonstration recorded BY A WORKER over the bus."""
    return client.record_demonstration(RecordRequest(scenario="slide_flat", seed=0, overrides={"move_duration_s": 1.0}))


@pytest.fixture(scope="module")
def skill(recorded):
    from skills.parameterize import learn_skill

    return learn_skill(recorded.demonstration, LearnOptions(skill_type="slide", min_segment_duration_s=0.5))


def _request(skill, **settings) -> ExecutionRequest:
    return ExecutionRequest(skill=skill, **{"scenario": "slide_flat", "pace": "fast", **settings})


# ---------------------------------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------------------------------


def test_workers_connect_and_are_listed(client):
    workers = client.workers()
    assert [w.worker_id for w in workers] == ["w-a", "w-b"]
    assert all(w.pid > 0 and w.activity in ("idle", "recording") for w in workers), workers


def test_record_demonstration_returns_a_valid_demonstration(client, recorded):
    reply = recorded
    assert reply.ok, reply.error
    demo = Demonstration.model_validate_json(reply.demonstration.model_dump_json())
    assert demo.metadata.source == "teacher:slide_flat"
    assert np.allclose(np.diff(demo.t), 1e-3)
    assert reply.ground_truth["scenario"] == "slide_flat" and reply.ground_truth["target_force_n"] == 15.0
    assert reply.worker_id in ("w-a", "w-b")
    bad = client.record_demonstration(RecordRequest(scenario="no_such_scenario"))
    assert bad.code == "error" and "unknown scenario" in bad.error


def test_execution_streams_every_sample_and_ends_done_with_metrics(bus, client, skill, tmp_path):
    endpoint, _ = bus
    recorder = client.recorder
    independent = Subscriber(endpoint, "ex-stream")
    snippet = tmp_path / "snippet.py"
    snippet.write_text(README_SNIPPET.replace("ENDPOINT", endpoint))
    readme = subprocess.Popen([sys.executable, str(snippet)], stdout=subprocess.PIPE, text=True)
    nobody = f"http://127.0.0.1:{_free_port()}"  # no API there (whatever serves :8000 on a shared machine)
    watch = spawn_cli(
        ["watch", "ex-stream", "--connect", endpoint, "--timeout", "60", "--url", nobody],
        tmp_path / "watch.log",
        cwd=REPO,
    )
    try:
        time.sleep(1.0)  # the snippet's and the watch's subscriptions (both also catch up on the final status)
        worker_id = client.start_execution("ex-stream", _request(skill))
        final = recorder.final("ex-stream")
        assert final.phase is ExecutionPhase.done and final.worker_id == worker_id
        assert final.metrics is not None and final.metrics.force_rms_error_n is not None
        steps = final.metrics.steps
        _wait(lambda: len(independent.t()) >= steps, 10, "every sample at the independent subscriber")
        t = independent.t()
        assert len(t) == steps and t[0] == 0.0
        np.testing.assert_allclose(np.diff(t), DT, atol=1e-9)  # every control step, in order, none twice
        # The BusClient gets them all too (the final status travels on another key and may arrive first).
        _wait(lambda: recorder.samples("ex-stream") >= steps, 10, "every sample at the BusClient")
        assert recorder.samples("ex-stream") == steps
        phases = [s.phase for s in recorder.statuses["ex-stream"]]
        assert phases[0] is ExecutionPhase.pending
        for phase in (ExecutionPhase.settle, ExecutionPhase.free, ExecutionPhase.approach, ExecutionPhase.contact):
            assert phase in phases
        seqs = [s.seq for s in recorder.statuses["ex-stream"]]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        assert watch.wait(30) == 0
        watched = (tmp_path / "watch.log").read_text()
        assert "done" in watched and "force error RMS" in watched
        out, _ = readme.communicate(timeout=30)
        assert readme.returncode == 0 and "status: ex-stream done" in out and "Fz=" in out
    finally:
        independent.close()
        for process in (readme, watch):
            if process.poll() is None:
                process.kill()
                process.wait()


def test_a_worker_runs_the_execution_on_the_engine_it_is_asked_for(client, skill):
    """``engine`` travels with the request to the worker, which runs the skill on MuJoCo: done, the metrics name the
    engine and its truth, every step streamed."""
    recorder = client.recorder
    client.start_execution("ex-mujoco", _request(skill, engine="mujoco"))
    final = recorder.final("ex-mujoco")
    assert final.phase is ExecutionPhase.done, final.metrics
    assert final.metrics.engine is Engine.mujoco and final.metrics.true_force_rms_error_pct is not None
    # MuJoCo's contact held over the contact phase (this fast 1 s stroke: 99.8 %, 15 steps off at a bounce; PyBullet
    # 100 %; docs/ENGINES.md, what is left)
    assert final.metrics.contact_ratio >= 0.99
    _wait(lambda: recorder.samples("ex-mujoco") >= final.metrics.steps, 10, "every sample at the BusClient")
    assert recorder.samples("ex-mujoco") == final.metrics.steps


def test_abort_stops_within_one_control_step(bus, client, skill):
    endpoint, _ = bus
    recorder = client.recorder
    independent = Subscriber(endpoint, "ex-abort")
    try:
        # Real-time pace: the abort is sent while the execution is where its telemetry says (at pace fast
        # the simulation runs ~8x ahead of the subscribers, so it would be sent "late").
        client.start_execution("ex-abort", _request(skill, pace="realtime"))
        _wait(lambda: recorder.samples("ex-abort") >= 500, what="telemetry")
        client.send_command("ex-abort", "abort")
        final = recorder.final("ex-abort")
        assert final.phase is ExecutionPhase.aborted and final.error == "aborted on request"
        assert final.metrics is not None and final.metrics.phase is ExecutionPhase.aborted
        _wait(lambda: len(independent.t()) == final.metrics.steps, 10, "the last samples")
        last_t = independent.t()[-1]
        assert final.abort_received_t is not None
        assert 0.0 <= last_t - final.abort_received_t <= DT + 1e-9, (last_t, final.abort_received_t)
        assert last_t < 5.0  # stopped long before the end (~7.5 s)
    finally:
        independent.close()


def test_pause_holds_the_reference_and_resume_continues(client, skill):
    recorder = client.recorder
    client.start_execution("ex-pause", _request(skill, pace="realtime"))  # commands act where telemetry says

    def moving():  # in the free segment, where the reference moves every step
        with recorder.lock:
            return any(ExecutionPhase.free in b.phase for b in recorder.telemetry["ex-pause"])

    _wait(moving, what="the free segment")
    client.send_command("ex-pause", "pause")
    paused = _wait(lambda: [s for s in recorder.statuses["ex-pause"] if s.paused], what="paused")[0]

    def held_steps() -> int:  # control steps run since the pause (the loop keeps running, at about real time)
        with recorder.lock:
            return sum(int(np.sum(np.asarray(b.t) > paused.t + 0.06)) for b in recorder.telemetry["ex-pause"])

    _wait(lambda: held_steps() > 200, what="the loop running while paused")
    client.send_command("ex-pause", "resume")
    resumed = _wait(lambda: [s for s in recorder.statuses["ex-pause"] if s.message == "resumed"], what="resumed")[0]

    def last_t() -> float:
        with recorder.lock:
            return recorder.telemetry["ex-pause"][-1].t[-1]

    _wait(lambda: last_t() > resumed.t + 0.3, what="running on after resume")
    client.send_command("ex-pause", "abort")
    final = recorder.final("ex-pause")
    assert final.phase is ExecutionPhase.aborted
    with recorder.lock:
        batches = list(recorder.telemetry["ex-pause"])
    t = np.concatenate([b.t for b in batches])
    ref = np.concatenate([b.reference_position for b in batches])
    held = (t > paused.t + 0.06) & (t < resumed.t - 0.01)  # status times are batch ends: keep a margin
    assert held.sum() > 100  # the loop kept running while paused
    assert np.ptp(ref[held], axis=0).max() < 1e-12  # ... holding one reference
    after = t > resumed.t + 0.06
    assert after.any() and np.ptp(ref[after], axis=0).max() > 1e-5  # and it moves again


def test_a_forgotten_pause_times_out_and_frees_the_worker(client, skill):
    recorder = client.recorder
    worker = client.start_execution("ex-pause-timeout", _request(skill, pace="realtime", pause_timeout_s=0.5))
    _wait(lambda: recorder.samples("ex-pause-timeout") >= 200, what="telemetry")
    client.send_command("ex-pause-timeout", "pause")
    paused = _wait(lambda: [s for s in recorder.statuses["ex-pause-timeout"] if s.paused], what="paused")[0]
    final = recorder.final("ex-pause-timeout")
    assert final.phase is ExecutionPhase.aborted
    assert final.error is not None and "longer than pause_timeout_s (0.5 s)" in final.error
    assert final.t - paused.t < 2.0  # the simulation held for the pause (0.5 s) and then stopped
    _wait(lambda: not next(w for w in client.workers() if w.worker_id == worker).busy, 10, "the worker free again")


def test_two_workers_run_two_executions_at_once(client, skill):
    recorder = client.recorder
    # Real-time pace: both must still run when the aborts arrive (at pace fast an 8.5 s skill ends in ~0.3 s, a race
    # against the 200 streamed samples below).
    first = client.start_execution("ex-two-1", _request(skill, pace="realtime"))
    second = client.start_execution("ex-two-2", _request(skill, pace="realtime"))
    assert {first, second} == {"w-a", "w-b"}
    busy = client.workers()
    assert all(w.busy for w in busy) and {w.execution_id for w in busy} == {"ex-two-1", "ex-two-2"}
    with pytest.raises(NoWorkerAvailable, match=r"2 worker\(s\) connected, none free"):
        client.start_execution("ex-two-3", _request(skill, pace="realtime"))
    _wait(lambda: recorder.samples("ex-two-1") > 200 and recorder.samples("ex-two-2") > 200, what="both streaming")
    for execution_id in ("ex-two-1", "ex-two-2"):
        client.send_command(execution_id, "abort")
    for execution_id in ("ex-two-1", "ex-two-2"):
        assert recorder.final(execution_id).phase is ExecutionPhase.aborted
    _wait(lambda: not any(w.busy for w in client.workers()), 10, "both workers free again")


def test_a_worker_keeps_the_demonstration_it_was_sent_for_the_starts_that_name_it(bus, client, recorded, skill):
    """The ~2 MB demonstration travels once per worker, not once per start: a start naming a demonstration the
    worker does not keep is answered need_demonstration (and BusClient.start_execution then sends it); one naming a
    demonstration it keeps runs on its copy: the path metric (against the demonstration) equals that of the run
    that brought it, and differs from a run without one (against the nominal DMP path)."""
    from schemas.bus import StartExecution, StartReply

    endpoint, _ = bus
    recorder, keys, demonstration = client.recorder, KeyExpressions("cskills"), recorded.demonstration
    _wait(lambda: not any(w.busy for w in client.workers()), 30, "both workers free")
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(session_config("client", connect=[endpoint]))))

    def start_naming(worker_id: str, execution_id: str) -> StartReply:
        start = StartExecution(
            execution_id=execution_id, request=_request(skill), demonstration_id="demo_kept", attempt="a1"
        )
        client.adopt(execution_id, worker_id, "a1")  # its reports verify with the secret the client would have sent
        secret = client.reports.execution_secret(execution_id, worker_id, "a1")
        [reply] = session.get(keys.start(worker_id), payload=start.model_dump_json(), timeout=WAIT_S, attachment=secret)
        return StartReply.model_validate_json(reply.ok.payload.to_bytes())

    try:
        for worker_id in ("w-a", "w-b"):
            unknown = start_naming(worker_id, "ex-demo-unknown")
            assert (unknown.accepted, unknown.code) == (False, "need_demonstration"), unknown
        worker = client.start_execution(
            "ex-demo-sent", _request(skill), demonstration=demonstration, demonstration_id="demo_kept"
        )
        sent = recorder.final("ex-demo-sent").metrics
        _wait(lambda: not any(w.busy for w in client.workers()), 30, "the worker free again")
        assert start_naming(worker, "ex-demo-kept").accepted
        kept = recorder.final("ex-demo-kept").metrics
    finally:
        session.close()
    client.start_execution("ex-demo-none", _request(skill))
    without = recorder.final("ex-demo-none").metrics
    assert sent.phase is kept.phase is without.phase is ExecutionPhase.done
    assert kept.path_rms_m == sent.path_rms_m and without.path_rms_m != sent.path_rms_m
    assert kept.steps == sent.steps and kept.true_force_rms_error_n == sent.true_force_rms_error_n


def test_the_demonstrations_a_worker_keeps_are_bounded_by_their_samples(recorded, skill):
    """A worker keeps the demonstrations starts sent within DEMONSTRATION_SAMPLES_KEPT samples in all (the least
    recently named goes first; the newest stays whatever its size), not only within a count: a minute at 1 kHz is
    ~38 MB of validated lists."""
    from schemas.bus import StartExecution
    from sim_worker.worker_keeping import DEMONSTRATIONS_CACHED, KeptDemonstrations
    from sim_worker.zenoh_worker import Worker

    assert isinstance(Worker(worker_id="w-bounded").demonstrations, KeptDemonstrations)  # what a worker keeps them in
    demonstration = recorded.demonstration
    samples = len(demonstration.t)
    keeping = KeptDemonstrations(DEMONSTRATIONS_CACHED, 2 * samples)

    def start(key: str, sent: bool) -> StartExecution | None:
        return keeping.completed(StartExecution(
            execution_id=f"ex-{key}", request=_request(skill), demonstration_id=key,
            demonstration=demonstration if sent else None))  # fmt: skip

    for key in ("d1", "d2"):
        assert start(key, sent=True).demonstration == demonstration
    assert start("d1", sent=False).demonstration == demonstration  # kept: d1 is now the most recently named
    start("d3", sent=True)  # a third would exceed 2 x samples: d2, the least recently named, goes
    assert list(keeping.kept) == ["d1", "d3"]
    assert start("d2", sent=False) is None
    keeping.samples = samples // 2
    start("d4", sent=True)  # larger than the bound on its own: kept alone
    assert list(keeping.kept) == ["d4"]


def test_bad_requests_are_refused(client, skill):
    with pytest.raises(BusRequestError, match="unknown scenario"):
        client.start_execution("ex-bad", _request(skill, scenario="no_such_world"))
    with pytest.raises(BusRequestError, match=r"gains\.gain_schedule: from_spread needs the spread"):
        client.start_execution("ex-bad", _request(skill, gains=ControllerGains(gain_schedule="from_spread")))
    with pytest.raises(ValueError, match="inline"):
        client.start_execution("ex-bad", ExecutionRequest(skill_id="sk_1"))
    with pytest.raises(ValueError, match="key-expression chunk"):
        client.start_execution("ex/bad", _request(skill))


def test_world_overrides_cross_the_bus_as_given_and_are_checked_against_the_world_on_both_ends(bus, skill):
    """A start's ``world_overrides`` travel as the JSON they were given, checked against ``WorldConfig`` where the start
    is built (the API's side: a typo is a validation error naming the field) and where a worker reads it (a start
    written without the check is answered 'error' naming the field, not run)."""
    from pydantic import ValidationError

    good = {"table_height_m": 0.12, "cylinder": {"offset_m": [0.0, 0.0, 0.01]}}
    start = StartExecution(execution_id="ex-world", request=_request(skill), world_overrides=good)
    assert json.loads(start.model_dump_json())["world_overrides"] == good
    assert StartExecution.model_validate_json(start.model_dump_json()).world_overrides == good
    with pytest.raises(ValidationError, match=r"world_overrides\n.*cylinder\.radius_mm: Extra inputs"):
        StartExecution(execution_id="ex-world", request=_request(skill), world_overrides={"cylinder": {"radius_mm": 9}})
    sent = {**json.loads(start.model_dump_json()), "world_overrides": {"table_height_m": "high"}}
    endpoint, _ = bus
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(session_config("client", connect=[endpoint]))))
    try:
        [answer] = session.get(KeyExpressions("cskills").start("w-a"), payload=json.dumps(sent), timeout=WAIT_S)
        reply = StartReply.model_validate_json(answer.ok.payload.to_bytes())
    finally:
        session.close()
    assert (reply.accepted, reply.code) == (False, "error")
    assert (
        reply.reason.startswith("world_overrides: ")
        and "table.height_m: Input should be a valid number" in reply.reason
    )


def _isolated_worker(bus, name: str):
    """A worker under its own prefix, with its own BusClient (so the shared workers are not involved)."""
    endpoint, logs = bus
    prefix = f"iso-{name}"
    process = spawn_cli(
        ["worker", "--connect", endpoint, "--id", name, "--prefix", prefix], logs / f"{name}.log", cwd=REPO
    )
    recorder = Recorder()
    bus_client = BusClient(
        BusSettings(endpoints=[endpoint], prefix=prefix),
        recorder.on_status,
        recorder.on_telemetry,
        recorder.on_worker_lost,
    )
    _wait(lambda: bus_client.workers(), what=f"worker {name}")
    return process, bus_client, recorder


def test_sigkill_of_a_worker_mid_execution_is_reported_within_2s(bus, skill):
    process, bus_client, recorder = _isolated_worker(bus, "w-kill")
    try:
        bus_client.start_execution("ex-kill", _request(skill, pace="realtime"))
        _wait(lambda: recorder.samples("ex-kill") >= 100, what="telemetry")
        killed = time.monotonic()
        os.kill(process.pid, signal.SIGKILL)
        worker_id, seen = _wait(lambda: recorder.lost, 5.0, "on_worker_lost")[0]
        assert worker_id == "w-kill" and seen - killed < 2.0
        final = recorder.final("ex-kill", 1.0)  # the client failed the orphaned execution
        assert final.phase is ExecutionPhase.failed and "w-kill lost" in final.error
        with pytest.raises(NoWorkerAvailable, match="no worker connected"):
            bus_client.start_execution("ex-kill-2", _request(skill))
    finally:
        bus_client.close()
        _stop(process)


def test_sigterm_aborts_the_execution_and_exits_0(bus, skill):
    process, bus_client, recorder = _isolated_worker(bus, "w-term")
    try:
        bus_client.start_execution("ex-term", _request(skill, pace="realtime"))
        _wait(lambda: recorder.samples("ex-term") >= 100, what="telemetry")
        process.send_signal(signal.SIGTERM)
        log = bus[1] / "w-term.log"
        assert process.wait(15) == 0, log.read_text()
        final = recorder.final("ex-term", 5.0)
        assert final.phase is ExecutionPhase.aborted and final.error == "worker shutting down", (final, log.read_text())
        assert final.metrics is not None
        _wait(lambda: recorder.lost, 5.0, "the worker's token to go")
    finally:
        bus_client.close()
        _stop(process)


def test_a_run_that_ended_while_no_api_listened_keeps_its_verdict_and_gets_its_telemetry_back(bus, skill, tmp_path):
    """The API's bus side (BusClient + BusEvents on a store) goes away mid-run; the run finishes on the real
    worker; a new bus side reconciles: the run is done with its metrics, and the telemetry published while no API
    listened is asked again of the worker (``P/exec/{worker}/replay``): every sample stored once, in order."""
    from conftest import api_settings, loopback_client

    from services.app import BusEvents, create_app
    from services.bus_events import REPORT_KEY_NAME, reconcile
    from services.bus_reports import new_attempt
    from services.store import Store

    endpoint, _ = bus
    store = Store(tmp_path / "api.db")
    events = BusEvents(store)
    # As `connect_bus`: the report key kept in the database, the store's record of each execution's worker and
    # dispatch attempt.
    settings = BusSettings(endpoints=[endpoint], report_key=store.service_key(REPORT_KEY_NAME))
    owner = store.executions.owner
    first = BusClient(settings, events.on_status, events.on_telemetry, events.on_worker_lost, owner=owner)
    try:
        _wait(lambda: len(first.workers()) == 2 and not any(w.busy for w in first.workers()), what="two free workers")
        row = store.executions.add({"skill": "inline"}, None, dispatch="{}")  # as the queue: claimed with a nonce
        attempt = new_attempt()
        assert store.executions.claim_queued(row.id, attempt)
        worker = first.start_execution(row.id, _request(skill, pace="realtime"), attempt=attempt)
        store.executions.mark_started(row.id, worker)
        _wait(lambda: store.telemetry.counts(row.id)[1] > 200, what="telemetry stored")
    finally:
        first.close()  # the API dies mid-run
    recorder = Recorder()  # watches the worker, stores nothing
    with BusClient(BusSettings(endpoints=[endpoint]), recorder.on_status, recorder.on_telemetry,
                   recorder.on_worker_lost) as watcher:  # fmt: skip
        _wait(lambda: not next(w for w in watcher.workers() if w.worker_id == worker).busy, 30, "the run to end")
    events = BusEvents(store)
    second = BusClient(settings, events.on_status, events.on_telemetry, events.on_worker_lost, owner=owner)
    events.bus = second
    try:
        stored_before = store.telemetry.counts(row.id)[1]
        assert store.executions.get(row.id).status.value == "running"
        assert reconcile(store, second) == []  # nothing marked failed: the worker told how it ended
        ended = _wait(lambda: (lambda r: r if r.status.value != "running" else None)(store.executions.get(row.id)), 15,
                      "the final status stored")  # fmt: skip
    finally:
        second.close()
    assert ended.status.value == "done" and ended.metrics is not None and ended.worker_id == worker
    steps = ended.metrics.steps
    assert store.telemetry.gaps(row.id, steps) == [] and store.telemetry.counts(row.id)[1] == steps > 200
    np.testing.assert_allclose(store.telemetry.rows(row.id)[:, 0], np.arange(steps) * DT, atol=1e-9)
    with loopback_client(create_app(api_settings(tmp_path, learn_warm_up=False), bus=None, store=store)) as c:
        view = c.get(f"/executions/{row.id}").json()
    assert view["telemetry_missing_samples"] == 0 and view["telemetry_samples"] == steps
    assert stored_before < steps  # what the dead API missed came back from the worker
    store.close()


def test_a_start_request_the_caller_gave_up_on_is_refused_not_run(client, skill):
    """A worker that could only answer a start after the caller's deadline refuses it (the caller may have started
    the execution elsewhere meanwhile): no execution runs twice. Then the same worker takes a fresh request."""
    late = StartExecution(execution_id="ex-late", request=_request(skill), answer_by_unix_s=time.time() - 1.0)
    reply = client._query_one(client.keys.start("w-a"), late.model_dump_json(), 10.0)
    answer = StartReply.model_validate_json(reply)
    assert not answer.accepted and answer.code == "busy" and "expired" in answer.reason
    fresh = StartExecution(
        execution_id="ex-fresh", request=_request(skill), answer_by_unix_s=time.time() + 10.0, attempt="a1"
    )
    client.adopt("ex-fresh", "w-a", "a1")
    secret = client.reports.execution_secret("ex-fresh", "w-a", "a1")
    answer = StartReply.model_validate_json(client._query_one(client.keys.start("w-a"), fresh.model_dump_json(), 10.0,
                                                              attachment=secret))  # fmt: skip
    assert answer.accepted
    assert client.recorder.final("ex-fresh").phase is ExecutionPhase.done
    assert not client.recorder.statuses.get("ex-late")  # the refused one never ran: not one status


def test_the_bus_sends_each_status_once(bus, client, skill):
    """Issue 27: the final ``done`` went out twice (once when the loop's last rows turned the phase to done, once
    with the metrics). An independent subscriber counts every status of a run on the real bus: numbered 0, 1, 2, ...
    without a repeat, one final status, the last, with the metrics; the API side got exactly the same ones."""
    endpoint, _ = bus
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(session_config("client", connect=[endpoint]))))
    seen: list[ExecutionStatus] = []
    try:
        key = KeyExpressions("cskills").status("ex-once")
        session.declare_subscriber(
            key, lambda sample: seen.append(ExecutionStatus.model_validate_json(sample.payload.to_bytes()))
        )
        time.sleep(0.5)  # the subscription reaches the router
        _wait(lambda: not any(w.busy for w in client.workers()), 30, "a free worker")
        client.start_execution("ex-once", _request(skill))
        final = client.recorder.final("ex-once")
        time.sleep(0.5)  # anything sent after the final status would have arrived
    finally:
        session.close()
    assert [s.seq for s in seen] == list(range(len(seen))) and len(seen) >= 4
    assert [s.phase for s in seen].count(ExecutionPhase.done) == 1 and [s.final for s in seen].count(True) == 1
    assert seen[-1].phase is ExecutionPhase.done and seen[-1].metrics == final.metrics
    with client.recorder.lock:
        assert [s.seq for s in client.recorder.statuses["ex-once"]] == [s.seq for s in seen]
