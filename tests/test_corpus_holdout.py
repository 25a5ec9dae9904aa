"""The held-out families (corpus.holdout) carry the truth they promise, and their files read back to it: a
torque-sensing arm's strip wipe on a near-flat cylinder, an uncompensated tool weight over one straight stroke, a hand
pushing the arm's links while it wipes, a torque-sensing arm's single circle. Ground truth only: nothing here learns,
and the importer is kept from learning (its direction hint would learn other readings of a file pressing up).
"""

from __future__ import annotations

from functools import cache
from itertools import combinations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d
from scipy.optimize import least_squares
from test_corpus_force_sources import rests

from corpus import holdout
from corpus.arm_wipe import LWR_RATE_HZ, ArmEstimateRecording
from corpus.case import CorpusCase
from schemas.import_options import CsvImportOptions
from services import csv_import, import_steps
from skills.quaternions import matrix_from_quaternion

SEEDS = (0, 1, 2)


@cache
def cases() -> tuple[CorpusCase, ...]:
    return tuple(holdout.holdout_cases(SEEDS))


def case_of(family: str, seed: int) -> CorpusCase:
    return next(c for c in cases() if c.family == family and c.name.endswith(f"-s{seed}"))


@pytest.fixture(autouse=True)
def never_learned(monkeypatch: pytest.MonkeyPatch) -> None:
    """The held-out files are read, never learned from: the importer learns only to judge other readings of a file
    whose force points up (and fits a tare only when asked to); either would fail the test instead."""

    def refused(*args: object, **kwargs: object) -> None:
        raise AssertionError("a held-out case must not be learned from (nor tared by a fit)")

    monkeypatch.setattr(import_steps, "learn_skill", refused)
    monkeypatch.setattr(import_steps, "tool_velocities", refused)
    monkeypatch.setattr(import_steps.tare_module, "fitted_sensor_offset", refused)


# --------------------------------------------------------------------------- helpers


def read_csv(text: str, options: dict[str, object], **more: object):
    return csv_import.demonstration_from_csv(text, CsvImportOptions(**options, **more)).arrays()


def parsed(text: str) -> np.ndarray:
    return np.loadtxt(text.splitlines()[1:], delimiter=",", ndmin=2)


def at(t_query: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t_query, t, column) for column in values.T], axis=1)


def unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(unit(a) * unit(b), axis=-1), -1.0, 1.0)))


def diameter_deg(directions: np.ndarray) -> float:
    """The largest angle between any two of ``directions`` (N, 3), deg."""
    directions = unit(directions)
    return float(np.degrees(np.arccos(np.clip(np.min(directions @ directions.T), -1.0, 1.0))))


def velocities(case: CorpusCase) -> np.ndarray:
    return np.gradient(case.positions, case.t, axis=0)


def contacts(case: CorpusCase) -> list[slice]:
    edges = np.flatnonzero(np.diff(np.concatenate([[0], case.in_contact.astype(int), [0]])))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def pressing(case: CorpusCase) -> np.ndarray:
    """Samples of each contact between its touch-down and lift-off ramps (the press's plateau)."""
    ramp, mask = case.parameters["ramp_s"], np.zeros(case.t.size, dtype=bool)
    for run in contacts(case):
        t0, t1 = case.t[run.start], case.t[run.stop - 1]
        mask |= (case.t > t0 + ramp) & (case.t < t1 - ramp)
    return mask


def imported(case: CorpusCase) -> np.ndarray:
    """An arm log's force after import, its offset removed (applied by the tool, world), at the truth's samples."""
    recording = case.recording
    arrays = read_csv(recording.csv_text, recording.import_options, force_offset=tuple(recording.sensor_offset))
    np.testing.assert_allclose(arrays.t, case.t, atol=1e-9)
    return arrays.wrenches[:, :3]


