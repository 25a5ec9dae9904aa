"""Sweep throughput: executions per minute of a robustness sweep with 1 and 2 sim workers, for a ~10 s skill, with
the trials' telemetry off (the default) and streamed and stored (``store_telemetry``), and where each trial's time
goes.

Run: ``.venv/bin/python benchmarks/bench_sweeps.py [--trials-per-worker 10] [--no-write] [--smoke]``; writes the
``bench_sweeps`` section of docs/BENCHMARKS.md. Run it when ``uptime`` shows a low load: it prints the 1-minute load
average before and after every run.

For N = 1, 2 and each telemetry choice: ``contact-skills up --workers N`` (real processes on loopback, a temporary
SQLite database); the teacher's ``slide_flat`` demonstration recorded by a worker with a stroke that makes an
execution last about 10 s of simulated time, learned; then ``POST /sweeps`` with ``trials-per-worker x N`` trials of
one controller (``hybrid_cf``) varying the unknown table height by ±5 mm and the friction 0.15-0.3 (every trial
runs the whole skill), polled over REST until done. Measured per run:

- executions per minute = executions / wall time from the submission to the sweep's end (the queue, the
  dispatcher and the bus included);
- the control loop's wall time per execution (each execution's simulated time / its real-time factor, median);
- worker-seconds per execution = wall time x N / executions, and what of it is not the loop (dispatch, world
  set-up, metrics, and the sweep's start and tail while a worker waits for the last trial of the other);
- CPU seconds per execution of the API process and of the workers (``/proc``), which the 2 cores share.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import add_smoke_argument, machine_line, machine_speed, pin_blas_threads, write_section

pin_blas_threads()

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.bench_service import process_cpu_s, running  # noqa: E402
from services.local_processes import free_port  # noqa: E402

SECTION = "bench_sweeps"
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 2.5}}
"""A stroke of 2.5 s: with settling, approach and retreat an execution runs ~10 s of simulated time."""
VARY = {"offset_z_m": {"low": -0.005, "high": 0.005}, "friction": {"low": 0.15, "high": 0.3}}
TARGET_PER_MINUTE = 150.0
"""Issue 14's target for 2 workers on 2 cores."""
POLL_S = 0.5
"""How often the sweep's state is asked over REST (as the CLI's progress bar does), s."""


def _children(pid: int) -> dict[str, list[int]]:
    """The API's and the workers' process ids among the children of ``contact-skills up`` (its own process runs the
    Zenoh router)."""
    found: dict[str, list[int]] = {"api": [], "worker": []}
    for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        argv = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        for role in found:
            if role.encode() in argv:
                found[role].append(int(child))
    return found


_WORKER_LINE = re.compile(
    r"^\s*(worker-\d+) \| (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) contact_skills\.worker INFO "
    r"exec_\w+ (accepted|done|aborted|failed)\b"
)
"""A worker's log line (``contact-skills up`` prefixes its name) of an execution accepted or ended."""


def hand_over_gaps(log: str) -> list[float]:
    """Per worker, the time from an execution's end (its final status queued for the bus) to the start of the
    next one it accepted, s, from the workers' log lines in ``contact-skills up``'s output (log level info)."""
    ended: dict[str, datetime] = {}
    gaps = []
    for line in log.splitlines():
        found = _WORKER_LINE.match(line)
        if found is None:
            continue
        worker, stamp, event = found.groups()
        at = datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S,%f")
        if event == "accepted" and worker in ended:
            gaps.append((at - ended.pop(worker)).total_seconds())
        elif event != "accepted":
            ended[worker] = at
    return gaps


@dataclass(frozen=True)
class Stack:
    """A running ``contact-skills up --workers {workers}``: its client, its process, its log (level info) and the
    skill learned on it."""

    workers: int
    client: httpx.Client
    up: subprocess.Popen
    log: Path
    skill_id: str


@contextlib.contextmanager
def stack(workers: int) -> Iterator[Stack]:
    """``contact-skills up --workers {workers}`` on a temporary SQLite database, :data:`RECORD` recorded by a worker and
    learned as a slide."""
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    argv = ["up", "--workers", str(workers), "--port", str(port), "--zenoh-port", str(zenoh_port)]
    with tempfile.TemporaryDirectory() as tmp, running(
        [*argv, "--db", f"{tmp}/bench.db", "--log-level", "info"], url, timeout_s=120, workers=workers,
        log_path=Path(tmp) / "up.log",
    ) as up:  # fmt: skip
        client = httpx.Client(base_url=url, timeout=180)
        demo = client.post("/demonstrations/record", json=RECORD)
        assert demo.status_code == 201, demo.text
        skill = client.post("/skills", json={"demonstration_id": demo.json()["id"], "skill_type": "slide"})
        assert skill.status_code == 201, skill.text
        yield Stack(workers, client, up, Path(tmp) / "up.log", skill.json()["id"])


