"""Benchmark: real-time factor and per-step cost of the full 1 kHz execution loop, on one core.

Run from the repository root::

    .venv/bin/python benchmarks/bench_control_loop.py [--repeats 3] [--floor-repeats 7] [--floor-only] [--no-write]
    .venv/bin/python benchmarks/bench_control_loop.py --smoke  # the smallest run through it all; writes nothing

Learns the skills from the scripted teacher (slide on the flat and the 15° table, contour over the
cylinder; seed 0), pins the process to one CPU, and executes each skill with ``pace=fast`` through
``sim_worker.executor.execute_skill``: PyBullet physics, sensing (joint state, contact wrench; tool pose,
Jacobian and gravity/Coriolis from the compiled arm model every step, mass matrix every
``NULL_SPACE_UPDATE_STEPS``), the control law (``skills.control``, compiled) and the telemetry record.
Reported: the real-time factor (simulated time over the loop's wall time, and over its thread's CPU
time, which a loaded machine disturbs less; medians of the repeats) and, for reference, the per-call cost of the
world's queries (``SimWorld.measure_costs``) and of the control law alone. Beside it, the floor: BARE loops this
script builds itself, making only the project loop's four PyBullet calls per step (``getJointStates``,
``getContactPoints``, ``setJointMotorControlArray``, ``stepSimulation``) through PyBullet's Python API, and the same
calls' C functions from compiled code as the project makes them, in the same world, replaying the exact torques one
project execution commanded from the same start state (so every step is the same physics: the contact steps are
counted and must agree), timed interleaved with project executions, for the ideal and the wrist sensor: µs per step
side by side and their ratios; and bare loops that add the project's per-step parts one at a time (``LADDER`` of
`benchmarks/control_loop_floor.py`, where the bare loops live), which say where the project's µs above the floor go.
The load average is printed with the table. The force / path measures of the same runs are reported too (ours and the
two baselines in the same run). Writes its section of docs/BENCHMARKS.md between
``<!-- bench_control_loop:start -->`` and ``<!-- bench_control_loop:end -->``.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import add_smoke_argument, machine_line, machine_speed, pin_blas_threads, write_section

pin_blas_threads()

import argparse  # noqa: E402
import os  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.control_loop_floor import (  # noqa: E402
    FLOOR_SCENARIO,
    floor_comparison,
    floor_lines,
    load_text,
    wall_us_per_step,
)
from schemas import ControllerKind, ExecutionSettings, LearnOptions  # noqa: E402
from schemas.execution import SensorChoice  # noqa: E402
from schemas.skill import SELECTION_CONTACT  # noqa: E402
from schemas.world import WorldConfig  # noqa: E402
from sim_worker.control_loop import NULL_SPACE_UPDATE_STEPS  # noqa: E402
from sim_worker.execution_world import execution_world  # noqa: E402
from sim_worker.executor import execute_skill, run_skill  # noqa: E402
from sim_worker.teacher import record_demonstration  # noqa: E402
from sim_worker.world import SimWorld  # noqa: E402
from skills.control import HybridController  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402

SECTION = "bench_control_loop"
COMMAND = ".venv/bin/python benchmarks/bench_control_loop.py"
TARGET_RTF = 30.0
RUNS = (
    ("slide_flat", "slide", ControllerKind.hybrid_cf, "ideal"),
    ("slide_flat", "slide", ControllerKind.hybrid_cf, "wrist"),
    ("slide_tilted", "slide", ControllerKind.hybrid_cf, "ideal"),
    ("slide_tilted", "slide", ControllerKind.impedance, "ideal"),
    ("slide_tilted", "slide", ControllerKind.hybrid_world_z, "ideal"),
    ("contour_cylinder", "contour", ControllerKind.hybrid_cf, "ideal"),
    ("contour_cylinder", "contour", ControllerKind.hybrid_cf, "wrist"),
    ("contour_cylinder", "contour", ControllerKind.impedance, "ideal"),
    ("contour_cylinder", "contour", ControllerKind.hybrid_world_z, "ideal"),
)
"""Scenario, skill type, controller, sensor: ``ideal`` executes in the recording's world (the exact contact wrench,
the control law's own view), ``wrist`` as a worker runs a request by default (``execution_world``: the wrist sensor
with its weight compensation, noise, drift, 2 ms delay and 200 Hz filter; the joint force/torque sensor of the tool
joint makes PyBullet's step dearer too)."""
SMOKE_RECORD = {"move_duration_s": 2.0}
"""The smoke run's teacher overrides: the same S-curve in 2 s, not 5 (every phase of the loop, fewer steps)."""


