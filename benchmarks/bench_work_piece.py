"""Benchmark: what the work piece a skill runs on adds to its true-force error, measured from the demonstration
(``sim_worker.work_piece.measured_work_pieces``) or rebuilt from the skill (``rebuilt_work_pieces``).

Run from the repository root::

    .venv/bin/python benchmarks/bench_work_piece.py

The ground-truth corpus's analytic cases (`corpus.families`), whose surfaces are known exactly: flat strokes (the
floor: the same skill on the ideal table and on the piece) and contours across cylinders of 5-30 cm (the piece
against the simulator's own cylinder primitive), each learned as it is and as the other type. Every skill is placed
as ``sim_worker.execution_world`` places it (the true world moved with it) and run with ``hybrid_cf`` and the
realistic wrist sensor. Then the four KU Leuven recordings (no exact truth here: their measured piece against the
slab or strip their skill rebuilds). Writes its section of docs/LEARNING.md.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import LEARNING_MD, ROOT, pin_blas_threads, report_main, report_text

pin_blas_threads()

import numpy as np  # noqa: E402

from corpus.case import CorpusCase  # noqa: E402
from corpus.families import cylinder_case, plane_case  # noqa: E402
from schemas import EnvironmentChange, ExecutionSettings, LearnOptions  # noqa: E402
from schemas.execution import ExecutionMetrics  # noqa: E402
from schemas.import_options import CsvImportOptions  # noqa: E402
from schemas.world import WorldConfig  # noqa: E402
from services.csv_import import demonstration_from_csv  # noqa: E402
from services.datasets import KULEUVEN_IMPORT  # noqa: E402
from sim_worker.execution_world import ExecutionWorld, execution_world  # noqa: E402
from sim_worker.executor import run_skill  # noqa: E402
from sim_worker.geometry import WorldGeometry  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402
from skills.quaternions import matrix_from_quaternion  # noqa: E402

SECTION = "work-piece"
COMMAND = ".venv/bin/python benchmarks/bench_work_piece.py"
FLAT_CASES = (("straight", 1), ("straight", 2), ("circle", 1), ("zigzag", 1))
"""Flat plane cases (shape, seed) of `corpus.families.plane_case`."""
CYLINDER_RADII_M = (0.05, 0.08, 0.15, 0.30)
KU_TRIALS = ("contour_a_1", "contour_a_2", "contour_b_1", "contour_b_2")
KU_IMPORT = KULEUVEN_IMPORT


@dataclass(frozen=True)
class Run:
    """One execution's true normal force error (RMS and max, % of the reference) and contact share."""

    rms: float
    max: float
    contact: float
    parts: int

    @classmethod
    def of(cls, world: ExecutionWorld, metrics: ExecutionMetrics) -> Run:
        if metrics.phase.value != "done" or metrics.true_force_rms_error_pct is None:
            raise RuntimeError(f"{world.source}: {metrics.phase.value} ({metrics.abort_reason})")
        rms, peak = metrics.true_force_rms_error_pct, metrics.true_force_max_error_pct
        return cls(rms, peak or 0.0, metrics.contact_ratio or 0.0, len(world.config.work_pieces))

    def text(self) -> str:
        contact = "" if self.contact >= 0.995 else f" ({100 * self.contact:.0f} % contact)"
        return f"{self.rms:.2f} / {self.max:.1f}{contact}"


def _run(world: ExecutionWorld) -> Run:
    return Run.of(world, run_skill(world, ExecutionSettings()).metrics)


def _true_surface(case: CorpusCase) -> tuple[np.ndarray, np.ndarray]:
    """The true surface points (M, 3) under the case's contact and their inward normals (M, 3), the case's frame."""
    c = case.in_contact
    sink = case.normal_force_n[c] / case.parameters["pad_stiffness_n_m"]
    return case.positions[c] - sink[:, None] * case.normals[c], case.normals[c]


