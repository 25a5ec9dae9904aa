"""The simulated world in PyBullet at 1 kHz, a facade: the robot of ``robot_model`` (iiwa + ball tool) among the static
solids of ``geometry`` (table, ramp, contour objects, work pieces), built by ``world_build``, its arm read through
``arm_model.Arm`` (joint state, then the compiled model), the tool's contact and wrench sensor through
``contact_sensing.ContactSensing``, stepped under torque control.

Conventions (docs/CONVENTIONS.md): SI units, world frame, quaternions ``[x, y, z, w]``, 6-vectors
``[x, y, z, rx, ry, rz]``; the contact wrench is the wrench the TOOL APPLIES TO THE ENVIRONMENT,
at the tool point, in the world frame.

Torque control
    ``step()`` sends ``TORQUE_CONTROL`` before every ``stepSimulation`` (the velocity motors are off and the joint and
    link damping zeroed: ``world_build``), so ``gravity_coriolis_torques()`` alone holds the arm still. Torques are
    clipped to ``WorldConfig.torque_limits_nm`` (the iiwa 14's ``schemas.world.IIWA_TORQUE_LIMITS_NM``: 320, 320,
    176, 176, 110, 40, 40 N·m); ``last_step_clipped`` says whether the last ``step()`` clipped. Joint limits are NOT
    enforced by PyBullet in torque mode (the executor checks them).

Measured PyBullet 3.2.7 facts this module relies on
    - The tool pose, Jacobian, gravity/Coriolis torques and mass matrix come from the arm's compiled model
      (``sim_worker.arm_model``, read from this multibody), equal to ``getLinkState`` (the COM pose, double; its
      link-frame pose is float32), ``calculateJacobian``, ``calculateInverseDynamics`` and ``calculateMassMatrix``
      to round-off (``tests/test_world.py``), without a PyBullet round trip per query.
    - The contact points and the tool joint's reaction: ``sim_worker.contact_sensing``; the contact model:
      ``sim_worker.world_build``.
    - Explicit damping must respect the light wrist: joint 7 + tool have ~1e-3 kg·m², so a Cartesian
      rotational damping of 3 N·m·s/rad is unstable at 1 kHz (D·dt/I > 2); 0.3 N·m·s/rad is fine.

Geometry for ground truth
    ``sim_worker.geometry.WorldGeometry`` (pure numpy) holds the exact shapes the PyBullet bodies are built from.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import pybullet
from numpy.typing import ArrayLike, NDArray

from execution.kinematics import inverse_kinematics
from schemas.world import SensorModel, WorldConfig
from sim_worker.arm_model import Arm
from sim_worker.bullet_client import BulletClient
from sim_worker.contact_sensing import ContactSensing
from sim_worker.geometry import WorldGeometry
from sim_worker.robot_model import N_JOINTS, Q_HOME
from sim_worker.world_build import build_environment, load_robot, work_piece_layers
from sim_worker.world_sensing import WorldSensing


@dataclass
class RobotState:
    """A snapshot of the robot for a controller: joints, tool pose, Jacobian at the tool point, twist, gravity."""

    q: NDArray[np.float64]
    qd: NDArray[np.float64]
    position: NDArray[np.float64]
    quat: NDArray[np.float64]
    rotation: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    twist: NDArray[np.float64]
    gravity_coriolis: NDArray[np.float64]


class Sensing(NamedTuple):
    """One step's measurements for a control loop (:meth:`SimWorld.sense`).

    The world's cached arrays of the current step, NOT copies (a 1 kHz loop cannot afford the copies):
    treat them as read-only; the next ``step()`` overwrites them in place (copy what must outlive the step).
    ``q``, ``qd`` (7,) rad, rad/s;
    ``position`` (3,) and ``quat`` (4,) ``[x, y, z, w]`` the tool pose; ``wrench`` (6,) as
    :meth:`SimWorld.contact_wrench`; ``in_contact`` as :meth:`SimWorld.in_contact`.
    """

    q: NDArray[np.float64]
    qd: NDArray[np.float64]
    position: NDArray[np.float64]
    quat: NDArray[np.float64]
    wrench: NDArray[np.float64]
    in_contact: bool


class Dynamics(NamedTuple):
    """One step's model queries for a control loop (:meth:`SimWorld.dynamics`); cached arrays, read-only as
    :class:`Sensing`: ``jacobian`` (6, 7) of the tool point, ``gravity_coriolis`` (7,) N·m, ``mass_matrix``
    (7, 7) or None when not asked for."""

    jacobian: NDArray[np.float64]
    gravity_coriolis: NDArray[np.float64]
    mass_matrix: NDArray[np.float64] | None


class LoopHandles(NamedTuple):
    """What a 1 kHz control loop calls directly, once per step, instead of :meth:`SimWorld.sense` and
    :meth:`SimWorld.step` (whose caches and Python calls cost more than the step's own PyBullet calls): ``bullet`` the
    arm's PyBullet queries and torque command from compiled code (``sim_worker.bullet_client``); ``model`` the arm's
    compiled model, ``arm`` its :attr:`Arm.buffer`, ``contact`` the :attr:`ContactSensing.buffer`
    (``sim_worker.contact_sensing.sense_client`` and ``sample_client`` bring them up to date), ``ideal`` whether the
    sensor reads the exact wrench (else it samples once per simulated state: ``draw()``, then ``sample_client`` with
    ``sensor``, its :attr:`WrenchSensor.buffer`), ``torque_limits`` (7,) N·m, what :meth:`SimWorld.step` clips to. A
    loop using them calls :meth:`SimWorld.loop_ended` when it stops."""

    bullet: BulletClient
    model: NDArray[np.float64]
    arm: NDArray[np.float64]
    contact: NDArray[np.float64]
    ideal: bool
    draw: Callable[[], None]
    sensor: NDArray[np.float64]
    torque_limits: NDArray[np.float64]


class SimWorld(WorldSensing):
    """One PyBullet DIRECT world (own client): iiwa + tool, table, optional ramp, cylinder, block and work pieces; an
    ``execution.robot.SimulatedRobot``. Its tool's contact and wrench sensor: :class:`WorldSensing`.

    Several worlds can live in one process; call ``close()`` (or use ``with``) to free the client.
    State queries are cached until the next ``step()``/``set_joint_positions()``/``reset()``; the accessors
    return copies, ``sense()`` and ``dynamics()`` (for a control loop) the cached arrays themselves.
    """

    def __init__(self, config: WorldConfig | None = None):
        self.config = c = config or WorldConfig()
        self.geometry = WorldGeometry(c)
        self._cid = cid = pybullet.connect(pybullet.DIRECT)
        pybullet.setGravity(*c.gravity, physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            fixedTimeStep=c.time_step_s, numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=cid
        )
        loaded = load_robot(cid, c, max(work_piece_layers(self.geometry).values(), default=1))
        self.robot, self.joint_lower, self.joint_upper = loaded.body, loaded.joint_lower, loaded.joint_upper
        self.torque_limits = np.asarray(c.torque_limits_nm, dtype=float)
        self._arm = Arm(cid, self.robot, c.gravity, read_tool_reaction=c.sensor.model is SensorModel.wrist)
        self.bodies: dict[str, int] = build_environment(cid, self.geometry)
        self._contact = ContactSensing(cid, self.robot, c, self._arm)
        self.sensor = self._contact.sensor
        arm = self._arm
        self._sensing = tuple(
            Sensing(arm.q, arm.qd, arm.position, arm.quat, self._contact.reading, touching)
            for touching in (False, True)
        )
        """What :meth:`sense` returns, without and with contact: the same arrays every step, overwritten in place."""
        self.last_step_clipped = False
        self.clip_count = 0
        self.step_count = 0
        self._invalidate()
        self.reset()

    # -- lifecycle -----------------------------------------------------------------------------------------------

    @property
    def client_id(self) -> int:
        """The PyBullet physics client id of this world."""
        return self._cid

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self._cid is not None and self._cid >= 0:
            with contextlib.suppress(pybullet.error):
                pybullet.disconnect(physicsClientId=self._cid)
            self._cid = -1

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        # try/except, not contextlib: at interpreter exit a module's globals may already be None (a world still bound
        # to a module global, closed or not, is collected then; "Exception ignored in __del__" would be printed).
        try:
            self.close()
        except Exception:  # nothing to report to from a finalizer
            return

    def _invalidate(self) -> None:
        """The simulated state changed: every per-step quantity is read again when next asked for. The arm and the
        contact keep their own flags because reading contacts or the sensor has a cost (and the sensor a state) a
        kinematic query must not pay (inverse kinematics teleports the arm hundreds of times)."""
        self._arm.fresh = self._arm.mass_fresh = self._contact.fresh = self._contact.measured_fresh = False

    @property
    def time_step_s(self) -> float:
        """The simulated time one :meth:`step` advances, s (``execution.robot.Robot``'s clock)."""
        return self.config.time_step_s

    @property
    def sensor_ideal(self) -> bool:
        """Whether the sensor reads the exact wrench (``execution.robot.Robot``)."""
        return self.sensor.ideal

    def reset(self, q: ArrayLike | None = None) -> None:
        """Set the joints to ``q`` (rad; default ``Q_HOME``: tool pointing down above the table) at rest; the sensor
        starts afresh, untared."""
        self.set_joint_positions(Q_HOME if q is None else q)
        self._contact.reset()
        self.last_step_clipped = False
        self.clip_count = 0
        self.step_count = 0

    def set_joint_positions(self, q: ArrayLike, qd: ArrayLike | None = None) -> None:
        """Teleport the joints to ``q`` (rad) with velocities ``qd`` (rad/s, default zero)."""
        q = np.asarray(q, dtype=float)
        self._arm.teleport(q, np.zeros(N_JOINTS) if qd is None else np.asarray(qd, dtype=float))
        self._invalidate()

    # -- state ---------------------------------------------------------------------------------------------------

    def joint_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Joint positions (rad) and velocities (rad/s), shape (7,) each."""
        self._arm.read()
        return self._arm.q.copy(), self._arm.qd.copy()

    def tool_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool point position (3,) m and tool orientation quaternion ``[x, y, z, w]`` (4,) in world."""
        self._arm.read()
        return self._arm.position.copy(), self._arm.quat.copy()

    def tool_rotation(self) -> NDArray[np.float64]:
        """Tool orientation as a (3, 3) rotation matrix (tool frame into world)."""
        self._arm.read()
        return self._arm.rotation.copy()

    def jacobian(self) -> NDArray[np.float64]:
        """Geometric Jacobian (6, 7) of the tool point in world: ``[v; ω] = J qd``."""
        self._arm.read()
        return self._arm.jacobian.copy()

    def tool_twist(self) -> NDArray[np.float64]:
        """Tool point twist ``[v, ω]`` (6,) in world (m/s, rad/s)."""
        self._arm.read()
        return self._arm.jacobian @ self._arm.qd

    def gravity_coriolis_torques(self) -> NDArray[np.float64]:
        """Joint torques (7,) N·m that cancel gravity and Coriolis/centrifugal terms (inverse dynamics, qdd = 0)."""
        self._arm.read()
        return self._arm.bias.copy()

    def mass_matrix(self) -> NDArray[np.float64]:
        """Joint-space mass matrix (7, 7), kg·m²."""
        return self._arm.mass_matrix().copy()

    def sense(self) -> Sensing:
        """Joint state, tool pose, measured wrench and contact flag of this step in one call, without copies.

        For a control loop: one PyBullet query each (shared with the other accessors' caches), the arrays
        returned as cached (read-only by contract, see :class:`Sensing`): the same arrays every step, and with them
        the arrays of :meth:`robot_state` and the true normal force's, brought up to date in place.
        """
        arm, contact = self._arm, self._contact
        # The freshness flags checked here, not in the calls: at 1 kHz a call that finds its work done costs more
        # than the check.
        if not arm.fresh:
            arm.read()
        if not contact.fresh:
            contact.summary()
        if not contact.measured_fresh and not contact.ideal:
            contact.reading_now()
        return self._sensing[contact.touching]

    def robot_state(self) -> NDArray[np.float64]:
        """This step's arm state as the control law reads it (``skills.control.ROBOT_*`` layout: joints, tool pose,
        Jacobian, gravity/Coriolis torques), the cached array itself: read-only by contract, as :meth:`sense`, and
        the same array every step (a loop may hold it: :meth:`sense` updates it)."""
        return self._arm.read()

    def dynamics(self, with_mass_matrix: bool = False) -> Dynamics:
        """Jacobian, gravity/Coriolis torques and (if asked) the mass matrix of this step, without copies.

        The model queries of a control loop, as :meth:`sense`: cached arrays, read-only by contract.
        """
        arm = self._arm
        arm.read()
        return Dynamics(arm.jacobian, arm.bias, arm.mass_matrix() if with_mass_matrix else None)

    def read_state(self) -> RobotState:
        """Everything a controller reads in one call (one PyBullet query each, shared caches), copies."""
        arm = self._arm
        arm.read()
        return RobotState(
            q=arm.q.copy(),
            qd=arm.qd.copy(),
            position=arm.position.copy(),
            quat=arm.quat.copy(),
            rotation=arm.rotation.copy(),
            jacobian=arm.jacobian.copy(),
            twist=arm.jacobian @ arm.qd,
            gravity_coriolis=arm.bias.copy(),
        )

    # -- stepping ------------------------------------------------------------------------------------------------

    def step(self, torque: ArrayLike) -> None:
        """Apply joint torques (7,) N·m for one time step: clip to the limits, TORQUE_CONTROL, stepSimulation.

        Sets ``last_step_clipped`` (and counts ``clip_count``) when any torque was clipped.
        """
        forces = np.array(torque, dtype=float)  # a copy: clipped in place
        if forces.shape != (N_JOINTS,):
            raise ValueError(f"torque: expected {N_JOINTS} joint torques (N·m), got shape {forces.shape}")
        limits = self.torque_limits
        clipped = bool((np.abs(forces) > limits).any())
        if clipped:
            np.clip(forces, -limits, limits, out=forces)
            self.clip_count += 1
        self.last_step_clipped = clipped
        self._arm.bullet.send_torques_and_step(forces)
        self.step_count += 1
        self._invalidate()
        if not self._contact.ideal:  # the sensor samples every step, read or not (its filter runs on)
            self._contact.reading_now()

    def loop_handles(self) -> LoopHandles:
        """The arrays and ids a control loop's compiled step works on (:class:`LoopHandles`)."""
        arm, contact = self._arm, self._contact
        return LoopHandles(
            arm.bullet, arm.model, arm.buffer, contact.buffer, contact.ideal, contact.sensor.draw,
            contact.sensor.buffer, self.torque_limits,
        )  # fmt: skip

    def loop_ended(self, steps: int, clipped_steps: int, last_clipped: bool) -> None:
        """A loop that stepped this world through its :meth:`loop_handles` stopped: count its ``steps``
        (``step_count``, ``clip_count`` by ``clipped_steps``, ``last_step_clipped``). With the ideal sensor the caches
        are read again when next asked for; a sampling sensor's loop has read and sampled the current state (its
        ``sample_client`` after each step), which must not be sampled twice: only the contact points are read again
        (the same state, the same summary)."""
        self.step_count += steps
        self.clip_count += clipped_steps
        if steps:
            self.last_step_clipped = last_clipped
        contact, arm = self._contact, self._arm
        if contact.ideal:
            self._invalidate()
        else:
            arm.fresh = contact.measured_fresh = True
            contact.fresh = arm.mass_fresh = False

    # -- kinematics ----------------------------------------------------------------------------------------------

    def forward_kinematics(self, q: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool pose (position m, quaternion ``[x, y, z, w]``) at joint positions ``q`` (rad); the simulated state is
        restored afterwards."""
        q_save, qd_save = self.joint_state()
        try:
            self.set_joint_positions(q)
            return self.tool_pose()
        finally:
            self.set_joint_positions(q_save, qd_save)

    def inverse_kinematics(
        self, position: ArrayLike, quat: ArrayLike, q_seed: ArrayLike | None = None, **options: float
    ) -> NDArray[np.float64]:
        """Joint positions (7,) rad putting the tool point at ``position`` with orientation ``quat`` (xyzw), world
        frame: ``execution.kinematics.inverse_kinematics`` (its keyword ``options``) on this world. The simulated
        state is restored; ValueError when the target is not reached within 0.1 mm and 1 mrad."""
        return inverse_kinematics(self, position, quat, q_seed, **options)

    # -- geometry (ground truth) ---------------------------------------------------------------------------------

    def surface_normal_at(self, point: ArrayLike) -> NDArray[np.float64]:
        """Outward unit normal of the nearest surface (table, ramp, cylinder, block) at ``point`` (3,) or (N, 3)."""
        return self.geometry.surface_normal_at(point)

    # -- diagnostics ---------------------------------------------------------------------------------------------

    def measure_costs(self, n: int = 500) -> dict[str, float]:
        """Mean cost (µs) of the per-step calls, measured on this world (it is stepped with gravity torques)."""
        tau = self.gravity_coriolis_torques()
        timings: dict[str, Callable[[], Any]] = {
            "step": lambda: self.step(tau),
            "joint_state": self.joint_state,
            "tool_pose": self.tool_pose,
            "jacobian": self.jacobian,
            "gravity_coriolis_torques": self.gravity_coriolis_torques,
            "mass_matrix": self.mass_matrix,
            "contact_wrench": self.contact_wrench,
            "sense": self.sense,
            "dynamics": self.dynamics,
        }
        result: dict[str, float] = {}
        for name, fn in timings.items():
            total = 0.0
            for _ in range(n):
                if name != "step":
                    self._invalidate()
                t0 = time.perf_counter()
                fn()
                total += time.perf_counter() - t0
            result[name] = 1e6 * total / n
        return result
