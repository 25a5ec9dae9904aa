"""Robustness sweeps.

On the real stack (`contact-skills up --workers 2`: embedded Zenoh router, the API, two PyBullet workers as
processes): a 12-trial sweep whose every trial's metrics are stored and whose success rate is the one the stored
trials give; a worker SIGKILLed mid-sweep and its trial run again elsewhere (a physical abort is NOT run again); the
live progress on Zenoh; the same seed giving the same parameters and the same metrics, with the trials' telemetry
off (the default: none sent or stored) or streamed and stored (``store_telemetry``). In process: the sweep's
knobs change the simulated cell as the ground truth says (an unknown tilt turns the real surface, not the skill;
the force scale; an untared sensor bias), the trial design is reproducible and stratified, and the sensitivity
ranking finds the parameter that drives the failures; bad input is a 422 naming the field.
"""

from __future__ import annotations

import json
import math
import os
import signal
import threading
import time
from collections import Counter

import numpy as np
import pytest

from schemas.api import ExecutionState
from schemas.execution import ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.sweep import ParameterRange, Sampler, SweepParameter
from schemas.verdict import ExecutionVerdict, Verdict, VerdictCheck, VerdictCheckName
from skills.sweeps import Outcome, cause_drivers, controller_summary, outcome, sensitivity, trial_parameters

P = SweepParameter
CONTROLLER = "hybrid_cf"


# --------------------------------------------------------------------------------------------- the trial design


def test_the_design_is_reproducible_stratified_and_within_the_ranges():
    vary = {
        P.offset_z_m: ParameterRange(low=-0.02, high=0.01),
        P.contact_stiffness_n_m: ParameterRange(low=1e4, high=1e6, log=True),
    }
    for sampler in Sampler:
        first = trial_parameters(vary, 16, seed=7, sampler=sampler)
        assert first == trial_parameters(vary, 16, seed=7, sampler=sampler)
        assert first != trial_parameters(vary, 16, seed=8, sampler=sampler)
        z = np.array([t[P.offset_z_m] for t in first])
        k = np.array([t[P.contact_stiffness_n_m] for t in first])
        assert z.min() >= -0.02 and z.max() <= 0.01 and k.min() >= 1e4 and k.max() <= 1e6
    lhs = trial_parameters(vary, 16, seed=7, sampler=Sampler.lhs)
    strata = np.floor((np.array([t[P.offset_z_m] for t in lhs]) + 0.02) / 0.03 * 16).astype(int)
    assert sorted(strata) == list(range(16))  # one trial in each sixteenth of the range
    log_strata = np.floor(np.log10([t[P.contact_stiffness_n_m] for t in lhs]) * 8 - 32).astype(int)
    assert sorted(log_strata) == list(range(16))  # log-uniform: one per sixteenth of the decades


def test_a_varied_pad_stays_unknown_to_the_touch_down_planning():
    """A trial's pad is the simulated world's; the touch-down and crease speeds are planned for the sweep's base pad
    (its environment's, else the nominal one), unless the sweep's settings already plan for one."""
    from schemas.execution import NOMINAL_CONTACT_DAMPING_N_S_M, NOMINAL_CONTACT_STIFFNESS_N_M
    from skills.sweeps import planned_pad

    P = SweepParameter
    varied = {P.contact_stiffness_n_m: 9e4, P.contact_damping_n_s_m: 900.0, P.friction: 0.3}
    assert planned_pad({"environment": {}}, varied) == {
        "planned_contact_stiffness_n_m": NOMINAL_CONTACT_STIFFNESS_N_M,
        "planned_contact_damping_n_s_m": NOMINAL_CONTACT_DAMPING_N_S_M,
    }
    base = {"environment": {"contact_stiffness_n_m": 5e4}, "planned_contact_damping_n_s_m": 100.0}
    assert planned_pad(base, varied) == {"planned_contact_stiffness_n_m": 5e4}
    assert planned_pad({"environment": {}}, {P.friction: 0.3}) == {}


