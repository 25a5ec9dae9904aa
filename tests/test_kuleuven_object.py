"""Ground truth of the KU Leuven contours from the object's CAD (``data/kuleuven_contour``: ``contour.STL``,
``contour_edge.mat``): the files load as their README says, the crease the tool rode on is one chain of convex mesh
edges with two faces each, every real trial registers onto it, a known placement is recovered, and the angle of a
direction from a normal cone is right where it can be worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import KULEUVEN_DATA
from scipy.spatial.transform import Rotation

from services.datasets import KULEUVEN_EDGE_MAT, KULEUVEN_OBJECT_STL
from services.kuleuven_object import (
    M_PER_MM,
    KuleuvenGroundTruth,
    kuleuven_ground_truth,
    kuleuven_object,
    mat_polyline,
    stl_triangles,
)
from skills.registration import (
    SHAPE_TIE_M,
    angle_outside_cone,
    angles_about_crease,
    closest_points_on_polyline,
    edge_registrations,
    normal_cones_at,
    polyline_resampled,
    registration_pressed_into,
)

TRIALS = ("contour_a_1", "contour_a_2", "contour_b_1", "contour_b_2")
RMS_BOUND_M = 0.0015
"""Measured RMS distance of a trial's path to the registered crease: 0.79-1.18 mm (docs/LEARNING.md)."""
MAX_BOUND_M = 0.005
"""Measured largest distance of a trial's path to the registered crease: 2.3-4.0 mm."""


@pytest.fixture(scope="module")
def truths() -> dict[str, KuleuvenGroundTruth]:
    return {trial: kuleuven_ground_truth(KULEUVEN_DATA / f"{trial}.csv") for trial in TRIALS}


def _rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.acos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0))


