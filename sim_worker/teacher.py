"""The scripted teacher: records demonstrations in the simulated world the way a person guiding the robot would.

The robot is driven in ``SimWorld`` at 1 kHz by the teacher's own torque-level controller (a Cartesian impedance
at the tool point with gravity/Coriolis compensation, plus, in contact, a force feed-forward with a PI correction
along the TRUE surface normal and only damping along it). The recorded wrench is the world's ``contact_wrench()``
(what the tool really applied in the simulation, through the world's sensor model, ideal by default) plus the
teacher's sensor noise; the recorded pose is ``tool_pose()``.

Every demonstration has the same phases: rest, free approach from above along the surface normal, guarded descent
until the force sensor reads ``contact_threshold_n``, force ramp-up, dwell, the motion in contact (sliding or
contouring), dwell, force ramp-down, retreat along the normal, rest.

Human-like imperfection (seeded, reproducible): the applied force wanders slowly around the target (± ``force_wander``,
a sum of 0.1-0.5 Hz sinusoids with zero mean over the contact phase), the hand trembles (``tremor_amplitude_m``,
4-9 Hz, in the desired position, tangential in contact), the path speed varies (± ``speed_variation``, with smooth
starts and stops), the orientation wobbles slightly, and the force sensor is noisy.

Scenarios (``SCENARIOS``): ``slide_flat``, ``slide_tilted``, ``slide_two_planes`` (one continuous contact that crosses
the concave crease between the table and a 20° ramp: two slide segments, split when the surface the ball is pressed
on changes, i.e. when the tool point crosses the crease, ±2 mm), ``contour_cylinder`` and ``contour_block``.

Ground truth (``TeacherRecording``): the true inward normal per sample (``normals_true``: the outward normal of the
nearest surface to the tool ball's centre, negated; for a ball this is exactly the direction of the normal contact
force the tool applies, i.e. it points INTO the surface), the true contact flag per sample and contact intervals,
the truth segments (free / slide with one constant normal / contour), the commanded force, the nominal (tremor-free)
path, the target force and the scenario's ``WorldConfig``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import JsonValue

from schemas.demonstration import Demonstration, DemonstrationMetadata
from schemas.job_budget import JobEstimate, JobPart
from schemas.text import JsonObject
from schemas.world import LEGACY_FIELDS, WorldConfig, WorldOverrides
from sim_worker.geometry import WorldGeometry
from sim_worker.robot_model import N_JOINTS, Q_HOME
from sim_worker.world import SimWorld
from skills.frames import matrix_from_axis_angle, rotation_vector_from_matrix
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix, quaternions_sign_continuous

R_TOOL_DOWN = np.diag([-1.0, 1.0, -1.0])
"""Tool orientation in a surface frame (z = outward normal) that points the tool z axis into the surface."""

SCENARIOS: dict[str, str] = {
    "slide_flat": "Slide an S-curve (0.3 m) on the horizontal table at 15 N.",
    "slide_tilted": "Slide an S-curve (0.3 m) on the table tilted 15° about the world x axis at 15 N.",
    "slide_two_planes": "Slide across the concave crease from the table onto a 20° ramp in one continuous contact at "
    "15 N: two slide segments with different normals, split where the tool point crosses the crease.",
    "contour_cylinder": "Contour over a cylinder (radius 0.08 m) lying on the table, ±50° around its top, with 12 N "
    "along the local normal.",
    "contour_block": "Contour along the elliptical cap (0.30 m × 0.06 m) of a curved block on the table, normal "
    "tilting ±35°, with 12 N along the local normal.",
}


@dataclass
class TeacherParams:
    """How the teacher moves and pushes; every field can be overridden in ``record_demonstration``."""

    target_force_n: float = 15.0
    force_wander: float = 0.20
    tremor_amplitude_m: float = 0.5e-3
    orientation_wobble_rad: float = 0.005
    speed_variation: float = 0.25
    move_duration_s: float = 5.0
    rest_s: float = 0.3
    approach_height_m: float = 0.08
    approach_duration_s: float = 1.0
    guard_height_m: float = 0.012
    guard_speed_m_s: float = 0.015
    contact_threshold_n: float = 1.0
    ramp_up_s: float = 0.4
    dwell_s: float = 0.3
    ramp_down_s: float = 0.3
    retreat_duration_s: float = 1.0
    sensor_noise_force_n: float = 0.15
    sensor_noise_torque_nm: float = 0.003
    # Controller gains (torque-level Cartesian impedance at the tool point).
    stiffness_n_m: float = 2000.0
    damping_n_s_m: float = 100.0
    rot_stiffness_nm_rad: float = 30.0
    rot_damping_nm_s_rad: float = 0.3
    normal_damping_n_s_m: float = 150.0
    force_integral_gain: float = 10.0
    force_integral_limit_n: float = 10.0
    joint_damping_nm_s_rad: float = 0.5
    null_stiffness_nm_rad: float = 5.0


@dataclass
class TruthSegment:
    """A ground-truth segment: ``kind`` is ``free``, ``slide`` (constant inward ``normal``) or ``contour``."""

    kind: str
    t_start: float
    t_end: float
    surface: str = ""
    normal: list[float] | None = None


@dataclass
class TeacherRecording:
    """A recorded demonstration and its ground truth (arrays have one row per demonstration sample).

    Attributes:
        demonstration: the validated ``Demonstration`` (metadata.source ``teacher:<scenario>``).
        world_config: the world it was recorded in (execute in ``SimWorld(world_config)`` for the same world).
        target_force_n: the force the teacher aimed at (N); ``force_desired`` the commanded force per sample
            (wandering around the target, 0 outside contact).
        contact_intervals: (t_on, t_off) of the true contact (PyBullet contact points), s.
        segments: free / slide (constant ``normal`` into the surface) / contour truth segments.
        in_contact: true contact flag per sample.
        normals_true: (N, 3) unit normal INTO the nearest surface at the contact point (the direction of the normal
            force the tool applies); defined for every sample, meaningful where ``in_contact``.
        normal_force_true: (N, 3) the normal part of the applied force (friction excluded), from PyBullet.
        wrench_true: (N, 6) the applied wrench without sensor noise.
        path_nominal: (N, 3) the intended, tremor-free tool point path.
        surface_names: nearest surface per sample (``table``, ``ramp``, ``cylinder``, ``block``).
    """

    scenario: str
    seed: int
    skill_type: str
    demonstration: Demonstration
    world_config: WorldConfig
    params: TeacherParams
    target_force_n: float
    contact_intervals: list[tuple[float, float]]
    segments: list[TruthSegment]
    in_contact: NDArray[np.bool_]
    normals_true: NDArray[np.float64]
    force_desired: NDArray[np.float64]
    path_nominal: NDArray[np.float64]
    wrench_true: NDArray[np.float64]
    normal_force_true: NDArray[np.float64]
    surface_names: list[str] = field(default_factory=list)

    def contact_segments(self) -> list[TruthSegment]:
        """The truth segments in contact (slide or contour)."""
        return [s for s in self.segments if s.kind != "free"]

    def ground_truth_dict(self) -> JsonObject:
        """JSON-able summary of the ground truth (no per-sample arrays)."""
        return {
            "scenario": self.scenario,
            "seed": self.seed,
            "skill_type": self.skill_type,
            "target_force_n": self.target_force_n,
            "contact_intervals": [list(i) for i in self.contact_intervals],
            "segments": [asdict(s) for s in self.segments],
            "world_config": self.world_config.to_dict(),
            "params": asdict(self.params),
        }


# ---------------------------------------------------------------------------------------------------------------
# Paths: s in [0, 1] -> surface point, outward normal, tool rotation.
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class _Scenario:
    kind: str  # "slide" | "contour"
    world: WorldOverrides
    params: dict[str, float]
    path: Callable[[WorldGeometry], Callable[[float], tuple[NDArray, NDArray, NDArray]]]
    surface_of: Callable[[WorldGeometry, float], str] = lambda g, s: "table"


def _smoothstep(x: NDArray | float) -> NDArray | float:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)


def _slide_path(geometry: WorldGeometry):
    R = geometry.table_R @ R_TOOL_DOWN
    n = geometry.table_normal

    def path(s: float):
        x = -0.03 + 0.05 * math.sin(2.0 * math.pi * s)
        y = -0.13 + 0.26 * s
        return geometry.table_point(x, y), n, R

    return path


_TWO_PLANES_HALF = 0.14
_TWO_PLANES_BLEND = 0.02


def _two_planes_u(s: float) -> float:
    return -_TWO_PLANES_HALF + 2.0 * _TWO_PLANES_HALF * s


def _two_planes_path(geometry: WorldGeometry):
    c = geometry.config
    n_table, n_ramp = geometry.table_normal, geometry.ramp_normal
    R_table = geometry.table_R @ R_TOOL_DOWN
    R_ramp = geometry.solids["ramp"].R @ R_TOOL_DOWN
    tilt = math.radians(c.ramp.tilt_deg)
    axis = geometry.table_R[:, 1]

    def path(s: float):
        u = _two_planes_u(s)
        y = 0.07 * math.sin(2.0 * math.pi * s)
        point = geometry.table_point(c.ramp.crease_x_m + u, y) if u < 0 else geometry.ramp_point(u, y)
        w = float(_smoothstep((u + _TWO_PLANES_BLEND) / (2.0 * _TWO_PLANES_BLEND)))
        R_blend = matrix_from_axis_angle(axis, -tilt * w) @ R_table
        n = n_table if u < 0 else n_ramp
        if abs(u) < _TWO_PLANES_BLEND:
            n = -R_blend[:, 2]
        return point, n, (R_ramp if w >= 1.0 else R_blend)

    return path


def _cylinder_path(geometry: WorldGeometry):
    cyl = geometry.solids["cylinder"]
    theta_max = math.radians(50.0)

    def path(s: float):
        theta = -theta_max + 2.0 * theta_max * s
        y = 0.02 * math.sin(math.pi * s)
        local = np.array([cyl.radius * math.sin(theta), y, cyl.radius * math.cos(theta)])
        n = cyl.R @ np.array([math.sin(theta), 0.0, math.cos(theta)])
        R = cyl.R @ matrix_from_axis_angle((0.0, 1.0, 0.0), theta) @ R_TOOL_DOWN
        return cyl.p + cyl.R @ local, n, R

    return path


def _block_path(geometry: WorldGeometry):
    block = geometry.solids["block"]
    phi0, phi1 = math.radians(150.0), math.radians(30.0)

    def path(s: float):
        phi = phi0 + (phi1 - phi0) * s
        x, z = block.profile_point(phi)
        nx, nz = block.profile_normal(phi)
        y = 0.015 * math.sin(math.pi * s)
        tilt = math.atan2(float(nx), float(nz))
        R = block.R @ matrix_from_axis_angle((0.0, 1.0, 0.0), tilt) @ R_TOOL_DOWN
        return block.p + block.R @ np.array([float(x), y, float(z)]), block.R @ np.array([float(nx), 0.0, float(nz)]), R

    return path


_SCENARIOS: dict[str, _Scenario] = {
    "slide_flat": _Scenario("slide", {}, {}, _slide_path),
    "slide_tilted": _Scenario("slide", {"table_tilt_deg": 15.0, "table_tilt_axis": [1.0, 0.0, 0.0]}, {}, _slide_path),
    "slide_two_planes": _Scenario(
        "slide",
        {"ramp_enabled": True, "ramp_tilt_deg": 20.0, "ramp_crease_x_m": 0.0},
        {"move_duration_s": 6.0},
        _two_planes_path,
        lambda g, s: "table" if _two_planes_u(s) < 0 else "ramp",
    ),
    "contour_cylinder": _Scenario(
        "contour",
        {"cylinder_enabled": True, "cylinder_xy_m": [0.0, 0.0], "cylinder_yaw_deg": 90.0},
        {"target_force_n": 12.0, "move_duration_s": 6.0},
        _cylinder_path,
        lambda g, s: "cylinder",
    ),
    "contour_block": _Scenario(
        "contour",
        {"block_enabled": True, "block_xy_m": [0.0, 0.0], "block_yaw_deg": 90.0},
        {"target_force_n": 12.0, "move_duration_s": 6.0},
        _block_path,
        lambda g, s: "block",
    ),
}
assert set(_SCENARIOS) == set(SCENARIOS)


def scenario_world_config(scenario: str) -> WorldConfig:
    """Return the ``WorldConfig`` a scenario records in (the taught world), without recording.

    Raises ValueError naming the known scenarios for an unknown name.
    """
    if scenario not in _SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known: {sorted(_SCENARIOS)}")
    return WorldConfig().replace(**_SCENARIOS[scenario].world)


# ---------------------------------------------------------------------------------------------------------------
# Human-like signals.
# ---------------------------------------------------------------------------------------------------------------


def _slow_signal(rng: np.random.Generator, t: NDArray, f_lo: float, f_hi: float, n: int = 3) -> NDArray:
    """Sum of ``n`` sinusoids with random frequencies in [f_lo, f_hi] Hz and random phases, peak-normalized to 1."""
    freqs = rng.uniform(f_lo, f_hi, n)
    phases = rng.uniform(0.0, 2.0 * math.pi, n)
    amps = rng.uniform(0.5, 1.0, n)
    x = (amps[:, None] * np.sin(2.0 * math.pi * freqs[:, None] * t[None, :] + phases[:, None])).sum(axis=0)
    return x / max(np.abs(x).max(), 1e-12)


def _min_jerk(x: float) -> float:
    return float(_smoothstep(x))


# ---------------------------------------------------------------------------------------------------------------
# The teacher's controller.
# ---------------------------------------------------------------------------------------------------------------


class _Controller:
    """Torque-level Cartesian impedance at the tool point; in contact: force along the normal, damping only."""

    def __init__(self, world: SimWorld, params: TeacherParams, q_rest: NDArray):
        self.world = world
        self.p = params
        self.q_rest = q_rest
        self.force_integral = 0.0

    def torque(
        self,
        p_d: NDArray,
        v_d: NDArray,
        R_d: NDArray,
        push_dir: NDArray | None = None,
        force_des: float = 0.0,
        force_meas: float = 0.0,
    ) -> NDArray:
        w, prm = self.world, self.p
        q, qd = w.joint_state()
        J = w.jacobian()
        p, _ = w.tool_pose()
        R = w.tool_rotation()
        twist = J @ qd
        v, omega = twist[:3], twist[3:]
        F = np.empty(6)
        f_lin = prm.stiffness_n_m * (p_d - p) + prm.damping_n_s_m * (v_d - v)
        if push_dir is not None:
            n = push_dir
            f_lin -= n * (n @ f_lin)
            dt = w.config.time_step_s
            self.force_integral = float(
                np.clip(
                    self.force_integral + prm.force_integral_gain * (force_des - force_meas) * dt,
                    -prm.force_integral_limit_n,
                    prm.force_integral_limit_n,
                )
            )
            # Force the TOOL applies along n (into the surface): the controller pushes the tool along n.
            f_lin += n * (force_des + self.force_integral - prm.normal_damping_n_s_m * (n @ v))
        else:
            self.force_integral = 0.0
        F[:3] = f_lin
        F[3:] = prm.rot_stiffness_nm_rad * rotation_vector_from_matrix(R_d @ R.T) - prm.rot_damping_nm_s_rad * omega
        JJt = J @ J.T + 1e-4 * np.eye(6)
        J_pinv = J.T @ np.linalg.inv(JJt)
        null = np.eye(N_JOINTS) - J.T @ J_pinv.T
        tau = w.gravity_coriolis_torques() + J.T @ F - prm.joint_damping_nm_s_rad * qd
        tau += null @ (prm.null_stiffness_nm_rad * (self.q_rest - q))
        return tau


# ---------------------------------------------------------------------------------------------------------------
# Recording.
# ---------------------------------------------------------------------------------------------------------------


def _split_overrides(overrides: Mapping[str, JsonValue]) -> tuple[JsonObject, JsonObject]:
    world_names = {*WorldConfig.model_fields, *LEGACY_FIELDS}
    param_names = {f.name for f in fields(TeacherParams)}
    world: JsonObject = {}
    params: JsonObject = {}
    for key, value in overrides.items():
        if key in param_names:
            params[key] = value
        elif key in world_names:
            world[key] = value
        else:
            raise TypeError(f"unknown override {key!r}: not a TeacherParams or WorldConfig field")
    return world, params


def _intervals(t: NDArray, flags: NDArray) -> list[tuple[float, float]]:
    """Contiguous runs of True in ``flags`` as (t_first, t_last)."""
    out = []
    padded = np.concatenate([[False], flags, [False]]).astype(int)
    starts = np.flatnonzero(np.diff(padded) == 1)
    ends = np.flatnonzero(np.diff(padded) == -1) - 1
    for a, b in zip(starts, ends, strict=True):
        out.append((float(t[a]), float(t[b])))
    return out


def record_demonstration(scenario: str, seed: int = 0, **overrides: Any) -> TeacherRecording:
    """Record the scripted demonstration of ``scenario`` (a key of ``SCENARIOS``) at 1 kHz.

    ``overrides`` are ``TeacherParams`` fields (e.g. ``target_force_n=10``, ``move_duration_s=4``) or
    ``WorldConfig`` fields (e.g. ``table_height_m=0.15``). Same scenario, seed and overrides give the same recording.
    """
    spec, config, params = _resolved(scenario, overrides)
    rng = np.random.default_rng(seed)
    with SimWorld(config) as world:
        return _record(world, scenario, spec, params, rng, seed)


def recording_estimate(scenario: str, **overrides: Any) -> JobEstimate:
    """What recording ``scenario`` with ``overrides`` implies (``schemas.job_budget``), before recording: its phases
    at the world's time step, the guarded descent at its longest; its log signals are allocated for the whole
    horizon at once. Raises ValueError or TypeError as :func:`record_demonstration` does."""
    _, config, params = _resolved(scenario, overrides)
    parts = _recording_parts(params)
    longest = max(parts, key=lambda part: part.simulated_s)
    horizon = JobPart(
        what=f"the recording's horizon (its longest stretch: {longest.what})",
        field=longest.field,
        simulated_s=sum(part.simulated_s for part in parts) + HORIZON_MARGIN_S,
    )
    return JobEstimate(
        kind="recording",
        time_step_s=config.time_step_s,
        time_step_field="overrides.time_step_s",
        parts=parts,
        longest_phase=horizon,
    )


def _resolved(scenario: str, overrides: Mapping[str, JsonValue]) -> tuple[_Scenario, WorldConfig, TeacherParams]:
    """The scenario, its world and the teacher's parameters with ``overrides`` applied."""
    if scenario not in _SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known: {sorted(SCENARIOS)}")
    spec = _SCENARIOS[scenario]
    world_over, param_over = _split_overrides(overrides)
    config = WorldConfig().replace(**{**spec.world, **world_over})
    return spec, config, TeacherParams(**{**asdict(TeacherParams()), **spec.params, **param_over})


