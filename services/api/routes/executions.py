"""``/executions``: run a skill on a sim worker over Zenoh, list, get, abort/pause/resume, the recorded telemetry,
delete."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Query, Response

from schemas.api import (
    ApiError,
    CommandAccepted,
    ExecutionCreated,
    ExecutionState,
    ExecutionView,
    TelemetryFormat,
    TelemetryView,
)
from schemas.bus import CommandName, KeyExpressions
from schemas.execution import ExecutionRequest
from services.api import errors
from services.api.deps import (
    EXPORT_RESPONSES,
    NEXT_CURSOR_HEADER,
    READ_GUARD,
    STORING_GUARD,
    TOKEN_GUARD,
    BusDep,
    ClientCapsDep,
    ClientDep,
    Cursor,
    ExportFormat,
    KeysDep,
    Limit,
    Offset,
    PageLimit,
    QueueDep,
    SettingsDep,
    StoreDep,
    TimeWindow,
    check_settings_for_skill,
    need_bus,
    need_queue,
    skill_to_run,
)
from services.api.errors import ERROR_RESPONSES, MUTATING_RESPONSES, READ_RESPONSES, STORING_RESPONSES
from services.api.limits import TOO_MANY, WorkKind
from services.api.responses import LIST_RESPONSES, OpenApiResponses, list_page, streamed
from services.bus import BusClient
from services.queue import ExecutionQueue
from services.store import TERMINAL, ExecutionRow, Store

log = logging.getLogger("contact_skills.api")

router = APIRouter(tags=["executions"], dependencies=READ_GUARD, responses=READ_RESPONSES)

COMMAND_RESPONSES: OpenApiResponses = {
    **ERROR_RESPONSES,
    **MUTATING_RESPONSES,
    409: {"model": ApiError},
    **errors.UNAVAILABLE,
}


def _view(row: ExecutionRow, store: Store, keys: KeyExpressions) -> ExecutionView:
    batches, samples = store.telemetry.counts(row.id)
    position = store.executions.queue_position(row.id) if row.status is ExecutionState.queued else None
    return ExecutionView(
        id=row.id,
        skill_id=row.skill_id,
        worker_id=row.worker_id,
        status=row.status,
        phase=row.phase,
        metrics=row.metrics,
        verdict=row.metrics.verdict.verdict if row.metrics and row.metrics.verdict else None,
        error=row.error,
        created=row.created,
        updated=row.updated,
        telemetry_key=keys.telemetry(row.id),
        telemetry_batches=batches,
        telemetry_samples=samples,
        telemetry_missing_samples=(
            max(0, row.metrics.steps - samples) if row.metrics and row.streams_telemetry else None
        ),
        request=row.request,
        priority=row.priority,
        queue_position=position,
    )


def _found(store: Store, execution_id: str) -> ExecutionRow:
    row = store.executions.get(execution_id)
    if row is None:
        raise errors.not_found("execution", execution_id)
    return row


@router.post(
    "/executions",
    status_code=202,
    response_model=ExecutionCreated,
    responses={**ERROR_RESPONSES, **STORING_RESPONSES, **errors.UNAVAILABLE, **TOO_MANY},
    dependencies=STORING_GUARD,
)
def post_execution(
    request: ExecutionRequest,
    store: StoreDep,
    queue: QueueDep,
    keys: KeysDep,
    settings: SettingsDep,
    caps: ClientCapsDep,
    client: ClientDep,
) -> ExecutionCreated:
    """Run a skill on a sim worker: in the world its demonstration was recorded in (simulator recordings), else on
    a work piece rebuilt from the skill and placed in the robot's reach (``environment.work_piece``,
    ``environment.placement``), changed by the known ``environment.offset`` and the ``environment.unknown_offset``,
    with the controller, gains and pace asked for. 422 when the skill cannot be placed in reach, and when the run
    its settings imply (segments, guarded approaches over their speeds, settle, ramps, the time step) is over the
    job budget (``CONTACT_SKILLS_JOB_MAX_SIMULATED_S``, ``..._STEPS``), naming the settings that make it so.

    Replies 202 at once with the execution id and the Zenoh key of its telemetry; follow it with
    ``GET /executions/{id}`` or a Zenoh subscriber. When every worker is busy it is ``queued`` (with its
    ``queue_position``; ``priority`` orders the queue) and starts as soon as one is free. 503 when no worker is
    connected or the queue is full; 429 when this client has ``CONTACT_SKILLS_CLIENT_QUEUED_MAX`` executions queued
    or running already; 507 when the telemetry its job estimate implies does not fit in the storage quota beside
    what is stored and what the queued and running executions reserve (it is reserved until the run ends)."""
    from services.bus import BusRequestError, NoWorkerAvailable
    from services.queue import Dispatch
    from services.store import QueueFull, QuotaFull

    skill, demonstration_id = skill_to_run(store, request.skill_id, request.skill)  # the queue sends the demo along
    skill_at = ("body", "skill_id" if request.skill_id is not None else "skill")
    check_settings_for_skill(skill, request, settings.job_budget, skill_at=skill_at)
    executions = need_queue(queue)
    caps.admit(WorkKind.execution, client)
    stored = request.model_dump(mode="json", exclude={"skill"})
    stored.update(inline_skill=request.skill is not None)
    wire = request.model_copy(update={"skill": skill, "skill_id": None})
    try:
        row, position = executions.submit(
            Dispatch(wire, {}, demonstration_id), stored, request.skill_id, request.priority
        )
    except (NoWorkerAvailable, QueueFull) as exc:
        raise errors.unavailable(str(exc)) from None
    except QuotaFull as exc:
        raise errors.quota_full(exc) from None
    except BusRequestError as exc:  # the worker refused: an unknown scenario, a skill it cannot place in reach
        raise errors.refused_by_worker(str(exc)) from None
    caps.hold(WorkKind.execution, client, row.id)
    return ExecutionCreated(
        id=row.id,
        status=row.status,
        worker_id=row.worker_id,
        queue_position=position,
        telemetry_key=keys.telemetry(row.id),
        status_key=keys.status(row.id),
    )


@router.get("/executions", response_model=list[ExecutionView], responses=LIST_RESPONSES)
def list_executions(store: StoreDep, keys: KeysDep, limit: Limit = 100, offset: Offset = 0) -> Response:
    """Executions, newest first.

    Each with its status (starting, running, paused, done, aborted, failed), phase, worker, metrics once
    finished and the count of stored telemetry samples; ``limit`` and ``offset`` page through them, a page of at most
    4 MiB naming the next one's offset in ``X-Next-Offset``."""
    return list_page(store.executions.page(limit + 1, offset), lambda row: _view(row, store, keys), offset, limit)


