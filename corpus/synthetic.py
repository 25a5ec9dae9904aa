"""Analytic demonstrations with known ground truth (for tests, benchmarks and documentation).

Each generator returns the sampled arrays of a demonstration (world frame, SI, quaternions
``[x, y, z, w]``, wrench applied by the tool) and the truth it was built from: surface normal(s)
pointing INTO the surface (along the applied normal force), target force, contact on/off times,
and the noise-free applied-force direction. Imperfections are human-like and seeded: the normal
force wanders ±20 % around the target (zero mean over the contact), the path has tremor, the
speed varies, the force sensor is noisy, and Coulomb friction tilts the applied force along the
motion. No physics engine is involved: the PyBullet teacher in `sim_worker/` is the physical one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from skills.frames import rotation_from_vectors
from skills.quaternions import quaternion_from_matrix

FRICTION_COEFFICIENT = 0.3
"""Coulomb coefficient of the synthetic surfaces: friction force = mu * normal force, along the motion."""


@dataclass(frozen=True)
class SyntheticDemo:
    """Arrays of one analytic demonstration plus its ground truth.

    ``normals`` holds one unit normal per contact phase (slide), pointing into the surface;
    ``force_direction`` is the intended unit applied force per sample (zero where free): normal
    force plus friction along the path, without sensor noise and without the jitter that hand
    tremor adds to the friction direction (a skill should not reproduce tremor).
    """

    t: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]
    wrenches: NDArray[np.float64]
    normals: list[NDArray[np.float64]]
    target_force_n: float
    contact_on_s: float
    contact_off_s: float
    force_direction: NDArray[np.float64]
    normal_force_true: NDArray[np.float64]
    phase_change_s: list[float] = field(default_factory=list)


def minimum_jerk(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the minimum-jerk profile 10u^3 - 15u^4 + 6u^5 (a C2 smooth step) of ``u`` clipped to [0, 1]."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def _contact_interval(duration_s: float) -> tuple[float, float]:
    """Return true contact on/off times (s): free approach and retreat of 1.5 s, or 20 % each of a short demo."""
    free_s = min(1.5, 0.2 * duration_s)
    return free_s, duration_s - free_s


def _zero_mean_wander(t: NDArray[np.float64], t0: float, t1: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """Return a slow relative wander in [-0.2, 0.2] over ``[t0, t1]`` with zero mean there (whole periods)."""
    span = t1 - t0
    u = (t - t0) / span
    periods = np.array([1.0, 2.0, 3.0])
    amplitudes = rng.uniform(0.3, 1.0, size=3)
    phases = rng.uniform(0, 2 * np.pi, size=3)
    wave = np.sum(amplitudes[:, None] * np.sin(2 * np.pi * periods[:, None] * u[None, :] + phases[:, None]), axis=0)
    return 0.2 * wave / np.sum(amplitudes)


def _tool_orientations(force_dirs: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return tool quaternions whose z axis follows ``force_dirs`` with a slow human wobble (a few degrees).

    The tool starts pointing down (z axis = world -z) and is turned by the minimal rotation
    onto each direction, far from the antipode where that rotation is undefined.
    """
    wobble = 0.05 * np.stack([np.sin(0.7 * t), np.cos(0.5 * t), np.zeros_like(t)], axis=1)
    tool_z = force_dirs + wobble
    pointing_down = np.diag([1.0, -1.0, -1.0])
    R = rotation_from_vectors(np.array([0.0, 0.0, -1.0]), tool_z) @ pointing_down
    return quaternion_from_matrix(R)


