"""The cross-engine tables (issue 44): the scripted teacher's slides and contours, taught in PyBullet, the robustness
perturbations (``experiments/verdict_truth.py``: each verdict and the judge's finding per engine) and the KU Leuven
skills (rebuilt work piece and CAD), executed on PyBullet and on MuJoCo (``experiments/cross_engine.py``); and the
MuJoCo loop's real-time factor beside the bare MuJoCo loop's on the same machine in the same run.

    .venv/bin/python benchmarks/bench_engines.py [--no-write] [--smoke] [--scenarios S ...] [--trials T ...]

Writes the tables into docs/RESULTS.md (section ``cross-engine``) and the real-time factors into docs/BENCHMARKS.md
(section ``bench_engines``). ``--scenarios`` runs the perturbations of these teacher scenarios only, ``--trials``
these KU Leuven recordings only (``none``: no KU rows); the doc names the subset run. ``--smoke``: the first teacher
case, the first perturbation and the first KU case on both engines, a short bare loop; prints, writes nothing.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import ROOT, add_smoke_argument, machine_line, pin_blas_threads, write_section

pin_blas_threads()

import mujoco  # noqa: E402

from benchmarks.bench_mujoco_loop import PRESS_N, bare_mujoco, pressing_pose, real_time_factors  # noqa: E402
from experiments.cross_engine import (  # noqa: E402
    CROSS_ENGINE_SECTION,
    ENGINE_CASES,
    EngineRun,
    difference_table,
    engine_table,
    kuleuven_cases,
    kuleuven_skills,
    run_case,
    run_kuleuven_case,
    taught,
    verdict_pair_counts,
    verdict_pair_table,
    verdict_pairs,
    why_they_differ,
)
from experiments.verdict_truth import PERTURBATIONS, TRUTH_SCENARIOS, Perturbation  # noqa: E402
from experiments.verdict_truth import taught as judged_teaching  # noqa: E402
from schemas.execution import Engine  # noqa: E402
from schemas.world import WorldConfig  # noqa: E402
from services.datasets import kuleuven_recordings  # noqa: E402
from sim_mujoco.robot import MujocoRobot  # noqa: E402
from sim_worker.world import SimWorld  # noqa: E402

COMMAND = ".venv/bin/python benchmarks/bench_engines.py"
RESULTS_MD = ROOT / "docs" / "RESULTS.md"
BARE_STEPS, BARE_REPEATS = 3000, 5
"""The bare MuJoCo loop's runs (``bench_mujoco_loop.bare_mujoco``: the table pressed with 15 N)."""


def bare_factors(steps: int, repeats: int) -> list[float]:
    """Real-time factors of the bare MuJoCo loop pressing the table (``bench_mujoco_loop``), this machine, now."""
    config = WorldConfig()
    with SimWorld(config) as world:
        q0 = pressing_pose(world)
    robot = MujocoRobot(config, q0)
    return real_time_factors(bare_mujoco(robot, q0, PRESS_N), steps, repeats, config.time_step_s)


def _print_run(run: EngineRun) -> EngineRun:
    m = run.metrics
    print(f"{run.case.name} on {run.engine.value}: {m.phase.value}, true RMS {m.true_force_rms_error_pct} %")
    return run


def _command(smoke: bool, scenarios: list[str], trials: list[str]) -> str:
    """The command line that reproduces this run: the subset options only when a subset ran."""
    if smoke:
        return COMMAND + " --smoke"
    options = "" if scenarios == list(TRUTH_SCENARIOS) else " --scenarios " + " ".join(scenarios)
    all_trials = [path.stem for path in kuleuven_recordings()]
    if trials != all_trials:
        options += " --trials " + (" ".join(trials) or "none")
    return COMMAND + options


