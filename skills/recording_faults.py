"""A recording's own faults, found by the skill learned from it (`schemas.skill.SkillCheck`, docs/LEARNING.md): the
checks of the recording itself (its wrench's sign and frame, its gaps, its sensor offset), not of what was learned
from it (`skills.skill_checks`); a work piece measured from the same recording carries what they find wrong
(``RECORDING_CHECKS``). The checks:

- ``friction_along_motion`` (skill) — the sign of the friction in the contact segments: the tool drags the surface
  along its motion, so the force it applies leans TOWARDS its sliding velocity. The median lean (the force along the
  motion over the force across it, signed) where the tool slides faster than ``skills.friction.FAST_SLIDING_M_S``
  (leaning at most ``FRICTION_CONE_MAX``: more is settling or a push) must not be below ``-FRICTION_SIGN_LIMIT``.
  Leaning against the motion, the wrench was recorded with the other sign (the sensor's reaction) or in another
  frame, and every CF z would point out of the surface. A rolling tool leans little either way; no sliding, no
  verdict (passed).
- ``press_direction`` (skill) — the direction the tool pressed in its contact segments (the mean of the stronger
  half of their forces): at most ``UPWARD_PRESS_LIMIT_DEG`` above the horizontal. Pressing on a table, a part or a
  wall points down or sideways; a wrench read with the other sign, in the other frame or turned with orientations in
  the wrong quaternion order often points up, and can still pass every other check (on the KU Leuven contours, a
  tool-frame wrench read as a world one learns a contour or a slide that does). Work done from below fails it too:
  a warning, not a refusal, unless strict.
- ``unmeasured_contact`` (skill) — the time the contact segments spend in gaps of the recording, where neither the pose
  nor the wrench was measured for longer than `skills.preprocess.GAP_FACTOR` times its usual interval (a tracker
  that lost the tool, a stalled logger; the import's ``unmeasured_intervals_s`` and the demonstration's own): any is
  a failure, for the skill follows an interpolation there, not the demonstration.
- ``sensor_offset`` (skill, recordings imported from a file) — the offset's uncertainty (the hand's slow wander
  the fit cannot tell apart, `skills.tare`) against the weakest contact's press: beyond ``OFFSET_SHARE_LIMIT``
  forces, and a straight stroke's tilt, are uncertain by more than the tolerance. A recording with no free space
  to fit it over fails (an offset or a tool's weight of unknown size stays in), never skipped; one the user gave
  the offset for (or declared compensated) passes as given.

Inputs are world-frame arrays (SI) of the uniformly sampled demonstration: forces (N, 3) N applied by the tool,
velocities (N, 3) m/s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import TareMethod
from schemas.skill import CheckName, SkillCheck
from skills.friction import friction_leans, sliding_fast
from skills.skill_checks import press_share

OFFSET_SHARE_LIMIT = 0.05
"""The sensor offset's uncertainty may be at most this fraction of the weakest contact's press (the force tolerance)."""

FRICTION_SIGN_LIMIT = 0.01
"""The contact's median lean to the motion may be at most this far AGAINST it (tan of the angle; 0.01 is 0.6°)."""

UPWARD_PRESS_LIMIT_DEG = 30.0
"""The force the tool applies in contact may point at most this far above the horizontal, deg (world z up)."""

RECORDING_CHECKS = frozenset(
    {CheckName.friction_along_motion, CheckName.press_direction, CheckName.unmeasured_contact, CheckName.sensor_offset}
)
"""The checks of the recording itself (its wrench's sign and frame, its sensor offset), not of what was learned from
it: a work piece measured from the same recording carries what they find wrong."""


def median_friction_lean(forces: NDArray[np.float64], velocities: NDArray[np.float64]) -> tuple[float, int]:
    """Return the median lean of ``forces`` (N, 3) N towards the motion (``velocities`` (N, 3) m/s; tan of the angle,
    positive TOWARDS it, `skills.friction.friction_leans`) where friction's lean is measured
    (`skills.friction.sliding_fast`: fast sliding, leaning within the friction cone either way; more moves the tool
    along its press: settling, a push), and the number of those samples (0: no verdict, the lean is 0)."""
    leans = friction_leans(forces, velocities)
    sliding = sliding_fast(leans, np.linalg.norm(velocities, axis=1))
    return (float(np.median(leans[sliding])) if sliding.any() else 0.0), int(sliding.sum())


