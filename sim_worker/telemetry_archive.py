"""What a worker keeps of the telemetry it published, so a receiver that missed batches can ask for them again
(``P/exec/{worker_id}/replay``, ``schemas.bus.TelemetryReplay``).

Bounded and in memory: the rows of the last :data:`TELEMETRY_KEEP_EXECUTIONS` executions, at most
:data:`TELEMETRY_KEEP_BYTES` in all (the oldest finished execution goes first; the running one is never dropped, the
execution bounds of ``schemas.execution`` cap it). In memory because a replay is asked of THIS worker process, by its
id: once the process is gone nobody can ask it, so a file would outlive its use, and the 1 kHz control loop writes
nothing to disk. An API that was down or cut off from the router for minutes still finds the last executions here.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from execution.telemetry import Telemetry
from schemas.execution import TELEMETRY_WIDTH

TELEMETRY_KEEP_EXECUTIONS = 16
"""Executions whose telemetry a worker keeps for replays."""
TELEMETRY_KEEP_BYTES = 32 * 2**20
"""Most bytes of kept telemetry (35 float64 per control step: 280 kB per simulated second at 1 kHz, so the cap
holds about 2 simulated minutes of finished runs, and the running one whatever its length). A worker's memory
budget (docs/BENCHMARKS.md, "A worker's memory") leaves this much to replays: 256 MB took a worker that ran many
long skills past it, and with 64 MiB one running one-minute skills peaked at 568-630 MB, around its 600 MB."""


CONSOLIDATED_ROWS = 4096
"""The control loop hands its rows over in batches of a few (10 by default: 2.8 kB each, in the heap); every this many
rows a stream's loose batches become one block (1.1 MB, mapped on its own, ``sim_worker.process_memory``), so that an
evicted execution's rows go back to the system whole instead of leaving thousands of holes in the heap, which made a
worker's peak vary by tens of MB from run to run."""


class _Stream:
    """One execution's rows: blocks of :data:`CONSOLIDATED_ROWS` and the loose batches handed over since."""

    def __init__(self) -> None:
        self.chunks: list[np.ndarray] = []
        self.rows = 0
        self.loose = 0
        """The last chunks that are loose batches (not yet one block)."""
        self.loose_rows = 0
        self.batches = 0
        """Batches published (the next batch's ``seq``)."""
        self.finished = False

    def add(self, rows: np.ndarray) -> None:
        """Keep the next ``rows`` (a loose batch); the loose batches become one block once they hold
        :data:`CONSOLIDATED_ROWS` rows."""
        self.chunks.append(rows)
        self.rows += len(rows)
        self.loose += 1
        self.loose_rows += len(rows)
        if self.loose_rows >= CONSOLIDATED_ROWS:
            self.consolidate()

    def consolidate(self) -> None:
        """The loose batches as one block (the same rows in the same order)."""
        if self.loose > 1:
            self.chunks[-self.loose :] = [np.concatenate(self.chunks[-self.loose :])]
        self.loose = self.loose_rows = 0

    def rows_between(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start`` to ``stop - 1`` (those that exist)."""
        parts, offset = [], 0
        for chunk in self.chunks:
            end = offset + len(chunk)
            if end > start and offset < stop:
                parts.append(chunk[max(start - offset, 0) : min(stop - offset, len(chunk))])
            offset = end
            if offset >= stop:
                break
        return np.concatenate(parts) if parts else np.empty((0, TELEMETRY_WIDTH))


class TelemetryArchive:
    """The telemetry of a worker's recent executions (see the module docstring); thread-safe."""

    def __init__(self, keep_executions: int = TELEMETRY_KEEP_EXECUTIONS, keep_bytes: int = TELEMETRY_KEEP_BYTES):
        self.keep_executions = keep_executions
        self.keep_bytes = keep_bytes
        self._streams: OrderedDict[str, _Stream] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def append(self, execution_id: str, telemetry: Telemetry) -> int:
        """Keep the control loop's next rows of ``execution_id``; return the stream index of their first row."""
        with self._lock:
            stream = self._streams.get(execution_id)
            if stream is None:
                stream = self._streams[execution_id] = _Stream()
            first = stream.rows
            stream.add(telemetry.data)
            self._bytes += telemetry.data.nbytes
            self._evict()
        return first

    def next_batch(self, execution_id: str) -> int:
        """The ``seq`` of the execution's next published batch (counted from 0)."""
        with self._lock:
            stream = self._streams.get(execution_id)
            if stream is None:
                return 0
            stream.batches += 1
            return stream.batches - 1

    def finish(self, execution_id: str) -> None:
        """The execution ended: its rows may go when newer executions need the room."""
        with self._lock:
            stream = self._streams.get(execution_id)
            if stream is not None:
                stream.finished = True
                stream.consolidate()
            self._evict()

    def rows(self, execution_id: str, start: int, stop: int) -> Telemetry | None:
        """Rows ``start`` to ``stop - 1`` of the execution's stream as far as they exist (an empty `Telemetry`
        when none of them does yet), or None if this worker keeps nothing of it (never ran it, or dropped it)."""
        with self._lock:
            stream = self._streams.get(execution_id)
            if stream is None:
                return None
            return Telemetry(stream.rows_between(start, stop))

    def _evict(self) -> None:
        """Drop the oldest finished executions while over a bound (the caller holds the lock)."""
        finished = [e for e, s in self._streams.items() if s.finished]
        while finished and (len(self._streams) > self.keep_executions or self._bytes > self.keep_bytes):
            stream = self._streams.pop(finished.pop(0))
            self._bytes -= sum(chunk.nbytes for chunk in stream.chunks)
