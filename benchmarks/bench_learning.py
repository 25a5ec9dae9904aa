"""Benchmark: learning time and peak memory per demonstration size (1 kHz slide and contour demos).

Run from the repository root::

    .venv/bin/python benchmarks/bench_learning.py

For 2 k, 10 k and 60 k samples (2 s, 10 s, 60 s at 1 kHz) of the analytic slide and contour
demonstrations (`corpus.synthetic`): median wall time of validating the `Demonstration` (the
REST body) and of `learn_skill` (auto selection, so classification included), and the peak
memory traced by tracemalloc during learning (checks included). Target: under 0.5 s per 10 s of 1 kHz
recording (10 s in under 0.5 s, 60 s in under 3 s), memory under 1 GiB. Writes its section of docs/BENCHMARKS.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import machine_line, median_time, pin_blas_threads, report_main

pin_blas_threads()

import tracemalloc  # noqa: E402

from corpus import synthetic  # noqa: E402
from schemas import Demonstration  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402

SECTION = "bench_learning"
COMMAND = ".venv/bin/python benchmarks/bench_learning.py"
SIZES_S = (2.0, 10.0, 60.0)
TARGETS_S = {10.0: 0.5, 60.0: 3.0}
"""Learning under 0.5 s per 10 s of 1 kHz recording."""


def _body(kind: str, duration_s: float) -> dict:
    demo = (
        synthetic.plane_slide(duration_s=duration_s)
        if kind == "slide"
        else synthetic.cylinder_contour(duration_s=duration_s)
    )
    return {
        "t": demo.t.tolist(),
        "positions": demo.positions.tolist(),
        "orientations": demo.orientations.tolist(),
        "wrenches": demo.wrenches.tolist(),
    }


def _peak_memory_mib(demonstration: Demonstration) -> float:
    tracemalloc.start()
    learn_skill(demonstration)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def build_report(repeats: int) -> str:
    rows = [
        "| demo | samples | validate ms | learn ms (median) | target | peak MiB | segments | chosen (confidence) |",
        "|---|--:|--:|--:|---|--:|--:|---|",
    ]
    for kind in ("slide", "contour"):
        for duration in SIZES_S:
            body = _body(kind, duration)
            validate_s, demonstration = median_time(lambda body=body: Demonstration.model_validate(body), repeats)
            learn_s, skill = median_time(lambda d=demonstration: learn_skill(d), repeats)
            target = TARGETS_S.get(duration)
            verdict = "–" if target is None else f"< {target:g} s {'MET' if learn_s < target else 'MISSED'}"
            rows.append(
                f"| {kind} {duration:.0f} s | {len(body['t'])} | {validate_s * 1e3:.0f} | {learn_s * 1e3:.0f} | "
                f"{verdict} | {_peak_memory_mib(demonstration):.0f} | {len(skill.segments)} | "
                f"{skill.skill_type.value} ({skill.auto_selection.confidence:.3f}) |"
            )
            print(rows[-1], flush=True)
    return "\n".join(
        [
            "## Learning time and memory per demonstration size",
            "",
            f"Command: `{COMMAND}` (median of {repeats} runs; peak memory by tracemalloc during `learn_skill`).",
            "`validate` is building the pydantic `Demonstration` from a JSON-like body (what the REST API does);",
            "`learn` is `learn_skill` with `skill_type=auto`, the skill's checks included. Target: under 0.5 s per "
            "10 s of 1 kHz recording (10 s in < 0.5 s, 60 s in < 3 s), < 1 GiB.",
            "",
            *rows,
            "",
            machine_line(),
        ]
    )


def main(argv: list[str] | None = None) -> int:
    return report_main(
        __doc__.splitlines()[0],
        SECTION,
        build_report,
        argv,
        options=[("--repeats", {"type": int, "default": 5, "help": "timing repeats (median reported)"})],
    )


if __name__ == "__main__":
    raise SystemExit(main())
