"""What a demo run writes: why a target was missed (from what was measured) and RESULTS.md; its tables are
``experiments.report_tables``, its figures ``experiments.report_figures``.

Every force figure is shown twice: the TRUE normal force (the simulator's contact force along the true surface
normal, what the work piece feels; the targets are judged on it) and the CF-z force (along the learned compliant
frame: the controller's view). Every sentence about a number is computed from the run."""

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path

from experiments.cases import (
    BASELINE_FACTOR,
    FAIR_IMPEDANCE,
    FIGURE_NAMES,
    KULEUVEN_FORM,
    OURS,
    PAPER_CONTROLLERS,
    TARGETS,
    Case,
    DemoOptions,
    DemoReport,
    Outcome,
    counted,
    fmt,
)
from experiments.contour_stress import RESULTS_SECTION
from experiments.cross_engine import CROSS_ENGINE_SECTION
from experiments.report_figures import applied_placement
from experiments.report_tables import markdown_table
from experiments.sweep import SWEEPS_SECTION
from services.machine import machine_line

# --------------------------------------------------------------------------------------------------- why


def _impedance_stiffness() -> float:
    """CF-z stiffness of the default gains (the demo sends none), N/m."""
    from schemas.execution import ControllerGains

    return float(ControllerGains().translational_stiffness_n_per_m[2])


def _steady_delay_s() -> float:
    """Where the steady contact the force errors cover starts after contact with the default gains, s."""
    from execution.metrics import STEADY_CONTACT_DELAY_S
    from schemas.execution import ControllerGains

    return max(STEADY_CONTACT_DELAY_S, ControllerGains().force_ramp_s)


def _ours(outcomes: list[Outcome], case: Case) -> Outcome | None:
    return next((o for o in outcomes if o.case == case and o.controller == OURS), None)


def _found_text(o: Outcome) -> str:
    """Where the guarded approach found the surface, as measured (``+10.0 mm``), or '' if it reported none."""
    found = (o.metrics or {}).get("contact_found_offsets_m") or []
    return ", ".join(f"{1e3 * v:+.1f} mm" for v in found)


def _against_ours(o: Outcome, outcomes: list[Outcome]) -> str:
    """``1.7x (true 1.79 % vs 1.05 %)``: the baseline's ratio and both figures it is computed from."""
    mine = _ours(outcomes, o.case)
    figure = FIGURE_NAMES[o.judged_figure()]
    ours = fmt(mine.rms()) if mine is not None else "—"
    ratio = f"{o.ratio:.1f}x" if o.ratio is not None else "no ratio"
    return f"{ratio} ({figure} {fmt(o.rms())} % vs {ours} %)"


def _shifted_text(o: Outcome, outcomes: list[Outcome]) -> str:
    """A baseline row with an unknown shift: its ratio to ours (or how it ended) and where the guarded approach
    found the surface."""
    found = _found_text(o)
    where = f" (surface found {found} from where it was taught)" if found else ""
    if o.ratio is None:
        return o.final + where
    return f"{_against_ours(o, outcomes)}{_ended(o)}{where}"


def _ended(o: Outcome) -> str:
    """``, then aborted (...)`` for a scored row that did not end done, '' otherwise."""
    return f", then {o.final}" if o.final != "done" else ""


