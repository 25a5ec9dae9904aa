"""The bus side of the service: the `BusClient` callbacks that write status, metrics and telemetry into the store
(:class:`BusEvents`, called from Zenoh threads), :func:`reconcile` on start, and :func:`connect_bus`."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from schemas.api import ExecutionState
from schemas.bus import CommandName, ExecutionStatus
from schemas.execution import ExecutionPhase, TelemetryBatch
from services.settings import ServiceSettings
from services.store import RESTART_REASON, DiskFull, Store

if TYPE_CHECKING:
    from services.bus import BusClient

log = logging.getLogger("contact_skills.api")

FINAL_STATES = {
    ExecutionPhase.done: ExecutionState.done,
    ExecutionPhase.aborted: ExecutionState.aborted,
    ExecutionPhase.failed: ExecutionState.failed,
}
"""Execution status for each final phase; any other phase means running."""
REPORT_KEY_NAME = "bus-reports"
"""The database's key every execution's secret is derived from (``services.bus.BusSettings.report_key``)."""
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


FINAL_TELEMETRY_GRACE_S = 1.0
"""How long a final status waits for the last telemetry batches (another Zenoh key, no order between them) before
what is still missing is asked again of the worker, s."""


@dataclass
class Unstored:
    """The telemetry of a run that the store could not take (its disk is full): the run is failed and aborted."""

    disk: str
    """What the store said (``services.store.DiskFull``: the disk, its free space)."""
    first: int
    """The stream index of the first sample not stored."""
    lost: int
    """Samples received and not stored so far."""

    def reason(self, total: int | None = None) -> str:
        """The run's error: the disk, and how many samples were not stored (of ``total``, once its worker said)."""
        lost = f"{self.lost:,} of its {total:,}" if total is not None else f"{self.lost:,}"
        return (f"{self.disk}: {lost} telemetry samples were not stored (from sample {self.first:,} on); the run "
                "was aborted")  # fmt: skip


def store_status(store: Store, status: ExecutionStatus, state: ExecutionState) -> bool:
    """Apply a worker's status to its (active) execution: state, phase, worker, metrics, error (the abort reason
    when it gives none). True if applied."""
    error = status.error
    if error is None and status.metrics is not None and status.metrics.abort_reason:
        error = status.metrics.abort_reason
    return store.executions.update(
        status.execution_id,
        status=state,
        phase=status.phase,
        worker_id=status.worker_id,
        metrics=status.metrics,
        error=error,
        work_piece=status.work_piece,
    )


