"""Robustness sweeps (``/sweeps``): one skill run over N sampled variations of its cell with several controllers.

A sweep draws N trials from the ranges asked for (Latin hypercube or scrambled Sobol, reproducible from the seed;
``skills.sweeps``) and runs every trial with every controller as one execution (the service's queue, at a priority
below single executions). A trial succeeds when its execution's VERDICT passes (``ExecutionMetrics.verdict``,
``execution.verdict.execution_verdict``): it ran every segment (``finished``) and, judged by the TRUE normal force
(the simulator's contact force along the true surface normal), its RMS error is ``<= success_rms_pct`` % of the
reference force (the learned constant of a slide, the profile peak of a contour; ``true_force_rms``), it stayed in
contact ``>= success_contact_ratio`` of its contact phase (``contact_ratio``), its largest steady error and its
touch-down peak are within the rest of ``settings.tolerances`` (``true_force_max``, ``touchdown``). The sweep writes
``success_rms_pct`` and ``success_contact_ratio`` into every trial's ``settings.tolerances`` (``true_force_rms_pct``,
``contact_ratio``), so the criteria stay the sweep's own; the others come from ``settings.tolerances``. A surface
found outside the expected window (``surface_found``) is a warning (with ``settings.surface_outside_window`` ``abort``
the trial aborts there). A failed trial's causes are its failed checks (``aborted: <reason>`` for one that did not
finish). A trial stored before executions had a verdict is judged as then: done, with the contact ratio and the true
RMS error within the two thresholds.

Units: SI, angles in degrees where a name says ``_deg`` (docs/CONVENTIONS.md).
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
    Engine,
    ExecutionMetrics,
    ExecutionSettings,
)
from schemas.numbers import Real, WholeNumber
from schemas.skill import Skill
from schemas.text import Identifier
from schemas.verdict import Verdict

MAX_TRIALS = 2000
"""Most trials of one sweep (each runs once per controller)."""
SWEEP_PRIORITY = -10
"""Queue priority of a sweep's executions: below a single execution's default (0), so one asked for meanwhile
starts first."""


class SweepParameter(StrEnum):
    """What a sweep can vary; each maps onto one `schemas.execution.EnvironmentChange` field, the cylinder's onto the
    skill's taught world (``skills.sweeps``)."""

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
    sensor_bias_x_n = "sensor_bias_x_n"
    """Untared force bias of the F/T sensor along world x, N (fixed in the world, as a misestimated tool weight)."""
    sensor_bias_y_n = "sensor_bias_y_n"
    """Untared force bias of the F/T sensor along world y, N."""
    sensor_bias_z_n = "sensor_bias_z_n"
    """Untared force bias of the F/T sensor along world z, N (negative reads as pressing down)."""
    sensor_offset_x_n = "sensor_offset_x_n"
    """The F/T sensor's own force offset along its (the tool's) x, N: its zero drifted since it was last zeroed; it
    turns with the tool, so the tare before contact removes it in every pose."""
    sensor_offset_y_n = "sensor_offset_y_n"
    """The same along the tool's y, N."""
    sensor_offset_z_n = "sensor_offset_z_n"
    """The same along the tool's z, N."""
    sensor_noise_n = "sensor_noise_n"
    """F/T sensor force noise, standard deviation per axis, N."""
    force_scale = "force_scale"
    """Factor on the skill's desired force profile (1)."""
    cylinder_radius_m = "cylinder_radius_m"
    """Radius of the cylinder of the skill's taught world, m, its crown (the top line) held where it was taught: the
    curvature changes, not the height (that is ``offset_z_m``). Only for a skill taught on a cylinder
    (:data:`CYLINDER_PARAMETERS`)."""
    cylinder_yaw_deg = "cylinder_yaw_deg"
    """Unknown turn of that cylinder about the table normal through its centre, from its taught yaw, deg."""


CYLINDER_PARAMETERS = frozenset({SweepParameter.cylinder_radius_m, SweepParameter.cylinder_yaw_deg})
"""The parameters that change the cylinder of the skill's taught world: a sweep may vary them only when its trials
run in that world and it has a cylinder (no ``scenario``, ``environment.work_piece`` auto or taught, a skill
recorded on ``contour_cylinder``); else ``POST /sweeps`` is a 422 naming the parameter (``skills.sweeps``)."""
MAX_CYLINDER_YAW_DEG = 45.0
"""Largest change of the cylinder's yaw, deg (beyond it a contour across the cylinder runs mostly along it)."""

