"""Errors a user can fix, and how every command reports them: one line per problem on stderr, exit code 2, never a
traceback (a bug keeps its traceback)."""

from __future__ import annotations

import sys

EXIT_USAGE = 2
"""Exit code for bad input (as argparse uses for bad arguments)."""


class UserError(Exception):
    """An error the user can fix: ``problems`` are printed one per line, exit code 2."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems


def user_problems(exc: BaseException) -> list[str] | None:
    """The printable problems of a user-fixable error, or None for a bug (which keeps its traceback)."""
    from pydantic import ValidationError

    from services.import_steps import DemonstrationImportError, validation_problems

    if isinstance(exc, UserError | DemonstrationImportError):
        return exc.problems
    if isinstance(exc, ValidationError):
        return validation_problems(exc)
    if isinstance(exc, OSError):
        return [f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": ")]
    learning = sys.modules.get("skills.parameterize")  # loaded when it raised: not imported for the help
    if learning is not None and isinstance(exc, learning.SkillCheckError):
        return [f"--strict: the skill fails its check {c.name.value}: {c.message}" for c in exc.checks]
    if learning is not None and isinstance(exc, learning.LearningError):
        return str(exc).splitlines()
    return None


def report_user_error(command: str, exc: BaseException) -> int:
    """Print the problems of a user-fixable ``exc`` as ``contact-skills COMMAND: error: ...`` and return the exit code
    2; re-raise anything else (a bug)."""
    problems = user_problems(exc)
    if problems is None:
        raise exc
    for problem in problems:
        print(f"contact-skills {command}: error: {problem}", file=sys.stderr)
    return EXIT_USAGE
