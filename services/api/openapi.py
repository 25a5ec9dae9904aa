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

from collections.abc import Iterator

from fastapi import FastAPI
from pydantic import JsonValue

from services.settings import ServiceSettings

BEARER_REQUIREMENT: dict[str, JsonValue] = {"HTTPBearer": []}
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


def _object(value: JsonValue) -> dict[str, JsonValue]:
    """``value``, a JSON object of the document; an empty one where the document has none."""
    return value if isinstance(value, dict) else {}


def _array(value: JsonValue) -> list[JsonValue]:
    """``value``, a JSON array of the document; an empty one where the document has none."""
    return value if isinstance(value, list) else []


def _member(document: JsonValue, *keys: str) -> JsonValue:
    """The member at ``keys`` down the nested objects of ``document``; None where one is missing."""
    for key in keys:
        document = _object(document).get(key)
    return document


def operations(spec: dict[str, JsonValue]) -> Iterator[tuple[str, str, dict[str, JsonValue]]]:
    """Every operation of an OpenAPI document: its path, its method and the operation object (to change in place)."""
    for path, methods in _object(spec["paths"]).items():
        for method, operation in _object(methods).items():
            yield path, method, _object(operation)


def _operation_id(spec: dict[str, JsonValue], method: str, path: str) -> str | None:
    operation_id = _member(spec, "paths", path, method, "operationId")
    return operation_id if isinstance(operation_id, str) else None


def _links(spec: dict[str, JsonValue], parameter: str) -> dict[str, JsonValue]:
    """Every operation a created object's ``id`` (``$response.body#/id``) leads to, by a link name."""
    links: dict[str, JsonValue] = {}
    for path, _, operation in operations(spec):
        if "{" + parameter + "}" not in path:
            continue
        operation_id = str(operation["operationId"])
        links[operation_id] = {"operationId": operation_id, "parameters": {parameter: "$response.body#/id"}}
    for path in BODY_LINKS.get(parameter, []):
        if (body_operation_id := _operation_id(spec, "post", path)) is not None:
            links[body_operation_id] = {
                "operationId": body_operation_id,
                "requestBody": {parameter: "$response.body#/id"},
            }
    return links


def _component(components: dict[str, JsonValue], reference: JsonValue) -> dict[str, JsonValue]:
    """The component schema a ``$ref`` (``#/components/schemas/Name``) names; an empty one for none."""
    name = reference.rsplit("/", 1)[-1] if isinstance(reference, str) else ""
    return _object(components.get(name))


def _form_models(spec: dict[str, JsonValue]) -> list[dict[str, JsonValue]]:
    """The component schemas the multipart request bodies are made of (their own and those they include)."""
    components = _object(_member(spec, "components", "schemas"))
    models = []
    for _, _, operation in operations(spec):
        form = _member(operation, "requestBody", "content", "multipart/form-data")
        if form is None:
            continue
        body = _component(components, _member(form, "schema", "$ref"))
        models.append(body)
        models.extend(_component(components, _member(part, "$ref")) for part in _array(body.get("allOf")))
    return models


def _without_null(field: dict[str, JsonValue]) -> None:
    """``field``'s schema without its null alternative (in place): ``anyOf [X, null]`` becomes ``X``."""
    alternatives = _array(field.get("anyOf"))
    options = [option for option in alternatives if option != {"type": "null"}]
    if "anyOf" in field and len(options) < len(alternatives):
        del field["anyOf"]
        if len(options) == 1:
            field.update(_object(options[0]))
        else:
            field["anyOf"] = options
        if field.get("default", 0) is None:
            del field["default"]


def truthful_openapi(spec: dict[str, JsonValue], settings: ServiceSettings) -> dict[str, JsonValue]:
    """``spec`` (FastAPI's) with each operation's security as the API applies it, the form fields and the links of
    the module docstring (changed in place, returned)."""
    for model in _form_models(spec):
        for field in _object(model.get("properties")).values():
            _without_null(_object(field))
    for path, method, operation in operations(spec):
        if "security" in operation:
            operation["security"] = (
                [BEARER_REQUIREMENT] if needs_token(settings, method, path) else [{}, BEARER_REQUIREMENT]
            )
    for path, (status, parameter) in CREATED.items():
        response = _member(spec, "paths", path, "post", "responses", status)
        if isinstance(response, dict):
            response["links"] = _links(spec, parameter)
    return spec


def install_truthful_openapi(app: FastAPI, settings: ServiceSettings) -> None:
    """Serve :func:`truthful_openapi` of the app's document (built once, on the first request)."""
    generate = app.openapi

    def openapi() -> dict[str, JsonValue]:
        if app.openapi_schema is None:
            app.openapi_schema = truthful_openapi(generate(), settings)
        return app.openapi_schema

    vars(app)["openapi"] = openapi  # FastAPI's documented override: the app's openapi, an attribute of its own