HORIZON_MARGIN_S = 1.0
"""The teacher's signals run this long past the longest recording its parameters allow, s."""


def _longest_descent_s(prm: TeacherParams) -> float:
    """The longest guarded descent before it gives up (three times its height and a centimetre), s."""
    return 3.0 * (prm.guard_height_m + 0.01) / prm.guard_speed_m_s


def _recording_parts(prm: TeacherParams) -> list[JobPart]:
    """The stretches of a recording with parameters ``prm`` (the guarded descent at its longest), each named by the
    override that sets its length."""
    stretches = [
        ("the rests before and after", "rest_s", 2.0 * prm.rest_s),
        ("the approach from above", "approach_duration_s", prm.approach_duration_s),
        (f"the guarded descent at guard_speed_m_s {prm.guard_speed_m_s:g} m/s at its longest", "guard_speed_m_s",
         _longest_descent_s(prm)),
        ("the force ramp up", "ramp_up_s", prm.ramp_up_s),
        ("the dwells", "dwell_s", 2.0 * prm.dwell_s),
        ("the motion in contact", "move_duration_s", prm.move_duration_s),
        ("the force ramp down", "ramp_down_s", prm.ramp_down_s),
        ("the retreat", "retreat_duration_s", prm.retreat_duration_s),
    ]  # fmt: skip
    return [JobPart(what=what, field=f"overrides.{name}", simulated_s=s) for what, name, s in stretches]


