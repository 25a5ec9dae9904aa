"""``contact-skills learn FILE``: the import options as flags, generated from the options models
(`schemas.import_options`, the one spelling the API forms and the importers share), and FILE imported by what it holds.

A field's flag is its form name (``rate_hz`` -> ``--rate``), a true-by-default switch its negation (``--no-tare``),
and ``tf_parent``/``tf_child`` are one ``--tf PARENT CHILD``; its help is the field's description, its choices the
enum's values, its type and count the annotation's. The models import pydantic and numpy, so the flags are added
when ``learn`` is parsed or its help shown (:class:`LazyArgumentsParser`), not when ``contact-skills --help`` builds
every subcommand.
"""

from __future__ import annotations

import argparse
import types
import typing
from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pydantic.fields import FieldInfo

    from schemas import Demonstration
    from schemas.import_options import ImportOptions

METAVARS: dict[str, str | tuple[str, ...]] = {
    "rate_hz": "HZ",
    "dt_s": "SECONDS",
    "tare_window_s": ("T0", "T1"),
    "force_offset": "F",
    "columns": "SPEC",
    "wrench_topic": "TOPIC",
    "pose_topic": "TOPIC",
    "tool_frame": "FRAME",
}
"""What argparse needs beyond a field's type and description: the placeholder its help shows."""
TF_FIELDS = ("tf_parent", "tf_child")
TF_FLAG = "--tf"
TF_HELP = "the tool pose from /tf instead: the world (PARENT) and tool (CHILD) frames of the pair"
"""``tf_parent`` and ``tf_child`` given together, as ``--tf PARENT CHILD`` (the API form has the two fields)."""


class LazyArgumentsParser(argparse.ArgumentParser):
    """An argument parser some of whose arguments are added on first use (parsing, help, usage), so that building
    every subcommand (``contact-skills --help``) does not import what generates them."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._lazy: list[Callable[[argparse.ArgumentParser], None]] = []

    def add_lazily(self, add: Callable[[argparse.ArgumentParser], None]) -> None:
        """Call ``add(self)`` before this parser is first used."""
        self._lazy.append(add)

    def _add_lazy(self) -> None:
        while self._lazy:
            self._lazy.pop(0)(self)

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        self._add_lazy()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self._add_lazy()
        return super().format_usage()

    def format_help(self) -> str:
        self._add_lazy()
        return super().format_help()


def _models() -> list[tuple[type[ImportOptions], str]]:
    """Each options model with the title of its group of flags, the shared one first."""
    from schemas.import_options import BagImportOptions, CsvImportOptions, ImportOptions

    return [
        (ImportOptions, "import options of CSV files and ROS bags"),
        (CsvImportOptions, "CSV files"),
        (BagImportOptions, "ROS 1 and ROS 2 bags (a topic is chosen automatically when the bag holds one candidate)"),
    ]


def _own_fields(model: type[ImportOptions]) -> dict[str, FieldInfo]:
    """The fields ``model`` adds to its base (all of them for the base)."""
    inherited = getattr(model.__base__, "model_fields", {})
    return {name: field for name, field in model.model_fields.items() if name not in inherited}


def _without_none(annotation: Any) -> Any:
    """``X`` of ``X | None``; anything else unchanged."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        [kind] = [arg for arg in typing.get_args(annotation) if arg is not type(None)]
        return kind
    return annotation


def _flag(name: str, field: FieldInfo) -> str:
    """The command-line flag of the options field ``name``."""
    if name in TF_FIELDS:
        return TF_FLAG
    if field.annotation is bool:
        return f"--no-{name}" if field.default else f"--{name}"
    return "--" + (field.alias or name).replace("_", "-")


def _add_field(group: argparse._ArgumentGroup, name: str, field: FieldInfo) -> None:
    """One flag from one field: not given, it is None (the model's default applies)."""
    kind = _without_none(field.annotation)
    options: dict[str, Any] = {"dest": name, "default": None, "help": (field.description or "").replace("%", "%%")}
    if kind is bool:
        options.update(action="store_const", const=not field.default)
    elif isinstance(kind, type) and issubclass(kind, Enum):
        options["choices"] = [member.value for member in kind]
    elif typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        options.update(type=items[0], nargs="+" if items[-1] is Ellipsis else len(items))
    else:
        options["type"] = kind
    if name in METAVARS:
        options["metavar"] = METAVARS[name]
    group.add_argument(_flag(name, field), **options)


def _import_arguments(parser: argparse.ArgumentParser) -> None:
    """One group of flags per options model: each field's flag, and ``--tf`` for the ``/tf`` pair."""
    for model, title in _models():
        group = parser.add_argument_group(title)
        fields = _own_fields(model)
        for name, field in fields.items():
            if name not in TF_FIELDS:
                _add_field(group, name, field)
        if TF_FIELDS[0] in fields:
            group.add_argument(TF_FLAG, dest="tf", nargs=2, metavar=("PARENT", "CHILD"), help=TF_HELP)


def add_import_arguments(parser: LazyArgumentsParser) -> None:
    """Give ``parser`` a flag for every field of the import options models, generated when it is first used."""
    parser.add_lazily(_import_arguments)


def _given_options(args: argparse.Namespace) -> dict[str, object]:
    """The options fields the command line gave (by field name), whatever the model."""
    given = {
        name: getattr(args, name)
        for model, _ in _models()
        for name in _own_fields(model)
        if getattr(args, name, None) is not None
    }
    if getattr(args, "tf", None):
        given.update(zip(TF_FIELDS, args.tf, strict=True))
    return given


def options_from_args(args: argparse.Namespace, model: type[ImportOptions], what: str) -> ImportOptions:
    """The options ``args`` gave, as ``model``; a flag that is not one of ``model``'s is a user error naming it and
    ``what`` the file is ('x.bag is a ROS 1 bag')."""
    from cli.errors import UserError

    given = _given_options(args)
    fields = {name: field for base, _ in _models() for name, field in _own_fields(base).items()}
    foreign = sorted({_flag(name, fields[name]) for name in given if name not in model.model_fields})
    if foreign:
        raise UserError([f"{', '.join(foreign)}: not an option of this file: {what}"])
    return model.model_validate(given)


def import_demonstration(file: Path, args: argparse.Namespace) -> Demonstration:
    """``file`` imported by what it holds (its content, not only its name) with the import options ``args`` gives
    for its kind: a JSON Demonstration, a CSV recording, a ROS 1 or ROS 2 bag; any other file gets the one message
    every interface gives (`services.demonstration_files.unsupported_file`)."""
    from schemas.import_options import BagImportOptions, CsvImportOptions
    from services.demonstration_files import BAGS, DESCRIBED, DemonstrationFile
    from services.importing import demonstration_file, demonstration_from_file

    kind = demonstration_file(file)  # once: the options are those of its kind
    if kind is DemonstrationFile.json:
        return demonstration_from_file(file, kind=kind)
    model = BagImportOptions if kind in BAGS else CsvImportOptions
    return demonstration_from_file(file, options_from_args(args, model, f"{file} is {DESCRIBED[kind]}"), kind)
