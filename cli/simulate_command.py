"""``contact-skills simulate``: a learned skill run in the PyBullet world with the hybrid controller (or a
baseline), its metrics and verdict printed."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from cli import bus_commands
from cli.bus_commands import ENGINES, PACES
from cli.errors import UserError, report_user_error
from cli.sweep_command import CONTROLLERS
from services.quiet_imports import import_pybullet_quietly


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``simulate`` to the `contact-skills` parser."""
    sim = commands.add_parser(
        "simulate",
        help="execute a learned skill in the PyBullet world with the hybrid controller",
        description=_run_simulate.__doc__,
    )
    sim.add_argument("skill", type=Path, help="skill JSON (from `contact-skills learn` or POST /skills)")
    world = sim.add_mutually_exclusive_group()
    world.add_argument("--scenario", help="run in this teacher scenario's world instead of the skill's own")
    world.add_argument("--world", type=Path,
                       help="run in this world: a WorldConfig JSON or the file `record --truth` writes")  # fmt: skip
    sim.add_argument("--work-piece", choices=["auto", "taught", "measured", "rebuilt"], default="auto",
                     help="taught: the world a simulator recording carries; measured: surfaces fitted to what the "
                          "--demonstration measured; rebuilt: surfaces rebuilt from the skill (planes under slides, "
                          "strips along contours); auto: taught if known, else measured if --demonstration is "
                          "given")  # fmt: skip
    sim.add_argument("--placement", type=float, nargs="+", metavar="V",
                     help="where the skill and its rebuilt work piece go in the robot's world: X Y Z (m), "
                          "X Y Z YAW_DEG, or X Y Z QX QY QZ QW (default: chosen to be in reach)")  # fmt: skip
    sim.add_argument("--offset", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("DX", "DY", "DZ"),
                     help="KNOWN work piece shift, m (applied to the skill and the world)")  # fmt: skip
    sim.add_argument("--unknown-offset", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("DX", "DY", "DZ"),
                     help="UNKNOWN work piece shift, m (applied to the world only)")  # fmt: skip
    sim.add_argument("--friction", type=float, metavar="MU", help="tool-surface friction (default 0.2)")
    sim.add_argument("--contact-stiffness", type=float, metavar="N_PER_M", help="contact stiffness (default 3e4)")
    sim.add_argument("--sensor", choices=["wrist", "ideal"], default="wrist",
                     help="force/torque sensor the controller reads: a realistic wrist sensor (noise, drift, 2 ms "
                          "delay, 200 Hz filter, tool inertia) or the exact contact wrench")  # fmt: skip
    sim.add_argument("--controller", choices=CONTROLLERS,
                     default="hybrid_cf", help="ours (hybrid_cf) or a baseline (see docs/CONVENTIONS.md)")  # fmt: skip
    sim.add_argument("--engine", choices=ENGINES,
                     help="the physics engine: pybullet (the compiled loop) or mujoco (the same cell in MuJoCo; its "
                          "loop in Python); default: the world's `engine` (a --world file's), else pybullet "
                          "(docs/ENGINES.md)")  # fmt: skip
    sim.add_argument(
        "--pace",
        choices=PACES,
        default="fast",
        help="fast: as fast as it runs; realtime: simulated time follows the clock (default fast)",
    )
    sim.add_argument("--demonstration", type=Path,
                     help="demonstration JSON the skill was learned from: the path the path error refers to, and "
                          "the surface the work piece is measured from")  # fmt: skip
    sim.add_argument("--figure", type=Path, help="force-tracking figure to write (PNG)")
    sim.add_argument("--scene", type=Path, help="3-D figure of the work piece, learned and executed paths (PNG)")
    sim.add_argument("--json", type=Path, help="metrics JSON to write")
    sim.set_defaults(run=_run_simulate)


