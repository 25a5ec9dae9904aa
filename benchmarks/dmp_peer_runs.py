"""The measurements of the peer benchmark (`benchmarks/bench_dmp_peer.py`): its pose trajectories, the scores, both
libraries' fits and rollouts (ours: `skills.dmp.DMP` + `skills.quaternion_dmp.QuaternionDMP`; the peer: dfki-ric
``movement_primitives``, imported only inside the functions that call it), and the three comparisons it reports
(accuracy, time, noise). Positions in m (errors in mm), orientations as scalar-last quaternions (errors in deg),
times in s.

Imported by the benchmark script after it pins the BLAS threads (`benchmarks.report.pin_blas_threads`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from benchmarks.report import median_time
from corpus.synthetic import minimum_jerk, reach_pose_trajectory
from schemas.skill import LearnOptions
from skills.dmp import BASIS_OVERLAP, DMP
from skills.quaternion_dmp import QuaternionDMP
from skills.quaternions import quaternion_angle_between, quaternions_from_wxyz

N_SAMPLES = 2000
DURATION_S = 4.0
LONG_DURATION_S = 20.0
N_BASIS = 50
FINE = 4
"""The finer rollout step is dt / FINE."""
NOISE_MM = (0.01, 0.1)
NOISE_SEEDS = 5
LONG_REPEATS_MIN = 3
"""The long trajectory's timings take a third of the repeats, at least this many (at most the repeats asked)."""


# --------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class Trajectory:
    name: str
    t: np.ndarray
    position: np.ndarray
    q: np.ndarray
    """Unit quaternions, scalar-last [x, y, z, w]."""
    n_basis: int
    timed: bool = True
    """Whether its fit and rollout are timed (the 20 s wipe only with learn_skill's basis count)."""

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def short(self) -> bool:
        return self.duration <= DURATION_S + 1e-9


