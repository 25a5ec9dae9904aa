"""Learning from recordings like a real human's, against their ground truth (corpus.kinesthetic).

Each recording: 1-4 wiping strokes with 20-35 cm lifts between them, a hand pushing the arm with
up to ~17 N in free space, a sensor offset of 0.7-2.3 N in the sensor frame, the sensor's
reaction in its own frame at 100 Hz with no time column, friction 0.1-0.4, ramped and swinging
presses. Imported exactly as the README says, then learned with ``--type auto``.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from corpus import kinesthetic
from schemas import Demonstration, LearnOptions, Skill, SkillTypeRequest
from schemas.import_options import CsvImportOptions
from schemas.skill import SegmentKind
from services.csv_import import demonstration_from_csv
from skills.parameterize import learn_skill
from skills.quaternions import matrix_from_quaternion

FRICTIONS = (0.1, 0.25, 0.4)
CASES = [(surface, seed) for surface in kinesthetic.SURFACES for seed in range(4)]
IMPORT = {"rate_hz": 100.0, "quaternion_order": "wxyz", "wrench_convention": "measured-on-tool", "wrench_frame": "tool"}


@cache
def recording(surface: str, seed: int) -> tuple[kinesthetic.KinestheticDemo, Demonstration]:
    demo = kinesthetic.kinesthetic_wipe(surface, n_strokes=1 + seed % 4, friction=FRICTIONS[seed % 3], seed=seed)
    return demo, demonstration_from_csv(kinesthetic.recording_csv_text(demo), CsvImportOptions(**IMPORT))


@cache
def learned(surface: str, seed: int, skill_type: SkillTypeRequest = SkillTypeRequest.auto) -> Skill:
    return learn_skill(recording(surface, seed)[1], LearnOptions(skill_type=skill_type))


def contacts(skill: Skill) -> list:
    return [s for s in skill.segments if s.kind is SegmentKind.contact]


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize(("surface", "seed"), CASES)
def test_auto_picks_the_true_type_with_confidence(surface: str, seed: int) -> None:
    demo, _ = recording(surface, seed)
    skill = learned(surface, seed)
    assert skill.skill_type.value == demo.truth.skill_type, skill.auto_selection.reason
    assert skill.auto_selection.confidence >= 0.8, skill.auto_selection.reason


@pytest.mark.parametrize(("surface", "seed"), CASES)
def test_one_contact_segment_per_stroke_within_0_3_s_of_the_truth(surface: str, seed: int) -> None:
    demo, _ = recording(surface, seed)
    for skill_type in (SkillTypeRequest.auto, SkillTypeRequest.slide):
        segments = contacts(learned(surface, seed, skill_type))
        assert len(segments) == len(demo.truth.strokes), [(s.t_start, s.t_end) for s in segments]
        for segment, stroke in zip(segments, demo.truth.strokes, strict=True):
            assert abs(segment.t_start - stroke.t_on) < 0.3
            assert abs(segment.t_end - stroke.t_off) < 0.3
            assert segment.start_reason in ("force", "surface") and segment.end_reason in ("force", "surface")


@pytest.mark.parametrize(("surface", "seed"), CASES)
def test_no_contact_is_found_with_the_tool_in_the_air(surface: str, seed: int) -> None:
    """The hand pushes the arm with up to ~17 N in free space: none of it may count as contact."""
    demo, _ = recording(surface, seed)
    assert demo.truth.operator_force_max_n > 8.0
    for segment in contacts(learned(surface, seed)):
        touching = demo.truth.in_contact[segment.start_index : segment.end_index]
        assert touching.mean() > 0.95


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("surface", ["flat", "tilted"])
def test_slide_normal_within_3_deg_and_force_within_5_percent(surface: str, seed: int) -> None:
    demo, _ = recording(surface, seed)
    for segment, stroke in zip(contacts(learned(surface, seed)), demo.truth.strokes, strict=True):
        z = matrix_from_quaternion(segment.compliant_frames.orientations[0])[:, 2]
        assert angle_deg(z, stroke.normal) < 3.0
        assert segment.force_constant_n == pytest.approx(stroke.plateau_force_n, rel=0.05)
        p10, _, p90 = segment.quality.force_measured_percentiles_n
        assert p10 < segment.force_constant_n < p90  # the measured, ramped and swinging profile around it


@pytest.mark.parametrize("seed", range(4))
def test_contour_frames_follow_the_curved_surface_normal(seed: int) -> None:
    """CF z is the force without friction: the normal; the hand's lean and tremor-driven friction remain."""
    demo, _ = recording("curved", seed)
    skill = learned("curved", seed)
    errors = []
    for segment, stroke in zip(contacts(skill), demo.truth.strokes, strict=True):
        frames = segment.compliant_frames
        rows = segment.start_index + np.round(np.asarray(frames.t) * skill.sample_rate_hz).astype(int)
        pressing = demo.truth.normal_force_n[rows] > 0.3 * stroke.plateau_force_n
        z = matrix_from_quaternion(frames.orientations)[:, :, 2]
        errors.extend(angle_deg(z, demo.truth.normals[rows])[pressing])
    assert np.median(errors) < 3.0
    assert np.percentile(errors, 95) < 15.0
    assert skill.auto_selection.plane_rms_m > 0.006


