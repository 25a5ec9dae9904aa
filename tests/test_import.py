"""Importing recordings: the real KU Leuven contour logs, and synthetic CSVs with a known ground truth."""

from __future__ import annotations

import io
import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from conftest import KULEUVEN_DATA
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from corpus import kinesthetic
from schemas import Demonstration
from schemas.import_options import CsvImportOptions
from services.csv_import import ColumnMap, CsvImportError, demonstration_from_csv
from services.demonstration_files import path_kind
from services.importing import DemonstrationImportError, demonstration_from_json
from skills import preprocess
from skills.quaternions import matrix_from_quaternion, quaternion_angle_between

DATA = KULEUVEN_DATA
TRIALS = ("contour_a_1", "contour_a_2", "contour_b_1", "contour_b_2")
KULEUVEN = {"quaternion_order": "wxyz", "wrench_convention": "measured-on-tool", "tare": False}  # compensated files


# --------------------------------------------------------------------------- the real recordings


@pytest.fixture(scope="module")
def real() -> dict[str, dict[str, Demonstration]]:
    """Each trial imported from the TCP-frame wrench columns and from the world-frame ones."""
    assert DATA.is_dir(), f"the KU Leuven recordings are part of the repository: {DATA}"
    return {
        name: {
            frame: demonstration_from_csv(DATA / f"{name}.csv", CsvImportOptions(wrench_frame=frame, **KULEUVEN))
            for frame in ("tool", "world")
        }
        for name in TRIALS
    }


def _raw(name: str) -> dict[str, np.ndarray]:
    table = np.loadtxt(DATA / f"{name}.csv", delimiter=",", skiprows=1)
    return {
        "t": table[:, 0],
        "q": preprocess.quaternions_scalar_last(table[:, 4:8], "wxyz"),
        "wrench_tcp": table[:, 8:14],
        "wrench_world": table[:, 14:20],
    }


@pytest.mark.parametrize("name", TRIALS)
def test_real_time_is_uniform_and_strictly_increasing(real, name):
    demo = real[name]["tool"]
    t = np.asarray(demo.t)
    assert np.all(np.diff(t) > 0)
    assert demo.metadata.resampled_rate_hz == pytest.approx(200.0)  # the wrench's 5 ms period
    np.testing.assert_allclose(np.diff(t), 1 / 200, rtol=1e-6)
    raw_t = _raw(name)["t"]
    assert t[0] >= raw_t[0] and t[-1] <= raw_t[-1] and t[-1] - t[0] > raw_t[-1] - raw_t[0] - 0.05


@pytest.mark.parametrize("name", TRIALS)
def test_real_quaternions_are_unit_and_sign_continuous(real, name):
    q = np.asarray(real[name]["tool"].orientations)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0.99)  # no flips, and 200 Hz steps are small
    raw_q = _raw(name)["q"]
    assert np.any(np.sum(raw_q[1:] * raw_q[:-1], axis=1) < 0), "the raw files DO flip sign (README)"


@pytest.mark.parametrize("name", TRIALS)
def test_real_wrench_is_applied_by_tool_pushing_down_into_the_contour(real, name):
    forces = np.asarray(real[name]["tool"].wrenches)[:, :3]
    assert np.mean(forces[:, 2] < 0) > 0.99
    mean_direction = forces.mean(axis=0) / np.linalg.norm(forces.mean(axis=0))
    assert mean_direction[2] < -0.9
    raw_mean = _raw(name)["wrench_world"][:, :3].mean(axis=0)
    assert raw_mean[2] > 0, "the recording holds the reaction (points up): the importer negates it"


@pytest.mark.parametrize("name", TRIALS)
def test_real_tool_frame_columns_rotate_onto_the_world_columns(name):
    """The frame conversion itself, row by row: R(q) * wrench_tcp equals the file's world columns to its rounding."""
    raw = _raw(name)
    world = preprocess.wrenches_tool_to_world(raw["wrench_tcp"], raw["q"])
    difference = np.abs(world - raw["wrench_world"])
    # 6 significant digits in the file (wrench and quaternion): about 1e-4 N at 20-30 N
    assert difference[:, :3].max() < 2e-4 and difference[:, 3:].max() < 1e-5


@pytest.mark.parametrize("name", TRIALS)
def test_real_import_from_tool_columns_matches_import_from_world_columns(real, name):
    """Through the whole importer, tool-frame vs world-frame columns.

    Not equal to rounding: the file's world columns were rotated with the pose HELD since its
    last 30 Hz update, while the importer rotates on the grid with the slerped pose (the held
    value is not a measurement). The difference is |f| times the pose staleness (< 35 ms of
    turning): RMS about 0.1 N of a 17 N mean force.
    """
    tool = np.asarray(real[name]["tool"].wrenches)
    world = np.asarray(real[name]["world"].wrenches)
    assert real[name]["tool"].t == real[name]["world"].t
    difference = np.linalg.norm(tool[:, :3] - world[:, :3], axis=1)
    assert np.sqrt(np.mean(difference**2)) < 0.25
    assert np.max(difference) < 0.6
    assert np.max(np.abs(tool[:, 3:] - world[:, 3:])) < 0.01  # N·m; moments are small here
    cos = np.sum(tool[:, :3] * world[:, :3], axis=1) / np.linalg.norm(tool[:, :3], axis=1)
    assert np.degrees(np.arccos(np.clip(cos / np.linalg.norm(world[:, :3], axis=1), -1, 1))).max() < 3.0


