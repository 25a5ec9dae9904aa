"""Sensor offset (tare) of a wrist force/torque sensor, estimated over every free-space stretch of a recording.

A wrist sensor's offset is constant in the SENSOR frame, which turns with the tool: it must be
estimated and removed there, not in the world (where it turns whenever the tool does). The tool
frame stands for the sensor frame (a wrist sensor is fixed to the tool; the demonstration's
orientations are world-from-tool).

In free space the sensor does not read its offset alone: a person guiding a gravity-compensated
arm pushes it, and the sensor carries that push — the arm's apparent inertia and damping against
the motion (m·a + c·v) and its joint friction (Coulomb, along the motion). And it may carry a force
that is constant in the WORLD: the weight of a tool nobody compensated (it reads as m·g UP in the
applied-by-tool convention: the arm holds the tool up), or the offset of a wrench estimated from an
arm's joint torques (KUKA LWR / iiwa, Franka: constant in the robot's base, not in the tool). So over
the free-space samples the offset is fitted TOGETHER with those terms, in the tool frame, by least
squares with Huber weights (a stray push does not drag the offset):

    R_kᵀ f_k = b + R_kᵀ w + c · R_kᵀ v_k + m · R_kᵀ a_k + μ · R_kᵀ tanh(|v_k| / 1 cm/s) v̂_k

The world force ``w`` can be told from the tool-frame ``b`` only where the tool was held in clearly
different orientations in free space (``WORLD_FORCE_MIN_TURN_DEG``); otherwise it is not fitted (b
takes all of it at the orientations seen, which is what matters while the tool turns little). Where
``w`` is fitted, the moments give the centre of the force (a tool's centre of mass): the moment of
``w`` about the tool point, ``c × w``, is fitted with the moment offset.

With no hand in the loop (a robot's recording, the simulator) c, m and μ come out ~0 and b is
the plain mean. Free space is what `skills.contact` does not call contact, ``FREE_MARGIN_S`` away
from any contact (touch-down and lift-off transients) — found on the wrench with the force it carries
where it rests at the ends or moves freely ALONG it taken out first (`fitted_sensor_offset`): a tool's weight can be as
large as a light press, and would otherwise make every move through the air look pressed. Units SI;
forces applied by the tool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_dilation, gaussian_filter1d

from skills.contact import analyse_contact, mask_runs
from skills.frames import skew
from skills.quaternions import matrix_from_quaternion

GRAVITY_M_S2 = 9.81
"""Standard gravity, m/s²."""

FREE_MARGIN_S = 0.3
"""Free-space samples closer than this to a contact are not used, s."""

MIN_FREE_S = 0.5
"""Least free-space time (s), summed over the stretches, to estimate an offset from."""

UNCERTAINTY_BLOCK_S = 1.0
"""Free space is cut into blocks this long (s) to see how much of the slow wander the offset may have taken in."""

HUBER_SCALE_N = 1.0
"""Residuals above this (N) get Huber weights (less pull on the fit)."""

COULOMB_SPEED_M_S = 0.01
"""Speed (m/s) over which the Coulomb friction term rises to its full value (tanh)."""

WORLD_FORCE_MIN_TURN_DEG = 20.0
"""The free-space orientations must span at least this much (deg: the largest angle between two of their tool z
axes) for a world-constant force to be told from the tool-frame offset."""

WORLD_FORCE_GAIN = 0.8
"""...and fitting it must leave at most this share of the RMS residual the offset alone leaves (it explains what the
offset cannot: a tool's weight read in three orientations; not a hand's wander split into two opposite terms), with
neither term larger than the forces read in free space (95th percentile)."""

FREE_MOTION_SPEED_M_S = 0.03
"""A tool moving faster than this (m/s) within ``FREE_MOTION_CONE_DEG`` of the line of its force is in free space:
pressing on a surface it can neither move into it nor away from it at speed."""

FREE_MOTION_CONE_DEG = 40.0
"""How close (deg) to the force's line (either way) such a free motion runs."""

FREE_MOTION_MIN_S = 0.3
"""Least time (s) of free motion along the force (or of rest at the ends) from which a force carried in the air is
taken."""

