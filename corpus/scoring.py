"""Scoring a learned skill against a corpus case's ground truth (`corpus.case.CorpusCase`).

`score` is a pure function of the learned `schemas.Skill` and the case. Times are the demonstration's (s), angles
deg, forces N; the learned contact segments are those of kind ``contact``, in time order. A truth sample is
*scored* when the tool touches, the sample lies in a truth segment's span (`corpus.case.TruthSegment.span`) and the
true normal force exceeds `SCORED_PRESSING_FRACTION` of that segment's plateau ``force_n`` (the ramps' feet and the dips
are left out). The metrics:

- ``type_right``: the learned skill type is the truth's (slide or contour).
- ``strokes_right``: as many learned contact segments as truth segments (``learned_strokes`` == ``truth_strokes``).
- ``boundary_error_s``: for every truth boundary window (touch-downs, lift-offs and the windows between strokes),
  the distance (s) from the nearest learned contact-segment boundary (any ``t_start`` or ``t_end``) to the window,
  0 inside it; the largest over the windows.
- ``normal_error_deg``: slide truth: for every learned contact segment, the angle between its CF z (the mean of its
  frames' z axes if it holds a series) and the normal of the truth segment it overlaps most in time (the nearest
  in time if it overlaps none); the largest over the learned segments. Contour truth: the time-weighted mean, over
  the scored samples, of the angle between the true normal and the CF z of the learned contact segment holding the
  sample (the nearest one in time if none does), its frames slerped at the time since its start and clamped at
  their ends (`skills.compliant_frames.compliant_frame_rotations`).
- ``force_error``: slide truth: for every learned contact segment, ``|force − force_n| / force_n`` against its
  matched truth segment, where ``force`` is its ``force_constant_n``; the largest. A learned segment matched to an
  UNSTEADY truth segment (``steady`` False: a ramp, a wobble, no single plateau; its ``force_n`` is the mean true
  normal force over its samples pressing above 30 % of its largest, `corpus.case.UNSTEADY_PRESS_FRACTION`), or one
  that learned a profile (a force DMP), is judged by its profile instead: the RMS, over that truth segment's scored
  samples the learned segment holds (all of them if it holds none), of (the learned force − the true normal
  force), divided by the truth segment's ``force_n``. Contour truth: the RMS over the scored samples of (the
  learned force − the true normal force), divided by the mean of the truth segments' ``force_n``. The learned force
  is the force DMP of the segment holding the sample (as for the normal), rolled out at the skill's sample rate and
  interpolated at the time since its start (held at its ends), or its ``force_constant_n``; the RMS weighs the
  samples by their time steps.

Without any learned contact segment every error is infinite.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from corpus.case import CorpusCase, TruthSegment
from schemas import Skill
from schemas.skill import Segment, SegmentKind
from skills.compliant_frames import compliant_frame_rotations
from skills.dmp import DMP

SCORED_PRESSING_FRACTION = 0.3
"""A sample is scored (contours, unsteady slides) where the true normal force exceeds this fraction of its
segment's ``force_n``."""


@dataclass(frozen=True)
class Score:
    """How a learned skill compares with a case's truth (definitions: module docstring)."""

    type_right: bool
    strokes_right: bool
    learned_strokes: int
    truth_strokes: int
    boundary_error_s: float
    """s."""
    normal_error_deg: float
    """deg."""
    force_error: float
    """Relative to the truth's ``force_n`` (the plateau force, or an unsteady press's mean pressing force)."""


def _gap(t0: NDArray, t1: NDArray, lo: NDArray, hi: NDArray) -> NDArray:
    """Distance (s) between the intervals ``[t0, t1]`` and ``[lo, hi]`` (broadcast), 0 where they meet."""
    return np.maximum(np.maximum(lo - t1, t0 - hi), 0.0)


def _matched(learned: list[Segment], truth: list[TruthSegment]) -> NDArray[np.int_]:
    """For each learned segment, the truth segment it overlaps most in time (the nearest if it overlaps none)."""
    t0 = np.array([s.t_start for s in learned])[:, None]
    t1 = np.array([s.t_end for s in learned])[:, None]
    lo = np.array([s.span[0] for s in truth])[None, :]
    hi = np.array([s.span[1] for s in truth])[None, :]
    overlap = np.minimum(t1, hi) - np.maximum(t0, lo)
    return np.argmax(np.where(overlap > 0, overlap, -_gap(t0, t1, lo, hi)), axis=1)


def _holder(learned: list[Segment], t: NDArray) -> NDArray[np.int_]:
    """For each time ``t`` (s), the learned segment holding it (the nearest in time if none does)."""
    t0 = np.array([s.t_start for s in learned])[None, :]
    t1 = np.array([s.t_end for s in learned])[None, :]
    return np.argmin(_gap(t[:, None], t[:, None], t0, t1), axis=1)


def _cf_z(segment: Segment, t_since_start: NDArray) -> NDArray[np.float64]:
    """CF z axes (M, 3) of ``segment`` at times since its start (s)."""
    return compliant_frame_rotations(segment, t_since_start)[:, :, 2]