def bench_sweep(on: Stack, trials: int, store_telemetry: bool) -> dict:
    """One sweep of ``trials`` trials on the stack ``on``: its rate, where its time went."""
    workers, client = on.workers, on.client
    log_from = on.log.stat().st_size  # the hand-overs of this sweep only (a stack may run more than one)
    body = {"skill_id": on.skill_id, "controllers": ["hybrid_cf"], "vary": VARY, "trials": trials,
            "store_telemetry": store_telemetry}  # fmt: skip
    pids = _children(on.up.pid)
    cpu_before = {role: sum(process_cpu_s(p) for p in found) for role, found in pids.items()}
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    created = client.post("/sweeps", json=body)
    submitted_s = time.perf_counter() - start
    assert created.status_code == 202, created.text
    sweep_id = created.json()["id"]
    while (view := client.get(f"/sweeps/{sweep_id}").json())["status"] == "running":
        time.sleep(POLL_S)
    wall = time.perf_counter() - start
    cpu = {role: sum(process_cpu_s(p) for p in found) - cpu_before[role] for role, found in pids.items()}
    load_after = os.getloadavg()[0]
    trials_view = client.get(f"/sweeps/{sweep_id}/trials").json()
    stored = [client.get(f"/executions/{t['execution_id']}").json()["telemetry_samples"] for t in trials_view]
    with on.log.open("rb") as log:
        log.seek(log_from)
        gaps = hand_over_gaps(log.read().decode(errors="replace"))
    metrics = [t["metrics"] for t in trials_view if t["metrics"]]
    executions = view["counts"]["finished"]
    loop_s = float(np.median([m["duration_s"] / m["real_time_factor"] for m in metrics]))
    per_execution_s = wall * workers / executions
    return {
        "workers": workers,
        "telemetry": "stream (store_telemetry)" if store_telemetry else "none (default)",
        "executions": executions,
        "done": sum(m["phase"] == "done" for m in metrics),
        "per_minute": executions / wall * 60.0,
        "wall_s": wall,
        "submitted_s": submitted_s,
        "simulated_s": float(np.median([m["duration_s"] for m in metrics])),
        "real_time_factor": float(np.median([m["real_time_factor"] for m in metrics])),
        "loop_s": loop_s,
        "per_execution_s": per_execution_s,
        "other_s": per_execution_s - loop_s,
        "api_cpu_s": cpu["api"] / executions,
        "worker_cpu_s": cpu["worker"] / executions,
        "stored_samples": float(np.median(stored)),
        "hand_over_s": float(np.median(gaps)) if gaps else float("nan"),
        "load": (load_before, load_after),
    }


