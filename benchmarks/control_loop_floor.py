"""The floor of the control-loop benchmark (`benchmarks/bench_control_loop.py`): bare loops this benchmark builds,
replaying the exact torques one project execution commanded from the same start state (the same physics step by
step), through PyBullet's Python API and through its C API from compiled code as the project makes them; the ladder of
bare loops that add the project's per-step parts one at a time (:data:`LADDER`); the parts alone
(:func:`isolated_costs`) and a model update's aftermath (:func:`update_aftermath`); and the tables that compare them
with the project loop (:func:`floor_lines`). Times in µs per step (wall and thread CPU), forces in N, torques in N·m.

Imported by the benchmark script after it pins the BLAS threads (`benchmarks.report.pin_blas_threads`).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NamedTuple

import numba
import numpy as np
import pybullet

from schemas import ControllerKind, ExecutionSettings
from schemas.execution import TELEMETRY_WIDTH, EnvironmentChange, SensorChoice
from schemas.skill import SELECTION_CONTACT, Skill
from sim_worker import control_loop
from sim_worker.arm_model import arm_mass_matrix
from sim_worker.bullet_client import read_contact_rows, read_joint_rows
from sim_worker.compiled_calls import state_reader, stepper
from sim_worker.contact_sensing import CONTACT_APPLIED, CONTACT_MEASURED
from sim_worker.control_loop import (
    _S_DT,
    _S_LIMITS,
    _S_SIZE,
    NULL_SPACE_UPDATE_STEPS,
    _outside_limits,
    _record_and_control,
)
from sim_worker.execution_world import ExecutionWorld, execution_world
from sim_worker.executor import ExecutionResult, run_skill
from sim_worker.robot_model import N_JOINTS, TOOL_LINK
from sim_worker.world import LoopHandles, SimWorld
from skills.compiled import compiled_entry
from skills.control import DAMPING_UPDATE_EVERY, ControlFrame, HybridController, LawKernel
from skills.control.layouts import (
    REFERENCE_SIZE,
    REFERENCE_TWIST,
    ROBOT_POSITION,
    ROBOT_Q,
    ROBOT_QUAT,
    ROBOT_STATE_SIZE,
)

FLOOR_SCENARIO = "slide_flat"
"""The skill the project loop is compared with the bare PyBullet loop on (settle, free motion, touch-down, slide)."""
TARGET_FLOOR_RATIO = 1.3
"""Issue 28's target: the project loop within this factor of the bare loop's µs per step."""


def wall_us_per_step(result: ExecutionResult) -> float:
    """The loop's wall time per control step of an execution, µs."""
    return 1e6 * result.loop_wall_s / max(result.metrics.steps, 1)


def captured_torques(world: ExecutionWorld, settings: ExecutionSettings) -> tuple[list[list[float]], tuple, int]:
    """Execute once, capturing every torque command of the loop (N·m, as sent to PyBullet) and the joint states
    (PyBullet's tuples) at the first one; and the steps the telemetry records in contact."""
    torques: list[list[float]] = []
    start: list[tuple] = []
    original = control_loop.stepper

    def capturing(handles: LoopHandles) -> Callable[[np.ndarray, np.ndarray], None]:
        advance, bullet = original(handles), handles.bullet

        def capture(ids: np.ndarray, tau: np.ndarray) -> None:
            if not torques:
                start.append(pybullet.getJointStates(bullet.body, list(range(N_JOINTS)), bullet.client_id))
            torques.append(tau.tolist())
            advance(ids, tau)

        return capture

    control_loop.stepper = capturing
    try:
        result = run_skill(world, settings)
    finally:
        control_loop.stepper = original
    return torques, start[0], int(result.telemetry.in_contact.sum())


