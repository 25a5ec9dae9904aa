"""What the service learns from: time stamps it can work on in bounded memory."""

from __future__ import annotations

import numpy as np

from schemas.demonstration import Demonstration

MAX_RATE_HZ = 100_000.0
"""Highest sampling rate the service learns from (as the CSV importer's resampling limit), Hz."""
MAX_GRID_SAMPLES = 1_000_000
"""Most samples a demonstration may span on its uniform grid (duration / median step): 16.7 min at 1 kHz."""


def check_sampling(demonstration: Demonstration) -> None:
    """Raise `LearningError` on ``t`` for time stamps the pipeline cannot work on in bounded memory: a rate above
    :data:`MAX_RATE_HZ` (filter windows are sized in samples per second) or a uniform grid (duration at the
    median step, what irregular stamps are resampled to) longer than :data:`MAX_GRID_SAMPLES`."""
    from skills.parameterize import LearningError

    t = np.asarray(demonstration.t)
    step = float(np.median(np.diff(t)))
    if 1.0 / step > MAX_RATE_HZ:
        raise LearningError(
            "t",
            f"median time step {step:.3g} s is a {1 / step:.3g} Hz rate, above {MAX_RATE_HZ:g} Hz: are the "
            "time stamps in seconds?",
        )
    grid = (t[-1] - t[0]) / step + 1
    if grid > MAX_GRID_SAMPLES:
        raise LearningError(
            "t",
            f"{t[-1] - t[0]:.6g} s at the median step of {step:.3g} s spans {grid:.3g} samples, more than "
            f"{MAX_GRID_SAMPLES} (a gap in the time stamps, or a very long recording)",
        )
