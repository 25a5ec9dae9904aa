"""Replies built from already-serialized JSON (stored demonstrations and skills are kept as JSON text), files to
save, bodies streamed in chunks, and pages of a list bounded in bytes."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import TypeAlias, TypeVar

import numpy as np
from fastapi import Response
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, JsonValue

from schemas.api import NEXT_OFFSET_HEADER

RowT = TypeVar("RowT")
OpenApiResponses: TypeAlias = dict[int | str, dict[str, type[BaseModel] | JsonValue]]
"""A route's ``responses=``: by status, FastAPI's ``model`` (the body's pydantic class) and members of an OpenAPI
Response Object (``description``, ``headers``, ``content``)."""


def raw_json(parts: Mapping[str, JsonValue], raw: dict[str, str], status_code: int = 200) -> Response:
    """A JSON object from JSON-able ``parts`` and already-serialized ``raw`` members (no re-encoding)."""
    members = [f"{json.dumps(k)}:{json.dumps(v)}" for k, v in parts.items()]
    members += [f"{json.dumps(k)}:{v}" for k, v in raw.items()]
    return Response("{" + ",".join(members) + "}", status_code=status_code, media_type="application/json")


def download(content: str | bytes, media_type: str, filename: str) -> Response:
    """A file to save: ``content`` with its media type and a ``Content-Disposition`` naming ``filename``."""
    return Response(
        content, media_type=media_type, headers={"Content-Disposition": f'attachment; filename="{filename}"'}
    )


def streamed(
    chunks: Iterable[str | bytes], media_type: str, filename: str | None = None, headers: dict[str, str] | None = None
) -> StreamingResponse:
    """A body sent chunk by chunk as ``chunks`` yields them (never held whole), a file to save when ``filename`` is
    given, with ``headers``."""
    disposition = {"Content-Disposition": f'attachment; filename="{filename}"'} if filename else {}
    return StreamingResponse(chunks, media_type=media_type, headers={**disposition, **(headers or {})})


LIST_PAGE_BYTES = 4 * 2**20
"""Most bytes of one page of a list (``GET /demonstrations``, ``/skills``, ``/executions``, ``/sweeps``): a page
stops before it (with at least one item) and names the next one in :data:`NEXT_OFFSET_HEADER`. Listed items are a few
hundred bytes (an execution with its metrics a few KB): only a list of very large items is cut before ``limit``."""
LIST_RESPONSES: OpenApiResponses = {
    200: {
        "headers": {
            NEXT_OFFSET_HEADER: {
                "description": f"The next page's offset: present while more items follow (a page holds at most "
                f"``limit`` items and {LIST_PAGE_BYTES // 2**20} MiB).",
                "schema": {"type": "integer"},
            }
        }
    }
}
"""OpenAPI ``responses`` of a list route."""


def list_page(rows: Sequence[RowT], view: Callable[[RowT], BaseModel], offset: int, limit: int) -> Response:
    """A page of a list as a JSON array: the views of ``rows`` (read from ``offset``, up to ``limit`` + 1: one more
    than asked tells that more follow), stopped before :data:`LIST_PAGE_BYTES` (at least one item: every page moves on),
    with :data:`NEXT_OFFSET_HEADER` when more follow. A view is built only for an item that is sent."""
    items: list[bytes] = []
    size = 2  # the brackets
    for row in rows[:limit]:
        item = view(row).model_dump_json().encode()
        grown = size + len(item) + bool(items)  # a comma before every item but the first
        if items and grown > LIST_PAGE_BYTES:
            break
        items.append(item)
        size = grown
    more = len(items) < len(rows)
    headers = {NEXT_OFFSET_HEADER: str(offset + len(items))} if more else {}
    return Response(b"[" + b",".join(items) + b"]", media_type="application/json", headers=headers)


SAMPLES_PAGE_BYTES = 8 * 2**20
"""Most bytes of one page of a demonstration's samples (``GET /demonstrations/{id}``): ~23 000 samples at the
longest a number can be written, ~30 000 as recordings' numbers are (a 163 503-sample recording is 46 MB of JSON)."""
MAX_NUMBER_JSON_CHARS = 24
"""Longest JSON text of a finite float64 (``-1.2345678901234567e-100``)."""
SAMPLE_JSON_BYTES = 14 * (MAX_NUMBER_JSON_CHARS + 1) + 3 * 3
"""Most bytes one sample takes in the JSON of a demonstration: its 14 numbers (t, position, quaternion, wrench) with
their commas, and the brackets and comma of its three rows."""
SAMPLE_CHUNK_ROWS = 2000
"""Samples written per chunk of a streamed reply."""


def samples_that_fit(other_bytes: int) -> int:
    """How many samples a reply of :data:`SAMPLES_PAGE_BYTES` holds besides ``other_bytes`` of other members (at
    least one: every page moves on)."""
    return max(1, (SAMPLES_PAGE_BYTES - other_bytes) // SAMPLE_JSON_BYTES)


def samples_json_chunks(
    head: Mapping[str, object], member: str | None, columns: dict[str, np.ndarray], raw: dict[str, str]
) -> Iterator[str]:
    """A JSON object of ``head``'s (JSON-able) members and then, in an object named ``member`` (None: in the same
    object), the ``columns`` (arrays, one row per sample) written :data:`SAMPLE_CHUNK_ROWS` rows at a time and the
    already-serialized ``raw`` members. A reply sent in chunks, never held whole."""
    yield "{" + "".join(f"{json.dumps(key)}:{json.dumps(value)}," for key, value in head.items())
    if member is not None:
        yield f"{json.dumps(member)}:{{"
    for k, (name, values) in enumerate(columns.items()):
        yield f"{',' if k else ''}{json.dumps(name)}:["
        for a in range(0, values.shape[0], SAMPLE_CHUNK_ROWS):
            yield ("," if a else "") + json.dumps(values[a : a + SAMPLE_CHUNK_ROWS].tolist())[1:-1]
        yield "]"
    yield "".join(f",{json.dumps(key)}:{text}" for key, text in raw.items()) + ("}}" if member is not None else "}")
