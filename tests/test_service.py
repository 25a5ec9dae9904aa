"""The service with REAL processes: `contact-skills up --workers 2` (embedded Zenoh router, the API, two sim
workers) on free loopback ports with a temporary SQLite database.

record -> learn -> execute, telemetry seen by an independent Zenoh subscriber, metrics stored and served; an
execution with telemetry 'none' that sends nothing and ends with the same metrics; two executions at once on two
workers; a worker killed mid-execution; the API killed (-9) and restarted by `up` with
every stored object kept; `up` stopped by SIGTERM with every child gone and exit code 0.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

zenoh = pytest.importorskip("zenoh")

from waiting import wait_for  # noqa: E402

from schemas.bus_security import ENV_PASSWORD, ENV_USER, BusSecurity  # noqa: E402
from services.bus import open_session  # noqa: E402
from services.bus_keys import local_logins_folder, read_env_file  # noqa: E402
from services.local_processes import free_port as _free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 2.0}}
FINAL = ("done", "aborted", "failed")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie child of `up` that was not reaped yet counts as gone
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


class Stack:
    """`contact-skills up` with ``workers`` workers in ``tmp``, its children given ``env`` on top of this process's."""

    def __init__(self, tmp: Path, workers: int = 2, env: dict[str, str] | None = None) -> None:
        self.port, self.zenoh_port = _free_port(), _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.endpoint = f"tcp/127.0.0.1:{self.zenoh_port}"
        self.log_path = tmp / "up.log"
        self.log = self.log_path.open("w")
        environment = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
        for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "CONTACT_SKILLS_TOKEN",
                     "CONTACT_SKILLS_TOKEN_READS"):  # fmt: skip
            environment.pop(name, None)  # `up` sets the thread limits of its children itself
        argv = ["up", "--workers", str(workers), "--port", str(self.port), "--zenoh-port", str(self.zenoh_port),
                "--db", str(tmp / "service.db")]  # fmt: skip
        self.process = subprocess.Popen(
            [sys.executable, "-m", "cli.main", *argv],
            cwd=tmp,
            env=environment,
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )
        self.http = httpx.Client(base_url=self.url, timeout=60)

    def health(self) -> dict | None:
        if self.process.poll() is not None:
            raise AssertionError(f"`up` exited ({self.process.returncode}):\n{self.log_path.read_text()[-4000:]}")
        try:
            return self.http.get("/health", timeout=5).json()
        except httpx.HTTPError:
            return None

    def api_pid(self) -> int:
        """The process id of the API `up` started last (from its log: /health shows none without a token)."""
        return int(re.findall(r"started api \(pid (\d+)\)", self.log_path.read_text())[-1])

    def worker_pids(self) -> dict[str, int]:
        """The process id of each worker `up` started last, by worker id (its login, named as its child; from the
        log: the open /health shows no process ids)."""
        started = re.findall(r"started (worker-\d+) \(pid (\d+)\)", self.log_path.read_text())
        return {name: int(pid) for name, pid in started}

    def session(self, login: str = "observer"):  # -> zenoh.Session
        """A Zenoh session on this stack's bus as one of the logins `up` made (``observer``: read only)."""
        values = read_env_file(local_logins_folder(self.zenoh_port) / f"{login}.env")
        security = BusSecurity(user=values[ENV_USER], password=values[ENV_PASSWORD])
        return open_session("client", connect=[self.endpoint], security=security, wait_s=10)

    def pids(self) -> list[int]:
        """The API's and the connected workers' process ids."""
        pids = self.worker_pids()
        return [self.api_pid(), *(pids[w["worker_id"]] for w in self.health()["workers"])]

    def workers(self, n: int = 2, timeout_s: float = 90) -> list[dict]:
        def ready():
            health = self.health()
            return health["workers"] if health and len(health["workers"]) >= n else None

        return wait_for(ready, timeout_s, f"{n} workers")

    def post(self, path: str, body: dict, expect: int) -> dict:
        response = self.http.post(path, json=body)
        assert response.status_code == expect, response.text
        return response.json()

    def execution(self, execution_id: str) -> dict:
        response = self.http.get(f"/executions/{execution_id}")
        assert response.status_code == 200, response.text
        return response.json()

    def finished(self, execution_id: str, timeout_s: float = 60) -> dict:
        return wait_for(
            lambda: (lambda v: v if v["status"] in FINAL else None)(self.execution(execution_id)),
            timeout_s,
            f"execution {execution_id} to finish",
        )

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(40)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.http.close()
        self.log.close()
        return self.process.returncode


