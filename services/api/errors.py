"""Every error the API answers, in one place: how a failure of the store, the science, the importer or the bus
becomes a status code and a ``detail``, the handlers that shape 422 and 500 bodies, and the OpenAPI ``responses``.

- 422: any bad body or parameter — pydantic's errors, plus `LearningError` and `CsvImportError`
  with ``loc`` naming the field (``["body", "demonstration", "wrenches"]``, ``["body", "file"]``);
  error entries never echo large inputs back.
- 404: unknown id. 409: a command to a finished execution, the telemetry of one run without it, the deletion of
  a queued or running execution or a sweep's trial, a demonstration stored under looser rules that cannot be read
  back. 401:
  missing/wrong bearer token on POST/DELETE when ``CONTACT_SKILLS_TOKEN`` is set (``deps.require_token``; on GET
  too with ``CONTACT_SKILLS_TOKEN_READS``). 413: body over the limit (``body_limit.BodyLimit``). 400: a malformed
  request or a Host that is not the loopback service's; 403: a cross-origin browser request (``browser_guard``).
- 405 for a method the path does not answer, with ``Allow``; OPTIONS answers 204 with it.
- 503: no Zenoh bus or no sim worker connected; 504: a recording timed out.
- 507: the storage quota is reached (what is stored and what queued and running executions reserve), or a write found
  the disk full (``services.store.DiskFull``: nothing stored; a DELETE still works).
- 500 only for a bug: logged with its traceback, answered with a short JSON body.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Mapping
from typing import TYPE_CHECKING, NotRequired, TypedDict

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import JsonValue
from starlette.routing import Match, Mount

from schemas.api import ApiError
from services.api.responses import OpenApiResponses
from services.learner_pool import LearnOutcome, LearnOutcomeKind
from services.store import DiskFull, SweepTrialRef

if TYPE_CHECKING:
    from services.csv_import import CsvImportError
    from services.import_steps import DemonstrationImportError
    from services.store import QuotaFull

log = logging.getLogger("contact_skills.api")

MAX_ECHOED_INPUT = 200
"""A validation error echoes the offending input only if its JSON is at most this many characters."""

ERROR_RESPONSES: OpenApiResponses = {404: {"model": ApiError}}
"""OpenAPI ``responses`` of a route that looks an id up."""
MUTATING_RESPONSES: OpenApiResponses = {401: {"model": ApiError}, 413: {"model": ApiError}}
"""OpenAPI ``responses`` of a route behind the token guard and the body limit."""
READ_RESPONSES: OpenApiResponses = {401: {"model": ApiError}, 403: {"model": ApiError}}
"""OpenAPI ``responses`` of every resource route: 401 without the token (reads too with ``token_reads``), 403 for a
cross-origin browser request (``browser_guard``)."""
STORING_RESPONSES: OpenApiResponses = {**MUTATING_RESPONSES, 507: {"model": ApiError}}
"""OpenAPI ``responses`` of a route that stores something new: 507 when the database holds its quota."""
UNAVAILABLE: OpenApiResponses = {503: {"model": ApiError}}
"""OpenAPI ``responses`` of a route that needs the bus."""


# --------------------------------------------------------------------------- the errors routes raise


def unprocessable(loc: list[str | int], message: str, kind: str = "value_error") -> RequestValidationError:
    """A 422 in FastAPI's shape: ``{"detail": [{"loc": loc, "msg": message, "type": kind}]}``."""
    return RequestValidationError([{"loc": tuple(loc), "msg": message, "type": kind}])


def check_window(t0: float | None, t1: float | None) -> None:
    """422 on ``t1`` when a time window ends before it starts."""
    if t0 is not None and t1 is not None and t1 < t0:
        raise unprocessable(["query", "t1"], f"the window ends ({t1:g} s) before it starts (t0 = {t0:g} s)")


def not_found(kind: str, ident: str) -> HTTPException:
    return HTTPException(404, f"no {kind} with id {ident!r}")


def no_bus() -> HTTPException:
    return HTTPException(503, "no Zenoh bus: start the API connected to a router (contact-skills up / api)")


def unavailable(detail: str) -> HTTPException:
    """503: no sim worker can take the request now (none connected, every one busy, the bus failed)."""
    return HTTPException(503, detail)


