"""The shared core of every importer (``services.csv_import``, ``services.bag_import``): a recording on its uniform
time grid becomes a validated `schemas.Demonstration` in the project's conventions (docs/CONVENTIONS.md), with the
same steps, notes and errors whatever the file was.

:func:`demonstration_from_samples`, in order: an offset the user gave (``force_offset``) or named by a quiet window
(``tare_window_s``) is subtracted in the file's own frame and sign; a TOOL-frame wrench is rotated into the world
with the tool orientation; a ``measured-on-tool`` wrench is negated; otherwise, with ``tare``, contact is found from
force and kinematics (`skills.contact`) and the sensor offset is fitted in the sensor (tool) frame over every
free-space stretch with the hand's push on the arm (`skills.tare`) and removed; the result is validated. Also here:
the error every importer raises (:class:`DemonstrationImportError`, one problem per line) and the rate options
(:func:`sampling_rate_hz`). Which importer reads a file: ``services.importing``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from pydantic import ValidationError

from schemas import Demonstration, DemonstrationMetadata, QuaternionOrder, TareMethod, WrenchConvention, WrenchFrame
from schemas.demonstration import MIN_DEMONSTRATION_SAMPLES
from schemas.import_options import PLAUSIBLE_READINGS, ImportOptions
from skills import preprocess, recording_faults
from skills import tare as tare_module
from skills.compliant_frames import tool_velocities
from skills.parameterize import MAX_RATE_HZ, learn_skill
from skills.quaternions import matrix_from_quaternion

MAX_PROBLEMS_LISTED = 10
"""At most this many problems are listed in one error (the count of the rest is given)."""


class DemonstrationImportError(ValueError):
    """A demonstration file could not be imported; ``problems`` holds one human-readable line per problem."""

    def __init__(self, problems: str | Iterable[str]) -> None:
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        if len(self.problems) > MAX_PROBLEMS_LISTED:
            more = len(self.problems) - MAX_PROBLEMS_LISTED
            self.problems = [*self.problems[:MAX_PROBLEMS_LISTED], f"... and {more} more problems"]
        super().__init__("\n".join(self.problems))


RATE_DT_AGREEMENT = 1e-6
"""Relative tolerance within which a rate and a dt given together count as the same (``rate * dt == 1``)."""


def sampling_rate_hz(
    rate_hz: float | None,
    dt_s: float | None = None,
    error: type[DemonstrationImportError] = DemonstrationImportError,
) -> float | None:
    """Return the rate (Hz) given as ``rate_hz`` or as a time step ``dt_s`` (s), or None if neither is given.

    Both may be given if they agree (``rate_hz * dt_s`` = 1 within :data:`RATE_DT_AGREEMENT`).
    Raises ``error`` for a value that is not a positive finite number, a rate above
    :data:`MAX_RATE_HZ` (a dt below its inverse), or a rate and a dt that disagree.
    """
    problems = []
    if rate_hz is not None and not (np.isfinite(rate_hz) and 0 < rate_hz <= MAX_RATE_HZ):
        problems.append(f"rate: {rate_hz} Hz is not a rate in (0, {MAX_RATE_HZ:g}] Hz")
    if dt_s is not None and not (np.isfinite(dt_s) and dt_s >= 1.0 / MAX_RATE_HZ):
        problems.append(f"dt: {dt_s} s is not a positive time step of at least {1.0 / MAX_RATE_HZ:g} s")
    if problems:
        raise error(problems)
    if rate_hz is not None and dt_s is not None:
        if abs(rate_hz * dt_s - 1.0) > RATE_DT_AGREEMENT:
            raise error(
                f"rate and dt disagree: rate {rate_hz:g} Hz is a step of {1.0 / rate_hz:g} s, dt {dt_s:g} s "
                f"is {1.0 / dt_s:g} Hz; give one of them"
            )
        return float(rate_hz)
    if dt_s is not None:
        return 1.0 / float(dt_s)
    return None if rate_hz is None else float(rate_hz)


def demonstration_from_samples(
    recording: RecordingSamples,
    options: ImportOptions,
    *,
    wrench_frame: WrenchFrame,
    metadata: DemonstrationMetadata,
    extra: dict[str, object] | None = None,
    notes: Sequence[str] = (),
    error: type[DemonstrationImportError] = DemonstrationImportError,
) -> Demonstration:
    """The shared last steps of every importer (CSV, ROS 1 and ROS 2 bags): a recording on its time grid -> a
    validated `schemas.Demonstration` in the project's conventions.

    ``recording`` holds the file's wrench at the tool point (N, N·m) in ``wrench_frame`` (the frame the importer
    resolved: the option, a CSV file's default, a bag's header) and in ``options.wrench_convention``. In order: a
    given offset (``options.force_offset``) or a quiet window's median (``options.tare_window_s``, s) is subtracted
    in the file's own frame and sign; a TOOL-frame wrench is rotated into the world with the tool orientation; a
    ``measured-on-tool`` wrench is negated; otherwise with ``options.tare`` the sensor offset is fitted in the tool
    frame over every free-space stretch and removed. ``metadata`` gives the name, source and quaternion order; the
    conventions, rate, offset and ``extra`` (plus ``import_notes``: ``recording.notes``, then ``notes``, then one
    line per step, and ``tare``) are filled in here. Every problem raises ``error`` (naming the option or field and
    the reason).
    """
    frame, convention, tare = wrench_frame, options.wrench_convention, options.tare
    notes = [*recording.notes, *notes]
    wrenches, spikes = preprocess.despiked(recording.wrenches)
    if spikes:
        notes.append(
            f"{spikes} single-sample spike(s) in the wrench (a sample far off its neighbours while they agree) "
            "replaced by the median of their neighbours"
        )
    given = _given_offset(recording, options.tare_window_s, options.force_offset, error)
    if given is not None:
        wrenches = wrenches - given.offset
    if frame == WrenchFrame.tool:
        wrenches = preprocess.wrenches_tool_to_world(wrenches, recording.orientations)
        notes.append("wrench given in the tool frame: rotated into the world with the interpolated tool orientation")
    if convention == WrenchConvention.measured_on_tool:
        wrenches = preprocess.wrenches_applied_by_tool(wrenches)
        notes.append("wrench measured on the tool: negated to the wrench the tool applies")
    offset, offset_frame, uncertainty, tare_report = None, None, None, {"method": "none"}
    world_force, method = None, TareMethod.off
    if given is not None:
        offset, offset_frame, tare_report = given.offset, frame.value, {"method": given.method}
        method = TareMethod.given
        notes.append(given.note)
    elif tare:
        estimate = (
            tare_module.fitted_sensor_offset(recording.t, recording.positions, recording.orientations, wrenches)
            if recording.t.size >= MIN_DEMONSTRATION_SAMPLES
            else None
        )
        if estimate is None:
            method = TareMethod.impossible
            notes.append(
                f"no free-space part of at least {tare_module.MIN_FREE_S} s found: no sensor offset removed, and any "
                "offset or uncompensated tool weight stays in the forces (the skill's sensor_offset check fails; "
                "--no-tare if the file is already compensated, --tare-window or --force-offset set one)"
            )
        else:
            method = TareMethod.free_space
            wrenches = estimate.removed_from(recording.orientations, wrenches)
            sign = -1.0 if convention == WrenchConvention.measured_on_tool else 1.0
            offset, offset_frame, uncertainty = sign * estimate.wrench, "tool", estimate.uncertainty_n
            world_force = estimate.world_force
            notes.append(_tare_note(estimate, offset))
            tare_report = {
                "method": "free-space fit",
                "stretches_s": [list(s) for s in estimate.stretches],
                "samples": estimate.samples,
                "uncertainty_n": estimate.uncertainty_n,
                "arm_damping_n_s_m": estimate.arm_damping_n_s_m,
                "arm_mass_kg": estimate.arm_mass_kg,
                "arm_friction_n": estimate.arm_friction_n,
                "orientation_span_deg": estimate.orientation_span_deg,
                "world_force_n": None if world_force is None else world_force.tolist(),
                "tool_mass_kg": estimate.tool_mass_kg,
                "world_force_centre_m": None
                if estimate.world_force_centre is None
                else estimate.world_force_centre.tolist(),
            }
    else:
        notes.append("tare off: no sensor offset removed (the file is taken as compensated)")
    hint, readings = _direction_hint(recording, wrenches, options, frame, metadata.quaternion_order_on_import)
    notes.extend(hint)
    if recording.t.size < MIN_DEMONSTRATION_SAMPLES:
        remedy = "record longer" if recording.fixed_rate else "record longer, or pass a higher rate"
        raise error(
            f"too few samples: {recording.t.size} at {recording.rate_hz:g} Hz over {np.ptp(recording.t):.3g} s, "
            f"at least {MIN_DEMONSTRATION_SAMPLES} are needed ({remedy})"
        )
    metadata = metadata.model_copy(
        update={
            "wrench_convention_on_import": convention,
            "wrench_frame_on_import": frame,
            "resampled_rate_hz": None if recording.fixed_rate else recording.rate_hz,
            "force_offset_removed": None if offset is None else offset.tolist(),
            "force_offset_frame": offset_frame,
            "force_offset_uncertainty_n": uncertainty,
            "world_force_removed": None if world_force is None else world_force.tolist(),
            "tare": method,
            "unmeasured_intervals_s": [] if recording.unmeasured_s is None else recording.unmeasured_s.tolist(),
            "extra": {
                **metadata.extra,
                "import_notes": notes,
                **(extra or {}),
                "tare": tare_report,
                **({PLAUSIBLE_READINGS: readings} if readings else {}),
            },
        }
    )
    try:
        return Demonstration.from_arrays(recording.t, recording.positions, recording.orientations, wrenches, metadata)
    except ValidationError as exc:
        raise error(validation_problems(exc)) from None


def _tare_note(estimate: tare_module.SensorOffset, offset: np.ndarray) -> str:
    """The import note of a free-space tare: the offset as the file reads it (``offset`` (6,), sensor frame), its
    uncertainty, where it was fitted, the hand's push and, where told apart, the force constant in the world."""
    where = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in estimate.stretches[:6])
    more = f" and {len(estimate.stretches) - 6} more" if len(estimate.stretches) > 6 else ""
    force = ", ".join(f"{v:+.2f}" for v in offset[:3])
    note = (
        f"sensor offset removed: [{force}] N (±{estimate.uncertainty_n:.2f} N) in the sensor (tool) frame as the file "
        f"reads it, fitted over {estimate.samples} free-space samples ({where}{more}) with the hand's push on the arm "
        f"(damping {estimate.arm_damping_n_s_m:.1f} N·s/m, mass {estimate.arm_mass_kg:.1f} kg, friction "
        f"{estimate.arm_friction_n:.1f} N)"
    )
    if estimate.world_force is None:
        return (
            note + f"; the tool was held within {estimate.orientation_span_deg:.0f} deg in free space, too little to "
            "tell a tool's weight from the offset"
        )
    shown = ", ".join(f"{v:+.2f}" for v in estimate.world_force)
    note += f", and a force constant in the world removed with it: [{shown}] N (applied by the tool)"
    mass = estimate.tool_mass_kg
    if mass is not None and mass > 0.05 and estimate.world_force[2] > 0.8 * np.linalg.norm(estimate.world_force):
        centre = estimate.world_force_centre
        at = "" if centre is None else f", its centre {1000 * centre[2]:+.0f} mm along the tool z from the tool point"
        note += f": an uncompensated tool weight of {mass:.2f} kg{at}"
    return note