def test_sensitivity_ranks_the_parameter_that_drives_the_failures_first():
    rng = np.random.default_rng(0)
    parameters = [{P.friction: float(f), P.offset_z_m: float(z)} for f, z in rng.uniform(0, 1, (60, 2))]
    outcomes = []
    for p in parameters:  # the error grows with friction; offset_z does nothing; the worst ones abort
        rms = 2.0 + 10.0 * p[P.friction] + rng.normal(0, 0.5)
        aborted = p[P.friction] > 0.9
        phase, rms = (ExecutionPhase.aborted, None) if aborted else (ExecutionPhase.done, rms)
        outcomes.append(Outcome(phase, rms, None, 1.0, 1.0, "x", success=not aborted and rms <= 8.0))
    ranking = sensitivity(CONTROLLER, parameters, outcomes)
    assert [s.parameter for s in ranking] == [P.friction, P.offset_z_m]
    friction, offset = ranking
    assert friction.spearman_rms > 0.9 and abs(offset.spearman_rms) < 0.3
    assert friction.success_low_half > 0.9 and friction.success_high_half < 0.1
    assert friction.success_difference == pytest.approx(friction.success_high_half - friction.success_low_half)
    # Where a failure happened: the parameter whose quarters differ most in its share, an offset failing either way
    # (|z| > 0.3) as well as one failing at one end.
    causes = [("true_force_rms",) * (p[P.friction] > 0.5) + ("touchdown",) * (abs(p[P.offset_z_m] - 0.5) > 0.3)
              for p in parameters]  # fmt: skip
    drivers = {d.cause: d for d in cause_drivers(parameters, causes)}
    assert drivers["true_force_rms"].parameter is P.friction and drivers["touchdown"].parameter is P.offset_z_m
    quarters = drivers["touchdown"].bins
    assert [total for *_, total in quarters] == [15, 15, 15, 15] and quarters[0][0] < 0.05 and quarters[3][1] > 0.95
    low, middle_low, middle_high, high = (n for _, _, n, _ in quarters)
    assert min(low, high) >= 12 and max(middle_low, middle_high) <= 3
    assert drivers["touchdown"].count == sum("touchdown" in c for c in causes) and drivers["touchdown"].finished == 60


def _verdict(*failed: VerdictCheckName, warned: tuple[VerdictCheckName, ...] = (), phase="done") -> ExecutionMetrics:
    """The metrics of an execution whose verdict failed ``failed`` and warned about ``warned``."""
    names = [VerdictCheckName.finished, VerdictCheckName.true_force_rms, VerdictCheckName.true_force_max,
             VerdictCheckName.contact_ratio, VerdictCheckName.touchdown, VerdictCheckName.surface_found]  # fmt: skip
    checks = [
        VerdictCheck(name=n, passed=n not in failed and n not in warned, warning_only=n in warned, message=f"{n} msg")
        for n in names
    ]
    verdict = ExecutionVerdict(
        verdict=Verdict.failed if failed else Verdict.passed,
        reasons=[f"{n} msg" for n in failed],
        warnings=[f"{n} msg" for n in warned],
        checks=checks,
    )
    metrics = ExecutionMetrics(
        controller=CONTROLLER, phase=phase, real_time_factor=5.0, duration_s=9.0, steps=9000, peak_force_n=20.0,
        true_force_rms_error_pct=3.0, contact_ratio=1.0, verdict=verdict,
        abort_reason="contact lost in segment 1 at t = 4.200 s: no contact 8 mm beyond" if phase != "done" else None,
    )  # fmt: skip
    return metrics


def test_a_trial_succeeds_when_its_verdict_passes_and_its_causes_are_the_failed_checks():
    """The verdict decides, not the sweep's own rule: a run whose RMS error (3 %) and contact (100 %) pass the
    thresholds fails on its max error or touch-down, each counted; a warning counts apart and fails nothing; an abort
    is one cause, its reason's head; a trial stored before verdicts is judged by the old rule."""
    V = VerdictCheckName
    criteria = {"success_rms_pct": 10.0, "success_contact_ratio": 0.99}
    passed = outcome(_verdict(warned=(V.surface_found,)), ExecutionState.done, None, criteria)
    failed = outcome(_verdict(V.true_force_max, V.touchdown), ExecutionState.done, None, criteria)
    aborted = outcome(_verdict(V.finished, V.contact_ratio, phase="aborted"), ExecutionState.aborted, None, criteria)
    assert (passed.success, passed.verdict, passed.causes, passed.warnings) == (
        True, Verdict.passed, (), ("surface_found",)
    )  # fmt: skip
    assert (failed.success, failed.verdict) == (False, Verdict.failed)
    assert failed.causes == ("true_force_max", "touchdown")
    assert failed.reasons == ("true_force_max msg", "touchdown msg")
    assert aborted.causes == ("aborted: contact lost in segment 1",)
    legacy = _verdict().model_copy(update={"verdict": None})
    assert outcome(legacy, ExecutionState.done, None, criteria).success  # 3 % <= 10 %, in contact 100 %
    assert outcome(legacy, ExecutionState.done, None, {**criteria, "success_rms_pct": 2.0}).causes == (
        "true_force_rms",
    )
    assert outcome(None, ExecutionState.failed, "worker w1 lost", criteria).causes == ("failed: worker w1 lost",)
    summary = controller_summary(CONTROLLER, 4, [passed, failed, aborted, failed])
    assert (summary.succeeded, summary.finished, summary.success_rate) == (1, 4, 0.25)
    assert summary.failures == {"true_force_max": 2, "touchdown": 2, "aborted: contact lost in segment 1": 1}
    assert summary.warnings == {"surface_found": 1}


# --------------------------------------------------------------------------------------------- the knobs, in the sim


