"""Where and how an execution touched its part, from its telemetry: the touch-downs (peak, settle time) and where
each contact segment pressed against where it was taught (``schemas.verdict.SurfacePressed``). World frame, SI units;
forces in N along CF z.

A touch-down is counted in whatever phase the tool first meets a surface, free segments included.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from execution.plans import contact_geometry
from execution.telemetry import Telemetry
from schemas.execution import PHASE_CODES, ExecutionPhase
from schemas.skill import Segment, SegmentKind, Skill
from schemas.verdict import SurfacePressed
from skills import pressed_normals

TRANSITION_WINDOW_S = 0.25
"""A switch between contact segments is scored on its own over this long on each side, s."""
TOUCHDOWN_DEBOUNCE_S = 0.02
"""A touch counts as a new touch-down only after this long out of contact (a bouncing or chattering contact is one
touch-down), s."""
SETTLED_BAND = 0.05
"""Settled: the true normal force within this fraction of the reference force of the desired one ..."""
SETTLED_HOLD_S = 0.1
"""... for at least this long, s."""
REGION_SAMPLES = 501
"""A contour's taught normals are sampled this many times, evenly in time, for its region."""
PRESSED_NORMAL_WINDOW_S = 0.1
"""A touch-down's and a contact's final normal are the mean normal pressed over this long, s."""
CREASE_SIDE_S = 0.2
"""Across a switch between contact segments, the normal pressed on either side is the mean over a slide's rows
outside the transition window, or over this long of a contour's next to that window, s."""


def run_starts(mask: NDArray[np.bool_]) -> NDArray[np.int_]:
    """Indices where runs of True in ``mask`` start."""
    return np.flatnonzero(mask & ~np.r_[False, mask[:-1]])


def touchdown_metrics(
    tel: Telemetry, steady: NDArray[np.bool_], exits: NDArray[np.bool_], reference: float, dt: float
) -> dict[str, float]:
    """Touch-down peak (N, over the press that followed and over the force asked at contact) and the longest settle
    time (s) over the touch-downs.

    A touch-down starts at the first row touching a surface (true normal force > 0) after ``TOUCHDOWN_DEBOUNCE_S``
    out of contact, in ANY phase (a surface met early, in a free segment, too) but on the way out of a contact
    (``exits``: an exit collision, not a touch-down), outside the steady contact; it ends where its steady contact
    starts, or where the tool leaves the surface (a touch that bounced off). Its ratio is over the desired force
    where the next steady contact starts (without one, the reference force), and, reported beside it, over the
    desired force where the next contact phase starts (the force asked at contact). Its settle time is from the first
    touch until the true normal force stays within ``SETTLED_BAND`` of the reference of the desired force for
    ``SETTLED_HOLD_S``."""
    if len(tel) == 0:  # failed before its first step
        return {}
    touching = tel.normal_force_true > 0.0
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    contact_starts = run_starts(contact)
    debounce = max(1, round(TOUCHDOWN_DEBOUNCE_S / dt))
    free_before = np.convolve(~touching, np.ones(debounce), mode="full")[: len(tel)] >= debounce  # up to this row
    starts = np.flatnonzero(touching & ~steady & ~exits & np.r_[True, free_before[:-1]])
    steady_starts = run_starts(steady)
    leaves = np.flatnonzero(free_before) - (debounce - 1)  # where a stretch out of contact of `debounce` rows starts
    error = np.abs(tel.normal_force_true - tel.desired_force)
    hold = max(1, round(SETTLED_HOLD_S / dt))
    peaks, ratios, asked_ratios, settles = [], [], [], []
    for begin in starts:
        later = steady_starts[steady_starts > begin]
        left = leaves[leaves > begin]
        lift = int(left[0]) if left.size else len(tel)
        steady_start = int(later[0]) if later.size else len(tel)
        peaks.append(float(tel.normal_force_true[begin : min(steady_start, lift)].max()))
        # Against the press that followed (a touch that bounced off too), else the reference force.
        target = float(tel.desired_force[steady_start]) if steady_start < len(tel) else reference
        if target > 0:
            ratios.append(peaks[-1] / target)
        asked = contact_starts[contact_starts >= begin]
        if asked.size and tel.desired_force[asked[0]] > 0:
            asked_ratios.append(peaks[-1] / float(tel.desired_force[asked[0]]))
        if steady_start > lift or steady_start >= len(tel):
            continue  # left the surface before any steady contact: it did not settle
        outside = error[begin:] > SETTLED_BAND * max(reference, 1e-9)
        settled_for = np.convolve(~outside, np.ones(hold), mode="valid") >= hold  # the next `hold` rows are inside
        if settled_for.any():
            settles.append(float(np.argmax(settled_for)) * dt)
    result: dict[str, float] = {}
    if peaks:
        result["touchdown_peak_n"] = max(peaks)
    if ratios:
        result["touchdown_peak_ratio"] = max(ratios)
    if asked_ratios:
        result["touchdown_contact_force_ratio"] = max(asked_ratios)
    if settles:
        result["settle_time_s"] = max(settles)
    return result


