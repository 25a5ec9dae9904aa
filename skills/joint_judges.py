"""Each demonstration judged against the skill learned WITHOUT it (leave-one-out, docs/LEARNING.md, section 11,
step 4): its press within the others' force band, its own CF z against theirs (`skills.skill_checks
.demonstration_in_band`, `demonstration_normal`). World frame, SI units."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.skill import ForceBand, SkillType
from skills.force_band import band_alignment, band_and_mean_press, offset_uncertainty_n, weighted_share
from skills.joint_alignment import RUN_POINTS, Stroke, angles_deg, contact_segments, resampled
from skills.joint_normals import joint_normals
from skills.parameterize import LearnedSegment, LearnedTrial

LEAVE_ONE_OUT_MIN_OTHERS = 2
"""A demonstration's press is judged against the band of the OTHERS only when at least this many others remain: one
demonstration's band has no spread across demonstrations to predict another's with."""


@dataclass(frozen=True)
class Judge:
    """A contact segment's force band and CF z on the alignment points (G, 3), learned from some of the
    demonstrations: all of them for one left out by the learner, all but the one judged for the others."""

    band: ForceBand
    normals: NDArray[np.float64]

    @property
    def predicts(self) -> bool:
        """Whether the band says where a NEW demonstration presses: it needs a spread, so at least
        `LEAVE_ONE_OUT_MIN_OTHERS` demonstrations."""
        return self.band.demonstrations >= LEAVE_ONE_OUT_MIN_OTHERS


def left_out_judges(
    skill_type: SkillType,
    strokes: list[Stroke],
    aligned: list[NDArray[np.float64]],
    trials: list[LearnedTrial],
    items: list[LearnedSegment],
    reference_positions: NDArray[np.float64],
    mean_positions: NDArray[np.float64],
) -> list[Judge]:
    """For each demonstration, the segment's CF z and force band learned from the OTHERS (the same estimators as the
    joint segment's, on the same alignment): a demonstration is not compared with an estimate it is part of. Empty
    where it is the only one (no others to judge it by)."""
    if len(trials) < 2:
        return []
    judges = []
    for k in range(len(trials)):
        others = [i for i in range(len(trials)) if i != k]
        normals = joint_normals(
            skill_type,
            [strokes[i] for i in others],
            [trials[i] for i in others],
            [items[i] for i in others],
            reference_positions,
            mean_positions,
        )[0]
        offset = offset_uncertainty_n([trials[i] for i in others])
        judges.append(Judge(band_and_mean_press([aligned[i] for i in others], normals, offset)[0], normals))
    return judges


def agreement(learned: LearnedTrial, judges: list[Judge]) -> tuple[float | None, float]:
    """A demonstration against contact segments learned without it (``judges``, one per contact segment): its share
    of contact within their bands (None where a band cannot predict a new demonstration, `Judge.predicts`), and the
    median angle (deg) between its own CF z and theirs at the matched phases."""
    r, insides, samples, angles = learned.recording, [], [], []
    for item, judge in zip(contact_segments(learned), judges, strict=True):
        rows = slice(item.segment.start_index, item.segment.end_index)
        assert item.measured_force_n is not None and item.cf_z is not None
        inside, matched = band_alignment(judge.band, r.positions[rows], item.measured_force_n)
        insides.append(inside)
        samples.append(rows.stop - rows.start)
        own = resampled(np.asarray(item.cf_z), RUN_POINTS)
        known = matched >= 0
        angles.append(angles_deg(own[known], judge.normals[matched[known]]))
    share = weighted_share(insides, samples) if all(judge.predicts for judge in judges) else None
    return share, float(np.median(np.concatenate(angles)))