@router.get("/executions/{execution_id}", response_model=ExecutionView, responses=ERROR_RESPONSES)
def get_execution(execution_id: str, store: StoreDep, keys: KeysDep) -> ExecutionView:
    """Status, phase and (once finished) metrics of an execution.

    Poll it until the status is done, aborted or failed (or follow the Zenoh keys it names); the metrics hold the
    CF-z force errors, path error, contact ratio and real-time factor. 404 for an unknown id."""
    return _view(_found(store, execution_id), store, keys)


@router.delete(
    "/executions/{execution_id}",
    status_code=204,
    responses={**ERROR_RESPONSES, **MUTATING_RESPONSES, 409: {"model": ApiError}},
    dependencies=TOKEN_GUARD,
)
def delete_execution(execution_id: str, store: StoreDep) -> Response:
    """Delete a finished execution: its record (request, status, metrics, verdict) and its stored telemetry.

    409 while it is queued or running (abort it first: ``POST /executions/{id}/abort``) and for a sweep's trial (the
    sweep's results are its executions); the skill it ran is kept. 204 when deleted, 404 for an unknown id; needs the
    bearer token when one is set."""
    row = _found(store, execution_id)
    if sweep := row.sweep:
        raise errors.part_of_sweep(execution_id, sweep)
    if not store.executions.delete(execution_id, TERMINAL):
        raise errors.still_active(execution_id, (store.executions.get(execution_id) or row).status.value)
    return Response(status_code=204)


def _command(
    execution_id: str,
    name: CommandName,
    store: Store,
    bus: BusClient | None,
    queue: ExecutionQueue | None,
    keys: KeyExpressions,
) -> CommandAccepted:
    row = _found(store, execution_id)
    if row.status is ExecutionState.queued:  # not on a worker yet: abort cancels it, pause/resume make no sense
        if name is CommandName.abort and need_queue(queue).cancel(execution_id):
            return CommandAccepted(id=execution_id, command=name, sent_to="queue")
        if name is not CommandName.abort:
            raise errors.not_running(execution_id, "queued")
        row = _found(store, execution_id)  # it left the queue meanwhile
    if row.status in TERMINAL:
        raise errors.already_finished(execution_id, row.status.value)
    need_bus(bus).send_command(execution_id, name)
    return CommandAccepted(id=execution_id, command=name, sent_to=keys.cmd(execution_id))


