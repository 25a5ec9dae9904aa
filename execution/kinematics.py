"""Inverse kinematics of a 7-joint arm on any engine's model of it (``execution.robot.Robot`` implementations:
PyBullet's ``SimWorld``, MuJoCo's ``MujocoRobot``), engine-free: damped least squares on the robot's own Jacobian
with set-and-check forward kinematics. World frame, SI units, quaternions ``[x, y, z, w]`` (docs/CONVENTIONS.md)."""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skills.frames import rotation_vector_from_matrix
from skills.quaternions import matrix_from_quaternion


class Kinematic(Protocol):
    """What inverse kinematics needs of a world: teleporting the arm and reading its tool pose and Jacobian."""

    joint_lower: NDArray[np.float64]
    joint_upper: NDArray[np.float64]

    def joint_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def set_joint_positions(self, q: ArrayLike, qd: ArrayLike | None = None) -> None: ...
    def tool_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def tool_rotation(self) -> NDArray[np.float64]: ...
    def jacobian(self) -> NDArray[np.float64]: ...


def inverse_kinematics(
    world: Kinematic,
    position: ArrayLike,
    quat: ArrayLike,
    q_seed: ArrayLike | None = None,
    *,
    position_tolerance_m: float = 1e-5,
    orientation_tolerance_rad: float = 1e-4,
    max_iterations: int = 300,
    null_gain: float = 0.05,
) -> NDArray[np.float64]:
    """Joint positions (7,) rad putting ``world``'s tool point at ``position`` (3,) m with orientation ``quat``
    (``[x, y, z, w]``), world frame.

    Damped least squares on the world's Jacobian with set-and-check forward kinematics, a null-space pull
    towards ``q_seed`` (default: the current posture) and joint limits. The simulated state is restored.
    Raises ``ValueError`` when the target is not reached within 0.1 mm and 1 mrad.
    """
    target_p = np.asarray(position, dtype=float)
    target_R = matrix_from_quaternion(np.asarray(quat, dtype=float))
    q_save, qd_save = world.joint_state()
    q = q_save.copy() if q_seed is None else np.asarray(q_seed, dtype=float).copy()
    q_rest = q.copy()
    margin = 1e-3
    lo, hi = world.joint_lower + margin, world.joint_upper - margin
    err_p = err_o = np.inf
    try:
        for _ in range(max_iterations):
            world.set_joint_positions(q)
            p = world.tool_pose()[0]
            R = world.tool_rotation()
            err = np.empty(6)
            err[:3] = target_p - p
            err[3:] = rotation_vector_from_matrix(target_R @ R.T)
            err_p, err_o = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
            if err_p < position_tolerance_m and err_o < orientation_tolerance_rad:
                break
            J = world.jacobian()
            step = err.copy()
            step[:3] = np.clip(step[:3], -0.05, 0.05)
            damping = 1e-4 + 1e-2 * min(err_p, 0.05)
            JJt = J @ J.T + damping * np.eye(6)
            J_pinv = J.T @ np.linalg.inv(JJt)
            dq = J_pinv @ step + null_gain * (np.eye(q.size) - J_pinv @ J) @ (q_rest - q)
            q = np.clip(q + dq, lo, hi)
    finally:
        world.set_joint_positions(q_save, qd_save)
    if err_p > 1e-4 or err_o > 1e-3:
        raise ValueError(
            f"inverse kinematics did not converge: position error {err_p * 1e3:.3f} mm, "
            f"orientation error {math.degrees(err_o):.3f} deg (target unreachable or near a joint limit)"
        )
    return q
