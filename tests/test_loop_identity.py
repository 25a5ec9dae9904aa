"""The control loop steps its world through PyBullet's C API from compiled calls (``SimWorld.loop_handles``,
``sim_worker.bullet_client``), not through ``SimWorld.sense`` / ``SimWorld.step``: it must leave the world exactly as
those would have, the same states, the same clipped torques counted, and a sensor that sampled every state once (its
noise, delay and filter go on alike afterwards).

No mocked physics: two worlds of the same configuration, one run by the loop, the other stepped through the world's
own calls, through PyBullet's Python API, with the torques the loop commanded (captured as it sent them).
"""

from __future__ import annotations

import numpy as np
import pybullet
import pytest

from execution.plans import PhasePlan
from schemas.execution import ExecutionPhase, Pace
from schemas.skill import SELECTION_CONTACT
from schemas.world import WorldConfig
from sim_worker import control_loop
from sim_worker.bullet_client import BulletClient
from sim_worker.control_loop import NULL_SPACE_UPDATE_STEPS, ControlLoop, ExecutionAbortError
from sim_worker.sensor import WRIST_SENSOR
from sim_worker.world import SimWorld
from skills.control import HybridController


def through_python(world: SimWorld) -> None:
    """``world``'s arm queried and driven through PyBullet's Python API (``BulletClient`` not compiled)."""
    bullet = world.loop_handles().bullet
    world._arm.bullet = BulletClient(bullet.client_id, bullet.body, bullet.queried, bullet.link, compiled=False)


def captured_torques(monkeypatch: pytest.MonkeyPatch) -> list[np.ndarray]:
    """The torques the loop's next phases send, appended as they are sent (``control_loop.stepper`` wrapped)."""
    sent: list[np.ndarray] = []
    stepper = control_loop.stepper

    def capturing(handles):
        advance = stepper(handles)

        def capture(ids, tau):
            sent.append(tau.copy())
            advance(ids, tau)

        return capture

    monkeypatch.setattr(control_loop, "stepper", capturing)
    return sent


STEPS = 3000
DESCENT_STEPS = 2000
"""The reference descends over these steps (at ~0.1 m/s, as a slow touch-down), then holds."""


@pytest.mark.parametrize("sensor", ["ideal", "wrist"])
@pytest.mark.parametrize(
    ("depth_m", "abort"), [(0.2, None), (0.3, "force limit")], ids=["pressing", "aborted on the force limit"]
)
def test_the_loop_leaves_the_world_as_its_own_calls_would(sensor: str, depth_m: float, abort, monkeypatch) -> None:
    """The reference goes ``depth_m`` down from the start, into the table under the tool: the tool presses on it
    (and, deeper, presses too hard: the loop stops before the step, with its reason)."""
    config = WorldConfig(sensor=WRIST_SENSOR) if sensor == "wrist" else WorldConfig()
    with SimWorld(config) as looped, SimWorld(config) as stepped:
        through_python(stepped)
        assert looped.loop_handles().bullet.compiled
        controller = HybridController(posture=looped.joint_state()[0], torque_limits=looped.torque_limits)
        frame = controller.frame(np.diag([1.0, -1.0, -1.0]), np.ones(6))
        p, q = looped.tool_pose()
        descent = np.minimum(np.arange(STEPS) / DESCENT_STEPS, 1.0) * depth_m
        ref_p = p - descent[:, None] * [0.0, 0.0, 1.0]
        twist = np.zeros((STEPS, 6))
        twist[1:, :3] = np.diff(ref_p, axis=0) / config.time_step_s
        plan = PhasePlan(ExecutionPhase.contact, 0, ref_p, np.tile(q, (STEPS, 1)), twist, np.zeros(STEPS), frame=frame)
        loop = ControlLoop(looped, controller, 1.0, 100, Pace.fast, True, None, None, None)
        sent = captured_torques(monkeypatch)
        if abort is None:
            loop.run_plan(plan)
        else:
            with pytest.raises(ExecutionAbortError, match=abort):
                loop.run_plan(plan)
        touched = 0
        for tau in sent:  # what the loop did, through the world's own calls: sense, then step
            touched += stepped.sense().in_contact
            stepped.step(tau)

        assert looped.step_count == stepped.step_count == loop.step_count == len(sent)
        assert len(sent) == STEPS if abort is None else len(sent) < STEPS
        assert len(loop.telemetry()) == len(sent) + (abort is not None)  # the aborted step was recorded
        assert touched > 0 and loop.touched  # it pressed on the table
        assert looped.clip_count == stepped.clip_count
        assert looped.last_step_clipped == stepped.last_step_clipped
        np.testing.assert_array_equal(loop.telemetry().in_contact[: len(sent)].sum(), touched)
        for world_a, world_b in ((looped, stepped), (stepped, looped)):  # either read first: the same
            for read in ("joint_state", "tool_pose"):
                for a, b in zip(getattr(world_a, read)(), getattr(world_b, read)(), strict=True):
                    np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(world_a.robot_state(), world_b.robot_state())
            np.testing.assert_array_equal(world_a.mass_matrix(), world_b.mass_matrix())
            np.testing.assert_array_equal(world_a.true_contact_wrench(), world_b.true_contact_wrench())
            np.testing.assert_array_equal(world_a.contact_wrench(), world_b.contact_wrench())
            assert world_a.in_contact() == world_b.in_contact()
        for _ in range(3):  # the sensors go on alike: each state was sampled once
            looped.step(sent[-1])
            stepped.step(sent[-1])
            np.testing.assert_array_equal(looped.contact_wrench(), stepped.contact_wrench())


