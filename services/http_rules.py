"""The rules both of the service's HTTP servers apply, the REST API's (``services/api/``: ``browser_guard.py``,
``limits.py``) and the Foxglove live view's WebSocket gate (``services/origin_gate.py``): which browser requests are
refused, and how large a request head may be."""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import urlsplit

MAX_HEAD_BYTES = 64 * 1024
"""Largest request head (request line and headers) a server of the service takes, bytes; a larger one: 431."""

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
