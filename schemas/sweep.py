"""Robustness sweeps (``/sweeps``): one skill run over N sampled variations of its cell with several controllers.

A sweep draws N trials from the ranges asked for (Latin hypercube or scrambled Sobol, reproducible from the seed;
``skills.sweeps``), runs every trial with every controller as one execution (the service's queue, at a priority
below single executions) and judges each by the TRUE normal force (the simulator's contact force along the true
surface normal): a trial succeeds when it finished (``done``), stayed in contact ``>= success_contact_ratio`` of
its contact phase and its true normal-force RMS error is ``<= success_rms_pct`` % of the reference force (the
learned constant of a slide, the profile peak of a contour). Units: SI, angles in degrees where a name says
``_deg`` (docs/CONVENTIONS.md).
"""

from __future__ import annotations

import math
from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from schemas.execution import (
    MAX_FORCE_SCALE,
    MAX_OFFSET_M,
    MAX_SENSOR_BIAS_N,
    MAX_SENSOR_NOISE_N,
    MAX_TILT_DEG,
    ControllerKind,
    ExecutionMetrics,
    ExecutionSettings,
)
from schemas.skill import Skill

MAX_TRIALS = 2000
"""Most trials of one sweep (each runs once per controller)."""
SWEEP_PRIORITY = -10
"""Queue priority of a sweep's executions: below a single execution's default (0), so one asked for meanwhile
starts first."""


class SweepParameter(StrEnum):
    """What a sweep can vary; each maps onto one `schemas.execution.EnvironmentChange` field (``skills.sweeps``)."""

    offset_x_m = "offset_x_m"
    """Unknown work-piece offset along world x, m."""
    offset_y_m = "offset_y_m"
    """Unknown work-piece offset along world y, m."""
    offset_z_m = "offset_z_m"
    """Unknown work-piece offset along world z, m."""
    tilt_x_deg = "tilt_x_deg"
    """Unknown work-piece tilt about world x through the skill's contact centre, deg."""
    tilt_y_deg = "tilt_y_deg"
    """Unknown work-piece tilt about world y through the skill's contact centre, deg."""
    friction = "friction"
    """Tool-surface friction coefficient (1)."""
    contact_stiffness_n_m = "contact_stiffness_n_m"
    """Contact stiffness of the tool pad, N/m."""
    contact_damping_n_s_m = "contact_damping_n_s_m"
    """Contact damping of the tool pad, N·s/m."""
    sensor_bias_z_n = "sensor_bias_z_n"
    """Untared force bias of the F/T sensor along world z, N (negative reads as pressing down)."""
    sensor_noise_n = "sensor_noise_n"
    """F/T sensor force noise, standard deviation per axis, N."""
    force_scale = "force_scale"
    """Factor on the skill's desired force profile (1)."""


PARAMETER_BOUNDS: dict[SweepParameter, tuple[float, float]] = {
    SweepParameter.offset_x_m: (-MAX_OFFSET_M, MAX_OFFSET_M),
    SweepParameter.offset_y_m: (-MAX_OFFSET_M, MAX_OFFSET_M),
    SweepParameter.offset_z_m: (-MAX_OFFSET_M, MAX_OFFSET_M),
    SweepParameter.tilt_x_deg: (-MAX_TILT_DEG, MAX_TILT_DEG),
    SweepParameter.tilt_y_deg: (-MAX_TILT_DEG, MAX_TILT_DEG),
    SweepParameter.friction: (0.0, 2.0),
    SweepParameter.contact_stiffness_n_m: (1e2, 1e7),
    SweepParameter.contact_damping_n_s_m: (0.0, 1e5),
    SweepParameter.sensor_bias_z_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_noise_n: (0.0, MAX_SENSOR_NOISE_N),
    SweepParameter.force_scale: (0.05, MAX_FORCE_SCALE),
}
"""The range each parameter may be drawn from (the bounds of the `EnvironmentChange` field it sets)."""


class Sampler(StrEnum):
    """How the trials are spread over the ranges (``scipy.stats.qmc``, seeded: same seed, same trials)."""

    lhs = "lhs"
    """Latin hypercube: each range cut into N equal strata, one trial in each, per parameter."""
    sobol = "sobol"
    """Scrambled Sobol sequence (best balanced when N is a power of 2)."""


