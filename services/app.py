"""The REST service (DESIGN.md "Interfaces"): FastAPI routes over the SQLite store and the Zenoh bus client.

``create_app(settings, bus)`` builds the app. Route functions are thin: they validate (the pydantic
models of ``schemas/``), call the store, the science (``skills.parameterize.learn_skill``, in the
thread pool) or the bus, and shape the reply. The bus callbacks (:class:`BusEvents`) write status,
metrics and telemetry into the same store from Zenoh threads.

Errors (the ``detail`` of every error body says what and why):

- 422: any bad body or parameter — pydantic's errors, plus `LearningError` and `CsvImportError`
  with ``loc`` naming the field (``["body", "demonstration", "wrenches"]``, ``["body", "file"]``);
  error entries never echo large inputs back.
- 404: unknown id. 409: a command to a finished execution. 401: missing/wrong bearer token on
  POST/DELETE when ``CONTACT_SKILLS_TOKEN`` is set. 413: body over the limit (checked from
  ``Content-Length`` before reading; a chunked body is cut off at the limit).
- 503: no Zenoh bus or no sim worker connected; 504: a recording timed out.
- 500 only for a bug: logged with its traceback, answered with a short JSON body.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import threading
import time
from collections.abc import Callable
from contextlib import asynccontextmanager
from importlib import metadata
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
from fastapi import Depends, FastAPI, File, Form, HTTPException, Query, Request, Response, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from schemas.api import (
    ApiError,
    CommandAccepted,
    DemonstrationCreated,
    DemonstrationInfo,
    ExecutionCreated,
    ExecutionState,
    ExecutionView,
    Health,
    SkillInfo,
    SkillRequest,
    StoredDemonstration,
    StoredSkill,
    TelemetryView,
)
from schemas.bus import ExecutionStatus, KeyExpressions, RecordRequest
from schemas.demonstration import Demonstration, QuaternionOrder, WrenchConvention, WrenchFrame
from schemas.execution import ExecutionPhase, ExecutionRequest, TelemetryBatch
from services.settings import ServiceSettings
from services.store import RESTART_REASON, TERMINAL, ExecutionRow, Store, telemetry_columns

if TYPE_CHECKING:
    from services.bus import BusClient

log = logging.getLogger("contact_skills.api")

FINAL_STATES = {
    ExecutionPhase.done: ExecutionState.done,
    ExecutionPhase.aborted: ExecutionState.aborted,
    ExecutionPhase.failed: ExecutionState.failed,
}
"""Execution status for each final phase; any other phase means running."""
WORKER_DISCOVERY_S = 2.0
"""On start, how long the API waits to see workers before reconciling executions left running."""
MAX_ECHOED_INPUT = 200
"""A validation error echoes the offending input only if its JSON is at most this many characters."""
RECORD_TIMEOUT_S = 120.0


def _version() -> str:
    try:
        return metadata.version("contact-skills")
    except metadata.PackageNotFoundError:
        return "0+unknown"


# --------------------------------------------------------------------------- errors


def unprocessable(loc: list[str | int], message: str, kind: str = "value_error") -> RequestValidationError:
    """A 422 in FastAPI's shape: ``{"detail": [{"loc": loc, "msg": message, "type": kind}]}``."""
    return RequestValidationError([{"loc": tuple(loc), "msg": message, "type": kind}])


def not_found(kind: str, ident: str) -> HTTPException:
    return HTTPException(404, f"no {kind} with id {ident!r}")


_NAMES_A_FIELD = re.compile(r"^(?:Value error, )?(\w+) has ")


