"""A skill's plan as a real cell loads it (docs/REAL_CELL.md): the references an execution's phase planner
(``execution.plans.PhasePlanner``) computes for every control step, flattened into one timed table, with the
controller's gains. Column-wise (one list per field, one entry per sample) so that a plan of tens of thousands of
samples stays a few MB of JSON. SI units, world frame, quaternions ``[x, y, z, w]`` (docs/CONVENTIONS.md).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.demonstration import Quaternion, Vector3
from schemas.execution import ControllerGains, ControllerKind, ExecutionPhase
from schemas.execution.environment import Placement

SKILL_PLAN_FORMAT = "contact-skills/skill-plan"
"""The ``format`` every exported plan names."""
SKILL_PLAN_VERSION = 1
"""The plan format's version: raised when a field changes meaning or goes away (a new field keeps it)."""
MAX_PLAN_SAMPLES = 200_000
"""Most samples one exported plan holds (200 s at 1 kHz; ``every`` thins a longer one), about 60 MB of JSON."""


class PlanFormat(StrEnum):
    """How a plan is exported (``GET /skills/{id}/plan?format=``, ``contact-skills plan --format``)."""

    json = "json"
    """The :class:`SkillPlan` as JSON."""
    mcap = "mcap"
    """The same plan as MCAP: the samples as ROS 2 messages (timed poses, twist, CF, force, phase, segment,
    selection), the other fields as JSON in its metadata (``services.telemetry_export.plan_mcap``)."""


Selection6 = Annotated[list[int], Field(min_length=6, max_length=6)]
Twist6 = Annotated[list[float], Field(min_length=6, max_length=6)]


class PlanSamples(BaseModel):
    """One entry per sample in every list, in time order."""

    model_config = ConfigDict(extra="forbid")

    t: list[float] = Field(description="Time of the sample from the start of the plan, s (strictly increasing).")
    phase: list[ExecutionPhase] = Field(description="The execution phase the sample belongs to.")
    segment: list[int] = Field(description="The skill's segment index (-1: the settle at the start pose).")
    position_m: list[Vector3] = Field(description="Reference tool-point position, m, world frame.")
    orientation: list[Quaternion] = Field(description="Reference tool orientation, world from tool, [x, y, z, w].")
    twist: list[Twist6] = Field(description="Reference tool twist [v (m/s), ω (rad/s)], world axes.")
    cf_orientation: list[Quaternion] = Field(
        description="Compliant frame, world from CF, [x, y, z, w]: z along the force the tool applies (into the "
        "surface); the world frame in free space."
    )
    cf_origin_m: list[Vector3] = Field(
        description="Compliant frame origin, m, world: the reference tool point (the controller's compliance centre)."
    )
    selection: list[Selection6] = Field(
        description="Diagonal of the selection matrix S in the CF, [x, y, z, rx, ry, rz]: 1 = motion-controlled, "
        "0 = force-controlled."
    )
    force_n: list[float] = Field(description="Desired force the tool applies along CF z, N (0 in free space).")

    @model_validator(mode="after")
    def _same_length(self) -> PlanSamples:
        n = len(self.t)
        for name in PlanSamples.model_fields:
            if len(getattr(self, name)) != n:
                raise ValueError(f"samples.{name} has {len(getattr(self, name))} entries, samples.t has {n}")
        if any(b <= a for a, b in zip(self.t, self.t[1:], strict=False)):
            raise ValueError("samples.t must be strictly increasing")
        return self


class SkillPlan(BaseModel):
    """A skill's nominal execution plan: what the phase planner commands when every surface is where it was taught."""

    model_config = ConfigDict(extra="forbid")

    format: Literal["contact-skills/skill-plan"] = SKILL_PLAN_FORMAT
    version: Literal[1] = SKILL_PLAN_VERSION
    skill_id: str | None = Field(None, description="The stored skill's id (None for a skill file).")
    skill_type: str = Field(description="slide or contour.")
    controller: ControllerKind = Field(description="The control law the references are planned for.")
    gains: ControllerGains = Field(description="Stiffness, damping ratio, force gains and limits (CF axes).")
    placement: Placement | None = Field(
        None, description="How the skill was placed into the robot's world (None: as stored, in its own frame)."
    )
    control_period_s: float = Field(description="The planner's control step, s.")
    every: int = Field(description="Every how many control steps one sample was kept.")
    touchdown_speed_m_s: float = Field(description="Speed of the last part of each approach, m/s.")
    samples: PlanSamples
