"""The ground-truth corpus record (`CorpusCase`, `TruthSegment`) and the segment rules that turn a generated
contact into the segments a learner should produce (`truth_segments`).

World frame, z up, SI units (m, s, N), quaternions scalar-last ``[x, y, z, w]`` world-from-tool; the wrench
is the one the TOOL APPLIES to the environment, at the tool point, world frame (docs/CONVENTIONS.md). Normals
point INTO the surface (along the pressing direction). The demonstrations are built in `corpus.build`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
from numpy.typing import NDArray

from corpus.build import Assembled
from schemas import Demonstration, DemonstrationMetadata
from skills.frames import rotation_from_vectors
from skills.segmentation import DIP_FRACTION

WINDING_WINDOW_S = 0.1
"""Half width of a winding cut's window around the moment the winding crosses a multiple of 360 deg, s."""
WINDING_MIN_REMAINDER_TURNS = 0.25
"""A winding cut is made only if at least this many turns of winding remain after it."""
UNSTEADY_PRESS_FRACTION = 0.3
"""An unsteady segment's ``force_n`` is the mean true normal force over its samples pressing above this fraction of
its largest true normal force (the ramps' feet left out)."""
CsvReader = Callable[[str, dict[str, object]], Demonstration]
"""Reads a recording's CSV text with its import options (``services.csv_import``, which the corpus may not import)."""


@dataclass(frozen=True)
class TruthSegment:
    """One contact segment a learner should produce.

    ``start_window`` / ``end_window`` (lo, hi) s: where the boundary may lie (lo == hi for a touch-down, where
    the normal force starts to rise, or a lift-off, where it has fallen to zero). ``normal`` the inward unit
    normal of the plane (slide cases; None for contours), world. ``force_n`` the mean true normal force over
    the segment's plateau (between its ramps), N; for an unsteady segment the mean true normal force over the
    samples of its span that press above `UNSTEADY_PRESS_FRACTION` of its largest. ``steady``: False where the
    press was not steady (a ramp, a wobble), so the skill must reproduce the force profile, not a constant.
    """

    start_window: tuple[float, float]
    end_window: tuple[float, float]
    normal: NDArray[np.float64] | None
    force_n: float
    steady: bool = True

    @property
    def span(self) -> tuple[float, float]:
        """(start, end) s from the middle of the start window to the middle of the end window."""
        return 0.5 * sum(self.start_window), 0.5 * sum(self.end_window)


@dataclass(frozen=True)
class CsvRecording:
    """A human-like case as its recording file holds it, and how to read it back.

    ``csv_text``: columns ``t, x, y, z, qw, qx, qy, qz, fx, fy, fz, mx, my, mz``: time stamps (s, irregular for
    some cases, with repeated and dropped rows), tool point (m, world), orientation scalar-FIRST, the wrist
    sensor's reading of the wrench ON the tool in the sensor (= tool) frame with its offset, the hand's push
    on the arm and noise (N, N·m). ``import_options``: the import options that read it correctly, by field
    name (``schemas.import_options.CsvImportOptions(**import_options)``): quaternion order wxyz, wrench
    measured-on-tool in the tool frame, the rate, the case's name. ``sensor_offset`` (6,): the
    offset as the file reads it (sensor frame, measured on the tool). ``hand_forces`` (N, 3): the force the
    hand puts on the arm at the case's samples, world, applied-by-tool convention, N (the file carries it too).
    """

    csv_text: str
    import_options: dict[str, object]
    sensor_offset: NDArray[np.float64]
    hand_forces: NDArray[np.float64]