def pin_one_core() -> str:
    """Pin this process to one CPU (the last one); return a description."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpus[-1]})
        return f"pinned to CPU {cpus[-1]}"
    except (AttributeError, OSError):
        return "not pinned (no sched_setaffinity)"


def control_law_cost(repeats: int = 20000) -> dict[str, float]:
    """µs per call of the control law alone on a recorded-like state: cached model, and a model update."""
    world = SimWorld(WorldConfig())
    q, qd = world.joint_state()
    p, quat = world.tool_pose()
    state = {
        "jacobian": world.jacobian(),
        "q": q,
        "qd": qd,
        "bias_torques": world.gravity_coriolis_torques(),
        "tool_position": p,
        "tool_quaternion": quat,
        "reference_position": p + 0.001,
        "reference_quaternion": quat,
        "reference_twist": np.zeros(6),
        "wrench": np.array([0.5, 0.2, -14.0, 0.0, 0.0, 0.0]),
        "desired_force": 15.0,
    }
    mass = world.mass_matrix()
    world.close()
    ctrl = HybridController(posture=q)
    frame = ctrl.frame(np.diag([1.0, -1.0, -1.0]), SELECTION_CONTACT)
    ctrl.compute(frame=frame, mass_matrix=mass, **state)
    robot = np.concatenate((q, qd, p, quat, np.zeros(9), state["jacobian"].ravel(), state["bias_torques"]))
    reference = np.concatenate((state["reference_position"], quat, np.zeros(6), [state["desired_force"]]))
    wrench = state["wrench"]
    start = time.perf_counter()
    for _ in range(repeats):
        ctrl.step(frame, robot, reference, wrench, True, None, False)
    cached = (time.perf_counter() - start) / repeats * 1e6
    n_update = max(1, repeats // 10)
    start = time.perf_counter()
    for _ in range(n_update):
        ctrl.step(frame, robot, reference, wrench, True, mass, True)
    update = (time.perf_counter() - start) / n_update * 1e6
    return {"step (model cached)": cached, "step + model update (projector, Λ, damping every 5th)": update}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="executions per run (median RTF)")
    parser.add_argument(
        "--floor-repeats", type=int, default=7, help="project executions and bare loops per sensor (median ratio)"
    )
    parser.add_argument("--no-write", action="store_true", help="print only, do not touch docs/BENCHMARKS.md")
    parser.add_argument(
        "--floor-only", action="store_true", help="only the comparison with the bare PyBullet loop (print, no write)"
    )
    add_smoke_argument(
        parser, f"one repeat, the {FLOOR_SCENARIO} hybrid_cf rows only, a 2 s stroke, fewer timing calls"
    )
    args = parser.parse_args()
    runs, law_repeats, cost_calls, overrides = RUNS, 20000, 2000, {}
    if args.smoke:
        args.repeats = args.floor_repeats = 1
        runs = tuple(r for r in RUNS if r[0] == FLOOR_SCENARIO and r[2] is ControllerKind.hybrid_cf)
        law_repeats, cost_calls, overrides = 200, 50, SMOKE_RECORD
        args.no_write = True
    pinned = pin_one_core()
    load_before = os.getloadavg()

    learned = {}
    for scenario, skill_type, _, _ in runs:
        if scenario not in learned:
            recording = record_demonstration(scenario, seed=0, **overrides)
            options = LearnOptions(skill_type=skill_type)
            learned[scenario] = (recording, learn_skill(recording.demonstration, options))

    recording, skill = learned[FLOOR_SCENARIO]
    floor = floor_comparison(skill, recording, args.floor_repeats, cost_calls)
    if args.floor_only:
        print("\n".join(floor_lines(floor, args.floor_repeats, os.getloadavg())))
        return
    rows = []
    for scenario, _, controller, sensor in runs:
        recording, skill = learned[scenario]
        settings = ExecutionSettings(controller=controller, pace="fast")
        if sensor == "wrist":
            world = execution_world(skill, scenario=scenario, demonstration=recording.demonstration)
            results = [run_skill(world, settings) for _ in range(args.repeats)]
        else:
            results = [
                execute_skill(skill, recording.world_config, settings, demonstration=recording.demonstration)
                for _ in range(args.repeats)
            ]
        rtfs = [r.metrics.real_time_factor for r in results]
        cpu_us = statistics.median(1e6 * r.loop_cpu_s / max(r.metrics.steps, 1) for r in results)
        best = results[int(np.argsort(rtfs)[len(rtfs) // 2])]
        rows.append((scenario, controller, sensor, statistics.median(rtfs), min(rtfs), max(rtfs), cpu_us, best))
        m = best.metrics
        print(f"{scenario:17s} {controller.value:15s} {sensor:5s} RTF {statistics.median(rtfs):5.1f} "
              f"({min(rtfs):.1f}-{max(rtfs):.1f}), {wall_us_per_step(best):.0f} µs/step wall, {cpu_us:.0f} µs/step "
              f"CPU, {m.phase.value}, f_z RMS {m.force_rms_error_pct or float('nan'):.2f} %", flush=True)  # fmt: skip

    with SimWorld(WorldConfig()) as world:
        world_costs = world.measure_costs(cost_calls)
    law = control_law_cost(law_repeats)
    calibration = machine_speed()
    load_after = os.getloadavg()

    lines = [
        "## Control loop: real-time factor of the 1 kHz execution loop (one core)",
        "",
        f"Reproduce: `{COMMAND} --repeats {args.repeats} --floor-repeats {args.floor_repeats}` ({args.repeats} "
        "executions per row, median real-time "
        f"factor; {pinned}).",
        "",
        "Each row executes a skill learned from the scripted teacher (seed 0) in PyBullet at 1 kHz with "
        "`execute_skill(..., pace=fast)` (sensor `ideal`: the recording's world, the exact contact wrench) or as a "
        "worker runs a request by default (`wrist`: `execution_world` + `run_skill`, the wrist sensor model): "
        "settle, free motion, guarded approach, contact, retreat. The "
        "loop time covers physics, sensing, dynamics queries, the control law, the telemetry record and "
        "the guarded-approach / abort checks, and the work between the phases (the start pose's IK, the phases' "
        "DMP rollouts and control frames); not the world construction before it. Real-time factor = simulated "
        "time / the loop's wall time; CPU = the same over the loop thread's CPU time (`time.thread_time`), which "
        "other processes on a loaded machine disturb less (SMT siblings and caches still do). Load average "
        f"(1, 5, 15 min) before the run {load_text(load_before)}, after it {load_text(load_after)}.",
        "",
        "| scenario | controller | sensor | real-time factor (median, min-max) | µs / step | CPU µs / step (RTF) | "
        "f_z RMS error | f_z max error | contact ratio | path RMS (CF x-y) | peak force |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for scenario, controller, sensor, rtf, lo, hi, cpu_us, result in rows:
        m = result.metrics
        rms = f"{m.force_rms_error_n:.3f} N ({m.force_rms_error_pct:.2f} %)" if m.force_rms_error_n else "–"
        worst = f"{m.force_max_error_n:.2f} N ({m.force_max_error_pct:.1f} %)" if m.force_max_error_n else "–"
        ratio = f"{100 * m.contact_ratio:.2f} %" if m.contact_ratio is not None else "–"
        path = f"{1e3 * m.path_rms_m:.2f} mm" if m.path_rms_m is not None else "–"
        lines.append(
            f"| {scenario} | {controller.value} | {sensor} | {rtf:.1f} ({lo:.1f}-{hi:.1f}) | "
            f"{wall_us_per_step(result):.0f} | "
            f"{cpu_us:.0f} ({1e3 / cpu_us:.1f}) | {rms} | {worst} | {ratio} | {path} | {m.peak_force_n:.1f} N |"
        )
    lines += floor_lines(floor, args.floor_repeats, load_after)
    lines += [
        "",
        "Per-call costs for reference (µs, mean; `SimWorld.measure_costs` on a free arm, and the control law alone):",
        "",
        "| call | µs |",
        "| --- | ---: |",
    ]
    for name, value in world_costs.items():
        lines.append(f"| world.{name} | {value:.1f} |")
    for name, value in law.items():
        lines.append(f"| control law: {name} | {value:.1f} |")
    median_rtf = statistics.median(r[3] for r in rows)
    median_cpu_rtf = statistics.median(1e3 / r[6] for r in rows)
    verdict = "MET" if median_rtf >= TARGET_RTF else "NOT MET"
    verdict_cpu = "MET" if median_cpu_rtf >= TARGET_RTF else "NOT MET"
    ideal_floor = next(r for r in floor if r["sensor"] == SensorChoice.ideal.value)
    simulator, total = ideal_floor["c_api_cpu"], ideal_floor["project_cpu"]
    at_target = [f"{r[0]} {r[1].value} {r[2]}" for r in rows if r[3] >= TARGET_RTF]
    below = [f"{r[0]} {r[1].value} {r[2]} {r[3]:.1f}x" for r in rows if r[3] < TARGET_RTF]
    lines += [
        "",
        f"- Target: real-time factor >= {TARGET_RTF:.0f} on one core, i.e. <= {1e3 / TARGET_RTF:.0f} µs per step. "
        f"Median over the rows {median_rtf:.1f} by wall time: {verdict}; {median_cpu_rtf:.1f} by CPU time: "
        f"{verdict_cpu}. PyBullet's own calls, made as the project makes them (the C-API bare loop above), take "
        f"{simulator:.1f} of the project's {total:.1f} CPU µs per step ({FLOOR_SCENARIO}, ideal sensor): with no other "
        f"work the loop could not exceed {1e3 / simulator:.0f}x by CPU time. "
        f"Rows at or above the target: {len(at_target)} of {len(rows)}"
        + (f" ({', '.join(at_target)})" if at_target else "")
        + (f"; below it: {', '.join(below)}." if below else "."),
        "- Per step the loop makes what PyBullet's four Python functions `getJointStates`, `getContactPoints`, "
        "`setJointMotorControlArray` and `stepSimulation` would make, through PyBullet's C API from compiled code "
        "(`sim_worker/bullet_client.py`; with the wrist sensor the joint states include the tool joint's reaction); "
        "the tool pose, Jacobian, gravity/Coriolis torques and "
        "mass matrix come from the arm's compiled model (`sim_worker/arm_model.py`, equal to PyBullet's "
        "`getLinkState` / `calculateJacobian` / `calculateInverseDynamics` / `calculateMassMatrix` to round-off, "
        "`tests/test_world.py`), written into one array the compiled control law reads as it is "
        "(`HybridController.step`; the model update every "
        f"{NULL_SPACE_UPDATE_STEPS} steps compiled too). Every remaining numpy or PyBullet call costs ~0.3-3 µs "
        "of call overhead whatever it computes, more right after `stepSimulation`, which evicts the caches.",
        "",
        f"- How fast this machine was during the run (to compare tables taken on other machines or days: the "
        f"loop's µs scale with these): CPython `sum(range(1000))` {calibration['python']:.1f} µs, PyBullet "
        f"`stepSimulation` of the arm at rest, gravity off, in the flat-table world {calibration['physics']:.1f} µs "
        "(best of 5 runs each, pinned to the same CPU).",
        "",
        machine_line(f"pybullet {_pybullet_version()}", load_before[0]),
    ]
    body = "\n".join(lines)
    print()
    print(body)
    if not args.no_write:
        write_section(SECTION, body)


def _pybullet_version() -> str:
    try:
        from importlib.metadata import version

        return version("pybullet")
    except Exception:
        return "unknown"


if __name__ == "__main__":
    main()