@pytest.fixture(scope="module")
def short_slide():
    from schemas.skill import LearnOptions
    from sim_worker.teacher import record_demonstration
    from skills.parameterize import learn_skill

    recording = record_demonstration(
        "slide_flat", seed=0, move_duration_s=2.0, approach_duration_s=0.5, retreat_duration_s=0.5
    )
    return learn_skill(recording.demonstration, LearnOptions(skill_type="slide"))


@pytest.fixture(scope="module")
def plain(short_slide):
    """The short slide with the ideal sensor and nothing changed."""
    return _metrics(short_slide, sensor="ideal")


def _metrics(skill, tare_sensor: bool = True, follow_surface_normal: bool = False, **environment):
    """The metrics of ``skill`` run in the changed ``environment``, with the paper's fixed frame unless asked: these
    tests compare what a change does to the TRUE surface and force against an unchanged run, CF for CF."""
    from sim_worker.execution_world import execution_world
    from sim_worker.executor import run_skill

    settings = ExecutionSettings(
        environment=environment, tare_sensor=tare_sensor, follow_surface_normal=follow_surface_normal
    )
    return run_skill(execution_world(skill, settings.environment), settings).metrics


def test_an_unknown_tilt_turns_the_real_surface_and_not_the_skill(short_slide, plain):
    """The learned CF stays where it was taught; the TRUE surface normal (the simulator's geometry) is off by the
    tilt asked for, about x or y, through the contact (the tool still finds it within the approach)."""
    for tilt in ([6.0, 0.0], [0.0, -4.0]):
        metrics = _metrics(short_slide, unknown_tilt_deg=tilt, sensor="ideal")
        assert metrics.phase is ExecutionPhase.done and metrics.contact_ratio >= 0.99, metrics.abort_reason
        assert metrics.cf_normal_angle_deg == pytest.approx(max(abs(a) for a in tilt), abs=0.1)
    assert plain.cf_normal_angle_deg < 0.1


def test_force_scale_changes_the_true_force_and_the_tare_removes_a_bias_that_would(short_slide, plain):
    """The force scale multiplies the learned force (the % refer to the scaled one). A +1 N bias along world z reads
    as 1 N less pressing: left in (``tare_sensor`` off), the controller presses 1 N harder and the TRUE error gains a
    1 N mean (RMS² = mean² + variance: the squares differ by ~1 N² as the unbiased run's mean error is ~0); the tare
    in free space before contact (the default) removes it, and the true error is the unbiased run's."""
    scaled = _metrics(short_slide, sensor="ideal", force_scale=1.4)
    assert scaled.force_reference_n == pytest.approx(1.4 * plain.force_reference_n, rel=1e-9)
    assert scaled.phase is ExecutionPhase.done and scaled.true_force_rms_error_pct < 10
    biased = _metrics(short_slide, tare_sensor=False, sensor="ideal", sensor_bias_n=[0.0, 0.0, 1.0])
    shift = math.sqrt(biased.true_force_rms_error_n**2 - plain.true_force_rms_error_n**2)
    assert shift == pytest.approx(1.0, abs=0.15)
    tared = _metrics(short_slide, sensor="ideal", sensor_bias_n=[0.0, 0.0, 1.0])
    assert tared.phase is ExecutionPhase.done
    assert tared.true_force_rms_error_n == pytest.approx(plain.true_force_rms_error_n, abs=0.02)


def test_a_bias_that_reads_as_a_touch_down_in_free_space_is_tared_away(short_slide):
    """-1 N along world z reads as pressing with 1 N, the contact threshold of this 15 N skill. Without the tare the
    guarded approach stops in the air (noise 0.3 N tips the reading over), the force loop then pushes into nothing
    and the run aborts saying that no contact was made (what 6 of 8 failed slide trials of the 200-trial sweep did,
    then reported as "contact lost"), its verdict failing, and warning of the surface "found" cm early; tared
    in free space before contact, the run is the unbiased one's (TRUE normal force)."""
    biased = {"sensor_bias_n": [0.0, 0.0, -1.0], "sensor_noise_n": 0.3}
    untared = _metrics(short_slide, tare_sensor=False, **biased)
    assert untared.phase is ExecutionPhase.aborted and untared.abort_reason.startswith("no contact made")
    assert untared.verdict.verdict is Verdict.failed
    assert {c.name for c in untared.verdict.checks if not c.passed} == {"finished", "contact_ratio", "surface_found"}
    # "Found" in the air, far before the table: the free segment stopped on the reading, the touch-down after it too.
    assert untared.verdict.warnings[0].startswith("surface found -") and untared.contact_found_offsets_m[0] < -0.03
    tared = _metrics(short_slide, **biased)
    unbiased = _metrics(short_slide, sensor_noise_n=0.3)
    assert tared.phase is ExecutionPhase.done and tared.contact_ratio >= 0.99
    assert tared.true_force_rms_error_pct == pytest.approx(unbiased.true_force_rms_error_pct, abs=0.1)


