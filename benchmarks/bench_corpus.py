"""Benchmark: the learner on the ground-truth corpus, one table row per family (`corpus.families.corpus_cases`).

Run from the repository root::

    .venv/bin/python benchmarks/bench_corpus.py [--seeds 0 1 2]

Every case is learned with ``skill_type=auto``: the analytic ones from their samples, the human-like ones from their
recording file read back as the README says (`services.csv_import.demonstration_from_csv`: irregular stamps, the
sensor's offset, the hand's push in free space). Each is scored by `corpus.scoring.score` (definitions there and in
docs/LEARNING.md). Per family: the right type, one segment per stroke or pass, and the worst and median errors. For
the human-like families a second table learns the same cases again from their TRUE applied wrench (no sensor, no
hand) and from it plus the hand's push, so the learner's own error and the floor the recording sets can be told
apart. Writes its section of docs/LEARNING.md.
"""

from __future__ import annotations

import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import LEARNING_MD, pin_blas_threads, report_main, report_text

pin_blas_threads()

from corpus.case import CorpusCase  # noqa: E402
from corpus.families import corpus_cases  # noqa: E402
from corpus.scoring import Score, score  # noqa: E402
from schemas import Demonstration, Skill  # noqa: E402
from schemas.import_options import CsvImportOptions  # noqa: E402
from services.csv_import import demonstration_from_csv  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402

SECTION = "corpus"
COMMAND = ".venv/bin/python benchmarks/bench_corpus.py --seeds 0 1 2"
TOLERANCES = {"slide": 3.0, "contour": 5.0}
"""Normal error tolerance per type, deg (slides: the worst segment; contours: time-weighted mean)."""
FORCE_TOLERANCE = 0.05
BOUNDARY_TOLERANCE_S = 0.2


def read_csv(text: str, options: dict[str, object]) -> Demonstration:
    """A human-like case's file, imported with the options it comes with."""
    return demonstration_from_csv(text, CsvImportOptions(**options))


def _learned(demonstration: Demonstration, case: CorpusCase) -> tuple[Skill | None, Score | None, str]:
    try:
        skill = learn_skill(demonstration)
    except ValueError as exc:
        return None, None, f"{type(exc).__name__}: {exc}"
    return skill, score(skill, case), ""


def _worst_median(values: list[float], fmt: str) -> str:
    return f"{fmt.format(max(values))} / {fmt.format(statistics.median(values))}"


def within(case: CorpusCase, s: Score) -> bool:
    """Whether a score is within every tolerance (the type, one segment per stroke, the normal, force and boundary
    tolerances above)."""
    return (
        s.type_right
        and s.strokes_right
        and s.normal_error_deg < TOLERANCES[case.skill_type]
        and s.force_error < FORCE_TOLERANCE
        and s.boundary_error_s < BOUNDARY_TOLERANCE_S
    )


