"""Kinesthetic demonstrations with ground truth: what a person guiding a robot arm by hand records.

Built to carry the facts of real kinesthetic wiping recordings (a KUKA arm guided by hand with a
wrist force/torque sensor), so that learning is tested against what real data does to it:

- **Strokes.** 1-4 wiping strokes of 2.5-15 s on one surface, the tool lifted 20-35 cm between
  them. A stroke: the tool comes down and touches the surface still moving (a few cm/s), the
  normal force ramps up over 0.5-1 s, holds a plateau of 15-32 N with slow ±20 % swings
  (0.1-0.5 Hz), ramps down over 0.5-1 s, and the tool lifts off. Coulomb friction (``mu`` up to
  0.4) adds a tangential force along the motion; the pad gives 0.5-15 mm under the load, and the
  surface is uneven by 1.5-3.5 mm (together a plane fit of a stroke leaves ~0.5-3 mm RMS).
- **The operator's hand in free space.** The sensor also carries the hand's push on the
  gravity-compensated arm: the arm's inertia and damping against the motion
  (``OperatorModel``: m·a + c·v) plus a slow wander, 2-10 N typically, up to ~17 N.
- **The sensor.** Force and moment in the SENSOR (= tool) frame, measured ON the tool (the
  reaction, sign flipped w.r.t. the applied wrench), with a constant offset of 0.7-2.3 N in the
  sensor frame (not zeroed), Gaussian noise, averaged and sampled at 100 Hz; quaternions
  scalar-FIRST in the file; no time column (``recording_csv_text``).
- **Surfaces** (``SURFACES``): ``flat`` (horizontal table), ``tilted`` (a plane at 35°),
  ``curved`` (a cylinder of large radius, the stroke across its axis: the normal turns 25-40°
  along a stroke, plane RMS ~8-14 mm), like a car fender.

Everything is analytic (no physics engine) and seeded. The ground truth (`KinestheticTruth`)
holds per stroke the true contact interval (touch-down to lift-off), the inward normal (plane
surfaces) or per-sample inward normals (curved), the true force plateau (mean normal force
between the ramps), and the skill type a learner should find (slide for planes, contour for the
curved surface). World frame: z up, SI units, quaternions scalar-last ``[x, y, z, w]`` in the
arrays; see docs/CONVENTIONS.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from corpus.synthetic import minimum_jerk
from skills.frames import rotation_from_vectors
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix, quaternions_sign_continuous

SURFACES = ("flat", "tilted", "curved")
"""Surfaces a kinesthetic demonstration can be recorded on."""

SIMULATION_RATE_HZ = 1000.0
"""Rate the motion and forces are built at before the sensor averages them down, Hz."""

PAD_STIFFNESS_N_M = (2.0e3, 3.0e4)
"""Range of the stiffness of the tool pad (sponge to rubber), N/m: the tool point sinks force/stiffness into it."""


@dataclass(frozen=True)
class OperatorModel:
    """The force a hand puts on a gravity-compensated arm to move it, as the wrist sensor sees it (world, N).

    ``effective_mass_kg`` · acceleration + ``damping_n_s_m`` · velocity (the arm's apparent inertia
    and joint friction), plus a slow wander of ``wander_n`` (the hand leaning, gripping).
    """

    effective_mass_kg: float = 4.0
    damping_n_s_m: float = 20.0
    wander_n: float = 2.0


@dataclass(frozen=True)
class WristSensor:
    """A wrist force/torque sensor: constant offset in its own frame, noise, output rate."""

    offset: NDArray[np.float64]
    """(6,) offset of the raw reading in the sensor frame, measured-on-tool convention, N and N·m."""
    noise_force_n: float = 0.2
    noise_torque_nm: float = 0.004
    rate_hz: float = 100.0


@dataclass(frozen=True)
class StrokeTruth:
    """One stroke's ground truth: contact ``[t_on, t_off]`` (s), inward normal (planes), force plateau (N).

    The plateau is the mean true normal force between the ramps (the slow ±20 % swings included).
    """

    t_on: float
    t_off: float
    plateau_force_n: float
    normal: NDArray[np.float64] | None
    """Inward unit normal (into the surface) of the plane through the surface points the stroke touched
    (plane surfaces; the surface is uneven by a few mm, so it differs from the ideal plane's by up to ~3°);
    None on the curved surface."""
    normal_turn_deg: float
    """Angle the inward normal turns between the stroke's touch-down and lift-off, deg."""


@dataclass(frozen=True)
class KinestheticTruth:
    """Ground truth of a kinesthetic demonstration (arrays at the recording's samples)."""

    surface: str
    skill_type: str
    """The skill a learner should find: ``slide`` on planes, ``contour`` on the curved surface."""
    friction: float
    strokes: list[StrokeTruth]
    in_contact: NDArray[np.bool_]
    normals: NDArray[np.float64]
    """(N, 3) inward normal of the surface at the tool (also in free space: of the nearest surface point)."""
    normal_force_n: NDArray[np.float64]
    """(N,) true normal force the tool applies, N."""
    sensor_offset: NDArray[np.float64]
    """(6,) the sensor's offset, sensor frame, measured-on-tool convention (as in the file), N and N·m."""
    operator_force_max_n: float
    """Largest operator force in free space, N."""


@dataclass(frozen=True)
class KinestheticDemo:
    """Samples of a kinesthetic recording at the sensor rate, and its ground truth.

    ``positions`` (N, 3) m world; ``orientations`` (N, 4) world-from-tool, scalar-last;
    ``wrenches_applied`` (N, 6): the TRUE wrench the tool applies, world frame, no offset, no
    hand force, no noise; ``sensor_readings`` (N, 6): what the sensor file holds (sensor frame,
    measured on the tool, offset, hand, noise).
    """

    t: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]
    wrenches_applied: NDArray[np.float64]
    sensor_readings: NDArray[np.float64]
    truth: KinestheticTruth
    notes: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------- the hand and the sensor


