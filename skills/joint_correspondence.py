"""Which demonstrations of one task fit together (docs/LEARNING.md, section 11, step 1).

A demonstration fits the others when its contact lies at the same place (the median distance of its contact points
to the others', both ways, at most `SAME_PLACE_M`), presses along the same direction (its mean CF z within
`SAME_SURFACE_DEG`), is not confidently the other type, and has as many contact segments as most of them. The
reference is the one that agrees best with the others (the medoid); contact segments are matched by order. A
demonstration that does not fit is named with its reason (`schemas.skill.MisfitReason`). World frame, SI units."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from schemas.demonstration import Demonstration
from schemas.skill import LearnOptions, MisfitReason, SkillType, SkillTypeRequest
from skills.friction import unit_rows
from skills.joint_alignment import angles_deg, contact_segments
from skills.parameterize import LearnedTrial, LearningError, learn_trial
from skills.selection import MIXED_CONFIDENCE
from skills.surface_geometry import POOL_NORMAL_DEG

SAME_PLACE_M = 0.05
"""A demonstration's contact points lie at most this far (median, m) from another's to be on the same part."""

SAME_SURFACE_DEG = POOL_NORMAL_DEG
"""Two demonstrations whose mean CF z differ by more than this (deg) press on different surfaces (as the pooled
surfaces of one demonstration, `skills.surface_geometry.POOL_NORMAL_DEG`)."""

PLACE_POINTS = 400
"""Contact points per demonstration compared for its place on the part (decimated evenly)."""


@dataclass(frozen=True)
class _Trial:
    """A demonstration given: its source's name, its learning (None: not learnable), and why it was left out."""

    index: int
    source: str
    learned: LearnedTrial | None
    misfit: MisfitReason | None = None
    reason: str | None = None

    def left_out(self, misfit: MisfitReason, reason: str) -> _Trial:
        """This trial, left out for ``misfit``, explained by ``reason``."""
        return replace(self, misfit=misfit, reason=reason)


