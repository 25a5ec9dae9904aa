"""A fast teacher stroke on both engines (issue 44, docs/ENGINES.md, *A fast stroke*): the teacher's ``slide_flat``
(seed 0) taught in 2 s and in 1 s instead of its 5 s, learned as a slide, executed with the default execution
settings on PyBullet and on MuJoCo, and the telemetry's signature of why they differ: how far the tool rides up
while it slides fast (MuJoCo's soft friction lifts it by ``μ c v / k``), how far the friction points from the slip
(PyBullet's fixed friction directions), how far that tilts the surface follower's normal estimate, and when the
second contact segment starts.

Reproduce: ``nice -n 10 .venv/bin/python -m experiments.fast_stroke`` (about a minute on one core).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from execution.telemetry import Telemetry
from schemas.execution import PHASE_CODES, Engine, ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.skill import LearnOptions
from schemas.world import WorldConfig
from sim_worker.execution_world import execution_world
from sim_worker.executor import run_skill
from sim_worker.teacher import record_demonstration
from skills.parameterize import learn_skill

STROKES_S = (2.0, 1.0)
"""The teacher's ``move_duration_s`` of the strokes run (its default is 5 s)."""
FAST_SLIP_M_S = 0.15
"""A contact step slides fast above this slip speed (m/s): the rise is the median over those steps."""
SLIDING_M_S = 0.002
"""A contact step slides above this slip speed (m/s) (the surface follower's evidence of the friction's direction)."""


@dataclass(frozen=True)
class StrokeSignature:
    """One stroke on one engine: the metrics, the contact steps without contact, the tool's rise while sliding fast
    above where it presses still (m, positive up), the median slip speed of those steps (m/s), the friction's median
    angle from the slip (°, the sensor's wrench) and the median tilt of the normal estimated as the force without its
    part along the slip (°, from vertical: the table is flat), both over the first contact segment, and when the
    second contact segment starts after the contact phase does (s; None: it does not)."""

    metrics: ExecutionMetrics
    lost_steps: int
    fast_rise_m: float
    fast_slip_m_s: float
    friction_off_slip_deg: float
    normal_tilt_deg: float
    second_segment_s: float | None


def signature(telemetry: Telemetry, metrics: ExecutionMetrics) -> StrokeSignature:
    """The :class:`StrokeSignature` of a slide's ``telemetry`` on the flat table (world frame, 1 kHz rows)."""
    t = telemetry.t
    contact = telemetry.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    position = telemetry.tool_position
    velocity = np.gradient(position, t, axis=0)
    slip = velocity.copy()
    slip[:, 2] = 0.0
    speed = np.linalg.norm(slip, axis=1)
    still_z = float(np.median(position[contact & (speed < 1e-3), 2]))
    fast = contact & (speed > FAST_SLIP_M_S)
    first = contact & (telemetry.segment_index == telemetry.segment_index[contact][0])
    sliding = first & (speed > SLIDING_M_S)
    direction = slip[sliding] / speed[sliding, None]
    force = telemetry.wrench_world[sliding, :3]  # applied BY the tool: friction along the slip, normal down
    friction = force[:, :2]
    off = np.sum(friction * direction[:, :2], axis=1) / np.linalg.norm(friction, axis=1)
    normal = force - np.sum(force * direction, axis=1)[:, None] * direction
    tilt = -normal[:, 2] / np.linalg.norm(normal, axis=1)
    segments = telemetry.segment_index[contact]
    switch = np.flatnonzero(np.diff(segments) != 0)
    return StrokeSignature(
        metrics,
        int(np.count_nonzero(contact & ~telemetry.in_contact)),
        float(np.median(position[fast, 2]) - still_z) if fast.any() else 0.0,
        float(np.median(speed[fast])) if fast.any() else 0.0,
        float(np.degrees(np.median(np.arccos(np.clip(off, -1.0, 1.0))))),
        float(np.degrees(np.median(np.arccos(np.clip(tilt, -1.0, 1.0))))),
        float(t[contact][switch[0] + 1] - t[contact][0]) if switch.size else None,
    )


def stroke_signature(move_duration_s: float, engine: Engine) -> StrokeSignature:
    """Teach ``slide_flat`` (seed 0) in ``move_duration_s``, learn it as a slide, execute it on ``engine`` (default
    settings otherwise, pace fast) and return its :class:`StrokeSignature`."""
    recording = record_demonstration("slide_flat", seed=0, move_duration_s=move_duration_s)
    skill = learn_skill(recording.demonstration, LearnOptions(skill_type="slide"))
    settings = ExecutionSettings(engine=engine, pace="fast")
    result = run_skill(execution_world(skill, settings.environment, demonstration=recording.demonstration), settings)
    return signature(result.telemetry, result.metrics)


def lift_m(slip_m_s: float, config: WorldConfig) -> float:
    """How far MuJoCo's soft friction lifts a tool sliding at ``slip_m_s`` (m/s) out of its pad's compression (m):
    ``μ c v / k`` (docs/ENGINES.md, *A fast stroke*)."""
    contact = config.contact
    return contact.lateral_friction * contact.damping_n_s_m * slip_m_s / contact.stiffness_n_m


def fast_stroke_table() -> list[str]:
    """The markdown rows of every stroke of :data:`STROKES_S` on both engines."""
    config = WorldConfig()
    lines = [
        "| stroke | engine | true RMS (%) | true max (%) | contact (%) | steps lost | slip (mm/s) | rise (mm) | "
        "μ c v / k (mm) | friction off slip (°) | normal estimate tilt (°) | 2nd segment after (s) |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for duration in STROKES_S:
        for engine in (Engine.pybullet, Engine.mujoco):
            s = stroke_signature(duration, engine)
            m = s.metrics
            second = "—" if s.second_segment_s is None else f"{s.second_segment_s:.2f}"
            lines.append(
                f"| {duration:g} s | {engine.value} | {m.true_force_rms_error_pct:.2f} | "
                f"{m.true_force_max_error_pct:.1f} | {100.0 * m.contact_ratio:.2f} | {s.lost_steps} | "
                f"{1e3 * s.fast_slip_m_s:.0f} | {1e3 * s.fast_rise_m:.3f} | "
                f"{1e3 * lift_m(s.fast_slip_m_s, config):.3f} | "
                f"{s.friction_off_slip_deg:.1f} | {s.normal_tilt_deg:.2f} | {second} |"
            )
    return lines


if __name__ == "__main__":
    print("\n".join(fast_stroke_table()))
