"""The control law's numbers (``skills.control``'s docstring): the pose error, the compiled step
(:func:`law_step`, :func:`law_step_packed`), the compiled null-space model update (:func:`model_update_packed`) and
the writes of a control frame into the gain matrix, and the damping (diagonal, or the double diagonalization).

Pure numpy and numba on the packed arrays of :mod:`skills.control.layouts`; no state of its own.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.execution import ControllerGains
from skills.control.layouts import (
    F_P,
    F_QUAT,
    F_QUAT_END,
    F_TWIST,
    G_FORCE,
    G_JOINT,
    G_JOINT0,
    G_MOTION,
    G_ROWS,
    G_TASK,
    G_TASK_END,
    G_WRENCH,
    G_WRENCH0,
    L_ADG_INV0,
    L_AXES0,
    L_CF_Z0,
    L_DT,
    L_ERROR_PER_N0,
    L_FRAME,
    L_IMPEDANCE_KZ,
    L_INTEGRAL0,
    L_INTEGRAL_BOUND,
    L_LIMITS0,
    L_MAX_FORCE_SQ,
    L_SATURATED,
    L_SATURATED_FOR,
    L_SATURATION_ABORT,
    L_X0,
    L_Y0,
    LAW_FORCE_LIMIT,
    LAW_GAIN_SIZE,
    LAW_NON_FINITE,
    LAW_OK,
    LAW_TORQUE_LIMIT,
    O_JOINT,
    O_MOTION0,
    O_SATURATED,
    R_BIAS,
    R_J,
    R_J_END,
    R_P,
    R_Q,
    R_QD,
    R_QUAT,
    R_QUAT_END,
    REFERENCE_FORCE,
    REFERENCE_POSITION,
    REFERENCE_QUAT,
    REFERENCE_TWIST,
    ROBOT_BIAS,
    ROBOT_JACOBIAN,
    ROBOT_POSITION,
    ROBOT_Q,
    ROBOT_QD,
    ROBOT_QUAT,
    X_BIAS0,
    X_FORCE,
    X_INTEGRAL0,
    X_ONE,
    X_Q,
    X_Q0,
    X_QD,
    X_QD0,
    X_REF_TWIST,
    X_REF_TWIST0,
    X_SIZE,
    X_TASK,
    X_TASK_END,
    X_TWIST,
    X_TWIST0,
    X_WRENCH0,
)

_SINGULAR_DAMPING = 1e-6
"""Relative Tikhonov term of the task-space inverses in the null-space projector."""
NO_MASS_MATRIX = np.zeros((0, 0))
"""The mass matrix argument of the compiled model update when there is none (the static null-space projector)."""


def pose_error(
    position: ArrayLike, quaternion: ArrayLike, reference_position: ArrayLike, reference_quaternion: ArrayLike
) -> NDArray[np.float64]:
    """Return the pose error ``[p_r - p, 2 log(q_r ⊗ q*)]`` (6,) in world axes (m, rad).

    The rotational part is the rotation vector (world axes) that turns the current orientation
    into the reference one, on the short branch. Quaternions scalar-last.
    """
    e = np.empty(6)
    p, q = np.asarray(position, dtype=float), np.asarray(quaternion, dtype=float)
    pr, qr = np.asarray(reference_position, dtype=float), np.asarray(reference_quaternion, dtype=float)
    _pose_error_into(p[0], p[1], p[2], q, pr[0], pr[1], pr[2], qr, e)
    return e


@numba.njit(cache=True)
def _pose_error_into(px, py, pz, q, rpx, rpy, rpz, qr, out):  # pragma: no cover - compiled
    """:func:`pose_error` of the position (px, py, pz), quaternion ``q`` (4,) and their references, into ``out``."""
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    rx, ry, rz, rw = qr[0], qr[1], qr[2], qr[3]
    # e = q_r ⊗ conj(q)
    ew = rw * qw + rx * qx + ry * qy + rz * qz
    ex = -rw * qx + qw * rx - (ry * qz - rz * qy)
    ey = -rw * qy + qw * ry - (rz * qx - rx * qz)
    ez = -rw * qz + qw * rz - (rx * qy - ry * qx)
    if ew < 0.0:
        ex, ey, ez, ew = -ex, -ey, -ez, -ew
    vn = math.sqrt(ex * ex + ey * ey + ez * ez)
    scale = 2.0 * math.atan2(vn, ew) / vn if vn > 1e-12 else 2.0
    out[0], out[1], out[2] = rpx - px, rpy - py, rpz - pz
    out[3], out[4], out[5] = scale * ex, scale * ey, scale * ez


@numba.njit(cache=True)
def law_step(G, robot, reference, wrench, law, in_contact, out):  # pragma: no cover - compiled
    """One step of the law (module docstring, "Cost"): τ, F_m, F_f into ``out``; returns a code (``LAW_OK``, ...).

    ``G`` the gain matrix, ``robot`` / ``reference`` / ``law`` / ``out`` in the ``ROBOT_*``, ``REFERENCE_*``,
    ``_L_*``, ``_O_*`` layouts, ``wrench`` (6,) the measured wrench; updates the force integral and the saturation
    state in ``law``.
    """
    f_d = reference[REFERENCE_FORCE]
    rpx, rpy, rpz = reference[F_P], reference[F_P + 1], reference[F_P + 2]
    kz = law[L_IMPEDANCE_KZ]
    if kz != 0.0 and f_d != 0.0:  # impedance: the reference presses f_d through the spring along CF z
        shift = f_d / kz
        rpx, rpy, rpz = rpx + law[L_CF_Z0] * shift, rpy + law[L_CF_Z0 + 1] * shift, rpz + law[L_CF_Z0 + 2] * shift
    x = law[L_X0 : L_X0 + X_SIZE]
    _pose_error_into(
        robot[R_P], robot[R_P + 1], robot[R_P + 2], robot[R_QUAT:R_QUAT_END], rpx, rpy, rpz,
        reference[F_QUAT:F_QUAT_END], x,
    )  # fmt: skip

    # Force integral, CF coordinates, one force axis at a time: ∫ S~ (f_d S~ Adg^-1 F_d,1 - Adg^-1 F) dt.
    if in_contact and law[L_SATURATED] == 0.0:
        dt, limit = law[L_DT], law[L_INTEGRAL_BOUND]
        for i in range(6):
            if law[L_AXES0 + i] != 0.0:
                row = L_ADG_INV0 + 6 * i
                measured = law[row] * wrench[0]
                for j in range(1, 6):
                    measured += law[row + j] * wrench[j]
                error = f_d * law[L_ERROR_PER_N0 + i] - measured
                law[L_INTEGRAL0 + i] = min(max(law[L_INTEGRAL0 + i] + error * dt, -limit), limit)

    # x = [e_p, f_d, 1, ξ_r, F, ∫e_cf, J q̇, q, q̇, g + c]; y = G x = [F_m; F_f; F_m + F_f; N^T τ_0 + g + c].
    x[X_FORCE] = f_d
    x[X_ONE] = 1.0
    for i in range(6):
        x[X_REF_TWIST0 + i] = reference[F_TWIST + i]
        x[X_WRENCH0 + i] = wrench[i]
        x[X_INTEGRAL0 + i] = law[L_INTEGRAL0 + i]
        twist = 0.0
        for j in range(7):
            twist += robot[R_J + 7 * i + j] * robot[R_QD + j]
        x[X_TWIST0 + i] = twist
    for j in range(7):
        x[X_Q0 + j] = robot[R_Q + j]
        x[X_QD0 + j] = robot[R_QD + j]
        x[X_BIAS0 + j] = robot[R_BIAS + j]
    y = law[L_Y0 : L_Y0 + G_ROWS]
    for r in range(G_JOINT0):  # the wrench rows read the task columns only, the joint rows the joint columns and 1
        acc = 0.0
        for col in range(X_TASK_END):
            acc += G[r, col] * x[col]
        y[r] = acc
    for r in range(G_JOINT0, G_ROWS):
        acc = G[r, X_ONE]
        for col in range(X_Q0, X_SIZE):
            acc += G[r, col] * x[col]
        y[r] = acc
    total = 0.0
    for j in range(7):  # τ = J^T (F_m + F_f) + N^T τ_0 + g + c
        acc = 0.0
        for i in range(6):
            acc += robot[R_J + 7 * i + j] * y[G_WRENCH0 + i]
        out[j] = acc + y[G_JOINT0 + j]
        total += out[j]
    for i in range(G_TASK_END):  # F_m, F_f
        out[O_MOTION0 + i] = y[i]

    # Limits and sanity.
    fx, fy, fz, mx, my, mz = wrench[0], wrench[1], wrench[2], wrench[3], wrench[4], wrench[5]
    force_sq = fx * fx + fy * fy + fz * fz
    out[O_SATURATED] = 0.0
    out[O_JOINT] = 0.0
    if not math.isfinite(total + force_sq + mx * mx + my * my + mz * mz):
        law[L_SATURATED] = 0.0
        for j in range(7):
            out[j] = 0.0
        return LAW_NON_FINITE
    saturated, joint, worst = False, 0, 1.0
    for j in range(7):
        limit = law[L_LIMITS0 + j]
        if abs(out[j]) > limit * worst:
            saturated, joint, worst = True, j, abs(out[j]) / limit
    code = LAW_OK
    if saturated:
        for j in range(7):
            limit = law[L_LIMITS0 + j]
            out[j] = min(max(out[j], -limit), limit)
        law[L_SATURATED_FOR] += law[L_DT]
        if law[L_SATURATED_FOR] >= law[L_SATURATION_ABORT]:
            code = LAW_TORQUE_LIMIT
        out[O_SATURATED] = 1.0
        out[O_JOINT] = joint
    else:
        law[L_SATURATED_FOR] = 0.0
    law[L_SATURATED] = 1.0 if saturated else 0.0
    if force_sq > law[L_MAX_FORCE_SQ]:
        code = LAW_FORCE_LIMIT
    return code


@numba.njit(cache=True)
def law_step_packed(law_buffer, robot, reference, wrench, in_contact, out):  # pragma: no cover - compiled
    """:func:`law_step` on a controller's :attr:`HybridController.law_buffer` (G by rows, then the law's state): one
    array fewer for a compiled caller to pass."""
    G = law_buffer[:LAW_GAIN_SIZE].reshape((G_ROWS, X_SIZE))
    return law_step(G, robot, reference, wrench, law_buffer[LAW_GAIN_SIZE:], in_contact, out)


@numba.njit(cache=True)
def _regularized(A):  # pragma: no cover - compiled
    """Add ``_SINGULAR_DAMPING * trace(A) / n`` (relative Tikhonov term) to the diagonal of square ``A``, in place."""
    n = A.shape[0]
    trace = 0.0
    for i in range(n):
        trace += A[i, i]
    term = _SINGULAR_DAMPING * trace / n
    for i in range(n):
        A[i, i] += term
    return A


@numba.njit(cache=True)
def _null_space_model(J, M, dynamic):  # pragma: no cover - compiled
    """The null-space projector ``N^T`` (7, 7) and the apparent inertia ``Λ`` (6, 6; zeros without ``M``).

    ``M`` (7, 7) the mass matrix, or an empty (0, 0) array: the static projector ``I - J^T (J J^T)^-1 J``; with it
    and ``dynamic`` the dynamically consistent ``I - J^T Λ J M^-1``, ``Λ = (J M^-1 J^T)^-1``. Both inverses are
    regularized (:func:`_regularized`).
    """
    Jt = np.ascontiguousarray(J.T)
    lam = np.zeros((6, 6))
    if M.shape[0] > 0:
        JMinv = np.ascontiguousarray(np.linalg.solve(M, Jt).T)  # J M^-1 (M symmetric)
        lam = np.linalg.inv(_regularized(JMinv @ Jt))
        if dynamic:
            return np.eye(7) - Jt @ (lam @ JMinv), lam
    JJ = _regularized(J @ Jt)
    return np.eye(7) - Jt @ np.linalg.solve(JJ, J), lam


@numba.njit(cache=True)
def write_frame(G, law, task_gain, left, damping, right, law_rows):  # pragma: no cover - compiled
    """Write a control frame into the law's gain matrix ``G`` and state ``law``, in place: the task rows ``[F_m;
    F_f]`` (``task_gain`` (12, 32) with the motion damping ``D_m = left damping right`` (6, 6 each; see
    :class:`ControlFrame`): ``D_m`` on the reference twist, ``-(D_f + D_m)`` on the tool twist), their sum in the
    wrench rows, and the frame's constants ``law_rows`` (51,). One compiled call, as a contour changes frame every
    few steps; its products go through the same BLAS as numpy's, its sums are elementwise: equal bit for bit."""
    motion_damping = np.dot(np.dot(left, damping), right)
    for i in range(G_TASK.stop):
        for j in range(X_TASK.stop):
            G[i, j] = task_gain[i, j]
    for i in range(6):
        for j in range(6):
            G[i, X_REF_TWIST.start + j] = motion_damping[i, j]
            G[i, X_TWIST.start + j] = task_gain[i, X_TWIST.start + j] - motion_damping[i, j]
    for i in range(6):
        for j in range(X_TASK.stop):
            G[G_WRENCH.start + i, j] = G[G_MOTION.start + i, j] + G[G_FORCE.start + i, j]
    for i in range(law_rows.shape[0]):
        law[L_FRAME.start + i] = law_rows[i]


