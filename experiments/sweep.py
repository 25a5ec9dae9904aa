"""``contact-skills sweep``: a robustness sweep driven through the running service (or an embedded one), as a user
does: record and learn the teacher's demonstration of a scenario (or take a stored skill), ``POST /sweeps``, follow
``GET /sweeps/{id}`` with a progress bar, then the tables (text and Markdown) and the figure
(``services.sweep_figure``).

The Markdown goes into the ``sweeps`` section of a RESULTS.md (``--results``): one subsection per skill, replaced
when the same scenario is swept again, so docs/RESULTS.md keeps a sweep of each skill side by side.
"""

from __future__ import annotations

import re
import sys
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from experiments.cases import DemoOptions
from experiments.stack import DemoError, ServiceClient, say, service_session
from schemas.sweep import SweepView, TrialResult
from services.machine import machine_line

SWEEPS_SECTION = "sweeps"
"""The generated section of RESULTS.md holding the sweeps (``services.doc_sections``)."""
POLL_S = 0.5
"""How often the progress bar asks the service, s."""


@dataclass
class SweepOptions:
    """What ``contact-skills sweep`` was asked for (the body of ``POST /sweeps`` and where the service is)."""

    body: dict[str, Any]
    """``SweepRequest`` fields but the skill (``controllers``, ``vary``, ``trials``, ``seed``, ...)."""
    scenario: str | None = None
    """Record and learn this teacher scenario first (when no ``skill_id``)."""
    skill_id: str | None = None
    record_seed: int = 0
    service: DemoOptions = field(default_factory=DemoOptions)
    timeout_s: float = 24 * 3600.0


@dataclass
class SweepOutcome:
    view: SweepView
    trials: list[TrialResult]
    skill_label: str
    wall_s: float
    """From the sweep's submission to its end, s."""
    service: str
    """Which service ran it."""
    workers: int


def _skill(client: ServiceClient, options: SweepOptions) -> tuple[str, str]:
    """The skill to sweep: (id, label); records and learns ``options.scenario`` when no id is given."""
    if options.skill_id is not None:
        return options.skill_id, options.skill_id
    started = time.perf_counter()
    demo = client.request(
        "POST", "/demonstrations/record", 201, json={"scenario": options.scenario, "seed": options.record_seed}
    )
    learned = client.request("POST", "/skills", 201, json={"demonstration_id": demo["id"], "skill_type": "auto"})
    kind = learned["skill"]["skill_type"]
    say(f"sweep: recorded {options.scenario} (seed {options.record_seed}) and learned a {kind} skill "
        f"{learned['id']} in {time.perf_counter() - started:.1f} s")  # fmt: skip
    return learned["id"], f"{options.scenario} ({kind}, teacher seed {options.record_seed})"


def _follow(client: ServiceClient, sweep_id: str, total: int, timeout_s: float) -> SweepView:
    """Poll the sweep until it ends, with a progress bar (executions finished, success rate per controller)."""
    from tqdm import tqdm

    tty = sys.stderr.isatty()
    bar = tqdm(total=total, desc="sweep", unit="run", file=sys.stderr, dynamic_ncols=True, disable=not tty)
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            view = SweepView.model_validate(client.request("GET", f"/sweeps/{sweep_id}", 200))
            bar.update(view.counts.finished - bar.n)
            rates = {s.controller.value: s.success_rate for s in view.controllers}
            bar.set_postfix_str(
                " ".join(f"{name} {rate:.0%}" for name, rate in rates.items() if rate is not None)
                + f" running {view.counts.running} queued {view.counts.queued}"
            )
            if view.status.value != "running":
                return view
            if time.monotonic() > deadline:
                raise DemoError(f"sweep {sweep_id} did not finish within {timeout_s:.0f} s")
            time.sleep(POLL_S)
    finally:
        bar.close()


def run_sweep(options: SweepOptions) -> SweepOutcome:
    """Run the sweep on the service at ``options.service.url`` (or an embedded one) and fetch its results."""
    timings: dict[str, float] = {}
    with service_session(options.service, timings) as (client, health, _endpoints, description):
        skill_id, label = _skill(client, options)
        started = time.perf_counter()
        created = client.request("POST", "/sweeps", 202, json={**options.body, "skill_id": skill_id})
        say(f"sweep: {created['id']}: {created['executions']} executions on {len(health['workers'])} worker(s); "
            f"live progress on Zenoh key {created['progress_key']}")  # fmt: skip
        view = _follow(client, created["id"], created["executions"], options.timeout_s)
        wall = time.perf_counter() - started
        trials = [TrialResult.model_validate(t) for t in client.request("GET", f"/sweeps/{created['id']}/trials", 200)]
        workers = len((client.health() or health).get("workers", []))
    return SweepOutcome(view, trials, label, wall, description, workers)


# --------------------------------------------------------------------------------------------------- tables


def _q(quantiles, key: str, digits: int = 2) -> str:
    return "–" if quantiles is None else f"{getattr(quantiles, key):.{digits}f}"