AFTERMATH_SETTLED = 5
"""Steps after a model update from which a step's parts count as settled (:func:`update_aftermath`)."""
LADDER = ("bare", "bare_c_api", "arm_contact", "row_law", "model_update")
"""The bare loops: the four PyBullet calls per step through PyBullet's Python API (the issue's floor); the same calls
from compiled code through its C API as the project makes them (``sim_worker.bullet_client``: the joint states and
contact points in one compiled call, the torque command and physics step in another; the C-API floor); then the
project's per-step parts added one at a time: the arm state and contact summary with the queries
(``contact_sensing.sense_client``; with the wrist sensor ``sample_client``, its reading too); the telemetry row with
the control law (``control_loop._record_and_control``); the model update every ``NULL_SPACE_UPDATE_STEPS`` steps as
the project loop makes it (:func:`model_update`)."""
BARE_LEVELS = ("bare", "bare_c_api")
"""The ladder's levels that compute nothing of the project's (their steps in contact are counted: the same physics)."""


@numba.njit(cache=True)
def _query(ids, joint_rows):  # pragma: no cover - compiled
    """The project loop's two PyBullet queries from compiled code, nothing computed: the number of contact points."""
    read_joint_rows(ids, joint_rows)
    return read_contact_rows(ids).shape[0]


class StepParts(NamedTuple):
    """The project loop's per-step compiled parts' inputs in a bare loop's world (:func:`step_parts`): the world's loop
    handles, a controller prepared for the contact frame at the start pose and holding it, the loop's state and rows."""

    handles: LoopHandles
    reading_at: int
    controller: HybridController
    frame: ControlFrame
    references: np.ndarray
    loop_state: np.ndarray
    rows: np.ndarray
    read_state: Callable[..., bool]
    advance: Callable[..., None]
    record_and_control: Callable[..., tuple]
    mass_of: Callable[..., np.ndarray]
    kernel: LawKernel


def step_parts(sim: SimWorld, steps: int) -> StepParts:
    """:class:`StepParts` for ``steps`` steps in ``sim`` (its arm in the state the steps start from)."""
    handles = sim.loop_handles()
    arm, contact = handles.arm, handles.contact
    controller = HybridController(posture=arm[ROBOT_Q])
    sim.robot_state()
    frame = controller.frame(np.diag([1.0, -1.0, -1.0]), SELECTION_CONTACT)
    references = np.zeros((steps, REFERENCE_SIZE))
    references[:, : REFERENCE_TWIST.start] = arm[ROBOT_POSITION.start : ROBOT_QUAT.stop]
    kernel = controller.kernel(arm[:ROBOT_STATE_SIZE])
    kernel.refresh(frame, arm[:ROBOT_STATE_SIZE], references[0], contact[:6], None, True)
    loop_state = np.zeros(_S_SIZE)
    loop_state[_S_LIMITS : _S_LIMITS + N_JOINTS] = sim.torque_limits
    loop_state[_S_DT] = sim.config.time_step_s
    reading_at = CONTACT_APPLIED.start if handles.ideal else CONTACT_MEASURED.start
    rows = np.zeros((steps, TELEMETRY_WIDTH))
    # The compiled calls as the project loop makes them: their specializations, not the dispatcher.
    law_buffer = controller.law_buffer
    record_and_control = compiled_entry(
        _record_and_control, (arm, contact, reading_at, False, law_buffer, loop_state, rows, references, 0, False, 0, 0)
    )
    mass_of = compiled_entry(arm_mass_matrix, (handles.model, arm[ROBOT_Q]))
    return StepParts(handles, reading_at, controller, frame, references, loop_state, rows, state_reader(handles),
                     stepper(handles), record_and_control, mass_of, kernel)  # fmt: skip


@contextmanager
def replayed_world(world: ExecutionWorld, start: tuple) -> Iterator[SimWorld]:
    """A new world as the project builds ``world``'s, its arm put in the captured ``start`` state (joint positions
    and velocities), for a bare loop to replay the project's torques from."""
    with SimWorld(world.config) as sim:
        for joint, state in zip(range(N_JOINTS), start, strict=True):
            pybullet.resetJointState(sim.robot, joint, state[0], state[1], physicsClientId=sim.client_id)
        yield sim


