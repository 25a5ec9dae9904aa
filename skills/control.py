"""The hybrid impedance/force control law of paper eq. (1)-(4) for a torque-controlled 7-DoF arm.

Pure numpy: no simulator, no I/O. :class:`HybridController` turns the robot state, the
reference and the compliant frame (CF) into 7 joint torques, once per control step.

Frames
------
The paper writes eq. (4) in the end-effector frame EF. This module computes in frame **A**:
origin at the tool point, axes of the world frame, i.e. the frame in which the simulator gives
the Jacobian ``J`` (``ξ_A = J q̇``, twist ``(v, ω)`` of the tool point, world axes) and the
measured wrench. A and EF share the origin and differ by the rotation ``R_w_ef``, so
``Ad(A <- EF) = blockdiag(R_w_ef, R_w_ef) = Adg(A <- EF)``, ``J_A = Ad J_EF``,
``F_A = Adg F_EF`` and ``J_A^T F_A = J_EF^T F_EF``: the torques are identical, and with
``T(A <- CF) = T(A <- EF) T(EF <- CF)`` eq. (3) evaluated with ``T(A <- CF)`` is eq. (3) of the
paper mapped into A. ``(R, p)`` of ``T(A <- CF)``: ``R`` = the CF orientation in the world
(world from CF), ``p`` = the CF origin minus the tool point (world axes).

Compliance centre. By default (``compliance_center="tool"``) the CF is used with its origin at
the tool point (``p = 0``): the stored CF origin (a point of the fitted plane, possibly far from
the tool) only locates the surface and the CF x-y coordinates of the path. With the literal
offset, a CF moment about the distant origin would become a lateral force at the tool, and the
contact force, whose line of action passes through the tool point, would not survive ``Ω~``
unchanged (``Ω~`` would add the moment ``p × f``). ``compliance_center="cf_origin"`` keeps the
literal form for completeness (then ``p`` changes with the tool position and the frame has to
be rebuilt every step).

The law (all 6-vectors in A; wrenches are applied BY the tool TO the environment)::

    e_p   = [p_r - p,  2 log(q_r ⊗ q*)]                      pose error (position, rotation vector)
    F_m   = Ω e_p + F_damp                                   impedance on the motion axes (eq. 3, 4)
    e_f   = F_d - F                                          force error, F_d = Adg (0, 0, f_d, 0, 0, 0)
    F_f   = Ω~ F_d + K_p Ω~ e_f + K_i Adg S~ ∫ S~ Adg^-1 e_f dt  PI force control with feed-forward
    τ     = J^T (F_m + F_f) + g(q) + c(q, q̇) + N^T τ_0        N^T τ_0: null-space posture torque

with ``Ω = Adg K_c S Ad^-1`` and ``Ω~ = Adg S~ Adg^-1`` from :mod:`skills.frames`.

Damping (Cartesian, in the CF). In CF coordinates ``ξ_cf = Ad^-1 ξ``::

    F_damp = Adg (S D_cf S (ξ_r,cf - ξ_cf) - d_f ⊙ S~ ⊙ ξ_cf)

the motion axes damp the velocity error, the force axes the absolute tool velocity (the
surface does not move): "active damping" that keeps the PI force loop stable on a stiff
surface (``force_axis_damping_ns_per_m``). With a damping RATIO the motion-axes damping is the
full matrix of the "double diagonalization" (Albu-Schäffer et al. 2003),
``D = 2 ζ L (L^-1 K L^-T)^{1/2} L^T`` with ``Λ = L L^T`` the apparent inertia at the tool
point, ``Λ = (J M^-1 J^T)^-1``, and ``K`` the CF stiffness mapped into A: every decoupled mode
gets damping ratio ζ. It is rebuilt with the null-space projector whenever a mass matrix is
given (until then, or without one, the diagonal ``2 ζ sqrt(K_i m_i)`` with the nominal
``apparent_mass_kg`` / ``apparent_inertia_kgm2``) and mapped into the current CF every step
(``D_cf = Ad^T D Ad``; restricted to the motion axes, ``S D_cf S``). This matters on the iiwa:
the apparent inertia about the tool axis is ~1e-3 kg·m² but ~0.2 kg·m² about the other two, so
one fixed (or per-axis diagonal) rotational damping is either unstable at 1 kHz about the tool
axis or far too weak about the others, as soon as the tool is tilted. Explicit damping values
override the ratio (a constant diagonal in the CF). The null-space task has its own joint
damping. The paper's ``D_x J q̇`` term is this Cartesian damping with the sign that dissipates
energy.

Force loop. The desired wrench is fed forward (``Ω~ F_d``), so the PI part only corrects the
residual; the integral is kept in CF coordinates (it travels with a contour's moving CF) and
integrated only on the force axes. Anti-windup: ``|K_i ∫e|`` is clamped to
``force_integral_limit_n`` per axis, and integration is frozen while the previous torque command
saturated or the caller reports no contact.

Null space. ``τ_0 = K_n (q_0 - q) - D_n q̇`` pulls the redundant elbow towards the posture
``q_0``. Projector (``null_space``): ``dynamic`` (default) ``N^T = I - J^T Λ J M^-1`` with
``Λ = (J M^-1 J^T)^-1`` (dynamically consistent: the posture torque produces no task-space
acceleration), or ``static`` ``N^T = I - J^T (J J^T)^-1 J`` (``I - J^T J^{+T}``; no mass matrix
needed, but not free of task-space acceleration). Both are regularized near singularities.

Limits. Torques are clipped to the robot's limits; a clip lasting ``torque_saturation_abort_s``
aborts. A measured force above ``max_force_n`` aborts at once. Non-finite inputs never give a
non-finite torque: the output is zero torques with an abort reason.

Cost. The law runs at 1 kHz, where a numpy call on a 6- or 7-vector costs ~0.3-1 µs of call
overhead whatever it computes. Everything above is linear in the step's input vector ``x = [e_p,
f_d, 1, ξ_r, F, ∫e_cf, ξ, q, q̇, g + c]`` (53 values, layout ``_X_*``), so a cached gain matrix
``G`` (25 x 53) gives ``y = G x = [F_m; F_f; F_m + F_f; N^T τ_0 + g + c]`` and ``τ = J^T (F_m +
F_f) + (N^T τ_0 + g + c)``. One step is ONE compiled call (:func:`law_step`, numba) on packed
arrays (the robot state ``ROBOT_*``, the reference ``REFERENCE_*``, the law's state ``_L_*``):
the pose error, the force integral, ``x``, ``G x``, ``τ`` and the limit checks. The rows of ``G``
that depend on the control frame (``Ω``, the motion damping ``D_m`` and ``-(D_m + D_f)``, the
feed-forward ``(1 + K_p) Ω~ F_d,1`` per N desired, ``-K_p Ω~``, ``K_i Adg``) are rebuilt when the
frame or the damping matrix changes (a contour's frame series every few steps: the frame-only
products come precomputed, vectorized, with the frames); the null-space rows (``N^T K_n q_0``,
``-K_n N^T``, ``-D_n N^T``) whenever the caller refreshes the model (``update_null_space``: the
projector and the apparent inertia, the damping every :data:`DAMPING_UPDATE_EVERY`-th time; both
compiled too).

Baselines (``ControllerKind``), the same class with other settings:

- ``impedance``: ``S = I`` on every axis (no force loop, no feed-forward), stiffness and damping
  in the CF; the force is only what the reference implies: during contact the reference is
  moved ``f_d / k_z`` along +CF z (``k_z`` the CF-z translational stiffness), so the spring
  presses with ``f_d`` if the surface is exactly where its reference is based: the taught surface
  (``impedance``) or the surface the guarded approach found (``impedance_found_surface``, the
  executor re-bases the reference; the law is the same).
- ``hybrid_world_z``: the CF orientation is replaced by the "world z down" frame: z = -z_world,
  x = the CF x axis projected onto the horizontal plane (world x if the CF x is vertical),
  y = z × x. The selection and force loop are as in ``hybrid_cf``, so the desired force pushes
  straight down whatever the surface normal is.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.execution import ControllerGains, ControllerKind, NullSpaceProjection
from skills.frames import (
    adjoint_from_transform,
    force_projector_in_frame,
    stiffness_in_frame,
    transform_inverse,
    wrench_adjoint_from_transform,
)

IIWA_TORQUE_LIMITS_NM: tuple[float, ...] = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)
"""Joint torque limits of the KUKA LBR iiwa 14 R820 (N·m), the default when the robot gives none."""
DAMPING_UPDATE_EVERY = 5
"""The adaptive damping matrix is rebuilt on every this-many-th model update (it costs ~2x the projector)."""
_SINGULAR_DAMPING = 1e-6
"""Relative Tikhonov term of the task-space inverses in the null-space projector."""
_EYE6 = np.eye(6)
_EYE7 = np.eye(7)
NO_MASS_MATRIX = np.zeros((0, 0))
"""The mass matrix argument of the compiled model update when there is none (the static null-space projector)."""

# Layout of the law's per-step input vector x (see the module docstring, "Cost") and of the gain matrix G.
_X_POSE = slice(0, 6)  # e_p: pose error (m, rad)
_X_FORCE = 6  # f_d: desired CF-z force (N)
_X_ONE = 7  # 1: carries the constant null-space torque N^T K_n q_0
_X_REF_TWIST = slice(8, 14)  # ξ_r: reference twist
_X_WRENCH = slice(14, 20)  # F: measured wrench
_X_INTEGRAL = slice(20, 26)  # ∫ S~ e_cf dt: force integral, CF coordinates
_X_TWIST = slice(26, 32)  # ξ = J q̇: tool twist
_X_Q = slice(32, 39)  # q
_X_QD = slice(39, 46)  # q̇
_X_BIAS = slice(46, 53)  # g + c: gravity and Coriolis torques
_X_SIZE = 53
_X_TASK = slice(0, 32)  # the columns the task-space rows of G can use
_G_MOTION = slice(0, 6)  # rows of G giving F_m
_G_FORCE = slice(6, 12)  # rows giving F_f
_G_TASK = slice(0, 12)  # F_m and F_f: the rows that change with the control frame
_G_WRENCH = slice(12, 18)  # rows giving F_m + F_f (their sum, so that τ needs no further addition)
_G_JOINT = slice(18, 25)  # rows giving N^T τ_0 + g + c
_G_ROWS = 25
LAW_GAIN_SIZE = _G_ROWS * _X_SIZE
"""G's floats at the head of a controller's law buffer (:attr:`HybridController.law_buffer`), the law's state after."""

