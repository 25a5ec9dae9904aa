"""The statistics of a robustness sweep (pure functions, no I/O): the trial design, what each trial changes in the
cell, how a trial is judged (its execution's verdict), and what the results say (per-controller success, failure
causes and force-error quantiles, which parameters drive the failures). The service (``services/sweeps.py``) stores
and runs; this module computes.

Units: a parameter's values are in the unit its name says (``_m``, ``_deg``, ``_n``, ``_n_m``, ``_n_s_m``, or 1).
"""

from __future__ import annotations

import math
import warnings
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import JsonValue

from schemas.api import ExecutionState
from schemas.execution import (
    NOMINAL_CONTACT_DAMPING_N_S_M,
    NOMINAL_CONTACT_STIFFNESS_N_M,
    ControllerKind,
    EnvironmentChange,
    ExecutionMetrics,
    ExecutionPhase,
    WorkPieceSource,
)
from schemas.skill import Skill
from schemas.sweep import (
    CYLINDER_PARAMETERS,
    SWEEP_TOLERANCES,
    ControllerSummary,
    ParameterRange,
    Quantiles,
    Sampler,
    Sensitivity,
    SweepParameter,
)
from schemas.text import JsonObject
from schemas.verdict import ExecutionVerdict, Verdict, VerdictCheckName
from schemas.world import WorldOverrides
from skills.frames import matrix_from_axis_angle

SEED_STRIDE = 1_000_003
"""Trial k's sensor noise seed is ``(seed * SEED_STRIDE + k) mod 2**32``: distinct per trial, the same for every
controller of that trial (like with like) and for the same sweep seed."""


def trial_parameters(
    vary: Mapping[SweepParameter, ParameterRange], trials: int, seed: int, sampler: Sampler
) -> list[dict[SweepParameter, float]]:
    """``trials`` parameter sets drawn over ``vary`` with ``sampler`` (seeded: the same arguments give the same
    sets, in the same order). Each range maps the unit cube linearly (log-uniformly with ``log``)."""
    from scipy.stats import qmc  # here: scipy.stats costs the API's start a second or more

    names = sorted(vary, key=lambda p: list(SweepParameter).index(p))
    d = len(names)
    if sampler is Sampler.sobol:
        engine = qmc.Sobol(d, scramble=True, seed=seed)
        with warnings.catch_warnings():  # N not a power of 2: still a valid, only less balanced, design
            warnings.simplefilter("ignore", UserWarning)
            unit = engine.random(trials)
    else:
        unit = qmc.LatinHypercube(d, seed=seed).random(trials)
    columns = []
    for j, name in enumerate(names):
        spread = vary[name]
        if spread.log:
            low, high = np.log(spread.low), np.log(spread.high)
            columns.append(np.exp(low + unit[:, j] * (high - low)))
        else:
            columns.append(spread.low + unit[:, j] * (spread.high - spread.low))
    values = np.column_stack(columns)
    return [{name: float(values[k, j]) for j, name in enumerate(names)} for k in range(trials)]


def trial_environment(
    base: Mapping[str, JsonValue], parameters: Mapping[SweepParameter, float], noise_seed: int
) -> JsonObject:
    """The `EnvironmentChange` fields (a JSON dict) of one trial: ``base`` with the varied fields set.

    Offsets and tilts are UNKNOWN to the controller (``unknown_offset``, ``unknown_tilt_deg``); the bias is along
    world x, y and z, the sensor's own offset along the tool's; ``noise_seed`` makes the sensor noise differ between
    trials (and repeat with the sweep's seed)."""
    env = dict(base)
    offset = list(env.get("unknown_offset") or [0.0, 0.0, 0.0])
    tilt = list(env.get("unknown_tilt_deg") or [0.0, 0.0])
    bias = list(env.get("sensor_bias_n") or [0.0, 0.0, 0.0])
    own = list(env.get("sensor_offset_tool_n") or [0.0, 0.0, 0.0])
    P = SweepParameter
    for axis, name in enumerate((P.offset_x_m, P.offset_y_m, P.offset_z_m)):
        offset[axis] = parameters.get(name, offset[axis])
    for axis, name in enumerate((P.tilt_x_deg, P.tilt_y_deg)):
        tilt[axis] = parameters.get(name, tilt[axis])
    for axis, name in enumerate((P.sensor_bias_x_n, P.sensor_bias_y_n, P.sensor_bias_z_n)):
        bias[axis] = parameters.get(name, bias[axis])
    for axis, name in enumerate((P.sensor_offset_x_n, P.sensor_offset_y_n, P.sensor_offset_z_n)):
        own[axis] = parameters.get(name, own[axis])
    env.update(
        unknown_offset=offset,
        unknown_tilt_deg=tilt,
        sensor_bias_n=bias,
        sensor_offset_tool_n=own,
        noise_seed=noise_seed,
    )
    for name, field in (
        (P.friction, "friction"),
        (P.contact_stiffness_n_m, "contact_stiffness_n_m"),
        (P.contact_damping_n_s_m, "contact_damping_n_s_m"),
        (P.sensor_noise_n, "sensor_noise_n"),
        (P.force_scale, "force_scale"),
    ):
        if name in parameters:
            env[field] = parameters[name]
    return env


