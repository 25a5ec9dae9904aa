"""The HELD-OUT families: built after the learner was tuned, and never tuned on. Their scores are for the final report
only: whoever tunes the learner does not look at how it does on them before that.

World frame, z up, SI units (m, s, N, N·m, rad; angles in the docs in deg), quaternions scalar-last in the arrays; the
truth wrench is the one the tool APPLIES, world frame, at the tool point (the contact point); normals point INTO the
surface (docs/CONVENTIONS.md). Every family is a function of a seed returning a `corpus.case.CorpusCase` whose
``recording`` is the FILE a user brings (CSV text and the import options that read it right, read back by
``services.csv_import.demonstration_from_csv(text, CsvImportOptions(**options))``), with its truth as the other families
carry it (the tool point's positions, the true applied wrench, contact, normals, normal force,
`corpus.case.truth_segments`, ``parameters``). They reuse the building blocks of `corpus.build`, `corpus.families`,
`corpus.arm_wipe`, `corpus.force_sources` and `corpus.recording`; all four are slides:

- **A torque-sensing arm wiping a near-flat part** (`lwr_wipe_curved_case`, ``lwr-wipe-curved``): the strip wipe of
  `corpus.arm_wipe.lwr_wipe_case` (250 × 44-48 mm, 5 lanes 8-12 mm apart joined by rounded U-turns slowed to
  40-50 %, 1-2 contacts, 10-12 cm/s, press 8-20 N, friction 0.2-0.5, a stiff pad, rests of 1-1.2 s in the air at both
  ends) on a horizontal cylinder (random yaw) of radius 1.14-2.3 m (in 1-3 m: at least what turns the normal 14 deg over
  the contacts, which extend 0.27-0.4 m across the axis with their touch-downs, lift-offs and U-turns beyond the strip's
  ends, and at most 2.3 m, so that the path leaves its best plane by over 1.2 mm RMS), the lanes ACROSS its axis, the
  strip's middle 0-15 deg (either way) off the cylinder's top. The TRUE normal turns about the axis as the tool moves
  along a lane: by 6.2-12.6 deg over the strip's 250 mm (the length over the radius) and 6.9-14 deg over a contact, and
  the contact path leaves its best plane by 1.2-3 mm RMS (the lanes ALONG the axis would turn the normal by only
  1-2.5 deg across the strip's width and leave a plane by ~0.1 mm: a flat strip; they are not drawn). The file is the
  arm's log as on the flat strip: the FLANGE's pose 0.10-0.20 m behind the tool point along tool z, and the arm's
  estimate of the wrench ON the robot at the flange, world frame: the applied force turned by a configuration-dependent
  error (about an axis in the tangent plane at the strip's middle within 15 deg of the lanes, by an angle linear in
  where the arm reaches, scaled so that the estimate's friction-free force turns 28-32 deg midway between the least and
  the most pass, the surface's own turn included), a constant offset of 2-4 N (world), joint friction of 1.5-4 N (after
  import along the motion), the hand's push in free space only (2-8 N) and white noise (0.3-0.5 N, 0.05 N·m); ~100 Hz,
  stamps jittered ±20 %. One truth segment per contact; its normal is the mean TRUE normal over its pressing samples
  (the plateau between the ramps), which no single sample's normal equals: the normal turns under the tool.
- **An uncompensated tool weight on one line** (`tool_weight_line_case`, ``tool-weight-line``): a wrist sensor that does
  not compensate its 0.3-0.6 kg tool (as `corpus.force_sources.tool_weight_case`: the sensor carries ``F_applied - m g``
  and the weight's moment about the tool point, the sensor 0.12-0.18 m behind the tool point, the centre of mass 3-8 cm
  in front of the sensor), ONE straight stroke of 15-20 cm (random heading, 6-9 cm/s) on a table tilted 0-10 deg, press
  6-12 N, friction 0.2-0.4. In the air the hand holds the tool still in three orientations on a cone of 17.5-20 deg
  round the table's normal, 120 deg apart round it (29-35 deg from each other; 20-45 deg with the hand's wobble): before
  the approach, 4-6 cm aside from it (1.2-1.5 s), then at the approach's start (1.2-1.5 s), and after the retreat
  (1.2-1.5 s); an approach and a retreat from 8-15 cm. The file is the human-like wrist sensor's (`corpus.recording`:
  tool frame, the reaction, an offset of 0.7-2.3 N, noise 0.2 N, the hand's push on the arm) at 100, 125, 200 or 250 Hz;
  columns ``t,x,y,z,qw,qx,qy,qz,fx,fy,fz,mx,my,mz`` (scalar-FIRST), import options ``quaternion_order="wxyz"``,
  ``wrench_convention="measured-on-tool"``, ``wrench_frame="tool"``.
- **The hand on the arm while wiping** (`hand_on_arm_wipe_case`, ``hand-on-arm``): 1-2 zig-zag strokes (as the
  ``zigzag`` plane shape: 4-6 legs at ±30-40 deg over 20 cm, 6-10 cm/s; two strokes 7 cm apart) on a plane tilted
  0-30 deg, press 10-20 N, friction 0.2-0.5, rests of 1-1.5 s in the air at both ends. The person guides the arm by a
  LINK, not by the tool, and keeps pushing it in contact. A wrist sensor would not see that push (it sits between the
  links and the tool: only what passes through the tool reaches it), so the file is a torque-sensing arm's: its joint
  torques see every external force, the hand's included. The arm's tool point (TCP) is set to the tool point, so the
  file's pose is the TOOL POINT's and its wrench the estimate ON the robot at the tool point, world frame: the reaction
  to the applied force, plus the hand's push on the links as the arm maps it to the tool point (taken as the same force;
  its moment left out): a slow wander of 2-5 N in random directions (`corpus.kinesthetic.operator_forces` with neither
  mass nor damping; 0.1-0.7 Hz) and a drag of 10-25 N·s/m times the tool point's velocity, along the motion (the hand
  drives the arm against its damping: 0.5-1.5 N at the median speed in contact, up to 2.5 N; also in free space, at rest
  only the tremor's few tenths of a newton), plus a constant offset of 2-4 N (world) and white noise (0.3-0.5 N,
  0.05 N·m); ~100 Hz, stamps jittered ±20 %. After import (applied by the tool) the push reads as its NEGATIVE: the drag
  pulls the imported force AGAINST the motion, taking back part of the surface's friction.
- **A torque-sensing arm wiping one circle** (`lwr_circle_case`, ``lwr-circle``): one contact going 1.05-1.2 or 1.5-2
  times round the same circle of radius 2-4 cm (touch-down and lift-off at 3-4 cm/s, 5-8 cm/s between) on a table tilted
  0-15 deg, press 8-20 N, friction 0.2-0.5, a stiff pad, rests of 1-1.2 s in the air at both ends, an approach and a
  retreat from 3-8 cm: a single curve, not an area. The file is the arm's log as `lwr_wipe_curved_case`'s (flange pose,
  offset 2-4 N, joint friction 1.5-4 N, the hand in free space, noise), its direction error turning the force about an
  in-plane axis by an angle linear in where the arm reaches along the in-plane direction across that axis (within
  25 deg): where the tool moves along the axis the turn shows across the motion, so the friction-free force turns
  22-28 deg within the stroke (its pressing part) while the true one stays on the table's normal. The winding rule of
  `corpus.case.truth_segments` cuts a contact going round more than 1.25 times: 1 or 2 truth segments (between 1.2 and
  1.5 turns the part past the cut could lie within the lift-off ramp, a segment without a press).

The arm files' columns are ``t,x,y,z,qx,qy,qz,qw,fx,fy,fz,mx,my,mz`` (scalar-LAST), their import options
``wrench_convention="measured-on-tool"``, ``wrench_frame="world"``, ``rate_hz=100``; their recordings are
`corpus.arm_wipe.ArmEstimateRecording` (the hand-on-arm's a `HandOnArmRecording`: the push split into its drag and
its wander). A case lasts 6-23 s. `holdout_cases` yields every family once per seed.

Reused as they are: `corpus.arm_wipe._wipe_contacts`, though private there (the strip's lanes, so that the curved
wipe is the flat one's), and `corpus.build.through_the_air` (rests, approaches and retreats). Re-implemented here, being
small: the in-plane direction error and its scaling, the joint friction, the free-space weight of the hand, the log's
rows and text, the three held orientations.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from corpus.arm_log import (
    FINE_DT,
    arm_estimate_case,
    arm_options,
    in_plane_error,
    log_rows,
    slide_case,
    tool_velocity,
    written_log,
)
from corpus.arm_wipe import (
    LWR_RATE_HZ,
    WIPE_AREAS,
    ArmEstimateRecording,
    _wipe_contacts,
    arm_draws,
    wipe_draws,
    wipe_lanes,
    wipe_passes,
)
from corpus.build import (
    UP,
    Fold,
    Piece,
    assemble,
    circle_path,
    contact_piece,
    heading_path,
    rest,
    rotated,
    speed_profile,
    through_the_air,
    tilted_plane,
    timed,
    transfer,
)
from corpus.case import CorpusCase
from corpus.force_sources import carried_weight, tool_centre
from corpus.kinesthetic import OperatorModel, operator_forces
from corpus.recording import recorded_case
from corpus.strokes import plane_stroke

HOLDOUT_FAMILIES: tuple[str, ...] = ("lwr-wipe-curved", "tool-weight-line", "hand-on-arm", "lwr-circle")
"""The held-out families, in the order `holdout_cases` yields them."""
CURVED_RADIUS_M = (1.0, 3.0)
"""Radius range of `lwr_wipe_curved_case`'s cylinder, m (within it, `_curved_radius_range`)."""
CURVED_TURN_DEG = (5.0, 14.0)
"""How far the true normal turns over the strip's length (at least) and over a whole contact (at most), deg."""
CURVED_SAGITTA_M = 3.4e-3
"""Least sagitta of the strip's length on the cylinder, m (at most 2.3 m of radius): the contact path, mostly
lanes, then leaves its best plane by over 1.2 mm RMS (0.36-0.47 times the sagitta, measured)."""
DRAG_N_S_M = (10.0, 25.0)
"""The hand's drag on the arm's links (`hand_on_arm_wipe_case`), N·s/m."""
CIRCLE_RADIUS_M = (0.02, 0.04)
"""Radius of `lwr_circle_case`'s circle, m."""


