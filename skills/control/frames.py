"""The compliant frame as the control law uses it (``skills.control``'s docstring, "Frames"): :class:`ControlFrame`
(one instant's matrices, built by ``HybridController.frame``), :class:`ControlFrameSeries` (a contour's, built at
once), both from :func:`control_frame_fields` with the controller's :class:`FrameGains`, and the ``hybrid_world_z``
baseline's frame (:func:`world_z_down_rotation`). World axes; rotations world from
frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.execution import ControllerKind
from skills.control.layouts import G_FORCE, G_MOTION, G_TASK, X_FORCE, X_INTEGRAL, X_POSE, X_TASK, X_TWIST, X_WRENCH
from skills.frames import (
    adjoint_from_transform,
    force_projector_in_frame,
    stiffness_in_frame,
    transform_inverse,
    wrench_adjoint_from_transform,
)


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


class FrameGains(NamedTuple):
    """What a control frame's matrices take from the controller: its ``kind`` (our law or a baseline), the CF
    ``stiffness`` diagonal (6,) N/m and N·m/rad and the nominal CF ``damping`` diagonal (6,) N·s/m and N·m·s/rad that
    matches it (the gains'), the ``force_axis_damping`` (6,) N·s/m and N·m·s/rad on the force axes, and the force
    loop's ``kp`` and ``ki`` (zero for the impedance baselines)."""

    kind: ControllerKind
    stiffness: NDArray[np.float64]
    damping: NDArray[np.float64]
    force_axis_damping: NDArray[np.float64]
    kp: float
    ki: float


def control_rotation_and_selection(
    kind: ControllerKind, cf_rotation: NDArray[np.float64], selection: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The CONTROL frame's rotation and selection diagonal for a CF's (``kind``'s: the impedance baseline controls
    motion on every axis, ``hybrid_world_z`` presses along -z_world where the CF has a force axis)."""
    if kind.is_impedance:
        return cf_rotation, np.ones_like(selection)
    if kind is ControllerKind.hybrid_world_z and np.any(selection < 1.0):
        return world_z_down_rotation(cf_rotation), selection
    return cf_rotation, selection


def control_frame_fields(
    gains: FrameGains,
    cf_rotation: ArrayLike,
    selection: ArrayLike,
    offset: ArrayLike | None,
    scheduled: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> dict[str, NDArray[np.float64]]:
    """The fields of :class:`ControlFrame` (or, for ``(M, 3, 3)`` rotations, of a :class:`ControlFrameSeries`) for
    the CF ``cf_rotation`` (world from CF) with ``selection`` (6,) under ``gains``; the compliance centre at the tool
    (``offset`` None) or ``offset`` (3,) m from it (world); ``scheduled``: a gain schedule's CF stiffness and the
    nominal damping that matches it, (..., 6) each (None: the gains' own)."""
    cf_rotation = np.asarray(cf_rotation, dtype=float)
    batch = cf_rotation.shape[:-2]
    stiffness, damping = (gains.stiffness, gains.damping) if scheduled is None else scheduled
    sel_in = np.broadcast_to(np.asarray(selection, dtype=float), (*batch, 6))
    R, S = control_rotation_and_selection(gains.kind, cf_rotation, sel_in)
    S = np.ascontiguousarray(S)
    if offset is None:
        p = np.zeros((*batch, 3))
        ad = blockdiag_rotation(R)
        ad_inv = np.swapaxes(ad, -1, -2)
        adg, adg_inv = ad, ad_inv
    else:
        p = np.broadcast_to(np.asarray(offset, float), (*batch, 3))
        ad = adjoint_from_transform(R, p)
        ad_inv = adjoint_from_transform(*transform_inverse(R, p))
        adg = wrench_adjoint_from_transform(R, p)
        adg_inv = wrench_adjoint_from_transform(*transform_inverse(R, p))
    force_axes = 1.0 - S
    force_direction = adg[..., :, 2] * force_axes[..., 2:3] if not gains.kind.is_impedance else np.zeros((*batch, 6))
    omega = stiffness_in_frame(R, p, stiffness, S)
    projector = force_projector_in_frame(R, p, S)
    error_direction = force_axes * (adg_inv @ force_direction[..., None])[..., 0]  # S~ Adg^-1 F_d,1
    task_gain = np.zeros((*batch, G_TASK.stop, X_TASK.stop))
    motion, force = task_gain[..., G_MOTION, :], task_gain[..., G_FORCE, :]
    motion[..., X_POSE] = omega
    motion[..., X_TWIST] = -(adg @ ((force_axes * gains.force_axis_damping)[..., :, None] * ad_inv))  # -D_f
    force[..., X_FORCE] = force_direction + gains.kp * (adg @ error_direction[..., None])[..., 0]
    force[..., X_WRENCH] = -gains.kp * projector
    force[..., X_INTEGRAL] = gains.ki * adg
    return {
        "rotation": R,
        "cf_rotation": cf_rotation,
        "cf_z": np.ascontiguousarray(cf_rotation[..., :, 2]),
        "selection": S,
        "force_axes": force_axes,
        "omega": omega,
        "projector": projector,
        "ad": ad,
        "ad_inv": np.ascontiguousarray(ad_inv),
        "adg": adg,
        "adg_inv": np.ascontiguousarray(adg_inv),
        "force_direction": np.ascontiguousarray(force_direction),
        "damping_left": (adg * S[..., None, :]) @ np.swapaxes(ad, -1, -2),
        "damping_right": ad @ (S[..., :, None] * ad_inv),
        "law_rows": np.concatenate(
            (
                cf_rotation[..., :, 2],
                force_axes if gains.ki > 0.0 else np.zeros_like(force_axes),
                error_direction,
                adg_inv.reshape(*batch, 36),
            ),
            axis=-1,
        ),
        "task_gain": task_gain,
        "stiffness": np.broadcast_to(stiffness, (*batch, 6)),
        "damping": np.broadcast_to(damping, (*batch, 6)),
    }
