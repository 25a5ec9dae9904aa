"""Shared by the benchmark scripts: timing, the machine line, the command line, and writing one section of
docs/BENCHMARKS.md.

Each script owns the section between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->`` and
replaces only that, so scripts can be re-run independently. Every script takes ``--smoke``: its smallest run that
still goes through the whole script (tiny sizes, one repeat), printing the report computed from that run and writing
nothing (``make test`` runs each so, tests/test_benchmarks_smoke*.py); ``make bench`` runs each in its full mode.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from services import doc_sections
from services import machine as _machine

__all__ = [
    "BENCHMARKS_MD",
    "ROOT",
    "add_smoke_argument",
    "machine_line",
    "median_time",
    "pin_blas_threads",
    "report_main",
    "report_text",
    "write_section",
]

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS_MD = ROOT / "docs" / "BENCHMARKS.md"
LEARNING_MD = ROOT / "docs" / "LEARNING.md"
"""The learning page: the corpus and KU Leuven benchmarks write their sections there."""


def pin_blas_threads() -> None:
    """Use one BLAS thread: on a small shared machine a multi-threaded BLAS is 10-20x slower under contention.

    Call before numpy is imported.
    """
    from services.local_processes import THREAD_LIMIT_ENV  # (imports no numpy)

    for var, value in THREAD_LIMIT_ENV.items():
        os.environ.setdefault(var, value)


def machine_line(extra: str = "", load_at_start: float | None = None) -> str:
    """The machine line (`services.machine.machine_line`, with ``extra``) and the load the run came from: the 1-minute
    load average now, at the end of the run (and ``load_at_start`` when the script took it before), on a machine
    shared with other jobs."""
    now = os.getloadavg()[0]
    load = (
        f"1-minute load average {now:.1f} at the end of the run"
        if load_at_start is None
        else f"1-minute load average {load_at_start:.1f} at the start of the run, {now:.1f} at its end"
    )
    return _machine.machine_line(f"{extra}; {load}" if extra else load)


def report_text(lines: Sequence[str], load_at_start: float | None = None) -> str:
    """A benchmark's report: its ``lines``, a blank line and the machine line (:func:`machine_line`, with the load
    average ``load_at_start`` when the script took it before its run), one to a line."""
    return "\n".join([*lines, "", machine_line(load_at_start=load_at_start)])


def add_smoke_argument(parser: argparse.ArgumentParser, smallest: str) -> None:
    """Add ``--smoke`` to a benchmark's ``parser``: ``smallest`` says what that run is (the script sets it)."""
    parser.add_argument(
        "--smoke",
        action="store_true",
        help=f"the smallest run through the whole script ({smallest}): prints its report, writes nothing",
    )


def median_time(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """Return the median wall time (s) of ``repeats`` calls of ``fn`` and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def report_main(
    description: str,
    section: str,
    build: Callable[..., str],
    argv: list[str] | None = None,
    path: Path = BENCHMARKS_MD,
    options: Sequence[tuple[str, dict[str, Any]]] = (),
    *,
    smoke: Mapping[str, Any],
) -> int:
    """The command line of a benchmark that builds one report section: its ``options`` (a flag and its
    ``argparse`` keywords; their values go to ``build`` by name), ``--no-write`` and ``--smoke`` (the values of
    ``smoke`` replace those of the options: the smallest run; nothing is written). Prints the report ``build``
    returns and writes it into ``path`` between the ``section`` markers. Returns the exit code."""
    parser = argparse.ArgumentParser(description=description)
    for flag, keywords in options:
        parser.add_argument(flag, **keywords)
    parser.add_argument("--no-write", action="store_true", help=f"only print the report; leave {path.name} alone")
    add_smoke_argument(parser, ", ".join(f"{name} {value}" for name, value in smoke.items()) or "as it is")
    arguments = vars(parser.parse_args(argv))
    write = not arguments.pop("no_write")
    if arguments.pop("smoke"):
        arguments.update(smoke)
        write = False
    report = build(**arguments)
    print(report)
    if write:
        write_section(section, report, path)
    return 0


def write_section(name: str, body: str, path: Path = BENCHMARKS_MD) -> None:
    """Replace (or append) the section between the ``name`` markers in ``path``; keep everything else."""
    doc_sections.write_section(path, name, body, title="# Benchmarks\n")


def machine_speed() -> dict[str, float]:
    """µs of two fixed workloads, best of 5 (a shared or throttled machine drifts by 2x between days): CPython
    ``sum(range(1000))`` and one PyBullet step of the arm at rest in the flat-table world, gravity off (nothing
    moves, nothing touches: the same work every step)."""
    import timeit

    import pybullet

    from schemas.world import WorldConfig
    from sim_worker.world import SimWorld

    python = min(timeit.repeat("sum(range(1000))", number=2000, repeat=5)) / 2000 * 1e6
    with SimWorld(WorldConfig()) as world:
        cid = world.client_id
        pybullet.setGravity(0.0, 0.0, 0.0, physicsClientId=cid)

        def steps(n: int = 2000) -> float:
            start = time.perf_counter()
            for _ in range(n):
                pybullet.stepSimulation(physicsClientId=cid)
            return (time.perf_counter() - start) / n * 1e6

        physics = min(steps() for _ in range(5))
    return {"python": python, "physics": physics}