def _applied_force(
    normal: NDArray[np.float64], velocity: NDArray[np.float64], magnitude: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Return the applied force: ``magnitude`` along ``normal`` plus Coulomb friction along the tangential velocity."""
    v_t = velocity - np.sum(velocity * normal, axis=1, keepdims=True) * normal
    speed = np.linalg.norm(v_t, axis=1, keepdims=True)
    direction = np.where(speed > 1e-6, v_t / np.maximum(speed, 1e-12), 0.0)
    # Friction is smoothed in at low speed (no jump at rest), as a real contact behaves.
    regularized = np.tanh(speed / 0.005)
    return magnitude[:, None] * (normal + FRICTION_COEFFICIENT * regularized * direction)


def _finish(
    t: NDArray[np.float64],
    path: NDArray[np.float64],
    normal_per_sample: NDArray[np.float64],
    magnitude: NDArray[np.float64],
    rng: np.random.Generator,
    tremor_m: float,
    force_noise_n: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Add tremor, friction, sensor noise and orientations; return positions, quaternions, wrenches, force dirs."""
    phases = rng.uniform(0, 6, 3)
    tremor = tremor_m * np.stack(
        [np.sin(2 * np.pi * f * t + p) for f, p in zip((4.1, 5.3, 6.7), phases, strict=True)], axis=1
    )
    # The surface constrains tremor along the normal while in contact.
    in_contact = (magnitude > 0)[:, None]
    tremor = tremor - in_contact * np.sum(tremor * normal_per_sample, axis=1, keepdims=True) * normal_per_sample
    # Friction opposes the true motion of the tool, tremor included; the truth a skill should
    # reproduce is the intended force: friction along the path, without the tremor's jitter.
    force = _applied_force(normal_per_sample, np.gradient(path + tremor, t, axis=0), magnitude)
    intended = _applied_force(normal_per_sample, np.gradient(path, t, axis=0), magnitude)
    intended_norm = np.linalg.norm(intended, axis=1, keepdims=True)
    force_dirs = np.where(intended_norm > 1e-9, intended / np.maximum(intended_norm, 1e-12), 0.0)
    positions = path + tremor + rng.normal(0.0, 2e-5, path.shape)
    # The person holds the tool roughly along the surface normal, not along the (friction-tilted) force.
    # A hand turns the tool over ~0.1 s, not instantly, when the surface normal jumps (a crease).
    held_axis = gaussian_filter1d(normal_per_sample, sigma=0.1 / (t[1] - t[0]), axis=0, mode="nearest")
    orientations = _tool_orientations(held_axis, t)
    wrenches = np.zeros((t.size, 6))
    wrenches[:, :3] = force + rng.normal(0.0, force_noise_n, force.shape)
    wrenches[:, 3:] = rng.normal(0.0, force_noise_n * 0.01, force.shape)
    return positions, orientations, wrenches, force_dirs


def _contact_magnitude(
    t: NDArray[np.float64], t_on: float, t_off: float, target: float, ramp_s: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Return the normal-force magnitude: ramps at contact on/off, wandering target in between, 0 when free."""
    ramp = minimum_jerk((t - t_on) / ramp_s) * minimum_jerk((t_off - t) / ramp_s)
    wander = _zero_mean_wander(t, t_on, t_off, rng)
    return np.where((t >= t_on) & (t <= t_off), target * (1.0 + wander) * ramp, 0.0)


def plane_slide(
    normal: tuple[float, float, float] = (0.0, 0.0, -1.0),
    target_force_n: float = 15.0,
    rate_hz: float = 1000.0,
    duration_s: float = 8.0,
    seed: int = 0,
    tremor_m: float = 3e-4,
    force_noise_n: float = 0.3,
) -> SyntheticDemo:
    """Slide on a plane through (0.5, 0, 0.2) m with unit ``normal`` into the surface (world).

    Phases: free approach along the normal (1.5 s, or 20 % of a short demonstration), contact
    with an S-shaped 2-D path of about 0.25 m at varying speed, free retreat (as long as the
    approach). Contact on/off are the true times
    at which the normal force starts rising / has fallen to zero.
    """
    rng = np.random.default_rng(seed)
    n = np.asarray(normal, dtype=float)
    n /= np.linalg.norm(n)
    R_plane = rotation_from_vectors(np.array([0.0, 0.0, 1.0]), n)
    u_axis, v_axis = R_plane[:, 0], R_plane[:, 1]
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    t_on, t_off = _contact_interval(duration_s)
    origin = np.array([0.5, 0.0, 0.2])

    # In-plane S-curve with varying speed: s(t) runs 0..1 over the contact, faster in the middle.
    s = minimum_jerk((t - t_on) / (t_off - t_on))
    s = s + 0.03 * np.sin(2 * np.pi * np.clip((t - t_on) / (t_off - t_on), 0, 1))
    u = 0.25 * (s - 0.5)
    v = 0.05 * np.sin(2 * np.pi * s)
    lift = 0.06 * (minimum_jerk((t_on - t) / (0.8 * t_on)) + minimum_jerk((t - t_off) / (0.8 * t_on)))
    path = origin + u[:, None] * u_axis + v[:, None] * v_axis - lift[:, None] * n
    magnitude = _contact_magnitude(t, t_on, t_off, target_force_n, 0.15, rng)
    normals = np.broadcast_to(n, path.shape)
    positions, orientations, wrenches, force_dirs = _finish(t, path, normals, magnitude, rng, tremor_m, force_noise_n)
    return SyntheticDemo(t, positions, orientations, wrenches, [n], target_force_n, t_on, t_off, force_dirs, magnitude)


def two_plane_slide(
    tilt_deg: float = 20.0,
    target_force_n: float = 15.0,
    rate_hz: float = 1000.0,
    duration_s: float = 10.0,
    seed: int = 0,
) -> SyntheticDemo:
    """Slide across a crease between a flat plane and one tilted by ``tilt_deg`` about world y, in one contact.

    The tool moves along world x on the flat plane z = 0.2 m, crosses the crease at x = 0.5 m
    and continues up the tilted plane; ``phase_change_s`` holds the true crossing time.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    t_on, t_off = _contact_interval(duration_s)
    n1 = np.array([0.0, 0.0, -1.0])
    tilt = np.deg2rad(tilt_deg)
    n2 = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])
    direction2 = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
    crease = np.array([0.5, 0.0, 0.2])

    s = minimum_jerk((t - t_on) / (t_off - t_on))
    arc = 0.36 * (s - 0.5)  # arc length along the surface from the crease, m
    lateral = 0.03 * np.sin(2 * np.pi * s)
    on_first = arc < 0
    path = np.where(
        on_first[:, None],
        crease + arc[:, None] * np.array([1.0, 0.0, 0.0]),
        crease + arc[:, None] * direction2,
    )
    path[:, 1] += lateral
    normals = np.where(on_first[:, None], n1, n2)
    lift = 0.06 * (minimum_jerk((t_on - t) / (0.8 * t_on)) + minimum_jerk((t - t_off) / (0.8 * t_on)))
    path -= lift[:, None] * normals
    magnitude = _contact_magnitude(t, t_on, t_off, target_force_n, 0.15, rng)
    positions, orientations, wrenches, force_dirs = _finish(t, path, normals, magnitude, rng, 3e-4, 0.3)
    t_cross = float(t[np.flatnonzero(~on_first)[0]])
    return SyntheticDemo(
        t, positions, orientations, wrenches, [n1, n2], target_force_n, t_on, t_off, force_dirs, magnitude, [t_cross]
    )