def _record(
    world: SimWorld, scenario: str, spec: _Scenario, params: TeacherParams, rng: np.random.Generator, seed: int
) -> TeacherRecording:
    geometry = world.geometry
    path = spec.path(geometry)
    dt = world.config.time_step_s
    prm = params

    # Path timing: speed varies around its mean, smooth start and stop; s(t) over the motion phase.
    T_move = prm.move_duration_s
    n_move = round(T_move / dt)
    t_move = np.arange(n_move + 1) * dt
    envelope = np.minimum(_smoothstep(t_move / 0.5), _smoothstep((T_move - t_move) / 0.5))
    speed = envelope * (1.0 + prm.speed_variation * _slow_signal(rng, t_move, 0.2, 0.6))
    s_of_move = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]))])
    s_of_move /= s_of_move[-1]

    # Tremor (3-D, 4-9 Hz) and orientation wobble, generated for a generous horizon.
    horizon = sum(part.simulated_s for part in _recording_parts(prm)) + HORIZON_MARGIN_S
    t_all = np.arange(round(horizon / dt)) * dt
    tremor = np.zeros((t_all.size, 3))
    for _ in range(3):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        f, ph = rng.uniform(4.0, 9.0), rng.uniform(0.0, 2.0 * math.pi)
        tremor += np.outer(np.sin(2.0 * math.pi * f * t_all + ph), direction)
    tremor *= prm.tremor_amplitude_m / max(np.abs(tremor).max(), 1e-12)
    wobble = np.stack([_slow_signal(rng, t_all, 0.3, 1.5) for _ in range(3)], axis=1) * prm.orientation_wobble_rad
    force_signal = _slow_signal(rng, t_all, 0.1, 0.5)
    noise_rng = np.random.default_rng(rng.integers(2**63))

    # Start: at rest above the first path point, along its outward normal.
    p0, n0, R0 = path(0.0)
    p_above = p0 + prm.approach_height_m * n0
    q_start = world.inverse_kinematics(p_above, quaternion_from_matrix(R0), Q_HOME)
    world.reset(q_start)
    ctrl = _Controller(world, prm, q_start)

    # The signals of every step, over the horizon at once (a minute's lists of small arrays took ~60 MB more).
    n_all = t_all.size
    log_t, log_fd, log_s, log_c = np.empty(n_all), np.empty(n_all), np.empty(n_all), np.empty(n_all, bool)
    log_p, log_fn, log_nom = np.empty((n_all, 3)), np.empty((n_all, 3)), np.empty((n_all, 3))
    log_q, log_w, log_sensor = np.empty((n_all, 4)), np.empty((n_all, 6)), np.empty((n_all, 6))
    k = 0

    def run(p_d, v_d, R_d, nominal, push=None, f_des=0.0, s_val=-1.0):
        nonlocal k
        wob = matrix_from_axis_angle(wobble[k], float(np.linalg.norm(wobble[k]))) if np.any(wobble[k]) else np.eye(3)
        R_cmd = wob @ R_d
        f_meas = 0.0
        wrench = world.true_contact_wrench()
        if push is not None:
            f_meas = float(wrench[:3] @ push)
        tau = ctrl.torque(p_d + tremor[k], v_d, R_cmd, push, f_des, f_meas)
        world.step(tau)
        p, quat = world.tool_pose()
        log_t[k] = k * dt
        log_p[k] = p
        log_q[k] = quat
        log_w[k] = world.true_contact_wrench()
        log_sensor[k] = world.contact_wrench()
        log_fn[k] = world.contact_forces()[0]
        log_c[k] = world.in_contact()
        log_fd[k] = f_des if push is not None else 0.0
        log_nom[k] = nominal
        log_s[k] = s_val
        k += 1

    zero = np.zeros(3)
    # Rest.
    for _ in range(round(prm.rest_s / dt)):
        run(p_above, zero, R0, p_above)
    # Free approach to the guard height (min-jerk).
    p_guard = p0 + prm.guard_height_m * n0
    n_app = round(prm.approach_duration_s / dt)
    for i in range(n_app):
        a = _min_jerk((i + 1) / n_app)
        p_d = p_above + a * (p_guard - p_above)
        run(p_d, zero, R0, p_d)
    # Guarded descent along the normal until the force sensor reads the threshold.
    p_d = p_guard.copy()
    v_guard = -prm.guard_speed_m_s * n0
    max_guard = round(_longest_descent_s(prm) / dt)
    for _ in range(max_guard):
        p_d = p_d + v_guard * dt
        run(p_d, v_guard, R0, p_d.copy())
        if float(log_w[k - 1, :3] @ -n0) > prm.contact_threshold_n:
            break
    else:
        raise RuntimeError(f"{scenario}: no contact found during the guarded approach")

    # Contact phase: the commanded force (ramp up, dwell, wander during the motion, dwell, ramp down).
    F = prm.target_force_n
    n_up, n_dwell, n_down = round(prm.ramp_up_s / dt), round(prm.dwell_s / dt), round(prm.ramp_down_s / dt)
    k_contact0 = k
    n_contact = n_up + n_dwell + (n_move + 1) + n_dwell + n_down
    wander = force_signal[k_contact0 : k_contact0 + n_contact].copy()
    core = slice(n_up, n_contact - n_down)
    wander[core] -= wander[core].mean()
    wander = np.clip(wander, -1.2, 1.2)
    f_start = float(log_w[k - 1, :3] @ -n0)
    profile = F * (1.0 + prm.force_wander * wander)
    ramp_up = np.array([_min_jerk((i + 1) / n_up) for i in range(n_up)])
    profile[:n_up] = f_start + ramp_up * (profile[:n_up] - f_start)
    f_end = 2.0  # the person lifts off while still pressing lightly
    ramp_down = np.array([_min_jerk((i + 1) / n_down) for i in range(n_down)])
    profile[-n_down:] = profile[-n_down:] + ramp_down * (f_end - profile[-n_down:])

    p_hold = world.tool_pose()[0]
    i_force = 0

    def contact_step(p_d, v_d, R_d, n_out, nominal, s_val):
        nonlocal i_force
        run(p_d, v_d, R_d, nominal, push=-n_out, f_des=float(profile[i_force]), s_val=s_val)
        i_force += 1

    contour_solid = geometry.solids[spec.surface_of(geometry, 0.5)]

    def push_normal(R_d: NDArray, n_nominal: NDArray) -> NDArray:
        if spec.kind == "contour":
            # The true normal at the tool ball's centre (the person feels the surface).
            p, _ = world.tool_pose()
            centre = p - world.config.tool.radius_m * world.tool_rotation()[:, 2]
            return contour_solid.outward_normal(centre)
        return n_nominal

    for _ in range(n_up + n_dwell):
        contact_step(p_hold, zero, R0, push_normal(R0, n0), p0, 0.0)
    prev = path(0.0)[0]
    for i in range(n_move + 1):
        s = float(s_of_move[i])
        p_s, n_s, R_s = path(s)
        v_s = (p_s - prev) / dt if i > 0 else zero
        prev = p_s
        contact_step(p_s, v_s, R_s, push_normal(R_s, n_s), p_s, s)
    p1, n1, R1 = path(1.0)
    for _ in range(n_dwell + n_down):
        contact_step(p1, zero, R1, push_normal(R1, n1), p1, 1.0)

    # Retreat along the normal (min-jerk) and rest.
    p_start = world.tool_pose()[0] + 0.002 * n1  # a decisive lift-off: the hand tremor cannot touch again
    p_top = p1 + prm.approach_height_m * n1
    n_ret = round(prm.retreat_duration_s / dt)
    for i in range(n_ret):
        a = _min_jerk((i + 1) / n_ret)
        p_d = p_start + a * (p_top - p_start)
        run(p_d, zero, R1, p1 + a * (p_top - p1))
    for _ in range(round(prm.rest_s / dt)):
        run(p_top, zero, R1, p_top)

    # Assemble.
    t, positions, s_log = log_t[:k], log_p[:k], log_s[:k]
    quats = quaternions_sign_continuous(log_q[:k])
    wrench_true = log_w[:k]
    noise = noise_rng.normal(size=wrench_true.shape) * np.array(
        [prm.sensor_noise_force_n] * 3 + [prm.sensor_noise_torque_nm] * 3
    )
    wrenches = log_sensor[:k] + noise
    in_contact = log_c[:k]
    R_all = matrix_from_quaternion(quats)
    centres = positions - world.config.tool.radius_m * R_all[:, :, 2]
    query = geometry.query(centres)
    normals_true = -query.normal

    intervals = _intervals(t, in_contact)
    segments = _truth_segments(t, in_contact, s_log, spec, geometry, normals_true, query.name)
    metadata = DemonstrationMetadata(
        name=f"{scenario} (seed {seed})",
        source=f"teacher:{scenario}",
        extra={
            "scenario": scenario,
            "seed": seed,
            "skill_type": spec.kind,
            "target_force_n": F,
            "world": world.config.to_dict(),
        },
    )
    demonstration = Demonstration.from_arrays(t, positions, quats, wrenches, metadata)
    return TeacherRecording(
        scenario=scenario,
        seed=seed,
        skill_type=spec.kind,
        demonstration=demonstration,
        world_config=world.config,
        params=prm,
        target_force_n=F,
        contact_intervals=intervals,
        segments=segments,
        in_contact=in_contact,
        normals_true=normals_true,
        force_desired=log_fd[:k],
        path_nominal=log_nom[:k],
        wrench_true=wrench_true,
        normal_force_true=log_fn[:k],
        surface_names=list(query.name),
    )


