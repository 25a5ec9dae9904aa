"""A skill's strokes: the runs of consecutive contact segments, and a skill cut into one skill per stroke.

A stroke is what the tool does between a touch-down and a lift-off: one contact segment, or several that follow
each other without a free segment between them (a crease, a press dip without lift-off, a path going round). The
free segments between strokes carry the tool from one to the next; a long demonstration's transfers can take the
tool far beyond any arm's reach while every stroke itself is small. A per-stroke skill keeps only the stroke's
contact segments: the executor settles at the pre-contact point of its first segment and approaches it guarded
(``execution.executor``), which is the free approach of that stroke.
"""

from __future__ import annotations

from schemas.skill import Segment, SegmentKind, Skill


def stroke_segments(skill: Skill) -> list[list[Segment]]:
    """The contact segments of ``skill`` grouped by stroke (runs of consecutive contact segments), in time order."""
    strokes: list[list[Segment]] = []
    previous_contact = False
    for segment in skill.segments:
        contact = segment.kind is SegmentKind.contact
        if contact and previous_contact:
            strokes[-1].append(segment)
        elif contact:
            strokes.append([segment])
        previous_contact = contact
    return strokes


def stroke_skills(skill: Skill) -> list[Skill]:
    """One skill per stroke of ``skill``: that stroke's contact segments, re-indexed from 0.

    The segments keep their sample rows (``start_index``, ``end_index``) and times, so a per-stroke skill still
    refers to the demonstration it was learned from; the checks of its segments (re-indexed) and the skill-wide
    ones come along. Raises ValueError when the skill has no contact segment.
    """
    strokes = stroke_segments(skill)
    if not strokes:
        raise ValueError("the skill has no contact segment: it has no stroke to run")
    skills = []
    for stroke in strokes:
        new_index = {segment.index: k for k, segment in enumerate(stroke)}
        checks = [
            check.model_copy(update={"segment": new_index.get(check.segment)})
            for check in skill.checks
            if check.segment is None or check.segment in new_index
        ]
        segments = [segment.model_copy(update={"index": k}) for k, segment in enumerate(stroke)]
        skills.append(skill.model_copy(update={"segments": segments, "checks": checks}))
    return skills
