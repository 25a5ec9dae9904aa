"""The data vendored in the repository (``data/``) and where it is found: the KU Leuven contour recordings
(``data/kuleuven_contour``, MIT licence) with the options they are imported with, and the CAD of their object. One
definition for the CLI (``contact-skills demo-learn``), the demo (``experiments``) and the tests."""

from __future__ import annotations

import os
from pathlib import Path

DATA_ENV = "CONTACT_SKILLS_DATA"
"""Environment variable: a data directory (holding ``kuleuven_contour/``) to use instead of the repository's."""

KULEUVEN_IMPORT = {
    "quaternion_order": "wxyz",
    "wrench_convention": "measured-on-tool",
    "wrench_frame": "tool",
    "tare": False,
}
"""Import options of the KU Leuven recordings for ``services.csv_import.demonstration_from_csv`` (scalar-first
quaternions, the sensor's reaction in the TCP frame, already compensated: the authors' calibration removed the tool's
weight, and the files, all contact, hold no free space to fit an offset over)."""


def repository_data_directory() -> Path:
    """The data vendored in the repository: ``<repo>/data`` (``kuleuven_contour/``: the KU Leuven recordings)."""
    return Path(__file__).resolve().parents[1] / "data"


def data_directory() -> Path:
    """The data directory: ``$CONTACT_SKILLS_DATA`` if set, else :func:`repository_data_directory`."""
    override = os.environ.get(DATA_ENV)
    return Path(override) if override else repository_data_directory()


KULEUVEN_OBJECT_STL = "contour.STL"
"""The CAD model of the object the KU Leuven recordings follow (binary STL, mm, CAD frame), next to the recordings."""
KULEUVEN_EDGE_MAT = "contour_edge.mat"
"""The authors' extraction of the edge the tool followed (MATLAB v5, variable ``contour_edge``, (101, 3) mm, CAD
frame), next to the recordings."""


def kuleuven_file(name: str) -> Path:
    """The file ``name`` of the KU Leuven data in :func:`data_directory` (its ``kuleuven_contour/`` or itself, as for
    :func:`kuleuven_recordings`); raises ``FileNotFoundError`` naming both places."""
    root = data_directory()
    for folder in (root / "kuleuven_contour", root):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"no {name} in {root / 'kuleuven_contour'} or {root}; set {DATA_ENV}")


def kuleuven_recordings() -> list[Path]:
    """The KU Leuven contour recordings (``contour_*.csv``) in :func:`data_directory`, sorted; empty if none."""
    root = data_directory()
    for folder in (root / "kuleuven_contour", root):
        found = sorted(folder.glob("contour_*.csv"))
        if found:
            return found
    return []
