"""The API side of the Zenoh bus: find workers, dispatch executions and recordings, relay status and telemetry.

``BusClient`` opens one Zenoh session (client mode, connected to the router) and

- subscribes to ``P/exec/*/status`` and ``P/exec/*/telemetry`` and hands every ``ExecutionStatus`` /
  ``TelemetryBatch`` to ``on_status`` / ``on_telemetry``,
- watches the workers' liveliness tokens ``P/workers/*`` (with history, so workers already running are seen) and
  its own link to the router (Zenoh transport events), and tells a worker that is gone from a router outage:

  - a token goes while this client's link to the router stays up (the worker process ended or died, even by
    SIGKILL: the router sees its connection close and propagates the DELETE within milliseconds): after
    ``LOST_GRACE_S`` (0.25 s, for the worker's last statuses) the worker's info queryable is asked; if it does not
    answer within ``WORKER_CHECK_S`` the worker is LOST: ``on_status`` gets a synthesized ``failed`` status for
    every execution this client started (or adopted) on it that has not finished, then ``on_worker_lost``;
  - tokens that go with this client's link (the router stopped or restarted, the network between us broke: every
    token vanishes at once) are a router outage: nothing is failed. Once the link is back each such worker has
    ``WORKER_RETURN_GRACE_S`` to show its token again, else it is lost as above;
  - a worker whose token comes back after it went (either case) is asked what became of the executions it runs
    for this client (its status queryable): the latest status of each is handed to ``on_status`` as if received
    (a run that ended during the outage gets its true final status), or a ``failed`` one if the worker does not
    know the execution (it restarted). Telemetry missed meanwhile is asked again by the receiver
    (:meth:`BusClient.telemetry_replay`; ``services.bus_events`` does it);
  - a worker LOST as above whose token comes back within ``LOST_RUNS_KEPT_S`` (its own link to the router dropped;
    the process lived and went on running) is asked the same about the executions that were failed for its loss:
    the latest status of each it still knows goes to ``on_worker_back`` (the receiver withdraws the failure and
    applies the worker's true status; a run still going is followed again as before).

REPORTS: a worker's status, telemetry batch or replay counts only if it proves it comes from the worker the execution
was handed to, for the current dispatch. Each hand-over gets a fresh nonce (``StartExecution.attempt``) and a secret
bound to the execution, the chosen worker and that nonce (:meth:`.ReportChecks.execution_secret`, derived from
``BusSettings.report_key``, which the API keeps in its database so that it survives a restart), sent only to that
worker as the attachment of its start query (the router lets only that worker's login answer its start key); the
worker attaches ``schemas.bus_security.report_signature`` of every payload it sends for the execution, and echoes the
nonce and a rising ``seq`` in every status. The receiver takes a status only for an active run, on its current
attempt, above the last ``seq`` it took (``services.store.executions.ExecutionRepository.advance``), so a status
recorded off the bus and replayed later moves nothing. A worker's latest status is asked with a fresh challenge and
counts only signed with it (``schemas.bus_security.challenge_signature``): a recorded status cannot answer for a
worker that is gone. A report
whose signature does not verify (forged, or from another worker, whatever ``worker_id`` it names), or that is
implausible (negative counters, ``done`` without a control step), is dropped and logged (each kind of line at most
once per ``services.log_limits.LOG_EVERY_S``). An info reply counts only under the key of the worker it names (its own
queryable, which the router lets only that worker declare) and with plausible counters.

THREADS: the callbacks run on Zenoh's threads (``on_worker_lost`` and the synthesized or caught-up statuses on
timer threads), concurrently with each other and with the caller's threads.
They must be thread-safe and quick (store, enqueue, notify; no blocking I/O, no calls back into the client that
wait for the bus). An exception in a callback is logged and swallowed. Status and telemetry of one execution
arrive in the order the worker published them; a status may arrive before ``start_execution`` returns.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import logging
import os
import queue
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from schemas.bus import (
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    ENV_ENDPOINTS,
    ENV_PREFIX,
    REPLAY_MAX_SAMPLES,
    CommandName,
    ExecutionCommand,
    ExecutionStatus,
    KeyExpressions,
    RecordReply,
    RecordRequest,
    StartExecution,
    StartReply,
    TelemetryReplay,
    WorkerInfo,
    session_config,
    split_endpoints,
)
from schemas.bus_security import ENV_LOGINS, ENV_PASSWORD, ENV_USER, BusSecurity
from schemas.demonstration import Demonstration
from schemas.execution import ExecutionRequest, TelemetryBatch
from services.bus_keys import local_logins_folder, read_env_file
from services.bus_reports import ReportChecks, implausible_info, implausible_status, new_attempt
from services.dispatch_watch import DispatchWatch
from services.worker_liveness import WORKER_CHECK_S, WorkerLiveness

log = logging.getLogger("contact_skills.bus")  # rate-limited: services.bus_reports adds the filter

INFO_TIMEOUT_S = 2.0
"""How long ``workers()`` waits for the workers' info replies, s (they answer in about a millisecond)."""
WORKERS_FRESH_S = 0.5
"""``workers_seen()`` answers from the last info query younger than this, s; an older one is refreshed in the
background."""
START_TIMEOUT_S = 30.0
"""How long a start request waits for the chosen worker's reply, s: the worker builds the execution's world and
checks its reach (placement) before it accepts, 0.1-1.2 s on a quiet core, ten times that on a loaded one."""
REPLAY_TIMEOUT_S = 10.0
"""How long a telemetry replay waits for the worker's replies, s."""
INBOX_BYTES = 512 * 2**20
"""Telemetry received and not yet handled, at most, bytes of JSON (~850 000 samples). Zenoh's threads only put
statuses and batches in the inbox and never wait: the handling (parse, check, store: a busy database waits) is the
inbox thread's. A session that does not read its link for the lease (10 s) loses it: the API lost its link to its own
router 6 times in a 733 s fast run when its callbacks stored each batch themselves (making them wait for room instead
lost it 3 times in a 1344 s run). A batch past this is dropped, and asked again of the worker."""
INBOX_CLOSE_S = 10.0
"""How long ``close`` waits for the inbox to be handled, s."""


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
    report_key: bytes = field(default_factory=lambda: secrets.token_bytes(32))
    """The key every execution's secret is derived from (:meth:`.ReportChecks.execution_secret`): the API keeps its own
    in its database (``services.store.Store.service_key``), so the executions it adopts after a restart verify."""

    @classmethod
    def from_env(cls) -> BusSettings:
        return cls(
            endpoints=split_endpoints(os.environ.get(ENV_ENDPOINTS)) or [DEFAULT_ENDPOINT],
            prefix=os.environ.get(ENV_PREFIX) or DEFAULT_PREFIX,
        )


