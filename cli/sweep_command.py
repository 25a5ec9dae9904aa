"""``contact-skills sweep``: a robustness sweep of a skill through the service (``experiments.sweep`` runs it), with
a progress bar; prints the summary and sensitivity tables, writes the figure, the trials and a RESULTS.md section."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from cli.bus_commands import ENGINES
from services.service_url import URL_HELP

SHOWN_CONTROLLERS = "hybrid_cf,impedance_found_surface,hybrid_world_z"
CONTROLLERS = ("hybrid_cf", "impedance", "impedance_found_surface", "hybrid_world_z")
"""`schemas.execution.ControllerKind`, spelled out: `--help` imports no pydantic (tests/test_sweeps.py compares)."""
PARAMETERS = (
    "offset_x_m", "offset_y_m", "offset_z_m", "tilt_x_deg", "tilt_y_deg", "friction", "contact_stiffness_n_m",
    "contact_damping_n_s_m", "sensor_bias_x_n", "sensor_bias_y_n", "sensor_bias_z_n", "sensor_offset_x_n",
    "sensor_offset_y_n", "sensor_offset_z_n", "sensor_noise_n", "force_scale", "cylinder_radius_m", "cylinder_yaw_deg",
)  # fmt: skip
"""`schemas.sweep.SweepParameter`, spelled out likewise."""
SAMPLERS = ("lhs", "sobol")
"""`schemas.sweep.Sampler`, spelled out likewise."""


def _vary(items: list[str] | None) -> dict[str, dict]:
    """``NAME=LOW:HIGH[:log]`` options as the ``vary`` of a `SweepRequest` (none: :data:`DEFAULT_RANGES`)."""
    from cli.errors import UserError
    from schemas.sweep import DEFAULT_RANGES

    if not items:
        return {name.value: spread.model_dump() for name, spread in DEFAULT_RANGES.items()}
    vary = {}
    for item in items:
        name, _, spread = item.partition("=")
        parts = spread.split(":")
        try:
            low, high = float(parts[0]), float(parts[1])
        except (ValueError, IndexError):
            raise UserError([f"--vary {item!r}: give NAME=LOW:HIGH or NAME=LOW:HIGH:log"]) from None
        if len(parts) > 3 or (len(parts) == 3 and parts[2] != "log"):
            raise UserError([f"--vary {item!r}: only ':log' may follow LOW:HIGH"])
        vary[name] = {"low": low, "high": high, "log": len(parts) == 3}
    return vary


def _settings(path: Path | None) -> dict:
    """The execution settings every trial starts from, read from a JSON object file (validated by the request); none:
    the fields :data:`schemas.sweep.DEFAULT_SETTINGS` sets."""
    from cli.errors import UserError
    from schemas.sweep import DEFAULT_SETTINGS

    if path is None:
        return DEFAULT_SETTINGS.model_dump(mode="json", exclude_unset=True)
    try:
        settings = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError([f"--settings {path}: not JSON ({exc.msg}, line {exc.lineno})"]) from None
    if not isinstance(settings, dict):
        raise UserError([f"--settings {path}: give a JSON object of execution settings, e.g. "
                         '{"approach_slow_distance_m": 0.04}'])  # fmt: skip
    return settings


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run SCENARIO's skill (the teacher's demonstration of it, recorded and learned through the service), or a
    stored skill (--skill-id), over --trials sampled variations of its cell (--vary; default: every parameter over
    what a real cell sees, the cylinder's radius and yaw too for a skill taught on a cylinder), once per controller,
    on every sim worker of the service at --url (started here with --workers if none answers). Prints per controller
    the success rate (the executions' verdicts: finished, in contact >= 99 %, TRUE normal RMS error <= --threshold %,
    max error and touch-down within the default tolerances), the failures by verdict check, the error quantiles and
    the parameters that drive the failures. Exit 0 when the sweep finished, 1 when it did not, 2 for bad options."""
    from cli.errors import UserError, report_user_error
    from experiments.cases import DemoOptions
    from experiments.stack import DemoError
    from experiments.sweep import (
        SENSITIVITY_HEADER,
        SUMMARY_HEADER,
        SWEEPS_SECTION,
        SweepOptions,
        failure_lines,
        merged_sweeps_section,
        run_sweep,
        sensitivity_rows,
        summary_rows,
        sweep_markdown,
        text_table,
    )
    from schemas.sweep import SweepRequest, SweepState
    from services.service_url import service_url

    shown = ["contact-skills", "sweep", *sys.argv[2:]] if sys.argv[1:2] == ["sweep"] else ["contact-skills", "sweep"]
    try:
        if (args.scenario is None) == (args.skill_id is None):
            raise UserError(["give a SCENARIO to record and learn, or --skill-id of a stored skill (not both)"])
        body = {
            "controllers": [c.strip() for c in args.controllers.split(",") if c.strip()],
            "vary": _vary(args.vary),
            "trials": args.trials,
            "seed": args.seed,
            "sampler": args.sampler,
            "success_rms_pct": args.threshold,
            "store_telemetry": args.store_telemetry,
            "settings": {**_settings(args.settings), **({"engine": args.engine} if args.engine else {})},
        }
        SweepRequest.model_validate({**body, "skill_id": "checked-by-the-service"})  # bad options: exit 2 here
    except Exception as exc:
        return report_user_error("sweep", exc)
    service = DemoOptions(url=service_url(args.url), workers=args.workers, db=args.db, command=shlex.join(shown))
    options = SweepOptions(body, args.scenario, args.skill_id, args.record_seed, service, world_ranges=not args.vary)
    try:
        outcome = run_sweep(options)
    except DemoError as exc:
        print(f"contact-skills sweep: error: {exc}", file=sys.stderr)
        return 2 if "HTTP 422" in str(exc) or "HTTP 404" in str(exc) else 1
    except KeyboardInterrupt:
        print("contact-skills sweep: interrupted (the sweep goes on in the service)", file=sys.stderr)
        return 130
    view = outcome.view
    print()
    counts = view.counts
    print(f"sweep {view.id} of {outcome.skill_label}: {view.status.value}, {counts.finished}/{counts.total} "
          f"executions in {outcome.wall_s:.0f} s ({counts.reruns} rerun after an infrastructure failure)")  # fmt: skip
    print(text_table(SUMMARY_HEADER, summary_rows(view)))
    print()
    print("\n".join(failure_lines(view, outcome.trials)))
    print()
    print(text_table(SENSITIVITY_HEADER, sensitivity_rows(view)))
    if args.figure is not None:
        from services.sweep_figure import write_sweep_figure

        args.figure.parent.mkdir(parents=True, exist_ok=True)
        write_sweep_figure(view, outcome.trials, args.figure)
        print(f"figure -> {args.figure}")
    if args.json is not None:
        data = {"sweep": view.model_dump(mode="json"), "trials": [t.model_dump(mode="json") for t in outcome.trials]}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(data, indent=1))
        print(f"trials -> {args.json}")
    if args.results is not None:
        from services.doc_sections import section_of, write_section

        figure = None if args.figure is None else Path(*_relative(args.figure, args.results.parent)).as_posix()
        subsection = sweep_markdown(outcome, shlex.join(shown), figure)
        existing = section_of(args.results.read_text(), SWEEPS_SECTION) if args.results.exists() else None
        key = args.scenario or args.skill_id
        write_section(args.results, SWEEPS_SECTION, merged_sweeps_section(existing, key, subsection), "# Results\n")
        print(f"results -> {args.results} (section {SWEEPS_SECTION}, {key})")
    return 0 if view.status is SweepState.done else 1


