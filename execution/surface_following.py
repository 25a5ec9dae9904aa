"""A contact phase that follows the surface as it finds it (``hybrid_cf`` with ``follow_surface_normal``).

The learned skill says how the tool moves and presses RELATIVE to the surface: its compliant frame (CF) z is the
surface normal, its path runs in the surface. When the part is not where, or not what, it was taught (moved,
tilted, another radius), the taught frames and the taught world path no longer fit it. :class:`SurfaceFollower`
keeps the execution on the surface that is really there, every ``FOLLOW_PERIOD_STEPS`` control steps:

- the CF z is the normal estimated online (:class:`skills.normal_tracking.SurfaceNormalTracker`: the applied force
  without its friction part while sliding, its own direction while still), and the CF is the learned one turned by
  the least rotation ``Δ`` that takes the learned z (where the path is now) to it;
- on a contour, the references are rewritten from where the tool is: the taught velocity and angular velocity
  turned by ``Δ`` (so the tool moves along the surface it presses on, as it moved along the taught one), integrated
  from a reference point that is kept on the surface's tangent plane through the tool while the tool presses (the
  path is re-anchored where the surface was found, and stays anchored to it), and the taught orientation turned by
  ``Δ`` (the tool keeps its pose relative to the surface; the orientation turns towards ``Δ`` at no more than
  ``ORIENTATION_RATE_RAD_S``, so a frame turned a lot while the tool stood still does not jerk the tool when it starts
  moving). A slide keeps its references (its path already runs in
  the plane of the surface found; the turned frame takes the force along the real normal).

Crease evidence: a follower told the next segment's learned z (``next_z``) reports when the tracked normal has
turned more than half-way from the current learned z towards it: the tool is on the next surface, whenever the
taught time says it should be.

World frame, m, s, N, rad; quaternions ``[x, y, z, w]`` (docs/CONVENTIONS.md).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from execution.plans import ContactGeometry, PhasePlan
from schemas.execution import ExecutionPhase
from skills.control import ControlFrame, HybridController
from skills.control.layouts import REFERENCE_POSITION, REFERENCE_QUAT, REFERENCE_TWIST
from skills.frames import rotation_from_vectors
from skills.normal_tracking import SurfaceNormalTracker
from skills.quaternions import quaternion_from_matrix, quaternion_product

FOLLOW_PERIOD_STEPS = 10
"""The frame (and a contour's references) follow the estimated normal every this many control steps."""
CONTOUR_MAX_DEVIATION_RAD = math.radians(75.0)
"""How far a contour's CF z may turn from the taught one where the path is now: a cylinder found 8 cm higher than
taught, approached along the taught normal 50° from its top, is met on its side, 43° from that normal."""
CONTOUR_MAX_RATE_RAD_S = math.radians(90.0)
"""How fast a contour's CF z may turn (its taught frames turn at ~15°/s over an 8 cm cylinder, more on a smaller
one, on top of the correction)."""

ORIENTATION_RATE_RAD_S = math.radians(30.0)
"""How fast a contour's orientation reference turns with the followed frame on top of the taught turning."""

NEXT_SURFACE_FRACTION = 0.35
"""The tracked normal has turned this fraction of a crease's angle towards the next surface: the tool is on it
(measured on the 20° table-ramp crease met 2 cm late: a later switch, at half the angle, wedges the tool longer)."""
CREASE_TIME_CONSTANT_S = 0.05
CREASE_MAX_RATE_RAD_S = math.radians(120.0)
"""The normal estimate's low-pass and turn rate near a crease (``PhasePlan.quick_steps``): a 20° crease turned within
~0.2 s (the table-ramp crease met 2 cm after the taught one peaks at 14.6 % with these, 15.8 % with the slide's own
0.1 s and 60°/s). Everywhere else the slower ones: with a noisy sensor (up to 2 N) the quick ones cost a slide sweep 2
of 64 trials (its 95th-percentile RMS 3.1 % -> 7.5 %)."""
CREASE_RESPONSE = (CREASE_TIME_CONSTANT_S, CREASE_MAX_RATE_RAD_S)

_LINEAR = slice(REFERENCE_TWIST.start, REFERENCE_TWIST.start + 3)
_ANGULAR = slice(REFERENCE_TWIST.start + 3, REFERENCE_TWIST.stop)


def contour_tracker(z0: NDArray[np.float64], dt: float) -> SurfaceNormalTracker:
    """The normal tracker of a contact run on a contour: a first estimate while still, wider and faster bounds."""
    return SurfaceNormalTracker(
        z0,
        FOLLOW_PERIOD_STEPS * dt,
        max_rate_rad_s=CONTOUR_MAX_RATE_RAD_S,
        max_deviation_rad=CONTOUR_MAX_DEVIATION_RAD,
        static_estimate=True,
    )


def slide_tracker(z0: NDArray[np.float64], dt: float) -> SurfaceNormalTracker:
    """The normal tracker of a slide's contact run (sliding evidence only, the tracker's default response)."""
    return SurfaceNormalTracker(z0, FOLLOW_PERIOD_STEPS * dt)


class SurfaceFollower:
    """Turns one phase's control frame towards the tracked normal and, on a contour, rewrites its references.

    ``learned_rotations`` (M, 3, 3) the learned CF (world from CF) every ``stride`` steps of the phase (a slide or a
    hold: one); ``selection`` (6,) the phase's; ``references`` (n, REFERENCE_SIZE) the phase's reference rows,
    rewritten in place from the taught ones when ``moves_references`` (a contour); ``next_z`` (3,) the next contact
    segment's learned CF z when a crease follows (see :attr:`on_next_surface`); ``quick_steps`` (n,) per step whether
    it is near a crease, where the normal is followed with the quicker ``CREASE_*`` response; ``stiffness`` (M, 6) a
    gain schedule's CF stiffness every ``stride`` steps (``PhasePlan.stiffness``; None: the gains').
    """

    def __init__(
        self,
        tracker: SurfaceNormalTracker,
        controller: HybridController,
        selection: NDArray[np.float64],
        learned_rotations: NDArray[np.float64],
        stride: int,
        references: NDArray[np.float64],
        moves_references: bool,
        dt: float,
        next_z: NDArray[np.float64] | None = None,
        quick_steps: NDArray[np.bool_] | None = None,
        stiffness: NDArray[np.float64] | None = None,
    ) -> None:
        self.tracker = tracker
        self._controller = controller
        self._selection = selection
        self._rotations = learned_rotations
        self._stride = stride
        self._dt = dt
        self._next_z = next_z
        self._quick = quick_steps
        self._stiffness = stiffness
        self.on_next_surface = False
        """The tracked normal has turned past half-way from the learned z towards ``next_z``."""
        self._next_step = 0
        self._taught: tuple[NDArray[np.float64], ...] | None = None
        if moves_references:
            self._taught = (
                references[:, _LINEAR].copy(),
                references[:, _ANGULAR].copy(),
                references[:, REFERENCE_QUAT].copy(),
            )
            self._point = references[0, REFERENCE_POSITION].copy()
            self._orientation_turn = np.array([0.0, 0.0, 0.0, 1.0])
            """The turn applied to the taught orientation, following ``Δ`` at a bounded rate."""
            self._orientation_step = ORIENTATION_RATE_RAD_S * FOLLOW_PERIOD_STEPS * dt

    def _learned(self, k: int) -> NDArray[np.float64]:
        return self._rotations[min(k // self._stride, len(self._rotations) - 1)]

    def _frame(self, rotation: NDArray[np.float64], k: int) -> ControlFrame:
        """The control frame of CF ``rotation`` at step ``k``, with the gain schedule's stiffness there if any."""
        if self._stiffness is None:
            return self._controller.frame(rotation, self._selection)
        stiffness = self._stiffness[min(k // self._stride, len(self._stiffness) - 1)]
        return self._controller.frame(rotation, self._selection, stiffness=stiffness)

    def first_frame(self) -> ControlFrame:
        """The frame to start the phase with: the first learned CF turned to the normal tracked so far."""
        return self._frame(self.tracker.turned(self._learned(0)), 0)

    def due(self, k: int) -> bool:
        """Whether an update is due at step ``k`` (every ``FOLLOW_PERIOD_STEPS`` steps the phase advances)."""
        return k >= self._next_step

    def update(
        self,
        k: int,
        force: list[float],
        velocity: list[float],
        position: list[float],
        pressing: bool,
        references: NDArray[np.float64],
    ) -> ControlFrame:
        """After step ``k``: the applied force (3,) N, the tool velocity (3,) m/s and position (3,) m; ``pressing``
        the measured CF-z force says the tool presses. Returns the frame for the next steps; on a contour, rewrites
        ``references`` rows ``k + 1 ... k + FOLLOW_PERIOD_STEPS`` (the rows of the steps until the next update)."""
        self._next_step = k + FOLLOW_PERIOD_STEPS
        quick = self._quick is not None and bool(self._quick[min(k, len(self._quick) - 1)])
        self.tracker.respond(
            *((CREASE_TIME_CONSTANT_S, CREASE_MAX_RATE_RAD_S) if quick else self.tracker.base_response)
        )
        learned = self._learned(k)
        z_learned = learned[:, 2]
        z = self.tracker.update(force, velocity, z_learned)
        turn = rotation_from_vectors(z_learned, z)
        if self._next_z is not None:  # turned a fraction of the way from the learned z towards the next one
            turned = math.acos(min(1.0, float(z @ z_learned)))
            crease = math.acos(min(1.0, float(self._next_z @ z_learned)))
            nearer = z @ self._next_z > z_learned @ self._next_z
            self.on_next_surface = turned > NEXT_SURFACE_FRACTION * crease and nearer
        if self._taught is not None:
            rows = slice(k + 1, min(k + 1 + FOLLOW_PERIOD_STEPS, references.shape[0]))
            linear, angular, quats = (taught[rows] for taught in self._taught)
            if linear.shape[0]:
                if pressing:  # the reference stays on the tangent plane through the tool, where the surface is
                    self._point -= float((self._point - np.asarray(position)) @ z) * z
                v = linear @ turn.T
                steps = np.cumsum(np.vstack((np.zeros((1, 3)), v[:-1])), axis=0) * self._dt
                references[rows, REFERENCE_POSITION] = self._point + steps
                self._point = self._point + steps[-1] + v[-1] * self._dt
                references[rows, _LINEAR] = v
                references[rows, _ANGULAR] = angular @ turn.T
                self._orientation_turn = _quaternion_towards(
                    self._orientation_turn, quaternion_from_matrix(turn), self._orientation_step
                )
                references[rows, REFERENCE_QUAT] = quaternion_product(self._orientation_turn, quats)
        return self._frame(turn @ learned, k)


def _quaternion_towards(a: NDArray[np.float64], b: NDArray[np.float64], max_angle: float) -> NDArray[np.float64]:
    """Unit quaternion ``a`` turned towards ``b`` by a rotation of at most ``max_angle`` (rad), scalar-last."""
    dot = float(a @ b)
    if dot < 0.0:  # the same rotation, the shorter way
        b, dot = -b, -dot
    angle = 2.0 * math.acos(min(dot, 1.0))
    if angle <= max_angle:
        return b
    f = max_angle / angle
    half = angle / 2.0
    return (math.sin((1.0 - f) * half) * a + math.sin(f * half) * b) / math.sin(half)


def run_tracker(geometry: ContactGeometry, dt: float) -> SurfaceNormalTracker:
    """The normal tracker of a contact run that starts on the contact segment of ``geometry``, from its first
    learned CF z: a contour's (several frames) or a slide's (one); control step ``dt``, s."""
    track = contour_tracker if geometry.t.size > 1 else slide_tracker
    return track(geometry.first_rotation[:, 2], dt)


def phase_follower(
    plan: PhasePlan,
    references: NDArray[np.float64],
    tracker: SurfaceNormalTracker | None,
    controller: HybridController,
    selections: dict[int, NDArray[np.float64]],
    dt: float,
) -> SurfaceFollower | None:
    """The follower of a phase that follows the surface found (``plan.follows_surface``), on the run's ``tracker``
    (None: no contact run tracked yet), its frames built by ``controller`` with the selection of the plan's segment
    (``selections`` by segment index), control step ``dt`` (s); a contour's contact phase has its ``references``
    rewritten too. None for every other phase."""
    if not plan.follows_surface or tracker is None:
        return None
    contour = plan.learned_rotations is not None
    rotations = plan.learned_rotations if contour else plan.frame.cf_rotation[None]
    return SurfaceFollower(
        tracker,
        controller,
        selections[plan.segment],
        rotations,
        plan.stride,
        references,
        contour and plan.phase is ExecutionPhase.contact,
        dt,
        plan.next_z,
        plan.quick_steps,
        plan.stiffness,
    )


def relocation_offset(
    normals: NDArray[np.float64],
    path_m: NDArray[np.float64],
    pressing: NDArray[np.float64],
    tool_m: NDArray[np.float64],
    cone_rad: float,
) -> NDArray[np.float64] | None:
    """How far a contour's part moved, from one touch-down: ``normals`` (K, 3) the taught CF z at K places evenly
    along the path, ``path_m`` (N, 3) the taught tool path (m, world, as planned), ``pressing`` (3,) the unit direction
    the tool presses in at the touch-down (the normal lies within ``cone_rad``, the friction angle, of it), ``tool_m``
    (3,) where the tool is. When ``pressing`` is farther than ``cone_rad`` from the normal at the path's start and
    within it of the normal at another place ``s*``, the tool touched the part there: it moved by
    ``tool - path(s*)`` (the same tool point on a part that translated), projected on the plane of the path and the
    normal at ``s*`` (across it, along a cylinder's axis, every place looks the same: taken as not moved that way).
    None otherwise (the start, or no taught normal like it)."""
    match = normals @ pressing
    best = int(np.argmax(match))
    cone = math.cos(cone_rad)
    if best == 0 or match[best] < cone or match[0] >= cone:
        return None
    k = min(round(best / (len(normals) - 1) * (len(path_m) - 1)), len(path_m) - 2)
    shift = tool_m - path_m[k]
    across = np.cross(path_m[k + 1] - path_m[k], normals[best])
    if np.linalg.norm(across) > 0.0:
        across /= np.linalg.norm(across)
        shift -= (shift @ across) * across
    return shift
