"""The retention setting at work: a thread that deletes, every :data:`RETENTION_PASS_S`, the finished executions and
sweeps older than ``retention_days`` (``Store.retire``: what it deletes and keeps)."""

from __future__ import annotations

import logging
import threading

from services.store import Store

log = logging.getLogger("contact_skills.retention")

RETENTION_PASS_S = 3600.0
"""How often the retention runs, s (and once when the API starts)."""
DAY_S = 86_400.0


class Retention:
    """Deletes what is older than ``days`` (> 0) from ``store``, once at :meth:`start` and then every ``every_s``."""

    def __init__(self, store: Store, days: float, every_s: float = RETENTION_PASS_S) -> None:
        self.store, self.days, self.every_s = store, days, every_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="retention", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)

    def _run(self) -> None:
        while True:
            try:
                retired = self.store.retire(self.days * DAY_S)
                if retired.executions or retired.sweeps:
                    log.info("retention (%g days): deleted %d executions and %d sweeps", self.days,
                             retired.executions, retired.sweeps)  # fmt: skip
            except Exception:  # a failed pass (the database busy for long) is tried again on the next one
                log.exception("retention pass failed")
            if self._stop.wait(self.every_s):
                return
