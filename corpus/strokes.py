"""The strokes the corpus's families are made of: paths on a plane and across a cylinder, their presses, and the
analytic assembly (approach, contact, retreat; an ideal sensor) with the parameters every analytic family draws.

World frame, z up, SI units (m, s, N, rad; angles in the docs in deg), quaternions scalar-last; the wrench is the one
the tool APPLIES (docs/CONVENTIONS.md). The families (`corpus.families`, `corpus.press_and_path`,
`corpus.force_sources`, `corpus.holdout`) draw their contacts from these, seeded by the generator they pass.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from corpus.build import (
    UP,
    Fold,
    Piece,
    approach,
    assemble,
    circle_path,
    contact_piece,
    heading_path,
    retreat,
    rotated,
    speed_profile,
    timed,
)
from corpus.case import CorpusCase, analytic_case

PLANE_SHAPES = (
    "straight",
    "straight-soft",
    "l-shape",
    "zigzag",
    "circle",
    "spiral",
    "multi-pass-circle",
    "back-and-forth",
)
"""Path shapes on a plane (`plane_case`)."""
ANALYTIC_RATE_HZ = 500.0
"""Sampling rate of the analytic cases, Hz."""
BACK_AND_FORTH_PHASE = 0.1
"""A back-and-forth path touches down and lifts off this fraction of a pass from a turning point."""


def _draw(value: float | None, lo: float, hi: float, rng: np.random.Generator) -> float:
    """``value``, or a uniform draw in [lo, hi] when it is None."""
    return float(rng.uniform(lo, hi)) if value is None else float(value)


# --------------------------------------------------------------------------- paths on a plane


def plane_chart(shape: str, rng: np.random.Generator, radius_m: float | None = None) -> tuple[NDArray, NDArray, tuple]:
    """Chart path of a plane ``shape`` (param (K,), points (K, 2) m from the origin) and its corners
    ``(s_centre m, slow-down factor, width m)`` (see `corpus.build.speed_profile`)."""
    if shape in ("straight", "straight-soft"):
        s, xy = heading_path([0.0], [0.15], 0.02)
        return s, xy, ()
    if shape == "l-shape":
        s, xy = heading_path([0.0, rng.choice([-1.0, 1.0]) * np.pi / 2], [0.12, 0.12], 0.03)
        return s, xy, ((0.12, 0.35, 0.015),)
    if shape == "zigzag":
        legs, angle = int(rng.integers(4, 7)), np.radians(rng.uniform(30.0, 40.0))
        leg = 0.2 / (legs * np.cos(angle))
        s, xy = heading_path(angle * (-1.0) ** np.arange(legs), [leg] * legs, 0.02)
        return s, xy, tuple((leg * (k + 1), 0.5, 0.012) for k in range(legs - 1))
    if shape == "circle":
        radius = _draw(radius_m, 0.04, 0.06, rng)
        return *circle_path(lambda a: np.full_like(a, radius), 1.05), ()
    if shape == "spiral":
        return *circle_path(lambda a: 0.02 + 0.05 * a / (5 * np.pi), 2.5), ()
    if shape == "multi-pass-circle":
        return *circle_path(lambda a: np.full_like(a, 0.05 if radius_m is None else radius_m), 3.0), ()
    raise ValueError(f"shape must be one of {PLANE_SHAPES}, got {shape!r}")


def back_and_forth(
    length_m: float, passes: int, pass_s: float, dt: float, rng: np.random.Generator
) -> tuple[NDArray, NDArray, NDArray]:
    """``passes`` passes along a line of ``length_m`` at step ``dt``: times (M,) s, chart points (M, 2) m and the
    turning times (s). A cosine in time: it turns at rest and touches down and lifts off at ~30 % of the top
    speed (`BACK_AND_FORTH_PHASE`); the passes drift sideways by a few mm."""
    u0 = BACK_AND_FORTH_PHASE
    t = np.arange(0.0, (passes - 2 * u0) * pass_s, dt)
    u = u0 + t / pass_s
    across = 0.003 * np.sin(np.pi * u / passes + rng.uniform(0, 2 * np.pi))
    xy = np.stack([0.5 * length_m * (1.0 - np.cos(np.pi * u)), across - across[0]], axis=1)
    return t, xy, (np.arange(1, passes) - u0) * pass_s


def plane_stroke(
    plane: Fold, shape: str, rng: np.random.Generator, dt: float, force_n: float, ramp_s: float, cruise: float,
    radius_m: float | None = None,
) -> Piece:  # fmt: skip
    """The contact of ``shape`` on ``plane`` sampled at ``dt``: touch-down and lift-off at 3-4 cm/s, ``cruise``
    (m/s) between (slower at corners), pressing ``force_n`` with ramps of ``ramp_s``."""
    if shape == "back-and-forth":
        t, xy, _ = back_and_forth(0.15, 3, 1.3, dt, rng)
    else:
        param, chart, corners = plane_chart(shape, rng, radius_m)
        speed = speed_profile(rng.uniform(0.03, 0.04), cruise, rng.uniform(0.03, 0.04), corners)
        t, p = timed(param, plane.points(chart[:, 0], chart[:, 1]), dt, speed)
        xy = np.stack([np.interp(p, param, chart[:, 0]), np.interp(p, param, chart[:, 1])], axis=1)
    return contact_piece(plane.points(xy[:, 0], xy[:, 1]), plane.inward(xy[:, 0]), t, force_n, ramp_s)


def _profile(t: NDArray, force_n: float) -> NDArray:
    """A contour's pressing profile (N) over a contact sampled at ``t``: 0.6 -> 1 -> 0.75 of ``force_n``."""
    return force_n * np.interp(t / t[-1], [0.0, 0.5, 1.0], [0.6, 1.0, 0.75])