def _placement_of(values: list[float] | None) -> dict | None:
    """``--placement`` numbers as a ``Placement`` dict: X Y Z, X Y Z YAW_DEG or X Y Z QX QY QZ QW."""
    if values is None:
        return None
    if len(values) == 3:
        return {"translation_m": values}
    if len(values) == 4:
        half = math.radians(values[3]) / 2
        return {"translation_m": values[:3], "rotation": [0.0, 0.0, math.sin(half), math.cos(half)]}
    if len(values) == 7:
        return {"translation_m": values[:3], "rotation": values[3:]}
    raise UserError([f"placement: give 3, 4 or 7 numbers (X Y Z [YAW_DEG | QX QY QZ QW]), not {len(values)}"])


def _run_simulate(args: argparse.Namespace) -> int:
    """``contact-skills simulate``: run a skill in simulation, print the metrics and the verdict (exit 1 if it aborted,
    4 if its verdict failed).

    Any skill runs with no other argument: a skill recorded in the simulator runs in the world it carries; any
    other (a real recording) runs on a work piece measured from its --demonstration (else rebuilt from what it
    learned), placed in the robot's reach.
    """
    import_pybullet_quietly()
    try:
        import json

        from schemas import Demonstration, ExecutionSettings, Skill
        from schemas.execution import ExecutionPhase
        from sim_worker.execution_world import execution_worlds
        from sim_worker.executor import run_skill

        skill = Skill.model_validate_json(args.skill.read_text())
        demonstration = (
            Demonstration.model_validate_json(args.demonstration.read_text()) if args.demonstration else None
        )
        settings = ExecutionSettings(
            controller=args.controller,
            engine=args.engine,
            environment={
                "offset": args.offset,
                "unknown_offset": args.unknown_offset,
                "work_piece": args.work_piece,
                "placement": _placement_of(args.placement),
                "friction": args.friction,
                "contact_stiffness_n_m": args.contact_stiffness,
                "sensor": args.sensor,
            },
            pace=args.pace,
        )
        world_file = json.loads(args.world.read_text()) if args.world is not None else None
        try:
            worlds = execution_worlds(
                skill,
                settings.environment,
                scenario=args.scenario,
                world=world_file,
                demonstration=demonstration,
                approach_clearance_m=settings.approach_clearance_m,
            )
        except ValueError as exc:  # unknown scenario or world field, a skill out of reach: the message says why
            raise UserError([str(exc)]) from None
        if len(worlds) > 1:
            print(f"no placement reaches all {len(worlds)} strokes: each stroke runs on its own, placed on its own")
        codes, metrics = [], []
        for k, world in enumerate(worlds):
            print(("" if len(worlds) == 1 else f"stroke {k + 1} of {len(worlds)}: ") + _world_line(world))
            if settings.engine is None and world.config.engine is not None:  # said only when the world chose it
                print(f"engine: {world.config.engine.value} (the world's engine; --engine chooses another)")
            result = run_skill(world, settings)
            metrics.append(result.metrics)
            codes.append(bus_commands.exit_code(result.metrics.phase is ExecutionPhase.done, result.metrics))
            _print_execution(result)
            suffix = "" if len(worlds) == 1 else f"_stroke{k + 1}"
            _write_execution_figures(args, world, result, suffix)
    except Exception as exc:
        return report_user_error("simulate", exc)
    if args.json is not None:
        documents = [m.model_dump(mode="json") for m in metrics]
        args.json.write_text(json.dumps(documents[0] if len(documents) == 1 else documents, indent=1))
    return next((code for code in codes if code), 0)


