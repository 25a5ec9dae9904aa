"""``/demonstrations``: store one (JSON, a CSV or ROS bag upload, or recorded by a sim worker's scripted teacher), list,
get, delete."""

from __future__ import annotations

import json
from typing import Annotated

from fastapi import APIRouter, File, Form, Response, UploadFile
from pydantic import JsonValue, TypeAdapter, ValidationError

from schemas.api import (
    ApiError,
    DemonstrationCreated,
    DemonstrationInfo,
    StoredDemonstration,
    TelemetryFormat,
)
from schemas.bus import RecordRequest
from schemas.demonstration import Demonstration, DemonstrationArrays
from schemas.import_options import PLAUSIBLE_READINGS, BagImportOptions, CsvImportOptions
from schemas.text import Name
from services.api import errors
from services.api.deps import (
    EXPORT_RESPONSES,
    NEXT_CURSOR_HEADER,
    READ_GUARD,
    STORING_GUARD,
    TOKEN_GUARD,
    BusDep,
    ExportFormat,
    Limit,
    Offset,
    QueueDep,
    SampleCursor,
    SampleLimit,
    StoreDep,
    TimeWindow,
    need_bus,
)
from services.api.errors import ERROR_RESPONSES, MUTATING_RESPONSES, READ_RESPONSES, STORING_RESPONSES
from services.api.limits import UPLOAD_STORED_MULTIPLE
from services.api.responses import (
    LIST_RESPONSES,
    SAMPLE_CHUNK_ROWS,
    download,
    list_page,
    samples_json_chunks,
    samples_that_fit,
    streamed,
)
from services.demonstration_files import (
    BAGS,
    HEAD_BYTES,
    DemonstrationFile,
    file_kind,
    other_kind,
    unsupported_file,
)
from services.store import DemonstrationRow, Store
from services.store.demonstrations import StoredTooLarge
from services.store.rows import SAMPLE_ARRAYS, DemonstrationSamples

UPLOAD_NAME: TypeAdapter[str] = TypeAdapter(Name)
"""An upload's file name, a name like any other (it becomes the demonstration's name and source)."""
RECORD_TIMEOUT_S = 120.0
"""How long ``POST /demonstrations/record`` waits for the worker's recording, s."""

router = APIRouter(tags=["demonstrations"], dependencies=READ_GUARD, responses=READ_RESPONSES)


def _created(row: DemonstrationRow, notes: list[str] | None = None, extra: dict | None = None) -> DemonstrationCreated:
    return DemonstrationCreated(
        id=row.id,
        created=row.created,
        source=row.source,
        summary=row.summary,
        import_notes=notes or [],
        extra=extra or {},
    )


def _upload(
    file: UploadFile, accepted: frozenset[DemonstrationFile], wanted: str
) -> tuple[bytes, str, DemonstrationFile]:
    """The uploaded bytes, the file's name and what it holds (told once, by its content, and passed on to the
    importer); a 422 on ``file`` when its content is none of ``accepted``: the one message for a file no importer
    reads, or which route takes the kind it is (``wanted``: what this one takes)."""
    try:  # the file's name becomes the demonstration's name and source: bounded as a name is
        name = UPLOAD_NAME.validate_python(file.filename or "upload").rsplit("/", 1)[-1]
    except ValidationError as exc:
        raise errors.unprocessable(["body", "file"], f"its file name: {exc.errors()[0]['msg']}", "file_name") from None
    data = file.file.read()
    kind = file_kind(name, data[:HEAD_BYTES])
    if kind is None:
        raise errors.unprocessable(["body", "file"], unsupported_file(name), "unsupported_file")
    if kind not in accepted:
        raise errors.unprocessable(["body", "file"], other_kind(name, kind, wanted), "unsupported_file")
    return data, name, kind


def _store_upload(store: Store, demonstration: Demonstration, uploaded_bytes: int) -> DemonstrationRow:
    """Store an imported upload; a 422 on ``file`` when it would take more than :data:`UPLOAD_STORED_MULTIPLE`
    times the bytes uploaded."""
    multiple = UPLOAD_STORED_MULTIPLE
    try:
        return store.demonstrations.add(demonstration, max_bytes=int(multiple * uploaded_bytes))
    except StoredTooLarge as exc:
        raise errors.stored_too_large(["body", "file"], exc.stored_bytes, uploaded_bytes, multiple) from None


