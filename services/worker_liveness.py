"""Which workers are alive, and what becomes of the executions of one that goes (the rules are in ``services.bus``'s
module docstring: a token that goes with this client's router link is an outage, one that goes alone is a worker lost
once it does not answer; a worker that comes back is asked about its executions).

:class:`WorkerLiveness` holds that bookkeeping, apart from the transport: the bus client feeds it the liveliness
tokens and router-link events it receives and gives it three questions to ask the bus (is a worker answering, a
worker's latest status of an execution) and the callbacks to report to. Its timers run on their own threads.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from schemas.bus import ExecutionStatus
from schemas.execution import ExecutionPhase

log = logging.getLogger("contact_skills.bus")

LOST_GRACE_S = 0.25
"""A worker's token gone, wait this long for its last statuses before checking whether it is lost, s (a token that
comes back within it cancels the check)."""
WORKER_CHECK_S = 0.5
"""A worker whose token went while this client kept its router link is lost unless it answers its info query within
this, s."""
WORKER_RETURN_GRACE_S = 15.0
"""After a router outage, how long a worker whose token went with this client's link has, once the link is back, to
show its token again before it is lost, s (clients retry the router with a back-off: 4.4 s measured after a 2.6 s
outage)."""
OUTAGE_WINDOW_S = 1.0
"""A token that went within this of this client losing (or regaining) its router link went with the link, s."""
LOST_RUNS_KEPT_S = 600.0
"""A lost worker that comes back within this is asked what became of the executions failed for its loss, s."""


def lost_worker_reason(worker_id: str) -> str:
    """The error of an execution failed because its worker was lost (the one the worker's return can withdraw)."""
    return f"worker {worker_id} lost during the execution (process ended or connection lost)"


class WorkerLiveness:
    """The live workers, the executions running on each, and the checks of those whose token went (thread-safe)."""

    def __init__(
        self,
        answering: Callable[[str], bool],
        latest_status: Callable[[str, str], ExecutionStatus | None],
        report: Callable[[ExecutionStatus], None],
        on_worker_lost: Callable[[str], None],
        on_worker_back: Callable[[ExecutionStatus], None] | None = None,
    ) -> None:
        """``answering(worker_id)``: whether a worker answers its info query within :data:`WORKER_CHECK_S`;
        ``latest_status(worker_id, execution_id)``: the worker's latest status of an execution (None: it does not
        know it); ``report``: where a synthesized or caught-up status goes (``on_status``, guarded by the caller);
        ``on_worker_lost`` / ``on_worker_back``: as ``services.bus.BusClient``'s."""
        self._answering = answering
        self._latest_status = latest_status
        self._report = report
        self._on_worker_lost = on_worker_lost
        self._on_worker_back = on_worker_back
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._running: dict[str, str] = {}  # execution_id -> worker_id, started or adopted here, not finished
        self._lost_runs: dict[str, dict[str, float]] = {}  # worker_id -> {execution failed for its loss: when}
        self._timers: dict[str, threading.Timer] = {}  # worker_id -> the check of a token that went
        self._out_of_sight: set[str] = set()  # workers whose tokens went with the router link
        self._link_up = True
        self._link_changed = -math.inf  # time.monotonic() when the router link last went or came back
        self._closed = False

    # ------------------------------------------------------------------ what the caller tells

    def alive(self) -> set[str]:
        """The workers whose liveliness tokens are present now."""
        with self._lock:
            return set(self._alive)

    def running(self, execution_id: str, worker_id: str) -> None:
        """``execution_id`` runs on ``worker_id`` for this client: failed if the worker is lost, caught up on if it
        comes back."""
        with self._lock:
            self._running[execution_id] = worker_id

    def finished(self, execution_id: str) -> None:
        """``execution_id`` has ended: its worker's loss no longer concerns it."""
        with self._lock:
            self._running.pop(execution_id, None)

    def link(self, up: bool, initial: bool = False) -> None:
        """This client's link to a router went (``up`` False) or came back; ``initial``: the state found on opening
        (not a change)."""
        with self._lock:
            self._link_up = up
            if initial:
                return
            self._link_changed = time.monotonic()
            waiting = sorted(self._out_of_sight - set(self._timers)) if up else []
        log.warning("router link %s%s", "back" if up else "lost", f"; waiting for {', '.join(waiting)}" if waiting
                    else "")  # fmt: skip
        for worker_id in waiting:
            self._schedule(worker_id, WORKER_RETURN_GRACE_S, self._overdue)

    def token(self, worker_id: str, present: bool) -> None:
        """A worker's liveliness token came (``present``) or went."""
        with self._lock:
            pending = self._timers.pop(worker_id, None)
            returned = present and (
                pending is not None or worker_id in self._out_of_sight or worker_id in self._lost_runs
            )
            self._out_of_sight.discard(worker_id)
            (self._alive.add if present else self._alive.discard)(worker_id)
        if pending is not None:
            pending.cancel()
        if present:
            log.info("worker %s connected%s", worker_id, " again" if returned else "")
            if returned:
                self._schedule(worker_id, 0.0, self._caught_up)
            return
        # The token goes on the control path, the worker's last statuses on the data path: give them
        # LOST_GRACE_S to arrive before deciding what became of the worker.
        self._schedule(worker_id, LOST_GRACE_S, self._token_gone, time.monotonic())

    def close(self) -> None:
        """Cancel the pending checks; none starts after this."""
        with self._lock:
            self._closed = True
            timers, self._timers = list(self._timers.values()), {}
        for timer in timers:
            timer.cancel()

    # ------------------------------------------------------------------ the checks (timer threads)

    def _schedule(self, worker_id: str, delay_s: float, check: Callable[..., None], *args: Any) -> None:
        """Run ``check(worker_id, *args)`` on a timer thread after ``delay_s``, unless the worker's token comes back
        first (or another check replaces this one)."""

        def run() -> None:
            with self._lock:
                if self._timers.get(worker_id) is not timer:
                    return
                del self._timers[worker_id]
            check(worker_id, *args)

        timer = threading.Timer(delay_s, run)
        timer.daemon = True
        with self._lock:
            if self._closed:
                return
            replaced = self._timers.pop(worker_id, None)
            self._timers[worker_id] = timer
        if replaced is not None:
            replaced.cancel()
        timer.start()

    def _token_gone(self, worker_id: str, gone_at: float) -> None:
        """A worker's token went ``LOST_GRACE_S`` ago and has not come back: a router outage, or the worker lost."""
        with self._lock:
            with_link = not self._link_up or self._link_changed >= gone_at - OUTAGE_WINDOW_S
            if with_link:
                self._out_of_sight.add(worker_id)
            link_up = self._link_up
        if with_link:
            log.warning("worker %s out of sight with the router link: its executions wait for it", worker_id)
            if link_up:
                self._schedule(worker_id, WORKER_RETURN_GRACE_S, self._overdue)
            return
        if self._answering(worker_id):
            log.warning("worker %s's token went but it answers: kept", worker_id)
            return
        self._worker_lost(worker_id)

    def _overdue(self, worker_id: str) -> None:
        """The router link is back and a worker out of sight since the outage did not return in time."""
        with self._lock:
            gone = worker_id in self._out_of_sight
            self._out_of_sight.discard(worker_id)
        if gone:
            self._worker_lost(worker_id)

    def _caught_up(self, worker_id: str) -> None:
        """A worker is back after its token went: what became of the executions it runs for this client, and of
        those failed when it was lost (:meth:`_lost_and_back`)."""
        with self._lock:
            executions = [e for e, w in self._running.items() if w == worker_id]
            lost = self._lost_runs.pop(worker_id, {})
        self._lost_and_back(worker_id, lost)
        for execution_id in executions:
            status = self._latest_status(worker_id, execution_id)
            if status is None:
                error = f"worker {worker_id} came back without execution {execution_id} (it restarted)"
                status = ExecutionStatus(execution_id=execution_id, worker_id=worker_id, phase=ExecutionPhase.failed,
                                         message=error, error=error)  # fmt: skip
            log.warning("worker %s back: execution %s is %s", worker_id, execution_id, status.phase.value)
            if status.final:
                self.finished(execution_id)
            self._report(status)

    def _lost_and_back(self, worker_id: str, lost: dict[str, float]) -> None:
        """Executions failed when ``worker_id`` was lost (``lost``: id -> time.monotonic() of the failure), the worker
        now back: the latest status of each it still knows goes to ``on_worker_back``; one still running is
        followed again. Unknown to the worker (it restarted), or failed too long ago: the verdict stands."""
        if self._on_worker_back is None:
            return
        for execution_id, failed_at in lost.items():
            if time.monotonic() - failed_at > LOST_RUNS_KEPT_S:
                continue
            status = self._latest_status(worker_id, execution_id)
            if status is None:
                continue
            if not status.final:
                self.running(execution_id, worker_id)
            log.warning("worker %s back: execution %s, failed for its loss, is %s", worker_id, execution_id,
                        status.phase.value)  # fmt: skip
            _call(self._on_worker_back, status)

    def _worker_lost(self, worker_id: str) -> None:
        with self._lock:
            orphans = [e for e, w in self._running.items() if w == worker_id]
            for execution_id in orphans:
                del self._running[execution_id]
            now = time.monotonic()
            runs = self._lost_runs.setdefault(worker_id, {})
            runs.update(dict.fromkeys(orphans, now))
            for execution_id in [e for e, when in runs.items() if now - when > LOST_RUNS_KEPT_S]:
                del runs[execution_id]
        log.warning("worker %s lost (%d execution(s) running on it)", worker_id, len(orphans))
        for execution_id in orphans:
            status = ExecutionStatus(
                execution_id=execution_id,
                worker_id=worker_id,
                phase=ExecutionPhase.failed,
                message=f"worker {worker_id} lost",
                error=lost_worker_reason(worker_id),
            )
            self._report(status)
        _call(self._on_worker_lost, worker_id)


def _call(callback: Callable[[Any], None], value: Any) -> None:
    """``callback(value)``, an exception logged and swallowed (a callback never stops the bookkeeping)."""
    try:
        callback(value)
    except Exception:
        log.exception("bus callback %s failed", getattr(callback, "__name__", callback))
