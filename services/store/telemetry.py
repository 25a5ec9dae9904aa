"""Stored telemetry: rows of consecutive samples, each keyed by (execution, index of its first sample in the
execution's stream, ``TelemetryBatch.first_sample``), the samples' columns as a float64 matrix
(:data:`TELEMETRY_LAYOUT`, phases as :data:`schemas.execution.PHASE_CODES`), zlib-compressed. The stored ranges never
overlap: a batch received twice (a replay of what the live stream already brought) stores only the samples not stored
yet, so every sample is stored once, and reading in key order gives the samples in order
(:meth:`TelemetryRepository.add`, :meth:`TelemetryRepository.gaps`)."""

from __future__ import annotations

import time
import zlib
from collections.abc import Iterator

import numpy as np

from schemas.execution import STREAMED_TELEMETRY_COLUMNS, STREAMED_TELEMETRY_WIDTH, TelemetryBatch
from schemas.telemetry_rows import telemetry_matrix
from services.store.database import Database

TELEMETRY_LAYOUT: dict[str, tuple[int, int]] = {
    name: (columns.start, columns.stop) for name, columns in STREAMED_TELEMETRY_COLUMNS.items()
}
"""Column range of each `TelemetryBatch` field in the stored float64 matrix (width
:data:`schemas.execution.STREAMED_TELEMETRY_WIDTH`): the worker's row layout, its streamed columns."""
TELEMETRY_READ_SAMPLES = 8192
"""Telemetry samples read per query by :meth:`TelemetryRepository.blocks` (~2 MB; more when one block holds more)."""
_TELEMETRY_END = "SELECT COALESCE(MAX(seq + rows), 0) FROM telemetry WHERE execution_id = ?"
"""One past the last stored sample of an execution."""


def _stored_rows(data: bytes, n: int) -> np.ndarray:
    """``n`` stored telemetry rows as an (n, :data:`STREAMED_TELEMETRY_WIDTH`) matrix; rows stored narrower (before
    the later columns were streamed) get NaN there."""
    rows = np.frombuffer(data, dtype="<f8").reshape(n, -1) if n else np.empty((0, STREAMED_TELEMETRY_WIDTH))
    if rows.shape[1] == STREAMED_TELEMETRY_WIDTH:
        return rows
    wide = np.full((n, STREAMED_TELEMETRY_WIDTH), np.nan)
    wide[:, : rows.shape[1]] = rows
    return wide


def _uncovered(start: int, stop: int, covered: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The parts of ``[start, stop)`` outside the sorted, disjoint ranges ``covered``."""
    parts = []
    for a, b in covered:
        if a > start:
            parts.append((start, min(a, stop)))
        start = max(start, b)
        if start >= stop:
            break
    if start < stop:
        parts.append((start, stop))
    return [(a, b) for a, b in parts if b > a]


class TelemetryRepository:
    """The ``telemetry`` table."""

    def __init__(self, database: Database) -> None:
        self.database = database

    def add(self, execution_id: str, batch: TelemetryBatch) -> int:
        """Store the samples of a telemetry batch of a KNOWN execution that are not stored yet; return how many were
        new (0 for an unknown execution or a batch already stored). A batch without ``first_sample`` (not from the
        bus) goes after the last sample stored."""
        matrix = telemetry_matrix(batch)
        received = time.time()
        with self.database.transaction() as db:
            if db.execute("SELECT 1 FROM executions WHERE id = ?", (execution_id,)).fetchone() is None:
                return 0
            first = batch.first_sample
            if first is None:
                first = int(db.execute(_TELEMETRY_END, (execution_id,)).fetchone()[0])
            stop = first + matrix.shape[0]
            stored = db.execute(
                "SELECT seq, rows FROM telemetry WHERE execution_id = ? AND seq < ? AND seq + rows > ? ORDER BY seq",
                (execution_id, stop, first),
            ).fetchall()
            new = 0
            for start, end in _uncovered(first, stop, [(r["seq"], r["seq"] + r["rows"]) for r in stored]):
                block = matrix[start - first : end - first]
                db.execute(
                    "INSERT INTO telemetry (execution_id, seq, received, rows, data) VALUES (?, ?, ?, ?, ?)",
                    (execution_id, start, received, end - start, zlib.compress(block.astype("<f8").tobytes(), 1)),
                )
                new += end - start
            return new

    def end(self, execution_id: str) -> int:
        """One past the last stored sample index of an execution (0 with none)."""
        r = self.database.one(_TELEMETRY_END, (execution_id,))
        return int(r[0]) if r is not None else 0

    def gaps(self, execution_id: str, total: int | None = None) -> list[tuple[int, int]]:
        """The sample ranges ``[start, stop)`` missing from an execution's stored telemetry, below ``total`` samples
        (default: up to the last stored one)."""
        rows = self.database.all("SELECT seq, rows FROM telemetry WHERE execution_id = ? ORDER BY seq", (execution_id,))
        end = total if total is not None else max((r["seq"] + r["rows"] for r in rows), default=0)
        return _uncovered(0, end, [(r["seq"], r["seq"] + r["rows"]) for r in rows])

    def counts(self, execution_id: str) -> tuple[int, int]:
        """(batches, samples) stored for an execution."""
        r = self.database.one(
            "SELECT COUNT(*), COALESCE(SUM(rows), 0) FROM telemetry WHERE execution_id = ?", (execution_id,)
        )
        return (int(r[0]), int(r[1])) if r is not None else (0, 0)

    def rows(self, execution_id: str) -> np.ndarray:
        """Every stored sample of an execution, in stream order, as one (N, ``STREAMED_TELEMETRY_WIDTH``) matrix
        (a whole run in memory: the API reads it page by page, :meth:`blocks`)."""
        blocks = [block for _, block in self.blocks(execution_id)]
        return np.concatenate(blocks) if blocks else np.empty((0, STREAMED_TELEMETRY_WIDTH))

    def blocks(self, execution_id: str, start: int = 0) -> Iterator[tuple[int, np.ndarray]]:
        """The stored telemetry of an execution from sample ``start`` on, in stream order, as (stream index of its
        first sample, (n, ``STREAMED_TELEMETRY_WIDTH``) matrix) blocks: the first block may begin before ``start``.
        Read about :data:`TELEMETRY_READ_SAMPLES` samples per query, so memory stays bounded, a reader that stops
        early has read little, and no cursor stays open while the caller works."""
        while index := self.database.all(
            "SELECT seq, rows FROM telemetry WHERE execution_id = ? AND seq + rows > ? ORDER BY seq LIMIT ?",
            (execution_id, start, TELEMETRY_READ_SAMPLES),
        ):
            upto = np.cumsum([r["rows"] for r in index])
            last = index[max(1, int(np.searchsorted(upto, TELEMETRY_READ_SAMPLES, side="right"))) - 1]
            for first, n, data in self.database.all(
                "SELECT seq, rows, data FROM telemetry WHERE execution_id = ? AND seq BETWEEN ? AND ? ORDER BY seq",
                (execution_id, index[0]["seq"], last["seq"]),
            ):
                yield first, _stored_rows(zlib.decompress(data), n)
            start = last["seq"] + last["rows"]
