"""An execution's verdict: its metrics (``schemas.execution.ExecutionMetrics``) and the executor's log against the
tolerances (``schemas.verdict.ExecutionTolerances``), one ``VerdictCheck`` per thing judged. Angles in deg, forces as
ratios or % of the reference force."""

from __future__ import annotations

import numpy as np

from execution.execution_log import ExecutionLog
from schemas.execution import ExecutionMetrics, ExecutionPhase, WorkPieceSource
from schemas.skill import IN_BAND_SHARE, SkillCheck
from schemas.verdict import (
    ExecutionTolerances,
    ExecutionVerdict,
    SurfacePressed,
    Verdict,
    VerdictCheck,
    VerdictCheckName,
)
from skills import recording_faults

CREASE_MIN_DEG = 15.0
"""A switch between contact segments whose taught normals differ by less than this is not held to its crease: a
normal learned from a short or an estimated-wrench recording can be that far off (docs/LEARNING.md), and a surface
within it of the taught one is pressed as taught (a flat table learned as two slides 8° apart is one surface), deg."""


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
    ``recording_faults.RECORDING_CHECKS``)."""
    names = ", ".join(dict.fromkeys(c.name.value for c in failed))
    message = f"the skill fails {len(failed)} of its checks against its demonstration ({names}): {failed[0].message}"
    if work_piece == WorkPieceSource.rebuilt:
        carried = "was rebuilt from what the skill learned"
    elif work_piece == WorkPieceSource.measured and any(c.name in recording_faults.RECORDING_CHECKS for c in failed):
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
