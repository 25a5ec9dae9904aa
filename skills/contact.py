"""Contact detection from force AND kinematics: when the tool really touches the work piece.

Force alone cannot tell contact on a human demonstration: a person guiding a gravity-compensated
arm pushes on it in free space with 2-17 N, as much as a light stroke presses. What only contact
does is *press without moving along the push*: on the surface the tool slides ACROSS the force
(the force lies within the friction cone around the surface normal), and the surface stops it
from going deeper. So contact is decided in two steps (all world frame, SI):

1. **Stroke cores** — samples where the tool presses (|f| above ``CORE_FORCE_FRACTION`` of the
   robust peak) while sliding (speed above ``CORE_MIN_SPEED_M_S``) ACROSS the force (the force
   component along the motion is at most ``FRICTION_CONE_MAX`` times the component across it:
   friction, not a push that moves the arm). Runs shorter than ``CORE_MIN_S`` are noise; gaps
   shorter than ``CORE_GAP_S`` (a pause on the surface) are bridged.
2. **Boundaries** — from each core, contact extends back to the touch-down and forward to the
   lift-off for as long as the tool stays ON the surface the core pressed on (its depth along the
   local surface normal stays within ``SURFACE_TOLERANCE_M`` of the surface found at the core's
   end, no higher, where the surface's depth allows for a compliant pad that sinks with the
   press) AND presses into it (force along that normal above the touch level: 4 standard
   deviations of the smoothed force's noise, at least ``TOUCH_FORCE_MIN_N``) or rests on it
   (moving along the normal slower than ``RESTING_SPEED_M_S``, not pulling off). Whichever of the
   two fails first decides the boundary, and the analysis says which ("force" or "surface").
   Intervals that overlap or are less than ``CORE_GAP_S`` apart are one contact; contacts shorter
   than ``MIN_CONTACT_S`` are dropped.

Without any sliding press (a press-and-hold), the cores fall back to the pressing samples alone.
Every input is uniformly sampled: ``t`` (N,) s, ``positions`` (N, 3) m, ``forces`` (N, 3) N
applied by the tool (world frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_closing, binary_opening, gaussian_filter1d

from schemas.skill import BoundaryReason
from skills.friction import FRICTION_CONE_MAX, friction_coefficient, friction_free
from skills.surface import pressed_surface

CORE_FORCE_FRACTION = 0.4
"""A stroke core presses with at least this fraction of the robust peak force (98th percentile of |f|)."""

CORE_FORCE_MIN_N = 1.0
"""...and at least this force, N (sensor noise never makes a core)."""

CORE_MIN_SPEED_M_S = 0.005
"""A stroke core slides at least this fast, m/s (below it the friction direction is undefined)."""

CORE_MIN_S = 0.15
"""Shortest run of sliding-press samples that makes a stroke core, s."""

CORE_GAP_S = 0.3
"""Gaps in a core shorter than this (a pause, a turn of direction) are bridged, s."""

SURFACE_TOLERANCE_M = 0.003
"""How far (m) above the surface found under load the tool may be and still touch it (pad relief, tremor)."""

LOCAL_NORMAL_S = 1.0
"""Length of the core's first/last stretch that gives the local surface: normal, plane and pad compliance, s."""

RAMP_FRACTION = 0.25
"""The surface model uses the ramp next to a core down to this fraction of the core's press."""

NORMAL_MIN_SPEED_M_S = 0.02
"""Least sliding speed (m/s) at which the friction-free force direction is taken as the surface normal.

Slower, the sliding direction is the hand's tremor (~1-2 cm/s at 4-9 Hz), which friction follows
but the smoothed velocity does not: the friction left in the direction tilts it by up to ~20°.
"""

RESTING_SPEED_M_S = 0.002
"""A tool on the surface moving along its normal slower than this (m/s) rests on it: still in contact."""

TOUCH_FORCE_MIN_N = 0.3
"""Smallest force along the normal (N) that counts as still touching."""

MIN_CONTACT_S = 0.3
"""Contacts shorter than this are dropped, s."""

SMOOTHING_S = 0.02
"""Standard deviation of the zero-phase Gaussian that smooths positions and forces before differentiating, s."""


@dataclass(frozen=True)
class ContactInterval:
    """One contact ``[start, end)`` in samples, and what decided each boundary.

    ``start_reason`` / ``end_reason``: ``force`` (the force along the normal rose from / fell
    to the touch level), ``surface`` (the tool reached / left the surface it pressed on) or
    ``recording`` (the recording starts / ends in contact).
    """

    start: int
    end: int
    start_reason: BoundaryReason
    end_reason: BoundaryReason


@dataclass(frozen=True)
class ContactAnalysis:
    """Contact of a uniformly sampled demonstration.

    ``in_contact`` (N,) per sample; ``directions`` (N, 3) unit friction-free force directions
    (the surface normal into the surface where the tool slides in contact, zero where unknown);
    ``intervals`` the contacts in time order; ``core_force_n`` the pressing level of the cores
    and ``touch_force_n`` the touch level (N); ``sliding_cores`` False when no sliding press was
    found and cores fell back to force alone.
    """

    rate_hz: float
    in_contact: NDArray[np.bool_]
    directions: NDArray[np.float64]
    intervals: list[ContactInterval]
    core_force_n: float
    touch_force_n: float
    sliding_cores: bool = True