def planned_pad(base: Mapping[str, JsonValue], parameters: Mapping[SweepParameter, float]) -> dict[str, float]:
    """The `ExecutionSettings` fields (a JSON dict) that keep a varied pad UNKNOWN to the controller: the touch-down
    and crease speeds planned for the base pad (``base``: the sweep's execution settings; its environment's pad if
    it sets one, else the worlds' nominal pad), not for the trial's. Settings that already plan for a pad keep it."""
    env = base.get("environment") or {}
    pad = (
        (SweepParameter.contact_stiffness_n_m, "planned_contact_stiffness_n_m", "contact_stiffness_n_m",
         NOMINAL_CONTACT_STIFFNESS_N_M),
        (SweepParameter.contact_damping_n_s_m, "planned_contact_damping_n_s_m", "contact_damping_n_s_m",
         NOMINAL_CONTACT_DAMPING_N_S_M),
    )  # fmt: skip
    return {
        planned: float(env.get(field) if env.get(field) is not None else nominal)
        for name, planned, field, nominal in pad
        if name in parameters and base.get(planned) is None
    }


def trials_in_taught_world(scenario: str | None, environment: EnvironmentChange) -> bool:
    """Whether a sweep's trials run in the skill's taught world: the sweep names no scenario and its environment's
    work piece is ``auto`` or ``taught`` (the precedence of ``sim_worker.execution_world``: a sweep gives no world
    file)."""
    return scenario is None and environment.work_piece in (WorkPieceSource.auto, WorkPieceSource.taught)


def taught_cylinder_world(skill: Skill, scenario: str | None, environment: EnvironmentChange) -> JsonObject | None:
    """The skill's taught world (a `WorldConfig` dict) when a sweep's trials run in it (:func:`trials_in_taught_world`)
    and it has a cylinder, else None."""
    world = skill.taught_world
    in_taught_world = trials_in_taught_world(scenario, environment)
    return world if in_taught_world and world is not None and _world_field(world, "cylinder", "enabled") else None


def inapplicable_parameter(
    vary: Mapping[SweepParameter, ParameterRange], skill: Skill, scenario: str | None, environment: EnvironmentChange
) -> tuple[SweepParameter, str] | None:
    """The first varied parameter the trials' world has nothing for, with why (a 422 names it), or None: the
    cylinder parameters need :func:`taught_cylinder_world`."""
    cylinder = [name for name in vary if name in CYLINDER_PARAMETERS]
    if not cylinder or taught_cylinder_world(skill, scenario, environment) is not None:
        return None
    if skill.taught_world is None or not _world_field(skill.taught_world, "cylinder", "enabled"):
        why = "the skill's taught world has no cylinder (vary it for a contour skill recorded on contour_cylinder)"
    elif scenario is not None:
        why = f"the trials run in the scenario {scenario!r}, not in the skill's taught world (give no scenario)"
    else:
        why = f"the trials run on a {environment.work_piece.value} work piece, not in the skill's taught world"
    return cylinder[0], f"{cylinder[0].value} changes the cylinder of the skill's taught world: {why}"