def _notes(demonstration: Demonstration) -> list[str]:
    """What the importer did (``metadata.extra.import_notes``)."""
    return list(demonstration.metadata.extra.get("import_notes", []))


def _advice(demonstration: Demonstration) -> dict[str, JsonValue]:
    """An upload answer's ``extra``: the readings the import note advises as import options (the form's names and
    values, ``plausible_readings``), when it advises any."""
    readings = demonstration.metadata.extra.get(PLAUSIBLE_READINGS) or []
    return {PLAUSIBLE_READINGS: readings} if readings else {}


@router.post(
    "/demonstrations",
    status_code=201,
    response_model=DemonstrationCreated,
    responses=STORING_RESPONSES,
    dependencies=STORING_GUARD,
)
def post_demonstration(demonstration: Demonstration, store: StoreDep) -> DemonstrationCreated:
    """Store a demonstration given as JSON (a `Demonstration`; CSV: ``POST /demonstrations/csv``).

    The samples must already follow the conventions (SI, quaternions [x, y, z, w], the wrench the tool applies in
    the world frame at the tool point); a field that does not is a 422 naming it. 201 with the id and summary."""
    return _created(store.demonstrations.add(demonstration))


@router.post(
    "/demonstrations/csv",
    status_code=201,
    response_model=DemonstrationCreated,
    responses=STORING_RESPONSES,
    dependencies=STORING_GUARD,
)
def post_demonstration_csv(
    store: StoreDep,
    file: Annotated[UploadFile, File(description="The CSV recording (header row + samples, SI units).")],
    options: Annotated[CsvImportOptions, Form()],
) -> DemonstrationCreated:
    """Import a CSV recording with the options of ``contact-skills learn`` (multipart form) and store it.

    Columns are found by their names (or ``columns``), quaternions reordered, event-driven logs resampled, the
    wrench turned into the one the tool applies in the world, the sensor offset removed; ``import_notes`` says what
    was done. A problem is a 422 naming the form field and, for the file, the column and line."""
    from services.csv_import import CsvImportError, demonstration_from_csv

    data, name, _ = _upload(file, frozenset({DemonstrationFile.csv}), "a CSV recording")
    try:
        demonstration = demonstration_from_csv(
            data, options.model_copy(update={"name": options.name or name.removesuffix(".csv")})
        )
    except CsvImportError as exc:
        raise errors.csv_import_failed(exc) from None
    if file.filename:
        demonstration.metadata.source = f"csv:{file.filename}"
    stored = _store_upload(store, demonstration, len(data))
    return _created(stored, notes=_notes(demonstration), extra=_advice(demonstration))


@router.post(
    "/demonstrations/bag",
    status_code=201,
    response_model=DemonstrationCreated,
    responses=STORING_RESPONSES,
    dependencies=STORING_GUARD,
)
def post_demonstration_bag(
    store: StoreDep,
    file: Annotated[
        UploadFile,
        File(description="A ROS 2 bag's storage file (the .mcap or .db3 inside its directory) or a ROS 1 .bag."),
    ],
    options: Annotated[BagImportOptions, Form()],
) -> DemonstrationCreated:
    """Import a ROS 1 or ROS 2 bag (a WrenchStamped topic and the tool pose as a PoseStamped topic or /tf) and store it.

    Topics are chosen automatically when the bag holds one candidate, else named by the form fields; header stamps
    and frames are honoured, the asynchronous topics aligned on one time base (as ``contact-skills learn BAG``)."""
    from services.bag_import import BagImportError, demonstration_from_bag_upload

    data, name, kind = _upload(file, BAGS, "a ROS bag")
    try:
        demonstration = demonstration_from_bag_upload(data, name, options, kind)
    except BagImportError as exc:
        raise errors.import_failed(exc) from None
    stored = _store_upload(store, demonstration, len(data))
    return _created(stored, notes=_notes(demonstration), extra=_advice(demonstration))