def _rng(seed: int, family: str) -> np.random.Generator:
    """The random generator of ``family`` at ``seed`` (streams apart from the other modules' 100-499)."""
    return np.random.default_rng([seed, 500 + HOLDOUT_FAMILIES.index(family)])


# --------------------------------------------------------------------------- a near-flat part


class HorizontalCylinder(Fold):
    """A horizontal cylinder (axis along the unit ``axis``, horizontal) of ``radius_m`` (m) in the chart of a
    `corpus.build.Fold` (so that the builders that wipe a plane's chart wipe it): ``u`` m the arc length round the
    axis from the chart's origin, a point ``middle_rad`` (rad) round from the cylinder's top, ``v`` m along the axis.
    ``e_u``, ``e_v``, ``out`` are the chart's directions at its origin (the tangent across the axis, the axis, the
    outward normal); the normal turns about the axis by ``u / radius_m`` rad."""

    def __init__(self, origin: NDArray, axis: NDArray, radius_m: float, middle_rad: float) -> None:
        self.across = np.cross(axis, UP)  # horizontal, across the axis: the top's e_u
        self.middle = middle_rad
        tangent = np.cos(middle_rad) * self.across - np.sin(middle_rad) * UP
        super().__init__(origin, tangent, axis, 0.0, radius_m)
        self.centre = origin - radius_m * self.out  # the chart's origin lies on the surface

    def _outward(self, u: NDArray) -> NDArray[np.float64]:
        """Outward unit normals (M, 3) at chart coordinate ``u`` (M,) m."""
        angle = self.middle + np.asarray(u) / self.radius
        return np.sin(angle)[:, None] * self.across + np.cos(angle)[:, None] * UP

    def points(self, u: NDArray, v: NDArray) -> NDArray[np.float64]:
        """Surface points (M, 3) m at chart coordinates ``u``, ``v`` (M,) m."""
        return self.centre + self.radius * self._outward(u) + np.asarray(v)[:, None] * self.e_v

    def inward(self, u: NDArray) -> NDArray[np.float64]:
        """Inward unit normals (M, 3) at chart coordinate ``u`` (M,) m."""
        return -self._outward(u)


