"""Stored demonstrations: the recording as validated JSON, and its summary for listings.

A recording is stored as one JSON text (up to 200 000 samples: ~60 MB). Reading one whole takes ~5 times that in
Python objects while it is parsed, so the reads that need every sample (:meth:`DemonstrationRepository.samples`,
:meth:`DemonstrationRepository.get`) parse one recording at a time, and the last few recordings' samples are kept
as arrays: twelve concurrent paged reads of a 163 503-sample recording parse it once."""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict

import numpy as np
from pydantic import ValidationError

from schemas.demonstration import Demonstration, DemonstrationSummary
from schemas.text import MAX_NAME_CHARS, MAX_TEXT_CHARS
from services.store.database import Database, cut_text, log, new_id
from services.store.rows import DemonstrationRow, DemonstrationSamples, first_problem

_SUMMARY_NAME = "json_extract(summary, '$.name')"
_SOURCE_SQL = "json_extract(body, '$.metadata.source')"
_HEAD_COLUMNS = (
    f"id, created, {cut_text('name')} AS name, "
    f"CASE WHEN length({_SUMMARY_NAME}) > {MAX_NAME_CHARS} "
    f"THEN json_set(summary, '$.name', {cut_text(_SUMMARY_NAME)}) ELSE summary END AS summary"
)
"""The columns of a :class:`DemonstrationRow` that do not read the samples."""
_COLUMNS = (
    f"{_HEAD_COLUMNS}, {cut_text(_SOURCE_SQL, MAX_TEXT_CHARS)} AS source, "
    "length(body) + length(summary) AS stored_bytes"
)
"""The columns a :class:`DemonstrationRow` is read from: its name, summary's name and source cut to the bounds of
``schemas.text`` (rows stored before them may hold more)."""
SAMPLES_KEPT = 4
"""How many recordings' samples :meth:`DemonstrationRepository.samples` keeps parsed (the most recently read): at
most 4 x 200 000 samples x 14 float64 = 90 MB."""
_ARRAYS = {"t": (-1,), "positions": (-1, 3), "orientations": (-1, 4), "wrenches": (-1, 6)}
"""The sample arrays of a stored demonstration and their shapes."""


class StoredTooLarge(ValueError):  # noqa: N818 (reads as what happened)
    """A demonstration would take more than the room it was given (``DemonstrationRepository.add``'s ``max_bytes``)."""

    def __init__(self, stored_bytes: int, max_bytes: int) -> None:
        super().__init__(f"{stored_bytes} bytes to store, at most {max_bytes}")
        self.stored_bytes, self.max_bytes = stored_bytes, max_bytes


