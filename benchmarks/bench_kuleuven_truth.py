"""Ground truth of the four KU Leuven contours from the object's CAD: registration, normal cone, and where the measured
force lies against it.

For each recording (``data/kuleuven_contour``, imported as its README says): the object's crease registered to the
contact path (`services.kuleuven_object.kuleuven_ground_truth`), the normal cone of the crease at every sample, and
the applied force, with and without its friction part (:func:`friction_free_forces`: its component along the
smoothed velocity removed: the textbook way), measured against the cone across the crease
(`skills.registration.angle_outside_cone`, `angles_about_crease`); and the skill learned from it, its CF z judged
against the cone at every sample. Writes its section of docs/LEARNING.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import LEARNING_MD, machine_line, pin_blas_threads, report_main

pin_blas_threads()

import numpy as np  # noqa: E402
from scipy.ndimage import gaussian_filter1d  # noqa: E402

from services.datasets import kuleuven_recordings  # noqa: E402
from services.kuleuven_object import kuleuven_ground_truth, kuleuven_object, skill_against_object  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402
from skills.registration import angle_outside_cone, angles_about_crease, closest_points_on_polyline  # noqa: E402

SECTION = "kuleuven-truth"
COMMAND = ".venv/bin/python benchmarks/bench_kuleuven_truth.py"
VELOCITY_SMOOTHING_S = 0.02
"""Standard deviation (s) of the Gaussian smoothing of the positions the velocity is taken from (the learner's)."""


def smoothed_velocities(positions: np.ndarray, rate_hz: float) -> np.ndarray:
    """Velocities (N, 3) m/s of uniformly sampled ``positions`` (N, 3) m smoothed over ``VELOCITY_SMOOTHING_S``."""
    smoothed = gaussian_filter1d(positions, sigma=max(1.0, VELOCITY_SMOOTHING_S * rate_hz), axis=0, mode="nearest")
    return np.gradient(smoothed, 1.0 / rate_hz, axis=0)


def friction_free_forces(forces: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """The applied ``forces`` (N, 3) N without their component along ``velocities`` (N, 3): on every sample, at any
    speed (world frame)."""
    direction = velocities / np.maximum(np.linalg.norm(velocities, axis=1, keepdims=True), 1e-12)
    return forces - np.sum(forces * direction, axis=1, keepdims=True) * direction


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) sample of every run of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def trial_measures(recording: Path) -> dict:
    """The measures of one recording (distances in m, angles in rad, times in s, speeds in m/s)."""
    truth = kuleuven_ground_truth(recording)
    arrays = truth.demonstration.arrays()
    positions, forces, t = arrays.positions, arrays.wrenches[:, :3], arrays.t
    rate_hz = truth.demonstration.metadata.resampled_rate_hz or 1.0 / float(np.median(np.diff(t)))
    cone = truth.cone
    velocities = smoothed_velocities(positions, rate_hz)
    speed = np.linalg.norm(velocities, axis=1)
    free = friction_free_forces(forces, velocities)
    outside = angle_outside_cone(free, cone.inward_a, cone.inward_b)
    chosen = truth.candidates.index(truth.registration)
    others = [k for k in range(len(truth.candidates)) if k != chosen]
    twin = min(others, key=lambda k: truth.candidates[k].rms_distance_m) if others else None
    edge = closest_points_on_polyline(truth.registration.to_cad(positions), truth.kuleuven_object.edge).distances
    bisectors = cone.bisectors
    skill = learn_skill(truth.demonstration)
    judged = skill_against_object(skill, truth)
    return {
        "skill": skill,
        "judged": judged,
        "trial": recording.stem,
        "samples": len(t),
        "duration": float(t[-1] - t[0]),
        "registration": truth.registration,
        "edge_rms": float(np.sqrt(np.mean(edge**2))),
        "edge_max": float(edge.max()),
        "candidates": len(truth.candidates),
        "chosen_angle": float(truth.candidate_bisector_angles_rad[chosen]),
        "twin": None if twin is None else truth.candidates[twin],
        "twin_angle": None if twin is None else float(truth.candidate_bisector_angles_rad[twin]),
        "turn": float(np.arccos(np.clip(bisectors @ bisectors.T, -1.0, 1.0)).max()),
        "opening": cone.openings_rad,
        "outside": outside,
        "outside_runs": [
            (float(t[a]), float(t[b]), float(outside[a : b + 1].max()), float(speed[a : b + 1].max()))
            for a, b in _runs(outside > 0.0)
        ],
        "lean": angles_about_crease(free, cone.inward_a, cone.inward_b) - cone.openings_rad / 2.0,
        "applied_outside": angle_outside_cone(forces, cone.inward_a, cone.inward_b),
        "applied_lean": angles_about_crease(forces, cone.inward_a, cone.inward_b) - cone.openings_rad / 2.0,
    }


def _deg(value: float) -> str:
    return f"{np.degrees(value):.1f}"


def _spread(angles: np.ndarray) -> str:
    """Median / 95th percentile / max of ``angles`` (rad), in degrees."""
    return f"{_deg(np.median(angles))} / {_deg(np.percentile(angles, 95))} / {_deg(angles.max())}"


def _range(angles: np.ndarray) -> str:
    """Median [5th to 95th percentile] of ``angles`` (rad), in degrees."""
    return f"{_deg(np.median(angles))} [{_deg(np.percentile(angles, 5))} to {_deg(np.percentile(angles, 95))}]"


def build_report() -> str:
    rows = [trial_measures(path) for path in kuleuven_recordings()]
    registration = [
        "| trial | samples | path to crease RMS / max, mm | path to authors' edge RMS / max, mm | placements found | "
        "shape twin's RMS, mm | force from bisector °: chosen / twin (median) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    cone = [
        "| trial | bisector turn ° | opening ° median [min-max] | friction-free force outside the cone °: median / "
        "95 % / max | samples outside % | applied force outside the cone °: max | lean °, friction-free: median "
        "[5-95 %] | lean °, applied: median [5-95 %] | abs. lean ° friction-free: median / 95 % / max |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        reg, twin = r["registration"], r["twin"]
        registration.append(
            f"| {r['trial']} | {r['samples']} | {1e3 * reg.rms_distance_m:.2f} / {1e3 * reg.max_distance_m:.2f} | "
            f"{1e3 * r['edge_rms']:.2f} / {1e3 * r['edge_max']:.2f} | {r['candidates']} | "
            f"{'-' if twin is None else f'{1e3 * twin.rms_distance_m:.2f}'} | "
            f"{_deg(r['chosen_angle'])} / {'-' if twin is None else _deg(r['twin_angle'])} |"
        )
        opening = r["opening"]
        cone.append(
            f"| {r['trial']} | {_deg(r['turn'])} | {_deg(np.median(opening))} [{_deg(opening.min())}-"
            f"{_deg(opening.max())}] | {_spread(r['outside'])} | {100 * np.mean(r['outside'] > 0):.1f} | "
            f"{_deg(r['applied_outside'].max())} | {_range(r['lean'])} | {_range(r['applied_lean'])} | "
            f"{_spread(np.abs(r['lean']))} |"
        )
    learned = [
        "| trial | learned (auto, confidence) | failed checks | CF z outside the cone °: max | CF z from the "
        "bisector °: median | CF z from the friction-free force °: 95 % / max | the same in the first 0.3 s: max |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        skill, judged = r["skill"], r["judged"]
        first = judged.since_touch_down_s < 0.3
        learned.append(
            f"| {r['trial']} | {skill.skill_type.value} ({skill.auto_selection.confidence:.2f}) | "
            f"{len(skill.warnings())} | {_deg(judged.outside_cone.max())} | {_deg(np.median(judged.from_bisector))} | "
            f"{_deg(np.percentile(judged.from_friction_free, 95))} / {_deg(judged.from_friction_free.max())} | "
            f"{_deg(judged.from_friction_free[first].max())} |"
        )
    where = []
    for r in rows:
        runs = ", ".join(
            f"{a:.2f}-{b:.2f} s (up to {_deg(peak)}°, speed ≤ {1e3 * fastest:.0f} mm/s)"
            for a, b, peak, fastest in r["outside_runs"]
        )
        where.append(f"{r['trial']} ({r['duration']:.2f} s): {runs or 'never'}")
    crease = kuleuven_object().crease.points
    placements = []
    for k, first in enumerate(rows):
        for second in rows[k + 1 :]:
            a, b = first["registration"], second["registration"]
            turn = np.arccos(np.clip((np.trace(a.rotation.T @ b.rotation) - 1.0) / 2.0, -1.0, 1.0))
            moved = np.linalg.norm(a.to_world(crease) - b.to_world(crease), axis=1).max()
            placements.append(f"{first['trial']}/{second['trial']} {_deg(turn)}°, {1e3 * moved:.1f} mm")
    return "\n".join(
        [
            f"Command: `{COMMAND}`. Per recording: the object's crease (`data/kuleuven_contour/contour.STL`) "
            "registered to the imported contact path (`services/kuleuven_object.py`, `skills/registration.py`); the "
            "normal cone of the crease at every sample; the applied force with and without its friction part (its "
            "component along the velocity, smoothed over 20 ms, removed at every sample) measured against the cone "
            "ACROSS the crease (the component along the crease tangent removed). Lean: the signed angle from the "
            "bisector, positive towards face b.",
            "",
            *registration,
            "",
            *cone,
            "",
            "Where the friction-free force leaves the cone: " + "; ".join(where) + ".",
            "",
            "Placements compared (the rotation between two trials' registrations, and how far the crease moved at "
            "most): " + "; ".join(placements) + ".",
            "",
            "The skills learned from them (`skill_type=auto`), judged against the object at every sample of their "
            "contact segments (`services.kuleuven_object.skill_against_object`): the CF z against the cone, its "
            "bisector (the person's lean) and the friction-free force the learner sees (`skills.friction`, about "
            "the CF z, smoothed over 50 ms), touch-down included.",
            "",
            *learned,
            "",
            machine_line(),
        ]
    )


def main(argv: list[str] | None = None) -> int:
    # The full run is its own smoke run: four recordings registered and learned, ~5 s.
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, path=LEARNING_MD, smoke={})


if __name__ == "__main__":
    raise SystemExit(main())
