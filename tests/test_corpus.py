"""The ground-truth corpus checks its own truth (corpus.families, corpus.case), not the learner: normals, forces,
segment windows and the shapes the families promise; the human-like files read back to the true wrench; and the
scoring (corpus.scoring) gives a skill built from the truth zero errors and a wrong one the errors it has.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.ndimage import binary_erosion

from corpus import families
from corpus.case import CorpusCase
from corpus.scoring import score
from schemas import Skill
from schemas.import_options import CsvImportOptions
from schemas.skill import CompliantFrames, Segment, SegmentKind, SkillType
from services.csv_import import demonstration_from_csv
from skills.compliant_frames import frame_from_z_and_x
from skills.dmp import DMP
from skills.frames import matrix_from_axis_angle, rotation_from_vectors
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix

EXPECTED_SEGMENTS = {
    "straight": 1,
    "straight-soft": 1,
    "l-shape": 1,
    "zigzag": 1,
    "circle": 1,
    "spiral": 3,
    "multi-pass-circle": 3,
    "back-and-forth": 1,
    "cylinder": 1,
    "sphere": 1,
    "planar-edge": 1,
    "planar-edge-twisted": 1,
    "rim": 4,
    "human-straight": 1,
    "human-zigzag": 1,
    "human-cylinder": 1,
    "brush": 1,
    "merged-strokes": 2,
    "reversal-strokes": 2,
}
TIGHT_ROUNDING_RAD_M = 30.0
"""Where the normal turns faster than this along the path (a rounding under 3.3 cm), the hand's 0.4 mm tremor
moves the contact point across it by more than a degree of normal: the tangent test leaves those samples out."""


@cache
def corpus() -> tuple[CorpusCase, ...]:
    return tuple(families.corpus_cases((0,)))


def by_family(family: str) -> list[CorpusCase]:
    return [case for case in corpus() if case.family == family]


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def read_csv(text: str, options: dict[str, object], **more: object):
    return demonstration_from_csv(text, CsvImportOptions(**options, **more))


def check_truth(case: CorpusCase) -> None:
    """The truth of one case is consistent with itself."""
    assert np.all(np.diff(case.t) > 0)
    np.testing.assert_allclose(np.linalg.norm(case.normals, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(case.orientations, axis=1), 1.0, atol=1e-9)
    # The applied force is the normal force along the normal plus friction across it.
    np.testing.assert_allclose(np.sum(case.wrenches[:, :3] * case.normals, axis=1), case.normal_force_n, atol=1e-9)
    assert np.all(case.normal_force_n[~case.in_contact] == 0.0) and np.all(case.normal_force_n >= 0.0)
    # The tool z points roughly into the surface (within the hand's tilt and turn) while stroking.
    stroking = np.any([(case.t >= s.span[0]) & (case.t <= s.span[1]) for s in case.segments], axis=0)
    tool_z = matrix_from_quaternion(case.orientations[stroking])[:, :, 2]
    assert np.all(angle_deg(tool_z, case.normals[stroking]) < 25.0)
    # Moving in contact, the path on the surface (the pad's sink-in removed) runs across the normal.
    on_surface = case.positions - (case.normal_force_n / case.parameters["pad_stiffness_n_m"])[:, None] * case.normals
    velocity = np.gradient(on_surface, case.t, axis=0)
    step = np.linalg.norm(np.gradient(on_surface, axis=0), axis=1)
    turning = np.linalg.norm(np.gradient(case.normals, axis=0), axis=1) / np.maximum(step, 1e-12)
    moving = binary_erosion(case.in_contact, iterations=2) & (np.linalg.norm(velocity, axis=1) > 0.01)
    moving &= turning < TIGHT_ROUNDING_RAD_M
    assert moving.sum() > 100
    assert np.max(np.abs(angle_deg(velocity[moving], case.normals[moving]) - 90.0)) < 1.0
    # Segments in time order; every window inside the contact; sharp touch-down and lift-off.
    assert case.segments
    for segment in case.segments:
        (a, b), (c, d) = segment.start_window, segment.end_window
        assert a <= b <= c <= d
        inside = (case.t >= a) & (case.t <= d)
        assert np.all(case.in_contact[inside]), f"{case.name}: window outside the contact"
        assert segment.force_n > 0.0
        assert (segment.normal is None) == (case.skill_type == "contour")
    for before, after in zip(case.segments[:-1], case.segments[1:], strict=True):
        assert before.end_window[1] <= after.start_window[0] or before.end_window == after.start_window
    first = case.segments[0].start_window
    assert first[0] == first[1]
    touch, pressing = np.searchsorted(case.t, [first[0], first[0] + 0.25])
    assert case.normal_force_n[touch] < 0.05 * case.segments[0].force_n < case.normal_force_n[pressing]


@pytest.mark.parametrize("case", corpus(), ids=lambda case: case.name)
def test_the_truth_of_every_case_is_consistent(case: CorpusCase) -> None:
    check_truth(case)
    assert len(case.segments) == EXPECTED_SEGMENTS[case.family]
    contours = ("cylinder", "sphere", "planar-edge", "planar-edge-twisted", "rim", "human-cylinder")
    assert case.skill_type == ("contour" if case.family in contours else "slide")


def test_the_corpus_holds_every_family_at_its_values() -> None:
    names = [case.name for case in corpus()]
    assert len(names) == len(set(names)) == 39
    assert {case.family for case in corpus()} == set(EXPECTED_SEGMENTS)
    assert sorted(c.parameters["tilt_deg"] for c in by_family("straight")) == [0.0, 25.0, 50.0]
    assert sorted(c.parameters["radius_m"] for c in by_family("cylinder")) == [0.05, 0.08, 0.15, 0.30]
    for case in by_family("cylinder") + by_family("sphere"):
        inside = case.in_contact
        turn = angle_deg(case.normals[np.argmax(inside)], case.normals[len(inside) - 1 - np.argmax(inside[::-1])])
        assert turn == pytest.approx(case.parameters["turn_deg"], abs=1.0)
        assert (60.0 if case.family == "cylinder" else 50.0) <= turn <= (100.0 if case.family == "cylinder" else 90.0)


def test_the_tool_touches_down_and_lifts_off_moving() -> None:
    for case in corpus():
        speed = np.linalg.norm(np.gradient(case.positions, case.t, axis=0), axis=1)
        for segment in (case.segments[0], case.segments[-1]):
            for t in (segment.start_window[0], segment.end_window[1]):
                near = np.abs(case.t - t) < 0.05
                if case.family not in ("back-and-forth", "reversal-strokes"):  # these touch down slower, ~3 cm/s
                    assert np.median(speed[near]) > 0.02, case.name


def test_the_straight_stroke_sinks_in_under_a_millimetre_and_the_soft_one_by_millimetres() -> None:
    for case in by_family("straight") + by_family("straight-soft"):
        normal = case.segments[0].normal
        touch = np.searchsorted(case.t, case.segments[0].start_window[0])
        depth = (case.positions[case.in_contact] - case.positions[touch]) @ normal
        if case.family == "straight":
            assert 0.2e-3 < depth.max() < 0.5e-3, case.name
        else:
            assert depth.max() > 3e-3, case.name
        assert case.segments[0].force_n == pytest.approx(10.0, rel=0.1)


def test_the_planar_edge_and_the_rim_stay_in_a_horizontal_plane_while_the_normal_turns() -> None:
    for case, within_m in ((by_family("planar-edge")[0], 1e-3), (by_family("rim")[0], 8e-3)):
        path = case.positions[case.in_contact]
        centred = path - path.mean(axis=0)
        plane_normal = np.linalg.svd(centred, full_matrices=False)[2][2]
        assert np.max(np.abs(centred @ plane_normal)) < within_m
        assert min(angle_deg(plane_normal, np.array([0.0, 0.0, 1.0])), angle_deg(-plane_normal, [0, 0, 1.0])) < 1.0
        normals = case.normals[case.in_contact]
        below_horizontal = np.degrees(np.arcsin(-normals[:, 2]))
        heading = np.degrees(np.unwrap(np.arctan2(normals[:, 1], normals[:, 0])))
        if case.family == "planar-edge":
            assert 35.0 <= np.ptp(heading) <= 45.0
            # The lean puts the pressed normal 5-12 deg off the crease's bisector, between the faces' normals.
            assert 5.0 - 1.5 <= abs(np.mean(below_horizontal) - 45.0) <= 12.0 + 1.5
            assert below_horizontal.min() > 0.0 and below_horizontal.max() < 90.0
        else:
            assert abs(heading[-1] - heading[0]) == pytest.approx(3.6 * 360.0, abs=2.0)
            assert below_horizontal.min() > 35.0 and below_horizontal.max() < 55.0


def test_the_twisted_planar_edge_lies_in_a_plane_while_its_normal_turns_about_the_path() -> None:
    """Pressed 70° down onto a crease whose profile twists 30° along it: within 2 mm of a plane, ~27° of turning."""
    [case] = by_family("planar-edge-twisted")
    path = case.positions[case.in_contact]
    centred = path - path.mean(axis=0)
    assert np.max(np.abs(centred @ np.linalg.svd(centred, full_matrices=False)[2][2])) < 2e-3
    normals = case.normals[case.in_contact]
    assert 20.0 < angle_deg(normals[0], normals[-1]) < 40.0


def test_boundaries_follow_the_rules() -> None:
    # Winding cuts lie a full turn apart and in the plateau; a back-and-forth wipe at a steady press is one stroke.
    for case in by_family("multi-pass-circle") + by_family("spiral") + by_family("rim"):
        cuts = [s.end_window for s in case.segments[:-1]]
        assert all(hi - lo == pytest.approx(0.2) for lo, hi in cuts)
    for case in by_family("back-and-forth"):
        turns = np.flatnonzero(np.diff(np.sign(np.gradient(case.positions @ (case.positions[-1] - case.positions[0])))))
        assert len(case.segments) == 1 and turns.size >= 2  # it does go back and forth
    # Dips: the window is where the force is under 30 % of the plateaus; no lift-off in it.
    for case in by_family("merged-strokes") + by_family("reversal-strokes"):
        first, second = case.segments
        lo, hi = first.end_window
        assert first.end_window == second.start_window
        dip = (case.t > lo + 0.01) & (case.t < hi - 0.01)
        threshold = 0.3 * min(first.force_n, second.force_n)
        assert np.all(case.normal_force_n[dip] < threshold) and np.all(case.normal_force_n[dip] > 0.0)
        assert 0.3 < hi - lo < 1.1
    merged = by_family("merged-strokes")[0]
    assert angle_deg(merged.segments[0].normal, merged.segments[1].normal) == pytest.approx(60.0, abs=0.5)
    assert np.min(merged.normal_force_n[(merged.t > merged.segments[0].end_window[0])][:50]) < 2.0


def test_the_brush_touches_the_side_lightly_before_the_stroke_and_is_no_segment() -> None:
    case = by_family("brush")[0]
    starts = np.flatnonzero(np.diff(case.in_contact.astype(int)) == 1) + 1
    assert len(starts) == 2  # the brush, then the stroke
    brush = slice(starts[0], starts[1])
    assert case.t[starts[0]] < case.segments[0].start_window[0]
    assert np.max(case.normal_force_n[brush]) < 0.5 * case.parameters["force_n"]  # light: under half the stroke
    assert np.all(np.abs(case.normals[brush][case.in_contact[brush], 2]) < 1e-9)  # the vertical side
    assert 15.0 <= case.parameters["force_n"] <= 30.0


@pytest.mark.parametrize("case", [c for c in corpus() if c.recording is not None], ids=lambda case: case.name)
def test_the_recording_file_reads_back_to_the_true_wrench_once_the_offset_is_removed(case: CorpusCase) -> None:
    recording = case.recording
    lines = recording.csv_text.splitlines()
    assert lines[0] == "t,x,y,z,qw,qx,qy,qz,fx,fy,fz,mx,my,mz"
    stamps = np.array([float(line.split(",")[0]) for line in lines[1:]])
    irregular = case.parameters["irregular"] == 1.0
    assert (np.ptp(np.diff(stamps)) > 0.2 / case.parameters["rate_hz"]) == irregular
    assert (np.any(np.diff(stamps) == 0.0)) == irregular
    demo = read_csv(recording.csv_text, recording.import_options, force_offset=tuple(recording.sensor_offset)).arrays()
    assert demo.t[0] == pytest.approx(0.0) and demo.t[-1] == pytest.approx(case.t[-1], abs=0.02)

    def truth_at(values: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(demo.t, case.t, column) for column in values.T], axis=1)

    # The file also carries the hand's push on the arm: the sensor reads tool and hand together.
    residual = demo.wrenches[:, :3] - truth_at(case.wrenches[:, :3] + recording.hand_forces)
    assert np.sqrt(np.mean(residual**2)) < 0.3  # the sensor's noise is 0.2 N
    assert np.max(np.abs(np.mean(residual, axis=0))) < 0.05
    assert np.max(np.abs(demo.positions - truth_at(case.positions))) < 3e-4
    assert np.max(angle_deg(matrix_from_quaternion(demo.orientations)[:, :, 2],
                            truth_at(matrix_from_quaternion(case.orientations)[:, :, 2]))) < 1.0  # fmt: skip


def test_human_like_cases_carry_a_hand_and_an_offset_like_real_recordings() -> None:
    for case in corpus():
        if case.recording is None:
            assert case.sensed_wrenches is not None
            continue
        hand = np.linalg.norm(case.recording.hand_forces[~case.in_contact], axis=1)
        assert 2.0 < hand.max() < 17.0, case.name
        assert 0.7 <= np.linalg.norm(case.recording.sensor_offset[:3]) <= 2.3
        assert 0.1 <= case.parameters["friction"] <= 0.5 and 2e3 <= case.parameters["pad_stiffness_n_m"] <= 3e4
    assert {c.parameters["rate_hz"] for c in corpus() if c.recording is not None} == {100.0, 250.0, 1000.0}


# --------------------------------------------------------------------------- scoring


def perfect_skill(case: CorpusCase) -> Skill:
    """A skill built from the truth: one contact segment per truth segment over its span, CF z along the true
    normal, the true plateau force (slide) or a force DMP fitted to the true normal force (contour)."""
    segments = []
    for k, truth in enumerate(case.segments):
        t0, t1 = truth.span
        rows = np.flatnonzero((case.t >= t0) & (case.t <= t1))
        if truth.normal is not None:
            rotations = frame_from_z_and_x(truth.normal, np.array([1.0, 0.0, 0.0]))[None]
            times, extra = [0.0], {"force_constant_n": truth.force_n}
        else:
            rotations = rotation_from_vectors(np.array([0.0, 0.0, 1.0]), case.normals[rows])
            times = (case.t[rows] - t0).tolist()
            force = DMP.fit(case.t[rows], case.normal_force_n[rows], n_basis=60, kind="force")
            extra = {"force_dmp": force.to_parameters()}
        frames = CompliantFrames(
            t=times,
            origins=case.positions[rows[: len(times)]].tolist(),
            orientations=quaternion_from_matrix(rotations).tolist(),
        )
        segments.append(
            Segment.model_construct(
                index=k, kind=SegmentKind.contact, t_start=t0, t_end=t1, compliant_frames=frames, **extra
            )
        )
    return Skill.model_construct(
        skill_type=SkillType(case.skill_type), segments=segments, sample_rate_hz=1.0 / (case.t[1] - case.t[0])
    )


@pytest.mark.parametrize("name", ["spiral-tilt25-s0", "rim-s0", "cylinder-r8cm-s0", "merged-strokes-s0"])
def test_a_skill_built_from_the_truth_scores_zero_errors(name: str) -> None:
    case = next(c for c in corpus() if c.name == name)
    result = score(perfect_skill(case), case)
    assert result.type_right and result.strokes_right
    assert result.boundary_error_s == 0.0
    assert result.normal_error_deg < 1e-3
    assert result.force_error < 1e-2


def test_scoring_measures_what_it_says_on_a_hand_made_skill() -> None:
    case = next(c for c in corpus() if c.name == "spiral-tilt25-s0")
    skill = perfect_skill(case)
    first, second, third = skill.segments
    normal = case.segments[0].normal
    turned = matrix_from_axis_angle(np.cross(normal, [1.0, 0.0, 0.0]), np.radians(10.0)) @ frame_from_z_and_x(
        normal, np.array([1.0, 0.0, 0.0])
    )
    late = 0.5 + case.segments[0].start_window[1]
    wrong = first.model_copy(
        update={
            "t_start": late,
            "force_constant_n": 1.2 * case.segments[0].force_n,
            "compliant_frames": first.compliant_frames.model_copy(
                update={"orientations": quaternion_from_matrix(turned[None]).tolist()}
            ),
        }
    )
    result = score(skill.model_copy(update={"segments": [wrong, second, third]}), case)
    assert result.boundary_error_s == pytest.approx(0.5)
    assert result.normal_error_deg == pytest.approx(10.0, abs=1e-6)
    assert result.force_error == pytest.approx(0.2)
    # One segment over the whole contact: the two inner boundaries are missed.
    whole = first.model_copy(update={"t_end": third.t_end})
    result = score(skill.model_copy(update={"segments": [whole], "skill_type": SkillType.contour}), case)
    assert not result.type_right and not result.strokes_right and result.learned_strokes == 1
    inner = [s.end_window for s in case.segments[:-1]]
    expected = max(min(lo - whole.t_start, whole.t_end - hi) for lo, hi in inner)
    assert result.boundary_error_s == pytest.approx(expected)


# --------------------------------------------------------------------------- random cases


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_random_cases_keep_their_truth_consistent(seed: int) -> None:
    case = families.random_case(seed)
    check_truth(case)
    bounds = families.RANDOM_BOUNDS
    assert bounds["friction"][0] <= case.parameters["friction"] <= bounds["friction"][1]
    assert bounds["pad_stiffness_n_m"][0] <= case.parameters["pad_stiffness_n_m"] <= bounds["pad_stiffness_n_m"][1]
    assert bounds["force_n"][0] <= case.parameters["force_n"] <= bounds["force_n"][1]
    assert len(case.segments) == EXPECTED_SEGMENTS[case.family]
