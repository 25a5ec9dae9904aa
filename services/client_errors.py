"""The errors of the typed client (``services.client``): one exception class per kind of error answer of the API,
each carrying its message, status and, for a 422, each field's problem; and the warning of a skill that failed one of
its checks."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import httpx


class SkillCheckWarning(UserWarning):
    """A learned skill failed one of its checks against its demonstration: it may be wrong there (the message says
    where and by how much)."""


class ServiceError(Exception):
    """The API answered with an error (or did not answer): ``status`` (0: no answer), ``detail`` (its message),
    ``problems`` (a 422's ``(field path, message)`` pairs)."""

    def __init__(self, status: int, detail: str, problems: Sequence[tuple[str, str]] = ()) -> None:
        self.status, self.detail, self.problems = status, detail, list(problems)
        super().__init__(f"{status}: {detail}" if status else detail)


class NotFoundError(ServiceError):
    """404: no such id."""


class InvalidRequestError(ServiceError):
    """422: the request (body, form, query) is invalid; ``problems`` names each field."""


class ConflictError(ServiceError):
    """409: a command to an execution that has already finished."""


class UnauthorizedError(ServiceError):
    """401: the service wants a bearer token (``Client(token=...)``)."""


class UnavailableError(ServiceError):
    """503/504, or no answer at all: no bus, no free worker, a timeout, the API not running."""


_ERRORS: dict[int, type[ServiceError]] = {
    401: UnauthorizedError,
    404: NotFoundError,
    409: ConflictError,
    422: InvalidRequestError,
    503: UnavailableError,
    504: UnavailableError,
}


def service_error(response: httpx.Response) -> ServiceError:
    """The exception for an error ``response``, with the API's own message."""
    try:
        detail: Any = response.json().get("detail", response.text)
    except (ValueError, AttributeError):
        detail = response.text
    problems: list[tuple[str, str]] = []
    if isinstance(detail, list):
        problems = [(".".join(str(p) for p in entry.get("loc", [])), str(entry.get("msg", ""))) for entry in detail]
        detail = "; ".join(f"{loc}: {msg}" for loc, msg in problems)
    return _ERRORS.get(response.status_code, ServiceError)(response.status_code, str(detail), problems)
