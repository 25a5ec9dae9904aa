"""The bus's sessions and queries, as the API side opens and asks them (``services.bus``): how it reaches the bus
(:class:`BusSettings`, :func:`open_session`, the read-only :func:`observer_login`), and the queries every part of
``BusClient`` makes (:class:`BusQueries`: every valid reply, or one worker's first)."""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from schemas.bus import (
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    ENV_ENDPOINTS,
    ENV_PREFIX,
    CommandName,
    ExecutionCommand,
    KeyExpressions,
    session_config,
    split_endpoints,
)
from schemas.bus_security import ENV_LOGINS, ENV_PASSWORD, ENV_USER, BusSecurity
from services.bus_keys import local_logins_folder, read_env_file
from services.bus_reports import ReportChecks
from services.dispatch_watch import DispatchWatch
from services.worker_liveness import WorkerLiveness

log = logging.getLogger("contact_skills.bus")  # rate-limited: services.bus_reports adds the filter


@dataclass
class BusSettings:
    """How the API reaches the bus. ``from_env`` reads ``CONTACT_SKILLS_ZENOH_ENDPOINTS`` (comma-separated) and
    ``CONTACT_SKILLS_ZENOH_PREFIX``."""

    endpoints: list[str] = field(default_factory=lambda: [DEFAULT_ENDPOINT])
    """Router endpoints to connect to."""
    prefix: str = DEFAULT_PREFIX
    mode: str = "client"
    connect_timeout_s: float = 30.0
    """How long ``BusClient()`` keeps trying to reach the router before raising ``ConnectionError``, s."""
    security: BusSecurity | None = None
    """Login and TLS (None: from the environment, ``schemas.bus_security``)."""
    report_key: bytes = field(default_factory=lambda: secrets.token_bytes(32))
    """The key every execution's secret is derived from (:meth:`.ReportChecks.execution_secret`): the API keeps its own
    in its database (``services.store.Store.service_key``), so the executions it adopts after a restart verify."""

    @classmethod
    def from_env(cls) -> BusSettings:
        return cls(
            endpoints=split_endpoints(os.environ.get(ENV_ENDPOINTS)) or [DEFAULT_ENDPOINT],
            prefix=os.environ.get(ENV_PREFIX) or DEFAULT_PREFIX,
        )


@dataclass(frozen=True)
class Reply:
    """One valid reply of a query: its payload as ``model``, its key, its exact bytes and its attachment."""

    value: Any
    key: str
    payload: bytes
    signature: bytes | None


def attachment_bytes(zbytes: Any) -> bytes | None:
    return None if zbytes is None else zbytes.to_bytes()


def observer_login(endpoints: list[str]) -> dict[str, str] | None:
    """The bus's read-only ``observer`` login (``{"user": …, "password": …}``), or None: the one in the folder of
    logins ``CONTACT_SKILLS_ZENOH_LOGINS`` (docker-compose), else that of the ``contact-skills up`` of this user that
    serves one of ``endpoints`` on loopback (``services.bus_keys.local_logins_folder``)."""
    folders = [Path(os.environ[ENV_LOGINS])] if os.environ.get(ENV_LOGINS) else []
    for endpoint in endpoints:
        protocol, _, address = endpoint.partition("/")
        host, _, port = address.rpartition(":")
        if protocol == "tcp" and host in ("127.0.0.1", "localhost") and port.isdigit():
            folders.append(local_logins_folder(int(port)))
    for folder in folders:
        login = folder / "observer.env"
        if login.is_file():
            values = read_env_file(login)
            return {"user": values[ENV_USER], "password": values[ENV_PASSWORD]}
    return None


