"""What the tool's contact gives a control loop, once per simulated state: the contact points' summary (the exact
applied wrench, the contact flag, the force along the true surface normal), and the force/torque sensor's reading
(``sensor``: the exact wrench, or a wrist sensor between flange and tool with its weight compensated), with the
sensor's own offset and a tare removed.

Conventions (docs/CONVENTIONS.md): the contact wrench is the wrench the TOOL APPLIES TO THE ENVIRONMENT, at the tool
point, in the world frame (N, N·m); a tare and the sensor's own offset are in the TOOL frame.

Measured PyBullet 3.2.7 facts this module relies on
    - ``getContactPoints`` with the tool as body A: ``contactNormalOnB`` points from the environment to the tool, and
      ``lateralFriction1/2`` along ``lateralFrictionDir1/2`` are forces ON THE TOOL too; the applied wrench is minus
      their sum.
    - The multibody solver uses fixed friction directions with a circular friction cone: while sliding the friction
      magnitude is exactly μ·N, but its direction can be ~15° off the slip direction (depends on the arm's
      mobility); the normal part is exact (:meth:`ContactSensing.contact_forces` separates them).
    - The fixed tool joint's reaction (``enableJointForceTorqueSensor``) is the force the flange exerts on the tool,
      in the tool frame, and its moment about the tool's centre of mass (``-m g`` along the tool z when it hangs
      pointing down; a lateral force at the tool point gives ``M_c = F × c``).
"""

from __future__ import annotations

import math
from typing import TypedDict

import numba
import numpy as np
import pybullet
from numpy.typing import ArrayLike, NDArray

from execution.robot import CONTACT_DISTANCE_M
from schemas.world import SensorModel, WorldConfig
from sim_worker.arm_model import ARM_REACTION, Arm, read_arm
from sim_worker.bullet_client import (
    CONTACT_DISTANCE,
    CONTACT_FRICTION_1,
    CONTACT_FRICTION_2,
    CONTACT_FRICTION_DIRECTION_1,
    CONTACT_FRICTION_DIRECTION_2,
    CONTACT_NORMAL_FORCE,
    CONTACT_NORMAL_ON_B,
    CONTACT_ON_A,
    CONTACT_ROW,
    contact_bodies,
    read_contact_rows,
    read_joint_rows,
)
from sim_worker.robot_model import TOOL_LINK
from sim_worker.sensor import WrenchSensor, measure_drawn
from skills.control.layouts import ROBOT_POSITION, ROBOT_ROTATION

_ROTATION = ROBOT_ROTATION.start
_POSITION = ROBOT_POSITION.start
# The first columns of the contact rows' vectors as plain ints for the compiled code (it takes no slices as globals):
# the position on the tool (body A), the normal on the environment (B, pointing to the tool), the two friction
# directions (their forces on the tool).
_ON_TOOL, _NORMAL = CONTACT_ON_A.start, CONTACT_NORMAL_ON_B.start
_FRICTION_DIR_1, _FRICTION_DIR_2 = CONTACT_FRICTION_DIRECTION_1.start, CONTACT_FRICTION_DIRECTION_2.start


@numba.njit(cache=True)
def _wrist_wrench(reaction, arm, weight, com_z, out):  # pragma: no cover - compiled
    """:meth:`ContactSensing.wrist_wrench_into` from the tool joint's ``reaction`` (the flange's force on the tool,
    tool frame, and its moment about the tool's centre of mass, which lies on the tool axis at ``com_z``), the tool
    orientation in ``arm`` (``ROBOT_ROTATION``, world from tool by rows) and the tool's ``weight`` (world, N), into
    ``out``."""
    fx, fy, fz, mx, my, mz = reaction[0], reaction[1], reaction[2], reaction[3], reaction[4], reaction[5]
    r = arm[_ROTATION : _ROTATION + 9]
    gx, gy, gz = weight[0], weight[1], weight[2]
    wx = r[0] * gx + r[3] * gy + r[6] * gz  # the weight in the tool frame: R^T m g
    wy = r[1] * gx + r[4] * gy + r[7] * gz
    wz = r[2] * gx + r[5] * gy + r[8] * gz
    fx, fy, fz = fx + wx, fy + wy, fz + wz
    mx, my = mx - com_z * fy, my + com_z * fx  # M_c + c x F, c = (0, 0, com_z)
    out[0] = r[0] * fx + r[1] * fy + r[2] * fz
    out[1] = r[3] * fx + r[4] * fy + r[5] * fz
    out[2] = r[6] * fx + r[7] * fy + r[8] * fz
    out[3] = r[0] * mx + r[1] * my + r[2] * mz
    out[4] = r[3] * mx + r[4] * my + r[5] * mz
    out[5] = r[6] * mx + r[7] * my + r[8] * mz