@dataclass(frozen=True)
class _Footprint:
    """Where a demonstration pressed: contact points (P, 3) m and its CF z at each (P, 3)."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64]


def _footprint(learned: LearnedTrial) -> _Footprint:
    items = contact_segments(learned)
    points = np.concatenate([learned.recording.positions[i.segment.start_index : i.segment.end_index] for i in items])
    normals = np.concatenate([np.asarray(i.cf_z) for i in items])
    keep = np.unique(np.linspace(0, len(points) - 1, min(len(points), PLACE_POINTS)).round().astype(int))
    return _Footprint(points[keep], unit_rows(normals[keep]))


def _place_m(a: _Footprint, b: _Footprint) -> float:
    """The median distance (m) of each one's contact points to the other's, the larger of the two ways."""
    ab = np.median(cKDTree(b.points).query(a.points)[0])
    ba = np.median(cKDTree(a.points).query(b.points)[0])
    return float(max(ab, ba))


def _surface_deg(a: _Footprint, b: _Footprint) -> float:
    """The median angle (deg) between each one's CF z and the other's at the nearest contact point: the same place
    on the same surface gives the same normal, on a plane as on a curve."""
    nearest_b = cKDTree(b.points).query(a.points)[1]
    nearest_a = cKDTree(a.points).query(b.points)[1]
    ab = np.median(angles_deg(a.normals, b.normals[nearest_b]))
    ba = np.median(angles_deg(b.normals, a.normals[nearest_a]))
    return float(max(ab, ba))


def _disagreement(a: _Footprint, b: _Footprint) -> float:
    """Place and direction, each over its limit: below 1 both agree."""
    return max(_place_m(a, b) / SAME_PLACE_M, _surface_deg(a, b) / SAME_SURFACE_DEG)


def _medoid(indices: list[int], disagreement: dict[tuple[int, int], float]) -> int:
    """The demonstration of ``indices`` whose summed disagreement (by pair, `_disagreement`) with the others is least
    (the first on a tie)."""
    sums = [sum(disagreement[min(i, j), max(i, j)] for j in indices if j != i) for i in indices]
    return indices[int(np.argmin(sums))]


def _log_odds(learned: LearnedTrial) -> NDArray[np.float64] | None:
    return None if learned.classification is None else learned.classification.log_odds


def _forced(options: LearnOptions, skill_type: SkillType) -> LearnOptions:
    return options.model_copy(update={"skill_type": SkillTypeRequest(skill_type.value), "strict": False})


def _fitting(trials: list[_Trial]) -> list[int]:
    """The indices of the trials not left out."""
    return [t.index for t in trials if t.misfit is None]


def _evidence(trials: list[_Trial], kept: list[int]) -> list[NDArray[np.float64]]:
    """The log-odds for contour (3,) of the ``kept`` trials whose type could be measured."""
    return [odds for i in kept if (odds := _log_odds(trials[i].learned)) is not None]  # type: ignore[arg-type]


def corresponding_trials(
    demonstrations: Sequence[Demonstration], sources: Sequence[str], options: LearnOptions
) -> tuple[list[_Trial], SkillType, NDArray[np.float64] | None, int]:
    """Learn each demonstration and decide which fit together: the trials (the left-out ones with their reason),
    the joint type, the summed log-odds for contour (3,) of the ones kept (None: not measured) and the reference
    (the index of the kept one that agrees best with the others)."""
    single = options.model_copy(update={"strict": False})
    trials = []
    for k, (demonstration, source) in enumerate(zip(demonstrations, sources, strict=True)):
        try:
            trials.append(_Trial(k, source, learn_trial(demonstration, single)))
        except LearningError as exc:
            trials.append(_Trial(k, source, None, MisfitReason.not_learnable, f"{exc.field}: {exc.reason}"))
    kept = [t.index for t in trials if t.learned is not None]
    if not kept:
        raise LearningError("demonstrations", "; ".join(f"{t.source}: {t.reason}" for t in trials))
    footprints = {i: _footprint(trials[i].learned) for i in kept}  # type: ignore[arg-type]
    disagreement = {(i, j): _disagreement(footprints[i], footprints[j]) for i in kept for j in kept if i < j}
    medoid = _medoid(kept, disagreement)
    for i in kept:
        place, angle = _place_m(footprints[i], footprints[medoid]), _surface_deg(footprints[i], footprints[medoid])
        if place > SAME_PLACE_M:
            trials[i] = trials[i].left_out(
                MisfitReason.another_place,
                f"its contact lies {1000 * place:.0f} mm from {trials[medoid].source}'s (median; at most "
                f"{1000 * SAME_PLACE_M:.0f} mm on the same part): another part, or the part moved",
            )
        elif angle > SAME_SURFACE_DEG:
            trials[i] = trials[i].left_out(
                MisfitReason.another_surface,
                f"it presses {angle:.0f} deg from {trials[medoid].source}'s direction at the same place "
                f"(median; at most {SAME_SURFACE_DEG:.0f} deg): another surface",
            )
    kept = _fitting(trials)

    evidence = _evidence(trials, kept)
    summed = np.sum(evidence, axis=0) if evidence else None
    if options.skill_type is SkillTypeRequest.auto:
        assert summed is not None  # auto learning raises where the type cannot be measured
        skill_type = SkillType.contour if summed.sum() > 0 else SkillType.slide
        for i in kept:
            own = trials[i].learned.skill.auto_selection  # type: ignore[union-attr]
            if own is not None and own.chosen is not skill_type and own.confidence >= MIXED_CONFIDENCE:
                trials[i] = trials[i].left_out(
                    MisfitReason.another_type,
                    f"it is a {own.chosen.value} on its own at {100 * own.confidence:.0f} % where the others "
                    f"together are a {skill_type.value}",
                )
        kept = _fitting(trials)
        summed = np.sum(_evidence(trials, kept), axis=0)
    else:
        skill_type = SkillType(options.skill_type.value)
    for i in kept:
        if trials[i].learned.skill.skill_type is not skill_type:  # type: ignore[union-attr]
            try:
                trials[i] = replace(trials[i], learned=learn_trial(demonstrations[i], _forced(options, skill_type)))
            except LearningError as exc:
                reason = f"as a {skill_type.value}: {exc.field}: {exc.reason}"
                trials[i] = trials[i].left_out(MisfitReason.not_learnable, reason)
    kept = _fitting(trials)

    counts = {i: len(contact_segments(trials[i].learned)) for i in kept}  # type: ignore[arg-type]
    tally = Counter(counts.values()).most_common()
    usual = [n for n, c in tally if c == tally[0][1]]
    reference = _medoid(kept, disagreement)
    wanted = counts[reference] if counts[reference] in usual else usual[0]
    for i in kept:
        if counts[i] != wanted:
            trials[i] = trials[i].left_out(
                MisfitReason.another_stroke_count,
                f"it has {counts[i]} contact segment(s) as a {skill_type.value} where the others have {wanted}",
            )
    kept = _fitting(trials)
    return trials, skill_type, summed, _medoid(kept, disagreement)
