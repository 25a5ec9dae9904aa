"""The KU Leuven skills executed on the true object (the registered CAD), beside their rebuilt work piece.

Three parts, each computed here:

1. The collision geometry, on a case with a known answer: a straight 90° ridge (400 mm, 60 mm legs), the ball pressed
   15 N along its bisector while sliding 0.3 m along the crease at 0.1 m/s (``hybrid_cf``, the wrist sensor), on one
   exact convex prism and on the ridge cut into convex pieces (`sim_worker.cad_work_piece`) as the KU object is.
2. How closely the CAD pieces hold the STL's faces, by distance from the crease.
3. Every KU Leuven skill on its rebuilt (and measured) work piece and on the CAD, and how far those surfaces lie from
   the CAD (`experiments/kuleuven_cad.py`).

Writes its section of docs/BENCHMARKS.md.
"""

from __future__ import annotations

import itertools
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.report import pin_blas_threads, report_main, report_text

pin_blas_threads()

import numpy as np  # noqa: E402
from scipy.spatial import ConvexHull  # noqa: E402

from experiments.kuleuven_cad import (  # noqa: E402
    CAD_STIFFNESSES_N_PER_M,
    LATERAL_STIFFNESS_N_PER_M,
    ON_FACE_DEG,
    STL_FIT_SAMPLES,
    execution_table,
    gap_table,
    kuleuven_cad_trials,
    runs_of,
    stl_fit,
)
from schemas import Demonstration, ExecutionSettings  # noqa: E402
from schemas.world import WorldConfig  # noqa: E402
from services.datasets import kuleuven_recordings  # noqa: E402
from services.kuleuven_object import kuleuven_ground_truth  # noqa: E402
from sim_worker.cad_work_piece import (  # noqa: E402
    CAD_LAYERS,
    CAD_STATION_SPACING_M,
    CONVEX_MARGIN_M,
    cad_world_config,
    margin_shrunk_hull,
)
from sim_worker.execution_world import execution_world  # noqa: E402
from sim_worker.executor import run_skill  # noqa: E402
from skills.parameterize import learn_skill  # noqa: E402
from skills.quaternions import quaternion_from_matrix  # noqa: E402
from skills.registration import Crease, TriangleMesh, crease_along_edge, welded_mesh  # noqa: E402

SECTION = "kuleuven-cad"
COMMAND = ".venv/bin/python benchmarks/bench_kuleuven_cad.py"
RIDGE_APEX_M = np.array([0.55, 0.0, 0.15])
"""The middle of the straight ridge's crease (the robot's world, m): in front of the iiwa, at table height."""
RIDGE_HALF_LENGTH_M = 0.2
RIDGE_LEG_M = 0.06
RIDGE_SPEED_M_S = 0.1
RIDGE_STROKE_M = 0.3
RIDGE_FORCE_N = 15.0
RIDGE_FRICTION = 0.2
"""The friction coefficient of every tool contact in the simulator (the demonstration's drag along the stroke)."""
RIDGE_PIECES = ((0.005, 1), (0.0025, 4), (0.00125, 16), (CAD_STATION_SPACING_M, CAD_LAYERS))
"""(station spacing m, layers) of the pieces compared on the ridge; the last is what the KU object gets."""
STL_BANDS_M = (0.0, 0.002, 0.005, 0.015)
"""Distances from the crease (m) the pieces' fit to the STL is reported between."""


def ridge() -> tuple[TriangleMesh, Crease]:
    """A straight ridge along world y through :data:`RIDGE_APEX_M`: a prism whose cross-section is the right triangle
    with the apex up and legs of :data:`RIDGE_LEG_M` (its two faces at 45°), and its crease."""
    leg = RIDGE_LEG_M / np.sqrt(2.0)
    section = np.array([[0.0, 0.0, 0.0], [leg, 0.0, -leg], [-leg, 0.0, -leg]])  # apex, then the legs' ends
    vertices = np.vstack([RIDGE_APEX_M + section + [0.0, y, 0.0] for y in (-RIDGE_HALF_LENGTH_M, RIDGE_HALF_LENGTH_M)])
    hull = ConvexHull(vertices)
    corners = vertices[hull.simplices]
    inward = np.einsum("ij,ij->i", np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                       hull.equations[:, :3]) < 0.0  # fmt: skip
    corners[inward] = corners[inward][:, ::-1]
    mesh = welded_mesh(corners)
    return mesh, crease_along_edge(mesh, vertices[[0, 3]])