def explanations(outcomes: list[Outcome]) -> list[str]:
    """Why each missed target row missed, from what was measured (one paragraph per baseline and skill, or row)."""
    notes = []
    k = _impedance_stiffness()
    grouped: dict[str, list[Outcome]] = {}
    for o in outcomes:
        if o.met is False and o.controller == "impedance" and not o.case.unknown_shift and o.ratio is not None:
            grouped.setdefault(o.case.skill, []).append(o)
    for rows in grouped.values():
        spec = rows[0].case.spec
        listed = "; ".join(f"{o.case.label}: {_against_ours(o, outcomes)}{_ended(o)}" for o in rows)
        reference = rows[0].metric("force_reference_n") or 0.0
        known = any(any(o.case.offset) for o in rows)
        where = "a KNOWN offset (the skill moves with the work piece)" if known else "the taught geometry"
        better = min(o.ratio or 0.0 for o in rows) > 1.0
        text = (
            f"**impedance, {spec.title} — {listed}.** Pure impedance (S = I, no force loop) presses only through "
            f"its reference, placed f/k = {reference:.1f} N"
            f"{' (the profile peak)' if spec.skill_type == 'contour' else ''} / {k:.0f} N/m = "
            f"{1e3 * reference / k:.1f} mm beyond the surface where the skill expects it. With {where} the surface "
            "is exactly there, so its force error is only its position error along CF z times the stiffness "
            f"({k:.0f} N/m: 0.1 mm is {0.1e-3 * k:.1f} N); "
            + (
                f"ours is better in every such case (it closes a force loop), but not {BASELINE_FACTOR:g}x."
                if better
                else "ours is not better in every such case."
            )
        )
        notes.append(text)
    explained = {id(r) for rows in grouped.values() for r in rows}
    for o in outcomes:
        if o.met is not False or id(o) in explained:
            continue
        mine = _ours(outcomes, o.case)
        notes.append(
            f"**{o.controller}, {o.case.spec.title}, {o.case.label}: {o.target_text}** — measured force RMS "
            f"{o.rms_text()}"
            + (f" (ours {mine.rms_text()})" if mine is not None and mine is not o else "")
            + f", max true {fmt(o.metric('true_force_max_error_pct'))} % / CF-z "
            f"{fmt(o.metric('force_max_error_pct'))} %, contact {fmt(o.metric('contact_ratio'), 100)} %, "
            f"final {o.final}."
        )
    return notes


def like_with_like(outcomes: list[Outcome], traces: dict) -> list[str]:
    """For each skill where the work piece moved WITHOUT telling the controller: ``impedance`` (its reference at
    the taught surface) beside ``impedance_found_surface`` (re-based where the guarded approach found it) in the
    same cases, and ``impedance`` at the taught geometry: the ratios that compare the control laws and those that
    only measure the missing re-referencing."""
    notes = []
    for skill in dict.fromkeys(o.case.skill for o in outcomes):
        rows = [o for o in outcomes if o.controller in ("impedance", FAIR_IMPEDANCE) and o.case.skill == skill]
        shifted_cases = list(dict.fromkeys(o.case for o in rows if o.case.unknown_shift))
        if not shifted_cases:
            continue
        taught = [o for o in rows if not o.case.unknown_shift]
        text = f"**{shifted_cases[0].spec.title}**: "
        if taught:
            text += "at the taught geometry, impedance " + "; ".join(
                f"{_against_ours(o, outcomes)}{_ended(o)} ({o.case.label})" for o in taught
            )
            text += ". "
        text += "With an UNKNOWN shift: " + "; ".join(
            f"{case.label}: "
            + ", ".join(f"{o.controller} {_shifted_text(o, outcomes)}" for o in rows if o.case == case)
            for case in shifted_cases
        )
        fair = [o for o in rows if o.controller == FAIR_IMPEDANCE and o.case.unknown_shift]
        text += (
            ". `impedance` keeps its reference at the TAUGHT surface after the guarded approach found the moved "
            f"one, so its shifted ratios measure the missing re-referencing; like with like, `{FAIR_IMPEDANCE}` "
            "(re-based at the found surface) is the classical baseline there"
        )
        if fair and all(o.ratio is not None for o in fair):
            text += (
                f": ours is {_span([o.ratio for o in fair], 1, 'x')} better"
                if min(o.ratio for o in fair) > 1.0
                else f": it is {_span([o.ratio for o in fair], 1, 'x')} ours, not worse in every case"
            )
        drifts = [_drift_text(o, traces[(o.case, o.controller)]) for o in fair if (o.case, o.controller) in traces]
        drifts = [d for d in drifts if d]
        if drifts:
            text += ". Where it is far worse, its CF-z force error " + "; ".join(drifts)
        notes.append(text + ".")
    return notes


def _drift_text(o: Outcome, trace) -> str:
    """For a baseline at least :data:`BASELINE_FACTOR` times ours: its mean CF-z force error over the first and
    the last fifth of its contact phase (from its telemetry), and whether it grew along the stroke; '' otherwise."""
    import numpy as np

    contact = trace.mask("contact")
    error = (trace.wrench_cf[:, 2] - trace.desired)[contact]
    if o.ratio is None or o.ratio < BASELINE_FACTOR or error.size < 10:
        return ""
    fifth = error.size // 5
    first, last = float(np.mean(error[:fifth])), float(np.mean(error[-fifth:]))
    grew = abs(last) > 2.0 * abs(first)
    return (
        f"{'grows along the stroke: ' if grew else 'is '}{first:+.1f} N over the first fifth of the contact, "
        f"{last:+.1f} N over the last ({o.case.label})"
        + (", so its re-basing at touch-down does not carry along the path" if grew else "")
    )


