"""How long an execution of a skill runs, from the skill and ALL its execution settings (``schemas.job_budget``).

The phases follow ``execution.executor``: the settle at the start pose (with the tare's hold), then per segment a
free motion, or before a contact run the tare's hold, the guarded approach (at ``approach_speed_m_s`` until
``approach_slow_distance_m`` before the taught contact point, then at the touch-down speed), the force ramp, the
contact segments, the force release and the lift-off. Each guarded approach is counted until the surface at the far
end of its expected window (``tolerances.surface_window_m``); its references are allocated for its whole
``approach_max_distance_m``, the job's longest phase. A default touch-down speed depends on the world's pad and
the arm's pose (the worker's business): it is counted at its slowest, :data:`TOUCHDOWN_SPEED_MIN_M_S`. Not counted,
and cut by the worker's step budget at run time: pauses, creases passed slowly (or a crease found later than taught,
followed to it), a surface found beyond its window, a contour relocated where its part was found
(``follow_surface_normal``: a second touch, then one more retract, transfer and approach).
"""

from __future__ import annotations

from schemas.execution import ExecutionSettings, SensorChoice, TelemetryMode
from schemas.job_budget import NOMINAL_TIME_STEP_S, JobEstimate, JobPart
from schemas.skill import SegmentKind, Skill

TARE_HOLD_S = 0.2
"""With ``tare_sensor``, the tool holds still this long in free space (the start pose's settle, the pre-contact point
before each later guarded approach) and the wrist sensor is tared with its mean reading over the last
``execution.tare.TARE_AVERAGE_S``, s. The executor's and the estimate's."""
TOUCHDOWN_SPEED_MIN_M_S = 0.0005
"""The slowest touch-down, m/s (a 5 N skill on a 1e6 N/m surface would ask for less). The executor's and the
estimate's."""
LIFT_OFF_M = 0.02
"""After a contact run the tool lifts off this far along the normal it pressed along, before its way out, m. The
executor's and the estimate's."""
LIFT_OFF_S = 0.5
"""... over this long, s."""
SURFACE_WINDOW_MIN_M = 0.005
"""The window around the taught surface where a guarded approach expects it is at least this wide each way, m. The
executor's and the estimate's."""


def surface_window_m(settings: ExecutionSettings) -> float:
    """How far from where it was taught a guarded approach may find the surface, m (either way along CF z): the
    settings' tolerance, else the slow stretch of the approach (at least ``SURFACE_WINDOW_MIN_M``)."""
    window = settings.tolerances.surface_window_m
    return window if window is not None else max(settings.approach_slow_distance_m, SURFACE_WINDOW_MIN_M)


def taught_time_step_s(skill: Skill) -> float:
    """The control step of the world the skill was taught in (``taught_world``, or its ``world_config``), s; the
    nominal step for a skill without one."""
    world = skill.taught_world or {}
    world = world["world_config"] if isinstance(world.get("world_config"), dict) else world
    step = world.get("time_step_s")
    return float(step) if isinstance(step, int | float) and step > 0 else NOMINAL_TIME_STEP_S


def stored_telemetry_bytes(skill: Skill, settings: ExecutionSettings) -> int:
    """The telemetry an execution of ``skill`` with ``settings`` streams for the API to store, bytes: its estimate's
    at the taught control step (an upper bound: the store compresses it); 0 with ``telemetry`` ``none``."""
    if settings.telemetry is TelemetryMode.none:
        return 0
    return execution_estimate(skill, settings, taught_time_step_s(skill)).telemetry_bytes


