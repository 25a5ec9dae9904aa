"""Stored robustness sweeps (``services/sweeps.py``): the request, the spec every trial starts from, and one row per
trial x controller with its drawn parameters and its latest execution."""

from __future__ import annotations

import json
import time

from pydantic import JsonValue

from schemas.api import ExecutionState
from schemas.execution import ControllerKind
from schemas.sweep import SweepState
from services.store.database import Database, new_id
from services.store.rows import SweepRow, SweepTrialRow, stored_metrics


class SweepRepository:
    """The ``sweeps`` and ``sweep_trials`` tables."""

    def __init__(self, database: Database) -> None:
        self.database = database

    def add(
        self,
        request: dict[str, JsonValue],
        spec: str,
        trials: list[tuple[int, ControllerKind, dict[str, float]]],
        status: SweepState,
    ) -> SweepRow:
        """Store a new sweep in ``status`` with its trials (index, controller, drawn parameters) not yet submitted."""
        now = time.time()
        row = SweepRow(new_id("sweep"), now, now, SweepState(status), request, spec)
        with self.database.transaction() as db:
            db.execute(
                "INSERT INTO sweeps (id, created, updated, status, request, spec) VALUES (?, ?, ?, ?, ?, ?)",
                (row.id, now, now, row.status.value, json.dumps(request), spec),
            )
            db.executemany(
                "INSERT INTO sweep_trials (sweep_id, trial, controller, parameters) VALUES (?, ?, ?, ?)",
                [(row.id, trial, ControllerKind(c).value, json.dumps(parameters)) for trial, c, parameters in trials],
            )
        return row

    def get(self, sweep_id: str) -> SweepRow | None:
        r = self.database.one("SELECT * FROM sweeps WHERE id = ?", (sweep_id,))
        return None if r is None else SweepRow.of(r)

    def page(self, limit: int = 100, offset: int = 0, status: SweepState | None = None) -> list[SweepRow]:
        """Sweeps, newest first (only those in ``status`` when given)."""
        where, parameters = ("WHERE status = ?", (status.value,)) if status is not None else ("", ())
        rows = self.database.all(
            f"SELECT * FROM sweeps {where} ORDER BY created DESC, id LIMIT ? OFFSET ?", (*parameters, limit, offset)
        )
        return [SweepRow.of(r) for r in rows]

    def set_status(self, sweep_id: str, status: SweepState, only_from: SweepState | None = None) -> bool:
        """Set a sweep's status (only if it is ``only_from`` now, when given); True if changed."""
        condition, extra = (" AND status = ?", (only_from.value,)) if only_from is not None else ("", ())
        with self.database.transaction() as db:
            cursor = db.execute(
                f"UPDATE sweeps SET status = ?, updated = ? WHERE id = ?{condition}",
                (status.value, time.time(), sweep_id, *extra),
            )
            return cursor.rowcount > 0

    def trials(self, sweep_id: str) -> list[SweepTrialRow]:
        """Every trial x controller of a sweep, in trial order, with its latest execution's status, metrics and
        error (None before it was submitted)."""
        rows = self.database.all(
            "SELECT t.trial, t.controller, t.parameters, t.execution_id, t.attempts, e.status, e.metrics, e.error "
            "FROM sweep_trials t LEFT JOIN executions e ON e.id = t.execution_id WHERE t.sweep_id = ? "
            "ORDER BY t.trial, t.rowid",
            (sweep_id,),
        )
        return [
            SweepTrialRow(
                trial=r["trial"],
                controller=ControllerKind(r["controller"]),
                parameters=json.loads(r["parameters"]),
                execution_id=r["execution_id"],
                attempts=r["attempts"],
                status=ExecutionState(r["status"]) if r["status"] else None,
                metrics=stored_metrics(r["metrics"], r["execution_id"]),
                error=r["error"],
            )
            for r in rows
        ]

    def delete(self, sweep_id: str) -> None:
        """Forget a sweep none of whose executions was stored (its first submission failed)."""
        with self.database.transaction() as db:
            db.execute("DELETE FROM sweep_trials WHERE sweep_id = ?", (sweep_id,))
            db.execute("DELETE FROM sweeps WHERE id = ?", (sweep_id,))

    def assign_trial(self, sweep_id: str, trial: int, controller: ControllerKind, execution_id: str) -> None:
        """Record the execution submitted for a trial x controller (one more attempt)."""
        with self.database.transaction() as db:
            db.execute(
                "UPDATE sweep_trials SET execution_id = ?, attempts = attempts + 1 "
                "WHERE sweep_id = ? AND trial = ? AND controller = ?",
                (execution_id, sweep_id, trial, ControllerKind(controller).value),
            )
            db.execute("UPDATE sweeps SET updated = ? WHERE id = ?", (time.time(), sweep_id))
