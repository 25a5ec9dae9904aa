"""The arm's rigid-body model, compiled: forward kinematics, the tool point's Jacobian, gravity/Coriolis torques and the
mass matrix of the PyBullet multibody, without a PyBullet round trip.

Why: at 1 kHz each PyBullet query costs 2-5 µs of call and tuple overhead (``calculateJacobian`` ~4 µs,
``getLinkState`` + ``getMatrixFromQuaternion`` ~3, ``calculateInverseDynamics`` ~2), more than the arithmetic of a
7-joint chain compiled (~1 µs for all of them). The model is read from the loaded multibody itself
(:func:`arm_model_from_pybullet`: ``getJointInfo`` / ``getDynamicsInfo``, i.e. the numbers Bullet integrates with),
and ``tests/test_world.py`` checks it against ``calculateJacobian``, ``calculateInverseDynamics``,
``calculateMassMatrix`` and ``getLinkState`` to round-off.

Frames (as Bullet's multibody): body ``b``'s link frame is its parent's centre-of-mass (COM) frame times the joint's
parent frame (``parentFramePos/Orn``) times the joint rotation about ``jointAxis`` by ``q_b``; its COM frame is the
link frame times the local inertial frame. The base's COM frame is where ``getBasePositionAndOrientation`` puts it.
World axes, SI units; quaternions ``[x, y, z, w]``.

The arm state is one float64 array in the controller's layout (``skills.control.ROBOT_*``, so that the law reads it as
it is): ``q``, ``q̇`` (inputs) and the outputs ``p`` (tool point), ``quat`` (tool orientation), ``R`` (by rows),
``J`` (6 x 7 by rows), ``g + c``.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pybullet
from numpy.typing import NDArray

from sim_worker.bullet_client import BulletClient
from sim_worker.robot_model import N_JOINTS, TOOL_LINK
from skills.control.layouts import (
    ROBOT_BIAS,
    ROBOT_JACOBIAN,
    ROBOT_POSITION,
    ROBOT_Q,
    ROBOT_QD,
    ROBOT_QUAT,
    ROBOT_ROTATION,
    ROBOT_STATE_SIZE,
)

# Rows of the model array (one per body; body 0 is the base, then the links in PyBullet order).
_M_POS = slice(0, 3)  # parent COM frame -> link frame: translation (parent COM axes)
_M_ROT = slice(3, 12)  # ... rotation, 3 x 3 by rows
_M_AXIS = slice(12, 15)  # joint axis in the link frame (zero: fixed joint)
_M_COM_POS = slice(15, 18)  # link frame -> COM frame: translation
_M_COM_ROT = slice(18, 27)  # ... rotation by rows
_M_MASS = 27
_M_INERTIA = slice(28, 31)  # principal moments of inertia in the COM frame, kg m^2
_M_PARENT = 31  # parent body row
_M_WIDTH = 32

_WORK_PER_BODY = 45
_NO_ACCELERATION = np.zeros(N_JOINTS)  # a compile-time constant of the compiled functions
_P = ROBOT_POSITION.start
_QUAT = ROBOT_QUAT.start
_R = ROBOT_ROTATION.start
_J = ROBOT_JACOBIAN.start
_BIAS = ROBOT_BIAS.start


def _rotation_rows(quat: tuple[float, ...]) -> list[float]:
    return list(pybullet.getMatrixFromQuaternion(quat))


def arm_model_from_pybullet(body: int, tool_link: int, gravity: tuple[float, float, float], client: int):
    """The packed model (rows: base, links ``0..tool_link``) of a fixed-base PyBullet multibody whose links up to
    ``tool_link`` form a chain of revolute joints then fixed ones; the tool point is ``tool_link``'s frame origin."""
    rows = []
    base_pos, base_orn = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
    base = np.zeros(_M_WIDTH)
    base[_M_POS] = base_pos  # world -> base COM frame (the base's "parent COM frame" is the world)
    base[_M_ROT] = _rotation_rows(base_orn)
    base[_M_COM_ROT] = np.eye(3).ravel()
    base[_M_PARENT] = -1
    rows.append(base)
    for link in range(tool_link + 1):
        info = pybullet.getJointInfo(body, link, physicsClientId=client)
        dyn = pybullet.getDynamicsInfo(body, link, physicsClientId=client)
        row = np.zeros(_M_WIDTH)
        row[_M_POS] = info[14]
        # parentFrameOrn is reported as Bullet stores it, parent-from-joint inverted (measured, pybullet 3.2.7)
        row[_M_ROT] = np.asarray(_rotation_rows(info[15])).reshape(3, 3).T.ravel()
        if info[2] == pybullet.JOINT_REVOLUTE:
            row[_M_AXIS] = info[13]
        elif info[2] != pybullet.JOINT_FIXED:
            raise ValueError(f"arm model: joint {link} is neither revolute nor fixed")
        row[_M_COM_POS] = dyn[3]
        row[_M_COM_ROT] = _rotation_rows(dyn[4])
        row[_M_MASS] = dyn[0]
        row[_M_INERTIA] = dyn[2]
        row[_M_PARENT] = info[16] + 1
        rows.append(row)
    model = np.array(rows)
    if int(np.count_nonzero(np.abs(model[1:, _M_AXIS]).sum(axis=1))) != N_JOINTS:
        raise ValueError(f"arm model: expected {N_JOINTS} revolute joints")
    gravity_row = np.zeros(_M_WIDTH)
    gravity_row[:3] = gravity
    return np.vstack([model, gravity_row])


