"""What the service accepts beyond the field bounds of ``schemas/``: time stamps it can learn from in bounded
memory, inline skills whose parts fit together, connections that send their request head in time, per-client caps
on queued work."""

from __future__ import annotations

import asyncio
import threading
from enum import StrEnum
from typing import Any

import numpy as np
from fastapi import HTTPException
from uvicorn.protocols.http.h11_impl import H11Protocol

from schemas.api import ApiError, ExecutionState
from schemas.demonstration import Demonstration
from schemas.skill import Skill
from schemas.sweep import SweepState
from services.store import ACTIVE, Store

MAX_RATE_HZ = 100_000.0
"""Highest sampling rate the service learns from (as the CSV importer's resampling limit), Hz."""
UPLOAD_STORED_MULTIPLE = 16.0
"""An uploaded recording (CSV, bag) stores at most this many times the bytes it brought. The real recordings store
0.4-0.6x (KU Leuven CSVs); a row-per-sample CSV with short numbers ~7x. Past it the time stamps span far more samples
than the file has rows (resampling would invent them)."""
MAX_GRID_SAMPLES = 1_000_000
"""Most samples a demonstration may span on its uniform grid (duration / median step): 16.7 min at 1 kHz."""


def check_sampling(demonstration: Demonstration) -> None:
    """Raise `LearningError` on ``t`` for time stamps the pipeline cannot work on in bounded memory: a rate above
    :data:`MAX_RATE_HZ` (filter windows are sized in samples per second) or a uniform grid (duration at the
    median step, what irregular stamps are resampled to) longer than :data:`MAX_GRID_SAMPLES`."""
    from skills.parameterize import LearningError

    t = np.asarray(demonstration.t)
    step = float(np.median(np.diff(t)))
    if 1.0 / step > MAX_RATE_HZ:
        raise LearningError(
            "t",
            f"median time step {step:.3g} s is a {1 / step:.3g} Hz rate, above {MAX_RATE_HZ:g} Hz: are the "
            "time stamps in seconds?",
        )
    grid = (t[-1] - t[0]) / step + 1
    if grid > MAX_GRID_SAMPLES:
        raise LearningError(
            "t",
            f"{t[-1] - t[0]:.6g} s at the median step of {step:.3g} s spans {grid:.3g} samples, more than "
            f"{MAX_GRID_SAMPLES} (a gap in the time stamps, or a very long recording)",
        )


def skill_problems(skill: Skill) -> list[tuple[list[str | int], str]]:
    """Where an inline skill that validates field by field is still incoherent, as (loc under ``skill``, reason):
    a contact segment without compliant frames or without a force, DMP parameters whose shapes disagree
    (``skills.dmp`` rebuilds each one), compliant frame lists of different lengths."""
    from schemas.skill import SegmentKind
    from skills.dmp import DMP, QuaternionDMP

    problems: list[tuple[list[str | int], str]] = []
    for k, segment in enumerate(skill.segments):
        where: list[str | int] = ["segments", k]
        if segment.kind is SegmentKind.contact:
            if segment.compliant_frames is None:
                problems.append(([*where, "compliant_frames"], "a contact segment needs its compliant frame(s)"))
            if segment.force_constant_n is None and segment.force_dmp is None:
                problems.append(([*where, "force_constant_n"], "a contact segment needs force_constant_n or force_dmp"))
        frames = segment.compliant_frames
        if frames is not None and not len(frames.t) == len(frames.origins) == len(frames.orientations):
            problems.append(([*where, "compliant_frames"], "t, origins and orientations need one entry per frame"))
        for name, rebuild in (("position_dmp", DMP), ("orientation_dmp", QuaternionDMP), ("force_dmp", DMP)):
            parameters = getattr(segment, name)
            if parameters is None:
                continue
            try:
                rebuild.from_parameters(parameters)
            except ValueError as exc:
                problems.append(([*where, name], f"inconsistent DMP parameters: {exc}"))
    return problems


