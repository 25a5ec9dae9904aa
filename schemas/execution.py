"""Executing a learned skill: the request, the controller settings, telemetry and the measured result.

Conventions (docs/CONVENTIONS.md): SI units; quaternions scalar-last ``[x, y, z, w]``; 6-vectors
``[x, y, z, rx, ry, rz]``; wrenches are the wrench the TOOL APPLIES TO THE ENVIRONMENT at the
tool point, in the world frame unless a field says CF. The compliant frame (CF) z axis points
into the surface, so the desired normal force is a positive CF ``f_z``.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.demonstration import Quaternion, Vector3, Wrench
from schemas.numbers import Real, WholeNumber
from schemas.skill import Skill
from schemas.text import Identifier
from schemas.verdict import ExecutionTolerances, ExecutionVerdict, SurfacePressed


def _triple(low: float, high: float) -> type[list[float]]:
    """Three numbers, each within [low, high] (the bound is declared in the OpenAPI and enforced)."""
    return Annotated[list[Annotated[Real, Field(ge=low, le=high)]], Field(min_length=3, max_length=3)]  # type: ignore[return-value]


Stiffness3 = _triple(0.0, 1e5)
"""Translational stiffness or damping diagonal: 0 to 1e5 (N/m, N·s/m), beyond any real arm's impedance."""
RotStiffness3 = _triple(0.0, 1e4)
"""Rotational stiffness or damping diagonal: 0 to 1e4 (N·m/rad, N·m·s/rad)."""
MAX_OFFSET_M = 1.0
"""Largest work-piece offset per axis, m: further than that it is another work cell, not a moved piece."""
Offset3 = _triple(-MAX_OFFSET_M, MAX_OFFSET_M)
MAX_TILT_DEG = 30.0
"""Largest unknown tilt of the work piece about each axis, deg."""
Tilt2 = Annotated[list[Annotated[Real, Field(ge=-MAX_TILT_DEG, le=MAX_TILT_DEG)]], Field(min_length=2, max_length=2)]
MAX_SENSOR_BIAS_N = 50.0
"""Largest untared force bias of the sensor per axis, N (a 10 % offset of a large wrist sensor's range)."""
Bias3 = _triple(-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N)
MAX_SENSOR_NOISE_N = 20.0
"""Largest sensor force noise (standard deviation), N."""
MAX_FORCE_SCALE = 5.0
"""Largest factor on a skill's force profile."""
MAX_PAUSE_TIMEOUT_S = 3600.0
"""Longest a paused execution may wait for resume before it is aborted, s."""
NOMINAL_CONTACT_STIFFNESS_N_M = 3.0e4
"""The tool pad's contact stiffness of a world that sets none (the simulated worlds' default), N/m."""
NOMINAL_CONTACT_DAMPING_N_S_M = 300.0
"""The tool pad's contact damping of a world that sets none, N·s/m."""


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


class TelemetryMode(StrEnum):
    """Whether an execution's control steps leave the worker (the metrics are computed in the worker either way)."""

    stream = "stream"
    """Every control step published on the bus, stored by the API, kept by the worker for replays."""
    none = "none"
    """Nothing published, stored or kept: only the statuses and the final metrics (robustness sweeps, where the
    35-column stream of ~10 000 steps per trial costs as much CPU as the physics)."""


class ExecutionPhase(StrEnum):
    """Phase of an execution (reported in telemetry and status)."""

    pending = "pending"
    """Accepted, not started."""
    settle = "settle"
    """Moving to the skill's start pose and settling there (free space, impedance)."""
    free = "free"
    """A free segment: motion control on all axes (S = I)."""
    approach = "approach"
    """Guarded approach along +CF z until contact, then the force ramps to the desired value."""
    contact = "contact"
    """A contact segment: hybrid motion/force control in the CF."""
    retreat = "retreat"
    """Ramping the force down after a contact segment, before the next free segment lifts off."""
    done = "done"
    """Finished every segment."""
    aborted = "aborted"
    """Stopped by a safety limit (force, torque, contact not found, non-finite state) or on request."""
    failed = "failed"
    """Stopped by an internal error (see the abort reason)."""


