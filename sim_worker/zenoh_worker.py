"""The sim worker process on the Zenoh bus: executes skills and records teacher demonstrations on request.

``run_worker(settings)`` opens a Zenoh session (client mode, connected to the router's endpoints; it waits for the
router if it is not up yet), declares

- the liveliness token ``P/workers/{worker_id}`` (it disappears when the process dies, even by SIGKILL),
- the queryables ``P/exec/{worker_id}/info`` (``WorkerInfo``), ``P/exec/{worker_id}/start`` (``StartExecution``
  -> ``StartReply``; the demonstration a start sends is kept by its id for the next starts that name it),
  ``P/exec/{worker_id}/record`` (``RecordRequest`` -> ``RecordReply``),
  ``P/exec/{worker_id}/replay`` (``TelemetryReplay`` -> ``TelemetryBatch`` replies: the telemetry of its recent
  executions, ``sim_worker.telemetry_archive``, for a receiver that missed batches; at most
  ``schemas.bus.REPLAY_MAX_SAMPLES`` per query) and ``P/exec/*/status`` (the latest ``ExecutionStatus`` of the
  executions this worker ran, for late joiners and after a router outage; signed with the query's challenge when it
  carries one),

and serves until SIGINT/SIGTERM. One job at a time: a start or record request while busy gets a ``busy`` reply.

An execution runs ``sim_worker.executor.execute_skill`` in its own thread with the inline skill, in the world of
the request's ``scenario`` (else the scenario named by the skill's demonstration, else the default flat table) plus
``world_overrides``, on the engine the request names (none: the worker's own, ``WorkerSettings.engine``, which its
info reports). While it runs the worker

- publishes every control step on ``P/exec/{execution_id}/telemetry`` (``TelemetryBatch`` of
  ``request.telemetry_batch`` rows, reliable, congestion control BLOCK, numbered by ``seq`` and ``first_sample``)
  and keeps them for replays (what a disconnected receiver or router outage lost is asked again); with
  ``request.telemetry`` ``none`` it does neither (the metrics come from the loop's own rows all the same),
- publishes ``ExecutionStatus`` on ``P/exec/{execution_id}/status``: ``pending`` on acceptance, then on every phase
  or segment change, pause and resume, a heartbeat when none went out for ``schemas.bus.HEARTBEAT_S``, and a final
  one (done / aborted / failed) with the metrics; each echoes the start's ``attempt`` and counts up ``seq``,
- listens on ``P/exec/{execution_id}/cmd``: ``abort`` is polled by the control loop after every step (the
  execution stops within one control cycle; the final status carries ``abort_received_t``), ``pause`` holds the
  controller at its current reference with the loop running (throttled to about real time), ``resume`` continues.

The parts: ``sim_worker.worker_settings`` (settings, login, session), ``sim_worker.worker_run`` (one execution),
``sim_worker.worker_keeping`` (what it keeps between jobs), ``sim_worker.worker_recording`` (recordings); here the
worker on the bus.

Nothing an execution or a recording does can kill the worker: any exception becomes a ``failed`` status or an
``error`` reply. On SIGINT/SIGTERM the running execution is aborted, its final status published, everything
undeclared, and the process exits with 0.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import socket
import threading
import time
from typing import Any

from schemas.bus import (
    HEARTBEAT_S,
    REPLAY_MAX_SAMPLES,
    CommandName,
    ExecutionCommand,
    KeyExpressions,
    RecordReply,
    RecordRequest,
    StartExecution,
    StartReply,
    TelemetryReplay,
    WorkerInfo,
    check_id,
)
from schemas.job_budget import JobEstimate
from sim_worker.process_memory import bound_heap
from sim_worker.telemetry_archive import TelemetryArchive
from sim_worker.worker_keeping import KeptDemonstrations, ReportBook
from sim_worker.worker_recording import over_budget, record_request, recording_reply, short_error
from sim_worker.worker_run import (
    NOTHING_HELD,
    ExecutionRun,
    FinalStatus,
    merged_telemetry,
    replay_batches,
    then_trim_heap,
    worlds_for,
)
from sim_worker.worker_settings import LOGIN_LEASE_S, WorkerSettings, default_worker_id, opened_session
from skills.job_estimate import execution_estimate

log = logging.getLogger("contact_skills.worker")

FINAL_STATUS_HEAD_START_S = 0.1
"""At shutdown, pause between publishing the last status and undeclaring the liveliness token, s."""
SHUTDOWN_JOIN_S = 10.0
"""How long shutdown waits for the aborted execution and the publisher to finish, s."""
START_REPLY_MARGIN_S = 1.0
"""A start request is refused when its reply could reach the caller less than this before the caller's deadline
(``StartExecution.answer_by_unix_s``; the reply's transit, and clocks of other machines a little off), s."""


def _load_execution_code() -> None:
    """Import what an execution runs and load the compiled control loop (``sim_worker.warm_up``) before the worker
    shows itself: its first execution would otherwise pay for it (~2 s on a quiet core), not just the ones after."""
    import sim_worker.execution_world
    import sim_worker.executor  # noqa: F401  (imported for its cost, used by ExecutionRun.run)
    from sim_worker.warm_up import warm_up

    warm_up()


# ---------------------------------------------------------------------------------------------------------------
# The worker
# ---------------------------------------------------------------------------------------------------------------


class Worker:
    """A sim worker on the bus (see the module docstring). ``open()``, serve, ``close()``; or ``run_worker``."""

    def __init__(self, settings: WorkerSettings | None = None, worker_id: str | None = None) -> None:
        self.settings = settings or WorkerSettings()
        user = self.settings.security.user
        if user is not None and worker_id is not None and worker_id != user:
            raise ValueError(f"worker id {worker_id!r} differs from its bus user {user!r}: a worker's id is its user")
        self.worker_id = check_id(worker_id or user or default_worker_id(), "worker_id")
        self.keys = KeyExpressions(self.settings.prefix)
        self.hostname = socket.gethostname()
        self.started_unix_s = time.time()
        self.executions_run = 0
        self._lock = threading.Lock()
        self._run: ExecutionRun | None = None
        self._recording = False
        self.reports = ReportBook()
        self.demonstrations = KeptDemonstrations()
        self.archive = TelemetryArchive()
        self.publish_queue: queue.Queue = queue.Queue()
        self._publisher: threading.Thread | None = None
        self._session = None
        self._declared: list = []
        self._closed = False

    # ------------------------------------------------------------------------------------------ lifecycle

    def open(self, stop: threading.Event | None = None) -> bool:
        """Connect (retrying until the router answers, ``stop`` is set or the timeout passes) and declare.

        Returns False if stopped or timed out before a connection.
        """
        _load_execution_code()
        self._session = opened_session(self.settings, stop)
        if self._session is None:
            return False
        session, keys = self._session, self.keys
        self._publisher = threading.Thread(target=self._publish_loop, name="bus-publisher", daemon=True)
        self._publisher.start()
        self._declared = [
            session.declare_queryable(keys.info(self.worker_id), self._on_info),
            session.declare_queryable(keys.start(self.worker_id), self._on_start),
            session.declare_queryable(keys.record(self.worker_id), self._on_record),
            session.declare_queryable(keys.replay(self.worker_id), self._on_replay),
            session.declare_queryable(keys.status("*"), self._on_status_query),
        ]
        # The token last: whoever sees the worker can use it at once.
        self._declared.append(session.liveliness().declare_token(keys.worker(self.worker_id)))
        log.info("worker %s connected to %s (prefix %s)", self.worker_id, self.settings.endpoints, keys.prefix)
        return True

    def close(self, reason: str = "worker shutting down") -> None:
        """Abort the running execution, publish its final status, undeclare everything and close the session."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            run = self._run
        if run is not None:
            run.command(ExecutionCommand(command=CommandName.abort, execution_id=run.execution_id, reason=reason))
            if run.thread is not None:
                run.thread.join(SHUTDOWN_JOIN_S)
        if self._publisher is not None:
            self.publish_queue.put(None)
            self._publisher.join(SHUTDOWN_JOIN_S)
            if run is not None:  # the token's DELETE travels on another lane: let the final status go first
                time.sleep(FINAL_STATUS_HEAD_START_S)
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception:  # already gone with the session
                log.debug("undeclare failed", exc_info=True)
        self._declared = []
        if self._session is not None:
            self._session.close()
            self._session = None
        log.info("worker %s stopped", self.worker_id)

    def info(self) -> WorkerInfo:
        """What this worker reports on its info queryable."""
        with self._lock:
            run, recording = self._run, self._recording
        activity = "executing" if run is not None else "recording" if recording else "idle"
        return WorkerInfo(
            worker_id=self.worker_id,
            busy=activity != "idle",
            activity=activity,
            execution_id=run.execution_id if run is not None else None,
            hostname=self.hostname,
            pid=os.getpid(),
            started_unix_s=self.started_unix_s,
            executions_run=self.executions_run,
            engine=self.settings.engine,
        )

    # ------------------------------------------------------------------------------------------ publishing

    def _publish_loop(self) -> None:
        """The one thread that puts telemetry and statuses, in the order they were queued.

        When the control loop outruns the network (``pace: fast`` runs ~8x real time), telemetry
        batches of one execution that queued up behind each other are sent as ONE message of up to
        :data:`MAX_COALESCED_ROWS` rows: fewer, larger messages let the stream catch up, nothing is
        dropped or reordered, and at real-time pace the batches keep their requested size.
        """
        import zenoh

        block = zenoh.CongestionControl.BLOCK
        held: Any = NOTHING_HELD
        while True:
            with self._lock:
                run = self._run
            if run is not None:
                run.beat()
            try:
                item = self.publish_queue.get(timeout=HEARTBEAT_S) if held is NOTHING_HELD else held
            except queue.Empty:
                continue
            held = NOTHING_HELD
            if item is None:
                return
            kind, execution_id, payload, stamp, first = item
            try:
                if kind == "telemetry":
                    telemetry, held = merged_telemetry(payload, execution_id, self.publish_queue)
                    batch = telemetry.to_batch(execution_id)
                    batch.sent_unix_s, batch.first_sample = stamp, first
                    batch.seq = self.archive.next_batch(execution_id)
                    key, data = self.keys.telemetry(execution_id), batch.model_dump_json().encode()
                    signature = self.reports.signature(execution_id, data)
                else:
                    payload.sent_unix_s = time.time()
                    key, data = self.keys.status(execution_id), payload.model_dump_json().encode()
                    signature = self.reports.signature(execution_id, data)
                    self.reports.keep_status(execution_id, data, signature)
                self._session.put(key, data, congestion_control=block, attachment=signature)
            except Exception:  # keep publishing whatever happens to one item
                log.exception("publishing %s of %s failed", kind, execution_id)

    # ------------------------------------------------------------------------------------------ queryables

    def _on_info(self, query) -> None:
        try:
            query.reply(self.keys.info(self.worker_id), self.info().model_dump_json())
        except Exception:
            log.exception("info query failed")

    def _on_status_query(self, query) -> None:
        import zenoh

        try:
            wanted = zenoh.KeyExpr(str(query.key_expr))
            challenge = query.payload.to_bytes() if query.payload is not None else b""
            for execution_id, data, signature in self.reports.statuses(challenge):
                key = self.keys.status(execution_id)
                if wanted.intersects(zenoh.KeyExpr(key)):
                    query.reply(key, data, attachment=signature)
        except Exception:
            log.exception("status query failed")

    def _on_replay(self, query) -> None:
        """Send again the telemetry rows asked for, in messages of up to :data:`MAX_COALESCED_ROWS` rows; an error
        reply if this worker keeps none of them."""
        try:
            try:
                ask = TelemetryReplay.model_validate_json(query.payload.to_bytes() if query.payload else b"")
            except ValueError as exc:
                query.reply_err(short_error(exc))
                return
            stop = min(ask.stop, ask.start + REPLAY_MAX_SAMPLES)  # one query never pulls a whole run
            telemetry = self.archive.rows(ask.execution_id, ask.start, stop)
            if telemetry is None or not len(telemetry):
                query.reply_err(f"worker {self.worker_id} keeps no telemetry of {ask.execution_id} from sample "
                                f"{ask.start} to {stop - 1}")  # fmt: skip
                return
            key = self.keys.replay(self.worker_id)
            for batch in replay_batches(telemetry, ask.execution_id, ask.start):
                data = batch.model_dump_json().encode()
                query.reply(key, data, attachment=self.reports.signature(ask.execution_id, data))
        except Exception:
            log.exception("replay query failed")

    def _on_start(self, query) -> None:
        execution_id = "?"

        def reply(code: str, reason: str | None = None) -> None:
            answer = StartReply(accepted=code == "accepted", code=code, worker_id=self.worker_id,
                                execution_id=execution_id, reason=reason)  # fmt: skip
            query.reply(self.keys.start(self.worker_id), answer.model_dump_json())

        try:
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                named = StartExecution.model_validate_json(payload)
                execution_id = named.execution_id
                secret = query.attachment.to_bytes() if query.attachment is not None else None
                start = self.demonstrations.completed(named)
                if start is None:
                    reply("need_demonstration", f"worker {self.worker_id} keeps no demonstration "
                          f"{named.demonstration_id}")  # fmt: skip
                    return
                worlds = worlds_for(start)
                estimate = _whole_estimate(
                    [execution_estimate(w.skill, start.request, float(w.config.time_step_s)) for w in worlds]
                )
            except Exception as exc:
                reply("error", short_error(exc))
                return
            if over := over_budget(estimate, self.settings.budget):
                reply("error", over)
                return
            if start.answer_by_unix_s is not None and time.time() > start.answer_by_unix_s - START_REPLY_MARGIN_S:
                reply("busy", "the start request expired before this worker could take it (the caller gave up)")
                return
            with self._lock:
                busy = self._busy_reason()
                if busy is None and not self._closed:
                    run = ExecutionRun(self, start, worlds)
                    self._run = run
                    self.executions_run += 1
            if busy is not None or self._closed:
                reply("busy", busy or "worker shutting down")
                return
            if secret is not None:
                self.reports.keep_secret(execution_id, secret)
            # Listen for commands before anyone knows the execution exists.
            run.cmd_subscriber = self._session.declare_subscriber(self.keys.cmd(execution_id), run.command_sample)
            reply("accepted")
            log.info("%s accepted (%d segments, pace %s, engine %s)", execution_id, run.segments, run.request.pace,
                     run.request.engine)  # fmt: skip
            run.thread = threading.Thread(target=then_trim_heap, args=(run.run,), name=f"execution-{execution_id}",
                                          daemon=True)  # fmt: skip
            run.thread.start()
        except Exception as exc:
            log.exception("start query failed")
            with self._lock:
                if self._run is not None and self._run.execution_id == execution_id and self._run.thread is None:
                    self._run = None
            try:
                reply("error", short_error(exc))
            except Exception:
                log.debug("could not reply", exc_info=True)

    def _busy_reason(self) -> str | None:
        if self._run is not None:
            return f"worker {self.worker_id} is executing {self._run.execution_id}"
        if self._recording:
            return f"worker {self.worker_id} is recording a demonstration"
        return None

    def finish(self, run: ExecutionRun, final: FinalStatus) -> None:
        """End of an execution (its thread): free the worker, then publish the final status."""
        run.stop_listening()
        with self._lock:
            if self._run is run:
                self._run = None
        self.archive.finish(run.execution_id)
        status = run.status(abort_received_t=run.abort_received_t, paused=False, **final)
        log.info("%s %s after %.3f s simulated", run.execution_id, status.phase.value, status.t)

    def _on_record(self, query) -> None:
        try:
            try:
                request = record_request(query.payload.to_bytes() if query.payload else b"", self.settings.budget)
            except Exception as exc:
                query.reply(self.keys.record(self.worker_id), RecordReply(worker_id=self.worker_id, code="error",
                                                        error=short_error(exc)).model_dump_json())  # fmt: skip
                return
            with self._lock:
                busy = self._busy_reason() or ("worker shutting down" if self._closed else None)
                if busy is None:
                    self._recording = True
            if busy is not None:
                query.reply(self.keys.record(self.worker_id), RecordReply(worker_id=self.worker_id, code="busy",
                                                        error=busy).model_dump_json())  # fmt: skip
                return
            # Recording takes seconds: reply from a thread, keep the zenoh callback thread free.
            threading.Thread(target=then_trim_heap, args=(self._record, query, request), name="record",
                             daemon=True).start()  # fmt: skip
        except Exception:
            log.exception("record query failed")
            with self._lock:
                self._recording = False

    def _record(self, query, request: RecordRequest) -> None:
        """The recording thread: record, reply, and only then free the worker (its info says ``recording`` until
        the reply, whose demonstration may take seconds to encode, is out)."""
        try:
            reply = recording_reply(self.worker_id, request)
            try:
                query.reply(self.keys.record(self.worker_id), reply.model_dump_json())
                query.drop()
            except Exception:
                log.exception("record reply failed")
        finally:
            with self._lock:
                self._recording = False


def _whole_estimate(estimates: list[JobEstimate]) -> JobEstimate:
    """The estimate of one execution that runs its strokes one after the other (each estimated on its own): their
    stretches of time in order, the longest phase of any."""
    if len(estimates) == 1:
        return estimates[0]
    longest = max((e.longest_phase for e in estimates), key=lambda part: part.simulated_s)
    return estimates[0].model_copy(update={"parts": [p for e in estimates for p in e.parts], "longest_phase": longest})


def run_worker(settings: WorkerSettings | None = None, worker_id: str | None = None) -> int:
    """Run a worker until SIGINT/SIGTERM (see the module docstring); returns the exit code (0)."""
    bound_heap()  # before the execution and Zenoh threads allocate: one process runs job after job
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: stop.set())
    worker = Worker(settings, worker_id)
    claim = worker.settings.login_claim
    try:
        if worker.open(stop):
            while not stop.wait(0.5):
                if claim is not None and time.time() - claim.stat().st_mtime > LOGIN_LEASE_S / 6:
                    os.utime(claim)  # renew the lease on the login
    finally:
        worker.close()
        if claim is not None:
            claim.unlink(missing_ok=True)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


__all__ = ["Worker", "run_worker"]
