"""What an execution achieved, computed from its telemetry: force errors over the steady contact, contact ratio,
path error, touch-down, and the verdict against the tolerances (``schemas.execution.ExecutionMetrics``). World
frame, SI units; forces in N along CF z.

Every peak is seen: the steady window of a contact run starts once, after its touch-down and force ramp, and spans
its crease passages and segment switches (each also scored on its own, the transition figure); a touch-down is
counted in whatever phase the tool first meets a surface, free segments included; the CF angle is that of the frame
the controller used at each row.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from execution.contact_detection import ContactGuard
from execution.plans import contact_geometry
from execution.telemetry import Telemetry
from schemas.demonstration import Demonstration
from schemas.execution import (
    PHASE_CODES,
    ControllerKind,
    ExecutionMetrics,
    ExecutionPhase,
    ExecutionSettings,
    WorkPieceSource,
)
from schemas.skill import IN_BAND_SHARE, Segment, SegmentKind, Skill, SkillCheck
from schemas.verdict import (
    ExecutionTolerances,
    ExecutionVerdict,
    SurfacePressed,
    Verdict,
    VerdictCheck,
    VerdictCheckName,
)
from skills import pressed_normals, skill_checks
from skills.dmp import DMP
from skills.joint_learning import share_in_band

STEADY_CONTACT_DELAY_S = 0.2
"""The steady contact phase starts this long after a contact run starts (and after its force ramp), s."""
TRANSITION_WINDOW_S = 0.25
"""A switch between contact segments is scored on its own over this long on each side, s."""
TOUCHDOWN_DEBOUNCE_S = 0.02
"""A touch counts as a new touch-down only after this long out of contact (a bouncing or chattering contact is one
touch-down), s."""
SETTLED_BAND = 0.05
"""Settled: the true normal force within this fraction of the reference force of the desired one ..."""
SETTLED_HOLD_S = 0.1
"""... for at least this long, s."""


def reference_force(skill: Skill, dt: float = 1e-3) -> float:
    """The force the % errors refer to: the largest learned constant, or the peak of the force profile
    rolled out at the control step ``dt`` (s), as executed (N)."""
    values = [s.force_constant_n for s in skill.segments if s.force_constant_n is not None]
    for s in skill.segments:
        if s.force_dmp is not None:
            values.append(float(np.max(DMP.from_parameters(s.force_dmp).rollout(dt).y)))
    return max(values) if values else 0.0


def _run_starts(mask: NDArray[np.bool_]) -> NDArray[np.int_]:
    """Indices where runs of True in ``mask`` start."""
    return np.flatnonzero(mask & ~np.r_[False, mask[:-1]])


def _steady_mask(tel: Telemetry, ramp_s: float) -> NDArray[np.bool_]:
    """Contact-phase rows at least max(0.2 s, the force ramp) after the start of their contact RUN (consecutive
    contact-phase rows: contact segments that follow each other directly are one run, their switch inside it)."""
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    if not contact.any():
        return contact
    run = np.cumsum(np.isin(np.arange(len(tel)), _run_starts(contact)))  # run number of each row (1-based)
    started = tel.t[_run_starts(contact)][run - 1]
    return contact & (tel.t >= started + max(STEADY_CONTACT_DELAY_S, ramp_s) - 1e-9)


def _transition_mask(tel: Telemetry, steady: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Steady rows within ``TRANSITION_WINDOW_S`` of a switch between two contact segments inside a contact run."""
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    switches = np.flatnonzero(contact[1:] & contact[:-1] & (np.diff(tel.segment_index) != 0)) + 1
    near = np.zeros(len(tel), dtype=bool)
    for k in switches:
        near |= np.abs(tel.t - tel.t[k]) <= TRANSITION_WINDOW_S
    return near & steady


def _demonstrated_path(
    skill: Skill, segment: Segment, offset: NDArray[np.float64], demonstration: Demonstration | None, dt: float
) -> NDArray[np.float64]:
    """The demonstrated tool path of a contact segment (K, 3), shifted by the known offset (world, m)."""
    if demonstration is not None:
        a = demonstration.arrays()
        rows = (a.t >= segment.t_start - 1e-9) & (a.t <= segment.t_end + 1e-9)
        if rows.sum() >= 2:
            return a.positions[rows] + offset
    geo = contact_geometry(segment, offset)
    y = DMP.from_parameters(segment.position_dmp).rollout(dt).y
    if segment.position_dmp.frame == "cf":
        return geo.origins[0] + y[:, :2] @ geo.rotations[0][:, :2].T
    return y + offset


