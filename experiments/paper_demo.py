"""``contact-skills demo``: the paper's experiments (section 6, Fig. 3 slide and Fig. 4 contour) reproduced end to end
against the RUNNING service, the way a user drives it, with both baselines, figures and a results page.

- HTTP (httpx) for everything stored: ``POST /demonstrations/record`` (the scripted teacher records on a sim
  worker), ``POST /demonstrations/csv`` (the KU Leuven recordings uploaded as a user would, with their import
  options), ``POST /skills`` (learn), ``POST /executions`` (run), ``GET /executions/{id}`` (metrics) and
  ``GET /executions/{id}/telemetry`` (the recorded stream, for the figures).
- Zenoh for live progress: one subscriber on ``P/exec/*/status`` shows the phase of every running execution.
- If nothing answers ``GET /health`` at the URL (loopback), the embedded stack is started
  (``contact-skills up --workers N`` as a child process, a temporary database), used and stopped at the end.

The package: ``experiments.cases`` (what runs, the targets, :func:`~experiments.cases.judge`),
``experiments.stack`` (the service driven, the live view), ``experiments.report`` (RESULTS.md),
``experiments.report_tables`` and ``experiments.report_figures`` (its tables and figures) and this module, which
runs a demo: record and learn, schedule the executions on the workers, fetch the telemetry,
judge and write. RESULTS.md and figures/ go to ``options.out`` (default ``demo-output/``; ``docs`` rewrites the
tracked pages).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

from experiments.cases import (
    FINAL,
    KULEUVEN_FORM,
    SKILLS,
    Case,
    DemoOptions,
    DemoReport,
    LearnedSkill,
    Outcome,
    SkillSpec,
    cases,
    judge,
)
from experiments.report import write_results
from experiments.report_figures import write_figures
from experiments.report_tables import text_table
from experiments.stack import DemoError, LiveStatus, ServiceClient, say, service_session
from services.datasets import DATA_ENV, data_directory, kuleuven_recordings

__all__ = ["DemoError", "DemoOptions", "DemoReport", "run_demo", "text_table"]

TELEMETRY_BATCH = 100
"""Control steps per telemetry message: pace fast produces ~10 000 samples/s per worker; the demo watches statuses,
so big batches spare the bus and the API."""
TELEMETRY_EVERY = 5
"""The figures read every N-th telemetry sample (1 kHz -> 200 Hz)."""
EXECUTION_TIMEOUT_S = 600.0
"""An execution not finished after this long (wall) is aborted and reported failed."""
DEMO_RECORD_TIMEOUT_S = 300.0


def run_demo(options: DemoOptions) -> DemoReport:
    """Run the demo (see the module docstring) and write ``options.out``/RESULTS.md and figures/."""
    timings: dict[str, float] = {}
    t_total = time.perf_counter()
    jobs = [Outcome(case, controller) for case in cases(options.quick) for controller in case.controllers]
    needed = list(dict.fromkeys(o.case.skill for o in jobs))
    recordings = _recordings([SKILLS[k] for k in needed])
    with service_session(options, timings) as (client, health, endpoints, description):
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
                futures = {
                    k: pool.submit(_demonstrate_and_learn, client, SKILLS[k], options.seed, recordings) for k in needed
                }
                skills = {k: f.result() for k, f in futures.items()}
            timings["demonstrations + learning"] = time.perf_counter() - started
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
    report = DemoReport(jobs, verdicts, skills, timings, service=description, traces=traces)
    report.figures = write_figures(options.out, skills, jobs, traces)
    timings["figures"] = time.perf_counter() - started
    timings["total"] = time.perf_counter() - t_total
    report.results_path = write_results(options, report)
    return report


# --------------------------------------------------------------------------------------------------- steps


def _recordings(specs: list[SkillSpec]) -> dict[str, Path]:
    """The KU Leuven files the real-data skills of ``specs`` are learned from, by stem (before anything starts)."""
    found = {path.stem: path for path in kuleuven_recordings()}
    missing = [f"{s.recording}.csv" for s in specs if s.recording is not None and s.recording not in found]
    if missing:
        raise DemoError(f"no KU Leuven recording {', '.join(missing)} under {data_directory()} (set {DATA_ENV})")
    return {s.recording: found[s.recording] for s in specs if s.recording is not None}


def _demonstration_created(client: ServiceClient, spec: SkillSpec, seed: int, recordings: dict[str, Path]) -> dict:
    """The demonstration of ``spec``, stored by the service: recorded by the teacher on a sim worker, or the KU
    Leuven file uploaded as CSV with its import options (the form fields of ``POST /demonstrations/csv``)."""
    if spec.recording is None:
        body = {"scenario": spec.scenario, "seed": seed}
        return client.request(
            "POST",
            "/demonstrations/record",
            201,
            retry_busy_s=DEMO_RECORD_TIMEOUT_S,
            json=body,
            timeout=DEMO_RECORD_TIMEOUT_S,
        )
    path = recordings[spec.recording]
    files = {"file": (path.name, path.read_bytes(), "text/csv")}
    return client.request("POST", "/demonstrations/csv", 201, files=files, data=KULEUVEN_FORM)


def _demonstrate_and_learn(
    client: ServiceClient, spec: SkillSpec, seed: int, recordings: dict[str, Path]
) -> LearnedSkill:
    from schemas import Demonstration, Skill

    started = time.perf_counter()
    created = _demonstration_created(client, spec, seed, recordings)
    demonstrate_wall = time.perf_counter() - started
    learned = client.request(
        "POST", "/skills", 201, json={"demonstration_id": created["id"], "skill_type": spec.skill_type}
    )
    stored = client.request("GET", f"/demonstrations/{created['id']}", 200)
    demonstration = Demonstration.model_validate(stored["demonstration"])
    skill = Skill.model_validate(learned["skill"])
    summary = created["summary"]
    how = f"uploaded {spec.recording}.csv" if spec.real else f"recorded {spec.scenario} (seed {seed})"
    say(
        f"demo: {how} -> {created['id']}: {summary['n_samples']} samples, {summary['duration_s']:.1f} s; learned "
        f"{skill.skill_type.value} skill {learned['id']} with {len(skill.segments)} segments in "
        f"{learned['learn_seconds']:.2f} s"
    )
    return LearnedSkill(
        spec, created["id"], learned["id"], demonstration, skill, demonstrate_wall, float(learned["learn_seconds"])
    )


def _run_executions(
    client: ServiceClient, live: LiveStatus, skills: dict[str, LearnedSkill], jobs: list[Outcome], capacity: int
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
                        say(
                            f"demo: {job.case.short} {job.controller}: {job.final}, force RMS {job.rms_text()} "
                            f"({job.wall_s:.1f} s)"
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


def _fetch_traces(client: ServiceClient, outcomes: list[Outcome]) -> dict[tuple[Case, str], Any]:
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