@pytest.fixture(scope="module")
def cylinder_skill(short_slide):
    """A skill whose taught world holds the contour_cylinder scenario's cylinder (the slide's segments: only the
    world matters to what a sweep changes in it)."""
    from sim_worker.teacher import scenario_world_config

    return short_slide.model_copy(update={"taught_world": scenario_world_config("contour_cylinder").to_dict()})


def test_a_sweep_runs_each_trial_with_its_criteria_its_bias_and_its_cylinder_and_reports_the_verdicts(
    bus_client, cylinder_skill
):
    """Through the API on a fake bus: every trial's execution carries the sweep's success criteria as tolerances
    (the others from its settings), its sensor bias on world x, y and z and the sensor's own offset on the tool's,
    and its cylinder as world overrides, which the
    worker's world resolution (`execution_worlds`, as `worlds_for` calls it) applies: the radius drawn, the crown where
    it was taught. Their verdicts then decide the trials, the failed checks are the causes, the warnings counted
    apart."""
    from schemas.bus import ExecutionStatus
    from schemas.world import WorldConfig
    from sim_worker.execution_world import execution_world
    from sim_worker.geometry import WorldGeometry

    c, bus = bus_client, bus_client.bus
    overrides = []
    start = bus.start_execution

    def spy(execution_id, request, **options):
        overrides.append(options["world_overrides"])
        return start(execution_id, request, **options)

    bus.start_execution = spy
    vary = {"cylinder_radius_m": {"low": 0.06, "high": 0.12}, "cylinder_yaw_deg": {"low": -15, "high": 15},
            **{f"sensor_bias_{axis}_n": {"low": -5, "high": 5} for axis in "xyz"},
            **{f"sensor_offset_{axis}_n": {"low": -5, "high": 5} for axis in "xyz"}}  # fmt: skip
    settings = {"tolerances": {"touchdown_ratio": 2}}
    body = {"skill": cylinder_skill.model_dump(mode="json"), "vary": vary, "trials": 2, "seed": 4,
            "success_rms_pct": 8.0, "success_contact_ratio": 0.95, "settings": settings}  # fmt: skip
    created = c.post("/sweeps", json=body)
    assert created.status_code == 202, created.text
    sweep_id = created.json()["id"]
    trials = c.get(f"/sweeps/{sweep_id}/trials").json()
    assert len(bus.started) == 2 and [t["execution_id"] for t in trials] == [e for e, _ in bus.started]
    taught = WorldGeometry(WorldConfig.from_dict(cylinder_skill.taught_world)).solids["cylinder"]
    for (_, request), world, trial in zip(bus.started, overrides, trials, strict=True):
        drawn = trial["parameters"]
        tolerances = request.tolerances
        assert (tolerances.true_force_rms_pct, tolerances.contact_ratio, tolerances.touchdown_ratio) == (8.0, 0.95, 2)
        assert tolerances.true_force_max_pct == 50.0  # the default, untouched
        bias = [drawn[f"sensor_bias_{axis}_n"] for axis in "xyz"]
        config = execution_world(request.skill, request.environment, overrides=world).config
        assert config.sensor.bias_n == pytest.approx(tuple(bias)) and max(map(abs, bias)) > 1.0
        own = [drawn[f"sensor_offset_{axis}_n"] for axis in "xyz"]
        assert config.sensor.offset_tool_n == pytest.approx(tuple(own)) and max(map(abs, own)) > 1.0
        assert config.cylinder.yaw_deg == pytest.approx(90.0 + drawn["cylinder_yaw_deg"])
        cylinder = WorldGeometry(config).solids["cylinder"]
        assert cylinder.radius == pytest.approx(drawn["cylinder_radius_m"])
        assert cylinder.p[2] + cylinder.radius == pytest.approx(taught.p[2] + taught.radius)  # the crown stays
        assert c.get(f"/executions/{trial['execution_id']}").json()["request"]["world_overrides"] == world

    V = VerdictCheckName
    results = [_verdict(warned=(V.surface_found,)), _verdict(V.true_force_max, V.touchdown)]
    for (execution_id, _), metrics in zip(bus.started, results, strict=True):
        status = ExecutionStatus(execution_id=execution_id, worker_id="w0", phase="done", metrics=metrics)
        bus.on_status(status)
    trials = c.get(f"/sweeps/{sweep_id}/trials").json()
    assert [(t["success"], t["verdict"]) for t in trials] == [(True, "pass"), (False, "fail")]
    assert trials[1]["causes"] == ["true_force_max", "touchdown"]
    assert trials[1]["reasons"] == ["true_force_max msg", "touchdown msg"] and trials[0]["reasons"] == []
    view = c.get(f"/sweeps/{sweep_id}").json()
    [summary] = view["controllers"]
    assert (summary["succeeded"], summary["finished"], view["counts"]["succeeded"]) == (1, 2, 1)
    assert summary["failures"] == {"true_force_max": 1, "touchdown": 1} and summary["warnings"] == {"surface_found": 1}


