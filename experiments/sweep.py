"""``contact-skills sweep``: a robustness sweep driven through the running service (or an embedded one), as a user
does: record and learn the teacher's demonstration of a scenario (or take a stored skill), ``POST /sweeps``, follow
``GET /sweeps/{id}`` with a progress bar, then the tables (text and Markdown) and the figure
(``services.sweep_figure``).

The Markdown goes into the ``sweeps`` section of a RESULTS.md (``--results``): one subsection per skill, replaced
when the same scenario is swept again, so docs/RESULTS.md keeps a sweep of each skill side by side.
"""

from __future__ import annotations

import json
import re
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from pydantic import JsonValue

from experiments.cases import DemoOptions
from experiments.stack import DemoError, ServiceClient, say, service_session
from schemas.sweep import SweepState, SweepView, TrialResult
from services.machine import machine_line

SWEEPS_SECTION = "sweeps"
"""The generated section of RESULTS.md holding the sweeps (``services.doc_sections``)."""
STATUS_POLL_S = 0.5
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
    world_ranges: bool = False
    """Add to ``vary`` the default ranges of what the skill's world has beyond a table (``CYLINDER_RANGES`` for a
    skill taught on a cylinder): the CLI's default sweep."""


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


def _skill(client: ServiceClient, options: SweepOptions) -> tuple[str, str, dict[str, JsonValue]]:
    """The skill to sweep: (id, label, the skill); records and learns ``options.scenario`` when no id is given."""
    if options.skill_id is not None:
        stored = client.request("GET", f"/skills/{options.skill_id}", 200)
        return options.skill_id, options.skill_id, stored["skill"]
    started = time.perf_counter()
    demo = client.request(
        "POST", "/demonstrations/record", 201, json={"scenario": options.scenario, "seed": options.record_seed}
    )
    learned = client.request("POST", "/skills", 201, json={"demonstration_id": demo["id"], "skill_type": "auto"})
    kind = learned["skill"]["skill_type"]
    say(f"sweep: recorded {options.scenario} (seed {options.record_seed}) and learned a {kind} skill "
        f"{learned['id']} in {time.perf_counter() - started:.1f} s")  # fmt: skip
    return learned["id"], f"{options.scenario} ({kind}, teacher seed {options.record_seed})", learned["skill"]