def trial_world_overrides(
    world: Mapping[str, Any] | None, parameters: Mapping[SweepParameter, float]
) -> WorldOverrides:
    """The `WorldConfig` fields one trial changes in ``world`` (the skill's taught world, the trials' world when they
    vary a cylinder parameter: :func:`taught_cylinder_world`; read only then): the cylinder's radius with its crown
    held where it was taught (the cylinder lies on the table, its centre one radius above it: lowering it by twice
    the change along the table normal keeps the crown), and its yaw turned from the taught one (deg)."""
    P = SweepParameter
    changes: WorldOverrides = {}
    if world is None:
        return changes
    if P.cylinder_radius_m in parameters:
        radius = parameters[P.cylinder_radius_m]
        tilt_axis, tilt_deg = _world_field(world, "table", "tilt_axis"), _world_field(world, "table", "tilt_deg")
        normal = matrix_from_axis_angle(tilt_axis, math.radians(tilt_deg))[:, 2]
        taught_offset = np.asarray(_world_field(world, "cylinder", "offset_m"), float)
        lowered = taught_offset + 2.0 * (_world_field(world, "cylinder", "radius_m") - radius) * normal
        changes.update(cylinder_radius_m=radius, cylinder_offset_m=lowered.tolist())
    if P.cylinder_yaw_deg in parameters:
        changes["cylinder_yaw_deg"] = _world_field(world, "cylinder", "yaw_deg") + parameters[P.cylinder_yaw_deg]
    return changes


def _world_field(world: Mapping[str, Any], part: str, name: str) -> Any:
    """Field ``name`` of sub-config ``part`` of a `WorldConfig` dict: nested (``world[part][name]``), or flat as a world
    stored before the sub-configs holds it (``world[f"{part}_{name}"]``); None when absent."""
    section = world.get(part)
    return section.get(name) if isinstance(section, Mapping) else world.get(f"{part}_{name}")


def trial_tolerances(base: Mapping[str, JsonValue], criteria: Mapping[str, float]) -> JsonObject:
    """The `ExecutionTolerances` fields (a JSON dict) of every trial: ``base`` (the sweep's settings' tolerances) with
    the sweep's success criteria (``criteria``: its request, ``success_rms_pct`` and ``success_contact_ratio``)
    written in (:data:`schemas.sweep.SWEEP_TOLERANCES`)."""
    return {**base, **{tolerance: criteria[field] for field, tolerance in SWEEP_TOLERANCES.items()}}


def trial_noise_seed(seed: int, trial: int) -> int:
    """The sensor noise seed of trial ``trial`` of a sweep seeded ``seed`` (:data:`SEED_STRIDE`)."""
    return (seed * SEED_STRIDE + trial) % 2**32


@dataclass(frozen=True)
class Outcome:
    """What one finished trial x controller gave (from its execution's status and metrics) and how it is judged."""

    phase: ExecutionPhase
    """done, aborted or failed."""
    true_rms_pct: float | None
    true_max_pct: float | None
    touchdown_ratio: float | None
    contact_ratio: float | None
    abort_reason: str | None
    success: bool
    """Its verdict passed (for a trial stored without a verdict: :func:`legacy_success`)."""
    reasons: tuple[str, ...] = ()
    """Why it failed, in words (its verdict's reasons)."""
    causes: tuple[str, ...] = ()
    """Why it failed, as counted (:func:`failure_causes`)."""
    warnings: tuple[str, ...] = ()
    """The checks its verdict warned about (names)."""

    @property
    def verdict(self) -> Verdict:
        """Pass or fail (its execution's verdict, or the old rule's)."""
        return Verdict.passed if self.success else Verdict.failed


def legacy_success(
    phase: ExecutionPhase, contact_ratio: float | None, true_rms_pct: float | None, criteria: Mapping[str, float]
) -> bool:
    """How a trial stored before executions had a verdict is judged: done, in contact at least
    ``success_contact_ratio`` of the contact phase and a true normal RMS error of at most ``success_rms_pct`` % (the
    sweep request's fields in ``criteria``)."""
    return (
        phase is ExecutionPhase.done
        and contact_ratio is not None
        and contact_ratio >= criteria["success_contact_ratio"]
        and true_rms_pct is not None
        and true_rms_pct <= criteria["success_rms_pct"]
    )


_FINAL_PHASES = {ExecutionState.done: ExecutionPhase.done, ExecutionState.aborted: ExecutionPhase.aborted}
"""The phase of a trial's execution that ended with this status and no metrics."""


