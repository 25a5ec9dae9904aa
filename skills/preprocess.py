"""Turning a raw recording into a demonstration in the project's conventions: pure numpy/scipy, no I/O.

Every function is vectorized over samples. Units are SI (s, m, N, N·m); quaternions are
scalar-LAST ``[x, y, z, w]`` once converted; wrenches are ``[fx, fy, fz, mx, my, mz]``.

Event-driven logs (e.g. the KU Leuven contour recordings) write a row whenever ANY channel
produces a value and repeat the last value of every other channel. A repeated value is not a
new measurement: resampling it as one would turn a 30 Hz pose stream into a staircase. So per
channel group (pose: position + orientation; wrench) :func:`channel_group_samples` keeps the
rows where the group changed (plus the first, plus the rows of a real hold, see
:data:`HOLD_FACTOR`), and :func:`resampled_recording` interpolates each group onto one
uniform time grid (default rate: the fastest group's median update rate):

- positions: modified Akima cubic (C1, no overshoot next to a hold), or linear;
- orientations: slerp (:func:`skills.quaternions.quaternions_slerp`) after sign continuity;
- wrenches: linear.

Time stamps: a row whose time stamp is BELOW an earlier row's is dropped (out of order, its
place in time is unknown); samples of one group that share a time stamp are AVERAGED
(quaternions after sign alignment, then renormalized). Both are counted in the result's notes.

Wrench conventions (:func:`wrenches_applied_by_tool`, :func:`wrenches_tool_to_world`) complete
what an importer needs; the sensor offset is `skills.tare`'s. `services.csv_import` applies them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import Akima1DInterpolator

from skills.quaternions import (
    matrix_from_quaternion,
    quaternions_from_wxyz,
    quaternions_sign_continuous,
    quaternions_slerp,
)

HOLD_FACTOR = 4.0
"""A group unchanged for longer than this times its median update interval really was constant
(a robot standing still, a sensor reading exactly 0): the rows of such a hold are kept as samples,
so interpolation does not ramp across it. Shorter repeats are event-log repeats and are dropped."""
GAP_FACTOR = 5.0
"""A channel group with no measurement for longer than this times its median update interval (and than
:data:`MIN_GAP_S`) has a gap: the resampled samples across it are interpolated, not measured (a tracker that lost
the tool, a logger that stalled). The KU Leuven logs' longest interval is 2.7 times their median."""
MIN_GAP_S = 0.1
"""Shortest gap, s: a few missed updates of a fast stream are what resampling is for."""
MAX_GAP_S = 1.0
"""Longest gap, s: across a longer one the motion is unknown, not interpolable (the recording is refused there)."""
MAX_QUATERNION_NORM_DEVIATION = 0.1
"""Quaternions whose norm is further than this from 1 are rejected (wrong columns?), closer ones renormalized."""
DEFAULT_RATE_SIGNIFICANT_DIGITS = 3
"""The default resampling rate (the fastest group's median update rate) is rounded to this many digits."""

PositionMethod = Literal["cubic", "linear"]


# --------------------------------------------------------------------------- quaternions


def quaternions_scalar_last(q: ArrayLike, order: Literal["xyzw", "wxyz"] = "xyzw") -> NDArray[np.float64]:
    """Return ``(N, 4)`` quaternions as scalar-last ``[x, y, z, w]`` from the given component ``order``."""
    q = np.asarray(q, dtype=float)
    if order == "wxyz":
        return quaternions_from_wxyz(q)
    if order == "xyzw":
        return q.copy()
    raise ValueError(f"quaternion order must be 'xyzw' or 'wxyz', got {order!r}")


def quaternion_norm_deviations(q: ArrayLike) -> NDArray[np.float64]:
    """Return ``|‖q‖ - 1|`` per row of ``(N, 4)`` quaternions (dimensionless)."""
    return np.abs(np.linalg.norm(np.asarray(q, dtype=float), axis=-1) - 1.0)


def quaternions_unit_continuous(q: ArrayLike) -> NDArray[np.float64]:
    """Return ``(N, 4)`` scalar-last quaternions renormalized to unit norm and made sign-continuous.

    Sign continuity: ``q_k`` is flipped when ``dot(q_k, q_{k-1}) < 0`` (same rotation, one
    branch), see :func:`skills.quaternions.quaternions_sign_continuous`. Zero rows are not
    allowed (the caller checks :func:`quaternion_norm_deviations` first).
    """
    q = np.asarray(q, dtype=float)
    return quaternions_sign_continuous(q / np.linalg.norm(q, axis=-1, keepdims=True))


