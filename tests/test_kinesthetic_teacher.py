"""The kinesthetic teacher in PyBullet: recordings carry the facts of real hand-guided wiping, and their truth holds.

Real PyBullet (DIRECT), no mocks. Each recording is made once per module (two seeds per scenario: seed 0 with 2
strokes asked, seed 1 with its own default stroke count (2); one with the friction asked), ~150 s simulated.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cli.main import main
from corpus.kinesthetic import RECORDING_COLUMNS, KinestheticDemo, recording_csv_text
from schemas.world import WorldConfig
from sim_worker.geometry import WorldGeometry
from sim_worker.kinesthetic_teacher import (
    KINESTHETIC_SCENARIOS,
    SimKinestheticDemo,
    kinesthetic_world_config,
    record_kinesthetic,
)
from skills.quaternions import matrix_from_quaternion

CASES = [
    (scenario, seed, strokes, friction)
    for scenario in KINESTHETIC_SCENARIOS
    for seed, strokes, friction in ((0, 2, None), (1, None, 0.4 if scenario == "wipe_tilted" else None))
]
"""(scenario, seed, n_strokes asked or None, friction asked or None)."""

DT = 0.01


@pytest.fixture(scope="module")
def recordings() -> dict[tuple, SimKinestheticDemo]:
    """Every case's recording, made once."""
    return {case: record_kinesthetic(case[0], seed=case[1], n_strokes=case[2], friction=case[3]) for case in CASES}


def _wiped(demo: SimKinestheticDemo):
    """The solid the strokes wipe (exact geometry of the recording's world)."""
    geometry = WorldGeometry(demo.world_config)
    return geometry.solids["cylinder" if demo.truth.surface == "curved" else "table"]


def _stroke_rows(demo: KinestheticDemo, k: int) -> np.ndarray:
    stroke = demo.truth.strokes[k]
    return (demo.t >= stroke.t_on) & (demo.t <= stroke.t_off)


