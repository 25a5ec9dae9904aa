"""Learning against ground truth: analytic demonstrations with known planes, normals, forces and phases."""

from functools import cache

import numpy as np
import pytest
from pydantic import ValidationError

from corpus import synthetic
from schemas import Demonstration, LearnOptions, Skill, SkillType, SkillTypeRequest
from schemas.skill import SELECTION_CONTACT, SELECTION_FREE, SegmentKind
from skills.dmp import DMP
from skills.parameterize import LearningError, learn_skill
from skills.quaternions import matrix_from_quaternion

TILT_15 = (np.sin(np.radians(15.0)), 0.0, -np.cos(np.radians(15.0)))


def demonstration_of(demo: synthetic.SyntheticDemo, orientations: np.ndarray | None = None) -> Demonstration:
    held = demo.orientations if orientations is None else orientations
    return Demonstration.from_arrays(demo.t, demo.positions, held, demo.wrenches)


@cache
def learned(kind: str, seed: int, skill_type: SkillTypeRequest = SkillTypeRequest.auto) -> tuple:
    demo = {
        "flat": lambda: synthetic.plane_slide(seed=seed),
        "tilted": lambda: synthetic.plane_slide(normal=TILT_15, seed=seed),
        "two_planes": lambda: synthetic.two_plane_slide(seed=seed),
        "cylinder": lambda: synthetic.cylinder_contour(seed=seed),
    }[kind]()
    return demo, learn_skill(demonstration_of(demo), LearnOptions(skill_type=skill_type))


def contact_segments(skill: Skill) -> list:
    return [s for s in skill.segments if s.kind is SegmentKind.contact]


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize("kind", ["flat", "tilted"])
@pytest.mark.parametrize("seed", [0, 1])
def test_slide_normal_force_and_boundaries_match_truth(kind: str, seed: int) -> None:
    demo, skill = learned(kind, seed, SkillTypeRequest.slide)
    assert skill.skill_type is SkillType.slide
    [contact] = contact_segments(skill)
    z = matrix_from_quaternion(contact.compliant_frames.orientations[0])[:, 2]
    assert angle_deg(z, demo.normals[0]) < 1.0
    assert contact.force_constant_n == pytest.approx(demo.target_force_n, rel=0.02)
    assert abs(contact.t_start - demo.contact_on_s) < 0.05
    assert abs(contact.t_end - demo.contact_off_s) < 0.05
    assert contact.selection == SELECTION_CONTACT
    assert [s.kind for s in skill.segments] == [SegmentKind.free, SegmentKind.contact, SegmentKind.free]
    assert skill.segments[0].selection == SELECTION_FREE
    assert contact.quality.plane_residual_rms_m < 1e-3


def test_slide_cf_x_follows_the_motion_and_positions_live_in_the_plane() -> None:
    demo, skill = learned("tilted", 0, SkillTypeRequest.slide)
    [contact] = contact_segments(skill)
    R = matrix_from_quaternion(contact.compliant_frames.orientations[0])
    travel = demo.positions[contact.end_index - 1] - demo.positions[contact.start_index]
    assert np.dot(R[:, 0], travel) / np.linalg.norm(travel) > 0.9
    assert contact.position_dmp.frame == "cf" and len(contact.position_dmp.start) == 2
    assert contact.quality.position_rms_m < 3e-4


def test_two_planes_give_two_contact_segments_with_their_own_frames() -> None:
    demo, skill = learned("two_planes", 0)
    assert skill.skill_type is SkillType.slide
    first, second = contact_segments(skill)
    for segment, normal in ((first, demo.normals[0]), (second, demo.normals[1])):
        z = matrix_from_quaternion(segment.compliant_frames.orientations[0])[:, 2]
        assert angle_deg(z, normal) < 1.0
    assert abs(first.t_end - demo.phase_change_s[0]) < 0.1
    assert second.start_index == first.end_index


def test_contour_frames_follow_the_surface_normal_and_are_continuous() -> None:
    """CF z is the applied force without its friction part: the cylinder's inward normal, not the tilted force."""
    demo, skill = learned("cylinder", 0, SkillTypeRequest.contour)
    [contact] = contact_segments(skill)
    frames = contact.compliant_frames
    R = matrix_from_quaternion(frames.orientations)
    rows = contact.start_index + np.round(np.asarray(frames.t) * skill.sample_rate_hz).astype(int)
    # The direction of a near-zero force is noise: judge where the true force exceeds 10 % of its peak.
    pressing = demo.normal_force_true[rows] > 0.1 * demo.target_force_n
    assert pressing.mean() > 0.9
    outward = demo.positions[rows] - np.array([0.5, 0.0, 0.1])  # the cylinder's axis runs along world y
    outward[:, 1] = 0.0
    errors = angle_deg(R[:, :, 2], -outward)[pressing]
    assert errors.max() < 3.0, f"CF z off the true surface normal by up to {errors.max():.2f} deg"
    friction_tilt = angle_deg(demo.force_direction[rows], -outward)[pressing]
    assert np.median(friction_tilt) > 10.0  # the applied force itself is far off the normal (mu = 0.3)
    # Continuity: neighbouring stored frames never jump (the data turns < 1 deg between them).
    relative = np.einsum("kji,kjl->kil", R[1:], R[:-1])
    steps = np.degrees(np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert steps.max() < 5.0
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9)


def test_contour_force_profile_reproduces_the_demonstrated_force() -> None:
    demo, skill = learned("cylinder", 0, SkillTypeRequest.contour)
    [contact] = contact_segments(skill)
    assert contact.force_dmp is not None and contact.force_constant_n is None
    assert contact.quality.force_rms_n < 0.05 * demo.target_force_n


