"""What the routes share, as ``Annotated`` dependencies: the store, the settings, the bus and the Zenoh key
expressions live on ``app.state`` (set by ``services.app.create_app``) and are resolved through the ``Request``;
the token guard of the mutating routes; the paging parameters.

The bus is optional (``BusDep`` is None without one): a route asks for it with :func:`need_bus` where it needs it,
after validating its input, so a bad body is still a 422 and an unknown id a 404 when no bus is connected.
"""

from __future__ import annotations

import ipaddress
import secrets
from typing import Annotated

from fastapi import Depends, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from schemas.api import TelemetryFormat
from schemas.bus import KeyExpressions
from schemas.execution import ExecutionSettings, GainSchedule
from schemas.job_budget import JobBudget
from schemas.skill import Skill
from schemas.world import world_engine
from services.api import errors
from services.api.limits import ClientCaps
from services.api.responses import OpenApiResponses
from services.bus import BusClient
from services.learner_pool import LearnerPool
from services.queue import ExecutionQueue
from services.settings import ServiceSettings
from services.store import DemonstrationRow, Store
from services.sweeps import SweepRunner


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_settings(request: Request) -> ServiceSettings:
    return request.app.state.settings


def get_bus(request: Request) -> BusClient | None:
    return request.app.state.bus


def get_keys(request: Request) -> KeyExpressions:
    return request.app.state.keys


def get_learners(request: Request) -> LearnerPool:
    return request.app.state.learners


def get_queue(request: Request) -> ExecutionQueue | None:
    return request.app.state.queue


def get_sweeps(request: Request) -> SweepRunner | None:
    return request.app.state.sweeps


def get_client_caps(request: Request) -> ClientCaps:
    return request.app.state.client_caps


StoreDep = Annotated[Store, Depends(get_store)]
SettingsDep = Annotated[ServiceSettings, Depends(get_settings)]
BusDep = Annotated[BusClient | None, Depends(get_bus)]
KeysDep = Annotated[KeyExpressions, Depends(get_keys)]
LearnersDep = Annotated[LearnerPool, Depends(get_learners)]
QueueDep = Annotated[ExecutionQueue | None, Depends(get_queue)]
SweepsDep = Annotated[SweepRunner | None, Depends(get_sweeps)]
ClientCapsDep = Annotated[ClientCaps, Depends(get_client_caps)]


def need_bus(bus: BusClient | None) -> BusClient:
    """The bus, or a 503 when the API runs without one."""
    if bus is None:
        raise errors.no_bus()
    return bus


def need_queue(queue: ExecutionQueue | None) -> ExecutionQueue:
    """The execution queue, or a 503 when the API runs without a bus."""
    if queue is None:
        raise errors.no_bus()
    return queue


def need_sweeps(sweeps: SweepRunner | None) -> SweepRunner:
    """The sweep runner, or a 503 when the API runs without a bus."""
    if sweeps is None:
        raise errors.no_bus()
    return sweeps


def skill_to_run(store: Store, skill_id: str | None, skill: Skill | None) -> tuple[Skill, str | None]:
    """The skill a request runs, given by id (404 if unknown) or inline (422 naming each incoherence), and the id of
    the demonstration it was learned from (for the path metric; None for an inline skill)."""
    from services.api.limits import skill_problems

    if skill is not None:
        if problems := skill_problems(skill):
            raise errors.incoherent_skill(problems)
        return skill, None
    stored = store.skills.get(skill_id or "")
    if stored is None:
        raise errors.not_found("skill", str(skill_id))
    return Skill.model_validate_json(stored.skill_json), stored.demonstration_id


def readable_demonstration(store: Store, demonstration_id: str) -> tuple[DemonstrationRow, str]:
    """The stored demonstration's row and body (JSON text): 404 for an unknown id, 409 for one stored under looser
    rules that cannot be read back."""
    found = store.demonstrations.json(demonstration_id)
    if found is None:
        raise errors.not_found("demonstration", demonstration_id)
    if found[0].problem is not None:
        raise errors.unreadable(demonstration_id, found[0].problem)
    return found


def check_settings_for_skill(
    skill: Skill,
    settings: ExecutionSettings,
    budget: JobBudget,
    settings_at: tuple[str, ...] = ("body",),
    skill_at: tuple[str, ...] = ("body", "skill_id"),
) -> None:
    """422 when ``skill`` cannot run with ``settings``: on ``gains.gain_schedule`` for a spread the skill does not
    have (``skills.gain_schedule.missing_spread``: checked here, before a worker is asked), and naming each setting
    that takes the execution past ``budget`` (at the step of the world it was taught in; ``skills.job_estimate``);
    ``settings_at``, ``skill_at``: where the settings and the skill are in the request; and on the skill's
    ``taught_world.engine`` when that world names an engine there is not (a worker could only refuse it, or fail it
    after it waited in the queue)."""
    from skills.gain_schedule import missing_spread
    from skills.job_estimate import execution_estimate, taught_time_step_s

    try:
        world_engine(skill.taught_world)
    except ValueError as exc:
        raise errors.unprocessable([*skill_at, "taught_world", "engine"], str(exc)) from None
    if settings.gains.gain_schedule is GainSchedule.from_spread and (reason := missing_spread(skill)):
        raise errors.unprocessable([*settings_at, "gains", "gain_schedule"], reason)
    if problems := execution_estimate(skill, settings, taught_time_step_s(skill)).problems(budget):
        raise errors.over_budget(problems, settings_at, skill_at)


BEARER = HTTPBearer(auto_error=False, description="Set CONTACT_SKILLS_TOKEN on the server to require it.")
"""Optional bearer token of the mutating endpoints."""


Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(BEARER)]


