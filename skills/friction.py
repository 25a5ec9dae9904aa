"""The applied force without its friction part: what a contact's force says about the surface normal.

On a surface the applied force is the normal force plus Coulomb friction along the sliding
direction: ``f = N (n + mu t)``, so it leans from the normal ``n`` towards the motion by the
friction angle ``atan(mu)``. Two ways to take the lean out, and why this module uses the second:

- **Remove the force's component along the velocity** (the textbook way) assumes the velocity is
  tangent to the surface. A tool settling onto a surface, or sliding into a crease, also moves
  along the normal; then the removal takes away part of the normal force itself and turns the
  estimate by tens of degrees (the real KU Leuven contours: up to 28° outside the physically
  possible cone of normals during the first 0.1 s).
- **Turn the force back by the friction angle**, in the plane of force and velocity (which holds
  ``n`` whatever the normal speed: both ``f`` and ``v`` lie in the plane of ``n`` and ``t``). The
  friction coefficient is a property of the tool and the surface, so it is measured once, as the
  median ratio of the textbook removal to what it leaves where the tool slides fast
  (``FAST_SLIDING_M_S``: there the normal speed is a negligible part of the velocity), and then
  applied at every sample, settling ones included. The turn fades in with the speed over
  ``FRICTION_SPEED_M_S`` (static friction at rest), and `FrictionFree.weights` says how far each
  sample's direction can be trusted.

All arrays are world frame, SI: ``forces`` (N, 3) N applied by the tool, ``velocities`` (N, 3) m/s
of the tool point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FRICTION_SPEED_M_S = 0.005
"""Sliding speed (m/s) over which friction, and the trust in a friction-free direction, fade in (tanh)."""

FAST_SLIDING_M_S = 0.02
"""Speed (m/s) above which the velocity is taken as the sliding direction to measure the friction coefficient."""

SETTLING_SINE = float(np.sin(np.radians(20.0)))
"""A velocity this far out of the surface (sine of its elevation) is settling: friction is turned back, not removed."""

FRICTION_CONE_MAX = 1.0
"""Largest ratio of the force along the motion to the force across it that counts as friction (mu <= 1: a rubber
pad on a dry part reaches 0.9, where every fast sample leaned past the 0.7 this once was and nothing was measured).

A larger one is a push that moves the tool (a hand in free space, a tool settling along its press)."""


def unit_rows(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the rows of ``vectors`` (N, 3) scaled to unit length; zero rows stay zero."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, vectors / np.maximum(norm, 1e-12), 0.0)


def friction_leans(forces: NDArray[np.float64], velocities: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return per sample the force along the velocity over the force across it (N,): tan of the force's lean to the
    motion, positive TOWARDS it (friction applied by the tool on the surface leans so)."""
    direction = unit_rows(velocities)
    along = np.sum(forces * direction, axis=1, keepdims=True)
    across = np.linalg.norm(forces - along * direction, axis=1)
    return along[:, 0] / np.maximum(across, 1e-12)


def sliding_fast(leans: NDArray[np.float64], speed: NDArray[np.float64]) -> NDArray[np.bool_]:
    """The samples (N,) that slide faster than ``FAST_SLIDING_M_S`` (``speed`` m/s) leaning at most
    ``FRICTION_CONE_MAX`` either way (``leans``, :func:`friction_leans`): where the lean is friction's."""
    return (speed > FAST_SLIDING_M_S) & (np.abs(leans) <= FRICTION_CONE_MAX)


