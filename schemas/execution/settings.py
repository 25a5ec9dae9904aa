"""How to execute a skill: the controller (:class:`ControllerKind`, :class:`ControllerGains`, the null-space
projection, the surface window), the guarded approach, the pace, and the request naming the skill
(:class:`ExecutionSettings`, :class:`ExecutionRequest`). SI units (docs/CONVENTIONS.md)."""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.execution.environment import EnvironmentChange
from schemas.execution.telemetry import TelemetryMode
from schemas.numbers import Real, WholeNumber, bounded_triple
from schemas.skill import Skill
from schemas.text import Identifier
from schemas.verdict import ExecutionTolerances

Stiffness3 = bounded_triple(0.0, 1e5)
"""Translational stiffness or damping diagonal: 0 to 1e5 (N/m, N·s/m), beyond any real arm's impedance."""
RotStiffness3 = bounded_triple(0.0, 1e4)
"""Rotational stiffness or damping diagonal: 0 to 1e4 (N·m/rad, N·m·s/rad)."""


MAX_PAUSE_TIMEOUT_S = 3600.0
"""Longest a paused execution may wait for resume before it is aborted, s."""


class ControllerKind(StrEnum):
    """Which control law runs the skill (``skills.control``).

    - ``hybrid_cf`` (ours, paper eq. 1-4): impedance on the CF motion axes, PI force control
      with feed-forward on the CF force axis (CF z), frames from the skill.
    - ``impedance``: pure Cartesian impedance, ``S = I`` everywhere, no force loop; the force
      only as the pose reference implies it (the reference is pushed ``f_desired / k_z``
      into the TAUGHT surface along CF z): it cannot know that the surface moved.
    - ``impedance_found_surface``: the same law with its reference re-based where the guarded
      approach FOUND the surface (``f_desired / k_z`` beyond the found contact point): the fair
      classical baseline when the surface is not where it was taught.
    - ``hybrid_world_z``: the classical hybrid controller of earlier work, force control fixed
      to the world z axis (pressing down, -z_world) whatever the skill's CF says.
    """

    hybrid_cf = "hybrid_cf"
    impedance = "impedance"
    impedance_found_surface = "impedance_found_surface"
    hybrid_world_z = "hybrid_world_z"

    @property
    def is_impedance(self) -> bool:
        """Pure impedance (no force loop), whichever surface its reference is based on."""
        return self in (ControllerKind.impedance, ControllerKind.impedance_found_surface)


class NullSpaceProjection(StrEnum):
    """How the posture torque is kept out of the task space (7-DoF arm, 6-D task)."""

    dynamic = "dynamic"
    """Dynamically consistent, ``I - J^T (J M^-1 J^T)^-1 J M^-1`` (needs the mass matrix)."""
    static = "static"
    """``I - J^T J^{+T}`` with the (damped) Moore-Penrose pseudo-inverse; no mass matrix."""


class Pace(StrEnum):
    """How fast simulated time runs relative to the wall clock."""

    realtime = "realtime"
    fast = "fast"


class Engine(StrEnum):
    """The physics engine an execution runs on (docs/ENGINES.md): the same cell, controller and truth on either."""

    pybullet = "pybullet"
    """PyBullet (``sim_worker``): the compiled 1 kHz loop."""
    mujoco = "mujoco"
    """MuJoCo (``sim_mujoco``): the same world built from the same URDF and world config, its loop in Python."""


DEFAULT_ENGINE = Engine.pybullet
"""The engine of an execution that names none in a world that names none (``WorldConfig.engine``), where no worker
chose another (``contact-skills worker --engine``): the local runs (``contact-skills simulate``), a worker started
without one, and every sweep that names none in such a world."""


class SurfaceWindowAction(StrEnum):
    """What a guarded approach does when it finds the surface outside the window it was taught to expect."""

    report = "report"
    """Go on (the force is still measured); the verdict carries a warning naming the distance."""
    abort = "abort"
    """Stop there: retract and abort with the distance in the reason (the part is not where the skill expects it)."""


