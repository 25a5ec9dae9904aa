"""The engine chosen per worker, per world and per sweep (issue 44, docs/ENGINES.md): a REAL stack (`contact-skills
up` on 127.0.0.1, one worker, its default engine MuJoCo from ``CONTACT_SKILLS_ENGINE``) runs an execution that names
no engine on MuJoCo and one that names PyBullet on PyBullet, each judged by its own engine's contact; a skill whose
world names an engine runs on it over the worker's default, under the execution's own choice; a sweep runs every
trial on the engine it names (else its world's, else PyBullet, not the worker's default) and records it in each
trial; an unknown engine is refused naming the field, or the variable."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytest.importorskip("zenoh")
pytest.importorskip("mujoco")

from test_service import running_stack

from sim_worker.worker_settings import ENV_ENGINE

RECORD = {"scenario": "slide_flat", "seed": 0}
"""The teacher's flat slide at its own pace (a faster stroke differs more between the engines, docs/ENGINES.md)."""
SLIDE_RMS_PCT = 5.0
"""The teacher's flat slide keeps its true normal-force RMS error within this on either engine (% of the learned
force; measured 1-2 % on PyBullet and MuJoCo alike, docs/RESULTS.md's cross-engine table)."""


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    yield from running_stack(tmp_path_factory.mktemp("engine"), workers=1, env={ENV_ENGINE: "mujoco"})


@pytest.fixture(scope="module")
def skill_id(stack) -> str:
    demo = stack.post("/demonstrations/record", RECORD, 201)
    return stack.post("/skills", {"demonstration_id": demo["id"], "skill_type": "auto"}, 201)["id"]


def _run(stack, skill_id: str, **settings) -> dict:
    execution = stack.post("/executions", {"skill_id": skill_id, **settings}, 202)
    view = stack.finished(execution["id"], timeout_s=180)
    assert view["status"] == "done", view
    assert view["metrics"]["true_force_rms_error_pct"] <= SLIDE_RMS_PCT, view["metrics"]
    return view


def test_health_shows_the_worker_s_default_engine(stack):
    """The worker started with ``CONTACT_SKILLS_ENGINE=mujoco`` says so on ``/health``."""
    assert [w["engine"] for w in stack.workers(1)] == ["mujoco"]


def test_an_execution_naming_no_engine_runs_on_the_worker_s_and_one_naming_pybullet_on_pybullet(stack, skill_id):
    """No engine in the request: the worker's (MuJoCo) ran it, the stored execution says so; ``engine: pybullet``:
    PyBullet ran it on the same worker."""
    unnamed = _run(stack, skill_id)
    assert unnamed["metrics"]["engine"] == "mujoco"
    named = _run(stack, skill_id, engine="pybullet")
    assert named["metrics"]["engine"] == "pybullet"
    # Two engines, two contact models: the same skill, not the same numbers (a run that ignored the engine would
    # repeat the first one's to the last digit).
    assert unnamed["metrics"]["true_force_rms_error_pct"] != named["metrics"]["true_force_rms_error_pct"]


def _sweep_trials(stack, skill_id: str, settings: dict, **given) -> list[dict]:
    """The trials of a one-trial sweep of the stored skill ``skill_id`` (or ``given``'s inline ``skill``)."""
    skill = {"skill_id": skill_id} if "skill" not in given else {}
    body = {**skill, "vary": {"offset_z_m": {"low": -0.005, "high": 0.005}}, "trials": 1, "settings": settings,
            **given}  # fmt: skip
    sweep = stack.post("/sweeps", body, 202)

    def finished():
        view = stack.http.get(f"/sweeps/{sweep['id']}").json()
        return view if view["status"] != "running" else None

    from waiting import wait_for

    assert wait_for(finished, 180, "the sweep")["status"] == "done"
    return stack.http.get(f"/sweeps/{sweep['id']}/trials").json()