def _middle_rows(demo: KinestheticDemo, k: int) -> np.ndarray:
    """A stroke's samples without its first and last second (the force ramps and the slow start and stop)."""
    stroke = demo.truth.strokes[k]
    return (demo.t > stroke.t_on + 1.0) & (demo.t < stroke.t_off - 1.0)


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-seed{c[1]}" for c in CASES])
def test_a_recording_at_100_hz_with_its_strokes_friction_and_world(recordings, case):
    scenario, seed, strokes, friction = case
    demo = recordings[case]
    truth = demo.truth
    assert isinstance(demo, KinestheticDemo)
    n = demo.t.size
    assert np.allclose(np.diff(demo.t), DT) and demo.t[0] == 0.0
    for array, width in ((demo.positions, 3), (demo.orientations, 4), (demo.wrenches_applied, 6),
                         (demo.sensor_readings, 6), (demo.hand_forces, 3), (truth.normals, 3)):  # fmt: skip
        assert array.shape == (n, width)
    assert truth.in_contact.shape == truth.normal_force_n.shape == (n,)
    assert np.allclose(np.linalg.norm(demo.orientations, axis=1), 1.0)
    assert np.all(np.sum(demo.orientations[1:] * demo.orientations[:-1], axis=1) > 0)  # sign-continuous
    if strokes is not None:
        assert len(truth.strokes) == strokes
    else:  # from the seed
        assert 1 <= len(truth.strokes) <= 4
    if friction is not None:
        assert truth.friction == friction
    else:
        assert 0.2 <= truth.friction <= 0.4
    assert demo.world_config.contact.lateral_friction == truth.friction
    assert demo.world_config == kinesthetic_world_config(scenario, seed, friction)
    assert truth.surface == {"wipe_flat": "flat", "wipe_tilted": "tilted", "wipe_curved": "curved"}[scenario]
    assert truth.skill_type == ("contour" if scenario == "wipe_curved" else "slide")
    assert 0.7 <= np.linalg.norm(truth.sensor_offset[:3]) <= 2.3


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-seed{c[1]}" for c in CASES])
def test_strokes_touch_moving_and_lift_at_least_20_cm_between_them(recordings, case):
    demo = recordings[case]
    truth = demo.truth
    distance = _wiped(demo).signed_distance(demo.positions)[0]
    speed = np.linalg.norm(np.gradient(demo.positions, DT, axis=0), axis=1)
    edges = [0.0] + [x for s in truth.strokes for x in (s.t_on, s.t_off)] + [demo.t[-1] + DT]
    assert edges == sorted(edges)  # ordered, not overlapping
    free_spans = [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]
    for a, b in free_spans:
        span = (demo.t > a + 0.05) & (demo.t < b - 0.05)
        assert 0.20 <= distance[span].max() <= 0.45, (a, b)  # comes down from / lifts to 20-35 cm (+ a small arc)
        assert not truth.in_contact[span].any()
    for k, stroke in enumerate(truth.strokes):
        assert 2.5 <= stroke.t_off - stroke.t_on <= 15.0
        rows = _stroke_rows(demo, k)
        assert truth.in_contact[rows].mean() > 0.98  # one contact from touch to lift-off (no bounce)
        before = (demo.t > stroke.t_on - 0.06) & (demo.t < stroke.t_on - 0.01)
        assert 0.01 <= speed[before].mean() <= 0.07  # touches while still moving a few cm/s
        assert np.abs(distance[rows]).max() < 2e-3  # on the surface (the pad gives < 1.5 mm)


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-seed{c[1]}" for c in CASES])
def test_plateau_forces_and_the_wipe_along_a_curved_path(recordings, case):
    demo = recordings[case]
    truth = demo.truth
    speed = np.linalg.norm(np.gradient(demo.positions, DT, axis=0), axis=1)
    for k, stroke in enumerate(truth.strokes):
        assert 15.0 * 0.9 <= stroke.plateau_force_n <= 32.0 * 1.1
        middle = _middle_rows(demo, k)
        force = truth.normal_force_n[middle]
        # Swings of ±20 % around the plateau (plus the tracking error), never a lost contact.
        assert np.all(np.abs(force / stroke.plateau_force_n - 1.0) < 0.35)
        applied = np.einsum("ij,ij->i", demo.wrenches_applied[middle, :3], truth.normals[middle])
        assert np.allclose(applied, force, rtol=2e-3)  # (the normal turns a little within a sensor period)
        tangential = demo.wrenches_applied[middle, :3] - applied[:, None] * truth.normals[middle]
        sliding = speed[middle] > 0.02
        ratio = np.linalg.norm(tangential[sliding], axis=1) / force[sliding]
        assert np.median(ratio) == pytest.approx(truth.friction, abs=0.05)  # Coulomb friction while sliding
        assert 0.04 <= speed[middle].mean() <= 0.15
        # Not a straight line: the path leaves its own best-fit line by more than 5 mm.
        points = demo.positions[_stroke_rows(demo, k)]
        centred = points - points.mean(axis=0)
        direction = np.linalg.svd(centred, full_matrices=False)[2][0]
        off_line = centred - np.outer(centred @ direction, direction)
        assert np.linalg.norm(off_line, axis=1).max() > 5e-3


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-seed{c[1]}" for c in CASES])
def test_normals_come_from_the_world_geometry(recordings, case):
    demo = recordings[case]
    truth = demo.truth
    solid = _wiped(demo)
    tool_z = matrix_from_quaternion(demo.orientations)[:, :, 2]
    centres = demo.positions - demo.world_config.tool.radius_m * tool_z
    outward = solid.signed_distance(centres)[1]
    # (The file's positions are period means, its normals at mid-period: 0.5 mm apart at 0.1 m/s.)
    assert np.allclose(truth.normals[truth.in_contact], -outward[truth.in_contact], atol=2e-3)
    # The tool is held roughly perpendicular to the surface (the hand tilts it by a few degrees).
    tilt = np.degrees(np.arccos(np.clip(np.sum(tool_z * truth.normals, axis=1), -1, 1)))
    assert np.percentile(tilt[truth.in_contact], 95) < 8.0
    for k, stroke in enumerate(truth.strokes):
        rows = _stroke_rows(demo, k)
        if truth.surface == "curved":
            assert stroke.normal is None
            assert 25.0 <= stroke.normal_turn_deg <= 45.0
            # A plane pressed on (depth along the mean normal, fitted linearly over the surface) misses the
            # stroke by ~1 cm RMS: a contour, not a slide.
            centred = demo.positions[rows] - demo.positions[rows].mean(axis=0)
            normal = truth.normals[rows].mean(axis=0) / np.linalg.norm(truth.normals[rows].mean(axis=0))
            depth = centred @ normal
            design = np.column_stack([np.ones(len(depth)), centred - np.outer(depth, normal)])
            residual = depth - design @ np.linalg.lstsq(design, depth, rcond=None)[0]
            assert 0.0065 <= np.sqrt(np.mean(residual**2)) <= 0.015
        else:
            table_normal = WorldGeometry(demo.world_config).table_normal
            assert np.allclose(stroke.normal, -table_normal, atol=1e-9)
            assert stroke.normal_turn_deg < 1e-3
            tilt_deg = demo.world_config.table.tilt_deg
            assert math.degrees(math.acos(-stroke.normal[2])) == pytest.approx(tilt_deg, abs=1e-6)


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]}-seed{c[1]}" for c in CASES])
def test_the_sensor_reads_the_applied_wrench_and_the_hand_in_its_frame_with_its_offset(recordings, case):
    demo = recordings[case]
    truth = demo.truth
    R = matrix_from_quaternion(demo.orientations)
    offset = truth.sensor_offset
    force_world = -np.einsum("nij,nj->ni", R, demo.sensor_readings[:, :3] - offset[:3])
    error = force_world - (demo.wrenches_applied[:, :3] + demo.hand_forces)
    assert np.all(np.std(error, axis=0) < 0.25) and np.abs(error).max() < 1.2  # sensor noise 0.2 N
    moment_world = -np.einsum("nij,nj->ni", R, demo.sensor_readings[:, 3:] - offset[3:])
    assert np.abs(moment_world - demo.wrenches_applied[:, 3:]).max() < 0.03
    # In free space the sensor sees the hand (several N) plus its offset: not zero.
    free = np.ones(demo.t.size, dtype=bool)
    for stroke in truth.strokes:  # (the periods around touch-down and lift-off average some contact in)
        free &= (demo.t < stroke.t_on - 0.02) | (demo.t > stroke.t_off + 0.02)
    assert np.linalg.norm(demo.sensor_readings[free, :3] - offset[:3], axis=1).max() > 4.0
    assert 4.0 < truth.operator_force_max_n < 25.0
    assert np.allclose(demo.wrenches_applied[free], 0.0, atol=1e-9)