def running_stack(tmp: Path, workers: int = 2, env: dict[str, str] | None = None) -> Iterator[Stack]:
    """`contact-skills up --workers N` in ``tmp`` (``env``: for its children) with every worker connected; stopped
    afterwards."""
    stack = Stack(tmp, workers, env)
    try:
        stack.workers(workers)
        yield stack
    finally:
        stack.stop()


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("service"))


@pytest.fixture(scope="module")
def skill_id(stack) -> str:
    demo = stack.post("/demonstrations/record", RECORD, 201)
    assert demo["source"] == "teacher:slide_flat" and demo["extra"]["ground_truth"]["scenario"] == "slide_flat"
    skill = stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "auto"}, 201)
    assert skill["skill"]["skill_type"] == "slide"
    return skill["id"]


class Watcher:
    """An independent Zenoh session (not the API's) counting every execution's telemetry samples and keeping the
    phases of its statuses, per execution."""

    def __init__(self, endpoint: str) -> None:
        self.samples: dict[str, int] = {}
        self.phases: dict[str, list[str]] = {}
        self._lock = threading.Lock()
        self.session = open_session("client", connect=[endpoint], wait_s=10)  # as this user's `up`'s observer
        self._subscribers = [
            self.session.declare_subscriber("cskills/exec/*/telemetry", self._on_telemetry),
            self.session.declare_subscriber("cskills/exec/*/status", self._on_status),
        ]
        time.sleep(0.5)  # the subscriptions reach the router

    def _on_telemetry(self, sample) -> None:
        batch = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.samples[batch["execution_id"]] = self.samples.get(batch["execution_id"], 0) + len(batch["t"])

    def _on_status(self, sample) -> None:
        status = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.phases.setdefault(status["execution_id"], []).append(status["phase"])

    def close(self) -> None:
        """After what is still in flight has arrived."""
        time.sleep(0.5)
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self.session.close()