@router.post(
    "/executions/{execution_id}/abort",
    status_code=202,
    response_model=CommandAccepted,
    responses=COMMAND_RESPONSES,
    dependencies=TOKEN_GUARD,
)
def abort_execution(execution_id: str, store: StoreDep, bus: BusDep, queue: QueueDep, keys: KeysDep) -> CommandAccepted:
    """Abort a running execution (a live command over Zenoh; the final status follows), or cancel a queued one
    (status aborted at once, ``sent_to`` "queue").

    202 once the command is put on the bus; the worker stops within one control step and reports ``aborted``.
    409 if the execution has already finished, 503 without a bus."""
    return _command(execution_id, CommandName.abort, store, bus, queue, keys)


@router.post(
    "/executions/{execution_id}/pause",
    status_code=202,
    response_model=CommandAccepted,
    responses=COMMAND_RESPONSES,
    dependencies=TOKEN_GUARD,
)
def pause_execution(execution_id: str, store: StoreDep, bus: BusDep, queue: QueueDep, keys: KeysDep) -> CommandAccepted:
    """Pause a running execution: it holds its current reference (and force) until resumed.

    202 once the command is put on the bus; the status then reads ``paused``. 409 if the execution has already
    finished or is still queued, 503 without a bus."""
    return _command(execution_id, CommandName.pause, store, bus, queue, keys)


@router.post(
    "/executions/{execution_id}/resume",
    status_code=202,
    response_model=CommandAccepted,
    responses=COMMAND_RESPONSES,
    dependencies=TOKEN_GUARD,
)
def resume_execution(
    execution_id: str, store: StoreDep, bus: BusDep, queue: QueueDep, keys: KeysDep
) -> CommandAccepted:
    """Resume a paused execution.

    202 once the command is put on the bus; the execution continues from where it held and its status goes
    back from paused to running. 409 if it has already finished, 503 without a bus."""
    return _command(execution_id, CommandName.resume, store, bus, queue, keys)


@router.get(
    "/executions/{execution_id}/telemetry",
    responses={
        200: {
            "model": TelemetryView,
            **EXPORT_RESPONSES[200],
            "headers": {NEXT_CURSOR_HEADER: {"description": "The next page's cursor (absent on the last page).",
                                             "schema": {"type": "integer"}}},
        },
        **ERROR_RESPONSES,
        409: {"model": ApiError},
    },
)  # fmt: skip
def get_telemetry(
    execution_id: str,
    store: StoreDep,
    settings: SettingsDep,
    every: Annotated[int, Query(ge=1, le=1_000_000, description="Return every N-th sample.")] = 1,
    format: ExportFormat = TelemetryFormat.json,
    window: TimeWindow = (None, None),
    cursor: Cursor = 0,
    limit: PageLimit = None,
) -> Response:
    """A page of the recorded telemetry stream (wrenches, poses, references, phases): JSON columns, CSV or MCAP.

    ``t0``/``t1`` (s of the execution's time) cut a window, ``every`` decimates; MCAP holds ROS 2 messages (poses,
    wrenches in world and CF, desired force, phases, /tf) stamped from the execution's creation time. One reply holds
    at most ``CONTACT_SKILLS_TELEMETRY_PAGE_SAMPLES`` samples (20 000 by default; ``limit`` asks for fewer), streamed:
    a longer window goes on from ``cursor`` = the ``next_cursor`` of the JSON body, or the ``X-Next-Cursor`` header
    (absent on the last page). 409 for an execution run with ``telemetry`` ``none`` (e.g. a sweep's trial): it never
    had a stream."""
    from services.telemetry_export import (
        CSV_MEDIA_TYPE,
        MCAP_MEDIA_TYPE,
        execution_csv_chunks,
        execution_json_chunks,
        execution_mcap,
        telemetry_page,
    )

    row = _found(store, execution_id)
    if not row.streams_telemetry:
        raise errors.no_telemetry(execution_id, row.sweep)
    t0, t1 = window
    size = min(limit or settings.telemetry_page_samples, settings.telemetry_page_samples)
    page = telemetry_page(store.telemetry.blocks(execution_id, cursor), cursor, every, t0, t1, size)
    headers = {} if page.next_cursor is None else {NEXT_CURSOR_HEADER: str(page.next_cursor)}
    if format is TelemetryFormat.csv:
        return streamed(execution_csv_chunks(page.rows), CSV_MEDIA_TYPE, f"{execution_id}.csv", headers)
    if format is TelemetryFormat.mcap:
        mcap = execution_mcap(page.rows, row.created, execution_id).data  # a page: at most the cap
        return streamed([mcap], MCAP_MEDIA_TYPE, f"{execution_id}.mcap", headers)
    head = {"execution_id": execution_id, "every": every, "cursor": cursor, "next_cursor": page.next_cursor,
            "n_samples": int(page.rows.shape[0]), "stored_samples": store.telemetry.counts(execution_id)[1],
            "status": row.status.value}  # fmt: skip
    return streamed(execution_json_chunks(head, page.rows), "application/json", headers=headers)
