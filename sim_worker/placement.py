"""Where a skill goes in the simulated robot's reach: a rigid placement checked by inverse kinematics.

A recording lives in its own frame (another robot's base, a tracker's world, metres). A placement ``(R, t)``
maps it into the robot's world, ``x_world = R x_skill + t`` (``skills.placement``). The skill's tool poses
(every ``REACH_CHECK_STEP_S`` of every segment, plus the pre-contact points the guarded approach starts from, in
the order the executor visits them) are solved one after the other by inverse kinematics: the first, the start pose,
from the home posture as the executor solves it (``execution.executor``), each later one from the previous
solution; a placement is reachable when every pose converges with every joint at least ``JOINT_MARGIN_RAD`` inside
its limits.

The choice: the skill as it is when that is reachable (a skill recorded on this robot), else the first
reachable candidate, with the tool frame first aligned when the recording's tool pressed more than
``TOOL_ALIGNMENT_MIN_DEG`` off its own z axis (``skills.placement.tool_aligned_skill``: the simulated ball tool
presses along its shaft), of: the rotation that keeps the recording's "up" (a yaw about world z) when its mean
pressing direction (CF z) is within ``KEEP_UP_WITHIN_DEG`` of straight down, otherwise the rotation that turns
the mean pressing direction straight down (the work piece faces up), each at yaws every 45°, with the contact
path's centre moved to one of ``TARGET_CENTRES_M`` in front of the robot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from schemas.skill import Skill
from schemas.world import WorldConfig
from sim_worker.robot_model import Q_HOME
from sim_worker.world import SimWorld
from skills.frames import matrix_from_axis_angle, rotation_from_vectors
from skills.placement import ToolPath, pressing_direction_in_tool, skill_tool_path, tool_aligned_skill
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix

REACH_CHECK_STEP_S = 0.1
"""Time between the tool poses checked for reachability, s."""
JOINT_MARGIN_RAD = 0.05
"""Smallest distance of every joint from its limits for a pose to count as reachable, rad."""
KEEP_UP_WITHIN_DEG = 60.0
"""A recording whose mean pressing direction is this close to straight down keeps its vertical."""
TARGET_CENTRES_M = ((0.55, 0.0, 0.15), (0.5, 0.0, 0.25), (0.6, 0.0, 0.08), (0.45, 0.0, 0.35))
"""Where the contact path's centre may go (world, m): in front of the iiwa at table height and above."""
SHOULDER_M = np.array([0.0, 0.0, 0.36])
"""The iiwa's shoulder (joint 2 axis), m."""
MAX_REACH_M = 0.95
"""Tool points farther than this from the shoulder are out of reach (arm 0.82 m + tool 0.125 m)."""


TOOL_ALIGNMENT_MIN_DEG = 15.0
"""A recording whose mean pressing direction is farther than this from its tool z axis gets its tool frame aligned."""
IK_SEEDS = (
    Q_HOME,
    (0.0, 0.5325, 0.0, -1.6083, 0.0, 1.0008, 1.5),
    (0.0, 0.5325, 0.0, -1.6083, 0.0, 1.0008, -1.5),
    (0.8, 0.7, 0.0, -1.4, 0.0, 1.0, 0.0),
    (-0.8, 0.7, 0.0, -1.4, 0.0, 1.0, 0.0),
)
"""Joint positions (rad) the first pose of a path is solved from, in turn, until one converges."""


class PlacementError(ValueError):
    """The skill cannot be put in the robot's reach (the message says what to change)."""


@dataclass(frozen=True)
class PlacementChoice:
    """A placement ``x_world = rotation @ x_skill + translation`` (m) and why it was chosen."""

    rotation: NDArray[np.float64]
    translation: NDArray[np.float64]
    reason: str
    joint_margin_rad: float
    tool_alignment: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    """Right-multiplied onto every tool orientation (``skills.placement.tool_aligned_skill``)."""

    @property
    def quaternion(self) -> list[float]:
        """The rotation as ``[x, y, z, w]``."""
        return quaternion_from_matrix(self.rotation).tolist()

    @property
    def tool_alignment_quaternion(self) -> list[float]:
        """The tool alignment as ``[x, y, z, w]``."""
        return quaternion_from_matrix(self.tool_alignment).tolist()

    @property
    def is_identity(self) -> bool:
        return bool(
            np.allclose(self.rotation, np.eye(3))
            and not np.any(self.translation)
            and np.allclose(self.tool_alignment, np.eye(3))
        )


def _checked_poses(skill: Skill, clearance_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64], ToolPath]:
    """Positions (N, 3) and rotations (N, 3, 3) to reach, in the skill's frame, in the order the executor visits
    them: the path, each touch-down preceded by the pre-contact point its guarded approach starts from (back along
    CF z, in the orientation there). The first is the executor's start pose."""
    path = skill_tool_path(skill, REACH_CHECK_STEP_S)
    rotations = matrix_from_quaternion(path.quaternions)
    touch_downs = np.flatnonzero(path.contact & ~np.r_[False, path.contact[:-1]])
    before = path.positions[touch_downs] - clearance_m * path.cf_z[touch_downs]
    positions = np.insert(path.positions, touch_downs, before, axis=0)
    return positions, np.insert(rotations, touch_downs, rotations[touch_downs], axis=0), path