# --------------------------------------------------------------------------- a torque-sensing arm's log


@dataclass(frozen=True)
class HandOnArmRecording(ArmEstimateRecording):
    """A torque-sensing arm's log whose estimate carries the hand's push on the links (`hand_on_arm_wipe_case`).

    As `corpus.arm_wipe.ArmEstimateRecording`, with the file's pose at the tool point (``flange_positions`` is
    the tool point's path, ``flange_wrenches`` the true applied wrench, no direction error, no joint friction), and
    ``hand_forces`` (N, 3) the push as the estimate reads it in applied-by-tool terms (world, N: the push on the robot
    negated), split into ``hand_drag`` (N, 3), minus the drag times the tool point's velocity (AGAINST the motion
    after import), and ``hand_wander`` (N, 3), the slow wander: ``hand_forces = hand_drag + hand_wander``.
    """

    hand_drag: NDArray[np.float64]
    hand_wander: NDArray[np.float64]


def _curved_radius_range(extent_m: float, length_m: float) -> tuple[float, float]:
    """The radii (m) of `lwr_wipe_curved_case`'s cylinder for contacts extending ``extent_m`` (m) across its axis
    over a strip ``length_m`` (m) long: within `CURVED_RADIUS_M`, the normal turning at most `CURVED_TURN_DEG`'s
    largest over the contacts and at least its least over the strip, the strip's sagitta at least
    `CURVED_SAGITTA_M`."""
    low = max(CURVED_RADIUS_M[0], extent_m / np.radians(CURVED_TURN_DEG[1]))
    high = min(CURVED_RADIUS_M[1], length_m / np.radians(CURVED_TURN_DEG[0]), length_m**2 / (8 * CURVED_SAGITTA_M))
    if low >= high:
        raise ValueError(f"no radius fits contacts extending {extent_m:.3f} m over a {length_m:.3f} m strip")
    return low, high


