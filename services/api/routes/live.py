"""``GET /executions/{id}/live``: an execution as it runs, for a browser, as server-sent events.

Read from the store as the bus callbacks write it (every sample received, a repaired gap too, once and in order),
every :data:`PERIOD_S`: each ``telemetry`` event carries what arrived since the last, decimated to :data:`PLOT_HZ`
samples per second of execution time, ALWAYS with the last sample stored (so the live plot ends where the stored
telemetry ends); each event's ``id`` is the stream index to go on from. A client that lost the connection (the API
restarted) asks again with ``cursor`` = that id and misses nothing. ``status`` events carry the state when it
changes; ``end``, once the execution has finished and its telemetry is stored, the final view (metrics, verdict),
and closes the stream.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Mapping
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse
from pydantic import JsonValue

from services.api import errors
from services.api.deps import MAX_OFFSET, READ_GUARD, StoreDep
from services.api.errors import ERROR_RESPONSES, READ_RESPONSES
from services.dashboard.scene import JointSolver, cf_rotations
from services.dashboard.stream import decimated, stored_rows
from services.store import TELEMETRY_LAYOUT, TERMINAL, ExecutionRow, Store

router = APIRouter(tags=["executions"], dependencies=READ_GUARD, responses=READ_RESPONSES)

PERIOD_S = 0.04
"""How often the store is read for new samples, s: 25 events per second at most."""
PLOT_HZ = 100.0
"""Samples per second of execution time an event carries (the control loop's 1 kHz is in the stored telemetry)."""
FINAL_WAIT_S = 3.0
"""After the final status, how long to wait for the telemetry it counts before ending the stream anyway, s."""
SEND = ("t", "phase", "segment_index", "tool_position", "reference_position", "wrench_world", "wrench_cf",
        "desired_force_cf_z_n", "in_contact", "normal_force_true_n")  # fmt: skip
"""The columns an event carries (poses' orientations stay in the stored telemetry)."""
ROUND = 6
"""Decimals sent of the vector columns (positions m, wrenches N N·m): 1 µm, 1 µN; scalars go unrounded."""

LiveCursor = Annotated[int, Query(ge=0, le=MAX_OFFSET, description="The stream index to start from (an event's id).")]


def _event(kind: str, data: Mapping[str, JsonValue], ident: int | None = None) -> str:
    head = f"id: {ident}\n" if ident is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data, allow_nan=False)}\n\n"


def _column(block: np.ndarray, name: str) -> list:
    """One column of the kept rows as JSON values: NaN (a value not recorded, e.g. the true force and the contact
    in telemetry stored before they were streamed) as null, never as a number; ``in_contact`` as booleans."""
    if block.shape[1] > 1:
        block = block.round(ROUND)
    values: list = np.where(np.isfinite(block), block, None).tolist()
    if block.shape[1] > 1:
        return values
    if name == "in_contact":
        return [None if v is None else v > 0.5 for (v,) in values]
    return [v for (v,) in values]


def _telemetry(rows: np.ndarray, first: int, scene: _Scene | None = None) -> dict[str, JsonValue]:
    """The columns of ``rows`` (the store's matrix, stream index ``first`` onwards) decimated to :data:`PLOT_HZ`,
    the last row always kept; ``index``: each kept row's stream index. With ``scene`` (what the 3-D view draws):
    ``cf_axes``, each kept row's compliant frame (world-from-CF rotation, rows of the matrix; recovered from its two
    wrenches, the last one kept where they do not fix it), and ``joints``, the arm's 7 joint angles (rad) at the last
    row (inverse kinematics of its tool pose)."""
    keep = decimated(rows[:, 0], PLOT_HZ)
    picked = rows[keep]
    out: dict[str, JsonValue] = {"index": (first + keep).tolist()}
    for name in SEND:
        a, b = TELEMETRY_LAYOUT[name]
        out[name] = _column(picked[:, a:b], name)
    if scene is not None:
        out.update(scene.drawn(picked))
    return out


