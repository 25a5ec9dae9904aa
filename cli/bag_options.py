"""``contact-skills learn BAG``: the options of a ROS 2 bag import (``services.bag_import``), checked against the
CSV-only ones."""

from __future__ import annotations

import argparse


def bag_demonstration(args: argparse.Namespace):  # -> schemas.Demonstration
    """Import the bag ``args.file`` with the ``learn`` options; a CSV-only option is a user error."""
    from cli.main import UserError

    csv_only = [flag for flag, value in (("--columns", args.columns), ("--quaternion-order", args.quaternion_order),
                                         ("--dt", args.dt)) if value]  # fmt: skip
    if csv_only:
        raise UserError([f"{', '.join(csv_only)}: for CSV files only; {args.file} is a ROS 2 bag"])
    try:
        from services.bag_import import demonstration_from_bag
    except ImportError as exc:  # rosbags is in the service extra
        raise UserError([f"reading ROS 2 bags needs the service extra (pip install -e '.[service]'): {exc}"]) from None
    return demonstration_from_bag(
        args.file,
        wrench_topic=args.wrench_topic,
        pose_topic=args.pose_topic,
        tf_frames=tuple(args.tf) if args.tf else None,
        tool_frame=args.tool_frame,
        wrench_frame=args.wrench_frame,
        wrench_convention=args.wrench_convention,
        rate_hz=args.rate,
        tare=not args.no_tare,
        tare_window_s=tuple(args.tare_window) if args.tare_window else None,
        force_offset=args.force_offset,
    )