# Layout of the robot state one control step reads (one float array, so that the compiled step takes few arguments;
# ``sim_worker.arm_model`` fills a world's in this layout): joints, tool pose, Jacobian, gravity/Coriolis torques.
ROBOT_Q = slice(0, 7)  # q, rad
ROBOT_QD = slice(7, 14)  # q̇, rad/s
ROBOT_POSITION = slice(14, 17)  # tool point, world, m
ROBOT_QUAT = slice(17, 21)  # tool orientation [x, y, z, w]
ROBOT_ROTATION = slice(21, 30)  # tool orientation, 3 x 3 by rows (not read by the law)
ROBOT_JACOBIAN = slice(30, 72)  # J (6 x 7 by rows), tool point, world axes
ROBOT_BIAS = slice(72, 79)  # g + c, N·m
ROBOT_STATE_SIZE = 79
# Layout of one step's reference: position (3), quaternion (4), twist (6), desired CF-z force (N).
REFERENCE_POSITION = slice(0, 3)
REFERENCE_QUAT = slice(3, 7)
REFERENCE_TWIST = slice(7, 13)
REFERENCE_FORCE = 13
REFERENCE_SIZE = 14
# Layout of the law's own state and per-frame constants (``HybridController._law``), read by the compiled step.
_L_INTEGRAL = slice(0, 6)  # ∫ S~ e_cf dt, CF coordinates
_L_SATURATED = 6  # 1 when the previous torque command was clipped
_L_SATURATED_FOR = 7  # how long the torques have been clipped, s
_L_DT = 8
_L_INTEGRAL_BOUND = 9  # |∫e| bound per axis (force_integral_limit_n / K_i)
_L_IMPEDANCE_KZ = 10  # k_z for the impedance baseline's reference shift f_d / k_z along CF z; 0: no shift
_L_MAX_FORCE_SQ = 11
_L_SATURATION_ABORT = 12  # torque_saturation_abort_s - dt / 2
_L_LIMITS = slice(13, 20)  # torque limits, N·m
_L_FRAME = slice(20, 71)  # the control frame's constants (ControlFrame.law_rows), these four:
_L_CF_Z = slice(20, 23)  # the control frame's CF z axis
_L_AXES = slice(23, 29)  # 1 on the CF force axes the integral runs on
_L_ERROR_PER_N = slice(29, 35)  # S~ Adg^-1 F_d,1: CF force error per N desired
_L_ADG_INV = slice(35, 71)  # Adg^-1 by rows: the measured wrench into CF coordinates
_L_X = slice(71, 71 + _X_SIZE)  # scratch: the step's input vector x (no allocation per step)
_L_Y = slice(_L_X.stop, _L_X.stop + _G_ROWS)  # scratch: y = G x
_L_SIZE = _L_Y.stop
# Layout of a step's output: τ (7), F_m (6), F_f (6), saturated (1/0), the most saturated joint.
LAW_TAU = slice(0, 7)
_O_MOTION = slice(7, 13)
_O_FORCE = slice(13, 19)
_O_SATURATED = 19
_O_JOINT = 20
LAW_OUTPUT_SIZE = 21
# Codes the compiled step returns.
LAW_OK, _NON_FINITE, _TORQUE_LIMIT, _FORCE_LIMIT = 0, 1, 2, 3


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