def reach_report(
    world: SimWorld, positions: NDArray[np.float64], rotations: NDArray[np.float64], stop_at_first: bool = False
) -> tuple[int, float, str]:
    """Solve the poses (world frame) in order; return (unreachable count, smallest joint margin rad, first problem).

    The first pose is solved from the home posture only, with the solver's own iteration budget: the executor
    starts there that way (a start pose that only another seed reaches would fail the execution at once).
    ``stop_at_first``: return at the first unreachable pose (to reject a candidate placement quickly).
    """
    far = np.linalg.norm(positions - SHOULDER_M, axis=1) > MAX_REACH_M
    if far.any():
        k = int(np.argmax(far))
        return int(far.sum()), 0.0, f"pose {k} at {np.round(positions[k], 3).tolist()} m is beyond the arm's reach"
    q_seed: NDArray[np.float64] | None = None
    failures, margin, problem = 0, math.inf, ""
    for k in range(len(positions)):
        quat = quaternion_from_matrix(rotations[k])
        seeds = [q_seed] if q_seed is not None else [np.asarray(seed, dtype=float) for seed in IK_SEEDS]
        q, error = None, ""
        for seed in seeds[:1] if k == 0 else seeds:
            try:
                q = world.inverse_kinematics(positions[k], quat, seed, max_iterations=300 if k == 0 else 150)
                break
            except ValueError as exc:
                error = str(exc)
        if q is None:
            failures += 1
            problem = problem or f"pose {k} at {np.round(positions[k], 3).tolist()} m: {error}"
            q_seed = None
            if stop_at_first:
                break
            continue
        margins = np.minimum(q - world.joint_lower, world.joint_upper - q)
        joint = int(np.argmin(margins))
        m = float(margins[joint])
        margin = min(margin, m)
        if m < JOINT_MARGIN_RAD:
            failures += 1
            where = np.round(positions[k], 3).tolist()
            joint += 1
            problem = problem or f"pose {k} at {where} m: joint {joint} within {m:.3f} rad of its limit"
            if stop_at_first:
                break
        q_seed = q
    return failures, margin, problem


def _candidates(path: ToolPath, positions: NDArray[np.float64]):
    """Candidate placements (R, t, description), most natural first."""
    contact = path.contact & np.all(np.isfinite(path.cf_z), axis=1)
    pressing = path.cf_z[contact].mean(axis=0) if contact.any() else np.array([0.0, 0.0, -1.0])
    pressing /= max(float(np.linalg.norm(pressing)), 1e-12)
    tilt = math.degrees(math.acos(float(np.clip(-pressing[2], -1.0, 1.0))))
    if tilt <= KEEP_UP_WITHIN_DEG:
        base, how = np.eye(3), "its vertical kept"
    else:
        base, how = rotation_from_vectors(pressing, [0.0, 0.0, -1.0]), f"turned {tilt:.0f} deg to press downwards"
    centre = path.positions[contact].mean(axis=0) if contact.any() else path.positions.mean(axis=0)
    for target in TARGET_CENTRES_M:
        for yaw in (0, 90, 180, 270, 45, 135, 225, 315):
            R = matrix_from_axis_angle([0.0, 0.0, 1.0], math.radians(yaw)) @ base
            t = np.asarray(target) - R @ centre
            yield R, t, f"{how}, yawed {yaw} deg, contact centre at {list(target)} m"


def choose_placement(skill: Skill, approach_clearance_m: float, world: SimWorld | None = None) -> PlacementChoice:
    """The placement that puts ``skill`` in the iiwa's comfortable reach (see the module); raises PlacementError."""
    own = world is None
    world = world or SimWorld(WorldConfig(table_enabled=False))
    try:
        positions, rotations, path = _checked_poses(skill, approach_clearance_m)
        failures, margin, problem = reach_report(world, positions, rotations)
        if failures == 0:
            return PlacementChoice(np.eye(3), np.zeros(3), "in reach as recorded", margin)
        alignment, aligned = np.eye(3), ""
        pressing = pressing_direction_in_tool(skill)
        if pressing is not None:
            off_axis = math.degrees(math.acos(float(np.clip(pressing[2], -1.0, 1.0))))
            if off_axis > TOOL_ALIGNMENT_MIN_DEG:
                alignment = rotation_from_vectors([0.0, 0.0, 1.0], pressing)
                aligned = f"tool frame turned {off_axis:.0f} deg to press along the tool axis, "
                positions, rotations, path = _checked_poses(tool_aligned_skill(skill, alignment), approach_clearance_m)
        span = float(np.max(np.linalg.norm(positions - positions.mean(axis=0), axis=1)))
        if span > MAX_REACH_M:
            raise PlacementError(
                f"the skill cannot be placed in the robot's reach: its tool path reaches {span:.2f} m from its centre "
                f"(the iiwa reaches about {MAX_REACH_M:.2f} m from its shoulder); check the recording's units "
                "(metres) or split the demonstration"
            )
        tried = 0
        for R, t, description in _candidates(path, positions):
            placed = positions @ R.T + t
            tried += 1
            failures, margin, _ = reach_report(world, placed, R @ rotations, stop_at_first=True)
            if failures == 0:
                return PlacementChoice(R, t, f"placed: {aligned}{description}", margin, alignment)
        raise PlacementError(
            f"the skill cannot be placed in the robot's reach: no placement of {tried} tried reaches every tool pose "
            f"(as recorded: {problem}); give one with --placement (API: environment.placement)"
        )
    finally:
        if own:
            world.close()