class HeadTimeoutH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline on the request head: a connection that has not sent a whole request
    line and headers within ``head_timeout_s`` of connecting (or of its first byte after a response) is closed.

    uvicorn itself times out only idle keep-alive connections after a response: a client that connects and sends
    nothing, or a header byte now and then, kept its connection (and a file handle) for good; 20 600 such
    connections exhausted the API's file handles and ``/health`` stopped answering."""

    head_timeout_s = 10.0
    """Set by :func:`head_timeout_protocol`, s."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        self._head_deadline: asyncio.TimerHandle | None = None
        super().connection_made(transport)
        self._watch_head()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._watch_head()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._head_deadline is not None:
            self._head_deadline.cancel()
            self._head_deadline = None
        super().connection_lost(exc)

    def _waiting_for_head(self) -> bool:
        return self.cycle is None or self.cycle.response_complete

    def _watch_head(self) -> None:
        """Arm the deadline while a request head is awaited, cancel it once one arrived."""
        if self._waiting_for_head():
            if self._head_deadline is None:
                self._head_deadline = self.loop.call_later(self.head_timeout_s, self._head_overdue)
        elif self._head_deadline is not None:
            self._head_deadline.cancel()
            self._head_deadline = None

    def _head_overdue(self) -> None:
        self._head_deadline = None
        if self._waiting_for_head() and not self.transport.is_closing():
            self.transport.close()


def head_timeout_protocol(head_timeout_s: float) -> type[HeadTimeoutH11Protocol]:
    """The protocol class for ``uvicorn.Config(http=...)`` with a head deadline of ``head_timeout_s`` seconds."""
    return type("HeadTimeoutH11", (HeadTimeoutH11Protocol,), {"head_timeout_s": head_timeout_s})


class WorkKind(StrEnum):
    """What one client may hold at most so many of at once (:class:`ClientCaps`)."""

    execution = "execution"
    sweep = "sweep"


TOO_MANY: dict[int | str, dict[str, Any]] = {429: {"model": ApiError}}
"""``responses=`` of the routes a client's cap applies to (:class:`ClientCaps`)."""


class ClientCaps:
    """Per-client caps on the work waiting in the service: executions queued or running (``client_queued_max``) and
    sweeps running (``client_sweeps_max``), by client address. One more answers 429 naming the cap; the global queue
    cap (``queue_max``, 503) still holds for all clients together. Counted by this API process: a restart forgets
    who submitted what (the store keeps no client)."""

    def __init__(self, store: Store, max_executions: int, max_sweeps: int) -> None:
        self.store = store
        self.caps = {WorkKind.execution: max_executions, WorkKind.sweep: max_sweeps}
        self._held: dict[tuple[WorkKind, str], set[str]] = {}
        self._lock = threading.Lock()

    def _active(self, kind: WorkKind, ident: str) -> bool:
        if kind is WorkKind.execution:
            row = self.store.executions.get(ident)
            return row is not None and row.status in (ExecutionState.queued, *ACTIVE)
        sweep = self.store.sweeps.get(ident)
        return sweep is not None and sweep.status == SweepState.running.value

    def admit(self, kind: WorkKind, client: str) -> None:
        """Raise a 429 ``HTTPException`` if ``client`` holds its cap of ``kind`` already."""
        with self._lock:
            held = set(self._held.get((kind, client), ()))
        active = {ident for ident in held if self._active(kind, ident)}
        with self._lock:
            self._held[(kind, client)] = active | (self._held.get((kind, client), set()) - held)
        if len(active) >= self.caps[kind]:
            setting = {WorkKind.execution: "CONTACT_SKILLS_CLIENT_QUEUED_MAX", WorkKind.sweep:
                       "CONTACT_SKILLS_CLIENT_SWEEPS_MAX"}[kind]  # fmt: skip
            raise HTTPException(
                429,
                f"client {client} has {len(active)} {kind.value}s queued or running, its cap ({setting}="
                f"{self.caps[kind]}): wait for one to end, or cancel one",
            )

    def hold(self, kind: WorkKind, client: str, ident: str) -> None:
        """Count ``ident`` (just created) against ``client``'s cap until it ends."""
        with self._lock:
            self._held.setdefault((kind, client), set()).add(ident)
