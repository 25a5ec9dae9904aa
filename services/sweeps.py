"""Robustness sweeps on the service: trials fanned out as executions through the queue, followed, rerun after an
infrastructure failure, summarized (``schemas/sweep.py`` is the contract, ``skills/sweeps.py`` the statistics).

- :meth:`SweepRunner.create` draws the trials (``skills.sweeps.trial_parameters``), stores the sweep with one row
  per trial x controller, and submits the first ones at once (so no worker is a 503 and a request a worker refuses
  is a 422, with nothing stored);
- every trial's execution runs with the sweep's ``store_telemetry``: by default ``telemetry`` ``none`` (no stream
  published, stored or kept: the metrics, computed in the worker, are the same either way), with the sweep's
  success criteria as its tolerances (``skills.sweeps.trial_tolerances``) and, when the sweep varies the cylinder
  of the skill's taught world, that cylinder changed by world overrides (``skills.sweeps.trial_world_overrides``);
- a trial is judged by its execution's verdict (``skills.sweeps.outcome``; a trial stored before verdicts by the
  old rule), its failure causes are the verdict's failed checks;
- the runner's thread (:meth:`SweepRunner.start`) keeps at most ``window`` executions of each sweep queued or
  running (the queue then holds a few, however large the sweep; single executions, at a higher priority, go
  first), submits the next ones as they finish (woken by the store when an execution ends,
  `services.store.Store.on_finish`; a poll every ``poll_s`` as the safety net), and puts the progress on
  ``P/sweeps/{id}/progress``
  (`schemas.sweep.SweepProgress`) whenever the counts change. Every worker on the bus takes executions from the
  queue: more workers, or workers on other machines joining the router, run a sweep faster with no change here;
- an execution that failed for an infrastructure reason (its worker lost, the API restarted while it ran:
  :func:`infrastructure_failure`) is submitted again, up to :data:`MAX_ATTEMPTS` times; one that ended physically
  (done, or aborted by the force limit, a lost contact, ...) is the trial's result;
- the state lives in SQLite (``sweeps``, ``sweep_trials``; the executions hold status and metrics), so after an
  API restart the thread picks running sweeps up where they were.

:func:`sweep_view` and :func:`trial_results` read a sweep back (no bus needed).
"""

from __future__ import annotations

import json
import logging
import re
import threading
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from schemas.api import ExecutionState
from schemas.bus import CommandName, KeyExpressions
from schemas.execution import (
    DEFAULT_ENGINE,
    ControllerKind,
    Engine,
    ExecutionPhase,
    ExecutionRequest,
    TelemetryMode,
)
from schemas.skill import Skill
from schemas.sweep import (
    SWEEP_TOLERANCES,
    SweepCounts,
    SweepParameter,
    SweepProgress,
    SweepRequest,
    SweepState,
    SweepView,
    TrialResult,
)
from schemas.world import engine_to_run, world_engine
from services.background import WakeableThread
from services.queue import Dispatch, ExecutionQueue
from services.store import RESTART_REASON, TERMINAL, Store, SweepRow, SweepTrialRef, SweepTrialRow
from skills.sweeps import (
    Outcome,
    controller_summary,
    outcome,
    planned_pad,
    sensitivity,
    trial_environment,
    trial_noise_seed,
    trial_parameters,
    trial_tolerances,
    trial_world_overrides,
    trials_in_taught_world,
)

if TYPE_CHECKING:
    from services.bus import BusClient

log = logging.getLogger("contact_skills.sweeps")

WINDOW = 8
"""Executions one sweep keeps queued or running at once (a few per worker: none idles between two trials)."""
MAX_ATTEMPTS = 3
"""Executions one trial x controller may take when they keep failing for an infrastructure reason."""
SWEEP_POLL_S = 0.5
"""How often the runner looks at the running sweeps when nothing woke it, s (an execution that ends wakes it)."""
_LOST = re.compile(r"^worker \S+ (was )?lost")
"""The errors of the worker-lost path (`services.bus.BusClient`, `services.bus_events.BusEvents`)."""


def infrastructure_failure(status: ExecutionState | None, error: str | None) -> bool:
    """Whether an execution failed for a reason that says nothing about the trial: its worker was lost, or the API
    restarted while it ran (not an abort by a safety limit, a lost contact or an internal error of the run)."""
    if status is not ExecutionState.failed or error is None:
        return False
    return error == RESTART_REASON or bool(_LOST.match(error))


