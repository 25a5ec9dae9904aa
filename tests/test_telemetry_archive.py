"""What a worker keeps for replays (``sim_worker.telemetry_archive``): every row handed over, in order, whatever blocks
it keeps them in; bounded by bytes, the running execution never dropped."""

from __future__ import annotations

import numpy as np

from execution.telemetry import Telemetry
from schemas.execution import TELEMETRY_WIDTH
from sim_worker.telemetry_archive import CONSOLIDATED_ROWS, TelemetryArchive


def _batches(rows: int, size: int, start: int = 0) -> list[Telemetry]:
    """``rows`` numbered rows (column 0 their index from ``start``) in batches of ``size``, as the loop hands them."""
    data = np.zeros((rows, TELEMETRY_WIDTH))
    data[:, 0] = np.arange(start, start + rows)
    return [Telemetry(data[k : k + size].copy()) for k in range(0, rows, size)]


def test_the_archive_gives_back_every_row_in_order_from_blocks_and_loose_batches() -> None:
    archive = TelemetryArchive()
    rows = 2 * CONSOLIDATED_ROWS + 137  # two blocks and loose batches
    firsts = [archive.append("run", batch) for batch in _batches(rows, 10)]
    assert firsts == list(range(0, rows, 10))
    for start, stop in ((0, rows), (5, 17), (CONSOLIDATED_ROWS - 3, CONSOLIDATED_ROWS + 4), (rows - 20, rows + 50)):
        np.testing.assert_array_equal(archive.rows("run", start, stop).data[:, 0], np.arange(start, min(stop, rows)))
    kept = archive._streams["run"].chunks
    assert len(kept) < rows / 10 and max(len(chunk) for chunk in kept) >= CONSOLIDATED_ROWS  # blocks, not batches
    archive.finish("run")
    assert len(archive._streams["run"].chunks) == 3  # the last loose batches made one block too
    np.testing.assert_array_equal(archive.rows("run", 0, rows).data[:, 0], np.arange(rows))
    assert archive.rows("never ran", 0, 10) is None


def test_finished_executions_go_oldest_first_when_over_the_bytes_and_the_running_one_stays() -> None:
    row_bytes = TELEMETRY_WIDTH * 8
    archive = TelemetryArchive(keep_bytes=3000 * row_bytes)
    for name in ("first", "second"):
        for batch in _batches(1000, 10):
            archive.append(name, batch)
        archive.finish(name)
    for batch in _batches(5000, 10):  # the running one alone is over the bound: it stays, the finished ones go
        archive.append("running", batch)
    assert archive.rows("first", 0, 10) is None and archive.rows("second", 0, 10) is None
    assert len(archive.rows("running", 0, 5000)) == 5000
    assert archive._bytes == 5000 * row_bytes