@pytest.mark.parametrize("name", TRIALS)
def test_real_metadata_records_the_conversions(real, name):
    meta = real[name]["tool"].metadata
    assert meta.name == name and meta.source == f"csv:{name}.csv"
    assert meta.quaternion_order_on_import == "wxyz"
    assert meta.wrench_convention_on_import == "measured-on-tool"
    assert meta.wrench_frame_on_import == "tool"
    assert meta.force_offset_removed is None and meta.tare == "off"  # compensated by the authors' calibration
    assert meta.extra["columns"]["fx"] == "fx_tcp" and real[name]["world"].metadata.extra["columns"]["fx"] == "fx_w"
    notes = " | ".join(meta.extra["import_notes"])
    assert "tare off" in notes and "event-driven log" in notes and "resampled to 200 Hz" in notes


HINT = "check how the wrench is read"


def hints(demonstration) -> list[str]:
    return [note for note in demonstration.metadata.extra["import_notes"] if note.startswith(HINT)]


def test_real_reaction_imported_as_applied_gets_a_sign_hint(real):
    """The sensor's reaction read as the wrench the tool applies presses UP; the note names the other sign, the one
    reading that presses down leaning towards the motion as friction makes it."""
    [hint] = hints(demonstration_from_csv(DATA / "contour_a_1.csv", CsvImportOptions(wrench_frame="tool")))
    assert "read with --wrench measured-on-tool it presses" in hint and "below the horizontal" in hint, hint
    assert "--wrench-frame world it" not in hint and "--quaternion-order" not in hint, hint
    assert hints(real["contour_a_1"]["tool"]) == []


def test_real_tool_frame_wrench_read_with_the_wrong_quaternion_order_gets_a_hint_naming_it(real):
    """Read with the quaternion order wrong (the columns mapped w, x, y, z as x, y, z, w), the tool-frame wrench is
    turned into the world wrongly and presses UP on three of the four trials: the note names the other quaternion
    order, which presses down leaning with friction, and not the other sign. A world-frame wrench read with the
    wrong sign gets a note naming the sign alone."""
    wrong_order = {"wrench_convention": "measured-on-tool", "wrench_frame": "tool",
                   "columns": "qx=tcp_qw,qy=tcp_qx,qz=tcp_qy,qw=tcp_qz"}  # fmt: skip
    hinted = []
    for name in TRIALS:
        hint = hints(demonstration_from_csv(DATA / f"{name}.csv", CsvImportOptions(**wrong_order)))
        if hint:
            assert "read with --quaternion-order wxyz (--columns for named ones) it presses" in hint[0], hint
            hinted.append(name)
        assert hints(real[name]["tool"]) == []
    assert hinted == ["contour_a_2", "contour_b_1", "contour_b_2"]
    [hint] = hints(demonstration_from_csv(DATA / "contour_a_1.csv", CsvImportOptions(wrench_frame="world")))
    assert "read with --wrench measured-on-tool it presses" in hint and "--quaternion-order" not in hint, hint


def test_real_position_path_matches_the_readme(real):
    for name in TRIALS:
        p = np.asarray(real[name]["tool"].positions)
        path_length = np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))
        assert 0.45 < path_length < 0.65, (name, path_length)


# --------------------------------------------------------------------------- synthetic ground truth


def _truth(t: np.ndarray):
    """Smooth pose (m, scalar-last) and applied world wrench (N, N·m) at times ``t`` (s)."""
    positions = np.stack([0.4 + 0.1 * t, 0.05 * np.sin(2 * t), 0.3 + 0.01 * np.cos(3 * t)], axis=1)
    axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    turn = Rotation.from_rotvec(np.outer(0.6 * np.sin(t), axis))
    q = (turn * Rotation.from_euler("x", np.pi)).as_quat()
    forces = np.stack([2 * np.sin(t), np.cos(2 * t), 10 + 3 * np.sin(1.5 * t)], axis=1)
    wrenches = np.hstack([forces, 0.1 * forces[:, ::-1]])
    return positions, preprocess.quaternions_unit_continuous(q), wrenches


HEADER = ["t", "px", "py", "pz", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz"]


def _csv(header: list[str], rows: np.ndarray) -> str:
    out = io.StringIO()
    out.write(",".join(header) + "\n")
    np.savetxt(out, rows, delimiter=",", fmt="%.10g")
    return out.getvalue()


def _angle(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return quaternion_angle_between(p, q)


def test_irregular_duplicated_and_out_of_order_time_stamps_resample_to_the_truth():
    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0.0, 2.0, 1500))
    t[0], t[-1] = 0.0, 2.0
    rows = np.column_stack([t, *_truth(t)])
    exact_copies = rows[rng.choice(1500, 20, replace=False)]  # whole row logged twice
    noisy = rows[rng.choice(np.arange(1, 1499), 10, replace=False)].copy()  # same stamp, another reading
    noisy[:, 8:11] += rng.normal(0, 0.05, (10, 3))
    table = np.vstack([rows, exact_copies, noisy])
    table = table[np.argsort(table[:, 0], kind="stable")]
    late = table[[400, 800, 1200]].copy()
    late[:, 0] -= 0.02  # three rows stamped 20 ms too early: out of order where they sit
    table = np.insert(table, [401, 801, 1201], late, axis=0)

    demo = demonstration_from_csv(_csv(HEADER, table), CsvImportOptions(rate_hz=100.0))
    a = demo.arrays()
    np.testing.assert_allclose(np.diff(a.t), 0.01, rtol=1e-9)
    positions, q, wrenches = _truth(a.t)
    assert np.abs(a.positions - positions).max() < 1e-5
    assert _angle(a.orientations, q).max() < 1e-4
    assert np.abs(a.wrenches - wrenches).max() < 0.05
    notes = " | ".join(demo.metadata.extra["import_notes"])
    assert "3 rows stamped earlier than a previous row were dropped" in notes
    assert "averaged" in notes and "repeat the previous row's time stamp" in notes


