"""The default stack's bus is secured (issue 25 H2): `contact-skills up`, as `make run` starts it, with REAL processes
on free loopback ports.

`up` makes its own logins (api, worker-1, observer; random passwords, in a folder only this user can read): a plain
anonymous Zenoh client cannot even open a session, so it can neither abort, forge a status, take a run nor append
telemetry. The observer login (which this user's `watch` and client find by the port) reads telemetry and statuses,
and its abort, forged ``done``, forged telemetry and fake worker change nothing: the run ends as its worker says,
with its own samples. The open `/health` names workers by their login, no host name or process id.

Connection hygiene (issue 25 M2, L1, M4) on the same stack, its limits set low: a connection that sends no request
head, or one header byte now and then, is closed after the header timeout; past the connection cap the silent
connections waiting longest make way and `/health` answers (issue 41); a flood of malformed requests logs one line; a
client's executions queued or running and its sweeps are capped (429 naming the setting); a Host that is not one
of the service's names gets 400 on every bind, all interfaces included.
"""

from __future__ import annotations

import contextlib
import json
import socket
import time

import pytest

zenoh = pytest.importorskip("zenoh")

from test_service import running_stack  # noqa: E402
from waiting import wait_for  # noqa: E402

from schemas.bus import ExecutionCommand, ExecutionStatus, KeyExpressions, WorkerInfo, session_config  # noqa: E402
from services.bus import open_session  # noqa: E402
from services.bus_keys import local_logins_folder  # noqa: E402

KEYS = KeyExpressions("cskills")
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 1.0}}


LIMITS = {"CONTACT_SKILLS_HEADER_TIMEOUT_S": "1", "CONTACT_SKILLS_KEEP_ALIVE_S": "1",
          "CONTACT_SKILLS_MAX_CONNECTIONS": "12", "CONTACT_SKILLS_CLIENT_QUEUED_MAX": "2",
          "CONTACT_SKILLS_CLIENT_SWEEPS_MAX": "1"}  # fmt: skip


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("secure-default"), workers=1, env=LIMITS)


@pytest.fixture(scope="module")
def skill_id(stack) -> str:
    demo = stack.post("/demonstrations/record", RECORD, 201)
    return stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "slide"}, 201)["id"]


def test_up_makes_its_own_logins_readable_by_this_user_only(stack):
    folder = local_logins_folder(stack.zenoh_port)
    assert folder.stat().st_mode & 0o077 == 0 and folder.parent.stat().st_mode & 0o077 == 0
    assert {p.name for p in folder.iterdir()} == {"users.txt", "api.env", "worker-1.env", "observer.env"}
    assert all(p.stat().st_mode & 0o077 == 0 for p in folder.iterdir())
    assert [w["worker_id"] for w in stack.health()["workers"]] == ["worker-1"]  # its login: no host name, no pid


def test_an_anonymous_zenoh_client_cannot_even_open_a_session(stack):
    config = zenoh.Config.from_json5(json.dumps(session_config("client", connect=[stack.endpoint])))
    with pytest.raises(zenoh.ZError):
        zenoh.open(config)


def test_the_observer_reads_but_cannot_abort_forge_append_or_take_a_run(stack, skill_id):
    observer = open_session("client", connect=[stack.endpoint], wait_s=10)  # this user's `up`'s observer login
    seen: list[int] = []
    taken: list[str] = []
    try:
        observer.declare_subscriber(KEYS.telemetry("*"), lambda sample: seen.append(1))
        observer.liveliness().declare_token(KEYS.worker("impostor"))
        observer.declare_queryable(KEYS.start("impostor"), lambda query: taken.append(str(query.key_expr)))
        time.sleep(0.5)
        created = stack.post("/executions", {"skill_id": skill_id, "pace": "realtime"}, 202)
        run = created["id"]
        assert created["worker_id"] in (None, "worker-1")
        wait_for(lambda: len(seen) >= 20, 30, "the observer to read telemetry")
        observer.put(KEYS.cmd(run), ExecutionCommand(command="abort", execution_id=run).model_dump_json())
        forged = ExecutionStatus(execution_id=run, worker_id="worker-1", phase="done", message="forged", steps=5)
        observer.put(KEYS.status(run), forged.model_dump_json())
        observer.put(KEYS.telemetry(run), '{"execution_id": "' + run + '", "t": [0.0]}')
        observer.put(KEYS.info("worker-1"), WorkerInfo(worker_id="worker-1", busy=False).model_dump_json())
        time.sleep(1.0)
        assert stack.execution(run)["status"] == "running"
        view = stack.finished(run, timeout_s=90)
    finally:
        observer.close()
    assert view["status"] == "done" and view["worker_id"] == "worker-1", view
    assert view["telemetry_samples"] == view["metrics"]["steps"] and view["telemetry_missing_samples"] == 0
    assert taken == [] and [w["worker_id"] for w in stack.health()["workers"]] == ["worker-1"]


