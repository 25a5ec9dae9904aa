"""The API side of the Zenoh bus: find workers, dispatch executions and recordings, relay status and telemetry.

``BusClient`` opens one Zenoh session (client mode, connected to the router) and

- subscribes to ``P/exec/*/status`` and ``P/exec/*/telemetry`` and hands every ``ExecutionStatus`` /
  ``TelemetryBatch`` to ``on_status`` / ``on_telemetry``,
- watches the workers' liveliness tokens ``P/workers/*`` (with history, so workers already running are seen);
  when a token goes (the worker process ended or died, even by SIGKILL: the router sees its connection close
  and propagates the DELETE within milliseconds), it waits ``LOST_GRACE_S`` (0.25 s) for the worker's last
  statuses, then calls ``on_status`` with a synthesized ``failed`` status for every execution this client
  started on that worker that has not finished, then ``on_worker_lost(worker_id)``: about 0.26 s after the
  process died.

THREADS: the three callbacks run on Zenoh's threads (``on_worker_lost`` and the synthesized statuses on a timer
thread), concurrently with each other and with the caller's threads.
They must be thread-safe and quick (store, enqueue, notify; no blocking I/O, no calls back into the client that
wait for the bus). An exception in a callback is logged and swallowed. Status and telemetry of one execution
arrive in the order the worker published them; a status may arrive before ``start_execution`` returns.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from schemas.bus import (
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    ENV_ENDPOINTS,
    ENV_PREFIX,
    ExecutionCommand,
    ExecutionStatus,
    KeyExpressions,
    RecordReply,
    RecordRequest,
    StartExecution,
    StartReply,
    WorkerInfo,
    session_config,
    split_endpoints,
)
from schemas.bus_security import BusSecurity
from schemas.demonstration import Demonstration
from schemas.execution import ExecutionPhase, ExecutionRequest, TelemetryBatch

log = logging.getLogger("contact_skills.bus")

INFO_TIMEOUT_S = 2.0
"""How long ``workers()`` waits for the workers' info replies, s (they answer in about a millisecond)."""
START_TIMEOUT_S = 30.0
"""How long a start request waits for the chosen worker's reply, s: the worker builds the execution's world and
checks its reach (placement) before it accepts, 0.1-1.2 s on a quiet core, ten times that on a loaded one."""
LOST_GRACE_S = 0.25
"""A worker's token gone, wait this long for its last statuses before reporting it lost, s (a token that comes
back within it, e.g. after a router restart as short, cancels the report)."""


@dataclass
class BusSettings:
    """How the API reaches the bus. ``from_env`` reads ``CONTACT_SKILLS_ZENOH_ENDPOINTS`` (comma-separated) and
    ``CONTACT_SKILLS_ZENOH_PREFIX``."""

    endpoints: list[str] = field(default_factory=lambda: [DEFAULT_ENDPOINT])
    """Router endpoints to connect to."""
    prefix: str = DEFAULT_PREFIX
    mode: str = "client"
    connect_timeout_s: float = 30.0
    """How long ``BusClient()`` keeps trying to reach the router before raising ``ConnectionError``, s."""
    security: BusSecurity | None = None
    """Login and TLS (None: from the environment, ``schemas.bus_security``)."""

    @classmethod
    def from_env(cls) -> BusSettings:
        return cls(
            endpoints=split_endpoints(os.environ.get(ENV_ENDPOINTS)) or [DEFAULT_ENDPOINT],
            prefix=os.environ.get(ENV_PREFIX) or DEFAULT_PREFIX,
        )


class NoWorkerAvailable(RuntimeError):  # noqa: N818 (the name is the interface)
    """No connected worker can take the job; the message says how many are connected and why none could."""


class BusRequestError(ValueError):
    """A worker refused a request as invalid (e.g. an unknown scenario or world override); the message says why."""


