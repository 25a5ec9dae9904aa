"""The `contact-skills` command line: `learn` on the real KU Leuven recordings, `demo-learn`, and its errors."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import KULEUVEN_DATA, README_CF_Z_TOOL

from cli.main import main
from corpus.synthetic import plane_slide
from schemas import Demonstration, Skill
from schemas.import_options import CsvImportOptions
from services.csv_import import demonstration_from_csv
from services.datasets import DATA_ENV, KULEUVEN_IMPORT, kuleuven_recordings
from services.figures import compliant_frame_axes, forces_in_compliant_frames
from services.quiet_imports import PYBULLET_BANNER
from skills.quaternions import matrix_from_quaternion

REPO = Path(__file__).resolve().parents[1]
DATA = KULEUVEN_DATA
TRIALS = ("contour_a_1", "contour_a_2", "contour_b_1", "contour_b_2")
KULEUVEN_ARGS = ["--quaternion-order", "wxyz", "--wrench", "measured-on-tool", "--wrench-frame", "tool", "--no-tare"]


def _run(argv: list[str]) -> tuple[int, str, str]:
    """Run the CLI in-process; return (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _subprocess(args: list[str], cwd: Path, **env: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "PYTHONPATH": str(REPO), **env}
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args], cwd=cwd, env=environment, capture_output=True, text=True, timeout=300
    )


@pytest.fixture(scope="module")
def learned(tmp_path_factory) -> dict[str, tuple[Demonstration, Skill, str]]:
    """Each real trial learned with `contact-skills learn --type contour` (in-process)."""
    out = tmp_path_factory.mktemp("skills")
    results = {}
    for name in TRIALS:
        path = DATA / f"{name}.csv"
        code, stdout, stderr = _run(["learn", str(path), "--type", "contour", *KULEUVEN_ARGS, "-o", str(out / name)])
        assert code == 0, stderr
        skill = Skill.model_validate_json((out / name).read_text())
        demo = demonstration_from_csv(path, CsvImportOptions(**KULEUVEN_IMPORT))
        results[name] = (demo, skill, stdout)
    return results


def _mean_cf_z_in_tool(demo: Demonstration, skill: Skill) -> np.ndarray:
    axes = [compliant_frame_axes(demo, s) for s in skill.segments if s.compliant_frames is not None]
    z = np.concatenate([a.z_tool for a in axes])
    return z.mean(axis=0) / np.linalg.norm(z.mean(axis=0))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize("name", TRIALS)
def test_real_trials_learn_as_contour_skills(learned, name):
    _, skill, stdout = learned[name]
    assert skill.skill_type == "contour" and skill.auto_selection is None
    contact = [s for s in skill.segments if s.kind == "contact"]
    assert contact and all(s.force_dmp is not None and s.compliant_frames is not None for s in contact)
    for text in ("skill type: contour (as asked)", "CF z mean in world", "in tool", "force profile (DMP): min",
                 "DMP reproduction RMS", "import: resampled to 200 Hz", "no sensor offset removed"):  # fmt: skip
        assert text in stdout, (text, stdout)


def test_cf_z_in_the_tool_frame_is_nearly_constant_across_trials(learned):
    """The README's known fact: the contact force direction is fixed in the tool, across trials and mountings."""
    means = {name: _mean_cf_z_in_tool(demo, skill) for name, (demo, skill, _) in learned.items()}
    for name, z in means.items():
        assert abs(z[0]) < 0.1 and 0.55 < z[1] < 0.76 and 0.66 < z[2] < 0.86, (name, z)
        assert _angle_deg(z, np.array(README_CF_Z_TOOL)) < 6.0, (name, z)
    spread = max(_angle_deg(a, b) for a in means.values() for b in means.values())
    assert spread < 6.0, means
    for demo, skill, _ in learned.values():  # within a trial the CF z wanders only a little in the tool frame
        for segment in skill.segments:
            if segment.compliant_frames is not None:
                assert compliant_frame_axes(demo, segment).tool_spread_deg < 12.0


def test_contour_frames_put_the_force_on_cf_z(learned):
    for demo, skill, _ in learned.values():
        f_cf = forces_in_compliant_frames(demo, skill)
        inside = ~np.isnan(f_cf[:, 0])
        assert inside.mean() > 0.9
        assert np.all(f_cf[inside, 2] > 0)  # CF z points along the applied force
        assert np.sqrt(np.mean(f_cf[inside, :2] ** 2)) < 0.1 * np.mean(f_cf[inside, 2])


