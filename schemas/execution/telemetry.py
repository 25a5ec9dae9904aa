"""An execution's phases (:class:`ExecutionPhase` and their codes) and its telemetry: what is streamed
(:class:`TelemetryMode`), a batch of samples in columns (:class:`TelemetryBatch`) and the columns of one recorded
control step (:data:`TELEMETRY_COLUMNS`). World frame unless a column says CF; wrenches applied by the tool."""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field

from schemas.demonstration import Quaternion, Vector3, Wrench
from schemas.numbers import Real


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
PHASES_BY_CODE: tuple[ExecutionPhase, ...] = tuple(PHASE_CODES)
"""The phase of each code of :data:`PHASE_CODES` (its inverse: ``PHASES_BY_CODE[PHASE_CODES[phase]] is phase``)."""


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
