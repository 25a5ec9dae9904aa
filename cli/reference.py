"""docs/CLI.md, generated from the parser itself (``python -m cli.reference > docs/CLI.md``), so the page cannot drift
from what ``contact-skills COMMAND --help`` says: per command its purpose, its description and every argument.
``tests/test_cli.py`` compares the page with a fresh rendering."""

from __future__ import annotations

import argparse
import inspect
import re

from cli.help import plain
from cli.main import build_parser

INTRO = """# The `contact-skills` command line

Every command below, as `contact-skills COMMAND --help` describes it (this page is generated from the same parser:
`.venv/bin/python -m cli.reference > docs/CLI.md`; `--help` also ends with examples). The console script is
`.venv/bin/contact-skills` after `make run` or `make test`. Errors a user can fix print one line per problem and exit
with code 2; the commands that talk to the service find it at `$CONTACT_SKILLS_URL` (default
`http://127.0.0.1:8000`) unless `--url` says otherwise ([GETTING_STARTED.md](GETTING_STARTED.md)).
"""


def _cell(text: str) -> str:
    """``text`` as one Markdown table cell: one line, pipes escaped."""
    return " ".join(plain(text).split()).replace("|", "\\|")


def _name(action: argparse.Action) -> str:
    """How an argument is written: its flags with the value it takes, or a positional's name."""
    if not action.option_strings:
        return action.metavar or action.dest
    flags = ", ".join(action.option_strings)
    if action.nargs == 0:
        return flags
    if action.choices is not None:
        return f"{flags} {{{','.join(str(c) for c in action.choices)}}}"
    metavar = action.metavar or action.dest.upper()
    return f"{flags} {' '.join(metavar) if isinstance(metavar, tuple) else metavar}"


def _description(text: str | None) -> str:
    """A command's description as Markdown paragraphs (markup removed, lines joined)."""
    paragraphs = re.split(r"\n\s*\n", inspect.cleandoc(plain(text or "")))
    return "\n\n".join(" ".join(p.split()) for p in paragraphs if p.strip())


def reference(parser: argparse.ArgumentParser) -> str:
    """The Markdown reference of every subcommand of ``parser``."""
    [commands] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    helps = {choice.dest: choice.help for choice in commands._choices_actions}
    sections = [INTRO]
    for name, sub in commands.choices.items():
        sub.format_help()  # a lazy parser adds its generated arguments on first use
        rows = [f"| `{_name(a)}` | {_cell(a.help or '')} |" for a in sub._actions if a.help != argparse.SUPPRESS
                and not isinstance(a, argparse._HelpAction)]  # fmt: skip
        table = "\n".join(["| argument | meaning |", "| --- | --- |", *rows]) if rows else "(no arguments)"
        sections.append(f"## `contact-skills {name}`\n\n{_cell(helps.get(name) or '')}.\n\n"
                        f"{_description(sub.description)}\n\n{table}\n")  # fmt: skip
    return "\n".join(sections)


if __name__ == "__main__":
    print(reference(build_parser()), end="")
