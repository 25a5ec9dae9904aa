"""One execution on a sim worker (:class:`ExecutionRun`): its worlds (:func:`worlds_for`), its thread running the
skill, the control loop's callbacks (abort, pause, telemetry), its statuses and its commands. What it needs of the
worker that runs it: :class:`RunningWorker`."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any, NotRequired, Protocol, TypedDict

import numpy as np

from execution.telemetry import Telemetry
from schemas.bus import FINAL_PHASES, HEARTBEAT_S, CommandName, ExecutionCommand, ExecutionStatus, StartExecution
from schemas.execution import (
    PHASES_BY_CODE,
    EnvironmentChange,
    ExecutionMetrics,
    ExecutionPhase,
    GainSchedule,
    TelemetryBatch,
    TelemetryMode,
)
from schemas.world import engine_to_run
from sim_worker.process_memory import trim_heap
from sim_worker.telemetry_archive import TelemetryArchive
from sim_worker.worker_settings import WorkerSettings

log = logging.getLogger("contact_skills.worker")

MAX_COALESCED_ROWS = 1000
"""Most control steps sent in one telemetry message when queued batches are merged to catch up, and in one reply
to a replay query."""
NOTHING_HELD = object()
"""What :func:`merged_telemetry` holds back when it took nothing else from the queue (None is the queue's stop
sentinel)."""

PAUSED_SLEEP_S = 1e-3
"""While paused, each held control step sleeps this long (so a paused fast execution does not spin)."""


class FinalStatus(TypedDict):
    """The fields of an execution's final status its thread sets (:meth:`ExecutionRun.status` fills the rest)."""

    phase: ExecutionPhase
    error: str | None
    message: str
    metrics: NotRequired[ExecutionMetrics]
    """Absent when the execution failed before any (an exception in the run)."""
    t: NotRequired[float]
    """Time of the last control step, s."""
    steps: NotRequired[int]


class RunningWorker(Protocol):
    """What an execution uses of the worker running it (``sim_worker.zenoh_worker.Worker``)."""

    worker_id: str
    settings: WorkerSettings
    archive: TelemetryArchive
    """Its control steps, kept for replays."""
    publish_queue: queue.Queue
    """What the worker's publisher sends: ("telemetry" | "status", execution id, payload, stamp, first sample)."""

    def finish(self, run: ExecutionRun, final: FinalStatus) -> None:
        """Publish ``run``'s final status and free the worker."""


def then_trim_heap(job: Callable[..., None], *args: Any) -> None:
    """A job thread: run ``job(*args)``, then give the heap's free pages back (``trim_heap``): once it has returned,
    its locals (the worlds, plans and rows of an execution; a recording and its reply) are gone."""
    try:
        job(*args)
    finally:
        trim_heap()


# ---------------------------------------------------------------------------------------------------------------
# Worlds
# ---------------------------------------------------------------------------------------------------------------


def worlds_for(start: StartExecution) -> list:
    """Where ``start``'s skill runs (``sim_worker.execution_world.execution_worlds``): its world and its placed skill,
    or one world per stroke when no single placement reaches them all (the run goes through them in order).

    Raises ValueError (an unknown scenario or world field, a skill out of reach, a gain schedule the skill has no
    spread for) with the message to reply.
    """
    from sim_worker.execution_world import execution_worlds
    from skills.gain_schedule import missing_spread

    request = start.request
    if request.gains.gain_schedule is GainSchedule.from_spread and (reason := missing_spread(request.skill)):
        raise ValueError(reason)
    return execution_worlds(
        request.skill,  # type: ignore[arg-type]  (inline, checked by StartExecution)
        request.environment,
        scenario=request.scenario,
        overrides=start.world_overrides,
        demonstration=start.demonstration,
        approach_clearance_m=request.approach_clearance_m,
    )