def operator_forces(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    operator: OperatorModel,
    rng: np.random.Generator,
    in_contact: NDArray[np.bool_] | None = None,
) -> NDArray[np.float64]:
    """Return the force (N, 3) the guiding hand adds to the wrist sensor's reading, world frame, N.

    ``t`` (N,) s uniform, ``positions`` (N, 3) m of the tool point: the arm's apparent inertia and
    damping against the motion (m·a + c·v, velocities from positions smoothed over ~5 ms) plus a
    slow wander (0.1-0.7 Hz) of ``operator.wander_n``. In the applied-by-tool convention. Where
    ``in_contact`` the hand presses the tool onto the surface and leans aside by a quarter as much
    (the sideways force of a wipe is friction along the motion).
    """
    dt = float(t[1] - t[0])
    smoothed = gaussian_filter1d(positions, max(1.0, 0.005 / dt), axis=0, mode="nearest")
    velocity = np.gradient(smoothed, dt, axis=0)
    acceleration = np.gradient(velocity, dt, axis=0)
    wander = operator.wander_n * _slow_wander(t, rng, 0.1, 0.7, dims=3)
    if in_contact is not None:
        wander *= np.where(in_contact, 0.25, 1.0)[:, None]
    return operator.effective_mass_kg * acceleration + operator.damping_n_s_m * velocity + wander


def random_wrist_sensor(rng: np.random.Generator, rate_hz: float = 100.0) -> WristSensor:
    """Return a sensor with a random offset: 0.7-2.3 N of force in a random direction, ~0.05 N·m of moment."""
    direction = rng.normal(size=3)
    force = rng.uniform(0.7, 2.3) * direction / np.linalg.norm(direction)
    return WristSensor(offset=np.concatenate([force, rng.normal(0.0, 0.05, 3)]), rate_hz=rate_hz)


@dataclass(frozen=True)
class SensedRecording:
    """A fine simulation as the wrist sensor records it, at the sensor's rate.

    ``t`` (M,) s from 0; ``positions`` (M, 3) m; ``orientations`` (M, 4) scalar-last;
    ``readings`` (M, 6) the file's wrench (sensor frame, measured ON the tool, offset, hand, noise);
    ``wrenches_applied`` (M, 6) the true applied wrench (world), averaged like the readings;
    ``sample_index`` (M,) the fine sample each output sample is taken at (mid-period).
    """

    t: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]
    readings: NDArray[np.float64]
    wrenches_applied: NDArray[np.float64]
    sample_index: NDArray[np.int_]


