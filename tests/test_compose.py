"""docker-compose.yml, docker-compose.secure.yml and the Dockerfile agree with the code (no Docker engine needed):
services, commands, environment variables, ports, the installed entry point; the bus secured as shipped (the logins
made by a one-shot service into volumes owned by the image's user, which the router reads; each scaled worker claims
its own login; the numba cache warmed as the runtime user). Where a Docker engine runs, the compose file itself is
brought up with two workers (skipped with the reason elsewhere)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml")

from cli.main import build_parser  # noqa: E402
from schemas import bus as bus_contract  # noqa: E402
from schemas import bus_security  # noqa: E402
from services.settings import DEFAULT_FOXGLOVE_PORT, DEFAULT_PORT, ENV_VARS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
COMPOSE = yaml.safe_load((REPO / "docker-compose.yml").read_text())
SECURE = yaml.safe_load((REPO / "docker-compose.secure.yml").read_text())
DOCKERFILE = (REPO / "Dockerfile").read_text()
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
KNOWN_ENV = set(ENV_VARS.values()) | {bus_contract.ENV_ENDPOINTS, bus_contract.ENV_PREFIX, bus_contract.ENV_LISTEN,
                                        bus_security.ENV_LOGINS, bus_security.ENV_TLS_CA}  # fmt: skip


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
    assert {"bus-keys", "router", "api", "worker"} <= set(services)
    assert {s["image"] for s in services.values()} == {services["api"]["image"]}  # one image, the router's too
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
    # the Foxglove live view listens where the API does (0.0.0.0 in the container), published on the host's loopback
    assert f"127.0.0.1:{DEFAULT_FOXGLOVE_PORT}:{DEFAULT_FOXGLOVE_PORT}" in api_ports
    assert re.search(rf"^EXPOSE\s+.*\b{DEFAULT_FOXGLOVE_PORT}\b", DOCKERFILE, re.MULTILINE)
    assert SECURE["services"]["api"]["environment"]["CONTACT_SKILLS_TOKEN_READS"] == "true"  # there it is off
    assert str(DEFAULT_PORT) in COMPOSE["services"]["api"]["environment"]["CONTACT_SKILLS_PORT"]
    router_port = bus_contract.DEFAULT_ENDPOINT.rsplit(":", 1)[1]
    assert router_port == "7447"
    assert COMPOSE["services"]["router"]["ports"] == [f"127.0.0.1:{router_port}:{router_port}"]  # the host's only
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
    for name in ("bus-keys", "api", "worker"):
        assert services[name]["pull_policy"] == "build" and services[name]["build"] == services["api"]["build"]
    assert all(service.get("init") is True for service in services.values())


def test_no_anonymous_volume_per_worker():
    assert not re.search(r"^VOLUME\b", DOCKERFILE, re.MULTILINE), "VOLUME gives every container an anonymous volume"
    assert COMPOSE["services"]["worker"]["volumes"] == ["cskills-worker-logins:/worker-logins"]  # its logins only


def test_the_build_context_leaves_out_what_the_image_does_not_need():
    ignored = [line.strip() for line in (REPO / ".dockerignore").read_text().splitlines() if line.strip()]
    ignored = [line for line in ignored if not line.startswith("#")]
    assert {".venv", ".git", "*.db", "tests"} <= set(ignored)
    copied = {c.rstrip("/") for c in re.findall(r"^COPY\s+(?!--)(.+?)\s+\S+$", DOCKERFILE, re.MULTILINE)}
    copied = {name for group in copied for name in group.split()}
    assert not copied & set(ignored), copied & set(ignored)


def _bus_keys_argv(service: dict, env: dict[str, str]) -> tuple[list[str], str]:
    """The `contact-skills bus-keys` command line inside the one-shot service's shell command (its ``$${VAR:-x}``
    filled from ``env``, else their defaults), and the whole shell command."""
    [script] = service["command"]
    assert service["entrypoint"] == ["sh", "-c"] and script.startswith("test -f /keys/users.txt ||")  # kept if made
    filled = re.sub(r'"\$\$\{(\w+):-([^}]*)\}"', lambda m: env.get(m[1], m[2]), script)
    command = re.search(r"contact-skills (bus-keys [^&]*)&&", filled)
    assert command, script
    return command[1].split(), filled


@pytest.mark.parametrize("compose", [COMPOSE, SECURE], ids=["docker-compose.yml", "docker-compose.secure.yml"])
def test_the_bus_is_secured_as_shipped(compose, tmp_path):
    """Logins made by the one-shot `bus-keys` (kept across starts) into volumes; the router requires them; the API
    logs in from the keys volume; the workers claim theirs from a volume that holds no API login."""
    from services.bus_keys import generate_bus_keys

    services, parser = compose["services"], build_parser()
    argv, script = _bus_keys_argv(services["bus-keys"], {"CONTACT_SKILLS_WORKER_LOGINS": "3"})
    keys = parser.parse_args(argv)
    assert keys.command == "bus-keys" and str(keys.folder) == "/keys" and keys.workers == 3 and "router" in keys.host
    assert "mv /keys/worker-*.env /worker-logins/" in script
    router = parser.parse_args(_command(services["router"]))
    assert router.command == "router" and router.users == "/keys/users.txt"
    assert services["router"]["depends_on"]["bus-keys"] == {"condition": "service_completed_successfully"}
    assert services["router"]["volumes"] == ["cskills-keys:/keys:ro"]
    assert services["api"]["environment"][bus_security.ENV_LOGINS] == "/keys"
    assert "cskills-keys:/keys:ro" in services["api"]["volumes"]
    assert services["worker"]["environment"][bus_security.ENV_LOGINS] == "/worker-logins"
    assert not any("cskills-keys" in volume for volume in services["worker"]["volumes"])
    assert {"cskills-keys", "cskills-worker-logins"} <= set(compose["volumes"])
    # What the service writes: logins any process of the image's user reads (the router, the API, the workers).
    generate_bus_keys(tmp_path, keys.host, keys.workers, keys.ca_path, keys.endpoint)
    assert {f"worker-{k}.env" for k in (1, 2, 3)} | {"api.env", "users.txt", "router.key"} <= {
        p.name for p in tmp_path.iterdir()}  # fmt: skip


def test_key_permissions_work_for_the_routers_uid():
    """Every service runs as the image's user (no ``user:`` override), the one that owns the volumes' mount points
    and writes the 0600 keys: the router reads what `bus-keys` wrote."""
    user = re.search(r"useradd[^\n]*--uid (\d+) (\w+)", DOCKERFILE)
    assert user and re.search(rf"^USER {user[2]}$", DOCKERFILE, re.MULTILINE)
    owned = re.search(rf"chown {user[2]} ([^\n]+)", DOCKERFILE)
    assert owned and {"/keys", "/worker-logins", "/data"} <= set(owned[1].split())
    for compose in (COMPOSE, SECURE):
        assert not any("user" in service for service in compose["services"].values())


def test_the_numba_cache_is_warm_for_the_runtime_user():
    """The control loop is compiled at build time by the user that runs it, into a cache it owns."""
    user_line = DOCKERFILE.index("\nUSER cskills")
    warm = DOCKERFILE.index("RUN contact-skills warm-up")
    cache = re.search(r"^ENV NUMBA_CACHE_DIR=(\S+)$", DOCKERFILE, re.MULTILINE)
    assert user_line < warm and cache and cache[1].startswith("/home/cskills/")
    assert DOCKERFILE.index(cache[0]) < warm


def test_scaled_workers_each_claim_their_own_login(tmp_path):
    """`--scale worker=2`: the workers share the logins volume and each claims a login no other live one holds
    (``sim_worker.worker_settings.claim_login``); a restarted container (same host name) gets its own back; a removed
    one's lapses and is taken."""
    import os
    import time

    from services.bus_keys import generate_logins
    from sim_worker.worker_settings import LOGIN_LEASE_S, claim_login

    generate_logins(tmp_path, 3)
    (tmp_path / "api.env").unlink()  # as the compose file's `mv`: the workers' volume holds worker logins only
    first, first_login = claim_login(tmp_path, "container-a")
    _, second_login = claim_login(tmp_path, "container-b")
    assert (first_login["CONTACT_SKILLS_ZENOH_USER"], second_login["CONTACT_SKILLS_ZENOH_USER"]) == (
        "worker-1",
        "worker-2",
    )
    assert first_login["CONTACT_SKILLS_ZENOH_PASSWORD"] != second_login["CONTACT_SKILLS_ZENOH_PASSWORD"]
    assert claim_login(tmp_path, "container-a")[0] == first  # restarted: its own login again
    lapsed = time.time() - 2 * LOGIN_LEASE_S
    os.utime(first, (lapsed, lapsed))  # container-a removed, its claim not renewed
    assert claim_login(tmp_path, "container-c")[0] == first
    claim_login(tmp_path, "container-d")
    with pytest.raises(ValueError, match="no free worker login"):
        claim_login(tmp_path, "container-e")


