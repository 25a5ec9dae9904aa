"""An embedded Zenoh router (the eclipse-zenoh package in ``mode: router``): no separate router binary needed.

``EmbeddedRouter(listen)`` is a context manager (``with EmbeddedRouter(["tcp/127.0.0.1:7447"]): ...``) used by
``contact-skills up`` and the tests; ``run_router(listen)`` blocks until SIGINT/SIGTERM
(``contact-skills router``). Multicast scouting is off: clients reach the router by its endpoints only.
The default listens on loopback only; use ``tcp/0.0.0.0:7447`` (or the docker-compose router) to serve a network.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from schemas.bus import DEFAULT_ENDPOINT, DEFAULT_PREFIX, ENV_LISTEN, split_endpoints
from schemas.bus_security import BusSecurity, BusUser, access_control, parse_users

log = logging.getLogger("contact_skills.router")


def read_users(path: str | Path) -> list[BusUser]:
    """The router's users file at ``path`` (``schemas.bus_security.parse_users`` says what it holds)."""
    return parse_users(Path(path).read_text(), str(path))


def listen_from_env() -> list[str]:
    """``CONTACT_SKILLS_ZENOH_LISTEN`` (comma-separated) or the default ``tcp/127.0.0.1:7447``."""
    return split_endpoints(os.environ.get(ENV_LISTEN)) or [DEFAULT_ENDPOINT]


class EmbeddedRouter:
    """A Zenoh router session in this process, listening on ``listen`` from ``start()`` (or ``__enter__``).

    ``security`` (`schemas.bus_security.BusSecurity`): with a ``users_file`` the router requires a login and applies
    the access control of ``schemas.bus_security.access_control`` for ``prefix``; with ``tls_cert``/``tls_key`` it
    serves ``tls/`` endpoints. None: an open router."""

    def __init__(
        self, listen: list[str] | None = None, security: BusSecurity | None = None, prefix: str = DEFAULT_PREFIX
    ) -> None:
        self.listen = list(listen or [DEFAULT_ENDPOINT])
        self.security = security or BusSecurity()
        self.prefix = prefix
        self._session = None
        self._dictionary: Path | None = None

    @property
    def running(self) -> bool:
        return self._session is not None

    def start(self) -> EmbeddedRouter:
        """Open the router session; raises ``ConnectionError`` if an endpoint cannot be bound (port in use)."""
        from services.bus import open_session

        if self._session is None:
            security, access = self.security, None
            if security.users_file:
                users = read_users(security.users_file)
                security = replace(security, users_file=str(self._zenoh_dictionary(users)))
                access = access_control(self.prefix, users)
            self._session = open_session("router", listen=self.listen, security=security, access_control=access)
            guarded = f", login required ({len(access['subjects'])} subjects)" if access else ""
            log.info("zenoh router listening on %s%s", ", ".join(self.listen), guarded)
        return self

    def _zenoh_dictionary(self, users: list[BusUser]) -> Path:
        """The users as Zenoh's ``user:password`` dictionary, in a file only this user can read (removed on close)."""
        descriptor, name = tempfile.mkstemp(prefix="cskills-zenoh-users-", suffix=".txt")
        with os.fdopen(descriptor, "w") as out:
            out.writelines(f"{u.user}:{u.password}\n" for u in users)
        self._dictionary = Path(name)
        return self._dictionary

    def close(self) -> None:
        """Close the router session (idempotent); connected clients lose their connection."""
        if self._session is not None:
            session, self._session = self._session, None
            session.close()
            log.info("zenoh router stopped")
        if self._dictionary is not None:
            self._dictionary.unlink(missing_ok=True)
            self._dictionary = None

    def __enter__(self) -> EmbeddedRouter:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextlib.contextmanager
def local_router(port: int, workers: int, prefix: str, open_bus: bool = False) -> Iterator[dict[str, dict[str, str]]]:
    """The router of ``contact-skills up`` on ``tcp/127.0.0.1:PORT``, running inside the block, secured by default.

    Fresh logins (``services.bus_keys.make_local_logins``: ``api``, ``worker-1`` .. ``worker-N``, ``observer``, random
    passwords, in a folder of this user's removed on exit) and the access control of
    ``schemas.bus_security.access_control``: an anonymous local process cannot even open a session, the observer
    login (which this user's ``watch`` and ``live()`` find by the port) only reads. Yields each login's environment
    variables by login name (the children of ``up`` are named after theirs). ``open_bus`` (development only): an
    open router, no logins (yields {})."""
    from services.bus_keys import make_local_logins

    listen = [f"tcp/127.0.0.1:{port}"]
    if open_bus:
        with EmbeddedRouter(listen, prefix=prefix):
            yield {}
        return
    folder, logins = make_local_logins(port, workers)
    try:
        with EmbeddedRouter(listen, BusSecurity(users_file=str(folder / "users.txt")), prefix):
            yield logins
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run_router(listen: list[str], security: BusSecurity | None = None, prefix: str = DEFAULT_PREFIX) -> None:
    """Run a router on ``listen`` until SIGINT or SIGTERM (``security``, ``prefix``: see :class:`EmbeddedRouter`)."""
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: stop.set())
    try:
        with EmbeddedRouter(listen, security, prefix):
            while not stop.wait(0.5):
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