def authenticated(settings: SettingsDep, credentials: Credentials) -> bool:
    """Whether the request carries the configured token (False when none is configured)."""
    if settings.token is None or credentials is None:
        return False
    return secrets.compare_digest(credentials.credentials.encode(), settings.token.encode())


AuthenticatedDep = Annotated[bool, Depends(authenticated)]

TOKEN_CLIENT = "the bearer token"
"""The client key of every request that carries the configured token (:func:`client_keys`)."""


def client_keys(request: Request, known: AuthenticatedDep) -> tuple[str, ...]:
    """Who sent the request, for the per-client caps (``services.api.limits.ClientCaps``): its address, every
    loopback address one (127.0.0.2 is this machine as much as 127.0.0.1), and :data:`TOKEN_CLIENT` when it carries
    the token (one identity, whatever address its holders send from)."""
    host = request.client.host if request.client is not None else "unknown"
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        address = None
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    keys = ("client on this machine (loopback)" if address is not None and address.is_loopback else f"client {host}",)
    return (*keys, TOKEN_CLIENT) if known else keys


ClientDep = Annotated[tuple[str, ...], Depends(client_keys)]


def require_token(settings: SettingsDep, known: AuthenticatedDep) -> None:
    """401 unless the request carries the configured token (no token configured: everyone passes)."""
    if settings.token is not None and not known:
        raise errors.unauthorized()


def require_token_to_read(settings: SettingsDep, known: AuthenticatedDep) -> None:
    """401 on a read without the token when ``token_reads`` is set."""
    if settings.token_reads and not known:
        raise errors.unauthorized()


def require_storage_room(store: StoreDep, settings: SettingsDep) -> None:
    """507 when what the database holds and what the queued and running executions reserve for their telemetry
    reach ``storage_quota_mb`` (0: no quota)."""
    quota = settings.storage_quota_bytes
    if quota and (stored := store.usage_bytes()) + (reserved := store.reserved_bytes()) >= quota:
        raise errors.storage_full(stored, reserved, quota)


TOKEN_GUARD = [Depends(require_token)]
"""``dependencies=`` of every POST/DELETE route."""
STORING_GUARD = [*TOKEN_GUARD, Depends(require_storage_room)]
"""``dependencies=`` of a POST that stores something new (a demonstration, skill, execution, sweep): the token, then
room in the storage quota (a DELETE, which frees room, never needs it)."""
READ_GUARD = [Depends(require_token_to_read)]
"""``dependencies=`` of every GET route but ``/health`` (open unless ``token_reads``)."""

MAX_OFFSET = 1_000_000_000
"""Largest list offset (SQLite takes 64-bit integers; a larger one would overflow)."""
Limit = Annotated[int, Query(ge=1, le=1000, description="Most items to return.")]
Offset = Annotated[int, Query(ge=0, le=MAX_OFFSET, description="Items to skip (newest first).")]

ExportFormat = Annotated[
    TelemetryFormat,
    Query(
        alias="format",
        description="json: columns of arrays; csv: one row per sample; mcap: ROS 2 messages for Foxglove or "
        "PlotJuggler (topics in docs/API.md, 'Export').",
    ),
]
WindowStart = Annotated[
    float | None, Query(allow_inf_nan=False, description="Only samples at or after this time, s (the record's t).")
]
WindowEnd = Annotated[
    float | None, Query(allow_inf_nan=False, description="Only samples at or before this time, s (the record's t).")
]
"""The window parameters of ``GET .../telemetry``: finite (``?t0=nan`` is a 422 naming it, not a scan of a run)."""


def time_window(t0: WindowStart = None, t1: WindowEnd = None) -> tuple[float | None, float | None]:
    """The time window (``t0``, ``t1``, s) of a samples read; 422 on ``t1`` when it ends before it starts, checked
    before the route looks anything up."""
    errors.check_window(t0, t1)
    return t0, t1


TimeWindow = Annotated[tuple[float | None, float | None], Depends(time_window)]
"""The checked ``t0``, ``t1`` of ``GET .../telemetry``."""
Cursor = Annotated[
    int,
    Query(
        ge=0,
        le=MAX_OFFSET,
        description="The stream index to start from: 0 for the first page, then the previous page's next_cursor "
        "(X-Next-Cursor header).",
    ),
]
PageLimit = Annotated[
    int | None,
    Query(
        ge=1,
        description="Most samples in this page; at most (and by default) the service's cap, "
        "CONTACT_SKILLS_TELEMETRY_PAGE_SAMPLES (20 000).",
    ),
]
"""The paging parameters of ``GET /executions/{id}/telemetry``."""
SampleCursor = Annotated[
    int | None,
    Query(
        ge=0,
        le=MAX_OFFSET,
        description="Page the samples: the index of the first sample, 0 for the first page, then the previous "
        "page's next_cursor (X-Next-Cursor header). Without cursor and limit the whole demonstration is returned, "
        "or a 422 when it does not fit in one reply.",
    ),
]
SampleLimit = Annotated[
    int | None,
    Query(
        ge=1,
        description="Page the samples: most samples in this page; at most (and by default) what fits in one reply.",
    ),
]
"""The paging parameters of ``GET /demonstrations/{id}``."""
NEXT_CURSOR_HEADER = "X-Next-Cursor"
"""The header of a telemetry or samples page that is not the last: the cursor of the next one."""
EXPORT_RESPONSES: OpenApiResponses = {
    200: {"content": {"text/csv": {}, "application/octet-stream": {}}, "description": "JSON, CSV or MCAP."}
}
