"""Settings of the REST service: defaults, then environment variables, then command-line flags.

| setting | env var | default |
| --- | --- | --- |
| host | ``CONTACT_SKILLS_HOST`` | ``127.0.0.1`` (loopback only; set ``0.0.0.0`` inside a container) |
| port | ``CONTACT_SKILLS_PORT`` | ``8000`` |
| db_path | ``CONTACT_SKILLS_DB`` | ``./contact_skills.db``; ``./contact_skills_<port>.db`` on another port |
| token | ``CONTACT_SKILLS_TOKEN`` | none: POST/DELETE are open; set it to require ``Authorization: Bearer <token>`` |
| max_body_mb | ``CONTACT_SKILLS_MAX_BODY_MB`` | ``64`` (MiB; a larger request body gets 413) |
| workers | ``CONTACT_SKILLS_WORKERS`` | ``1`` (sim worker processes started by ``contact-skills up``) |
| zenoh_endpoints | ``CONTACT_SKILLS_ZENOH_ENDPOINTS`` | ``tcp/127.0.0.1:7447`` (comma separated) |
| zenoh_prefix | ``CONTACT_SKILLS_ZENOH_PREFIX`` | ``cskills`` |
| connect_timeout_s | ``CONTACT_SKILLS_CONNECT_TIMEOUT_S`` | ``30`` (s the API waits for the router) |
| token_reads | ``CONTACT_SKILLS_TOKEN_READS`` | ``false``; ``true``: GETs need the token too (``/health`` stays open) |
| cors_origins | ``CONTACT_SKILLS_CORS_ORIGINS`` | none: no cross-origin browser request (comma-separated origins) |
| learn_processes | ``CONTACT_SKILLS_LEARN_PROCESSES`` | the number of CPUs (learner processes of ``POST /skills``) |
| learn_timeout_s | ``CONTACT_SKILLS_LEARN_TIMEOUT_S`` | ``120`` (CPU-time budget of one learning job, s) |
| queue_max | ``CONTACT_SKILLS_QUEUE_MAX`` | ``1000`` (executions waiting for a worker at most; more get 503) |
| learn_memory_mb | ``CONTACT_SKILLS_LEARN_MEMORY_MB`` | ``4096`` (address space of a learner process, MiB; 0: none) |
| job_max_simulated_s | ``CONTACT_SKILLS_JOB_MAX_SIMULATED_S`` | ``1800`` (longest simulated time of one job, s) |
| job_max_steps | ``CONTACT_SKILLS_JOB_MAX_STEPS`` | ``2000000`` (most control steps of one job) |
| telemetry_page_samples | ``CONTACT_SKILLS_TELEMETRY_PAGE_SAMPLES`` | ``20000`` (samples per telemetry response) |
| allowed_hosts | ``CONTACT_SKILLS_ALLOWED_HOSTS`` | none (``Host`` names besides loopback, bind address, host name) |
| header_timeout_s | ``CONTACT_SKILLS_HEADER_TIMEOUT_S`` | ``10`` (s a connection has to send a whole request head) |
| body_timeout_s | ``CONTACT_SKILLS_BODY_TIMEOUT_S`` | ``60`` (s a request has for its whole body after its head; 408) |
| keep_alive_s | ``CONTACT_SKILLS_KEEP_ALIVE_S`` | ``5`` (s an idle keep-alive connection is kept) |
| max_connections | ``CONTACT_SKILLS_MAX_CONNECTIONS`` | ``256`` (connections at once; idle ones make way, else 503) |
| client_queued_max | ``CONTACT_SKILLS_CLIENT_QUEUED_MAX`` | ``100`` (a client's queued or running executions; 429) |
| client_sweeps_max | ``CONTACT_SKILLS_CLIENT_SWEEPS_MAX`` | ``2`` (sweeps one client may have running; more get 429) |
| storage_quota_mb | ``CONTACT_SKILLS_STORAGE_QUOTA_MB`` | ``4096`` (MiB stored and reserved by runs, at most; 507) |
| retention_days | ``CONTACT_SKILLS_RETENTION_DAYS`` | ``0`` (keep all; > 0: older finished runs deleted) |
| foxglove_port | ``CONTACT_SKILLS_FOXGLOVE_PORT`` | ``8765`` (the live view; ``0`` any free port; ``off``: none) |
| dispatch_report_s | ``CONTACT_SKILLS_DISPATCH_REPORT_S`` | ``10`` (s a worker has to report on a job it accepted) |
| run_silence_s | ``CONTACT_SKILLS_RUN_SILENCE_S`` | ``30`` (s a running job's worker may go without a report) |
| dispatch_handovers | ``CONTACT_SKILLS_DISPATCH_HANDOVERS`` | ``3`` (hand-overs of a job to silent workers) |

A job is one execution or recording; its budget (``schemas.job_budget``) is read from the same variables by the sim
workers, which hold every job they are sent to it too.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from schemas.job_budget import JobBudget

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
DEFAULT_DB = "contact_skills.db"
"""The database of the API on :data:`DEFAULT_PORT`; on another port, :func:`default_database` names it for the port."""
DEFAULT_MAX_BODY_MB = 64.0
DEFAULT_WORKERS = 1
DEFAULT_ZENOH_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_ZENOH_PREFIX = "cskills"
DEFAULT_STORAGE_QUOTA_MB = 4096.0
"""What the database may hold, MiB. Measured: a one-minute execution's 1 kHz telemetry takes ~8.4 MB (147 bytes a
sample), so about 120 of them fit in a GiB; a demonstration takes ~285 bytes a sample (the longest, 200 000 samples,
~57 MB)."""
DEFAULT_FOXGLOVE_PORT = 8765
DEFAULT_DISPATCH_REPORT_S = 10.0
"""How long a worker has to report on a job it accepted, s. Measured on the shared 2-core machine at load 6: a real
worker's first status arrived at most 0.03 s after its accept reply (10 runs; mostly before it), so this leaves a
margin of 300x for a loaded machine, while a worker that takes jobs and never reports holds each for 10 s only."""
DEFAULT_RUN_SILENCE_S = 30.0
"""How long a running job's worker may go without a report, s: a worker reports at least every
``schemas.bus.HEARTBEAT_S`` (2 s; the longest gap measured in a real-time run without telemetry at load 6: 2.00 s)."""
"""Foxglove's own default WebSocket port (what its "Open connection" dialog proposes)."""
FOXGLOVE_OFF = frozenset({"off", "none", "no", "false"})
"""Values of ``foxglove_port`` that turn the live view's server off."""
DEFAULT_TELEMETRY_PAGE_SAMPLES = 20_000
"""Most samples one ``GET /executions/{id}/telemetry`` returns (20 s at 1 kHz; ~11 MB of JSON, ~15 MB of the API's
memory while it streams): a longer run is read page by page (``cursor``)."""