def model_update(sim: SimWorld, parts: StepParts, touching: bool, k: int) -> None:
    """The project loop's model update at step ``k``, as it makes it: the joint-limit check, the mass matrix, the
    kernel's refresh (``LawKernel.refresh``: the null-space model in one compiled call, or, when the update rebuilds
    the adaptive damping, in the controller's Python), then the step's row and law (one call)."""
    handles, reading_at, loop_state = parts.handles, parts.reading_at, parts.loop_state
    arm, contact, references, rows = handles.arm, handles.contact, parts.references, parts.rows
    robot = arm[:ROBOT_STATE_SIZE]
    q = robot[ROBOT_Q]
    _outside_limits(q, sim.joint_lower, sim.joint_upper)
    M = parts.mass_of(handles.model, q)
    parts.kernel.refresh(parts.frame, robot, references[k], contact[reading_at : reading_at + 6], M, True)
    parts.record_and_control(arm, contact, reading_at, touching, parts.kernel.buffer, loop_state, rows, references, k,
                             False, k, k)  # fmt: skip


def bare_loop(
    world: ExecutionWorld, torques: list[list[float]], start: tuple, level: str = "bare"
) -> tuple[float, float, int]:
    """A level of :data:`LADDER` in the same world (built as the project builds it), the arm put in the captured start
    state, replaying ``torques``: the four PyBullet calls per step through its Python API (``bare``) or as the project
    makes them from compiled code, with the project's compiled per-step parts on top (computed and not used: the
    torques stay the replayed ones, so the physics stays the same). Returns µs per step by wall time and by the
    thread's CPU time, and the steps that began with contact points reported (0 above the bare levels: not counted)."""
    with replayed_world(world, start) as sim:
        client, robot = sim.client_id, sim.robot
        joints = list(range(N_JOINTS))
        parts = step_parts(sim, len(torques))
        handles, reading_at, references, loop_state, rows = (
            parts.handles, parts.reading_at, parts.references, parts.loop_state, parts.rows
        )  # fmt: skip
        queried = handles.bullet.queried  # with the wrist sensor the tool joint's reaction is read with the joints
        ids, joint_rows = handles.bullet.ids, handles.bullet.joint_rows
        model, arm, contact, ideal, draw, sensor = (
            handles.model, handles.arm, handles.contact, handles.ideal, handles.draw, handles.sensor
        )  # fmt: skip
        law_buffer, record_and_control = parts.controller.law_buffer, parts.record_and_control
        read_state, advance = parts.read_state, parts.advance
        query = compiled_entry(_query, (ids, joint_rows))
        updating = level == "model_update"
        row_law = level == "row_law" or updating
        in_contact = 0
        wall, cpu = time.perf_counter(), time.thread_time()
        if level == "bare":  # each call as the project made them through Python (positional where PyBullet allows)
            joint_states, contact_points = pybullet.getJointStates, pybullet.getContactPoints
            command, step, torque_control = (
                pybullet.setJointMotorControlArray, pybullet.stepSimulation, pybullet.TORQUE_CONTROL
            )  # fmt: skip
            for forces in torques:
                joint_states(robot, queried, client)
                if contact_points(robot, -1, TOOL_LINK, -2, client):
                    in_contact += 1
                command(robot, joints, torque_control, forces=forces, physicsClientId=client)
                step(client)
        elif level == "bare_c_api":
            for forces in list(np.array(torques)):
                if query(ids, joint_rows):
                    in_contact += 1
                advance(ids, forces)
        else:
            for k, forces in enumerate(list(np.array(torques))):
                if ideal:
                    touching = read_state(ids, model, joint_rows, arm, contact)
                else:
                    draw()
                    touching = read_state(ids, model, joint_rows, arm, contact, sensor)
                if updating and k % NULL_SPACE_UPDATE_STEPS == 0:
                    model_update(sim, parts, touching, k)
                elif row_law:
                    record_and_control(
                        arm, contact, reading_at, touching, law_buffer, loop_state, rows, references, k, False, k, k
                    )
                advance(ids, forces)
        wall, cpu = time.perf_counter() - wall, time.thread_time() - cpu
    return 1e6 * wall / len(torques), 1e6 * cpu / len(torques), in_contact


