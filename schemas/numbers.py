"""Number types of the wire contract shared by its models (no I/O)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BeforeValidator, Field


def _not_a_boolean(value: object) -> object:
    """Refuse ``true`` / ``false`` where a number is asked: JSON's booleans are not numbers (pydantic's lax mode
    would take ``false`` as 0 and ``true`` as 1.0)."""
    if isinstance(value, bool):
        raise ValueError("a number, not a boolean")
    return value


WholeNumber = Annotated[int, BeforeValidator(_not_a_boolean)]
"""An integer a request gives (a seed, a count, a priority): a boolean is refused, naming the field."""

Real = Annotated[float, BeforeValidator(_not_a_boolean)]
"""A real number a model holds (a speed, a force, a gain, a time): a boolean is refused, naming the field. Scalar
fields only: an array of samples is checked whole by ``schemas.arrays``."""


def bounded_triple(low: float, high: float) -> type[list[float]]:
    """Three numbers, each within [low, high] (the bound is declared in the OpenAPI and enforced)."""
    return Annotated[list[Annotated[Real, Field(ge=low, le=high)]], Field(min_length=3, max_length=3)]  # type: ignore[return-value]
