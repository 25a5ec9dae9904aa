"""Array checks shared by the validators of the contract. Each raises ValueError saying where and why."""

from __future__ import annotations

import numpy as np


def finite_rows(array: np.ndarray, what: str) -> None:
    """Raise ValueError naming the first row of a 2-D ``array`` that holds NaN or inf."""
    if array.size == 0:
        raise ValueError("is empty")
    bad = ~np.isfinite(array)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=-1))[0]) if array.ndim > 1 else int(np.flatnonzero(bad)[0])
        raise ValueError(f"{what} {row} is not finite (NaN or inf); {int(bad.sum())} non-finite values in all")


def strictly_increasing(t: np.ndarray, min_step: float) -> None:
    """Raise ValueError naming the first sample where time stamps ``t`` (s) do not increase, or increase by less than
    ``min_step`` (s: a rate above ``1 / min_step`` Hz is no recording, and a step of 5e-324 s an infinite rate)."""
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise ValueError(
            f"time stamps must be strictly increasing: sample {k} has t={t[k]:.6g} s after "
            f"t={t[k - 1]:.6g} s ({bad.size} such steps; the CSV importer resamples irregular data)"
        )
    small = np.flatnonzero(steps < min_step)
    if small.size:
        k = int(small[0]) + 1
        raise ValueError(
            f"time stamps must step by at least {min_step:g} s (a rate of at most {1 / min_step:g} Hz): sample {k} "
            f"is {steps[k - 1]:.3g} s after sample {k - 1} ({small.size} such steps; are the time stamps in seconds?)"
        )


def bounded_rows(array: np.ndarray, limit: float, what: str, unit: str, hint: str = "") -> None:
    """Raise ValueError naming the first row of a 2-D ``array`` with a value whose magnitude exceeds ``limit``
    (in ``unit``): finite but implausible values (1e300 N, positions in mm) never reach the science or the store."""
    bad = np.abs(array) > limit
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=-1))[0])
        value = float(array[row][np.flatnonzero(bad[row])[0]])
        raise ValueError(
            f"{what} {row} holds {value:.6g} {unit}, beyond the plausible ±{limit:g} {unit}"
            f"{hint}; {int(bad.any(axis=-1).sum())} such rows"
        )
