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
side by side and their ratios; and bare loops that add the project's per-step parts one at a time (:data:`LADDER`),
which say where the project's µs above the floor go. The load average is printed with the table. The force / path
measures of the same runs are reported too (ours and the two baselines in the same run). Writes its
section of docs/BENCHMARKS.md between ``<!-- bench_control_loop:start -->`` and
``<!-- bench_control_loop:end -->``.
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
from collections.abc import Callable, Iterator  # noqa: E402
from contextlib import contextmanager  # noqa: E402
from typing import NamedTuple  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
import pybullet  # noqa: E402

from schemas import ControllerKind, ExecutionSettings, LearnOptions  # noqa: E402
from schemas.execution import (  # noqa: E402
    TELEMETRY_WIDTH,
    EnvironmentChange,
    SensorChoice,
)
from schemas.skill import SELECTION_CONTACT, Skill  # noqa: E402
from schemas.world import WorldConfig  # noqa: E402
from sim_worker import control_loop  # noqa: E402
from sim_worker.arm_model import arm_mass_matrix  # noqa: E402
from sim_worker.bullet_client import read_contact_rows, read_joint_rows  # noqa: E402
from sim_worker.compiled_calls import state_reader, stepper  # noqa: E402
from sim_worker.contact_sensing import CONTACT_APPLIED, CONTACT_MEASURED  # noqa: E402
from sim_worker.control_loop import (  # noqa: E402
    _S_DT,
    _S_LIMITS,
    _S_SIZE,
    NULL_SPACE_UPDATE_STEPS,
    _outside_limits,
    _record_and_control,
)
from sim_worker.execution_world import ExecutionWorld, execution_world  # noqa: E402
from sim_worker.executor import ExecutionResult, execute_skill, run_skill  # noqa: E402
from sim_worker.robot_model import N_JOINTS, TOOL_LINK  # noqa: E402
from sim_worker.teacher import record_demonstration  # noqa: E402
from sim_worker.world import LoopHandles, SimWorld  # noqa: E402
from skills.compiled import compiled_entry  # noqa: E402
from skills.control import DAMPING_UPDATE_EVERY, ControlFrame, HybridController, LawKernel  # noqa: E402
from skills.control.layouts import (  # noqa: E402
    REFERENCE_SIZE,
    REFERENCE_TWIST,
    ROBOT_POSITION,
    ROBOT_Q,
    ROBOT_QUAT,
    ROBOT_STATE_SIZE,
)
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
FLOOR_SCENARIO = "slide_flat"
"""The skill the project loop is compared with the bare PyBullet loop on (settle, free motion, touch-down, slide)."""
TARGET_FLOOR_RATIO = 1.3
"""Issue 28's target: the project loop within this factor of the bare loop's µs per step."""
SMOKE_RECORD = {"move_duration_s": 2.0}
"""The smoke run's teacher overrides: the same S-curve in 2 s, not 5 (every phase of the loop, fewer steps)."""


def wall_us_per_step(result: ExecutionResult) -> float:
    """The loop's wall time per control step of an execution, µs."""
    return 1e6 * result.loop_wall_s / max(result.metrics.steps, 1)


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
        f"table above, the phases' set-up included). Load average (1, 5, 15 min) at the end: {_load(load)}.",
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
        f"(1, 5, 15 min) before the run {_load(load_before)}, after it {_load(load_after)}.",
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


def _load(load: tuple[float, float, float]) -> str:
    return ", ".join(f"{v:.2f}" for v in load)


def _pybullet_version() -> str:
    try:
        from importlib.metadata import version

        return version("pybullet")
    except Exception:
        return "unknown"


if __name__ == "__main__":
    main()