def build_report(seeds: list[int]) -> str:
    started = time.perf_counter()
    cases = list(corpus_cases(seeds))
    generated_s = time.perf_counter() - started
    by_family: dict[str, list[tuple[CorpusCase, Score, Skill]]] = defaultdict(list)
    errors, learning_s, learned_samples = [], 0.0, 0
    for case in cases:
        demonstration = case.demonstration(read_csv)
        started = time.perf_counter()
        skill, result, error = _learned(demonstration, case)
        learning_s += time.perf_counter() - started
        learned_samples += len(demonstration.t)
        if skill is None:
            errors.append(f"{case.name}: {error}")
            continue
        by_family[case.family].append((case, result, skill))
    rows = [
        "| family (truth) | cases | right type | segments = truth | within all tolerances | boundary error s max / "
        "median | normal error ° max / median | force error % max / median | warnings |",
        "|---|--:|--:|--:|--:|---|---|---|--:|",
    ]
    for family, group in by_family.items():
        scores = [s for _, s, _ in group]
        kind = group[0][0].skill_type
        rows.append(
            f"| {family} ({kind}) | {len(group)} | {sum(s.type_right for s in scores)} | "
            f"{sum(s.strokes_right for s in scores)} | {sum(within(c, s) for c, s, _ in group)} | "
            f"{_worst_median([s.boundary_error_s for s in scores], '{:.2f}')} | "
            f"{_worst_median([s.normal_error_deg for s in scores], '{:.1f}')} | "
            f"{_worst_median([100 * s.force_error for s in scores], '{:.1f}')} | "
            f"{sum(len(k.warnings()) for _, _, k in group)} |"
        )
        print(rows[-1], flush=True)
    human = [(c, s) for group in by_family.values() for c, s, _ in group if c.recording is not None]
    floor = [
        "| case | normal error °: file / true wrench / true + hand | force error %: file / true wrench / true + hand |",
        "|---|---|---|",
    ]
    for case, from_file in human:
        applied = Demonstration.from_arrays(case.t, case.positions, case.orientations, case.wrenches)
        pushed = case.wrenches.copy()
        pushed[:, :3] += case.recording.hand_forces
        with_hand = Demonstration.from_arrays(case.t, case.positions, case.orientations, pushed)
        true_score, hand_score = (_learned(d, case)[1] for d in (applied, with_hand))
        cells = [from_file, true_score, hand_score]
        floor.append(
            f"| {case.name} | " + " / ".join("–" if c is None else f"{c.normal_error_deg:.1f}" for c in cells)
            + " | " + " / ".join("–" if c is None else f"{100 * c.force_error:.1f}" for c in cells) + " |"
        )  # fmt: skip
    total = sum(len(group) for group in by_family.values())
    inside = sum(within(c, s) for group in by_family.values() for c, s, _ in group)
    wrong_confident = [
        c.name
        for group in by_family.values()
        for c, s, k in group
        if not s.type_right and k.auto_selection is not None and k.auto_selection.confidence >= 0.8
    ]
    analytic = [(c, s) for group in by_family.values() for c, s, _ in group if c.recording is None]
    outside = [(c, k) for group in by_family.values() for c, s, k in group if not within(c, s)]
    silent = [c.name for c, k in outside if not k.warnings()]
    per_10s = 10.0 * learning_s / max(learned_samples / 1000.0, 1e-9)
    sentences = [
        f"{inside} of {total} cases are within every tolerance (type right, one segment per stroke or pass, normals "
        f"within {TOLERANCES['slide']:.0f}° for slides and {TOLERANCES['contour']:.0f}° for contours, forces within "
        f"{100 * FORCE_TOLERANCE:.0f} %, boundaries within {BOUNDARY_TOLERANCE_S} s); "
        f"{sum(within(c, s) for c, s in analytic)} of the {len(analytic)} analytic ones.",
        f"{len(wrong_confident)} cases got a wrong type with confidence >= 0.8"
        + (f" ({', '.join(wrong_confident)})." if wrong_confident else "."),
        f"{len(outside)} cases fall outside a tolerance; {len(outside) - len(silent)} of them say so with a warning, "
        f"{len(silent)} do not" + (f" ({', '.join(silent)})." if silent else "."),
        f"Learning took {learning_s:.1f} s for {total} cases ({learned_samples} samples): {per_10s:.2f} s per 10 s of "
        f"1 kHz recording on average over the corpus (its cases are short; `bench_learning.py` times long ones).",
    ]
    if errors:
        sentences.append("Refused: " + "; ".join(errors) + ".")
    return report_text(
        [
            "## The ground-truth corpus: accuracy per family",
            "",
            f"Command: `{COMMAND}` (seeds {', '.join(map(str, seeds))}; {total} cases generated in "
            f"{generated_s:.1f} s, `skill_type=auto`; the human-like cases imported from their recording files). "
            "Errors as defined in "
            "`corpus/scoring.py` (below). `warnings`: the failed checks of the family's skills.",
            "",
            *rows,
            "",
            *sentences,
            "",
            "The human-like cases learned three ways: from their recording file (the sensor's offset, noise, irregular "
            "stamps, the hand's push), from the true applied wrench alone, and from it plus the hand's push. The gap "
            "between the first and the other two is what the recording itself costs (the offset the import's tare "
            "cannot tell from a slow hand, the hand leaning across a straight stroke): on a straight stroke nothing "
            "but the force says how the plane is tilted about it.",
            "",
            *floor,
        ]
    )


OPTIONS = [("--seeds", {"type": int, "nargs": "+", "default": [0, 1, 2], "help": "corpus seeds (default 0 1 2)"})]
"""The options of the command line (`benchmarks.report.report_main`): a flag and its ``argparse`` keywords."""
SMOKE = {"seeds": [0]}
"""The smoke run's values of the options."""


def main(argv: list[str] | None = None) -> int:
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, LEARNING_MD, options=OPTIONS, smoke=SMOKE)


if __name__ == "__main__":
    raise SystemExit(main())
