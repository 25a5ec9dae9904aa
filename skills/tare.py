"""Sensor offset (tare) of a wrist force/torque sensor, estimated over every free-space stretch of a recording.

A wrist sensor's offset is constant in the SENSOR frame, which turns with the tool: it must be
estimated and removed there, not in the world (where it turns whenever the tool does). The tool
frame stands for the sensor frame (a wrist sensor is fixed to the tool; the demonstration's
orientations are world-from-tool).

In free space the sensor does not read its offset alone: a person guiding a gravity-compensated
arm pushes it, and the sensor carries that push — the arm's apparent inertia and damping against
the motion (m·a + c·v) and its joint friction (Coulomb, along the motion). So over the free-space
samples the offset is fitted TOGETHER with those terms, in the tool frame, by least squares with
Huber weights (a stray push does not drag the offset):

    R_kᵀ f_k = b + c · R_kᵀ v_k + m · R_kᵀ a_k + μ · R_kᵀ tanh(|v_k| / 1 cm/s) v̂_k

With no hand in the loop (a robot's recording, the simulator) c, m and μ come out ~0 and b is
the plain mean. Free space is what `skills.contact` does not call contact, ``FREE_MARGIN_S`` away
from any contact (touch-down and lift-off transients). Units SI; forces applied by the tool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_dilation, gaussian_filter1d

from skills.contact import mask_runs
from skills.quaternions import matrix_from_quaternion

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


@dataclass(frozen=True)
class SensorOffset:
    """A sensor offset in the tool (sensor) frame, applied-by-tool convention, and where it came from.

    ``wrench`` (6,) N and N·m; ``stretches`` the free-space ``(t_start, t_end)`` used, s;
    ``samples`` how many samples; ``uncertainty_n`` the force offset's 95 % uncertainty (two standard
    errors, N, see `sensor_offset_in_free_space`); ``arm_damping_n_s_m``, ``arm_mass_kg``, ``arm_friction_n`` the
    hand's push explained by the arm's motion (0 without a hand).
    """

    wrench: NDArray[np.float64]
    stretches: list[tuple[float, float]]
    samples: int
    uncertainty_n: float
    arm_damping_n_s_m: float = 0.0
    arm_mass_kg: float = 0.0
    arm_friction_n: float = 0.0


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
    force = _in_tool(R[rows], wrenches[rows, :3])
    regressors = [_in_tool(R[rows], x[rows]) for x in (velocity, acceleration, coulomb)]
    # One block of 3 equations per sample: 3 offsets + 3 shared scalar coefficients.
    design = np.zeros((rows.size, 3, 6))
    design[:, :, :3] = np.eye(3)
    for j, x in enumerate(regressors):
        design[:, :, 3 + j] = x
    design = design.reshape(-1, 6)
    target = force.reshape(-1)
    weights = np.ones_like(target)
    for _ in range(5):
        w = np.sqrt(weights)
        solution, *_ = np.linalg.lstsq(design * w[:, None], target * w, rcond=None)
        residual = np.abs(target - design @ solution)
        weights = np.minimum(1.0, HUBER_SCALE_N / np.maximum(residual, 1e-12))
    moments = np.median(_in_tool(R[rows], wrenches[rows, 3:]), axis=0)
    stretches = [(float(t[a]), float(t[b - 1])) for a, b in mask_runs(free)]
    left = (target - design @ solution).reshape(-1, 3)
    blocks = np.array_split(left, max(1, round(rows.size * dt / UNCERTAINTY_BLOCK_S)))
    block_means = np.array([block.mean(axis=0) for block in blocks])
    spread = float(np.sqrt(np.mean(np.sum(block_means**2, axis=1))))
    return SensorOffset(
        wrench=np.concatenate([solution[:3], moments]),
        stretches=stretches,
        samples=int(rows.size),
        uncertainty_n=2.0 * spread / np.sqrt(max(len(blocks) - 1, 1)),
        arm_damping_n_s_m=float(solution[3]),
        arm_mass_kg=float(solution[4]),
        arm_friction_n=float(solution[5]),
    )


def wrenches_without_offset(
    orientations: NDArray[np.float64], wrenches: NDArray[np.float64], offset_tool: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Return world wrenches (N, 6) with a tool-frame offset (6,) removed: ``w_k - blockdiag(R_k, R_k) offset``."""
    R = matrix_from_quaternion(orientations)
    out = np.array(wrenches, dtype=float, copy=True)
    out[:, :3] -= R @ offset_tool[:3]
    out[:, 3:] -= R @ offset_tool[3:]
    return out
