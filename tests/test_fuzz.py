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
from hypothesis.stateful import multiple, rule
from test_api import _demo_json

schemathesis = pytest.importorskip("schemathesis")

from schemathesis.generation.stateful.state_machine import StepOutput  # noqa: E402
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
    _check(case, case.call(base_url=live_api.url, timeout=30))


def _check(case, response) -> None:
    """No 5xx but the declared 503, and an answer the document declares; the request printed if not."""
    try:
        assert response.status_code < 500 or response.status_code == UNAVAILABLE, response.text
        case.validate_response(response, checks=CHECKS)
    except Exception:
        print("request:", case.method, case.formatted_path, json.dumps(case.body, default=str)[:2000])
        raise


STATEFUL_SCENARIOS = 25
"""Scenarios of the stateful run (each up to ``STATEFUL_STEPS`` linked calls)."""
STATEFUL_STEPS = 8
STATEFUL_PATHS = r"^/(demonstrations|skills)(/\{[a-z_]+\}(/telemetry)?)?$"
"""What the stateful run goes through: without a bus (here) no recording, execution or sweep is ever created, and a
random CSV or bag upload is never valid: the steps go to the chains that can succeed."""
DEMONSTRATION = _demo_json(duration_s=1.0)


def test_stateful_runs_follow_the_links_past_unknown_ids(live_api):
    """The document's links (``services.api.openapi``) lead from each created object to the operations that take its
    id: the state machine chains a created demonstration into its reads, its telemetry, its deletion and a learned
    skill, a skill into its reads and an execution or a sweep (503: no bus here). Every answer is checked as above,
    and the linked calls find what they ask for: most calls on an id path answer 2xx, not 404."""
    calls: list[tuple[str, str, int]] = []
    machine = schema.include(path_regex=STATEFUL_PATHS).as_state_machine()

    class Workflow(machine):  # type: ignore[misc,valid-type]
        @rule(target=machine.bundles["POST /demonstrations -> 201"])
        def store_a_demonstration(self):
            """A valid demonstration (random ones never are: 50 strictly increasing stamps, unit quaternions, ...)
            starts the chains; the links take it from there."""
            case = schema["/demonstrations"]["POST"].Case(body=DEMONSTRATION)
            self.recorder.record_case(case=case)  # the root of the chains that follow it
            response = case.call(**self.get_call_kwargs(case))
            self.after_call(response, case)
            self.validate_response(response, case)
            return StepOutput(response, case)

        @rule(target=machine.bundles["POST /skills -> 201"], stored=machine.bundles["POST /demonstrations -> 201"])
        def learn_a_skill(self, stored):
            """A skill learned from a stored demonstration (a random learning request rarely is valid)."""
            if stored.response.status_code != 201:
                return multiple()
            case = schema["/skills"]["POST"].Case(body={"demonstration_id": stored.response.json()["id"]})
            self.recorder.record_case(parent_id=stored.case.id, case=case, transition=None)
            response = case.call(**self.get_call_kwargs(case))
            self.after_call(response, case)
            self.validate_response(response, case)
            return StepOutput(response, case)

        def get_call_kwargs(self, case):
            return {"base_url": live_api.url, "timeout": 30}

        def after_call(self, response, case):
            super().after_call(response, case)
            calls.append((case.method, case.path, response.status_code))

        def validate_response(self, response, case, **kwargs):
            _check(case, response)

    Workflow.run(
        settings=settings(
            max_examples=STATEFUL_SCENARIOS,
            stateful_step_count=STATEFUL_STEPS,
            deadline=None,
            phases=[Phase.generate],
            suppress_health_check=list(HealthCheck),
            database=None,  # the linked steps depend on the ids the API gave: nothing to replay another time
            derandomize=True,
        )
    )
    print(sorted(set(calls)))
    on_ids = [status for _, path, status in calls if "{" in path]
    print(f"{len(calls)} calls, {len(on_ids)} on id paths: {sum(s < 300 for s in on_ids)} 2xx, {on_ids.count(404)} 404")
    assert on_ids and sum(status < 300 for status in on_ids) > on_ids.count(404)


@pytest.mark.parametrize(("token", "reads"), [(None, False), ("t0ken", False), ("t0ken", True)])
def test_the_openapi_declares_the_token_where_the_api_requires_it(tmp_path, token, reads):
    """Each operation declares the bearer token required exactly when a request without it gets 401, optional
    otherwise: every parameterless operation is asked without the token."""
    from conftest import loopback_client

    from services.api.openapi import BEARER_REQUIREMENT

    settings_ = ServiceSettings(db_path=tmp_path / "api.db", token=token, token_reads=reads, learn_warm_up=False)
    app = create_app(settings_, bus=None)
    spec = app.openapi()
    with loopback_client(app) as c:
        for path, operations in spec["paths"].items():
            for method, operation in operations.items():
                required = operation["security"] == [BEARER_REQUIREMENT]
                assert required or operation["security"] == [{}, BEARER_REQUIREMENT], (
                    method,
                    path,
                    operation["security"],
                )
                if "{" not in path:
                    answer = c.request(method.upper(), path)
                    assert (answer.status_code == 401) == required, (method, path, answer.status_code, required)
        assert spec["paths"]["/health"]["get"]["security"] == [
            {},
            BEARER_REQUIREMENT,
        ]  # details with the token, never refused


def test_the_upload_forms_are_declared_as_a_form_sends_them():
    """A form field is present or absent, never null: the upload forms declare no null alternative (a generated
    client sent ``null`` as text, refused); a 2-number field takes ``'T0,T1'`` and a JSON array's text alike."""
    from schemas.import_options import CsvImportOptions

    components = _openapi()["components"]["schemas"]
    for name in ("CsvImportOptions", "BagImportOptions"):
        for field, declared in components[name]["properties"].items():
            assert {"type": "null"} not in declared.get("anyOf", []), (name, field)
        assert components[name]["properties"]["wrench_frame"]["$ref"].endswith("/WrenchFrame")
    assert {"type": "null"} in components["ExecutionRequest"]["properties"]["skill_id"]["anyOf"]  # JSON keeps them
    for text in ("0.0,0.5", "[0.0, 0.5]"):
        assert CsvImportOptions.model_validate({"tare_window": text}).tare_window_s == (0.0, 0.5)
