"""Which demonstration files the importers read, told by their content where that is cheap (a bag's magic bytes;
text or not), and the one message for every other file: ``contact-skills learn``, the upload routes and the typed
client say the same words.

Light on purpose (no numpy, no pydantic): the typed client and the command line use it before anything is imported.
"""

from __future__ import annotations

import codecs
import os
from enum import StrEnum
from pathlib import Path


class DemonstrationFile(StrEnum):
    """What a file holds, as the importers see it."""

    csv = "csv"
    """A CSV recording: UTF-8 text with a header row (``services.csv_import``)."""
    json = "json"
    """A JSON `schemas.Demonstration`: text named ``.json`` or starting with ``{``."""
    ros2_bag = "ros2-bag"
    """A ROS 2 bag: its MCAP or sqlite3 storage file, or the bag directory (``metadata.yaml``)."""
    ros1_bag = "ros1-bag"
    """A ROS 1 bag, format 2.0 (``services.bag_import`` reads both)."""


BAGS = frozenset({DemonstrationFile.ros1_bag, DemonstrationFile.ros2_bag})

DESCRIBED = {
    DemonstrationFile.csv: "a CSV recording",
    DemonstrationFile.json: "a JSON Demonstration",
    DemonstrationFile.ros2_bag: "a ROS 2 bag",
    DemonstrationFile.ros1_bag: "a ROS 1 bag",
}
"""Each kind in the words of the messages."""

UPLOAD_PATHS = {
    DemonstrationFile.csv: "/demonstrations/csv",
    DemonstrationFile.json: "/demonstrations",
    DemonstrationFile.ros2_bag: "/demonstrations/bag",
    DemonstrationFile.ros1_bag: "/demonstrations/bag",
}
"""The REST route that takes each kind (``POST``)."""

BAG_STORAGE_MAGIC = {b"\x89MCAP": ".mcap", b"SQLite format 3\x00": ".db3", b"#ROSBAG V2.0": ".bag"}
"""The first bytes of a bag's storage file -> the suffix ``rosbags`` reads it by: MCAP and sqlite3 (ROS 2), ROS 1."""
ROS2_STORAGE_SUFFIXES = (".mcap", ".db3")
"""The storage files of a ROS 2 bag directory."""
BAG_SUFFIXES = (*ROS2_STORAGE_SUFFIXES, ".bag")
"""Names that promise a bag: a file so named whose content is not one is refused, not read as CSV."""
HEAD_BYTES = 4096
"""How much of a file the detection reads."""

SUPPORTED_FILES = (
    "a CSV recording (UTF-8 text with a header row), a JSON Demonstration (.json), a ROS 2 bag (its .mcap or .db3 "
    "storage file, or the bag directory) or a ROS 1 bag (.bag)"
)


def unsupported_file(name: str) -> str:
    """The one message for a file no importer reads (``name``: the file's name, without its folder)."""
    return f"{name!r} is not a demonstration file: give {SUPPORTED_FILES}"


def other_kind(name: str, kind: DemonstrationFile, expected: str) -> str:
    """The message for a readable file given where another kind is expected (``expected``: 'a ROS bag', ...)."""
    return f"{name!r} is {DESCRIBED[kind]}, not {expected} (POST {UPLOAD_PATHS[kind]} takes it)"


def bag_storage_suffix(head: bytes) -> str | None:
    """The suffix ``rosbags`` reads a bag storage file by (.mcap, .db3, .bag), from its first bytes; None if none."""
    return next((suffix for magic, suffix in BAG_STORAGE_MAGIC.items() if head.startswith(magic)), None)


def _is_text(head: bytes) -> bool:
    """UTF-8 without NUL bytes (a multi-byte character cut at the end of ``head`` is fine)."""
    if b"\x00" in head:
        return False
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
    except UnicodeDecodeError:
        return False
    return True


def file_kind(name: str, head: bytes) -> DemonstrationFile | None:
    """What a file named ``name`` whose first bytes are ``head`` (at least :data:`HEAD_BYTES`, or all of it) holds;
    None: nothing the importers read (binary, or text named like a bag)."""
    suffix = bag_storage_suffix(head)
    if suffix is not None:
        return DemonstrationFile.ros1_bag if suffix == ".bag" else DemonstrationFile.ros2_bag
    named = Path(name).suffix.lower()
    if not _is_text(head) or named in BAG_SUFFIXES:
        return None
    if named == ".json" or head.removeprefix(codecs.BOM_UTF8).lstrip().startswith(b"{"):
        return DemonstrationFile.json
    return DemonstrationFile.csv


def path_kind(path: str | os.PathLike[str]) -> DemonstrationFile | None:
    """:func:`file_kind` of the file at ``path``; a directory is a ROS 2 bag if it holds ``metadata.yaml``.
    Raises ``OSError`` when it cannot be read."""
    path = Path(path)
    if path.is_dir():
        return DemonstrationFile.ros2_bag if (path / "metadata.yaml").is_file() else None
    with path.open("rb") as file:
        return file_kind(path.name, file.read(HEAD_BYTES))


__all__ = [
    "BAGS",
    "BAG_STORAGE_MAGIC",
    "BAG_SUFFIXES",
    "DESCRIBED",
    "HEAD_BYTES",
    "ROS2_STORAGE_SUFFIXES",
    "SUPPORTED_FILES",
    "UPLOAD_PATHS",
    "DemonstrationFile",
    "bag_storage_suffix",
    "file_kind",
    "other_kind",
    "path_kind",
    "unsupported_file",
]