def lwr_wipe_curved_case(seed: int = 0) -> CorpusCase:
    """The strip wipe of `corpus.arm_wipe.lwr_wipe_case` on a near-flat part: a horizontal cylinder of radius
    1.14-2.3 m (in `CURVED_RADIUS_M`, by `_curved_radius_range`), the lanes across its axis, the strip's middle
    0-15 deg (either way) off its top (see the module docstring); slide, family ``lwr-wipe-curved``, recorded by the
    torque-sensing arm's log.

    The TRUE normal turns about the cylinder's axis by the path's length over the radius: 6.2-12.6 deg over the
    250 mm of a lane, 6.9-14 deg over a whole contact (whose ends lie outside the strip). Each truth segment (one per
    contact) carries the mean true normal over its pressing samples. ``parameters``: as `lwr_wipe_case`'s (``tilt_deg``
    is the strip's middle's normal off the vertical, deg, signed; the direction error's axis and gradient lie in the
    tangent plane at the strip's middle, ``direction_origin_x/y/z`` its middle), plus ``radius_m``,
    ``cylinder_axis_x/y/z`` (unit, horizontal), ``cylinder_centre_x/y/z`` (a point on the axis, m),
    ``normal_turn_deg`` (the true normal's turn over the strip's length, deg) and ``contact_turn_deg`` (over the
    contacts' whole extent across the axis, deg)."""
    rng = _rng(seed, "lwr-wipe-curved")
    shape = WIPE_AREAS["strip"]
    width, lanes = wipe_lanes(rng, shape)
    tilt = float(rng.uniform(0.0, 15.0) * rng.choice([-1.0, 1.0]))
    params = {**wipe_draws(rng, shape, width, lanes, tilt), **arm_draws(rng, (28.0, 32.0))}
    where = rng.uniform()  # where the radius lies in its range, which the contacts' extent sets
    axis = rotated(np.array([1.0, 0.0, 0.0]), UP, rng.uniform(-np.pi, np.pi))
    middle = np.array([0.5 + rng.uniform(-0.05, 0.05), rng.uniform(-0.1, 0.1), 0.15])
    tilt = np.radians(params["tilt_deg"])
    wipe = (shape.length_m, width, lanes, int(params["contacts"]), params["cruise_m_s"], params["force_n"])
    # The cylinder's chart is its tangent plane at the strip's middle rolled onto it (u is arc length): the same
    # draws wipe the same chart path with the same timing on either. On the plane, the contacts' extent across the
    # axis (the lanes plus the touch-downs, lift-offs and U-turns beyond the strip's ends) sets the radius range.
    tangent = HorizontalCylinder(middle, axis, 1.0, tilt).e_u  # the chart's directions do not depend on the radius
    flat = Fold(middle, tangent, axis, 0.0, 1.0)
    probe = _wipe_contacts(flat, *wipe, params["ramp_s"], copy.deepcopy(rng), FINE_DT)
    extent = float(np.ptp(np.concatenate([c.points for c in probe]) @ flat.e_u))
    low, high = _curved_radius_range(extent, shape.length_m)
    radius = low + where * (high - low)
    part = HorizontalCylinder(middle, axis, radius, tilt)
    params |= {
        "radius_m": radius,
        "normal_turn_deg": float(np.degrees(shape.length_m / radius)),
        "contact_turn_deg": float(np.degrees(extent / radius)),
    }
    params |= {f"cylinder_axis_{x}": float(v) for x, v in zip("xyz", axis, strict=True)}
    params |= {f"cylinder_centre_{x}": float(v) for x, v in zip("xyz", part.centre, strict=True)}
    # The lanes run along the chart's e_u: across the axis, where the normal turns.
    contacts = _wipe_contacts(part, *wipe, params["ramp_s"], rng, FINE_DT)
    pieces = through_the_air(contacts, rng, FINE_DT, (0.03, 0.08), (0.7, 1.0), rest_s=(1.0, 1.2))
    fine = assemble(pieces, FINE_DT, rng, params["pad_stiffness_n_m"], params["friction"], 3e-4, 0.1)
    # The arm's error turns about an axis in the tangent plane at the strip's middle, near the lanes (as on the flat
    # strip, where that plane is the part's).
    error = in_plane_error(
        middle, part.e_u, part.out, rng.uniform(-15.0, 15.0), rng.uniform(-25.0, 25.0), params["direction_constant_deg"]
    )
    pressing = fine.plateau_id >= 0

    def passes(t: NDArray, tip: NDArray) -> list[slice]:
        # The lanes' direction at the strip's middle: a lane's own turns by half the normal's turn either side.
        return wipe_passes(t, tip, pressing[np.rint(t / FINE_DT).astype(int)], part.e_u, shape.length_m)

    name = f"lwr-wipe-curved-s{seed}"
    return arm_estimate_case(name, "lwr-wipe-curved", fine, params, rng, error, passes)


