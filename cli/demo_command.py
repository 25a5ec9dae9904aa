"""``contact-skills demo``: the paper's experiments end to end against the running service (or an embedded one).

The logic is ``experiments.paper_demo`` (the runner; HTTP + Zenoh client side, cases, report) and
``services.figures`` (the figures); this module only parses the options, runs it and prints the results table.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from services.service_url import URL_HELP


def cmd_demo(args: argparse.Namespace) -> int:
    """``contact-skills demo``: record, learn and execute the paper's slide (Fig. 3) and contour (Fig. 4) trials,
    and upload, learn and execute the KU Leuven recordings on their rebuilt work pieces, with our controller and
    both baselines through the service, then print the results table and write RESULTS.md and the figures (to
    ./demo-output unless --out says; --out docs regenerates docs/RESULTS.md and docs/figures). Starts the embedded
    stack (`contact-skills up`) if nothing answers at --url. Exits 1 when a case did not finish or a target is
    MISSED (--report-only: only when a case did not finish)."""
    import time

    from experiments.paper_demo import DemoError, DemoOptions, run_demo, text_table
    from services.service_url import service_url

    shown = ["contact-skills", "demo", *sys.argv[2:]] if sys.argv[1:2] == ["demo"] else ["contact-skills", "demo"]
    options = DemoOptions(
        url=service_url(args.url),
        workers=args.workers,
        quick=args.quick,
        out=args.out,
        seed=args.seed,
        db=args.db,
        connect=[e for v in args.connect or [] for e in v.split(",") if e.strip()] or None,
        prefix=args.prefix,
        command=shlex.join(shown),
    )
    started = time.perf_counter()
    try:
        report = run_demo(options)
    except DemoError as exc:
        print(f"contact-skills demo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("contact-skills demo: interrupted", file=sys.stderr)
        return 130
    print()
    print(text_table(report.outcomes))
    print()
    for verdict in report.verdicts:
        print(f"{'MET   ' if verdict.met else 'MISSED'} {verdict.name}: {verdict.detail}")
    print()
    timings = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in report.timings.items())
    print(f"timings: {timings}")
    print(f"results: {report.results_path}; figures: {', '.join(str(p) for p in report.figures)}")
    print(f"demo finished in {time.perf_counter() - started:.1f} s")
    if not report.all_finished:
        return 1
    missed = [verdict.name for verdict in report.verdicts if not verdict.met]
    if missed and not args.report_only:
        print(f"contact-skills demo: {len(missed)} target(s) MISSED (exit 1; --report-only exits 0)", file=sys.stderr)
        return 1
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the `contact-skills` parser."""
    from experiments.cases import DEFAULT_OUT

    demo = commands.add_parser(
        "demo",
        help="reproduce the paper's experiments (slide Fig. 3, contour Fig. 4) and run the KU Leuven recordings, "
        "with baselines, through the service",
        description=cmd_demo.__doc__,
    )
    demo.add_argument(
        "--url", help=f"{URL_HELP}; if none answers there (loopback), the embedded stack is started on its port"
    )
    demo.add_argument("--workers", type=int, default=2, help="sim workers of the embedded stack (default 2)")
    demo.add_argument(
        "--quick", action="store_true", help="the reduced case set (one KU Leuven trial, ours only; used by the test)"
    )
    demo.add_argument(
        "--out",
        type=Path,
        default=DEFAULT_OUT,
        help=f"where RESULTS.md and figures/ go (default ./{DEFAULT_OUT}; `--out docs` regenerates the tracked docs)",
    )
    demo.add_argument("--seed", type=int, default=0, help="seed of the teacher's demonstrations (default 0)")
    demo.add_argument("--db", type=Path, help="database of the embedded stack (default: a temporary file)")
    demo.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint for the live view (default: the one the service reports)",
    )
    demo.add_argument("--prefix", help="Zenoh key-expression prefix (default $CONTACT_SKILLS_ZENOH_PREFIX or cskills)")
    demo.add_argument(
        "--report-only",
        action="store_true",
        help="exit 0 when every case ran, even if a target is MISSED (default: a missed target exits 1)",
    )
    demo.set_defaults(run=cmd_demo)
