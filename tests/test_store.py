"""The SQLite store under failure: a read that fails half-way leaves no cursor (and so no read transaction) open,
so later writes on the same thread never see "database is locked". Its finish listeners hear of every execution
that ends, once, after the write, and of nothing else."""

from __future__ import annotations

import sqlite3
import threading

import pytest

from corpus.synthetic import plane_slide
from schemas import Demonstration
from schemas.api import ExecutionState
from schemas.execution import ExecutionMetrics, ExecutionPhase
from services.store import Store


def _demonstration() -> Demonstration:
    d = plane_slide(rate_hz=100.0, duration_s=1.0)
    return Demonstration.from_arrays(d.t, d.positions, d.orientations, d.wrenches)


def _in_thread(fn):
    """Run ``fn`` in a new thread (its own store connection); return what it returned or raise what it raised."""
    box: dict = {}

    def run() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # handed to the caller
            box["error"] = exc

    thread = threading.Thread(target=run)
    thread.start()
    thread.join(30)
    if "error" in box:
        raise box["error"]
    return box.get("value")


def test_a_failed_read_leaves_no_transaction_open_and_writes_go_on(tmp_path):
    store = Store(tmp_path / "s.db")
    demonstration = _demonstration()
    for k in range(3):
        store.executions.add({"n": k}, None)
    # One stored row no version of the service writes (a status it does not know): reading the list fails.
    raw = sqlite3.connect(tmp_path / "s.db")
    raw.execute("UPDATE executions SET status = 'lost in space' WHERE rowid = 2")
    raw.commit()
    raw.close()

    kept: list[BaseException] = []  # what a web framework does with an exception: keep it (and its frames) a while
    done = threading.Event()
    go_on = threading.Event()
    outcome: dict = {}

    def reader_then_writer() -> None:
        try:
            store.executions.page(limit=10)
        except Exception as exc:
            kept.append(exc)
        done.set()
        go_on.wait(30)
        try:
            outcome["row"] = store.demonstrations.add(demonstration)
        except Exception as exc:
            outcome["error"] = exc

    thread = threading.Thread(target=reader_then_writer)
    thread.start()
    assert done.wait(30) and kept, "the corrupt row should make the read fail"
    _in_thread(lambda: store.demonstrations.add(demonstration))  # another connection writes meanwhile
    go_on.set()
    thread.join(30)
    assert "error" not in outcome, f"write after a failed read: {outcome.get('error')!r}"
    assert outcome["row"].id.startswith("demo_")
    store.close()


@pytest.mark.parametrize("offset", [0, 10**9])
def test_large_offsets_read_nothing(tmp_path, offset):
    store = Store(tmp_path / "s.db")
    store.demonstrations.add(_demonstration())
    assert len(store.demonstrations.page(limit=10, offset=offset)) == (1 if offset == 0 else 0)
    store.close()


def test_finish_listeners_hear_each_execution_that_ends_once_and_after_the_write(tmp_path):
    """What wakes the queue and the sweeps (`Store.on_finish`): a terminal status applied (a final status, a lost
    worker's executions), not a running one, not a write to an execution already finished; a failing listener
    undoes nothing."""
    store = Store(tmp_path / "s.db")
    heard: list[tuple[str, str]] = []
    store.executions.on_finish(
        lambda execution_id: heard.append((execution_id, store.executions.get(execution_id).status.value))
    )
    store.executions.on_finish(lambda execution_id: 1 / 0)
    a, b, c = (store.executions.add({"n": k}, None) for k in range(3))
    for row in (b, c):
        store.executions.mark_started(row.id, "worker-x")
    store.executions.mark_started(a.id, "worker-y")
    assert store.executions.update(a.id, ExecutionState.running, ExecutionPhase.contact)
    assert heard == []
    assert store.executions.update(
        a.id, ExecutionState.done, ExecutionPhase.done, metrics=ExecutionMetrics.model_construct(steps=3)
    )
    assert heard == [(a.id, "done")]  # the listener reads the committed status
    assert not store.executions.update(a.id, ExecutionState.failed, ExecutionPhase.failed)  # finished stays finished
    assert sorted(store.executions.fail_active("worker worker-x was lost", "worker-x")) == sorted([b.id, c.id])
    assert sorted(heard[1:]) == sorted([(b.id, "failed"), (c.id, "failed")])
    assert store.executions.get(a.id).status is ExecutionState.done
    store.close()
