"""The bare MuJoCo loop at 1 kHz with the iiwa pressing on the table: its real-time factor, beside the same loop
through ``sim_mujoco.robot.MujocoRobot`` (a joint impedance reading the robot interface every step) and PyBullet's
bare loop (``SimWorld.step``) on the same cell; and the KU Leuven CAD's world (1030 convex pieces) in both engines.

    .venv/bin/python benchmarks/bench_mujoco_loop.py [--steps 3000] [--repeats 5] [--no-write] [--smoke]

Each row: ``repeats`` runs of ``steps`` steps (1 ms each) from the same state, the tool pressing 15 N on the table
(or, in the CAD world, the arm in free space among the pieces); real-time factor = simulated time / wall time,
median (min-max) of the runs.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import machine_line, pin_blas_threads, report_main

pin_blas_threads()

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from schemas.world import WorldConfig  # noqa: E402
from sim_mujoco.model import TOOL_SITE  # noqa: E402
from sim_mujoco.robot import MujocoRobot  # noqa: E402
from sim_mujoco.sensing import true_contact  # noqa: E402
from sim_worker.world import SimWorld  # noqa: E402

PRESS_N = 15.0
"""The force the tool presses the table with, N."""
DOWN = (1.0, 0.0, 0.0, 0.0)
PRESS_XY = (0.6, 0.0)


def pressing_pose(world: SimWorld) -> np.ndarray:
    """Joint positions (rad) with the tool point at the depth the pad takes at :data:`PRESS_N`, pointing down."""
    depth = PRESS_N / world.config.contact.stiffness_n_m
    return world.inverse_kinematics([*PRESS_XY, world.config.table.height_m - depth], DOWN)


def real_time_factors(run: Callable[[int], None], steps: int, repeats: int, dt: float) -> list[float]:
    """Real-time factors of ``repeats`` calls of ``run(steps)`` (simulated ``steps * dt`` s each)."""
    factors = []
    for _ in range(repeats):
        start = time.perf_counter()
        run(steps)
        factors.append(steps * dt / (time.perf_counter() - start))
    return factors


def joint_gains(mass_matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Constant joint stiffness (N·m/rad) and damping (N·m·s/rad) of the bare loops' hold: 100 /s² and 20 /s times
    the mass matrix's diagonal at the start (the light wrist gets gains it can take at 1 kHz)."""
    diagonal = np.diag(mass_matrix)
    return 100.0 * diagonal, 20.0 * diagonal


def bare_mujoco(robot: MujocoRobot, q0: np.ndarray, press_n: float) -> Callable[[int], None]:
    """MuJoCo alone: each step the bias of the current state, a constant joint-space hold of ``q0``
    (:func:`joint_gains`) and a constant push of ``press_n`` (N, down) through the Jacobian at ``q0`` as the applied
    joint torques, then ``mj_step``."""
    model, data = robot.model, robot.data
    robot.reset(q0)
    push = robot.jacobian().T @ np.array([0.0, 0.0, -press_n, 0.0, 0.0, 0.0])
    stiffness, damping = joint_gains(robot.mass_matrix())

    def run(steps: int) -> None:
        robot.reset(q0)
        applied, bias, q, qd = data.qfrc_applied, data.qfrc_bias, data.qpos, data.qvel
        for _ in range(steps):
            applied[:] = bias + push + stiffness * (q0 - q) - damping * qd
            mujoco.mj_step(model, data)

    return run


def interface_loop(robot: MujocoRobot, q0: np.ndarray) -> Callable[[int], None]:
    """A joint impedance (``M (K e - D qd)`` + bias + ``J^T f``) through :class:`MujocoRobot`: the joint state, the
    model queries, the torque command, the step, the true contact and the wrist reading, every step."""
    push = np.array([0.0, 0.0, -PRESS_N, 0.0, 0.0, 0.0])

    def run(steps: int) -> None:
        robot.reset(q0)
        for _ in range(steps):
            q, qd = robot.joint_state()
            tau = robot.gravity_coriolis_torques() + robot.mass_matrix() @ (100.0 * (q0 - q) - 20.0 * qd)
            robot.step(tau + robot.jacobian().T @ push)
            robot.true_contact()
            robot.contact_wrench()

    return run


def bare_pybullet(world: SimWorld, q0: np.ndarray, press_n: float) -> Callable[[int], None]:
    """PyBullet alone on the same cell: the torques of :func:`bare_mujoco` (the bias of the current state, the hold,
    the push of ``press_n``), through ``SimWorld.step``."""
    world.reset(q0)
    push = world.jacobian().T @ np.array([0.0, 0.0, -press_n, 0.0, 0.0, 0.0])
    stiffness, damping = joint_gains(world.mass_matrix())

    def run(steps: int) -> None:
        world.reset(q0)
        for _ in range(steps):
            q, qd = world.joint_state()
            world.step(world.gravity_coriolis_torques() + push + stiffness * (q0 - q) - damping * qd)

    return run


