"""Teacher demonstration -> learned skill -> execution in PyBullet with the hybrid controller.

Real physics at 1 kHz; every test asserts the force the controller actually produced (the
simulator's contact wrench along the CF z axis), not just that the run finished. The learned
skills (default learning options) are cached per module.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from execution.telemetry import Telemetry
from schemas.execution import (
    ControllerGains,
    ControllerKind,
    EnvironmentChange,
    ExecutionMetrics,
    ExecutionPhase,
    ExecutionSettings,
)
from schemas.skill import LearnOptions, SegmentKind
from sim_worker.executor import ExecutionResult, execute_skill
from sim_worker.teacher import record_demonstration
from skills.parameterize import learn_skill
from skills.quaternions import matrix_from_quaternion


def _learn(scenario: str, skill_type: str):
    recording = record_demonstration(scenario, seed=0)
    skill = learn_skill(recording.demonstration, LearnOptions(skill_type=skill_type))
    return recording, skill


@pytest.fixture(scope="module")
def slide_flat():
    return _learn("slide_flat", "slide")


@pytest.fixture(scope="module")
def slide_tilted():
    return _learn("slide_tilted", "slide")


@pytest.fixture(scope="module")
def contour_cylinder():
    return _learn("contour_cylinder", "contour")


@pytest.fixture(scope="module")
def slide_two_planes():
    return _learn("slide_two_planes", "slide")


def _run(
    learned,
    controller: ControllerKind = ControllerKind.hybrid_cf,
    offset=(0.0, 0.0, 0.0),
    unknown_offset=(0.0, 0.0, 0.0),
    **settings,
) -> ExecutionResult:
    recording, skill = learned
    request = ExecutionSettings(
        controller=controller,
        environment=EnvironmentChange(offset=list(offset), unknown_offset=list(unknown_offset)),
        pace="fast",
        **settings,
    )
    return execute_skill(skill, recording.world_config, request, demonstration=recording.demonstration)


def _contact_segment(skill):
    [segment] = [s for s in skill.segments if s.kind is SegmentKind.contact]
    return segment


def _steady_cf_z_force(result: ExecutionResult) -> np.ndarray:
    """The measured CF-z force over the steady contact phase (from 0.25 s after contact starts)."""
    tel = result.telemetry
    contact = np.array([p is ExecutionPhase.contact for p in tel.phases])
    t0 = tel.t[contact][0]
    return tel.wrench_cf[contact & (tel.t >= t0 + 0.25), 2]


def _assert_clean(result: ExecutionResult) -> None:
    assert np.all(np.isfinite(result.telemetry.data))
    for name, value in result.metrics.model_dump().items():
        if isinstance(value, float):
            assert math.isfinite(value), name


@pytest.mark.parametrize("dz", [-0.03, 0.0, 0.03])
def test_slide_on_a_table_with_unknown_height(slide_flat, dz: float) -> None:
    recording, skill = slide_flat
    segment = _contact_segment(skill)
    result = _run(slide_flat, unknown_offset=(0.0, 0.0, dz))
    m = result.metrics
    _assert_clean(result)
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.force_rms_error_pct < 5.0
    assert m.contact_ratio >= 0.99
    assert m.path_rms_m < 0.003
    # the guarded approach found the table where it really is (CF z points down, into it)
    [found] = m.contact_found_offsets_m
    assert found == pytest.approx(-dz, abs=0.002)
    # the force the controller produced: the learned constant (which is the teacher's 15 N)
    assert segment.force_constant_n == pytest.approx(recording.target_force_n, rel=0.03)
    f = _steady_cf_z_force(result)
    assert np.mean(f) == pytest.approx(segment.force_constant_n, rel=0.02)
    assert m.peak_force_n < 1.3 * segment.force_constant_n


def test_slide_on_a_tilted_plane_beats_both_baselines(slide_tilted) -> None:
    _, skill = slide_tilted
    segment = _contact_segment(skill)
    normal = matrix_from_quaternion(segment.compliant_frames.orientations[0])[:, 2]
    assert math.degrees(math.acos(-normal[2])) == pytest.approx(15.0, abs=1.0)
    results = {kind: _run(slide_tilted, controller=kind) for kind in ControllerKind}
    ours = results[ControllerKind.hybrid_cf].metrics
    assert ours.phase is ExecutionPhase.done, ours.abort_reason
    assert ours.force_rms_error_pct < 5.0
    assert ours.contact_ratio >= 0.99
    assert ours.path_rms_m < 0.003
    assert np.mean(_steady_cf_z_force(results[ControllerKind.hybrid_cf])) == pytest.approx(
        segment.force_constant_n, rel=0.02
    )
    world_z = results[ControllerKind.hybrid_world_z].metrics
    impedance = results[ControllerKind.impedance].metrics
    for baseline in (world_z, impedance):
        assert baseline.phase is ExecutionPhase.done, baseline.abort_reason
    # force along world z presses 1/cos(15°) too hard into the slope and its x-y impedance fights
    # the normal force's horizontal part; the impedance has no force loop
    assert world_z.force_rms_error_n > 3.0 * ours.force_rms_error_n
    assert world_z.force_rms_error_pct > 5.0
    assert impedance.force_rms_error_n > 1.2 * ours.force_rms_error_n


def test_impedance_baseline_cannot_handle_an_unknown_height(slide_tilted) -> None:
    ours = _run(slide_tilted, unknown_offset=(0.0, 0.0, 0.01)).metrics
    impedance = _run(slide_tilted, controller=ControllerKind.impedance, unknown_offset=(0.0, 0.0, 0.01)).metrics
    assert ours.phase is ExecutionPhase.done and ours.force_rms_error_pct < 5.0
    assert ours.contact_ratio >= 0.99
    # 1 cm deeper than taught at 3000 N/m: the reference presses ~30 N too hard
    assert impedance.force_rms_error_pct > 100.0
    # the fair classical baseline: the same law re-based where the guarded approach found the surface
    found = _run(
        slide_tilted, controller=ControllerKind.impedance_found_surface, unknown_offset=(0.0, 0.0, 0.01)
    ).metrics
    assert found.phase is ExecutionPhase.done and found.contact_ratio >= 0.99
    assert found.true_force_rms_error_pct < 10.0
    assert found.true_force_rms_error_pct > ours.true_force_rms_error_pct


@pytest.mark.parametrize("offset", [(0.02, 0.0, 0.0), (0.0, 0.02, 0.0)])
def test_contour_on_a_shifted_cylinder(contour_cylinder, offset) -> None:
    recording, skill = contour_cylinder
    result = _run(contour_cylinder, offset=offset)
    m = result.metrics
    _assert_clean(result)
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.force_rms_error_pct < 10.0
    assert m.contact_ratio >= 0.98
    assert m.path_rms_m < 0.003
    # the whole contact path moved with the cylinder
    tel = result.telemetry
    contact = np.array([p is ExecutionPhase.contact for p in tel.phases])
    demo = recording.demonstration.arrays()
    segment = _contact_segment(skill)
    in_demo = (demo.t >= segment.t_start) & (demo.t <= segment.t_end)
    shift = tel.tool_position[contact].mean(axis=0) - demo.positions[in_demo].mean(axis=0)
    np.testing.assert_allclose(shift, offset, atol=0.003)
    # the produced force follows the learned profile (desired = force DMP, 4-15 N along the way)
    desired = tel.desired_force[contact]
    assert desired.max() - desired.min() > 3.0
    assert m.force_reference_n == pytest.approx(desired.max(), rel=0.05)


def test_a_raised_table_is_found_by_the_guarded_approach_not_hit(slide_flat) -> None:
    _, skill = slide_flat
    target = _contact_segment(skill).force_constant_n
    result = _run(slide_flat, unknown_offset=(0.0, 0.0, 0.05))
    m = result.metrics
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.peak_force_n < 2.0 * target
    assert m.contact_found_offsets_m[0] == pytest.approx(-0.05, abs=0.002)
    # no contact before the guarded approach: the free motion stopped above the raised table
    tel = result.telemetry
    free = np.array([p in (ExecutionPhase.settle, ExecutionPhase.free) for p in tel.phases])
    first_contact = np.flatnonzero(tel.in_contact)[0]
    assert not tel.in_contact[free & (np.arange(len(tel)) < first_contact)].any()
    assert tel.phases[first_contact] is ExecutionPhase.approach
    assert m.force_rms_error_pct < 5.0


def test_force_limit_aborts_with_a_reason_and_no_nan(slide_flat) -> None:
    result = _run(slide_flat, gains=ControllerGains(max_force_n=10.0))
    m = result.metrics
    assert m.phase is ExecutionPhase.aborted
    assert m.abort_reason is not None and m.abort_reason.startswith("force limit")
    _assert_clean(result)
    assert 10.0 < m.peak_force_n < 12.0  # stopped on the first step above the limit


def test_contact_not_found_aborts(slide_flat) -> None:
    result = _run(slide_flat, unknown_offset=(0.0, 0.0, -0.06), approach_max_distance_m=0.08)
    m = result.metrics
    assert m.phase is ExecutionPhase.aborted
    assert m.abort_reason is not None and m.abort_reason.startswith("contact not found")
    assert m.peak_force_n == 0.0
    _assert_clean(result)


def test_telemetry_batches_and_abort_on_request(slide_flat) -> None:
    batches: list[Telemetry] = []
    polls = {"n": 0}

    def should_abort() -> bool:
        polls["n"] += 1
        return polls["n"] >= 1500  # polled after every control step: the 1500th step is the last

    recording, skill = slide_flat
    result = execute_skill(
        skill,
        recording.world_config,
        ExecutionSettings(telemetry_batch=50),
        on_sample=batches.append,
        should_abort=should_abort,
    )
    assert result.metrics.phase is ExecutionPhase.aborted
    assert result.metrics.abort_reason == "aborted on request"
    assert result.metrics.steps == 1500
    assert result.metrics.duration_s == pytest.approx(1.5)
    assert all(len(b) == 50 for b in batches)
    np.testing.assert_array_equal(np.concatenate([b.data for b in batches]), result.telemetry.data)
    payload = batches[0].to_batch("exec-1")
    assert len(payload.t) == 50 and payload.phase[0] is ExecutionPhase.settle


def test_a_joint_limit_aborts_with_a_reason(slide_flat, monkeypatch) -> None:
    """PyBullet does not enforce joint limits in torque mode: the executor does."""
    import sim_worker.executor as executor

    class NarrowBaseJoint(executor.SimWorld):
        def __init__(self, config) -> None:
            super().__init__(config)
            self.joint_upper = self.joint_upper.copy()
            self.joint_upper[0] = 0.1  # the S-curve turns the base from about -0.22 to +0.22 rad

    monkeypatch.setattr(executor, "SimWorld", NarrowBaseJoint)
    result = _run(slide_flat)
    m = result.metrics
    assert m.phase is ExecutionPhase.aborted
    assert m.abort_reason is not None and m.abort_reason.startswith("joint limit: joint 1")
    _assert_clean(result)


def test_cli_simulate_prints_metrics_and_writes_the_figure(slide_flat, tmp_path, capsys) -> None:
    from cli.main import main

    _, skill = slide_flat
    skill_file = tmp_path / "skill.json"
    skill_file.write_text(skill.model_dump_json())
    figure = tmp_path / "force.png"
    metrics_file = tmp_path / "metrics.json"
    code = main(
        ["simulate", str(skill_file), "--unknown-offset", "0", "0", "0.02", "--figure", str(figure),
         "--json", str(metrics_file)]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert "controller hybrid_cf: done" in out
    assert "guarded approach: surface found -20." in out  # the table 2 cm higher, found along CF z (down)
    assert "verdict: pass (7 checks)" in out
    assert figure.stat().st_size > 10_000
    # Met 7.5 cm early by the free segment, a stiff table: it runs to the end, its verdict fails (exit 4) and says why.
    stiff = ["--unknown-offset", "0", "0", "0.075", "--contact-stiffness", "3e5"]
    assert main(["simulate", str(skill_file), *stiff]) == 4
    out = capsys.readouterr().out
    assert "controller hybrid_cf: done" in out and "verdict: FAIL\n  - touch-down peak / target" in out
    assert "WARNING: surface found -75." in out
    metrics = ExecutionMetrics.model_validate_json(metrics_file.read_text())
    assert metrics.force_rms_error_pct < 5.0
    # a skill without its taught world (a real recording) runs on the work piece rebuilt from it
    real = skill.model_copy(update={"taught_world": None})
    skill_file.write_text(real.model_dump_json())
    assert main(["simulate", str(skill_file)]) == 0
    assert "work piece: rebuilt from the skill" in capsys.readouterr().out
    assert main(["simulate", str(skill_file), "--work-piece", "taught"]) == 2
    assert "environment.work_piece: the skill carries no taught world" in capsys.readouterr().err
    assert main(["simulate", str(skill_file), "--placement", "1", "2"]) == 2
    assert "placement: give 3, 4 or 7 numbers" in capsys.readouterr().err


@functools.cache
def _flat_skill_pressing(target_n: float):
    return learn_skill(record_demonstration("slide_flat", seed=0, target_force_n=target_n).demonstration)


@pytest.mark.parametrize(
    ("target_n", "stiffness", "damping"), [(5.0, 3e4, 300.0), (5.0, 1e6, 300.0), (30.0, 1e6, 300.0), (5.0, 1e4, 1e3)]
)
def test_touch_down_stays_within_20_percent_of_the_target_on_soft_and_stiff_surfaces(
    target_n, stiffness, damping
) -> None:
    """The touch-down speed follows from the target and the contact stiffness (a 3 cm/s approach would peak at 13 N
    for a 5 N skill on the pad and at 70 N on a 1e6 N/m surface) and its damping where that dominates (a soft, heavily
    damped pad: from the stiffness alone the damper's c·v gave 2-6x the target in the sweeps); judged by the TRUE
    normal force."""
    from sim_worker.execution_world import execution_world
    from sim_worker.executor import run_skill

    skill = _flat_skill_pressing(target_n)
    pad = {"contact_stiffness_n_m": stiffness, "contact_damping_n_s_m": damping}
    settings = ExecutionSettings(environment={**pad, "unknown_offset": [0, 0, -0.01]})
    metrics = run_skill(execution_world(skill, settings.environment), settings).metrics
    assert metrics.phase is ExecutionPhase.done, metrics.abort_reason
    assert metrics.touchdown_peak_ratio <= 1.2, metrics.touchdown_peak_n
    assert metrics.true_force_rms_error_pct < 5.0 and metrics.settle_time_s < 0.5


def test_the_touch_down_is_planned_for_the_pad_the_cell_believes_in() -> None:
    """A 5 N slide on a soft, heavily damped pad (1e4 N/m, 1000 N·s/m): planned for that pad it touches down within
    20 % of the target; planned for the nominal pad (3e4 N/m, 300 N·s/m, what a sweep's cell believes) it comes in
    too fast and the damper's c·v overshoots: the pad is unknown to the controller then, as in a real cell."""
    from sim_worker.execution_world import execution_world
    from sim_worker.executor import run_skill

    skill = _flat_skill_pressing(5.0)
    pad = {"contact_stiffness_n_m": 1e4, "contact_damping_n_s_m": 1e3, "unknown_offset": [0, 0, -0.01]}
    peaks = {}
    for planned in ({}, {"planned_contact_stiffness_n_m": 3e4, "planned_contact_damping_n_s_m": 300.0}):
        settings = ExecutionSettings(environment=pad, **planned)
        metrics = run_skill(execution_world(skill, settings.environment), settings).metrics
        assert metrics.phase is ExecutionPhase.done, metrics.abort_reason
        peaks[bool(planned)] = metrics.touchdown_peak_ratio
    assert peaks[False] <= 1.2 and peaks[True] > 1.4, peaks


@pytest.mark.parametrize(("stiffness", "damping"), [(1e6, 300.0), (1e4, 1e3)])
def test_a_profile_starting_under_the_contact_threshold_still_touches_down_gently(
    contour_cylinder, stiffness, damping
) -> None:
    """The contour's force profile starts at 0.9 N, under the contact threshold (10 % of its peak, 1.4 N) that the
    approach has to pass anyway: the touch-down speed budgets that threshold's impact instead of 0.8 x 0.9 N (which
    crawled at 0.5 mm/s on a stiff surface). The faster touch-down must not overshoot: the TRUE normal force peaks
    within 20 % of the target on a stiff surface and on a soft, heavily damped pad."""
    from sim_worker.execution_world import execution_world
    from sim_worker.executor import run_skill

    _, skill = contour_cylinder
    first = next(segment for segment in skill.segments if segment.kind is SegmentKind.contact)
    assert first.force_dmp is not None and first.force_dmp.start[0] < 1.0  # the case this test is about
    environment = {"contact_stiffness_n_m": stiffness, "contact_damping_n_s_m": damping}
    settings = ExecutionSettings(environment=environment)
    metrics = run_skill(execution_world(skill, settings.environment), settings).metrics
    assert metrics.phase is ExecutionPhase.done, metrics.abort_reason
    assert metrics.touchdown_peak_ratio <= 1.2, metrics.touchdown_peak_n
    assert metrics.contact_ratio >= 0.99


def test_a_path_that_runs_off_the_table_stops_pressing_into_nothing(slide_flat) -> None:
    """The table moved 45 cm sideways without telling the controller: the stroke starts on it and runs off its edge.
    The tool may not chase the lost surface (it went 31 cm below the table top before): it stops within the travel
    bound, retracts and the execution aborts naming the loss."""
    from sim_worker.control_loop import CONTACT_LOSS_TRAVEL_M

    recording, _ = slide_flat
    result = _run(slide_flat, unknown_offset=(0.0, -0.45, 0.0))
    assert result.metrics.phase is ExecutionPhase.aborted
    assert result.metrics.abort_reason.startswith("contact lost in segment")
    table_top = recording.world_config.table.height_m
    assert result.telemetry.tool_position[:, 2].min() > table_top - CONTACT_LOSS_TRAVEL_M - 0.01
    assert result.telemetry.phases[-1] is ExecutionPhase.retreat
    assert result.telemetry.tool_position[-1, 2] > table_top + 0.03  # backed off


@pytest.mark.parametrize(("tilt_deg", "bound_pct"), [(15.0, 5.0), (30.0, 8.0)])
def test_following_the_surface_normal_holds_on_an_unknown_tilt(slide_flat, tilt_deg, bound_pct) -> None:
    """A flat-table skill on a table tilted (and raised 1 cm) without telling the controller: the paper's fixed CF
    presses along the taught normal (8 % too hard along the true normal at 15°, 27 % at 30°); following the
    normal estimated online keeps the TRUE normal force within the bound."""
    recording, skill = slide_flat
    world = recording.world_config.replace(table_tilt_deg=tilt_deg)
    metrics = {}
    for follow in (False, True):
        settings = ExecutionSettings(follow_surface_normal=follow, environment={"unknown_offset": [0.0, 0.0, 0.01]})
        metrics[follow] = execute_skill(skill, world, settings).metrics
        assert metrics[follow].phase is ExecutionPhase.done and metrics[follow].contact_ratio >= 0.99
    assert metrics[True].true_force_rms_error_pct <= bound_pct
    assert metrics[False].true_force_rms_error_pct > 1.5 * bound_pct  # the fixed CF cannot


def test_the_crease_between_two_planes_is_passed_within_15_percent_of_the_true_force(slide_two_planes) -> None:
    """Table -> 20° ramp in one contact: the plan slows to the crease speed around the switch, so the ball meets
    the ramp gently. Before, it was driven into the ramp at ~8 cm/s and the true normal force peaked 38 % high.

    The crease passage is scored: the steady window spans the switch (it used to restart there, and the crease's
    11.8 % peak was reported as 4.6 %), and the transition figure is that peak."""
    result = _run(slide_two_planes)
    m = result.metrics
    _assert_clean(result)
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.true_force_max_error_pct < 15.0
    assert m.transition_true_force_max_error_pct == pytest.approx(m.true_force_max_error_pct)  # the worst is there
    assert m.true_force_rms_error_pct < 3.0
    tel = result.telemetry
    contact = np.array([p is ExecutionPhase.contact for p in tel.phases])
    # it passed the crease: the true normal turned from the table's to the ramp's (20°), slowly there
    normals = tel.contact_normal[contact]
    tilt = np.degrees(np.arccos(np.clip(np.abs(normals[:, 2]), 0.0, 1.0)))
    assert tilt[:100].max() < 1.0 and tilt[-100:].min() > 19.0
    speed = np.linalg.norm(np.diff(tel.tool_position[contact], axis=0), axis=1) / 1e-3
    meeting = np.flatnonzero(tilt > 1.0)[0]
    assert speed[meeting - 50 : meeting + 50].max() < 0.03 < speed.max()


def test_impedance_on_a_contour_releases_on_the_surface_where_the_contour_ends(contour_cylinder) -> None:
    """The release after a contour holds the reference on the taught surface at the END of the contour (it held the
    first frame's plane before and stepped into the cylinder: a force-limit abort)."""
    result = _run(contour_cylinder, ControllerKind.impedance)
    assert result.metrics.phase is ExecutionPhase.done, result.metrics.abort_reason
    assert np.abs(result.telemetry.wrench_world[:, :3]).max() < 40.0
