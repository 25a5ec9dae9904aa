"""Free-form input bounded at the door: names, ids, lines of text and free-form dicts a request gives (no I/O).

Every free-form string and dict of a request schema is one of these types, so a field too long, nested too deep or
holding a lone surrogate (``"\\ud800"``: no UTF-8 can store it) is a 422 naming it, and nothing is stored that is
too large to list or too deep to read back (docs/SERVICE.md, "Every read is bounded").
"""

from __future__ import annotations

import json
from typing import Annotated

from pydantic import BeforeValidator, Field, JsonValue, WithJsonSchema

MAX_NAME_CHARS = 255
"""Longest name (a demonstration's, a topic's, a frame's, a unit), characters: the longest file name most file
systems take, so a file's name always fits as its demonstration's name."""
MAX_ID_CHARS = 64
"""Longest id or scenario name a request refers to, characters (ids are a kind prefix and 12 hex digits)."""
MAX_TEXT_CHARS = 2000
"""Longest line of free text (a demonstration's source, a check's message, a reason), characters."""
MAX_FREE_FORM_DEPTH = 16
"""Deepest nesting of a free-form dict (``metadata.extra``, a skill's ``taught_world``, a recording's overrides):
the dict itself is depth 1. JSON readers recurse per level (pydantic's stops at 200: a deeper dict stored would not
read back); a teacher recording's ``extra`` is 5 deep."""
MAX_FREE_FORM_BYTES = 64 * 1024
"""Largest free-form dict, bytes of its UTF-8 JSON (a teacher recording's ``extra``, its world and ground truth, takes
~4 KB)."""


def _is_text(value: str) -> str:
    """``value``, unless it holds a lone surrogate (``\\ud800``): a string no UTF-8 encoder can write (pydantic's
    ``str`` refuses it; a free-form dict's strings are not validated as ``str``)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise ValueError(
            f"holds a lone surrogate (U+{ord(value[exc.start]):04X} at character {exc.start}): not text UTF-8 can "
            "hold; send each character as itself or as a surrogate pair"
        ) from None
    return value


def _is_bounded_free_form(value: object) -> object:
    """``value``, unless it nests deeper than :data:`MAX_FREE_FORM_DEPTH`, holds a string or key that is not text
    (:func:`_is_text`) or takes more than :data:`MAX_FREE_FORM_BYTES` as JSON. Walked without recursion, so a dict
    nested 10 000 deep is refused as quickly as one 17 deep; run BEFORE the ``JsonValue`` types are checked (they
    recurse per level: one error per level of a deep dict, the field lost among them), on the raw input, so what is
    not JSON is left to them."""
    pending: list[tuple[object, str, int]] = [(value, "", 1)]
    while pending:
        item, path, depth = pending.pop()
        if isinstance(item, dict | list) and depth > MAX_FREE_FORM_DEPTH:
            raise ValueError(f"nested deeper than {MAX_FREE_FORM_DEPTH} levels (at {path or 'the top'})")
        if isinstance(item, dict):
            for key, child in item.items():
                _is_text(str(key))
                pending.append((child, f"{path}.{key}" if path else str(key), depth + 1))
        elif isinstance(item, list):
            pending.extend((child, f"{path}[{k}]", depth + 1) for k, child in enumerate(item))
        elif isinstance(item, str):
            _is_text(item)
    try:
        size = len(json.dumps(value, ensure_ascii=False).encode("utf-8"))
    except (TypeError, ValueError):  # not JSON (a Python object, a NaN): the JsonValue check names it
        return value
    if size > MAX_FREE_FORM_BYTES:
        raise ValueError(f"takes {size} bytes as JSON, more than {MAX_FREE_FORM_BYTES // 1024} KiB")
    return value


Name = Annotated[str, Field(max_length=MAX_NAME_CHARS)]
"""A name: at most :data:`MAX_NAME_CHARS` characters (pydantic's ``str`` refuses a lone surrogate itself)."""
Identifier = Annotated[str, Field(max_length=MAX_ID_CHARS)]
"""An id or a scenario's name: at most :data:`MAX_ID_CHARS` characters."""
Text = Annotated[str, Field(max_length=MAX_TEXT_CHARS)]
"""A line of free text: at most :data:`MAX_TEXT_CHARS` characters."""
JsonObject = dict[str, Annotated[JsonValue, WithJsonSchema({})]]
"""An open JSON object: its values pydantic's ``JsonValue`` (strings, numbers, booleans, null, lists and objects of
them; a tuple or a numpy integer is refused). Its JSON schema is any object, as the OpenAPI has always declared it
(pydantic's own would add a ``JsonValue`` definition that accepts anything)."""
FreeForm = Annotated[JsonObject, BeforeValidator(_is_bounded_free_form)]
"""A free-form JSON object (:data:`JsonObject`): at most :data:`MAX_FREE_FORM_DEPTH` levels deep and
:data:`MAX_FREE_FORM_BYTES` of JSON, its keys and strings text."""
