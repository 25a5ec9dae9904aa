"""The dashboard: how long a telemetry sample takes from leaving the worker to being drawn in the browser, and how
long the page takes to load.

Run from the repository root::

    .venv/bin/python benchmarks/bench_dashboard.py [--executions 3] [--loads 10] [--no-write] [--smoke]

Real processes on 127.0.0.1: ``contact-skills up --workers 1`` (embedded Zenoh router, the API, a sim worker) and
the system's headless Chromium driven by Playwright (``services.dashboard.browser``). This process also holds an
independent Zenoh session subscribed to the executions' telemetry, to learn when each batch left the worker.

1. Page load: ``goto /`` until the four lists are drawn from the API (its data included), a fresh page each time.
2. Draw latency: a ``slide_flat`` skill executed with ``pace: realtime`` (1 kHz of control steps against the wall
   clock) while its page is open (``#/execution/ID``). The page logs, for every frame it draws, the stream index of
   the plot's last point and ``Date.now()`` (``window.__drawLog``); the batch holding that sample carries
   ``sent_unix_s``, the worker's wall clock when it handed the batch to the bus. Latency = drawn - sent: the router
   hop, the API storing the batch, its server-sent-events poll (every 40 ms), the browser's parsing and the next
   animation frame. Also the draw rate while the execution runs (the dashboard's target: >= 20 Hz).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import machine_line, pin_blas_threads, report_main

pin_blas_threads()

import json  # noqa: E402
import os  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from services.dashboard.browser import headless_chromium  # noqa: E402
from services.local_processes import free_port, spawn_cli, stop_process, wait_for_port  # noqa: E402

SECTION = "bench_dashboard"
COMMAND = ".venv/bin/python benchmarks/bench_dashboard.py"
RECORD = {"scenario": "slide_flat", "seed": 0, "overrides": {"move_duration_s": 2.0}}


class Departures:
    """When each telemetry batch left its worker (``sent_unix_s``), by execution and first sample, from a Zenoh
    session of its own (as any user's subscriber)."""

    def __init__(self, endpoint: str) -> None:
        from services.bus import open_session

        self.batches: dict[str, list[tuple[int, int, float]]] = {}
        self._lock = threading.Lock()
        self.session = open_session("client", connect=[endpoint], wait_s=10)
        self.subscriber = self.session.declare_subscriber("cskills/exec/*/telemetry", self._batch)

    def _batch(self, sample) -> None:
        batch = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.batches.setdefault(batch["execution_id"], []).append(
                (batch["first_sample"], len(batch["t"]), batch["sent_unix_s"])
            )

    def sent(self, execution_id: str, index: int) -> float | None:
        """When the batch holding sample ``index`` left the worker, Unix s (None: not seen on the bus)."""
        with self._lock:
            for first, n, sent in self.batches.get(execution_id, []):
                if first <= index < first + n:
                    return sent
        return None

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()


def _wait(url: str, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            health = httpx.get(f"{url}/health", timeout=2).json()
            if health["workers"]:
                return
        except (httpx.HTTPError, ValueError):
            pass
        time.sleep(0.3)
    raise TimeoutError("the stack did not come up")


def build(executions: int, loads: int) -> str:
    load = os.getloadavg()[0]  # other work on the machine shares the cores
    folder = Path(tempfile.mkdtemp(prefix="bench-dashboard-"))
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    env = {"CONTACT_SKILLS_FOXGLOVE_PORT": str(free_port())}
    up = spawn_cli(["up", "--workers", "1", "--port", str(port), "--zenoh-port", str(zenoh_port), "--db",
                    str(folder / "bench.db")], folder / "up.log", env=env)  # fmt: skip
    try:
        wait_for_port(port, 120)
        _wait(url)
        http = httpx.Client(base_url=url, timeout=120)
        demo = http.post("/demonstrations/record", json=RECORD).json()
        skill = http.post("/skills", json={"demonstration_id": demo["id"], "skill_type": "auto"}).json()
        departures = Departures(f"tcp/127.0.0.1:{zenoh_port}")
        load_s: list[float] = []
        latencies_ms: list[float] = []
        rates_hz: list[float] = []
        longest_pause_ms: list[float] = []
        with headless_chromium() as browser:
            for _ in range(loads):
                page = browser.new_page()
                start = time.perf_counter()
                page.goto(url + "/")
                page.wait_for_selector("#sweeps table")
                load_s.append(time.perf_counter() - start)
                page.close()
            for _ in range(executions):
                page = browser.new_page()
                execution = http.post("/executions", json={"skill_id": skill["id"], "pace": "realtime"}).json()
                page.goto(f"{url}/#/execution/{execution['id']}")
                page.wait_for_selector("section.live[data-ended='1']", timeout=120_000)
                log = page.evaluate("window.__drawLog")
                page.close()
                first_draw: dict[int, float] = {}
                for _, index, drawn_ms in log:
                    first_draw.setdefault(int(index), drawn_ms / 1000.0)
                running = [(index, drawn) for index, drawn in sorted(first_draw.items())]
                for index, drawn in running:
                    sent = departures.sent(execution["id"], index)
                    if sent is not None:
                        latencies_ms.append((drawn - sent) * 1000.0)
                times = np.array([drawn for _, drawn in running])
                if times.size > 2:
                    rates_hz.append((times.size - 1) / (times[-1] - times[0]))
                    longest_pause_ms.append(float(np.max(np.diff(times))) * 1000.0)
        departures.close()
        http.close()
    finally:
        stop_process(up, 40)
    latency = np.array(latencies_ms)
    loads_ms = np.array(load_s) * 1000.0
    rows = [
        "| measure | n | p50 | p99 | max |",
        "| --- | ---: | ---: | ---: | ---: |",
        f"| page load: `/` until the four lists are drawn, ms | {loads_ms.size} | {np.percentile(loads_ms, 50):.0f} | "
        f"{np.percentile(loads_ms, 99):.0f} | {loads_ms.max():.0f} |",
        f"| sample left the worker -> drawn in the live plot, ms | {latency.size} | {np.percentile(latency, 50):.1f} | "
        f"{np.percentile(latency, 99):.1f} | {latency.max():.1f} |",
    ]
    return "\n".join(
        [
            "## Dashboard: telemetry to the browser, page load",
            "",
            f"Reproduce: `{COMMAND}`. Real processes on 127.0.0.1: `contact-skills up --workers 1` and "
            "the system's headless Chromium (Playwright). Skill: `slide_flat` recorded by the worker (seed 0, move "
            f"2 s), learned, run {executions} times with `pace: realtime` while its live page is open. Latency: for "
            "every frame the page draws, from its last sample's batch `sent_unix_s` (the worker's clock when the "
            "batch left it, seen by an independent Zenoh subscriber) to the page's `Date.now()` after drawing: the "
            "router hop, the API storing it, its server-sent-events poll (40 ms), the browser's parsing and the next "
            "animation frame.",
            "",
            *rows,
            "",
            f"- Live plot frames while running: {', '.join(f'{r:.1f}' for r in rates_hz)} per s (target >= 20); "
            f"longest pause between two frames {max(longest_pause_ms, default=float('nan')):.0f} ms.",
            "",
            machine_line("the API, the router, the worker and Chromium on 2 shared cores", load_at_start=load),
        ]
    )


def main(argv: list[str] | None = None) -> int:
    return report_main(
        __doc__.split("\n\n")[0],
        SECTION,
        build,
        argv,
        options=[
            ("--executions", {"type": int, "default": 3, "help": "realtime executions watched"}),
            ("--loads", {"type": int, "default": 10, "help": "page loads timed"}),
        ],
        smoke={"executions": 1, "loads": 1},
    )


if __name__ == "__main__":
    sys.exit(main())
