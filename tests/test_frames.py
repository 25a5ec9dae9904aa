"""Invariants of the frame conventions (docs/CONVENTIONS.md): adjoints, eq. (3), Möller-Hughes, quaternions, CF."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from schemas.skill import SELECTION_CONTACT, SELECTION_FREE
from skills.compliant_frames import contour_frames, slide_frame
from skills.frames import (
    adjoint_from_transform,
    force_projector_in_frame,
    matrix_from_axis_angle,
    rotation_from_vectors,
    rotation_vector_from_matrix,
    skew,
    stiffness_in_frame,
    transform_inverse,
    wrench_adjoint_from_transform,
)
from skills.quaternions import (
    matrix_from_quaternion,
    quaternion_exp,
    quaternion_from_matrix,
    quaternion_log,
    quaternion_product,
    quaternions_sign_continuous,
)

RNG = np.random.default_rng(7)
STIFFNESS_CF = np.array([2000.0, 2000.0, 2000.0, 150.0, 150.0, 150.0])


def random_transform() -> tuple[np.ndarray, np.ndarray]:
    return Rotation.random(random_state=RNG.integers(1 << 30)).as_matrix(), RNG.normal(0, 0.3, 3)


def cf_to_ef(R: np.ndarray, p: np.ndarray, wrench_cf: np.ndarray) -> np.ndarray:
    return wrench_adjoint_from_transform(R, p) @ wrench_cf


def test_adjoint_pair_is_dual_and_inverts() -> None:
    R, p = random_transform()
    Ad, Adg = adjoint_from_transform(R, p), wrench_adjoint_from_transform(R, p)
    np.testing.assert_allclose(Adg, np.linalg.inv(Ad).T, atol=1e-12)
    # There and back is the identity.
    np.testing.assert_allclose(adjoint_from_transform(*transform_inverse(R, p)) @ Ad, np.eye(6), atol=1e-12)
    np.testing.assert_allclose(wrench_adjoint_from_transform(*transform_inverse(R, p)) @ Adg, np.eye(6), atol=1e-12)


def test_power_is_frame_invariant() -> None:
    """Twist·wrench (power) is the same in both frames: the adjoints are a consistent pair."""
    R, p = random_transform()
    twist_b, wrench_b = RNG.normal(size=6), RNG.normal(size=6)
    power_a = (adjoint_from_transform(R, p) @ twist_b) @ (wrench_adjoint_from_transform(R, p) @ wrench_b)
    assert power_a == pytest.approx(twist_b @ wrench_b)


def test_wrench_adjoint_moves_a_force_as_physics_says() -> None:
    """A pure force f at B's origin, seen at A's origin, gains the moment p x f."""
    R, p = random_transform()
    f_b = np.array([0.0, 0.0, 10.0])
    wrench_a = wrench_adjoint_from_transform(R, p) @ np.concatenate([f_b, np.zeros(3)])
    np.testing.assert_allclose(wrench_a[:3], R @ f_b, atol=1e-12)
    np.testing.assert_allclose(wrench_a[3:], np.cross(p, R @ f_b), atol=1e-12)


def test_twist_adjoint_moves_an_angular_velocity_as_physics_says() -> None:
    """Twists are (v, ω): a pure rotation ω about B's origin, seen at A's origin, gains the velocity p x (R ω)."""
    R, p = random_transform()
    omega_b = np.array([0.0, 0.0, 2.0])
    twist_a = adjoint_from_transform(R, p) @ np.concatenate([np.zeros(3), omega_b])
    np.testing.assert_allclose(twist_a[3:], R @ omega_b, atol=1e-12)
    np.testing.assert_allclose(twist_a[:3], np.cross(p, R @ omega_b), atol=1e-12)
    # and a pure velocity only rotates
    v_b = np.array([0.3, -0.1, 0.2])
    np.testing.assert_allclose(adjoint_from_transform(R, p) @ np.concatenate([v_b, np.zeros(3)]),
                               np.concatenate([R @ v_b, np.zeros(3)]), atol=1e-12)  # fmt: skip


def test_force_projector_keeps_cf_z_and_removes_cf_x() -> None:
    R, p = random_transform()
    projector = force_projector_in_frame(R, p, SELECTION_CONTACT)
    along_z = cf_to_ef(R, p, np.array([0, 0, 12.0, 0, 0, 0]))
    along_x = cf_to_ef(R, p, np.array([7.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(projector @ along_z, along_z, atol=1e-10)
    np.testing.assert_allclose(projector @ along_x, np.zeros(6), atol=1e-10)
    np.testing.assert_allclose(projector @ projector, projector, atol=1e-10)


def test_cf_z_position_error_produces_no_motion_wrench() -> None:
    R, p = random_transform()
    omega = stiffness_in_frame(R, p, STIFFNESS_CF, SELECTION_CONTACT)
    error_along_cf_z = adjoint_from_transform(R, p) @ np.array([0, 0, 0.01, 0, 0, 0])
    error_along_cf_x = adjoint_from_transform(R, p) @ np.array([0.01, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(omega @ error_along_cf_z, np.zeros(6), atol=1e-10)
    # A CF-x error gives the CF-x stiffness force, expressed in A.
    expected = cf_to_ef(R, p, np.array([STIFFNESS_CF[0] * 0.01, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(omega @ error_along_cf_x, expected, atol=1e-9)


def test_identity_frame_reduces_to_diagonal_stiffness() -> None:
    omega = stiffness_in_frame(np.eye(3), np.zeros(3), STIFFNESS_CF, np.ones(6))
    np.testing.assert_allclose(omega, np.diag(STIFFNESS_CF))


def test_selection_diagonals_contact_and_free() -> None:
    """1 = motion-controlled, 0 = force-controlled: contact frees CF z for force control, free space is all motion."""
    assert SELECTION_CONTACT == [1.0, 1.0, 0.0, 1.0, 1.0, 1.0] and SELECTION_FREE == [1.0] * 6
    R, p = random_transform()
    np.testing.assert_allclose(force_projector_in_frame(R, p, SELECTION_FREE), np.zeros((6, 6)), atol=1e-12)
    Ad, Adg = adjoint_from_transform(R, p), wrench_adjoint_from_transform(R, p)
    full = Adg @ np.diag(STIFFNESS_CF) @ np.linalg.inv(Ad)  # every axis stiff: pure impedance
    np.testing.assert_allclose(stiffness_in_frame(R, p, STIFFNESS_CF, SELECTION_FREE), full, atol=1e-9)
    # contact: the motion and force subspaces split the wrench space (Ω~ + Adg S Adg^-1 = I)
    motion_projector = Adg @ np.diag(SELECTION_CONTACT) @ np.linalg.inv(Adg)
    np.testing.assert_allclose(force_projector_in_frame(R, p, SELECTION_CONTACT) + motion_projector, np.eye(6),
                               atol=1e-10)  # fmt: skip


def test_compliant_frame_z_points_along_the_applied_force() -> None:
    """CF z is along the force the tool applies (into the surface), so the pressing force is a positive CF f_z."""
    rng = np.random.default_rng(5)
    normal_into_surface = np.array([0.2, -0.3, -1.0]) / np.linalg.norm([0.2, -0.3, -1.0])
    R_plane = rotation_from_vectors([0.0, 0.0, 1.0], normal_into_surface)
    s = np.linspace(0.0, 1.0, 400)
    positions = (R_plane @ np.stack([0.2 * s, 0.05 * np.sin(6 * s), 1e-5 * rng.normal(size=s.size)])).T
    forces = 15.0 * normal_into_surface + 0.5 * rng.normal(size=(s.size, 3))  # applied by the tool, world
    fit = slide_frame(positions, forces)
    z = fit.rotation[:, 2]
    assert np.degrees(np.arccos(z @ normal_into_surface)) < 0.5
    assert np.all((forces @ fit.rotation)[:, 2] > 0)  # CF f_z = z . f > 0
    assert fit.rotation[:, 0] @ (positions[-1] - positions[0]) > 0  # x along the motion
    frames = contour_frames(positions, forces, rate_hz=100.0, segment=slice(0, s.size))
    assert np.all(np.einsum("kj,kj->k", forces, frames[:, :, 2]) > 0)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-9)


def test_skew_is_cross_product() -> None:
    a, b = RNG.normal(size=3), RNG.normal(size=3)
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b))


@pytest.mark.parametrize("b", [[0, 0, 1.0], [0.3, -0.2, 0.9], [1.0, 0, 0], [0, 0, -1.0], [1e-7, 0, -1.0]])
def test_rotation_from_vectors_maps_a_to_b(b: list[float]) -> None:
    a = np.array([0.0, 0.0, 1.0])
    R = rotation_from_vectors(a, b)
    # 1e-6: within ~sqrt(eps) of the antipode the closed form is replaced by the exact flip.
    np.testing.assert_allclose(R @ a, np.asarray(b) / np.linalg.norm(b), atol=1e-6)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_rotation_from_vectors_is_minimal_and_continuous() -> None:
    """Minimal: its axis is a x b (nothing turns about b). Continuous: tiny change in b, tiny change in R."""
    a = np.array([0.0, 0.0, 1.0])
    angles = np.linspace(0, 2.5, 500)
    b = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    R = rotation_from_vectors(a, b)
    rotvec = Rotation.from_matrix(R).as_rotvec()
    np.testing.assert_allclose(rotvec[:, [0, 2]], 0.0, atol=1e-9)  # axis along y = a x b
    steps = np.linalg.norm(np.diff(R, axis=0), axis=(1, 2))
    assert steps.max() < 3 * np.median(steps)


def test_quaternion_conventions_are_scalar_last_and_match_scipy() -> None:
    q = Rotation.random(5, random_state=3).as_quat()
    np.testing.assert_allclose(matrix_from_quaternion(q), Rotation.from_quat(q).as_matrix())
    np.testing.assert_allclose(np.abs(quaternion_from_matrix(matrix_from_quaternion(q))), np.abs(q), atol=1e-12)
    p = Rotation.random(5, random_state=4).as_quat()
    np.testing.assert_allclose(
        matrix_from_quaternion(quaternion_product(p, q)),
        Rotation.from_quat(p).as_matrix() @ Rotation.from_quat(q).as_matrix(),
    )
    np.testing.assert_allclose(np.abs(quaternion_exp(quaternion_log(q))), np.abs(q), atol=1e-12)


def test_sign_continuity_flips_only_signs() -> None:
    q = Rotation.from_rotvec(np.outer(np.linspace(0, 3, 100), [0, 0, 1])).as_quat()
    flipped = q * np.where(RNG.random(100) < 0.5, -1.0, 1.0)[:, None]
    continuous = quaternions_sign_continuous(flipped)
    assert np.all(np.sum(continuous[1:] * continuous[:-1], axis=1) > 0)
    np.testing.assert_allclose(continuous, quaternions_sign_continuous(q))


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.3, 2.0, np.pi - 0.1, np.pi - 1e-6])
def test_axis_angle_and_rotation_vector_are_inverse(angle: float) -> None:
    """Rodrigues and its inverse agree with scipy, also next to pi where the closed form loses the axis."""
    axis = RNG.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = matrix_from_axis_angle(axis, angle)
    np.testing.assert_allclose(R, Rotation.from_rotvec(axis * angle).as_matrix(), atol=1e-12)
    r = rotation_vector_from_matrix(R)
    np.testing.assert_allclose(matrix_from_axis_angle(r, np.linalg.norm(r)) if angle > 0 else np.eye(3), R, atol=1e-8)
    assert np.linalg.norm(r) == pytest.approx(angle, abs=1e-7)