def test_event_driven_log_uses_only_real_measurements():
    """Pose at 30 Hz, wrench at 200 Hz, one row per event repeating the other group: the truth is recovered."""
    pose_t = np.arange(0.0, 3.0, 1 / 30)
    wrench_t = np.arange(0.0013, 3.0, 1 / 200)
    t = np.union1d(pose_t, wrench_t)
    last_pose = pose_t[np.searchsorted(pose_t, t, side="right") - 1]
    last_wrench = wrench_t[np.clip(np.searchsorted(wrench_t, t, side="right") - 1, 0, None)]
    p, q, _ = _truth(last_pose)
    _, _, w = _truth(last_wrench)
    demo = demonstration_from_csv(_csv(HEADER, np.column_stack([t, p, q, w])))
    a = demo.arrays()
    assert demo.metadata.resampled_rate_hz == pytest.approx(200.0)
    p_true, q_true, w_true = _truth(a.t)
    error = np.linalg.norm(a.positions - p_true, axis=1).max()
    held_error = np.linalg.norm(_truth(pose_t[np.searchsorted(pose_t, a.t, side="right") - 1])[0] - p_true, axis=1)
    assert error < 2e-4 and held_error.max() > 3e-3  # cubic over the real samples vs a 30 Hz staircase
    assert _angle(a.orientations, q_true).max() < 2e-3
    assert np.abs(a.wrenches - w_true).max() < 0.01


def test_a_real_hold_stays_constant():
    """A regularly sampled log where the robot stands still for 0.5 s: the hold is not a ramp."""
    t = np.arange(0.0, 2.0, 0.002)
    moving = np.clip(t - 0.5, 0.0, None)
    p, q, w = _truth(moving)
    demo = demonstration_from_csv(_csv(HEADER, np.column_stack([t, p, q, w])), CsvImportOptions(tare=False))
    a = demo.arrays()
    still = a.t <= 0.5
    assert np.abs(a.positions[still] - p[0]).max() < 1e-9
    assert demo.metadata.resampled_rate_hz == pytest.approx(500.0)


def test_scalar_first_and_sign_flips():
    t = np.arange(0.0, 2.0, 0.005)
    p, q, w = _truth(t)
    flipped = q * np.where(np.random.default_rng(2).random(t.size) < 0.3, -1.0, 1.0)[:, None]
    wxyz = np.column_stack([flipped[:, 3], flipped[:, :3]])
    numbered = ["t", "px", "py", "pz", "q0", "q1", "q2", "q3", "fx", "fy", "fz", "mx", "my", "mz"]
    text = _csv(numbered, np.column_stack([t, p, wxyz, w]))
    demo = demonstration_from_csv(text, CsvImportOptions(quaternion_order="wxyz"))
    a = demo.arrays()
    assert demo.metadata.quaternion_order_on_import == "wxyz"
    assert np.all(np.sum(a.orientations[1:] * a.orientations[:-1], axis=1) > 0)
    assert _angle(a.orientations, _truth(a.t)[1]).max() < 1e-6  # the grid is the file's: only CSV rounding
    # named scalar-first columns need no option; an option contradicting the names is refused
    named = ["t", "px", "py", "pz", "qw", "qx", "qy", "qz", "fx", "fy", "fz", "mx", "my", "mz"]
    named_text = _csv(named, np.column_stack([t, p, wxyz, w]))
    assert demonstration_from_csv(named_text).orientations == demo.orientations
    with pytest.raises(CsvImportError, match="named in wxyz order"):
        demonstration_from_csv(named_text, CsvImportOptions(quaternion_order="xyzw"))
    with pytest.raises(CsvImportError, match="q0, q1, q2, q3 are numbered"):
        demonstration_from_csv(text)


def test_measured_on_tool_in_the_tool_frame_is_converted_to_applied_in_world():
    t = np.arange(0.0, 2.0, 0.005)
    p, q, w_world = _truth(t)
    R = Rotation.from_quat(q)
    w_tool_measured = -np.hstack([R.inv().apply(w_world[:, :3]), R.inv().apply(w_world[:, 3:])])
    text = _csv(HEADER, np.column_stack([t, p, q, w_tool_measured]))
    demo = demonstration_from_csv(text, CsvImportOptions(wrench_convention="measured-on-tool", wrench_frame="tool"))
    np.testing.assert_allclose(demo.arrays().wrenches, _truth(demo.arrays().t)[2], atol=1e-6)


@cache
def _kinesthetic(seed: int) -> tuple[kinesthetic.KinestheticDemo, str]:
    demo = kinesthetic.kinesthetic_wipe("tilted", n_strokes=3, friction=0.3, seed=seed)
    return demo, kinesthetic.recording_csv_text(demo)


REAL_FORMAT = {
    "rate_hz": 100.0,
    "quaternion_order": "wxyz",
    "wrench_convention": "measured-on-tool",
    "wrench_frame": "tool",
}