def _tidy_error(error: dict[str, Any]) -> dict[str, Any]:
    """An error entry without large inputs; a model-level error whose message starts with a field name gets it
    appended to ``loc`` (``positions has 4 samples but t has 5`` -> ``[..., "positions"]``)."""
    loc = list(error.get("loc", ()))
    msg = str(error.get("msg", ""))
    match = _NAMES_A_FIELD.match(msg)
    if match and (not loc or loc[-1] != match[1]) and error.get("type") == "value_error":
        loc.append(match[1])
    tidy: dict[str, Any] = {
        "loc": loc,
        "msg": msg.removeprefix("Value error, "),
        "type": error.get("type", "value_error"),
    }
    if "input" in error:
        try:  # strictly JSON: the echo of a NaN is its text (a JSONResponse refuses NaN)
            text = json.dumps(error["input"], allow_nan=False, default=str)
            echo: Any = json.loads(text)
        except ValueError:
            text = json.dumps(error["input"], default=str)
            echo = text
        if len(text) <= MAX_ECHOED_INPUT:
            tidy["input"] = echo
    ctx = error.get("ctx")
    if isinstance(ctx, dict) and set(ctx) - {"error"}:  # limits like {"gt": 0}; an exception is already in msg
        tidy["ctx"] = {
            k: v if isinstance(v, int | float | str | bool) else str(v) for k, v in ctx.items() if k != "error"
        }
    return tidy


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    return JSONResponse(status_code=422, content={"detail": [_tidy_error(dict(e)) for e in exc.errors()]})


async def _unexpected_error(request: Request, exc: Exception) -> JSONResponse:
    log.exception("bug: %s %s raised %s", request.method, request.url.path, type(exc).__name__)
    return JSONResponse(
        status_code=500, content={"detail": f"internal error ({type(exc).__name__}); it is logged by the API"}
    )


# --------------------------------------------------------------------------- body size limit


class BodyTooLarge(HTTPException):
    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than the limit of {limit} bytes (CONTACT_SKILLS_MAX_BODY_MB)")


