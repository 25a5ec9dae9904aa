"""Nothing dropped on a busy database (issue 25 M1): a write that meets "database is locked" past SQLite's busy
timeout retries instead of failing, so a worker's status is stored once the database is free, whatever held it.
(The long run itself, samples and statuses counted against the worker's own, is benchmarks/bench_long_run.py.)"""

from __future__ import annotations

import sqlite3
import threading
import time

from schemas.api import ExecutionState
from schemas.execution import ExecutionPhase
from services.store import Store

HELD_S = 6.0
"""How long another connection holds the write lock: longer than the store's busy timeout (5 s)."""


def test_a_status_write_waits_out_a_lock_held_past_the_busy_timeout(tmp_path):
    store = Store(tmp_path / "api.db")
    row = store.executions.add({"skill": "inline"}, None)
    other = sqlite3.connect(tmp_path / "api.db", isolation_level=None, check_same_thread=False)
    other.execute("BEGIN IMMEDIATE")  # another writer (another process, a long deletion) holds the database
    released = threading.Timer(HELD_S, lambda: other.execute("COMMIT"))
    released.start()
    started = time.monotonic()
    try:
        stored = store.executions.update(row.id, status=ExecutionState.done, phase=ExecutionPhase.done, worker_id="w")
        waited = time.monotonic() - started
    finally:
        released.join()
        other.close()
    assert stored and waited >= HELD_S - 0.5  # it waited for the lock rather than failing after 5 s
    assert store.executions.get(row.id).status is ExecutionState.done
    store.close()
