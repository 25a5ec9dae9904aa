"""Quiet imports: the PyBullet C extension prints ``pybullet build time: ...`` when it is imported, from C, past
Python's ``sys.stdout``/``sys.stderr``. What imports it (the commands that simulate, the typed client before an MCAP
export, whose scene solves the arm's joints) imports it here first, with that line discarded; every later
``import pybullet`` finds it loaded. Light on purpose: no numpy, no pydantic."""

from __future__ import annotations

import ctypes
import os
import sys

PYBULLET_BANNER = "pybullet build time"
"""How the line PyBullet's C extension prints on import begins (a log may name the engine ``pybullet``; only this
line is the banner)."""


def import_pybullet_quietly() -> None:
    """Import ``pybullet`` with file descriptors 1 and 2 pointed at ``/dev/null``; every later import finds it loaded.

    C stdio may still hold the banner in its buffer when the import returns (stdout is block-buffered when it is a
    pipe or a file) and would write it at exit, through the restored descriptor: ``fflush(NULL)`` empties every C
    stream while they still point at ``/dev/null``."""
    if "pybullet" in sys.modules:
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        import pybullet  # noqa: F401  (loaded for the simulating modules that import it next)

        ctypes.CDLL(None).fflush(None)
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for descriptor in (null, *saved):
            os.close(descriptor)
