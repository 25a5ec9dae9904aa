"""The execution queue: executions wait for a free sim worker, in the database, in priority order.

``POST /executions`` and the sweeps (``services/sweeps.py``, at a lower priority) call :meth:`ExecutionQueue.submit`
with what to send to a worker (:class:`Dispatch`: the request with its skill inline, the world overrides, the
demonstration's id), the request as it is shown back, and a priority. The execution is stored in status ``queued``
with its dispatch JSON (so the queue survives an API restart) and handed to a free worker at once when nothing waits
before it; else the dispatcher thread hands it over as soon as one is free.

Order: higher ``priority`` first, then submission order. Fairness across workers: each hand-over goes through
`services.bus.BusClient.start_execution`, which tries the free workers by what the API saw of them (those that let
a dispatch time out last, then the fewest dispatches; round robin among equals), so every worker on the bus gets
work. A queued execution can be cancelled
(:meth:`ExecutionQueue.cancel`: status aborted). The dispatcher wakes at once on :meth:`ExecutionQueue.wake`: a
submission, and an execution the store put in a terminal status (`services.store.Store.on_finish`: its final status
arrived, its worker was lost), so a worker that finished gets the next queued execution without waiting for a poll;
it also polls the workers every ``poll_s`` while something is queued (a worker freed without a status, e.g. one
that finished recording).

Status flow: queued -> starting (claimed by the dispatcher, atomically in SQLite, with a fresh dispatch nonce:
``StartExecution.attempt``) -> running (a worker accepted it), or back to queued (every worker busy after all), or
failed (the worker refused it as invalid), or aborted (cancelled while queued).

The dispatch watchdog (every pass of the dispatcher, at least every :data:`IDLE_POLL_S`): a worker that accepted an
execution and sent no report on it (a status, a heartbeat, a telemetry batch that passed the checks) within
``first_report_s`` loses it: the execution is aborted on the bus (a slow worker stops) and put back in the queue in
its place, for another dispatch (another nonce: nothing the first worker sends counts any more), at most
``handovers`` times, then failed with a reason naming the worker. An execution whose worker goes silent for
``silence_s`` mid-run is failed with a reason naming the worker. Either way the worker goes to the back of the
workers tried (``services.dispatch_watch``).

An execution left ``starting`` by an API that died is put back in the queue on restart unless a worker reports
running it (`services.bus_events.reconcile`).
"""

from __future__ import annotations

import json
import logging
import threading
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

from pydantic import JsonValue

from schemas.api import ExecutionState
from schemas.bus import CommandName
from schemas.demonstration import Demonstration
from schemas.execution import ExecutionPhase, ExecutionRequest
from schemas.world import WorldOverrides
from services.background import WakeableThread
from services.bus_reports import new_attempt
from services.dispatch_watch import Overdue
from services.settings import DEFAULT_DISPATCH_REPORT_S, DEFAULT_RUN_SILENCE_S
from services.store import ExecutionRow, Store

if TYPE_CHECKING:
    from services.bus import BusClient

log = logging.getLogger("contact_skills.queue")

DISPATCH_POLL_S = 0.2
"""How often the dispatcher asks the workers whether one is free while executions are queued, s."""
IDLE_POLL_S = 1.0
"""How often the dispatcher looks at an empty queue (it is woken on every submission anyway) and the dispatch
watchdog at the executions handed over, s."""
DEFAULT_MAX_QUEUED = 1000
"""Most executions waiting at once (more get 503)."""
DEMONSTRATIONS_KEPT = 8
"""Demonstrations the queue keeps parsed, to send along with the executions of the skills learned from them."""


@dataclass(frozen=True)
class Dispatch:
    """What the queue sends to a worker for one execution; stored as JSON while it waits."""

    request: ExecutionRequest
    """The request with its skill inline (``skill_id`` resolved)."""
    world_overrides: WorldOverrides
    """WorldConfig fields on top of the scenario's world (the world the skill was taught in)."""
    demonstration_id: str | None = None
    """The stored demonstration the skill was learned from (for the path metric), if any."""

    def to_json(self) -> str:
        return json.dumps(
            {
                "request": json.loads(self.request.model_dump_json()),
                "world_overrides": self.world_overrides,
                "demonstration_id": self.demonstration_id,
            }
        )

    @classmethod
    def from_json(cls, text: str) -> Dispatch:
        data = json.loads(text)
        return cls(ExecutionRequest.model_validate(data["request"]), data["world_overrides"], data["demonstration_id"])