@router.post(
    "/demonstrations/record",
    status_code=201,
    response_model=DemonstrationCreated,
    responses={**STORING_RESPONSES, **errors.UNAVAILABLE, 504: {"model": ApiError}},
    dependencies=STORING_GUARD,
)
def record_demonstration(request: RecordRequest, store: StoreDep, bus: BusDep) -> DemonstrationCreated:
    """Ask a sim worker to record the scripted teacher's demonstration of a scenario, and store it.

    The teacher's ground truth is returned in ``extra.ground_truth`` and kept in the demonstration's
    metadata (``metadata.extra.ground_truth``). The worker refuses at once (422 naming the override) a recording
    over the job budget (``CONTACT_SKILLS_JOB_MAX_SIMULATED_S``, ``..._STEPS``) or longer than a demonstration may
    be (200 000 samples: one per step of ``overrides.time_step_s``)."""
    from services.bus import NoWorkerAvailable

    client = need_bus(bus)
    try:
        reply = client.record_demonstration(request, timeout_s=RECORD_TIMEOUT_S)
    except NoWorkerAvailable as exc:
        raise errors.unavailable(f"no sim worker available to record: {exc}") from None
    except TimeoutError as exc:
        raise errors.recording_timed_out(exc) from None
    if reply.code == "busy":
        raise errors.unavailable(f"every sim worker is busy: {reply.error or 'try again later'}")
    if not reply.ok or reply.demonstration is None:
        raise errors.refused_by_worker(reply.error or "the worker recorded nothing")
    demonstration = reply.demonstration
    demonstration.metadata.extra.setdefault("scenario", request.scenario)
    demonstration.metadata.extra["record_request"] = request.model_dump(mode="json")
    if reply.ground_truth is not None:
        demonstration.metadata.extra["ground_truth"] = reply.ground_truth
    row = store.demonstrations.add(demonstration)
    return _created(row, extra={"ground_truth": reply.ground_truth, "worker_id": reply.worker_id})


@router.get("/demonstrations", response_model=list[DemonstrationInfo], responses=LIST_RESPONSES)
def list_demonstrations(store: StoreDep, limit: Limit = 100, offset: Offset = 0) -> Response:
    """Stored demonstrations, newest first (summaries, no samples).

    Each row: id, name, source (json, csv:FILE, bag:FILE, teacher:SCENARIO), creation time and the summary
    (samples, duration, rate, largest force); ``limit`` and ``offset`` page through them, a page of at most 4 MiB
    naming the next one's offset in ``X-Next-Offset``. A demonstration stored under looser rules that cannot be
    read back is listed with its ``problem`` (and no summary); a name or source stored longer than a name may be
    now is listed cut, ending in "…"."""
    return list_page(store.demonstrations.page(limit + 1, offset), _info, offset, limit)


def _info(r: DemonstrationRow) -> DemonstrationInfo:
    return DemonstrationInfo(
        id=r.id, created=r.created, name=r.name, source=r.source, summary=r.summary, problem=r.problem
    )


def readable_samples(store: Store, demonstration_id: str) -> tuple[DemonstrationRow, DemonstrationSamples]:
    """The stored demonstration's row and samples: 404 for an unknown id, 409 for one stored under looser rules that
    cannot be read back. Parsed one recording at a time, and kept (``DemonstrationRepository.samples``)."""
    row = store.demonstrations.row(demonstration_id)
    samples = (
        None if row is None else store.demonstrations.samples(demonstration_id) if row.problem is None else row.problem
    )
    if row is None or samples is None:
        raise errors.not_found("demonstration", demonstration_id)
    if isinstance(samples, str):
        raise errors.unreadable(demonstration_id, samples)
    return row, samples


