"""An execution's recorded control steps: one float row per 1 kHz step, viewed by columns (world frame, SI units,
quaternions ``[x, y, z, w]``; docs/CONVENTIONS.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from schemas.execution import TELEMETRY_COLUMNS, ExecutionPhase, TelemetryBatch
from schemas.telemetry_rows import telemetry_batch
from skills.control.layouts import REFERENCE_FORCE, ROBOT_POSITION

_PHASES = list(ExecutionPhase)


@dataclass(frozen=True)
class Telemetry:
    """Recorded control steps, one row each (``data`` (N, :data:`TELEMETRY_WIDTH`), columns
    :data:`schemas.execution.TELEMETRY_COLUMNS`).

    The properties are views: ``t`` (N,), ``phase_codes`` (N,), ``segment_index`` (N,),
    ``tool_position`` (N, 3), ``tool_orientation`` (N, 4), ``reference_position``,
    ``reference_orientation``, ``wrench_world`` (N, 6), ``wrench_cf`` (N, 6),
    ``desired_force`` (N,), ``in_contact`` (N,) bool, ``normal_force_true`` (N,), ``contact_normal`` (N, 3).
    """

    data: NDArray[np.float64]

    def _col(self, name: str) -> NDArray[np.float64]:
        return self.data[:, TELEMETRY_COLUMNS[name]]

    def _scalar(self, name: str) -> NDArray[np.float64]:
        """A one-column field as (N,)."""
        return self.data[:, TELEMETRY_COLUMNS[name].start]

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def t(self) -> NDArray[np.float64]:
        return self._scalar("t")

    @property
    def phase_codes(self) -> NDArray[np.int_]:
        return self._scalar("phase").astype(int)

    @property
    def phases(self) -> list[ExecutionPhase]:
        return [_PHASES[c] for c in self.phase_codes]

    @property
    def segment_index(self) -> NDArray[np.int_]:
        return self._scalar("segment_index").astype(int)

    @property
    def tool_position(self) -> NDArray[np.float64]:
        return self._col("tool_position")

    @property
    def tool_orientation(self) -> NDArray[np.float64]:
        return self._col("tool_orientation")

    @property
    def reference_position(self) -> NDArray[np.float64]:
        return self._col("reference_position")

    @property
    def reference_orientation(self) -> NDArray[np.float64]:
        return self._col("reference_orientation")

    @property
    def wrench_world(self) -> NDArray[np.float64]:
        return self._col("wrench_world")

    @property
    def wrench_cf(self) -> NDArray[np.float64]:
        return self._col("wrench_cf")

    @property
    def desired_force(self) -> NDArray[np.float64]:
        return self._scalar("desired_force_cf_z_n")

    @property
    def in_contact(self) -> NDArray[np.bool_]:
        return self._scalar("in_contact") > 0.5

    @property
    def normal_force_true(self) -> NDArray[np.float64]:
        return self._scalar("normal_force_true_n")

    @property
    def contact_normal(self) -> NDArray[np.float64]:
        return self._col("contact_normal")

    def to_batch(self, execution_id: str = "") -> TelemetryBatch:
        """Return the rows as the columnar wire payload (``schemas.TelemetryBatch``: the streamed columns)."""
        return telemetry_batch(self.data, execution_id)


# Telemetry columns (schemas.execution.TELEMETRY_COLUMNS) and arm state entries, as plain ints for the compiled step.
_C_T, _C_PHASE, _C_SEGMENT = (TELEMETRY_COLUMNS[c].start for c in ("t", "phase", "segment_index"))
_C_POSE = TELEMETRY_COLUMNS["tool_position"].start  # position then orientation
_C_REFERENCE = TELEMETRY_COLUMNS["reference_position"].start  # position then orientation
_C_WRENCH, _C_WRENCH_CF = TELEMETRY_COLUMNS["wrench_world"].start, TELEMETRY_COLUMNS["wrench_cf"].start
_C_DESIRED, _C_CONTACT = TELEMETRY_COLUMNS["desired_force_cf_z_n"].start, TELEMETRY_COLUMNS["in_contact"].start
_C_TRUE_NORMAL = TELEMETRY_COLUMNS["normal_force_true_n"].start  # force then the normal (3)
_R_POSE = ROBOT_POSITION.start  # position then quaternion
_REFERENCE_FORCE = REFERENCE_FORCE


@numba.njit(cache=True)
def record_row(
    robot, reference, wrench, cf_rotation, in_contact, normal, rows, n, t, phase, segment
):  # pragma: no cover - compiled
    """Telemetry row ``n`` of ``rows`` for one control step, in one compiled call, as every engine's loop records it
    (:data:`TELEMETRY_COLUMNS`: the state measured before the step, its reference and desired force, the measured
    wrench in world and CF axes (``R^T f``, ``R^T m``, ``cf_rotation`` (9,) by rows), the true normal force and
    direction ``normal`` (4,)).
    Returns the control law's contact flag: the CF-z force above half the desired one, at most 0.5 N."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
        cf_rotation[0], cf_rotation[1], cf_rotation[2], cf_rotation[3], cf_rotation[4], cf_rotation[5],
        cf_rotation[6], cf_rotation[7], cf_rotation[8],
    )  # fmt: skip
    fx, fy, fz, mx, my, mz = wrench[0], wrench[1], wrench[2], wrench[3], wrench[4], wrench[5]
    row = rows[n]
    row[_C_T], row[_C_PHASE], row[_C_SEGMENT] = t, phase, segment
    for i in range(7):  # tool pose (position, quaternion); reference pose, the same layout
        row[_C_POSE + i] = robot[_R_POSE + i]
        row[_C_REFERENCE + i] = reference[i]
    for i in range(6):
        row[_C_WRENCH + i] = wrench[i]
    cf = _C_WRENCH_CF
    row[cf] = fx * r00 + fy * r10 + fz * r20
    row[cf + 1] = fx * r01 + fy * r11 + fz * r21
    row[cf + 2] = fx * r02 + fy * r12 + fz * r22
    row[cf + 3] = mx * r00 + my * r10 + mz * r20
    row[cf + 4] = mx * r01 + my * r11 + mz * r21
    row[cf + 5] = mx * r02 + my * r12 + mz * r22
    f_des = reference[_REFERENCE_FORCE]
    row[_C_DESIRED] = f_des
    row[_C_CONTACT] = 1.0 if in_contact else 0.0
    for i in range(4):  # the true normal force and the normal
        row[_C_TRUE_NORMAL + i] = normal[i]
    return row[cf + 2] > min(0.5, 0.5 * f_des)
