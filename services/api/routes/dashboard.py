"""The dashboard: its page at ``/`` and its assets (``services/dashboard/static``, in the package: it works offline),
and the two views its pages draw that the resources do not give in a drawable size (a skill with its demonstration
decimated, a sweep's figure)."""

from __future__ import annotations

import asyncio
from pathlib import Path

from fastapi import APIRouter, Response
from fastapi.responses import FileResponse

from schemas import Skill
from schemas.dashboard import SkillView
from services.api import errors
from services.api.deps import READ_GUARD, KeysDep, StoreDep
from services.api.errors import ERROR_RESPONSES, READ_RESPONSES
from services.dashboard.views import skill_view, sweep_png
from services.store import Store

STATIC = Path(__file__).resolve().parents[2] / "dashboard" / "static"
MEDIA_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}
"""The asset kinds the dashboard has; any other name is a 404."""

router = APIRouter(tags=["dashboard"])  # the page is open (it holds no data); its views need what reads need


@router.get("/", include_in_schema=False)
def page() -> FileResponse:
    """The dashboard (a single page; its data comes from the API with the token the user gives it)."""
    return FileResponse(STATIC / "index.html", media_type=MEDIA_TYPES[".html"])


@router.get("/dashboard/static/{name}", include_in_schema=False)
def asset(name: str) -> FileResponse:
    """One of the dashboard's assets (only the files of its folder: no sub-paths)."""
    path = STATIC / name
    if "/" in name or name.startswith(".") or path.suffix not in MEDIA_TYPES or not path.is_file():
        raise errors.not_found("dashboard asset", name)
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], headers={"Cache-Control": "no-cache"})


@router.get(
    "/dashboard/api/skills/{skill_id}",
    response_model=SkillView,
    responses={**READ_RESPONSES, **ERROR_RESPONSES},
    dependencies=READ_GUARD,
)
async def get_skill_view(skill_id: str, store: StoreDep) -> SkillView:
    """A skill as its dashboard page draws it: segments on the demonstration's time line, the demonstrated and
    the learned force along CF z (N), the tool path and CF triads (world, m), the auto-selection verdict with its
    evidence, the skill's checks. The demonstration decimated to at most 1500 samples. 404 for an unknown id."""
    return await asyncio.to_thread(_skill_view, store, skill_id)


def _skill_view(store: Store, skill_id: str) -> SkillView:
    row = store.skills.get(skill_id)
    if row is None:
        raise errors.not_found("skill", skill_id)
    demonstration = store.demonstrations.get(row.demonstration_id) if row.demonstration_id else None
    return skill_view(skill_id, row.demonstration_id, Skill.model_validate_json(row.skill_json), demonstration)


@router.get(
    "/dashboard/api/sweeps/{sweep_id}/figure.png",
    responses={200: {"content": {"image/png": {}}, "description": "PNG."}, **READ_RESPONSES, **ERROR_RESPONSES},
    dependencies=READ_GUARD,
)
async def get_sweep_figure(sweep_id: str, store: StoreDep, keys: KeysDep) -> Response:
    """A sweep's figure: per varied parameter, the true normal-force RMS error of every trial and the success rate
    along its range, one colour per controller. 404 for an unknown id."""
    from services.sweeps import sweep_view, trial_results

    row = store.sweeps.get(sweep_id)
    if row is None:
        raise errors.not_found("sweep", sweep_id)
    png = await asyncio.to_thread(lambda: sweep_png(sweep_view(store, keys, row), trial_results(store, row)))
    return Response(png, media_type="image/png")
