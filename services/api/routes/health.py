"""``GET /health``: liveness, the sim workers connected over Zenoh, the learner processes; details with the token."""

from __future__ import annotations

import dataclasses
import os

from fastapi import APIRouter, Request

from schemas.api import Health, HealthDetail, WorkerSummary
from services.api.deps import AuthenticatedDep, BusDep, LearnersDep, SettingsDep, StoreDep
from services.bus import observer_login

router = APIRouter(tags=["service"])


@router.get("/health", response_model=Health)
def health(
    request: Request,
    store: StoreDep,
    settings: SettingsDep,
    bus: BusDep,
    learners: LearnersDep,
    known: AuthenticatedDep,
) -> Health:
    """Liveness, the sim workers connected over Zenoh and the learner processes.

    Always 200 while the API answers (docker-compose's healthcheck uses it): the version, whether the Zenoh bus is
    connected, each connected worker's state (idle, executing, recording; as the bus showed it at most about half a
    second ago: the answer never waits for the workers), the executions running now, the learner processes. The
    database path and the process ids and host names of the API and its workers only for a request with the
    bearer token."""
    infos = bus.workers_seen() if bus is not None else []  # never waits on the bus (but the first time)
    reads = known or not settings.token_reads
    zenoh_login = observer_login(settings.zenoh_endpoints) if bus is not None and reads else None
    detail = None
    if known:
        detail = HealthDetail(
            database=str(store.path),
            schema_version=store.schema_version(),
            pid=os.getpid(),
            workers=[info.model_dump(mode="json") for info in infos],
        )
    return Health(
        version=request.app.version,
        started_unix_s=request.app.state.started_unix_s,
        instance=settings.instance,
        bus_connected=bus is not None,
        zenoh_endpoints=settings.zenoh_endpoints,
        workers=[WorkerSummary(**info.model_dump(include=set(WorkerSummary.model_fields))) for info in infos],
        active_executions=len(store.executions.active()),
        queued_executions=store.executions.queued_count(),
        learning=dataclasses.asdict(learners.stats),
        foxglove_url=request.app.state.foxglove.url if request.app.state.foxglove is not None else None,
        zenoh_login=zenoh_login,
        detail=detail,
    )
