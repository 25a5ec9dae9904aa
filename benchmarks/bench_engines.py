"""The cross-engine table (issue 44): the scripted teacher's slides and contours, taught in PyBullet, executed on
PyBullet and on MuJoCo (``experiments/cross_engine.py``), and the MuJoCo loop's real-time factor beside the bare
MuJoCo loop's on the same machine in the same run.

    .venv/bin/python benchmarks/bench_engines.py [--no-write] [--smoke]

Writes the table into docs/RESULTS.md (section ``cross-engine``) and the real-time factors into docs/BENCHMARKS.md
(section ``bench_engines``). ``--smoke``: the first case only, a short bare loop; prints, writes nothing.
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
    run_case,
    taught,
    why_they_differ,
)
from schemas.execution import Engine  # noqa: E402
from schemas.world import WorldConfig  # noqa: E402
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


def reports(smoke: bool) -> tuple[str, str]:
    """Run the cases on both engines and the bare loop; return the RESULTS.md and the BENCHMARKS.md sections."""
    load_before = os.getloadavg()[0]
    cases = ENGINE_CASES[:1] if smoke else ENGINE_CASES
    skills = taught(cases)
    runs: list[EngineRun] = []
    for case in cases:
        for engine in Engine:
            run = run_case(case, engine, skills)
            m = run.metrics
            print(f"{case.name} on {engine.value}: {m.phase.value}, true RMS {m.true_force_rms_error_pct} %")
            runs.append(run)
    steps, repeats = (300, 1) if smoke else (BARE_STEPS, BARE_REPEATS)
    bare = statistics.median(bare_factors(steps, repeats))
    machine = machine_line(f"MuJoCo {mujoco.__version__}", load_at_start=load_before)
    command = COMMAND + (" --smoke" if smoke else "")
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
    add_smoke_argument(parser, "the first case on both engines, a short bare loop")
    arguments = parser.parse_args(argv)
    results, benchmarks = reports(arguments.smoke)
    print(results, benchmarks, sep="\n\n")
    if not (arguments.smoke or arguments.no_write):
        write_section(CROSS_ENGINE_SECTION, results, RESULTS_MD)
        write_section("bench_engines", benchmarks)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
