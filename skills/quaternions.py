"""Unit quaternions, scalar-LAST ``[x, y, z, w]`` (the project convention, as PyBullet and scipy).

Conventions: docs/CONVENTIONS.md

Every function takes arrays of shape ``(4,)`` or ``(N, 4)`` and is vectorized over N.
A quaternion ``q`` maps a vector from the rotated (body) frame into the reference frame,
``v_ref = R(q) v_body``. Angles are in rad.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

_EPS = 1e-12


def quaternions_normalized(q: ArrayLike) -> NDArray[np.float64]:
    """Return ``q`` scaled to unit norm, shape preserved, scalar-last."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quaternions_sign_continuous(q: ArrayLike) -> NDArray[np.float64]:
    """Return the ``(N, 4)`` sequence with signs flipped so that ``dot(q_k, q_{k-1}) >= 0``.

    ``q`` and ``-q`` are the same rotation; a trajectory (and a DMP learned on it) needs one
    continuous branch. The first sample keeps its sign, except that a negative ``w`` on the
    first sample is flipped so the result does not depend on the sign of the input.
    """
    q = np.array(q, dtype=float, copy=True)
    if q.ndim != 2 or q.shape[0] == 0:
        return q
    step_sign = np.sign(np.einsum("ij,ij->i", q[1:], q[:-1]))
    step_sign[step_sign == 0] = 1.0
    first = -1.0 if q[0, 3] < 0 else 1.0
    cumulative = np.concatenate(([first], first * np.cumprod(step_sign)))
    return q * cumulative[:, None]


def quaternion_product(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``p ⊗ q`` (rotation q first, then p), scalar-last, broadcast over N."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pv, pw = p[..., :3], p[..., 3:4]
    qv, qw = q[..., :3], q[..., 3:4]
    vec = pw * qv + qw * pv + np.cross(pv, qv)
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    return np.concatenate([vec, w], axis=-1)


def quaternion_conjugate(q: ArrayLike) -> NDArray[np.float64]:
    """Return the conjugate (the inverse of a unit quaternion), scalar-last."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([-q[..., :3], q[..., 3:4]], axis=-1)


def quaternion_log(q: ArrayLike) -> NDArray[np.float64]:
    """Return ``log(q)`` as a 3-vector ``u * theta/2`` (rad) for unit ``q = (u sin(theta/2), cos(theta/2))``.

    ``2 log(q)`` is the rotation vector. The short branch is taken (``w`` made non-negative),
    so the result has norm at most ``pi/2``.
    """
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:4] < 0, -q, q)
    v = q[..., :3]
    v_norm = np.linalg.norm(v, axis=-1, keepdims=True)
    half_angle = np.arctan2(v_norm, q[..., 3:4])
    scale = np.where(v_norm > _EPS, half_angle / np.maximum(v_norm, _EPS), 1.0)
    return v * scale


def quaternion_exp(r: ArrayLike) -> NDArray[np.float64]:
    """Return the unit quaternion ``exp(r)`` for a 3-vector ``r = u * theta/2`` (inverse of log)."""
    r = np.asarray(r, dtype=float)
    half_angle = np.linalg.norm(r, axis=-1, keepdims=True)
    sinc = np.where(half_angle > _EPS, np.sin(half_angle) / np.maximum(half_angle, _EPS), 1.0)
    return np.concatenate([r * sinc, np.cos(half_angle)], axis=-1)


def quaternion_angle_between(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Return the rotation angle (rad, in ``[0, pi]``) taking ``q`` to ``p``, sign-invariant."""
    p = quaternions_normalized(p)
    q = quaternions_normalized(q)
    dot = np.abs(np.sum(p * q, axis=-1))
    return 2.0 * np.arccos(np.clip(dot, -1.0, 1.0))


def matrix_from_quaternion(q: ArrayLike) -> NDArray[np.float64]:
    """Return rotation matrices ``(3, 3)`` or ``(N, 3, 3)`` for scalar-last quaternions."""
    return Rotation.from_quat(np.asarray(q, dtype=float)).as_matrix()


def quaternion_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Return scalar-last unit quaternions for rotation matrices ``(3, 3)`` or ``(N, 3, 3)``."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()


def quaternions_from_wxyz(q_wxyz: ArrayLike) -> NDArray[np.float64]:
    """Reorder scalar-FIRST ``[w, x, y, z]`` quaternions into the project's ``[x, y, z, w]``."""
    q_wxyz = np.asarray(q_wxyz, dtype=float)
    return np.concatenate([q_wxyz[..., 1:4], q_wxyz[..., 0:1]], axis=-1)


def quaternions_slerp(t_query: ArrayLike, t: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Spherical linear interpolation of the ``(N, 4)`` samples ``q`` at times ``t`` (s).

    Query times outside ``[t[0], t[-1]]`` are clamped to the ends. The output is made
    sign-continuous.
    """
    from scipy.spatial.transform import Slerp

    t = np.asarray(t, dtype=float)
    t_query = np.clip(np.asarray(t_query, dtype=float), t[0], t[-1])
    slerp = Slerp(t, Rotation.from_quat(np.asarray(q, dtype=float)))
    return quaternions_sign_continuous(slerp(t_query).as_quat())
