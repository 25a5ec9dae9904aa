"""Shared test constants: the real data the tests read lives inside the repository (``data/``)."""

from __future__ import annotations

from services.datasets import repository_data_directory

KULEUVEN_DATA = repository_data_directory() / "kuleuven_contour"
"""The KU Leuven contour recordings vendored in the repository (``data/kuleuven_contour``, MIT licence)."""
