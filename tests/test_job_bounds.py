"""Issue 25 (H1, H4, H5) on the real stack: every job bounded by the work it implies, reads that stay bounded, nothing
stored that cannot be read back. Each test failed on the code before the fix.

`contact-skills up --workers 1` on loopback with a job budget of 12 000 control steps and telemetry pages of 2 000
samples, so that the bounds show within seconds (the defaults, 2 000 000 steps and 20 000 samples, are what
docs/SERVICE.md measures).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")

from test_service import RECORD, running_stack  # noqa: E402
from waiting import wait_for  # noqa: E402

from schemas import Demonstration, DemonstrationMetadata, ExecutionRequest, Skill  # noqa: E402
from schemas.bus import (  # noqa: E402
    ExecutionCommand,
    RecordReply,
    RecordRequest,
    StartExecution,
    StartReply,
)
from schemas.job_budget import ENV_JOB_MAX_STEPS, NOMINAL_TIME_STEP_S  # noqa: E402
from services.client import Client  # noqa: E402
from services.store import Store  # noqa: E402
from skills.job_estimate import execution_estimate, taught_time_step_s  # noqa: E402

BUDGET_STEPS = 12_000
"""The stack's job budget, control steps (the recording of RECORD implies 10 300, a run of its skill 10 400)."""
PAGE = 2_000
"""The stack's telemetry page, samples."""
TOUCHDOWN = {"touchdown_speed_m_s": 0.03}
"""A touch-down speed for the runs of this module: a default one counts at its slowest (0.5 mm/s, 80 s per
approach), more than this small budget holds."""
CRAWL = {"approach_speed_m_s": 1e-5, "touchdown_speed_m_s": 1e-5}
"""The probe's settings: each within its bounds, together a guarded approach of hours."""


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    env = {ENV_JOB_MAX_STEPS: str(BUDGET_STEPS), "CONTACT_SKILLS_TELEMETRY_PAGE_SAMPLES": str(PAGE)}
    yield from running_stack(tmp_path_factory.mktemp("bounds"), workers=1, env=env)


@pytest.fixture(scope="module")
def skill(stack) -> dict:
    demo = stack.post("/demonstrations/record", RECORD, 201)
    return stack.post("/skills", {"demonstration_id": demo["id"]}, 201)


@pytest.fixture(scope="module")
def finished(stack, skill) -> dict:
    """A run of the skill, done."""
    created = stack.post("/executions", {"skill_id": skill["id"], **TOUCHDOWN}, 202)
    view = stack.finished(created["id"])
    assert view["status"] == "done", view
    return view


def _worker(stack) -> dict:
    return stack.workers(1)[0]


def _rss_mb(stack, worker: dict) -> float:
    """The resident memory of a worker process of ``stack``, MB."""
    status = Path(f"/proc/{stack.worker_pids()[worker['worker_id']]}/status").read_text()
    return int(next(line for line in status.splitlines() if line.startswith("VmRSS")).split()[1]) / 1024


