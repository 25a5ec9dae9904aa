"""The dashboard (services/dashboard, served at ``/``) in a real browser: headless Chromium (the system's, driven by
Playwright) against the REAL stack (`contact-skills up`: embedded Zenoh router, the API, two PyBullet sim workers on
127.0.0.1). Every outcome is checked against what the API stores: the lists show the stored rows, a recording made
from the page is learned from the page, the live plot of an execution ends at the stored telemetry's last sample
(its CF-z and true normal force, its contact) with no gap in the stream, a point plotted while the tool presses
shows the stored true force of that very sample, abort stops it, two executions are followed at once through a
restart of the API. Screenshots go to each test's tmp directory."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import httpx
import numpy as np
import pytest

pytest.importorskip("zenoh")
pytest.importorskip("playwright")

from test_service import running_stack
from waiting import wait_for

from corpus.synthetic import plane_slide
from schemas import Demonstration
from services.csv_import import demonstration_csv_text
from services.dashboard.browser import chromium_path, headless_chromium
from services.local_processes import free_port

if chromium_path() is None:
    _missing = "chromium is not installed (make test installs it as root with apt-get: apt-get install chromium)"
    if os.environ.get("CONTACT_SKILLS_REQUIRE_BROWSER"):  # CI (.ci/run): a dashboard untested is a failure
        pytest.fail(f"{_missing}; CONTACT_SKILLS_REQUIRE_BROWSER is set", pytrace=False)
    pytest.skip(_missing, allow_module_level=True)

MAX_INDEX_STEP = 10
"""Largest step between consecutive plotted stream indices: the API sends 100 of the 1000 samples per second (every
10th) plus the last of each event; a larger step is a gap in the stream."""


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    env = {"CONTACT_SKILLS_FOXGLOVE_PORT": str(free_port())}
    yield from running_stack(tmp_path_factory.mktemp("dashboard"), workers=2, env=env)


@pytest.fixture(scope="module")
def browser():
    with headless_chromium() as context:
        yield context


@pytest.fixture
def page(browser, stack):
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(stack.url + "/")
    yield page
    page.close()
    assert errors == [], f"the page raised: {errors}"


def _stored_sample(stack, execution_id: str, index: int) -> dict:
    """Stored telemetry sample ``index`` of an execution: t s, CF-z force N, true normal force N, desired CF-z force
    N, in contact."""
    body = stack.http.get(f"/executions/{execution_id}/telemetry", params={"cursor": index, "limit": 1}).json()
    return {"index": index, "t": body["t"][0], "fz": body["wrench_cf"][0][2], "ft": body["normal_force_true_n"][0],
            "fd": body["desired_force_cf_z_n"][0], "contact": body["in_contact"][0]}  # fmt: skip


def _stored_end(stack, execution_id: str) -> dict:
    """The last stored telemetry sample of an execution (:func:`_stored_sample`) and the execution's outcome."""
    view = stack.execution(execution_id)
    sample = _stored_sample(stack, execution_id, view["telemetry_samples"] - 1)
    return {**sample, "status": view["status"], "verdict": view["verdict"]}


def _plot_end(page, execution_id: str) -> dict:
    """The live plot's last point (read in one go, so its fields belong to one sample)."""
    data = page.eval_on_selector(f"canvas.live-force[data-execution='{execution_id}']", "c => ({...c.dataset})")
    return {"index": int(data["lastIndex"]), "t": float(data["lastT"]), "fz": float(data["lastFz"]),
            "ft": float(data["lastFt"]), "contact": data["lastContact"] == "true", "max_gap": int(data["maxGap"]),
            "points": int(data["points"]), "err_true": data["lastErrTrue"], "err_cfz": data["lastErrCfz"]}  # fmt: skip


def _assert_the_checks_read_whole(page, checks: list[dict]) -> None:
    """Every check's row says which side of its limit it must stay on (as the value and the verdict agree) and
    shows its whole message: nothing of the table lies beyond its section's right edge."""
    from schemas.skill import SkillCheck
    from skills.skill_checks import check_bound

    rows = page.locator("#checks tbody tr")
    for k, check in enumerate(checks):
        cells = rows.nth(k).locator("td")
        bound = {">=": "≥", "<=": "≤"}[check_bound(SkillCheck.model_validate(check)).value]
        assert cells.nth(4).inner_text().startswith(bound), (check["name"], cells.nth(4).inner_text())
        assert cells.nth(5).inner_text() == check["message"]
    overflow = page.eval_on_selector("#checks", "s => s.scrollWidth - s.clientWidth")
    assert overflow <= 1, f"the checks table is {overflow} px wider than its section"


