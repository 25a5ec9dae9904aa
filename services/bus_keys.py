"""Everything a secured bus needs, generated in one folder (``contact-skills bus-keys``): a CA, the router's TLS
certificate signed by it, a users file with random passwords, and one environment file per login.

Files (keys, users and environment files readable by their owner only):

- ``ca.pem`` — the CA certificate every client checks the router against (``CONTACT_SKILLS_ZENOH_TLS_CA``);
- ``router.pem``, ``router.key`` — the router's certificate (valid for the host names/addresses given and
  ``localhost``, ``127.0.0.1``) and key (``router --tls-cert/--tls-key``);
- ``users.txt`` — ``role:user:password`` lines for ``router --users``: ``api``, ``worker-1`` .. ``worker-N``,
  ``observer``;
- ``api.env``, ``worker-K.env``, ``observer.env`` — ``CONTACT_SKILLS_ZENOH_USER``, ``..._PASSWORD``, ``..._TLS_CA``
  (and ``..._ENDPOINTS`` when a router endpoint is given) for that login (``env $(cat api.env) contact-skills api``,
  or docker-compose ``env_file``).

The CA's private key is not kept: to add a worker, add a line to ``users.txt`` (and restart the router), or
generate a new folder.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import secrets
import tempfile
from pathlib import Path

from schemas.bus import ENV_ENDPOINTS
from schemas.bus_security import ENV_PASSWORD, ENV_TLS_CA, ENV_USER, parse_env

CERTIFICATE_DAYS = 825
"""Validity of the generated certificates, days."""


def _private(path: Path, data: bytes) -> None:
    """Write ``data`` to a file only its owner can read."""
    path.write_bytes(data)
    os.chmod(path, 0o600)


def _certificates(folder: Path, hosts: list[str]) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    def name(common_name: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])

    now = datetime.datetime.now(datetime.UTC)
    ca_key, key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("contact-skills bus CA"))
        .issuer_name(name("contact-skills bus CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=CERTIFICATE_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    alternative: list[x509.GeneralName] = []
    for host in dict.fromkeys([*hosts, "localhost", "127.0.0.1"]):
        try:
            alternative.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            alternative.append(x509.DNSName(host))
    router = (
        x509.CertificateBuilder()
        .subject_name(name(hosts[0] if hosts else "localhost"))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=CERTIFICATE_DAYS))
        .add_extension(x509.SubjectAlternativeName(alternative), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    (folder / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    (folder / "router.pem").write_bytes(router.public_bytes(serialization.Encoding.PEM))
    pkcs8 = serialization.PrivateFormat.PKCS8
    _private(folder / "router.key", key.private_bytes(serialization.Encoding.PEM, pkcs8, serialization.NoEncryption()))


def generate_bus_keys(
    folder: str | Path,
    hosts: list[str],
    workers: int,
    ca_path: str | None = None,
    endpoint: str | None = None,
) -> list[Path]:
    """Write the files of the module docstring into ``folder`` (created; existing files are replaced).

    ``hosts``: the router's host names or addresses as the clients will reach it; ``ca_path``: where the clients
    find ``ca.pem`` (default: its absolute path here; ``/keys/ca.pem`` for docker-compose); ``endpoint``: the router
    endpoint written into the environment files (e.g. ``tls/sim-router.lan:7447``). Returns the files written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _certificates(folder, hosts)
    extra = {ENV_TLS_CA: ca_path or str((folder / "ca.pem").resolve())}
    if endpoint:
        extra[ENV_ENDPOINTS] = endpoint
    generate_logins(folder, workers, extra)
    return sorted(folder.iterdir())


def generate_logins(folder: Path, workers: int, extra: dict[str, str] | None = None) -> dict[str, dict[str, str]]:
    """Write ``users.txt`` (random passwords) and one ``LOGIN.env`` per login into ``folder`` (which must exist), all
    readable by their owner only: ``api``, ``worker-1`` .. ``worker-N``, ``observer``, each env file with ``extra``
    variables too. Returns each login's variables (what its env file holds)."""
    logins = [("api", "api"), *((f"worker-{k}", "worker") for k in range(1, workers + 1)), ("observer", "observer")]
    passwords = {user: secrets.token_urlsafe(18) for user, _ in logins}
    _private(folder / "users.txt", "".join(f"{role}:{user}:{passwords[user]}\n" for user, role in logins).encode())
    variables = {user: {ENV_USER: user, ENV_PASSWORD: passwords[user], **(extra or {})} for user, _ in logins}
    for user, values in variables.items():
        _private(folder / f"{user}.env", "".join(f"{name}={value}\n" for name, value in values.items()).encode())
    return variables


def local_logins_folder(port: int) -> Path:
    """Where ``contact-skills up`` keeps the logins of its bus on loopback ``port``: a folder of this user's
    (``$XDG_RUNTIME_DIR``, else the temporary directory), readable by this user only. Its ``observer.env`` is how
    this user's other processes (``watch``, the client's ``live()``) read the bus without being told a login."""
    base = Path(os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()) / f"contact-skills-{os.getuid()}"
    return base / f"bus-{port}"


def read_env_file(path: Path) -> dict[str, str]:
    """The ``NAME=value`` lines of an env file (``schemas.bus_security.parse_env``)."""
    return parse_env(path.read_text())


def make_local_logins(port: int, workers: int) -> tuple[Path, dict[str, dict[str, str]]]:
    """Fresh logins for the bus of ``contact-skills up`` on loopback ``port`` (:func:`generate_logins` in
    :func:`local_logins_folder`, replacing what a previous run left): (the folder, each login's variables)."""
    folder = local_logins_folder(port)
    folder.parent.mkdir(mode=0o700, exist_ok=True)
    os.chmod(folder.parent, 0o700)  # made by this user: another one could otherwise list or swap its folders
    folder.mkdir(mode=0o700, exist_ok=True)
    for stale in folder.glob("*"):
        stale.unlink()
    return folder, generate_logins(folder, workers)