# --------------------------------------------------------------------------- wrench conventions


def wrenches_applied_by_tool(measured_on_tool: ArrayLike) -> NDArray[np.float64]:
    """Return the wrench the tool APPLIES to the environment from the one a sensor MEASURES on the tool.

    Newton's third law at the same point in the same frame: a plain negation of the ``(N, 6)``
    ``[f, m]`` rows (N, N·m).
    """
    return -np.asarray(measured_on_tool, dtype=float)


def wrenches_tool_to_world(wrenches_tool: ArrayLike, orientations: ArrayLike) -> NDArray[np.float64]:
    """Return ``(N, 6)`` wrenches expressed in the world from ones expressed in the TOOL frame.

    ``orientations`` are ``(N, 4)`` scalar-last world-from-tool quaternions. The wrench stays at
    the tool point (no change of reference point, so no ``p × f`` term): force and moment just
    rotate, ``f_w = R f_tool``, ``m_w = R m_tool``.
    """
    w = np.asarray(wrenches_tool, dtype=float)
    R = matrix_from_quaternion(orientations)
    return np.concatenate([np.einsum("nij,nj->ni", R, w[:, :3]), np.einsum("nij,nj->ni", R, w[:, 3:])], axis=1)


# --------------------------------------------------------------------------- event-driven logs


def rows_in_time_order(t: ArrayLike) -> NDArray[np.bool_]:
    """Return the mask of rows to keep: those whose time stamp (s) is not below an earlier one.

    A row stamped earlier than a previous row is out of order and dropped. Equal stamps are kept
    (their samples are averaged per group later, see :func:`channel_group_samples`).
    """
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return np.zeros(0, dtype=bool)
    previous_max = np.maximum.accumulate(np.concatenate(([-np.inf], t[:-1])))
    return t >= previous_max


