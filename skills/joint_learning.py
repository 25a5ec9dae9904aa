"""One skill from several demonstrations of the same task: what repeats is the task, what varies is the hand.

Each demonstration is learned on its own first (`skills.parameterize.learn_trial`), then they are put in
correspondence and joined (docs/LEARNING.md, section 11):

1. **Correspondence.** A demonstration fits the others when its contact lies at the same place (the median distance
   of its contact points to the others', both ways, at most `SAME_PLACE_M`), presses along the same direction (its
   mean CF z within `SAME_SURFACE_DEG`), is not confidently the other type, and has as many contact segments as
   most of them. The reference is the one that agrees best with the others (the medoid); contact segments are
   matched by order. A demonstration that does not fit is named with its reason (`schemas.skill.MisfitReason`),
   and left out or refused (`schemas.skill.MisfitPolicy`).
2. **Time alignment.** Every contact segment is resampled to `ALIGNMENT_POINTS` points evenly in time and aligned
   to the reference's by dynamic time warping (`warping_path`, vectorized over anti-diagonals) on its path about
   its centroid and its press: place along the path first, the press's ramps second.
3. **Joint estimates.** The type from the summed log-odds of all of them (independent evidence: the confidence
   grows with agreement); a slide's plane from their contact points and friction-free forces pooled
   (`skills.compliant_frames.slide_frame`: strokes side by side span the plane a single line cannot); a contour's
   normals as the mean, at the same place, of each one's fused normals (a normal that turns at the same place in
   every trial is kept, one hand's wander is averaged down); the press as the mean with its spread per phase (the
   force band: across them and within each); the DMPs fitted to the aligned mean (position, orientation, force),
   on the reference's time base: its own samples moved by the mean's smoothed deviation from them.
4. **Self-checks.** The joint skill's checks against the reference recording (`skills.parameterize
   .recording_checks`), and each demonstration against the skill learned WITHOUT it (leave-one-out): its press
   within the others' band, its own CF z against theirs (`skills.skill_checks.demonstration_in_band`,
   `demonstration_normal`).

ONE demonstration learns exactly as `learn_skill` (the same skill, bit for bit). World frame, SI units.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist
from scipy.stats import t as student_t

from schemas.demonstration import Demonstration
from schemas.skill import (
    MAX_JOINT_DEMONSTRATIONS,
    MAX_JOINT_SAMPLES,
    SELECTION_CONTACT,
    AutoSelection,
    CheckName,
    CompliantFrames,
    DemonstrationUse,
    ForceBand,
    LearnOptions,
    MisfitPolicy,
    MisfitReason,
    Segment,
    SegmentKind,
    SegmentQuality,
    Skill,
    SkillType,
    SkillTypeRequest,
    TypeEvidence,
)
from skills import skill_checks
from skills.compliant_frames import PlaneFit, contour_frames, plane_along, slide_frame
from skills.force_profile import cf_z_forces, constant_force, plateau_mask, press_steadiness
from skills.friction import unit_rows
from skills.parameterize import (
    PROFILE_FLOOR,
    UNSTEADY_BASIS_PER_SECOND,
    LearnedSegment,
    LearnedTrial,
    LearningError,
    SkillCheckError,
    basis_count,
    force_profile_dmp,
    learn_skill,
    learn_trial,
    motion_dmps,
    recording_checks,
)
from skills.quaternions import (
    quaternion_conjugate,
    quaternion_exp,
    quaternion_from_matrix,
    quaternion_log,
    quaternion_product,
    quaternions_sign_continuous,
)
from skills.selection import MIXED_CONFIDENCE, SkillClassification
from skills.surface_geometry import FORCE_SIGMA_MIN_DEG, POOL_NORMAL_DEG

ALIGNMENT_POINTS = 100
"""Points, evenly in time, each demonstration's contact segment is aligned and averaged on (the band's phases)."""

RUN_POINTS = 200
"""Points a run judged against a band (a left-out demonstration, an execution) is resampled to before alignment."""

SAME_PLACE_M = 0.05
"""A demonstration's contact points lie at most this far (median, m) from another's to be on the same part."""

SAME_SURFACE_DEG = POOL_NORMAL_DEG
"""Two demonstrations whose mean CF z differ by more than this (deg) press on different surfaces (as the pooled
surfaces of one demonstration, `skills.surface_geometry.POOL_NORMAL_DEG`)."""

PRESS_ALIGNMENT_SCALE_M = 0.02
"""The press, over its median, weighs in the time alignment as a path of this length (m): a 2 cm path counts as
much as the press doubling."""

WOBBLE_SMOOTHING_S = 0.2
"""A demonstration's own wobble is its press's RMS about the press smoothed over this (s)."""

BAND_SIGMAS = 3.0
"""The force band is the mean press plus or minus this many standard deviations (across and within)."""

AGREEMENT_DEG = 2.0
"""A demonstration whose contour normals lie this far (deg, median) from the others' mean weighs half as much as
one that agrees with it exactly (`_normals_by_place`)."""

BAND_POOLING_POINTS = 5.0
"""The across-trial variance is pooled over the nearby phases by a Gaussian of this many alignment points (5 % of the
segment): its degrees of freedom are (n - 1) times the pooled points, sqrt(2 pi) times this."""

BAND_CONFIDENCE = 0.95
"""The force band is the prediction interval, at this confidence, of a new demonstration's press."""