@pytest.mark.parametrize("sensor", ["ideal", "wrist"])
def test_the_loop_through_pybullets_python_api_records_the_same_telemetry(sensor: str) -> None:
    """Where PyBullet's client cannot be reached from compiled code, the loop calls the same queries and step through
    PyBullet's Python API (``compiled_calls.state_reader`` / ``stepper``'s fallbacks): the same run, row for row."""
    config = WorldConfig(sensor=WRIST_SENSOR) if sensor == "wrist" else WorldConfig()
    telemetry = []
    for compiled in (True, False):
        with SimWorld(config) as world:
            if not compiled:
                through_python(world)
            assert world.loop_handles().bullet.compiled == compiled
            controller = HybridController(posture=world.joint_state()[0], torque_limits=world.torque_limits)
            frame = controller.frame(np.diag([1.0, -1.0, -1.0]), np.ones(6))
            p, q = world.tool_pose()
            descent = np.minimum(np.arange(STEPS) / DESCENT_STEPS, 1.0) * 0.2
            ref_p = p - descent[:, None] * [0.0, 0.0, 1.0]
            twist = np.zeros((STEPS, 6))
            twist[1:, :3] = np.diff(ref_p, axis=0) / config.time_step_s
            plan = PhasePlan(ExecutionPhase.contact, 0, ref_p, np.tile(q, (STEPS, 1)), twist, np.zeros(STEPS),
                             frame=frame)  # fmt: skip
            loop = ControlLoop(world, controller, 1.0, 100, Pace.fast, True, None, None, None)
            loop.run_plan(plan)
            telemetry.append(loop.telemetry().data)
            assert loop.touched  # it pressed on the table
    np.testing.assert_array_equal(telemetry[0], telemetry[1])


@pytest.mark.parametrize("updates_done", [1, 4], ids=["inside the compiled step", "with the damping, in Python"])
def test_a_non_finite_arm_state_on_a_model_update_stops_the_loop_before_its_torque(updates_done: int) -> None:
    """A model update makes the null-space model in one compiled call, except the one in five that also rebuilds the
    adaptive damping in the controller's Python (``LawKernel.refresh``): either way a non-finite Jacobian stops the
    loop with the same reason, the step recorded and no torque commanded."""
    steps = NULL_SPACE_UPDATE_STEPS * updates_done  # the next step makes the next model update
    with SimWorld() as world:
        controller = HybridController(posture=world.joint_state()[0], torque_limits=world.torque_limits)
        frame = controller.frame(np.diag([1.0, -1.0, -1.0]), np.ones(6))
        p, q = world.tool_pose()
        plan = PhasePlan(ExecutionPhase.free, 0, np.tile(p, (steps, 1)), np.tile(q, (steps, 1)),
                         np.zeros((steps, 6)), np.zeros(steps), frame=frame)  # fmt: skip
        loop = ControlLoop(world, controller, 1.0, 100, Pace.fast, True, None, None, None)
        loop.run_plan(plan)
        assert controller.model.damping_due(True) == (updates_done == 4)
        pybullet.resetJointState(world.robot, 3, float("nan"), 0.0, physicsClientId=world.client_id)
        with pytest.raises(ExecutionAbortError, match=r"non-finite value \(NaN or inf\) in jacobian, q,"):
            loop.run_plan(plan)
        assert loop.step_count == steps and len(loop.telemetry()) == steps + 1