def _true_world(case: CorpusCase, placed: ExecutionWorld) -> WorldConfig:
    """The case's exact surface (a table, or a cylinder primitive) moved by ``placed``'s placement."""
    assert placed.placement is not None
    R = matrix_from_quaternion(np.asarray(placed.placement.rotation))
    points, normals = _true_surface(case)
    points, normals = points @ R.T + placed.placement.translation_m, normals @ R.T
    if case.family != "cylinder":
        if normals.mean(axis=0)[2] > -0.999:
            raise ValueError(f"{case.name}: the placement tilted the table")
        return WorldConfig(table_height_m=float(np.median(points[:, 2])), table_center_xy=tuple(points[:, :2].mean(0)))
    radius = case.parameters["radius_m"]
    axis = np.linalg.svd(normals, full_matrices=False)[2][2]
    if abs(axis[2]) > 1e-3:
        raise ValueError(f"{case.name}: the placement tilted the cylinder")
    yaw = float(np.degrees(np.arctan2(axis[1], axis[0]))) + 90.0  # the world's cylinder lies along its body y
    base = WorldConfig(table_enabled=False, cylinder_enabled=True, cylinder_radius_m=radius, cylinder_yaw_deg=yaw)
    geometry = WorldGeometry(base)
    centre = (points + radius * normals).mean(axis=0)
    offset = centre - (geometry.table_point(0.0, 0.0) + radius * geometry.table_normal)
    return base.replace(cylinder_offset_m=tuple(offset.tolist()))


def _case_rows(case: CorpusCase, other_type: str) -> list[dict]:
    """The case's skill learned as it is (auto) and forced to ``other_type``, each on the truth and both pieces."""
    demonstration = case.demonstration()
    learned = {"auto": learn_skill(demonstration)}
    learned[other_type] = learn_skill(demonstration, LearnOptions(skill_type=other_type))
    rows = []
    for asked, skill in learned.items():
        measured = execution_world(skill, demonstration=demonstration)
        truth = execution_world(measured.skill, world=_true_world(case, measured).to_dict())
        rebuilt = execution_world(skill, EnvironmentChange(work_piece="rebuilt"), demonstration=demonstration)
        rows.append(
            {
                "case": case.name,
                "learned": f"{skill.skill_type.value}{'' if asked == 'auto' else ' (forced)'}",
                "truth": _run(truth),
                "measured": _run(measured),
                "rebuilt": _run(rebuilt),
            }
        )
        print(f"{case.name} {rows[-1]['learned']}: true {rows[-1]['truth'].text()}, "
              f"measured {rows[-1]['measured'].text()}, rebuilt {rows[-1]['rebuilt'].text()}")  # fmt: skip
    return rows


def _ku_rows(trials: list[str]) -> list[dict]:
    rows = []
    for trial in trials:
        path = ROOT / "data" / "kuleuven_contour" / f"{trial}.csv"
        demonstration = demonstration_from_csv(path, CsvImportOptions(**KU_IMPORT))
        for asked in ("auto", "slide"):
            skill = learn_skill(demonstration, LearnOptions(skill_type=asked))
            runs = {
                source: _run(execution_world(skill, EnvironmentChange(work_piece=source), demonstration=demonstration))
                for source in ("measured", "rebuilt")
            }
            learned = skill.skill_type.value + ("" if asked == "auto" else " (forced)")
            rows.append({"case": trial, "learned": learned, **runs})
            print(f"{trial} {learned}: measured {runs['measured'].text()}, rebuilt {runs['rebuilt'].text()}")
    return rows


def _table(rows: list[dict], columns: list[tuple[str, str]]) -> list[str]:
    lines = [
        "| case | learned as | " + " | ".join(title for title, _ in columns) + " |",
        "| --- | --- | " + " | ".join("---" for _ in columns) + " |",
    ]
    for r in rows:
        cells = []
        for _, key in columns:
            value = r[key]
            cells.append(value.text() if isinstance(value, Run) else value)
        lines.append(f"| {r['case']} | {r['learned']} | " + " | ".join(cells) + " |")
    return lines


def _added(rows: list[dict], key: str) -> tuple[float, float]:
    """The largest RMS and max (percentage points) the ``key`` piece adds to the truth's over ``rows``."""
    return (
        max(r[key].rms - r["truth"].rms for r in rows),
        max(r[key].max - r["truth"].max for r in rows),
    )


