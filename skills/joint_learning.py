"""One skill from several demonstrations of the same task: what repeats is the task, what varies is the hand.

Each demonstration is learned on its own first (`skills.parameterize.learn_trial`), then they are put in
correspondence and joined (docs/LEARNING.md, section 11):

1. **Correspondence** (`skills.joint_correspondence`): which demonstrations fit together, the reference among them
   (the medoid); one that does not fit is named with its reason (`schemas.skill.MisfitReason`), and left out or
   refused (`schemas.skill.MisfitPolicy`).
2. **Time alignment** (`skills.joint_alignment`): every contact segment on common points, aligned to the
   reference's by dynamic time warping on its path and its press.
3. **Joint estimates.** The type from the summed log-odds of all of them (independent evidence: the confidence
   grows with agreement); the CF z (`skills.joint_normals`: a slide's plane pooled, a contour's normals by place);
   the press as the mean with its spread per phase (`skills.force_band`: across them and within each), and the
   spread of their paths along the CF motion axes per phase (`skills.gain_schedule`: what a gain schedule reads);
   the DMPs fitted to the aligned mean (position, orientation, force), on the reference's time base: its own samples
   moved by the mean's smoothed deviation from them.
4. **Self-checks.** The joint skill's checks against the reference recording (`skills.parameterize
   .recording_checks`), and each demonstration against the skill learned WITHOUT it (`skills.joint_judges`).

ONE demonstration learns exactly as `learn_skill` (the same skill, bit for bit). World frame, SI units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from schemas.demonstration import Demonstration
from schemas.skill import (
    MAX_JOINT_DEMONSTRATIONS,
    MAX_JOINT_SAMPLES,
    SELECTION_CONTACT,
    AutoSelection,
    CheckName,
    CompliantFrames,
    DemonstrationUse,
    LearnOptions,
    MisfitPolicy,
    Segment,
    SegmentKind,
    SegmentQuality,
    Skill,
    SkillType,
    SkillTypeRequest,
    TypeEvidence,
)
from skills import skill_checks
from skills.compliant_frames import contour_frames
from skills.force_band import band_and_mean_press, offset_uncertainty_n
from skills.force_profile import cf_z_forces, constant_force, plateau_mask, press_steadiness
from skills.friction import unit_rows
from skills.gain_schedule import motion_spread
from skills.joint_alignment import (
    ALIGNMENT_POINTS,
    aligned_stroke,
    alignment_features,
    contact_segments,
    on_reference,
    resampled,
)
from skills.joint_correspondence import corresponding_trials
from skills.joint_judges import Judge, agreement, left_out_judges
from skills.joint_normals import joint_normals
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

DEVIATION_SMOOTHING_POINTS = 2.0
"""The demonstrations' mean deviation from the reference is smoothed over this many alignment points (2 % of the
segment) before it moves the reference's samples."""


REFERENCE_FORCE_CHECKS = frozenset({CheckName.force_along_cf, CheckName.press_profile})
"""A single demonstration's checks of its learned force against its own press; a joint skill's force is checked
against every demonstration's press by `skill_checks.demonstration_in_band` instead."""


class JointLearningError(LearningError):
    """A demonstration does not fit the others and ``misfit`` is `MisfitPolicy.refuse`."""


@dataclass(frozen=True)
class _JointSegment:
    """A joint contact segment and what the checks compare on the reference recording."""

    learned: LearnedSegment
    normals: NDArray[np.float64]
    """The joint CF z on the alignment points (G, 3)."""
    weights: NDArray[np.float64]
    """Each demonstration's weight (T,) in the joint normals (in the order learned from)."""
    judges: list[Judge]
    """What each demonstration (in the order learned from) is judged against: the segment learned without it."""


def _joint_segment(
    trials: list[LearnedTrial], k: int, reference: int, skill_type: SkillType, options: LearnOptions
) -> _JointSegment:
    """The ``k``-th contact segment joined over ``trials`` (``reference`` gives the time base and the samples)."""
    items = [contact_segments(t)[k] for t in trials]
    strokes = [aligned_stroke(t, item) for t, item in zip(trials, items, strict=True)]
    ref_trial, ref_item, ref_stroke = trials[reference], items[reference], strokes[reference]
    ref_features = alignment_features(ref_stroke.positions, ref_stroke.press)
    aligned = []
    for stroke in strokes:
        q = (
            stroke.quaternions
            * np.where(np.sum(stroke.quaternions * ref_stroke.quaternions, axis=1) < 0, -1.0, 1.0)[:, None]
        )
        values = np.column_stack([stroke.positions, q, stroke.forces, stroke.normals, stroke.wobble])
        aligned.append(on_reference(ref_features, alignment_features(stroke.positions, stroke.press), values))
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
    normals, weights, plane = joint_normals(skill_type, strokes, trials, items, ref_stroke.positions, mean_positions)
    if plane is not None:
        cf_z = np.broadcast_to(plane.rotation[:, 2], (m, 3))
    else:
        own_normals = np.asarray(ref_item.cf_z)
        on_path = unit_rows(mean_on_samples(normals, ref_stroke.normals, own_normals))
        rotations = contour_frames(mean_positions, np.zeros_like(mean_positions), rate_hz, slice(0, m), normals=on_path)
        cf_z = rotations[:, :, 2]
    band, mean_press = band_and_mean_press(aligned, normals, offset_uncertainty_n(trials))
    points = len(aligned[0])
    frames_on_points = (
        plane.rotation if plane is not None else rotations[np.linspace(0, m - 1, points).round().astype(int)]
    )
    spread = motion_spread([a[:, 0:3] for a in aligned], frames_on_points) if len(aligned) > 1 else None
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
        "motion_spread": spread,
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
    judges = left_out_judges(skill_type, strokes, aligned, trials, items, ref_stroke.positions, mean_positions)
    return _JointSegment(LearnedSegment(joint, cf_z, learned_force, plane, measured), normals, weights, judges)


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
    trials, skill_type, summed, reference_index = corresponding_trials(demonstrations, sources, options)
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
    contacts = iter(range(len(contact_segments(ref))))
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
        offset_uncertainty_n(learned),
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
        if (
            judged
            and t.learned is not None
            and len(contact_segments(t.learned)) == len(joints)
            and own_type is skill_type
        ):
            # Each one used is judged against the skill learned from the OTHERS (leave-one-out); one left out by the
            # learner is in none of the joint estimates, so against the joint skill itself.
            judges = (
                [Judge(j.learned.segment.force_band, j.normals) for j in joints]  # type: ignore[arg-type]
                if t.misfit is not None
                else [j.judges[position[t.index]] for j in joints]
            )
            share, angle = agreement(t.learned, judges)
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
