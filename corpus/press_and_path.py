"""More ground-truth families: unsteady presses, quick and covering wipes on curved parts, a path off any plane, and
a wrist sensor with the artefacts real ones have. Generated (nothing stored), seeded, like `corpus.families`.

World frame, z up, SI units (m, s, N, rad; angles in the docs in deg); quaternions scalar-last; the wrench is the
one the tool APPLIES, world frame, at the tool point; normals point INTO the surface (docs/CONVENTIONS.md). Every
family is a function of a seed (and optional parameters, drawn from the seed when unset) returning a
`corpus.case.CorpusCase` with exact ground truth; every case lasts under ~15 s.

- **Unsteady presses** (slide, analytic like `corpus.families.plane_case`: an ideal applied-by-tool world sensor
  with 0.2 N of noise, 500 Hz; approach and retreat 1-1.5 s from 10 cm; the press's slow wander only ±2 %, so the
  drawn profile is the press). Their truth segments are unsteady (`corpus.case.TruthSegment.steady` False): the
  skill must reproduce the profile, and `corpus.scoring` judges it so; ``force_n`` is the mean true normal force
  over the samples pressing above 30 % of the largest.

  - ``ramp-press`` (`ramp_press_case`): one straight 15 cm stroke (6-10 cm/s) on a plane tilted 0-30 deg about a
    random horizontal axis, the press ramping linearly from 1.5-2.9 N to 16.5-22 N between the touch-down ramp
    and the lift-off ramp (0.3 s each, minimum jerk).
  - ``wobble-press`` (`wobble_press_case`): a straight (15 cm) or L-shaped (two 12 cm legs) stroke at 5-8 cm/s
    on a plane tilted 0-30 deg, pressing 10-14 N wobbling ±4-6 N at 2.5-3.5 Hz (a sine, random phase).

- **Contours** (analytic like `corpus.families.cylinder_case`: a hand's 0.3 mm tremor, ±10 % force wander; the
  contour profile 0.6 -> 1 -> 0.75 of a 10-20 N press, except the curved wipe's steady one; per-sample normals):

  - ``drum-quick`` (`quick_drum_case`): ONE quick wipe across the top of a drum (a horizontal cylinder of radius
    8-15 cm, random yaw), across its axis, the normal turning 40-60 deg, the contact lasting 1.05-1.35 s
    (touch-down to lift-off; 6-25 cm/s), ramps of 0.2 s.
  - ``curved-wipe`` (`curved_wipe_case`): a wipe covering an area of a curved part (a car fender): 3-5 passes
    across a horizontal cylinder of radius 15-30 cm (random yaw), the normal turning 31-50 deg per pass, the
    passes shifted 10-15 mm along the axis one after the other (a pad as wide as the shift wipes a band of
    passes × shift, 30-75 mm), back and forth with rounded turns (slowed to 40 %), in ONE contact at a steady
    10-20 N press (ramps of 0.3 s), 12-18 cm/s. One truth segment: a back-and-forth wipe at a steady press is one
    stroke, and its turns alternate left and right, so its heading never winds a full turn.
  - ``helix`` (`helix_case`): the tool follows a helix round a vertical or a horizontal cylinder of radius 5-10 cm,
    pressing into it (radially), 0.95-1 turn at a pitch of 6.5-8.5 cm per turn, 8-12 cm/s: the normal turns
    342-360 deg and the path leaves any plane by over 11 mm RMS (a pitch of 3-6 cm leaves it by 2-13 mm, over
    10 mm only near a full turn at 6 cm). One truth segment: the segment rules count the heading's winding
    across the contact's mean normal, a radial direction, across which the helix only advances along the axis.

- **Sensor artefacts** (``sensor-artefacts``, `sensor_artefacts_case`, slide): the very recording file of
  ``human-straight`` or ``human-zigzag`` (`corpus.families.human_case`, the same seed; drawn per seed), whose
  wrist sensor also has artefacts real ones have (`with_sensor_artefacts`, on the file's rows): an offset
  drifting linearly by 0.5-1.0 N over the recording (warm-up), one stretch of 0.1-0.2 s in the stroke where one
  force axis saturates (reads a flat level), and 3-6 single-row spikes of 30-80 N on a force axis. The truth is
  the human-like case's: the score difference between the two is the artefacts'.
"""

