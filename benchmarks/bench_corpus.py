"""The learner on the ground-truth corpus (`corpus.families.corpus_cases`), scored by `corpus.scoring.score`.

Every case is learned with ``skill_type=auto``: the analytic ones from their samples, the human-like ones from their
recording file read back by `services.csv_import.demonstration_from_csv`. Prints one markdown row per case (a learner
that raises gets its error in the row) and the time to generate and to learn the corpus.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import pin_blas_threads

pin_blas_threads()

from corpus.families import corpus_cases  # noqa: E402
from corpus.scoring import score  # noqa: E402
from schemas import Demonstration  # noqa: E402
from schemas.import_options import CsvImportOptions  # noqa: E402
from services.csv_import import demonstration_from_csv  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402

COMMAND = ".venv/bin/python benchmarks/bench_corpus.py [--seeds 0 1 2]"


def read_csv(text: str, options: dict[str, object]) -> Demonstration:
    """A human-like case's file, imported with the options it comes with."""
    return demonstration_from_csv(text, CsvImportOptions(**options))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    seeds = parser.parse_args().seeds
    start = time.perf_counter()
    cases = list(corpus_cases(seeds))
    generated_s = time.perf_counter() - start
    print("| case | type (truth) | segments learned/truth | boundary error s | normal error deg | force error |")
    print("|---|---|---|---|---|---|")
    learning_s = 0.0
    for case in cases:
        demonstration = case.demonstration(read_csv)
        start = time.perf_counter()
        try:
            skill = learn_skill(demonstration)
        except ValueError as exc:
            learning_s += time.perf_counter() - start
            print(f"| {case.name} | error ({case.skill_type}) | {type(exc).__name__}: {str(exc)[:80]} | | | |")
            continue
        learning_s += time.perf_counter() - start
        s = score(skill, case)
        learned_type = skill.skill_type.value + ("" if s.type_right else " ✗")
        strokes = f"{s.learned_strokes}/{s.truth_strokes}" + ("" if s.strokes_right else " ✗")
        print(
            f"| {case.name} | {learned_type} ({case.skill_type}) | {strokes} | {s.boundary_error_s:.3f} "
            f"| {s.normal_error_deg:.1f} | {s.force_error:.3f} |",
            flush=True,
        )
    print(f"\n{len(cases)} cases: generated in {generated_s:.1f} s, learned in {learning_s:.1f} s")


if __name__ == "__main__":
    main()