def _abort_cause(phase: ExecutionPhase, abort_reason: str | None) -> str:
    """``<phase>: <the reason up to its first colon or its time>``, e.g. ``aborted: contact lost in segment 1``."""
    return f"{phase}: {(abort_reason or phase).split(':', 1)[0].split(' at t =', 1)[0]}"


def failure_causes(verdict: ExecutionVerdict, phase: ExecutionPhase, abort_reason: str | None) -> tuple[str, ...]:
    """Why a trial failed its verdict, as the sweep counts it: ``aborted: <reason>`` (or ``failed: <error>``) for one
    that did not finish (the verdict fails on that alone), else the names of its failed checks (a warning is no
    cause); () for a verdict that passed."""
    if verdict.verdict is Verdict.passed:
        return ()
    if phase is not ExecutionPhase.done:
        return (_abort_cause(phase, abort_reason),)
    return tuple(c.name.value for c in verdict.checks if not c.passed and not c.warning_only)


def outcome(
    metrics: ExecutionMetrics | None, status: ExecutionState | None, error: str | None, criteria: Mapping[str, float]
) -> Outcome:
    """The judged outcome of a finished trial from its execution's ``metrics`` (None when it failed before any), its
    ``status`` and ``error``: success is the metrics' verdict, or for metrics without one (stored before verdicts;
    no metrics at all) :func:`legacy_success` with the sweep's ``criteria``. Without metrics the phase is the
    status's (done, aborted; any other: failed)."""
    phase = metrics.phase if metrics is not None else _FINAL_PHASES.get(status, ExecutionPhase.failed)
    abort_reason = (metrics.abort_reason if metrics is not None else None) or error
    rms = metrics.true_force_rms_error_pct if metrics is not None else None
    contact = metrics.contact_ratio if metrics is not None else None
    warned: tuple[str, ...] = ()
    if metrics is not None and metrics.verdict is not None:
        verdict = metrics.verdict
        success = verdict.verdict is Verdict.passed
        reasons = tuple(verdict.reasons)
        causes = failure_causes(verdict, phase, abort_reason)
        warned = tuple(c.name.value for c in verdict.checks if not c.passed and c.warning_only)
    else:
        success = legacy_success(phase, contact, rms, criteria)
        if success:
            causes = ()
        elif phase is not ExecutionPhase.done:
            causes = (_abort_cause(phase, abort_reason),)
        elif contact is None or contact < criteria["success_contact_ratio"]:
            causes = (VerdictCheckName.contact_ratio.value,)
        else:
            causes = (VerdictCheckName.true_force_rms.value,)
        reasons = causes
    return Outcome(
        phase=phase,
        true_rms_pct=rms,
        true_max_pct=metrics.true_force_max_error_pct if metrics is not None else None,
        touchdown_ratio=metrics.touchdown_peak_ratio if metrics is not None else None,
        contact_ratio=contact,
        abort_reason=abort_reason,
        success=success,
        reasons=reasons,
        causes=causes,
        warnings=warned,
    )


def quantiles(values: Sequence[float | None]) -> Quantiles | None:
    """p10, p50, p90 and max of the values that are not None (None when there is none)."""
    finite = np.asarray([v for v in values if v is not None], dtype=float)
    if finite.size == 0:
        return None
    p10, p50, p90 = np.percentile(finite, [10, 50, 90])
    return Quantiles(p10=float(p10), p50=float(p50), p90=float(p90), max=float(finite.max()), n=int(finite.size))


def controller_summary(controller: ControllerKind, trials: int, outcomes: Sequence[Outcome]) -> ControllerSummary:
    """Success rate, force-error quantiles, failure causes (a trial under each of its causes) and warnings of one
    controller over its finished ``outcomes``."""
    succeeded = sum(o.success for o in outcomes)
    causes = Counter(cause for o in outcomes for cause in o.causes)
    warned = Counter(name for o in outcomes for name in o.warnings)
    return ControllerSummary(
        controller=controller,
        trials=trials,
        finished=len(outcomes),
        succeeded=succeeded,
        success_rate=succeeded / len(outcomes) if outcomes else None,
        true_force_rms_error_pct=quantiles([o.true_rms_pct for o in outcomes]),
        true_force_max_error_pct=quantiles([o.true_max_pct for o in outcomes]),
        touchdown_peak_ratio=quantiles([o.touchdown_ratio for o in outcomes]),
        failures=dict(causes.most_common()),
        warnings=dict(warned.most_common()),
    )


