"""What the database holds and for how long (issue 25): a storage quota (507 on a storing POST, DELETE always
allowed), an upload that stores at most a stated multiple of what it brought, retention of finished runs, and
telemetry stored before the truth columns were streamed still read back."""

from __future__ import annotations

import time
import zlib

import numpy as np
from conftest import api_settings, loopback_client
from test_api import _demo_json

from schemas.api import ExecutionState
from schemas.execution import STREAMED_TELEMETRY_WIDTH, ExecutionPhase, TelemetryBatch
from schemas.sweep import SweepState
from services.api.limits import UPLOAD_STORED_MULTIPLE
from services.app import create_app
from services.retention import Retention
from services.store import Store


def _batch(n: int, first: int = 0) -> TelemetryBatch:
    t = (np.arange(n) + first) * 1e-3
    return TelemetryBatch(
        t=t.tolist(), phase=[ExecutionPhase.contact] * n, segment_index=[0] * n, tool_position=[[0, 0, 0.1]] * n,
        tool_orientation=[[0, 0, 0, 1]] * n, reference_position=[[0, 0, 0.1]] * n,
        reference_orientation=[[0, 0, 0, 1]] * n, wrench_world=[[0, 0, -5.0, 0, 0, 0]] * n,
        wrench_cf=[[0, 0, 5.0, 0, 0, 0]] * n, desired_force_cf_z_n=[5.0] * n, in_contact=[True] * n,
        normal_force_true_n=(5.0 + 0.01 * np.arange(n)).tolist(), first_sample=first,
    )  # fmt: skip


def test_a_storing_post_past_the_quota_gets_507_and_a_delete_makes_room_again(tmp_path):
    demo = _demo_json()
    store = Store(tmp_path / "api.db")
    empty = store.usage_bytes()
    settings = api_settings(tmp_path, storage_quota_mb=(empty + 4096) / 2**20)  # room for about one page
    with loopback_client(create_app(settings, bus=None, store=store)) as client:
        first = client.post("/demonstrations", json=demo)
        assert first.status_code == 201  # the database had room when it came
        assert store.usage_bytes() > settings.storage_quota_mb * 2**20
        refused = client.post("/demonstrations", json=demo)
        assert refused.status_code == 507
        assert "storage quota" in refused.json()["detail"] and "CONTACT_SKILLS_STORAGE_QUOTA_MB" in refused.text
        assert client.post("/skills", json={"demonstration_id": first.json()["id"]}).status_code == 507
        assert client.get("/demonstrations").status_code == 200  # reads go on
        assert client.delete(f"/demonstrations/{first.json()['id']}").status_code == 204
        assert store.usage_bytes() < settings.storage_quota_mb * 2**20  # freed pages are reused, not counted
        assert client.post("/demonstrations", json=demo).status_code == 201
    store.close()


def test_a_csv_whose_stamps_span_far_more_samples_than_rows_is_refused_naming_the_file(client):
    header = "t,x,y,z,qx,qy,qz,qw,fx,fy,fz,tx,ty,tz\n"
    # 20 rows 1 ms apart, then one 150 s later: a gap no resampling may fill, refused as such
    rows = [f"{k * 0.001:.3f},0.5,0.0,0.2,0,0,0,1,0,0,-5,0,0,0" for k in range(20)] + [
        "150.0,0.5,0,0.2,0,0,0,1,0,0,-5,0,0,0"
    ]
    response = client.post("/demonstrations/csv", files={"file": ("gap.csv", (header + "\n".join(rows)).encode())})
    assert response.status_code == 422, response.text
    (problem,) = response.json()["detail"]
    assert problem["loc"] == ["body", "file"] and "no measurement for 149.98 s (0.019-150 s)" in problem["msg"], problem
    # 301 rows 0.5 s apart resampled at 1 kHz: 150 000 samples (~33 MB) from ~15 KB
    rows = [f"{k * 0.5:.1f},0.5,0.0,0.2,0,0,0,1,0,0,-5,0,0,0" for k in range(301)]
    text = header + "\n".join(rows) + "\n"
    response = client.post("/demonstrations/csv", files={"file": ("slow.csv", text.encode())}, data={"rate": "1000"})
    assert response.status_code == 422, response.text
    (problem,) = response.json()["detail"]
    assert problem["loc"] == ["body", "file"] and problem["type"] == "stored_too_large"
    assert f"at most {UPLOAD_STORED_MULTIPLE:g}x" in problem["msg"] and "KiB uploaded" in problem["msg"]
    assert client.get("/demonstrations").json() == []  # nothing stored