def force_noise_std(forces: NDArray[np.float64]) -> float:
    """Return the robust standard deviation (N) of the sensor noise of (N, 3) forces.

    From sample-to-sample differences (the noise of a difference is sqrt(2) times the sample's),
    median absolute deviation, largest axis: slow changes of the real force do not count.
    """
    diffs = np.diff(forces, axis=0)
    mad = np.median(np.abs(diffs - np.median(diffs, axis=0)), axis=0)
    return float(np.max(1.4826 * mad / np.sqrt(2.0)))


def normal_directions(
    forces: NDArray[np.float64], velocities: NDArray[np.float64], in_contact: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """Return per-sample unit directions of the applied force with the friction part removed (`skills.friction`).

    What is left is the surface normal direction into the surface, but only where the tool SLIDES
    in contact: where it rests or creeps (speed below ``NORMAL_MIN_SPEED_M_S``, or half the median
    speed in contact for a slow wipe, at least ``CORE_MIN_SPEED_M_S``) static friction or tremor
    can point it anywhere in the cone; where it moves along the force (touching down, lifting off:
    the removed part exceeds ``FRICTION_CONE_MAX`` of what is left) the removed component is not
    friction; where the force is below a third of the median contact force, noise dominates. There
    the direction says nothing about the normal and is zero, as where not in contact.
    """
    free = friction_free(forces, velocities, friction_coefficient(forces, velocities, in_contact))
    speed = np.linalg.norm(velocities, axis=1)
    magnitude = np.linalg.norm(forces, axis=1)
    typical = float(np.median(magnitude[in_contact])) if in_contact.any() else 0.0
    # A slow wipe (a few cm/s) still has its normals: the floor is lowered to half its median speed.
    wiping_speed = float(np.median(speed[in_contact])) if in_contact.any() else 0.0
    floor = float(np.clip(0.5 * wiping_speed, CORE_MIN_SPEED_M_S, NORMAL_MIN_SPEED_M_S))
    sliding = (speed > floor) & (magnitude > typical / 3.0) & (free.weights > 0.0)
    return free.directions * (in_contact & sliding)[:, None]


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Return ``[start, end)`` of every run of True in ``mask``."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _stretch_normal(forces: NDArray[np.float64], velocities: NDArray[np.float64], rows: slice) -> NDArray[np.float64]:
    """Return the surface normal (into the surface) over ``rows``: the mean friction-free force direction."""
    v = velocities[rows]
    sliding = np.linalg.norm(v, axis=1, keepdims=True) > CORE_MIN_SPEED_M_S
    return _unit(friction_free(forces[rows], v * sliding).forces.mean(axis=0))


def analyse_contact(
    t: NDArray[np.float64],
    positions: NDArray[np.float64],
    forces: NDArray[np.float64],
    core_force_n: float | None = None,
) -> ContactAnalysis:
    """Return the contact analysis of a uniformly sampled demonstration (s, m, N applied, world).

    ``core_force_n`` overrides the pressing level of the stroke cores (default: adaptive, see
    the module docstring).
    """
    n = t.size
    rate_hz = (n - 1) / (t[-1] - t[0])
    sigma = max(1.0, SMOOTHING_S * rate_hz)
    p = gaussian_filter1d(positions, sigma, axis=0, mode="nearest")
    f = gaussian_filter1d(forces, sigma, axis=0, mode="nearest")
    v = np.gradient(p, t, axis=0)
    magnitude = np.linalg.norm(f, axis=1)
    # The touch level: 4 standard deviations of the noise left after the smoothing (white noise
    # averaged by a Gaussian of sigma samples keeps 1 / sqrt(2 sqrt(pi) sigma) of its std).
    smoothed_noise = force_noise_std(forces) / np.sqrt(2.0 * np.sqrt(np.pi) * sigma)
    touch = max(TOUCH_FORCE_MIN_N, 4.0 * smoothed_noise)
    core_force = core_force_n or max(CORE_FORCE_MIN_N, CORE_FORCE_FRACTION * float(np.percentile(magnitude, 98)))

    speed = np.linalg.norm(v, axis=1)
    v_hat = v / np.maximum(speed, 1e-12)[:, None]
    along = np.sum(f * v_hat, axis=1)
    across = np.linalg.norm(f - along[:, None] * v_hat, axis=1)
    pressing = magnitude >= core_force
    sliding = pressing & (speed >= CORE_MIN_SPEED_M_S) & (np.abs(along) <= FRICTION_CONE_MAX * across)

    def cleaned(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        gap = max(1, round(CORE_GAP_S * rate_hz))
        bridged = binary_closing(np.pad(mask, gap), structure=np.ones(gap))[gap:-gap]
        return binary_opening(bridged, structure=np.ones(max(1, round(CORE_MIN_S * rate_hz))))

    cores_mask = cleaned(sliding)
    sliding_cores = bool(cores_mask.any())
    if not sliding_cores:
        cores_mask = cleaned(pressing)
    window = max(2, round(LOCAL_NORMAL_S * rate_hz))

    intervals: list[tuple[int, int, BoundaryReason, BoundaryReason]] = []
    cores = _runs(cores_mask)
    for k, (c0, c1) in enumerate(cores):
        # Each search reads only the rows up to the neighbouring cores (a whole-recording scan per core made
        # learning grow with strokes x samples); a contact that reaches a neighbour core merges with it below.
        lo = cores[k - 1][1] if k > 0 else 0
        hi = cores[k + 1][0] if k + 1 < len(cores) else n
        rows = slice(lo, hi)
        head = slice(c0 - lo, min(c1, c0 + window) - lo)
        tail = slice(max(c0, c1 - window) - lo, c1 - lo)
        start, start_reason = _touch_down(p[rows], f[rows], v[rows], head, c0 - lo, touch, backward=True)
        end, end_reason = _touch_down(p[rows], f[rows], v[rows], tail, c1 - 1 - lo, touch, backward=False)
        intervals.append((lo + start, lo + end + 1, start_reason, end_reason))

    merged: list[ContactInterval] = []
    bridge = round(CORE_GAP_S * rate_hz)
    for start, end, start_reason, end_reason in sorted(intervals):
        # Overlapping, or apart for less than a pause: no lift fits in there, it is one contact.
        if merged and start <= merged[-1].end + bridge:
            last = merged[-1]
            if end > last.end:
                merged[-1] = ContactInterval(last.start, end, last.start_reason, end_reason)
            continue
        merged.append(ContactInterval(start, end, start_reason, end_reason))
    shortest = round(MIN_CONTACT_S * rate_hz)
    merged = [c for c in merged if c.end - c.start >= shortest]

    in_contact = np.zeros(n, dtype=bool)
    for c in merged:
        in_contact[c.start : c.end] = True
    return ContactAnalysis(
        rate_hz=rate_hz,
        in_contact=in_contact,
        directions=normal_directions(forces, v, in_contact),
        intervals=merged,
        core_force_n=core_force,
        touch_force_n=touch,
        sliding_cores=sliding_cores,
    )


def _touch_down(
    p: NDArray[np.float64],
    f: NDArray[np.float64],
    v: NDArray[np.float64],
    reference: slice,
    edge: int,
    touch_n: float,
    backward: bool,
) -> tuple[int, BoundaryReason]:
    """Return the first (``backward``: earliest) sample still in contact beyond a core's ``edge``, and why it ends.

    The local surface (normal, plane, pad compliance: `skills.surface`) comes from the core's
    ``reference`` stretch next to the edge; contact goes on while the tool is no higher than
    ``SURFACE_TOLERANCE_M`` (or 2 model residuals) above the surface at the force it presses with,
    and the force along the normal is at least ``touch_n`` or the tool rests there without pulling.
    """
    normal = _stretch_normal(f, v, reference)
    pressing = f @ normal
    # The surface model also takes the upper part of the ramp next to the core (the press above
    # RAMP_FRACTION of the core's): there the force changes most, which shows the pad's compliance.
    firm = pressing >= RAMP_FRACTION * float(np.median(pressing[reference]))
    if backward:
        soft = np.flatnonzero(~firm[: reference.start])
        model_rows = slice(int(soft[-1]) + 1 if soft.size else 0, reference.stop)
    else:
        soft = np.flatnonzero(~firm[reference.stop :])
        model_rows = slice(reference.start, reference.stop + int(soft[0]) if soft.size else p.shape[0])
    surface = pressed_surface(p[model_rows], pressing[model_rows], normal)
    tolerance = max(SURFACE_TOLERANCE_M, 2.0 * surface.residual_rms_m)
    on_surface = p @ normal >= surface.depth_at(p, pressing) - tolerance
    # Touching: pressing above the touch level, or resting on the surface without pulling off it
    # (a hand that has let go of the press before it lifts: the surface still stops the tool).
    resting = (np.abs(v @ normal) < RESTING_SPEED_M_S) & (pressing > -touch_n)
    touching = (pressing >= touch_n) | resting
    inside = on_surface & touching
    if backward:
        outside = np.flatnonzero(~inside[:edge])
        if outside.size == 0:
            return 0, BoundaryReason.recording
        k = int(outside[-1])
        return k + 1, BoundaryReason.force if on_surface[k] else BoundaryReason.surface
    outside = np.flatnonzero(~inside[edge + 1 :])
    if outside.size == 0:
        return p.shape[0] - 1, BoundaryReason.recording
    k = edge + 1 + int(outside[0])
    return k - 1, BoundaryReason.force if on_surface[k] else BoundaryReason.surface


def mask_runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Return ``[start, end)`` of every run of True in a per-sample ``mask``."""
    return _runs(mask)