@dataclass(frozen=True)
class Reply:
    """One valid reply of a query: its payload as ``model``, its key, its exact bytes and its attachment."""

    value: Any
    key: str
    payload: bytes
    signature: bytes | None


def _attachment(zbytes: Any) -> bytes | None:
    return None if zbytes is None else zbytes.to_bytes()


def observer_login(endpoints: list[str]) -> dict[str, str] | None:
    """The bus's read-only ``observer`` login (``{"user": …, "password": …}``), or None: the one in the folder of
    logins ``CONTACT_SKILLS_ZENOH_LOGINS`` (docker-compose), else that of the ``contact-skills up`` of this user that
    serves one of ``endpoints`` on loopback (``services.bus_keys.local_logins_folder``)."""
    folders = [Path(os.environ[ENV_LOGINS])] if os.environ.get(ENV_LOGINS) else []
    for endpoint in endpoints:
        protocol, _, address = endpoint.partition("/")
        host, _, port = address.rpartition(":")
        if protocol == "tcp" and host in ("127.0.0.1", "localhost") and port.isdigit():
            folders.append(local_logins_folder(int(port)))
    for folder in folders:
        login = folder / "observer.env"
        if login.is_file():
            values = read_env_file(login)
            return {"user": values[ENV_USER], "password": values[ENV_PASSWORD]}
    return None


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

    if security is None:
        logins = os.environ.get(ENV_LOGINS)  # docker-compose: the API's login in its folder of logins
        api_env = Path(logins or ".") / "api.env"
        api_login = read_env_file(api_env) if logins and mode == "client" and api_env.is_file() else {}
        security = BusSecurity.from_env({**os.environ, **api_login})
    if mode == "client" and security.user is None and (observer := observer_login(connect or [])):
        security = replace(security, **observer)  # how `watch`, `live()` and this user's sessions read the bus
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
                within = f" within {wait_s:g} s" if wait_s else ""
                raise ConnectionError(f"zenoh ({mode}) could not {where}{within}: {_reason(exc)}") from exc
            log.warning("zenoh (%s) could not connect to %s; retrying", mode, connect)
            time.sleep(0.5)