@pytest.mark.parametrize("seed", [0, 1])
def test_sensor_offset_is_fitted_in_the_sensor_frame_over_every_free_stretch(seed):
    """A wrist sensor's offset turns with the tool; the hand pushes the arm in free space."""
    truth, text = _kinesthetic(seed)
    demo = demonstration_from_csv(text, CsvImportOptions(**REAL_FORMAT))
    meta = demo.metadata
    assert meta.force_offset_frame == "tool"
    error = np.linalg.norm(np.asarray(meta.force_offset_removed[:3]) - truth.truth.sensor_offset[:3])
    assert error < 0.5, f"offset off by {error:.2f} N (offset {np.linalg.norm(truth.truth.sensor_offset[:3]):.2f} N)"
    # Before, between the three strokes and after: every free stretch is used, not only the ends.
    assert len(meta.extra["tare"]["stretches_s"]) == 4
    assert meta.extra["tare"]["arm_damping_n_s_m"] > 5.0  # the hand's push explained by the arm's motion
    assert "sensor offset removed" in " ".join(meta.extra["import_notes"])
    untared = demonstration_from_csv(text, CsvImportOptions(**REAL_FORMAT, tare=False))
    assert untared.metadata.force_offset_removed is None


def test_given_offset_and_tare_window_act_on_the_file_columns():
    truth, text = _kinesthetic(0)
    offset = truth.truth.sensor_offset
    given = demonstration_from_csv(text, CsvImportOptions(**REAL_FORMAT, force_offset=offset[:3].tolist()))
    assert given.metadata.force_offset_removed[:3] == pytest.approx(offset[:3].tolist())
    assert given.metadata.force_offset_frame == "tool"
    rows = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1)
    window = demonstration_from_csv(text, CsvImportOptions(**REAL_FORMAT, tare_window_s=(0.0, 0.8)))
    expected = np.median(rows[: round(0.8 * 100) + 1, 7:13], axis=0)
    np.testing.assert_allclose(window.metadata.force_offset_removed, expected, atol=1e-9)
    assert "tare window 0-0.8 s" in " ".join(window.metadata.extra["import_notes"])
    with pytest.raises(CsvImportError, match="either a tare window or a force offset"):
        demonstration_from_csv(
            text, CsvImportOptions(**REAL_FORMAT, tare_window_s=(0.0, 0.8), force_offset=[1.0, 2.0, 3.0])
        )
    with pytest.raises(CsvImportError, match="tare window: 50-60 s holds 0 samples"):
        demonstration_from_csv(text, CsvImportOptions(**REAL_FORMAT, tare_window_s=(50.0, 60.0)))
    with pytest.raises(CsvImportError, match="force offset: 3 forces"):
        demonstration_from_csv(text, CsvImportOptions(**REAL_FORMAT, force_offset=[1.0, 2.0]))


def test_no_free_space_means_an_unknown_offset_and_a_failed_check() -> None:
    """The KU Leuven files are cut to the contact: imported asking for a tare there is no free space to fit it over.
    Nothing is removed, the metadata says the tare was impossible, and the skill's sensor_offset check FAILS (an
    offset or a tool's weight of unknown size may be in every force) instead of being skipped; with --no-tare (the
    files are compensated) it passes, as given."""
    from skills.parameterize import learn_skill

    asked = demonstration_from_csv(DATA / "contour_a_1.csv", CsvImportOptions(**{**KULEUVEN, "tare": True}))
    assert asked.metadata.force_offset_removed is None and asked.metadata.tare == "impossible"
    assert "no free-space part" in " ".join(asked.metadata.extra["import_notes"])
    [check] = [c for c in learn_skill(asked).checks if c.name.value == "sensor_offset"]
    assert not check.passed and "no free space" in check.message and "--no-tare" in check.message
    declared = demonstration_from_csv(DATA / "contour_a_1.csv", CsvImportOptions(**KULEUVEN))
    [check] = [c for c in learn_skill(declared).checks if c.name.value == "sensor_offset"]
    assert check.passed and "--no-tare" in check.message


def test_column_spec_and_common_names():
    t = np.arange(0.0, 1.0, 0.005)
    p, q, w = _truth(t)
    header = ["Time [s]", "X (m)", "Y (m)", "Z (m)", "quat_x", "quat_y", "quat_z", "quat_w", "Force_X", "Force_Y",
              "Force_Z", "my_torque_a", "my_torque_b", "my_torque_c"]  # fmt: skip
    text = _csv(header, np.column_stack([t, p, q, w]))
    spec = "mx=my_torque_a, my=my_torque_b, mz=my_torque_c"
    assert ColumnMap.parse(spec) == ColumnMap(mx="my_torque_a", my="my_torque_b", mz="my_torque_c")
    demo = demonstration_from_csv(text, CsvImportOptions(columns=spec))
    assert demo.metadata.extra["columns"]["t"] == "Time [s]" and demo.metadata.extra["columns"]["mz"] == "my_torque_c"
    np.testing.assert_allclose(demo.arrays().wrenches[:, 3:], _truth(demo.arrays().t)[2][:, 3:], atol=1e-6)
    without_moments = demonstration_from_csv(_csv(header[:11], np.column_stack([t, p, q, w[:, :3]])))
    assert np.all(without_moments.arrays().wrenches[:, 3:] == 0)
    assert "moments set to zero" in " ".join(without_moments.metadata.extra["import_notes"])