def test_a_real_recording_stores_less_than_it_brought(client):
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "data" / "kuleuven_contour" / "contour_a_1.csv"
    data = path.read_bytes()
    response = client.post("/demonstrations/csv", files={"file": (path.name, data)})
    assert response.status_code == 201, response.text
    listed = client.get("/demonstrations").json()
    assert len(listed) == 1 and listed[0]["id"] == response.json()["id"]


def test_retention_deletes_old_finished_runs_and_keeps_the_rest(tmp_path):
    store = Store(tmp_path / "s.db")
    old_done, old_failed, old_running, new_done = (store.executions.add({"k": k}, None) for k in range(4))
    sweep = store.sweeps.add({"trials": 1}, "{}", [], SweepState.running)
    in_sweep = store.executions.add({"sweep": {"id": sweep.id, "trial": 0}}, None)
    finished_sweep = store.sweeps.add({"trials": 1}, "{}", [], SweepState.done)
    for row in (old_done, old_failed, old_running, new_done, in_sweep):
        store.executions.mark_started(row.id, "w")
        store.telemetry.add(row.id, _batch(50))
    for row, state in ((old_done, ExecutionState.done), (old_failed, ExecutionState.failed),
                       (new_done, ExecutionState.done), (in_sweep, ExecutionState.done)):  # fmt: skip
        store.executions.update(row.id, state)
    day = 86_400.0
    with store.database.transaction() as db:  # age everything but new_done by 10 days
        db.execute("UPDATE executions SET updated = updated - ? WHERE id != ?", (10 * day, new_done.id))
        db.execute("UPDATE sweeps SET updated = updated - ?", (10 * day,))
    retired = store.retire(7 * day)
    assert (retired.executions, retired.sweeps) == (2, 1)
    assert store.executions.get(old_done.id) is None and store.executions.get(old_failed.id) is None
    assert store.telemetry.counts(old_done.id) == (0, 0)
    kept = [store.executions.get(r.id) for r in (old_running, new_done, in_sweep)]
    assert [row.status for row in kept] == [ExecutionState.running, ExecutionState.done, ExecutionState.done]
    assert store.sweeps.get(sweep.id) is not None and store.sweeps.get(finished_sweep.id) is None
    # the API's retention thread runs a pass when it starts
    store.executions.update(old_running.id, ExecutionState.aborted)
    with store.database.transaction() as db:
        db.execute("UPDATE executions SET updated = updated - ? WHERE id = ?", (10 * day, old_running.id))
    retention = Retention(store, days=7)
    retention.start()
    deadline = time.monotonic() + 10
    while store.executions.get(old_running.id) is not None and time.monotonic() < deadline:
        time.sleep(0.05)
    retention.close()
    assert store.executions.get(old_running.id) is None
    store.close()


def test_telemetry_stored_before_the_truth_columns_reads_back_without_them(tmp_path):
    store = Store(tmp_path / "s.db")
    old, new = store.executions.add({}, None), store.executions.add({}, None)
    narrow = 30  # the stored width before in_contact and normal_force_true_n were streamed
    block = np.zeros((20, narrow))
    block[:, 0] = np.arange(20) * 1e-3
    with store.database.transaction() as db:
        db.execute(
            "INSERT INTO telemetry (execution_id, seq, received, rows, data) VALUES (?, ?, ?, ?, ?)",
            (old.id, 0, time.time(), 20, zlib.compress(block.astype("<f8").tobytes())),
        )
    store.telemetry.add(new.id, _batch(30))
    rows = store.telemetry.rows(old.id)
    assert rows.shape == (20, STREAMED_TELEMETRY_WIDTH) and np.isnan(rows[:, narrow:]).all()
    with loopback_client(create_app(api_settings(tmp_path), bus=None, store=store)) as client:
        old_page = client.get(f"/executions/{old.id}/telemetry").json()
        new_page = client.get(f"/executions/{new.id}/telemetry").json()
        csv = client.get(f"/executions/{new.id}/telemetry", params={"format": "csv"}).text
    assert len(old_page["t"]) == 20 and old_page["normal_force_true_n"] == [] and old_page["in_contact"] == []
    assert new_page["in_contact"] == [True] * 30
    assert new_page["normal_force_true_n"] == [5.0 + 0.01 * k for k in range(30)]
    assert "normal_force_true_n" in csv.splitlines()[0]
    store.close()
