"""Entry point of the `contact-skills` console script: the parser of every subcommand, and ``main``.

Each subcommand lives in its own module (``cli/*_command.py``, ``cli/bus_commands.py``, ``cli/service_commands.py``)
and imports its dependencies lazily, so ``contact-skills --help`` stays fast. Errors a user can fix print one line per
problem and exit with code 2 (``cli/errors.py``).
"""

from __future__ import annotations

import argparse
import sys

from cli import (
    bus_commands,
    demo_command,
    export_command,
    learn_command,
    plan_command,
    record_command,
    service_commands,
    simulate_command,
    sweep_command,
)
from cli.help import polish
from cli.import_options import LazyArgumentsParser

DESCRIPTION = "Learn a robot contact skill from one demonstration, run it in simulation, serve it (REST + Zenoh)."


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of all subcommands."""
    from services.settings import package_version

    parser = argparse.ArgumentParser(prog="contact-skills", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"contact-skills {package_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=LazyArgumentsParser)
    for module in (learn_command, record_command, simulate_command, bus_commands, service_commands, demo_command,
                   export_command, plan_command, sweep_command):  # fmt: skip
        module.register(commands)
    polish(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen subcommand; returns the process exit code."""
    args = build_parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
