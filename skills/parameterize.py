"""Skill parameterization (paper sections 3-4): one demonstration in, one executable `Skill` out.

Pipeline: uniform time grid -> contact analysis -> slide segmentation -> (auto: classify) ->
segmentation of the chosen skill -> per segment: compliant frame(s), force profile, DMPs for
position, orientation and force -> quality figures from rolling the DMPs out again.
All in the world frame unless stated; slide positions are learned in their CF x-y plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt, gaussian_filter1d

from schemas.demonstration import Demonstration, DemonstrationArrays, DemonstrationSummary, TareMethod
from schemas.skill import (
    SELECTION_CONTACT,
    SELECTION_FREE,
    AutoSelection,
    CompliantFrames,
    LearnOptions,
    Segment,
    SegmentKind,
    SegmentQuality,
    Skill,
    SkillAttributes,
    SkillCheck,
    SkillType,
    SkillTypeRequest,
    TypeEvidence,
)
from skills import recording_faults, skill_checks
from skills.compliant_frames import PlaneFit, contour_frames, plane_along, slide_frame, tool_velocities
from skills.contact import ContactAnalysis, analyse_contact
from skills.dmp import DMP, uniform_grid_step
from skills.force_profile import cf_z_forces, constant_force, press_steadiness
from skills.friction import blended_friction_free, friction_coefficient, unit_rows
from skills.preprocess import MAX_GAP_S, merged_intervals, resampled_recording, unmeasured_intervals
from skills.quaternion_dmp import QuaternionDMP
from skills.quaternions import (
    matrix_from_quaternion,
    quaternion_angle_between,
    quaternion_from_matrix,
    quaternions_sign_continuous,
)
from skills.segmentation import SegmentBounds, segment_demonstration
from skills.selection import SkillClassification, classify_skill
from skills.surface_evidence import SurfaceEvidence, surface_evidence

MAX_RATE_HZ = 100_000.0
"""Highest sampling rate learned from, Hz (a force sensor at 10 kHz is plausible; 200 MHz is a unit error)."""

UNSTEADY_BASIS_PER_SECOND = 40.0
"""Force DMP bases per second of a slide segment whose press was not steady: 25 ms apart, a 3 Hz wobble keeps 97 %
of its amplitude through the fit's smoothing (`basis_resolution`)."""

PROFILE_FLOOR = 0.3
"""A slide's force profile presses at least this fraction of its 90th percentile (its feet are the approach's)."""

MAX_SAMPLES = 1_000_000
"""Most samples of the uniform grid learned from (about 17 minutes at 1 kHz)."""


class LearningError(ValueError):
    """The demonstration cannot give the asked-for skill; ``field`` names the input at fault."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


def uniform_arrays(demonstration: Demonstration | DemonstrationArrays) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Return (t, positions, quaternions, wrenches) of ``demonstration`` (or its ``arrays()``, converted once by a
    caller that reads them too) on the uniform grid the learner works on (s, m, scalar-last sign-continuous
    quaternions, N and N·m applied, world): the grid a skill's sample indices refer to."""
    a = demonstration.arrays() if isinstance(demonstration, Demonstration) else demonstration
    steps = np.diff(a.t)
    median_step = float(np.median(steps))
    if 1.0 / median_step > MAX_RATE_HZ:
        raise LearningError("t", f"time stamps {median_step:.3g} s apart ({1 / median_step:.3g} Hz): must be seconds")
    longest = int(np.argmax(steps))
    if steps[longest] > MAX_GAP_S:
        raise LearningError(
            "t",
            f"a gap of {steps[longest]:.3g} s between samples {longest} and {longest + 1} (longest allowed "
            f"{MAX_GAP_S} s): split the recording there",
        )
    if (a.t[-1] - a.t[0]) / median_step > MAX_SAMPLES:
        raise LearningError(
            "t", f"{(a.t[-1] - a.t[0]) / median_step:.3g} samples at the median rate: at most {MAX_SAMPLES}"
        )
    # Uniform as the DMP fit will judge it: a grid 0.2 % off once passed here (1 % allowed) and failed the fit.
    if uniform_grid_step(a.t) is not None:
        return a.t, a.positions, quaternions_sign_continuous(a.orientations), a.wrenches
    r = resampled_recording(a.t, a.positions, a.orientations, a.wrenches, rate_hz=1.0 / median_step)
    return r.t, r.positions, r.orientations, r.wrenches


