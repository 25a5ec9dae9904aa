"""Every read bounded (issue 41, item 2): free-form fields bounded at input (a 422 naming the field), time windows
that are finite and in order.

The API in-process on a real SQLite database (``client`` of conftest.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from schemas.text import MAX_FREE_FORM_BYTES, MAX_FREE_FORM_DEPTH, MAX_ID_CHARS, MAX_NAME_CHARS


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
    assert response.status_code == 422, response.text
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
    return ("t,px,py,pz,qx,qy,qz,qw,fx,fy,fz\n" + "\n".join(f"{k * 0.01},0,0,0,0,0,0,1,0,0,1" for k in range(rows))).encode()


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
