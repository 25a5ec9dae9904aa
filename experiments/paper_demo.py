"""``contact-skills demo``: the paper's experiments (section 6, Fig. 3 slide and Fig. 4 contour) reproduced end to end
against the RUNNING service, the way a user drives it, with both baselines, figures and a results page.

- HTTP (httpx) for everything stored: ``POST /demonstrations/record`` (the scripted teacher records on a sim
  worker), ``POST /skills`` (learn), ``POST /executions`` (run), ``GET /executions/{id}`` (metrics) and
  ``GET /executions/{id}/telemetry`` (the recorded stream, for the figures).
- Zenoh for live progress: one subscriber on ``P/exec/*/status`` shows the phase of every running execution.
- If nothing answers ``GET /health`` at the URL (loopback), the embedded stack is started
  (``contact-skills up --workers N`` as a child process, a temporary database), used and stopped at the end.

Cases (every one with the three controllers, ``hybrid_cf`` = ours, ``impedance``, ``hybrid_world_z``):

- slide on the flat table, table height shifted WITHOUT telling the controller (``unknown_offset`` z: -4..+4 cm);
- slide on the 15° tilted table, at the taught height and 1 cm higher (unknown);
- contour over the cylinder moved as in the paper with a KNOWN offset (trial 1: +0.08 m z, trial 2: + 0.02 m y,
  trial 3: + 0.02 m x) and 1 cm higher without telling the controller. A known ``offset`` moves the simulated
  work piece AND the skill (``sim_worker.executor`` builds the world shifted by ``offset + unknown_offset``), so
  the known trials send ``offset`` alone: the cylinder really moves by the stated amount, not twice it.

Targets (:data:`SLIDE_RMS_PCT`, :data:`CONTOUR_RMS_PCT`, :data:`MIN_CONTACT_RATIO`, :data:`BASELINE_FACTOR`) are
judged per row and reported MET or MISSED as measured; a miss is explained, never hidden.
The figure code lives in ``services.figures``; this module only fetches, schedules and reports.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from services.local_processes import free_port
from services.machine import machine_line

SLIDE_RMS_PCT = 3.0
"""Ours: CF-z force RMS error below this % of the learned force in every slide case."""
CONTOUR_RMS_PCT = 8.0
"""Ours: CF-z force RMS error below this % of the learned profile's peak in every contour case."""
MIN_CONTACT_RATIO = 0.99
"""Ours: share of the contact phase in contact, at least."""
BASELINE_FACTOR = 3.0
"""Each baseline's CF-z force RMS error at least this many times ours, on the tilted plane and on the contour."""

OURS = "hybrid_cf"
CONTROLLERS = ("hybrid_cf", "impedance", "hybrid_world_z")
FINAL = frozenset({"done", "aborted", "failed"})
TELEMETRY_BATCH = 100
"""Control steps per telemetry message: pace fast produces ~10 000 samples/s per worker; the demo watches statuses,
so big batches spare the bus and the API."""
TELEMETRY_EVERY = 5
"""The figures read every N-th telemetry sample (1 kHz -> 200 Hz)."""
EXECUTION_TIMEOUT_S = 600.0
"""An execution not finished after this long (wall) is aborted and reported failed."""
READY_TIMEOUT_S = 180.0
RECORD_TIMEOUT_S = 300.0


class DemoError(RuntimeError):
    """The demo cannot go on (no service, a request refused); the message says why."""


# --------------------------------------------------------------------------------------------------- the cases


@dataclass(frozen=True)
class SkillSpec:
    """One demonstration to record and the skill to learn from it."""

    key: str
    scenario: str
    skill_type: str
    title: str
    figure: str
    """The paper figure it reproduces."""


SKILLS: dict[str, SkillSpec] = {
    "slide_flat": SkillSpec("slide_flat", "slide_flat", "slide", "slide on the flat table", "Fig. 3"),
    "slide_tilted": SkillSpec("slide_tilted", "slide_tilted", "slide", "slide on the 15° tilted table", "Fig. 3"),
    "contour": SkillSpec("contour", "contour_cylinder", "contour", "contour over the cylinder", "Fig. 4"),
}


@dataclass(frozen=True)
class Case:
    """One world change in which a skill is executed (with each of ``controllers``)."""

    skill: str
    label: str
    short: str
    """A few characters for the live line."""
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    unknown_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    controllers: tuple[str, ...] = CONTROLLERS

    @property
    def kind(self) -> str:
        return SKILLS[self.skill].skill_type

    @property
    def unknown_shift(self) -> bool:
        return any(abs(v) > 0 for v in self.unknown_offset)

    @property
    def baseline_target(self) -> bool:
        """Whether the baselines must be :data:`BASELINE_FACTOR` times worse here (tilted plane, contour)."""
        return self.skill in ("slide_tilted", "contour")


