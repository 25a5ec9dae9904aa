"""The world configuration's old home: it is ``schemas.world`` (the contract), kept here for ``sim_worker/executor.py``
alone until the execution package's session moves that file (issue 45); remove this module at that merge."""

from schemas.world import WorldConfig

__all__ = ["WorldConfig"]