def mujoco_force(robot: MujocoRobot) -> float:
    """The true normal force (N) of the last step MuJoCo took on ``robot``'s data (by the robot or bare)."""
    data = robot.data
    return true_contact(
        robot.model, data, robot.cell.tool_geoms, data.site_xpos[robot.model.site(TOOL_SITE).id]
    ).normal_force_n


def cad_config() -> WorldConfig:
    """The world of the KU Leuven object's CAD where contour_a_1's registration puts it (no placement)."""
    from experiments.kuleuven_cad import cad_world
    from schemas.execution import Placement
    from services.datasets import repository_data_directory
    from services.kuleuven_object import kuleuven_ground_truth

    truth = kuleuven_ground_truth(repository_data_directory() / "kuleuven_contour" / "contour_a_1.csv")
    placement = Placement(translation_m=[0.0, 0.0, 0.0], rotation=[0.0, 0.0, 0.0, 1.0])
    return WorldConfig.from_dict(cad_world(truth, placement))


def build(steps: int, repeats: int) -> str:
    """Run the rows; the report section."""
    load_before = os.getloadavg()[0]
    config, cad = WorldConfig(), cad_config()
    dt = config.time_step_s
    table, pieces = "table, pressing 15 N", f"KU Leuven CAD ({len(cad.work_pieces)} pieces), arm at rest"
    with ExitStack() as worlds:
        world = worlds.enter_context(SimWorld(config))
        q0 = pressing_pose(world)
        robot = MujocoRobot(config, q0)
        start = time.perf_counter()
        cad_robot = MujocoRobot(cad)
        built = time.perf_counter() - start
        cad_world_ = worlds.enter_context(SimWorld(cad))
        home = cad_world_.joint_state()[0]
        cases = [
            (table, "MuJoCo, bare (`mj_step`)", bare_mujoco(robot, q0, PRESS_N), lambda: mujoco_force(robot)),
            (table, "MuJoCo through `MujocoRobot`", interface_loop(robot, q0), lambda: mujoco_force(robot)),
            (table, "PyBullet, bare (`SimWorld.step`)", bare_pybullet(world, q0, PRESS_N),
             lambda: world.true_normal_force()[0]),
            (pieces, f"MuJoCo, bare (model built in {built:.1f} s)", bare_mujoco(cad_robot, home, 0.0),
             lambda: mujoco_force(cad_robot)),
            (pieces, "PyBullet, bare", bare_pybullet(cad_world_, home, 0.0), lambda: cad_world_.true_normal_force()[0]),
        ]  # fmt: skip
        rows = []
        for world_name, engine, run, force in cases:
            rows.append((world_name, engine, real_time_factors(run, steps, repeats, dt), force()))
    bare, through = statistics.median(rows[0][2]), statistics.median(rows[1][2])
    lines = [
        "## MuJoCo: the bare loop's real-time factor (issue 44)",
        "",
        f"Reproduce: `.venv/bin/python benchmarks/bench_mujoco_loop.py --steps {steps} --repeats {repeats}` "
        f"({repeats} run{'s' * (repeats > 1)} of {steps} steps of 1 ms per row, median real-time factor and "
        f"min-max; one BLAS thread, not pinned). MuJoCo {mujoco.__version__}. "
        f"{machine_line(load_at_start=load_before)}",
        "",
        "| world | loop | real-time factor (median, min-max) | µs / step | true normal force at the end |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    for world_name, engine, factors, force in rows:
        median = statistics.median(factors)
        lines.append(
            f"| {world_name} | {engine} | {median:.1f} ({min(factors):.1f}-{max(factors):.1f}) | "
            f"{1e6 * dt / median:.0f} | {force:.2f} N |"
        )
    lines += [
        "",
        f"Through the robot interface the MuJoCo loop runs at {through / bare:.2f} of its bare real-time factor: a "
        "plain-Python joint impedance with its model queries (the mass matrix, the Jacobian, the bias), the true "
        "contact from `mj_contactForce` and the wrist reading every step (the product's compiled loop, "
        "`bench_control_loop`, is not behind it yet). The bare loops step the same cell with the same torques: the "
        "gravity and Coriolis torques of the current state, a constant joint-space hold of the start pose and a "
        "constant push (15 N down on the table, none among the CAD's pieces). PyBullet's bare loop here is "
        "`SimWorld.step` from Python, with its per-step model query; the product's loop calls PyBullet's C API from "
        "compiled code (`bench_control_loop`). Every static body costs PyBullet time at every step (its broad phase "
        "over the CAD's 1030 pieces); MuJoCo's static geoms in the world body cost it far less.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return report_main(
        __doc__.splitlines()[0],
        "bench_mujoco_loop",
        build,
        argv,
        options=(
            ("--steps", {"type": int, "default": 3000, "help": "steps (1 ms) per run"}),
            ("--repeats", {"type": int, "default": 5, "help": "runs per row (median)"}),
        ),
        smoke={"steps": 200, "repeats": 1},
    )


if __name__ == "__main__":
    raise SystemExit(main())