@dataclass(frozen=True)
class _GivenOffset:
    """An offset the user gave (or a window they named), in the file's frame and sign: (6,) N, N·m."""

    offset: np.ndarray
    method: str
    note: str


def _given_offset(
    recording: RecordingSamples,
    tare_window_s: tuple[float, float] | None,
    force_offset: Sequence[float] | None,
    error: type[DemonstrationImportError],
) -> _GivenOffset | None:
    """Return the offset the options ask for (``--force-offset`` or ``--tare-window``), or None; else ``error``."""
    if tare_window_s is not None and force_offset is not None:
        raise error("tare: give either a tare window or a force offset, not both")
    if force_offset is not None:
        values = np.asarray(force_offset, dtype=float)
        if values.shape not in ((3,), (6,)) or not np.all(np.isfinite(values)):
            raise error(f"force offset: 3 forces (N) or 6 values with moments (N·m) are needed, got {values}")
        offset = np.concatenate([values, np.zeros(6 - values.size)])
        shown = ", ".join(f"{v:+.2f}" for v in offset[:3])
        return _GivenOffset(offset, "given", f"sensor offset removed as given: [{shown}] N in the file's frame")
    if tare_window_s is None:
        return None
    t0, t1 = (float(v) for v in tare_window_s)
    inside = (recording.t >= t0) & (recording.t <= t1)
    if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0) or inside.sum() < 2:
        raise error(
            f"tare window: {t0:g}-{t1:g} s holds {int(inside.sum())} samples; the recording runs "
            f"{recording.t[0]:g}-{recording.t[-1]:g} s and the window needs at least 2 of them"
        )
    offset = np.median(recording.wrenches[inside], axis=0)
    shown = ", ".join(f"{v:+.2f}" for v in offset[:3])
    note = f"sensor offset removed: [{shown}] N, median of the file's wrench over the tare window {t0:g}-{t1:g} s"
    return _GivenOffset(offset, "window", note)


