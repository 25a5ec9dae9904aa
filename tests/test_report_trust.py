"""Reports bound to a run and a moment (issue 41 item 5 and its bus-side smaller items), on a secured loopback bus of
REAL processes: `contact-skills bus-keys` logins, `contact-skills router` (TLS, users, access control), the sim worker
``worker-1`` and `contact-skills api` (each a child of this module; the API with short watchdog deadlines), and
attackers holding the ``observer`` and ``worker-2`` logins as real Zenoh sessions.

- N2: a status of ``worker-1`` recorded off the bus by the observer and replayed by ``worker-2`` (a put on the status
  key, an answer to the API's status query) does not move a paused run back to running, does not reopen the run once
  ``worker-1`` was SIGKILLed (not even when ``worker-1`` comes back and the API asks what became of it), and the
  failed run can be deleted.
- N3: ``worker-2`` answers ``info`` as idle with ``executions_run: 0`` and accepts every start without ever reporting:
  the job it took is taken back and completed by ``worker-1``; a job whose worker reports once and goes silent is
  failed with a reason naming it.
- The observer can no longer ask the workers' info (host names, process ids) nor replays; one replay query is
  answered with at most ``REPLAY_MAX_SAMPLES`` samples; ``/health`` does not show a worker busy with a run the store
  shows ended.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import httpx
import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")
pytest.importorskip("cryptography")
from waiting import wait_for  # noqa: E402

from schemas.bus import (  # noqa: E402
    REPLAY_MAX_SAMPLES,
    ExecutionStatus,
    KeyExpressions,
    StartExecution,
    StartReply,
    TelemetryReplay,
    WorkerInfo,
)
from schemas.bus_security import BusSecurity, report_signature  # noqa: E402
from schemas.execution import ExecutionPhase  # noqa: E402
from services.bus import BusClient, BusSettings, open_session  # noqa: E402
from services.local_processes import free_port, spawn_cli, stop_process, wait_for_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
KEYS = KeyExpressions("cskills")
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 1.0}}
FIRST_REPORT_S = 5.0
"""The API's dispatch_report_s here: a real worker's first report comes within a second even on a loaded machine."""
SILENCE_S = 10.0
"""The API's run_silence_s here: a real worker reports at least every HEARTBEAT_S (2 s)."""
WAIT_S = 120.0
"""How long an outcome is waited for (generous: a loaded machine runs 3x slower)."""


def _env_file(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines() if "=" in line)