def report(runs: list[dict], trials_per_worker: int, speed: dict[str, float]) -> str:
    """The section's Markdown: the table and the sentences computed from these runs; ``speed`` the machine's
    (``report.machine_speed``), measured before them."""
    rows = [
        f"| {r['workers']} | {r['telemetry']} | {r['executions']} ({r['done']} done) | {r['wall_s']:.1f} | "
        f"{r['submitted_s']:.2f} | "
        f"**{r['per_minute']:.1f}** | {r['simulated_s']:.1f} | {r['loop_s']:.2f} ({r['real_time_factor']:.1f}x) | "
        f"{r['per_execution_s']:.2f} | {r['other_s']:.2f} | {r['api_cpu_s']:.2f} | {r['worker_cpu_s']:.2f} | "
        f"{r['stored_samples']:.0f} | {r['hand_over_s']:.3f} | {r['load'][0]:.1f} → {r['load'][1]:.1f} |"
        for r in runs
    ]
    rate = {(r["workers"], r["telemetry"].split()[0]): r for r in runs}
    two, two_stream, one = rate[(2, "none")], rate[(2, "stream")], rate.get((1, "none"))
    cpu = {mode: two_run["api_cpu_s"] + two_run["worker_cpu_s"] for mode, two_run in (("none", two),
           ("stream", two_stream))}  # fmt: skip
    verdict = "met" if two["per_minute"] >= TARGET_PER_MINUTE else "not met"
    versus_one = " (1 worker: not run)"
    if one is not None:
        versus_one = f", and {two['per_minute'] / one['per_minute']:.2f}x the {one['per_minute']:.1f} of 1 worker"
    return "\n".join(
        [
            "## Sweeps: executions per minute with 1 and 2 workers",
            "",
            "Reproduce: `.venv/bin/python benchmarks/bench_sweeps.py` (`contact-skills up --workers N` as real "
            f"processes on loopback; a `POST /sweeps` of {trials_per_worker} trials per worker, controller "
            f"hybrid_cf, varying {', '.join(VARY)}; the teacher's slide_flat with overrides {RECORD['overrides']}; "
            "each run on a fresh stack, with the trials' telemetry off (the default) and with `store_telemetry`).",
            "",
            "| workers | telemetry | executions | wall s | of which POST /sweeps s | per minute | simulated s each "
            "(median) | loop s each "
            "(median, real-time factor) | worker-s per execution | of which not the loop | API CPU s per execution "
            "| worker CPU s per execution | samples stored per execution (median) | hand-over s (median) | load "
            "average (1 min) before → after |",
            "| ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
            *rows,
            "",
            f"With 2 workers the default (no telemetry) ran {two['per_minute']:.1f} executions per minute, "
            f"{two['per_minute'] / two_stream['per_minute']:.2f}x the {two_stream['per_minute']:.1f} of the same "
            f"sweep storing its telemetry{versus_one}. Streaming cost the API {two_stream['api_cpu_s']:.2f} CPU s per "
            f"execution against {two['api_cpu_s']:.2f} without (decoding the JSON batches, writing every sample to "
            f"SQLite), and the workers {two_stream['worker_cpu_s']:.2f} against {two['worker_cpu_s']:.2f} (encoding "
            f"and publishing them): {cpu['stream']:.2f} CPU s per execution against {cpu['none']:.2f}, so 2 cores "
            f"of our own would run at most {120.0 / cpu['stream']:.0f} against {120.0 / cpu['none']:.0f} per "
            "minute (the CPU per execution depends far less on the other jobs than the rates do). Per execution a "
            "worker spent "
            f"{two['loop_s']:.2f} s in the control loop and {two['other_s']:.2f} s around it (the hand-over from "
            f"its previous trial's end to the next start, {two['hand_over_s']:.3f} s, median from the workers' log; "
            "the world's set-up, the metrics, and the sweep's start and tail: "
            f"the reply to `POST /sweeps` took {two['submitted_s']:.2f} s, most of it the API process's first import "
            f"of scipy.stats, once per process: {two['submitted_s'] * two['workers'] / two['executions']:.2f} s per "
            "execution of this short sweep). The "
            f"issue's target of {TARGET_PER_MINUTE:.0f} per minute with 2 workers on 2 cores is {verdict} in this "
            f"run ({two['per_minute']:.1f}); with the 2 cores to itself the default would still be bounded by its "
            f"CPU per execution ({120.0 / cpu['none']:.0f} per minute), most of it the control loop (its speed: "
            "`bench_control_loop`).",
            "",
            "What a number is: the rate of this sweep, on this machine, at the load shown beside it (the machine is "
            "shared with other jobs: a run at a higher load is slower, so compare rows only at a similar load; the "
            "load average includes the run's own busy workers, about 1 per worker, and the run before). It "
            "is not the rate on 2 cores of our own (the CPU bound above is), nor a rate for another skill (it scales "
            "with 1 / the skill's "
            "simulated time and with the loop's real-time factor, `bench_control_loop`).",
            "",
            "How fast this machine was before the runs (the rates scale with it; compare tables from other days by "
            f"it): CPython `sum(range(1000))` {speed['python']:.1f} µs, a fixed PyBullet step "
            f"{speed['physics']:.1f} µs (`benchmarks/report.py` machine_speed, best of 5).",
            "",
            machine_line(f"{os.cpu_count()} cores shared by the API, the router, the workers and other jobs"),
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials-per-worker", type=int, default=10, help="trials per sim worker (default 10)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/BENCHMARKS.md alone")
    add_smoke_argument(parser, "--trials-per-worker 1, 2 workers only")
    args = parser.parse_args()
    worker_counts = (1, 2)
    if args.smoke:  # each row starts a stack of its own (seconds): the 2-worker rows go through all the code
        args.trials_per_worker, args.no_write, worker_counts = 1, True, (2,)
    os.chdir(Path(__file__).resolve().parents[1])
    speed = machine_speed()
    runs = []
    for workers in worker_counts:
        with contextlib.ExitStack() as shared:
            # The smoke run's two sweeps share one stack (its start-up, recording and learning cost more than its
            # two trials); the full run gives each sweep a fresh one.
            one = shared.enter_context(stack(workers)) if args.smoke else None
            for store_telemetry in (False, True):
                with contextlib.ExitStack() as own:
                    on = one or own.enter_context(stack(workers))
                    run = bench_sweep(on, args.trials_per_worker * workers, store_telemetry)
                runs.append(run)
                print({k: round(v, 3) if isinstance(v, float) else v for k, v in run.items()}, flush=True)
    body = report(runs, args.trials_per_worker, speed)
    print(body)
    if not args.no_write:
        write_section(SECTION, body)


if __name__ == "__main__":
    main()