# The layouts' offsets as plain ints for the compiled step (numba freezes module-level ints as constants; it does not
# take slices as globals). Derived from the slices above: one home for each layout.
_R_Q, _R_QD, _R_P, _R_QUAT, _R_QUAT_END = (
    ROBOT_Q.start,
    ROBOT_QD.start,
    ROBOT_POSITION.start,
    ROBOT_QUAT.start,
    ROBOT_QUAT.stop,
)
_R_J, _R_BIAS = ROBOT_JACOBIAN.start, ROBOT_BIAS.start
_F_P, _F_QUAT, _F_QUAT_END, _F_TWIST = (
    REFERENCE_POSITION.start,
    REFERENCE_QUAT.start,
    REFERENCE_QUAT.stop,
    REFERENCE_TWIST.start,
)
_X_REF_TWIST0, _X_WRENCH0, _X_INTEGRAL0 = _X_REF_TWIST.start, _X_WRENCH.start, _X_INTEGRAL.start
_X_TWIST0, _X_Q0, _X_QD0, _X_BIAS0, _X_TASK_END = _X_TWIST.start, _X_Q.start, _X_QD.start, _X_BIAS.start, _X_TASK.stop
_G_WRENCH0, _G_JOINT0, _G_TASK_END = _G_WRENCH.start, _G_JOINT.start, _G_TASK.stop
_L_INTEGRAL0, _L_LIMITS0, _L_CF_Z0 = _L_INTEGRAL.start, _L_LIMITS.start, _L_CF_Z.start
_L_AXES0, _L_ERROR_PER_N0, _L_ADG_INV0 = _L_AXES.start, _L_ERROR_PER_N.start, _L_ADG_INV.start
_L_X0, _L_Y0 = _L_X.start, _L_Y.start
_O_MOTION0 = _O_MOTION.start
if _O_FORCE.start != _O_MOTION.stop or _G_FORCE.start != _G_MOTION.stop:  # the step copies F_m, F_f in one run
    raise AssertionError("F_m and F_f must be adjacent in G and in the output")


@numba.njit(cache=True)
def law_step(G, robot, reference, wrench, law, in_contact, out):  # pragma: no cover - compiled
    """One step of the law (module docstring, "Cost"): τ, F_m, F_f into ``out``; returns a code (``LAW_OK``, ...).

    ``G`` the gain matrix, ``robot`` / ``reference`` / ``law`` / ``out`` in the ``ROBOT_*``, ``REFERENCE_*``,
    ``_L_*``, ``_O_*`` layouts, ``wrench`` (6,) the measured wrench; updates the force integral and the saturation
    state in ``law``.
    """
    f_d = reference[REFERENCE_FORCE]
    rpx, rpy, rpz = reference[_F_P], reference[_F_P + 1], reference[_F_P + 2]
    kz = law[_L_IMPEDANCE_KZ]
    if kz != 0.0 and f_d != 0.0:  # impedance: the reference presses f_d through the spring along CF z
        shift = f_d / kz
        rpx, rpy, rpz = rpx + law[_L_CF_Z0] * shift, rpy + law[_L_CF_Z0 + 1] * shift, rpz + law[_L_CF_Z0 + 2] * shift
    x = law[_L_X0 : _L_X0 + _X_SIZE]
    _pose_error_into(
        robot[_R_P], robot[_R_P + 1], robot[_R_P + 2], robot[_R_QUAT:_R_QUAT_END], rpx, rpy, rpz,
        reference[_F_QUAT:_F_QUAT_END], x,
    )  # fmt: skip

    # Force integral, CF coordinates, one force axis at a time: ∫ S~ (f_d S~ Adg^-1 F_d,1 - Adg^-1 F) dt.
    if in_contact and law[_L_SATURATED] == 0.0:
        dt, limit = law[_L_DT], law[_L_INTEGRAL_BOUND]
        for i in range(6):
            if law[_L_AXES0 + i] != 0.0:
                row = _L_ADG_INV0 + 6 * i
                measured = law[row] * wrench[0]
                for j in range(1, 6):
                    measured += law[row + j] * wrench[j]
                error = f_d * law[_L_ERROR_PER_N0 + i] - measured
                law[_L_INTEGRAL0 + i] = min(max(law[_L_INTEGRAL0 + i] + error * dt, -limit), limit)

    # x = [e_p, f_d, 1, ξ_r, F, ∫e_cf, J q̇, q, q̇, g + c]; y = G x = [F_m; F_f; F_m + F_f; N^T τ_0 + g + c].
    x[_X_FORCE] = f_d
    x[_X_ONE] = 1.0
    for i in range(6):
        x[_X_REF_TWIST0 + i] = reference[_F_TWIST + i]
        x[_X_WRENCH0 + i] = wrench[i]
        x[_X_INTEGRAL0 + i] = law[_L_INTEGRAL0 + i]
        twist = 0.0
        for j in range(7):
            twist += robot[_R_J + 7 * i + j] * robot[_R_QD + j]
        x[_X_TWIST0 + i] = twist
    for j in range(7):
        x[_X_Q0 + j] = robot[_R_Q + j]
        x[_X_QD0 + j] = robot[_R_QD + j]
        x[_X_BIAS0 + j] = robot[_R_BIAS + j]
    y = law[_L_Y0 : _L_Y0 + _G_ROWS]
    for r in range(_G_JOINT0):  # the wrench rows read the task columns only, the joint rows the joint columns and 1
        acc = 0.0
        for col in range(_X_TASK_END):
            acc += G[r, col] * x[col]
        y[r] = acc
    for r in range(_G_JOINT0, _G_ROWS):
        acc = G[r, _X_ONE]
        for col in range(_X_Q0, _X_SIZE):
            acc += G[r, col] * x[col]
        y[r] = acc
    total = 0.0
    for j in range(7):  # τ = J^T (F_m + F_f) + N^T τ_0 + g + c
        acc = 0.0
        for i in range(6):
            acc += robot[_R_J + 7 * i + j] * y[_G_WRENCH0 + i]
        out[j] = acc + y[_G_JOINT0 + j]
        total += out[j]
    for i in range(_G_TASK_END):  # F_m, F_f
        out[_O_MOTION0 + i] = y[i]

    # Limits and sanity.
    fx, fy, fz, mx, my, mz = wrench[0], wrench[1], wrench[2], wrench[3], wrench[4], wrench[5]
    force_sq = fx * fx + fy * fy + fz * fz
    out[_O_SATURATED] = 0.0
    out[_O_JOINT] = 0.0
    if not math.isfinite(total + force_sq + mx * mx + my * my + mz * mz):
        law[_L_SATURATED] = 0.0
        for j in range(7):
            out[j] = 0.0
        return _NON_FINITE
    saturated, joint, worst = False, 0, 1.0
    for j in range(7):
        limit = law[_L_LIMITS0 + j]
        if abs(out[j]) > limit * worst:
            saturated, joint, worst = True, j, abs(out[j]) / limit
    code = LAW_OK
    if saturated:
        for j in range(7):
            limit = law[_L_LIMITS0 + j]
            out[j] = min(max(out[j], -limit), limit)
        law[_L_SATURATED_FOR] += law[_L_DT]
        if law[_L_SATURATED_FOR] >= law[_L_SATURATION_ABORT]:
            code = _TORQUE_LIMIT
        out[_O_SATURATED] = 1.0
        out[_O_JOINT] = joint
    else:
        law[_L_SATURATED_FOR] = 0.0
    law[_L_SATURATED] = 1.0 if saturated else 0.0
    if force_sq > law[_L_MAX_FORCE_SQ]:
        code = _FORCE_LIMIT
    return code