def _scene_is_drawn(page, selector: str) -> bool:
    """Whether the 3-D scene's canvas holds a picture (WebGL drew more than the background)."""
    colours = page.eval_on_selector(
        f"{selector} canvas",
        """c => {
        const small = document.createElement('canvas'); small.width = 64; small.height = 48;
        const ctx = small.getContext('2d'); ctx.drawImage(c, 0, 0, 64, 48);
        const d = ctx.getImageData(0, 0, 64, 48).data, seen = new Set();
        for (let i = 0; i < d.length; i += 4) seen.add(`${d[i] >> 4},${d[i + 1] >> 4},${d[i + 2] >> 4}`);
        return seen.size; }""",
    )
    return colours > 20


def _more_than(stack, n: int) -> list[dict] | None:
    """The stored demonstrations once there are more than ``n``."""
    listed = stack.http.get("/demonstrations").json()
    return listed if len(listed) > n else None


def _learned_skill(stack) -> str:
    skills = stack.http.get("/skills").json()
    if skills:
        return skills[0]["id"]
    demo = stack.post("/demonstrations/record", {"scenario": "slide_flat", "seed": 0}, 201)
    return stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "auto"}, 201)["id"]


def test_lists_render_a_recording_from_the_page_is_learned_and_an_upload_is_listed(stack, page, tmp_path):
    page.wait_for_selector("#executions table")
    assert page.locator("#demonstrations tbody tr").count() == len(stack.http.get("/demonstrations").json())
    page.click("#record")
    page.wait_for_selector("#demonstrations tbody tr", timeout=90_000)
    demo = stack.http.get("/demonstrations").json()[0]
    assert demo["source"] == "teacher:slide_flat"
    row = page.locator(f"#demonstrations tr[data-id='{demo['id']}']")
    assert demo["name"] in row.inner_text()
    row.locator("button.learn").click()
    page.wait_for_selector("#timeline[data-segments]", timeout=90_000)
    skill = stack.http.get("/skills").json()[0]
    assert page.url.endswith(f"#/skill/{skill['id']}") and skill["demonstration_id"] == demo["id"]
    stored = stack.http.get(f"/skills/{skill['id']}").json()["skill"]
    assert int(page.get_attribute("#timeline", "data-segments")) == len(stored["segments"])
    assert page.locator("#checks tbody tr").count() == len(stored["checks"])
    assert stored["auto_selection"]["chosen"] in page.inner_text("#auto-selection")
    _assert_the_checks_read_whole(page, stored["checks"])
    scene = page.wait_for_selector("#skill-scene[data-robot='1']", timeout=30_000)  # the arm at the path's start
    view = stack.http.get(f"/dashboard/api/skills/{skill['id']}").json()
    assert int(scene.get_attribute("data-taught")) == len(view["path"]) and view["joints"] is not None
    assert int(scene.get_attribute("data-triads")) == len(view["triads"]) > 0
    assert _scene_is_drawn(page, "#skill-scene")
    page.screenshot(path=tmp_path / "skill.png", full_page=True)

    truth = plane_slide(seed=3)  # recordings uploaded from the page are stored whole and listed
    demonstration = Demonstration.from_arrays(truth.t, truth.positions, truth.orientations, truth.wrenches)
    (tmp_path / "stroke.csv").write_text(demonstration_csv_text(demonstration))
    (tmp_path / "stroke.json").write_text(demonstration.model_dump_json())
    page.goto(stack.url + "/")
    for name, source in (("stroke.csv", "csv:stroke.csv"), ("stroke.json", "json")):
        before = len(stack.http.get("/demonstrations").json())
        page.set_input_files("#upload-file", tmp_path / name)
        page.click("#upload")
        listed = wait_for(lambda n=before: _more_than(stack, n), 30, f"the uploaded {name}")
        assert listed[0]["source"] == source and listed[0]["summary"]["n_samples"] == len(truth.t)
        page.wait_for_selector(f"#demonstrations tr[data-id='{listed[0]['id']}']", timeout=10_000)
    page.screenshot(path=tmp_path / "lists.png", full_page=True)


