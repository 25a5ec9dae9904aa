"""Peer benchmark: skills.dmp against dfki-ric ``movement_primitives`` on the same pose trajectories.

Run from the repository root (the peer is installed ONLY for this benchmark, not a dependency)::

    .venv/bin/pip install movement-primitives pytransform3d
    .venv/bin/python benchmarks/bench_dmp_peer.py

For each trajectory (2000 samples over 4 s, starting and ending at rest) both libraries learn the
positions and the orientation with 50 basis functions per dimension and roll out with the
ORIGINAL start and goal at the demonstration's step (the peer's forcing term has no (g - y0)
scaling, ours is then s = 1). Reported: median fit and rollout wall time over repeats, the
RMS position error (mm) and RMS orientation angle (deg) of the reproduction against the demo.
Ours: ``DMP`` (3-D positions) + ``QuaternionDMP``; peer: ``CartesianDMP`` (positions + quaternion,
its default integration ``int_dt = 1 ms``; also at ``int_dt = dt``) and its position-only ``DMP``.

Prints a markdown table and writes it into docs/BENCHMARKS.md between the marker lines
``<!-- bench_dmp_peer:start -->`` and ``<!-- bench_dmp_peer:end -->`` (other sections are kept).
If the peer is missing or fails, that is said in the table and our numbers are still reported.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.report import machine_line, median_time, pin_blas_threads, write_section  # noqa: E402

pin_blas_threads()

import argparse  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Callable  # noqa: E402
from importlib.metadata import PackageNotFoundError, version  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from skills.dmp import DMP, QuaternionDMP  # noqa: E402
from skills.quaternions import quaternion_angle_between, quaternions_from_wxyz  # noqa: E402
from skills.synthetic import minimum_jerk, reach_pose_trajectory  # noqa: E402

N_SAMPLES = 2000
DURATION_S = 4.0
N_BASIS = 50
SECTION = "bench_dmp_peer"
COMMAND = ".venv/bin/python benchmarks/bench_dmp_peer.py"


# --------------------------------------------------------------------------- trajectories


def trajectory_reach() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reach of :func:`skills.synthetic.reach_pose_trajectory` at this module's size."""
    return reach_pose_trajectory(N_SAMPLES, DURATION_S)