@pytest.mark.parametrize(
    ("kind", "expected"), [("flat", "slide"), ("tilted", "slide"), ("two_planes", "slide"), ("cylinder", "contour")]
)
def test_auto_selection_picks_the_right_skill(kind: str, expected: str) -> None:
    _, skill = learned(kind, 0)
    assert skill.skill_type.value == expected
    assert skill.auto_selection is not None and skill.auto_selection.confidence > 0.9


def test_a_short_gentle_arc_with_a_tool_that_does_not_turn_is_mixed_and_learned_as_contour() -> None:
    """16 cm of a 30 cm radius, the tool held still: the normal turns 24° (near even odds), the path leaves its
    plane by 2.4 mm (like a hand-wiped plane) and the tool does not follow. The evidence is mixed, so `auto`
    says so, picks the more likely type (contour, by a little), and the skill's type check warns.
    """
    demo = synthetic.cylinder_contour(radius_m=0.3, arc_deg=30.0, seed=2)
    held_still = np.tile(demo.orientations[0], (demo.t.size, 1))
    skill = learn_skill(demonstration_of(demo, orientations=held_still))
    auto = skill.auto_selection
    assert auto is not None and auto.mixed and auto.confidence < 0.75
    assert skill.skill_type is SkillType.contour and auto.reason.startswith("mixed evidence")
    assert auto.evidence.turning > 0 > auto.evidence.planarity and auto.evidence.tool_following < 1e-9
    [type_check] = [c for c in skill.checks if c.name.value == "type_evidence"]
    assert not type_check.passed and "mixed evidence" in type_check.message


def test_an_arc_the_tool_follows_is_a_contour_whatever_its_planarity() -> None:
    """The same 24° arc with the hand turning the tool along (as people do on curved parts): contour, confidently,
    although its path lies within 2.4 mm of a plane."""
    skill = learn_skill(demonstration_of(synthetic.cylinder_contour(radius_m=0.3, arc_deg=30.0, seed=2)))
    assert skill.skill_type is SkillType.contour
    assert skill.auto_selection.confidence >= 0.8 and skill.auto_selection.tool_following > 0.5


def test_skill_json_round_trip_is_lossless() -> None:
    _, skill = learned("cylinder", 0, SkillTypeRequest.contour)
    assert Skill.model_validate_json(skill.model_dump_json()) == skill


def test_learning_is_deterministic() -> None:
    demo = synthetic.two_plane_slide(seed=3)
    first = learn_skill(demonstration_of(demo))
    second = learn_skill(demonstration_of(demo))
    assert first.model_dump_json() == second.model_dump_json()


def test_irregular_time_stamps_are_resampled_before_learning() -> None:
    demo = synthetic.plane_slide(seed=4)
    rng = np.random.default_rng(0)
    keep = np.sort(rng.choice(demo.t.size, size=demo.t.size // 2, replace=False))
    jittered = Demonstration.from_arrays(
        demo.t[keep], demo.positions[keep], demo.orientations[keep], demo.wrenches[keep]
    )
    skill = learn_skill(jittered, LearnOptions(skill_type=SkillTypeRequest.slide))
    [contact] = contact_segments(skill)
    z = matrix_from_quaternion(contact.compliant_frames.orientations[0])[:, 2]
    assert angle_deg(z, demo.normals[0]) < 1.0
    assert contact.force_constant_n == pytest.approx(demo.target_force_n, rel=0.02)


def test_a_demonstration_without_contact_is_refused_naming_the_wrenches() -> None:
    demo = synthetic.plane_slide(seed=0)
    free = Demonstration.from_arrays(demo.t, demo.positions, demo.orientations, np.zeros_like(demo.wrenches))
    with pytest.raises(LearningError) as raised:
        learn_skill(free)
    assert raised.value.field == "wrenches"
    assert "contact" in raised.value.reason


def test_learned_profiles_do_not_depend_on_the_rollout_step() -> None:
    """The executor rolls out at its control step, not the demonstration's: the profile must not care."""
    _, skill = learned("cylinder", 0, SkillTypeRequest.contour)
    [contact] = contact_segments(skill)
    force = DMP.from_parameters(contact.force_dmp)
    fine, coarse = force.rollout(0.001).y[:, 0], force.rollout(0.005).y[:, 0]
    assert abs(coarse.max() - fine.max()) < 0.03 * fine.max()
    assert abs(coarse.mean() - fine.mean()) < 0.03 * fine.mean()


@pytest.mark.parametrize(
    ("scale", "gap_s", "reason"),
    [(5e-3, 0.0, "must be seconds"), (1.0, 100.0, "gap of 100 s")],
)
def test_implausible_time_stamps_are_refused_naming_t(scale: float, gap_s: float, reason: str) -> None:
    """Time stamps 5 µs apart (200 kHz: not seconds) and a 100 s gap: the learner refuses them naming t. Time
    stamps closer than the contract's minimum step (1 µs) do not even make a demonstration."""
    demo = synthetic.plane_slide(seed=0)
    t = demo.t * scale
    t[t.size // 2 :] += gap_s
    with pytest.raises(LearningError) as raised:
        learn_skill(Demonstration.from_arrays(t, demo.positions, demo.orientations, demo.wrenches))
    assert raised.value.field == "t"
    assert reason in raised.value.reason
    with pytest.raises(ValidationError, match="step by at least 1e-06 s"):
        Demonstration.from_arrays(demo.t * 1e-6, demo.positions, demo.orientations, demo.wrenches)