def leans_with_friction(lean: float) -> bool:
    """Whether a median lean (`median_friction_lean`) is friction's as the tool applies it: not against the motion by
    more than ``FRICTION_SIGN_LIMIT``."""
    return lean >= -FRICTION_SIGN_LIMIT


def lean_sentence(lean: float, samples: int) -> str:
    """``the applied force leans 1.3 deg towards the tool's motion (median over 969 sliding contact samples)``."""
    if samples == 0:
        return "no contact sample slides: the friction's sign is not judged"
    side = "towards" if lean >= 0 else "against"
    return (
        f"the applied force leans {abs(np.degrees(np.arctan(lean))):.1f} deg {side} the tool's motion (median over "
        f"{samples} sliding contact samples)"
    )


def friction_along_motion(
    forces: NDArray[np.float64], velocities: NDArray[np.float64], geometry_decides: bool = False
) -> SkillCheck:
    """Check that the force the tool applies in contact leans towards its motion, as friction makes it: ``forces``
    (N, 3) N and ``velocities`` (N, 3) m/s, the samples of every contact segment (`median_friction_lean`).

    The message names the likely cause by what the other sign would do: where the force presses down or sideways
    (`press_elevation_deg` below the horizontal), the other sign would press UP, so the sign is not it — something
    else drags against the motion in the wrench (an arm's joint friction in a wrench estimated from joint torques, a
    hand on the arm). Such a drag matters where the force's direction decides a normal; where the contact geometry
    decided every one (``geometry_decides``: every contact covers an area of its surface) it is reported, not failed.
    """
    lean, samples = median_friction_lean(forces, velocities)
    passed = leans_with_friction(lean)
    message = lean_sentence(lean, samples)
    pressing_up = press_elevation_deg(forces) > 0.0
    if not passed and not pressing_up and geometry_decides:
        passed = True
        message += (
            ": something in the wrench drags against the motion (an arm's joint friction in a wrench estimated from "
            "joint torques, a hand on the arm), not the sign (the tool presses down); the contact's geometry decided "
            "every normal, so the force's direction decides none"
        )
    elif not passed and pressing_up:
        message += (
            ": friction drags the surface ALONG the motion, so the wrench looks recorded with the other sign (what "
            "the sensor measures on the tool, not what the tool applies) or in another frame, and CF z points out of "
            "the surface"
        )
    elif not passed:
        message += (
            ": friction drags the surface ALONG the motion, so something else in the wrench pulls against it (an "
            "arm's joint friction in a wrench estimated from joint torques, a hand on the arm); the tool presses "
            "down, so the other sign is not the cause — the force's direction is suspect wherever it alone decides "
            "a normal"
        )
    return SkillCheck(
        name=CheckName.friction_along_motion,
        segment=None,
        passed=passed,
        value=lean,
        limit=-FRICTION_SIGN_LIMIT,
        unit="ratio",
        message=message,
    )


def press_elevation_deg(forces: NDArray[np.float64]) -> float:
    """Return how far above the world's horizontal (deg, + up, world z up) the tool pressed: the direction of the mean
    of the stronger half of ``forces`` (N, 3) N (applied by the tool, world), where the press is (a recording's
    free-space samples and a contact's light touches are the weaker half); 0 when they sum to nothing."""
    magnitude = np.linalg.norm(forces, axis=1)
    mean = forces[magnitude >= np.median(magnitude)].mean(axis=0)
    norm = float(np.linalg.norm(mean))
    return float(np.degrees(np.arcsin(np.clip(mean[2] / norm, -1.0, 1.0)))) if norm > 0 else 0.0