# --------------------------------------------------------------------------- bad input


def _good_rows(n: int = 200) -> np.ndarray:
    t = np.arange(n) * 0.005
    return np.column_stack([t, *_truth(t)])


def _with_cell(line: int, column: int, value: str) -> str:
    """The good CSV with the cell of 1-based file ``line`` (the header is line 1) in ``column`` replaced."""
    lines = _csv(HEADER, _good_rows()).splitlines()
    cells = lines[line - 1].split(",")
    cells[column] = value
    lines[line - 1] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (_csv([h for h in HEADER if h != "fz"], np.delete(_good_rows(), 10, axis=1)), "missing column for fz"),
        (_with_cell(17, 3, "abc"), "column 'pz' (pz), line 17: 'abc' is not a number"),
        (_with_cell(23, 9, ""), "column 'fy' (fy), line 23: an empty value is not a number"),
        (_with_cell(30, 10, "nan"), "column 'fz' (fz), line 30: 'nan' is not finite"),
        (_with_cell(31, 0, "inf"), "column 't' (t), line 31: 'inf' is not finite"),
        (_csv(HEADER, _good_rows()[:1]), "too few rows: 1 data row"),
        (_csv(HEADER, _good_rows(30)), "too few samples: 30 at"),
        ("", "the file is empty"),
        (_csv(HEADER, _good_rows()).split("\n", 1)[1], "a header row is required"),
        (_csv(HEADER, _good_rows()) + "1,2,3\n", "line 202: 3 fields, the header has 14"),
        (_with_cell(5, 7, "3.0"), "quaternion (qx, qy, qz, qw), line 5: norm"),
    ],
    ids=[
        "missing",
        "non-numeric",
        "empty",
        "nan",
        "inf",
        "one-row",
        "short",
        "empty-file",
        "no-header",
        "ragged",
        "quaternion-norm",
    ],
)
def test_bad_input_names_column_and_line(text, expected):
    with pytest.raises(CsvImportError) as raised:
        demonstration_from_csv(text)
    assert expected in str(raised.value), str(raised.value)
    assert isinstance(raised.value, ValueError)


def test_bad_options_and_specs():
    with pytest.raises(CsvImportError, match="unknown key 'force'"):
        ColumnMap.parse("t=time,force=F")
    with pytest.raises(CsvImportError, match="is not key=column"):
        ColumnMap.parse("t")
    text = _csv(HEADER, _good_rows())
    with pytest.raises(CsvImportError, match="column 'Force_Z' given for fz is not in the header"):
        demonstration_from_csv(text, CsvImportOptions(columns="fz=Force_Z"))
    with pytest.raises(CsvImportError, match="rate"):
        demonstration_from_csv(text, CsvImportOptions(rate_hz=0.0))
    with pytest.raises(ValidationError, match=r"reaction"):
        CsvImportOptions(wrench_convention="reaction")
    with pytest.raises(CsvImportError, match=r"cannot read"):
        demonstration_from_csv(Path("/nonexistent/demo.csv"))


def test_tool_frame_columns_hint_the_option():
    header = [h if h[0] not in "fm" else f"{h}_tcp" for h in HEADER]
    with pytest.raises(CsvImportError, match="the file has a tool-frame wrench: pass wrench_frame='tool'"):
        demonstration_from_csv(_csv(header, _good_rows()))
    assert demonstration_from_csv(_csv(header, _good_rows()), CsvImportOptions(wrench_frame="tool")).n_samples > 50


def test_json_round_trip_and_field_errors(tmp_path):
    demo = demonstration_from_csv(_csv(HEADER, _good_rows()))
    path = tmp_path / "demo.json"
    path.write_text(demo.model_dump_json())
    assert demonstration_from_json(path) == demo
    broken = demo.model_dump()
    broken["orientations"][3] = [0.0, 0.0, 0.0, 2.0]
    path.write_text(json.dumps(broken))
    with pytest.raises(DemonstrationImportError, match="orientations: quaternion at sample 3"):
        demonstration_from_json(path)
    with pytest.raises(DemonstrationImportError, match="cannot read"):
        demonstration_from_json(tmp_path / "missing.json")


