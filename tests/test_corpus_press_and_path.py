"""The press-and-path families (corpus.press_and_path) carry the truth they promise: unsteady presses marked so and
scored by their profile, a quick drum wipe, a wipe covering a curved part, a helix off any plane, and a recording
file with a wrist sensor's spikes, saturation and drift. Nothing here learns: it checks the truth and the scoring.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from test_corpus import angle_deg, check_truth, perfect_skill, read_csv

from corpus import press_and_path as pp
from corpus.case import CorpusCase, winding_windows
from corpus.families import human_case
from corpus.scoring import score
from skills.dmp import DMP

SEEDS = (0, 1, 2)


@cache
def case_of(family: str, seed: int) -> CorpusCase:
    return next(c for c in pp.press_and_path_cases([seed]) if c.family == family)


def contact_rows(case: CorpusCase) -> np.ndarray:
    return np.flatnonzero(case.in_contact)


def between_ramps(case: CorpusCase) -> np.ndarray:
    """Rows of the stroke between its touch-down and lift-off ramps."""
    (start, _), (_, end) = case.segments[0].start_window, case.segments[-1].end_window
    ramp = case.parameters["ramp_s"]
    return np.flatnonzero((case.t >= start + ramp) & (case.t <= end - ramp))


def parsed(text: str) -> np.ndarray:
    return np.loadtxt(text.splitlines()[1:], delimiter=",", ndmin=2)


def test_every_family_once_per_seed_and_its_truth_consistent() -> None:
    cases = list(pp.press_and_path_cases(SEEDS))
    assert [c.family for c in cases] == list(pp.PRESS_AND_PATH_FAMILIES) * len(SEEDS)
    assert len({c.name for c in cases}) == len(cases)
    for case in cases:
        check_truth(case)
        assert case.t[-1] < 15.0, case.name
        assert case.skill_type == ("contour" if case.family in ("drum-quick", "curved-wipe", "helix") else "slide")
        assert all(s.steady == (case.family not in ("ramp-press", "wobble-press")) for s in case.segments)
    assert pp.ramp_press_case(1).parameters == case_of("ramp-press", 1).parameters  # seeded


@pytest.mark.parametrize("seed", SEEDS)
def test_the_ramp_press_rises_from_a_touch_to_a_hard_press_and_its_truth_is_unsteady(seed: int) -> None:
    case = case_of("ramp-press", seed)
    [segment] = case.segments
    assert not segment.steady
    rows = between_ramps(case)
    force = case.normal_force_n[rows]
    assert force[0] <= 3.0 and force[-1] >= 16.0
    # The drawn ends, up to the press's 2 % wander.
    assert force[0] == pytest.approx(case.parameters["force_start_n"], rel=0.021)
    assert force[-1] == pytest.approx(case.parameters["force_end_n"], rel=0.021)
    # Linear: a straight line leaves the force by under 3 % of its rise (the press wanders by 2 %).
    line = np.polyval(np.polyfit(case.t[rows], force, 1), case.t[rows])
    assert np.max(np.abs(force - line)) < 0.03 * np.ptp(force)
    # Its force_n: the mean over the samples pressing above 30 % of the largest.
    span = (case.t >= segment.span[0]) & (case.t <= segment.span[1])
    pressed = case.normal_force_n[span][case.normal_force_n[span] > 0.3 * case.normal_force_n[span].max()]
    assert segment.force_n == pytest.approx(pressed.mean())
    assert 0.0 <= case.parameters["tilt_deg"] <= 30.0
    stroke = case.positions[contact_rows(case)]
    assert np.linalg.norm(stroke[-1] - stroke[0]) == pytest.approx(0.15, abs=3e-3)


@pytest.mark.parametrize("seed", SEEDS)
def test_the_wobble_press_peaks_at_its_frequency_with_its_amplitude(seed: int) -> None:
    case = case_of("wobble-press", seed)
    assert not case.segments[0].steady
    rows = between_ramps(case)
    force = case.normal_force_n[rows]
    window = np.hanning(rows.size)
    spectrum = np.abs(np.fft.rfft((force - force.mean()) * window, 2**18))
    frequencies = np.fft.rfftfreq(2**18, case.t[1] - case.t[0])
    peak = np.argmax(spectrum)
    assert frequencies[peak] == pytest.approx(case.parameters["frequency_hz"], abs=0.05)
    assert 2.0 * spectrum[peak] / window.sum() == pytest.approx(case.parameters["amplitude_n"], rel=0.05)
    assert 2.5 <= case.parameters["frequency_hz"] <= 3.5 and 4.0 <= case.parameters["amplitude_n"] <= 6.0
    assert force.mean() == pytest.approx(case.parameters["force_n"], rel=0.1)
    assert 10.0 <= case.parameters["force_n"] <= 14.0


@pytest.mark.parametrize("seed", SEEDS)
def test_the_quick_drum_wipe_is_one_short_contact_turning_40_to_60_degrees(seed: int) -> None:
    case = case_of("drum-quick", seed)
    rows = contact_rows(case)
    assert np.all(np.diff(rows) == 1)  # one contact
    assert 1.0 <= rows.size * (case.t[1] - case.t[0]) <= 1.4
    turn = angle_deg(case.normals[rows[0]], case.normals[rows[-1]])
    assert 40.0 <= turn <= 60.0 and turn == pytest.approx(case.parameters["turn_deg"], abs=1.0)
    assert len(case.segments) == 1 and case.segments[0].normal is None
    assert 0.08 <= case.parameters["radius_m"] <= 0.15


def wipe_passes(case: CorpusCase) -> tuple[np.ndarray, list[np.ndarray]]:
    """The drum's axis (normals lie across it) and the normal's angle about it over each pass."""
    rows = contact_rows(case)
    normals = case.normals[rows]
    axis = np.linalg.svd(normals, full_matrices=False)[2][2]
    e1 = normals.mean(axis=0) - (normals.mean(axis=0) @ axis) * axis
    e1 /= np.linalg.norm(e1)
    angle = np.degrees(np.arctan2(normals @ np.cross(axis, e1), normals @ e1))
    step = np.diff(angle)
    moving = np.flatnonzero(step != 0.0)
    turns = moving[1:][np.diff(np.sign(step[moving])) != 0]
    return axis, np.split(angle, turns + 1)


@pytest.mark.parametrize("seed", SEEDS)
def test_the_curved_wipe_covers_the_part_in_passes_in_one_stroke(seed: int) -> None:
    case = case_of("curved-wipe", seed)
    rows = contact_rows(case)
    assert np.all(np.diff(rows) == 1)  # one contact: no lift-off between the passes
    axis, passes = wipe_passes(case)
    assert len(passes) == case.parameters["passes"] and 3 <= len(passes) <= 5
    for angles in passes:
        assert 30.0 <= np.ptp(angles) <= 50.0
        assert np.ptp(angles) == pytest.approx(case.parameters["turn_deg"], abs=0.1)
    # Along the axis: the passes lie a shift apart, and a pad one shift wide wipes passes x shift.
    extent = np.ptp(case.positions[rows] @ axis)
    shift = extent / (len(passes) - 1)
    assert shift == pytest.approx(case.parameters["shift_m"], abs=5e-4) and 0.0095 <= shift <= 0.0155
    assert len(passes) * shift >= 0.03
    assert 0.15 <= case.parameters["radius_m"] <= 0.30
    # One stroke: a back-and-forth wipe at a steady press, its heading winding no full turn.
    [segment] = case.segments
    assert segment.normal is None and segment.steady
    assert segment.start_window[0] == case.t[rows[0]] and segment.end_window[1] == case.t[rows[-1]]


@pytest.mark.parametrize("seed", SEEDS)
def test_the_helix_leaves_any_plane_while_its_normal_goes_round_and_stays_one_segment(seed: int) -> None:
    case = case_of("helix", seed)
    rows = contact_rows(case)
    path = case.positions[rows]
    centred = path - path.mean(axis=0)
    off_plane = np.linalg.svd(centred, full_matrices=False)[1][2] / np.sqrt(rows.size)
    assert off_plane >= 0.010
    normals = case.normals[rows]
    turned = np.sum(angle_deg(normals[1:], normals[:-1]))
    assert 270.0 <= turned <= 360.0 and turned == pytest.approx(case.parameters["turn_deg"], abs=0.5)
    # The rules: the heading across the contact's mean normal (a radial direction) never winds a full turn.
    mean_normal = normals.mean(axis=0) / np.linalg.norm(normals.mean(axis=0))
    assert winding_windows(case.t[rows], path, mean_normal) == []
    [segment] = case.segments
    assert segment.start_window == (case.t[rows[0]],) * 2 and segment.end_window == (case.t[rows[-1]],) * 2
    assert 0.05 <= case.parameters["radius_m"] <= 0.10


@pytest.mark.parametrize("seed", SEEDS)
def test_the_artefact_file_holds_spikes_a_clipped_stretch_and_a_drift(seed: int) -> None:
    case = case_of("sensor-artefacts", seed)
    source = human_case("human-zigzag" if case.parameters["zigzag"] else "human-straight", seed)
    assert case.recording.csv_text.splitlines()[0] == source.recording.csv_text.splitlines()[0]
    spoilt, clean = parsed(case.recording.csv_text), parsed(source.recording.csv_text)
    np.testing.assert_array_equal(spoilt[:, :8], clean[:, :8])  # time stamps and poses untouched
    np.testing.assert_array_equal(spoilt[:, 11:], clean[:, 11:])
    np.testing.assert_array_equal(case.normal_force_n, source.normal_force_n)
    assert [s.span for s in case.segments] == [s.span for s in source.segments]
    stamps, forces, change = spoilt[:, 0], spoilt[:, 8:11], spoilt[:, 8:11] - clean[:, 8:11]

    # The clipped stretch: one axis reads one value over 0.1-0.2 s in the stroke, below what it carried.
    runs = []
    for axis in range(3):
        same = np.concatenate([[False], np.diff(forces[:, axis]) == 0.0])
        starts = np.flatnonzero(~same)
        for lo, hi in zip(starts, [*starts[1:], same.size], strict=True):
            runs.append((stamps[hi - 1] - stamps[lo], axis, lo, hi))
    length, axis, lo, hi = max(runs)
    assert 0.08 <= length <= 0.2
    assert sorted(r[0] for r in runs)[-2] < 0.05  # no other stretch: a stale row repeats one value once
    assert case.segments[0].span[0] < stamps[lo] and stamps[hi - 1] < case.segments[0].span[1]
    assert np.all(np.abs(clean[lo:hi, 8 + axis]) > np.abs(forces[lo, axis]) + 1.0)
    clipped = np.zeros(stamps.size, dtype=bool)
    clipped[lo:hi] = True

    # The drift: linear in time over the whole file, 0.5-1.0 N from the first row to the last.
    elapsed = (stamps - stamps[0]) / (stamps[-1] - stamps[0])
    ordinary = ~clipped & np.all(np.abs(change) < 2.0, axis=1)
    slope, offset = np.polyfit(elapsed[ordinary], change[ordinary], 1)
    assert np.max(np.abs(offset)) < 1e-4
    assert 0.5 <= np.linalg.norm(slope) <= 1.0
    residual = change - np.outer(elapsed, slope) - offset
    assert np.max(np.abs(residual[ordinary])) < 1e-4

    # The spikes: 3-6 single rows, 30-80 N on one axis, outside the clipped stretch.
    spiked = np.flatnonzero(np.any(np.abs(residual) > 1.0, axis=1) & ~clipped)
    assert 3 <= spiked.size <= 6 and np.all(np.diff(spiked) > 1)
    for row in spiked:
        size = np.sort(np.abs(residual[row]))
        assert 30.0 <= size[-1] <= 80.0 and size[-2] < 1e-4
    assert case.parameters["spikes"] == spiked.size and 0.5 <= case.parameters["drift_n"] <= 1.0
    demo = read_csv(case.recording.csv_text, case.recording.import_options).arrays()  # still a readable file
    assert demo.t[-1] == pytest.approx(case.t[-1], abs=0.02)


def slide_skill_with_profile(case: CorpusCase, constant: bool):
    """The truth's skill (`test_corpus.perfect_skill`: CF z along the plane's normal over the span) carrying the
    true normal force as a force DMP, or (``constant``) the truth segment's ``force_n`` as a constant."""
    skill = perfect_skill(case)
    [segment] = skill.segments
    if not constant:
        rows = np.flatnonzero((case.t >= segment.t_start) & (case.t <= segment.t_end))
        force = DMP.fit(case.t[rows], case.normal_force_n[rows], n_basis=80, kind="force")
        segment = segment.model_copy(update={"force_dmp": force.to_parameters(), "force_constant_n": None})
    return skill.model_copy(update={"segments": [segment]})


@pytest.mark.parametrize("family", ["ramp-press", "wobble-press"])
def test_an_unsteady_press_is_scored_by_its_profile_not_by_a_constant(family: str) -> None:
    case = case_of(family, 0)
    profile = score(slide_skill_with_profile(case, constant=False), case)
    assert profile.type_right and profile.strokes_right and profile.boundary_error_s == 0.0
    assert profile.normal_error_deg < 1e-3
    assert profile.force_error < 0.02
    # A constant at the mean matches force_n exactly, which a steady truth would score 0: the profile misses.
    flat = score(slide_skill_with_profile(case, constant=True), case)
    assert flat.force_error > 0.2