def ridge_demonstration(stroke_m: float = RIDGE_STROKE_M) -> Demonstration:
    """The tool point ``stroke_m`` (m) along the ridge's crease at :data:`RIDGE_SPEED_M_S`, still for 0.3 s at both
    ends, the tool pointing down with its x along the stroke, applying :data:`RIDGE_FORCE_N` down and the drag of
    friction."""
    dt = 0.005
    travel = np.arange(-0.5 * stroke_m, 0.5 * stroke_m, RIDGE_SPEED_M_S * dt)
    hold = round(0.3 / dt)
    y = np.concatenate([np.full(hold, travel[0]), travel, np.full(hold, travel[-1])])
    positions = RIDGE_APEX_M + np.column_stack([np.zeros_like(y), y, np.zeros_like(y)])
    wrenches = np.zeros((len(y), 6))
    wrenches[:, 1] = RIDGE_FRICTION * RIDGE_FORCE_N * (np.gradient(y) > 0.0)
    wrenches[:, 2] = -RIDGE_FORCE_N
    tool = quaternion_from_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]))  # x along y, z down
    return Demonstration(
        t=(np.arange(len(y)) * dt).tolist(),
        positions=positions.tolist(),
        orientations=[tool.tolist()] * len(y),
        wrenches=wrenches.tolist(),
        metadata={"name": "straight ridge"},
    )


def ridge_rows(layouts: int, stroke_m: float) -> list[dict]:
    """The ridge stroke of ``stroke_m`` (m) on one exact prism and on the last ``layouts`` of `RIDGE_PIECES` (see the
    module)."""
    mesh, crease = ridge()
    skill = learn_skill(ridge_demonstration(stroke_m))
    settings = ExecutionSettings()
    base = WorldConfig(table_enabled=False)
    worlds = {"one exact convex prism": base.replace(work_pieces=({"name": "prism", "vertices": margin_shrunk_hull(
        mesh.vertices).tolist()},))}  # fmt: skip
    for spacing, layers in RIDGE_PIECES[len(RIDGE_PIECES) - layouts :]:
        label = f"pieces {1e3 * spacing * layers:g} mm long, {1e3 * spacing:g} mm apart ({layers} layers)"
        worlds[label] = cad_world_config(mesh, crease, np.eye(3), np.zeros(3), base, spacing, layers)
    rows = []
    for label, config in worlds.items():
        result = run_skill(execution_world(skill, settings.environment, world=config.to_dict()), settings)
        m = result.metrics
        rows.append(
            {
                "geometry": label,
                "parts": len(config.work_pieces),
                "phase": m.phase.value,
                "true": m.true_force_rms_error_pct,
                "true_max": m.true_force_max_error_pct,
                "cf_z": m.force_rms_error_pct,
                "rtf": m.real_time_factor,
            }
        )
        print(f"ridge, {label}: true RMS {m.true_force_rms_error_pct:.2f} %", flush=True)
    return rows


def stl_rows(samples: int) -> list[tuple[float, float, float, float, float]]:
    """(from, to, RMS, most inside, most outside) of the CAD pieces' surface against the STL's faces at ``samples``
    points, per band of distance from the crease, m (the pieces' surface outside the STL face is negative)."""
    distance, signed = stl_fit(kuleuven_ground_truth(kuleuven_recordings()[0]), samples)
    rows = []
    for low, high in itertools.pairwise(STL_BANDS_M):
        band = signed[(distance >= low) & (distance < high)]
        rows.append((low, high, float(np.sqrt(np.mean(band**2))), float(band.min()), float(band.max())))
    return rows