def _removal_ratios(forces: NDArray[np.float64], velocities: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return per sample |force along the velocity| / |force across it| (N,): tan of the force's lean to the motion."""
    return np.abs(friction_leans(forces, velocities))


def friction_coefficient(
    forces: NDArray[np.float64], velocities: NDArray[np.float64], mask: NDArray[np.bool_] | None = None
) -> float:
    """Return the friction coefficient the samples show: the median lean of the force to the motion where fast.

    Over the samples of ``mask`` (default all) that slide faster than ``FAST_SLIDING_M_S`` and lean less than
    ``FRICTION_CONE_MAX`` (more is a push, not friction); 0 when there are none.
    """
    return _median_fast_lean(_removal_ratios(forces, velocities), np.linalg.norm(velocities, axis=1), mask)


def _median_fast_lean(ratios: NDArray[np.float64], speed: NDArray[np.float64], mask: NDArray[np.bool_] | None) -> float:
    """The median of the leans ``ratios`` (N,) where the tool moves faster than ``FAST_SLIDING_M_S`` (``speed`` (N,)
    m/s) within ``mask``, leaning less than ``FRICTION_CONE_MAX``; 0 when there are none."""
    fast = sliding_fast(ratios, speed)
    if mask is not None:
        fast &= mask
    return float(np.median(ratios[fast])) if fast.any() else 0.0


@dataclass(frozen=True)
class FrictionFree:
    """The applied forces without their friction part, and how far each sample's direction can be trusted.

    ``forces`` (N, 3) N; ``weights`` (N,) 0 to 1 (see `friction_free`).
    """

    forces: NDArray[np.float64]
    weights: NDArray[np.float64]

    @property
    def directions(self) -> NDArray[np.float64]:
        """Unit friction-free force directions (N, 3): the surface normal into the surface where trusted."""
        return unit_rows(self.forces)


def blended_friction_free(
    forces: NDArray[np.float64], velocities: NDArray[np.float64], friction: float, normals: NDArray[np.float64]
) -> FrictionFree:
    """Return the applied forces (N, 3) N without their friction part, each sample by the removal that fits its motion.

    Where the tool slides along the surface (``normals`` (N, 3): an estimate of its normal, not the
    per-sample force), everything the force has along the velocity goes: friction and whatever else
    drags along the motion (a hand pushing the arm, whose push follows the whole velocity). Where the
    tool also moves along the normal (settling onto the surface), that removal would take normal force
    away, and the force is turned back by the friction angle instead (`friction_free`). The blend is
    linear in the velocity's elevation from the surface, the sine of its angle up to
    ``SETTLING_SINE`` (all turned back beyond). Weights as `friction_free`.
    """
    turned = friction_free(forces, velocities, friction)
    direction = unit_rows(velocities)
    removed = forces - np.sum(forces * direction, axis=1, keepdims=True) * direction
    elevation = np.abs(np.sum(direction * unit_rows(normals), axis=1, keepdims=True))
    settling = np.clip(elevation / SETTLING_SINE, 0.0, 1.0)
    return FrictionFree(forces=(1.0 - settling) * removed + settling * turned.forces, weights=turned.weights)


def friction_free(
    forces: NDArray[np.float64], velocities: NDArray[np.float64], friction: float | None = None
) -> FrictionFree:
    """Return the applied forces (N, 3) N turned back by the friction angle, with their weights.

    ``friction`` is the coefficient mu (default: `friction_coefficient` of these samples). Each force
    is turned by ``atan(mu) tanh(speed / FRICTION_SPEED_M_S)`` away from the velocity, in their
    plane, and scaled by the cosine (the normal force ``N``). A sample's weight is
    ``tanh(speed / FRICTION_SPEED_M_S)²``, and 0 where the force leans to the motion by more than
    ``FRICTION_CONE_MAX`` (a push that moves the tool: a hand in free space) while moving faster
    than ``FAST_SLIDING_M_S`` (slower, a settling tool leans that much along its press).
    """
    ratios, speed = _removal_ratios(forces, velocities), np.linalg.norm(velocities, axis=1)
    mu = _median_fast_lean(ratios, speed, None) if friction is None else friction
    magnitude = np.linalg.norm(forces, axis=1, keepdims=True)
    along_force = unit_rows(forces)
    # The direction across the force, in the plane of force and velocity, pointing to the motion.
    towards_motion = unit_rows(velocities - np.sum(velocities * along_force, axis=1, keepdims=True) * along_force)
    angle = (np.arctan(mu) * np.tanh(speed / FRICTION_SPEED_M_S))[:, None]
    free = magnitude * np.cos(angle) * unit_rows(np.cos(angle) * along_force - np.sin(angle) * towards_motion)
    pushed = (ratios > FRICTION_CONE_MAX) & (speed > FAST_SLIDING_M_S)
    return FrictionFree(forces=free, weights=np.where(pushed, 0.0, np.tanh(speed / FRICTION_SPEED_M_S) ** 2))
