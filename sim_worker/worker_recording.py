"""A sim worker's recordings of the scripted teacher (``P/exec/{worker_id}/record``): whether a request may run, and
the reply its recording makes. The worker answers the query and holds itself busy meanwhile
(``sim_worker.zenoh_worker``)."""

from __future__ import annotations

import logging
import time

from schemas.bus import RecordReply, RecordRequest
from schemas.job_budget import JobBudget, JobEstimate

log = logging.getLogger("contact_skills.worker")


def over_budget(estimate: JobEstimate, budget: JobBudget) -> str | None:
    """Why a job is refused (``field: reason`` for each setting that takes it past ``budget``), or None if it fits."""
    problems = estimate.problems(budget)
    return "; ".join(f"{field}: {message}" for field, message in problems) or None


def short_error(exc: BaseException) -> str:
    """One readable line (pydantic errors: field and reason)."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        parts = [f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}" for e in exc.errors()[:5]]
        return "; ".join(parts)
    text = str(exc) or type(exc).__name__
    return text if isinstance(exc, ValueError | TypeError) else f"{type(exc).__name__}: {text}"


def record_request(payload: bytes, budget: JobBudget) -> RecordRequest:
    """The record request ``payload`` holds, when it fits ``budget``; else ``ValueError`` (pydantic's, or the budget's
    reason) to answer with :func:`short_error`."""
    from sim_worker.teacher import recording_estimate

    request = RecordRequest.model_validate_json(payload)
    if over := over_budget(recording_estimate(request.scenario, **request.overrides), budget):
        raise ValueError(over)
    return request


def recording_reply(worker_id: str, request: RecordRequest) -> RecordReply:
    """Record ``request``'s demonstration and the reply that carries it; an ``error`` reply whatever fails (the
    import too)."""
    started = time.perf_counter()
    try:
        from sim_worker.teacher import record_demonstration

        log.info("recording %s (seed %d, overrides %s)", request.scenario, request.seed, request.overrides)
        recording = record_demonstration(request.scenario, request.seed, **request.overrides)
        return RecordReply(
            worker_id=worker_id,
            code="ok",
            demonstration=recording.demonstration,
            ground_truth=recording.ground_truth_dict(),
            wall_s=time.perf_counter() - started,
        )
    except Exception as exc:
        return RecordReply(
            worker_id=worker_id, code="error", error=short_error(exc), wall_s=time.perf_counter() - started
        )
