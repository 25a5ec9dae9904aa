"""What an execution achieved, computed from its telemetry: force errors over the steady contact, contact ratio,
path error, touch-down (``schemas.execution.ExecutionMetrics``). World frame, SI units; forces in N along CF z."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from schemas.demonstration import Demonstration
from schemas.execution import PHASE_CODES, ControllerKind, ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.skill import Segment, Skill
from sim_worker.plans import contact_geometry
from sim_worker.telemetry import Telemetry
from skills.dmp import DMP

STEADY_CONTACT_DELAY_S = 0.2
"""The steady contact phase starts this long after contact (and after each force ramp), s."""
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


def _steady_mask(tel: Telemetry, ramp_s: float) -> NDArray[np.bool_]:
    """Contact-phase rows at least max(0.2 s, the force ramp) after the start of their contact segment."""
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    mask = np.zeros(len(tel), dtype=bool)
    if not contact.any():
        return mask
    seg = tel.segment_index
    t = tel.t
    delay = max(STEADY_CONTACT_DELAY_S, ramp_s)
    for s in np.unique(seg[contact]):
        rows = contact & (seg == s)
        t0 = t[rows][0]
        mask |= rows & (t >= t0 + delay - 1e-9)
    return mask


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


def _learned_cf_z(skill: Skill, tel: Telemetry, contact: NDArray[np.bool_], offset: NDArray) -> NDArray[np.float64]:
    """The learned CF z the controller used at each contact-phase row (N, 3); NaN elsewhere. Contour frames by the
    row's time fraction of its segment, as the executor indexes them."""
    z = np.full((len(tel), 3), np.nan)
    segments = {s.index: s for s in skill.segments}
    for index in np.unique(tel.segment_index[contact]):
        rows = np.flatnonzero(contact & (tel.segment_index == index))
        geo = contact_geometry(segments[int(index)], offset)
        fractions = np.arange(rows.size) / max(rows.size - 1, 1)
        z[rows] = geo.rotations_at(fractions)[:, :, 2]
    return z


def _touchdowns(tel: Telemetry, steady: NDArray[np.bool_], reference: float, dt: float) -> dict[str, float]:
    """Touch-down peak (N, and over the first desired force) and the longest settle time (s) over the contact runs.

    A run starts at the first row in contact after a free stretch and ends where its steady contact starts; its
    settle time is from the first touch until the true normal force stays within ``SETTLED_BAND`` of the reference
    of the desired force for ``SETTLED_HOLD_S``."""
    touching = tel.normal_force_true > 0.0
    approach_or_contact = np.isin(
        tel.phase_codes, [PHASE_CODES[ExecutionPhase.approach], PHASE_CODES[ExecutionPhase.contact]]
    )
    starts = np.flatnonzero(touching & approach_or_contact & ~np.r_[False, touching[:-1]])
    steady_starts = np.flatnonzero(steady & ~np.r_[False, steady[:-1]])
    error = np.abs(tel.normal_force_true - tel.desired_force)
    hold = max(1, round(SETTLED_HOLD_S / dt))
    peaks, ratios, settles = [], [], []
    for begin in starts:
        later = steady_starts[steady_starts > begin]
        if later.size == 0:
            continue
        end = int(later[0])
        if np.any(~touching[begin:end] & ~approach_or_contact[begin:end]):
            continue  # lifted off in between: not one touch-down
        peak = float(tel.normal_force_true[begin:end].max())
        peaks.append(peak)
        target = float(tel.desired_force[end])
        if target > 0:
            ratios.append(peak / target)
        outside = error[begin:] > SETTLED_BAND * max(reference, 1e-9)
        settled_for = np.convolve(~outside, np.ones(hold), mode="valid") >= hold  # the next `hold` rows are inside
        if settled_for.any():
            settles.append(float(np.argmax(settled_for)) * dt)
    result: dict[str, float] = {}
    if peaks:
        result["touchdown_peak_n"] = max(peaks)
    if ratios:
        result["touchdown_peak_ratio"] = max(ratios)
    if settles:
        result["settle_time_s"] = max(settles)
    return result


def compute_metrics(
    skill: Skill,
    tel: Telemetry,
    settings: ExecutionSettings,
    phase: ExecutionPhase,
    abort_reason: str | None,
    loop_wall_s: float,
    contact_offsets: list[float],
    demonstration: Demonstration | None = None,
    dt: float = 1e-3,
) -> ExecutionMetrics:
    """The measures of one execution (see ``schemas.execution.ExecutionMetrics``) from its recorded telemetry."""
    reference = reference_force(skill, dt)
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    steady = _steady_mask(tel, settings.gains.force_ramp_s)
    offset = np.asarray(settings.environment.offset, float)
    metrics: dict = {}
    if steady.any():
        desired = tel.desired_force[steady]
        metrics |= _errors(tel.wrench_cf[steady, 2] - desired, reference, "force")
        metrics |= _errors(tel.normal_force_true[steady] - desired, reference, "true_force")
    if contact.any():
        metrics["contact_ratio"] = float(np.mean(tel.in_contact[contact]))
        metrics["path_rms_m"] = _path_rms(skill, tel, offset, demonstration, dt)
        touching = contact & (tel.normal_force_true > 0.0)
        if touching.any():
            cf_z = _learned_cf_z(skill, tel, contact, offset)[touching]
            cosine = np.clip(np.sum(cf_z * tel.contact_normal[touching], axis=1), -1.0, 1.0)
            angles = np.degrees(np.arccos(cosine))
            metrics |= {"cf_normal_angle_deg": float(angles.mean()), "cf_normal_angle_max_deg": float(angles.max())}
    metrics |= _touchdowns(tel, steady, reference, dt)
    duration = float(len(tel) * dt)
    forces = np.linalg.norm(tel.wrench_world[:, :3], axis=1) if len(tel) else np.zeros(1)
    return ExecutionMetrics(
        controller=ControllerKind(settings.controller),
        phase=phase,
        force_reference_n=reference if reference > 0 else None,
        real_time_factor=duration / loop_wall_s if loop_wall_s > 0 else 0.0,
        duration_s=duration,
        steps=len(tel),
        peak_force_n=float(forces.max()),
        contact_found_offsets_m=contact_offsets,
        steady_contact_s=float(steady.sum() * dt),
        abort_reason=abort_reason,
        **metrics,
    )
