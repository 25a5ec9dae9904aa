"""What the tool's contact gives in MuJoCo, computed as ``sim_worker.contact_sensing`` computes it from PyBullet's
contact points: the exact applied wrench, the force along the true surface normal with that normal, the contact flag
(the truth an execution is judged by), and the wrist sensor's source wrench (the flange's force on the tool, its
weight compensated from the tool model).

Conventions (docs/CONVENTIONS.md): the wrench is the one the TOOL APPLIES TO THE ENVIRONMENT, at the tool point, in
the world frame, ``(f, m)`` in N and N·m.

Measured MuJoCo 4.0 facts this module relies on (``tests/test_mujoco.py``)
    - ``mj_contactForce`` gives contact ``i``'s force in its frame (rows of ``contact.frame``: the normal, pointing
      from ``geom1`` to ``geom2``, then the two tangents) as the force ``geom1`` exerts on ``geom2``.
    - The ``force`` and ``torque`` sensors at a site of the tool body give the force and torque (about the site) the
      parent, the flange, exerts on the tool's subtree, in the site frame (hanging at rest: ``m g`` up).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np
from numpy.typing import NDArray

from execution.robot import CONTACT_DISTANCE_M


class TrueContact(NamedTuple):
    """The exact contact of the tool at one step: ``wrench`` (6,) applied by the tool at the tool point, world frame
    (N, N·m); ``normal_force_n`` the magnitude of the vector sum of the contacts' normal forces (N) and ``normal``
    (3,) its unit direction, into the surface (zeros without force); ``in_contact`` whether the tool touches."""

    wrench: NDArray[np.float64]
    normal_force_n: float
    normal: NDArray[np.float64]
    in_contact: bool


def true_contact(
    model: mujoco.MjModel, data: mujoco.MjData, tool_geoms: frozenset[int], tool_point: NDArray[np.float64]
) -> TrueContact:
    """The tool's :class:`TrueContact` from ``data``'s contacts (after a step: the forces that drove it) and
    ``mj_contactForce``, moments about ``tool_point`` (3,) m, world: each contact's applied force is its normal and
    friction force on the environment, summed; the normal force is the sum of the normal parts alone. ``tool_geoms``
    the tool's geom ids. Plain floats: a contact or two a step, where numpy's per-call cost would be most of it."""
    contacts = data.contact
    sides = [
        (i, 1.0 if first in tool_geoms else -1.0)  # the tool as geom1 applies geom1's force on geom2, else minus it
        for i, (first, second) in enumerate(zip(contacts.geom1.tolist(), contacts.geom2.tolist(), strict=True))
        if first in tool_geoms or second in tool_geoms
    ]
    if not sides:
        return TrueContact(np.zeros(6), 0.0, np.zeros(3), False)
    frames, positions = contacts.frame.tolist(), contacts.pos.tolist()
    distances = (contacts.dist - contacts.includemargin).tolist()
    px, py, pz = tool_point.tolist()
    fx = fy = fz = mx = my = mz = nx = ny = nz = 0.0
    touching = False
    local = np.zeros(6)
    for i, sign in sides:
        mujoco.mj_contactForce(model, data, i, local)
        fn, f1, f2 = local[0], local[1], local[2]
        frame = frames[i]  # rows: the normal (geom1 to geom2), tangent 1, tangent 2
        ax = sign * (fn * frame[0] + f1 * frame[3] + f2 * frame[6])
        ay = sign * (fn * frame[1] + f1 * frame[4] + f2 * frame[7])
        az = sign * (fn * frame[2] + f1 * frame[5] + f2 * frame[8])
        rx, ry, rz = positions[i][0] - px, positions[i][1] - py, positions[i][2] - pz
        fx, fy, fz = fx + ax, fy + ay, fz + az
        mx, my, mz = mx + ry * az - rz * ay, my + rz * ax - rx * az, mz + rx * ay - ry * ax
        nx, ny, nz = nx + sign * fn * frame[0], ny + sign * fn * frame[1], nz + sign * fn * frame[2]
        touching = touching or distances[i] <= CONTACT_DISTANCE_M or fn > 0.0
    magnitude = math.sqrt(nx * nx + ny * ny + nz * nz)
    normal = [nx / magnitude, ny / magnitude, nz / magnitude] if magnitude > 0.0 else [0.0, 0.0, 0.0]
    return TrueContact(np.array([fx, fy, fz, mx, my, mz]), magnitude, np.array(normal), touching)


def wrist_wrench(
    sensed: NDArray[np.float64],
    rotation: NDArray[np.float64],
    tool_weight_n: NDArray[np.float64],
    com_offset_m: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The wrench (6,) the tool applies at the tool point, world frame, from the wrist sensor's ``sensed`` (6,: the
    flange's force and torque on the tool, about the tool point, tool frame, N and N·m), the tool orientation
    ``rotation`` (3, 3: world from tool), its weight ``tool_weight_n`` (3,: m g, world, N) and its centre of mass
    relative to the tool point ``com_offset_m`` (3,: tool frame, m). Tool equilibrium without its inertia (which a real
    integration does not compensate either): the flange's force ``F`` on the tool and moment ``M`` about the tool point
    give ``F + m g`` and ``M + c × m g``."""
    force = rotation @ sensed[:3] + tool_weight_n
    moment = rotation @ sensed[3:] + np.cross(rotation @ com_offset_m, tool_weight_n)
    return np.concatenate([force, moment])