def storage_full(stored_bytes: int, reserved_bytes: int, quota_bytes: int, needed_bytes: int = 0) -> HTTPException:
    """507: what the database holds and what the queued and running executions reserve for their telemetry reach
    the quota (``CONTACT_SKILLS_STORAGE_QUOTA_MB``), or leave less than ``needed_bytes`` (an execution's)."""
    need = f"this execution's telemetry needs {_mib(needed_bytes)} and " if needed_bytes else ""
    return HTTPException(
        507,
        f"the storage quota is reached: {need}the database holds {_mib(stored_bytes)} and queued or running "
        f"executions reserve {_mib(reserved_bytes)} for their telemetry, of the quota of {_mib(quota_bytes)} "
        "(CONTACT_SKILLS_STORAGE_QUOTA_MB); delete executions or demonstrations (DELETE /executions/{id}, "
        "/demonstrations/{id}), wait for running executions to end, or raise the quota",
    )


def quota_full(exc: QuotaFull) -> HTTPException:
    """507: an execution's telemetry does not fit in the storage quota (:func:`storage_full`)."""
    return storage_full(exc.stored_bytes, exc.reserved_bytes, exc.quota_bytes, exc.needed_bytes)


def _mib(n: int) -> str:
    """``n`` bytes in MiB, to one decimal."""
    return f"{n / 2**20:,.1f} MiB"


def stored_too_large(
    loc: list[str | int], stored_bytes: int, brought_bytes: int, multiple: float
) -> RequestValidationError:
    """422 on the upload: what it would store is more than ``multiple`` times what it brought."""
    return unprocessable(
        loc,
        f"importing it would store {stored_bytes / 2**20:.1f} MiB from {brought_bytes / 1024:.1f} KiB uploaded "
        f"({stored_bytes / max(brought_bytes, 1):.0f}x; at most {multiple:g}x): its time stamps span far more samples "
        "than it has rows (a gap, or time in the wrong unit); fix the time column or give a lower rate_hz",
        "stored_too_large",
    )


def recording_timed_out(exc: TimeoutError) -> HTTPException:
    return HTTPException(504, f"the recording did not finish in time: {exc}")


def already_finished(execution_id: str, status: str) -> HTTPException:
    return HTTPException(409, f"execution {execution_id} has already finished ({status})")


def no_telemetry(execution_id: str, sweep: SweepTrialRef | None) -> HTTPException:
    """409: the execution ran with ``telemetry`` ``none`` (``sweep``: the sweep and trial it ran for, if any)."""
    origin = f" (trial {sweep.trial} of sweep {sweep.id}, which did not ask for store_telemetry)" if sweep else ""
    return HTTPException(
        409,
        f"execution {execution_id} ran with telemetry 'none'{origin}: no telemetry was published or stored; its "
        "metrics are in GET /executions/{id}. Run it with telemetry 'stream' to record the stream.",
    )


def unreadable(demonstration_id: str, problem: str) -> HTTPException:
    """409: a demonstration stored by an earlier version under looser rules cannot be read back."""
    return HTTPException(
        409,
        f"demonstration {demonstration_id} was stored under looser rules and cannot be read back ({problem}); delete "
        f"it with DELETE /demonstrations/{demonstration_id}",
    )


def no_demonstration(skill_id: str) -> HTTPException:
    """409: a skill learned from an inline demonstration has no stored one to show it along."""
    return HTTPException(
        409,
        f"skill {skill_id} was learned from an inline demonstration, which was not stored: store it (POST "
        "/demonstrations) and learn from its demonstration_id to export the skill along it",
    )


def samples_over_budget(demonstration_id: str, n_samples: int, fit: int) -> RequestValidationError:
    """422 on ``limit``: a whole demonstration asked for (no ``cursor``, no ``limit``) does not fit in one reply."""
    return unprocessable(
        ["query", "limit"],
        f"demonstration {demonstration_id} has {n_samples} samples, more than one reply holds ({fit}): page them with "
        f"GET /demonstrations/{demonstration_id}?cursor=0, then cursor=next_cursor (also the X-Next-Cursor header) "
        "until next_cursor is null",
        "over_budget",
    )


def still_active(execution_id: str, status: str) -> HTTPException:
    """409: an execution queued or running cannot be deleted."""
    return HTTPException(
        409, f"execution {execution_id} is {status}: abort it (POST /executions/{execution_id}/abort) before deleting"
    )


def part_of_sweep(execution_id: str, sweep: SweepTrialRef) -> HTTPException:
    """409: a sweep's trial cannot be deleted alone (the sweep's results are its executions)."""
    return HTTPException(
        409, f"execution {execution_id} is trial {sweep.trial} of sweep {sweep.id}: the sweep's results "
        "are its executions, it cannot be deleted alone"
    )  # fmt: skip