def cases(quick: bool = False) -> list[Case]:
    """The demo's cases; ``quick``: the reduced set of the test (the bounds still checked on each)."""
    contour_known = [
        Case("contour", "trial 1: cylinder +8 cm z (known)", "contour T1", offset=(0.0, 0.0, 0.08)),
        Case("contour", "trial 2: cylinder +8 cm z, +2 cm y (known)", "contour T2", offset=(0.0, 0.02, 0.08)),
        Case("contour", "trial 3: cylinder +8 cm z, +2 cm y, +2 cm x (known)", "contour T3", offset=(0.02, 0.02, 0.08)),
    ]
    contour_unknown = Case("contour", "cylinder +1 cm z (unknown)", "contour +1cm?", unknown_offset=(0.0, 0.0, 0.01))
    tilted_shift = Case(
        "slide_tilted", "tilted table +1 cm z (unknown)", "tilted +1cm?", unknown_offset=(0.0, 0.0, 0.01)
    )
    if quick:
        return [
            Case("slide_flat", "table 0 cm", "flat 0cm", controllers=(OURS,)),
            Case(
                "slide_flat",
                "table +2 cm (unknown)",
                "flat +2cm?",
                unknown_offset=(0.0, 0.0, 0.02),
                controllers=(OURS,),
            ),
            tilted_shift,
            replace(contour_known[2], controllers=(OURS,)),
            contour_unknown,
        ]
    flat = [
        Case(
            "slide_flat",
            f"table {dz:+d} cm (unknown)" if dz else "table 0 cm",
            f"flat {dz:+d}cm" + ("?" if dz else ""),
            unknown_offset=(0.0, 0.0, dz / 100),
        )
        for dz in (-4, -2, 0, 2, 4)
    ]
    tilted = [Case("slide_tilted", "tilted table, taught height", "tilted 0cm"), tilted_shift]
    return [*flat, *tilted, *contour_known, contour_unknown]


# --------------------------------------------------------------------------------------------------- outcomes


@dataclass
class Outcome:
    """One execution: its case and controller, what the service reported, and the verdict of its target."""

    case: Case
    controller: str
    execution_id: str | None = None
    worker_id: str | None = None
    status: str = "pending"
    metrics: dict[str, Any] | None = None
    error: str | None = None
    wall_s: float = 0.0
    verdict: str = ""
    met: bool | None = None
    """True/False when a target applies to this row, None when none does."""
    ratio: float | None = None
    """Baselines: force RMS error / ours in the same case."""

    def metric(self, name: str) -> float | None:
        value = (self.metrics or {}).get(name)
        return None if value is None else float(value)

    @property
    def final(self) -> str:
        """The final phase, with the abort reason if any."""
        m = self.metrics or {}
        phase = m.get("phase") or self.status
        reason = m.get("abort_reason") or self.error
        return f"{phase} ({reason})" if reason and phase != "done" else str(phase)


@dataclass
class TargetVerdict:
    name: str
    met: bool
    detail: str


