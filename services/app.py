"""The REST service (docs/SERVICE.md, docs/API.md): FastAPI routes over the SQLite store and the Zenoh bus client.

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
- ``services/foxglove_live.py``: the Foxglove WebSocket server of the live execution (with a bus; ``/health`` gives
  its URL); ``services/dashboard/``: the browser dashboard served at ``/``;
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
from services.api.browser_guard import BrowserGuard
from services.api.docs import install_offline_docs
from services.api.errors import install_error_handlers
from services.api.limits import ClientCaps
from services.api.main import api_router
from services.api.openapi import install_truthful_openapi
from services.bus_events import BusEvents, connect_bus, reconcile
from services.foxglove_live import live_view
from services.learner_pool import LearnerPool
from services.queue import ExecutionQueue
from services.retention import Retention
from services.settings import ServiceSettings, package_version
from services.store import Store
from services.sweeps import SweepRunner

if TYPE_CHECKING:
    import uvicorn

    from services.bus import BusClient

__all__ = ["BusEvents", "connect_bus", "create_app"]


def server_config(app: FastAPI, settings: ServiceSettings, log_level: str = "info") -> uvicorn.Config:
    """uvicorn's configuration of ``app`` with the connection limits of ``settings``: a request head within
    ``header_timeout_s`` and of at most ``services.http_rules.MAX_HEAD_BYTES`` (431), a body within
    ``body_timeout_s`` of its head (408) (``services.api.limits.BoundedH11Protocol``), idle keep-alive connections
    closed after ``keep_alive_s``, at most ``max_connections`` connections and requests at once (uvicorn answers 503
    past it; a new connection closes those waiting longest on their client first)."""
    import uvicorn

    from services.api.limits import bounded_protocol

    return uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level=log_level,
        access_log=False,
        http=bounded_protocol(settings.header_timeout_s, settings.body_timeout_s),
        timeout_keep_alive=max(1, round(settings.keep_alive_s)),
        limit_concurrency=settings.max_connections,
    )


def serve_api(app: FastAPI, settings: ServiceSettings, log_level: str) -> None:
    """Serve ``app`` with uvicorn until SIGINT/SIGTERM, with the connection limits of :func:`server_config`; and
    every log line of a kind at most once per ``services.log_limits.LOG_EVERY_S``."""
    import logging

    import uvicorn

    from services.log_limits import RateLimitFilter

    server = uvicorn.Server(server_config(app, settings, log_level))  # configures uvicorn's loggers: filter after
    limit = RateLimitFilter()
    for name in ("", "uvicorn", "uvicorn.error", "contact_skills"):
        for handler in logging.getLogger(name).handlers:
            handler.addFilter(limit)
    server.run()


def create_app(settings: ServiceSettings, bus: BusClient | None = None, store: Store | None = None) -> FastAPI:
    """The FastAPI app. ``bus``: a connected `services.bus.BusClient` whose callbacks are a :class:`BusEvents`
    on the same store (see :func:`connect_bus`), or None (executions and recordings then get 503).
    ``store``: the open store; default: opened from ``settings.db_path`` and closed with the app."""
    own_store = store is None
    store = store if store is not None else Store(settings.db_path)
    learners = LearnerPool(settings.learn_processes, settings.learn_timeout_s, settings.learn_memory_mb)
    queue = None
    if bus is not None:
        queue = ExecutionQueue(
            store,
            bus,
            settings.queue_max,
            first_report_s=settings.dispatch_report_s,
            silence_s=settings.run_silence_s,
            handovers=settings.dispatch_handovers,
            quota_bytes=settings.storage_quota_bytes,
        )
    keys = KeyExpressions(settings.zenoh_prefix)
    sweeps = SweepRunner(store, queue, bus, keys) if bus is not None and queue is not None else None
    foxglove = live_view(store, settings) if bus is not None else None  # the live view: with a bus
    retention = Retention(store, settings.retention_days) if settings.retention_days > 0 else None

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
        if foxglove is not None:
            foxglove.start()
        if retention is not None:
            retention.start()
        yield
        if retention is not None:
            retention.close()
        if foxglove is not None:
            foxglove.close()
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
    app.state.client_caps = ClientCaps(store, settings.client_queued_max, settings.client_sweeps_max)
    app.state.foxglove = foxglove
    app.state.started_unix_s = time.time()
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "DELETE"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(BrowserGuard, allowed_origins=settings.cors_origins, host_names=settings.host_names)
    install_error_handlers(app)
    app.include_router(api_router)
    install_offline_docs(app)
    install_truthful_openapi(app, settings)
    return app