def _reason(error: Exception) -> str:
    """A Zenoh error's message without the Rust source location it ends with (`` at /root/.cargo/...rs:388.``), which
    says nothing to a user."""
    return re.sub(r"\s+at \S+\.rs:\d+\.?$", "", str(error).strip())


class BusClient:
    """The REST service's handle on the bus (see the module docstring for the callbacks' threading rules)."""

    def __init__(
        self,
        settings: BusSettings,
        on_status: Callable[[ExecutionStatus], None],
        on_telemetry: Callable[[TelemetryBatch], None],
        on_worker_lost: Callable[[str], None],
        on_worker_back: Callable[[ExecutionStatus], None] | None = None,
        owner: Callable[[str], tuple[str, str] | None] | None = None,
    ) -> None:
        """``owner``: the (worker, dispatch attempt) an execution this client does not remember was handed to (the
        store's record), for the reports of executions started by a previous API process."""
        self.settings = settings
        self.keys = KeyExpressions(settings.prefix)
        self.reports = ReportChecks(settings.report_key, self.keys, owner)
        self.watch = DispatchWatch()
        """What this client saw of its dispatches and of each worker (the dispatch watchdog's, the worker order's)."""
        self._on_status = on_status
        self._on_telemetry = on_telemetry
        self._lock = threading.Lock()
        self._rotation = itertools.count()
        self._seen: tuple[float, dict[str, WorkerInfo]] | None = None  # (time.monotonic(), the last info replies)
        self._refreshing = False
        self._refresh_again = False  # asked to refresh while a refresh ran: run it once more
        self.liveness = WorkerLiveness(
            answering=lambda worker_id: bool(self._ask_all(self.keys.info(worker_id), WorkerInfo, WORKER_CHECK_S)),
            latest_status=self.latest_status,
            report=functools.partial(self._call, on_status),
            on_worker_lost=on_worker_lost,
            on_worker_back=on_worker_back,
        )
        self._closed = False
        self._inbox: queue.Queue = queue.Queue()
        self._inbox_bytes = 0  # telemetry bytes in the inbox (statuses are few and always kept)
        self._drainer = threading.Thread(target=self._drain_inbox, name="bus-inbox", daemon=True)
        self._drainer.start()
        self._session = open_session(
            settings.mode, connect=settings.endpoints, wait_s=settings.connect_timeout_s, security=settings.security
        )
        try:
            s, k = self._session, self.keys
            self._subscribers = [
                s.info.declare_transport_events_listener(self._transport_event, history=False),
                s.declare_subscriber(k.status("*"), self._status_sample),
                s.declare_subscriber(k.telemetry("*"), self._telemetry_sample),
                s.liveliness().declare_subscriber(k.workers, self._liveliness_sample, history=True),
            ]
            self.liveness.link(bool(list(s.info.routers_zid())), initial=True)
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
        infos: dict[str, WorkerInfo] = {}
        for reply in self._ask_all(self.keys.info("*"), WorkerInfo, timeout_s):
            if why := implausible_info(reply.value, reply.key, self.keys):
                log.warning("worker info refused: %s", why)
            else:
                infos[reply.value.worker_id] = reply.value
        alive = self.liveness.alive()
        with self._lock:
            self._seen = (time.monotonic(), dict(infos))
        for worker_id in alive - set(infos):
            infos[worker_id] = WorkerInfo(worker_id=worker_id, busy=True, activity="unknown")
        return [infos[w] for w in sorted(infos)]

    def workers_seen(self) -> list[WorkerInfo]:
        """The connected workers without waiting on the bus (for ``GET /health``, which must answer at once on a
        loaded machine, where a query waits for every worker process to be scheduled): the workers whose liveliness
        tokens are present now, each with the info of the last query (at most about :data:`WORKERS_FRESH_S` old;
        an older one is refreshed in the background; ``unknown`` for a worker that query did not see). The first
        call waits for a query."""
        with self._lock:
            seen, alive = self._seen, self.liveness.alive()
        if seen is None:
            return self.workers()
        if time.monotonic() - seen[0] > WORKERS_FRESH_S:
            self._refresh_in_background()
        unknown = WorkerInfo(worker_id="?", busy=True, activity="unknown")
        return [seen[1].get(w) or unknown.model_copy(update={"worker_id": w}) for w in sorted(alive)]

    def seen_age(self) -> float | None:
        """How old the workers' answers :meth:`workers_seen` gives are, s (None: none asked yet)."""
        with self._lock:
            seen = self._seen
        return None if seen is None else time.monotonic() - seen[0]

    def _refresh_in_background(self) -> None:
        """Ask the workers' info on a thread of its own (one at a time) for :meth:`workers_seen`. Asked while one
        runs, it runs once more after it: a worker whose token arrived while a query was out was not asked by it
        (its answer would show it ``unknown`` until the next)."""
        with self._lock:
            if self._closed:
                return
            if self._refreshing:
                self._refresh_again = True
                return
            self._refreshing = True
        threading.Thread(target=self._refresh_seen, name="workers-refresh", daemon=True).start()

    def _refresh_seen(self) -> None:
        again = True
        while again:
            with self._lock:
                self._refresh_again = False
            try:
                self.workers()
            except Exception:  # the session closed meanwhile
                log.debug("refreshing the workers' info failed", exc_info=True)
            with self._lock:
                again = self._refresh_again and not self._closed
                self._refreshing = again

    def latest_statuses(self, timeout_s: float = INFO_TIMEOUT_S) -> dict[str, ExecutionStatus]:
        """The latest status of every execution the connected workers ran recently (their status queryables keep
        the last ``STATUS_CACHE``), by execution id: how runs ended while this client was not listening."""
        latest: dict[str, ExecutionStatus] = {}
        challenge = secrets.token_bytes(16)
        for reply in self._ask_all(self.keys.status("*"), ExecutionStatus, timeout_s, challenge):
            status = reply.value
            if not self._answers_now(reply, challenge):
                continue
            known = latest.get(status.execution_id)
            if known is None or status.seq > known.seq:
                latest[status.execution_id] = status
        return latest

    def latest_status(
        self, worker_id: str, execution_id: str, timeout_s: float = INFO_TIMEOUT_S
    ) -> ExecutionStatus | None:
        """The latest status of ``execution_id`` that ``worker_id`` reports now (its status queryable, asked with a
        fresh challenge), or None if it does not know the execution (it never ran it, restarted, or forgot it among
        more recent ones) or does not answer."""
        challenge = secrets.token_bytes(16)
        replies = self._ask_all(self.keys.status(execution_id), ExecutionStatus, timeout_s, challenge)
        statuses = [r.value for r in replies if r.value.worker_id == worker_id and r.value.execution_id == execution_id
                    and self._answers_now(r, challenge)]  # fmt: skip
        return max(statuses, key=lambda s: s.seq, default=None)

    def _answers_now(self, reply: Reply, challenge: bytes) -> bool:
        """Whether a status reply to a query that carried ``challenge`` comes from the worker of the execution's
        current attempt, signed with the challenge, and is plausible (refusals logged)."""
        status = reply.value
        if not self.reports.answers_now(status, reply.payload, reply.signature, challenge):
            log.warning("status of %s naming %s not signed with this query's challenge: refused",
                        status.execution_id, status.worker_id)  # fmt: skip
            return False
        if why := implausible_status(status):
            log.warning("status of %s from %s refused: %s", status.execution_id, status.worker_id, why)
            return False
        return True

    def telemetry_replay(
        self, worker_id: str, execution_id: str, start: int, stop: int, timeout_s: float = REPLAY_TIMEOUT_S
    ) -> list[TelemetryBatch]:
        """The samples ``start`` to ``stop - 1`` of an execution's telemetry, asked again of the worker that ran it
        (``P/exec/{worker_id}/replay``, :data:`REPLAY_MAX_SAMPLES` at a time, each ask waiting up to ``timeout_s``): the
        batches it still keeps of them (none if it is gone or dropped them)."""
        batches = []
        for first in range(start, stop, REPLAY_MAX_SAMPLES):
            batches += self._replay_part(
                worker_id, execution_id, first, min(first + REPLAY_MAX_SAMPLES, stop), timeout_s
            )
        return batches

    def _replay_part(
        self, worker_id: str, execution_id: str, start: int, stop: int, timeout_s: float
    ) -> list[TelemetryBatch]:
        ask = TelemetryReplay(execution_id=execution_id, start=start, stop=stop).model_dump_json()
        import zenoh

        batches = []
        replies = self._session.get(
            self.keys.replay(worker_id), payload=ask, timeout=timeout_s, consolidation=zenoh.ConsolidationMode.NONE
        )  # every reply has the same key
        for reply in replies:
            if reply.ok is None:
                log.warning("replay of %s [%d, %d) from %s: %s", execution_id, start, stop, worker_id,
                            reply.err.payload.to_string() if reply.err else "no reply")  # fmt: skip
                continue
            payload = reply.ok.payload.to_bytes()
            try:
                batch = TelemetryBatch.model_validate_json(payload)
            except ValueError:
                log.warning("bad replayed telemetry from %s", worker_id)
                continue
            if not self.reports.signed_by(execution_id, worker_id, payload, _attachment(reply.ok.attachment)):
                log.warning("replayed telemetry of %s not signed by %s: refused", execution_id,
                                      worker_id)  # fmt: skip
                continue
            if batch.execution_id == execution_id and batch.first_sample is not None and batch.first_sample >= 0:
                batches.append(batch)
        return batches

    def adopt(self, execution_id: str, worker_id: str, attempt: str) -> None:
        """Watch an execution this client did not start (a previous API process did, as dispatch ``attempt``) as its
        own: it is failed if its worker is lost, caught up on if the worker comes back from an outage, taken back if
        its worker goes silent."""
        self.liveness.running(execution_id, worker_id)
        self.reports.hand(execution_id, worker_id, attempt)
        self.watch.handed(execution_id, worker_id, attempt)

    # ------------------------------------------------------------------------------------------ reports

    def deliver(self, status: ExecutionStatus) -> None:
        """Hand ``status`` to ``on_status`` as if it had just been received (one the subscriber missed)."""
        if status.final:
            self.liveness.finished(status.execution_id)
            self.watch.ended(status.execution_id)
        self._call(self._on_status, status)

    def _ask_all(self, key: str, model: type[Any], timeout_s: float, payload: bytes | None = None) -> list[Reply]:
        """Every valid reply (its payload as ``model``) of every queryable on ``key`` to a query carrying
        ``payload``; bad replies are logged and skipped."""
        import zenoh

        answers = []
        replies = self._session.get(key, payload=payload, timeout=timeout_s, consolidation=zenoh.ConsolidationMode.NONE)
        for reply in replies:
            if reply.ok is None:
                continue
            payload = reply.ok.payload.to_bytes()
            try:
                value = model.model_validate_json(payload)
            except ValueError:
                log.warning("bad %s on %s", model.__name__, reply.ok.key_expr)
                continue
            answers.append(Reply(value, str(reply.ok.key_expr), payload, _attachment(reply.ok.attachment)))
        return answers

    def _candidates(self, everyone: list[WorkerInfo] | None = None) -> tuple[list[WorkerInfo], list[WorkerInfo]]:
        """(all workers, the free ones in the order to try: by what this client saw of them,
        :meth:`.DispatchWatch.order` (those that let a dispatch time out last, then the fewest dispatches), round robin
        among equals; never by what a worker says it ran); ``everyone``: the workers' info just asked for (else asked
        now)."""
        everyone = self.workers() if everyone is None else everyone
        free = [w for w in everyone if not w.busy]
        if free:
            shift = next(self._rotation) % len(free)
            free = free[shift:] + free[:shift]
            free.sort(key=lambda w: self.watch.order(w.worker_id))  # stable: the rotation breaks ties
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
        demonstration_id: str | None = None,
        timeout_s: float = START_TIMEOUT_S,
        workers: list[WorkerInfo] | None = None,
        attempt: str | None = None,
    ) -> str:
        """Start ``request`` (its skill INLINE) as ``execution_id`` on a free worker; return the worker's id.

        Free workers are tried in turn (:meth:`_candidates`), so executions spread over the workers. ``attempt``: the
        dispatch's nonce (``StartExecution.attempt``; None: a fresh one), which the caller stored before asking (the
        worker's first statuses may come before its reply). ``world_overrides`` (WorldConfig fields) and
        ``demonstration`` (for the path metric) are optional. With ``demonstration_id`` (the stored id of
        ``demonstration``) each worker is first asked to use its own copy, and sent the demonstration only when it
        keeps none (``need_demonstration``).
        ``workers``: the result of a :meth:`workers` call the caller just made (not asked again).
        Raises ``ValueError`` for an id that is not a key chunk or a request without an inline skill,
        ``BusRequestError`` if the worker refuses the request as invalid, ``NoWorkerAvailable`` if no worker
        takes it.
        """
        named = demonstration_id if demonstration is not None else None
        attempt = attempt or new_attempt()
        start = StartExecution(
            execution_id=execution_id,
            attempt=attempt,
            request=request,
            world_overrides=world_overrides or {},
            demonstration=None if named else demonstration,
            demonstration_id=named,
        )
        everyone, free = self._candidates(workers)
        refused: list[str] = []
        for worker in free:
            key, secret = (
                self.keys.start(worker.worker_id),
                self.reports.execution_secret(execution_id, worker.worker_id, attempt),
            )
            self.reports.hand(execution_id, worker.worker_id, attempt)  # its first statuses may come before its reply
            answer = self._ask_start(key, start, secret, timeout_s)
            if answer is not None and answer.code == "need_demonstration":
                with_demonstration = start.model_copy(update={"demonstration": demonstration})
                answer = self._ask_start(key, with_demonstration, secret, timeout_s)
            if answer is None:
                refused.append(f"{worker.worker_id} did not answer within {timeout_s:g} s")
                continue
            if answer.accepted:
                self.liveness.running(execution_id, worker.worker_id)
                self.watch.handed(execution_id, worker.worker_id, attempt)
                log.info("execution %s started on %s", execution_id, worker.worker_id)
                return worker.worker_id
            if answer.code == "error":
                raise BusRequestError(answer.reason or "refused")
            refused.append(f"{worker.worker_id} busy ({answer.reason})")
        raise self._why_none(everyone, refused, f"run execution {execution_id}")

    def _ask_start(self, key: str, start: StartExecution, secret: bytes, timeout_s: float) -> StartReply | None:
        """One worker's reply to ``start`` (None if none came within ``timeout_s``), the execution's ``secret`` for
        that worker attached. Each ask carries its own deadline: a worker that could only answer after it refuses,
        so a request given up on here (and offered to the next worker) never runs twice."""
        start.answer_by_unix_s = time.time() + timeout_s
        reply = self._query_one(key, start.model_dump_json(), timeout_s, attachment=secret)
        return None if reply is None else StartReply.model_validate_json(reply)

    def send_command(self, execution_id: str, command: CommandName, reason: str | None = None) -> None:
        """Publish ``command`` to the execution (fire and forget; its status tells what happened); ``reason``: what
        an abort's final status says (default: aborted on request)."""
        import zenoh

        message = ExecutionCommand(command=command, execution_id=execution_id, reason=reason)
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

    def _query_one(self, key: str, payload: str, timeout_s: float, attachment: bytes | None = None) -> bytes | None:
        """The first OK reply's payload of a query to one worker's queryable, or None (no reply, error reply)."""
        for reply in self._session.get(key, payload=payload, timeout=timeout_s, attachment=attachment):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
            log.warning("error reply on %s: %s", key, reply.err.payload.to_string() if reply.err else "?")
        return None

    # ------------------------------------------------------------------------------------------ callbacks

    def _status_sample(self, sample) -> None:
        """Zenoh's thread: hand the status to the inbox thread (never dropped; waits if the inbox is full)."""
        self._inbox.put((self._status_received, sample.payload.to_bytes(), str(sample.key_expr),
                         _attachment(sample.attachment)))  # fmt: skip

    def _telemetry_sample(self, sample) -> None:
        """Zenoh's thread: hand the batch to the inbox thread, never waiting: past :data:`INBOX_BYTES` it is dropped
        (the receiver sees the gap in ``first_sample`` and asks the worker for it again)."""
        item = (
            self._telemetry_received,
            sample.payload.to_bytes(),
            str(sample.key_expr),
            _attachment(sample.attachment),
        )
        with self._lock:
            full = self._inbox_bytes + len(item[1]) > INBOX_BYTES
            self._inbox_bytes += 0 if full else len(item[1])
        if full:
            log.warning("bus inbox full (%d MB): a telemetry batch dropped, to be asked again", INBOX_BYTES >> 20)
        else:
            self._inbox.put(item)

    def _drain_inbox(self) -> None:
        """The inbox thread: check and deliver each status and telemetry batch in the order they arrived."""
        while (item := self._inbox.get()) is not None:
            handle, *received = item
            try:
                handle(*received)
            except Exception:
                log.exception("handling a message from the bus failed")
            if handle == self._telemetry_received:
                with self._lock:
                    self._inbox_bytes -= len(received[0])

    def _status_received(self, payload: bytes, key: str, signature: bytes | None) -> None:
        try:
            status = ExecutionStatus.model_validate_json(payload)
        except ValueError:
            log.warning("bad status on %s", key)
            return
        if key == self.keys.status(status.execution_id) and self.reports.status_trusted(status, payload, signature):
            self.watch.heard(status.execution_id, status.worker_id)
            self.deliver(status)

    def _telemetry_received(self, payload: bytes, key: str, signature: bytes | None) -> None:
        try:
            batch = TelemetryBatch.model_validate_json(payload)
        except ValueError:
            log.warning("bad telemetry on %s", key)
            return
        if self.reports.telemetry_trusted(batch, key, payload, signature):
            self.watch.heard(batch.execution_id, self.reports.owner(batch.execution_id) or "")
            self._call(self._on_telemetry, batch)

    def _transport_event(self, event) -> None:
        """This client's link to a router went or came back."""
        import zenoh

        if event.transport.whatami != zenoh.WhatAmI.ROUTER:
            return
        self.liveness.link(event.kind == zenoh.SampleKind.PUT)

    def _liveliness_sample(self, sample) -> None:
        import zenoh

        try:
            worker_id = self.keys.worker_id_of(str(sample.key_expr))
        except ValueError:
            return
        present = sample.kind == zenoh.SampleKind.PUT
        self.liveness.token(worker_id, present)
        if present:  # ask the newcomer at once: `workers_seen` shows it as it is, not `unknown` until the next ask
            self._refresh_in_background()

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
        self.liveness.close()
        for subscriber in self._subscribers:
            with contextlib.suppress(Exception):
                subscriber.undeclare()
        self._session.close()
        self._inbox.put(None)
        self._drainer.join(INBOX_CLOSE_S)