def friction_free(forces: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """The forces' component across the velocity, smoothed over 0.1 s (10 samples at 100 Hz)."""
    direction = unit(velocity)
    free = forces - np.sum(forces * direction, axis=1, keepdims=True) * direction
    return uniform_filter1d(free, 10, axis=0, mode="nearest")


def weight_wrench(case: CorpusCase, R: np.ndarray) -> np.ndarray:
    """What the wrist sensor carries for the tool's weight with the tool at ``R`` (N, 3, 3) world-from-tool
    (applied-by-tool terms, world, about the tool point): m·9.81 N up and its moment."""
    p = case.parameters
    lift = np.array([0.0, 0.0, 9.81 * p["tool_mass_kg"]])
    lever = R @ np.array([p["tool_com_x"], p["tool_com_y"], p["tool_com_z"]])
    return np.hstack([np.broadcast_to(lift, lever.shape), np.cross(lever, lift)])


def without_weight(case: CorpusCase) -> str:
    """The wrist sensor file with the tool's weight taken out of its rows (tool frame, on the tool): read with it,
    the weight (m g UP in applied terms) would make the importer's direction hint judge other readings by learning."""
    rows = parsed(case.recording.csv_text)
    R = matrix_from_quaternion(rows[:, [5, 6, 7, 4]])  # the file's quaternions are scalar-first
    weight = weight_wrench(case, R)
    rows[:, 8:11] += np.einsum("nji,nj->ni", R, weight[:, :3])  # the reading is -R^T (applied + weight)
    rows[:, 11:14] += np.einsum("nji,nj->ni", R, weight[:, 3:])
    header = case.recording.csv_text.splitlines()[0]
    lines = [",".join([f"{row[0]:.6f}", *(f"{v:.7g}" for v in row[1:])]) for row in rows]
    return "\n".join([header, *lines]) + "\n"


def consistent(case: CorpusCase) -> None:
    """The truth of one case agrees with itself (as tests/test_corpus.py checks every family's)."""
    assert np.all(np.diff(case.t) > 0)
    np.testing.assert_allclose(np.linalg.norm(case.normals, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(case.orientations, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.sum(case.wrenches[:, :3] * case.normals, axis=1), case.normal_force_n, atol=1e-9)
    assert np.all(case.normal_force_n[~case.in_contact] == 0.0) and np.all(case.normal_force_n >= 0.0)
    assert np.all(case.wrenches[:, 3:] == 0.0)
    stroking = np.any([(case.t >= s.span[0]) & (case.t <= s.span[1]) for s in case.segments], axis=0)
    tool_z = matrix_from_quaternion(case.orientations[stroking])[:, :, 2]
    assert np.all(angle_deg(tool_z, case.normals[stroking]) < 25.0)
    # Moving in contact, the path on the surface (the pad's sink-in removed) runs across the normal.
    sunk = (case.normal_force_n / case.parameters["pad_stiffness_n_m"])[:, None] * case.normals
    velocity = np.gradient(case.positions - sunk, case.t, axis=0)
    moving = pressing(case) & (np.linalg.norm(velocity, axis=1) > 0.01)
    assert moving.sum() > 100 and np.max(np.abs(angle_deg(velocity[moving], case.normals[moving]) - 90.0)) < 1.0
    for segment in case.segments:
        (a, b), (c, d) = segment.start_window, segment.end_window
        assert a <= b <= c <= d and np.all(case.in_contact[(case.t >= a) & (case.t <= d)])
        assert segment.force_n > 0.0 and segment.normal is not None and np.all(np.isfinite(segment.normal))
        if case.family != "lwr-wipe-curved":  # a plane's: the normal of every sample (the curved one's: its test)
            assert np.max(angle_deg(segment.normal, case.normals[(case.t >= b) & (case.t <= c)])) < 0.01
    for before, after in zip(case.segments[:-1], case.segments[1:], strict=True):
        assert before.end_window[1] <= after.start_window[0] or before.end_window == after.start_window


# --------------------------------------------------------------------------- every family


def test_every_family_once_per_seed_with_its_truth_consistent() -> None:
    assert [c.family for c in cases()] == list(holdout.HOLDOUT_FAMILIES) * len(SEEDS)
    assert len({c.name for c in cases()}) == len(cases())
    for case in cases():
        consistent(case)
        assert case.skill_type == "slide" and case.recording is not None and case.t[-1] < 24.0, case.name
        p = case.parameters
        strokes = {
            "lwr-wipe-curved": p.get("contacts"),
            "tool-weight-line": 1,
            "hand-on-arm": p.get("strokes"),
            # The winding rule cuts a contact going round more than a quarter turn past a full turn.
            "lwr-circle": 1 + (p.get("turns", 0.0) >= 1.25),
        }
        assert len(contacts(case)) == (1 if case.family == "lwr-circle" else strokes[case.family]), case.name
        assert len(case.segments) == strokes[case.family], case.name
    assert holdout.lwr_circle_case(SEEDS[1]).parameters == case_of("lwr-circle", SEEDS[1]).parameters  # seeded


@pytest.mark.parametrize("case", cases(), ids=lambda c: c.name)
def test_every_file_reads_back_to_its_path_and_the_truth_plus_the_modelled_errors(case: CorpusCase) -> None:
    recording = case.recording
    offset = tuple(recording.sensor_offset)
    if isinstance(recording, ArmEstimateRecording):
        text = recording.csv_text
        assert text.splitlines()[0] == "t,x,y,z,qx,qy,qz,qw,fx,fy,fz,mx,my,mz"
        assert recording.import_options == {
            "wrench_convention": "measured-on-tool",
            "wrench_frame": "world",
            "rate_hz": LWR_RATE_HZ,
            "name": case.name,
        }
    else:
        text = without_weight(case)
        assert text.splitlines()[0] == "t,x,y,z,qw,qx,qy,qz,fx,fy,fz,mx,my,mz"
        assert recording.import_options["quaternion_order"] == "wxyz"
        assert recording.import_options["wrench_frame"] == "tool"
    demo = read_csv(text, recording.import_options, force_offset=offset)
    raw = read_csv(text, recording.import_options, tare=False)
    assert demo.t[0] == pytest.approx(0.0) and demo.t[-1] == pytest.approx(case.t[-1], abs=0.02)
    noise = case.parameters["noise_n"] if isinstance(recording, ArmEstimateRecording) else 0.2  # N, per force axis
    tolerance = 4.0 * noise / np.sqrt(demo.t.size)  # four standard errors of a mean of the noise, N
    if isinstance(recording, ArmEstimateRecording):
        # The file's pose is the flange's, L behind the tool point along tool z (L = 0 for the hand on the arm,
        # whose arm logs the tool point).
        lever = case.parameters["flange_offset_m"] * matrix_from_quaternion(case.orientations)[:, :, 2]
        flange = case.positions - lever
        np.testing.assert_allclose(recording.flange_positions, flange, atol=1e-12)
        assert np.max(np.linalg.norm(demo.positions - at(demo.t, case.t, flange), axis=1)) < 2e-4
        if case.parameters["flange_offset_m"] > 0.0:
            assert 0.10 <= case.parameters["flange_offset_m"] <= 0.20
            assert np.min(np.linalg.norm(demo.positions - at(demo.t, case.t, case.positions), axis=1)) > 0.09
        expected = recording.flange_wrenches[:, :3] + recording.direction_errors + recording.joint_friction
        expected = at(demo.t, case.t, expected + recording.hand_forces)
        # The moment is the applied force's about the file's point: L tool_z x F.
        moment = np.cross(at(demo.t, case.t, lever), at(demo.t, case.t, case.wrenches[:, :3]))
        assert np.sqrt(np.mean((demo.wrenches[:, 3:] - moment) ** 2)) < 0.06
        # A constant offset of 2-4 N in the world frame, on the robot: it reads as its negative after import.
        assert 2.0 <= np.linalg.norm(offset[:3]) <= 4.0 and offset[3:] == (0.0, 0.0, 0.0)
        np.testing.assert_allclose(
            np.mean(raw.wrenches[:, :3] - expected, axis=0), -np.array(offset[:3]), atol=tolerance
        )
    else:
        assert np.max(np.linalg.norm(demo.positions - at(demo.t, case.t, case.positions), axis=1)) < 3e-4
        expected = at(demo.t, case.t, case.wrenches[:, :3] + recording.hand_forces)
        assert np.sqrt(np.mean(demo.wrenches[:, 3:] ** 2)) < 0.01  # the weight's moment taken out, none left
        # The sensor's offset is in the tool frame, as the reaction: it turns with the tool in the world.
        R = matrix_from_quaternion(at(demo.t, case.t, case.orientations))
        untared = raw.wrenches[:, :3] - expected + R @ np.array(offset[:3])
        np.testing.assert_allclose(np.mean(untared, axis=0), 0.0, atol=tolerance)
    residual = demo.wrenches[:, :3] - expected
    assert np.sqrt(np.mean(residual**2)) < 1.1 * noise
    assert np.max(np.abs(np.mean(residual, axis=0))) < tolerance
    stamps = parsed(recording.csv_text)[:, 0]
    assert np.all(np.diff(stamps) > 0)


# --------------------------------------------------------------------------- the wipe on a near-flat cylinder


def cylinder_fit(points: np.ndarray, axis_guess: np.ndarray) -> tuple[float, np.ndarray, float]:
    """The least-squares cylinder through ``points`` (N, 3) m: its radius (m), unit axis and RMS distance (m)."""
    centroid = points.mean(axis=0)
    e1 = unit(np.cross(axis_guess, [0.0, 0.0, 1.0]))
    e2 = np.cross(axis_guess, e1)
    # Start from the circle through the points seen along the guessed axis (an algebraic fit).
    x, y = (points - centroid) @ e1, (points - centroid) @ e2
    a, b, c = np.linalg.lstsq(np.column_stack([x, y, np.ones_like(x)]), x**2 + y**2)[0]

    def axis_of(angles: np.ndarray) -> np.ndarray:
        return unit(axis_guess + angles[0] * e1 + angles[1] * e2)

    def distances(v: np.ndarray) -> np.ndarray:
        axis, point = axis_of(v[:2]), centroid + v[2] * e1 + v[3] * e2
        offsets = points - point
        return np.linalg.norm(offsets - np.outer(offsets @ axis, axis), axis=1) - v[4]

    start = np.array([0.0, 0.0, a / 2, b / 2, np.sqrt(c + (a / 2) ** 2 + (b / 2) ** 2)])
    fit = least_squares(distances, start, x_scale=[0.01, 0.01, 1.0, 1.0, 1.0])
    return float(fit.x[4]), axis_of(fit.x[:2]), float(np.sqrt(np.mean(fit.fun**2)))


@pytest.mark.parametrize("seed", SEEDS)
def test_the_curved_wipe_turns_its_true_normal_5_to_14_deg_and_lies_on_a_cylinder_of_its_radius(seed: int) -> None:
    case = case_of("lwr-wipe-curved", seed)
    p = case.parameters
    normals = case.normals[case.in_contact]
    turn = diameter_deg(normals)
    assert 5.0 <= turn <= 14.0 + 1e-6 and turn == pytest.approx(p["contact_turn_deg"], abs=0.2)
    assert 5.0 <= p["normal_turn_deg"] <= turn and 1.0 <= p["radius_m"] <= 3.0
    # The contact path leaves its best plane by over a millimetre: no plane holds it.
    path = case.positions[case.in_contact] - case.positions[case.in_contact].mean(axis=0)
    assert np.sqrt(np.mean((path @ np.linalg.svd(path, full_matrices=False)[2][2]) ** 2)) >= 1e-3
    # The tool point, its pad's sink-in given back, lies on a cylinder of the drawn radius round the drawn axis.
    sunk = (case.normal_force_n / p["pad_stiffness_n_m"])[:, None] * case.normals
    surface = (case.positions - sunk)[case.in_contact]
    axis = np.array([p["cylinder_axis_x"], p["cylinder_axis_y"], p["cylinder_axis_z"]])
    radius, fitted_axis, misfit = cylinder_fit(surface, unit(axis + np.array([0.02, -0.02, 0.01])))
    assert radius == pytest.approx(p["radius_m"], rel=0.01) and misfit < 1e-4
    assert min(angle_deg(fitted_axis, axis), angle_deg(-fitted_axis, axis)) < 1.0 and abs(axis[2]) < 1e-12
    # The normal turns about the axis: every true normal is across it; the lanes run across it.
    assert np.max(np.abs(normals @ axis)) < 1e-9
    velocity = velocities(case)[pressing(case)]
    lane = np.linalg.eigh(velocity.T @ velocity)[1][:, -1]
    assert abs(lane @ axis) < np.sin(np.radians(5.0))
    # Each truth segment's normal is the mean true normal over its pressing samples, which turn under the tool.
    for segment, run in zip(case.segments, contacts(case), strict=True):
        rows = pressing(case)[run]
        mean = case.normals[run][rows].mean(axis=0)
        assert angle_deg(segment.normal, mean) < 0.2
        assert diameter_deg(case.normals[run][rows]) > 4.0


# --------------------------------------------------------------------------- the tool weight over one line


@pytest.mark.parametrize("seed", SEEDS)
def test_the_tool_weight_turns_with_the_tool_in_three_rests_and_the_stroke_is_a_line(seed: int) -> None:
    case = case_of("tool-weight-line", seed)
    p, recording = case.parameters, case.recording
    assert 0.3 <= p["tool_mass_kg"] <= 0.6 and 0.0 <= p["tilt_deg"] <= 10.0 and 0.15 <= p["length_m"] <= 0.2
    assert 6.0 * 0.9 <= case.segments[0].force_n <= 12.0 * 1.1
    rows = parsed(recording.csv_text)
    assert rows.shape[0] == case.t.size
    R = matrix_from_quaternion(case.orientations)
    # The sensor's reading (tool frame, on the tool) with its offset removed and the hand's push given back.
    reading = rows[:, 8:11] - recording.sensor_offset[:3] + np.einsum("nji,nj->ni", R, recording.hand_forces)
    stretches = rests(case)
    assert len(stretches) == 3  # aside before the approach, at its start, after the retreat
    tool_z = [unit(np.mean(R[r][:, :, 2], axis=0)) for r in stretches]
    for a, b in combinations(tool_z, 2):
        assert 20.0 <= angle_deg(a, b) <= 45.0
    weight = [np.mean(-p["tool_mass_kg"] * 9.81 * R[r][:, 2, :], axis=0) for r in stretches]  # -R^T (m g up)
    for r, predicted in zip(stretches, weight, strict=True):
        np.testing.assert_allclose(np.mean(reading[r], axis=0), predicted, atol=0.1)
    assert min(np.linalg.norm(a - b) for a, b in combinations(weight, 2)) > 1.0  # the orientations tell apart
    # Over the rests, offset and mass fit the raw reading; a plain offset cannot.
    free = np.concatenate([np.arange(r.start, r.stop) for r in stretches])
    raw = rows[free, 8:11] + np.einsum("nji,nj->ni", R[free], recording.hand_forces[free])
    design = np.zeros((3 * free.size, 4))
    design[:, :3] = np.tile(np.eye(3), (free.size, 1))
    design[:, 3] = (-9.81 * R[free][:, 2, :]).ravel()
    solution = np.linalg.lstsq(design, raw.ravel())[0]
    assert solution[3] == pytest.approx(p["tool_mass_kg"], rel=0.05)
    np.testing.assert_allclose(solution[:3], recording.sensor_offset[:3], atol=0.15)
    assert np.sqrt(np.mean(np.sum((raw - raw.mean(axis=0)) ** 2, axis=1))) > 0.7
    # The contact is one straight line: its path's RMS width across its direction under 2 mm, 15-20 cm long.
    path = case.positions[case.in_contact] - case.positions[case.in_contact].mean(axis=0)
    axes = np.linalg.svd(path, full_matrices=False)[2]
    assert np.sqrt(np.mean((path @ axes[1]) ** 2)) < 2e-3
    assert np.ptp(path @ axes[0]) == pytest.approx(p["length_m"], abs=3e-3)  # less a sample at either end
    assert abs(axes[0] @ case.segments[0].normal) < np.sin(np.radians(1.0))  # along the table


# --------------------------------------------------------------------------- the hand on the arm


@pytest.mark.parametrize("seed", SEEDS)
def test_the_hand_on_the_links_drags_the_imported_force_against_the_motion_by_its_damping(seed: int) -> None:
    case = case_of("hand-on-arm", seed)
    p, recording = case.parameters, case.recording
    assert 10.0 <= p["drag_n_s_m"] <= 25.0 and 2.0 <= p["wander_n"] <= 5.0 and 0.0 <= p["tilt_deg"] <= 30.0
    np.testing.assert_allclose(recording.hand_forces, recording.hand_drag + recording.hand_wander, atol=1e-12)
    velocity = velocities(case)
    speed = np.linalg.norm(velocity, axis=1)
    sliding = pressing(case) & (speed > 0.03)
    assert sliding.sum() > 200
    # In contact the file's force (after import, the offset removed) is the applied force plus the hand's push
    # negated: with its wander taken out, what is left lies along the motion, against it, as the drag says.
    left = (imported(case) - case.wrenches[:, :3] - recording.hand_wander)[sliding]
    direction = unit(velocity[sliding])
    along = np.sum(left * direction, axis=1)
    assert np.median(along / speed[sliding]) == pytest.approx(-p["drag_n_s_m"], rel=0.1)
    across = left - along[:, None] * direction
    assert np.sqrt(np.mean(across**2)) < 1.1 * p["noise_n"] + 0.05
    assert np.median(along) < -0.5  # at least half a newton against the motion
    # The hand keeps pushing in contact (a wrist sensor would not see it; the arm's joints do).
    push = np.linalg.norm(recording.hand_wander[case.in_contact], axis=1)
    assert push.max() > 1.0 and np.median(np.linalg.norm(recording.hand_drag[sliding], axis=1)) > 0.5
    # The zig-zag: 1-2 strokes, rests held still in the air at both ends.
    assert p["strokes"] in (1.0, 2.0)
    for rows in (slice(0, 100), slice(-100, None)):
        assert not case.in_contact[rows].any() and np.ptp(case.positions[rows], axis=0).max() < 3e-3


# --------------------------------------------------------------------------- the arm's single circle


@pytest.mark.parametrize("seed", SEEDS)
def test_the_circle_is_one_curve_whose_estimate_turns_20_to_30_deg_and_whose_truth_does_not(seed: int) -> None:
    case = case_of("lwr-circle", seed)
    p = case.parameters
    rows = pressing(case)
    velocity = velocities(case)
    assert 20.0 <= diameter_deg(friction_free(imported(case), velocity)[rows]) <= 30.0
    assert diameter_deg(friction_free(case.wrenches[:, :3], velocity)[rows]) < 1.0
    # One circle: the contact path within 2 mm RMS of the circle fitted in its plane, of the drawn radius, gone
    # round 1.05-2 times.
    path = case.positions[case.in_contact]
    centred = path - path.mean(axis=0)
    e1, e2, normal = np.linalg.svd(centred, full_matrices=False)[2]
    x, y = centred @ e1, centred @ e2
    a, b, c = np.linalg.lstsq(np.column_stack([x, y, np.ones_like(x)]), x**2 + y**2)[0]
    radius = np.sqrt(c + (a / 2) ** 2 + (b / 2) ** 2)
    distance = np.hypot(x - a / 2, y - b / 2) - radius
    assert np.sqrt(np.mean(distance**2)) < 2e-3 and np.sqrt(np.mean((centred @ normal) ** 2)) < 1e-3
    assert radius == pytest.approx(p["circle_radius_m"], abs=1e-3) and 0.02 <= p["circle_radius_m"] <= 0.04
    heading = np.unwrap(np.arctan2(velocity[case.in_contact] @ e2, velocity[case.in_contact] @ e1))
    assert 1.0 <= abs(heading[-1] - heading[0]) / (2 * np.pi) <= 2.05
    assert angle_deg(np.abs(normal), np.abs(case.segments[0].normal)) < 1.0 and p["tilt_deg"] <= 15.0
