"""The benchmarks that start a stack of their own on loopback (``contact-skills up``, a router, workers, a browser):
each ``--smoke`` run exits 0 and prints numbers from that run, writing nothing (helpers: test_benchmarks_smoke.py;
two files so that ``pytest -n 2 --dist loadfile`` runs them beside the others)."""

from __future__ import annotations

import re

import pytest
from test_benchmarks_smoke import finite, numbers, run_smoke, table


def test_service_benchmark_smoke():
    """Learning through the API (2 requests per variant) and 2 executions with 2 workers: every execution finished,
    and the CPU sentence adds up the row it comes from."""
    out = run_smoke("bench_service.py")
    learning = table(out, "request | n")
    assert len(learning) == 3
    for row in learning[:2]:
        p50, p99, server = float(row[2]), float(row[3]), float(row[4])
        assert int(row[1]) == 2 and 0 < p50 <= p99 and 0 < server < p99, row
    runs = table(out, "workers | executions")
    assert [int(row[0]) for row in runs] == [2]
    assert int(runs[0][1]) == 2 and float(runs[0][2]) > 0 and sum(numbers(runs[0][6])) == 2, runs[0]
    workers, api, router = numbers(runs[0][5])
    total = float(re.search(r"With 2 workers an execution cost (\d+\.\d+) CPU s in all", out).group(1))
    assert total == pytest.approx(workers + api + router, abs=0.02)


def test_service_load_benchmark_smoke():
    """2 learns at once while /health is polled, and 2 executions queued on 2 workers."""
    out = run_smoke("bench_service_load.py")
    learns = table(out, "learns | 201")
    assert len(learns) == 2 and learns[1][0] == "2 at once" and learns[1][1] == "2 / 2"
    for row in learns:
        p50, p99, peak = numbers(row[7])
        assert int(row[6]) > 0 and 0 < p50 <= p99 <= peak, row
    queue = table(out, "workers | submitted")
    assert [int(row[0]) for row in queue] == [2]
    assert int(queue[0][1]) == 2 and int(queue[0][2]) == 2 and queue[0][9] == "done 2", queue[0]
    assert "2 of 2 learns answered 201" in out


def test_telemetry_benchmark_smoke():
    """One execution's telemetry at the default batch: every step accounted for (received + lost), the latency
    percentiles ordered; one abort, one worker killed, one execution on 2 workers."""
    out = run_smoke("bench_telemetry.py", timeout_s=300.0)
    rows = table(out, "batch (rows)")
    assert len(rows) == 1
    steps, received, lost = int(rows[0][1]), int(rows[0][2]), int(rows[0][3])
    assert steps > 1000 and received - int(rows[0][4]) + lost == steps, rows[0]
    p50, p99, peak = float(rows[0][6]), float(rows[0][7]), float(rows[0][8])
    assert 0 < p50 <= p99 <= peak, rows[0]
    assert re.search(r"Abort \(1 executions, pace fast", out) and "Worker SIGKILLed mid-execution (1 times)" in out
    rate = re.search(r"s simulated each\): 2 workers (\d+\.\d)/min \(", out)  # the smoke run: 2 workers only
    assert rate and float(rate.group(1)) > 0


def test_sweeps_benchmark_smoke():
    """A sweep of 1 trial per worker with 2 workers, telemetry off and stored: a row each."""
    out = run_smoke("bench_sweeps.py", timeout_s=360.0)
    rows = table(out, "workers | telemetry")
    assert [(int(row[0]), row[2]) for row in rows] == [(2, "2 (2 done)"), (2, "2 (2 done)")]
    for row in rows:
        executions, wall, per_minute = int(row[0]), float(row[3]), numbers(row[5])[0]
        assert wall > 0 and per_minute == pytest.approx(60.0 * executions / wall, rel=0.05), row
        assert finite(*(v for cell in row[3:13] for v in numbers(cell))), row  # hand-over: none with 1 trial each
    stored = [int(row[12]) for row in rows]
    assert stored[0] == 0 and stored[1] > 5000  # samples only when telemetry is stored


