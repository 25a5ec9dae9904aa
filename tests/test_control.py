"""Invariants of the hybrid impedance/force control law (skills/control/): pure numpy, fast."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from scipy.spatial.transform import Rotation

from schemas.execution import ControllerGains, ControllerKind, NullSpaceProjection
from schemas.skill import SELECTION_CONTACT, SELECTION_FREE
from skills.control import (
    HybridController,
    damping_diagonal,
    damping_matrix,
    pose_error,
    world_z_down_rotation,
)
from skills.frames import force_projector_in_frame, stiffness_in_frame

RNG_SEED = 7


def _state(seed: int = RNG_SEED) -> dict:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(7, 7))
    return {
        "jacobian": rng.normal(size=(6, 7)),
        "q": rng.normal(size=7) * 0.3,
        "qd": np.zeros(7),
        "bias_torques": rng.normal(size=7),
        "mass_matrix": A @ A.T + 7.0 * np.eye(7),
        "tool_position": np.array([0.5, 0.1, 0.3]),
        "tool_quaternion": Rotation.from_euler("xyz", [3.0, 0.2, -0.4]).as_quat(),
    }


def _cf(seed: int = 3) -> np.ndarray:
    return Rotation.random(random_state=seed).as_matrix()


def _call(ctrl: HybridController, frame, state: dict, **overrides) -> tuple:
    args = {
        "frame": frame,
        "reference_position": state["tool_position"],
        "reference_quaternion": state["tool_quaternion"],
        "reference_twist": np.zeros(6),
        "wrench": np.zeros(6),
        "desired_force": 0.0,
        **state,
    }
    args.update(overrides)
    return ctrl.compute(**args)


def test_pose_error_matches_rotation_vector() -> None:
    q = Rotation.from_euler("xyz", [0.3, -0.2, 0.5])
    q_ref = Rotation.from_rotvec([0.05, -0.1, 0.2]) * q
    e = pose_error([1.0, 2.0, 3.0], q.as_quat(), [1.1, 2.0, 2.9], q_ref.as_quat())
    np.testing.assert_allclose(e[:3], [0.1, 0.0, -0.1], atol=1e-12)
    np.testing.assert_allclose(e[3:], [0.05, -0.1, 0.2], atol=1e-12)
    # sign-invariant in the quaternions
    e2 = pose_error([1.0, 2.0, 3.0], -q.as_quat(), [1.1, 2.0, 2.9], q_ref.as_quat())
    np.testing.assert_allclose(e, e2, atol=1e-12)


def test_cf_z_force_error_gives_only_cf_z_force_command() -> None:
    ctrl = HybridController(gains=ControllerGains(force_kp=0.3, force_ki=10.0))
    R = _cf()
    frame = ctrl.frame(R, SELECTION_CONTACT)
    out = _call(ctrl, frame, _state(), desired_force=10.0)
    z = R[:, 2]
    # feed-forward + P on the full 10 N error + one step of I, all along CF z, no moment
    expected = (10.0 + 0.3 * 10.0 + 10.0 * 10.0 * 1e-3) * z
    np.testing.assert_allclose(out.wrench_force[:3], expected, atol=1e-9)
    np.testing.assert_allclose(out.wrench_force[3:], 0.0, atol=1e-12)


def test_cf_x_force_error_is_removed() -> None:
    ctrl = HybridController()
    R = _cf()
    frame = ctrl.frame(R, SELECTION_CONTACT)
    measured = np.concatenate([12.0 * R[:, 2] + 5.0 * R[:, 0] - 3.0 * R[:, 1], [0.4, -0.2, 0.1]])
    out = _call(ctrl, frame, _state(), wrench=measured, desired_force=12.0)
    # no CF-z error: only the feed-forward is left; the CF-x/y forces and moments are not fed back
    np.testing.assert_allclose(out.wrench_force, np.concatenate([12.0 * R[:, 2], np.zeros(3)]), atol=1e-9)
    np.testing.assert_allclose(ctrl.integral_cf, 0.0, atol=1e-12)


def test_cf_z_position_error_produces_no_motion_wrench() -> None:
    ctrl = HybridController()
    R = _cf()
    frame = ctrl.frame(R, SELECTION_CONTACT)
    state = _state()
    out = _call(ctrl, frame, state, reference_position=state["tool_position"] + 0.02 * R[:, 2])
    np.testing.assert_allclose(out.wrench_motion, 0.0, atol=1e-9)
    # ... while a CF-x error does, along CF x with the CF-x stiffness
    out_x = _call(ctrl, frame, state, reference_position=state["tool_position"] + 0.01 * R[:, 0])
    np.testing.assert_allclose(out_x.wrench_motion[:3], 30.0 * R[:, 0], atol=1e-9)
    np.testing.assert_allclose(out_x.wrench_motion[3:], 0.0, atol=1e-9)


def test_frame_matrices_are_eq3_from_frames_module() -> None:
    ctrl = HybridController()
    R = _cf()
    frame = ctrl.frame(R, SELECTION_CONTACT)
    K = [3000.0, 3000.0, 3000.0, 40.0, 40.0, 40.0]
    np.testing.assert_allclose(frame.omega, stiffness_in_frame(R, np.zeros(3), K, SELECTION_CONTACT))
    np.testing.assert_allclose(frame.projector, force_projector_in_frame(R, np.zeros(3), SELECTION_CONTACT))
    # the CF-origin compliance centre is the literal eq. (3) with the offset, and a CF-z force
    # whose line of action passes through the CF origin survives Ω~ unchanged
    literal = HybridController(compliance_center="cf_origin")
    origin, tool = np.array([0.6, 0.0, 0.1]), np.array([0.5, 0.1, 0.1])
    f_lit = literal.frame(R, SELECTION_CONTACT, cf_origin=origin, tool_position=tool)
    np.testing.assert_allclose(f_lit.omega, stiffness_in_frame(R, origin - tool, K, SELECTION_CONTACT))
    force = 7.0 * R[:, 2]
    wrench_through_origin = np.concatenate([force, np.cross(origin - tool, force)])
    np.testing.assert_allclose(f_lit.projector @ wrench_through_origin, wrench_through_origin, atol=1e-12)


def test_world_computation_equals_paper_ef_form() -> None:
    """eq. (4) in EF (tool frame) with EF_T_CF gives the same torques as the world-axes form."""
    ctrl = HybridController()
    state = _state()
    R_cf = _cf()
    R_ef = Rotation.from_quat(state["tool_quaternion"]).as_matrix()
    rng = np.random.default_rng(1)
    e_a = rng.normal(size=6) * 0.01
    frame = ctrl.frame(R_cf, SELECTION_CONTACT)
    tau_a = state["jacobian"].T @ (frame.omega @ e_a)
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = R_ef.T  # A -> EF for twists and wrenches (same origin)
    K = [3000.0, 3000.0, 3000.0, 40.0, 40.0, 40.0]
    omega_ef = stiffness_in_frame(R_ef.T @ R_cf, np.zeros(3), K, SELECTION_CONTACT)
    tau_ef = (B @ state["jacobian"]).T @ (omega_ef @ (B @ e_a))
    np.testing.assert_allclose(tau_a, tau_ef, atol=1e-9)


def test_reduces_to_plain_impedance_with_world_cf_and_identity_selection() -> None:
    gains = ControllerGains(nullspace_stiffness_nm_per_rad=0.0, nullspace_damping_nms_per_rad=0.0)
    ctrl = HybridController(gains=gains)
    frame = ctrl.frame(np.eye(3), SELECTION_FREE)
    state = _state()
    state["qd"] = np.random.default_rng(2).normal(size=7) * 0.1
    ref_p = state["tool_position"] + np.array([0.01, -0.02, 0.005])
    ref_q = (Rotation.from_rotvec([0.02, 0.0, -0.03]) * Rotation.from_quat(state["tool_quaternion"])).as_quat()
    ref_twist = np.array([0.1, 0.0, 0.0, 0.0, 0.2, 0.0])
    out = _call(
        ctrl,
        frame,
        state,
        reference_position=ref_p,
        reference_quaternion=ref_q,
        reference_twist=ref_twist,
        wrench=np.array([3.0, 1.0, 9.0, 0.1, 0.0, 0.0]),
        desired_force=10.0,
    )
    K = np.diag([3000.0] * 3 + [40.0] * 3)
    J, M = state["jacobian"], state["mass_matrix"]
    Lam = np.linalg.inv(J @ np.linalg.solve(M, J.T))
    D = damping_matrix(K, Lam, 0.8)  # damping ratio 0.8 on the apparent inertia from the mass matrix
    np.testing.assert_allclose(ctrl.model.damping_matrix_a, D, rtol=1e-3, atol=1e-6 * np.abs(D).max())
    e = pose_error(state["tool_position"], state["tool_quaternion"], ref_p, ref_q)
    twist = J @ state["qd"]
    expected = J.T @ (K @ e + ctrl.model.damping_matrix_a @ (ref_twist - twist)) + state["bias_torques"]
    np.testing.assert_allclose(out.tau, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out.wrench_force, 0.0)


def test_damping_matrix_gives_the_damping_ratio_on_every_mode() -> None:
    np.testing.assert_allclose(damping_matrix(np.eye(6) * 100.0, np.eye(6) * 4.0, 0.5), np.eye(6) * 20.0)
    rng = np.random.default_rng(5)
    A = rng.normal(size=(6, 6))
    Lam = A @ A.T + 0.1 * np.eye(6)
    K = np.diag([3000.0] * 3 + [40.0] * 3)
    D = damping_matrix(K, Lam, 0.7)
    np.testing.assert_allclose(D, D.T, atol=1e-9)
    # in the modal coordinates (Φ^T Λ Φ = I, Φ^T K Φ = diag(ω²)) D is diag(2 ζ ω)
    w, Phi = scipy.linalg.eigh(K, Lam)
    np.testing.assert_allclose(Phi.T @ D @ Phi, np.diag(2 * 0.7 * np.sqrt(w)), atol=1e-8 * np.sqrt(w).max())
    # without a mass matrix the nominal diagonal is used
    gains = ControllerGains()
    np.testing.assert_allclose(HybridController(gains=gains).damping, damping_diagonal(gains))


@pytest.mark.parametrize("projection", [NullSpaceProjection.dynamic, NullSpaceProjection.static])
def test_null_space_torque_does_not_act_on_the_task(projection: NullSpaceProjection) -> None:
    gains = ControllerGains(null_space=projection, nullspace_stiffness_nm_per_rad=50.0)
    ctrl = HybridController(gains=gains, posture=np.full(7, 0.4))
    state = _state()
    state["qd"] = np.random.default_rng(4).normal(size=7)
    tau_null = ctrl.null_space_torque(state["jacobian"], state["q"], state["qd"], state["mass_matrix"])
    assert np.linalg.norm(tau_null) > 1.0
    if projection is NullSpaceProjection.dynamic:
        # no task-space acceleration: J M^-1 τ_null = 0
        residual = state["jacobian"] @ np.linalg.solve(state["mass_matrix"], tau_null)
    else:
        residual = state["jacobian"] @ tau_null
    np.testing.assert_allclose(residual, 0.0, atol=1e-3 * np.linalg.norm(tau_null))


def test_force_integral_anti_windup() -> None:
    gains = ControllerGains(force_ki=10.0, force_integral_limit_n=2.0)
    ctrl = HybridController(gains=gains)
    R = _cf()
    frame = ctrl.frame(R, SELECTION_CONTACT)
    state = _state()
    for _ in range(2000):  # 2 s of a 5 N error
        _call(ctrl, frame, state, desired_force=5.0)
    assert ctrl.integral_cf[2] == pytest.approx(2.0 / 10.0)  # K_i ∫e clamped at 2 N
    np.testing.assert_allclose(ctrl.integral_cf[[0, 1, 3, 4, 5]], 0.0)
    ctrl.reset_integral()
    _call(ctrl, frame, state, desired_force=5.0, in_contact=False)  # frozen out of contact
    assert ctrl.integral_cf[2] == 0.0


def test_torque_saturation_clips_freezes_integral_and_aborts() -> None:
    gains = ControllerGains(torque_saturation_abort_s=0.005)
    ctrl = HybridController(gains=gains)
    frame = ctrl.frame(_cf(), SELECTION_CONTACT)
    state = _state()
    far = state["tool_position"] + np.array([5.0, 5.0, 5.0])  # a huge pose error
    reasons = []
    for _ in range(6):
        out = _call(ctrl, frame, state, reference_position=far, desired_force=5.0)
        assert out.saturated
        assert np.all(np.abs(out.tau) <= ctrl.torque_limits + 1e-12)
        reasons.append(out.abort_reason)
    assert reasons[0] is None
    assert reasons[-1] is not None and reasons[-1].startswith("torque limit")
    # integration ran on the first step only, then froze while saturated
    assert ctrl.integral_cf[2] == pytest.approx(5.0 * 1e-3)


def test_force_limit_aborts_with_reason() -> None:
    ctrl = HybridController(gains=ControllerGains(max_force_n=30.0))
    frame = ctrl.frame(_cf(), SELECTION_CONTACT)
    out = _call(ctrl, frame, _state(), wrench=np.array([0.0, 0.0, 35.0, 0.0, 0.0, 0.0]), desired_force=10.0)
    assert out.abort_reason is not None and "force limit" in out.abort_reason
    assert np.all(np.isfinite(out.tau))


@pytest.mark.parametrize("field", ["wrench", "jacobian", "tool_position", "bias_torques"])
def test_non_finite_input_never_gives_a_nan_torque(field: str) -> None:
    ctrl = HybridController()
    frame = ctrl.frame(_cf(), SELECTION_CONTACT)
    state = _state()
    bad = np.array(state.get(field, np.zeros(6)), dtype=float)
    bad.flat[0] = np.nan
    out = _call(ctrl, frame, state, **{field: bad}, desired_force=10.0)
    assert np.all(np.isfinite(out.tau))
    np.testing.assert_array_equal(out.tau, 0.0)
    assert out.abort_reason is not None and field in out.abort_reason


def test_impedance_baseline_has_no_force_loop_and_presses_through_the_reference() -> None:
    ctrl = HybridController(kind=ControllerKind.impedance)
    R = _cf()
    frame = ctrl.frame(R, SELECTION_CONTACT)
    np.testing.assert_array_equal(frame.selection, 1.0)
    # tool exactly at the (taught) surface reference: the spring presses f_d along CF z
    out = _call(ctrl, frame, _state(), desired_force=15.0, wrench=np.array([0.0, 0.0, 40.0, 0, 0, 0]))
    np.testing.assert_allclose(out.wrench_force, 0.0)
    np.testing.assert_allclose(out.wrench_motion[:3], 15.0 * R[:, 2], atol=1e-9)


def test_world_z_baseline_pushes_down_whatever_the_cf() -> None:
    tilted = Rotation.from_euler("y", 180.0 + 15.0, degrees=True).as_matrix()  # CF z into a 15° slope
    ctrl = HybridController(kind=ControllerKind.hybrid_world_z)
    frame = ctrl.frame(tilted, SELECTION_CONTACT)
    np.testing.assert_allclose(frame.rotation[:, 2], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(np.linalg.det(frame.rotation), 1.0)
    out = _call(ctrl, frame, _state(), desired_force=10.0)
    np.testing.assert_allclose(out.wrench_force[:2], 0.0, atol=1e-12)
    assert out.wrench_force[2] < -10.0
    # a free segment keeps the CF (S = I: no force axis to redirect)
    free = ctrl.frame(tilted, SELECTION_FREE)
    np.testing.assert_allclose(free.rotation, tilted)
    R = world_z_down_rotation(np.stack([tilted, np.eye(3)]))
    np.testing.assert_allclose(np.linalg.det(R), 1.0)


def test_frame_series_equals_single_frames() -> None:
    ctrl = HybridController()
    Rs = Rotation.random(5, random_state=11).as_matrix()
    series = ctrl.frames(Rs, SELECTION_CONTACT)
    assert len(series) == 5
    for k in range(5):
        single = ctrl.frame(Rs[k], SELECTION_CONTACT)
        np.testing.assert_allclose(series[k].omega, single.omega, atol=1e-12)
        np.testing.assert_allclose(series[k].ad_inv, single.ad_inv, atol=1e-12)
        np.testing.assert_allclose(series[k].force_direction, single.force_direction, atol=1e-12)
        np.testing.assert_allclose(series[k].law_rows, single.law_rows, atol=1e-12)
        np.testing.assert_allclose(series[k].task_gain, single.task_gain, atol=1e-12)
        np.testing.assert_allclose(series[k].damping_left, single.damping_left, atol=1e-12)


def test_law_rows_pack_the_frame_constants_in_the_law_layout() -> None:
    """law_rows = [CF z, force axes (0 without a force integral), S~ Adg^-1 F_d,1, Adg^-1 by rows]."""
    R = _cf()
    frame = HybridController().frame(R, SELECTION_CONTACT)
    np.testing.assert_array_equal(frame.law_rows[:3], R[:, 2])
    np.testing.assert_array_equal(frame.law_rows[3:9], 1.0 - np.asarray(SELECTION_CONTACT, dtype=float))
    np.testing.assert_array_equal(frame.law_rows[15:], frame.adg_inv.ravel())
    unit_force = frame.force_direction  # the wrench of 1 N along CF z: its CF force error per N is S~ Adg^-1 of it
    np.testing.assert_allclose(frame.law_rows[9:15], frame.force_axes * (frame.adg_inv @ unit_force), atol=1e-15)
    without_integral = HybridController(gains=ControllerGains(force_ki=0.0)).frame(R, SELECTION_CONTACT)
    np.testing.assert_array_equal(without_integral.law_rows[3:9], 0.0)


@pytest.mark.parametrize("explicit_damping", [False, True])
def test_a_new_frame_each_step_gives_the_torques_of_a_controller_that_saw_only_it(explicit_damping: bool) -> None:
    """Switching frames every step (a contour) rewrites every frame-dependent gain: each step's torques equal those
    of a new controller given only that frame, the same state and the same damping matrix (the force integral is
    off: it carries the switching controller's history)."""
    damping = {"translational_damping_ns_per_m": (60.0,) * 3, "rotational_damping_nms_per_rad": (1.0,) * 3}
    gains = ControllerGains(force_ki=0.0, **(damping if explicit_damping else {}))
    Rs = Rotation.random(4, random_state=5).as_matrix()
    state = _state()
    wrench = np.array([1.0, -2.0, 8.0, 0.1, 0.0, -0.1])
    switching = HybridController(gains=gains)
    series = switching.frames(Rs, SELECTION_CONTACT)
    for k in range(len(series)):
        got = _call(switching, series[k], state, wrench=wrench, desired_force=10.0)
        alone = HybridController(gains=gains)
        alone.model.damping_matrix_a = (
            None if switching.model.damping_matrix_a is None else switching.model.damping_matrix_a.copy()
        )
        expected = _call(alone, alone.frame(Rs[k], SELECTION_CONTACT), state, wrench=wrench, desired_force=10.0)
        np.testing.assert_allclose(got.tau, expected.tau, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got.wrench_motion, expected.wrench_motion, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got.wrench_force, expected.wrench_force, rtol=1e-9, atol=1e-9)
