"""The secured bus with REAL processes: `contact-skills bus-keys` makes the certificates and logins, `contact-skills
router` serves a TLS endpoint with the users file, a sim worker logs in as ``worker-1`` (its env file), the API side
(`BusClient`) as ``api``.

An authenticated API and worker run an execution end to end. A session without a login, with a wrong password, or
without the CA that signed the router's certificate is never opened. A read-only observer receives telemetry but its
abort, its forged ``done`` status and its fake worker have no effect; another worker cannot take ``worker-1``'s
queries (start, replay) nor command an execution.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")
pytest.importorskip("cryptography")
from test_bus import REPO, WAIT_S, Recorder, _wait  # noqa: E402

from schemas import ExecutionRequest, LearnOptions, RecordRequest  # noqa: E402
from schemas.bus import ExecutionCommand, ExecutionStatus, KeyExpressions, WorkerInfo  # noqa: E402
from schemas.bus_security import BusSecurity, access_control, report_signature  # noqa: E402
from schemas.execution import ExecutionPhase, TelemetryBatch  # noqa: E402
from services.bus import BusClient, BusSettings, open_session  # noqa: E402
from services.local_processes import free_port, spawn_cli, wait_for_port  # noqa: E402
from services.local_processes import stop_process as _stop  # noqa: E402
from services.router import read_users  # noqa: E402

KEYS = KeyExpressions("cskills")


def _env_file(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines() if "=" in line)


@pytest.fixture(scope="module")
def secure_bus(tmp_path_factory):
    """Keys from `contact-skills bus-keys`, the router (TLS + users) and the worker worker-1 as subprocesses; yields
    (endpoint, the keys folder)."""
    folder = tmp_path_factory.mktemp("secure-bus")
    keys = folder / "keys"
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    made = subprocess.run(
        [sys.executable, "-m", "cli.main", "bus-keys", str(keys), "--host", "127.0.0.1", "--workers", "2",
         "--endpoint", endpoint], cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert made.returncode == 0, made.stderr
    assert all((keys / f).stat().st_mode & 0o077 == 0 for f in ("router.key", "users.txt", "api.env"))
    router = spawn_cli(["router", "--listen", endpoint, "--users", str(keys / "users.txt"), "--tls-cert",
                        str(keys / "router.pem"), "--tls-key", str(keys / "router.key")], folder / "router.log",
                       cwd=REPO)  # fmt: skip
    processes = [router]
    try:
        wait_for_port(port, WAIT_S)
        login = _env_file(keys / "worker-1.env")  # its endpoint, user, password and CA
        processes.append(spawn_cli(["worker"], folder / "worker-1.log", cwd=REPO, env=login))
        yield endpoint, keys
    finally:
        for process in reversed(processes):
            _stop(process)


def _login(keys: Path, user: str | None, password: str | None = None, with_ca: bool = True) -> BusSecurity:
    """The login of ``user`` from its env file (``password`` instead of its own if given; None: no login)."""
    env = _env_file(keys / f"{user or 'api'}.env")
    ca = env["CONTACT_SKILLS_ZENOH_TLS_CA"] if with_ca else None
    if user is None:
        return BusSecurity(tls_ca=ca)
    return BusSecurity(user=user, password=password or env["CONTACT_SKILLS_ZENOH_PASSWORD"], tls_ca=ca)


@pytest.fixture(scope="module")
def api(secure_bus):
    endpoint, keys = secure_bus
    recorder = Recorder()
    settings = BusSettings(endpoints=[endpoint], security=_login(keys, "api"), connect_timeout_s=10)
    client = BusClient(settings, recorder.on_status, recorder.on_telemetry, recorder.on_worker_lost)
    client.recorder = recorder  # type: ignore[attr-defined]
    try:
        _wait(lambda: [w.worker_id for w in client.workers()] == ["worker-1"], what="the worker worker-1")
        yield client
    finally:
        client.close()


@pytest.fixture(scope="module")
def skill(api):
    from skills.parameterize import learn_skill

    reply = api.record_demonstration(RecordRequest(scenario="slide_flat", seed=0, overrides={"move_duration_s": 1.0}))
    assert reply.ok, reply.error
    return learn_skill(reply.demonstration, LearnOptions(skill_type="slide", min_segment_duration_s=0.5))


def _request(skill, **settings) -> ExecutionRequest:
    return ExecutionRequest(skill=skill, **{"scenario": "slide_flat", "pace": "fast", **settings})


def test_the_users_file_gives_each_role_its_rights(secure_bus):
    _, keys = secure_bus
    acl = access_control("cskills", read_users(keys / "users.txt"))
    assert acl["default_permission"] == "deny"
    by_id = {rule["id"]: rule for rule in acl["rules"]}
    assert by_id["api-sends"]["key_exprs"] == ["cskills/exec/*/cmd", "cskills/sweeps/*/progress"]
    assert "cskills/exec/worker-1/start" in by_id["worker:worker-1-declares"]["key_exprs"]
    assert by_id["worker:worker-1-lives"]["key_exprs"] == ["cskills/workers/worker-1"]
    assert not any(rule["id"].startswith("observer") and "put" in rule["messages"] and rule["flows"] == ["ingress"]
                   for rule in acl["rules"])  # fmt: skip
    assert {s["id"] for s in acl["subjects"]} == {"api", "observer", "worker:worker-1", "worker:worker-2"}


@pytest.mark.parametrize(
    ("user", "password", "with_ca"),
    [(None, None, True), ("api", "wrong", True), ("observer", None, False)],
    ids=["no login", "wrong password", "no CA for the router's certificate"],
)
def test_a_session_without_a_valid_login_is_never_opened(secure_bus, user, password, with_ca):
    endpoint, keys = secure_bus
    with pytest.raises(ConnectionError):
        open_session("client", connect=[endpoint], security=_login(keys, user, password, with_ca))


def test_the_authenticated_api_and_worker_run_an_execution(api, skill):
    worker = api.start_execution("sec-run", _request(skill))
    assert worker == "worker-1"
    final = api.recorder.final("sec-run")
    assert final.phase is ExecutionPhase.done and final.metrics is not None
    _wait(lambda: api.recorder.samples("sec-run") == final.metrics.steps, 10, "every telemetry sample")


def test_an_observer_reads_but_cannot_command_forge_or_pose_as_a_worker(secure_bus, api, skill):
    endpoint, keys = secure_bus
    observer = open_session("client", connect=[endpoint], security=_login(keys, "observer"))
    seen: list[int] = []
    impostor_queries: list[str] = []
    try:
        observer.declare_subscriber(KEYS.telemetry("sec-obs"), lambda sample: seen.append(1))
        observer.liveliness().declare_token(KEYS.worker("fake"))
        observer.declare_queryable(KEYS.start("fake"), lambda query: impostor_queries.append(str(query.key_expr)))
        api.start_execution("sec-obs", _request(skill, pace="realtime"))
        _wait(lambda: len(seen) >= 20, what="the observer to read telemetry")
        abort = ExecutionCommand(command="abort", execution_id="sec-obs", reason="observer")
        observer.put(KEYS.cmd("sec-obs"), abort.model_dump_json())
        forged = ExecutionStatus(execution_id="sec-obs", worker_id="worker-1", phase="done", message="forged")
        observer.put(KEYS.status("sec-obs"), forged.model_dump_json())
        time.sleep(1.0)
        with api.recorder.lock:
            statuses = list(api.recorder.statuses["sec-obs"])
        assert not any(s.message == "forged" or s.final for s in statuses), statuses
        assert [w.worker_id for w in api.workers()] == ["worker-1"]
        api.send_command("sec-obs", "abort")
        final = api.recorder.final("sec-obs")
        assert final.phase is ExecutionPhase.aborted and final.error == "aborted on request"
        assert impostor_queries == []
    finally:
        observer.close()


def test_the_api_publishes_sweep_progress_an_observer_reads_and_cannot_forge(secure_bus, api):
    endpoint, keys = secure_bus
    reader = open_session("client", connect=[endpoint], security=_login(keys, "observer"))
    forger = open_session("client", connect=[endpoint], security=_login(keys, "observer"))
    seen: list[str] = []
    try:
        reader.declare_subscriber(KEYS.sweep_progress("*"), lambda sample: seen.append(sample.payload.to_string()))
        time.sleep(0.5)
        forger.put(KEYS.sweep_progress("sweep_forged"), '{"forged": true}')
        api.publish(KEYS.sweep_progress("sweep_1"), '{"sweep_id": "sweep_1"}')
        _wait(lambda: seen, what="the observer to read the progress")
        time.sleep(0.5)
        assert seen == ['{"sweep_id": "sweep_1"}']
    finally:
        reader.close()
        forger.close()


def test_a_worker_cannot_take_another_workers_queries_or_command(secure_bus, api, skill):
    endpoint, keys = secure_bus
    other = open_session("client", connect=[endpoint], security=_login(keys, "worker-2"))
    stolen: list[str] = []
    try:
        other.declare_queryable(KEYS.start("worker-1"), lambda query: stolen.append(str(query.key_expr)))
        other.declare_queryable(KEYS.replay("worker-1"), lambda query: stolen.append(str(query.key_expr)))
        other.liveliness().declare_token(KEYS.worker("worker-3"))
        time.sleep(0.5)
        assert [w.worker_id for w in api.workers()] == ["worker-1"]
        assert api.start_execution("sec-other", _request(skill, pace="realtime")) == "worker-1"
        _wait(lambda: api.recorder.samples("sec-other") > 100, what="the execution to run")
        abort = ExecutionCommand(command="abort", execution_id="sec-other", reason="another worker")
        other.put(KEYS.cmd("sec-other"), abort.model_dump_json())
        time.sleep(1.0)
        with api.recorder.lock:
            assert not any(s.final for s in api.recorder.statuses["sec-other"])
        api.send_command("sec-other", "abort")
        assert api.recorder.final("sec-other").error == "aborted on request"
        # A replay of the run is answered by worker-1 alone, with what it streamed: worker-2's queryable got nothing.
        replayed = api.telemetry_replay("worker-1", "sec-other", 0, 100)
        assert replayed and sum(len(b.t) for b in replayed) == 100
        streamed = np.concatenate([b.t for b in sorted(api.recorder.telemetry["sec-other"], key=lambda b: b.seq)])
        np.testing.assert_array_equal(np.concatenate([b.t for b in replayed]), streamed[:100])
        assert stolen == []
    finally:
        other.close()


def _forged_batch(execution_id: str, first_sample: int) -> TelemetryBatch:
    """One telemetry row that no worker produced (a force of 999 N)."""
    zero3, unit_q, wrench = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 999.0, 0.0, 0.0, 0.0]
    return TelemetryBatch(execution_id=execution_id, t=[0.0], phase=["contact"], segment_index=[0],
                          tool_position=[zero3], tool_orientation=[unit_q], reference_position=[zero3],
                          reference_orientation=[unit_q], wrench_world=[wrench], wrench_cf=[wrench],
                          desired_force_cf_z_n=[999.0], seq=0, first_sample=first_sample)  # fmt: skip


def test_a_second_worker_login_cannot_falsify_another_workers_run(secure_bus, api, skill):
    """Issue 25 H3, with a REAL second worker login (worker-2) on the secured bus while worker-1 runs: a ``done``
    naming worker-1 (signed with a made-up secret, and unsigned), a status naming itself, telemetry appended while
    the run goes and after it ended, an answer to the status query with a forged final status, and its own info
    reply of ``executions_run: -1000`` are all refused: the run ends as worker-1 says, with worker-1's samples
    only, and worker-2 is never offered an execution."""
    endpoint, keys = secure_bus
    other = open_session("client", connect=[endpoint], security=_login(keys, "worker-2"))
    run = "sec-falsify"
    forged_done = ExecutionStatus(execution_id=run, worker_id="worker-1", phase="done", message="forged", steps=5)
    info = WorkerInfo(worker_id="worker-2", busy=False, executions_run=-1000)
    try:
        other.declare_queryable(KEYS.info("worker-2"), lambda q: q.reply(KEYS.info("worker-2"), info.model_dump_json()))
        other.declare_queryable(KEYS.status("*"), lambda q: q.reply(KEYS.status(run), forged_done.model_dump_json(),
                                                                     attachment=b"\0" * 32))  # fmt: skip
        token = other.liveliness().declare_token(KEYS.worker("worker-2"))
        time.sleep(0.5)
        assert {w.worker_id: w.busy for w in api.workers()} == {"worker-1": False, "worker-2": True}
        assert api.start_execution(run, _request(skill, pace="realtime")) == "worker-1"
        _wait(lambda: api.recorder.samples(run) > 100, what="the execution to run")
        other.put(KEYS.status(run), forged_done.model_dump_json(), attachment=b"\1" * 32)
        other.put(KEYS.status(run), forged_done.model_dump_json())
        own = forged_done.model_copy(update={"worker_id": "worker-2"})
        other.put(KEYS.status(run), own.model_dump_json(), attachment=report_signature(b"guess", b"x"))
        other.put(KEYS.telemetry(run), _forged_batch(run, 50).model_dump_json(), attachment=b"\2" * 32)
        time.sleep(1.0)
        with api.recorder.lock:
            assert not any(s.final or s.message == "forged" for s in api.recorder.statuses[run])
        assert api.latest_status("worker-1", run) is not None and not api.latest_status("worker-1", run).final
        api.send_command(run, "abort")
        final = api.recorder.final(run)
        assert final.worker_id == "worker-1" and final.phase is ExecutionPhase.aborted and final.metrics.steps > 100
        other.put(KEYS.telemetry(run), _forged_batch(run, final.metrics.steps).model_dump_json())  # after the end
        time.sleep(1.0)
        with api.recorder.lock:
            batches = sorted(api.recorder.telemetry[run], key=lambda b: b.first_sample)
        assert sum(len(b.t) for b in batches) == final.metrics.steps
        assert max(abs(f[2]) for b in batches for f in b.wrench_cf) < 500  # not one forged row
        assert api.latest_statuses()[run].phase is ExecutionPhase.aborted  # worker-1's, not the forged done
        token.undeclare()
    finally:
        other.close()


def test_implausible_reports_are_named_and_refused():
    """A worker's own reports that cannot be true: negative counters, ``done`` without a control step, an info
    reply under another worker's key."""
    from schemas.execution import ExecutionMetrics
    from services.bus_reports import implausible_info, implausible_status

    ok = ExecutionStatus(execution_id="e", worker_id="w", phase="contact", steps=10, seq=3)
    assert implausible_status(ok) is None
    assert "steps -1" in implausible_status(ok.model_copy(update={"steps": -1}))
    done = ok.model_copy(update={"phase": ExecutionPhase.done})
    assert implausible_status(done) == "done without a control step"
    assert implausible_status(done.model_copy(update={"metrics": ExecutionMetrics.model_construct(steps=0)}))
    assert "negative" in implausible_info(WorkerInfo(worker_id="w", busy=False, executions_run=-1000),
                                          KEYS.info("w"), KEYS)  # fmt: skip
    assert "under" in implausible_info(WorkerInfo(worker_id="w", busy=False), KEYS.info("v"), KEYS)
    assert implausible_info(WorkerInfo(worker_id="w", busy=False), KEYS.info("w"), KEYS) is None
