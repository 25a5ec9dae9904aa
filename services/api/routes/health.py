"""``GET /health``: liveness, and the sim workers connected over Zenoh."""

from __future__ import annotations

import os

from fastapi import APIRouter, Request

from schemas.api import Health
from services.api.deps import BusDep, SettingsDep, StoreDep

router = APIRouter(tags=["service"])


@router.get("/health", response_model=Health)
def health(request: Request, store: StoreDep, settings: SettingsDep, bus: BusDep) -> Health:
    """Liveness, and the sim workers connected over Zenoh.

    Always 200 while the API answers (docker-compose's healthcheck uses it): the version, whether the Zenoh bus is
    connected, each connected worker's state (idle, executing, recording), the database and its schema version,
    the executions running now."""
    workers = [info.model_dump(mode="json") for info in bus.workers()] if bus is not None else []
    return Health(
        version=request.app.version,
        bus_connected=bus is not None,
        zenoh_endpoints=settings.zenoh_endpoints,
        workers=workers,
        database=str(store.path),
        schema_version=store.schema_version(),
        active_executions=len(store.active_executions()),
        pid=os.getpid(),
    )
