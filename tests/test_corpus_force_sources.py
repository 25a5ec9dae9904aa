"""The force-source families (corpus.force_sources) carry the truth they promise, and their files read back to it:
a torque-sensing arm's wipe logged at the flange with a turning, offset, friction-dragged estimate; a tool weight the
wrist sensor does not compensate; a grinder's side force; a friction beyond the friction cone. Nothing here learns.
"""

from __future__ import annotations

from functools import cache
from itertools import combinations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d
from test_corpus import angle_deg, check_truth, read_csv

from corpus import force_sources as fs
from corpus.arm_wipe import LWR_RATE_HZ, ArmEstimateRecording
from corpus.case import CorpusCase
from skills.quaternions import matrix_from_quaternion

SEEDS = (0, 1, 2)
WIPES = [(area, seed) for area in ("patch", "strip") for seed in SEEDS]


@cache
def cases() -> tuple[CorpusCase, ...]:
    return tuple(fs.force_source_cases(SEEDS))


def case_of(family: str, seed: int) -> CorpusCase:
    return next(c for c in cases() if c.family == family and c.name.endswith(f"-s{seed}"))


def parsed(text: str) -> np.ndarray:
    return np.loadtxt(text.splitlines()[1:], delimiter=",", ndmin=2)


def at(t_query: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t_query, t, column) for column in values.T], axis=1)


def unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def pressing(case: CorpusCase) -> np.ndarray:
    """Samples of the truth segments between their touch-down and lift-off ramps."""
    ramp = case.parameters["ramp_s"]
    return np.any([(case.t > s.span[0] + ramp) & (case.t < s.span[1] - ramp) for s in case.segments], axis=0)


def velocities(case: CorpusCase) -> np.ndarray:
    return np.gradient(case.positions, case.t, axis=0)


