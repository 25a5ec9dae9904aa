"""The command line as a new user meets it: --version, help on every option, plain help text with examples, defaults
the help states that are the defaults used, `up` refusing ports that are taken, `watch` on an unknown id answering at
once (the API) or within --wait (the bus alone), `demo` exiting 1 on a missed target unless --report-only."""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from waiting import wait_for

from cli.main import build_parser
from services.local_processes import free_port, stop_process, wait_for_port
from services.settings import ENV_VARS, ServiceSettings

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _cli(*args: str, timeout: float = 60, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cli.main", *args], env=env or ENV, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    [action] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def test_version_is_the_package_version():
    result = _cli("--version")
    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    assert result.returncode == 0 and result.stdout.strip() == f"contact-skills {version}"


def test_every_option_of_every_command_has_help():
    for name, parser in _subparsers().items():
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"contact-skills {name}: {action.option_strings or action.dest} has no help"


def test_help_is_plain_text_with_examples():
    for name, parser in _subparsers().items():
        text = parser.format_help()
        assert "`" not in text, f"contact-skills {name} --help shows markup:\n{text}"
        examples = text.split("examples:\n", 1)
        assert len(examples) == 2, f"contact-skills {name} --help has no examples"
        lines = [line for line in examples[1].splitlines() if line.strip()]
        assert lines and all(line.startswith(f"  contact-skills {name}") for line in lines), lines
    assert "`" not in build_parser().format_help()


def _same(stated: str, default: object) -> bool:
    if isinstance(default, int | float) and not isinstance(default, bool):
        return float(stated) == float(default)
    return stated == str(default)


def test_stated_defaults_are_the_defaults():
    """'(default X)' is argparse's default; 'default $ENV or X' is what the settings use without the variable."""
    settings = ServiceSettings()
    for name, parser in _subparsers().items():
        for action in parser._actions:
            help_text = action.help or ""
            for env, value in re.findall(r"default \$(\w+) or ([\w./:-]+)", help_text):
                fields = [f for f, var in ENV_VARS.items() if var == env]
                if fields and isinstance(getattr(settings, fields[0]), int | float):
                    assert _same(value, getattr(settings, fields[0])), f"{name} {action.dest}: {help_text}"
            stated = re.search(r"\(default ([\w./-]+)\)", help_text)
            if stated and action.default not in (None, False):
                assert _same(stated[1], action.default), f"{name} {action.dest}: {help_text}"
    assert " ".join(_subparsers()["up"].format_help().split()).count("$CONTACT_SKILLS_WORKERS or 1)") == 1


@pytest.mark.parametrize("which", ["http", "zenoh"])
def test_up_refuses_a_taken_port_before_starting_anything(which):
    port, zenoh_port = free_port(), free_port()
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", port if which == "http" else zenoh_port))
        holder.listen()
        result = _cli("up", "--port", str(port), "--zenoh-port", str(zenoh_port), timeout=30)
    assert result.returncode == 2, result.stdout + result.stderr
    taken = f"HTTP port {port}" if which == "http" else f"Zenoh router port {zenoh_port}"
    assert f"{taken} on 127.0.0.1 already in use" in result.stderr and "ready" not in result.stdout
    assert "started api" not in result.stdout


@pytest.mark.parametrize("launcher", ["make", "flags"])
def test_a_taken_port_is_answered_with_free_ports_in_the_words_the_user_started_with(launcher):
    """The hint named `curl http://127.0.0.1:<this port>/health` when only the Zenoh port was held (nothing answers
    there) and told a `make run` user to use --port and --zenoh-port: it names the /health of a held HTTP port only,
    and free ports as `make run PORT= ZENOH_PORT=` under make (which exports MAKELEVEL), else as the flags."""
    port, zenoh_port = free_port(), free_port()
    env = {k: v for k, v in ENV.items() if k != "MAKELEVEL"} | ({"MAKELEVEL": "1"} if launcher == "make" else {})
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", zenoh_port))
        holder.listen()
        result = _cli("up", "--port", str(port), "--zenoh-port", str(zenoh_port), env=env, timeout=30)
    assert result.returncode == 2 and "started" not in result.stdout, result.stdout + result.stderr
    assert "/health" not in result.stderr, result.stderr
    suggested = re.search(r"run this one on free ports: (.+)$", result.stderr.strip())
    assert suggested, result.stderr
    if launcher == "make":
        [(again, zenoh_again)] = re.findall(r"^make run PORT=(\d+) ZENOH_PORT=(\d+)$", suggested[1])
    else:
        [(again, zenoh_again)] = re.findall(r"^contact-skills up --port (\d+) --zenoh-port (\d+)$", suggested[1])
    assert int(again) == port and int(zenoh_again) > zenoh_port  # the free HTTP port kept, the held one moved


def test_each_instance_keeps_its_own_database_and_one_database_has_one_api(tmp_path):
    """A second `make run` on other ports silently shared ./contact_skills.db with the first: an instance on another
    port than 8000 keeps ./contact_skills_<port>.db unless told (--db, CONTACT_SKILLS_DB); told to share a live one,
    `up` and `api` refuse naming its holder (two APIs on one file fail each other's runs); its end frees it. What it
    leaves beside the database (the ballast, the claim) is git-ignored like the database, so `git status` stays
    clean after a `make run`."""
    from services.store.owner import database_owner

    port, zenoh_port = free_port(), free_port()
    log_path = tmp_path / "up.log"
    env = {k: v for k, v in ENV.items() if not k.startswith("CONTACT_SKILLS_")}
    with log_path.open("w") as log:
        first = subprocess.Popen([sys.executable, "-m", "cli.main", "up", "--workers", "0", "--port", str(port),
                                  "--zenoh-port", str(zenoh_port)], cwd=tmp_path, env=env, stdout=log,
                                 stderr=subprocess.STDOUT)  # fmt: skip
    try:
        ready = wait_for(lambda: re.search(r"ready: .*$", log_path.read_text(), re.MULTILINE), 120, "up's ready line")
        own = f"contact_skills_{port}.db"
        assert f"db {own}" in ready[0] and f"export CONTACT_SKILLS_URL=http://127.0.0.1:{port}" in ready[0], ready[0]
        assert (tmp_path / own).is_file() and not (tmp_path / "contact_skills.db").exists()
        holder = database_owner(tmp_path / own)
        assert holder is not None and holder.endswith(f"http://127.0.0.1:{port}"), holder
        shared = ["--db", str(tmp_path / own), "--port", str(free_port())]
        again = _cli("up", *shared, "--zenoh-port", str(free_port()), env=env, timeout=30)
        api = _cli("api", "--no-bus", *shared, env=env, timeout=30)
        for result in (again, api):
            assert result.returncode == 2, result.stdout + result.stderr
            assert f"is in use by another API ({holder})" in result.stderr and "--db" in result.stderr, result.stderr
        assert "started" not in again.stdout
    finally:
        stop_process(first)
    assert database_owner(tmp_path / own) is None
    left = sorted(path.name for path in tmp_path.iterdir() if path != log_path)  # the database and its companions
    assert own in left and ".owner" in " ".join(left), left
    ignored = subprocess.run(["git", "check-ignore", "--no-index", *left], cwd=REPO, capture_output=True, text=True)
    assert sorted(ignored.stdout.split()) == left, f"git status would show {set(left) - set(ignored.stdout.split())}"


def test_up_is_ready_when_health_shows_its_worker_idle(tmp_path):
    """`up` said ready once the API answered; the worker connected after that, and /health showed it missing, then
    busy/unknown until the API next asked it (1-10 s): from ready on, /health shows the worker idle, at every ask."""
    import json
    import urllib.request

    port = free_port()
    log_path = tmp_path / "up.log"
    with log_path.open("w") as log:
        up = subprocess.Popen([sys.executable, "-m", "cli.main", "up", "--workers", "1", "--port", str(port),
                               "--zenoh-port", str(free_port()), "--db", str(tmp_path / "up.db")], env=ENV,
                              stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        wait_for(lambda: "ready:" in log_path.read_text(), 120, "up's ready line", every_s=0.02)
        shown = []
        for _ in range(10):
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=30) as response:
                shown.append([(w["worker_id"], w["busy"], w["activity"]) for w in json.load(response)["workers"]])
        assert shown == [[("worker-1", False, "idle")]] * 10, (shown, log_path.read_text())
    finally:
        stop_process(up)


def test_watch_an_unknown_id_asks_the_api_or_gives_up_on_the_bus(tmp_path):
    port, zenoh_port = free_port(), free_port()
    log = (tmp_path / "log").open("w")
    api = subprocess.Popen([sys.executable, "-m", "cli.main", "api", "--no-bus", "--port", str(port), "--db",
                            str(tmp_path / "w.db")], env=ENV, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    router = subprocess.Popen([sys.executable, "-m", "cli.main", "router", "--listen", f"tcp/127.0.0.1:{zenoh_port}"],
                              env=ENV, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        wait_for_port(port, 60)
        wait_for_port(zenoh_port, 60)
        connect = ["--connect", f"tcp/127.0.0.1:{zenoh_port}"]
        asked = _cli("watch", "exec_000000000000", "--url", f"http://127.0.0.1:{port}", *connect)
        assert asked.returncode == 2
        assert "no execution with id 'exec_000000000000' (asked the API at" in asked.stderr
        nobody = f"http://127.0.0.1:{free_port()}"  # no API there: the bus alone
        alone = _cli("watch", "exec_000000000000", "--url", nobody, *connect, "--wait", "2")
        assert alone.returncode == 3
        assert "no status from exec_000000000000 on the bus" in alone.stderr and "within 2 s" in alone.stderr
    finally:
        stop_process(api)
        stop_process(router)
        log.close()


def test_watch_with_no_api_says_which_url_it_asked_and_the_setting_as_export_does(tmp_path):
    """`watch` with no API answering and no router named waited for the default router (12.7 s) and then printed a
    Zenoh error ending in a Rust source path: now it says at once which URL it asked and the setting that points
    elsewhere, in the words `export` uses (one message, the typed client's)."""
    nobody = f"http://127.0.0.1:{free_port()}"
    env = {k: v for k, v in ENV.items() if k != "CONTACT_SKILLS_ZENOH_ENDPOINTS"} | {"CONTACT_SKILLS_URL": nobody}
    watched = _cli("watch", "exec_000000000000", env=env)
    exported = _cli("export", "exec_000000000000", "-o", str(tmp_path / "run.mcap"), env=env)
    assert watched.returncode == exported.returncode == 2, watched.stderr + exported.stderr
    said = watched.stderr.strip().removeprefix("contact-skills watch: error: ")
    assert said == exported.stderr.strip().removeprefix("contact-skills export: error: ")
    assert said.startswith(f"the API at {nobody} does not answer") and "CONTACT_SKILLS_URL" in said
    assert "zenoh" not in watched.stderr.lower() and not (tmp_path / "run.mcap").exists()


def test_a_router_that_does_not_answer_is_named_without_zenoh_source_paths():
    """The bus's connection error ended in ``at /root/.cargo/.../orchestrator.rs:388.``: the endpoint, not Rust."""
    from services.bus import open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with pytest.raises(ConnectionError) as raised:
        open_session("client", connect=[endpoint], wait_s=0.0)
    assert endpoint in str(raised.value) and ".rs:" not in str(raised.value)


def test_the_warm_up_of_make_run_and_make_test_prints_no_banner():
    """`make run` and `make test` began with PyBullet's `pybullet build time: ...` (``python -m sim_worker.warm_up``
    imported it bare): they run `contact-skills warm-up`, which prints its one line and nothing of PyBullet's."""
    makefile = (REPO / "Makefile").read_text()
    for target in ("run", "test"):
        recipe = re.search(rf"^{target}:.*\n((?:\t.*\n)+)", makefile, re.MULTILINE)
        assert recipe and "\t$(BIN)/contact-skills warm-up" in recipe[1], f"make {target}: {recipe}"
    assert "sim_worker.warm_up" not in makefile
    result = _cli("warm-up", timeout=300)
    assert result.returncode == 0, result.stderr
    assert re.fullmatch(r"compiled code ready in \d+\.\d s\n", result.stdout) and result.stderr == "", result


def test_demo_exits_1_on_a_missed_target_unless_report_only(monkeypatch, capsys):
    """The exit code contract of `contact-skills demo` (the run itself is tests/test_demo.py's)."""
    import experiments.paper_demo as paper_demo
    from experiments.cases import DemoReport, TargetVerdict

    verdicts = [TargetVerdict("ours < 3 %", True, "1.3 %"), TargetVerdict("impedance >= 3x ours", False, "1.7x")]
    monkeypatch.setattr(paper_demo, "run_demo", lambda options: DemoReport([], verdicts, {}))
    parser = build_parser()
    assert parser.parse_args(["demo"]).run(parser.parse_args(["demo"])) == 1
    assert "1 target(s) MISSED" in capsys.readouterr().err
    args = parser.parse_args(["demo", "--report-only"])
    assert args.run(args) == 0
    monkeypatch.setattr(paper_demo, "run_demo", lambda options: DemoReport([], verdicts[:1], {}))
    assert args.run(parser.parse_args(["demo"])) == 0
