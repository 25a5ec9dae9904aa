"""What the dashboard's pages draw that the REST resources do not give in a drawable size: a skill with its
demonstration decimated for plotting (:func:`skill_view`), and a sweep's success-rate figure (:func:`sweep_png`).

Units: s, m, N; frames: world (positions, CF triads), CF (forces along CF z). Quaternions ``[x, y, z, w]``.
"""

from __future__ import annotations

import numpy as np

from schemas import Demonstration, Skill
from schemas.dashboard import BandSpan, SegmentSpan, SkillView, Triad
from schemas.skill import ForceBand, Segment
from schemas.sweep import SweepView, TrialResult

PLOT_POINTS = 1500
"""Samples of the demonstration a skill page plots at most (decimated evenly; the shape of a force profile)."""
TRIADS = 40
"""CF triads a skill page draws at most along the path."""


def _evenly(n: int, most: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, most)).round().astype(int)) if n else np.zeros(0, dtype=int)


def _nullable(values: np.ndarray) -> list[float | None]:
    return [None if not np.isfinite(v) else float(v) for v in values]


def skill_view(
    skill_id: str, demonstration_id: str | None, skill: Skill, demonstration: Demonstration | None
) -> SkillView:
    """The skill's segments, learned force and CF triads, with its demonstration (when stored) decimated to
    :data:`PLOT_POINTS` samples: path and force along CF z; for a skill learned from several demonstrations, the
    demonstrations with their weights and its segments' force bands on the (reference) demonstration's time line."""
    from services.figures import forces_in_compliant_frames, learned_force_curve
    from skills.quaternions import matrix_from_quaternion
    from skills.skill_checks import check_bound

    t: list[float] = []
    path: list[list[float]] = []
    force: list[float | None] = []
    dt = 1.0 / skill.sample_rate_hz
    if demonstration is not None:
        a = demonstration.arrays()
        keep = _evenly(a.t.size, PLOT_POINTS)
        t, path = a.t[keep].tolist(), a.positions[keep].tolist()
        force = _nullable(forces_in_compliant_frames(demonstration, skill)[keep, 2])
        dt = float(np.median(np.diff(a.t)))
    learned_t: list[float] = []
    learned: list[float | None] = []
    for segment in skill.segments:
        curve = learned_force_curve(segment, dt)
        if curve is None:
            continue
        keep = _evenly(curve[0].size, PLOT_POINTS // 4)
        learned_t += [*curve[0][keep].tolist(), float(curve[0][-1])]
        learned += [*curve[1][keep].tolist(), None]  # a break before the next segment's curve
    frames = [(o, q) for s in skill.segments if s.compliant_frames is not None
              for o, q in zip(s.compliant_frames.origins, s.compliant_frames.orientations, strict=True)]  # fmt: skip
    triads = [Triad(origin=list(frames[k][0]), axes=matrix_from_quaternion(frames[k][1]).T.tolist())
              for k in _evenly(len(frames), TRIADS)]  # fmt: skip
    return SkillView(
        id=skill_id,
        skill_type=skill.skill_type.value,
        demonstration_id=demonstration_id,
        segments=[
            SegmentSpan(index=s.index, kind=s.kind.value, t_start=s.t_start, t_end=s.t_end, force_n=s.force_constant_n)
            for s in skill.segments
        ],
        t=t,
        path=path,
        force_cf_z=force,
        learned_t=learned_t,
        learned_force=learned,
        force_bands=[_band_span(s, s.force_band) for s in skill.segments if s.force_band is not None],
        demonstrations=skill.demonstrations,
        triads=triads,
        auto_selection=skill.auto_selection,
        checks=skill.checks,
        check_bounds=[check_bound(check) for check in skill.checks],
    )


def _band_span(segment: Segment, band: ForceBand) -> BandSpan:
    """The segment's force band with its phases (0-1 of the segment) placed on the segment's time span, s."""
    t = segment.t_start + np.asarray(band.phase) * (segment.t_end - segment.t_start)
    return BandSpan(segment=segment.index, t=t.tolist(), mean_n=band.mean_n, lower_n=band.lower_n,
                    upper_n=band.upper_n, demonstrations=band.demonstrations)  # fmt: skip


def sweep_png(view: SweepView, trials: list[TrialResult]) -> bytes:
    """The sweep's figure (``services.sweep_figure``: true RMS error and success rate along each varied
    parameter, per controller) as PNG bytes."""
    import tempfile
    from pathlib import Path

    from services.sweep_figure import write_sweep_figure

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "sweep.png"
        write_sweep_figure(view, trials, path)
        return path.read_bytes()
