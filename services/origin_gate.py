"""The browser rule of the REST API (``services.http_rules.browser_refusal``: a ``Host`` among the service's
names, an ``Origin`` that is the request's own or allowed by ``CONTACT_SKILLS_CORS_ORIGINS``) in front of a WebSocket
server that checks neither: the Foxglove SDK's (``services.foxglove_live``), which accepted a handshake from any web
page's origin.

:class:`OriginGate` listens where the server is reached, reads each connection's handshake (at most
``services.http_rules.MAX_HEAD_BYTES`` within :data:`HANDSHAKE_TIMEOUT_S`), answers a refused one 400 or 403 and
closes it, and relays an accepted one, byte for byte both ways, to the server on a loopback port of its own.

It also answers a client that names the server's subprotocol by another name (``subprotocol_aliases``: Foxglove's
``foxglove.websocket.v1``, which the SDK's server calls ``foxglove.sdk.v1`` and refuses): when the client offers an
alias and none of the server's own names, the handshake reaches the server with the server's name, and the server's
answer reaches the client with the name the client offered (the ``Sec-WebSocket-Accept`` depends on the key alone, so
nothing else changes); every byte after the handshake is relayed unchanged.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from http import HTTPStatus

from services.http_rules import MAX_HEAD_BYTES, browser_refusal, origin_set

log = logging.getLogger("contact_skills.foxglove")

HANDSHAKE_TIMEOUT_S = 10.0
"""How long a connection has to send its whole handshake request, s (the API's header timeout's default)."""
RELAY_CHUNK = 65536
"""Bytes relayed per read."""
PROTOCOL_HEADER = "sec-websocket-protocol"


class OriginGate:
    """A TCP front on ``host``:``port`` (0: any free port) of the WebSocket server on ``127.0.0.1``:``upstream_port``
    that refuses what :func:`~services.http_rules.browser_refusal` refuses (``allowed_origins``, ``host_names``
    as ``ServiceSettings.cors_origins``, ``.host_names``), and answers a client offering a subprotocol by a name of
    ``subprotocol_aliases`` (alias -> the server's name) in that name (see the module docstring). :meth:`start` raises
    ``OSError`` if the port is taken."""

    def __init__(
        self,
        host: str,
        port: int,
        upstream_port: int,
        allowed_origins: list[str],
        host_names: frozenset[str],
        subprotocol_aliases: dict[str, str] | None = None,
    ) -> None:
        self.host, self.port, self.upstream_port = host, port, upstream_port
        self.allowed = origin_set(allowed_origins)
        self.host_names = host_names
        self.aliases = dict(subprotocol_aliases or {})
        self._loop = asyncio.new_event_loop()
        self._server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()  # every open connection's, both sides: closed by close()
        self._thread = threading.Thread(target=self._loop.run_forever, name="foxglove-gate", daemon=True)

    def start(self) -> int:
        """Listen, and relay in a thread of its own (its own event loop: this may run in the API's); returns the port
        listened on."""
        self._thread.start()
        start = asyncio.start_server(self._serve, self.host, self.port, limit=MAX_HEAD_BYTES)
        try:
            self._server = asyncio.run_coroutine_threadsafe(start, self._loop).result(HANDSHAKE_TIMEOUT_S)
        except OSError:
            self._stop_loop()
            raise
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    def close(self) -> None:
        """Stop listening and drop every relayed connection."""
        if self._server is not None:
            server, self._server = self._server, None

            async def stop() -> None:
                server.close()
                for writer in list(self._writers):
                    writer.close()
                await server.wait_closed()

            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(HANDSHAKE_TIMEOUT_S)
        self._stop_loop()

    def _stop_loop(self) -> None:
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(HANDSHAKE_TIMEOUT_S)
        self._loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            await self._gate(reader, writer)
        finally:
            self._writers.discard(writer)

    async def _gate(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
        except (TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
            writer.close()
            return
        lines = head.decode("latin-1").split("\r\n")[1:]
        headers = {name.strip().lower(): value.strip() for name, _, value in (line.partition(":") for line in lines)}
        if refusal := browser_refusal(headers, self.allowed, self.host_names):
            status, detail = refusal
            body = detail.encode()
            writer.write(f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\nContent-Type: text/plain; charset=utf-8"
                         f"\r\nContent-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode() + body)  # fmt: skip
            await _close(writer)
            return
        try:
            upstream_reader, upstream_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port)
        except OSError:
            log.warning("Foxglove live view: its server on port %d does not answer", self.upstream_port)
            writer.close()
            return
        self._writers.add(upstream_writer)
        try:
            alias = offered_alias(lines, self.aliases)
            upstream_writer.write(head if alias is None else renamed_subprotocol(head, self.aliases[alias]))
            if alias is not None:  # the server's answer, under the name the client offered
                with contextlib.suppress(asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
                    answer = await asyncio.wait_for(upstream_reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
                    writer.write(renamed_subprotocol(answer, alias, only=self.aliases[alias]))
            await asyncio.gather(_relay(reader, upstream_writer), _relay(upstream_reader, writer))
        finally:
            self._writers.discard(upstream_writer)


def offered_subprotocols(lines: list[str]) -> list[str]:
    """The subprotocols a handshake's header ``lines`` offer, in order (every ``Sec-WebSocket-Protocol`` header,
    comma-separated names)."""
    offered = []
    for line in lines:
        name, _, value = line.partition(":")
        if name.strip().lower() == PROTOCOL_HEADER:
            offered += [item.strip() for item in value.split(",") if item.strip()]
    return offered


def offered_alias(lines: list[str], aliases: dict[str, str]) -> str | None:
    """The first alias (a key of ``aliases``) the handshake's header ``lines`` offer, if they offer none of the
    server's own names (the values); else None (the handshake goes to the server as it is)."""
    offered = offered_subprotocols(lines)
    if set(offered) & set(aliases.values()):
        return None
    return next((name for name in offered if name in aliases), None)


def renamed_subprotocol(head: bytes, name: str, only: str | None = None) -> bytes:
    """An HTTP ``head`` (ending in a blank line) whose ``Sec-WebSocket-Protocol`` headers are replaced by one naming
    ``name``; with ``only``, a head that names another subprotocol (or none: a refusal) is returned as it is."""
    lines = head.decode("latin-1").split("\r\n")
    named = [k for k, line in enumerate(lines) if line.partition(":")[0].strip().lower() == PROTOCOL_HEADER]
    if only is not None and offered_subprotocols([lines[k] for k in named]) != [only]:
        return head
    kept = [line for k, line in enumerate(lines) if k not in named]
    end = kept.index("")  # the blank line that ends the head
    return "\r\n".join([*kept[:end], f"Sec-WebSocket-Protocol: {name}", *kept[end:]]).encode("latin-1")


async def _relay(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """Copy ``reader`` to ``writer`` until either side closes, then close ``writer``."""
    with contextlib.suppress(ConnectionError):
        while chunk := await reader.read(RELAY_CHUNK):
            writer.write(chunk)
            await writer.drain()
    await _close(writer)


async def _close(writer: asyncio.StreamWriter) -> None:
    writer.close()
    with contextlib.suppress(ConnectionError):
        await writer.wait_closed()