def _path_rms(
    skill: Skill,
    tel: Telemetry,
    offset: NDArray[np.float64],
    demonstration: Demonstration | None,
    dt: float,
) -> float | None:
    """RMS distance, in the motion subspace (CF x-y), of the executed contact path to the demonstrated one (m)."""
    from scipy.spatial import cKDTree

    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    if not contact.any():
        return None
    squared: list[NDArray[np.float64]] = []
    segs = {s.index: s for s in skill.segments}
    for index in np.unique(tel.segment_index[contact]):
        segment = segs[int(index)]
        rows = contact & (tel.segment_index == index)
        executed = tel.tool_position[rows]
        demo = _demonstrated_path(skill, segment, offset, demonstration, dt)
        geo = contact_geometry(segment, offset)
        if geo.t.size == 1:  # one CF: distances in its x-y plane
            R = geo.rotations[0]
            tree = cKDTree((demo - geo.origins[0]) @ R[:, :2])
            d, _ = tree.query((executed - geo.origins[0]) @ R[:, :2])
            squared.append(d**2)
        else:  # a CF series: nearest demonstrated point, error without its component along that point's CF z
            tree = cKDTree(demo)
            _, nearest = tree.query(executed)
            err = executed - demo[nearest]
            frac = nearest / max(len(demo) - 1, 1)
            z = geo.rotations_at(frac)[:, :, 2]
            err_tangent = err - np.sum(err * z, axis=1, keepdims=True) * z
            squared.append(np.sum(err_tangent**2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(squared))))


def _errors(error: NDArray[np.float64], reference: float, prefix: str) -> dict[str, float]:
    """RMS and largest absolute ``error`` (N), also in % of ``reference`` (N), as metric fields."""
    rms = float(np.sqrt(np.mean(error**2)))
    worst = float(np.max(np.abs(error)))
    fields = {f"{prefix}_rms_error_n": rms, f"{prefix}_max_error_n": worst}
    if reference > 0:
        fields[f"{prefix}_rms_error_pct"] = 100.0 * rms / reference
        fields[f"{prefix}_max_error_pct"] = 100.0 * worst / reference
    return fields


def used_cf_z(frame_log: list[tuple[int, float, float, float]], rows: int) -> NDArray[np.float64]:
    """The CF z the controller used at each of ``rows`` telemetry rows (rows, 3), world, from the executor's log of
    (first row, CF z) of every control frame it took; NaN before the first."""
    z = np.full((rows, 3), np.nan)
    if not frame_log:
        return z
    log = np.asarray(frame_log, dtype=float)
    starts = log[:, 0].astype(int)
    which = np.searchsorted(starts, np.arange(rows), side="right") - 1
    valid = which >= 0
    z[valid] = log[which[valid], 1:]
    return z


def exit_rows(skill: Skill, tel: Telemetry) -> NDArray[np.bool_]:
    """Rows of the free segments on the way out of a contact: after a contact segment, and not leading into another
    one (a free segment that leads into a contact may meet its surface early: a touch-down), with the retreat that
    backs off a hit there."""
    segments = skill.segments
    exits = [
        s.index
        for k, s in enumerate(segments)
        if s.kind is SegmentKind.free
        and any(p.kind is SegmentKind.contact for p in segments[:k])
        and not (k + 1 < len(segments) and segments[k + 1].kind is SegmentKind.contact)
    ]
    moving = np.isin(tel.phase_codes, [PHASE_CODES[ExecutionPhase.free], PHASE_CODES[ExecutionPhase.retreat]])
    return moving & np.isin(tel.segment_index, exits)


