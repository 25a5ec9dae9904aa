"""Subcommands of `contact-skills` for the service: api, warm-up, up (lazy imports inside each command).

- ``contact-skills api``: the REST API (uvicorn) with its SQLite store, connected to a Zenoh router.
- ``contact-skills up``: everything on this machine, loopback only: an embedded Zenoh router (in this
  process), the API and N sim workers (child processes), their logs prefixed by name. Ctrl-C or
  SIGTERM stops all cleanly (children terminated, waited for; exit 0). A child that dies is restarted
  (the API keeps its database, so nothing stored is lost); one that keeps dying at start is given up,
  and if that is the API, everything stops (exit 1). Children get SIGTERM if `up` itself is killed.
"""

from __future__ import annotations

import argparse
import contextlib
import secrets
import sys
import threading
from pathlib import Path
from typing import IO, Any

from cli.bus_commands import ENGINE_HELP, ENGINES, LOG_LEVEL_HELP, LOG_LEVELS, apply_login, login_arguments
from services.service_url import DEFAULT_URL, URL_ENV
from services.settings import DEFAULT_WORKERS

STOP_TIMEOUT_S = 10.0
"""How long `up` waits for a child to exit after SIGTERM before killing it."""
RESTART_DELAY_S = 1.0
"""`up` restarts a child that died after this (times 1 + its quick exits in a row), s."""
QUICK_EXIT_S = 5.0
MAX_QUICK_EXITS = 3

READY_TIMEOUT_S = 60.0


def _settings(args: argparse.Namespace):  # -> services.settings.ServiceSettings
    from services.settings import ServiceSettings

    return ServiceSettings.from_env(
        host=args.host,
        port=args.port,
        db_path=args.db,
        zenoh_endpoints=getattr(args, "connect", None),
        max_body_mb=getattr(args, "max_body_mb", None),
        workers=getattr(args, "workers", None),
    )


def _configure_logging(level: str) -> None:
    import logging

    logging.basicConfig(
        level=level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )


# --------------------------------------------------------------------------- api


def cmd_api(args: argparse.Namespace) -> int:
    """``contact-skills api``: serve the REST API (OpenAPI at /docs) over the SQLite store and the Zenoh bus."""
    import os

    from services.quiet_imports import import_pybullet_quietly

    import_pybullet_quietly()  # the live scene and the MCAP export solve the arm's joints with PyBullet: no banner
    from services.app import connect_bus, create_app, serve_api

    apply_login(args)
    from services.settings import SettingsError
    from services.store import Store, StoreError
    from services.store.owner import claimed_database

    _configure_logging(args.log_level)
    with contextlib.ExitStack() as held:
        try:
            settings = _settings(args)
            owner = f"pid {os.getpid()}, http://{settings.host}:{settings.port}"
            held.enter_context(claimed_database(settings.db_path, owner))
            store = held.enter_context(contextlib.closing(Store(settings.db_path)))
        except (SettingsError, StoreError, OSError) as exc:
            print(f"contact-skills api: error: {exc}", file=sys.stderr)
            return 2
        bus = None
        try:
            if not args.no_bus:
                try:
                    bus = connect_bus(settings, store)
                except ConnectionError as exc:
                    print(f"contact-skills api: error: {exc}", file=sys.stderr)
                    return 1
            app = create_app(settings, bus, store)
            print(
                f"contact-skills api: http://{settings.host}:{settings.port} (OpenAPI /docs), database "
                f"{settings.db_path}, zenoh {'off' if bus is None else ','.join(settings.zenoh_endpoints)}"
                + (", token required for POST/DELETE" if settings.token else ""),
                file=sys.stderr,
                flush=True,
            )
            serve_api(app, settings, args.log_level.lower())  # with the connection limits of the settings
        finally:
            if bus is not None:
                bus.close()
    return 0


# --------------------------------------------------------------------------- warm-up


def cmd_warm_up(args: argparse.Namespace) -> int:
    """``contact-skills warm-up``: compile every compiled function of the sim worker's control loop once (or load it
    from numba's on-disk cache), after installing or changing the code; make run, make test and the Docker image run
    it. The first compile takes tens of seconds and holds the interpreter: a worker or learner that met it inside a
    request would miss its deadline."""
    from services.quiet_imports import import_pybullet_quietly

    import_pybullet_quietly()  # the warm-up builds PyBullet worlds: no banner
    from sim_worker.warm_up import warm_up

    print(f"compiled code ready in {warm_up():.1f} s")
    return 0


