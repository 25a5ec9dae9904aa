"""Execute a learned skill in the simulated world (PyBullet or MuJoCo) with the hybrid controller (the paper's
section 6).

``execute_skill(skill, world_config, settings)`` builds the robot of the engine ``settings.engine`` names (none: the
world's ``engine``, else ``schemas.execution.DEFAULT_ENGINE``: ``schemas.world.engine_to_run``; a worker fills in the
world's or its own before) in the taught world plus the known and the unknown offset of the work piece: PyBullet's
``SimWorld`` and its compiled 1 kHz loop (``sim_worker.control_loop.ControlLoop``), or MuJoCo's
``sim_mujoco.robot.MujocoRobot`` and its loop (``sim_mujoco.loop.MujocoLoop``), and hands them to
``execution.executor.Execution``, which sequences the phases (settle, free motion, guarded approach, contact,
retreat: its docstring) apart from the engine; the metrics and the verdict come from ``execution.metrics`` (the
metrics name the engine).
Every control step is recorded as one row of a float array (:data:`schemas.execution.TELEMETRY_COLUMNS`) and handed
to ``on_sample`` in batches of ``telemetry_batch`` rows (a :class:`Telemetry` view). Aborts (force limit, torque
limit, joint limit, contact not found, non-finite values, ``should_abort()``) stop the loop cleanly and are reported
in the metrics; nothing is ever NaN.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from execution.executor import Execution
from execution.metrics import compute_metrics
from execution.robot import SimulatedRobot
from execution.runner import PhaseRunner
from execution.telemetry import Telemetry
from schemas.demonstration import Demonstration
from schemas.execution import (
    Engine,
    ExecutionMetrics,
    ExecutionPhase,
    ExecutionSettings,
    NullSpaceProjection,
)
from schemas.skill import Skill
from schemas.world import WorldConfig, engine_to_run
from sim_worker.control_loop import ControlLoop
from sim_worker.execution_world import ExecutionWorld
from sim_worker.world import SimWorld
from skills.control import HybridController


@dataclass
class ExecutionResult:
    """What ``execute_skill`` returns: the metrics, the recorded telemetry and how long things took."""

    metrics: ExecutionMetrics
    telemetry: Telemetry
    world_config: WorldConfig
    """The simulated world (the taught one plus the known and unknown offsets)."""
    setup_s: float
    """Wall time to build the world, solve IK and precompute before the loop, s."""
    loop_wall_s: float
    """Wall time of the control loop, s."""
    loop_cpu_s: float = 0.0
    """CPU time of the control loop's thread, s (on a loaded machine the wall time also counts other processes')."""

    @property
    def phase(self) -> ExecutionPhase:
        return self.metrics.phase

    @property
    def abort_reason(self) -> str | None:
        return self.metrics.abort_reason


# ---------------------------------------------------------------------------------------------------------------


def shifted_world_config(config: WorldConfig, offset: list[float] | NDArray[np.float64]) -> WorldConfig:
    """Return ``config`` with its work piece moved by ``offset`` [dx, dy, dz] (m, world).

    The work piece is the rebuilt one (``work_pieces``) when the world has one, else the contour object(s)
    (cylinder, curved block) when it has any, else the table (with its ramp): the table centre and height move,
    so the table top plane moves by ``offset``. The pivot of an unknown tilt moves with it.
    """
    d = np.asarray(offset, dtype=float)
    if not np.any(d):
        return config
    config = config.replace(work_piece_tilt={"pivot_m": (np.asarray(config.work_piece_tilt.pivot_m) + d).tolist()})
    if config.work_pieces:
        moved = [{**p.model_dump(), "vertices": (np.asarray(p.vertices) + d).tolist()} for p in config.work_pieces]
        return config.replace(work_pieces=moved)
    if config.cylinder.enabled or config.block.enabled:
        changes = {}
        if config.cylinder.enabled:
            changes["cylinder"] = {"offset_m": (np.asarray(config.cylinder.offset_m) + d).tolist()}
        if config.block.enabled:
            changes["block"] = {"offset_m": (np.asarray(config.block.offset_m) + d).tolist()}
        return config.replace(**changes)
    cx, cy = config.table.center_xy
    return config.replace(table={"center_xy": (cx + d[0], cy + d[1]), "height_m": config.table.height_m + d[2]})


def execute_skill(
    skill: Skill,
    world_config: WorldConfig,
    settings: ExecutionSettings | None = None,
    *,
    on_sample: Callable[[Telemetry], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
    should_pause: Callable[[], bool] | None = None,
    demonstration: Demonstration | None = None,
    work_piece: str | None = None,
) -> ExecutionResult:
    """Execute ``skill`` in ``world_config`` and return metrics and telemetry (:func:`run_skill` chooses the world).

    ``settings`` (an ``ExecutionSettings`` or an ``ExecutionRequest``) gives the environment change,
    controller kind, gains, guarded approach and pace. ``on_sample(telemetry)`` gets every recorded step,
    in batches of ``settings.telemetry_batch`` rows (a :class:`Telemetry`; the last batch may be shorter).
    ``should_abort()`` is polled after every control step; True stops the execution ("aborted on request")
    before the next step, so at most one more step is recorded after the flag is raised.
    ``should_pause()`` is polled before every control step; while True the controller holds the current
    reference (zero reference twist, desired force held) and the loop keeps running (simulated time and
    telemetry go on; the plan does not advance). With pace ``fast`` the caller should throttle while paused.
    ``demonstration``, if given, is the path the path metric compares with (else the nominal DMP path);
    ``work_piece`` where the world's work piece came from (``ExecutionWorld.source``: one rebuilt from the skill
    cannot show it wrong, and the verdict says so).
    Never raises for a failed execution: the metrics say ``aborted`` / ``failed`` and why.
    """
    settings = settings or ExecutionSettings()
    t_setup = time.perf_counter()
    env = settings.environment
    config = shifted_world_config(world_config, np.asarray(env.offset, float) + np.asarray(env.unknown_offset, float))
    engine = engine_to_run(settings.engine, config.engine)
    world: SimulatedRobot
    loop_type: Callable[..., PhaseRunner]
    if engine is Engine.mujoco:  # MuJoCo loaded by the executions that ask for it only
        from sim_mujoco.loop import MujocoLoop
        from sim_mujoco.robot import MujocoRobot

        world, loop_type = MujocoRobot(config), MujocoLoop
    else:
        world, loop_type = SimWorld(config), ControlLoop
    dynamic_null = settings.gains.null_space is NullSpaceProjection.dynamic

    def control_loop(controller: HybridController, capacity_s: float) -> PhaseRunner:
        return loop_type(world, controller, capacity_s, settings.telemetry_batch, settings.pace, dynamic_null,
                         on_sample, should_abort, should_pause)  # fmt: skip

    execution = Execution(
        skill, settings, world, control_loop, (config.contact.stiffness_n_m, config.contact.damping_n_s_m)
    )
    setup_s = time.perf_counter() - t_setup
    loop = execution.loop
    loop.wall_start = time.perf_counter()
    cpu_start = time.thread_time()
    phase, reason = execution.outcome()
    loop_wall_s = time.perf_counter() - loop.wall_start
    loop_cpu_s = time.thread_time() - cpu_start
    loop.emit(final=True)
    world.close()
    tel = loop.telemetry(copy=False)  # the loop is done
    log = execution.log(work_piece)
    metrics = compute_metrics(skill, tel, settings, phase, reason, loop_wall_s, log, demonstration, execution.dt)
    metrics = metrics.model_copy(update={"engine": engine})
    return ExecutionResult(
        metrics=metrics,
        telemetry=tel,
        world_config=config,
        setup_s=setup_s,
        loop_wall_s=loop_wall_s,
        loop_cpu_s=loop_cpu_s,
    )


def run_skill(
    world: ExecutionWorld,
    settings: ExecutionSettings | None = None,
    *,
    on_sample: Callable[[Telemetry], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
    should_pause: Callable[[], bool] | None = None,
) -> ExecutionResult:
    """Execute a resolved :class:`ExecutionWorld` (``sim_worker.execution_world.execution_world``): its placed skill
    in its world, the metrics saying which work piece and placement it ran on (else as :func:`execute_skill`)."""
    result = execute_skill(
        world.skill,
        world.config,
        settings,
        on_sample=on_sample,
        should_abort=should_abort,
        should_pause=should_pause,
        demonstration=world.demonstration,
        work_piece=world.source,
    )
    result.metrics = result.metrics.model_copy(update={"work_piece": world.source, "placement": world.placement})
    return result
