"""``/skills``: learn one from a stored or an inline demonstration (``skills.parameterize.learn_skill``, in a learner
process of ``services.learner_pool``: the event loop never waits on it), list, get, delete, its MCAP (the robot,
the demonstrated path and the learned compliant frames, for Foxglove) and its plan for a real cell."""

from __future__ import annotations

import asyncio
from dataclasses import asdict
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from pydantic import JsonValue

from schemas.api import ApiError, SkillInfo, SkillRequest, StoredSkill
from schemas.skill import MAX_JOINT_SAMPLES
from schemas.skill_plan import MAX_PLAN_SAMPLES, PlanFormat, SkillPlan
from services.api import errors
from services.api.deps import (
    READ_GUARD,
    STORING_GUARD,
    TOKEN_GUARD,
    LearnersDep,
    Limit,
    Offset,
    StoreDep,
    readable_demonstration,
)
from services.api.errors import ERROR_RESPONSES, MUTATING_RESPONSES, READ_RESPONSES, STORING_RESPONSES
from services.api.responses import LIST_RESPONSES, list_page, raw_json
from services.learner_pool import LearnerPoolFull, LearningCancelled, LearningTimedOut, LearnOutcomeKind
from services.store import Store

router = APIRouter(tags=["skills"], dependencies=READ_GUARD, responses=READ_RESPONSES)


@router.post(
    "/skills",
    status_code=201,
    responses={
        201: {"model": StoredSkill},
        **ERROR_RESPONSES,
        **STORING_RESPONSES,
        409: {"model": ApiError},
        503: {"model": ApiError},
    },
    dependencies=STORING_GUARD,
)
async def post_skill(request: SkillRequest, store: StoreDep, learners: LearnersDep, http: Request) -> Response:
    """Learn a skill (slide, contour or auto) from a stored or an inline demonstration, or from several stored ones
    of the same task together (``demonstration_ids``: the skill names each with its weight, and those left out with
    their reason, docs/LEARNING.md section 11), and store it.

    Learns in a separate process within the service's time and memory budget (422 past either); a request
    whose client goes away is cancelled. A demonstration that cannot give the skill is a 422 naming the field, a
    stored one that cannot be read back (stored under looser rules) a 409; 503 when too many learning requests are
    waiting. The skill checks itself against the demonstration: the
    reply's ``warnings`` are its failed checks; with ``strict: true`` such a skill is refused instead (422, one
    entry per failed check)."""
    ids = request.stored_ids()
    if ids is None:
        assert request.demonstration is not None
        demonstrations_json = [await asyncio.to_thread(request.demonstration.model_dump_json)]
        loc, sources, stored_id = ["body", "demonstration"], ["inline"], None
    else:
        field = "demonstration_ids" if request.demonstration_ids is not None else "demonstration_id"
        loc, sources = ["body", field], ids
        if len(ids) > 1:
            await asyncio.to_thread(_within_joint_bounds, store, ids)
        demonstrations_json = [(await asyncio.to_thread(readable_demonstration, store, i))[1] for i in ids]
        stored_id = ids[0] if len(ids) == 1 else None
    options_json = request.learn_options().model_dump_json()
    try:
        outcome = await learners.learn(demonstrations_json, sources, options_json, http.is_disconnected)
    except LearnerPoolFull as exc:
        raise errors.unavailable(str(exc)) from None
    except LearningTimedOut as exc:
        raise errors.unprocessable(loc, f"cannot learn from this demonstration: {exc}", "learning_budget") from None
    except LearningCancelled:
        return Response(status_code=499)  # nobody reads it: the client is gone
    if outcome.kind is LearnOutcomeKind.learning and outcome.field == "demonstrations":  # the demonstrations together
        raise errors.unprocessable(loc, outcome.reason, "learning_error")
    if outcome.kind is not LearnOutcomeKind.ok:
        raise errors.learning_outcome_failed(outcome, loc, stored_id, learners.memory_mb)
    if len(sources) > 1:  # a joint skill's segments refer to its reference demonstration: the one stored with it
        stored_id = outcome.reference
    warnings = list(outcome.reasons)
    row = await asyncio.to_thread(store.skills.add, outcome.skill_json, outcome.skill_type, stored_id, warnings)
    parts: dict[str, JsonValue] = {"id": row.id, "demonstration_id": row.demonstration_id, "created": row.created}
    parts |= {"learn_seconds": round(outcome.seconds, 4), "warnings": list(row.warnings)}
    return raw_json(parts, {"skill": outcome.skill_json}, 201)


def _within_joint_bounds(store: Store, ids: list[str]) -> None:
    """422 on ``demonstration_ids`` when the stored demonstrations hold more samples in all than are learned together
    (`schemas.skill.MAX_JOINT_SAMPLES`; from their summaries, before any is read); 404 for an unknown id."""
    total = 0
    for demonstration_id in ids:
        row = store.demonstrations.row(demonstration_id)
        if row is None:
            raise errors.not_found("demonstration", demonstration_id)
        total += row.summary.n_samples if row.summary is not None else 0
    if total > MAX_JOINT_SAMPLES:
        raise errors.unprocessable(
            ["body", "demonstration_ids"],
            f"{total} samples in all: at most {MAX_JOINT_SAMPLES} are learned together (fewer or shorter "
            "demonstrations)",
            "learning_budget",
        )


