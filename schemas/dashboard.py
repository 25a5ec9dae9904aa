"""What the dashboard's views answer (``GET /dashboard/api/...``, ``services/dashboard/views.py``): a skill as its page
draws it. Units: s, m, N; positions and CF axes in the world frame, forces along CF z."""

from __future__ import annotations

from pydantic import BaseModel, Field

from schemas.numbers import Real
from schemas.skill import AutoSelection, CheckBound, DemonstrationUse, SkillCheck

MAX_MESH_VERTICES = 4096
"""Vertices of one work piece solid at most (a curved block has a few hundred; a rebuilt part a few dozen)."""
MAX_WORK_PIECE_SOLIDS = 512
"""Solids of one world at most (a rebuilt work piece has one per stretch of its path: tens)."""


class WorkPieceMesh(BaseModel):
    """One solid of the world an execution ran in (table, ramp, contour object, a work piece part) as a triangle mesh:
    vertices in the world frame, m; triangles as vertex indices."""

    name: str
    vertices: list[tuple[float, float, float]] = Field(max_length=MAX_MESH_VERTICES)
    triangles: list[tuple[int, int, int]] = Field(max_length=2 * MAX_MESH_VERTICES)


class SegmentSpan(BaseModel):
    """One segment on the skill's time line (demonstration time, s)."""

    index: int
    kind: str = Field(description="contact or free.")
    t_start: Real
    t_end: Real
    force_n: Real | None = Field(None, description="The learned constant CF-z force of a slide segment, N.")


class BandSpan(BaseModel):
    """A contact segment's force band (``Segment.force_band``) on the skill's time line: the press the demonstrations
    learned together showed along CF z, N, at each of the band's phases placed on the reference demonstration's time
    (s), every point of the band."""

    segment: int = Field(description="The segment's index.")
    t: list[float] = Field(description="Times of the band's phases on the reference demonstration's time line, s.")
    mean_n: list[float] = Field(description="Mean press along CF z, N.")
    lower_n: list[float] = Field(description="Band's lower edge, N.")
    upper_n: list[float] = Field(description="Band's upper edge, N.")
    demonstrations: int = Field(description="How many demonstrations the band was built from.")


class Triad(BaseModel):
    """A compliant frame: its origin (world, m) and its world-from-CF rotation's columns (x, y, z axes, unit)."""

    origin: list[float]
    axes: list[list[float]]


class ExecutionScene(BaseModel):
    """``GET /dashboard/api/executions/{id}/scene``: what the execution's 3-D view draws besides its telemetry."""

    work_piece: list[WorkPieceMesh] | None = Field(
        description="The solids of the world the execution runs in (world, m); None until its worker started it."
    )


class SkillView(BaseModel):
    """``GET /dashboard/api/skills/{id}``: a skill as its page draws it."""

    id: str
    skill_type: str
    demonstration_id: str | None
    segments: list[SegmentSpan]
    t: list[float] = Field(description="Demonstration times of the plotted samples, s (empty without demonstration).")
    path: list[list[float]] = Field(description="Tool point at those times, world, m.")
    force_cf_z: list[float | None] = Field(description="Demonstrated applied force along CF z, N (None in free "
                                           "segments).")  # fmt: skip
    learned_t: list[float] = Field(description="Times of the learned CF-z force, s.")
    learned_force: list[float | None] = Field(description="Learned CF-z force, N (None between contact segments).")
    force_bands: list[BandSpan] = Field(
        default_factory=list, description="The force bands of its contact segments (empty: learned from one)."
    )
    demonstrations: list[DemonstrationUse] | None = Field(
        None, description="The demonstrations it was learned from together (``Skill.demonstrations``; None: one)."
    )
    triads: list[Triad]
    joints: list[float] | None = Field(
        None, description="The arm's 7 joint angles at the path's first sample, rad (None: out of the arm's reach)."
    )
    work_piece: list[WorkPieceMesh] | None = Field(
        None, description="The solids of the world the skill's latest execution ran in (world, m), if one ran."
    )
    work_piece_execution: str | None = Field(None, description="That execution's id.")
    auto_selection: AutoSelection | None
    checks: list[SkillCheck]
    check_bounds: list[CheckBound] = Field(
        default_factory=list, description="Per check, the side of its limit its value must stay on (>= or <=)."
    )
