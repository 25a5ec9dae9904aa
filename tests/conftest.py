"""Shared test constants and helpers: the real data the tests read lives inside the repository (``data/``); the API
in-process (``client``: no bus; ``bus_client``: a fake bus the test drives, `FakeBus`) and served by uvicorn on a free
loopback port (`LiveApi`)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest
from threadpoolctl import threadpool_limits

from schemas.bus import RecordReply, RecordRequest, WorkerInfo
from services.datasets import repository_data_directory
from services.dispatch_watch import DispatchWatch
from services.local_processes import THREAD_LIMIT_ENV, free_port

# One BLAS/OpenMP thread per test process and its children, as the product runs its own processes
# (`THREAD_LIMIT_ENV`): `make test` runs two test processes on two cores, and a BLAS thread per core in each made a
# least-squares fit of a DMP 1.7 s instead of 0.06 s at load 6 (each library's threads wait on one another's core).
# Tests that prove the product sets these limits itself remove them from their children's environment.
os.environ.update(THREAD_LIMIT_ENV)
threadpool_limits(1)

KULEUVEN_DATA = repository_data_directory() / "kuleuven_contour"
"""The KU Leuven contour recordings vendored in the repository (``data/kuleuven_contour``, MIT licence)."""

README_CF_Z_TOOL = (0.03, 0.65, 0.77)
"""The KU Leuven README's contact force direction in the TCP frame (measured on the tool, the middle of its ranges),
negated: the direction the tool applies, which a contour's CF z follows (not unit)."""


class LiveApi:
    """``app`` served by uvicorn on a free loopback port, in a thread of this process (``with LiveApi(app) as api``:
    ``api.url``)."""

    def __init__(self, app) -> None:
        import uvicorn

        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> LiveApi:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            assert time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(30)


class FakeBus:
    """The `BusClient` interface; the test drives the callbacks."""

    def __init__(self, on_status, on_telemetry, on_worker_lost, workers: int = 1) -> None:
        self.on_status, self.on_telemetry, self.on_worker_lost = on_status, on_telemetry, on_worker_lost
        self.infos = [WorkerInfo(worker_id=f"w{k}", busy=False) for k in range(workers)]
        self.started: list[tuple[str, object]] = []
        self.commands: list[tuple[str, str]] = []
        self.recorded: RecordReply | None = None
        self.replays: list[tuple[str, str, int, int]] = []
        self.watch = DispatchWatch()

    def workers(self) -> list[WorkerInfo]:
        return list(self.infos)

    workers_seen = workers

    def seen_age(self) -> float:
        return 0.0

    def start_execution(self, execution_id, request, **options) -> str:
        from services.bus import NoWorkerAvailable

        if not self.infos:
            raise NoWorkerAvailable("no worker")
        assert request.skill is not None and request.skill_id is None
        self.started.append((execution_id, request))
        return self.infos[0].worker_id

    def latest_statuses(self) -> dict:
        return {}

    def telemetry_replay(self, worker_id: str, execution_id: str, start: int, stop: int) -> list:
        """A worker that keeps none of the telemetry asked for (it dropped it, or restarted)."""
        self.replays.append((worker_id, execution_id, start, stop))
        return []

    def send_command(self, execution_id, command, reason=None) -> None:
        self.commands.append((execution_id, command))

    def record_demonstration(self, request: RecordRequest, timeout_s: float = 120) -> RecordReply:
        assert self.recorded is not None
        return self.recorded

    def close(self) -> None:
        pass


def loopback_client(app, **options):
    """A test client addressing the loopback API by a loopback name (the Host check refuses others)."""
    from fastapi.testclient import TestClient

    return TestClient(app, base_url="http://127.0.0.1", **options)


def api_settings(tmp_path: Path, **changes):
    """Service settings on a database in ``tmp_path``."""
    from services.settings import ServiceSettings

    return ServiceSettings(db_path=tmp_path / "api.db", **changes)


@pytest.fixture
def client(tmp_path):
    from services.app import create_app

    with loopback_client(create_app(api_settings(tmp_path), bus=None)) as c:
        yield c


@pytest.fixture
def bus_client(tmp_path):
    from services.app import BusEvents, create_app
    from services.store import Store

    store = Store(tmp_path / "api.db")
    events = BusEvents(store)
    bus = events.bus = FakeBus(events.on_status, events.on_telemetry, events.on_worker_lost)
    with loopback_client(create_app(api_settings(tmp_path), bus=bus, store=store)) as c:
        c.bus = bus
        yield c
    store.close()