DEVIATION_SMOOTHING_POINTS = 2.0
"""The demonstrations' mean deviation from the reference is smoothed over this many alignment points (2 % of the
segment) before it moves the reference's samples."""

LEAVE_ONE_OUT_MIN_OTHERS = 2
"""A demonstration's press is judged against the band of the OTHERS only when at least this many others remain: one
demonstration's band has no spread across demonstrations to predict another's with."""

PLACE_POINTS = 400
"""Contact points per demonstration compared for its place on the part (decimated evenly)."""


REFERENCE_FORCE_CHECKS = frozenset({CheckName.force_along_cf, CheckName.press_profile})
"""A single demonstration's checks of its learned force against its own press; a joint skill's force is checked
against every demonstration's press by `skill_checks.demonstration_in_band` instead."""


def _offset_uncertainty_n(learned: Sequence[LearnedTrial]) -> float | None:
    """The 95 % uncertainty (N) of the mean of the demonstrations' forces from their sensor offsets, each tared on
    its own (independent): the root of their squares' sum over their count; None where any has none."""
    each = [t.demonstration.metadata.force_offset_uncertainty_n for t in learned]
    if any(u is None for u in each):
        return None
    return float(np.sqrt(np.sum(np.square(each)))) / len(each)


class JointLearningError(LearningError):
    """A demonstration does not fit the others and ``misfit`` is `MisfitPolicy.refuse`."""


@dataclass(frozen=True)
class _Trial:
    """A demonstration given: its source's name, its learning (None: not learnable), and why it was left out."""

    index: int
    source: str
    learned: LearnedTrial | None
    misfit: MisfitReason | None = None
    reason: str | None = None


@dataclass(frozen=True)
class _Stroke:
    """One contact segment of one demonstration on `ALIGNMENT_POINTS` points evenly in time (world, SI): its path
    (G, 3) m, tool orientations (G, 4), applied forces (G, 3) N, CF z (G, 3), press along its own CF z (G,) N and
    its wobble (G,) N; ``rows`` its samples in the demonstration."""

    positions: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    forces: NDArray[np.float64]
    normals: NDArray[np.float64]
    press: NDArray[np.float64]
    wobble: NDArray[np.float64]
    rows: slice


def resampled(values: NDArray[np.float64], n_points: int) -> NDArray[np.float64]:
    """Return ``values`` (M, ...) linearly interpolated at ``n_points`` points evenly spread from the first to the
    last sample."""
    m = len(values)
    x = np.linspace(0.0, m - 1.0, n_points)
    lo = np.minimum(np.floor(x).astype(int), m - 1)
    hi = np.minimum(lo + 1, m - 1)
    frac = (x - lo).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - frac) * values[lo] + frac * values[hi]