class ParameterRange(BaseModel):
    """A uniform distribution over ``[low, high]`` (log-uniform with ``log``; ``low == high``: held fixed)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"low": -0.02, "high": 0.02}]})

    low: float = Field(description="Lower end, in the parameter's unit.")
    high: float = Field(description="Upper end, in the parameter's unit (>= low).")
    log: bool = Field(False, description="Uniform in log(value) (both ends > 0): for stiffness and damping.")

    @model_validator(mode="after")
    def _ordered(self) -> ParameterRange:
        if not (math.isfinite(self.low) and math.isfinite(self.high)):
            raise ValueError("low and high must be finite numbers")
        if self.high < self.low:
            raise ValueError(f"high ({self.high:g}) is below low ({self.low:g})")
        if self.log and self.low <= 0.0:
            raise ValueError(f"a log range needs low > 0, got {self.low:g}")
        return self


DEFAULT_RANGES: dict[SweepParameter, ParameterRange] = {
    SweepParameter.offset_x_m: ParameterRange(low=-0.01, high=0.01),
    SweepParameter.offset_y_m: ParameterRange(low=-0.01, high=0.01),
    SweepParameter.offset_z_m: ParameterRange(low=-0.02, high=0.02),
    SweepParameter.tilt_x_deg: ParameterRange(low=-5.0, high=5.0),
    SweepParameter.tilt_y_deg: ParameterRange(low=-5.0, high=5.0),
    SweepParameter.friction: ParameterRange(low=0.1, high=0.5),
    SweepParameter.contact_stiffness_n_m: ParameterRange(low=1e4, high=1e5, log=True),
    SweepParameter.contact_damping_n_s_m: ParameterRange(low=100.0, high=1000.0, log=True),
    SweepParameter.sensor_bias_z_n: ParameterRange(low=-1.0, high=1.0),
    SweepParameter.sensor_noise_n: ParameterRange(low=0.0, high=0.3),
    SweepParameter.force_scale: ParameterRange(low=0.7, high=1.3),
}
"""A cell's usual variation (the CLI's default ranges): ±1 cm in x-y and ±2 cm in z unknown, ±5° of unknown tilt,
friction 0.1-0.5, a pad from 1e4 to 1e5 N/m, ±1 N of untared bias, up to 0.3 N of noise, ±30 % force level."""


class SweepRequest(BaseModel):
    """``POST /sweeps``: the skill, the controllers to compare, the ranges to vary, how many trials and how judged."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "skill_id": "skill_3f2a9c01b2d4",
                    "controllers": ["hybrid_cf", "impedance_found_surface", "hybrid_world_z"],
                    "vary": {"offset_z_m": {"low": -0.02, "high": 0.02}, "tilt_x_deg": {"low": -5, "high": 5}},
                    "trials": 50,
                    "seed": 0,
                    "sampler": "lhs",
                }
            ]
        },
    )

    skill_id: str | None = Field(None, description="Id of a stored skill (or give `skill` inline).")
    skill: Skill | None = Field(None, description="An inline skill (or give `skill_id`).")
    scenario: str | None = Field(
        None, description="Teacher scenario whose world to run in (default: the skill's own world).", max_length=64
    )
    controllers: list[ControllerKind] = Field(
        default_factory=lambda: [ControllerKind.hybrid_cf],
        min_length=1,
        max_length=len(ControllerKind),
        description="The control laws to compare; every trial runs once with each.",
    )
    vary: dict[SweepParameter, ParameterRange] = Field(
        min_length=1,
        description="The parameters to vary and their ranges; the others stay as in `settings.environment`.",
    )
    trials: int = Field(20, ge=1, le=MAX_TRIALS, description="Number of sampled trials (N).")
    seed: int = Field(0, ge=0, le=2**32 - 1, description="Seed of the sampler and of each trial's sensor noise.")
    sampler: Sampler = Field(Sampler.lhs, description="Latin hypercube or scrambled Sobol.")
    success_rms_pct: float = Field(
        10.0,
        gt=0.0,
        le=1000.0,
        description="A trial succeeds when its TRUE normal-force RMS error is at most this, % of the reference force.",
    )
    success_contact_ratio: float = Field(
        0.99, ge=0.0, le=1.0, description="... and it stayed in contact at least this share of its contact phase."
    )
    settings: ExecutionSettings = Field(
        default_factory=ExecutionSettings,
        description="The execution settings every trial starts from (gains, pace, environment); the sweep sets the "
        "varied fields of the environment, the controller and the telemetry (from store_telemetry).",
    )
    store_telemetry: bool = Field(
        False,
        description="Stream and store every trial's telemetry (each trial's execution with telemetry 'stream', its "
        "GET /executions/{id}/telemetry served). Default false: telemetry 'none', nothing published, stored or "
        "kept (cheaper: docs/BENCHMARKS.md, bench_sweeps); every metric and the success rates are the same.",
    )
    priority: int = Field(
        SWEEP_PRIORITY,
        ge=-100,
        le=-1,
        description="Queue priority of the sweep's executions (below a single execution's 0, so those go first).",
    )

    @field_validator("controllers")
    @classmethod
    def _distinct(cls, value: list[ControllerKind]) -> list[ControllerKind]:
        if len(set(value)) != len(value):
            raise ValueError("each controller may be listed once")
        return value

    @field_validator("vary")
    @classmethod
    def _within_bounds(cls, value: dict[SweepParameter, ParameterRange]) -> dict[SweepParameter, ParameterRange]:
        for name, spread in value.items():
            low, high = PARAMETER_BOUNDS[name]
            if spread.low < low or spread.high > high:
                raise ValueError(f"{name.value}: [{spread.low:g}, {spread.high:g}] leaves [{low:g}, {high:g}]")
        return value

    @model_validator(mode="after")
    def _one_skill(self) -> SweepRequest:
        if (self.skill_id is None) == (self.skill is None):
            raise ValueError("give exactly one of skill_id (a stored skill) or skill (inline)")
        return self

    @field_validator("settings")
    @classmethod
    def _telemetry_from_store_telemetry(cls, value: ExecutionSettings) -> ExecutionSettings:
        if "telemetry" in value.model_fields_set:
            raise ValueError(
                "telemetry: a sweep sets its trials' telemetry from store_telemetry (true: stream, false: none); "
                "give store_telemetry instead"
            )
        return value


