"""Frame algebra of the project conventions: rotations between vectors, adjoints, eq. (2)-(3).

Conventions: docs/CONVENTIONS.md

A transform ``T = (R, p)`` maps coordinates of frame B into frame A: ``x_A = R x_B + p``.
6-vectors are ``[x, y, z, rx, ry, rz]``: twists ``(v, ω)``, wrenches ``(f, m)``.

- twist:  ``ξ_A = Ad(T) ξ_B``,  ``Ad = [[R, [p]× R], [0, R]]``
- wrench: ``F_A = Adg(T) F_B``, ``Adg = Ad^{-T} = [[R, 0], [[p]× R, R]]``
- eq. (3): ``Ω = Adg K_c S Ad^{-1}`` (stiffness restricted to the motion axes) and
  ``Ω~ = Adg S~ Adg^{-1}`` (projector onto the force axes), both mapping CF quantities
  into the frame A the controller works in.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

_PARALLEL_EPS = 1e-9


def skew(v: ArrayLike) -> NDArray[np.float64]:
    """Return the ``(3, 3)`` (or ``(N, 3, 3)``) cross-product matrix ``[v]×`` with ``[v]× u = v × u``."""
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    rows = [
        np.stack([zero, -z, y], axis=-1),
        np.stack([z, zero, -x], axis=-1),
        np.stack([-y, x, zero], axis=-1),
    ]
    return np.stack(rows, axis=-2)


def rotation_from_vectors(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Return the minimal rotation matrix ``R`` with ``R â = b̂`` (Möller & Hughes 1999).

    ``a`` and ``b`` are 3-vectors (any norm, not zero) or ``(N, 3)`` batches. The rotation
    turns about ``a × b`` by the angle between them, so it is unique and varies continuously
    with ``b`` except at ``b = -a``, where the closed form is singular; there a rotation of
    pi about the axis most orthogonal to ``a`` is returned (Möller & Hughes' own remedy).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    a, b = np.broadcast_arrays(a, b)
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1)
    near_opposite = 1.0 + c < _PARALLEL_EPS
    h = 1.0 / np.where(near_opposite, 1.0, 1.0 + c)
    V = skew(v)
    R = np.eye(3) + V + (V @ V) * h[..., None, None]
    if np.any(near_opposite):
        a_opp = np.atleast_2d(a)[np.atleast_1d(near_opposite)]
        # Axis: the coordinate axis least aligned with a, made orthogonal to it.
        helper = np.eye(3)[np.argmin(np.abs(a_opp), axis=-1)]
        axis = np.cross(a_opp, helper)
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        flipped = 2.0 * axis[:, :, None] * axis[:, None, :] - np.eye(3)
        R = np.array(R, copy=True)
        if R.ndim == 2:
            R = flipped[0]
        else:
            R[near_opposite] = flipped
    return R


def matrix_from_axis_angle(axis: ArrayLike, angle_rad: float) -> NDArray[np.float64]:
    """Rotation matrix (3, 3) of ``angle_rad`` (rad) about the unit direction of ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    K = skew(a)
    return np.eye(3) + math.sin(angle_rad) * K + (1.0 - math.cos(angle_rad)) * (K @ K)


def rotation_vector_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector (3,) (unit axis times angle, rad) of a rotation matrix (3, 3).

    Closed form below 170° (plain floats: it runs inside inverse-kinematics loops), through the quaternion
    logarithm near pi, where the closed form loses its axis.
    """
    R = np.asarray(R, dtype=float)
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    if c > -0.985:
        w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        s = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        if s < 1e-12:
            return w
        return w * (math.atan2(s, c) / s)
    from skills.quaternions import quaternion_from_matrix, quaternion_log

    return 2.0 * quaternion_log(quaternion_from_matrix(R))


def transform_inverse(R: ArrayLike, p: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Return ``(R^T, -R^T p)``: the inverse of the transform ``(R, p)``."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    Rt = np.swapaxes(R, -1, -2)
    return Rt, -(Rt @ p[..., None])[..., 0]


def adjoint_from_transform(R: ArrayLike, p: ArrayLike) -> NDArray[np.float64]:
    """Return the ``(6, 6)`` twist adjoint ``Ad = [[R, [p]× R], [0, R]]`` of ``T = (R, p)`` (B into A)."""
    R = np.asarray(R, dtype=float)
    Ad = np.zeros((*R.shape[:-2], 6, 6))
    Ad[..., :3, :3] = R
    Ad[..., :3, 3:] = skew(p) @ R
    Ad[..., 3:, 3:] = R
    return Ad


def wrench_adjoint_from_transform(R: ArrayLike, p: ArrayLike) -> NDArray[np.float64]:
    """Return the ``(6, 6)`` wrench adjoint ``Adg = Ad^{-T} = [[R, 0], [[p]× R, R]]`` of ``T = (R, p)``."""
    R = np.asarray(R, dtype=float)
    Adg = np.zeros((*R.shape[:-2], 6, 6))
    Adg[..., :3, :3] = R
    Adg[..., 3:, :3] = skew(p) @ R
    Adg[..., 3:, 3:] = R
    return Adg


def stiffness_in_frame(
    R: ArrayLike, p: ArrayLike, stiffness_cf: ArrayLike, selection_cf: ArrayLike
) -> NDArray[np.float64]:
    """Return eq. (3) ``Ω = Adg K_c S Ad^{-1}``: the CF stiffness on the motion axes, in frame A.

    ``(R, p)`` maps CF into A; ``stiffness_cf`` and ``selection_cf`` are 6-vectors (the
    diagonals of K_c in N/m and N·m/rad, and of S with 1 = motion axis). ``Ω`` maps a pose
    error (twist-like, in A) to a restoring wrench (in A).
    """
    Ad_inv = adjoint_from_transform(*transform_inverse(R, p))
    Adg = wrench_adjoint_from_transform(R, p)
    K = np.asarray(stiffness_cf, dtype=float) * np.asarray(selection_cf, dtype=float)
    return Adg @ (K[..., :, None] * Ad_inv)


def force_projector_in_frame(R: ArrayLike, p: ArrayLike, selection_cf: ArrayLike) -> NDArray[np.float64]:
    """Return eq. (3) ``Ω~ = Adg S~ Adg^{-1}``: the projector of wrenches in A onto the CF force axes.

    ``S~ = I - S``; ``Ω~`` is idempotent, keeps a wrench along a CF force axis unchanged and
    removes one along a CF motion axis.
    """
    Adg = wrench_adjoint_from_transform(R, p)
    Adg_inv = wrench_adjoint_from_transform(*transform_inverse(R, p))
    S_tilde = 1.0 - np.asarray(selection_cf, dtype=float)
    return Adg @ (S_tilde[..., :, None] * Adg_inv)