def wipe(duration_s: float, n_samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A wipe: strokes of +-6 cm (one per second) across a 20 cm advance on a plane, the tool tilting +-15 deg
    with the strokes."""
    t = np.linspace(0.0, duration_s, n_samples)
    s = t / duration_s
    mj = minimum_jerk(s)
    envelope = np.sin(np.pi * s) ** 2
    stroke = np.sin(2 * np.pi * duration_s * mj) * envelope
    position = np.stack([0.5 + 0.2 * mj, 0.06 * stroke, 0.1 + 0.002 * envelope], axis=1)
    rotvec = np.stack([np.radians(15) * stroke, np.radians(10) * envelope, 0.3 * mj], axis=1)
    q = (Rotation.from_rotvec(rotvec) * Rotation.from_euler("xyz", [np.pi, 0.0, 0.0])).as_quat()
    return t, position, q


def learn_skill_basis_count(duration_s: float) -> int:
    """The basis count ``skills.parameterize`` gives a segment this long with the default ``LearnOptions``."""
    o = LearnOptions()
    return max(2, min(max(o.n_basis, math.ceil(o.basis_per_second * duration_s)), o.max_basis))


def trajectories() -> list[Trajectory]:
    long_n = round(LONG_DURATION_S / DURATION_S * (N_SAMPLES - 1)) + 1  # the same dt as the 4 s ones
    long_basis = learn_skill_basis_count(LONG_DURATION_S)
    return [
        Trajectory("reach 4 s", *reach_pose_trajectory(N_SAMPLES, DURATION_S), N_BASIS),
        Trajectory("wipe 4 s", *wipe(DURATION_S, N_SAMPLES), N_BASIS),
        Trajectory(f"wipe {LONG_DURATION_S:.0f} s", *wipe(LONG_DURATION_S, long_n), N_BASIS, timed=False),
        Trajectory(f"wipe {LONG_DURATION_S:.0f} s", *wipe(LONG_DURATION_S, long_n), long_basis),
    ]


# --------------------------------------------------------------------------- scoring


def position_rms_mm(out: np.ndarray, reference: np.ndarray) -> float:
    return 1e3 * float(np.sqrt(np.mean(np.sum((out - reference) ** 2, axis=1))))


def orientation_rms_deg(out: np.ndarray, reference: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(quaternion_angle_between(out, reference) ** 2))))


def at_demo_stamps(out: np.ndarray, every: int, n: int) -> np.ndarray:
    """Every ``every``-th rollout sample (those at the demonstration's stamps), at most ``n``."""
    return out[::every][:n]


# --------------------------------------------------------------------------- the two libraries


def fit_ours(tr: Trajectory) -> tuple[DMP, QuaternionDMP]:
    return DMP.fit(tr.t, tr.position, n_basis=tr.n_basis), QuaternionDMP.fit(tr.t, tr.q, n_basis=tr.n_basis)


def rollout_ours(models: tuple[DMP, QuaternionDMP], dt: float) -> tuple[np.ndarray, np.ndarray]:
    pos, quat = models
    return pos.rollout(dt).y, quat.rollout(dt).q


def ours_steps(tr: Trajectory, dt: float) -> int:
    return round(tr.duration / dt)


def set_overlap(forcing_term, overlap: float):
    """A copy of one of the peer's forcing terms with another basis overlap (same centres, widths from it)."""
    from movement_primitives.dmp._forcing_term import ForcingTerm

    ft = forcing_term
    return ForcingTerm(ft.weights_.shape[0], ft.n_weights_per_dim, ft.goal_t, ft.start_t, overlap, ft.alpha_z)


def peer_cartesian(tr: Trajectory, out_dt: float, int_dt: float | None = None, overlap: float | None = None):
    """The peer's CartesianDMP for ``tr`` (output step ``out_dt``; ``int_dt`` None: its default), fitted."""
    from movement_primitives import dmp as peer

    options = {} if int_dt is None else {"int_dt": int_dt}
    model = peer.CartesianDMP(execution_time=tr.duration, dt=out_dt, n_weights_per_dim=tr.n_basis, **options)
    if overlap is not None:
        model.forcing_term_pos = set_overlap(model.forcing_term_pos, overlap)
        model.forcing_term_rot = set_overlap(model.forcing_term_rot, overlap)
    q_wxyz = np.concatenate([tr.q[:, 3:4], tr.q[:, :3]], axis=1)
    model.imitate(tr.t, np.hstack([tr.position, q_wxyz]))
    return model


def peer_positions(t, position, n_basis: int, out_dt: float, int_dt: float | None = None, overlap=None):
    """The peer's position-only DMP, fitted."""
    from movement_primitives import dmp as peer

    options = {} if int_dt is None else {"int_dt": int_dt}
    duration = float(t[-1] - t[0])
    model = peer.DMP(3, execution_time=duration, dt=out_dt, n_weights_per_dim=n_basis, **options)
    if overlap is not None:
        model.forcing_term = set_overlap(model.forcing_term, overlap)
    model.imitate(t, position)
    return model


def peer_steps(n_out: int, out_dt: float, int_dt: float) -> int:
    """Integration steps of the peer's open loop: its loop of sub-steps of at most ``int_dt`` per output step."""
    current, sub = 0.0, 0
    while current < out_dt:
        current += min(int_dt, out_dt - current)
        sub += 1
    return (n_out - 1) * sub


def peer_default_overlap() -> float:
    from movement_primitives import dmp as peer

    return float(peer.CartesianDMP(execution_time=1.0, dt=0.01, n_weights_per_dim=10).forcing_term_pos.overlap)


def peer_step_functions() -> tuple[str, str]:
    """The peer's default position and quaternion step functions (what ``open_loop`` uses)."""
    from movement_primitives.dmp import _cartesian_dmp, _dmp

    return _dmp.DEFAULT_DMP_STEP_FUNCTION, _cartesian_dmp.DEFAULT_CARTESIAN_DMP_STEP_FUNCTION


def peer_default_int_dt() -> float:
    from movement_primitives import dmp as peer

    return float(peer.CartesianDMP(execution_time=1.0, dt=0.01, n_weights_per_dim=10).int_dt)


# --------------------------------------------------------------------------- 1. accuracy


def accuracy(tr: Trajectory, peer_ok: bool) -> list[dict]:
    n, dt, fine = len(tr.t), tr.dt, tr.dt / FINE
    ours = fit_ours(tr)
    pos, q = rollout_ours(ours, dt)
    pos_f, q_f = rollout_ours(ours, fine)
    pos_f, q_f = at_demo_stamps(pos_f, FINE, n), at_demo_stamps(q_f, FINE, n)
    rows = [
        dict(
            lib="ours",
            overlap=BASIS_OVERLAP,
            pos=position_rms_mm(pos, tr.position),
            ori=orientation_rms_deg(q, tr.q),
            pos_fine=position_rms_mm(pos_f, tr.position),
            ori_fine=orientation_rms_deg(q_f, tr.q),
            steps=ours_steps(tr, dt),
            steps_fine=ours_steps(tr, fine),
        )
    ]
    if not peer_ok:
        return rows
    for overlap in (None, BASIS_OVERLAP):
        model = peer_cartesian(tr, dt, overlap=overlap)
        _, out = model.open_loop()
        m = min(out.shape[0], n)
        p_out, q_out = out[:m, :3], quaternions_from_wxyz(out[:m, 3:])
        model_f = peer_cartesian(tr, fine, overlap=overlap)
        _, out_f_all = model_f.open_loop()
        out_f = at_demo_stamps(out_f_all, FINE, n)
        k = out_f.shape[0]
        rows.append(
            dict(
                lib="movement_primitives",
                overlap=model.forcing_term_pos.overlap,
                pos=position_rms_mm(p_out, tr.position[:m]),
                ori=orientation_rms_deg(q_out, tr.q[:m]),
                pos_lead=position_rms_mm(p_out[:-1], tr.position[1:m]),
                ori_lead=orientation_rms_deg(q_out[:-1], tr.q[1:m]),
                pos_fine=position_rms_mm(out_f[:, :3], tr.position[:k]),
                ori_fine=orientation_rms_deg(quaternions_from_wxyz(out_f[:, 3:]), tr.q[:k]),
                steps=peer_steps(out.shape[0], model.dt_, model.int_dt),
                steps_fine=peer_steps(out_f_all.shape[0], fine, model_f.int_dt),
                n_out=out.shape[0],
            )
        )
    return rows


# --------------------------------------------------------------------------- 2. time


def timing(tr: Trajectory, repeats: int, peer_ok: bool) -> list[dict]:
    dt = tr.dt
    fit_s, ours = median_time(lambda: fit_ours(tr), repeats)
    roll_s, _ = median_time(lambda: rollout_ours(ours, dt), repeats)
    rows = [dict(lib="ours", model="DMP + QuaternionDMP", steps=ours_steps(tr, dt), fit=fit_s, roll=roll_s)]
    fit_p, pos_only = median_time(lambda: DMP.fit(tr.t, tr.position, n_basis=tr.n_basis), repeats)
    roll_p, _ = median_time(lambda: pos_only.rollout(dt), repeats)
    rows.append(dict(lib="ours", model="DMP (positions)", steps=ours_steps(tr, dt), fit=fit_p, roll=roll_p))
    if not peer_ok:
        return rows
    default_int_dt = peer_default_int_dt()
    for int_dt, label in (
        (dt, "CartesianDMP, int_dt = dt (equal steps)"),
        (default_int_dt, f"CartesianDMP, int_dt {default_int_dt * 1e3:g} ms (default)"),
    ):
        fit_c, model = median_time(lambda int_dt=int_dt: peer_cartesian(tr, dt, int_dt=int_dt), repeats)
        roll_c, (_, out) = median_time(model.open_loop, repeats)
        steps = peer_steps(out.shape[0], dt, int_dt)
        rows.append(
            dict(lib="movement_primitives", model=label, steps=steps, fit=fit_c, roll=roll_c, equal=int_dt == dt)
        )
    fit_d, model_d = median_time(lambda: peer_positions(tr.t, tr.position, tr.n_basis, dt, int_dt=dt), repeats)
    roll_d, (_, out_d) = median_time(model_d.open_loop, repeats)
    rows.append(
        dict(
            lib="movement_primitives",
            model="DMP (positions), int_dt = dt (equal steps)",
            steps=peer_steps(out_d.shape[0], dt, dt),
            fit=fit_d,
            roll=roll_d,
        )
    )
    return rows


# --------------------------------------------------------------------------- 3. noise


def noise(tr: Trajectory, sigma_mm: float, peer_ok: bool, seeds: int = NOISE_SEEDS) -> dict[str, float]:
    """Median over ``seeds`` seeds of the position RMS error (mm) against the clean trajectory, rolled out at dt."""
    results: dict[str, list[float]] = {}
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        noisy = tr.position + rng.normal(0.0, sigma_mm * 1e-3, tr.position.shape)
        results.setdefault("noise", []).append(position_rms_mm(noisy, tr.position))
        ours = DMP.fit(tr.t, noisy, n_basis=tr.n_basis).rollout(tr.dt).y
        results.setdefault("ours", []).append(position_rms_mm(ours, tr.position))
        if not peer_ok:
            continue
        for key, overlap in (("peer", None), ("peer_equal", BASIS_OVERLAP)):
            _, out = peer_positions(tr.t, noisy, tr.n_basis, tr.dt, overlap=overlap).open_loop()
            m = min(out.shape[0], len(tr.t))
            results.setdefault(key, []).append(position_rms_mm(out[:m], tr.position[:m]))
    return {k: float(np.median(v)) for k, v in results.items()}


def long_repeats(repeats: int) -> int:
    """The timing repeats of the long trajectory when the short ones take ``repeats`` (:data:`LONG_REPEATS_MIN`)."""
    return min(repeats, max(LONG_REPEATS_MIN, repeats // 3))


def long_rollout_times(repeats: int) -> tuple[float, float]:
    """Median wall time (s) of our position and quaternion rollouts over 60 000 steps (the reach demo)."""
    t, position, q = reach_pose_trajectory(N_SAMPLES, DURATION_S)
    pos_dmp, q_dmp = DMP.fit(t, position, n_basis=N_BASIS), QuaternionDMP.fit(t, q, n_basis=N_BASIS)
    dt = DURATION_S / 60_000
    n = long_repeats(repeats)
    return median_time(lambda: pos_dmp.rollout(dt), n)[0], median_time(lambda: q_dmp.rollout(dt), n)[0]