def _world_ranges(skill: dict[str, Any], body: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The default ranges of what the sweep's world has beyond a table (``schemas.sweep.CYLINDER_RANGES`` when its
    trials run on the skill's taught cylinder), as ``vary`` entries."""
    from schemas.execution import ExecutionSettings
    from schemas.skill import Skill
    from schemas.sweep import CYLINDER_RANGES
    from skills.sweeps import taught_cylinder_world

    environment = ExecutionSettings.model_validate(body.get("settings") or {}).environment
    if taught_cylinder_world(Skill.model_validate(skill), body.get("scenario"), environment) is None:
        return {}
    return {name.value: spread.model_dump() for name, spread in CYLINDER_RANGES.items()}


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
            if view.status is not SweepState.running:
                return view
            if time.monotonic() > deadline:
                raise DemoError(f"sweep {sweep_id} did not finish within {timeout_s:.0f} s")
            time.sleep(STATUS_POLL_S)
    finally:
        bar.close()


def run_sweep(options: SweepOptions) -> SweepOutcome:
    """Run the sweep on the service at ``options.service.url`` (or an embedded one) and fetch its results."""
    timings: dict[str, float] = {}
    with service_session(options.service, timings) as (client, health, _endpoints, description):
        skill_id, label, skill = _skill(client, options)
        body = {**options.body, "skill_id": skill_id}
        if options.world_ranges:
            body["vary"] = {**body["vary"], **_world_ranges(skill, body)}
        started = time.perf_counter()
        created = client.request("POST", "/sweeps", 202, json=body)
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


def _counted(counts: dict[str, int]) -> str:
    return "; ".join(f"{n}× {name}" for name, n in counts.items()) or "none"


def summary_rows(view: SweepView) -> list[list[str]]:
    """One row per controller: success, the true RMS and max error quantiles, the touch-down peak, the failures by
    verdict check and the warnings."""
    rows = []
    for s in view.controllers:
        rate = "–" if s.success_rate is None else f"{s.success_rate:.0%} ({s.succeeded}/{s.finished})"
        rms, peak, touch = s.true_force_rms_error_pct, s.true_force_max_error_pct, s.touchdown_peak_ratio
        rows.append([
            s.controller.value, rate,
            f"{_q(rms, 'p10')} / {_q(rms, 'p50')} / {_q(rms, 'p90')}", _q(peak, "p50", 1) + " / " + _q(peak, "p90", 1),
            f"{_q(touch, 'p50')} / {_q(touch, 'max')}", _counted(s.failures), _counted(s.warnings),
        ])  # fmt: skip
    return rows


SUMMARY_HEADER = ["controller", "success", "true RMS % p10/p50/p90", "true max % p50/p90", "touch-down p50/max",
                  "failures (verdict checks)", "warnings"]  # fmt: skip


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


def _changed(given: Mapping[str, JsonValue], default: Mapping[str, JsonValue], prefix: str = "") -> list[str]:
    """``name value`` of every field of ``given`` (settings as JSON) that differs from ``default`` (nested fields
    dotted)."""
    changed = []
    for name, value in given.items():
        if isinstance(value, dict) and isinstance(nested := default.get(name), dict):
            changed += _changed(value, nested, f"{prefix}{name}.")
        elif value != default.get(name):
            changed.append(f"{prefix}{name} {json.dumps(value)}")
    return changed


def _settings(view: SweepView) -> str:
    """The sweep's base execution settings that differ from the defaults (the telemetry and the two tolerances the
    sweep sets are left out), in words."""
    from schemas.execution import ExecutionSettings
    from schemas.sweep import SWEEP_TOLERANCES

    given = dict(view.request["settings"])
    default = ExecutionSettings().model_dump(mode="json")
    given.pop("telemetry", None)
    given["tolerances"] = {k: v for k, v in given["tolerances"].items() if k not in SWEEP_TOLERANCES.values()}
    return ", ".join(_changed(given, default)) or "the defaults"


def _criteria(view: SweepView) -> str:
    """The verdict's checks with the sweep's tolerances, in words."""
    request, tolerances = view.request, view.request["settings"]["tolerances"]
    return (
        f"finished, in contact ≥ {request['success_contact_ratio']:.0%} of the contact phase, TRUE normal-force RMS "
        f"error ≤ {request['success_rms_pct']:g} % of the reference force, largest steady error ≤ "
        f"{tolerances['true_force_max_pct']:g} % and touch-down peak ≤ {tolerances['touchdown_ratio']:g}× the target"
    )


def failure_lines(view: SweepView, trials: list[TrialResult]) -> list[str]:
    """Per controller, each failure cause with where it happened: over quarters of the trials along the parameter
    that separates them best (``skills.sweeps.cause_drivers``), how many of each quarter had it."""
    from skills.sweeps import cause_drivers

    lines = []
    for s in view.controllers:
        mine = [t for t in trials if t.controller is s.controller and t.success is not None]
        drivers = cause_drivers([t.parameters for t in mine], [t.causes for t in mine])
        if not drivers:
            lines.append(f"- **{s.controller.value}**: no failure.")
            continue
        parts = []
        for d in drivers:
            where = ", ".join(f"{n}/{total} at {low:.3g}..{high:.3g}" for low, high, n, total in d.bins)
            parts.append(f"`{d.cause}` in {d.count} of {d.finished} trials, by {d.parameter.value}: {where}")
        lines.append(f"- **{s.controller.value}**: " + "; ".join(parts) + ".")
    return lines


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
        f"failure); {datetime.now(UTC):%Y-%m-%d}. Varied (unknown to the controller): {_ranges(view)}. Settings: "
        f"{_settings(view)}. Success: the execution's verdict passes: {_criteria(view)}. A trial that fails several "
        "checks counts under each; a warning (`surface_found`: the surface met farther from where it was taught "
        "than the window) fails nothing.",
        "",
        markdown_table(SUMMARY_HEADER, summary_rows(view)),
        "",
        "Where each failure happened (the quarters of the trials along the varied parameter that separates the "
        "trials with that failure best: trials with it / trials in the quarter; one parameter at a time, so a failure "
        "that several drive together, or that competes with an abort at the same values, shows weakly in each):",
        "",
        *failure_lines(view, outcome.trials),
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
        "every controller runs the same trials; a trial succeeds when its execution's verdict passes.\n"
    )
    parts: dict[str, str] = {}
    if existing:
        for match in re.finditer(r"<!-- sweep:(\S+) -->\n(.*?)<!-- /sweep:\1 -->", existing, flags=re.S):
            parts[match.group(1)] = match.group(2)
    parts[key] = subsection
    body = [intro] + [f"<!-- sweep:{k} -->\n{v.rstrip()}\n<!-- /sweep:{k} -->\n" for k, v in parts.items()]
    return "\n".join(body) + f"\n{machine_line()}\n"