def test_an_execution_started_from_the_page_plots_up_to_the_stored_telemetry(stack, page, tmp_path):
    skill_id = _learned_skill(stack)
    page.goto(f"{stack.url}/#/skill/{skill_id}")
    page.fill("input[name='unknown z m']", "0.01")  # the table 1 cm lower than taught, unknown to the controller
    page.click("#execute")
    page.wait_for_selector("section.live[data-ended='1']", timeout=120_000)
    execution_id = page.get_attribute("section.live", "data-execution")
    stored, plotted = _stored_end(stack, execution_id), _plot_end(page, execution_id)
    assert stack.execution(execution_id)["request"]["environment"]["unknown_offset"] == [0.0, 0.0, 0.01]
    assert plotted["index"] == stored["index"] and plotted["t"] == pytest.approx(stored["t"], abs=1e-9)
    assert plotted["fz"] == pytest.approx(stored["fz"], abs=1e-5)  # sent rounded to 1e-6 N
    assert plotted["ft"] == stored["ft"] and plotted["contact"] == stored["contact"]  # sent as stored
    assert plotted["max_gap"] <= MAX_INDEX_STEP and plotted["points"] >= stored["index"] // 10
    assert stored["verdict"] in page.inner_text("section.live .final")
    final = page.inner_text("section.live .final")
    metrics = stack.execution(execution_id)["metrics"]
    assert f"{metrics['path_rms_m'] * 1000:.2f} mm" in final and f"{100 * metrics['contact_ratio']:.1f} %" in final
    assert page.eval_on_selector_all("section.live h2 button", "bs => bs.map(b => b.disabled)") == [True] * 3
    # The scene: the robot, and the work piece the run met: the taught table moved 1 cm up (the unknown offset).
    page.wait_for_selector("section.live .live-scene[data-work-piece][data-robot='1']", timeout=30_000)
    taught = stack.http.get(f"/skills/{skill_id}").json()["skill"]["taught_world"]["table"]
    [table] = stack.http.get(f"/dashboard/api/executions/{execution_id}/scene").json()["work_piece"]
    corners = np.array(table["vertices"])
    assert corners[:, 2].max() == pytest.approx(taught["height_m"] + 0.01, abs=1e-6)
    assert corners[:, :2].mean(axis=0) == pytest.approx(taught["center_xy"], abs=1e-6)
    assert _scene_is_drawn(page, "section.live .live-scene")
    page.screenshot(path=tmp_path / "execution.png", full_page=True)


def test_abort_from_the_page_stops_the_execution(stack, page, tmp_path):
    skill_id = _learned_skill(stack)
    page.goto(f"{stack.url}/#/skill/{skill_id}")
    page.select_option("select[name=pace]", "realtime")
    page.click("#execute")
    pressing_now = "canvas.live-force[data-last-contact='true']:not([data-last-err-true=''])"  # in the contact phase
    page.wait_for_selector(pressing_now, timeout=60_000)
    execution_id = page.get_attribute("section.live", "data-execution")
    pressing = _plot_end(page, execution_id)
    stored = _stored_sample(stack, execution_id, pressing["index"])
    assert stored["contact"] is True and stored["ft"] > 1.0  # pressing, not grazing
    # The force error plotted is the stored sample's: true normal force and CF-z force less the desired force.
    assert float(pressing["err_true"]) == pytest.approx(stored["ft"] - stored["fd"], abs=1e-9)
    assert float(pressing["err_cfz"]) == pytest.approx(stored["fz"] - stored["fd"], abs=1e-5)
    assert pressing["ft"] == stored["ft"] and pressing["t"] == stored["t"]
    assert "in contact" in page.inner_text("section.live .live-head")
    # The scene while it runs: the arm and the work piece its worker reported at the start.
    page.wait_for_selector("section.live .live-scene[data-work-piece='1'][data-robot='1']", timeout=10_000)
    buttons = "bs => bs.map(b => [b.className, b.disabled])"
    assert page.eval_on_selector_all("section.live h2 button", buttons) == [["pause", False], ["resume", True],
                                                                           ["abort", False]]  # fmt: skip
    page.click("section.live button.abort")
    page.wait_for_selector("section.live[data-ended='1']", timeout=60_000)
    stored = _stored_end(stack, execution_id)
    assert stored["status"] == "aborted" and stored["t"] < 10.0  # the run takes 12.7 s
    assert page.get_attribute("section.live", "data-status") == "aborted"
    assert _plot_end(page, execution_id)["index"] == stored["index"]
    assert page.eval_on_selector_all("section.live h2 button", "bs => bs.every(b => b.disabled)")
    page.screenshot(path=tmp_path / "aborted.png", full_page=True)