@numba.njit(cache=True)
def law_step_packed(law_buffer, robot, reference, wrench, in_contact, out):  # pragma: no cover - compiled
    """:func:`law_step` on a controller's :attr:`HybridController.law_buffer` (G by rows, then the law's state): one
    array fewer for a compiled caller to pass."""
    G = law_buffer[:LAW_GAIN_SIZE].reshape((_G_ROWS, _X_SIZE))
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
def _write_frame(G, law, task_gain, left, damping, right, law_rows):  # pragma: no cover - compiled
    """Write a control frame into the law's gain matrix ``G`` and state ``law``, in place: the task rows ``[F_m;
    F_f]`` (``task_gain`` (12, 32) with the motion damping ``D_m = left damping right`` (6, 6 each; see
    :class:`ControlFrame`): ``D_m`` on the reference twist, ``-(D_f + D_m)`` on the tool twist), their sum in the
    wrench rows, and the frame's constants ``law_rows`` (51,). One compiled call, as a contour changes frame every
    few steps; its products go through the same BLAS as numpy's, its sums are elementwise: equal bit for bit."""
    motion_damping = np.dot(np.dot(left, damping), right)
    for i in range(_G_TASK.stop):
        for j in range(_X_TASK.stop):
            G[i, j] = task_gain[i, j]
    for i in range(6):
        for j in range(6):
            G[i, _X_REF_TWIST.start + j] = motion_damping[i, j]
            G[i, _X_TWIST.start + j] = task_gain[i, _X_TWIST.start + j] - motion_damping[i, j]
    for i in range(6):
        for j in range(_X_TASK.stop):
            G[_G_WRENCH.start + i, j] = G[_G_MOTION.start + i, j] + G[_G_FORCE.start + i, j]
    for i in range(law_rows.shape[0]):
        law[_L_FRAME.start + i] = law_rows[i]


@numba.njit(cache=True)
def _write_null_space(G, projector, kn, dn, posture):  # pragma: no cover - compiled
    """Write the joint-torque rows of the gain matrix ``G`` in place: ``N^T K_n q_0`` on the constant column,
    ``-K_n N^T`` on q and ``-D_n N^T`` on q̇ (``projector`` = N^T (7, 7), ``kn`` / ``dn`` the null-space stiffness
    and damping, ``posture`` q_0 (7,)). Compiled with the projector's BLAS product, equal to numpy's bit for bit."""
    constant = np.dot(projector, kn * posture)
    for i in range(7):
        G[_G_JOINT.start + i, _X_ONE] = constant[i]
        for j in range(7):
            G[_G_JOINT.start + i, _X_Q.start + j] = -kn * projector[i, j]
            G[_G_JOINT.start + i, _X_QD.start + j] = -dn * projector[i, j]


@numba.njit(cache=True)
def _null_space_rows(J, M, dynamic, G, kn, dn, posture):  # pragma: no cover - compiled
    """:func:`_null_space_model`, then its rows of ``G`` (:func:`_write_null_space`), in one compiled call (a model
    update every few steps); returns the projector and the apparent inertia."""
    projector, lam = _null_space_model(J, M, dynamic)
    _write_null_space(G, projector, kn, dn, posture)
    return projector, lam


_J0, _J1 = ROBOT_JACOBIAN.start, ROBOT_JACOBIAN.stop  # plain ints for the compiled code


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
    J = robot[_J0:_J1].reshape((6, 7))
    if not _all_finite(J, mass_matrix):
        return _NON_FINITE
    G = law_buffer[:LAW_GAIN_SIZE].reshape((_G_ROWS, _X_SIZE))
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


def world_z_down_rotation(cf_rotation: ArrayLike) -> NDArray[np.float64]:
    """Return the ``hybrid_world_z`` frame for a CF: z = -z_world, x = CF x made horizontal, y = z × x.

    ``cf_rotation`` (3, 3) or (N, 3, 3), world from CF; falls back to the CF y axis, then world x,
    when the CF x axis is (nearly) vertical.
    """
    R = np.asarray(cf_rotation, dtype=float)
    z = np.broadcast_to(np.array([0.0, 0.0, -1.0]), R.shape[:-1])
    candidates = [R[..., :, 0], R[..., :, 1], np.broadcast_to(np.array([1.0, 0.0, 0.0]), R.shape[:-1])]
    x = np.zeros(R.shape[:-1])
    chosen = np.zeros(R.shape[:-2], dtype=bool)
    for c in candidates:
        h = c - np.sum(c * z, axis=-1, keepdims=True) * z
        n = np.linalg.norm(h, axis=-1)
        use = (~chosen) & (n > 1e-3)
        x = np.where(use[..., None], h / np.maximum(n, 1e-12)[..., None], x)
        chosen |= use
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def _blockdiag_rotation(R: NDArray[np.float64]) -> NDArray[np.float64]:
    Ad = np.zeros((*R.shape[:-2], 6, 6))
    Ad[..., :3, :3] = R
    Ad[..., 3:, 3:] = R
    return Ad