def observations(outcomes: list[Outcome]) -> list[str]:
    """Rows without a target that did not finish or lost contact, with the arithmetic of why (impedance)."""
    notes = []
    k = _impedance_stiffness()
    for o in outcomes:
        contact = o.metric("contact_ratio")
        enough = TARGETS[o.case.group].min_contact
        if o.met is not None or (o.status == "done" and (contact is None or contact >= enough)):
            continue
        what = f"**{o.controller}, {o.case.spec.title}, {o.case.label}**: "
        what += f"contact {fmt(contact, 100)} %" if o.status == "done" else o.final
        dz = o.case.unknown_offset[2]
        mine = _ours(outcomes, o.case)
        reference = (mine.metric("force_reference_n") if mine is not None else None) or 0.0
        if o.controller == "impedance" and o.case.skill == "slide_flat" and dz:
            depth = reference / k
            found = _found_text(o)
            approach = f"the guarded approach found the table {found} from where it was taught" if found else ""
            if dz < 0:
                what += (
                    f" — the table is {100 * -dz:g} cm lower than taught and the impedance reference lies only "
                    f"f/k = {1e3 * depth:.0f} mm below the TAUGHT surface: the tool never presses"
                    + (f" ({approach}, but this baseline keeps the taught height)." if approach else ".")
                )
            else:
                what += (
                    f" — the table is {100 * dz:g} cm higher than taught: the reference lies {100 * dz:g} cm + "
                    f"{1e3 * depth:.0f} mm inside it, k·Δ ≈ {k * (dz + depth):.0f} N wanted"
                    + (" (the force limit aborts it)." if o.status == "aborted" else ".")
                )
        notes.append(what)
    return notes


def _turn_deg(quaternion: list[float]) -> float:
    """The angle of the rotation a unit quaternion [x, y, z, w] stands for, deg."""
    norm = math.sqrt(sum(v * v for v in quaternion))
    return math.degrees(2.0 * math.acos(min(1.0, abs(quaternion[3]) / norm)))


def _work_piece_text(outcomes: list[Outcome], case: Case) -> str:
    """What the worker reported it ran ``case`` on: the work piece and the placement applied."""
    sources = {str((o.metrics or {}).get("work_piece")) for o in outcomes if o.case == case and o.metrics}
    text = ", ".join(sorted(sources - {"None"})) or "—"
    placement = applied_placement(outcomes, case)
    if placement is not None:
        t = ", ".join(f"{v:+.3f}" for v in placement.translation_m)
        text += (
            f"; placed: translation ({t}) m, rotated {_turn_deg(placement.rotation):.0f}°, tool frame turned "
            f"{_turn_deg(placement.tool_alignment):.0f}°"
        )
    return text


# --------------------------------------------------------------------------------------------------- RESULTS.md


def _vec_cm(v: tuple[float, float, float]) -> str:
    return "(" + ", ".join(f"{100 * x:+g}" for x in v) + ") cm"


def _span(values: list[float], digits: int = 2, unit: str = " %") -> str:
    """``1.20-3.40 %`` (or one value) over ``values``."""
    if not values:
        return "—"
    low, high = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return f"{low}{unit}" if low == high else f"{low}-{high}{unit}"


def _values(rows: list[Outcome], name: str, scale: float = 1.0) -> list[float]:
    return [scale * v for v in (o.metric(name) for o in rows) if v is not None]


