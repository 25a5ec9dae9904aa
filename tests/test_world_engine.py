"""The engine a WORLD names (issue 44, docs/ENGINES.md "Choosing the engine"): ``WorldConfig.engine`` runs the world
on that engine when the execution names none, over a worker's default, under the execution's own choice. Each row
of the precedence table runs a real execution (the teacher's 1 s flat slide, PyBullet and MuJoCo, no mocked physics)
and is held against a run that named its engine outright: the same telemetry to the last bit, so the engine that
the table says ran is the engine that ran. A world file for ``contact-skills simulate --world`` says its engine; a
world naming an unknown engine is refused naming the field (the CLI's exit 2, the API's 422); a world that names
none is written and read as before the field existed."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")

from cli.main import main
from schemas.execution import DEFAULT_ENGINE, Engine, ExecutionPhase, ExecutionRequest, ExecutionSettings
from schemas.skill import LearnOptions, Skill
from schemas.sweep import SweepRequest
from schemas.world import WorldConfig, engine_to_run, world_engine
from services.sweeps import sweep_engine
from sim_worker.execution_world import execution_world, world_config_from_file_dict
from sim_worker.executor import ExecutionResult, run_skill
from sim_worker.teacher import record_demonstration, scenario_world_config
from skills.parameterize import learn_skill

REPO = Path(__file__).resolve().parents[1]
ENGINES = (None, Engine.pybullet, Engine.mujoco)
"""An execution's or a world's choice: none, or one of the engines."""
VARY = {"offset_z_m": {"low": -0.005, "high": 0.005}}
"""A sweep's varied parameter (any would do: the engine does not depend on it)."""


@pytest.fixture(scope="module")
def skill() -> Skill:
    """The teacher's flat slide with a 1 s stroke (an execution of about 12 s simulated: 1 s on PyBullet, 5 s on
    MuJoCo), learned as a slide; it carries the PyBullet world it was taught in (no engine named)."""
    recording = record_demonstration("slide_flat", seed=0, move_duration_s=1.0)
    return learn_skill(recording.demonstration, LearnOptions(skill_type="slide"))


def _world_file(skill: Skill, engine: Engine | None) -> dict:
    """The skill's taught world as a world file, naming ``engine`` (none: the key left out, as every file before)."""
    world = dict(skill.taught_world or {})
    assert "engine" not in world  # the recorder writes no engine
    return world if engine is None else {**world, "engine": engine.value}


def _run(skill: Skill, requested: Engine | None, world: Engine | None) -> ExecutionResult:
    """The skill run in its world file naming ``world`` (``simulate --world``'s path), the execution naming
    ``requested``."""
    settings = ExecutionSettings(engine=requested)
    return run_skill(execution_world(skill, settings.environment, world=_world_file(skill, world)), settings)


@pytest.fixture(scope="module")
def named_runs(skill) -> dict[Engine, ExecutionResult]:
    """The skill run on each engine named by the execution, in a world that names none: the reference runs."""
    return {engine: _run(skill, engine, None) for engine in Engine}


@pytest.mark.parametrize("requested", ENGINES)
@pytest.mark.parametrize("world", ENGINES)
@pytest.mark.parametrize("default", list(Engine))
def test_the_precedence_is_the_execution_then_the_world_then_the_default(requested, world, default):
    """``schemas.world.engine_to_run``, case by case: the execution's engine if it names one, else the world's, else
    the default (a worker's own; pybullet for a local run or a sweep)."""
    expected = requested if requested is not None else world if world is not None else default
    assert engine_to_run(requested, world, default) is expected


def test_the_reference_runs_differ_by_engine(named_runs):
    """Two engines, two contact models: the runs the table is held against finish, say their engine and are not
    the same numbers (else the comparisons below could not tell the engines apart)."""
    for engine, result in named_runs.items():
        assert result.metrics.phase is ExecutionPhase.done, result.metrics.abort_reason
        assert result.metrics.engine is engine
    pybullet, mujoco = (named_runs[engine].telemetry.data for engine in (Engine.pybullet, Engine.mujoco))
    assert pybullet.shape != mujoco.shape or not np.array_equal(pybullet, mujoco)


@pytest.mark.parametrize(
    ("requested", "world", "runs_on"),
    [
        (None, None, DEFAULT_ENGINE),  # nothing named: pybullet, as before the field
        (None, Engine.mujoco, Engine.mujoco),  # the world's engine
        (None, Engine.pybullet, Engine.pybullet),
        (Engine.pybullet, Engine.mujoco, Engine.pybullet),  # the execution's choice wins over the world's
        (Engine.mujoco, Engine.pybullet, Engine.mujoco),
    ],
)
def test_a_world_s_engine_runs_it_unless_the_execution_names_one(skill, named_runs, requested, world, runs_on):
    """Each row: the metrics name the engine the table says, and the telemetry is bit for bit that of the run that
    named that engine outright (the same world otherwise)."""
    result = _run(skill, requested, world)
    assert result.metrics.engine is runs_on
    assert result.world_config.engine is world
    assert np.array_equal(result.telemetry.data, named_runs[runs_on].telemetry.data)
    assert result.metrics.true_force_rms_error_pct == named_runs[runs_on].metrics.true_force_rms_error_pct


