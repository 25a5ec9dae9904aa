"""The force band: where a new demonstration of a task is expected to press, phase by phase along a contact segment,
from the demonstrations shown (docs/LEARNING.md, section 11, step 3), and a run (a demonstration, an execution)
aligned to it (`band_alignment`, `share_in_band`). World frame, SI units."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d
from scipy.special import stdtrit

from schemas.skill import ForceBand
from skills.joint_alignment import RUN_POINTS, alignment_features, resampled, warping_path
from skills.parameterize import LearnedTrial

BAND_SIGMAS = 3.0
"""The force band is the mean press plus or minus this many standard deviations (across and within)."""

BAND_POOLING_POINTS = 5.0
"""The across-trial variance is pooled over the nearby phases by a Gaussian of this many alignment points (5 % of the
segment): its degrees of freedom are (n - 1) times the pooled points, sqrt(2 pi) times this."""

BAND_CONFIDENCE = 0.95
"""The force band is the prediction interval, at this confidence, of a new demonstration's press."""


def offset_uncertainty_n(learned: Sequence[LearnedTrial]) -> float | None:
    """The 95 % uncertainty (N) of the mean of the demonstrations' forces from their sensor offsets, each tared on
    its own (independent): the root of their squares' sum over their count; None where any has none."""
    each = [t.demonstration.metadata.force_offset_uncertainty_n for t in learned]
    if any(u is None for u in each):
        return None
    return float(np.sqrt(np.sum(np.square(each)))) / len(each)


def band_and_mean_press(
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
    # Student t quantile (what scipy.stats.t.ppf returns, without importing scipy.stats: half a second of
    # every worker and API start)
    t_quantile = float(stdtrit(pooled_df, 0.5 + 0.5 * BAND_CONFIDENCE)) if n > 1 else 0.0
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


def band_alignment(
    band: ForceBand, positions: NDArray[np.float64], press: NDArray[np.float64]
) -> tuple[NDArray[np.bool_], NDArray[np.int_]]:
    """Align a run's contact segment to ``band``: its path ``positions`` (M, 3) m and press ``press`` (M,) N are
    resampled to `RUN_POINTS` points evenly in time and warped onto the band's points. Return, per resampled point,
    whether its press lies within the band where it is matched, and the band point (phase index) it is matched to
    (the first, where several are)."""
    run_positions, run_press = resampled(positions, RUN_POINTS), resampled(press, RUN_POINTS)
    reference = alignment_features(np.asarray(band.positions), np.asarray(band.mean_n))
    i, j = warping_path(reference, alignment_features(run_positions, run_press))
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
    return weighted_share([band_alignment(band, positions, press)[0] for band, positions, press in segments],
                           [len(press) for _, _, press in segments])  # fmt: skip


def weighted_share(insides: Sequence[NDArray[np.bool_]], samples: Sequence[int]) -> float:
    """The share of samples in band over segments, each segment's resampled points counting by its ``samples``."""
    weights = np.asarray(samples, dtype=float)
    return float(weights @ np.array([inside.mean() for inside in insides]) / weights.sum())
