"""A typed Python client of the Contact Skills service: REST over ``httpx``, live telemetry over Zenoh.

    from services.client import Client

    with Client("http://127.0.0.1:8000") as client:
        demo = client.record("slide_flat", seed=0)                  # or client.upload("demo.mcap")
        skill = client.learn(demo.id, skill_type="auto")
        execution = client.execute(skill.id, unknown_offset=[0, 0, 0.02])
        for batch in execution.live():                              # over Zenoh while it runs
            print(batch.t[-1], batch.wrench_cf[-1][2])
        view = execution.wait()                                     # status, metrics
        telemetry = execution.telemetry()                           # numpy arrays

Every reply is a pydantic model of ``schemas`` (`DemonstrationCreated`, `StoredSkill`, `ExecutionView`, ...).
Every error answer raises a :class:`ServiceError` subclass carrying the API's message (``str(error)``), the
status code and, for a 422, one ``(field path, message)`` per problem.
"""

from __future__ import annotations

import queue
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from schemas.api import (
    CommandAccepted,
    DemonstrationCreated,
    DemonstrationInfo,
    ExecutionCreated,
    ExecutionView,
    Health,
    SkillInfo,
    StoredSkill,
)
from schemas.demonstration import Demonstration
from schemas.execution import TelemetryBatch
from schemas.skill import SkillTypeRequest
from services.demonstration_files import (
    ROS2_STORAGE_SUFFIXES,
    UPLOAD_PATHS,
    DemonstrationFile,
    path_kind,
    unsupported_file,
)

DEFAULT_URL = "http://127.0.0.1:8000"
FINAL_STATUSES = ("done", "aborted", "failed")


# --------------------------------------------------------------------------- errors


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


def _error(response: httpx.Response) -> ServiceError:
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


# --------------------------------------------------------------------------- telemetry as arrays


@dataclass(frozen=True)
class Telemetry:
    """An execution's telemetry as numpy arrays, one row per control step (SI units, quaternions [x, y, z, w]).

    ``wrench_world`` is the wrench the tool applies at the tool point in world axes; ``wrench_cf`` the same in the
    compliant frame (force z into the surface); ``desired_force_cf_z_n`` the desired CF-z force."""

    t: np.ndarray
    phase: np.ndarray
    segment_index: np.ndarray
    tool_position: np.ndarray
    tool_orientation: np.ndarray
    reference_position: np.ndarray
    reference_orientation: np.ndarray
    wrench_world: np.ndarray
    wrench_cf: np.ndarray
    desired_force_cf_z_n: np.ndarray

    @classmethod
    def from_columns(cls, columns: dict[str, Any]) -> Telemetry:
        """From the columns of ``GET /executions/{id}/telemetry`` or of a `TelemetryBatch`."""
        arrays = {}
        for name in cls.__dataclass_fields__:
            values = columns[name]
            arrays[name] = np.asarray(values, dtype=object if name == "phase" else float)
        arrays["phase"] = arrays["phase"].astype(str)
        arrays["segment_index"] = arrays["segment_index"].astype(int)
        return cls(**arrays)

    @classmethod
    def joined(cls, parts: Sequence[Telemetry]) -> Telemetry:
        """The samples of ``parts`` (pages of one stream, in order) as one."""
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in cls.__dataclass_fields__})

    def __len__(self) -> int:
        return int(self.t.size)


# --------------------------------------------------------------------------- an execution


