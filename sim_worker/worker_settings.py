"""A sim worker's settings (where it connects, under which prefix, its login, job budget and default engine:
:class:`WorkerSettings`, from the environment), the shared folder of worker logins it claims one of
(:func:`claim_login`), and its session on the bus (:func:`opened_session`)."""

from __future__ import annotations

import json
import logging
import os
import secrets
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from schemas.bus import DEFAULT_ENDPOINT, DEFAULT_PREFIX, ENV_ENDPOINTS, ENV_PREFIX, session_config, split_endpoints
from schemas.bus_security import ENV_LOGINS, BusSecurity, parse_env
from schemas.execution import DEFAULT_ENGINE, Engine
from schemas.job_budget import JobBudget

log = logging.getLogger("contact_skills.worker")

ENV_ENGINE = "CONTACT_SKILLS_ENGINE"
"""The worker's default engine (``pybullet`` or ``mujoco``): the one an execution that names none runs on."""


def engine_from_env(value: str | None) -> Engine:
    """The engine ``value`` (the variable :data:`ENV_ENGINE`) names; unset or empty: :data:`DEFAULT_ENGINE`. Raises
    ValueError naming the variable and the engines for another value."""
    if not value:
        return DEFAULT_ENGINE
    try:
        return Engine(value.strip().lower())
    except ValueError:
        known = ", ".join(e.value for e in Engine)
        raise ValueError(f"{ENV_ENGINE}={value!r}: not an engine (give one of {known})") from None


@dataclass
class WorkerSettings:
    """Where the worker connects and under which prefix (env: ``CONTACT_SKILLS_ZENOH_ENDPOINTS``, ``..._PREFIX``)."""

    endpoints: list[str] = field(default_factory=lambda: [DEFAULT_ENDPOINT])
    prefix: str = DEFAULT_PREFIX
    connect_retry_s: float = 1.0
    """Pause between attempts while the router is not reachable, s."""
    connect_timeout_s: float | None = None
    """Give up connecting after this long (None: keep trying until a signal arrives), s."""
    security: BusSecurity = field(default_factory=BusSecurity)
    """Login and TLS (``schemas.bus_security``); with a login the worker's id is its user name."""
    budget: JobBudget = field(default_factory=JobBudget)
    """The most one execution or recording may imply (``schemas.job_budget``): a job over it is refused, a job that
    reaches it while running is aborted."""
    login_claim: Path | None = None
    """The claim this worker holds on a login of a shared folder (``CONTACT_SKILLS_ZENOH_LOGINS``, :func:`claim_login`):
    renewed while it runs, released when it stops."""
    engine: Engine = DEFAULT_ENGINE
    """The engine an execution that names none runs on (``ExecutionSettings.engine`` absent; env
    ``CONTACT_SKILLS_ENGINE``, ``contact-skills worker --engine``); one that names an engine runs on it."""

    @classmethod
    def from_env(cls) -> WorkerSettings:
        """Settings from the environment, defaults for what is not set. With ``CONTACT_SKILLS_ZENOH_LOGINS`` (a folder
        of ``worker-K.env`` files) the worker claims a login no other live worker holds. Raises ValueError for an
        unknown engine (:data:`ENV_ENGINE`)."""
        env, claim = dict(os.environ), None
        engine = engine_from_env(env.get(ENV_ENGINE))
        if logins := env.get(ENV_LOGINS):
            claim, login = claim_login(Path(logins), socket.gethostname())
            env.update(login)
        return cls(
            endpoints=split_endpoints(env.get(ENV_ENDPOINTS)) or [DEFAULT_ENDPOINT],
            prefix=env.get(ENV_PREFIX) or DEFAULT_PREFIX,
            security=BusSecurity.from_env(env),
            budget=JobBudget.from_env(os.environ),
            login_claim=claim,
            engine=engine,
        )


LOGIN_LEASE_S = 30.0
"""A worker's claim on a shared login (:func:`claim_login`) lapses when not renewed for this long, s: the login of a
container that was removed (``--scale`` down) is free again; a running worker renews its claim every few seconds."""


def claim_login(folder: Path, holder: str) -> tuple[Path, dict[str, str]]:
    """Claim one of the ``worker-K.env`` logins of ``folder`` for ``holder`` (this container's host name, stable
    across its restarts): the one it held before, else the first that no one holds or whose claim lapsed
    (:data:`LOGIN_LEASE_S`). Claims are files ``folder/claims/worker-K`` holding the holder's name, made with
    ``O_EXCL`` (two workers starting at once never get the same login). Returns (the claim, the login's variables).
    Raises ValueError when every login is held."""
    claims = folder / "claims"
    claims.mkdir(exist_ok=True)
    logins = sorted(folder.glob("worker-*.env"), key=lambda f: int(f.stem.rsplit("-", 1)[1]))
    for prefer_own in (True, False):
        for login in logins:
            claim = claims / login.stem
            try:
                descriptor = os.open(claim, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
            except FileExistsError:
                try:
                    owner, age = claim.read_text(), time.time() - claim.stat().st_mtime
                except FileNotFoundError:
                    continue
                if owner != holder and (prefer_own or age < LOGIN_LEASE_S):
                    continue
                taken = claims / f".{login.stem}.{holder}"
                taken.write_text(holder)
                os.replace(taken, claim)  # a lapsed claim: whoever replaced it last holds it, the others go on
                time.sleep(0.2)
                if claim.read_text() != holder:
                    continue
            else:
                if prefer_own:  # the first pass only looks for this holder's own claim
                    os.close(descriptor)
                    claim.unlink()
                    continue
                with os.fdopen(descriptor, "w") as out:
                    out.write(holder)
            return claim, parse_env(login.read_text())
    raise ValueError(f"no free worker login in {folder}: all {len(logins)} are held by live workers (make more with "
                     "`contact-skills bus-keys --workers N`)")  # fmt: skip


def default_worker_id() -> str:
    """``worker-<6 random hex digits>`` for a worker without a login or ``--id``: unique enough on one bus, and
    naming neither the host nor the process (the id shows on the open ``/health`` and ``GET /executions``)."""
    return f"worker-{secrets.token_hex(3)}"


def opened_session(settings: WorkerSettings, stop: threading.Event | None = None) -> Any | None:
    """A Zenoh session (client mode) on ``settings``' endpoints, retried every ``connect_retry_s`` while the router is
    not reachable (one warning); None once ``stop`` is set or ``connect_timeout_s`` has passed."""
    import zenoh

    config = zenoh.Config.from_json5(
        json.dumps(session_config("client", connect=settings.endpoints, security=settings.security))
    )
    deadline = None if settings.connect_timeout_s is None else time.time() + settings.connect_timeout_s
    warned = False
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            if not warned:
                log.warning("router not reachable at %s (%s); retrying", settings.endpoints, exc)
                warned = True
            if (stop is not None and stop.wait(settings.connect_retry_s)) or (
                deadline is not None and time.time() > deadline
            ):
                return None
            if stop is None:
                time.sleep(settings.connect_retry_s)