def _fmt(value: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "—" if value is None else f"{value * scale:.{digits}f}"


def judge(outcomes: list[Outcome]) -> list[TargetVerdict]:
    """Judge every row (sets ``verdict``, ``met``, ``ratio``) and return the per-target verdicts."""
    ours = {o.case: o for o in outcomes if o.controller == OURS}
    for o in outcomes:
        if o.controller == OURS:
            limit = SLIDE_RMS_PCT if o.case.kind == "slide" else CONTOUR_RMS_PCT
            rms, contact = o.metric("force_rms_error_pct"), o.metric("contact_ratio")
            problems = []
            if o.status != "done":
                problems.append(f"ended {o.final}")
            if rms is None or rms >= limit:
                problems.append(f"RMS {_fmt(rms)} % ≥ {limit:g} %")
            if contact is None or contact < MIN_CONTACT_RATIO:
                problems.append(f"contact {_fmt(contact, 100)} % < {100 * MIN_CONTACT_RATIO:g} %")
            o.met = not problems
            o.verdict = (
                f"MET (< {limit:g} %, contact ≥ {100 * MIN_CONTACT_RATIO:g} %)"
                if o.met
                else ("MISSED: " + "; ".join(problems))
            )
        elif o.case.baseline_target:
            mine = ours.get(o.case)
            theirs = o.metric("force_rms_error_n")
            reference = mine.metric("force_rms_error_n") if mine is not None else None
            if o.status == "aborted" and theirs is None:  # tripped a safety limit before any steady contact
                o.met, o.verdict = True, f"MET (the baseline did not finish: {o.final})"
            elif theirs is None or not reference:
                o.met, o.verdict = False, "MISSED: no force error to compare"
            else:
                o.ratio = theirs / reference
                o.met = o.ratio >= BASELINE_FACTOR
                o.verdict = f"{'MET' if o.met else 'MISSED'}: {o.ratio:.1f}x ours (target ≥ {BASELINE_FACTOR:g}x)"
        else:
            o.met, o.verdict = None, "— (no target on the flat table)"
    verdicts = []
    for kind, limit, what in (("slide", SLIDE_RMS_PCT, "learned force"), ("contour", CONTOUR_RMS_PCT, "peak")):
        rows = [o for o in outcomes if o.controller == OURS and o.case.kind == kind]
        if not rows:
            continue
        worst = max(rows, key=lambda o: o.metric("force_rms_error_pct") or float("inf"))
        verdicts.append(
            TargetVerdict(
                f"ours ({OURS}): CF-z force RMS error < {limit:g} % of the {what} in every {kind} case",
                all(o.status == "done" and (o.metric("force_rms_error_pct") or float("inf")) < limit for o in rows),
                f"worst {_fmt(worst.metric('force_rms_error_pct'))} % ({worst.case.label}); {len(rows)} cases",
            )
        )
    rows = [o for o in outcomes if o.controller == OURS]
    if rows:
        worst = min(rows, key=lambda o: o.metric("contact_ratio") or 0.0)
        verdicts.append(
            TargetVerdict(
                f"ours: contact ratio ≥ {100 * MIN_CONTACT_RATIO:g} % in every case",
                all((o.metric("contact_ratio") or 0.0) >= MIN_CONTACT_RATIO for o in rows),
                f"lowest {_fmt(worst.metric('contact_ratio'), 100)} % ({worst.case.label})",
            )
        )
    for skill, where in (("slide_tilted", "on the tilted plane"), ("contour", "on the contour")):
        for controller in CONTROLLERS[1:]:
            rows = [o for o in outcomes if o.controller == controller and o.case.skill == skill]
            if not rows:
                continue
            parts = [f"{o.case.label}: {f'{o.ratio:.1f}x' if o.ratio is not None else o.verdict}" for o in rows]
            verdicts.append(
                TargetVerdict(
                    f"{controller} ≥ {BASELINE_FACTOR:g}x ours in force RMS error {where}",
                    all(o.met for o in rows),
                    "; ".join(parts),
                )
            )
    return verdicts


def _impedance_stiffness() -> float:
    """CF-z stiffness of the default gains (the demo sends none), N/m."""
    from schemas.execution import ControllerGains

    return float(ControllerGains().translational_stiffness_n_per_m[2])


def explanations(outcomes: list[Outcome]) -> list[str]:
    """Why each missed target row missed, from what was measured (one paragraph per baseline and skill, or row)."""
    notes = []
    k = _impedance_stiffness()
    grouped: dict[str, list[Outcome]] = {}
    for o in outcomes:
        if o.met is False and o.controller == "impedance" and not o.case.unknown_shift and o.ratio is not None:
            grouped.setdefault(o.case.skill, []).append(o)
    for skill, rows in grouped.items():
        listed = "; ".join(
            f"{o.case.label}: {o.ratio:.1f}x ({_fmt(o.metric('force_rms_error_pct'))} % vs "
            f"{_fmt(_ours(outcomes, o.case, 'force_rms_error_pct'))} %)"
            for o in rows
        )
        reference = rows[0].metric("force_reference_n") or 0.0
        known = any(any(o.case.offset) for o in rows)
        where = "a KNOWN offset (the skill moves with the work piece)" if known else "the taught geometry"
        text = (
            f"**impedance on the {SKILLS[skill].title.removeprefix('slide on the ').removeprefix('contour over the ')}"
            f" — {listed}.** Pure impedance (S = I, no force loop) presses only through its reference, placed "
            f"f/k = {reference:.1f} N{' (the profile peak)' if SKILLS[skill].skill_type == 'contour' else ''} / "
            f"{k:.0f} N/m = {1e3 * reference / k:.1f} mm beyond the surface where the skill "
            f"expects it. With {where} the surface is exactly there, so its force error is only its position error "
            f"along CF z times the stiffness ({k:.0f} N/m: 0.1 mm is {0.1e-3 * k:.1f} N); ours is still better (it "
            "closes a force loop) but not 3x. The baseline is not robust: "
        )
        shifted = [
            x for x in outcomes if x.controller == "impedance" and x.case.skill == skill and x.case.unknown_shift
        ]
        if shifted:
            text += "with an UNKNOWN shift of the same work piece it is " + ", ".join(
                f"{x.ratio:.0f}x worse than ours ({_fmt(x.metric('force_rms_error_pct'), digits=0)} %, {x.case.label})"
                if x.ratio is not None
                else f"{x.final} ({x.case.label})"
                for x in shifted
            )
            text += "."
        else:
            text += f"any unknown shift Δ of the surface adds k·Δ of force error ({k * 0.01:.0f} N per cm)."
        notes.append(text)
    for o in outcomes:
        if o.met is not False or o in [r for rows in grouped.values() for r in rows]:
            continue
        ours = _ours(outcomes, o.case, "force_rms_error_pct")
        notes.append(
            f"**{o.controller}, {SKILLS[o.case.skill].title}, {o.case.label}: {o.verdict}** — measured force RMS "
            f"{_fmt(o.metric('force_rms_error_pct'))} % (ours {_fmt(ours)} %), max "
            f"{_fmt(o.metric('force_max_error_pct'))} %, contact {_fmt(o.metric('contact_ratio'), 100)} %, "
            f"final {o.final}."
        )
    return notes


def observations(outcomes: list[Outcome]) -> list[str]:
    """Rows without a target that did not finish or lost contact, with the arithmetic of why (impedance)."""
    notes = []
    k = _impedance_stiffness()
    for o in outcomes:
        contact = o.metric("contact_ratio")
        if o.met is not None or (o.status == "done" and (contact is None or contact >= MIN_CONTACT_RATIO)):
            continue
        what = f"**{o.controller}, {SKILLS[o.case.skill].title}, {o.case.label}**: "
        what += f"contact {_fmt(contact, 100)} %" if o.status == "done" else o.final
        dz = o.case.unknown_offset[2]
        reference = _ours(outcomes, o.case, "force_reference_n") or 0.0
        if o.controller == "impedance" and o.case.skill == "slide_flat" and dz:
            depth = reference / k
            if dz < 0:
                what += (
                    f" — the table is {100 * -dz:g} cm lower than taught and the impedance reference lies only "
                    f"f/k = {1e3 * depth:.0f} mm below the TAUGHT surface: the tool never presses (the guarded "
                    "approach finds the table, but this baseline keeps the taught height)."
                )
            else:
                what += (
                    f" — the table is {100 * dz:g} cm higher than taught: the reference lies {100 * dz:g} cm + "
                    f"{1e3 * depth:.0f} mm inside it, k·Δ ≈ {k * (dz + depth):.0f} N wanted"
                    + (" (the force limit aborts it)." if o.status == "aborted" else ".")
                )
        notes.append(what)
    return notes


def _ours(outcomes: list[Outcome], case: Case, name: str) -> float | None:
    for o in outcomes:
        if o.case == case and o.controller == OURS:
            return o.metric(name)
    return None


# --------------------------------------------------------------------------------------------------- the table

TABLE_HEADER = (
    "case",
    "controller",
    "F_z RMS (N)",
    "F_z RMS (%)",
    "F_z max (N)",
    "F_z max (%)",
    "contact (%)",
    "path RMS (mm)",
    "RTF",
    "final",
    "target",
)
"""Columns of the results table (``docs/RESULTS.md`` and the console)."""


def table_rows(outcomes: list[Outcome], compact: bool = False) -> list[tuple[str, ...]]:
    """One row of strings per execution, columns :data:`TABLE_HEADER` (``compact``: shorter case and final texts,
    for the console)."""
    rows = []
    for o in outcomes:
        final = o.final if not compact or len(o.final) <= 40 else o.final[:39] + "…)"
        rows.append(
            (
                f"{o.case.skill}: {o.case.label}" if compact else f"{SKILLS[o.case.skill].title}: {o.case.label}",
                o.controller,
                _fmt(o.metric("force_rms_error_n"), digits=3),
                _fmt(o.metric("force_rms_error_pct")),
                _fmt(o.metric("force_max_error_n"), digits=3),
                _fmt(o.metric("force_max_error_pct")),
                _fmt(o.metric("contact_ratio"), 100),
                _fmt(o.metric("path_rms_m"), 1e3),
                _fmt(o.metric("real_time_factor"), digits=1),
                final,
                o.verdict,
            )
        )
    return rows


def markdown_table(outcomes: list[Outcome]) -> str:
    lines = ["| " + " | ".join(TABLE_HEADER) + " |", "|" + "|".join(" --- " for _ in TABLE_HEADER) + "|"]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in table_rows(outcomes)]
    return "\n".join(lines)