@numba.njit(cache=True)
def _write_null_space(G, projector, kn, dn, posture):  # pragma: no cover - compiled
    """Write the joint-torque rows of the gain matrix ``G`` in place: ``N^T K_n q_0`` on the constant column,
    ``-K_n N^T`` on q and ``-D_n N^T`` on q̇ (``projector`` = N^T (7, 7), ``kn`` / ``dn`` the null-space stiffness
    and damping, ``posture`` q_0 (7,)). Compiled with the projector's BLAS product, equal to numpy's bit for bit."""
    constant = np.dot(projector, kn * posture)
    for i in range(7):
        G[G_JOINT.start + i, X_ONE] = constant[i]
        for j in range(7):
            G[G_JOINT.start + i, X_Q.start + j] = -kn * projector[i, j]
            G[G_JOINT.start + i, X_QD.start + j] = -dn * projector[i, j]


@numba.njit(cache=True)
def _null_space_rows(J, M, dynamic, G, kn, dn, posture):  # pragma: no cover - compiled
    """:func:`_null_space_model`, then its rows of ``G`` (:func:`_write_null_space`), in one compiled call (a model
    update every few steps); returns the projector and the apparent inertia."""
    projector, lam = _null_space_model(J, M, dynamic)
    _write_null_space(G, projector, kn, dn, posture)
    return projector, lam


