"""The kinesthetic teacher: the simulated KUKA iiwa does what a person guiding it by hand does, with ground truth.

Where ``sim_worker/teacher.py`` records one clean stroke the way a careful script would, this module records
what real kinesthetic wiping recordings look like (see ``corpus/kinesthetic.py`` for the facts they carry):
1-4 strokes per recording, each one coming down from 20-35 cm, touching the surface while still moving a few
cm/s, ramping the normal force up over 0.5-1 s to a plateau of 15-32 N that swings ±20 % (0.1-0.5 Hz), wiping
2.5-15 s at 0.05-0.15 m/s along a path that is not straight and may go back over itself, ramping down over
0.5-1 s and lifting 20-35 cm before moving to the next stroke's start. Friction ``mu`` 0.2-0.4.

The physics is PyBullet's (``SimWorld``, 1 kHz): the robot is driven by the scripted teacher's control law
(Cartesian impedance at the tool point with gravity/Coriolis compensation and a null-space posture spring; in
contact a force feed-forward with a PI correction along the surface's inward normal and only damping along it;
the gains are ``TeacherParams``'s), written here against ``SimWorld.sense()/dynamics()`` with plain-float
arithmetic so that a 4-stroke recording (~50 s simulated) takes a few seconds. The world's TRUE contact
wrench (applied by the tool, at the tool point, world frame) and the tool pose are logged at 1 kHz; the
operator's hand force (``operator_forces``) and a wrist sensor (``random_wrist_sensor``,
``wrist_sensor_samples``) from ``corpus/kinesthetic.py`` turn them into the 100 Hz recording a real sensor
gives (sensor frame, measured ON the tool, constant offset, noise), exactly as ``kinesthetic_wipe`` does.

Ground truth (``KinestheticTruth``) comes from the simulation, not from the plan: contact intervals from
PyBullet's contact points (first touch to lift-off of each stroke), the plateau force as the mean TRUE
normal force between the ramps, normals from the exact world geometry at the tool ball's centre.

Scenarios (``KINESTHETIC_SCENARIOS``): ``wipe_flat``, ``wipe_tilted`` (table tilted 35°), ``wipe_curved`` (a cylinder of
radius 0.6-0.75 m sunk in the table, its axis horizontal; each stroke runs across the axis, so the normal turns
~28-44° along it and a plane fit of a stroke leaves an RMS of ~8-14 mm).

Conventions: world frame z up, SI units, quaternions scalar-last ``[x, y, z, w]`` in arrays (the CSV file is
scalar-first, as real recordings are: ``recording_csv_text``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from corpus.kinesthetic import (
    KinestheticDemo,
    KinestheticTruth,
    OperatorModel,
    StrokeTruth,
    operator_forces,
    random_wrist_sensor,
    wrist_sensor_samples,
)
from corpus.synthetic import minimum_jerk
from schemas.text import JsonObject
from schemas.world import WorldConfig
from sim_worker.geometry import CylinderSolid, WorldGeometry
from sim_worker.robot_model import Q_HOME
from sim_worker.teacher import R_TOOL_DOWN, TeacherParams
from sim_worker.world import SimWorld
from skills.quaternions import quaternion_from_matrix, quaternions_sign_continuous

KINESTHETIC_SCENARIOS: dict[str, str] = {
    "wipe_flat": "Wipe the horizontal table by hand: 1-4 strokes at 15-32 N, lifted 20-35 cm between them.",
    "wipe_tilted": "Wipe the table tilted 35° about the world x axis by hand: 1-4 strokes at 15-32 N along the plane.",
    "wipe_curved": "Wipe across a large cylinder (radius 0.6-0.75 m, axis along world x, sunk in the table) by "
    "hand: 1-4 strokes at 15-32 N, the normal turning 28-44° along each stroke.",
}

SURFACE_OF_SCENARIO: dict[str, str] = {"wipe_flat": "flat", "wipe_tilted": "tilted", "wipe_curved": "curved"}
"""The ``KinestheticTruth.surface`` name of each scenario (the names ``corpus.kinesthetic.SURFACES`` uses)."""

SENSOR_RATE_HZ = 100.0
"""Rate of the recording (the wrist sensor's output), Hz."""

LEARN_IMPORT_OPTIONS = "--rate 100 --quaternion-order wxyz --wrench measured-on-tool --wrench-frame tool"
"""The ``contact-skills learn`` options that import a kinesthetic recording file (``recording_csv_text``)."""

TILT_DEG = 35.0
"""Tilt of the table in ``wipe_tilted`` (about the world x axis), deg."""

CURVED_CROWN_HEIGHT_M = 0.14
"""Height of the cylinder's crown above the table top in ``wipe_curved``, m (the rest of it is sunk in the table,
so the strokes, ±0.3 m of arc from the crown, stay clear of the table)."""

CURVED_TABLE_HEIGHT_M = 0.0
"""Table height in ``wipe_curved``, m: lower than the default 0.10 m so that the strokes' starts 20-35 cm above the
crown stay within the iiwa's wrist range (joint 6) with the tool pointing down."""

PLANE_CHART_TABLE_X_M = -0.02
"""Where the strokes on a plane are centred: this far along the table's x axis from its centre, m (2 cm towards the
robot: the arm keeps ~0.2 rad from its joint limits also 35 cm above the table)."""

V_RANGE_M = 0.09
"""The strokes stay within ±this of the chart's centre line along ``v`` (world x: towards or away from the robot), m:
closer to the robot the elbow (joint 4), farther the wrist (joint 6) reaches its limit on the lift."""

_UP = np.array([0.0, 0.0, 1.0])
_PHASE_FREE, _PHASE_DESCENT, _PHASE_UP, _PHASE_PLATEAU, _PHASE_DOWN, _PHASE_LIFT = range(6)
_NULL_UPDATE_STEPS = 5
"""The null-space posture torque is refreshed every this many steps (the arm moves < 1 mrad in between)."""


@dataclass(frozen=True)
class SimKinestheticDemo(KinestheticDemo):
    """A kinesthetic demonstration recorded in PyBullet: a ``KinestheticDemo`` plus where and how it was made.

    Every ``KinestheticDemo`` field has its meaning there (100 Hz samples, ``wrenches_applied`` the TRUE wrench
    averaged over each sensor period, ``sensor_readings`` the file's wrench); in addition:
    """

    scenario: str = ""
    seed: int = 0
    world_config: WorldConfig | None = None
    """The world it was recorded in: ``SimWorld(world_config)`` rebuilds it (to execute the learned skill)."""
    hand_forces: NDArray[np.float64] | None = None
    """(N, 3) the operator's hand force in the sensor reading, world frame, applied-by-tool convention, N,
    averaged over each sensor period like the readings (``readings[:, :3] = -R^T (applied + hand) + offset +
    noise``)."""
    simulated_s: float = 0.0
    """Simulated duration at 1 kHz, s."""
    wall_time_s: float = 0.0
    """Wall time of the recording (simulation and sensor model), s."""


# --------------------------------------------------------------------------- the world


@dataclass(frozen=True)
class _Draws:
    """What the seed decides about a scenario before the strokes: stroke count, friction, cylinder radius."""

    n_strokes: int
    friction: float
    cylinder_radius_m: float


def _draws(seed: int) -> _Draws:
    # A stream of its own, so that the world of a seed is known without planning the strokes.
    rng = np.random.default_rng([seed, 0])
    return _Draws(int(rng.integers(1, 5)), float(rng.uniform(0.2, 0.4)), float(rng.uniform(0.6, 0.75)))


def kinesthetic_world_config(scenario: str, seed: int = 0, friction: float | None = None) -> WorldConfig:
    """Return the ``WorldConfig`` ``record_kinesthetic(scenario, seed, friction=friction)`` records in.

    ``friction`` is the tool-surface Coulomb coefficient (``lateral_friction``; default from the seed, 0.2-0.4).
    ``wipe_curved``'s cylinder radius (0.6-0.75 m) comes from the seed too. Raises ValueError for an unknown
    scenario or a friction outside [0, 1].
    """
    if scenario not in KINESTHETIC_SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known: {', '.join(KINESTHETIC_SCENARIOS)}")
    draws = _draws(seed)
    mu = draws.friction if friction is None else float(friction)
    if not 0.0 <= mu <= 1.0:
        raise ValueError(f"friction must be in [0, 1], got {mu}")
    config = WorldConfig(lateral_friction=mu)
    if scenario == "wipe_tilted":
        return config.replace(table_tilt_deg=TILT_DEG, table_tilt_axis=(1.0, 0.0, 0.0))
    if scenario == "wipe_curved":
        r = draws.cylinder_radius_m
        # Yaw 90°: the axis along world x (the strokes run across it, along world y, in front of the robot),
        # 5 cm towards the robot from the table centre; sunk so that its crown is CURVED_CROWN_HEIGHT_M above
        # the table top.
        return config.replace(
            table_height_m=CURVED_TABLE_HEIGHT_M,
            cylinder_xy_m=(-0.05, 0.0),
            cylinder_enabled=True,
            cylinder_radius_m=r,
            cylinder_length_m=0.5,
            cylinder_yaw_deg=90.0,
            cylinder_offset_m=(0.0, 0.0, CURVED_CROWN_HEIGHT_M - 2.0 * r),
        )
    return config


class _Surface:
    """The wiped surface in chart coordinates (u, v), m: plane (table) or the cylinder across its axis.

    Plane: ``u`` along the table's y axis, ``v`` along its -x axis, from ``PLANE_CHART_TABLE_X_M`` on the table's
    x axis. Cylinder: ``u`` the
    arc length across the axis from the crown (towards the body x axis = world +y), ``v`` along the axis.
    ``frames(u)`` are (N, 3, 3) with columns (e_u, e_v, outward normal).
    """

    def __init__(self, geometry: WorldGeometry, curved: bool):
        self.geometry = geometry
        self.cylinder: CylinderSolid | None = None
        if curved:
            solid = geometry.solids["cylinder"]
            assert isinstance(solid, CylinderSolid)
            self.cylinder = solid
        # Columns (table y, -table x, table normal): right-handed since y × (-x) = z.
        self.table_frame = np.column_stack([geometry.table_R[:, 1], -geometry.table_R[:, 0], geometry.table_R[:, 2]])
        self.origin = geometry.table_point(PLANE_CHART_TABLE_X_M, 0.0)

    def frames(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Surface frames (N, 3, 3) at chart ``u`` (N,) m: columns e_u, e_v, outward normal (world)."""
        u = np.atleast_1d(u)
        if self.cylinder is None:
            return np.broadcast_to(self.table_frame, (u.size, 3, 3)).copy()
        theta = u / self.cylinder.radius
        c, s = np.cos(theta), np.sin(theta)
        local = np.zeros((u.size, 3, 3))  # body frame: e_u = (cos, 0, -sin), e_v = y, n = (sin, 0, cos)
        local[:, 0, 0], local[:, 2, 0] = c, -s
        local[:, 1, 1] = 1.0
        local[:, 0, 2], local[:, 2, 2] = s, c
        return self.cylinder.R @ local

    def points(self, u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
        """Surface points (N, 3) m at chart coordinates ``u``, ``v`` (N,) m."""
        u, v = np.atleast_1d(u), np.atleast_1d(v)
        if self.cylinder is None:
            F = self.table_frame
            return self.origin + u[:, None] * F[:, 0] + v[:, None] * F[:, 1]
        cyl = self.cylinder
        theta = u / cyl.radius
        local = np.column_stack([cyl.radius * np.sin(theta), v, cyl.radius * np.cos(theta)])
        return cyl.p + local @ cyl.R.T

    def normals(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Outward unit normals (N, 3) at chart ``u`` (N,) m."""
        return self.frames(u)[:, :, 2]

    def away(self, outward: NDArray[np.float64]) -> NDArray[np.float64]:
        """Direction (3,) to lift along from where the surface's outward normal is ``outward`` (3,), scaled so that
        a unit step along it takes the tool a unit distance from the surface (lifting h along it: h above it).

        On a plane halfway between the normal and up (on the tilted table: up and a little down the slope); on
        the cylinder straight up (leaning out with the normal would take the arm beyond its wrist's range).
        """
        direction = _UP.copy() if self.cylinder is not None else (outward + _UP) / np.linalg.norm(outward + _UP)
        return direction / float(direction @ outward)

    def distance_and_outward(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Signed distance (N,) m of ``points`` (N, 3) to the wiped surface and its outward normal (N, 3) there.

        The plane is taken as unbounded and the cylinder as infinitely long (the strokes stay far from their
        edges), so the normal is the plane's or the radial direction from the axis.
        """
        if self.cylinder is None:
            n = self.table_frame[:, 2]
            return (points - self.origin) @ n, np.broadcast_to(n, points.shape).copy()
        cyl = self.cylinder
        local = (points - cyl.p) @ cyl.R
        radial = local * np.array([1.0, 0.0, 1.0])
        rho = np.linalg.norm(radial, axis=1)
        return rho - cyl.radius, (radial / rho[:, None]) @ cyl.R.T


# --------------------------------------------------------------------------- human-like signals and plans


class _Wander:
    """A smooth random signal: per dimension the sum of 3 sinusoids in [f_lo, f_hi] Hz, |value| <= 1."""

    def __init__(self, rng: np.random.Generator, f_lo: float, f_hi: float, dims: int = 1):
        self.freq = rng.uniform(f_lo, f_hi, (3, dims))
        self.phase = rng.uniform(0.0, 2.0 * np.pi, (3, dims))
        self.amp = rng.uniform(0.4, 1.0, (3, dims))

    def __call__(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Values (N, dims) at times ``t`` (N,) s (normalized by the amplitude sum: never beyond ±1)."""
        arg = 2.0 * np.pi * self.freq[:, None, :] * t[None, :, None] + self.phase[:, None, :]
        return np.sum(self.amp[:, None, :] * np.sin(arg), axis=0) / np.sum(self.amp, axis=0)


@dataclass
class _StrokePlan:
    """One stroke as planned before the simulation (chart path at 1 kHz from the touch on)."""

    u: NDArray[np.float64]
    v: NDArray[np.float64]
    plateau_n: float
    ramp_up_s: float
    ramp_down_s: float
    above_height_m: float
    descent_s: float
    touch_speed_m_s: float
    lift_height_m: float
    lift_s: float
    transit_s: float
    """Duration of the free move to this stroke's start (for the first stroke: the rest before it), s."""


def _leg_positions(legs: list[tuple[float, float]], durations: NDArray, dt: float) -> NDArray[np.float64]:
    """Position along a stroke (in units of its length) at 1 kHz over consecutive ``legs`` (from, to).

    Each leg takes its duration (s) with a smooth trapezoidal speed (speeding up and slowing down over 20 %
    of it each, zero speed at both ends: the hand turns around at rest), so the speed peaks at 1.25x the
    leg's mean.
    """
    pieces = []
    for (start, stop), duration in zip(legs, durations, strict=True):
        x = np.linspace(0.0, 1.0, max(2, round(duration / dt)))
        speed = minimum_jerk(x / 0.2) * minimum_jerk((1.0 - x) / 0.2)
        travelled = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]))])
        pieces.append(start + (stop - start) * travelled / travelled[-1])
    return np.concatenate(pieces)