# --------------------------------------------------------------------------- up


class _Printer:
    """Writes the children's lines with a name prefix, one whole line at a time."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.width = 8

    def line(self, name: str, text: str) -> None:
        with self._lock:
            sys.stdout.write(f"{name:>{self.width}} | {text.rstrip()}\n")
            sys.stdout.flush()

    def pump(self, name: str, stream: IO[str]) -> threading.Thread:
        def run() -> None:
            for text in stream:
                self.line(name, text)

        thread = threading.Thread(target=run, name=f"log-{name}", daemon=True)
        thread.start()
        return thread


class _Child:
    """One child process of `up`, restartable."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str], printer: _Printer, preexec: Any) -> None:
        self.name, self.argv, self.env, self.printer, self.preexec = name, argv, env, printer, preexec
        self.process: Any = None
        self.restarts = 0
        self.quick_exits = 0
        self.given_up = False
        self.started_at = 0.0

    def start(self) -> None:
        import subprocess
        import time

        self.started_at = time.monotonic()
        self.process = subprocess.Popen(
            self.argv,
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
            bufsize=1,
            start_new_session=True,  # Ctrl-C reaches only `up`, which stops the children in order
            preexec_fn=self.preexec,
        )
        self.printer.pump(self.name, self.process.stdout)
        shown = " ".join(["contact-skills", *self.argv[3:]])  # argv: python -m cli.main ...
        self.printer.line("up", f"started {self.name} (pid {self.process.pid}): {shown}")

    def exit_code(self) -> int | None:
        return None if self.process is None else self.process.poll()

    def terminate(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()

    def wait(self, timeout_s: float) -> int:
        import subprocess

        try:
            return self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.printer.line("up", f"{self.name} did not stop in {timeout_s:.0f} s: killing it")
            self.process.kill()
            return self.process.wait()


def _not_ready(
    url: str, api: _Child, instance: str, workers: int, stop: threading.Event, timeout_s: float
) -> str | None:
    """None once THIS API (its ``instance``) answers ``/health`` showing ``workers`` workers each in the state it
    answered itself (idle, executing, recording; not ``unknown``): what ``ready`` promises, so that the first
    ``/health`` after it shows the workers as they are and a run posted at once finds one. Else why not (stopped,
    exited, another process, timeout)."""
    import json
    import time
    import urllib.request

    deadline = time.monotonic() + timeout_s
    answering = False
    while time.monotonic() < deadline and not stop.is_set():
        if api.exit_code() is not None:
            return f"the API exited ({_exit_text(api.exit_code())})"
        try:
            with urllib.request.urlopen(url + "/health", timeout=2) as response:
                health = json.loads(response.read())
            if health.get("instance") != instance:
                return f"{url} is answered by another process, not this API (pid {api.process.pid})"
            answering = True
            known = [w for w in health.get("workers", []) if w.get("activity") != "unknown"]
            if len(known) >= workers:
                return None
        except (OSError, ValueError):
            pass
        stop.wait(0.2)
    if stop.is_set():
        return "stopped"
    if answering:
        return f"the API answers {url}/health, but not all {workers} workers connected within {timeout_s:.0f} s"
    return f"the API did not answer {url}/health within {timeout_s:.0f} s"


def _ports_taken(settings, zenoh_port: int) -> str | None:
    """Why `up` cannot start on the ports asked (something else holds one or both), with what to run instead: free
    ports, in the words the user started it with (make's ``PORT=`` and ``ZENOH_PORT=`` under make, else the flags),
    and the ``/health`` to ask when the HTTP port is held; None when both are free."""
    import os

    from services.local_processes import LOOPBACK, port_free

    http_taken = not port_free(settings.port, settings.host)
    zenoh_taken = not port_free(zenoh_port, LOOPBACK)
    if not (http_taken or zenoh_taken):
        return None
    held = [f"HTTP port {settings.port} on {settings.host}"] if http_taken else []
    held += [f"Zenoh router port {zenoh_port} on {LOOPBACK}"] if zenoh_taken else []
    why = (
        f"another contact-skills up? curl http://{settings.host}:{settings.port}/health tells"
        if http_taken
        else "the Zenoh router of another contact-skills up?"
    )
    port = _free_from(settings.port, settings.host) if http_taken else settings.port
    zenoh = _free_from(zenoh_port, LOOPBACK) if zenoh_taken else zenoh_port
    instead = (
        f"make run PORT={port} ZENOH_PORT={zenoh}"
        if "MAKELEVEL" in os.environ  # GNU make exports it to every recipe: `up` was started by `make run`
        else f"contact-skills up --port {port} --zenoh-port {zenoh}"
    )
    return f"{' and '.join(held)} already in use ({why}); stop it, or run this one on free ports: {instead}"


def _free_from(port: int, host: str) -> int:
    """The first port above ``port`` nothing listens on at ``host``."""
    from services.local_processes import port_free

    candidate = port + 1
    while not port_free(candidate, host):
        candidate += 1
    return candidate


def cmd_up(args: argparse.Namespace) -> int:
    """``contact-skills up``: a Zenoh router (in this process), the API and N sim workers on loopback, one command."""
    import os
    import signal

    from services.settings import SettingsError

    try:
        settings = _settings(args)
    except SettingsError as exc:
        print(f"contact-skills up: error: {exc}", file=sys.stderr)
        return 2
    from services.store.owner import DatabaseInUse, database_owner

    taken = _ports_taken(settings, args.zenoh_port)
    owner = database_owner(settings.db_path)
    if taken or owner is not None:
        for problem in (taken, owner and DatabaseInUse(settings.db_path, owner)):
            if problem:
                print(f"contact-skills up: error: {problem}", file=sys.stderr)
        return 2
    from services.local_processes import parent_death_signal

    preexec = parent_death_signal()
    listen = f"tcp/127.0.0.1:{args.zenoh_port}"
    printer = _Printer()
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        if not stop.is_set():
            printer.line("up", f"{signal.Signals(signum).name}: stopping")
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    from services.local_processes import with_thread_limits

    env = {
        **with_thread_limits(dict(os.environ)),  # every child: one BLAS thread (unless the environment says otherwise)
        "PYTHONUNBUFFERED": "1",
        "CONTACT_SKILLS_ZENOH_ENDPOINTS": listen,
        "CONTACT_SKILLS_ZENOH_PREFIX": settings.zenoh_prefix,
    }
    env.pop("CONTACT_SKILLS_HOST", None)  # `up` is loopback-only: the API gets --host explicitly
    base = [sys.executable, "-m", "cli.main"]
    api_argv = [*base, "api", "--host", settings.host, "--port", str(settings.port), "--db", str(settings.db_path),
                "--connect", listen, "--log-level", args.log_level]  # fmt: skip
    instance = secrets.token_hex(8)  # how `up` knows ITS API answers /health (which shows no pid without the token)
    api = _Child("api", api_argv, {**env, "CONTACT_SKILLS_INSTANCE": instance}, printer, preexec)
    worker_argv = [*base, "worker", *(["--engine", args.engine] if args.engine else [])]
    workers = [_Child(f"worker-{k + 1}", worker_argv, env, printer, preexec) for k in range(settings.workers)]
    code = 0
    try:
        from services.router import local_router

        with local_router(args.zenoh_port, len(workers), settings.zenoh_prefix, args.open_bus) as logins:
            for child in (api, *workers):  # each its own login (none with --open-bus)
                child.env = {**child.env, **logins.get(child.name, {})}
            guard = "OPEN to every local process (--open-bus)" if args.open_bus else "each process logs in"
            printer.line("up", f"zenoh router listening on {listen} (in process {os.getpid()}), {guard}")
            api.start()
            for worker in workers:
                worker.start()
            url = f"http://{settings.host}:{settings.port}"
            reason = _not_ready(url, api, instance, len(workers), stop, READY_TIMEOUT_S)
            if reason is None:
                clients = "" if url == DEFAULT_URL else f"; clients: export {URL_ENV}={url}"
                printer.line("up", f"ready: {url} (OpenAPI {url}/docs), {len(workers)} workers, db {settings.db_path}"
                             + clients)  # fmt: skip
                code = _supervise(api, workers, stop, printer)
            elif "another process" in reason:
                printer.line("up", f"error: {reason}: stopping")
                code = 1
            else:
                if not stop.is_set():
                    printer.line("up", f"not ready: {reason}")
                code = _supervise(api, workers, stop, printer)
            _stop_all([api, *workers], printer)
    except Exception as exc:  # the router could not start (port taken, ...)
        printer.line("up", f"error: {type(exc).__name__}: {exc}")
        _stop_all([api, *workers], printer)
        code = 1
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    printer.line("up", f"stopped (exit {code})")
    return code


def _supervise(api: _Child, workers: list[_Child], stop: threading.Event, printer: _Printer) -> int:
    """Wait until stopped, restarting children that die (after a delay growing with their failures).

    A child that dies within :data:`QUICK_EXIT_S` of its start counts as failing; after
    :data:`MAX_QUICK_EXITS` such exits in a row it is not restarted (and for the API everything stops: 1).
    Returns 0 when stopped by a signal."""
    import time

    restart_at: dict[str, float] = {}
    while not stop.wait(0.2):
        for child in (api, *workers):
            code = child.exit_code()
            if code is None or child.given_up:
                continue
            if child.name not in restart_at:
                quick = time.monotonic() - child.started_at < QUICK_EXIT_S
                child.quick_exits = child.quick_exits + 1 if quick else 0
                if child.quick_exits >= MAX_QUICK_EXITS:
                    child.given_up = True
                    printer.line("up", f"{child.name} keeps exiting at start (code {code}): not restarting it")
                    if child is api:
                        return 1
                    continue
                delay = RESTART_DELAY_S * (1 + child.quick_exits)
                printer.line("up", f"{child.name} ended ({_exit_text(code)}): restarting it in {delay:.0f} s")
                restart_at[child.name] = time.monotonic() + delay
            if time.monotonic() >= restart_at[child.name]:
                del restart_at[child.name]
                child.restarts += 1
                child.start()
    return 0


def _exit_text(code: int) -> str:
    """``exit 0``, or the signal that ended the process (uvicorn re-raises SIGTERM after a clean shutdown)."""
    import signal

    if code < 0:
        with contextlib.suppress(ValueError):
            return (
                f"{signal.Signals(-code).name} after shutdown"
                if -code == signal.SIGTERM
                else signal.Signals(-code).name
            )
    return f"exit {code}"


def _stop_all(children: list[_Child], printer: _Printer) -> None:
    running = [c for c in children if c.process is not None and c.exit_code() is None]
    for child in running:
        child.terminate()
    for child in running:
        code = child.wait(STOP_TIMEOUT_S)
        printer.line("up", f"{child.name} stopped ({_exit_text(code)})")


# --------------------------------------------------------------------------- registration


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", help="interface to listen on (default $CONTACT_SKILLS_HOST or 127.0.0.1)")
    parser.add_argument("--port", type=int, help="HTTP port (default $CONTACT_SKILLS_PORT or 8000)")
    parser.add_argument(
        "--db",
        type=Path,
        help="SQLite database file (default $CONTACT_SKILLS_DB, else ./contact_skills.db on port 8000 and "
        "./contact_skills_PORT.db on another: each instance its own)",
    )
    parser.add_argument("--log-level", default="info", choices=LOG_LEVELS, help=LOG_LEVEL_HELP)


def register(commands: argparse._SubParsersAction) -> None:
    """Add this group's subcommands to the `contact-skills` parser."""
    api = commands.add_parser(
        "api", help="serve the REST API (uvicorn + SQLite + Zenoh client)", description=cmd_api.__doc__
    )
    _add_common(api)
    api.add_argument(
        "--connect",
        metavar="ENDPOINTS",
        help="Zenoh router endpoint(s), comma separated (default $CONTACT_SKILLS_ZENOH_ENDPOINTS, tcp/127.0.0.1:7447)",
    )
    api.add_argument("--max-body-mb", type=float, help="request body limit, MiB (default 64)")
    api.add_argument("--no-bus", action="store_true", help="run without Zenoh (executions and recordings get 503)")
    login_arguments(api)
    api.set_defaults(run=cmd_api)

    warm = commands.add_parser(
        "warm-up", help="compile the sim worker's control loop once (after installing)", description=cmd_warm_up.__doc__
    )
    warm.set_defaults(run=cmd_warm_up)

    up = commands.add_parser(
        "up", help="run router + API + N sim workers on this machine (loopback)", description=cmd_up.__doc__
    )
    _add_common(up)
    up.add_argument(
        "--workers", type=int, help=f"sim worker processes (default $CONTACT_SKILLS_WORKERS or {DEFAULT_WORKERS})"
    )
    up.add_argument("--zenoh-port", type=int, default=7447, help="TCP port of the embedded Zenoh router (loopback)")
    up.add_argument("--engine", choices=ENGINES, help=f"the workers' {ENGINE_HELP}")
    up.add_argument(
        "--open-bus",
        action="store_true",
        help="DEVELOPMENT ONLY: no logins on the bus, so any local process can command and report (default: each "
        "process logs in; others read with the observer login, services/bus_keys.py)",
    )
    up.set_defaults(run=cmd_up)
