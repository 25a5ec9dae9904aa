"""``/skills``: learn one from a stored or an inline demonstration (``skills.parameterize.learn_skill``, in the thread
pool), list, get, delete."""

from __future__ import annotations

import time

from fastapi import APIRouter, Response

from schemas.api import SkillInfo, SkillRequest, StoredSkill
from services.api import errors
from services.api.deps import TOKEN_GUARD, Limit, Offset, StoreDep
from services.api.errors import ERROR_RESPONSES, MUTATING_RESPONSES
from services.api.limits import check_sampling
from services.api.responses import raw_json

router = APIRouter(tags=["skills"])


@router.post(
    "/skills",
    status_code=201,
    responses={201: {"model": StoredSkill}, **ERROR_RESPONSES, **MUTATING_RESPONSES},
    dependencies=TOKEN_GUARD,
)
def post_skill(request: SkillRequest, store: StoreDep) -> Response:
    """Learn a skill (slide, contour or auto) from a stored or an inline demonstration, and store it.

    Runs in the thread pool. A demonstration that cannot give the skill is a 422 naming the field."""
    from skills.parameterize import LearningError, learn_skill

    if request.demonstration is not None:
        demonstration, loc = request.demonstration, ["body", "demonstration"]
    else:
        assert request.demonstration_id is not None
        demonstration = store.demonstration(request.demonstration_id)
        if demonstration is None:
            raise errors.not_found("demonstration", request.demonstration_id)
        loc = ["body", "demonstration_id"]
    started = time.perf_counter()
    try:
        check_sampling(demonstration)
        skill = learn_skill(demonstration, request.learn_options())
    except LearningError as exc:
        stored_id = None if request.demonstration is not None else request.demonstration_id
        raise errors.learning_failed(exc, loc, stored_id) from None
    except ValueError as exc:  # the science refused the data without saying which field: still the input's
        raise errors.cannot_learn(exc, loc) from None
    elapsed = time.perf_counter() - started
    skill_json = skill.model_dump_json()
    row = store.add_skill(skill_json, skill.skill_type.value, request.demonstration_id)
    parts = {"id": row.id, "demonstration_id": row.demonstration_id, "created": row.created}
    return raw_json({**parts, "learn_seconds": round(elapsed, 4)}, {"skill": skill_json}, status_code=201)


@router.get("/skills", response_model=list[SkillInfo])
def list_skills(store: StoreDep, limit: Limit = 100, offset: Offset = 0) -> list[SkillInfo]:
    """Stored skills, newest first (no parameters).

    Each row: id, the demonstration it was learned from, type (slide or contour), number of segments and the
    auto selection's confidence; ``limit`` and ``offset`` page through them."""
    return [SkillInfo(**row) for row in store.list_skills(limit, offset)]


@router.get("/skills/{skill_id}", responses={200: {"model": StoredSkill}, **ERROR_RESPONSES})
def get_skill(skill_id: str, store: StoreDep) -> Response:
    """A stored skill with all its parameters.

    Segments with their compliant frames, DMPs (position, orientation, force), selection matrices, the force and
    the quality figures, as ``schemas.Skill``; 404 for an unknown id."""
    row = store.skill(skill_id)
    if row is None:
        raise errors.not_found("skill", skill_id)
    parts = {"id": row.id, "demonstration_id": row.demonstration_id, "created": row.created, "learn_seconds": None}
    return raw_json(parts, {"skill": row.skill_json})


@router.delete(
    "/skills/{skill_id}",
    status_code=204,
    responses={**ERROR_RESPONSES, **MUTATING_RESPONSES},
    dependencies=TOKEN_GUARD,
)
def delete_skill(skill_id: str, store: StoreDep) -> Response:
    """Delete a stored skill (executions that ran it keep their records).

    204 when deleted, 404 for an unknown id; needs the bearer token when one is set."""
    if not store.delete_skill(skill_id):
        raise errors.not_found("skill", skill_id)
    return Response(status_code=204)