def _print_execution(result) -> None:
    """The metrics and the verdict of one execution, as ``simulate`` prints them."""
    m = result.metrics
    print(f"controller {m.controller.value}: {m.phase.value}" + (f" ({m.abort_reason})" if m.abort_reason else ""))
    if m.true_force_rms_error_n is not None:
        print(f"  true normal force error over {m.steady_contact_s:.2f} s of steady contact: RMS "
              f"{m.true_force_rms_error_n:.3f} N ({m.true_force_rms_error_pct:.2f} %), "
              f"max {m.true_force_max_error_n:.3f} N ({m.true_force_max_error_pct:.2f} %) "
              f"of {m.force_reference_n:.2f} N")  # fmt: skip
        print(f"  CF-z force error (the controller's view): RMS {m.force_rms_error_n:.3f} N "
              f"({m.force_rms_error_pct:.2f} %), max {m.force_max_error_n:.3f} N "
              f"({m.force_max_error_pct:.2f} %)")  # fmt: skip
    if m.touchdown_peak_n is not None:
        settle = f", settled within 5 % after {m.settle_time_s:.2f} s" if m.settle_time_s is not None else ""
        asked = m.touchdown_contact_force_ratio
        asked_text = f", {asked:.2f} x the force asked at contact" if asked is not None else ""
        print(f"  touch-down peak {m.touchdown_peak_n:.2f} N ({m.touchdown_peak_ratio or 0:.2f} x the press that "
              f"followed{asked_text}){settle}")  # fmt: skip
    if m.cf_normal_angle_deg is not None:
        print(f"  CF z (as the controller used it) vs true surface normal: mean {m.cf_normal_angle_deg:.2f} deg, "
              f"max {m.cf_normal_angle_max_deg:.2f} deg")  # fmt: skip
    for s in m.surfaces_pressed:
        line = (
            f"  segment {s.segment} pressed normals {s.normal_error_deg:.1f} deg from the taught ones (median), "
            f"{s.touchdown_normal_error_deg:.1f} at touch-down, {s.final_normal_error_deg:.1f} at its end"
        )
        if s.region_coverage is not None and s.pressed_region_deg and s.taught_region_deg:
            (a, b), (c, d) = s.pressed_region_deg, s.taught_region_deg
            line += f"; over {a:+.0f}..{b:+.0f} of {c:+.0f}..{d:+.0f} deg taught ({100 * s.region_coverage:.0f} %)"
        if s.crease_deg is not None and s.crease_turn_deg is not None:
            line += f"; turned {s.crease_turn_deg:.1f} deg across the {s.crease_deg:.0f} deg crease"
        print(line)
    if m.exit_collision_n is not None:
        print(f"  exit collision: the way out hit the part at {m.exit_collision_n:.2f} N")
    if m.path_rms_m is not None:
        print(f"  path RMS (CF x-y) {m.path_rms_m * 1e3:.2f} mm; contact ratio {m.contact_ratio * 100:.2f} %")
    for found in m.contact_found_offsets_m:
        print(f"  guarded approach: surface found {found * 1e3:+.1f} mm along CF z from where it was taught")
    print(f"  peak force {m.peak_force_n:.2f} N; {m.duration_s:.2f} s simulated in {result.loop_wall_s:.2f} s "
          f"(real-time factor {m.real_time_factor:.1f})")  # fmt: skip
    for line in m.verdict.lines():
        print(line)


def _write_execution_figures(args: argparse.Namespace, world, result, suffix: str) -> None:
    """``--figure`` and ``--scene`` of one execution (``suffix`` added to their names: a stroke's)."""
    if args.figure is not None:
        from services.figures import write_execution_figure

        figure = args.figure.with_name(args.figure.stem + suffix + args.figure.suffix)
        figure.parent.mkdir(parents=True, exist_ok=True)
        write_execution_figure(result, figure)
        print(f"figure written to {figure}")
    if args.scene is not None:
        from services.figures import write_scene_figure

        scene = args.scene.with_name(args.scene.stem + suffix + args.scene.suffix)
        scene.parent.mkdir(parents=True, exist_ok=True)
        pieces = [piece.vertices for piece in result.world_config.work_pieces]
        write_scene_figure(world.skill, result.telemetry, pieces, scene, title=_world_line(world))
        print(f"scene figure written to {scene}")


def _world_line(world) -> str:
    """One line: which world a skill runs in, and where it was placed."""
    if world.placement is None:
        return f"work piece: {world.source} world"
    t = ", ".join(f"{v:+.3f}" for v in world.placement.translation_m)
    q = ", ".join(f"{v:+.3f}" for v in world.placement.rotation)
    origin = "measured from the demonstration" if world.source == "measured" else "rebuilt from the skill"
    return (f"work piece: {origin} ({len(world.config.work_pieces)} parts); placement "
            f"({world.placement_reason}): translation [{t}] m, rotation [{q}] (xyzw)")  # fmt: skip
