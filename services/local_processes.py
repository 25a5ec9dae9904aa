"""Loopback ports and child processes: what `contact-skills up`, the demo, the tests and the benchmarks share to run
the stack locally."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

LOOPBACK = "127.0.0.1"
THREAD_LIMIT_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""One BLAS/OpenMP thread per process: the service runs several processes (API, learners, workers) on few cores,
and each library's default of one thread per core makes them oversubscribe (50 learns: 173-252 s instead of 10 s)."""


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time a live process has used so far, s (Linux ``/proc``); None where it cannot be read (no
    ``/proc``, or the process is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def with_thread_limits(env: dict[str, str]) -> dict[str, str]:
    """``env`` with :data:`THREAD_LIMIT_ENV` for every variable it does not set itself."""
    return {**THREAD_LIMIT_ENV, **env}


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that nothing listens on right now (the OS picks it)."""
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


def port_free(port: int, host: str = LOOPBACK) -> bool:
    """Return whether a server could listen on ``host``:``port`` now (nothing bound there)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn and zenoh bind: TIME_WAIT is no obstacle
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def port_listening(port: int) -> bool:
    """Return whether something accepts TCP connections on 127.0.0.1:``port``."""
    with socket.socket() as s:
        return s.connect_ex((LOOPBACK, port)) == 0


def wait_for_port(port: int, timeout_s: float) -> None:
    """Wait until something listens on 127.0.0.1:``port``; raise TimeoutError after ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if port_listening(port):
            return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listening on {LOOPBACK}:{port} after {timeout_s:.0f} s")


def stop_process(process: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """Stop a child process: SIGTERM, then SIGKILL if it has not exited within ``timeout_s``; always reaped."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def spawn_cli(
    args: list[str], log: Path, cwd: Path | None = None, env: dict[str, str] | None = None
) -> subprocess.Popen:
    """Start ``contact-skills ARGS`` as a child process (this interpreter), its output appended to ``log``; ``env``:
    variables added to this process's environment.

    One BLAS thread and unbuffered output, so several children share the cores and their logs are current.
    """
    env = {**with_thread_limits(dict(os.environ)), **(env or {}), "PYTHONUNBUFFERED": "1"}
    if cwd is not None:
        env["PYTHONPATH"] = str(cwd)
    with log.open("ab") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "cli.main", *args], cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT
        )


def parent_death_signal():  # -> Callable[[], None] | None
    """A ``preexec_fn`` that makes the child get SIGTERM when its parent dies, even by SIGKILL (Linux ``prctl``);
    None elsewhere.

    Resolved here, in the parent: the function run between fork and exec imports nothing."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes
    import signal

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    sigterm = int(signal.SIGTERM)

    def preexec() -> None:
        prctl(1, sigterm)  # PR_SET_PDEATHSIG

    return preexec