from __future__ import annotations

import copy
import io
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from corpus.build import (
    UP,
    Fold,
    Piece,
    approach,
    assemble,
    contact_piece,
    retreat,
    rotated,
    speed_profile,
    tilted_plane,
    timed,
)
from corpus.case import CorpusCase, TruthSegment, analytic_case
from corpus.families import human_case
from corpus.recording import CSV_COLUMNS
from corpus.strokes import (
    ANALYTIC_RATE_HZ,
    _analytic,
    _draw,
    _params,
    _profile,
    cylinder_stroke,
    plane_chart,
)
from corpus.synthetic import minimum_jerk

PRESS_AND_PATH_FAMILIES: tuple[str, ...] = (
    "ramp-press",
    "wobble-press",
    "drum-quick",
    "curved-wipe",
    "helix",
    "sensor-artefacts",
)
"""The families of this module, in the order `press_and_path_cases` yields them."""
UNSTEADY_WANDER = 0.02
"""Slow wander (relative, 0.1-0.5 Hz) of an unsteady press: the drawn ramp or wobble is the press's unsteadiness."""
PRESS_RAMP_S = 0.3
"""Touch-down and lift-off ramps of the unsteady presses, s."""
WIPE_TURN = 0.3
"""Share of a pass (in the curved wipe's pass parameter) over which the shift along the axis is made at a turn."""
ARTEFACT_SOURCES = ("human-straight", "human-zigzag")
"""Human-like cases whose recording `sensor_artefacts_case` spoils."""
_CSV_FORMAT = ["%.6f"] + ["%.7g"] * 13
"""The number format `corpus.recording.recorded_case` writes a file's rows with (time, pose, wrench)."""
_FORCE_COLUMNS = slice(8, 11)
"""The file's force columns ``fx, fy, fz`` (sensor frame, measured on the tool, N)."""


def _rng(seed: int, family: str) -> np.random.Generator:
    """The random generator of ``family`` at ``seed`` (streams apart from `corpus.families`' 101-999)."""
    return np.random.default_rng([seed, 400 + PRESS_AND_PATH_FAMILIES.index(family)])


# --------------------------------------------------------------------------- unsteady presses


def _plane_contact(
    plane: Fold, shape: str, rng: np.random.Generator, dt: float, cruise: float, level: Callable[[NDArray], NDArray]
) -> Piece:
    """A ``shape`` stroke (`corpus.strokes.plane_chart`) on ``plane`` sampled at ``dt`` (s): touch-down and lift-off
    at 3-4 cm/s, ``cruise`` (m/s) between (slower at a corner), pressing ``level(t)`` (N at s since touch-down)
    shaped by ramps of `PRESS_RAMP_S` (like `corpus.strokes.plane_stroke`, with a force that varies in time)."""
    param, chart, corners = plane_chart(shape, rng)
    speed = speed_profile(rng.uniform(0.03, 0.04), cruise, rng.uniform(0.03, 0.04), corners)
    t, p = timed(param, plane.points(chart[:, 0], chart[:, 1]), dt, speed)
    u, v = np.interp(p, param, chart[:, 0]), np.interp(p, param, chart[:, 1])
    return contact_piece(plane.points(u, v), plane.inward(u), t, level(t), PRESS_RAMP_S)


