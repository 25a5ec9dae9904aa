"""The world a skill executes in, and the skill placed in it: one way to run any skill.

In order of precedence:

1. ``world`` given (a ``WorldConfig`` dict, or the ground-truth file ``contact-skills record --truth`` writes,
   which holds one under ``world_config``): that world ("given");
2. ``scenario`` given: that teacher scenario's world ("scenario");
3. the skill carries the world its demonstration was recorded in (``Skill.taught_world``, simulator
   recordings) and the work piece asked for is ``auto`` or ``taught``: that world ("taught");
4. otherwise the skill is placed in the robot's reach (``sim_worker.placement``; the placement asked for, or one
   chosen), and its work piece, moved with it, is MEASURED from the demonstration when that is given and the work
   piece asked for is ``auto`` or ``measured`` ("measured"), else rebuilt from what the skill learned ("rebuilt";
   ``sim_worker.work_piece``). A skill learned as the wrong type is then tested on the surface its demonstration
   touched, not on one that agrees with its mistake.

A long demonstration whose strokes no single placement reaches (its transfers between them carry the tool farther
than the arm) runs one stroke at a time (``execution_worlds``): each stroke its own skill (``skills.strokes``), placed
on its own, on its own part of the work piece.

The environment's friction, contact stiffness and damping override the world's, its sensor choice sets the sensor the
controller reads (a realistic wrist sensor unless ``ideal`` is asked for, in the fields a given world file does not
set to something of its own; the environment's noise, untared bias and noise seed override the sensor's), its force
scale multiplies the skill's desired forces, and its unknown tilt turns the work piece (not the skill) about the placed
skill's contact centre. Frames: world, metres (docs/CONVENTIONS.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from schemas.demonstration import Demonstration
from schemas.execution import EnvironmentChange, Placement, SensorChoice, WorkPieceSource
from schemas.skill import Skill
from schemas.text import JsonObject
from schemas.world import WorldConfig, WorldOverrides
from sim_worker.placement import PlacementChoice, PlacementError, choose_placement
from sim_worker.sensor import WRIST_SENSOR
from sim_worker.teacher import scenario_world_config
from sim_worker.work_piece import measured_world_config, rebuilt_world_config
from skills.perturbation import contact_centre, force_scaled_skill
from skills.placement import placed_skill, tool_aligned_skill
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix, quaternions_normalized
from skills.strokes import stroke_skills


@dataclass(frozen=True)
class ExecutionWorld:
    """A skill ready to run: the world, the skill (placed) and its demonstration (placed, for the path metric)."""

    config: WorldConfig
    skill: Skill
    demonstration: Demonstration | None
    source: str
    """'given', 'scenario', 'taught', 'measured' or 'rebuilt'."""
    placement: Placement | None
    """The placement applied (measured and rebuilt work pieces only)."""
    placement_reason: str = ""


def world_config_from_file_dict(data: JsonObject) -> WorldConfig:
    """A ``WorldConfig`` from its dict or from a ground-truth dict holding one under ``world_config``.

    Raises ValueError naming unknown fields."""
    if isinstance(data.get("world_config"), dict):
        data = data["world_config"]
    try:
        return WorldConfig.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"world: {exc}") from None


def _sensor_fields_set(world: JsonObject) -> set[str]:
    """The ``SensorConfig`` fields a world dict (or ground-truth dict) sets to something else than the default world's:
    a file written whole (``record --truth``) carries every field, its defaults are not a choice."""
    return set(world_config_from_file_dict(world).sensor.model_dump(exclude_defaults=True))


def _placed_demonstration(demonstration: Demonstration | None, choice: PlacementChoice) -> Demonstration | None:
    """The demonstration moved as its skill: positions, tool orientations (tool alignment included) and the
    world-frame wrenches (forces and moments turn with the placement)."""
    if demonstration is None or choice.is_identity:
        return demonstration
    a = demonstration.arrays()
    positions = a.positions @ choice.rotation.T + choice.translation
    rotations = choice.rotation @ matrix_from_quaternion(a.orientations) @ choice.tool_alignment
    orientations = quaternion_from_matrix(rotations)
    wrenches = np.hstack([a.wrenches[:, :3] @ choice.rotation.T, a.wrenches[:, 3:] @ choice.rotation.T])
    update = {"positions": positions.tolist(), "orientations": orientations.tolist(), "wrenches": wrenches.tolist()}
    return demonstration.model_copy(update=update)


def execution_world(
    skill: Skill,
    environment: EnvironmentChange | None = None,
    *,
    scenario: str | None = None,
    world: JsonObject | None = None,
    overrides: WorldOverrides | None = None,
    demonstration: Demonstration | None = None,
    approach_clearance_m: float = 0.06,
) -> ExecutionWorld:
    """Resolve where ``skill`` runs (see the module). Raises ValueError (PlacementError included) with a message
    naming what to change."""
    env = environment or EnvironmentChange()
    sensor = WRIST_SENSOR.model_dump(exclude_defaults=True) if env.sensor is SensorChoice.wrist else {}
    if world is not None:  # a world file's own sensor is honoured: the wrist sensor fills the fields it leaves out
        sensor = {name: value for name, value in sensor.items() if name not in _sensor_fields_set(world)}
    changes = {"sensor": sensor, **(overrides or {})}
    changes.update(_environment_fields(env))
    skill = force_scaled_skill(skill, env.force_scale)
    source = None
    if world is not None:
        config, source = world_config_from_file_dict(world), "given"
    elif scenario is not None:
        config, source = scenario_world_config(scenario), "scenario"
    elif skill.taught_world is not None and env.work_piece in (WorkPieceSource.auto, WorkPieceSource.taught):
        config, source = world_config_from_file_dict(skill.taught_world), "taught"
    elif env.work_piece is WorkPieceSource.taught:
        raise ValueError(
            "environment.work_piece: the skill carries no taught world (it was not recorded in the simulator); "
            "use 'auto', 'measured' or 'rebuilt'"
        )
    elif env.work_piece is WorkPieceSource.measured and demonstration is None:
        raise ValueError(
            "environment.work_piece: 'measured' needs the demonstration the skill was learned from; give it, or use "
            "'rebuilt'"
        )
    if source is not None:
        if env.placement is not None:
            raise ValueError(
                f"environment.placement: a placement moves a rebuilt work piece; this skill runs in its {source} "
                "world (ask for work_piece 'rebuilt' to place it)"
            )
        return ExecutionWorld(_with(config, _tilt_about(skill, env, changes)), skill, demonstration, source, None)
    if env.placement is not None:
        given = (env.placement.rotation, env.placement.tool_alignment)
        R, A = (matrix_from_quaternion(quaternions_normalized(q)) for q in given)
        choice = PlacementChoice(R, np.asarray(env.placement.translation_m, float), "given", float("nan"), A)
    else:
        choice = choose_placement(skill, approach_clearance_m)
    placed = placed_skill(tool_aligned_skill(skill, choice.tool_alignment), choice.rotation, choice.translation)
    placed_demonstration = _placed_demonstration(demonstration, choice)
    measured = placed_demonstration is not None and env.work_piece is not WorkPieceSource.rebuilt
    try:
        if placed_demonstration is not None and measured:
            config, source = measured_world_config(placed, placed_demonstration), "measured"
        else:
            config, source = rebuilt_world_config(placed), "rebuilt"
    except ValueError as exc:
        raise PlacementError(str(exc)) from None
    placement = Placement(
        translation_m=choice.translation.tolist(),
        rotation=choice.quaternion,
        tool_alignment=choice.tool_alignment_quaternion,
    )
    return ExecutionWorld(
        _with(config, _tilt_about(placed, env, changes)), placed, placed_demonstration, source, placement, choice.reason
    )


def execution_worlds(
    skill: Skill,
    environment: EnvironmentChange | None = None,
    *,
    scenario: str | None = None,
    world: JsonObject | None = None,
    overrides: WorldOverrides | None = None,
    demonstration: Demonstration | None = None,
    approach_clearance_m: float = 0.06,
) -> list[ExecutionWorld]:
    """Where ``skill`` runs, as :func:`execution_world`, in ONE world when a placement reaches the whole skill; else,
    for a skill of several strokes on a measured or rebuilt work piece without a placement given, one world per
    stroke (``skills.strokes.stroke_skills``), each stroke placed on its own on its own part of the work piece, to run
    one after the other. Raises ValueError (PlacementError included) naming what to change, as
    :func:`execution_world` does, when even a stroke cannot be placed."""
    arguments = {
        "scenario": scenario,
        "world": world,
        "overrides": overrides,
        "demonstration": demonstration,
        "approach_clearance_m": approach_clearance_m,
    }
    try:
        return [execution_world(skill, environment, **arguments)]
    except PlacementError:
        strokes = stroke_skills(skill)
        if len(strokes) < 2 or (environment is not None and environment.placement is not None):
            raise
    return [execution_world(stroke, environment, **arguments) for stroke in strokes]


def _environment_fields(env: EnvironmentChange) -> WorldOverrides:
    """The ``WorldConfig`` fields the environment sets (only those it gives: the world's own stay otherwise)."""
    given = {
        "lateral_friction": env.friction,
        "contact_stiffness": env.contact_stiffness_n_m,
        "contact_damping": env.contact_damping_n_s_m,
        "wrench_noise_force_std_n": env.sensor_noise_n,
        "seed": env.noise_seed,
    }
    fields = {name: value for name, value in given.items() if value is not None}
    if any(env.sensor_bias_n):
        fields["wrench_bias_n"] = list(env.sensor_bias_n)
    if any(env.sensor_offset_tool_n):
        fields["wrench_offset_tool_n"] = list(env.sensor_offset_tool_n)
    return fields


def _tilt_about(skill: Skill, env: EnvironmentChange, changes: WorldOverrides) -> WorldOverrides:
    """``changes`` plus the unknown tilt of the work piece about the (placed) skill's contact centre."""
    if not any(env.unknown_tilt_deg):
        return changes
    pivot = contact_centre(skill).tolist()
    return {**changes, "work_piece_tilt_deg": list(env.unknown_tilt_deg), "work_piece_tilt_pivot_m": pivot}


def _with(config: WorldConfig, changes: WorldOverrides) -> WorldConfig:
    try:
        return config.replace(**changes)
    except ValueError as exc:
        raise ValueError(f"world_overrides: {exc}") from None