def real_data_summary(report: DemoReport) -> list[str]:
    """The paragraph before the real recordings' table: how they were taught and what ours and the baselines
    measured on them (every number from the run)."""
    rows = [o for o in report.outcomes if o.case.group == "real"]
    skills = [report.skills[k] for k in dict.fromkeys(o.case.skill for o in rows)]
    chosen = sorted({learned.skill.skill_type.value for learned in skills})
    confidences = [s.skill.auto_selection.confidence for s in skills if s.skill.auto_selection is not None]
    ours = [o for o in rows if o.controller == OURS]
    text = (
        f"{counted(len(skills), 'real human contour-following demonstration')} (KU Leuven, "
        "`data/kuleuven_contour`, MIT licence), each uploaded as a user would (`POST /demonstrations/csv` with "
        + ", ".join(f"`{k}={v}`" for k, v in KULEUVEN_FORM.items())
        + ") and learned with `skill_type` auto (chosen: "
        f"{', '.join(chosen)}"
        + (f", confidence {_span(confidences, unit='')}" if confidences else "")
        + "). A real recording carries no world: the worker builds the work piece from what the recording measured "
        "(its contact points and friction-free force normals, not what the skill learned) and places skill and work "
        "piece together in the robot's reach (the placement is in the cases table). What that piece itself adds to "
        "the error, its floor on a flat surface against the ideal table, is measured by "
        "`benchmarks/bench_work_piece.py` (docs/LEARNING.md, section 10); a curved crease like these is held by "
        "several convex hulls, whose seams add to the max."
    )
    if ours:
        text += (
            f" Ours: true normal force RMS error {_span(_values(ours, 'true_force_rms_error_pct'))} of the "
            f"profile's peak (CF-z, the controller's view: {_span(_values(ours, 'force_rms_error_pct'))}), contact "
            f"{_span(_values(ours, 'contact_ratio', 100))}, touch-down peak "
            f"{_span(_values(ours, 'touchdown_peak_ratio'), unit='x')} the first target, CF z a mean "
            f"{_span(_values(ours, 'cf_normal_angle_deg'), 1, '°')} from the measured surface's normal."
        )
    for controller in PAPER_CONTROLLERS[1:]:
        theirs = [o for o in rows if o.controller == controller and o.ratio is not None]
        if theirs:
            figure = FIGURE_NAMES[theirs[0].judged_figure()]
            text += (
                f" {controller}: {_span([o.ratio for o in theirs], 1, 'x')} ours in {figure} force RMS error on the "
                f"same trials ({figure} {_span([o.rms() for o in theirs if o.rms() is not None])})."
            )
    return [text]


