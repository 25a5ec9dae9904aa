"""SQLite persistence of demonstrations, skills, executions, their telemetry and sweeps (one file, stdlib ``sqlite3``).

Durability: the database runs in WAL mode with ``synchronous=NORMAL``. Every write is its own
transaction and is committed before the method returns (so before the HTTP response is sent): a
committed transaction is in the WAL file, handed to the operating system, so it survives the API
process being killed (``kill -9``) at any moment. Only an OS crash or power cut could lose the last
transactions before a checkpoint (``synchronous=FULL`` would close that too, at an fsync per
write; the telemetry writes at 20 Hz per execution make that a poor trade here).

Threads: one connection per thread (``threading.local``); the bus callbacks write from Zenoh
threads and the REST routes from the thread pool. SQLite serializes the writers (``busy_timeout``
5 s); readers never block in WAL mode. Every read fetches its rows and closes its cursor before
anything is built from them (:meth:`Store._all`, :meth:`Store._one`): a cursor left open by a
failed read would keep its connection in a read transaction on an old snapshot, and the next write
on that thread would fail with "database is locked".

Schema: created on open and versioned with ``PRAGMA user_version`` (:data:`SCHEMA_VERSION`);
a database written by a newer version is refused rather than misread.

Telemetry: rows of consecutive samples, each keyed by (execution, index of its first sample in the execution's
stream, ``TelemetryBatch.first_sample``), the samples' columns as a float64 matrix (:data:`TELEMETRY_LAYOUT`, phases
as :data:`schemas.execution.PHASE_CODES`), zlib-compressed. The stored ranges never overlap: a batch received twice
(a replay of what the live stream already brought) stores only the samples not stored yet, so every sample is
stored once, and reading in key order gives the samples in order (:meth:`Store.add_telemetry`,
:meth:`Store.telemetry_gaps`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import secrets
import sqlite3
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from schemas.api import ExecutionState
from schemas.demonstration import Demonstration, DemonstrationSummary
from schemas.execution import (
    PHASE_CODES,
    STREAMED_TELEMETRY_COLUMNS,
    STREAMED_TELEMETRY_WIDTH,
    ExecutionPhase,
    TelemetryBatch,
    TelemetryMode,
)

SCHEMA_VERSION = 4
"""Version of the tables below, kept in ``PRAGMA user_version`` (2: the execution queue's columns; 3: telemetry keyed
by sample index; 4: sweeps)."""

_SCHEMA_V1 = """
CREATE TABLE demonstrations (
    id TEXT PRIMARY KEY,
    created REAL NOT NULL,
    name TEXT NOT NULL,
    summary TEXT NOT NULL,
    body TEXT NOT NULL
);
CREATE TABLE skills (
    id TEXT PRIMARY KEY,
    demonstration_id TEXT,
    created REAL NOT NULL,
    skill_type TEXT NOT NULL,
    skill TEXT NOT NULL
);
CREATE TABLE executions (
    id TEXT PRIMARY KEY,
    skill_id TEXT,
    worker_id TEXT,
    status TEXT NOT NULL,
    phase TEXT NOT NULL,
    request TEXT NOT NULL,
    metrics TEXT,
    error TEXT,
    created REAL NOT NULL,
    updated REAL NOT NULL
);
CREATE INDEX executions_by_status ON executions (status, worker_id);
CREATE TABLE telemetry (
    execution_id TEXT NOT NULL,
    seq INTEGER NOT NULL,
    received REAL NOT NULL,
    rows INTEGER NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (execution_id, seq)
);
"""

_SCHEMA_V2 = """
ALTER TABLE executions ADD COLUMN priority INTEGER NOT NULL DEFAULT 0;
ALTER TABLE executions ADD COLUMN dispatch TEXT;
CREATE INDEX executions_queue ON executions (status, priority DESC, created, id)
"""
"""Version 2: an execution's queue priority, and what to send to a worker while it is queued (``dispatch``: JSON
with the request with its skill inline, the world overrides and the demonstration id; cleared once started)."""

_SCHEMA_V3 = """
UPDATE telemetry SET seq = -1 - stream.first FROM (
    SELECT execution_id, seq, COALESCE(SUM(rows) OVER (PARTITION BY execution_id ORDER BY seq
        ROWS BETWEEN UNBOUNDED PRECEDING AND 1 PRECEDING), 0) AS first FROM telemetry
) AS stream WHERE telemetry.execution_id = stream.execution_id AND telemetry.seq = stream.seq;
UPDATE telemetry SET seq = -1 - seq
"""
"""Version 3: ``telemetry.seq`` is the index of the row's first sample in the execution's stream (it counted the
received batches): the samples stored before it, in the order they were received (through negative values, so no
two rows share a key on the way)."""

_SCHEMA_V4 = """
CREATE TABLE sweeps (
    id TEXT PRIMARY KEY,
    created REAL NOT NULL,
    updated REAL NOT NULL,
    status TEXT NOT NULL,
    request TEXT NOT NULL,
    spec TEXT NOT NULL
);
CREATE TABLE sweep_trials (
    sweep_id TEXT NOT NULL,
    trial INTEGER NOT NULL,
    controller TEXT NOT NULL,
    parameters TEXT NOT NULL,
    execution_id TEXT,
    attempts INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (sweep_id, trial, controller)
);
CREATE INDEX sweeps_by_status ON sweeps (status)
"""
"""Version 4: robustness sweeps (``services/sweeps.py``): the request as shown and the spec (the execution request
with the skill inline, JSON, stored once); one row per trial x controller with its drawn parameters and its latest
execution (whose row holds the status and metrics)."""

TELEMETRY_LAYOUT: dict[str, tuple[int, int]] = {
    name: (columns.start, columns.stop) for name, columns in STREAMED_TELEMETRY_COLUMNS.items()
}
"""Column range of each `TelemetryBatch` field in the stored float64 matrix (width
:data:`schemas.execution.STREAMED_TELEMETRY_WIDTH`): the worker's row layout, its streamed columns."""
TELEMETRY_READ_SAMPLES = 8192
"""Telemetry samples read per query by :meth:`Store.telemetry_blocks` (~2 MB; more when one block holds more)."""
_TELEMETRY_END = "SELECT COALESCE(MAX(seq + rows), 0) FROM telemetry WHERE execution_id = ?"
"""One past the last stored sample of an execution."""
_PHASES_BY_CODE = {code: phase for phase, code in PHASE_CODES.items()}
log = logging.getLogger("contact_skills.store")