ENV_VARIABLE_PREFIX = "CONTACT_SKILLS_"
ENV_VARS: dict[str, str] = {
    "host": "CONTACT_SKILLS_HOST",
    "port": "CONTACT_SKILLS_PORT",
    "db_path": "CONTACT_SKILLS_DB",
    "token": "CONTACT_SKILLS_TOKEN",
    "max_body_mb": "CONTACT_SKILLS_MAX_BODY_MB",
    "workers": "CONTACT_SKILLS_WORKERS",
    "zenoh_endpoints": "CONTACT_SKILLS_ZENOH_ENDPOINTS",
    "zenoh_prefix": "CONTACT_SKILLS_ZENOH_PREFIX",
    "connect_timeout_s": "CONTACT_SKILLS_CONNECT_TIMEOUT_S",
    "token_reads": "CONTACT_SKILLS_TOKEN_READS",
    "cors_origins": "CONTACT_SKILLS_CORS_ORIGINS",
    "learn_processes": "CONTACT_SKILLS_LEARN_PROCESSES",
    "learn_timeout_s": "CONTACT_SKILLS_LEARN_TIMEOUT_S",
    "learn_memory_mb": "CONTACT_SKILLS_LEARN_MEMORY_MB",
    "queue_max": "CONTACT_SKILLS_QUEUE_MAX",
    "job_max_simulated_s": "CONTACT_SKILLS_JOB_MAX_SIMULATED_S",
    "job_max_steps": "CONTACT_SKILLS_JOB_MAX_STEPS",
    "telemetry_page_samples": "CONTACT_SKILLS_TELEMETRY_PAGE_SAMPLES",
    "allowed_hosts": "CONTACT_SKILLS_ALLOWED_HOSTS",
    "header_timeout_s": "CONTACT_SKILLS_HEADER_TIMEOUT_S",
    "body_timeout_s": "CONTACT_SKILLS_BODY_TIMEOUT_S",
    "keep_alive_s": "CONTACT_SKILLS_KEEP_ALIVE_S",
    "max_connections": "CONTACT_SKILLS_MAX_CONNECTIONS",
    "client_queued_max": "CONTACT_SKILLS_CLIENT_QUEUED_MAX",
    "client_sweeps_max": "CONTACT_SKILLS_CLIENT_SWEEPS_MAX",
    "storage_quota_mb": "CONTACT_SKILLS_STORAGE_QUOTA_MB",
    "retention_days": "CONTACT_SKILLS_RETENTION_DAYS",
    "foxglove_port": "CONTACT_SKILLS_FOXGLOVE_PORT",
    "instance": "CONTACT_SKILLS_INSTANCE",
    "dispatch_report_s": "CONTACT_SKILLS_DISPATCH_REPORT_S",
    "run_silence_s": "CONTACT_SKILLS_RUN_SILENCE_S",
    "dispatch_handovers": "CONTACT_SKILLS_DISPATCH_HANDOVERS",
}
"""Setting name -> the environment variable that sets it."""


