"""The dashboard: its page at ``/`` and its assets (``services/dashboard/static``, in the package: it works offline),
and the two views its pages draw that the resources do not give in a drawable size (a skill with its demonstration
decimated, a sweep's figure)."""

from __future__ import annotations

import asyncio
from functools import cache
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Response
from fastapi.responses import FileResponse

from schemas import Skill
from schemas.dashboard import ExecutionScene, SkillView
from schemas.import_options import BagImportOptions, CsvImportOptions
from services.api import errors
from services.api.deps import READ_GUARD, KeysDep, StoreDep
from services.api.errors import ERROR_RESPONSES, READ_RESPONSES
from services.dashboard.scene import MESH_URI, JointSolver, robot_asset, robot_description
from services.dashboard.views import skill_view, sweep_png
from services.store import Store

STATIC = Path(__file__).resolve().parents[2] / "dashboard" / "static"
MEDIA_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}
"""The asset kinds the dashboard has; any other name is a 404."""

IMPORT_OPTIONS = {"csv": CsvImportOptions, "bag": BagImportOptions}
"""The options model of each upload route the page's form posts to."""

router = APIRouter(tags=["dashboard"])  # the page is open (it holds no data); its views need what reads need


@router.get("/", include_in_schema=False)
def page() -> FileResponse:
    """The dashboard (a single page; its data comes from the API with the token the user gives it)."""
    return FileResponse(STATIC / "index.html", media_type=MEDIA_TYPES[".html"])


@router.get("/dashboard/static/{name}", include_in_schema=False)
def asset(name: str) -> FileResponse:
    """One of the dashboard's own assets (only the files of its folder: no sub-paths)."""
    return _asset(STATIC, name)


@router.get("/dashboard/static/vendor/{name:path}", include_in_schema=False)
def vendored_asset(name: str) -> FileResponse:
    """One of the libraries the dashboard vendors (three.js and its addons in their package's folders,
    ``static/vendor/README.md``): a path inside that folder, no part of it hidden."""
    return _asset(STATIC / "vendor", name, nested=True)


def _asset(folder: Path, name: str, nested: bool = False) -> FileResponse:
    parts = name.split("/")
    path = folder.joinpath(*parts)
    hidden = any(not part or part.startswith(".") for part in parts)  # also "..", and "a//b"
    if (len(parts) > 1 and not nested) or hidden or path.suffix not in MEDIA_TYPES or not path.is_file():
        raise errors.not_found("dashboard asset", name)
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], headers={"Cache-Control": "no-cache"})


@router.get("/dashboard/robot/model.urdf", include_in_schema=False)
def robot_urdf() -> Response:
    """The robot the 3-D scene draws: the URDF Foxglove gets (``services.dashboard.scene.robot_description``), its
    meshes named ``package://kuka_iiwa/meshes/NAME.stl`` and served below."""
    return Response(robot_description(), media_type="application/xml", headers={"Cache-Control": "max-age=3600"})


@router.get("/dashboard/robot/meshes/{name}", include_in_schema=False)
def robot_mesh(name: str) -> Response:
    """One of the robot's STL meshes (the ones Foxglove live serves, from the same folder); 404 for any other name."""
    data = robot_asset(MESH_URI + name)
    if data is None:
        raise errors.not_found("robot mesh", name)
    return Response(data, media_type="model/stl", headers={"Cache-Control": "max-age=3600"})


@router.get("/dashboard/api/import-options", responses=READ_RESPONSES, dependencies=READ_GUARD)
def get_import_options() -> dict[str, Any]:
    """The options of an upload by kind, as JSON schemas by their form names: ``csv``, those of ``POST
    /demonstrations/csv`` (``CsvImportOptions``), ``bag``, those of ``POST /demonstrations/bag``
    (``BagImportOptions``); the same models give ``contact-skills learn FILE`` its flags. The page's upload form is
    generated from them."""
    return {kind: model.model_json_schema(by_alias=True) for kind, model in IMPORT_OPTIONS.items()}


@router.get(
    "/dashboard/api/skills/{skill_id}",
    response_model=SkillView,
    responses={**READ_RESPONSES, **ERROR_RESPONSES},
    dependencies=READ_GUARD,
)
async def get_skill_view(skill_id: str, store: StoreDep) -> SkillView:
    """A skill as its dashboard page draws it: segments on the demonstration's time line, the demonstrated and
    the learned force along CF z (N), the tool path and CF triads (world, m), the auto-selection verdict with its
    evidence, the skill's checks; a skill learned from several demonstrations also its segments' force bands on the
    reference demonstration's time line (N, s) and the demonstrations with their weights. The demonstration
    decimated to at most 1500 samples. 404 for an unknown id."""
    return await asyncio.to_thread(_skill_view, store, skill_id)


def _skill_view(store: Store, skill_id: str) -> SkillView:
    row = store.skills.get(skill_id)
    if row is None:
        raise errors.not_found("skill", skill_id)
    demonstration = store.demonstrations.get(row.demonstration_id) if row.demonstration_id else None
    view = skill_view(skill_id, row.demonstration_id, Skill.model_validate_json(row.skill_json), demonstration)
    if demonstration is not None:
        a = demonstration.arrays()
        view.joints = _joint_solver().reached(a.positions[0], a.orientations[0])
    latest = store.executions.latest_work_piece(skill_id)
    if latest is not None:
        view.work_piece_execution, view.work_piece = latest
    return view


@cache
def _joint_solver() -> JointSolver:
    """One inverse kinematics solver for the skill pages' arm (thread-safe; each solve starts from home)."""
    return JointSolver()


@router.get(
    "/dashboard/api/executions/{execution_id}/scene",
    response_model=ExecutionScene,
    responses={**READ_RESPONSES, **ERROR_RESPONSES},
    dependencies=READ_GUARD,
)
def get_execution_scene(execution_id: str, store: StoreDep) -> ExecutionScene:
    """What an execution's 3-D view draws besides its telemetry: the solids of the world it runs in (world frame,
    m), as its worker reported them when it started (null before). 404 for an unknown id."""
    if store.executions.get(execution_id) is None:
        raise errors.not_found("execution", execution_id)
    return ExecutionScene(work_piece=store.executions.work_piece(execution_id))


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
