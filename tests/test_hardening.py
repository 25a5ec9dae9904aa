"""The service probed as an attacker and under load (issue 13): every finding has a test here that failed on the
code before the fix.

Bounds declared in the schemas (positions, forces, time span, resampled samples, basis counts, execution settings,
recording overrides): 422 naming the field, at once. Learning in learner processes: a time budget, the job killed
when its client goes away, the event loop free meanwhile. /health minimal without the token, the token on reads,
no cross-origin browser request, no foreign Host.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import time

import httpx
import pytest
from conftest import LiveApi
from conftest import api_settings as _settings
from conftest import loopback_client as _client
from test_api import _demo_json, _locs, _names

from corpus.synthetic import plane_slide
from schemas import Demonstration
from services import learner_pool
from services.app import create_app
from services.learner_pool import WALL_BUDGETS, LearnerPool, LearningCancelled, LearningTimedOut

SLOW_OPTIONS = {"n_basis": 500, "max_basis": 1000, "basis_per_second": 200, "max_fit_samples": 100_000}
"""Learning options at their bounds: a 20 s, 1 kHz demonstration then takes ~13 s on one core."""


@pytest.fixture(scope="module")
def demo() -> dict:
    return _demo_json()


def _slow_demonstration_json(duration_s: float = 20.0) -> str:
    d = plane_slide(rate_hz=1000.0, duration_s=duration_s)
    return Demonstration.from_arrays(d.t, d.positions, d.orientations, d.wrenches).model_dump_json()


# --------------------------------------------------------------------------- implausible values


def test_a_wrench_near_1e300_is_refused_and_reads_keep_working(client, demo):
    body = json.loads(json.dumps(demo))
    body["wrenches"][12][2] = 1e300
    response = client.post("/demonstrations", json=body)
    assert _names(response, "wrenches") and "row 12" in response.text and "10000 N" in response.text
    assert client.post("/demonstrations", json=demo).status_code == 201
    listed = client.get("/demonstrations")
    assert listed.status_code == 200 and listed.json()[0]["summary"]["max_force_n"] < 100


@pytest.mark.parametrize(
    ("field", "change", "words"),
    [
        ("positions", lambda b: b["positions"].__setitem__(3, [570.0, 10.0, 300.0]), "millimetres"),
        ("wrenches", lambda b: b["wrenches"][4].__setitem__(4, 5e3), "N·m"),
        ("t", lambda b: b.__setitem__("t", [t * 1e3 for t in b["t"]]), "3600 s"),
        ("t", lambda b: b.__setitem__("t", [t + 1e12 for t in b["t"]]), "plausible"),
    ],
)
def test_implausible_demonstrations_name_the_field(client, demo, field, change, words):
    body = json.loads(json.dumps(demo))
    change(body)
    response = client.post("/demonstrations", json=body)
    assert _names(response, field) and words in response.text, response.text


def test_the_bounds_are_declared_in_the_openapi(client):
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    demonstration = schemas["Demonstration"]["properties"]
    assert demonstration["t"]["maxItems"] == 200_000
    assert demonstration["positions"]["items"]["prefixItems"][0]["maximum"] == 10.0
    assert demonstration["wrenches"]["items"]["prefixItems"][2]["maximum"] == 10_000.0
    assert schemas["SkillRequest"]["properties"]["basis_per_second"]["maximum"] == 200
    settings = schemas["ExecutionRequest"]["properties"]
    assert settings["settle_s"]["maximum"] == 10 and settings["approach_max_distance_m"]["maximum"] == 0.5
    assert settings["pause_timeout_s"]["maximum"] == 3600
    assert "within" in schemas["RecordRequest"]["properties"]["overrides"]["description"]


def test_unbounded_learning_options_are_422(client, demo):
    response = client.post(
        "/skills", json={"demonstration": demo, "n_basis": 1000, "basis_per_second": 1e9, "max_basis": 2000}
    )
    assert {tuple(loc) for loc in _locs(response)} == {
        ("body", "n_basis"),
        ("body", "basis_per_second"),
        ("body", "max_basis"),
    }


# --------------------------------------------------------------------------- CSV uploads


def _csv(rows: int, span_s: float, header: str = "t,x,y,z,qx,qy,qz,qw,fx,fy,fz", scale: float = 1.0) -> bytes:
    lines = [header]
    for k in range(rows):
        t = span_s * k / (rows - 1)
        lines.append(f"{t:.4f},{0.5 * scale},{0.01 * k * scale},{0.3 * scale},0,0,0,1,0,0,{5 + k % 3}")
    return "\n".join(lines).encode()


def test_a_3_kb_csv_cannot_ask_for_millions_of_samples(client):
    data = _csv(60, 30.0)
    assert len(data) < 3500
    cpu = time.process_time()  # (the API runs in this process; CPU time, which other processes' load leaves alone)
    response = client.post("/demonstrations/csv", files={"file": ("tiny.csv", data)}, data={"rate": "100000"})
    assert time.process_time() - cpu < 2.0  # refused before resampling: 3 M samples would take far longer
    assert _names(response, "rate") and "200000" in response.text, response.text


def test_csv_units_and_oversized_fields_are_422(client):
    in_mm = _csv(60, 3.0, header="t,x [mm],y [mm],z [mm],qx,qy,qz,qw,fx [N],fy [N],fz [N]", scale=1000.0)
    response = client.post("/demonstrations/csv", files={"file": ("mm.csv", in_mm)}, data={"rate": "20"})
    assert _names(response, "file") and "unit 'mm'" in response.text, response.text
    unlabelled = client.post(
        "/demonstrations/csv", files={"file": ("mm.csv", _csv(60, 3.0, scale=1000.0))}, data={"rate": "20"}
    )
    assert _names(unlabelled, "file") and "millimetres" in unlabelled.text, unlabelled.text
    huge_field = _csv(60, 3.0) + b'\n"' + b"9" * 140_000 + b'",1,1,1,0,0,0,1,0,0,1'
    response = client.post("/demonstrations/csv", files={"file": ("big.csv", huge_field)})
    assert _names(response, "file") and "not a readable CSV" in response.text, response.text


# --------------------------------------------------------------------------- executions and recordings


def test_execution_settings_and_recording_overrides_are_bounded(bus_client, demo):
    c = bus_client
    skill_id = c.post("/skills", json={"demonstration": demo}).json()["id"]
    for field, value in (
        ("settle_s", 3000),
        ("approach_max_distance_m", 100),
        ("pause_timeout_s", 1e9),
        ("telemetry_batch", 10**6),
    ):
        assert _names(c.post("/executions", json={"skill_id": skill_id, field: value}), field)
    big_offset = {"skill_id": skill_id, "environment": {"unknown_offset": [0, 0, 50]}}
    assert _names(c.post("/executions", json=big_offset), "unknown_offset")
    stiff = {"skill_id": skill_id, "gains": {"translational_stiffness_n_per_m": [1e9, 1, 1]}}
    assert _names(c.post("/executions", json=stiff), "translational_stiffness_n_per_m")
    for overrides, words in (
        ({"move_duration_s": 2000}, "[0, 60]"),
        ({"table_height_m": 100}, "[-2, 2]"),
        ({"target_force_n": "lots"}, "a number"),
        ({"../etc": 1}, "not a field name"),
    ):
        response = c.post("/demonstrations/record", json={"scenario": "slide_flat", "overrides": overrides})
        assert _names(response, "overrides") and words in response.text, response.text
    assert c.bus.started == []


def test_incoherent_inline_skills_are_422(bus_client, demo):
    c = bus_client
    skill = c.post("/skills", json={"demonstration": demo}).json()["skill"]
    contact = next(k for k, s in enumerate(skill["segments"]) if s["kind"] == "contact")
    broken = json.loads(json.dumps(skill))
    broken["segments"][contact]["compliant_frames"] = None
    broken["segments"][contact]["force_constant_n"] = None
    broken["segments"][0]["position_dmp"]["weights"] = broken["segments"][0]["position_dmp"]["weights"][:-1]
    locs = _locs(c.post("/executions", json={"skill": broken}))
    assert ["body", "skill", "segments", contact, "compliant_frames"] in locs
    assert ["body", "skill", "segments", contact, "force_constant_n"] in locs
    assert ["body", "skill", "segments", 0, "position_dmp"] in locs
    assert c.bus.started == []
    assert c.post("/executions", json={"skill": skill}).status_code == 202


def test_a_status_from_another_worker_than_the_one_running_it_is_ignored(bus_client, demo):
    from schemas.bus import ExecutionStatus

    c = bus_client
    skill_id = c.post("/skills", json={"demonstration": demo}).json()["id"]
    created = c.post("/executions", json={"skill_id": skill_id}).json()
    assert created["worker_id"] == "w0"
    c.bus.on_status(ExecutionStatus(execution_id=created["id"], worker_id="intruder", phase="done", message="forged"))
    assert c.get(f"/executions/{created['id']}").json()["status"] == "running"
    c.bus.on_status(ExecutionStatus(execution_id=created["id"], worker_id="w0", phase="aborted", error="stop"))
    assert c.get(f"/executions/{created['id']}").json()["status"] == "aborted"


@pytest.mark.parametrize("path", ["/demonstrations", "/skills", "/executions"])
def test_huge_list_offsets_are_422_not_500(client, path):
    response = client.get(path, params={"offset": "9223372036854775808"})
    assert _names(response, "offset")
    assert client.get(path, params={"offset": 10**9}).json() == []


def test_a_learning_failure_is_told_in_our_words(client, demo):
    body = dict(demo)
    t = [x + 100.0 if x > 2.0 else x for x in demo["t"]]  # a 100 s gap: the clustering sees NaN
    response = client.post("/skills", json={"demonstration": {**body, "t": t}})
    assert response.status_code in (201, 422), response.text
    assert "Input X" not in response.text and "sklearn" not in response.text


# --------------------------------------------------------------------------- health, token, browsers


def test_health_is_minimal_without_the_token(tmp_path):
    with _client(create_app(_settings(tmp_path, token="s3cret"), bus=None)) as c:
        public = c.get("/health").json()
        assert public["detail"] is None and str(tmp_path) not in json.dumps(public)
        assert "pid" not in json.dumps(public) and public["learning"]["processes"] >= 1
        detail = c.get("/health", headers={"Authorization": "Bearer s3cret"}).json()["detail"]
        assert detail["database"] == str(tmp_path / "api.db") and detail["pid"] > 0


def test_the_token_can_be_required_on_reads(tmp_path, demo):
    auth = {"Authorization": "Bearer s3cret"}
    with _client(create_app(_settings(tmp_path, token="s3cret", token_reads=True), bus=None)) as c:
        for path in ("/demonstrations", "/skills", "/executions", "/skills/skill_x"):
            assert c.get(path).status_code == 401, path
        assert c.get("/demonstrations", headers=auth).status_code == 200
        assert c.get("/skills/skill_x", headers=auth).status_code == 404
        assert c.get("/health").status_code == 200
    with _client(create_app(_settings(tmp_path, token="s3cret"), bus=None)) as c:
        assert c.get("/demonstrations").status_code == 200  # reads open unless asked


def test_cross_origin_browser_requests_and_foreign_hosts_are_refused(tmp_path, demo):
    with _client(create_app(_settings(tmp_path), bus=None)) as c:
        evil = c.post("/demonstrations", json=demo, headers={"Origin": "http://evil.example"})
        assert evil.status_code == 403 and "CONTACT_SKILLS_CORS_ORIGINS" in evil.text
        assert "access-control-allow-origin" not in evil.headers
        same = c.post("/demonstrations", json=demo, headers={"Origin": "http://127.0.0.1"})
        assert same.status_code == 201
        rebound = c.get("/demonstrations", headers={"Host": "attacker.example:8000"})
        assert rebound.status_code == 400 and "loopback" in rebound.text
    settings = _settings(tmp_path, cors_origins=["https://ui.example"])
    with _client(create_app(settings, bus=None)) as c:
        allowed = c.get("/demonstrations", headers={"Origin": "https://ui.example"})
        assert allowed.status_code == 200 and allowed.headers["access-control-allow-origin"] == "https://ui.example"
        assert c.get("/demonstrations", headers={"Origin": "https://other.example"}).status_code == 403


# --------------------------------------------------------------------------- learning off the event loop


async def _never() -> bool:
    return False


def test_the_pool_kills_a_job_past_its_cpu_budget_and_replaces_the_process(monkeypatch):
    # The budget is CPU time, not wall time: the quick learn (~0.3 s of CPU; over 15 s of wall time at a load of 6,
    # the learners being niced) fits however busy the machine is; the slow one (~13 s of CPU) is stopped once it has
    # used 6 s, not run to its end. The wall-time backstop (its own test below) is set far off here: at a load of 8
    # the niced learner got 2.3 s of CPU in its 5 budgets of wall time, and the backstop, not the CPU budget, ended it.
    monkeypatch.setattr(learner_pool, "WALL_BUDGETS", 1000)
    pool = LearnerPool(processes=1, time_budget_s=6.0)
    options = json.dumps(SLOW_OPTIONS)
    demonstration = _slow_demonstration_json()

    async def scenario() -> int:
        quick = await pool.learn([_demo_as_json()], ["demo"], "{}", _never)
        assert quick.kind == "ok" and quick.skill_type == "slide"
        first_pid = pool.pids()[0]
        with pytest.raises(LearningTimedOut, match="budget of 6 s of CPU time") as stopped:
            await pool.learn([demonstration], ["slow"], options, _never)
        used = re.search(r"\(([\d.]+) s of CPU used in ([\d.]+) s\)", str(stopped.value))
        assert used and 6.0 <= float(used[1]) < 10.0, str(stopped.value)  # stopped at its budget, within a few polls
        again = await pool.learn([_demo_as_json()], ["demo"], "{}", _never)
        assert again.kind == "ok" and pool.pids()[0] != first_pid
        return pool.stats.restarted

    try:
        restarted = asyncio.run(scenario())
    finally:
        pool.close()
    assert restarted == 1


def test_a_learner_starved_of_cpu_is_stopped_after_its_wall_budgets():
    """A learner that gets no CPU at all (stopped here; on a machine busy enough, niced) still ends: after
    WALL_BUDGETS budgets of wall time, saying it used no CPU."""
    pool = LearnerPool(processes=1, time_budget_s=0.4)

    async def scenario() -> None:
        pool.warm_up()
        await pool._warming  # the process exists, idle
        [pid] = pool.pids()
        os.kill(pid, signal.SIGSTOP)
        with pytest.raises(LearningTimedOut, match=r"\(0\.0 s of CPU used in") as stopped:
            await pool.learn([_demo_as_json()], ["demo"], "{}", _never)
        waited = float(re.search(r"used in ([\d.]+) s\)", str(stopped.value))[1])
        assert waited >= WALL_BUDGETS * 0.4, str(stopped.value)

    try:
        asyncio.run(scenario())
    finally:
        pool.close()
    assert pool.stats.timed_out == 1 and pool.stats.restarted == 1


def _demo_as_json() -> str:
    return Demonstration.model_validate(_demo_json()).model_dump_json()


def test_the_pool_cancels_a_job_whose_client_is_gone():
    pool = LearnerPool(processes=1, time_budget_s=120.0)
    gone_after = time.monotonic() + 1.0

    async def gone() -> bool:
        return time.monotonic() > gone_after

    try:
        with pytest.raises(LearningCancelled):  # (not a result: the learn was stopped, not run to its end)
            asyncio.run(pool.learn([_slow_demonstration_json()], ["slow"], json.dumps(SLOW_OPTIONS), gone))
        assert pool.stats.cancelled == 1 and pool.stats.completed == 0 and pool.pids() == []
    finally:
        pool.close()


def test_an_abandoned_learn_stops_and_health_answers_meanwhile(tmp_path):
    body = {"demonstration": json.loads(_slow_demonstration_json()), **SLOW_OPTIONS}
    app = create_app(_settings(tmp_path, learn_processes=1), bus=None)
    with LiveApi(app) as api, httpx.Client(base_url=api.url, timeout=30) as http:
        with pytest.raises(httpx.ReadTimeout):  # the client gives up after 2 s and closes its connection
            http.post("/skills", json=body, timeout=httpx.Timeout(30, read=2.0))
        health = http.get("/health", timeout=5).json()  # the event loop is free while the learner computes
        assert health["learning"]["running"] <= 1
        deadline = time.monotonic() + 120  # a hang guard, not a timing: `completed == 0` below tells a stopped learn
        while (learning := http.get("/health").json()["learning"])["cancelled"] < 1 or learning["running"]:
            assert time.monotonic() < deadline, f"the abandoned learn kept computing: {learning}"
            time.sleep(0.2)
        assert learning["completed"] == 0 and learning["restarted"] == 1


def test_a_learn_past_the_memory_budget_is_422_and_the_next_one_learns(tmp_path, demo):
    """The learner's address space is capped (50 learns once took 1.4 GB): 64 MiB is less than a learner process
    needs at all (~370 MiB for this learn), so the job fails inside its process, answered as a 422 naming the
    budget, not a 500 and not the machine's memory; a learner with room learns the same demonstration."""
    with _client(create_app(_settings(tmp_path, learn_processes=1, learn_memory_mb=64), bus=None)) as c:
        response = c.post("/skills", json={"demonstration": demo})
        assert response.status_code == 422, response.text
        assert "memory budget of 64 MiB" in response.text and "CONTACT_SKILLS_LEARN_MEMORY_MB" in response.text
    with _client(create_app(_settings(tmp_path, learn_processes=1, learn_memory_mb=1024), bus=None)) as c:
        assert c.post("/skills", json={"demonstration": demo}).status_code == 201


