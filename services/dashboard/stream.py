"""Reading an execution's stored telemetry as a live stream (the dashboard's server-sent events, the Foxglove live
server): from a cursor on, only as far as the samples are contiguous, so a gap the API is still repairing (asked
again of the worker, ``services.bus_events``) is waited for rather than skipped."""

from __future__ import annotations

import numpy as np

from schemas.execution import STREAMED_TELEMETRY_WIDTH
from services.store import Store


def stored_rows(store: Store, execution_id: str, cursor: int, skip_gaps: bool = False) -> np.ndarray:
    """The stored samples of ``execution_id`` from stream index ``cursor`` on (the store's rows), up to the first
    missing one; ``skip_gaps``: past missing ones too (the stream has ended, nothing more will come)."""
    parts, expected = [], cursor
    for first, block in store.telemetry.blocks(execution_id, cursor):
        if first > expected and not skip_gaps:
            break
        part = block[max(0, expected - first) :]
        parts.append(part)
        expected = first + block.shape[0]
    return np.concatenate(parts) if parts else np.empty((0, STREAMED_TELEMETRY_WIDTH))


def decimated(t: np.ndarray, hz: float) -> np.ndarray:
    """The rows to show of samples at times ``t`` (s): the first of each ``1/hz`` interval, and the last row."""
    bins = np.floor(t * hz + 1e-6)  # 1e-6: a stamp a rounding below a bin's edge (1.13 s as 1.1299999) is in it
    keep = np.flatnonzero(np.diff(bins, prepend=-np.inf) > 0)
    if t.size and (keep.size == 0 or keep[-1] != t.size - 1):
        keep = np.append(keep, t.size - 1)
    return keep
