"""The REST contract (services/app.py) in-process: every bad input is a 4xx naming the field, never a 500.

The bus is a fake with the `services.bus.BusClient` interface (the real one runs in tests/test_service.py).
"""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
from conftest import KULEUVEN_DATA, FakeBus
from conftest import api_settings as _settings
from conftest import loopback_client as _client

from corpus import kinesthetic
from corpus.synthetic import plane_slide
from schemas import Demonstration, Engine, ExecutionMetrics, TelemetryBatch
from schemas.api import ExecutionState
from schemas.bus import ExecutionStatus, RecordReply
from services.app import BusEvents, create_app
from services.settings import ServiceSettings, SettingsError
from services.store import RESTART_REASON, Store

DATA = KULEUVEN_DATA


def _demo_json(rate_hz: float = 200.0, duration_s: float = 4.0, **changes) -> dict:
    d = plane_slide(rate_hz=rate_hz, duration_s=duration_s)
    body = {
        "t": d.t.tolist(),
        "positions": d.positions.tolist(),
        "orientations": d.orientations.tolist(),
        "wrenches": d.wrenches.tolist(),
        "metadata": {"name": "plane"},
    }
    body.update(changes)
    return body


@pytest.fixture(scope="module")
def demo() -> dict:
    return _demo_json()


def _locs(response) -> list[list]:
    assert response.status_code == 422, response.text
    return [entry["loc"] for entry in response.json()["detail"]]


def _names(response, field: str) -> bool:
    """Every error of a 422 names ``field``."""
    locs = _locs(response)
    return bool(locs) and all(field in loc for loc in locs)


# --------------------------------------------------------------------------- bad input -> 4xx naming the field


def _post_raw(client, path: str, body: dict):
    """POST with NaN/inf written as JS literals (what a careless client sends); Python's json writes them so."""
    return client.post(path, content=json.dumps(body), headers={"content-type": "application/json"})


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        (lambda b: b["positions"][7].__setitem__(1, float("nan")), "positions", "row 7 is not finite"),
        (lambda b: b["wrenches"][3].__setitem__(2, float("inf")), "wrenches", "not finite"),
        (lambda b: b["t"].__setitem__(5, float("nan")), "t", "not finite"),
        (lambda b: b["positions"].pop(), "positions", "samples but t has"),
        (lambda b: b["positions"][2].pop(), "positions", "at least 3"),
        (lambda b: b["t"].__setitem__(10, b["t"][9]), "t", "strictly increasing"),
        (lambda b: b["orientations"].__setitem__(4, [0.0, 0.0, 0.0, 2.0]), "orientations", "not unit"),
        (lambda b: b.__setitem__("wrenches", []), "wrenches", ""),
        (lambda b: b.__setitem__("colour", "red"), "colour", "Extra inputs"),
        (lambda b: b.pop("t"), "t", "required"),
    ],
)
def test_bad_demonstrations_are_422_naming_the_field(client, demo, change, field, words):
    body = json.loads(json.dumps(demo))
    change(body)
    response = _post_raw(client, "/demonstrations", body)
    assert _names(response, field), response.text
    assert words in response.text
    assert len(response.content) < 5000  # large inputs are not echoed back
    # the same demonstration inline in POST /skills names it under "demonstration"
    response = _post_raw(client, "/skills", {"demonstration": body})
    assert any(loc[:2] == ["body", "demonstration"] and field in loc for loc in _locs(response)), response.text


def test_too_few_samples_and_invalid_json(client, demo):
    short = {k: v[:20] for k, v in demo.items() if k != "metadata"}
    assert _names(client.post("/demonstrations", json=short), "t")
    bad = client.post("/demonstrations", content=b'{"t": [0, 1,', headers={"content-type": "application/json"})
    assert bad.status_code == 422 and "JSON" in bad.text
    assert client.post("/demonstrations", content=b"[]", headers={"content-type": "application/json"}).status_code
    assert client.post("/demonstrations", content=b"", headers={"content-type": "application/json"}).status_code == 422