class Execution:
    """A handle on one execution: status, wait, telemetry, live stream, commands."""

    def __init__(self, client: Client, execution_id: str, created: ExecutionCreated | None = None) -> None:
        self.client, self.id, self.created = client, execution_id, created

    def __repr__(self) -> str:
        return f"Execution({self.id!r})"

    def status(self) -> ExecutionView:
        """``GET /executions/{id}``: status, phase, metrics."""
        return ExecutionView.model_validate(self.client._request("GET", f"/executions/{self.id}").json())

    def wait(self, timeout_s: float = 600.0, poll_s: float = 0.2) -> ExecutionView:
        """Poll until the execution is done, aborted or failed; return its final view.

        Raises ``TimeoutError`` (naming the last status) after ``timeout_s`` seconds."""
        deadline = time.monotonic() + timeout_s
        while True:
            view = self.status()
            if view.status.value in FINAL_STATUSES:
                return view
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"execution {self.id} still {view.status.value} ({view.phase.value}) after {timeout_s:g} s"
                )
            time.sleep(poll_s)

    def telemetry(self, every: int = 1, t0: float | None = None, t1: float | None = None) -> Telemetry:
        """The stored telemetry as numpy arrays (``t0``/``t1`` s cut a window, ``every`` decimates)."""
        return self.client.telemetry(self.id, every=every, t0=t0, t1=t1)

    def export(self, path: str | Path, t0: float | None = None, t1: float | None = None) -> Path:
        """Save the telemetry as MCAP, CSV or JSON (by ``path``'s suffix); returns ``path``."""
        path = Path(path)
        data = self.client.export(self.id, format=path.suffix.lstrip(".") or "json", t0=t0, t1=t1)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        return path

    def live(self, endpoints: Sequence[str] | None = None, timeout_s: float | None = None) -> Iterator[TelemetryBatch]:
        """The telemetry batches as the worker publishes them (over Zenoh), until the execution ends.

        Starts with the batches published after it subscribed (the whole stream is in :meth:`telemetry`). ``endpoints``:
        the Zenoh router (default: the API's, from ``GET /health``). Raises ``TimeoutError`` if nothing final
        arrives within ``timeout_s``."""
        return self.client.live(self.id, endpoints=endpoints, timeout_s=timeout_s)

    def abort(self) -> CommandAccepted:
        return self.client._command(self.id, "abort")

    def pause(self) -> CommandAccepted:
        return self.client._command(self.id, "pause")

    def resume(self) -> CommandAccepted:
        return self.client._command(self.id, "resume")


# --------------------------------------------------------------------------- the client