def summary_rows(view: SweepView) -> list[list[str]]:
    """One row per controller: success, the true RMS and max error quantiles, the touch-down peak, the failures."""
    rows = []
    for s in view.controllers:
        rate = "–" if s.success_rate is None else f"{s.success_rate:.0%} ({s.succeeded}/{s.finished})"
        rms, peak, touch = s.true_force_rms_error_pct, s.true_force_max_error_pct, s.touchdown_peak_ratio
        failures = "; ".join(f"{n}× {cause}" for cause, n in s.failures.items()) or "none"
        rows.append([
            s.controller.value, rate,
            f"{_q(rms, 'p10')} / {_q(rms, 'p50')} / {_q(rms, 'p90')}", _q(peak, "p50", 1) + " / " + _q(peak, "p90", 1),
            f"{_q(touch, 'p50')} / {_q(touch, 'max')}", failures,
        ])  # fmt: skip
    return rows


SUMMARY_HEADER = ["controller", "success", "true RMS % p10/p50/p90", "true max % p50/p90", "touch-down p50/max",
                  "failures"]  # fmt: skip


def sensitivity_rows(view: SweepView, top: int = 4) -> list[list[str]]:
    """Per controller its ``top`` parameters by importance: Spearman rho with the true RMS, success low/high half."""
    rows = []
    for s in view.controllers:
        ranked = [r for r in view.sensitivity if r.controller is s.controller][:top]
        for r in ranked:
            rho = "–" if r.spearman_rms is None else f"{r.spearman_rms:+.2f}"
            low = "–" if r.success_low_half is None else f"{r.success_low_half:.0%}"
            high = "–" if r.success_high_half is None else f"{r.success_high_half:.0%}"
            rows.append([s.controller.value, r.parameter.value, rho, low, high])
    return rows


SENSITIVITY_HEADER = ["controller", "parameter", "Spearman ρ (true RMS)", "success low half", "success high half"]


def text_table(header: list[str], rows: list[list[str]]) -> str:
    """An aligned plain-text table."""
    widths = [max(len(str(r[j])) for r in [header, *rows]) for j in range(len(header))]
    lines = ["  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)) for row in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    return "\n".join([*lines, *("| " + " | ".join(row) + " |" for row in rows)])


def _ranges(view: SweepView) -> str:
    vary = view.request["vary"]
    return ", ".join(
        f"{name} {spread['low']:g}..{spread['high']:g}{' (log)' if spread.get('log') else ''}"
        for name, spread in vary.items()
    )


def sweep_markdown(outcome: SweepOutcome, command: str, figure: str | None) -> str:
    """The subsection of one sweep for RESULTS.md: what was varied, the tables, the figure, how to regenerate."""
    view, request = outcome.view, outcome.view.request
    executions = view.counts.total
    lines = [
        f"### {outcome.skill_label}",
        "",
        f"`{command}`",
        "",
        f"{request['trials']} trials ({request['sampler']}, seed {request['seed']}) × {len(view.controllers)} "
        f"controllers = {executions} executions in {outcome.wall_s / 60:.1f} min on {outcome.workers} worker(s) "
        f"({executions / outcome.wall_s * 60:.0f} per minute; {view.counts.reruns} rerun after an infrastructure "
        f"failure); {datetime.now(UTC):%Y-%m-%d}. Varied (unknown to the controller): {_ranges(view)}. Success: "
        f"done, in contact ≥ {request['success_contact_ratio']:.0%} of the contact phase and TRUE normal-force RMS "
        f"error ≤ {request['success_rms_pct']:g} % of the reference force.",
        "",
        markdown_table(SUMMARY_HEADER, summary_rows(view)),
        "",
        "Which parameters drive the error (Spearman rank correlation with the true RMS error, an aborted trial "
        "ranking worst; success rate below and above the parameter's median), the four strongest per controller:",
        "",
        markdown_table(SENSITIVITY_HEADER, sensitivity_rows(view)),
        "",
    ]
    if figure:
        lines += [f"![sweep of {outcome.skill_label}]({figure})", ""]
    return "\n".join(lines)


def merged_sweeps_section(existing: str | None, key: str, subsection: str) -> str:
    """The body of the sweeps section with ``subsection`` (marked by ``key``) replacing its previous version."""
    intro = (
        "## Robustness sweeps\n\nGenerated by `contact-skills sweep ... --results docs/RESULTS.md` (one subsection "
        "per skill; the command that made it is in each). Each trial draws the cell's variation (Latin hypercube); "
        "every controller runs the same trials.\n"
    )
    parts: dict[str, str] = {}
    if existing:
        for match in re.finditer(r"<!-- sweep:(\S+) -->\n(.*?)<!-- /sweep:\1 -->", existing, flags=re.S):
            parts[match.group(1)] = match.group(2)
    parts[key] = subsection
    body = [intro] + [f"<!-- sweep:{k} -->\n{v.rstrip()}\n<!-- /sweep:{k} -->\n" for k, v in parts.items()]
    return "\n".join(body) + f"\n{machine_line()}\n"