def test_inline_demonstration_without_contact_names_wrenches(client, demo):
    body = dict(demo, wrenches=[[0.0] * 6 for _ in demo["t"]])
    response = client.post("/skills", json={"demonstration": body, "skill_type": "slide"})
    assert ["body", "demonstration", "wrenches"] in _locs(response)
    assert "contact" in response.text


@pytest.mark.parametrize(
    ("scale_t", "loc", "words"),
    [
        (lambda t: t * 1e-7, ["body", "demonstration", "t"], "Hz"),  # 200 MHz
        (lambda t: np.where(t > 2.0, t + 1e4, t), ["body", "demonstration", "t"], "more than 3600 s"),  # 2.8 h gap
        # a 100 s gap, resampled: today the clustering raises a plain ValueError (NaN) -> 422, never a 500
        (lambda t: np.where(t > 2.0, t + 100.0, t), None, ""),
    ],
)
def test_time_stamps_the_pipeline_cannot_handle_are_4xx(client, demo, scale_t, loc, words):
    body = dict(demo, t=scale_t(np.asarray(demo["t"])).tolist())
    response = client.post("/skills", json={"demonstration": body})
    if loc is None:
        assert response.status_code in (201, 422), response.text
    else:
        assert _locs(response) == [loc] and words in response.text


def test_unknown_skill_type_and_learn_options(client, demo):
    stored = client.post("/demonstrations", json=demo).json()["id"]
    assert _names(client.post("/skills", json={"demonstration_id": stored, "skill_type": "circle"}), "skill_type")
    assert _names(client.post("/skills", json={"demonstration_id": stored, "n_basis": 0}), "n_basis")
    response = client.post("/skills", json={"demonstration_id": stored, "demonstration": demo})
    assert response.status_code == 422 and "exactly one" in response.text
    assert client.post("/skills", json={}).status_code == 422


def test_unknown_ids_are_404(bus_client):
    c = bus_client
    for path in ("/demonstrations/demo_x", "/skills/skill_x", "/executions/exec_x", "/executions/exec_x/telemetry"):
        response = c.get(path)
        assert response.status_code == 404 and "no " in response.json()["detail"], path
    assert c.delete("/skills/skill_x").status_code == 404
    assert c.post("/executions/exec_x/abort").status_code == 404
    assert c.post("/skills", json={"demonstration_id": "demo_x"}).status_code == 404
    response = c.post("/executions", json={"skill_id": "skill_x"})
    assert response.status_code == 404 and "skill_x" in response.text


# --------------------------------------------------------------------------- learning


def test_learn_from_inline_and_stored_demonstrations(client, demo):
    created = client.post("/demonstrations", json=demo)
    assert created.status_code == 201
    info = created.json()
    assert info["summary"]["n_samples"] == len(demo["t"]) and info["id"].startswith("demo_")

    listed = client.get("/demonstrations").json()
    assert [d["id"] for d in listed] == [info["id"]]
    fetched = client.get(f"/demonstrations/{info['id']}").json()
    assert Demonstration.model_validate(fetched["demonstration"]).t == demo["t"]

    from_stored = client.post("/skills", json={"demonstration_id": info["id"], "skill_type": "auto"})
    assert from_stored.status_code == 201, from_stored.text
    skill = from_stored.json()
    assert skill["skill"]["skill_type"] == "slide" and skill["demonstration_id"] == info["id"]
    assert skill["learn_seconds"] > 0

    inline = client.post("/skills", json={"demonstration": demo, "skill_type": "slide", "n_basis": 30})
    assert inline.status_code == 201 and inline.json()["demonstration_id"] is None

    assert {s["id"] for s in client.get("/skills").json()} == {skill["id"], inline.json()["id"]}
    again = client.get(f"/skills/{skill['id']}").json()
    assert again["skill"] == skill["skill"]
    assert client.delete(f"/skills/{skill['id']}").status_code == 204
    assert client.get(f"/skills/{skill['id']}").status_code == 404


