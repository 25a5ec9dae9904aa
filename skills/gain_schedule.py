"""A gain schedule from several demonstrations (docs/LEARNING.md, section 11, step 4; docs/EXECUTION.md, "A gain
schedule from the demonstrations' spread"): where the trials moved the tool to the same place the skill holds its path
stiffly, where they varied it is compliant (Calinon's task-parameterized models: stiffness ~ 1 / variance).

`motion_spread` keeps, per phase of a contact segment, the spread of the aligned trials' tool-point positions along
the CF motion axes (x, y); `stiffness_schedule` turns it into the CF translational stiffness per control step between
`STIFFNESS_FLOOR` times the configured one and the configured one. CF z (the force axis) and the rotations keep the
configured stiffness. World frame, SI units.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from schemas.execution import ControllerGains, GainSchedule
from schemas.skill import MotionSpread, Segment, SegmentKind, Skill
from skills.force_band import BAND_POOLING_POINTS

STIFFNESS_FLOOR = 0.25
"""The scheduled CF x-y stiffness never falls below this share of the configured one (where the trials varied
most): a quarter keeps the tool on its path against friction (3000 N/m -> 750 N/m, 1.3 mm for a 1 N drag)."""

SPREAD_RESOLUTION_M = 0.0005
"""Spreads below this (m) count as agreement: the aligned positions' own noise (a hand's tremor, the warping's
sampling) is about this much, so a smaller spread says nothing more about where the trials agree."""


def motion_spread(aligned_positions: Sequence[NDArray[np.float64]], rotations: NDArray[np.float64]) -> MotionSpread:
    """The spread of the demonstrations' tool-point positions ``aligned_positions`` (each (G, 3), m, world, on the
    reference's G alignment points) along the CF x and y axes of ``rotations`` (G, 3, 3) or (3, 3), world from CF:
    at each phase their standard deviation about their mean (n - 1 in the denominator), the variance pooled over
    the nearby phases as the force band's (`skills.force_band.BAND_POOLING_POINTS`)."""
    positions = np.asarray(aligned_positions, dtype=float)
    deviations = positions - positions.mean(axis=0)
    axes = np.broadcast_to(np.asarray(rotations, dtype=float)[..., :, :2], (positions.shape[1], 3, 2))
    along = np.einsum("tgi,gij->tgj", deviations, axes)  # (T, G, 2): along CF x and CF y
    variance = along.var(axis=0, ddof=1)
    spread = np.sqrt(gaussian_filter1d(variance, BAND_POOLING_POINTS, axis=0, mode="nearest"))
    return MotionSpread(
        phase=np.linspace(0.0, 1.0, len(spread)).tolist(),
        spread_m=spread.tolist(),
        demonstrations=len(positions),
    )


def stiffness_schedule(
    spread: MotionSpread, stiffness_n_per_m: Sequence[float], fractions: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The CF translational stiffness (M, 3), N/m, at the segment's time ``fractions`` (M,) (0-1) from its motion
    ``spread`` and the configured ``stiffness_n_per_m`` (3,) (CF x, y, z).

    On CF x and y: ``k = K σ_min² / σ²`` (``σ`` the spread with `SPREAD_RESOLUTION_M` added in quadrature, ``σ_min``
    its least over the segment and both axes), clipped to ``[STIFFNESS_FLOOR K, K]``: the configured stiffness where
    the trials agreed best, less where they varied. CF z keeps ``K_z``."""
    phase = np.asarray(spread.phase, dtype=float)
    sigma_sq = np.square(np.asarray(spread.spread_m, dtype=float)) + SPREAD_RESOLUTION_M**2  # (G, 2)
    ratio = sigma_sq.min() / sigma_sq
    at = np.column_stack([np.interp(np.clip(fractions, 0.0, 1.0), phase, ratio[:, i]) for i in range(2)])
    k = np.asarray(stiffness_n_per_m, dtype=float)
    schedule = np.empty((len(fractions), 3))
    schedule[:, :2] = k[:2] * np.clip(at, STIFFNESS_FLOOR, 1.0)
    schedule[:, 2] = k[2]
    return schedule


def missing_spread(skill: Skill) -> str | None:
    """Why ``skill`` cannot run with ``gain_schedule`` from_spread (a contact segment without a motion spread: a
    skill learned from one demonstration), naming the field; None when every contact segment has one."""
    missing = [s.index for s in skill.segments if s.kind is SegmentKind.contact and s.motion_spread is None]
    return _no_spread(missing) if missing else None


def _no_spread(segments: list[int]) -> str:
    """The one message for contact ``segments`` (indices) a from_spread schedule cannot run on, naming the field."""
    return (
        f"gains.gain_schedule: from_spread needs the spread of several demonstrations, and contact segment(s) "
        f"{', '.join(map(str, segments))} of the skill have none (a skill learned from one demonstration): learn it "
        "from several, or use constant"
    )


def scheduled_stiffness(
    segment: Segment, gains: ControllerGains, fractions: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """The CF stiffness diagonal (M, 6) (N/m, N·m/rad) of contact ``segment`` at its time ``fractions`` (M,) as
    ``gains.gain_schedule`` says: None for constant (the gains' own), else `stiffness_schedule` on CF x-y with the
    configured CF z and rotational stiffness. Raises ValueError (`missing_spread`) for a segment without a spread."""
    if gains.gain_schedule is GainSchedule.constant:
        return None
    if segment.motion_spread is None:
        raise ValueError(_no_spread([segment.index]))
    translational = stiffness_schedule(segment.motion_spread, gains.translational_stiffness_n_per_m, fractions)
    rotational = np.broadcast_to(np.asarray(gains.rotational_stiffness_nm_per_rad, dtype=float), translational.shape)
    return np.column_stack([translational, rotational])
