"""Which worker reports count (``services.bus``'s REPORTS rules): each execution's secret, bound to the worker it was
handed to and to the dispatch (its attempt nonce), the signatures checked against it, and the plausibility of what a
worker says."""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
import threading
from collections import OrderedDict
from collections.abc import Callable

from schemas.bus import ExecutionStatus, KeyExpressions, WorkerInfo
from schemas.bus_security import challenge_signature, report_signature
from schemas.execution import ExecutionPhase, TelemetryBatch
from services.log_limits import RateLimitFilter

log = logging.getLogger("contact_skills.bus")
log.addFilter(RateLimitFilter())  # a flood of forged or bad reports cannot flood the log

HANDED_KEPT = 10_000
"""Executions whose worker this client remembers (to check their reports), the most recent ones; older ones are
looked up through ``owner``."""


def new_attempt() -> str:
    """A fresh dispatch nonce (``StartExecution.attempt``): 16 hex digits, never reused."""
    return secrets.token_hex(8)


def implausible_status(status: ExecutionStatus) -> str | None:
    """Why a worker's status cannot be true (negative counters or time, ``done`` without a control step), or None."""
    counters = {"steps": status.steps, "seq": status.seq, "segments": status.segments, "t": status.t}
    if status.metrics is not None:
        counters["metrics.steps"] = status.metrics.steps
    negative = [f"{name} {value}" for name, value in counters.items() if value < 0]
    if negative:
        return "negative " + ", ".join(negative)
    if status.segment_index < -1:
        return f"segment_index {status.segment_index}"
    if status.phase is ExecutionPhase.done and (status.metrics is None or status.metrics.steps <= 0):
        return "done without a control step"
    return None


def implausible_info(info: WorkerInfo, key: str, keys: KeyExpressions) -> str | None:
    """Why a worker's info reply on ``key`` cannot be taken (under another worker's key, negative counters), or
    None."""
    if key != keys.info(info.worker_id):
        return f"info of {info.worker_id} under {key}"
    if info.executions_run < 0 or info.pid < 0 or info.started_unix_s < 0:
        return f"negative counters from {info.worker_id}"
    if info.busy != (info.activity != "idle"):
        return f"{info.worker_id} busy={info.busy} while {info.activity}"
    return None


def signed(secret: bytes, payload: bytes, signature: bytes | None) -> bool:
    """Whether ``signature`` is ``payload``'s under ``secret`` (compared in constant time)."""
    return signature is not None and hmac.compare_digest(report_signature(secret, payload), signature)