def build_report(flat_cases: int, radii: list[float], ku_trials: list[str]) -> str:
    """The report over the first ``flat_cases`` of `FLAT_CASES`, the cylinders of ``radii`` (m) and the KU Leuven
    recordings ``ku_trials``."""
    started = time.perf_counter()
    cases = FLAT_CASES[:flat_cases]
    flat = [row for shape, seed in cases for row in _case_rows(plane_case(shape, 0.0, seed), "contour")]
    curved = [row for radius in radii for row in _case_rows(cylinder_case(radius, 0), "slide")]
    ku = _ku_rows(ku_trials)
    for r in flat:
        r["added"] = f"{r['measured'].rms - r['truth'].rms:+.2f} / {r['measured'].max - r['truth'].max:+.1f}"
    elapsed = time.perf_counter() - started
    floor_rms, floor_max = _added(flat, "measured")
    old_rms, old_max = _added([r for r in flat if r["learned"].startswith("contour")], "rebuilt")
    right = [r for r in curved if not r["learned"].endswith("(forced)")]
    wrong = [r for r in curved if r["learned"].endswith("(forced)")]
    truth_columns = [("ideal table", "truth"), ("measured", "measured"), ("added", "added"), ("rebuilt", "rebuilt")]
    curved_columns = [("true cylinder", "truth"), ("measured", "measured"), ("rebuilt", "rebuilt")]
    return report_text(
        [
            f"Command: `{COMMAND}` ({elapsed:.0f} s). True normal force error, RMS / max in % of the reference force "
            "(`ExecutionMetrics.true_force_*`), `hybrid_cf`, the realistic wrist sensor; each skill placed as "
            "`execution_world` places it, the true world moved with it. *measured*: the work piece measured from "
            "the demonstration (the default when it is given); *rebuilt*: rebuilt from what the skill learned (the "
            "fallback without it).",
            "",
            "Flat strokes (corpus plane cases at 0°): the floor, the same skill on the ideal table and on its piece.",
            "",
            *_table(flat, truth_columns),
            "",
            f"The measured piece adds at most {floor_rms:+.2f} % RMS and {floor_max:+.1f} % max to the ideal table "
            f"(a slab: the table itself); the strip rebuilt from a contour's frames added up to {old_rms:+.2f} % RMS "
            f"and {old_max:+.1f} % max on the same flat strokes.",
            "",
            "Contours across cylinders (corpus cylinder cases, the normal turning 40-90°), learned as they are and "
            "forced to a slide:",
            "",
            *_table(curved, curved_columns),
            "",
            f"Learned right, on the measured piece: {min(r['measured'].rms for r in right):.2f}-"
            f"{max(r['measured'].rms for r in right):.2f} % RMS (on the true cylinder "
            f"{min(r['truth'].rms for r in right):.2f}-{max(r['truth'].rms for r in right):.2f} %); forced to a "
            f"slide: {min(r['measured'].rms for r in wrong):.1f}-{max(r['measured'].rms for r in wrong):.1f} % "
            f"(true {min(r['truth'].rms for r in wrong):.1f}-{max(r['truth'].rms for r in wrong):.1f} %), where its "
            f"own rebuilt slab showed {min(r['rebuilt'].rms for r in wrong):.2f}-"
            f"{max(r['rebuilt'].rms for r in wrong):.2f} %.",
            "",
            "The KU Leuven recordings (no exact truth in the simulator):",
            "",
            *_table(ku, [("measured", "measured"), ("rebuilt", "rebuilt")]),
        ]
    )


OPTIONS = [
    ("--flat-cases", {"type": int, "default": len(FLAT_CASES), "help": "how many of the flat cases to run"}),
    ("--radii", {"type": float, "nargs": "+", "default": list(CYLINDER_RADII_M), "help": "cylinder radii, m"}),
    ("--ku-trials", {"nargs": "+", "default": list(KU_TRIALS), "choices": KU_TRIALS, "help": "KU recordings"}),
]
"""The options of the command line (`benchmarks.report.report_main`): a flag and its ``argparse`` keywords."""
SMOKE = {"flat_cases": 1, "radii": [0.08], "ku_trials": ["contour_a_1"]}
"""The smoke run's values of the options."""


def main(argv: list[str] | None = None) -> int:
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, LEARNING_MD, options=OPTIONS, smoke=SMOKE)


if __name__ == "__main__":
    raise SystemExit(main())
