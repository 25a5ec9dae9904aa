"""Shared test constants and helpers: the real data the tests read lives inside the repository (``data/``); a live
API served by uvicorn on a free loopback port."""

from __future__ import annotations

import threading
import time

from cli.main import repository_data_directory
from services.local_processes import free_port

KULEUVEN_DATA = repository_data_directory() / "kuleuven_contour"
"""The KU Leuven contour recordings vendored in the repository (``data/kuleuven_contour``, MIT licence)."""


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