class DemonstrationRepository:
    """The ``demonstrations`` table."""

    def __init__(self, database: Database) -> None:
        self.database = database
        self._parsing = threading.Lock()  # one whole recording parsed at a time
        self._parsed: OrderedDict[str, DemonstrationSamples | str] = OrderedDict()  # id -> samples, or the problem

    def add(self, demonstration: Demonstration, max_bytes: int | None = None) -> DemonstrationRow:
        """Store ``demonstration``; return its row (with the new id). Raises :class:`StoredTooLarge` when its JSON
        and summary would take more than ``max_bytes``."""
        summary = DemonstrationSummary.of(demonstration)
        body, summary_json = demonstration.model_dump_json(), summary.model_dump_json()
        if max_bytes is not None and len(body) + len(summary_json) > max_bytes:
            raise StoredTooLarge(len(body) + len(summary_json), max_bytes)
        row = DemonstrationRow(
            id=new_id("demo"),
            created=time.time(),
            name=demonstration.metadata.name,
            summary=summary,
            source=demonstration.metadata.source,
            stored_bytes=len(body) + len(summary_json),
        )
        with self.database.transaction() as db:
            db.execute(
                "INSERT INTO demonstrations (id, created, name, summary, body) VALUES (?, ?, ?, ?, ?)",
                (row.id, row.created, row.name, summary_json, body),
            )
        return row

    def page(self, limit: int = 100, offset: int = 0) -> list[DemonstrationRow]:
        """Demonstration rows, newest first; one that cannot be read back is listed with its ``problem``."""
        rows = self.database.all(
            f"SELECT {_COLUMNS} FROM demonstrations ORDER BY created DESC, id LIMIT ? OFFSET ?", (limit, offset)
        )
        return [DemonstrationRow.of(r) for r in rows]

    def json(self, demonstration_id: str) -> tuple[DemonstrationRow, str] | None:
        """The row and the stored body (JSON text of a `Demonstration`), or None."""
        r = self.database.one(f"SELECT {_COLUMNS}, body FROM demonstrations WHERE id = ?", (demonstration_id,))
        return None if r is None else (DemonstrationRow.of(r), r["body"])

    def row(self, demonstration_id: str) -> DemonstrationRow | None:
        """The row without reading its samples (its id, creation time, name and summary; not its source nor its
        stored size, which take reading them), or None."""
        r = self.database.one(f"SELECT {_HEAD_COLUMNS} FROM demonstrations WHERE id = ?", (demonstration_id,))
        return None if r is None else DemonstrationRow.of(r)

    def samples(self, demonstration_id: str) -> DemonstrationSamples | str | None:
        """The stored samples as arrays with the metadata as stored; a string saying why they cannot be read (rows
        stored by an earlier version), or None when none is stored. Parsed one recording at a time, the last
        :data:`SAMPLES_KEPT` kept (ids are never reused: a kept recording is the stored one until deleted)."""
        with self._parsing:
            if (kept := self._parsed.get(demonstration_id)) is not None:
                self._parsed.move_to_end(demonstration_id)
                return kept
            r = self.database.one("SELECT body FROM demonstrations WHERE id = ?", (demonstration_id,))
            if r is None:
                return None
            parsed = _samples(r["body"])
            del r
            self._parsed[demonstration_id] = parsed
            while len(self._parsed) > SAMPLES_KEPT:
                self._parsed.popitem(last=False)
            return parsed

    def get(self, demonstration_id: str) -> Demonstration | None:
        """The stored demonstration (validated again), or None: none stored, or one stored by an earlier version
        that no longer validates (logged). Parsed one recording at a time, as :meth:`samples`."""
        with self._parsing:
            found = self.json(demonstration_id)
            if found is None:
                return None
            try:
                return Demonstration.model_validate_json(found[1])
            except ValidationError as exc:
                log.warning("stored demonstration %s cannot be read back: %s", demonstration_id, first_problem(exc))
                return None

    def delete(self, demonstration_id: str) -> bool:
        """Delete a demonstration; False if there was none. Skills learned from it keep their parameters."""
        with self._parsing:
            self._parsed.pop(demonstration_id, None)

        def delete() -> bool:
            with self.database.transaction() as db:
                return db.execute("DELETE FROM demonstrations WHERE id = ?", (demonstration_id,)).rowcount > 0

        return self.database.deletion(delete)


def _samples(body: str) -> DemonstrationSamples | str:
    """A stored demonstration's JSON text as arrays, or why it cannot be read as such."""
    try:
        stored = json.loads(body)
        arrays = {name: np.asarray(stored.pop(name), dtype=float).reshape(shape) for name, shape in _ARRAYS.items()}
    except (ValueError, TypeError, KeyError) as exc:
        return f"its samples do not parse: {exc}"
    if len({a.shape[0] for a in arrays.values()}) != 1:
        return "its sample arrays differ in length"
    metadata = stored.get("metadata", {})
    for field, chars in (("name", MAX_NAME_CHARS), ("source", MAX_TEXT_CHARS)):  # stored before they were bounded
        if isinstance(text := metadata.get(field), str) and len(text) > chars:
            metadata[field] = text[: chars - 1] + "…"
    return DemonstrationSamples(**arrays, metadata=json.dumps(metadata))
