"""The bus side of the service: the `BusClient` callbacks that write status, metrics and telemetry into the store
(:class:`BusEvents`, called from Zenoh threads), :func:`reconcile` on start, and :func:`connect_bus`."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from schemas.api import ExecutionState
from schemas.bus import ExecutionStatus
from schemas.execution import ExecutionPhase, TelemetryBatch
from services.settings import ServiceSettings
from services.store import RESTART_REASON, Store

if TYPE_CHECKING:
    from services.bus import BusClient

log = logging.getLogger("contact_skills.api")

FINAL_STATES = {
    ExecutionPhase.done: ExecutionState.done,
    ExecutionPhase.aborted: ExecutionState.aborted,
    ExecutionPhase.failed: ExecutionState.failed,
}
"""Execution status for each final phase; any other phase means running."""
WORKER_DISCOVERY_S = 2.0
"""On start, how long the API waits to see workers before reconciling executions left running."""


def _guarded(fn: Callable[..., None]) -> Callable[..., None]:
    """A bus callback never raises into the Zenoh thread: errors are logged."""

    def call(*args: Any) -> None:
        try:
            fn(*args)
        except Exception:
            log.exception("bus callback %s failed", fn.__name__)

    call.__name__ = fn.__name__
    return call


FINAL_TELEMETRY_GRACE_S = 2.0
"""How long a final status waits for the last telemetry batches (another Zenoh key, no order between them), s."""


def store_status(store: Store, status: ExecutionStatus, state: ExecutionState) -> bool:
    """Apply a worker's status to its (active) execution: state, phase, worker, metrics, error (the abort reason
    when it gives none). True if applied."""
    error = status.error
    if error is None and status.metrics is not None and status.metrics.abort_reason:
        error = status.metrics.abort_reason
    return store.update_execution(
        status.execution_id,
        status=state,
        phase=status.phase,
        worker_id=status.worker_id,
        metrics=status.metrics.model_dump(mode="json") if status.metrics is not None else None,
        error=error,
    )


class BusEvents:
    """The callbacks given to the `BusClient`: status, telemetry and lost workers go into the store.

    Status and telemetry travel on different keys, so the final status can overtake the last
    telemetry batches. A final status is therefore stored once the telemetry it counts
    (``metrics.steps``) is stored, or after :data:`FINAL_TELEMETRY_GRACE_S`: a client that sees
    ``done`` can read the whole stream.
    """

    def __init__(self, store: Store) -> None:
        self.store = store
        self.on_status = _guarded(self._status)
        self.on_telemetry = _guarded(self._telemetry)
        self.on_worker_lost = _guarded(self._worker_lost)
        self._held: dict[str, ExecutionStatus] = {}
        self._lock = threading.Lock()

    def _status(self, status: ExecutionStatus) -> None:
        row = self.store.execution(status.execution_id)
        if row is not None and row.worker_id is not None and row.worker_id != status.worker_id:
            log.warning("status of %s from %s ignored: it runs on %s", status.execution_id, status.worker_id,
                        row.worker_id)  # fmt: skip
            return
        state = FINAL_STATES.get(status.phase, ExecutionState.paused if status.paused else ExecutionState.running)
        if status.final and not self._telemetry_complete(status):
            with self._lock:
                self._held[status.execution_id] = status
            self.store.update_execution(status.execution_id, phase=status.phase, worker_id=status.worker_id)
            timer = threading.Timer(FINAL_TELEMETRY_GRACE_S, self._release, args=(status.execution_id,))
            timer.daemon = True
            timer.start()
            return
        self._store_status(status, state)

    def _store_status(self, status: ExecutionStatus, state: ExecutionState) -> None:
        store_status(self.store, status, state)

    def _telemetry_complete(self, status: ExecutionStatus) -> bool:
        if status.metrics is None:
            return True
        return self.store.telemetry_counts(status.execution_id)[1] >= status.metrics.steps

    def _release(self, execution_id: str) -> None:
        with self._lock:
            status = self._held.pop(execution_id, None)
        if status is not None:
            self._store_status(status, FINAL_STATES[status.phase])

    def _telemetry(self, batch: TelemetryBatch) -> None:
        if batch.execution_id and len(batch.t):
            self.store.add_telemetry(batch.execution_id, batch)
            with self._lock:
                held = self._held.get(batch.execution_id)
            if held is not None and self._telemetry_complete(held):
                self._release(batch.execution_id)

    def _worker_lost(self, worker_id: str) -> None:
        marked = self.store.fail_active(f"worker {worker_id} was lost while running (process gone)", worker_id)
        if marked:
            log.warning("worker %s lost: executions %s marked failed", worker_id, ", ".join(marked))


def reconcile(store: Store, bus: BusClient | None, wait_s: float = WORKER_DISCOVERY_S) -> list[str]:
    """Executions left starting/running by a previous API process: keep those a live worker reports running
    (``WorkerInfo.execution_id``; their statuses keep arriving), store the final status of those that ended while
    no API listened (the workers' status queryables keep it: a run that finished is ``done``, not failed; the
    telemetry it published meanwhile is missing, and ``ExecutionView.telemetry_missing_samples`` says how much),
    put those still being handed over back in the queue (``services.queue``), mark the rest failed
    (:data:`RESTART_REASON`). Returns the ids marked failed."""
    active = store.active_executions()
    if not active:
        return []
    running: set[str] = set()
    if bus is not None:
        wanted = {row.worker_id for row in active if row.worker_id}
        deadline = time.monotonic() + wait_s
        while True:
            infos = bus.workers()
            seen = {info.worker_id for info in infos}
            running = {info.execution_id for info in infos if info.execution_id}
            if wanted <= seen or time.monotonic() >= deadline:
                break
            time.sleep(0.1)
    ended = {} if bus is None else bus.latest_statuses()
    marked = []
    for row in active:
        if row.id in running or (row.status is ExecutionState.starting and store.requeue(row.id)):
            continue
        status = ended.get(row.id)
        if status is not None and status.final and store_status(store, status, FINAL_STATES[status.phase]):
            log.warning("execution %s ended %s while no API listened", row.id, status.phase.value)
            continue
        if store.update_execution(
            row.id, status=ExecutionState.failed, phase=ExecutionPhase.failed, error=RESTART_REASON
        ):
            marked.append(row.id)
    if marked:
        log.warning("%d executions left running by a previous API process marked failed", len(marked))
    return marked


def connect_bus(settings: ServiceSettings, store: Store) -> BusClient:
    """A `BusClient` on the settings' endpoints whose callbacks write into ``store`` (:class:`BusEvents`).

    Waits up to ``settings.connect_timeout_s`` for the router, then raises ``ConnectionError``."""
    from services.bus import BusClient, BusSettings

    events = BusEvents(store)
    bus_settings = BusSettings(
        endpoints=list(settings.zenoh_endpoints),
        prefix=settings.zenoh_prefix,
        connect_timeout_s=settings.connect_timeout_s,
    )
    return BusClient(bus_settings, events.on_status, events.on_telemetry, events.on_worker_lost)