class _Scene:
    """What a stream adds for the 3-D view: the CF of each sample and the arm's joints at the last; one joint solver
    per stream (seeded by its previous solution, so the arm moves continuously), closed with the stream."""

    def __init__(self) -> None:
        self.solver = JointSolver()
        self.frame: np.ndarray | None = None

    def drawn(self, picked: np.ndarray) -> dict[str, JsonValue]:
        columns = {name: picked[:, a:b] for name, (a, b) in TELEMETRY_LAYOUT.items()}
        world, cf = (np.nan_to_num(columns[name]) for name in ("wrench_world", "wrench_cf"))
        frames = cf_rotations(world, cf, self.frame)
        self.frame = frames[-1]
        joints = self.solver.solve(columns["tool_position"][-1:], columns["tool_orientation"][-1:])[0]
        return {"cf_axes": frames.round(4).tolist(), "joints": joints.round(5).tolist()}

    def close(self) -> None:
        self.solver.close()


def _read(store: Store, execution_id: str, cursor: int, skip_gaps: bool) -> tuple[ExecutionRow | None, np.ndarray]:
    """The execution's row and its samples from ``cursor`` on (up to a gap still being repaired, unless
    ``skip_gaps``)."""
    return store.executions.get(execution_id), stored_rows(store, execution_id, cursor, skip_gaps)


async def _events(request: Request, store: Store, execution_id: str, cursor: int) -> AsyncIterator[str]:
    scene = await asyncio.to_thread(_Scene)
    try:
        async for event in _scene_events(request, store, execution_id, cursor, scene):
            yield event
    finally:
        scene.close()


async def _scene_events(
    request: Request, store: Store, execution_id: str, cursor: int, scene: _Scene
) -> AsyncIterator[str]:
    sent_state: tuple | None = None
    final_since: float | None = None
    loop = asyncio.get_running_loop()
    next_read = loop.time()
    while not await request.is_disconnected():
        next_read += PERIOD_S  # a fixed rate: the time spent reading and sending is not added to the period
        given_up = final_since is not None and loop.time() - final_since > FINAL_WAIT_S  # what is missing is lost
        row, rows = await asyncio.to_thread(_read, store, execution_id, cursor, given_up)
        if row is None:
            yield _event("end", {"error": f"execution {execution_id} was deleted"})
            return
        if rows.shape[0]:
            event = await asyncio.to_thread(_telemetry, rows, cursor, scene)
            yield _event("telemetry", event, cursor + rows.shape[0])
            cursor += rows.shape[0]
        state = (row.status.value, row.phase.value, row.error)
        if state != sent_state:
            sent_state = state
            yield _event("status", {"status": row.status.value, "phase": row.phase.value, "error": row.error})
        if row.status in TERMINAL:
            final_since = final_since if final_since is not None else loop.time()
            steps = row.metrics.steps if row.metrics else None
            complete = not row.streams_telemetry or steps is None or cursor >= steps
            if complete or (given_up and not rows.shape[0]):
                verdict = row.metrics.verdict.verdict if row.metrics and row.metrics.verdict else None
                metrics = row.metrics.model_dump(mode="json") if row.metrics else None
                final = {"status": row.status.value, "phase": row.phase.value, "error": row.error,
                         "metrics": metrics, "verdict": verdict, "samples": cursor}  # fmt: skip
                yield _event("end", final, cursor)
                return
        await asyncio.sleep(max(0.0, next_read - loop.time()))


@router.get(
    "/executions/{execution_id}/live",
    responses={200: {"content": {"text/event-stream": {}}, "description": "Server-sent events."}, **ERROR_RESPONSES},
)
def get_live(execution_id: str, request: Request, store: StoreDep, cursor: LiveCursor = 0) -> StreamingResponse:
    """An execution as it runs, as server-sent events (``text/event-stream``), for a browser: ``telemetry`` events
    (t s, phase code, segment, tool and reference positions world m, wrenches world and CF N N·m, desired CF-z force
    N, whether the tool touches anything and the true normal force N, both from the simulator and null where not
    recorded; decimated to 100 samples per s of execution time, always with the last one stored) at up to 25 per s,
    each with the stream index to resume from as its ``id``; ``status`` when the state changes; ``end`` with the
    final view (metrics, verdict) once it finished and its telemetry is stored. ``cursor``: where to start (0: the
    beginning; after a lost connection, the last event's id). 404 for an unknown id."""
    if store.executions.get(execution_id) is None:
        raise errors.not_found("execution", execution_id)
    return StreamingResponse(
        _events(request, store, execution_id, cursor),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