def isolated_costs(world: ExecutionWorld, torques: list[list[float]], start: tuple, calls: int) -> dict[str, float]:
    """The ladder's parts (:data:`LADDER`) in isolation: the world of :func:`bare_loop` replayed to its first step in
    contact, then each part called ``calls`` times back to back on that state (no physics step between: its code and
    data stay in the CPU caches). Returns CPU µs per step by part, the best of 5 batches (the arm state and contact
    summary's less the queries alone; the model update's less the row and law it replaces, per
    ``NULL_SPACE_UPDATE_STEPS`` steps)."""
    with replayed_world(world, start) as sim:
        client, robot = sim.client_id, sim.robot
        parts = step_parts(sim, len(torques))
        handles = parts.handles
        for forces in torques:  # to the first state in contact: a contact point's tuple to unpack, as in a slide
            if pybullet.getContactPoints(robot, -1, TOOL_LINK, -2, client):
                break
            pybullet.setJointMotorControlArray(robot, list(range(N_JOINTS)), pybullet.TORQUE_CONTROL, forces=forces,
                                               physicsClientId=client)  # fmt: skip
            pybullet.stepSimulation(client)
        model, arm, contact, draw, sensor = handles.model, handles.arm, handles.contact, handles.draw, handles.sensor
        ids, joint_rows = handles.bullet.ids, handles.bullet.joint_rows
        read_state = parts.read_state  # the specialization the project loop calls
        query = compiled_entry(_query, (ids, joint_rows))

        def arm_and_contact() -> bool:
            if handles.ideal:
                return read_state(ids, model, joint_rows, arm, contact)
            draw()
            return read_state(ids, model, joint_rows, arm, contact, sensor)

        touching = arm_and_contact()

        law_buffer, loop_state, rows, references = (
            parts.controller.law_buffer, parts.loop_state, parts.rows, parts.references
        )  # fmt: skip
        row_law_arguments = (arm, contact, parts.reading_at, touching, law_buffer, loop_state, rows, references, 0,
                             False, 0, 0)  # fmt: skip
        record_and_control = parts.record_and_control
        timed = {
            "queries": lambda: query(ids, joint_rows),
            "arm_contact": arm_and_contact,
            "row_law": lambda: record_and_control(*row_law_arguments),
            "model_update": lambda: model_update(sim, parts, touching, 0),
        }
        costs = {}
        for name, call in timed.items():
            batches = []
            for _ in range(5):
                cpu = time.thread_time()
                for _ in range(calls):
                    call()
                batches.append((time.thread_time() - cpu) / calls)
            costs[name] = 1e6 * min(batches)
    # As in the ladder: the arm state and contact summary above the queries they make; a model update replaces one
    # step's row and law, once every NULL_SPACE_UPDATE_STEPS steps.
    costs["arm_contact"] -= costs.pop("queries")
    costs["model_update"] = (costs["model_update"] - costs["row_law"]) / NULL_SPACE_UPDATE_STEPS
    return costs


def update_aftermath(world: ExecutionWorld, torques: list[list[float]], start: tuple) -> dict[str, float]:
    """The model update's cost in the loop, in its parts: one bare loop with the project's per-step parts (the ladder's
    last level), each part of each step timed (wall clock; the timers cost every step the same). Returns µs per model
    update: ``own``, its step's compiled call less a row-and-law step's; ``physics`` and ``sensing``, how much longer
    the physics step right after it and the next step's arm state and contact summary take than those of steps
    ``AFTERMATH_SETTLED`` or more steps after an update (their code and data evicted by the update's LAPACK)."""
    perf = time.perf_counter_ns
    with replayed_world(world, start) as sim:
        parts = step_parts(sim, len(torques))
        handles, law_buffer, loop_state = parts.handles, parts.controller.law_buffer, parts.loop_state
        read_state, advance = parts.read_state, parts.advance
        ids, joint_rows = handles.bullet.ids, handles.bullet.joint_rows
        extra = () if handles.ideal else (handles.sensor,)
        times = np.zeros((len(torques), 3))  # sensing, compiled step, physics: ns
        for k, forces in enumerate(list(np.array(torques))):
            t0 = perf()
            if not handles.ideal:
                handles.draw()
            touching = read_state(ids, handles.model, joint_rows, handles.arm, handles.contact, *extra)
            t1 = perf()
            if k % NULL_SPACE_UPDATE_STEPS == 0:
                model_update(sim, parts, touching, k)
            else:
                parts.record_and_control(handles.arm, handles.contact, parts.reading_at, touching, law_buffer,
                                         loop_state, parts.rows, parts.references, k, False, k, k)  # fmt: skip
            t2 = perf()
            advance(ids, forces)
            times[k] = t1 - t0, t2 - t1, perf() - t2
    since = np.arange(len(torques)) % NULL_SPACE_UPDATE_STEPS
    settled = times[since >= AFTERMATH_SETTLED].mean(axis=0)
    return {
        "own": 1e-3 * (times[since == 0, 1].mean() - settled[1]),
        "physics": 1e-3 * (times[since == 0, 2].mean() - settled[2]),
        "sensing": 1e-3 * (times[since == 1, 0].mean() - settled[0]),
    }


