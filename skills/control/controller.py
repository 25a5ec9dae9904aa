"""The hybrid impedance/force controller (``skills.control``'s docstring): :class:`HybridController` holds the gains,
the force integral, the null-space model and the gain matrix it caches per control frame; :meth:`HybridController.step`
runs one control step; :class:`LawKernel` is how a compiled 1 kHz loop runs the same law, one phase at a time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from schemas.execution import ControllerGains, ControllerKind
from schemas.world import IIWA_TORQUE_LIMITS_NM
from skills.compiled import compiled_entry
from skills.control.frames import ControlFrame, ControlFrameSeries, FrameGains, control_frame_fields
from skills.control.law import (
    NO_MASS_MATRIX,
    damping_diagonal,
    law_step,
    model_update_packed,
    non_finite_reason,
    write_frame,
)
from skills.control.layouts import (
    G_JOINT,
    G_ROWS,
    L_DT,
    L_IMPEDANCE_KZ,
    L_INTEGRAL,
    L_INTEGRAL_BOUND,
    L_LIMITS,
    L_MAX_FORCE_SQ,
    L_SATURATED,
    L_SATURATED_FOR,
    L_SATURATION_ABORT,
    L_SIZE,
    LAW_GAIN_SIZE,
    LAW_NON_FINITE,
    LAW_OK,
    LAW_OUTPUT_SIZE,
    LAW_TAU,
    LAW_TORQUE_LIMIT,
    O_FORCE,
    O_JOINT,
    O_MOTION,
    O_SATURATED,
    REFERENCE_FORCE,
    REFERENCE_POSITION,
    REFERENCE_QUAT,
    REFERENCE_SIZE,
    REFERENCE_TWIST,
    ROBOT_BIAS,
    ROBOT_JACOBIAN,
    ROBOT_POSITION,
    ROBOT_Q,
    ROBOT_QD,
    ROBOT_QUAT,
    ROBOT_ROTATION,
    ROBOT_STATE_SIZE,
    X_BIAS,
    X_SIZE,
)
from skills.control.model import NullSpaceModel

_EYE6 = np.eye(6)
_EYE7 = np.eye(7)


class ControlOutput(NamedTuple):
    """One control step's result.

    ``tau`` (7,) joint torques after limits, N·m (zeros when ``abort_reason`` says non-finite);
    ``wrench_motion`` and ``wrench_force`` (6,) the task-space commands of the motion subspace
    (stiffness and damping) and the force subspace in A (applied by the tool, N, N·m);
    ``saturated``: a joint torque was clipped; ``abort_reason``: why the execution must stop
    now, or None.
    """

    tau: NDArray[np.float64]
    wrench_motion: NDArray[np.float64]
    wrench_force: NDArray[np.float64]
    saturated: bool
    abort_reason: str | None


class HybridController:
    """The hybrid impedance/force controller (see the module docstring for frames and the law).

    ``kind`` picks our law or a baseline; ``gains`` the gains and limits; ``dt`` the control
    period (s); ``torque_limits`` (7,) N·m (default: the iiwa's); ``posture`` (7,) the null-space
    target q_0 (rad; also settable with :meth:`reset`); ``compliance_center`` "tool" (default) or
    "cf_origin". State: the force integral (CF coordinates), the damping diagonal, the
    null-space projector and the saturation timer.
    """

    def __init__(
        self,
        kind: ControllerKind | str = ControllerKind.hybrid_cf,
        gains: ControllerGains | None = None,
        dt: float = 1e-3,
        torque_limits: ArrayLike | None = None,
        posture: ArrayLike | None = None,
        compliance_center: Literal["tool", "cf_origin"] = "tool",
    ) -> None:
        self.kind = ControllerKind(kind)
        self.gains = gains if gains is not None else ControllerGains()
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt}")
        self.dt = float(dt)
        limits = IIWA_TORQUE_LIMITS_NM if torque_limits is None else torque_limits
        self.torque_limits = np.asarray(limits, dtype=float)
        if self.torque_limits.shape != (7,) or np.any(self.torque_limits <= 0):
            raise ValueError(f"torque_limits must be 7 positive values (N·m), got {self.torque_limits}")
        if compliance_center not in ("tool", "cf_origin"):
            raise ValueError(f"compliance_center must be 'tool' or 'cf_origin', got {compliance_center!r}")
        self.compliance_center = compliance_center
        g = self.gains
        self._stiffness = np.concatenate(
            [np.asarray(g.translational_stiffness_n_per_m, float), np.asarray(g.rotational_stiffness_nm_per_rad, float)]
        )
        self.damping = damping_diagonal(g)
        self._force_loop = not self.kind.is_impedance
        self._kp = g.force_kp if self._force_loop else 0.0
        self._ki = g.force_ki if self._force_loop else 0.0
        self._kz = float(self._stiffness[2])
        self._integral_bound = g.force_integral_limit_n / self._ki if self._ki > 0.0 else 0.0
        force_axis_damping = np.concatenate([np.full(3, g.force_axis_damping_ns_per_m), self.damping[3:]])
        self._frame_gains = FrameGains(self.kind, self._stiffness, self.damping, force_axis_damping, self._kp, self._ki)
        self.model = NullSpaceModel(g, posture)
        """The null-space projector and the adaptive damping (``damping_matrix_a``), rebuilt on model updates."""
        self.law_buffer = np.zeros(LAW_GAIN_SIZE + L_SIZE)
        """G by rows (:attr:`_gain`), then the law's state (:attr:`_law`): one array, so that a loop's compiled step
        runs the law (:func:`law_step_packed`) with one argument for both; written in place, never replaced."""
        self._law = self.law_buffer[LAW_GAIN_SIZE:]
        """The compiled step's state and constants (layout ``_L_*``)."""
        law = self._law
        law[L_DT] = self.dt
        law[L_INTEGRAL_BOUND] = self._integral_bound
        law[L_IMPEDANCE_KZ] = 0.0 if self._force_loop else self._kz
        law[L_MAX_FORCE_SQ] = g.max_force_n**2
        law[L_SATURATION_ABORT] = g.torque_saturation_abort_s - 0.5 * self.dt
        law[L_LIMITS] = self.torque_limits
        self.integral_cf = law[L_INTEGRAL]
        """The force integral ∫ S~ e_cf dt, CF coordinates (a view of the law's state)."""
        self._gain = self.law_buffer[:LAW_GAIN_SIZE].reshape(G_ROWS, X_SIZE)
        """G: [F_m; F_f; F_m + F_f; N^T τ_0 + g + c] = G x (module docstring, "Cost"), cached by parts."""
        self._gain[G_JOINT, X_BIAS] = _EYE7
        self._gain_frame: ControlFrame | None = None
        self._gain_damping: NDArray[np.float64] | None = None
        """The damping matrix the frame rows of G were built with (rebuilt when it is replaced)."""

    # ------------------------------------------------------------------ state

    def reset(self, posture: ArrayLike | None = None) -> None:
        """Clear the force integral, projector and saturation timer; optionally set the posture (7,) rad."""
        if posture is not None:
            self.model.posture = np.asarray(posture, dtype=float).copy()
        self.reset_integral()
        self.model.projector = None
        self.model.damping_matrix_a = None
        self._law[L_SATURATED] = 0.0
        self._law[L_SATURATED_FOR] = 0.0

    def reset_integral(self) -> None:
        """Clear the force integral (e.g. at the start of a contact segment)."""
        self.integral_cf[:] = 0.0

    # ------------------------------------------------------------------ frames

    def frame(
        self,
        cf_rotation: ArrayLike,
        selection: ArrayLike,
        cf_origin: ArrayLike | None = None,
        tool_position: ArrayLike | None = None,
        stiffness: ArrayLike | None = None,
    ) -> ControlFrame:
        """Precompute the law's matrices for one CF (``cf_rotation`` (3, 3) world from CF, ``selection`` (6,)).

        ``cf_origin`` and ``tool_position`` (m, world) matter only with ``compliance_center="cf_origin"``;
        ``stiffness`` (6,) a gain schedule's CF stiffness diagonal (N/m, N·m/rad; default: the gains').
        """
        offset = None
        if self.compliance_center == "cf_origin":
            if cf_origin is None or tool_position is None:
                raise ValueError("compliance_center='cf_origin' needs cf_origin and tool_position")
            offset = np.asarray(cf_origin, float) - np.asarray(tool_position, float)
        return ControlFrame(
            **control_frame_fields(self._frame_gains, cf_rotation, selection, offset, self._scheduled(stiffness))
        )

    def frames(
        self, cf_rotations: ArrayLike, selection: ArrayLike, stiffness: ArrayLike | None = None
    ) -> ControlFrameSeries:
        """Precompute control frames for ``(M, 3, 3)`` CF orientations at once (compliance centre at the tool);
        ``stiffness`` (M, 6) a gain schedule's CF stiffness diagonal per frame (default: the gains')."""
        if self.compliance_center != "tool":
            raise ValueError("frame series need compliance_center='tool' (the offset changes every step otherwise)")
        R = np.asarray(cf_rotations, dtype=float)
        if R.ndim != 3 or R.shape[1:] != (3, 3):
            raise ValueError(f"cf_rotations must have shape (M, 3, 3), got {R.shape}")
        return ControlFrameSeries(
            control_frame_fields(self._frame_gains, R, selection, None, self._scheduled(stiffness))
        )

    def _scheduled(self, stiffness: ArrayLike | None) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """A gain schedule's CF stiffness (..., 6) and the nominal damping that matches it; None: the gains' own."""
        if stiffness is None:
            return None
        stiffness = np.asarray(stiffness, dtype=float)
        return stiffness, damping_diagonal(self.gains, stiffness=stiffness)

    # ------------------------------------------------------------------ the law

    def compute(
        self,
        *,
        frame: ControlFrame,
        jacobian: NDArray[np.float64],
        q: NDArray[np.float64],
        qd: NDArray[np.float64],
        bias_torques: NDArray[np.float64],
        tool_position: ArrayLike,
        tool_quaternion: ArrayLike,
        reference_position: ArrayLike,
        reference_quaternion: ArrayLike,
        reference_twist: NDArray[np.float64],
        wrench: NDArray[np.float64],
        desired_force: float,
        in_contact: bool = True,
        mass_matrix: NDArray[np.float64] | None = None,
        update_null_space: bool = True,
    ) -> ControlOutput:
        """Return the joint torques of one control step (see the module docstring).

        ``jacobian`` (6, 7) of the tool point, world axes; ``q``, ``qd`` (7,) rad, rad/s;
        ``bias_torques`` (7,) gravity + Coriolis/centrifugal torques, N·m; tool and reference
        poses in the world (m, ``[x, y, z, w]``; arrays or sequences of floats);
        ``reference_twist`` (6,) world, m/s, rad/s; ``wrench`` (6,) measured, applied by the tool,
        world, at the tool point, N, N·m; ``desired_force`` N along +CF z (into the surface);
        ``in_contact`` lets the force integral run. The null-space projector (and, with a damping
        ratio, the damping from the apparent inertia) is rebuilt when ``update_null_space`` (else
        the last one is reused: it changes with the posture only, so a caller may refresh it every
        few steps); the dynamic projector and the adaptive damping need ``mass_matrix`` (7, 7)
        then; without it the static projector and the nominal damping are used.
        """
        robot = np.empty(ROBOT_STATE_SIZE)
        robot[ROBOT_Q], robot[ROBOT_QD] = q, qd
        robot[ROBOT_POSITION], robot[ROBOT_QUAT] = tool_position, tool_quaternion
        robot[ROBOT_ROTATION] = 0.0
        robot[ROBOT_JACOBIAN], robot[ROBOT_BIAS] = np.asarray(jacobian, dtype=float).ravel(), bias_torques
        reference = np.empty(REFERENCE_SIZE)
        reference[REFERENCE_POSITION], reference[REFERENCE_QUAT] = reference_position, reference_quaternion
        reference[REFERENCE_TWIST], reference[REFERENCE_FORCE] = reference_twist, desired_force
        return self.step(frame, robot, reference, np.asarray(wrench, dtype=float), in_contact, mass_matrix,
                         update_null_space)  # fmt: skip

    def step(
        self,
        frame: ControlFrame,
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        in_contact: bool = True,
        mass_matrix: NDArray[np.float64] | None = None,
        update_null_space: bool = True,
    ) -> ControlOutput:
        """:meth:`compute` on packed arrays: ``robot`` (:data:`ROBOT_STATE_SIZE`,) in the ``ROBOT_*`` layout (a
        simulated world's arm state as it is), ``reference`` (:data:`REFERENCE_SIZE`,) in the ``REFERENCE_*`` layout,
        ``wrench`` (6,) float64; the rest as :meth:`compute`. The outputs are new arrays. A 1 kHz loop runs the same
        law through :meth:`kernel` (the same floating-point operations: the same torques to the last bit)."""
        out = np.zeros(LAW_OUTPUT_SIZE)  # a step that must not run leaves it zero
        reason = None
        if update_null_space or frame is not self._gain_frame or self.model.projector is None:
            reason = self._prepare(frame, robot, reference, wrench, mass_matrix, update_null_space)
        if reason is None:
            code = law_step(self._gain, robot, reference, wrench, self._law, in_contact, out)
            if code != LAW_OK:
                reason = self._abort_reason(code, out, robot, reference, wrench, mass_matrix)
        return ControlOutput(out[LAW_TAU], out[O_MOTION], out[O_FORCE], out[O_SATURATED] > 0.0, reason)

    def kernel(self, robot: NDArray[np.float64]) -> LawKernel:
        """The law as a compiled 1 kHz loop runs it for one phase, on the robot state array ``robot`` (the
        ``ROBOT_*`` layout, float64, the array the loop passes on every step): :class:`LawKernel`."""
        update = compiled_entry(model_update_packed, (self.law_buffer, robot, NO_MASS_MATRIX, *self.model.arguments()))
        return LawKernel(self.law_buffer, partial(self._prepare, model_update=update), self._abort_reason)

    def _prepare(
        self,
        frame: ControlFrame,
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
        update_null_space: bool,
        model_update: Callable[..., int] = model_update_packed,
    ) -> str | None:
        """The part of a step before the compiled law (:func:`law_step`): rebuild the null-space model when asked
        (or when there is none) with ``model_update`` (:func:`model_update_packed`, or a loop's specialization of it),
        the gain rows when the frame or the damping changed. Returns why the step must not run (a non-finite or
        singular model; zero torque then), else None."""
        if update_null_space or self.model.projector is None:
            try:
                code = self.model.update(frame, self.law_buffer, robot, mass_matrix, model_update)
            except np.linalg.LinAlgError as exc:
                return self._singular_model_reason(exc)
            if code != LAW_OK:  # non-finite J or M
                return self._non_finite_model_reason(robot, reference, wrench, mass_matrix)
        self._use_frame(frame)
        return None

    def _use_frame(self, frame: ControlFrame) -> None:
        """Make the gain rows of ``frame`` with the damping in use (rebuilt only when the frame or the damping
        matrix changed since the last time)."""
        if frame is not self._gain_frame or self._gain_damping is not self.model.damping_matrix_a:
            self._cache_frame(frame)

    def _singular_model_reason(self, error: np.linalg.LinAlgError) -> str:
        """Why a step must not run after ``error`` in a model update (the model is rebuilt on the next step)."""
        self.model.projector = None
        return f"singular robot model: {error}"

    def _non_finite_model_reason(
        self,
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
    ) -> str:
        """Why a step must not run on non-finite inputs, naming them (the model is rebuilt on the next step)."""
        self.model.projector = None
        return non_finite_reason(robot, reference, wrench, mass_matrix)

    def _abort_reason(
        self,
        code: int,
        out: NDArray[np.float64],
        robot: NDArray[np.float64],
        reference: NDArray[np.float64],
        wrench: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
    ) -> str:
        """Why :func:`law_step` returned ``code`` (not :data:`LAW_OK`) with output ``out``, in words."""
        if code == LAW_NON_FINITE:
            return self._non_finite_model_reason(robot, reference, wrench, mass_matrix)
        if code == LAW_TORQUE_LIMIT:
            joint = int(out[O_JOINT])
            return (
                f"torque limit: joint {joint + 1} saturated at {self.torque_limits[joint]:.0f} N·m "
                f"for {self._law[L_SATURATED_FOR]:.3f} s"
            )
        force = math.sqrt(float(wrench[:3] @ wrench[:3]))
        return f"force limit: measured {force:.1f} N > max_force_n {self.gains.max_force_n:.1f} N"

    def _cache_frame(self, frame: ControlFrame) -> None:
        """Build the rows of G that give the wrenches (until the frame or the damping matrix changes)."""
        D = self.model.damping_matrix_a
        if D is None:  # the nominal CF damping, D_m = Adg diag(S d S) Ad^-1, as the product I D_m I
            S = frame.selection
            left, D, right = _EYE6, frame.adg @ ((S * frame.damping * S)[:, None] * frame.ad_inv), _EYE6
        else:
            left, right = frame.damping_left, frame.damping_right
        write_frame(self._gain, self._law, frame.task_gain, left, D, right, frame.law_rows)
        self._gain_frame, self._gain_damping = frame, self.model.damping_matrix_a

    def null_space_torque(
        self,
        jacobian: NDArray[np.float64],
        q: NDArray[np.float64],
        qd: NDArray[np.float64],
        mass_matrix: NDArray[np.float64] | None,
    ) -> NDArray[np.float64]:
        """Return ``N^T τ_0`` with ``τ_0 = K_n (q_0 - q) - D_n q̇`` (see the module docstring); rebuilds N^T."""
        robot = np.zeros(ROBOT_STATE_SIZE)
        robot[ROBOT_JACOBIAN] = np.asarray(jacobian, dtype=float).ravel()
        model = self.model
        if model.update(self.frame(np.eye(3), [1.0] * 6), self.law_buffer, robot, mass_matrix) != LAW_OK:
            raise ValueError("non-finite jacobian or mass_matrix")
        tau0 = model.kn * (model.posture - q) - model.dn * qd
        return model.projector_rows @ tau0


class LawKernel(NamedTuple):
    """The door of a compiled 1 kHz control loop into a :class:`HybridController` for one phase
    (:meth:`HybridController.kernel`); the same law as :meth:`HybridController.step`, to the last bit.

    ``buffer``: the law's gains and state in one array (``LAW_GAIN_SIZE`` floats of G by rows, then the ``L_*``
    state), which the loop's own compiled step hands to :func:`law_step_packed` with the robot state, the step's
    reference, the wrench and the output (``LAW_OUTPUT_SIZE``: the torque first). ``refresh(frame, robot, reference,
    wrench, mass_matrix, update_model)``, before that step on a new control frame or a model update: the gain rows of
    ``frame`` and, when ``update_model``, the null-space model for the Jacobian in ``robot`` and ``mass_matrix`` (7, 7;
    None: the static projector) in one compiled call (the model update's own specialization: no dispatcher), the
    adaptive damping rebuilt in Python when due (one update in :data:`DAMPING_UPDATE_EVERY`); returns why the step
    must not run (a non-finite or singular model), else None. ``abort_reason(code, out, robot, reference, wrench,
    mass_matrix)``: why the compiled step returned ``code`` (not :data:`LAW_OK`) with output ``out``, in words.
    """

    buffer: NDArray[np.float64]
    refresh: Callable[..., str | None]
    abort_reason: Callable[..., str]
