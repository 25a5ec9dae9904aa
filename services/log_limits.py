"""Logging that a flood cannot grow without bound: :class:`RateLimitFilter` lets each kind of record (its logger and
message template) through at most once per interval, and says how many it held back.

The API installs it on its log handlers (`services.app.serve_api`), the bus client on its logger: 20 600 slow
connections or a flood of forged reports once grew the log by 166 MB in 39 s of tracebacks."""

from __future__ import annotations

import logging
import threading
import time

LOG_EVERY_S = 10.0
"""A kind of log record passes at most once per this many seconds, s."""


class RateLimitFilter(logging.Filter):
    """Passes the first record of each kind (logger name and unformatted message), then at most one per ``every_s``
    seconds; a record let through after others were held back says how many, and carries no traceback if the kind
    had one before (the first traceback of a kind is enough to debug it)."""

    def __init__(self, every_s: float = LOG_EVERY_S) -> None:
        super().__init__()
        self.every_s = every_s
        self._lock = threading.Lock()
        self._kinds: dict[tuple[str, str], tuple[float, int]] = {}  # kind -> (time.monotonic() let through, held)

    def filter(self, record: logging.LogRecord) -> bool:
        kind = (record.name, str(record.msg))
        now = time.monotonic()
        with self._lock:
            last, held = self._kinds.get(kind, (None, 0))
            if last is not None and now - last < self.every_s:
                self._kinds[kind] = (last, held + 1)
                return False
            self._kinds[kind] = (now, 0)
            if len(self._kinds) > 10_000:  # many distinct messages: forget the oldest kinds
                for old in sorted(self._kinds, key=lambda k: self._kinds[k][0])[:5_000]:
                    del self._kinds[old]
        if last is not None:
            record.exc_info, record.exc_text = None, None
        if held:
            record.msg = f"{record.msg} ({held} more like this held back in the last {now - last:.0f} s)"
        return True
