"""An embedded Zenoh router (the eclipse-zenoh package in ``mode: router``): no separate router binary needed.

``EmbeddedRouter(listen)`` is a context manager (``with EmbeddedRouter(["tcp/127.0.0.1:7447"]): ...``) used by
``contact-skills up`` and the tests; ``run_router(listen)`` blocks until SIGINT/SIGTERM
(``contact-skills router``). Multicast scouting is off: clients reach the router by its endpoints only.
The default listens on loopback only; use ``tcp/0.0.0.0:7447`` (or the docker-compose router) to serve a network.
"""

from __future__ import annotations

import logging
import os
import signal
import threading

from schemas.bus import DEFAULT_ENDPOINT, ENV_LISTEN, split_endpoints

log = logging.getLogger("contact_skills.router")


def listen_from_env() -> list[str]:
    """``CONTACT_SKILLS_ZENOH_LISTEN`` (comma-separated) or the default ``tcp/127.0.0.1:7447``."""
    return split_endpoints(os.environ.get(ENV_LISTEN)) or [DEFAULT_ENDPOINT]


class EmbeddedRouter:
    """A Zenoh router session in this process, listening on ``listen`` from ``start()`` (or ``__enter__``)."""

    def __init__(self, listen: list[str] | None = None) -> None:
        self.listen = list(listen or [DEFAULT_ENDPOINT])
        self._session = None

    @property
    def running(self) -> bool:
        return self._session is not None

    def start(self) -> EmbeddedRouter:
        """Open the router session; raises ``ConnectionError`` if an endpoint cannot be bound (port in use)."""
        from services.bus import open_session

        if self._session is None:
            self._session = open_session("router", listen=self.listen)
            log.info("zenoh router listening on %s", ", ".join(self.listen))
        return self

    def close(self) -> None:
        """Close the router session (idempotent); connected clients lose their connection."""
        if self._session is not None:
            session, self._session = self._session, None
            session.close()
            log.info("zenoh router stopped")

    def __enter__(self) -> EmbeddedRouter:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_router(listen: list[str]) -> None:
    """Run a router on ``listen`` until SIGINT or SIGTERM."""
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: stop.set())
    try:
        with EmbeddedRouter(listen):
            while not stop.wait(0.5):
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
