"""Floods without a login, as an attacker holds them open (tests/test_floods.py, benchmarks/bench_floods.py): idle
TCP connections reopened as soon as the server closes them, request bodies that never arrive. Loopback only."""

from __future__ import annotations

import contextlib
import socket
import threading
import time

FLOOD_WAIT_S = 60.0
"""How long a flood waits to hold all its connections before it gives up, s (a loaded machine is slow)."""


def port_of(url: str) -> int:
    """The port of ``url`` (``http://127.0.0.1:PORT``)."""
    return int(url.rsplit(":", 1)[1])


def slow_body(url: str, timeout_s: float) -> socket.socket:
    """A connection to the API at ``url`` that sent a POST's head and the first byte of its 100 000-byte body
    (``timeout_s``: the socket's, s)."""
    sock = socket.create_connection(("127.0.0.1", port_of(url)), timeout=timeout_s)
    sock.sendall(b"POST /demonstrations HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                 b"Content-Length: 100000\r\n\r\n{")  # fmt: skip
    return sock


def closed(sock: socket.socket) -> bool:
    """Whether the server closed ``sock`` (without waiting)."""
    sock.setblocking(False)
    try:
        return sock.recv(65536) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True
    finally:
        sock.setblocking(True)


class IdleFlood:
    """``n`` idle TCP connections to ``port`` that send nothing, each reopened as soon as the router closes it
    (``_open``, ``_gone`` and ``_tend``: other floods, benchmarks/bench_floods.py's slow bodies)."""

    def __init__(self, port: int, n: int) -> None:
        self.port, self.n = port, n
        self.opened = 0
        self.held_most = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._hold, daemon=True)

    def _open(self) -> socket.socket:
        """One more connection of the flood (a subclass sends something first)."""
        return socket.create_connection(("127.0.0.1", self.port), timeout=5)

    def _gone(self, sock: socket.socket) -> bool:
        """Whether to reopen ``sock``: as soon as the router closed it."""
        return closed(sock)

    def _tend(self, held: list[socket.socket]) -> None:
        """What the flood does with the connections it ``held`` every round: nothing (they are idle)."""

    def _hold(self) -> None:
        held: list[socket.socket] = []
        while not self._stop.is_set():
            held = [s for s in held if not self._gone(s) or s.close()]
            while len(held) < self.n and not self._stop.is_set():
                with contextlib.suppress(OSError):
                    held.append(self._open())
                    self.opened += 1
            self.held_most = max(self.held_most, len(held))
            self._tend(held)
            self._stop.wait(0.01)
        for s in held:
            s.close()

    def __enter__(self) -> IdleFlood:
        self._thread.start()
        deadline = time.monotonic() + FLOOD_WAIT_S
        while self.held_most < self.n:
            if time.monotonic() > deadline:
                raise TimeoutError(f"held {self.held_most} of {self.n} connections after {FLOOD_WAIT_S} s")
            time.sleep(0.05)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(FLOOD_WAIT_S)