class GainSchedule(StrEnum):
    """How the CF translational stiffness on the motion axes (CF x, y) is set along a contact segment
    (``skills.gain_schedule``; docs/EXECUTION.md, "A gain schedule from the demonstrations' spread")."""

    constant = "constant"
    """The configured stiffness everywhere."""
    from_spread = "from_spread"
    """From the spread of the demonstrations the skill was learned from (``Segment.motion_spread``), phase by phase:
    the configured stiffness where they agree, down to a floor where they vary (stiffness ~ 1 / variance, clipped),
    the damping matched to it by the damping ratio. Needs a skill learned from several demonstrations."""


class ControllerGains(BaseModel):
    """Gains and limits of the hybrid impedance/force controller (defaults work for the simulated iiwa).

    Stiffness and damping are diagonals in the compliant frame (CF) with its origin at the tool
    point; the force gains act on the CF force axes (CF z for slide and contour).
    """

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "translational_stiffness_n_per_m": [3000.0, 3000.0, 3000.0],
                    "rotational_stiffness_nm_per_rad": [40.0, 40.0, 40.0],
                    "damping_ratio": 0.8,
                    "force_kp": 0.3,
                    "force_ki": 10.0,
                    "max_force_n": 80.0,
                }
            ]
        },
    )

    translational_stiffness_n_per_m: Stiffness3 = Field(
        default_factory=lambda: [3000.0, 3000.0, 3000.0],
        description="CF translational stiffness K_c (x, y, z), N/m; only the motion axes use it.",
    )
    rotational_stiffness_nm_per_rad: RotStiffness3 = Field(
        default_factory=lambda: [40.0, 40.0, 40.0],
        description="CF rotational stiffness K_c (rx, ry, rz), N·m/rad.",
    )
    damping_ratio: Real = Field(
        0.8,
        gt=0,
        le=2.0,
        description="Damping ratio zeta of the Cartesian damping d_i = 2 zeta sqrt(K_i m_i), m_i the apparent "
        "inertia of CF axis i from the mass matrix (1).",
    )
    apparent_mass_kg: Real = Field(
        3.0,
        gt=0,
        le=1000,
        description="Nominal translational apparent mass for the damping ratio before/without a mass matrix, kg.",
    )
    apparent_inertia_kgm2: Real = Field(
        0.002,
        gt=0,
        le=100,
        description="Nominal rotational apparent inertia for the damping ratio before/without a mass matrix, kg·m² "
        "(small: the iiwa's inertia about the tool axis is ~0.001 kg·m²).",
    )
    translational_damping_ns_per_m: Stiffness3 | None = Field(
        None, description="Explicit CF translational damping (x, y, z), N·s/m; overrides the damping ratio."
    )
    rotational_damping_nms_per_rad: RotStiffness3 | None = Field(
        None, description="Explicit CF rotational damping (rx, ry, rz), N·m·s/rad; overrides the damping ratio."
    )
    force_axis_damping_ns_per_m: Real = Field(
        150.0,
        ge=0,
        le=1e5,
        description="Damping of the tool velocity along the CF force axes, N·s/m (keeps the force loop "
        "stable on a stiff surface; the motion axes use the translational damping).",
    )
    force_kp: Real = Field(0.3, ge=0, le=100, description="Proportional force gain K_p, N per N of force error (1).")
    force_ki: Real = Field(10.0, ge=0, le=1e4, description="Integral force gain K_i, N per N·s of force error (1/s).")
    force_integral_limit_n: Real = Field(
        20.0, ge=0, le=1000, description="Anti-windup: bound on |K_i ∫e_f dt| per CF force axis, N."
    )
    nullspace_stiffness_nm_per_rad: Real = Field(
        10.0,
        ge=0,
        le=1e4,
        description="Joint stiffness of the null-space posture task (to the start posture), N·m/rad.",
    )
    nullspace_damping_nms_per_rad: Real = Field(
        1.0, ge=0, le=1e3, description="Joint damping of the null-space posture task, N·m·s/rad."
    )
    null_space: NullSpaceProjection = Field(
        NullSpaceProjection.dynamic, description="Null-space projector: dynamically consistent or static."
    )
    max_force_n: Real = Field(
        80.0, gt=0, le=1000, description="Abort threshold on the measured contact force magnitude, N."
    )
    torque_saturation_abort_s: Real = Field(
        0.2,
        gt=0,
        le=10,
        description="Abort when the torque command stays at a joint's limit (from the robot) this long, s.",
    )
    force_ramp_s: Real = Field(
        0.25,
        ge=0,
        le=10,
        description="Time to ramp the desired force from the contact force to its target after contact, s.",
    )
    force_release_s: Real = Field(
        0.1, ge=0, le=10, description="Time to ramp the desired force down to zero after a contact segment, s."
    )
    contact_force_threshold_n: Real | None = Field(
        None,
        gt=0,
        le=1000,
        description="CF-z force that counts as contact for the guarded approach (and ends a guarded free "
        "segment early), N; default: 10 % of the skill's reference force, within [1, 3] N.",
    )
    gain_schedule: GainSchedule = Field(
        GainSchedule.constant,
        description="constant: translational_stiffness_n_per_m everywhere. from_spread: along each contact segment "
        "the CF x and y stiffness follow the spread of the demonstrations the skill was learned from, phase by "
        "phase: the configured stiffness where they agree, down to a floor where they vary (stiffness ~ "
        "1 / variance, clipped; docs/EXECUTION.md), the damping kept at the damping ratio; a skill learned from one "
        "demonstration has no spread and is refused (422).",
    )