def _rate(flags: NDArray[np.bool_]) -> float | None:
    return float(flags.mean()) if flags.size else None


def sensitivity(
    controller: ControllerKind, parameters: Sequence[Mapping[SweepParameter, float]], outcomes: Sequence[Outcome]
) -> list[Sensitivity]:
    """For each varied parameter: the Spearman rank correlation with the true RMS error (a trial without one ranks
    worst: it failed harder than any that pressed) and the success rates of the trials below and above the
    parameter's median. ``parameters[k]`` belongs to ``outcomes[k]`` (finished trials of ``controller``)."""
    from scipy.stats import rankdata, spearmanr

    if not outcomes:
        return []
    rms = np.asarray([np.inf if o.true_rms_pct is None else o.true_rms_pct for o in outcomes])
    ranks = rankdata(rms)  # inf ranks last; ties share their mean rank
    success = np.asarray([o.success for o in outcomes])
    result = []
    for name in parameters[0]:
        values = np.asarray([p[name] for p in parameters], dtype=float)
        rho = None
        if np.ptp(values) > 0 and np.ptp(ranks) > 0:
            rho = float(spearmanr(values, ranks).statistic)
        median = float(np.median(values))
        low, high = _rate(success[values < median]), _rate(success[values > median])
        difference = None if low is None or high is None else high - low
        importance = max(abs(rho or 0.0), abs(difference or 0.0))
        result.append(
            Sensitivity(
                parameter=name,
                controller=controller,
                spearman_rms=rho,
                success_low_half=low,
                success_high_half=high,
                success_difference=difference,
                importance=importance,
            )
        )
    return sorted(result, key=lambda s: -s.importance)


def equal_count_bins(values: NDArray[np.float64], bins: int) -> list[NDArray[np.int_]]:
    """The indices of ``values`` split into ``bins`` groups of (nearly) equal count, lowest values first (fewer groups
    for fewer values; none empty)."""
    order = np.argsort(values, kind="stable")
    return [group for group in np.array_split(order, min(bins, values.size)) if group.size]


@dataclass(frozen=True)
class CauseDriver:
    """Where along the parameter that best separates them one failure cause of a controller happened."""

    cause: str
    count: int
    """Finished trials with this cause."""
    finished: int
    parameter: SweepParameter
    bins: tuple[tuple[float, float, int, int], ...]
    """Per equal-count bin of the parameter: its lowest and highest value, the trials in it with the cause, and all
    trials in it."""


def cause_drivers(
    parameters: Sequence[Mapping[SweepParameter, float]], causes: Sequence[Sequence[str]], bins: int = 4
) -> list[CauseDriver]:
    """For each failure cause of one controller's finished trials (``causes[k]`` of ``parameters[k]``; most frequent
    first): the varied parameter whose ``bins`` equal-count bins differ most in the share of trials with that cause
    (a cause at both ends of a range, such as an offset either way, shows as well as one at one end); of equals, the
    one whose rank correlates most with the cause (its trials bunched at one end)."""
    from scipy.stats import spearmanr

    if not parameters:
        return []
    counted = Counter(cause for trial in causes for cause in trial)
    columns = {name: np.asarray([p[name] for p in parameters], dtype=float) for name in parameters[0]}
    groups = {name: equal_count_bins(values, bins) for name, values in columns.items()}
    result = []
    for cause, count in counted.most_common():
        has = np.asarray([cause in trial for trial in causes])

        def separation(name: SweepParameter, has: NDArray[np.bool_] = has) -> tuple[float, float]:
            rates = [float(has[g].mean()) for g in groups[name]]
            values = columns[name]
            rho = spearmanr(values, has).statistic if np.ptp(values) > 0 and 0 < has.sum() < has.size else 0.0
            return max(rates) - min(rates), abs(float(rho))

        name = max(columns, key=separation)
        values = columns[name]
        summary = tuple(
            (float(values[g].min()), float(values[g].max()), int(has[g].sum()), int(g.size)) for g in groups[name]
        )
        result.append(CauseDriver(cause, count, len(causes), name, summary))
    return result
