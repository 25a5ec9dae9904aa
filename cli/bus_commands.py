"""Subcommands of `contact-skills` for the Zenoh bus: router, worker, watch (lazy imports inside each command)."""

from __future__ import annotations

import argparse


def register(commands: argparse._SubParsersAction) -> None:
    """Add this group's subcommands to the `contact-skills` parser."""