def _needs_rerun(row: SweepTrialRow) -> bool:
    return infrastructure_failure(row.status, row.error) and row.attempts < MAX_ATTEMPTS


def _finished(row: SweepTrialRow) -> bool:
    return row.status in TERMINAL and not _needs_rerun(row)


def _outcome(row: SweepTrialRow, criteria: dict[str, float]) -> Outcome:
    """The judged outcome of a finished trial (``criteria``: the sweep's request, for a trial without a verdict)."""
    return outcome(row.metrics, row.status, row.error, criteria)


def _counts(rows: list[SweepTrialRow], criteria: dict[str, float]) -> SweepCounts:
    finished = [r for r in rows if _finished(r)]
    return SweepCounts(
        total=len(rows),
        finished=len(finished),
        succeeded=sum(_outcome(r, criteria).success for r in finished),
        running=sum(r.status in (ExecutionState.starting, ExecutionState.running, ExecutionState.paused) for r in rows),
        queued=sum(r.status is ExecutionState.queued for r in rows),
        pending=sum(r.execution_id is None or _needs_rerun(r) for r in rows),
        reruns=sum(max(0, r.attempts - 1) for r in rows),
    )


def _criteria(row: SweepRow) -> dict[str, float]:
    """The sweep's success criteria: ``success_rms_pct`` and ``success_contact_ratio`` of its request."""
    terms = row.terms
    return {field: float(getattr(terms, field)) for field in SWEEP_TOLERANCES}


def sweep_engine(request: SweepRequest, skill: Skill) -> Engine:
    """The engine of every trial of ``request`` (one sweep, one engine, whichever workers its trials reach): its
    ``settings.engine``, else the one the trials' world names (the skill's taught world's ``engine``, when they run
    in it: ``skills.sweeps.trials_in_taught_world``), else :data:`DEFAULT_ENGINE`, never a worker's default
    (``schemas.world.engine_to_run``)."""
    in_taught_world = trials_in_taught_world(request.scenario, request.settings.environment)
    return engine_to_run(request.settings.engine, world_engine(skill.taught_world) if in_taught_world else None)


def trial_results(store: Store, row: SweepRow) -> list[TrialResult]:
    """Every trial x controller of the sweep with its execution's result (judged once finished: its verdict)."""
    criteria = _criteria(row)
    engine = Engine(row.request["settings"].get("engine") or DEFAULT_ENGINE)  # a sweep stored before it was set
    results = []
    for r in store.sweeps.trials(row.id):
        finished = _finished(r)
        judged = _outcome(r, criteria)
        results.append(
            TrialResult(
                trial=r.trial,
                controller=ControllerKind(r.controller),
                engine=engine,
                parameters={SweepParameter(k): v for k, v in r.parameters.items()},
                execution_id=r.execution_id,
                attempts=r.attempts,
                status="pending" if r.status is None or _needs_rerun(r) else r.status.value,
                success=judged.success if finished else None,
                verdict=judged.verdict if finished else None,
                reasons=list(judged.reasons) if finished else [],
                causes=list(judged.causes) if finished else [],
                true_force_rms_error_pct=judged.true_rms_pct,
                true_force_max_error_pct=judged.true_max_pct,
                touchdown_peak_ratio=judged.touchdown_ratio,
                contact_ratio=judged.contact_ratio,
                abort_reason=judged.abort_reason if finished and judged.phase is not ExecutionPhase.done else None,
                metrics=r.metrics,
            )
        )
    return results


def sweep_view(store: Store, keys: KeyExpressions, row: SweepRow) -> SweepView:
    """The sweep's state, counts, per-controller summary and sensitivity ranking (from the finished trials)."""
    criteria = _criteria(row)
    rows = store.sweeps.trials(row.id)
    summaries, ranking = [], []
    for kind in row.terms.controllers:
        controller = kind.value
        mine = [r for r in rows if r.controller == controller]
        done = [r for r in mine if _finished(r)]
        outcomes = [_outcome(r, criteria) for r in done]
        summaries.append(controller_summary(kind, len(mine), outcomes))
        parameters = [{SweepParameter(k): v for k, v in r.parameters.items()} for r in done]
        ranking.extend(sensitivity(kind, parameters, outcomes))
    return SweepView(
        id=row.id,
        status=row.status,
        created=row.created,
        updated=row.updated,
        request=row.request,
        counts=_counts(rows, criteria),
        controllers=summaries,
        sensitivity=sorted(ranking, key=lambda s: -s.importance),
        progress_key=keys.sweep_progress(row.id),
    )