def text_table(outcomes: list[Outcome]) -> str:
    """The results table for the console: aligned columns."""
    rows = [TABLE_HEADER, *table_rows(outcomes, compact=True)]
    widths = [max(len(r[j]) for r in rows) for j in range(len(TABLE_HEADER) - 1)]
    out = []
    for k, row in enumerate(rows):
        out.append("  ".join(c.ljust(w) for c, w in zip(row[:-1], widths, strict=True)) + "  " + row[-1])
        if k == 0:
            out.append("  ".join("-" * w for w in widths) + "  " + "-" * 6)
    return "\n".join(out)


def parse_markdown_table(text: str) -> list[dict[str, str]]:
    """The rows of the results table in a RESULTS.md (header :data:`TABLE_HEADER`) as dicts of cell strings."""
    lines = [line.strip() for line in text.splitlines() if line.strip().startswith("|")]
    header = "| " + " | ".join(TABLE_HEADER) + " |"
    start = lines.index(header)
    rows = []
    for line in lines[start + 2 :]:
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        if len(cells) != len(TABLE_HEADER):
            break
        rows.append(dict(zip(TABLE_HEADER, cells, strict=True)))
    return rows


# --------------------------------------------------------------------------------------------------- the stack


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


class EmbeddedStack:
    """``contact-skills up`` as a child process on loopback (its own Zenoh port, a given database); stopped by
    SIGTERM (``up`` stops its API and workers cleanly), killed only if it does not stop in time."""

    def __init__(self, port: int, workers: int, db: Path, log_path: Path) -> None:
        self.port, self.workers, self.db, self.log_path = port, workers, db, log_path
        self.zenoh_port = free_port()
        self.url = f"http://127.0.0.1:{port}"
        self.endpoint = f"tcp/127.0.0.1:{self.zenoh_port}"
        self.process: subprocess.Popen | None = None
        self._log = None

    def start(self) -> None:
        from cli.service_commands import _parent_death_signal

        root = Path(__file__).resolve().parents[1]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH", "")) if p)
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(var, "1")
        argv = [
            sys.executable,
            "-m",
            "cli.main",
            "up",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--zenoh-port",
            str(self.zenoh_port),
            "--workers",
            str(self.workers),
            "--db",
            str(self.db),
            "--log-level",
            "warning",
        ]
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("w")
        self.process = subprocess.Popen(
            argv,
            env=env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=_parent_death_signal(),
        )

    def check_alive(self) -> None:
        if self.process is not None and self.process.poll() is not None:
            raise DemoError(f"`contact-skills up` exited with {self.process.returncode}; its log:\n{self.log_tail()}")

    def log_tail(self, n: int = 30) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return "(no log)"

    def stop(self, timeout_s: float = 40.0) -> int | None:
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._log is not None:
            self._log.close()
        return self.process.returncode


# --------------------------------------------------------------------------------------------------- live status