def _rest_axes(normal: NDArray, e_u: NDArray, rng: np.random.Generator) -> list[NDArray[np.float64]]:
    """Three tool axes on a cone of 17.5-20 deg round ``normal`` (unit, world), 120 deg apart round it from a random
    phase off ``e_u`` (a unit vector across ``normal``): 29-35 deg from each other, so that with the hand's wobble in
    the air (up to ~8 deg between two holds) they stay 20-45 deg apart (a narrower cone than
    `corpus.force_sources.tool_weight_case`'s 18-22 deg, which reaches 44 deg)."""
    cone, phase = np.radians(rng.uniform(17.5, 20.0)), rng.uniform(-np.pi, np.pi)
    return [rotated(normal, rotated(e_u, normal, phase + 2 * np.pi * k / 3), cone) for k in range(3)]


def _straight_stroke(
    plane: Fold, length_m: float, cruise: float, force_n: float, ramp_s: float, rng: np.random.Generator
) -> Piece:
    """One straight stroke of ``length_m`` (m) on ``plane`` at a random heading, touching down and lifting off at
    3-4 cm/s and ``cruise`` (m/s) between, pressing ``force_n`` (N) with ramps of ``ramp_s`` (s)."""
    s, xy = heading_path([rng.uniform(-np.pi, np.pi)], [length_m], 0.02)
    speed = speed_profile(rng.uniform(0.03, 0.04), cruise, rng.uniform(0.03, 0.04))
    t, p = timed(s, plane.points(xy[:, 0], xy[:, 1]), FINE_DT, speed)
    u, v = np.interp(p, s, xy[:, 0]), np.interp(p, s, xy[:, 1])
    return contact_piece(plane.points(u, v), plane.inward(u), t, force_n, ramp_s)


