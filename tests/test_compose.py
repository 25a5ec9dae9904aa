"""docker-compose.yml and the Dockerfile agree with the code (no Docker engine needed): services, commands,
environment variables, ports, the installed entry point."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")

from cli.main import build_parser  # noqa: E402
from schemas import bus as bus_contract  # noqa: E402
from services.settings import DEFAULT_PORT, ENV_VARS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
COMPOSE = yaml.safe_load((REPO / "docker-compose.yml").read_text())
DOCKERFILE = (REPO / "Dockerfile").read_text()
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
KNOWN_ENV = set(ENV_VARS.values()) | {bus_contract.ENV_ENDPOINTS, bus_contract.ENV_PREFIX, bus_contract.ENV_LISTEN}


def _command(service: dict) -> list[str]:
    command = service.get("command", [])
    return command.split() if isinstance(command, str) else list(command)


def _dockerfile_json(instruction: str) -> list[str]:
    import json

    match = re.search(rf"^{instruction}\s+(\[.*\])\s*$", DOCKERFILE, re.MULTILINE)
    assert match, f"Dockerfile has no exec-form {instruction}"
    return json.loads(match[1])


def test_services_exist_and_use_the_right_images():
    services = COMPOSE["services"]
    assert {"router", "api", "worker"} <= set(services)
    assert services["router"]["image"].startswith("eclipse/zenoh")
    assert "build" in services["api"]
    assert services["worker"]["image"] == services["api"]["image"]  # same built image
    assert "build" not in services["worker"] or services["worker"]["build"] == services["api"]["build"]


def test_commands_are_real_subcommands():
    entrypoint = _dockerfile_json("ENTRYPOINT")
    assert entrypoint == ["contact-skills"]
    assert "contact-skills" in PYPROJECT["project"]["scripts"]
    parser = build_parser()
    for name in ("api", "worker"):
        argv = _command(COMPOSE["services"][name])
        args = parser.parse_args(argv)  # exits (SystemExit) on an unknown subcommand or flag
        assert args.command == name
    parser.parse_args(_dockerfile_json("CMD"))


def test_environment_variables_are_read_by_the_settings():
    for name in ("api", "worker"):
        env = COMPOSE["services"][name].get("environment", {})
        names = set(env) if isinstance(env, dict) else {item.split("=", 1)[0] for item in env}
        assert names <= KNOWN_ENV, names - KNOWN_ENV
        assert names, f"{name} sets no environment"
    api_env = COMPOSE["services"]["api"]["environment"]
    assert api_env["CONTACT_SKILLS_HOST"] == "0.0.0.0"  # inside the container only
    assert api_env[bus_contract.ENV_ENDPOINTS] == "tcp/router:7447"
    assert COMPOSE["services"]["worker"]["environment"][bus_contract.ENV_ENDPOINTS] == "tcp/router:7447"
    for var in re.findall(r"^ENV\s+(\w+)=", DOCKERFILE, re.MULTILINE):
        assert var in KNOWN_ENV or not var.startswith("CONTACT_SKILLS_"), var


def test_ports_match_the_defaults():
    api_ports = COMPOSE["services"]["api"]["ports"]
    assert any(p.endswith(f":{DEFAULT_PORT}") and p.startswith("127.0.0.1:") for p in api_ports)
    assert str(DEFAULT_PORT) in COMPOSE["services"]["api"]["environment"]["CONTACT_SKILLS_PORT"]
    router_port = bus_contract.DEFAULT_ENDPOINT.rsplit(":", 1)[1]
    assert router_port == "7447"
    assert any(p.endswith(f":{router_port}") for p in COMPOSE["services"]["router"]["ports"])
    assert f"tcp/0.0.0.0:{router_port}" in _command(COMPOSE["services"]["router"])
    assert re.search(rf"^EXPOSE\s+{DEFAULT_PORT}\b", DOCKERFILE, re.MULTILINE)


def test_database_is_on_a_named_volume():
    volumes = COMPOSE["services"]["api"]["volumes"]
    mounted = {v.split(":", 1)[0]: v.split(":", 1)[1] for v in volumes}
    named = [name for name in mounted if name in (COMPOSE.get("volumes") or {})]
    assert named, "the API's database needs a named volume"
    db = COMPOSE["services"]["api"]["environment"]["CONTACT_SKILLS_DB"]
    assert db.startswith(mounted[named[0]].rstrip("/") + "/")


def test_the_dockerfile_installs_the_project():
    name = PYPROJECT["project"]["name"]
    built = re.search(r"pip (?:wheel|install)\b[^\n]*\"\.\[service\]\"", DOCKERFILE)
    installed = re.search(rf"pip install\b[^\n]*(\"{name}\[service\]\"|\"\.\[service\]\")", DOCKERFILE)
    assert built and installed, "the Dockerfile must build and install the project with its service extra"
    assert "contact-skills --help" in DOCKERFILE  # the entry point runs in the image
    copied = set(re.findall(r"^COPY\s+(\S+)", DOCKERFILE, re.MULTILINE))
    packages = PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]
    for package in packages:
        name = package.rstrip("*")
        assert f"{name}/" in copied, f"Dockerfile does not copy {name}/"
    assert "pyproject.toml" in " ".join(copied)


def test_the_api_is_healthy_on_health_and_the_workers_wait_for_it():
    api, worker = COMPOSE["services"]["api"], COMPOSE["services"]["worker"]
    check = " ".join(api["healthcheck"]["test"])
    assert f"http://127.0.0.1:{api['environment']['CONTACT_SKILLS_PORT']}/health" in check
    assert api["healthcheck"]["test"][0] == "CMD" and api["healthcheck"]["test"][1] == "python"  # in the image
    assert worker["depends_on"]["api"] == {"condition": "service_healthy"}
    assert api["depends_on"]["router"]["condition"] == "service_started"
    from services.api.routes.health import router

    assert "/health" in {route.path for route in router.routes}


def test_built_images_are_built_not_pulled_and_every_service_has_an_init():
    services = COMPOSE["services"]
    for name in ("api", "worker"):
        assert services[name]["pull_policy"] == "build" and services[name]["build"] == services["api"]["build"]
    assert all(service.get("init") is True for service in services.values())


def test_no_anonymous_volume_per_worker():
    assert not re.search(r"^VOLUME\b", DOCKERFILE, re.MULTILINE), "VOLUME gives every container an anonymous volume"
    assert "volumes" not in COMPOSE["services"]["worker"]


def test_zenoh_is_the_same_version_in_the_router_image_and_the_python_package():
    router_tag = COMPOSE["services"]["router"]["image"].split(":", 1)[1]
    [pin] = [d for d in PYPROJECT["project"]["optional-dependencies"]["service"] if d.startswith("eclipse-zenoh")]
    assert pin.split("==", 1)[1] == router_tag, (pin, router_tag)
    from importlib import metadata

    assert metadata.version("eclipse-zenoh") == router_tag


def test_the_build_context_leaves_out_what_the_image_does_not_need():
    ignored = [line.strip() for line in (REPO / ".dockerignore").read_text().splitlines() if line.strip()]
    ignored = [line for line in ignored if not line.startswith("#")]
    assert {".venv", ".git", "*.db", "tests"} <= set(ignored)
    copied = {c.rstrip("/") for c in re.findall(r"^COPY\s+(?!--)(.+?)\s+\S+$", DOCKERFILE, re.MULTILINE)}
    copied = {name for group in copied for name in group.split()}
    assert not copied & set(ignored), copied & set(ignored)


def test_the_secure_compose_file_runs_real_commands_with_generated_logins(tmp_path):
    from services.bus_keys import generate_bus_keys
    from services.settings import ServiceSettings

    secure = yaml.safe_load((REPO / "docker-compose.secure.yml").read_text())["services"]
    parser = build_parser()
    router = parser.parse_args(_command(secure["router"]))
    assert router.command == "router" and router.users == "/keys/users.txt" and router.tls_cert == "/keys/router.pem"
    assert all(endpoint.startswith("tls/") for endpoint in router.listen)
    generate_bus_keys(tmp_path, ["router"], 2, ca_path="/keys/ca.pem", endpoint="tls/router:7447")
    for name, login in (("api", "api"), ("worker", "worker-1")):
        assert parser.parse_args(_command(secure[name])).command == name
        assert secure[name]["env_file"] == [f"./bus-keys/{login}.env"]
        env = dict(line.split("=", 1) for line in (tmp_path / f"{login}.env").read_text().splitlines())
        assert env["CONTACT_SKILLS_ZENOH_TLS_CA"] == "/keys/ca.pem"
        assert env["CONTACT_SKILLS_ZENOH_ENDPOINTS"] == "tls/router:7447"
        assert "./bus-keys/ca.pem:/keys/ca.pem:ro" in secure[name]["volumes"]
    api_env = {k: ("t0ken" if "$" in v else v) for k, v in secure["api"]["environment"].items()}
    assert ServiceSettings.from_env(api_env).token_reads and secure["api"]["environment"]["CONTACT_SKILLS_TOKEN"]
