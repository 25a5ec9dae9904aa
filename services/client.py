"""A typed Python client of the Contact Skills service: REST over ``httpx``, live telemetry over Zenoh.

    from services.client import Client

    with Client("http://127.0.0.1:8000") as client:
        demo = client.record("slide_flat", seed=0)                  # or client.upload("demo.mcap")
        skill = client.learn(demo.id, skill_type="auto")
        execution = client.execute(skill.id, unknown_offset=[0, 0, 0.02])
        for batch in execution.live(pace=Pace.realtime, from_start=True):  # over Zenoh, at the clock's pace
            print(batch.t[-1], batch.wrench_cf[-1][2])
        view = execution.wait()                                     # status, metrics
        telemetry = execution.telemetry()                           # numpy arrays

``Client()`` finds the service at ``$CONTACT_SKILLS_URL`` (default http://127.0.0.1:8000) and the Zenoh router from
the API (``GET /health``). Every closed set is an enum of ``schemas`` (`ControllerKind`, `Pace`, `ExecutionPhase`,
`TelemetryFormat`, `SkillTypeRequest`, `Sampler`, `SweepParameter`; their string values are accepted too and
checked by the API). Every reply is a pydantic model of ``schemas`` (`DemonstrationCreated`, `StoredSkill`,
`ExecutionView`, `SweepView`, ...).
Every error answer raises a :class:`ServiceError` subclass carrying the API's message (``str(error)``), the
status code and, for a 422, one ``(field path, message)`` per problem.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel

from schemas.api import (
    NEXT_OFFSET_HEADER,
    CommandAccepted,
    DemonstrationCreated,
    DemonstrationInfo,
    ExecutionCreated,
    ExecutionState,
    ExecutionView,
    Health,
    SkillInfo,
    StoredDemonstration,
    StoredSkill,
    TelemetryFormat,
    TelemetryView,
)
from schemas.bus import CommandName
from schemas.demonstration import Demonstration
from schemas.execution import ControllerKind, Pace, TelemetryBatch
from schemas.skill import SkillTypeRequest
from schemas.skill_plan import PlanFormat
from schemas.sweep import (
    DEFAULT_RANGES,
    ParameterRange,
    Sampler,
    SweepCreated,
    SweepParameter,
    SweepState,
    SweepView,
    TrialResult,
)
from services.client_errors import (
    ConflictError,
    InvalidRequestError,
    NotFoundError,
    ServiceError,
    SkillCheckWarning,
    UnauthorizedError,
    UnavailableError,
    service_error,
)
from services.client_export import execution_file
from services.client_telemetry import Pacer, StoredStream, Telemetry, live_batches
from services.demonstration_files import (
    ROS2_STORAGE_SUFFIXES,
    UPLOAD_PATHS,
    DemonstrationFile,
    path_kind,
    unsupported_file,
)
from services.quiet_imports import import_pybullet_quietly
from services.service_url import not_answering, service_url

ListedT = TypeVar("ListedT", bound=BaseModel)
FINAL_STATUSES = frozenset({ExecutionState.done, ExecutionState.aborted, ExecutionState.failed})
"""The API's states of an execution that has ended."""


# --------------------------------------------------------------------------- telemetry as arrays


# --------------------------------------------------------------------------- an execution


class _Handle:
    """A handle on one resource of the service, by its id: nothing is fetched until a method asks."""

    def __init__(self, client: Client, resource_id: str) -> None:
        self.client, self.id = client, resource_id

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.id!r})"


