"""The REST service (DESIGN.md "Interfaces"): FastAPI routes over the SQLite store and the Zenoh bus client.

``create_app(settings, bus)`` builds the app: the state the routes share (store, settings, bus, Zenoh key
expressions) on ``app.state``, the body limit, the error handlers and the routers of ``services.api``:

- ``services/api/routes/``: one APIRouter per resource (``health``, ``demonstrations``, ``skills``,
  ``executions``, ``sweeps``). Route functions are thin: they validate (the pydantic models of ``schemas/``), call the
  store, the science (``skills.parameterize.learn_skill``, in a learner process) or the bus, and shape the reply;
- ``services/api/deps.py``: the shared dependencies as ``Annotated`` types, resolved through the ``Request``;
- ``services/api/errors.py``: every error answer (422 naming the field, 404, 409, 401, 503, 504, the logged 500);
- ``services/api/browser_guard.py``: the CORS policy (none by default) and the Host check of a loopback API;
- ``services/learner_pool.py``: learning in separate processes with a time and memory budget;
- ``services/queue.py``: executions wait in the database for a free worker, in priority order;
- ``services/sweeps.py``: robustness sweeps, their trials fanned out through the queue, resumed after a restart;
- ``services/bus_events.py``: the bus callbacks (:class:`BusEvents`) that write status, metrics and telemetry
  into the same store from Zenoh threads, and :func:`connect_bus`.
"""

from __future__ import annotations

import time
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware

from schemas.bus import KeyExpressions
from services.api.body_limit import BodyLimit
from services.api.browser_guard import LOOPBACK_NAMES, BrowserGuard
from services.api.docs import install_offline_docs
from services.api.errors import install_error_handlers
from services.api.main import api_router
from services.bus_events import BusEvents, connect_bus, reconcile
from services.learner_pool import LearnerPool
from services.queue import ExecutionQueue
from services.settings import ServiceSettings, package_version
from services.store import Store
from services.sweeps import SweepRunner

if TYPE_CHECKING:
    from services.bus import BusClient

__all__ = ["BusEvents", "connect_bus", "create_app"]


def create_app(settings: ServiceSettings, bus: BusClient | None = None, store: Store | None = None) -> FastAPI:
    """The FastAPI app. ``bus``: a connected `services.bus.BusClient` whose callbacks are a :class:`BusEvents`
    on the same store (see :func:`connect_bus`), or None (executions and recordings then get 503).
    ``store``: the open store; default: opened from ``settings.db_path`` and closed with the app."""
    own_store = store is None
    store = store if store is not None else Store(settings.db_path)
    learners = LearnerPool(settings.learn_processes, settings.learn_timeout_s, settings.learn_memory_mb)
    queue = ExecutionQueue(store, bus, settings.queue_max) if bus is not None else None
    keys = KeyExpressions(settings.zenoh_prefix)
    sweeps = SweepRunner(store, queue, bus, keys) if bus is not None and queue is not None else None

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        from starlette.concurrency import run_in_threadpool

        await run_in_threadpool(reconcile, store, bus)
        if settings.learn_warm_up:
            learners.warm_up()
        if queue is not None:
            queue.start()
        if sweeps is not None:
            sweeps.start()
        yield
        if sweeps is not None:
            sweeps.close()
        if queue is not None:
            queue.close()
        learners.close()
        if own_store:
            store.close()

    app = FastAPI(
        title="Contact Skills",
        version=package_version(),
        description="Learn robot contact skills (slide, contour) from one demonstration and execute them with a "
        "hybrid impedance/force controller in a PyBullet simulation. Telemetry streams over Zenoh.",
        lifespan=lifespan,
        docs_url=None,  # served offline by install_offline_docs
        redoc_url=None,
    )
    app.state.store = store
    app.state.bus = bus
    app.state.settings = settings
    app.state.keys = keys
    app.state.learners = learners
    app.state.queue = queue
    app.state.sweeps = sweeps
    app.state.started_unix_s = time.time()
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "DELETE"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(
        BrowserGuard, allowed_origins=settings.cors_origins, loopback_only=settings.host in LOOPBACK_NAMES
    )
    install_error_handlers(app)
    app.include_router(api_router)
    install_offline_docs(app)
    return app
