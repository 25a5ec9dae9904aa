"""A long run at full pace loses nothing (issue 25 M1): missing samples, dropped statuses, router link drops.

Run: ``.venv/bin/python benchmarks/bench_long_run.py [--minutes 30]`` (``--smoke``: 12 s of simulated time, nothing
written); writes the ``bench_long_run`` section of docs/BENCHMARKS.md (``--no-write``: only print).

``contact-skills up --workers 1`` (secured bus, temp SQLite) on free loopback ports; a slide is recorded and learned;
one execution at ``pace: fast`` (the worker as fast as it can step) whose guarded approach is slowed
(``approach_speed_m_s``, chosen by bisection on the job estimate, ``skills.job_estimate``) so that its estimate is
``--minutes`` of simulated time at 1 kHz (the estimate is an upper bound: the run is about two thirds of it), the job
budget raised to let it. Meanwhile an independent Zenoh session (the
observer login) counts every status on the bus. Reported, against the truth:

- samples: control steps run (the final metrics), samples stored by the API, ``telemetry_missing_samples``;
- statuses: those on the bus (numbered by ``seq``: none skipped, none repeated), the final one stored by the API;
- the API's log: router link drops, telemetry batches asked again of the worker, database-locked retries, dropped
  inbox batches;
- the wall time, the simulated time, the machine's load average.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_service import running
from benchmarks.report import add_smoke_argument, machine_line, pin_blas_threads, write_section

pin_blas_threads()

import httpx  # noqa: E402

from schemas.bus import FINAL_PHASES  # noqa: E402
from services.local_processes import free_port  # noqa: E402

SECTION = "bench_long_run"
FULL_MINUTES = 30.0
"""The documented run: half an hour of simulated time by the job estimate (an upper bound: 1344 s were run, in
151 s of wall time)."""
SMOKE_MINUTES = 0.2
"""The smoke run: 12 s of simulated time, every step of the long one."""
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 2.0}}
LOG_MARKS = {
    "router link drops": "router link lost",
    "telemetry asked again": "asking the worker again",
    "database-locked retries": "database locked",
    "inbox drops": "bus inbox full",
}
"""What the API's log says when something on the way went wrong (the count of each line)."""


def approach_speed_for(skill: dict, minutes: float) -> float:
    """The slowest ``approach_speed_m_s`` (m/s) whose run the job estimate puts within ``minutes`` of simulated time
    and within the job budget (``schemas.job_budget``, as :func:`raise_budget` set it)."""
    from schemas import ExecutionRequest, Skill
    from schemas.job_budget import JobBudget
    from skills.job_estimate import execution_estimate, taught_time_step_s

    model, budget = Skill.model_validate(skill), JobBudget.from_env(os.environ)
    step = taught_time_step_s(model)

    def too_long(speed: float) -> bool:
        request = ExecutionRequest(skill_id="s", pace="fast", approach_speed_m_s=speed, touchdown_speed_m_s=0.03)
        estimate = execution_estimate(model, request, step)
        return estimate.simulated_s > minutes * 60 or bool(estimate.problems(budget))

    low, high = 1e-5, 0.05  # m/s: slow is long
    for _ in range(40):
        middle = (low * high) ** 0.5
        low, high = (middle, high) if too_long(middle) else (low, middle)
    return high


def raise_budget(minutes: float) -> None:
    """Let a job of ``minutes`` (its estimate: an upper bound) fit the job budget of the stack this process starts
    (``up`` hands the variables to its API and worker): the default budget, 1800 s, caps the slowest approach."""
    from schemas.job_budget import ENV_JOB_MAX_SIMULATED_S, ENV_JOB_MAX_STEPS, JobBudget

    default = JobBudget()
    os.environ[ENV_JOB_MAX_SIMULATED_S] = str(max(default.max_simulated_s, 3 * 60 * minutes))
    os.environ[ENV_JOB_MAX_STEPS] = str(max(default.max_steps, 3 * 60_000 * round(minutes)))


class StatusCounter:
    """An independent Zenoh session (this user's observer login) keeping every status of one execution."""

    def __init__(self, endpoint: str, execution_id_prefix: str = "cskills/exec/*/status") -> None:
        from services.bus import open_session

        self.statuses: list[dict] = []
        self._lock = threading.Lock()
        self.session = open_session("client", connect=[endpoint], wait_s=10)
        self.subscriber = self.session.declare_subscriber(execution_id_prefix, self._on)
        time.sleep(0.5)

    def _on(self, sample) -> None:
        import json

        with self._lock:
            self.statuses.append(json.loads(sample.payload.to_bytes()))

    def of(self, execution_id: str) -> list[dict]:
        with self._lock:
            return [s for s in self.statuses if s["execution_id"] == execution_id]

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()


def logged(log: str, mark: str) -> int:
    """How many times the API logged a line containing ``mark``: each line written, plus those it says it held back
    (``services.log_limits``: a kind of line at most once per 10 s)."""
    lines = [line for line in log.splitlines() if mark in line]
    return len(lines) + sum(int(m[1]) for line in lines if (m := re.search(r"\((\d+) more like this held back", line)))