class Execution(_Handle):
    """A handle on one execution: status, wait, telemetry, live stream, commands (``created``: the reply that
    started it, when this client did)."""

    def __init__(self, client: Client, execution_id: str, created: ExecutionCreated | None = None) -> None:
        super().__init__(client, execution_id)
        self.created = created

    def status(self) -> ExecutionView:
        """``GET /executions/{id}``: status, phase, metrics."""
        return ExecutionView.model_validate(self.client._request("GET", f"/executions/{self.id}").json())

    def wait(self, timeout_s: float = 600.0, poll_s: float = 0.2) -> ExecutionView:
        """Poll until the execution is done, aborted or failed; return its final view.

        Raises ``TimeoutError`` (naming the last status) after ``timeout_s`` seconds."""
        deadline = time.monotonic() + timeout_s
        while True:
            view = self.status()
            if view.status in FINAL_STATUSES:
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
        """Save the telemetry as MCAP, CSV or JSON (by ``path``'s suffix; ``t0``/``t1`` s cut a window); returns
        ``path``."""
        path = Path(path)
        data = self.client.export(self.id, format=TelemetryFormat(path.suffix.lstrip(".") or "json"), t0=t0, t1=t1)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        return path

    def live(
        self,
        endpoints: Sequence[str] | None = None,
        timeout_s: float | None = None,
        pace: Pace = Pace.fast,
        from_start: bool = False,
    ) -> Iterator[TelemetryBatch]:
        """The telemetry batches as the worker publishes them (over Zenoh), until the execution ends.

        ``from_start`` False: starts with the batches published after it subscribed, and yields nothing for an
        execution that has ended (the whole stream is in :meth:`telemetry`). ``from_start`` True: first the samples
        already stored (``GET /executions/{id}/telemetry``, from sample 0), then the live ones, each sample once and
        in order: a run watched late, or one that has ended, is replayed from its start.
        ``pace`` `Pace.realtime`: no batch is yielded before its last sample's simulated time has passed on the
        clock since the first one (a run at the default fast pace, ~20x real time, is then seen as it would run);
        `Pace.fast`: as they come. ``endpoints``: the Zenoh router (default: the API's, from ``GET /health``).
        Raises ``TimeoutError`` if nothing final arrives within ``timeout_s`` seconds."""
        return self.client.live(self.id, endpoints=endpoints, timeout_s=timeout_s, pace=pace, from_start=from_start)

    def abort(self) -> CommandAccepted:
        return self.client._command(self.id, CommandName.abort)

    def pause(self) -> CommandAccepted:
        return self.client._command(self.id, CommandName.pause)

    def resume(self) -> CommandAccepted:
        return self.client._command(self.id, CommandName.resume)


# --------------------------------------------------------------------------- a sweep


class Sweep(_Handle):
    """A handle on one robustness sweep: status, wait, trials, cancel (``created``: the reply that started it, when
    this client did)."""

    def __init__(self, client: Client, sweep_id: str, created: SweepCreated | None = None) -> None:
        super().__init__(client, sweep_id)
        self.created = created

    def status(self) -> SweepView:
        """``GET /sweeps/{id}``: state, counts, per-controller summary, sensitivity ranking."""
        return SweepView.model_validate(self.client._request("GET", f"/sweeps/{self.id}").json())

    def wait(self, timeout_s: float = 3600.0, poll_s: float = 0.5) -> SweepView:
        """Poll until the sweep is no longer running; return its final view. Raises ``TimeoutError`` (naming the
        counts) after ``timeout_s`` seconds."""
        deadline = time.monotonic() + timeout_s
        while True:
            view = self.status()
            if view.status is not SweepState.running:
                return view
            if time.monotonic() > deadline:
                counts = view.counts
                raise TimeoutError(f"sweep {self.id} still running after {timeout_s:g} s "
                                   f"({counts.finished}/{counts.total} executions finished)")  # fmt: skip
            time.sleep(poll_s)

    def trials(self) -> list[TrialResult]:
        """``GET /sweeps/{id}/trials``: every trial x controller with its parameters, execution and metrics."""
        return [TrialResult.model_validate(t) for t in self.client._request("GET", f"/sweeps/{self.id}/trials").json()]

    def cancel(self) -> SweepView:
        """``POST /sweeps/{id}/cancel``: queued executions cancelled, running ones aborted."""
        return SweepView.model_validate(self.client._request("POST", f"/sweeps/{self.id}/cancel").json())


# --------------------------------------------------------------------------- the client


