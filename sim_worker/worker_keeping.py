"""What a sim worker keeps between its jobs, bounded: the demonstrations starts sent (:class:`KeptDemonstrations`),
and each recent execution's secret and latest status as sent (:class:`ReportBook`), which sign its reports and answer
the status queries of late joiners."""

from __future__ import annotations

import threading
from collections import OrderedDict

from schemas.bus import StartExecution
from schemas.bus_security import challenge_signature, report_signature
from schemas.demonstration import Demonstration

STATUS_CACHE = 200
"""Latest statuses (and the secrets of their executions) kept for the status queryable (executions of this
worker)."""
DEMONSTRATIONS_CACHED = 4
"""Demonstrations kept for the starts that name them (``StartExecution.demonstration_id``), at most."""
DEMONSTRATION_SAMPLES_KEPT = 100_000
"""Samples of the kept demonstrations, at most (the newest is kept whatever its size): as validated models (lists
of Python floats) a sample takes ~640 bytes, so about 64 MB; a minute at 1 kHz is 38 MB. A start naming one no
longer kept is answered ``need_demonstration`` and the API sends it again."""


def _kept(book: OrderedDict, key: str, value: object, most: int) -> None:
    """``book[key] = value`` as its most recent entry, the oldest dropped beyond ``most`` entries."""
    book[key] = value
    book.move_to_end(key)
    while len(book) > most:
        book.popitem(last=False)


class KeptDemonstrations:
    """The demonstrations starts sent, by their stored id, the most recently named last: at most ``count`` of them
    and ``samples`` samples in all (the newest stays whatever its size)."""

    def __init__(self, count: int = DEMONSTRATIONS_CACHED, samples: int = DEMONSTRATION_SAMPLES_KEPT) -> None:
        self.count, self.samples = count, samples
        self.kept: OrderedDict[str, Demonstration] = OrderedDict()
        self._lock = threading.Lock()

    def completed(self, start: StartExecution) -> StartExecution | None:
        """``start`` with its demonstration: as sent (and kept under its ``demonstration_id`` for the starts that
        follow), or the copy kept of the one it names; None when it names one not kept."""
        key = start.demonstration_id
        if key is None:
            return start
        with self._lock:
            if start.demonstration is not None:
                self.kept[key] = start.demonstration
            kept = self.kept.get(key)
            if kept is not None:
                self.kept.move_to_end(key)
            while len(self.kept) > 1 and (
                len(self.kept) > self.count or sum(len(d.t) for d in self.kept.values()) > self.samples
            ):
                self.kept.popitem(last=False)  # the least recently named first
        if kept is None:
            return None
        return start if start.demonstration is not None else start.model_copy(update={"demonstration": kept})


class ReportBook:
    """Each recent execution's secret (the start query's attachment: what its reports are signed with) and its latest
    status as sent (payload, signature), :data:`STATUS_CACHE` of each."""

    def __init__(self) -> None:
        self._secrets: OrderedDict[str, bytes] = OrderedDict()
        self._statuses: OrderedDict[str, tuple[bytes, bytes | None]] = OrderedDict()
        self._lock = threading.Lock()

    def keep_secret(self, execution_id: str, secret: bytes) -> None:
        with self._lock:
            _kept(self._secrets, execution_id, secret, STATUS_CACHE)

    def signature(self, execution_id: str, data: bytes) -> bytes | None:
        """The attachment of a report of ``execution_id`` (``schemas.bus_security.report_signature``); None for an
        execution started without a secret (a caller that checks none)."""
        with self._lock:
            secret = self._secrets.get(execution_id)
        return None if secret is None else report_signature(secret, data)

    def keep_status(self, execution_id: str, data: bytes, signature: bytes | None) -> None:
        with self._lock:
            _kept(self._statuses, execution_id, (data, signature), STATUS_CACHE)

    def statuses(self, challenge: bytes) -> list[tuple[str, bytes, bytes | None]]:
        """(execution id, status as sent, its attachment) of each status kept: signed with ``challenge`` when one is
        given and the execution has a secret (the asker wants proof the worker answers now), else as sent."""
        with self._lock:
            kept = [(e, data, signature, self._secrets.get(e)) for e, (data, signature) in self._statuses.items()]
        return [
            (e, data, challenge_signature(secret, data, challenge) if challenge and secret is not None else signature)
            for e, data, signature, secret in kept
        ]
