"""The figures of a demo run (drawn by ``services.figures``): each teacher skill's paths, learning and CF force per
case, each real recording's paths, and the real recordings' CF forces; a real recording placed as the worker placed it
(``applied_placement``)."""

from __future__ import annotations

from pathlib import Path

from experiments.cases import (
    OURS,
    Case,
    LearnedSkill,
    Outcome,
    fmt,
)
from schemas.execution import Placement


def applied_placement(outcomes: list[Outcome], case: Case) -> Placement | None:
    """The ``schemas.Placement`` the worker applied in ``case`` (the same for every controller), or None."""
    for o in outcomes:
        if o.case == case and (o.metrics or {}).get("placement"):
            return Placement.model_validate(o.metrics["placement"])
    return None


def _placed(learned: LearnedSkill, placement):
    """(demonstration, skill) as they ran: placed by ``placement`` (a real recording's), else as learned."""
    if placement is None:
        return learned.demonstration, learned.skill
    from schemas.execution import EnvironmentChange, WorkPieceSource
    from sim_worker.execution_world import execution_world

    environment = EnvironmentChange(work_piece=WorkPieceSource.measured, placement=placement)
    world = execution_world(learned.skill, environment, demonstration=learned.demonstration)
    return world.demonstration, world.skill


# --------------------------------------------------------------------------------------------------- figures


def _short_final(o: Outcome) -> str:
    """``aborted (force limit)`` from ``aborted (force limit: measured 83.5 N > ...)``."""
    head, _, reason = o.final.partition(" (")
    return f"{head} ({reason.split(':')[0].rstrip(')')})" if reason else head


def _trial_label(case: Case, outcomes: list[Outcome]) -> str:
    """A trial's subplot title: the case and each controller's force RMS errors (true, and CF z)."""
    errors = [
        f"{o.controller} {fmt(o.metric('true_force_rms_error_pct'))} / {fmt(o.metric('force_rms_error_pct'))} %"
        if o.metric("force_rms_error_pct") is not None
        else f"{o.controller} {_short_final(o)}"
        for o in outcomes
        if o.case == case
    ]
    title = case.label if not case.spec.real else case.spec.title
    return f"{title} — force RMS error true / CF-z: " + ", ".join(errors)


def write_figures(out: Path, skills: dict[str, LearnedSkill], outcomes: list[Outcome], traces: dict) -> list[Path]:
    """The figures of the run in ``out/figures``: for each teacher skill its paths (ours in every case), learning
    and CF force per case; for each real recording its paths (every controller); the real recordings' CF forces in
    one figure."""
    from schemas.skill import SkillType
    from services.figures import write_learning_figure, write_paths_figure, write_trials_force_figure

    folder = out / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    real_cases: list[Case] = []
    for key, learned in skills.items():
        spec = learned.spec
        skill_cases = list(dict.fromkeys(o.case for o in outcomes if o.case.skill == key))
        paths = folder / f"demo_{key}_paths.png"
        contour_view = (18.0, -20.0) if learned.skill.skill_type is SkillType.contour else (22.0, -58.0)
        if spec.real:
            [case] = skill_cases
            real_cases.append(case)
            demonstration, skill = _placed(learned, applied_placement(outcomes, case))
            runs = [(k, traces[(case, k)]) for k in case.controllers if (case, k) in traces]
            write_paths_figure(
                demonstration,
                skill,
                runs,
                paths,
                title=f"{spec.title} ({spec.figure}): demonstration and reproductions on the work piece measured "
                "from it, placed in reach",
                view=contour_view,
            )
            written.append(paths)
            continue
        learn = folder / f"demo_{key}_learned.png"
        write_learning_figure(learned.demonstration, learned.skill, learn)
        ours = [(c.label, traces[(c, OURS)]) for c in skill_cases if (c, OURS) in traces]
        write_paths_figure(
            learned.demonstration,
            learned.skill,
            ours,
            paths,
            title=f"{spec.title} ({spec.figure}a/b): demonstration and reproductions ({OURS})",
            view=contour_view,
        )
        forces = folder / f"demo_{key}_forces.png"
        write_trials_force_figure(
            _force_trials(skill_cases, outcomes, traces),
            forces,
            ours=OURS,
            title=f"{spec.title} ({spec.figure}d): CF-z force per trial, desired vs measured",
        )
        written += [paths, learn, forces]
    if real_cases:
        forces = folder / "demo_kuleuven_forces.png"
        write_trials_force_figure(
            _force_trials(real_cases, outcomes, traces),
            forces,
            ours=OURS,
            title="KU Leuven recordings (real data): CF-z force per trial on the work piece measured from it, "
            "desired vs measured",
        )
        written.append(forces)
    return written


def _force_trials(cases: list[Case], outcomes: list[Outcome], traces: dict) -> list[tuple[str, dict]]:
    return [(_trial_label(c, outcomes), {k: traces[(c, k)] for k in c.controllers if (c, k) in traces}) for c in cases]