@numba.njit(cache=True)
def _remove_tare(wrench, arm, tare):  # pragma: no cover - compiled
    """Subtract the sensor's ``tare`` (6,: force, moment, TOOL frame) turned into the world with the tool orientation
    in ``arm`` (``ROBOT_ROTATION``, world from tool by rows) from ``wrench`` (6,, world), in place."""
    r = arm[_ROTATION : _ROTATION + 9]
    for i in range(3):
        wrench[i] -= r[3 * i] * tare[0] + r[3 * i + 1] * tare[1] + r[3 * i + 2] * tare[2]
        wrench[3 + i] -= r[3 * i] * tare[3] + r[3 * i + 1] * tare[4] + r[3 * i + 2] * tare[5]


@numba.njit(cache=True)
def _contact_summary(points, arm, out):  # pragma: no cover - compiled
    """Sum the tool's contact rows ``points`` (m, ``bullet_client.CONTACT_ROW``: PyBullet's contact points with the
    tool as body A, any number) in one pass: into ``out`` (10,) the wrench the tool applies (6,: force N, moment N·m
    about the tool point in ``arm``, world frame) and the force along the true surface normal (N) with that unit
    normal (3,; zeros without normal force); returns whether the tool touches (a point at or below
    :data:`CONTACT_DISTANCE_M`, or carrying force)."""
    px, py, pz = arm[_POSITION], arm[_POSITION + 1], arm[_POSITION + 2]
    fx = fy = fz = mx = my = mz = 0.0
    nx = ny = nz = 0.0
    touching = False
    for c in points:
        fn, f1, f2 = c[CONTACT_NORMAL_FORCE], c[CONTACT_FRICTION_1], c[CONTACT_FRICTION_2]
        n0, n1, n2 = c[_NORMAL], c[_NORMAL + 1], c[_NORMAL + 2]
        d10, d11, d12 = c[_FRICTION_DIR_1], c[_FRICTION_DIR_1 + 1], c[_FRICTION_DIR_1 + 2]
        d20, d21, d22 = c[_FRICTION_DIR_2], c[_FRICTION_DIR_2 + 1], c[_FRICTION_DIR_2 + 2]
        r0, r1, r2 = c[_ON_TOOL], c[_ON_TOOL + 1], c[_ON_TOOL + 2]
        touching = touching or c[CONTACT_DISTANCE] <= CONTACT_DISTANCE_M or fn > 0.0
        ax = -(fn * n0 + f1 * d10 + f2 * d20)
        ay = -(fn * n1 + f1 * d11 + f2 * d21)
        az = -(fn * n2 + f1 * d12 + f2 * d22)
        rx, ry, rz = r0 - px, r1 - py, r2 - pz
        fx += ax
        fy += ay
        fz += az
        mx += ry * az - rz * ay
        my += rz * ax - rx * az
        mz += rx * ay - ry * ax
        nx -= fn * n0
        ny -= fn * n1
        nz -= fn * n2
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    out[0], out[1], out[2], out[3], out[4], out[5] = fx, fy, fz, mx, my, mz
    if norm > 0.0:
        out[6], out[7], out[8], out[9] = norm, nx / norm, ny / norm, nz / norm
    else:
        out[6] = out[7] = out[8] = out[9] = 0.0
    return touching


