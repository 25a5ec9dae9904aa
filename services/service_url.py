"""Where the service is, for everything that calls it: the typed client, ``watch``, ``export``, ``demo``, ``sweep`` and
the README's snippets. One setting, ``CONTACT_SKILLS_URL`` (e.g. ``http://127.0.0.1:8001``); an explicit ``--url`` or
``Client(url)`` wins over it. The Zenoh endpoint is not a second setting: a client asks the API (``GET /health``,
``zenoh_endpoints``).

Light on purpose (no httpx, no numpy): the command line builds its help from it.
"""

from __future__ import annotations

import os

from services.settings import DEFAULT_HOST, DEFAULT_PORT

URL_ENV = "CONTACT_SKILLS_URL"
"""Environment variable: the service's base URL."""
DEFAULT_URL = f"http://{DEFAULT_HOST}:{DEFAULT_PORT}"
"""Where ``make run`` / ``contact-skills up`` serve by default (loopback)."""
URL_HELP = f"the service's URL (default ${URL_ENV}, else {DEFAULT_URL})"
"""The ``--url`` option's help, the same in every command."""


def service_url(url: str | None = None) -> str:
    """``url`` if given, else ``$CONTACT_SKILLS_URL``, else :data:`DEFAULT_URL`; without a trailing slash."""
    return (url or os.environ.get(URL_ENV) or DEFAULT_URL).rstrip("/")


def not_answering(url: str, reason: str) -> str:
    """What every client says when no API answers at ``url`` (``reason``: why the connection failed): the URL it
    asked, how to start the service there, and the one setting that points a client at a service elsewhere."""
    return (
        f"the API at {url} does not answer ({reason}): start it (make run, or contact-skills up), or point "
        f"{URL_ENV} at the one that runs (e.g. export {URL_ENV}=http://127.0.0.1:8001; --url for one command)"
    )
