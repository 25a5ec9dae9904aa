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
from schemas.skill_plan import SkillPlan
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
