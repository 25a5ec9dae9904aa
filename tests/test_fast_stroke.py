"""Why a fast stroke differs between the engines (docs/ENGINES.md, *A fast stroke*): the same 15 N press dragged along
the table at about 0.2 m/s on both. MuJoCo's soft friction lifts the tool out of its pad's compression by
``μ c v / k`` while its normal force stays the engines' same; PyBullet's pad keeps its compression (real engines, no
mocks)."""

from __future__ import annotations

import numpy as np
import pytest
from test_mujoco import DOWN, PRESS_XY, pose_above_table, press

from experiments.fast_stroke import lift_m
from schemas.world import WorldConfig
from sim_mujoco.robot import MujocoRobot
from sim_worker.world import SimWorld

FORCE_N = 15.0
STROKE_M, STROKE_STEPS = 0.1, 500
"""10 cm in 0.5 s: the fast stroke's slip speed (its 1 s and 2 s strokes slide at 0.15-0.3 m/s)."""


def slide(engine: MujocoRobot | SimWorld, start: np.ndarray, end: np.ndarray) -> tuple[float, float, float]:
    """Press ``start`` with :data:`FORCE_N` for 0.3 s, then drag a stiff joint impedance's target to ``end`` in
    :data:`STROKE_STEPS` steps; over the stroke's second half the medians of the slip speed (m/s), the tool point's
    height above where it started (m) and the true normal force (N)."""
    press(engine, start, FORCE_N, 300)
    z0 = engine.tool_pose()[0][2]
    rows = []
    for s in np.linspace(0.0, 1.0, STROKE_STEPS):
        x0 = engine.tool_pose()[0]
        press(engine, (1.0 - s) * start + s * end, FORCE_N, 1, stiffness=400.0)
        x1 = engine.tool_pose()[0]
        rows.append((np.linalg.norm(x1[:2] - x0[:2]) / engine.time_step_s, x1[2] - z0, engine.true_normal_force()[0]))
    speed, rise, force = np.median(np.array(rows)[STROKE_STEPS // 2 :], axis=0)
    return float(speed), float(rise), float(force)


@pytest.fixture(scope="module")
def strokes():
    """The same stroke on PyBullet and on MuJoCo: ``{engine: (speed, rise, force)}``."""
    config = WorldConfig()
    with SimWorld(config) as world:
        depth = FORCE_N / config.contact.stiffness_n_m
        start = pose_above_table(world, depth)
        goal = [PRESS_XY[0] + STROKE_M, PRESS_XY[1], config.table.height_m - depth]
        end = world.inverse_kinematics(goal, DOWN, q_seed=start)
        world.set_joint_positions(start)
        bullet = slide(world, start, end)
    return {"pybullet": bullet, "mujoco": slide(MujocoRobot(config, q=start), start, end)}


def test_mujocos_soft_friction_lifts_a_fast_sliding_tool_by_mu_c_v_over_k(strokes):
    """Measured: both slide at 0.189 m/s pressing 13.5 N (PyBullet) and 14.0 N (MuJoCo); PyBullet's tool rises
    0.08 mm (the impedance's lag), MuJoCo's 0.43 mm: 0.35 mm more, against ``μ c v / k`` = 0.2 × 300 × 0.188 / 3e4 =
    0.38 mm, most of the 0.5 mm the pad is compressed at 15 N: at ``F / (μ c)`` = 0.25 m/s the tool leaves the
    table (with ``impratio`` 100: 0.45 mm, 0.37 mm more)."""
    (v_bullet, rise_bullet, f_bullet), (v_mujoco, rise_mujoco, f_mujoco) = strokes["pybullet"], strokes["mujoco"]
    assert v_mujoco == pytest.approx(v_bullet, rel=0.05) and v_mujoco > 0.15
    # the same force (3.6 % apart): a press lighter by the 0.37 mm would be 11 N lighter
    assert f_mujoco == pytest.approx(f_bullet, rel=0.1)
    assert rise_bullet < 0.15e-3
    assert rise_mujoco - rise_bullet == pytest.approx(lift_m(v_mujoco, WorldConfig()), rel=0.15)
