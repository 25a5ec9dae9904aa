"""The secured bus with REAL processes: `contact-skills router` on a TLS endpoint with a users file (certificates
made here with `cryptography`), a sim worker logged in as ``w-sec``, the API side (`BusClient`) logged in as
``api``.

An authenticated API and worker run an execution end to end. A session without a login, with a wrong password, or
without the CA that signed the router's certificate is never opened. A read-only observer receives telemetry but its
abort, its forged ``done`` status and its fake worker have no effect; another worker cannot take ``w-sec``'s
queries nor command an execution.
"""

from __future__ import annotations

import datetime
import ipaddress
import time
from pathlib import Path

import pytest

zenoh = pytest.importorskip("zenoh")
x509 = pytest.importorskip("cryptography.x509")

from cryptography.hazmat.primitives import hashes, serialization  # noqa: E402
from cryptography.hazmat.primitives.asymmetric import ec  # noqa: E402
from cryptography.x509.oid import NameOID  # noqa: E402
from test_bus import REPO, WAIT_S, Recorder, _wait  # noqa: E402

from schemas import ExecutionRequest, LearnOptions, RecordRequest  # noqa: E402
from schemas.bus import ExecutionCommand, ExecutionStatus, KeyExpressions  # noqa: E402
from schemas.bus_security import BusSecurity, access_control, read_users  # noqa: E402
from schemas.execution import ExecutionPhase  # noqa: E402
from services.bus import BusClient, BusSettings, open_session  # noqa: E402
from services.local_processes import free_port, spawn_cli, wait_for_port  # noqa: E402
from services.local_processes import stop_process as _stop  # noqa: E402

USERS = {"api": ("api", "api-pw"), "w-sec": ("worker", "w-sec-pw"), "w-other": ("worker", "w-other-pw"),
         "obs": ("observer", "obs-pw")}  # fmt: skip
KEYS = KeyExpressions("cskills")


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _certificates(folder: Path) -> tuple[Path, Path, Path]:
    """A CA, and the router's certificate (for 127.0.0.1 and localhost) signed by it, with its key: PEM files."""
    now = datetime.datetime.now(datetime.UTC)
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())

    def build(subject: str, public_key, extensions: list) -> x509.CertificateBuilder:
        builder = (
            x509.CertificateBuilder()
            .subject_name(_name(subject))
            .issuer_name(_name("contact-skills test CA"))
            .public_key(public_key)
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=1))
            .not_valid_after(now + datetime.timedelta(days=1))
        )
        for extension, critical in extensions:
            builder = builder.add_extension(extension, critical=critical)
        return builder

    ca = build("contact-skills test CA", ca_key.public_key(), [(x509.BasicConstraints(ca=True, path_length=0), True)])
    ca = ca.sign(ca_key, hashes.SHA256())
    names = x509.SubjectAlternativeName([x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))])
    router = build("router", key.public_key(), [(names, False)]).sign(ca_key, hashes.SHA256())
    paths = folder / "ca.pem", folder / "router.pem", folder / "router.key"
    paths[0].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    paths[1].write_bytes(router.public_bytes(serialization.Encoding.PEM))
    paths[2].write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    return paths


@pytest.fixture(scope="module")
def secure_bus(tmp_path_factory):
    """Router (TLS + users) and the worker w-sec as subprocesses; yields (endpoint, CA path)."""
    folder = tmp_path_factory.mktemp("secure-bus")
    ca, cert, key = _certificates(folder)
    users = folder / "users.txt"
    users.write_text("".join(f"{role}:{user}:{password}\n" for user, (role, password) in USERS.items()))
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    router = spawn_cli(["router", "--listen", endpoint, "--users", str(users), "--tls-cert", str(cert),
                        "--tls-key", str(key)], folder / "router.log", cwd=REPO)  # fmt: skip
    processes = [router]
    try:
        wait_for_port(port, WAIT_S)
        login = {"CONTACT_SKILLS_ZENOH_USER": "w-sec", "CONTACT_SKILLS_ZENOH_PASSWORD": "w-sec-pw",
                 "CONTACT_SKILLS_ZENOH_TLS_CA": str(ca)}  # fmt: skip
        processes.append(spawn_cli(["worker", "--connect", endpoint], folder / "w-sec.log", cwd=REPO, env=login))
        yield endpoint, ca
    finally:
        for process in reversed(processes):
            _stop(process)


def _login(user: str | None, ca: Path | None, password: str | None = None) -> BusSecurity:
    if user is None:
        return BusSecurity(tls_ca=str(ca) if ca else None)
    return BusSecurity(user=user, password=password or USERS[user][1], tls_ca=str(ca) if ca else None)


@pytest.fixture(scope="module")
def api(secure_bus):
    endpoint, ca = secure_bus
    recorder = Recorder()
    settings = BusSettings(endpoints=[endpoint], security=_login("api", ca), connect_timeout_s=10)
    client = BusClient(settings, recorder.on_status, recorder.on_telemetry, recorder.on_worker_lost)
    client.recorder = recorder  # type: ignore[attr-defined]
    try:
        _wait(lambda: [w.worker_id for w in client.workers()] == ["w-sec"], what="the worker w-sec")
        yield client
    finally:
        client.close()


