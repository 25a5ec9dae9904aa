"""The service the demo drives: the one answering at ``--url``, else ``contact-skills up`` started here.

- :class:`ServiceClient`: HTTP (httpx) that turns refusals into :class:`DemoError`;
- :class:`EmbeddedStack`: ``contact-skills up --workers N`` as a child process on loopback (its own Zenoh port, a
  temporary database), stopped by SIGTERM at the end;
- :class:`LiveStatus`: one Zenoh subscriber on ``P/exec/*/status`` for the live phase of every execution;
- :func:`service_session`: picks or starts the service and yields a client, its health and the Zenoh endpoints.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from experiments.cases import DemoOptions
from services.local_processes import free_port, parent_death_signal, port_free

if TYPE_CHECKING:
    from schemas.bus import ExecutionStatus

STACK_READY_TIMEOUT_S = 180.0
"""How long the embedded stack may take to answer /health with every worker connected."""


class DemoError(RuntimeError):
    """The demo cannot go on (no service, a request refused); the message says why."""


def say(text: str) -> None:
    """A progress line on stderr that does not break the progress bars."""
    from tqdm import tqdm

    tqdm.write(text, file=sys.stderr)


# --------------------------------------------------------------------------------------------------- the stack


class EmbeddedStack:
    """``contact-skills up`` as a child process on loopback (its own Zenoh port, a given database); stopped by
    SIGTERM (``up`` stops its API and workers cleanly), killed only if it does not stop in time."""

    def __init__(self, port: int, workers: int, db: Path, log_path: Path) -> None:
        self.port, self.workers, self.db, self.log_path = port, workers, db, log_path
        self.zenoh_port = free_port()
        self.url = f"http://127.0.0.1:{port}"
        self.endpoint = f"tcp/127.0.0.1:{self.zenoh_port}"
        self.process: subprocess.Popen | None = None
        self._log = None

    def start(self) -> None:
        root = Path(__file__).resolve().parents[1]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH", "")) if p)
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(var, "1")
        argv = [
            sys.executable,
            "-m",
            "cli.main",
            "up",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--zenoh-port",
            str(self.zenoh_port),
            "--workers",
            str(self.workers),
            "--db",
            str(self.db),
            "--log-level",
            "warning",
        ]
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("w")
        self.process = subprocess.Popen(
            argv,
            env=env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=parent_death_signal(),
        )

    def check_alive(self) -> None:
        if self.process is not None and self.process.poll() is not None:
            raise DemoError(f"`contact-skills up` exited with {self.process.returncode}; its log:\n{self.log_tail()}")

    def log_tail(self, n: int = 30) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return "(no log)"

    def stop(self, timeout_s: float = 40.0) -> int | None:
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._log is not None:
            self._log.close()
        return self.process.returncode


# --------------------------------------------------------------------------------------------------- live status


class LiveStatus:
    """A Zenoh subscriber on ``P/exec/*/status``: the latest ``ExecutionStatus`` of every execution, and an
    event set whenever one reaches a final phase. Without a bus (not reachable) it stays empty: the demo polls."""

    def __init__(self, endpoints: list[str], prefix: str) -> None:
        self.lock = threading.Lock()
        self.latest: dict[str, ExecutionStatus] = {}
        self.received = 0
        """Status messages received."""
        self.changed = threading.Event()
        self.session = None
        self.subscriber = None
        self.prefix = prefix
        self.error: str | None = None
        try:
            from services.bus import open_session

            self.session = open_session("client", connect=endpoints, wait_s=3.0)
            self._subscribe(prefix)
        except Exception as exc:  # no zenoh, router not reachable from here
            self.error = f"{type(exc).__name__}: {exc}"
            self.session = None

    @property
    def connected(self) -> bool:
        return self.session is not None

    def _subscribe(self, prefix: str) -> None:
        from schemas.bus import KeyExpressions

        if self.subscriber is not None:
            with contextlib.suppress(Exception):
                self.subscriber.undeclare()
        self.prefix = prefix
        self.subscriber = self.session.declare_subscriber(KeyExpressions(prefix).status("*"), self._on_status)

    def follow_prefix(self, status_key: str) -> None:
        """Re-subscribe if the service's prefix (seen in a ``status_key``) is not the one assumed."""
        prefix = status_key.rsplit("/exec/", 1)[0]
        if self.session is not None and prefix != self.prefix:
            self._subscribe(prefix)

    def _on_status(self, sample) -> None:
        from schemas.bus import ExecutionStatus

        try:
            status = ExecutionStatus.model_validate_json(sample.payload.to_bytes())
        except ValueError:
            return
        with self.lock:
            self.received += 1
            current = self.latest.get(status.execution_id)
            if current is None or status.seq >= current.seq:
                self.latest[status.execution_id] = status
        self.changed.set()

    def get(self, execution_id: str) -> ExecutionStatus | None:
        with self.lock:
            return self.latest.get(execution_id)

    def close(self) -> None:
        if self.session is not None:
            with contextlib.suppress(Exception):
                if self.subscriber is not None:
                    self.subscriber.undeclare()
                self.session.close()
            self.session = None


# --------------------------------------------------------------------------------------------------- the session


class ServiceClient:
    """The HTTP side: a thin httpx client that turns refusals into :class:`DemoError`."""

    def __init__(self, url: str) -> None:
        import httpx

        headers = {}
        token = os.environ.get("CONTACT_SKILLS_TOKEN")
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self.http = httpx.Client(base_url=url.rstrip("/"), timeout=60.0, headers=headers)
        self.httpx = httpx

    def health(self, timeout_s: float = 3.0) -> dict | None:
        try:
            response = self.http.get("/health", timeout=timeout_s)
        except self.httpx.HTTPError:
            return None
        return response.json() if response.status_code == 200 else None

    def request(self, method: str, path: str, expect: int, retry_busy_s: float = 0.0, **kwargs) -> dict:
        """``method path``; a 503 (no free worker) is retried for ``retry_busy_s``; another status than
        ``expect`` raises :class:`DemoError` with the service's ``detail``."""
        deadline = time.monotonic() + retry_busy_s
        while True:
            response = self.http.request(method, path, **kwargs)
            if response.status_code == expect:
                return response.json()
            if response.status_code == 503 and time.monotonic() < deadline:
                time.sleep(0.5)
                continue
            try:
                detail = response.json().get("detail")
            except ValueError:
                detail = response.text[:300]
            raise DemoError(f"{method} {path}: HTTP {response.status_code}: {detail}")

    def try_post(self, path: str, body: dict) -> tuple[int, dict]:
        response = self.http.post(path, json=body)
        try:
            return response.status_code, response.json()
        except ValueError:
            return response.status_code, {"detail": response.text[:300]}

    def close(self) -> None:
        self.http.close()


@contextlib.contextmanager
def service_session(
    options: DemoOptions, timings: dict[str, float]
) -> Iterator[tuple[ServiceClient, dict, list[str], str]]:
    """The service to drive: the one answering at ``options.url``, else the embedded stack started here.

    Yields (client, health, Zenoh endpoints to subscribe on, a description)."""
    started = time.perf_counter()
    client = ServiceClient(options.url)
    stack: EmbeddedStack | None = None
    tmp: tempfile.TemporaryDirectory | None = None
    try:
        health = client.health()
        if health is not None:
            description = f"the running service at {options.url}"
            endpoints = options.connect or list(health.get("zenoh_endpoints") or [])
            say(f"{_who(options)}: using {description} ({len(health.get('workers', []))} worker(s) connected)")
        else:
            parts = urlsplit(options.url)
            if parts.hostname not in ("127.0.0.1", "localhost"):
                raise DemoError(f"no service answers {options.url}/health (and only a loopback one is started here)")
            port = parts.port or 80
            if not port_free(port):
                port = free_port()
            tmp = tempfile.TemporaryDirectory(prefix="contact-skills-demo-")
            db = options.db or Path(tmp.name) / "demo.db"
            stack = EmbeddedStack(port, options.workers, db, Path(tmp.name) / "up.log")
            say(
                f"{_who(options)}: no service at {options.url}: starting `contact-skills up "
                f"--workers {options.workers} --port {port} --zenoh-port {stack.zenoh_port} --db {db}`"
            )
            stack.start()
            client.close()
            client = ServiceClient(stack.url)
            health = _wait_ready(client, stack, options.workers, _who(options))
            description = f"the embedded stack (`contact-skills up --workers {options.workers}`, started by the demo)"
            endpoints = options.connect or [stack.endpoint]
        if not health.get("bus_connected", False):
            raise DemoError("the service has no Zenoh bus: it cannot record or execute")
        if not health.get("workers"):
            health = _wait_workers(client, 1, 60.0)
        timings["service start"] = time.perf_counter() - started
        yield client, health, endpoints, description
    finally:
        client.close()
        if stack is not None:
            code = stack.stop()
            say(f"{_who(options)}: embedded stack stopped (exit {code})")
        if tmp is not None:
            tmp.cleanup()


def _who(options: DemoOptions) -> str:
    """The command the progress lines speak for (``demo``, ``sweep``), from ``options.command``."""
    words = options.command.split()
    return words[1] if len(words) > 1 else "demo"


def _wait_ready(client: ServiceClient, stack: EmbeddedStack, workers: int, who: str) -> dict:
    deadline = time.monotonic() + STACK_READY_TIMEOUT_S
    while time.monotonic() < deadline:
        stack.check_alive()
        health = client.health(timeout_s=2.0)
        if health is not None and len(health.get("workers", [])) >= workers:
            say(f"{who}: service ready at {stack.url} with {len(health['workers'])} workers")
            return health
        time.sleep(0.3)
    raise DemoError(f"the embedded stack was not ready in {STACK_READY_TIMEOUT_S:.0f} s; its log:\n{stack.log_tail()}")


def _wait_workers(client: ServiceClient, n: int, timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        health = client.health()
        if health is not None and len(health.get("workers", [])) >= n:
            return health
        time.sleep(0.5)
    raise DemoError(f"no sim worker connected to the service within {timeout_s:.0f} s")