class LiveStatus:
    """A Zenoh subscriber on ``P/exec/*/status``: the latest ``ExecutionStatus`` of every execution, and an
    event set whenever one reaches a final phase. Without a bus (not reachable) it stays empty: the demo polls."""

    def __init__(self, endpoints: list[str], prefix: str) -> None:
        self.lock = threading.Lock()
        self.latest: dict[str, Any] = {}
        self.received = 0
        """Status messages received."""
        self.changed = threading.Event()
        self.session = None
        self.subscriber = None
        self.prefix = prefix
        self.error: str | None = None
        try:
            from services.bus import open_session

            self.session = open_session("client", connect=endpoints, wait_s=3.0)
            self._subscribe(prefix)
        except Exception as exc:  # no zenoh, router not reachable from here
            self.error = f"{type(exc).__name__}: {exc}"
            self.session = None

    @property
    def connected(self) -> bool:
        return self.session is not None

    def _subscribe(self, prefix: str) -> None:
        from schemas.bus import KeyExpressions

        if self.subscriber is not None:
            with contextlib.suppress(Exception):
                self.subscriber.undeclare()
        self.prefix = prefix
        self.subscriber = self.session.declare_subscriber(KeyExpressions(prefix).status("*"), self._on_status)

    def follow_prefix(self, status_key: str) -> None:
        """Re-subscribe if the service's prefix (seen in a ``status_key``) is not the one assumed."""
        prefix = status_key.rsplit("/exec/", 1)[0]
        if self.session is not None and prefix != self.prefix:
            self._subscribe(prefix)

    def _on_status(self, sample) -> None:
        from schemas.bus import ExecutionStatus

        try:
            status = ExecutionStatus.model_validate_json(sample.payload.to_bytes())
        except ValueError:
            return
        with self.lock:
            self.received += 1
            current = self.latest.get(status.execution_id)
            if current is None or status.seq >= current.seq:
                self.latest[status.execution_id] = status
        self.changed.set()

    def get(self, execution_id: str):
        with self.lock:
            return self.latest.get(execution_id)

    def close(self) -> None:
        if self.session is not None:
            with contextlib.suppress(Exception):
                if self.subscriber is not None:
                    self.subscriber.undeclare()
                self.session.close()
            self.session = None


# --------------------------------------------------------------------------------------------------- the run


@dataclass
class DemoOptions:
    url: str = "http://127.0.0.1:8000"
    workers: int = 2
    quick: bool = False
    out: Path = Path("docs")
    seed: int = 0
    db: Path | None = None
    connect: list[str] | None = None
    prefix: str | None = None
    command: str = "contact-skills demo"
    """The command line shown in RESULTS.md as the way to regenerate it."""


@dataclass
class LearnedSkill:
    spec: SkillSpec
    demonstration_id: str
    skill_id: str
    demonstration: Any  # schemas.Demonstration
    skill: Any  # schemas.Skill
    record_wall_s: float
    learn_s: float


@dataclass
class DemoReport:
    outcomes: list[Outcome]
    verdicts: list[TargetVerdict]
    skills: dict[str, LearnedSkill]
    timings: dict[str, float] = field(default_factory=dict)
    results_path: Path | None = None
    figures: list[Path] = field(default_factory=list)
    service: str = ""

    @property
    def all_finished(self) -> bool:
        return all(o.status in FINAL for o in self.outcomes)


class _Client:
    """The HTTP side: a thin httpx client that turns refusals into :class:`DemoError`."""

    def __init__(self, url: str) -> None:
        import httpx

        headers = {}
        token = os.environ.get("CONTACT_SKILLS_TOKEN")
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self.http = httpx.Client(base_url=url.rstrip("/"), timeout=60.0, headers=headers)
        self.httpx = httpx

    def health(self, timeout_s: float = 3.0) -> dict | None:
        try:
            response = self.http.get("/health", timeout=timeout_s)
        except self.httpx.HTTPError:
            return None
        return response.json() if response.status_code == 200 else None

    def request(self, method: str, path: str, expect: int, retry_busy_s: float = 0.0, **kwargs) -> dict:
        """``method path``; a 503 (no free worker) is retried for ``retry_busy_s``; another status than
        ``expect`` raises :class:`DemoError` with the service's ``detail``."""
        deadline = time.monotonic() + retry_busy_s
        while True:
            response = self.http.request(method, path, **kwargs)
            if response.status_code == expect:
                return response.json()
            if response.status_code == 503 and time.monotonic() < deadline:
                time.sleep(0.5)
                continue
            try:
                detail = response.json().get("detail")
            except ValueError:
                detail = response.text[:300]
            raise DemoError(f"{method} {path}: HTTP {response.status_code}: {detail}")

    def try_post(self, path: str, body: dict) -> tuple[int, dict]:
        response = self.http.post(path, json=body)
        try:
            return response.status_code, response.json()
        except ValueError:
            return response.status_code, {"detail": response.text[:300]}

    def close(self) -> None:
        self.http.close()


def _say(text: str) -> None:
    from tqdm import tqdm

    tqdm.write(text, file=sys.stderr)


@contextlib.contextmanager
def _service(options: DemoOptions, timings: dict[str, float]) -> Iterator[tuple[_Client, dict, list[str], str]]:
    """The service to drive: the one answering at ``options.url``, else the embedded stack started here.

    Yields (client, health, Zenoh endpoints to subscribe on, a description)."""
    started = time.perf_counter()
    client = _Client(options.url)
    stack: EmbeddedStack | None = None
    tmp: tempfile.TemporaryDirectory | None = None
    try:
        health = client.health()
        if health is not None:
            description = f"the running service at {options.url}"
            endpoints = options.connect or list(health.get("zenoh_endpoints") or [])
            _say(f"demo: using {description} ({len(health.get('workers', []))} worker(s) connected)")
        else:
            parts = urlsplit(options.url)
            if parts.hostname not in ("127.0.0.1", "localhost"):
                raise DemoError(f"no service answers {options.url}/health (and only a loopback one is started here)")
            port = parts.port or 80
            if not _port_free(port):
                port = free_port()
            tmp = tempfile.TemporaryDirectory(prefix="contact-skills-demo-")
            db = options.db or Path(tmp.name) / "demo.db"
            stack = EmbeddedStack(port, options.workers, db, Path(tmp.name) / "up.log")
            _say(
                f"demo: no service at {options.url}: starting `contact-skills up --workers {options.workers} "
                f"--port {port} --zenoh-port {stack.zenoh_port} --db {db}`"
            )
            stack.start()
            client.close()
            client = _Client(stack.url)
            health = _wait_ready(client, stack, options.workers)
            description = f"the embedded stack (`contact-skills up --workers {options.workers}`, started by the demo)"
            endpoints = options.connect or [stack.endpoint]
        if not health.get("bus_connected", False):
            raise DemoError("the service has no Zenoh bus: it cannot record or execute")
        if not health.get("workers"):
            health = _wait_workers(client, 1, 60.0)
        timings["service start"] = time.perf_counter() - started
        yield client, health, endpoints, description
    finally:
        client.close()
        if stack is not None:
            code = stack.stop()
            _say(f"demo: embedded stack stopped (exit {code})")
        if tmp is not None:
            tmp.cleanup()