def test_the_command_line_tells_a_files_kind_once_and_imports_it_through_the_one_dispatcher(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``contact-skills learn`` tells what a file holds once (its options are those of its kind) and imports it through
    ``services.importing.demonstration_from_file``, as the API's uploads: the same demonstration as the CSV importer's,
    the options given applied (a measured-on-tool wrench negated)."""
    import argparse

    from cli.import_options import import_demonstration
    from services import importing

    path = tmp_path / "demo.txt"  # not named .csv: told by its content
    path.write_text(_csv(HEADER, _good_rows()))
    told = []
    monkeypatch.setattr(importing, "path_kind", lambda p: told.append(p) or path_kind(p))
    args = argparse.Namespace(wrench_convention="measured-on-tool")
    imported = import_demonstration(path, args)
    assert told == [path]
    expected = demonstration_from_csv(path, CsvImportOptions(wrench_convention="measured-on-tool"))
    np.testing.assert_array_equal(imported.wrenches, expected.wrenches)
    np.testing.assert_allclose(-np.asarray(imported.wrenches)[:, 2], _truth(np.asarray(imported.t))[2][:, 2], atol=0.5)


# --------------------------------------------------------------------------- files without a time column

NO_TIME_HEADER = ["px", "py", "pz", "qw", "qx", "qy", "qz", "fx", "fy", "fz", "mx", "my", "mz"]
"""A kinesthetic recording at a fixed rate: no time column, scalar-first quaternion columns."""


def _no_time_rows(n: int = 300, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(true t, rows): the robot holds still for the first 0.5 s, then moves; quaternions w-first."""
    t = np.arange(n) * dt
    p, q, w = _truth(np.clip(t - 0.5, 0.0, None))
    return t, np.column_stack([p, q[:, 3], q[:, :3], w])


def test_file_without_time_column_takes_rows_as_samples_at_the_given_rate():
    t, rows = _no_time_rows()
    text = _csv(NO_TIME_HEADER, rows)
    by_rate = demonstration_from_csv(text, CsvImportOptions(rate_hz=100.0, tare=False))
    by_dt = demonstration_from_csv(text, CsvImportOptions(dt_s=0.01, tare=False))
    both = demonstration_from_csv(text, CsvImportOptions(rate_hz=100.0, dt_s=0.01, tare=False))
    assert by_rate.t == by_dt.t == both.t
    np.testing.assert_allclose(by_rate.t, t, rtol=0, atol=1e-12)  # t = row * dt from 0
    a = by_dt.arrays()
    assert a.t.size == rows.shape[0]  # every row is a sample: the 0.5 s hold is not an event-log repeat
    np.testing.assert_allclose(a.positions, rows[:, :3], atol=1e-9)
    _, q, w = _truth(np.clip(t - 0.5, 0.0, None))
    assert _angle(a.orientations, q).max() < 1e-6  # wxyz columns became scalar-last
    np.testing.assert_allclose(a.wrenches, w, atol=1e-8)
    meta = by_dt.metadata
    assert meta.quaternion_order_on_import == "wxyz" and meta.resampled_rate_hz is None
    assert "t" not in meta.extra["columns"]
    assert meta.extra["import_notes"][0] == "no time column: rows taken as samples at 100 Hz (dt 0.01 s)"


def test_file_without_time_column_needs_rate_or_dt():
    _, rows = _no_time_rows()
    with pytest.raises(CsvImportError) as raised:
        demonstration_from_csv(_csv(NO_TIME_HEADER, rows))
    message = str(raised.value)
    assert message.startswith("missing column for t (time): none of t, time, timestamp")
    assert "pass --rate HZ or --dt SECONDS" in message and len(raised.value.problems) == 1


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        ({"dt_s": 0.0}, "dt: 0.0 s is not a positive time step"),
        ({"dt_s": -0.01}, "dt: -0.01 s is not a positive time step"),
        ({"dt_s": float("nan")}, "dt: nan s is not a positive time step"),
        ({"rate_hz": float("nan")}, "rate: nan Hz is not a rate"),
        ({"rate_hz": 100.0, "dt_s": 0.02}, "rate and dt disagree: rate 100 Hz is a step of 0.01 s, dt 0.02 s is 50 Hz"),
    ],
    ids=["dt-zero", "dt-negative", "dt-nan", "rate-nan", "disagree"],
)
def test_bad_rate_or_dt_is_refused(options, expected):
    _, rows = _no_time_rows()
    with pytest.raises(CsvImportError) as raised:
        demonstration_from_csv(_csv(NO_TIME_HEADER, rows), CsvImportOptions(**options))
    assert expected in str(raised.value), str(raised.value)


def test_with_a_time_column_dt_is_the_resampling_step():
    text = _csv(HEADER, _good_rows())  # 200 Hz time stamps
    by_dt = demonstration_from_csv(text, CsvImportOptions(dt_s=0.01))
    by_rate = demonstration_from_csv(text, CsvImportOptions(rate_hz=100.0))
    assert by_dt.t == by_rate.t and by_dt.metadata.resampled_rate_hz == pytest.approx(100.0)
    assert not any("no time column" in note for note in by_dt.metadata.extra["import_notes"])


def test_a_too_long_csv_is_refused_before_it_is_parsed(tmp_path):
    """More rows than a recording may have: refused from a count of its lines, before any row is parsed (the rows
    after the header are not even numbers here), and a file larger than such a recording can be is refused from its
    size before it is read."""
    from services import csv_import

    text = "t,px,py,pz,qx,qy,qz,qw,fx,fy,fz\n" + "not,a,number\n" * (csv_import.MAX_CSV_ROWS + 1)
    with pytest.raises(CsvImportError, match=rf"too many rows: {csv_import.MAX_CSV_ROWS + 2} lines, at most"):
        demonstration_from_csv(text)
    huge = tmp_path / "huge.csv"
    with huge.open("wb") as f:
        f.truncate(csv_import.MAX_CSV_BYTES + 1)  # a sparse file: nothing written, its size is what is checked
    with pytest.raises(CsvImportError, match="MB, larger than the 400 MB a recording"):
        demonstration_from_csv(huge)


# --------------------------------------------------------------------------- gaps: stretches without measurement


def test_gaps_are_intervals_much_longer_than_the_usual_and_merge_into_disjoint_ones():
    t = np.r_[np.arange(0.0, 1.0, 0.01), np.arange(1.3, 2.0, 0.01), 2.05, 2.5]
    gaps = preprocess.unmeasured_intervals(t)
    np.testing.assert_allclose(gaps, [[0.99, 1.3], [2.05, 2.5]])  # 0.06 s is 6 intervals but under MIN_GAP_S
    assert preprocess.unmeasured_intervals(np.arange(0.0, 5.0, 0.035)).shape == (0, 2)
    merged = preprocess.merged_intervals([[3.0, 4.0], [0.0, 1.0], [0.5, 2.0], [1.5, 1.8], [4.0, 4.5]])
    np.testing.assert_allclose(merged, [[0.0, 2.0], [3.0, 4.5]])
    assert preprocess.merged_intervals(np.zeros((0, 2))).shape == (0, 2)


