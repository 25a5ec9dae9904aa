"""The robot an execution drives, as an interface: what a physics engine (PyBullet's ``sim_worker.world.SimWorld``
today, a second engine or a real cell later) offers the control loop and the phase sequencing.

Units SI, world frame, quaternions ``[x, y, z, w]`` (docs/CONVENTIONS.md). :class:`Robot` is what every robot has:
its joint state, the state the control law reads (``skills.control.layouts.ROBOT_*``), its dynamics, the torque
command and the clock (one :attr:`Robot.time_step_s` per :meth:`Robot.step`), the wrist sensor's reading and its
tare. :class:`SimulatedRobot` adds what only a simulator knows, for scoring: the true contact wrench and the true
normal force. The 1 kHz loop of an engine may step it through its own compiled kernel (``SimWorld.loop_handles``:
PyBullet's C API from compiled code) as long as it leaves the robot as :meth:`Robot.step` would
(``tests/test_loop_identity.py``).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

CONTACT_DISTANCE_M = 0.0
"""A contact point counts as contact when its distance (beyond an engine's margin) is at or below this (m) or it
carries force: the one definition of "in contact" every engine's truth (:meth:`SimulatedRobot.true_normal_force`)
uses."""


@runtime_checkable
class Robot(Protocol):
    """A torque-controlled 7-joint arm with a wrist force/torque sensor, stepped at a fixed time step."""

    torque_limits: NDArray[np.float64]
    """The joint torque limits (7,) N·m a torque command is clipped to."""
    joint_lower: NDArray[np.float64]
    """The joint position limits (7,) rad; a torque-controlled joint is not stopped at them: the loop checks."""
    joint_upper: NDArray[np.float64]
    step_count: int
    """The steps taken since the last :meth:`reset`."""

    @property
    def time_step_s(self) -> float:
        """The clock: the time one :meth:`step` advances, s."""
        ...

    def reset(self, q: ArrayLike | None = None) -> None:
        """Put the joints at ``q`` (7,) rad at rest, the sensor afresh and untared; the step count to zero."""
        ...

    def joint_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Joint positions (rad) and velocities (rad/s), (7,) each."""
        ...

    def robot_state(self) -> NDArray[np.float64]:
        """This step's state as the control law reads it (``skills.control.layouts.ROBOT_*``: joints, tool pose,
        Jacobian of the tool point in world axes, gravity and Coriolis torques)."""
        ...

    def mass_matrix(self) -> NDArray[np.float64]:
        """The joint-space mass matrix (7, 7), kg·m²."""
        ...

    def tool_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The tool point's position (3,) m and orientation (4,), world."""
        ...

    def inverse_kinematics(self, position: ArrayLike, quat: ArrayLike) -> NDArray[np.float64]:
        """Joint positions (7,) rad putting the tool point at ``position`` with orientation ``quat``; ValueError when
        the pose cannot be reached."""
        ...

    def contact_wrench(self) -> NDArray[np.float64]:
        """The wrist sensor's reading of this step: the wrench (6,) N, N·m the tool applies, at the tool point, world
        axes, tared."""
        ...

    @property
    def sensor_ideal(self) -> bool:
        """Whether the sensor reads the exact wrench (no offset, noise, delay or filter: nothing to tare)."""
        ...

    @property
    def sensor_tare(self) -> NDArray[np.float64]:
        """The offset (6,) subtracted from the sensor's readings, in the tool frame, N, N·m."""
        ...

    def tare_sensor(self, offset: ArrayLike) -> None:
        """Subtract ``offset`` (6,) tool frame, N, N·m, from the sensor's readings from now on."""
        ...

    def step(self, torque: ArrayLike) -> None:
        """Command the joint torques (7,) N·m, clipped to :attr:`torque_limits`, for one time step, and advance."""
        ...

    def close(self) -> None:
        """Release the robot (a simulator's world, a cell's connection)."""
        ...


@runtime_checkable
class SimulatedRobot(Robot, Protocol):
    """A simulated :class:`Robot`: its contact is known exactly, for scoring an execution."""

    def true_contact_wrench(self) -> NDArray[np.float64]:
        """The exact wrench (6,) the tool applies to the environment at the tool point, world axes, N, N·m."""
        ...

    def true_normal_force(self) -> tuple[float, tuple[float, float, float]]:
        """The exact force (N) the tool presses with along the true surface normal, and that normal (unit, into the
        surface, world; zeros without contact)."""
        ...