# --------------------------------------------------------------------------------------------- bad input


def test_the_cli_spells_out_the_schema_names():
    from cli import sweep_command
    from schemas.execution import ControllerKind

    assert tuple(c.value for c in ControllerKind) == sweep_command.CONTROLLERS
    assert tuple(p.value for p in SweepParameter) == sweep_command.PARAMETERS
    assert tuple(s.value for s in Sampler) == sweep_command.SAMPLERS


def test_the_default_sweep_is_what_a_real_cell_sees_and_validates():
    """The CLI's default sweep (no --vary, no --settings): ±8 cm, ±15°, ±5 N of bias on every axis, 2 N of noise, with
    the surface normal followed and an approach that expects the surface anywhere within the offsets; the cylinder's
    radius and yaw besides for a skill taught on one. The request validates and stays within the bounds."""
    from cli.sweep_command import _settings, _vary
    from schemas.sweep import CYLINDER_RANGES, DEFAULT_RANGES, DEFAULT_SETTINGS, PARAMETER_BOUNDS, SweepRequest

    assert set(DEFAULT_RANGES) | set(CYLINDER_RANGES) == set(SweepParameter)
    for name, spread in (*DEFAULT_RANGES.items(), *CYLINDER_RANGES.items()):
        assert PARAMETER_BOUNDS[name][0] <= spread.low < spread.high <= PARAMETER_BOUNDS[name][1], name
    for name in (P.offset_x_m, P.offset_y_m, P.offset_z_m):
        assert (DEFAULT_RANGES[name].low, DEFAULT_RANGES[name].high) == (-0.08, 0.08)
    for name in (P.sensor_offset_x_n, P.sensor_offset_y_n, P.sensor_offset_z_n):  # the sensor's own, tool frame
        assert (DEFAULT_RANGES[name].low, DEFAULT_RANGES[name].high) == (-5.0, 5.0)
    for name in (P.sensor_bias_x_n, P.sensor_bias_y_n, P.sensor_bias_z_n):  # a tool weight error, world frame
        assert (DEFAULT_RANGES[name].low, DEFAULT_RANGES[name].high) == (-1.0, 1.0)
    assert DEFAULT_RANGES[P.tilt_x_deg].high == 15.0 and DEFAULT_RANGES[P.sensor_noise_n].high == 2.0
    offset = DEFAULT_RANGES[P.offset_z_m].high
    assert DEFAULT_SETTINGS.follow_surface_normal and DEFAULT_SETTINGS.approach_slow_distance_m >= offset
    assert DEFAULT_SETTINGS.approach_clearance_m > offset
    assert DEFAULT_SETTINGS.approach_max_distance_m >= DEFAULT_SETTINGS.approach_clearance_m + offset
    body = {"skill_id": "skill_000000000000", "vary": _vary(None), "settings": _settings(None)}
    request = SweepRequest.model_validate(body)
    # No engine named: the sweep's world chooses it when the sweep is created (services.sweeps.sweep_engine)
    assert request.settings == DEFAULT_SETTINGS and set(request.vary) == set(DEFAULT_RANGES)
    assert request.settings.tolerances.surface_window_m is None  # the window is the slow zone: 10 cm