def _sideways(n: int, drift: float, wave: float, cycles: float, phase: float) -> NDArray[np.float64]:
    """Sideways offset (n,) m of a stroke from its line: a ``drift`` (m over the stroke) and a ``wave`` (m) of
    ``cycles`` over it, on a min-jerk clock (at rest at both ends, like the motion along), from 0."""
    clock = minimum_jerk(np.linspace(0.0, 1.0, n))
    side = drift * (clock - 0.5) + wave * np.sin(2.0 * np.pi * cycles * clock + phase)
    return side - side[0]


def _arc_plane_rms(shape: NDArray[np.float64], side: NDArray[np.float64], length: float, radius: float) -> float:
    """Plane-fit RMS (m) of a path across a cylinder of ``radius`` (m): arc positions ``length · shape`` (m) from
    the crown and ``side`` (m) along the axis, one per sample.

    The plane is the one a learner fits to a pressed surface: depth along the mean normal (here the crown's,
    the path being symmetric enough), fitted linearly over the two in-plane coordinates. (The plane of least
    RMS would be the cross-section the path is drawn in, with no residual at all, but nobody presses on it.)
    """
    angle = length * shape / radius
    across, depth = radius * np.sin(angle), radius * np.cos(angle)
    design = np.column_stack([np.ones_like(across), across, side])
    residual = depth - design @ np.linalg.lstsq(design, depth, rcond=None)[0]
    return float(np.sqrt(np.mean(residual**2)))


