"""A skill's nominal plan for a real cell (docs/REAL_CELL.md): the phase plans an execution's
:class:`execution.plans.PhasePlanner` builds, in the order :class:`execution.executor.Execution` runs them, when
every phase ends where its plan ends and every surface is met exactly where it was taught.

What only a robot can decide is left out or fixed: no tare holds (an ideal sensor), the guarded approach cut where
the taught surface is (a cell's own guard ends it where its surface is), the touch-down at the settings' speed
(else :data:`NOMINAL_TOUCHDOWN_SPEED_M_S`: the simulator plans it from the arm's apparent mass and the pad), creases
passed unslowed (their speed too comes from the arm's mass), no surface following and no relocation (online, from
the forces read).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from execution.executor import LIFT_OFF_SPEED_M_S
from execution.plans import PhasePlan, PhasePlanner, first_force
from schemas.execution import ControllerKind, ExecutionPhase, ExecutionSettings
from schemas.execution.environment import Placement
from schemas.skill import Segment, SegmentKind, Skill
from schemas.skill_plan import MAX_PLAN_SAMPLES, SKILL_PLAN_FORMAT, SKILL_PLAN_VERSION, PlanSamples, SkillPlan
from skills.control import HybridController
from skills.job_estimate import LIFT_OFF_M
from skills.placement import placed_skill, tool_aligned_skill
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix, quaternions_normalized

CONTROL_PERIOD_S = 1e-3
"""The control step the plan is computed at, s (the simulated cell's 1 kHz loop)."""
NOMINAL_TOUCHDOWN_SPEED_M_S = 0.005
"""The touch-down speed of an exported plan when the settings give none, m/s. The simulator plans its own from the
arm's apparent mass along CF z and the pad (``execution.impacts``), which an export does not know: a cell with a
stiffer pad or a heavier arm gives ``touchdown_speed_m_s`` in the settings."""


def _cut(plan: PhasePlan, n: int) -> PhasePlan:
    """``plan``'s first ``n`` steps."""
    return dataclasses.replace(
        plan, ref_p=plan.ref_p[:n], ref_q=plan.ref_q[:n], ref_twist=plan.ref_twist[:n], force=plan.force[:n]
    )


def _approach_to_taught_surface(plan: PhasePlan, start_world: NDArray[np.float64], z: NDArray[np.float64]) -> PhasePlan:
    """A guarded approach ``plan`` ended at the first step on or beyond the taught contact point ``start_world`` (m,
    world) along CF z ``z``: where a surface that is where it was taught stops it."""
    beyond = np.nonzero((plan.ref_p - start_world) @ z >= 0.0)[0]
    return _cut(plan, int(beyond[0]) + 1 if beyond.size else plan.steps)


def placed(skill: Skill, placement: Placement | None) -> Skill:
    """``skill`` in the robot's world: its tool frame aligned, then rotated and moved by ``placement`` (as
    ``sim_worker.execution_world`` places a rebuilt work piece); as stored without one."""
    if placement is None:
        return skill
    R, A = (matrix_from_quaternion(quaternions_normalized(q)) for q in (placement.rotation, placement.tool_alignment))
    return placed_skill(tool_aligned_skill(skill, A), R, np.asarray(placement.translation_m, dtype=float))


def nominal_phase_plans(skill: Skill, settings: ExecutionSettings, dt: float = CONTROL_PERIOD_S) -> list[PhasePlan]:
    """The phase plans of an execution of ``skill`` (already placed in the robot's world) with ``settings``, each
    starting where the previous one ends, the surfaces met where taught (module docstring), in execution order."""
    controller = HybridController(ControllerKind(settings.controller), settings.gains, dt=dt)
    planner = PhasePlanner(skill, settings, controller, np.asarray(settings.environment.offset, dtype=float), dt)
    geometry, gains = planner.geometry, settings.gains
    speed = settings.touchdown_speed_m_s or NOMINAL_TOUCHDOWN_SPEED_M_S
    segments = skill.segments
    first = segments[0]
    q = np.asarray(first.orientation_dmp.start, dtype=float)
    if first.kind is SegmentKind.contact:
        p = (
            geometry[first.index].start_world
            - settings.approach_clearance_m * geometry[first.index].first_rotation[:, 2]
        )
    else:
        p = np.asarray(first.position_dmp.start, dtype=float) + planner.offset
    plans = [planner.still(ExecutionPhase.settle, -1, p, q, settings.settle_s)]
    f_last: float | None = None
    exit_from: NDArray[np.float64] | None = None  # where the last contact run lifted off (the way out starts there)

    def add(plan: PhasePlan) -> None:
        nonlocal p, q
        plans.append(plan)
        p, q = plan.ref_p[-1], plan.ref_q[-1]

    for i, segment in enumerate(segments):
        nxt: Segment | None = segments[i + 1] if i + 1 < len(segments) else None
        if segment.kind is SegmentKind.free:
            if nxt is not None and nxt.kind is SegmentKind.contact:
                z = geometry[nxt.index].first_rotation[:, 2]
                add(planner.free(segment, p, q, geometry[nxt.index].start_world - settings.approach_clearance_m * z, z))
            else:
                dmp = segment.position_dmp
                goal = np.asarray(dmp.goal, float) + planner.offset
                if exit_from is not None:  # the way out as taught from where the contact ended
                    goal = exit_from + np.asarray(dmp.goal, float) - np.asarray(dmp.start, float)
                add(planner.free(segment, p, q, goal, None))
            exit_from = None
            continue
        geo = geometry[segment.index]
        if f_last is None:  # a contact run begins: touch down where taught, ramp the force in holding the place
            approach = planner.approach(segment, p, q, speed)
            add(_approach_to_taught_surface(approach, geo.start_world, geo.first_rotation[:, 2]))
            add(planner.hold(segment, ExecutionPhase.approach, p, 0.0, first_force(segment), gains.force_ramp_s, q,
                             geo.first_rotation))  # fmt: skip
        contact = planner.contact(segment, p, q, f_last)
        add(contact)
        f_last = float(contact.force[-1])
        if nxt is None or nxt.kind is SegmentKind.free:
            last_cf = (
                contact.learned_rotations[-1] if contact.learned_rotations is not None else contact.frame.cf_rotation
            )
            add(planner.hold(segment, ExecutionPhase.retreat, p, f_last, 0.0, gains.force_release_s, q, last_cf,
                             at_end=True))  # fmt: skip
            z = last_cf[:, 2]
            add(planner.transfer(segment.index, p, q, p - LIFT_OFF_M * z, q, None, ExecutionPhase.retreat,
                                 LIFT_OFF_SPEED_M_S))  # fmt: skip
            exit_from, f_last = p, None
    return plans


def _frame_rows(plan: PhasePlan, selection: list[float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per step of ``plan``: the CF rotation (n, 3, 3), world from CF, and the selection diagonal (n, 6)."""
    n = plan.steps
    if plan.learned_rotations is not None:  # a contour: one learned frame every ``stride`` steps
        rotations = plan.learned_rotations[np.minimum(np.arange(n) // plan.stride, len(plan.learned_rotations) - 1)]
        return rotations, np.broadcast_to(np.asarray(selection, dtype=float), (n, 6))
    return np.broadcast_to(plan.frame.cf_rotation, (n, 3, 3)), np.broadcast_to(plan.frame.selection, (n, 6))


class PlanTooLongError(ValueError):
    """The plan holds more samples than asked for at most (``max_samples``)."""


def skill_plan(
    skill: Skill,
    settings: ExecutionSettings | None = None,
    placement: Placement | None = None,
    every: int = 1,
    max_samples: int = MAX_PLAN_SAMPLES,
    skill_id: str | None = None,
    dt: float = CONTROL_PERIOD_S,
) -> SkillPlan:
    """The exported plan of ``skill`` placed by ``placement`` and executed with ``settings`` (default ones), one
    sample every ``every`` control steps of ``dt`` s. :class:`PlanTooLongError` when that is more than
    ``max_samples`` samples."""
    settings = settings or ExecutionSettings()
    skill = placed(skill, placement)
    plans = nominal_phase_plans(skill, settings, dt)
    steps = sum(plan.steps for plan in plans)
    keep = np.arange(0, steps, every)
    if keep.size > max_samples:
        raise PlanTooLongError(
            f"the plan has {keep.size} samples ({steps * dt:.1f} s at every={every}), more than max_samples "
            f"{max_samples}: ask for every={-(-steps // max_samples)} or more"
        )
    selections = {s.index: s.selection for s in skill.segments}
    frames = [_frame_rows(plan, selections.get(plan.segment, [1.0] * 6)) for plan in plans]
    rows = np.concatenate([plan.reference_rows() for plan in plans])[keep]
    rotations = np.concatenate([f[0] for f in frames])[keep]
    selection = np.concatenate([f[1] for f in frames])[keep]
    phases = np.concatenate([np.full(plan.steps, plan.phase.value, dtype=object) for plan in plans])[keep]
    segment = np.concatenate([np.full(plan.steps, plan.segment) for plan in plans])[keep]
    samples = PlanSamples.model_construct(
        t=(keep * dt).tolist(),
        phase=[ExecutionPhase(p) for p in phases],
        segment=segment.tolist(),
        position_m=rows[:, 0:3].tolist(),
        orientation=rows[:, 3:7].tolist(),
        twist=rows[:, 7:13].tolist(),
        cf_orientation=quaternion_from_matrix(rotations).tolist(),
        cf_origin_m=rows[:, 0:3].tolist(),
        selection=selection.astype(int).tolist(),
        force_n=rows[:, 13].tolist(),
    )
    plan = SkillPlan.model_construct(
        format=SKILL_PLAN_FORMAT,
        version=SKILL_PLAN_VERSION,
        skill_id=skill_id,
        skill_type=skill.skill_type.value,
        controller=ControllerKind(settings.controller),
        gains=settings.gains,
        placement=placement,
        control_period_s=dt,
        every=every,
        touchdown_speed_m_s=settings.touchdown_speed_m_s or NOMINAL_TOUCHDOWN_SPEED_M_S,
        samples=samples,
    )
    return plan