def test_a_value_repeated_up_to_a_stretch_without_rows_is_no_hold():
    """An event log's repeats stop where its rows stop: the value before a stretch with no rows at all was not held
    through it (a hold's repeated rows span the hold)."""
    t = np.r_[np.arange(0.0, 1.0, 0.01), np.arange(1.5, 2.0, 0.01)]
    values = np.repeat(np.arange(t.size // 5, dtype=float), 5)[: t.size, None]  # a new value every 5 rows
    values = np.vstack([values, np.full((t.size - values.shape[0], 1), values[-1, 0])])
    group = preprocess.channel_group_samples(t, values)
    assert group.n_holds == 0
    np.testing.assert_allclose(preprocess.unmeasured_intervals(group.t), [[0.95, 1.5]], atol=1e-9)


def _without_rows(name: str, t0: float, t1: float) -> str:
    """The KU Leuven file ``name`` with its rows from ``t0`` to ``t1`` s left out, as a tracker and a logger that
    stalled together would leave it."""
    lines = (DATA / f"{name}.csv").read_text().splitlines()
    kept = [line for line in lines[1:] if not t0 <= float(line.split(",", 1)[0]) <= t1]
    return "\n".join([lines[0], *kept]) + "\n"


def test_a_real_recording_with_a_gap_says_so_and_its_skill_fails_its_unmeasured_contact_check():
    """0.3 s of contour_a_1 left out: the import resamples across it as before, and now notes it, records it in the
    metadata, and the skill (whose contact crosses it) fails ``unmeasured_contact`` and nothing else; without the
    gap it passes. Over 1 s the motion is unknown: the import refuses it, naming the channel and the stretch (the
    learner refuses the same gap in a JSON demonstration)."""
    from skills.parameterize import learn_skill

    options = CsvImportOptions(**KULEUVEN, wrench_frame="tool")
    gapped = demonstration_from_csv(_without_rows("contour_a_1", 2.0, 2.3), options)
    [[start, end]] = gapped.metadata.unmeasured_intervals_s
    assert 1.95 < start < 2.0 and 2.3 < end < 2.35, (start, end)  # the last pose before, the first wrench after
    notes = " | ".join(gapped.metadata.extra["import_notes"])
    assert "no measurement of the pose or the wrench for 0.31 s in 1 gap(s)" in notes and "holds" not in notes
    skill = learn_skill(gapped)
    assert [c.name.value for c in skill.checks if not c.passed] == ["unmeasured_contact"]
    [check] = [c for c in skill.checks if c.name.value == "unmeasured_contact"]
    assert check.value == pytest.approx(end - start) and "interpolation" in check.message
    whole = demonstration_from_csv(DATA / "contour_a_1.csv", options)
    assert whole.metadata.unmeasured_intervals_s == []
    assert all(c.passed for c in learn_skill(whole).checks)
    with pytest.raises(CsvImportError, match=r"the pose has no measurement for 1\.2\d s \(1\.99\d*-3\.2\d* s\)"):
        demonstration_from_csv(_without_rows("contour_a_1", 2.0, 3.2), options)


def test_a_json_demonstration_with_a_gap_in_contact_fails_the_check():
    """A Demonstration sent as JSON carries its own time stamps: a stretch of them missing is a gap the same way."""
    from corpus.synthetic import plane_slide
    from skills.parameterize import learn_skill

    d = plane_slide(rate_hz=200.0)
    middle = 0.5 * (d.contact_on_s + d.contact_off_s)
    keep = (d.t < middle) | (d.t > middle + 0.4)
    demo = Demonstration.from_arrays(d.t[keep], d.positions[keep], d.orientations[keep], d.wrenches[keep])
    [check] = [c for c in learn_skill(demo).checks if c.name.value == "unmeasured_contact"]
    assert not check.passed and check.value == pytest.approx(np.diff(d.t[keep]).max(), abs=1e-9)  # 0.4 s and a step
    whole = Demonstration.from_arrays(d.t, d.positions, d.orientations, d.wrenches)
    assert all(c.passed for c in learn_skill(whole).checks if c.name.value == "unmeasured_contact")


@pytest.mark.parametrize(("per_second", "unit"), [(1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")])
def test_epoch_stamps_in_another_unit_are_refused_naming_it(per_second: float, unit: str):
    """A logger's stamps since 1970 in ms, µs or ns (ROS's are ns) read as seconds: refused, the unit named."""
    t = (1.7e9 + np.arange(100) * 0.01) * per_second
    rows = "\n".join(f"{stamp:.0f},0.5,0,0.2,0,0,0,1,0,0,-5,0,0,0" for stamp in t)
    with pytest.raises(DemonstrationImportError, match=f"beyond the plausible ±1e\\+10 s \\(in {unit} since 1970"):
        demonstration_from_csv("t,x,y,z,qx,qy,qz,qw,fx,fy,fz,mx,my,mz\n" + rows)


def test_a_demonstrations_gaps_must_be_finite_intervals_in_order():
    from schemas import DemonstrationMetadata

    assert DemonstrationMetadata(unmeasured_intervals_s=[(1.0, 1.5)]).unmeasured_intervals_s == [(1.0, 1.5)]
    for bad, reason in (
        ([(1.0, float("nan"))], "interval 0 is not finite"),
        ([(0.0, 0.1), (2.0, 1.0)], "interval 1 ends before"),
    ):
        with pytest.raises(ValidationError, match=reason):
            DemonstrationMetadata(unmeasured_intervals_s=bad)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start=st.floats(min_value=0.0, max_value=1.8e9, allow_nan=False),
    rows=st.integers(min_value=60, max_value=3000),
    rate=st.floats(min_value=50.0, max_value=1000.0),
    jitter=st.floats(min_value=0.0, max_value=0.3),
    seed=st.integers(min_value=0, max_value=2**16),
)
@example(start=1.899, rows=9702, rate=1000.0, jitter=0.0, seed=0)  # the README's recording, shifted
@example(start=2.998, rows=150, rate=1000.0, jitter=0.0, seed=0)
@example(start=100.123, rows=801, rate=1000.0, jitter=0.0, seed=0)
def test_a_recording_imports_whatever_its_first_stamp_rows_rate_and_jitter(
    start: float, rows: int, rate: float, jitter: float, seed: int
) -> None:
    """Property (issue 41): a CSV whose clock does not start at 0 imports like one that does — the README's own
    recording shifted to start at 1.899 s once gave a LinAlgError (its uniform grid ended at 11.600000000000001,
    past the last stamp 11.6, where the positions' interpolation is NaN), and 101-201 rows a false "row 100 is not
    finite". Stamps up to Unix-epoch seconds, 60-3000 rows, 50-1000 Hz, jitter up to 0.3 periods: every sample of
    the result is finite and the grid never passes the last stamp."""
    rng = np.random.default_rng(seed)
    nominal = np.arange(rows) / rate
    nominal[1:-1] += rng.uniform(-jitter, jitter, rows - 2) / rate
    positions, q, wrenches = _truth(nominal)
    wrenches[:, 2] *= -1.0  # pressing down: a force pointing up would have the import try its other readings
    stamps = start + nominal
    values = np.column_stack([positions, q, wrenches])
    # Stamps as loggers write them, to the microsecond: 1.899 + 9.701 is then exactly the last stamp, 11.600000.
    lines = (f"{stamp:.6f}," + ",".join(f"{v:.9g}" for v in row) for stamp, row in zip(stamps, values, strict=True))
    text = ",".join(HEADER) + "\n" + "\n".join(lines) + "\n"
    demo = demonstration_from_csv(text, CsvImportOptions(tare=False))
    a = demo.arrays()
    assert np.all(np.isfinite(a.positions)) and np.all(np.isfinite(a.wrenches))
    assert a.t[-1] <= stamps[-1] + 1e-6 * max(1.0, stamps[-1]) and len(a.t) >= rows // 2


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start=st.floats(min_value=0.0, max_value=1.8e9, allow_nan=False),
    rate=st.floats(min_value=100.0, max_value=1000.0),
    jitter=st.floats(min_value=0.0, max_value=0.3),
    seed=st.integers(min_value=0, max_value=2**16),
)
@example(start=1.899, rate=1000.0, jitter=0.0, seed=0)
def test_a_json_demonstration_learns_whatever_its_first_stamp_rate_and_jitter(
    start: float, rate: float, jitter: float, seed: int
) -> None:
    """Property (issue 41, the JSON importer's share): a JSON `Demonstration` is taken as it is, and learning resamples
    it; with stamps from 0 to Unix-epoch seconds, 100-1000 Hz and jitter up to 0.3 periods, the tilted slide it holds
    is learned as that slide — one contact segment whose compliant frame's z is the true normal within 3° and whose
    force is the taught 15 N within 1 N — never a traceback."""
    from corpus import synthetic
    from schemas import SkillType
    from schemas.skill import SegmentKind
    from skills.parameterize import learn_skill

    normal = np.array([np.sin(np.radians(10.0)), 0.0, -np.cos(np.radians(10.0))])
    truth = synthetic.plane_slide(normal=tuple(normal), seed=0)
    rows = int(truth.t[-1] * rate) + 1
    rng = np.random.default_rng(seed)
    nominal = np.arange(rows) / rate
    nominal[1:-1] += rng.uniform(-jitter, jitter, rows - 2) / rate
    index = np.minimum(np.searchsorted(truth.t, nominal), truth.t.size - 1)  # the truth's sample at each stamp
    stamps = start + nominal
    if np.any(np.diff(stamps) <= 0):  # epoch-sized stamps round a 1 ms step away: nothing to learn from
        return
    text = json.dumps({
        "t": stamps.tolist(), "positions": truth.positions[index].tolist(),
        "orientations": truth.orientations[index].tolist(), "wrenches": truth.wrenches[index].tolist(),
    })  # fmt: skip
    skill = learn_skill(demonstration_from_json(text))
    assert skill.skill_type is SkillType.slide
    contact = [s for s in skill.segments if s.kind is SegmentKind.contact]
    assert len(contact) == 1
    z = matrix_from_quaternion(contact[0].compliant_frames.orientations[0])[:, 2]
    assert np.degrees(np.arccos(np.clip(z @ normal, -1.0, 1.0))) < 3.0
    assert abs(contact[0].force_constant_n - truth.target_force_n) < 1.0
