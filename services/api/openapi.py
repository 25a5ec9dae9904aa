"""The OpenAPI document as the API behaves: who needs the bearer token, and how the ids one answer gives lead to the
operations that take them (OpenAPI links, which clients and stateful fuzzers follow).

- **Security.** FastAPI declares the bearer scheme on every operation that reads the ``Authorization`` header, as
  if each required it. The truth depends on the settings: with no ``CONTACT_SKILLS_TOKEN`` nothing needs it; with
  one, POST and DELETE need it, and the GETs only with ``CONTACT_SKILLS_TOKEN_READS`` (never ``/health``, which
  shows details to a request that carries it). An operation that does not need the token declares it optional
  (``security: [{}, {"HTTPBearer": []}]``).
- **Forms.** A multipart form field is present or absent, never null: the upload forms' options (whose models
  allow None for "not given", as in JSON) are declared without the null alternative, so a client generated from
  the document leaves them out instead of sending ``null`` as text.
- **Links.** A created demonstration's ``id`` is the ``demonstration_id`` of its GET, DELETE and telemetry, and of
  ``POST /skills``; a skill's is the ``skill_id`` of its GET and DELETE and of ``POST /executions`` and ``/sweeps``;
  an execution's and a sweep's ids those of their reads and commands.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI

from services.settings import ServiceSettings

BEARER_REQUIREMENT = {"HTTPBearer": []}
CREATED: dict[str, tuple[str, str]] = {
    "/demonstrations": ("201", "demonstration_id"),
    "/demonstrations/csv": ("201", "demonstration_id"),
    "/demonstrations/bag": ("201", "demonstration_id"),
    "/demonstrations/record": ("201", "demonstration_id"),
    "/skills": ("201", "skill_id"),
    "/executions": ("202", "execution_id"),
    "/sweeps": ("202", "sweep_id"),
}
"""The POST operations that create an object: (their success status, the path parameter its ``id`` fills)."""
BODY_LINKS: dict[str, list[str]] = {"demonstration_id": ["/skills"], "skill_id": ["/executions", "/sweeps"]}
"""The POST operations whose body takes a created object's id (``{"demonstration_id": id}``)."""


def needs_token(settings: ServiceSettings, method: str, path: str) -> bool:
    """Whether a request of ``method`` on ``path`` is refused (401) without the bearer token."""
    if settings.token is None:
        return False
    if method.lower() != "get":
        return True
    return settings.token_reads and path != "/health"


def _operation_id(spec: dict[str, Any], method: str, path: str) -> str | None:
    return spec["paths"].get(path, {}).get(method, {}).get("operationId")


def _links(spec: dict[str, Any], parameter: str) -> dict[str, Any]:
    """Every operation a created object's ``id`` (``$response.body#/id``) leads to, by a link name."""
    links: dict[str, Any] = {}
    for path, operations in spec["paths"].items():
        if "{" + parameter + "}" not in path:
            continue
        for operation in operations.values():
            links[operation["operationId"]] = {
                "operationId": operation["operationId"],
                "parameters": {parameter: "$response.body#/id"},
            }
    for path in BODY_LINKS.get(parameter, []):
        if (operation_id := _operation_id(spec, "post", path)) is not None:
            links[operation_id] = {"operationId": operation_id, "requestBody": {parameter: "$response.body#/id"}}
    return links


def _form_models(spec: dict[str, Any]) -> list[dict[str, Any]]:
    """The component schemas the multipart request bodies are made of (their own and those they include)."""
    components = spec.get("components", {}).get("schemas", {})
    models = []
    for operations in spec["paths"].values():
        for operation in operations.values():
            form = operation.get("requestBody", {}).get("content", {}).get("multipart/form-data")
            if form is None:
                continue
            body = components.get(form["schema"].get("$ref", "").rsplit("/", 1)[-1], {})
            models.append(body)
            models.extend(components.get(part["$ref"].rsplit("/", 1)[-1], {}) for part in body.get("allOf", []))
    return models


def _without_null(field: dict[str, Any]) -> None:
    """``field``'s schema without its null alternative (in place): ``anyOf [X, null]`` becomes ``X``."""
    options = [option for option in field.get("anyOf", []) if option != {"type": "null"}]
    if "anyOf" in field and len(options) < len(field["anyOf"]):
        del field["anyOf"]
        if len(options) == 1:
            field.update(options[0])
        else:
            field["anyOf"] = options
        if field.get("default", 0) is None:
            del field["default"]


def truthful_openapi(spec: dict[str, Any], settings: ServiceSettings) -> dict[str, Any]:
    """``spec`` (FastAPI's) with each operation's security as the API applies it, the form fields and the links of
    the module docstring (changed in place, returned)."""
    for model in _form_models(spec):
        for field in model.get("properties", {}).values():
            _without_null(field)
    for path, operations in spec["paths"].items():
        for method, operation in operations.items():
            if "security" in operation:
                operation["security"] = (
                    [BEARER_REQUIREMENT] if needs_token(settings, method, path) else [{}, BEARER_REQUIREMENT]
                )
    for path, (status, parameter) in CREATED.items():
        response = spec["paths"].get(path, {}).get("post", {}).get("responses", {}).get(status)
        if response is not None:
            response["links"] = _links(spec, parameter)
    return spec


def install_truthful_openapi(app: FastAPI, settings: ServiceSettings) -> None:
    """Serve :func:`truthful_openapi` of the app's document (built once, on the first request)."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = truthful_openapi(generate(), settings)
        return app.openapi_schema

    vars(app)["openapi"] = openapi  # FastAPI's documented override: the app's openapi, an attribute of its own
