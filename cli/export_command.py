"""``contact-skills export``: a stored demonstration or execution (from the API) or a local demonstration file, as
MCAP (ROS 2 messages for Foxglove and PlotJuggler), CSV or JSON, optionally a time window of it; or a stored skill as
MCAP (the robot, the demonstrated path and the learned compliant frames)."""

from __future__ import annotations

import argparse
from pathlib import Path

from services.service_url import URL_HELP


def cmd_export(args: argparse.Namespace) -> int:
    """Export a demonstration, an execution or a skill: an id (demo_..., exec_..., skill_...: a skill as MCAP only,
    along its demonstration, with the robot and the learned compliant frames) is fetched from the API, a local JSON or
    CSV demonstration (in the project's conventions, as `record` writes them) is converted here. The format
    follows the output's suffix (.mcap, .csv, .json) unless --format says."""
    from cli.errors import UserError, report_user_error

    try:
        fmt = args.format or {".mcap": "mcap", ".csv": "csv", ".json": "json"}.get(args.output.suffix.lower())
        if fmt is None:
            raise UserError([f"format: {args.output} ends in neither .mcap, .csv nor .json: pass --format"])
        if args.t0 is not None and args.t1 is not None and args.t1 < args.t0:
            raise UserError([f"--t1 {args.t1:g} s is before --t0 {args.t0:g} s"])
        source = Path(args.source)
        if source.exists():
            data, what = _local(source, fmt, args.t0, args.t1)
        else:
            data, what = _remote(args, fmt)
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_bytes(data)
    except Exception as exc:
        return report_user_error("export", exc)
    print(f"{what} -> {args.output} ({fmt}, {len(data) / 1e6:.2f} MB)")
    return 0


def _local(source: Path, fmt: str, t0: float | None, t1: float | None) -> tuple[bytes, str]:
    """A local demonstration file exported: its samples unchanged (no tare), in the window."""
    import json

    from schemas.demonstration import DemonstrationArrays
    from schemas.import_options import ImportOptions
    from services.csv_import import samples_csv_text
    from services.importing import demonstration_from_file
    from services.telemetry_export import demonstration_mcap, window_mask

    demonstration = demonstration_from_file(source, ImportOptions(tare=False))
    a = demonstration.arrays()
    keep = window_mask(a.t, t0, t1)
    what = f"demonstration {source} ({int(keep.sum())} of {a.t.size} samples)"
    if fmt == "mcap":
        window = DemonstrationArrays(
            **{name: getattr(a, name)[keep] for name in ("t", "positions", "orientations", "wrenches")}
        )
        return demonstration_mcap(window, demonstration.metadata.name, source.stat().st_mtime).data, what
    if fmt == "csv":
        return samples_csv_text(a.t[keep], a.positions[keep], a.orientations[keep], a.wrenches[keep]).encode(), what
    columns = {"t": a.t, "positions": a.positions, "orientations": a.orientations, "wrenches": a.wrenches}
    return json.dumps({name: values[keep].tolist() for name, values in columns.items()}).encode(), what


def _remote(args: argparse.Namespace, fmt: str) -> tuple[bytes, str]:
    """The record ``args.source`` (an id) fetched from the API at ``args.url``."""
    from cli.errors import UserError
    from services.client import Client, ServiceError
    from services.service_url import service_url

    try:
        with Client(service_url(args.url)) as client:
            data = client.export(args.source, format=fmt, t0=args.t0, t1=args.t1, every=args.every)
    except ServiceError as exc:
        raise UserError([str(exc)]) from None
    except ValueError as exc:  # neither a file nor an id
        raise UserError([f"{args.source}: no such file, and {exc}"]) from None
    return data, f"{args.source} from {service_url(args.url)}"


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``export`` to the `contact-skills` parser."""
    export = commands.add_parser(
        "export",
        help="export a demonstration or execution as MCAP (Foxglove, PlotJuggler), CSV or JSON; a skill as MCAP",
        description=cmd_export.__doc__,
    )
    export.add_argument(
        "source", metavar="ID_OR_FILE", help="demo_..., exec_... or skill_... (from the API), or a local file"
    )
    export.add_argument("-o", "--output", type=Path, required=True, help="file to write (.mcap, .csv or .json)")
    export.add_argument("--format", choices=["mcap", "csv", "json"], help="default: from the output's suffix")
    export.add_argument("--t0", type=float, metavar="S", help="only samples at or after S seconds")
    export.add_argument("--t1", type=float, metavar="S", help="only samples at or before S seconds")
    export.add_argument("--every", type=int, default=1, metavar="N", help="every N-th sample (executions)")
    export.add_argument("--url", help=f"{URL_HELP}, to fetch ids from")
    export.set_defaults(run=cmd_export)