def _asked(session, key: str, payload: str, timeout_s: float = 10.0) -> bytes:
    """The first reply of a worker's queryable (asked again while a new session's routes are still unknown)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for reply in session.get(key, payload=payload, timeout=max(deadline - time.monotonic(), 0.1)):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        time.sleep(0.2)
    raise AssertionError(f"no reply on {key} within {timeout_s:g} s")


def _detail(response: httpx.Response) -> list[dict]:
    assert response.status_code == 422, response.text
    return response.json()["detail"]


# --------------------------------------------------------------------------- H1: jobs bounded by the work they imply


def test_an_execution_whose_settings_imply_hours_is_422_naming_them(stack, skill):
    """The probe's POST /executions (approach and touch-down at 10 µm/s: 8 000 s, 3.3 GB of worker memory before):
    a 422 naming both speeds and the budget; the worker never sees it. The same skill at a sane speed fits."""
    worker = _worker(stack)
    before = _rss_mb(stack, worker)
    response = stack.http.post("/executions", json={"skill_id": skill["id"], **CRAWL})
    detail = _detail(response)
    assert {tuple(entry["loc"]) for entry in detail} == {
        ("body", "approach_speed_m_s"),
        ("body", "touchdown_speed_m_s"),
    }
    for entry in detail:
        assert entry["type"] == "job_budget" and "8,0" in entry["msg"] and "s of simulated time" in entry["msg"]
        assert f"{BUDGET_STEPS:,} control steps" in entry["msg"] and ENV_JOB_MAX_STEPS in entry["msg"]
    time.sleep(1.0)
    assert _rss_mb(stack, worker) < before + 50
    assert _worker(stack)["executions_run"] == worker["executions_run"]
    estimate = execution_estimate(Skill.model_validate(skill["skill"]), ExecutionRequest(**TOUCHDOWN, skill_id="s"),
                                  taught_time_step_s(Skill.model_validate(skill["skill"])))  # fmt: skip
    assert estimate.steps <= BUDGET_STEPS


def test_a_recording_at_a_10_us_step_is_422_at_once_and_health_shows_a_recording(stack, skill):
    """The probe's POST /demonstrations/record at time_step_s 1e-5 (a 504 after 120 s before, the worker recording
    for minutes): a 422 on overrides.time_step_s at once. A recording that fits shows as such in /health while it
    runs."""
    started = time.monotonic()
    response = stack.http.post(
        "/demonstrations/record", json={**RECORD, "overrides": {**RECORD["overrides"], "time_step_s": 1e-5}}
    )
    (entry,) = _detail(response)
    assert entry["loc"] == ["body", "overrides", "time_step_s"] and "200,000 samples" in entry["msg"]
    assert time.monotonic() - started < 10
    wait_for(lambda: _worker(stack)["activity"] == "idle", 10, "the worker idle")

    reply: dict = {}
    thread = threading.Thread(target=lambda: reply.update(stack.post("/demonstrations/record", RECORD, 201)))
    thread.start()
    seen = wait_for(lambda: (w := _worker(stack))["activity"] == "recording" and w, 30, "a worker recording")
    assert seen["busy"]
    thread.join(60)
    assert reply["summary"]["n_samples"] > 1000


def test_a_worker_refuses_a_job_over_its_budget_sent_over_the_bus(stack, skill):
    """Straight to the worker over Zenoh (no API in between): the same execution and recording are refused at once,
    naming the settings; nothing runs."""
    worker = _worker(stack)
    keys = f"cskills/exec/{worker['worker_id']}"
    request = ExecutionRequest(skill=Skill.model_validate(skill["skill"]), **CRAWL)
    start = StartExecution(execution_id="exec_straight_to_the_worker", request=request)
    with stack.session("api") as session:  # the API's login: a worker takes starts from it alone
        answer = StartReply.model_validate_json(_asked(session, f"{keys}/start", start.model_dump_json()))
        if answer.accepted:  # the code before: it runs for hours; stop it
            abort = ExecutionCommand(command="abort", execution_id=start.execution_id)
            session.put(f"cskills/exec/{start.execution_id}/cmd", abort.model_dump_json())
        assert (answer.accepted, answer.code) == (False, "error"), answer
        assert "touchdown_speed_m_s" in answer.reason and "job budget" in answer.reason
        record = RecordRequest(scenario="slide_flat", overrides={"time_step_s": 1e-5})
        recorded = RecordReply.model_validate_json(_asked(session, f"{keys}/record", record.model_dump_json()))
        assert recorded.code == "error" and recorded.error.startswith("overrides.time_step_s: ")
    idle = wait_for(lambda: (w := _worker(stack))["activity"] == "idle" and w, 10, "the worker idle")
    assert idle["executions_run"] == worker["executions_run"]


def test_a_paused_execution_is_aborted_when_its_steps_reach_the_budget(stack, skill):
    """What no estimate can foresee (a pause holds the run stepping in place) is cut by the worker at the budget."""
    created = stack.post("/executions", {"skill_id": skill["id"], "pace": "realtime", **TOUCHDOWN}, 202)
    wait_for(lambda: stack.execution(created["id"])["telemetry_samples"] > 500, 30, "the run to start")
    stack.post(f"/executions/{created['id']}/pause", {}, 202)
    view = stack.finished(created["id"], timeout_s=60)
    assert view["status"] == "aborted" and "job budget" in view["error"], view
    assert abs(view["metrics"]["steps"] - BUDGET_STEPS) <= 1


# --------------------------------------------------------------------------- H4: bounded reads


def test_telemetry_comes_in_pages_of_at_most_the_cap_and_the_client_follows_them(stack, finished):
    """One GET returns at most the cap (a whole 607 000-sample run was 373 MB of JSON and 2.4 GB of API memory per
    GET before), with the next page's cursor in the body and the header; the typed client reads every page."""
    execution_id, steps = finished["id"], finished["metrics"]["steps"]
    assert steps > 2 * PAGE
    first = stack.http.get(f"/executions/{execution_id}/telemetry", params={"limit": 10**6})
    page = first.json()
    assert page["n_samples"] == len(page["t"]) == PAGE and page["stored_samples"] == steps
    assert page["next_cursor"] == PAGE and first.headers["x-next-cursor"] == str(PAGE)
    assert len(first.content) < PAGE * 700
    csv = stack.http.get(f"/executions/{execution_id}/telemetry", params={"format": "csv", "cursor": PAGE})
    assert len(csv.text.splitlines()) == PAGE + 1 and csv.headers["x-next-cursor"] == str(2 * PAGE)

    with Client(stack.url) as client:
        whole = client.telemetry(execution_id)
        assert len(whole) == steps and np.all(np.diff(whole.t) > 0)
        decimated = client.telemetry(execution_id, every=7, t0=1.0)
        later = whole.t[whole.t >= 1.0]
        np.testing.assert_array_equal(decimated.t, later[::7])
    last = stack.http.get(f"/executions/{execution_id}/telemetry", params={"cursor": steps - 5}).json()
    assert last["n_samples"] == 5 and last["next_cursor"] is None


# --------------------------------------------------------------------------- H5: what is stored can be read back