@dataclass(frozen=True)
class RecordingSamples:
    """A recording on its uniform time grid (what the steps after the time step need): ``t`` (N,) s, ``positions``
    (N, 3) m, ``orientations`` (N, 4), ``wrenches`` (N, 6) N and N·m as the file holds them, ``rate_hz``, the
    notes of the time step."""

    t: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    """Unit, scalar-last, sign-continuous."""
    wrenches: np.ndarray
    rate_hz: float
    notes: list[str]
    fixed_rate: bool = False
    """True: the rows were taken as samples at a given rate (no time column), not resampled."""
    unmeasured_s: np.ndarray | None = None
    """(K, 2) start and end, s on ``t``'s axis, of the gaps in the measurements the grid interpolates over."""


def _direction_hint(
    recording: RecordingSamples,
    wrenches: np.ndarray,
    options: ImportOptions,
    frame: WrenchFrame,
    order: QuaternionOrder,
) -> tuple[list[str], list[dict[str, str]]]:
    """A note when the applied force (``wrenches``: world, applied by the tool, as imported) points UP in the world
    (`skills.recording_faults.press_elevation_deg` above ``UPWARD_PRESS_LIMIT_DEG``): pressing on a table, a part or
    a wall points down or sideways. Not an error (work done from below is possible), but a reaction read as
    applied-by-tool, a tool-frame wrench read as a world one or the reverse, and a tool-frame wrench turned with
    quaternions read in the other ``order`` all look like this, and can still learn a skill that passes every check
    but the skill's own ``press_direction``. The note says which other readings of the file (sign, frame, quaternion
    order, and the sign with either) press down (as far below the horizontal as the limit is above) AND lean towards
    the tool's motion as friction makes it (`skills.recording_faults.leans_with_friction`, over the stronger half of
    the samples) AND learn a skill that passes every check (`_failed_checks_read_so`: a reading is advised only when
    learning with it is tried first and clean), with their numbers: the one to import it with, unless the tool worked
    from below. Several may: a tool held straight down looks alike in both quaternion orders. Judged on the wrench as
    tared (an uncompensated tool weight, which reads as a force UP, is gone where the free space showed it). Returns
    the note (none, or one) and the readings it advises as import options (form names and values: what to import it
    with).
    """
    forces = wrenches[:, :3]
    elevation = recording_faults.press_elevation_deg(forces)
    if elevation <= recording_faults.UPWARD_PRESS_LIMIT_DEG:
        return [], []
    magnitude = np.linalg.norm(forces, axis=1)
    pressed = magnitude >= np.median(magnitude)  # where the tool presses: the lean of free space's noise says nothing
    velocities = tool_velocities(recording.positions, recording.rate_hz)[pressed]
    readings = _other_readings(forces, recording.orientations, options.wrench_convention, frame, order)
    sentences, advised = [], []
    for reading, alternative in readings:
        down = recording_faults.press_elevation_deg(alternative)
        lean, samples = recording_faults.median_friction_lean(alternative[pressed], velocities)
        if down < -recording_faults.UPWARD_PRESS_LIMIT_DEG and recording_faults.leans_with_friction(lean):
            failed = _failed_checks_read_so(recording, alternative)
            if failed:
                continue  # it presses down, but the skill learned so would still be warned: no advice to give
            advised.append(reading)
            sentences.append(
                f"read with {reading_flags(reading)} it presses {-down:.0f} deg below the horizontal, "
                + recording_faults.lean_sentence(lean, samples).removeprefix("the applied force ")
                + ", and the skill learned so passes every check"
            )
    found = (
        "; ".join(sentences) + ": import it so unless the tool worked from below"
        if sentences
        else "no other reading of its sign, frame or quaternion order learns a skill that presses down and passes "
        "every check (an uncompensated tool weight, which reads as a force UP, needs free space in a few "
        "orientations to be removed)"
    )
    return [
        f"check how the wrench is read: the force the tool applies points {elevation:.0f} deg above the horizontal in "
        f"the world, where pressing on a table, a part or a wall points down or sideways; {found}"
    ], advised