def _relative(path: Path, base: Path) -> tuple[str, ...]:
    """``path`` relative to ``base`` (for a Markdown link), as parts."""
    import os

    return tuple(Path(os.path.relpath(path.resolve(), base.resolve())).parts)


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``sweep`` to the `contact-skills` parser."""
    sweep = commands.add_parser(
        "sweep",
        help="robustness sweep of a skill over sampled cell variations, per controller",
        description=cmd_sweep.__doc__,
    )
    sweep.add_argument("scenario", nargs="?", help="teacher scenario to record and learn (e.g. slide_flat)")
    sweep.add_argument("--skill-id", help="a stored skill instead of a scenario")
    sweep.add_argument("--record-seed", type=int, default=0, help="seed of the teacher's recording (default 0)")
    sweep.add_argument("--trials", type=int, default=20, help="sampled trials (default 20); each runs per controller")
    sweep.add_argument("--seed", type=int, default=0, help="seed of the trial design and the sensor noise (default 0)")
    sweep.add_argument("--sampler", choices=SAMPLERS, default="lhs", help="default lhs")
    sweep.add_argument(
        "--controllers",
        default=SHOWN_CONTROLLERS,
        help=f"comma separated, of {', '.join(CONTROLLERS)} (default {SHOWN_CONTROLLERS})",
    )
    sweep.add_argument(
        "--vary",
        action="append",
        metavar="NAME=LOW:HIGH[:log]",
        help=f"a parameter and its range, repeatable; NAME of {', '.join(PARAMETERS)} (default: all of them over what "
        "a real cell sees, schemas.sweep.DEFAULT_RANGES; the cylinder's only for a skill taught on a cylinder)",
    )
    sweep.add_argument("--threshold", type=float, default=10.0, help="success: true RMS error <= this %% (default 10)")
    sweep.add_argument(
        "--settings",
        type=Path,
        metavar="FILE",
        help="JSON object of the execution settings every trial starts from (POST /executions fields, e.g. "
        '{"approach_slow_distance_m": 0.04}; the sweep sets the controller, the varied environment, telemetry and '
        "its success tolerances; default: schemas.sweep.DEFAULT_SETTINGS, follow_surface_normal and an approach "
        "that expects the surface within the default offsets)",
    )
    sweep.add_argument(
        "--engine",
        choices=ENGINES,
        help="the physics engine of every trial (overrides the settings' engine; default: theirs, else the one the "
        "skill's taught world names, else pybullet), docs/ENGINES.md",
    )
    sweep.add_argument(
        "--store-telemetry",
        action="store_true",
        help="stream and store every trial's telemetry (default: none is sent; the metrics are the same)",
    )
    sweep.add_argument("--figure", type=Path, help="write the figure (PNG) here")
    sweep.add_argument("--json", type=Path, help="write the sweep and every trial (JSON) here")
    sweep.add_argument("--results", type=Path, help="write/replace this sweep's subsection of a RESULTS.md")
    sweep.add_argument("--url", help=f"{URL_HELP} (none there: started here)")
    sweep.add_argument("--workers", type=int, default=2, help="sim workers of a service started here (default 2)")
    sweep.add_argument("--db", type=Path, help="database of a service started here (default: a temporary file)")
    sweep.set_defaults(run=cmd_sweep)
