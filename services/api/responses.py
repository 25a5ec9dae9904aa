"""Replies built from already-serialized JSON (stored demonstrations and skills are kept as JSON text), files to
save, and bodies streamed in chunks."""

from __future__ import annotations

import json
from collections.abc import Iterable
from typing import Any

from fastapi import Response
from fastapi.responses import StreamingResponse


def raw_json(parts: dict[str, Any], raw: dict[str, str], status_code: int = 200) -> Response:
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