@pytest.fixture(scope="module")
def skill(api):
    from skills.parameterize import learn_skill

    reply = api.record_demonstration(RecordRequest(scenario="slide_flat", seed=0, overrides={"move_duration_s": 1.0}))
    assert reply.ok, reply.error
    return learn_skill(reply.demonstration, LearnOptions(skill_type="slide", min_segment_duration_s=0.5))


def _request(skill, **settings) -> ExecutionRequest:
    return ExecutionRequest(skill=skill, **{"scenario": "slide_flat", "pace": "fast", **settings})


def test_the_users_file_gives_each_role_its_rights():
    acl = access_control("cskills", read_users_from(USERS))
    assert acl["default_permission"] == "deny"
    by_id = {rule["id"]: rule for rule in acl["rules"]}
    assert by_id["api-sends"]["key_exprs"] == ["cskills/exec/*/cmd"]
    assert "cskills/exec/w-sec/start" in by_id["worker:w-sec-declares"]["key_exprs"]
    assert by_id["worker:w-sec-lives"]["key_exprs"] == ["cskills/workers/w-sec"]
    assert not any(rule["id"].startswith("observer") and "put" in rule["messages"] and rule["flows"] == ["ingress"]
                   for rule in acl["rules"])  # fmt: skip
    assert {s["id"] for s in acl["subjects"]} == {"api", "observer", "worker:w-sec", "worker:w-other"}


def read_users_from(users: dict[str, tuple[str, str]]):
    import tempfile

    with tempfile.NamedTemporaryFile("w", suffix=".txt", delete=False) as out:
        out.write("# role:user:password\n")
        out.writelines(f"{role}:{user}:{password}\n" for user, (role, password) in users.items())
    try:
        return read_users(out.name)
    finally:
        Path(out.name).unlink()


@pytest.mark.parametrize(
    ("user", "password", "with_ca"),
    [(None, None, True), ("api", "wrong", True), ("obs", None, False)],
    ids=["no login", "wrong password", "no CA for the router's certificate"],
)
def test_a_session_without_a_valid_login_is_never_opened(secure_bus, user, password, with_ca):
    endpoint, ca = secure_bus
    with pytest.raises(ConnectionError):
        open_session("client", connect=[endpoint], security=_login(user, ca if with_ca else None, password))


def test_the_authenticated_api_and_worker_run_an_execution(api, skill):
    worker = api.start_execution("sec-run", _request(skill))
    assert worker == "w-sec"
    final = api.recorder.final("sec-run")
    assert final.phase is ExecutionPhase.done and final.metrics is not None
    _wait(lambda: api.recorder.samples("sec-run") == final.metrics.steps, 10, "every telemetry sample")


def test_an_observer_reads_but_cannot_command_forge_or_pose_as_a_worker(secure_bus, api, skill):
    endpoint, ca = secure_bus
    observer = open_session("client", connect=[endpoint], security=_login("obs", ca))
    seen: list[int] = []
    impostor_queries: list[str] = []
    try:
        observer.declare_subscriber(KEYS.telemetry("sec-obs"), lambda sample: seen.append(1))
        observer.liveliness().declare_token(KEYS.worker("fake"))
        observer.declare_queryable(KEYS.start("fake"), lambda query: impostor_queries.append(str(query.key_expr)))
        api.start_execution("sec-obs", _request(skill, pace="realtime"))
        _wait(lambda: len(seen) >= 20, what="the observer to read telemetry")
        abort = ExecutionCommand(command="abort", execution_id="sec-obs", reason="observer")
        observer.put(KEYS.cmd("sec-obs"), abort.model_dump_json())
        forged = ExecutionStatus(execution_id="sec-obs", worker_id="w-sec", phase="done", message="forged")
        observer.put(KEYS.status("sec-obs"), forged.model_dump_json())
        time.sleep(1.0)
        with api.recorder.lock:
            statuses = list(api.recorder.statuses["sec-obs"])
        assert not any(s.message == "forged" or s.final for s in statuses), statuses
        assert [w.worker_id for w in api.workers()] == ["w-sec"]
        api.send_command("sec-obs", "abort")
        final = api.recorder.final("sec-obs")
        assert final.phase is ExecutionPhase.aborted and final.error == "aborted on request"
        assert impostor_queries == []
    finally:
        observer.close()


def test_a_worker_cannot_take_another_workers_queries_or_command(secure_bus, api, skill):
    endpoint, ca = secure_bus
    other = open_session("client", connect=[endpoint], security=_login("w-other", ca))
    stolen: list[str] = []
    try:
        other.declare_queryable(KEYS.start("w-sec"), lambda query: stolen.append(str(query.key_expr)))
        other.liveliness().declare_token(KEYS.worker("w-sec2"))
        time.sleep(0.5)
        assert [w.worker_id for w in api.workers()] == ["w-sec"]
        assert api.start_execution("sec-other", _request(skill, pace="realtime")) == "w-sec"
        _wait(lambda: api.recorder.samples("sec-other") > 100, what="the execution to run")
        abort = ExecutionCommand(command="abort", execution_id="sec-other", reason="another worker")
        other.put(KEYS.cmd("sec-other"), abort.model_dump_json())
        time.sleep(1.0)
        with api.recorder.lock:
            assert not any(s.final for s in api.recorder.statuses["sec-other"])
        api.send_command("sec-other", "abort")
        assert api.recorder.final("sec-other").error == "aborted on request"
        assert stolen == []
    finally:
        other.close()