def test_a_parameter_the_trials_world_has_nothing_for_is_422_naming_it(client, short_slide, cylinder_skill):
    """The cylinder's radius on a skill taught on a table, or with the trials in another world than the taught one,
    is refused before anything runs; on a skill taught on a cylinder it passes (then 503: no bus here). The sweep's
    criteria cannot be given twice: a tolerance the sweep sets from its own field is a 422 naming that field."""
    vary = {"cylinder_radius_m": {"low": 0.06, "high": 0.12}}
    cases = [
        (short_slide, {}, "the skill's taught world has no cylinder"),
        (cylinder_skill, {"scenario": "contour_cylinder"}, "give no scenario"),
        (cylinder_skill, {"settings": {"environment": {"work_piece": "rebuilt"}}}, "on a rebuilt work piece"),
    ]
    for skill, extra, message in cases:
        body = {"skill": skill.model_dump(mode="json"), "vary": vary, **extra}
        response = client.post("/sweeps", json=body)
        assert response.status_code == 422, response.text
        [error] = response.json()["detail"]
        assert error["loc"] == ["body", "vary", "cylinder_radius_m"] and message in error["msg"], error
    body = {"skill": cylinder_skill.model_dump(mode="json"), "vary": vary}
    assert client.post("/sweeps", json=body).status_code == 503
    twice = {**body, "settings": {"tolerances": {"true_force_rms_pct": 5, "true_force_max_pct": 40}}}
    response = client.post("/sweeps", json=twice)
    assert response.status_code == 422 and "true_force_rms_pct (give success_rms_pct)" in response.text, response.text


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"approach_slow_distance_m": -1}', "settings.approach_slow_distance_m: Input should be greater than"),
        ('{"approach_slow": 0.04}', "settings.approach_slow: Extra inputs are not permitted"),
        ("[0.04]", "give a JSON object of execution settings"),
        ("{approach", "not JSON"),
    ],
)
def test_bad_cli_sweep_settings_exit_2_naming_the_field(tmp_path, capsys, content, message):
    """`contact-skills sweep --settings FILE` is checked before anything starts: exit 2, one line naming the field."""
    from cli.main import main

    settings = tmp_path / "settings.json"
    settings.write_text(content)
    assert main(["sweep", "slide_flat", "--settings", str(settings)]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("change", "loc"),
    [
        ({"trials": 0}, ["body", "trials"]),
        ({"vary": {"offset_z_m": {"low": 0.02, "high": -0.02}}}, ["body", "vary", "offset_z_m"]),
        ({"vary": {"tilt_x_deg": {"low": -45, "high": 5}}}, ["body", "vary"]),
        ({"vary": {"humidity": {"low": 0, "high": 1}}}, ["body", "vary", "humidity", "[key]"]),
        ({"vary": {}}, ["body", "vary"]),
        ({"controllers": ["hybrid_cf", "hybrid_cf"]}, ["body", "controllers"]),
        ({"controllers": ["pid"]}, ["body", "controllers", 0]),
        ({"sampler": "grid"}, ["body", "sampler"]),
        ({"success_rms_pct": -1}, ["body", "success_rms_pct"]),
        ({"priority": 5}, ["body", "priority"]),
        ({"settings": {"telemetry": "stream"}}, ["body", "settings"]),
    ],
)
def test_bad_sweeps_are_422_naming_the_field(client, change, loc):
    body = {"skill_id": "skill_000000000000", "vary": {"friction": {"low": 0.1, "high": 0.4}}, **change}
    response = client.post("/sweeps", json=body)
    assert response.status_code == 422, response.text
    assert loc in [error["loc"] for error in response.json()["detail"]], response.text


def test_unknown_sweeps_and_skills_are_404_and_a_sweep_without_a_bus_is_503(client):
    assert client.get("/sweeps/sweep_000000000000").status_code == 404
    assert client.get("/sweeps/sweep_000000000000/trials").status_code == 404
    body = {"skill_id": "skill_000000000000", "vary": {"friction": {"low": 0.1, "high": 0.4}}}
    assert client.post("/sweeps", json=body).status_code == 404
    assert client.get("/sweeps").json() == []


# --------------------------------------------------------------------------------------------- the real stack

zenoh = pytest.importorskip("zenoh")

from test_service import running_stack  # noqa: E402
from waiting import wait_for  # noqa: E402

from services.bus import open_session  # noqa: E402

TRIALS = 12
RECORD = {
    "scenario": "slide_flat",
    "seed": 0,
    "overrides": {"move_duration_s": 2.0, "approach_duration_s": 0.5, "retreat_duration_s": 0.5},
}
"""A short stroke: each execution runs ~8 s of simulated time."""
SWEEP = {
    "controllers": [CONTROLLER],
    "vary": {
        "offset_z_m": {"low": -0.01, "high": 0.01},
        "tilt_x_deg": {"low": -6.0, "high": 6.0},
        "friction": {"low": 0.1, "high": 0.5},
        "sensor_bias_z_n": {"low": -2.5, "high": 1.0},
    },
    "trials": TRIALS,
    "seed": 3,
    "success_rms_pct": 8.0,
    "settings": {"settle_s": 0.2, "tare_sensor": False},
}
"""A cell that does not tare its sensor: a bias beyond about -1.5 N reads as contact in free space, and those trials
abort (lost contact), a physical result that is never run again; the threshold splits the rest."""
COMPARED = tuple(name for name in ExecutionMetrics.model_fields if name != "real_time_factor")
"""The metrics a deterministic simulation repeats exactly: all but the wall-clock real-time factor."""


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("sweeps"))


@pytest.fixture(scope="module")
def skill_id(stack) -> str:
    demo = stack.post("/demonstrations/record", RECORD, 201)
    return stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "slide"}, 201)["id"]


class Progress:
    """Every `SweepProgress` put on the bus, from an independent Zenoh subscriber."""

    def __init__(self, endpoint: str) -> None:
        self.received: list[dict] = []
        self._lock = threading.Lock()
        self.session = open_session("client", connect=[endpoint], wait_s=10)  # as this user's `up`'s observer
        self.subscriber = self.session.declare_subscriber("cskills/sweeps/*/progress", self._on)
        time.sleep(0.5)  # the subscription reaches the router

    def _on(self, sample) -> None:
        with self._lock:
            self.received.append(json.loads(sample.payload.to_bytes()))

    def of(self, sweep_id: str) -> list[dict]:
        with self._lock:
            return [p for p in self.received if p["sweep_id"] == sweep_id]

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()