def test_a_boolean_is_not_a_number(client, demo):
    """``"seed": false`` was taken as seed 0, ``"n_basis": true`` as 1 basis function, ``"approach_speed_m_s": true``
    as 1 m/s: a 422 naming the field."""
    response = client.post("/demonstrations/record", json={"scenario": "slide_flat", "seed": False})
    assert _names(response, "seed") and "not a boolean" in response.text, response.text
    response = client.post("/skills", json={"demonstration": demo, "n_basis": True})
    assert _names(response, "n_basis") and "not a boolean" in response.text, response.text
    response = client.post("/executions", json={"skill_id": "skill_0", "approach_speed_m_s": True})
    assert _names(response, "approach_speed_m_s") and "not a boolean" in response.text, response.text
    response = client.post("/executions", json={"skill_id": "skill_0", "environment": {"offset": [0.0, True, 0.0]}})
    assert _names(response, "offset") and "not a boolean" in response.text, response.text
    response = client.post("/skills", json={"demonstration": demo, "basis_per_second": False})
    assert _names(response, "basis_per_second") and "not a boolean" in response.text, response.text
    response = client.post("/demonstrations/record", json={"scenario": "slide_flat", "seed": 7})
    assert response.status_code != 422, response.text  # a number is still a number (no bus here: 503)
    response = client.post("/skills", json={"demonstration": demo, "basis_per_second": 30})
    assert response.status_code == 201, response.text  # an integer is a real number
