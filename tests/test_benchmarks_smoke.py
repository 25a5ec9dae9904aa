"""Every benchmark runs: its ``--smoke`` run (the smallest that goes through the whole script) exits 0, prints its
report with numbers computed from that run, and writes nothing into docs/ (issue 28, "benchmarks that cannot rot").

The benchmarks that start a stack of their own (``contact-skills up``, a router, workers) are in
tests/test_benchmarks_smoke_stack.py, those that execute skills on work pieces, the CAD and changed parts in
tests/test_benchmarks_smoke_parts.py: ``pytest -n 2 --dist loadfile`` runs a file in one process, and three files of
similar cost spread over both.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def run_smoke(script: str, timeout_s: float = 240.0) -> str:
    """Run ``benchmarks/<script> --smoke`` as its own process; return its output after checking it exited 0, gave
    the machine line with its load, and left every page of docs/ as it was (nothing written: same bytes, same
    modification time; a page holding the same text is no evidence either way, since a deterministic report can
    print what a full run wrote before)."""
    pages_before = docs_pages()
    result = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), "--smoke"],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
    assert result.returncode == 0, f"{script} --smoke exited {result.returncode}:\n{result.stderr[-4000:]}"
    out = result.stdout
    machine = next((line for line in out.splitlines() if "Machine: nproc=" in line), None)
    assert machine is not None and re.search(r"1-minute load average \d+\.\d", machine), out[-2000:]
    pages_after = docs_pages()
    changed = sorted(
        name for name in pages_before.keys() | pages_after.keys() if pages_before.get(name) != pages_after.get(name)
    )
    assert not changed, f"{script} --smoke wrote into {', '.join(changed)}"
    return out


def docs_pages() -> dict[str, tuple[int, bytes]]:
    """Every page of docs/ by name: its modification time (ns) and its bytes."""
    return {page.name: (page.stat().st_mtime_ns, page.read_bytes()) for page in DOCS.glob("*.md")}


def table(out: str, header: str) -> list[list[str]]:
    """The body rows (cells, stripped) of the first markdown table in ``out`` whose header line starts with
    ``| header``; fails when there is none or it is empty."""
    return tables(out, header)[0]


def tables(out: str, header: str) -> list[list[list[str]]]:
    """The body rows (cells, stripped) of every markdown table in ``out`` whose header line starts with ``| header``,
    in order; fails when there is none or one is empty."""
    lines = out.splitlines()
    starts = [k for k, line in enumerate(lines) if line.startswith(f"| {header}")]
    assert starts, f"no table headed {header!r} in:\n{out[-3000:]}"
    found = []
    for start in starts:
        rows = []
        for line in lines[start + 2 :]:
            if not line.startswith("|"):
                break
            rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
        assert rows, f"table {header!r} has no rows"
        found.append(rows)
    return found


def numbers(cell: str) -> list[float]:
    """The numbers in a table cell (``"1.04 / 2.7 (94 % contact)"`` -> [1.04, 2.7, 94.0])."""
    return [float(x) for x in NUMBER.findall(cell.replace(",", ""))]


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def test_every_benchmark_has_a_smoke_test_and_a_line_in_make_bench():
    """A new benchmark cannot be left out: each ``benchmarks/bench_*.py`` is smoke-run by one of the smoke test files
    (tests/test_benchmarks_smoke*.py) and run in its full mode by ``make bench``."""
    scripts = sorted(p.name for p in (ROOT / "benchmarks").glob("bench_*.py"))
    tests = "".join(path.read_text() for path in (ROOT / "tests").glob("test_benchmarks_smoke*.py"))
    make_bench = (ROOT / "Makefile").read_text().split("\nbench:", 1)[1].split("\n\n", 1)[0]
    assert len(scripts) > 10
    assert [s for s in scripts if f'run_smoke("{s}"' not in tests] == []
    assert [s for s in scripts if f"benchmarks/{s}" not in make_bench] == []


def test_learning_benchmark_smoke():
    """Sizes and strokes tables from the run: 1 and 5 strokes of the same length, one contact segment per stroke,
    the time per sample the learning time over the samples, the exponent the fit through them."""
    out = run_smoke("bench_learning.py")
    sizes = table(out, "demo | samples")
    assert [row[0] for row in sizes] == ["slide 2 s", "contour 2 s"] and {row[1] for row in sizes} == {"2000"}
    for row in sizes:
        assert float(row[3]) > 0 and int(row[6]) >= 3, row  # learn ms; segments: free, contact, free at least
    strokes = table(out, "strokes | samples")
    assert [int(row[0]) for row in strokes] == [1, 5]
    one, five = (int(row[1]) for row in strokes)
    assert five == 5 * one + 4 * 150  # 4 moves of 0.6 s at 250 Hz between the strokes
    for row in strokes:
        count, samples, contact = (int(cell) for cell in row[:3])
        seconds, per_sample = float(row[3]), float(row[4])
        assert contact == count, row
        rounding = 0.0005 / samples * 1e6 + 0.05  # µs: the seconds printed to 1 ms, the µs to 0.1
        assert seconds > 0 and per_sample == pytest.approx(seconds / samples * 1e6, abs=rounding), row
    assert float(strokes[0][5]) == 1.0
    k = float(re.search(r"From 1 to 5 strokes the time per sample lies within .* µs, .* k = (\d\.\d\d)", out).group(1))
    (n1, s1), (n5, s5) = ((int(row[1]), float(row[3])) for row in strokes)
    assert k == pytest.approx(math.log(s5 / s1) / math.log(n5 / n1), abs=0.05)  # the fit through the two rows


def test_toolchain_benchmark_smoke():
    """A 5 s bag imported from MCAP and sqlite3 (every message counted), a real execution exported in three formats."""
    out = run_smoke("bench_toolchain.py")
    imports = table(out, "bag storage")
    assert [row[0] for row in imports] == ["mcap", "sqlite3"]
    for row in imports:
        messages, samples, seconds = int(row[1]), int(row[3]), float(row[4])
        assert messages >= 2 * 4990 and 4990 <= samples <= 5000 and seconds > 0, row  # 2 topics at 1 kHz for 5 s
    exports = table(out, "format | samples")
    assert [row[0] for row in exports] == ["mcap", "csv", "json"]
    for row in exports:
        samples, megabytes, per_sample = int(row[1]), float(row[2]), float(row[3])
        assert samples > 1000 and megabytes * 1e6 / samples == pytest.approx(per_sample, rel=0.05, abs=1), row
    assert "A 5 s bag at 1 kHz imports in" in out and "A 2 s execution exports as MCAP in" in out


def test_dmp_peer_benchmark_smoke():
    """Ours fitted and rolled out on every trajectory, the errors and times from the run (the peer itself may be
    missing: the report says so)."""
    out = run_smoke("bench_dmp_peer.py")
    rows = [line for line in out.splitlines() if line.startswith("| ") and "ours" in line.lower()]
    assert rows, out[-3000:]
    values = [v for line in rows for cell in line.split("|")[2:] for v in numbers(cell)]
    assert values and finite(*values) and max(values) > 0


def test_kinesthetic_benchmark_smoke():
    """One recording per surface learned against its truth: the sentences count the rows of the table."""
    out = run_smoke("bench_kinesthetic.py")
    rows = table(out, "surface (truth)")
    assert [row[0] for row in rows] == ["flat", "tilted", "curved"] and all(row[1] == "1" for row in rows)
    right = sum(int(row[2]) for row in rows)
    assert f"{right} of 3 recordings got the true type" in out


def test_corpus_benchmark_smoke():
    """Seed 0 of every family: cases counted per family, errors finite."""
    out = run_smoke("bench_corpus.py")
    rows = table(out, "family")
    assert len(rows) >= 10
    for row in rows:
        cases = int(row[1])
        assert cases >= 1 and all(0 <= int(row[k]) <= cases for k in (2, 3, 4)), row
        assert finite(*(v for cell in row[5:] for v in numbers(cell))), row


def test_learning_sources_benchmark_smoke():
    """One seed of each force-source family, tuned on and held out: every case counted in exactly one outcome; of
    those tuned on (the first table) none confidently wrong, and the estimated-wrench wipes' CF z within the issue's
    5° (median) / 10° (max) of the surface normal. (The held-out cases are reported, not held to anything here.)"""
    out = run_smoke("bench_learning_sources.py", timeout_s=400.0)
    rows = table(out, "family")
    assert len(rows) >= 10
    for row in rows:
        counts = [int(cell) for cell in row[2:7]]
        assert sum(counts) == int(row[1]) and row[5] == "0", row  # the confidently wrong column
    tuned_wipes = [row for row in table(out, "case") if row[0] in ("lwr-wipe-patch-s0", "lwr-wipe-strip-s0")]
    assert len(tuned_wipes) == 2
    for row in tuned_wipes:
        median, largest = numbers(row[2])
        assert median < 5.0 and largest < 10.0, row


def test_joint_learning_benchmark_smoke():
    """Task 0 of each corpus kind, each trial left out of four: on the straight strokes, the left-out trial's true
    press within the band learned from the other three for >= 90 % of its contact and the joint CF error no larger
    than the best single trial's, every time; a trial of another task named, weighted 0, and the joint segments as
    without it; two flat slides learned together and executed pass, in their band for >= 90 % of the contact; the
    cost table's times from the run."""
    out = run_smoke("bench_joint_learning.py", timeout_s=400.0)
    rows = table(out, "left out")
    straight = [row for row in rows if row[0].startswith("human-straight-task0-t")]
    assert len(straight) == 4
    for row in straight:
        assert numbers(row[1])[0] >= 90 and row[4] == "yes" and row[5].startswith("right"), row
    strangers = table(out, "set")
    assert len(strangers) == 2
    for row in strangers:
        assert row[1].startswith(("another_place", "another_surface")) and row[2] == "0.00" and row[3] == "yes", row
    [executed] = table(out, "scenario")
    assert executed[0] == "slide_flat" and executed[4] == "pass" and numbers(executed[5])[0] >= 90, executed
    for row in table(out, "trials of"):
        assert finite(*numbers(" ".join(row[1:]))) and numbers(row[6])[0] > 0, row