def not_running(execution_id: str, status: str) -> HTTPException:
    return HTTPException(409, f"execution {execution_id} is {status}, not running: only abort applies (it cancels it)")


def refused_by_worker(reason: str, environment_at: tuple[str, ...] = ("body",)) -> RequestValidationError:
    """422 for a request a worker refused (an unknown scenario, a skill it cannot place in reach, a recording over
    the job budget), on the field the worker's message names; ``environment_at``: where the request's
    ``environment`` is."""
    if reason.startswith("unknown scenario"):
        loc: list[str | int] = ["body", "scenario"]
    elif reason.startswith(("environment.", "the skill cannot be placed")):
        field = reason.split(":", 1)[0] if reason.startswith("environment.") else "environment.placement"
        loc = [*environment_at, *field.split(".")]
    elif reason.startswith("overrides."):
        loc = ["body", *reason.split(":", 1)[0].split(".")]
    else:
        loc = ["body"]
    return unprocessable(loc, reason)


def over_budget(
    problems: list[tuple[str, str]], settings_at: tuple[str, ...], skill_at: tuple[str, ...]
) -> RequestValidationError:
    """422 with one entry per setting that takes a job past the job budget (``schemas.job_budget``): on the setting
    (under ``settings_at``), or on the skill (``skill_at``) for its own segments and time step."""
    return RequestValidationError(
        [{"loc": skill_at if field == "skill" else (*settings_at, *field.split(".")), "msg": message,
          "type": "job_budget"} for field, message in problems]
    )  # fmt: skip


def sweep_not_running(sweep_id: str, status: str) -> HTTPException:
    return HTTPException(409, f"sweep {sweep_id} is {status}, not running: nothing to cancel")


def unauthorized() -> HTTPException:
    return HTTPException(
        401, "missing or wrong bearer token (Authorization: Bearer <token>)", {"WWW-Authenticate": "Bearer"}
    )


def incoherent_skill(problems: list[tuple[list[str | int], str]]) -> RequestValidationError:
    """422 with one entry per incoherence of an inline skill (``services.api.limits.skill_problems``)."""
    return RequestValidationError(
        [{"loc": ("body", "skill", *loc), "msg": reason, "type": "incoherent_skill"} for loc, reason in problems]
    )


def csv_import_failed(exc: CsvImportError) -> RequestValidationError:
    """422 with one entry per import problem, each naming the form field it is about."""
    field = _csv_problem_field(exc.problems)
    return RequestValidationError(
        [{"loc": ("body", field), "msg": problem, "type": "csv_import"} for problem in exc.problems]
    )


BAG_PROBLEM_FIELDS = {"wrench_topic": "wrench_topic", "pose_topic": "pose_topic", "tf": "tf_parent",
                      "wrench_frame": "wrench_frame", "file": "file"}  # fmt: skip
"""A bag import problem's prefix (``services.bag_import``) -> the form field of ``POST /demonstrations/bag``."""


def import_failed(exc: DemonstrationImportError) -> RequestValidationError:
    """422 for a bag import: one entry per problem, on the form field its prefix names (else as for a CSV)."""
    entries = []
    for problem in exc.problems:
        prefix = problem.partition(":")[0]
        field = BAG_PROBLEM_FIELDS.get(prefix) or _csv_problem_field([problem])
        entries.append({"loc": ("body", field), "msg": problem, "type": "bag_import"})
    return RequestValidationError(entries)


def learning_outcome_failed(
    outcome: LearnOutcome, loc: list[str | int], demonstration_id: str | None, memory_mb: int
) -> RequestValidationError:
    """422 for a learner process's answer other than ok: the science refused the demonstration (naming the field),
    failed on it without naming one (in our words; the library's text goes to the log), or ran out of the memory
    budget; strict learning that refused a skill is a 422 on ``strict`` with one entry per failed check. A bug in
    the learner is a logged 500."""
    if outcome.kind is LearnOutcomeKind.checks:
        return RequestValidationError(
            [{"loc": ("body", "strict"), "msg": f"the skill fails its check {reason}", "type": "skill_check"}
             for reason in outcome.reasons]
        )  # fmt: skip
    if outcome.kind is LearnOutcomeKind.learning:
        if demonstration_id is None:
            return unprocessable([*loc, outcome.field], outcome.reason, "learning_error")
        return unprocessable(
            loc, f"demonstration {demonstration_id}: {outcome.field}: {outcome.reason}", "learning_error"
        )
    if outcome.kind is LearnOutcomeKind.value:
        log.warning("learning failed on valid-looking input: %s", outcome.reason)
        return unprocessable(
            loc, "cannot learn from this demonstration: the segmentation or the fit failed on its samples "
            "(degenerate or inconsistent motion and force)", "learning_error",
        )  # fmt: skip
    if outcome.kind is LearnOutcomeKind.memory:
        return unprocessable(
            loc, f"cannot learn from this demonstration within the learner's memory budget of {memory_mb} MiB "
            "(CONTACT_SKILLS_LEARN_MEMORY_MB): use fewer samples or fewer basis functions", "learning_budget",
        )  # fmt: skip
    raise RuntimeError(f"the learner failed:\n{outcome.reason}")


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


