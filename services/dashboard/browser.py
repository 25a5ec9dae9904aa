"""Headless Chromium driven by Playwright, as the dashboard's tests and benchmark run it: the system's Chromium
(Debian's ``chromium`` package; Playwright's own browser download is not used), no network of its own, a fresh
profile each time."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
"""Flags: no sandbox (root in a container), nothing fetched on its own (updates, sync, QUIC probes)."""


def chromium_path() -> str | None:
    """The system's Chromium, or None when it is not installed."""
    found = shutil.which("chromium")
    return found or (CHROMIUM if shutil.which(CHROMIUM) else None)


@contextmanager
def headless_chromium(viewport: tuple[int, int] = (1280, 900)) -> Iterator[Any]:
    """A Playwright browser context (``playwright.sync_api.BrowserContext``) of the system's Chromium in a fresh
    profile, closed afterwards. Raises ``FileNotFoundError`` when Chromium is not installed."""
    from playwright.sync_api import sync_playwright

    path = chromium_path()
    if path is None:
        raise FileNotFoundError("chromium is not installed (Debian: apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="chromium-") as profile, sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            profile,
            executable_path=path,
            args=CHROMIUM_ARGS,
            headless=True,
            viewport={"width": viewport[0], "height": viewport[1]},
        )
        try:
            yield context
        finally:
            context.close()