def trajectory_wipe() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A wipe: 4 strokes of +-6 cm across a 20 cm advance on a plane, the tool tilting +-15 deg with the strokes."""
    t = np.linspace(0.0, DURATION_S, N_SAMPLES)
    s = t / DURATION_S
    mj = minimum_jerk(s)
    envelope = np.sin(np.pi * s) ** 2
    stroke = np.sin(8 * np.pi * mj) * envelope
    position = np.stack([0.5 + 0.2 * mj, 0.06 * stroke, 0.1 + 0.002 * envelope], axis=1)
    rotvec = np.stack([np.radians(15) * stroke, np.radians(10) * envelope, 0.3 * mj], axis=1)
    q = (Rotation.from_rotvec(rotvec) * Rotation.from_euler("xyz", [np.pi, 0.0, 0.0])).as_quat()
    return t, position, q


TRAJECTORIES: dict[str, Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]] = {
    "reach": trajectory_reach,
    "wipe": trajectory_wipe,
}


# --------------------------------------------------------------------------- measurement


def _errors(position: np.ndarray, q: np.ndarray, pos_out: np.ndarray | None, q_out: np.ndarray | None) -> tuple:
    pos_mm = None if pos_out is None else 1e3 * float(np.sqrt(np.mean(np.sum((pos_out - position) ** 2, axis=1))))
    ori_deg = None
    if q_out is not None:
        ori_deg = float(np.degrees(np.sqrt(np.mean(quaternion_angle_between(q_out, q) ** 2))))
    return pos_mm, ori_deg


def bench_ours(t, position, q, repeats: int) -> list[dict]:
    dt = float(t[1] - t[0])

    def fit_pose():
        return DMP.fit(t, position, n_basis=N_BASIS), QuaternionDMP.fit(t, q, n_basis=N_BASIS)

    fit_s, (pos_dmp, q_dmp) = median_time(fit_pose, repeats)
    roll_s, (pos_roll, q_roll) = median_time(lambda: (pos_dmp.rollout(dt), q_dmp.rollout(dt)), repeats)
    pos_mm, ori_deg = _errors(position, q, pos_roll.y, q_roll.q)
    rows = [dict(lib="ours", model="DMP + QuaternionDMP", fit=fit_s, roll=roll_s, pos=pos_mm, ori=ori_deg)]

    fit_p, dmp_p = median_time(lambda: DMP.fit(t, position, n_basis=N_BASIS), repeats)
    roll_p, out_p = median_time(lambda: dmp_p.rollout(dt), repeats)
    pos_only_mm = _errors(position, q, out_p.y, None)[0]
    rows.append(dict(lib="ours", model="DMP (positions only)", fit=fit_p, roll=roll_p, pos=pos_only_mm, ori=None))
    return rows


def bench_peer(t, position, q, repeats: int) -> list[dict]:
    from movement_primitives import dmp as peer

    dt = float(t[1] - t[0])
    duration = float(t[-1] - t[0])
    q_wxyz = np.concatenate([q[:, 3:4], q[:, :3]], axis=1)
    pose = np.hstack([position, q_wxyz])
    rows = []
    variants = ((0.001, "CartesianDMP (int_dt 1 ms, default)"), (dt, f"CartesianDMP (int_dt = dt = {dt * 1e3:.1f} ms)"))
    for int_dt, label in variants:

        def fit_pose(int_dt=int_dt):
            dmp = peer.CartesianDMP(execution_time=duration, dt=dt, n_weights_per_dim=N_BASIS, int_dt=int_dt)
            dmp.imitate(t, pose)
            return dmp

        fit_s, dmp = median_time(fit_pose, repeats)
        roll_s, (_, out) = median_time(dmp.open_loop, repeats)
        n = min(out.shape[0], N_SAMPLES)
        pos_mm, ori_deg = _errors(position[:n], q[:n], out[:n, :3], quaternions_from_wxyz(out[:n, 3:]))
        # The peer's samples lead its own time stamps by about one step: also score out[k] against demo[k + 1].
        pos_lead, ori_lead = _errors(position[1:n], q[1:n], out[: n - 1, :3], quaternions_from_wxyz(out[: n - 1, 3:]))
        rows.append(
            dict(
                lib="movement_primitives",
                model=label,
                fit=fit_s,
                roll=roll_s,
                pos=pos_mm,
                ori=ori_deg,
                pos_lead=pos_lead,
                ori_lead=ori_lead,
                n=out.shape[0],
            )
        )

    def fit_positions():
        dmp = peer.DMP(3, execution_time=duration, dt=dt, n_weights_per_dim=N_BASIS)
        dmp.imitate(t, position)
        return dmp

    fit_p, dmp_p = median_time(fit_positions, repeats)
    roll_p, (_, out_p) = median_time(dmp_p.open_loop, repeats)
    n = min(out_p.shape[0], N_SAMPLES)
    pos_mm = _errors(position[:n], q[:n], out_p[:n], None)[0]
    pos_lead = _errors(position[1:n], q[1:n], out_p[: n - 1], None)[0]
    rows.append(
        dict(
            lib="movement_primitives",
            model="DMP (positions only, int_dt 1 ms, rk4)",
            fit=fit_p,
            roll=roll_p,
            pos=pos_mm,
            ori=None,
            pos_lead=pos_lead,
            ori_lead=None,
            n=out_p.shape[0],
        )
    )
    return rows


# --------------------------------------------------------------------------- report


def _fmt(value: float | None, digits: int, lead: float | None = None) -> str:
    if value is None:
        return "–"
    return f"{value:.{digits}f}" + ("" if lead is None else f" ({lead:.{digits}f}†)")


def long_rollout_times(repeats: int) -> tuple[float, float]:
    """Median wall time (s) of our position and quaternion rollouts over 60 000 steps (the reach demo)."""
    t, position, q = trajectory_reach()
    pos_dmp, q_dmp = DMP.fit(t, position, n_basis=N_BASIS), QuaternionDMP.fit(t, q, n_basis=N_BASIS)
    dt = DURATION_S / 60_000
    n = max(3, repeats // 3)
    return median_time(lambda: pos_dmp.rollout(dt), n)[0], median_time(lambda: q_dmp.rollout(dt), n)[0]


def _peer_version() -> str:
    try:
        return version("movement-primitives")
    except PackageNotFoundError:
        return "not installed"


def build_report(repeats: int) -> str:
    lines = [
        "## DMP: skills.dmp vs movement_primitives (dfki-ric)",
        "",
        f"Reproduce: `{COMMAND}` (the peer is installed only for this: "
        "`.venv/bin/pip install movement-primitives pytransform3d`).",
        "",
        f"Same pose trajectories for both: {N_SAMPLES} samples over {DURATION_S:.0f} s (dt = "
        f"{DURATION_S / (N_SAMPLES - 1) * 1e3:.3f} ms), {N_BASIS} basis functions per dimension, rollout with the "
        f"ORIGINAL start and goal at the demo's step; errors against the demonstration. Median of {repeats} repeats. "
        "Fit = learning positions (+ orientation), rollout = integrating them.",
        "",
        "| trajectory | library | model | fit ms | rollout ms | position RMS mm | orientation RMS deg |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    notes: list[str] = []
    summary: list[str] = []
    extra_samples: set[int] = set()
    for name, make in TRAJECTORIES.items():
        t, position, q = make()
        rows = bench_ours(t, position, q, repeats)
        try:
            peer_rows = bench_peer(t, position, q, repeats)
        except Exception as exc:  # the peer is optional: say so clearly, keep our numbers
            peer_rows = []
            notes.append(f"PEER FAILED on `{name}`: {type(exc).__name__}: {exc}")
            traceback.print_exc()
        for row in rows + peer_rows:
            lines.append(
                f"| {name} | {row['lib']} | {row['model']} | {row['fit'] * 1e3:.2f} | {row['roll'] * 1e3:.2f} | "
                f"{_fmt(row['pos'], 4, row.get('pos_lead'))} | {_fmt(row['ori'], 4, row.get('ori_lead'))} |"
            )
            if row.get("n", N_SAMPLES) != N_SAMPLES:
                extra_samples.add(row["n"])
        if peer_rows:
            ours, peer = rows[0], peer_rows[0]
            best_pos = min(peer["pos"], peer["pos_lead"])
            best_ori = min(peer["ori"], peer["ori_lead"])
            accurate = ours["pos"] <= best_pos and ours["ori"] <= best_ori
            fast = peer["fit"] >= 5 * ours["fit"]
            ours_p, peer_p = rows[1], peer_rows[-1]
            summary.append(
                f"`{name}` vs the peer's default CartesianDMP: fit {peer['fit'] / ours['fit']:.1f}x faster, rollout "
                f"{peer['roll'] / ours['roll']:.1f}x faster; position RMS {ours['pos']:.4f} vs {best_pos:.4f} mm, "
                f"orientation RMS {ours['ori']:.5f} vs {best_ori:.4f} deg (peer at its better alignment). "
                f"Targets: at least as accurate {'MET' if accurate else 'NOT MET'}, >= 5x faster fit "
                f"{'MET' if fast else 'NOT MET'}. Positions only vs the peer's DMP: fit "
                f"{peer_p['fit'] / ours_p['fit']:.1f}x, rollout {peer_p['roll'] / ours_p['roll']:.1f}x faster."
            )
    lines.append("")
    lines.append(
        "† the peer scored with its rollout advanced by one sample (its sample k against the demo's k + 1): its "
        "samples lead its own time stamps by about one step, and this alignment fits it better. Without †: "
        "scored at its own time stamps."
    )
    lines.append("")
    lines.extend(f"- {s}" for s in summary)
    lines.extend(f"- {n}" for n in notes)
    if extra_samples:
        lines.append(
            f"- The peer's open_loop returns {sorted(extra_samples)} samples for {N_SAMPLES} demo samples "
            "(np.arange(0, T + dt, dt) overshoots); compared over the common samples."
        )
    long_pos, long_q = long_rollout_times(repeats)
    lines += [
        "- Why the accuracy differs: ours computes the forcing targets from the same semi-implicit Euler step used in "
        "rollout, so rollout at the demo's step reproduces the demo up to the basis-function fit; the peer takes "
        "targets from np.gradient (central difference) derivatives and integrates with another scheme (RK4 for "
        "positions, Euler sub-steps of int_dt for quaternions), so its reproduction has O(dt) error and runs about "
        "one step ahead of its time stamps.",
        f"- Rollout: ours evaluates the linear position/force DMP with one scipy.signal.lfilter call "
        f"({long_pos * 1e3:.1f} ms for 60 000 steps, 3-D); the quaternion DMP is a plain-float Python loop "
        f"({long_q / 60_000 * 1e6:.2f} µs per step over 60 000 steps, forcing-term evaluation included).",
        "",
        machine_line(f"movement-primitives {_peer_version()}"),
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="timing repeats (median reported)")
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "BENCHMARKS.md", help="markdown file to update")
    parser.add_argument("--no-write", action="store_true", help="only print the table")
    args = parser.parse_args(argv)
    try:
        import movement_primitives  # noqa: F401
    except ImportError as exc:
        print(f"PEER NOT AVAILABLE: movement_primitives cannot be imported ({exc}); reporting our numbers only.")
    report = build_report(args.repeats)
    print(report)
    if not args.no_write:
        write_section(SECTION, report, args.output)
        print(f"wrote section to {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
