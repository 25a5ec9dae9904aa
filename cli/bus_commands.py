"""Subcommands of `contact-skills` for the Zenoh bus: router, worker, watch (lazy imports inside each command).

Settings come from the options, else the environment (``CONTACT_SKILLS_ZENOH_LISTEN``,
``CONTACT_SKILLS_ZENOH_ENDPOINTS``, ``CONTACT_SKILLS_ZENOH_PREFIX``), else the defaults
(``tcp/127.0.0.1:7447``, ``cskills``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from services.service_url import URL_HELP

PACES = ("realtime", "fast")
"""`schemas.execution.Pace`, spelled out: ``--help`` imports no pydantic (tests/test_cli.py compares)."""
ENGINES = ("pybullet", "mujoco")
"""`schemas.execution.Engine`, spelled out as :data:`PACES` is."""
ENGINE_HELP = (
    "default engine of the executions that name none: pybullet (the compiled loop) or mujoco (the same cell in "
    "MuJoCo; its loop in Python), docs/ENGINES.md (default $CONTACT_SKILLS_ENGINE, else pybullet)"
)

EXIT_ENDED_EARLY = 1
"""`watch`: the execution was aborted or failed."""
EXIT_TIMEOUT = 3
"""`watch`: nothing final arrived within --timeout."""
EXIT_VERDICT_FAILED = 4
"""`watch`, `simulate`: the execution ran every segment, but its verdict failed (the force, contact or touch-down
outside the tolerances)."""
LOG_LEVELS = ["debug", "info", "warning", "error"]
LOG_LEVEL_HELP = "how much the process logs to stderr (default info)"


def _endpoints(values: list[str] | None) -> list[str]:
    from schemas.bus import split_endpoints

    return [e for v in values or [] for e in split_endpoints(v)]


def login_arguments(parser: argparse.ArgumentParser) -> None:
    """--zenoh-user and --tls-ca of a bus client (the password only from CONTACT_SKILLS_ZENOH_PASSWORD)."""
    parser.add_argument(
        "--zenoh-user", help="log in to the router as this user (env CONTACT_SKILLS_ZENOH_USER; password from env "
        "CONTACT_SKILLS_ZENOH_PASSWORD)",
    )  # fmt: skip
    parser.add_argument(
        "--tls-ca", metavar="PEM", help="CA certificate of the router's TLS (env CONTACT_SKILLS_ZENOH_TLS_CA)"
    )


def apply_login(args: argparse.Namespace) -> None:
    """Put --zenoh-user / --tls-ca into the environment, where every bus session of this process and its children
    reads them (``schemas.bus_security.BusSecurity.from_env``)."""
    from schemas.bus_security import ENV_TLS_CA, ENV_USER

    for value, name in ((getattr(args, "zenoh_user", None), ENV_USER), (getattr(args, "tls_ca", None), ENV_TLS_CA)):
        if value:
            os.environ[name] = value


def _logging(level: str) -> None:
    import logging

    logging.basicConfig(level=level.upper(), stream=sys.stderr, format="%(asctime)s %(name)s %(levelname)s %(message)s")


# --------------------------------------------------------------------------- router


def cmd_router(args: argparse.Namespace) -> int:
    """``contact-skills router``: run a Zenoh router (embedded, eclipse-zenoh) until SIGINT/SIGTERM."""
    from schemas.bus import DEFAULT_PREFIX, ENV_PREFIX
    from schemas.bus_security import BusSecurity, BusSecurityError
    from services.router import listen_from_env, run_router

    _logging(args.log_level)
    listen = _endpoints(args.listen) or listen_from_env()
    try:
        security = BusSecurity.from_env(os.environ, users_file=args.users, tls_cert=args.tls_cert, tls_key=args.tls_key)
        run_router(listen, security, args.prefix or os.environ.get(ENV_PREFIX) or DEFAULT_PREFIX)
    except (ConnectionError, BusSecurityError, OSError) as exc:
        print(f"contact-skills router: error: {exc}", file=sys.stderr)
        return 2
    return 0


def cmd_bus_keys(args: argparse.Namespace) -> int:
    """``contact-skills bus-keys DIR``: a CA, the router's TLS certificate, a users file with random passwords and one
    environment file per login (api, worker-1..N, observer), for a secured bus across machines."""
    from services.bus_keys import generate_bus_keys

    try:
        written = generate_bus_keys(args.folder, args.host or [], args.workers, args.ca_path, args.endpoint)
    except (OSError, ValueError) as exc:
        print(f"contact-skills bus-keys: error: {exc}", file=sys.stderr)
        return 2
    print(f"contact-skills bus-keys: wrote {', '.join(p.name for p in written)} to {args.folder}")
    return 0


# --------------------------------------------------------------------------- worker


def cmd_worker(args: argparse.Namespace) -> int:
    """``contact-skills worker``: a sim worker on the bus (executes skills, records demonstrations)."""
    from services.quiet_imports import import_pybullet_quietly

    import_pybullet_quietly()
    from schemas.execution import Engine
    from sim_worker.worker_settings import WorkerSettings
    from sim_worker.zenoh_worker import run_worker

    _logging(args.log_level)
    apply_login(args)
    try:
        settings = WorkerSettings.from_env()
    except ValueError as exc:  # e.g. CONTACT_SKILLS_ENGINE naming no engine
        print(f"contact-skills worker: error: {exc}", file=sys.stderr)
        return 2
    if args.connect:
        settings.endpoints = _endpoints(args.connect)
    if args.prefix:
        settings.prefix = args.prefix
    if args.engine:
        settings.engine = Engine(args.engine)
    try:
        return run_worker(settings, worker_id=args.id)
    except ValueError as exc:  # e.g. an id that cannot be a key chunk
        print(f"contact-skills worker: error: {exc}", file=sys.stderr)
        return 2


# --------------------------------------------------------------------------- watch


def _status_line(execution_id: str, status, last: dict | None, samples: int) -> str:
    """One line: phase, segment, simulated time, CF-z force vs desired, paused."""
    phase = status.phase.value if status is not None else (last["phase"] if last else "waiting")
    segment = status.segment_index if status is not None else -1
    total = status.segments if status is not None else 0
    if last is not None:
        segment = last["segment"]
    parts = [execution_id, f"{phase:<8s}", f"seg {segment if segment >= 0 else '-'}/{total or '?'}"]
    if last is not None:
        parts += [f"t {last['t']:7.3f} s", f"Fz {last['fz']:6.2f} N (desired {last['fdes']:6.2f} N)"]
    parts.append(f"{samples} samples")
    if status is not None and status.paused:
        parts.append("PAUSED")
    return " | ".join(parts)


def _show(line: str, tty: bool, last_print: float) -> float:
    """Show the status ``line``: rewritten in place on a terminal, else printed at most once a second (``last_print``:
    the monotonic time of the last one, s); returns the new ``last_print``."""
    import time

    if tty:
        sys.stdout.write("\r" + line + "\x1b[K")
        sys.stdout.flush()
    elif time.monotonic() - last_print >= 1.0:
        print(line, flush=True)
        return time.monotonic()
    return last_print


def _metrics_lines(status) -> list[str]:
    m = status.metrics
    lines = [f"{status.execution_id} {status.phase.value} on {status.worker_id}: {status.message}"]
    if status.error:
        lines.append(f"  reason: {status.error}")
    if m is None:
        return lines
    lines.append(f"  {m.steps} steps, {m.duration_s:.3f} s simulated, real-time factor {m.real_time_factor:.1f}")
    if m.force_rms_error_n is not None:
        pct = f" ({m.force_rms_error_pct:.1f} %)" if m.force_rms_error_pct is not None else ""
        lines.append(f"  force error RMS {m.force_rms_error_n:.2f} N{pct}, max {m.force_max_error_n:.2f} N")
    if m.path_rms_m is not None:
        lines.append(f"  path RMS {m.path_rms_m * 1e3:.2f} mm")
    if m.contact_ratio is not None:
        lines.append(f"  contact ratio {m.contact_ratio:.3f}")
    lines.append(f"  peak force {m.peak_force_n:.1f} N")
    if m.verdict is not None:
        lines += [f"  {line}" for line in m.verdict.lines()]
    return lines


def exit_code(done: bool, metrics) -> int:
    """0 when an execution ran every segment (``done``) and passed its verdict (``metrics``, may be None); else why
    not (``EXIT_*``)."""
    from schemas.verdict import Verdict

    if not done:
        return EXIT_ENDED_EARLY
    failed = metrics is not None and metrics.verdict is not None and metrics.verdict.verdict is Verdict.failed
    return EXIT_VERDICT_FAILED if failed else 0


def _asked_the_api(args: argparse.Namespace, router_named: bool) -> int | list[str] | None:
    """Ask the API at ``--url`` about the execution first: exit 2 for an id it does not know, the stored metrics for
    a finished one (exit as :func:`exit_code`; unless it is to be replayed, ``--from-start``); else, to follow it,
    the Zenoh endpoints the API reports (``GET /health``). No API there: exit 2 saying so, unless the user named the
    router (``router_named``: --connect or $CONTACT_SKILLS_ZENOH_ENDPOINTS), whose bus is then watched alone (None);
    without it there is no bus to watch, and a default one would only time out after seconds."""
    from services.client import FINAL_STATUSES, Client, NotFoundError, ServiceError

    try:
        with Client(args.url, timeout_s=5.0) as client:
            view = client.execution(args.execution_id).status()
            endpoints = client.health().zenoh_endpoints
    except NotFoundError as exc:
        print(f"contact-skills watch: error: {exc.detail} (asked the API at {args.url})", file=sys.stderr)
        return 2
    except ServiceError as exc:
        if exc.status == 0 and not router_named:
            print(f"contact-skills watch: error: {exc.detail}", file=sys.stderr)
            return 2
        return None
    if view.status not in FINAL_STATUSES or args.from_start:
        return endpoints
    return _report_final(view)


def _report_final(view) -> int:
    """Print a finished execution's metrics and verdict as the API stored them (an `ExecutionView`); its exit code."""
    from schemas.api import ExecutionState
    from schemas.bus import ExecutionStatus

    status = ExecutionStatus(
        execution_id=view.id,
        worker_id=view.worker_id or "?",
        phase=view.phase,
        message=f"finished ({view.status.value})",
        metrics=view.metrics,
        error=view.error,
    )
    for text in _metrics_lines(status):
        print(text)
    return exit_code(view.status is ExecutionState.done, view.metrics)


