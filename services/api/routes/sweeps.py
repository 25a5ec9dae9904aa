"""``/sweeps``: run a skill over N sampled variations of its cell with several controllers (``services.sweeps``),
follow it, list, cancel, read every trial."""

from __future__ import annotations

from fastapi import APIRouter, Response

from schemas.sweep import SweepCreated, SweepRequest, SweepView, TrialResult
from services.api import errors
from services.api.deps import (
    READ_GUARD,
    STORING_GUARD,
    TOKEN_GUARD,
    ClientCapsDep,
    ClientDep,
    KeysDep,
    Limit,
    Offset,
    SettingsDep,
    StoreDep,
    SweepsDep,
    check_settings_for_skill,
    need_sweeps,
    skill_to_run,
)
from services.api.errors import ERROR_RESPONSES, MUTATING_RESPONSES, READ_RESPONSES, STORING_RESPONSES
from services.api.limits import TOO_MANY, WorkKind
from services.api.responses import LIST_RESPONSES, list_page
from services.store import Store, SweepRow
from services.sweeps import sweep_view, trial_results
from skills.sweeps import inapplicable_parameter

router = APIRouter(tags=["sweeps"], dependencies=READ_GUARD, responses=READ_RESPONSES)


def _found(store: Store, sweep_id: str) -> SweepRow:
    row = store.sweeps.get(sweep_id)
    if row is None:
        raise errors.not_found("sweep", sweep_id)
    return row


@router.post(
    "/sweeps",
    status_code=202,
    response_model=SweepCreated,
    responses={**ERROR_RESPONSES, **STORING_RESPONSES, **errors.UNAVAILABLE, **TOO_MANY},
    dependencies=STORING_GUARD,
)
def post_sweep(
    request: SweepRequest,
    store: StoreDep,
    sweeps: SweepsDep,
    keys: KeysDep,
    settings: SettingsDep,
    caps: ClientCapsDep,
    client: ClientDep,
) -> SweepCreated:
    """Run a skill over ``trials`` sampled variations (``vary``: unknown offset and tilt, friction, contact
    stiffness and damping, sensor bias and noise, force scale) once per controller, each as an execution through
    the queue at ``priority`` (below single executions), on every worker of the bus.

    Replies 202 once the first executions are submitted; follow it with ``GET /sweeps/{id}`` or the Zenoh key
    ``progress_key``. The same ``seed`` draws the same trials. 404 for an unknown skill, 422 for a bad request, for a
    parameter the trials' world has nothing for (``cylinder_radius_m`` of a skill not taught on a cylinder) or one a
    worker refuses (an unknown scenario), for ``settings`` whose trials would each be over the job budget, 503 when
    no worker is connected, 429 when this client has ``CONTACT_SKILLS_CLIENT_SWEEPS_MAX`` sweeps running already,
    507 when the first trial's telemetry (``store_telemetry``) does not fit in the storage quota (each trial
    reserves its own when submitted; later ones wait for room)."""
    from services.bus import BusRequestError, NoWorkerAvailable
    from services.store import QueueFull, QuotaFull

    skill, demonstration_id = skill_to_run(store, request.skill_id, request.skill)
    skill_at = ("body", "skill_id" if request.skill_id is not None else "skill")
    check_settings_for_skill(skill, request.settings, settings.job_budget, ("body", "settings"), skill_at)
    if problem := inapplicable_parameter(request.vary, skill, request.scenario, request.settings.environment):
        parameter, why = problem
        raise errors.unprocessable(["body", "vary", parameter.value], why)
    runner = need_sweeps(sweeps)
    caps.admit(WorkKind.sweep, client)
    try:
        row = runner.create(request, skill, request.skill_id, demonstration_id)
    except (NoWorkerAvailable, QueueFull) as exc:
        raise errors.unavailable(str(exc)) from None
    except QuotaFull as exc:
        raise errors.quota_full(exc) from None
    except BusRequestError as exc:
        raise errors.refused_by_worker(str(exc), environment_at=("body", "settings")) from None
    caps.hold(WorkKind.sweep, client, row.id)
    return SweepCreated(
        id=row.id,
        status=row.status,
        executions=request.trials * len(request.controllers),
        progress_key=keys.sweep_progress(row.id),
    )


@router.get("/sweeps", response_model=list[SweepView], responses=LIST_RESPONSES)
def list_sweeps(store: StoreDep, keys: KeysDep, limit: Limit = 100, offset: Offset = 0) -> Response:
    """Sweeps, newest first, with their results so far.

    Each with its state, its counts (finished, succeeded, running, queued, reruns), its per-controller summary and
    sensitivity ranking, as ``GET /sweeps/{id}``; ``limit`` and ``offset`` page through them, a page of at most 4 MiB
    naming the next one's offset in ``X-Next-Offset``."""
    return list_page(store.sweeps.page(limit + 1, offset), lambda row: sweep_view(store, keys, row), offset, limit)


@router.get("/sweeps/{sweep_id}", response_model=SweepView, responses=ERROR_RESPONSES)
def get_sweep(sweep_id: str, store: StoreDep, keys: KeysDep) -> SweepView:
    """State and progress of a sweep, and its results so far: per controller the success rate and the quantiles
    of the true normal-force errors and the touch-down peak, and the varied parameters ranked by how much they
    drive the failures. 404 for an unknown id."""
    return sweep_view(store, keys, _found(store, sweep_id))


@router.get("/sweeps/{sweep_id}/trials", response_model=list[TrialResult], responses=ERROR_RESPONSES)
def get_sweep_trials(sweep_id: str, store: StoreDep) -> list[TrialResult]:
    """Every trial x controller: the parameters drawn, its execution, its metrics and whether it succeeded."""
    return trial_results(store, _found(store, sweep_id))


@router.post(
    "/sweeps/{sweep_id}/cancel",
    status_code=202,
    response_model=SweepView,
    responses={**ERROR_RESPONSES, **MUTATING_RESPONSES, 409: {"model": errors.ApiError}, **errors.UNAVAILABLE},
    dependencies=TOKEN_GUARD,
)
def cancel_sweep(sweep_id: str, store: StoreDep, sweeps: SweepsDep, keys: KeysDep) -> SweepView:
    """Cancel a running sweep: its queued executions are cancelled, its running ones aborted (their results stay).
    409 when it is not running any more."""
    row = _found(store, sweep_id)
    if not need_sweeps(sweeps).cancel(sweep_id):
        raise errors.sweep_not_running(sweep_id, row.status)
    return sweep_view(store, keys, _found(store, sweep_id))
