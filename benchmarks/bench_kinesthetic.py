"""Learning from kinesthetic recordings against their ground truth: type, strokes, boundaries, normals, forces.

Every recording of `corpus.kinesthetic` (flat, 35° tilted and gently curved surfaces; 1-4 strokes;
friction 0.1/0.25/0.4; the hand pushing the arm with up to ~17 N in free space; a sensor offset
of 0.7-2.3 N in the sensor frame) is written in the real file format, imported exactly as the
README says and learned with ``skill_type=auto``. The table gives, per surface, the worst and
the median case over the seeds; the sentences below it are computed from the same rows.
"""

from __future__ import annotations

import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import pin_blas_threads, report_main, report_text

pin_blas_threads()

import numpy as np  # noqa: E402

from corpus import kinesthetic  # noqa: E402
from schemas import SegmentKind  # noqa: E402
from schemas.import_options import CsvImportOptions  # noqa: E402
from services.csv_import import demonstration_from_csv  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402
from skills.quaternions import matrix_from_quaternion  # noqa: E402

SECTION = "kinesthetic"
COMMAND = ".venv/bin/python benchmarks/bench_kinesthetic.py"
FRICTIONS = (0.1, 0.25, 0.4)
IMPORT = {"rate_hz": 100.0, "quaternion_order": "wxyz", "wrench_convention": "measured-on-tool", "wrench_frame": "tool"}


@dataclass(frozen=True)
class Case:
    """One recording learned: what was found against the truth."""

    surface: str
    seed: int
    right_type: bool
    confidence: float
    strokes_found: int
    strokes_true: int
    boundary_error_s: float
    normal_error_deg: float
    """Slide: largest angle of a segment's CF z to its stroke's plane normal; contour: median per-frame angle."""
    force_error: float
    """Slide: largest relative error of a segment's force against the stroke's plateau; contour: nan."""
    offset_error_n: float


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def run_case(surface: str, seed: int) -> Case:
    demo = kinesthetic.kinesthetic_wipe(surface, n_strokes=1 + seed % 4, friction=FRICTIONS[seed % 3], seed=seed)
    imported = demonstration_from_csv(kinesthetic.recording_csv_text(demo), CsvImportOptions(**IMPORT))
    offset = np.asarray(imported.metadata.force_offset_removed or np.zeros(6))
    skill = learn_skill(imported)
    truth = demo.truth
    contacts = [s for s in skill.segments if s.kind is SegmentKind.contact]
    matched = len(contacts) == len(truth.strokes)
    boundary = normal = force = float("nan")
    if matched:
        boundary = max(
            max(abs(s.t_start - k.t_on), abs(s.t_end - k.t_off)) for s, k in zip(contacts, truth.strokes, strict=True)
        )
        if skill.skill_type.value == "slide":
            normal = max(
                float(_angles_deg(matrix_from_quaternion(s.compliant_frames.orientations[0])[:, 2], k.normal))
                for s, k in zip(contacts, truth.strokes, strict=True)
                if k.normal is not None
            ) if truth.skill_type == "slide" else float("nan")  # fmt: skip
            force = max(
                abs(s.force_constant_n / k.plateau_force_n - 1.0) for s, k in zip(contacts, truth.strokes, strict=True)
            )
        else:
            errors = []
            for s, k in zip(contacts, truth.strokes, strict=True):
                rows = s.start_index + np.round(np.asarray(s.compliant_frames.t) * skill.sample_rate_hz).astype(int)
                pressing = truth.normal_force_n[rows] > 0.3 * k.plateau_force_n
                z = matrix_from_quaternion(s.compliant_frames.orientations)[:, :, 2]
                errors.extend(_angles_deg(z, truth.normals[rows])[pressing])
            normal = float(np.median(errors))
    return Case(
        surface=surface,
        seed=seed,
        right_type=skill.skill_type.value == truth.skill_type,
        confidence=skill.auto_selection.confidence,
        strokes_found=len(contacts),
        strokes_true=len(truth.strokes),
        boundary_error_s=boundary,
        normal_error_deg=normal,
        force_error=force,
        offset_error_n=float(np.linalg.norm(offset[:3] - truth.sensor_offset[:3])),
    )


def _worst_median(values: list[float], fmt: str) -> str:
    finite = [v for v in values if np.isfinite(v)]
    if not finite:
        return "–"
    return f"{fmt.format(max(finite))} / {fmt.format(statistics.median(finite))}"


def build_report(seeds: int) -> str:
    cases = [run_case(surface, seed) for surface in kinesthetic.SURFACES for seed in range(seeds)]
    rows = [
        "| surface (truth) | recordings | right type | confidence min / median | strokes found = true "
        "| boundary error max / median | normal error max / median | slide force error max / median "
        "| offset error max / median |",
        "|---|--:|--:|---|--:|---|---|---|---|",
    ]
    for surface in kinesthetic.SURFACES:
        group = [c for c in cases if c.surface == surface]
        confidences = [c.confidence for c in group]
        rows.append(
            f"| {surface} | {len(group)} | {sum(c.right_type for c in group)} | "
            f"{min(confidences):.2f} / {statistics.median(confidences):.2f} | "
            f"{sum(c.strokes_found == c.strokes_true for c in group)} | "
            f"{_worst_median([c.boundary_error_s for c in group], '{:.2f} s')} | "
            f"{_worst_median([c.normal_error_deg for c in group], '{:.1f}°')} | "
            f"{_worst_median([100 * c.force_error for c in group], '{:.1f} %')} | "
            f"{_worst_median([c.offset_error_n for c in group], '{:.2f} N')} |"
        )
        print(rows[-1], flush=True)
    wrong_confident = [c for c in cases if not c.right_type and c.confidence >= 0.8]
    all_right = sum(c.right_type for c in cases)
    sentences = [
        f"{all_right} of {len(cases)} recordings got the true type; {len(wrong_confident)} got a wrong type with "
        "confidence >= 0.8.",
        f"{sum(c.strokes_found == c.strokes_true for c in cases)} of {len(cases)} have exactly one contact segment "
        "per stroke.",
    ]
    return report_text(
        [
            "## Learning from kinesthetic recordings (ground truth)",
            "",
            f"Command: `{COMMAND}` ({seeds} seeds per surface; `corpus.kinesthetic`, imported as the README says, "
            "`skill_type=auto`).",
            "Normal error: slide, the largest angle of a segment's CF z to its stroke's plane; contour, the median "
            "per-frame angle of CF z to the true surface normal where the true force exceeds 30 % of the plateau. "
            "Boundary error: the largest distance of a contact segment's start or end to the true touch-down or "
            "lift-off. These recordings are analytic, made to carry the facts of real ones; they are not real ones.",
            "",
            *rows,
            "",
            *sentences,
        ]
    )


OPTIONS = [("--seeds", {"type": int, "default": 10, "help": "recordings per surface"})]
"""The options of the command line (`benchmarks.report.report_main`): a flag and its ``argparse`` keywords."""
SMOKE = {"seeds": 1}
"""The smoke run's values of the options."""


def main(argv: list[str] | None = None) -> int:
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, options=OPTIONS, smoke=SMOKE)


if __name__ == "__main__":
    raise SystemExit(main())