def _truth_segments(
    t: NDArray,
    in_contact: NDArray,
    s_log: NDArray,
    spec: _Scenario,
    geometry: WorldGeometry,
    normals_true: NDArray,
    names: list[str],
) -> list[TruthSegment]:
    """Free / slide / contour segments from the true contact flags and, for slides, the surface under the path."""
    idx = np.flatnonzero(in_contact)
    if idx.size == 0:
        return [TruthSegment("free", float(t[0]), float(t[-1]))]
    on, off = int(idx[0]), int(idx[-1])
    segments = [TruthSegment("free", float(t[0]), float(t[on]))]
    if spec.kind == "contour":
        segments.append(TruthSegment("contour", float(t[on]), float(t[off]), spec.surface_of(geometry, 0.5)))
    else:
        # Split where the surface the ball is pressed on changes (slide_two_planes: the crease).
        surfaces = names[on : off + 1]
        start = on
        for i in range(on + 1, off + 2):
            if i == off + 1 or surfaces[i - on] != surfaces[i - 1 - on]:
                name = surfaces[i - 1 - on]
                normal = -(geometry.ramp_normal if name == "ramp" else geometry.table_normal)
                segments.append(TruthSegment("slide", float(t[start]), float(t[i - 1]), name, normal.tolist()))
                start = i
    segments.append(TruthSegment("free", float(t[off]), float(t[-1])))
    return segments