@pytest.mark.parametrize(
    ("given", "runs_on"),
    [
        ({}, Engine.mujoco),  # the trials run in the skill's taught world, which names MuJoCo
        ({"settings": {"engine": "pybullet"}}, Engine.pybullet),  # the sweep's own choice
        ({"scenario": "slide_flat"}, Engine.pybullet),  # the scenario's world names none: pybullet, not a worker's
        ({"settings": {"environment": {"work_piece": "rebuilt"}}}, Engine.pybullet),  # a rebuilt piece: likewise
    ],
)
def test_a_sweep_runs_on_its_engine_else_its_trials_world_s_else_pybullet(skill, given, runs_on):
    """``services.sweeps.sweep_engine``: the order of an execution, with pybullet where a worker's default would be
    (tests/test_engine_choice.py runs such a sweep on a real stack)."""
    taught = skill.model_copy(update={"taught_world": _world_file(skill, Engine.mujoco)})
    request = SweepRequest.model_validate({"skill": taught.model_dump(mode="json"), "vary": VARY, **given})
    assert sweep_engine(request, taught) is runs_on


def _cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def test_simulate_runs_a_world_file_on_the_engine_it_names(skill, named_runs, tmp_path):
    """``contact-skills simulate SKILL --world FILE`` with ``"engine": "mujoco"`` in the file and no ``--engine``:
    MuJoCo ran it (the line says so, the metrics JSON names it, the force error is MuJoCo's run's)."""
    skill_path, world_path, metrics_path = tmp_path / "skill.json", tmp_path / "world.json", tmp_path / "m.json"
    skill_path.write_text(skill.model_dump_json())
    world_path.write_text(json.dumps(_world_file(skill, Engine.mujoco)))
    code, out, err = _cli(["simulate", str(skill_path), "--world", str(world_path), "--json", str(metrics_path)])
    assert code == 0, err
    assert "engine: mujoco (the world's engine; --engine chooses another)" in out
    metrics = json.loads(metrics_path.read_text())
    assert metrics["engine"] == "mujoco"
    assert metrics["true_force_rms_error_pct"] == named_runs[Engine.mujoco].metrics.true_force_rms_error_pct


def test_simulate_refuses_a_world_file_naming_an_unknown_engine(skill, tmp_path):
    """A world file with ``"engine": "ode"``: exit 2 before anything runs, the message naming the field and the
    engines there are."""
    skill_path, world_path = tmp_path / "skill.json", tmp_path / "world.json"
    skill_path.write_text(skill.model_dump_json())
    world_path.write_text(json.dumps({**_world_file(skill, None), "engine": "ode"}))
    code, out, err = _cli(["simulate", str(skill_path), "--world", str(world_path)])
    assert code == 2
    assert "engine: Input should be 'pybullet' or 'mujoco'" in err, err
    assert "controller" not in out  # nothing ran


def test_a_world_naming_no_engine_is_written_and_read_as_before():
    """The key is left out of a world that names none (a recording's world, a truth file, a skill's taught world:
    byte for byte as before the field); a world that names one keeps it through ``replace`` and a JSON round trip;
    an older flat world file loads with no engine."""
    plain = WorldConfig(table={"height_m": 0.12})
    assert "engine" not in plain.to_dict() and '"engine"' not in plain.model_dump_json()
    assert WorldConfig.from_dict(plain.to_dict()) == plain
    named = plain.replace(engine="mujoco")
    assert named.to_dict()["engine"] == "mujoco"
    assert WorldConfig.model_validate_json(named.model_dump_json()).engine is Engine.mujoco
    assert named.replace(table_height_m=0.2).engine is Engine.mujoco  # a flat key changes the table, not the engine
    legacy = WorldConfig.from_dict({"table_height_m": 0.12, "lateral_friction": 0.3})
    assert legacy.engine is None and legacy.table.height_m == 0.12
    assert world_engine(plain.to_dict()) is None and world_engine(None) is None
    assert world_engine(named.to_dict()) is Engine.mujoco
    stored = ExecutionRequest.model_validate({"skill_id": "sk_1", "engine": "pybullet"})  # stored before, as it was
    assert stored.engine is Engine.pybullet


def test_the_example_world_file_is_the_tilted_table_on_mujoco():
    """``data/worlds/slide_tilted_on_mujoco.json`` (docs/ENGINES.md runs it): the ``slide_tilted`` scenario's world,
    field for field, naming MuJoCo."""
    world = world_config_from_file_dict(json.loads((REPO / "data/worlds/slide_tilted_on_mujoco.json").read_text()))
    assert world.engine is Engine.mujoco
    assert world.replace(engine=None) == scenario_world_config("slide_tilted")


def test_the_api_refuses_a_skill_whose_world_names_an_unknown_engine(client, skill):
    """``POST /executions`` and ``POST /sweeps`` with an inline skill whose taught world names ``"engine": "ode"``:
    a 422 on ``skill.taught_world.engine`` naming the engines, before any worker is asked (this API has none: a
    good request would be a 503)."""
    bad = skill.model_copy(update={"taught_world": {**_world_file(skill, None), "engine": "ode"}})
    body = bad.model_dump(mode="json")
    for path, request in (
        ("/executions", {"skill": body}),
        ("/sweeps", {"skill": body, "vary": {"friction": {"low": 0.1, "high": 0.2}}}),
    ):
        response = client.post(path, json=request)
        assert response.status_code == 422, response.text
        [error] = response.json()["detail"]
        assert error["loc"] == ["body", "skill", "taught_world", "engine"], error
        assert "'ode' is not an engine (give one of pybullet, mujoco" in error["msg"]
    good = skill.model_dump(mode="json")
    assert client.post("/executions", json={"skill": good}).status_code == 503  # no worker: the world was fine
