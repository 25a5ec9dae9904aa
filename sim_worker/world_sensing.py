"""The tool's contact and its wrench sensor as a :class:`sim_worker.world.SimWorld` offers them: the contact points, the
exact wrench and normal force (ground truth), what the sensor reads and its tare, all from the world's
``contact_sensing.ContactSensing`` (conventions: ``sim_worker.world``'s docstring, docs/CONVENTIONS.md)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_worker.contact_sensing import ContactPoint, ContactSensing


class WorldSensing:
    """The contact and sensing queries of a simulated world, a mixin of :class:`sim_worker.world.SimWorld`: it sets
    ``_contact`` (the world's :class:`ContactSensing`) and ``bodies`` (the bodies' ids by name)."""

    _contact: ContactSensing
    bodies: dict[str, int]

    def in_contact(self) -> bool:
        """Whether the tool touches anything (a contact point at zero or negative distance, or carrying force)."""
        self._contact.summary()
        return self._contact.touching

    def contacts(self) -> list[ContactPoint]:
        """The tool's contact points: body name, position on the tool, normal force (N), distance (m)."""
        return self._contact.contacts({v: k for k, v in self.bodies.items()})

    def true_contact_wrench(self) -> NDArray[np.float64]:
        """Exact wrench (6,) the tool applies to the environment, at the tool point, world frame (no sensor model).

        Sum over the tool's contact points of the normal and both friction forces. PyBullet reports, with the tool
        as body A, ``contactNormalOnB`` pointing from the environment (B) to the tool (A) and the friction forces
        along ``lateralFrictionDir1/2`` as forces on the environment's side, so the force the tool applies is
        ``-normalForce * n_B + f1 * d1 + f2 * d2`` (sign verified by tests: pressing a table gives ``fz < 0``,
        sliding drags the table along the tool velocity). Moments about the tool point from the contact positions.
        """
        self._contact.summary()
        return self._contact.applied.copy()

    def true_normal_force(self) -> tuple[float, tuple[float, float, float]]:
        """The exact force (N) the tool presses with along the TRUE surface normal, and that normal (unit, into the
        surface, world frame; zeros without contact).

        The magnitude of the vector sum of the contact points' normal forces, each along its own contact normal (the
        collision geometry's surface normal), so it holds whatever the learned frame or the sensor say; its
        direction is the normal (on one surface its normal; in a corner, e.g. a ball pressing on both planes of a
        crease, the direction the two press along together). Friction is not part of it.
        """
        self._contact.summary()
        force, nx, ny, nz = self._contact.true_normal.tolist()
        return force, (nx, ny, nz)

    def contact_forces(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The tool's applied contact force split into its normal part and its friction part (3,) each, world frame.

        Their sum is ``true_contact_wrench()[:3]``. Note: PyBullet's multibody solver uses fixed friction directions
        with a circular cone, so the friction force has magnitude μ·N while sliding but can point up to ~15° away
        from the slip direction (measured here); the normal part is exact.
        """
        return self._contact.contact_forces()

    def contact_wrench(self) -> NDArray[np.float64]:
        """Wrench (6,) the tool applies to the environment at the tool point, world frame, as the sensor reports it.

        With the default config (ideal sensor) this is ``true_contact_wrench()``; otherwise the sensor model of
        ``sim_worker.sensor`` (a wrist sensor, drift, noise, delay, low-pass), once per step.
        """
        return self._contact.reading_now().copy()

    def wrist_wrench(self) -> NDArray[np.float64]:
        """What a wrist force/torque sensor between flange and tool reports, weight-compensated and turned into the
        convention of :meth:`true_contact_wrench` (applied by the tool, at the tool point, world frame), noise-free
        (``contact_sensing``: the fixed tool joint's reaction, the tool's weight compensated, its inertia not)."""
        return self._contact.wrist_wrench_into(np.empty(6))

    @property
    def sensor_tare(self) -> NDArray[np.float64]:
        """The offset the last :meth:`tare_sensor` removes from every reading (6,), tool frame, N and N·m (a copy)."""
        return self._contact.tare

    def tare_sensor(self, offset: ArrayLike) -> None:
        """Tare the force/torque sensor, as a real driver's bias command does: from the next reading on, ``offset``
        (6,: force N, moment N·m, in the TOOL frame: the sensor turns with the tool) is removed from every reading,
        turned into the world with the tool's orientation at that reading. ``reset()`` clears it.

        An offset that turns with the sensor (its own bias, its drift) is removed in any pose; one that is fixed in
        the world (a misestimated tool weight, ``SensorConfig.bias_n``) only in the orientation of the tare.
        The reading of the current state, which the sensor sampled at the last :meth:`step`, is tared too: the step
        after a tare reads the tared force (a phase starting right after the tare must not see the old offset).
        The ideal sensor reads the exact wrench and is never tared (ValueError)."""
        self._contact.set_tare(offset)
