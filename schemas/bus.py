"""The Zenoh bus contract: key expressions, payload models (JSON on the wire) and the session configuration.

Key expressions (``P`` is the prefix, default ``cskills``; ids are single key chunks; both built in
``schemas/key_expressions.py``):

- ``P/workers/{worker_id}`` — liveliness token, present while the worker process lives.
- ``P/exec/{worker_id}/info`` — queryable; reply ``WorkerInfo``.
- ``P/exec/{worker_id}/start`` — queryable; query ``StartExecution``, reply ``StartReply`` (accepted, busy, error,
  need_demonstration).
- ``P/exec/{worker_id}/record`` — queryable; query ``RecordRequest``, reply ``RecordReply``.
- ``P/exec/{worker_id}/replay`` — queryable; query ``TelemetryReplay``, replies ``TelemetryBatch`` (each with its
  ``first_sample``) covering the samples asked that the worker still keeps (its last ``TELEMETRY_KEEP_EXECUTIONS``
  executions), or an error reply saying it keeps none of them; at most ``REPLAY_MAX_SAMPLES`` samples per query
  (the first ones asked). Under the worker's own keys: only the worker that ran an execution can answer for it, and
  only the API may ask (``schemas.bus_security``).
- ``P/exec/{execution_id}/cmd`` — put/subscribe; ``ExecutionCommand`` (abort | pause | resume).
- ``P/exec/{execution_id}/status`` — put/subscribe; ``ExecutionStatus`` on acceptance (pending), every phase or
  segment change, pause and resume, at least every ``HEARTBEAT_S`` while it runs, and a final one (done | aborted
  | failed) with the metrics; each echoes the dispatch's ``attempt`` and counts up ``seq``. Workers also answer a
  query on it with the latest status of the executions they ran (for late joiners); a query whose payload is a
  challenge (bytes the asker just drew) is answered with the signature of the status followed by the challenge
  (``schemas.bus_security.challenge_signature``): proof that the worker holding the run's secret answers now, not a
  recording of an earlier answer.
- ``P/exec/{execution_id}/telemetry`` — put/subscribe; ``schemas.execution.TelemetryBatch``: every control step,
  in batches of ``telemetry_batch`` rows, reliable (congestion control BLOCK), numbered: ``seq`` counts the batches,
  ``first_sample`` places each in the stream, so a receiver that missed some (it was down, the router was) sees the
  gap and asks ``P/exec/{worker_id}/replay`` for it.
- ``P/sweeps/{sweep_id}/progress`` — put/subscribe; ``schemas.sweep.SweepProgress`` (the API puts it whenever a
  sweep's counts change).

Every payload is the JSON of the pydantic model named (``Model.model_validate_json(sample.payload.to_bytes())``);
queries carry theirs as the query payload. This module imports neither zenoh nor the simulator: it is the
contract, shared by the REST side (``services.bus``), the worker (``sim_worker.zenoh_worker``) and any
subscriber, in Python or another language.
"""

from __future__ import annotations

import math
import re
import time
from enum import StrEnum
from typing import Literal, TypedDict

from pydantic import BaseModel, ConfigDict, Field, JsonValue, field_validator, model_validator

