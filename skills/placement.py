"""A skill moved by a rigid transform, and the tool path a skill describes.

A recording lives in its own frame (another robot's base, a tracker's world). A placement ``(R, t)`` maps it into
the simulated robot's world, ``x_world = R x_skill + t`` (docs/CONVENTIONS.md: quaternions ``[x, y, z, w]``,
world-from-frame rotations). Everything a skill holds in the world frame moves with it:

- compliant frames: origins ``R o + t``, orientations ``R R_cf``;
- position DMPs in the world frame: start and goal ``R y + t``, forcing weights ``R w`` (each basis' weight
  vector is a world-frame vector; the transformation system is linear and the same in every dimension, so the
  rollout from the moved start to the moved goal is the moved rollout). Slide positions are CF coordinates and
  do not change: their frame moves;
- orientation DMPs (Ude 2014, world-frame angular terms): start and goal ``q_R * q``, weights ``R w``
  (``2 log(q_R g q^-1 q_R^-1) = R 2 log(g q^-1)``);
- forces along CF z do not change.

The per-dimension amplitude-scaling flags of a world-frame position DMP follow the axis each new axis mostly
comes from; they only matter when a rollout gets a start or goal other than the demonstrated one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.skill import DMPParameters, Segment, SegmentKind, Skill
from skills.compliant_frames import compliant_frame_rotations
from skills.dmp import DMP
from skills.quaternion_dmp import QuaternionDMP
from skills.quaternions import (
    matrix_from_quaternion,
    quaternion_from_matrix,
    quaternion_product,
    quaternions_sign_continuous,
)


def _moved_position_dmp(p: DMPParameters, R: NDArray[np.float64], t: NDArray[np.float64]) -> DMPParameters:
    if p.frame == "cf":
        return p
    W = np.asarray(p.weights, dtype=float) @ R.T
    source_axis = np.argmax(np.abs(R), axis=1)
    return p.model_copy(
        update={
            "start": (R @ np.asarray(p.start) + t).tolist(),
            "goal": (R @ np.asarray(p.goal) + t).tolist(),
            "weights": W.tolist(),
            "amplitude_scaling": [bool(p.amplitude_scaling[j]) for j in source_axis],
        }
    )


def _moved_orientation_dmp(p: DMPParameters, R: NDArray[np.float64], q_R: NDArray[np.float64]) -> DMPParameters:
    W = np.asarray(p.weights, dtype=float) @ R.T
    return p.model_copy(
        update={
            "start": quaternion_product(q_R, np.asarray(p.start)).tolist(),
            "goal": quaternion_product(q_R, np.asarray(p.goal)).tolist(),
            "weights": W.tolist(),
        }
    )


def _moved_segment(segment: Segment, R: NDArray[np.float64], t: NDArray[np.float64], q_R) -> Segment:
    update: dict = {
        "position_dmp": _moved_position_dmp(segment.position_dmp, R, t),
        "orientation_dmp": _moved_orientation_dmp(segment.orientation_dmp, R, q_R),
    }
    frames = segment.compliant_frames
    if frames is not None:
        origins = np.asarray(frames.origins, dtype=float) @ R.T + t
        rotations = R @ matrix_from_quaternion(np.asarray(frames.orientations, dtype=float))
        update["compliant_frames"] = frames.model_copy(
            update={
                "origins": origins.tolist(),
                "orientations": quaternions_sign_continuous(quaternion_from_matrix(rotations)).tolist(),
            }
        )
    band = segment.force_band
    if band is not None:  # its mean path moves with the skill (runs are aligned to it)
        update["force_band"] = band.model_copy(
            update={"positions": (np.asarray(band.positions, dtype=float) @ R.T + t).tolist()}
        )
    return segment.model_copy(update=update)


def placed_skill(skill: Skill, rotation: ArrayLike, translation: ArrayLike) -> Skill:
    """``skill`` moved by the placement ``x_world = R x_skill + t`` (``rotation`` (3, 3), ``translation`` (3,) m)."""
    R = np.asarray(rotation, dtype=float)
    t = np.asarray(translation, dtype=float)
    if np.allclose(R, np.eye(3), atol=1e-15) and not np.any(t):
        return skill
    q_R = quaternion_from_matrix(R)
    return skill.model_copy(update={"segments": [_moved_segment(s, R, t, q_R) for s in skill.segments]})


def tool_aligned_skill(skill: Skill, alignment: ArrayLike) -> Skill:
    """``skill`` with every tool orientation turned by the constant tool-frame rotation ``alignment`` (3, 3):
    ``R_tool' = R_tool @ alignment`` (a different tool frame on the same tool point, like a TCP calibration).

    Positions, compliant frames and forces stay; the orientation DMPs' starts and goals are right-multiplied and
    their weights stay (``g q_A (q q_A)^-1 = g q^-1``: the Ude error term does not change).
    """
    A = np.asarray(alignment, dtype=float)
    if np.allclose(A, np.eye(3), atol=1e-15):
        return skill
    q_A = quaternion_from_matrix(A)

    def turned(p: DMPParameters) -> DMPParameters:
        return p.model_copy(
            update={
                "start": quaternion_product(np.asarray(p.start), q_A).tolist(),
                "goal": quaternion_product(np.asarray(p.goal), q_A).tolist(),
            }
        )

    segments = [s.model_copy(update={"orientation_dmp": turned(s.orientation_dmp)}) for s in skill.segments]
    return skill.model_copy(update={"segments": segments})


def pressing_direction_in_tool(skill: Skill, every_s: float = 0.05) -> NDArray[np.float64] | None:
    """The mean CF z (the pressing direction) expressed in the tool frame over the contact samples (unit), or None."""
    path = skill_tool_path(skill, every_s)
    rows = path.contact & np.all(np.isfinite(path.cf_z), axis=1)
    if not rows.any():
        return None
    R = matrix_from_quaternion(path.quaternions[rows])
    c = np.einsum("nji,nj->i", R, path.cf_z[rows])
    return c / np.linalg.norm(c)


@dataclass(frozen=True)
class ToolPath:
    """The tool poses a skill describes, rolled out from its demonstrated starts (world frame).

    ``segment`` (N,) segment index per sample; ``positions`` (N, 3) m; ``quaternions`` (N, 4) ``[x, y, z, w]``
    world from tool; ``contact`` (N,) bool; ``cf_z`` (N, 3) the CF z axis (into the surface) where in contact,
    NaN elsewhere.
    """

    segment: NDArray[np.int_]
    positions: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    contact: NDArray[np.bool_]
    cf_z: NDArray[np.float64]


def _segment_cf_z(segment: Segment, fractions: NDArray[np.float64]) -> NDArray[np.float64]:
    """The CF z (M, 3) at time ``fractions`` of a segment; NaN for a free segment."""
    if segment.compliant_frames is None:
        return np.full((fractions.size, 3), np.nan)
    return compliant_frame_rotations(segment, fractions * (segment.t_end - segment.t_start))[:, :, 2]


def segment_positions(segment: Segment, dt: float) -> NDArray[np.float64]:
    """The segment's demonstrated tool positions (M, 3) in the world, rolled out at step ``dt`` (s)."""
    y = DMP.from_parameters(segment.position_dmp).rollout(dt).y
    if segment.position_dmp.frame != "cf":
        return y
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"segment {segment.index}: CF positions without a compliant frame")
    R = matrix_from_quaternion(np.asarray(frames.orientations[0], dtype=float))
    return np.asarray(frames.origins[0], dtype=float) + y[:, :2] @ R[:, :2].T


ROLLOUT_STEP_S = 0.002
"""Integration step of the rollouts a tool path is sampled from, s (a DMP's Euler step must stay small)."""


def skill_tool_path(skill: Skill, every_s: float = 0.02) -> ToolPath:
    """The tool path of ``skill`` sampled every ``every_s`` (s): each segment rolled out from its own demonstrated
    start at ``ROLLOUT_STEP_S`` and subsampled (plus its last sample)."""
    stride = max(1, round(every_s / ROLLOUT_STEP_S))
    parts: list[tuple] = []
    for segment in skill.segments:
        p = segment_positions(segment, ROLLOUT_STEP_S)
        q = QuaternionDMP.from_parameters(segment.orientation_dmp).rollout(ROLLOUT_STEP_S).q
        n = min(len(p), len(q))
        rows = np.unique(np.r_[np.arange(0, n, stride), n - 1])
        fractions = rows / max(n - 1, 1)
        contact = segment.kind is SegmentKind.contact
        parts.append(
            (np.full(rows.size, segment.index), p[rows], q[rows], np.full(rows.size, contact),
             _segment_cf_z(segment, fractions))
        )  # fmt: skip
    return ToolPath(*(np.concatenate(list(column)) for column in zip(*parts, strict=True)))