class Client:
    """The service at ``url`` (default ``$CONTACT_SKILLS_URL``, else http://127.0.0.1:8000: ``services.service_url``);
    ``token``: the bearer token, if the service requires one; ``timeout_s``: of one HTTP request, s."""

    def __init__(self, url: str | None = None, token: str | None = None, timeout_s: float = 300.0) -> None:
        self.url = service_url(url)
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
            raise UnavailableError(0, not_answering(self.url, str(exc))) from None
        if response.status_code >= 400:
            raise service_error(response)
        return response

    def _list(self, path: str, model: type[ListedT], limit: int, offset: int) -> list[ListedT]:
        """``GET path`` of a resource's list (``limit`` items from ``offset``), each item as ``model``: the pages
        followed (a page stops before the API's byte budget and names the next one's offset, ``X-Next-Offset``)."""
        items: list[ListedT] = []
        while len(items) < limit:
            reply = self._request("GET", path, params={"limit": limit - len(items), "offset": offset})
            items += [model.model_validate(item) for item in reply.json()]
            if (next_offset := reply.headers.get(NEXT_OFFSET_HEADER)) is None:
                break
            offset = int(next_offset)
        return items

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
        """Store a demonstration file, sent to the route that takes what it holds, told by its content (its first
        bytes, whatever its name): an MCAP or sqlite3 file (a ROS 2 bag's storage; or the bag directory) or a ROS 1
        bag (``#ROSBAG V2.0``) to ``POST /demonstrations/bag``, UTF-8 text starting with ``{`` (a JSON
        `Demonstration`; or named ``.json``) to ``POST /demonstrations``, other UTF-8 text (a CSV recording) to
        ``POST /demonstrations/csv``; text named like a bag is refused here, as every interface refuses it.
        ``options`` are the form fields of ``POST /demonstrations/csv`` or ``/bag``
        (the fields of `schemas.import_options.CsvImportOptions` or `BagImportOptions` by their form names, e.g.
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
        """A stored demonstration with its samples, read page by page (one reply holds at most 8 MiB)."""
        columns: dict[str, list] = {"t": [], "positions": [], "orientations": [], "wrenches": []}
        cursor: int | None = 0
        while cursor is not None:
            path = f"/demonstrations/{demonstration_id}"
            page = StoredDemonstration.model_validate(self._request("GET", path, params={"cursor": cursor}).json())
            for name, values in columns.items():
                values += getattr(page.demonstration, name)
            cursor = page.next_cursor
        return Demonstration(**columns, metadata=page.demonstration.metadata)

    def demonstrations(self, limit: int = 100, offset: int = 0) -> list[DemonstrationInfo]:
        return self._list("/demonstrations", DemonstrationInfo, limit, offset)

    # ------------------------------------------------------------------ skills

    def learn(
        self,
        demonstration: str | Demonstration | Sequence[str],
        skill_type: SkillTypeRequest = SkillTypeRequest.auto,
        *,
        strict: bool = False,
        **options: Any,
    ) -> StoredSkill:
        """Learn a skill from a stored demonstration (its id), several stored demonstrations of the same task
        together (a list of ids: the skill's ``demonstrations`` name each with its weight, and those left out with
        their reason; ``misfit="refuse"`` refuses instead) or an inline `Demonstration`; ``options`` are
        `LearnOptions` fields.

        The skill checks itself against the demonstration: each failed check is issued as a `SkillCheckWarning`
        (Python's ``warnings``) and listed in the reply's ``warnings``. ``strict``: refuse such a skill instead
        (`InvalidRequestError` giving each failed check)."""
        body: dict[str, Any] = {"skill_type": SkillTypeRequest(skill_type).value, "strict": strict, **options}
        if isinstance(demonstration, Demonstration):
            body["demonstration"] = demonstration.model_dump(mode="json")
        elif isinstance(demonstration, str):
            body["demonstration_id"] = demonstration
        else:
            body["demonstration_ids"] = list(demonstration)
        stored = StoredSkill.model_validate(self._request("POST", "/skills", json=body).json())
        for message in stored.warnings:
            warnings.warn(SkillCheckWarning(f"skill {stored.id}: {message}"), stacklevel=2)
        return stored

    def skill(self, skill_id: str) -> StoredSkill:
        return StoredSkill.model_validate(self._request("GET", f"/skills/{skill_id}").json())

    def skill_plan(
        self, skill_id: str, every: int = 1, max_samples: int | None = None, format: PlanFormat = PlanFormat.json
    ) -> bytes:
        """A skill's nominal plan for a real cell (``GET /skills/{id}/plan``, ``schemas.skill_plan``) as JSON bytes,
        or with ``format`` ``PlanFormat.mcap`` the same plan as MCAP bytes (docs/REAL_CELL.md): every ``every``-th
        control step; refused (``InvalidRequestError``) when over ``max_samples`` samples."""
        params: dict[str, Any] = {"every": every} | ({} if max_samples is None else {"max_samples": max_samples})
        if format is not PlanFormat.json:  # the JSON request stays as it was (no format parameter)
            params["format"] = PlanFormat(format).value
        return self._request("GET", f"/skills/{skill_id}/plan", params=params).content

    def skills(self, limit: int = 100, offset: int = 0) -> list[SkillInfo]:
        return self._list("/skills", SkillInfo, limit, offset)

    # ------------------------------------------------------------------ executions

    def execute(
        self,
        skill_id: str,
        *,
        offset: Sequence[float] | None = None,
        unknown_offset: Sequence[float] | None = None,
        controller: ControllerKind = ControllerKind.hybrid_cf,
        pace: Pace = Pace.fast,
        **settings: Any,
    ) -> Execution:
        """Run a stored skill on a sim worker (``offset`` known, ``unknown_offset`` unknown work piece shifts, world,
        m; ``pace`` `Pace.realtime` makes simulated time follow the clock, so a live view sees the run as it
        happens; ``settings``: other `ExecutionRequest` fields, e.g. ``gains``, ``scenario``). Returns at once."""
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
        return self._list("/executions", ExecutionView, limit, offset)

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
        format: TelemetryFormat = TelemetryFormat.mcap,
        t0: float | None = None,
        t1: float | None = None,
        every: int | None = None,
    ) -> bytes:
        """A demonstration (``demo_...``) or an execution (``exec_...``) as MCAP, CSV or JSON bytes, or a skill
        (``skill_...``) as MCAP (``GET /skills/{id}/mcap``: the robot, the path and the learned frames; whole).

        An execution's file is written here from every page of its telemetry (the service sends at most its cap of
        samples per request), exactly as the service writes one page."""
        if record_id.startswith("demo_"):
            params = _given({"format": TelemetryFormat(format).value, "t0": t0, "t1": t1})
            return self._request("GET", f"/demonstrations/{record_id}/telemetry", params=params).content
        if record_id.startswith("skill_"):
            whole = t0 is None and t1 is None and every in (None, 1)
            if TelemetryFormat(format) is not TelemetryFormat.mcap or not whole:
                raise ValueError(f"{record_id} is a skill: it exports whole, as MCAP only (no --t0, --t1, --every)")
            return self._request("GET", f"/skills/{record_id}/mcap").content
        if not record_id.startswith("exec_"):
            raise ValueError(
                f"{record_id!r} is not a demonstration (demo_...), an execution (exec_...) or a skill (skill_...) id"
            )
        kind = TelemetryFormat(format)
        if kind is TelemetryFormat.mcap:
            import_pybullet_quietly()  # the MCAP's scene solves the arm's joints with PyBullet: no banner in our output
        pages = [TelemetryView.model_validate(page) for page in self.telemetry_pages(record_id, every or 1, t0, t1)]
        return execution_file(pages, kind, record_id, lambda: Execution(self, record_id).status().created)

    def _command(self, execution_id: str, command: CommandName) -> CommandAccepted:
        return CommandAccepted.model_validate(self._request("POST", f"/executions/{execution_id}/{command}").json())

    # ------------------------------------------------------------------ live telemetry over Zenoh

    def live(
        self,
        execution_id: str,
        endpoints: Sequence[str] | None = None,
        timeout_s: float | None = None,
        pace: Pace = Pace.fast,
        from_start: bool = False,
    ) -> Iterator[TelemetryBatch]:
        """See :meth:`Execution.live`."""
        paced = Pacer(Pace(pace))
        view = Execution(self, execution_id).status()

        def page(params: dict[str, int]) -> TelemetryView:
            return TelemetryView.model_validate(self._request("GET", path, params=params).json())

        path = f"/executions/{execution_id}/telemetry"
        stored = StoredStream(page, execution_id) if from_start else None
        if view.status in FINAL_STATUSES:
            if stored is not None:
                yield from map(paced, stored.batches_before(None))
            return
        connect = list(endpoints) if endpoints else self.health().zenoh_endpoints
        for batch in live_batches(view, connect, timeout_s):
            if stored is None:
                yield paced(batch)
                continue
            yield from map(paced, stored.batches_before(batch.first_sample))  # what was sent before we listened
            rest = stored.unseen(batch)
            if rest is not None:
                yield paced(rest)
        if stored is not None:
            yield from map(paced, stored.batches_before(None))  # the end, when it came before the last live batch

    # ------------------------------------------------------------------ robustness sweeps

    def run_sweep(
        self,
        skill_id: str,
        *,
        controllers: Sequence[ControllerKind] = (ControllerKind.hybrid_cf,),
        vary: Mapping[SweepParameter, ParameterRange | Mapping[str, Any]] | None = None,
        trials: int = 20,
        seed: int = 0,
        sampler: Sampler = Sampler.lhs,
        **request: Any,
    ) -> Sweep:
        """``POST /sweeps``: run the stored skill over ``trials`` sampled variations of ``vary`` (a parameter's
        `ParameterRange`, or its fields ``low``, ``high``, ``log``; default: ``schemas.sweep.DEFAULT_RANGES``, what a
        real cell sees), once per controller; ``request``: other `SweepRequest` fields (``settings``,
        ``success_rms_pct``, ``store_telemetry``, ...). Returns at once, with the sweep's handle."""
        ranges = DEFAULT_RANGES if vary is None else vary
        body: dict[str, Any] = {"skill_id": skill_id, "controllers": list(controllers), "trials": trials,
                                "seed": seed, "sampler": sampler, **request}  # fmt: skip
        body["vary"] = {
            str(name): spread.model_dump() if isinstance(spread, ParameterRange) else dict(spread)
            for name, spread in ranges.items()
        }
        created = SweepCreated.model_validate(self._request("POST", "/sweeps", json=body).json())
        return Sweep(self, created.id, created)

    def sweep(self, sweep_id: str) -> Sweep:
        """A handle on an existing sweep (nothing is fetched)."""
        return Sweep(self, sweep_id)

    def sweeps(self, limit: int = 100, offset: int = 0) -> list[SweepView]:
        return self._list("/sweeps", SweepView, limit, offset)


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
    "Sweep",
    "Telemetry",
    "UnauthorizedError",
    "UnavailableError",
]
