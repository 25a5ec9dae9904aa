"""The typed rows the repositories return (one class per table's view), and how they are read from SQLite rows."""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, JsonValue, ValidationError

from schemas.api import ExecutionState
from schemas.demonstration import DemonstrationSummary
from schemas.execution import ControllerKind, ExecutionMetrics, ExecutionPhase, TelemetryMode
from schemas.skill import SkillType
from schemas.sweep import SweepState
from services.store.database import log


def first_problem(exc: ValidationError) -> str:
    """The first problem of a validation error, as ``field: message``."""
    first = exc.errors()[0]
    return f"{'.'.join(str(part) for part in first['loc']) or 'body'}: {first['msg']}"


def stored_metrics(text: str | None, what: str) -> ExecutionMetrics | None:
    """Stored metrics JSON as :class:`ExecutionMetrics`; None when there are none, or when they no longer validate
    (stored by an earlier version: logged with ``what`` they belong to, so one old row cannot fail a listing)."""
    if not text:
        return None
    try:
        return ExecutionMetrics.model_validate_json(text)
    except ValidationError as exc:
        log.warning("the stored metrics of %s cannot be read back: %s", what, first_problem(exc))
        return None


@dataclass(frozen=True)
class DemonstrationRow:
    id: str
    created: float
    name: str
    summary: DemonstrationSummary | None
    """None for a row stored by an earlier version that cannot be read back (``problem`` says why)."""
    source: str
    problem: str | None = None
    """Why the stored demonstration cannot be read back (None: it can)."""
    stored_bytes: int = 0
    """What the row takes in the database (its body and summary), bytes."""

    @classmethod
    def of(cls, r: sqlite3.Row) -> DemonstrationRow:
        """From a demonstrations row (id, created, name, summary[, source, stored_bytes]); a summary that does not
        validate (stored by an earlier version: a step of 5e-324 s gave an infinite rate, stored as null) leaves it
        None with the problem."""
        try:
            summary, problem = DemonstrationSummary.model_validate_json(r["summary"]), None
        except ValidationError as exc:
            summary, problem = None, f"its stored summary does not validate: {first_problem(exc)}"
        more = r.keys()
        source = r["source"] if "source" in more else None
        stored = r["stored_bytes"] if "stored_bytes" in more else None
        return cls(r["id"], r["created"], r["name"], summary, source or "", problem, int(stored or 0))


SAMPLE_ARRAYS = ("t", "positions", "orientations", "wrenches")
"""The per-sample arrays of a demonstration, in the order it is written."""


@dataclass(frozen=True)
class DemonstrationSamples:
    """A stored demonstration's samples as arrays (``DemonstrationRepository.samples``): what a paged read slices."""

    t: np.ndarray
    """Time stamps, (N,), s."""
    positions: np.ndarray
    """Tool positions, (N, 3), m, world."""
    orientations: np.ndarray
    """Tool orientations, (N, 4), [x, y, z, w], world."""
    wrenches: np.ndarray
    """Applied wrenches, (N, 6), N and N·m, world."""
    metadata: str
    """The metadata as stored (JSON text)."""

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.size)


@dataclass(frozen=True)
class SkillRow:
    id: str
    demonstration_id: str | None
    created: float
    skill_type: SkillType
    skill_json: str
    warnings: list[str]
    """The messages of the skill's failed checks (``Skill.warnings()``)."""


@dataclass(frozen=True)
class SkillSummaryRow:
    """A skill as listed (no parameters)."""

    id: str
    demonstration_id: str | None
    created: float
    skill_type: SkillType
    segments: int
    confidence: float | None
    failed_checks: int
    demonstration_name: str | None


class SweepTrialRef(BaseModel):
    """The sweep and trial an execution ran for (its shown request's ``sweep``)."""

    id: str
    trial: int


@dataclass(frozen=True)
class ExecutionRow:
    id: str
    skill_id: str | None
    worker_id: str | None
    status: ExecutionState
    phase: ExecutionPhase
    request: dict[str, JsonValue]
    """The request as it was accepted and is shown back (an inline skill left out; ``sweep`` names a sweep's)."""
    metrics: ExecutionMetrics | None
    error: str | None
    created: float
    updated: float
    priority: int = 0
    attempt: str | None = None
    """The nonce of its current dispatch (``StartExecution.attempt``); None before its first."""
    handovers: int = 0
    """How many times a worker accepted it (more than one: the dispatch watchdog took it back from a silent one)."""

    @classmethod
    def of(cls, row: sqlite3.Row) -> ExecutionRow:
        return cls(
            id=row["id"],
            skill_id=row["skill_id"],
            worker_id=row["worker_id"],
            status=ExecutionState(row["status"]),
            phase=ExecutionPhase(row["phase"]),
            request=json.loads(row["request"]),
            metrics=stored_metrics(row["metrics"], row["id"]),
            error=row["error"],
            created=row["created"],
            updated=row["updated"],
            priority=row["priority"],
            attempt=row["attempt"],
            handovers=row["handovers"],
        )

    @property
    def streams_telemetry(self) -> bool:
        """Whether its worker publishes its telemetry (``ExecutionSettings.telemetry``; a request stored before
        that setting existed streamed)."""
        return self.request.get("telemetry", TelemetryMode.stream.value) == TelemetryMode.stream.value

    @property
    def sweep(self) -> SweepTrialRef | None:
        """The sweep and trial it ran for; None when it was not a sweep's trial."""
        sweep = self.request.get("sweep")
        return SweepTrialRef.model_validate(sweep) if sweep else None


class SweepTerms(BaseModel):
    """What a sweep's trials run with and are judged by, read back from its stored request: the controllers each
    trial runs, the seed of the trials' noise, and the success criteria (`schemas.sweep.SWEEP_TOLERANCES`)."""

    controllers: list[ControllerKind]
    seed: int
    success_rms_pct: float
    success_contact_ratio: float


@dataclass(frozen=True)
class SweepRow:
    id: str
    created: float
    updated: float
    status: SweepState
    request: dict[str, JsonValue]
    """The request as shown back (an inline skill is not repeated)."""
    spec: str
    """JSON: what every trial's execution starts from (the request with the skill inline, the demonstration id)."""

    @classmethod
    def of(cls, row: sqlite3.Row) -> SweepRow:
        return cls(
            row["id"],
            row["created"],
            row["updated"],
            SweepState(row["status"]),
            json.loads(row["request"]),
            row["spec"],
        )

    @property
    def terms(self) -> SweepTerms:
        """The controllers, seed and success criteria of its request."""
        return SweepTerms.model_validate(self.request)


@dataclass(frozen=True)
class SweepTrialRow:
    trial: int
    controller: ControllerKind
    parameters: dict[str, float]
    execution_id: str | None
    attempts: int
    status: ExecutionState | None
    metrics: ExecutionMetrics | None
    error: str | None
