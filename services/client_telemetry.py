"""An execution's telemetry on the typed client's side (``services.client``): as numpy arrays (:class:`Telemetry`),
and as the live stream yields it (:func:`live_batches` over Zenoh, the stored part read in pages by
:class:`StoredStream`, both paced by :class:`Pacer`)."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.api import ExecutionView, TelemetryView
from schemas.execution import ExecutionPhase, Pace, TelemetryBatch


@dataclass(frozen=True)
class Telemetry:
    """An execution's telemetry as numpy arrays, one row per control step (SI units, quaternions [x, y, z, w]): the
    columns of `TelemetryBatch` with the same types (``phase`` holds `ExecutionPhase` members, ``segment_index``
    ints), so a live batch and the stored stream compare as they are.

    ``t`` s since the execution started; ``tool_position`` / ``reference_position`` world, m; ``wrench_world`` is the
    wrench the tool applies at the tool point in world axes (N, N·m); ``wrench_cf`` the same in the compliant frame
    (force z into the surface); ``desired_force_cf_z_n`` the desired CF-z force, N; ``in_contact`` (bool) and
    ``normal_force_true_n`` (N) the simulator's truth: whether the tool touched anything and the exact force along the
    true surface normal (both empty for telemetry stored before they were streamed)."""

    t: np.ndarray
    phase: np.ndarray
    segment_index: np.ndarray
    tool_position: np.ndarray
    tool_orientation: np.ndarray
    reference_position: np.ndarray
    reference_orientation: np.ndarray
    wrench_world: np.ndarray
    wrench_cf: np.ndarray
    desired_force_cf_z_n: np.ndarray
    in_contact: np.ndarray
    normal_force_true_n: np.ndarray

    @classmethod
    def from_columns(cls, columns: dict[str, Any]) -> Telemetry:
        """From the columns of ``GET /executions/{id}/telemetry`` or of a `TelemetryBatch`."""
        arrays = {name: np.asarray(columns[name], dtype=float) for name in cls.__dataclass_fields__ if name != "phase"}
        phases = {phase.value: phase for phase in ExecutionPhase}  # a lookup per row, not an enum call
        arrays["phase"] = np.array([phases[str(p)] for p in columns["phase"]], dtype=object)
        arrays["segment_index"] = arrays["segment_index"].astype(int)
        arrays["in_contact"] = arrays["in_contact"].astype(bool)
        return cls(**arrays)

    @classmethod
    def of_batches(cls, batches: Sequence[TelemetryBatch]) -> Telemetry:
        """The rows of ``batches`` (e.g. what ``Client.live`` yielded), in order, as one."""
        return cls.joined([cls.from_columns(batch.model_dump()) for batch in batches])

    @classmethod
    def joined(cls, parts: Sequence[Telemetry]) -> Telemetry:
        """The samples of ``parts`` (pages of one stream, in order) as one."""
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in cls.__dataclass_fields__})

    def __len__(self) -> int:
        return int(self.t.size)


def live_batches(view: ExecutionView, connect: list[str], timeout_s: float | None) -> Iterator[TelemetryBatch]:
    """The telemetry batches of ``view``'s execution as they arrive over Zenoh (the router at ``connect``), until it
    ends (``TimeoutError`` when no final status came within ``timeout_s``)."""
    from schemas.bus import ExecutionStatus
    from services.bus import open_session

    status_key = view.telemetry_key.rsplit("/", 1)[0] + "/status"
    batches: queue.Queue[TelemetryBatch] = queue.Queue()
    final = threading.Event()

    def on_status(sample) -> None:
        if ExecutionStatus.model_validate_json(sample.payload.to_bytes()).final:
            final.set()

    session = open_session("client", connect=connect, wait_s=5.0)
    try:
        subscribers = [
            session.declare_subscriber(
                view.telemetry_key, lambda s: batches.put(TelemetryBatch.model_validate_json(s.payload.to_bytes()))
            ),
            session.declare_subscriber(status_key, on_status),
        ]
        for reply in session.get(status_key, timeout=2.0):  # it may have ended while we subscribed
            if reply.ok is not None:
                on_status(reply.ok)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            try:
                yield batches.get(timeout=LIVE_DRAIN_S if final.is_set() else 0.1)
                continue
            except queue.Empty:
                if final.is_set():
                    break  # ended, and nothing more arrived for LIVE_DRAIN_S
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"execution {view.id}: no final status within {timeout_s:g} s")
        for subscriber in subscribers:
            subscriber.undeclare()
    finally:
        session.close()


LIVE_DRAIN_S = 0.5
"""After the final status, ``Client.live`` keeps yielding until no batch arrived for this long, s (status and
telemetry travel on different keys: the last batches may come after the final status)."""


class Pacer:
    """Holds each batch back until its simulated time has passed on the clock since the first one (`Pace.realtime`);
    `Pace.fast` lets every batch through at once."""

    def __init__(self, pace: Pace) -> None:
        self.pace = pace
        self.origin: float | None = None  # monotonic clock at simulated time 0, s

    def __call__(self, batch: TelemetryBatch) -> TelemetryBatch:
        if self.pace is Pace.realtime and batch.t:
            if self.origin is None:
                self.origin = time.monotonic() - batch.t[0]
            time.sleep(max(0.0, self.origin + batch.t[-1] - time.monotonic()))
        return batch


class StoredStream:
    """The stored part of an execution's stream, read in pages from where the caller has got to (``next_sample``)."""

    def __init__(self, read_page: Callable[[dict[str, int]], TelemetryView], execution_id: str) -> None:
        """``read_page``: ``GET /executions/{execution_id}/telemetry`` with these query parameters."""
        self.read_page, self.execution_id = read_page, execution_id
        self.next_sample = 0  # the stream index of the first sample not yielded yet

    def batches_before(self, stop: int | None) -> Iterator[TelemetryBatch]:
        """Stored samples from ``next_sample`` (up to ``stop``, None: all that are stored) as batches."""
        while stop is None or self.next_sample < stop:
            params = {"cursor": self.next_sample} | ({} if stop is None else {"limit": stop - self.next_sample})
            page = self.read_page(params)
            if page.n_samples == 0:
                return  # not stored yet (the API stores what it receives): the live batches carry it
            for start in range(0, page.n_samples, REPLAY_BATCH_SAMPLES):  # small batches, as the bus sends them
                rows = slice(start, start + REPLAY_BATCH_SAMPLES)
                columns = {name: getattr(page, name)[rows] for name in TELEMETRY_FIELDS}
                yield TelemetryBatch(execution_id=self.execution_id, first_sample=self.next_sample, **columns)
                self.next_sample += len(columns["t"])

    def unseen(self, batch: TelemetryBatch) -> TelemetryBatch | None:
        """The rows of a live ``batch`` not yielded yet (None: none), advancing ``next_sample`` past them."""
        first = batch.first_sample if batch.first_sample is not None else self.next_sample
        skip = max(0, self.next_sample - first)
        if skip >= len(batch.t):
            return None
        self.next_sample = first + len(batch.t)
        if skip == 0:
            return batch
        columns = {name: getattr(batch, name)[skip:] for name in TELEMETRY_FIELDS}
        return batch.model_copy(update={**columns, "first_sample": first + skip})


REPLAY_BATCH_SAMPLES = 100
"""Samples per batch ``Client.live`` yields of the stored part of a stream (0.1 s at 1 kHz): a replay at
`Pace.realtime` moves on in steps no coarser than that."""
TELEMETRY_FIELDS = tuple(Telemetry.__dataclass_fields__)
"""The per-sample columns of a `TelemetryBatch` (the rest describe the batch)."""