from schemas.bus_security import AccessControl, BusSecurity, Transport
from schemas.dashboard import MAX_WORK_PIECE_SOLIDS, WorkPieceMesh
from schemas.demonstration import Demonstration
from schemas.execution import Engine, ExecutionMetrics, ExecutionPhase, ExecutionRequest
from schemas.key_expressions import DEFAULT_PREFIX as DEFAULT_PREFIX  # the bus contract is imported from here
from schemas.key_expressions import KeyExpressions as KeyExpressions
from schemas.key_expressions import check_id
from schemas.numbers import Real, WholeNumber
from schemas.text import FreeForm, Identifier, JsonObject
from schemas.world import WorldOverrides

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the router listens and the clients connect by default (loopback only)."""

HANDSHAKE_TIMEOUT_MS = 2000
"""How long a client waits for the router to open its session (Zenoh's ``connect/timeout_ms``), and how long the
router gives a new connection to finish its handshake and login (``transport/unicast/accept_timeout``), ms. Measured
on loopback: an authenticated session opens in 10-50 ms."""
ROUTER_UNICAST_LIMITS: dict[str, int] = {
    "accept_timeout": HANDSHAKE_TIMEOUT_MS,
    "accept_pending": 1000,
    "max_links": 1,
}
"""The router's ``transport/unicast`` limits on connections that have not logged in: a connection that has not
finished its handshake within :data:`HANDSHAKE_TIMEOUT_MS` is closed, and past ``accept_pending`` such connections at
once a new one is closed at once (one link per session, ``max_links``). Zenoh's defaults (10 s, 100) let ~110 idle
TCP connections, reopened as the router closed them, refuse 21 of 22 new sessions: a restarted worker needed 28 s to
get back in. With these, an attacker must keep 1000 connections open, each reopened within 2 s, to delay a session
(docs/BUS.md, "Floods without a login")."""

ENV_ENDPOINTS = "CONTACT_SKILLS_ZENOH_ENDPOINTS"
"""Environment variable: comma-separated endpoints the clients (API, worker, watch) connect to."""
ENV_LISTEN = "CONTACT_SKILLS_ZENOH_LISTEN"
"""Environment variable: comma-separated endpoints the embedded router listens on."""
ENV_PREFIX = "CONTACT_SKILLS_ZENOH_PREFIX"
"""Environment variable: the key-expression prefix."""

FINAL_PHASES = frozenset({ExecutionPhase.done, ExecutionPhase.aborted, ExecutionPhase.failed})
"""Phases after which an execution publishes nothing more."""


class CommandName(StrEnum):
    """A command to a running execution (``P/exec/{id}/cmd``; the REST routes ``POST /executions/{id}/<name>``)."""

    abort = "abort"
    """Stop now (within one control step of arrival)."""
    pause = "pause"
    """Hold the current reference (the control loop keeps running, in contact the force is held)."""
    resume = "resume"
    """Continue after a pause."""


HEARTBEAT_S = 2.0
"""A running execution publishes a status at least this often, s (a phase can last minutes: without it, a worker
that went silent could not be told from one in a long phase)."""
REPLAY_MAX_SAMPLES = 10_000
"""Most telemetry samples one replay query is answered with (~7 MB of JSON): a query asking more gets the first
ones; the API asks a longer gap in parts."""

OVERRIDE_BOUNDS: dict[str, tuple[float, float]] = {
    "_s": (0.0, 60.0),
    "_hz": (0.0, 10_000.0),
    "_m": (-2.0, 2.0),
    "_m_s": (0.0, 2.0),
    "_n": (-500.0, 500.0),
    "_nm": (-1000.0, 1000.0),
    "_deg": (-360.0, 360.0),
    "_rad": (-6.3, 6.3),
    "_kg": (0.0, 100.0),
    "_n_m": (0.0, 1e7),
    "_n_s_m": (0.0, 1e6),
    "_nm_rad": (0.0, 1e5),
    "_nm_s_rad": (0.0, 1e4),
}
"""Range of a recording override by the unit its name ends with (the longest matching suffix applies): a teacher
move of 2000 s or a table 100 m away is refused before a worker spends minutes and gigabytes on it."""
OVERRIDE_DEFAULT_BOUND = 1e5
"""Magnitude bound of an override whose name ends with no known unit (gains, ratios)."""
_OVERRIDE_NAME = re.compile(r"^[a-z][a-z0-9_]{0,63}$")


def check_override(name: str, value: JsonValue) -> None:
    """Raise ValueError unless ``value`` is a plausible override ``name``: a snake_case name, a boolean, null, or a
    finite number (or a list of at most 16) within the bounds of :data:`OVERRIDE_BOUNDS` for its unit suffix."""
    if not _OVERRIDE_NAME.match(name):
        raise ValueError(f"override {name!r}: not a field name (snake_case, at most 64 characters)")
    if value is None or isinstance(value, bool):
        return
    items = value if isinstance(value, list) else [value]
    if len(items) > 16 or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in items):
        raise ValueError(f"override {name}: a number, a boolean or a list of at most 16 numbers is needed, got "
                         f"{str(value)[:80]}")  # fmt: skip
    suffix = max((s for s in OVERRIDE_BOUNDS if name.endswith(s)), key=len, default=None)
    low, high = OVERRIDE_BOUNDS[suffix] if suffix else (-OVERRIDE_DEFAULT_BOUND, OVERRIDE_DEFAULT_BOUND)
    for v in items:
        if not (math.isfinite(v) and low <= v <= high):
            raise ValueError(f"override {name}: {v!r} is outside the plausible range [{low:g}, {high:g}]")


def split_endpoints(text: str | None) -> list[str]:
    """Split a comma-separated endpoint list (``tcp/127.0.0.1:7447,tcp/10.0.0.2:7447``); empty items dropped."""
    return [item.strip() for item in (text or "").split(",") if item.strip()]


class Endpoints(TypedDict, total=False):
    """Where a session connects or listens; a client also bounds its handshake and retries (``session_config``)."""

    endpoints: list[str]
    timeout_ms: int
    exit_on_failure: bool


class SessionConfig(TypedDict, total=False):
    """A Zenoh session configuration as :func:`session_config` builds it (JSON-able)."""

    mode: Literal["client", "peer", "router"]
    scouting: dict[str, dict[str, bool]]
    connect: Endpoints
    listen: Endpoints
    transport: Transport
    access_control: AccessControl


def session_config(
    mode: Literal["client", "peer", "router"],
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    security: BusSecurity | None = None,
    access_control: AccessControl | None = None,
) -> SessionConfig:
    """The Zenoh session configuration (a JSON-able dict) every process of the bus uses.

    Multicast scouting is off: sessions meet only through the configured endpoints (a router). A client's
    ``zenoh.open`` fails after 2 s without a router (:data:`HANDSHAKE_TIMEOUT_MS`); a router bounds the connections
    that have not logged in (:data:`ROUTER_UNICAST_LIMITS`); the processes retry (start order does not matter, e.g. in
    docker-compose); once connected, a client reconnects by itself when the router restarts.
    ``security`` (`schemas.bus_security.BusSecurity`): the login and TLS of the session, or what the router
    requires; ``access_control``: the router's (`schemas.bus_security.access_control`). Neither: an open bus.
    Open with ``zenoh.open(zenoh.Config.from_json5(json.dumps(session_config(...))))``.
    """
    config: SessionConfig = {
        "mode": mode,
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": mode != "client"}},
    }
    if connect:
        config["connect"] = {"endpoints": list(connect)}
        if mode == "client":
            config["connect"].update({"timeout_ms": HANDSHAKE_TIMEOUT_MS, "exit_on_failure": False})
    if listen:
        config["listen"] = {"endpoints": list(listen)}
    transport: Transport = security.transport(mode) if security is not None else {}
    if mode == "router":  # the listening side bounds the connections that have not logged in
        transport["unicast"] = dict(ROUTER_UNICAST_LIMITS)
    if transport:
        config["transport"] = transport
    if access_control is not None:
        config["access_control"] = access_control
    return config


# ---------------------------------------------------------------------------------------------------------------
# Payloads
# ---------------------------------------------------------------------------------------------------------------


class WorkerInfo(BaseModel):
    """What a worker says about itself (reply of ``P/exec/{worker_id}/info``)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "worker_id": "worker-sim1-4242",
                    "busy": True,
                    "activity": "executing",
                    "execution_id": "ex_01",
                    "hostname": "sim1",
                    "pid": 4242,
                    "started_unix_s": 1763700000.0,
                    "executions_run": 3,
                    "engine": "pybullet",
                }
            ]
        },
    )

    worker_id: str
    busy: bool = Field(description="True while executing or recording (a start or record request gets 'busy').")
    activity: Literal["idle", "executing", "recording", "unknown"] = Field(
        "idle", description="unknown: alive (liveliness token) but its info query was not answered in time."
    )
    execution_id: str | None = Field(None, description="The execution running now, if any.")
    hostname: str = ""
    pid: int = 0
    started_unix_s: Real = Field(0.0, description="When the worker process started, Unix time, s.")
    executions_run: int = Field(0, description="Executions accepted since the worker started.")
    engine: Engine | None = Field(
        None, description="Its default engine: what an execution that names none runs on (None: not said yet)."
    )