class BodyLimit:
    """ASGI middleware: 413 for a body over ``limit`` bytes — from ``Content-Length`` before reading anything,
    or as soon as a chunked body passes the limit."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        length = headers.get(b"content-length")
        if length is not None:
            try:
                declared = int(length)
            except ValueError:
                declared = -1
            if declared < 0:
                await JSONResponse({"detail": "invalid Content-Length"}, status_code=400)(scope, receive, send)
                return
            if declared > self.limit:
                await self._reply_413(scope, receive, send)
                return
        received = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise BodyTooLarge(self.limit)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except BodyTooLarge:
            if not started:
                await self._reply_413(scope, receive, send)

    async def _reply_413(self, scope: Scope, receive: Receive, send: Send) -> None:
        exc = BodyTooLarge(self.limit)
        response = JSONResponse({"detail": exc.detail}, status_code=413, headers={"Connection": "close"})
        await response(scope, receive, send)


# --------------------------------------------------------------------------- bus callbacks


def _guarded(fn: Callable[..., None]) -> Callable[..., None]:
    """A bus callback never raises into the Zenoh thread: errors are logged."""

    def call(*args: Any) -> None:
        try:
            fn(*args)
        except Exception:
            log.exception("bus callback %s failed", fn.__name__)

    call.__name__ = fn.__name__
    return call


FINAL_TELEMETRY_GRACE_S = 2.0
"""How long a final status waits for the last telemetry batches (another Zenoh key, no order between them), s."""


class BusEvents:
    """The callbacks given to the `BusClient`: status, telemetry and lost workers go into the store.

    Status and telemetry travel on different keys, so the final status can overtake the last
    telemetry batches. A final status is therefore stored once the telemetry it counts
    (``metrics.steps``) is stored, or after :data:`FINAL_TELEMETRY_GRACE_S`: a client that sees
    ``done`` can read the whole stream.
    """

    def __init__(self, store: Store) -> None:
        self.store = store
        self.on_status = _guarded(self._status)
        self.on_telemetry = _guarded(self._telemetry)
        self.on_worker_lost = _guarded(self._worker_lost)
        self._held: dict[str, ExecutionStatus] = {}
        self._lock = threading.Lock()

    def _status(self, status: ExecutionStatus) -> None:
        state = FINAL_STATES.get(status.phase, ExecutionState.running)
        if state is not ExecutionState.running and not self._telemetry_complete(status):
            with self._lock:
                self._held[status.execution_id] = status
            self.store.update_execution(status.execution_id, phase=status.phase, worker_id=status.worker_id)
            timer = threading.Timer(FINAL_TELEMETRY_GRACE_S, self._release, args=(status.execution_id,))
            timer.daemon = True
            timer.start()
            return
        self._store_status(status, state)

    def _store_status(self, status: ExecutionStatus, state: ExecutionState) -> None:
        error = status.error
        if error is None and status.metrics is not None and status.metrics.abort_reason:
            error = status.metrics.abort_reason
        self.store.update_execution(
            status.execution_id,
            status=state,
            phase=status.phase,
            worker_id=status.worker_id,
            metrics=status.metrics.model_dump(mode="json") if status.metrics is not None else None,
            error=error,
        )

    def _telemetry_complete(self, status: ExecutionStatus) -> bool:
        if status.metrics is None:
            return True
        return self.store.telemetry_counts(status.execution_id)[1] >= status.metrics.steps

    def _release(self, execution_id: str) -> None:
        with self._lock:
            status = self._held.pop(execution_id, None)
        if status is not None:
            self._store_status(status, FINAL_STATES[status.phase])

    def _telemetry(self, batch: TelemetryBatch) -> None:
        if batch.execution_id and len(batch.t):
            self.store.add_telemetry(batch.execution_id, batch)
            with self._lock:
                held = self._held.get(batch.execution_id)
            if held is not None and self._telemetry_complete(held):
                self._release(batch.execution_id)

    def _worker_lost(self, worker_id: str) -> None:
        marked = self.store.fail_active(f"worker {worker_id} was lost while running (process gone)", worker_id)
        if marked:
            log.warning("worker %s lost: executions %s marked failed", worker_id, ", ".join(marked))


def reconcile(store: Store, bus: BusClient | None, wait_s: float = WORKER_DISCOVERY_S) -> list[str]:
    """Executions left starting/running by a previous API process: keep those a live worker reports running
    (``WorkerInfo.execution_id``; their statuses keep arriving), mark the rest failed (:data:`RESTART_REASON`).
    Returns the ids marked failed."""
    active = store.active_executions()
    if not active:
        return []
    running: set[str] = set()
    if bus is not None:
        wanted = {row.worker_id for row in active if row.worker_id}
        deadline = time.monotonic() + wait_s
        while True:
            infos = bus.workers()
            seen = {info.worker_id for info in infos}
            running = {info.execution_id for info in infos if info.execution_id}
            if wanted <= seen or time.monotonic() >= deadline:
                break
            time.sleep(0.1)
    marked = []
    for row in active:
        if row.id not in running and store.update_execution(
            row.id, status=ExecutionState.failed, phase=ExecutionPhase.failed, error=RESTART_REASON
        ):
            marked.append(row.id)
    if marked:
        log.warning("%d executions left running by a previous API process marked failed", len(marked))
    return marked


# --------------------------------------------------------------------------- the app


def _raw_json(parts: dict[str, Any], raw: dict[str, str], status_code: int = 200) -> Response:
    """A JSON object from JSON-able ``parts`` and already-serialized ``raw`` members (no re-encoding)."""
    members = [f"{json.dumps(k)}:{json.dumps(v)}" for k, v in parts.items()]
    members += [f"{json.dumps(k)}:{v}" for k, v in raw.items()]
    return Response("{" + ",".join(members) + "}", status_code=status_code, media_type="application/json")


def _scenario_of(demonstration: Demonstration | None) -> str | None:
    """The teacher scenario a demonstration was recorded in (``teacher:<scenario>``), if any."""
    if demonstration is None:
        return None
    scenario = demonstration.metadata.extra.get("scenario")
    if isinstance(scenario, str):
        return scenario
    source = demonstration.metadata.source
    return source.split(":", 1)[1] if source.startswith("teacher:") else None


BEARER = HTTPBearer(auto_error=False, description="Set CONTACT_SKILLS_TOKEN on the server to require it.")
"""Optional bearer token of the mutating endpoints (module level: route annotations are resolved in globals)."""


MAX_RATE_HZ = 100_000.0
"""Highest sampling rate the service learns from (as the CSV importer's resampling limit), Hz."""
MAX_GRID_SAMPLES = 1_000_000
"""Most samples a demonstration may span on its uniform grid (duration / median step): 16.7 min at 1 kHz."""


def _numbers(text: str | None, field: str, count: tuple[int, ...]) -> tuple[float, ...] | None:
    """Parse a comma-separated form field of numbers; a 422 naming ``field`` when it is not ``count`` numbers."""
    if text is None or not text.strip():
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in count:
        wanted = " or ".join(str(n) for n in count)
        raise RequestValidationError(
            [
                {
                    "loc": ("body", field),
                    "msg": f"{wanted} comma-separated numbers are needed, got {text!r}",
                    "type": "value_error",
                }
            ]
        )
    return values


def _csv_problem_field(problems: list[str]) -> str:
    """The form field a CSV import problem is about: ``columns``, ``rate``/``dt`` (their values), else ``file``."""
    for prefix, field in (
        ("--columns", "columns"),
        ("rate and dt", "rate"),
        ("rate:", "rate"),
        ("dt:", "dt"),
        ("tare window", "tare_window"),
        ("force offset", "force_offset"),
        ("tare:", "tare_window"),
    ):
        if any(problem.startswith(prefix) for problem in problems):
            return field
    return "file"


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


def _taught_world(demonstration: Demonstration | None) -> dict[str, Any]:
    """The world a recorded demonstration was taught in (the teacher's ``ground_truth.world_config``), else {}."""
    if demonstration is None:
        return {}
    truth = demonstration.metadata.extra.get("ground_truth")
    world = truth.get("world_config") if isinstance(truth, dict) else None
    return dict(world) if isinstance(world, dict) else {}


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {404: {"model": ApiError}}
MUTATING_RESPONSES: dict[int | str, dict[str, Any]] = {401: {"model": ApiError}, 413: {"model": ApiError}}


def create_app(settings: ServiceSettings, bus: BusClient | None = None, store: Store | None = None) -> FastAPI:
    """The FastAPI app. ``bus``: a connected `services.bus.BusClient` whose callbacks are a :class:`BusEvents`
    on the same store (see :func:`connect_bus`), or None (executions and recordings then get 503).
    ``store``: the open store; default: opened from ``settings.db_path`` and closed with the app."""
    own_store = store is None
    store = store if store is not None else Store(settings.db_path)
    keys = KeyExpressions(settings.zenoh_prefix)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        from starlette.concurrency import run_in_threadpool

        await run_in_threadpool(reconcile, store, bus)
        yield
        if own_store:
            store.close()

    app = FastAPI(
        title="Contact Skills",
        version=_version(),
        description="Learn robot contact skills (slide, contour) from one demonstration and execute them with a "
        "hybrid impedance/force controller in a PyBullet simulation. Telemetry streams over Zenoh.",
        lifespan=lifespan,
    )
    app.state.store = store
    app.state.bus = bus
    app.state.settings = settings
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(Exception, _unexpected_error)

    def require_token(credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(BEARER)]) -> None:
        if settings.token is None:
            return
        if credentials is None or not secrets.compare_digest(credentials.credentials.encode(), settings.token.encode()):
            raise HTTPException(
                401, "missing or wrong bearer token (Authorization: Bearer <token>)", {"WWW-Authenticate": "Bearer"}
            )

    guarded = [Depends(require_token)]

    def need_bus() -> BusClient:
        if bus is None:
            raise HTTPException(503, "no Zenoh bus: start the API connected to a router (contact-skills up / api)")
        return bus

    # ------------------------------------------------------------------ health

    @app.get("/health", response_model=Health, tags=["service"])
    def health() -> Health:
        """Liveness, and the sim workers connected over Zenoh."""
        workers = [info.model_dump(mode="json") for info in bus.workers()] if bus is not None else []
        return Health(
            version=app.version,
            bus_connected=bus is not None,
            zenoh_endpoints=settings.zenoh_endpoints,
            workers=workers,
            database=str(store.path),
            schema_version=store.schema_version(),
            active_executions=len(store.active_executions()),
            pid=os.getpid(),
        )

    # ------------------------------------------------------------------ demonstrations

    def created(row, notes: list[str] | None = None, extra: dict | None = None) -> DemonstrationCreated:
        return DemonstrationCreated(
            id=row.id,
            created=row.created,
            source=row.source,
            summary=row.summary,
            import_notes=notes or [],
            extra=extra or {},
        )

    @app.post(
        "/demonstrations",
        status_code=201,
        response_model=DemonstrationCreated,
        responses=MUTATING_RESPONSES,
        dependencies=guarded,
        tags=["demonstrations"],
    )
    def post_demonstration(demonstration: Demonstration) -> DemonstrationCreated:
        """Store a demonstration given as JSON (a `Demonstration`; CSV: ``POST /demonstrations/csv``)."""
        return created(store.add_demonstration(demonstration))

    @app.post(
        "/demonstrations/csv",
        status_code=201,
        response_model=DemonstrationCreated,
        responses=MUTATING_RESPONSES,
        dependencies=guarded,
        tags=["demonstrations"],
    )
    def post_demonstration_csv(
        file: Annotated[UploadFile, File(description="The CSV recording (header row + samples, SI units).")],
        columns: Annotated[
            str | None, Form(description="Column names, e.g. t=time,px=tcp_x,qw=tcp_qw,fz=Fz (as --columns).")
        ] = None,
        quaternion_order: Annotated[
            QuaternionOrder | None, Form(description="Order of the quaternion columns (default: from their names).")
        ] = None,
        wrench: Annotated[
            WrenchConvention, Form(description="measured-on-tool (a sensor's reaction) is negated.")
        ] = WrenchConvention.applied_by_tool,
        wrench_frame: Annotated[WrenchFrame, Form(description="Frame of the recorded wrench.")] = WrenchFrame.world,
        rate: Annotated[
            float | None,
            Form(
                gt=0,
                le=MAX_RATE_HZ,
                description="With a time column: the resampling rate, Hz (default: the data's own). Without one: "
                "the rate the rows were sampled at (t = row / rate from 0); rate or dt is then required.",
            ),
        ] = None,
        dt: Annotated[
            float | None,
            Form(
                ge=1.0 / MAX_RATE_HZ,
                description="Time step, s: the same as rate = 1/dt (e.g. the fixed step of a file without a time "
                "column); may be given with rate only if they agree.",
            ),
        ] = None,
        tare: Annotated[
            bool,
            Form(description="Remove the sensor offset, fitted in the sensor frame over the free-space stretches."),
        ] = True,
        tare_window: Annotated[
            str | None,
            Form(description="'T0,T1' (s): the offset is the median of the file's wrench there (as --tare-window)."),
        ] = None,
        force_offset: Annotated[
            str | None,
            Form(description="'FX,FY,FZ[,MX,MY,MZ]': subtract this offset as the file reads it (as --force-offset)."),
        ] = None,
        name: Annotated[str | None, Form(description="Name (default: the file name).")] = None,
    ) -> DemonstrationCreated:
        """Import a CSV recording with the options of ``contact-skills learn`` (multipart form) and store it."""
        from services.csv_import import ColumnMap, CsvImportError, demonstration_from_csv

        data = file.file.read()
        stem = (file.filename or "upload.csv").rsplit("/", 1)[-1].removesuffix(".csv")
        try:
            demonstration = demonstration_from_csv(
                data,
                columns=ColumnMap.parse(columns) if columns else None,
                quaternion_order=quaternion_order,
                wrench_convention=wrench,
                wrench_frame=wrench_frame,
                rate_hz=rate,
                dt_s=dt,
                tare=tare,
                tare_window_s=_numbers(tare_window, "tare_window", count=(2,)),
                force_offset=_numbers(force_offset, "force_offset", count=(3, 6)),
                name=name or stem,
            )
        except CsvImportError as exc:
            field = _csv_problem_field(exc.problems)
            raise RequestValidationError(
                [{"loc": ("body", field), "msg": problem, "type": "csv_import"} for problem in exc.problems]
            ) from None
        if file.filename:
            demonstration.metadata.source = f"csv:{file.filename}"
        row = store.add_demonstration(demonstration)
        return created(row, notes=list(demonstration.metadata.extra.get("import_notes", [])))

    @app.post(
        "/demonstrations/record",
        status_code=201,
        response_model=DemonstrationCreated,
        responses={**MUTATING_RESPONSES, 503: {"model": ApiError}, 504: {"model": ApiError}},
        dependencies=guarded,
        tags=["demonstrations"],
    )
    def record_demonstration(request: RecordRequest) -> DemonstrationCreated:
        """Ask a sim worker to record the scripted teacher's demonstration of a scenario, and store it.

        The teacher's ground truth is returned in ``extra.ground_truth`` and kept in the demonstration's
        metadata (``metadata.extra.ground_truth``)."""
        from services.bus import NoWorkerAvailable

        client = need_bus()
        try:
            reply = client.record_demonstration(request, timeout_s=RECORD_TIMEOUT_S)
        except NoWorkerAvailable as exc:
            raise HTTPException(503, f"no sim worker available to record: {exc}") from None
        except TimeoutError as exc:
            raise HTTPException(504, f"the recording did not finish in time: {exc}") from None
        if reply.code == "busy":
            raise HTTPException(503, f"every sim worker is busy: {reply.error or 'try again later'}")
        if not reply.ok or reply.demonstration is None:
            raise unprocessable(["body"], reply.error or "the worker recorded nothing")
        demonstration = reply.demonstration
        demonstration.metadata.extra.setdefault("scenario", request.scenario)
        demonstration.metadata.extra["record_request"] = request.model_dump(mode="json")
        if reply.ground_truth is not None:
            demonstration.metadata.extra["ground_truth"] = reply.ground_truth
        row = store.add_demonstration(demonstration)
        return created(row, extra={"ground_truth": reply.ground_truth, "worker_id": reply.worker_id})

    @app.get("/demonstrations", response_model=list[DemonstrationInfo], tags=["demonstrations"])
    def list_demonstrations(
        limit: Annotated[int, Query(ge=1, le=1000)] = 100, offset: Annotated[int, Query(ge=0)] = 0
    ) -> list[DemonstrationInfo]:
        """Stored demonstrations, newest first (summaries, no samples)."""
        return [
            DemonstrationInfo(id=r.id, created=r.created, name=r.name, source=r.source, summary=r.summary)
            for r in store.list_demonstrations(limit, offset)
        ]

    @app.get(
        "/demonstrations/{demonstration_id}",
        responses={200: {"model": StoredDemonstration}, **ERROR_RESPONSES},
        tags=["demonstrations"],
    )
    def get_demonstration(demonstration_id: str) -> Response:
        """A stored demonstration with all its samples."""
        found = store.demonstration_json(demonstration_id)
        if found is None:
            raise not_found("demonstration", demonstration_id)
        row, body = found
        return _raw_json(
            {"id": row.id, "created": row.created, "summary": row.summary.model_dump(mode="json")},
            {"demonstration": body},
        )

    # ------------------------------------------------------------------ skills

    @app.post(
        "/skills",
        status_code=201,
        responses={201: {"model": StoredSkill}, **ERROR_RESPONSES, **MUTATING_RESPONSES},
        dependencies=guarded,
        tags=["skills"],
    )
    def post_skill(request: SkillRequest) -> Response:
        """Learn a skill (slide, contour or auto) from a stored or an inline demonstration, and store it.

        Runs in the thread pool. A demonstration that cannot give the skill is a 422 naming the field."""
        from skills.parameterize import LearningError, learn_skill

        if request.demonstration is not None:
            demonstration, loc = request.demonstration, ["body", "demonstration"]
        else:
            assert request.demonstration_id is not None
            demonstration = store.demonstration(request.demonstration_id)
            if demonstration is None:
                raise not_found("demonstration", request.demonstration_id)
            loc = ["body", "demonstration_id"]
        started = time.perf_counter()
        try:
            check_sampling(demonstration)
            skill = learn_skill(demonstration, request.learn_options())
        except LearningError as exc:
            if request.demonstration is not None:
                raise unprocessable([*loc, exc.field], exc.reason, "learning_error") from None
            message = f"demonstration {request.demonstration_id}: {exc.field}: {exc.reason}"
            raise unprocessable(loc, message, "learning_error") from None
        except ValueError as exc:  # the science refused the data without saying which field: still the input's
            log.warning("learning failed on valid-looking input (%s)", exc, exc_info=True)
            raise unprocessable(loc, f"cannot learn from this demonstration: {exc}", "learning_error") from None
        elapsed = time.perf_counter() - started
        skill_json = skill.model_dump_json()
        row = store.add_skill(skill_json, skill.skill_type.value, request.demonstration_id)
        parts = {"id": row.id, "demonstration_id": row.demonstration_id, "created": row.created}
        return _raw_json({**parts, "learn_seconds": round(elapsed, 4)}, {"skill": skill_json}, status_code=201)

    @app.get("/skills", response_model=list[SkillInfo], tags=["skills"])
    def list_skills(
        limit: Annotated[int, Query(ge=1, le=1000)] = 100, offset: Annotated[int, Query(ge=0)] = 0
    ) -> list[SkillInfo]:
        """Stored skills, newest first (no parameters)."""
        return [SkillInfo(**row) for row in store.list_skills(limit, offset)]

    @app.get("/skills/{skill_id}", responses={200: {"model": StoredSkill}, **ERROR_RESPONSES}, tags=["skills"])
    def get_skill(skill_id: str) -> Response:
        """A stored skill with all its parameters."""
        row = store.skill(skill_id)
        if row is None:
            raise not_found("skill", skill_id)
        parts = {"id": row.id, "demonstration_id": row.demonstration_id, "created": row.created, "learn_seconds": None}
        return _raw_json(parts, {"skill": row.skill_json})

    @app.delete(
        "/skills/{skill_id}",
        status_code=204,
        responses={**ERROR_RESPONSES, **MUTATING_RESPONSES},
        dependencies=guarded,
        tags=["skills"],
    )
    def delete_skill(skill_id: str) -> Response:
        """Delete a stored skill (executions that ran it keep their records)."""
        if not store.delete_skill(skill_id):
            raise not_found("skill", skill_id)
        return Response(status_code=204)

    # ------------------------------------------------------------------ executions

    def view(row: ExecutionRow) -> ExecutionView:
        batches, samples = store.telemetry_counts(row.id)
        return ExecutionView(
            id=row.id,
            skill_id=row.skill_id,
            worker_id=row.worker_id,
            status=row.status,
            phase=row.phase,
            metrics=row.metrics,
            error=row.error,
            created=row.created,
            updated=row.updated,
            telemetry_key=keys.telemetry(row.id),
            telemetry_batches=batches,
            telemetry_samples=samples,
            request=row.request,
        )

    @app.post(
        "/executions",
        status_code=202,
        response_model=ExecutionCreated,
        responses={**ERROR_RESPONSES, **MUTATING_RESPONSES, 503: {"model": ApiError}},
        dependencies=guarded,
        tags=["executions"],
    )
    def post_execution(request: ExecutionRequest) -> ExecutionCreated:
        """Run a skill on a sim worker: the world changed by the known ``environment.offset`` and the
        ``environment.unknown_offset``, with the controller, gains and pace asked for.

        Replies 202 at once with the execution id and the Zenoh key of its telemetry; follow it with
        ``GET /executions/{id}`` or a Zenoh subscriber. 503 when no worker is connected."""
        from schemas.skill import Skill
        from services.bus import BusRequestError, NoWorkerAvailable

        skill, demonstration = request.skill, None
        if request.skill_id is not None:
            row = store.skill(request.skill_id)
            if row is None:
                raise not_found("skill", request.skill_id)
            skill = Skill.model_validate_json(row.skill_json)
            if row.demonstration_id is not None:
                demonstration = store.demonstration(row.demonstration_id)
        client = need_bus()
        scenario = request.scenario or _scenario_of(demonstration)
        world = _taught_world(demonstration) if scenario == _scenario_of(demonstration) else {}
        stored = request.model_dump(mode="json", exclude={"skill"})
        stored.update(scenario=scenario, inline_skill=request.skill is not None, taught_world=bool(world))
        row = store.add_execution(stored, request.skill_id)
        wire = request.model_copy(update={"skill": skill, "skill_id": None, "scenario": scenario})
        try:
            worker_id = client.start_execution(row.id, wire, world_overrides=world, demonstration=demonstration)
        except NoWorkerAvailable as exc:
            store.delete_execution(row.id)
            raise HTTPException(503, str(exc)) from None
        except BusRequestError as exc:  # the worker refused the request (unknown scenario, bad world override)
            store.delete_execution(row.id)
            raise unprocessable(["body", "scenario"] if "scenario" in str(exc) else ["body"], str(exc)) from None
        except Exception as exc:
            log.exception("starting execution %s failed", row.id)
            store.update_execution(row.id, ExecutionState.failed, ExecutionPhase.failed, error=f"start failed: {exc}")
            raise HTTPException(503, f"the bus could not start the execution: {type(exc).__name__}: {exc}") from None
        store.mark_started(row.id, worker_id)
        current = store.execution(row.id)
        return ExecutionCreated(
            id=row.id,
            status=current.status if current else ExecutionState.running,
            worker_id=worker_id,
            telemetry_key=keys.telemetry(row.id),
            status_key=keys.status(row.id),
        )

    @app.get("/executions", response_model=list[ExecutionView], tags=["executions"])
    def list_executions(
        limit: Annotated[int, Query(ge=1, le=1000)] = 100, offset: Annotated[int, Query(ge=0)] = 0
    ) -> list[ExecutionView]:
        """Executions, newest first."""
        return [view(row) for row in store.list_executions(limit, offset)]

    @app.get("/executions/{execution_id}", response_model=ExecutionView, responses=ERROR_RESPONSES, tags=["executions"])
    def get_execution(execution_id: str) -> ExecutionView:
        """Status, phase and (once finished) metrics of an execution."""
        row = store.execution(execution_id)
        if row is None:
            raise not_found("execution", execution_id)
        return view(row)

    def command(execution_id: str, name: str) -> CommandAccepted:
        row = store.execution(execution_id)
        if row is None:
            raise not_found("execution", execution_id)
        if row.status in TERMINAL:
            raise HTTPException(409, f"execution {execution_id} has already finished ({row.status.value})")
        need_bus().send_command(execution_id, name)  # type: ignore[arg-type]
        return CommandAccepted(id=execution_id, command=name, sent_to=keys.cmd(execution_id))

    command_responses = {**ERROR_RESPONSES, **MUTATING_RESPONSES, 409: {"model": ApiError}, 503: {"model": ApiError}}

    @app.post(
        "/executions/{execution_id}/abort",
        status_code=202,
        response_model=CommandAccepted,
        responses=command_responses,
        dependencies=guarded,
        tags=["executions"],
    )
    def abort_execution(execution_id: str) -> CommandAccepted:
        """Abort a running execution (a live command over Zenoh; the final status follows)."""
        return command(execution_id, "abort")

    @app.post(
        "/executions/{execution_id}/pause",
        status_code=202,
        response_model=CommandAccepted,
        responses=command_responses,
        dependencies=guarded,
        tags=["executions"],
    )
    def pause_execution(execution_id: str) -> CommandAccepted:
        """Pause a running execution: it holds its current reference (and force) until resumed."""
        return command(execution_id, "pause")

    @app.post(
        "/executions/{execution_id}/resume",
        status_code=202,
        response_model=CommandAccepted,
        responses=command_responses,
        dependencies=guarded,
        tags=["executions"],
    )
    def resume_execution(execution_id: str) -> CommandAccepted:
        """Resume a paused execution."""
        return command(execution_id, "resume")

    @app.get(
        "/executions/{execution_id}/telemetry",
        responses={200: {"model": TelemetryView}, **ERROR_RESPONSES},
        tags=["executions"],
    )
    def get_telemetry(
        execution_id: str,
        every: Annotated[int, Query(ge=1, le=1_000_000, description="Return every N-th sample.")] = 1,
    ) -> Response:
        """The recorded telemetry stream (wrenches, poses, references, phases) as columns of arrays."""
        row = store.execution(execution_id)
        if row is None:
            raise not_found("execution", execution_id)
        matrix = store.telemetry(execution_id)
        picked = matrix[::every]
        columns: dict[str, Any] = telemetry_columns(picked)
        if not np.isfinite(picked).all():  # never expected (the executor reports no NaN); keep the JSON valid
            columns = json.loads(re.sub(r"-?Infinity|NaN", "null", json.dumps(columns)))
        body = {
            "execution_id": execution_id,
            "every": every,
            "n_samples": int(picked.shape[0]),
            "stored_samples": int(matrix.shape[0]),
            "status": row.status.value,
            **columns,
        }
        return Response(json.dumps(body), media_type="application/json")

    return app


def connect_bus(settings: ServiceSettings, store: Store) -> BusClient:
    """A `BusClient` on the settings' endpoints whose callbacks write into ``store`` (:class:`BusEvents`).

    Waits up to ``settings.connect_timeout_s`` for the router, then raises ``ConnectionError``."""
    from services.bus import BusClient, BusSettings

    events = BusEvents(store)
    bus_settings = BusSettings(
        endpoints=list(settings.zenoh_endpoints),
        prefix=settings.zenoh_prefix,
        connect_timeout_s=settings.connect_timeout_s,
    )
    return BusClient(bus_settings, events.on_status, events.on_telemetry, events.on_worker_lost)