@dataclass(frozen=True)
class CorpusCase:
    """One demonstration with its ground truth, at uniform samples ``t`` (N,) s.

    ``positions`` (N, 3) m tool point, world (tremor and pad sink-in included); ``orientations`` (N, 4)
    world-from-tool, scalar-last (tool z roughly into the surface); ``wrenches`` (N, 6) the TRUE wrench the tool
    applies, world, at the tool point (no noise, no offset, no hand); ``in_contact`` (N,) the tool touches a
    surface (including a brush that is no stroke); ``normals`` (N, 3) inward unit normal of the surface touched,
    in free space of the nearest traced surface point; ``normal_force_n`` (N,) the true normal force, N;
    ``segments`` the contact segments a learner should produce, in time order (`truth_segments`).
    ``sensed_wrenches`` (N, 6): what an ideal applied-by-tool world-frame sensor reports (the truth plus
    noise) for the analytic cases, None for the human-like ones, whose sensor view is ``recording``.
    ``parameters``: the values the case was drawn with (``tilt_deg``, ``radius_m``, ``friction``,
    ``pad_stiffness_n_m``, ``rate_hz``, ...).
    """

    name: str
    family: str
    skill_type: str
    t: NDArray[np.float64]
    positions: NDArray[np.float64]
    orientations: NDArray[np.float64]
    wrenches: NDArray[np.float64]
    in_contact: NDArray[np.bool_]
    normals: NDArray[np.float64]
    normal_force_n: NDArray[np.float64]
    segments: list[TruthSegment]
    parameters: dict[str, float] = field(default_factory=dict)
    sensed_wrenches: NDArray[np.float64] | None = None
    recording: CsvRecording | None = None

    def demonstration(self, csv_reader: CsvReader | None = None) -> Demonstration:
        """Return the demonstration a learner is given.

        Analytic cases: the samples with ``sensed_wrenches``. Human-like cases: the recording file read back by
        ``csv_reader(csv_text, import_options)`` (the corpus does not import services: e.g.
        ``lambda text, options: demonstration_from_csv(text, CsvImportOptions(**options))``).
        """
        if self.recording is None:
            assert self.sensed_wrenches is not None
            metadata = DemonstrationMetadata(name=self.name, source=f"corpus:{self.family}")
            return Demonstration.from_arrays(self.t, self.positions, self.orientations, self.sensed_wrenches, metadata)
        if csv_reader is None:
            raise ValueError(f"{self.name} is a recording file: pass a csv_reader (services.csv_import)")
        return csv_reader(self.recording.csv_text, self.recording.import_options)


# --------------------------------------------------------------------------- the segment rules