def tool_weight_line_case(seed: int = 0) -> CorpusCase:
    """ONE straight 15-20 cm stroke on a table tilted 0-10 deg, recorded by a wrist sensor that does not compensate
    the tool's 0.3-0.6 kg, the tool held still in the air in three orientations 29-35 deg apart (see the module
    docstring); slide, family ``tool-weight-line``.

    The truth wrench is what the tool applies; the file's sensor also carries the weight (``F_applied - m g`` and
    ``c × (-m g)`` about the tool point, as the reaction in the tool frame with the offset, the hand's push and
    noise: `corpus.recording.recorded_case`). ``parameters`` as `corpus.force_sources.tool_weight_case`'s
    (``tool_mass_kg``; ``tool_com_x/y/z`` the centre of mass in the TOOL frame from the tool point, m;
    ``sensor_to_tool_point_m``, ``com_from_sensor_m``, ``tilt_deg``, ``force_n``, ``ramp_s``, ``friction``,
    ``pad_stiffness_n_m``, ``cruise_m_s``, ``rate_hz``, ``irregular``), plus ``length_m`` (the stroke's, m).
    """
    rng = _rng(seed, "tool-weight-line")
    params: dict[str, float] = {
        "tilt_deg": rng.uniform(0.0, 10.0),
        "force_n": rng.uniform(6.0, 12.0),
        "ramp_s": rng.uniform(0.4, 0.7),
        "friction": rng.uniform(0.2, 0.4),
        "pad_stiffness_n_m": rng.uniform(1.5e4, 3e4),
        "cruise_m_s": rng.uniform(0.06, 0.09),
        "length_m": rng.uniform(0.15, 0.20),
        "tool_mass_kg": rng.uniform(0.3, 0.6),
        "sensor_to_tool_point_m": rng.uniform(0.12, 0.18),
        "com_from_sensor_m": rng.uniform(0.03, 0.08),
    }
    params |= tool_centre(rng, params)
    plane = tilted_plane(params["tilt_deg"], rng)
    stroke = _straight_stroke(plane, params["length_m"], params["cruise_m_s"], params["force_n"], params["ramp_s"], rng)
    held = _rest_axes(stroke.normals[0], plane.e_u, rng)
    # One contact gives two rests (before the approach, after the retreat); the third orientation is held first,
    # 4-6 cm aside, so that a tare sees the weight turn in three orientations.
    pieces = through_the_air([stroke], rng, FINE_DT, (0.08, 0.15), (1.0, 1.4), held[1:], (1.2, 1.5))
    start = pieces[0].points[0]
    first = start + rng.uniform(0.04, 0.06) * rotated(plane.e_u, plane.out, rng.uniform(-np.pi, np.pi))
    move = transfer(first, start, held[1], rng.uniform(0.6, 0.9), FINE_DT, 0.01)
    pieces = [rest(first, held[0], rng.uniform(1.2, 1.5), FINE_DT), move, *pieces]
    fine = assemble(pieces, FINE_DT, rng, params["pad_stiffness_n_m"], params["friction"], 4e-4, 0.1)
    weight = carried_weight(fine.orientations, params)
    operator = OperatorModel(rng.uniform(3.0, 5.0), rng.uniform(15.0, 25.0), rng.uniform(1.0, 2.0))
    rate = float(rng.choice([100.0, 125.0, 200.0, 250.0]))
    sensed = replace(fine, wrenches=fine.wrenches + weight)
    name = f"tool-weight-line-s{seed}"
    case = recorded_case(name, "tool-weight-line", "slide", sensed, params, rng, rate, False, operator)
    # The truth is the wrench the tool applies, without its weight.
    return replace(case, wrenches=fine.wrenches[np.rint(case.t / FINE_DT).astype(int)])