@numba.njit(cache=True)
def model_update_packed(
    law_buffer, robot, mass_matrix, dynamic, kn, dn, posture, projector, inertia
):  # pragma: no cover - compiled
    """The null-space model of a controller (:meth:`HybridController.model_arguments`: its :attr:`law_buffer`, the
    projection, ``K_n``, ``D_n``, the posture, then where the projector and the inertia go) for the Jacobian in
    ``robot`` (``ROBOT_*``) and ``mass_matrix`` (7, 7; (0, 0): none, the static projector), in one compiled call that
    a loop's own compiled step can make: the null-space rows of G, the projector N^T into ``projector`` (7, 7) and
    the apparent inertia Λ, symmetrized, into ``inertia`` (6, 6). Returns :data:`LAW_OK`, or the non-finite code
    (a non-finite J or M: nothing written). Raises ``numpy.linalg.LinAlgError`` on a singular model."""
    J = robot[R_J:R_J_END].reshape((6, 7))
    if not _all_finite(J, mass_matrix):
        return LAW_NON_FINITE
    G = law_buffer[:LAW_GAIN_SIZE].reshape((G_ROWS, X_SIZE))
    rows, lam = _null_space_rows(J, mass_matrix, dynamic, G, kn, dn, posture)
    projector[:, :] = rows
    inertia[:, :] = 0.5 * (lam + lam.T)
    return LAW_OK


