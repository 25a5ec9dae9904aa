"""What the service accepts beyond the field bounds of ``schemas/``: time stamps it can learn from in bounded
memory, inline skills whose parts fit together."""

from __future__ import annotations

import numpy as np

from schemas.demonstration import Demonstration
from schemas.skill import Skill

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


def skill_problems(skill: Skill) -> list[tuple[list[str | int], str]]:
    """Where an inline skill that validates field by field is still incoherent, as (loc under ``skill``, reason):
    a contact segment without compliant frames or without a force, DMP parameters whose shapes disagree
    (``skills.dmp`` rebuilds each one), compliant frame lists of different lengths."""
    from schemas.skill import SegmentKind
    from skills.dmp import DMP, QuaternionDMP

    problems: list[tuple[list[str | int], str]] = []
    for k, segment in enumerate(skill.segments):
        where: list[str | int] = ["segments", k]
        if segment.kind is SegmentKind.contact:
            if segment.compliant_frames is None:
                problems.append(([*where, "compliant_frames"], "a contact segment needs its compliant frame(s)"))
            if segment.force_constant_n is None and segment.force_dmp is None:
                problems.append(([*where, "force_constant_n"], "a contact segment needs force_constant_n or force_dmp"))
        frames = segment.compliant_frames
        if frames is not None and not len(frames.t) == len(frames.origins) == len(frames.orientations):
            problems.append(([*where, "compliant_frames"], "t, origins and orientations need one entry per frame"))
        for name, rebuild in (("position_dmp", DMP), ("orientation_dmp", QuaternionDMP), ("force_dmp", DMP)):
            parameters = getattr(segment, name)
            if parameters is None:
                continue
            try:
                rebuild.from_parameters(parameters)
            except ValueError as exc:
                problems.append(([*where, name], f"inconsistent DMP parameters: {exc}"))
    return problems
