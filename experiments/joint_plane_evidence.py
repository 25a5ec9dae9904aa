"""Why a slide learned from several straight strokes is not always as close to the plane as the best single stroke
(docs/LEARNING.md, section 11): the joint CF z against the truth as the pooled force direction is trusted less.

Run from the repository root::

    .venv/bin/python -m experiments.joint_plane_evidence

For every set of three of four trials of a straight stroke (`corpus.families.human_trials`, leave-one-out as
`benchmarks/bench_joint_learning.py` forms them; a trial whose own CF z is off by more than
`skills.joint_correspondence.SAME_SURFACE_DEG` left out, as the learner leaves it out), the pooled slide CF
(`skills.compliant_frames.slide_frame` on the three strokes' samples, as `skills.joint_normals` pools them) with the
friction-free force's uncertainty at the learner's value (the trials' median, 5° at the least) and at larger ones, up
to the geometry alone. Printed: the median and largest angle (deg) of the CF z from the true plane's normal, and in
how many sets it is no larger than the best single stroke's. Then, as a yardstick: how often the mean of three
independent leans is no larger than the smallest of them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from corpus.families import human_trials
from experiments.joint_trials import read_csv
from schemas.skill import LearnOptions, SegmentKind
from skills.compliant_frames import slide_frame
from skills.joint_correspondence import SAME_SURFACE_DEG
from skills.parameterize import LearnedSegment, LearnedTrial, learn_trial

TUNED, HELD_OUT = (0, 1, 2, 3), (4, 5, 6, 7)
FORCE_SIGMAS_DEG = (None, 7.5, 10.0, 15.0, 60.0)
"""The pooled force direction's uncertainty (deg): None the learner's; 60° leaves the geometry alone."""


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), 0.0, 1.0))))


def _stroke(trial: LearnedTrial) -> LearnedSegment | None:
    contacts = [item for item in trial.learned if item.segment.kind is SegmentKind.contact]
    return contacts[0] if len(contacts) == 1 and contacts[0].plane is not None else None


def errors(task: int) -> list[tuple[float, list[float]]]:
    """Per left-out trial of ``task``: the best single stroke's error and the pooled CF z's at each sigma (deg)."""
    cases = human_trials("human-straight", task, 4)
    truth = cases[0].segments[0].normal
    trials = [learn_trial(case.demonstration(read_csv), LearnOptions(strict=False)) for case in cases]
    strokes = [_stroke(t) for t in trials]
    usable = [
        i
        for i, s in enumerate(strokes)
        if s is not None and _angle_deg(s.plane.rotation[:, 2], truth) < SAME_SURFACE_DEG
    ]
    out = []
    for left_out in range(len(cases)):
        others = [i for i in usable if i != left_out]
        rows = [slice(strokes[i].segment.start_index, strokes[i].segment.end_index) for i in others]
        recordings = [trials[i].recording for i in others]
        pooled = [np.concatenate([r.positions[s] for r, s in zip(recordings, rows, strict=True)])]
        pooled += [np.concatenate([r.forces[s] for r, s in zip(recordings, rows, strict=True)])]
        pooled += [np.concatenate([r.contact.directions[s] for r, s in zip(recordings, rows, strict=True)])]
        groups = [r.surfaces.group(s.start, s.stop) for r, s in zip(recordings, rows, strict=True)]
        learners = float(np.median([g.force_sigma_deg for g in groups if g is not None]))
        joint = [
            _angle_deg(slide_frame(*pooled, force_sigma_deg=sigma or learners).rotation[:, 2], truth)
            for sigma in FORCE_SIGMAS_DEG
        ]
        out.append((min(_angle_deg(strokes[i].plane.rotation[:, 2], truth) for i in others), joint))
    return out


def main() -> int:
    header = "| tasks | force sigma | joint median ° | joint largest ° | no larger than the best single | best single"
    print(f"{header} median ° |")
    print("|---|---|--:|--:|--:|--:|")
    for label, tasks in (("tuned 0-3", TUNED), ("held out 4-7", HELD_OUT)):
        sets = [item for task in tasks for item in errors(task)]
        best = np.array([b for b, _ in sets])
        joint = np.array([j for _, j in sets])
        for k, sigma in enumerate(FORCE_SIGMAS_DEG):
            name = "the learner's" if sigma is None else ("geometry alone" if sigma >= 60 else f"{sigma:g}°")
            print(
                f"| {label} | {name} | {np.median(joint[:, k]):.2f} | {joint[:, k].max():.2f} | "
                f"{int(np.sum(joint[:, k] <= best + 1e-9))} of {len(sets)} | {np.median(best):.2f} |"
            )
    leans = np.random.default_rng(0).normal(size=(200_000, 3))
    mean_wins = np.abs(leans.mean(axis=1)) <= np.abs(leans).min(axis=1)
    print(
        f"\nThree independent leans (normal, one axis): their mean is no larger than the smallest of them in "
        f"{100 * mean_wins.mean():.0f} % of draws; its median is "
        f"{np.median(np.abs(leans.mean(axis=1))) / np.median(np.abs(leans).min(axis=1)):.2f} x the smallest's."
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
