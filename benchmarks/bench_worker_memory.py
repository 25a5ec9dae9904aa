"""A worker's memory over long executions (issue 28): its resident set, and its peak, as it runs long skills one after
another.

Run: ``.venv/bin/python benchmarks/bench_worker_memory.py`` (``--smoke``: one short skill, nothing written); writes
the ``bench_worker_memory`` section of docs/BENCHMARKS.md (``--no-write``: only print).

``contact-skills up --workers 1`` (temp SQLite, loopback); three demonstrations of ``--seconds`` in contact each
(a flat slide, a tilted slide, a cylinder contour) are recorded by the scripted teacher in this process, uploaded
and learned; the skills run at ``pace: fast`` with their telemetry stored, in turn on the same worker, ``--rounds``
times over. After each execution the worker's ``VmRSS`` (resident now) and ``VmHWM`` (the peak resident set since it
started) are read from ``/proc``: the peak is the figure the budget bounds, as the kernel counts it (shared
libraries included).
Last, the worker records one demonstration itself (``POST /demonstrations/record``), reported apart.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_service import running
from benchmarks.report import add_smoke_argument, machine_line, pin_blas_threads, write_section

pin_blas_threads()

import httpx  # noqa: E402

from schemas.bus import FINAL_PHASES  # noqa: E402
from services.local_processes import free_port  # noqa: E402

SECTION = "bench_worker_memory"
BUDGET_MB = 600.0
"""The stated budget of one worker's peak resident set, MB (10^6 bytes), issue 28."""
ROUNDS = 2
"""Times each skill runs, in turn (the first round, then the same skills again: a worker's memory must level off)."""
FULL_SECONDS = 55.0
"""Each demonstration's motion in contact, s: with the approach and retreat, executions of about a minute."""
SMOKE_SECONDS = 3.0
SCENARIOS = ("slide_flat", "slide_tilted", "contour_cylinder")


def worker_pids(parent: int) -> list[int]:
    """The pids of the sim workers among ``parent``'s descendants (``/proc``: their command line names ``worker``)."""
    found, queue = [], [parent]
    while queue:
        pid = queue.pop()
        for task in Path(f"/proc/{pid}/task").glob("*"):
            children = (task / "children").read_text().split() if (task / "children").exists() else []
            queue.extend(int(c) for c in children)
        if pid != parent and b"worker" in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0"):
            found.append(pid)
    return found


def resident_mb(pid: int) -> tuple[float, float]:
    """``pid``'s resident set now and its peak since it started (``VmRSS``, ``VmHWM``), MB."""
    fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    return (int(fields["VmRSS"].split()[0]) * 1024 / 1e6, int(fields["VmHWM"].split()[0]) * 1024 / 1e6)


def measure(seconds: float, scenarios: tuple[str, ...], rounds: int, work_dir: Path) -> dict:
    """Run the benchmark once; returns its figures."""
    from sim_worker.teacher import record_demonstration

    demonstrations = {s: record_demonstration(s, 0, move_duration_s=seconds).demonstration for s in scenarios}
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    argv = ["up", "--workers", "1", "--port", str(port), "--zenoh-port", str(zenoh_port),
            "--db", str(work_dir / "memory.db")]  # fmt: skip
    rows = []
    with running(argv, url, workers=1) as process, httpx.Client(base_url=url, timeout=300) as http:
        (worker,) = worker_pids(process.pid)
        idle = resident_mb(worker)
        skills = {}
        for scenario, demonstration in demonstrations.items():
            demo = _created(http.post("/demonstrations", json=demonstration.model_dump(mode="json")), scenario)
            learn = {"demonstration_id": demo["id"], "skill_type": "auto"}
            skills[scenario] = _created(http.post("/skills", json=learn), scenario)
        for scenario, skill in [item for _ in range(rounds) for item in skills.items()]:
            execution = _created(http.post("/executions", json={"skill_id": skill["id"], "pace": "fast"}), scenario)
            while (view := http.get(f"/executions/{execution['id']}").json())["status"] not in FINAL_PHASES:
                time.sleep(0.5)
            now, peak = resident_mb(worker)
            rows.append({"scenario": scenario, "skill_type": skill["skill"]["skill_type"], "status": view["status"],
                         "steps": (view["metrics"] or {}).get("steps", 0), "stored": view["telemetry_samples"],
                         "rss": now, "peak": peak})  # fmt: skip
        record = {"scenario": scenarios[0], "seed": 0, "overrides": {"move_duration_s": seconds}}
        recorded = _created(http.post("/demonstrations/record", json=record), "the recording")
        recording = {"samples": recorded["summary"]["n_samples"], "mb": resident_mb(worker)}
    return {"seconds": seconds, "rounds": rounds, "idle": idle, "rows": rows, "recording": recording}


