"""The world a skill executes in, and the skill placed in it: one way to run any skill.

In order of precedence:

1. ``world`` given (a ``WorldConfig`` dict, or the ground-truth file ``contact-skills record --truth`` writes,
   which holds one under ``world_config``): that world ("given");
2. ``scenario`` given: that teacher scenario's world ("scenario");
3. the skill carries the world its demonstration was recorded in (``Skill.taught_world``, simulator
   recordings) and the work piece asked for is ``auto`` or ``taught``: that world ("taught");
4. otherwise the work piece is rebuilt from the skill (``sim_worker.work_piece``) and the skill is placed in the
   robot's reach (``sim_worker.placement``; the placement asked for, or one chosen), the skill and its work piece
   moved together ("rebuilt").

The environment's friction, contact stiffness and damping override the world's, its sensor choice sets the sensor the
controller reads (a realistic wrist sensor unless ``ideal`` is asked for; its noise, untared bias and noise seed
override the sensor's), its force scale multiplies the skill's desired forces, and its unknown tilt turns the work
piece (not the skill) about the placed skill's contact centre. Frames: world, metres (docs/CONVENTIONS.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.demonstration import Demonstration
from schemas.execution import EnvironmentChange, Placement, SensorChoice, WorkPieceSource
from schemas.skill import Skill
from sim_worker.placement import PlacementChoice, PlacementError, choose_placement
from sim_worker.sensor import WRIST_SENSOR
from sim_worker.teacher import scenario_world_config
from sim_worker.work_piece import rebuilt_world_config
from sim_worker.world_config import WorldConfig
from skills.perturbation import contact_centre, force_scaled_skill
from skills.placement import placed_skill, tool_aligned_skill
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix, quaternions_normalized


@dataclass(frozen=True)
class ExecutionWorld:
    """A skill ready to run: the world, the skill (placed) and its demonstration (placed, for the path metric)."""

    config: WorldConfig
    skill: Skill
    demonstration: Demonstration | None
    source: str
    """'given', 'scenario', 'taught' or 'rebuilt'."""
    placement: Placement | None
    """The placement applied (rebuilt work pieces only)."""
    placement_reason: str = ""


def world_config_from_file_dict(data: dict[str, Any]) -> WorldConfig:
    """A ``WorldConfig`` from its dict or from a ground-truth dict holding one under ``world_config``.

    Raises ValueError naming unknown fields."""
    if isinstance(data.get("world_config"), dict):
        data = data["world_config"]
    try:
        return WorldConfig.from_dict(data)
    except TypeError as exc:
        raise ValueError(f"world: {exc}") from None


def _placed_demonstration(demonstration: Demonstration | None, choice: PlacementChoice) -> Demonstration | None:
    if demonstration is None or choice.is_identity:
        return demonstration
    a = demonstration.arrays()
    positions = a.positions @ choice.rotation.T + choice.translation
    rotations = choice.rotation @ matrix_from_quaternion(a.orientations) @ choice.tool_alignment
    orientations = quaternion_from_matrix(rotations)
    return demonstration.model_copy(update={"positions": positions.tolist(), "orientations": orientations.tolist()})


def execution_world(
    skill: Skill,
    environment: EnvironmentChange | None = None,
    *,
    scenario: str | None = None,
    world: dict[str, Any] | None = None,
    overrides: dict[str, Any] | None = None,
    demonstration: Demonstration | None = None,
    approach_clearance_m: float = 0.06,
) -> ExecutionWorld:
    """Resolve where ``skill`` runs (see the module). Raises ValueError (PlacementError included) with a message
    naming what to change."""
    env = environment or EnvironmentChange()
    changes = {**(WRIST_SENSOR if env.sensor is SensorChoice.wrist else {}), **(overrides or {})}
    changes.update(_environment_fields(env))
    skill = force_scaled_skill(skill, env.force_scale)
    source = None
    if world is not None:
        config, source = world_config_from_file_dict(world), "given"
    elif scenario is not None:
        config, source = scenario_world_config(scenario), "scenario"
    elif skill.taught_world is not None and env.work_piece is not WorkPieceSource.rebuilt:
        config, source = world_config_from_file_dict(skill.taught_world), "taught"
    elif env.work_piece is WorkPieceSource.taught:
        raise ValueError(
            "environment.work_piece: the skill carries no taught world (it was not recorded in the simulator); "
            "use 'auto' or 'rebuilt'"
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
    try:
        config = rebuilt_world_config(placed)
    except ValueError as exc:
        raise PlacementError(str(exc)) from None
    placement = Placement(
        translation_m=choice.translation.tolist(),
        rotation=choice.quaternion,
        tool_alignment=choice.tool_alignment_quaternion,
    )
    return ExecutionWorld(
        _with(config, _tilt_about(placed, env, changes)),
        placed,
        _placed_demonstration(demonstration, choice),
        "rebuilt",
        placement,
        choice.reason,
    )


def _environment_fields(env: EnvironmentChange) -> dict[str, Any]:
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
        fields["wrench_bias_n"] = tuple(env.sensor_bias_n)
    return fields


def _tilt_about(skill: Skill, env: EnvironmentChange, changes: dict[str, Any]) -> dict[str, Any]:
    """``changes`` plus the unknown tilt of the work piece about the (placed) skill's contact centre."""
    if not any(env.unknown_tilt_deg):
        return changes
    pivot = tuple(contact_centre(skill).tolist())
    return {**changes, "work_piece_tilt_deg": tuple(env.unknown_tilt_deg), "work_piece_tilt_pivot_m": pivot}


def _with(config: WorldConfig, changes: dict[str, Any]) -> WorldConfig:
    try:
        return config.replace(**changes)
    except TypeError as exc:
        raise ValueError(f"world_overrides: {exc}") from None