@pytest.mark.parametrize("name", TRIALS)
def test_auto_picks_contour_on_real_trials(tmp_path, name):
    code, stdout, stderr = _run(["learn", str(DATA / f"{name}.csv"), *KULEUVEN_ARGS, "-o", str(tmp_path / "s.json")])
    assert code == 0, stderr
    skill = Skill.model_validate_json((tmp_path / "s.json").read_text())
    assert skill.skill_type == "contour" and skill.auto_selection.chosen == "contour"
    assert skill.auto_selection.confidence >= 0.8, skill.auto_selection.reason
    assert "skill type: contour (auto, confidence" in stdout


def test_learn_as_a_real_subprocess_writes_skill_and_figure(tmp_path):
    result = _subprocess(
        ["learn", str(DATA / "contour_b_2.csv"), "--type", "contour", *KULEUVEN_ARGS, "--basis", "150",
         "-o", "skill.json", "--figure", "fig/learn.png"],
        cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    skill = Skill.model_validate_json((tmp_path / "skill.json").read_text())
    assert len(skill.segments[0].position_dmp.centers) == 150  # more than the 25/s default gives for 4.5 s
    assert (tmp_path / "fig" / "learn.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "figure written to fig/learn.png" in result.stdout and "Traceback" not in result.stderr


def test_demo_learn_writes_out_skill_and_figure(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, stdout, stderr = _run(["demo-learn"])
    assert code == 0, stderr
    assert "contour_a_1.csv" in stdout and "skill type: contour" in stdout
    assert Skill.model_validate_json((tmp_path / "out" / "skill.json").read_text()).skill_type == "contour"
    assert (tmp_path / "out" / "learn.png").stat().st_size > 10_000


def test_data_directory_override(tmp_path, monkeypatch):
    monkeypatch.setenv(DATA_ENV, str(tmp_path))
    assert kuleuven_recordings() == []
    code, _, stderr = _run(["demo-learn", "--out-dir", str(tmp_path / "out")])
    assert code == 2 and DATA_ENV in stderr and "Traceback" not in stderr
    (tmp_path / "kuleuven_contour").mkdir()
    (tmp_path / "kuleuven_contour" / "contour_x_1.csv").write_text("t\n")
    assert [p.name for p in kuleuven_recordings()] == ["contour_x_1.csv"]


# --------------------------------------------------------------------------- errors


def _csv_with_nan(path: Path) -> Path:
    t = np.arange(100) * 0.01
    rows = np.column_stack([t, np.zeros((100, 3)), np.tile([0, 0, 0, 1.0], (100, 1)), np.zeros((100, 6))])
    rows[:, 10] = 5.0
    rows[41, 10] = np.nan
    header = "t,px,py,pz,qx,qy,qz,qw,fx,fy,force_z,mx,my,mz"
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.6g")
    return path


def test_nan_in_a_column_exits_2_naming_it(tmp_path):
    path = _csv_with_nan(tmp_path / "nan.csv")
    code, stdout, stderr = _run(["learn", str(path), "-o", str(tmp_path / "s.json")])
    assert code == 2 and stdout == ""
    assert "column 'force_z' (fz), line 43: 'nan' is not finite" in stderr
    assert not (tmp_path / "s.json").exists()
    result = _subprocess(["learn", str(path), "-o", "s.json"], cwd=tmp_path)
    assert result.returncode == 2
    assert "contact-skills learn: error: column 'force_z'" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--columns", "t=time,force=F"], "--columns: unknown key 'force'"),
        (["--columns", "fz=Fz_missing"], "column 'Fz_missing' given for fz is not in the header"),
        (["--rate", "-5"], "rate: -5.0 Hz"),
    ],
)
def test_bad_options_exit_2(tmp_path, args, expected):
    path = _csv_with_nan(tmp_path / "d.csv")
    code, _, stderr = _run(["learn", str(path), *args, "-o", str(tmp_path / "s.json")])
    assert code == 2 and expected in stderr, stderr


def test_missing_file_and_invalid_json_exit_2(tmp_path):
    code, _, stderr = _run(["learn", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "s.json")])
    assert code == 2 and "cannot read" in stderr
    bad = {"t": [0.0, 1.0], "positions": [[0, 0, 0]], "orientations": [[0, 0, 0, 1]] * 2, "wrenches": [[0] * 6] * 2}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    code, _, stderr = _run(["learn", str(tmp_path / "bad.json"), "-o", str(tmp_path / "s.json")])
    assert code == 2 and "error: t: needs at least 50 samples" in stderr
    assert all(line.startswith("contact-skills learn: error: ") for line in stderr.splitlines())


def test_a_demonstration_without_contact_exits_2(tmp_path):
    t = np.arange(200) * 0.01
    positions = np.column_stack([0.4 + 0.1 * t, np.zeros(200), np.full(200, 0.3)])
    demo = Demonstration.from_arrays(t, positions, np.tile([0, 0, 0, 1.0], (200, 1)), np.zeros((200, 6)))
    (tmp_path / "free.json").write_text(demo.model_dump_json())
    code, _, stderr = _run(["learn", str(tmp_path / "free.json"), "--type", "contour", "-o", str(tmp_path / "s.json")])
    assert code == 2 and "error: wrenches:" in stderr, stderr