def rows_where_changed(values: ArrayLike) -> NDArray[np.bool_]:
    """Return the mask of rows of ``(N, D)`` ``values`` differing from the previous row in any column; row 0 is True."""
    values = np.asarray(values, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    changed = np.ones(values.shape[0], dtype=bool)
    changed[1:] = np.any(values[1:] != values[:-1], axis=1)
    return changed


@dataclass(frozen=True)
class GroupSamples:
    """The measurements of one channel group: time stamps (s, strictly increasing) and values (M, D)."""

    t: NDArray[np.float64]
    values: NDArray[np.float64]
    n_rows: int
    """Rows of the log the group was taken from."""
    n_repeats_dropped: int
    """Rows that only repeated the previous value."""
    n_holds: int
    """Stretches where the value really stayed constant (their rows were kept as samples)."""
    n_same_time_merged: int
    """Samples that shared a time stamp with the previous one and were averaged into it."""

    @property
    def median_rate_hz(self) -> float:
        """Median update rate of the group, Hz (inf for a single sample)."""
        return 1.0 / float(np.median(np.diff(self.t))) if self.t.size > 1 else float("inf")


def _same_time_averaged(
    t: NDArray[np.float64], values: NDArray[np.float64], quaternion_columns: slice | None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Average the rows of ``values`` that share a time stamp (``t`` non-decreasing).

    Quaternion columns are sign-aligned with the first row of their time stamp before the
    average and renormalized after it.
    """
    unique_t, first, counts = np.unique(t, return_index=True, return_counts=True)
    if unique_t.size == t.size:
        return t, values
    values = values.copy()
    if quaternion_columns is not None:
        q = values[:, quaternion_columns]
        reference = np.repeat(q[first], counts, axis=0)
        values[:, quaternion_columns] = q * np.where(np.sum(q * reference, axis=1) < 0, -1.0, 1.0)[:, None]
    averaged = np.add.reduceat(values, first, axis=0) / counts[:, None]
    if quaternion_columns is not None:
        q = averaged[:, quaternion_columns]
        averaged[:, quaternion_columns] = q / np.linalg.norm(q, axis=1, keepdims=True)
    return unique_t, averaged


def channel_group_samples(
    t: ArrayLike, values: ArrayLike, quaternion_columns: slice | None = None, hold_factor: float = HOLD_FACTOR
) -> GroupSamples:
    """Return the real measurements of one channel group of an event-driven log.

    ``t`` (N,) time stamps in s, non-decreasing (drop out-of-order rows first with
    :func:`rows_in_time_order`); ``values`` (N, D) the group's columns. Kept: the first row and
    every row that differs from the previous one. A value unchanged for longer than
    ``hold_factor`` times the group's median update interval was really constant (a robot
    standing still): every row of that hold is kept, so the interpolation stays flat there.
    Samples with equal time stamps are averaged (the columns in ``quaternion_columns`` as
    quaternions: sign-aligned, averaged, renormalized).
    """
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    changed = rows_where_changed(values)
    starts = np.flatnonzero(changed)  # first row of each run of equal values
    run_ends_t = np.append(t[starts[1:]], t[-1])  # a run lasts until the next change (or the log's end)
    durations = run_ends_t - t[starts]
    run_rows = np.diff(np.append(starts, t.size))
    between = durations[:-1][durations[:-1] > 0]
    typical = float(np.median(between)) if between.size else 0.0
    # A hold is logged: its rows span it (a run whose rows stop before a stretch without rows is a gap, not a hold).
    logged = t[np.append(starts[1:], t.size) - 1] - t[starts]
    hold = (logged > hold_factor * typical) & (run_rows > 1) & (typical > 0)
    if starts.size == 1:  # never changes: constant over the whole log
        hold[:] = True
    kept_mask = changed | hold[np.cumsum(changed) - 1]
    kept = np.flatnonzero(kept_mask)
    n_holds = int(np.count_nonzero(hold))
    t_unique, merged = _same_time_averaged(t[kept], values[kept], quaternion_columns)
    return GroupSamples(
        t=t_unique,
        values=merged,
        n_rows=int(t.size),
        n_repeats_dropped=int(t.size - kept.size),
        n_holds=n_holds,
        n_same_time_merged=int(kept.size - t_unique.size),
    )


def default_rate_hz(*groups: GroupSamples) -> float:
    """Return the default resampling rate, Hz: the fastest group's median update rate, rounded to 3 digits.

    For a regularly sampled file this is its sampling rate; for the KU Leuven logs (pose ~30 Hz,
    wrench every 5 ms) it is 200 Hz: no measurement is thrown away and none is invented.
    """
    rate = max(group.median_rate_hz for group in groups if group.t.size > 1)
    return float(f"{rate:.{DEFAULT_RATE_SIGNIFICANT_DIGITS}g}")


def uniform_time_grid(t_start: float, t_end: float, rate_hz: float) -> NDArray[np.float64]:
    """Return time stamps (s) ``t_start + k / rate_hz``, ``k = 0, 1, ...``, up to ``t_end`` (inclusive, 1e-9 s), never
    past it: in floating point ``1.899 + 9701 / 1000`` is 11.600000000000001, beyond a last stamp of 11.6, and the
    position interpolation there was NaN (a recording that did not start at 0 crashed its import)."""
    n = int(np.floor((t_end - t_start) * rate_hz + 1e-9)) + 1
    return np.minimum(t_start + np.arange(n) / rate_hz, t_end)


def positions_resampled(
    t_query: ArrayLike, t: ArrayLike, positions: ArrayLike, method: PositionMethod = "cubic"
) -> NDArray[np.float64]:
    """Interpolate ``(N, 3)`` positions (m) sampled at ``t`` (s, strictly increasing) at ``t_query`` (within range).

    ``cubic``: modified Akima spline (C1; unlike a natural cubic spline it does not overshoot
    next to a hold or a kink); falls back to linear with fewer than 3 samples. ``linear``: piecewise linear.
    """
    t = np.asarray(t, dtype=float)
    positions = np.asarray(positions, dtype=float)
    t_query = np.asarray(t_query, dtype=float)
    if method == "cubic" and t.size >= 3:
        return Akima1DInterpolator(t, positions, axis=0, method="makima")(t_query)
    if method not in ("cubic", "linear"):
        raise ValueError(f"position interpolation must be 'cubic' or 'linear', got {method!r}")
    return values_linearly_resampled(t_query, t, positions)


def values_linearly_resampled(t_query: ArrayLike, t: ArrayLike, values: ArrayLike) -> NDArray[np.float64]:
    """Linearly interpolate ``(N, D)`` values (any unit, e.g. a wrench in N, N·m) at ``t_query`` (s)."""
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    t_query = np.asarray(t_query, dtype=float)
    return np.stack([np.interp(t_query, t, values[:, j]) for j in range(values.shape[1])], axis=1)


@dataclass(frozen=True)
class ResampledRecording:
    """A recording on one uniform time grid.

    ``t`` (M,) s, uniform at ``rate_hz``; ``positions`` (M, 3) m; ``orientations`` (M, 4)
    unit, scalar-last, sign-continuous; ``wrenches`` (M, 6) N and N·m, in whatever convention
    and frame the input had (this step does not convert them).
    """

    t: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]
    wrenches: NDArray[np.float64]
    rate_hz: float
    pose: GroupSamples
    wrench: GroupSamples
    n_rows_out_of_order: int
    n_duplicate_stamps: int = 0
    """Rows (in order) whose time stamp equals the previous row's."""
    unmeasured: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    """(K, 2) start and end, s, of the gaps of either group within the grid (:func:`unmeasured_intervals`)."""
    notes: list[str] = field(default_factory=list)


class TooManySamples(ValueError):  # noqa: N818 (reads as what happened)
    """The uniform grid asked for would hold more samples than allowed."""


def resampled_recording(
    t: ArrayLike,
    positions: ArrayLike,
    orientations: ArrayLike,
    wrenches: ArrayLike,
    rate_hz: float | None = None,
    position_method: PositionMethod = "cubic",
    max_samples: int | None = None,
) -> ResampledRecording:
    """Resample an (event-driven or irregular) recording onto one uniform time grid.

    ``t`` (N,) s; ``positions`` (N, 3) m; ``orientations`` (N, 4) scalar-last (any sign, unit
    within :data:`MAX_QUATERNION_NORM_DEVIATION`); ``wrenches`` (N, 6). Out-of-order rows are
    dropped, each group (pose, wrench) reduced to its real measurements by
    :func:`channel_group_samples`, and interpolated at ``rate_hz`` (default
    :func:`default_rate_hz`) over the time span where every group has measurements
    (no extrapolation: the grid starts at the later first sample and ends at or before the
    earlier last sample). ``max_samples``: raise :class:`TooManySamples` before building a longer grid.
    """
    t = np.asarray(t, dtype=float)
    in_order = rows_in_time_order(t)
    t = t[in_order]
    positions = np.asarray(positions, dtype=float)[in_order]
    orientations = quaternions_unit_continuous(np.asarray(orientations, dtype=float)[in_order])
    wrenches = np.asarray(wrenches, dtype=float)[in_order]

    pose = channel_group_samples(t, np.hstack([positions, orientations]), quaternion_columns=slice(3, 7))
    wrench = channel_group_samples(t, wrenches)
    return recording_from_groups(
        pose,
        wrench,
        rate_hz,
        position_method,
        n_rows_out_of_order=int(np.count_nonzero(~in_order)),
        n_duplicate_stamps=int(np.count_nonzero(np.diff(t) == 0)),
        max_samples=max_samples,
    )


def stream_samples(t: ArrayLike, values: ArrayLike, quaternion_columns: slice | None = None) -> GroupSamples:
    """Return the measurements of one message stream (e.g. a ROS topic) as a channel group.

    Unlike a row of an event-driven log, every message is a measurement (a repeated value is the
    robot holding still): nothing is dropped. ``t`` (N,) s in any order is sorted (stable); samples
    sharing a time stamp are averaged (``quaternion_columns`` as quaternions: sign-aligned, averaged,
    renormalized).
    """
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    order = np.argsort(t, kind="stable")
    t_unique, merged = _same_time_averaged(t[order], values[order], quaternion_columns)
    return GroupSamples(
        t=t_unique,
        values=merged,
        n_rows=int(t.size),
        n_repeats_dropped=0,
        n_holds=0,
        n_same_time_merged=int(t.size - t_unique.size),
    )


def unmeasured_intervals(t: ArrayLike) -> NDArray[np.float64]:
    """Return the gaps of one channel group's measurement times ``t`` (M,) s, increasing: (K, 2) start and end (s)
    of each interval between consecutive measurements longer than :data:`GAP_FACTOR` times the median interval and
    than :data:`MIN_GAP_S`."""
    t = np.asarray(t, dtype=float)
    if t.size < 3:
        return np.zeros((0, 2))
    steps = np.diff(t)
    gap = steps > max(GAP_FACTOR * float(np.median(steps)), MIN_GAP_S)
    return np.column_stack([t[:-1][gap], t[1:][gap]])


def merged_intervals(intervals: ArrayLike) -> NDArray[np.float64]:
    """Return the union of (K, 2) [start, end] intervals (s) as sorted, disjoint (J, 2) intervals."""
    intervals = np.asarray(intervals, dtype=float).reshape(-1, 2)
    if intervals.shape[0] == 0:
        return intervals
    intervals = intervals[np.argsort(intervals[:, 0])]
    reach = np.maximum.accumulate(intervals[:, 1])
    starts = np.r_[True, intervals[1:, 0] > reach[:-1]]  # an interval starting after all before it ended
    ends = np.r_[starts[1:], True]
    return np.column_stack([intervals[starts, 0], reach[ends]])


def _gaps_within(groups: tuple[GroupSamples, GroupSamples], t_start: float, t_end: float) -> NDArray[np.float64]:
    """The gaps of either group (pose, wrench) within [t_start, t_end] s, merged; raises ValueError naming the group
    and the interval when one is longer than :data:`MAX_GAP_S`."""
    found = []
    for group, name in zip(groups, ("pose", "wrench"), strict=True):
        gaps = unmeasured_intervals(group.t)
        gaps = np.clip(gaps, t_start, t_end)
        gaps = gaps[gaps[:, 1] > gaps[:, 0]]
        lengths = gaps[:, 1] - gaps[:, 0]
        if lengths.size and lengths.max() > MAX_GAP_S:
            a, b = gaps[int(np.argmax(lengths))]
            raise ValueError(
                f"the {name} has no measurement for {b - a:.2f} s ({a:.6g}-{b:.6g} s), longer than {MAX_GAP_S:g} s: "
                "the motion there is unknown, not interpolable; cut or split the recording there"
            )
        found.append(gaps)
    return merged_intervals(np.concatenate(found))


def recording_from_groups(
    pose: GroupSamples,
    wrench: GroupSamples,
    rate_hz: float | None = None,
    position_method: PositionMethod = "cubic",
    n_rows_out_of_order: int = 0,
    n_duplicate_stamps: int = 0,
    max_samples: int | None = None,
) -> ResampledRecording:
    """Interpolate a pose group (values: position (m) then scalar-last quaternion) and a wrench group onto one
    uniform grid at ``rate_hz`` (default :func:`default_rate_hz`) over the span where both have measurements
    (no extrapolation): positions by ``position_method``, orientations by slerp, wrenches linearly.
    ``max_samples``: raise :class:`TooManySamples` before building a longer grid."""
    if rate_hz is None:
        if pose.t.size < 2 and wrench.t.size < 2:
            raise ValueError("cannot choose a resampling rate: no channel changes over time")
        rate_hz = default_rate_hz(pose, wrench)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"resampling rate must be a positive number of Hz, got {rate_hz}")
    for group, name in ((pose, "pose"), (wrench, "wrench")):
        if group.t.size < 2:
            raise ValueError(f"the {name} has a single sample: nothing to interpolate over time")
    t_start = max(pose.t[0], wrench.t[0])
    t_end = min(pose.t[-1], wrench.t[-1])
    wanted = (t_end - t_start) * rate_hz + 1
    if max_samples is not None and wanted > max_samples:
        raise TooManySamples(
            f"{t_end - t_start:.6g} s at {rate_hz:g} Hz would be {wanted:.4g} samples, more than {max_samples}: "
            "choose a lower rate"
        )
    unmeasured = _gaps_within((pose, wrench), t_start, t_end)
    grid = uniform_time_grid(t_start, t_end, rate_hz)

    q_measured = quaternions_sign_continuous(pose.values[:, 3:7])
    result = ResampledRecording(
        t=grid,
        positions=positions_resampled(grid, pose.t, pose.values[:, :3], position_method),
        orientations=quaternions_slerp(grid, pose.t, q_measured),
        wrenches=values_linearly_resampled(grid, wrench.t, wrench.values),
        rate_hz=float(rate_hz),
        pose=pose,
        wrench=wrench,
        n_rows_out_of_order=n_rows_out_of_order,
        n_duplicate_stamps=n_duplicate_stamps,
        unmeasured=unmeasured,
    )
    result.notes.extend(_resampling_notes(result))
    return result


