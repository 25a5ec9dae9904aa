"""SQLite persistence (one file, stdlib ``sqlite3``): one repository per resource, mirroring the API's routes.

- :mod:`services.store.database`: the file, its connections, transactions, schema versions (durability and
  threading are described there);
- :mod:`services.store.demonstrations`, :mod:`.skills`, :mod:`.executions` (with the queue), :mod:`.telemetry`,
  :mod:`.sweeps`: one repository each, returning the typed rows of :mod:`services.store.rows`;
- :class:`Store` (here): the façade that opens the database and holds the repositories, with what spans them: the
  storage quota (what is stored, what admitted executions reserve) and the retention of finished executions.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from schemas.sweep import SweepState
from services.store.database import SCHEMA_VERSION, Database, DiskFull, StoreError, new_id
from services.store.demonstrations import DemonstrationRepository
from services.store.executions import ACTIVE, RESTART_REASON, TERMINAL, ExecutionRepository, QueueFull, QuotaFull
from services.store.rows import (
    DemonstrationRow,
    ExecutionRow,
    SkillRow,
    SkillSummaryRow,
    SweepRow,
    SweepTerms,
    SweepTrialRef,
    SweepTrialRow,
    first_problem,
)
from services.store.skills import SkillRepository
from services.store.sweeps import SweepRepository
from services.store.telemetry import TELEMETRY_LAYOUT, TelemetryRepository

__all__ = [
    "ACTIVE",
    "RESTART_REASON",
    "SCHEMA_VERSION",
    "TELEMETRY_LAYOUT",
    "TERMINAL",
    "DemonstrationRow",
    "DiskFull",
    "ExecutionRow",
    "QueueFull",
    "QuotaFull",
    "Retired",
    "SkillRow",
    "SkillSummaryRow",
    "Store",
    "StoreError",
    "SweepRow",
    "SweepTerms",
    "SweepTrialRef",
    "SweepTrialRow",
    "first_problem",
    "new_id",
]


@dataclass(frozen=True)
class Retired:
    """What one pass of the retention deleted."""

    executions: int
    sweeps: int


class Store:
    """The service's database: its repositories, one per resource; safe to share between threads."""

    def __init__(self, path: str | Path, max_pages: int | None = None) -> None:
        """``max_pages``: a ceiling on the database file, pages (``Database``; None: the disk is the ceiling)."""
        self.database = Database(path, max_pages)
        self.path = self.database.path
        self.demonstrations = DemonstrationRepository(self.database)
        self.skills = SkillRepository(self.database)
        self.executions = ExecutionRepository(self.database)
        self.telemetry = TelemetryRepository(self.database)
        self.sweeps = SweepRepository(self.database)

    def usage_bytes(self) -> int:
        """What the stored rows take in the database file, bytes (``Database.used_bytes``)."""
        return self.database.used_bytes()

    def reserved_bytes(self) -> int:
        """What the queued and running executions still reserve for their telemetry, bytes
        (``ExecutionRepository.reserved_bytes``)."""
        return self.executions.reserved_bytes()

    def retire(self, older_than_s: float, now: float | None = None) -> Retired:
        """Delete what the retention setting lets go: finished executions last updated more than ``older_than_s``
        ago, with their telemetry, except those of a sweep still running (it counts them); then finished sweeps
        (done, cancelled) last updated that long ago, with their trials. Demonstrations and skills are kept: they
        are what a user made, and small. Gets through a full disk (``Database.deletion``)."""
        cutoff = (time.time() if now is None else now) - older_than_s
        finished = tuple(state.value for state in TERMINAL)
        running_sweeps = "SELECT id FROM sweeps WHERE status = ?"

        def delete() -> Retired:
            with self.database.transaction() as db:
                old = [
                    r["id"]
                    for r in db.execute(
                        f"SELECT id FROM executions WHERE updated < ? AND status IN ({', '.join('?' * len(finished))}) "
                        f"AND COALESCE(json_extract(request, '$.sweep.id'), '') NOT IN ({running_sweeps})",
                        (cutoff, *finished, SweepState.running.value),
                    ).fetchall()
                ]
                for execution_id in old:
                    db.execute("DELETE FROM telemetry WHERE execution_id = ?", (execution_id,))
                    db.execute("DELETE FROM executions WHERE id = ?", (execution_id,))
                sweeps = [
                    r["id"]
                    for r in db.execute(
                        "SELECT id FROM sweeps WHERE updated < ? AND status != ?", (cutoff, SweepState.running.value)
                    ).fetchall()
                ]
                for sweep_id in sweeps:
                    db.execute("DELETE FROM sweep_trials WHERE sweep_id = ?", (sweep_id,))
                    db.execute("DELETE FROM sweeps WHERE id = ?", (sweep_id,))
            return Retired(executions=len(old), sweeps=len(sweeps))

        return self.database.deletion(delete)

    def schema_version(self) -> int:
        """The database's schema version."""
        return self.database.schema_version()

    def service_key(self, name: str, size: int = 32) -> bytes:
        """A random key kept in the database (:meth:`Database.service_key`)."""
        return self.database.service_key(name, size)

    def close(self) -> None:
        """Close every thread's connection."""
        self.database.close()