def test_learn_a_file_without_time_column_at_a_given_rate(tmp_path):
    """A kinesthetic recording at 100 Hz with no time column (w-first quaternions): `--rate 100` gives its time."""
    d = plane_slide(rate_hz=100.0, duration_s=4.0)
    rows = np.column_stack([d.positions, d.orientations[:, 3], d.orientations[:, :3], d.wrenches])
    path = tmp_path / "kinesthetic.csv"
    np.savetxt(path, rows, delimiter=",", header="x,y,z,qw,qx,qy,qz,fx,fy,fz,mx,my,mz", comments="", fmt="%.10g")
    skill_path = tmp_path / "s.json"
    code, stdout, stderr = _run(["learn", str(path), "--rate", "100", "--type", "slide", "-o", str(skill_path)])
    assert code == 0, stderr
    assert "import: no time column: rows taken as samples at 100 Hz (dt 0.01 s)" in stdout
    assert f"{len(d.t)} samples, {(len(d.t) - 1) * 0.01:.2f} s, 100 Hz" in stdout
    assert Skill.model_validate_json(skill_path.read_text()).skill_type == "slide"
    code, _, stderr = _run(["learn", str(path), "-o", str(skill_path)])
    assert code == 2 and "missing column for t (time)" in stderr and "--rate HZ or --dt SECONDS" in stderr
    code, _, stderr = _run(["learn", str(path), "--rate", "100", "--dt", "0.02", "-o", str(skill_path)])
    assert code == 2 and "rate and dt disagree" in stderr


def test_learn_a_slide_recorded_from_its_first_contact_sample(tmp_path):
    """A recording cut to its contact (as the KU Leuven files are) starts in contact: its slide's one compliant frame
    sits at the first sample. `learn` prints its summary (it once failed there, reading the tool's orientation from a
    single sample) and the CF z it prints is the true normal, in the world and in the tool."""
    d = plane_slide(normal=(0.0, 0.3, -1.0), rate_hz=200.0)
    rows = (d.t >= d.contact_on_s + 0.3) & (d.t <= d.contact_off_s - 0.3)  # in contact from the first row to the last
    table = np.column_stack([d.t[rows] - d.t[rows][0], d.positions[rows], d.orientations[rows], d.wrenches[rows]])
    path = tmp_path / "cut.csv"
    np.savetxt(path, table, delimiter=",", header="t,x,y,z,qx,qy,qz,qw,fx,fy,fz,mx,my,mz", comments="", fmt="%.10g")
    code, stdout, stderr = _run(["learn", str(path), "--type", "slide", "-o", str(tmp_path / "s.json")])
    assert code == 0, stderr
    skill = Skill.model_validate_json((tmp_path / "s.json").read_text())
    [contact] = [s for s in skill.segments if s.kind.value == "contact"]
    assert contact.t_start == 0.0 and len(contact.compliant_frames.t) == 1
    normal = d.normals[0]
    printed = next(line for line in stdout.splitlines() if "CF normal (z) in world" in line)
    world = np.array([float(x) for x in printed.split("[")[1].rstrip("]").split(",")])
    assert _angle_deg(world, normal) < 1.5, printed
    axes = compliant_frame_axes(demonstration_from_csv(path), contact)
    tool = matrix_from_quaternion(d.orientations[rows][0]).T @ normal
    assert axes.t.size == 1 and _angle_deg(axes.z_tool[0], tool) < 1.5


