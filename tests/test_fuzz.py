"""Fuzzing in CI: schemathesis generates requests from the live API's own OpenAPI document (valid and invalid
bodies, parameters and paths) and checks every answer: never a 5xx, a status code the document declares for the
operation, the declared content type and a body that conforms to the declared schema.

The API runs with uvicorn on a free loopback port, on a temporary database, without a bus: recording and starting
an execution answer their declared 503 (the one 5xx allowed), the other execution operations 404; a few stored
objects give the id paths something to find. Bounded in time: a fixed number of examples per operation
(``EXAMPLES``) and no shrinking (about 40 s on 2 cores); a failure prints the request that caused it.
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest
from conftest import LiveApi
from hypothesis import HealthCheck, Phase, settings
from test_api import _demo_json

schemathesis = pytest.importorskip("schemathesis")

from schemathesis.specs.openapi.checks import (  # noqa: E402
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from services.app import create_app  # noqa: E402
from services.settings import ServiceSettings  # noqa: E402
from services.store import Store  # noqa: E402

EXAMPLES = 15
"""Examples per operation (17 operations)."""
CHECKS = [status_code_conformance, content_type_conformance, response_schema_conformance]
UNAVAILABLE = 503
"""The one 5xx the API gives by design here: no bus, so nothing can record or execute (declared, with its reason)."""


@pytest.fixture(scope="module")
def live_api(tmp_path_factory):
    settings = ServiceSettings(db_path=tmp_path_factory.mktemp("fuzz") / "fuzz.db", learn_timeout_s=10.0)
    with LiveApi(create_app(settings, bus=None)) as api:
        with httpx.Client(base_url=api.url, timeout=30) as http:  # something for the id paths to find
            demo = http.post("/demonstrations", json=_demo_json(duration_s=1.0)).json()
            http.post("/skills", json={"demonstration_id": demo["id"]}).raise_for_status()
        yield api


def _openapi() -> dict:
    """The OpenAPI document the live app serves (built without serving: pytest collects the cases from it)."""
    return create_app(ServiceSettings(db_path=Path(":memory:")), bus=None, store=Store(":memory:")).openapi()


schema = schemathesis.openapi.from_dict(_openapi())
"""Every operation, the uploads too: their options models declare the form's ``file`` beside the options
(`schemas.import_options`), so the multipart body FastAPI describes can be generated."""


@schema.parametrize()
@settings(
    max_examples=EXAMPLES,
    deadline=None,
    phases=[Phase.explicit, Phase.generate],  # no shrinking: bounded time; the failing request is printed
    suppress_health_check=list(HealthCheck),
    derandomize=True,
)
def test_no_5xx_and_answers_match_the_openapi(case, live_api):
    response = case.call(base_url=live_api.url, timeout=30)
    try:
        assert response.status_code < 500 or response.status_code == UNAVAILABLE, response.text
        case.validate_response(response, checks=CHECKS)
    except Exception:
        print("request:", case.method, case.formatted_path, json.dumps(case.body, default=str)[:2000])
        raise
