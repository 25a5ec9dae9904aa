"""REST-only bodies of the service (``services/api/``): what the endpoints take and return besides the core models.

Ids are short random strings with a kind prefix (``demo_``, ``skill_``, ``exec_`` + 12 hex digits).
Times (``created``, ``updated``) are Unix seconds.
"""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.bus import CommandName
from schemas.demonstration import (
    Demonstration,
    DemonstrationMetadata,
    DemonstrationSummary,
    Quaternion,
    Vector3,
    Wrench,
)
from schemas.execution import Engine, ExecutionMetrics, ExecutionPhase, TelemetryBatch
from schemas.numbers import Real
from schemas.skill import MAX_JOINT_DEMONSTRATIONS, MAX_JOINT_SAMPLES, LearnOptions, Skill
from schemas.text import Identifier, JsonObject
from schemas.verdict import Verdict

NEXT_OFFSET_HEADER = "X-Next-Offset"
"""The header of a list page (``GET /demonstrations``, ``/skills``, ``/executions``, ``/sweeps``) that is not the last:
the ``offset`` of the next one (a page stops at ``limit`` items or at the API's byte budget, whichever comes first)."""


class ExecutionState(StrEnum):
    """Life cycle of an execution as the API records it."""

    queued = "queued"
    """Waiting for a free sim worker (``services/queue.py``; kept in the database across API restarts)."""
    starting = "starting"
    """Being handed to a worker."""
    running = "running"
    """A worker accepted it."""
    paused = "paused"
    """The worker holds it paused (``POST /executions/{id}/resume`` continues it)."""
    done = "done"
    """The worker finished every segment."""
    aborted = "aborted"
    """Stopped early: a safety limit or an abort request (or cancelled while queued)."""
    failed = "failed"
    """An internal error, a lost worker, or the API restarted while it ran."""


class TelemetryFormat(StrEnum):
    """What ``GET .../telemetry`` returns."""

    json = "json"
    """Columns of arrays (JSON)."""
    csv = "csv"
    """One row per sample, a header row naming the columns (text/csv)."""
    mcap = "mcap"
    """MCAP with ROS 2 message types (Foxglove, PlotJuggler; see services/telemetry_export.py)."""


class ApiError(BaseModel):
    """The body of every 4xx/5xx that is not a validation error: ``detail`` says what and why."""

    detail: str = Field(description="What went wrong and what to do.", examples=["no skill with id 'skill_0a1b'"])


class DemonstrationCreated(BaseModel):
    """``POST /demonstrations`` (JSON, CSV, record): the stored demonstration's id and summary."""

    id: str = Field(description="Id of the stored demonstration.", examples=["demo_3f2a9c01b2d4"])
    created: Real = Field(description="When it was stored, Unix s.")
    source: str = Field(description="Where it came from: json, csv:<file>, teacher:<scenario>.")
    summary: DemonstrationSummary
    import_notes: list[str] = Field(
        default_factory=list, description="What the importer did (resampling, frame, sign, tare); uploads only."
    )
    extra: JsonObject = Field(
        default_factory=dict, description="Extra information (e.g. the teacher's ground truth for recordings)."
    )


class DemonstrationInfo(BaseModel):
    """One row of ``GET /demonstrations`` (no samples)."""

    id: str
    created: Real
    name: str
    source: str
    summary: DemonstrationSummary | None = Field(
        description="Samples, duration, rate, largest force; None for a demonstration that cannot be read back."
    )
    problem: str | None = Field(
        None,
        description="Why the stored demonstration cannot be read back (stored by an earlier version under looser "
        "rules, e.g. time stamps 5e-324 s apart); its GET and telemetry answer 409: delete it "
        "(DELETE /demonstrations/{id}). None when it can.",
    )


