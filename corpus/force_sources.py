"""Force sources real users record with, as corpus families: each case is the FILE a user brings, with its truth.

World frame, z up, SI units (m, s, N, N·m, rad; angles in the docs in deg), quaternions scalar-last in the arrays;
the truth wrench is the one the tool APPLIES, world frame, at the tool point (the contact point); normals point INTO
the surface (docs/CONVENTIONS.md). Every family is a function of a seed returning a `corpus.case.CorpusCase` built
from `corpus.build` (pieces, `assemble`) with its truth as the other families carry it (positions = the tool point,
the true applied wrench, contact, normals, normal force, `corpus.case.truth_segments`, ``parameters``):

- **A torque-sensing arm** (`corpus.arm_wipe.lwr_wipe_case`, slide; ``lwr-wipe-patch``, ``lwr-wipe-strip``): a
  person guides a KUKA LWR / iiwa or a Franka by hand and wipes a flat part; the file is the arm's own log (its
  module says what it holds).
  0.4-0.6 kg tool on a wrist sensor that does not compensate its weight: 7-10 N zig-zags (4-6 legs at ±30-40 deg
  over 20 cm, 6-9 cm/s) on a slope of 30-40 deg, the sensor at 100, 125, 200 or 250 Hz as in the human-like cases
  (`corpus.recording`: tool frame, the reaction, an offset of 0.7-2.3 N, noise 0.2 N, the hand's push). The sensor
  carries ``F_applied - m g`` (g = (0, 0, -9.81) m/s²: in free space the weight reads as m·9.81 N UP in applied
  terms) and the weight's moment about the tool point, ``c × (-m g)``. The sensor sits 0.12-0.18 m behind the tool
  point along tool z, the centre of mass 3-8 cm in front of the sensor (≤ 1 cm sideways). ``tool-weight``: two
  zig-zags 7 cm apart with a pause in the air between them and rests at the start and the end (1.2-1.5 s each), in
  which the hand holds the tool in three orientations ~25-40 deg apart (on a cone of 18-22 deg round the normal,
  plus the hand's wobble), so that a tare can separate the offset from the weight. ``tool-weight-no-free``: one
  zig-zag, the file cut to its contact (touch-down to lift-off, like the KU Leuven files). Columns and options as the
  human-like files (scalar-FIRST quaternion, the reaction in the tool frame).
- **A disc grinder** (`grinder_case`, slide; ``grinder``): one straight pass of 15-20 cm at 2-5 cm/s on a table
  tilted 0-10 deg, press 10-20 N, friction 0.2-0.4, and the disc's cutting force: 0.28-0.33 N per N of press,
  fixed in the TOOL frame across tool z, taken into the table's plane, pointing across the pass (within 5 deg at the
  pass's middle; it turns with the hand's slow yaw): the friction-free applied force leans 14-19 deg off the table
  normal, across the pass. It is truly applied: it is in the truth. Wrist sensor at 250 Hz as the human-like cases,
  rests in the air at both ends, a hand's approach and retreat from 10-20 cm.
- **High friction** (`high_friction_cylinder_case`, contour; ``cylinder-high-friction``): a
  `corpus.families.cylinder_case` across a cylinder of radius 8-20 cm with friction 0.76-0.9, beyond the 0.7 up to
  which a lean is taken for friction (`skills.friction.FRICTION_CONE_MAX`); analytic like the other cylinders.

A case lasts 10-23 s (a strip wiped in two contacts the longest). `force_source_cases` yields every family once per
seed.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from corpus.arm_wipe import lwr_wipe_case
from corpus.build import (
    UP,
    Fold,
    assemble,
    contact_piece,
    heading_path,
    rotated,
    speed_profile,
    through_the_air,
    tilted_plane,
    timed,
)
from corpus.case import CorpusCase
from corpus.families import cylinder_case
from corpus.kinesthetic import OperatorModel
from corpus.recording import FINE_RATE_HZ, recorded_case
from corpus.strokes import plane_stroke
from skills.quaternions import matrix_from_quaternion

FORCE_SOURCE_FAMILIES = (
    "lwr-wipe-patch",
    "lwr-wipe-strip",
    "tool-weight",
    "tool-weight-no-free",
    "grinder",
    "cylinder-high-friction",
)
"""The families of this module, in the order `force_source_cases` yields them."""


GRAVITY = np.array([0.0, 0.0, -9.81])
"""Gravity, world, m/s²."""


# --------------------------------------------------------------------------- an uncompensated tool weight


def _rest_axes(normal: NDArray[np.float64], e_u: NDArray[np.float64], rng: np.random.Generator) -> list[NDArray]:
    """Three tool axes on a cone of 18-22 deg round ``normal`` (unit, world), 120 deg apart round it (a random
    phase from ``e_u``, a unit vector across ``normal``): 31-38 deg from each other."""
    cone, phase = np.radians(rng.uniform(18.0, 22.0)), rng.uniform(-np.pi, np.pi)
    return [rotated(normal, rotated(e_u, normal, phase + 2 * np.pi * k / 3), cone) for k in range(3)]


def tool_centre(rng: np.random.Generator, params: dict[str, float]) -> dict[str, float]:
    """The tool's centre of mass (``tool_com_x/y/z``, m, tool frame from the tool point): ``com_from_sensor_m``
    along tool z from the sensor, which sits ``sensor_to_tool_point_m`` behind the tool point, and up to 1 cm
    aside."""
    aside = rng.uniform(0.0, 0.01) * rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    com = aside + (params["com_from_sensor_m"] - params["sensor_to_tool_point_m"]) * UP
    return {f"tool_com_{x}": float(v) for x, v in zip("xyz", com, strict=True)}


def carried_weight(orientations: NDArray[np.float64], params: dict[str, float]) -> NDArray[np.float64]:
    """The wrench (N, 6) N and N·m, world, applied-by-tool terms, an uncompensated tool weight adds to what the sensor
    carries at world-from-tool ``orientations`` (N, 4): the sensor holds the tool up against gravity, so it carries
    -m g (up) and its moment about the tool point (``tool_mass_kg``, ``tool_com_x/y/z`` of ``params``)."""
    lift = -params["tool_mass_kg"] * GRAVITY
    lever = matrix_from_quaternion(orientations) @ np.array([params[f"tool_com_{x}"] for x in "xyz"])
    return np.hstack([np.broadcast_to(lift, lever.shape), np.cross(lever, lift)])


def tool_weight_case(seed: int = 0, free_space: bool = True) -> CorpusCase:
    """A zig-zag on a 30-40 deg slope recorded by a wrist sensor that does not compensate the tool's 0.4-0.6 kg
    (see the module docstring); slide. Family ``tool-weight`` (``free_space``: two zig-zags, rests in the air at
    the start and the end and a pause between, the tool held in three orientations ~25-40 deg apart) or
    ``tool-weight-no-free`` (one zig-zag, the file cut to its contact: every sample touches).

    The truth wrench is what the tool applies; the file's sensor also carries the weight: ``F_applied - m g`` and
    ``c × (-m g)`` about the tool point (``c`` from the tool point to the centre of mass, world), as the reaction
    in the tool frame with the offset, the hand's push and noise (`corpus.recording.recorded_case`).
    ``parameters``: ``tool_mass_kg``; ``tool_com_x/y/z`` the centre of mass in the TOOL frame from the tool point
    (the point the file's wrench is about), m: z is negative, the sensor lying ``sensor_to_tool_point_m``
    (0.12-0.18 m) behind the tool point and the centre of mass ``com_from_sensor_m`` (3-8 cm) in front of the
    sensor, up to 1 cm sideways; ``tilt_deg``, ``force_n``, ``ramp_s``, ``friction``, ``pad_stiffness_n_m``,
    ``cruise_m_s``, ``rate_hz`` (100, 125, 200 or 250 Hz), ``irregular``.
    """
    rng = np.random.default_rng([seed, 310, int(free_space)])
    dt = 1.0 / FINE_RATE_HZ
    params: dict[str, float] = {
        "tilt_deg": rng.uniform(30.0, 40.0),
        "force_n": rng.uniform(7.0, 10.0),
        "ramp_s": rng.uniform(0.4, 0.7),
        "friction": rng.uniform(0.2, 0.4),
        "pad_stiffness_n_m": rng.uniform(1.5e4, 3e4),
        "cruise_m_s": rng.uniform(0.06, 0.09),
        "tool_mass_kg": rng.uniform(0.4, 0.6),
        "sensor_to_tool_point_m": rng.uniform(0.12, 0.18),
        "com_from_sensor_m": rng.uniform(0.03, 0.08),
    }
    params |= tool_centre(rng, params)
    plane = tilted_plane(params["tilt_deg"], rng)
    force, ramp, cruise = params["force_n"], params["ramp_s"], params["cruise_m_s"]
    first = plane_stroke(plane, "zigzag", rng, dt, force, ramp, cruise)
    if free_space:
        beside = Fold(plane.origin + 0.07 * plane.e_v, plane.e_u, plane.e_v, 0.0, plane.radius)
        contacts = [first, plane_stroke(beside, "zigzag", rng, dt, force, ramp, cruise)]
        axes = _rest_axes(first.normals[0], plane.e_u, rng)
        pieces = through_the_air(contacts, rng, dt, (0.08, 0.15), (1.0, 1.4), axes, (1.2, 1.5))
    else:
        pieces = [first]  # touch-down to lift-off: no air at all
    fine = assemble(pieces, dt, rng, params["pad_stiffness_n_m"], params["friction"], 4e-4, 0.1)
    weight = carried_weight(fine.orientations, params)
    operator = OperatorModel(rng.uniform(3.0, 5.0), rng.uniform(15.0, 25.0), rng.uniform(1.0, 2.0))
    rate = float(rng.choice([100.0, 125.0, 200.0, 250.0]))
    family = "tool-weight" if free_space else "tool-weight-no-free"
    sensed = replace(fine, wrenches=fine.wrenches + weight)
    case = recorded_case(f"{family}-s{seed}", family, "slide", sensed, params, rng, rate, False, operator)
    # The truth is the wrench the tool applies, without its weight.
    return replace(case, wrenches=fine.wrenches[np.rint(case.t / dt).astype(int)])


# --------------------------------------------------------------------------- a disc grinder


def grinder_case(seed: int = 0) -> CorpusCase:
    """One straight pass of a disc grinder on a table (see the module docstring); slide, family ``grinder``.

    The truth wrench holds the disc's cutting force: ``cut_ratio`` (0.28-0.33) × the normal force, along a
    tool-frame direction across tool z that points across the pass (within ``cut_skew_deg``, ±5 deg) at the pass's
    middle, taken into the table's plane at every sample (the table takes no normal force from it: the normal force
    stays the press). Recorded by a wrist sensor at 250 Hz (`corpus.recording.recorded_case`). ``parameters``:
    ``tilt_deg``, ``force_n``, ``ramp_s``, ``friction``, ``pad_stiffness_n_m``, ``cruise_m_s``, ``length_m``,
    ``cut_ratio``, ``cut_skew_deg``, ``rate_hz``, ``irregular``.
    """
    rng = np.random.default_rng([seed, 320])
    dt = 1.0 / FINE_RATE_HZ
    params: dict[str, float] = {
        "tilt_deg": rng.uniform(0.0, 10.0),
        "force_n": rng.uniform(10.0, 20.0),
        "ramp_s": rng.uniform(0.4, 0.7),
        "friction": rng.uniform(0.2, 0.4),
        "pad_stiffness_n_m": rng.uniform(1.5e4, 3e4),
        "cruise_m_s": rng.uniform(0.02, 0.05),
        "length_m": rng.uniform(0.15, 0.2),
        "cut_ratio": rng.uniform(0.28, 0.33),
        "cut_skew_deg": rng.uniform(-5.0, 5.0),
    }
    plane = tilted_plane(params["tilt_deg"], rng)
    heading = rng.uniform(-np.pi, np.pi)
    s, xy = heading_path([heading], [params["length_m"]], 0.02)
    cruise = params["cruise_m_s"]
    t, p = timed(s, plane.points(xy[:, 0], xy[:, 1]), dt, speed_profile(min(cruise, 0.03), cruise, min(cruise, 0.03)))
    u, v = np.interp(p, s, xy[:, 0]), np.interp(p, s, xy[:, 1])
    contact = contact_piece(plane.points(u, v), plane.inward(u), t, params["force_n"], params["ramp_s"])
    pieces = through_the_air([contact], rng, dt, (0.1, 0.2), (1.3, 1.8))
    fine = assemble(pieces, dt, rng, params["pad_stiffness_n_m"], params["friction"], 2e-4, 0.1)

    normal = contact.normals[0]
    motion = np.cos(heading) * plane.e_u + np.sin(heading) * plane.e_v
    across = rng.choice([-1.0, 1.0]) * np.cross(normal, motion)
    aim = rotated(across, normal, np.radians(params["cut_skew_deg"]))
    R = matrix_from_quaternion(fine.orientations)
    middle = int(np.median(np.flatnonzero(fine.touching)))
    in_tool = R[middle].T @ aim
    in_tool[2] = 0.0  # across tool z: the disc cuts in its own plane
    cut = R @ (in_tool / np.linalg.norm(in_tool))
    cut -= np.sum(cut * fine.normals, axis=1, keepdims=True) * fine.normals
    cut *= (params["cut_ratio"] * fine.normal_force / np.linalg.norm(cut, axis=1))[:, None]
    fine = replace(fine, wrenches=fine.wrenches + np.hstack([cut, np.zeros_like(cut)]))
    operator = OperatorModel(rng.uniform(3.0, 6.0), rng.uniform(15.0, 30.0), rng.uniform(2.0, 5.0))
    return recorded_case(f"grinder-s{seed}", "grinder", "slide", fine, params, rng, 250.0, False, operator)


# --------------------------------------------------------------------------- high friction


def high_friction_cylinder_case(seed: int = 0) -> CorpusCase:
    """`corpus.families.cylinder_case` across a cylinder of radius 8-20 cm with friction 0.76-0.9: the applied force
    leans 37-42 deg towards the motion, beyond what a learner may take for friction; contour, analytic (its sensor
    the truth plus 0.2 N of noise), family ``cylinder-high-friction``."""
    rng = np.random.default_rng([seed, 330])
    radius = round(float(rng.uniform(0.08, 0.2)), 3)
    case = cylinder_case(radius, seed, friction=float(rng.uniform(0.76, 0.9)))
    return replace(case, name=f"cylinder-high-friction-r{radius * 100:g}cm-s{seed}", family="cylinder-high-friction")


# --------------------------------------------------------------------------- the families together


def force_source_cases(seeds: Sequence[int] = (0,)) -> Iterator[CorpusCase]:
    """Every family of `FORCE_SOURCE_FAMILIES` once per seed, in that order (6 cases per seed)."""
    for seed in seeds:
        yield lwr_wipe_case(seed, "patch")
        yield lwr_wipe_case(seed, "strip")
        yield tool_weight_case(seed, free_space=True)
        yield tool_weight_case(seed, free_space=False)
        yield grinder_case(seed)
        yield high_friction_cylinder_case(seed)