def test_the_cad_files_hold_what_the_readme_says():
    triangles = stl_triangles(KULEUVEN_DATA / KULEUVEN_OBJECT_STL)
    assert triangles.shape == (1770, 3, 3)
    corners = triangles.reshape(-1, 3)
    # 540 x 173 x 60 mm nominal; the crease dips 1.4 mm below the z = 0 plane, so the box is 61.4 mm high.
    np.testing.assert_allclose(np.ptp(corners, axis=0), [540.0, 173.0, 61.42], atol=0.01)
    edge = mat_polyline(KULEUVEN_DATA / KULEUVEN_EDGE_MAT, "contour_edge")
    assert edge.shape == (101, 3)
    assert np.ptp(edge[:, 0]) == pytest.approx(508.3, abs=0.1)  # over 508 mm ...
    assert np.ptp(edge[:, 1]) == pytest.approx(69.4, abs=0.1)  # ... a 69 mm deep arc ...
    assert np.abs(edge[:, 2]).max() < 1.31  # ... in one plane (z within ±1.3 mm)

    contour = kuleuven_object()
    mesh = contour.mesh
    np.testing.assert_allclose(mesh.vertices.reshape(-1, 3).min(axis=0), corners.min(axis=0) * M_PER_MM)
    assert mesh.signed_volume > 0.0  # wound outward
    edges = np.sort(np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert set(count.tolist()) == {2}  # closed: every mesh edge joins exactly two faces


def test_an_ascii_stl_is_refused(tmp_path):
    path = tmp_path / "ascii.stl"
    path.write_text("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
                    "endfacet\nendsolid x\n")  # fmt: skip
    with pytest.raises(ValueError, match="ASCII"):
        stl_triangles(path)


def test_the_crease_is_one_chain_of_convex_edges_between_the_two_folded_faces():
    contour = kuleuven_object()
    crease, mesh = contour.crease, contour.mesh
    assert len(crease.faces) == 50 and len(crease.points) == 51
    for k, (a, b) in enumerate(crease.faces):
        ends = {tuple(crease.points[k]), tuple(crease.points[k + 1])}
        # both faces hold the segment, and they are two different triangles
        assert a != b
        assert ends <= {tuple(v) for v in mesh.vertices[mesh.faces[a]]}
        assert ends <= {tuple(v) for v in mesh.vertices[mesh.faces[b]]}
    np.testing.assert_allclose(crease.outward, mesh.outward_normals[crease.faces])
    # a folded sheet: the faces meet at ~90° all along (85-97° on the faceted mesh)
    assert np.degrees(crease.openings_rad).min() > 84.0 and np.degrees(crease.openings_rad).max() < 98.0
    # one labelling all along: face a x face b along the crease; at the first segment face a is the CAD's
    # y = 0 face (outward -y), face b the z = 0 face, the plane the edge lies in (outward -z)
    direction = np.diff(crease.points, axis=0)
    assert np.all(np.sum(np.cross(crease.outward[:, 0], crease.outward[:, 1]) * direction, axis=1) > 0)
    np.testing.assert_allclose(crease.outward[0], [[0, -1, 0], [0, 0, -1]], atol=1e-4)
    steps = np.sum(crease.outward[1:] * crease.outward[:-1], axis=2)
    assert np.degrees(np.arccos(np.clip(steps, -1, 1))).max() < 11.0  # facets, no jump to another face
    # the crease follows the authors' edge within a few mm
    along = polyline_resampled(crease.points, 0.001)
    assert np.abs(along[:, 2]).max() < 0.002


@pytest.mark.parametrize("trial", TRIALS)
def test_every_trial_registers_onto_the_crease_and_the_force_presses_into_it(truths, trial):
    truth = truths[trial]
    registration = truth.registration
    assert registration.rms_distance_m < RMS_BOUND_M
    assert registration.max_distance_m < MAX_BOUND_M
    np.testing.assert_allclose(registration.rotation @ registration.rotation.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(registration.rotation) == pytest.approx(1.0)
    # the shape alone leaves two placements half a turn apart (the edge's symmetry); the force tells them apart
    assert len(truth.candidates) == 2
    assert truth.candidates[1].rms_distance_m - truth.candidates[0].rms_distance_m < SHAPE_TIE_M
    assert registration is truth.candidates[0]
    assert np.degrees(truth.candidate_bisector_angles_rad).tolist() == [
        pytest.approx(6.0, abs=2.0),
        pytest.approx(122.0, abs=8.0),
    ]
    # the cone at every imported sample, and the same cone through the public evaluation at any positions
    positions = truth.demonstration.arrays().positions
    assert len(truth.cone.inward_a) == len(positions)
    assert np.all(truth.cone.distances_m < MAX_BOUND_M)
    again = truth.cones_at(positions[::7])
    np.testing.assert_array_equal(again.faces, truth.cone.faces[::7])
    np.testing.assert_allclose(again.bisectors, truth.cone.bisectors[::7])


def test_the_normal_cone_turns_along_the_path_as_the_readme_says(truths):
    for truth in truths.values():
        bisectors = truth.cone.bisectors
        turn = np.degrees(np.arccos(np.clip(bisectors @ bisectors.T, -1.0, 1.0)).max())
        assert turn == pytest.approx(45.0, abs=3.0)  # measured 46.4°
        assert np.degrees(np.median(truth.cone.openings_rad)) == pytest.approx(90.0, abs=1.0)
        # the applied force (friction along the crease ignored) lies in the cone at every sample
        forces = truth.demonstration.arrays().wrenches[:, :3]
        assert angle_outside_cone(forces, truth.cone.inward_a, truth.cone.inward_b).max() == 0.0


def test_trials_b_share_one_placement_and_register_alike(truths):
    """contour_b_2's path lies on contour_b_1's (median 0.9 mm, at most 4.4 mm away): the object did not move between
    them, and their registrations agree (the registration's repeatability)."""
    b1_path, b2_path = (truths[t].demonstration.arrays().positions for t in ("contour_b_1", "contour_b_2"))
    apart = closest_points_on_polyline(b2_path, b1_path).distances
    assert np.median(apart) < 0.0015 and apart.max() < 0.005
    b1, b2 = truths["contour_b_1"].registration, truths["contour_b_2"].registration
    crease = kuleuven_object().crease.points
    assert math.degrees(_rotation_angle(b1.rotation, b2.rotation)) < 1.5  # measured 0.69°
    assert np.linalg.norm(b1.to_world(crease) - b2.to_world(crease), axis=1).max() < 0.003  # measured 1.3 mm


def test_a_placement_moves_the_registered_object_with_the_skill(truths):
    """A skill placed in the robot's reach by ``x_robot = R x + t`` finds the object moved alike: the crease where the
    placement puts the recording's crease, and the normal cones at the placed path turned by ``R``."""
    truth = truths["contour_a_1"]
    R = Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix()
    t = np.array([0.9, -1.7, 1.2])
    placed = truth.placed_registration(R, t)
    crease = truth.kuleuven_object.crease
    np.testing.assert_allclose(placed.to_world(crease.points), truth.registration.to_world(crease.points) @ R.T + t)
    path = truth.demonstration.arrays().positions[::50]
    cones = normal_cones_at(path @ R.T + t, crease, placed)
    np.testing.assert_allclose(cones.bisectors, truth.cones_at(path).bisectors @ R.T, atol=1e-12)
    assert placed.rms_distance_m == truth.registration.rms_distance_m


@pytest.mark.parametrize("seed", [3, 11])
def test_registration_recovers_a_known_placement_of_the_edge(seed):
    rng = np.random.default_rng(seed)
    contour = kuleuven_object()
    R = Rotation.random(random_state=seed).as_matrix()
    p = rng.normal(0.0, 1.0, 3)
    cad = polyline_resampled(contour.edge, 0.0005)
    noise_m = 0.0005
    path = cad @ R.T + p + rng.normal(0.0, noise_m, cad.shape)
    candidates = edge_registrations(path, contour.edge)
    best = candidates[0]
    assert math.degrees(_rotation_angle(best.rotation, R)) < 0.2  # measured < 0.06°
    assert np.linalg.norm(best.to_world(cad) - (cad @ R.T + p), axis=1).max() < 0.0005  # measured < 0.11 mm
    assert best.rms_distance_m == pytest.approx(math.sqrt(2.0) * noise_m, rel=0.1)  # the noise across the edge
    # the half-turn twin fits almost as well; a force pressing into the true crease picks the truth, one pressing
    # into the twin's picks the twin
    assert len(candidates) == 2 and candidates[1].rms_distance_m < best.rms_distance_m + SHAPE_TIE_M
    crease = contour.crease
    for truth in candidates:
        forces = 15.0 * normal_cones_at(path, crease, truth).bisectors + rng.normal(0.0, 1.0, path.shape)
        assert registration_pressed_into(candidates, crease, path, forces) is truth


def _turned(vectors: np.ndarray, angle_deg: float) -> np.ndarray:
    """``vectors`` turned about z by ``angle_deg``."""
    return vectors @ Rotation.from_euler("z", angle_deg, degrees=True).as_matrix().T


def test_angle_outside_cone_is_zero_inside_and_the_angle_to_the_nearer_face_outside():
    n_a, n_b = np.array([1.0, 0.0, 0.0]), _turned(np.array([1.0, 0.0, 0.0]), 60.0)  # a 60° cone, tangent +z
    x = np.array([1.0, 0.0, 0.0])
    cases = {  # direction: (angle outside, angle about the crease from n_a), deg
        tuple(_turned(x, 30.0)): (0.0, 30.0),  # the bisector
        tuple(_turned(x, 59.0)): (0.0, 59.0),
        tuple(_turned(x, 10.0) * 3.0 + np.array([0.0, 0.0, 20.0])): (0.0, 10.0),  # friction along the crease is free
        (0.0, 0.0, 1.0): (0.0, 0.0),  # along the crease only: no angle across it
        tuple(_turned(x, -20.0)): (20.0, -20.0),  # beyond face a
        tuple(_turned(x, 75.0)): (15.0, 75.0),  # beyond face b
        tuple(_turned(x, 75.0) + np.array([0.0, 0.0, 5.0])): (15.0, 75.0),  # ... whatever the friction along the crease
        tuple(_turned(x, 200.0)): (140.0, -160.0),  # pulling off: nearer to face b (140°) than to face a (160°)
        tuple(_turned(x, -150.0)): (150.0, -150.0),
    }
    directions = np.array(list(cases))
    expected = np.radians(np.array(list(cases.values())))
    n_a_rows, n_b_rows = np.tile(n_a, (len(directions), 1)), np.tile(n_b, (len(directions), 1))
    np.testing.assert_allclose(angle_outside_cone(directions, n_a_rows, n_b_rows), expected[:, 0], atol=1e-12)
    np.testing.assert_allclose(angles_about_crease(directions, n_a_rows, n_b_rows), expected[:, 1], atol=1e-12)
    # the same in any frame
    turn = Rotation.random(random_state=5).as_matrix()
    np.testing.assert_allclose(
        angle_outside_cone(directions @ turn.T, n_a_rows @ turn.T, n_b_rows @ turn.T), expected[:, 0], atol=1e-12
    )
    with pytest.raises(ValueError, match="parallel"):
        angle_outside_cone(directions[:1], n_a[None], n_a[None])