def without_velocity(forces: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """The friction-free forces: their component along the velocity removed."""
    direction = unit(velocity)
    return forces - np.sum(forces * direction, axis=1, keepdims=True) * direction


def weight_wrench(case: CorpusCase) -> np.ndarray:
    """What the wrist sensor carries for the tool's weight (applied-by-tool terms, world, about the tool point)."""
    p = case.parameters
    lift = np.array([0.0, 0.0, 9.81 * p["tool_mass_kg"]])
    com = np.array([p["tool_com_x"], p["tool_com_y"], p["tool_com_z"]])
    lever = matrix_from_quaternion(case.orientations) @ com
    return np.hstack([np.broadcast_to(lift, lever.shape), np.cross(lever, lift)])


# --------------------------------------------------------------------------- every family


def test_every_family_once_per_seed_with_its_truth_consistent() -> None:
    assert [c.family for c in cases()] == list(fs.FORCE_SOURCE_FAMILIES) * len(SEEDS)
    assert len({c.name for c in cases()}) == len(cases())
    for case in cases():
        check_truth(case)
        assert case.t[-1] < 23.5, case.name
        assert case.skill_type == ("contour" if case.family == "cylinder-high-friction" else "slide")
        assert (case.recording is None) == (case.family == "cylinder-high-friction")
        strokes = {"tool-weight": 2, "tool-weight-no-free": 1, "grinder": 1, "cylinder-high-friction": 1}
        expected = case.parameters["contacts"] if case.family.startswith("lwr-wipe") else strokes[case.family]
        assert len(case.segments) == expected, case.name
    assert fs.grinder_case(SEEDS[1]).parameters == case_of("grinder", SEEDS[1]).parameters  # seeded


@pytest.mark.parametrize("case", [c for c in cases() if c.recording is not None], ids=lambda c: c.name)
def test_every_file_reads_back_to_the_truth_plus_the_modelled_errors(case: CorpusCase) -> None:
    recording = case.recording
    offset = tuple(recording.sensor_offset)
    demo = read_csv(recording.csv_text, recording.import_options, force_offset=offset).arrays()
    raw = read_csv(recording.csv_text, recording.import_options, tare=False).arrays()
    assert demo.t[0] == pytest.approx(0.0) and demo.t[-1] == pytest.approx(case.t[-1], abs=0.02)
    R = matrix_from_quaternion(at(demo.t, case.t, case.orientations))
    if isinstance(recording, ArmEstimateRecording):
        assert recording.csv_text.splitlines()[0] == "t,x,y,z,qx,qy,qz,qw,fx,fy,fz,mx,my,mz"
        assert recording.import_options["wrench_frame"] == "world"
        # The file's pose is the flange's, L behind the tool point along tool z.
        flange = (
            case.positions - case.parameters["flange_offset_m"] * matrix_from_quaternion(case.orientations)[:, :, 2]
        )
        np.testing.assert_allclose(recording.flange_positions, flange, atol=1e-12)
        assert np.max(np.linalg.norm(demo.positions - at(demo.t, case.t, flange), axis=1)) < 2e-4
        assert np.min(np.linalg.norm(demo.positions - at(demo.t, case.t, case.positions), axis=1)) > 0.09
        expected = recording.flange_wrenches[:, :3] + recording.direction_errors + recording.joint_friction
        expected = at(demo.t, case.t, expected + recording.hand_forces)
        noise = case.parameters["noise_n"]
        # The moment is the applied force's about the flange: L tool_z x F.
        moment = np.cross(at(demo.t, case.t, case.positions - flange), at(demo.t, case.t, case.wrenches[:, :3]))
        assert np.sqrt(np.mean((demo.wrenches[:, 3:] - moment) ** 2)) < 0.06
        # A constant offset of 2-4 N in the world frame, on the robot: it reads as its negative after import.
        assert 2.0 <= np.linalg.norm(offset[:3]) <= 4.0
        untared = np.mean(raw.wrenches[:, :3] - expected, axis=0)
        np.testing.assert_allclose(untared, -np.array(offset[:3]), atol=0.05)
    else:
        assert recording.csv_text.splitlines()[0] == "t,x,y,z,qw,qx,qy,qz,fx,fy,fz,mx,my,mz"
        assert np.max(np.linalg.norm(demo.positions - at(demo.t, case.t, case.positions), axis=1)) < 3e-4
        sensed = case.wrenches + (weight_wrench(case) if case.family.startswith("tool-weight") else 0.0)
        expected = at(demo.t, case.t, sensed[:, :3] + recording.hand_forces)
        noise = 0.2
        assert np.sqrt(np.mean((demo.wrenches[:, 3:] - at(demo.t, case.t, sensed[:, 3:])) ** 2)) < 0.01
        # The sensor's offset is in the tool frame, as the reaction: it turns with the tool in the world.
        untared = raw.wrenches[:, :3] - expected + R @ np.array(offset[:3])
        np.testing.assert_allclose(np.mean(untared, axis=0), 0.0, atol=0.05)
    residual = demo.wrenches[:, :3] - expected
    assert np.sqrt(np.mean(residual**2)) < 1.1 * noise
    assert np.max(np.abs(np.mean(residual, axis=0))) < 0.05


# --------------------------------------------------------------------------- the torque-sensing arm's wipe


def lane_direction(case: CorpusCase) -> np.ndarray:
    """The wipe's main direction of motion at the press (unit, either sign)."""
    velocity = velocities(case)[pressing(case)]
    return np.linalg.eigh(velocity.T @ velocity)[1][:, -1]


def wipe_passes(case: CorpusCase) -> list[slice]:
    """Straight runs at the press along the wipe's main direction of motion (within 20 deg either way), faster than
    2 cm/s, covering 80 % of its length: from U-turn to U-turn."""
    velocity, lane = velocities(case), lane_direction(case)
    speed = np.linalg.norm(velocity, axis=1)
    mask = pressing(case) & (np.abs(velocity @ lane) > np.cos(np.radians(20.0)) * speed) & (speed > 0.02)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    runs = [slice(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return [r for r in runs if np.ptp(case.positions[r] @ lane) > 0.8 * case.parameters["length_m"]]


def turn_deg(case: CorpusCase, forces: np.ndarray, run: slice) -> float:
    """The angular diameter (deg) of the friction-free force's direction over a pass, smoothed over 0.1 s."""
    free = uniform_filter1d(without_velocity(forces, velocities(case)), 10, axis=0, mode="nearest")[run]
    directions = unit(free)
    return float(np.degrees(np.arccos(np.clip(np.min(directions @ directions.T), -1.0, 1.0))))


def imported(case: CorpusCase) -> np.ndarray:
    """The file's force after import, its offset removed (applied-by-tool, world), at the truth's samples."""
    recording = case.recording
    demo = read_csv(recording.csv_text, recording.import_options, force_offset=tuple(recording.sensor_offset))
    arrays = demo.arrays()
    np.testing.assert_allclose(arrays.t, case.t, atol=1e-9)
    return arrays.wrenches[:, :3]


@pytest.mark.parametrize(("area", "seed"), WIPES)
def test_the_arm_estimate_turns_25_to_35_deg_within_every_pass_and_the_true_force_does_not(
    area: str, seed: int
) -> None:
    case = case_of(f"lwr-wipe-{area}", seed)
    passes = wipe_passes(case)
    assert passes
    estimate = imported(case)
    for run in passes:
        assert 25.0 <= turn_deg(case, estimate, run) <= 35.0
        assert turn_deg(case, case.wrenches[:, :3], run) < 1.0  # the plane does not turn: the estimate does


@pytest.mark.parametrize(("area", "seed"), WIPES)
def test_the_direction_error_depends_on_where_the_arm_is_not_on_time(area: str, seed: int) -> None:
    """The estimate without its other errors is the true force turned about a fixed axis (in the part's plane) by an
    angle linear in where the arm reaches (the tool point): the fit on position leaves only the noise, one on time
    does not."""
    case, p = case_of(f"lwr-wipe-{area}", seed), case_of(f"lwr-wipe-{area}", seed).parameters
    recording = case.recording
    axis = np.array([p["direction_axis_x"], p["direction_axis_y"], p["direction_axis_z"]])
    assert abs(axis @ case.segments[0].normal) < 1e-9 and abs(axis[2]) < np.sin(np.radians(15.0))
    turned = imported(case) - recording.joint_friction - recording.hand_forces
    turned = uniform_filter1d(turned, 10, axis=0, mode="nearest")
    rows = pressing(case)
    true = uniform_filter1d(case.wrenches[:, :3], 10, axis=0, mode="nearest")[rows]
    across_true, across_turned = true - np.outer(true @ axis, axis), turned[rows] - np.outer(turned[rows] @ axis, axis)
    angle = np.arctan2(np.cross(across_true, across_turned) @ axis, np.sum(across_true * across_turned, axis=1))
    # In-plane coordinates of the tool point (along the plane's normal it hardly moves: no fit there).
    normal = case.segments[0].normal
    in_plane = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    by_position = np.column_stack([np.ones(rows.sum()), case.positions[rows] @ in_plane])
    coefficients, *_ = np.linalg.lstsq(by_position, angle)
    misfit = np.degrees(np.sqrt(np.mean((by_position @ coefficients - angle) ** 2)))
    by_time = np.column_stack([np.ones(rows.sum()), case.t[rows], case.t[rows] ** 2])
    misfit_time = np.degrees(np.sqrt(np.mean((by_time @ np.linalg.lstsq(by_time, angle)[0] - angle) ** 2)))
    assert misfit < 1.5 and misfit_time > max(3.0 * misfit, 2.0)
    gradient = p["direction_gradient_rad_m"] * np.array([p[f"direction_gradient_{x}"] for x in "xyz"]) @ in_plane
    np.testing.assert_allclose(coefficients[1:], gradient, atol=0.1 * np.linalg.norm(gradient))


@pytest.mark.parametrize(("area", "seed"), WIPES)
def test_the_wipe_covers_its_area_on_a_plane_and_its_estimate_leans_against_the_motion(area: str, seed: int) -> None:
    case = case_of(f"lwr-wipe-{area}", seed)
    p, recording = case.parameters, case.recording
    path = case.positions[case.in_contact] - case.positions[case.in_contact].mean(axis=0)
    axes = np.linalg.svd(path, full_matrices=False)[2]
    assert np.sqrt(np.mean((path @ axes[2]) ** 2)) < 1.5e-3  # the contact points lie on a plane
    assert np.sqrt(np.mean((path @ axes[1]) ** 2)) >= 8e-3  # lanes side by side cover the width
    # At the full press the lanes cover the area: its length (a touch-down and a lift-off ramp just outside it)
    # and its width, lane after lane.
    lane = lane_direction(case)
    pressed = case.positions[pressing(case)]
    assert 0.98 * p["length_m"] <= np.ptp(pressed @ lane) <= p["length_m"] + 0.02
    assert np.ptp(pressed @ np.cross(axes[2], lane)) == pytest.approx(p["width_m"], abs=2e-3)
    assert angle_deg(axes[2], case.segments[0].normal) < 1.0 or angle_deg(-axes[2], case.segments[0].normal) < 1.0
    assert 4 <= p["lanes"] <= 6 and 0.008 <= p["lane_spacing_m"] <= 0.012
    # On the file's side (the force on the robot) the estimate leans against the motion: surface and joint friction.
    velocity = velocities(case)
    speed = np.linalg.norm(velocity, axis=1)
    sliding = pressing(case) & (speed > 0.02)
    direction = unit(velocity[sliding])
    estimate = imported(case)[sliding]
    assert np.median(np.sum(-estimate * direction, axis=1)) < 0.0
    # After import the joint friction drags it along the motion beyond the surface's friction, by its 1.5-4 N.
    extra = np.sum((estimate - case.wrenches[sliding, :3]) * direction, axis=1)
    assert np.median(extra) == pytest.approx(p["joint_friction_n"], abs=0.5)
    assert 1.5 <= p["joint_friction_n"] <= 4.0
    # The hand's push shows in free space only, 2-8 N at most.
    hand = np.linalg.norm(recording.hand_forces, axis=1)
    assert np.all(hand[case.in_contact] == 0.0) and 2.0 < hand.max() < 8.0
    # Rests held still in the air at both ends, at least 1 s.
    for rows in (slice(0, 100), slice(-100, None)):
        assert not case.in_contact[rows].any() and np.ptp(case.positions[rows], axis=0).max() < 3e-3
    stamps = parsed(recording.csv_text)[:, 0]
    steps = np.diff(stamps) * LWR_RATE_HZ
    assert steps.min() > 0.55 and steps.max() < 1.45 and np.ptp(steps) > 0.5  # ±20 % jitter, increasing


# --------------------------------------------------------------------------- the tool weight


def rests(case: CorpusCase) -> list[slice]:
    """Stretches of at least 0.8 s in free space where the tool point stays within 4 mm, less 0.3 s at each end."""
    rate = round(case.parameters["rate_hz"])
    window = round(0.5 * rate)
    still = np.array(
        [
            np.ptp(case.positions[max(0, k - window // 2) : k + window // 2 + 1], axis=0).max() < 4e-3
            for k in range(case.t.size)
        ]
    )
    mask = still & ~case.in_contact
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    trim = round(0.3 * rate)
    return [slice(a + trim, b - trim) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 0.8 * rate]


@pytest.mark.parametrize("seed", SEEDS)
def test_the_free_space_readings_turn_with_the_tool_as_its_weight_predicts(seed: int) -> None:
    case = case_of("tool-weight", seed)
    p, recording = case.parameters, case.recording
    assert 0.4 <= p["tool_mass_kg"] <= 0.6
    assert (
        0.03 <= p["tool_com_z"] + p["sensor_to_tool_point_m"] <= 0.08
        and np.hypot(p["tool_com_x"], p["tool_com_y"]) <= 0.01
    )
    rows = parsed(recording.csv_text)
    assert rows.shape[0] == case.t.size
    R = matrix_from_quaternion(case.orientations)
    # The sensor's reading (tool frame, on the tool) with its offset removed and the hand's push given back.
    reading = rows[:, 8:11] - recording.sensor_offset[:3] + np.einsum("nji,nj->ni", R, recording.hand_forces)
    stretches = rests(case)
    assert len(stretches) == 3  # at the start, between the strokes, at the end
    tool_z = [unit(np.mean(R[r][:, :, 2], axis=0)) for r in stretches]
    for a, b in combinations(tool_z, 2):
        assert 20.0 <= angle_deg(a, b) <= 45.0
    weight = [np.mean(-p["tool_mass_kg"] * 9.81 * R[r][:, 2, :], axis=0) for r in stretches]  # -R^T (m g up)
    for r, predicted in zip(stretches, weight, strict=True):
        np.testing.assert_allclose(np.mean(reading[r], axis=0), predicted, atol=0.1)
    # Clearly different: ten times as far apart as the readings are from the prediction.
    assert min(np.linalg.norm(a - b) for a, b in combinations(weight, 2)) > 1.0
    # Over the rests a tare can separate the offset from the weight: offset + mass fit to the raw reading.
    free = np.concatenate([np.arange(r.start, r.stop) for r in stretches])
    raw = rows[free, 8:11] + np.einsum("nji,nj->ni", R[free], recording.hand_forces[free])
    design = np.zeros((3 * free.size, 4))
    design[:, :3] = np.tile(np.eye(3), (free.size, 1))
    design[:, 3] = (-9.81 * R[free][:, 2, :]).ravel()
    solution, *_ = np.linalg.lstsq(design, raw.ravel())
    assert solution[3] == pytest.approx(p["tool_mass_kg"], rel=0.05)
    np.testing.assert_allclose(solution[:3], recording.sensor_offset[:3], atol=0.15)
    offset_only = raw - raw.mean(axis=0)
    assert np.sqrt(np.mean(np.sum(offset_only**2, axis=1))) > 1.0  # a plain offset cannot explain the rests
    # The weight's moment about the tool point, as the centre of mass predicts.
    moment = rows[:, 11:14] - recording.sensor_offset[3:]
    predicted = -np.einsum("nji,nj->ni", R, weight_wrench(case)[:, 3:])
    np.testing.assert_allclose(np.mean(moment[free] - predicted[free], axis=0), 0.0, atol=0.005)


@pytest.mark.parametrize("seed", SEEDS)
def test_the_file_cut_to_its_contact_has_no_sample_in_the_air(seed: int) -> None:
    case = case_of("tool-weight-no-free", seed)
    assert np.all(case.in_contact)
    assert parsed(case.recording.csv_text).shape[0] == case.t.size
    [segment] = case.segments
    assert segment.start_window == (0.0, 0.0) and segment.end_window[1] == pytest.approx(case.t[-1], abs=0.01)
    assert case.normal_force_n[0] < 0.05 * segment.force_n and case.normal_force_n[-1] < 0.05 * segment.force_n
    recording = case.recording
    # In contact the uncompensated weight makes the press look lighter by m g cos(slope) along the normal.
    applied = read_csv(recording.csv_text, recording.import_options, force_offset=tuple(recording.sensor_offset))
    seen = applied.arrays().wrenches[:, :3] - recording.hand_forces - case.wrenches[:, :3]
    lighter = -case.parameters["tool_mass_kg"] * 9.81 * np.cos(np.radians(case.parameters["tilt_deg"]))
    assert np.median(seen @ segment.normal) == pytest.approx(lighter, abs=0.05)
    assert 7.0 * 0.9 <= segment.force_n <= 10.0 * 1.1 and 30.0 <= case.parameters["tilt_deg"] <= 40.0


# --------------------------------------------------------------------------- the grinder and high friction


@pytest.mark.parametrize("seed", SEEDS)
def test_the_grinder_leans_its_friction_free_force_14_to_19_deg_across_its_pass(seed: int) -> None:
    case = case_of("grinder", seed)
    [segment] = case.segments
    # Over 0.1 s (the hand's tremor turns the sampled velocity by up to ~25 deg at 2 cm/s).
    window = round(0.1 * case.parameters["rate_hz"])
    velocity = uniform_filter1d(velocities(case), window, axis=0, mode="nearest")
    rows = pressing(case) & (np.linalg.norm(velocity, axis=1) > 0.01)
    force = uniform_filter1d(case.wrenches[:, :3], window, axis=0, mode="nearest")
    free = without_velocity(force, velocity)[rows]
    lean = angle_deg(free, segment.normal)
    assert lean.min() >= 14.0 and lean.max() <= 19.0
    # Across the pass, always to the same side.
    across = np.cross(segment.normal, unit(velocity[rows]))
    sideways = np.sum(free * across, axis=1) / np.linalg.norm(free, axis=1)
    assert np.all(sideways > 0.2) or np.all(sideways < -0.2)
    # The side force is the disc's cut, 0.28-0.33 N per N of press (friction acts along the motion only).
    cut = np.abs(np.sum(force[rows] * across, axis=1)) / case.normal_force_n[rows]
    assert np.median(cut) == pytest.approx(case.parameters["cut_ratio"], rel=0.05)
    assert 0.28 <= case.parameters["cut_ratio"] <= 0.33
    # The true normal force is the press alone (10-20 N plateau); the pass is straight, 15-20 cm, at 2-5 cm/s.
    assert 10.0 * 0.9 <= segment.force_n <= 20.0 * 1.1
    path = case.positions[case.in_contact]
    assert 0.15 <= np.linalg.norm(path[-1] - path[0]) <= 0.2
    assert segment.normal[2] <= -np.cos(np.radians(10.0))


@pytest.mark.parametrize("seed", SEEDS)
def test_the_high_friction_cylinder_drags_more_than_the_friction_cone(seed: int) -> None:
    case = case_of("cylinder-high-friction", seed)
    velocity = velocities(case)
    rows = case.in_contact & (case.normal_force_n > 1.0) & (np.linalg.norm(velocity, axis=1) > 0.03)
    force = case.wrenches[rows, :3]
    normal = case.normals[rows]
    tangential = force - np.sum(force * normal, axis=1, keepdims=True) * normal
    ratio = np.linalg.norm(tangential, axis=1) / case.normal_force_n[rows]
    assert rows.sum() > 500 and ratio.min() >= 0.75
    assert 0.08 <= case.parameters["radius_m"] <= 0.2