def _rms(values: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def basis_count(duration_s: float, options: LearnOptions) -> int:
    """Return the DMP basis count for a segment: ``n_basis``, more for long segments, at most ``max_basis``."""
    wanted = max(options.n_basis, int(np.ceil(options.basis_per_second * duration_s)))
    return max(2, min(wanted, options.max_basis))


def basis_resolution(values: NDArray, t: NDArray, n_basis: int) -> NDArray:
    """Return ``values`` (N, D) smoothed by a Gaussian of half the basis spacing in time.

    The DMP fit takes second differences of the data (targets consistent with the integrator):
    sensor noise and tremor faster than the bases can follow would otherwise be fitted as huge
    weights that reproduce the demonstration only at its own time step (measured: a contour
    force profile peaking at 14.7 N when rolled out at 1 ms and 33.6 N at 10 ms).
    """
    spacing_samples = (len(t) - 1) / max(n_basis - 1, 1)
    return gaussian_filter1d(values, sigma=max(0.5 * spacing_samples, 1e-3), axis=0, mode="nearest")


def motion_dmps(
    t: NDArray, positions: NDArray, quaternions: NDArray, n_basis: int, frame: str
) -> tuple[DMP, QuaternionDMP, float, float]:
    """Fit position and orientation DMPs; return them with their reproduction RMS (m, rad) on the fit grid."""
    position_dmp = DMP.fit(t, basis_resolution(positions, t, n_basis), n_basis=n_basis, kind="position", frame=frame)
    orientation_dmp = QuaternionDMP.fit(t, quaternions, n_basis=n_basis)
    dt = float(t[1] - t[0])
    y = position_dmp.rollout(dt).y
    q = orientation_dmp.rollout(dt).q
    n = min(len(y), len(q), len(t))
    position_rms = _rms(np.linalg.norm(y[:n] - positions[:n], axis=1))
    orientation_rms = _rms(quaternion_angle_between(q[:n], quaternions[:n]))
    return position_dmp, orientation_dmp, position_rms, orientation_rms


def _decimated_indices(n: int, most: int) -> NDArray[np.int_]:
    """Return at most ``most`` evenly spread indices of ``range(n)``, first and last included."""
    return np.unique(np.linspace(0, n - 1, min(n, most)).round().astype(int))


@dataclass(frozen=True)
class Recording:
    """The demonstration on its uniform grid (world, SI), its contact analysis and the normals of its surfaces."""

    t: NDArray[np.float64]
    positions: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    forces: NDArray[np.float64]
    velocities: NDArray[np.float64]
    contact: ContactAnalysis
    surfaces: SurfaceEvidence
    pooled_planes: dict[int, PlaneFit] = field(default_factory=dict)
    """The slide CF fitted to each pooled surface (by `SurfaceGroup.index`), once for all its segments."""


@dataclass(frozen=True)
class LearnedSegment:
    """A segment and what its checks compare: per sample CF z (M, 3), the force learned along it (M,) N and the
    force measured along it (M,) N."""

    segment: Segment
    cf_z: NDArray[np.float64] | None = None
    learned_force_n: NDArray[np.float64] | None = None
    plane: PlaneFit | None = None
    measured_force_n: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class ForceProfileFit:
    """A contact segment's CF-z force as a DMP, its rollout at every sample (M,) N and its RMS against the data (N)."""

    dmp: DMP
    learned_n: NDArray[np.float64]
    rms_n: float


def force_profile_dmp(
    t_seg: NDArray[np.float64], f_z: NDArray[np.float64], fit: slice, stride: int, n_basis: int, rate_hz: float
) -> ForceProfileFit:
    """Fit the CF-z force ``f_z`` (M,) N of a segment (times ``t_seg`` (M,) s from its start) as a 1-D force DMP on
    the strided grid ``fit`` (every ``stride`` samples) with ``n_basis`` bases."""
    dmp = DMP.fit(t_seg[fit], basis_resolution(f_z[fit], t_seg[fit], n_basis), n_basis=n_basis, kind="force")
    rollout = dmp.rollout(stride / rate_hz).y[:, 0]
    n = min(len(rollout), len(f_z[fit]))
    learned = np.interp(t_seg, np.arange(len(rollout)) * stride / rate_hz, rollout)
    return ForceProfileFit(dmp, learned, _rms(rollout[:n] - f_z[fit][:n]))


def _segment(
    index: int, bounds: SegmentBounds, skill_type: SkillType, r: Recording, options: LearnOptions
) -> LearnedSegment:
    """Parameterize one segment: frames, force profile, DMPs and their quality."""
    rows = slice(bounds.start, bounds.end)
    t_seg = r.t[rows] - r.t[bounds.start]
    p_seg, q_seg, f_seg = r.positions[rows], r.quaternions[rows], r.forces[rows]
    n_basis = basis_count(float(t_seg[-1]), options)
    # DMPs are fitted on an evenly strided grid that ends on the last sample (the goal).
    stride = -(-len(t_seg) // options.max_fit_samples)
    fit = slice((len(t_seg) - 1) % stride, None, stride)
    common = {
        "index": index,
        "start_index": bounds.start,
        "end_index": bounds.end,
        "t_start": float(r.t[bounds.start]),
        "t_end": float(r.t[bounds.end - 1]),
        "start_reason": bounds.start_reason,
        "end_reason": bounds.end_reason,
    }
    if not bounds.contact:
        position_dmp, orientation_dmp, p_rms, q_rms = motion_dmps(t_seg[fit], p_seg[fit], q_seg[fit], n_basis, "world")
        free = Segment(
            kind=SegmentKind.free,
            selection=list(SELECTION_FREE),
            position_dmp=position_dmp.to_parameters(),
            orientation_dmp=orientation_dmp.to_parameters(),
            quality=SegmentQuality(position_rms_m=p_rms, orientation_rms_rad=q_rms),
            **common,
        )
        return LearnedSegment(free)

    rate_hz = r.contact.rate_hz
    if skill_type is SkillType.slide:
        plane = _pooled_plane(bounds, r)
        in_plane = ((p_seg - plane.origin) @ plane.rotation)[:, :2]
        position_dmp, orientation_dmp, p_rms, q_rms = motion_dmps(t_seg[fit], in_plane[fit], q_seg[fit], n_basis, "cf")
        f_z = cf_z_forces(f_seg, plane.rotation[:, 2])
        steadiness = press_steadiness(f_z, rate_hz)
        force = constant_force(f_z, rate_hz)
        profile = None
        if not steadiness.steady:
            # A press that wobbles (3 Hz) needs bases closer than the motion's: their smoothing would halve it.
            force_basis = min(options.max_basis, max(n_basis, round(UNSTEADY_BASIS_PER_SECOND * float(t_seg[-1]))))
            # Its touch-down and lift-off feet are the approach's and the retreat's to make (as for a constant): a
            # profile asking ~0 N at its ends lets the tool leave the surface it is meant to press.
            pressed = np.maximum(f_z, PROFILE_FLOOR * np.percentile(f_z, 90))
            profile = force_profile_dmp(t_seg, pressed, fit, stride, force_basis, rate_hz)
        slide = Segment(
            kind=SegmentKind.contact,
            selection=list(SELECTION_CONTACT),
            compliant_frames=CompliantFrames(
                t=[0.0],
                origins=[plane.origin.tolist()],
                orientations=[quaternion_from_matrix(plane.rotation).tolist()],
            ),
            position_dmp=position_dmp.to_parameters(),
            orientation_dmp=orientation_dmp.to_parameters(),
            force_constant_n=force.value_n if profile is None else None,
            force_dmp=None if profile is None else profile.dmp.to_parameters(),
            quality=SegmentQuality(
                position_rms_m=p_rms,
                orientation_rms_rad=q_rms,
                force_rms_n=_rms(f_z[force.region] - force.value_n) if profile is None else profile.rms_n,
                plane_residual_rms_m=plane.residual_rms_m,
                force_std_low_variance_n=force.std_n,
                force_measured_percentiles_n=np.percentile(f_z, [10, 50, 90]).tolist(),
                press_spread=steadiness.spread,
                press_trend=steadiness.trend,
            ),
            **common,
        )
        cf_z = np.broadcast_to(plane.rotation[:, 2], p_seg.shape)
        learned = np.full(len(p_seg), force.value_n) if profile is None else profile.learned_n
        return LearnedSegment(slide, cf_z, learned, plane, f_z)

    rotations = contour_frames(r.positions, r.forces, rate_hz, rows, normals=_contour_normals(rows, r))
    f_z = cf_z_forces(f_seg, rotations[:, :, 2])
    position_dmp, orientation_dmp, p_rms, q_rms = motion_dmps(t_seg[fit], p_seg[fit], q_seg[fit], n_basis, "world")
    profile = force_profile_dmp(t_seg, f_z, fit, stride, n_basis, rate_hz)
    keep = _decimated_indices(len(t_seg), options.contour_frames_max)
    contour = Segment(
        kind=SegmentKind.contact,
        selection=list(SELECTION_CONTACT),
        compliant_frames=CompliantFrames(
            t=t_seg[keep].tolist(),
            origins=p_seg[keep].tolist(),
            orientations=quaternions_sign_continuous(quaternion_from_matrix(rotations[keep])).tolist(),
        ),
        position_dmp=position_dmp.to_parameters(),
        orientation_dmp=orientation_dmp.to_parameters(),
        force_dmp=profile.dmp.to_parameters(),
        quality=SegmentQuality(position_rms_m=p_rms, orientation_rms_rad=q_rms, force_rms_n=profile.rms_n),
        **common,
    )
    return LearnedSegment(contour, rotations[:, :, 2], profile.learned_n, None, f_z)


def _pooled_plane(bounds: SegmentBounds, r: Recording) -> PlaneFit:
    """The slide CF of a contact segment from its surface (`skills.surface_evidence`): its own positions where they
    span a plane (an uneven part's local plane), else those of every contact segment on the same surface, pooled
    (strokes side by side, each a line); weighed against the force with the force direction's uncertainty measured
    on that surface, and bounded by the friction cone where the contact covers an area of it."""
    rows = slice(bounds.start, bounds.end)
    surface = r.surfaces.group(bounds.start, bounds.end)
    if surface is None:
        return slide_frame(r.positions[rows], r.forces[rows], r.contact.directions[rows])
    evidence = {"force_sigma_deg": surface.force_sigma_deg, "area": surface.is_area}
    own = slide_frame(r.positions[rows], r.forces[rows], r.contact.directions[rows], **evidence)
    if own.across_width_m >= own.equal_width_m or len(surface.segments) == 1:
        return own
    if surface.index not in r.pooled_planes:
        pooled = surface.rows
        r.pooled_planes[surface.index] = slide_frame(
            r.positions[pooled], r.forces[pooled], r.contact.directions[pooled], **evidence
        )
    return plane_along(r.pooled_planes[surface.index], r.positions[rows])


def _contour_normals(rows: slice, r: Recording) -> NDArray[np.float64] | None:
    """The fused normals (M, 3) of a contour segment's samples (`skills.surface_evidence`), the force's where a
    sample lies on no surface of the slide segmentation (none at all: None, the force's alone)."""
    normals = r.surfaces.normals[rows]
    known = np.linalg.norm(normals, axis=1) > 0.5
    if not known.any():
        return None
    if known.all():
        return normals
    nearest = distance_transform_edt(~known, return_distances=False, return_indices=True)[0]
    return normals[nearest]


def recording_checks(
    learned: list[LearnedSegment],
    r: Recording,
    classification: SkillClassification | None,
    skill_type: SkillType,
    auto: bool,
    tare: TareMethod,
    offset_uncertainty_n: float | None,
    unmeasured: NDArray[np.float64],
) -> list[SkillCheck]:
    """Return the skill's checks against what the demonstration measured (`skills.skill_checks`); the import's
    sensor-offset uncertainty (N) is checked where it fitted one, and the contact segments against the intervals
    (K, 2) s without measurement (the import's gaps, the demonstration's own)."""
    checks, presses, free = [], {}, np.zeros(len(r.t), dtype=bool)
    in_contact, contact_spans = [], []
    for item in learned:
        segment = item.segment
        rows = slice(segment.start_index, segment.end_index)
        if segment.kind is SegmentKind.free:
            free[rows] = True
            continue
        in_contact.append(rows)
        contact_spans.append((segment.t_start, segment.t_end))
        f, v = r.forces[rows], r.velocities[rows]
        free_of_friction = blended_friction_free(f, v, friction_coefficient(f, v), normals=item.cf_z)
        checks.append(skill_checks.force_along_cf(segment.index, free_of_friction, item.learned_force_n))
        checks.append(skill_checks.press_profile(segment.index, item.measured_force_n, item.learned_force_n))
        limit = skill_checks.PLANE_FORCE_TOLERANCE_DEG if item.plane is None else item.plane.plane_force_limit_deg
        checks.append(
            skill_checks.cf_z_vs_force(segment.index, free_of_friction, item.cf_z, skill_type, r.contact.rate_hz, limit)
        )
        if item.plane is not None:
            tool_axis = unit_rows(matrix_from_quaternion(r.quaternions[rows])[:, :, 2].mean(axis=0))
            checks.extend(skill_checks.plane_checks(segment.index, item.plane, tool_axis))
        presses[segment.index] = float(np.percentile(np.linalg.norm(f, axis=1), 90))
    checks.extend(skill_checks.stroke_strength(presses))
    weakest = min(presses.values())
    checks.append(skill_checks.force_outside_contact(r.forces, r.velocities, free, weakest, r.contact.rate_hz))
    contact_forces = np.concatenate([r.forces[rows] for rows in in_contact])
    contact_velocities = np.concatenate([r.velocities[rows] for rows in in_contact])
    contacts = [item.segment for item in learned if item.segment.kind is SegmentKind.contact]
    areas = [r.surfaces.group(segment.start_index, segment.end_index) for segment in contacts]
    geometry_decides = all(surface is not None and surface.is_area for surface in areas)
    checks.append(recording_faults.friction_along_motion(contact_forces, contact_velocities, geometry_decides))
    checks.append(recording_faults.press_direction(contact_forces))
    checks.append(recording_faults.unmeasured_contact(contact_spans, unmeasured))
    if tare is not TareMethod.none:
        checks.append(recording_faults.sensor_offset(tare, offset_uncertainty_n, weakest))
    checks.append(skill_checks.type_evidence(classification, skill_type, auto))
    return checks


class SkillCheckError(LearningError):
    """Strict learning refused the skill: ``checks`` are the ones it failed."""

    def __init__(self, checks: list[SkillCheck]) -> None:
        reasons = "; ".join(check.message for check in checks)
        super().__init__("strict", f"the skill fails {len(checks)} of its checks: {reasons}")
        self.checks = checks


@dataclass(frozen=True)
class LearnedTrial:
    """One demonstration learned: the skill, the recording it was learned on, its segments with what their checks
    compare, the type's evidence (None where it could not be measured) and the intervals (K, 2) s without
    measurement. What `skills.joint_learning` joins across demonstrations."""

    skill: Skill
    recording: Recording
    learned: list[LearnedSegment]
    classification: SkillClassification | None
    unmeasured: NDArray[np.float64]
    demonstration: Demonstration


def learn_skill(demonstration: Demonstration, options: LearnOptions | None = None) -> Skill:
    """Return the skill parameterized from one validated ``demonstration``, with its checks.

    Raises `LearningError` (a ValueError naming the field) when the demonstration cannot give
    a contact skill, e.g. it has no contact or no moving contact to classify; `SkillCheckError`
    (a `LearningError`) when ``options.strict`` and the skill fails any of its checks.
    """
    return learn_trial(demonstration, options).skill


def learn_trial(demonstration: Demonstration, options: LearnOptions | None = None) -> LearnedTrial:
    """Return ``demonstration`` learned (`learn_skill`'s skill) with what it was learned from; raises as
    `learn_skill`."""
    options = options or LearnOptions()
    recorded = demonstration.arrays()
    t, positions, quaternions, wrenches = uniform_arrays(recorded)
    forces = wrenches[:, :3]
    contact = analyse_contact(t, positions, forces, options.contact_force_threshold_n)
    if not contact.intervals:
        raise LearningError(
            "wrenches",
            "the tool never touches anything (no force pressing on a surface), so there is no contact skill",
        )
    slide_segments = segment_demonstration(positions, forces, contact, True, options.min_segment_duration_s)
    if not any(s.contact for s in slide_segments):
        raise LearningError(
            "wrenches",
            f"contact lasts less than the shortest segment ({options.min_segment_duration_s} s)",
        )
    velocities = tool_velocities(positions, contact.rate_hz)
    surfaces = surface_evidence(positions, forces, velocities, contact, slide_segments)
    r = Recording(t, positions, quaternions, forces, velocities, contact, surfaces)

    auto = options.skill_type is SkillTypeRequest.auto
    try:
        sliding = np.linalg.norm(contact.directions, axis=1, keepdims=True) > 0.5
        shares = [surfaces.group(s.start, s.end).area_share for s in slide_segments if s.contact]
        classification = classify_skill(
            positions, forces, surfaces.normals * sliding, quaternions, slide_segments, contact.rate_hz, shares
        )
    except ValueError as exc:
        if auto:
            raise LearningError("wrenches", str(exc)) from None
        classification = None
    auto_selection = None
    if auto:
        assert classification is not None
        skill_type = SkillType.slide if classification.is_slide else SkillType.contour
        odds = classification.log_odds
        auto_selection = AutoSelection(
            chosen=skill_type,
            confidence=classification.confidence,
            mixed=classification.mixed,
            turning_within_planes_deg=classification.turning_within_planes_deg,
            tool_following=classification.tool_following,
            plane_rms_m=classification.plane_rms_m,
            evidence=TypeEvidence(turning=odds[0], tool_following=odds[1], planarity=odds[2]),
            reason=classification.reason,
        )
    else:
        skill_type = SkillType(options.skill_type.value)

    if skill_type is SkillType.slide:
        bounds = slide_segments
    else:
        bounds = segment_demonstration(positions, forces, contact, False, options.min_segment_duration_s)
    learned = [_segment(k, b, skill_type, r, options) for k, b in enumerate(bounds)]
    uncertainty = demonstration.metadata.force_offset_uncertainty_n
    unmeasured = merged_intervals(
        np.concatenate(
            [np.reshape(demonstration.metadata.unmeasured_intervals_s, (-1, 2)), unmeasured_intervals(recorded.t)]
        )
    )
    checks = recording_checks(
        learned, r, classification, skill_type, auto, demonstration.metadata.tare, uncertainty, unmeasured
    )
    failed = [check for check in checks if not check.passed]
    if options.strict and failed:
        raise SkillCheckError(failed)
    skill = Skill(
        skill_type=skill_type,
        attributes=SkillAttributes(
            selection_matrix_cf=list(SELECTION_CONTACT),
            cf_constraint="plane" if skill_type is SkillType.slide else "force-direction",
        ),
        segments=[item.segment for item in learned],
        auto_selection=auto_selection,
        checks=checks,
        demonstration=DemonstrationSummary.of(demonstration),
        sample_rate_hz=contact.rate_hz,
        taught_world=_taught_world(demonstration),
    )
    return LearnedTrial(skill, r, learned, classification, unmeasured, demonstration)


def _taught_world(demonstration: Demonstration) -> dict | None:
    """The simulated world a simulator recording carries (``metadata.extra['world']``), passed on to the skill."""
    world = demonstration.metadata.extra.get("world")
    return dict(world) if isinstance(world, dict) else None