def test_csv_upload_of_a_kuleuven_recording(client):
    path = DATA / "contour_a_1.csv"
    options = {"quaternion_order": "wxyz", "wrench": "measured-on-tool", "wrench_frame": "tool", "tare": "true"}
    with path.open("rb") as f:
        response = client.post("/demonstrations/csv", files={"file": (path.name, f, "text/csv")}, data=options)
    assert response.status_code == 201, response.text
    created = response.json()
    assert created["source"] == "csv:contour_a_1.csv" and created["summary"]["n_samples"] > 1000
    assert any("negated" in note for note in created["import_notes"])
    learned = client.post("/skills", json={"demonstration_id": created["id"], "skill_type": "contour"})
    assert learned.status_code == 201, learned.text
    assert learned.json()["skill"]["skill_type"] == "contour"


def test_bad_csv_uploads_are_422(client):
    good = "t,px,py,pz,qx,qy,qz,qw,fx,fy,fz\n" + "\n".join(f"{k * 0.01},0,0,0,0,0,0,1,0,0,1" for k in range(100))
    missing = good.replace("fz", "force_q")
    response = client.post("/demonstrations/csv", files={"file": ("m.csv", missing.encode(), "text/csv")})
    assert ["body", "file"] in _locs(response) and "missing column for fz" in response.text
    response = client.post(
        "/demonstrations/csv", files={"file": ("m.csv", good.encode(), "text/csv")}, data={"wrench_frame": "moon"}
    )
    assert _names(response, "wrench_frame")
    response = client.post(
        "/demonstrations/csv", files={"file": ("m.csv", good.encode(), "text/csv")}, data={"columns": "t"}
    )
    assert _names(response, "columns")
    response = client.post("/demonstrations/csv", files={"file": ("b.csv", b"\xff\xfe\x00", "text/csv")})
    assert _names(response, "file")
    assert _names(client.post("/demonstrations/csv", data={"rate": "5"}), "file")
    ok = client.post("/demonstrations/csv", files={"file": ("g.csv", good.encode(), "text/csv")}, data={"rate": "100"})
    assert ok.status_code == 201, ok.text


def test_csv_upload_without_time_column_takes_the_rate_from_rate_or_dt(client):
    rows = "px,py,pz,qx,qy,qz,qw,fx,fy,fz\n" + "\n".join(f"{k * 0.001},0,0,0,0,0,1,0,0,1" for k in range(100))

    def upload(**options: str):
        return client.post("/demonstrations/csv", files={"file": ("k.csv", rows.encode(), "text/csv")}, data=options)

    missing = upload()
    assert _names(missing, "file") and "missing column for t (time)" in missing.text and "--dt SECONDS" in missing.text
    created = upload(dt="0.01")
    assert created.status_code == 201, created.text
    assert created.json()["import_notes"][0] == "no time column: rows taken as samples at 100 Hz (dt 0.01 s)"
    stored = client.get(f"/demonstrations/{created.json()['id']}").json()
    assert stored["demonstration"]["t"][:3] == [0.0, 0.01, 0.02] and len(stored["demonstration"]["t"]) == 100
    assert _names(upload(dt="0"), "dt")
    assert _names(upload(rate="100", dt="0.02"), "rate")


def test_csv_upload_of_a_kinesthetic_recording_learns_one_segment_per_stroke(client):
    """The real format (100 Hz, no time column, w-first, sensor-frame reaction with an offset), end to end."""
    demo = kinesthetic.kinesthetic_wipe("flat", n_strokes=2, friction=0.3, seed=1)
    text = kinesthetic.recording_csv_text(demo).encode()
    options = {"rate": "100", "quaternion_order": "wxyz", "wrench": "measured-on-tool", "wrench_frame": "tool"}

    def upload(**extra: str):
        return client.post("/demonstrations/csv", files={"file": ("wipe.csv", text, "text/csv")}, data=options | extra)

    created = upload()
    assert created.status_code == 201, created.text
    assert any("sensor offset removed" in note for note in created.json()["import_notes"])
    learned = client.post("/skills", json={"demonstration_id": created.json()["id"], "skill_type": "auto"})
    assert learned.status_code == 201, learned.text
    skill = learned.json()["skill"]
    assert skill["skill_type"] == "slide" and skill["auto_selection"]["confidence"] >= 0.8
    assert sum(s["kind"] == "contact" for s in skill["segments"]) == 2
    assert upload(tare_window="0,0.8").status_code == 201
    assert upload(force_offset="1,2,3").status_code == 201
    assert _names(upload(force_offset="1,2"), "force_offset")
    assert _names(upload(tare_window="0,x"), "tare_window")
    assert _names(upload(tare_window="50,60"), "tare_window")


