"""What the API itself observed of its dispatches and of each worker, for the dispatch watchdog (``services.queue``)
and the choice of a worker (``services.bus.BusClient``): when each execution was handed over, when its worker was
last heard from (a status, a heartbeat or a telemetry batch that passed the report checks), and per worker how many
executions it was handed and how many it let time out. A worker's word about itself
(``WorkerInfo.executions_run``) never decides where a job goes: a worker that claims it ran nothing wins nothing by
it, and one that took a job and went silent goes to the back of the line."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

WATCHED_KEPT = 10_000
"""Dispatches watched at most (the oldest are dropped: an execution that ends is forgotten at once anyway)."""


@dataclass(frozen=True)
class Overdue:
    """A dispatch whose worker did not report in time."""

    execution_id: str
    worker_id: str
    attempt: str
    silent_s: float
    """Since the hand-over (never heard) or since the last report, s."""
    heard: bool
    """Whether the worker reported at all for it (False: never, after accepting it)."""


@dataclass
class _Dispatch:
    worker_id: str
    attempt: str
    handed_at: float
    heard_at: float | None = None


@dataclass
class _Worker:
    dispatches: int = 0
    timeouts: int = 0
    heard_at: float | None = None


class DispatchWatch:
    """The dispatches in flight and the workers as this API saw them (thread-safe; times from time.monotonic())."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._dispatches: dict[str, _Dispatch] = {}
        self._workers: dict[str, _Worker] = {}
        self._early: dict[str, tuple[str, float]] = {}  # execution -> (worker, when) heard before its hand-over

    def handed(self, execution_id: str, worker_id: str, attempt: str) -> None:
        """``worker_id`` accepted ``execution_id`` as dispatch ``attempt``: its first report is now due."""
        with self._lock:
            early = self._early.pop(execution_id, None)  # its first status can overtake the worker's accept reply
            heard_at = early[1] if early is not None and early[0] == worker_id else None
            self._dispatches.pop(execution_id, None)
            self._dispatches[execution_id] = _Dispatch(worker_id, attempt, time.monotonic(), heard_at)
            for watched in (self._dispatches, self._early):
                while len(watched) > WATCHED_KEPT:
                    watched.pop(next(iter(watched)))
            self._workers.setdefault(worker_id, _Worker()).dispatches += 1

    def heard(self, execution_id: str, worker_id: str) -> None:
        """A report of ``execution_id`` from ``worker_id`` passed the checks."""
        now = time.monotonic()
        with self._lock:
            dispatch = self._dispatches.get(execution_id)
            if dispatch is None:
                self._early[execution_id] = (worker_id, now)
            elif dispatch.worker_id == worker_id:
                dispatch.heard_at = now
            self._workers.setdefault(worker_id, _Worker()).heard_at = now

    def ended(self, execution_id: str) -> None:
        """``execution_id`` ended or was taken back: nothing more is due."""
        with self._lock:
            self._dispatches.pop(execution_id, None)
            self._early.pop(execution_id, None)

    def timed_out(self, worker_id: str) -> None:
        """``worker_id`` let a dispatch time out: it goes after every worker that did not (:meth:`order`)."""
        with self._lock:
            self._workers.setdefault(worker_id, _Worker()).timeouts += 1

    def overdue(self, first_report_s: float, silence_s: float) -> list[Overdue]:
        """The dispatches not heard from within ``first_report_s`` of their hand-over, or silent for more than
        ``silence_s`` since their last report."""
        now = time.monotonic()
        late = []
        with self._lock:
            for execution_id, d in self._dispatches.items():
                since, limit = (d.handed_at, first_report_s) if d.heard_at is None else (d.heard_at, silence_s)
                if now - since > limit:
                    late.append(Overdue(execution_id, d.worker_id, d.attempt, now - since, d.heard_at is not None))
        return late

    def order(self, worker_id: str) -> tuple[int, int]:
        """Sort key of a free worker (lowest first): the dispatches it let time out, then those it was handed."""
        with self._lock:
            worker = self._workers.get(worker_id) or _Worker()
            return worker.timeouts, worker.dispatches

    def heard_age(self, worker_id: str) -> float | None:
        """Seconds since ``worker_id``'s last report that passed the checks (None: never heard from)."""
        with self._lock:
            worker = self._workers.get(worker_id)
            heard = None if worker is None else worker.heard_at
        return None if heard is None else time.monotonic() - heard
