"""Who may do what on the Zenoh bus: authentication (user and password, TLS) and the router's access control.

Without any of the settings below the bus is open, as it has always been on loopback (``contact-skills up``).
To open the router beyond loopback, give it a users file and, across machines, a TLS certificate:

- ``CONTACT_SKILLS_ZENOH_USERS`` (``router --users FILE``): the router's users, one ``role:user:password`` per line,
  role ``api``, ``worker`` or ``observer``;
- ``CONTACT_SKILLS_ZENOH_USER`` (``--zenoh-user``) and ``CONTACT_SKILLS_ZENOH_PASSWORD`` (environment only, never on a
  command line): who an api, worker or watch process logs in as (a worker's id is its user name);
- ``CONTACT_SKILLS_ZENOH_TLS_CERT`` and ``..._TLS_KEY`` (``router --tls-cert/--tls-key``): the router's certificate
  and key (PEM), for endpoints ``tls/host:port``;
- ``CONTACT_SKILLS_ZENOH_TLS_CA`` (``--tls-ca``): the CA certificate (PEM) the clients check the router's against.

With a users file the router refuses every session that does not log in (a wrong password or none: the session is
never opened) and applies :func:`access_control`, default deny:

- ``api``: command executions (put ``P/exec/*/cmd``), publish sweep progress (``P/sweeps/*/progress``), query the
  workers (``info``, ``start``, ``record``, ``status``, ``replay``), subscribe to statuses, telemetry and the workers'
  liveliness;
- ``worker`` *W* (its user name is its worker id): declare only ITS queryables ``P/exec/W/{info,start,record,replay}``
  (so only the worker that ran an execution can replay its telemetry) and ITS liveliness token ``P/workers/W``,
  answer the status queryable, receive commands, publish statuses and telemetry; it cannot command, and cannot pose
  as another worker;
- ``observer``: read only: subscribe to statuses, telemetry, sweep progress and liveliness, query statuses. Not the
  workers' info (their host names and process ids stay between them and the API) nor telemetry replays (a replay
  costs the worker that answers it; an observer reads the live stream, or the API's stored telemetry).

Statuses and telemetry are keyed by execution, not by worker: an authenticated worker could publish for an
execution it does not run, and write any ``worker_id`` into a payload. The API therefore gives each execution a
secret bound to the worker it chose (sent as the attachment of that worker's start query, which only that worker's
login can receive) and takes a status, a telemetry batch or a replay only when its attachment is
:func:`report_signature` of the payload under that secret (`services.bus`). The secret is bound to the dispatch too
(``StartExecution.attempt``), and a status counts only above the last one taken (``ExecutionStatus.seq``), for a run
still active: a recorded status replayed later, by anyone, moves nothing.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal, TypedDict

from schemas.key_expressions import KeyExpressions, check_id

ENV_USERS = "CONTACT_SKILLS_ZENOH_USERS"
ENV_USER = "CONTACT_SKILLS_ZENOH_USER"
ENV_PASSWORD = "CONTACT_SKILLS_ZENOH_PASSWORD"
ENV_TLS_CA = "CONTACT_SKILLS_ZENOH_TLS_CA"
ENV_TLS_CERT = "CONTACT_SKILLS_ZENOH_TLS_CERT"
ENV_TLS_KEY = "CONTACT_SKILLS_ZENOH_TLS_KEY"
ENV_LOGINS = "CONTACT_SKILLS_ZENOH_LOGINS"
"""A folder of login env files (docker-compose): the API logs in with its ``api.env``; a worker claims one of its
``worker-K.env`` no other live worker holds (``sim_worker.worker_settings.claim_login``), so scaled workers each get
their own login and id."""

Role = Literal["api", "worker", "observer"]
ROLES: tuple[str, ...] = ("api", "worker", "observer")


class Transport(TypedDict, total=False):
    """The ``transport`` part of a Zenoh session configuration: the login (``auth.usrpwd``), the TLS files
    (``link.tls``) and, for a router, the limits on connections that have not logged in (``unicast``)."""

    auth: dict[str, dict[str, str]]
    link: dict[str, dict[str, str]]
    unicast: dict[str, int]


class AclRule(TypedDict):
    """One rule of the router's access control: which ``messages`` flow (``ingress``, ``egress``) on ``key_exprs``."""

    id: str
    permission: Literal["allow", "deny"]
    flows: list[Literal["ingress", "egress"]]
    messages: list[str]
    key_exprs: list[str]


