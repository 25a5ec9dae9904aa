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

from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
"""Host names a loopback-bound API answers to."""


def _host_name(host_header: str) -> str:
    """The name in a ``Host`` header or an origin's netloc, without the port (``[::1]:8000`` -> ``::1``)."""
    return (urlsplit(f"//{host_header}").hostname or "").lower()


class BrowserGuard:
    """ASGI middleware: 403 for a cross-origin request from an origin not in ``allowed_origins``; 400 for a ``Host``
    whose name is not in ``host_names``."""

    def __init__(self, app: ASGIApp, allowed_origins: list[str], host_names: frozenset[str]) -> None:
        self.app = app
        self.allowed = {origin.rstrip("/").lower() for origin in allowed_origins}
        self.host_names = host_names

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers") or []}
        host = headers.get("host", "")
        if _host_name(host) not in self.host_names:
            names = ", ".join(sorted(self.host_names - LOOPBACK_NAMES))
            detail = (f"Host {host!r} is neither a loopback name nor one of this service's ({names}); "
                      "CONTACT_SKILLS_ALLOWED_HOSTS adds names")  # fmt: skip
            await JSONResponse({"detail": detail}, status_code=400)(scope, receive, send)
            return
        origin = headers.get("origin")
        if origin is not None and origin.rstrip("/").lower() not in self.allowed:
            same = urlsplit(origin).netloc.lower() == host.lower()
            if not same:
                detail = f"cross-origin request from {origin} refused: allow it with CONTACT_SKILLS_CORS_ORIGINS"
                await JSONResponse({"detail": detail}, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)
