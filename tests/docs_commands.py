"""The shell commands and quoted outputs of the README and the docs pages, in reading order, each with how it is
checked (tests/test_readme.py runs the offline ones and compares the quoted outputs; tests/test_client.py runs the
service flows against the real stack).

A page's fenced ```bash blocks hold commands (continuation lines joined, ``#`` comments dropped); a plain ``` block
that starts with ``$ `` is a quoted run: the command, then what it printed (``…`` stands for a wall-clock figure).
A bash block that calls the service (``curl``) is a service flow, run whole as a bash script.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGES = (
    "README.md",
    "docs/GETTING_STARTED.md",
    "docs/IMPORTING.md",
    "docs/CONCEPTS.md",
    "docs/API.md",
    "docs/BUS.md",
    "docs/DEPLOYMENT.md",
    "docs/EXPERIMENTS.md",
    "docs/CLI.md",
    "docs/ENGINES.md",
    "docs/REAL_CELL.md",
)
"""The pages whose commands run, in the order they run (a page may use what an earlier one wrote in scratch/)."""
CLI = ".venv/bin/contact-skills"
OFFLINE = frozenset({"record", "learn", "simulate", "bus-keys", "demo-learn"})
"""Subcommands that run here as written, without the service."""
SERVERS = frozenset({"up", "api", "router", "worker"})
"""Subcommands that serve until stopped: their command lines are parsed here; tests/test_service.py and
tests/test_bus*.py run them."""
ELLIPSIS = "…"


class Check(Enum):
    """How a command is checked."""

    run = "run here, in a directory laid out as a fresh clone (data/ and nothing else)"
    quoted = "run here, and what it prints compared with the quoted output"
    sweep = "run here with --trials 2 (the rest as written)"
    service = "run by tests/test_client.py against the real stack, its whole block as a bash script"
    parse = "a server or a long run: its command line parsed by the real parser"
    make = "`make -n`: the command line it runs"
    environment = "an environment variable the code reads"
    suite = "`make test`: the suite this test is part of (a test file it runs, a benchmark's --smoke run it makes)"
    docker = "docker compose: no engine here; tests/test_compose.py checks the files"


@dataclass(frozen=True)
class Step:
    """One command of a page, with the output a quoted run shows (empty for a bash block's command)."""

    page: str
    command: str
    check: Check
    quoted: tuple[str, ...] = ()

    @property
    def args(self) -> list[str]:
        """The ``contact-skills`` arguments of the command (``env $(cat F)`` and a trailing ``&`` removed)."""
        words = shlex.split(_without_env_file(self.command).removesuffix("&").strip())
        return words[1:] if words and words[0] == CLI else words

    @property
    def env_file(self) -> str | None:
        """The file of an ``env $(cat FILE)`` prefix."""
        found = re.match(r"env \$\(cat (\S+)\) ", self.command)
        return found.group(1) if found else None


def _without_env_file(command: str) -> str:
    return re.sub(r"^env \$\(cat \S+\) ", "", command)


def fenced_blocks(text: str) -> list[tuple[str, str]]:
    """(info string, body) of every fenced block of a Markdown ``text``, in order."""
    return re.findall(r"^```(\w*)\n(.*?)^```", text, flags=re.M | re.S)


def shell_commands(block: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", block)
    lines = [re.split(r"\s#\s|\s{2,}#", line)[0].strip() for line in joined.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def is_service_block(block: str) -> bool:
    return "curl " in block


def classify(command: str) -> Check | None:
    """How a command of a bash block (not a service flow) is checked; None: no test checks it."""
    if command == "make test" or re.fullmatch(
        r"\.venv/bin/python (-m pytest( tests/test_\w+\.py)+ -q|benchmarks/bench_\w+\.py --smoke)", command
    ):
        return Check.suite
    if command.startswith("make run"):
        return Check.make
    if re.fullmatch(r"export [A-Z_]+=\S+", command):
        return Check.environment
    if command.startswith("docker compose "):
        return Check.docker
    words = shlex.split(_without_env_file(command).removesuffix("&").strip())
    if len(words) < 2 or words[0] != CLI:
        return None
    name = words[1]
    local_file = name in ("export", "plan") and not words[2].startswith(("demo_", "exec_", "skill_", "$"))
    if name in OFFLINE or local_file:
        return Check.run
    if name == "sweep":
        return Check.sweep
    if name in SERVERS or name in {"demo", "watch"}:
        return Check.parse
    return None


def steps(pages: tuple[str, ...] = PAGES) -> tuple[list[Step], list[str]]:
    """Every command of ``pages`` in reading order, and the problems: commands no test checks."""
    found: list[Step] = []
    problems: list[str] = []
    for page in pages:
        for info, body in fenced_blocks((REPO / page).read_text()):
            if info == "bash" and is_service_block(body):
                found.append(Step(page, body, Check.service))
            elif info == "bash":
                for command in shell_commands(body):
                    check = classify(command)
                    if check is None:
                        problems.append(f"{page}: no test runs `{command}`")
                    else:
                        found.append(Step(page, command, check))
            elif info == "" and body.startswith("$ "):
                command, _, printed = re.sub(r"\\\n\s*", " ", body).partition("\n")
                found.append(Step(page, command.removeprefix("$ "), Check.quoted, tuple(printed.splitlines())))
    return found, problems


def unmatched_lines(quoted: tuple[str, ...], printed: str) -> list[str]:
    """The quoted lines the run did not print, in order (``…`` matches any text within a line)."""
    lines = printed.splitlines()
    missing, at = [], 0
    for line in quoted:
        pattern = re.compile(".*?".join(re.escape(part) for part in line.split(ELLIPSIS)) + r"\Z")
        hit = next((k for k in range(at, len(lines)) if pattern.match(lines[k])), None)
        if hit is None:
            missing.append(line)
        else:
            at = hit + 1
    return missing


def python_blocks(page: str = "README.md") -> list[str]:
    """The ```python blocks of a page."""
    return [body for info, body in fenced_blocks((REPO / page).read_text()) if info == "python"]