def _shift_into(values: NDArray[np.float64], bound: float) -> float:
    """The shift that moves ``values`` into [-bound, bound] (0 if they are within; centred if they span more)."""
    low, high = float(values.min()), float(values.max())
    if high - low >= 2.0 * bound:
        return -0.5 * (low + high)
    return max(0.0, -bound - low) - max(0.0, high - bound)


def _plan_strokes(
    n_strokes: int, curved: bool, radius_m: float, rng: np.random.Generator, dt: float
) -> list[_StrokePlan]:
    """Plan ``n_strokes`` wiping strokes: chart paths, forces, ramps, heights and durations (see module doc)."""
    plans = []
    v_centres = np.linspace(-0.04, 0.04, n_strokes) + rng.uniform(-0.015, 0.015, n_strokes)
    for k in range(n_strokes):
        mean_speed = rng.uniform(0.055, 0.085)
        if curved:
            # The turn of the normal makes the plane-fit RMS ~0.149 r (turn/2)^2 (uniform speed); the length is
            # refined below for the stroke's own timing.
            rms = rng.uniform(0.009, 0.012)
            turn = float(np.clip(2.0 * math.sqrt(rms / (0.149 * radius_m)), math.radians(28.0), math.radians(44.0)))
            length = radius_m * turn
            back = rng.random() < 0.5
        else:
            duration = rng.uniform(2.5, 9.0) if n_strokes > 1 else rng.uniform(4.0, 12.0)
            passes = max(1, round(mean_speed * duration / rng.uniform(0.15, 0.3)))
            back = passes == 1 and rng.random() < 0.5
            length = 0.0  # from the duration below
        if back:  # go forth, back over a part, forth to the end
            a, c = rng.uniform(0.5, 0.8), rng.uniform(0.2, 0.35)
            legs = [(0.0, a), (a, a - c), (a - c, 1.0)]
        else:
            legs = [(float(i % 2), float((i + 1) % 2)) for i in range(1 if curved else passes)]
        spans = np.array([abs(b - a) for a, b in legs])
        pace = rng.uniform(0.85, 1.15, len(legs))  # the hand is faster on some legs than on others
        if not curved:
            length = float(np.clip(mean_speed * duration / np.sum(spans * pace), 0.10, 0.32))
        # The sideways drift and wave, on a min-jerk clock: at rest at both ends like the motion along.
        sway = (rng.uniform(-0.03, 0.03), rng.uniform(0.01, 0.03), rng.uniform(0.8, 1.6), rng.uniform(0, 2 * np.pi))

        durations = spans * pace * length / mean_speed
        if curved:
            # Where the hand dwells (slow turns, going back over the middle) sets the plane-fit RMS: scale the
            # stroke's length until the RMS of its own path is the one aimed at (RMS ~ length²), the turn of
            # the normal kept within 28-44°.
            # Going back over the middle can put so much of the stroke there that 44° cannot give that RMS: the
            # hand then wipes straight across.
            for candidate in (legs, [(0.0, 1.0)]):
                spans = np.array([abs(b - a) for a, b in candidate])
                pace = pace[: len(candidate)]
                shape = _leg_positions(candidate, spans * pace * length / mean_speed, 10 * dt) - 0.5
                side = _sideways(shape.size, *sway)
                for _ in range(3):
                    length *= math.sqrt(rms / _arc_plane_rms(shape, side, length, radius_m))
                    length = float(np.clip(length, radius_m * math.radians(28.0), radius_m * math.radians(44.0)))
                legs = candidate
                if _arc_plane_rms(shape, side, length, radius_m) > 0.85 * rms:
                    break
            durations = spans * pace * length / mean_speed
        along = length * (_leg_positions(legs, durations, dt) - 0.5)
        lateral = _sideways(along.size, *sway)
        u0 = rng.uniform(-0.03, 0.03)
        if curved:
            sign = 1.0 if rng.random() < 0.5 else -1.0
            u, v = u0 + sign * along, v_centres[k] + lateral
        else:
            # On a plane the stroke runs either way across the robot's front (±17° from the table's y axis).
            angle = rng.uniform(-0.3, 0.3) + (0.0 if rng.random() < 0.5 else np.pi)
            c_, s_ = math.cos(angle), math.sin(angle)
            u = u0 + c_ * along - s_ * lateral
            v = v_centres[k] + s_ * along + c_ * lateral
        # Keep the stroke where the arm stays clear of its joint limits (elbow near the robot, wrist far from it).
        v = v + _shift_into(v, V_RANGE_M)
        plans.append(
            _StrokePlan(
                u=u,
                v=v,
                plateau_n=rng.uniform(15.0, 32.0),
                ramp_up_s=rng.uniform(0.5, 1.0),
                ramp_down_s=rng.uniform(0.5, 1.0),
                above_height_m=rng.uniform(0.21, 0.35),
                descent_s=rng.uniform(1.4, 2.2),
                touch_speed_m_s=rng.uniform(0.02, 0.05),
                lift_height_m=rng.uniform(0.21, 0.35),
                lift_s=rng.uniform(1.3, 2.0),
                transit_s=rng.uniform(1.0, 2.0) if k == 0 else rng.uniform(1.5, 2.5),
            )
        )
    return plans