def open_session(
    mode: str,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    wait_s: float = 0.0,
    security: BusSecurity | None = None,
    access_control: dict[str, Any] | None = None,
):
    """Open a Zenoh session with the bus configuration (``schemas.bus.session_config``).

    ``security`` None: the login and TLS settings of the environment (``schemas.bus_security``; none: an open bus).
    A client retries for ``wait_s`` seconds while no router answers (or it refuses the login), then raises
    ``ConnectionError``.
    """
    import zenoh

    security = security if security is not None else BusSecurity.from_env()
    config = zenoh.Config.from_json5(
        json.dumps(session_config(mode, connect, listen, security, access_control))  # type: ignore[arg-type]
    )
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            if time.monotonic() >= deadline:
                where = f"connect to {connect}" if connect else f"listen on {listen}"
                raise ConnectionError(f"zenoh ({mode}) could not {where}: {exc}") from exc
            log.warning("zenoh (%s) could not connect to %s; retrying", mode, connect)
            time.sleep(0.5)


class BusClient:
    """The REST service's handle on the bus (see the module docstring for the callbacks' threading rules)."""

    def __init__(
        self,
        settings: BusSettings,
        on_status: Callable[[ExecutionStatus], None],
        on_telemetry: Callable[[TelemetryBatch], None],
        on_worker_lost: Callable[[str], None],
    ) -> None:
        self.settings = settings
        self.keys = KeyExpressions(settings.prefix)
        self._on_status = on_status
        self._on_telemetry = on_telemetry
        self._on_worker_lost = on_worker_lost
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._running: dict[str, str] = {}  # execution_id -> worker_id, started by this client, not finished
        self._rotation = itertools.count()
        self._lost_timers: dict[str, threading.Timer] = {}
        self._closed = False
        self._session = open_session(
            settings.mode, connect=settings.endpoints, wait_s=settings.connect_timeout_s, security=settings.security
        )
        try:
            s, k = self._session, self.keys
            self._subscribers = [
                s.declare_subscriber(k.status("*"), self._status_sample),
                s.declare_subscriber(k.telemetry("*"), self._telemetry_sample),
                s.liveliness().declare_subscriber(k.workers, self._liveliness_sample, history=True),
            ]
        except Exception:
            self._session.close()
            raise

    def __enter__(self) -> BusClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ workers

    def workers(self, timeout_s: float = INFO_TIMEOUT_S) -> list[WorkerInfo]:
        """The connected workers, sorted by id: each one's own ``WorkerInfo`` (activity ``unknown`` and busy if a
        live worker did not answer its info query in time)."""
        infos = {info.worker_id: info for info in self._ask_all(self.keys.info("*"), WorkerInfo, timeout_s)}
        with self._lock:
            alive = set(self._alive)
        for worker_id in alive - set(infos):
            infos[worker_id] = WorkerInfo(worker_id=worker_id, busy=True, activity="unknown")
        return [infos[w] for w in sorted(infos)]

    def latest_statuses(self, timeout_s: float = INFO_TIMEOUT_S) -> dict[str, ExecutionStatus]:
        """The latest status of every execution the connected workers ran recently (their status queryables keep
        the last ``STATUS_CACHE``), by execution id: how runs ended while this client was not listening."""
        latest: dict[str, ExecutionStatus] = {}
        for status in self._ask_all(self.keys.status("*"), ExecutionStatus, timeout_s):
            known = latest.get(status.execution_id)
            if known is None or status.seq > known.seq:
                latest[status.execution_id] = status
        return latest

    def _ask_all(self, key: str, model: type[Any], timeout_s: float) -> list[Any]:
        """Every valid reply (as ``model``) of every queryable on ``key``; bad replies are logged and skipped."""
        import zenoh

        answers = []
        for reply in self._session.get(key, timeout=timeout_s, consolidation=zenoh.ConsolidationMode.NONE):
            if reply.ok is None:
                continue
            try:
                answers.append(model.model_validate_json(reply.ok.payload.to_bytes()))
            except ValueError:
                log.warning("bad %s on %s", model.__name__, reply.ok.key_expr)
        return answers

    def _candidates(self) -> tuple[list[WorkerInfo], list[WorkerInfo]]:
        """(all workers, the free ones in the order to try: fewest executions run first, then round robin)."""
        everyone = self.workers()
        free = [w for w in everyone if not w.busy]
        if free:
            shift = next(self._rotation) % len(free)
            free = free[shift:] + free[:shift]
            free.sort(key=lambda w: w.executions_run)  # stable: the rotation breaks ties
        return everyone, free

    @staticmethod
    def _why_none(everyone: list[WorkerInfo], refused: list[str], what: str) -> NoWorkerAvailable:
        if not everyone:
            return NoWorkerAvailable(f"no worker connected: cannot {what} (start one with `contact-skills worker`)")
        states = []
        for w in everyone:
            doing = {"executing": f"executing {w.execution_id}", "recording": "recording a demonstration",
                     "unknown": "not answering"}.get(w.activity, "idle")  # fmt: skip
            states.append(f"{w.worker_id} {doing}")
        states += refused
        return NoWorkerAvailable(f"{len(everyone)} worker(s) connected, none free to {what}: " + "; ".join(states))

    # ------------------------------------------------------------------------------------------ executions

    def start_execution(
        self,
        execution_id: str,
        request: ExecutionRequest,
        *,
        world_overrides: dict[str, Any] | None = None,
        demonstration: Demonstration | None = None,
        timeout_s: float = START_TIMEOUT_S,
    ) -> str:
        """Start ``request`` (its skill INLINE) as ``execution_id`` on a free worker; return the worker's id.

        Free workers are tried in turn (fewest executions first, round robin among equals), so executions spread
        over the workers. ``world_overrides`` (WorldConfig fields) and ``demonstration`` (for the path metric)
        are optional. Raises ``ValueError`` for an id that is not a key chunk or a request without an inline
        skill, ``BusRequestError`` if the worker refuses the request as invalid, ``NoWorkerAvailable`` if no
        worker takes it.
        """
        start = StartExecution(
            execution_id=execution_id,
            request=request,
            world_overrides=world_overrides or {},
            demonstration=demonstration,
        )
        payload = start.model_dump_json()
        everyone, free = self._candidates()
        refused: list[str] = []
        for worker in free:
            reply = self._query_one(self.keys.start(worker.worker_id), payload, timeout_s)
            if reply is None:
                refused.append(f"{worker.worker_id} did not answer within {timeout_s:g} s")
                continue
            answer = StartReply.model_validate_json(reply)
            if answer.accepted:
                with self._lock:
                    self._running[execution_id] = worker.worker_id
                log.info("execution %s started on %s", execution_id, worker.worker_id)
                return worker.worker_id
            if answer.code == "error":
                raise BusRequestError(answer.reason or "refused")
            refused.append(f"{worker.worker_id} busy ({answer.reason})")
        raise self._why_none(everyone, refused, f"run execution {execution_id}")

    def send_command(self, execution_id: str, command: Literal["abort", "pause", "resume"]) -> None:
        """Publish ``command`` to the execution (fire and forget; its status tells what happened)."""
        import zenoh

        message = ExecutionCommand(command=command, execution_id=execution_id)
        self._session.put(
            self.keys.cmd(execution_id),
            message.model_dump_json(),
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.INTERACTIVE_HIGH,
            express=True,
        )

    def publish(self, key: str, payload: str) -> None:
        """Put ``payload`` (JSON) on ``key`` (reliable; e.g. a sweep's progress, ``KeyExpressions.sweep_progress``)."""
        import zenoh

        self._session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def record_demonstration(self, request: RecordRequest, timeout_s: float = 120) -> RecordReply:
        """Have a free worker record the teacher's demonstration of ``request.scenario``.

        Returns the reply: ``reply.ok`` with the demonstration and ground truth, or ``code == "error"`` with
        ``reply.error`` for a bad request (unknown scenario or override, failed recording). Raises
        ``NoWorkerAvailable`` if no worker is free, ``TimeoutError`` if the worker does not answer in time.
        """
        payload = request.model_dump_json()
        everyone, free = self._candidates()
        refused: list[str] = []
        for worker in free:
            reply = self._query_one(self.keys.record(worker.worker_id), payload, timeout_s)
            if reply is None:
                raise TimeoutError(f"worker {worker.worker_id} did not finish recording within {timeout_s:g} s")
            answer = RecordReply.model_validate_json(reply)
            if answer.code != "busy":
                return answer
            refused.append(f"{worker.worker_id} busy ({answer.error})")
        raise self._why_none(everyone, refused, f"record {request.scenario}")

    def _query_one(self, key: str, payload: str, timeout_s: float) -> bytes | None:
        """The first OK reply's payload of a query to one worker's queryable, or None (no reply, error reply)."""
        for reply in self._session.get(key, payload=payload, timeout=timeout_s):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
            log.warning("error reply on %s: %s", key, reply.err.payload.to_string() if reply.err else "?")
        return None

    # ------------------------------------------------------------------------------------------ callbacks

    def _status_sample(self, sample) -> None:
        try:
            status = ExecutionStatus.model_validate_json(sample.payload.to_bytes())
        except ValueError:
            log.warning("bad status on %s", sample.key_expr)
            return
        if status.final:
            with self._lock:
                self._running.pop(status.execution_id, None)
        self._call(self._on_status, status)

    def _telemetry_sample(self, sample) -> None:
        try:
            batch = TelemetryBatch.model_validate_json(sample.payload.to_bytes())
        except ValueError:
            log.warning("bad telemetry on %s", sample.key_expr)
            return
        self._call(self._on_telemetry, batch)

    def _liveliness_sample(self, sample) -> None:
        import zenoh

        try:
            worker_id = self.keys.worker_id_of(str(sample.key_expr))
        except ValueError:
            return
        with self._lock:
            pending = self._lost_timers.pop(worker_id, None)
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(worker_id)
            else:
                self._alive.discard(worker_id)
        if pending is not None:
            pending.cancel()
        if sample.kind == zenoh.SampleKind.PUT:
            log.info("worker %s connected%s", worker_id, " again" if pending is not None else "")
            return
        # The token goes on the control path, the worker's last statuses on the data path: give them
        # LOST_GRACE_S to arrive before failing what is still running there.
        timer = threading.Timer(LOST_GRACE_S, self._worker_lost, args=(worker_id,))
        timer.daemon = True
        with self._lock:
            self._lost_timers[worker_id] = timer
        timer.start()

    def _worker_lost(self, worker_id: str) -> None:
        with self._lock:
            if self._lost_timers.get(worker_id) is not threading.current_thread():
                return  # cancelled: the worker came back, or the client closed
            del self._lost_timers[worker_id]
            orphans = [e for e, w in self._running.items() if w == worker_id]
            for execution_id in orphans:
                del self._running[execution_id]
        log.warning("worker %s lost (%d execution(s) running on it)", worker_id, len(orphans))
        for execution_id in orphans:
            status = ExecutionStatus(
                execution_id=execution_id,
                worker_id=worker_id,
                phase=ExecutionPhase.failed,
                message=f"worker {worker_id} lost",
                error=f"worker {worker_id} lost during the execution (process ended or connection lost)",
            )
            self._call(self._on_status, status)
        self._call(self._on_worker_lost, worker_id)

    @staticmethod
    def _call(callback: Callable[[Any], None], value: Any) -> None:
        try:
            callback(value)
        except Exception:
            log.exception("bus callback %s failed", getattr(callback, "__name__", callback))

    # ------------------------------------------------------------------------------------------ close

    def close(self) -> None:
        """Undeclare the subscribers and close the session (idempotent). Callbacks stop before it returns."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            timers, self._lost_timers = list(self._lost_timers.values()), {}
        for timer in timers:
            timer.cancel()
        for subscriber in self._subscribers:
            with contextlib.suppress(Exception):
                subscriber.undeclare()
        self._session.close()