class ControlFrame(NamedTuple):
    """The compliant frame as the law needs it at one instant (matrices map CF quantities into A).

    Immutable, and a named tuple rather than a frozen dataclass: a contour builds one every few control steps, and
    a tuple of 16 views is built in a third of the time.

    ``rotation`` (3, 3): orientation of the CONTROL frame in the world (the CF, or world-z-down
    for ``hybrid_world_z``); ``cf_rotation`` (3, 3) the skill's CF (world from CF) and ``cf_z``
    (3,) its z axis (the measured CF-z force is taken along it; the impedance baseline moves its
    reference along it); ``selection`` (6,) the diagonal of S in the control frame (1 = motion),
    ``force_axes`` = ``1 - selection``; ``omega`` = Ω = ``Adg K_c S Ad^-1``, ``projector`` =
    Ω~ = ``Adg S~ Adg^-1``; ``ad`` / ``ad_inv`` the twist adjoint CF -> A and its inverse,
    ``adg`` / ``adg_inv`` the wrench adjoint and its inverse; ``force_direction`` (6,) =
    ``Adg S~ e_z``: the wrench in A of 1 N desired along CF z (zero without a force loop).

    Frame-only products of the law (with the controller's gains, without the robot model),
    precomputed with the frame so that a contour's changing frame costs little per step:
    ``damping_left`` = ``Adg S Ad^T`` and ``damping_right`` = ``Ad S Ad^-1`` (6, 6), so that a
    damping matrix ``D`` in A gives the motion-subspace damping ``D_m = damping_left D
    damping_right`` (``Adg S D_cf S Ad^-1`` with ``D_cf = Ad^T D Ad``); ``law_rows`` (51,) the
    frame's constants of the compiled law, packed as its state stores them (``cf_z``, the force axes the
    integral runs on, ``S~ Adg^-1 F_d,1`` the CF force error per N desired, ``Adg^-1`` by rows), so that a
    new frame is one copy; ``task_gain`` (12, 32) the rows of
    the controller's gain matrix that give ``[F_m; F_f]`` (module docstring, "Cost") without the
    motion damping: ``Ω`` on the pose error, ``-D_f`` on the tool twist (``D_f = Adg diag(d_f ⊙
    S~) Ad^-1``, the force axes' active damping), the feed-forward ``F_d,1 + K_p Ω~ F_d,1`` on
    ``f_d``, ``-K_p Ω~`` on the wrench and ``K_i Adg`` on the force integral.
    """

    rotation: NDArray[np.float64]
    cf_rotation: NDArray[np.float64]
    cf_z: NDArray[np.float64]
    selection: NDArray[np.float64]
    force_axes: NDArray[np.float64]
    omega: NDArray[np.float64]
    projector: NDArray[np.float64]
    ad: NDArray[np.float64]
    ad_inv: NDArray[np.float64]
    adg: NDArray[np.float64]
    adg_inv: NDArray[np.float64]
    force_direction: NDArray[np.float64]
    damping_left: NDArray[np.float64]
    damping_right: NDArray[np.float64]
    law_rows: NDArray[np.float64]
    task_gain: NDArray[np.float64]


class ControlFrameSeries:
    """Control frames for a sequence of CF orientations (a contour segment), built in one vectorized pass.

    Index it with the control step to get a :class:`ControlFrame` (clamped to the ends). Each frame is built
    once, with the series, so that the controller's per-frame cache sees the same object again.
    """

    def __init__(self, fields: dict[str, NDArray[np.float64]]) -> None:
        # zip walks the (M, ...) arrays along their first axis in C: a frame's 16 views in ~1 µs.
        self._frames = list(map(ControlFrame._make, zip(*[fields[name] for name in ControlFrame._fields], strict=True)))

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, k: int) -> ControlFrame:
        return self._frames[min(max(int(k), 0), len(self._frames) - 1)]


class ControlOutput(NamedTuple):
    """One control step's result.

    ``tau`` (7,) joint torques after limits, N·m (zeros when ``abort_reason`` says non-finite);
    ``wrench_motion`` and ``wrench_force`` (6,) the task-space commands of the motion subspace
    (stiffness and damping) and the force subspace in A (applied by the tool, N, N·m);
    ``saturated``: a joint torque was clipped; ``abort_reason``: why the execution must stop
    now, or None.
    """

    tau: NDArray[np.float64]
    wrench_motion: NDArray[np.float64]
    wrench_force: NDArray[np.float64]
    saturated: bool
    abort_reason: str | None


def damping_diagonal(gains: ControllerGains, apparent_inertia: ArrayLike | None = None) -> NDArray[np.float64]:
    """Return the CF damping diagonal (6,), N·s/m and N·m·s/rad.

    Explicit values win; else ``2 ζ sqrt(K_i m_i)`` with ``m_i`` the apparent inertia of CF axis i
    (``apparent_inertia`` (6,), kg and kg·m²) or, without it, the nominal apparent mass and inertia.
    """
    k = np.concatenate(
        [
            np.asarray(gains.translational_stiffness_n_per_m, float),
            np.asarray(gains.rotational_stiffness_nm_per_rad, float),
        ]
    )
    if apparent_inertia is None:
        m = np.array([gains.apparent_mass_kg] * 3 + [gains.apparent_inertia_kgm2] * 3)
    else:
        m = np.maximum(np.asarray(apparent_inertia, dtype=float), 0.0)
    d = 2.0 * gains.damping_ratio * np.sqrt(k * m)
    if gains.translational_damping_ns_per_m is not None:
        d[:3] = gains.translational_damping_ns_per_m
    if gains.rotational_damping_nms_per_rad is not None:
        d[3:] = gains.rotational_damping_nms_per_rad
    return d


def damping_matrix(stiffness: ArrayLike, inertia: ArrayLike, damping_ratio: float) -> NDArray[np.float64]:
    """Return ``D = 2 ζ L (L^-1 K L^-T)^{1/2} L^T`` (double diagonalization) for SPD ``K`` and ``Λ = L L^T``.

    In the coordinates that diagonalize both ``Λ`` and ``K`` every mode ``i`` gets the damping
    ``2 ζ sqrt(k_i m_i)``; for ``Λ = m I``, ``K = k I`` this is ``2 ζ sqrt(k m) I``.
    """
    K = np.ascontiguousarray(stiffness, dtype=float)
    return _damping_matrix(K, np.ascontiguousarray(inertia, dtype=float), float(damping_ratio))