def _resampling_notes(r: ResampledRecording) -> list[str]:
    """One line per thing the resampling did, for the import report."""
    source = (
        f"{r.pose.n_rows} rows"
        if r.pose.n_rows == r.wrench.n_rows
        else f"{r.pose.n_rows} pose and {r.wrench.n_rows} wrench messages"
    )
    notes = [
        f"resampled to {r.rate_hz:g} Hz ({r.t.size} samples, {r.t[-1] - r.t[0]:.3f} s) from "
        f"{source}: pose {r.pose.t.size} measurements (median {r.pose.median_rate_hz:.3g} Hz), "
        f"wrench {r.wrench.t.size} (median {r.wrench.median_rate_hz:.3g} Hz)"
    ]
    repeats = r.pose.n_repeats_dropped + r.wrench.n_repeats_dropped
    if repeats:
        notes.append(
            f"event-driven log: {r.pose.n_repeats_dropped} pose and {r.wrench.n_repeats_dropped} wrench rows "
            "only repeated the last value and were not used as measurements"
        )
    if r.pose.n_holds or r.wrench.n_holds:
        notes.append(f"constant stretches kept as holds: pose {r.pose.n_holds}, wrench {r.wrench.n_holds}")
    if r.n_duplicate_stamps:
        notes.append(f"{r.n_duplicate_stamps} rows repeat the previous row's time stamp")
    merged = r.pose.n_same_time_merged + r.wrench.n_same_time_merged
    if merged:
        notes.append(f"{merged} samples sharing a time stamp with the previous one were averaged into it")
    if r.n_rows_out_of_order:
        notes.append(f"{r.n_rows_out_of_order} rows stamped earlier than a previous row were dropped")
    if r.unmeasured.shape[0]:
        lengths = r.unmeasured[:, 1] - r.unmeasured[:, 0]
        where = ", ".join(f"{a:.6g}-{b:.6g} s" for a, b in r.unmeasured[:5])
        more = f" and {lengths.size - 5} more" if lengths.size > 5 else ""
        notes.append(
            f"no measurement of the pose or the wrench for {lengths.sum():.2f} s in {lengths.size} gap(s) ({where}"
            f"{more}): the samples there are interpolated, not measured"
        )
    return notes


