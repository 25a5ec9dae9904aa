"""The service under load (issue 13): concurrent learns against /health latency, and the execution queue.

Run: ``.venv/bin/python benchmarks/bench_service_load.py [--learns 50] [--executions 20] [--no-write] [--smoke]``;
writes the ``bench_service_load`` section of docs/BENCHMARKS.md.

1. Learning under load: ``contact-skills up --workers 2`` (a real uvicorn API, its learner processes, temp SQLite);
   a 10 s 1 kHz demonstration (``corpus.synthetic.plane_slide(duration_s=10)``) is stored, then ``--learns``
   ``POST /skills`` (``demonstration_id``) are sent at once from as many client threads, while another thread
   asks ``GET /health`` every 50 ms. Reported: the learns' wall time and throughput, their client latency, and
   /health's p50/p99/max during the whole burst, beside the same figures over 15 s with no learning just before
   (the machine is shared: what other jobs' load alone does to the API's latency). Target: /health p99 < 100 ms.
2. Queue wait: ``contact-skills up --workers N`` (N = 1, 2): one scripted slide demonstration is recorded and
   learned, then ``--executions`` executions (pace fast) are submitted at once from as many threads; the
   executions list is polled every 0.1 s. Queue wait = first poll that shows a worker for it minus its
   submission; makespan = first submission to last finish.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_service import RECORD_OVERRIDES, SCENARIO, demonstration_body, running
from benchmarks.report import add_smoke_argument, machine_line, pin_blas_threads, write_section

pin_blas_threads()

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from schemas.bus import FINAL_PHASES  # noqa: E402
from services.local_processes import free_port  # noqa: E402

HEALTH_EVERY_S = 0.05
BASELINE_S = 15.0
"""/health is first asked for this long with no learning: its latency on the machine as loaded by others."""
HEALTH_TARGET_P99_S = 0.100
POLL_S = 0.25


def _up(workers: int, tmp: str) -> tuple[list[str], str]:
    port, zenoh_port = free_port(), free_port()
    argv = ["up", "--workers", str(workers), "--port", str(port), "--zenoh-port", str(zenoh_port),
            "--db", f"{tmp}/load-{workers}.db", "--log-level", "warning"]  # fmt: skip
    return argv, f"http://127.0.0.1:{port}"


@contextlib.contextmanager
def _stack(workers: int) -> Iterator[str]:
    """``contact-skills up --workers {workers}`` on a temporary SQLite database until the context ends: its URL."""
    with tempfile.TemporaryDirectory() as tmp:
        argv, url = _up(workers, tmp)
        with running(argv, url, workers=workers):
            yield url


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.0f}" if seconds >= 0.1 else f"{seconds * 1000:.1f}"


def bench_learns(learns: int, baseline_s: float, on: str | None = None) -> tuple[list[str], dict[str, float]]:
    """The learns at once against /health, on a fresh 2-worker stack (or the one at the URL ``on``)."""
    with contextlib.ExitStack() as own:
        url = on or own.enter_context(_stack(2))
        limits = httpx.Limits(max_connections=learns + 8)
        with httpx.Client(base_url=url, timeout=600, limits=limits) as http:
            demo_id = http.post("/demonstrations", json=demonstration_body()).json()["id"]
            assert http.post("/skills", json={"demonstration_id": demo_id}).status_code == 201  # warm-up
            single = time.perf_counter()
            assert http.post("/skills", json={"demonstration_id": demo_id}).status_code == 201
            single = time.perf_counter() - single
            health: list[float] = []
            stop = threading.Event()

            def poll_health(into: list[float]) -> None:
                while not stop.is_set():
                    started = time.perf_counter()
                    http.get("/health", timeout=30).raise_for_status()
                    into.append(time.perf_counter() - started)
                    stop.wait(HEALTH_EVERY_S)

            idle: list[float] = []  # the same requests with no learning, on the machine as loaded now
            idle_load = os.getloadavg()[0]
            timer = threading.Timer(baseline_s, stop.set)
            timer.start()
            poll_health(idle)
            stop.clear()

            def learn(_: int) -> tuple[int, float]:
                started = time.perf_counter()
                response = http.post("/skills", json={"demonstration_id": demo_id})
                return response.status_code, time.perf_counter() - started

            burst_load = os.getloadavg()[0]
            poller = threading.Thread(target=poll_health, args=(health,))
            poller.start()
            started = time.perf_counter()
            with ThreadPoolExecutor(learns) as pool:
                results = list(pool.map(learn, range(learns)))
            wall = time.perf_counter() - started
            stop.set()
            poller.join()
            stats = http.get("/health").json()["learning"]
    codes = [code for code, _ in results]
    latency = np.array([t for _, t in results])
    h, i = np.array(health), np.array(idle)
    p99, idle_p99 = float(np.percentile(h, 99)), float(np.percentile(i, 99))
    rows = [
        f"| none ({baseline_s:g} s) | — | — | — | — | {idle_load:.1f} | {len(i)} | {_ms(np.median(i))} / "
        f"{_ms(idle_p99)} / {_ms(i.max())} | {'MET' if idle_p99 < HEALTH_TARGET_P99_S else 'NOT MET'} |",
        f"| {learns} at once | {codes.count(201)} / {learns} | {wall:.1f} | {learns / wall:.2f} | "
        f"{np.median(latency):.2f} / {latency.max():.2f} | {burst_load:.1f} | {len(h)} | {_ms(np.median(h))} / "
        f"{_ms(p99)} / {_ms(h.max())} | {'MET' if p99 < HEALTH_TARGET_P99_S else 'NOT MET'} |",
    ]
    return rows, {"single": single, "wall": wall, "health_p99": p99, "processes": stats["processes"],
                  "ok": codes.count(201), "learns": learns, "idle_p99": idle_p99, "idle_load": idle_load}  # fmt: skip


def bench_queue(workers: int, executions: int, on: str | None = None) -> tuple[str, dict[str, float]]:
    """The executions queued at once on a fresh stack of ``workers`` (or the one at the URL ``on``)."""
    with contextlib.ExitStack() as own:
        url = on or own.enter_context(_stack(workers))
        with httpx.Client(base_url=url, timeout=120) as http:
            record = {"scenario": SCENARIO, "seed": 0, "overrides": RECORD_OVERRIDES}
            demo_id = http.post("/demonstrations/record", json=record).json()["id"]
            skill_id = http.post("/skills", json={"demonstration_id": demo_id}).json()["id"]

            def submit(_: int) -> tuple[float, dict]:
                sent = time.perf_counter()
                response = http.post("/executions", json={"skill_id": skill_id, "pace": "fast"})
                return sent, {"code": response.status_code, **response.json()}

            with ThreadPoolExecutor(executions) as pool:
                submitted = list(pool.map(submit, range(executions)))
            first = min(sent for sent, _ in submitted)
            sent_at = {reply["id"]: sent for sent, reply in submitted if reply["code"] == 202}
            queued = sum(reply.get("status") == "queued" for _, reply in submitted)
            assigned: dict[str, float] = {}
            ran_on: dict[str, str] = {}
            finished: dict[str, str] = {}
            last = first
            deadline = time.monotonic() + 60 + 15 * executions
            while len(finished) < len(sent_at) and time.monotonic() < deadline:
                now = time.perf_counter()
                for view in http.get("/executions", params={"limit": 1000}).json():
                    if view["id"] not in sent_at:
                        continue
                    if view["worker_id"] is not None:
                        assigned.setdefault(view["id"], now)
                        ran_on[view["id"]] = view["worker_id"]
                    if view["status"] in FINAL_PHASES:
                        finished.setdefault(view["id"], view["status"])
                        last = now
                time.sleep(POLL_S)
    waits = np.array([assigned[e] - sent_at[e] for e in assigned])
    makespan = last - first
    done = sum(status == "done" for status in finished.values())
    per_worker = " / ".join(str(n) for n in sorted(Counter(ran_on.values()).values(), reverse=True))
    row = (
        f"| {workers} | {executions} | {len(sent_at)} | {queued} | {np.median(waits):.1f} | {waits.max():.1f} | "
        f"{makespan:.1f} | {60 * done / makespan:.1f} | {per_worker} | done {done} |"
    )
    return row, {"accepted": len(sent_at), "done": done, "wait_max": float(waits.max()), "makespan": makespan}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learns", type=int, default=50)
    parser.add_argument("--executions", type=int, default=20)
    parser.add_argument("--baseline-s", type=float, default=BASELINE_S, help="/health asked with no learning, s")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/BENCHMARKS.md alone")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts of the queue runs")
    add_smoke_argument(parser, "2 learns, 2 executions queued on 2 workers, a 1 s baseline")
    args = parser.parse_args()
    if args.smoke:  # one queue stack: each `up` costs more than its executions
        args.learns, args.executions, args.workers, args.baseline_s, args.no_write = 2, 2, [2], 1.0, True
    load_before = os.getloadavg()[0]
    queue_rows, queues = [], {}
    with contextlib.ExitStack() as shared:
        # The smoke run learns and queues on one 2-worker stack (its start-up costs more than its 2 learns and 2
        # executions); the full run gives each part a fresh one.
        one = shared.enter_context(_stack(2)) if args.smoke else None
        learn_rows, learning = bench_learns(args.learns, args.baseline_s, one)
        load_learning = os.getloadavg()[0]
        for workers in args.workers:
            row, numbers = bench_queue(workers, args.executions, one)
            queue_rows.append(row)
            queues[workers] = numbers
            print(row, flush=True)
    options = (
        ""
        if (args.learns, args.executions, args.baseline_s, args.workers) == (50, 20, BASELINE_S, [1, 2])
        else f" --learns {args.learns} --executions {args.executions} --baseline-s {args.baseline_s:g} --workers "
        + " ".join(map(str, args.workers))
    )
    command = f"`.venv/bin/python benchmarks/bench_service_load.py{options}`"
    sentences = [
        f"{learning['ok']} of {learning['learns']} learns answered 201 in {learning['wall']:.1f} s on "
        f"{learning['processes']} learner processes ({learning['learns'] / learning['wall']:.2f} learns/s; one alone "
        f"took {learning['single']:.2f} s); /health p99 during the burst: {learning['health_p99'] * 1000:.0f} ms, "
        f"with no learning just before: {learning['idle_p99'] * 1000:.0f} ms (load average "
        f"{learning['idle_load']:.1f}).",
        *(
            f"{workers} worker(s): {q['accepted']} of {args.executions} executions accepted (none refused for "
            f"lack of a free worker), {q['done']} done, the longest queue wait {q['wait_max']:.1f} s, all finished "
            f"{q['makespan']:.1f} s after the first submission."
            for workers, q in queues.items()
        ),
    ]
    load_after = os.getloadavg()[0]
    sentences.append(
        f"Load average (1 min) before the run {load_before:.1f}, after the learns {load_learning:.1f}, at the end "
        f"{load_after:.1f} on {os.cpu_count()} cores: other jobs share this machine, and every process here competes "
        "with them for the same cores."
    )
    body = "\n".join(
        [
            "## Service under load: concurrent learns, /health, the execution queue",
            "",
            f"Reproduce: {command} (real processes on loopback: `contact-skills up --workers N`, temp SQLite).",
            machine_line(load_at_start=load_before),
            "",
            f"Learning: a 10 s 1 kHz demonstration stored once, then `POST /skills` (`demonstration_id`) sent at once "
            f"from {args.learns} client threads while `GET /health` is asked every {HEALTH_EVERY_S * 1000:.0f} ms. "
            f"Target: /health p99 < {HEALTH_TARGET_P99_S * 1000:.0f} ms.",
            "",
            "| learns | 201 | wall s | learns/s | client latency median / max s | load (1 min) at start | "
            "/health samples | /health p50 / p99 / max ms | target |",
            "| --- | --- | ---: | ---: | --- | ---: | ---: | --- | --- |",
            *learn_rows,
            "",
            f"Queue: a `{SCENARIO}` demonstration recorded by a worker (overrides {RECORD_OVERRIDES}) and learned, "
            f"then {args.executions} executions (pace fast) submitted at once; queue wait = first poll (every "
            f"{POLL_S:g} s) showing a worker minus the submission.",
            "",
            "| workers | submitted | accepted (202) | queued on submission | queue wait median s | max s | "
            "makespan s | executions/min | executions per worker | outcome |",
            "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |",
            *queue_rows,
            "",
            *sentences,
        ]
    )
    print(body)
    if not args.no_write:
        write_section("bench_service_load", body)


if __name__ == "__main__":
    main()
