"""The hybrid impedance/force control law of paper eq. (1)-(4) for a torque-controlled 7-DoF arm.

Pure numpy: no simulator, no I/O. :class:`HybridController` turns the robot state, the
reference and the compliant frame (CF) into 7 joint torques, once per control step; a compiled 1 kHz loop runs the
same law through one :class:`LawKernel` per phase (:meth:`HybridController.kernel`).

The package: :mod:`~skills.control.layouts` (the packed arrays), :mod:`~skills.control.law` (the numbers, compiled),
:mod:`~skills.control.frames` (the control frame), :mod:`~skills.control.controller` (the controller and its kernel).

Frames
------
The paper writes eq. (4) in the end-effector frame EF. This module computes in frame **A**:
origin at the tool point, axes of the world frame, i.e. the frame in which the simulator gives
the Jacobian ``J`` (``ξ_A = J q̇``, twist ``(v, ω)`` of the tool point, world axes) and the
measured wrench. A and EF share the origin and differ by the rotation ``R_w_ef``, so
``Ad(A <- EF) = blockdiag(R_w_ef, R_w_ef) = Adg(A <- EF)``, ``J_A = Ad J_EF``,
``F_A = Adg F_EF`` and ``J_A^T F_A = J_EF^T F_EF``: the torques are identical, and with
``T(A <- CF) = T(A <- EF) T(EF <- CF)`` eq. (3) evaluated with ``T(A <- CF)`` is eq. (3) of the
paper mapped into A. ``(R, p)`` of ``T(A <- CF)``: ``R`` = the CF orientation in the world
(world from CF), ``p`` = the CF origin minus the tool point (world axes).

Compliance centre. By default (``compliance_center="tool"``) the CF is used with its origin at
the tool point (``p = 0``): the stored CF origin (a point of the fitted plane, possibly far from
the tool) only locates the surface and the CF x-y coordinates of the path. With the literal
offset, a CF moment about the distant origin would become a lateral force at the tool, and the
contact force, whose line of action passes through the tool point, would not survive ``Ω~``
unchanged (``Ω~`` would add the moment ``p × f``). ``compliance_center="cf_origin"`` keeps the
literal form for completeness (then ``p`` changes with the tool position and the frame has to
be rebuilt every step).

The law (all 6-vectors in A; wrenches are applied BY the tool TO the environment)::

    e_p   = [p_r - p,  2 log(q_r ⊗ q*)]                      pose error (position, rotation vector)
    F_m   = Ω e_p + F_damp                                   impedance on the motion axes (eq. 3, 4)
    e_f   = F_d - F                                          force error, F_d = Adg (0, 0, f_d, 0, 0, 0)
    F_f   = Ω~ F_d + K_p Ω~ e_f + K_i Adg S~ ∫ S~ Adg^-1 e_f dt  PI force control with feed-forward
    τ     = J^T (F_m + F_f) + g(q) + c(q, q̇) + N^T τ_0        N^T τ_0: null-space posture torque

with ``Ω = Adg K_c S Ad^-1`` and ``Ω~ = Adg S~ Adg^-1`` from :mod:`skills.frames`.

Damping (Cartesian, in the CF). In CF coordinates ``ξ_cf = Ad^-1 ξ``::

    F_damp = Adg (S D_cf S (ξ_r,cf - ξ_cf) - d_f ⊙ S~ ⊙ ξ_cf)

the motion axes damp the velocity error, the force axes the absolute tool velocity (the
surface does not move): "active damping" that keeps the PI force loop stable on a stiff
surface (``force_axis_damping_ns_per_m``). With a damping RATIO the motion-axes damping is the
full matrix of the "double diagonalization" (Albu-Schäffer et al. 2003),
``D = 2 ζ L (L^-1 K L^-T)^{1/2} L^T`` with ``Λ = L L^T`` the apparent inertia at the tool
point, ``Λ = (J M^-1 J^T)^-1``, and ``K`` the CF stiffness mapped into A: every decoupled mode
gets damping ratio ζ. It is rebuilt with the null-space projector whenever a mass matrix is
given (until then, or without one, the diagonal ``2 ζ sqrt(K_i m_i)`` with the nominal
``apparent_mass_kg`` / ``apparent_inertia_kgm2``) and mapped into the current CF every step
(``D_cf = Ad^T D Ad``; restricted to the motion axes, ``S D_cf S``). This matters on the iiwa:
the apparent inertia about the tool axis is ~1e-3 kg·m² but ~0.2 kg·m² about the other two, so
one fixed (or per-axis diagonal) rotational damping is either unstable at 1 kHz about the tool
axis or far too weak about the others, as soon as the tool is tilted. Explicit damping values
override the ratio (a constant diagonal in the CF). The null-space task has its own joint
damping. The paper's ``D_x J q̇`` term is this Cartesian damping with the sign that dissipates
energy.

Force loop. The desired wrench is fed forward (``Ω~ F_d``), so the PI part only corrects the
residual; the integral is kept in CF coordinates (it travels with a contour's moving CF) and
integrated only on the force axes. Anti-windup: ``|K_i ∫e|`` is clamped to
``force_integral_limit_n`` per axis, and integration is frozen while the previous torque command
saturated or the caller reports no contact.

Null space. ``τ_0 = K_n (q_0 - q) - D_n q̇`` pulls the redundant elbow towards the posture
``q_0``. Projector (``null_space``): ``dynamic`` (default) ``N^T = I - J^T Λ J M^-1`` with
``Λ = (J M^-1 J^T)^-1`` (dynamically consistent: the posture torque produces no task-space
acceleration), or ``static`` ``N^T = I - J^T (J J^T)^-1 J`` (``I - J^T J^{+T}``; no mass matrix
needed, but not free of task-space acceleration). Both are regularized near singularities.

Limits. Torques are clipped to the robot's limits; a clip lasting ``torque_saturation_abort_s``
aborts. A measured force above ``max_force_n`` aborts at once. Non-finite inputs never give a
non-finite torque: the output is zero torques with an abort reason.

Cost. The law runs at 1 kHz, where a numpy call on a 6- or 7-vector costs ~0.3-1 µs of call
overhead whatever it computes. Everything above is linear in the step's input vector ``x = [e_p,
f_d, 1, ξ_r, F, ∫e_cf, ξ, q, q̇, g + c]`` (53 values, layout ``X_*``), so a cached gain matrix
``G`` (25 x 53) gives ``y = G x = [F_m; F_f; F_m + F_f; N^T τ_0 + g + c]`` and ``τ = J^T (F_m +
F_f) + (N^T τ_0 + g + c)``. One step is ONE compiled call (:func:`law_step`, numba) on packed
arrays (the robot state ``ROBOT_*``, the reference ``REFERENCE_*``, the law's state ``L_*``; all in
:mod:`skills.control.layouts`):
the pose error, the force integral, ``x``, ``G x``, ``τ`` and the limit checks. The rows of ``G``
that depend on the control frame (``Ω``, the motion damping ``D_m`` and ``-(D_m + D_f)``, the
feed-forward ``(1 + K_p) Ω~ F_d,1`` per N desired, ``-K_p Ω~``, ``K_i Adg``) are rebuilt when the
frame or the damping matrix changes (a contour's frame series every few steps: the frame-only
products come precomputed, vectorized, with the frames); the null-space rows (``N^T K_n q_0``,
``-K_n N^T``, ``-D_n N^T``) whenever the caller refreshes the model (``update_null_space``: the
projector and the apparent inertia, the damping every :data:`DAMPING_UPDATE_EVERY`-th time; both
compiled too).

Baselines (``ControllerKind``), the same class with other settings:

- ``impedance``: ``S = I`` on every axis (no force loop, no feed-forward), stiffness and damping
  in the CF; the force is only what the reference implies: during contact the reference is
  moved ``f_d / k_z`` along +CF z (``k_z`` the CF-z translational stiffness), so the spring
  presses with ``f_d`` if the surface is exactly where its reference is based: the taught surface
  (``impedance``) or the surface the guarded approach found (``impedance_found_surface``, the
  executor re-bases the reference; the law is the same).
- ``hybrid_world_z``: the CF orientation is replaced by the "world z down" frame: z = -z_world,
  x = the CF x axis projected onto the horizontal plane (world x if the CF x is vertical),
  y = z × x. The selection and force loop are as in ``hybrid_cf``, so the desired force pushes
  straight down whatever the surface normal is.
"""

from skills.control.controller import ControlOutput, HybridController, LawKernel
from skills.control.frames import ControlFrame, ControlFrameSeries, world_z_down_rotation
from skills.control.law import damping_diagonal, damping_matrix, law_step_packed, pose_error
from skills.control.model import DAMPING_UPDATE_EVERY

__all__ = [
    "DAMPING_UPDATE_EVERY",
    "ControlFrame",
    "ControlFrameSeries",
    "ControlOutput",
    "HybridController",
    "LawKernel",
    "damping_diagonal",
    "damping_matrix",
    "law_step_packed",
    "pose_error",
    "world_z_down_rotation",
]