def wrist_sensor_samples(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    orientations: NDArray[np.float64],
    wrenches_applied: NDArray[np.float64],
    hand_forces: NDArray[np.float64],
    sensor: WristSensor,
    rng: np.random.Generator,
) -> SensedRecording:
    """Return what a hand-guided wrist sensor records of a fine simulation.

    Inputs at the fine rate: ``t`` (N,) s uniform; ``positions`` (N, 3) m; ``orientations`` (N, 4)
    world-from-sensor (= tool), scalar-last; ``wrenches_applied`` (N, 6) the wrench the tool
    applies (world, N and N·m); ``hand_forces`` (N, 3) the hand's force (world, applied convention,
    see `operator_forces`). The sensor averages over each of its periods, reads the REACTION in
    its own frame (``-R^T (f + f_hand)``, ``-R^T m``) and adds its offset and noise.
    """
    stride = max(1, round(1.0 / (sensor.rate_hz * float(t[1] - t[0]))))
    n_out = t.size // stride
    rows = slice(0, n_out * stride)

    def averaged(values: NDArray) -> NDArray:
        return values[rows].reshape(n_out, stride, -1).mean(axis=1)

    sample = np.arange(n_out) * stride + stride // 2
    R = matrix_from_quaternion(orientations[sample])
    applied = averaged(wrenches_applied)
    loaded_force = applied[:, :3] + averaged(hand_forces)
    readings = np.empty((n_out, 6))
    readings[:, :3] = -np.einsum("nji,nj->ni", R, loaded_force)
    readings[:, 3:] = -np.einsum("nji,nj->ni", R, applied[:, 3:])
    readings += sensor.offset
    readings[:, :3] += rng.normal(0.0, sensor.noise_force_n, (n_out, 3))
    readings[:, 3:] += rng.normal(0.0, sensor.noise_torque_nm, (n_out, 3))
    return SensedRecording(
        t=np.arange(n_out) / sensor.rate_hz,
        positions=averaged(positions),
        orientations=quaternions_sign_continuous(orientations[sample]),
        readings=readings,
        wrenches_applied=applied,
        sample_index=sample,
    )


# --------------------------------------------------------------------------- surfaces


@dataclass(frozen=True)
class _Surface:
    """A surface in chart coordinates (u, v) m: point and OUTWARD unit normal (world)."""

    kind: str
    origin: NDArray[np.float64]
    e_u: NDArray[np.float64]
    e_v: NDArray[np.float64]
    radius_m: float = np.inf
    waviness_m: float = 0.0
    """Amplitude of the surface's unevenness along its normal, m (a real part is not a perfect plane)."""
    wavelength_m: tuple[float, float] = (0.3, 0.3)
    phase: tuple[float, float] = (0.0, 0.0)

    def unevenness(self, u: NDArray, v: NDArray) -> NDArray[np.float64]:
        """Height (N,) m of the surface above its ideal shape at chart coordinates ``u``, ``v``."""
        return self.waviness_m * (
            np.sin(2 * np.pi * u / self.wavelength_m[0] + self.phase[0])
            * np.cos(2 * np.pi * v / self.wavelength_m[1] + self.phase[1])
        )

    def point(self, u: NDArray, v: NDArray) -> NDArray[np.float64]:
        """Surface points (N, 3) m at chart coordinates ``u``, ``v`` (N,) m."""
        outward = self.outward_normal(u)
        bump = self.unevenness(u, v)[:, None] * outward
        if np.isinf(self.radius_m):
            return self.origin + u[:, None] * self.e_u + v[:, None] * self.e_v + bump
        centre = self.origin - self.radius_m * np.cross(self.e_u, self.e_v)
        return centre + v[:, None] * self.e_v + self.radius_m * outward + bump

    def outward_normal(self, u: NDArray) -> NDArray[np.float64]:
        """Outward unit normals (N, 3) at chart coordinate ``u`` (the normal does not depend on v)."""
        up = np.cross(self.e_u, self.e_v)
        if np.isinf(self.radius_m):
            return np.broadcast_to(up, (np.size(u), 3)).copy()
        angle = np.asarray(u) / self.radius_m
        return np.sin(angle)[:, None] * self.e_u + np.cos(angle)[:, None] * up