class ExecutionSettings(BaseModel):
    """How to execute a skill: world change, controller, gains, guarded approach, pace (no skill reference)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "environment": {"offset": [0.0, 0.0, 0.0], "unknown_offset": [0.0, 0.0, 0.03]},
                    "controller": "hybrid_cf",
                    "pace": "fast",
                }
            ]
        },
    )

    environment: EnvironmentChange = Field(default_factory=EnvironmentChange)
    controller: ControllerKind = Field(ControllerKind.hybrid_cf, description="The control law.")
    engine: Engine | None = Field(
        None,
        description="The physics engine the execution runs on: pybullet (the compiled loop) or mujoco (the same "
        "cell in MuJoCo, the same controller and truth; its loop in Python, slower). Absent (null): the engine "
        "its world names (the world's `engine`), else that of the worker that runs it (`contact-skills worker "
        "--engine`, pybullet unless set; a sweep: pybullet, never a worker's); the metrics say which ran. "
        "docs/ENGINES.md.",
    )
    gains: ControllerGains = Field(default_factory=ControllerGains)
    approach_speed_m_s: Real = Field(
        0.03,
        gt=0,
        le=0.2,
        description="Speed of the guarded approach along +CF z until approach_slow_distance_m before the taught "
        "contact point, m/s.",
    )
    approach_slow_distance_m: Real = Field(
        0.02,
        ge=0,
        le=0.5,
        description="The last part of the guarded approach before the taught contact point (and any distance beyond "
        "it) runs at the touch-down speed, m: as far as the surface may be from where it was taught.",
    )
    touchdown_speed_m_s: Real | None = Field(
        None,
        gt=0,
        le=0.2,
        description="Speed at which the tool meets the surface, m/s; default: from the first target force F and the "
        "contact stiffness k and damping c so that the impact stays below the target (v = 0.8 max(F, F_c) / "
        "max(sqrt(k m), c), m the arm's apparent mass along CF z, F_c the contact threshold, which the approach has "
        "to pass anyway), within [0.5 mm/s, approach_speed_m_s].",
    )
    planned_contact_stiffness_n_m: Real | None = Field(
        None,
        ge=1e2,
        le=1e7,
        description="The pad stiffness the touch-down and crease speeds are planned for, N/m: what the cell believes "
        "(its nominal pad). Default: the simulated world's own, as if the cell knew its pad exactly. A sweep that "
        "varies the pad plans for its base pad, so the variation stays unknown to the controller.",
    )
    planned_contact_damping_n_s_m: Real | None = Field(
        None,
        ge=0.0,
        le=1e5,
        description="The pad damping the touch-down and crease speeds are planned for, N·s/m (as "
        "planned_contact_stiffness_n_m).",
    )
    approach_max_distance_m: Real = Field(
        0.15, gt=0, le=0.5, description="Longest guarded approach before aborting with 'contact not found', m."
    )
    approach_clearance_m: Real = Field(
        0.06,
        ge=0,
        le=0.3,
        description="The free segment before a contact segment ends this far before the taught contact point "
        "(back along CF z); the guarded approach covers the rest, m.",
    )
    pace: Pace = Field(
        Pace.fast, description="realtime: simulated time follows the wall clock; fast: as fast as possible."
    )
    follow_surface_normal: bool | None = Field(
        None,
        description="hybrid_cf: every contact phase follows the surface it meets: the CF z turns towards the normal "
        "estimated online from the applied force without its friction part (contours: within 75 deg of the taught "
        "one; slides: 40 deg), a contour's path is re-anchored where the surface was found and kept on it (relocated "
        "when the touch-down presses on a normal taught elsewhere on its path), and consecutive contact segments "
        "switch where the next surface is met. Off: the paper's fixed CF. Default (null): on for a skill whose "
        "contact segments are all slides, off for one with a contour, as measured over moved, tilted, resized, "
        "swapped and missing parts (docs/EXECUTION.md, 'Following the surface, or not').",
    )
    tare_sensor: bool = Field(
        True,
        description="Tare the wrist force/torque sensor in free space before contact, as a real cell does: the tool "
        "holds still for 0.2 s at the start pose and at the pre-contact point before each later guarded approach, "
        "and the mean reading of the last 0.1 s (tool frame) is removed from every reading after it. Removes the "
        "sensor's offset and drift so far; an offset fixed in the world (a misestimated tool weight) only in the "
        "orientation of the tare. Off: the readings keep whatever offset the sensor has. The ideal sensor is never "
        "tared.",
    )
    settle_s: Real = Field(
        0.5, ge=0, le=10, description="Time to settle at the start pose before the first segment, s."
    )
    tolerances: ExecutionTolerances = Field(
        default_factory=ExecutionTolerances, description="What the execution must achieve to pass its verdict."
    )
    surface_outside_window: SurfaceWindowAction = Field(
        SurfaceWindowAction.report,
        description="A guarded approach that finds the surface farther from where it was taught than the "
        "tolerances' surface window: report (go on; the verdict warns) or abort.",
    )
    pause_timeout_s: Real = Field(
        300.0,
        gt=0,
        le=MAX_PAUSE_TIMEOUT_S,
        description="A paused execution that is not resumed within this time is aborted (reason 'paused for "
        "longer than pause_timeout_s'), so a forgotten pause never holds a worker, s.",
    )
    telemetry_batch: WholeNumber = Field(
        10,
        ge=1,
        le=10000,
        description="Control steps per telemetry batch handed to subscribers (1 kHz / 10 = 100 batches/s: "
        "per-sample p99 latency ~10 ms on loopback; 50 would be ~50 ms, mostly waiting for the batch to fill).",
    )
    telemetry: TelemetryMode = Field(
        TelemetryMode.stream,
        description="stream: every control step is published on the bus, stored and served by "
        "GET /executions/{id}/telemetry. none: no telemetry is published, stored or kept by the worker (that "
        "endpoint answers 409 saying so); the statuses and the final metrics, computed in the worker from every "
        "step, are the same as with stream. A sweep's trials run with none unless it asks for store_telemetry.",
    )


class ExecutionRequest(ExecutionSettings):
    """Run a skill in simulation (``POST /executions``): which skill and world, plus the execution settings."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "skill_id": "sk_3f2a",
                    "scenario": "slide_flat",
                    "environment": {"offset": [0.0, 0.0, 0.0], "unknown_offset": [0.0, 0.0, 0.03]},
                    "controller": "hybrid_cf",
                    "pace": "fast",
                }
            ]
        },
    )

    skill_id: Identifier | None = Field(None, description="Id of a stored skill (or give `skill` inline).")
    skill: Skill | None = Field(None, description="An inline skill (or give `skill_id`).")
    scenario: Identifier | None = Field(
        None,
        description="Teacher scenario whose world to build (the world the skill was taught in); "
        "default: the one named by the skill's demonstration.",
        examples=["slide_flat"],
    )

    priority: WholeNumber = Field(
        0,
        ge=-100,
        le=100,
        description="Queue priority: when every worker is busy, higher priorities start first; equal ones in the "
        "order they were submitted.",
    )

    @model_validator(mode="after")
    def _one_skill(self) -> ExecutionRequest:
        if (self.skill_id is None) == (self.skill is None):
            raise ValueError("give exactly one of skill_id (a stored skill) or skill (inline)")
        return self
