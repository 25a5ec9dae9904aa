"""The demonstration: time-stamped tool poses and the wrench the tool applied.

Conventions (docs/CONVENTIONS.md): SI units; quaternions scalar-last ``[x, y, z, w]``; wrench
``[fx, fy, fz, mx, my, mz]`` is the wrench the TOOL APPLIES TO THE ENVIRONMENT, at the tool
point, in the world frame.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, JsonValue, ValidationInfo, field_validator, model_validator

from schemas.arrays import bounded_rows, finite_rows, strictly_increasing
from schemas.numbers import Real
from schemas.text import FreeForm, Name, Text

MIN_DEMONSTRATION_SAMPLES = 50
"""Fewest samples a demonstration may have: segmentation and 50-basis DMPs need more than a handful."""
MAX_DEMONSTRATION_SAMPLES = 200_000
"""Most samples a demonstration may have (200 s at 1 kHz, 33 min at 100 Hz): learning stays within seconds and
a few hundred MB; the CSV importer refuses to resample to more."""
MAX_DURATION_S = 3600.0
"""Longest time span of a demonstration, s (one hour: a skill is taught in seconds to minutes)."""
MAX_TIME_S = 1e10
"""Largest time stamp magnitude, s (Unix time stamps fit; 1e300 does not)."""
MIN_TIME_STEP_S = 1e-6
"""Smallest step between two time stamps, s: a 1 MHz rate, far above any force/torque sensor's (a few kHz), and a
finite one (a step of 5e-324 s is an infinite rate, a summary no JSON can hold)."""
MAX_POSITION_M = 10.0
"""Largest tool position coordinate, m: no robot's workspace reaches further from its world origin."""
MAX_FORCE_N = 10_000.0
"""Largest force component, N (well beyond any contact tool's sensor)."""
MAX_MOMENT_NM = 1_000.0
"""Largest moment component, N·m."""

QUATERNION_NORM_TOLERANCE = 0.01
"""Largest accepted deviation of a quaternion's norm from 1; inside it quaternions are renormalized."""

Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Quaternion = Annotated[list[float], Field(min_length=4, max_length=4)]
Wrench = Annotated[list[float], Field(min_length=6, max_length=6)]


_PLAUSIBLE: dict[str, list[tuple[slice, float, str, str]]] = {
    "positions": [(slice(0, 3), MAX_POSITION_M, "m", " (is the recording in millimetres? positions are in m)")],
    "wrenches": [
        (slice(0, 3), MAX_FORCE_N, "N", " (forces are in N)"),
        (slice(3, 6), MAX_MOMENT_NM, "N·m", " (moments are in N·m)"),
    ],
}
"""Per array field: the columns, their magnitude bound, unit and the hint of the error."""


def _bounded_number(limit: float) -> dict[str, JsonValue]:
    """JSON schema of a number within ±``limit`` (the bounds the validators enforce, declared in the OpenAPI)."""
    return {"type": "number", "minimum": -limit, "maximum": limit}


def _bounded_row(limits: list[float]) -> dict[str, JsonValue]:
    """JSON schema of a fixed-length row whose element k lies within ±``limits[k]``."""
    return {
        "type": "array",
        "prefixItems": [_bounded_number(limit) for limit in limits],
        "items": False,
        "minItems": len(limits),
        "maxItems": len(limits),
    }


class WrenchConvention(StrEnum):
    """Which wrench a recording holds; the stored demonstration is always ``applied-by-tool``."""

    applied_by_tool = "applied-by-tool"
    measured_on_tool = "measured-on-tool"


class WrenchFrame(StrEnum):
    """Frame a recorded wrench is expressed in; the stored demonstration is always ``world``."""

    world = "world"
    tool = "tool"


class QuaternionOrder(StrEnum):
    """Component order of recorded quaternions; the stored demonstration is always ``xyzw``."""

    xyzw = "xyzw"
    wxyz = "wxyz"