def test_a_hand_wiped_plane_that_leaves_its_plane_by_mm_is_still_a_slide() -> None:
    """Real flat wipes leave a plane fit by 1.4-3.4 mm (pad, unevenness): that alone is no curve."""
    demo, imported = recording("flat", 2)
    a = imported.arrays()
    bump = 0.003 * np.sin(2 * np.pi * a.positions[:, 0] / 0.25) * np.cos(2 * np.pi * a.positions[:, 1] / 0.3)
    positions = a.positions + bump[:, None] * np.array([0.0, 0.0, 1.0])
    uneven = Demonstration.from_arrays(a.t, positions, a.orientations, a.wrenches)
    skill = learn_skill(uneven)
    assert skill.auto_selection.plane_rms_m > 0.0015
    assert skill.skill_type.value == "slide" and skill.auto_selection.confidence >= 0.8
    assert len(contacts(skill)) == len(demo.truth.strokes)


@pytest.mark.parametrize("seed", [0, 2])
def test_a_soft_pad_that_sinks_15_mm_keeps_touch_down_and_lift_off(seed: int) -> None:
    """A sponge (2 kN/m) sinks ~15 mm under the press: as it relaxes the tool rises ON the surface, not off it."""
    demo = kinesthetic.kinesthetic_wipe("flat", n_strokes=2, friction=0.3, seed=seed, pad_stiffness_n_m=2000.0)
    skill = learn_skill(demonstration_from_csv(kinesthetic.recording_csv_text(demo), CsvImportOptions(**IMPORT)))
    assert skill.skill_type.value == "slide" and skill.auto_selection.confidence >= 0.8
    segments = contacts(skill)
    assert len(segments) == len(demo.truth.strokes)
    for segment, stroke in zip(segments, demo.truth.strokes, strict=True):
        assert abs(segment.t_start - stroke.t_on) < 0.3 and abs(segment.t_end - stroke.t_off) < 0.3
        assert segment.force_constant_n == pytest.approx(stroke.plateau_force_n, rel=0.05)


# --------------------------------------------------------------------------- the PyBullet kinesthetic teacher


@cache
def simulated(scenario: str) -> tuple[kinesthetic.KinestheticDemo, Skill]:
    from sim_worker.kinesthetic_teacher import record_kinesthetic

    demo = record_kinesthetic(scenario, seed=1)  # 2 strokes, real PyBullet contact, friction and arm
    return demo, learn_skill(demonstration_from_csv(kinesthetic.recording_csv_text(demo), CsvImportOptions(**IMPORT)))


@pytest.mark.parametrize("scenario", ["wipe_flat", "wipe_tilted", "wipe_curved"])
def test_learning_holds_on_the_simulated_kinesthetic_teacher(scenario: str) -> None:
    demo, skill = simulated(scenario)
    truth = demo.truth
    assert skill.skill_type.value == truth.skill_type and skill.auto_selection.confidence >= 0.8
    segments = contacts(skill)
    assert len(segments) == len(truth.strokes)
    for segment, stroke in zip(segments, truth.strokes, strict=True):
        assert abs(segment.t_start - stroke.t_on) < 0.3 and abs(segment.t_end - stroke.t_off) < 0.3
        if stroke.normal is not None:
            z = matrix_from_quaternion(segment.compliant_frames.orientations[0])[:, 2]
            assert angle_deg(z, stroke.normal) < 3.0
            assert segment.force_constant_n == pytest.approx(stroke.plateau_force_n, rel=0.05)