ACTIVE = (ExecutionState.starting, ExecutionState.running, ExecutionState.paused)
_ACTIVE_IN = f"status IN ({', '.join('?' * len(ACTIVE))})"
"""SQL condition on the active statuses (their values as the parameters)."""
TERMINAL = (ExecutionState.done, ExecutionState.aborted, ExecutionState.failed)
RESTART_REASON = "API restarted while running; worker state unknown"


LOCKED_RETRY_S = 120.0
"""How long a write keeps retrying a locked database before it fails, s (each try waits ``busy_timeout``)."""


def _retry_locked(step: Callable[[], object], what: str) -> None:
    """Run ``step`` (a BEGIN or a COMMIT), again while SQLite says the database is locked or busy, for up to
    :data:`LOCKED_RETRY_S`."""
    deadline = time.monotonic() + LOCKED_RETRY_S
    tries = 0
    while True:
        try:
            step()
            return
        except sqlite3.OperationalError as exc:
            tries += 1
            if ("locked" not in str(exc) and "busy" not in str(exc)) or time.monotonic() > deadline:
                raise
            log.warning("%s: database locked (try %d); retrying", what, tries)
            time.sleep(min(0.05 * tries, 1.0))


def new_id(prefix: str) -> str:
    """A short random id: ``prefix`` + 12 hex digits (48 random bits)."""
    return f"{prefix}_{secrets.token_hex(6)}"


class StoreError(RuntimeError):
    """The database cannot be used (newer schema, not a database)."""


class QueueFull(RuntimeError):  # noqa: N818 (reads as what happened)
    """The execution queue holds its maximum."""


@dataclass(frozen=True)
class DemonstrationRow:
    id: str
    created: float
    name: str
    summary: DemonstrationSummary | None
    """None for a row stored by an earlier version that cannot be read back (``problem`` says why)."""
    source: str
    problem: str | None = None
    """Why the stored demonstration cannot be read back (None: it can)."""


@dataclass(frozen=True)
class SkillRow:
    id: str
    demonstration_id: str | None
    created: float
    skill_type: str
    skill_json: str
    warnings: list[str]
    """The messages of the skill's failed checks (``Skill.warnings()``)."""


_FAILED_CHECKS = "FROM json_each(skill, '$.checks') WHERE json_extract(value, '$.passed') = 0"
"""SQL: the failed checks of a stored skill (``skills.skill``), one row each (``value`` the check)."""


@dataclass(frozen=True)
class ExecutionRow:
    id: str
    skill_id: str | None
    worker_id: str | None
    status: ExecutionState
    phase: ExecutionPhase
    request: dict[str, Any]
    metrics: dict[str, Any] | None
    error: str | None
    created: float
    updated: float
    priority: int = 0

    @property
    def streams_telemetry(self) -> bool:
        """Whether its worker publishes its telemetry (``ExecutionSettings.telemetry``; a request stored before
        that setting existed streamed)."""
        return self.request.get("telemetry", TelemetryMode.stream.value) == TelemetryMode.stream.value


@dataclass(frozen=True)
class SweepRow:
    id: str
    created: float
    updated: float
    status: str
    request: dict[str, Any]
    """The request as shown back (an inline skill is not repeated)."""
    spec: str
    """JSON: what every trial's execution starts from (the request with the skill inline, the demonstration id)."""


