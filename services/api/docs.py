"""Offline API docs: Swagger UI (``/docs``) and ReDoc (``/redoc``) served by the API from the assets of the
``fastapi-offline`` package (no CDN: they work in a robot cell without internet), and a summary on every route.

FastAPI's own pages load their JavaScript and CSS from a CDN; :func:`install_offline_docs` replaces them with
pages whose every asset is under :data:`ASSETS_URL` on the API itself, and turns Swagger UI's online validator
badge off (it would call an outside host). Every route's OpenAPI summary is the first sentence of its docstring
(:func:`summary_of`) and its description the docstring (a route without a docstring has neither, which
tests/test_docs.py refuses).
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from pydantic import JsonValue

from services.api.openapi import operations

ASSETS_URL = "/docs-assets"
"""Where the Swagger UI and ReDoc assets are served."""


def _assets_directory() -> Path:
    import fastapi_offline

    return Path(fastapi_offline.__file__).parent / "static"


def install_offline_docs(app: FastAPI) -> None:
    """Serve ``/docs`` and ``/redoc`` from local assets (create the app with ``docs_url=None, redoc_url=None``) and
    give every route its summary."""
    app.mount(ASSETS_URL, StaticFiles(directory=_assets_directory()), name="docs-assets")
    openapi_url = app.openapi_url or "/openapi.json"
    redirect_url = app.swagger_ui_oauth2_redirect_url or "/docs/oauth2-redirect"

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        return get_swagger_ui_html(
            openapi_url=root + openapi_url,
            title=f"{app.title} - Swagger UI",
            oauth2_redirect_url=root + redirect_url,
            swagger_js_url=f"{root}{ASSETS_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{root}{ASSETS_URL}/swagger-ui.css",
            swagger_favicon_url=f"{root}{ASSETS_URL}/favicon.png",
            swagger_ui_parameters={"validatorUrl": None, "tryItOutEnabled": True},
        )

    @app.get(redirect_url, include_in_schema=False)
    async def swagger_ui_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    @app.get("/redoc", include_in_schema=False)
    async def redoc(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        return get_redoc_html(
            openapi_url=root + openapi_url,
            title=f"{app.title} - ReDoc",
            redoc_js_url=f"{root}{ASSETS_URL}/redoc.standalone.js",
            redoc_favicon_url=f"{root}{ASSETS_URL}/favicon.png",
            with_google_fonts=False,
        )

    generate = app.openapi

    def openapi() -> dict[str, JsonValue]:
        summarized = app.openapi_schema is not None  # the document is built once, and summarized then
        schema = generate()
        if not summarized:
            for _, _, operation in operations(schema):
                description = operation.get("description")
                if isinstance(description, str) and description:
                    operation["summary"] = summary_of(description)
        return schema

    vars(app)["openapi"] = openapi  # FastAPI's documented override: the app's openapi, an attribute of its own


SUMMARY_LENGTH = 90
"""A summary longer than this is cut at its first colon, semicolon or parenthesis."""


def summary_of(description: str) -> str:
    """The first sentence of a route's docstring, without markup: its OpenAPI summary."""
    paragraph = " ".join(description.strip().split("\n\n")[0].split()).replace("`", "")
    sentence = paragraph.split(". ")[0].rstrip(".")
    if len(sentence) > SUMMARY_LENGTH:
        cuts = [k for k in (sentence.find(": "), sentence.find("; "), sentence.find(" (")) if k > 0]
        sentence = sentence[: min(cuts)] if cuts else sentence
    return sentence