def _created(response: httpx.Response, what: str) -> dict:
    """The JSON of a 201/202 answer; else an error naming ``what`` and the answer."""
    if response.status_code not in (201, 202):
        raise RuntimeError(f"{what}: {response.request.method} {response.request.url.path} answered "
                           f"{response.status_code} {response.text[:500]}")  # fmt: skip
    return response.json()


def report(figures: dict) -> str:
    rows, idle, recording = figures["rows"], figures["idle"], figures["recording"]
    peak = max(row["peak"] for row in rows)
    longest = max(row["steps"] for row in rows) / 1000.0
    verdict = "within" if peak <= BUDGET_MB else "OVER"
    lines = [
        "## A worker's memory over long executions (`benchmarks/bench_worker_memory.py`)",
        "",
        f"{machine_line()} `contact-skills up --workers 1`. Demonstrations {figures['seconds']:g} s in contact, "
        "recorded by the scripted teacher in the benchmark's process and uploaded (`POST /demonstrations`), learned "
        f"(`auto`) and executed at `pace: fast` with their telemetry stored, in turn on the one worker, "
        f"{figures['rounds']} round{'s' * (figures['rounds'] > 1)}. "
        "The worker's resident set is read from `/proc` after each execution (`VmRSS`; `VmHWM`, the peak since the "
        "worker started; shared libraries included). MB = 10^6 bytes. "
        "`.venv/bin/python benchmarks/bench_worker_memory.py`.",
        "",
        "| execution | skill | status | simulated s | samples stored | worker RSS after, MB | worker peak so far, MB |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: |",
        f"| (idle, after start-up) | | | | | {idle[0]:.0f} | {idle[1]:.0f} |",
        *(
            f"| {row['scenario']} | {row['skill_type']} | {row['status']} | {row['steps'] / 1000:.1f} | "
            f"{row['stored']:,} | {row['rss']:.0f} | {row['peak']:.0f} |"
            for row in rows
        ),
        "",
        f"- Over {len(rows)} execution{'s' * (len(rows) > 1)} (the longest {longest:.1f} s simulated) the worker "
        f"peaked at {peak:.0f} MB: {verdict} the {BUDGET_MB:.0f} MB budget (issue 28). Of it, {idle[1]:.0f} MB "
        "before any execution (the interpreter, numpy, scipy, numba and its compiled loop, PyBullet, Zenoh).",
        f"- Then the same worker recorded a demonstration of {recording['samples']:,} samples "
        f"(`POST /demonstrations/record`, the teacher at 1 kHz): its peak rose to {recording['mb'][1]:.0f} MB, "
        f"{'within' if recording['mb'][1] <= BUDGET_MB else 'OVER'} the budget too ({recording['mb'][0]:.0f} MB "
        "resident after): the teacher's signals, the validated demonstration (lists of Python floats, ~640 bytes a "
        "sample) and its JSON reply are alive at once.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=FULL_SECONDS, help="each demonstration's motion in contact")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="times each skill runs, in turn")
    parser.add_argument("--no-write", action="store_true", help="only print the report")
    add_smoke_argument(parser, f"one {SMOKE_SECONDS:g} s slide, once")
    args = parser.parse_args(argv)
    scenarios, rounds = SCENARIOS, args.rounds
    if args.smoke:
        args.seconds, args.no_write, scenarios, rounds = SMOKE_SECONDS, True, SCENARIOS[:1], 1
    with tempfile.TemporaryDirectory(prefix="bench-worker-memory-") as tmp:
        figures = measure(args.seconds, scenarios, rounds, Path(tmp))
    text = report(figures)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)
    done = all(row["status"] == "done" for row in figures["rows"])
    return 0 if done and max(row["peak"] for row in figures["rows"]) <= BUDGET_MB else 1


if __name__ == "__main__":
    sys.exit(main())
