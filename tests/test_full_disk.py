"""Storage honest under pressure (issue 41, N5): the quota reserves the telemetry accepted executions will write, a
full disk answers 507 and still deletes through the API, and a run whose telemetry cannot be stored ends failed with
the count of what was lost, its worker told to abort. The full disk is SQLite's own: ``max_page_count`` makes every
write that needs a new page answer ``SQLITE_FULL`` ("database or disk is full"), as a full disk does."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from conftest import FakeBus, api_settings, loopback_client
from test_api import _demo_json

from schemas.bus import ExecutionStatus
from schemas.demonstration import Demonstration
from schemas.execution import ExecutionMetrics, ExecutionPhase, ExecutionRequest, TelemetryBatch
from schemas.skill import LearnOptions, Skill
from services.app import BusEvents, create_app
from services.store import Store
from skills.job_estimate import stored_telemetry_bytes


@pytest.fixture(scope="module")
def skill() -> Skill:
    from skills.parameterize import learn_skill

    return learn_skill(Demonstration.model_validate(_demo_json()), LearnOptions(skill_type="slide"))


@contextmanager
def _api(tmp_path, max_pages: int | None = None, **settings) -> Iterator:
    """The API on a store in ``tmp_path`` (at most ``max_pages`` pages: a disk that fills up) with a fake bus the
    test drives through the real bus callbacks (``client.bus``, ``client.store``)."""
    store = Store(tmp_path / "api.db", max_pages)
    events = BusEvents(store)
    bus = events.bus = FakeBus(events.on_status, events.on_telemetry, events.on_worker_lost)
    with loopback_client(create_app(api_settings(tmp_path, **settings), bus=bus, store=store)) as client:
        client.bus, client.store = bus, store
        yield client
    store.close()


def _pages(store: Store) -> int:
    row = store.database.one("PRAGMA page_count")
    assert row is not None
    return int(row[0])


def _batch(execution_id: str, first: int, n: int, rng: np.random.Generator) -> TelemetryBatch:
    """``n`` samples from stream index ``first`` on, of noise (it does not compress: each takes its room)."""
    return TelemetryBatch(
        execution_id=execution_id, first_sample=first, t=((np.arange(n) + first) * 1e-3).tolist(),
        phase=[ExecutionPhase.contact] * n, segment_index=[0] * n, tool_position=rng.normal(size=(n, 3)).tolist(),
        tool_orientation=[[0, 0, 0, 1]] * n, reference_position=rng.normal(size=(n, 3)).tolist(),
        reference_orientation=[[0, 0, 0, 1]] * n,
        wrench_world=rng.normal(size=(n, 6)).tolist(), wrench_cf=rng.normal(size=(n, 6)).tolist(),
        desired_force_cf_z_n=[5.0] * n, in_contact=[True] * n, normal_force_true_n=rng.normal(size=n).tolist(),
    )  # fmt: skip


def test_accepted_work_over_the_quota_is_refused_507_before_it_runs_and_its_reservation_ends_with_it(tmp_path, skill):
    body = {"skill": skill.model_dump(mode="json")}
    need = stored_telemetry_bytes(skill, ExecutionRequest.model_validate(body))
    assert need > 0
    empty = Store(tmp_path / "api.db")
    room = empty.usage_bytes() + need * 3 // 2  # one execution's telemetry fits, two do not
    empty.close()
    with _api(tmp_path, storage_quota_mb=room / 2**20) as c:
        first = c.post("/executions", json=body)
        assert first.status_code == 202, first.text
        assert c.store.reserved_bytes() == need  # it has stored nothing yet: all of it is reserved
        refused = c.post("/executions", json=body)
        assert refused.status_code == 507, refused.text
        detail = refused.json()["detail"]
        mib = f"{need / 2**20:,.1f} MiB"
        assert f"needs {mib}" in detail and f"reserve {mib}" in detail, detail
        assert "CONTACT_SKILLS_STORAGE_QUOTA_MB" in detail and f"{room / 2**20:,.1f} MiB" in detail, detail
        assert [started for started, _ in c.bus.started] == [first.json()["id"]]  # never sent to a worker
        assert len(c.get("/executions").json()) == 1  # nor stored
        # restart-safe: another process on the database sees the same reservation
        again = Store(tmp_path / "api.db")
        assert again.reserved_bytes() == need
        again.close()
        # what the run stored counts as stored, no longer as reserved; its end releases the rest
        c.bus.on_telemetry(_batch(first.json()["id"], 0, 100, np.random.default_rng(0)))
        assert c.store.reserved_bytes() == need - 100 * 256
        metrics = ExecutionMetrics(controller="hybrid_cf", phase="done", real_time_factor=1.0, duration_s=0.1,
                                   steps=100, peak_force_n=5.0)  # fmt: skip
        c.bus.on_status(ExecutionStatus(execution_id=first.json()["id"], worker_id="w0", phase="done", metrics=metrics))
        assert c.get(f"/executions/{first.json()['id']}").json()["status"] == "done"
        assert c.store.reserved_bytes() == 0
        assert c.post("/executions", json=body).status_code == 202


def test_a_full_disk_answers_507_naming_it_and_a_delete_through_the_api_makes_room_for_an_upload(tmp_path):
    demo = _demo_json()
    empty = Store(tmp_path / "api.db")
    max_pages = _pages(empty) + 400  # about seven demonstrations
    empty.close()
    with _api(tmp_path, max_pages, storage_quota_mb=0) as c:
        answers = []
        while len(answers) < 50 and (not answers or answers[-1].status_code == 201):
            answers.append(c.post("/demonstrations", json=demo))
        full = answers[-1]
        assert [a.status_code for a in answers[:-1]] == [201] * (len(answers) - 1) and len(answers) > 2
        assert full.status_code == 507, full.text
        assert "is full" in full.json()["detail"] and str(tmp_path / "api.db") in full.json()["detail"]
        assert len(c.get("/demonstrations").json()) == len(answers) - 1  # nothing half stored
        assert c.delete(f"/demonstrations/{answers[0].json()['id']}").status_code == 204
        assert c.post("/demonstrations", json=demo).status_code == 201


def test_a_run_whose_telemetry_meets_a_full_disk_ends_failed_with_the_count_of_lost_samples(tmp_path, skill):
    rng = np.random.default_rng(1)
    empty = Store(tmp_path / "api.db")
    max_pages = _pages(empty) + 300  # ~1.2 MB: about 20 batches of 200 noisy samples
    empty.close()
    with _api(tmp_path, max_pages, storage_quota_mb=0) as c:
        run = c.post("/executions", json={"skill": skill.model_dump(mode="json")}).json()["id"]
        sent = 0
        while c.get(f"/executions/{run}").json()["status"] == "running":
            assert sent < 100_000, "the disk never filled"
            c.bus.on_telemetry(_batch(run, sent, 200, rng))
            sent += 200
        view = c.get(f"/executions/{run}").json()
        stored = view["telemetry_samples"]
        assert view["status"] == "failed" and 0 < stored < sent, view
        assert "is full" in view["error"] and f"{sent - stored:,} telemetry samples were not stored" in view["error"]
        assert f"(from sample {stored:,} on)" in view["error"]
        assert c.bus.commands == [(run, "abort")]  # the worker is told to stop
        for _ in range(2):  # what the worker sent before the abort reached it: counted, not stored
            c.bus.on_telemetry(_batch(run, sent, 200, rng))
            sent += 200
        steps = sent + 50  # and what it ran and never sent
        metrics = ExecutionMetrics(controller="hybrid_cf", phase="aborted", real_time_factor=1.0, duration_s=1.0,
                                   steps=steps, peak_force_n=5.0, abort_reason="abort requested")  # fmt: skip
        c.bus.on_status(ExecutionStatus(execution_id=run, worker_id="w0", phase="aborted", metrics=metrics))
        view = c.get(f"/executions/{run}").json()
        assert view["status"] == "failed" and view["telemetry_samples"] == stored, view
        assert view["telemetry_missing_samples"] == steps - stored and view["metrics"]["steps"] == steps
        assert f"{steps - stored:,} of its {steps:,} telemetry samples were not stored" in view["error"], view
        assert c.delete(f"/executions/{run}").status_code == 204  # and the full disk still deletes it
        assert c.post("/demonstrations", json=_demo_json()).status_code == 201


@contextmanager
def _small_disk(path, size_mib: int) -> Iterator:
    """A real file system of ``size_mib`` MiB (tmpfs) mounted at ``path``: needs root and the right to mount (CI runs
    as root); skips otherwise, saying why."""
    import os
    import subprocess

    if os.geteuid() != 0:
        pytest.skip("a real full disk needs root to mount a small tmpfs (the page-limit tests above run anyway)")
    path.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mib}m", "tmpfs", str(path)],
                             capture_output=True, text=True)  # fmt: skip
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def test_a_real_full_disk_still_deletes_through_the_api_and_the_room_is_used_again(tmp_path):
    """Not SQLite's page limit: a 24 MiB file system filled by uploads. There even a deletion needs room (the
    write-ahead log grows, and its committed pages may lie past the database file's end): before the ballast FILE
    every DELETE answered 507 (measured); it is freed first, the log emptied, and the deletion goes through."""
    demo = Demonstration.model_validate(_demo_json())
    t = np.arange(8000) * 1e-3  # an 8 s, 1 kHz recording: ~2 MiB as JSON
    arrays = demo.arrays()
    index = np.minimum(np.arange(8000) * arrays.t.size // 8000, arrays.t.size - 1)
    body = Demonstration.from_arrays(t, arrays.positions[index], arrays.orientations[index], arrays.wrenches[index])
    with _small_disk(tmp_path / "disk", 24) as disk:
        store = Store(disk / "api.db")
        try:
            with loopback_client(create_app(api_settings(tmp_path, storage_quota_mb=0), bus=None, store=store)) as c:
                answers = []
                while len(answers) < 40 and (not answers or answers[-1].status_code == 201):
                    answers.append(c.post("/demonstrations", content=body.model_dump_json(),
                                          headers={"content-type": "application/json"}))  # fmt: skip
                assert answers[-1].status_code == 507 and "is full" in answers[-1].text, answers[-1].text
                assert len(answers) > 3
                stored = [a.json()["id"] for a in answers[:-1]]
                assert c.get("/demonstrations").status_code == 200
                assert c.delete(f"/demonstrations/{stored[0]}").status_code == 204
                assert c.delete(f"/demonstrations/{stored[1]}").status_code == 204
                again = c.post("/demonstrations", content=body.model_dump_json(),
                               headers={"content-type": "application/json"})  # fmt: skip
                assert again.status_code == 201, again.text
                assert len(c.get("/demonstrations").json()) == len(stored) - 1
        finally:
            store.close()
