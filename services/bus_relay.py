"""What the workers report, as the API side takes it (``services.bus``): every status and telemetry batch on the bus,
checked (``services.bus_reports``) and handed to the receiver's callbacks from one inbox thread, the latest statuses
and the telemetry a receiver missed asked again, the workers' tokens and this client's link to the router."""

from __future__ import annotations

import logging
import queue
import secrets
from collections.abc import Callable
from typing import Any

from schemas.bus import (
    REPLAY_MAX_SAMPLES,
    ExecutionStatus,
    TelemetryReplay,
)
from schemas.execution import TelemetryBatch
from services.bus_dispatch import INFO_TIMEOUT_S, WorkerDispatch
from services.bus_reports import implausible_status
from services.bus_session import Reply, attachment_bytes

log = logging.getLogger("contact_skills.bus")  # rate-limited: services.bus_reports adds the filter

REPLAY_TIMEOUT_S = 10.0
"""How long a telemetry replay waits for the worker's replies, s."""
INBOX_BYTES = 512 * 2**20
"""Telemetry received and not yet handled, at most, bytes of JSON (~850 000 samples). Zenoh's threads only put
statuses and batches in the inbox and never wait: the handling (parse, check, store: a busy database waits) is the
inbox thread's. A session that does not read its link for the lease (10 s) loses it: the API lost its link to its own
router 6 times in a 733 s fast run when its callbacks stored each batch themselves (making them wait for room instead
lost it 3 times in a 1344 s run). A batch past this is dropped, and asked again of the worker."""


class ReportRelay(WorkerDispatch):
    """The workers' reports to the receiver (part of ``BusClient``)."""

    _on_status: Callable[[ExecutionStatus], None]
    _on_telemetry: Callable[[TelemetryBatch], None]
    _inbox: queue.Queue
    _inbox_bytes: int
    """Telemetry bytes in the inbox (statuses are few and always kept)."""

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
            if not self.reports.signed_by(execution_id, worker_id, payload, attachment_bytes(reply.ok.attachment)):
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

    def deliver(self, status: ExecutionStatus) -> None:
        """Hand ``status`` to ``on_status`` as if it had just been received (one the subscriber missed)."""
        if status.final:
            self.liveness.finished(status.execution_id)
            self.watch.ended(status.execution_id)
        self._call(self._on_status, status)

    def _status_sample(self, sample) -> None:
        """Zenoh's thread: hand the status to the inbox thread (never dropped; waits if the inbox is full)."""
        self._inbox.put((self._status_received, sample.payload.to_bytes(), str(sample.key_expr),
                         attachment_bytes(sample.attachment)))  # fmt: skip

    def _telemetry_sample(self, sample) -> None:
        """Zenoh's thread: hand the batch to the inbox thread, never waiting: past :data:`INBOX_BYTES` it is dropped
        (the receiver sees the gap in ``first_sample`` and asks the worker for it again)."""
        item = (
            self._telemetry_received,
            sample.payload.to_bytes(),
            str(sample.key_expr),
            attachment_bytes(sample.attachment),
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
