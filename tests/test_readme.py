"""The README's commands run as written, so they cannot rot.

Every ``.venv/bin/contact-skills record|learn|simulate|export FILE`` command in a ```bash block of the README
runs, in the README's order, in a temporary directory that holds the repository's ``data/`` (as
a fresh clone does); outputs go to ``scratch/`` there. The quoted output of the KU Leuven example
(a ``$`` command with its printed lines) must be printed line for line by the same command today.
The commands that need a running service (``up``, ``api``, ``watch``, ``demo``, curl) are tested
by the service tests; here their subcommands must at least exist.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()
CLI = [sys.executable, "-m", "cli.main"]
OFFLINE = ("record", "learn", "simulate", "export")


def _blocks(language: str) -> list[str]:
    """The fenced blocks of the README whose info string is ``language`` ('' for plain ones)."""
    return [body for info, body in re.findall(r"^```(\w*)\n(.*?)^```", README, flags=re.M | re.S) if info == language]


def _commands(block: str) -> list[str]:
    """The shell commands of a block: continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", block)
    lines = [line.split("  #")[0].strip() for line in joined.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def _contact_skills_commands() -> list[list[str]]:
    found = []
    for block in _blocks("bash"):
        for command in _commands(block):
            if command.startswith(".venv/bin/contact-skills "):
                found.append(shlex.split(command)[1:])
    return found


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"}
    return subprocess.run([*CLI, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def clone_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory laid out like the repository's root for the commands: ``data/`` and nothing else."""
    root = tmp_path_factory.mktemp("readme")
    (root / "data").symlink_to(REPO / "data", target_is_directory=True)
    return root


def test_the_readme_shows_the_offline_flows() -> None:
    subcommands = [args[0] for args in _contact_skills_commands()]
    for name in OFFLINE:
        assert name in subcommands, f"the README shows no `contact-skills {name}` command"


def test_every_offline_readme_command_runs_as_written(clone_dir: Path) -> None:
    ran = 0
    for args in _contact_skills_commands():
        if args[0] not in OFFLINE or (args[0] == "export" and not Path(args[1]).suffix):
            continue  # `export ID` needs the service (tests/test_export.py runs it)
        result = _run(args, clone_dir)
        assert result.returncode == 0, f"contact-skills {' '.join(args)}\n{result.stdout}\n{result.stderr}"
        for value in args:  # every file the command names in scratch/ exists afterwards
            if value.startswith("scratch/"):
                assert (clone_dir / value).exists(), value
        ran += 1
    assert ran >= 8


def test_the_quoted_kuleuven_output_is_what_the_command_prints(clone_dir: Path) -> None:
    [block] = [b for b in _blocks("") if b.startswith("$ .venv/bin/contact-skills learn data/kuleuven_contour")]
    command_text, _, printed = block.partition("\ndemonstration ")
    args = shlex.split(re.sub(r"\\\n\s*", " ", command_text.removeprefix("$ ")))[1:]
    result = _run(args, clone_dir)
    assert result.returncode == 0, result.stderr
    for line in ("demonstration " + printed).strip().splitlines():
        assert line in result.stdout, f"README line not printed any more: {line!r}\n{result.stdout}"


def test_service_subcommands_the_readme_shows_exist() -> None:
    shown = {args[0] for args in _contact_skills_commands()} | {"up", "api", "worker", "router", "watch", "demo"}
    for name in sorted(shown):
        result = subprocess.run([*CLI, name, "--help"], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, (name, result.stderr)


def test_the_readme_sweep_runs_as_written_with_fewer_trials(clone_dir: Path) -> None:
    """The README's `contact-skills sweep` command in a fresh clone's layout: nothing serves its --url there, so it
    starts the embedded stack itself, records and learns the scenario, runs the sweep with a progress bar and
    writes the figure and the tables. Only --trials is cut to 2 (6 executions), to keep the suite short."""
    [args] = [a for a in _contact_skills_commands() if a[0] == "sweep"]
    settings = clone_dir / "scratch" / "sweep_settings.json"  # the base settings reach every trial's request
    settings.parent.mkdir(exist_ok=True)
    settings.write_text('{"approach_slow_distance_m": 0.04}')
    args = [*args, "--url", "http://127.0.0.1:8799", "--json", "scratch/readme_sweep.json", "--settings", str(settings)]
    args[args.index("--trials") + 1] = "2"
    result = _run(args, clone_dir)
    assert result.returncode == 0, f"contact-skills {' '.join(args)}\n{result.stdout}\n{result.stderr}"
    assert "starting `contact-skills up" in result.stderr and "done, 6/6 executions" in result.stdout
    for name in ("hybrid_cf", "impedance_found_surface", "hybrid_world_z"):
        assert re.search(rf"^{name} +\d+% \(\d/2\)", result.stdout, flags=re.M), result.stdout
    figure = clone_dir / args[args.index("--figure") + 1]
    assert figure.stat().st_size > 20_000
    stored = json.loads((clone_dir / "scratch" / "readme_sweep.json").read_text())
    assert stored["sweep"]["request"]["settings"]["approach_slow_distance_m"] == 0.04
