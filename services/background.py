"""A service's background thread that sleeps until woken: the execution queue's dispatcher and the sweeps' runner
(:class:`WakeableThread`)."""

from __future__ import annotations

import threading
from typing import Self

JOIN_TIMEOUT_S = 10.0
"""How long :meth:`WakeableThread.close` waits for the thread to end, s (it is a daemon: a stuck one dies with the
process)."""


class WakeableThread:
    """A daemon thread running :meth:`_run` from :meth:`start` until :meth:`close`: ``_run`` waits on ``_wake`` (set
    by :meth:`wake`, and by :meth:`close` so a sleeping loop ends at once) and ends when ``_stop`` is set."""

    thread_name = "background"
    """The thread's name in a stack dump."""

    def __init__(self) -> None:
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def wake(self) -> None:
        """Run the loop's next round now, not after its poll interval."""
        self._wake.set()

    def start(self) -> Self:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread (what it works on stays in the database, taken up again on the next start)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(JOIN_TIMEOUT_S)
            self._thread = None

    def _run(self) -> None:
        raise NotImplementedError