# --------------------------------------------------------------------------- the control loop


@dataclass
class _Reference:
    """What the hand asks for over a phase, at 1 kHz: tool point (n, 3) m and velocity (n, 3) m/s, orientation
    (n, 4) scalar-last, and in contact the inward push direction (n, 3) and normal force (n,) N."""

    p: NDArray[np.float64]
    v: NDArray[np.float64]
    q: NDArray[np.float64]
    phase: NDArray[np.int_]
    push: NDArray[np.float64] | None = None
    force: NDArray[np.float64] | None = None


class _Log:
    """The 1 kHz log: per step the tool pose and the TRUE applied wrench before the step, contact, labels.

    Rows are tuples of floats appended to a list (a numpy row assignment costs 30x an append at 1 kHz).
    """

    COLUMNS = ("px", "py", "pz", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz", "touch", "window", "phase")

    def __init__(self) -> None:
        self.rows: list[tuple[float, ...]] = []

    def table(self) -> NDArray[np.float64]:
        """The rows written so far (n, 16)."""
        return np.array(self.rows, dtype=float).reshape(-1, len(self.COLUMNS))


class _Hand:
    """Drives the robot with the teacher's control law (``TeacherParams`` gains) and logs every step.

    The law is the one of ``sim_worker.teacher``'s controller: ``F = K (p_d - p) + D (v_d - v)`` at the tool
    point, in contact minus its part along the inward normal n plus ``n (f_d + I - D_n n·v)`` (I the force
    error integral), a rotational spring-damper, and ``tau = h + J^T F - d qd + null-space posture spring``.
    """

    def __init__(self, world: SimWorld, params: TeacherParams, q_rest: NDArray[np.float64]):
        self.world = world
        self.params = params
        self.q_rest = q_rest
        self.log = _Log()
        self.window = -1
        self.force_integral = 0.0
        self.null_tau = np.zeros(len(q_rest))
        self.joint_margin_rad = math.inf
        """Smallest distance of a joint to its limit so far, rad (checked every few steps)."""
        self.joint_margin_where = (0, 0.0)
        """Which joint (1-7) had ``joint_margin_rad`` and when (s)."""

    @property
    def k(self) -> int:
        """Steps simulated so far (the global 1 kHz sample index)."""
        return len(self.log.rows)

    def run(self, ref: _Reference, stop_on_touch: bool = False) -> bool:
        """Follow ``ref`` step by step; return True if ``stop_on_touch`` and the tool touched (not stepped then)."""
        world, prm, log = self.world, self.params, self.log
        sense, dynamics, step = world.sense, world.dynamics, world.step
        K, D, Kr, Dr = prm.stiffness_n_m, prm.damping_n_s_m, prm.rot_stiffness_nm_rad, prm.rot_damping_nm_s_rad
        Dn, Ki, I_max = prm.normal_damping_n_s_m, prm.force_integral_gain, prm.force_integral_limit_n
        d_joint, k_null = prm.joint_damping_nm_s_rad, prm.null_stiffness_nm_rad
        dt = world.config.time_step_s
        P, V, Q, phases = ref.p.tolist(), ref.v.tolist(), ref.q.tolist(), ref.phase.tolist()
        push = ref.push.tolist() if ref.push is not None else None
        force = ref.force.tolist() if ref.force is not None else None
        window = float(self.window)
        rows = log.rows
        append = rows.append
        F = np.empty(6)
        dot = np.dot
        for i in range(len(P)):
            q, qd, p, quat, w, touching = sense()
            if stop_on_touch and touching:
                return True
            J, h, _ = dynamics(False)
            px, py, pz = p.tolist()
            x, y, z, qw = quat.tolist()
            wl = w.tolist()
            if len(rows) % _NULL_UPDATE_STEPS == 0:
                # PyBullet does not enforce joint limits in torque mode: a person cannot take the arm beyond them.
                margins = np.minimum(q - world.joint_lower, world.joint_upper - q)
                j = int(np.argmin(margins))
                if margins[j] < self.joint_margin_rad:
                    if margins[j] < 0.0:
                        at = len(rows) * dt
                        raise RuntimeError(f"kinesthetic teacher: joint {j + 1} past its limit at {at:.3f} s")
                    self.joint_margin_rad, self.joint_margin_where = float(margins[j]), (j + 1, len(rows) * dt)
                # Posture spring projected into the null space of J: v - J^T (J J^T)^-1 J v (the teacher's
                # (I - J^T J^+T) v with the same 1e-4 regularization).
                spring = k_null * (self.q_rest - q)
                self.null_tau = spring - J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(6), J @ spring)
            append((px, py, pz, x, y, z, qw, *wl, 1.0 if touching else 0.0, window, phases[i]))
            vx, vy, vz, ox, oy, oz = dot(J, qd).tolist()
            pd, vd = P[i], V[i]
            fx = K * (pd[0] - px) + D * (vd[0] - vx)
            fy = K * (pd[1] - py) + D * (vd[1] - vy)
            fz = K * (pd[2] - pz) + D * (vd[2] - vz)
            if push is not None and force is not None:
                nx, ny, nz = push[i]
                along = nx * fx + ny * fy + nz * fz
                measured = nx * wl[0] + ny * wl[1] + nz * wl[2]
                f_d = force[i]
                self.force_integral = min(I_max, max(-I_max, self.force_integral + Ki * (f_d - measured) * dt))
                along = f_d + self.force_integral - Dn * (nx * vx + ny * vy + nz * vz) - along
                fx, fy, fz = fx + nx * along, fy + ny * along, fz + nz * along
            else:
                self.force_integral = 0.0
            # Orientation error q_d ⊗ q^-1 (world frame, = R_d R^T) as a rotation vector.
            dx, dy, dz, dw = Q[i]
            ex = qw * dx - dw * x - (dy * z - dz * y)
            ey = qw * dy - dw * y - (dz * x - dx * z)
            ez = qw * dz - dw * z - (dx * y - dy * x)
            ew = dw * qw + dx * x + dy * y + dz * z
            s = math.sqrt(ex * ex + ey * ey + ez * ez)
            gain = (2.0 * math.atan2(s, abs(ew)) / s if s > 1e-12 else 2.0) * (1.0 if ew >= 0.0 else -1.0)
            F[:] = (fx, fy, fz, Kr * gain * ex - Dr * ox, Kr * gain * ey - Dr * oy, Kr * gain * ez - Dr * oz)
            tau = dot(F, J)
            tau += h
            tau += self.null_tau
            tau -= d_joint * qd
            step(tau)
        return False


