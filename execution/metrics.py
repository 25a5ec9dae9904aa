"""What an execution achieved, computed from its telemetry (``schemas.execution.ExecutionMetrics``): force errors over
the steady contact, contact ratio, path error; its touch-downs and where it pressed (``execution.contact_metrics``),
and its verdict against the tolerances (``execution.verdict``). World frame, SI units; forces in N along CF z.

Every peak is seen: the steady window of a contact run starts once, after its touch-down and force ramp, and spans
its crease passages and segment switches (each also scored on its own, the transition figure); a touch-down is
counted in whatever phase the tool first meets a surface, free segments included; the CF angle is that of the frame
the controller used at each row.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from execution.contact_metrics import TRANSITION_WINDOW_S, run_starts, surfaces_pressed, touchdown_metrics
from execution.execution_log import ExecutionLog
from execution.plans import contact_geometry
from execution.telemetry import Telemetry
from execution.verdict import execution_verdict
from schemas.demonstration import Demonstration
from schemas.execution import (
    PHASE_CODES,
    ControllerKind,
    ExecutionMetrics,
    ExecutionPhase,
    ExecutionSettings,
)
from schemas.skill import Segment, SegmentKind, Skill
from schemas.verdict import ExecutionVerdict, Verdict
from skills.dmp import DMP
from skills.force_band import share_in_band

STEADY_CONTACT_DELAY_S = 0.2
"""The steady contact phase starts this long after a contact run starts (and after its force ramp), s."""


def reference_force(skill: Skill, dt: float = 1e-3) -> float:
    """The force the % errors refer to: the largest learned constant, or the peak of the force profile
    rolled out at the control step ``dt`` (s), as executed (N)."""
    values = [s.force_constant_n for s in skill.segments if s.force_constant_n is not None]
    for s in skill.segments:
        if s.force_dmp is not None:
            values.append(float(np.max(DMP.from_parameters(s.force_dmp).rollout(dt).y)))
    return max(values) if values else 0.0


def _steady_mask(tel: Telemetry, ramp_s: float) -> NDArray[np.bool_]:
    """Contact-phase rows at least max(0.2 s, the force ramp) after the start of their contact RUN (consecutive
    contact-phase rows: contact segments that follow each other directly are one run, their switch inside it)."""
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    if not contact.any():
        return contact
    run = np.cumsum(np.isin(np.arange(len(tel)), run_starts(contact)))  # run number of each row (1-based)
    started = tel.t[run_starts(contact)][run - 1]
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


def _true_force_in_band(skill: Skill, tel: Telemetry, contact: NDArray[np.bool_]) -> float | None:
    """The share of the contact phase of the segments with a force band (`Segment.force_band`) whose true normal
    force lies within it, each segment's contact aligned to its band by the tool's path
    (`skills.force_band.share_in_band`); None where no segment has a band or ran in contact."""
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
    metrics |= touchdown_metrics(tel, steady, exits, reference, dt)
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