def test_record_learn_execute_with_an_independent_subscriber(stack, skill_id):
    watcher = Watcher(stack.endpoint)
    try:
        body = {"skill_id": skill_id, "environment": {"unknown_offset": [0.0, 0.0, 0.01]}, "pace": "fast"}
        created = stack.post("/executions", body, 202)
        assert created["telemetry_key"] == f"cskills/exec/{created['id']}/telemetry"
        view = stack.finished(created["id"])
    finally:
        watcher.close()
    received, statuses = watcher.samples, watcher.phases[created["id"]]

    assert view["status"] == "done", view
    metrics = view["metrics"]
    assert metrics["phase"] == "done" and metrics["contact_ratio"] > 0.9 and metrics["force_rms_error_n"] < 5
    assert metrics["path_rms_m"] is not None  # the stored demonstration was sent along
    assert received[created["id"]] == metrics["steps"] == view["telemetry_samples"]
    assert statuses[-1] == "done" and "contact" in statuses
    telemetry = stack.http.get(f"/executions/{created['id']}/telemetry", params={"every": 10}).json()
    assert telemetry["stored_samples"] == metrics["steps"] and telemetry["n_samples"] == -(-metrics["steps"] // 10)
    assert "contact" in telemetry["phase"] and len(telemetry["wrench_cf"][0]) == 6


def test_an_execution_without_telemetry_sends_none_and_ends_with_the_same_metrics(stack, skill_id):
    """telemetry 'none': not one sample on the bus (an independent subscriber), none stored, none kept by the worker
    (its replay queryable has nothing), GET .../telemetry a 409 saying why, and no missing samples reported; the
    statuses still follow the phases, and every metric equals that of the same request streamed on the other worker
    (a deterministic simulation; all but the wall-clock real-time factor)."""
    from schemas.bus import TelemetryReplay

    stack.workers(2)
    watcher = Watcher(stack.endpoint)
    try:
        body = {"skill_id": skill_id, "environment": {"unknown_offset": [0.0, 0.0, 0.01], "noise_seed": 4}}
        streamed = stack.post("/executions", body, 202)
        silent = stack.post("/executions", {**body, "telemetry": "none"}, 202)
        assert streamed["worker_id"] != silent["worker_id"]  # at once, on the two workers
        streamed, silent = stack.finished(streamed["id"]), stack.finished(silent["id"])
        steps = silent["metrics"]["steps"]
        ask = TelemetryReplay(execution_id=silent["id"], start=0, stop=steps).model_dump_json()
        api_login = stack.session("api")  # replays are the API's alone (the observer may not ask them)
        try:
            replies = list(api_login.get(f"cskills/exec/{silent['worker_id']}/replay", payload=ask, timeout=10))
        finally:
            api_login.close()
    finally:
        watcher.close()
    samples, phases = watcher.samples, watcher.phases

    assert silent["status"] == streamed["status"] == "done", (silent, streamed)
    assert silent["request"]["telemetry"] == "none" and streamed["request"]["telemetry"] == "stream"
    wall_clock = "real_time_factor"
    assert {k: v for k, v in silent["metrics"].items() if k != wall_clock} == {
        k: v for k, v in streamed["metrics"].items() if k != wall_clock
    }
    assert samples.get(silent["id"], 0) == 0 and samples[streamed["id"]] == streamed["metrics"]["steps"]
    stored = ("telemetry_samples", "telemetry_batches", "telemetry_missing_samples")
    assert [silent[k] for k in stored] == [0, 0, None]
    assert (streamed["telemetry_samples"], streamed["telemetry_missing_samples"]) == (steps, 0)
    assert "contact" in phases[silent["id"]] and phases[silent["id"]][-1] == "done"
    assert [r.ok for r in replies] == [None] and "keeps no telemetry" in replies[0].err.payload.to_string()
    for params in ({}, {"format": "csv"}):
        response = stack.http.get(f"/executions/{silent['id']}/telemetry", params=params)
        assert response.status_code == 409, response.text
        assert "telemetry 'none'" in response.json()["detail"] and silent["id"] in response.json()["detail"]
    assert stack.http.get(f"/executions/{streamed['id']}/telemetry").json()["stored_samples"] == steps


def test_two_executions_run_at_once_on_two_workers(stack, skill_id):
    stack.workers(2)
    first = stack.post("/executions", {"skill_id": skill_id}, 202)
    second = stack.post("/executions", {"skill_id": skill_id}, 202)
    assert first["worker_id"] != second["worker_id"]
    views = [stack.finished(first["id"]), stack.finished(second["id"])]
    assert [v["status"] for v in views] == ["done", "done"]
    assert views[0]["updated"] > views[1]["created"]  # they overlapped in time
    third = stack.http.get("/executions").json()
    assert {first["id"], second["id"]} <= {v["id"] for v in third}


def test_a_skill_learned_from_an_uploaded_real_recording_executes(stack):
    """POST /executions for a skill learned from a CSV (KU Leuven, another lab's frame): the worker measures its work
    piece from the stored recording and places it in reach; a skill too large to place is refused with 422 on
    environment.placement."""
    stack.workers(2)
    path = REPO / "data" / "kuleuven_contour" / "contour_a_2.csv"
    options = {"quaternion_order": "wxyz", "wrench": "measured-on-tool", "wrench_frame": "tool", "tare": "false"}
    with path.open("rb") as f:
        response = stack.http.post("/demonstrations/csv", files={"file": (path.name, f, "text/csv")}, data=options)
    assert response.status_code == 201, response.text
    learned = stack.post("/skills", {"demonstration_id": response.json()["id"], "skill_type": "auto"}, 201)
    created = stack.post("/executions", {"skill_id": learned["id"]}, 202)
    view = stack.finished(created["id"], timeout_s=120)
    metrics = view["metrics"]
    assert view["status"] == "done", view
    assert metrics["work_piece"] == "measured" and metrics["placement"]["translation_m"] != [0.0, 0.0, 0.0]
    assert metrics["force_rms_error_pct"] <= 10.0 and metrics["contact_ratio"] >= 0.95, metrics
    assert metrics["true_force_rms_error_pct"] is not None and metrics["touchdown_peak_n"] > 0

    skill = learned["skill"]
    for segment in skill["segments"]:  # the same skill read in the wrong unit: 8x too large for any placement
        for dmp in (segment["position_dmp"],):
            dmp["start"] = [8 * v for v in dmp["start"]]
            dmp["goal"] = [8 * v for v in dmp["goal"]]
            dmp["weights"] = [[8 * v for v in row] for row in dmp["weights"]]
        frames = segment["compliant_frames"]
        frames["origins"] = [[8 * v for v in o] for o in frames["origins"]]
    response = stack.http.post("/executions", json={"skill": skill})
    assert response.status_code == 422, response.text
    assert response.json()["detail"][0]["loc"] == ["body", "environment", "placement"]
    assert "reach" in response.text


def test_killing_a_worker_mid_execution_fails_it_and_the_api_keeps_serving(stack, skill_id):
    stack.workers(2)
    workers = stack.worker_pids()
    created = stack.post("/executions", {"skill_id": skill_id, "pace": "realtime"}, 202)
    wait_for(lambda: stack.execution(created["id"])["telemetry_samples"] > 300, 30, "the execution to run")
    os.kill(workers[created["worker_id"]], signal.SIGKILL)
    view = stack.finished(created["id"], timeout_s=20)
    assert view["status"] == "failed" and created["worker_id"] in view["error"] and "lost" in view["error"]
    health = stack.health()
    assert health is not None and health["status"] == "ok"
    assert created["worker_id"] not in {w["worker_id"] for w in health["workers"]}
    assert stack.http.get(f"/skills/{skill_id}").status_code == 200
    dead = workers[created["worker_id"]]
    wait_for(lambda: stack.worker_pids()[created["worker_id"]] != dead, 30, "`up` to restart the dead worker")
    assert created["worker_id"] in {w["worker_id"] for w in stack.workers(2)}  # back, under its own login


def test_api_killed_and_restarted_keeps_every_stored_object(stack, skill_id):
    stack.workers(2)
    before = {path: stack.http.get(path).json() for path in ("/demonstrations", "/skills", "/executions?limit=1000")}
    running = stack.post("/executions", {"skill_id": skill_id, "pace": "realtime"}, 202)
    wait_for(lambda: stack.execution(running["id"])["telemetry_samples"] > 200, 30, "the execution to run")
    api_pid = stack.api_pid()
    os.kill(api_pid, signal.SIGKILL)  # `up` restarts it on the same database
    wait_for(lambda: stack.health() and stack.api_pid() != api_pid, 60, "the API to restart")

    after = {path: stack.http.get(path).json() for path in before}
    assert after["/demonstrations"] == before["/demonstrations"]
    assert after["/skills"] == before["/skills"]
    old_executions = {v["id"]: v for v in before["/executions?limit=1000"]}
    new_executions = {v["id"]: v for v in after["/executions?limit=1000"]}
    assert set(old_executions) | {running["id"]} == set(new_executions)
    for execution_id, view in old_executions.items():
        kept = new_executions[execution_id]
        assert (kept["status"], kept["metrics"], kept["telemetry_samples"]) == (
            view["status"], view["metrics"], view["telemetry_samples"]
        )  # fmt: skip
    for demo in before["/demonstrations"]:
        assert stack.http.get(f"/demonstrations/{demo['id']}").status_code == 200
    # The execution outlived the API: its worker still reports it, so it was kept, and its final status arrived.
    view = stack.finished(running["id"], timeout_s=60)
    assert view["status"] == "done" and view["metrics"]["steps"] > 0, view


def _started(stack: Stack, execution_id: str) -> dict:
    return wait_for(
        lambda: (lambda v: v if v["worker_id"] is not None else None)(stack.execution(execution_id)), 30, "a worker"
    )


def test_executions_queue_by_priority_when_every_worker_is_busy(stack, skill_id):
    stack.workers(2)
    busy = [stack.post("/executions", {"skill_id": skill_id, "pace": "realtime"}, 202) for _ in range(2)]
    assert [b["status"] for b in busy] == ["running", "running"] and len({b["worker_id"] for b in busy}) == 2
    low = stack.post("/executions", {"skill_id": skill_id}, 202)
    dropped = stack.post("/executions", {"skill_id": skill_id}, 202)
    # realtime: it holds its worker until aborted, so that the next worker to free up is the other one
    high = stack.post("/executions", {"skill_id": skill_id, "priority": 5, "pace": "realtime"}, 202)
    assert (low["status"], low["worker_id"], low["queue_position"]) == ("queued", None, 0)
    assert dropped["queue_position"] == 1 and high["queue_position"] == 0
    assert [stack.execution(e["id"])["queue_position"] for e in (high, low, dropped)] == [0, 1, 2]
    assert stack.http.post(f"/executions/{low['id']}/pause").status_code == 409
    cancelled = stack.post(f"/executions/{dropped['id']}/abort", {}, 202)
    assert cancelled["sent_to"] == "queue"
    view = stack.execution(dropped["id"])
    assert (view["status"], view["error"], view["queue_position"]) == ("aborted", "cancelled while queued", None)

    stack.post(f"/executions/{busy[0]['id']}/abort", {}, 202)  # one worker frees: the higher priority goes first
    first = _started(stack, high["id"])
    assert first["worker_id"] == busy[0]["worker_id"]
    assert stack.execution(low["id"])["status"] == "queued"
    stack.post(f"/executions/{busy[1]['id']}/abort", {}, 202)  # the other worker takes the next one
    assert _started(stack, low["id"])["worker_id"] == busy[1]["worker_id"]
    assert stack.finished(low["id"])["status"] == "done"
    stack.post(f"/executions/{high['id']}/abort", {}, 202)
    assert stack.finished(high["id"])["status"] == "aborted"
    assert stack.health()["queued_executions"] == 0


def test_the_queue_survives_an_api_restart(stack, skill_id):
    stack.workers(2)
    busy = [stack.post("/executions", {"skill_id": skill_id, "pace": "realtime"}, 202) for _ in range(2)]
    waiting = stack.post("/executions", {"skill_id": skill_id}, 202)
    assert waiting["status"] == "queued"
    api_pid = stack.api_pid()
    os.kill(api_pid, signal.SIGKILL)
    wait_for(lambda: stack.health() and stack.api_pid() != api_pid, 60, "the API to restart")
    # still there, in the database (starting: the new API's dispatcher is offering it to the busy workers)
    assert stack.execution(waiting["id"])["status"] in ("queued", "starting", "running")
    for execution in busy:
        stack.post(f"/executions/{execution['id']}/abort", {}, 202)
    assert stack.finished(waiting["id"], timeout_s=60)["status"] == "done"


def test_up_limits_the_blas_threads_of_every_child(stack):
    for pid in stack.pids():
        environ = dict(
            item.split("=", 1) for item in Path(f"/proc/{pid}/environ").read_text().split("\0") if "=" in item
        )
        assert {environ.get(v) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")} == {"1"}


def test_up_stops_cleanly_on_sigterm(stack):
    pids = stack.pids()
    assert stack.stop() == 0, stack.log_path.read_text()[-3000:]
    wait_for(lambda: not any(_alive(pid) for pid in pids), 10, "every child to exit")
    log = stack.log_path.read_text()
    assert "stopped (exit 0)" in log and "api | " in log and "worker-1 | " in log
