"""A skill's plan for a real cell (docs/REAL_CELL.md): the exported samples are the phase planner's references, the
force over contact is the skill's (and the taught one), the file is a valid ``SkillPlan``, and a plan over its bound
is refused with a 422 naming ``max_samples``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import LiveApi, api_settings

from cli.main import main
from corpus import synthetic
from execution.plan_export import CONTROL_PERIOD_S, nominal_phase_plans, skill_plan
from execution.plans import force_profile
from schemas import Demonstration, LearnOptions, Skill
from schemas.execution import ExecutionPhase, ExecutionSettings
from schemas.execution.environment import Placement
from schemas.skill import SELECTION_CONTACT, SELECTION_FREE
from schemas.skill_plan import PlanFormat, SkillPlan
from services.client import Client
from skills.parameterize import learn_skill

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def taught() -> dict[str, tuple[synthetic.SyntheticDemo, Skill]]:
    """A flat slide and a cylinder contour, each with its ground truth, learned once."""
    demos = {"slide": synthetic.plane_slide(seed=0), "contour": synthetic.cylinder_contour(seed=0)}
    arrays = {kind: (demo.t, demo.positions, demo.orientations, demo.wrenches) for kind, demo in demos.items()}
    return {
        kind: (demo, learn_skill(Demonstration.from_arrays(*arrays[kind]), LearnOptions()))
        for kind, demo in demos.items()
    }


@pytest.mark.parametrize("kind", ["slide", "contour"])
def test_the_plans_first_and_last_poses_are_the_planners_and_start_where_taught(taught, kind):
    demo, skill = taught[kind]
    plans = nominal_phase_plans(skill, ExecutionSettings())
    samples = skill_plan(skill).samples
    assert len(samples.t) == sum(plan.steps for plan in plans)
    np.testing.assert_array_equal(samples.position_m[0], plans[0].ref_p[0])
    np.testing.assert_array_equal(samples.orientation[0], plans[0].ref_q[0])
    np.testing.assert_array_equal(samples.position_m[-1], plans[-1].ref_p[-1])
    np.testing.assert_array_equal(samples.orientation[-1], plans[-1].ref_q[-1])
    assert samples.t[-1] == pytest.approx((len(samples.t) - 1) * CONTROL_PERIOD_S)
    # Ground truth: the skill's first free segment starts where the teacher did.
    assert np.linalg.norm(np.asarray(samples.position_m[0]) - demo.positions[0]) < 2e-3
    assert [p.value for p in dict.fromkeys(samples.phase)] == ["settle", "free", "approach", "contact", "retreat"]


@pytest.mark.parametrize("kind", ["slide", "contour"])
def test_the_force_over_contact_is_the_skills_along_cf_z_with_force_control_there(taught, kind):
    demo, skill = taught[kind]
    samples = skill_plan(skill).samples
    phase = np.array([p.value for p in samples.phase])
    contact = phase == ExecutionPhase.contact.value
    force = np.asarray(samples.force_n)[contact]
    segment = next(s for s in skill.segments if s.index == samples.segment[int(np.argmax(contact))])
    np.testing.assert_allclose(force, force_profile(segment, force.size, CONTROL_PERIOD_S), atol=1e-9)
    # Ground truth: the teacher's force (the slide's constant; the contour's profile peaks at it).
    peak = force.max() if kind == "contour" else np.median(force)
    assert peak == pytest.approx(demo.target_force_n, rel=0.1)
    selection = np.asarray(samples.selection)
    np.testing.assert_array_equal(selection[contact], np.broadcast_to(SELECTION_CONTACT, (force.size, 6)))
    np.testing.assert_array_equal(selection[phase == "free"][0], SELECTION_FREE)
    # The CF z the force acts along is the taught normal, into the surface.
    cf_z = np.array([_rotation_z(q) for q in np.asarray(samples.cf_orientation)[contact][::500]])
    if kind == "slide":
        assert np.degrees(np.arccos(np.clip(cf_z @ demo.normals[0], -1, 1))).max() < 2.0
    else:  # the cylinder's normal at the tool points to its axis (along world y through (0.5, 0, 0.1) m)
        p = np.asarray(samples.position_m)[contact][::500]
        inward = np.array([0.5, 0.0, 0.1]) - p
        inward[:, 1] = 0.0
        inward /= np.linalg.norm(inward, axis=1, keepdims=True)
        assert np.degrees(np.arccos(np.clip(np.sum(cf_z * inward, axis=1), -1, 1))).max() < 5.0


def _rotation_z(q: np.ndarray) -> np.ndarray:
    from skills.quaternions import matrix_from_quaternion

    return matrix_from_quaternion(q)[:, 2]


def test_the_cli_writes_a_file_the_schema_validates_placed_as_asked(taught, tmp_path):
    _, skill = taught["slide"]
    skill_path, out = tmp_path / "skill.json", tmp_path / "plan.json"
    skill_path.write_text(skill.model_dump_json())
    placement = '{"translation_m": [0.1, 0.2, 0.3]}'
    assert main(["plan", str(skill_path), "-o", str(out), "--every", "10", "--placement", placement]) == 0
    plan = SkillPlan.model_validate_json(out.read_text())  # every field, every length, time increasing
    assert plan.format == "contact-skills/skill-plan" and plan.version == 1 and plan.every == 10
    unplaced = skill_plan(skill, every=10).samples
    moved = np.asarray(plan.samples.position_m) - np.asarray(unplaced.position_m)
    # (the approach's switch to the touch-down speed may fall one step apart in floating point: 0.1 mm at most)
    np.testing.assert_allclose(moved, np.broadcast_to([0.1, 0.2, 0.3], moved.shape), atol=2e-4)
    assert plan.placement == Placement(translation_m=[0.1, 0.2, 0.3])
    assert main(["plan", str(skill_path), "-o", str(out), "--max-samples", "100"]) == 2


def test_the_published_json_schema_is_the_models():
    published = json.loads((REPO / "docs" / "skill_plan.schema.json").read_text())
    assert published == SkillPlan.model_json_schema()


def test_the_api_serves_the_plan_and_refuses_one_over_max_samples_naming_it(taught, tmp_path):
    """``GET /skills/{id}/plan`` on a live API, directly and through `contact-skills plan ID` (the typed client)."""
    import httpx

    from services.app import create_app

    _, skill = taught["slide"]
    app = create_app(api_settings(tmp_path), bus=None)
    with LiveApi(app) as api, httpx.Client(base_url=api.url) as http:
        skill_id = app.state.store.skills.add(skill.model_dump_json(), skill.skill_type, None, []).id
        plan = SkillPlan.model_validate_json(http.get(f"/skills/{skill_id}/plan", params={"every": 20}).content)
        assert plan.skill_id == skill_id
        assert plan.samples.position_m == skill_plan(skill, every=20).samples.position_m
        too_long = http.get(f"/skills/{skill_id}/plan", params={"max_samples": 100})
        assert too_long.status_code == 422
        problem = too_long.json()["detail"][0]
        assert problem["loc"] == ["query", "max_samples"] and "more than max_samples 100" in problem["msg"]
        assert http.get("/skills/skill_000000000000/plan").status_code == 404
        out = tmp_path / "plan.json"
        assert main(["plan", skill_id, "-o", str(out), "--every", "20", "--url", api.url]) == 0
        assert SkillPlan.model_validate_json(out.read_text()) == plan
        assert main(["plan", skill_id, "-o", str(out), "--max-samples", "100", "--url", api.url]) == 2


def _plan_from_mcap(data: bytes) -> SkillPlan:
    """A plan MCAP read back with the ``mcap`` reader and ``rosbags``' own CDR decoder (not the writer's layouts):
    the metadata's fields, every sample from the per-sample topics, phase, segment and selection held from each change
    to the next."""
    import io

    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_HUMBLE)
    reader = make_reader(io.BytesIO(data))
    [metadata] = [m.metadata for m in reader.iter_metadata() if m.name == "contact_skills"]
    topics: dict[str, list] = {}
    for schema, channel, message in reader.iter_messages():
        topics.setdefault(channel.topic, []).append(
            (message.log_time, typestore.deserialize_cdr(message.data, schema.name))
        )
    stamps = np.array([stamp for stamp, _ in topics["/reference/pose"]])

    def held(topic: str, value) -> list:
        changes = topics[topic]
        at = np.searchsorted([stamp for stamp, _ in changes], stamps, side="right") - 1
        return [value(changes[k][1]) for k in at]

    def pose(topic: str) -> tuple[list, list]:
        poses = [m.pose for _, m in topics[topic]]
        return [[p.position.x, p.position.y, p.position.z] for p in poses], [
            [p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in poses
        ]

    position, orientation = pose("/reference/pose")
    cf_origin, cf_orientation = pose("/cf/pose")
    twists = [m.twist for _, m in topics["/reference/twist"]]
    samples = {
        "t": (stamps * 1e-9).tolist(),
        "phase": held("/phase", lambda m: m.data),
        "segment": held("/segment", lambda m: m.data),
        "position_m": position,
        "orientation": orientation,
        "twist": [[w.linear.x, w.linear.y, w.linear.z, w.angular.x, w.angular.y, w.angular.z] for w in twists],
        "cf_orientation": cf_orientation,
        "cf_origin_m": cf_origin,
        "selection": held("/selection", lambda m: m.data.tolist()),
        "force_n": [m.wrench.force.z for _, m in topics["/force/desired"]],
    }
    assert all(m.header.frame_id == "cf" for _, m in topics["/force/desired"])
    assert not any(m.wrench.force.x or m.wrench.force.y or m.wrench.torque.z for _, m in topics["/force/desired"])
    return SkillPlan.model_validate({**json.loads(metadata["plan"]), "samples": samples})


def _assert_same_plan(decoded: SkillPlan, plan: SkillPlan) -> None:
    """Equal field by field; the time to the stamps' nanosecond, every other number to the bit."""
    np.testing.assert_allclose(decoded.samples.t, plan.samples.t, rtol=0, atol=1e-9)
    assert decoded.model_dump(exclude={"samples": {"t"}}) == plan.model_dump(exclude={"samples": {"t"}})