def press_direction(forces: NDArray[np.float64]) -> SkillCheck:
    """Check that the tool pressed down or sideways in its contact segments (``forces`` (N, 3) N, world, applied by the
    tool, their samples): at most ``UPWARD_PRESS_LIMIT_DEG`` above the horizontal (`press_elevation_deg`)."""
    elevation = press_elevation_deg(forces)
    passed = elevation <= UPWARD_PRESS_LIMIT_DEG
    side = "above" if elevation >= 0 else "below"
    message = f"the tool pressed {abs(elevation):.0f} deg {side} the horizontal in its contact"
    if not passed:
        message += (
            f" (more than {UPWARD_PRESS_LIMIT_DEG:.0f} deg up): pressing on a table, a part or a wall points down or "
            "sideways, so unless the tool worked from below, the wrench was read with the other sign, in the other "
            "frame or with the quaternions in the other order (the import notes say which reading presses down)"
        )
    return SkillCheck(
        name=CheckName.press_direction,
        segment=None,
        passed=passed,
        value=elevation,
        limit=UPWARD_PRESS_LIMIT_DEG,
        unit="deg",
        message=message,
    )


def unmeasured_contact(contact_spans: list[tuple[float, float]], unmeasured: NDArray[np.float64]) -> SkillCheck:
    """Check the contact segments (``contact_spans``: their start and end, s) against the recording's gaps
    (``unmeasured`` (K, 2) start and end, s, disjoint): the seconds of contact no measurement covers, at most 0."""
    spans = np.asarray(contact_spans, dtype=float).reshape(-1, 1, 2)
    overlap = np.minimum(spans[..., 1], unmeasured[:, 1]) - np.maximum(spans[..., 0], unmeasured[:, 0])  # (S, K)
    inside = np.clip(overlap, 0.0, None)
    total = float(inside.sum())
    passed = total <= 0.0
    if passed:
        message = f"every contact segment was measured throughout ({unmeasured.shape[0]} gap(s) in the recording)"
    else:
        hit = unmeasured[(inside > 0).any(axis=0)]
        where = ", ".join(f"{a:.6g}-{b:.6g} s" for a, b in hit[:5])
        message = (
            f"the contact segments spend {total:.2f} s in {hit.shape[0]} gap(s) of the recording ({where}) where the "
            "pose or the wrench went unmeasured: the skill follows an interpolation there, not the demonstration "
            "(record again, or cut the recording at the gap)"
        )
    return SkillCheck(
        name=CheckName.unmeasured_contact,
        segment=None,
        passed=passed,
        value=total,
        limit=0.0,
        unit="s",
        message=message,
    )


def sensor_offset(method: TareMethod, uncertainty_n: float | None, weakest_press_n: float) -> SkillCheck:
    """Check how well the import knew the sensor's offset (``method``, `skills.tare`; ``uncertainty_n`` N where it
    fitted one) against the weakest contact's press (N). A recording with no free space to fit it over fails: an
    offset or a tool's weight of unknown size may be in every force (never skipped)."""
    if method is TareMethod.impossible:
        # Unknown: as large as the press, for all the recording tells (JSON holds no infinity).
        passed, share = False, 1.0
        message = (
            "the recording has no free space to fit the sensor's offset over: an offset or an uncompensated tool "
            "weight of unknown size may be in every force, and in a straight stroke's tilt (record a rest in the air "
            "before and after the strokes, in a few orientations; or import with --no-tare if the file is already "
            "compensated, --force-offset if the offset is known)"
        )
    elif uncertainty_n is None:
        passed, share = True, 0.0
        taken = "compensated as the file came (--no-tare)" if method is TareMethod.off else "as given"
        message = f"the sensor offset is taken {taken}, not estimated"
    else:
        share = press_share(uncertainty_n, weakest_press_n)
        passed = share <= OFFSET_SHARE_LIMIT
        message = (
            f"the sensor offset removed on import is known to ±{uncertainty_n:.2f} N, {100 * share:.1f} % of the "
            "weakest contact's press"
        )
        if not passed:
            message += (
                f": learned forces may be off by as much, and the tilt of a straight stroke's CF z (which only the "
                f"force decides) by {float(np.degrees(np.arctan(share))):.1f} deg; a longer free-space rest before "
                "and after the strokes (or --tare-window) pins the offset down"
            )
    return SkillCheck(
        name=CheckName.sensor_offset,
        segment=None,
        passed=passed,
        value=share,
        limit=OFFSET_SHARE_LIMIT,
        unit="ratio",
        message=message,
    )