@router.get("/skills", response_model=list[SkillInfo], responses=LIST_RESPONSES)
def list_skills(store: StoreDep, limit: Limit = 100, offset: Offset = 0) -> Response:
    """Stored skills, newest first (no parameters).

    Each row: id, the demonstration it was learned from, type (slide or contour), number of segments and the
    auto selection's confidence; ``limit`` and ``offset`` page through them, a page of at most 4 MiB naming the next
    one's offset in ``X-Next-Offset``."""
    return list_page(store.skills.page(limit + 1, offset), lambda row: SkillInfo(**asdict(row)), offset, limit)


@router.get("/skills/{skill_id}", responses={200: {"model": StoredSkill}, **ERROR_RESPONSES})
def get_skill(skill_id: str, store: StoreDep) -> Response:
    """A stored skill with all its parameters.

    Segments with their compliant frames, DMPs (position, orientation, force), selection matrices, the force and
    the quality figures, as ``schemas.Skill``; 404 for an unknown id."""
    row = store.skills.get(skill_id)
    if row is None:
        raise errors.not_found("skill", skill_id)
    parts: dict[str, JsonValue] = {
        "id": row.id,
        "demonstration_id": row.demonstration_id,
        "created": row.created,
        "learn_seconds": None,
    }
    return raw_json({**parts, "warnings": list(row.warnings)}, {"skill": row.skill_json})


@router.delete(
    "/skills/{skill_id}",
    status_code=204,
    responses={**ERROR_RESPONSES, **MUTATING_RESPONSES},
    dependencies=TOKEN_GUARD,
)
def delete_skill(skill_id: str, store: StoreDep) -> Response:
    """Delete a stored skill (executions that ran it keep their records).

    204 when deleted, 404 for an unknown id; needs the bearer token when one is set."""
    if not store.skills.delete(skill_id):
        raise errors.not_found("skill", skill_id)
    return Response(status_code=204)


@router.get(
    "/skills/{skill_id}/mcap",
    responses={
        200: {"content": {"application/octet-stream": {}}, "description": "MCAP."},
        **ERROR_RESPONSES,
        409: {"model": ApiError},
    },
)
def get_skill_mcap(skill_id: str, store: StoreDep) -> Response:
    """A skill along the demonstration it was learned from, as MCAP (ROS 2 messages, for Foxglove): the
    demonstration's tool pose and applied wrench, ``/tf`` with the LEARNED compliant frame ``cf`` through every contact
    segment, ``/markers`` with the path and a triad at each learned frame, and, for a demonstration recorded in the
    simulator (the robot's world), the robot: ``/robot_description``, ``/joint_states`` (inverse kinematics of the tool
    pose) and the URDF's joints in ``/tf``. 404 for an unknown skill or a deleted demonstration; 409 for a skill
    learned from an inline demonstration (none stored) or from one that cannot be read back."""
    from schemas.demonstration import DemonstrationArrays
    from schemas.skill import Skill
    from services.api.responses import download
    from services.api.routes.demonstrations import readable_samples
    from services.store.rows import SAMPLE_ARRAYS
    from services.telemetry_export import MCAP_MEDIA_TYPE, skill_mcap

    row = store.skills.get(skill_id)
    if row is None:
        raise errors.not_found("skill", skill_id)
    if row.demonstration_id is None:
        raise errors.no_demonstration(skill_id)
    demonstration, samples = readable_samples(store, row.demonstration_id)
    a = DemonstrationArrays(**{name: getattr(samples, name) for name in SAMPLE_ARRAYS})
    mcap = skill_mcap(a, Skill.model_validate_json(row.skill_json), skill_id, demonstration.created)
    return download(mcap.data, MCAP_MEDIA_TYPE, f"{skill_id}.mcap")


@router.get(
    "/skills/{skill_id}/plan",
    responses={
        200: {"model": SkillPlan, "content": {"application/octet-stream": {}}, "description": "JSON, or MCAP."},
        **ERROR_RESPONSES,
    },
)
def get_skill_plan(
    skill_id: str,
    store: StoreDep,
    every: Annotated[int, Query(ge=1, le=1000, description="Keep every N-th control step.")] = 1,
    max_samples: Annotated[
        int, Query(ge=1, le=MAX_PLAN_SAMPLES, description="Refuse (422) a plan of more samples than this.")
    ] = MAX_PLAN_SAMPLES,
    format: Annotated[
        PlanFormat,
        Query(description="json: the plan (SkillPlan); mcap: the same as ROS 2 messages (docs/REAL_CELL.md)."),
    ] = PlanFormat.json,
) -> Response:
    """A skill's nominal plan for a real cell (``schemas.skill_plan.SkillPlan``, docs/REAL_CELL.md): the phase
    planner's references for every control step (timed poses, compliant frame, selection, desired force along CF z,
    phase) with the default settings' controller gains, the skill as stored; ``format=mcap``: the same plan as MCAP
    (the samples as ROS 2 messages, the rest in its metadata). 404 for an unknown id; 422 on ``max_samples`` when the
    plan holds more samples than that (``every`` thins it)."""
    from execution.plan_export import PlanTooLongError, skill_plan
    from schemas.skill import Skill

    row = store.skills.get(skill_id)
    if row is None:
        raise errors.not_found("skill", skill_id)
    try:
        plan = skill_plan(Skill.model_validate_json(row.skill_json), every=every, max_samples=max_samples,
                          skill_id=skill_id)  # fmt: skip
    except PlanTooLongError as exc:
        raise errors.unprocessable(["query", "max_samples"], str(exc)) from None
    if format is PlanFormat.mcap:
        from services.api.responses import download
        from services.telemetry_export import MCAP_MEDIA_TYPE, plan_mcap

        return download(plan_mcap(plan).data, MCAP_MEDIA_TYPE, f"{skill_id}_plan.mcap")
    return Response(plan.model_dump_json(), media_type="application/json")
