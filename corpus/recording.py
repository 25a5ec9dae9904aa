"""Human-like corpus cases as a hand-guided arm's wrist sensor records them: a CSV file with a time column.

A case is simulated at `FINE_RATE_HZ`; the hand's push on the arm (`corpus.kinesthetic.operator_forces`) and the
wrist sensor (`corpus.kinesthetic.random_wrist_sensor`, `wrist_sensor_samples`: the reaction in the sensor = tool
frame, with a constant offset of 0.7-2.3 N) are added, and the file's rows are taken at the sensor's rate, with
jittered time stamps and a few repeated and dropped rows when asked. The truth stays at the uniform sample
times ``k / rate`` (see `corpus.case.CorpusCase`).
"""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
from scipy.interpolate import interp1d

from corpus.build import Assembled
from corpus.case import CorpusCase, CsvRecording, sampled_case
from corpus.kinesthetic import OperatorModel, operator_forces, random_wrist_sensor, wrist_sensor_samples
from skills.quaternions import quaternions_slerp

FINE_RATE_HZ = 1000.0
"""Rate human-like cases are simulated at before the sensor samples them, Hz."""
CSV_COLUMNS = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "fx", "fy", "fz", "mx", "my", "mz")
"""Columns of a human-like case's file: time (s), position (m), scalar-first quaternion, sensor-frame wrench."""
JITTER_PERIODS = 0.3
"""Largest time stamp jitter of an irregular file, in sample periods."""
ODD_ROWS = 4
"""Rows dropped, rows repeated (same stamp) and rows repeating the previous values (new stamp) in an irregular file."""


def _file_rows(n: int, irregular: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Which nominal sample each file row stands for (repeats and drops included), and which rows are stale."""
    counts = np.ones(n, dtype=int)
    stale = np.zeros(n, dtype=bool)
    if irregular:
        odd = rng.choice(np.arange(2, n - 2), size=3 * ODD_ROWS, replace=False)
        counts[odd[:ODD_ROWS]] = 0
        counts[odd[ODD_ROWS : 2 * ODD_ROWS]] = 2
        stale[odd[2 * ODD_ROWS :]] = True
    return np.repeat(np.arange(n), counts), np.repeat(stale, counts)


def recorded_case(
    name: str,
    family: str,
    skill_type: str,
    fine: Assembled,
    parameters: dict[str, float],
    rng: np.random.Generator,
    rate_hz: float,
    irregular: bool,
    operator: OperatorModel,
) -> CorpusCase:
    """The `CorpusCase` of ``fine`` (assembled at `FINE_RATE_HZ`) as a wrist sensor at ``rate_hz`` records it.

    The file (``recording.csv_text``): the sensor's reaction wrench in the tool frame with its offset, the
    hand's push and noise, tool poses, and time stamps ``k / rate_hz`` (``irregular``: jittered by up to
    `JITTER_PERIODS` periods, with `ODD_ROWS` rows dropped, repeated, and repeating their predecessor's values).
    The truth arrays are the fine simulation at ``k / rate_hz``; the truth segments are found on the fine grid.
    """
    dt = float(fine.t[1] - fine.t[0])
    hand = operator_forces(fine.t, fine.positions, operator, rng, fine.touching)
    sensor = random_wrist_sensor(rng, rate_hz)
    # Readings at every fine sample without noise (the noise is added to the file's rows).
    exact = replace(sensor, noise_force_n=0.0, noise_torque_nm=0.0, rate_hz=1.0 / dt)
    readings = wrist_sensor_samples(fine.t, fine.positions, fine.orientations, fine.wrenches, hand, exact, rng).readings
    samples = np.arange(0, fine.t.size, round(1.0 / (rate_hz * dt)))
    nominal, stale = _file_rows(samples.size, irregular, rng)
    stamps = fine.t[samples][nominal]
    if irregular:
        jitter = rng.uniform(-JITTER_PERIODS, JITTER_PERIODS, samples.size) / rate_hz
        jitter[[0, -1]] = 0.0
        stamps = stamps + jitter[nominal]
    values = interp1d(fine.t, np.hstack([fine.positions, readings]), axis=0)(stamps)
    quaternions = quaternions_slerp(stamps, fine.t, fine.orientations)
    values[:, 3:6] += rng.normal(0.0, sensor.noise_force_n, (stamps.size, 3))
    values[:, 6:] += rng.normal(0.0, sensor.noise_torque_nm, (stamps.size, 3))
    previous = np.maximum(np.arange(stamps.size) - 1, 0)
    values[stale] = values[previous[stale]]
    quaternions[stale] = quaternions[previous[stale]]
    table = np.column_stack([stamps, values[:, :3], quaternions[:, 3:], quaternions[:, :3], values[:, 3:]])
    text = io.StringIO()
    np.savetxt(text, table, fmt=["%.6f"] + ["%.7g"] * 13, delimiter=",", header=",".join(CSV_COLUMNS), comments="")
    recording = CsvRecording(
        csv_text=text.getvalue(),
        import_options={
            "quaternion_order": "wxyz",
            "wrench_convention": "measured-on-tool",
            "wrench_frame": "tool",
            "rate_hz": rate_hz,
            "name": name,
        },
        sensor_offset=sensor.offset,
        hand_forces=hand[samples],
    )
    parameters = {**parameters, "rate_hz": rate_hz, "irregular": float(irregular)}
    return sampled_case(name, family, skill_type, fine, samples, parameters, recording)
