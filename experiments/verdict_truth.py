"""Does a verdict know where the tool pressed? The teacher's skills run on parts changed without telling the controller
(moved, tilted, resized, swapped and missing parts; stiff and soft pads; high friction; sensor offsets, noise and
drift), with and without following the surface, and each run's verdict is held against a JUDGE that knows the world.

The judge (:func:`judge_run`) is independent of the verdict's where-checks: it places every touching row on the
EXACT shapes of the world that ran (``sim_worker.geometry.WorldGeometry``, which the controller never sees), from
the tool's POSITION, where the verdict compares the simulator's contact normals with the taught frames. A run did its
job when it ran to its end; pressed within the force tolerances (true normal force RMS ≤ 10 %, steady max ≤ 50 %, in
contact ≥ 97 % of its contact phase, touch-down ≤ 1.5× the press); pressed every contact segment on the body it was
taught on (the body the teacher's own demonstration touched in that segment, for most of its touching rows); covered
at least 85 % of a contour's taught region, measured as the angle about the body's own axis of the exact surface
normal under the tool (the teacher's rows against the run's); and never hit the part on its way out.

The set is split: the TUNED cases were looked at while the verdict's limits were set; the HELD-OUT ones (other
values, the curved block's skill) were not. The first held-out round ran once, showed three false failures, two of
them from one check (a crease met where a steeper ramp or an early crease turned the normal more, or before the
switch), which was then changed: it is no longer blind. The second round was written after that change and run
once, at the end (``benchmarks/bench_verdicts.py`` reports every group apart).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from execution.metrics import exit_rows
from execution.telemetry import Telemetry
from experiments.contour_stress import APPROACH_MAX_DISTANCE_M
from schemas import LearnOptions
from schemas.execution import PHASE_CODES, Engine, ExecutionMetrics, ExecutionPhase, ExecutionSettings
from schemas.skill import SegmentKind, Skill
from schemas.sweep import SweepParameter
from schemas.verdict import ExecutionTolerances, Verdict, VerdictCheckName
from schemas.world import WorldConfig, WorldOverrides
from sim_worker.execution_world import execution_world
from sim_worker.executor import run_skill
from sim_worker.geometry import WorldGeometry
from sim_worker.teacher import TeacherRecording, record_demonstration
from skills.parameterize import learn_skill
from skills.sweeps import trial_world_overrides

TRUTH_SCENARIOS = ("slide_flat", "slide_two_planes", "contour_cylinder", "contour_block")
ON_BODY_SHARE = 0.5
"""A contact segment pressed on its taught body when at least this share of its touching rows lie on it (a crease
met a little off where it was taught moves a part of a segment onto its neighbour's body: the job is still done)."""
EXIT_HIT_N = 1.0
"""A true normal force above this on the way out of a contact is a hit, N."""


class Fault(StrEnum):
    """What the judge found wrong with a run, and the verdict checks that name it."""

    ended_early = "ended early"
    force = "force"
    wrong_body = "wrong body"
    region = "region"
    exit_hit = "exit hit"


NAMED_BY: dict[Fault, frozenset[VerdictCheckName]] = {
    Fault.ended_early: frozenset({VerdictCheckName.finished}),
    Fault.force: frozenset(
        {
            VerdictCheckName.true_force_rms,
            VerdictCheckName.true_force_max,
            VerdictCheckName.contact_ratio,
            VerdictCheckName.touchdown,
        }
    ),
    Fault.wrong_body: frozenset(
        {VerdictCheckName.surface_pressed, VerdictCheckName.next_surface, VerdictCheckName.region_covered}
    ),
    Fault.region: frozenset({VerdictCheckName.region_covered, VerdictCheckName.surface_pressed}),
    Fault.exit_hit: frozenset({VerdictCheckName.exit_collision}),
}
"""The verdict checks whose failure names each fault (a failed verdict names what happened when one of its failed
checks names one of the judge's faults)."""


@dataclass(frozen=True)
class Perturbation:
    """One unknown change: its name, the scenario whose skill runs, the ``EnvironmentChange`` fields and a function
    of the taught world dict giving the ``WorldConfig`` fields it changes; ``held_out``: not looked at while tuning."""

    name: str
    scenario: str
    environment: Mapping[str, Any] = field(default_factory=dict)
    world: Callable[[Mapping[str, Any]], WorldOverrides] | None = None
    held_out: bool = False
    round: int = 1
    """Held out: 1, run once before the crease check was changed (then again after); 2, run once at the end."""


def _cylinder(**values: float) -> Callable[[Mapping[str, Any]], WorldOverrides]:
    parameters = {SweepParameter(f"cylinder_{k}"): v for k, v in values.items()}
    return lambda world: trial_world_overrides(world, parameters)


def _swap_cylinder_for_block(world: Mapping[str, Any]) -> WorldOverrides:
    return {"cylinder": {"enabled": False}, "block": {"enabled": True}}


def _swap_block_for_cylinder(world: Mapping[str, Any]) -> WorldOverrides:
    return {"block": {"enabled": False}, "cylinder": {"enabled": True}}


def _no_ramp(world: Mapping[str, Any]) -> WorldOverrides:
    return {"ramp": {"enabled": False}}


def _ramp(**values: float) -> Callable[[Mapping[str, Any]], WorldOverrides]:
    return lambda world: {"ramp": values}


P = Perturbation
PERTURBATIONS: tuple[Perturbation, ...] = (
    # Tuned: looked at while the verdict's where-checks and their limits were set.
    P("as taught", "slide_flat"),
    P("table 2 cm higher", "slide_flat", {"unknown_offset": [0.0, 0.0, 0.02]}),
    P("table tilted 15°", "slide_flat", {"unknown_tilt_deg": [15.0, 0.0]}),
    P("pad 3e3 N/m", "slide_flat", {"contact_stiffness_n_m": 3e3}),
    P("friction 0.6", "slide_flat", {"friction": 0.6}),
    P("sensor offset 3 N (tool z)", "slide_flat", {"sensor_offset_tool_n": [0.0, 0.0, 3.0]}),
    P("as taught", "slide_two_planes"),
    P("ramp missing", "slide_two_planes", world=_no_ramp),
    P("crease 2 cm late", "slide_two_planes", world=_ramp(crease_x_m=0.02)),
    P("as taught", "contour_cylinder"),
    P("8 cm higher", "contour_cylinder", {"unknown_offset": [0.0, 0.0, 0.08]}),
    P("8 cm lower", "contour_cylinder", {"unknown_offset": [0.0, 0.0, -0.08]}),
    P("5 cm across", "contour_cylinder", {"unknown_offset": [0.0, 0.05, 0.0]}),
    P("radius 12 cm", "contour_cylinder", world=_cylinder(radius_m=0.12)),
    P("radius 6 cm", "contour_cylinder", world=_cylinder(radius_m=0.06)),
    P("axis turned 10°", "contour_cylinder", world=_cylinder(yaw_deg=10.0)),
    P("swapped for the block", "contour_cylinder", world=_swap_cylinder_for_block),
    P("pad 1e6 N/m", "contour_cylinder", {"contact_stiffness_n_m": 1e6}),
    # Held out: run once, after the limits were set.
    P("table 3 cm lower", "slide_flat", {"unknown_offset": [0.0, 0.0, -0.03]}, held_out=True),
    P("table tilted 25° about y", "slide_flat", {"unknown_tilt_deg": [0.0, 25.0]}, held_out=True),
    P("pad 1e6 N/m", "slide_flat", {"contact_stiffness_n_m": 1e6}, held_out=True),
    P("friction 0.9", "slide_flat", {"friction": 0.9}, held_out=True),
    P("sensor noise 1 N", "slide_flat", {"sensor_noise_n": 1.0}, held_out=True),
    P("sensor bias 3 N (world y)", "slide_flat", {"sensor_bias_n": [0.0, 3.0, 0.0]}, held_out=True),
    P("ramp steeper (30°)", "slide_two_planes", world=_ramp(tilt_deg=30.0), held_out=True),
    P("ramp missing, table 1 cm higher", "slide_two_planes", {"unknown_offset": [0.0, 0.0, 0.01]}, _no_ramp, True),
    P("crease 3 cm early", "slide_two_planes", world=_ramp(crease_x_m=-0.03), held_out=True),
    P("4 cm across", "contour_cylinder", {"unknown_offset": [0.0, -0.04, 0.0]}, held_out=True),
    P("radius 10 cm", "contour_cylinder", world=_cylinder(radius_m=0.10), held_out=True),
    P("3 cm higher", "contour_cylinder", {"unknown_offset": [0.0, 0.0, 0.03]}, held_out=True),
    P("sensor offset 4 N (tool y)", "contour_cylinder", {"sensor_offset_tool_n": [0.0, 4.0, 0.0]}, held_out=True),
    P("pad 3e3 N/m", "contour_cylinder", {"contact_stiffness_n_m": 3e3}, held_out=True),
    P("as taught", "contour_block", held_out=True),
    P("2 cm across", "contour_block", {"unknown_offset": [0.0, 0.02, 0.0]}, held_out=True),
    P("5 cm along", "contour_block", {"unknown_offset": [0.05, 0.0, 0.0]}, held_out=True),
    P("swapped for the cylinder", "contour_block", world=_swap_block_for_cylinder, held_out=True),
    P("friction 0.6", "contour_block", {"friction": 0.6}, held_out=True),
    # Held out, second round: written after the first round's run had changed the crease check, run once after.
    P("table 5 cm along x", "slide_flat", {"unknown_offset": [0.05, 0.0, 0.0]}, held_out=True, round=2),
    P(
        "table tilted 10°, 1 cm higher",
        "slide_flat",
        {"unknown_tilt_deg": [10.0, 0.0], "unknown_offset": [0.0, 0.0, 0.01]},
        held_out=True,
        round=2,
    ),
    P("pad 1e3 N/m", "slide_flat", {"contact_stiffness_n_m": 1e3}, held_out=True, round=2),
    P("ramp 12°", "slide_two_planes", world=_ramp(tilt_deg=12.0), held_out=True, round=2),
    P(
        "crease 1 cm late, table 1 cm lower",
        "slide_two_planes",
        {"unknown_offset": [0.0, 0.0, -0.01]},
        _ramp(crease_x_m=0.01),
        held_out=True,
        round=2,
    ),
    P("friction 0.6", "slide_two_planes", {"friction": 0.6}, held_out=True, round=2),
    P("radius 7 cm", "contour_cylinder", world=_cylinder(radius_m=0.07), held_out=True, round=2),
    P("2 cm higher, 2 cm across", "contour_cylinder", {"unknown_offset": [0.0, 0.02, 0.02]}, held_out=True, round=2),
    P("axis turned -15°", "contour_cylinder", world=_cylinder(yaw_deg=-15.0), held_out=True, round=2),
    P("sensor bias 2 N (world x)", "contour_cylinder", {"sensor_bias_n": [2.0, 0.0, 0.0]}, held_out=True, round=2),
    P("cylinder missing", "contour_cylinder", world=lambda w: {"cylinder": {"enabled": False}}, held_out=True, round=2),
    P("3 cm higher", "contour_block", {"unknown_offset": [0.0, 0.0, 0.03]}, held_out=True, round=2),
    P(
        "longer cap (18 cm half length)",
        "contour_block",
        world=lambda w: {"block": {"half_length_m": 0.18}},
        held_out=True,
        round=2,
    ),
)


@dataclass(frozen=True)
class Taught:
    """A scenario's teacher recording, its skill, and per contact segment the body its demonstration pressed on and
    the taught region (the angles about that body's axis of the normals under the tool, deg; None on a plane)."""

    recording: TeacherRecording
    skill: Skill
    bodies: dict[int, str]
    regions: dict[int, tuple[float, float] | None]


@dataclass(frozen=True)
class Judgement:
    """One run: the perturbation, whether it followed the surface (None: the product's default,
    ``ExecutionSettings.follow_surface_normal``), the metrics, the judge's faults (each with a sentence), what the
    verdict said, and the engine it ran on."""

    perturbation: Perturbation
    follow: bool | None
    metrics: ExecutionMetrics
    faults: dict[Fault, str]
    engine: Engine = Engine.pybullet

    @property
    def job_done(self) -> bool:
        return not self.faults

    @property
    def verdict_passed(self) -> bool:
        return self.metrics.verdict is not None and self.metrics.verdict.verdict is Verdict.passed

    @property
    def failed_checks(self) -> set[VerdictCheckName]:
        verdict = self.metrics.verdict
        return {c.name for c in verdict.checks if not c.passed and not c.warning_only} if verdict else set()

    @property
    def reason_named(self) -> bool:
        """A failed verdict on a failed job names one of the judge's faults."""
        return any(self.failed_checks & NAMED_BY[f] for f in self.faults)


def _body_angles_deg(geometry: WorldGeometry, body: str, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """The angle (deg) about ``body``'s own y axis (a cylinder's axis, a block's extrusion) of its exact outward
    normal at the surface point nearest each of ``points`` (N, 3), from its local up (z) towards its local x."""
    solid = geometry.solids[body]
    _, normals = solid.signed_distance(points)
    local = normals @ solid.R
    return np.degrees(np.arctan2(local[:, 0], local[:, 2]))


def _touching_rows(tel: Telemetry, segment: int) -> NDArray[np.bool_]:
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    return contact & (tel.segment_index == segment) & (tel.normal_force_true > 0.0)


def taught(scenario: str, seed: int = 0) -> Taught:
    """Record ``scenario`` with the teacher, learn its skill, and place each contact segment's demonstrated rows on
    the taught world's exact shapes."""
    recording = record_demonstration(scenario, seed=seed)
    skill = learn_skill(recording.demonstration, LearnOptions())
    geometry = WorldGeometry(recording.world_config)
    arrays = recording.demonstration.arrays()
    pressing = np.linalg.norm(arrays.wrenches[:, :3], axis=1) > 1.0
    bodies, regions = {}, {}
    for segment in skill.segments:
        if segment.kind is not SegmentKind.contact:
            continue
        rows = (arrays.t >= segment.t_start) & (arrays.t <= segment.t_end) & pressing
        names = geometry.query(arrays.positions[rows]).name
        body = max(set(names), key=names.count)
        bodies[segment.index] = body
        regions[segment.index] = None
        if body in ("cylinder", "block"):
            angles = _body_angles_deg(geometry, body, arrays.positions[rows])
            regions[segment.index] = (float(np.percentile(angles, 2)), float(np.percentile(angles, 98)))
    return Taught(recording, skill, bodies, regions)


def judge_run(
    teaching: Taught, world: WorldConfig, tel: Telemetry, metrics: ExecutionMetrics, tolerances: ExecutionTolerances
) -> dict[Fault, str]:
    """The judge's faults of one run (empty: the job was done), each with what happened, from the world that ran
    (``world``, with every unknown change) and the telemetry's positions and true forces."""
    faults: dict[Fault, str] = {}
    if metrics.phase is not ExecutionPhase.done:
        faults[Fault.ended_early] = f"{metrics.phase.value}: {metrics.abort_reason}"
    m, t = metrics, tolerances
    limits = (
        (m.true_force_rms_error_pct, t.true_force_rms_pct, "true RMS %"),
        (m.true_force_max_error_pct, t.true_force_max_pct, "true max %"),
        (m.touchdown_peak_ratio, t.touchdown_ratio, "touch-down ratio"),
    )
    force = [
        f"{what} {value:.3g} > {limit:.3g}" for value, limit, what in limits if value is not None and value > limit
    ]
    if m.contact_ratio is not None and m.contact_ratio < t.contact_ratio:
        force.append(f"contact {m.contact_ratio:.3f} < {t.contact_ratio}")
    if force:
        faults[Fault.force] = "; ".join(force)
    geometry = WorldGeometry(world)
    for index, body in teaching.bodies.items():
        rows = _touching_rows(tel, index)
        if not rows.any():
            continue
        if body not in geometry.solids:
            faults[Fault.wrong_body] = f"segment {index}: its {body} is not there"
            continue
        names = geometry.query(tel.tool_position[rows]).name
        share = names.count(body) / len(names)
        if share < ON_BODY_SHARE:
            other = max(set(names) - {body}, key=names.count)
            faults[Fault.wrong_body] = f"segment {index}: {100 * share:.0f} % on the {body}, the rest on the {other}"
            continue
        region = teaching.regions[index]
        if region is not None:
            angles = _body_angles_deg(geometry, body, tel.tool_position[rows])
            low, high = np.percentile(angles, [2, 98])
            covered = max(0.0, min(high, region[1]) - max(low, region[0])) / (region[1] - region[0])
            if covered < t.region_coverage:
                faults[Fault.region] = (
                    f"segment {index}: {low:+.0f}..{high:+.0f}° of the {body}, taught "
                    f"{region[0]:+.0f}..{region[1]:+.0f}° ({100 * covered:.0f} %)"
                )
    way_out = exit_rows(teaching.skill, tel)
    if way_out.any() and tel.normal_force_true[way_out].max() > EXIT_HIT_N:
        faults[Fault.exit_hit] = f"the way out hit the part at {tel.normal_force_true[way_out].max():.1f} N"
    return faults


def run_judged(
    perturbation: Perturbation,
    follow: bool | None,
    teachings: Mapping[str, Taught],
    engine: Engine = Engine.pybullet,
) -> Judgement:
    """Run one perturbation on ``engine`` with following on, off or as the product's default (None), and judge it
    (the judge reads the world that ran and the telemetry: the same on either engine)."""
    teaching = teachings[perturbation.scenario]
    settings = ExecutionSettings(
        environment=dict(perturbation.environment),
        approach_max_distance_m=APPROACH_MAX_DISTANCE_M,
        follow_surface_normal=follow,
        engine=engine,
    )
    world = execution_world(teaching.skill, settings.environment, scenario=perturbation.scenario)
    if perturbation.world is not None:
        world = replace(world, config=world.config.replace(**perturbation.world(world.config.to_dict())))
    result = run_skill(world, settings)
    faults = judge_run(teaching, result.world_config, result.telemetry, result.metrics, settings.tolerances)
    return Judgement(perturbation, follow, result.metrics, faults, engine)