def cylinder_stroke(
    radius_m: float, turn_rad: float, rng: np.random.Generator, dt: float, force_n: float, ramp_s: float, cruise: float
) -> Piece:
    """A contour across a horizontal cylinder (random yaw) over ``turn_rad`` of its top (±9 deg off centre),
    drifting 1 cm along the axis; touch-down and lift-off at up to 3-3.5 cm/s, ``cruise`` between; the
    profile 0.6 -> 1 -> 0.75 of ``force_n``."""
    axis = rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    across = np.cross(axis, UP)
    centre = np.array([0.5, rng.uniform(-0.1, 0.1), 0.1 - radius_m])
    start = rng.uniform(-0.15, 0.15) - 0.5 * turn_rad

    def surface(angle: NDArray) -> tuple[NDArray, NDArray]:
        out = np.sin(angle)[:, None] * across + np.cos(angle)[:, None] * UP
        drift = 0.01 * np.sin(np.pi * (angle - start) / turn_rad)[:, None] * axis
        return centre + radius_m * out + drift, -out

    angle = np.linspace(start, start + turn_rad, 20000)
    speed = speed_profile(min(cruise, 0.03), cruise, min(cruise, 0.035))
    t, a = timed(angle, surface(angle)[0], dt, speed)
    return contact_piece(*surface(a), t, _profile(t, force_n), ramp_s)


def _analytic(
    name: str, family: str, skill_type: str, contact: Piece, params: dict, rng: np.random.Generator
) -> CorpusCase:
    """Approach from 10 cm (1-1.5 s), ``contact``, retreat (1-1.5 s), at ``params['rate_hz']``; a person's
    tremor (``params['tremor_m']``, default 0.3 mm) and force wander (±10 %); sensor noise 0.2 N."""
    dt = 1.0 / params["rate_hz"]
    before, after = rng.uniform(1.0, 1.5, 2)
    pieces = [approach(contact, before, 0.1, dt), contact, retreat(contact, after, 0.1, dt)]
    tremor = params.setdefault("tremor_m", 3e-4)
    case = assemble(pieces, dt, rng, params["pad_stiffness_n_m"], params["friction"], tremor, 0.1)
    return analytic_case(name, family, skill_type, case, params, rng)


def _params(
    rng: np.random.Generator, force: tuple[float, float], friction: float | None, pad: float | None, rate_hz: float
) -> dict[str, float]:
    """Common parameters: plateau force (drawn in ``force`` N), friction (0.2-0.4), pad stiffness (1.5e4-3e4 N/m)."""
    return {
        "force_n": _draw(None, *force, rng),
        "friction": _draw(friction, 0.2, 0.4, rng),
        "pad_stiffness_n_m": _draw(pad, 1.5e4, 3e4, rng),
        "rate_hz": rate_hz,
    }