def _wait_ready(client: _Client, stack: EmbeddedStack, workers: int) -> dict:
    deadline = time.monotonic() + READY_TIMEOUT_S
    while time.monotonic() < deadline:
        stack.check_alive()
        health = client.health(timeout_s=2.0)
        if health is not None and len(health.get("workers", [])) >= workers:
            _say(f"demo: service ready at {stack.url} with {len(health['workers'])} workers")
            return health
        time.sleep(0.3)
    raise DemoError(f"the embedded stack was not ready in {READY_TIMEOUT_S:.0f} s; its log:\n{stack.log_tail()}")


def _wait_workers(client: _Client, n: int, timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        health = client.health()
        if health is not None and len(health.get("workers", [])) >= n:
            return health
        time.sleep(0.5)
    raise DemoError(f"no sim worker connected to the service within {timeout_s:.0f} s")


def _record_and_learn(client: _Client, spec: SkillSpec, seed: int) -> LearnedSkill:
    from schemas import Demonstration, Skill

    started = time.perf_counter()
    body = {"scenario": spec.scenario, "seed": seed}
    created = client.request(
        "POST", "/demonstrations/record", 201, retry_busy_s=RECORD_TIMEOUT_S, json=body, timeout=RECORD_TIMEOUT_S
    )
    record_wall = time.perf_counter() - started
    learned = client.request(
        "POST", "/skills", 201, json={"demonstration_id": created["id"], "skill_type": spec.skill_type}
    )
    stored = client.request("GET", f"/demonstrations/{created['id']}", 200)
    demonstration = Demonstration.model_validate(stored["demonstration"])
    skill = Skill.model_validate(learned["skill"])
    summary = created["summary"]
    _say(
        f"demo: recorded {spec.scenario} (seed {seed}) -> {created['id']}: {summary['n_samples']} samples, "
        f"{summary['duration_s']:.1f} s; learned {skill.skill_type.value} skill {learned['id']} with "
        f"{len(skill.segments)} segments in {learned['learn_seconds']:.2f} s"
    )
    return LearnedSkill(
        spec, created["id"], learned["id"], demonstration, skill, record_wall, float(learned["learn_seconds"])
    )


def _run_executions(
    client: _Client, live: LiveStatus, skills: dict[str, LearnedSkill], jobs: list[Outcome], capacity: int
) -> None:
    """Run ``jobs`` on the service, at most ``capacity`` at once, with a progress bar and a live phase line."""
    from tqdm import tqdm

    pending = deque(jobs)
    running: dict[str, tuple[Outcome, float]] = {}
    tty = sys.stderr.isatty()
    bar = tqdm(
        total=len(jobs),
        desc="executions",
        unit="run",
        file=sys.stderr,
        dynamic_ncols=True,
        position=0,
        disable=not tty,
    )
    line = tqdm(total=0, bar_format="{desc}", file=sys.stderr, dynamic_ncols=True, position=1, disable=not tty)
    last_poll = 0.0
    backoff_until = 0.0
    try:
        while pending or running:
            now = time.monotonic()
            while pending and len(running) < capacity and now >= backoff_until:
                job = pending[0]
                body = {
                    "skill_id": skills[job.case.skill].skill_id,
                    "controller": job.controller,
                    "pace": "fast",
                    "telemetry_batch": TELEMETRY_BATCH,
                    "environment": {"offset": list(job.case.offset), "unknown_offset": list(job.case.unknown_offset)},
                }
                code, reply = client.try_post("/executions", body)
                if code == 503:  # every worker busy (one is finishing): try again shortly
                    backoff_until = now + 0.3
                    break
                if code != 202:
                    raise DemoError(
                        f"POST /executions ({job.case.label}, {job.controller}): HTTP {code}: {reply.get('detail')}"
                    )
                pending.popleft()
                job.execution_id, job.worker_id, job.status = reply["id"], reply["worker_id"], "running"
                live.follow_prefix(reply["status_key"])
                running[job.execution_id] = (job, time.monotonic())
            live.changed.wait(0.25)
            live.changed.clear()
            now = time.monotonic()
            poll_all = now - last_poll > 2.0 or not live.connected
            for execution_id, (job, t0) in list(running.items()):
                status = live.get(execution_id)
                if not (poll_all or (status is not None and status.final)):
                    continue
                view = client.request("GET", f"/executions/{execution_id}", 200)
                if view["status"] in FINAL:
                    job.status, job.metrics, job.error = view["status"], view.get("metrics"), view.get("error")
                    job.wall_s = time.monotonic() - t0
                    del running[execution_id]
                    bar.update(1)
                    if not tty:
                        _say(
                            f"demo: {job.case.short} {job.controller}: {job.final}, force RMS "
                            f"{_fmt(job.metric('force_rms_error_pct'))} % ({job.wall_s:.1f} s)"
                        )
                elif now - t0 > EXECUTION_TIMEOUT_S:
                    with contextlib.suppress(DemoError):
                        client.request("POST", f"/executions/{execution_id}/abort", 202)
                    job.status, job.error = "failed", f"no final status after {EXECUTION_TIMEOUT_S:.0f} s (aborted)"
                    del running[execution_id]
                    bar.update(1)
            if poll_all:
                last_poll = now
            line.set_description_str(_live_line(live, running), refresh=True)
    finally:
        line.close()
        bar.close()


def _live_line(live: LiveStatus, running: dict[str, tuple[Outcome, float]]) -> str:
    if not running:
        return "live: idle"
    parts = []
    for execution_id, (job, _) in running.items():
        status = live.get(execution_id)
        where = f"{job.case.short} {job.controller}"
        if status is None:
            parts.append(f"{where}: starting")
        else:
            seg = f" {status.segment_index + 1}/{status.segments}" if status.segment_index >= 0 else ""
            parts.append(f"{where}: {status.phase.value}{seg} t={status.t:.1f}s")
    return ("live: " if live.connected else "polled: ") + " | ".join(parts)


def _fetch_traces(client: _Client, outcomes: list[Outcome]) -> dict[tuple[Case, str], Any]:
    """The telemetry of every execution (every :data:`TELEMETRY_EVERY`-th sample) as ``figures.Trace``."""
    from services.figures import Trace

    traces = {}
    for o in outcomes:
        if o.execution_id is None:
            continue
        columns = client.request(
            "GET", f"/executions/{o.execution_id}/telemetry", 200, params={"every": TELEMETRY_EVERY}
        )
        if columns.get("n_samples", 0) > 0:
            traces[(o.case, o.controller)] = Trace.from_columns(o.case.label, columns)
    return traces


def _short_final(o: Outcome) -> str:
    """``aborted (force limit)`` from ``aborted (force limit: measured 83.5 N > ...)``."""
    head, _, reason = o.final.partition(" (")
    return f"{head} ({reason.split(':')[0].rstrip(')')})" if reason else head


def _trial_label(case: Case, outcomes: list[Outcome]) -> str:
    """A trial's subplot title: the case and each controller's CF-z force RMS error."""
    errors = [
        f"{o.controller} {_fmt(o.metric('force_rms_error_pct'))} %"
        if o.metric("force_rms_error_pct") is not None
        else f"{o.controller} {_short_final(o)}"
        for o in outcomes
        if o.case == case
    ]
    return f"{case.label} — force RMS error: " + ", ".join(errors)


def _write_figures(out: Path, skills: dict[str, LearnedSkill], outcomes: list[Outcome], traces: dict) -> list[Path]:
    from services.figures import write_learning_figure, write_paths_figure, write_trials_force_figure

    folder = out / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for key, learned in skills.items():
        spec = learned.spec
        skill_cases = []
        for o in outcomes:
            if o.case.skill == key and o.case not in skill_cases:
                skill_cases.append(o.case)
        learn = folder / f"demo_{key}_learned.png"
        write_learning_figure(learned.demonstration, learned.skill, learn)
        paths = folder / f"demo_{key}_paths.png"
        ours = [(c.label, traces[(c, OURS)]) for c in skill_cases if (c, OURS) in traces]
        write_paths_figure(
            learned.demonstration,
            learned.skill,
            ours,
            paths,
            title=f"{spec.title} ({spec.figure}a/b): demonstration and reproductions ({OURS})",
            view=(18.0, -20.0) if spec.skill_type == "contour" else (22.0, -58.0),
        )
        forces = folder / f"demo_{key}_forces.png"
        trials = [
            (_trial_label(c, outcomes), {k: traces[(c, k)] for k in c.controllers if (c, k) in traces})
            for c in skill_cases
        ]
        write_trials_force_figure(
            trials, forces, ours=OURS, title=f"{spec.title} ({spec.figure}d): CF-z force per trial, desired vs measured"
        )
        written += [paths, learn, forces]
    return written


def run_demo(options: DemoOptions) -> DemoReport:
    """Run the demo (see the module docstring) and write ``options.out``/RESULTS.md and figures/."""
    say = _say
    timings: dict[str, float] = {}
    t_total = time.perf_counter()
    jobs = [Outcome(case, controller) for case in cases(options.quick) for controller in case.controllers]
    needed = list(dict.fromkeys(o.case.skill for o in jobs))
    with _service(options, timings) as (client, health, endpoints, description):
        from schemas.bus import DEFAULT_PREFIX, ENV_PREFIX

        prefix = options.prefix or os.environ.get(ENV_PREFIX) or DEFAULT_PREFIX
        live = LiveStatus(endpoints, prefix) if endpoints else LiveStatus([], prefix)
        if not live.connected:
            say(f"demo: no live view over Zenoh ({live.error or 'no endpoint'}): polling the REST API instead")
        try:
            capacity = max(1, len(health.get("workers", [])))
            started = time.perf_counter()
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=capacity) as pool:
                futures = {k: pool.submit(_record_and_learn, client, SKILLS[k], options.seed) for k in needed}
                skills = {k: f.result() for k, f in futures.items()}
            timings["record + learn"] = time.perf_counter() - started
            say(f"demo: {len(jobs)} executions ({len(cases(options.quick))} cases) on {capacity} worker(s), pace fast")
            started = time.perf_counter()
            _run_executions(client, live, skills, jobs, capacity)
            timings["executions"] = time.perf_counter() - started
            if live.connected:
                seen = sum(live.get(o.execution_id) is not None for o in jobs if o.execution_id)
                say(
                    f"demo: live view: {live.received} status messages over Zenoh from {seen} of {len(jobs)} executions"
                )
            started = time.perf_counter()
            traces = _fetch_traces(client, jobs)
            timings["telemetry fetch"] = time.perf_counter() - started
        finally:
            live.close()
    started = time.perf_counter()
    verdicts = judge(jobs)
    report = DemoReport(jobs, verdicts, skills, timings, service=description)
    report.figures = _write_figures(options.out, skills, jobs, traces)
    timings["figures"] = time.perf_counter() - started
    timings["total"] = time.perf_counter() - t_total
    report.results_path = write_results(options, report)
    return report