def surfaces_pressed(
    skill: Skill, tel: Telemetry, offset: NDArray[np.float64], next_found: dict[int, bool] | None = None
) -> list[SurfacePressed]:
    """Where each contact segment pressed against where it was taught (``schemas.verdict.SurfacePressed``): the true
    contact normals of its contact-phase rows that touched against the taught CF z at the same share of the segment
    (world, unit, into the surface). ``next_found``: per segment entered across a crease while following the surface,
    whether the next surface was met."""
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    touching = contact & (tel.normal_force_true > 0.0)
    result: list[SurfacePressed] = []
    previous: tuple[Segment, NDArray[np.bool_]] | None = None
    for k, segment in enumerate(skill.segments):
        if segment.kind is not SegmentKind.contact:
            previous = None
            continue
        in_segment = contact & (tel.segment_index == segment.index)
        rows = touching & (tel.segment_index == segment.index)
        if rows.sum() < 2:
            previous = None
            continue
        geo = contact_geometry(segment, offset)
        t_first, t_last = tel.t[in_segment][[0, -1]]
        t, pressed = tel.t[rows], tel.contact_normal[rows]
        taught = geo.rotations_at(np.clip((t - t_first) / max(t_last - t_first, 1e-9), 0.0, 1.0))[:, :, 2]
        errors = pressed_normals.angles_deg(pressed, taught)
        first, last = t <= t[0] + PRESSED_NORMAL_WINDOW_S, t >= t[-1] - PRESSED_NORMAL_WINDOW_S
        fields: dict = {
            "segment": segment.index,
            "normal_error_deg": float(np.median(errors)),
            "normal_error_max_deg": float(np.percentile(errors, 95)),
            "touchdown_normal_error_deg": pressed_normals.mean_angle_deg(pressed[first], taught[first]),
            "final_normal_error_deg": pressed_normals.mean_angle_deg(pressed[last], taught[last]),
        }
        taught_path = geo.rotations_at(np.linspace(0.0, 1.0, REGION_SAMPLES))[:, :, 2] if geo.t.size > 1 else None
        if taught_path is not None and (plane := pressed_normals.turn_plane(taught_path)) is not None:
            taught_span = pressed_normals.span_deg(plane, taught_path, trim_pct=0.0)
            pressed_span = pressed_normals.span_deg(plane, pressed)
            fields |= {
                "taught_region_deg": taught_span,
                "pressed_region_deg": pressed_span,
                "region_coverage": pressed_normals.region_coverage(taught_span, pressed_span),
            }
        if previous is not None and previous[0].index == skill.segments[k - 1].index:
            before_segment, before_rows = previous
            before_geo = contact_geometry(before_segment, offset)
            switch = t_first
            before = before_rows & (tel.t < switch - TRANSITION_WINDOW_S)
            if before_geo.t.size > 1:  # a contour's normal turns: the one just before the switch
                before &= tel.t >= switch - TRANSITION_WINDOW_S - CREASE_SIDE_S
            after = rows & (tel.t > switch + TRANSITION_WINDOW_S)
            if geo.t.size > 1:
                after &= tel.t <= switch + TRANSITION_WINDOW_S + CREASE_SIDE_S
            before = before if before.sum() >= 2 else before_rows
            after = after if after.sum() >= 2 else rows
            taught_before = before_geo.rotations[-1][:, 2]
            taught_after = geo.rotations_at(np.zeros(1))[0][:, 2]
            fields["crease_deg"] = float(pressed_normals.angles_deg(taught_before, taught_after))
            fields["crease_turn_deg"] = pressed_normals.crease_turn_deg(
                pressed_normals.unit_mean(tel.contact_normal[before]),
                pressed_normals.unit_mean(tel.contact_normal[after]),
                taught_before,
                taught_after,
            )
            if next_found is not None and segment.index in next_found:
                fields["next_surface_found"] = next_found[segment.index]
        result.append(SurfacePressed(**fields))
        previous = (segment, rows)
    return result
