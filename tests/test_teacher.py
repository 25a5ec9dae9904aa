"""The scripted teacher: each scenario records a valid demonstration whose force and geometry match the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas.demonstration import Demonstration
from sim_worker.geometry import WorldGeometry
from sim_worker.teacher import SCENARIOS, TeacherRecording, record_demonstration

_CACHE: dict[str, TeacherRecording] = {}


def _recording(scenario: str) -> TeacherRecording:
    if scenario not in _CACHE:
        _CACHE[scenario] = record_demonstration(scenario, seed=0)
    return _CACHE[scenario]


def _core(rec: TeacherRecording) -> np.ndarray:
    """Samples of the contact phase without the force ramps at its ends (and, for two planes, the crease)."""
    t = np.asarray(rec.demonstration.t)
    ((t_on, t_off),) = rec.contact_intervals
    core = (t > t_on + rec.params.ramp_up_s + 0.1) & (t < t_off - rec.params.ramp_down_s - 0.1)
    for a, b in zip(rec.segments[1:-2], rec.segments[2:-1], strict=True):  # boundaries between contact segments
        core &= np.abs(t - 0.5 * (a.t_end + b.t_start)) > 0.5
    return core


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_scenario_records_a_valid_demonstration_at_1khz(scenario):
    rec = _recording(scenario)
    demo = rec.demonstration
    again = Demonstration.model_validate_json(demo.model_dump_json())
    assert again.n_samples == demo.n_samples
    assert demo.metadata.source == f"teacher:{scenario}"
    t = np.asarray(demo.t)
    assert 5.0 <= t[-1] - t[0] <= 12.0
    assert np.diff(t) == pytest.approx(1e-3)
    assert rec.skill_type == ("contour" if scenario.startswith("contour") else "slide")
    n = demo.n_samples
    for array in (rec.in_contact, rec.normals_true, rec.force_desired, rec.path_nominal, rec.wrench_true):
        assert len(array) == n
    q = np.asarray(demo.orientations)
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0)  # sign-continuous quaternions
    assert rec.world_config == WorldGeometry(rec.world_config).config


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_contact_force_tracks_the_target_along_the_true_normal(scenario):
    rec = _recording(scenario)
    d = rec.demonstration.arrays()
    core = _core(rec)
    f = d.wrenches[core, :3]
    normals = rec.normals_true[core]
    f_normal = np.einsum("ij,ij->i", f, normals)
    # Mean within 10 % of the target; the force wanders (±20 %) but is not chatter.
    assert f_normal.mean() == pytest.approx(rec.target_force_n, rel=0.10)
    assert 0.02 * rec.target_force_n < f_normal.std() < 0.2 * rec.target_force_n
    # The normal part of the contact force (friction excluded) points along the true normal.
    fn = rec.normal_force_true[core]
    angle = np.degrees(
        np.arccos(np.clip(np.einsum("ij,ij->i", fn / np.linalg.norm(fn, axis=1)[:, None], normals), -1.0, 1.0))
    )
    assert np.percentile(angle, 99) < 2.0
    # The whole force stays inside the friction cone around the true normal (Coulomb friction while sliding).
    total = np.degrees(np.arccos(np.clip(f_normal / np.linalg.norm(f, axis=1), -1.0, 1.0)))
    assert np.percentile(total, 99) < math.degrees(math.atan(rec.world_config.contact.lateral_friction)) + 3.0


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_contact_on_and_off_times_match_the_truth(scenario):
    rec = _recording(scenario)
    d = rec.demonstration.arrays()
    assert len(rec.contact_intervals) == 1  # one contact phase, approach before and retreat after
    ((t_on, t_off),) = rec.contact_intervals
    touching = np.flatnonzero(np.linalg.norm(d.wrenches[:, :3], axis=1) > 1.0)
    assert d.t[touching[0]] == pytest.approx(t_on, abs=0.03)
    assert d.t[touching[-1]] == pytest.approx(t_off, abs=0.12)
    assert np.all(np.linalg.norm(rec.wrench_true[~rec.in_contact, :3], axis=1) == 0.0)
    kinds = [s.kind for s in rec.segments]
    assert kinds[0] == kinds[-1] == "free"
    assert rec.segments[1].t_start == t_on and rec.segments[-2].t_end == t_off
    # Free approach from above and retreat: the tool starts and ends well away from the surface.
    geometry = WorldGeometry(rec.world_config)
    assert geometry.signed_distance(d.positions[0]) > 0.05 and geometry.signed_distance(d.positions[-1]) > 0.05


@pytest.mark.parametrize("scenario", ["slide_flat", "slide_tilted", "slide_two_planes"])
def test_slide_segments_lie_on_their_true_planes(scenario):
    rec = _recording(scenario)
    d = rec.demonstration.arrays()
    slides = rec.contact_segments()
    assert [s.kind for s in slides] == ["slide"] * (2 if scenario == "slide_two_planes" else 1)
    assert len({s.surface for s in slides}) == len(slides)
    for seg in slides:
        inside = (d.t > seg.t_start + 0.6) & (d.t < seg.t_end - 0.6)
        pts = d.positions[inside]
        centred = pts - pts.mean(axis=0)
        _, sv, vt = np.linalg.svd(centred, full_matrices=False)
        normal_fit = vt[2] * np.sign(vt[2] @ seg.normal)
        angle = math.degrees(math.acos(min(1.0, float(normal_fit @ seg.normal))))
        assert angle < 1.0, f"{seg.surface}: plane fit {angle:.2f} deg off the true normal"
        assert sv[1] > 0.1 * sv[0]  # a 2-D path: the plane fit is well conditioned
        assert np.abs(centred @ np.asarray(seg.normal)).max() < 1e-3  # sub-mm off the plane
        extent = np.ptp(pts, axis=0)
        assert np.linalg.norm(extent) > 0.1


@pytest.mark.parametrize(("scenario", "spread_deg"), [("contour_cylinder", 90.0), ("contour_block", 55.0)])
def test_contours_follow_the_curved_surface_with_the_tool_along_the_normal(scenario, spread_deg):
    rec = _recording(scenario)
    d = rec.demonstration.arrays()
    (seg,) = rec.contact_segments()
    assert seg.kind == "contour" and seg.normal is None
    core = _core(rec)
    normals = rec.normals_true[core]
    spread = math.degrees(math.acos(float(np.clip(normals[0] @ normals[-1], -1.0, 1.0))))
    assert spread > spread_deg
    geometry = WorldGeometry(rec.world_config)
    assert np.abs(geometry.signed_distance(d.positions[core])).max() < 1.5e-3  # the tool point rides on the surface
    from skills.quaternions import matrix_from_quaternion

    tool_z = matrix_from_quaternion(d.orientations[core])[:, :, 2]
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", tool_z, normals), -1.0, 1.0)))
    assert tilt.max() < 3.0


def test_same_seed_same_recording_and_overrides_apply():
    a = record_demonstration("slide_flat", seed=1, move_duration_s=2.0, target_force_n=10.0, table_height_m=0.12)
    b = record_demonstration("slide_flat", seed=1, move_duration_s=2.0, target_force_n=10.0, table_height_m=0.12)
    assert a.demonstration.wrenches == b.demonstration.wrenches
    assert a.demonstration.positions == b.demonstration.positions
    assert a.world_config.table.height_m == 0.12 and a.target_force_n == 10.0
    core = _core(a)
    assert np.asarray(a.demonstration.positions)[core, 2].mean() == pytest.approx(0.12, abs=1e-3)
    assert a.ground_truth_dict()["segments"][1]["kind"] == "slide"


def test_unknown_scenarios_and_overrides_are_refused():
    with pytest.raises(ValueError, match="unknown scenario"):
        record_demonstration("polish_the_moon")
    with pytest.raises(TypeError, match="unknown override"):
        record_demonstration("slide_flat", table_colour="red")