def test_help_is_light():
    """`contact-skills --help` imports no numeric or plotting library."""
    code = (
        "import sys, cli.main; cli.main.build_parser().format_help(); "
        "print(sorted(m for m in ('numpy', 'scipy', 'pydantic', 'matplotlib', 'sklearn') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.stdout.strip() == "[]", result.stdout + result.stderr


@pytest.mark.parametrize("modules", ["services.app", "sim_worker.zenoh_worker, sim_worker.warm_up"])
def test_a_service_process_starts_without_the_heavy_libraries_it_needs_only_on_request(modules: str) -> None:
    """The API's and a worker's start import neither scipy.stats (half a second of CPU: the statistics of sweeps and
    of the force band load the few functions they need) nor scikit-learn, plotting, MuJoCo or the bag reader: every
    process start pays for what its imports load, and a stack starts several."""
    heavy = ("scipy.stats", "sklearn", "matplotlib", "mujoco", "rosbags")
    code = f"import sys; import {modules}; print(sorted(m for m in {heavy!r} if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.stdout.strip().splitlines()[-1] == "[]", result.stdout + result.stderr


def test_record_to_csv_then_learn_recovers_the_taught_plane(tmp_path: Path) -> None:
    """The teacher's recording survives the CSV round trip: learning from it finds the true normal and force."""
    csv_path, truth_path, skill_path = tmp_path / "demo.csv", tmp_path / "truth.json", tmp_path / "skill.json"
    assert main(["record", "slide_tilted", "-o", str(csv_path), "--truth", str(truth_path)]) == 0
    assert demonstration_from_csv(csv_path).n_samples > 9000
    assert main(["learn", str(csv_path), "-o", str(skill_path)]) == 0
    skill = Skill.model_validate_json(skill_path.read_text())
    truth = json.loads(truth_path.read_text())
    [contact] = [s for s in skill.segments if s.kind.value == "contact"]
    z = matrix_from_quaternion(contact.compliant_frames.orientations[0])[:, 2]
    [slide] = [s for s in truth["segments"] if s["kind"] == "slide"]
    normal = np.asarray(slide["normal"])
    assert np.degrees(np.arccos(np.clip(z @ normal, -1, 1))) < 1.0
    assert contact.force_constant_n == pytest.approx(truth["target_force_n"], rel=0.02)


def test_record_refuses_an_unknown_scenario(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["record", "slide_on_the_moon", "-o", str(tmp_path / "x.json")]) == 2
    assert "slide_on_the_moon" in capsys.readouterr().err


def test_simulate_prints_no_library_banner(learned, tmp_path):
    """PyBullet's C extension prints `pybullet build time: ...` when it is imported (a bare import shows it, so the
    check can see it); a simulating command discards it, whether its output is a pipe or a file."""
    bare = subprocess.run([sys.executable, "-c", "import pybullet"], capture_output=True, text=True, timeout=60)
    assert PYBULLET_BANNER in bare.stdout + bare.stderr
    _, skill, _ = learned["contour_a_1"]
    (tmp_path / "skill.json").write_text(skill.model_dump_json())
    result = _subprocess(["simulate", "skill.json", "--sensor", "ideal"], tmp_path)
    assert result.returncode == 0 and "controller hybrid_cf: done" in result.stdout, result.stderr
    assert PYBULLET_BANNER not in result.stdout + result.stderr


def test_the_cli_reference_page_is_what_the_parser_says():
    """docs/CLI.md is generated from the parser (`python -m cli.reference > docs/CLI.md`): it names every command and
    every argument as `--help` does, and a change to the parser without regenerating it fails here."""
    from cli.main import build_parser
    from cli.reference import reference

    page = (REPO / "docs" / "CLI.md").read_text()
    assert page == reference(build_parser()), "docs/CLI.md is stale: .venv/bin/python -m cli.reference > docs/CLI.md"


def test_the_spelled_out_paces_are_the_schema_s():
    """`--pace` choices are spelled out so that `--help` imports no pydantic: they are `schemas.execution.Pace`."""
    from cli.bus_commands import PACES
    from schemas.execution import Pace

    assert set(PACES) == {pace.value for pace in Pace}


def test_the_spelled_out_engines_are_the_schema_s():
    """`--engine` choices (`worker`, `up`, `simulate`, `sweep`) are spelled out too: `schemas.execution.Engine`."""
    from cli.bus_commands import ENGINES
    from schemas.execution import Engine

    assert set(ENGINES) == {engine.value for engine in Engine}


def test_the_client_commands_find_the_service_by_contact_skills_url(tmp_path):
    """Without --url, `demo`, `sweep` and `export ID` ask the service at $CONTACT_SKILLS_URL: nothing answers at this
    one (and, not named 127.0.0.1 or localhost, it is not one they would start), and each says where it asked."""
    from services.local_processes import free_port

    nobody = f"http://[::1]:{free_port()}"
    for args, code in ((["demo", "--quick"], 1), (["sweep", "slide_flat", "--trials", "1"], 1),
                       (["export", "exec_000000000000", "-o", "run.csv"], 2)):  # fmt: skip
        result = _subprocess(args, tmp_path, CONTACT_SKILLS_URL=nobody)
        assert result.returncode == code and nobody in result.stderr, (args, result.stdout, result.stderr)


def test_a_skill_exports_whole_as_mcap_and_export_says_so_for_another_format(tmp_path):
    """`export skill_...` writes the skill's MCAP (tests/test_foxglove.py reads one back); CSV, or a window, of a skill
    is refused before any request, naming what it takes."""
    for args in (["-o", "skill.csv"], ["-o", "skill.mcap", "--t0", "1"]):
        result = _subprocess(["export", "skill_000000000000", *args, "--url", "http://127.0.0.1:9"], tmp_path)
        assert result.returncode == 2 and "is a skill: it exports whole, as MCAP only" in result.stderr, result.stderr
        assert not (tmp_path / args[1]).exists()
