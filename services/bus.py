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
import logging
import queue
import threading
from collections.abc import Callable

from schemas.bus import (
    ExecutionStatus,
    KeyExpressions,
    WorkerInfo,
)
from schemas.execution import TelemetryBatch
from services.bus_dispatch import BusRequestError, NoWorkerAvailable
from services.bus_relay import ReportRelay
from services.bus_reports import ReportChecks
from services.bus_session import BusSettings, observer_login, open_session
from services.dispatch_watch import DispatchWatch
from services.worker_liveness import WORKER_CHECK_S, WorkerLiveness

log = logging.getLogger("contact_skills.bus")  # rate-limited: services.bus_reports adds the filter

INBOX_CLOSE_S = 10.0
"""How long ``close`` waits for the inbox to be handled, s."""


class BusClient(ReportRelay):
    """The REST service's handle on the bus (see the module docstring for the callbacks' threading rules): its session
    and queries (``services.bus_session``), the workers and the hand-over of jobs (``services.bus_dispatch``), their
    reports relayed to the callbacks (``services.bus_relay``)."""

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


__all__ = ["BusClient", "BusRequestError", "BusSettings", "NoWorkerAvailable", "observer_login", "open_session"]