def _surface(kind: str, rng: np.random.Generator) -> _Surface:
    origin = np.array([0.55, rng.uniform(-0.1, 0.1), 0.12])
    yaw = rng.uniform(-np.pi, np.pi)
    e_u = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    e_v = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    uneven = {
        "waviness_m": rng.uniform(1.5e-3, 3.5e-3),
        "wavelength_m": (rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)),
        "phase": (rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi)),
    }
    if kind == "flat":
        return _Surface(kind, origin, e_u, e_v, **uneven)
    if kind == "tilted":
        tilt = np.radians(35.0)
        e_u_tilted = np.cos(tilt) * e_u + np.sin(tilt) * np.array([0.0, 0.0, 1.0])
        return _Surface(kind, origin, e_u_tilted, e_v, **uneven)
    if kind == "curved":
        return _Surface(kind, origin, e_u, e_v, radius_m=rng.uniform(0.7, 1.0), **uneven)
    raise ValueError(f"surface must be one of {SURFACES}, got {kind!r}")


# --------------------------------------------------------------------------- timeline


def _slow_wander(t: NDArray, rng: np.random.Generator, f_lo: float, f_hi: float, dims: int = 1) -> NDArray:
    """Sum of 3 sinusoids per dimension in [f_lo, f_hi] Hz, normalized to peak 1 (N, dims)."""
    freq = rng.uniform(f_lo, f_hi, size=(3, dims))
    phase = rng.uniform(0, 2 * np.pi, size=(3, dims))
    amp = rng.uniform(0.4, 1.0, size=(3, dims))
    wave = np.sum(amp[:, None, :] * np.sin(2 * np.pi * freq[:, None, :] * t[None, :, None] + phase[:, None, :]), axis=0)
    return wave / np.sum(amp, axis=0)


@dataclass
class _Phase:
    """A piece of the timeline: world positions over its samples, contact flag, stroke index (-1 free)."""

    positions: NDArray[np.float64]
    chart_u: NDArray[np.float64]
    stroke: int
    kind: str  # "free", "ramp_up", "plateau", "ramp_down"
    ramp: NDArray[np.float64] | None = None


def _stroke_chart_path(n: int, length_m: float, rng: np.random.Generator, surface: _Surface) -> tuple[NDArray, NDArray]:
    """Chart (u, v) of one wiping stroke over ``n`` samples: mostly along u (across a curved surface's axis)."""
    s = np.linspace(0.0, 1.0, n)
    # The hand speeds up and slows down (±25 %) and sometimes wipes back over a part of the stroke.
    warped = s + 0.25 / (2 * np.pi) * np.sin(2 * np.pi * s * rng.uniform(1.0, 2.0))
    warped = (warped - warped[0]) / (warped[-1] - warped[0])
    back = rng.uniform(0.0, 0.25) * np.sin(np.pi * s) ** 2 * np.sin(2 * np.pi * s * rng.integers(2, 4))
    along = length_m * (minimum_jerk(warped) * 0.8 + 0.2 * warped + back - 0.5)
    lateral = rng.uniform(0.01, 0.04) * np.sin(2 * np.pi * s * rng.uniform(0.8, 1.6) + rng.uniform(0, 6))
    direction = 1.0 if rng.random() < 0.5 else -1.0
    u = direction * along
    if np.isinf(surface.radius_m):
        # On a plane the stroke may run any way across it.
        angle = rng.uniform(-0.6, 0.6)
        return u * np.cos(angle) - lateral * np.sin(angle), u * np.sin(angle) + lateral * np.cos(angle)
    return u, lateral


