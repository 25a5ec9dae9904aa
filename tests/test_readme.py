"""The README's and the docs pages' commands run as written, and their quoted outputs are what the commands print
today, so neither can rot (``tests/docs_commands.py`` finds them and says how each is checked).

Every offline command (``record``, ``learn``, ``simulate``, ``export FILE``, ``bus-keys``) runs in page order in a
directory laid out as a fresh clone (``data/`` and nothing else), outputs in ``scratch/`` there; a quoted run (a
plain block starting with ``$``) runs too and every line it quotes must be printed, in order (``…`` marks a wall-clock
figure). The sweep runs with 2 trials. Commands that serve until stopped, and ``demo`` (4 minutes; tests/test_demo.py
runs ``--quick``), are parsed by the real parser; ``make run`` by ``make -n``. The service flows (curl, the typed
client, the Zenoh snippet) run against the real stack in tests/test_client.py. A command no test checks fails here.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from docs_commands import PAGES, REPO, Check, Step, steps, unmatched_lines

from cli.main import build_parser
from services.local_processes import free_port
from services.quiet_imports import PYBULLET_BANNER
from services.service_url import URL_ENV
from services.settings import ENV_VARS

CLI = [sys.executable, "-m", "cli.main"]
SWEEP_TRIALS = 2


def _run(args: list[str], cwd: Path, **variables: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg", **variables}
    return subprocess.run([*CLI, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def clone_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory laid out like the repository's root for the commands: ``data/`` and nothing else."""
    root = tmp_path_factory.mktemp("readme")
    (root / "data").symlink_to(REPO / "data", target_is_directory=True)
    return root


ALL_STEPS, UNCHECKED = steps()


def test_every_command_of_the_pages_is_checked_by_a_test() -> None:
    assert UNCHECKED == []
    shown = {step.args[0] for step in ALL_STEPS if step.check in (Check.run, Check.quoted) and step.args}
    assert {"record", "learn", "simulate", "export"} <= shown, f"the pages show no offline flow: {shown}"
    assert any(step.check is Check.service for step in ALL_STEPS if step.page == "README.md")


def test_the_readme_fits_one_read() -> None:
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 250
    assert readme.index("make run") < readme.index("## ") and readme.index("make test") < readme.index("## ")
    assert "<!-- contour results -->" in readme.split("## Results", 1)[1].split("\n## ", 1)[0]
    assert "docs/CONVENTIONS.md" in readme and "Where things live" in (REPO / "docs/CONVENTIONS.md").read_text()


def test_the_readme_s_browser_note_is_what_make_and_ci_do() -> None:
    """The README says `make test` installs Chromium as root (`make browser`), says so and skips the browser tests
    otherwise, and that CI's CONTACT_SKILLS_REQUIRE_BROWSER=1 makes a missing one a failure: so the Makefile, .ci/run
    and tests/test_dashboard.py do."""
    readme = " ".join((REPO / "README.md").read_text().split())
    assert "`make test` installs it with apt-get when run as root (`make browser` is that step alone)" in readme
    assert "CI sets `CONTACT_SKILLS_REQUIRE_BROWSER=1`, which makes a missing Chromium a failure" in readme
    makefile = (REPO / "Makefile").read_text()
    assert re.search(r"^test: .*\bbrowser\b", makefile, re.MULTILINE), "make test does not run make browser"
    browser = re.search(r"^browser:\n((?:\t.*\n)+)", makefile, re.MULTILINE)
    assert browser and "apt-get install" in browser[1] and '"$$(id -u)" = 0' in browser[1] and "skip" in browser[1]
    assert "export CONTACT_SKILLS_REQUIRE_BROWSER=1" in (REPO / ".ci" / "run").read_text().split("\nmake test")[0]
    dashboard = (REPO / "tests" / "test_dashboard.py").read_text()
    assert re.search(r'if os\.environ\.get\("CONTACT_SKILLS_REQUIRE_BROWSER"\):.*\n\s+pytest\.fail\(', dashboard)


@pytest.mark.parametrize("page", [*PAGES, "docs/CONVENTIONS.md"])
def test_every_relative_link_of_the_pages_leads_to_a_file(page: str) -> None:
    base = (REPO / page).parent
    found = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", (REPO / page).read_text())
    links = [link for link in found if "://" not in link]
    missing = [link for link in links if not (base / link).exists()]
    assert missing == [], f"{page} links to missing files"


