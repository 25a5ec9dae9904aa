"""The key expressions of the Zenoh bus (``schemas/bus.py`` has the whole contract: what each key carries) and the
one rule for the ids they hold: a worker, execution or sweep id is a single key chunk.

Pure: no zenoh, no I/O; ``schemas.bus`` (the payloads) and ``schemas.bus_security`` (the router's access control)
both build their keys here.
"""

from __future__ import annotations

import re

DEFAULT_PREFIX = "cskills"
"""Key-expression prefix used unless configured (``CONTACT_SKILLS_ZENOH_PREFIX``)."""

ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.:@+=-]{0,127}$"
"""Worker and execution ids are one key chunk: no ``/``, no wildcard or reserved characters (``* $ ? #``)."""
_ID = re.compile(ID_PATTERN)


def check_id(value: str, what: str = "id") -> str:
    """Return ``value`` if it can be a key chunk (``ID_PATTERN``), else raise ValueError saying why."""
    if not isinstance(value, str) or not _ID.match(value):
        raise ValueError(
            f"{what} {value!r} cannot be a key-expression chunk: use 1-128 characters from letters, digits and "
            "_ . : @ + = - (starting with a letter or digit)"
        )
    return value


class KeyExpressions:
    """Builds the key expressions of the bus from the prefix (see the module docstring)."""

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        prefix = prefix.strip("/")
        if not prefix or any(c in prefix for c in "*$?#") or "//" in prefix:
            raise ValueError(f"invalid key-expression prefix {prefix!r}")
        self.prefix = prefix

    def __repr__(self) -> str:
        return f"KeyExpressions({self.prefix!r})"

    # Workers.
    def worker(self, worker_id: str) -> str:
        """Liveliness token of a worker."""
        return f"{self.prefix}/workers/{check_id(worker_id, 'worker_id')}"

    @property
    def workers(self) -> str:
        """Every worker's liveliness token (``P/workers/*``)."""
        return f"{self.prefix}/workers/*"

    def info(self, worker_id: str = "*") -> str:
        """A worker's info queryable (``*``: every worker's)."""
        return f"{self.prefix}/exec/{self._chunk(worker_id, 'worker_id')}/info"

    def start(self, worker_id: str) -> str:
        """A worker's start queryable."""
        return f"{self.prefix}/exec/{check_id(worker_id, 'worker_id')}/start"

    def record(self, worker_id: str) -> str:
        """A worker's record queryable."""
        return f"{self.prefix}/exec/{check_id(worker_id, 'worker_id')}/record"

    def replay(self, worker_id: str) -> str:
        """A worker's telemetry replay queryable."""
        return f"{self.prefix}/exec/{check_id(worker_id, 'worker_id')}/replay"

    # Executions.
    def cmd(self, execution_id: str) -> str:
        """Commands to an execution."""
        return f"{self.prefix}/exec/{check_id(execution_id, 'execution_id')}/cmd"

    def status(self, execution_id: str = "*") -> str:
        """Status of an execution (``*``: of every execution)."""
        return f"{self.prefix}/exec/{self._chunk(execution_id, 'execution_id')}/status"

    def telemetry(self, execution_id: str = "*") -> str:
        """Telemetry of an execution (``*``: of every execution)."""
        return f"{self.prefix}/exec/{self._chunk(execution_id, 'execution_id')}/telemetry"

    # Sweeps.
    def sweep_progress(self, sweep_id: str = "*") -> str:
        """Live progress of a sweep (``*``: of every sweep)."""
        return f"{self.prefix}/sweeps/{self._chunk(sweep_id, 'sweep_id')}/progress"

    # Parsing.
    def worker_id_of(self, key: str) -> str:
        """The worker id in a liveliness key ``P/workers/{worker_id}``."""
        head = f"{self.prefix}/workers/"
        if not key.startswith(head) or "/" in key[len(head) :]:
            raise ValueError(f"{key!r} is not a worker key under {head}")
        return key[len(head) :]

    def id_of(self, key: str) -> str:
        """The worker or execution id in ``P/exec/{id}/...``."""
        head = f"{self.prefix}/exec/"
        if not key.startswith(head):
            raise ValueError(f"{key!r} is not under {head}")
        return key[len(head) :].split("/", 1)[0]

    @staticmethod
    def _chunk(value: str, what: str) -> str:
        return value if value == "*" else check_id(value, what)
