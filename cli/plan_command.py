"""``contact-skills plan``: a skill's nominal plan for a real cell (docs/REAL_CELL.md) as JSON
(``schemas.skill_plan.SkillPlan``) or MCAP (``services.telemetry_export.plan_mcap``): of a stored skill (from the
API, ``GET /skills/{id}/plan``) or of a local skill file (as ``contact-skills learn -o`` writes it), computed here,
optionally placed into the robot's world."""

from __future__ import annotations

import argparse
from pathlib import Path

from services.service_url import URL_HELP


def cmd_plan(args: argparse.Namespace) -> int:
    """Write a skill's plan for a real cell: the phase planner's references for every control step (timed tool
    poses, compliant frame, selection, desired force along CF z, phase) and the controller's gains, as JSON or (--format
    mcap) as MCAP. An id (skill_...) is fetched from the API; a local skill file is planned here, where --placement
    (JSON, as the execution's environment.placement) moves it into the robot's world first."""
    from cli.errors import UserError, report_user_error

    try:
        source = Path(args.source)
        if source.exists():
            data, what = _local(source, args.every, args.max_samples, args.placement)
        elif args.placement is not None:
            raise UserError([f"--placement: only for a local skill file ({args.source} is not one)"])
        else:
            data, what = _remote(args)
        if args.format == "mcap":
            data = _as_mcap(data)
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_bytes(data)
    except Exception as exc:
        return report_user_error("plan", exc)
    print(f"{what} -> {args.output} ({len(data) / 1e6:.2f} MB)")
    return 0


def _local(source: Path, every: int, max_samples: int | None, placement: str | None) -> tuple[bytes, str]:
    """The plan of the skill file ``source``, placed by the ``placement`` JSON if given, of at most ``max_samples``
    samples (default: ``MAX_PLAN_SAMPLES``)."""
    from cli.errors import UserError
    from execution.plan_export import PlanTooLongError, skill_plan
    from schemas.execution.environment import Placement
    from schemas.skill import Skill
    from schemas.skill_plan import MAX_PLAN_SAMPLES

    if max_samples is not None and max_samples > MAX_PLAN_SAMPLES:
        raise UserError([f"--max-samples: at most {MAX_PLAN_SAMPLES}, got {max_samples}"])

    skill = Skill.model_validate_json(source.read_text())
    where = None if placement is None else Placement.model_validate_json(placement)
    try:
        plan = skill_plan(skill, placement=where, every=every, max_samples=max_samples or MAX_PLAN_SAMPLES)
    except PlanTooLongError as exc:
        raise UserError([f"--max-samples: {exc}"]) from None
    return plan.model_dump_json().encode(), f"plan of {source} ({len(plan.samples.t)} samples)"


def _remote(args: argparse.Namespace) -> tuple[bytes, str]:
    """The plan of the stored skill ``args.source`` (an id) from the API at ``args.url``."""
    from cli.errors import UserError
    from services.client import Client, ServiceError
    from services.service_url import service_url

    if not args.source.startswith("skill_"):
        raise UserError([f"{args.source}: no such file, and not a skill id (skill_...)"])
    try:
        with Client(service_url(args.url)) as client:
            data = client.skill_plan(args.source, every=args.every, max_samples=args.max_samples)
    except ServiceError as exc:
        raise UserError([str(exc)]) from None
    return data, f"plan of {args.source} from {service_url(args.url)}"


def _as_mcap(plan_json: bytes) -> bytes:
    """The plan ``plan_json`` (a ``SkillPlan``'s JSON, as the API and :func:`_local` give it) as MCAP: the same file
    ``GET /skills/{id}/plan?format=mcap`` serves."""
    from schemas.skill_plan import SkillPlan
    from services.telemetry_export import plan_mcap

    return plan_mcap(SkillPlan.model_validate_json(plan_json)).data


def _positive(text: str) -> int:
    """A positive whole number from the command line."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``plan`` to the `contact-skills` parser."""
    plan = commands.add_parser(
        "plan", help="export a skill's plan for a real cell (timed poses, CF, selection, force, gains): JSON or MCAP",
        description=cmd_plan.__doc__,
    )  # fmt: skip
    plan.add_argument("source", metavar="ID_OR_FILE", help="skill_... (from the API), or a local skill JSON file")
    plan.add_argument("-o", "--output", type=Path, required=True, help="file to write (JSON, or MCAP with --format)")
    plan.add_argument(
        "--format", choices=("json", "mcap"), default="json",
        help="json (default): the plan; mcap: the same plan as ROS 2 messages for Foxglove or a ROS 2 cell",
    )  # fmt: skip
    plan.add_argument("--every", type=_positive, default=1, metavar="N", help="keep every N-th control step")
    plan.add_argument(
        "--max-samples", type=_positive, metavar="N",
        help="refuse a plan of more samples (default and most: the API's bound, schemas.skill_plan.MAX_PLAN_SAMPLES)",
    )  # fmt: skip
    plan.add_argument(
        "--placement", metavar="JSON", help="a local skill's placement, e.g. '{\"translation_m\": [0.55, 0, 0.2]}'"
    )
    plan.add_argument("--url", help=f"{URL_HELP}, to fetch ids from")
    plan.set_defaults(run=cmd_plan)
