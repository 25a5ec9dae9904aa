"""Waiting on a live service in tests: poll a condition until it holds or a deadline passes."""

from __future__ import annotations

import time
from collections.abc import Callable

import httpx


def wait_for(predicate: Callable[[], object], timeout_s: float, what: str, every_s: float = 0.2):
    """The first truthy value of ``predicate()``, polled every ``every_s`` s (an HTTP error counts as not yet);
    AssertionError naming ``what`` after ``timeout_s`` s."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            value = predicate()
        except httpx.HTTPError:
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(every_s)
