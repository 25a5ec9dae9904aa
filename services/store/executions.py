"""Stored executions and the execution queue: status, phase, metrics, and what a queued one will be sent."""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Callable

from pydantic import TypeAdapter

from schemas.api import ExecutionState
from schemas.dashboard import WorkPieceMesh
from schemas.execution import ExecutionMetrics, ExecutionPhase
from schemas.job_budget import TELEMETRY_BYTES_PER_STEP
from services.store.database import Database, log, new_id
from services.store.execution_queue import ExecutionQueue
from services.store.rows import ExecutionRow

_MESHES: TypeAdapter[list[WorkPieceMesh]] = TypeAdapter(list[WorkPieceMesh])
"""The ``work_piece`` column's JSON."""

ACTIVE = (ExecutionState.starting, ExecutionState.running, ExecutionState.paused)
_ACTIVE_IN = f"status IN ({', '.join('?' * len(ACTIVE))})"
"""SQL condition on the active statuses (their values as the parameters)."""
TERMINAL = (ExecutionState.done, ExecutionState.aborted, ExecutionState.failed)
RESTART_REASON = "API restarted while running; worker state unknown"


ADMITTED = (ExecutionState.queued, *ACTIVE)
"""The statuses of an execution whose telemetry is still to come: what it reserves counts against the quota."""
_RESERVED = (
    "SELECT COALESCE(SUM(MAX(e.reserved_bytes - ? * COALESCE((SELECT SUM(t.rows) FROM telemetry t "
    f"WHERE t.execution_id = e.id), 0), 0)), 0) FROM executions e WHERE e.status IN ({', '.join('?' * len(ADMITTED))})"
)
"""What the admitted executions still reserve, bytes: each its reservation less its samples stored so far (those
count in the pages in use); the sample size and the admitted statuses as the parameters."""


class QueueFull(RuntimeError):  # noqa: N818 (reads as what happened)
    """The execution queue holds its maximum."""


class QuotaFull(RuntimeError):  # noqa: N818 (reads as what happened)
    """An execution's telemetry does not fit in the storage quota beside what is stored and what the executions
    admitted before it reserve (bytes each)."""

    def __init__(self, stored_bytes: int, reserved_bytes: int, needed_bytes: int, quota_bytes: int) -> None:
        super().__init__(f"{needed_bytes} bytes needed, {stored_bytes} stored and {reserved_bytes} reserved of "
                         f"{quota_bytes}")  # fmt: skip
        self.stored_bytes, self.reserved_bytes = stored_bytes, reserved_bytes
        self.needed_bytes, self.quota_bytes = needed_bytes, quota_bytes