@numba.njit(cache=True)
def _all_finite(J, M):  # pragma: no cover - compiled
    """Whether every entry of ``J`` and ``M`` is finite (one compiled call: four numpy calls cost ~3 µs)."""
    return np.isfinite(J).all() and np.isfinite(M).all()


@numba.njit(cache=True)
def _damping_matrix(K, inertia, damping_ratio):  # pragma: no cover - compiled
    L = np.linalg.cholesky(inertia)
    X = np.linalg.solve(L, np.ascontiguousarray(np.linalg.solve(L, 0.5 * (K + K.T)).T))  # L^-1 K L^-T (K symmetric)
    w, V = np.linalg.eigh(0.5 * (X + X.T))
    sqrt_x = (V * np.sqrt(np.maximum(w, 0.0))) @ V.T
    return 2.0 * damping_ratio * (L @ sqrt_x @ L.T)


def damping_diagonal(
    gains: ControllerGains, apparent_inertia: ArrayLike | None = None, stiffness: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Return the CF damping diagonal (6,) (or (..., 6) for a ``stiffness`` (..., 6)), N·s/m and N·m·s/rad.

    Explicit values win; else ``2 ζ sqrt(K_i m_i)`` with ``K_i`` the gains' CF stiffness (or ``stiffness``, a gain
    schedule's, N/m and N·m/rad) and ``m_i`` the apparent inertia of CF axis i (``apparent_inertia`` (6,), kg and
    kg·m²) or, without it, the nominal apparent mass and inertia.
    """
    k = (
        np.concatenate(
            [
                np.asarray(gains.translational_stiffness_n_per_m, float),
                np.asarray(gains.rotational_stiffness_nm_per_rad, float),
            ]
        )
        if stiffness is None
        else np.asarray(stiffness, dtype=float)
    )
    if apparent_inertia is None:
        m = np.array([gains.apparent_mass_kg] * 3 + [gains.apparent_inertia_kgm2] * 3)
    else:
        m = np.maximum(np.asarray(apparent_inertia, dtype=float), 0.0)
    d = 2.0 * gains.damping_ratio * np.sqrt(k * m)
    if gains.translational_damping_ns_per_m is not None:
        d[..., :3] = gains.translational_damping_ns_per_m
    if gains.rotational_damping_nms_per_rad is not None:
        d[..., 3:] = gains.rotational_damping_nms_per_rad
    return d


def damping_matrix(stiffness: ArrayLike, inertia: ArrayLike, damping_ratio: float) -> NDArray[np.float64]:
    """Return ``D = 2 ζ L (L^-1 K L^-T)^{1/2} L^T`` (double diagonalization) for SPD ``K`` and ``Λ = L L^T``.

    In the coordinates that diagonalize both ``Λ`` and ``K`` every mode ``i`` gets the damping
    ``2 ζ sqrt(k_i m_i)``; for ``Λ = m I``, ``K = k I`` this is ``2 ζ sqrt(k m) I``.
    """
    K = np.ascontiguousarray(stiffness, dtype=float)
    return _damping_matrix(K, np.ascontiguousarray(inertia, dtype=float), float(damping_ratio))


def non_finite_reason(
    robot: NDArray[np.float64],
    reference: NDArray[np.float64],
    wrench: NDArray[np.float64],
    mass_matrix: NDArray[np.float64] | None,
) -> str:
    """Why a step must not run on these packed inputs (``ROBOT_*``, ``REFERENCE_*``, the wrench (6,), the mass matrix
    or None), naming each non-finite one as ``HybridController.compute``'s arguments are named (else the computed
    torque)."""
    named = {
        "jacobian": robot[ROBOT_JACOBIAN],
        "q": robot[ROBOT_Q],
        "qd": robot[ROBOT_QD],
        "bias_torques": robot[ROBOT_BIAS],
        "tool_position": robot[ROBOT_POSITION],
        "tool_quaternion": robot[ROBOT_QUAT],
        "reference_position": reference[REFERENCE_POSITION],
        "reference_quaternion": reference[REFERENCE_QUAT],
        "reference_twist": reference[REFERENCE_TWIST],
        "wrench": wrench,
        "desired_force": reference[REFERENCE_FORCE],
        "mass_matrix": mass_matrix,
    }
    bad = [name for name, value in named.items() if value is not None and not np.all(np.isfinite(value))]
    what = ", ".join(bad) if bad else "the computed torque"
    return f"non-finite value (NaN or inf) in {what}; zero torque commanded"
