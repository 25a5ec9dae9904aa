"""A torque-sensing arm's log of a fine simulation, as the held-out families (`corpus.holdout`) write it: the rows of a
~100 Hz log with jittered stamps and white noise, the arm's estimate of the applied force (a configuration-dependent
direction error, joint friction, the hand's push in free space, a constant offset), written as the CSV a user brings
(`corpus.arm_wipe.LWR_COLUMNS`: the wrench ON the robot, world frame).

World frame, z up, SI units (m, s, N, N·m, rad), quaternions scalar-last; the truth wrench is the one the tool APPLIES
(docs/CONVENTIONS.md).
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt, gaussian_filter1d
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from corpus.arm_wipe import (
    JOINT_FRICTION_SPEED_M_S,
    LWR_COLUMNS,
    LWR_JITTER_PERIODS,
    LWR_RATE_HZ,
    ArmEstimateRecording,
    friction_free_turn_deg,
)
from corpus.build import (
    TREMOR_FADE_S,
    Assembled,
    rotated,
)
from corpus.case import CorpusCase, sampled_case
from corpus.kinesthetic import OperatorModel, operator_forces
from corpus.recording import FINE_RATE_HZ
from corpus.synthetic import minimum_jerk
from skills.quaternions import matrix_from_quaternion, quaternions_slerp

FINE_DT = 1.0 / FINE_RATE_HZ
"""Step of the fine simulation, s."""


@dataclass(frozen=True)
class LogRows:
    """Where a torque-sensing arm's log takes its rows on a fine simulation: ``samples`` (M,) the fine samples of
    the truth's uniform times ``k / LWR_RATE_HZ``; ``stamps`` (M,) s the rows' jittered time stamps (±
    `LWR_JITTER_PERIODS` periods, the first and last exact); ``noise`` (M, 6) the rows' white noise (N, N·m);
    ``seen`` (M, 3) N the force noise as a reader sees it on the uniform grid (interpolated between the stamps)."""

    samples: NDArray[np.int_]
    stamps: NDArray[np.float64]
    noise: NDArray[np.float64]
    seen: NDArray[np.float64]


def log_rows(fine: Assembled, noise_n: float, rng: np.random.Generator) -> LogRows:
    """The rows of a ~100 Hz arm log of ``fine`` with white noise of ``noise_n`` N on the forces, 0.05 N·m on the
    moments (as `corpus.arm_wipe.lwr_wipe_case` takes them)."""
    samples = np.arange(0, fine.t.size, round(FINE_RATE_HZ / LWR_RATE_HZ))
    stamps = fine.t[samples] + rng.uniform(-LWR_JITTER_PERIODS, LWR_JITTER_PERIODS, samples.size) / LWR_RATE_HZ
    stamps[[0, -1]] = fine.t[samples[[0, -1]]]
    noise = rng.normal(0.0, noise_n, (samples.size, 6)) * np.repeat([1.0, 0.05 / noise_n], 3)
    seen = np.stack([np.interp(fine.t[samples], stamps, column) for column in noise[:, :3].T], axis=1)
    return LogRows(samples, stamps, noise, seen)


def tool_velocity(fine: Assembled) -> NDArray[np.float64]:
    """The tool point's velocity (N, 3) m/s on the fine grid, its positions smoothed over 5 ms (the hand's tremor
    kept, the grid's steps not)."""
    smoothed = gaussian_filter1d(fine.positions, 0.005 / FINE_DT, axis=0, mode="nearest")
    return np.gradient(smoothed, FINE_DT, axis=0)


def _joint_friction(fine: Assembled, joint_friction_n: float) -> NDArray[np.float64]:
    """The arm's unmodelled joint friction as its estimate reads it in applied-by-tool terms (N, 3) N, world: along
    the tool point's motion, ``joint_friction_n`` faded in over `JOINT_FRICTION_SPEED_M_S` (joint friction opposes
    the joints' motion: a force on the robot against the motion, which the estimate reads as the tool applying it
    along it; as `corpus.arm_wipe.lwr_wipe_case` has it)."""
    velocity = tool_velocity(fine)
    speed = np.linalg.norm(velocity, axis=1, keepdims=True)
    return joint_friction_n * np.tanh(speed / JOINT_FRICTION_SPEED_M_S) * velocity / np.maximum(speed, 1e-9)


