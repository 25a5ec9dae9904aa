"""The KU Leuven skills executed on the true object, beside the work piece rebuilt from each skill.

For each recording (``data/kuleuven_contour``, imported as its README says): the skill learned from it (``auto``, as
`benchmarks/bench_real_skills.py` learns it) is placed in the robot's reach as every real recording is
(`sim_worker.execution_world.execution_world`, which rebuilds its work piece); the object's CAD, registered to the
recording (`services.kuleuven_object`), is moved by the same placement and held as overlapping convex pieces
(`sim_worker.cad_work_piece`). The skill then runs with ``hybrid_cf`` and the realistic wrist sensor on the rebuilt
work piece, on the measured one where the resolver builds one from the demonstration, and on the CAD: with the default
gains and with the CF x-y stiffness raised to :data:`LATERAL_STIFFNESS_N_PER_M`. Why the second: a ball of radius
``r`` resting on a convex crease and pressed with ``F`` rolls off it unless the lateral stiffness holding it exceeds
``F / r`` (as it moves sideways the contact normal tilts and pushes it further): 2000-2600 N/m for the KU forces of
20-26 N and the 10 mm ball, against the default 3000 N/m; off the crease the ball presses on one face, whose normal
lies 45° from the CF z, and the true force grows by up to 1/cos 45°.

Also: how far each work piece's surface, as PyBullet holds it (its pieces' faces out by the convex margin), lies from
the registered CAD along the skill's contact path and across a band about it; and how closely the CAD pieces hold
the STL's faces.

Frames: the robot's world (m) after the placement; a recording's world before it; the CAD frame of the STL (m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull

from execution.telemetry import Telemetry
from schemas import ExecutionSettings
from schemas.execution import PHASE_CODES, ExecutionMetrics, ExecutionPhase, Placement
from schemas.verdict import VerdictCheckName
from schemas.world import WorldConfig
from services.datasets import kuleuven_recordings
from services.kuleuven_object import KuleuvenGroundTruth, kuleuven_ground_truth
from sim_worker.cad_work_piece import CONVEX_MARGIN_M, cad_world_config, crease_pieces, crease_side_faces
from sim_worker.execution_world import ExecutionWorld, execution_world
from sim_worker.executor import run_skill
from skills.mesh_geometry import closest_points_on_mesh
from skills.parameterize import learn_skill
from skills.placement import skill_tool_path
from skills.quaternions import matrix_from_quaternion
from skills.registration import (
    Registration,
    TriangleMesh,
    angle_outside_cone,
    angles_about_crease,
    closest_points_on_polyline,
    normal_cones_at,
)

LATERAL_STIFFNESS_N_PER_M = 10000.0
"""The CF x and y stiffness of the second execution on the CAD, N/m (the default is 3000 N/m): 3 × the largest
``F / r`` (33 N on the 10 mm ball). A lateral spring ``K`` against the crease's negative stiffness ``F / r`` holds the
ball ``x = K x_ref / (K - F / r)`` off the crease when its taught path lies ``x_ref`` off it (up to 2.7 mm on these
recordings); its contact normal then leans ``asin(x / r)`` from the CF z, and the force along it grows by ``1 / cos``
of that lean: within 10 % needs ``x`` under 4 mm, ``K`` at least 3 ``F / r``. (6000 N/m, 2-3 × ``F / r``, held three
of the four within 10 %: contour_b_2 ran at 15.5 %.)"""
CAD_STIFFNESSES_N_PER_M: tuple[float | None, ...] = (None, LATERAL_STIFFNESS_N_PER_M)
"""The CF x-y stiffnesses each skill runs with on the CAD, N/m (None: the default gains')."""
ON_FACE_DEG = 2.0
"""The ball presses on one face of the crease when the true contact normal lies within this of that face's normal
(across the crease), deg."""
PATH_STEP_S = 0.01
"""The skill's contact path is sampled this often for the surface comparison, s."""
BAND_HALF_WIDTH_M = 0.005
"""Half width of the band about the contact path the surfaces are compared over, m (where the ball touches when it
leans off the crease's bisector by up to 30°)."""
BAND_RAYS = 11
"""Rays across the band at every path sample."""
STL_FIT_REACH_M = 0.003
"""A piece counts for an STL point's distance when the point lies within this of its bounding box, m (the pieces
hold the faces within a millimetre)."""
STL_FIT_SAMPLES = 20000
"""Points spread over the STL's faces by the crease for :func:`stl_fit`."""
RAY_CLEARANCE_M = 0.05
"""The rays start this far back along the CF z from the surface, m."""


@dataclass(frozen=True)
class CadRun:
    """One execution: the ``work_piece`` it ran on ("CAD", "rebuilt" or "measured"), the CF x-y stiffness (N/m), its
    metrics, and on the CAD the share of the contact phase's pressing steps with the ball on one face (else None)."""

    work_piece: str
    lateral_stiffness_n_per_m: float
    metrics: ExecutionMetrics
    on_face: float | None


@dataclass(frozen=True)
class SurfaceGap:
    """A work piece's surface against the registered CAD (robot's world).

    Along the contact line (the surface where the CF z through the skill's tool point meets it): ``line_distance_m``
    (M,) from the CAD's surface, ``line_outside_cone_rad`` (M,) its normal's angle outside the CAD crease's normal
    cone and ``line_from_bisector_rad`` (M,) from the cone's bisector. Over the band across the path:
    ``band_distance_m`` (B,) and ``band_normal_rad`` (B,), the angle between its normal and the normal of the CAD face
    nearest.
    """

    work_piece: str
    line_distance_m: NDArray[np.float64]
    line_outside_cone_rad: NDArray[np.float64]
    line_from_bisector_rad: NDArray[np.float64]
    band_distance_m: NDArray[np.float64]
    band_normal_rad: NDArray[np.float64]


@dataclass(frozen=True)
class CadTrial:
    """One recording: its ``trial`` name, the placement chosen for its skill and why, the number of convex pieces
    holding the CAD, the distances (m) of the placed skill's contact path (its tool point every
    :data:`PATH_STEP_S`) from the CAD's crease, the executions and the surfaces compared."""

    trial: str
    placement: Placement
    placement_reason: str
    pieces: int
    path_to_crease_m: NDArray[np.float64]
    runs: tuple[CadRun, ...]
    gaps: tuple[SurfaceGap, ...]


def _placement_matrices(placement: Placement) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The placement's rotation (3, 3) and translation (3,) m, ``x_robot = R x_recording + t``."""
    return matrix_from_quaternion(np.asarray(placement.rotation, dtype=float)), np.asarray(placement.translation_m)


def placed_object(truth: KuleuvenGroundTruth, placement: Placement) -> Registration:
    """Robot's world from CAD for a recording whose skill ``placement`` put in reach."""
    return truth.placed_registration(*_placement_matrices(placement))


def cad_world(truth: KuleuvenGroundTruth, placement: Placement, base: WorldConfig | None = None) -> dict[str, Any]:
    """The world (a ``WorldConfig`` dict, for ``execution_world(..., world=...)``) holding the recording's object where
    the skill's ``placement`` puts it: ``base`` (default the default world) without its table."""
    where = placed_object(truth, placement)
    contour = truth.kuleuven_object
    return cad_world_config(contour.mesh, contour.crease, where.rotation, where.translation_m, base).to_dict()


def placed_mesh(truth: KuleuvenGroundTruth, placement: Placement) -> TriangleMesh:
    """The object's mesh in the robot's world, m."""
    mesh = truth.kuleuven_object.mesh
    return TriangleMesh(vertices=placed_object(truth, placement).to_world(mesh.vertices), faces=mesh.faces)


def on_face_share(telemetry: Telemetry, where: Registration, truth: KuleuvenGroundTruth, tool_radius_m: float) -> float:
    """The share of the contact phase's pressing steps with the ball on one face of the crease: the true contact
    normal within :data:`ON_FACE_DEG` of a face's normal, or beyond it (across the crease), at the crease segment
    nearest the ball's centre (``where``: robot's world from CAD)."""
    rows = (telemetry.phase_codes == PHASE_CODES[ExecutionPhase.contact]) & (telemetry.normal_force_true > 0.0)
    if not rows.any():
        return 0.0
    tool_z = matrix_from_quaternion(telemetry.tool_orientation[rows])[:, :, 2]
    centres = telemetry.tool_position[rows] - tool_radius_m * tool_z
    cone = normal_cones_at(centres, truth.kuleuven_object.crease, where)
    across = angles_about_crease(telemetry.contact_normal[rows], cone.inward_a, cone.inward_b)
    tolerance = math.radians(ON_FACE_DEG)
    return float(np.mean((across < tolerance) | (across > cone.openings_rad - tolerance)))


def _inflated_equations(vertices: NDArray[np.float64], margin_m: float) -> NDArray[np.float64]:
    """The faces (F, 4) ``n·x + d <= 0`` of the convex hull of ``vertices`` moved ``margin_m`` outward."""
    equations = ConvexHull(vertices).equations.copy()
    equations[:, 3] -= margin_m
    return equations


def convex_union_ray_hits(
    origins: NDArray[np.float64], directions: NDArray[np.float64], pieces: list[NDArray[np.float64]]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Where the rays ``origins + s directions`` (R, 3 each, unit directions, s >= 0) first enter the union of convex
    ``pieces`` (each (F, 4) face equations, :func:`_inflated_equations`): the points (R, 3), the outward normals of
    the faces entered (R, 3) and which rays hit (R,); NaN where none does."""
    entry = np.full(len(origins), np.inf)
    normals = np.full((len(origins), 3), np.nan)
    for equations in pieces:
        facing = directions @ equations[:, :3].T  # (R, F): < 0 the ray enters through that face, > 0 it leaves
        height = origins @ equations[:, :3].T + equations[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            crossing = -height / facing
        enter = np.where(facing < 0.0, crossing, -np.inf)
        leave = np.where(facing > 0.0, crossing, np.inf)
        parallel_outside = np.any((facing == 0.0) & (height > 0.0), axis=1)
        s_in, s_out = enter.max(axis=1), leave.min(axis=1)
        hit = (s_in <= s_out) & (s_in >= 0.0) & ~parallel_outside & (s_in < entry)
        entry[hit] = s_in[hit]
        normals[hit] = equations[np.argmax(enter[hit], axis=1), :3]
    found = np.isfinite(entry)
    points = np.where(found[:, None], origins + np.where(found, entry, np.nan)[:, None] * directions, np.nan)
    return points, normals, found


def surface_gap(
    work_piece: str,
    world: ExecutionWorld,
    truth: KuleuvenGroundTruth,
    placement: Placement,
    margin_m: float = CONVEX_MARGIN_M,
) -> SurfaceGap:
    """How far the surface of ``world``'s work piece (its pieces' faces out by ``margin_m``: the collision surface)
    lies from the recording's object placed by ``placement``, along and across the placed skill's contact path (see
    :class:`SurfaceGap`)."""
    pieces = [_inflated_equations(np.asarray(p.vertices, dtype=float), margin_m) for p in world.config.work_pieces]
    path = skill_tool_path(world.skill, PATH_STEP_S)
    points, z = path.positions[path.contact], path.cf_z[path.contact]
    across = np.cross(z, np.gradient(points, axis=0))
    length = np.linalg.norm(across, axis=1)
    moving = length > 1e-9  # where the tool stands still there is no "across"
    points, z, across = points[moving], z[moving], across[moving] / length[moving, None]
    offsets = np.linspace(-BAND_HALF_WIDTH_M, BAND_HALF_WIDTH_M, BAND_RAYS)
    origins = (points[:, None] + offsets[None, :, None] * across[:, None] - RAY_CLEARANCE_M * z[:, None]).reshape(-1, 3)
    hits, normals, found = convex_union_ray_hits(origins, np.repeat(z, BAND_RAYS, axis=0), pieces)
    mesh = placed_mesh(truth, placement)
    nearest = closest_points_on_mesh(hits[found], mesh)
    band_normal = np.arccos(np.clip(np.sum(normals[found] * nearest.normals, axis=1), -1.0, 1.0))
    line = found.reshape(-1, BAND_RAYS)[:, BAND_RAYS // 2]
    line_hits = hits.reshape(-1, BAND_RAYS, 3)[line, BAND_RAYS // 2]
    line_inward = -normals.reshape(-1, BAND_RAYS, 3)[line, BAND_RAYS // 2]
    cone = normal_cones_at(line_hits, truth.kuleuven_object.crease, placed_object(truth, placement))
    return SurfaceGap(
        work_piece=work_piece,
        line_distance_m=closest_points_on_mesh(line_hits, mesh).distances,
        line_outside_cone_rad=angle_outside_cone(line_inward, cone.inward_a, cone.inward_b),
        line_from_bisector_rad=np.arccos(np.clip(np.sum(line_inward * cone.bisectors, axis=1), -1.0, 1.0)),
        band_distance_m=nearest.distances,
        band_normal_rad=band_normal,
    )


def stl_fit(truth: KuleuvenGroundTruth, samples: int = STL_FIT_SAMPLES, seed: int = 0) -> tuple[NDArray, NDArray]:
    """How closely the CAD pieces (`sim_worker.cad_work_piece.crease_pieces`, as PyBullet holds them: faces out by
    the margin) hold the STL's faces on both sides of the crease: for ``samples`` points spread evenly over those
    faces (CAD frame), their distance from the crease (m) and their signed distance from the pieces' surface (m,
    negative inside: the smallest over the pieces of the height above a piece's highest face plane, exact over a face,
    an underestimate by an edge)."""
    contour = truth.kuleuven_object
    mesh = contour.mesh
    corners = mesh.vertices[mesh.faces[np.concatenate(crease_side_faces(mesh, contour.crease))]]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    chosen = corners[rng.choice(len(corners), samples, p=areas / areas.sum())]
    u, v = rng.random((2, samples))
    flip = u + v > 1.0
    u, v = np.where(flip, 1.0 - u, u), np.where(flip, 1.0 - v, v)
    points = chosen[:, 0] + u[:, None] * (chosen[:, 1] - chosen[:, 0]) + v[:, None] * (chosen[:, 2] - chosen[:, 0])
    signed = np.full(samples, np.inf)
    for vertices, _ in crease_pieces(mesh, contour.crease):
        # Only the points by the piece: a farther piece is not the nearest surface (a point lies on the faces).
        reach = STL_FIT_REACH_M + CONVEX_MARGIN_M
        by = np.flatnonzero(
            np.all((points >= vertices.min(axis=0) - reach) & (points <= vertices.max(axis=0) + reach), axis=1)
        )
        equations = _inflated_equations(vertices, CONVEX_MARGIN_M)
        heights = np.max(points[by] @ equations[:, :3].T + equations[:, 3], axis=1)
        signed[by] = np.minimum(signed[by], heights)
    return closest_points_on_polyline(points, contour.crease.points).distances, signed


def kuleuven_cad_trial(
    recording: Path, cad_stiffnesses: tuple[float | None, ...] = CAD_STIFFNESSES_N_PER_M
) -> CadTrial:
    """Learn, place and execute one KU Leuven recording's skill on its work pieces and on the CAD (see the module),
    there once per CF x-y stiffness of ``cad_stiffnesses`` (N/m; None: the default gains')."""
    truth = kuleuven_ground_truth(recording)
    skill = learn_skill(truth.demonstration)
    settings = ExecutionSettings()
    default_stiffness = settings.gains.translational_stiffness_n_per_m[0]
    worlds = {"rebuilt": execution_world(skill, settings.environment)}
    measured = execution_world(skill, settings.environment, demonstration=truth.demonstration)
    if measured.source == "measured":
        worlds["measured"] = measured
    rebuilt = worlds["rebuilt"]
    placement = rebuilt.placement
    assert placement is not None  # a real recording carries no world: it is always placed
    runs = [CadRun(name, default_stiffness, run_skill(world, settings).metrics, None) for name, world in worlds.items()]
    cad = cad_world(truth, placement)
    where = placed_object(truth, placement)
    runs += cad_runs(rebuilt, truth, cad_stiffnesses)
    path = skill_tool_path(rebuilt.skill, PATH_STEP_S)
    crease = where.to_world(truth.kuleuven_object.crease.points)
    return CadTrial(
        trial=recording.stem,
        placement=placement,
        placement_reason=rebuilt.placement_reason,
        pieces=len(cad["work_pieces"]),
        path_to_crease_m=closest_points_on_polyline(path.positions[path.contact], crease).distances,
        runs=tuple(runs),
        gaps=tuple(surface_gap(name, world, truth, placement) for name, world in worlds.items()),
    )


def cad_runs(
    rebuilt: ExecutionWorld,
    truth: KuleuvenGroundTruth,
    cad_stiffnesses: tuple[float | None, ...] = CAD_STIFFNESSES_N_PER_M,
) -> list[CadRun]:
    """Execute a skill on the CAD of the object ``truth`` registered (the skill's demonstrations are in its recording's
    world), moved by the placement ``rebuilt`` (the skill's own resolved world) gave it: once per CF x-y stiffness of
    ``cad_stiffnesses`` (N/m; None: the default gains'), ``hybrid_cf`` and the wrist sensor."""
    settings = ExecutionSettings()
    placement = rebuilt.placement
    assert placement is not None  # a real recording carries no world: it is always placed
    cad = cad_world(truth, placement)
    where = placed_object(truth, placement)
    runs = []
    for stiffness in (settings.gains.translational_stiffness_n_per_m[0] if v is None else v for v in cad_stiffnesses):
        along_cf_z = settings.gains.translational_stiffness_n_per_m[2]
        gains = settings.gains.model_copy(
            update={"translational_stiffness_n_per_m": [stiffness, stiffness, along_cf_z]}
        )
        chosen = settings.model_copy(update={"gains": gains})
        resolved = execution_world(rebuilt.skill, chosen.environment, world=cad)
        result = run_skill(resolved, chosen)
        share = on_face_share(result.telemetry, where, truth, resolved.config.tool.radius_m)
        runs.append(CadRun("CAD", stiffness, result.metrics, share))
    return runs


def kuleuven_cad_trials(
    recordings: list[Path] | None = None, cad_stiffnesses: tuple[float | None, ...] = CAD_STIFFNESSES_N_PER_M
) -> list[CadTrial]:
    """:func:`kuleuven_cad_trial` of every KU Leuven recording (default: `services.datasets.kuleuven_recordings`):
    about 15 s each on one core."""
    return [kuleuven_cad_trial(path, cad_stiffnesses) for path in (recordings or kuleuven_recordings())]


def _mm(values: NDArray[np.float64]) -> str:
    """RMS / largest of distances (m), in mm."""
    return f"{1e3 * np.sqrt(np.mean(values**2)):.1f} / {1e3 * values.max():.1f}"


def _deg(values: NDArray[np.float64]) -> str:
    """Median / largest of angles (rad), in degrees."""
    return f"{np.degrees(np.median(values)):.1f} / {np.degrees(values.max()):.1f}"


def _verdict(m: ExecutionMetrics) -> str:
    """The verdict, its failed checks, and what it was judged on when that confirms the recording only."""
    if m.verdict is None:
        return "—"
    failed = sorted({c.name.value for c in m.verdict.checks if not c.passed and not c.warning_only})
    text = "pass" if not failed else "fail: " + ", ".join(failed)
    if any(c.name is VerdictCheckName.judged_on for c in m.verdict.checks):
        text += " (confirms the recording only)"
    return text


def execution_table(trials: list[CadTrial]) -> list[str]:
    """A markdown table of every execution of ``trials`` (one row each)."""
    lines = [
        "| trial | work piece | CF x-y stiffness (N/m) | final | true RMS (%) | true max (%) | CF-z RMS (%) | "
        "contact (%) | CF-normal angle (°) | ball on one face (%) | verdict |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for trial in trials:
        for run in trial.runs:
            m = run.metrics
            face = "—" if run.on_face is None else f"{100 * run.on_face:.1f}"
            lines.append(
                f"| {trial.trial} | {run.work_piece} | {run.lateral_stiffness_n_per_m:.0f} | {m.phase.value} | "
                f"{m.true_force_rms_error_pct:.2f} | {m.true_force_max_error_pct:.1f} | {m.force_rms_error_pct:.2f} | "
                f"{100 * m.contact_ratio:.2f} | {m.cf_normal_angle_deg:.1f} | {face} | {_verdict(m)} |"
            )
    return lines


def gap_table(trials: list[CadTrial]) -> list[str]:
    """A markdown table of every work piece's surface against the CAD (one row per trial and work piece)."""
    lines = [
        "| trial | work piece | along the path: from the CAD, RMS / max (mm) | its normal outside the crease's cone, "
        "median / max (°) | from the cone's bisector, median / max (°) | "
        f"±{1e3 * BAND_HALF_WIDTH_M:g} mm band: from the CAD, RMS / max (mm) | band: normal from the CAD face's, "
        "median / max (°) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for trial in trials:
        for gap in trial.gaps:
            line = (gap.line_distance_m, gap.line_outside_cone_rad, gap.line_from_bisector_rad)
            lines.append(
                f"| {trial.trial} | {gap.work_piece} | {_mm(line[0])} | {_deg(line[1])} | {_deg(line[2])} | "
                f"{_mm(gap.band_distance_m)} | {_deg(gap.band_normal_rad)} |"
            )
    return lines


def runs_of(trials: list[CadTrial], work_piece: str, stiffness: float | None = None) -> list[CadRun]:
    """The executions of ``trials`` on ``work_piece``, with the CF x-y ``stiffness`` (N/m) if given."""
    return [
        run
        for trial in trials
        for run in trial.runs
        if run.work_piece == work_piece and stiffness in (None, run.lateral_stiffness_n_per_m)
    ]


def _span(values: list[float], digits: int = 2) -> str:
    """The smallest and the largest of ``values``, as "a-b" (one number when they agree to ``digits``)."""
    low, high = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return low if low == high else f"{low}-{high}"


def cad_result_lines(trials: list[CadTrial] | None = None) -> list[str]:
    """Markdown lines for the KU Leuven section of docs/RESULTS.md: the skills on the true object beside their rebuilt
    work piece, and how far that surface lies from the CAD (:func:`kuleuven_cad_trials` unless ``trials`` given)."""
    trials = trials if trials is not None else kuleuven_cad_trials()
    default = ExecutionSettings().gains.translational_stiffness_n_per_m[0]
    rebuilt = runs_of(trials, "rebuilt")
    cad, stiff = runs_of(trials, "CAD", default), runs_of(trials, "CAD", LATERAL_STIFFNESS_N_PER_M)
    gaps = [gap for trial in trials for gap in trial.gaps if gap.work_piece == "rebuilt"]
    line = np.concatenate([gap.line_distance_m for gap in gaps])
    band_normal = np.concatenate([gap.band_normal_rad for gap in gaps])

    def true_rms(runs: list[CadRun]) -> str:
        return _span([run.metrics.true_force_rms_error_pct for run in runs])

    def on_face(runs: list[CadRun]) -> str:
        return _span([100 * run.on_face for run in runs if run.on_face is not None], 1)

    stiffer = f"{LATERAL_STIFFNESS_N_PER_M:.0f} N/m"
    path_spread = "; ".join(f"{trial.trial} {_mm(trial.path_to_crease_m)} mm" for trial in trials) + " (RMS / max)"
    return [
        "### Real recordings (KU Leuven), on the true object",
        "",
        "The object's CAD (`data/kuleuven_contour/contour.STL`), registered to each recording (`services/"
        "kuleuven_object.py`), moved by the placement the skill got, held as overlapping convex pieces "
        f"(`sim_worker/cad_work_piece.py`, {trials[0].pieces} pieces); each skill run with `hybrid_cf` and the wrist "
        f"sensor there, with the default CF x-y stiffness ({default:.0f} N/m) and with {stiffer}, beside its rebuilt "
        "work piece (`experiments/kuleuven_cad.py`). Ball on one face: share of the pressing steps whose true contact "
        f"normal lies within {ON_FACE_DEG:g}° of a face's normal (the ball rolled off the crease).",
        "",
        *execution_table(trials),
        "",
        f"True force RMS on the CAD: {true_rms(cad)} % with the default gains, {true_rms(stiff)} % with {stiffer}, "
        f"against {true_rms(rebuilt)} % on the rebuilt work piece; the ball pressed on one face for {on_face(cad)} % "
        f"of the contact with the default gains and {on_face(stiff)} % with {stiffer}. A ball on a convex crease "
        "rolls off unless the lateral stiffness exceeds force / radius (2000-2600 N/m for the 10 mm ball at the KU "
        "forces): the rebuilt strip, flat across the path, hides that. On the crease the contact normal points from "
        "the edge to the ball's centre, not along the learned CF z: it leans about 6° per millimetre the ball sits off "
        f"the line the CF z passes through, and the skill's path (the demonstration's) lies across the true crease by "
        f"{path_spread}. What must be modelled is that pair: the lateral spring K against the crease's negative "
        "stiffness F / r holds the ball K x_ref / (K - F / r) off the crease when its path lies x_ref off it, and the "
        "force along the leaning normal grows by 1 / cos of the lean; K at least 3 F / r keeps it within 10 % for "
        f"x_ref up to 2.7 mm ({stiffer} is 3 × the largest F / r, 33 N on the 10 mm ball). The default 3000 N/m is "
        "about F / r itself: the ball rolls onto a face.",
        "",
        *gap_table(trials),
        "",
        f"The rebuilt surface along the contact path lies {1e3 * np.sqrt(np.mean(line**2)):.1f} mm RMS (at most "
        f"{1e3 * line.max():.1f} mm) from the CAD; across the path it is flat where the object is a 90° crease: its "
        f"normal is a median {np.degrees(np.median(band_normal)):.0f}° from the CAD face's within "
        f"±{1e3 * BAND_HALF_WIDTH_M:g} mm of the path.",
    ]
