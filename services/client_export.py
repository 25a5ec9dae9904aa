"""An execution's telemetry file written on the client's side (``services.client.Client.export``): from every page of
its telemetry (the service sends at most its cap of samples per request), exactly as the service writes one page."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from schemas.api import TelemetryFormat, TelemetryView


def execution_file(
    pages: list[TelemetryView], kind: TelemetryFormat, execution_id: str, created: Callable[[], float]
) -> bytes:
    """The MCAP, CSV or JSON bytes (``kind``) of execution ``execution_id`` from its telemetry ``pages`` in order;
    ``created()`` its start, Unix s (asked for only by an MCAP, whose clock starts there)."""
    from schemas.telemetry_rows import telemetry_matrix
    from services.telemetry_export import execution_csv, execution_json_chunks, execution_mcap

    matrix = np.concatenate([telemetry_matrix(page) for page in pages])
    if kind is TelemetryFormat.mcap:
        return execution_mcap(matrix, created(), execution_id).data
    if kind is TelemetryFormat.csv:
        return execution_csv(matrix).encode()
    last = pages[-1]
    head = {"execution_id": execution_id, "every": last.every, "cursor": 0, "next_cursor": None,
            "n_samples": int(matrix.shape[0]), "stored_samples": last.stored_samples,
            "status": last.status.value}  # fmt: skip
    return "".join(execution_json_chunks(head, matrix)).encode()