def _free_space_hand(fine: Assembled, flange: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
    """The hand's push on the arm that the estimate sees in free space only (N, 3) N, applied-by-tool terms, world,
    as `corpus.arm_wipe.lwr_wipe_case` has it: `corpus.kinesthetic.operator_forces` of the flange's path (mass
    2-4 kg, damping 10-20 N·s/m, wander 1.5-3 N), weighted 0 in contact rising to 1 over
    `corpus.build.TREMOR_FADE_S` away from it (no step at a touch-down or a lift-off)."""
    operator = OperatorModel(rng.uniform(2.0, 4.0), rng.uniform(10.0, 20.0), rng.uniform(1.5, 3.0))
    away = minimum_jerk(distance_transform_edt(~fine.touching) * FINE_DT / TREMOR_FADE_S)
    return operator_forces(fine.t, flange, operator, rng) * away[:, None]


def _turned(vectors: NDArray, axis: NDArray, angles: NDArray) -> NDArray[np.float64]:
    """``vectors`` (N, 3) each turned by its ``angles`` (N,) rad about the unit ``axis`` (3,)."""
    return Rotation.from_rotvec(np.outer(angles, axis)).apply(vectors)


@dataclass(frozen=True)
class DirectionError:
    """A configuration-dependent direction error: the estimate's force is the applied one turned about the unit
    ``axis`` (world) by ``constant_rad + gain_rad_m * (p - origin) · gradient`` (rad), p the tool point (m), the
    ``gradient`` a unit world direction."""

    axis: NDArray[np.float64]
    gradient: NDArray[np.float64]
    origin: NDArray[np.float64]
    constant_rad: float
    gain_rad_m: float

    def angles(self, positions: NDArray) -> NDArray[np.float64]:
        """The turn (N,) rad at the tool points ``positions`` (N, 3) m."""
        return self.constant_rad + self.gain_rad_m * ((positions - self.origin) @ self.gradient)

    def parameters(self) -> dict[str, float]:
        """The error as ``parameters`` entries, named as `corpus.arm_wipe.lwr_wipe_case` names them."""
        params = {"direction_gradient_rad_m": self.gain_rad_m}
        for name, vector in (("axis", self.axis), ("gradient", self.gradient), ("origin", self.origin)):
            params |= {f"direction_{name}_{x}": float(v) for x, v in zip("xyz", vector, strict=True)}
        return params


def _scaled_error(
    error: DirectionError,
    t: NDArray,
    tip: NDArray,
    force: NDArray,
    extra: NDArray,
    runs: list[slice],
    target_deg: float,
) -> DirectionError:
    """``error`` with its gain (rad/m) set so that the friction-free turn (`friction_free_turn_deg`, over each run of
    ``runs``) of the turned ``force`` (N, 3) N plus ``extra`` (N, 3) N is ``target_deg`` midway between the least
    and the most run; ``t`` (N,) s and ``tip`` (N, 3) m the tool point's samples. Scaled on what the file shows (the
    joint friction and the noise a reader sees are in ``extra``), as `corpus.arm_wipe.lwr_wipe_case` scales
    its error."""

    def missing(gain: float) -> float:
        turned = _turned(force, error.axis, replace(error, gain_rad_m=gain).angles(tip)) + extra
        turns = [friction_free_turn_deg(t, tip, turned, run) for run in runs]
        return 0.5 * (min(turns) + max(turns)) - target_deg

    high = 5.0
    while missing(high) < 0.0:
        high *= 2.0
    return replace(error, gain_rad_m=float(brentq(missing, 0.0, high, xtol=1e-4)))


def _log_text(stamps: NDArray, fine: Assembled, path: NDArray, on_robot: NDArray) -> str:
    """The CSV text (`corpus.arm_wipe.LWR_COLUMNS`) of an arm's log: at ``stamps`` (s) the position ``path``
    (N, 3) m (the flange's, or the tool point's) and the tool's orientation of ``fine`` (both on its grid), and
    ``on_robot`` (one (6,) row per stamp: the estimated wrench ON the robot, world, N and N·m)."""
    position = np.stack([np.interp(stamps, fine.t, column) for column in path.T], axis=1)
    table = np.column_stack([stamps, position, quaternions_slerp(stamps, fine.t, fine.orientations), on_robot])
    text = io.StringIO()
    np.savetxt(text, table, fmt=["%.6f"] + ["%.7g"] * 13, delimiter=",", header=",".join(LWR_COLUMNS), comments="")
    return text.getvalue()


@dataclass(frozen=True)
class _Log:
    """An arm's log written: its ``csv_text``, its ``offset`` (6,) as the file reads it (world, on the robot, N; no
    moment offset), ``at_path`` (N, 6) the true applied wrench referred to the file's point (the force, and its
    moment about that point; fine grid)."""

    csv_text: str
    offset: NDArray[np.float64]
    at_path: NDArray[np.float64]


def written_log(
    fine: Assembled, rows: LogRows, path: NDArray, force: NDArray, offset_n: float, rng: np.random.Generator
) -> _Log:
    """The log of an arm estimating, at the point ``path`` (N, 3) m (fine grid), the force ``force`` (N, 3) N
    (applied-by-tool terms, world, fine grid: the applied force and its errors) with the applied force's moment about
    that point (the true moment at the tool point is zero), written as the wrench ON the robot with a constant offset
    of ``offset_n`` N in a random world direction, at the ``rows``' stamps with their noise."""
    applied = fine.wrenches[:, :3]
    at_path = np.hstack([applied, np.cross(fine.positions - path, applied)])
    offset = rng.normal(size=3)
    offset *= offset_n / np.linalg.norm(offset)
    estimate = np.hstack([force, at_path[:, 3:]])
    on_robot = np.stack([np.interp(rows.stamps, fine.t, column) for column in (-estimate).T], axis=1) + rows.noise
    on_robot[:, :3] += offset
    return _Log(_log_text(rows.stamps, fine, path, on_robot), np.concatenate([offset, np.zeros(3)]), at_path)


def arm_options(name: str) -> dict[str, object]:
    """The import options that read an arm's log right: the reaction (on the robot), world frame, 100 Hz."""
    return {"wrench_convention": "measured-on-tool", "wrench_frame": "world", "rate_hz": LWR_RATE_HZ, "name": name}


def slide_case(
    name: str,
    family: str,
    fine: Assembled,
    samples: NDArray,
    params: dict[str, float],
    recording: ArmEstimateRecording,
) -> CorpusCase:
    """The slide `CorpusCase` of ``fine`` at its ``samples`` (the truth at the tool point), recorded as
    ``recording``; one truth segment per contact (`corpus.case.truth_segments`, found on the fine grid)."""
    return sampled_case(name, family, "slide", fine, samples, params, recording)


def arm_estimate_case(
    name: str,
    family: str,
    fine: Assembled,
    params: dict[str, float],
    rng: np.random.Generator,
    error: DirectionError,
    runs: Callable[[NDArray, NDArray], list[slice]],
) -> CorpusCase:
    """``fine`` recorded by a torque-sensing arm's log as `corpus.arm_wipe.lwr_wipe_case` records its wipe: the
    flange ``params['flange_offset_m']`` behind the tool point along tool z; the estimate the applied force turned
    by ``error`` (its gain scaled so that the friction-free force turns ``params['direction_turn_deg']`` over the
    ``runs(t, tip)`` of the truth's samples, midway between the least and the most), plus the joint friction, the
    hand's push in free space, the offset and the noise. Adds the error's ``parameters``."""
    lever = params["flange_offset_m"] * matrix_from_quaternion(fine.orientations)[:, :, 2]
    flange = fine.positions - lever
    joint_friction = _joint_friction(fine, params["joint_friction_n"])
    hand = _free_space_hand(fine, flange, rng)
    rows = log_rows(fine, params["noise_n"], rng)
    applied = fine.wrenches[:, :3]
    s = rows.samples
    t, tip = fine.t[s], fine.positions[s]
    extra = joint_friction[s] - rows.seen
    error = _scaled_error(error, t, tip, applied[s], extra, runs(t, tip), params["direction_turn_deg"])
    params |= error.parameters()
    direction_errors = _turned(applied, error.axis, error.angles(fine.positions)) - applied
    log = written_log(fine, rows, flange, applied + direction_errors + joint_friction + hand, params["offset_n"], rng)
    recording = ArmEstimateRecording(
        csv_text=log.csv_text,
        import_options=arm_options(name),
        sensor_offset=log.offset,
        hand_forces=hand[s],
        flange_positions=flange[s],
        flange_wrenches=log.at_path[s],
        direction_errors=direction_errors[s],
        joint_friction=joint_friction[s],
    )
    return slide_case(name, family, fine, s, params, recording)


def in_plane_error(
    origin: NDArray, e_u: NDArray, out: NDArray, axis_deg: float, gradient_deg: float, constant_deg: float
) -> DirectionError:
    """A direction error (gain still 0) about the in-plane axis ``e_u`` turned by ``axis_deg`` (deg) round ``out``
    (the plane's outward normal), linear along ``e_u`` turned by ``gradient_deg``, from ``origin``."""
    return DirectionError(
        axis=rotated(e_u, out, np.radians(axis_deg)),
        gradient=rotated(e_u, out, np.radians(gradient_deg)),
        origin=origin,
        constant_rad=float(np.radians(constant_deg)),
        gain_rad_m=0.0,
    )


# --------------------------------------------------------------------------- the families