# --------------------------------------------------------------------------- recording


class _Recorder:
    """Plans and simulates one kinesthetic recording (see ``record_kinesthetic``)."""

    def __init__(self, world: SimWorld, surface: _Surface, rng: np.random.Generator, params: TeacherParams):
        self.world = world
        self.surface = surface
        self.dt = world.config.time_step_s
        self.rng = rng
        # The hand's imperfections, as functions of the global time: tremor 0.4 mm at 4-9 Hz, the tool axis
        # wobbling (0.08 rad in contact, 0.12 rad in free space), the tool turned about its axis (±0.4 rad),
        # the force swinging ±20 % at 0.1-0.5 Hz.
        self.tremor = _Wander(rng, 4.0, 9.0, dims=3)
        self.wobble = _Wander(rng, 0.05, 0.3, dims=3)
        self.yaw = _Wander(rng, 0.02, 0.1)
        self.swing = _Wander(rng, 0.1, 0.5)
        self.params = params
        frame0 = surface.frames(np.zeros(1))[0] @ R_TOOL_DOWN
        # Turn the tool about its axis so that its x axis points as close to -world x as it can (as at home).
        self.yaw0 = math.atan2(-frame0[0, 1], -frame0[0, 0])
        self.hand: _Hand | None = None

    def times(self, n: int) -> NDArray[np.float64]:
        """Global times (n,) s of the next ``n`` steps."""
        assert self.hand is not None
        return (self.hand.k + np.arange(n)) * self.dt

    def orientations(
        self, u: NDArray[np.float64], t: NDArray[np.float64], wobble_rad: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Tool orientations (n, 4): perpendicular to the surface at chart ``u``, turned and wobbled by the hand."""
        yaw = self.yaw0 + 0.4 * self.yaw(t)[:, 0]
        twist = Rotation.from_rotvec(yaw[:, None] * _UP).as_matrix()
        tilt = Rotation.from_rotvec(wobble_rad[:, None] * self.wobble(t)).as_matrix()
        return quaternion_from_matrix(tilt @ self.surface.frames(u) @ R_TOOL_DOWN @ twist)

    def free_reference(
        self, path: NDArray[np.float64], u: NDArray[np.float64], wobble_rad: NDArray[np.float64], phase: int
    ) -> _Reference:
        """A free-space reference along ``path`` (n, 3) with the hand's tremor, frames at chart ``u`` (n,)."""
        t = self.times(len(path))
        velocity = np.gradient(path, self.dt, axis=0)
        p = path + 4e-4 * self.tremor(t)
        return _Reference(p, velocity, self.orientations(u, t, wobble_rad), np.full(len(path), phase))

    def record(self, plans: list[_StrokePlan]) -> None:
        """Simulate the strokes (fills ``self.hand.log``)."""
        dt, surface, rng = self.dt, self.surface, self.rng
        free, contact = 0.12, 0.08
        touches = [surface.points(p.u[:1], p.v[:1])[0] for p in plans]
        normals = [surface.normals(p.u[:1])[0] for p in plans]
        aboves = [x + p.above_height_m * surface.away(n) for x, n, p in zip(touches, normals, plans, strict=True)]
        # Start at rest above the first stroke (the arm placed there by inverse kinematics, solved first for the
        # touch point: from there the solver reaches the higher pose also near the edge of the workspace).
        orientation = self.orientations(plans[0].u[:1], np.zeros(1), np.full(1, free))[0]
        q_touch = self.world.inverse_kinematics(touches[0], orientation, Q_HOME)
        q_start = self.world.inverse_kinematics(aboves[0], orientation, q_touch)
        self.world.reset(q_start)
        self.hand = hand = _Hand(self.world, self.params, q_start)
        hover, u_hover = aboves[0], plans[0].u[0]
        for k, plan in enumerate(plans):
            n_move = max(2, round(plan.transit_s / dt))
            g = minimum_jerk(np.linspace(0.0, 1.0, n_move))
            path = hover + (aboves[k] - hover) * g[:, None] + 0.03 * np.sin(np.pi * g)[:, None] * _UP
            u = u_hover + (plan.u[0] - u_hover) * g
            hand.window = -1
            hand.run(self.free_reference(path, u, np.full(n_move, free), _PHASE_FREE))
            hand.window = k
            self._descend(plan, aboves[k], touches[k], free, contact)
            self._wipe(plan, contact)
            hover, u_hover = self._lift(plan, free, contact)
        hand.window = -1
        n_rest = max(2, round(rng.uniform(1.0, 2.0) / dt))
        hand.run(self.free_reference(np.repeat(hover[None], n_rest, 0), np.full(n_rest, u_hover), np.full(n_rest, free),
                                     _PHASE_FREE))  # fmt: skip

    def _descend(self, plan: _StrokePlan, above: NDArray, touch: NDArray, free: float, contact: float) -> None:
        """Come down to the stroke's start and on along the same line at the touch speed until the tool touches."""
        assert self.hand is not None
        dt = self.dt
        distance = float(np.linalg.norm(touch - above))
        direction = (touch - above) / distance
        n = max(2, round(plan.descent_s / dt))
        x = np.linspace(0.0, 1.0, n)
        # Blend the min-jerk profile with x^2 (from rest, ending at 2x the mean speed) so that it arrives at
        # touch_speed, still moving, with no step in velocity anywhere (the hand's force would spike).
        blend = min(1.0, 0.5 * plan.touch_speed_m_s * plan.descent_s / distance)
        s = distance * ((1.0 - blend) * minimum_jerk(x) + blend * x**2)
        n_on = round(0.04 / plan.touch_speed_m_s / dt)  # then up to 4 cm further at that speed
        s = np.concatenate([s, s[-1] + plan.touch_speed_m_s * dt * np.arange(1, n_on + 1)])
        wobble = np.concatenate([free + (contact - free) * minimum_jerk(x), np.full(n_on, contact)])
        path = above + s[:, None] * direction
        reference = self.free_reference(path, np.full(len(s), plan.u[0]), wobble, _PHASE_DESCENT)
        if not self.hand.run(reference, stop_on_touch=True):
            raise RuntimeError("kinesthetic teacher: the tool did not touch the surface 4 cm past its start point")

    def _wipe(self, plan: _StrokePlan, contact: float) -> None:
        """Press and wipe along the planned chart path: force ramp up, plateau with swings, ramp down."""
        assert self.hand is not None
        dt, surface = self.dt, self.surface
        n = plan.u.size
        t = self.times(n)
        tau = np.arange(n) * dt
        n_up, n_down = round(plan.ramp_up_s / dt), round(plan.ramp_down_s / dt)
        plateau = slice(n_up, n - n_down)
        swing = self.swing(t)[:, 0]
        swing -= swing[plateau].mean()  # the swings leave the plateau's level where the person meant it
        level = plan.plateau_n * (1.0 + 0.2 * np.clip(swing, -1.2, 1.2))
        f_start, f_end = 3.0, 0.5  # a light press when touching; nearly nothing left when lifting off
        force = level.copy()
        force[:n_up] = f_start + (level[:n_up] - f_start) * minimum_jerk(tau[:n_up] / plan.ramp_up_s)
        x_down = (tau[n - n_down :] - tau[n - n_down]) / plan.ramp_down_s
        force[n - n_down :] = level[n - n_down :] + (f_end - level[n - n_down :]) * minimum_jerk(x_down)
        points = surface.points(plan.u, plan.v)
        outward = surface.normals(plan.u)
        tremor = 4e-4 * self.tremor(t)
        tremor -= np.sum(tremor * outward, axis=1, keepdims=True) * outward  # the hand trembles along the surface
        phase = np.full(n, _PHASE_PLATEAU)
        phase[:n_up], phase[n - n_down :] = _PHASE_UP, _PHASE_DOWN
        reference = _Reference(
            p=points + tremor,
            v=np.gradient(points, dt, axis=0),
            q=self.orientations(plan.u, t, np.full(n, contact)),
            phase=phase,
            push=-outward,
            force=force,
        )
        self.hand.run(reference)

    def _lift(self, plan: _StrokePlan, free: float, contact: float) -> tuple[NDArray[np.float64], float]:
        """Lift off from where the tool is, away from the surface and up; return the hover point and its chart u."""
        assert self.hand is not None
        dt = self.dt
        start = self.world.tool_pose()[0]
        leave = self.surface.points(plan.u[-1:], plan.v[-1:])[0]
        hover = leave + plan.lift_height_m * self.surface.away(self.surface.normals(plan.u[-1:])[0])
        n = max(2, round(plan.lift_s / dt))
        # From rest (the wipe ends at rest): the tool leaves the surface ~0.1 s in, once it has risen 0.5 mm.
        g = minimum_jerk(np.linspace(0.0, 1.0, n))
        path = start + (hover - start) * g[:, None]
        self.hand.run(self.free_reference(path, np.full(n, plan.u[-1]), contact + (free - contact) * g, _PHASE_LIFT))
        return hover, float(plan.u[-1])


def _period_mean(values: NDArray[np.float64], stride: int, n_out: int) -> NDArray[np.float64]:
    """Mean of ``values`` (N, ...) over consecutive groups of ``stride`` rows: (n_out, ...) (the sensor's averaging)."""
    return values[: n_out * stride].reshape(n_out, stride, *values.shape[1:]).mean(axis=1)


def record_kinesthetic(
    scenario: str, seed: int = 0, n_strokes: int | None = None, friction: float | None = None
) -> SimKinestheticDemo:
    """Record a kinesthetic wiping demonstration of ``scenario`` (a key of ``KINESTHETIC_SCENARIOS``) in PyBullet.

    ``n_strokes`` 1-6 (default from the seed: 1-4); ``friction`` the tool-surface Coulomb coefficient (default
    from the seed: 0.2-0.4). Same arguments, same recording. Returns a ``SimKinestheticDemo`` (a
    ``KinestheticDemo``: 100 Hz samples, the sensor's readings and the ground truth; plus the world config, the
    hand's forces and timings). Raises ValueError for an unknown scenario or a bad argument.
    """
    started = time.perf_counter()
    config = kinesthetic_world_config(scenario, seed, friction)
    draws = _draws(seed)
    n = draws.n_strokes if n_strokes is None else int(n_strokes)
    if not 1 <= n <= 6:
        raise ValueError(f"n_strokes must be 1..6, got {n}")
    curved = scenario == "wipe_curved"
    rng = np.random.default_rng([seed, 1])
    plans = _plan_strokes(n, curved, config.cylinder.radius_m, rng, config.time_step_s)
    with SimWorld(config) as world:
        surface = _Surface(world.geometry, curved)
        recorder = _Recorder(world, surface, rng, TeacherParams())
        recorder.record(plans)
        assert recorder.hand is not None
        log = recorder.hand.log.table()
        joint_margin, (joint, joint_t) = recorder.hand.joint_margin_rad, recorder.hand.joint_margin_where
    dt = config.time_step_s
    t = np.arange(len(log)) * dt
    positions = log[:, 0:3]
    quats = quaternions_sign_continuous(log[:, 3:7])
    wrenches = log[:, 7:13]
    touching = log[:, 13] > 0.5
    window = log[:, 14].astype(int)
    phase = log[:, 15].astype(int)

    # Truth from the simulation: inward normal at the tool ball's centre, true normal force along it.
    tool_z = Rotation.from_quat(quats).as_matrix()[:, :, 2]
    _, outward = surface.distance_and_outward(positions - config.tool.radius_m * tool_z)
    inward = -outward
    normal_force = np.einsum("ij,ij->i", wrenches[:, :3], inward)

    # The hand and the sensor, as in corpus.kinesthetic.kinesthetic_wipe (own stream: the plan is unchanged by it).
    sensor_rng = np.random.default_rng([seed, 2])
    hand = operator_forces(t, positions, OperatorModel(), sensor_rng)
    sensor = random_wrist_sensor(sensor_rng, SENSOR_RATE_HZ)
    sensed = wrist_sensor_samples(t, positions, quats, wrenches, hand, sensor, sensor_rng)
    stride = round(1.0 / (SENSOR_RATE_HZ * dt))
    n_out = sensed.t.size
    sample = sensed.sample_index

    strokes: list[StrokeTruth] = []
    stroke_span = np.zeros(len(t), dtype=bool)
    for k in range(n):
        in_window = window == k
        on = np.flatnonzero(in_window & touching)
        if on.size == 0:
            raise RuntimeError(f"kinesthetic teacher: stroke {k} never touched the surface")
        stroke_span[on[0] : on[-1] + 1] = True
        plateau = in_window & (phase == _PHASE_PLATEAU)
        turn = math.degrees(math.acos(float(np.clip(inward[on[0]] @ inward[on[-1]], -1.0, 1.0))))
        strokes.append(
            StrokeTruth(
                t_on=float(t[on[0]]),
                t_off=float(t[on[-1]]),
                plateau_force_n=float(np.mean(normal_force[plateau])),
                normal=None if curved else inward[on[0]].copy(),
                normal_turn_deg=turn,
            )
        )
    truth = KinestheticTruth(
        surface=SURFACE_OF_SCENARIO[scenario],
        skill_type="contour" if curved else "slide",
        friction=config.contact.lateral_friction,
        strokes=strokes,
        in_contact=touching[sample],
        normals=inward[sample],
        normal_force_n=_period_mean(normal_force, stride, n_out),
        sensor_offset=sensor.offset,
        operator_force_max_n=float(np.linalg.norm(hand[~stroke_span], axis=1).max()),
    )
    wall = time.perf_counter() - started
    notes = [
        f"PyBullet kinesthetic teacher {scenario} (seed {seed}): {n} strokes, "
        f"friction {config.contact.lateral_friction:.3f}, "
        f"{t[-1] + dt:.1f} s simulated at 1 kHz in {wall:.1f} s; joints >= {joint_margin:.2f} rad from their limits "
        f"(joint {joint} at {joint_t:.2f} s)"
    ]
    return SimKinestheticDemo(
        t=sensed.t,
        positions=sensed.positions,
        orientations=sensed.orientations,
        wrenches_applied=sensed.wrenches_applied,
        sensor_readings=sensed.readings,
        truth=truth,
        notes=notes,
        scenario=scenario,
        seed=seed,
        world_config=config,
        hand_forces=_period_mean(hand, stride, n_out),
        simulated_s=float(len(t) * dt),
        wall_time_s=wall,
    )


def kinesthetic_truth_dict(demo: SimKinestheticDemo) -> JsonObject:
    """JSON-able ground truth of a recording: strokes, sensor offset, world config and the per-sample truth.

    Per-sample arrays are at the recording's samples (row i of the CSV file, t = i / 100 s).
    """
    truth = demo.truth
    return {
        "scenario": demo.scenario,
        "seed": demo.seed,
        "surface": truth.surface,
        "skill_type": truth.skill_type,
        "friction": truth.friction,
        "rate_hz": SENSOR_RATE_HZ,
        "n_samples": int(demo.t.size),
        "learn_import_options": LEARN_IMPORT_OPTIONS,
        "strokes": [
            {
                "t_on": s.t_on,
                "t_off": s.t_off,
                "plateau_force_n": s.plateau_force_n,
                "normal": None if s.normal is None else [float(x) for x in s.normal],
                "normal_turn_deg": s.normal_turn_deg,
            }
            for s in truth.strokes
        ],
        "sensor_offset": [float(x) for x in truth.sensor_offset],
        "operator_force_max_n": truth.operator_force_max_n,
        "world_config": demo.world_config.to_dict() if demo.world_config is not None else None,
        "samples": {
            "in_contact": truth.in_contact.astype(int).tolist(),
            "normals": np.round(truth.normals, 6).tolist(),
            "normal_force_n": np.round(truth.normal_force_n, 4).tolist(),
        },
        "notes": list(demo.notes),
    }