def warping_path(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
    """Return the dynamic-time-warping path (i, j) between feature rows ``a`` (N, D) and ``b`` (M, D), Euclidean
    cost, steps (1, 0), (0, 1), (1, 1); from (0, 0) to (N - 1, M - 1). The cumulative cost is filled one
    anti-diagonal at a time (every cell of one depends only on the two before it)."""
    n, m = len(a), len(b)
    cost = cdist(a, b)
    total = np.full((n + 1, m + 1), np.inf)
    total[0, 0] = 0.0
    for s in range(2, n + m + 1):
        i = np.arange(max(1, s - m), min(n, s - 1) + 1)
        j = s - i
        best = np.minimum(np.minimum(total[i - 1, j - 1], total[i - 1, j]), total[i, j - 1])
        total[i, j] = cost[i - 1, j - 1] + best
    # Backtrack along the cheapest predecessor of each cell (0: diagonal, 1: from above, 2: from the left).
    came_from = np.argmin(np.stack([total[:-1, :-1], total[:-1, 1:], total[1:, :-1]]), axis=0)
    steps = ((-1, -1), (-1, 0), (0, -1))
    i, j, path = n, m, [(n - 1, m - 1)]
    while i > 1 or j > 1:
        if i == 1:
            j -= 1
        elif j == 1:
            i -= 1
        else:
            di, dj = steps[came_from[i - 1, j - 1]]
            i, j = i + di, j + dj
        path.append((i - 1, j - 1))
    pairs = np.array(path[::-1])
    return pairs[:, 0], pairs[:, 1]


def _features(positions: NDArray[np.float64], press: NDArray[np.float64]) -> NDArray[np.float64]:
    """Alignment features (G, 4): the path about its centroid (m) and the press over its median, scaled to a path."""
    scale = max(float(np.median(np.abs(press))), 1e-6)
    centred = positions - positions.mean(axis=0)
    return np.column_stack([centred, PRESS_ALIGNMENT_SCALE_M * press / scale])


def _on_reference(
    reference: NDArray[np.float64], features: NDArray[np.float64], values: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Return ``values`` (M, D) of a run with ``features`` (M, F) on the reference's points (G, F): at each, the mean
    of the run's values the warping path matches to it."""
    i, j = warping_path(reference, features)
    sums = np.zeros((len(reference), values.shape[1]))
    np.add.at(sums, i, values[j])
    return sums / np.bincount(i, minlength=len(reference))[:, None]


def _wobble(press: NDArray[np.float64], rate_hz: float) -> NDArray[np.float64]:
    """The press's local RMS (N) about itself smoothed over `WOBBLE_SMOOTHING_S`."""
    sigma = max(WOBBLE_SMOOTHING_S * rate_hz, 1.0)
    residual = press - gaussian_filter1d(press, sigma, mode="nearest")
    return np.sqrt(gaussian_filter1d(residual**2, sigma, mode="nearest"))


def _contacts(learned: LearnedTrial) -> list[LearnedSegment]:
    return [item for item in learned.learned if item.segment.kind is SegmentKind.contact]


def _stroke(learned: LearnedTrial, item: LearnedSegment) -> _Stroke:
    """One contact segment of a demonstration on the alignment points."""
    r, segment = learned.recording, item.segment
    rows = slice(segment.start_index, segment.end_index)
    assert item.cf_z is not None and item.measured_force_n is not None
    g = ALIGNMENT_POINTS
    return _Stroke(
        positions=resampled(r.positions[rows], g),
        quaternions=resampled(r.quaternions[rows], g),
        forces=resampled(r.forces[rows], g),
        normals=unit_rows(resampled(np.asarray(item.cf_z), g)),
        press=resampled(item.measured_force_n, g),
        wobble=resampled(_wobble(item.measured_force_n, r.contact.rate_hz), g),
        rows=rows,
    )


def _angles_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.degrees(np.arccos(np.clip(np.sum(unit_rows(a) * unit_rows(b), axis=-1), -1.0, 1.0)))


@dataclass(frozen=True)
class _Footprint:
    """Where a demonstration pressed: contact points (P, 3) m and its CF z at each (P, 3)."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64]


def _footprint(learned: LearnedTrial) -> _Footprint:
    items = _contacts(learned)
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
    ab = np.median(_angles_deg(a.normals, b.normals[nearest_b]))
    ba = np.median(_angles_deg(b.normals, a.normals[nearest_a]))
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


def _corresponding(
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
            trials[i] = replace(
                trials[i],
                misfit=MisfitReason.another_place,
                reason=f"its contact lies {1000 * place:.0f} mm from {trials[medoid].source}'s (median; at most "
                f"{1000 * SAME_PLACE_M:.0f} mm on the same part): another part, or the part moved",
            )
        elif angle > SAME_SURFACE_DEG:
            trials[i] = replace(
                trials[i],
                misfit=MisfitReason.another_surface,
                reason=f"it presses {angle:.0f} deg from {trials[medoid].source}'s direction at the same place "
                f"(median; at most {SAME_SURFACE_DEG:.0f} deg): another surface",
            )
    kept = [t.index for t in trials if t.misfit is None]

    evidence = [odds for i in kept if (odds := _log_odds(trials[i].learned)) is not None]  # type: ignore[arg-type]
    summed = np.sum(evidence, axis=0) if evidence else None
    if options.skill_type is SkillTypeRequest.auto:
        assert summed is not None  # auto learning raises where the type cannot be measured
        skill_type = SkillType.contour if summed.sum() > 0 else SkillType.slide
        for i in kept:
            own = trials[i].learned.skill.auto_selection  # type: ignore[union-attr]
            if own is not None and own.chosen is not skill_type and own.confidence >= MIXED_CONFIDENCE:
                trials[i] = replace(
                    trials[i],
                    misfit=MisfitReason.another_type,
                    reason=f"it is a {own.chosen.value} on its own at {100 * own.confidence:.0f} % where the others "
                    f"together are a {skill_type.value}",
                )
        kept = [t.index for t in trials if t.misfit is None]
        remaining = [odds for i in kept if (odds := _log_odds(trials[i].learned)) is not None]  # type: ignore[arg-type]
        summed = np.sum(remaining, axis=0)
    else:
        skill_type = SkillType(options.skill_type.value)
    for i in kept:
        if trials[i].learned.skill.skill_type is not skill_type:  # type: ignore[union-attr]
            try:
                trials[i] = replace(trials[i], learned=learn_trial(demonstrations[i], _forced(options, skill_type)))
            except LearningError as exc:
                reason = f"as a {skill_type.value}: {exc.field}: {exc.reason}"
                trials[i] = replace(trials[i], misfit=MisfitReason.not_learnable, reason=reason)
    kept = [t.index for t in trials if t.misfit is None]

    counts = {i: len(_contacts(trials[i].learned)) for i in kept}  # type: ignore[arg-type]
    tally = Counter(counts.values()).most_common()
    usual = [n for n, c in tally if c == tally[0][1]]
    reference = _medoid(kept, disagreement)
    wanted = counts[reference] if counts[reference] in usual else usual[0]
    for i in kept:
        if counts[i] != wanted:
            trials[i] = replace(
                trials[i],
                misfit=MisfitReason.another_stroke_count,
                reason=f"it has {counts[i]} contact segment(s) as a {skill_type.value} where the others have {wanted}",
            )
    kept = [t.index for t in trials if t.misfit is None]
    return trials, skill_type, summed, _medoid(kept, disagreement)


@dataclass(frozen=True)
class _Judge:
    """A contact segment's force band and CF z on the alignment points (G, 3), learned from some of the
    demonstrations: all of them for one left out by the learner, all but the one judged for the others."""

    band: ForceBand
    normals: NDArray[np.float64]

    @property
    def predicts(self) -> bool:
        """Whether the band says where a NEW demonstration presses: it needs a spread, so at least
        `LEAVE_ONE_OUT_MIN_OTHERS` demonstrations."""
        return self.band.demonstrations >= LEAVE_ONE_OUT_MIN_OTHERS


@dataclass(frozen=True)
class _JointSegment:
    """A joint contact segment and what the checks compare on the reference recording."""

    learned: LearnedSegment
    normals: NDArray[np.float64]
    """The joint CF z on the alignment points (G, 3)."""
    weights: NDArray[np.float64]
    """Each demonstration's weight (T,) in the joint normals (in the order learned from)."""
    judges: list[_Judge]
    """What each demonstration (in the order learned from) is judged against: the segment learned without it."""


def _pooled_plane(strokes: list[_Stroke], trials: list[LearnedTrial], positions: NDArray) -> PlaneFit:
    """The slide CF of matched segments from their contact points and forces pooled, its x and origin along the mean
    path ``positions`` (M, 3) m."""
    r = [t.recording for t in trials]
    pooled = {
        "positions": np.concatenate([ri.positions[s.rows] for ri, s in zip(r, strokes, strict=True)]),
        "forces": np.concatenate([ri.forces[s.rows] for ri, s in zip(r, strokes, strict=True)]),
        "directions": np.concatenate([ri.contact.directions[s.rows] for ri, s in zip(r, strokes, strict=True)]),
    }
    groups = [ri.surfaces.group(s.rows.start, s.rows.stop) for ri, s in zip(r, strokes, strict=True)]
    known = [g for g in groups if g is not None]
    sigma = float(np.median([g.force_sigma_deg for g in known])) if known else FORCE_SIGMA_MIN_DEG
    area = any(g.is_area for g in known)
    fit = slide_frame(**pooled, force_sigma_deg=sigma, area=area)
    return plane_along(fit, positions)


def _normals_by_place(
    positions: NDArray[np.float64], trials: list[LearnedTrial], items: list[LearnedSegment]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The joint contour normals (G, 3) at the reference's path ``positions`` (G, 3) m, and each demonstration's
    weight (T,) in them. Each demonstration's CF z at its contact sample nearest each point (a normal turns at the
    same PLACE in every trial, whenever each got there; farther than `SAME_PLACE_M` it does not count there), their
    mean, then again weighted by how far each one agrees with that mean (its median angle to it, against
    `AGREEMENT_DEG`): one hand's lean does not pull the others' surface."""
    own, near = [], []
    for trial, item in zip(trials, items, strict=True):
        points = trial.recording.positions[item.segment.start_index : item.segment.end_index]
        distance, nearest = cKDTree(points).query(positions)
        own.append(np.asarray(item.cf_z)[nearest])
        near.append(distance <= SAME_PLACE_M)
    normals, counts = np.array(own), np.array(near, dtype=float)
    mean = unit_rows(np.einsum("tg,tgd->gd", counts, normals))
    angles = [
        np.median(_angles_deg(n[c > 0], mean[c > 0])) if c.any() else 0.0 for n, c in zip(normals, counts, strict=True)
    ]
    weights = 1.0 / (1.0 + (np.asarray(angles) / AGREEMENT_DEG) ** 2)
    weights /= weights.sum()
    return unit_rows(np.einsum("t,tg,tgd->gd", weights, counts, normals)), weights


def _band(
    aligned: list[NDArray[np.float64]],
    normals: NDArray[np.float64],
    offset_uncertainty_n: float | None,
) -> tuple[ForceBand, NDArray[np.float64]]:
    """The force band of matched segments (their forces and wobbles aligned on the reference's points) and the mean
    press (G,) N along the joint ``normals`` (G, 3).

    Where a NEW demonstration's press is expected, at `BAND_CONFIDENCE`: the prediction interval of one more draw
    from the n shown, Student's t times ``s·sqrt(1 + 1/n)`` (``s`` their standard deviation, pooled over the nearby
    phases, `BAND_POOLING_POINTS`, with the degrees of freedom that pooling gives), combined with
    the wobble within each (`BAND_SIGMAS` times its RMS) and the sensor offsets' 95 % uncertainty (N; the press each
    recorded is known to no better), in quadrature."""
    presses = np.array([np.sum(a[:, 7:10] * normals, axis=1) for a in aligned])
    wobble = np.sqrt(np.mean([a[:, 13] ** 2 for a in aligned], axis=0))
    mean = presses.mean(axis=0)
    n = len(presses)
    # The spread across trials, pooled over the nearby phases (a few trials give one noisy number per phase; the
    # pooled variance has (n - 1) degrees of freedom per phase pooled).
    variance = presses.var(axis=0, ddof=1) if n > 1 else np.zeros_like(mean)
    across = np.sqrt(gaussian_filter1d(variance, BAND_POOLING_POINTS, mode="nearest"))
    spread = np.sqrt(across**2 + wobble**2)
    pooled_df = (n - 1) * np.sqrt(2.0 * np.pi) * BAND_POOLING_POINTS
    t_quantile = float(student_t.ppf(0.5 + 0.5 * BAND_CONFIDENCE, pooled_df)) if n > 1 else 0.0
    half = np.sqrt(
        (t_quantile * across * np.sqrt(1.0 + 1.0 / n)) ** 2
        + (BAND_SIGMAS * wobble) ** 2
        + (offset_uncertainty_n or 0.0) ** 2
    )
    positions = np.mean([a[:, 0:3] for a in aligned], axis=0)
    band = ForceBand(
        phase=np.linspace(0.0, 1.0, len(mean)).tolist(),
        positions=positions.tolist(),
        mean_n=mean.tolist(),
        spread_n=spread.tolist(),
        lower_n=np.maximum(mean - half, 0.0).tolist(),
        upper_n=(mean + half).tolist(),
        demonstrations=n,
    )
    return band, mean


def _joint_segment(
    trials: list[LearnedTrial], k: int, reference: int, skill_type: SkillType, options: LearnOptions
) -> _JointSegment:
    """The ``k``-th contact segment joined over ``trials`` (``reference`` gives the time base and the samples)."""
    items = [_contacts(t)[k] for t in trials]
    strokes = [_stroke(t, item) for t, item in zip(trials, items, strict=True)]
    ref_trial, ref_item, ref_stroke = trials[reference], items[reference], strokes[reference]
    ref_features = _features(ref_stroke.positions, ref_stroke.press)
    aligned = []
    for stroke in strokes:
        q = (
            stroke.quaternions
            * np.where(np.sum(stroke.quaternions * ref_stroke.quaternions, axis=1) < 0, -1.0, 1.0)[:, None]
        )
        values = np.column_stack([stroke.positions, q, stroke.forces, stroke.normals, stroke.wobble])
        aligned.append(_on_reference(ref_features, _features(stroke.positions, stroke.press), values))
    r = ref_trial.recording
    segment = ref_item.segment
    rows = slice(segment.start_index, segment.end_index)
    m, rate_hz = rows.stop - rows.start, r.contact.rate_hz
    t_seg = r.t[rows] - r.t[rows.start]

    def on_samples(values: NDArray[np.float64]) -> NDArray[np.float64]:
        x = np.linspace(0.0, m - 1.0, len(values))
        return np.column_stack([np.interp(np.arange(m), x, column) for column in np.atleast_2d(values.T)])

    def mean_on_samples(mean: NDArray[np.float64], own: NDArray[np.float64], samples: NDArray) -> NDArray[np.float64]:
        # The reference's own samples moved by the demonstrations' mean deviation from it, smoothed over phase: the
        # mean of warped runs steps where the warping does, and a path interpolated through such steps would jerk.
        return samples + on_samples(gaussian_filter1d(mean - own, DEVIATION_SMOOTHING_POINTS, axis=0, mode="nearest"))

    mean_positions = mean_on_samples(
        np.mean([a[:, 0:3] for a in aligned], axis=0), ref_stroke.positions, r.positions[rows]
    )
    turn = quaternion_log(
        quaternion_product(
            unit_rows(np.mean([a[:, 3:7] for a in aligned], axis=0)), quaternion_conjugate(ref_stroke.quaternions)
        )
    )
    own_turn = np.zeros_like(turn)
    mean_quaternions = quaternions_sign_continuous(
        quaternion_product(quaternion_exp(mean_on_samples(turn, own_turn, np.zeros((m, 3)))), r.quaternions[rows])
    )
    n_basis = basis_count(float(t_seg[-1]), options)
    stride = -(-m // options.max_fit_samples)
    fit = slice((m - 1) % stride, None, stride)
    normals, weights, plane = _joint_normals(skill_type, strokes, trials, items, ref_stroke.positions, mean_positions)
    if plane is not None:
        cf_z = np.broadcast_to(plane.rotation[:, 2], (m, 3))
    else:
        own_normals = np.asarray(ref_item.cf_z)
        on_path = unit_rows(mean_on_samples(normals, ref_stroke.normals, own_normals))
        rotations = contour_frames(mean_positions, np.zeros_like(mean_positions), rate_hz, slice(0, m), normals=on_path)
        cf_z = rotations[:, :, 2]
    band, mean_press = _band(aligned, normals, _offset_uncertainty_n(trials))
    measured = cf_z_forces(r.forces[rows], cf_z)
    own_press = resampled(measured, ALIGNMENT_POINTS)
    press = mean_on_samples(mean_press[:, None], own_press[:, None], measured[:, None])[:, 0]
    common = {
        "index": segment.index,
        "start_index": segment.start_index,
        "end_index": segment.end_index,
        "t_start": segment.t_start,
        "t_end": segment.t_end,
        "start_reason": segment.start_reason,
        "end_reason": segment.end_reason,
        "kind": SegmentKind.contact,
        "selection": list(SELECTION_CONTACT),
        "force_band": band,
    }
    if plane is not None:
        in_plane = ((mean_positions - plane.origin) @ plane.rotation)[:, :2]
        position_dmp, orientation_dmp, p_rms, q_rms = motion_dmps(
            t_seg[fit], in_plane[fit], mean_quaternions[fit], n_basis, "cf"
        )
        steadiness = press_steadiness(press, rate_hz)
        if steadiness.steady:
            constants = [
                constant_force(
                    cf_z_forces(t.recording.forces[s.rows], plane.rotation[:, 2]), t.recording.contact.rate_hz
                ).value_n
                for t, s in zip(trials, strokes, strict=True)
            ]
            constant, profile = float(np.mean(constants)), None
            learned_force = np.full(m, constant)
            force_rms = float(np.sqrt(np.mean((press[plateau_mask(press)] - constant) ** 2)))
        else:
            force_basis = min(options.max_basis, max(n_basis, round(UNSTEADY_BASIS_PER_SECOND * float(t_seg[-1]))))
            pressed = np.maximum(press, PROFILE_FLOOR * np.percentile(press, 90))
            profile = force_profile_dmp(t_seg, pressed, fit, stride, force_basis, rate_hz)
            constant, learned_force, force_rms = None, profile.learned_n, profile.rms_n
        joint = Segment(
            compliant_frames=CompliantFrames(
                t=[0.0], origins=[plane.origin.tolist()], orientations=[quaternion_from_matrix(plane.rotation).tolist()]
            ),
            position_dmp=position_dmp.to_parameters(),
            orientation_dmp=orientation_dmp.to_parameters(),
            force_constant_n=constant,
            force_dmp=None if profile is None else profile.dmp.to_parameters(),
            quality=SegmentQuality(
                position_rms_m=p_rms,
                orientation_rms_rad=q_rms,
                force_rms_n=force_rms,
                plane_residual_rms_m=plane.residual_rms_m,
                force_std_low_variance_n=float(np.median(np.asarray(band.spread_n)[plateau_mask(mean_press)])),
                force_measured_percentiles_n=np.percentile(press, [10, 50, 90]).tolist(),
                press_spread=steadiness.spread,
                press_trend=steadiness.trend,
            ),
            **common,
        )
    else:
        position_dmp, orientation_dmp, p_rms, q_rms = motion_dmps(
            t_seg[fit], mean_positions[fit], mean_quaternions[fit], n_basis, "world"
        )
        profile = force_profile_dmp(t_seg, press, fit, stride, n_basis, rate_hz)
        learned_force = profile.learned_n
        keep = np.unique(np.linspace(0, m - 1, min(m, options.contour_frames_max)).round().astype(int))
        joint = Segment(
            compliant_frames=CompliantFrames(
                t=t_seg[keep].tolist(),
                origins=mean_positions[keep].tolist(),
                orientations=quaternions_sign_continuous(quaternion_from_matrix(rotations[keep])).tolist(),
            ),
            position_dmp=position_dmp.to_parameters(),
            orientation_dmp=orientation_dmp.to_parameters(),
            force_dmp=profile.dmp.to_parameters(),
            quality=SegmentQuality(position_rms_m=p_rms, orientation_rms_rad=q_rms, force_rms_n=profile.rms_n),
            **common,
        )
    judges = _left_out_judges(skill_type, strokes, aligned, trials, items, ref_stroke.positions, mean_positions)
    return _JointSegment(LearnedSegment(joint, cf_z, learned_force, plane, measured), normals, weights, judges)


def _joint_normals(
    skill_type: SkillType,
    strokes: list[_Stroke],
    trials: list[LearnedTrial],
    items: list[LearnedSegment],
    reference_positions: NDArray[np.float64],
    mean_positions: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], PlaneFit | None]:
    """The joint CF z of matched segments on the alignment points (G, 3), each demonstration's weight in it (T,),
    and a slide's plane (None for a contour): a slide's from their evidence pooled (`_pooled_plane`, its x and
    origin along the mean path ``mean_positions`` (M, 3) m), a contour's by place along the reference's path
    ``reference_positions`` (G, 3) m (`_normals_by_place`)."""
    if skill_type is SkillType.slide:
        plane = _pooled_plane(strokes, trials, mean_positions)
        normals = np.broadcast_to(plane.rotation[:, 2], (ALIGNMENT_POINTS, 3))
        return normals, np.full(len(trials), 1.0 / len(trials)), plane
    normals, weights = _normals_by_place(reference_positions, trials, items)
    return normals, weights, None


def _left_out_judges(
    skill_type: SkillType,
    strokes: list[_Stroke],
    aligned: list[NDArray[np.float64]],
    trials: list[LearnedTrial],
    items: list[LearnedSegment],
    reference_positions: NDArray[np.float64],
    mean_positions: NDArray[np.float64],
) -> list[_Judge]:
    """For each demonstration, the segment's CF z and force band learned from the OTHERS (the same estimators as the
    joint segment's, on the same alignment): a demonstration is not compared with an estimate it is part of. Empty
    where it is the only one (no others to judge it by)."""
    if len(trials) < 2:
        return []
    judges = []
    for k in range(len(trials)):
        others = [i for i in range(len(trials)) if i != k]
        normals = _joint_normals(
            skill_type,
            [strokes[i] for i in others],
            [trials[i] for i in others],
            [items[i] for i in others],
            reference_positions,
            mean_positions,
        )[0]
        offset = _offset_uncertainty_n([trials[i] for i in others])
        judges.append(_Judge(_band([aligned[i] for i in others], normals, offset)[0], normals))
    return judges


def band_alignment(
    band: ForceBand, positions: NDArray[np.float64], press: NDArray[np.float64]
) -> tuple[NDArray[np.bool_], NDArray[np.int_]]:
    """Align a run's contact segment to ``band``: its path ``positions`` (M, 3) m and press ``press`` (M,) N are
    resampled to `RUN_POINTS` points evenly in time and warped onto the band's points. Return, per resampled point,
    whether its press lies within the band where it is matched, and the band point (phase index) it is matched to
    (the first, where several are)."""
    run_positions, run_press = resampled(positions, RUN_POINTS), resampled(press, RUN_POINTS)
    reference = _features(np.asarray(band.positions), np.asarray(band.mean_n))
    i, j = warping_path(reference, _features(run_positions, run_press))
    lower, upper = np.asarray(band.lower_n), np.asarray(band.upper_n)
    inside = np.zeros(RUN_POINTS, dtype=bool)
    np.logical_or.at(inside, j, (run_press[j] >= lower[i]) & (run_press[j] <= upper[i]))
    matched = np.full(RUN_POINTS, -1)
    first = np.unique(j, return_index=True)[1]
    matched[j[first]] = i[first]
    return inside, matched


def share_in_band(segments: Sequence[tuple[ForceBand, NDArray[np.float64], NDArray[np.float64]]]) -> float:
    """The share (0-1) of a run's contact time that presses within the bands: ``segments`` holds per contact segment
    its band, its path (M, 3) m and its press (M,) N; each segment counts by its samples."""
    return _weighted_share([band_alignment(band, positions, press)[0] for band, positions, press in segments],
                           [len(press) for _, _, press in segments])  # fmt: skip


def _weighted_share(insides: Sequence[NDArray[np.bool_]], samples: Sequence[int]) -> float:
    """The share of samples in band over segments, each segment's resampled points counting by its ``samples``."""
    weights = np.asarray(samples, dtype=float)
    return float(weights @ np.array([inside.mean() for inside in insides]) / weights.sum())


def _agreement(learned: LearnedTrial, judges: list[_Judge]) -> tuple[float | None, float]:
    """A demonstration against contact segments learned without it (``judges``, one per contact segment): its share
    of contact within their bands (None where a band cannot predict a new demonstration, `_Judge.predicts`), and the
    median angle (deg) between its own CF z and theirs at the matched phases."""
    r, insides, samples, angles = learned.recording, [], [], []
    for item, judge in zip(_contacts(learned), judges, strict=True):
        rows = slice(item.segment.start_index, item.segment.end_index)
        assert item.measured_force_n is not None and item.cf_z is not None
        inside, matched = band_alignment(judge.band, r.positions[rows], item.measured_force_n)
        insides.append(inside)
        samples.append(rows.stop - rows.start)
        own = resampled(np.asarray(item.cf_z), RUN_POINTS)
        known = matched >= 0
        angles.append(_angles_deg(own[known], judge.normals[matched[known]]))
    share = _weighted_share(insides, samples) if all(judge.predicts for judge in judges) else None
    return share, float(np.median(np.concatenate(angles)))


def _auto_selection(
    reference: SkillClassification, summed: NDArray[np.float64], kept: list[LearnedTrial], skill_type: SkillType
) -> tuple[AutoSelection, SkillClassification]:
    """The joint type's record and its classification for `skill_checks.type_evidence`: the summed log-odds."""
    p_contour = float(1.0 / (1.0 + np.exp(-summed.sum())))
    confidence = max(p_contour, 1.0 - p_contour)
    mixed = confidence < MIXED_CONFIDENCE
    own = [t.classification for t in kept if t.classification is not None]
    reason = (
        f"{'mixed evidence, ' if mixed else ''}{len(kept)} demonstrations together give {skill_type.value} at "
        f"{100 * confidence:.0f} % (their log-odds summed, {summed.sum():+.1f}); the reference: {reference.reason}"
    )
    classification = replace(
        reference,
        is_slide=skill_type is SkillType.slide,
        confidence=confidence,
        mixed=mixed,
        log_odds=summed,
        reason=reason,
    )
    selection = AutoSelection(
        chosen=skill_type,
        confidence=confidence,
        mixed=mixed,
        turning_within_planes_deg=max(c.turning_within_planes_deg for c in own),
        tool_following=max(c.tool_following for c in own),
        plane_rms_m=max(c.plane_rms_m for c in own),
        evidence=TypeEvidence(turning=summed[0], tool_following=summed[1], planarity=summed[2]),
        reason=reason,
    )
    return selection, classification


def learn_joint_skill(
    demonstrations: Sequence[Demonstration],
    options: LearnOptions | None = None,
    sources: Sequence[str] | None = None,
) -> Skill:
    """Return ONE skill learned from ``demonstrations`` of the same task, given as ``sources`` (ids, file names;
    default their indices), with `Skill.demonstrations` saying which were used, their weights, and which were left
    out and why; each contact segment carries its force band.

    One demonstration: exactly `learn_skill`. Raises `LearningError` when none can be learned, `JointLearningError`
    when one does not fit and ``options.misfit`` is `MisfitPolicy.refuse`, `SkillCheckError` when ``options.strict``
    and the joint skill fails a check.
    """
    options = options or LearnOptions()
    if len(demonstrations) == 1:
        return learn_skill(demonstrations[0], options)
    if len(demonstrations) > MAX_JOINT_DEMONSTRATIONS:
        raise LearningError(
            "demonstrations", f"{len(demonstrations)} given: at most {MAX_JOINT_DEMONSTRATIONS} are learned together"
        )
    total = sum(len(d.t) for d in demonstrations)
    if total > MAX_JOINT_SAMPLES:
        raise LearningError(
            "demonstrations", f"{total} samples in all: at most {MAX_JOINT_SAMPLES} are learned together"
        )
    sources = list(sources) if sources is not None else [str(k) for k in range(len(demonstrations))]
    trials, skill_type, summed, reference_index = _corresponding(demonstrations, sources, options)
    misfits = [t for t in trials if t.misfit is not None]
    if misfits and options.misfit is MisfitPolicy.refuse:
        raise JointLearningError(
            "demonstrations", "; ".join(f"{t.source} does not fit the others: {t.reason}" for t in misfits)
        )
    kept = [t for t in trials if t.misfit is None]
    learned = [t.learned for t in kept]
    assert all(item is not None for item in learned)
    reference = next(k for k, t in enumerate(kept) if t.index == reference_index)
    ref = learned[reference]
    assert ref is not None
    contacts = iter(range(len(_contacts(ref))))
    segments, items, joints = [], [], []
    for item in ref.learned:
        if item.segment.kind is SegmentKind.free:
            segments.append(item.segment)
            items.append(item)
            continue
        joint = _joint_segment(learned, next(contacts), reference, skill_type, options)  # type: ignore[arg-type]
        joints.append(joint)
        segments.append(joint.learned.segment)
        items.append(joint.learned)

    auto = options.skill_type is SkillTypeRequest.auto
    auto_selection, classification = None, ref.classification
    if summed is not None and ref.classification is not None:
        selection, classification = _auto_selection(ref.classification, summed, learned, skill_type)  # type: ignore[arg-type]
        auto_selection = selection if auto else None
    metadata = ref.demonstration.metadata
    own_checks = recording_checks(
        items,
        ref.recording,
        classification,
        skill_type,
        auto,
        metadata.tare,
        _offset_uncertainty_n(learned),
        ref.unmeasured,
    )
    # The joint force is the demonstrations' mean: held against each of them by its band (below), not against the
    # reference's own press, which differs from the mean by the hand.
    checks = [check for check in own_checks if check.name not in REFERENCE_FORCE_CHECKS]
    uses = []
    position = {t.index: p for p, t in enumerate(kept)}
    weights = dict(zip((t.index for t in kept), np.mean([j.weights for j in joints], axis=0), strict=True))
    for t in trials:
        own_type = None if t.learned is None else t.learned.skill.skill_type
        share = angle = None
        judged = t.misfit is not None or len(kept) > 1  # one used alone has no others to be judged against
        if judged and t.learned is not None and len(_contacts(t.learned)) == len(joints) and own_type is skill_type:
            # Each one used is judged against the skill learned from the OTHERS (leave-one-out); one left out by the
            # learner is in none of the joint estimates, so against the joint skill itself.
            judges = (
                [_Judge(j.learned.segment.force_band, j.normals) for j in joints]  # type: ignore[arg-type]
                if t.misfit is not None
                else [j.judges[position[t.index]] for j in joints]
            )
            share, angle = _agreement(t.learned, judges)
            if t.misfit is None:
                if share is not None:
                    checks.append(skill_checks.demonstration_in_band(t.index, t.source, share))
                checks.append(skill_checks.demonstration_normal(t.index, t.source, angle))
        uses.append(
            DemonstrationUse(
                index=t.index,
                source=t.source,
                reference=t.index == kept[reference].index,
                name=None if t.learned is None else t.learned.demonstration.metadata.name,
                weight=float(weights.get(t.index, 0.0)),
                misfit=t.misfit,
                reason=t.reason,
                skill_type=own_type,
                share_in_band=share,
                normal_angle_deg=angle,
            )
        )
    failed = [check for check in checks if not check.passed]
    if options.strict and failed:
        raise SkillCheckError(failed)
    return ref.skill.model_copy(
        update={
            "skill_type": skill_type,
            "segments": segments,
            "auto_selection": auto_selection,
            "checks": checks,
            "demonstrations": uses,
        }
    )