def work_piece_meshes_as_run(config, environment: EnvironmentChange) -> list:
    """The solids of the world ``config`` (a ``WorldConfig``) as the run meets them, moved by the environment's known
    and unknown offsets as the executor moves them, as ``schemas.dashboard.WorkPieceMesh`` (world, m)."""
    from sim_worker.executor import shifted_world_config
    from sim_worker.geometry import WorldGeometry
    from sim_worker.world_build import work_piece_meshes

    shift = np.asarray(environment.offset, dtype=float) + np.asarray(environment.unknown_offset, dtype=float)
    return work_piece_meshes(WorldGeometry(shifted_world_config(config, shift)))


# ---------------------------------------------------------------------------------------------------------------
# One execution
# ---------------------------------------------------------------------------------------------------------------


class ExecutionRun:
    """State of one execution, shared by its thread, the command callback and the publisher."""

    def __init__(self, worker: RunningWorker, start: StartExecution, worlds: list) -> None:
        self.worker = worker
        self.execution_id = start.execution_id
        self.start = start
        self.request = start.request
        if self.request.engine is None:  # the request leaves the engine to its world, else to the worker running it
            engine = engine_to_run(None, worlds[0].config.engine, worker.settings.engine)
            self.request = self.request.model_copy(update={"engine": engine})
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
        self.work_piece = work_piece_meshes_as_run(worlds[0].config, start.request.environment)
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
            self.worker.publish_queue.put(("telemetry", self.execution_id, tel, stamp, first))
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
                self.worker.publish_queue.put(("status", self.execution_id, status, None, None))
        return status

    def beat(self) -> None:
        """Queue a heartbeat (the current status) if no status went out for :data:`HEARTBEAT_S`: the API tells a
        run in a long phase from a worker gone silent."""
        with self.lock:
            due = not self.ended and time.monotonic() - self.status_at >= HEARTBEAT_S
        if due:
            self.status(message=f"{self.phase.value}: running")

    def command_sample(self, sample: Any) -> None:
        """A command arriving on the execution's command key (a Zenoh sample; zenoh callback thread)."""
        try:
            self.command(ExecutionCommand.model_validate_json(sample.payload.to_bytes()))
        except Exception:
            log.exception("bad command for %s", self.execution_id)

    def stop_listening(self) -> None:
        """Undeclare the subscriber of its commands (the run has ended)."""
        if self.cmd_subscriber is not None:
            try:
                self.cmd_subscriber.undeclare()
            except Exception:
                log.debug("undeclare cmd failed", exc_info=True)

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
        from execution.metrics import combined_stroke_metrics
        from sim_worker.executor import run_skill

        final: FinalStatus
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
        self.worker.finish(self, final)
        self.worlds = []  # their work pieces and skills: freed before the heap is trimmed (``then_trim_heap``)


def merged_telemetry(first: Telemetry, execution_id: str, pending: queue.Queue) -> tuple[Telemetry, Any]:
    """``first`` (telemetry of ``execution_id`` taken from the worker's publish queue) merged with the telemetry of the
    same execution queued right behind it, up to :data:`MAX_COALESCED_ROWS` rows, nothing dropped or reordered; and
    the item taken from ``pending`` that does not belong to it (to publish next), or :data:`NOTHING_HELD`."""
    parts, held = [first.data], NOTHING_HELD
    while sum(len(p) for p in parts) < MAX_COALESCED_ROWS:
        try:
            following = pending.get_nowait()
        except queue.Empty:
            break
        if following is None or following[0] != "telemetry" or following[1] != execution_id:
            held = following
            break
        parts.append(following[2].data)
    return (first if len(parts) == 1 else Telemetry(np.concatenate(parts))), held


def replay_batches(telemetry: Telemetry, execution_id: str, start: int) -> list[TelemetryBatch]:
    """``telemetry`` (the archived rows from sample ``start`` of ``execution_id``) as replay batches of up to
    :data:`MAX_COALESCED_ROWS` rows, each numbered by its first sample."""
    batches = []
    for first in range(0, len(telemetry), MAX_COALESCED_ROWS):
        batch = Telemetry(telemetry.data[first : first + MAX_COALESCED_ROWS]).to_batch(execution_id)
        batch.first_sample = start + first
        batches.append(batch)
    return batches