def test_a_sweep_runs_every_trial_on_its_engine_and_records_it(stack, skill_id):
    """``settings.engine: mujoco``: the trial says MuJoCo and MuJoCo ran it; no engine: PyBullet, not the worker's
    MuJoCo (one sweep, one engine, whichever workers its trials reach)."""
    [mujoco] = _sweep_trials(stack, skill_id, {"engine": "mujoco"})
    assert mujoco["engine"] == "mujoco" and mujoco["metrics"]["engine"] == "mujoco"
    assert mujoco["status"] == "done", mujoco
    [pybullet] = _sweep_trials(stack, skill_id, {})
    assert pybullet["engine"] == "pybullet" and pybullet["metrics"]["engine"] == "pybullet"


def _in_world_on(stack, skill_id: str, engine: str) -> dict:
    """The stored skill inline, its taught world naming ``engine`` (a world a user keeps with its engine)."""
    skill = stack.http.get(f"/skills/{skill_id}").json()["skill"]
    assert "engine" not in skill["taught_world"]  # the recorder names none
    return {**skill, "taught_world": {**skill["taught_world"], "engine": engine}}


def test_a_world_s_engine_wins_over_the_worker_s_and_the_execution_s_over_the_world_s(stack, skill_id):
    """On the MuJoCo worker, the skill whose world names PyBullet and a request naming no engine: PyBullet ran it
    (the world's engine, not the worker's default); the same request naming MuJoCo: MuJoCo (the execution's own)."""
    skill = _in_world_on(stack, skill_id, "pybullet")
    world_s = stack.post("/executions", {"skill": skill}, 202)
    execution_s = stack.post("/executions", {"skill": skill, "engine": "mujoco"}, 202)
    for execution, engine in ((world_s, "pybullet"), (execution_s, "mujoco")):
        view = stack.finished(execution["id"], timeout_s=180)
        assert view["status"] == "done", view
        assert view["metrics"]["engine"] == engine
        assert view["metrics"]["true_force_rms_error_pct"] <= SLIDE_RMS_PCT, view["metrics"]


def test_a_sweep_naming_no_engine_runs_on_its_world_s(stack, skill_id):
    """A sweep without ``settings.engine`` of the skill whose world names MuJoCo: every trial on MuJoCo (the stored
    request says so); the same sweep in the scenario's world (which names none): PyBullet."""
    skill = _in_world_on(stack, skill_id, "mujoco")
    [in_world] = _sweep_trials(stack, skill_id, {}, skill=skill)
    assert in_world["engine"] == "mujoco" and in_world["metrics"]["engine"] == "mujoco", in_world
    assert in_world["status"] == "done", in_world
    [in_scenario] = _sweep_trials(stack, skill_id, {}, skill=skill, scenario="slide_flat")
    assert in_scenario["engine"] == "pybullet" and in_scenario["metrics"]["engine"] == "pybullet", in_scenario


def test_an_unknown_engine_is_refused_naming_the_field(stack, skill_id):
    """``POST /sweeps`` with ``settings.engine: ode``: a 422 whose error names ``engine``."""
    response = stack.http.post("/sweeps", json={"skill_id": skill_id, "vary": {"friction": {"low": 0.1, "high": 0.2}},
                                                "settings": {"engine": "ode"}})  # fmt: skip
    assert response.status_code == 422, response.text
    assert [e["loc"][-1] for e in response.json()["detail"]] == ["engine"]


@pytest.mark.parametrize(
    ("argv", "env", "said"),
    [
        (["worker", "--engine", "ode"], {}, "--engine: invalid choice: 'ode'"),
        (["worker"], {ENV_ENGINE: "ode"}, f"{ENV_ENGINE}='ode': not an engine (give one of pybullet, mujoco)"),
    ],
)
def test_a_worker_refuses_an_unknown_engine_by_name(argv, env, said):
    """A worker told an unknown engine, by flag or variable, exits 2 naming it (before it connects anywhere)."""
    done = subprocess.run([sys.executable, "-m", "cli.main", *argv], env={**os.environ, **env}, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and said in done.stderr, done.stderr