HINT_SAMPLES = 20_000
"""Most samples a reading the import's note tries is learned from (`_failed_checks_read_so`)."""


def _failed_checks_read_so(recording: RecordingSamples, forces: np.ndarray) -> list[str]:
    """The checks a skill learned from ``recording`` with its forces read as ``forces`` (N, 3) N (world, applied by
    the tool) fails (``["no skill"]`` when none can be learned): a reading is advised only when learning with it
    passes every check."""
    wrenches = np.concatenate([forces, np.zeros_like(forces)], axis=1)
    # Learning each reading is the import's work: on a long recording it is done on every k-th sample (the checks
    # judge directions and shares, which a 20 000-sample copy shows as well), so the note costs a bounded time.
    step = -(-recording.t.size // HINT_SAMPLES)
    try:
        demonstration = Demonstration.from_arrays(
            recording.t[::step], recording.positions[::step], recording.orientations[::step], wrenches[::step]
        )
        skill = learn_skill(demonstration)
    except (ValueError, ValidationError):
        return ["no skill"]
    return [check.name.value for check in skill.checks if not check.passed]


def _other_readings(
    forces: np.ndarray,
    orientations: np.ndarray,
    convention: WrenchConvention,
    frame: WrenchFrame,
    order: QuaternionOrder,
) -> list[tuple[dict[str, str], np.ndarray]]:
    """The other readings of a file's forces as the import would turn them (world, applied by the tool) from
    ``forces`` (N, 3) N as it turned them, each with the import options that give it (form names and values, as
    :func:`reading_flags` prints them): the other sign; the other frame (tool <-> world: ``orientations`` (N, 4) turn
    them); for a tool-frame wrench, the quaternions in the other component order (``order`` is the one read); and the
    other sign with each of those."""
    flip = "measured-on-tool" if convention == WrenchConvention.applied_by_tool else "applied-by-tool"
    R = matrix_from_quaternion(orientations)
    others: list[tuple[dict[str, str], np.ndarray]]
    if frame == WrenchFrame.world:
        others = [({"wrench_frame": WrenchFrame.tool.value}, np.einsum("nij,nj->ni", R, forces))]
    else:
        in_tool = np.einsum("nji,nj->ni", R, forces)
        other = QuaternionOrder.wxyz if order == QuaternionOrder.xyzw else QuaternionOrder.xyzw
        # The file's components, read in the other order: scalar-last as read -> rolled one place either way.
        reordered = np.roll(orientations, -1 if other == QuaternionOrder.wxyz else 1, axis=1)
        others = [
            ({"wrench_frame": WrenchFrame.world.value}, in_tool),
            (
                {"quaternion_order": other.value},
                np.einsum("nij,nj->ni", matrix_from_quaternion(reordered), in_tool),
            ),
        ]
    signed = [({"wrench": flip, **options}, -alternative) for options, alternative in others]
    return [({"wrench": flip}, -forces), *others, *signed]


def reading_flags(reading: dict[str, str]) -> str:
    """A reading's import options as ``contact-skills learn`` flags (``{"wrench_frame": "tool"}``: ``--wrench-frame
    tool``); a quaternion order names ``--columns`` too, which named quaternion columns need instead."""
    parts = [f"--{name.replace('_', '-')} {value}" for name, value in reading.items()]
    return " ".join(part + (" (--columns for named ones)" if "quaternion" in part else "") for part in parts)


def validation_problems(exc: ValidationError) -> list[str]:
    """One line per pydantic validation error: ``field.path: message``."""
    problems = []
    for error in exc.errors():
        location = ".".join(str(part) for part in error["loc"]) or "demonstration"
        message = error["msg"].removeprefix("Value error, ")
        problems.append(f"{location}: {message}")
    return problems


__all__ = [
    "DemonstrationImportError",
    "RecordingSamples",
    "demonstration_from_samples",
    "sampling_rate_hz",
    "validation_problems",
]
