"""Compliant frame (CF) extraction (paper 4.1-4.2). The CF z axis points along the force the tool applies.

- slide: one CF per contact segment from a plane fitted to the positions (SVD); z = plane
  normal signed along the applied force; x = dominant motion direction in the plane.
- contour: one CF per sample; z = the normalized, smoothed applied force with its friction
  part (the component along the motion) removed, i.e. the surface normal; x, y from the
  Möller-Hughes minimal rotation that takes the segment's mean direction to z, applied to a
  reference frame, so the frames are unique and vary continuously.

Inputs are world-frame arrays (positions m, forces N applied by the tool); rotations are
world-from-CF matrices whose columns are the CF axes in world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from schemas.skill import Segment
from skills.frames import rotation_from_vectors
from skills.quaternions import matrix_from_quaternion, quaternions_sign_continuous, quaternions_slerp

PLANE_CONDITION_RATIO = 3.0
"""A plane fit is trusted when the 2nd singular value exceeds the 3rd by this factor (else the path is a line)."""

FRICTION_SPEED_M_S = 0.005
"""Speed (m/s) over which the removal of friction (the force along the motion) fades in (tanh)."""

CONTOUR_FORCE_SMOOTHING_S = 0.1
"""Standard deviation of the zero-phase Gaussian smoothing of the force for contour frames, s.

It removes sensor noise and the 4-12 Hz jitter hand tremor puts into the friction direction
(attenuated to < 1 % at 5 Hz) while following turns of the surface normal slower than ~1 Hz.
"""


@dataclass(frozen=True)
class PlaneFit:
    """A slide CF: ``rotation`` (3, 3) world-from-CF, ``origin`` (3,) m on the plane, RMS residual (m)."""

    rotation: NDArray[np.float64]
    origin: NDArray[np.float64]
    residual_rms_m: float
    well_conditioned: bool


def frame_from_z_and_x(z: NDArray[np.float64], x_hint: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the world-from-frame rotation with z axis ``z`` and x axis ``x_hint`` made orthogonal to z.

    Falls back to the Möller-Hughes rotation of world z onto ``z`` when ``x_hint`` is (nearly)
    parallel to ``z``.
    """
    z = z / np.linalg.norm(z)
    x = x_hint - np.dot(x_hint, z) * z
    if np.linalg.norm(x) < 1e-6:
        return rotation_from_vectors(np.array([0.0, 0.0, 1.0]), z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def slide_frame(positions: NDArray[np.float64], forces: NDArray[np.float64]) -> PlaneFit:
    """Return the slide CF of one contact segment: plane fit of ``positions`` (m), z along ``forces`` (N).

    When the path is nearly a straight line the plane is not determined by the positions; the
    normal is then the mean applied force with its component along the line removed (friction
    acts along the motion, the normal force across it).
    """
    centroid = positions.mean(axis=0)
    centred = positions - centroid
    _, singular, vt = np.linalg.svd(centred, full_matrices=False)
    mean_force = forces.mean(axis=0)
    motion = vt[0]
    well_conditioned = bool(singular[1] > PLANE_CONDITION_RATIO * singular[2])
    if well_conditioned:
        normal = vt[2]
    else:
        normal = mean_force - np.dot(mean_force, motion) * motion
        normal /= np.linalg.norm(normal)
    if np.dot(normal, mean_force) < 0:
        normal = -normal
    # x along the dominant motion, pointing the way the tool travelled overall.
    if np.dot(motion, positions[-1] - positions[0]) < 0:
        motion = -motion
    rotation = frame_from_z_and_x(normal, motion)
    residual = centred @ rotation[:, 2]
    return PlaneFit(rotation, centroid, float(np.sqrt(np.mean(residual**2))), well_conditioned)


def friction_free_forces(
    positions: NDArray[np.float64], forces: NDArray[np.float64], rate_hz: float
) -> NDArray[np.float64]:
    """Return the applied forces (N, 3) N with the friction part removed: the component along the motion.

    On a surface the normal is across the motion and friction along it (Coulomb), so what is
    left is the normal force. The removal fades out below ``FRICTION_SPEED_M_S`` (at rest static
    friction can point anywhere in the cone and the motion says nothing about it). Velocities
    from positions (N, 3) m smoothed over 20 ms.
    """
    smoothed = gaussian_filter1d(positions, sigma=max(1.0, 0.02 * rate_hz), axis=0, mode="nearest")
    velocity = np.gradient(smoothed, 1.0 / rate_hz, axis=0)
    speed = np.linalg.norm(velocity, axis=1, keepdims=True)
    v_hat = velocity / np.maximum(speed, 1e-12)
    along = np.sum(forces * v_hat, axis=1, keepdims=True) * np.tanh(speed / FRICTION_SPEED_M_S)
    return forces - along * v_hat


def contour_frames(
    positions: NDArray[np.float64], forces: NDArray[np.float64], rate_hz: float, segment: slice
) -> NDArray[np.float64]:
    """Return per-sample world-from-CF rotations (M, 3, 3) of the contour contact ``segment``.

    ``positions`` (N, 3) m and ``forces`` (N, 3) N are the WHOLE demonstration, so that the
    smoothing sees real data on both sides of the segment (free space contributes ~0 force)
    instead of padding at its edges. z_k is the applied force without its friction part
    (`friction_free_forces`: the surface normal), smoothed with a zero-phase Gaussian of
    ``CONTOUR_FORCE_SMOOTHING_S`` and normalized. The reference frame has z along the segment's
    mean direction and x along the dominant motion; each sample's frame is that reference turned
    by the Möller-Hughes minimal rotation from the mean direction to z_k.
    """
    normal_forces = friction_free_forces(positions, forces, rate_hz)
    smoothed = gaussian_filter1d(normal_forces, sigma=CONTOUR_FORCE_SMOOTHING_S * rate_hz, axis=0, mode="nearest")
    z = smoothed[segment] / np.linalg.norm(smoothed[segment], axis=1, keepdims=True)
    mean_direction = z.mean(axis=0)
    mean_direction /= np.linalg.norm(mean_direction)
    path = positions[segment]
    _, _, vt = np.linalg.svd(path - path.mean(axis=0), full_matrices=False)
    motion = vt[0] if np.dot(vt[0], path[-1] - path[0]) >= 0 else -vt[0]
    reference = frame_from_z_and_x(mean_direction, motion)
    return rotation_from_vectors(mean_direction, z) @ reference


def compliant_frame_rotations(segment: Segment, t_since_start: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return world-from-CF rotation matrices ``(M, 3, 3)`` of a contact segment at times since its start (s).

    One stored frame (slide) is constant; a series (contour) is slerped, clamped at its ends.
    """
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"segment {segment.index} ({segment.kind.value}) has no compliant frame")
    q = np.asarray(frames.orientations, dtype=float)
    if len(frames.t) == 1:
        return np.broadcast_to(matrix_from_quaternion(q[0]), (len(t_since_start), 3, 3)).copy()
    return matrix_from_quaternion(quaternions_slerp(t_since_start, frames.t, quaternions_sign_continuous(q)))