def _touchdowns(
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
    contact_starts = _run_starts(contact)
    debounce = max(1, round(TOUCHDOWN_DEBOUNCE_S / dt))
    free_before = np.convolve(~touching, np.ones(debounce), mode="full")[: len(tel)] >= debounce  # up to this row
    starts = np.flatnonzero(touching & ~steady & ~exits & np.r_[True, free_before[:-1]])
    steady_starts = _run_starts(steady)
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


REGION_SAMPLES = 501
"""A contour's taught normals are sampled this many times, evenly in time, for its region."""
CREASE_MIN_DEG = 15.0
"""A switch between contact segments whose taught normals differ by less than this is not held to its crease: a
normal learned from a short or an estimated-wrench recording can be that far off (docs/LEARNING.md), and a surface
within it of the taught one is pressed as taught (a flat table learned as two slides 8° apart is one surface), deg."""
PRESSED_NORMAL_WINDOW_S = 0.1
"""A touch-down's and a contact's final normal are the mean normal pressed over this long, s."""
CREASE_SIDE_S = 0.2
"""Across a switch between contact segments, the normal pressed on either side is the mean over a slide's rows
outside the transition window, or over this long of a contour's next to that window, s."""


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


@dataclass
class ExecutionLog:
    """What the executor knows beyond the telemetry rows: where each guarded approach found the surface, the
    control frames it took and the contact guard of its last approach."""

    contact_offsets_m: list[float] = field(default_factory=list)
    """Per guarded approach: the surface found along +CF z from where it was taught, m."""
    frame_log: list[tuple[int, float, float, float]] = field(default_factory=list)
    """(first telemetry row, CF z) of every control frame the controller took."""
    contact_guard: ContactGuard | None = None
    relocations_m: list[list[float]] = field(default_factory=list)
    """Per contour relocated where its touch-down found the part, the part's move (m, world)."""
    unconfirmed_relocations_m: list[list[float]] = field(default_factory=list)
    """Per move of the part a touch-down suggested and a second touch did not confirm (m, world): not relocated."""
    surface_window_m: float = 0.02
    """How far from where it was taught a surface may be found, m."""
    work_piece: str | None = None
    """Where the world's work piece came from, when it was resolved for the skill (``ExecutionWorld.source``)."""
    next_surface_found: dict[int, bool] = field(default_factory=dict)
    """Following the surface: per contact segment entered across a crease, whether the next surface was met."""


def _bounded_check(name: VerdictCheckName, value: float | None, limit: float, what: str, upper: bool) -> VerdictCheck:
    """``value`` held to ``limit`` (at most, or at least with ``upper`` False); None: not measured, failed."""
    if value is None:
        return VerdictCheck(name=name, passed=False, limit=limit, message=f"{what}: not measured")
    passed = value <= limit if upper else value >= limit
    relation = ("≤" if passed else ">") if upper else ("≥" if passed else "<")
    message = f"{what} {value:.3g} {relation} {limit:.3g}"
    return VerdictCheck(name=name, passed=passed, value=value, limit=limit, message=message)


def execution_verdict(
    metrics: ExecutionMetrics,
    tolerances: ExecutionTolerances,
    log: ExecutionLog,
    contact_expected: bool,
    skill_failed: list[SkillCheck] | None = None,
) -> ExecutionVerdict:
    """Pass or fail: ``metrics`` against ``tolerances``; a surface found outside its window is a warning. A skill with
    a contact segment that ran to its end without a measured steady contact fails (nothing was pressed); an aborted
    run fails on that alone (its other checks are listed where they were measured). The skill's own failed checks
    (``skill_failed``) are a warning, and fail the verdict where the work piece carries their finding
    (:func:`_skill_checks_check`)."""
    finished = metrics.phase is ExecutionPhase.done
    reason = "ran every segment" if finished else f"{metrics.phase.value}: {metrics.abort_reason}"
    checks = [VerdictCheck(name=VerdictCheckName.finished, passed=finished, message=reason)]
    t, m, name = tolerances, metrics, VerdictCheckName
    bounds = [  # name, value, limit, what, upper bound
        (name.true_force_rms, m.true_force_rms_error_pct, t.true_force_rms_pct, "true force RMS error %", True),
        (name.true_force_max, m.true_force_max_error_pct, t.true_force_max_pct, "true force max error %", True),
        (name.contact_ratio, m.contact_ratio, t.contact_ratio, "contact ratio", False),
        (name.touchdown, m.touchdown_peak_ratio, t.touchdown_ratio, "touch-down peak / target", True),
    ]
    for check, value, limit, what, upper in bounds:
        due = contact_expected and finished and check is not name.touchdown  # a run that pressed must measure it
        if value is not None or due:
            checks.append(_bounded_check(check, value, limit, what, upper))
    touchdown = next((c for c in checks if c.name is name.touchdown), None)
    if touchdown is not None and m.touchdown_contact_force_ratio is not None:
        asked = m.touchdown_contact_force_ratio
        touchdown.message += f" (target: the press that followed; over the force asked at contact: {asked:.3g})"
    checks += _where_pressed_checks(m, t)
    if m.exit_collision_n is not None:
        message = (
            f"exit collision: on the way out of the contact the tool hit the part at {m.exit_collision_n:.1f} N (the "
            "way out, as taught from where the contact ended, runs into the part where it is now)"
        )
        checks.append(
            VerdictCheck(name=name.exit_collision, passed=False, value=m.exit_collision_n, limit=0.0, message=message)
        )
    if log.work_piece in (WorkPieceSource.measured, WorkPieceSource.rebuilt):
        if log.work_piece == WorkPieceSource.measured:
            basis = "measured from the skill's own recording: the run confirms that recording"
        else:
            basis = "rebuilt from what the skill learned: the run confirms the skill with itself"
        message = (
            f"judged on a work piece {basis}, not the skill on the real part (run it on a work piece of known shape, "
            "such as its CAD, to judge that)"
        )
        checks.append(VerdictCheck(name=name.judged_on, passed=False, warning_only=True, message=message))
    if log.contact_offsets_m:
        worst = max(log.contact_offsets_m, key=abs)
        inside = abs(worst) <= log.surface_window_m
        window = f"{'within' if inside else 'outside'} ±{log.surface_window_m * 1e3:.0f} mm"
        message = f"surface found {worst * 1e3:+.1f} mm from where it was taught ({window})"
        checks.append(
            VerdictCheck(
                name=name.surface_found,
                passed=inside,
                warning_only=True,
                value=worst,
                limit=log.surface_window_m,
                message=message,
            )
        )
    for move in log.relocations_m:
        checks.append(
            _relocation_check(
                move,
                "contour relocated: its touch-down, and a second touch there, pressed on a normal taught elsewhere on "
                "its path, so the part was taken as moved by ({}) mm and the contour ran there",
            )
        )
    for move in log.unconfirmed_relocations_m:
        checks.append(
            _relocation_check(
                move,
                "a touch-down pressed on a normal taught elsewhere on the contour (the part moved by ({}) mm?), a "
                "second touch there did not confirm it: not relocated",
            )
        )
    if m.true_force_in_band is not None:
        judged = t.force_in_band is not None
        limit = t.force_in_band if judged else IN_BAND_SHARE
        passed = m.true_force_in_band >= limit
        message = (
            f"true force within the demonstrated band for {100 * m.true_force_in_band:.0f} % of the contact "
            f"({'≥' if passed else '<'} {100 * limit:.0f} %)"
        )
        checks.append(
            VerdictCheck(
                name=name.force_in_band,
                passed=passed,
                warning_only=not judged,
                value=m.true_force_in_band,
                limit=limit,
                message=message,
            )
        )
    if skill_failed:
        checks.append(_skill_checks_check(skill_failed, log.work_piece))
    failed = [c.message for c in checks if not c.passed and not c.warning_only]
    warnings = [c.message for c in checks if not c.passed and c.warning_only]
    verdict = Verdict.failed if failed else Verdict.passed
    return ExecutionVerdict(verdict=verdict, reasons=failed, warnings=warnings, checks=checks)


def _relocation_check(move: list[float], message: str) -> VerdictCheck:
    """The warning of a contour's part found moved by ``move`` (m, world), ``message`` holding ``{}`` for it in mm."""
    where = ", ".join(f"{v * 1e3:+.0f}" for v in move)
    return VerdictCheck(
        name=VerdictCheckName.not_relocated,
        passed=False,
        warning_only=True,
        value=float(np.linalg.norm(move)),
        limit=0.0,
        message=message.format(where),
    )


def _crease_not_met(s: SurfacePressed) -> bool:
    """Across the switch into ``s``'s segment, a taught crease of at least ``CREASE_MIN_DEG`` turned the normal
    pressed less than half its way."""
    if s.crease_deg is None or s.crease_turn_deg is None or s.crease_deg < CREASE_MIN_DEG:
        return False
    return s.crease_turn_deg < 0.5 * s.crease_deg


def _where_pressed_checks(m: ExecutionMetrics, t: ExecutionTolerances) -> list[VerdictCheck]:
    """The checks of where each contact segment pressed (``m.surfaces_pressed``): its touch-down and final normals
    within ``t.normal_cone_deg`` of the taught ones and a crease met as taught (within half its angle) — one
    ``surface_pressed`` check per segment —, a contour's taught region covered (``region_covered``), and, following
    the surface, every next surface met (``next_surface``)."""
    name, checks = VerdictCheckName, []
    for s in m.surfaces_pressed:
        where = f"segment {s.segment}"
        problems = [
            f"its {when} normal lies {angle:.0f}° from the taught one (beyond the {t.normal_cone_deg:.0f}° friction "
            "cone: another surface or another place of the part)"
            for when, angle in (("touch-down", s.touchdown_normal_error_deg), ("final", s.final_normal_error_deg))
            if angle > t.normal_cone_deg
        ]
        worst = max(s.touchdown_normal_error_deg, s.final_normal_error_deg)
        if _crease_not_met(s):
            problems.append(
                f"across the switch the normal pressed turned {s.crease_turn_deg:.0f}° where the taught crease turns "
                f"it {s.crease_deg:.0f}° (less than half): the next surface is not where it was taught, or not there"
            )
        message = f"{where} pressed the surface it was taught on (normals within {worst:.0f}° at touch-down and end)"
        if problems:
            message = f"{where}: " + "; ".join(problems)
        checks.append(
            VerdictCheck(
                name=name.surface_pressed, passed=not problems, value=worst, limit=t.normal_cone_deg, message=message
            )
        )
        if s.region_coverage is not None and s.taught_region_deg and s.pressed_region_deg:
            covered = s.region_coverage >= t.region_coverage
            (a, b), (c, d) = s.pressed_region_deg, s.taught_region_deg
            message = (
                f"{where} pressed normals over {a:+.0f}..{b:+.0f}° of the {c:+.0f}..{d:+.0f}° it was taught on: "
                f"{100 * s.region_coverage:.0f} % of its region {'≥' if covered else '<'} "
                f"{100 * t.region_coverage:.0f} %"
            )
            checks.append(
                VerdictCheck(
                    name=name.region_covered,
                    passed=covered,
                    value=s.region_coverage,
                    limit=t.region_coverage,
                    message=message,
                )
            )
        if s.next_surface_found is False:  # the extension past the taught crease ran out before it was met
            missed = _crease_not_met(s)
            if missed:
                message = (
                    f"next surface not found: segment {s.segment}'s surface ({s.crease_deg or 0:.0f}° from the "
                    "previous one) was never met, not past the taught crease nor after it"
                )
            else:
                message = (
                    f"segment {s.segment}'s surface was met only after the extension past the taught crease ran out "
                    f"(the normal then turned {s.crease_turn_deg or 0:.0f}° of the taught {s.crease_deg or 0:.0f}°): "
                    "the crease is farther than taught"
                )
            checks.append(VerdictCheck(name=name.next_surface, passed=False, warning_only=not missed, message=message))
    return checks


def _skill_checks_check(failed: list[SkillCheck], work_piece: str | None) -> VerdictCheck:
    """The verdict's check of the skill's own ``failed`` checks against its demonstration: a warning, or a failure
    where the work piece carries what they found wrong, so that the run would confirm it: one rebuilt from what the
    skill learned (every check), or one measured from its demonstration (the checks of the recording itself,
    ``skill_checks.RECORDING_CHECKS``)."""
    names = ", ".join(dict.fromkeys(c.name.value for c in failed))
    message = f"the skill fails {len(failed)} of its checks against its demonstration ({names}): {failed[0].message}"
    if work_piece == WorkPieceSource.rebuilt:
        carried = "was rebuilt from what the skill learned"
    elif work_piece == WorkPieceSource.measured and any(c.name in skill_checks.RECORDING_CHECKS for c in failed):
        carried = "was measured from the same recording"
    else:
        carried = None
    if carried is not None:
        message += (
            f"; this work piece {carried}, so the run cannot show it wrong (fix the recording's import, or run the "
            "skill on a work piece of known shape)"
        )
    return VerdictCheck(
        name=VerdictCheckName.skill_checks,
        passed=False,
        warning_only=carried is None,
        value=float(len(failed)),
        limit=0.0,
        message=message,
    )


def _true_force_in_band(skill: Skill, tel: Telemetry, contact: NDArray[np.bool_]) -> float | None:
    """The share of the contact phase of the segments with a force band (`Segment.force_band`) whose true normal
    force lies within it, each segment's contact aligned to its band by the tool's path
    (`skills.joint_learning.share_in_band`); None where no segment has a band or ran in contact."""
    runs = []
    for segment in skill.segments:
        rows = contact & (tel.segment_index == segment.index)
        if segment.force_band is not None and rows.sum() >= 2:
            runs.append((segment.force_band, tel.tool_position[rows], tel.normal_force_true[rows]))
    return share_in_band(runs) if runs else None


def compute_metrics(
    skill: Skill,
    tel: Telemetry,
    settings: ExecutionSettings,
    phase: ExecutionPhase,
    abort_reason: str | None,
    loop_wall_s: float,
    log: ExecutionLog,
    demonstration: Demonstration | None = None,
    dt: float = 1e-3,
) -> ExecutionMetrics:
    """The measures of one execution (see ``schemas.execution.ExecutionMetrics``) from its recorded telemetry and the
    executor's ``log``, with its verdict against ``settings.tolerances``."""
    reference = reference_force(skill, dt)
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    steady = _steady_mask(tel, settings.gains.force_ramp_s)
    offset = np.asarray(settings.environment.offset, float)
    metrics: dict = {}
    if steady.any():
        desired = tel.desired_force[steady]
        metrics |= _errors(tel.wrench_cf[steady, 2] - desired, reference, "force")
        metrics |= _errors(tel.normal_force_true[steady] - desired, reference, "true_force")
        transition = _transition_mask(tel, steady)
        if transition.any():
            worst = _errors(tel.normal_force_true[transition] - tel.desired_force[transition], reference, "t")
            metrics["transition_true_force_max_error_n"] = worst["t_max_error_n"]
            if "t_max_error_pct" in worst:
                metrics["transition_true_force_max_error_pct"] = worst["t_max_error_pct"]
    if contact.any():
        metrics["contact_ratio"] = float(np.mean(tel.in_contact[contact]))
        metrics["path_rms_m"] = _path_rms(skill, tel, offset, demonstration, dt)
        touching = contact & (tel.normal_force_true > 0.0)
        if touching.any():
            cf_z = used_cf_z(log.frame_log, len(tel))[touching]
            cosine = np.clip(np.sum(cf_z * tel.contact_normal[touching], axis=1), -1.0, 1.0)
            angles = np.degrees(np.arccos(cosine))
            metrics |= {"cf_normal_angle_deg": float(angles.mean()), "cf_normal_angle_max_deg": float(angles.max())}
    in_band = _true_force_in_band(skill, tel, contact)
    if in_band is not None:
        metrics["true_force_in_band"] = in_band
    exits = exit_rows(skill, tel)
    metrics |= _touchdowns(tel, steady, exits, reference, dt)
    if (exits & (tel.normal_force_true > 0.0)).any():
        metrics["exit_collision_n"] = float(tel.normal_force_true[exits].max())
    surfaces = surfaces_pressed(skill, tel, offset, log.next_surface_found)
    if log.contact_guard is not None:
        metrics["contact_threshold_n"] = log.contact_guard.threshold_n
        metrics["contact_persistence_steps"] = log.contact_guard.window_steps
    duration = float(len(tel) * dt)
    forces = np.linalg.norm(tel.wrench_world[:, :3], axis=1) if len(tel) else np.zeros(1)
    result = ExecutionMetrics(
        controller=ControllerKind(settings.controller),
        phase=phase,
        force_reference_n=reference if reference > 0 else None,
        real_time_factor=duration / loop_wall_s if loop_wall_s > 0 else 0.0,
        duration_s=duration,
        steps=len(tel),
        peak_force_n=float(forces.max()),
        contact_found_offsets_m=log.contact_offsets_m,
        contour_relocations_m=log.relocations_m,
        steady_contact_s=float(steady.sum() * dt),
        surfaces_pressed=surfaces,
        abort_reason=abort_reason,
        **metrics,
    )
    contact_expected = any(s.kind is SegmentKind.contact for s in skill.segments)
    skill_failed = [c for c in skill.checks if not c.passed]
    result.verdict = execution_verdict(result, settings.tolerances, log, contact_expected, skill_failed)
    return result


def combined_stroke_metrics(strokes: list[ExecutionMetrics]) -> ExecutionMetrics:
    """The metrics of one execution run one stroke at a time (``strokes``, each its own run, in order): time, steps and
    real-time factor over all of them; each RMS error over their steady contact together (weighted by its length);
    the largest max error, touch-down, exit collision and CF angle; the contact ratio and mean CF angle weighted by
    steady contact; every stroke's surfaces pressed, in order; the first phase and abort reason that is not ``done``;
    a verdict that fails when one stroke's fails (its reasons prefixed with the stroke). ``strokes`` keeps each one's
    own metrics."""
    if len(strokes) == 1:
        return strokes[0]
    weights = np.array([m.steady_contact_s for m in strokes])

    def rms(name: str) -> float | None:
        values = [getattr(m, name) for m in strokes]
        if any(v is None for v in values) or weights.sum() <= 0:
            return None
        return float(np.sqrt(np.sum(weights * np.square(values)) / weights.sum()))

    def largest(name: str) -> float | None:
        values = [getattr(m, name) for m in strokes if getattr(m, name) is not None]
        return max(values) if values else None

    ended = next((m for m in strokes if m.phase is not ExecutionPhase.done), strokes[-1])
    duration = sum(m.duration_s for m in strokes)
    wall = sum(m.duration_s / m.real_time_factor for m in strokes if m.real_time_factor > 0)
    fields = {
        name: rms(name)
        for name in ("force_rms_error_n", "force_rms_error_pct", "true_force_rms_error_n", "true_force_rms_error_pct")
    }
    fields |= {
        name: largest(name)
        for name in (
            "force_max_error_n", "force_max_error_pct", "true_force_max_error_n", "true_force_max_error_pct",
            "force_reference_n", "touchdown_peak_n", "touchdown_peak_ratio", "settle_time_s",
            "cf_normal_angle_max_deg", "transition_true_force_max_error_n", "transition_true_force_max_error_pct",
            "contact_threshold_n", "contact_persistence_steps", "touchdown_contact_force_ratio", "exit_collision_n",
        )
    }  # fmt: skip
    for name in (
        "contact_ratio",
        "cf_normal_angle_deg",
        "true_force_in_band",
    ):  # shares and means: weighted by steady contact
        values = [getattr(m, name) for m in strokes]
        if all(v is not None for v in values) and weights.sum() > 0:
            fields[name] = float(np.sum(weights * np.asarray(values)) / weights.sum())
    reasons = [f"stroke {k + 1}: {r}" for k, m in enumerate(strokes) if m.verdict for r in m.verdict.reasons]
    warnings = [f"stroke {k + 1}: {w}" for k, m in enumerate(strokes) if m.verdict for w in m.verdict.warnings]
    verdict = ExecutionVerdict(
        verdict=Verdict.failed if reasons else Verdict.passed,
        reasons=reasons,
        warnings=warnings,
        checks=[c for m in strokes if m.verdict for c in m.verdict.checks],
    )
    return ExecutionMetrics(
        controller=strokes[0].controller,
        phase=ended.phase,
        abort_reason=ended.abort_reason,
        real_time_factor=duration / wall if wall > 0 else 0.0,
        duration_s=duration,
        steps=sum(m.steps for m in strokes),
        peak_force_n=max(m.peak_force_n for m in strokes),
        contact_found_offsets_m=[o for m in strokes for o in m.contact_found_offsets_m],
        contour_relocations_m=[o for m in strokes for o in m.contour_relocations_m],
        surfaces_pressed=[s for m in strokes for s in m.surfaces_pressed],
        steady_contact_s=float(weights.sum()),
        work_piece=strokes[0].work_piece,
        verdict=verdict,
        strokes=strokes,
        **{name: value for name, value in fields.items() if value is not None},
    )