def _connect(stack) -> socket.socket:
    return socket.create_connection(("127.0.0.1", stack.port), timeout=10)


def _closed_after(sock: socket.socket, dribble: bytes = b"") -> float:
    """Seconds until the server closes ``sock`` (which sends ``dribble`` one byte every 0.2 s meanwhile)."""
    started = time.monotonic()
    sock.settimeout(0.2)
    for byte in [dribble[k : k + 1] for k in range(len(dribble))] + [b""] * 100:
        try:
            if byte:
                sock.sendall(byte)
            if sock.recv(1024) == b"":
                return time.monotonic() - started
        except TimeoutError:
            continue
        except OSError:
            return time.monotonic() - started
    return time.monotonic() - started


def test_a_connection_without_a_whole_request_head_is_closed_after_the_header_timeout(stack):
    with _connect(stack) as silent, _connect(stack) as dribbling:
        assert _closed_after(silent) < 5
        assert _closed_after(dribbling, b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 60) < 5


def test_past_the_connection_cap_silent_connections_make_way_and_health_answers(stack):
    slow = [_connect(stack) for _ in range(int(LIMITS["CONTACT_SKILLS_MAX_CONNECTIONS"]) + 2)]
    try:
        health = stack.http.get("/health", timeout=5)
        assert health.status_code == 200 and health.json()["status"] == "ok"  # uvicorn alone: 503
        slow[0].settimeout(30)  # a generous wait: it was closed when /health connected
        with contextlib.suppress(ConnectionResetError):
            assert slow[0].recv(1) == b""  # the one waiting longest made way
    finally:
        for sock in slow:
            sock.close()


def test_a_flood_of_malformed_requests_logs_one_line(stack):
    before = stack.log_path.read_text().count("Invalid HTTP request")
    for _ in range(100):
        with _connect(stack) as sock:
            sock.sendall(b"NOT HTTP AT ALL\r\n\r\n")
            sock.recv(1024)
    time.sleep(0.5)
    assert stack.log_path.read_text().count("Invalid HTTP request") - before <= 1


def test_a_clients_queued_executions_and_sweeps_are_capped_with_429(stack, skill_id):
    body = {"skill_id": skill_id, "pace": "realtime"}
    held = [stack.post("/executions", body, 202)["id"] for _ in range(int(LIMITS["CONTACT_SKILLS_CLIENT_QUEUED_MAX"]))]
    try:
        refused = stack.http.post("/executions", json=body)
        assert refused.status_code == 429 and "CONTACT_SKILLS_CLIENT_QUEUED_MAX=2" in refused.json()["detail"]
        sweep = {"skill_id": skill_id, "trials": 1, "controllers": ["hybrid_cf"], "settings": {"pace": "fast"},
                 "vary": {"offset_z_m": {"low": 0.0, "high": 0.001}}}  # fmt: skip
        first = stack.http.post("/sweeps", json=sweep)
        assert first.status_code == 202, first.text
        second = stack.http.post("/sweeps", json=sweep)
        assert second.status_code == 429 and "CONTACT_SKILLS_CLIENT_SWEEPS_MAX=1" in second.json()["detail"]
        stack.http.post(f"/sweeps/{first.json()['id']}/cancel")
    finally:
        for execution_id in held:
            stack.http.post(f"/executions/{execution_id}/abort")
    for execution_id in held:
        stack.finished(execution_id, timeout_s=60)
    assert stack.http.post("/executions", json={**body, "pace": "fast"}).status_code == 202  # freed: admitted


def test_a_foreign_host_is_refused_on_every_bind(tmp_path):
    from conftest import api_settings, loopback_client

    from services.app import create_app

    for host, allowed in (("127.0.0.1", []), ("0.0.0.0", ["api"])):
        settings = api_settings(tmp_path, host=host, allowed_hosts=allowed)
        with loopback_client(create_app(settings, bus=None)) as c:
            rebound = c.get("/demonstrations", headers={"Host": "attacker.example:8000"})
            assert rebound.status_code == 400 and "CONTACT_SKILLS_ALLOWED_HOSTS" in rebound.text
            assert c.get("/demonstrations").status_code == 200  # 127.0.0.1
            assert c.get("/demonstrations", headers={"Host": "api:8000"}).status_code == (200 if allowed else 400)
