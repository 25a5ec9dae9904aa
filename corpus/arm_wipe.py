"""A torque-sensing arm's wipe, as a corpus family: the FILE a user brings (`corpus.force_sources`), with its truth.

World frame, z up, SI units (m, s, N, N·m, rad; angles in the docs in deg), quaternions scalar-last in the arrays;
the truth wrench is the one the tool APPLIES, world frame, at the tool point (the contact point); normals point INTO
the surface (docs/CONVENTIONS.md). The case is built from `corpus.build` (pieces, `assemble`) with its truth as the
other families carry it (positions = the tool point, the true applied wrench, contact, normals, normal force,
`corpus.case.truth_segments`, ``parameters``):

- **A torque-sensing arm** (`lwr_wipe_case`, slide; ``lwr-wipe-patch``, ``lwr-wipe-strip``): a person guides a
  KUKA LWR / iiwa or a Franka by hand and wipes a flat part tilted 0-15 deg about a random horizontal axis. The
  area (``patch`` 60 × 36-44 mm, 5-6 lanes; ``strip`` 250 × 44-48 mm, 5 lanes) is covered lane by lane:
  back-and-forth passes along its long side 8-12 mm apart, joined by rounded U-turns slowed to 40-50 %, split over
  1-3 contacts (the strip: 1-2) with lifts of 3-8 cm between; each contact touches down (and lifts off) just outside
  the area, as far as it slides while the press ramps (0.3-0.8 s), so every lane is wiped at the full press. Rests
  of 1-1.2 s held in the air at the start and the end, a free approach and retreat (0.7-1 s). Cruise 4-8 cm/s
  (patch), 10-12 cm/s (strip); press 8-20 N (±10 % slow wander), friction 0.2-0.5, a stiff pad (1.5e4-3e4 N/m),
  tremor 0.3 mm. The file's pose is the FLANGE's: 0.10-0.20 m behind the tool point along tool z (tool z points
  from the flange into the surface), the tool's orientation (~3 deg of wobble). Its wrench is the arm's estimate
  from its joint torques, world (base) frame, at the flange, as the force ON the robot (the reaction); in applied
  terms the estimate is the applied force turned by a configuration-dependent error (about an axis in the part's
  plane near the lanes, by an angle linear in where the arm reaches: the friction-free force turns 25-35 deg within
  every pass, the same at the same place on every pass), plus a constant offset of 2-4 N (random direction, world),
  unmodelled joint friction of 1.5-4 N (on the robot against the motion: after import along it, on top of the
  surface's friction), the hand's push on the arm in free space (2-8 N; none in contact) and white noise
  (0.3-0.5 N, 0.05 N·m); the moment is the applied force's about the flange. ~100 Hz, stamps jittered ±20 %.
  Columns ``t,x,y,z,qx,qy,qz,qw,fx,fy,fz,mx,my,mz`` (scalar-LAST); import options
  ``wrench_convention="measured-on-tool"``, ``wrench_frame="world"``, ``rate_hz=100``. The recording is an
  `ArmEstimateRecording`: the flange path and each part of the estimate.
- **An uncompensated tool weight** (`tool_weight_case`, slide; ``tool-weight``, ``tool-weight-no-free``): a
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt, gaussian_filter1d, uniform_filter1d
from scipy.optimize import brentq

from corpus.build import (
    TREMOR_FADE_S,
    Assembled,
    Fold,
    Piece,
    assemble,
    contact_piece,
    heading_path,
    rotated,
    speed_profile,
    through_the_air,
    tilted_plane,
    timed,
)
from corpus.case import CorpusCase, CsvRecording, sampled_case
from corpus.kinesthetic import OperatorModel, operator_forces
from corpus.recording import FINE_RATE_HZ
from corpus.synthetic import minimum_jerk
from skills.quaternions import matrix_from_quaternion, quaternions_slerp


@dataclass(frozen=True)
class WipeArea:
    """An area a wipe covers: ``length_m`` along its lanes, a ``width_m`` range across them (m, drawn), the lane
    counts it may be wiped in (`LANE_SPACING_M` apart), a ``cruise_m_s`` range (m/s) and the most contacts."""

    length_m: float
    width_m: tuple[float, float]
    lanes: tuple[int, ...]
    cruise_m_s: tuple[float, float]
    most_contacts: int


WIPE_AREAS = {
    "patch": WipeArea(0.06, (0.036, 0.044), (5, 6), (0.04, 0.08), 3),
    "strip": WipeArea(0.25, (0.044, 0.048), (5,), (0.10, 0.12), 2),
}
"""The areas `lwr_wipe_case` wipes (the strip's lanes are few and fast and its contacts at most two: ~20 s)."""
LANE_SPACING_M = (0.008, 0.012)
"""Distance between neighbouring wiping lanes, m."""
LWR_RATE_HZ = 100.0
"""Nominal rate of a torque-sensing arm's log, Hz; its stamps jitter by `LWR_JITTER_PERIODS`."""
LWR_JITTER_PERIODS = 0.2
"""Largest time stamp jitter of the arm's log, in sample periods (±)."""
LWR_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz")
"""Columns of a torque-sensing arm's file: time (s), flange position (m, world), scalar-LAST quaternion, the
estimated wrench on the robot at the flange (N, N·m, world)."""
JOINT_FRICTION_SPEED_M_S = 0.01
"""The arm's unmodelled joint friction fades in over this speed of the tool point (tanh), m/s."""
PASS_SMOOTHING_S = 0.1
"""The friction-free force is smoothed over this long (moving average) before its turn over a pass is measured, s."""
PASS_MIN_COVER = 0.8
"""A pass (a straight run along a lane, pressing) counts when it covers this fraction of the area's length."""
PASS_ALIGNMENT_DEG = 20.0
"""A sample belongs to a pass when it moves within this angle of the lanes' direction (either way), deg."""
PASS_MIN_SPEED_M_S = 0.02
"""A sample belongs to a pass when it moves faster than this (too), m/s."""


def _turned(vectors: NDArray[np.float64], axis: NDArray[np.float64], angles: NDArray[np.float64]) -> NDArray:
    """``vectors`` (N, 3) each turned by its ``angles`` (N,) rad about the unit ``axis`` (3,) (Rodrigues)."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    return vectors * c + np.cross(axis, vectors) * s + np.outer(vectors @ axis, axis) * (1.0 - c)


def _free_space_weight(touching: NDArray[np.bool_], dt: float) -> NDArray[np.float64]:
    """0 in contact rising to 1 over `corpus.build.TREMOR_FADE_S` after leaving it (and falling before it): where a
    push that only free space shows is seen, with no step at touch-down or lift-off."""
    free_s = distance_transform_edt(~touching) * dt
    return minimum_jerk(free_s / TREMOR_FADE_S)


# --------------------------------------------------------------------------- the torque-sensing arm's wipe


def _lane_geometry(spacing_m: float) -> tuple[float, float]:
    """A rounded U-turn between lanes ``spacing_m`` apart as `corpus.build.heading_path` makes it (the heading
    turning by pi, minimum jerk in arc length): its length (m) and how far short of its corner the turn's far end
    stays along the lanes (m)."""
    x = np.linspace(0.0, 1.0, 2001)
    heading = np.pi * minimum_jerk(x)
    turn_m = spacing_m / np.trapezoid(np.sin(heading), x)
    half = x <= 0.5
    short = turn_m * (0.5 - np.trapezoid(np.cos(heading[half]), x[half]))
    return float(turn_m), float(short)


def _wipe_contacts(
    plane: Fold,
    length_m: float,
    width_m: float,
    lanes: int,
    contacts: int,
    cruise_m_s: float,
    force_n: float,
    ramp_s: float,
    rng: np.random.Generator,
    dt: float,
) -> list[Piece]:
    """The contacts wiping a ``length_m`` × ``width_m`` area of ``plane`` (centred on its origin, the long side
    along its ``e_u``) lane by lane: ``lanes`` back-and-forth passes along the length, ``width_m / (lanes - 1)``
    apart, joined by rounded U-turns (slowed to 40-50 % of ``cruise_m_s``), the lanes split over ``contacts``
    contacts. Each touches down at 3-4 cm/s as far before the area's edge as it slides while its press ramps up to
    ``force_n`` over ``ramp_s`` (and lifts off as far past it), so that every lane is wiped at the full press."""
    spacing = width_m / (lanes - 1)
    turn_m, short = _lane_geometry(spacing)
    pieces = []
    for lane_ids in np.array_split(np.arange(lanes), contacts):
        n = lane_ids.size
        headings = [np.pi * (j % 2) for j in lane_ids]
        touch, lift = rng.uniform(0.03, 0.04, 2)
        lead_in, lead_out = _ramp_distance(touch, cruise_m_s, ramp_s), _ramp_distance(lift, cruise_m_s, ramp_s)
        # The corners sit beyond the area's ends by as much as a U-turn stays short of its corner.
        legs = [length_m + 2 * short] * n
        legs[0] += lead_in - short
        legs[-1] += lead_out - short
        s, xy = heading_path(headings, legs, turn_m)
        first = -1.0 if lane_ids[0] % 2 else 1.0  # the first lane's direction along e_u
        start = np.array([length_m if first < 0 else 0.0, lane_ids[0] * spacing]) - np.array([first * lead_in, 0.0])
        xy = xy + start - np.array([0.5 * length_m, 0.5 * width_m])
        corners = tuple((c, rng.uniform(0.4, 0.5), 0.5 * turn_m) for c in np.cumsum(legs)[:-1])
        t, p = timed(s, plane.points(xy[:, 0], xy[:, 1]), dt, speed_profile(touch, cruise_m_s, lift, corners))
        u, v = np.interp(p, s, xy[:, 0]), np.interp(p, s, xy[:, 1])
        pieces.append(contact_piece(plane.points(u, v), plane.inward(u), t, force_n, ramp_s))
    return pieces


def _ramp_distance(touch_m_s: float, cruise_m_s: float, ramp_s: float) -> float:
    """How far (m) the tool slides during a press ramp of ``ramp_s`` (s) after touching down at ``touch_m_s``
    (m/s) and speeding up to ``cruise_m_s`` as `corpus.build.speed_profile` has it (far from any corner)."""
    s = np.linspace(0.0, cruise_m_s * ramp_s + 0.03, 4001)
    v = speed_profile(touch_m_s, cruise_m_s, cruise_m_s)(s, np.inf)
    elapsed = np.concatenate([[0.0], np.cumsum(np.diff(s) / (0.5 * (v[1:] + v[:-1])))])
    return float(np.interp(ramp_s, elapsed, s))


def wipe_passes(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    pressing: NDArray[np.bool_],
    lane: NDArray[np.float64],
    length_m: float,
) -> list[slice]:
    """The passes of a wipe: runs of ``pressing`` samples (at ``t`` (N,) s, ``positions`` (N, 3) m of the tool
    point) moving faster than `PASS_MIN_SPEED_M_S` within `PASS_ALIGNMENT_DEG` of ``lane`` (a unit vector, either
    way) that cover at least `PASS_MIN_COVER` of the area's ``length_m`` along it: the straight runs from U-turn to
    U-turn (the turns, and lanes cut short by a touch-down or a lift-off, left out)."""
    velocity = np.gradient(positions, t, axis=0)
    speed = np.linalg.norm(velocity, axis=1)
    aligned = np.abs(velocity @ lane) > np.cos(np.radians(PASS_ALIGNMENT_DEG)) * speed
    mask = pressing & aligned & (speed > PASS_MIN_SPEED_M_S)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    runs = [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return [run for run in runs if np.ptp(positions[run] @ lane) >= PASS_MIN_COVER * length_m]


def friction_free_turn_deg(
    t: NDArray[np.float64], positions: NDArray[np.float64], forces: NDArray[np.float64], run: slice
) -> float:
    """How far the friction-free direction of ``forces`` (N, 3) N turns over the samples ``run`` (its angular
    diameter, deg): the component along the velocity of ``positions`` (N, 3) m at ``t`` (N,) s removed, the result
    smoothed over `PASS_SMOOTHING_S` (moving average)."""
    velocity = np.gradient(positions, t, axis=0)
    direction = velocity / np.maximum(np.linalg.norm(velocity, axis=1, keepdims=True), 1e-12)
    free = forces - np.sum(forces * direction, axis=1, keepdims=True) * direction
    size = max(1, round(PASS_SMOOTHING_S / float(np.median(np.diff(t)))))
    free = uniform_filter1d(free, size, axis=0, mode="nearest")[run]
    unit = free / np.linalg.norm(free, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip(np.min(unit @ unit.T), -1.0, 1.0))))


@dataclass(frozen=True)
class ArmEstimateRecording(CsvRecording):
    """A torque-sensing arm's log (`CsvRecording`) and what its estimated wrench is made of, at the case's samples.

    ``csv_text``: see `LWR_COLUMNS`; ``sensor_offset`` (6,) the estimate's constant offset as the file reads it
    (world frame, the force ON the robot; no moment offset); ``hand_forces`` (N, 3) the hand's push the estimate
    sees in free space (world, applied-by-tool convention, N). The parts below are in the applied-by-tool
    convention, world, N: ``flange_positions`` (N, 3) m the file's path; ``flange_wrenches`` (N, 6) the true applied
    wrench referred to the flange (the force, and its moment about the flange); ``direction_errors`` (N, 3) the
    configuration-dependent error (the turned force minus the true one); ``joint_friction`` (N, 3) the unmodelled
    joint friction (along the tool point's motion in these terms). After import (the offset removed) the force is
    ``flange_wrenches[:, :3] + direction_errors + joint_friction + hand_forces`` plus noise.
    """

    flange_positions: NDArray[np.float64]
    flange_wrenches: NDArray[np.float64]
    direction_errors: NDArray[np.float64]
    joint_friction: NDArray[np.float64]


def _direction_gain(
    t: NDArray, tip: NDArray, force: NDArray, extra: NDArray, passes: list[slice], angles: tuple, target_deg: float
) -> float:
    """The gain (rad/m) of a direction error turning ``force`` (N, 3) about ``angles = (axis, constant rad, along
    (N,) m)`` by ``constant + gain * along`` such that the friction-free turn (`friction_free_turn_deg`) of the turned
    force plus ``extra`` (N, 3) is ``target_deg`` midway between the least and the most over ``passes``; ``t`` (N,)
    s, ``tip`` (N, 3) m the tool point's path."""
    axis, constant, along = angles

    def missing(gain: float) -> float:
        estimate = _turned(force, axis, constant + gain * along) + extra
        turns = [friction_free_turn_deg(t, tip, estimate, run) for run in passes]
        return 0.5 * (min(turns) + max(turns)) - target_deg

    high = 5.0
    while missing(high) < 0.0:
        high *= 2.0
    return float(brentq(missing, 0.0, high, xtol=1e-4))


def _arm_log_text(stamps: NDArray, fine: Assembled, flange: NDArray, on_robot: NDArray) -> str:
    """The CSV text (`LWR_COLUMNS`) of a torque-sensing arm's log: at ``stamps`` (s) the flange's position
    ``flange`` (N, 3) m and the tool's orientation of ``fine`` (both on its grid), and ``on_robot`` (one (6,) row
    per stamp: the estimated wrench on the robot at the flange, world, N and N·m)."""
    position = np.stack([np.interp(stamps, fine.t, column) for column in flange.T], axis=1)
    table = np.column_stack([stamps, position, quaternions_slerp(stamps, fine.t, fine.orientations), on_robot])
    text = io.StringIO()
    np.savetxt(text, table, fmt=["%.6f"] + ["%.7g"] * 13, delimiter=",", header=",".join(LWR_COLUMNS), comments="")
    return text.getvalue()


def wipe_lanes(rng: np.random.Generator, shape: WipeArea) -> tuple[float, int]:
    """Draw a wipe's width (m) within ``shape`` and as many lanes as keep them 8-12 mm apart across it."""
    width = rng.uniform(*shape.width_m)
    fits = [n for n in shape.lanes if LANE_SPACING_M[0] <= width / (n - 1) <= LANE_SPACING_M[1] + 1e-9]
    return width, int(rng.choice(fits))


def wipe_draws(
    rng: np.random.Generator, shape: WipeArea, width: float, lanes: int, tilt_deg: float
) -> dict[str, float]:
    """A wipe's parameters (`lwr_wipe_case`): the part's ``tilt_deg``, the press (8-20 N, ramps 0.3-0.8 s), friction
    μ 0.2-0.5, a stiff pad, the cruise speed, the area's ``width`` (m) and ``lanes``, and 1 to a few contacts."""
    return {
        "tilt_deg": tilt_deg,
        "force_n": rng.uniform(8.0, 20.0),
        "ramp_s": rng.uniform(0.3, 0.8),
        "friction": rng.uniform(0.2, 0.5),
        "pad_stiffness_n_m": rng.uniform(1.5e4, 3e4),
        "cruise_m_s": rng.uniform(*shape.cruise_m_s),
        "length_m": shape.length_m,
        "width_m": width,
        "lanes": float(lanes),
        "lane_spacing_m": width / (lanes - 1),
        "contacts": float(rng.integers(1, min(shape.most_contacts, lanes) + 1)),
    }


def arm_draws(rng: np.random.Generator, turn_deg: tuple[float, float]) -> dict[str, float]:
    """The arm's own numbers of an estimated-wrench recording: ``flange_offset_m`` (L, m), ``offset_n`` (N),
    ``direction_turn_deg`` (in ``turn_deg``) and ``direction_constant_deg`` (deg), ``joint_friction_n`` (N),
    ``noise_n`` (N), ``rate_hz``."""
    return {
        "flange_offset_m": rng.uniform(0.10, 0.20),
        "offset_n": rng.uniform(2.0, 4.0),
        "direction_turn_deg": rng.uniform(*turn_deg),
        "direction_constant_deg": rng.uniform(-10.0, 10.0),
        "joint_friction_n": rng.uniform(1.5, 4.0),
        "noise_n": rng.uniform(0.3, 0.5),
        "rate_hz": LWR_RATE_HZ,
    }


def lwr_wipe_case(seed: int = 0, area: str = "patch") -> CorpusCase:
    """A kinesthetic wipe covering a flat ``area`` (``patch`` or ``strip``, `WIPE_AREAS`) recorded by a
    torque-sensing arm's log (see the module docstring for its numbers); slide, family ``lwr-wipe-<area>``.

    The truth is the tool point's (the contact point's), at the uniform times ``k / LWR_RATE_HZ``; the file holds the
    FLANGE's pose and the arm's estimate of the wrench on the robot at the flange, world frame, at jittered stamps
    (`ArmEstimateRecording` splits it into its parts). One truth segment per contact, its normal the plane's.
    ``parameters``: ``tilt_deg``, ``force_n``, ``ramp_s``, ``friction``, ``pad_stiffness_n_m``, ``cruise_m_s``,
    ``length_m``, ``width_m``, ``lanes``, ``lane_spacing_m``, ``contacts``, ``flange_offset_m`` (L, m),
    ``offset_n``, ``direction_turn_deg`` (the friction-free turn per pass the direction error was scaled to, midway
    between the least and the most of the passes), ``direction_constant_deg``, ``direction_gradient_rad_m``, and
    the error's axis, in-plane gradient direction and origin (``direction_axis_x/y/z``,
    ``direction_gradient_x/y/z``, ``direction_origin_x/y/z``: the estimate's force is the applied force turned about
    the axis by ``constant + gradient_rad_m * (p - origin) · gradient``, p the tool point, world), ``joint_friction_n``,
    ``noise_n``, ``rate_hz``.
    """
    if area not in WIPE_AREAS:
        raise ValueError(f"area must be one of {tuple(WIPE_AREAS)}, got {area!r}")
    rng = np.random.default_rng([seed, 300, tuple(WIPE_AREAS).index(area)])
    shape = WIPE_AREAS[area]
    dt = 1.0 / FINE_RATE_HZ
    width, lanes = wipe_lanes(rng, shape)
    tilt = rng.uniform(0.0, 15.0)
    params = {**wipe_draws(rng, shape, width, lanes, tilt), **arm_draws(rng, (28.0, 32.0))}
    plane = tilted_plane(params["tilt_deg"], rng)
    contacts = _wipe_contacts(
        plane, shape.length_m, width, lanes, int(params["contacts"]), params["cruise_m_s"], params["force_n"],
        params["ramp_s"], rng, dt,
    )  # fmt: skip
    pieces = through_the_air(contacts, rng, dt, (0.03, 0.08), (0.7, 1.0), rest_s=(1.0, 1.2))
    fine = assemble(pieces, dt, rng, params["pad_stiffness_n_m"], params["friction"], 3e-4, 0.1)

    # The flange: L behind the tool point along tool z (tool z points from the flange into the surface).
    lever = params["flange_offset_m"] * matrix_from_quaternion(fine.orientations)[:, :, 2]
    flange = fine.positions - lever
    applied = fine.wrenches[:, :3]
    flange_wrench = np.hstack([applied, np.cross(lever, applied)])

    # (c) Joint friction opposes the joints' motion: a force on the robot against the arm's Cartesian motion,
    # which the estimate reads as the tool applying it along the motion. Taken along the tool point's velocity (the
    # flange's differs by the tool's slow wobble times L, up to ~1 cm/s: along it, the part left across the tool
    # point's motion would turn the friction-free force by up to ~5 deg more on slow, lightly pressed passes).
    velocity = np.gradient(gaussian_filter1d(fine.positions, 0.005 / dt, axis=0, mode="nearest"), dt, axis=0)
    speed = np.linalg.norm(velocity, axis=1, keepdims=True)
    fade = np.tanh(speed / JOINT_FRICTION_SPEED_M_S)
    joint_friction = params["joint_friction_n"] * fade * velocity / np.maximum(speed, 1e-9)
    # (d) In free space the estimate sees the hand pushing the arm (its inertia and damping, a slow wander).
    operator = OperatorModel(rng.uniform(2.0, 4.0), rng.uniform(10.0, 20.0), rng.uniform(1.5, 3.0))
    hand = operator_forces(fine.t, flange, operator, rng) * _free_space_weight(fine.touching, dt)[:, None]

    # (b) The direction error: a turn about an axis in the part's plane (within 15 deg of horizontal) within 15 deg
    # of the lanes' direction, so that the friction-free force shows it, across the motion (an axis off the plane
    # also turns the friction across the motion, one way on a pass and the other on the next: passes would differ by
    # up to 12 deg), by an angle linear in where the arm reaches (the tool point: the flange's own few-mm wobble
    # would make passes turn by ±15 % more or less) along an in-plane direction within 25 deg of the lanes'.
    axis = rotated(plane.e_u, plane.out, np.radians(rng.uniform(-15.0, 15.0)))
    gradient = rotated(plane.e_u, plane.out, np.radians(rng.uniform(-25.0, 25.0)))
    along = (fine.positions - plane.origin) @ gradient
    constant = np.radians(params["direction_constant_deg"])
    # The log's rows: ~100 Hz, jittered stamps, white noise. The gain is scaled on what the file shows on a uniform
    # grid: the rows' noise interpolated between their stamps, as a reader resamples them (minus: on the robot).
    samples = np.arange(0, fine.t.size, round(FINE_RATE_HZ / LWR_RATE_HZ))
    stamps = fine.t[samples] + rng.uniform(-LWR_JITTER_PERIODS, LWR_JITTER_PERIODS, samples.size) / LWR_RATE_HZ
    stamps[[0, -1]] = fine.t[samples[[0, -1]]]
    noise = rng.normal(0.0, params["noise_n"], (samples.size, 6)) * np.repeat([1.0, 0.05 / params["noise_n"]], 3)
    seen = np.stack([np.interp(fine.t[samples], stamps, column) for column in noise[:, :3].T], axis=1)
    t, tip = fine.t[samples], fine.positions[samples]
    passes = wipe_passes(t, tip, fine.plateau_id[samples] >= 0, plane.e_u, shape.length_m)
    extra = joint_friction[samples] - seen
    turn = (axis, constant, along[samples])
    gain = _direction_gain(t, tip, applied[samples], extra, passes, turn, params["direction_turn_deg"])
    params["direction_gradient_rad_m"] = gain
    for name, vector in (("axis", axis), ("gradient", gradient), ("origin", plane.origin)):
        params |= {f"direction_{name}_{x}": float(v) for x, v in zip("xyz", vector, strict=True)}
    direction_errors = _turned(applied, axis, constant + gain * along) - applied

    # (a) A constant offset, world frame, in the file's convention (the force on the robot).
    offset = rng.normal(size=3)
    offset *= params["offset_n"] / np.linalg.norm(offset)
    estimate = np.hstack([applied + direction_errors + joint_friction + hand, flange_wrench[:, 3:]])
    on_robot = np.stack([np.interp(stamps, fine.t, column) for column in (-estimate).T], axis=1) + noise
    on_robot[:, :3] += offset
    name = f"lwr-wipe-{area}-s{seed}"
    recording = ArmEstimateRecording(
        csv_text=_arm_log_text(stamps, fine, flange, on_robot),
        import_options={
            "wrench_convention": "measured-on-tool",
            "wrench_frame": "world",
            "rate_hz": LWR_RATE_HZ,
            "name": name,
        },
        sensor_offset=np.concatenate([offset, np.zeros(3)]),
        hand_forces=hand[samples],
        flange_positions=flange[samples],
        flange_wrenches=flange_wrench[samples],
        direction_errors=direction_errors[samples],
        joint_friction=joint_friction[samples],
    )
    return sampled_case(name, f"lwr-wipe-{area}", "slide", fine, samples, params, recording)
