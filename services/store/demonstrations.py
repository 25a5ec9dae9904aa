"""Stored demonstrations: the recording as validated JSON, and its summary for listings."""

from __future__ import annotations

import time

from pydantic import ValidationError

from schemas.demonstration import Demonstration, DemonstrationSummary
from services.store.database import Database, log, new_id
from services.store.rows import DemonstrationRow, first_problem

_COLUMNS = (
    "id, created, name, summary, json_extract(body, '$.metadata.source') AS source, "
    "length(body) + length(summary) AS stored_bytes"
)
"""The columns a :class:`DemonstrationRow` is read from."""


class StoredTooLarge(ValueError):  # noqa: N818 (reads as what happened)
    """A demonstration would take more than the room it was given (``DemonstrationRepository.add``'s ``max_bytes``)."""

    def __init__(self, stored_bytes: int, max_bytes: int) -> None:
        super().__init__(f"{stored_bytes} bytes to store, at most {max_bytes}")
        self.stored_bytes, self.max_bytes = stored_bytes, max_bytes


class DemonstrationRepository:
    """The ``demonstrations`` table."""

    def __init__(self, database: Database) -> None:
        self.database = database

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

    def get(self, demonstration_id: str) -> Demonstration | None:
        """The stored demonstration (validated again), or None: none stored, or one stored by an earlier version
        that no longer validates (logged)."""
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

        def delete() -> bool:
            with self.database.transaction() as db:
                return db.execute("DELETE FROM demonstrations WHERE id = ?", (demonstration_id,)).rowcount > 0

        return self.database.deletion(delete)
