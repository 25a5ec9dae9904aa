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
``world_overrides``. While it runs the worker

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

Nothing an execution or a recording does can kill the worker: any exception becomes a ``failed`` status or an
``error`` reply. On SIGINT/SIGTERM the running execution is aborted, its final status published, everything
undeclared, and the process exits with 0.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import secrets
import signal
import socket
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from schemas.bus import (
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    ENV_ENDPOINTS,
    ENV_PREFIX,
    FINAL_PHASES,
    HEARTBEAT_S,
    REPLAY_MAX_SAMPLES,
    CommandName,
    ExecutionCommand,
    ExecutionStatus,
    KeyExpressions,
    RecordReply,
    RecordRequest,
    StartExecution,
    StartReply,
    TelemetryReplay,
    WorkerInfo,
    check_id,
    session_config,
    split_endpoints,
)
from schemas.bus_security import ENV_LOGINS, BusSecurity, challenge_signature, parse_env, report_signature
from schemas.demonstration import Demonstration
from schemas.execution import PHASES_BY_CODE, EnvironmentChange, ExecutionPhase, TelemetryMode
from schemas.job_budget import JobBudget, JobEstimate
from sim_worker.process_memory import bound_heap, trim_heap
from sim_worker.telemetry import Telemetry
from sim_worker.telemetry_archive import TelemetryArchive
from skills.job_estimate import execution_estimate

log = logging.getLogger("contact_skills.worker")

STATUS_CACHE = 200
"""Latest statuses kept for the status queryable (executions of this worker)."""
DEMONSTRATIONS_CACHED = 4
"""Demonstrations kept for the starts that name them (``StartExecution.demonstration_id``), at most."""
DEMONSTRATION_SAMPLES_KEPT = 100_000
"""Samples of the kept demonstrations, at most (the newest is kept whatever its size): as validated models (lists
of Python floats) a sample takes ~640 bytes, so about 64 MB; a minute at 1 kHz is 38 MB. A start naming one no
longer kept is answered ``need_demonstration`` and the API sends it again."""
MAX_COALESCED_ROWS = 1000
"""Most control steps sent in one telemetry message when queued batches are merged to catch up, and in one reply
to a replay query."""
PAUSED_SLEEP_S = 1e-3
"""While paused, each held control step sleeps this long (so a paused fast execution does not spin)."""
FINAL_STATUS_HEAD_START_S = 0.1
"""At shutdown, pause between publishing the last status and undeclaring the liveliness token, s."""
SHUTDOWN_JOIN_S = 10.0
"""How long shutdown waits for the aborted execution and the publisher to finish, s."""
START_REPLY_MARGIN_S = 1.0
"""A start request is refused when its reply could reach the caller less than this before the caller's deadline
(``StartExecution.answer_by_unix_s``; the reply's transit, and clocks of other machines a little off), s."""


@dataclass
class WorkerSettings:
    """Where the worker connects and under which prefix (env: ``CONTACT_SKILLS_ZENOH_ENDPOINTS``, ``..._PREFIX``)."""

    endpoints: list[str] = field(default_factory=lambda: [DEFAULT_ENDPOINT])
    prefix: str = DEFAULT_PREFIX
    connect_retry_s: float = 1.0
    """Pause between attempts while the router is not reachable, s."""
    connect_timeout_s: float | None = None
    """Give up connecting after this long (None: keep trying until a signal arrives), s."""
    security: BusSecurity = field(default_factory=BusSecurity)
    """Login and TLS (``schemas.bus_security``); with a login the worker's id is its user name."""
    budget: JobBudget = field(default_factory=JobBudget)
    """The most one execution or recording may imply (``schemas.job_budget``): a job over it is refused, a job that
    reaches it while running is aborted."""
    login_claim: Path | None = None
    """The claim this worker holds on a login of a shared folder (``CONTACT_SKILLS_ZENOH_LOGINS``, :func:`claim_login`):
    renewed while it runs, released when it stops."""

    @classmethod
    def from_env(cls) -> WorkerSettings:
        """Settings from the environment, defaults for what is not set. With ``CONTACT_SKILLS_ZENOH_LOGINS`` (a folder
        of ``worker-K.env`` files) the worker claims a login no other live worker holds."""
        env, claim = dict(os.environ), None
        if logins := env.get(ENV_LOGINS):
            claim, login = claim_login(Path(logins), socket.gethostname())
            env.update(login)
        return cls(
            endpoints=split_endpoints(env.get(ENV_ENDPOINTS)) or [DEFAULT_ENDPOINT],
            prefix=env.get(ENV_PREFIX) or DEFAULT_PREFIX,
            security=BusSecurity.from_env(env),
            budget=JobBudget.from_env(os.environ),
            login_claim=claim,
        )


