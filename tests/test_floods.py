"""Floods without a login (issue 41, item 4) and the smaller HTTP and Foxglove items, on the real stack: the API served
by uvicorn with the service's own configuration (``services.app.server_config``) on a free loopback port, a real
Zenoh router with logins, the Foxglove live view's real server, real sockets.

- Idle TCP connections to the router's port, reopened as soon as the router closes them, do not keep a worker's
  authenticated session out (``schemas.bus.ROUTER_UNICAST_LIMITS``).
- A request body that does not arrive in time is answered 408 and closed; slow bodies past the connection cap do
  not keep ``/health`` out (``services.api.limits.BoundedH11Protocol``).
- A request head over 64 KiB is answered 431 even when it arrives whole.
- OPTIONS answers ``Allow`` with every method of the path.
- The Foxglove handshake is held to the REST API's origin rule.
- Per-client caps are per identity (the token) as well as per address: another loopback address gets no fresh cap.
"""

from __future__ import annotations

import contextlib
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from conftest import FakeBus, api_settings
from floods import IdleFlood, closed, port_of, slow_body
from test_api import _demo_json
from waiting import wait_for

from services.local_processes import free_port

WAIT_S = 60.0
"""Generous waits: a loaded CI machine runs three times slower."""


@contextlib.contextmanager
def served(tmp_path: Path, bus: bool = False, **changes) -> Iterator[str]:
    """The API (``bus``: on a `FakeBus` with one worker) served with ``services.app.server_config`` and the settings
    ``changes`` on a free loopback port; yields its URL."""
    import uvicorn

    from services.app import BusEvents, create_app, server_config
    from services.store import Store

    settings = api_settings(tmp_path, port=free_port(), learn_warm_up=False, learn_processes=1, foxglove_port="off",
                            **changes)  # fmt: skip
    store = Store(settings.db_path)
    events = BusEvents(store)
    fake = FakeBus(events.on_status, events.on_telemetry, events.on_worker_lost) if bus else None
    events.bus = fake
    server = uvicorn.Server(server_config(create_app(settings, bus=fake, store=store), settings, "warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: server.started, WAIT_S, "uvicorn to start")
        yield f"http://127.0.0.1:{settings.port}"
    finally:
        server.should_exit = True
        thread.join(WAIT_S)
        store.close()


def _answer(sock: socket.socket) -> bytes:
    """Everything the server sends until it closes the connection."""
    received = b""
    with contextlib.suppress(ConnectionResetError):
        while chunk := sock.recv(65536):
            received += chunk
    return received


# ------------------------------------------------------------------------------------------------ the Zenoh router


def test_idle_connections_to_the_router_do_not_keep_a_worker_out(tmp_path):
    """110 idle connections, reopened as the router closes them (Zenoh's defaults: the 100 pending for 10 s each
    refused 21 of 22 sessions): a worker's authenticated session opens, three times in a row, while they are held."""
    pytest.importorskip("zenoh")
    from schemas.bus_security import ENV_PASSWORD, ENV_USER, BusSecurity
    from services.bus import open_session
    from services.bus_keys import generate_logins
    from services.router import EmbeddedRouter

    worker = generate_logins(tmp_path, workers=1)["worker-1"]
    login = BusSecurity(user=worker[ENV_USER], password=worker[ENV_PASSWORD])
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with EmbeddedRouter([endpoint], BusSecurity(users_file=str(tmp_path / "users.txt"))), IdleFlood(port, 110) as flood:
        for _ in range(3):
            opened_before = flood.opened
            session = open_session("client", connect=[endpoint], wait_s=WAIT_S, security=login)
            session.close()
            assert flood.held_most >= 110 and flood.opened >= opened_before  # the flood went on meanwhile


# ------------------------------------------------------------------------------------------------ slow bodies


def test_a_body_that_does_not_arrive_in_time_is_answered_408_and_closed(tmp_path):
    with served(tmp_path, body_timeout_s=1.0) as url, slow_body(url, WAIT_S) as slow:
        answer = _answer(slow)  # the server closes it: recv returns b""
        assert answer.startswith(b"HTTP/1.1 408 ") and b"request body not received within 1 s" in answer
        assert httpx.get(f"{url}/health", timeout=WAIT_S).status_code == 200


@pytest.mark.parametrize("token", [None, "s3cret"])
def test_slow_bodies_past_the_connection_cap_do_not_keep_health_out(tmp_path, token):
    """Two more slow bodies than the cap (12), with a body deadline far away: the ones waiting longest make way,
    ``/health`` answers 200 (before: 503 while the slow bodies held every slot), on a token stack too."""
    with served(tmp_path, max_connections=12, body_timeout_s=600.0, token=token) as url:
        slow = []
        try:
            for _ in range(14):
                slow.append(slow_body(url, WAIT_S))
                time.sleep(0.05)  # in order: the first ones wait longest
            for _ in range(3):
                health = httpx.get(f"{url}/health", timeout=WAIT_S)
                assert health.status_code == 200 and health.json()["status"] == "ok"
            wait_for(lambda: closed(slow[0]) and closed(slow[1]), WAIT_S, "the oldest slow bodies to be closed")
            assert not closed(slow[-1])  # the newest still waits for its body
        finally:
            for sock in slow:
                sock.close()


# ------------------------------------------------------------------------------------------------ heads, OPTIONS


def test_a_request_head_over_64_kib_is_431_even_when_it_arrives_whole(tmp_path):
    from services.http_rules import MAX_HEAD_BYTES

    with served(tmp_path) as url:
        for size, status in ((60_000, b"200"), (100_000, b"431"), (MAX_HEAD_BYTES + 1, b"431")):
            with socket.create_connection(("127.0.0.1", port_of(url)), timeout=WAIT_S) as sock:
                head = b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\nX-Pad: "
                sock.sendall(head + b"a" * (size - len(head) - 4) + b"\r\n\r\n")  # exactly `size` bytes, at once
                assert _answer(sock).startswith(b"HTTP/1.1 " + status), size


def test_options_answers_allow_with_every_method_of_the_path(tmp_path):
    with served(tmp_path) as url:
        for path, methods in (("/demonstrations", "GET, OPTIONS, POST"), ("/executions/ex_1", "DELETE, GET, OPTIONS"),
                              ("/health", "GET, OPTIONS")):  # fmt: skip
            answer = httpx.options(f"{url}{path}", timeout=WAIT_S)
            assert answer.status_code == 204 and answer.headers["allow"] == methods, path
        refused = httpx.put(f"{url}/demonstrations", timeout=WAIT_S)
        assert refused.status_code == 405 and refused.headers["allow"] == "GET, OPTIONS, POST"
        assert httpx.options(f"{url}/nothing-here", timeout=WAIT_S).status_code == 404
    preflight = {"Origin": "http://ui.example", "Access-Control-Request-Method": "POST"}
    with served(tmp_path, cors_origins=["http://ui.example"]) as url:  # CORS preflight: CORSMiddleware's, unchanged
        answer = httpx.options(f"{url}/demonstrations", headers=preflight, timeout=WAIT_S)
        assert answer.status_code == 200 and answer.headers["access-control-allow-origin"] == "http://ui.example"


# ------------------------------------------------------------------------------------------------ Foxglove's origin


def test_the_foxglove_handshake_is_held_to_the_rest_apis_origin_rule_under_either_protocol_name(tmp_path):
    """The origin gate refuses a foreign page's handshake whichever name of Foxglove's protocol it offers, and
    answers an accepted one in the name the client offered (``foxglove.websocket.v1`` alone: older Foxglove Studio
    releases; both: the SDK's own name, which the server picks), with the server's first message behind it."""
    import asyncio
    import json

    websockets = pytest.importorskip("websockets")
    pytest.importorskip("foxglove")
    from services.foxglove_live import SDK_SUBPROTOCOL, WEBSOCKET_SUBPROTOCOL, live_view
    from services.settings import ServiceSettings
    from services.store import Store

    async def handshake(url: str, offered: list[str], **headers: str) -> int | str:
        """The subprotocol a handshake offering ``offered`` with ``headers`` agreed (once the server's first
        message, serverInfo, came through it), or the HTTP status refusing it."""
        try:
            async with websockets.connect(url, subprotocols=offered, **headers) as ws:
                assert json.loads(await ws.recv())["op"] == "serverInfo"
                return ws.subprotocol
        except websockets.InvalidStatus as exc:
            return exc.response.status_code

    async def handshakes(url: str, port: int, offered: list[str]) -> list[int | str]:
        local = f"http://127.0.0.1:{port}"
        return await asyncio.gather(
            handshake(url, offered), handshake(url, offered, origin=local),
            handshake(url, offered, origin="http://ui.example"),
            handshake(url, offered, origin="http://attacker.example"),
            handshake(f"ws://localhost:{port}", offered, origin=local),
            handshake(url, offered, additional_headers={"Host": f"attacker.example:{port}"}),
        )  # fmt: skip

    store = Store(tmp_path / "api.db")
    view = live_view(store, ServiceSettings(foxglove_port="0", cors_origins=["http://ui.example"]))
    view.start()
    results = {}
    try:
        for offered in ([SDK_SUBPROTOCOL], [WEBSOCKET_SUBPROTOCOL], [WEBSOCKET_SUBPROTOCOL, SDK_SUBPROTOCOL]):
            results[offered[0], len(offered)] = asyncio.run(asyncio.wait_for(handshakes(view.url, view.gate.port,
                                                                                        offered), WAIT_S))  # fmt: skip
        results["other", 1] = asyncio.run(asyncio.wait_for(handshake(view.url, ["other.v1"]), WAIT_S))
    finally:
        view.close()
        store.close()
    for (name, count), agreed in results.items():
        if name != "other":
            expected = name if count == 1 else SDK_SUBPROTOCOL
            assert agreed == [expected, expected, expected, 403, 403, 400], (name, count)
    assert results["other", 1] == 400  # a protocol of another name: the server's own refusal, passed on


# ------------------------------------------------------------------------------------------------ per-client caps


def _execution(url: str, skill: dict, source: str, token: str | None) -> int:
    """The status of ``POST /executions`` of ``skill`` sent from the loopback address ``source``."""
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    transport = httpx.HTTPTransport(local_address=source)
    with httpx.Client(transport=transport, timeout=WAIT_S) as client:
        answer = client.post(f"{url}/executions", json={"skill": skill, "pace": "realtime"}, headers=headers)
    assert answer.status_code in (202, 429), answer.text
    return answer.status_code


@pytest.fixture(scope="module")
def inline_skill() -> dict:
    from schemas import Demonstration, LearnOptions
    from skills.parameterize import learn_skill

    demonstration = Demonstration.model_validate(_demo_json())
    return learn_skill(demonstration, LearnOptions(skill_type="slide")).model_dump(mode="json")


@pytest.mark.parametrize("token", [None, "s3cret"])
def test_another_loopback_address_gets_no_fresh_cap(inline_skill, token):
    """A client's cap of 2 queued executions, from 127.0.0.1: the third, from 127.0.0.2 (the same machine, with the
    same token on a token stack), is 429."""
    with tempfile.TemporaryDirectory() as folder, served(Path(folder), bus=True, client_queued_max=2,
                                                         token=token) as url:  # fmt: skip
        assert [_execution(url, inline_skill, "127.0.0.1", token) for _ in range(2)] == [202, 202]
        assert _execution(url, inline_skill, "127.0.0.2", token) == 429