def test_dashboard_benchmark_smoke():
    """One page load and one realtime execution watched in headless Chromium: latencies from the run."""
    out = run_smoke("bench_dashboard.py", timeout_s=300.0)
    rows = table(out, "measure | n")
    assert len(rows) == 2
    for row in rows:
        count, p50, p99, peak = (float(x) for x in row[1:5])
        assert count >= 1 and 0 < p50 <= p99 <= peak, row
    frames = re.search(r"Live plot frames while running: (\d+\.\d) per s", out)
    assert frames and float(frames.group(1)) > 0


def test_long_run_benchmark_smoke():
    """12 s of simulated time at full pace: every step stored, none missing, the last status on the bus stored."""
    out = run_smoke("bench_long_run.py", timeout_s=300.0)
    figures = {row[0]: row[1] for row in table(out, "figure | value")}
    simulated, steps = numbers(figures["simulated time, control steps"])
    stored, missing = numbers(figures["samples stored / missing"])
    assert steps > 5000 and simulated == pytest.approx(steps / 1000.0, abs=1.0)  # s at 1 kHz, printed to the s
    assert stored == steps and missing == 0
    assert figures["final status stored by the API"] == "done (the last one on the bus)"


def test_worker_memory_benchmark_smoke():
    """One short skill executed on one worker, then one recording: the resident sets read from /proc, each peak at
    least the resident set it was read with and never below the one before."""
    out = run_smoke("bench_worker_memory.py")
    rows = table(out, "execution | skill")
    assert [row[0] for row in rows] == ["(idle, after start-up)", "slide_flat"] and rows[1][2] == "done", rows
    (idle_rss, idle_peak), (rss, peak) = ((float(row[5]), float(row[6])) for row in rows)
    assert 50 < idle_rss <= idle_peak <= peak and rss <= peak, rows
    assert int(rows[1][4].replace(",", "")) > 5000  # the telemetry stored: one sample per control step
    recorded = re.search(r"its peak rose to (\d+) MB, (within|OVER) the budget too \((\d+) MB resident after\)", out)
    assert recorded and float(recorded.group(3)) <= float(recorded.group(1)) and float(recorded.group(1)) >= peak
    budget = float(re.search(r"(within|OVER) the (\d+) MB budget", out).group(2))
    assert (recorded.group(2) == "within") == (float(recorded.group(1)) <= budget)  # the verdict from the run


def test_floods_benchmark_smoke():
    """20 slow bodies, 20 idle router connections, 3 s of /health probes each; 12 paged reads of 20 000 samples and
    3 lists: every probe and bus session counted, every read whole, the peaks read from /proc."""
    out = run_smoke("bench_floods.py", timeout_s=120.0)
    floods = table(out, "flood | held")
    assert [row[0] for row in floods] == ["quiet", "slow `POST` bodies to the API",
                                          "idle TCP connections to the Zenoh port"]  # fmt: skip
    for row in floods:
        probes, not_ok, p50, p99, peak = int(row[2]), int(row[3]), float(row[4]), float(row[5]), float(row[6])
        assert probes >= 5 and 0 <= not_ok <= probes and 0 < p50 <= p99 <= peak, row
    assert numbers(floods[1][1])[0] == 20 and numbers(floods[2][1])[0] == 20
    for row in (floods[0], floods[2]):  # the sessions opened: median <= max, none refused
        median, most = numbers(row[7])
        assert 0 < median <= most and "refused" not in row[7], row
    reads, lists = table(out, "read burst | answered")
    assert reads[1].startswith("12 of 12 whole") and lists[1] == "3 of 3 with all 6", (reads, lists)
    for row in (reads, lists):
        assert 50 < float(row[3]) <= float(row[4]) and float(row[2]) > 0, row  # peak reset to the resident set
    p99 = re.search(r"p99 of `/health` during the slow-body flood: (\d+(?:\.\d+)?) ms", out)
    assert p99 and float(p99.group(1)) == float(floods[1][5])