PARAMETER_BOUNDS: dict[SweepParameter, tuple[float, float]] = {
    SweepParameter.offset_x_m: (-MAX_OFFSET_M, MAX_OFFSET_M),
    SweepParameter.offset_y_m: (-MAX_OFFSET_M, MAX_OFFSET_M),
    SweepParameter.offset_z_m: (-MAX_OFFSET_M, MAX_OFFSET_M),
    SweepParameter.tilt_x_deg: (-MAX_TILT_DEG, MAX_TILT_DEG),
    SweepParameter.tilt_y_deg: (-MAX_TILT_DEG, MAX_TILT_DEG),
    SweepParameter.friction: (0.0, 2.0),
    SweepParameter.contact_stiffness_n_m: (1e2, 1e7),
    SweepParameter.contact_damping_n_s_m: (0.0, 1e5),
    SweepParameter.sensor_bias_x_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_bias_y_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_bias_z_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_offset_x_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_offset_y_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_offset_z_n: (-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N),
    SweepParameter.sensor_noise_n: (0.0, MAX_SENSOR_NOISE_N),
    SweepParameter.force_scale: (0.05, MAX_FORCE_SCALE),
    SweepParameter.cylinder_radius_m: (0.02, 0.30),
    SweepParameter.cylinder_yaw_deg: (-MAX_CYLINDER_YAW_DEG, MAX_CYLINDER_YAW_DEG),
}
"""The range each parameter may be drawn from: the bounds of the `EnvironmentChange` field it sets; a cylinder of 2 to
30 cm (the tool's 1 cm pad follows the smallest), turned by up to ±45°."""


class Sampler(StrEnum):
    """How the trials are spread over the ranges (``scipy.stats.qmc``, seeded: same seed, same trials)."""

    lhs = "lhs"
    """Latin hypercube: each range cut into N equal strata, one trial in each, per parameter."""
    sobol = "sobol"
    """Scrambled Sobol sequence (best balanced when N is a power of 2)."""