class StartExecution(BaseModel):
    """Query payload of ``P/exec/{worker_id}/start``: run ``request`` (with the skill INLINE) as ``execution_id``."""

    model_config = ConfigDict(extra="forbid")

    execution_id: str = Field(description="Id chosen by the caller; the key chunk of the execution's keys.")
    request: ExecutionRequest = Field(description="What to run; ``request.skill`` must be given inline.")
    world_overrides: WorldOverrides = Field(
        default_factory=dict,
        description="WorldConfig fields applied on top of the scenario's world (e.g. those the demonstration "
        "was recorded with: ``{'table_height_m': 0.12}``), checked against it (``schemas.world.WorldOverrides``).",
    )
    demonstration: Demonstration | None = Field(
        None, description="The demonstration the skill was learned from, for the path metric (optional)."
    )
    answer_by_unix_s: Real | None = Field(
        None,
        description="When the caller stops waiting for the reply (wall clock, s since the epoch). A worker that "
        "could only answer later refuses instead of starting: the caller has given up on it and may have started "
        "the execution on another worker.",
    )
    attempt: str = Field(
        "",
        max_length=64,
        description="This dispatch's nonce, fresh for every hand-over of the execution: the worker echoes it in every "
        "status (``ExecutionStatus.attempt``) and the run's secret is bound to it, so no report of an earlier "
        "dispatch counts for this one.",
    )
    demonstration_id: str | None = Field(
        None,
        max_length=64,
        description="The stored id of that demonstration (stored demonstrations never change): a worker keeps the "
        "last few it was sent under their ids, and a start that names one without sending it runs with its copy; "
        "one it does not keep is answered ``need_demonstration`` (then sent again with it). A sweep's trials send "
        "their ~2 MB demonstration once per worker instead of once per trial.",
    )

    @model_validator(mode="after")
    def _inline(self) -> StartExecution:
        check_id(self.execution_id, "execution_id")
        if self.request.skill is None:
            raise ValueError("request.skill must be inline on the bus (resolve skill_id before sending)")
        return self