def default_database(port: int) -> Path:
    """The database an API on ``port`` uses unless told (``--db``, ``CONTACT_SKILLS_DB``): ``contact_skills.db`` on
    the default port, ``contact_skills_<port>.db`` on another, so that a second instance (``make run PORT=8001
    ZENOH_PORT=7448``) keeps its own records beside the first's and finds them again when restarted on its port."""
    if port == DEFAULT_PORT:
        return Path(DEFAULT_DB)
    stem, suffix = DEFAULT_DB.rsplit(".", 1)
    return Path(f"{stem}_{port}.{suffix}")


class SettingsError(ValueError):
    """An environment variable or flag holds a value the setting cannot take."""


def _endpoints(value: str | list[str]) -> list[str]:
    items = value.split(",") if isinstance(value, str) else value
    endpoints = [item.strip() for item in items if item.strip()]
    if not endpoints:
        raise SettingsError("zenoh_endpoints: give at least one endpoint, e.g. tcp/127.0.0.1:7447")
    return endpoints


def _flag(text: str) -> bool:
    """``1/true/yes/on`` or ``0/false/no/off`` (any case); ValueError otherwise."""
    value = text.strip().lower()
    if value in ("1", "true", "yes", "on"):
        return True
    if value in ("0", "false", "no", "off"):
        return False
    raise ValueError(text)