def _finished_sweep(stack, sweep_id: str, timeout_s: float = 150) -> dict:
    def done():
        view = stack.http.get(f"/sweeps/{sweep_id}").json()
        return view if view["status"] != "running" else None

    return wait_for(done, timeout_s, f"sweep {sweep_id}", every_s=0.5)


def test_a_sweep_survives_a_killed_worker_and_repeats_with_its_seed(stack, skill_id):
    stack.workers(2)
    workers = stack.worker_pids()
    progress = Progress(stack.endpoint)
    try:
        created = stack.post("/sweeps", {**SWEEP, "skill_id": skill_id}, 202)
        assert created["executions"] == TRIALS and created["progress_key"] == f"cskills/sweeps/{created['id']}/progress"

        def victim():  # a trial's execution well under way (its statuses say it approaches or presses; no telemetry)
            for trial in stack.http.get(f"/sweeps/{created['id']}/trials").json():
                if trial["status"] == "running" and trial["execution_id"]:
                    execution = stack.execution(trial["execution_id"])
                    if execution["phase"] in ("approach", "contact"):
                        return trial, execution["worker_id"]
            return None

        # At pace fast a trial presses for ~0.1 s of wall time: the kill follows the sighting with no other request.
        killed, killed_worker = wait_for(victim, 60, "a running trial", every_s=0.05)
        os.kill(workers[killed_worker], signal.SIGKILL)
        view = _finished_sweep(stack, created["id"])
        time.sleep(1.0)  # the last progress reaches the subscriber
        live = progress.of(created["id"])
    finally:
        progress.close()

    assert view["status"] == "done"
    trials = stack.http.get(f"/sweeps/{created['id']}/trials").json()
    assert len(trials) == TRIALS and all(t["status"] in ("done", "aborted") for t in trials), trials
    for trial in trials:  # every trial's metrics stored, and the execution that ran it holds them; no telemetry
        execution = stack.execution(trial["execution_id"])
        assert execution["metrics"] == trial["metrics"] and execution["request"]["sweep"]["trial"] == trial["trial"]
        assert execution["request"]["telemetry"] == "none" and execution["telemetry_samples"] == 0
        assert execution["telemetry_missing_samples"] is None
        # Judged by its verdict, against the sweep's criteria written into its tolerances; its causes are the
        # verdict's failed checks (or the abort).
        tolerances = execution["request"]["tolerances"]
        assert (tolerances["true_force_rms_pct"], tolerances["contact_ratio"]) == (8.0, 0.99)
        verdict = trial["metrics"]["verdict"]
        assert trial["success"] is (verdict["verdict"] == "pass") and trial["verdict"] == verdict["verdict"]
        assert trial["reasons"] == verdict["reasons"]
        failed = [c["name"] for c in verdict["checks"] if not c["passed"] and not c["warning_only"]]
        if trial["success"] or trial["status"] == "done":
            assert trial["causes"] == ([] if trial["success"] else failed)
        else:  # an abort is one cause: the head of its reason
            [cause] = trial["causes"]
            assert cause.startswith("aborted: ") and trial["abort_reason"].startswith(cause.removeprefix("aborted: "))
    refused = stack.http.get(f"/executions/{trials[0]['execution_id']}/telemetry")
    assert refused.status_code == 409 and "store_telemetry" in refused.json()["detail"], refused.text
    # The killed worker's trial ran again on another worker; its first execution is failed, naming the loss.
    again = next(t for t in trials if t["trial"] == killed["trial"])
    first = stack.execution(killed["execution_id"])
    assert first["status"] == "failed" and "lost" in first["error"] and killed_worker in first["error"]
    assert again["attempts"] == 2 and again["execution_id"] != killed["execution_id"]
    rerun_by = stack.execution(again["execution_id"])["worker_id"]  # another worker, or the killed one restarted
    assert rerun_by != killed_worker or stack.worker_pids()[killed_worker] != workers[killed_worker]
    assert again["status"] in ("done", "aborted") and again["metrics"]["steps"] > 0
    # A physical abort is a result, not a reason to run again.
    aborted = [t for t in trials if t["status"] == "aborted"]
    assert aborted and all(t["attempts"] == 1 for t in aborted if t["trial"] != killed["trial"])
    assert all(t["abort_reason"] and t["success"] is False for t in aborted)
    # The success rate is the one the stored trials' verdicts give; the failures are their causes.
    succeeded = [t for t in trials if t["metrics"]["verdict"]["verdict"] == "pass"]
    [summary] = view["controllers"]
    assert 0 < len(succeeded) < TRIALS - len(aborted)  # the threshold splits the trials that finished
    assert (summary["finished"], summary["succeeded"]) == (TRIALS, len(succeeded))
    assert summary["failures"] == dict(Counter(c for t in trials for c in t["causes"]))
    assert summary["success_rate"] == pytest.approx(len(succeeded) / TRIALS)
    rms = [t["metrics"]["true_force_rms_error_pct"] for t in trials if t["metrics"]["true_force_rms_error_pct"]]
    assert summary["true_force_rms_error_pct"]["p50"] == pytest.approx(float(np.median(rms)))
    assert view["counts"] == {"total": TRIALS, "finished": TRIALS, "succeeded": len(succeeded), "running": 0,
                              "queued": 0, "pending": 0, "reruns": 1}  # fmt: skip
    assert view["sensitivity"][0]["parameter"] == "sensor_bias_z_n"  # the bias decides which trials abort
    # Live on Zenoh: the counts grew to the end.
    assert live and live[-1]["status"] == "done" and live[-1]["counts"]["finished"] == TRIALS
    assert [p["counts"]["finished"] for p in live] == sorted(p["counts"]["finished"] for p in live)

    # The same seed, now streaming and storing every trial's telemetry: the same trials, the same physics
    # (deterministic simulation), the killed one included, so the same metrics and success rates either way.
    repeat = stack.post("/sweeps", {**SWEEP, "skill_id": skill_id, "store_telemetry": True}, 202)
    repeated_view = _finished_sweep(stack, repeat["id"])
    assert repeated_view["status"] == "done" and repeated_view["counts"]["reruns"] == 0
    repeated = stack.http.get(f"/sweeps/{repeat['id']}/trials").json()
    assert [t["parameters"] for t in repeated] == [t["parameters"] for t in trials]
    for a, b in zip(trials, repeated, strict=True):
        assert {k: a["metrics"][k] for k in COMPARED} == {k: b["metrics"][k] for k in COMPARED}, (a, b)
        assert (a["success"], a["status"]) == (b["success"], b["status"])
        execution = stack.execution(b["execution_id"])
        assert execution["request"]["telemetry"] == "stream" and execution["telemetry_missing_samples"] == 0
        assert execution["telemetry_samples"] == b["metrics"]["steps"]
    assert repeated_view["controllers"] == view["controllers"]  # success rate, quantiles, failures by cause
    listed = stack.http.get("/sweeps").json()
    assert [s["id"] for s in listed[:2]] == [repeat["id"], created["id"]]
    assert stack.http.post(f"/sweeps/{created['id']}/cancel").status_code == 409