class ParameterRange(BaseModel):
    """A uniform distribution over ``[low, high]`` (log-uniform with ``log``; ``low == high``: held fixed)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"low": -0.02, "high": 0.02}]})

    low: Real = Field(description="Lower end, in the parameter's unit.")
    high: Real = Field(description="Upper end, in the parameter's unit (>= low).")
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
    SweepParameter.offset_x_m: ParameterRange(low=-0.08, high=0.08),
    SweepParameter.offset_y_m: ParameterRange(low=-0.08, high=0.08),
    SweepParameter.offset_z_m: ParameterRange(low=-0.08, high=0.08),
    SweepParameter.tilt_x_deg: ParameterRange(low=-15.0, high=15.0),
    SweepParameter.tilt_y_deg: ParameterRange(low=-15.0, high=15.0),
    SweepParameter.friction: ParameterRange(low=0.1, high=0.5),
    SweepParameter.contact_stiffness_n_m: ParameterRange(low=1e4, high=1e5, log=True),
    SweepParameter.contact_damping_n_s_m: ParameterRange(low=100.0, high=1000.0, log=True),
    SweepParameter.sensor_bias_x_n: ParameterRange(low=-1.0, high=1.0),
    SweepParameter.sensor_bias_y_n: ParameterRange(low=-1.0, high=1.0),
    SweepParameter.sensor_bias_z_n: ParameterRange(low=-1.0, high=1.0),
    SweepParameter.sensor_offset_x_n: ParameterRange(low=-5.0, high=5.0),
    SweepParameter.sensor_offset_y_n: ParameterRange(low=-5.0, high=5.0),
    SweepParameter.sensor_offset_z_n: ParameterRange(low=-5.0, high=5.0),
    SweepParameter.sensor_noise_n: ParameterRange(low=0.0, high=2.0),
    SweepParameter.force_scale: ParameterRange(low=0.7, high=1.3),
}
"""What a real cell sees (the CLI's default ranges), not only what passes today: a part placed by hand or by a
fixture that is not measured, ±8 cm off in x, y and z and ±15° tilted; friction 0.1-0.5; a pad from 1e4 to 1e5 N/m;
±5 N of the wrist F/T sensor's own force offset on each of its axes (its zero drifting between tares: it turns with
the tool and the tare removes it in every pose), ±1 N more fixed in the world on each world axis (a tool weight
misestimated by up to 100 g: the tare before contact removes that only in the orientation it was taken in, a tool
turned by θ from there reads up to 2 |f| sin(θ/2) of it) and up to 2 N of noise (an unfiltered sensor on a vibrating
arm); ±30 % force level. Run with
:data:`DEFAULT_SETTINGS`: a fixed compliant frame cannot hold a 15° tilt, and the guarded approach has to expect the
surface anywhere within the offsets."""
CYLINDER_RANGES: dict[SweepParameter, ParameterRange] = {
    SweepParameter.cylinder_radius_m: ParameterRange(low=0.06, high=0.12),
    SweepParameter.cylinder_yaw_deg: ParameterRange(low=-15.0, high=15.0),
}
"""Added to :data:`DEFAULT_RANGES` for a skill taught on a cylinder (the CLI's defaults): another pipe, 6 to 12 cm
in radius where 8 cm was taught, its axis turned by up to ±15°."""
DEFAULT_SETTINGS = ExecutionSettings(
    follow_surface_normal=True,
    approach_clearance_m=0.12,
    approach_slow_distance_m=0.10,
    approach_max_distance_m=0.25,
)
"""The execution settings the CLI's default sweep starts every trial from (the ones it sets; the rest are the
defaults): ``hybrid_cf`` turns its CF z to the surface normal it measures (``follow_surface_normal``); the free
segment before a contact stops 12 cm short of the taught contact point and the guarded approach goes on for up to
25 cm, so a surface up to 12 cm higher or 13 cm lower than taught (±8 cm of offset, and what a ±15° tilt adds at the
start of a stroke) is met by the approach, at the touch-down speed over the last 10 cm on either side of the taught
point (the slow zone, also the verdict's surface window: a surface found farther away is a warning). The price,
measured on the teacher's skills with nothing changed: 2 s more of simulated approach on the 15 N slide_tilted slide
(12.7 -> 14.7 s), whose touch-down speed is the approach speed anyway, and 20 s more on the contour_cylinder contour
(18.6 -> 38.9 s), whose small first force makes it meet the surface at 3 mm/s; in CPU time of the control loop at
pace fast 0.99 -> 1.22 s (+23 %) and 1.12 -> 2.02 s (+80 %) an execution. A narrower slow zone would meet a surface
found beyond it at the approach speed, 10 times the contour's touch-down speed."""


SWEEP_TOLERANCES: dict[str, str] = {
    "success_rms_pct": "true_force_rms_pct",
    "success_contact_ratio": "contact_ratio",
}
"""The `SweepRequest` field that sets each of its trials' `schemas.execution.ExecutionTolerances` fields."""


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

    skill_id: Identifier | None = Field(None, description="Id of a stored skill (or give `skill` inline).")
    skill: Skill | None = Field(None, description="An inline skill (or give `skill_id`).")
    scenario: Identifier | None = Field(
        None, description="Teacher scenario whose world to run in (default: the skill's own world)."
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
    trials: WholeNumber = Field(20, ge=1, le=MAX_TRIALS, description="Number of sampled trials (N).")
    seed: WholeNumber = Field(
        0, ge=0, le=2**32 - 1, description="Seed of the sampler and of each trial's sensor noise."
    )
    sampler: Sampler = Field(Sampler.lhs, description="Latin hypercube or scrambled Sobol.")
    success_rms_pct: Real = Field(
        10.0,
        gt=0.0,
        le=1000.0,
        description="A trial succeeds when its execution's verdict passes; the verdict holds its TRUE normal-force RMS "
        "error to at most this, % of the reference force (written into every trial's "
        "settings.tolerances.true_force_rms_pct).",
    )
    success_contact_ratio: Real = Field(
        0.99,
        ge=0.0,
        le=1.0,
        description="... and its time in contact to at least this share of its contact phase (written into every "
        "trial's settings.tolerances.contact_ratio).",
    )
    settings: ExecutionSettings = Field(
        default_factory=ExecutionSettings,
        description="The execution settings every trial starts from (gains, pace, environment, tolerances); the sweep "
        "sets the varied fields of the environment, the controller, the telemetry (from store_telemetry) and the two "
        "tolerances of its success criteria (from success_rms_pct and success_contact_ratio). Every trial runs on "
        "settings.engine, when absent the engine their world names (the skill's taught world's `engine`, when the "
        "trials run in it), else pybullet: not each worker's own default (the trials spread over the workers and "
        "must compare like with like). The CLI's default sweep starts from DEFAULT_SETTINGS.",
    )
    store_telemetry: bool = Field(
        False,
        description="Stream and store every trial's telemetry (each trial's execution with telemetry 'stream', its "
        "GET /executions/{id}/telemetry served). Default false: telemetry 'none', nothing published, stored or "
        "kept (cheaper: docs/BENCHMARKS.md, bench_sweeps); every metric and the success rates are the same.",
    )
    priority: WholeNumber = Field(
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

    @field_validator("settings")
    @classmethod
    def _criteria_from_success_fields(cls, value: ExecutionSettings) -> ExecutionSettings:
        given = value.tolerances.model_fields_set & set(SWEEP_TOLERANCES.values())
        if given:
            spelled = ", ".join(f"{tolerance} (give {field})" for field, tolerance in SWEEP_TOLERANCES.items()
                                if tolerance in given)  # fmt: skip
            raise ValueError(f"tolerances: a sweep sets its trials' {spelled} from its own success criteria")
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
    engine: Engine = Field(
        Engine.pybullet, description="The physics engine it runs on: the sweep's settings.engine (every trial's)."
    )
    parameters: dict[SweepParameter, float] = Field(description="The values drawn for this trial.")
    execution_id: str | None = Field(None, description="The execution that ran it (the last, if it was rerun).")
    attempts: int = Field(0, description="Executions submitted for it (> 1: rerun after a lost worker or restart).")
    status: str = Field(description="The execution's status (queued, running, done, aborted, failed), or pending.")
    success: bool | None = Field(
        None, description="Whether its verdict passed, once finished (None while pending or running)."
    )
    verdict: Verdict | None = Field(
        None,
        description="Its execution's verdict against the sweep's tolerances, once finished (for a trial stored before "
        "executions had a verdict: the old rule's, done with the contact ratio and true RMS error within the "
        "thresholds).",
    )
    reasons: list[str] = Field(
        default_factory=list,
        description="Why it failed: the failed checks of its verdict, in words (empty on success and while running).",
    )
    causes: list[str] = Field(
        default_factory=list,
        description="Its failure causes as ControllerSummary.failures counts them: the names of its verdict's failed "
        "checks (true_force_rms, true_force_max, contact_ratio, touchdown), or 'aborted: <reason>' for one that did "
        "not finish (empty on success and while running).",
    )
    true_force_rms_error_pct: Real | None = None
    true_force_max_error_pct: Real | None = None
    touchdown_peak_ratio: Real | None = None
    contact_ratio: Real | None = None
    abort_reason: str | None = Field(None, description="Why it stopped early, if it did.")
    metrics: ExecutionMetrics | None = Field(None, description="Every metric of the execution, once finished.")


class Quantiles(BaseModel):
    """10th, 50th and 90th percentile and the largest value over the trials that have the measure."""

    model_config = ConfigDict(extra="forbid")

    p10: Real
    p50: Real
    p90: Real
    max: Real
    n: int = Field(description="Trials with the measure (finished with contact).")


class ControllerSummary(BaseModel):
    """How one controller did over the finished trials."""

    model_config = ConfigDict(extra="forbid")

    controller: ControllerKind
    trials: int = Field(description="Trials of the sweep.")
    finished: int = Field(description="Trials with a result.")
    succeeded: int
    success_rate: Real | None = Field(None, description="succeeded / finished (None before any finished).")
    true_force_rms_error_pct: Quantiles | None = None
    true_force_max_error_pct: Quantiles | None = None
    touchdown_peak_ratio: Quantiles | None = None
    failures: dict[str, int] = Field(
        default_factory=dict,
        description="Unsuccessful trials by cause, most frequent first: each failed check of a verdict "
        "(true_force_rms, true_force_max, contact_ratio, touchdown), or 'aborted: <reason>' for a trial that did not "
        "finish; a trial that failed several checks counts under each.",
    )
    warnings: dict[str, int] = Field(
        default_factory=dict,
        description="Finished trials whose verdict warned, by check (surface_found: the surface was found outside the "
        "expected window), pass or fail.",
    )


class Sensitivity(BaseModel):
    """How much one varied parameter drives one controller's failures."""

    model_config = ConfigDict(extra="forbid")

    parameter: SweepParameter
    controller: ControllerKind
    spearman_rms: Real | None = Field(
        None,
        description="Spearman rank correlation of the parameter with the true RMS error (a trial without one, e.g. "
        "aborted, ranks worst); None when undefined (a constant column).",
    )
    success_low_half: Real | None = Field(None, description="Success rate of the trials below the median value.")
    success_high_half: Real | None = Field(None, description="Success rate of the trials above the median value.")
    success_difference: Real | None = Field(None, description="success_high_half - success_low_half.")
    importance: Real = Field(
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
    created: Real
    updated: Real
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