def _heading_basis(normal: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit vectors spanning the plane across ``normal``."""
    e1 = rotation_from_vectors(np.array([0.0, 0.0, 1.0]), normal)[:, 0]
    return e1, np.cross(normal, e1)


def winding_windows(t: NDArray, path: NDArray, normal: NDArray) -> list[tuple[float, float]]:
    """Windows (s) ±`WINDING_WINDOW_S` around each full turn of the heading of ``path`` across ``normal``,
    counted from the first sample, where at least `WINDING_MIN_REMAINDER_TURNS` of winding remain after it.

    Reversals (a heading flip of more than 90 deg between samples) do not wind.
    """
    velocity = np.gradient(path, t, axis=0)
    e1, e2 = _heading_basis(normal)
    heading = np.arctan2(velocity @ e2, velocity @ e1)
    step = np.angle(np.exp(1j * np.diff(heading)))
    winding = np.concatenate([[0.0], np.cumsum(np.where(np.abs(step) > np.pi / 2, 0.0, step))])
    winding *= 1.0 if winding[-1] >= 0 else -1.0
    turns = np.arange(1, int((winding[-1] / (2 * np.pi)) - WINDING_MIN_REMAINDER_TURNS) + 1)
    target = 2 * np.pi * turns
    after = np.searchsorted(np.maximum.accumulate(winding), target)  # first sample at or past each full turn
    fraction = (target - winding[after - 1]) / (winding[after] - winding[after - 1])
    crossings = t[after - 1] + fraction * (t[after] - t[after - 1])
    return [(c - WINDING_WINDOW_S, c + WINDING_WINDOW_S) for c in crossings]


def dip_windows(t: NDArray, force: NDArray, plateau_id: NDArray) -> list[tuple[float, float]]:
    """Windows (s) of the force dips between consecutive plateaus of one contact: from the moment the force
    falls below `DIP_FRACTION` of the lower plateau's mean to the moment it rises above it again."""
    windows = []
    strokes = np.unique(plateau_id[plateau_id >= 0])
    for a, b in pairwise(strokes):
        threshold = DIP_FRACTION * min(force[plateau_id == a].mean(), force[plateau_id == b].mean())
        lo, hi = np.flatnonzero(plateau_id == a)[-1], np.flatnonzero(plateau_id == b)[0]
        below = lo + np.flatnonzero(force[lo:hi] < threshold)
        windows.append((float(t[below[0]]), float(t[below[-1] + 1])))
    return windows


def merged(windows: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The windows sorted, overlapping ones joined (both rules found the same boundary)."""
    out: list[tuple[float, float]] = []
    for lo, hi in sorted(windows):
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def truth_segments(case: Assembled, slide: bool, steady: bool = True) -> list[TruthSegment]:
    """The contact segments a learner should produce from ``case`` (the segment rules, docs in corpus/families.py).

    Per stroke contact (touch-down to lift-off): boundaries at force dips (`dip_windows`; every dip in the corpus
    lies between strokes that go another way or press another surface) and full turns of winding
    (`winding_windows`), windows that overlap joined. The
    heading is taken on the noise-free path across the contact's mean normal. ``slide``: each segment carries
    the mean inward normal over its plateau (a plane's normal). ``steady`` False: the press was not steady (a
    ramp, a wobble), every segment is marked so and its ``force_n`` is taken over its pressing samples
    (`TruthSegment`).
    """
    segments = []
    for c in range(int(case.contact_id.max()) + 1):
        rows = np.flatnonzero(case.contact_id == c)
        t, path = case.t[rows], case.path[rows]
        mean_normal = case.normals[rows].mean(axis=0)
        mean_normal /= np.linalg.norm(mean_normal)
        boundaries = merged(
            dip_windows(t, case.normal_force[rows], case.plateau_id[rows]) + winding_windows(t, path, mean_normal)
        )
        starts = [(t[0], t[0]), *boundaries]
        ends = [*boundaries, (t[-1], t[-1])]
        for start, end in zip(starts, ends, strict=True):
            plateau = rows[(case.plateau_id[rows] >= 0) & (t > start[1]) & (t < end[0])]
            normal = None
            if slide:
                normal = case.normals[plateau].mean(axis=0)
                normal /= np.linalg.norm(normal)
            force = case.normal_force[plateau].mean()
            if not steady:
                # No plateau to average: the profile's pressing part, over the span the scoring scores.
                spanned = case.normal_force[rows[(t >= 0.5 * sum(start)) & (t <= 0.5 * sum(end))]]
                force = spanned[spanned > UNSTEADY_PRESS_FRACTION * spanned.max()].mean()
            segments.append(
                TruthSegment(
                    start_window=(float(start[0]), float(start[1])),
                    end_window=(float(end[0]), float(end[1])),
                    normal=normal,
                    force_n=float(force),
                    steady=steady,
                )
            )
    return segments


def analytic_case(
    name: str,
    family: str,
    skill_type: str,
    case: Assembled,
    parameters: dict[str, float],
    rng: np.random.Generator,
    noise_n: float = 0.2,
    steady: bool = True,
) -> CorpusCase:
    """The `CorpusCase` of an analytic demonstration; its sensor reads the true wrench plus Gaussian noise
    (``noise_n`` N on the forces, 2 % of it in N·m on the moments). ``steady``: see `truth_segments`."""
    sensed = case.wrenches + rng.normal(0.0, noise_n, case.wrenches.shape) * np.repeat([1.0, 0.02], 3)
    return CorpusCase(
        name=name,
        family=family,
        skill_type=skill_type,
        t=case.t,
        positions=case.positions,
        orientations=case.orientations,
        wrenches=case.wrenches,
        in_contact=case.touching,
        normals=case.normals,
        normal_force_n=case.normal_force,
        segments=truth_segments(case, skill_type == "slide", steady),
        parameters=parameters,
        sensed_wrenches=sensed,
    )


def sampled_case(
    name: str,
    family: str,
    skill_type: str,
    fine: Assembled,
    samples: NDArray[np.int_],
    parameters: dict[str, float],
    recording: CsvRecording,
) -> CorpusCase:
    """The `CorpusCase` of a recording FILE made from the assembled demonstration ``fine``: the truth at its samples
    ``samples`` (indices into ``fine``: the file's nominal sample times), the truth segments found on the fine
    grid."""
    return CorpusCase(
        name=name,
        family=family,
        skill_type=skill_type,
        t=fine.t[samples],
        positions=fine.positions[samples],
        orientations=fine.orientations[samples],
        wrenches=fine.wrenches[samples],
        in_contact=fine.touching[samples],
        normals=fine.normals[samples],
        normal_force_n=fine.normal_force[samples],
        segments=truth_segments(fine, skill_type == "slide"),
        parameters=parameters,
        recording=recording,
    )