def _not_run(ran: list[Perturbation]) -> str:
    """The sentence naming the perturbations a subset run left out, per scenario (empty when none was)."""
    left = [p for p in PERTURBATIONS if p not in ran]
    if not left:
        return ""
    counts = {s: sum(p.scenario == s for p in left) for s in dict.fromkeys(p.scenario for p in left)}
    named = ", ".join(f"`{s}` ({n})" for s, n in counts.items())
    return f" Not run in this run (a subset, the command's options): the perturbations of {named}."


def reports(smoke: bool, scenarios: list[str], trials: list[str]) -> tuple[str, str]:
    """Run the teacher cases, the perturbations of ``scenarios`` and the KU Leuven recordings ``trials`` (stems) on
    both engines, and the bare loop; return the RESULTS.md and the BENCHMARKS.md sections."""
    load_before = os.getloadavg()[0]
    cases = ENGINE_CASES[:1] if smoke else ENGINE_CASES
    skills = taught(cases)
    runs = [_print_run(run_case(case, engine, skills)) for case in cases for engine in Engine]
    perturbations = [p for p in PERTURBATIONS if p.scenario in scenarios][: 1 if smoke else None]
    teachings = {s: judged_teaching(s) for s in dict.fromkeys(p.scenario for p in perturbations)}
    pairs = verdict_pairs(perturbations, teachings)
    ku_cases = kuleuven_cases(path for path in kuleuven_recordings() if path.stem in trials)[: 1 if smoke else None]
    ku_skills = kuleuven_skills(ku_cases)
    ku_names = ", ".join(f"`{path.stem}`" for path in ku_skills)
    ku_runs = [_print_run(run_kuleuven_case(case, engine, ku_skills)) for case in ku_cases for engine in Engine]
    steps, repeats = (300, 1) if smoke else (BARE_STEPS, BARE_REPEATS)
    bare = statistics.median(bare_factors(steps, repeats))
    machine = machine_line(f"MuJoCo {mujoco.__version__}", load_at_start=load_before)
    command = _command(smoke, scenarios, trials)
    factors = {e: [r.metrics.real_time_factor for r in runs if r.engine is e] for e in Engine}
    loop = statistics.median(factors[Engine.mujoco])
    results = [
        "## The same skills on two engines (issue 44)",
        "",
        f"Reproduce: `{command}`. {machine}",
        "",
        "The scripted teacher's skills, taught in PyBullet (seed 0), executed with `hybrid_cf` on PyBullet and on "
        "MuJoCo (`engine` in the execution settings, docs/ENGINES.md): the same skill, settings (the default wrist "
        "sensor: noise, drift, 2 ms delay, 200 Hz filter, tared before contact), controller and phases; each row "
        "judged by its own engine's contact (true normal force RMS and largest steady error in % "
        "of the learned force, the touch-down peak over the first target, the share of the contact phase in "
        "contact, the verdict).",
        "",
        *engine_table(runs),
        "",
        *difference_table(runs),
    ]
    differing = why_they_differ(runs)
    results += ["", "### Where the engines differ by more than 2 points", ""]
    results += differing or ["None: every case's true RMS and true max agree within 2 points."]
    if differing:
        results += [
            "",
            "A jump of the true normal force in one step along a normal that turned is a new contact appearing (the "
            "ball meeting the ramp at the crease): the contact model's transient, not the controller, which commands "
            "the same law on the same state up to that step. MuJoCo's new contact brings its full damping and its "
            "constraint's apparent mass in its first step, Bullet's builds up over two steps "
            "([ENGINES.md](ENGINES.md), *What could not be matched*); the RMS, over the whole contact, agrees.",
        ]
    results += [
        "",
        "### The robustness perturbations on both engines",
        "",
        f"The {len(pairs)} perturbation{'s' * (len(pairs) != 1)} of `experiments/verdict_truth.py` (teacher scenarios "
        f"{', '.join(f'`{s}`' for s in teachings) or 'none'}; the skills learned `auto`, seed 0; moved, tilted, "
        "resized, swapped and missing parts, stiff and soft pads, friction, sensor faults, none told to the "
        "controller), each on PyBullet and on MuJoCo with the product's default following (slides follow the "
        "surface, contours keep the taught frames) and the approach limit of the verdict-truth runs. Per engine: "
        "the verdict (its failed checks) and the judge's finding (`judge_run`: the tool's positions on the exact "
        "shapes of the world that ran, docs/EXECUTION.md). MuJoCo builds every world of the set (boxes, the capsule, "
        f"the block's mesh).{_not_run(perturbations)} Why the engines differ where they do: "
        "[ENGINES.md](ENGINES.md), *The perturbations and the KU Leuven skills on both engines*.",
        "",
        *verdict_pair_counts(pairs),
        "",
        *verdict_pair_table(pairs),
        "",
        "### The KU Leuven skills on both engines",
        "",
        f"The KU Leuven recordings' skills ({ku_names or 'none'}; learned `auto`, placed "
        "in the robot's reach as every real recording is) on the work piece rebuilt from each demonstration (as "
        "placed, and 2 cm higher without telling the controller) and on the object's CAD placed the same way "
        "(`experiments/kuleuven_cad.py`, default gains), `hybrid_cf`, the wrist sensor; each row judged by its own "
        "engine's contact.",
        "",
        *engine_table(ku_runs),
        "",
        *difference_table(ku_runs),
    ]
    ku_differing = why_they_differ(ku_runs)
    results += ["", "Where the KU rows differ by more than 2 points:", ""]
    results += ku_differing or ["None: every KU case's true RMS and true max agree within 2 points."]
    benchmarks = [
        "## MuJoCo: the product's loop against the bare loop (issue 44)",
        "",
        f"Reproduce: `{command}` (the executions of docs/RESULTS.md's cross-engine table, pace fast; the bare loop "
        f"{repeats} run{'s' * (repeats > 1)} of {steps} steps). {machine}",
        "",
        "| loop | real-time factor (median) | runs |",
        "| --- | ---: | ---: |",
        f"| MuJoCo, the product's loop (`sim_mujoco.loop.MujocoLoop`, hybrid controller, executions) | {loop:.1f} | "
        f"{len(factors[Engine.mujoco])} |",
        f"| MuJoCo, bare (`mj_step`, a joint hold pressing the table: `bench_mujoco_loop`) | {bare:.1f} | {repeats} |",
        f"| PyBullet, the product's compiled loop (`sim_worker.control_loop.ControlLoop`, the same executions) | "
        f"{statistics.median(factors[Engine.pybullet]):.1f} | {len(factors[Engine.pybullet])} |",
        "",
        f"The MuJoCo execution loop runs at {loop / bare:.2f} of the bare MuJoCo loop's real-time factor: the "
        "controller's law is the same compiled step as PyBullet's, but the loop around it (the robot state, the "
        "mass matrix every 20 steps, the true contact from `mj_contactForce`, the sensor, the telemetry row, the "
        "phase's checks) is plain Python, one step at a time.",
    ]
    return "\n".join(results), "\n".join(benchmarks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-write", action="store_true", help="only print the reports; write nothing")
    parser.add_argument(
        "--scenarios",
        nargs="+",
        default=list(TRUTH_SCENARIOS),
        choices=TRUTH_SCENARIOS,
        help="run the perturbations of these teacher scenarios only",
    )
    trials = [path.stem for path in kuleuven_recordings()]
    parser.add_argument(
        "--trials",
        nargs="+",
        default=trials,
        choices=[*trials, "none"],
        help="run these KU Leuven recordings only (none: no KU rows)",
    )
    add_smoke_argument(parser, "the first teacher case, perturbation and KU case on both engines, a short bare loop")
    arguments = parser.parse_args(argv)
    chosen_trials = [t for t in arguments.trials if t != "none"]
    results, benchmarks = reports(arguments.smoke, arguments.scenarios, chosen_trials)
    print(results, benchmarks, sep="\n\n")
    if not (arguments.smoke or arguments.no_write):
        write_section(CROSS_ENGINE_SECTION, results, RESULTS_MD)
        write_section("bench_engines", benchmarks)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