def test_gain_schedule_benchmark_smoke():
    """A 2 s flat slide recorded by two hands and learned together, executed with each gain schedule, as taught and
    with the friction tripled: every run passes with its true force within 15 %; constant holds the configured
    3000 N/m, from_spread schedules between the floor (a quarter) and it."""
    out = run_smoke("bench_gain_schedule.py")
    rows = table(out, "scenario | condition")
    assert [(row[1], row[2]) for row in rows] == [
        (condition, schedule)
        for condition in ("table 2 cm higher", "and friction 0.6")
        for schedule in ("constant", "from_spread")
    ]
    for row in rows:
        least, median = numbers(row[3])
        force, path = numbers(row[4])[0], numbers(row[5])[0]
        assert row[6] == "pass" and finite(force, path) and force < 15.0, row
        if row[2] == "constant":
            assert least == median == 3000.0, row
        else:
            assert 750.0 <= least <= median <= 3000.0, row


def test_control_loop_benchmark_smoke():
    """The control loop's real-time factors, from the run. (``--smoke`` is the control loop's owner's to add.)"""
    out = run_smoke("bench_control_loop.py", timeout_s=300.0)
    rows = [line for line in out.splitlines() if line.startswith("| ") and ("ideal" in line or "wrist" in line)]
    assert rows, out[-3000:]
    values = [v for line in rows for v in numbers(line)]
    assert finite(*values) and max(values) > 1
    # The model update's cost in its parts, per sensor, from the run: its own call costs more than a row-and-law step
    # (the mass matrix and the projector's LAPACK), and the parts add up to the total printed.
    parts = re.findall(
        r"(ideal|wrist): its own call (-?[\d.]+) µs more than a row-and-law step, the physics step right after it "
        r"([+-][\d.]+) µs and the next step's sensing ([+-][\d.]+) µs against settled steps, ([\d.]+) µs in all",
        out,
    )
    assert [p[0] for p in parts] == ["ideal", "wrist"], out[-3000:]
    for _, own, physics, sensing, total in parts:
        assert float(own) > 0 and abs(float(own) + float(physics) + float(sensing) - float(total)) < 0.15
    # The project beside both floors (PyBullet's Python API, its C API from compiled code), per sensor, from the run;
    # the bare loops and the project saw the same physics (the same steps in contact) with either API.
    floors = re.findall(r"(ideal|wrist): ([\d.]+)x the Python-API bare loop, ([\d.]+)x the C-API one", out)
    assert [f[0] for f in floors] == ["ideal", "wrist"], out[-3000:]
    assert all(float(python_ratio) > 0 and float(c_ratio) > 0 for _, python_ratio, c_ratio in floors), floors
    same_physics = re.findall(r"^\| (ideal|wrist) \| \d+ \(\d+\) \| (yes|NO) \|", out, flags=re.MULTILINE)
    assert same_physics == [("ideal", "yes"), ("wrist", "yes")], out[-3000:]