@router.get(
    "/demonstrations/{demonstration_id}",
    responses={
        200: {"model": StoredDemonstration, "headers": {NEXT_CURSOR_HEADER: {
            "description": "The next page's cursor (absent on the last page).", "schema": {"type": "integer"}}}},
        **ERROR_RESPONSES,
        409: {"model": ApiError},
    },
)  # fmt: skip
def get_demonstration(
    demonstration_id: str, store: StoreDep, cursor: SampleCursor = None, limit: SampleLimit = None
) -> Response:
    """A stored demonstration with its samples, whole or a page of them.

    Time, tool positions and orientations ([x, y, z, w]) and the wrench the tool applied (world frame, at the tool
    point), with the import metadata (conventions of the file, resampling, tare, notes). One reply holds at most
    8 MiB (~23 000 samples): ``cursor`` (and ``limit``) page the samples, a page that is not the last naming the
    next one's cursor in ``next_cursor`` and the ``X-Next-Cursor`` header; asked whole (neither given) a
    demonstration that does not fit is a 422 on ``limit`` saying how to page. 404 for an unknown id, 409 for one
    stored under looser rules that cannot be read back (delete it)."""
    row, samples = readable_samples(store, demonstration_id)
    assert row.summary is not None  # a readable row has its summary
    head: dict[str, JsonValue] = {"id": row.id, "created": row.created, "summary": row.summary.model_dump(mode="json")}
    fit = samples_that_fit(len(json.dumps(head)) + len(samples.metadata.encode()) + 200)  # 200: keys, brackets
    if cursor is None and limit is None and samples.n_samples > fit:
        raise errors.samples_over_budget(demonstration_id, samples.n_samples, fit)
    start = min(cursor or 0, samples.n_samples)
    stop = min(samples.n_samples, start + min(limit or fit, fit))
    next_cursor = stop if stop < samples.n_samples else None
    window = {name: getattr(samples, name)[start:stop] for name in SAMPLE_ARRAYS}
    chunks = samples_json_chunks(
        {**head, "cursor": start, "next_cursor": next_cursor}, "demonstration", window, {"metadata": samples.metadata}
    )
    headers = {} if next_cursor is None else {NEXT_CURSOR_HEADER: str(next_cursor)}
    return streamed(chunks, "application/json", headers=headers)


@router.delete(
    "/demonstrations/{demonstration_id}",
    status_code=204,
    responses={**ERROR_RESPONSES, **MUTATING_RESPONSES},
    dependencies=TOKEN_GUARD,
)
def delete_demonstration(demonstration_id: str, store: StoreDep, queue: QueueDep) -> Response:
    """Delete a stored demonstration: its samples, metadata and ground truth (one that cannot be read back too).

    Skills learned from it keep their parameters and still run; their executions from now on get no path metric
    (it compares the run with the demonstration). 204 when deleted, 404 for an unknown id; needs the bearer token
    when one is set."""
    if not store.demonstrations.delete(demonstration_id):
        raise errors.not_found("demonstration", demonstration_id)
    if queue is not None:
        queue.forget_demonstration(demonstration_id)
    return Response(status_code=204)


@router.get(
    "/demonstrations/{demonstration_id}/telemetry",
    responses={**EXPORT_RESPONSES, **ERROR_RESPONSES, 409: {"model": ApiError}},
)
def get_demonstration_telemetry(
    demonstration_id: str,
    store: StoreDep,
    format: ExportFormat = TelemetryFormat.json,
    window: TimeWindow = (None, None),
) -> Response:
    """A stored demonstration's samples to save or plot: JSON columns, CSV (as the importer reads it) or MCAP.

    ``t0``/``t1`` (s) cut a window; MCAP holds the tool pose, the applied wrench and /tf as ROS 2 messages, a bag
    that ``contact-skills learn`` reads back. 409 for a demonstration stored under looser rules that cannot be read
    back."""
    from services.csv_import import samples_csv_text
    from services.telemetry_export import CSV_MEDIA_TYPE, MCAP_MEDIA_TYPE, demonstration_mcap, window_mask

    row, samples = readable_samples(store, demonstration_id)
    keep = window_mask(samples.t, *window)
    a = DemonstrationArrays(**{name: getattr(samples, name)[keep] for name in SAMPLE_ARRAYS})
    if format is TelemetryFormat.csv:
        rows = range(0, a.t.size, SAMPLE_CHUNK_ROWS)
        chunks = (samples_csv_text(*(getattr(a, name)[k : k + SAMPLE_CHUNK_ROWS] for name in SAMPLE_ARRAYS),
                                   header=k == 0) for k in rows)  # fmt: skip
        return streamed(chunks, CSV_MEDIA_TYPE, f"{demonstration_id}.csv")
    if format is TelemetryFormat.mcap:
        name = json.loads(samples.metadata).get("name", "")
        mcap = demonstration_mcap(a, name, row.created).data
        return download(mcap, MCAP_MEDIA_TYPE, f"{demonstration_id}.mcap")
    head = {"demonstration_id": demonstration_id, "n_samples": int(a.t.size)}
    return streamed(
        samples_json_chunks(head, None, {name: getattr(a, name) for name in SAMPLE_ARRAYS}, {}), "application/json"
    )