def hand_on_arm_wipe_case(seed: int = 0) -> CorpusCase:
    """1-2 zig-zag strokes on a plane tilted 0-30 deg, guided by a hand pushing the arm's links all along, recorded
    by a torque-sensing arm's log at the tool point (see the module docstring); slide, family ``hand-on-arm``.

    The file's force (on the robot, world) is the reaction to the applied force plus the hand's push (a drag of
    ``drag_n_s_m`` times the tool point's velocity along the motion, plus a slow wander of ``wander_n``) plus the
    offset and noise; after import (applied by the tool) it is the applied force plus ``recording.hand_forces`` (the
    push negated: the drag against the motion). Its moment is the noise alone (the estimate at the tool point, where
    the applied wrench has no moment; the push's moment is left out). ``parameters``: ``tilt_deg``, ``force_n``,
    ``ramp_s``, ``friction``, ``pad_stiffness_n_m``, ``cruise_m_s``, ``strokes``, ``drag_n_s_m``, ``wander_n``,
    ``offset_n``, ``noise_n``, ``rate_hz``, ``flange_offset_m`` (0: the file's pose is the tool point's).
    """
    rng = _rng(seed, "hand-on-arm")
    params: dict[str, float] = {
        "tilt_deg": rng.uniform(0.0, 30.0),
        "force_n": rng.uniform(10.0, 20.0),
        "ramp_s": rng.uniform(0.4, 0.8),
        "friction": rng.uniform(0.2, 0.5),
        "pad_stiffness_n_m": rng.uniform(1.5e4, 3e4),
        "cruise_m_s": rng.uniform(0.06, 0.1),
        "strokes": float(rng.integers(1, 3)),
        "drag_n_s_m": rng.uniform(*DRAG_N_S_M),
        "wander_n": rng.uniform(2.0, 5.0),
        "offset_n": rng.uniform(2.0, 4.0),
        "noise_n": rng.uniform(0.3, 0.5),
        "rate_hz": LWR_RATE_HZ,
        "flange_offset_m": 0.0,
    }
    plane = tilted_plane(params["tilt_deg"], rng)
    force, ramp, cruise = params["force_n"], params["ramp_s"], params["cruise_m_s"]
    contacts = [plane_stroke(plane, "zigzag", rng, FINE_DT, force, ramp, cruise)]
    if params["strokes"] == 2.0:
        beside = Fold(plane.origin + 0.07 * plane.e_v, plane.e_u, plane.e_v, 0.0, plane.radius)
        contacts.append(plane_stroke(beside, "zigzag", rng, FINE_DT, force, ramp, cruise))
    pieces = through_the_air(contacts, rng, FINE_DT, (0.08, 0.15), (1.0, 1.4), rest_s=(1.0, 1.5))
    fine = assemble(pieces, FINE_DT, rng, params["pad_stiffness_n_m"], params["friction"], 4e-4, 0.1)
    # The push on the robot: the drag along the tool point's motion (the hand drives the arm against its damping)
    # and a slow wander; in contact as in free space. In applied-by-tool terms (as the import reads it) negated.
    drag = -params["drag_n_s_m"] * tool_velocity(fine)
    wander = -operator_forces(fine.t, fine.positions, OperatorModel(0.0, 0.0, params["wander_n"]), rng)
    rows = log_rows(fine, params["noise_n"], rng)
    applied = fine.wrenches[:, :3]
    log = written_log(fine, rows, fine.positions, applied + drag + wander, params["offset_n"], rng)
    s = rows.samples
    name = f"hand-on-arm-s{seed}"
    recording = HandOnArmRecording(
        csv_text=log.csv_text,
        import_options=arm_options(name),
        sensor_offset=log.offset,
        hand_forces=drag[s] + wander[s],
        flange_positions=fine.positions[s],
        flange_wrenches=log.at_path[s],
        direction_errors=np.zeros((s.size, 3)),
        joint_friction=np.zeros((s.size, 3)),
        hand_drag=drag[s],
        hand_wander=wander[s],
    )
    return slide_case(name, "hand-on-arm", fine, s, params, recording)


