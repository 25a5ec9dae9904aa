"""``MujocoRobot``: the iiwa of the MuJoCo cell (``sim_mujoco.model``) behind what a 1 kHz control loop needs: joint
state in, joint torques out, one time step, the clock, the wrist sensor's reading, and (a simulator's privilege) the
true contact for scoring: an ``execution.robot.SimulatedRobot``, as PyBullet's ``SimWorld`` is (the law's robot
state, the mass matrix, the tool pose and inverse kinematics from MuJoCo's own kinematics and Jacobians).

Conventions (docs/CONVENTIONS.md): SI units; joints in rad, rad/s, N·m; the world frame; wrenches ``(f, m)`` applied
BY the tool TO the environment, at the tool point, in the world frame; quaternions ``[x, y, z, w]``.

One step (:meth:`MujocoRobot.step`) is MuJoCo's ``mj_step2`` (the commanded torques, the contact forces, the
integration) then ``mj_step1`` of the new state: the joint state, the model queries and the tool pose are the new
state's, the contact and the sensor's reading are the forces that drove the step just taken, as PyBullet's
``getContactPoints`` after ``stepSimulation`` (``sim_worker.world``).
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from execution.kinematics import inverse_kinematics
from schemas.world import SensorModel, WorldConfig
from sim_mujoco.model import TOOL_SITE, MujocoCell, cell_model
from sim_mujoco.sensing import TrueContact, true_contact, wrist_wrench
from sim_worker.robot_model import N_JOINTS, Q_HOME
from sim_worker.sensor import WrenchSensor
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


class MujocoRobot:
    """The simulated iiwa and tool of one ``WorldConfig`` in MuJoCo (:func:`sim_mujoco.model.cell_model`), under
    torque control at ``config.time_step_s`` (1 ms), with the sensor model of ``config.sensor``
    (``sim_worker.sensor.WrenchSensor``: the exact wrench or the wrist, then drift, noise, bias, delay, low-pass; the
    sensor's own offset added, a tare removed, both in the tool frame)."""

    def __init__(self, config: WorldConfig | None = None, q: ArrayLike | None = None) -> None:
        """Build the cell of ``config`` (default: the default world) with the arm at ``q`` (rad, default ``Q_HOME``)
        at rest."""
        self.cell: MujocoCell = cell_model(config)
        self.config = config = self.cell.config
        self.model = self.cell.model
        self.data = mujoco.MjData(self.model)
        self.torque_limits = np.asarray(config.torque_limits_nm, dtype=float)
        self.joint_lower, self.joint_upper = self.cell.joint_lower, self.cell.joint_upper
        """The URDF's joint limits (7,) rad, not enforced (``execution.robot.Robot``)."""
        self.step_count = 0
        self._state = np.zeros(ROBOT_STATE_SIZE)
        self._state_fresh = False
        """The law's robot state (``skills.control.layouts.ROBOT_*``), rebuilt when first asked for after a step."""
        self._site = self.model.site(TOOL_SITE).id
        self._sensor = WrenchSensor(config.sensor, config.time_step_s)
        tool = config.tool
        self._tool_weight = tool.mass_kg * np.asarray(config.gravity, dtype=float)
        self._com_offset = np.array([0.0, 0.0, -(0.5 * tool.shaft_length_m + tool.radius_m)])
        """The tool model the wrist reading is compensated with (as ``sim_worker.contact_sensing``): its weight (world,
        N), its centre of mass from the tool point (tool frame, m)."""
        self._tare = np.zeros(6)
        self._reading = np.zeros(6)
        self._truth = TrueContact(np.zeros(6), 0.0, np.zeros(3), False)
        self.last_step_clipped = False
        self.reset(q)

    # -- lifecycle -----------------------------------------------------------------------------------------------

    def reset(self, q: ArrayLike | None = None) -> None:
        """The arm at ``q`` (rad, default ``Q_HOME``) at rest, no torque commanded, time 0; the sensor starts afresh,
        untared."""
        data = self.data
        mujoco.mj_resetData(self.model, data)
        data.qpos[:N_JOINTS] = np.asarray(Q_HOME if q is None else q, dtype=float)
        mujoco.mj_forward(self.model, data)
        self._sensor.reset()
        self._tare[:] = 0.0
        self.last_step_clipped = False
        self.step_count = 0
        self._state_fresh = False
        self._sample()

    def set_joint_positions(self, q: ArrayLike, qd: ArrayLike | None = None) -> None:
        """Teleport the joints to ``q`` (rad) with velocities ``qd`` (rad/s, default zero): the kinematics and the model
        queries are the new state's; the contact and the sensor are not sampled (inverse kinematics teleports the arm
        hundreds of times; the sensor has a state)."""
        data = self.data
        data.qpos[:N_JOINTS] = np.asarray(q, dtype=float)
        data.qvel[:N_JOINTS] = 0.0 if qd is None else np.asarray(qd, dtype=float)
        mujoco.mj_forward(self.model, data)
        self._state_fresh = False

    def close(self) -> None:
        """Nothing to release (the model and data are Python objects; ``execution.robot.Robot``)."""

    @property
    def time_s(self) -> float:
        """Simulated time since the last :meth:`reset` (s)."""
        return float(self.data.time)

    @property
    def time_step_s(self) -> float:
        """The duration of one :meth:`step` (s)."""
        return float(self.model.opt.timestep)

    # -- the loop's interface ----------------------------------------------------------------------------------

    def joint_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Joint positions (7,) rad and velocities (7,) rad/s, copies."""
        return self.data.qpos[:N_JOINTS].copy(), self.data.qvel[:N_JOINTS].copy()

    def command_torques(self, tau: ArrayLike) -> None:
        """Command joint torques (7,) N·m for the next :meth:`step`, clipped to ``WorldConfig.torque_limits_nm``
        (``last_step_clipped`` says whether they were). ValueError for another shape or a non-finite torque."""
        torques = np.asarray(tau, dtype=float)
        if torques.shape != (N_JOINTS,) or not np.all(np.isfinite(torques)):
            raise ValueError(f"tau: expected {N_JOINTS} finite joint torques (N·m), got {tau!r}")
        limits = self.torque_limits
        self.last_step_clipped = bool((np.abs(torques) > limits).any())
        self.data.qfrc_applied[:N_JOINTS] = np.clip(torques, -limits, limits)

    def step(self, torque: ArrayLike) -> None:
        """Command the joint torques ``torque`` (7,) N·m (:meth:`command_torques`: clipped) and advance one time step
        (``time_step_s``, 1 ms) under them (module docstring)."""
        self.command_torques(torque)
        mujoco.mj_step2(self.model, self.data)
        self._sample()
        mujoco.mj_step1(self.model, self.data)
        self.step_count += 1
        self._state_fresh = False

    def contact_wrench(self) -> NDArray[np.float64]:
        """The force/torque sensor's reading (6,) of the last step: the wrench the tool applies, at the tool point,
        world frame (N, N·m), through the sensor model of ``config.sensor``, tared (a copy)."""
        return self._reading.copy()

    @property
    def sensor_ideal(self) -> bool:
        """Whether the sensor reads the exact wrench (``execution.robot.Robot``)."""
        return self._sensor.ideal

    @property
    def sensor_tare(self) -> NDArray[np.float64]:
        """The offset the last :meth:`tare_sensor` removes from every reading (6,), tool frame, N and N·m (a copy)."""
        return self._tare.copy()

    def true_contact_wrench(self) -> NDArray[np.float64]:
        """The exact wrench (6,) the tool applied in the last step, at the tool point, world frame, N, N·m."""
        return self._truth.wrench.copy()

    def true_normal_force(self) -> tuple[float, tuple[float, float, float]]:
        """The exact force (N) the tool pressed with along the true surface normal in the last step, and that normal
        (unit, into the surface, world; zeros without contact): :func:`sim_mujoco.sensing.true_contact`."""
        nx, ny, nz = self._truth.normal.tolist()
        return self._truth.normal_force_n, (nx, ny, nz)

    def true_contact(self) -> TrueContact:
        """The exact contact of the last step (:class:`~sim_mujoco.sensing.TrueContact`: the applied wrench, the
        force along the true normal and that normal, the contact flag), from MuJoCo's contacts."""
        return self._truth

    def tare_sensor(self, offset: ArrayLike) -> None:
        """Tare the sensor as ``SimWorld.tare_sensor`` does: ``offset`` (6,: force N, moment N·m, TOOL frame) is removed
        from every reading, turned into the world with the tool's orientation at that reading, this step's reading
        included. ValueError for the ideal sensor (it reads the exact wrench) or a malformed offset."""
        if self._sensor.ideal:
            raise ValueError("the ideal sensor reads the exact contact wrench: there is nothing to tare")
        tare = np.asarray(offset, dtype=float)
        if tare.shape != (6,) or not np.all(np.isfinite(tare)):
            raise ValueError(f"tare: expected 6 finite numbers (force N, moment N·m, tool frame), got {offset!r}")
        change = tare - self._tare
        rotation = self._rotation()
        self._reading[:3] -= rotation @ change[:3]
        self._reading[3:] -= rotation @ change[3:]
        self._tare[:] = tare

    # -- model queries (the new state's, after mj_step1) -------------------------------------------------------

    def robot_state(self) -> NDArray[np.float64]:
        """This step's state as the control law reads it (``skills.control.layouts.ROBOT_*``: joints, tool pose,
        Jacobian of the tool point in world axes, gravity and Coriolis torques), the same array every step (read-only
        by contract, as ``SimWorld.robot_state``; rebuilt when first asked for after a step or a teleport)."""
        if not self._state_fresh:
            state, data = self._state, self.data
            rotation = self._rotation()
            state[ROBOT_Q], state[ROBOT_QD] = data.qpos[:N_JOINTS], data.qvel[:N_JOINTS]
            state[ROBOT_POSITION], state[ROBOT_QUAT] = data.site_xpos[self._site], self._quaternion()
            state[ROBOT_ROTATION] = rotation.ravel()
            state[ROBOT_JACOBIAN] = self.jacobian().ravel()
            state[ROBOT_BIAS] = data.qfrc_bias[:N_JOINTS]
            self._state_fresh = True
        return self._state

    def tool_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Tool point position (3,) m and orientation ``[x, y, z, w]`` (4,), world frame."""
        return self.data.site_xpos[self._site].copy(), self._quaternion()

    def tool_rotation(self) -> NDArray[np.float64]:
        """The tool orientation (3, 3), world from tool."""
        return self._rotation()

    def inverse_kinematics(
        self, position: ArrayLike, quat: ArrayLike, q_seed: ArrayLike | None = None, **options: float
    ) -> NDArray[np.float64]:
        """Joint positions (7,) rad putting the tool point at ``position`` with orientation ``quat`` (xyzw), world
        frame: ``execution.kinematics.inverse_kinematics`` (its keyword ``options``) on MuJoCo's kinematics, as
        ``SimWorld.inverse_kinematics`` on PyBullet's. The state is restored; ValueError when not reached."""
        return inverse_kinematics(self, position, quat, q_seed, **options)

    def jacobian(self) -> NDArray[np.float64]:
        """Geometric Jacobian (6, 7) of the tool point, world frame: ``[v; ω] = J qd``."""
        jacobian = np.zeros((6, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jacobian[:3], jacobian[3:], self._site)
        return jacobian[:, :N_JOINTS]

    def gravity_coriolis_torques(self) -> NDArray[np.float64]:
        """Joint torques (7,) N·m that cancel gravity and Coriolis/centrifugal terms (MuJoCo's ``qfrc_bias``)."""
        return self.data.qfrc_bias[:N_JOINTS].copy()

    def mass_matrix(self) -> NDArray[np.float64]:
        """Joint-space mass matrix (7, 7), kg·m²."""
        full = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, self.data, full)
        return full[:N_JOINTS, :N_JOINTS]

    # -- internals ---------------------------------------------------------------------------------------------

    def _rotation(self) -> NDArray[np.float64]:
        """The tool orientation (3, 3), world from tool, of the state the kinematics were last computed for."""
        return self.data.site_xmat[self._site].reshape(3, 3).copy()

    def _quaternion(self) -> NDArray[np.float64]:
        """The tool orientation ``[x, y, z, w]`` (4,), world from tool, of the same state as :meth:`_rotation`:
        MuJoCo's ``mju_mat2Quat`` (scalar-first, reordered here; a tenth of scipy's cost, every step)."""
        wxyz = np.empty(4)
        mujoco.mju_mat2Quat(wxyz, self.data.site_xmat[self._site])
        return wxyz[[1, 2, 3, 0]]

    def _sample(self) -> None:
        """The truth and the sensor's reading of the forces just computed (the sensor samples every step)."""
        data, cell = self.data, self.cell
        rotation = self._rotation()
        self._truth = true_contact(self.model, data, cell.tool_geoms, data.site_xpos[self._site].copy())
        if self.config.sensor.model is SensorModel.wrist:
            sensed = np.concatenate(
                [
                    data.sensordata[cell.force_address : cell.force_address + 3],
                    data.sensordata[cell.torque_address : cell.torque_address + 3],
                ]
            )
            source = wrist_wrench(sensed, rotation, self._tool_weight, self._com_offset)
        else:
            source = self._truth.wrench
        reading = self._sensor.measure(source)
        offset = self._sensor.tool_offset - self._tare  # the sensor's own offset added, the tare removed (tool frame)
        reading[:3] += rotation @ offset[:3]
        reading[3:] += rotation @ offset[3:]
        self._reading = reading