TARE_RESTING_SPEED_M_S = 0.005
"""A tool slower than this (m/s) in the first or last ``END_SHARE`` of a recording rests (in the air, where a
recording starts and ends)."""

END_SHARE = 0.15
"""The share of a recording at each end where a resting tool is taken to rest in the air."""

SETTLED_MARGIN = 0.05
"""A force carried in the air is taken out only where it makes the contact fewer than this share more physical
(`implausible_contact_share`) than taking nothing out: otherwise nothing is."""


@dataclass(frozen=True)
class SensorOffset:
    """A sensor offset in the tool (sensor) frame, applied-by-tool convention, and where it came from.

    ``wrench`` (6,) N and N·m; ``stretches`` the free-space ``(t_start, t_end)`` used, s;
    ``samples`` how many samples; ``uncertainty_n`` the force offset's 95 % uncertainty (two standard
    errors, N, see `sensor_offset_in_free_space`); ``arm_damping_n_s_m``, ``arm_mass_kg``, ``arm_friction_n`` the
    hand's push explained by the arm's motion (0 without a hand); ``world_force`` (3,) N the force constant in the
    world (applied-by-tool convention: an uncompensated tool weight is ``(0, 0, m g)``) and ``world_force_centre``
    (3,) m where it acts, in the tool frame from the tool point (None: not told from the offset, the free-space
    orientations span less than ``WORLD_FORCE_MIN_TURN_DEG``); ``orientation_span_deg`` what they span.
    """

    wrench: NDArray[np.float64]
    stretches: list[tuple[float, float]]
    samples: int
    uncertainty_n: float
    arm_damping_n_s_m: float = 0.0
    arm_mass_kg: float = 0.0
    arm_friction_n: float = 0.0
    world_force: NDArray[np.float64] | None = None
    world_force_centre: NDArray[np.float64] | None = None
    orientation_span_deg: float = 0.0

    def removed_from(self, orientations: NDArray[np.float64], wrenches: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return world ``wrenches`` (N, 6) with this offset and world force removed (`wrenches_without_offset`;
        ``orientations`` (N, 4) world-from-tool, scalar-last)."""
        return wrenches_without_offset(orientations, wrenches, self.wrench, self.world_force, self.world_force_centre)

    @property
    def tool_mass_kg(self) -> float | None:
        """The mass (kg) an uncompensated tool weight of ``world_force`` stands for (its upward part over g), or
        None when no world force was told apart."""
        return None if self.world_force is None else float(self.world_force[2] / GRAVITY_M_S2)


def free_space_mask(rate_hz: float, in_contact: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Return the samples in free space at least ``FREE_MARGIN_S`` away from any contact sample."""
    margin = max(1, round(FREE_MARGIN_S * rate_hz))
    return ~binary_dilation(in_contact, structure=np.ones(2 * margin + 1))


def _in_tool(R: NDArray[np.float64], vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """Express world (N, 3) vectors in the tool frames given by world-from-tool rotations R (N, 3, 3)."""
    return np.einsum("nji,nj->ni", R, vectors)


def sensor_offset_in_free_space(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    orientations: NDArray[np.float64],
    wrenches: NDArray[np.float64],
    free: NDArray[np.bool_],
) -> SensorOffset | None:
    """Return the sensor offset fitted over the ``free`` samples, or None with too little free space.

    ``t`` (N,) s uniform; ``positions`` (N, 3) m; ``orientations`` (N, 4) world-from-tool
    scalar-last; ``wrenches`` (N, 6) applied by the tool, world frame, NOT yet tared.

    Its uncertainty: what the model leaves is mostly a hand's slow wander, which averages out only
    over time, not over samples. So the residuals are averaged over blocks of ``UNCERTAINTY_BLOCK_S``
    of free space, and the standard error is their RMS over the root of the number of blocks less one
    (a single short stretch says little about a slow wander); the uncertainty is two of them.
    """
    dt = float(t[1] - t[0])
    if free.sum() * dt < MIN_FREE_S:
        return None
    R = matrix_from_quaternion(orientations)
    smoothed = gaussian_filter1d(positions, max(1.0, 0.02 / dt), axis=0, mode="nearest")
    velocity = np.gradient(smoothed, dt, axis=0)
    acceleration = np.gradient(velocity, dt, axis=0)
    speed = np.linalg.norm(velocity, axis=1, keepdims=True)
    coulomb = np.tanh(speed / COULOMB_SPEED_M_S) * velocity / np.maximum(speed, 1e-12)

    rows = np.flatnonzero(free)
    span = orientation_span_deg(R[rows])
    force = _in_tool(R[rows], wrenches[rows, :3])
    regressors = [_in_tool(R[rows], x[rows]) for x in (velocity, acceleration, coulomb)]
    target = force.reshape(-1)
    solution, design, offsets = _huber_fit(R[rows], regressors, target, world=False)
    if span >= WORLD_FORCE_MIN_TURN_DEG:
        # A world force is kept only where it explains what the offset alone cannot: with the orientations barely
        # apart, the two split any residual into large opposite terms that cancel in the air and not in contact.
        candidate = _huber_fit(R[rows], regressors, target, world=True)
        # ...and only at a size the free-space forces show (both terms within what the sensor read there).
        seen = float(np.percentile(np.linalg.norm(force, axis=1), 95))
        sized = max(np.linalg.norm(candidate[0][:3]), np.linalg.norm(candidate[0][3:6])) <= seen
        if sized and _rms(target - candidate[1] @ candidate[0]) <= WORLD_FORCE_GAIN * _rms(target - design @ solution):
            solution, design, offsets = candidate
    world = offsets == 6
    moments = _in_tool(R[rows], wrenches[rows, 3:])
    world_force = solution[3:6] if world else None
    centre = None
    if world_force is not None:
        # m_tool = b_m + c × (Rᵀ w) = b_m - [Rᵀ w]× c: the moment offset and the force's centre together.
        seen = _in_tool(R[rows], np.broadcast_to(world_force, (rows.size, 3)))
        moment_design = np.concatenate([np.broadcast_to(np.eye(3), (rows.size, 3, 3)), -skew(seen)], axis=2)
        fit, *_ = np.linalg.lstsq(moment_design.reshape(-1, 6), moments.reshape(-1), rcond=None)
        moment_offset, centre = fit[:3], fit[3:]
    else:
        moment_offset = np.median(moments, axis=0)
    stretches = [(float(t[a]), float(t[b - 1])) for a, b in mask_runs(free)]
    left = (target - design @ solution).reshape(-1, 3)
    blocks = np.array_split(left, max(1, round(rows.size * dt / UNCERTAINTY_BLOCK_S)))
    block_means = np.array([block.mean(axis=0) for block in blocks])
    spread = float(np.sqrt(np.mean(np.sum(block_means**2, axis=1))))
    return SensorOffset(
        wrench=np.concatenate([solution[:3], moment_offset]),
        stretches=stretches,
        samples=int(rows.size),
        uncertainty_n=2.0 * spread / np.sqrt(max(len(blocks) - 1, 1)),
        arm_damping_n_s_m=float(solution[offsets]),
        arm_mass_kg=float(solution[offsets + 1]),
        arm_friction_n=float(solution[offsets + 2]),
        world_force=world_force,
        world_force_centre=centre,
        orientation_span_deg=span,
    )


def _rms(values: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(values**2)))


def _huber_fit(
    R: NDArray[np.float64], regressors: list[NDArray[np.float64]], target: NDArray[np.float64], world: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Fit the tool-frame offset (and with ``world`` the world force) with the hand's push terms to the tool-frame
    forces ``target`` (3M,) of M samples of world-from-tool ``R`` (M, 3, 3) and ``regressors`` (3 of (M, 3)): least
    squares with Huber weights. Returns (coefficients, design (3M, P), the number of offset columns)."""
    offsets = 6 if world else 3
    # One block of 3 equations per sample: 3 offsets (+ 3 world-force components) + 3 shared scalar coefficients.
    design = np.zeros((R.shape[0], 3, offsets + 3))
    design[:, :, :3] = np.eye(3)
    if world:
        design[:, :, 3:6] = np.transpose(R, (0, 2, 1))  # R_kᵀ w: the world force seen in the tool frame
    for j, x in enumerate(regressors):
        design[:, :, offsets + j] = x
    design = design.reshape(-1, offsets + 3)
    weights = np.ones_like(target)
    for _ in range(5):
        w = np.sqrt(weights)
        solution, *_ = np.linalg.lstsq(design * w[:, None], target * w, rcond=None)
        residual = np.abs(target - design @ solution)
        weights = np.minimum(1.0, HUBER_SCALE_N / np.maximum(residual, 1e-12))
    return solution, design, offsets


def orientation_span_deg(R: NDArray[np.float64]) -> float:
    """Return the largest angle (deg) between two of the tool z axes of world-from-tool rotations ``R`` (N, 3, 3)
    (over at most 200 of them, evenly taken)."""
    z = R[np.unique(np.linspace(0, len(R) - 1, min(len(R), 200)).round().astype(int)), :, 2]
    return float(np.degrees(np.arccos(np.clip(np.min(z @ z.T), -1.0, 1.0))))


def resting_force(t: NDArray[np.float64], positions: NDArray[np.float64], forces: NDArray[np.float64]) -> NDArray:
    """Return the median force (3,) N, world, where the tool rests (slower than ``TARE_RESTING_SPEED_M_S``) in the first
    or last ``END_SHARE`` of the recording, ``FREE_MOTION_MIN_S`` in all; zero without such a rest. Recordings start
    and end at rest in the air, where the sensor reads only what it carries (arrays as `free_motion`)."""
    dt = float(t[1] - t[0])
    speed = np.linalg.norm(np.gradient(gaussian_filter1d(positions, max(1.0, 0.02 / dt), axis=0), dt, axis=0), axis=1)
    ends = np.zeros(t.size, dtype=bool)
    edge = max(1, round(END_SHARE * t.size))
    ends[:edge] = ends[-edge:] = True
    resting = ends & (speed < TARE_RESTING_SPEED_M_S)
    return np.median(forces[resting], axis=0) if resting.sum() * dt >= FREE_MOTION_MIN_S else np.zeros(3)


def implausible_contact_share(
    t: NDArray[np.float64], positions: NDArray[np.float64], forces: NDArray[np.float64], in_contact: NDArray[np.bool_]
) -> float:
    """Return the share (0-1) of the contact samples moving faster than ``FREE_MOTION_SPEED_M_S`` that move within
    ``FREE_MOTION_CONE_DEG`` of their force's line: pressing on a surface the tool can neither move into it nor away
    from it at speed, so a contact found on forces that still carry something (a tool's weight) shows it."""
    dt = float(t[1] - t[0])
    velocity = np.gradient(gaussian_filter1d(positions, max(1.0, 0.02 / dt), axis=0, mode="nearest"), dt, axis=0)
    speed = np.linalg.norm(velocity, axis=1)
    along = np.abs(np.sum(velocity * forces, axis=1)) / np.maximum(speed * np.linalg.norm(forces, axis=1), 1e-12)
    moving = in_contact & (speed > FREE_MOTION_SPEED_M_S)
    return float(np.mean(along[moving] >= np.cos(np.radians(FREE_MOTION_CONE_DEG)))) if moving.any() else 0.0


def fitted_sensor_offset(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    orientations: NDArray[np.float64],
    wrenches: NDArray[np.float64],
) -> SensorOffset | None:
    """Return the sensor offset of a recording (arrays as `sensor_offset_in_free_space`, ``wrenches`` untared),
    fitted over the free space that contact analysis finds, or None with too little free space.

    Contact is found on the forces with what the sensor carries in the air taken out first — nothing, the force
    where the tool rests at the recording's ends (`resting_force`) or its median where it moves freely along it
    (`free_motion`; only where it does so somewhere, else nothing): an uncompensated tool weight can be as large as
    a light press, and would otherwise make the whole recording look pressed, or the strokes look free. Of these,
    the one whose tared forces give the most physical contact (`implausible_contact_share`) is kept (nothing, unless
    another is clearly better), and the offset is fitted again over the free space of the tared forces.
    """
    forces = wrenches[:, :3]
    rate_hz = 1.0 / float(t[1] - t[0])
    best: tuple[float, SensorOffset] | None = None
    candidates = [np.zeros(3)]
    moving_freely = free_motion(t, positions, forces)
    # Only a recording that shows the tool moving freely through the air (an approach, a retreat) tells what the
    # sensor carries there; one that is all contact (cut to its strokes) does not, and nothing is taken out.
    if moving_freely.sum() / rate_hz >= FREE_MOTION_MIN_S:
        candidates += [resting_force(t, positions, forces), np.median(forces[moving_freely], axis=0)]
    for k, carried in enumerate(candidates):
        if k and any(np.linalg.norm(carried - other) < 0.5 for other in candidates[:k]):
            continue
        contact = analyse_contact(t, positions, forces - carried)
        if not contact.intervals:
            continue
        free = free_space_mask(rate_hz, contact.in_contact)
        offset = sensor_offset_in_free_space(t, positions, orientations, wrenches, free)
        if offset is None:
            continue
        tared = offset.removed_from(orientations, wrenches)
        again = analyse_contact(t, positions, tared[:, :3])
        if not again.intervals:
            continue
        refit = (
            sensor_offset_in_free_space(
                t, positions, orientations, wrenches, free_space_mask(rate_hz, again.in_contact)
            )
            or offset
        )
        tared = refit.removed_from(orientations, wrenches)
        share = implausible_contact_share(t, positions, tared[:, :3], again.in_contact) + (SETTLED_MARGIN if k else 0.0)
        if best is None or share < best[0]:
            best = (share, refit)
        if k == 0 and share <= SETTLED_MARGIN:
            break  # no other candidate can be clearly better than taking nothing out: none is tried
    return None if best is None else best[1]


def free_motion(t: NDArray[np.float64], positions: NDArray[np.float64], forces: NDArray[np.float64]) -> NDArray:
    """Return where (N,) the tool moves freely ALONG its force: the tool point faster than ``FREE_MOTION_SPEED_M_S``
    within ``FREE_MOTION_CONE_DEG`` of the force's line, either way. Pressing on a surface the tool can neither move
    into it nor away from it at speed, so there the force is not a press but what the sensor carries in the air (an
    uncompensated tool weight, an offset, a hand's push).

    ``t`` (N,) s uniform, ``positions`` (N, 3) m, ``forces`` (N, 3) N applied by the tool, world, untared.
    """
    dt = float(t[1] - t[0])
    velocity = np.gradient(gaussian_filter1d(positions, max(1.0, 0.02 / dt), axis=0, mode="nearest"), dt, axis=0)
    speed = np.linalg.norm(velocity, axis=1)
    along = np.abs(np.sum(velocity * forces, axis=1)) / np.maximum(speed * np.linalg.norm(forces, axis=1), 1e-12)
    return (speed > FREE_MOTION_SPEED_M_S) & (along >= np.cos(np.radians(FREE_MOTION_CONE_DEG)))


def wrenches_without_offset(
    orientations: NDArray[np.float64],
    wrenches: NDArray[np.float64],
    offset_tool: NDArray[np.float64],
    world_force: NDArray[np.float64] | None = None,
    world_force_centre: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Return world wrenches (N, 6) with a tool-frame offset (6,) removed, ``w_k - blockdiag(R_k, R_k) offset``, and
    a world-constant force (3,) N acting at ``world_force_centre`` (3,) m in the tool frame (its moment about the
    tool point ``(R_k c) × w`` with it)."""
    R = matrix_from_quaternion(orientations)
    out = np.array(wrenches, dtype=float, copy=True)
    out[:, :3] -= R @ offset_tool[:3]
    out[:, 3:] -= R @ offset_tool[3:]
    if world_force is not None:
        out[:, :3] -= world_force
        if world_force_centre is not None:
            out[:, 3:] -= np.cross(R @ world_force_centre, world_force)
    return out