class AclSubject(TypedDict):
    """A subject of the access control: the user names it stands for."""

    id: str
    usernames: list[str]


class AclPolicy(TypedDict):
    """Which rules (their ids) apply to which subjects (theirs)."""

    subjects: list[str]
    rules: list[str]


class AccessControl(TypedDict):
    """The router's ``access_control`` configuration (:func:`access_control`)."""

    enabled: bool
    default_permission: Literal["allow", "deny"]
    rules: list[AclRule]
    subjects: list[AclSubject]
    policies: list[AclPolicy]


class BusSecurityError(ValueError):
    """A users file or a security setting that cannot be used; the message says which and why."""


@dataclass(frozen=True)
class BusUser:
    """One line of the router's users file."""

    role: Role
    user: str
    password: str


def parse_users(text: str, source: str) -> list[BusUser]:
    """The users of a users file's ``text`` (``source``: its name, for the messages): one ``role:user:password`` per
    line, ``#`` comments and blank lines ignored. Reading the file is the router's (``services.router.read_users``)."""
    users: list[BusUser] = []
    for number, line in enumerate(text.splitlines(), start=1):
        text_line = line.strip()
        if not text_line or text_line.startswith("#"):
            continue
        parts = text_line.split(":", 2)
        if len(parts) != 3 or parts[0] not in ROLES or not parts[1] or not parts[2]:
            raise BusSecurityError(f"{source} line {number}: expected role:user:password with role one of {ROLES}")
        role, user, password = parts
        check_id(user, "user name")
        users.append(BusUser(role, user, password))  # type: ignore[arg-type]
    if not users:
        raise BusSecurityError(f"{source}: no users")
    return users


@dataclass(frozen=True)
class BusSecurity:
    """What a session presents (``user``, ``password``, ``tls_ca``) or, for the router, requires (``users_file``,
    ``tls_cert``, ``tls_key``). All None: an open bus."""

    user: str | None = None
    password: str | None = None
    tls_ca: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    users_file: str | None = None

    @classmethod
    def from_env(cls, env: Mapping[str, str], **overrides: str | None) -> BusSecurity:
        """The ``CONTACT_SKILLS_ZENOH_*`` variables of the table above in ``env`` (the caller passes its process's
        ``os.environ``: the contract reads no environment itself), replaced by ``overrides`` not None."""
        names = {"user": ENV_USER, "password": ENV_PASSWORD, "tls_ca": ENV_TLS_CA, "tls_cert": ENV_TLS_CERT,
                 "tls_key": ENV_TLS_KEY, "users_file": ENV_USERS}  # fmt: skip
        values = {field: env.get(var) or None for field, var in names.items()}
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def transport(self, mode: str) -> Transport:
        """The ``transport`` part of the session configuration (empty for an open bus)."""
        transport: Transport = {}
        if mode == "router":
            if self.users_file:
                transport["auth"] = {"usrpwd": {"dictionary_file": self.users_file}}
            if bool(self.tls_cert) != bool(self.tls_key):
                raise BusSecurityError("the router's TLS needs both a certificate and its key (tls_cert, tls_key)")
            if self.tls_cert:
                transport["link"] = {"tls": {"listen_certificate": self.tls_cert, "listen_private_key": self.tls_key}}
            return transport
        if bool(self.user) != bool(self.password):
            raise BusSecurityError(f"bus login needs both {ENV_USER} and {ENV_PASSWORD}")
        if self.user:
            transport["auth"] = {"usrpwd": {"user": self.user, "password": self.password}}
        if self.tls_ca:
            transport["link"] = {"tls": {"root_ca_certificate": self.tls_ca}}
        return transport


def _rule(rule_id: str, flow: Literal["ingress", "egress"], messages: list[str], keys: list[str]) -> AclRule:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": keys}


