"""``GET /health``: liveness, the sim workers connected over Zenoh, the learner processes; details with the token."""

from __future__ import annotations

import dataclasses
import os

from fastapi import APIRouter, Request

from schemas.api import Health, HealthDetail, WorkerSummary
from schemas.bus import WorkerInfo
from services.api.deps import AuthenticatedDep, BusDep, LearnersDep, SettingsDep, StoreDep
from services.bus import observer_login
from services.store import TERMINAL, Store

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
    connected, each connected worker's state (idle, executing, recording: its own last answer, ``info_age_s`` old,
    the answer never waits for the workers; a run it was executing that the store shows ended is not shown) and how
    long since the API last heard from it (``heard_s_ago``), the executions running now, the learner processes. The
    database path and the process ids and host names of the API and its workers only for a request with the
    bearer token."""
    infos = bus.workers_seen() if bus is not None else []  # never waits on the bus (but the first time)
    age = bus.seen_age() if bus is not None else None
    summaries = [_summary(info, store, age, bus.watch.heard_age(info.worker_id)) for info in infos]
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
        workers=summaries,
        active_executions=len(store.executions.active()),
        queued_executions=store.executions.queued_count(),
        learning=dataclasses.asdict(learners.stats),
        foxglove_url=request.app.state.foxglove.url if request.app.state.foxglove is not None else None,
        zenoh_login=zenoh_login,
        detail=detail,
    )


def _summary(info: WorkerInfo, store: Store, info_age_s: float | None, heard_s_ago: float | None) -> WorkerSummary:
    """A worker as ``/health`` shows it: its own answer (``info_age_s`` old; none for a worker that has not answered
    yet), unless the run it said it executes has ended since, by the store (which the final status or the worker's
    loss updated after that answer): then idle."""
    summary = WorkerSummary(**info.model_dump(include=set(WorkerSummary.model_fields)), heard_s_ago=heard_s_ago)
    if info.activity == "unknown":
        return summary
    summary.info_age_s = info_age_s
    row = store.executions.get(info.execution_id) if info.execution_id else None
    if info.activity == "executing" and (row is None or row.status in TERMINAL):
        summary.busy, summary.activity, summary.execution_id = False, "idle", None
    return summary
