"""The dashboard without a browser: its page and assets come from the API itself (offline, no outside host), unknown
names and paths out of its folder are 404s, its views answer 404 for unknown ids; the compliant frame recovered from
the two recorded wrenches is the rotation that made them; the live stream's decimation keeps the last sample, and a
column not recorded (the true force and the contact of telemetry stored before they were streamed) is sent as null,
never as 0."""

from __future__ import annotations

import json
import re

import numpy as np
from conftest import loopback_client
from scipy.spatial.transform import Rotation

from services.api.routes.live import MAX_OFFSET, PLOT_HZ, _telemetry
from services.app import create_app
from services.dashboard.scene import cf_rotations
from services.settings import ServiceSettings
from services.store import TELEMETRY_LAYOUT


def _client(tmp_path):
    return loopback_client(create_app(ServiceSettings(db_path=tmp_path / "d.db"), bus=None))


def test_the_page_loads_every_asset_from_the_api_itself(tmp_path):
    with _client(tmp_path) as client:
        seen, queue = set(), ["/"]
        while queue:
            url = queue.pop()
            response = client.get(url)
            assert response.status_code == 200, url
            text = response.text
            assert not re.findall(r"(?:https?:)?//[\w.-]+\.\w+", text), f"{url} names an outside host"
            seen.add(url)
            queue += [u for u in re.findall(r"""(?:src|href|from)\s*=?\s*["'](/dashboard/[^"']+)["']""", text)
                      if u not in seen]  # fmt: skip
        assert {"/dashboard/static/app.js", "/dashboard/static/plot.js", "/dashboard/static/style.css"} <= seen
        assert client.get("/dashboard/static/app.js").headers["content-type"].startswith("text/javascript")
        for bad in ("nothing.js", "..%2Fviews.py", ".hidden.js", "scene.py"):
            assert client.get(f"/dashboard/static/{bad}").status_code == 404, bad
        for url in ("/dashboard/api/skills/skill_0", "/dashboard/api/sweeps/sweep_0/figure.png", "/executions/x/live"):
            response = client.get(url)
            assert response.status_code == 404 and "no " in response.json()["detail"], url
        assert client.get("/executions/x/live", params={"cursor": MAX_OFFSET + 1}).status_code == 422


def test_the_recovered_compliant_frame_is_the_rotation_that_made_the_cf_wrenches():
    rng = np.random.default_rng(4)
    R = Rotation.random(200, random_state=rng).as_matrix()
    wrench_cf = rng.normal(0.0, 5.0, (200, 6))
    wrench_world = np.concatenate([np.einsum("nij,nj->ni", R, wrench_cf[:, :3]),
                                   np.einsum("nij,nj->ni", R, wrench_cf[:, 3:])], axis=1)  # fmt: skip
    wrench_world[50:60] = wrench_cf[50:60] = 0.0  # no wrench (free space, the ideal sensor): the frame is kept
    recovered = cf_rotations(wrench_world, wrench_cf)
    keep = np.ones(200, dtype=bool)
    keep[50:60] = False
    np.testing.assert_allclose(recovered[keep], R[keep], atol=1e-9)
    np.testing.assert_allclose(recovered[50:60], np.broadcast_to(R[49], (10, 3, 3)), atol=1e-9)
    assert np.allclose(np.linalg.det(recovered), 1.0)


def test_a_live_event_decimates_to_the_plot_rate_and_ends_with_the_last_sample():
    n = 537  # 0.537 s at 1 kHz, starting at stream index 1000
    rows = np.zeros((n, max(b for _, b in TELEMETRY_LAYOUT.values())))
    rows[:, 0] = 1.0 + np.arange(n) * 1e-3
    a, _ = TELEMETRY_LAYOUT["wrench_cf"]
    rows[:, a + 2] = np.linspace(0.0, 15.0, n)
    event = _telemetry(rows, 1000)
    assert event["index"][-1] == 1000 + n - 1 and event["t"][-1] == rows[-1, 0]
    assert event["wrench_cf"][-1][2] == 15.0
    steps = np.diff(event["index"])
    every = round(1000 / PLOT_HZ)  # samples per plotted point at 1 kHz
    assert steps.max() == every and len(event["t"]) == -(-n // every) + 1  # one per interval, and the last
    assert event["in_contact"] == [False] * len(event["t"]) and event["normal_force_true_n"][-1] == 0.0


def test_a_live_event_sends_the_true_force_and_the_contact_as_stored_and_null_where_not_recorded():
    rows = np.zeros((30, max(b for _, b in TELEMETRY_LAYOUT.values())))
    rows[:, 0] = np.arange(30) * 0.01  # 100 Hz: every row is plotted
    contact, true_force = TELEMETRY_LAYOUT["in_contact"][0], TELEMETRY_LAYOUT["normal_force_true_n"][0]
    rows[10:, contact] = 1.0
    rows[10:, true_force] = np.linspace(3.0, 15.0, 20)
    rows[25:, contact] = rows[25:, true_force] = np.nan  # as the store reads rows stored before the columns were
    rows[28, TELEMETRY_LAYOUT["wrench_cf"][0]] = np.nan
    event = json.loads(json.dumps(_telemetry(rows, 0), allow_nan=False))  # what the stream sends: valid JSON
    assert event["in_contact"] == [False] * 10 + [True] * 15 + [None] * 5
    assert event["normal_force_true_n"][:25] == rows[:25, true_force].tolist()
    assert event["normal_force_true_n"][25:] == [None] * 5 and event["wrench_cf"][28][0] is None


def test_with_reads_behind_the_token_the_page_opens_and_its_data_needs_the_token(tmp_path):
    settings = ServiceSettings(db_path=tmp_path / "d.db", token="s3cret", token_reads=True)
    with loopback_client(create_app(settings, bus=None)) as client:
        assert client.get("/").status_code == 200 and client.get("/dashboard/static/app.js").status_code == 200
        for url in ("/dashboard/api/skills/skill_0", "/executions/x/live", "/dashboard/api/sweeps/s/figure.png"):
            assert client.get(url).status_code == 401, url
            assert client.get(url, headers={"Authorization": "Bearer s3cret"}).status_code == 404, url
        page = client.get("/", headers={"Host": "attacker.example"})  # a DNS-rebinding page: refused
        assert page.status_code == 400
