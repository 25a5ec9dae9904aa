"""The dashboard without a browser: its page and assets come from the API itself (offline, no outside host), unknown
names and paths out of its folder are 404s, its views answer 404 for unknown ids; the compliant frame recovered from
the two recorded wrenches is the rotation that made them; the live stream's decimation keeps the last sample, and a
column not recorded (the true force and the contact of telemetry stored before they were streamed) is sent as null,
never as 0."""

from __future__ import annotations

import json
import re
from collections import Counter
from urllib.parse import urljoin

import numpy as np
from conftest import loopback_client
from scipy.spatial.transform import Rotation

from schemas.import_options import BagImportOptions, CsvImportOptions
from services.api.routes.live import MAX_OFFSET, PLOT_HZ, _telemetry
from services.app import create_app
from services.dashboard.scene import cf_rotations
from services.settings import ServiceSettings
from services.store import TELEMETRY_LAYOUT

VENDOR = "/dashboard/static/vendor/"


def _client(tmp_path):
    return loopback_client(create_app(ServiceSettings(db_path=tmp_path / "d.db"), bus=None))


def _imported(url: str, text: str, import_map: dict[str, str]) -> list[str]:
    """The page's own URLs a file names (src, href, an ES module's from) and the vendored modules it imports by a
    bare name or a relative path, resolved as the browser does (through the page's import map)."""
    urls = re.findall(r"""(?:src|href|from|import\()\s*=?\s*["'](/dashboard/[^"']+)["']""", text)
    for name in re.findall(r"""^(?:import|export)\b[^'";=]*?["']([^"']+)["']""", text, re.M):  # a module's imports
        if name.startswith("/"):
            continue  # found above
        if name.startswith("."):
            urls.append(urljoin(url, name))
        else:
            prefix = max((p for p in import_map if name == p or (p.endswith("/") and name.startswith(p))), key=len)
            urls.append(import_map[prefix] + name[len(prefix) :])
    return urls


def test_the_page_loads_every_asset_from_the_api_itself(tmp_path):
    with _client(tmp_path) as client:
        page = client.get("/").text
        import_map = json.loads(re.search(r'<script type="importmap">(.*?)</script>', page, re.S).group(1))["imports"]
        # An import map's prefix ("three/addons/") is no file: its files come through the imports that use it.
        seen, queue = set(), ["/", *(u for u in import_map.values() if not u.endswith("/"))]
        while queue:
            url = queue.pop()
            response = client.get(url)
            assert response.status_code == 200, url
            text = response.text
            if not url.startswith(VENDOR):  # a vendored library names hosts in comments and XML namespaces only
                assert not re.findall(r"(?:https?:)?//[\w.-]+\.\w+", text), f"{url} names an outside host"
            seen.add(url)
            queue += [u for u in _imported(url, text, import_map) if u not in seen]
        assert {"/dashboard/static/app.js", "/dashboard/static/plot.js", "/dashboard/static/scene3d.js",
                "/dashboard/static/style.css", f"{VENDOR}three.module.min.js", f"{VENDOR}jsm/controls/OrbitControls.js",
                f"{VENDOR}jsm/lines/LineSegmentsGeometry.js"} <= seen  # fmt: skip
        assert client.get("/dashboard/static/app.js").headers["content-type"].startswith("text/javascript")
        for bad in ("nothing.js", "..%2Fviews.py", ".hidden.js", "scene.py", "vendor/..%2F..%2Fscene.py",
                    "vendor/jsm/%2E%2E/%2E%2E/app.js", "vendor/jsm//lines/Line2.js", "vendor/LICENSE"):  # fmt: skip
            assert client.get(f"/dashboard/static/{bad}").status_code == 404, bad
        urdf = client.get("/dashboard/robot/model.urdf").text  # the robot Foxglove gets, its meshes served here
        meshes = set(re.findall(r'filename="package://kuka_iiwa/meshes/([^"]+)"', urdf))  # visual and collision
        assert len(meshes) == 8 and all(client.get(f"/dashboard/robot/meshes/{m}").status_code == 200 for m in meshes)
        for bad in ("link_0.obj", "..%2Fmodel.urdf", "nothing.stl"):
            assert client.get(f"/dashboard/robot/meshes/{bad}").status_code == 404, bad
        for url in ("/dashboard/api/skills/skill_0", "/dashboard/api/sweeps/sweep_0/figure.png", "/executions/x/live",
                    "/dashboard/api/executions/x/scene"):  # fmt: skip
            response = client.get(url)
            assert response.status_code == 404 and "no " in response.json()["detail"], url
        assert client.get("/executions/x/live", params={"cursor": MAX_OFFSET + 1}).status_code == 422


def test_the_upload_form_is_the_import_options_model(tmp_path):
    """The page's upload form is generated from these schemas: the models' own, by their form names."""
    with _client(tmp_path) as client:
        schemas = client.get("/dashboard/api/import-options").json()
    assert schemas == {"csv": CsvImportOptions.model_json_schema(by_alias=True),
                       "bag": BagImportOptions.model_json_schema(by_alias=True)}  # fmt: skip
    assert {"wrench", "wrench_frame", "tare", "quaternion_order", "rate"} <= set(schemas["csv"]["properties"])


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


def test_the_work_piece_meshes_are_the_simulated_solids_surfaces():
    """What the worker reports of its world: every vertex on its solid's surface (the simulator's signed distance
    is 0 there) and each mesh closed (every edge shared by two triangles), for each kind of solid."""
    from schemas.world import BlockConfig, CylinderConfig, RampConfig, TableConfig, WorldConfig
    from sim_worker.geometry import WorldGeometry
    from sim_worker.world_build import work_piece_meshes

    config = WorldConfig(table=TableConfig(tilt_deg=10.0), ramp=RampConfig(enabled=True),
                         cylinder=CylinderConfig(enabled=True, xy_m=(-0.15, 0.0)),
                         block=BlockConfig(enabled=True, xy_m=(0.15, 0.0), yaw_deg=30.0))  # fmt: skip
    geometry = WorldGeometry(config)
    meshes = {mesh.name: mesh for mesh in work_piece_meshes(geometry)}
    assert set(meshes) == set(geometry.solids) == {"table", "ramp", "cylinder", "block"}
    for name, mesh in meshes.items():
        distance, _ = geometry.solids[name].signed_distance(np.array(mesh.vertices))
        np.testing.assert_allclose(distance, 0.0, atol=1e-6, err_msg=name)
        edges = Counter(tuple(sorted(e)) for t in mesh.triangles for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])))
        assert set(edges.values()) == {2}, name