@dataclass(frozen=True)
class ServiceSettings:
    """Where the API listens, where it stores, how it reaches the Zenoh router (see the module table)."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    db_path: Path | None = None
    """The SQLite file; None: :func:`default_database` of :attr:`port` (a Path once made)."""
    token: str | None = None
    max_body_mb: float = DEFAULT_MAX_BODY_MB
    workers: int = DEFAULT_WORKERS
    zenoh_endpoints: list[str] = field(default_factory=lambda: [DEFAULT_ZENOH_ENDPOINT])
    zenoh_prefix: str = DEFAULT_ZENOH_PREFIX
    connect_timeout_s: float = 30.0
    token_reads: bool = False
    cors_origins: list[str] = field(default_factory=list)
    learn_processes: int = field(default_factory=lambda: os.cpu_count() or 1)
    learn_timeout_s: float = 120.0
    learn_memory_mb: int = 4096
    learn_warm_up: bool = True
    """Start the learner processes when the API starts (tests that never learn turn it off)."""
    queue_max: int = 1000
    job_max_simulated_s: float = field(default_factory=lambda: _default_budget().max_simulated_s)
    job_max_steps: int = field(default_factory=lambda: _default_budget().max_steps)
    telemetry_page_samples: int = DEFAULT_TELEMETRY_PAGE_SAMPLES
    allowed_hosts: list[str] = field(default_factory=list)
    """``Host`` names the API answers besides loopback names, its bind address and this host's name (a DNS-rebinding
    page's own name is refused on every bind)."""
    header_timeout_s: float = 10.0
    body_timeout_s: float = 60.0
    """s a request's whole body has to arrive in after its head: 64 MiB (the body limit) needs ~1.1 MB/s."""
    keep_alive_s: float = 5.0
    max_connections: int = 256
    client_queued_max: int = 100
    client_sweeps_max: int = 2
    storage_quota_mb: float = DEFAULT_STORAGE_QUOTA_MB
    retention_days: float = 0.0
    foxglove_port: str | None = None
    """The Foxglove live view's port as given (a number, ``0`` any free one, or ``off``); None: not given
    (:attr:`foxglove_server_port` decides)."""
    instance: str = field(default_factory=lambda: secrets.token_hex(8))
    """Names this API process in ``GET /health`` (``contact-skills up`` sets it to know its own API answers)."""
    dispatch_report_s: float = DEFAULT_DISPATCH_REPORT_S
    """A worker that accepted a job and sends no report on it (status, heartbeat, telemetry) within this loses it
    (``services.queue``'s watchdog), s."""
    run_silence_s: float = DEFAULT_RUN_SILENCE_S
    """A running job whose worker sends nothing for this long is failed, s (workers report at least every
    ``schemas.bus.HEARTBEAT_S``)."""
    dispatch_handovers: int = 3
    """Hand-overs of one job at most: taken back that many times from workers that did not report, it is failed."""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise SettingsError(f"port: {self.port} is not a TCP port (0-65535)")
        if not self.max_body_mb > 0:
            raise SettingsError(f"max_body_mb: {self.max_body_mb} must be > 0")
        if self.workers < 0:
            raise SettingsError(f"workers: {self.workers} must be >= 0")
        if self.connect_timeout_s < 0:
            raise SettingsError(f"connect_timeout_s: {self.connect_timeout_s} must be >= 0")
        if self.learn_processes < 1:
            raise SettingsError(f"learn_processes: {self.learn_processes} must be >= 1")
        if not self.learn_timeout_s > 0:
            raise SettingsError(f"learn_timeout_s: {self.learn_timeout_s} must be > 0")
        if self.queue_max < 1:
            raise SettingsError(f"queue_max: {self.queue_max} must be >= 1")
        if self.learn_memory_mb < 0:
            raise SettingsError(f"learn_memory_mb: {self.learn_memory_mb} must be >= 0 (0: no limit)")
        if not self.job_max_simulated_s > 0 or self.job_max_steps < 1:
            raise SettingsError(
                f"job budget: {self.job_max_simulated_s} s and {self.job_max_steps} steps must be > 0 s and >= 1 step"
            )
        if self.telemetry_page_samples < 1:
            raise SettingsError(f"telemetry_page_samples: {self.telemetry_page_samples} must be >= 1")
        if not (self.header_timeout_s > 0 and self.body_timeout_s > 0 and self.keep_alive_s > 0) or (
            self.max_connections < 1
        ):
            raise SettingsError(
                f"header_timeout_s {self.header_timeout_s}, body_timeout_s {self.body_timeout_s}, keep_alive_s "
                f"{self.keep_alive_s} must be > 0 s and max_connections {self.max_connections} >= 1"
            )
        if self.client_queued_max < 1 or self.client_sweeps_max < 1:
            raise SettingsError(
                f"client_queued_max {self.client_queued_max}, client_sweeps_max {self.client_sweeps_max}: must be >= 1"
            )
        if not (self.storage_quota_mb >= 0 and self.retention_days >= 0):
            raise SettingsError(
                f"storage_quota_mb {self.storage_quota_mb}, retention_days {self.retention_days}: must be >= 0 "
                "(0: no quota, keep all)"
            )
        if self.foxglove_port is not None:
            port = str(self.foxglove_port).strip().lower()
            if port not in FOXGLOVE_OFF and not (port.isdigit() and int(port) <= 65535):
                raise SettingsError(f"foxglove_port: {self.foxglove_port!r}: give a port number, 0 (any free port) "
                                    "or off")  # fmt: skip
            object.__setattr__(self, "foxglove_port", port)
        if not (self.dispatch_report_s > 0 and self.run_silence_s > 0) or self.dispatch_handovers < 1:
            raise SettingsError(
                f"dispatch_report_s {self.dispatch_report_s}, run_silence_s {self.run_silence_s} must be > 0 s and "
                f"dispatch_handovers {self.dispatch_handovers} >= 1"
            )
        if self.token_reads and not self.token:
            raise SettingsError("token_reads: set CONTACT_SKILLS_TOKEN too (there is no token to require)")
        cors = self.cors_origins.split(",") if isinstance(self.cors_origins, str) else self.cors_origins
        object.__setattr__(self, "cors_origins", [origin.strip() for origin in cors if origin.strip()])
        hosts = self.allowed_hosts.split(",") if isinstance(self.allowed_hosts, str) else self.allowed_hosts
        object.__setattr__(self, "allowed_hosts", [host.strip().lower() for host in hosts if host.strip()])
        object.__setattr__(self, "db_path", default_database(self.port) if self.db_path is None else Path(self.db_path))
        object.__setattr__(self, "zenoh_endpoints", _endpoints(self.zenoh_endpoints))
        object.__setattr__(self, "token", self.token or None)

    @property
    def job_budget(self) -> JobBudget:
        """The most one execution or recording may imply (``schemas.job_budget``)."""
        from schemas.job_budget import JobBudget

        return JobBudget(max_simulated_s=self.job_max_simulated_s, max_steps=self.job_max_steps)

    @property
    def host_names(self) -> frozenset[str]:
        """Every ``Host`` name the API answers: loopback names, the address it binds (unless all interfaces), this
        host's name (docker-compose: the container's) and ``allowed_hosts``."""
        import socket

        from services.http_rules import LOOPBACK_NAMES

        bound = set() if self.host in ("0.0.0.0", "::", "") else {self.host.lower()}
        return frozenset(LOOPBACK_NAMES | bound | {socket.gethostname().lower()} | set(self.allowed_hosts))

    @property
    def foxglove_server_port(self) -> int | None:
        """The port the Foxglove live view serves on (0: any free one), or None: off (``off``; or not given while
        reads need the token, since Foxglove's protocol carries none)."""
        if self.foxglove_port is None:
            return None if self.token_reads else DEFAULT_FOXGLOVE_PORT
        return None if self.foxglove_port in FOXGLOVE_OFF else int(self.foxglove_port)

    @property
    def storage_quota_bytes(self) -> int:
        """The storage quota in bytes (0: none)."""
        return int(self.storage_quota_mb * 2**20)

    @property
    def max_body_bytes(self) -> int:
        """The body limit in bytes."""
        return int(self.max_body_mb * 1024 * 1024)

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None, **overrides: Any) -> ServiceSettings:
        """Defaults, replaced by the ``CONTACT_SKILLS_*`` variables of ``env`` (default ``os.environ``),
        then by ``overrides`` whose value is not None (command-line flags)."""
        env = os.environ if env is None else env
        kinds = {f.name: f.type for f in fields(cls)}
        values: dict[str, Any] = {}
        for name, var in ENV_VARS.items():
            raw = env.get(var)
            if raw is None or raw.strip() == "":
                continue
            kind = kinds[name]
            try:
                if kind == "int":
                    values[name] = int(raw)
                elif kind == "float":
                    values[name] = float(raw)
                elif kind == "bool":
                    values[name] = _flag(raw)
                else:
                    values[name] = raw.strip()
            except ValueError:
                raise SettingsError(f"{var}={raw!r}: not a valid {kind}") from None
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def replace(self, **changes: Any) -> ServiceSettings:
        """A copy with ``changes`` (None values ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})


def _default_budget() -> JobBudget:
    """The job budget's defaults (imported when settings are made: ``--help`` loads no pydantic)."""
    from schemas.job_budget import JobBudget

    return JobBudget()


def package_version() -> str:
    """The installed contact-skills version (``0+unknown`` when run from a tree that was never installed)."""
    from importlib import metadata

    try:
        return metadata.version("contact-skills")
    except metadata.PackageNotFoundError:
        return "0+unknown"
