"""The database under the repositories: one SQLite file, its connections, transactions and schema versions.

Durability: the database runs in WAL mode with ``synchronous=NORMAL``. Every write is its own transaction and is
committed before the repository method returns (so before the HTTP response is sent): a committed transaction is in
the WAL file, handed to the operating system, so it survives the API process being killed (``kill -9``) at any
moment. Only an OS crash or power cut could lose the last transactions before a checkpoint (``synchronous=FULL``
would close that too, at an fsync per write; the telemetry writes at 20 Hz per execution make that a poor trade).

Threads: one connection per thread (``threading.local``); the bus callbacks write from Zenoh threads and the REST
routes from the thread pool. SQLite serializes the writers (``busy_timeout`` 5 s); readers never block in WAL mode.
Every read fetches its rows and closes its cursor before anything is built from them (:meth:`Database.all`,
:meth:`Database.one`): a cursor left open by a failed read would keep its connection in a read transaction on an old
snapshot, and the next write on that thread would fail with "database is locked".

Schema: created on open and versioned with ``PRAGMA user_version`` (:data:`SCHEMA_VERSION`); a database written by
a newer version is refused rather than misread.

A full disk: a write SQLite answers "database or disk is full" (``SQLITE_FULL``) raises :class:`DiskFull`, which the
API answers 507 naming the disk. What must get through a full disk all the same (a deletion, which makes room; a
run's final status) is written with :meth:`Database.essential`: on :class:`DiskFull` it releases the ballast — a
file of :data:`BALLAST_FILE_BYTES` next to the database (``<database>.ballast``: room on the disk, first for emptying
the write-ahead log) and a row of :data:`BALLAST_BYTES` (room inside a database at its page limit), both kept for
that moment — and tries once more; a deletion puts the ballast back (:meth:`Database.deletion`).
"""

from __future__ import annotations

import contextlib
import logging
import secrets
import shutil
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

from schemas.text import MAX_NAME_CHARS

T = TypeVar("T")

log = logging.getLogger("contact_skills.store")

SCHEMA_VERSION = 7
"""Version of the tables below, kept in ``PRAGMA user_version`` (2: the execution queue's columns; 3: telemetry keyed
by sample index; 4: sweeps; 5: the telemetry an execution reserves, the ballast; 6: an execution's dispatch
attempt and the last report taken; 7: the work piece an execution ran on)."""
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

_SCHEMA_V5 = """
ALTER TABLE executions ADD COLUMN reserved_bytes INTEGER NOT NULL DEFAULT 0;
CREATE TABLE ballast (id INTEGER PRIMARY KEY, data BLOB NOT NULL)
"""
"""Version 5: the telemetry bytes an execution reserves in the storage quota while it is queued or running (its job
estimate's, ``schemas.job_budget.JobEstimate.telemetry_bytes``; 0 with telemetry ``none``); the ballast (one row of
:data:`BALLAST_BYTES`, released when the disk is full: :meth:`Database.essential`)."""

BALLAST_BYTES = 1 << 20
"""The ballast row, bytes: room kept in the database for the writes that must get through a full disk (a deletion's
B-tree pages, a run's final status; each a few pages of 4 KiB)."""
BALLAST_FILE_BYTES = 8 << 20
"""The ballast file, bytes: room kept on the disk for emptying the write-ahead log (whose committed pages may lie
past the database file's end; SQLite checkpoints it at 1000 pages, 4 MiB) and then for the essential write."""

_SCHEMA_V6 = """
ALTER TABLE executions ADD COLUMN attempt TEXT;
ALTER TABLE executions ADD COLUMN report_seq INTEGER NOT NULL DEFAULT -1;
ALTER TABLE executions ADD COLUMN handovers INTEGER NOT NULL DEFAULT 0
"""
"""Version 6: the nonce of an execution's current dispatch (``StartExecution.attempt``: only its reports count), the
``seq`` of the last status taken from it (a status at or below it is a replay), and how many times a worker accepted
it (the dispatch watchdog takes a job back from a worker that does not report, a bounded number of times)."""

_SCHEMA_V7 = """
ALTER TABLE executions ADD COLUMN work_piece TEXT
"""
"""Version 7: the solids of the world an execution runs in, as its worker reported them (JSON of
``schemas.dashboard.WorkPieceMesh`` rows; NULL before it started, and for runs stored before)."""

LOCKED_RETRY_S = 120.0
"""How long a write keeps retrying a locked database before it fails, s (each try waits ``busy_timeout``)."""


class StoreError(RuntimeError):
    """The database cannot be used (newer schema, not a database, closed)."""


