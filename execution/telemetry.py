"""An execution's recorded control steps: one float row per 1 kHz step, viewed by columns (world frame, SI units,
quaternions ``[x, y, z, w]``; docs/CONVENTIONS.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas.execution import TELEMETRY_COLUMNS, ExecutionPhase, TelemetryBatch
from schemas.telemetry_rows import telemetry_batch

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