# --------------------------------------------------------------------------- limits and auth


def test_body_over_the_limit_is_413(tmp_path, demo):
    with _client(create_app(_settings(tmp_path, max_body_mb=0.05), bus=None)) as c:
        big = c.post("/demonstrations", json=demo)  # ~200 kB
        assert big.status_code == 413 and "limit" in big.json()["detail"]

        def chunks():
            for _ in range(100):
                yield b" " * 1024

        chunked = c.post("/demonstrations", content=chunks(), headers={"content-type": "application/json"})
        assert chunked.status_code == 413
        assert c.get("/health").status_code == 200


def test_token_protects_mutating_endpoints(tmp_path, demo):
    with _client(create_app(_settings(tmp_path, token="s3cret"), bus=None)) as c:
        assert c.post("/demonstrations", json=demo).status_code == 401
        wrong = c.post("/demonstrations", json=demo, headers={"Authorization": "Bearer nope"})
        assert wrong.status_code == 401 and wrong.headers["www-authenticate"] == "Bearer"
        assert c.delete("/skills/skill_x").status_code == 401
        ok = c.post("/demonstrations", json=demo, headers={"Authorization": "Bearer s3cret"})
        assert ok.status_code == 201
        assert c.get("/demonstrations").status_code == 200 and c.get("/health").status_code == 200


def test_settings_from_env_and_flags(tmp_path):
    env = {
        "CONTACT_SKILLS_PORT": "9001",
        "CONTACT_SKILLS_DB": str(tmp_path / "x.db"),
        "CONTACT_SKILLS_ZENOH_ENDPOINTS": "tcp/a:1, tcp/b:2",
        "CONTACT_SKILLS_MAX_BODY_MB": "1.5",
        "CONTACT_SKILLS_TOKEN": "",
    }
    settings = ServiceSettings.from_env(env, port=9002)
    assert settings.port == 9002 and settings.db_path == tmp_path / "x.db" and settings.token is None
    assert settings.zenoh_endpoints == ["tcp/a:1", "tcp/b:2"] and settings.max_body_bytes == int(1.5 * 2**20)
    assert ServiceSettings.from_env({}).host == "127.0.0.1"
    with pytest.raises(SettingsError, match="CONTACT_SKILLS_PORT"):
        ServiceSettings.from_env({"CONTACT_SKILLS_PORT": "eighty"})


@pytest.mark.parametrize(
    ("env", "served"),
    [({}, 8765), ({"CONTACT_SKILLS_FOXGLOVE_PORT": "0"}, 0), ({"CONTACT_SKILLS_FOXGLOVE_PORT": " OFF "}, None),
     ({"CONTACT_SKILLS_TOKEN": "t", "CONTACT_SKILLS_TOKEN_READS": "1"}, None),
     ({"CONTACT_SKILLS_TOKEN": "t", "CONTACT_SKILLS_TOKEN_READS": "1", "CONTACT_SKILLS_FOXGLOVE_PORT": "9001"}, 9001)],
    ids=["default", "any free port", "off", "reads need the token", "asked for despite the token"],
)  # fmt: skip
def test_the_foxglove_port_is_a_setting(env, served):
    """The live view's port is read with the other settings: Foxglove's protocol has no token, so the server is off
    while reads need one unless the variable asks for it."""
    assert ServiceSettings.from_env(env).foxglove_server_port == served


def test_a_bad_foxglove_port_names_the_setting():
    for bad in ("eighty", "70000", "-1"):
        with pytest.raises(SettingsError, match="foxglove_port"):
            ServiceSettings.from_env({"CONTACT_SKILLS_FOXGLOVE_PORT": bad})