class TareMethod(StrEnum):
    """How the sensor's offset was dealt with on import (docs/IMPORTING.md, step 5)."""

    free_space = "free-space"
    """Fitted over the recording's free-space stretches (with a tool's weight where the orientations told it)."""
    given = "given"
    """Subtracted as the user gave it (``--force-offset``) or as the file reads over a window (``--tare-window``)."""
    off = "off"
    """Not touched: the user said the file is compensated (``--no-tare``)."""
    impossible = "impossible"
    """Asked for, but the recording has no free space to fit it over: an offset or a tool's weight may remain."""
    none = "none"
    """No recording file: the demonstration was given as applied wrenches (JSON, the simulator's teacher)."""


class DemonstrationMetadata(BaseModel):
    """Where a demonstration came from and how it was converted on import."""

    model_config = ConfigDict(extra="forbid")

    name: Name = Field("", description="Human-readable name.", examples=["slide_flat_table"])
    source: Text = Field(
        "json", description="Origin: 'json', 'csv:<file>', 'teacher:<scenario>'.", examples=["teacher:slide_flat"]
    )
    wrench_convention_on_import: WrenchConvention = Field(
        WrenchConvention.applied_by_tool,
        description="Convention of the wrench in the original recording (negated on import if measured-on-tool).",
    )
    wrench_frame_on_import: WrenchFrame = Field(
        WrenchFrame.world, description="Frame of the wrench in the original recording (rotated to world on import)."
    )
    quaternion_order_on_import: QuaternionOrder = Field(
        QuaternionOrder.xyzw, description="Quaternion order of the original recording."
    )
    resampled_rate_hz: Real | None = Field(
        None, description="Uniform rate (Hz) the importer resampled irregular time stamps to, if it did."
    )
    force_offset_removed: Wrench | None = Field(
        None,
        description="Sensor offset (N, N·m) subtracted on import, as the file reads it (its sign convention) with "
        "nothing touching the tool, in the frame named by force_offset_frame.",
    )
    force_offset_uncertainty_n: Real | None = Field(
        None,
        ge=0,
        description="95 % uncertainty (two standard errors, N) of the force offset fitted over the free-space "
        "stretches (what a hand's slow wander may have left in it); None when no offset was fitted.",
    )
    world_force_removed: Vector3 | None = Field(
        None,
        description="A force constant in the world (N, applied-by-tool convention) removed with the sensor offset: a "
        "tool weight nobody compensated (it reads as m·g UP: the arm holds the tool up), or the offset of a wrench "
        "estimated from an arm's joint torques; fitted where the tool was held in different orientations in free "
        "space. None when none was told apart.",
    )
    tare: TareMethod = Field(
        TareMethod.none,
        description="How the sensor offset was dealt with on import; 'impossible' (no free space to fit it over) "
        "fails the skill's sensor_offset check.",
    )
    force_offset_frame: Literal["tool", "world"] | None = Field(
        None,
        description="Frame of force_offset_removed: 'tool' (the sensor frame: estimated over the free-space "
        "stretches, or given for a tool-frame file) or 'world' (given for a world-frame file).",
    )
    unmeasured_intervals_s: list[tuple[float, float]] = Field(
        default_factory=list,
        description="Intervals (start, end), s on the demonstration's time axis, where the importer found no "
        "measurement of the pose or of the wrench for much longer than usual (a tracker that lost the tool, a "
        "stalled logger): the samples there were interpolated, not measured. A skill whose contact crosses one "
        "fails its unmeasured_contact check.",
        max_length=100_000,
        examples=[[[2.0, 2.5]]],
    )
    extra: FreeForm = Field(
        default_factory=dict,
        description="Free-form extra information (at most 16 levels deep and 64 KiB of JSON).",
    )

    @field_validator("unmeasured_intervals_s")
    @classmethod
    def _intervals_are_finite_and_ordered(cls, value: list[tuple[float, float]]) -> list[tuple[float, float]]:
        array = np.asarray(value, dtype=float).reshape(-1, 2)
        if array.size:
            finite_rows(array, "interval")
            backwards = np.flatnonzero(array[:, 1] < array[:, 0])
            if backwards.size:
                raise ValueError(f"interval {backwards[0]} ends before it starts")
        return value