def long_run(minutes: float, log_dir: Path) -> dict:
    """Run the benchmark once; returns its figures."""
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    argv = ["up", "--workers", "1", "--port", str(port), "--zenoh-port", str(zenoh_port),
            "--db", str(log_dir / "long_run.db")]  # fmt: skip
    log_path = log_dir / "up.log"
    with running(argv, url, workers=1, log_path=log_path), httpx.Client(base_url=url, timeout=120) as http:
        demo = http.post("/demonstrations/record", json=RECORD).json()
        skill = http.post("/skills", json={"demonstration_id": demo["id"], "skill_type": "slide"}).json()
        speed = approach_speed_for(skill["skill"], minutes)
        counter = StatusCounter(f"tcp/127.0.0.1:{zenoh_port}")
        try:
            load_before = os.getloadavg()
            started = time.monotonic()
            body = {"skill_id": skill["id"], "pace": "fast", "approach_speed_m_s": speed, "touchdown_speed_m_s": 0.03}
            created = http.post("/executions", json=body)
            if created.status_code != 202:
                raise RuntimeError(f"POST /executions {body}: {created.status_code} {created.text}")
            execution_id = created.json()["id"]
            while (view := http.get(f"/executions/{execution_id}").json())["status"] not in FINAL_PHASES:
                time.sleep(1.0)
            wall_s = time.monotonic() - started
            load_after = os.getloadavg()
            time.sleep(1.0)  # statuses in flight
            statuses = counter.of(execution_id)
        finally:
            counter.close()
    log = log_path.read_text(errors="replace")
    seqs = [s["seq"] for s in statuses]
    steps = (view["metrics"] or {}).get("steps", 0)
    return {
        "minutes": minutes,
        "approach_speed_m_s": speed,
        "status": view["status"],
        "steps": steps,
        "simulated_s": steps / 1000.0,
        "wall_s": wall_s,
        "stored": view["telemetry_samples"],
        "missing": view["telemetry_missing_samples"],
        "statuses_on_bus": len(statuses),
        "seq_gaps": sorted(set(range(max(seqs, default=-1) + 1)) - set(seqs)),
        "seq_repeats": len(seqs) - len(set(seqs)),
        "final_stored": view["status"] == (statuses[-1]["phase"] if statuses else None),
        "load": (load_before[0], load_after[0]),
        **{name: logged(log, mark) for name, mark in LOG_MARKS.items()},
    }


def report(figures: dict) -> str:
    f = figures
    last = "the last one on the bus" if f["final_stored"] else "NOT the last one on the bus"
    gaps = len(f["seq_gaps"])
    lines = [
        "## A long run at full pace (`benchmarks/bench_long_run.py`)",
        "",
        f"{machine_line()} `contact-skills up --workers 1` (secured bus), one execution at `pace: fast` "
        f"whose guarded approach at {f['approach_speed_m_s']:.3g} m/s the job estimate puts at {f['minutes']:g} min "
        "of simulated time at 1 kHz (an upper bound); an independent Zenoh session counts its statuses. "
        f"`.venv/bin/python benchmarks/bench_long_run.py --minutes {f['minutes']:g}`.",
        "",
        "| figure | value |",
        "| --- | --- |",
        f"| simulated time, control steps | {f['simulated_s']:.0f} s, {f['steps']:,} |",
        f"| wall time (speed-up) | {f['wall_s']:.0f} s ({f['simulated_s'] / max(f['wall_s'], 1e-9):.1f}x real time) |",
        f"| final status stored by the API | {f['status']} ({last}) |",
        f"| samples stored / missing | {f['stored']:,} / {f['missing']:,} |",
        f"| statuses on the bus, seq gaps, repeats | {f['statuses_on_bus']}, {gaps}, {f['seq_repeats']} |",
        *(f"| API log: {name} | {f[name]} |" for name in LOG_MARKS),
        f"| load average (1 min) before, after | {f['load'][0]:.1f}, {f['load'][1]:.1f} |",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=FULL_MINUTES, help="simulated minutes of the run")
    parser.add_argument("--no-write", action="store_true", help="only print the report")
    add_smoke_argument(parser, f"--minutes {SMOKE_MINUTES:g}")
    args = parser.parse_args(argv)
    if args.smoke:
        args.minutes, args.no_write = SMOKE_MINUTES, True
    raise_budget(args.minutes)
    with tempfile.TemporaryDirectory(prefix="bench-long-run-") as tmp:
        figures = long_run(args.minutes, Path(tmp))
    text = report(figures)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)
    ok = figures["status"] == "done" and figures["missing"] == 0 and figures["stored"] == figures["steps"]
    return 0 if ok and figures["final_stored"] and not figures["seq_gaps"] else 1


if __name__ == "__main__":
    sys.exit(main())