def results_markdown(options: DemoOptions, report: DemoReport) -> str:
    """The text of RESULTS.md."""
    outcomes = report.outcomes
    now = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    n_exec = len(outcomes)
    t = report.timings
    met = sum(v.met for v in report.verdicts)
    teacher = [o for o in outcomes if o.case.group != "real"]
    real = [o for o in outcomes if o.case.group == "real"]
    lines = [
        "# Results: the paper's experiments and real recordings, end to end",
        "",
        "The experiments of section 6 of Origanti, Eiband & Lee (slide, Fig. 3; contour, Fig. 4), and skills "
        "learned from real human demonstrations (the KU Leuven contour recordings), run through the service the "
        "way a user drives it: the scripted teacher records each demonstration on a sim worker "
        "(`POST /demonstrations/record`) or a recording is uploaded (`POST /demonstrations/csv`), the service "
        "learns the skill (`POST /skills`), and every trial runs on the sim workers (`POST /executions`, pace "
        "fast, concurrently) with our controller and both baselines; live phases come over Zenoh "
        "(`cskills/exec/*/status`), metrics and telemetry over REST.",
        "",
        f"Regenerate: `{options.command}`" + (" (reduced case set)" if options.quick else ""),
        "",
        f"Generated {now} against {report.service}. {machine_line()}",
        "",
        f"Timings (wall): {n_exec} executions in {t.get('executions', 0):.1f} s; service start "
        f"{t.get('service start', 0):.1f} s, demonstrations + learning {t.get('demonstrations + learning', 0):.1f} "
        f"s, telemetry fetch {t.get('telemetry fetch', 0):.1f} s, figures {t.get('figures', 0):.1f} s; total "
        f"{t.get('total', 0):.1f} s.",
        "",
        "## Cases",
        "",
        f"Teacher seed {options.seed}. Controllers: `hybrid_cf` (ours, paper eq. 1-4: force control along the "
        "compliant frame's z), `impedance` (pure Cartesian impedance, the reference pushed f/k into the TAUGHT "
        "surface; it keeps that reference when the guarded approach finds the surface elsewhere), "
        "`hybrid_world_z` (force control fixed to world z, as in earlier work) and, where the work piece moved "
        f"without telling the controller, `{FAIR_IMPEDANCE}` (the same impedance law re-based where the guarded "
        "approach found the surface: the fair classical baseline there; no target).",
        "",
        "| skill (learned from) | case | known offset (moves skill and world) | unknown offset (world only) "
        "| work piece (as the worker reported) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for case in dict.fromkeys(o.case for o in outcomes):
        learned = report.skills[case.skill]
        lines.append(
            f"| {learned.spec.title} ({learned.spec.source}, {learned.skill_id}) | {case.label} | "
            f"{_vec_cm(case.offset)} | {_vec_cm(case.unknown_offset)} | {_work_piece_text(outcomes, case)} |"
        )
    lines += [
        "",
        "A KNOWN offset is sent as `environment.offset` alone: the executor moves both the simulated work piece and "
        "the skill (DMP starts, goals, compliant frames) by it, so the cylinder really moves by the stated amount. "
        "An UNKNOWN offset (`environment.unknown_offset`) moves only the work piece; the guarded approach finds it.",
        "",
        "## How the rows are judged",
        "",
        f"Two force figures per row, over the steady contact (from {_steady_delay_s():g} s after contact), in N "
        "and in % of the "
        "learned force (slide: the constant; contour: the profile's peak): **true** = the force along the TRUE "
        "surface normal at the contact (the sum of the simulator's contact-point normal forces), what the work "
        "piece feels, whatever the learned compliant frame or the sensor say; **CF-z** = the measured force along "
        "the learned CF z, the controller's view. The targets are judged on the TRUE figures where the execution "
        "reports them (else on CF z; a verdict names the figure it used); a baseline is compared with ours on the "
        "same figure (true RMS error in N) in the same case. Touch-down = the largest true normal force from the "
        "first touch until the contact is steady, in N and over the first desired force of its segment. "
        "Contact = share of the contact phase in contact; path RMS in the CF x-y plane against the (known-offset-"
        "shifted or placed) demonstration; RTF = simulated / wall time of the worker's 1 kHz loop (the workers "
        "share the machine's cores).",
        "",
        f"## Targets: {met} of {len(report.verdicts)} met",
        "",
        "| target | verdict | detail |",
        "| --- | --- | --- |",
    ]
    lines += [f"| {v.name} | **{'MET' if v.met else 'MISSED'}** | {v.detail} |" for v in report.verdicts]
    notes = explanations(outcomes)
    if notes:
        lines += ["", "### Why a target is missed", ""]
        lines += [f"- {note}" for note in notes]
    fair = like_with_like(outcomes, report.traces)
    if fair:
        lines += ["", "### The baselines, like with like", ""]
        lines += [f"- {note}" for note in fair]
    seen_notes = observations(outcomes)
    if seen_notes:
        lines += ["", "### Also seen (rows without a target)", ""]
        lines += [f"- {note}" for note in seen_notes]
    if teacher:
        lines += ["", "## Results: the paper's experiments (the scripted teacher)", "", markdown_table(teacher)]
    if real:
        lines += ["", "## Results: real recordings (KU Leuven)", "", *real_data_summary(report), ""]
        lines.append(markdown_table(real))
        if not options.quick:  # the true object's 1000 bodies run at ~0.5x real time: the full report only
            from experiments.kuleuven_cad import cad_result_lines

            lines += ["", *cad_result_lines()]
    lines += ["", "## Figures", ""]
    for key, learned in report.skills.items():
        if learned.spec.real:
            continue
        lines += [f"### {learned.spec.title} ({learned.spec.figure})", ""]
        lines += [f"![{kind}](figures/demo_{key}_{kind}.png)\n" for kind in ("paths", "learned", "forces")]
    if real:
        lines += ["### Real recordings (KU Leuven), on the work pieces measured from them", ""]
        lines += ["![forces](figures/demo_kuleuven_forces.png)", ""]
        lines += [f"![paths](figures/demo_{key}_paths.png)\n" for key, s in report.skills.items() if s.spec.real]
    return "\n".join(lines)


def write_results(options: DemoOptions, report: DemoReport) -> Path:
    """Write RESULTS.md, keeping the generated sections it may hold: the sweeps (``contact-skills sweep --results``)
    the contour stress table (``benchmarks/bench_contours.py``) and the cross-engine table
    (``benchmarks/bench_engines.py``)."""
    from services.doc_sections import section_of

    options.out.mkdir(parents=True, exist_ok=True)
    path = options.out / "RESULTS.md"
    text = path.read_text() if path.exists() else ""
    names = (SWEEPS_SECTION, RESULTS_SECTION, CROSS_ENGINE_SECTION)
    kept = [section for name in names if (section := section_of(text, name))]
    path.write_text(results_markdown(options, report) + "".join(f"\n{section}\n" for section in kept))
    return path