def open_session(
    mode: str,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    wait_s: float = 0.0,
    security: BusSecurity | None = None,
    access_control: dict[str, Any] | None = None,
):
    """Open a Zenoh session with the bus configuration (``schemas.bus.session_config``).

    ``security`` None: the login and TLS settings of the environment (``schemas.bus_security``; none: an open bus).
    A client retries for ``wait_s`` seconds while no router answers (or it refuses the login), then raises
    ``ConnectionError``.
    """
    import zenoh

    if security is None:
        logins = os.environ.get(ENV_LOGINS)  # docker-compose: the API's login in its folder of logins
        api_env = Path(logins or ".") / "api.env"
        api_login = read_env_file(api_env) if logins and mode == "client" and api_env.is_file() else {}
        security = BusSecurity.from_env({**os.environ, **api_login})
    if mode == "client" and security.user is None and (observer := observer_login(connect or [])):
        security = replace(security, **observer)  # how `watch`, `live()` and this user's sessions read the bus
    config = zenoh.Config.from_json5(
        json.dumps(session_config(mode, connect, listen, security, access_control))  # type: ignore[arg-type]
    )
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            if time.monotonic() >= deadline:
                where = f"connect to {connect}" if connect else f"listen on {listen}"
                within = f" within {wait_s:g} s" if wait_s else ""
                raise ConnectionError(f"zenoh ({mode}) could not {where}{within}: {_reason(exc)}") from exc
            log.warning("zenoh (%s) could not connect to %s; retrying", mode, connect)
            time.sleep(0.5)


def _reason(error: Exception) -> str:
    """A Zenoh error's message without the Rust source location it ends with (`` at /root/.cargo/...rs:388.``), which
    says nothing to a user."""
    return re.sub(r"\s+at \S+\.rs:\d+\.?$", "", str(error).strip())


class BusQueries:
    """What ``BusClient`` asks and puts on its session: queries to the workers' queryables, commands, publications."""

    # The state BusClient.__init__ (services.bus) sets and every part of it shares.
    settings: BusSettings
    keys: KeyExpressions
    reports: ReportChecks
    watch: DispatchWatch
    liveness: WorkerLiveness
    _session: Any
    _lock: threading.Lock
    _closed: bool

    def _ask_all(self, key: str, model: type[Any], timeout_s: float, payload: bytes | None = None) -> list[Reply]:
        """Every valid reply (its payload as ``model``) of every queryable on ``key`` to a query carrying
        ``payload``; bad replies are logged and skipped."""
        import zenoh

        answers = []
        replies = self._session.get(key, payload=payload, timeout=timeout_s, consolidation=zenoh.ConsolidationMode.NONE)
        for reply in replies:
            if reply.ok is None:
                continue
            payload = reply.ok.payload.to_bytes()
            try:
                value = model.model_validate_json(payload)
            except ValueError:
                log.warning("bad %s on %s", model.__name__, reply.ok.key_expr)
                continue
            answers.append(Reply(value, str(reply.ok.key_expr), payload, attachment_bytes(reply.ok.attachment)))
        return answers

    def send_command(self, execution_id: str, command: CommandName, reason: str | None = None) -> None:
        """Publish ``command`` to the execution (fire and forget; its status tells what happened); ``reason``: what
        an abort's final status says (default: aborted on request)."""
        import zenoh

        message = ExecutionCommand(command=command, execution_id=execution_id, reason=reason)
        self._session.put(
            self.keys.cmd(execution_id),
            message.model_dump_json(),
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.INTERACTIVE_HIGH,
            express=True,
        )

    def publish(self, key: str, payload: str) -> None:
        """Put ``payload`` (JSON) on ``key`` (reliable; e.g. a sweep's progress, ``KeyExpressions.sweep_progress``)."""
        import zenoh

        self._session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def _query_one(self, key: str, payload: str, timeout_s: float, attachment: bytes | None = None) -> bytes | None:
        """The first OK reply's payload of a query to one worker's queryable, or None (no reply, error reply)."""
        for reply in self._session.get(key, payload=payload, timeout=timeout_s, attachment=attachment):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
            log.warning("error reply on %s: %s", key, reply.err.payload.to_string() if reply.err else "?")
        return None