def _watch_replayed(args: argparse.Namespace, endpoints: list[str]) -> int:
    """``--pace realtime`` or ``--from-start``: the run through the typed client's live view (``Client.live``: the
    stored samples first with --from-start, each batch held back to the clock with realtime), then its end as the
    API stored it."""
    from schemas.execution import Pace
    from services.client import Client, ServiceError

    tty, samples, last_print, line = sys.stdout.isatty(), 0, 0.0, ""
    try:
        with Client(args.url) as client:
            execution = client.execution(args.execution_id)
            live = execution.live(endpoints, args.timeout, Pace(args.pace), from_start=args.from_start)
            for batch in live:
                samples += len(batch.t)
                last = {"t": batch.t[-1], "phase": batch.phase[-1].value, "segment": batch.segment_index[-1],
                        "fz": batch.wrench_cf[-1][2], "fdes": batch.desired_force_cf_z_n[-1]}  # fmt: skip
                line = _status_line(args.execution_id, None, last, samples)
                last_print = _show(line, tty, last_print)
            print(("\r" + line + "\x1b[K") if tty else line)  # where it ended: every sample counted
            view = execution.wait(timeout_s=10.0, poll_s=0.05)
    except TimeoutError as exc:
        print(f"contact-skills watch: {exc}", file=sys.stderr)
        return EXIT_TIMEOUT
    except ServiceError as exc:
        print(f"contact-skills watch: error: {exc} (asked the API at {args.url})", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print()
        return 130
    return _report_final(view)


def _await_the_api(args: argparse.Namespace, timeout_s: float = 10.0) -> None:
    """After the bus's final status: wait until the API at ``--url`` has stored the end too (it finishes the
    execution's telemetry first), so that a request right after ``watch`` sees it; at most ``timeout_s`` seconds,
    and not at all when no API answers."""
    from services.client import Client, ServiceError

    try:
        with Client(args.url, timeout_s=5.0) as client:
            client.execution(args.execution_id).wait(timeout_s=timeout_s, poll_s=0.05)
    except (ServiceError, TimeoutError):
        pass


def cmd_watch(args: argparse.Namespace) -> int:
    """``contact-skills watch``: live view of an execution from the bus; exits when it ends, printing its metrics.

    The API at --url is asked first: an id it does not know is an error at once, a finished execution's metrics are
    printed from it, and no API answering there is an error at once naming the URL. With the router named
    (--connect or CONTACT_SKILLS_ZENOH_ENDPOINTS), the bus alone is watched instead: no status within --wait
    seconds is an error (an unknown id, or no worker runs it). After the end on the bus it waits (up to 10 s) for
    the API to have stored it, so that the next request to the API sees the execution finished."""
    import threading
    import time

    from schemas.bus import ENV_ENDPOINTS, ExecutionStatus, KeyExpressions, check_id
    from schemas.execution import ExecutionPhase, TelemetryBatch
    from services.bus import BusSettings, open_session
    from services.service_url import service_url

    apply_login(args)
    args.url = service_url(args.url)
    settings = BusSettings.from_env()
    try:
        check_id(args.execution_id, "execution_id")
    except ValueError as exc:
        print(f"contact-skills watch: error: {exc}", file=sys.stderr)
        return 2
    named = _endpoints(args.connect) or _endpoints([os.environ.get(ENV_ENDPOINTS, "")])
    answered = _asked_the_api(args, router_named=bool(named))
    if isinstance(answered, int):
        return answered
    if answered is not None and (args.from_start or args.pace != "fast"):
        return _watch_replayed(args, _endpoints(args.connect) or answered)
    if args.from_start:
        print(f"contact-skills watch: error: --from-start reads the stored run from the API at {args.url}, which "
              "does not answer", file=sys.stderr)  # fmt: skip
        return 2
    # --connect, else $CONTACT_SKILLS_ZENOH_ENDPOINTS, else the endpoints the API reports
    endpoints = named or answered or settings.endpoints
    try:
        keys = KeyExpressions(args.prefix or settings.prefix)
        session = open_session("client", connect=endpoints, wait_s=10.0)
    except (ValueError, ConnectionError) as exc:
        print(f"contact-skills watch: error: {exc}", file=sys.stderr)
        return 2
    lock = threading.Lock()
    state: dict = {"status": None, "last": None, "samples": 0}
    ended = threading.Event()

    def on_status(sample) -> None:
        status = ExecutionStatus.model_validate_json(sample.payload.to_bytes())
        with lock:
            current = state["status"]
            if current is None or status.seq >= current.seq:
                state["status"] = status
        if status.final:
            ended.set()

    def on_telemetry(sample) -> None:
        batch = TelemetryBatch.model_validate_json(sample.payload.to_bytes())
        with lock:
            state["samples"] += len(batch.t)
            state["last"] = {"t": batch.t[-1], "phase": batch.phase[-1].value, "segment": batch.segment_index[-1],
                             "fz": batch.wrench_cf[-1][2], "fdes": batch.desired_force_cf_z_n[-1]}  # fmt: skip

    tty = sys.stdout.isatty()
    subscribers = []
    try:
        subscribers = [
            session.declare_subscriber(keys.status(args.execution_id), on_status),
            session.declare_subscriber(keys.telemetry(args.execution_id), on_telemetry),
        ]
        for reply in session.get(keys.status(args.execution_id), timeout=2.0):  # late joiner: the latest status
            if reply.ok is not None:
                on_status(reply.ok)
        deadline = None if args.timeout is None else time.monotonic() + args.timeout
        first_deadline = time.monotonic() + args.wait
        last_print = 0.0
        while not ended.wait(0.1):
            with lock:
                heard = state["status"] is not None or state["samples"] > 0
            if not heard and time.monotonic() > first_deadline:
                print(
                    f"contact-skills watch: no status from {args.execution_id} on the bus ({', '.join(endpoints)}) "
                    f"within {args.wait:g} s: unknown id, or no worker runs it (the API at {args.url} did not answer)",
                    file=sys.stderr,
                )
                return EXIT_TIMEOUT
            with lock:
                line = _status_line(args.execution_id, state["status"], state["last"], state["samples"])
            last_print = _show(line, tty, last_print)
            if deadline is not None and time.monotonic() > deadline:
                if tty:
                    print()
                print(f"contact-skills watch: no final status within {args.timeout:g} s", file=sys.stderr)
                return EXIT_TIMEOUT
        with lock:
            status, line = (
                state["status"],
                _status_line(args.execution_id, state["status"], state["last"], state["samples"]),
            )
        print(("\r" + line + "\x1b[K") if tty else line)
        for text in _metrics_lines(status):
            print(text)
        _await_the_api(args)
        return exit_code(status.phase is ExecutionPhase.done, status.metrics)
    except KeyboardInterrupt:
        print()
        return 130
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
        session.close()


# --------------------------------------------------------------------------- registration


def register(commands: argparse._SubParsersAction) -> None:
    """Add this group's subcommands to the `contact-skills` parser."""
    router = commands.add_parser(
        "router", help="run the Zenoh router (embedded; until SIGINT/SIGTERM)", description=cmd_router.__doc__
    )
    router.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on, repeatable or comma-separated (env CONTACT_SKILLS_ZENOH_LISTEN; "
        "default tcp/127.0.0.1:7447)",
    )
    router.add_argument("--users", metavar="FILE", help="require a login: role:user:password per line, role api, "
                        "worker or observer (env CONTACT_SKILLS_ZENOH_USERS); access control by role")  # fmt: skip
    router.add_argument("--tls-cert", metavar="PEM", help="TLS certificate for tls/ endpoints (env ..._ZENOH_TLS_CERT)")
    router.add_argument("--tls-key", metavar="PEM", help="its private key (env CONTACT_SKILLS_ZENOH_TLS_KEY)")
    router.add_argument("--prefix", help="key-expression prefix the access control covers (default cskills)")
    router.add_argument("--log-level", default="info", choices=LOG_LEVELS, help=LOG_LEVEL_HELP)
    router.set_defaults(run=cmd_router)

    keys = commands.add_parser(
        "bus-keys", help="generate TLS certificates and logins for a secured bus", description=cmd_bus_keys.__doc__
    )
    keys.add_argument("folder", type=Path, metavar="DIR", help="folder to write into (created)")
    keys.add_argument("--host", action="append", help="router host name or address the clients use (repeatable)")
    keys.add_argument("--workers", type=int, default=2, help="worker logins worker-1..N (default 2)")
    keys.add_argument("--ca-path", help="path of ca.pem on the clients, written into the .env files")
    keys.add_argument("--endpoint", help="router endpoint written into the .env files, e.g. tls/router.lan:7447")
    keys.set_defaults(run=cmd_bus_keys)

    connect_help = (
        "router endpoint to connect to, repeatable or comma-separated (env CONTACT_SKILLS_ZENOH_ENDPOINTS; "
        "default tcp/127.0.0.1:7447)"
    )
    prefix_help = "key-expression prefix (env CONTACT_SKILLS_ZENOH_PREFIX; default cskills)"
    worker = commands.add_parser(
        "worker", help="run a sim worker on the Zenoh bus (until SIGINT/SIGTERM)", description=cmd_worker.__doc__
    )
    worker.add_argument("--connect", action="append", metavar="ENDPOINT", help=connect_help)
    worker.add_argument("--id", help="worker id (default: its bus login, else worker-<6 random hex digits>)")
    worker.add_argument("--prefix", help=prefix_help)
    worker.add_argument("--engine", choices=ENGINES, help=ENGINE_HELP)
    login_arguments(worker)
    worker.add_argument("--log-level", default="info", choices=LOG_LEVELS, help=LOG_LEVEL_HELP)
    worker.set_defaults(run=cmd_worker)

    watch = commands.add_parser(
        "watch", help="live view of an execution from the Zenoh bus", description=cmd_watch.__doc__
    )
    watch.add_argument("execution_id", metavar="EXECUTION_ID", help="the execution to follow (exec_...)")
    watch.add_argument("--connect", action="append", metavar="ENDPOINT", help=connect_help)
    watch.add_argument("--prefix", help=prefix_help)
    login_arguments(watch)
    watch.add_argument("--timeout", type=float, metavar="S", help="give up after S seconds without a final status")
    watch.add_argument(
        "--wait",
        type=float,
        default=10.0,
        metavar="S",
        help="without an answer from the API, the router named (--connect): give up if the bus says nothing of the "
        "execution for S s (default 10)",
    )
    watch.add_argument("--url", help=f"{URL_HELP}: asked about the execution first, and for the Zenoh endpoint")
    watch.add_argument(
        "--pace",
        choices=PACES,
        default="fast",
        help="fast: show the samples as they arrive; realtime: hold each back until its simulated time has passed on "
        "the clock, so a run executed at the default fast pace (~20x real time) is seen as it would run (default fast)",
    )
    watch.add_argument(
        "--from-start",
        action="store_true",
        help="replay the run from its first sample (the samples the API stored, then the live ones), also one that "
        "has ended",
    )
    watch.set_defaults(run=cmd_watch)