def _unsteady_case(name: str, family: str, contact: Piece, params: dict, rng: np.random.Generator) -> CorpusCase:
    """A slide case as `corpus.strokes._analytic` assembles it (approach from 10 cm in 1-1.5 s, ``contact``,
    retreat), the press wandering only by `UNSTEADY_WANDER`, its truth segments unsteady."""
    dt = 1.0 / params["rate_hz"]
    before, after = rng.uniform(1.0, 1.5, 2)
    pieces = [approach(contact, before, 0.1, dt), contact, retreat(contact, after, 0.1, dt)]
    pad, friction = params["pad_stiffness_n_m"], params["friction"]
    case = assemble(pieces, dt, rng, pad, friction, params["tremor_m"], UNSTEADY_WANDER)
    return analytic_case(name, family, "slide", case, params, rng, steady=False)


def ramp_press_case(
    seed: int = 0,
    *,
    tilt_deg: float | None = None,
    start_n: float | None = None,
    end_n: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """One straight 15 cm stroke on a plane tilted by ``tilt_deg`` (0-30 deg), the press ramping linearly from
    ``start_n`` (1.5-2.9 N) to ``end_n`` (16.5-22 N) between the touch-down and the lift-off ramps; slide,
    unsteady truth. Drawn from ``seed`` too: cruise 6-10 cm/s, friction 0.2-0.4, pad 1.5e4-3e4 N/m; a steady
    hand (0.05 mm of tremor, as the plane strokes)."""
    rng = _rng(seed, "ramp-press")
    params = _params(rng, (2.0, 20.0), None, None, rate_hz)
    del params["force_n"]  # no plateau force: the ramp's two ends say the press
    params |= {
        "tilt_deg": _draw(tilt_deg, 0.0, 30.0, rng),
        "force_start_n": _draw(start_n, 1.5, 2.9, rng),
        "force_end_n": _draw(end_n, 16.5, 22.0, rng),
        "cruise_m_s": rng.uniform(0.06, 0.1),
        "ramp_s": PRESS_RAMP_S,
        "tremor_m": 5e-5,
    }
    plane = tilted_plane(params["tilt_deg"], rng)

    def level(t: NDArray) -> NDArray:
        ends = [PRESS_RAMP_S, t[-1] - PRESS_RAMP_S]
        return np.interp(t, ends, [params["force_start_n"], params["force_end_n"]])

    contact = _plane_contact(plane, "straight", rng, 1.0 / rate_hz, params["cruise_m_s"], level)
    return _unsteady_case(f"ramp-press-s{seed}", "ramp-press", contact, params, rng)


def wobble_press_case(
    seed: int = 0,
    *,
    shape: str | None = None,
    mean_n: float | None = None,
    amplitude_n: float | None = None,
    frequency_hz: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """A ``shape`` stroke (``straight`` 15 cm or ``l-shape`` 2 x 12 cm, drawn) on a plane tilted 0-30 deg, pressing
    ``mean_n`` (10-14 N) wobbling by ``amplitude_n`` (4-6 N) at ``frequency_hz`` (2.5-3.5 Hz), a sine of random
    phase from touch-down on, shaped by the touch-down and lift-off ramps; slide, unsteady truth. Drawn from
    ``seed`` too: cruise 5-8 cm/s (2-5 s of contact: 5-18 wobbles), friction 0.2-0.4, pad 1.5e4-3e4 N/m, tremor
    0.3 mm."""
    rng = _rng(seed, "wobble-press")
    params = _params(rng, (10.0, 14.0), None, None, rate_hz)
    params["force_n"] = params["force_n"] if mean_n is None else mean_n  # the wobble's mean
    shape = shape or str(rng.choice(["straight", "l-shape"]))
    params |= {
        "tilt_deg": rng.uniform(0.0, 30.0),
        "l_shape": float(shape == "l-shape"),
        "amplitude_n": _draw(amplitude_n, 4.0, 6.0, rng),
        "frequency_hz": _draw(frequency_hz, 2.5, 3.5, rng),
        "phase_rad": rng.uniform(0.0, 2 * np.pi),
        "cruise_m_s": rng.uniform(0.05, 0.08),
        "ramp_s": PRESS_RAMP_S,
        "tremor_m": 3e-4,
    }
    plane = tilted_plane(params["tilt_deg"], rng)

    def level(t: NDArray) -> NDArray:
        angle = 2 * np.pi * params["frequency_hz"] * t + params["phase_rad"]
        return params["force_n"] + params["amplitude_n"] * np.sin(angle)

    contact = _plane_contact(plane, shape, rng, 1.0 / rate_hz, params["cruise_m_s"], level)
    return _unsteady_case(f"wobble-press-s{seed}", "wobble-press", contact, params, rng)


# --------------------------------------------------------------------------- contours


def quick_drum_case(
    seed: int = 0,
    *,
    radius_m: float | None = None,
    turn_deg: float | None = None,
    contact_s: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """ONE quick wipe across the top of a drum (a horizontal cylinder of ``radius_m``, 8-15 cm), across its axis,
    the normal turning ``turn_deg`` (40-60 deg) within ``contact_s`` (1.05-1.35 s, touch-down to lift-off; the
    cruise speed solved for it); contour, profile 0.6 -> 1 -> 0.75 of a 10-20 N press with ramps of 0.2 s. The
    path as `corpus.strokes.cylinder_stroke` (±9 deg off the top, drifting 1 cm along the axis)."""
    rng = _rng(seed, "drum-quick")
    params = _params(rng, (10.0, 20.0), None, None, rate_hz)
    radius = _draw(radius_m, 0.08, 0.15, rng)
    turn = np.radians(_draw(turn_deg, 40.0, 60.0, rng))
    duration = _draw(contact_s, 1.05, 1.35, rng)
    dt = 1.0 / rate_hz

    def stroke(cruise: float, generator: np.random.Generator) -> Piece:
        return cylinder_stroke(radius, turn, generator, dt, params["force_n"], 0.2, cruise)

    # The same draws at every cruise speed tried (a copy of the generator): only the timing changes.
    cruise = brentq(lambda c: len(stroke(c, copy.deepcopy(rng)).points) * dt - duration, 0.04, 2.0, xtol=1e-5)
    params |= {"radius_m": radius, "turn_deg": float(np.degrees(turn)), "contact_s": duration, "cruise_m_s": cruise}
    return _analytic(f"drum-quick-s{seed}", "drum-quick", "contour", stroke(cruise, rng), params, rng)


def _wipe_chart(width_m: float, shift_m: float, passes: int) -> tuple[NDArray, NDArray, NDArray]:
    """A back-and-forth wipe in a chart: pass parameter (K,) (pass k runs over [k, k + 1]), points (K, 2) m
    (``u`` across the passes, from -width/2 to width/2 and back, ``v`` along them) and the turns' parameters.

    ``u`` is a cosine of the parameter (each pass spans exactly ``width_m`` and turns at its ends); the shift of
    ``shift_m`` in ``v`` is made over `WIPE_TURN` of a pass around each turn (minimum jerk), so the path turns
    in a rounded U, never stopping."""
    p = np.linspace(0.0, passes, 20000 * passes)
    turns = np.arange(1, passes)
    u = -0.5 * width_m * np.cos(np.pi * p)
    v = shift_m * np.sum([minimum_jerk((p - k) / WIPE_TURN + 0.5) for k in turns], axis=0)
    return p, np.stack([u, v - 0.5 * shift_m * (passes - 1)], axis=1), turns.astype(float)


def curved_wipe_case(
    seed: int = 0,
    *,
    radius_m: float | None = None,
    passes: int | None = None,
    turn_deg: float | None = None,
    shift_m: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """A wipe covering an area of a horizontal cylinder of ``radius_m`` (15-30 cm): ``passes`` (3-5) passes
    across its axis, the normal turning ``turn_deg`` (31-50 deg) over each, shifted ``shift_m`` (10-15 mm) along
    the axis from one to the next, back and forth with rounded turns, in ONE contact at a steady 10-20 N press
    (ramps of 0.3 s); touch-down and lift-off at a pass's end, 3-4 cm/s, 12-18 cm/s between, slowed to 40 % in
    the turns; the band wiped ±0.1 rad off the top. Contour, one truth segment (module docstring)."""
    rng = _rng(seed, "curved-wipe")
    params = _params(rng, (10.0, 20.0), None, None, rate_hz)
    radius = _draw(radius_m, 0.15, 0.30, rng)
    count = int(rng.integers(3, 6)) if passes is None else passes
    turn = np.radians(_draw(turn_deg, 31.0, 50.0, rng))
    shift = _draw(shift_m, 0.010, 0.015, rng)
    axis = rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    across = np.cross(axis, UP)
    centre = np.array([0.5, rng.uniform(-0.1, 0.1), 0.1 - radius])
    off_top = rng.uniform(-0.1, 0.1)

    def surface(chart: NDArray) -> tuple[NDArray, NDArray]:
        angle = off_top + chart[:, 0] / radius
        out = np.sin(angle)[:, None] * across + np.cos(angle)[:, None] * UP
        return centre + radius * out + chart[:, 1:2] * axis, -out

    p, chart, turns = _wipe_chart(radius * turn, shift, count)
    points = surface(chart)[0]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    corners = tuple((float(np.interp(k, p, s)), 0.4, 0.01) for k in turns)
    cruise = rng.uniform(0.12, 0.18)
    t, p_t = timed(p, points, 1.0 / rate_hz, speed_profile(rng.uniform(0.03, 0.04), cruise, 0.035, corners))
    chart_t = np.stack([np.interp(p_t, p, chart[:, 0]), np.interp(p_t, p, chart[:, 1])], axis=1)
    contact = contact_piece(*surface(chart_t), t, params["force_n"], 0.3)
    params |= {
        "radius_m": radius,
        "passes": float(count),
        "turn_deg": float(np.degrees(turn)),
        "shift_m": shift,
        "cruise_m_s": cruise,
    }
    return _analytic(f"curved-wipe-s{seed}", "curved-wipe", "contour", contact, params, rng)


def helix_case(
    seed: int = 0,
    *,
    radius_m: float | None = None,
    turns: float | None = None,
    pitch_m: float | None = None,
    vertical: bool | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """The tool follows a helix round a cylinder of ``radius_m`` (5-10 cm), its axis ``vertical`` or horizontal
    (drawn; random yaw), ``turns`` (0.95-1) turns at ``pitch_m`` (6.5-8.5 cm per turn) along the axis, pressing into
    the cylinder, either way round and along; 8-12 cm/s (touch-down 3 cm/s, lift-off 3.5 cm/s); contour, profile
    0.6 -> 1 -> 0.75 of a 10-20 N press. One truth segment (module docstring)."""
    rng = _rng(seed, "helix")
    params = _params(rng, (10.0, 20.0), None, None, rate_hz)
    radius = _draw(radius_m, 0.05, 0.10, rng)
    turns = _draw(turns, 0.95, 1.0, rng)
    pitch = _draw(pitch_m, 0.065, 0.085, rng)
    upright = bool(rng.random() < 0.5) if vertical is None else vertical
    yaw = rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    axis = UP if upright else yaw
    e1 = yaw if upright else UP
    e2 = np.cross(axis, e1)
    advance = pitch * rng.choice([-1.0, 1.0]) / (2 * np.pi)  # m of axis per rad, up or down the axis
    centre = np.array([0.55, rng.uniform(-0.1, 0.1), 0.1 if upright else 0.3])
    start = rng.uniform(-np.pi, np.pi)

    def surface(angle: NDArray) -> tuple[NDArray, NDArray]:
        out = np.cos(angle)[:, None] * e1 + np.sin(angle)[:, None] * e2
        return centre + radius * out + (advance * (angle - start))[:, None] * axis, -out

    angle = start + rng.choice([-1.0, 1.0]) * np.linspace(0.0, 2 * np.pi * turns, round(2e4 * turns))
    cruise = rng.uniform(0.08, 0.12)
    t, a = timed(angle, surface(angle)[0], 1.0 / rate_hz, speed_profile(0.03, cruise, 0.035))
    contact = contact_piece(*surface(a), t, _profile(t, params["force_n"]), 0.3)
    params |= {
        "radius_m": radius,
        "turns": turns,
        "pitch_m": pitch,
        "vertical": float(upright),
        "turn_deg": 360.0 * turns,
        "cruise_m_s": cruise,
    }
    return _analytic(f"helix-s{seed}", "helix", "contour", contact, params, rng)


# --------------------------------------------------------------------------- sensor artefacts


@dataclass(frozen=True)
class SensorArtefacts:
    """What `with_sensor_artefacts` did to a recording file's force columns (sensor frame, measured on the tool).

    ``drift_n`` (3,) N: the offset's change from the first row to the last, linear in the time stamp;
    ``clip_axis`` (0, 1, 2 for ``fx, fy, fz``), ``clip_n`` N and ``clip_window_s`` (lo, hi) s: that axis reads
    ``clip_n`` at every row stamped in the window; ``spike_rows`` the file's data rows (0 = the first after the
    header) each carrying a spike of ``spike_n`` (signed, N) on ``spike_axes``.
    """

    drift_n: NDArray[np.float64]
    clip_axis: int
    clip_n: float
    clip_window_s: tuple[float, float]
    spike_rows: tuple[int, ...]
    spike_axes: tuple[int, ...]
    spike_n: tuple[float, ...]


def with_sensor_artefacts(csv_text: str, stroke: TruthSegment, rng: np.random.Generator) -> tuple[str, SensorArtefacts]:
    """``csv_text`` (a `corpus.recording` file: columns `corpus.recording.CSV_COLUMNS`) with a wrist sensor's
    artefacts added to its force columns, row by row (the recording code adds none; the other columns and the
    time stamps are left as they are):

    - the offset drifts linearly over the recording by 0.5-1.0 N in a random direction (the sensor warming up);
    - one force axis saturates for 0.1-0.2 s inside ``stroke``'s span (at least 0.2 s from its ends): the axis
      pressed hardest there reads one level, 85 % of its smallest reading in the stretch, at every row;
    - 3-6 single-row spikes of 30-80 N (either sign) on a random force axis at random rows outside the stretch
      (not the first or last 10 rows, none on a repeated stamp, none within 3 rows of another).
    """
    header = ",".join(CSV_COLUMNS)
    if not csv_text.startswith(header + "\n"):
        raise ValueError(f"not a corpus recording file: its header is not {header!r}")
    table = np.loadtxt(io.StringIO(csv_text), delimiter=",", skiprows=1, ndmin=2)
    stamps, forces = table[:, 0], table[:, _FORCE_COLUMNS]
    direction = rng.normal(size=3)
    drift = rng.uniform(0.5, 1.0) * direction / np.linalg.norm(direction)
    forces += ((stamps - stamps[0]) / (stamps[-1] - stamps[0]))[:, None] * drift

    length = rng.uniform(0.1, 0.2)
    lo = rng.uniform(stroke.span[0] + 0.2, stroke.span[1] - 0.2 - length)
    clipped = (stamps >= lo) & (stamps <= lo + length)
    axis = int(np.argmax(np.median(np.abs(forces[clipped]), axis=0)))
    level = 0.85 * np.min(np.abs(forces[clipped, axis])) * np.sign(np.median(forces[clipped, axis]))
    forces[clipped, axis] = level

    # Single rows: a stamp shared with a neighbour (a repeated row) would not be one sample of the sensor.
    lone = np.ones(stamps.size, dtype=bool)
    lone[1:] &= np.diff(stamps) > 0
    lone[:-1] &= np.diff(stamps) > 0
    lone[:10] = lone[-10:] = False
    lone &= ~clipped
    rows: list[int] = []
    for row in rng.permutation(np.flatnonzero(lone)):
        if all(abs(row - other) > 3 for other in rows):
            rows.append(int(row))
        if len(rows) == 6:
            break
    rows = sorted(rows[: int(rng.integers(3, 7))])
    axes = tuple(int(a) for a in rng.integers(0, 3, len(rows)))
    spikes = tuple(float(v) for v in rng.uniform(30.0, 80.0, len(rows)) * rng.choice([-1.0, 1.0], len(rows)))
    forces[rows, axes] += spikes

    table[:, _FORCE_COLUMNS] = forces
    text = io.StringIO()
    np.savetxt(text, table, fmt=_CSV_FORMAT, delimiter=",", header=header, comments="")
    artefacts = SensorArtefacts(drift, axis, float(level), (float(lo), float(lo + length)), tuple(rows), axes, spikes)
    return text.getvalue(), artefacts


def sensor_artefacts_case(seed: int = 0) -> CorpusCase:
    """The recording of ``human-straight`` or ``human-zigzag`` (drawn) at ``seed`` (`corpus.families.human_case`)
    with the artefacts of `with_sensor_artefacts` in its file; slide, the human-like case's truth. The case's
    ``parameters`` add ``drift_n`` (N), ``clip_axis``, ``clip_n`` (N), ``clip_start_s``, ``clip_end_s`` (s),
    ``spikes`` and ``zigzag`` (1.0 for the zig-zag source); ``recording.sensor_offset`` is the offset at the first
    row (before the drift)."""
    return _sensor_artefacts(seed)[0]


def _sensor_artefacts(seed: int) -> tuple[CorpusCase, SensorArtefacts]:
    """`sensor_artefacts_case` with what was done to its file."""
    rng = _rng(seed, "sensor-artefacts")
    source = ARTEFACT_SOURCES[int(rng.integers(len(ARTEFACT_SOURCES)))]
    clean = human_case(source, seed)
    assert clean.recording is not None
    text, artefacts = with_sensor_artefacts(clean.recording.csv_text, clean.segments[0], rng)
    name = f"sensor-artefacts-s{seed}"
    recording = replace(clean.recording, csv_text=text, import_options={**clean.recording.import_options, "name": name})
    parameters = clean.parameters | {
        "zigzag": float(source == "human-zigzag"),
        "drift_n": float(np.linalg.norm(artefacts.drift_n)),
        "clip_axis": float(artefacts.clip_axis),
        "clip_n": artefacts.clip_n,
        "clip_start_s": artefacts.clip_window_s[0],
        "clip_end_s": artefacts.clip_window_s[1],
        "spikes": float(len(artefacts.spike_rows)),
    }
    case = replace(clean, name=name, family="sensor-artefacts", parameters=parameters, recording=recording)
    return case, artefacts


# --------------------------------------------------------------------------- the families together

_FAMILY_CASES: dict[str, Callable[[int], CorpusCase]] = {
    "ramp-press": ramp_press_case,
    "wobble-press": wobble_press_case,
    "drum-quick": quick_drum_case,
    "curved-wipe": curved_wipe_case,
    "helix": helix_case,
    "sensor-artefacts": sensor_artefacts_case,
}


def press_and_path_cases(seeds: Sequence[int]) -> Iterator[CorpusCase]:
    """Every family of `PRESS_AND_PATH_FAMILIES` once per seed, in that order, seed by seed."""
    for seed in seeds:
        for family in PRESS_AND_PATH_FAMILIES:
            yield _FAMILY_CASES[family](seed)
