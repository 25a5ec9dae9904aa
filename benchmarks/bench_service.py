"""The service end to end over HTTP: learning latency through the API and executions per minute per worker count.

Run: ``.venv/bin/python benchmarks/bench_service.py [--repeats 15] [--executions 8] [--no-write] [--smoke]``; writes
the ``bench_service`` section of docs/BENCHMARKS.md.

1. Learning latency: ``contact-skills api --no-bus`` (a real uvicorn process, temp SQLite), a 10 s 1 kHz
   demonstration (``corpus.synthetic.plane_slide(duration_s=10)``, 10 000 samples):
   ``POST /skills`` with the demonstration inline, and with it stored (``demonstration_id``); p50 and p99 of
   the client-side wall time (request sent -> 201 parsed). Target: p50 < 1.5 s.
2. Throughput: ``contact-skills up --workers N`` (N = 1, 2): one scripted slide demonstration is recorded and
   learned, then executions (pace fast) are kept queued, one per idle worker, until ``--executions`` have
   finished; executions per minute = finished / wall time from the first submission to the last finish.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import add_smoke_argument, machine_line, median_time, pin_blas_threads, write_section

pin_blas_threads()

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from services.local_processes import cpu_seconds, free_port  # noqa: E402

LEARN_TARGET_P50_S = 1.5
POLL_S = 0.1
"""How often the throughput loop polls each running execution over REST, s."""
SCENARIO = "slide_flat"
RECORD_OVERRIDES = {"move_duration_s": 2.0}
LEARN_DEMO_S = 10.0
"""Duration of the synthetic demonstration learned through the API (``corpus.synthetic.plane_slide``), s."""


@contextlib.contextmanager
def running(
    argv: list[str], url: str, timeout_s: float = 90.0, workers: int = 0, log_path: Path | None = None
) -> Iterator[subprocess.Popen]:
    """Start a `contact-skills` process, wait for /health (and ``workers`` workers), stop it with SIGTERM; its
    output goes to ``log_path`` (kept) or a temporary file."""
    log = tempfile.TemporaryFile() if log_path is None else log_path.open("w+b")  # noqa: SIM115 (closed in finally)
    process = subprocess.Popen([sys.executable, "-m", "cli.main", *argv], stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if process.poll() is not None:
                log.seek(0)
                raise RuntimeError(f"{argv[0]} exited: {log.read().decode(errors='replace')[-3000:]}")
            with contextlib.suppress(httpx.HTTPError):
                health = httpx.get(f"{url}/health", timeout=5).json()
                if len(health["workers"]) >= workers:
                    break
            if time.monotonic() > deadline:
                log.seek(0)
                output = log.read().decode(errors="replace")[-3000:]
                raise RuntimeError(f"{argv[0]} not ready in {timeout_s} s: {output}")
            time.sleep(0.3)
        yield process
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        log.close()


def demonstration_body(duration_s: float = LEARN_DEMO_S, name: str | None = None) -> dict:
    """The JSON body of ``POST /demonstrations``: a ``duration_s`` synthetic slide at 1 kHz
    (``corpus.synthetic.plane_slide``), named ``name`` (default: what it is)."""
    from corpus.synthetic import plane_slide

    d = plane_slide(duration_s=duration_s)
    return {
        "t": d.t.tolist(),
        "positions": d.positions.tolist(),
        "orientations": d.orientations.tolist(),
        "wrenches": d.wrenches.tolist(),
        "metadata": {"name": f"plane_slide {duration_s:g} s 1 kHz" if name is None else name},
    }


def percentiles(times: list[float]) -> tuple[float, float]:
    return float(np.percentile(times, 50)), float(np.percentile(times, 99))


def bench_learning(repeats: int) -> tuple[list[str], dict[str, float]]:
    body = demonstration_body()
    size_mb = len(json.dumps({"demonstration": body, "skill_type": "auto"})) / 1e6
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with (
        tempfile.TemporaryDirectory() as tmp,
        running(["api", "--no-bus", "--port", str(port), "--db", f"{tmp}/bench.db", "--log-level", "warning"], url),
    ):
        client = httpx.Client(base_url=url, timeout=120)
        upload_s, created = median_time(lambda: client.post("/demonstrations", json=body), 3)
        demo_id = created.json()["id"]
        client.post("/skills", json={"demonstration_id": demo_id})  # warm-up (imports, caches)
        rows, numbers = [], {}
        for label, request in (
            (f"inline demonstration (body {size_mb:.1f} MB)", {"demonstration": body, "skill_type": "auto"}),
            ("stored demonstration (demonstration_id)", {"demonstration_id": demo_id, "skill_type": "auto"}),
        ):
            times, learn = [], []
            for _ in range(repeats):
                start = time.perf_counter()
                response = client.post("/skills", json=request)
                times.append(time.perf_counter() - start)
                assert response.status_code == 201, response.text
                learn.append(response.json()["learn_seconds"])
            p50, p99 = percentiles(times)
            numbers[label] = p50
            verdict = "MET" if p50 < LEARN_TARGET_P50_S else "NOT MET"
            rows.append(f"| {label} | {repeats} | {p50:.3f} | {p99:.3f} | {np.median(learn):.3f} | {verdict} |")
        rows.append(f"| (upload only: POST /demonstrations, median of 3) | 3 | {upload_s:.3f} | – | – | – |")
    return rows, numbers


def child_commands(pid: int) -> dict[int, list[str]]:
    """The direct children of process ``pid``: their pids and command lines (from /proc)."""
    children = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            if parent == pid:
                argv = (stat.parent / "cmdline").read_bytes().decode().split("\0")
                children[int(stat.parent.name)] = [a for a in argv if a]
        except (OSError, ValueError, IndexError):  # the process ended meanwhile
            continue
    return children


def process_cpu_s(pid: int) -> float:
    """User + system CPU time of a process so far, s (0 where it cannot be read)."""
    return cpu_seconds(pid) or 0.0


def bench_executions(workers: int, executions: int) -> tuple[float, list[dict], dict[str, float]]:
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    argv = ["up", "--workers", str(workers), "--port", str(port), "--zenoh-port", str(zenoh_port)]
    with (
        tempfile.TemporaryDirectory() as tmp,
        running(
            [*argv, "--db", f"{tmp}/bench.db", "--log-level", "warning"], url, timeout_s=120, workers=workers
        ) as up,
    ):
        client = httpx.Client(base_url=url, timeout=180)
        record = {"scenario": SCENARIO, "seed": 0, "overrides": RECORD_OVERRIDES}
        demo = client.post("/demonstrations/record", json=record)
        assert demo.status_code == 201, demo.text
        skill = client.post("/skills", json={"demonstration_id": demo.json()["id"]})
        assert skill.status_code == 201, skill.text
        request = {"skill_id": skill.json()["id"], "pace": "fast"}
        children = child_commands(up.pid)  # /health shows no pids (it is open): the processes `up` started
        pids = {
            "workers": [pid for pid, argv in children.items() if "worker" in argv],
            "API": [pid for pid, argv in children.items() if "api" in argv],
            "router (up)": [up.pid],
        }
        assert len(pids["workers"]) == workers and len(pids["API"]) == 1, children
        cpu_before = {name: sum(map(process_cpu_s, p)) for name, p in pids.items()}
        running_ids: list[str] = []
        finished: list[dict] = []
        submitted = 0
        start = time.perf_counter()
        while len(finished) < executions:
            while submitted < executions and len(running_ids) < workers:
                response = client.post("/executions", json=request)
                if response.status_code == 503:  # every worker busy (finishing); try again shortly
                    break
                assert response.status_code == 202, response.text
                running_ids.append(response.json()["id"])
                submitted += 1
            time.sleep(POLL_S)
            for execution_id in list(running_ids):
                view = client.get(f"/executions/{execution_id}").json()
                if view["status"] in ("done", "aborted", "failed"):
                    running_ids.remove(execution_id)
                    finished.append(view)
        wall = time.perf_counter() - start
        cpu = {name: (sum(map(process_cpu_s, p)) - cpu_before[name]) / len(finished) for name, p in pids.items()}
    return len(finished) / wall * 60.0, finished, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="learning requests per variant")
    parser.add_argument("--executions", type=int, default=8, help="executions per worker count")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts of the throughput runs")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/BENCHMARKS.md alone")
    add_smoke_argument(parser, "2 learning requests per variant, 2 executions with 2 workers")
    args = parser.parse_args()
    if args.smoke:  # one stack of workers: each `up` costs more than its executions
        args.repeats, args.executions, args.workers, args.no_write = 2, 2, [2], True
    os.chdir(Path(__file__).resolve().parents[1])
    load_before = os.getloadavg()[0]

    learn_rows, _ = bench_learning(args.repeats)
    print("\n".join(learn_rows), flush=True)
    sample = demonstration_body()
    n_samples = len(sample["t"])
    duration = sample["t"][-1] - sample["t"][0]
    rate = (n_samples - 1) / duration
    throughput_rows = []
    runs: dict[int, dict] = {}
    for workers in args.workers:
        per_minute, finished, cpu = bench_executions(workers, args.executions)
        phases = {}
        for view in finished:
            phases[view["status"]] = phases.get(view["status"], 0) + 1
        sim_s = [v["metrics"]["duration_s"] for v in finished if v.get("metrics")]
        rtf = [v["metrics"]["real_time_factor"] for v in finished if v.get("metrics")]
        batches = [v["telemetry_batches"] for v in finished]
        runs[workers] = {"per_minute": per_minute, "cpu": cpu, "batches": float(np.median(batches))}
        row = (
            f"| {workers} | {len(finished)} | {per_minute:.1f} | {np.median(sim_s):.2f} | {np.median(rtf):.1f} | "
            f"{' / '.join(f'{cpu[k]:.2f}' for k in ('workers', 'API', 'router (up)'))} | "
            f"{', '.join(f'{k} {n}' for k, n in sorted(phases.items()))} |"
        )
        throughput_rows.append(row)
        print(row, flush=True)

    cores = os.cpu_count() or 1
    last = runs[max(runs)]
    per_execution = sum(last["cpu"].values())
    ceiling = cores * 60.0 / per_execution if per_execution > 0 else float("inf")
    busy = last["per_minute"] / 60.0 * per_execution  # cores kept busy by these processes during the run
    body = "\n".join(
        [
            "## Service: learning latency through the API, executions per minute",
            "",
            "Reproduce: `.venv/bin/python benchmarks/bench_service.py` (real processes on loopback: "
            "`contact-skills api`, `contact-skills up --workers N`, a temporary SQLite database).",
            "",
            f"Learning: `POST /skills` with a {duration:.0f} s, {rate:.0f} Hz demonstration "
            f"(`corpus.synthetic.plane_slide(duration_s={LEARN_DEMO_S:g})`, {n_samples} samples), skill_type auto; "
            "client wall "
            "time from sending the request to the parsed 201 (JSON parsing, validation, learning in the thread pool, "
            f"storing). {args.repeats} requests per variant after one warm-up (p99 of {args.repeats} samples "
            f"interpolates between the two largest). Target p50 < {LEARN_TARGET_P50_S} s.",
            "",
            "| request | n | p50 s | p99 s | learn_skill median s (server) | target |",
            "| --- | ---: | ---: | ---: | ---: | --- |",
            *learn_rows,
            "",
            f"Executions: `{SCENARIO}` recorded by the worker (overrides {RECORD_OVERRIDES}), learned, executed "
            f"{args.executions} times per worker count with pace fast (one execution queued per idle worker, status "
            f"polled every {POLL_S:g} s over REST); executions per minute = finished / wall time from the first "
            "submission to the last finish.",
            "",
            "| workers | executions | per minute | simulated s each (median) | real-time factor (median) | "
            "CPU s per execution: workers / API / router | outcome |",
            "| ---: | ---: | ---: | ---: | ---: | --- | --- |",
            *throughput_rows,
            "",
            f"With {max(runs)} workers an execution cost {per_execution:.2f} CPU s in all "
            f"({last['cpu']['workers']:.2f} the workers: simulation, controller, telemetry JSON; "
            f"{last['cpu']['API']:.2f} the API: decoding and storing a median {last['batches']:.0f} telemetry "
            f"batches; {last['cpu']['router (up)']:.2f} `up` and its router). At that cost {cores} cores allow at most "
            f"{ceiling:.0f} executions per minute; the {last['per_minute']:.1f}/min measured kept {busy:.1f} of the "
            f"{cores} cores busy with these processes (this benchmark client and other jobs use the rest: the load "
            "below).",
            "",
            machine_line(f"{cores} cores shared by the API, the router and the workers", load_at_start=load_before),
        ]
    )
    print(body)
    if not args.no_write:
        write_section("bench_service", body)


if __name__ == "__main__":
    main()
