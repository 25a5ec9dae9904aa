"""The compliant frame as the control law uses it (``skills.control``'s docstring, "Frames"): :class:`ControlFrame`
(one instant's matrices, built by ``HybridController.frame``), :class:`ControlFrameSeries` (a contour's, built at
once), and the ``hybrid_world_z`` baseline's frame (:func:`world_z_down_rotation`). World axes; rotations world from
frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray


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


def blockdiag_rotation(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """``blockdiag(R, R)`` (..., 6, 6): the twist and the wrench adjoint of a pure rotation ``R`` (..., 3, 3)."""
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

    ``stiffness`` (6,) the CF stiffness diagonal ``K_c`` the frame was built with (N/m, N·m/rad: the gains', or a
    gain schedule's at this instant, ``skills.gain_schedule``) and ``damping`` (6,) the nominal CF damping diagonal
    that matches it (``damping_diagonal``): the adaptive damping is rebuilt from the frame's stiffness, so a
    scheduled stiffness keeps its damping ratio.
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
    stiffness: NDArray[np.float64]
    damping: NDArray[np.float64]


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