# Layout of :attr:`ContactSensing.buffer`: the contact summary (the applied wrench, the true normal force and normal),
# the sensor's reading and source, the offsets it removes with their flags, the tool's weight and centre of mass.
CONTACT_APPLIED = slice(0, 6)
CONTACT_NORMAL = slice(6, 10)
CONTACT_MEASURED = slice(10, 16)
_SOURCE = slice(16, 22)
_OFFSETS = slice(22, 34)  # (2, 6) by rows
_REMOVED = slice(34, 36)
_WEIGHT = slice(36, 39)
_COM_Z = 39
_WRIST_SOURCE = 40  # 1: the reading's source is the wrist (the tool joint's reaction), else the exact wrench
_BUFFER_SIZE = 41
_REACTION0 = ARM_REACTION.start  # the offsets as plain ints for the compiled code (it takes no slices as globals)
_MEASURED0, _SOURCE0, _OFFSETS0, _REMOVED0, _WEIGHT0 = (
    CONTACT_MEASURED.start, _SOURCE.start, _OFFSETS.start, _REMOVED.start, _WEIGHT.start
)  # fmt: skip


@numba.njit(cache=True)
def _reading(arm, contact, sensor):  # pragma: no cover - compiled
    """A non-ideal sensor's reading of this state into ``contact``'s ``CONTACT_MEASURED``, in one compiled call: the
    source wrench (the wrist: the tool joint's reaction, weight-compensated, :func:`_wrist_wrench`; else the exact
    wrench of the summary), the sensor model (``sensor.measure_drawn`` on the :attr:`WrenchSensor.buffer` ``sensor``
    after its ``draw()``), then the offsets whose flag is set removed, turned with the tool (:func:`_remove_tare`).
    ``arm`` an :attr:`Arm.buffer` of this state, ``contact`` a :attr:`ContactSensing.buffer` with this state's
    summary."""
    source = contact[0:6]  # CONTACT_APPLIED
    if contact[_WRIST_SOURCE] != 0.0:
        source = contact[_SOURCE0 : _SOURCE0 + 6]
        _wrist_wrench(arm[_REACTION0 : _REACTION0 + 6], arm, contact[_WEIGHT0 : _WEIGHT0 + 3], contact[_COM_Z], source)
    measured = contact[_MEASURED0 : _MEASURED0 + 6]
    measure_drawn(source, measured, sensor)
    for k in range(2):
        if contact[_REMOVED0 + k] != 0.0:
            _remove_tare(measured, arm, contact[_OFFSETS0 + 6 * k : _OFFSETS0 + 6 * k + 6])


@numba.njit(cache=True)
def sense(model, joint_rows, points, arm, contact):  # pragma: no cover - compiled
    """The arm state (:func:`read_arm` into the :attr:`Arm.buffer` ``arm``) and the contact summary
    (:func:`_contact_summary` into the :attr:`ContactSensing.buffer` ``contact``) of this state from its joint rows and
    the tool's contact rows (``sim_worker.bullet_client``); returns whether the tool touches."""
    read_arm(model, joint_rows, arm)
    return _contact_summary(points, arm, contact)


@numba.njit(cache=True)
def sample(model, joint_rows, points, arm, contact, sensor):  # pragma: no cover - compiled
    """:func:`sense`, then the non-ideal sensor's reading (:func:`_reading`; ``sensor`` its
    :attr:`WrenchSensor.buffer`, after its ``draw()``); returns whether the tool touches."""
    touching = sense(model, joint_rows, points, arm, contact)
    _reading(arm, contact, sensor)
    return touching


@numba.njit(cache=True)
def sense_client(ids, model, joint_rows, arm, contact):  # pragma: no cover - compiled
    """:func:`sense` of the state PyBullet's client holds, queried through its C API (``bullet_client.read_joint_rows``
    into ``joint_rows``, ``read_contact_rows``; ``ids`` the :attr:`BulletClient.ids`): a control loop's one compiled
    call per simulated state."""
    read_joint_rows(ids, joint_rows)
    return sense(model, joint_rows, read_contact_rows(ids), arm, contact)