class DiskFull(StoreError):  # noqa: N818 (reads as what happened)
    """A write found the database's disk full (SQLite's ``SQLITE_FULL``: the disk, or the database's page limit)."""

    def __init__(self, path: Path, max_pages: int | None) -> None:
        free = shutil.disk_usage(path.parent).free if path.parent.exists() else 0
        limit = f"; the database may take {max_pages} pages" if max_pages is not None else ""
        super().__init__(f"the disk holding the database {path} is full ({free / 2**20:.0f} MiB free{limit})")
        self.path, self.free_bytes = path, free


def _is_full(exc: sqlite3.Error) -> bool:
    """Whether SQLite answered ``SQLITE_FULL`` (its extended codes keep it in the low byte)."""
    return (getattr(exc, "sqlite_errorcode", 0) or 0) & 0xFF == sqlite3.SQLITE_FULL


def cut_text(expression: str, chars: int = MAX_NAME_CHARS) -> str:
    """SQL: the text ``expression`` cut to ``chars`` characters, ending in "…" when cut: a name stored before names
    were bounded (a 55 MB one) is listed as a name may be now, and never read whole into the API."""
    cut = f"substr({expression}, 1, {chars - 1}) || '…'"
    return f"(CASE WHEN length({expression}) > {chars} THEN {cut} ELSE {expression} END)"


def new_id(prefix: str) -> str:
    """A short random id: ``prefix`` + 12 hex digits (48 random bits)."""
    return f"{prefix}_{secrets.token_hex(6)}"


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