def floor_comparison(skill: Skill, recording, repeats: int, isolated_calls: int) -> list[dict[str, float | str | int]]:
    """Per sensor: the project loop (``run_skill``, µs per step of the loop's wall and CPU time) and the bare loops of
    :data:`LADDER` replaying its torques, interleaved ``repeats`` times; medians, and whether every step was the same
    physics; and the ladder's parts in isolation (:func:`isolated_costs`, ``isolated_calls`` calls each)."""
    rows = []
    for sensor in (SensorChoice.ideal, SensorChoice.wrist):
        environment = EnvironmentChange(sensor=sensor)
        settings = ExecutionSettings(controller=ControllerKind.hybrid_cf, pace="fast", environment=environment)
        world = execution_world(skill, environment, scenario=FLOOR_SCENARIO, demonstration=recording.demonstration)
        torques, start, project_contact = captured_torques(world, settings)
        project_wall, project_cpu = [], []
        ladder_wall: dict[str, list[float]] = {level: [] for level in LADDER}
        ladder_cpu: dict[str, list[float]] = {level: [] for level in LADDER}
        contact_steps = set()
        for _ in range(repeats):
            result = run_skill(world, settings)
            project_wall.append(wall_us_per_step(result))
            project_cpu.append(1e6 * result.loop_cpu_s / max(result.metrics.steps, 1))
            for level in LADDER:
                wall, cpu, in_contact = bare_loop(world, torques, start, level)
                ladder_wall[level].append(wall)
                ladder_cpu[level].append(cpu)
                if level in BARE_LEVELS:
                    contact_steps.add(in_contact)
        bare_wall, bare_cpu = ladder_wall["bare"], ladder_cpu["bare"]
        c_api_cpu = ladder_cpu["bare_c_api"]
        rows.append(
            {
                "sensor": sensor.value,
                "steps": len(torques),
                "contact_steps": project_contact,
                "same_physics": contact_steps == {project_contact},
                "project_wall": statistics.median(project_wall),
                "bare_wall": statistics.median(bare_wall),
                "project_cpu": statistics.median(project_cpu),
                "bare_cpu": statistics.median(bare_cpu),
                "ratio_wall": statistics.median(p / b for p, b in zip(project_wall, bare_wall, strict=True)),
                "ratio_cpu": statistics.median(p / b for p, b in zip(project_cpu, bare_cpu, strict=True)),
                "c_api_cpu": statistics.median(c_api_cpu),
                "ratio_c_api": statistics.median(p / b for p, b in zip(project_cpu, c_api_cpu, strict=True)),
                "ladder_cpu": {level: statistics.median(values) for level, values in ladder_cpu.items()},
                "isolated_cpu": isolated_costs(world, torques, start, isolated_calls),
                "aftermath": update_aftermath(world, torques, start),
            }
        )
        row = rows[-1]
        print(
            f"floor {sensor.value:5s}: project {row['project_wall']:.1f} µs/step, bare {row['bare_wall']:.1f}, ratio "
            f"{row['ratio_wall']:.2f} (CPU {row['project_cpu']:.1f} / {row['bare_cpu']:.1f} = {row['ratio_cpu']:.2f}); "
            f"bare + arm & contact {row['ladder_cpu']['arm_contact']:.1f}, + row & law "
            f"{row['ladder_cpu']['row_law']:.1f} µs CPU; contact steps {sorted(contact_steps)} bare, {project_contact} "
            "project",
            flush=True,
        )
    return rows