def test_a_sweep_resumes_after_the_api_is_killed(stack, skill_id):
    """The API SIGKILLed mid-sweep (`up` restarts it on the same database): the sweep goes on from SQLite, the
    executions that outlived the API keep their results, and every trial ends with one."""
    stack.workers(2)
    created = stack.post("/sweeps", {**SWEEP, "trials": 4, "seed": 11, "skill_id": skill_id}, 202)
    wait_for(lambda: stack.http.get(f"/sweeps/{created['id']}").json()["counts"]["running"] >= 1, 30, "a trial")
    api_pid = stack.api_pid()
    os.kill(api_pid, signal.SIGKILL)
    wait_for(lambda: stack.health() and stack.api_pid() != api_pid, 60, "the API to restart")
    view = _finished_sweep(stack, created["id"])
    trials = stack.http.get(f"/sweeps/{created['id']}/trials").json()
    assert view["status"] == "done" and view["counts"]["finished"] == 4 and view["counts"]["pending"] == 0
    assert all(t["status"] in ("done", "aborted") and t["metrics"]["steps"] > 0 for t in trials), trials


def test_cancelling_a_sweep_stops_its_executions_and_submits_no_more(stack, skill_id):
    stack.workers(2)
    created = stack.post("/sweeps", {**SWEEP, "trials": 20, "seed": 5, "skill_id": skill_id}, 202)
    wait_for(lambda: stack.http.get(f"/sweeps/{created['id']}").json()["counts"]["running"] >= 1, 30, "a trial")
    view = stack.post(f"/sweeps/{created['id']}/cancel", {}, 202)
    assert view["status"] == "cancelled" and view["counts"]["pending"] > 0
    submitted = {t["execution_id"] for t in stack.http.get(f"/sweeps/{created['id']}/trials").json()} - {None}
    for execution_id in submitted:  # queued ones cancelled at once, running ones aborted over the bus
        final = stack.finished(execution_id, timeout_s=30)
        assert final["status"] in ("aborted", "done"), final
    time.sleep(1.5)  # the runner would have submitted more by now
    after = {t["execution_id"] for t in stack.http.get(f"/sweeps/{created['id']}/trials").json()} - {None}
    assert after == submitted and stack.http.get(f"/sweeps/{created['id']}").json()["status"] == "cancelled"
    assert stack.http.post(f"/sweeps/{created['id']}/cancel").status_code == 409