def test_openapi_and_health(client):
    assert client.get("/docs").status_code == 200
    spec = client.get("/openapi.json").json()
    for path in ("/health", "/demonstrations", "/demonstrations/csv", "/demonstrations/record", "/skills",
                 "/skills/{skill_id}", "/executions", "/executions/{execution_id}",
                 "/executions/{execution_id}/abort", "/executions/{execution_id}/telemetry"):  # fmt: skip
        assert path in spec["paths"], path
    parameters = [p["name"] for op in spec["paths"]["/skills"].values() for p in op.get("parameters", [])]
    assert parameters == [] or "credentials" not in parameters
    health = client.get("/health").json()
    assert health["status"] == "ok" and health["bus_connected"] is False and health["workers"] == []


# --------------------------------------------------------------------------- executions (fake bus)


def test_no_bus_or_no_worker_is_503(client, bus_client, demo):
    skill_id = client.post("/skills", json={"demonstration": demo}).json()["id"]
    response = client.post("/executions", json={"skill_id": skill_id})
    assert response.status_code == 503 and "Zenoh" in response.json()["detail"]
    assert client.post("/demonstrations/record", json={"scenario": "slide_flat"}).status_code == 503

    c = bus_client
    skill_id = c.post("/skills", json={"demonstration": demo}).json()["id"]
    c.bus.infos.clear()
    response = c.post("/executions", json={"skill_id": skill_id})
    assert response.status_code == 503 and "worker" in response.json()["detail"]
    assert c.get("/executions").json() == []  # nothing half-created


def _batch(execution_id: str, t0: float, n: int = 10) -> TelemetryBatch:
    t = (t0 + np.arange(n) * 1e-3).tolist()
    return TelemetryBatch(
        execution_id=execution_id,
        t=t,
        phase=["contact"] * n,
        segment_index=[1] * n,
        tool_position=[[0.5, 0.0, 0.2]] * n,
        tool_orientation=[[1.0, 0.0, 0.0, 0.0]] * n,
        reference_position=[[0.5, 0.0, 0.2]] * n,
        reference_orientation=[[1.0, 0.0, 0.0, 0.0]] * n,
        wrench_world=[[0.0, 0.0, -15.0, 0.0, 0.0, 0.0]] * n,
        wrench_cf=[[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]] * n,
        desired_force_cf_z_n=[15.0] * n,
        first_sample=round(t0 / 1e-3),
    )