# --------------------------------------------------------------------------------------------------- RESULTS.md


def _vec_cm(v: tuple[float, float, float]) -> str:
    return "(" + ", ".join(f"{100 * x:+g}" for x in v) + ") cm"


def results_markdown(options: DemoOptions, report: DemoReport) -> str:
    """The text of RESULTS.md."""
    outcomes = report.outcomes
    now = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    n_exec = len(outcomes)
    t = report.timings
    met = sum(v.met for v in report.verdicts)
    lines = [
        "# Results: the paper's experiments, reproduced end to end",
        "",
        "The experiments of section 6 of Origanti, Eiband & Lee (slide, Fig. 3; contour, Fig. 4), run through the "
        "service the way a user drives it: the scripted teacher records each demonstration on a sim worker "
        "(`POST /demonstrations/record`), the service learns the skill (`POST /skills`), and every trial runs on "
        "the sim workers (`POST /executions`, pace fast, concurrently) with our controller and both baselines; "
        "live phases come over Zenoh (`cskills/exec/*/status`), metrics and telemetry over REST.",
        "",
        f"Regenerate: `{options.command}`" + (" (reduced case set)" if options.quick else ""),
        "",
        f"Generated {now} against {report.service}. {machine_line()}",
        "",
        f"Timings (wall): {n_exec} executions in {t.get('executions', 0):.1f} s; service start "
        f"{t.get('service start', 0):.1f} s, recording + learning {t.get('record + learn', 0):.1f} s, telemetry "
        f"fetch {t.get('telemetry fetch', 0):.1f} s, figures {t.get('figures', 0):.1f} s; total "
        f"{t.get('total', 0):.1f} s.",
        "",
        "## Cases",
        "",
        f"Teacher seed {options.seed}. Controllers: `hybrid_cf` (ours, paper eq. 1-4: force control along the "
        "compliant frame's z), `impedance` (pure Cartesian impedance, the reference pushed f/k into the taught "
        "surface) and `hybrid_world_z` (force control fixed to world z, as in earlier work).",
        "",
        "| skill (learned from) | case | known offset (moves skill and world) | unknown offset (world only) |",
        "| --- | --- | --- | --- |",
    ]
    seen: list[Case] = []
    for o in outcomes:
        if o.case in seen:
            continue
        seen.append(o.case)
        learned = report.skills[o.case.skill]
        lines.append(
            f"| {learned.spec.title} (`{learned.spec.scenario}`, {learned.skill_id}) | {o.case.label} | "
            f"{_vec_cm(o.case.offset)} | {_vec_cm(o.case.unknown_offset)} |"
        )
    lines += [
        "",
        "A KNOWN offset is sent as `environment.offset` alone: the executor moves both the simulated work piece and "
        "the skill (DMP starts, goals, compliant frames) by it, so the cylinder really moves by the stated amount. "
        "An UNKNOWN offset (`environment.unknown_offset`) moves only the work piece; the guarded approach finds it.",
        "",
        f"## Targets: {met} of {len(report.verdicts)} met",
        "",
        "| target | verdict | detail |",
        "| --- | --- | --- |",
    ]
    lines += [f"| {v.name} | **{'MET' if v.met else 'MISSED'}** | {v.detail} |" for v in report.verdicts]
    notes = explanations(outcomes)
    if notes:
        lines += ["", "### Why a target is missed", ""]
        lines += [f"- {note}" for note in notes]
    seen_notes = observations(outcomes)
    if seen_notes:
        lines += ["", "### Also seen (rows without a target)", ""]
        lines += [f"- {note}" for note in seen_notes]
    lines += [
        "",
        "## Results",
        "",
        "CF-z force error over the steady contact (from 0.2 s after contact), in N and in % of the learned force "
        "(slide: the constant; contour: the profile's peak); contact = share of the contact phase in contact; "
        "path RMS in the CF x-y plane against the (known-offset-shifted) demonstration; RTF = simulated / wall "
        "time of the worker's 1 kHz loop (two workers share two cores here).",
        "",
        markdown_table(outcomes),
        "",
        "## Figures",
        "",
    ]
    for key, learned in report.skills.items():
        lines += [
            f"### {learned.spec.title} ({learned.spec.figure})",
            "",
            f"![paths](figures/demo_{key}_paths.png)",
            "",
            f"![learned](figures/demo_{key}_learned.png)",
            "",
            f"![forces](figures/demo_{key}_forces.png)",
            "",
        ]
    return "\n".join(lines)


def write_results(options: DemoOptions, report: DemoReport) -> Path:
    options.out.mkdir(parents=True, exist_ok=True)
    path = options.out / "RESULTS.md"
    path.write_text(results_markdown(options, report))
    return path