def test_a_compiled_entry_is_the_dispatchers_own_specialization_for_those_types() -> None:
    """``compiled_entry`` hands out the specialization the dispatcher would call for these argument types (the same
    result, without its per-call typing), and another one for other types."""
    import numba

    from sim_worker.control_loop import _outside_limits
    from skills.compiled import compiled_entry

    lower, upper = np.zeros(3), np.ones(3)
    entry = compiled_entry(_outside_limits, (np.full(3, 0.5), lower, upper))
    assert entry is _outside_limits.overloads[(numba.typeof(lower),) * 3].entry_point
    for q in (np.full(3, 0.5), np.array([0.5, 1.5, 0.5]), np.array([-0.1, 0.5, 0.5])):
        assert entry(q, lower, upper) == _outside_limits(q, lower, upper) == bool(np.any((q < 0) | (q > 1)))
    integers = compiled_entry(_outside_limits, (np.zeros(3, dtype=np.int64), lower, upper))
    assert integers is not entry and integers(np.array([0, 2, 0]), lower, upper)
    # Kept by a key cheaper than numba's typing, which still tells apart every type numba tells apart: a strided
    # view, a read-only array, each gets the dispatcher's own specialization for it, not the contiguous one's.
    assert compiled_entry(_outside_limits, (np.ones(3), np.zeros(3), np.ones(3))) is entry
    strided, frozen = np.zeros(6)[::2], np.full(3, 2.0)
    frozen.flags.writeable = False
    for q in (strided, frozen):
        other = compiled_entry(_outside_limits, (q, lower, upper))
        assert other is not entry
        assert (
            other is _outside_limits.overloads[(numba.typeof(q), numba.typeof(lower), numba.typeof(upper))].entry_point
        )
        assert other(q, lower, upper) == bool(np.any((q < 0) | (q > 1)))


@pytest.mark.parametrize("dynamic_null", [True, False], ids=["dynamic projector", "static projector"])
def test_the_loops_kernel_commands_the_torques_of_the_controllers_own_step(dynamic_null: bool, monkeypatch) -> None:
    """The loop runs the law through the phase's ``LawKernel`` (its compiled step on the kernel's buffer; the
    null-space model in a compiled call, the damping's rebuild in one update of five and a new frame in Python);
    ``HybridController.step`` runs the same law on its own. Pressing 15 N on the table with force control along CF z,
    a second controller stepped through the second world's own calls, at the same model updates, commands the torques
    the loop sent to the last bit, and the force reached is the one asked for (the physics outcome)."""
    with SimWorld() as looped, SimWorld() as stepped:
        posture = looped.joint_state()[0]
        controllers = [HybridController(posture=posture, torque_limits=looped.torque_limits) for _ in range(2)]
        frames = [c.frame(np.diag([1.0, -1.0, -1.0]), SELECTION_CONTACT) for c in controllers]
        p, q = looped.tool_pose()
        descent = np.minimum(np.arange(STEPS) / DESCENT_STEPS, 1.0) * 0.2
        ref_p = p - descent[:, None] * [0.0, 0.0, 1.0]
        twist = np.zeros((STEPS, 6))
        twist[1:, :3] = np.diff(ref_p, axis=0) / looped.config.time_step_s
        force = np.full(STEPS, 15.0)
        plan = PhasePlan(ExecutionPhase.approach, 0, ref_p, np.tile(q, (STEPS, 1)), twist, force, frame=frames[0])
        loop = ControlLoop(looped, controllers[0], 1.0, 100, Pace.fast, dynamic_null, None, None, None)
        sent = captured_torques(monkeypatch)
        loop.run_plan(plan)
        references = plan.reference_rows()
        cf_z = frames[1].cf_rotation[:, 2].tolist()
        for k, tau in enumerate(sent):
            robot, wrench = stepped.robot_state(), stepped.contact_wrench()
            fx, fy, fz = wrench[:3].tolist()
            pressing = fx * cf_z[0] + fy * cf_z[1] + fz * cf_z[2] > min(0.5, 0.5 * force[k])  # the loop's flag
            update = k % NULL_SPACE_UPDATE_STEPS == 0
            mass = stepped.mass_matrix() if update and dynamic_null else None
            out = controllers[1].step(frames[1], robot, references[k], wrench, pressing, mass, update)
            assert out.abort_reason is None
            np.testing.assert_array_equal(out.tau, tau, err_msg=f"step {k}")
            stepped.step(tau)
        pressed = loop.recent(0.1).wrench_cf[:, 2]
        assert abs(float(pressed.mean()) - 15.0) < 0.2