def test_execution_lifecycle_with_a_fake_bus(bus_client, demo):
    c, bus = bus_client, bus_client.bus
    skill_id = c.post("/skills", json={"demonstration": demo}).json()["id"]
    bad = c.post("/executions", json={"skill_id": skill_id, "environment": {"offset": [0, 0]}})
    assert _names(bad, "offset")
    assert _names(c.post("/executions", json={"skill_id": skill_id, "controller": "pid"}), "controller")
    assert _names(c.post("/executions", json={"skill_id": skill_id, "engine": "ode"}), "engine")
    assert _names(c.post("/executions", json={"skill_id": skill_id, "gains": {"damping_ratio": -1}}), "damping_ratio")
    one_demonstration = c.post("/executions", json={"skill_id": skill_id, "gains": {"gain_schedule": "from_spread"}})
    assert _locs(one_demonstration) == [["body", "gains", "gain_schedule"]]  # no spread to schedule from
    assert c.post("/executions", json={}).status_code == 422

    body = {"skill_id": skill_id, "scenario": "slide_flat", "environment": {"unknown_offset": [0, 0, 0.02]},
            "engine": "mujoco"}  # fmt: skip
    response = c.post("/executions", json=body)
    assert response.status_code == 202, response.text
    created = response.json()
    exec_id = created["id"]
    assert created["telemetry_key"] == f"cskills/exec/{exec_id}/telemetry" and created["worker_id"] == "w0"
    assert bus.started[0][0] == exec_id and bus.started[0][1].scenario == "slide_flat"
    assert bus.started[0][1].engine is Engine.mujoco  # the worker is asked for the engine chosen
    assert c.get(f"/executions/{exec_id}").json()["status"] == "running"

    # status and telemetry arrive from "Zenoh threads"; batches out of order are stored in stream order
    threads = [threading.Thread(target=bus.on_telemetry, args=(_batch(exec_id, t0),)) for t0 in (0.02, 0.0, 0.01)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    bus.on_status(ExecutionStatus(execution_id=exec_id, worker_id="w0", phase="contact", segment_index=1))
    assert c.post(f"/executions/{exec_id}/abort").status_code == 202
    assert bus.commands == [(exec_id, "abort")]
    view = c.get(f"/executions/{exec_id}").json()
    assert view["phase"] == "contact" and view["telemetry_samples"] == 30 and view["telemetry_batches"] == 3

    metrics = ExecutionMetrics(controller="hybrid_cf", phase="aborted", real_time_factor=10.0, duration_s=0.03,
                               steps=30, peak_force_n=15.0, abort_reason="abort requested")  # fmt: skip
    bus.on_status(ExecutionStatus(execution_id=exec_id, worker_id="w0", phase="aborted", metrics=metrics))
    view = c.get(f"/executions/{exec_id}").json()
    assert view["status"] == "aborted" and view["metrics"]["steps"] == 30 and view["error"] == "abort requested"
    late = ExecutionStatus(execution_id=exec_id, worker_id="w0", phase="contact")
    bus.on_status(late)  # a late status never reopens a finished execution
    assert c.get(f"/executions/{exec_id}").json()["status"] == "aborted"
    assert c.post(f"/executions/{exec_id}/abort").status_code == 409

    tel = c.get(f"/executions/{exec_id}/telemetry").json()
    assert tel["n_samples"] == 30 and np.all(np.diff(tel["t"]) > 0)
    assert tel["phase"][0] == "contact" and tel["wrench_cf"][0][2] == 15.0 and tel["segment_index"][0] == 1
    assert c.get(f"/executions/{exec_id}/telemetry?every=7").json()["n_samples"] == 5
    assert _names(c.get(f"/executions/{exec_id}/telemetry?every=0"), "every")
    bus.on_telemetry(_batch("exec_unknown", 0.0))  # not ours: not stored, no error


def test_what_a_deletion_keeps_and_what_cannot_be_deleted(bus_client, demo):
    """A demonstration's skills outlive it and still run; a running execution and a sweep's trial are 409."""
    c, store = bus_client, bus_client.app.state.store
    stored = c.post("/demonstrations", json=demo).json()["id"]
    skill_id = c.post("/skills", json={"demonstration_id": stored}).json()["id"]
    assert c.delete(f"/demonstrations/{stored}").status_code == 204
    assert c.delete(f"/demonstrations/{stored}").status_code == 404
    assert c.get(f"/skills/{skill_id}").status_code == 200
    running = c.post("/executions", json={"skill_id": skill_id})
    assert running.status_code == 202 and c.bus.started[-1][0] == running.json()["id"]
    refused = c.delete(f"/executions/{running.json()['id']}")
    assert refused.status_code == 409 and "running" in refused.text
    trial = store.executions.add({"sweep": {"id": "sweep_0a1b", "trial": 3}}, skill_id)
    store.executions.update(trial.id, ExecutionState.done)
    refused = c.delete(f"/executions/{trial.id}")
    assert refused.status_code == 409 and "trial 3 of sweep sweep_0a1b" in refused.text
    assert c.get(f"/executions/{trial.id}").status_code == 200


def test_a_gap_no_worker_fills_is_reported_and_a_repeated_batch_is_counted_once(bus_client, demo):
    c, bus = bus_client, bus_client.bus
    skill_id = c.post("/skills", json={"demonstration": demo}).json()["id"]
    exec_id = c.post("/executions", json={"skill_id": skill_id}).json()["id"]
    for t0 in (0.0, 0.0, 0.02):  # samples 0-9 twice (a replay of what came live), 20-29; 10-19 never arrive
        bus.on_telemetry(_batch(exec_id, t0))
    metrics = ExecutionMetrics(controller="hybrid_cf", phase="done", real_time_factor=10.0, duration_s=0.03,
                               steps=30, peak_force_n=15.0)  # fmt: skip
    bus.on_status(ExecutionStatus(execution_id=exec_id, worker_id="w0", phase="done", metrics=metrics))
    deadline = time.monotonic() + 10
    while (view := c.get(f"/executions/{exec_id}").json())["status"] != "done":  # stored once the gap was asked
        assert time.monotonic() < deadline, view
        time.sleep(0.05)
    assert view["telemetry_samples"] == 20 and view["telemetry_missing_samples"] == 10
    assert ("w0", exec_id, 10, 20) in bus.replays  # the worker was asked for exactly the gap


def test_worker_lost_and_api_restart_mark_running_executions_failed(tmp_path, demo):
    store = Store(tmp_path / "api.db")
    events = BusEvents(store)
    bus = FakeBus(events.on_status, events.on_telemetry, events.on_worker_lost, workers=1)
    with _client(create_app(_settings(tmp_path), bus=bus, store=store)) as c:
        skill_id = c.post("/skills", json={"demonstration": demo}).json()["id"]
        lost = c.post("/executions", json={"skill_id": skill_id}).json()["id"]
        bus.on_worker_lost("w0")
        view = c.get(f"/executions/{lost}").json()
        assert view["status"] == "failed" and "w0" in view["error"] and "lost" in view["error"]
        left_running = c.post("/executions", json={"skill_id": skill_id}).json()["id"]
    store.close()
    with _client(create_app(_settings(tmp_path), bus=None)) as c:  # the API restarts; nothing is lost
        view = c.get(f"/executions/{left_running}").json()
        assert view["status"] == "failed" and view["error"] == RESTART_REASON
        assert c.get(f"/skills/{skill_id}").status_code == 200


def test_record_through_the_bus(bus_client):
    c, bus = bus_client, bus_client.bus
    d = plane_slide(rate_hz=200, duration_s=4)
    demonstration = Demonstration.from_arrays(d.t, d.positions, d.orientations, d.wrenches)
    bus.recorded = RecordReply(worker_id="w0", code="error", error="unknown scenario 'moon'")
    response = c.post("/demonstrations/record", json={"scenario": "moon"})
    assert response.status_code == 422 and "moon" in response.text
    bus.recorded = RecordReply(worker_id="w0", code="busy", error="busy")
    assert c.post("/demonstrations/record", json={"scenario": "slide_flat"}).status_code == 503
    bus.recorded = RecordReply(worker_id="w0", code="ok", demonstration=demonstration, ground_truth={"scenario": "s"})
    response = c.post("/demonstrations/record", json={"scenario": "slide_flat", "seed": 3})
    assert response.status_code == 201 and response.json()["extra"]["ground_truth"] == {"scenario": "s"}
    assert _names(c.post("/demonstrations/record", json={"scenario": "slide_flat", "seed": -1}), "seed")


# --------------------------------------------------------------------------- bugs and the store


def test_a_true_bug_is_a_logged_500_with_a_json_body(tmp_path, caplog):
    store = Store(tmp_path / "api.db")
    app = create_app(_settings(tmp_path), bus=None, store=store)
    store.skills.page = lambda *a: 1 / 0  # type: ignore[method-assign]
    with _client(app, raise_server_exceptions=False) as c:
        response = c.get("/skills")
    assert response.status_code == 500 and "ZeroDivisionError" in response.json()["detail"]
    assert any("bug: GET /skills" in r.getMessage() for r in caplog.records)
    store.close()


def test_store_schema_version_threads_and_newer_databases(tmp_path, demo):
    import sqlite3

    from services.store import SCHEMA_VERSION, StoreError

    store = Store(tmp_path / "s.db")
    assert store.schema_version() == SCHEMA_VERSION
    execution = store.executions.add({"x": 1}, None)
    batches = [_batch(execution.id, k * 0.01) for k in range(20)]
    threads = [threading.Thread(target=store.telemetry.add, args=(execution.id, b)) for b in batches]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert store.telemetry.counts(execution.id) == (20, 200)
    assert np.all(np.diff(store.telemetry.rows(execution.id)[:, 0]) > 0)
    store.close()
    with sqlite3.connect(tmp_path / "s.db") as db:
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        db.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    with pytest.raises(StoreError, match="newer"):
        Store(tmp_path / "s.db")
    (tmp_path / "junk.db").write_bytes(b"not a database at all" * 100)
    with pytest.raises(StoreError, match="not a usable SQLite database"):
        Store(tmp_path / "junk.db")