class Database:
    """One SQLite file shared by the repositories (see the module docstring); safe to share between threads."""

    def __init__(self, path: str | Path, max_pages: int | None = None) -> None:
        """``max_pages``: a ceiling on the database file, pages (SQLite's ``max_page_count`` on every connection):
        past it every write that needs a new page fails as on a full disk; None: the disk is the ceiling."""
        self.path = Path(path)
        self.max_pages = max_pages
        if str(path) != ":memory:":
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        self._connections: list[sqlite3.Connection] = []
        self._lock = threading.Lock()
        self._closed = False
        self._migrate()

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
            if self.max_pages is not None:
                connection.execute(f"PRAGMA max_page_count={int(self.max_pages)}")
            self._local.connection = connection
            with self._lock:
                self._connections.append(connection)
        return connection

    def all(self, sql: str, parameters: tuple = ()) -> list[sqlite3.Row]:
        """Every row of a query; the cursor is closed before they are returned."""
        cursor = self._connection().execute(sql, parameters)
        try:
            return cursor.fetchall()
        finally:
            cursor.close()

    def one(self, sql: str, parameters: tuple = ()) -> sqlite3.Row | None:
        """The first row of a query (or None); the cursor is closed before it is returned."""
        cursor = self._connection().execute(sql, parameters)
        try:
            return cursor.fetchone()
        finally:
            cursor.close()

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """A write transaction. Taking the write lock, and committing, retry while the database is locked (each try
        waits ``busy_timeout``, 5 s), for up to :data:`LOCKED_RETRY_S`: a status or a telemetry batch from a bus
        thread waits for a long write (a big upload, a deletion) instead of being dropped. A full disk raises
        :class:`DiskFull`, nothing written."""
        connection = self._connection()
        try:
            _retry_locked(lambda: connection.execute("BEGIN IMMEDIATE"), "BEGIN")
            try:
                yield connection
            except BaseException:
                if connection.in_transaction:  # SQLite rolls back by itself after SQLITE_FULL
                    connection.execute("ROLLBACK")
                raise
            _retry_locked(lambda: connection.execute("COMMIT"), "COMMIT")
        except sqlite3.OperationalError as exc:
            if connection.in_transaction:  # a COMMIT that failed leaves it open
                connection.execute("ROLLBACK")
            if _is_full(exc):
                raise DiskFull(self.path, self.max_pages) from exc
            raise

    def essential(self, write: Callable[[], T]) -> T:
        """Run ``write`` (a function that makes one transaction), which must get through a full disk: on
        :class:`DiskFull` the ballast is released (:meth:`_release_ballast`) and it runs once more."""
        try:
            return write()
        except DiskFull:
            released = self._release_ballast()
            log.warning("%s: the disk is full; %d ballast bytes released for an essential write", self.path, released)
            return write()

    def deletion(self, delete: Callable[[], T]) -> T:
        """Run ``delete`` (a function that makes one transaction that deletes) as an :meth:`essential` write, then
        put the ballast back if it was released and the deletion made room for it."""
        deleted = self.essential(delete)
        self._refill_ballast()
        return deleted

    def _ballast_file(self) -> Path | None:
        """The ballast on the disk, next to the database (None for an in-memory one)."""
        return None if str(self.path) == ":memory:" else self.path.with_name(self.path.name + ".ballast")

    def _release_ballast(self) -> int:
        """Free the ballast, the file first (on a full disk even a deletion needs room: its write-ahead log grows,
        which the row alone, inside the database file, cannot give; measured on a full 24 MiB tmpfs, every DELETE
        answered 507 before the file was kept), then the row (room inside a database at its page limit); returns
        the bytes freed."""
        freed = 0
        file = self._ballast_file()
        if file is not None and file.exists():
            freed += file.stat().st_size
            file.unlink()
        # The log holds committed pages past the database file's end: copied in, the log emptied to zero bytes, the
        # disk has room for the deletion's few pages (the file is sized for a log at its checkpoint threshold).
        with contextlib.suppress(sqlite3.OperationalError):
            self._connection().execute("PRAGMA wal_checkpoint(TRUNCATE)")
        with contextlib.suppress(DiskFull), self.transaction() as db:  # a deletion: it needs no new page
            freed += db.execute("DELETE FROM ballast").rowcount * BALLAST_BYTES
        return freed

    def _refill_ballast(self) -> None:
        """Put the ballast back (file and row) where it was released and there is room for it; else leave it for
        the next deletion."""
        file = self._ballast_file()
        if file is not None and not file.exists():
            try:
                with open(file, "wb") as ballast:  # zeros written, not a sparse file: the disk blocks are taken
                    ballast.write(bytes(BALLAST_FILE_BYTES))
            except OSError:  # no room yet
                file.unlink(missing_ok=True)
        if self.one("SELECT 1 FROM ballast") is not None:
            return
        with contextlib.suppress(DiskFull), self.transaction() as db:
            db.execute("INSERT INTO ballast (data) SELECT zeroblob(?) WHERE NOT EXISTS (SELECT 1 FROM ballast)",
                       (BALLAST_BYTES,))  # fmt: skip

    def used_bytes(self, db: sqlite3.Connection | None = None) -> int:
        """What the stored rows take in the database file, bytes: its pages in use (pages freed by deletions are
        reused before the file grows, so they do not count; the write-ahead log does not either); ``db``: the
        connection of an open transaction to read it in."""
        read = db or self._connection()
        pages, free, size = (int(read.execute(f"PRAGMA {name}").fetchone()[0])
                             for name in ("page_count", "freelist_count", "page_size"))  # fmt: skip
        return (pages - free) * size

    def _migrate(self) -> None:
        try:
            with self.transaction() as db:
                version = db.execute("PRAGMA user_version").fetchone()[0]
                if version > SCHEMA_VERSION:
                    raise StoreError(
                        f"{self.path}: database schema version {version} is newer than this program's "
                        f"({SCHEMA_VERSION}); upgrade contact-skills or use another database"
                    )
                # not executescript: it would COMMIT the open transaction
                scripts = (_SCHEMA_V1, _SCHEMA_V2, _SCHEMA_V3, _SCHEMA_V4, _SCHEMA_V5, _SCHEMA_V6, _SCHEMA_V7)
                for script in scripts[version:]:
                    for statement in filter(None, (s.strip() for s in script.split(";"))):
                        db.execute(statement)
                if version < SCHEMA_VERSION:
                    db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: not a usable SQLite database ({exc})") from None
        self._refill_ballast()

    def schema_version(self) -> int:
        """The database's schema version."""
        row = self.one("PRAGMA user_version")
        return int(row[0]) if row is not None else 0

    def service_key(self, name: str, size: int = 32) -> bytes:
        """A random key of ``size`` bytes kept in the database under ``name`` (made on first use, then the same for
        every process and restart on this database): e.g. what the bus client derives each execution's secret
        from (``services.bus.BusSettings.report_key``)."""
        with self.transaction() as db:
            db.execute("CREATE TABLE IF NOT EXISTS service_keys (name TEXT PRIMARY KEY, value BLOB NOT NULL)")
            db.execute("INSERT OR IGNORE INTO service_keys VALUES (?, ?)", (name, secrets.token_bytes(size)))
            return bytes(db.execute("SELECT value FROM service_keys WHERE name = ?", (name,)).fetchone()[0])

    def close(self) -> None:
        """Close every thread's connection (the WAL is checkpointed by the last one)."""
        with self._lock:
            self._closed = True
            connections, self._connections = self._connections, []
        for connection in connections:
            with contextlib.suppress(sqlite3.ProgrammingError):  # another thread's, in use right now
                connection.close()
