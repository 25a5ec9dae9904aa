"""What an execution achieved (:class:`ExecutionMetrics`): errors of the true normal force, contact, the verdict,
timings. SI units, percentages of the desired force."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from schemas.execution.environment import Offset3, Placement
from schemas.execution.settings import ControllerKind, Engine
from schemas.execution.telemetry import ExecutionPhase
from schemas.numbers import Real
from schemas.verdict import ExecutionVerdict, SurfacePressed


class ExecutionMetrics(BaseModel):
    """What an execution achieved (execution/metrics.py); None where a measure does not apply."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "controller": "hybrid_cf",
                    "phase": "done",
                    "force_rms_error_n": 0.21,
                    "force_rms_error_pct": 1.4,
                    "force_max_error_n": 0.9,
                    "force_max_error_pct": 6.0,
                    "force_reference_n": 15.0,
                    "path_rms_m": 0.0012,
                    "contact_ratio": 1.0,
                    "real_time_factor": 9.5,
                    "duration_s": 6.2,
                    "peak_force_n": 17.3,
                    "abort_reason": None,
                }
            ]
        },
    )

    controller: ControllerKind = Field(description="The control law that ran.")
    engine: Engine = Field(Engine.pybullet, description="The physics engine it ran on.")
    phase: ExecutionPhase = Field(description="Final phase: done, aborted or failed.")
    force_rms_error_n: Real | None = Field(
        None,
        description="RMS of (measured - desired) CF-z force over the steady contact phase (each contact segment "
        "from max(0.2 s, force_ramp_s) after its start), N.",
    )
    force_rms_error_pct: Real | None = Field(
        None, description="The same in % of the reference force (learned constant; contour: profile peak)."
    )
    force_max_error_n: Real | None = Field(
        None, description="Largest |measured - desired| CF-z force over the steady contact phase, N."
    )
    force_max_error_pct: Real | None = Field(None, description="The same in % of the reference force.")
    force_reference_n: Real | None = Field(
        None, description="The force the % refer to: the learned constant (slide) or the profile peak (contour), N."
    )
    path_rms_m: Real | None = Field(
        None,
        description="RMS distance of the executed tool path to the (shifted) demonstrated path in the motion "
        "subspace (CF x-y), over the contact phase, m.",
    )
    contact_ratio: Real | None = Field(
        None,
        ge=0,
        le=1,
        description="Share of contact-phase time in contact (the simulator reports a tool contact point).",
    )
    real_time_factor: Real = Field(description="Simulated time / wall-clock time of the control loop (1).")
    duration_s: Real = Field(description="Simulated duration of the execution, s.")
    steps: int = Field(description="Control steps run.")
    peak_force_n: Real = Field(description="Largest measured contact force magnitude, N.")
    contact_found_offsets_m: list[float] = Field(
        default_factory=list,
        description="Per guarded approach: where contact was found along +CF z relative to the expected "
        "(known-offset-shifted) surface, m (positive = deeper than taught).",
    )
    contour_relocations_m: list[Offset3] = Field(
        default_factory=list,
        description="Per contour relocated (follow_surface_normal): the move of the part [dx, dy, dz] (m, world) its "
        "touch-down found, from the normal it pressed on matched against the taught ones; the contour then ran "
        'where the part is (docs/EXECUTION.md, "Following the surface").',
    )
    steady_contact_s: Real = Field(0.0, description="Length of the steady contact phase the force errors cover, s.")
    abort_reason: str | None = Field(None, description="Why the execution stopped early, or None.")
    work_piece: str | None = Field(
        None,
        description="What the skill ran on: 'taught', 'scenario', 'given' (a world file), 'measured' (from the "
        "demonstration) or 'rebuilt' (from the skill).",
    )
    placement: Placement | None = Field(None, description="The placement applied to the skill and work piece.")
    true_force_rms_error_n: Real | None = Field(
        None,
        description="RMS of (force along the TRUE surface normal at the contact - desired) over the steady contact "
        "phase, N: the simulator's exact contact force, whatever the learned CF or the sensor say.",
    )
    true_force_rms_error_pct: Real | None = Field(None, description="The same in % of the reference force.")
    true_force_in_band: Real | None = Field(
        None,
        ge=0,
        le=1,
        description="Skills learned from several demonstrations: the share of the contact whose true normal force lies "
        "within the force band the demonstrations pressed (aligned to it by the tool's path; None: no band).",
    )
    true_force_max_error_n: Real | None = Field(
        None, description="Largest |true normal force - desired| over the steady contact phase, N."
    )
    true_force_max_error_pct: Real | None = Field(None, description="The same in % of the reference force.")
    touchdown_peak_n: Real | None = Field(
        None,
        description="Largest true normal force from each first touch until the contact phase is steady, N "
        "(the impact of the guarded approach and the force ramp).",
    )
    touchdown_peak_ratio: Real | None = Field(
        None,
        description="The largest touch-down peak over the press that follows it (the desired force where its steady "
        "contact starts; 1 = no overshoot): what the touchdown check holds to its tolerance.",
    )
    touchdown_contact_force_ratio: Real | None = Field(
        None,
        description="The largest touch-down peak over the force its contact segment asks at contact (the first "
        "desired force; a contour's profile may start far below its press), reported beside the checked ratio.",
    )
    exit_collision_n: Real | None = Field(
        None,
        description="Largest true normal force where a free segment after a contact hit the part on the way out, N "
        "(None: no hit).",
    )
    settle_time_s: Real | None = Field(
        None,
        description="Longest time from a first touch until the true normal force stays within 5 % of the desired "
        "force (of the reference), s.",
    )
    cf_normal_angle_deg: Real | None = Field(
        None,
        description="Mean angle between the CF z the controller used (the learned one, or the one it turned to with "
        "follow_surface_normal) and the true surface normal, over the contact-phase steps that touched, deg.",
    )
    cf_normal_angle_max_deg: Real | None = Field(
        None, description="Largest angle between the CF z the controller used and the true surface normal, deg."
    )
    surfaces_pressed: list[SurfacePressed] = Field(
        default_factory=list,
        description="Per contact segment that touched: where it pressed against where it was taught, told by the "
        "surface normals (docs/EXECUTION.md).",
    )
    transition_true_force_max_error_n: Real | None = Field(
        None,
        description="Largest |true normal force - desired| within 0.25 s of a switch between two contact segments "
        "(a crease passage, a slide-to-contour switch), N; None without such a switch. Part of the steady window.",
    )
    transition_true_force_max_error_pct: Real | None = Field(None, description="The same in % of the reference.")
    contact_threshold_n: Real | None = Field(
        None,
        description="The force along CF z (tared) at which the last guarded approach took the surface as found, N: "
        "the skill's base threshold, raised when the noise measured while taring needs it.",
    )
    contact_persistence_steps: int | None = Field(
        None, description="How many consecutive control steps' mean reading had to pass that threshold."
    )
    verdict: ExecutionVerdict | None = Field(
        None, description="Pass or fail against the tolerances, with reasons (None only for stored older runs)."
    )
    strokes: list[ExecutionMetrics] | None = Field(
        None,
        description="A skill whose strokes no single placement reaches runs one stroke at a time, each placed on its "
        "own: each stroke's own metrics, in order (the figures above combine them: RMS over all their steady "
        "contact, the largest max, the verdict fails when one of them fails). None for a single run.",
    )
