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
from schemas.bus import ExecutionCommand, ExecutionStatus, KeyExpressions  # noqa: E402
from schemas.bus_security import BusSecurity, access_control, read_users  # noqa: E402
from schemas.execution import ExecutionPhase  # noqa: E402
from services.bus import BusClient, BusSettings, open_session  # noqa: E402
from services.local_processes import free_port, spawn_cli, wait_for_port  # noqa: E402
from services.local_processes import stop_process as _stop  # noqa: E402

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