@numba.njit(cache=True)
def _cross(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def _frames(model, q, R, o, Rc, c, z):  # pragma: no cover - compiled
    """Fill the world link frames (``R`` (B, 3, 3), origins ``o`` (B, 3)), COM frames (``Rc``, ``c``) and world joint
    axes ``z`` (B, 3; zero for a fixed joint) of every body at joint positions ``q``."""
    n = model.shape[0] - 1
    dof = 0
    A = np.empty((3, 3))
    for b in range(n):
        parent = int(model[b, _M_PARENT])
        for i in range(3):
            for j in range(3):
                if parent >= 0:
                    R[b, i, j] = (
                        Rc[parent, i, 0] * model[b, 3 + j]
                        + Rc[parent, i, 1] * model[b, 6 + j]
                        + Rc[parent, i, 2] * model[b, 9 + j]
                    )
                else:
                    R[b, i, j] = model[b, 3 + 3 * i + j]
            if parent >= 0:
                o[b, i] = c[parent, i] + (
                    Rc[parent, i, 0] * model[b, 0] + Rc[parent, i, 1] * model[b, 1] + Rc[parent, i, 2] * model[b, 2]
                )
            else:
                o[b, i] = model[b, i]
        ax, ay, az = model[b, 12], model[b, 13], model[b, 14]
        if ax != 0.0 or ay != 0.0 or az != 0.0:
            angle = q[dof]
            dof += 1
            s, co = math.sin(angle), math.cos(angle)
            t = 1.0 - co
            A[0, 0], A[0, 1], A[0, 2] = t * ax * ax + co, t * ax * ay - s * az, t * ax * az + s * ay
            A[1, 0], A[1, 1], A[1, 2] = t * ax * ay + s * az, t * ay * ay + co, t * ay * az - s * ax
            A[2, 0], A[2, 1], A[2, 2] = t * ax * az - s * ay, t * ay * az + s * ax, t * az * az + co
            for i in range(3):
                z[b, i] = R[b, i, 0] * ax + R[b, i, 1] * ay + R[b, i, 2] * az
                r0, r1, r2 = R[b, i, 0], R[b, i, 1], R[b, i, 2]
                for j in range(3):
                    R[b, i, j] = r0 * A[0, j] + r1 * A[1, j] + r2 * A[2, j]
        else:
            z[b, 0] = z[b, 1] = z[b, 2] = 0.0
        for i in range(3):
            for j in range(3):
                Rc[b, i, j] = (
                    R[b, i, 0] * model[b, 18 + j] + R[b, i, 1] * model[b, 21 + j] + R[b, i, 2] * model[b, 24 + j]
                )
            c[b, i] = o[b, i] + (R[b, i, 0] * model[b, 15] + R[b, i, 1] * model[b, 16] + R[b, i, 2] * model[b, 17])


@numba.njit(cache=True)
def _rnea(model, Rc, o, c, z, qd, qdd, gravity_on, tau, work):  # pragma: no cover - compiled
    """Joint torques ``tau`` (7,) of inverse dynamics (recursive Newton-Euler, world axes) for q̇, q̈ and gravity
    (``gravity_on`` 0 or 1), with the frames of :func:`_frames`; ``work`` (B, 18) scratch."""
    n = model.shape[0] - 1
    w = work[:, 0:3]
    wd = work[:, 3:6]
    a = work[:, 6:9]  # COM linear acceleration
    f = work[:, 9:12]  # force on the body from its parent (and, summed, its subtree)
    m = work[:, 12:15]  # moment about the link frame origin
    dofs = work[:, 15]
    dof = 0
    for b in range(n):
        parent = int(model[b, _M_PARENT])
        if parent < 0:
            for i in range(3):
                w[b, i] = wd[b, i] = f[b, i] = m[b, i] = 0.0
                a[b, i] = -model[n, i] * gravity_on
            dofs[b] = -1.0
            continue
        r0, r1, r2 = o[b, 0] - c[parent, 0], o[b, 1] - c[parent, 1], o[b, 2] - c[parent, 2]
        wp0, wp1, wp2 = w[parent, 0], w[parent, 1], w[parent, 2]
        t0, t1, t2 = _cross(wd[parent, 0], wd[parent, 1], wd[parent, 2], r0, r1, r2)
        u0, u1, u2 = _cross(wp0, wp1, wp2, r0, r1, r2)
        v0, v1, v2 = _cross(wp0, wp1, wp2, u0, u1, u2)
        ao0, ao1, ao2 = a[parent, 0] + t0 + v0, a[parent, 1] + t1 + v1, a[parent, 2] + t2 + v2
        wb0, wb1, wb2 = wp0, wp1, wp2
        wdb0, wdb1, wdb2 = wd[parent, 0], wd[parent, 1], wd[parent, 2]
        dofs[b] = -1.0
        if z[b, 0] != 0.0 or z[b, 1] != 0.0 or z[b, 2] != 0.0:
            dofs[b] = dof
            s0, s1, s2 = z[b, 0] * qd[dof], z[b, 1] * qd[dof], z[b, 2] * qd[dof]
            wb0, wb1, wb2 = wp0 + s0, wp1 + s1, wp2 + s2
            x0, x1, x2 = _cross(wp0, wp1, wp2, s0, s1, s2)
            wdb0 += x0 + z[b, 0] * qdd[dof]
            wdb1 += x1 + z[b, 1] * qdd[dof]
            wdb2 += x2 + z[b, 2] * qdd[dof]
            dof += 1
        w[b, 0], w[b, 1], w[b, 2] = wb0, wb1, wb2
        wd[b, 0], wd[b, 1], wd[b, 2] = wdb0, wdb1, wdb2
        rc0, rc1, rc2 = c[b, 0] - o[b, 0], c[b, 1] - o[b, 1], c[b, 2] - o[b, 2]
        t0, t1, t2 = _cross(wdb0, wdb1, wdb2, rc0, rc1, rc2)
        u0, u1, u2 = _cross(wb0, wb1, wb2, rc0, rc1, rc2)
        v0, v1, v2 = _cross(wb0, wb1, wb2, u0, u1, u2)
        mass = model[b, _M_MASS]
        a[b, 0], a[b, 1], a[b, 2] = ao0 + t0 + v0, ao1 + t1 + v1, ao2 + t2 + v2
        f0, f1, f2 = mass * a[b, 0], mass * a[b, 1], mass * a[b, 2]
        f[b, 0], f[b, 1], f[b, 2] = f0, f1, f2
        # I_world = Rc diag(I) Rc^T: moments of w and ẇ through the COM frame
        ew0 = Rc[b, 0, 0] * wb0 + Rc[b, 1, 0] * wb1 + Rc[b, 2, 0] * wb2
        ew1 = Rc[b, 0, 1] * wb0 + Rc[b, 1, 1] * wb1 + Rc[b, 2, 1] * wb2
        ew2 = Rc[b, 0, 2] * wb0 + Rc[b, 1, 2] * wb1 + Rc[b, 2, 2] * wb2
        ed0 = Rc[b, 0, 0] * wdb0 + Rc[b, 1, 0] * wdb1 + Rc[b, 2, 0] * wdb2
        ed1 = Rc[b, 0, 1] * wdb0 + Rc[b, 1, 1] * wdb1 + Rc[b, 2, 1] * wdb2
        ed2 = Rc[b, 0, 2] * wdb0 + Rc[b, 1, 2] * wdb1 + Rc[b, 2, 2] * wdb2
        I0, I1, I2 = model[b, 28], model[b, 29], model[b, 30]
        h0 = Rc[b, 0, 0] * I0 * ew0 + Rc[b, 0, 1] * I1 * ew1 + Rc[b, 0, 2] * I2 * ew2
        h1 = Rc[b, 1, 0] * I0 * ew0 + Rc[b, 1, 1] * I1 * ew1 + Rc[b, 1, 2] * I2 * ew2
        h2 = Rc[b, 2, 0] * I0 * ew0 + Rc[b, 2, 1] * I1 * ew1 + Rc[b, 2, 2] * I2 * ew2
        g0 = Rc[b, 0, 0] * I0 * ed0 + Rc[b, 0, 1] * I1 * ed1 + Rc[b, 0, 2] * I2 * ed2
        g1 = Rc[b, 1, 0] * I0 * ed0 + Rc[b, 1, 1] * I1 * ed1 + Rc[b, 1, 2] * I2 * ed2
        g2 = Rc[b, 2, 0] * I0 * ed0 + Rc[b, 2, 1] * I1 * ed1 + Rc[b, 2, 2] * I2 * ed2
        k0, k1, k2 = _cross(wb0, wb1, wb2, h0, h1, h2)
        l0, l1, l2 = _cross(rc0, rc1, rc2, f0, f1, f2)
        m[b, 0], m[b, 1], m[b, 2] = g0 + k0 + l0, g1 + k1 + l1, g2 + k2 + l2
    for b in range(n - 1, 0, -1):
        parent = int(model[b, _M_PARENT])
        if dofs[b] >= 0.0:
            tau[int(dofs[b])] = z[b, 0] * m[b, 0] + z[b, 1] * m[b, 1] + z[b, 2] * m[b, 2]
        if parent > 0:
            d0, d1, d2 = o[b, 0] - o[parent, 0], o[b, 1] - o[parent, 1], o[b, 2] - o[parent, 2]
            x0, x1, x2 = _cross(d0, d1, d2, f[b, 0], f[b, 1], f[b, 2])
            for i in range(3):
                f[parent, i] += f[b, i]
            m[parent, 0] += m[b, 0] + x0
            m[parent, 1] += m[b, 1] + x1
            m[parent, 2] += m[b, 2] + x2


def workspace_size(model: NDArray[np.float64]) -> int:
    """Floats of scratch space :func:`arm_state` needs for ``model`` (frames and the recursion's per-body values)."""
    return (model.shape[0] - 1) * _WORK_PER_BODY


@numba.njit(cache=True)
def _workspace(model, work):  # pragma: no cover - compiled
    """Views of ``work`` (:func:`workspace_size` floats) as the frames and scratch arrays of :func:`_frames` and
    :func:`_rnea` (no allocation: a call at 1 kHz)."""
    n = model.shape[0] - 1
    R = work[0 : 9 * n].reshape((n, 3, 3))
    o = work[9 * n : 12 * n].reshape((n, 3))
    Rc = work[12 * n : 21 * n].reshape((n, 3, 3))
    c = work[21 * n : 24 * n].reshape((n, 3))
    z = work[24 * n : 27 * n].reshape((n, 3))
    scratch = work[27 * n : 45 * n].reshape((n, 18))
    return R, o, Rc, c, z, scratch


@numba.njit(cache=True)
def bullet_quaternion(R):  # pragma: no cover - compiled
    """Quaternion ``[x, y, z, w]`` of a rotation matrix by Bullet's ``btMatrix3x3::getRotation`` (its sign choice, so
    that a pose equals PyBullet's ``getLinkState`` one)."""
    out = np.zeros(4)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    if trace > 0.0:
        s = math.sqrt(trace + 1.0)
        out[3] = s * 0.5
        s = 0.5 / s
        out[0] = (R[2, 1] - R[1, 2]) * s
        out[1] = (R[0, 2] - R[2, 0]) * s
        out[2] = (R[1, 0] - R[0, 1]) * s
    else:
        i = (2 if R[1, 1] < R[2, 2] else 1) if R[0, 0] < R[1, 1] else (2 if R[0, 0] < R[2, 2] else 0)
        j = (i + 1) % 3
        k = (i + 2) % 3
        s = math.sqrt(R[i, i] - R[j, j] - R[k, k] + 1.0)
        out[i] = s * 0.5
        s = 0.5 / s
        out[3] = (R[k, j] - R[j, k]) * s
        out[j] = (R[j, i] + R[i, j]) * s
        out[k] = (R[k, i] + R[i, k]) * s
    return out


@numba.njit(cache=True)
def arm_state(model, state, work, with_bias):  # pragma: no cover - compiled
    """Fill ``state``'s outputs from its ``q``, ``q̇``: tool pose, rotation, Jacobian and (``with_bias``) ``g + c``;
    ``work`` scratch of :func:`workspace_size` floats."""
    R, o, Rc, c, z, work = _workspace(model, work)
    _frames(model, state[0:N_JOINTS], R, o, Rc, c, z)
    tool = model.shape[0] - 2
    p0, p1, p2 = o[tool, 0], o[tool, 1], o[tool, 2]
    state[_P], state[_P + 1], state[_P + 2] = p0, p1, p2
    state[_QUAT : _QUAT + 4] = bullet_quaternion(Rc[tool])
    for i in range(3):
        for j in range(3):
            state[_R + 3 * i + j] = R[tool, i, j]
    dof = 0
    for b in range(tool + 1):
        if z[b, 0] != 0.0 or z[b, 1] != 0.0 or z[b, 2] != 0.0:
            v0, v1, v2 = _cross(z[b, 0], z[b, 1], z[b, 2], p0 - o[b, 0], p1 - o[b, 1], p2 - o[b, 2])
            state[_J + dof], state[_J + 7 + dof], state[_J + 14 + dof] = v0, v1, v2
            state[_J + 21 + dof], state[_J + 28 + dof], state[_J + 35 + dof] = z[b, 0], z[b, 1], z[b, 2]
            dof += 1
    if with_bias:
        _rnea(
            model,
            Rc,
            o,
            c,
            z,
            state[N_JOINTS : 2 * N_JOINTS],
            _NO_ACCELERATION,
            1.0,
            state[_BIAS : _BIAS + N_JOINTS],
            work,
        )


@numba.njit(cache=True)
def arm_state_from_joint_rows(model, joint_rows, state, work, reaction):  # pragma: no cover - compiled
    """:func:`arm_state` with ``g + c`` from joint rows (``sim_worker.bullet_client.JOINT_ROW``: PyBullet's
    ``b3JointSensorState``, written there by its C API): the positions and velocities of the first 7 joints into
    ``state``; an 8th joint's (the tool joint's, wrist sensor) reaction force and moment into ``reaction`` (6,)."""
    for j in range(N_JOINTS):
        state[j] = joint_rows[j, 0]
        state[N_JOINTS + j] = joint_rows[j, 1]
    for j in range(N_JOINTS, joint_rows.shape[0]):
        for i in range(6):
            reaction[i] = joint_rows[j, 2 + i]
    arm_state(model, state, work, True)


ARM_REACTION = slice(ROBOT_STATE_SIZE, ROBOT_STATE_SIZE + 6)
"""Where :attr:`Arm.buffer` keeps the tool joint's reaction, after the arm state (``skills.control.ROBOT_*``); its
scratch space follows."""
_REACTION, _WORK = ARM_REACTION.start, ARM_REACTION.stop


@numba.njit(cache=True)
def read_arm(model, joint_rows, buffer):  # pragma: no cover - compiled
    """:func:`arm_state_from_joint_rows` into an :attr:`Arm.buffer` (the arm
    state, the reaction, the scratch space of its layout): the arm's one compiled call per simulated state, callable
    from another compiled step."""
    arm_state_from_joint_rows(model, joint_rows, buffer[:ROBOT_STATE_SIZE], buffer[_WORK:], buffer[_REACTION:_WORK])


@numba.njit(cache=True)
def arm_mass_matrix(model, q):  # pragma: no cover - compiled
    """Joint-space mass matrix (7, 7) at ``q``: column j is the inverse dynamics of ``q̈ = e_j`` without gravity."""
    R, o, Rc, c, z, work = _workspace(model, np.empty(model.shape[0] * _WORK_PER_BODY))
    _frames(model, q, R, o, Rc, c, z)
    M = np.empty((N_JOINTS, N_JOINTS))
    zero = np.zeros(N_JOINTS)
    e = np.zeros(N_JOINTS)
    column = np.empty(N_JOINTS)
    for j in range(N_JOINTS):
        e[:] = 0.0
        e[j] = 1.0
        _rnea(model, Rc, o, c, z, zero, e, 0.0, column, work)
        M[:, j] = column
    return M


def arm_inverse_dynamics(
    model: NDArray[np.float64], q: NDArray[np.float64], qd: NDArray[np.float64], qdd: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Joint torques (7,) N·m for ``q``, ``q̇``, ``q̈`` with gravity (inverse dynamics, as PyBullet's)."""
    return _inverse_dynamics(model, np.asarray(q, float), np.asarray(qd, float), np.asarray(qdd, float))


@numba.njit(cache=True)
def _inverse_dynamics(model, q, qd, qdd):  # pragma: no cover - compiled
    R, o, Rc, c, z, work = _workspace(model, np.empty(model.shape[0] * _WORK_PER_BODY))
    _frames(model, q, R, o, Rc, c, z)
    tau = np.empty(N_JOINTS)
    _rnea(model, Rc, o, c, z, qd, qdd, 1.0, tau, work)
    return tau


class Arm:
    """The arm of a PyBullet world as a control loop reads it: its state (:attr:`state`, the ``skills.control.ROBOT_*``
    layout) brought up to date once per simulated state by :meth:`read` (one ``getJointStates`` query, then the
    compiled model), the mass matrix on demand, and, with the wrist sensor, the tool joint's reaction read with the
    joints (same query).

    The arrays are overwritten in place by the next read: the views below are the same arrays every step.
    """

    def __init__(self, client: int, body: int, gravity: tuple[float, float, float], read_tool_reaction: bool):
        self._client, self._body = client, body
        # The arm's kinematics and dynamics come from its compiled model, read from this multibody: equal to
        # calculateJacobian / calculateInverseDynamics / calculateMassMatrix / getLinkState to round-off, without
        # their 2-5 µs round trips per step.
        self.model = arm_model_from_pybullet(body, TOOL_LINK, gravity, client)
        self.buffer = np.zeros(_WORK + workspace_size(self.model))
        """The arm state, the tool joint's reaction and the model's scratch space in one array (:data:`ARM_REACTION`),
        so that a compiled step reads the arm with one argument (:func:`read_arm`); the views below are of it."""
        self.state = self.buffer[:ROBOT_STATE_SIZE]
        self.q, self.qd = self.state[ROBOT_Q], self.state[ROBOT_QD]
        self.position, self.quat = self.state[ROBOT_POSITION], self.state[ROBOT_QUAT]
        self.rotation = self.state[ROBOT_ROTATION].reshape(3, 3)
        self.jacobian = self.state[ROBOT_JACOBIAN].reshape(6, N_JOINTS)
        self.bias = self.state[ROBOT_BIAS]
        self._joints = list(range(N_JOINTS))
        self.queried = [*self._joints, TOOL_LINK] if read_tool_reaction else self._joints
        """The joints read each step (``getJointStates``): the arm's, and the tool joint's reaction with the wrist
        sensor (one query)."""
        self.bullet = BulletClient(client, body, self.queried, TOOL_LINK)
        """The arm's PyBullet queries and torque command, made from compiled code (``sim_worker.bullet_client``)."""
        self.tool_reaction = self.buffer[ARM_REACTION]
        """The tool joint's reaction of this state (force on the tool N, moment N·m; tool frame), wrist sensor only."""
        self._mass = np.zeros((N_JOINTS, N_JOINTS))
        self.fresh = self.mass_fresh = False

    def invalidate(self) -> None:
        """The simulated state changed: read again when next asked for."""
        self.fresh = self.mass_fresh = False

    def read(self) -> NDArray[np.float64]:
        """This state's arm state (``skills.control.ROBOT_*`` layout): joints (one PyBullet query), then in one
        compiled call from its joint rows the tool pose, Jacobian, gravity/Coriolis (the compiled model)."""
        if not self.fresh:
            read_arm(self.model, self.bullet.read_joints(), self.buffer)
            self.fresh = True
        return self.state

    def mass_matrix(self) -> NDArray[np.float64]:
        """Joint-space mass matrix (7, 7) of this state, the cached array."""
        if not self.mass_fresh:
            self._mass = arm_mass_matrix(self.model, self.read()[ROBOT_Q])
            self.mass_fresh = True
        return self._mass

    def teleport(self, q: NDArray[np.float64], qd: NDArray[np.float64]) -> None:
        """Reset the joints to ``q`` (rad) with velocities ``qd`` (rad/s)."""
        for j in self._joints:
            pybullet.resetJointState(self._body, j, float(q[j]), float(qd[j]), physicsClientId=self._client)
        self.invalidate()
