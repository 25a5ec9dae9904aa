"""The API's routes: one APIRouter per resource, included in the order the OpenAPI document lists them."""

from __future__ import annotations

from fastapi import APIRouter

from schemas.api import ApiError
from services.api.routes import dashboard, demonstrations, executions, health, live, skills, sweeps

api_router = APIRouter(responses={400: {"model": ApiError, "description": "Malformed request (body, header, host)"}})
api_router.include_router(health.router)
api_router.include_router(demonstrations.router)
api_router.include_router(skills.router)
api_router.include_router(executions.router)
api_router.include_router(live.router)
api_router.include_router(sweeps.router)
api_router.include_router(dashboard.router)
