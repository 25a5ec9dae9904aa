"""Number types of the wire contract shared by its models (no I/O)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BeforeValidator


def _not_a_boolean(value: object) -> object:
    """Refuse ``true`` / ``false`` where a count or a seed is asked: JSON's booleans are not numbers (pydantic's lax
    mode would take ``false`` as 0)."""
    if isinstance(value, bool):
        raise ValueError("a whole number, not a boolean")
    return value


WholeNumber = Annotated[int, BeforeValidator(_not_a_boolean)]
"""An integer a request gives (a seed, a count, a priority): a boolean is refused, naming the field."""