class DemonstrationWindow(BaseModel):
    """Consecutive samples of a stored demonstration with its metadata: a `Demonstration`'s fields, any number of
    samples (a page of ``GET /demonstrations/{id}``; the pages put together are the `Demonstration`)."""

    t: list[float] = Field(description="Time stamps, s.")
    positions: list[Vector3] = Field(description="Tool point positions, m, world frame.")
    orientations: list[Quaternion] = Field(description="Tool orientations in world, [x, y, z, w].")
    wrenches: list[Wrench] = Field(description="Wrenches applied by the tool, world frame, N and N·m.")
    metadata: DemonstrationMetadata


class StoredDemonstration(BaseModel):
    """``GET /demonstrations/{id}``: the demonstration with its samples, or a page of them."""

    id: str
    created: Real
    summary: DemonstrationSummary
    cursor: int = Field(0, description="Index of the first sample in this reply.")
    next_cursor: int | None = Field(
        None, description="Index of the first sample of the next page (also the X-Next-Cursor header); None: the last."
    )
    demonstration: DemonstrationWindow


class SkillRequest(LearnOptions):
    """``POST /skills``: learn from a stored demonstration (``demonstration_id``), several stored demonstrations of
    the same task learned together (``demonstration_ids``), OR an inline one (``demonstration``), with the options of
    `LearnOptions` (all optional)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"demonstration_id": "demo_3f2a9c01b2d4", "skill_type": "auto"},
                {"demonstration_id": "demo_3f2a9c01b2d4", "skill_type": "contour", "n_basis": 80},
                {"demonstration_ids": ["demo_3f2a9c01b2d4", "demo_77aa01c2d3e4"], "misfit": "refuse"},
            ]
        },
    )

    demonstration_id: Identifier | None = Field(
        None, description="Id of a stored demonstration (or give `demonstration_ids` or `demonstration`)."
    )
    demonstration_ids: list[Identifier] | None = Field(
        None,
        min_length=1,
        max_length=MAX_JOINT_DEMONSTRATIONS,
        description="Ids of stored demonstrations of the same task, learned together into ONE skill (docs/LEARNING.md "
        f"section 11): at most {MAX_JOINT_DEMONSTRATIONS}, each once, {MAX_JOINT_SAMPLES} samples in all; one id "
        "learns exactly as `demonstration_id`.",
    )
    demonstration: Demonstration | None = Field(
        None, description="An inline demonstration (not stored; or give `demonstration_id`)."
    )

    @model_validator(mode="after")
    def _one_demonstration(self) -> SkillRequest:
        given = [self.demonstration_id, self.demonstration_ids, self.demonstration]
        if sum(value is not None for value in given) != 1:
            raise ValueError(
                "give exactly one of demonstration_id (a stored demonstration), demonstration_ids (several stored "
                "ones of the same task) or demonstration (inline)"
            )
        if self.demonstration_ids is not None and len(set(self.demonstration_ids)) != len(self.demonstration_ids):
            twice = sorted({i for i in self.demonstration_ids if self.demonstration_ids.count(i) > 1})
            raise ValueError(f"demonstration_ids: each demonstration once ({', '.join(twice)} given twice)")
        return self

    def stored_ids(self) -> list[str] | None:
        """The stored demonstrations to learn from, in order (None: the inline one)."""
        if self.demonstration_ids is not None:
            return list(self.demonstration_ids)
        return None if self.demonstration_id is None else [self.demonstration_id]

    def learn_options(self) -> LearnOptions:
        """The `LearnOptions` part of the request."""
        return LearnOptions(**self.model_dump(include=set(LearnOptions.model_fields)))


class StoredSkill(BaseModel):
    """``POST /skills`` (201) and ``GET /skills/{id}``: the skill with its id."""

    id: str = Field(description="Id of the stored skill.", examples=["skill_9b1c2d3e4f50"])
    demonstration_id: str | None = Field(description="The stored demonstration it was learned from; None if inline.")
    created: Real = Field(description="When it was stored, Unix s.")
    learn_seconds: Real | None = Field(None, description="How long learning took, s (only in the POST reply).")
    warnings: list[str] = Field(
        default_factory=list,
        description="The messages of the skill's failed checks against its demonstration (`skill.checks`): where it "
        "may be wrong. Empty when every check passed.",
    )
    skill: Skill


class SkillInfo(BaseModel):
    """One row of ``GET /skills`` (no parameters)."""

    id: str
    demonstration_id: str | None
    created: Real
    skill_type: str = Field(description="slide or contour.")
    segments: int = Field(description="Number of segments.")
    confidence: Real | None = Field(description="Confidence of the auto selection, if `auto` was asked.")
    failed_checks: int = Field(0, description="How many of the skill's checks failed (its warnings).")
    demonstration_name: str | None = Field(description="Name of the demonstration it was learned from.")


class ExecutionCreated(BaseModel):
    """``POST /executions`` (202): the execution runs on a worker; follow it over REST or Zenoh."""

    id: str = Field(description="Id of the execution.", examples=["exec_0c1d2e3f4a5b"])
    status: ExecutionState = Field(description="Status when the reply was sent: running, or queued while every "
                                   "worker is busy.")  # fmt: skip
    worker_id: str | None = Field(description="The sim worker that runs it (None while queued).")
    queue_position: int | None = Field(
        None, description="While queued: how many queued executions start before it (0: the next one)."
    )
    telemetry_key: str = Field(
        description="Zenoh key expression of its telemetry (TelemetryBatch JSON).",
        examples=["cskills/exec/exec_0c1d2e3f4a5b/telemetry"],
    )
    status_key: str = Field(
        description="Zenoh key expression of its status updates.", examples=["cskills/exec/exec_0c1d2e3f4a5b/status"]
    )


class ExecutionView(BaseModel):
    """``GET /executions/{id}``: status, phase, metrics of one execution."""

    id: str
    skill_id: str | None = Field(description="The stored skill it runs (None for an inline skill).")
    worker_id: str | None = Field(description="The worker that runs/ran it (None until one accepted it).")
    status: ExecutionState
    phase: ExecutionPhase = Field(description="Last reported execution phase.")
    metrics: ExecutionMetrics | None = Field(None, description="What it achieved; present once it has finished.")
    verdict: Verdict | None = Field(
        None,
        description="Once finished: pass or fail against its tolerances (the reasons and warnings are in "
        "metrics.verdict).",
    )
    error: str | None = Field(None, description="Why it failed or aborted, if it did.")
    created: Real
    updated: Real
    telemetry_key: str = Field(description="Zenoh key expression of its telemetry.")
    telemetry_batches: int = Field(
        description="Telemetry blocks stored so far (a batch received, or the part of a replayed one that was missing)."
    )
    telemetry_samples: int = Field(description="Telemetry samples (control steps) stored so far.")
    telemetry_missing_samples: int | None = Field(
        None,
        description="Once finished: control steps the worker ran whose telemetry is not stored and could not be "
        "fetched back from the worker (it was published while the API was down or cut off from the router, and the "
        "worker is gone or no longer keeps it), 0 when the stream is complete; None while it runs and for an "
        "execution run with telemetry 'none' (no stream was meant to be sent).",
    )
    request: JsonObject = Field(description="The request as it was accepted (an inline skill is left out).")
    priority: int = Field(0, description="Its queue priority.")
    queue_position: int | None = Field(
        None, description="While queued: how many queued executions start before it (0: the next one)."
    )


class TelemetryView(TelemetryBatch):
    """``GET /executions/{id}/telemetry``: a page of the recorded stream as columns (row k of every list is one
    sample); ``next_cursor`` names the next page (also in the ``X-Next-Cursor`` header)."""

    model_config = ConfigDict(extra="forbid")

    every: int = Field(1, description="Decimation: every N-th stored sample is returned.")
    cursor: int = Field(0, description="The stream index this page started from (the request's cursor).")
    next_cursor: int | None = Field(
        None,
        description="Where the next page starts: pass it as cursor (with the same t0, t1 and every) to go on; None "
        "when this page holds the rest of the window.",
    )
    n_samples: int = Field(description="Samples returned (rows of each column).")
    stored_samples: int = Field(description="Samples stored for the execution.")
    status: ExecutionState = Field(description="Execution status when read (the stream grows while running).")


class CommandAccepted(BaseModel):
    """``POST /executions/{id}/abort|pause|resume`` (202): the command was sent to the worker over Zenoh."""

    id: str
    command: CommandName = Field(examples=["abort"])
    sent_to: str = Field(description="Zenoh key expression the command was put on.")


class WorkerSummary(BaseModel):
    """A connected sim worker as ``GET /health`` shows it to anyone (no host name, no process id)."""

    worker_id: str
    busy: bool
    activity: str = Field(
        description="idle, executing, recording, or unknown (it did not answer yet). From the worker's own answer, "
        "``info_age_s`` old, unless the store knows better: a run the store shows ended is not shown."
    )
    execution_id: str | None = Field(None, description="The execution it runs now, if any.")
    executions_run: int = Field(0, description="Executions it accepted since it started (its own count).")
    engine: Engine | None = Field(
        None, description="Its default engine, run by an execution that names none (None: it did not answer yet)."
    )
    info_age_s: Real | None = Field(
        None, description="How old the worker's answer behind busy and activity is, s (None: no answer yet)."
    )
    heard_s_ago: Real | None = Field(
        None,
        description="Seconds since the API last took a report from it (a status, a heartbeat or telemetry that "
        "passed the checks); None: none since the API started.",
    )


class HealthDetail(BaseModel):
    """What ``GET /health`` adds for a client that presents the bearer token."""

    database: str = Field(description="Path of the SQLite database.")
    schema_version: int
    pid: int = Field(description="Process id of the API.")
    workers: list[JsonObject] = Field(description="The sim workers' full WorkerInfo (host names, process ids).")


class Health(BaseModel):
    """``GET /health``: the API is alive; the bus, its workers, the queue and the learners as seen from here.

    Details (database path, process ids, host names) only with the bearer token (``CONTACT_SKILLS_TOKEN``)."""

    status: str = Field("ok", description="Always ok when the API answers.")
    version: str
    started_unix_s: Real = Field(description="When this API process started, Unix s.")
    instance: str = Field(description="A random name of this API process (set by `contact-skills up` for its API).")
    bus_connected: bool = Field(description="Whether the API has a Zenoh session (false: executions get 503).")
    zenoh_endpoints: list[str] = Field(description="The router endpoints the API connects to.")
    workers: list[WorkerSummary] = Field(description="The sim workers connected now.")
    active_executions: int = Field(description="Executions starting or running.")
    queued_executions: int = Field(0, description="Executions waiting for a free worker.")
    learning: dict[str, int] = Field(
        description="The learner processes: processes, running, waiting, completed, timed_out, cancelled, restarted, "
        "rejected."
    )
    foxglove_url: str | None = Field(
        None,
        description="The Foxglove WebSocket server of the live execution (foxglove.websocket.v1, loopback), e.g. "
        "ws://127.0.0.1:8765; None when it is off (CONTACT_SKILLS_FOXGLOVE_PORT=off, or no bus).",
    )
    zenoh_login: dict[str, str] | None = Field(
        None,
        description="The bus's read-only login, ``{'user': 'observer', 'password': …}``, for a Zenoh session that "
        "reads telemetry and statuses (``transport: {auth: {usrpwd: …}}``); it cannot command or report. None on an "
        "open bus, and without the bearer token when reads need it (CONTACT_SKILLS_TOKEN_READS).",
    )
    detail: HealthDetail | None = Field(None, description="Only for a request with the bearer token.")