class BusEvents:
    """The callbacks given to the `BusClient`: status, telemetry and lost workers go into the store.

    Nothing lost: every telemetry batch on the bus says where it starts in the execution's stream
    (``TelemetryBatch.first_sample``). A batch that starts past the samples received so far (this process came up
    mid-run, or the router was down) shows a gap, and a repair thread asks the worker that runs the execution for
    the missing samples again (``BusClient.telemetry_replay``); the store keeps each sample once whichever way it
    came (`services.store.Store.add_telemetry`).

    Status and telemetry travel on different keys, so the final status can overtake the last telemetry batches. A
    final status is therefore stored once the telemetry it counts (``metrics.steps``) is stored, or, after
    :data:`FINAL_TELEMETRY_GRACE_S`, once what is still missing has been asked again: a client that sees ``done``
    can read the whole stream, or ``ExecutionView.telemetry_missing_samples`` says how much of it is lost for good
    (the worker is gone or no longer keeps it). An execution run with ``telemetry`` ``none`` has no stream: its
    final status is stored as it arrives.

    A full disk never leaves a run ``running`` with its telemetry silently missing: the first batch the store cannot
    take (``services.store.DiskFull``) fails the run, saying the disk is full and how many samples were not stored,
    and tells its worker to abort; its later batches are counted, not stored; its worker's final status then gives
    the run its metrics and the final count (:class:`Unstored`).
    """

    def __init__(self, store: Store, bus: BusClient | None = None) -> None:
        self.store = store
        self.bus = bus
        """The client whose callbacks these are (set by :func:`connect_bus`): where missing telemetry is asked."""
        self.on_status = _guarded(self._status)
        self.on_telemetry = _guarded(self._telemetry)
        self.on_worker_lost = _guarded(self._worker_lost)
        self.on_worker_back = _guarded(self._worker_back)
        self._held: dict[str, ExecutionStatus] = {}
        self._seen_stored: dict[str, int] = {}  # held execution -> samples stored when last looked at
        self._received: dict[str, int] = {}  # execution -> one past the last sample received live
        self._unstored: dict[str, Unstored] = {}  # execution failed for a full disk, until its final status
        self._lock = threading.Lock()
        self._repairs: queue.Queue[str] = queue.Queue()
        self._repairing: set[str] = set()
        self._repairer: threading.Thread | None = None

    def _status(self, status: ExecutionStatus) -> None:
        if status.final and self._unstored_final(status):
            return
        row = self.store.executions.get(status.execution_id)
        if row is not None and row.worker_id is not None and row.worker_id != status.worker_id:
            log.warning("status of %s from %s ignored: it runs on %s", status.execution_id, status.worker_id,
                        row.worker_id)  # fmt: skip
            return
        # A worker's status (it echoes its dispatch; the ones the bus client makes up for a lost worker do not) is
        # taken once, in order, for the current dispatch of an active run: a replayed one moves nothing.
        if status.attempt and not self.store.executions.advance(status.execution_id, status.attempt, status.seq):
            log.warning("status %d of %s from %s ignored: the run ended, was handed over again, or took a later "
                        "status already", status.seq, status.execution_id, status.worker_id)  # fmt: skip
            return
        state = FINAL_STATES.get(status.phase, ExecutionState.paused if status.paused else ExecutionState.running)
        streamed = row is None or row.streams_telemetry  # telemetry 'none': no stream to wait for
        if status.final and streamed and not self._telemetry_complete(status):
            with self._lock:
                self._held[status.execution_id] = status
            self.store.executions.update(status.execution_id, phase=status.phase, worker_id=status.worker_id)
            timer = threading.Timer(FINAL_TELEMETRY_GRACE_S, self._repair, args=(status.execution_id,))
            timer.daemon = True
            timer.start()
            return
        store_status(self.store, status, state)
        if status.final:
            self._forget(status.execution_id)

    def _telemetry_complete(self, status: ExecutionStatus) -> bool:
        if status.metrics is None:
            return True
        return self.store.telemetry.counts(status.execution_id)[1] >= status.metrics.steps

    def _still_arriving(self, execution_id: str) -> bool:
        """Whether a held final status's telemetry is incomplete but still arriving (more samples stored than at the
        last look: a fast run's stream behind its status); if so, look again after :data:`FINAL_TELEMETRY_GRACE_S`
        before asking the worker for what is missing."""
        with self._lock:
            held = self._held.get(execution_id)
        if held is None or self._telemetry_complete(held):
            return False
        stored = self.store.telemetry.counts(execution_id)[1]
        with self._lock:
            growing = stored > self._seen_stored.get(execution_id, -1)
            self._seen_stored[execution_id] = stored
        if growing:
            timer = threading.Timer(FINAL_TELEMETRY_GRACE_S, self._repair, args=(execution_id,))
            timer.daemon = True
            timer.start()
        return growing

    def _release(self, execution_id: str) -> None:
        with self._lock:
            status = self._held.pop(execution_id, None)
            self._seen_stored.pop(execution_id, None)
        if status is not None:
            store_status(self.store, status, FINAL_STATES[status.phase])
            self._forget(execution_id)

    def _forget(self, execution_id: str) -> None:
        with self._lock:
            self._received.pop(execution_id, None)

    def _telemetry(self, batch: TelemetryBatch) -> None:
        execution_id = batch.execution_id
        if not execution_id or not len(batch.t):
            return
        with self._lock:
            received = self._received.get(execution_id)
            unstored = self._unstored.get(execution_id)
            if unstored is not None:
                unstored.lost += len(batch.t)
                return
        if received is None:
            received = self.store.telemetry.end(execution_id)
        try:
            self.store.telemetry.add(execution_id, batch)
        except DiskFull as exc:
            self._disk_full(execution_id, batch.first_sample if batch.first_sample is not None else received,
                            len(batch.t), exc)  # fmt: skip
            return
        if batch.first_sample is not None:
            if batch.first_sample > received:
                log.warning("telemetry of %s: samples %d to %d missed; asking the worker again", execution_id,
                            received, batch.first_sample - 1)  # fmt: skip
                self._repair(execution_id)
            with self._lock:
                self._received[execution_id] = max(received, batch.first_sample + len(batch.t))
        with self._lock:
            held = self._held.get(execution_id)
        if held is not None and self._telemetry_complete(held):
            self._release(execution_id)

    def _disk_full(self, execution_id: str, first: int, n: int, exc: DiskFull) -> None:
        """The store could not take ``n`` samples of the run from sample ``first`` on: fail it and abort it (its
        later samples are counted, not stored, :meth:`_telemetry`)."""
        unstored = Unstored(str(exc), first, n)
        with self._lock:
            self._unstored[execution_id] = unstored
            self._held.pop(execution_id, None)
        log.error("execution %s: %s", execution_id, unstored.reason())
        if self.bus is not None:
            self.bus.send_command(execution_id, CommandName.abort)
        self.store.executions.update(
            execution_id, status=ExecutionState.failed, phase=ExecutionPhase.failed, error=unstored.reason()
        )

    def _unstored_final(self, status: ExecutionStatus) -> bool:
        """The final status of a run failed for a full disk: the run keeps its failure and gets the worker's metrics
        and the final count of samples not stored. False for any other run."""
        with self._lock:
            unstored = self._unstored.pop(status.execution_id, None)
        if unstored is None:
            return False
        total = status.metrics.steps if status.metrics is not None else None
        if total is not None:
            unstored.lost = max(unstored.lost, total - self.store.telemetry.counts(status.execution_id)[1])
        self.store.executions.amend_failure(status.execution_id, unstored.reason(total), status.metrics)
        self._forget(status.execution_id)
        return True

    def _repair(self, execution_id: str) -> None:
        """Have the repair thread fill the execution's telemetry gaps (then store its held final status)."""
        if self.bus is None:
            if not self._still_arriving(execution_id):
                self._release(execution_id)
            return
        with self._lock:
            if execution_id in self._repairing:
                return
            self._repairing.add(execution_id)
            if self._repairer is None:
                self._repairer = threading.Thread(target=self._repair_loop, name="telemetry-repair", daemon=True)
                self._repairer.start()
        self._repairs.put(execution_id)

    def _repair_loop(self) -> None:
        while True:
            execution_id = self._repairs.get()
            with self._lock:
                self._repairing.discard(execution_id)
            if self._still_arriving(execution_id):
                continue
            try:
                self._fill(execution_id)
            except Exception:
                log.exception("repairing the telemetry of %s failed", execution_id)
            self._release(execution_id)

    def _fill(self, execution_id: str) -> None:
        """Ask the worker that ran the execution for every sample missing from the store (up to the held final
        status's count, else up to the last one stored)."""
        row = self.store.executions.get(execution_id)
        if row is None or row.worker_id is None or self.bus is None:
            return
        with self._lock:
            held = self._held.get(execution_id)
        total = held.metrics.steps if held is not None and held.metrics is not None else None
        gaps = self.store.telemetry.gaps(execution_id, total)
        filled = sum(
            self.store.telemetry.add(execution_id, batch)
            for start, stop in gaps
            for batch in self.bus.telemetry_replay(row.worker_id, execution_id, start, stop)
        )
        missing = sum(stop - start for start, stop in gaps) - filled
        log.log(logging.WARNING if missing else logging.INFO, "telemetry of %s: %d missing samples asked again of %s, "
                "%d received, %d lost", execution_id, filled + missing, row.worker_id, filled, missing)  # fmt: skip

    def _worker_back(self, status: ExecutionStatus) -> None:
        """A worker failed as lost is back and knows the execution (its own link to the router had dropped): the
        failure is withdrawn and its true status applied (the telemetry it sent meanwhile is asked again)."""
        from services.worker_liveness import lost_worker_reason

        if self.store.executions.reopen(status.execution_id, lost_worker_reason(status.worker_id)):
            log.warning("execution %s: worker %s is back, its loss no longer fails the run", status.execution_id,
                        status.worker_id)  # fmt: skip
            self._status(status)

    def _worker_lost(self, worker_id: str) -> None:
        marked = self.store.executions.fail_active(
            f"worker {worker_id} was lost while running (process gone)", worker_id
        )
        if marked:
            log.warning("worker %s lost: executions %s marked failed", worker_id, ", ".join(marked))


