"""What a web browser may do with the API, as ASGI middleware: the CORS policy and the Host check.

- **Origins.** A browser sends ``Origin`` with every cross-origin POST, including the "simple" form posts it sends
  without asking first (a page elsewhere could otherwise post a CSV to a service on the visitor's loopback). A
  request whose ``Origin`` is neither the API itself nor in ``CONTACT_SKILLS_CORS_ORIGINS`` gets 403; none is
  allowed by default. The allowed ones get CORS headers (Starlette's ``CORSMiddleware``). Clients that are not
  browsers (curl, httpx, the CLI) send no ``Origin`` and are not affected.
- **Host.** On every bind, the API answers only requests addressed to one of its names
  (``ServiceSettings.host_names``: loopback names, the address it binds, this host's name, and
  ``CONTACT_SKILLS_ALLOWED_HOSTS``): a DNS-rebinding page, whose requests carry its own host name, gets 400, whether
  the API listens on loopback or, in a container, on every interface.
"""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
"""Host names a loopback-bound API answers to."""


def _host_name(host_header: str) -> str:
    """The name in a ``Host`` header or an origin's netloc, without the port (``[::1]:8000`` -> ``::1``)."""
    return (urlsplit(f"//{host_header}").hostname or "").lower()


def browser_refusal(
    headers: Mapping[str, str], allowed: set[str], host_names: frozenset[str]
) -> tuple[int, str] | None:
    """Why a request with ``headers`` (lower-case names) is refused, as (status, detail), or None: 400 for a ``Host``
    whose name is not in ``host_names``, 403 for an ``Origin`` neither the request's own (its ``Host``) nor in
    ``allowed`` (lower-case, without a trailing slash). The rule of the REST API and of the Foxglove live view's
    WebSocket handshake (``services.origin_gate``)."""
    host = headers.get("host", "")
    if _host_name(host) not in host_names:
        names = ", ".join(sorted(host_names - LOOPBACK_NAMES))
        return 400, (f"Host {host!r} is neither a loopback name nor one of this service's ({names}); "
                     "CONTACT_SKILLS_ALLOWED_HOSTS adds names")  # fmt: skip
    origin = headers.get("origin")
    if origin is None or origin.rstrip("/").lower() in allowed or urlsplit(origin).netloc.lower() == host.lower():
        return None
    return 403, f"cross-origin request from {origin} refused: allow it with CONTACT_SKILLS_CORS_ORIGINS"


def origin_set(origins: list[str]) -> set[str]:
    """``CONTACT_SKILLS_CORS_ORIGINS`` as :func:`browser_refusal` compares them."""
    return {origin.rstrip("/").lower() for origin in origins}


class BrowserGuard:
    """ASGI middleware: 403 for a cross-origin request from an origin not in ``allowed_origins``; 400 for a ``Host``
    whose name is not in ``host_names`` (:func:`browser_refusal`)."""

    def __init__(self, app: ASGIApp, allowed_origins: list[str], host_names: frozenset[str]) -> None:
        self.app = app
        self.allowed = origin_set(allowed_origins)
        self.host_names = host_names

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers") or []}
        if refusal := browser_refusal(headers, self.allowed, self.host_names):
            status, detail = refusal
            await JSONResponse({"detail": detail}, status_code=status)(scope, receive, send)
            return
        await self.app(scope, receive, send)
