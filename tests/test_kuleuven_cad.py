"""The KU Leuven object's CAD as the simulator holds it (``sim_worker/cad_work_piece.py``), and a KU Leuven skill
executed on it (``experiments/kuleuven_cad.py``): the convex pieces lie on the STL's faces, the world built for a
placed skill puts them where the registration and the placement put the object, and the skill holds its force on the
true crease."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import KULEUVEN_DATA
from scipy.spatial import ConvexHull

from experiments.kuleuven_cad import (
    LATERAL_STIFFNESS_N_PER_M,
    cad_world,
    on_face_share,
    placed_object,
    stl_fit,
)
from schemas import ExecutionSettings
from schemas.execution import Placement
from schemas.world import WorldConfig
from services.kuleuven_object import KuleuvenGroundTruth, kuleuven_ground_truth
from sim_worker.cad_work_piece import CONVEX_MARGIN_M
from sim_worker.execution_world import execution_world
from sim_worker.executor import run_skill
from skills.parameterize import learn_skill
from skills.registration import polyline_resampled

TRUE_RMS_BOUND_PCT = 5.0
"""Measured true force RMS of contour_a_1 on the CAD with the CF x-y stiffness at 6000 N/m: 3.0 % (2.7-3.3 % with
other piece sizes; the rebuilt work piece: 4.5 %)."""
TRUE_MAX_BOUND_PCT = 25.0
"""Measured largest true force error of the same execution: 12.8 %."""
ON_FACE_BOUND = 0.02
"""Measured share of its pressing steps with the ball on one face of the crease: 0 % (11.5 % with the default
3000 N/m, where the ball rolls off the crease)."""


@pytest.fixture(scope="module")
def truth() -> KuleuvenGroundTruth:
    return kuleuven_ground_truth(KULEUVEN_DATA / "contour_a_1.csv")


def test_the_pieces_lie_on_the_stl_faces_where_the_ball_touches(truth):
    """Points spread over the STL's two faces of the crease lie on the pieces' surface as PyBullet holds it (faces
    out by the margin): within 0.5 mm where the ball rides (2 mm of the crease; measured 0.41 mm, RMS 0.08 mm) and
    1 mm over the whole band the crease's pieces hold (15 mm; measured 0.74 mm where a hull bridges the STL's concave
    folds)."""
    distance, signed = stl_fit(truth)
    near, band = distance < 0.002, distance < 0.015
    assert near.sum() > 500 and band.sum() > 4000
    assert np.abs(signed[near]).max() < 5e-4
    assert np.sqrt(np.mean(signed[near] ** 2)) < 1.5e-4
    assert np.abs(signed[band]).max() < 1e-3


def test_the_world_puts_the_object_where_registration_and_placement_put_it(truth):
    """The crease (every 2 mm of it) placed by the registration and a placement lies on the surface of the world's
    pieces: inside no piece, and within the margin's rounding (0.41 mm for a 90° crease) of their faces."""
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    placement = Placement(translation_m=[0.3, -1.2, 0.9], rotation=[0.0, 0.0, 0.7071067811865476, 0.7071067811865476])
    world = WorldConfig.from_dict(cad_world(truth, placement))
    assert not world.table.enabled
    crease = polyline_resampled(truth.kuleuven_object.crease.points, 0.002)
    where = placed_object(truth, placement)
    np.testing.assert_allclose(where.rotation, turn @ truth.registration.rotation, atol=1e-12)
    points = where.to_world(crease)
    heights = np.full(len(points), np.inf)
    for piece in world.work_pieces:
        equations = ConvexHull(np.asarray(piece.vertices)).equations
        heights = np.minimum(heights, np.max(points @ equations[:, :3].T + equations[:, 3], axis=1))
    # Each piece is its part of the object shrunk by the margin: the crease lies margin-far outside the pieces' faces.
    np.testing.assert_allclose(heights, CONVEX_MARGIN_M, atol=5e-4)


def test_a_real_skill_holds_its_force_on_the_true_crease(truth):
    """contour_a_1, learned and placed as every real recording is, runs with ``hybrid_cf`` and the wrist sensor on
    the CAD where the placement puts it, the CF x-y stiffness above force / ball radius: in contact throughout, the
    true normal force within the bounds measured, the ball on the crease (not rolled onto a face)."""
    skill = learn_skill(truth.demonstration)
    rebuilt = execution_world(skill, ExecutionSettings().environment)
    settings = ExecutionSettings(
        gains={"translational_stiffness_n_per_m": [LATERAL_STIFFNESS_N_PER_M, LATERAL_STIFFNESS_N_PER_M, 3000.0]}
    )
    world = execution_world(rebuilt.skill, settings.environment, world=cad_world(truth, rebuilt.placement))
    result = run_skill(world, settings)
    m = result.metrics
    assert m.phase.value == "done", m.abort_reason
    assert m.contact_ratio >= 0.95
    assert m.true_force_rms_error_pct < TRUE_RMS_BOUND_PCT
    assert m.true_force_max_error_pct < TRUE_MAX_BOUND_PCT
    share = on_face_share(result.telemetry, placed_object(truth, rebuilt.placement), truth, world.config.tool.radius_m)
    assert share < ON_FACE_BOUND