@dataclass(frozen=True)
class SweepTrialRow:
    trial: int
    controller: str
    parameters: dict[str, float]
    execution_id: str | None
    attempts: int
    status: ExecutionState | None
    metrics: dict[str, Any] | None
    error: str | None


def _demonstration_row(r: sqlite3.Row) -> DemonstrationRow:
    """A demonstrations row (id, created, name, summary, source); a summary that does not validate (stored by an
    earlier version: a step of 5e-324 s gave an infinite rate, stored as null) leaves it None with the problem."""
    try:
        summary, problem = DemonstrationSummary.model_validate_json(r["summary"]), None
    except ValidationError as exc:
        summary, problem = None, f"its stored summary does not validate: {first_problem(exc)}"
    return DemonstrationRow(r["id"], r["created"], r["name"], summary, r["source"] or "", problem)


def first_problem(exc: ValidationError) -> str:
    """The first problem of a validation error, as ``field: message``."""
    first = exc.errors()[0]
    return f"{'.'.join(str(part) for part in first['loc']) or 'body'}: {first['msg']}"


def _sweep(row: sqlite3.Row) -> SweepRow:
    return SweepRow(row["id"], row["created"], row["updated"], row["status"], json.loads(row["request"]), row["spec"])


def _execution(row: sqlite3.Row) -> ExecutionRow:
    return ExecutionRow(
        id=row["id"],
        skill_id=row["skill_id"],
        worker_id=row["worker_id"],
        status=ExecutionState(row["status"]),
        phase=ExecutionPhase(row["phase"]),
        request=json.loads(row["request"]),
        metrics=json.loads(row["metrics"]) if row["metrics"] else None,
        error=row["error"],
        created=row["created"],
        updated=row["updated"],
        priority=row["priority"],
    )


def telemetry_matrix(batch: TelemetryBatch) -> np.ndarray:
    """The columns of ``batch`` as one (rows, :data:`STREAMED_TELEMETRY_WIDTH`) float64 matrix."""
    n = len(batch.t)
    matrix = np.empty((n, STREAMED_TELEMETRY_WIDTH))
    for name, (a, b) in TELEMETRY_LAYOUT.items():
        values = getattr(batch, name)
        if name == "phase":
            values = [PHASE_CODES[ExecutionPhase(p)] for p in values]
        column = np.asarray(values, dtype=float).reshape(n, b - a)
        matrix[:, a:b] = column
    return matrix


def telemetry_column(matrix: np.ndarray, name: str) -> list:
    """The inverse of :func:`telemetry_matrix` for one `TelemetryBatch` field of the stored ``matrix`` rows: a list
    (phases as names)."""
    a, b = TELEMETRY_LAYOUT[name]
    block = matrix[:, a:b]
    if name == "phase":
        return [_PHASES_BY_CODE.get(int(code), ExecutionPhase.failed).value for code in block[:, 0]]
    if name == "segment_index":
        return block[:, 0].astype(int).tolist()
    return block[:, 0].tolist() if b - a == 1 else block.tolist()