PART_NAMES = {
    "arm_contact": "arm state and contact summary, with the wrist sensor its reading (compiled, from the queries)",
    "row_law": "telemetry row, control law, torque limits (one compiled call)",
    "model_update": (
        f"model update every {NULL_SPACE_UPDATE_STEPS} steps (mass matrix, limits, projector, damping, gains)"
    ),
    "rest": "the rest of the loop body (Python: the calls, checks, the phases' set-up)",
}
"""The project's per-step parts above the C-API bare loop, named for the tables (the first three are
:data:`LADDER`'s)."""


def floor_parts(row: dict) -> dict[str, tuple[float, float | None]]:
    """What the project adds to the C-API bare loop per step (CPU µs), by part (:data:`PART_NAMES`): in the loop (from
    the ladder of bare loops, :data:`LADDER`, and the rest of the project's loop) and alone (:func:`isolated_costs`;
    None for the rest)."""
    ladder, alone = row["ladder_cpu"], row["isolated_cpu"]
    levels = [*LADDER[1:], "project"]
    totals = {**ladder, "project": row["project_cpu"]}
    return {
        part: (totals[above] - totals[below], alone.get(part))
        for part, below, above in zip(PART_NAMES, levels[:-1], levels[1:], strict=True)
    }


def floor_lines(rows: list[dict[str, float | str | int]], repeats: int, load: tuple[float, float, float]) -> list[str]:
    """The floor comparison's tables and their reading, every number from this run."""
    lines = [
        "",
        f"The project loop beside the floor ({FLOOR_SCENARIO}, hybrid_cf, `run_skill` as a worker runs it): a bare "
        "loop built by this benchmark makes only the project loop's four PyBullet calls per step through PyBullet's "
        "Python API (`getJointStates`, with the wrist sensor of the arm's joints and the tool joint; "
        "`getContactPoints` of the tool; `setJointMotorControlArray`; `stepSimulation`: the issue's floor), another "
        "makes the same calls' C functions from compiled code as the project loop does (`sim_worker/bullet_client.py`: "
        "the C-API floor, the project's own), both in the same world, from the same start state, replaying the "
        "torques one project execution commanded: the same physics step by step (the steps in contact agree, column "
        f"'same physics'). {repeats} project executions interleaved with {repeats} bare loops of each kind per "
        "sensor, medians; a ratio is the median of the pairs' ratios. The project's µs cover its whole loop (as the "
        f"table above, the phases' set-up included). Load average (1, 5, 15 min) at the end: {load_text(load)}.",
        "",
        "| sensor | steps (in contact) | same physics | project µs / step | bare loop µs / step | ratio | "
        "project CPU µs / step | bare CPU µs / step | ratio (CPU) | C-API bare CPU µs / step | ratio to it (CPU) |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['sensor']} | {r['steps']} ({r['contact_steps']}) | {'yes' if r['same_physics'] else 'NO'} | "
            f"{r['project_wall']:.1f} | {r['bare_wall']:.1f} | {r['ratio_wall']:.2f} | {r['project_cpu']:.1f} | "
            f"{r['bare_cpu']:.1f} | {r['ratio_cpu']:.2f} | {r['c_api_cpu']:.1f} | {r['ratio_c_api']:.2f} |"
        )
    parts = [floor_parts(r) for r in rows]
    lines += [
        "",
        "Where the project's µs above the C-API bare loop go (CPU µs per step). In the loop: medians of bare loops "
        "that add the project's per-step parts one at a time, interleaved with the others, and the project loop less "
        "the last of them. Alone: the same calls back to back on one state in contact (best of 5 batches; the arm "
        "state and contact summary's less the two queries alone), the model update's less the row and law it "
        f"replaces, per {NULL_SPACE_UPDATE_STEPS} steps:",
        "",
        "| part | " + " | ".join(f"{r['sensor']}: in the loop | {r['sensor']}: alone" for r in rows) + " |",
        "| --- |" + " ---: | ---: |" * len(rows),
    ]
    for part, name in PART_NAMES.items():
        cells = [f"{p[part][0]:.1f} | " + ("–" if p[part][1] is None else f"{p[part][1]:.1f}") for p in parts]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append(
        "| **project - C-API bare** | " + " | ".join(f"{r['project_cpu'] - r['c_api_cpu']:.1f} | " for r in rows) + " |"
    )
    lines.append(
        "| PyBullet's Python API (the bare loop less the C-API one; the project does not pay it) | "
        + " | ".join(f"{r['bare_cpu'] - r['c_api_cpu']:.1f} | " for r in rows)
        + " |"
    )
    met = [r["sensor"] for r in rows if r["ratio_cpu"] <= TARGET_FLOOR_RATIO]
    readings = []
    for r, p in zip(rows, parts, strict=True):
        compiled = [part for part in p.values() if part[1] is not None]
        in_loop, alone = sum(part[0] for part in compiled), sum(part[1] for part in compiled)
        readings.append(
            f"{r['sensor']}: {r['ratio_cpu']:.2f}x the Python-API bare loop, {r['ratio_c_api']:.2f}x the C-API one "
            f"({r['project_cpu'] - r['c_api_cpu']:.1f} µs above its {r['c_api_cpu']:.1f}); the compiled parts (arm, "
            f"contact, row, law, model update) take {in_loop:.1f} µs of them in the loop, {alone:.1f} alone"
        )
    lines += [
        "",
        f"- Target (issue 28): the project loop within {TARGET_FLOOR_RATIO}x of the bare PyBullet loop for both "
        "sensors. By CPU time against the Python-API bare loop: "
        + (f"met for {', '.join(map(str, met))}" if met else "not met")
        + (" only" if met and len(met) < len(rows) else "")
        + ". "
        + "; ".join(readings)
        + ". Against the C-API loop, the stricter floor, the ratio is what the project's own work costs: the "
        "arithmetic itself (the arm's kinematics and gravity/Coriolis by recursive Newton-Euler every step, the "
        "contact sum, the row, the law), called as compiled specializations (`sim_worker/compiled_calls.py`); the "
        f"model update's LAPACK (the projector every {NULL_SPACE_UPDATE_STEPS} steps, the adaptive damping's "
        f"eigen-decomposition every {DAMPING_UPDATE_EVERY}th time), in compiled calls with no Python between them but "
        "on the damping's updates; CPython executing the loop body between the calls and the phases' set-up. In the "
        "loop the compiled parts cost more than alone: `stepSimulation` between two steps evicts their code and data "
        "from the CPU caches. None of them can go without changing what the loop computes: the law needs the arm's "
        "Jacobian and gravity/Coriolis of every state, the projector needs the same LAPACK calls (another "
        "factorization rounds differently), and the telemetry must stay bit-identical.",
        "- The model update's cost in the loop, per update, from one more bare loop with every part of every step "
        f"timed ({'; '.join(_aftermath_reading(r) for r in rows)}): the update's LAPACK in turn evicts PyBullet's "
        "code and data, which the next steps take back.",
    ]
    return lines


def _aftermath_reading(row: dict) -> str:
    """One sensor's :func:`update_aftermath` in words."""
    a = row["aftermath"]
    total = a["own"] + a["physics"] + a["sensing"]
    return (
        f"{row['sensor']}: its own call {a['own']:.1f} µs more than a row-and-law step, the physics step right after "
        f"it {a['physics']:+.1f} µs and the next step's sensing {a['sensing']:+.1f} µs against settled steps, "
        f"{total:.1f} µs in all, {total / NULL_SPACE_UPDATE_STEPS:.1f} per step"
    )


def load_text(load: tuple[float, float, float]) -> str:
    """The 1-, 5- and 15-minute load averages ``load``, as the tables print them."""
    return ", ".join(f"{v:.2f}" for v in load)
