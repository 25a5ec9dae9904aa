"""Stored skills: the learned parameters as JSON, listed with their checks' outcome."""

from __future__ import annotations

import json
import time

from schemas.skill import SkillType
from services.store.database import Database, cut_text, new_id
from services.store.rows import SkillRow, SkillSummaryRow

_FAILED_CHECKS = "FROM json_each(skill, '$.checks') WHERE json_extract(value, '$.passed') = 0"
"""SQL: the failed checks of a stored skill (``skills.skill``), one row each (``value`` the check)."""
_DEMONSTRATION_NAME = "json_extract(skill, '$.demonstration.name')"


class SkillRepository:
    """The ``skills`` table."""

    def __init__(self, database: Database) -> None:
        self.database = database

    def add(
        self, skill_json: str, skill_type: SkillType, demonstration_id: str | None, warnings: list[str]
    ) -> SkillRow:
        """Store a skill given as JSON text (``warnings``: its failed checks' messages); return its row."""
        row = SkillRow(new_id("skill"), demonstration_id, time.time(), SkillType(skill_type), skill_json, warnings)
        with self.database.transaction() as db:
            db.execute(
                "INSERT INTO skills (id, demonstration_id, created, skill_type, skill) VALUES (?, ?, ?, ?, ?)",
                (row.id, row.demonstration_id, row.created, row.skill_type.value, row.skill_json),
            )
        return row

    def get(self, skill_id: str) -> SkillRow | None:
        r = self.database.one(
            "SELECT id, demonstration_id, created, skill_type, skill, "
            f"(SELECT json_group_array(json_extract(value, '$.message')) {_FAILED_CHECKS}) FROM skills WHERE id = ?",
            (skill_id,),
        )
        return None if r is None else SkillRow(r[0], r[1], r[2], SkillType(r[3]), r[4], json.loads(r[5]))

    def page(self, limit: int = 100, offset: int = 0) -> list[SkillSummaryRow]:
        """Skill summaries (no parameters), newest first."""
        rows = self.database.all(
            "SELECT id, demonstration_id, created, skill_type, json_array_length(skill, '$.segments') AS segments, "
            "json_extract(skill, '$.auto_selection.confidence') AS confidence, "
            f"(SELECT count(*) {_FAILED_CHECKS}) AS failed_checks, "
            f"{cut_text(_DEMONSTRATION_NAME)} AS demonstration_name "
            "FROM skills ORDER BY created DESC, id LIMIT ? OFFSET ?",
            (limit, offset),
        )
        return [SkillSummaryRow(**{**dict(r), "skill_type": SkillType(r["skill_type"])}) for r in rows]

    def delete(self, skill_id: str) -> bool:
        """Delete a skill; False if there was none. Executions that used it keep their records."""

        def delete() -> bool:
            with self.database.transaction() as db:
                return db.execute("DELETE FROM skills WHERE id = ?", (skill_id,)).rowcount > 0

        return self.database.deletion(delete)