class SweepState(StrEnum):
    """Life cycle of a sweep."""

    running = "running"
    """Trials are queued or running."""
    done = "done"
    """Every trial has a result (successful or not)."""
    cancelled = "cancelled"
    """Cancelled (``POST /sweeps/{id}/cancel``): queued trials dropped, running ones aborted."""


class TrialResult(BaseModel):
    """One trial with one controller: its parameters, its execution and what it achieved."""

    model_config = ConfigDict(extra="forbid")

    trial: int = Field(description="Trial index, 0..N-1 (the same parameters for every controller).")
    controller: ControllerKind
    parameters: dict[SweepParameter, float] = Field(description="The values drawn for this trial.")
    execution_id: str | None = Field(None, description="The execution that ran it (the last, if it was rerun).")
    attempts: int = Field(0, description="Executions submitted for it (> 1: rerun after a lost worker or restart).")
    status: str = Field(description="The execution's status (queued, running, done, aborted, failed), or pending.")
    success: bool | None = Field(None, description="Judged once finished (None while pending or running).")
    true_force_rms_error_pct: float | None = None
    true_force_max_error_pct: float | None = None
    touchdown_peak_ratio: float | None = None
    contact_ratio: float | None = None
    abort_reason: str | None = Field(None, description="Why it stopped early, if it did.")
    metrics: ExecutionMetrics | None = Field(None, description="Every metric of the execution, once finished.")


class Quantiles(BaseModel):
    """10th, 50th and 90th percentile and the largest value over the trials that have the measure."""

    model_config = ConfigDict(extra="forbid")

    p10: float
    p50: float
    p90: float
    max: float
    n: int = Field(description="Trials with the measure (finished with contact).")


class ControllerSummary(BaseModel):
    """How one controller did over the finished trials."""

    model_config = ConfigDict(extra="forbid")

    controller: ControllerKind
    trials: int = Field(description="Trials of the sweep.")
    finished: int = Field(description="Trials with a result.")
    succeeded: int
    success_rate: float | None = Field(None, description="succeeded / finished (None before any finished).")
    true_force_rms_error_pct: Quantiles | None = None
    true_force_max_error_pct: Quantiles | None = None
    touchdown_peak_ratio: Quantiles | None = None
    failures: dict[str, int] = Field(
        default_factory=dict, description="Unsuccessful trials by cause: force error, contact, aborted: <reason>."
    )


class Sensitivity(BaseModel):
    """How much one varied parameter drives one controller's failures."""

    model_config = ConfigDict(extra="forbid")

    parameter: SweepParameter
    controller: ControllerKind
    spearman_rms: float | None = Field(
        None,
        description="Spearman rank correlation of the parameter with the true RMS error (a trial without one, e.g. "
        "aborted, ranks worst); None when undefined (a constant column).",
    )
    success_low_half: float | None = Field(None, description="Success rate of the trials below the median value.")
    success_high_half: float | None = Field(None, description="Success rate of the trials above the median value.")
    success_difference: float | None = Field(None, description="success_high_half - success_low_half.")
    importance: float = Field(
        description="The ranking key: max(|spearman_rms|, |success_difference|) (0 where undefined)."
    )


class SweepCounts(BaseModel):
    """Progress over every trial x controller."""

    model_config = ConfigDict(extra="forbid")

    total: int
    finished: int
    succeeded: int
    running: int
    queued: int
    pending: int = Field(description="Not submitted yet (the sweep keeps a bounded number in the queue).")
    reruns: int = Field(description="Executions submitted again after an infrastructure failure.")


class SweepView(BaseModel):
    """``GET /sweeps/{id}``: state, progress and the results so far."""

    id: str
    status: SweepState
    created: float
    updated: float
    request: dict = Field(description="The request as given (an inline skill is not repeated).")
    counts: SweepCounts
    controllers: list[ControllerSummary]
    sensitivity: list[Sensitivity] = Field(description="Most important first.")
    progress_key: str = Field(description="Zenoh key of the live progress (`SweepProgress`).")


class SweepCreated(BaseModel):
    """``POST /sweeps``: the new sweep."""

    id: str = Field(examples=["sweep_3f2a9c01b2d4"])
    status: SweepState
    executions: int = Field(description="Executions the sweep will run (trials x controllers).")
    progress_key: str


class SweepProgress(BaseModel):
    """Payload of ``P/sweeps/{sweep_id}/progress`` (put on every change of the counts)."""

    model_config = ConfigDict(extra="forbid")

    sweep_id: str
    status: SweepState
    counts: SweepCounts
    success_rate: dict[str, float | None] = Field(description="Per controller, over the finished trials.")
