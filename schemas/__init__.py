"""The wire contract: pydantic models for REST bodies and Zenoh payloads (DESIGN.md "Interfaces")."""

from schemas.demonstration import (
    Demonstration,
    DemonstrationArrays,
    DemonstrationMetadata,
    DemonstrationSummary,
    QuaternionOrder,
    WrenchConvention,
    WrenchFrame,
)
from schemas.skill import (
    AutoSelection,
    CompliantFrames,
    DMPParameters,
    LearnOptions,
    Segment,
    SegmentKind,
    SegmentQuality,
    Skill,
    SkillAttributes,
    SkillType,
    SkillTypeRequest,
)

__all__ = [
    "AutoSelection",
    "CompliantFrames",
    "DMPParameters",
    "Demonstration",
    "DemonstrationArrays",
    "DemonstrationMetadata",
    "DemonstrationSummary",
    "LearnOptions",
    "QuaternionOrder",
    "Segment",
    "SegmentKind",
    "SegmentQuality",
    "Skill",
    "SkillAttributes",
    "SkillType",
    "SkillTypeRequest",
    "WrenchConvention",
    "WrenchFrame",
]