def kinesthetic_wipe(
    surface: str = "flat",
    n_strokes: int = 2,
    friction: float = 0.3,
    seed: int = 0,
    operator: OperatorModel | None = None,
    sensor_rate_hz: float = 100.0,
    pad_stiffness_n_m: float | None = None,
) -> KinestheticDemo:
    """Return a kinesthetic wiping demonstration on ``surface`` with ``n_strokes`` strokes and its truth.

    ``friction`` is the Coulomb coefficient (the tangential force is ``friction`` × normal force,
    along the motion); ``seed`` makes it reproducible; ``pad_stiffness_n_m`` fixes the tool pad's
    stiffness (default: drawn from ``PAD_STIFFNESS_N_M``). See the module docstring for the facts it carries.
    """
    if not 1 <= n_strokes <= 6:
        raise ValueError(f"n_strokes must be 1..6, got {n_strokes}")
    rng = np.random.default_rng(seed)
    operator = operator or OperatorModel()
    geometry = _surface(surface, rng)
    dt = 1.0 / SIMULATION_RATE_HZ

    def samples(duration_s: float) -> int:
        return max(2, round(duration_s * SIMULATION_RATE_HZ))

    phases: list[_Phase] = []
    plateaus: list[float] = []
    # Stroke starts spread over the surface; the first starts near the chart origin.
    u_starts = rng.uniform(-0.05, 0.05, n_strokes)
    v_starts = np.linspace(-0.08, 0.08, n_strokes) + rng.uniform(-0.02, 0.02, n_strokes)
    hover = None
    for k in range(n_strokes):
        duration = rng.uniform(2.5, 9.0) if n_strokes > 1 else rng.uniform(4.0, 12.0)
        ramp_up_s, ramp_down_s = rng.uniform(0.5, 1.0, 2)
        slide_s = max(duration - ramp_up_s - ramp_down_s, 1.0)
        # Real wipes of curved parts: long strokes that leave their best plane by 8-14 mm RMS.
        length = rng.uniform(0.45, 0.6) if surface == "curved" else min(rng.uniform(0.07, 0.11) * slide_s, 0.5)
        n_up, n_slide, n_down = samples(ramp_up_s), samples(slide_s), samples(ramp_down_s)
        u_path, v_path = _stroke_chart_path(n_slide, length, rng, geometry)
        u_path, v_path = u_path + u_starts[k], v_path + v_starts[k]
        # The tool starts sliding during the ramp up and stops during the ramp down (a person does both).
        creep_in = minimum_jerk(np.linspace(0, 1, n_up)) ** 2 * 0.01
        creep_out = minimum_jerk(np.linspace(0, 1, n_down)) ** 0.5 * 0.01
        tangent_in = np.array([u_path[1] - u_path[0], v_path[1] - v_path[0]])
        tangent_in /= np.linalg.norm(tangent_in)
        tangent_out = np.array([u_path[-1] - u_path[-2], v_path[-1] - v_path[-2]])
        tangent_out /= np.linalg.norm(tangent_out)
        u_up = u_path[0] - tangent_in[0] * (0.01 - creep_in)
        v_up = v_path[0] - tangent_in[1] * (0.01 - creep_in)
        u_dn = u_path[-1] + tangent_out[0] * creep_out
        v_dn = v_path[-1] + tangent_out[1] * creep_out
        touch = geometry.point(u_up[:1], v_up[:1])[0]
        touch_normal = geometry.outward_normal(u_up[:1])[0]
        # Come down from 20-35 cm above the touch point, touching while still moving a few cm/s.
        lift_height = rng.uniform(0.20, 0.35)
        above = touch + lift_height * np.array([0.0, 0.0, 1.0]) + 0.05 * touch_normal
        if hover is None:
            rest = np.repeat(above[None], samples(rng.uniform(1.0, 2.0)), axis=0)
            phases.append(_Phase(rest, np.full(len(rest), u_up[0]), -1, "free"))
        else:
            traverse_s = rng.uniform(1.5, 2.5)
            g = minimum_jerk(np.linspace(0, 1, samples(traverse_s)))
            path = hover + (above - hover) * g[:, None]
            path[:, 2] += 0.06 * np.sin(np.pi * g)
            phases.append(_Phase(path, np.full(len(path), u_up[0]), -1, "free"))
        descent_s = rng.uniform(1.4, 2.2)
        x = np.linspace(0, 1, samples(descent_s))
        blend = 0.12
        g = (1 - blend) * minimum_jerk(x) + blend * x
        phases.append(_Phase(above + (touch - above) * g[:, None], np.full(len(x), u_up[0]), -1, "free"))

        plateau = rng.uniform(15.0, 32.0)
        plateaus.append(plateau)
        phases.append(_Phase(geometry.point(u_up, v_up), u_up, k, "ramp_up", minimum_jerk(np.linspace(0, 1, n_up))))
        phases.append(_Phase(geometry.point(u_path, v_path), u_path, k, "plateau"))
        phases.append(
            _Phase(geometry.point(u_dn, v_dn), u_dn, k, "ramp_down", 1.0 - minimum_jerk(np.linspace(0, 1, n_down)))
        )
        # Lift off along the normal first, then up: 20-35 cm.
        leave = geometry.point(u_dn[-1:], v_dn[-1:])[0]
        leave_normal = geometry.outward_normal(u_dn[-1:])[0]
        hover = leave + rng.uniform(0.20, 0.35) * np.array([0.0, 0.0, 1.0]) + 0.05 * leave_normal
        lift_s = rng.uniform(1.3, 2.0)
        x = np.linspace(0, 1, samples(lift_s))
        g = (1 - blend) * minimum_jerk(x) + blend * x
        phases.append(_Phase(leave + (hover - leave) * g[:, None], np.full(len(x), u_dn[-1]), -1, "free"))
    rest = np.repeat(hover[None], samples(rng.uniform(1.0, 2.0)), axis=0)
    phases.append(_Phase(rest, np.full(len(rest), phases[-1].chart_u[-1]), -1, "free"))

    path = np.concatenate([p.positions for p in phases])
    chart_u = np.concatenate([p.chart_u for p in phases])
    stroke_index = np.concatenate([np.full(len(p.positions), p.stroke) for p in phases])
    n = len(path)
    t = np.arange(n) * dt
    in_contact = stroke_index >= 0
    outward = geometry.outward_normal(chart_u)

    # Normal force: ramps, plateau with slow ±20 % swings.
    swing = 0.2 * _slow_wander(t, rng, 0.1, 0.5)[:, 0]
    level = np.zeros(n)
    start = 0
    for p in phases:
        stop = start + len(p.positions)
        if p.stroke >= 0:
            shape = p.ramp if p.ramp is not None else np.ones(len(p.positions))
            level[start:stop] = plateaus[p.stroke] * shape
        start = stop
    normal_force = level * (1.0 + swing)

    # The pad gives under the load; the hand trembles (tangentially only while on the surface).
    tremor = 4e-4 * _slow_wander(t, rng, 4.0, 9.0, dims=3)
    tremor -= in_contact[:, None] * np.sum(tremor * outward, axis=1, keepdims=True) * outward
    pad_stiffness = rng.uniform(*PAD_STIFFNESS_N_M) if pad_stiffness_n_m is None else pad_stiffness_n_m
    positions_fine = path - (normal_force / pad_stiffness)[:, None] * outward + tremor
    velocity = np.gradient(gaussian_filter1d(positions_fine, 5.0, axis=0, mode="nearest"), dt, axis=0)

    tangential = velocity - np.sum(velocity * outward, axis=1, keepdims=True) * outward
    speed = np.linalg.norm(tangential, axis=1, keepdims=True)
    slip = np.tanh(speed / 0.005) * tangential / np.maximum(speed, 1e-9)
    applied_force = normal_force[:, None] * (-outward + friction * slip)

    # Tool orientation: z roughly into the surface, tilted and turned by the hand; more so in free space.
    wobble_amplitude = np.where(in_contact, 0.10, 0.25)[:, None]
    wobble = wobble_amplitude * _slow_wander(t, rng, 0.05, 0.3, dims=3)
    tool_z = gaussian_filter1d(-outward, 200.0, axis=0, mode="nearest") + wobble
    yaw = 0.6 * _slow_wander(t, rng, 0.02, 0.1)[:, 0]
    pointing_down = np.diag([1.0, -1.0, -1.0])
    twist = np.stack(
        [
            np.stack([np.cos(yaw), -np.sin(yaw), np.zeros(n)], axis=1),
            np.stack([np.sin(yaw), np.cos(yaw), np.zeros(n)], axis=1),
            np.tile([0.0, 0.0, 1.0], (n, 1)),
        ],
        axis=1,
    )
    R = rotation_from_vectors(np.array([0.0, 0.0, -1.0]), tool_z) @ pointing_down @ twist
    orientations = quaternions_sign_continuous(quaternion_from_matrix(R))

    wrenches_fine = np.zeros((n, 6))
    wrenches_fine[:, :3] = applied_force
    hand = operator_forces(t, positions_fine, operator, rng, in_contact)
    sensor = random_wrist_sensor(rng, sensor_rate_hz)
    sensed = wrist_sensor_samples(t, positions_fine, orientations, wrenches_fine, hand, sensor, rng)
    sample, n_out = sensed.sample_index, sensed.sample_index.size
    applied_out = sensed.wrenches_applied[:, :3]
    offset = sensor.offset

    contact_out = in_contact[sample]
    stroke_out = stroke_index[sample]
    strokes = []
    for k in range(n_strokes):
        on = np.flatnonzero(stroke_index == k)
        plateau_rows = [i for i, p in enumerate(phases) if p.stroke == k and p.kind == "plateau"]
        p_start = sum(len(p.positions) for p in phases[: plateau_rows[0]])
        p_stop = p_start + len(phases[plateau_rows[0]].positions)
        n_on, n_off = -outward[on[0]], -outward[on[-1]]
        turn = float(np.degrees(np.arccos(np.clip(np.dot(n_on, n_off), -1.0, 1.0))))
        # The plane the stroke lies on: fitted to the surface points it touched (the surface is uneven).
        touched = path[on] - path[on].mean(axis=0)
        plane_normal = np.linalg.svd(touched, full_matrices=False)[2][2]
        plane_normal *= np.sign(np.dot(plane_normal, n_on))
        strokes.append(
            StrokeTruth(
                t_on=float(on[0] * dt),
                t_off=float(on[-1] * dt),
                plateau_force_n=float(np.mean(normal_force[p_start:p_stop])),
                normal=None if geometry.kind == "curved" else plane_normal,
                normal_turn_deg=turn,
            )
        )
    free_hand = np.linalg.norm(hand[~in_contact], axis=1)
    truth = KinestheticTruth(
        surface=surface,
        skill_type="contour" if geometry.kind == "curved" else "slide",
        friction=friction,
        strokes=strokes,
        in_contact=contact_out & (stroke_out >= 0),
        normals=-outward[sample],
        normal_force_n=normal_force[sample],
        sensor_offset=offset,
        operator_force_max_n=float(free_hand.max()),
    )
    wrenches_applied = np.zeros((n_out, 6))
    wrenches_applied[:, :3] = applied_out
    return KinestheticDemo(
        t=sensed.t,
        positions=sensed.positions,
        orientations=sensed.orientations,
        wrenches_applied=wrenches_applied,
        sensor_readings=sensed.readings,
        truth=truth,
    )


RECORDING_COLUMNS = ("x", "y", "z", "qw", "qx", "qy", "qz", "fx", "fy", "fz", "mx", "my", "mz")
"""Columns of a kinesthetic recording file: no time column, quaternion scalar-first, sensor-frame wrench."""


def recording_csv_text(demo: KinestheticDemo) -> str:
    """Return the demonstration as a real recording file holds it: fixed rate, NO time column, w-first quaternions.

    The wrench columns are the raw sensor readings: sensor (= tool) frame, measured ON the tool,
    with the sensor's offset. Import with ``rate=100, quaternion_order='wxyz',
    wrench='measured-on-tool', wrench_frame='tool'``.
    """
    q = demo.orientations
    table = np.column_stack([demo.positions, q[:, 3:4], q[:, :3], demo.sensor_readings])
    lines = [",".join(RECORDING_COLUMNS)]
    lines.extend(",".join(f"{value:.6g}" for value in row) for row in table)
    return "\n".join(lines) + "\n"