def _steps_of_5e_324(n: int = 60) -> dict:
    return {"t": [k * 5e-324 for k in range(n)], "positions": [[0.5, 0.0, 0.3]] * n,
            "orientations": [[0.0, 0.0, 0.0, 1.0]] * n, "wrenches": [[0.0, 0.0, 5.0, 0.0, 0.0, 0.0]] * n}  # fmt: skip


def test_time_stamps_5e_324_apart_are_422_and_a_row_stored_before_fails_soft(stack, skill):
    """The probe's demonstration is refused at the contract; one the code before stored (201) answers 409 saying
    why, is listed with its problem (the list never 500s for it), and can be deleted."""
    (entry,) = _detail(stack.http.post("/demonstrations", json=_steps_of_5e_324()))
    assert entry["loc"] == ["body", "t"] and "at least 1e-06 s" in entry["msg"]

    store = Store(stack.log_path.parent / "service.db")  # what the code before stored: the step was never checked
    try:
        old = Demonstration.model_construct(**_steps_of_5e_324(), metadata=DemonstrationMetadata())
        stored = store.demonstrations.add(old)
    finally:
        store.close()
    listed = stack.http.get("/demonstrations")
    assert listed.status_code == 200
    rows = {row["id"]: row for row in listed.json()}
    assert rows[stored.id]["summary"] is None and "mean_rate_hz" in rows[stored.id]["problem"]
    assert rows[skill["demonstration_id"]]["problem"] is None
    for response in (
        stack.http.get(f"/demonstrations/{stored.id}"),
        stack.http.get(f"/demonstrations/{stored.id}/telemetry"),
        stack.http.post("/skills", json={"demonstration_id": stored.id}),
    ):
        assert response.status_code == 409 and f"DELETE /demonstrations/{stored.id}" in response.text, response.text
    assert stack.http.delete(f"/demonstrations/{stored.id}").status_code == 204
    assert stack.http.get(f"/demonstrations/{stored.id}").status_code == 404
    assert stored.id not in {row["id"] for row in stack.http.get("/demonstrations").json()}


def test_executions_are_deleted_once_finished_with_their_telemetry(stack, skill, finished):
    created = stack.post("/executions", {"skill_id": skill["id"], "pace": "realtime", **TOUCHDOWN}, 202)
    wait_for(lambda: stack.execution(created["id"])["status"] == "running", 30, "the run to start")
    refused = stack.http.delete(f"/executions/{created['id']}")
    assert refused.status_code == 409 and "abort it" in refused.text
    stack.post(f"/executions/{created['id']}/abort", {}, 202)
    stack.finished(created["id"])
    for execution_id in (created["id"], finished["id"]):
        assert stack.http.delete(f"/executions/{execution_id}").status_code == 204
        assert stack.http.get(f"/executions/{execution_id}").status_code == 404
        assert stack.http.get(f"/executions/{execution_id}/telemetry").status_code == 404
    assert stack.http.get(f"/skills/{skill['id']}").status_code == 200


def test_the_estimate_follows_the_executor_and_the_world_and_the_api_reads_the_workers_budget():
    """The constants the estimate counts with are the executor's and the world's own, its surface window the
    executor's; the API's settings read the variables the workers read."""
    from execution import executor, impacts
    from schemas import job_budget
    from schemas.world import WorldConfig
    from services.settings import ENV_VARS, ServiceSettings
    from skills import job_estimate

    for module, name in (
        (executor, "TARE_HOLD_S"),
        (impacts, "TOUCHDOWN_SPEED_MIN_M_S"),
    ):
        assert getattr(job_estimate, name) == getattr(module, name), name
    assert executor.surface_window_m is job_estimate.surface_window_m
    assert WorldConfig().time_step_s == NOMINAL_TIME_STEP_S
    names = {ENV_VARS["job_max_simulated_s"], ENV_VARS["job_max_steps"]}
    assert names == {job_budget.ENV_JOB_MAX_SIMULATED_S, job_budget.ENV_JOB_MAX_STEPS}
    env = {job_budget.ENV_JOB_MAX_SIMULATED_S: "60", job_budget.ENV_JOB_MAX_STEPS: "5000"}
    assert ServiceSettings.from_env(env).job_budget == job_budget.JobBudget.from_env(env)
    assert ServiceSettings().job_budget == job_budget.JobBudget()


def test_a_speed_of_5e_324_is_a_job_that_never_ends_422_naming_it_not_an_overflow(stack, skill):
    """The probe's 5e-324 m/s approach (and touch-down) speed made the estimate divide to infinity and the API answer
    500: the phase takes forever, the job is refused naming the speed, and a sane request still runs."""
    for field in ("approach_speed_m_s", "touchdown_speed_m_s"):
        response = stack.http.post("/executions", json={"skill_id": skill["id"], field: 5e-324})
        named = {entry["loc"][-1]: entry for entry in _detail(response)}
        entry = named[field]  # (with it, what the longest parts imply is named too)
        assert entry["type"] == "job_budget" and "takes forever" in entry["msg"], entry
        assert "would never end" in entry["msg"], entry["msg"]
    assert stack.http.get("/health").status_code == 200