class Client:
    """The service at ``url`` (``token``: the bearer token, if the service requires one)."""

    def __init__(self, url: str = DEFAULT_URL, token: str | None = None, timeout_s: float = 300.0) -> None:
        self.url = url.rstrip("/")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout_s)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.TimeoutException as exc:
            raise UnavailableError(0, f"the API at {self.url} did not answer {method} {path} in time ({exc})") from None
        except httpx.TransportError as exc:
            raise UnavailableError(
                0, f"the API at {self.url} does not answer ({exc}): is it running (contact-skills up)?"
            ) from None
        if response.status_code >= 400:
            raise _error(response)
        return response

    # ------------------------------------------------------------------ service

    def health(self) -> Health:
        """``GET /health``: version, bus, connected workers."""
        return Health.model_validate(self._request("GET", "/health").json())

    # ------------------------------------------------------------------ demonstrations

    def record(self, scenario: str, seed: int = 0, **overrides: Any) -> DemonstrationCreated:
        """A sim worker's scripted teacher records ``scenario`` (``overrides``: teacher or world fields)."""
        body = {"scenario": scenario, "seed": seed, "overrides": overrides}
        return DemonstrationCreated.model_validate(self._request("POST", "/demonstrations/record", json=body).json())

    def upload(self, path: str | Path, **options: Any) -> DemonstrationCreated:
        """Store a demonstration file, sent to the route that takes what it holds (its content, not only its name):
        a JSON `Demonstration`, a CSV recording, a ROS 2 bag (a bag directory, its ``.mcap`` or ``.db3``) or a ROS 1
        ``.bag``. ``options`` are the form fields of ``POST /demonstrations/csv`` or ``/bag`` (the fields of
        `schemas.import_options.CsvImportOptions` or `BagImportOptions` by their form names, e.g.
        ``wrench="measured-on-tool"``, ``wrench_topic="/ft"``, ``rate=100``). Raises ``ValueError`` for a file no
        importer reads, with the message the API and ``contact-skills learn`` give."""
        path = Path(path)
        kind = path_kind(path)
        if kind is None:
            raise ValueError(unsupported_file(path.name))
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix in ROS2_STORAGE_SUFFIXES)
            if len(found) != 1:
                raise ValueError(f"{path}: a bag directory with one .mcap or .db3 file is expected, found {len(found)}")
            path = found[0]
        if kind is DemonstrationFile.json:
            reply = self._request("POST", UPLOAD_PATHS[kind], content=path.read_bytes(),
                                  headers={"content-type": "application/json"})  # fmt: skip
        else:
            form = {k: _form_value(v) for k, v in options.items() if v is not None}
            with path.open("rb") as file:
                reply = self._request("POST", UPLOAD_PATHS[kind], files={"file": (path.name, file)}, data=form)
        return DemonstrationCreated.model_validate(reply.json())

    def demonstration(self, demonstration_id: str) -> Demonstration:
        """A stored demonstration with its samples."""
        return Demonstration.model_validate(
            self._request("GET", f"/demonstrations/{demonstration_id}").json()["demonstration"]
        )

    def demonstrations(self, limit: int = 100, offset: int = 0) -> list[DemonstrationInfo]:
        reply = self._request("GET", "/demonstrations", params={"limit": limit, "offset": offset})
        return [DemonstrationInfo.model_validate(item) for item in reply.json()]

    # ------------------------------------------------------------------ skills

    def learn(
        self,
        demonstration: str | Demonstration,
        skill_type: SkillTypeRequest = SkillTypeRequest.auto,
        *,
        strict: bool = False,
        **options: Any,
    ) -> StoredSkill:
        """Learn a skill from a stored demonstration (its id) or an inline `Demonstration`; ``options`` are
        `LearnOptions` fields.

        The skill checks itself against the demonstration: each failed check is issued as a `SkillCheckWarning`
        (Python's ``warnings``) and listed in the reply's ``warnings``. ``strict``: refuse such a skill instead
        (`InvalidRequestError` giving each failed check)."""
        body: dict[str, Any] = {"skill_type": SkillTypeRequest(skill_type).value, "strict": strict, **options}
        if isinstance(demonstration, Demonstration):
            body["demonstration"] = demonstration.model_dump(mode="json")
        else:
            body["demonstration_id"] = demonstration
        stored = StoredSkill.model_validate(self._request("POST", "/skills", json=body).json())
        for message in stored.warnings:
            warnings.warn(SkillCheckWarning(f"skill {stored.id}: {message}"), stacklevel=2)
        return stored

    def skill(self, skill_id: str) -> StoredSkill:
        return StoredSkill.model_validate(self._request("GET", f"/skills/{skill_id}").json())

    def skills(self, limit: int = 100, offset: int = 0) -> list[SkillInfo]:
        reply = self._request("GET", "/skills", params={"limit": limit, "offset": offset})
        return [SkillInfo.model_validate(item) for item in reply.json()]

    # ------------------------------------------------------------------ executions

    def execute(
        self,
        skill_id: str,
        *,
        offset: Sequence[float] | None = None,
        unknown_offset: Sequence[float] | None = None,
        controller: str = "hybrid_cf",
        pace: str = "fast",
        **settings: Any,
    ) -> Execution:
        """Run a stored skill on a sim worker (``offset`` known, ``unknown_offset`` unknown work piece shifts, m;
        ``settings``: other `ExecutionRequest` fields, e.g. ``gains``, ``scenario``). Returns at once."""
        environment = {
            "offset": list(offset or [0.0, 0.0, 0.0]),
            "unknown_offset": list(unknown_offset or [0.0, 0.0, 0.0]),
        }
        body = {"skill_id": skill_id, "environment": environment, "controller": controller, "pace": pace, **settings}
        created = ExecutionCreated.model_validate(self._request("POST", "/executions", json=body).json())
        return Execution(self, created.id, created)

    def execution(self, execution_id: str) -> Execution:
        """A handle on an existing execution (nothing is fetched)."""
        return Execution(self, execution_id)

    def executions(self, limit: int = 100, offset: int = 0) -> list[ExecutionView]:
        reply = self._request("GET", "/executions", params={"limit": limit, "offset": offset})
        return [ExecutionView.model_validate(item) for item in reply.json()]

    def telemetry(
        self, execution_id: str, every: int = 1, t0: float | None = None, t1: float | None = None
    ) -> Telemetry:
        """An execution's stored telemetry as numpy arrays: the whole window, however many pages the service sends
        it in (:meth:`telemetry_pages`)."""
        return Telemetry.joined(
            [Telemetry.from_columns(page) for page in self.telemetry_pages(execution_id, every, t0, t1)]
        )

    def telemetry_pages(
        self, execution_id: str, every: int = 1, t0: float | None = None, t1: float | None = None
    ) -> Iterator[dict[str, Any]]:
        """The JSON pages of ``GET /executions/{id}/telemetry`` (each at most the service's cap of samples), from the
        first to the last: each next one asked for from the previous one's ``next_cursor``."""
        params, cursor = _given({"every": every, "t0": t0, "t1": t1}), 0
        while True:
            page = self._request("GET", f"/executions/{execution_id}/telemetry", params={**params, "cursor": cursor})
            body = page.json()
            yield body
            if body.get("next_cursor") is None:
                return
            cursor = body["next_cursor"]

    def export(
        self,
        record_id: str,
        format: str = "mcap",
        t0: float | None = None,
        t1: float | None = None,
        every: int | None = None,
    ) -> bytes:
        """A demonstration (``demo_...``) or an execution (``exec_...``) as MCAP, CSV or JSON bytes.

        An execution's file is written here from every page of its telemetry (the service sends at most its cap of
        samples per request), exactly as the service writes one page."""
        if record_id.startswith("demo_"):
            params = _given({"format": format, "t0": t0, "t1": t1})
            return self._request("GET", f"/demonstrations/{record_id}/telemetry", params=params).content
        if not record_id.startswith("exec_"):
            raise ValueError(f"{record_id!r} is not a demonstration (demo_...) or an execution (exec_...) id")
        from schemas.api import TelemetryFormat, TelemetryView
        from services.store import telemetry_matrix
        from services.telemetry_export import execution_csv, execution_json_chunks, execution_mcap

        kind = TelemetryFormat(format)
        pages = [TelemetryView.model_validate(page) for page in self.telemetry_pages(record_id, every or 1, t0, t1)]
        matrix = np.concatenate([telemetry_matrix(page) for page in pages])
        if kind is TelemetryFormat.mcap:
            return execution_mcap(matrix, Execution(self, record_id).status().created, record_id).data
        if kind is TelemetryFormat.csv:
            return execution_csv(matrix).encode()
        last = pages[-1]
        head = {"execution_id": record_id, "every": last.every, "cursor": 0, "next_cursor": None,
                "n_samples": int(matrix.shape[0]), "stored_samples": last.stored_samples,
                "status": last.status.value}  # fmt: skip
        return "".join(execution_json_chunks(head, matrix)).encode()

    def _command(self, execution_id: str, command: str) -> CommandAccepted:
        return CommandAccepted.model_validate(self._request("POST", f"/executions/{execution_id}/{command}").json())

    # ------------------------------------------------------------------ live telemetry over Zenoh

    def live(
        self, execution_id: str, endpoints: Sequence[str] | None = None, timeout_s: float | None = None
    ) -> Iterator[TelemetryBatch]:
        """See :meth:`Execution.live`."""
        from schemas.bus import ExecutionStatus
        from services.bus import open_session

        view = Execution(self, execution_id).status()
        if view.status.value in FINAL_STATUSES:
            return
        connect = list(endpoints) if endpoints else self.health().zenoh_endpoints
        status_key = view.telemetry_key.rsplit("/", 1)[0] + "/status"
        batches: queue.Queue[TelemetryBatch] = queue.Queue()
        final = threading.Event()

        def on_status(sample) -> None:
            if ExecutionStatus.model_validate_json(sample.payload.to_bytes()).final:
                final.set()

        session = open_session("client", connect=connect, wait_s=5.0)
        try:
            subscribers = [
                session.declare_subscriber(
                    view.telemetry_key, lambda s: batches.put(TelemetryBatch.model_validate_json(s.payload.to_bytes()))
                ),
                session.declare_subscriber(status_key, on_status),
            ]
            for reply in session.get(status_key, timeout=2.0):  # it may have ended while we subscribed
                if reply.ok is not None:
                    on_status(reply.ok)
            deadline = None if timeout_s is None else time.monotonic() + timeout_s
            while True:
                try:
                    yield batches.get(timeout=LIVE_DRAIN_S if final.is_set() else 0.1)
                    continue
                except queue.Empty:
                    if final.is_set():
                        break  # ended, and nothing more arrived for LIVE_DRAIN_S
                if deadline is not None and time.monotonic() > deadline:
                    raise TimeoutError(f"execution {execution_id}: no final status within {timeout_s:g} s")
            for subscriber in subscribers:
                subscriber.undeclare()
        finally:
            session.close()


LIVE_DRAIN_S = 0.5
"""After the final status, :meth:`Client.live` keeps yielding until no batch arrived for this long, s (status and
telemetry travel on different keys: the last batches may come after the final status)."""


def _given(params: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in params.items() if v is not None}


def _form_value(value: Any) -> str:
    """A form field: numbers lists as ``a,b,c``, booleans as ``true``/``false``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple):
        return ",".join(str(v) for v in value)
    return str(value)


__all__ = [
    "Client",
    "ConflictError",
    "Execution",
    "InvalidRequestError",
    "NotFoundError",
    "ServiceError",
    "Telemetry",
    "UnauthorizedError",
    "UnavailableError",
]