class SweepRunner(WakeableThread):
    """Creates, advances and cancels sweeps over the execution queue (see the module docstring). ``start()`` the
    thread, ``close()`` it (running sweeps stay running in the database and resume on the next start); the routes
    call :meth:`create` and :meth:`cancel`."""

    thread_name = "sweeps"

    def __init__(
        self,
        store: Store,
        queue: ExecutionQueue,
        bus: BusClient,
        keys: KeyExpressions,
        window: int = WINDOW,
        poll_s: float = SWEEP_POLL_S,
    ) -> None:
        super().__init__()
        self.store, self.queue, self.bus, self.keys = store, queue, bus, keys
        self.window, self.poll_s = window, poll_s
        self._lock = threading.Lock()  # one advance at a time: the route's first submissions and the thread
        self._published: dict[str, SweepCounts] = {}
        store.executions.on_finish(lambda _execution_id: self.wake())  # submit the successor now, not on the next poll

    # ------------------------------------------------------------------ what the routes call

    def create(
        self, request: SweepRequest, skill: Skill, skill_id: str | None, demonstration_id: str | None
    ) -> SweepRow:
        """Store the sweep and submit its first executions. Raises what `ExecutionQueue.submit` raises for the
        first one (no worker, queue full, refused as invalid), with nothing stored."""
        drawn = trial_parameters(request.vary, request.trials, request.seed, request.sampler)
        trials = [
            (k, controller.value, {name.value: value for name, value in parameters.items()})
            for k, parameters in enumerate(drawn)
            for controller in request.controllers
        ]
        telemetry = TelemetryMode.stream if request.store_telemetry else TelemetryMode.none
        settings = request.settings.model_copy(update={"engine": sweep_engine(request, skill)})
        base = ExecutionRequest.model_validate(
            {**settings.model_dump(mode="json"), "skill": skill.model_dump(mode="json"),
             "scenario": request.scenario, "priority": request.priority, "telemetry": telemetry}
        )  # fmt: skip
        execution = json.loads(base.model_dump_json())
        spec = json.dumps({"execution": execution, "skill_id": skill_id, "demonstration_id": demonstration_id})
        shown = request.model_copy(update={"settings": settings}).model_dump(mode="json", exclude={"skill"})
        shown.update(inline_skill=request.skill is not None)
        with self._lock:
            row = self.store.sweeps.add(shown, spec, trials, SweepState.running)
            try:
                self._advance(row, first=True)
            except Exception:
                self.store.sweeps.delete(row.id)
                raise
        return row

    def cancel(self, sweep_id: str) -> bool:
        """Stop a running sweep: its queued executions are cancelled, its running ones aborted; False if it was not
        running."""
        with self._lock:
            running = SweepState.running
            if not self.store.sweeps.set_status(sweep_id, SweepState.cancelled, only_from=running):
                return False
            for r in self.store.sweeps.trials(sweep_id):
                if r.status is ExecutionState.queued and r.execution_id:
                    self.queue.cancel(r.execution_id, "sweep cancelled")
                elif r.status in (ExecutionState.running, ExecutionState.paused) and r.execution_id:
                    self.bus.send_command(r.execution_id, CommandName.abort)
            row = self.store.sweeps.get(sweep_id)
            if row is not None:
                self._publish(row)
        return True

    # ------------------------------------------------------------------ the thread

    def _run(self) -> None:
        while True:
            self._wake.wait(self.poll_s)
            self._wake.clear()  # before looking: an execution that ends meanwhile wakes the next round
            if self._stop.is_set():
                return
            for listed in self.store.sweeps.page(limit=1000, status=SweepState.running):
                try:
                    with self._lock:
                        row = self.store.sweeps.get(listed.id)  # read again under the lock: a cancel may have come
                        if row is not None and row.status == SweepState.running:
                            self._advance(row)
                except Exception:  # keep the thread alive whatever one sweep does
                    log.exception("sweep %s could not advance", listed.id)

    def _advance(self, row: SweepRow, first: bool = False) -> None:
        """Submit the trials that wait (new ones, and reruns after an infrastructure failure) while fewer than
        ``window`` are in flight; mark the sweep done once every trial has a result; publish the progress.
        ``first``: errors of the submission raise (the route answers them), else they wait for the next round."""
        from services.bus import BusRequestError, NoWorkerAvailable
        from services.store import QueueFull, QuotaFull

        rows = self.store.sweeps.trials(row.id)  # read once a round (~30 ms for 600 trials x controllers)
        in_flight = sum(r.status is not None and r.status not in TERMINAL for r in rows)
        waiting = [k for k, r in enumerate(rows) if r.execution_id is None or _needs_rerun(r)]
        if not waiting and in_flight == 0:
            self.store.sweeps.set_status(row.id, SweepState.done, only_from=SweepState.running)
            row = self.store.sweeps.get(row.id) or row
        spec = json.loads(row.spec) if waiting else {}
        for k in waiting[: max(0, self.window - in_flight)]:
            r = rows[k]
            try:
                rows[k] = self._submit(row, spec, r)
            except (NoWorkerAvailable, QueueFull, QuotaFull, BusRequestError):
                if first:
                    raise
                log.warning("sweep %s: trial %d (%s) not submitted now", row.id, r.trial, r.controller, exc_info=True)
                break
            first = False
        self._publish(row, rows)

    def _submit(self, row: SweepRow, spec: dict[str, Any], r: SweepTrialRow) -> SweepTrialRow:
        """Submit the trial's execution; return its row as now stored."""
        environment = trial_environment(
            spec["execution"]["environment"], r.parameters, trial_noise_seed(row.terms.seed, r.trial)
        )
        base = spec["execution"]
        tolerances = trial_tolerances(base.get("tolerances") or {}, _criteria(row))
        request = ExecutionRequest.model_validate(
            {**base, **planned_pad(base, r.parameters), "environment": environment, "controller": r.controller,
             "tolerances": tolerances}
        )  # fmt: skip
        # The skill's taught world is the trials' when they vary its cylinder (POST /sweeps refuses them otherwise).
        overrides = trial_world_overrides(base["skill"].get("taught_world"), r.parameters)
        shown = request.model_dump(mode="json", exclude={"skill"})
        shown.update(
            skill_id=spec["skill_id"],
            inline_skill=spec["skill_id"] is None,
            sweep=SweepTrialRef(id=row.id, trial=r.trial).model_dump(),
        )
        if overrides:
            shown.update(world_overrides=overrides)
        if _needs_rerun(r):
            log.warning("sweep %s: trial %d (%s) submitted again after: %s", row.id, r.trial, r.controller, r.error)
        execution, _ = self.queue.submit(
            Dispatch(request, overrides, spec["demonstration_id"]), shown, spec["skill_id"], request.priority
        )
        self.store.sweeps.assign_trial(row.id, r.trial, r.controller, execution.id)
        return replace(r, execution_id=execution.id, attempts=r.attempts + 1, status=execution.status, metrics=None,
                       error=execution.error)  # fmt: skip

    def _publish(self, row: SweepRow, rows: list[SweepTrialRow] | None = None) -> None:
        """Put the sweep's progress on the bus if its counts (or status) changed since the last put (``rows``: its
        trials as just read, else read now)."""
        criteria = _criteria(row)
        rows = self.store.sweeps.trials(row.id) if rows is None else rows
        counts = _counts(rows, criteria)
        key = f"{row.id}:{row.status}"
        if self._published.get(key) == counts:
            return
        rates: dict[str, float | None] = {}
        for controller in (kind.value for kind in row.terms.controllers):
            done = [_outcome(r, criteria) for r in rows if r.controller == controller and _finished(r)]
            ok = sum(o.success for o in done)
            rates[controller] = ok / len(done) if done else None
        progress = SweepProgress(sweep_id=row.id, status=row.status, counts=counts, success_rate=rates)
        try:
            self.bus.publish(self.keys.sweep_progress(row.id), progress.model_dump_json())
        except Exception:  # the bus is down for a moment: the next change publishes again
            log.warning("sweep %s: progress not published", row.id, exc_info=True)
            return
        self._published[key] = counts