def _named_inputs(
    robot: NDArray[np.float64],
    reference: NDArray[np.float64],
    wrench: NDArray[np.float64],
    mass_matrix: NDArray[np.float64] | None,
) -> dict[str, object]:
    """The packed inputs of a step by the names of :meth:`HybridController.compute`'s arguments (for error messages)."""
    return {
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


class HybridController:
    """The hybrid impedance/force controller (see the module docstring for frames and the law).

    ``kind`` picks our law or a baseline; ``gains`` the gains and limits; ``dt`` the control
    period (s); ``torque_limits`` (7,) N·m (default: the iiwa's); ``posture`` (7,) the null-space
    target q_0 (rad; also settable with :meth:`reset`); ``compliance_center`` "tool" (default) or
    "cf_origin". State: the force integral (CF coordinates), the damping diagonal, the
    null-space projector and the saturation timer.
    """

    def __init__(
        self,
        kind: ControllerKind | str = ControllerKind.hybrid_cf,
        gains: ControllerGains | None = None,
        dt: float = 1e-3,
        torque_limits: ArrayLike | None = None,
        posture: ArrayLike | None = None,
        compliance_center: Literal["tool", "cf_origin"] = "tool",
    ) -> None:
        self.kind = ControllerKind(kind)
        self.gains = gains if gains is not None else ControllerGains()
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt}")
        self.dt = float(dt)
        limits = IIWA_TORQUE_LIMITS_NM if torque_limits is None else torque_limits
        self.torque_limits = np.asarray(limits, dtype=float)
        if self.torque_limits.shape != (7,) or np.any(self.torque_limits <= 0):
            raise ValueError(f"torque_limits must be 7 positive values (N·m), got {self.torque_limits}")
        if compliance_center not in ("tool", "cf_origin"):
            raise ValueError(f"compliance_center must be 'tool' or 'cf_origin', got {compliance_center!r}")
        self.compliance_center = compliance_center
        g = self.gains
        self._stiffness = np.concatenate(
            [np.asarray(g.translational_stiffness_n_per_m, float), np.asarray(g.rotational_stiffness_nm_per_rad, float)]
        )
        self._adaptive_damping = g.translational_damping_ns_per_m is None and g.rotational_damping_nms_per_rad is None
        self.damping = damping_diagonal(g)
        self.damping_matrix_a: NDArray[np.float64] | None = None
        """The adaptive damping matrix in A (6, 6), or None while the diagonal ``damping`` (CF) applies."""
        self._force_axis_damping = np.concatenate([np.full(3, g.force_axis_damping_ns_per_m), self.damping[3:]])
        self._force_loop = not self.kind.is_impedance
        self._kp = g.force_kp if self._force_loop else 0.0
        self._ki = g.force_ki if self._force_loop else 0.0
        self._kz = float(self._stiffness[2])
        self._dynamic_null = g.null_space is NullSpaceProjection.dynamic
        self._kn = g.nullspace_stiffness_nm_per_rad
        self._dn = g.nullspace_damping_nms_per_rad
        self._integral_bound = g.force_integral_limit_n / self._ki if self._ki > 0.0 else 0.0
        self.posture = np.zeros(7) if posture is None else np.asarray(posture, dtype=float).copy()
        self.law_buffer = np.zeros(LAW_GAIN_SIZE + _L_SIZE)
        """G by rows (:attr:`_gain`), then the law's state (:attr:`_law`): one array, so that a loop's compiled step
        runs the law (:func:`law_step_packed`) with one argument for both; written in place, never replaced."""
        self._law = self.law_buffer[LAW_GAIN_SIZE:]
        """The compiled step's state and constants (layout ``_L_*``)."""
        law = self._law
        law[_L_DT] = self.dt
        law[_L_INTEGRAL_BOUND] = self._integral_bound
        law[_L_IMPEDANCE_KZ] = 0.0 if self._force_loop else self._kz
        law[_L_MAX_FORCE_SQ] = g.max_force_n**2
        law[_L_SATURATION_ABORT] = g.torque_saturation_abort_s - 0.5 * self.dt
        law[_L_LIMITS] = self.torque_limits
        self.integral_cf = law[_L_INTEGRAL]
        """The force integral ∫ S~ e_cf dt, CF coordinates (a view of the law's state)."""
        self._projector: NDArray[np.float64] | None = None
        """N^T (7, 7) of the last model update (:attr:`_projector_rows`), or None while there is none."""
        self._projector_rows = np.zeros((7, 7))
        self._inertia = np.zeros((6, 6))
        """Λ of the last model update, symmetrized: what the adaptive damping is rebuilt from."""
        self._model_version = 0
        self._gain = self.law_buffer[:LAW_GAIN_SIZE].reshape(_G_ROWS, _X_SIZE)
        """G: [F_m; F_f; F_m + F_f; N^T τ_0 + g + c] = G x (module docstring, "Cost"), cached by parts."""
        self._gain[_G_JOINT, _X_BIAS] = _EYE7
        self._gain_frame: ControlFrame | None = None
        self._gain_damping: NDArray[np.float64] | None = None
        """The damping matrix the frame rows of G were built with (rebuilt when it is replaced)."""

    # ------------------------------------------------------------------ state

    def reset(self, posture: ArrayLike | None = None) -> None:
        """Clear the force integral, projector and saturation timer; optionally set the posture (7,) rad."""
        if posture is not None:
            self.posture = np.asarray(posture, dtype=float).copy()
        self.reset_integral()
        self._projector = None
        self.damping_matrix_a = None
        self._law[_L_SATURATED] = 0.0
        self._law[_L_SATURATED_FOR] = 0.0

    def reset_integral(self) -> None:
        """Clear the force integral (e.g. at the start of a contact segment)."""
        self.integral_cf[:] = 0.0

    # ------------------------------------------------------------------ frames

    def _control_rotation_and_selection(
        self, cf_rotation: NDArray[np.float64], selection: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if self.kind.is_impedance:
            return cf_rotation, np.ones_like(selection)
        if self.kind is ControllerKind.hybrid_world_z and np.any(selection < 1.0):
            return world_z_down_rotation(cf_rotation), selection
        return cf_rotation, selection

    def _frame_fields(
        self, cf_rotation: ArrayLike, selection: ArrayLike, offset: ArrayLike | None
    ) -> dict[str, NDArray[np.float64]]:
        cf_rotation = np.asarray(cf_rotation, dtype=float)
        batch = cf_rotation.shape[:-2]
        sel_in = np.broadcast_to(np.asarray(selection, dtype=float), (*batch, 6))
        R, S = self._control_rotation_and_selection(cf_rotation, sel_in)
        S = np.ascontiguousarray(S)
        if offset is None:
            p = np.zeros((*batch, 3))
            ad = _blockdiag_rotation(R)
            ad_inv = np.swapaxes(ad, -1, -2)
            adg, adg_inv = ad, ad_inv
        else:
            p = np.broadcast_to(np.asarray(offset, float), (*batch, 3))
            ad = adjoint_from_transform(R, p)
            ad_inv = adjoint_from_transform(*transform_inverse(R, p))
            adg = wrench_adjoint_from_transform(R, p)
            adg_inv = wrench_adjoint_from_transform(*transform_inverse(R, p))
        force_axes = 1.0 - S
        force_direction = adg[..., :, 2] * force_axes[..., 2:3] if self._force_loop else np.zeros((*batch, 6))
        omega = stiffness_in_frame(R, p, self._stiffness, S)
        projector = force_projector_in_frame(R, p, S)
        error_direction = force_axes * (adg_inv @ force_direction[..., None])[..., 0]  # S~ Adg^-1 F_d,1
        task_gain = np.zeros((*batch, _G_TASK.stop, _X_TASK.stop))
        motion, force = task_gain[..., _G_MOTION, :], task_gain[..., _G_FORCE, :]
        motion[..., _X_POSE] = omega
        motion[..., _X_TWIST] = -(adg @ ((force_axes * self._force_axis_damping)[..., :, None] * ad_inv))  # -D_f
        force[..., _X_FORCE] = force_direction + self._kp * (adg @ error_direction[..., None])[..., 0]
        force[..., _X_WRENCH] = -self._kp * projector
        force[..., _X_INTEGRAL] = self._ki * adg
        return {
            "rotation": R,
            "cf_rotation": cf_rotation,
            "cf_z": np.ascontiguousarray(cf_rotation[..., :, 2]),
            "selection": S,
            "force_axes": force_axes,
            "omega": omega,
            "projector": projector,
            "ad": ad,
            "ad_inv": np.ascontiguousarray(ad_inv),
            "adg": adg,
            "adg_inv": np.ascontiguousarray(adg_inv),
            "force_direction": np.ascontiguousarray(force_direction),
            "damping_left": (adg * S[..., None, :]) @ np.swapaxes(ad, -1, -2),
            "damping_right": ad @ (S[..., :, None] * ad_inv),
            "law_rows": np.concatenate(
                (
                    cf_rotation[..., :, 2],
                    force_axes if self._ki > 0.0 else np.zeros_like(force_axes),
                    error_direction,
                    adg_inv.reshape(*batch, 36),
                ),
                axis=-1,
            ),
            "task_gain": task_gain,
        }

    def frame(
        self,
        cf_rotation: ArrayLike,
        selection: ArrayLike,
        cf_origin: ArrayLike | None = None,
        tool_position: ArrayLike | None = None,
    ) -> ControlFrame:
        """Precompute the law's matrices for one CF (``cf_rotation`` (3, 3) world from CF, ``selection`` (6,)).

        ``cf_origin`` and ``tool_position`` (m, world) matter only with ``compliance_center="cf_origin"``.
        """
        offset = None
        if self.compliance_center == "cf_origin":
            if cf_origin is None or tool_position is None:
                raise ValueError("compliance_center='cf_origin' needs cf_origin and tool_position")
            offset = np.asarray(cf_origin, float) - np.asarray(tool_position, float)
        return ControlFrame(**self._frame_fields(cf_rotation, selection, offset))

    def frames(self, cf_rotations: ArrayLike, selection: ArrayLike) -> ControlFrameSeries:
        """Precompute control frames for ``(M, 3, 3)`` CF orientations at once (compliance centre at the tool)."""
        if self.compliance_center != "tool":
            raise ValueError("frame series need compliance_center='tool' (the offset changes every step otherwise)")
        R = np.asarray(cf_rotations, dtype=float)
        if R.ndim != 3 or R.shape[1:] != (3, 3):
            raise ValueError(f"cf_rotations must have shape (M, 3, 3), got {R.shape}")
        return ControlFrameSeries(self._frame_fields(R, selection, None))

    # ------------------------------------------------------------------ the law

    def compute(
        self,
        *,
        frame: ControlFrame,
        jacobian: NDArray[np.float64],
        q: NDArray[np.float64],
        qd: NDArray[np.float64],
        bias_torques: NDArray[np.float64],
        tool_position: ArrayLike,
        tool_quaternion: ArrayLike,
        reference_position: ArrayLike,
        reference_quaternion: ArrayLike,
        reference_twist: NDArray[np.float64],
        wrench: NDArray[np.float64],
        desired_force: float,
        in_contact: bool = True,
        mass_matrix: NDArray[np.float64] | None = None,
        update_null_space: bool = True,
    ) -> ControlOutput:
        """Return the joint torques of one control step (see the module docstring).

        ``jacobian`` (6, 7) of the tool point, world axes; ``q``, ``qd`` (7,) rad, rad/s;
        ``bias_torques`` (7,) gravity + Coriolis/centrifugal torques, N·m; tool and reference
        poses in the world (m, ``[x, y, z, w]``; arrays or sequences of floats);
        ``reference_twist`` (6,) world, m/s, rad/s; ``wrench`` (6,) measured, applied by the tool,
        world, at the tool point, N, N·m; ``desired_force`` N along +CF z (into the surface);
        ``in_contact`` lets the force integral run. The null-space projector (and, with a damping
        ratio, the damping from the apparent inertia) is rebuilt when ``update_null_space`` (else
        the last one is reused: it changes with the posture only, so a caller may refresh it every
        few steps); the dynamic projector and the adaptive damping need ``mass_matrix`` (7, 7)
        then; without it the static projector and the nominal damping are used.
        """
        robot = np.empty(ROBOT_STATE_SIZE)
        robot[ROBOT_Q], robot[ROBOT_QD] = q, qd
        robot[ROBOT_POSITION], robot[ROBOT_QUAT] = tool_position, tool_quaternion
        robot[ROBOT_ROTATION] = 0.0
        robot[ROBOT_JACOBIAN], robot[ROBOT_BIAS] = np.asarray(jacobian, dtype=float).ravel(), bias_torques
        reference = np.empty(REFERENCE_SIZE)
        reference[REFERENCE_POSITION], reference[REFERENCE_QUAT] = reference_position, reference_quaternion
        reference[REFERENCE_TWIST], reference[REFERENCE_FORCE] = reference_twist, desired_force
        return self.step(frame, robot, reference, np.asarray(wrench, dtype=float), in_contact, mass_matrix,
                         update_null_space)  # fmt: skip

    def step(
        self,
        frame: ControlFrame,
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        in_contact: bool = True,
        mass_matrix: NDArray[np.float64] | None = None,
        update_null_space: bool = True,
    ) -> ControlOutput:
        """:meth:`compute` on packed arrays, for a control loop: ``robot`` (:data:`ROBOT_STATE_SIZE`,) in the
        ``ROBOT_*`` layout (a simulated world's arm state as it is), ``reference`` (:data:`REFERENCE_SIZE`,) in the
        ``REFERENCE_*`` layout, ``wrench`` (6,) float64; the rest as :meth:`compute`. The outputs are new arrays."""
        out = np.zeros(LAW_OUTPUT_SIZE)  # a step that must not run leaves it zero
        reason = self.step_into(frame, robot, reference, wrench, in_contact, mass_matrix, update_null_space, out)
        return ControlOutput(out[LAW_TAU], out[_O_MOTION], out[_O_FORCE], out[_O_SATURATED] > 0.0, reason)

    def step_into(
        self,
        frame: ControlFrame,
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        in_contact: bool,
        mass_matrix: NDArray[np.float64] | None,
        update_model: bool,
        out: NDArray[np.float64],
    ) -> str | None:
        """One control step for a 1 kHz loop, on packed arrays without allocations: the torque, F_m and F_f into
        ``out`` (:data:`LAW_OUTPUT_SIZE`, ``LAW_TAU`` first); returns why the loop must stop (a non-finite or
        singular model, a force or torque limit: the torque is zero or clipped then), else None.

        ``update_model``: refresh the null-space model with ``mass_matrix`` (a loop does it every few steps);
        the gain rows follow ``frame`` by themselves. The arrays as :meth:`step`. The same law as :meth:`step`
        (the same floating-point operations: the same torques to the last bit)."""
        if update_model or frame is not self._gain_frame or self._projector is None:
            reason = self.prepare(frame, robot, reference, wrench, mass_matrix, update_model)
            if reason is not None:
                out[LAW_TAU] = 0.0
                return reason
        code = law_step(self._gain, robot, reference, wrench, self._law, in_contact, out)
        return None if code == LAW_OK else self.abort_reason(code, out, robot, reference, wrench, mass_matrix)

    def prepare(
        self,
        frame: ControlFrame,
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
        update_null_space: bool,
    ) -> str | None:
        """The part of a step before the compiled law (:func:`law_step`): rebuild the null-space model when asked
        (or when there is none), the gain rows when the frame or the damping changed. Returns why the step must not
        run (a non-finite or singular model; zero torque then), else None. :meth:`step_into` calls it when needed; a
        loop that runs the law in its own compiled step (:func:`law_step_packed` on :attr:`law_buffer`) calls it on a
        model update and on a new frame (and, like :meth:`step_into`, aborts on its reason); or, on a model update
        that does not rebuild the damping (:meth:`damping_due`), calls :func:`model_update_packed` itself
        (:meth:`model_arguments`), then :meth:`model_updated` and :meth:`use_frame`."""
        if update_null_space or self._projector is None:
            try:
                code = self._update_model(frame, robot, mass_matrix)
            except np.linalg.LinAlgError as exc:
                return self.singular_model_reason(exc)
            if code != LAW_OK:  # non-finite J or M
                self._projector = None
                return self._non_finite_reason(_named_inputs(robot, reference, wrench, mass_matrix))
        self.use_frame(frame)
        return None

    def _update_model(
        self, frame: ControlFrame, robot: NDArray[np.float64], mass_matrix: NDArray[np.float64] | None
    ) -> int:
        """:func:`model_update_packed` on this controller's arrays for the Jacobian in ``robot`` and ``mass_matrix``
        (None: the static projector), then :meth:`model_updated`; returns the kernel's code (nothing taken unless
        ``LAW_OK``). Raises ``numpy.linalg.LinAlgError`` on a singular model."""
        M = NO_MASS_MATRIX if mass_matrix is None else np.ascontiguousarray(mass_matrix, dtype=float)
        code = model_update_packed(self.law_buffer, robot, M, *self.model_arguments())
        if code == LAW_OK:
            self.model_updated(frame, mass_matrix is not None)
        return code

    def model_arguments(self) -> tuple:
        """The arguments of :func:`model_update_packed` after the law buffer, the robot state and the mass matrix: the
        projection (dynamic or not), ``K_n``, ``D_n``, the posture, and the arrays the projector and the inertia are
        written to (this controller's own: a model update is then :meth:`model_updated`)."""
        return self._dynamic_null, self._kn, self._dn, self.posture, self._projector_rows, self._inertia

    def damping_due(self, with_mass_matrix: bool) -> bool:
        """Whether the next model update rebuilds the adaptive damping (a damping ratio, a mass matrix, and no damping
        yet or every :data:`DAMPING_UPDATE_EVERY`-th update): :meth:`model_updated` does it, in Python, not in the
        loop's compiled step."""
        return (
            with_mass_matrix
            and self._adaptive_damping
            and (self.damping_matrix_a is None or (self._model_version + 1) % DAMPING_UPDATE_EVERY == 0)
        )

    def model_updated(self, frame: ControlFrame, with_mass_matrix: bool) -> None:
        """Take the model :func:`model_update_packed` just wrote into :meth:`model_arguments`' arrays, and rebuild the
        damping from its inertia when due (:meth:`damping_due`, the stiffness turned into A by ``frame``). Raises
        ``numpy.linalg.LinAlgError`` on a singular inertia."""
        due = self.damping_due(with_mass_matrix)
        self._model_version += 1
        self._projector = self._projector_rows
        if due:
            stiffness_a = frame.adg @ (self._stiffness[:, None] * frame.ad_inv)
            self.damping_matrix_a = _damping_matrix(stiffness_a, self._inertia, self.gains.damping_ratio)

    def use_frame(self, frame: ControlFrame) -> None:
        """Make the gain rows of ``frame`` with the damping in use (rebuilt only when the frame or the damping
        matrix changed since the last time)."""
        if frame is not self._gain_frame or self._gain_damping is not self.damping_matrix_a:
            self._cache_frame(frame)

    def singular_model_reason(self, error: np.linalg.LinAlgError) -> str:
        """Why a step must not run after ``error`` in a model update (the model is rebuilt on the next step)."""
        self._projector = None
        return f"singular robot model: {error}"

    def abort_reason(
        self,
        code: int,
        out: NDArray[np.float64],
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
    ) -> str:
        """Why :func:`law_step` returned ``code`` (not :data:`LAW_OK`) with output ``out``, in words."""
        if code == _NON_FINITE:
            self._projector = None
            return self._non_finite_reason(_named_inputs(robot, reference, wrench, mass_matrix))
        if code == _TORQUE_LIMIT:
            joint = int(out[_O_JOINT])
            return (
                f"torque limit: joint {joint + 1} saturated at {self.torque_limits[joint]:.0f} N·m "
                f"for {self._law[_L_SATURATED_FOR]:.3f} s"
            )
        force = math.sqrt(float(wrench[:3] @ wrench[:3]))
        return f"force limit: measured {force:.1f} N > max_force_n {self.gains.max_force_n:.1f} N"

    def _cache_frame(self, frame: ControlFrame) -> None:
        """Build the rows of G that give the wrenches (until the frame or the damping matrix changes)."""
        D = self.damping_matrix_a
        if D is None:  # the nominal CF damping, D_m = Adg diag(S d S) Ad^-1, as the product I D_m I
            S = frame.selection
            left, D, right = _EYE6, frame.adg @ ((S * self.damping * S)[:, None] * frame.ad_inv), _EYE6
        else:
            left, right = frame.damping_left, frame.damping_right
        _write_frame(self._gain, self._law, frame.task_gain, left, D, right, frame.law_rows)
        self._gain_frame, self._gain_damping = frame, self.damping_matrix_a

    def null_space_torque(
        self,
        jacobian: NDArray[np.float64],
        q: NDArray[np.float64],
        qd: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
    ) -> NDArray[np.float64]:
        """Return ``N^T τ_0`` with ``τ_0 = K_n (q_0 - q) - D_n q̇`` (see the module docstring); rebuilds N^T."""
        robot = np.zeros(ROBOT_STATE_SIZE)
        robot[ROBOT_JACOBIAN] = np.asarray(jacobian, dtype=float).ravel()
        if self._update_model(self.frame(np.eye(3), [1.0] * 6), robot, mass_matrix) != LAW_OK:
            raise ValueError("non-finite jacobian or mass_matrix")
        tau0 = self._kn * (self.posture - q) - self._dn * qd
        return self._projector_rows @ tau0

    @staticmethod
    def _non_finite_reason(values: dict[str, object]) -> str:
        names = (
            "jacobian",
            "q",
            "qd",
            "bias_torques",
            "tool_position",
            "tool_quaternion",
            "reference_position",
            "reference_quaternion",
            "reference_twist",
            "wrench",
            "desired_force",
            "mass_matrix",
        )
        bad = [
            n
            for n in names
            if values.get(n) is not None and not np.all(np.isfinite(np.asarray(values[n], dtype=float)))
        ]
        what = ", ".join(bad) if bad else "the computed torque"
        return f"non-finite value (NaN or inf) in {what}; zero torque commanded"