def _stamp_unit_hint(stamp: float) -> str:
    """`` (nanoseconds since 1970, ...)`` when ``stamp`` read in ms, µs or ns is a date of the last decades."""
    for unit, per_second in (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9)):
        if 1e8 <= abs(stamp) / per_second <= MAX_TIME_S:
            return f" (in {unit} since 1970, as ROS and Unix stamps are? time stamps are in s)"
    return ""


class Demonstration(BaseModel):
    """One demonstration: N samples of time, tool pose and applied wrench.

    Positions are the tool point in the world frame (m); orientations the tool frame in the
    world (unit quaternion, scalar-last); wrenches are applied by the tool, at the tool point,
    world frame (N, N·m). Time stamps are seconds, strictly increasing by at least ``MIN_TIME_STEP_S``.
    """

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "t": [0.0, 0.001, 0.002],
                    "positions": [[0.5, 0.0, 0.3], [0.5, 0.0001, 0.3], [0.5, 0.0002, 0.3]],
                    "orientations": [[1.0, 0.0, 0.0, 0.0]] * 3,
                    "wrenches": [[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]] * 3,
                    "metadata": {"name": "three samples (too few to learn from, shows the shape)"},
                }
            ]
        },
    )

    t: list[float] = Field(
        max_length=MAX_DEMONSTRATION_SAMPLES,
        description=f"Time stamps, s, strictly increasing by at least {MIN_TIME_STEP_S:g} s; "
        f"{MIN_DEMONSTRATION_SAMPLES}-{MAX_DEMONSTRATION_SAMPLES} samples spanning at most {MAX_DURATION_S:g} s.",
        json_schema_extra={"minItems": MIN_DEMONSTRATION_SAMPLES, "items": _bounded_number(MAX_TIME_S)},
    )
    positions: list[Vector3] = Field(
        max_length=MAX_DEMONSTRATION_SAMPLES,
        description=f"Tool point positions, m, world frame; one [x, y, z] per sample, within ±{MAX_POSITION_M:g} m.",
        json_schema_extra={"items": _bounded_row([MAX_POSITION_M] * 3)},
    )
    orientations: list[Quaternion] = Field(
        max_length=MAX_DEMONSTRATION_SAMPLES,
        description="Tool orientations in world, unit quaternions scalar-last [x, y, z, w]; one per sample.",
        json_schema_extra={"items": _bounded_row([1.0 + QUATERNION_NORM_TOLERANCE] * 4)},
    )
    wrenches: list[Wrench] = Field(
        max_length=MAX_DEMONSTRATION_SAMPLES,
        description="Wrench applied BY the tool TO the environment at the tool point, world frame, "
        f"[fx, fy, fz, mx, my, mz] in N and N·m; one per sample; forces within ±{MAX_FORCE_N:g} N, moments within "
        f"±{MAX_MOMENT_NM:g} N·m.",
        json_schema_extra={"items": _bounded_row([MAX_FORCE_N] * 3 + [MAX_MOMENT_NM] * 3)},
    )
    metadata: DemonstrationMetadata = Field(default_factory=DemonstrationMetadata)

    @field_validator("t")
    @classmethod
    def _time_is_valid(cls, value: list[float]) -> list[float]:
        array = np.asarray(value, dtype=float)
        if array.size < MIN_DEMONSTRATION_SAMPLES:
            raise ValueError(f"needs at least {MIN_DEMONSTRATION_SAMPLES} samples to learn from, got {array.size}")
        finite_rows(array[:, None], "time stamp")
        beyond = array[np.abs(array) > MAX_TIME_S]
        bounded_rows(array[:, None], MAX_TIME_S, "time stamp", "s", _stamp_unit_hint(beyond[0]) if beyond.size else "")
        strictly_increasing(array, MIN_TIME_STEP_S)
        if array[-1] - array[0] > MAX_DURATION_S:
            raise ValueError(
                f"spans {array[-1] - array[0]:.6g} s, more than {MAX_DURATION_S:g} s: are the time stamps in seconds?"
            )
        return value

    @field_validator("positions", "wrenches")
    @classmethod
    def _rows_are_plausible(cls, value: list[list[float]], info: ValidationInfo) -> list[list[float]]:
        array = np.asarray(value, dtype=float)
        finite_rows(array, "row")
        for columns, limit, unit, hint in _PLAUSIBLE[info.field_name]:
            if array.ndim == 2 and array.shape[1] >= columns.stop:
                bounded_rows(array[:, columns], limit, "row", unit, hint)
        return value

    @field_validator("orientations")
    @classmethod
    def _quaternions_are_unit(cls, value: list[list[float]]) -> list[list[float]]:
        q = np.asarray(value, dtype=float)
        finite_rows(q, "quaternion")
        if q.size == 0:
            return value
        deviation = np.abs(np.linalg.norm(q, axis=1) - 1.0)
        bad = np.flatnonzero(deviation > QUATERNION_NORM_TOLERANCE)
        if bad.size:
            raise ValueError(
                f"quaternion at sample {bad[0]} has norm {np.linalg.norm(q[bad[0]]):.4g}, not unit "
                f"(tolerance {QUATERNION_NORM_TOLERANCE}); {bad.size} such samples; order must be [x, y, z, w]"
            )
        return (q / np.linalg.norm(q, axis=1, keepdims=True)).tolist()

    @model_validator(mode="after")
    def _lengths_match(self) -> Demonstration:
        n = len(self.t)
        for name in ("positions", "orientations", "wrenches"):
            length = len(getattr(self, name))
            if length != n:
                raise ValueError(f"{name} has {length} samples but t has {n}: every array needs one row per time stamp")
        return self

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return len(self.t)

    def arrays(self) -> DemonstrationArrays:
        """Return the samples as numpy arrays (the form `skills/` works on)."""
        return DemonstrationArrays(
            t=np.asarray(self.t, dtype=float),
            positions=np.asarray(self.positions, dtype=float),
            orientations=np.asarray(self.orientations, dtype=float),
            wrenches=np.asarray(self.wrenches, dtype=float),
        )

    @classmethod
    def from_arrays(
        cls,
        t: np.ndarray,
        positions: np.ndarray,
        orientations: np.ndarray,
        wrenches: np.ndarray,
        metadata: DemonstrationMetadata | None = None,
    ) -> Demonstration:
        """Build (and validate) a demonstration from numpy arrays of shapes (N,), (N,3), (N,4), (N,6)."""
        return cls(
            t=np.asarray(t, dtype=float).tolist(),
            positions=np.asarray(positions, dtype=float).tolist(),
            orientations=np.asarray(orientations, dtype=float).tolist(),
            wrenches=np.asarray(wrenches, dtype=float).tolist(),
            metadata=metadata or DemonstrationMetadata(),
        )


class DemonstrationArrays(BaseModel):
    """Numpy view of a validated `Demonstration` (no validation of its own: build it via `arrays()`)."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    t: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    wrenches: np.ndarray


class DemonstrationSummary(BaseModel):
    """Short description of a stored demonstration."""

    n_samples: int = Field(description="Number of samples.")
    duration_s: Real = Field(description="Last minus first time stamp, s.")
    mean_rate_hz: Real = Field(description="Mean sampling rate, Hz.")
    max_force_n: Real = Field(description="Largest applied force magnitude, N.")
    name: str = Field("", description="Name from the metadata.")

    @classmethod
    def of(cls, demonstration: Demonstration) -> DemonstrationSummary:
        """Summarize ``demonstration``."""
        t = np.asarray(demonstration.t)
        forces = np.asarray(demonstration.wrenches)[:, :3]
        duration = float(t[-1] - t[0])
        return cls(
            n_samples=t.size,
            duration_s=duration,
            mean_rate_hz=(t.size - 1) / duration,
            max_force_n=float(np.linalg.norm(forces, axis=1).max()),
            name=demonstration.metadata.name,
        )