class StartReply(BaseModel):
    """Reply of ``P/exec/{worker_id}/start``."""

    model_config = ConfigDict(extra="forbid")

    accepted: bool
    code: Literal["accepted", "busy", "error", "need_demonstration"] = Field(
        description="busy: the worker runs something else; need_demonstration: the start named a "
        "``demonstration_id`` this worker does not keep (ask again with the demonstration)."
    )
    worker_id: str
    execution_id: str
    reason: str | None = Field(None, description="Why not accepted.")


class RecordRequest(BaseModel):
    """Query payload of ``P/exec/{worker_id}/record``: record the scripted teacher's demonstration of a scenario."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"scenario": "slide_flat", "seed": 0, "overrides": {"target_force_n": 10.0}}]},
    )

    scenario: Identifier = Field(
        description="A teacher scenario (``sim_worker.teacher.SCENARIOS``).", examples=["slide_flat"]
    )
    seed: WholeNumber = Field(
        0, ge=0, le=2**32 - 1, description="Seed of the human-like imperfection; same seed, same recording."
    )
    overrides: FreeForm = Field(
        default_factory=dict,
        max_length=32,
        description="TeacherParams or WorldConfig fields, e.g. {'target_force_n': 10, 'move_duration_s': 4}. Booleans, "
        "null or numbers (or lists of up to 16), the numbers bounded by the unit their name ends with: "
        + ", ".join(f"``*{suffix}`` within [{low:g}, {high:g}]" for suffix, (low, high) in OVERRIDE_BOUNDS.items())
        + f", any other within ±{OVERRIDE_DEFAULT_BOUND:g}.",
    )

    @field_validator("overrides")
    @classmethod
    def _overrides_are_bounded(cls, value: dict[str, JsonValue]) -> dict[str, JsonValue]:
        for name, item in value.items():
            check_override(name, item)
        return value


class RecordReply(BaseModel):
    """Reply of ``P/exec/{worker_id}/record``: the demonstration and its ground truth, or an error."""

    model_config = ConfigDict(extra="forbid")

    worker_id: str
    code: Literal["ok", "busy", "error"]
    demonstration: Demonstration | None = None
    ground_truth: JsonObject | None = Field(
        None,
        description="The teacher's truth: scenario, seed, skill_type, target force, contact intervals, truth "
        "segments (with the true normals of slide segments), world_config, teacher params.",
    )
    error: str | None = Field(None, description="Why nothing was recorded (e.g. an unknown scenario or override).")
    wall_s: Real = Field(0.0, description="Wall time the recording took, s.")

    @property
    def ok(self) -> bool:
        return self.code == "ok" and self.demonstration is not None


class TelemetryReplay(BaseModel):
    """Query payload of ``P/exec/{worker_id}/replay``: send again the samples ``start`` to ``stop - 1`` of an
    execution's telemetry stream (``TelemetryBatch.first_sample`` numbering)."""

    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"execution_id": "ex_01", "start": 3000, "stop": 4710}]}
    )

    execution_id: str = Field(description="The execution whose telemetry is wanted.")
    start: int = Field(ge=0, description="First sample wanted (a control step index, from 0).")
    stop: int = Field(ge=0, description="One past the last sample wanted.")

    @model_validator(mode="after")
    def _range(self) -> TelemetryReplay:
        check_id(self.execution_id, "execution_id")
        if self.stop <= self.start:
            raise ValueError(f"stop ({self.stop}) must be greater than start ({self.start})")
        return self