def reconcile(store: Store, bus: BusClient | None, wait_s: float = WORKER_DISCOVERY_S) -> list[str]:
    """Executions left starting/running by a previous API process: keep those a live worker reports running
    (``WorkerInfo.execution_id``; the bus client adopts them, their statuses keep arriving, and the telemetry
    published while no API listened is asked again when the next batch shows the gap), hand the final status of
    those that ended while no API listened to the bus callbacks as if received (the workers' status queryables
    keep it: a run that finished is ``done``, not failed; it is stored once its missing telemetry has been asked
    again, :class:`BusEvents`), put those still being handed over back in the queue (``services.queue``), mark the
    rest failed (:data:`RESTART_REASON`). Returns the ids marked failed."""
    active = store.executions.active()
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
        if row.id in running and bus is not None and row.worker_id is not None and row.attempt is not None:
            bus.adopt(row.id, row.worker_id, row.attempt)
            continue
        if row.id in running or (row.status is ExecutionState.starting and store.executions.requeue(row.id)):
            continue
        status = ended.get(row.id)
        if bus is not None and status is not None and status.final and status.worker_id == row.worker_id:
            log.warning("execution %s ended %s while no API listened", row.id, status.phase.value)
            bus.deliver(status)
            continue
        if store.executions.update(
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
        report_key=store.service_key(REPORT_KEY_NAME),
    )

    events.bus = BusClient(
        bus_settings,
        events.on_status,
        events.on_telemetry,
        events.on_worker_lost,
        events.on_worker_back,
        store.executions.owner,
    )
    return events.bus
