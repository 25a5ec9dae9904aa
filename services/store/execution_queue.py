"""The execution queue's rows of the ``executions`` table (``services/queue.py`` hands them to the workers): which
are queued and in what order, and the moves into and out of the queue; ``ExecutionRepository`` is the whole table."""

from __future__ import annotations

import time

from schemas.api import ExecutionState
from schemas.execution import ExecutionPhase
from services.store.database import Database
from services.store.rows import ExecutionRow


class ExecutionQueue:
    """The queued executions of the ``executions`` table in ``database``, in dispatch order."""

    def __init__(self, database: Database) -> None:
        self.database = database

    def queued(self, limit: int = 1) -> list[tuple[ExecutionRow, str]]:
        """The first ``limit`` queued executions in dispatch order (priority high first, then oldest first), each
        with its dispatch JSON."""
        rows = self.database.all(
            "SELECT * FROM executions WHERE status = ? ORDER BY priority DESC, created, id LIMIT ?",
            (ExecutionState.queued.value, limit),
        )
        return [(ExecutionRow.of(r), r["dispatch"]) for r in rows]

    def queue_position(self, execution_id: str) -> int | None:
        """How many queued executions go before this one (0: next), or None if it is not queued."""
        r = self.database.one(
            "SELECT (SELECT COUNT(*) FROM executions o WHERE o.status = e.status AND (o.priority > e.priority OR "
            "(o.priority = e.priority AND (o.created < e.created OR (o.created = e.created AND o.id < e.id))))) "
            "FROM executions e WHERE e.id = ? AND e.status = ?",
            (execution_id, ExecutionState.queued.value),
        )
        return None if r is None else int(r[0])

    def queued_count(self) -> int:
        """Executions waiting in the queue."""
        r = self.database.one("SELECT COUNT(*) FROM executions WHERE status = ?", (ExecutionState.queued.value,))
        return int(r[0]) if r is not None else 0

    def claim_queued(self, execution_id: str, attempt: str) -> bool:
        """queued -> starting as dispatch ``attempt`` (a fresh nonce: from now on only its reports count, numbered
        from scratch), if it is still queued (a cancel may have come first); True if claimed."""
        with self.database.transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, attempt = ?, report_seq = -1, updated = ? "
                "WHERE id = ? AND status = ?",
                (ExecutionState.starting.value, attempt, time.time(), execution_id, ExecutionState.queued.value),
            )
            return cursor.rowcount > 0

    def requeue(self, execution_id: str) -> bool:
        """starting -> queued (no worker took it after all) if it still has its dispatch JSON; it keeps its place
        (priority, creation time). True if requeued."""
        with self.database.transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, updated = ? WHERE id = ? AND status = ? AND dispatch IS NOT NULL",
                (ExecutionState.queued.value, time.time(), execution_id, ExecutionState.starting.value),
            )
            return cursor.rowcount > 0

    def cancel_queued(self, execution_id: str, reason: str) -> bool:
        """queued -> aborted with ``reason``; True if it was still queued."""
        with self.database.transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, phase = ?, error = ?, dispatch = NULL, updated = ? "
                "WHERE id = ? AND status = ?",
                (ExecutionState.aborted.value, ExecutionPhase.aborted.value, reason, time.time(), execution_id,
                 ExecutionState.queued.value),
            )  # fmt: skip
            return cursor.rowcount > 0