def lwr_circle_case(seed: int = 0) -> CorpusCase:
    """One contact going 1.05-1.2 or 1.5-2 times round a circle of radius 2-4 cm on a table tilted 0-15 deg, recorded
    by a torque-sensing arm's log (see the module docstring); slide, family ``lwr-circle``.

    The estimate's direction error turns the force about an in-plane axis (the table's chart direction turned by a
    random angle) by ``constant + gain * (p - origin) · gradient``, the gradient within 25 deg of the in-plane
    direction across the axis: at the circle's points farthest along the gradient the tool moves along the axis, where
    the turn shows across the motion (along the gradient's own direction it would fall along the motion there, and a
    friction-free force would not show it). The gain is scaled so that the friction-free force of the estimate turns
    ``direction_turn_deg`` (22-28 deg) over the contact's pressing part (between its ramps). ``parameters`` as
    `corpus.arm_wipe.lwr_wipe_case`'s (without the wipe's area), plus ``circle_radius_m``, ``turns``."""
    rng = _rng(seed, "lwr-circle")
    params: dict[str, float] = {
        "tilt_deg": rng.uniform(0.0, 15.0),
        "circle_radius_m": rng.uniform(*CIRCLE_RADIUS_M),
        "turns": float(rng.choice([rng.uniform(1.05, 1.2), rng.uniform(1.5, 2.0)])),
        "force_n": rng.uniform(8.0, 20.0),
        "ramp_s": rng.uniform(0.3, 0.8),
        "friction": rng.uniform(0.2, 0.5),
        "pad_stiffness_n_m": rng.uniform(1.5e4, 3e4),
        "cruise_m_s": rng.uniform(0.05, 0.08),
        **arm_draws(rng, (22.0, 28.0)),
    }
    plane = tilted_plane(params["tilt_deg"], rng)
    radius = params["circle_radius_m"]
    angle, chart = circle_path(lambda a: np.full_like(a, radius), params["turns"])
    speed = speed_profile(rng.uniform(0.03, 0.04), params["cruise_m_s"], rng.uniform(0.03, 0.04))
    t, a = timed(angle, plane.points(chart[:, 0], chart[:, 1]), FINE_DT, speed)
    u, v = np.interp(a, angle, chart[:, 0]), np.interp(a, angle, chart[:, 1])
    circle = contact_piece(plane.points(u, v), plane.inward(u), t, params["force_n"], params["ramp_s"])
    pieces = through_the_air([circle], rng, FINE_DT, (0.03, 0.08), (0.7, 1.0), rest_s=(1.0, 1.2))
    fine = assemble(pieces, FINE_DT, rng, params["pad_stiffness_n_m"], params["friction"], 3e-4, 0.1)
    axis_deg = rng.uniform(-180.0, 180.0)
    across_deg = axis_deg + 90.0 + rng.uniform(-25.0, 25.0)
    error = in_plane_error(plane.origin, plane.e_u, plane.out, axis_deg, across_deg, params["direction_constant_deg"])
    pressing = fine.plateau_id >= 0

    def stroke(t: NDArray, tip: NDArray) -> list[slice]:
        rows = np.flatnonzero(pressing[np.rint(t / FINE_DT).astype(int)])
        return [slice(int(rows[0]), int(rows[-1]) + 1)]

    return arm_estimate_case(f"lwr-circle-s{seed}", "lwr-circle", fine, params, rng, error, stroke)


# --------------------------------------------------------------------------- the families together

_HOLDOUT_FAMILY_CASES: dict[str, Callable[[int], CorpusCase]] = {
    "lwr-wipe-curved": lwr_wipe_curved_case,
    "tool-weight-line": tool_weight_line_case,
    "hand-on-arm": hand_on_arm_wipe_case,
    "lwr-circle": lwr_circle_case,
}


def holdout_cases(seeds: Sequence[int]) -> Iterator[CorpusCase]:
    """Every family of `HOLDOUT_FAMILIES` once per seed, in that order, seed by seed (4 cases per seed)."""
    for seed in seeds:
        for family in HOLDOUT_FAMILIES:
            yield _HOLDOUT_FAMILY_CASES[family](seed)
