"""The statistics of a robustness sweep (pure functions, no I/O): the trial design, what each trial changes in the
cell, how a trial is judged, and what the results say (per-controller success and force-error quantiles, which
parameters drive the failures). The service (``services/sweeps.py``) stores and runs; this module computes.

Units: a parameter's values are in the unit its name says (``_m``, ``_deg``, ``_n``, ``_n_m``, ``_n_s_m``, or 1).
"""

from __future__ import annotations

import warnings
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.execution import NOMINAL_CONTACT_DAMPING_N_S_M, NOMINAL_CONTACT_STIFFNESS_N_M, ControllerKind
from schemas.sweep import (
    ControllerSummary,
    ParameterRange,
    Quantiles,
    Sampler,
    Sensitivity,
    SweepParameter,
)

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


def trial_environment(base: Mapping, parameters: Mapping[SweepParameter, float], noise_seed: int) -> dict:
    """The `EnvironmentChange` fields (a JSON dict) of one trial: ``base`` with the varied fields set.

    Offsets and tilts are UNKNOWN to the controller (``unknown_offset``, ``unknown_tilt_deg``); the bias is along
    world z; ``noise_seed`` makes the sensor noise differ between trials (and repeat with the sweep's seed)."""
    env = dict(base)
    offset = list(env.get("unknown_offset") or [0.0, 0.0, 0.0])
    tilt = list(env.get("unknown_tilt_deg") or [0.0, 0.0])
    bias = list(env.get("sensor_bias_n") or [0.0, 0.0, 0.0])
    P = SweepParameter
    for axis, name in enumerate((P.offset_x_m, P.offset_y_m, P.offset_z_m)):
        offset[axis] = parameters.get(name, offset[axis])
    for axis, name in enumerate((P.tilt_x_deg, P.tilt_y_deg)):
        tilt[axis] = parameters.get(name, tilt[axis])
    bias[2] = parameters.get(P.sensor_bias_z_n, bias[2])
    env.update(unknown_offset=offset, unknown_tilt_deg=tilt, sensor_bias_n=bias, noise_seed=noise_seed)
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


def planned_pad(base: Mapping, parameters: Mapping[SweepParameter, float]) -> dict[str, float]:
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


def trial_noise_seed(seed: int, trial: int) -> int:
    """The sensor noise seed of trial ``trial`` of a sweep seeded ``seed`` (:data:`SEED_STRIDE`)."""
    return (seed * SEED_STRIDE + trial) % 2**32


@dataclass(frozen=True)
class Outcome:
    """What one finished trial x controller gave (from its execution's status and metrics)."""

    phase: str
    """done, aborted or failed."""
    true_rms_pct: float | None
    true_max_pct: float | None
    touchdown_ratio: float | None
    contact_ratio: float | None
    abort_reason: str | None


def trial_success(outcome: Outcome, rms_pct: float, contact_ratio: float) -> bool:
    """Done, in contact at least ``contact_ratio`` of the contact phase, true normal RMS error <= ``rms_pct`` %."""
    return (
        outcome.phase == "done"
        and outcome.contact_ratio is not None
        and outcome.contact_ratio >= contact_ratio
        and outcome.true_rms_pct is not None
        and outcome.true_rms_pct <= rms_pct
    )


def failure_cause(outcome: Outcome, rms_pct: float, contact_ratio: float) -> str:
    """Why an unsuccessful trial failed, in a few words (the abort reason up to its first colon)."""
    if outcome.phase != "done":
        reason = (outcome.abort_reason or outcome.phase).split(":", 1)[0].split(" at t =", 1)[0]
        return f"{outcome.phase}: {reason}"
    if outcome.contact_ratio is None or outcome.contact_ratio < contact_ratio:
        return "contact below the threshold"
    return f"force error above {rms_pct:g} %"


def quantiles(values: Sequence[float | None]) -> Quantiles | None:
    """p10, p50, p90 and max of the values that are not None (None when there is none)."""
    finite = np.asarray([v for v in values if v is not None], dtype=float)
    if finite.size == 0:
        return None
    p10, p50, p90 = np.percentile(finite, [10, 50, 90])
    return Quantiles(p10=float(p10), p50=float(p50), p90=float(p90), max=float(finite.max()), n=int(finite.size))


def controller_summary(
    controller: ControllerKind, trials: int, outcomes: Sequence[Outcome], rms_pct: float, contact_ratio: float
) -> ControllerSummary:
    """Success rate, force-error quantiles and failure causes of one controller over its finished ``outcomes``."""
    success = [trial_success(o, rms_pct, contact_ratio) for o in outcomes]
    failed = [o for o, ok in zip(outcomes, success, strict=True) if not ok]
    causes = Counter(failure_cause(o, rms_pct, contact_ratio) for o in failed)
    return ControllerSummary(
        controller=controller,
        trials=trials,
        finished=len(outcomes),
        succeeded=sum(success),
        success_rate=sum(success) / len(outcomes) if outcomes else None,
        true_force_rms_error_pct=quantiles([o.true_rms_pct for o in outcomes]),
        true_force_max_error_pct=quantiles([o.true_max_pct for o in outcomes]),
        touchdown_peak_ratio=quantiles([o.touchdown_ratio for o in outcomes]),
        failures=dict(causes.most_common()),
    )


def _rate(flags: NDArray[np.bool_]) -> float | None:
    return float(flags.mean()) if flags.size else None


def sensitivity(
    controller: ControllerKind,
    parameters: Sequence[Mapping[SweepParameter, float]],
    outcomes: Sequence[Outcome],
    rms_pct: float,
    contact_ratio: float,
) -> list[Sensitivity]:
    """For each varied parameter: the Spearman rank correlation with the true RMS error (a trial without one ranks
    worst: it failed harder than any that pressed) and the success rates of the trials below and above the
    parameter's median. ``parameters[k]`` belongs to ``outcomes[k]`` (finished trials of ``controller``)."""
    from scipy.stats import rankdata, spearmanr

    if not outcomes:
        return []
    rms = np.asarray([np.inf if o.true_rms_pct is None else o.true_rms_pct for o in outcomes])
    ranks = rankdata(rms)  # inf ranks last; ties share their mean rank
    success = np.asarray([trial_success(o, rms_pct, contact_ratio) for o in outcomes])
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