class Stack:
    """Keys, router, ``worker-1`` and the API as child processes; attackers' sessions on demand."""

    def __init__(self, folder: Path) -> None:
        self.folder, self.keys = folder, folder / "keys"
        self.endpoint = f"tls/127.0.0.1:{free_port()}"
        self.port = free_port()
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{self.port}", timeout=60)
        self.processes: dict[str, subprocess.Popen] = {}
        made = subprocess.run(
            [sys.executable, "-m", "cli.main", "bus-keys", str(self.keys), "--host", "127.0.0.1", "--workers", "2",
             "--endpoint", self.endpoint], cwd=REPO, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert made.returncode == 0, made.stderr

    def start(self) -> None:
        self.processes["router"] = spawn_cli(
            ["router", "--listen", self.endpoint, "--users", str(self.keys / "users.txt"), "--tls-cert",
             str(self.keys / "router.pem"), "--tls-key", str(self.keys / "router.key")], self.folder / "router.log",
            cwd=REPO,
        )  # fmt: skip
        wait_for_port(int(self.endpoint.rsplit(":", 1)[1]), 60)
        self.start_worker()
        watchdog = {"CONTACT_SKILLS_DISPATCH_REPORT_S": str(FIRST_REPORT_S), "CONTACT_SKILLS_RUN_SILENCE_S":
                    str(SILENCE_S), "CONTACT_SKILLS_LEARN_PROCESSES": "1"}  # fmt: skip
        self.processes["api"] = spawn_cli(
            ["api", "--port", str(self.port), "--db", str(self.folder / "api.db")], self.api_log, cwd=REPO,
            env={**_env_file(self.keys / "api.env"), **watchdog},
        )  # fmt: skip
        wait_for(lambda: self.workers() == {"worker-1": "idle"}, WAIT_S, "the API with worker-1 idle")

    @property
    def api_log(self) -> Path:
        return self.folder / "api.log"

    def start_worker(self) -> None:
        login = _env_file(self.keys / "worker-1.env")
        self.processes["worker"] = spawn_cli(["worker"], self.folder / "worker-1.log", cwd=REPO, env=login)

    def kill_worker(self) -> None:
        self.processes["worker"].kill()
        self.processes["worker"].wait()

    def session(self, user: str):  # -> zenoh.Session
        env = _env_file(self.keys / f"{user}.env")
        security = BusSecurity(user=user, password=env["CONTACT_SKILLS_ZENOH_PASSWORD"],
                               tls_ca=env["CONTACT_SKILLS_ZENOH_TLS_CA"])  # fmt: skip
        return open_session("client", connect=[self.endpoint], security=security, wait_s=30)

    def workers(self) -> dict[str, str]:
        """worker id -> activity, as /health shows them."""
        assert self.processes["api"].poll() is None, self.api_log.read_text()[-3000:]
        return {w["worker_id"]: w["activity"] for w in self.http.get("/health").json()["workers"]}

    def post(self, path: str, body: dict | None, expect: int) -> dict:
        response = self.http.post(path, json=body)
        assert response.status_code == expect, response.text
        return response.json()

    def view(self, execution_id: str) -> dict:
        return self.http.get(f"/executions/{execution_id}").json()

    def reaches(self, execution_id: str, *statuses: str) -> dict:
        return wait_for(lambda: (lambda v: v if v["status"] in statuses else None)(self.view(execution_id)), WAIT_S,
                        f"execution {execution_id} {' or '.join(statuses)}")  # fmt: skip

    def logged(self, text: str) -> bool:
        return text in self.api_log.read_text()

    def run(self, pace: str = "realtime") -> str:
        return self.post("/executions", {"skill_id": self.skill_id, "pace": pace}, 202)["id"]

    def held(self) -> str:
        """A real-time run on worker-1, paused: worker-1 stays busy until it is aborted."""
        execution_id = self.run()
        self.reaches(execution_id, "running")
        self.post(f"/executions/{execution_id}/pause", None, 202)
        self.reaches(execution_id, "paused")
        return execution_id

    def close(self) -> None:
        self.http.close()
        for name in ("api", "worker", "router"):
            if name in self.processes:
                stop_process(self.processes[name])


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    stack = Stack(tmp_path_factory.mktemp("report-trust"))
    try:
        stack.start()
        demonstration = stack.post("/demonstrations/record", RECORD, 201)
        stack.skill_id = stack.post("/skills", {"demonstration_id": demonstration["id"], "skill_type": "slide"}, 201)[
            "id"
        ]
        yield stack
    finally:
        stack.close()


class Recording:
    """The observer's recording of every status on the bus: (status, payload, signature)."""

    def __init__(self, session) -> None:
        self.lock = threading.Lock()
        self.statuses: list[tuple[ExecutionStatus, bytes, bytes | None]] = []
        self.subscriber = session.declare_subscriber(KEYS.status("*"), self._on)

    def _on(self, sample) -> None:
        payload = sample.payload.to_bytes()
        signature = None if sample.attachment is None else sample.attachment.to_bytes()
        with self.lock:
            self.statuses.append((ExecutionStatus.model_validate_json(payload), payload, signature))

    def running(self, execution_id: str) -> tuple[ExecutionStatus, bytes, bytes | None] | None:
        """A recorded status of ``execution_id`` in a phase past pending, not paused, not final."""
        with self.lock:
            return next((s for s in self.statuses if s[0].execution_id == execution_id and not s[0].paused
                         and not s[0].final and s[0].phase is not ExecutionPhase.pending), None)  # fmt: skip


def test_a_replayed_status_moves_no_run_back_and_reopens_none(stack):
    """N2 of issue 41: the API reopened a failed run as running with no worker when a second worker login replayed
    a recorded ``approach`` status; abort (202, no effect) and DELETE (409) could not end it until an API restart."""
    observer, attacker = stack.session("observer"), stack.session("worker-2")
    try:
        recording = Recording(observer)
        run = stack.run()
        recorded = wait_for(lambda: recording.running(run), WAIT_S, "a running status of worker-1 recorded")
        status, payload, signature = recorded
        assert status.worker_id == "worker-1" and signature is not None and status.attempt
        stack.post(f"/executions/{run}/pause", None, 202)
        stack.reaches(run, "paused")

        attacker.put(KEYS.status(run), payload, attachment=signature)  # the run is paused: a running status is old
        wait_for(lambda: stack.logged(f"status {status.seq} of {run} from worker-1 ignored"), WAIT_S, "the replay")
        assert stack.view(run)["status"] == "paused"

        stack.kill_worker()
        failed = stack.reaches(run, "failed")
        assert "lost" in failed["error"]
        answering = attacker.declare_queryable(KEYS.status("*"), lambda query: query.reply(
            KEYS.status(run), payload, attachment=signature))  # fmt: skip
        attacker.put(KEYS.status(run), payload, attachment=signature)
        stack.start_worker()  # worker-1 back: the API asks what became of the run failed for its loss
        wait_for(lambda: stack.logged(f"status of {run} naming worker-1 not signed with this query's challenge"),
                 WAIT_S, "the API to ask worker-1 about the run and refuse the recorded answer")  # fmt: skip
        wait_for(lambda: stack.workers().get("worker-1") == "idle", WAIT_S, "worker-1 back, idle")
        after = stack.view(run)
        assert (after["status"], after["error"]) == ("failed", failed["error"])
        assert stack.http.post(f"/executions/{run}/abort").status_code == 409  # it has ended: nothing to abort
        assert stack.http.delete(f"/executions/{run}").status_code == 204
        answering.undeclare()
    finally:
        attacker.close()
        observer.close()


class SilentWorker:
    """``worker-2`` as a real bus participant that answers ``info`` as idle with ``executions_run: 0`` and accepts
    every start; it never reports, or (``reports_once``) sends one signed status and then nothing."""

    def __init__(self, stack: Stack, reports_once: bool = False) -> None:
        self.session = stack.session("worker-2")
        self.reports_once = reports_once
        self.starts: list[str] = []
        idle = WorkerInfo(worker_id="worker-2", busy=False, activity="idle", executions_run=0).model_dump_json()
        self.declared = [  # kept: a token dropped is undeclared
            self.session.declare_queryable(KEYS.info("worker-2"), lambda q: q.reply(KEYS.info("worker-2"), idle)),
            self.session.declare_queryable(KEYS.start("worker-2"), self._on_start),
            self.session.liveliness().declare_token(KEYS.worker("worker-2")),
        ]

    def _on_start(self, query) -> None:
        start = StartExecution.model_validate_json(query.payload.to_bytes())
        self.starts.append(start.execution_id)
        reply = StartReply(accepted=True, code="accepted", worker_id="worker-2", execution_id=start.execution_id)
        query.reply(KEYS.start("worker-2"), reply.model_dump_json())
        if self.reports_once:
            status = ExecutionStatus(execution_id=start.execution_id, worker_id="worker-2", phase="pending",
                                     attempt=start.attempt, message="accepted").model_dump_json().encode()  # fmt: skip
            secret = query.attachment.to_bytes()
            self.session.put(KEYS.status(start.execution_id), status, attachment=report_signature(secret, status))

    def close(self) -> None:
        self.session.close()


def test_a_worker_that_takes_a_job_and_never_reports_loses_it_to_one_that_does(stack):
    """N3 of issue 41: a worker login answering ``info`` as idle with ``executions_run: 0`` won every dispatch and
    held the jobs ``running`` without a report. Now it gets a job only while the real worker is busy, loses it after
    ``dispatch_report_s``, and the real worker completes it."""
    hold = stack.held()
    silent = SilentWorker(stack)
    try:
        wait_for(lambda: stack.workers() == {"worker-1": "executing", "worker-2": "idle"}, WAIT_S, "worker-2 seen")
        job = stack.run(pace="fast")
        wait_for(lambda: job in silent.starts, WAIT_S, "the job handed to the silent worker (the only free one)")
        stack.post(f"/executions/{hold}/abort", None, 202)
        stack.reaches(hold, "aborted")
        done = stack.reaches(job, "done", "failed", "aborted")
        assert (done["status"], done["worker_id"]) == ("done", "worker-1"), done
        assert stack.logged(f"execution {job} back in the queue: worker worker-2 accepted it and sent no report")
        assert 1 <= silent.starts.count(job) < 3  # taken back every time; worker-1 preferred once it was free
    finally:
        silent.close()


def test_a_job_whose_worker_goes_silent_mid_run_is_failed_naming_it(stack):
    hold = stack.held()  # worker-1 busy: worker-2, penalized for the job it let time out, is the only free one
    silent = SilentWorker(stack, reports_once=True)
    try:
        wait_for(lambda: "worker-2" in stack.workers(), WAIT_S, "worker-2 seen")
        job = stack.run(pace="fast")
        failed = stack.reaches(job, "failed", "done", "aborted")
        assert failed["status"] == "failed" and failed["worker_id"] == "worker-2", failed
        assert failed["error"].startswith("worker worker-2 sent no report for") and "mid-run" in failed["error"]
        assert stack.view(hold)["status"] == "paused"  # worker-1's paused run reports (heartbeats): not failed
    finally:
        silent.close()
        stack.post(f"/executions/{hold}/abort", None, 202)
        stack.reaches(hold, "aborted")


def test_an_observer_asks_no_worker_info_nor_replays_and_the_api_still_does(stack):
    """The observer login saw every worker's host name and process id, and its replay queries pulled 454 MB from
    a worker: it can ask neither any more; the API still gets both."""
    observer = stack.session("observer")
    run = stack.run(pace="fast")
    ended = stack.reaches(run, "done")
    report_key, attempt = _api_records(stack, run)
    api = BusClient(  # the API's login and report key: the reports of the API's runs verify
        BusSettings(endpoints=[stack.endpoint], security=_login(stack, "api"), connect_timeout_s=30,
                    report_key=report_key),
        lambda status: None, lambda batch: None, lambda worker_id: None,
    )  # fmt: skip
    try:
        ask = TelemetryReplay(execution_id=run, start=0, stop=100).model_dump_json()
        assert [r for r in observer.get(KEYS.info("*"), timeout=5) if r.ok is not None] == []
        assert [r for r in observer.get(KEYS.replay("worker-1"), payload=ask, timeout=5) if r.ok is not None] == []
        [info] = api.workers()
        assert info.worker_id == "worker-1" and info.hostname and info.pid > 0
        api.adopt(run, "worker-1", attempt)
        assert sum(len(b.t) for b in api.telemetry_replay("worker-1", run, 0, 100)) == 100
        assert ended["telemetry_samples"] > 100
    finally:
        api.close()
        observer.close()


def _login(stack: Stack, user: str) -> BusSecurity:
    env = _env_file(stack.keys / f"{user}.env")
    return BusSecurity(user=user, password=env["CONTACT_SKILLS_ZENOH_PASSWORD"],
                       tls_ca=env["CONTACT_SKILLS_ZENOH_TLS_CA"])  # fmt: skip


def _api_records(stack: Stack, execution_id: str) -> tuple[bytes, str]:
    """The API's report key and the dispatch attempt it stored for ``execution_id`` (from its database)."""
    from services.bus_events import REPORT_KEY_NAME
    from services.store import Store

    store = Store(stack.folder / "api.db")
    try:
        return store.service_key(REPORT_KEY_NAME), store.executions.get(execution_id).attempt
    finally:
        store.close()


class _Bytes(bytes):
    def to_bytes(self) -> bytes:
        return bytes(self)


class _Query:
    """What a Zenoh query gives a queryable: its payload, and where the replies go."""

    def __init__(self, payload: str) -> None:
        self.payload = _Bytes(payload.encode())
        self.replies: list[bytes] = []
        self.errors: list[str] = []

    def reply(self, key: str, data: bytes, attachment: bytes | None = None) -> None:
        self.replies.append(data)

    def reply_err(self, message: str) -> None:
        self.errors.append(message)


def test_one_replay_query_is_answered_with_at_most_replay_max_samples():
    """A worker's replay queryable answers one query with the first REPLAY_MAX_SAMPLES samples asked, whatever range
    it asks: the API asks a longer gap in parts (`BusClient.telemetry_replay`)."""
    from execution.telemetry import Telemetry
    from schemas.execution import TELEMETRY_WIDTH, TelemetryBatch
    from sim_worker.zenoh_worker import Worker

    worker = Worker(worker_id="w-replay")
    rows = np.zeros((REPLAY_MAX_SAMPLES + 5000, TELEMETRY_WIDTH))
    rows[:, 0] = np.arange(len(rows)) * 1e-3
    worker.archive.append("ex-long", Telemetry(rows))
    query = _Query(TelemetryReplay(execution_id="ex-long", start=100, stop=len(rows)).model_dump_json())
    worker._on_replay(query)
    batches = [TelemetryBatch.model_validate_json(reply) for reply in query.replies]
    assert query.errors == [] and sum(len(b.t) for b in batches) == REPLAY_MAX_SAMPLES
    assert batches[0].first_sample == 100 and batches[-1].first_sample + len(batches[-1].t) == 100 + REPLAY_MAX_SAMPLES


def test_health_does_not_show_a_worker_busy_with_a_run_the_store_shows_ended(tmp_path):
    """/health showed a worker busy with a run that had ended 30 minutes before (its last answer, never asked
    again): a run the store shows ended is not shown, and how old the worker's answer is, is."""
    from schemas.api import ExecutionState
    from services.api.routes.health import _summary
    from services.store import Store

    store = Store(tmp_path / "health.db")
    try:
        row = store.executions.add({"pace": "fast"}, None)
        store.executions.mark_started(row.id, "w-1")
        busy = WorkerInfo(worker_id="w-1", busy=True, activity="executing", execution_id=row.id)
        shown = _summary(busy, store, info_age_s=1800.0, heard_s_ago=1799.0)
        assert (shown.busy, shown.activity, shown.execution_id) == (True, "executing", row.id)
        store.executions.update(row.id, ExecutionState.done, ExecutionPhase.done)
        shown = _summary(busy, store, info_age_s=1800.0, heard_s_ago=1799.0)
        assert (shown.busy, shown.activity, shown.execution_id) == (False, "idle", None)
        assert (shown.info_age_s, shown.heard_s_ago) == (1800.0, 1799.0)
        unknown = _summary(WorkerInfo(worker_id="w-2", busy=True, activity="unknown"), store, 0.1, None)
        assert unknown.info_age_s is None and unknown.activity == "unknown"
    finally:
        store.close()