PHASE_CODES: dict[ExecutionPhase, int] = {phase: code for code, phase in enumerate(ExecutionPhase)}
"""Small-integer code of each phase, used in the columnar telemetry arrays."""


class SurfaceWindowAction(StrEnum):
    """What a guarded approach does when it finds the surface outside the window it was taught to expect."""

    report = "report"
    """Go on (the force is still measured); the verdict carries a warning naming the distance."""
    abort = "abort"
    """Stop there: retract and abort with the distance in the reason (the part is not where the skill expects it)."""


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


class Placement(BaseModel):
    """A rigid transform from the skill's frame (the recording's: another robot's base, a tracker's world) into
    the simulated robot's world: ``x_world = R x_skill + translation_m``, ``R`` from ``rotation``."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"translation_m": [0.55, 0.0, 0.2], "rotation": [0.0, 0.0, 0.0, 1.0]}]},
    )

    translation_m: Vector3 = Field(description="Translation, m (world frame).")
    rotation: Quaternion = Field(
        default_factory=lambda: [0.0, 0.0, 0.0, 1.0],
        description="Rotation world-from-skill, unit quaternion [x, y, z, w] (normalized on use).",
    )
    tool_alignment: Quaternion = Field(
        default_factory=lambda: [0.0, 0.0, 0.0, 1.0],
        description="A constant rotation of the tool frame, [x, y, z, w], right-multiplied onto every learned tool "
        "orientation so that the simulated tool presses along its own axis as the recorded tool pressed along "
        "its mean pressing direction (identity when the recording's tool frame already does).",
    )

    @model_validator(mode="after")
    def _finite(self) -> Placement:
        values = [*self.translation_m, *self.rotation, *self.tool_alignment]
        if not all(math.isfinite(v) for v in values):
            raise ValueError("placement values must be finite")
        if max(abs(v) for v in self.translation_m) > 100.0:
            raise ValueError("placement translation_m beyond 100 m: give metres")
        for q in (self.rotation, self.tool_alignment):
            if math.fsum(v * v for v in q) < 1e-6:
                raise ValueError("placement quaternions must be unit quaternions (a norm of ~0 was given)")
        return self


class WorkPieceSource(StrEnum):
    """Which work piece an execution runs on."""

    auto = "auto"
    """The taught world when the skill carries one (a simulator recording), else the work piece measured from the
    demonstration when it is given, else the one rebuilt from the skill."""
    taught = "taught"
    """The world the demonstration was recorded in (the skill must carry it)."""
    rebuilt = "rebuilt"
    """Surfaces rebuilt from what the skill learned: a plane under each slide segment, a strip along each contour."""
    measured = "measured"
    """Surfaces fitted to what the demonstration measured (its contact points and friction-free force directions),
    one smooth surface per pass, whatever type the skill learned (needs the demonstration)."""


class SensorChoice(StrEnum):
    """The force/torque sensor the controller reads (``sim_worker.sensor``)."""

    wrist = "wrist"
    """A realistic wrist sensor between flange and tool: tool weight compensated, its inertia not; 0.06 N noise,
    bias drift, 2 ms delay, 200 Hz driver low-pass."""
    ideal = "ideal"
    """The exact contact wrench (for tests of the control law)."""


class EnvironmentChange(BaseModel):
    """Which world the skill runs in and how it differs from the one the skill was taught in."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"offset": [0.02, 0.0, 0.0], "unknown_offset": [0.0, 0.0, 0.03]}]},
    )

    work_piece: WorkPieceSource = Field(
        WorkPieceSource.auto,
        description="Taught world, work piece measured from the demonstration, or rebuilt from the skill (auto: taught "
        "if known, else measured if the demonstration is given).",
    )
    placement: Placement | None = Field(
        None,
        description="Where the skill (and its rebuilt work piece) goes in the robot's world; default: none for a "
        "taught world or a skill already in reach, else one chosen to put the path in the arm's comfortable reach "
        "(reported in the metrics).",
    )
    friction: Real | None = Field(
        None, ge=0.0, le=2.0, description="Tool-surface friction coefficient (default: the world's, 0.2)."
    )
    contact_stiffness_n_m: Real | None = Field(
        None,
        ge=1e2,
        le=1e7,
        description="Contact stiffness of the tool pad, N/m (default: the world's, 3e4). The controller side knows "
        "it (the touch-down speed is planned for it) unless planned_contact_stiffness_n_m says otherwise.",
    )
    contact_damping_n_s_m: Real | None = Field(
        None,
        ge=0.0,
        le=1e5,
        description="Contact damping of the tool pad, N·s/m (default: the world's, 300); known to the controller "
        "side unless planned_contact_damping_n_s_m says otherwise.",
    )
    sensor: SensorChoice = Field(SensorChoice.wrist, description="The force/torque sensor the controller reads.")
    sensor_bias_n: Bias3 = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="A constant force offset of every sensor reading [fx, fy, fz], world frame, N (as a "
        "misestimated tool weight; the controller is not told). The tare before contact (tare_sensor) removes it "
        "in the tool orientation of the tare; what the tool turns away from it stays.",
    )
    sensor_offset_tool_n: Bias3 = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="The sensor's own force offset [fx, fy, fz] in the TOOL (sensor) frame, N: the zero its strain "
        "gauges drift to between tares (several N on real sensors). It turns with the tool, so the tare before "
        "contact removes it in every pose; the controller is not told.",
    )
    sensor_noise_n: Real | None = Field(
        None,
        ge=0.0,
        le=MAX_SENSOR_NOISE_N,
        description="White noise of each sensor force axis, standard deviation, N (default: the sensor's own, "
        "0.06 N for the wrist sensor, 0 for the ideal one).",
    )
    noise_seed: WholeNumber | None = Field(
        None,
        ge=0,
        le=2**32 - 1,
        description="Seed of the sensor's noise and bias drift (default 0): same seed, same noise.",
    )
    unknown_tilt_deg: Tilt2 = Field(
        default_factory=lambda: [0.0, 0.0],
        description="UNKNOWN rotation of the work piece about the world x then y axis through the skill's contact "
        "centre (the mean of its compliant frame origins), deg: the real surface tilts, the skill (its frames, its "
        "path) does not; like unknown_offset, the controller has to cope.",
    )
    force_scale: Real = Field(
        1.0,
        gt=0.0,
        le=MAX_FORCE_SCALE,
        description="Factor on the skill's desired force profile (1 = as taught): the same task at another force "
        "level; the errors are then in % of the scaled reference force.",
    )

    offset: Offset3 = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="KNOWN translation of the work piece [dx, dy, dz], m: applied to the simulated work piece "
        "and to the skill (DMP starts and goals, compliant frames).",
    )
    unknown_offset: Offset3 = Field(
        default_factory=lambda: [0.0, 0.0, 0.0],
        description="UNKNOWN translation [dx, dy, dz], m: applied to the simulated work piece only; "
        "the controller has to cope (e.g. a table height found by the guarded approach).",
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
    engine: Engine = Field(
        Engine.pybullet,
        description="The physics engine the execution runs on: pybullet (the compiled loop) or mujoco (the same "
        "cell in MuJoCo, the same controller and truth; its loop in Python, slower). docs/ENGINES.md.",
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


class TelemetryBatch(BaseModel):
    """Consecutive telemetry samples in columns (the Zenoh telemetry payload); row k of each list is one step."""

    model_config = ConfigDict(extra="forbid")

    execution_id: str = Field("", description="The execution these samples belong to.")
    t: list[float] = Field(description="Times since the execution started, s.")
    phase: list[ExecutionPhase] = Field(description="Phase per step.")
    segment_index: list[int] = Field(description="Segment index per step (-1 while settling).")
    tool_position: list[Vector3] = Field(description="Tool point positions, world, m.")
    tool_orientation: list[Quaternion] = Field(description="Tool orientations, world, [x, y, z, w].")
    reference_position: list[Vector3] = Field(description="Reference positions, world, m.")
    reference_orientation: list[Quaternion] = Field(description="Reference orientations, world, [x, y, z, w].")
    wrench_world: list[Wrench] = Field(description="Measured wrenches applied by the tool, world, N, N·m.")
    wrench_cf: list[Wrench] = Field(description="The same wrenches in the CF, N, N·m.")
    desired_force_cf_z_n: list[float] = Field(description="Desired CF-z forces, N.")
    in_contact: list[bool] = Field(
        default_factory=list,
        description="Whether the tool touched anything per step (the simulator's contact points, not the sensor); "
        "empty for telemetry stored before this column was streamed.",
    )
    normal_force_true_n: list[float] = Field(
        default_factory=list,
        description="The exact force the tool pressed with along the true surface normal per step, N (the "
        "simulator's contact points, not the sensor: what a test judges by; 0 without contact); empty for telemetry "
        "stored before this column was streamed.",
    )
    seq: int | None = Field(
        None,
        ge=0,
        description="Per-execution batch number on the bus, from 0, one more for every batch published (None for "
        "a replayed batch and off the bus).",
    )
    first_sample: int | None = Field(
        None,
        ge=0,
        description="Index in the execution's telemetry stream of row 0 (the stream's sample k is control step k, "
        "from 0): a receiver that has stored samples 0 to n-1 and gets first_sample > n has missed samples n to "
        "first_sample-1 (None off the bus).",
    )
    sent_unix_s: Real | None = Field(
        None,
        description="Worker's wall clock when the control loop handed the batch to the bus, just after recording "
        "its last row, Unix time, s (set on the Zenoh bus, None elsewhere). With pace realtime row k was recorded "
        "about (t[-1] - t[k]) s before it: receive time - (sent_unix_s - (t[-1] - t[k])) is row k's latency.",
    )


TELEMETRY_COLUMNS: dict[str, slice] = {
    "t": slice(0, 1),
    "phase": slice(1, 2),
    "segment_index": slice(2, 3),
    "tool_position": slice(3, 6),
    "tool_orientation": slice(6, 10),
    "reference_position": slice(10, 13),
    "reference_orientation": slice(13, 17),
    "wrench_world": slice(17, 23),
    "wrench_cf": slice(23, 29),
    "desired_force_cf_z_n": slice(29, 30),
    "in_contact": slice(30, 31),
    "normal_force_true_n": slice(31, 32),
    "contact_normal": slice(32, 35),
}
"""Columns of one recorded control step (the worker's float row): t (s), phase code (``PHASE_CODES``), segment (-1
settling), tool and reference pose (world, m, xyzw), measured wrench applied by the tool (world; CF axes), desired
CF-z force (N), in contact (1/0, the simulator's contact points), the exact force along the true surface normal (N)
and that normal (into the surface; zeros without contact), from the simulator's contact points, not the sensor."""
TELEMETRY_WIDTH = max(columns.stop for columns in TELEMETRY_COLUMNS.values())
STREAMED_TELEMETRY_COLUMNS: dict[str, slice] = {
    name: columns for name, columns in TELEMETRY_COLUMNS.items() if name in TelemetryBatch.model_fields
}
"""The columns a :class:`TelemetryBatch` carries (published, stored): the first ones of a row, at the same offsets.
They include the true normal force and the contact, so that a live view can judge the force by the truth; the true
normal's direction stays in the worker (its metrics use it)."""
STREAMED_TELEMETRY_WIDTH = max(columns.stop for columns in STREAMED_TELEMETRY_COLUMNS.values())
if sum(c.stop - c.start for c in STREAMED_TELEMETRY_COLUMNS.values()) != STREAMED_TELEMETRY_WIDTH:  # a prefix
    raise AssertionError("the streamed telemetry columns must lead the row")


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
