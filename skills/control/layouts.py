"""The packed arrays the control law reads and writes, one home for each layout (``skills.control``'s docstring,
"Cost"): the law's input vector ``x`` and gain matrix ``G`` (``X_*``, ``G_*``), the robot state a step reads
(``ROBOT_*``: a simulated world's arm fills it as it is), one step's reference (``REFERENCE_*``), the law's own state
(``L_*``), a step's output (``LAW_TAU`` first, ``O_*``), and the codes the compiled step returns (``LAW_*``).

Each layout is a set of slices (for Python) and, below them, their offsets as plain ints for compiled code (numba
freezes module-level ints as constants; it does not take slices as globals).
"""

from __future__ import annotations

# Layout of the law's per-step input vector x (see the module docstring, "Cost") and of the gain matrix G.
X_POSE = slice(0, 6)  # e_p: pose error (m, rad)
X_FORCE = 6  # f_d: desired CF-z force (N)
X_ONE = 7  # 1: carries the constant null-space torque N^T K_n q_0
X_REF_TWIST = slice(8, 14)  # ξ_r: reference twist
X_WRENCH = slice(14, 20)  # F: measured wrench
X_INTEGRAL = slice(20, 26)  # ∫ S~ e_cf dt: force integral, CF coordinates
X_TWIST = slice(26, 32)  # ξ = J q̇: tool twist
X_Q = slice(32, 39)  # q
X_QD = slice(39, 46)  # q̇
X_BIAS = slice(46, 53)  # g + c: gravity and Coriolis torques
X_SIZE = 53
X_TASK = slice(0, 32)  # the columns the task-space rows of G can use
G_MOTION = slice(0, 6)  # rows of G giving F_m
G_FORCE = slice(6, 12)  # rows giving F_f
G_TASK = slice(0, 12)  # F_m and F_f: the rows that change with the control frame
G_WRENCH = slice(12, 18)  # rows giving F_m + F_f (their sum, so that τ needs no further addition)
G_JOINT = slice(18, 25)  # rows giving N^T τ_0 + g + c
G_ROWS = 25
LAW_GAIN_SIZE = G_ROWS * X_SIZE
"""G's floats at the head of a controller's law buffer (:attr:`HybridController.law_buffer`), the law's state after."""

# Layout of the robot state one control step reads (one float array, so that the compiled step takes few arguments;
# ``sim_worker.arm_model`` fills a world's in this layout): joints, tool pose, Jacobian, gravity/Coriolis torques.
ROBOT_Q = slice(0, 7)  # q, rad
ROBOT_QD = slice(7, 14)  # q̇, rad/s
ROBOT_POSITION = slice(14, 17)  # tool point, world, m
ROBOT_QUAT = slice(17, 21)  # tool orientation [x, y, z, w]
ROBOT_ROTATION = slice(21, 30)  # tool orientation, 3 x 3 by rows (not read by the law)
ROBOT_JACOBIAN = slice(30, 72)  # J (6 x 7 by rows), tool point, world axes
ROBOT_BIAS = slice(72, 79)  # g + c, N·m
ROBOT_STATE_SIZE = 79
# Layout of one step's reference: position (3), quaternion (4), twist (6), desired CF-z force (N).
REFERENCE_POSITION = slice(0, 3)
REFERENCE_QUAT = slice(3, 7)
REFERENCE_TWIST = slice(7, 13)
REFERENCE_FORCE = 13
REFERENCE_SIZE = 14
# Layout of the law's own state and per-frame constants (``HybridController._law``), read by the compiled step.
L_INTEGRAL = slice(0, 6)  # ∫ S~ e_cf dt, CF coordinates
L_SATURATED = 6  # 1 when the previous torque command was clipped
L_SATURATED_FOR = 7  # how long the torques have been clipped, s
L_DT = 8
L_INTEGRAL_BOUND = 9  # |∫e| bound per axis (force_integral_limit_n / K_i)
L_IMPEDANCE_KZ = 10  # k_z for the impedance baseline's reference shift f_d / k_z along CF z; 0: no shift
L_MAX_FORCE_SQ = 11
L_SATURATION_ABORT = 12  # torque_saturation_abort_s - dt / 2
L_LIMITS = slice(13, 20)  # torque limits, N·m
L_FRAME = slice(20, 71)  # the control frame's constants (ControlFrame.law_rows), these four:
L_CF_Z = slice(20, 23)  # the control frame's CF z axis
L_AXES = slice(23, 29)  # 1 on the CF force axes the integral runs on
L_ERROR_PER_N = slice(29, 35)  # S~ Adg^-1 F_d,1: CF force error per N desired
L_ADG_INV = slice(35, 71)  # Adg^-1 by rows: the measured wrench into CF coordinates
L_X = slice(71, 71 + X_SIZE)  # scratch: the step's input vector x (no allocation per step)
L_Y = slice(L_X.stop, L_X.stop + G_ROWS)  # scratch: y = G x
L_SIZE = L_Y.stop
# Layout of a step's output: τ (7), F_m (6), F_f (6), saturated (1/0), the most saturated joint.
LAW_TAU = slice(0, 7)
O_MOTION = slice(7, 13)
O_FORCE = slice(13, 19)
O_SATURATED = 19
O_JOINT = 20
LAW_OUTPUT_SIZE = 21
# Codes the compiled step returns.
LAW_OK, LAW_NON_FINITE, LAW_TORQUE_LIMIT, LAW_FORCE_LIMIT = 0, 1, 2, 3

# The layouts' offsets as plain ints for the compiled step (numba freezes module-level ints as constants; it does not
# take slices as globals). Derived from the slices above: one home for each layout.
R_Q, R_QD, R_P, R_QUAT, R_QUAT_END = (
    ROBOT_Q.start,
    ROBOT_QD.start,
    ROBOT_POSITION.start,
    ROBOT_QUAT.start,
    ROBOT_QUAT.stop,
)
R_J, R_BIAS = ROBOT_JACOBIAN.start, ROBOT_BIAS.start
F_P, F_QUAT, F_QUAT_END, F_TWIST = (
    REFERENCE_POSITION.start,
    REFERENCE_QUAT.start,
    REFERENCE_QUAT.stop,
    REFERENCE_TWIST.start,
)
X_REF_TWIST0, X_WRENCH0, X_INTEGRAL0 = X_REF_TWIST.start, X_WRENCH.start, X_INTEGRAL.start
X_TWIST0, X_Q0, X_QD0, X_BIAS0, X_TASK_END = X_TWIST.start, X_Q.start, X_QD.start, X_BIAS.start, X_TASK.stop
G_WRENCH0, G_JOINT0, G_TASK_END = G_WRENCH.start, G_JOINT.start, G_TASK.stop
L_INTEGRAL0, L_LIMITS0, L_CF_Z0 = L_INTEGRAL.start, L_LIMITS.start, L_CF_Z.start
L_AXES0, L_ERROR_PER_N0, L_ADG_INV0 = L_AXES.start, L_ERROR_PER_N.start, L_ADG_INV.start
L_X0, L_Y0 = L_X.start, L_Y.start
O_MOTION0 = O_MOTION.start
if O_FORCE.start != O_MOTION.stop or G_FORCE.start != G_MOTION.stop:  # the step copies F_m, F_f in one run
    raise AssertionError("F_m and F_f must be adjacent in G and in the output")

R_J_END = ROBOT_JACOBIAN.stop