# --------------------------------------------------------------------------- sensor artefacts
SPIKE_NOISE_FACTOR = 8.0
"""A wrench sample further than this many noise standard deviations (and than ``SPIKE_MIN``) from the median of its
neighbours, while those neighbours agree with it, is a spike: one sample of an electrical glitch, not a force."""
SPIKE_MIN = 3.0
"""Least size of a spike, N (or N·m on the moment channels): a real press changes over several samples."""
SPIKE_RANGE_SHARE = 2.0
"""...and at least this multiple of the channel's own range (the 98th percentile of its distance from its median):
at 100 Hz a tool's touch-down or a hand turning a weighed tool lasts one sample too, and is a few newtons; a glitch
is far larger than what was pressed."""
SPIKE_HALF_WINDOW = 2
"""A spike is judged against the median of this many samples on either side of it."""


def despiked(values: ArrayLike) -> tuple[NDArray[np.float64], int]:
    """Return the samples (N, C) with single-sample spikes replaced by the median of their neighbours, and how many
    samples were replaced. Per channel: a sample further from the median of its ``SPIKE_HALF_WINDOW`` neighbours on
    either side than ``SPIKE_NOISE_FACTOR`` noise standard deviations (the channel's sample-to-sample median absolute
    deviation), than ``SPIKE_MIN`` and than ``SPIKE_RANGE_SHARE`` of the channel's range, whose two direct neighbours
    both lie within that of the median: a press rising fast moves its neighbours too, a glitch does not."""
    values = np.array(values, dtype=float, copy=True)
    n = values.shape[0]
    k = SPIKE_HALF_WINDOW
    if n < 2 * k + 1:
        return values, 0
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(values, ((k, k), (0, 0)), mode="edge"), 2 * k + 1, 0)
    neighbours = np.delete(windows, k, axis=-1)  # (N, C, 2k): the sample itself left out
    median = np.median(neighbours, axis=-1)
    noise = 1.4826 * np.median(np.abs(np.diff(values, axis=0)), axis=0) / np.sqrt(2.0)
    spread = np.percentile(np.abs(values - np.median(values, axis=0)), 98, axis=0)
    limit = np.maximum(np.maximum(SPIKE_NOISE_FACTOR * noise, SPIKE_MIN), SPIKE_RANGE_SHARE * spread)
    off = np.abs(values - median) > limit
    calm = np.ones_like(off)
    calm[1:] &= np.abs(values[:-1] - median[1:]) <= limit
    calm[:-1] &= np.abs(values[1:] - median[:-1]) <= limit
    spikes = off & calm
    values[spikes] = median[spikes]
    return values, int(spikes.any(axis=1).sum())