@numba.njit(cache=True)
def sample_client(ids, model, joint_rows, arm, contact, sensor):  # pragma: no cover - compiled
    """:func:`sample` of the state PyBullet's client holds (:func:`sense_client`), after the sensor's ``draw()``."""
    read_joint_rows(ids, joint_rows)
    return sample(model, joint_rows, read_contact_rows(ids), arm, contact, sensor)


class ContactPoint(TypedDict):
    """One contact point of the tool (``ContactSensing.contacts``); world frame."""

    body: str
    """The body the tool touches (its name in the world, else its PyBullet id)."""
    position: NDArray[np.float64]
    """The point on the tool, m."""
    normal_into_environment: NDArray[np.float64]
    """Unit normal from the tool into the environment."""
    normal_force_n: float
    distance_m: float
    """Signed distance, m (negative: penetration)."""


class ContactSensing:
    """The tool's contact and the wrench sensor of one world, read once per simulated state (:meth:`invalidate` after
    each change of it). The arrays are overwritten in place by the next state's reading: :attr:`applied` (6,) and
    :attr:`true_normal` (4,) views of one summary array, :attr:`measured` (6,) the non-ideal sensor's reading."""

    def __init__(self, client: int, robot: int, config: WorldConfig, arm: Arm) -> None:
        self._arm = arm
        self.sensor = WrenchSensor(config.sensor, config.time_step_s)
        self.ideal = self.sensor.ideal
        self._wrist = config.sensor.model is SensorModel.wrist
        buffer = self.buffer = np.zeros(_BUFFER_SIZE)
        """The contact summary, the sensor's reading and source, the offsets it removes and the tool model in one array
        (layout ``CONTACT_*``, ``_OFFSETS`` ...), so that a loop's compiled step reads them with one argument; the
        arrays below are views of it, overwritten in place."""
        buffer[_WRIST_SOURCE] = float(self._wrist)
        if self._wrist:  # the fixed tool joint reports the flange's force on the tool (its origin: the tool point)
            pybullet.enableJointForceTorqueSensor(robot, TOOL_LINK, True, physicsClientId=client)
        self._offsets = buffer[_OFFSETS].reshape(2, 6)
        """What every reading has removed (6, each: force N, moment N·m, TOOL frame): the sensor's own offset, negated
        (adding it), and the tare (:meth:`set_tare`), when their flag in ``_removed`` is set (1.0)."""
        self._offsets[0] = -self.sensor.tool_offset
        self._removed = buffer[_REMOVED]
        self._removed[0] = float(np.any(self.sensor.tool_offset))
        self._tare = self._offsets[1]
        self._state = buffer[: CONTACT_NORMAL.stop]
        """The summary of ``points``, written in one assignment (zeros without points): the two views below."""
        self.applied = buffer[CONTACT_APPLIED]
        """The exact wrench the tool applies this step (see :meth:`SimWorld.true_contact_wrench`)."""
        self.true_normal = buffer[CONTACT_NORMAL]
        """The force along the true surface normal (N) and that normal (3,), see :meth:`SimWorld.true_normal_force`."""
        self.measured = buffer[CONTACT_MEASURED]
        """The sensor's reading this step (a non-ideal sensor's; the ideal one reads :attr:`applied`)."""
        self.reading = self.applied if self.ideal else self.measured
        """The array the controller reads."""
        self.points = np.zeros((0, CONTACT_ROW))
        """This state's contact rows of the tool (``bullet_client.CONTACT_ROW``), after :meth:`summary`."""
        self.touching = False
        tool = config.tool
        # The tool model the weight is compensated with: its centre of mass on the tool axis (tool frame, m), its weight
        # in the world (N).
        buffer[_COM_Z] = -(0.5 * tool.shaft_length_m + tool.radius_m)
        self._tool_weight = buffer[_WEIGHT]
        self._tool_weight[:] = [tool.mass_kg * g for g in config.gravity]
        self.fresh = self.measured_fresh = False

    def invalidate(self) -> None:
        """The simulated state changed: read the contact points and the sensor again when next asked for."""
        self.fresh = self.measured_fresh = False

    def reset(self) -> None:
        """A new run: the sensor starts afresh, no tare."""
        self.sensor.reset()
        self._tare[:] = 0.0
        self._removed[1] = 0.0

    def summary(self) -> None:
        """Read the contact points (one PyBullet query) and sum them in one pass: the exact applied wrench
        (:attr:`applied`), the contact flag, the normal force and its direction (:attr:`true_normal`), kept until the
        next state (nothing to do when this state's are read)."""
        if self.fresh:
            return
        self.points = self._arm.bullet.read_contacts()
        self.touching = _contact_summary(self.points, self._arm.read(), self._state)
        self.fresh = True

    def contacts(self, names: dict[int, str]) -> list[ContactPoint]:
        """The tool's contact points: body name (``names``: by body id), position on the tool (m, world), the normal
        into the environment, normal force (N), distance (m)."""
        self.summary()
        return [
            {
                "body": names.get(int(body), str(body)),
                "position": c[CONTACT_ON_A].copy(),
                "normal_into_environment": -c[CONTACT_NORMAL_ON_B],
                "normal_force_n": float(c[CONTACT_NORMAL_FORCE]),
                "distance_m": float(c[CONTACT_DISTANCE]),
            }
            for c, body in zip(self.points, contact_bodies(self.points), strict=True)
        ]

    def contact_forces(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The applied contact force's normal part and friction part (3,) each, N, world frame."""
        self.summary()
        c = self.points
        normal = -(c[:, [CONTACT_NORMAL_FORCE]] * c[:, CONTACT_NORMAL_ON_B]).sum(axis=0)
        friction = -(
            c[:, [CONTACT_FRICTION_1]] * c[:, CONTACT_FRICTION_DIRECTION_1]
            + c[:, [CONTACT_FRICTION_2]] * c[:, CONTACT_FRICTION_DIRECTION_2]
        ).sum(axis=0)
        return normal, friction

    def wrist_wrench_into(self, out: NDArray[np.float64]) -> NDArray[np.float64]:
        """The wrist sensor's noise-free, weight-compensated wrench (6,) in the applied convention (at the tool point,
        world frame), written into ``out``; returns it.

        Tool equilibrium gives the applied wrench at the tool point from the flange's force ``F`` on the tool and its
        moment ``M_c`` about the tool's centre of mass ``c``: ``F + m g`` and ``M_c + c × (F + m g)``, minus the tool's
        inertial terms, which a real integration does not know either."""
        arm = self._arm.read()  # reads the tool joint's reaction too
        _wrist_wrench(self._arm.tool_reaction, arm, self._tool_weight, self.buffer[_COM_Z], out)
        return out

    def reading_now(self) -> NDArray[np.float64]:
        """This state's sensor reading (the array itself): the sensor samples once per simulated state."""
        if self.ideal:
            self.summary()
            return self.applied
        if not self.measured_fresh:
            self._arm.read()
            if not self._wrist:  # the exact wrench is the source
                self.summary()
            self.sensor.draw()
            _reading(self._arm.buffer, self.buffer, self.sensor.buffer)  # one compiled call to the reading
            self.measured_fresh = True
        return self.measured

    @property
    def tare(self) -> NDArray[np.float64]:
        """The offset the last :meth:`set_tare` removes from every reading (6,), tool frame, N and N·m (a copy)."""
        return self._tare.copy()

    def set_tare(self, offset: ArrayLike) -> None:
        """Remove ``offset`` (6,: force N, moment N·m, TOOL frame) from every reading from this state's on (see
        :meth:`SimWorld.tare_sensor`). ValueError for the ideal sensor or a malformed offset."""
        if self.ideal:
            raise ValueError("the ideal sensor reads the exact contact wrench: there is nothing to tare")
        tare = np.asarray(offset, dtype=float)
        if tare.shape != (6,) or not np.all(np.isfinite(tare)):
            raise ValueError(f"tare: expected 6 finite numbers (force N, moment N·m, tool frame), got {offset!r}")
        if self.measured_fresh:  # this state's reading was sampled before the tare: it is the first tared one
            _remove_tare(self.measured, self._arm.read(), tare - self._tare)
        self._tare[:] = tare
        self._removed[1] = float(np.any(tare != 0.0))
