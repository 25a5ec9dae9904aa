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

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from services.http_rules import browser_refusal, origin_set


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