def _docker_engine() -> str | None:
    """Why the compose files cannot be brought up here (None: a Docker engine answers)."""
    import shutil
    import subprocess

    if shutil.which("docker") is None:
        return "no docker command on this machine"
    info = subprocess.run(["docker", "info"], capture_output=True, text=True, timeout=30)
    return None if info.returncode == 0 else f"no Docker engine answers: {info.stderr.strip()[:200]}"


@pytest.mark.skipif(_docker_engine() is not None, reason=f"{_docker_engine()}")
def test_the_compose_file_runs_as_shipped_with_two_workers_each_with_its_login(tmp_path):
    """docker compose up --build --scale worker=2: two workers, worker-1 and worker-2; a recording, a skill and an
    execution end to end; an anonymous Zenoh client on the published router port cannot open a session."""
    import json
    import os
    import subprocess
    import time
    import urllib.request

    import zenoh

    from schemas.bus import session_config

    project = ["docker", "compose", "-p", f"cskills-test-{os.getpid()}", "-f", str(REPO / "docker-compose.yml")]
    subprocess.run([*project, "up", "--build", "-d", "--scale", "worker=2"], check=True, timeout=1800)

    def get(path: str, body: dict | None = None) -> dict:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(f"http://127.0.0.1:8000{path}", data=data,
                                         headers={"content-type": "application/json"})  # fmt: skip
        with urllib.request.urlopen(request, timeout=120) as response:
            return json.loads(response.read())

    try:
        deadline = time.monotonic() + 300
        while True:
            try:
                workers = sorted(w["worker_id"] for w in get("/health")["workers"])
                if len(workers) == 2:
                    break
            except OSError:
                pass
            assert time.monotonic() < deadline, "the stack did not come up with two workers"
            time.sleep(2)
        assert workers == ["worker-1", "worker-2"]
        demo = get("/demonstrations/record", {"scenario": "slide_flat", "seed": 0})
        skill = get("/skills", {"demonstration_id": demo["id"], "skill_type": "auto"})
        run = get("/executions", {"skill_id": skill["id"]})
        while (view := get(f"/executions/{run['id']}"))["status"] not in ("done", "aborted", "failed"):
            time.sleep(1)
        assert view["status"] == "done", view
        config = zenoh.Config.from_json5(json.dumps(session_config("client", connect=["tcp/127.0.0.1:7447"])))
        with pytest.raises(zenoh.ZError):
            zenoh.open(config)
    finally:
        subprocess.run([*project, "down", "-v"], timeout=300)
