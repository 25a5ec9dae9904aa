"""What a demonstration measured of the surface its tool touched: per pass, where the surface is and which way it
faces, whatever type of skill was learned from it.

A pass is one stroke's stretch of contact: the samples of a run of consecutive contact segments (`skills.strokes`).
At each of its samples (world frame, SI; docs/CONVENTIONS.md):

- the **normal** ``n`` (unit, into the surface) is the direction of the applied force without its friction part,
  smoothed along the pass (`skills.compliant_frames.contour_normals`: the same measurement a contour's frames come
  from, made here for every pass, so a pass learned as a slide keeps the turning its force measured);
- the **contact point** is where a ball tool of radius ``r`` touches when its tool point (the tip of the ball along
  the tool z axis) is at the recorded position ``p`` with the recorded orientation: ball centre ``p - r z_tool``,
  contact ``centre + r n`` (the tool point itself when the tool is held along the normal);
- the **surface at rest** is the contact point moved back out along the normal by the press over the contact
  stiffness of the simulated world that rebuilds it: pressing the recorded force, the simulated tool then sinks to
  where the recorded one was, whatever the real pad's compliance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import Demonstration
from schemas.skill import Skill
from skills.compliant_frames import contour_normals, tool_velocities
from skills.parameterize import uniform_arrays
from skills.quaternions import matrix_from_quaternion
from skills.strokes import stroke_segments


@dataclass(frozen=True)
class MeasuredPass:
    """One pass's contact, sample by sample (M samples of the demonstration's uniform grid, world frame).

    ``rows`` the samples (the grid the skill's sample indices refer to); ``surface_points`` (M, 3) m the surface at
    rest under the contact point; ``normals`` (M, 3) unit, into the surface; ``press_n`` (M,) N the force along the
    normal.
    """

    rows: slice
    surface_points: NDArray[np.float64]
    normals: NDArray[np.float64]
    press_n: NDArray[np.float64]


def pass_rows(skill: Skill) -> list[slice]:
    """The demonstration samples of each pass of ``skill`` (its strokes' sample rows), in time order."""
    return [slice(stroke[0].start_index, stroke[-1].end_index) for stroke in stroke_segments(skill)]


def measured_passes(
    demonstration: Demonstration, skill: Skill, tool_radius_m: float, contact_stiffness_n_m: float
) -> list[MeasuredPass]:
    """The passes of ``skill`` as its ``demonstration`` measured them (see the module), for a ball tool of
    ``tool_radius_m`` (m) in a world of ``contact_stiffness_n_m`` (N/m).

    Raises ValueError when the demonstration is not the one the skill was learned from (another sample count).
    """
    if demonstration.n_samples != skill.demonstration.n_samples:
        raise ValueError(
            f"the demonstration has {demonstration.n_samples} samples, the skill was learned from one of "
            f"{skill.demonstration.n_samples}: give the demonstration the skill was learned from"
        )
    t, positions, quaternions, wrenches = uniform_arrays(demonstration)
    rows_of = pass_rows(skill)
    if rows_of and rows_of[-1].stop > t.size:
        raise ValueError("the skill's segments reach beyond its demonstration: give the one it was learned from")
    forces = wrenches[:, :3]
    rate_hz = (t.size - 1) / (t[-1] - t[0])
    velocities = tool_velocities(positions, rate_hz)
    passes = []
    for rows in rows_of:
        normals = contour_normals(forces, velocities, rate_hz, rows)
        tool_z = matrix_from_quaternion(quaternions[rows])[:, :, 2]
        press = np.sum(forces[rows] * normals, axis=1)
        contact = positions[rows] + tool_radius_m * (normals - tool_z)
        at_rest = contact - (np.maximum(press, 0.0) / contact_stiffness_n_m)[:, None] * normals
        passes.append(MeasuredPass(rows, at_rest, normals, press))
    return passes