def test_two_executions_at_once_are_followed_through_a_restart_of_the_api(stack, page, tmp_path):
    skill_id = _learned_skill(stack)
    body = {"skill_id": skill_id, "pace": "realtime"}
    ids = [stack.post("/executions", body, 202)["id"] for _ in range(2)]
    page.goto(f"{stack.url}/#/execution/{','.join(ids)}")
    for execution_id in ids:
        page.wait_for_selector(f"canvas.live-force[data-execution='{execution_id}'][data-last-index]", timeout=60_000)
    os.kill(stack.api_pid(), signal.SIGKILL)  # `up` starts a new API; the workers go on running
    wait_for(lambda: page.locator("section.live[data-connected='0']").count() == 2 or None, 20, "the lost streams")

    def api_up() -> bool | None:
        try:
            return stack.http.get("/health", timeout=2).status_code == 200 or None
        except httpx.HTTPError:
            return None

    wait_for(api_up, 60, "the restarted API")
    for execution_id in ids:
        page.wait_for_selector(f"section.live[data-execution='{execution_id}'][data-ended='1']", timeout=120_000)
        stored, plotted = _stored_end(stack, execution_id), _plot_end(page, execution_id)
        assert stored["status"] == "done"
        assert plotted["index"] == stored["index"] and plotted["max_gap"] <= MAX_INDEX_STEP
    page.screenshot(path=tmp_path / "two_after_restart.png", full_page=True)


def test_bad_input_gets_a_message_naming_the_field(stack, page):
    skill_id = _learned_skill(stack)
    page.goto(f"{stack.url}/#/skill/{skill_id}")
    page.fill("input[name='known x m']", "5")  # beyond the 1 m a work piece may move
    page.click("#execute")
    page.wait_for_function("document.getElementById('message').textContent.includes('422')")
    assert "environment.offset" in page.inner_text("#message")
    assert Path(page.url).name != "execution"


def test_a_sweeps_page_shows_its_success_rate_and_figure(stack, page, tmp_path):
    skill_id = _learned_skill(stack)
    body = {"skill_id": skill_id, "controllers": ["hybrid_cf"], "vary": {"offset_z_m": {"low": -0.005, "high": 0.005}},
            "trials": 2}  # fmt: skip
    sweep_id = stack.post("/sweeps", body, 202)["id"]

    def done() -> dict | None:
        view = stack.http.get(f"/sweeps/{sweep_id}").json()
        return view if view["status"] == "done" else None

    view = wait_for(done, 120, "the sweep")
    page.wait_for_selector(f"#sweeps tr[data-id='{sweep_id}']")
    page.goto(f"{stack.url}/#/sweep/{sweep_id}")
    page.wait_for_function("document.getElementById('sweep-figure')?.naturalWidth > 0", timeout=60_000)
    [summary] = view["controllers"]
    row = page.locator("main table tbody tr").first.inner_text()
    assert "hybrid_cf" in row and f"{100 * summary['success_rate']:.1f} %" in row and f"{summary['finished']}/2" in row
    trials = stack.http.get(f"/sweeps/{sweep_id}/trials").json()
    rows = page.locator("#sweep-trials tbody tr")
    assert rows.count() == len(trials) == 2
    for trial in trials:  # every trial a row: its perturbation in mm, its verdict and error, a link to its execution
        row = page.locator(f"#sweep-trials tr[data-id='{trial['trial']}-{trial['controller']}']")
        text = row.inner_text()
        assert f"offset z {1000 * trial['parameters']['offset_z_m']:+.2f} mm" in text
        assert ("pass" if trial["success"] else "fail") in text and f"{trial['true_force_rms_error_pct']:.2f} %" in text
        assert row.locator("a").get_attribute("href") == f"#/execution/{trial['execution_id']}"
    page.screenshot(path=tmp_path / "sweep.png", full_page=True)


KULEUVEN = Path(__file__).resolve().parents[1] / "data" / "kuleuven_contour" / "contour_a_1.csv"


