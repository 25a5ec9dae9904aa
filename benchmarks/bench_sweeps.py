"""Sweep throughput: executions per minute of a robustness sweep with 1 and 2 sim workers, for a ~10 s skill.

Run: ``.venv/bin/python benchmarks/bench_sweeps.py [--trials-per-worker 10]``; writes the ``bench_sweeps`` section
of docs/BENCHMARKS.md.

For N = 1, 2: ``contact-skills up --workers N`` (real processes on loopback, a temporary SQLite database); the
teacher's ``slide_flat`` demonstration recorded by a worker with a stroke that makes an execution last about 10 s
of simulated time, learned; then ``POST /sweeps`` with ``trials-per-worker x N`` trials of one controller
(``hybrid_cf``) varying the unknown table height by ±5 mm and the friction 0.15-0.3 (every trial runs the whole
skill), polled over REST until done. Executions per minute = executions / wall time from the submission to the
sweep's end (the queue, the dispatcher and the bus included). The machine is shared: the 1-minute load average is
read before and after each run and printed beside it.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import machine_line, pin_blas_threads, write_section

pin_blas_threads()

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.bench_service import running  # noqa: E402
from services.local_processes import free_port  # noqa: E402

SECTION = "bench_sweeps"
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 2.5}}
"""A stroke of 2.5 s: with settling, approach and retreat an execution runs ~10 s of simulated time."""
VARY = {"offset_z_m": {"low": -0.005, "high": 0.005}, "friction": {"low": 0.15, "high": 0.3}}
TARGET_PER_MINUTE = 150.0
"""Issue 14's target for 2 workers on 2 cores."""
POLL_S = 0.5


def bench_sweep(workers: int, trials: int) -> dict:
    """One sweep of ``trials`` trials on ``contact-skills up --workers {workers}``: its rate and its executions."""
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    argv = ["up", "--workers", str(workers), "--port", str(port), "--zenoh-port", str(zenoh_port)]
    with tempfile.TemporaryDirectory() as tmp, running(
        [*argv, "--db", f"{tmp}/bench.db", "--log-level", "warning"], url, timeout_s=120, workers=workers
    ):  # fmt: skip
        client = httpx.Client(base_url=url, timeout=180)
        demo = client.post("/demonstrations/record", json=RECORD)
        assert demo.status_code == 201, demo.text
        skill = client.post("/skills", json={"demonstration_id": demo.json()["id"], "skill_type": "slide"})
        assert skill.status_code == 201, skill.text
        body = {"skill_id": skill.json()["id"], "controllers": ["hybrid_cf"], "vary": VARY, "trials": trials}
        load_before = os.getloadavg()[0]
        start = time.perf_counter()
        created = client.post("/sweeps", json=body)
        assert created.status_code == 202, created.text
        sweep_id = created.json()["id"]
        while (view := client.get(f"/sweeps/{sweep_id}").json())["status"] == "running":
            time.sleep(POLL_S)
        wall = time.perf_counter() - start
        trials_view = client.get(f"/sweeps/{sweep_id}/trials").json()
    metrics = [t["metrics"] for t in trials_view if t["metrics"]]
    return {
        "workers": workers,
        "executions": view["counts"]["finished"],
        "per_minute": view["counts"]["finished"] / wall * 60.0,
        "wall_s": wall,
        "simulated_s": float(np.median([m["duration_s"] for m in metrics])),
        "real_time_factor": float(np.median([m["real_time_factor"] for m in metrics])),
        "done": sum(m["phase"] == "done" for m in metrics),
        "load": (load_before, os.getloadavg()[0]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials-per-worker", type=int, default=10, help="trials per sim worker (default 10)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/BENCHMARKS.md alone")
    args = parser.parse_args()
    os.chdir(Path(__file__).resolve().parents[1])
    runs = []
    for workers in (1, 2):
        run = bench_sweep(workers, args.trials_per_worker * workers)
        runs.append(run)
        print(run, flush=True)
    rows = [
        f"| {r['workers']} | {r['executions']} ({r['done']} done) | {r['wall_s']:.0f} | {r['per_minute']:.1f} | "
        f"{r['simulated_s']:.1f} | {r['real_time_factor']:.1f} | {r['load'][0]:.1f} → {r['load'][1]:.1f} |"
        for r in runs
    ]
    one, two = runs
    verdict = "met" if two["per_minute"] >= TARGET_PER_MINUTE else "not met"
    body = "\n".join(
        [
            "## Sweeps: executions per minute with 1 and 2 workers",
            "",
            "Reproduce: `.venv/bin/python benchmarks/bench_sweeps.py` (`contact-skills up --workers N` as real "
            f"processes on loopback; a `POST /sweeps` of {args.trials_per_worker} trials per worker, controller "
            f"hybrid_cf, varying {', '.join(VARY)}; the teacher's slide_flat with overrides {RECORD['overrides']}).",
            "",
            "| workers | executions | wall s | per minute | simulated s each (median) | real-time factor (median) | "
            "load average (1 min) before → after |",
            "| ---: | --- | ---: | ---: | ---: | ---: | --- |",
            *rows,
            "",
            f"2 workers ran {two['per_minute'] / one['per_minute']:.2f}x the executions per minute of 1; the issue's "
            f"target of {TARGET_PER_MINUTE:.0f} per minute with 2 workers on 2 cores is {verdict} in this run "
            f"({two['per_minute']:.1f}). The machine is shared with other jobs (the load average beside each run): "
            "the rates are what this run measured, not the machine's ceiling.",
            "",
            machine_line(f"{os.cpu_count()} cores shared by the API, the router, the workers and other jobs"),
        ]
    )
    print(body)
    if not args.no_write:
        write_section(SECTION, body)


if __name__ == "__main__":
    main()