def cylinder_contour(
    radius_m: float = 0.08,
    arc_deg: float = 120.0,
    peak_force_n: float = 20.0,
    rate_hz: float = 1000.0,
    duration_s: float = 8.0,
    seed: int = 0,
) -> SyntheticDemo:
    """Contour around a cylinder (axis along world y through (0.5, 0, 0.1) m) over ``arc_deg`` of its top.

    The tool moves at a nearly constant speed through contact (touching and lifting off while
    moving). The normal force follows a profile (0.5 -> 1 -> 0.6 of ``peak_force_n``) with the ±20 %
    wander; the applied force points into the cylinder plus friction along the motion, so
    its direction turns continuously with the path.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    t_on, t_off = _contact_interval(duration_s)
    centre = np.array([0.5, 0.0, 0.1])
    # The hand is already moving along the shape when it touches and when it lifts off, at a
    # speed that varies by ±10 %: contouring, unlike pressing, has no rest in contact.
    u_lin = (t - t_on) / (t_off - t_on)
    s = u_lin + 0.1 / (2 * np.pi) * np.sin(2 * np.pi * u_lin)
    angle = np.deg2rad(arc_deg) * (s - 0.5)  # from the top, positive towards +x
    outward = np.stack([np.sin(angle), np.zeros_like(angle), np.cos(angle)], axis=1)
    lift = 0.04 * (minimum_jerk((t_on - t) / (0.8 * t_on)) + minimum_jerk((t - t_off) / (0.8 * t_on)))
    path = centre + (radius_m + lift)[:, None] * outward
    path[:, 1] += 0.01 * np.sin(np.pi * np.clip(s, 0, 1))
    u = np.clip((t - t_on) / (t_off - t_on), 0, 1)
    profile = peak_force_n * np.interp(u, [0.0, 0.5, 1.0], [0.5, 1.0, 0.6])
    magnitude = _contact_magnitude(t, t_on, t_off, 1.0, 0.15, rng) * profile
    positions, orientations, wrenches, force_dirs = _finish(t, path, -outward, magnitude, rng, 3e-4, 0.3)
    return SyntheticDemo(t, positions, orientations, wrenches, [], peak_force_n, t_on, t_off, force_dirs, magnitude)


def reach_pose_trajectory(n_samples: int = 2000, duration_s: float = 4.0) -> tuple[NDArray, NDArray, NDArray]:
    """Return a smooth free-space reach (t (N,) s, positions (N, 3) m, quaternions (N, 4) [x, y, z, w]).

    36 cm with a lateral wiggle and an 8 cm lift, rotating ~45 deg, starting and ending at rest
    (minimum jerk): the DMP reproduction benchmark and tests use it.
    """
    from scipy.spatial.transform import Rotation

    t = np.linspace(0.0, duration_s, n_samples)
    s = t / duration_s
    mj = minimum_jerk(s)
    bump = 16 * (s * (1 - s)) ** 2
    position = np.stack(
        [0.4 + 0.3 * mj, -0.1 + 0.2 * mj + 0.05 * np.sin(2 * np.pi * s) * bump, 0.3 + 0.08 * bump], axis=1
    )
    rotvec = np.stack([0.6 * mj, -0.4 * mj + 0.3 * bump * np.sin(3 * np.pi * s), 0.5 * bump], axis=1)
    q = (Rotation.from_rotvec(rotvec) * Rotation.from_euler("xyz", [0.3, -0.2, 1.0])).as_quat()
    return t, position, q
