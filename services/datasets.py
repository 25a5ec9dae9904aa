"""The data vendored in the repository (``data/``) and where it is found: the KU Leuven contour recordings
(``data/kuleuven_contour``, MIT licence) with the options they are imported with. One definition for the CLI
(``contact-skills demo-learn``), the demo (``experiments``) and the tests."""

from __future__ import annotations

import os
from pathlib import Path

DATA_ENV = "CONTACT_SKILLS_DATA"
"""Environment variable: a data directory (holding ``kuleuven_contour/``) to use instead of the repository's."""

KULEUVEN_IMPORT = {"quaternion_order": "wxyz", "wrench_convention": "measured-on-tool", "wrench_frame": "tool"}
"""Import options of the KU Leuven recordings for ``services.csv_import.demonstration_from_csv`` (scalar-first
quaternions, the sensor's reaction in the TCP frame)."""


def repository_data_directory() -> Path:
    """The data vendored in the repository: ``<repo>/data`` (``kuleuven_contour/``: the KU Leuven recordings)."""
    return Path(__file__).resolve().parents[1] / "data"


def data_directory() -> Path:
    """The data directory: ``$CONTACT_SKILLS_DATA`` if set, else :func:`repository_data_directory`."""
    override = os.environ.get(DATA_ENV)
    return Path(override) if override else repository_data_directory()


def kuleuven_recordings() -> list[Path]:
    """The KU Leuven contour recordings (``contour_*.csv``) in :func:`data_directory`, sorted; empty if none."""
    root = data_directory()
    for folder in (root / "kuleuven_contour", root):
        found = sorted(folder.glob("contour_*.csv"))
        if found:
            return found
    return []