def _force(segment: Segment, t_since_start: NDArray, rate_hz: float) -> NDArray[np.float64]:
    """The learned normal force (M,) N of ``segment`` at times since its start (s)."""
    if segment.force_dmp is None:
        return np.full(t_since_start.shape, float(segment.force_constant_n or 0.0))
    rollout = DMP.from_parameters(segment.force_dmp).rollout(1.0 / rate_hz)
    return np.interp(t_since_start, rollout.t, rollout.y[:, 0])


def _angle_deg(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """Angle (deg) between the rows of ``a`` and ``b``."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _boundary_error(learned: list[Segment], truth: list[TruthSegment]) -> float:
    windows = np.array(sorted({w for s in truth for w in (s.start_window, s.end_window)}))
    bounds = np.array([t for s in learned for t in (s.t_start, s.t_end)])[:, None]
    return float(np.max(np.min(_gap(bounds, bounds, windows[None, :, 0], windows[None, :, 1]), axis=0)))


def _scored(case: CorpusCase) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
    """The scored samples (module docstring) and the truth segment whose span holds each."""
    spans = np.array([s.span for s in case.segments])
    plateau = np.array([s.force_n for s in case.segments])
    inside = (case.t[:, None] >= spans[:, 0]) & (case.t[:, None] <= spans[:, 1])
    owner = np.argmax(inside, axis=1)
    scored = case.in_contact & inside.any(axis=1) & (case.normal_force_n > SCORED_PRESSING_FRACTION * plateau[owner])
    rows = np.flatnonzero(scored)
    return rows, owner[rows]


def _profile_error(segment: Segment, case: CorpusCase, rows: NDArray[np.int_], rate_hz: float) -> float:
    """Time-weighted RMS (N) of ``segment``'s force minus the true normal force at the samples ``rows``."""
    learned = _force(segment, case.t[rows] - segment.t_start, rate_hz)
    weights = np.gradient(case.t)[rows]
    return float(np.sqrt(np.sum(weights * (learned - case.normal_force_n[rows]) ** 2) / np.sum(weights)))


def _slide_errors(learned: list[Segment], case: CorpusCase, rate_hz: float) -> tuple[float, float]:
    """(normal error deg, force error) against plane truth: the worst learned segment."""
    matched = _matched(learned, case.segments)
    truth = [case.segments[j] for j in matched]
    normals = [_cf_z(s, np.asarray(s.compliant_frames.t)).mean(axis=0) for s in learned]
    forces = [_force(s, np.linspace(0.0, s.t_end - s.t_start, 100), rate_hz).mean() for s in learned]
    angles = _angle_deg(np.array(normals), np.array([s.normal for s in truth]))
    true_forces = np.array([s.force_n for s in truth])
    force_errors = np.abs(np.array(forces) - true_forces) / true_forces
    profiled = [not t.steady or s.force_dmp is not None for s, t in zip(learned, truth, strict=True)]
    if any(profiled):
        # An unsteady press has no plateau to match a constant against, and a learned profile is more than its mean:
        # the profile is judged against the true press instead.
        rows, owner = _scored(case)
        holder = _holder(learned, case.t[rows])
        for k, (segment, j) in enumerate(zip(learned, matched, strict=True)):
            if profiled[k]:
                mine = rows[(owner == j) & (holder == k)]
                mine = mine if mine.size else rows[owner == j]
                force_errors[k] = _profile_error(segment, case, mine, rate_hz) / case.segments[j].force_n
    return float(angles.max()), float(np.max(force_errors))


def _contour_errors(learned: list[Segment], case: CorpusCase, rate_hz: float) -> tuple[float, float]:
    """(time-weighted mean normal error deg, relative RMS force error) over the scored samples."""
    plateau = np.array([s.force_n for s in case.segments])
    rows, _ = _scored(case)
    holder = _holder(learned, case.t[rows])
    angles = np.empty(rows.size)
    forces = np.empty(rows.size)
    for k, segment in enumerate(learned):
        mine = holder == k
        since = case.t[rows[mine]] - segment.t_start
        angles[mine] = _angle_deg(_cf_z(segment, since), case.normals[rows[mine]])
        forces[mine] = _force(segment, since, rate_hz)
    weights = np.gradient(case.t)[rows]
    normal_error = float(np.sum(weights * angles) / np.sum(weights))
    rms = np.sqrt(np.sum(weights * (forces - case.normal_force_n[rows]) ** 2) / np.sum(weights))
    return normal_error, float(rms / plateau.mean())


def score(skill: Skill, case: CorpusCase) -> Score:
    """Score the learned ``skill`` against ``case``'s truth (the metrics: module docstring)."""
    learned = sorted((s for s in skill.segments if s.kind is SegmentKind.contact), key=lambda s: s.t_start)
    common = {
        "type_right": skill.skill_type.value == case.skill_type,
        "strokes_right": len(learned) == len(case.segments),
        "learned_strokes": len(learned),
        "truth_strokes": len(case.segments),
    }
    if not learned:
        return Score(**common, boundary_error_s=np.inf, normal_error_deg=np.inf, force_error=np.inf)
    errors = _slide_errors if case.skill_type == "slide" else _contour_errors
    normal_error, force_error = errors(learned, case, skill.sample_rate_hz)
    return Score(
        **common,
        boundary_error_s=_boundary_error(learned, case.segments),
        normal_error_deg=normal_error,
        force_error=force_error,
    )
