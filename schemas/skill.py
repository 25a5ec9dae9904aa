"""The learned skill: static attributes plus the parameters extracted from one demonstration.

Frames: every pose is in the world frame unless a field says CF. A compliant frame (CF) is
stored as its pose in the world (origin, scalar-last quaternion world-from-CF); its z axis
points along the force the tool applies (into the surface). Selection diagonals are in CF,
1 = motion-controlled axis, 0 = force-controlled axis, axes ``[x, y, z, rx, ry, rz]``.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.demonstration import MAX_DURATION_S, DemonstrationSummary, Quaternion, Vector3
from schemas.numbers import Real, WholeNumber
from schemas.text import FreeForm, Name, Text

SELECTION_CONTACT: list[float] = [1.0, 1.0, 0.0, 1.0, 1.0, 1.0]
"""Selection diagonal in CF for slide and contour contact segments: force control along CF z."""
SELECTION_FREE: list[float] = [1.0] * 6
"""Selection diagonal for free (no contact) segments: motion control on every axis."""
MAX_BASIS = 1000
"""Most basis functions a DMP may have (``LearnOptions.max_basis`` at most)."""
MAX_FRAMES = 5000
"""Most compliant frames per segment (``LearnOptions.contour_frames_max`` at most)."""
MAX_SEGMENTS = 500
"""Most segments a skill may have."""
MAX_JOINT_DEMONSTRATIONS = 8
"""Most demonstrations one skill is learned from together (``POST /skills``' ``demonstration_ids``)."""
MAX_JOINT_SAMPLES = 1_000_000
"""Most samples, summed over the demonstrations, one skill is learned from together (learning N costs N times one)."""
MAX_CHECKS = 8 * MAX_SEGMENTS + 2 * MAX_JOINT_DEMONSTRATIONS
"""Most checks a skill may carry (a few per segment, two per demonstration it was learned from)."""
IN_BAND_SHARE = 0.9
"""A run presses like the demonstrations when its press lies within their force band for at least this share of its
contact (a demonstration against its joint skill; an execution against the band, `ExecutionTolerances`)."""
MAX_BAND_POINTS = 1000
"""Most phase points of a segment's force band (and of its motion spread)."""

SpreadXY = Annotated[list[Annotated[Real, Field(ge=0)]], Field(min_length=2, max_length=2)]
"""A spread along CF x and CF y, m (never negative)."""


class SkillType(StrEnum):
    """A learned skill's type."""

    slide = "slide"
    contour = "contour"


class SkillTypeRequest(StrEnum):
    """The type asked for when learning; ``auto`` classifies it from the demonstration."""

    slide = "slide"
    contour = "contour"
    auto = "auto"


class BoundaryReason(StrEnum):
    """What decided where a segment starts or ends (docs/LEARNING.md)."""

    force = "force"
    """The force along the normal rose from (or fell to) the touch level."""
    surface = "surface"
    """The tool reached (or left) the surface it pressed on."""
    crease = "crease"
    """The surface normal jumps: another plane (slide)."""
    stroke = "stroke"
    """The press dips between two strokes that go another way or press on another surface, without a lift-off."""
    turn = "turn"
    """A path that goes round completed a full turn: one segment per pass."""
    recording = "recording"
    """The recording starts or ends there."""
    contact = "contact"
    """A free segment starts where a contact ended, or ends where one starts."""


class SegmentKind(StrEnum):
    """Whether the tool was in contact during a segment."""

    contact = "contact"
    free = "free"


class DMPParameters(BaseModel):
    """Everything needed to roll a discrete DMP out again (Ijspeert/Nakanishi/Schaal; Ude 2014 for quaternions).

    Transformation system, per dimension (``kind`` position or force)::

        tau dz = alpha_z (beta_z (g - y) - z) + s f(x),   tau dy = z,   tau dx = -alpha_x x
        f(x) = x sum_i psi_i(x) w_i / sum_i psi_i(x),    psi_i = exp(-h_i (x - c_i)^2)

    with ``s = (g' - y0') / (g - y0)`` for a new start y0' and goal g' when the demonstration's
    ``|g - y0|`` was large enough (``amplitude_scaling`` true), else ``s = 1``: the guard for
    start == goal, where the classic scaling would blow up or vanish.
    For ``kind = quaternion`` (Ude et al. 2014) ``y`` is a unit quaternion, ``z`` the scaled
    angular velocity ``eta`` (3-vector) and ``g - y`` becomes ``2 log(g * conj(q))``; no scaling.
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["position", "force", "quaternion"] = Field(description="What the DMP encodes.")
    frame: Literal["world", "cf"] = Field(
        "world", description="Coordinates of y: world frame, or the segment's compliant frame (slide positions)."
    )
    duration_s: Real = Field(gt=0, le=MAX_DURATION_S, description="Time constant tau: the demonstrated duration, s.")
    alpha_z: Real = Field(gt=0, description="Spring-damper gain alpha_z, 1/s scaled by tau.")
    beta_z: Real = Field(gt=0, description="Spring gain beta_z (alpha_z/4 is critically damped).")
    alpha_x: Real = Field(gt=0, description="Canonical system decay alpha_x.")
    centers: list[float] = Field(
        max_length=MAX_BASIS, description="Basis centres c_i in phase x (dimensionless, in (0, 1])."
    )
    widths: list[float] = Field(max_length=MAX_BASIS, description="Basis widths h_i (1/phase^2).")
    weights: list[list[float]] = Field(
        max_length=MAX_BASIS, description="Weights w, one row per basis, one column per dimension."
    )
    start: list[float] = Field(
        min_length=1, max_length=4, description="Demonstrated start y0 (m, N or quaternion [x, y, z, w])."
    )
    goal: list[float] = Field(min_length=1, max_length=4, description="Demonstrated goal g (same units as start).")
    amplitude_scaling: list[bool] = Field(
        description="Per dimension: whether the forcing term scales with (g - y0) on rollout."
    )


class CompliantFrames(BaseModel):
    """The compliant frame(s) of a contact segment in the world: one for slide, a series for contour.

    ``t`` is time since the segment start (s); between samples interpolate origins linearly and
    orientations by slerp (the contour series is smooth by construction).
    """

    model_config = ConfigDict(extra="forbid")

    t: list[float] = Field(
        min_length=1, max_length=MAX_FRAMES, description="Time since segment start, s; one per frame."
    )
    origins: list[Vector3] = Field(min_length=1, max_length=MAX_FRAMES, description="CF origins in world, m.")
    orientations: list[Quaternion] = Field(
        min_length=1, max_length=MAX_FRAMES, description="World-from-CF rotations, unit quaternions [x, y, z, w]."
    )


class SegmentQuality(BaseModel):
    """How well the parameters reproduce the demonstration segment."""

    position_rms_m: Real = Field(
        description="RMS distance of the position DMP rollout to the demonstrated positions, m."
    )
    orientation_rms_rad: Real = Field(description="RMS angle of the orientation DMP rollout to the demonstration, rad.")
    force_rms_n: Real | None = Field(
        None, description="RMS of the learned force profile against the demonstrated CF-z force, N (contact only)."
    )
    plane_residual_rms_m: Real | None = Field(
        None, description="RMS distance of the positions to the fitted plane, m (slide contact only)."
    )
    force_std_low_variance_n: Real | None = Field(
        None, description="Standard deviation of the CF-z force in the low-variance region, N (slide contact only)."
    )
    force_measured_percentiles_n: list[float] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Slide contact segments: 10th, 50th and 90th percentile of the demonstrated CF-z force over the "
        "segment (ramps included), N: the measured profile the constant stands for.",
    )
    press_spread: Real | None = Field(
        None,
        description="Slide contact segments: the 10th-90th percentile spread of the pressed CF-z force over the body "
        "of the segment (its ramps left out), over its median; above 0.5 the press was not steady and the segment "
        "keeps its force profile.",
    )
    press_trend: Real | None = Field(
        None,
        description="Slide contact segments: how much the press's linear trend changes it over the body of the "
        "segment, over its median (+ rising); beyond ±0.5 the press ramped and the segment keeps its force profile.",
    )


class ForceBand(BaseModel):
    """The force several demonstrations pressed along a contact segment's CF z, aligned in time: mean and spread
    per phase (`skills.joint_learning`).

    ``phase`` is the fraction (0-1) of the segment's duration; ``positions`` the demonstrations' mean path at each
    phase (world, m), by which another run (a left-out demonstration, an execution) is aligned to the band.
    """

    model_config = ConfigDict(extra="forbid")

    phase: list[Real] = Field(min_length=2, max_length=MAX_BAND_POINTS, description="Fraction of the segment, 0-1.")
    positions: list[Vector3] = Field(
        min_length=2, max_length=MAX_BAND_POINTS, description="Mean tool-point path at each phase, world, m."
    )
    mean_n: list[Real] = Field(
        min_length=2, max_length=MAX_BAND_POINTS, description="Mean press along CF z at each phase, N."
    )
    spread_n: list[Real] = Field(
        min_length=2,
        max_length=MAX_BAND_POINTS,
        description="Standard deviation of the press at each phase, N: across the demonstrations and within each "
        "(its wobble about its own smoothed press), combined.",
    )
    lower_n: list[Real] = Field(min_length=2, max_length=MAX_BAND_POINTS, description="Band's lower edge, N.")
    upper_n: list[Real] = Field(min_length=2, max_length=MAX_BAND_POINTS, description="Band's upper edge, N.")
    demonstrations: WholeNumber = Field(ge=1, description="How many demonstrations the band was built from.")


class MotionSpread(BaseModel):
    """How far apart several demonstrations moved the tool along a contact segment, phase by phase
    (`skills.joint_learning`): what a gain schedule reads (``ControllerGains.gain_schedule``, `skills.gain_schedule`).

    ``phase`` is the fraction (0-1) of the segment's duration, on the same points as its `ForceBand`; ``spread_m``
    the standard deviation, across the demonstrations aligned in time, of their tool-point positions along the CF x
    and CF y axes (the motion axes) at each phase, pooled over the nearby phases as the force band's.
    """

    model_config = ConfigDict(extra="forbid")

    phase: list[Real] = Field(min_length=2, max_length=MAX_BAND_POINTS, description="Fraction of the segment, 0-1.")
    spread_m: list[SpreadXY] = Field(
        min_length=2,
        max_length=MAX_BAND_POINTS,
        description="Standard deviation of the aligned tool-point positions across the demonstrations along CF x "
        "and CF y at each phase, m.",
    )
    demonstrations: WholeNumber = Field(ge=2, description="How many demonstrations the spread was taken over.")


class Segment(BaseModel):
    """One segment of the skill: a movement primitive with its frames and force profile."""

    model_config = ConfigDict(extra="forbid")

    index: int = Field(ge=0, description="Position in the sequence, from 0.")
    kind: SegmentKind = Field(description="Contact or free (from force and kinematics, see docs/LEARNING.md).")
    start_index: int = Field(ge=0, description="First sample of the (resampled) demonstration in this segment.")
    end_index: int = Field(ge=0, description="One past the last sample in this segment.")
    t_start: Real = Field(description="Demonstration time of the first sample, s.")
    t_end: Real = Field(description="Demonstration time of the last sample, s.")
    start_reason: BoundaryReason | None = Field(
        None, description="What decided where this segment starts (see BoundaryReason).", examples=["force"]
    )
    end_reason: BoundaryReason | None = Field(
        None, description="What decided where this segment ends (see BoundaryReason).", examples=["surface"]
    )
    selection: list[float] = Field(
        min_length=6, max_length=6, description="Diagonal of S in CF, [x, y, z, rx, ry, rz]; 1 = motion, 0 = force."
    )
    compliant_frames: CompliantFrames | None = Field(None, description="Compliant frame(s); None for free segments.")
    position_dmp: DMPParameters = Field(
        description="Positions: CF x-y of the tool point for slide contact segments, world x-y-z otherwise."
    )
    orientation_dmp: DMPParameters = Field(description="Tool orientation in world (quaternion DMP).")
    force_dmp: DMPParameters | None = Field(
        None,
        description="Contour contact segments, and slide ones whose press was not steady (a ramp, a wobble): the "
        "CF-z force profile, N.",
    )
    force_constant_n: Real | None = Field(
        None, description="Slide contact segments whose press was steady: the constant CF-z force to apply, N."
    )
    quality: SegmentQuality
    force_band: ForceBand | None = Field(
        None,
        description="Contact segments of a skill learned from several demonstrations: the press they showed, mean "
        "and spread per phase (None: learned from one).",
    )
    motion_spread: MotionSpread | None = Field(
        None,
        description="Contact segments of a skill learned from several demonstrations: how far apart they moved the "
        "tool along the CF motion axes per phase (None: learned from one, or one left of several). A gain schedule "
        "reads it.",
    )


class SkillAttributes(BaseModel):
    """Static attributes of the skill implementation (paper Tables 1-2)."""

    segmentation_method: Name = Field("agglomerative-ward-time-knn", description="How the demonstration was segmented.")
    selection_matrix_cf: list[float] = Field(
        default_factory=lambda: list(SELECTION_CONTACT),
        description="Diagonal of S in CF for contact segments; 1 = motion, 0 = force.",
    )
    cf_constraint: Literal["plane", "force-direction"] = Field(
        description="slide: plane fitted to the motion; contour: z along the applied force per sample."
    )


class TypeEvidence(BaseModel):
    """Log-odds for contour (positive) against slide (negative) of each measure `auto` weighs (docs/LEARNING.md)."""

    turning: Real = Field(description="From the turning of the friction-free normal along a stroke.")
    tool_following: Real = Field(description="From the tool's rotation following that turning (>= 0).")
    planarity: Real = Field(
        description="From how far the contact leaves its best pressed plane (towards slide at most 1.5)."
    )


class AutoSelection(BaseModel):
    """The result of ``skill_type = auto``."""

    chosen: SkillType
    confidence: Real = Field(ge=0.5, le=1.0, description="Confidence of the choice, 0.5 (a guess) to 1.")
    mixed: bool = Field(
        False,
        description="The evidence is mixed (confidence below 0.75): the more likely type was chosen, and the skill's "
        "type_evidence check warns.",
    )
    turning_within_planes_deg: Real = Field(
        description="Largest turn of the normal within one slide segment, deg (planes: a few): the contact's geometry "
        "where it covers an area, the friction-free force where it does not."
    )
    tool_following: Real | None = Field(
        None, description="Largest share (0-1) of that turning the tool's own rotation followed (contours: 0.4-0.9)."
    )
    plane_rms_m: Real | None = Field(
        None, description="Largest planarity residual of the contact within one slide segment, m (planes: < 4 mm)."
    )
    evidence: TypeEvidence | None = Field(None, description="Each measure's log-odds for contour.")
    reason: Text = Field(description="One sentence: why this type.")


class CheckName(StrEnum):
    """The checks a learned skill carries (docs/LEARNING.md, "Every skill checks itself")."""

    force_along_cf = "force_along_cf"
    press_profile = "press_profile"
    cf_z_vs_force = "cf_z_vs_force"
    plane_conditioning = "plane_conditioning"
    plane_vs_force = "plane_vs_force"
    stroke_strength = "stroke_strength"
    force_outside_contact = "force_outside_contact"
    friction_along_motion = "friction_along_motion"
    press_direction = "press_direction"
    unmeasured_contact = "unmeasured_contact"
    sensor_offset = "sensor_offset"
    type_evidence = "type_evidence"
    demonstration_in_band = "demonstration_in_band"
    demonstration_normal = "demonstration_normal"


class CheckBound(StrEnum):
    """Which side of its limit a check's value must stay on (``skills.skill_checks.check_bound``)."""

    at_least = ">="
    at_most = "<="


class SkillCheck(BaseModel):
    """One check of a learned skill against what its demonstration measured: its value, its limit and the verdict."""

    model_config = ConfigDict(extra="forbid")

    name: CheckName
    segment: int | None = Field(None, description="The segment checked; None for the whole skill.")
    demonstration: int | None = Field(
        None, description="The demonstration checked against the joint skill (its index in ``demonstrations``)."
    )
    passed: bool
    value: Real = Field(description="The measured value, in ``unit``.")
    limit: Real = Field(description="The limit the value is held to, in ``unit`` (see ``message``: at most / least).")
    unit: Name = Field(examples=["deg", "N", "ratio", "mm"])
    message: Text = Field(description="One sentence with the numbers; a warning when not passed.")


class MisfitReason(StrEnum):
    """Why a demonstration does not fit the others of a joint skill (docs/LEARNING.md, section 11)."""

    not_learnable = "not_learnable"
    """It gives no skill on its own (no contact, no moving contact), or none of the type the others together are."""
    another_place = "another_place"
    """Its contact lies elsewhere than the others' (another part, or the same part moved)."""
    another_surface = "another_surface"
    """It presses along another direction than the others."""
    another_type = "another_type"
    """It is confidently the other type (slide against contour)."""
    another_stroke_count = "another_stroke_count"
    """It has another number of contact segments than the others."""


class MisfitPolicy(StrEnum):
    """What joint learning does with a demonstration that does not fit the others."""

    leave_out = "leave_out"
    """Learn from the others; the skill names it with its reason."""
    refuse = "refuse"
    """Refuse to learn (a 422 naming it and the reason)."""


class DemonstrationUse(BaseModel):
    """One demonstration of a skill learned from several: where it came from, its weight, and how it agrees."""

    model_config = ConfigDict(extra="forbid")

    index: WholeNumber = Field(description="Its position in the list learned from, from 0.")
    source: Name = Field(description="What it was given as: a stored demonstration's id, a file's name.")
    reference: bool = Field(
        False,
        description="The reference: the one that agrees best with the others, whose time base and samples the "
        "segments' indices refer to (the skill's ``demonstration``).",
    )
    name: Name | None = Field(None, description="Its recording's name (metadata).")
    weight: Real = Field(ge=0, le=1, description="Its weight in the joint estimates (0: left out).")
    misfit: MisfitReason | None = Field(None, description="Why it was left out (None: it was used).")
    reason: Text | None = Field(None, description="One sentence with the numbers, when it was left out.")
    skill_type: SkillType | None = Field(None, description="The type it gives on its own.")
    share_in_band: Real | None = Field(
        None,
        ge=0,
        le=1,
        description="Share of its contact samples whose press lies in the force band learned from the OTHERS "
        "(leave-one-out; a demonstration left out by the learner: the joint band). None: not aligned, or fewer "
        "than two others.",
    )
    normal_angle_deg: Real | None = Field(
        None,
        description="Median angle between its own CF z and the one learned from the OTHERS (leave-one-out), over its "
        "contact, deg.",
    )


class Skill(BaseModel):
    """A parameterized contact skill, ready to execute."""

    model_config = ConfigDict(extra="forbid")

    skill_type: SkillType
    attributes: SkillAttributes
    segments: list[Segment] = Field(min_length=1, max_length=MAX_SEGMENTS)
    auto_selection: AutoSelection | None = Field(None, description="Present when skill_type 'auto' was asked for.")
    checks: list[SkillCheck] = Field(
        default_factory=list,
        max_length=MAX_CHECKS,
        description="The skill's checks against what its demonstration measured; a failed one is a warning (strict "
        "learning refuses the skill).",
    )
    demonstration: DemonstrationSummary
    demonstrations: list[DemonstrationUse] | None = Field(
        None,
        max_length=MAX_JOINT_DEMONSTRATIONS,
        description="A skill learned from several demonstrations: each with its weight, the left-out ones with their "
        "reason (None: learned from one, ``demonstration``). ``demonstration`` and the segments' sample indices are "
        "then those of the reference demonstration, the one that agrees best with the others.",
    )
    sample_rate_hz: Real = Field(description="Rate of the (resampled) demonstration the skill was learned from, Hz.")
    taught_world: FreeForm | None = Field(
        None,
        description="The simulated world the demonstration was recorded in (simulator recordings carry it as "
        "metadata.extra['world']); executions run in it. None for real recordings: executions rebuild the work "
        "piece from the skill.",
    )

    def warnings(self) -> list[str]:
        """The messages of the checks that failed, in order (empty when every check passed)."""
        return [check.message for check in self.checks if not check.passed]


class LearnOptions(BaseModel):
    """Options of the learning pipeline (all have defaults that work for 100 Hz - 1 kHz demonstrations)."""

    model_config = ConfigDict(extra="forbid")

    skill_type: SkillTypeRequest = Field(SkillTypeRequest.auto, description="slide, contour or auto.")
    n_basis: WholeNumber = Field(50, ge=2, le=500, description="Fewest DMP basis functions per dimension and segment.")
    basis_per_second: Real = Field(
        15.0,
        ge=0,
        le=200,
        description="More basis functions for long segments: at least this many per second of segment "
        "(denser bases fit faster detail but make the rollout depend on its time step).",
    )
    max_basis: WholeNumber = Field(
        300, ge=2, le=MAX_BASIS, description="Most basis functions per dimension and segment."
    )
    max_fit_samples: WholeNumber = Field(
        10_000,
        ge=100,
        le=100_000,
        description="DMPs of longer segments are fitted on this many evenly strided samples "
        "(bases are >= 40 ms apart, so a finer grid adds cost, not information).",
    )
    contact_force_threshold_n: Real | None = Field(
        None,
        gt=0,
        le=1000,
        description="Force (N) a stroke presses with at least while sliding (its core); default: 40 % of the "
        "robust peak. Contact boundaries are then found from the surface and the touch level.",
    )
    min_segment_duration_s: Real = Field(0.25, gt=0, le=600, description="Segments shorter than this are merged, s.")
    contour_frames_max: WholeNumber = Field(
        500, ge=2, le=MAX_FRAMES, description="Most compliant frames stored per contour segment (decimated evenly)."
    )
    misfit: MisfitPolicy = Field(
        MisfitPolicy.leave_out,
        description="Learning from several demonstrations: leave out one that does not fit the others (named with "
        "its reason in the skill), or refuse to learn.",
    )
    strict: bool = Field(
        False,
        description="Refuse a skill that fails any of its checks (422 giving each failed check) instead of returning "
        "it with warnings.",
    )
