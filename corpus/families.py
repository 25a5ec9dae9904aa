"""The ground-truth corpus a learner is judged on: families of demonstrations, generated (nothing stored), seeded.

World frame, z up, SI units, quaternions scalar-last; the wrench is the one the tool APPLIES (docs/CONVENTIONS.md).
Every family is a function of a seed and a few parameters returning a `corpus.case.CorpusCase`:

- **Planes** (`plane_case`, slide) tilted by 0-50 deg about a random horizontal axis, one contact: a free approach
  from 10 cm (1-1.5 s), touch-down while moving a few cm/s, the stroke, a free retreat (1-1.5 s). Shapes
  (`PLANE_SHAPES`): ``straight`` (15 cm, ~10 N, a stiff pad: ~0.3 mm of sink-in, a steady hand: the path leaves
  its line less than the pad sinks), ``straight-soft`` (the same on a soft pad: 5 mm), ``l-shape`` (two 12 cm
  legs at 90 deg, slowing at the corner), ``zigzag`` (4-6 legs at ±30-40 deg over 20 cm), ``circle`` (one pass,
  1.05 turns, radius 4-6 cm), ``spiral`` (2 -> 7 cm over 2.5 turns), ``multi-pass-circle`` (3 turns of radius
  5 cm), ``back-and-forth`` (3 passes along 15 cm at a steady press, no lift-off: one stroke).
- **Contours** (contour): ``cylinder`` (`cylinder_case`, the path across the axis, the normal turning 60-100 deg),
  ``sphere`` (`sphere_case`, an S over the cap, the normal turning 50-90 deg), ``planar-edge``
  (`planar_edge_case`: a convex crease traced along a horizontal curve 70 mm deep over 50 cm, the pressed normal
  ~45 deg down, its horizontal part turning 35-45 deg, the person leaning 5-12 deg toward one face),
  ``planar-edge-twisted`` (the same pressed 70 deg down onto a profile twisting 30 deg along the crease, like the
  real KU Leuven object: the path within ~2 mm of one plane while the normal turns ~27 deg), ``rim``
  (`rim_case`: 3.6 turns round a convex circular rim of radius 6 cm, the normal inward and ~45 deg down).
- **Human-like** (`human_case`, `HUMAN_KINDS`): recorded by a hand-guided arm's wrist sensor, as a CSV file
  (`corpus.recording`): ``human-straight``, ``human-zigzag``, ``human-cylinder``, and three failures seen on
  real recordings: ``brush`` (the tool brushes down the part's vertical side for ~1 s before the stroke, at
  under half its press: no stroke), ``merged-strokes`` (two strokes on faces 60 deg apart over a convex edge,
  the force dipping to ~1 N for 1.1 s with no lift-off between), ``reversal-strokes`` (a stroke and one back
  along it, the force dipping to 20 % at the turn).

Segment rules (`corpus.case.truth_segments`), what a learner should produce:

- a contact (touch-down to lift-off) is one stroke, unless it contains a stroke boundary below;
- a force dip between two pressing stretches below 30 % of their plateau, with no lift-off, is a boundary; its
  window is the dip's span (from falling below 30 % of the lower plateau to rising above it again);
- a reversal of the travel direction is a boundary only across such a dip (the reversal strokes): a back-and-forth
  wipe at a steady press is one stroke, nothing lies between its passes;
- a path going round is cut at each full turn of its heading (across the contact's mean normal, counted from
  the touch-down) that leaves at least a quarter turn after it, window ±0.1 s: a 1.05-turn circle is one
  segment, 3 turns give 3, the 2.5-turn spiral 3, the 3.6-turn rim 4;
- zigzag and L corners are no boundaries; windows found by two rules at once are joined.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

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
    fillet,
    heading_path,
    rest,
    retreat,
    rotated,
    speed_profile,
    tilted_plane,
    timed,
    transfer,
)
from corpus.case import CorpusCase, analytic_case
from corpus.kinesthetic import OperatorModel
from corpus.recording import FINE_RATE_HZ, recorded_case
from corpus.strokes import (
    ANALYTIC_RATE_HZ,
    PLANE_SHAPES,
    _analytic,
    _draw,
    _params,
    _profile,
    back_and_forth,
    cylinder_stroke,
    plane_stroke,
)
from corpus.synthetic import minimum_jerk
from skills.frames import rotation_from_vectors

PLANE_TILTS_DEG = (0.0, 25.0, 50.0)
"""Plane tilts of the corpus, deg."""
CYLINDER_RADII_M = (0.05, 0.08, 0.15, 0.30)
"""Cylinder radii of the corpus, m."""
SPHERE_RADII_M = (0.08, 0.15)
"""Sphere radii of the corpus, m."""
HUMAN_RECORDING = {
    "human-straight": (100.0, False),
    "human-zigzag": (250.0, True),
    "human-cylinder": (1000.0, False),
    "brush": (100.0, True),
    "merged-strokes": (250.0, False),
    "reversal-strokes": (100.0, True),
}
"""Human-like cases (`human_case`): the sensor's rate (Hz) and whether the file's time stamps are irregular."""
HUMAN_KINDS = tuple(HUMAN_RECORDING)
"""Human-like cases, each recorded as a file."""
PLANAR_EDGE_TWISTED = (70.0, 30.0)
"""Elevation and twist (deg) of the corpus's twisted planar edge: pressed mostly down onto a crease whose profile
twists along it, the path within ~2 mm of one plane while the normal turns ~27 deg (the real contours' way)."""
RANDOM_BOUNDS: dict[str, tuple[float, float]] = {
    "tilt_deg": (0.0, 50.0),
    "force_n": (5.0, 30.0),
    "cruise_m_s": (0.04, 0.15),
    "circle_radius_m": (0.03, 0.07),
    "cylinder_radius_m": (0.05, 0.30),
    "sphere_radius_m": (0.08, 0.15),
    "friction": (0.1, 0.5),
    "pad_stiffness_n_m": (2.0e3, 3.3e4),
}
"""Ranges `random_case` draws from (uniform; the pad stiffness log-uniform; the spiral's cruise at most 12 cm/s,
so that its tightest turn stays no reversal)."""


# --------------------------------------------------------------------------- analytic families


def plane_case(
    shape: str,
    tilt_deg: float = 0.0,
    seed: int = 0,
    *,
    force_n: float | None = None,
    cruise_m_s: float | None = None,
    radius_m: float | None = None,
    friction: float | None = None,
    pad_stiffness_n_m: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """One stroke of ``shape`` (`PLANE_SHAPES`) on a plane tilted by ``tilt_deg``; slide.

    Unset parameters are drawn from ``seed``: ``force_n`` plateau (10 N for the straight strokes, else
    10-20 N), ``cruise_m_s`` (8-12 cm/s, 15-20 cm/s on the 3-pass circle; back-and-forth: 1.3 s per pass),
    ``radius_m`` (circle 4-6 cm, the 3-pass circle 5 cm), ``friction`` (0.2-0.4), ``pad_stiffness_n_m``
    (3.3e4 N/m on ``straight``: 0.3 mm under 10 N; 2e3 on ``straight-soft``: 5 mm; else 1.5e4-3e4). The straight
    strokes are steady (0.05 mm of tremor): the pad's sink-in, not the hand, is what leaves the line.
    """
    rng = np.random.default_rng([seed, PLANE_SHAPES.index(shape), round(tilt_deg)])
    straight = shape.startswith("straight")
    pad = pad_stiffness_n_m or {"straight": 3.3e4, "straight-soft": 2.0e3}.get(shape)
    params = _params(rng, (10.0, 10.0) if straight else (10.0, 20.0), friction, pad, rate_hz)
    params["force_n"] = force_n or params["force_n"]
    fast = shape == "multi-pass-circle"
    cruise = _draw(cruise_m_s, 0.15 if fast else 0.08, 0.2 if fast else 0.12, rng)
    params |= {"tilt_deg": tilt_deg, "cruise_m_s": cruise, "tremor_m": 5e-5 if straight else 3e-4}
    plane = tilted_plane(tilt_deg, rng)
    contact = plane_stroke(plane, shape, rng, 1.0 / rate_hz, params["force_n"], 0.3, cruise, radius_m)
    return _analytic(f"{shape}-tilt{tilt_deg:g}-s{seed}", shape, "slide", contact, params, rng)


def two_tables_case(seed: int = 23) -> CorpusCase:
    """Two straight 15 cm strokes on flat tables 1.2 m apart, the tool lifted 40 cm between them: no placement puts
    both in the iiwa's reach, each alone fits easily (a long wiping recording's lifts, held back from us)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / 500.0
    strokes = []
    for y in (-0.6, 0.6):
        plane = tilted_plane(0.0, rng)
        plane.origin = np.array([0.5, y, 0.15])
        strokes.append(plane_stroke(plane, "straight", rng, dt, 12.0, 0.3, 0.1))
    lift_off, touch_down = retreat(strokes[0], 1.0, 0.1, dt), approach(strokes[1], 1.0, 0.1, dt)
    carry = transfer(lift_off.points[-1], touch_down.points[0], -UP, 3.0, dt, 0.4)
    pieces = [approach(strokes[0], 1.2, 0.1, dt), strokes[0], lift_off, carry, touch_down, strokes[1]]
    pieces.append(retreat(strokes[1], 1.2, 0.1, dt))
    assembled = assemble(pieces, dt, rng, 3.0e4, 0.3, 5e-5, 0.1)
    return analytic_case("two-tables", "straight", "slide", assembled, {"pad_stiffness_n_m": 3.0e4}, rng)


def cylinder_case(
    radius_m: float,
    seed: int = 0,
    *,
    turn_deg: float | None = None,
    force_n: float | None = None,
    cruise_m_s: float | None = None,
    friction: float | None = None,
    pad_stiffness_n_m: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """A contour across a horizontal cylinder of ``radius_m`` over its top, the normal turning ``turn_deg``
    (60-100 deg); ``cruise_m_s`` default: the arc in ~2.5 s, within 3-12 cm/s; the pressing profile
    0.6 -> 1 -> 0.75 of ``force_n`` (10-20 N)."""
    rng = np.random.default_rng([seed, 101, round(radius_m * 1000)])
    params = _params(rng, (10.0, 20.0), friction, pad_stiffness_n_m, rate_hz)
    params["force_n"] = force_n or params["force_n"]
    turn = np.radians(_draw(turn_deg, 60.0, 100.0, rng))
    cruise = float(np.clip(radius_m * turn / 2.5, 0.03, 0.12)) if cruise_m_s is None else cruise_m_s
    params |= {"radius_m": radius_m, "turn_deg": float(np.degrees(turn)), "cruise_m_s": cruise}
    contact = cylinder_stroke(radius_m, turn, rng, 1.0 / rate_hz, params["force_n"], 0.3, cruise)
    return _analytic(f"cylinder-r{radius_m * 100:g}cm-s{seed}", "cylinder", "contour", contact, params, rng)


def sphere_case(
    radius_m: float,
    seed: int = 0,
    *,
    turn_deg: float | None = None,
    force_n: float | None = None,
    friction: float | None = None,
    pad_stiffness_n_m: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """A contour over the cap of a sphere of ``radius_m``: an S through the top, the normal turning ``turn_deg``
    (50-90 deg) between touch-down and lift-off; 5-8 cm/s; profile as `cylinder_case`."""
    rng = np.random.default_rng([seed, 102, round(radius_m * 1000)])
    params = _params(rng, (10.0, 20.0), friction, pad_stiffness_n_m, rate_hz)
    params["force_n"] = force_n or params["force_n"]
    turn = np.radians(_draw(turn_deg, 50.0, 90.0, rng))
    e1 = rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    e2 = np.cross(UP, e1)
    centre = np.array([0.5, rng.uniform(-0.1, 0.1), 0.1 - radius_m])
    half = 0.5 * radius_m * turn

    def surface(x: NDArray) -> tuple[NDArray, NDArray]:
        # The exponential map at the top: the geodesic distance from it is |(x, y)|.
        y = 0.15 * half * np.sin(np.pi * x / half)
        rho = np.hypot(x, y) / radius_m
        sinc = np.sinc(rho / np.pi) / radius_m
        out = np.cos(rho)[:, None] * UP + (sinc * x)[:, None] * e1 + (sinc * y)[:, None] * e2
        return centre + radius_m * out, -out

    x = np.linspace(-half, half, 20000)
    cruise = rng.uniform(0.05, 0.08)
    t, xs = timed(x, surface(x)[0], 1.0 / rate_hz, speed_profile(0.03, cruise, 0.035))
    params |= {"radius_m": radius_m, "turn_deg": float(np.degrees(turn)), "cruise_m_s": cruise}
    contact = contact_piece(*surface(xs), t, _profile(t, params["force_n"]), 0.3)
    return _analytic(f"sphere-r{radius_m * 100:g}cm-s{seed}", "sphere", "contour", contact, params, rng)


def planar_edge_case(
    seed: int = 0,
    *,
    turn_deg: float | None = None,
    lean_deg: float | None = None,
    elevation_deg: float = 45.0,
    twist_deg: float = 0.0,
    friction: float | None = None,
    pad_stiffness_n_m: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """A convex crease traced along a horizontal curve (chord 50 cm, 70 mm deep, its direction turning
    ``turn_deg``, 35-45 deg) at 10-13 cm/s, pressing ``elevation_deg`` down across it, leaning ``lean_deg`` (5-12 deg,
    either way) toward one face (±1.5 deg of wobble); the crease is rounded (4 mm), so the pressed direction is
    the surface normal where the tool touches, between the faces' normals. ``twist_deg``: the profile twists
    about the crease along it (the KU Leuven object: ~45 deg), so the elevation runs linearly over that range
    about ``elevation_deg``: the normal turns about the path, which the path's shape cannot show. Profile as
    `cylinder_case`."""
    rng = np.random.default_rng([seed, 103])
    params = _params(rng, (10.0, 20.0), friction, pad_stiffness_n_m, rate_hz)
    turn = np.radians(_draw(turn_deg, 35.0, 45.0, rng))
    lean = np.radians(_draw(lean_deg, 5.0, 12.0, rng)) * rng.choice([-1.0, 1.0])
    half, depth = 0.25, 0.07
    # y = -A (sqrt(1 + (x/b)^2) - 1): the depth at the ends, and the end slopes tan(turn / 2).
    ratio = brentq(
        lambda r: depth / half * r**2 / ((np.hypot(1, r) - 1) * np.hypot(1, r)) - np.tan(turn / 2), 1e-3, 1e3
    )
    b, A = half / ratio, depth / (np.hypot(1.0, ratio) - 1.0)
    R = rotation_from_vectors(np.array([1.0, 0.0, 0.0]), rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-1, 1)))
    origin = np.array([0.5, rng.uniform(-0.1, 0.1), 0.12])
    wobble = rng.uniform(0, 2 * np.pi)

    def surface(x: NDArray) -> tuple[NDArray, NDArray]:
        root = np.sqrt(1 + (x / b) ** 2)
        edge = np.stack([x, -A * (root - 1), np.zeros_like(x)], axis=1) @ R.T + origin
        into = np.stack([-A * x / (b**2 * root), -np.ones_like(x), np.zeros_like(x)], axis=1) @ R.T
        twist = np.radians(twist_deg) * 0.5 * x / half
        elevation = np.radians(elevation_deg) + twist + lean + np.radians(1.5) * np.sin(6 * x / half + wobble)
        return fillet(edge, into / np.linalg.norm(into, axis=1, keepdims=True), elevation, 0.004)

    x = np.linspace(-half, half, 20000)
    t, xs = timed(x, surface(x)[0], 1.0 / rate_hz, speed_profile(0.04, rng.uniform(0.1, 0.13), 0.04))
    params |= {"turn_deg": float(np.degrees(turn)), "lean_deg": float(np.degrees(lean)), "twist_deg": twist_deg}
    contact = contact_piece(*surface(xs), t, _profile(t, params["force_n"]), 0.3, edge=True)
    family = "planar-edge-twisted" if twist_deg else "planar-edge"
    return _analytic(f"{family}-s{seed}", family, "contour", contact, params, rng)


def rim_case(
    seed: int = 0,
    *,
    turns: float = 3.6,
    friction: float | None = None,
    pad_stiffness_n_m: float | None = None,
    rate_hz: float = ANALYTIC_RATE_HZ,
) -> CorpusCase:
    """A wipe ``turns`` times round a convex circular rim (the edge of a cylinder's top, radius 6 cm, rounded
    10 mm) at 20-25 cm/s, pressing inward and 45 ± 8 deg down (the tool rides up and down the rounding, so the
    path stays within ~2 mm of a horizontal plane). Profile as `cylinder_case`."""
    rng = np.random.default_rng([seed, 104])
    params = _params(rng, (10.0, 20.0), friction, pad_stiffness_n_m, rate_hz)
    centre = np.array([0.5, rng.uniform(-0.1, 0.1), 0.12])
    start, phase, direction = rng.uniform(-np.pi, np.pi), rng.uniform(0, 2 * np.pi), rng.choice([-1.0, 1.0])

    def surface(angle: NDArray) -> tuple[NDArray, NDArray]:
        radial = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)
        elevation = np.radians(45.0 + 8.0 * np.sin(0.9 * (angle - start) + phase))
        return fillet(centre + 0.06 * radial, -radial, elevation, 0.01)

    angle = start + direction * np.linspace(0.0, 2 * np.pi * turns, round(2e4 * turns))
    t, a = timed(angle, surface(angle)[0], 1.0 / rate_hz, speed_profile(0.04, rng.uniform(0.2, 0.25), 0.04))
    params["turns"] = turns
    contact = contact_piece(*surface(a), t, _profile(t, params["force_n"]), 0.3, edge=True)
    return _analytic(f"rim-s{seed}", "rim", "contour", contact, params, rng)


# --------------------------------------------------------------------------- human-like families


def _with_rests(pieces: list[Piece], rng: np.random.Generator, dt: float) -> list[Piece]:
    """``pieces`` between two rests of 1-1.5 s (free space for the importer's sensor-offset fit)."""
    first, last = pieces[0], pieces[-1]
    return [
        rest(first.points[0], first.held_axis[0], rng.uniform(1.0, 1.5), dt),
        *pieces,
        rest(last.points[-1], last.held_axis[-1], rng.uniform(1.0, 1.5), dt),
    ]


def _carried(contact: Piece, rng: np.random.Generator, dt: float) -> list[Piece]:
    """``contact`` with a hand's approach from 15-25 cm and retreat as far (1.3-1.8 s each)."""
    return [
        approach(contact, rng.uniform(1.3, 1.8), rng.uniform(0.15, 0.25), dt),
        contact,
        retreat(contact, rng.uniform(1.3, 1.8), rng.uniform(0.15, 0.25), dt),
    ]


def _two_strokes(t: NDArray, t_turn: float, first_n: float, second_n: float) -> NDArray:
    """Pressing level (N) going from ``first_n`` to ``second_n`` over 0.5 s around ``t_turn`` (s)."""
    return first_n + (second_n - first_n) * minimum_jerk((t - t_turn) / 0.5 + 0.5)


def human_case(kind: str, seed: int = 0) -> CorpusCase:
    """A human-like case (`HUMAN_KINDS`) as a hand-guided arm's wrist sensor records it (a CSV file, see
    `corpus.recording`), at the rate of `HUMAN_RECORDING`.

    Drawn from ``seed``: friction 0.1-0.5, pad 2e3-3e4 N/m (log-uniform), force ramps 0.5-0.9 s, the hand's
    push on the arm (mass 3-6 kg, damping 15-30 N·s/m, wander 2-5 N: 2-17 N in free space), tremor 0.4 mm,
    force swings ±10 %. Plateaus 12-25 N (the brush case's stroke 15-30 N, its brush 40-45 % of that).
    """
    if kind not in HUMAN_RECORDING:
        raise ValueError(f"kind must be one of {HUMAN_KINDS}, got {kind!r}")
    rng = np.random.default_rng([seed, 200 + HUMAN_KINDS.index(kind)])
    dt = 1.0 / FINE_RATE_HZ
    params = {
        "friction": rng.uniform(0.1, 0.5),
        "pad_stiffness_n_m": float(np.exp(rng.uniform(np.log(2e3), np.log(3e4)))),
        "force_n": rng.uniform(15.0, 30.0) if kind == "brush" else rng.uniform(12.0, 25.0),
        "ramp_s": rng.uniform(0.5, 0.9),
        "cruise_m_s": rng.uniform(0.06, 0.1),
    }
    operator = OperatorModel(rng.uniform(3.0, 6.0), rng.uniform(15.0, 30.0), rng.uniform(2.0, 5.0))
    force, ramp, cruise = params["force_n"], params["ramp_s"], params["cruise_m_s"]
    skill_type = "slide"
    if kind in ("human-straight", "human-zigzag"):
        params["tilt_deg"] = rng.uniform(0.0, 35.0)
        plane = tilted_plane(params["tilt_deg"], rng)
        pieces = _carried(plane_stroke(plane, kind.removeprefix("human-"), rng, dt, force, ramp, cruise), rng, dt)
    elif kind == "human-cylinder":
        skill_type = "contour"
        radius, turn = rng.uniform(0.1, 0.2), np.radians(rng.uniform(60.0, 90.0))
        params |= {"radius_m": radius, "turn_deg": float(np.degrees(turn))}
        contact = cylinder_stroke(radius, turn, rng, dt, force, ramp, float(np.clip(radius * turn / 3, 0.04, 0.1)))
        pieces = _carried(contact, rng, dt)
    elif kind == "brush":
        pieces = _brush(rng, dt, force, ramp, cruise)
    elif kind == "merged-strokes":
        pieces = _carried(_merged_strokes(rng, dt, force, ramp, cruise), rng, dt)
    else:
        params["tilt_deg"] = rng.uniform(0.0, 30.0)
        plane = tilted_plane(params["tilt_deg"], rng)
        t, xy, (t_turn,) = back_and_forth(0.15, 2, rng.uniform(1.3, 1.6), dt, rng)
        level = _two_strokes(t, t_turn, force, force * rng.uniform(0.9, 1.1))
        points, normals = plane.points(xy[:, 0], xy[:, 1]), plane.inward(xy[:, 0])
        pieces = _carried(contact_piece(points, normals, t, level, ramp, ((t_turn, 0.3, 0.4, 0.2),)), rng, dt)
    fine = assemble(_with_rests(pieces, rng, dt), dt, rng, params["pad_stiffness_n_m"], params["friction"], 4e-4, 0.1)
    rate, irregular = HUMAN_RECORDING[kind]
    return recorded_case(f"{kind}-s{seed}", kind, skill_type, fine, params, rng, rate, irregular, operator)


TRIAL_KINDS = ("human-straight", "human-cylinder")
"""The human-like kinds `human_trials` repeats on one part: a line (where a single trial's tilt about it is the
hand's) and a contour."""

TRIAL_SHIFT_M = 0.015
"""Each trial of a straight stroke lies up to this far (m) beside the part's line: a person does not retrace it."""


def human_trials(kind: str, seed: int = 0, n_trials: int = 3) -> list[CorpusCase]:
    """``n_trials`` demonstrations of ONE task (`TRIAL_KINDS`): the same part, friction, pad and press (±10 % per
    trial), each with another hand (its push, wander, lean, tremor, ramps, speed) and another wrist sensor (offset,
    noise), recorded as `human_case` records them. ``human-straight``: a straight stroke on a plane tilted 0-35°,
    each trial shifted across the line by up to `TRIAL_SHIFT_M`; ``human-cylinder``: the same contour across a
    cylinder of 10-20 cm. Names ``{kind}-task{seed}-t{trial}``."""
    if kind not in TRIAL_KINDS:
        raise ValueError(f"kind must be one of {TRIAL_KINDS}, got {kind!r}")
    part = np.random.default_rng([seed, 300 + TRIAL_KINDS.index(kind)])
    dt = 1.0 / FINE_RATE_HZ
    task = {
        "friction": part.uniform(0.1, 0.5),
        "pad_stiffness_n_m": float(np.exp(part.uniform(np.log(2e3), np.log(3e4)))),
        "force_n": part.uniform(12.0, 25.0),
    }
    if kind == "human-straight":
        task["tilt_deg"] = part.uniform(0.0, 35.0)
        plane = tilted_plane(task["tilt_deg"], part)
    else:
        task |= {"radius_m": part.uniform(0.1, 0.2), "turn_deg": part.uniform(60.0, 90.0)}
    geometry_seed = int(part.integers(2**31))
    cases = []
    for trial in range(n_trials):
        rng = np.random.default_rng([seed, 300 + TRIAL_KINDS.index(kind), trial + 1])
        params = task | {
            "force_n": task["force_n"] * rng.uniform(0.9, 1.1),
            "ramp_s": rng.uniform(0.5, 0.9),
            "cruise_m_s": rng.uniform(0.06, 0.1),
        }
        operator = OperatorModel(rng.uniform(3.0, 6.0), rng.uniform(15.0, 30.0), rng.uniform(2.0, 5.0))
        force, ramp, cruise = params["force_n"], params["ramp_s"], params["cruise_m_s"]
        if kind == "human-straight":
            shift = rng.uniform(-TRIAL_SHIFT_M, TRIAL_SHIFT_M)
            params["shift_m"] = shift
            line = Fold(plane.origin + shift * plane.e_v, plane.e_u, plane.e_v, plane.fold, plane.radius)
            contact = plane_stroke(line, "straight", rng, dt, force, ramp, cruise)
            skill_type = "slide"
        else:
            radius, turn = task["radius_m"], np.radians(task["turn_deg"])
            params["cruise_m_s"] = cruise = float(np.clip(radius * turn / 3 * rng.uniform(0.8, 1.2), 0.04, 0.1))
            contact = cylinder_stroke(radius, turn, np.random.default_rng(geometry_seed), dt, force, ramp, cruise)
            skill_type = "contour"
        pieces = _carried(contact, rng, dt)
        fine = assemble(
            _with_rests(pieces, rng, dt), dt, rng, params["pad_stiffness_n_m"], params["friction"], 4e-4, 0.1
        )
        rate, irregular = HUMAN_RECORDING[kind]
        name = f"{kind}-task{seed}-t{trial}"
        cases.append(recorded_case(name, kind, skill_type, fine, params, rng, rate, irregular, operator))
    return cases


def _brush(rng: np.random.Generator, dt: float, force: float, ramp: float, cruise: float) -> list[Piece]:
    """The tool brushes 4 cm down a box's vertical side for ~1 s at 40-45 % of the stroke's press (held pointing
    down: no stroke), is carried over the top and strokes 15 cm across it, away from the edge."""
    box = tilted_plane(0.0, rng, np.pi / 2, 0.003)  # the top face (u < 0) over the vertical side
    down_side = box.radius * np.pi / 2 + 0.01 + np.linspace(0.0, 0.04, 4000)
    beside = rng.uniform(-0.05, 0.05)
    t, u = timed(down_side, box.points(down_side, np.full(4000, beside)), dt, speed_profile(0.035, 0.045, 0.035))
    pointing_down = -box.out
    brush = contact_piece(
        box.points(u, np.full(u.size, beside)), box.inward(u), t, force * rng.uniform(0.40, 0.45), 0.15,
        held_axis=pointing_down,
        stroke=False,
    )  # fmt: skip
    s, chart = heading_path([np.pi + rng.uniform(-0.5, 0.5)], [0.15], 0.02)
    chart = chart + np.array([-0.03, beside + rng.uniform(-0.03, 0.03)])
    t, p = timed(s, box.points(chart[:, 0], chart[:, 1]), dt, speed_profile(0.03, cruise, 0.03))
    u, v = np.interp(p, s, chart[:, 0]), np.interp(p, s, chart[:, 1])
    stroke = contact_piece(box.points(u, v), box.inward(u), t, force, ramp)
    off_side = retreat(brush, 0.8, 0.05, dt)
    onto_top = approach(stroke, rng.uniform(1.3, 1.8), rng.uniform(0.15, 0.25), dt)
    return [
        approach(brush, 1.3, 0.06, dt),
        brush,
        off_side,
        transfer(off_side.points[-1], onto_top.points[0], pointing_down, 2.0, dt, 0.05),
        onto_top,
        stroke,
        retreat(stroke, rng.uniform(1.3, 1.8), rng.uniform(0.15, 0.25), dt),
    ]


def _merged_strokes(rng: np.random.Generator, dt: float, force: float, ramp: float, cruise: float) -> Piece:
    """Two strokes over a convex edge between faces 60 deg apart (rounded 8 mm), in one contact: the tool slows to
    5 cm/s over the edge while the force dips to ~1 N for 1.1 s (0.3 s down, 0.5 s held, 0.3 s up)."""
    fold = tilted_plane(rng.uniform(0.0, 20.0), rng, np.radians(60.0), 0.008)
    middle = 0.5 * fold.radius * fold.fold
    u = np.linspace(-0.17, 2 * middle + 0.14, 20000)
    v = 0.01 * np.sin(np.pi * (u - u[0]) / (u[-1] - u[0]) + rng.uniform(0, 2 * np.pi))
    points = fold.points(u, v)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    speed = speed_profile(0.03, cruise, 0.03, ((float(np.interp(middle, u, s)), 0.05 / cruise, 0.02),))
    t, u_t = timed(u, points, dt, speed)
    t_edge = float(np.interp(middle, u_t, t))
    second = force * rng.uniform(0.9, 1.1)
    level = _two_strokes(t, t_edge, force, second)
    v_t = np.interp(u_t, u, v)
    dip = ((t_edge, 0.3, 0.5, 2.0 / (force + second)),)
    return contact_piece(fold.points(u_t, v_t), fold.inward(u_t), t, level, ramp, dip)


# --------------------------------------------------------------------------- the corpus


def corpus_cases(seeds: Sequence[int] = (0,)) -> Iterator[CorpusCase]:
    """Every family at its parameter values, per seed: the 8 plane shapes at 3 tilts, cylinders of 4 radii,
    spheres of 2, the planar edge plain and twisted, the rim, and the 6 human-like cases (39 cases per seed)."""
    for seed in seeds:
        for shape in PLANE_SHAPES:
            for tilt in PLANE_TILTS_DEG:
                yield plane_case(shape, tilt, seed)
        for radius in CYLINDER_RADII_M:
            yield cylinder_case(radius, seed)
        for radius in SPHERE_RADII_M:
            yield sphere_case(radius, seed)
        yield planar_edge_case(seed)
        yield planar_edge_case(seed, elevation_deg=PLANAR_EDGE_TWISTED[0], twist_deg=PLANAR_EDGE_TWISTED[1])
        yield rim_case(seed)
        for kind in HUMAN_KINDS:
            yield human_case(kind, seed)


def random_case(seed: int) -> CorpusCase:
    """A new analytic case drawn from ``seed`` within `RANDOM_BOUNDS`: a plane shape (`PLANE_SHAPES`), a cylinder
    or a sphere, with random tilt, plateau force, cruise speed, radius, friction and pad stiffness."""
    rng = np.random.default_rng([seed, 999])
    families = (*PLANE_SHAPES, "cylinder", "sphere")
    family = families[int(rng.integers(len(families)))]

    def draw(key: str) -> float:
        return float(rng.uniform(*RANDOM_BOUNDS[key]))

    common = {
        "force_n": draw("force_n"),
        "friction": draw("friction"),
        "pad_stiffness_n_m": float(np.exp(rng.uniform(*np.log(RANDOM_BOUNDS["pad_stiffness_n_m"])))),
    }
    if family == "cylinder":
        return cylinder_case(draw("cylinder_radius_m"), seed, cruise_m_s=draw("cruise_m_s"), **common)
    if family == "sphere":
        return sphere_case(draw("sphere_radius_m"), seed, **common)
    cruise = draw("cruise_m_s")
    return plane_case(
        family,
        draw("tilt_deg"),
        seed,
        cruise_m_s=min(cruise, 0.12) if family == "spiral" else cruise,
        radius_m=draw("circle_radius_m"),
        **common,
    )
