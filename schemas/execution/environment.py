"""How an execution's world differs from the one its skill was taught in, and where the skill goes: the unknown
changes (offset, tilt, sensor bias and noise, pad, force scale: :class:`EnvironmentChange`) with their bounds, the
work piece it runs on (:class:`WorkPieceSource`), the placement into the robot's world (:class:`Placement`), the
sensor (:class:`SensorChoice`). World frame, SI units (docs/CONVENTIONS.md)."""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.demonstration import Quaternion, Vector3
from schemas.numbers import Real, WholeNumber, bounded_triple

MAX_OFFSET_M = 1.0
"""Largest work-piece offset per axis, m: further than that it is another work cell, not a moved piece."""
Offset3 = bounded_triple(-MAX_OFFSET_M, MAX_OFFSET_M)
MAX_TILT_DEG = 30.0
"""Largest unknown tilt of the work piece about each axis, deg."""
Tilt2 = Annotated[list[Annotated[Real, Field(ge=-MAX_TILT_DEG, le=MAX_TILT_DEG)]], Field(min_length=2, max_length=2)]
MAX_SENSOR_BIAS_N = 50.0
"""Largest untared force bias of the sensor per axis, N (a 10 % offset of a large wrist sensor's range)."""
Bias3 = bounded_triple(-MAX_SENSOR_BIAS_N, MAX_SENSOR_BIAS_N)
MAX_SENSOR_NOISE_N = 20.0
"""Largest sensor force noise (standard deviation), N."""
MAX_FORCE_SCALE = 5.0
"""Largest factor on a skill's force profile."""


NOMINAL_CONTACT_STIFFNESS_N_M = 3.0e4
"""The tool pad's contact stiffness of a world that sets none (the simulated worlds' default), N/m."""
NOMINAL_CONTACT_DAMPING_N_S_M = 300.0
"""The tool pad's contact damping of a world that sets none, N·s/m."""


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