def access_control(prefix: str, users: list[BusUser]) -> AccessControl:
    """The router's ``access_control`` configuration for ``users`` (see the module docstring): default deny;
    ``ingress`` rules say what a role may send or declare, ``egress`` rules what the router delivers to it."""
    k = KeyExpressions(prefix)
    replays = f"{k.prefix}/exec/*/replay"
    queried = [k.info("*"), f"{k.prefix}/exec/*/start", f"{k.prefix}/exec/*/record", k.status("*"), replays]
    streams = [k.status("*"), k.telemetry("*")]
    commands = [f"{k.prefix}/exec/*/cmd"]
    everything = [f"{k.prefix}/**"]
    progress = [k.sweep_progress("*")]
    rules = [
        _rule("api-sends", "ingress", ["put"], [*commands, *progress]),
        _rule("api-asks", "ingress", ["query"], queried),
        _rule("api-listens", "ingress", ["declare_subscriber"], streams),
        _rule("api-watches", "ingress", ["declare_liveliness_subscriber", "liveliness_query"], [k.workers]),
        _rule("api-receives", "egress", ["put"], streams),
        _rule("api-answers", "egress", ["reply"], queried),
        _rule("api-sees", "egress", ["liveliness_token", "declare_queryable", "declare_subscriber"], everything),
        _rule("observer-listens", "ingress", ["declare_subscriber"], [*streams, *progress]),
        _rule("observer-asks", "ingress", ["query"], [k.status("*")]),
        _rule("observer-watches", "ingress", ["declare_liveliness_subscriber", "liveliness_query"], [k.workers]),
        _rule("observer-receives", "egress", ["put"], [*streams, *progress]),
        _rule("observer-answers", "egress", ["reply"], [k.status("*")]),
        _rule("observer-sees", "egress", ["liveliness_token", "declare_queryable"], everything),
    ]
    subjects: list[AclSubject] = []
    policies: list[AclPolicy] = []
    for role in ("api", "observer"):
        names = sorted({u.user for u in users if u.role == role})
        if names:
            subjects.append({"id": role, "usernames": names})
            policies.append({"subjects": [role], "rules": [r["id"] for r in rules if r["id"].startswith(role + "-")]})
    for worker in sorted({u.user for u in users if u.role == "worker"}):
        own = [k.info(worker), k.start(worker), k.record(worker), k.replay(worker)]
        worker_rules = [
            _rule(f"worker:{worker}-declares", "ingress", ["declare_queryable"], [*own, k.status("*")]),
            _rule(f"worker:{worker}-lives", "ingress", ["liveliness_token"], [k.worker(worker)]),
            _rule(f"worker:{worker}-publishes", "ingress", ["put"], streams),
            _rule(f"worker:{worker}-replies", "ingress", ["reply"], [*own, k.status("*")]),
            _rule(f"worker:{worker}-listens", "ingress", ["declare_subscriber"], commands),
            # the API asks every worker's info at once (P/exec/*/info): the query arrives with that key
            _rule(f"worker:{worker}-is-asked", "egress", ["query"], [*own, k.info("*"), k.status("*")]),
            _rule(f"worker:{worker}-is-told", "egress", ["put"], commands),
        ]
        rules.extend(worker_rules)
        subjects.append({"id": f"worker:{worker}", "usernames": [worker]})
        policies.append({"subjects": [f"worker:{worker}"], "rules": [r["id"] for r in worker_rules]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def report_signature(secret: bytes, payload: bytes) -> bytes:
    """The Zenoh attachment a worker puts on every status, telemetry batch and replay reply of an execution:
    HMAC-SHA256 (32 bytes) of the payload's exact bytes under the execution's secret (the attachment of the start
    query that handed the execution to this worker)."""
    return hmac.new(secret, payload, hashlib.sha256).digest()


def challenge_signature(secret: bytes, payload: bytes, challenge: bytes) -> bytes:
    """The attachment of a status sent in answer to a query that carried ``challenge`` (its payload): the
    :func:`report_signature` of the status followed by the challenge. Only the worker holding the run's secret can
    make it, and only after the challenge was drawn: a recorded status cannot answer a new query."""
    return report_signature(secret, payload + challenge)


def parse_env(text: str) -> dict[str, str]:
    """The ``NAME=value`` lines of an env file's ``text`` (as ``contact-skills bus-keys`` writes them)."""
    return dict(line.split("=", 1) for line in text.splitlines() if "=" in line and not line.startswith("#"))