class Handover(Enum):
    """What happened when the queue tried to hand an execution to a worker."""

    started = "started"
    busy = "busy"
    """Every worker was busy: back in the queue, in its place."""
    refused = "refused"
    """A worker refused it as invalid (unknown scenario, bad world override)."""
    gone = "gone"
    """It was no longer queued (cancelled meanwhile)."""


class ExecutionQueue(WakeableThread):
    """The queue over ``store`` and ``bus`` (see the module docstring). ``start()`` the dispatcher, ``close()`` it
    (queued executions stay queued in the database)."""

    thread_name = "execution-queue"

    def __init__(
        self,
        store: Store,
        bus: BusClient,
        max_queued: int = DEFAULT_MAX_QUEUED,
        poll_s: float = DISPATCH_POLL_S,
        first_report_s: float = DEFAULT_DISPATCH_REPORT_S,
        silence_s: float = DEFAULT_RUN_SILENCE_S,
        handovers: int = 3,
        quota_bytes: int = 0,
    ) -> None:
        """``first_report_s``, ``silence_s``, ``handovers``: the dispatch watchdog's (module docstring; the
        service's ``dispatch_report_s``, ``run_silence_s``, ``dispatch_handovers``); ``quota_bytes``: the storage
        quota each submission's telemetry is reserved in (0: none)."""
        super().__init__()
        self.store = store
        self.bus = bus
        self.max_queued = max_queued
        self.quota_bytes = quota_bytes
        self.poll_s = poll_s
        self.first_report_s = first_report_s
        self.silence_s = silence_s
        self.handovers = handovers
        self._lock = threading.Lock()  # one hand-over at a time: the order of the queue is the order of starts
        self._demonstrations: dict[str, Demonstration | None] = {}  # by id, the oldest first (hold self._lock)
        store.executions.on_finish(self._finished)

    # ------------------------------------------------------------------ what the service calls

    def submit(
        self, dispatch: Dispatch, shown_request: dict[str, JsonValue], skill_id: str | None, priority: int = 0
    ) -> tuple[ExecutionRow, int | None]:
        """Queue an execution and hand it to a free worker at once if nothing waits before it.

        Its estimated telemetry (``skills.job_estimate.stored_telemetry_bytes``) is reserved in the storage quota
        until it ends. Returns its row (status running, or queued when every worker is busy) and its queue
        position. Raises `services.bus.NoWorkerAvailable` when no worker is connected at all (nothing stored),
        `services.store.QueueFull`, `services.store.QuotaFull` when its telemetry does not fit beside what is stored
        and reserved, or `services.bus.BusRequestError` when the worker refused it as invalid (nothing stored)."""
        from services.bus import BusRequestError, NoWorkerAvailable
        from skills.job_estimate import stored_telemetry_bytes

        if not self.bus.workers():
            raise NoWorkerAvailable("no worker connected: cannot run executions (start one: contact-skills worker)")
        assert dispatch.request.skill is not None  # the dispatch carries the skill inline
        row = self.store.executions.add(
            shown_request, skill_id, dispatch.to_json(), priority, self.max_queued,
            stored_telemetry_bytes(dispatch.request.skill, dispatch.request), self.quota_bytes,
        )  # fmt: skip
        with self._lock:
            if self.store.executions.queue_position(row.id) == 0:
                outcome, reason = self._hand_over(row.id, dispatch)
                if outcome is Handover.refused:
                    self.store.executions.delete(row.id)
                    raise BusRequestError(reason)
            found, position = self.store.executions.get(row.id), self.store.executions.queue_position(row.id)
        self.wake()
        return found or row, position

    def cancel(self, execution_id: str, reason: str = "cancelled while queued") -> bool:
        """Take a queued execution out of the queue (status aborted with ``reason``); False if it was not queued."""
        with self._lock:
            return self.store.executions.cancel_queued(execution_id, reason)

    def position(self, execution_id: str) -> int | None:
        """0 for the next one to start, None for one not queued."""
        return self.store.executions.queue_position(execution_id)

    def forget_demonstration(self, demonstration_id: str) -> None:
        """Drop the parsed copy of a demonstration that was deleted: the executions handed over from now on run
        without it."""
        with self._lock:
            self._demonstrations.pop(demonstration_id, None)

    def _finished(self, execution_id: str) -> None:
        """An execution ended: nothing more is due from its worker, which is free: hand the next one over now."""
        self.bus.watch.ended(execution_id)
        self.wake()

    # ------------------------------------------------------------------ the dispatcher

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._watch()
                waiting = self._drain()
            except Exception:  # keep the dispatcher alive whatever one hand-over does
                log.exception("the execution queue failed to dispatch")
                waiting = True
            self._wake.wait(self.poll_s if waiting else IDLE_POLL_S)
            self._wake.clear()

    def _drain(self) -> bool:
        """Hand queued executions to free workers until the queue is empty or every worker is busy; returns
        whether executions are still waiting."""
        while not self._stop.is_set():
            with self._lock:
                heads = self.store.executions.queued(limit=1)
                if not heads:
                    return False
                row, dispatch_json = heads[0]
                outcome, reason = self._hand_over(row.id, Dispatch.from_json(dispatch_json))
            if outcome is Handover.busy:
                return True
            if outcome is Handover.refused:
                self.store.executions.update(
                    row.id, ExecutionState.failed, ExecutionPhase.failed, error=f"the worker refused it: {reason}"
                )
        return True

    def _watch(self) -> None:
        """The dispatch watchdog (module docstring): take back what workers that do not report hold."""
        for late in self.bus.watch.overdue(self.first_report_s, self.silence_s):
            self._take_back(late)

    def _take_back(self, late: Overdue) -> None:
        worker, waited = late.worker_id, f"{late.silent_s:.0f} s"
        if late.heard:
            reason = (
                f"worker {worker} sent no report for {waited} mid-run (more than run_silence_s, {self.silence_s:g} s)"
            )
            handovers = 0  # what it ran so far is lost with it: failed, not started again
        else:
            reason = (f"worker {worker} accepted it and sent no report for {waited} (more than dispatch_report_s, "
                      f"{self.first_report_s:g} s)")  # fmt: skip
            handovers = self.handovers
        self.bus.watch.ended(late.execution_id)
        self.bus.watch.timed_out(worker)
        with self._lock:
            row = self.store.executions.get(late.execution_id)
            if row is None or row.attempt != late.attempt:
                return
            if row.handovers >= handovers and not late.heard:
                reason += f"; handed over {row.handovers} times, the last to {worker}"
            # a slow worker stops, a silent one never minds
            self.bus.send_command(late.execution_id, CommandName.abort, reason)
            state = self.store.executions.take_back(late.execution_id, late.attempt, handovers, reason)
        if state is not None:
            log.warning("execution %s %s: %s", late.execution_id,
                        "back in the queue" if state is ExecutionState.queued else "failed", reason)  # fmt: skip
            self.wake()

    def _demonstration(self, demonstration_id: str) -> Demonstration | None:
        """The stored demonstration, read once: a sweep sends the same one with each of its trials (a 10 s
        recording is ~2 MB of JSON, ~40 ms to read and parse), and a stored demonstration never changes."""
        if demonstration_id not in self._demonstrations:
            if len(self._demonstrations) >= DEMONSTRATIONS_KEPT:
                self._demonstrations.pop(next(iter(self._demonstrations)))
            self._demonstrations[demonstration_id] = self.store.demonstrations.get(demonstration_id)
        return self._demonstrations[demonstration_id]

    def _hand_over(self, execution_id: str, dispatch: Dispatch) -> tuple[Handover, str]:
        """Claim a queued execution and start it on a free worker (hold ``self._lock``)."""
        from services.bus import BusRequestError, NoWorkerAvailable

        workers = self.bus.workers()
        if all(worker.busy for worker in workers):  # checked first: a queued one stays queued meanwhile
            return Handover.busy, "every worker busy"
        attempt = new_attempt()
        if not self.store.executions.claim_queued(execution_id, attempt):
            return Handover.gone, "not queued"
        demonstration = None if dispatch.demonstration_id is None else self._demonstration(dispatch.demonstration_id)
        try:
            worker_id = self.bus.start_execution(
                execution_id,
                dispatch.request,
                world_overrides=dispatch.world_overrides,
                demonstration=demonstration,
                demonstration_id=dispatch.demonstration_id,
                workers=workers,
                attempt=attempt,
            )
        except NoWorkerAvailable:
            self.store.executions.requeue(execution_id)
            return Handover.busy, "every worker busy"
        except BusRequestError as exc:
            return Handover.refused, str(exc)
        except Exception as exc:  # the bus failed: keep it queued and try again later
            log.exception("handing %s to a worker failed", execution_id)
            self.store.executions.requeue(execution_id)
            return Handover.busy, f"{type(exc).__name__}: {exc}"
        self.store.executions.mark_started(execution_id, worker_id)
        log.info("execution %s started on %s", execution_id, worker_id)
        return Handover.started, worker_id