LOGIN_LEASE_S = 30.0
"""A worker's claim on a shared login (:func:`claim_login`) lapses when not renewed for this long, s: the login of a
container that was removed (``--scale`` down) is free again; a running worker renews its claim every few seconds."""


def claim_login(folder: Path, holder: str) -> tuple[Path, dict[str, str]]:
    """Claim one of the ``worker-K.env`` logins of ``folder`` for ``holder`` (this container's host name, stable
    across its restarts): the one it held before, else the first that no one holds or whose claim lapsed
    (:data:`LOGIN_LEASE_S`). Claims are files ``folder/claims/worker-K`` holding the holder's name, made with
    ``O_EXCL`` (two workers starting at once never get the same login). Returns (the claim, the login's variables).
    Raises ValueError when every login is held."""
    claims = folder / "claims"
    claims.mkdir(exist_ok=True)
    logins = sorted(folder.glob("worker-*.env"), key=lambda f: int(f.stem.rsplit("-", 1)[1]))
    for prefer_own in (True, False):
        for login in logins:
            claim = claims / login.stem
            try:
                descriptor = os.open(claim, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
            except FileExistsError:
                try:
                    owner, age = claim.read_text(), time.time() - claim.stat().st_mtime
                except FileNotFoundError:
                    continue
                if owner != holder and (prefer_own or age < LOGIN_LEASE_S):
                    continue
                taken = claims / f".{login.stem}.{holder}"
                taken.write_text(holder)
                os.replace(taken, claim)  # a lapsed claim: whoever replaced it last holds it, the others go on
                time.sleep(0.2)
                if claim.read_text() != holder:
                    continue
            else:
                if prefer_own:  # the first pass only looks for this holder's own claim
                    os.close(descriptor)
                    claim.unlink()
                    continue
                with os.fdopen(descriptor, "w") as out:
                    out.write(holder)
            return claim, parse_env(login.read_text())
    raise ValueError(f"no free worker login in {folder}: all {len(logins)} are held by live workers (make more with "
                     "`contact-skills bus-keys --workers N`)")  # fmt: skip


def default_worker_id() -> str:
    """``worker-<6 random hex digits>`` for a worker without a login or ``--id``: unique enough on one bus, and
    naming neither the host nor the process (the id shows on the open ``/health`` and ``GET /executions``)."""
    return f"worker-{secrets.token_hex(3)}"


# ---------------------------------------------------------------------------------------------------------------
# Worlds
# ---------------------------------------------------------------------------------------------------------------


def worlds_for(start: StartExecution) -> list:
    """Where ``start``'s skill runs (``sim_worker.execution_world.execution_worlds``): its world and its placed skill,
    or one world per stroke when no single placement reaches them all (the run goes through them in order).

    Raises ValueError (an unknown scenario or world field, a skill out of reach) with the message to reply.
    """
    from sim_worker.execution_world import execution_worlds

    request = start.request
    return execution_worlds(
        request.skill,  # type: ignore[arg-type]  (inline, checked by StartExecution)
        request.environment,
        scenario=request.scenario,
        overrides=start.world_overrides,
        demonstration=start.demonstration,
        approach_clearance_m=request.approach_clearance_m,
    )


def _work_piece_meshes(config, environment: EnvironmentChange) -> list:
    """The solids of the world ``config`` (a ``WorldConfig``) as the run meets them, moved by the environment's known
    and unknown offsets as the executor moves them, as ``schemas.dashboard.WorkPieceMesh`` (world, m)."""
    from sim_worker.executor import shifted_world_config
    from sim_worker.geometry import WorldGeometry
    from sim_worker.world_build import work_piece_meshes

    shift = np.asarray(environment.offset, dtype=float) + np.asarray(environment.unknown_offset, dtype=float)
    return work_piece_meshes(WorldGeometry(shifted_world_config(config, shift)))


def _load_execution_code() -> None:
    """Import what an execution runs and load the compiled control loop (``sim_worker.warm_up``) before the worker
    shows itself: its first execution would otherwise pay for it (~2 s on a quiet core), not just the ones after."""
    import sim_worker.execution_world
    import sim_worker.executor  # noqa: F401  (imported for its cost, used by _Run.run)
    from sim_worker.warm_up import warm_up

    warm_up()


# ---------------------------------------------------------------------------------------------------------------
# One execution
# ---------------------------------------------------------------------------------------------------------------


class _Run:
    """State of one execution, shared by its thread, the command callback and the publisher."""

    def __init__(self, worker: Worker, start: StartExecution, worlds: list) -> None:
        self.worker = worker
        self.execution_id = start.execution_id
        self.start = start
        self.request = start.request
        self.worlds = worlds
        """The resolved ``ExecutionWorld`` (world config, placed skill and demonstration), or one per stroke."""
        self.segments = sum(len(world.skill.segments) for world in worlds)
        """Segments over all the worlds: a stroke's are numbered after the strokes before it."""
        self.dt = float(worlds[0].config.time_step_s)
        self.t_offset = 0.0
        self.segment_offset = 0
        """Where the world running now starts, in the execution's time (s) and segment numbers."""
        self.streams = self.request.telemetry is TelemetryMode.stream
        """Whether its control steps are published and kept for replays (``ExecutionSettings.telemetry``)."""
        self.step_limit = worker.settings.budget.step_limit(self.dt)
        """The most control steps it may run (the job budget at its time step): past them it is aborted."""
        self.abort_requested = False
        self.abort_received_t: float | None = None
        self.abort_reason: str | None = None
        self.paused = False
        self.paused_at = 0.0
        """time.monotonic() of the last pause (see ``should_pause``)."""
        self.polls = 0
        """should_abort() calls = control steps completed."""
        self.phase = ExecutionPhase.pending
        self.segment_index = -1
        self.t = 0.0
        self.seq = 0
        self.status_at = time.monotonic()
        """When the last status was queued (a heartbeat follows :data:`HEARTBEAT_S` after it)."""
        self.ended = False
        """Its final status is queued: nothing follows it."""
        self.lock = threading.Lock()
        self.cmd_subscriber = None
        self.thread: threading.Thread | None = None
        self.work_piece = _work_piece_meshes(worlds[0].config, start.request.environment)
        """The solids of its (first) world, sent with its first status (the dashboard's 3-D scene draws them)."""

    # Polled by the control loop (its thread).
    def should_abort(self) -> bool:
        """Whether to stop now: an abort was asked for, or the run reached its step limit (its pauses' held steps, a
        surface found beyond its window: what its estimate could not foresee)."""
        self.polls += 1
        if self.polls >= self.step_limit and not self.abort_requested:
            reason = f"reached {self.worker.settings.budget.describe()} after {self.polls:,} control steps"
            self.command(ExecutionCommand(command=CommandName.abort, execution_id=self.execution_id, reason=reason))
        return self.abort_requested

    def should_pause(self) -> bool:
        """Hold the reference while paused; a pause longer than ``request.pause_timeout_s`` aborts the run, so a
        forgotten pause never holds the worker."""
        if self.paused and not self.abort_requested:
            waited = time.monotonic() - self.paused_at
            if waited > self.request.pause_timeout_s:
                reason = f"paused for {waited:.0f} s, longer than pause_timeout_s ({self.request.pause_timeout_s:g} s)"
                self.command(ExecutionCommand(command=CommandName.abort, execution_id=self.execution_id, reason=reason))
                return False
            time.sleep(PAUSED_SLEEP_S)
            return True
        return False

    def on_sample(self, tel) -> None:
        """A batch of control steps from the loop: queue it (unless the request's telemetry is ``none``) and a status
        for each phase/segment change. A stroke after the first runs in its own world from t = 0: its rows move to
        the execution's time and segment numbers (the batch is the loop's copy)."""
        if self.t_offset or self.segment_offset:
            tel.data[:, 0] += self.t_offset
            segments = tel.data[:, 2]
            segments[segments >= 0] += self.segment_offset
        if self.streams:
            stamp = time.time()
            first = self.worker.archive.append(self.execution_id, tel)
            self.worker._publish_queue.put(("telemetry", self.execution_id, tel, stamp, first))
        codes, segments, t = tel.phase_codes, tel.segment_index, tel.t
        changes = np.flatnonzero((codes[1:] != codes[:-1]) | (segments[1:] != segments[:-1])) + 1
        for k in (0, *changes.tolist()):
            phase, segment = PHASES_BY_CODE[int(codes[k])], int(segments[k])
            if phase in FINAL_PHASES:  # the loop's last rows: the final status, with the metrics, is _finish's
                break
            if phase is not self.phase or segment != self.segment_index:
                self.phase, self.segment_index = phase, segment
                where = f"segment {segment}" if segment >= 0 else "start pose"
                self.status(message=f"{where}: {phase.value}", t=float(t[k]))
        self.t = float(t[-1])

    # Any thread.
    def status(self, **fields: Any) -> ExecutionStatus:
        """Queue an ExecutionStatus with the current phase, segment, time and pause state (``fields`` override);
        after the final one nothing more is queued (the status is returned all the same)."""
        with self.lock:
            values = {
                "execution_id": self.execution_id,
                "worker_id": self.worker.worker_id,
                "attempt": self.start.attempt,
                "phase": self.phase,
                "segment_index": self.segment_index,
                "segments": self.segments,
                "t": self.t,
                "steps": self.polls,
                "paused": self.paused,
                "seq": self.seq,
                "work_piece": self.work_piece if self.seq == 0 else None,
                **fields,
            }
            status = ExecutionStatus(**values)
            if not self.ended:
                self.seq += 1
                self.status_at = time.monotonic()
                self.ended = status.final
                self.worker._publish_queue.put(("status", self.execution_id, status, None, None))
        return status

    def beat(self) -> None:
        """Queue a heartbeat (the current status) if no status went out for :data:`HEARTBEAT_S`: the API tells a
        run in a long phase from a worker gone silent."""
        with self.lock:
            due = not self.ended and time.monotonic() - self.status_at >= HEARTBEAT_S
        if due:
            self.status(message=f"{self.phase.value}: running")

    def command(self, command: ExecutionCommand) -> None:
        """Apply a command (zenoh callback thread)."""
        note = f" ({command.reason})" if command.reason else ""
        if command.command is CommandName.abort:
            if not self.abort_requested:
                # The last control step completed now: polls steps done, the last row at t = (polls - 1) dt.
                self.abort_received_t = max(self.polls - 1, 0) * self.dt
                self.abort_reason = command.reason or "aborted on request"
                self.abort_requested = True
                log.info("%s: abort received at t=%.3f s%s", self.execution_id, self.abort_received_t, note)
        elif command.command is CommandName.pause:
            if not self.paused:
                self.paused_at = time.monotonic()
                self.paused = True
                self.status(message=f"paused{note}")
        elif command.command is CommandName.resume and self.paused:
            self.paused = False
            self.status(message=f"resumed{note}")

    def run(self) -> None:
        """The execution thread: run the skill, publish the final status, free the worker."""
        from sim_worker.executor import run_skill
        from sim_worker.metrics import combined_stroke_metrics

        final: dict[str, Any]
        try:
            self.status(message="accepted")
            strokes = []
            for world in self.worlds:  # one, or one per stroke: each from where the one before ended
                result = run_skill(
                    world,
                    self.request,
                    on_sample=self.on_sample,
                    should_abort=self.should_abort,
                    should_pause=self.should_pause,
                )
                strokes.append(result.metrics)
                if result.metrics.phase is not ExecutionPhase.done:
                    break
                self.t_offset += result.metrics.duration_s
                self.segment_offset += len(world.skill.segments)
            metrics = combined_stroke_metrics(strokes)
            phase = metrics.phase
            error = metrics.abort_reason
            if phase is ExecutionPhase.aborted and self.abort_requested and error == "aborted on request":
                error = self.abort_reason
                metrics = metrics.model_copy(update={"abort_reason": error})
            message = {"done": "finished every segment"}.get(phase.value, f"{phase.value}: {error}")
            final = {"phase": phase, "metrics": metrics, "error": error, "message": message,
                     "t": max(metrics.duration_s - self.dt, 0.0), "steps": metrics.steps}  # fmt: skip
        except Exception as exc:  # the worker must survive whatever an execution does
            log.exception("%s failed", self.execution_id)
            final = {"phase": ExecutionPhase.failed, "error": f"{type(exc).__name__}: {exc}",
                     "message": f"failed: {type(exc).__name__}: {exc}"}  # fmt: skip
        self.worker._finish(self, final)
        self.worlds = []  # their work pieces and skills: freed before the heap is trimmed (``_then_trim_heap``)


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
        self._run: _Run | None = None
        self._recording = False
        self._statuses: OrderedDict[str, tuple[bytes, bytes | None]] = OrderedDict()
        """The latest status of each recent execution as sent: (payload, signature)."""
        self._secrets: OrderedDict[str, bytes] = OrderedDict()
        """Each recent execution's secret (the start query's attachment): what its reports are signed with."""
        self._demonstrations: OrderedDict[str, Demonstration] = OrderedDict()
        """The demonstrations starts sent, by their stored id, the most recently used last."""
        self.archive = TelemetryArchive()
        self._publish_queue: queue.Queue = queue.Queue()
        self._publisher: threading.Thread | None = None
        self._session = None
        self._declared: list = []
        self._closed = False

    # ------------------------------------------------------------------------------------------ lifecycle

    def open(self, stop: threading.Event | None = None) -> bool:
        """Connect (retrying until the router answers, ``stop`` is set or the timeout passes) and declare.

        Returns False if stopped or timed out before a connection.
        """
        import zenoh

        _load_execution_code()
        config = zenoh.Config.from_json5(
            json.dumps(session_config("client", connect=self.settings.endpoints, security=self.settings.security))
        )
        deadline = None if self.settings.connect_timeout_s is None else time.time() + self.settings.connect_timeout_s
        warned = False
        while self._session is None:
            try:
                self._session = zenoh.open(config)
            except zenoh.ZError as exc:
                if not warned:
                    log.warning("router not reachable at %s (%s); retrying", self.settings.endpoints, exc)
                    warned = True
                if (stop is not None and stop.wait(self.settings.connect_retry_s)) or (
                    deadline is not None and time.time() > deadline
                ):
                    return False
                if stop is None:
                    time.sleep(self.settings.connect_retry_s)
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
            self._publish_queue.put(None)
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
        nothing = object()  # "no item held back" (None is the queue's stop sentinel)
        held: Any = nothing
        while True:
            with self._lock:
                run = self._run
            if run is not None:
                run.beat()
            try:
                item = self._publish_queue.get(timeout=HEARTBEAT_S) if held is nothing else held
            except queue.Empty:
                continue
            held = nothing
            if item is None:
                return
            kind, execution_id, payload, stamp, first = item
            try:
                if kind == "telemetry":
                    parts = [payload.data]
                    while sum(len(p) for p in parts) < MAX_COALESCED_ROWS:
                        try:
                            following = self._publish_queue.get_nowait()
                        except queue.Empty:
                            break
                        if following is None or following[0] != "telemetry" or following[1] != execution_id:
                            held = following
                            break
                        parts.append(following[2].data)
                    telemetry = payload if len(parts) == 1 else Telemetry(np.concatenate(parts))
                    batch = telemetry.to_batch(execution_id)
                    batch.sent_unix_s, batch.first_sample = stamp, first
                    batch.seq = self.archive.next_batch(execution_id)
                    key, data = self.keys.telemetry(execution_id), batch.model_dump_json().encode()
                    signature = self._signature(execution_id, data)
                else:
                    payload.sent_unix_s = time.time()
                    key, data = self.keys.status(execution_id), payload.model_dump_json().encode()
                    signature = self._signature(execution_id, data)
                    with self._lock:
                        self._statuses[execution_id] = (data, signature)
                        self._statuses.move_to_end(execution_id)
                        while len(self._statuses) > STATUS_CACHE:
                            self._statuses.popitem(last=False)
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
            with self._lock:
                statuses = [
                    (e, data, signature, self._secrets.get(e)) for e, (data, signature) in self._statuses.items()
                ]
            for execution_id, data, signature, secret in statuses:
                key = self.keys.status(execution_id)
                if wanted.intersects(zenoh.KeyExpr(key)):
                    if challenge and secret is not None:  # the asker wants proof this worker answers now
                        signature = challenge_signature(secret, data, challenge)
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
                query.reply_err(_short_error(exc))
                return
            stop = min(ask.stop, ask.start + REPLAY_MAX_SAMPLES)  # one query never pulls a whole run
            telemetry = self.archive.rows(ask.execution_id, ask.start, stop)
            if telemetry is None or not len(telemetry):
                query.reply_err(f"worker {self.worker_id} keeps no telemetry of {ask.execution_id} from sample "
                                f"{ask.start} to {stop - 1}")  # fmt: skip
                return
            key = self.keys.replay(self.worker_id)
            for first in range(0, len(telemetry), MAX_COALESCED_ROWS):
                batch = Telemetry(telemetry.data[first : first + MAX_COALESCED_ROWS]).to_batch(ask.execution_id)
                batch.first_sample = ask.start + first
                data = batch.model_dump_json().encode()
                query.reply(key, data, attachment=self._signature(ask.execution_id, data))
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
                start = self._with_demonstration(named)
                if start is None:
                    reply("need_demonstration", f"worker {self.worker_id} keeps no demonstration "
                          f"{named.demonstration_id}")  # fmt: skip
                    return
                worlds = worlds_for(start)
                estimate = _whole_estimate(
                    [execution_estimate(w.skill, start.request, float(w.config.time_step_s)) for w in worlds]
                )
            except Exception as exc:
                reply("error", _short_error(exc))
                return
            if over := _over_budget(estimate, self.settings.budget):
                reply("error", over)
                return
            if start.answer_by_unix_s is not None and time.time() > start.answer_by_unix_s - START_REPLY_MARGIN_S:
                reply("busy", "the start request expired before this worker could take it (the caller gave up)")
                return
            with self._lock:
                busy = self._busy_reason()
                if busy is None and not self._closed:
                    run = _Run(self, start, worlds)
                    self._run = run
                    self.executions_run += 1
            if busy is not None or self._closed:
                reply("busy", busy or "worker shutting down")
                return
            if secret is not None:
                with self._lock:
                    self._secrets[execution_id] = secret
                    self._secrets.move_to_end(execution_id)
                    while len(self._secrets) > STATUS_CACHE:
                        self._secrets.popitem(last=False)
            # Listen for commands before anyone knows the execution exists.
            run.cmd_subscriber = self._session.declare_subscriber(
                self.keys.cmd(execution_id), lambda sample: self._on_command(run, sample)
            )
            reply("accepted")
            log.info("%s accepted (%d segments, pace %s)", execution_id, run.segments, run.request.pace)
            run.thread = threading.Thread(target=_then_trim_heap, args=(run.run,), name=f"execution-{execution_id}",
                                          daemon=True)  # fmt: skip
            run.thread.start()
        except Exception as exc:
            log.exception("start query failed")
            with self._lock:
                if self._run is not None and self._run.execution_id == execution_id and self._run.thread is None:
                    self._run = None
            try:
                reply("error", _short_error(exc))
            except Exception:
                log.debug("could not reply", exc_info=True)

    def _signature(self, execution_id: str, data: bytes) -> bytes | None:
        """The attachment of a report of ``execution_id`` (``schemas.bus_security.report_signature``); None for an
        execution started without a secret (a caller that checks none)."""
        with self._lock:
            secret = self._secrets.get(execution_id)
        return None if secret is None else report_signature(secret, data)

    def _with_demonstration(self, start: StartExecution) -> StartExecution | None:
        """``start`` with its demonstration: as sent (and kept under its ``demonstration_id`` for the starts that
        follow), or this worker's copy of the one it names; None when it names one this worker does not keep."""
        key = start.demonstration_id
        if key is None:
            return start
        with self._lock:
            if start.demonstration is not None:
                self._demonstrations[key] = start.demonstration
            kept = self._demonstrations.get(key)
            if kept is not None:
                self._demonstrations.move_to_end(key)
            while len(self._demonstrations) > 1 and (
                len(self._demonstrations) > DEMONSTRATIONS_CACHED
                or sum(len(d.t) for d in self._demonstrations.values()) > DEMONSTRATION_SAMPLES_KEPT
            ):
                self._demonstrations.popitem(last=False)  # the least recently named first
        if kept is None:
            return None
        return start if start.demonstration is not None else start.model_copy(update={"demonstration": kept})

    def _busy_reason(self) -> str | None:
        if self._run is not None:
            return f"worker {self.worker_id} is executing {self._run.execution_id}"
        if self._recording:
            return f"worker {self.worker_id} is recording a demonstration"
        return None

    def _on_command(self, run: _Run, sample) -> None:
        try:
            command = ExecutionCommand.model_validate_json(sample.payload.to_bytes())
            run.command(command)
        except Exception:
            log.exception("bad command for %s", run.execution_id)

    def _finish(self, run: _Run, final: dict[str, Any]) -> None:
        """End of an execution (its thread): free the worker, then publish the final status."""
        if run.cmd_subscriber is not None:
            try:
                run.cmd_subscriber.undeclare()
            except Exception:
                log.debug("undeclare cmd failed", exc_info=True)
        with self._lock:
            if self._run is run:
                self._run = None
        self.archive.finish(run.execution_id)
        status = run.status(abort_received_t=run.abort_received_t, paused=False, **final)
        log.info("%s %s after %.3f s simulated", run.execution_id, status.phase.value, status.t)

    def _on_record(self, query) -> None:
        try:
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                request = RecordRequest.model_validate_json(payload)
                from sim_worker.teacher import recording_estimate

                over = _over_budget(recording_estimate(request.scenario, **request.overrides), self.settings.budget)
                if over:
                    raise ValueError(over)
            except Exception as exc:
                query.reply(self.keys.record(self.worker_id), RecordReply(worker_id=self.worker_id, code="error",
                                                        error=_short_error(exc)).model_dump_json())  # fmt: skip
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
            threading.Thread(target=_then_trim_heap, args=(self._record, query, request), name="record",
                             daemon=True).start()  # fmt: skip
        except Exception:
            log.exception("record query failed")
            with self._lock:
                self._recording = False

    def _record(self, query, request: RecordRequest) -> None:
        """The recording thread: record, reply, and only then free the worker (its info says ``recording`` until
        the reply, whose demonstration may take seconds to encode, is out)."""
        started = time.perf_counter()
        try:
            try:  # the import too: whatever fails, the query is answered and the worker is free again
                from sim_worker.teacher import record_demonstration

                log.info("recording %s (seed %d, overrides %s)", request.scenario, request.seed, request.overrides)
                recording = record_demonstration(request.scenario, request.seed, **request.overrides)
                reply = RecordReply(
                    worker_id=self.worker_id,
                    code="ok",
                    demonstration=recording.demonstration,
                    ground_truth=recording.ground_truth_dict(),
                    wall_s=time.perf_counter() - started,
                )
            except Exception as exc:
                reply = RecordReply(worker_id=self.worker_id, code="error", error=_short_error(exc),
                                    wall_s=time.perf_counter() - started)  # fmt: skip
            try:
                query.reply(self.keys.record(self.worker_id), reply.model_dump_json())
                query.drop()
            except Exception:
                log.exception("record reply failed")
        finally:
            with self._lock:
                self._recording = False


def _then_trim_heap(job: Callable[..., None], *args: Any) -> None:
    """A job thread: run ``job(*args)``, then give the heap's free pages back (``trim_heap``): once it has returned,
    its locals (the worlds, plans and rows of an execution; a recording and its reply) are gone."""
    try:
        job(*args)
    finally:
        trim_heap()


def _whole_estimate(estimates: list[JobEstimate]) -> JobEstimate:
    """The estimate of one execution that runs its strokes one after the other (each estimated on its own): their
    stretches of time in order, the longest phase of any."""
    if len(estimates) == 1:
        return estimates[0]
    longest = max((e.longest_phase for e in estimates), key=lambda part: part.simulated_s)
    return estimates[0].model_copy(update={"parts": [p for e in estimates for p in e.parts], "longest_phase": longest})


def _over_budget(estimate: JobEstimate, budget: JobBudget) -> str | None:
    """Why a job is refused (``field: reason`` for each setting that takes it past ``budget``), or None if it fits."""
    problems = estimate.problems(budget)
    return "; ".join(f"{field}: {message}" for field, message in problems) or None


def _short_error(exc: BaseException) -> str:
    """One readable line (pydantic errors: field and reason)."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        parts = [f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}" for e in exc.errors()[:5]]
        return "; ".join(parts)
    text = str(exc) or type(exc).__name__
    return text if isinstance(exc, ValueError | TypeError) else f"{type(exc).__name__}: {text}"


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


__all__ = ["Worker", "WorkerSettings", "default_worker_id", "run_worker", "worlds_for"]