def build_report(
    ridge_layouts: int, ridge_stroke_m: float, trials: int, cad_stiffnesses: list[float | None], stl_samples: int
) -> str:
    """The report over the last ``ridge_layouts`` ridge piece layouts (the last is the KU object's), with a ridge
    stroke of ``ridge_stroke_m`` (m), the CAD pieces' fit at ``stl_samples`` points, and the first ``trials`` KU
    Leuven recordings run on the CAD with each CF x-y stiffness of ``cad_stiffnesses`` (N/m; None: the default)."""
    started = time.perf_counter()
    ridges = ridge_rows(ridge_layouts, ridge_stroke_m)
    fit = stl_rows(stl_samples)
    trials = kuleuven_cad_trials(kuleuven_recordings()[:trials], tuple(cad_stiffnesses))
    elapsed = time.perf_counter() - started
    ridge_table = [
        "| geometry | convex parts | final | true RMS % | true max % | CF-z RMS % | real-time × |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *(
            f"| {r['geometry']} | {r['parts']} | {r['phase']} | {r['true']:.2f} | {r['true_max']:.1f} | "
            f"{r['cf_z']:.2f} | {r['rtf']:.1f} |"
            for r in ridges
        ),
    ]
    fit_table = [
        "| distance from the crease, mm | RMS, mm | STL face inside the pieces by at most, mm | outside by at most, "
        "mm |",
        "| --- | --- | --- | --- |",
        *(
            f"| {1e3 * a:g}-{1e3 * b:g} | {1e3 * rms:.2f} | {-1e3 * low:.2f} | {1e3 * high:.2f} |"
            for a, b, rms, low, high in fit
        ),
    ]
    default = ExecutionSettings().gains.translational_stiffness_n_per_m[0]

    def true_rms(work_piece: str, stiffness: float | None = None) -> str:
        values = [run.metrics.true_force_rms_error_pct for run in runs_of(trials, work_piece, stiffness)]
        if not values:  # a stiffness left out (--cad-stiffnesses)
            return "not run"
        return f"median {statistics.median(values):.2f} %, worst {max(values):.2f} %"

    exact = ridges[0]
    chosen = ridges[-1]
    sentences = [
        f"On the straight ridge one exact convex prism holds the force to {exact['true']:.2f} % RMS; the pieces the KU "
        f"object is built of ({chosen['geometry']}) to {chosen['true']:.2f} %: the seams between convex bodies "
        "(a second touching body, the force doubling there) cost that much once every piece is one of many layers.",
        f"True force RMS on the rebuilt work pieces {true_rms('rebuilt')}; on the CAD {true_rms('CAD', default)} with "
        f"the default CF x-y stiffness ({default:.0f} N/m) and {true_rms('CAD', LATERAL_STIFFNESS_N_PER_M)} with "
        f"{LATERAL_STIFFNESS_N_PER_M:.0f} N/m.",
        f"Ball on one face: the share of the contact phase's pressing steps whose true contact normal lies within "
        f"{ON_FACE_DEG:g}° of a face's normal (the ball rolled off the crease). A ball of radius r on a convex crease "
        "pressed with F rolls off unless the lateral stiffness exceeds F / r. On the crease the contact normal points "
        "from the edge to the ball's centre, not along the learned CF z: it leans about 6° per millimetre the ball "
        "sits off the line the CF z passes through, and the skill's path (the demonstration's) lies across the true "
        "crease by "
        + "; ".join(
            f"{t.trial} {1e3 * np.sqrt(np.mean(t.path_to_crease_m**2)):.1f} mm RMS, "
            f"{1e3 * t.path_to_crease_m.max():.1f} mm max"
            for t in trials
        )
        + f"; CF-normal angle with {LATERAL_STIFFNESS_N_PER_M:.0f} N/m: "
        + ", ".join(f"{r.metrics.cf_normal_angle_deg:.1f}°" for r in runs_of(trials, "CAD", LATERAL_STIFFNESS_N_PER_M))
        + ".",
        f"Placement of {trials[0].trial}: {trials[0].placement_reason}. The CAD pieces' faces are built "
        f"{1e3 * CONVEX_MARGIN_M:g} mm inside the STL's (PyBullet's convex margin inflates them back); the rebuilt "
        "and measured pieces are not, so PyBullet holds their surface that much proud of their vertices (included "
        f"in the distances above). Whole run {elapsed:.0f} s.",
    ]
    return report_text(
        [
            "## KU Leuven skills on the true object (the registered CAD)",
            "",
            f"Command: `{COMMAND}`. The object's CAD (`data/kuleuven_contour/contour.STL`) registered to each "
            "recording (`services/kuleuven_object.py`), moved with the skill's placement, held as overlapping convex "
            "pieces (`sim_worker/cad_work_piece.py`); the skills learned (`auto`) and run with `hybrid_cf` and the "
            "realistic wrist sensor (`experiments/kuleuven_cad.py`).",
            "",
            f"The collision geometry on a straight 90° ridge: the ball pressed {RIDGE_FORCE_N:g} N along the bisector, "
            f"sliding {1e3 * ridge_stroke_m:g} mm along the crease at {RIDGE_SPEED_M_S:g} m/s.",
            "",
            *ridge_table,
            "",
            "The CAD pieces against the STL's faces on both sides of the crease "
            f"({f'{stl_samples:,}'.replace(',', ' ')} points spread over them; signed distance from the pieces' "
            "surface as PyBullet holds it):",
            "",
            *fit_table,
            "",
            *execution_table(trials),
            "",
            *gap_table(trials),
            "",
            *sentences,
        ]
    )


OPTIONS = [
    ("--ridge-layouts", {"type": int, "default": len(RIDGE_PIECES), "help": "ridge piece layouts, from last"}),
    ("--ridge-stroke-m", {"type": float, "default": RIDGE_STROKE_M, "help": "ridge stroke length, m"}),
    ("--trials", {"type": int, "default": 4, "help": "KU Leuven recordings (the first N)"}),
    (
        "--cad-stiffnesses",
        {
            "type": float,
            "nargs": "+",
            "default": list(CAD_STIFFNESSES_N_PER_M),
            "help": "CF x-y N/m on the CAD",
        },
    ),
    ("--stl-samples", {"type": int, "default": STL_FIT_SAMPLES, "help": "points of the CAD pieces' fit"}),
]
"""The options of the command line (`benchmarks.report.report_main`): a flag and its ``argparse`` keywords."""
SMOKE = {
    "ridge_layouts": 1,
    "ridge_stroke_m": 0.05,
    "trials": 1,
    "cad_stiffnesses": [LATERAL_STIFFNESS_N_PER_M],
    "stl_samples": STL_FIT_SAMPLES // 10,
}
"""The smoke run's values of the options: every part once. One stiffness on the CAD (an execution there is the run's
dearest, its pieces make every step several times dearer; the other stiffness runs the same code), a tenth of the
fit's points (the same bands, the same code)."""


def main(argv: list[str] | None = None) -> int:
    return report_main(__doc__.splitlines()[0], SECTION, build_report, argv, options=OPTIONS, smoke=SMOKE)


if __name__ == "__main__":
    raise SystemExit(main())