def execution_estimate(skill: Skill, settings: ExecutionSettings, time_step_s: float) -> JobEstimate:
    """What running ``skill`` with ``settings`` at a control step of ``time_step_s`` (s) implies (see the module
    docstring); the parts name the request fields that set their lengths (``skill`` for its segments and its time
    step)."""
    s = settings
    tares = s.tare_sensor and s.environment.sensor is not SensorChoice.ideal
    settle = max(s.settle_s, TARE_HOLD_S) if tares else s.settle_s
    parts = [JobPart(what=f"the settle at the start pose ({settle:g} s)", field="settle_s", simulated_s=settle)]
    approaches: list[JobPart] = []
    in_contact_run = False
    segments = skill.segments
    for i, segment in enumerate(segments):
        duration = segment.position_dmp.duration_s
        kind = segment.kind.value
        if segment.kind is SegmentKind.contact and not in_contact_run:
            if tares and i > 0:
                parts.append(JobPart(what="the tare's hold", field="tare_sensor", simulated_s=TARE_HOLD_S))
            fast, slow, whole = _approach(i, s)
            parts += [fast, slow]
            approaches.append(whole)
            ramp = s.gains.force_ramp_s
            parts.append(JobPart(what=f"the force ramp ({ramp:g} s)", field="gains.force_ramp_s", simulated_s=ramp))
        parts.append(JobPart(what=f"segment {i} ({kind}, {duration:g} s)", field="skill", simulated_s=duration))
        in_contact_run = segment.kind is SegmentKind.contact
        following = segments[i + 1] if i + 1 < len(segments) else None
        if in_contact_run and (following is None or following.kind is SegmentKind.free):
            release = s.gains.force_release_s
            part = JobPart(
                what=f"the force release ({release:g} s)", field="gains.force_release_s", simulated_s=release
            )
            parts.append(part)
            parts.append(JobPart(what=f"the lift-off ({LIFT_OFF_S:g} s)", field="skill", simulated_s=LIFT_OFF_S))
            in_contact_run = False
    return JobEstimate(
        kind="execution",
        time_step_s=time_step_s,
        time_step_field="skill",
        parts=parts,
        longest_phase=max([*parts, *approaches], key=lambda part: part.simulated_s),
    )


def _approach(segment: int, s: ExecutionSettings) -> tuple[JobPart, JobPart, JobPart]:
    """The guarded approach before contact segment ``segment``: its fast stretch, its slow stretch until the surface
    at the far end of its window, and the whole approach over ``approach_max_distance_m`` (its references), each
    named by the field of its speed."""
    fast_m = min(max(s.approach_clearance_m - s.approach_slow_distance_m, 0.0), s.approach_max_distance_m)
    window = surface_window_m(s)
    slow_m = min(s.approach_clearance_m - fast_m + window, s.approach_max_distance_m - fast_m)
    whole_m = s.approach_max_distance_m - fast_m
    touchdown = s.touchdown_speed_m_s or TOUCHDOWN_SPEED_MIN_M_S
    slow_speed = min(touchdown, s.approach_speed_m_s)
    if s.approach_speed_m_s < touchdown:  # the touch-down speed never exceeds the approach speed
        slow_field, slow = "approach_speed_m_s", f"approach_speed_m_s {slow_speed:g} m/s"
    else:
        default = "" if s.touchdown_speed_m_s else " (the slowest default)"
        slow_field, slow = "touchdown_speed_m_s", f"touchdown_speed_m_s {slow_speed:g} m/s{default}"
    fast_s = fast_m / s.approach_speed_m_s
    where = f"the guarded approach of segment {segment}"
    return (
        JobPart(
            what=f"{where}, {fast_m:g} m at approach_speed_m_s {s.approach_speed_m_s:g} m/s,",
            field="approach_speed_m_s",
            simulated_s=fast_s,
        ),
        JobPart(what=f"{where}, {slow_m:g} m at {slow},", field=slow_field, simulated_s=slow_m / slow_speed),
        JobPart(
            what=f"{where} (approach_max_distance_m {s.approach_max_distance_m:g} m: {fast_m:g} m at "
            f"approach_speed_m_s {s.approach_speed_m_s:g} m/s, then {whole_m:g} m at {slow})",
            field=slow_field,
            simulated_s=fast_s + whole_m / slow_speed,
        ),
    )