def test_the_kuleuven_recording_uploads_from_the_page_with_the_reading_its_import_offers(stack, page):
    from schemas.import_options import UPLOAD_FIELD, CsvImportOptions

    page.wait_for_selector("#executions table")
    page.set_input_files("#upload-file", KULEUVEN)
    page.wait_for_selector("#import-options select[name=wrench]")
    fields = page.eval_on_selector_all("#import-options [name]", "fs => fs.map(f => f.name)")
    options = CsvImportOptions.model_json_schema(by_alias=True)["properties"]
    assert fields == [name for name in options if name != UPLOAD_FIELD]  # the form is the options model's
    page.click("#upload")  # with the defaults: its wrench is read upside down, and the note says so
    first = page.wait_for_selector(".upload-note", timeout=60_000).get_attribute("data-demonstration")
    assert "read with --wrench measured-on-tool it presses" in page.inner_text(".upload-note")
    page.uncheck("#import-options input[name=tare]")  # all contact, compensated by its authors (GETTING_STARTED.md)
    page.click(".use-reading:has-text('wrench = measured-on-tool')")
    page.wait_for_selector(".upload-note b:has-text('re-imported')", timeout=60_000)
    second = page.get_attribute(".upload-note", "data-demonstration")
    assert stack.http.get(f"/demonstrations/{first}").status_code == 404  # the first reading is gone
    metadata = stack.http.get(f"/demonstrations/{second}").json()["demonstration"]["metadata"]
    assert metadata["wrench_convention_on_import"] == "measured-on-tool" and metadata["force_offset_removed"] is None
    skill = stack.post("/skills", {"demonstration_id": second, "skill_type": "auto"}, 201)["skill"]
    assert skill["skill_type"] == "contour"
    assert [c["name"] for c in skill["checks"] if not c["passed"]] == []  # pressing down, with friction


def test_two_demonstrations_learned_together_from_the_page_show_their_band_and_weights(stack, page, tmp_path):
    # Last in the module: the joint skill it learns becomes the newest, which `_learned_skill` would give the others.
    demos = [stack.post("/demonstrations/record", {"scenario": "slide_flat", "seed": seed}, 201) for seed in (0, 1)]
    page.wait_for_selector(f"#demonstrations tr[data-id='{demos[1]['id']}']")
    page.click("#learn-together")  # nothing ticked: the API refuses, the page says why
    page.wait_for_function("document.getElementById('message').textContent.includes('422')")
    assert "demonstration_ids" in page.inner_text("#message")
    for demo in demos:
        page.check(f"#demonstrations tr[data-id='{demo['id']}'] input.choose")
    page.click("#learn-together")
    bands = page.wait_for_selector("#skill-force[data-bands]", timeout=90_000).get_attribute("data-bands")
    skill_id = page.url.split("/")[-1]
    stored = stack.http.get(f"/skills/{skill_id}").json()
    skill = stored["skill"]
    assert [use["source"] for use in skill["demonstrations"]] == [demo["id"] for demo in demos]
    assert stored["demonstration_id"] in {demo["id"] for demo in demos}  # the reference, whose time line is drawn
    banded = [segment for segment in skill["segments"] if segment["force_band"] is not None]
    assert banded and [b["segment"] for b in json.loads(bands)] == [segment["index"] for segment in banded]
    for drawn, segment in zip(json.loads(bands), banded, strict=True):  # drawn where the segment lies, as stored
        assert drawn["lower_n"] == segment["force_band"]["lower_n"]
        assert drawn["upper_n"] == segment["force_band"]["upper_n"]
        assert (drawn["t0"], drawn["t1"]) == pytest.approx((segment["t_start"], segment["t_end"]), abs=1e-9)
    assert "force band of the 2 demonstrations" in page.inner_text("#skill-force + .legend")
    rows = page.locator("#learned-from tbody tr")
    assert rows.count() == 2
    for use in skill["demonstrations"]:
        cells = page.locator(f"#learned-from tr[data-id='{use['source']}'] td")
        assert cells.nth(0).locator("a").get_attribute("href") == f"/demonstrations/{use['source']}"
        assert cells.nth(2).inner_text() == f"{use['weight']:.3f}"
        assert cells.nth(3).inner_text() == ("yes" if use["reference"] else "no")
        assert cells.nth(4).inner_text() == (
            "included" if use["misfit"] is None else f"left out ({use['misfit']}): {use['reason']}"
        )
    page.screenshot(path=tmp_path / "joint_skill.png", full_page=True)
