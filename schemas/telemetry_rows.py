"""Telemetry rows and the batch that carries them: the one conversion between a float matrix of control steps (the
worker's rows, :data:`schemas.execution.TELEMETRY_COLUMNS`, or the store's, their first
:data:`schemas.execution.STREAMED_TELEMETRY_WIDTH` columns) and a :class:`schemas.execution.TelemetryBatch` (one
list per streamed column; phases as names, stored as ``PHASE_CODES``)."""

from __future__ import annotations

import numpy as np

from schemas.execution import (
    PHASE_CODES,
    STREAMED_TELEMETRY_COLUMNS,
    STREAMED_TELEMETRY_WIDTH,
    ExecutionPhase,
    TelemetryBatch,
)

_PHASES_BY_CODE = {code: phase for phase, code in PHASE_CODES.items()}


def telemetry_matrix(batch: TelemetryBatch) -> np.ndarray:
    """The columns of ``batch`` as one (rows, :data:`STREAMED_TELEMETRY_WIDTH`) float64 matrix (NaN in a column the
    batch does not carry)."""
    n = len(batch.t)
    matrix = np.full((n, STREAMED_TELEMETRY_WIDTH), np.nan)
    for name, columns in STREAMED_TELEMETRY_COLUMNS.items():
        values = getattr(batch, name)
        if name == "phase":
            values = [PHASE_CODES[ExecutionPhase(p)] for p in values]
        if len(values) or n == 0:
            matrix[:, columns] = np.asarray(values, dtype=float).reshape(n, columns.stop - columns.start)
    return matrix


def telemetry_column(matrix: np.ndarray, name: str) -> list:
    """The inverse of :func:`telemetry_matrix` for one `TelemetryBatch` field of the rows ``matrix`` (the streamed
    columns at their offsets; more columns after them are not read): a list (phases as names; empty for a column of
    NaN, not recorded: telemetry stored before it was streamed)."""
    columns = STREAMED_TELEMETRY_COLUMNS[name]
    block = matrix[:, columns]
    if name == "phase":
        return [_PHASES_BY_CODE.get(int(code), ExecutionPhase.failed).value for code in block[:, 0]]
    if name == "segment_index":
        return block[:, 0].astype(int).tolist()
    if np.isnan(block).all() and block.size:
        return []
    if name == "in_contact":
        return (block[:, 0] > 0.5).tolist()
    return block[:, 0].tolist() if columns.stop - columns.start == 1 else block.tolist()


def telemetry_batch(matrix: np.ndarray, execution_id: str = "") -> TelemetryBatch:
    """The rows ``matrix`` (N, at least :data:`STREAMED_TELEMETRY_WIDTH` columns) as a batch of ``execution_id``
    (every streamed column, :func:`telemetry_column`)."""
    return TelemetryBatch(
        execution_id=execution_id, **{name: telemetry_column(matrix, name) for name in STREAMED_TELEMETRY_COLUMNS}
    )
