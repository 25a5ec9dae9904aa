"""Which worker takes a job, as the API side asks (``services.bus``): the workers and what they are doing
(:meth:`WorkerDispatch.workers`, :meth:`WorkerDispatch.workers_seen` without waiting), the free ones in the order to
try, and the hand-over of an execution or a recording to the first that accepts it."""

from __future__ import annotations

import itertools
import logging
import threading
import time

from schemas.bus import (
    RecordReply,
    RecordRequest,
    StartExecution,
    StartReply,
    WorkerInfo,
)
from schemas.demonstration import Demonstration
from schemas.execution import ExecutionRequest
from schemas.world import WorldOverrides
from services.bus_reports import implausible_info, new_attempt
from services.bus_session import BusQueries

log = logging.getLogger("contact_skills.bus")  # rate-limited: services.bus_reports adds the filter

INFO_TIMEOUT_S = 2.0
"""How long ``workers()`` waits for the workers' info replies, s (they answer in about a millisecond)."""
WORKERS_FRESH_S = 0.5
"""``workers_seen()`` answers from the last info query younger than this, s; an older one is refreshed in the
background."""
START_TIMEOUT_S = 30.0
"""How long a start request waits for the chosen worker's reply, s: the worker builds the execution's world and
checks its reach (placement) before it accepts, 0.1-1.2 s on a quiet core, ten times that on a loaded one."""


class NoWorkerAvailable(RuntimeError):  # noqa: N818 (the name is the interface)
    """No connected worker can take the job; the message says how many are connected and why none could."""


class BusRequestError(ValueError):
    """A worker refused a request as invalid (e.g. an unknown scenario or world override); the message says why."""


class WorkerDispatch(BusQueries):
    """The workers, and the hand-over of a job to one of them (part of ``BusClient``)."""

    _rotation: itertools.count
    _seen: tuple[float, dict[str, WorkerInfo]] | None
    """(time.monotonic(), the last info replies)."""
    _refreshing: bool
    _refresh_again: bool
    """Asked to refresh while a refresh ran: run it once more."""

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
        world_overrides: WorldOverrides | None = None,
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
