"""Settings of the REST service: defaults, then environment variables, then command-line flags.

| setting | env var | default |
| --- | --- | --- |
| host | ``CONTACT_SKILLS_HOST`` | ``127.0.0.1`` (loopback only; set ``0.0.0.0`` inside a container) |
| port | ``CONTACT_SKILLS_PORT`` | ``8000`` |
| db_path | ``CONTACT_SKILLS_DB`` | ``./contact_skills.db`` |
| token | ``CONTACT_SKILLS_TOKEN`` | none: POST/DELETE are open; set it to require ``Authorization: Bearer <token>`` |
| max_body_mb | ``CONTACT_SKILLS_MAX_BODY_MB`` | ``64`` (MiB; a larger request body gets 413) |
| workers | ``CONTACT_SKILLS_WORKERS`` | ``1`` (sim worker processes started by ``contact-skills up``) |
| zenoh_endpoints | ``CONTACT_SKILLS_ZENOH_ENDPOINTS`` | ``tcp/127.0.0.1:7447`` (comma separated) |
| zenoh_prefix | ``CONTACT_SKILLS_ZENOH_PREFIX`` | ``cskills`` |
| connect_timeout_s | ``CONTACT_SKILLS_CONNECT_TIMEOUT_S`` | ``30`` (s the API waits for the router) |
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
DEFAULT_DB = "contact_skills.db"
DEFAULT_MAX_BODY_MB = 64.0
DEFAULT_WORKERS = 1
DEFAULT_ZENOH_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_ZENOH_PREFIX = "cskills"

ENV_PREFIX = "CONTACT_SKILLS_"
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
}
"""Setting name -> the environment variable that sets it."""


class SettingsError(ValueError):
    """An environment variable or flag holds a value the setting cannot take."""


def _endpoints(value: str | list[str]) -> list[str]:
    items = value.split(",") if isinstance(value, str) else value
    endpoints = [item.strip() for item in items if item.strip()]
    if not endpoints:
        raise SettingsError("zenoh_endpoints: give at least one endpoint, e.g. tcp/127.0.0.1:7447")
    return endpoints


@dataclass(frozen=True)
class ServiceSettings:
    """Where the API listens, where it stores, how it reaches the Zenoh router (see the module table)."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    db_path: Path = Path(DEFAULT_DB)
    token: str | None = None
    max_body_mb: float = DEFAULT_MAX_BODY_MB
    workers: int = DEFAULT_WORKERS
    zenoh_endpoints: list[str] = field(default_factory=lambda: [DEFAULT_ZENOH_ENDPOINT])
    zenoh_prefix: str = DEFAULT_ZENOH_PREFIX
    connect_timeout_s: float = 30.0

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise SettingsError(f"port: {self.port} is not a TCP port (0-65535)")
        if not self.max_body_mb > 0:
            raise SettingsError(f"max_body_mb: {self.max_body_mb} must be > 0")
        if self.workers < 0:
            raise SettingsError(f"workers: {self.workers} must be >= 0")
        if self.connect_timeout_s < 0:
            raise SettingsError(f"connect_timeout_s: {self.connect_timeout_s} must be >= 0")
        object.__setattr__(self, "db_path", Path(self.db_path))
        object.__setattr__(self, "zenoh_endpoints", _endpoints(self.zenoh_endpoints))
        object.__setattr__(self, "token", self.token or None)

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
                else:
                    values[name] = raw.strip()
            except ValueError:
                raise SettingsError(f"{var}={raw!r}: not a valid {kind}") from None
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def replace(self, **changes: Any) -> ServiceSettings:
        """A copy with ``changes`` (None values ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})


def package_version() -> str:
    """The installed contact-skills version (``0+unknown`` when run from a tree that was never installed)."""
    from importlib import metadata

    try:
        return metadata.version("contact-skills")
    except metadata.PackageNotFoundError:
        return "0+unknown"
