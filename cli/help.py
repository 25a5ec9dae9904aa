"""How `contact-skills --help` reads: plain text (no RST markup from the docstrings it reuses), paragraphs filled, and
usage examples under every subcommand (:data:`EXAMPLES`)."""

from __future__ import annotations

import argparse
import inspect
import re
import textwrap

EXAMPLES: dict[str, list[str]] = {
    "learn": [
        "contact-skills learn scratch/slide_tilted.csv -o scratch/skill.json --figure scratch/learn.png",
        "contact-skills learn data/kuleuven_contour/contour_a_1.csv --quaternion-order wxyz --wrench measured-on-tool "
        "--wrench-frame tool --no-tare -o scratch/contour.json",
        "contact-skills learn scratch/wipe.csv --rate 100 --quaternion-order wxyz --wrench measured-on-tool "
        "--wrench-frame tool -o scratch/wipe.json",
        "contact-skills learn demo.mcap --wrench measured-on-tool --tool-frame tool -o scratch/skill.json",
        "contact-skills learn bag_dir/ --wrench-topic /ft/raw --tf world tool0 -o scratch/skill.json",
        "contact-skills learn demo.bag --wrench measured-on-tool --tool-frame tool0 -o scratch/skill.json",
    ],
    "demo-learn": ["contact-skills demo-learn --out-dir scratch/kuleuven"],
    "record": [
        "contact-skills record slide_tilted -o scratch/slide_tilted.csv --truth scratch/slide_tilted_truth.json",
        "contact-skills record wipe_tilted --style kinesthetic --strokes 3 --seed 2 -o scratch/wipe.csv",
    ],
    "simulate": [
        "contact-skills simulate scratch/skill.json --unknown-offset 0 0 0.03 --figure scratch/sim.png",
        "contact-skills simulate scratch/skill.json --controller impedance --json scratch/metrics.json",
    ],
    "export": [
        "contact-skills export exec_0c1d2e3f4a5b -o scratch/run.mcap         # from the API at --url",
        "contact-skills export demo_3f2a9c01b2d4 -o scratch/demo.csv --t0 2 --t1 6",
        "contact-skills export scratch/slide_tilted.csv -o scratch/slide_tilted.mcap   # a local file, no API",
    ],
    "plan": [
        "contact-skills plan skill_5e6f7a8b9c0d -o scratch/plan.json --every 10   # from the API at --url",
        "contact-skills plan scratch/skill.json -o scratch/plan.json --placement '{\"translation_m\": [0.55, 0, 0.2]}'",
        "contact-skills plan scratch/skill.json -o scratch/plan.mcap --format mcap --every 10   # for Foxglove, ROS 2",
    ],
    "router": [
        "contact-skills router --listen tcp/127.0.0.1:7447",
        "contact-skills router --listen tls/0.0.0.0:7447 --users bus-keys/users.txt --tls-cert bus-keys/router.pem "
        "--tls-key bus-keys/router.key",
    ],
    "bus-keys": [
        "contact-skills bus-keys bus-keys --host sim-router.lan --workers 2 --endpoint tls/sim-router.lan:7447",
    ],
    "worker": [
        "contact-skills worker --connect tcp/127.0.0.1:7447 --id worker-a",
        "contact-skills worker --connect tls/sim-router.lan:7447 --zenoh-user worker-1 --tls-ca bus-keys/ca.pem",
    ],
    "watch": [
        "contact-skills watch exec_0c1d2e3f4a5b",
        "contact-skills watch exec_0c1d2e3f4a5b --timeout 60 --url http://127.0.0.1:8000",
    ],
    "api": [
        "contact-skills api --port 8000 --db contact_skills.db",
        "contact-skills api --connect tcp/127.0.0.1:7447",
        "contact-skills api --no-bus",
    ],
    "warm-up": ["contact-skills warm-up"],
    "up": [
        "contact-skills up",
        "contact-skills up --workers 2 --port 8001 --zenoh-port 7448 --db scratch/service.db",
    ],
    "demo": [
        "contact-skills demo --quick",
        "contact-skills demo --out docs --report-only",
    ],
    "sweep": [
        "contact-skills sweep slide_flat --trials 24 --figure scratch/sweep.png",
        "contact-skills sweep --skill-id skill_0a1b2c3d4e5f --controllers hybrid_cf --vary offset_z_m=-0.03:0.03 "
        "--vary contact_stiffness_n_m=1e4:1e6:log --trials 50 --json scratch/sweep.json",
    ],
}
"""Usage examples of every subcommand, shown at the end of its ``--help``."""

EXAMPLES_HEADING = "examples:"
_MARKUP = re.compile(r"`+")


def plain(text: str) -> str:
    """``text`` without RST markup: backticks (``code``, `refs`) removed."""
    return _MARKUP.sub("", text)


class PlainHelpFormatter(argparse.HelpFormatter):
    """Docstring text cleaned (indentation, markup) and filled by paragraph; a paragraph with indented lines, and the
    examples epilog, kept as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith(EXAMPLES_HEADING):  # the epilog: as written
            return "\n".join(indent + line for line in text.splitlines())
        paragraphs = re.split(r"\n\s*\n", inspect.cleandoc(plain(text)))
        filled = []
        for paragraph in paragraphs:
            lines = paragraph.splitlines()
            if any(line.startswith(" ") for line in lines[1:]):
                filled.append("\n".join(indent + line for line in lines))
            else:
                filled.append(textwrap.fill(" ".join(paragraph.split()), width, initial_indent=indent,
                                            subsequent_indent=indent))  # fmt: skip
        return "\n\n".join(filled)

    def _split_lines(self, text: str, width: int) -> list[str]:
        return super()._split_lines(plain(text), width)


def examples_epilog(name: str) -> str | None:
    """The ``examples:`` block of subcommand ``name``."""
    lines = EXAMPLES.get(name)
    return None if lines is None else EXAMPLES_HEADING + "\n" + "\n".join(f"  {line}" for line in lines)


def polish(parser: argparse.ArgumentParser) -> None:
    """Give ``parser`` and every subcommand the plain formatter, and each subcommand its examples."""
    parser.formatter_class = PlainHelpFormatter
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, subparser in action.choices.items():
                subparser.formatter_class = PlainHelpFormatter
                subparser.epilog = examples_epilog(name) or subparser.epilog