class ReportChecks:
    """The worker and the dispatch attempt each execution was handed to, its secret, and whether a report proves it
    comes from that worker for that attempt (thread-safe)."""

    def __init__(
        self, report_key: bytes, keys: KeyExpressions, owner: Callable[[str], tuple[str, str] | None] | None
    ) -> None:
        """``report_key``: what every execution's secret is derived from; ``owner``: the (worker, attempt) an
        execution this client does not remember was handed to (the store's record)."""
        self._report_key = report_key
        self._keys = keys
        self._owner_of = owner
        self._handed: OrderedDict[str, tuple[str, str]] = OrderedDict()  # execution_id -> (worker, attempt)
        self._lock = threading.Lock()

    def execution_secret(self, execution_id: str, worker_id: str, attempt: str) -> bytes:
        """The secret of ``execution_id`` run by ``worker_id`` as dispatch ``attempt`` (32 bytes): known to this
        client and sent to that worker alone; the same execution offered to another worker, or handed over again,
        has another one."""
        message = f"{execution_id}/{worker_id}/{attempt}".encode()
        return hmac.new(self._report_key, message, hashlib.sha256).digest()

    def hand(self, execution_id: str, worker_id: str, attempt: str) -> None:
        """``execution_id`` is offered or handed to ``worker_id`` as ``attempt``: from now on only its reports
        count."""
        with self._lock:
            self._handed[execution_id] = (worker_id, attempt)
            self._handed.move_to_end(execution_id)
            while len(self._handed) > HANDED_KEPT:
                self._handed.popitem(last=False)

    def handed(self, execution_id: str) -> tuple[str, str] | None:
        """(the worker, the attempt) ``execution_id`` was handed to (None: not known to this client nor to
        ``owner``)."""
        with self._lock:
            handed = self._handed.get(execution_id)
        if handed is None and self._owner_of is not None:
            handed = self._owner_of(execution_id)
            if handed is not None:
                self.hand(execution_id, *handed)
        return handed

    def owner(self, execution_id: str) -> str | None:
        """The worker ``execution_id`` was handed to (None: not known)."""
        handed = self.handed(execution_id)
        return None if handed is None else handed[0]

    def signed_by(self, execution_id: str, worker_id: str, payload: bytes, signature: bytes | None) -> bool:
        """Whether ``payload`` carries ``worker_id``'s signature for ``execution_id``'s current attempt."""
        handed = self.handed(execution_id)
        if handed is None or handed[0] != worker_id:
            return False
        return signed(self.execution_secret(execution_id, *handed), payload, signature)

    def answers_now(self, status: ExecutionStatus, payload: bytes, signature: bytes | None, challenge: bytes) -> bool:
        """Whether a status answering a query that carried ``challenge`` is signed with it
        (``schemas.bus_security.challenge_signature``) by the worker the execution was handed to, for its current
        attempt: that worker answers now (not a recording of an earlier answer, whoever replays it)."""
        handed = self.handed(status.execution_id)
        if handed is None or handed != (status.worker_id, status.attempt) or signature is None:
            return False
        expected = challenge_signature(self.execution_secret(status.execution_id, *handed), payload, challenge)
        return hmac.compare_digest(expected, signature)

    def status_trusted(self, status: ExecutionStatus, payload: bytes, signature: bytes | None) -> bool:
        """Whether a status comes from the worker its execution was handed to, for the current attempt, and is
        plausible; a refused one is logged. (Whether it is newer than the last one taken is the store's:
        ``services.store.executions.ExecutionRepository.advance``.)"""
        handed = self.handed(status.execution_id)
        if handed is None:
            log.warning("status of %s, an execution handed to no worker: refused", status.execution_id)
            return False
        owner, attempt = handed
        if owner != status.worker_id:
            log.warning("status of %s naming %s refused: the execution was handed to %s",
                        status.execution_id, status.worker_id, owner)  # fmt: skip
            return False
        if status.attempt != attempt:
            log.warning("status of %s from %s refused: attempt %r, not the current one", status.execution_id, owner,
                        status.attempt)  # fmt: skip
            return False
        if not self.signed_by(status.execution_id, owner, payload, signature):
            log.warning("status of %s not signed by %s: refused", status.execution_id, owner)
            return False
        if why := implausible_status(status):
            log.warning("status of %s from %s refused: %s", status.execution_id, owner, why)
            return False
        return True

    def telemetry_trusted(self, batch: TelemetryBatch, key: str, payload: bytes, signature: bytes | None) -> bool:
        """Whether a telemetry batch received on ``key`` comes from the worker its execution was handed to and is
        plausible; a refused one is logged."""
        owner = self.owner(batch.execution_id) if batch.execution_id else None
        if owner is None or key != self._keys.telemetry(batch.execution_id):
            log.warning("telemetry of %s, an execution handed to no worker: refused", batch.execution_id)
            return False
        if not self.signed_by(batch.execution_id, owner, payload, signature):
            log.warning("telemetry of %s not signed by %s: refused", batch.execution_id, owner)
            return False
        if (batch.first_sample is not None and batch.first_sample < 0) or (batch.seq is not None and batch.seq < 0):
            log.warning("telemetry of %s from %s refused: negative counters", batch.execution_id, owner)
            return False
        return True