def _check(step: Step, cwd: Path) -> str | None:
    """Run or parse one step as its check says; the problem, or None."""
    if step.check in (Check.run, Check.quoted, Check.sweep):
        args = step.args
        if step.check is Check.sweep:
            settings = cwd / "scratch" / "sweep_settings.json"  # the base settings reach every trial's request
            settings.parent.mkdir(exist_ok=True)
            settings.write_text('{"approach_slow_distance_m": 0.04}')
            args = [*args, "--json", "scratch/sweep.json", "--settings", str(settings)]
            args[args.index("--trials") + 1] = str(SWEEP_TRIALS)
        nobody = f"http://127.0.0.1:{free_port()}"  # where the service is: nowhere, so the sweep starts one there
        result = _run(args, cwd, CONTACT_SKILLS_URL=nobody)
        if result.returncode != 0:
            return f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
        if PYBULLET_BANNER in result.stdout + result.stderr:
            return "printed the pybullet banner"
        missing = unmatched_lines(step.quoted, result.stdout)
        if missing:
            return "quoted lines not printed any more:\n" + "\n".join(missing) + "\n--- printed:\n" + result.stdout
        written = [v for v in args if v.startswith("scratch/") and not (cwd / v).exists()]
        if written:
            return f"did not write {written}"
        if step.check is Check.sweep:
            return _sweep_problem(result, cwd, args, nobody)
        return None
    if step.check is Check.parse:
        if step.env_file is not None and not (cwd / step.env_file).exists():
            return f"{step.env_file} does not exist after the commands before it"
        try:
            build_parser().parse_args(step.args)
        except SystemExit:
            return "the parser refuses it"
        return None
    if step.check is Check.make:
        dry = subprocess.run(["make", "-n", *step.command.split()[1:]], cwd=REPO, capture_output=True, text=True)
        [up] = [line for line in dry.stdout.splitlines() if "contact-skills up" in line]
        given = dict(word.split("=", 1) for word in step.command.split()[2:])
        flags = {"PORT": "--port", "ZENOH_PORT": "--zenoh-port"}
        expected = [f"{flags[name]} {value}" for name, value in given.items()]
        if not all(flag in up for flag in expected):
            return f"`make -n` runs {up!r}"
        build_parser().parse_args(up.split("contact-skills ", 1)[1].split())
        return None
    if step.check is Check.environment:
        name = step.command.split()[1].split("=")[0]
        return None if name in {URL_ENV, *ENV_VARS.values()} else f"{name} is read by no code"
    if step.check is Check.suite:
        return _suite_problem(step.command)
    return None  # docker, service: checked elsewhere (see Check)


def _suite_problem(command: str) -> str | None:
    """A test file the suite has, or a benchmark's ``--smoke`` run one of its tests makes (``make test`` is itself)."""
    named = re.findall(r"tests/test_\w+\.py|benchmarks/bench_\w+\.py", command)
    smoked = "".join(path.read_text() for path in (REPO / "tests").glob("test_benchmarks_smoke*.py"))
    for path in named:
        if not (REPO / path).exists():
            return f"{path} does not exist"
        if path.startswith("benchmarks/") and f'run_smoke("{Path(path).name}"' not in smoked:
            return f"no test runs {path} --smoke"
    return None


def _sweep_problem(result: subprocess.CompletedProcess, cwd: Path, args: list[str], url: str) -> str | None:
    """Nothing serves at ``$CONTACT_SKILLS_URL``: the sweep starts the embedded stack itself on its port, records and
    learns the scenario, runs the sweep with a progress bar and writes the figure and the tables."""
    executions = 3 * SWEEP_TRIALS
    started = f"no service at {url}: starting `contact-skills up" in result.stderr
    if not started or f"done, {executions}/{executions}" not in result.stdout:
        return result.stdout + result.stderr
    for name in ("hybrid_cf", "impedance_found_surface", "hybrid_world_z"):
        if not re.search(rf"^{name} +\d+% \(\d/{SWEEP_TRIALS}\)", result.stdout, flags=re.M):
            return result.stdout
    if (cwd / args[args.index("--figure") + 1]).stat().st_size < 20_000:
        return "figure too small"
    stored = json.loads((cwd / "scratch" / "sweep.json").read_text())
    return None if stored["sweep"]["request"]["settings"]["approach_slow_distance_m"] == 0.04 else "settings lost"


def test_every_command_runs_as_written_and_every_quoted_output_is_printed(clone_dir: Path) -> None:
    """In page order (a page may use what an earlier one wrote): each problem names its page and command."""
    problems, ran = [], set()
    for step in ALL_STEPS:
        if step.check is Check.run and tuple(step.args) in ran:
            continue  # shown again on another page: its files are there already
        ran.add(tuple(step.args))
        problem = _check(step, clone_dir)
        if problem is not None:
            problems.append(f"{step.page}: `{step.command}`: {problem}")
    assert problems == [], "\n\n".join(problems)
    assert {step.page for step in ALL_STEPS} >= {"README.md", "docs/GETTING_STARTED.md", "docs/BUS.md"}, PAGES


def test_a_stale_quoted_line_is_caught() -> None:
    """The comparison fails on a changed figure, passes over a wall-clock one."""
    printed = "peak force 15.95 N; 11.76 s simulated in 0.61 s (real-time factor 19.4)\nverdict: pass (6 checks)\n"
    assert unmatched_lines(("peak force 15.95 N; 11.76 s simulated in … s (real-time factor …)",), printed) == []
    assert unmatched_lines(("peak force 15.96 N; 11.76 s simulated in … s (real-time factor …)",), printed) != []
    assert unmatched_lines(("verdict: pass (6 checks)", "peak force 15.95 N; …"), printed) != []  # order counts
