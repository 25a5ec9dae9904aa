"""Offline API docs (services/api/docs.py): /docs (Swagger UI) and /redoc load every asset from the API itself, no
outside host, and every route has a summary and a description in the OpenAPI document."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient

from services.app import create_app
from services.settings import ServiceSettings


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    settings = ServiceSettings(db_path=tmp_path_factory.mktemp("docs") / "docs.db")
    with TestClient(create_app(settings, bus=None), base_url="http://127.0.0.1") as c:  # a loopback API's Host
        yield c


def _references(html: str) -> list[str]:
    """Every URL a page loads or names: src/href attributes, quoted urls in scripts, and any scheme://host."""
    found = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)["']""", html)
    found += re.findall(r"""\burl:\s*["']([^"']+)["']""", html)
    found += re.findall(r"""spec-url\s*=\s*["']([^"']+)["']""", html)
    found += re.findall(r"(?:https?:)?//[\w.-]+\.\w+", html)
    return found


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_the_docs_pages_load_everything_from_the_api_itself(client, page):
    response = client.get(page)
    assert response.status_code == 200 and response.headers["content-type"].startswith("text/html")
    references = _references(response.text)
    assert references, "the page loads nothing?"
    outside = [url for url in references if not url.startswith("/") or url.startswith("//")]
    assert outside == [], f"{page} references outside hosts: {outside}"
    for url in references:
        asset = client.get(url)
        assert asset.status_code == 200, url
        assert len(asset.content) > 200, url
    scripts = [url for url in references if url.endswith(".js")]
    assert scripts and all("javascript" in client.get(url).headers["content-type"] for url in scripts)


def test_swagger_ui_does_not_call_the_online_validator(client):
    assert '"validatorUrl": null' in client.get("/docs").text


def test_every_route_has_a_summary_and_a_description(client):
    spec = client.get("/openapi.json").json()
    operations = [(method.upper(), path, op) for path, ops in spec["paths"].items() for method, op in ops.items()]
    assert len(operations) >= 19
    for method, path, op in operations:
        summary, description = op.get("summary", ""), op.get("description", "")
        assert summary and description, f"{method} {path}"
        assert "`" not in summary, f"{method} {path}: markup in the summary {summary!r}"
        assert len(description) > len(summary) + 40, f"{method} {path}: the description only repeats the summary"
        function_like = " ".join(w.capitalize() for w in op["operationId"].split("_")[:3])
        assert summary != function_like, f"{method} {path}: FastAPI's generated summary"
