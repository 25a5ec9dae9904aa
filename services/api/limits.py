"""What the service accepts beyond the field bounds of ``schemas/``: inline skills whose parts fit together,
connections that send their request head and body in time and cannot keep new ones out, per-client caps on queued
work. (Time stamps it can learn from in bounded memory: ``services.learner_pool.check_sampling``.)"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from enum import StrEnum
from typing import Any

import h11
from fastapi import HTTPException
from uvicorn.protocols.http.h11_impl import H11Protocol

from schemas.api import ApiError, ExecutionState
from schemas.skill import Skill
from schemas.sweep import SweepState
from services.api.responses import OpenApiResponses
from services.http_rules import MAX_HEAD_BYTES
from services.store import ACTIVE, Store

UPLOAD_STORED_MULTIPLE = 16.0
"""An uploaded recording (CSV, bag) stores at most this many times the bytes it brought. The real recordings store
0.4-0.6x (KU Leuven CSVs); a row-per-sample CSV with short numbers ~7x. Past it the time stamps span far more samples
than the file has rows (resampling would invent them)."""


def skill_problems(skill: Skill) -> list[tuple[list[str | int], str]]:
    """Where an inline skill that validates field by field is still incoherent, as (loc under ``skill``, reason):
    a contact segment without compliant frames or without a force, DMP parameters whose shapes disagree
    (``skills.dmp`` rebuilds each one), compliant frame lists of different lengths."""
    from schemas.skill import SegmentKind
    from skills.dmp import DMP
    from skills.quaternion_dmp import QuaternionDMP

    problems: list[tuple[list[str | int], str]] = []
    for k, segment in enumerate(skill.segments):
        where: list[str | int] = ["segments", k]
        if segment.kind is SegmentKind.contact:
            if segment.compliant_frames is None:
                problems.append(([*where, "compliant_frames"], "a contact segment needs its compliant frame(s)"))
            if segment.force_constant_n is None and segment.force_dmp is None:
                problems.append(([*where, "force_constant_n"], "a contact segment needs force_constant_n or force_dmp"))
        frames = segment.compliant_frames
        if frames is not None and not len(frames.t) == len(frames.origins) == len(frames.orientations):
            problems.append(([*where, "compliant_frames"], "t, origins and orientations need one entry per frame"))
        for name, rebuild in (("position_dmp", DMP), ("orientation_dmp", QuaternionDMP), ("force_dmp", DMP)):
            parameters = getattr(segment, name)
            if parameters is None:
                continue
            try:
                rebuild.from_parameters(parameters)
            except ValueError as exc:
                problems.append(([*where, name], f"inconsistent DMP parameters: {exc}"))
    return problems


EVICTION_RESERVE_FRACTION = 16
"""At the connection cap, a new connection closes connections that are waiting on their client until one in this
many of the cap (at least 2) is free: room for the next few newcomers, whose requests would otherwise meet the
closed connections' requests still ending (uvicorn counts both against the cap)."""


def _head_bytes(request: h11.Request) -> int:
    """The size of ``request``'s head on the wire, bytes (request line, headers, blank line)."""
    line = len(request.method) + len(request.target) + len(b"  HTTP/1.1\r\n")
    return line + sum(len(name) + len(value) + 4 for name, value in request.headers.raw_items()) + 2


class _HeadBoundedConnection(h11.Connection):
    """h11's server side with the head limit applied to a whole head too: h11 bounds only a head still incomplete
    in its buffer (``max_incomplete_event_size``), so a 100 KB head that arrived at once was taken.
    :attr:`refused_status` is the status a protocol error should be answered with (431: a head too large)."""

    refused_status: int = 400

    def next_event(self) -> h11.Event | type[h11.NEED_DATA] | type[h11.PAUSED]:
        try:
            event = super().next_event()
        except h11.RemoteProtocolError as exc:
            self.refused_status = exc.error_status_hint
            raise
        if isinstance(event, h11.Request) and _head_bytes(event) > self._max_incomplete_event_size:
            self.refused_status = 431
            raise h11.RemoteProtocolError("request head too large", error_status_hint=431)
        return event


class BoundedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with bounds on what a client can hold without sending its request:

    - **the head**: a connection that has not sent a whole request line and headers within ``head_timeout_s`` of
      connecting (or of its previous response) is closed; a head larger than :data:`MAX_HEAD_BYTES` is answered 431
      (h11 alone took one that arrived whole). uvicorn itself times out only idle keep-alive connections: a client
      that sent nothing, or a header byte now and then, kept its connection for good; 20 600 such connections
      exhausted the API's file handles.
    - **the body**: a request whose body has not arrived whole within ``body_timeout_s`` of its head is answered 408
      and closed (closed if the app answered already). 300 bodies sent at 1 byte per 2 s held every slot of the
      connection cap and ``/health`` answered 503 to 141 of 174 probes.
    - **the cap** (``limit_concurrency``, past which uvicorn answers 503): a new connection at the cap closes the
      connections that have waited longest on their client (for a head, a body, or idle after a response), never
      one whose request is whole and being served. So slow or silent clients cannot keep a new client, ``/health``
      first, out; only requests being served can fill the cap."""

    head_timeout_s = 10.0
    """Set by :func:`bounded_protocol`, s."""
    body_timeout_s = 60.0
    """Set by :func:`bounded_protocol`, s."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.conn = _HeadBoundedConnection(h11.SERVER, max_incomplete_event_size=MAX_HEAD_BYTES)
        self._head_deadline: asyncio.TimerHandle | None = None
        self._body_deadline: asyncio.TimerHandle | None = None
        self.waiting_since: float | None = None
        """Since when (event loop time, s) this connection has been waiting on its client; None while its request
        is whole (being served)."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # H11Protocol's signature
        super().connection_made(transport)
        self._watch()
        self._make_room()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._watch()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._watch()

    def connection_lost(self, exc: Exception | None) -> None:
        for deadline in (self._head_deadline, self._body_deadline):
            if deadline is not None:
                deadline.cancel()
        self._head_deadline = self._body_deadline = None
        super().connection_lost(exc)

    def send_400_response(self, msg: str) -> None:
        """A malformed request (uvicorn's 400), or a head too large (431)."""
        if isinstance(self.conn, _HeadBoundedConnection) and self.conn.refused_status == 431:
            self._refuse(431, f"request head larger than {MAX_HEAD_BYTES} bytes")
        else:
            super().send_400_response(msg)

    def _watch(self) -> None:
        """Arm the deadline of what the connection waits for (a head, a body), cancel the others."""
        waiting_for_head = self.cycle is None or self.cycle.response_complete
        sending_body = not waiting_for_head and self.conn.their_state is h11.SEND_BODY
        self._head_deadline = self._arm(self._head_deadline, waiting_for_head, self.head_timeout_s, self._head_overdue)
        self._body_deadline = self._arm(self._body_deadline, sending_body, self.body_timeout_s, self._body_overdue)
        if not (waiting_for_head or sending_body):
            self.waiting_since = None
        elif self.waiting_since is None:
            self.waiting_since = self.loop.time()

    def _arm(
        self, deadline: asyncio.TimerHandle | None, needed: bool, delay_s: float, overdue: Callable[[], None]
    ) -> asyncio.TimerHandle | None:
        if needed:
            return deadline or self.loop.call_later(delay_s, overdue)
        if deadline is not None:
            deadline.cancel()
        return None

    def _head_overdue(self) -> None:
        self._head_deadline = None
        if (self.cycle is None or self.cycle.response_complete) and not self.transport.is_closing():
            self.transport.close()

    def _body_overdue(self) -> None:
        self._body_deadline = None
        if self.transport.is_closing() or self.conn.their_state is not h11.SEND_BODY:
            return
        if self.cycle is not None and not self.cycle.response_started:
            self.cycle.disconnected = True  # the app's receive() answers http.disconnect, its replies are dropped
            self.cycle.message_event.set()
            self._refuse(408, f"request body not received within {self.body_timeout_s:g} s")
        else:
            self.transport.close()

    def _refuse(self, status: int, text: str) -> None:
        """Answer ``status`` with ``text`` (plain text) and close the connection."""
        headers = [(b"content-type", b"text/plain; charset=utf-8"), (b"connection", b"close")]
        for event in (h11.Response(status_code=status, headers=headers), h11.Data(data=text.encode()),
                      h11.EndOfMessage()):  # fmt: skip
            self.transport.write(self.conn.send(event) or b"")
        self.transport.close()

    def _make_room(self) -> None:
        """At the cap, close the connections waiting longest on their client (see the class docstring)."""
        if self.limit_concurrency is None:
            return
        reserve = max(2, self.limit_concurrency // EVICTION_RESERVE_FRACTION)
        open_now = [c for c in self.connections if not c.transport.is_closing()]
        excess = len(open_now) - (self.limit_concurrency - reserve)
        if excess <= 0:
            return
        waiting = [c for c in open_now if c is not self and getattr(c, "waiting_since", None) is not None]
        for stalled in sorted(waiting, key=lambda c: c.waiting_since)[:excess]:
            stalled.transport.abort()


def bounded_protocol(head_timeout_s: float, body_timeout_s: float) -> type[BoundedH11Protocol]:
    """The protocol class for ``uvicorn.Config(http=...)`` with these deadlines (s)."""
    return type("BoundedH11", (BoundedH11Protocol,), {"head_timeout_s": head_timeout_s,
                                                       "body_timeout_s": body_timeout_s})  # fmt: skip


class WorkKind(StrEnum):
    """What one client may hold at most so many of at once (:class:`ClientCaps`)."""

    execution = "execution"
    sweep = "sweep"


TOO_MANY: OpenApiResponses = {429: {"model": ApiError}}
"""``responses=`` of the routes a client's cap applies to (:class:`ClientCaps`)."""


class ClientCaps:
    """Per-client caps on the work waiting in the service: executions queued or running (``client_queued_max``) and
    sweeps running (``client_sweeps_max``). A request counts against each of its client keys (``deps.client_keys``:
    its address, every loopback address one; and the bearer token when it carries it, one identity whatever the
    address): one more than a key's cap answers 429 naming the cap; the global queue cap (``queue_max``, 503) still
    holds for all clients together. Counted by this API process: a restart forgets who submitted what (the store
    keeps no client)."""

    def __init__(self, store: Store, max_executions: int, max_sweeps: int) -> None:
        self.store = store
        self.caps = {WorkKind.execution: max_executions, WorkKind.sweep: max_sweeps}
        self._held: dict[tuple[WorkKind, str], set[str]] = {}
        self._lock = threading.Lock()

    def _active(self, kind: WorkKind, ident: str) -> bool:
        if kind is WorkKind.execution:
            row = self.store.executions.get(ident)
            return row is not None and row.status in (ExecutionState.queued, *ACTIVE)
        sweep = self.store.sweeps.get(ident)
        return sweep is not None and sweep.status == SweepState.running.value

    def admit(self, kind: WorkKind, clients: tuple[str, ...]) -> None:
        """Raise a 429 ``HTTPException`` if one of ``clients`` (the request's keys) holds its cap of ``kind``."""
        for client in clients:
            with self._lock:
                held = set(self._held.get((kind, client), ()))
            active = {ident for ident in held if self._active(kind, ident)}
            with self._lock:
                self._held[(kind, client)] = active | (self._held.get((kind, client), set()) - held)
            if len(active) >= self.caps[kind]:
                setting = {WorkKind.execution: "CONTACT_SKILLS_CLIENT_QUEUED_MAX", WorkKind.sweep:
                           "CONTACT_SKILLS_CLIENT_SWEEPS_MAX"}[kind]  # fmt: skip
                raise HTTPException(
                    429,
                    f"{client} has {len(active)} {kind.value}s queued or running, its cap ({setting}="
                    f"{self.caps[kind]}): wait for one to end, or cancel one",
                )

    def hold(self, kind: WorkKind, clients: tuple[str, ...], ident: str) -> None:
        """Count ``ident`` (just created) against each of ``clients``' caps until it ends."""
        with self._lock:
            for client in clients:
                self._held.setdefault((kind, client), set()).add(ident)
