"""Every read bounded (issue 41, item 2): free-form fields bounded at input (a 422 naming the field), time windows
that are finite and in order, lists paged with a byte budget, a demonstration's samples paged like telemetry.

The API in-process on a real SQLite database (``client`` of conftest.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from schemas.api import NEXT_OFFSET_HEADER
from schemas.text import MAX_FREE_FORM_BYTES, MAX_FREE_FORM_DEPTH, MAX_ID_CHARS, MAX_NAME_CHARS
from services.api import responses
from services.api.deps import NEXT_CURSOR_HEADER


def _demo(n: int = 60, **metadata) -> dict:
    """A valid demonstration of ``n`` samples at 100 Hz (JSON-able), with ``metadata``."""
    t = np.arange(n) * 0.01
    positions = np.stack([0.5 + 0.01 * t, 0.0 * t, 0.3 + 0.0 * t], axis=1)
    return {
        "t": t.tolist(),
        "positions": positions.tolist(),
        "orientations": [[0.0, 0.0, 0.0, 1.0]] * n,
        "wrenches": [[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]] * n,
        "metadata": metadata,
    }


def _nested(depth: int) -> dict:
    """A dict nested ``depth`` levels deep (the dict itself is level 1)."""
    nested: dict = {}
    for _ in range(depth - 1):
        nested = {"a": nested}
    return nested


def _post(client, body: dict | str):
    """POST /demonstrations with ``body`` written as it is (a lone surrogate's escape kept)."""
    text = body if isinstance(body, str) else json.dumps(body)
    return client.post("/demonstrations", content=text, headers={"content-type": "application/json"})


def _only_loc(response) -> list:
    assert response.status_code == 422, response.text[:1000]
    (entry,) = response.json()["detail"]
    return entry["loc"]


# --------------------------------------------------------------------------- fields bounded at input


@pytest.mark.parametrize(
    ("metadata", "field", "words"),
    [
        ({"name": "n" * (MAX_NAME_CHARS + 1)}, "name", f"at most {MAX_NAME_CHARS} characters"),
        ({"source": "s" * 5000}, "source", "at most 2000 characters"),
        ({"extra": _nested(900)}, "extra", f"nested deeper than {MAX_FREE_FORM_DEPTH} levels"),
        ({"extra": _nested(200)}, "extra", f"nested deeper than {MAX_FREE_FORM_DEPTH} levels"),
        ({"extra": _nested(MAX_FREE_FORM_DEPTH + 1)}, "extra", "nested deeper"),
        ({"extra": {"x": [[[[{"y": "z" * MAX_FREE_FORM_BYTES}]]]]}}, "extra", "more than 64 KiB"),
        ({"extra": {"notes": ["ok", "LONE"]}}, "extra", "lone surrogate (U+D800"),
        ({"extra": {"LONE": 1}}, "extra", "lone surrogate"),
        ({"name": "LONE"}, "name", "unicode"),
    ],
)
def test_free_form_metadata_is_bounded_with_a_422_naming_the_field(client, metadata, field, words):
    text = json.dumps(_demo(**metadata)).replace("LONE", "\\ud800")
    response = _post(client, text)
    assert _only_loc(response) == ["body", "metadata", field]
    assert words in response.json()["detail"][0]["msg"]
    assert client.get("/demonstrations").json() == []  # nothing stored


def test_metadata_at_the_bounds_is_stored_and_reads_back(client):
    extra = {"deep": _nested(MAX_FREE_FORM_DEPTH - 1), "text": "é" * 1000, "pair": "\U0001f600"}
    created = _post(client, _demo(name="n" * MAX_NAME_CHARS, extra=extra))
    assert created.status_code == 201, created.text
    stored = client.get(f"/demonstrations/{created.json()['id']}").json()["demonstration"]["metadata"]
    assert stored["extra"] == extra and stored["name"] == "n" * MAX_NAME_CHARS


def test_request_ids_scenarios_and_overrides_are_bounded(client):
    long_id = "x" * (MAX_ID_CHARS + 1)
    assert _only_loc(client.post("/skills", json={"demonstration_id": long_id})) == ["body", "demonstration_id"]
    assert _only_loc(client.post("/executions", json={"skill_id": long_id})) == ["body", "skill_id"]
    sweep = {"skill_id": "skill_x", "scenario": long_id, "vary": {"offset_z_m": {"low": 0, "high": 0.01}}}
    assert _only_loc(client.post("/sweeps", json=sweep)) == ["body", "scenario"]
    record = '{"scenario": "slide_flat", "overrides": {"\\ud800": 1}}'
    response = client.post("/demonstrations/record", content=record, headers={"content-type": "application/json"})
    assert _only_loc(response) == ["body", "overrides"]


def _csv(rows: int = 100) -> bytes:
    lines = [f"{k * 0.01},0,0,0,0,0,0,1,0,0,1" for k in range(rows)]
    return "\n".join(["t,px,py,pz,qx,qy,qz,qw,fx,fy,fz", *lines]).encode()


def test_upload_names_obey_the_same_bounds(client):
    long_name = "n" * MAX_NAME_CHARS + ".csv"
    response = client.post("/demonstrations/csv", files={"file": (long_name, _csv(), "text/csv")})
    assert _only_loc(response) == ["body", "file"] and "file name" in response.text
    response = client.post(
        "/demonstrations/csv", files={"file": ("ok.csv", _csv(), "text/csv")}, data={"name": "n" * 300}
    )
    assert _only_loc(response) == ["body", "name"]
    response = client.post("/demonstrations/bag", files={"file": ("b.mcap", b"x", "application/octet-stream")},
                           data={"wrench_topic": "/" * 300})  # fmt: skip
    assert ["body", "wrench_topic"] in [entry["loc"] for entry in response.json()["detail"]]
    fits = "n" * (MAX_NAME_CHARS - 4) + ".csv"
    created = client.post("/demonstrations/csv", files={"file": (fits, _csv(), "text/csv")})
    assert created.status_code == 201, created.text
    (listed,) = client.get("/demonstrations").json()
    assert listed["name"] == fits.removesuffix(".csv") and listed["source"] == f"csv:{fits}"


# --------------------------------------------------------------------------- windows finite and in order


@pytest.mark.parametrize(
    ("query", "parameter"),
    [("t0=nan", "t0"), ("t0=inf", "t0"), ("t1=-inf", "t1"), ("t0=0&t1=NaN", "t1"), ("t0=2&t1=1", "t1")],
)
def test_a_non_finite_or_inverted_window_is_a_422_naming_the_parameter(client, query, parameter):
    created = _post(client, _demo())
    assert created.status_code == 201, created.text
    for path in (f"/demonstrations/{created.json()['id']}/telemetry", "/executions/exec_000000000000/telemetry"):
        assert _only_loc(client.get(f"{path}?{query}")) == ["query", parameter]
    window = client.get(f"/demonstrations/{created.json()['id']}/telemetry?t0=0.1&t1=0.2")
    assert window.status_code == 200 and window.json()["n_samples"] == 11


# --------------------------------------------------------------------------- lists paged with a byte budget


def _pages(client, path: str, limit: int = 100) -> list[tuple[list, int]]:
    """Every page of a list (following X-Next-Offset from 0) as (items, bytes of the reply)."""
    pages, offset = [], "0"
    while offset is not None:
        reply = client.get(path, params={"limit": limit, "offset": offset})
        assert reply.status_code == 200, reply.text[:1000]
        pages.append((reply.json(), len(reply.content)))
        offset = reply.headers.get(NEXT_OFFSET_HEADER)
    return pages


def test_a_list_page_stops_before_its_byte_budget_and_names_the_next(client, monkeypatch):
    ids = [_post(client, _demo(name=f"{k}" * MAX_NAME_CHARS)).json()["id"] for k in range(6)]
    whole = client.get("/demonstrations")
    assert NEXT_OFFSET_HEADER not in whole.headers and [d["id"] for d in whole.json()] == ids[::-1]
    budget = 2 * max(len(json.dumps(d, separators=(",", ":")).encode()) for d in whole.json()) + 3  # two items a page
    monkeypatch.setattr(responses, "LIST_PAGE_BYTES", budget)
    pages = _pages(client, "/demonstrations")
    assert [len(items) for items, _ in pages] == [2, 2, 2] and all(size <= budget for _, size in pages)
    assert [d["id"] for items, _ in pages for d in items] == ids[::-1]  # each once, newest first
    limited = client.get("/demonstrations", params={"limit": 1, "offset": 4})
    assert len(limited.json()) == 1 and limited.headers[NEXT_OFFSET_HEADER] == "5"
    monkeypatch.setattr(responses, "LIST_PAGE_BYTES", 10)  # smaller than one item: one a page, never none
    assert [len(items) for items, _ in _pages(client, "/demonstrations")] == [1] * 6
    for path in ("/skills", "/executions", "/sweeps"):
        empty = client.get(path)
        assert empty.json() == [] and NEXT_OFFSET_HEADER not in empty.headers


def test_rows_stored_before_the_bounds_list_cut_and_read(tmp_path):
    """A demonstration stored with a 2 MB name by an earlier version lists with its name cut, in a small reply."""
    from conftest import api_settings, loopback_client

    from schemas.demonstration import Demonstration, DemonstrationSummary
    from services.app import create_app
    from services.store import Store

    store = Store(tmp_path / "api.db")
    demonstration = Demonstration.model_validate(_demo())
    long_name = "n" * 2_000_000
    demonstration.metadata.name = demonstration.metadata.source = long_name  # assignments are not validated
    summary = DemonstrationSummary.of(demonstration)
    with store.database.transaction() as db:
        db.execute(
            "INSERT INTO demonstrations (id, created, name, summary, body) VALUES (?, ?, ?, ?, ?)",
            ("demo_old", 1.0, long_name, summary.model_dump_json(), demonstration.model_dump_json()),
        )
    with loopback_client(create_app(api_settings(tmp_path), bus=None, store=store)) as client:
        listed = client.get("/demonstrations")
        assert listed.status_code == 200 and len(listed.content) < 10_000
        (row,) = listed.json()
        assert row["name"] == "n" * (MAX_NAME_CHARS - 1) + "…" == row["summary"]["name"]
        assert len(row["source"]) == 2000 and row["problem"] is None
        read = client.get("/demonstrations/demo_old")
        assert read.status_code == 200 and len(read.content) < 20_000
        assert read.json()["demonstration"]["metadata"]["name"] == row["name"]
        assert len(read.json()["demonstration"]["t"]) == 60
    store.close()


# --------------------------------------------------------------------------- a demonstration's samples paged


def test_a_demonstration_is_paged_within_its_byte_budget(client, monkeypatch):
    body = _demo(2000, name="long")
    demo_id = _post(client, body).json()["id"]
    whole = client.get(f"/demonstrations/{demo_id}")
    assert whole.status_code == 200 and whole.json()["next_cursor"] is None
    assert whole.json()["demonstration"]["t"] == body["t"] and NEXT_CURSOR_HEADER not in whole.headers
    budget = 64 * 1024
    monkeypatch.setattr(responses, "SAMPLES_PAGE_BYTES", budget)
    refused = client.get(f"/demonstrations/{demo_id}")
    assert _only_loc(refused) == ["query", "limit"] and "cursor=0" in refused.text
    columns: dict[str, list] = {name: [] for name in ("t", "positions", "orientations", "wrenches")}
    cursor, pages = 0, 0
    while cursor is not None:
        page = client.get(f"/demonstrations/{demo_id}", params={"cursor": cursor})
        assert page.status_code == 200 and len(page.content) <= budget
        assert page.json()["cursor"] == cursor and page.json()["demonstration"]["metadata"]["name"] == "long"
        for name, values in columns.items():
            values += page.json()["demonstration"][name]
        cursor = page.json()["next_cursor"]
        assert page.headers.get(NEXT_CURSOR_HEADER) == (None if cursor is None else str(cursor))
        pages += 1
    assert pages > 1 and all(columns[name] == body[name] for name in columns)
    ten = client.get(f"/demonstrations/{demo_id}", params={"cursor": 1990, "limit": 50}).json()
    assert ten["demonstration"]["t"] == body["t"][1990:] and ten["next_cursor"] is None
    past = client.get(f"/demonstrations/{demo_id}", params={"cursor": 10**6}).json()
    assert past["demonstration"]["t"] == [] and past["next_cursor"] is None
    assert client.delete(f"/demonstrations/{demo_id}").status_code == 204
    assert client.get(f"/demonstrations/{demo_id}", params={"cursor": 0}).status_code == 404  # nothing kept


def test_the_client_follows_the_pages(tmp_path, monkeypatch):
    """`Client.demonstrations` and `Client.demonstration` see everything through small pages."""
    from conftest import LiveApi, api_settings

    from schemas.demonstration import Demonstration
    from services.app import create_app
    from services.client import Client

    monkeypatch.setattr(responses, "LIST_PAGE_BYTES", 800)
    monkeypatch.setattr(responses, "SAMPLES_PAGE_BYTES", 32 * 1024)
    body = _demo(1000, name="paged", extra={"k": [1, 2]})
    with LiveApi(create_app(api_settings(tmp_path), bus=None)) as api, Client(api.url) as client:
        ids = [client._request("POST", "/demonstrations", json=body).json()["id"] for _ in range(5)]
        assert [d.id for d in client.demonstrations()] == ids[::-1]
        assert [d.id for d in client.demonstrations(limit=3, offset=1)] == ids[::-1][1:4]
        assert client.demonstration(ids[0]) == Demonstration.model_validate(body)