class ExecutionRepository(ExecutionQueue):
    """The ``executions`` table, with the queue (``services/queue.py``; its rows: :class:`ExecutionQueue`) and the
    execution's telemetry rows when it is deleted."""

    def __init__(self, database: Database) -> None:
        super().__init__(database)
        self._finish_listeners: list[Callable[[str], None]] = []

    def on_finish(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(execution_id)`` whenever an execution that ran (or was handed to a worker) is put in a
        terminal status (:meth:`update`, :meth:`fail_active`), after the commit, on the writing thread (a bus
        callback): it must be quick, e.g. set an event (`services.queue`, `services.sweeps` hand the next
        executions over at once instead of on their next poll)."""
        self._finish_listeners.append(listener)

    def _finished(self, execution_ids: list[str]) -> None:
        for execution_id in execution_ids:
            for listener in self._finish_listeners:
                try:
                    listener(execution_id)
                except Exception:  # a listener never undoes a committed write
                    log.exception("finish listener failed for %s", execution_id)

    def add(
        self,
        request: dict,
        skill_id: str | None,
        dispatch: str | None = None,
        priority: int = 0,
        max_queued: int | None = None,
        reserved_bytes: int = 0,
        quota_bytes: int = 0,
    ) -> ExecutionRow:
        """Store a new execution (``request`` as shown back): in status ``starting`` without ``dispatch``; with it
        (what to send to a worker, JSON) in status ``queued`` at ``priority``; reserving ``reserved_bytes`` of
        telemetry in the storage quota until it ends. Raises :class:`QueueFull` when ``max_queued`` are queued,
        :class:`QuotaFull` when what is stored, what the admitted executions reserve and ``reserved_bytes`` are
        more than ``quota_bytes`` (0: no quota); checked and stored in one transaction, so two admissions at once
        cannot both take the last room."""
        now = time.time()
        execution_id = new_id("exec")
        status = ExecutionState.starting if dispatch is None else ExecutionState.queued
        with self.database.transaction() as db:
            if max_queued is not None:
                queued = db.execute("SELECT COUNT(*) FROM executions WHERE status = ?", (ExecutionState.queued.value,))
                if queued.fetchone()[0] >= max_queued:
                    raise QueueFull(f"{max_queued} executions are already queued; try again later")
            if quota_bytes:
                stored, reserved = self.database.used_bytes(db), self._reserved(db)
                if stored + reserved + reserved_bytes > quota_bytes:
                    raise QuotaFull(stored, reserved, reserved_bytes, quota_bytes)
            db.execute(
                "INSERT INTO executions (id, skill_id, worker_id, status, phase, request, created, updated, priority, "
                "dispatch, reserved_bytes) VALUES (?, ?, NULL, ?, ?, ?, ?, ?, ?, ?, ?)",
                (execution_id, skill_id, status.value, ExecutionPhase.pending.value, json.dumps(request), now, now,
                 priority, dispatch, reserved_bytes),
            )  # fmt: skip
        found = self.get(execution_id)
        assert found is not None
        return found

    def reserved_bytes(self) -> int:
        """What the queued and running executions still reserve in the storage quota, bytes (see :data:`_RESERVED`;
        from their rows, so the same after a restart)."""
        return self._reserved(None)

    def _reserved(self, db: sqlite3.Connection | None) -> int:
        parameters = (TELEMETRY_BYTES_PER_STEP, *(s.value for s in ADMITTED))
        r = db.execute(_RESERVED, parameters).fetchone() if db is not None else self.database.one(_RESERVED, parameters)
        return int(r[0]) if r is not None else 0

    def get(self, execution_id: str) -> ExecutionRow | None:
        r = self.database.one("SELECT * FROM executions WHERE id = ?", (execution_id,))
        return None if r is None else ExecutionRow.of(r)

    def work_piece(self, execution_id: str) -> list[WorkPieceMesh] | None:
        """The solids of the world the execution runs in, as its worker reported them; None before it started (or
        for a run stored before they were reported)."""
        r = self.database.one("SELECT work_piece FROM executions WHERE id = ?", (execution_id,))
        return None if r is None or r[0] is None else _MESHES.validate_json(r[0])

    def latest_work_piece(self, skill_id: str) -> tuple[str, list[WorkPieceMesh]] | None:
        """The newest execution of ``skill_id`` whose worker reported its work piece: its id and the solids."""
        r = self.database.one(
            "SELECT id, work_piece FROM executions WHERE skill_id = ? AND work_piece IS NOT NULL "
            "ORDER BY created DESC, id LIMIT 1",
            (skill_id,),
        )
        return None if r is None else (r[0], _MESHES.validate_json(r[1]))

    def page(self, limit: int = 100, offset: int = 0) -> list[ExecutionRow]:
        """Executions, newest first."""
        rows = self.database.all("SELECT * FROM executions ORDER BY created DESC, id LIMIT ? OFFSET ?", (limit, offset))
        return [ExecutionRow.of(r) for r in rows]

    def active(self) -> list[ExecutionRow]:
        """Executions in status starting, running or paused, oldest first."""
        rows = self.database.all(
            f"SELECT * FROM executions WHERE {_ACTIVE_IN} ORDER BY created", tuple(s.value for s in ACTIVE)
        )
        return [ExecutionRow.of(r) for r in rows]

    def delete(self, execution_id: str, statuses: tuple[ExecutionState, ...] | None = None) -> bool:
        """Delete an execution and its telemetry, only if it is in one of ``statuses`` when given (one that never
        started: any status); True if deleted. Gets through a full disk (:meth:`Database.essential`)."""
        condition = f" AND status IN ({', '.join('?' * len(statuses))})" if statuses else ""

        def delete() -> bool:
            with self.database.transaction() as db:
                cursor = db.execute(
                    f"DELETE FROM executions WHERE id = ?{condition}",
                    (execution_id, *(s.value for s in statuses or ())),
                )
                if cursor.rowcount:
                    db.execute("DELETE FROM telemetry WHERE execution_id = ?", (execution_id,))
                return cursor.rowcount > 0

        return self.database.deletion(delete)

    # ------------------------------------------------------------------ what the bus reports

    def mark_started(self, execution_id: str, worker_id: str) -> None:
        """A worker accepted the execution: record it and count the hand-over; starting -> running (a status that
        came first stays). Its dispatch JSON stays until it ends: the dispatch watchdog may take it back
        (:meth:`take_back`)."""
        with self.database.transaction() as db:
            db.execute(
                "UPDATE executions SET worker_id = ?, updated = ?, handovers = handovers + 1, "
                "status = CASE WHEN status = ? THEN ? ELSE status END WHERE id = ?",
                (worker_id, time.time(), ExecutionState.starting.value, ExecutionState.running.value, execution_id),
            )

    def advance(self, execution_id: str, attempt: str, seq: int) -> bool:
        """Take a worker's status numbered ``seq`` of dispatch ``attempt``: True (and ``seq`` remembered) only if the
        execution is active, ``attempt`` is its current dispatch and ``seq`` is above the last status taken. A
        status of an earlier dispatch, of a run that ended, or at or below the last one (a replay) is refused: no
        report moves a run back or reopens it."""
        with self.database.transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET report_seq = ? "
                f"WHERE id = ? AND attempt = ? AND report_seq < ? AND {_ACTIVE_IN}",
                (seq, execution_id, attempt, seq, *(s.value for s in ACTIVE)),
            )
            return cursor.rowcount > 0

    def owner(self, execution_id: str) -> tuple[str, str] | None:
        """(the worker, the dispatch attempt) ``execution_id`` was last handed to, or None if never handed."""
        r = self.database.one("SELECT worker_id, attempt FROM executions WHERE id = ?", (execution_id,))
        return None if r is None or r["worker_id"] is None or r["attempt"] is None else (r["worker_id"], r["attempt"])

    def take_back(self, execution_id: str, attempt: str, max_handovers: int, reason: str) -> ExecutionState | None:
        """The dispatch ``attempt`` of an active execution is given up (its worker did not report in time): back in
        the queue in its place (``queued``, no worker) while it was handed over fewer than ``max_handovers`` times,
        else ``failed`` with ``reason``. Returns the new status, or None when the execution is no longer on that
        attempt (it ended, or was handed over again meanwhile)."""
        now = time.time()
        with self.database.transaction() as db:
            requeued = db.execute(
                "UPDATE executions SET status = ?, phase = ?, worker_id = NULL, updated = ? "
                f"WHERE id = ? AND attempt = ? AND handovers < ? AND dispatch IS NOT NULL AND {_ACTIVE_IN}",
                (ExecutionState.queued.value, ExecutionPhase.pending.value, now, execution_id, attempt, max_handovers,
                 *(s.value for s in ACTIVE)),
            ).rowcount  # fmt: skip
            failed = 0
            if not requeued:
                failed = db.execute(
                    "UPDATE executions SET status = ?, phase = ?, error = ?, dispatch = NULL, updated = ? "
                    f"WHERE id = ? AND attempt = ? AND {_ACTIVE_IN}",
                    (ExecutionState.failed.value, ExecutionPhase.failed.value, reason, now, execution_id, attempt,
                     *(s.value for s in ACTIVE)),
                ).rowcount  # fmt: skip
        if failed:
            self._finished([execution_id])
        return ExecutionState.queued if requeued else ExecutionState.failed if failed else None

    def update(
        self,
        execution_id: str,
        status: ExecutionState | None = None,
        phase: ExecutionPhase | None = None,
        worker_id: str | None = None,
        metrics: ExecutionMetrics | None = None,
        error: str | None = None,
        work_piece: list[WorkPieceMesh] | None = None,
    ) -> bool:
        """Apply a status update to an ACTIVE execution (a finished one is never changed); True if applied. Gets
        through a full disk (:meth:`Database.essential`): a run's status must not stay behind for lack of room."""
        sets, values = ["updated = ?"], [time.time()]
        for column, value in (
            ("status", status.value if status else None),
            ("phase", phase.value if phase else None),
            ("worker_id", worker_id),
            ("metrics", metrics.model_dump_json() if metrics is not None else None),
            ("error", error),
            ("work_piece", _MESHES.dump_json(work_piece).decode() if work_piece is not None else None),
        ):
            if value is not None:
                sets.append(f"{column} = ?")
                values.append(value)
        if status in TERMINAL:
            sets.append("dispatch = NULL")  # what to send to a worker: no longer needed

        def write() -> bool:
            with self.database.transaction() as db:
                cursor = db.execute(
                    f"UPDATE executions SET {', '.join(sets)} WHERE id = ? AND {_ACTIVE_IN}",
                    (*values, execution_id, *(s.value for s in ACTIVE)),
                )
                return cursor.rowcount > 0

        applied = self.database.essential(write)
        if applied and status in TERMINAL:
            self._finished([execution_id])
        return applied

    def amend_failure(self, execution_id: str, error: str, metrics: ExecutionMetrics | None) -> bool:
        """A run the service failed (its telemetry could not be stored) gets what its worker reported when it
        stopped: ``error`` (the final count of what was lost) and its ``metrics``; only while failed. True if
        amended. Gets through a full disk (:meth:`Database.essential`)."""

        def write() -> bool:
            with self.database.transaction() as db:
                cursor = db.execute(
                    "UPDATE executions SET error = ?, metrics = COALESCE(?, metrics), updated = ? "
                    "WHERE id = ? AND status = ?",
                    (error, metrics.model_dump_json() if metrics is not None else None, time.time(), execution_id,
                     ExecutionState.failed.value),
                )  # fmt: skip
                return cursor.rowcount > 0

        return self.database.essential(write)

    def reopen(self, execution_id: str, error: str) -> bool:
        """failed with exactly ``error`` -> running again, the error cleared (what failed it turned out not to be the
        run's fate: its worker came back). True if reopened."""
        with self.database.transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, error = NULL, updated = ? WHERE id = ? AND status = ? AND error = ?",
                (ExecutionState.running.value, time.time(), execution_id, ExecutionState.failed.value, error),
            )
            return cursor.rowcount > 0

    def fail_active(self, reason: str, worker_id: str | None = None, keep_workers: set[str] | None = None) -> list[str]:
        """Mark active executions failed with ``reason``: those on ``worker_id`` (or all, when None) except
        those on a worker in ``keep_workers``. Returns the ids marked."""
        keep = keep_workers or set()

        def write() -> list[str]:
            marked = []
            with self.database.transaction() as db:
                for r in db.execute(
                    f"SELECT id, worker_id FROM executions WHERE {_ACTIVE_IN}", tuple(s.value for s in ACTIVE)
                ).fetchall():
                    if worker_id is not None and r["worker_id"] != worker_id:
                        continue
                    if r["worker_id"] in keep:
                        continue
                    db.execute(
                        "UPDATE executions SET status = ?, phase = ?, error = ?, dispatch = NULL, updated = ? "
                        "WHERE id = ?",
                        (ExecutionState.failed.value, ExecutionPhase.failed.value, reason, time.time(), r["id"]),
                    )
                    marked.append(r["id"])
            return marked

        marked = self.database.essential(write)
        self._finished(marked)
        return marked