# --------------------------------------------------------------------------- the handlers

_NAMES_A_FIELD = re.compile(r"^(?:Value error, )?(\w+) has ")


class TidyError(TypedDict):
    """One entry of a 422's ``detail``, FastAPI's shape: where, what, the error's kind, the offending input when it is
    short, and the limit broken (``{"gt": 0}``)."""

    loc: list[str | int]
    msg: str
    type: str
    input: NotRequired[JsonValue]
    ctx: NotRequired[dict[str, int | float | str | bool]]


def tidy_error(error: Mapping[str, object]) -> TidyError:
    """An error entry (pydantic's or :func:`unprocessable`'s) without large inputs; a model-level error whose message
    starts with a field name gets it appended to ``loc`` (``positions has 4 samples but t has 5`` ->
    ``[..., "positions"]``)."""
    given_loc = error.get("loc", ())
    loc: list[str | int] = list(given_loc) if isinstance(given_loc, tuple | list) else []
    msg = str(error.get("msg", ""))
    match = _NAMES_A_FIELD.match(msg)
    if match and (not loc or loc[-1] != match[1]) and error.get("type") == "value_error":
        loc.append(match[1])
    tidy = TidyError(loc=loc, msg=msg.removeprefix("Value error, "), type=str(error.get("type", "value_error")))
    if "input" in error:
        try:  # strictly JSON and UTF-8: the echo of a NaN or a lone surrogate is its text (a JSONResponse refuses both)
            text = json.dumps(error["input"], allow_nan=False, default=str)
            echo: JsonValue = json.loads(text)
            json.dumps(echo, ensure_ascii=False).encode("utf-8")
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
    return JSONResponse(status_code=422, content={"detail": [tidy_error(dict(e)) for e in exc.errors()]})


async def _disk_full(request: Request, exc: DiskFull) -> JSONResponse:
    log.error("%s %s: %s", request.method, request.url.path, exc)
    return JSONResponse(
        status_code=507,
        content={"detail": f"{exc}: nothing was stored; delete executions or demonstrations (DELETE "
                 "/executions/{id}, /demonstrations/{id}: deletion works on a full disk) or free disk space"},
    )  # fmt: skip


async def _unexpected_error(request: Request, exc: Exception) -> JSONResponse:
    log.exception("bug: %s %s raised %s", request.method, request.url.path, type(exc).__name__)
    return JSONResponse(
        status_code=500, content={"detail": f"internal error ({type(exc).__name__}); it is logged by the API"}
    )


HTTP_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")
"""The methods a route may answer, for ``Allow`` (:func:`allowed_methods`)."""


def allowed_methods(request: Request) -> list[str]:
    """The methods the request's path answers (a route takes the path and the method), and OPTIONS, sorted."""
    routes = [route for route in request.app.router.routes if not isinstance(route, Mount)]

    def answers(method: str) -> bool:
        return any(route.matches({**request.scope, "method": method})[0] is Match.FULL for route in routes)

    return sorted({method for method in HTTP_METHODS if answers(method)} | {"OPTIONS"})


async def _method_not_allowed(request: Request, exc: Exception) -> Response:
    """405 with an ``Allow`` naming every method of the path (Starlette names only the first route's); OPTIONS
    answers 204 with it (a CORS preflight never gets here: ``CORSMiddleware`` answers it first)."""
    allow = {"Allow": ", ".join(allowed_methods(request))}
    if request.method == "OPTIONS":
        return Response(status_code=204, headers=allow)
    return JSONResponse({"detail": "Method Not Allowed"}, status_code=405, headers=allow)


def install_error_handlers(app: FastAPI) -> None:
    """422 bodies through :func:`tidy_error`; a full disk 507 naming it; 405 and OPTIONS with ``Allow``
    (:func:`allowed_methods`); any other exception a logged 500 with a short JSON body."""
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(DiskFull, _disk_full)
    app.add_exception_handler(405, _method_not_allowed)
    app.add_exception_handler(Exception, _unexpected_error)