@pytest.mark.parametrize("kind", ["slide", "contour"])
def test_the_mcap_plan_decodes_to_the_json_plan(taught, tmp_path, kind):
    """`contact-skills plan --format mcap` of a local skill file holds the JSON plan: the same samples (poses, twist,
    CF, force, phase, segment, selection) and the same gains, placement and timing."""
    _, skill = taught[kind]
    skill_path, as_json, as_mcap = tmp_path / "skill.json", tmp_path / "plan.json", tmp_path / "plan.mcap"
    skill_path.write_text(skill.model_dump_json())
    placement = '{"translation_m": [0.0, 0.0, 0.02]}'
    assert main(["plan", str(skill_path), "-o", str(as_json), "--every", "10", "--placement", placement]) == 0
    argv = ["plan", str(skill_path), "-o", str(as_mcap), "--every", "10", "--placement", placement, "--format", "mcap"]
    assert main(argv) == 0
    plan = SkillPlan.model_validate_json(as_json.read_text())
    _assert_same_plan(_plan_from_mcap(as_mcap.read_bytes()), plan)
    assert len(set(plan.samples.phase)) == 5 and len({tuple(s) for s in plan.samples.selection}) == 2  # changes held


def test_the_api_serves_the_plan_as_mcap_and_refuses_an_unknown_format_naming_it(taught, tmp_path):
    """``GET /skills/{id}/plan?format=mcap`` decodes to the JSON plan the same query serves; `contact-skills plan ID
    --format mcap` writes the same file; ``format=yaml`` is a 422 on ``format``."""
    import httpx

    from services.app import create_app

    _, skill = taught["slide"]
    app = create_app(api_settings(tmp_path), bus=None)
    with LiveApi(app) as api, httpx.Client(base_url=api.url) as http:
        skill_id = app.state.store.skills.add(skill.model_dump_json(), skill.skill_type, None, []).id
        plan = SkillPlan.model_validate_json(http.get(f"/skills/{skill_id}/plan", params={"every": 20}).content)
        served = http.get(f"/skills/{skill_id}/plan", params={"every": 20, "format": "mcap"})
        assert served.status_code == 200 and served.headers["content-type"] == "application/octet-stream"
        _assert_same_plan(_plan_from_mcap(served.content), plan)
        out = tmp_path / "plan.mcap"
        assert main(["plan", skill_id, "-o", str(out), "--every", "20", "--format", "mcap", "--url", api.url]) == 0
        assert out.read_bytes() == served.content
        with Client(api.url) as client:  # the typed client asks the API for either format
            assert client.skill_plan(skill_id, every=20, format=PlanFormat.mcap) == served.content
            assert SkillPlan.model_validate_json(client.skill_plan(skill_id, every=20)) == plan
        unknown = http.get(f"/skills/{skill_id}/plan", params={"format": "yaml"})
        assert unknown.status_code == 422 and unknown.json()["detail"][0]["loc"] == ["query", "format"]
