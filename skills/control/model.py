"""The robot model the control law is rebuilt from every few control steps (``skills.control``'s docstring, "Cost"):
:class:`NullSpaceModel`, the null-space projector of the last model update and, with a damping ratio, the adaptive
damping from the apparent inertia; the update itself is the compiled :func:`skills.control.law.model_update_packed`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.execution import ControllerGains, NullSpaceProjection
from skills.control.frames import ControlFrame
from skills.control.law import NO_MASS_MATRIX, damping_matrix, model_update_packed
from skills.control.layouts import LAW_OK

DAMPING_UPDATE_EVERY = 5
"""The adaptive damping matrix is rebuilt on every this-many-th model update (it costs ~2x the projector)."""


class NullSpaceModel:
    """A controller's robot model (``HybridController.model``): the null-space target ``posture`` (7,) rad with its
    ``gains`` (``K_n``, ``D_n``, the projection), the projector N^T and the apparent inertia Λ of the last model
    update, and the adaptive damping matrix in A rebuilt from Λ and the CF stiffness of the frame it was updated in
    (``ControlFrame.stiffness``, N/m, N·m/rad: the gains', or a gain schedule's)."""

    def __init__(self, gains: ControllerGains, posture: ArrayLike | None) -> None:
        self.gains = gains
        self.adaptive_damping = (
            gains.translational_damping_ns_per_m is None and gains.rotational_damping_nms_per_rad is None
        )
        self.dynamic = gains.null_space is NullSpaceProjection.dynamic
        self.kn = gains.nullspace_stiffness_nm_per_rad
        self.dn = gains.nullspace_damping_nms_per_rad
        self.posture = np.zeros(7) if posture is None else np.asarray(posture, dtype=float).copy()
        self.damping_matrix_a: NDArray[np.float64] | None = None
        """The adaptive damping matrix in A (6, 6), or None while the diagonal CF damping applies."""
        self.projector: NDArray[np.float64] | None = None
        """N^T (7, 7) of the last model update (:attr:`projector_rows`), or None while there is none."""
        self.projector_rows = np.zeros((7, 7))
        self.inertia = np.zeros((6, 6))
        """Λ of the last model update, symmetrized: what the adaptive damping is rebuilt from."""
        self.version = 0

    def update(
        self,
        frame: ControlFrame,
        law_buffer: NDArray[np.float64],
        robot: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
        model_update: Callable[..., int] = model_update_packed,
    ) -> int:
        """``model_update`` (:func:`model_update_packed`) on the law's ``law_buffer`` for the Jacobian in ``robot`` and
        ``mass_matrix`` (None: the static projector), then :meth:`updated`; returns the kernel's code (nothing taken
        unless ``LAW_OK``). Raises ``numpy.linalg.LinAlgError`` on a singular model."""
        M = NO_MASS_MATRIX if mass_matrix is None else np.ascontiguousarray(mass_matrix, dtype=float)
        code = model_update(law_buffer, robot, M, *self.arguments())
        if code == LAW_OK:
            self.updated(frame, mass_matrix is not None)
        return code

    def arguments(self) -> tuple:
        """The arguments of :func:`model_update_packed` after the law buffer, the robot state and the mass matrix: the
        projection (dynamic or not), ``K_n``, ``D_n``, the posture, and the arrays the projector and the inertia are
        written to (this model's own: a model update is then :meth:`updated`)."""
        return self.dynamic, self.kn, self.dn, self.posture, self.projector_rows, self.inertia

    def damping_due(self, with_mass_matrix: bool) -> bool:
        """Whether the next model update rebuilds the adaptive damping (a damping ratio, a mass matrix, and no damping
        yet or every :data:`DAMPING_UPDATE_EVERY`-th update): :meth:`updated` does it, in Python, not in the loop's
        compiled step."""
        return (
            with_mass_matrix
            and self.adaptive_damping
            and (self.damping_matrix_a is None or (self.version + 1) % DAMPING_UPDATE_EVERY == 0)
        )

    def updated(self, frame: ControlFrame, with_mass_matrix: bool) -> None:
        """Take the model :func:`model_update_packed` just wrote into :meth:`arguments`' arrays, and rebuild the
        damping from its inertia when due (:meth:`damping_due`, the stiffness turned into A by ``frame``). Raises
        ``numpy.linalg.LinAlgError`` on a singular inertia."""
        due = self.damping_due(with_mass_matrix)
        self.version += 1
        self.projector = self.projector_rows
        if due:
            stiffness_a = frame.adg @ (frame.stiffness[:, None] * frame.ad_inv)
            self.damping_matrix_a = damping_matrix(stiffness_a, self.inertia, self.gains.damping_ratio)