class ExecutionCommand(BaseModel):
    """Payload of ``P/exec/{execution_id}/cmd``."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"command": "abort"}]})

    command: CommandName = Field(
        description="abort: stop now (within one control step of arrival); pause: hold the current reference "
        "(the control loop keeps running, in contact the force is held); resume: continue."
    )
    execution_id: str = ""
    reason: str | None = Field(None, description="Free text, reported back in the status message.")
    sent_unix_s: Real = Field(default_factory=time.time, description="Sender's wall clock, Unix time, s.")


class ExecutionStatus(BaseModel):
    """Payload of ``P/exec/{execution_id}/status``: published on every change; the last one has a final phase."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "execution_id": "ex_01",
                    "worker_id": "worker-sim1-4242",
                    "phase": "contact",
                    "segment_index": 1,
                    "segments": 7,
                    "message": "segment 1: contact",
                    "t": 2.731,
                    "seq": 5,
                }
            ]
        },
    )

    execution_id: str
    worker_id: str
    phase: ExecutionPhase
    segment_index: int = Field(-1, description="Skill segment being executed; -1 before the first one.")
    segments: int = Field(0, description="Number of segments of the skill.")
    message: str = ""
    t: Real = Field(0.0, description="Simulated time of the execution at this status, s.")
    steps: int = Field(0, description="Control steps run so far.")
    paused: bool = False
    metrics: ExecutionMetrics | None = Field(None, description="When finished (done, aborted, failed).")
    error: str | None = Field(None, description="Why it was aborted or failed.")
    abort_received_t: Real | None = Field(
        None,
        description="Simulated time of the last control step completed when the worker received the abort "
        "command, s (the last telemetry sample is at most one control step later).",
    )
    attempt: str = Field(
        "", max_length=64, description="The dispatch it reports on: ``StartExecution.attempt``, echoed."
    )
    seq: int = Field(
        0,
        description="Sequence number of the status within its attempt, from 0, one more for every status published: "
        "the API takes a status only above the last one it took, so none moves a run back.",
    )
    sent_unix_s: Real = Field(default_factory=time.time, description="Worker's wall clock at publication, s.")
    work_piece: list[WorkPieceMesh] | None = Field(
        None,
        max_length=MAX_WORK_PIECE_SOLIDS,
        description="The solids of the world the run uses (its first world, for a run stroke by stroke), world frame, "
        "m: sent with the first status of an attempt only (the dashboard's 3-D scene draws them).",
    )

    @property
    def final(self) -> bool:
        """True for done, aborted and failed: nothing follows."""
        return self.phase in FINAL_PHASES