def _uncovered(start: int, stop: int, covered: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The parts of ``[start, stop)`` outside the sorted, disjoint ranges ``covered``."""
    parts = []
    for a, b in covered:
        if a > start:
            parts.append((start, min(a, stop)))
        start = max(start, b)
        if start >= stop:
            break
    if start < stop:
        parts.append((start, stop))
    return [(a, b) for a, b in parts if b > a]


class Store:
    """The service's database (see the module docstring); safe to share between threads."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if str(path) != ":memory:":
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        self._connections: list[sqlite3.Connection] = []
        self._lock = threading.Lock()
        self._closed = False
        self._finish_listeners: list[Callable[[str], None]] = []
        self._migrate()

    def on_finish(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(execution_id)`` whenever this store puts an execution that ran (or was handed to a
        worker) in a terminal status (:meth:`update_execution`, :meth:`fail_active`), after the commit, on the
        writing thread (a bus callback): it must be quick, e.g. set an event (`services.queue`, `services.sweeps`
        hand the next executions over at once instead of on their next poll)."""
        self._finish_listeners.append(listener)

    def _finished(self, execution_ids: list[str]) -> None:
        for execution_id in execution_ids:
            for listener in self._finish_listeners:
                try:
                    listener(execution_id)
                except Exception:  # a listener never undoes a committed write
                    log.exception("finish listener failed for %s", execution_id)

    # ------------------------------------------------------------------ connections

    def _connection(self) -> sqlite3.Connection:
        if self._closed:
            raise StoreError("the store is closed")
        connection = getattr(self._local, "connection", None)
        if connection is None:
            connection = sqlite3.connect(self.path, timeout=5.0, isolation_level=None, check_same_thread=False)
            connection.row_factory = sqlite3.Row
            connection.execute("PRAGMA journal_mode=WAL")
            connection.execute("PRAGMA synchronous=NORMAL")
            connection.execute("PRAGMA busy_timeout=5000")
            self._local.connection = connection
            with self._lock:
                self._connections.append(connection)
        return connection

    def _all(self, sql: str, parameters: tuple = ()) -> list[sqlite3.Row]:
        """Every row of a query; the cursor is closed before they are returned."""
        cursor = self._connection().execute(sql, parameters)
        try:
            return cursor.fetchall()
        finally:
            cursor.close()

    def _one(self, sql: str, parameters: tuple = ()) -> sqlite3.Row | None:
        """The first row of a query (or None); the cursor is closed before it is returned."""
        cursor = self._connection().execute(sql, parameters)
        try:
            return cursor.fetchone()
        finally:
            cursor.close()

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """A write transaction. Taking the write lock, and committing, retry while the database is locked (each try
        waits ``busy_timeout``, 5 s), for up to :data:`LOCKED_RETRY_S`: a status or a telemetry batch from a bus
        thread waits for a long write (a big upload, a deletion) instead of being dropped."""
        connection = self._connection()
        _retry_locked(lambda: connection.execute("BEGIN IMMEDIATE"), "BEGIN")
        try:
            yield connection
        except BaseException:
            connection.execute("ROLLBACK")
            raise
        _retry_locked(lambda: connection.execute("COMMIT"), "COMMIT")

    def service_key(self, name: str, size: int = 32) -> bytes:
        """A random key of ``size`` bytes kept in the database under ``name`` (made on first use, then the same for
        every process and restart on this database): e.g. what the bus client derives each execution's secret
        from (``services.bus.BusSettings.report_key``)."""
        with self._transaction() as db:
            db.execute("CREATE TABLE IF NOT EXISTS service_keys (name TEXT PRIMARY KEY, value BLOB NOT NULL)")
            db.execute("INSERT OR IGNORE INTO service_keys VALUES (?, ?)", (name, secrets.token_bytes(size)))
            return bytes(db.execute("SELECT value FROM service_keys WHERE name = ?", (name,)).fetchone()[0])

    def _migrate(self) -> None:
        try:
            with self._transaction() as db:
                version = db.execute("PRAGMA user_version").fetchone()[0]
                if version > SCHEMA_VERSION:
                    raise StoreError(
                        f"{self.path}: database schema version {version} is newer than this program's "
                        f"({SCHEMA_VERSION}); upgrade contact-skills or use another database"
                    )
                # not executescript: it would COMMIT the open transaction
                for script in (_SCHEMA_V1, _SCHEMA_V2, _SCHEMA_V3, _SCHEMA_V4)[version:]:
                    for statement in filter(None, (s.strip() for s in script.split(";"))):
                        db.execute(statement)
                if version < SCHEMA_VERSION:
                    db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: not a usable SQLite database ({exc})") from None

    def schema_version(self) -> int:
        """The database's schema version."""
        row = self._one("PRAGMA user_version")
        return int(row[0]) if row is not None else 0

    def close(self) -> None:
        """Close every thread's connection (the WAL is checkpointed by the last one)."""
        with self._lock:
            self._closed = True
            connections, self._connections = self._connections, []
        for connection in connections:
            with contextlib.suppress(sqlite3.ProgrammingError):  # another thread's, in use right now
                connection.close()

    # ------------------------------------------------------------------ demonstrations

    def add_demonstration(self, demonstration: Demonstration) -> DemonstrationRow:
        """Store ``demonstration``; return its row (with the new id)."""
        summary = DemonstrationSummary.of(demonstration)
        row = DemonstrationRow(
            id=new_id("demo"),
            created=time.time(),
            name=demonstration.metadata.name,
            summary=summary,
            source=demonstration.metadata.source,
        )
        body = demonstration.model_dump_json()
        with self._transaction() as db:
            db.execute(
                "INSERT INTO demonstrations (id, created, name, summary, body) VALUES (?, ?, ?, ?, ?)",
                (row.id, row.created, row.name, summary.model_dump_json(), body),
            )
        return row

    def list_demonstrations(self, limit: int = 100, offset: int = 0) -> list[DemonstrationRow]:
        """Demonstration rows, newest first; one that cannot be read back is listed with its ``problem``."""
        rows = self._all(
            "SELECT id, created, name, summary, json_extract(body, '$.metadata.source') AS source "
            "FROM demonstrations ORDER BY created DESC, id LIMIT ? OFFSET ?",
            (limit, offset),
        )
        return [_demonstration_row(r) for r in rows]

    def demonstration_json(self, demonstration_id: str) -> tuple[DemonstrationRow, str] | None:
        """The row and the stored body (JSON text of a `Demonstration`), or None."""
        r = self._one(
            "SELECT id, created, name, summary, body, json_extract(body, '$.metadata.source') AS source "
            "FROM demonstrations WHERE id = ?",
            (demonstration_id,),
        )
        return None if r is None else (_demonstration_row(r), r["body"])

    def demonstration(self, demonstration_id: str) -> Demonstration | None:
        """The stored demonstration (validated again), or None: none stored, or one stored by an earlier version
        that no longer validates (logged)."""
        found = self.demonstration_json(demonstration_id)
        if found is None:
            return None
        try:
            return Demonstration.model_validate_json(found[1])
        except ValidationError as exc:
            log.warning("stored demonstration %s cannot be read back: %s", demonstration_id, first_problem(exc))
            return None

    def delete_demonstration(self, demonstration_id: str) -> bool:
        """Delete a demonstration; False if there was none. Skills learned from it keep their parameters."""
        with self._transaction() as db:
            return db.execute("DELETE FROM demonstrations WHERE id = ?", (demonstration_id,)).rowcount > 0

    # ------------------------------------------------------------------ skills

    def add_skill(
        self, skill_json: str, skill_type: str, demonstration_id: str | None, warnings: list[str]
    ) -> SkillRow:
        """Store a skill given as JSON text (``warnings``: its failed checks' messages); return its row."""
        row = SkillRow(new_id("skill"), demonstration_id, time.time(), skill_type, skill_json, warnings)
        with self._transaction() as db:
            db.execute(
                "INSERT INTO skills (id, demonstration_id, created, skill_type, skill) VALUES (?, ?, ?, ?, ?)",
                (row.id, row.demonstration_id, row.created, row.skill_type, row.skill_json),
            )
        return row

    def skill(self, skill_id: str) -> SkillRow | None:
        r = self._one(
            "SELECT id, demonstration_id, created, skill_type, skill, "
            f"(SELECT json_group_array(json_extract(value, '$.message')) {_FAILED_CHECKS}) FROM skills WHERE id = ?",
            (skill_id,),
        )
        return None if r is None else SkillRow(r[0], r[1], r[2], r[3], r[4], json.loads(r[5]))

    def list_skills(self, limit: int = 100, offset: int = 0) -> list[dict[str, Any]]:
        """Skill summaries (no parameters): id, demonstration_id, created, skill_type, segments, confidence,
        failed_checks."""
        rows = self._all(
            "SELECT id, demonstration_id, created, skill_type, json_array_length(skill, '$.segments') AS segments, "
            "json_extract(skill, '$.auto_selection.confidence') AS confidence, "
            f"(SELECT count(*) {_FAILED_CHECKS}) AS failed_checks, "
            "json_extract(skill, '$.demonstration.name') AS demonstration_name "
            "FROM skills ORDER BY created DESC, id LIMIT ? OFFSET ?",
            (limit, offset),
        )
        return [dict(r) for r in rows]

    def delete_skill(self, skill_id: str) -> bool:
        """Delete a skill; False if there was none. Executions that used it keep their records."""
        with self._transaction() as db:
            return db.execute("DELETE FROM skills WHERE id = ?", (skill_id,)).rowcount > 0

    # ------------------------------------------------------------------ executions

    def add_execution(
        self,
        request: dict[str, Any],
        skill_id: str | None,
        dispatch: str | None = None,
        priority: int = 0,
        max_queued: int | None = None,
    ) -> ExecutionRow:
        """Store a new execution: in status ``starting`` without ``dispatch``; with it (what to send to a worker,
        JSON) in status ``queued`` at ``priority``. Raises :class:`QueueFull` when ``max_queued`` are queued."""
        now = time.time()
        execution_id = new_id("exec")
        status = ExecutionState.starting if dispatch is None else ExecutionState.queued
        with self._transaction() as db:
            if max_queued is not None:
                queued = db.execute("SELECT COUNT(*) FROM executions WHERE status = ?", (ExecutionState.queued.value,))
                if queued.fetchone()[0] >= max_queued:
                    raise QueueFull(f"{max_queued} executions are already queued; try again later")
            db.execute(
                "INSERT INTO executions (id, skill_id, worker_id, status, phase, request, created, updated, priority, "
                "dispatch) VALUES (?, ?, NULL, ?, ?, ?, ?, ?, ?, ?)",
                (
                    execution_id,
                    skill_id,
                    status.value,
                    ExecutionPhase.pending.value,
                    json.dumps(request),
                    now,
                    now,
                    priority,
                    dispatch,
                ),
            )
        found = self.execution(execution_id)
        assert found is not None
        return found

    def execution(self, execution_id: str) -> ExecutionRow | None:
        r = self._one("SELECT * FROM executions WHERE id = ?", (execution_id,))
        return None if r is None else _execution(r)

    def list_executions(self, limit: int = 100, offset: int = 0) -> list[ExecutionRow]:
        rows = self._all("SELECT * FROM executions ORDER BY created DESC, id LIMIT ? OFFSET ?", (limit, offset))
        return [_execution(r) for r in rows]

    def active_executions(self) -> list[ExecutionRow]:
        """Executions in status starting or running."""
        rows = self._all(
            f"SELECT * FROM executions WHERE {_ACTIVE_IN} ORDER BY created", tuple(s.value for s in ACTIVE)
        )
        return [_execution(r) for r in rows]

    # ------------------------------------------------------------------ the queue (services/queue.py)

    def queued_executions(self, limit: int = 1) -> list[tuple[ExecutionRow, str]]:
        """The first ``limit`` queued executions in dispatch order (priority high first, then oldest first), each
        with its dispatch JSON."""
        rows = self._all(
            "SELECT * FROM executions WHERE status = ? ORDER BY priority DESC, created, id LIMIT ?",
            (ExecutionState.queued.value, limit),
        )
        return [(_execution(r), r["dispatch"]) for r in rows]

    def queue_position(self, execution_id: str) -> int | None:
        """How many queued executions go before this one (0: next), or None if it is not queued."""
        r = self._one(
            "SELECT (SELECT COUNT(*) FROM executions o WHERE o.status = e.status AND (o.priority > e.priority OR "
            "(o.priority = e.priority AND (o.created < e.created OR (o.created = e.created AND o.id < e.id))))) "
            "FROM executions e WHERE e.id = ? AND e.status = ?",
            (execution_id, ExecutionState.queued.value),
        )
        return None if r is None else int(r[0])

    def queued_count(self) -> int:
        """Executions waiting in the queue."""
        r = self._one("SELECT COUNT(*) FROM executions WHERE status = ?", (ExecutionState.queued.value,))
        return int(r[0]) if r is not None else 0

    def claim_queued(self, execution_id: str) -> bool:
        """queued -> starting, if it is still queued (a cancel may have come first); True if claimed."""
        with self._transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, updated = ? WHERE id = ? AND status = ?",
                (ExecutionState.starting.value, time.time(), execution_id, ExecutionState.queued.value),
            )
            return cursor.rowcount > 0

    def requeue(self, execution_id: str) -> bool:
        """starting -> queued (no worker took it after all) if it still has its dispatch JSON; it keeps its place
        (priority, creation time). True if requeued."""
        with self._transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, updated = ? WHERE id = ? AND status = ? AND dispatch IS NOT NULL",
                (ExecutionState.queued.value, time.time(), execution_id, ExecutionState.starting.value),
            )
            return cursor.rowcount > 0

    def cancel_queued(self, execution_id: str, reason: str) -> bool:
        """queued -> aborted with ``reason``; True if it was still queued."""
        with self._transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, phase = ?, error = ?, dispatch = NULL, updated = ? "
                "WHERE id = ? AND status = ?",
                (ExecutionState.aborted.value, ExecutionPhase.aborted.value, reason, time.time(), execution_id,
                 ExecutionState.queued.value),
            )  # fmt: skip
            return cursor.rowcount > 0

    def delete_execution(self, execution_id: str, statuses: tuple[ExecutionState, ...] | None = None) -> bool:
        """Delete an execution and its telemetry, only if it is in one of ``statuses`` when given (one that never
        started: any status); True if deleted."""
        condition = f" AND status IN ({', '.join('?' * len(statuses))})" if statuses else ""
        with self._transaction() as db:
            cursor = db.execute(
                f"DELETE FROM executions WHERE id = ?{condition}", (execution_id, *(s.value for s in statuses or ()))
            )
            if cursor.rowcount:
                db.execute("DELETE FROM telemetry WHERE execution_id = ?", (execution_id,))
            return cursor.rowcount > 0

    def mark_started(self, execution_id: str, worker_id: str) -> None:
        """A worker accepted the execution: record it; starting -> running (a status that came first stays); its
        dispatch JSON is no longer needed."""
        with self._transaction() as db:
            db.execute(
                "UPDATE executions SET worker_id = ?, updated = ?, dispatch = NULL, "
                "status = CASE WHEN status = ? THEN ? ELSE status END WHERE id = ?",
                (worker_id, time.time(), ExecutionState.starting.value, ExecutionState.running.value, execution_id),
            )

    def update_execution(
        self,
        execution_id: str,
        status: ExecutionState | None = None,
        phase: ExecutionPhase | None = None,
        worker_id: str | None = None,
        metrics: dict[str, Any] | None = None,
        error: str | None = None,
    ) -> bool:
        """Apply a status update to an ACTIVE execution (a finished one is never changed); True if applied."""
        sets, values = ["updated = ?"], [time.time()]
        for column, value in (
            ("status", status.value if status else None),
            ("phase", phase.value if phase else None),
            ("worker_id", worker_id),
            ("metrics", json.dumps(metrics) if metrics is not None else None),
            ("error", error),
        ):
            if value is not None:
                sets.append(f"{column} = ?")
                values.append(value)
        with self._transaction() as db:
            cursor = db.execute(
                f"UPDATE executions SET {', '.join(sets)} WHERE id = ? AND {_ACTIVE_IN}",
                (*values, execution_id, *(s.value for s in ACTIVE)),
            )
            applied = cursor.rowcount > 0
        if applied and status in TERMINAL:
            self._finished([execution_id])
        return applied

    def reopen_execution(self, execution_id: str, error: str) -> bool:
        """failed with exactly ``error`` -> running again, the error cleared (what failed it turned out not to be the
        run's fate: its worker came back). True if reopened."""
        with self._transaction() as db:
            cursor = db.execute(
                "UPDATE executions SET status = ?, error = NULL, updated = ? WHERE id = ? AND status = ? AND error = ?",
                (ExecutionState.running.value, time.time(), execution_id, ExecutionState.failed.value, error),
            )
            return cursor.rowcount > 0

    def fail_active(self, reason: str, worker_id: str | None = None, keep_workers: set[str] | None = None) -> list[str]:
        """Mark active executions failed with ``reason``: those on ``worker_id`` (or all, when None) except
        those on a worker in ``keep_workers``. Returns the ids marked."""
        keep = keep_workers or set()
        marked = []
        with self._transaction() as db:
            for r in db.execute(
                f"SELECT id, worker_id FROM executions WHERE {_ACTIVE_IN}", tuple(s.value for s in ACTIVE)
            ).fetchall():
                if worker_id is not None and r["worker_id"] != worker_id:
                    continue
                if r["worker_id"] in keep:
                    continue
                db.execute(
                    "UPDATE executions SET status = ?, phase = ?, error = ?, updated = ? WHERE id = ?",
                    (ExecutionState.failed.value, ExecutionPhase.failed.value, reason, time.time(), r["id"]),
                )
                marked.append(r["id"])
        self._finished(marked)
        return marked

    # ------------------------------------------------------------------ sweeps (services/sweeps.py)

    def add_sweep(
        self, request: dict[str, Any], spec: str, trials: list[tuple[int, str, dict[str, float]]], status: str
    ) -> SweepRow:
        """Store a new sweep in ``status`` with its trials (index, controller, drawn parameters) not yet submitted."""
        now = time.time()
        row = SweepRow(new_id("sweep"), now, now, status, request, spec)
        with self._transaction() as db:
            db.execute(
                "INSERT INTO sweeps (id, created, updated, status, request, spec) VALUES (?, ?, ?, ?, ?, ?)",
                (row.id, now, now, status, json.dumps(request), spec),
            )
            db.executemany(
                "INSERT INTO sweep_trials (sweep_id, trial, controller, parameters) VALUES (?, ?, ?, ?)",
                [(row.id, trial, controller, json.dumps(parameters)) for trial, controller, parameters in trials],
            )
        return row

    def sweep(self, sweep_id: str) -> SweepRow | None:
        r = self._one("SELECT * FROM sweeps WHERE id = ?", (sweep_id,))
        return None if r is None else _sweep(r)

    def list_sweeps(self, limit: int = 100, offset: int = 0, status: str | None = None) -> list[SweepRow]:
        """Sweeps, newest first (only those in ``status`` when given)."""
        where, parameters = ("WHERE status = ?", (status,)) if status is not None else ("", ())
        rows = self._all(
            f"SELECT * FROM sweeps {where} ORDER BY created DESC, id LIMIT ? OFFSET ?", (*parameters, limit, offset)
        )
        return [_sweep(r) for r in rows]

    def set_sweep_status(self, sweep_id: str, status: str, only_from: str | None = None) -> bool:
        """Set a sweep's status (only if it is ``only_from`` now, when given); True if changed."""
        condition, extra = (" AND status = ?", (only_from,)) if only_from is not None else ("", ())
        with self._transaction() as db:
            cursor = db.execute(
                f"UPDATE sweeps SET status = ?, updated = ? WHERE id = ?{condition}",
                (status, time.time(), sweep_id, *extra),
            )
            return cursor.rowcount > 0

    def sweep_trials(self, sweep_id: str) -> list[SweepTrialRow]:
        """Every trial x controller of a sweep, in trial order, with its latest execution's status, metrics and
        error (None before it was submitted)."""
        rows = self._all(
            "SELECT t.trial, t.controller, t.parameters, t.execution_id, t.attempts, e.status, e.metrics, e.error "
            "FROM sweep_trials t LEFT JOIN executions e ON e.id = t.execution_id WHERE t.sweep_id = ? "
            "ORDER BY t.trial, t.rowid",
            (sweep_id,),
        )
        return [
            SweepTrialRow(
                trial=r["trial"],
                controller=r["controller"],
                parameters=json.loads(r["parameters"]),
                execution_id=r["execution_id"],
                attempts=r["attempts"],
                status=ExecutionState(r["status"]) if r["status"] else None,
                metrics=json.loads(r["metrics"]) if r["metrics"] else None,
                error=r["error"],
            )
            for r in rows
        ]

    def delete_sweep(self, sweep_id: str) -> None:
        """Forget a sweep none of whose executions was stored (its first submission failed)."""
        with self._transaction() as db:
            db.execute("DELETE FROM sweep_trials WHERE sweep_id = ?", (sweep_id,))
            db.execute("DELETE FROM sweeps WHERE id = ?", (sweep_id,))

    def assign_sweep_trial(self, sweep_id: str, trial: int, controller: str, execution_id: str) -> None:
        """Record the execution submitted for a trial x controller (one more attempt)."""
        with self._transaction() as db:
            db.execute(
                "UPDATE sweep_trials SET execution_id = ?, attempts = attempts + 1 "
                "WHERE sweep_id = ? AND trial = ? AND controller = ?",
                (execution_id, sweep_id, trial, controller),
            )
            db.execute("UPDATE sweeps SET updated = ? WHERE id = ?", (time.time(), sweep_id))

    # ------------------------------------------------------------------ telemetry

    def add_telemetry(self, execution_id: str, batch: TelemetryBatch) -> int:
        """Store the samples of a telemetry batch of a KNOWN execution that are not stored yet; return how many were
        new (0 for an unknown execution or a batch already stored). A batch without ``first_sample`` (not from the
        bus) goes after the last sample stored."""
        matrix = telemetry_matrix(batch)
        received = time.time()
        with self._transaction() as db:
            if db.execute("SELECT 1 FROM executions WHERE id = ?", (execution_id,)).fetchone() is None:
                return 0
            first = batch.first_sample
            if first is None:
                first = int(db.execute(_TELEMETRY_END, (execution_id,)).fetchone()[0])
            stop = first + matrix.shape[0]
            stored = db.execute(
                "SELECT seq, rows FROM telemetry WHERE execution_id = ? AND seq < ? AND seq + rows > ? ORDER BY seq",
                (execution_id, stop, first),
            ).fetchall()
            new = 0
            for start, end in _uncovered(first, stop, [(r["seq"], r["seq"] + r["rows"]) for r in stored]):
                block = matrix[start - first : end - first]
                db.execute(
                    "INSERT INTO telemetry (execution_id, seq, received, rows, data) VALUES (?, ?, ?, ?, ?)",
                    (execution_id, start, received, end - start, zlib.compress(block.astype("<f8").tobytes(), 1)),
                )
                new += end - start
            return new

    def telemetry_end(self, execution_id: str) -> int:
        """One past the last stored sample index of an execution (0 with none)."""
        r = self._one(_TELEMETRY_END, (execution_id,))
        return int(r[0]) if r is not None else 0

    def telemetry_gaps(self, execution_id: str, total: int | None = None) -> list[tuple[int, int]]:
        """The sample ranges ``[start, stop)`` missing from an execution's stored telemetry, below ``total`` samples
        (default: up to the last stored one)."""
        rows = self._all("SELECT seq, rows FROM telemetry WHERE execution_id = ? ORDER BY seq", (execution_id,))
        end = total if total is not None else max((r["seq"] + r["rows"] for r in rows), default=0)
        return _uncovered(0, end, [(r["seq"], r["seq"] + r["rows"]) for r in rows])

    def telemetry_counts(self, execution_id: str) -> tuple[int, int]:
        """(batches, samples) stored for an execution."""
        r = self._one("SELECT COUNT(*), COALESCE(SUM(rows), 0) FROM telemetry WHERE execution_id = ?", (execution_id,))
        return (int(r[0]), int(r[1])) if r is not None else (0, 0)

    def telemetry(self, execution_id: str) -> np.ndarray:
        """Every stored sample of an execution, in stream order, as one (N, ``STREAMED_TELEMETRY_WIDTH``) matrix
        (a whole run in memory: the API reads it page by page, :meth:`telemetry_blocks`)."""
        blocks = [block for _, block in self.telemetry_blocks(execution_id)]
        return np.concatenate(blocks) if blocks else np.empty((0, STREAMED_TELEMETRY_WIDTH))

    def telemetry_blocks(self, execution_id: str, start: int = 0) -> Iterator[tuple[int, np.ndarray]]:
        """The stored telemetry of an execution from sample ``start`` on, in stream order, as (stream index of its
        first sample, (n, ``STREAMED_TELEMETRY_WIDTH``) matrix) blocks: the first block may begin before ``start``.
        Read about :data:`TELEMETRY_READ_SAMPLES` samples per query, so memory stays bounded, a reader that stops
        early has read little, and no cursor stays open while the caller works."""
        while index := self._all(
            "SELECT seq, rows FROM telemetry WHERE execution_id = ? AND seq + rows > ? ORDER BY seq LIMIT ?",
            (execution_id, start, TELEMETRY_READ_SAMPLES),
        ):
            upto = np.cumsum([r["rows"] for r in index])
            last = index[max(1, int(np.searchsorted(upto, TELEMETRY_READ_SAMPLES, side="right"))) - 1]
            for first, n, data in self._all(
                "SELECT seq, rows, data FROM telemetry WHERE execution_id = ? AND seq BETWEEN ? AND ? ORDER BY seq",
                (execution_id, index[0]["seq"], last["seq"]),
            ):
                yield first, np.frombuffer(zlib.decompress(data), dtype="<f8").reshape(n, STREAMED_TELEMETRY_WIDTH)
            start = last["seq"] + last["rows"]
