"""Executing skills learned from real recordings on their rebuilt, placed work piece: force, contact, placement.

The four KU Leuven contour recordings (``data/kuleuven_contour``, another lab's tracker frame 1-2 m from our
robot) are imported as the README says, learned with ``skill_type=auto``, placed and run with ``hybrid_cf`` and
the realistic wrist sensor, at the rebuilt surface and with the surface 2 cm higher than learned (unknown to the
controller). The rebuilt work piece is the only truth there is for a real recording: the TRUE normal force is
judged on it, so these figures say how well the skill runs on the surface it learned, not on the real part.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import ROOT, pin_blas_threads, report_main, report_text

pin_blas_threads()

from schemas import ExecutionSettings  # noqa: E402
from schemas.import_options import CsvImportOptions  # noqa: E402
from services.csv_import import demonstration_from_csv  # noqa: E402
from services.datasets import KULEUVEN_IMPORT  # noqa: E402
from sim_worker.execution_world import execution_world  # noqa: E402
from sim_worker.executor import run_skill  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402

SECTION = "real-skills"
COMMAND = ".venv/bin/python benchmarks/bench_real_skills.py"
TRIALS = ("contour_a_1", "contour_a_2", "contour_b_1", "contour_b_2")
IMPORT = KULEUVEN_IMPORT


def _rows(trials: list[str]) -> list[dict]:
    rows = []
    for trial in trials:
        skill = learn_skill(
            demonstration_from_csv(ROOT / "data" / "kuleuven_contour" / f"{trial}.csv", CsvImportOptions(**IMPORT))
        )
        for dz in (0.0, 0.02):
            settings = ExecutionSettings(environment={"unknown_offset": [0.0, 0.0, dz]})
            started = time.perf_counter()
            world = execution_world(skill, settings.environment)
            placed_s = time.perf_counter() - started
            result = run_skill(world, settings)
            m = result.metrics
            rows.append(
                {
                    "trial": trial,
                    "dz": dz,
                    "phase": m.phase.value,
                    "cf_z": m.force_rms_error_pct,
                    "true": m.true_force_rms_error_pct,
                    "true_max": m.true_force_max_error_pct,
                    "contact": m.contact_ratio,
                    "touchdown": m.touchdown_peak_ratio,
                    "angle": m.cf_normal_angle_deg,
                    "parts": len(world.config.work_pieces),
                    "place_s": placed_s,
                    "rtf": m.real_time_factor,
                    "reason": world.placement_reason,
                }
            )
            print(f"{trial} +{dz * 100:.0f} cm: {m.phase.value}, true RMS {m.true_force_rms_error_pct:.2f} %")
    return rows


def build_report(trials: list[str]) -> str:
    """The report over the KU Leuven recordings ``trials`` (names of `TRIALS`)."""
    rows = _rows(trials)
    table = [
        "| trial | unknown shift | final | CF-z RMS % | true RMS % | true max % | contact % | touch-down × | "
        "CF-normal angle ° | parts | placement s | real-time × |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        table.append(
            f"| {r['trial']} | +{r['dz'] * 100:.0f} cm | {r['phase']} | {r['cf_z']:.2f} | {r['true']:.2f} | "
            f"{r['true_max']:.1f} | {100 * r['contact']:.1f} | {r['touchdown']:.2f} | {r['angle']:.2f} | "
            f"{r['parts']} | {r['place_s']:.2f} | {r['rtf']:.1f} |"
        )
    done = [r for r in rows if r["phase"] == "done"]
    within = [r for r in done if r["cf_z"] <= 10.0 and r["contact"] >= 0.95]
    sentences = [
        f"{len(done)} of {len(rows)} executions finished; {len(within)} of {len(rows)} kept the CF-z force RMS within "
        "10 % of the profile peak with at least 95 % contact (the target of `tests/test_execute_any_skill.py`).",
        f"True normal force RMS: median {statistics.median(r['true'] for r in rows):.2f} %, worst "
        f"{max(r['true'] for r in rows):.2f} %; placement (inverse kinematics over the path): median "
        f"{statistics.median(r['place_s'] for r in rows):.2f} s.",
        f"Placement chosen for {rows[0]['trial']}: {rows[0]['reason']}.",
    ]
    return report_text(
        [
            "## Skills learned from real recordings, executed on their rebuilt work piece",
            "",
            f"Command: `{COMMAND}` ({_trials_text(trials)}, `hybrid_cf`, the realistic wrist sensor).",
            "The true normal force is judged on the rebuilt work piece, the only geometry known for a real recording; "
            "these rows say how a skill runs on the surface it learned, not on the real part. Real-time factors depend "
            "on the load of the machine at the time.",
            "",
            *table,
            "",
            *sentences,
        ]
    )


def _trials_text(trials: list[str]) -> str:
    """How the command line names the recordings run: the four of the full run, or the ones given."""
    return "the four KU Leuven trials" if list(trials) == list(TRIALS) else f"--trials {' '.join(trials)}"


OPTIONS = [("--trials", {"nargs": "+", "default": list(TRIALS), "choices": TRIALS, "help": "KU recordings"})]
"""The options of the command line (`benchmarks.report.report_main`): a flag and its ``argparse`` keywords."""
SMOKE = {"trials": TRIALS[:1]}
"""The smoke run's values of the options: one recording (its two executions); the four run the same code on other
data."""


def main(argv: list[str] | None = None) -> int:
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, options=OPTIONS, smoke=SMOKE)


if __name__ == "__main__":
    raise SystemExit(main())