def test_the_file_has_no_time_column_and_w_first_quaternions(recordings):
    demo = recordings[CASES[0]]
    lines = recording_csv_text(demo).splitlines()
    assert tuple(lines[0].split(",")) == RECORDING_COLUMNS and "t" not in lines[0].split(",")
    table = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    assert table.shape == (demo.t.size, 13)
    assert np.allclose(table[:, 3], demo.orientations[:, 3], atol=1e-5)  # qw first
    assert np.allclose(table[:, 4:7], demo.orientations[:, :3], atol=1e-5)
    assert np.allclose(table[:, 7:], demo.sensor_readings, atol=1e-4, rtol=1e-5)


def test_cli_records_a_kinesthetic_file_its_truth_and_world(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    csv_path, truth_path, world_path = tmp_path / "demo.csv", tmp_path / "truth.json", tmp_path / "world.json"
    code = main(["record", "wipe_flat", "--style", "kinesthetic", "--strokes", "1", "--friction", "0.3", "--seed",
                 "2", "-o", str(csv_path), "--truth", str(truth_path), "--world", str(world_path)])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "1 strokes" in out and "stroke 1: contact" in out and "sensor offset" in out
    assert "--rate 100 --quaternion-order wxyz --wrench measured-on-tool --wrench-frame tool" in out
    header = csv_path.read_text().splitlines()[0]
    assert header == ",".join(RECORDING_COLUMNS)
    truth = json.loads(truth_path.read_text())
    assert truth["scenario"] == "wipe_flat" and truth["friction"] == 0.3 and len(truth["strokes"]) == 1
    assert len(truth["samples"]["in_contact"]) == len(csv_path.read_text().splitlines()) - 1
    world = kinesthetic_world_config("wipe_flat", 2, 0.3)
    assert WorldConfig.from_dict(json.loads(world_path.read_text())) == world


def test_cli_refuses_kinesthetic_options_it_cannot_use(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    assert main(["record", "wipe_moon", "--style", "kinesthetic", "-o", str(tmp_path / "d.csv")]) == 2
    assert "wipe_moon" in capsys.readouterr().err
    assert main(["record", "wipe_flat", "--style", "kinesthetic", "-o", str(tmp_path / "d.json")]) == 2
    assert "must end in .csv" in capsys.readouterr().err
    assert main(["record", "slide_flat", "--strokes", "2", "-o", str(tmp_path / "d.csv")]) == 2
    assert "--style kinesthetic" in capsys.readouterr().err
