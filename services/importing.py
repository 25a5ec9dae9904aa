"""Which importer reads a demonstration file, the one door every interface imports a file through (the command line
with a path; the REST API's upload routes tell an upload's kind with the same ``services.demonstration_files``):
:func:`demonstration_file` tells what the file holds, by its content; :func:`demonstration_from_file` reads it with
the importer of its kind, a JSON `schemas.Demonstration` here (:func:`demonstration_from_json`), a CSV recording with
``services.csv_import``, a ROS 1 or ROS 2 bag with ``services.bag_import``. The steps they share:
``services.import_steps``.
"""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import ValidationError

from schemas import Demonstration
from schemas.import_options import BagImportOptions, CsvImportOptions, ImportOptions
from services.csv_import import demonstration_from_csv
from services.demonstration_files import DemonstrationFile, path_kind, unsupported_file
from services.import_steps import DemonstrationImportError, validation_problems


def demonstration_file(path: str | os.PathLike[str]) -> DemonstrationFile:
    """What the file (or bag directory) at ``path`` holds, by its content (`services.demonstration_files`); raises
    :class:`DemonstrationImportError` when it cannot be read or holds nothing the importers read (the one message
    every interface gives)."""
    path = Path(path)
    try:
        kind = path_kind(path)
    except OSError as exc:
        raise DemonstrationImportError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    if kind is None:
        raise DemonstrationImportError(unsupported_file(path.name))
    return kind


def demonstration_from_json(path_or_text: str | os.PathLike[str] | bytes) -> Demonstration:
    """Load a `schemas.Demonstration` from a JSON file (or JSON text); the data must already follow the conventions.

    Raises :class:`DemonstrationImportError` with one line per problem (unreadable file,
    invalid JSON, or each failing field with its path, e.g. ``orientations: quaternion at sample 3 ...``).
    """
    if isinstance(path_or_text, bytes):
        text = path_or_text.decode("utf-8-sig")
    elif isinstance(path_or_text, str) and path_or_text.lstrip().startswith("{"):
        text = path_or_text
    else:
        path = Path(path_or_text)
        try:
            text = path.read_text(encoding="utf-8-sig")
        except OSError as exc:
            raise DemonstrationImportError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
        except UnicodeDecodeError:
            raise DemonstrationImportError(f"{str(path)!r} is not a UTF-8 text file") from None
    try:
        return Demonstration.model_validate_json(text)
    except ValidationError as exc:
        raise DemonstrationImportError(validation_problems(exc)) from None


def demonstration_from_file(
    path: str | os.PathLike[str], options: ImportOptions | None = None, kind: DemonstrationFile | None = None
) -> Demonstration:
    """Import the file (or ROS 2 bag directory) at ``path`` by what it holds (its content, not only its name): a
    JSON `Demonstration` (``options`` do not apply), a CSV recording or a ROS 1 or ROS 2 bag
    (`services.bag_import.demonstration_from_bag`). ``options``: the shared `ImportOptions`, or those of the
    file's kind. Raises :class:`DemonstrationImportError` (a file no importer reads: the one message every
    interface gives, `services.demonstration_files.unsupported_file`). ``kind``: what the file holds when the caller
    has told it already (:func:`demonstration_file`, to choose the options), so that it is read once."""
    kind = demonstration_file(path) if kind is None else kind
    given = {} if options is None else options.model_dump(exclude_unset=True)
    if kind is DemonstrationFile.json:
        return demonstration_from_json(path)
    if kind is DemonstrationFile.csv:
        return demonstration_from_csv(path, CsvImportOptions(**given))
    from services.bag_import import demonstration_from_bag  # rosbags: the service extra

    return demonstration_from_bag(path, BagImportOptions(**given), kind)


__all__ = [
    "DemonstrationImportError",
    "demonstration_file",
    "demonstration_from_file",
    "demonstration_from_json",
]
