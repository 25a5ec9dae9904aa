"""What the dashboard's views answer (``GET /dashboard/api/...``, ``services/dashboard/views.py``): a skill as its page
draws it. Units: s, m, N; positions and CF axes in the world frame, forces along CF z."""

from __future__ import annotations

from pydantic import BaseModel, Field

from schemas.numbers import Real
from schemas.skill import AutoSelection, SkillCheck


class SegmentSpan(BaseModel):
    """One segment on the skill's time line (demonstration time, s)."""

    index: int
    kind: str = Field(description="contact or free.")
    t_start: Real
    t_end: Real
    force_n: Real | None = Field(None, description="The learned constant CF-z force of a slide segment, N.")


class Triad(BaseModel):
    """A compliant frame: its origin (world, m) and its world-from-CF rotation's columns (x, y, z axes, unit)."""

    origin: list[float]
    axes: list[list[float]]


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
    triads: list[Triad]
    auto_selection: AutoSelection | None
    checks: list[SkillCheck]
