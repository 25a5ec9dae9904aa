"""A learned skill checks itself against what its demonstration MEASURED, so that it is never confidently wrong.

Each check has a value, a limit and a verdict (`schemas.skill.SkillCheck`); a failed check is a
warning on every interface, and strict learning refuses the skill. The checks (docs/LEARNING.md):

- ``force_along_cf`` (per contact segment) — the force the skill will press with along its CF z,
  against the force the tool really pressed with (the friction-free force's magnitude), over the
  segment's plateau (`skills.force_profile.plateau_mask`): their ratio within
  ``FORCE_RATIO_LIMITS``. A CF z 90° off learns ~0 N where 10 N were pressed: this check catches it.
- ``press_profile`` (per contact segment) — the force the skill will press with over time against the press the
  demonstration measured along the same CF z, sample by sample over the body of the segment (its ramps left out,
  `skills.force_profile.press_body`): their RMS difference over the mean press at most ``PRESS_PROFILE_LIMIT``. A
  constant learned for a press that ramped or wobbled fails it.
- ``cf_z_vs_force`` (per contact segment) — the angle between CF z and the friction-free force
  direction: a slide's against the segment's mean (a hand leans: ``PLANE_FORCE_TOLERANCE_DEG``), a
  contour's per sample over ``CHECK_SMOOTHING_S``, its 95th percentile (``CONTOUR_FORCE_ANGLE_LIMIT_DEG``).
- ``plane_conditioning`` (slide contact segments) — the path's width across its main direction (its surface's,
  where strokes side by side are pooled): a plane that wide decides CF z's tilt. A narrower path (a straight
  stroke) leaves the tilt about it to the force, and only one independent thing sees that tilt: the tool's axis
  (the pose), which a hand holds about square to what it presses on. Where the two disagree about the line by more
  than ``TOOL_AXIS_AGREEMENT_DEG`` (a side force fixed in the tool, a disc grinder's cut, tilts the force 14-19°),
  it fails, saying how exposed the tilt is; where the tool never slid, nothing confirms the mean force.
- ``plane_vs_force`` (slide contact segments) — the angle between the plane the path spans and the
  friction-free force: beyond ``PLANE_FORCE_TOLERANCE_DEG`` the path was drawn on something else.
- ``stroke_strength`` (per contact segment) — its press against the strongest segment's: below
  ``skills.segmentation.BRUSH_FRACTION`` it may be a brush rather than a stroke (brief ones are
  already free).
- ``force_outside_contact`` (skill) — the largest press held in a free segment without moving
  along it (a stroke the contact analysis missed), against the weakest contact segment's press.
- ``type_evidence`` (skill) — the probability of the chosen type from `skills.selection`'s
  evidence: at least ``MIXED_CONFIDENCE`` for `auto`; a forced type fails only where the evidence
  is clearly against it.

The checks of the recording itself (``friction_along_motion``, ``press_direction``, ``unmeasured_contact``,
``sensor_offset``) are `skills.recording_faults`.

Inputs are world-frame arrays (SI) of the uniformly sampled demonstration: forces (N, 3) N applied
by the tool, velocities (N, 3) m/s, CF z axes (N, 3) unit, and a segment's friction-free forces.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from schemas.skill import IN_BAND_SHARE, CheckBound, CheckName, SkillCheck, SkillType
from skills.compliant_frames import PLANE_FORCE_TOLERANCE_DEG, PlaneFit
from skills.contact import mask_runs
from skills.force_profile import plateau_mask, press_body
from skills.friction import FrictionFree, unit_rows
from skills.pressed_normals import angles_deg
from skills.segmentation import BRUSH_FRACTION
from skills.selection import MIXED_CONFIDENCE, SkillClassification

FORCE_RATIO_LIMITS = (0.9, 1.1)
"""The learned force along CF z may be this fraction of the pressed force (0.9 = cos 26°; the plateau's swings)."""

PRESS_PROFILE_LIMIT = 0.25
"""Largest RMS difference between the learned and the measured press over the body of a segment, over the mean press
(a hand's slow ±20 % swing about a constant leaves 0.14; a constant for a 2 -> 20 N ramp 0.4)."""

CONTOUR_FORCE_ANGLE_LIMIT_DEG = 5.0
"""Largest 95th percentile of a contour CF z's angle to the friction-free force, deg (its noise and tremor)."""

CHECK_SMOOTHING_S = 0.05
"""The friction-free force a contour CF z is compared with is smoothed over this (s): sensor noise, not the CF."""

TRUSTED_WEIGHT = 0.5
"""Samples whose friction-free direction has at least this weight (`skills.friction`) are compared with CF z."""

HELD_PRESS_S = 0.2
"""A press outside contact counts when held this long, s."""

HELD_PRESS_SPEED_M_S = 0.02
"""...while the tool moves along the force slower than this, m/s (a hand pushing the arm moves it)."""

OUTSIDE_PRESS_FRACTION = 0.5
"""A press held outside contact above this fraction of the weakest contact segment's is a missed stroke."""

TOOL_AXIS_AGREEMENT_DEG = 10.0
"""Where a straight stroke leaves CF z's tilt about it to the force, the tool's axis (from the pose, not the wrench)
must lie within this (deg) of it about the line: a hand holds a tool about square to what it presses on, a hand's
lean tilts the force by up to ~5°, a powered tool's side force fixed in the tool by 14-19°."""


AGAINST_EVIDENCE = 1.0 - MIXED_CONFIDENCE
"""A type forced against evidence that gives it less than this probability fails ``type_evidence``."""


def press_share(force_n: float, press_n: float) -> float:
    """Return ``force_n`` (N) as a share of the press ``press_n`` (N), a press of 0 N counted as 1e-9 N (so a
    recording that never pressed gives a large share, not a division by zero)."""
    return force_n / max(press_n, 1e-9)


def reference_directions(free: FrictionFree, rate_hz: float) -> NDArray[np.float64]:
    """Return the unit directions (M, 3) a contour's CF z is held to: the friction-free forces of a segment sampled
    at ``rate_hz``, smoothed over ``CHECK_SMOOTHING_S`` (their noise, not the CF's)."""
    return unit_rows(gaussian_filter1d(free.forces, CHECK_SMOOTHING_S * rate_hz, axis=0, mode="nearest"))


def force_along_cf(index: int, free: FrictionFree, learned_force_n: NDArray[np.float64]) -> SkillCheck:
    """Check the learned force (N,) N along CF z against the friction-free press (`skills.friction`) of one contact
    segment."""
    press = np.linalg.norm(free.forces, axis=1)
    plateau = plateau_mask(press)
    measured, learned = float(np.median(press[plateau])), float(np.median(learned_force_n[plateau]))
    ratio = press_share(learned, measured)
    low, high = FORCE_RATIO_LIMITS
    passed = low <= ratio <= high
    verdict = "" if passed else f" (allowed {100 * low:.0f}-{100 * high:.0f} %): CF z is not along the press"
    return SkillCheck(
        name=CheckName.force_along_cf,
        segment=index,
        passed=passed,
        value=ratio,
        limit=low if ratio < 1 else high,
        unit="ratio",
        message=f"segment {index} presses {learned:.2f} N along its CF z where the tool pressed {measured:.2f} N "
        f"({100 * ratio:.0f} %){verdict}",
    )


def press_profile(index: int, measured_n: NDArray[np.float64], learned_n: NDArray[np.float64]) -> SkillCheck:
    """Check the learned force (M,) N against the measured press along CF z (M,) N of one contact segment, over its
    body (`skills.force_profile.press_body`)."""
    body = press_body(measured_n)
    measured, learned = measured_n[body], learned_n[body]
    mean = max(float(np.mean(measured)), 1e-9)
    share = float(np.sqrt(np.mean((learned - measured) ** 2))) / mean
    passed = share <= PRESS_PROFILE_LIMIT
    message = (
        f"segment {index}: the learned force follows the measured press within {100 * share:.0f} % RMS of its mean "
        f"({mean:.1f} N)"
    )
    if not passed:
        message += (
            f", more than {100 * PRESS_PROFILE_LIMIT:.0f} %: the press was not what the skill will press (a ramp or a "
            "wobble learned as one value?)"
        )
    return SkillCheck(
        name=CheckName.press_profile,
        segment=index,
        passed=passed,
        value=share,
        limit=PRESS_PROFILE_LIMIT,
        unit="ratio",
        message=message,
    )


def cf_z_vs_force(
    index: int,
    free: FrictionFree,
    cf_z: NDArray[np.float64],
    skill_type: SkillType,
    rate_hz: float,
    slide_limit_deg: float = PLANE_FORCE_TOLERANCE_DEG,
) -> SkillCheck:
    """Check CF z (M, 3) against the friction-free force (`skills.friction`) of one contact segment sampled at
    ``rate_hz`` (see the module docstring); a slide's CF z may be ``slide_limit_deg`` from the mean force (its
    plane's limit: the friction cone where its contact covers an area, `skills.compliant_frames.slide_frame`)."""
    press = np.linalg.norm(free.forces, axis=1)
    trusted = (free.weights >= TRUSTED_WEIGHT) & plateau_mask(press)
    if trusted.sum() < 2:
        trusted = plateau_mask(press)
    if skill_type is SkillType.slide:
        mean_direction = unit_rows(free.forces[trusted].mean(axis=0))
        value, limit = float(angles_deg(cf_z[0], mean_direction)), slide_limit_deg
        what = "the mean friction-free force"
    else:
        reference = reference_directions(free, rate_hz)
        value = float(np.percentile(angles_deg(cf_z[trusted], reference[trusted]), 95))
        limit = CONTOUR_FORCE_ANGLE_LIMIT_DEG
        what = f"the friction-free force over {1000 * CHECK_SMOOTHING_S:.0f} ms (95th percentile over the samples)"
    passed = value <= limit
    return SkillCheck(
        name=CheckName.cf_z_vs_force,
        segment=index,
        passed=passed,
        value=value,
        limit=limit,
        unit="deg",
        message=f"segment {index}: CF z is {value:.1f} deg from {what}"
        + ("" if passed else f", more than the {limit:.0f} deg a hand's lean or noise explains"),
    )


def tilt_about_line_deg(cf_z: NDArray[np.float64], direction: NDArray[np.float64], axis: NDArray[np.float64]) -> float:
    """Return the angle (deg) between unit ``cf_z`` (3,) and ``axis`` (3,) about the line along unit ``direction`` (3,):
    both projected on the plane across the line (``axis`` signed towards ``cf_z``)."""
    across_z = unit_rows(cf_z - np.dot(cf_z, direction) * direction)
    across_axis = unit_rows(axis - np.dot(axis, direction) * direction)
    across_axis = across_axis if np.dot(across_axis, across_z) >= 0 else -across_axis
    return float(angles_deg(across_z, across_axis))


def plane_checks(index: int, plane: PlaneFit, tool_axis: NDArray[np.float64]) -> list[SkillCheck]:
    """Return the ``plane_conditioning`` and ``plane_vs_force`` checks of one slide contact segment; ``tool_axis``
    (3,) unit, the segment's mean tool z axis in the world (the pose's, independent of the wrench)."""
    width_mm = 1000.0 * plane.across_width_m
    if plane.across_width_m >= plane.equal_width_m:
        conditioning = f"the path spans {width_mm:.1f} mm across its main direction: the plane decides CF z's tilt"
        conditioned = True
    elif plane.force_samples > 0:
        cf_z, line = plane.rotation[:, 2], plane.rotation[:, 0]
        held = tilt_about_line_deg(cf_z, line, tool_axis)
        conditioned = held <= TOOL_AXIS_AGREEMENT_DEG
        conditioning = (
            f"the path is a line ({width_mm:.2f} mm across its main direction): CF z's tilt about it is the "
            f"friction-free force's ({plane.force_samples} sliding samples), and the tool's axis, held "
            f"{held:.1f} deg from it about the line, "
        )
        if conditioned:
            conditioning += "agrees (a hand holds a tool about square to what it presses on)"
        else:
            conditioning += (
                f"does not (more than {TOOL_AXIS_AGREEMENT_DEG:.0f} deg): nothing else sees that tilt, and a side "
                "force fixed in the tool (a grinder's cut) or a hand's steady lean tilts it unseen, by as much as it "
                "leans; wipe across the line as well (or along a second line on the same surface) to let the surface "
                "decide"
            )
    else:
        conditioning = (
            f"the path is a line ({width_mm:.2f} mm across its main direction) and the tool never slid: CF z is the "
            "mean force's direction, which nothing confirms"
        )
        conditioned = False
    checks = [
        SkillCheck(
            name=CheckName.plane_conditioning,
            segment=index,
            passed=conditioned,
            value=width_mm,
            limit=1000.0 * plane.equal_width_m,
            unit="mm",
            message=f"segment {index}: {conditioning}",
        )
    ]
    angle, limit = plane.plane_force_angle_deg, plane.plane_force_limit_deg
    passed = angle is None or angle <= limit
    if angle is None:
        message = f"segment {index}: the path spans no plane to compare with the force"
    elif passed:
        message = f"segment {index}: the path's plane is {angle:.1f} deg from the friction-free force"
    else:
        message = (
            f"segment {index}: the path lies in a plane {angle:.0f} deg from the force pressing on it (more than "
            f"{limit:.0f} deg): it was drawn on something else, e.g. a curved edge; CF z follows the force"
        )
    checks.append(
        SkillCheck(
            name=CheckName.plane_vs_force,
            segment=index,
            passed=passed,
            value=0.0 if angle is None else angle,
            limit=limit,
            unit="deg",
            message=message,
        )
    )
    return checks


def stroke_strength(presses_n: dict[int, float]) -> list[SkillCheck]:
    """Check each contact segment's press (90th percentile, N, by segment index) against the strongest one's."""
    strongest = max(presses_n.values())
    checks = []
    for index, press in presses_n.items():
        share = press_share(press, strongest)
        passed = share >= BRUSH_FRACTION
        checks.append(
            SkillCheck(
                name=CheckName.stroke_strength,
                segment=index,
                passed=passed,
                value=share,
                limit=BRUSH_FRACTION,
                unit="ratio",
                message=f"segment {index} presses {press:.1f} N, {100 * share:.0f} % of the strongest "
                f"({strongest:.1f} N)" + ("" if passed else ": a brush, not a stroke?"),
            )
        )
    return checks


def force_outside_contact(
    forces: NDArray[np.float64],
    velocities: NDArray[np.float64],
    free: NDArray[np.bool_],
    weakest_press_n: float,
    rate_hz: float,
) -> SkillCheck:
    """Check the largest press held in free segments (``free`` (N,) mask) against the weakest contact's press (N)."""
    magnitude = np.linalg.norm(forces, axis=1)
    along_force = np.abs(np.sum(velocities * unit_rows(forces), axis=1))
    held = free & (along_force < HELD_PRESS_SPEED_M_S)
    longest = max(1, round(HELD_PRESS_S * rate_hz))
    worst = 0.0
    for a, b in mask_runs(held):
        if b - a >= longest:
            # The press sustained over the run: its level exceeded for HELD_PRESS_S at least.
            sustained = np.sort(magnitude[a:b])[-longest]
            worst = max(worst, float(sustained))
    share = press_share(worst, weakest_press_n)
    passed = share <= OUTSIDE_PRESS_FRACTION
    return SkillCheck(
        name=CheckName.force_outside_contact,
        segment=None,
        passed=passed,
        value=share,
        limit=OUTSIDE_PRESS_FRACTION,
        unit="ratio",
        message=f"free segments hold at most {worst:.1f} N for {HELD_PRESS_S:.1f} s without moving along it, "
        f"{100 * share:.0f} % of the weakest contact's press"
        + ("" if passed else ": a stroke the contact analysis missed?"),
    )


_AT_LEAST = frozenset({CheckName.plane_conditioning, CheckName.stroke_strength, CheckName.friction_along_motion,
                       CheckName.type_evidence, CheckName.demonstration_in_band})  # fmt: skip
"""The checks whose value must reach their limit (the others must not pass theirs; ``force_along_cf`` either way)."""


def check_bound(check: SkillCheck) -> CheckBound:
    """The side of its limit ``check``'s value must stay on, as its function above decides it: a ratio of the force
    along CF z below 1 is held to the lower limit, above 1 to the upper (``force_along_cf`` reports the nearer)."""
    if check.name is CheckName.force_along_cf:
        return CheckBound.at_least if check.value < 1.0 else CheckBound.at_most
    return CheckBound.at_least if check.name in _AT_LEAST else CheckBound.at_most


def type_evidence(classification: SkillClassification | None, chosen: SkillType, auto: bool) -> SkillCheck:
    """Check the chosen type against `skills.selection`'s evidence (None: it could not be measured)."""
    if classification is None:
        return SkillCheck(
            name=CheckName.type_evidence,
            segment=None,
            passed=True,
            value=0.5,
            limit=AGAINST_EVIDENCE,
            unit="probability",
            message=f"{chosen.value} was asked for; the tool never slid long enough to weigh slide against contour",
        )
    p_contour = float(1.0 / (1.0 + np.exp(-classification.log_odds.sum())))
    p_chosen = p_contour if chosen is SkillType.contour else 1.0 - p_contour
    limit = MIXED_CONFIDENCE if auto else AGAINST_EVIDENCE
    passed = p_chosen >= limit
    evidence_says = "contour" if p_contour >= 0.5 else "slide"
    if auto:
        message = f"auto chose {chosen.value} at {100 * p_chosen:.0f} %: {classification.reason}"
    elif passed:
        message = f"{chosen.value} was asked for; the evidence gives it {100 * p_chosen:.0f} %"
    else:
        message = (
            f"{chosen.value} was asked for, but the evidence says {evidence_says} ({100 * (1 - p_chosen):.0f} %): "
            f"{classification.reason}"
        )
    return SkillCheck(
        name=CheckName.type_evidence,
        segment=None,
        passed=passed,
        value=p_chosen,
        limit=limit,
        unit="probability",
        message=message,
    )


def demonstration_in_band(index: int, source: str, share: float) -> SkillCheck:
    """Check demonstration ``index`` (given as ``source``) against the force band the OTHER demonstrations give
    (leave-one-out: a band it is part of would be widened to hold it): ``share`` (0-1) of its contact samples press
    within it (`skills.force_band.share_in_band`)."""
    passed = share >= IN_BAND_SHARE
    verdict = "within" if passed else "outside"
    return SkillCheck(
        name=CheckName.demonstration_in_band,
        demonstration=index,
        passed=passed,
        value=share,
        limit=IN_BAND_SHARE,
        unit="ratio",
        message=f"demonstration {index} ({source}) presses within the others' force band for "
        f"{100 * share:.0f} % of its contact (at least {100 * IN_BAND_SHARE:.0f} %): {verdict} what the "
        "other demonstrations together showed",
    )


def demonstration_normal(index: int, source: str, angle_deg: float) -> SkillCheck:
    """Check demonstration ``index``'s own CF z against the one the OTHER demonstrations give (leave-one-out): the
    median angle (deg) over its contact may be at most a hand's lean (`PLANE_FORCE_TOLERANCE_DEG`)."""
    passed = angle_deg <= PLANE_FORCE_TOLERANCE_DEG
    return SkillCheck(
        name=CheckName.demonstration_normal,
        demonstration=index,
        passed=passed,
        value=angle_deg,
        limit=PLANE_FORCE_TOLERANCE_DEG,
        unit="deg",
        message=f"demonstration {index} ({source}) alone gives a CF z {angle_deg:.1f} deg from the others' joint one "
        f"(median over its contact; at most {PLANE_FORCE_TOLERANCE_DEG:.0f} deg, a hand's lean)"
        + ("" if passed else ": it pressed on something else, or its hand leaned more than the others'"),
    )
