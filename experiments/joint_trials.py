"""Leave-one-out of joint learning (`skills.joint_learning`) on sets of demonstrations of one task whose truth is
known: the corpus's repeated human-like trials (`corpus.families.human_trials`) and the four KU Leuven recordings,
each put on the object where trial ``contour_b_1`` found it (docs/LEARNING.md, section 11).

For every trial of a set: the skill learned from the others, its force band held against the left-out trial's
TRUE normal force (the corpus's truth; on the KU Leuven crease the force with its part along the crease removed,
which lies in the crease's normal cone), and the joint skill's CF z against the truth next to each single trial's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from corpus.case import CorpusCase
from corpus.scoring import Score, score
from schemas.demonstration import Demonstration
from schemas.import_options import CsvImportOptions
from schemas.skill import LearnOptions, SegmentKind, Skill, SkillTypeRequest
from services.csv_import import demonstration_from_csv
from services.datasets import kuleuven_file
from services.kuleuven_object import KuleuvenGroundTruth, kuleuven_ground_truth, skill_against_object
from skills.force_band import share_in_band
from skills.joint_learning import learn_joint_skill
from skills.parameterize import learn_skill
from skills.quaternions import matrix_from_quaternion, quaternion_from_matrix, quaternions_sign_continuous

if TYPE_CHECKING:
    from experiments.kuleuven_cad import CadRun

KULEUVEN_TRIALS = ("contour_a_1", "contour_a_2", "contour_b_1", "contour_b_2")
"""The KU Leuven recordings, two per configuration."""

KULEUVEN_REFERENCE = "contour_b_1"
"""The recording whose placement of the object every other is moved onto."""


def read_csv(text: str, options: dict[str, object]) -> Demonstration:
    """A corpus recording's file read as a user would (`corpus.case.CsvReader`)."""
    return demonstration_from_csv(text, CsvImportOptions(**options))


@dataclass(frozen=True)
class LeftOut:
    """One trial left out of its set: ``share_in_band`` of its contact samples whose true normal force lies in the
    joint skill's band (None: its contact segments do not match the joint skill's), the joint skill's and each
    single trial's CF error against the truth (deg; the singles are the trials learned from), the joint skill's
    warnings, the others left out by the learner, and the seconds joint learning took. Where the truth has
    tolerances (the corpus): whether the joint skill and each single one are within every one of them
    (``bench_corpus.within``'s tolerances: type, segments, normal, force, boundaries), and whether each single one
    was warned."""

    set_name: str
    left_out: str
    share_in_band: float | None
    joint_error_deg: float
    single_errors_deg: list[float]
    warnings: list[str]
    misfits: list[str]
    seconds: float
    joint_right: bool | None = None
    singles_right: tuple[bool, ...] = ()
    singles_warned: tuple[bool, ...] = ()

    @property
    def best_single_deg(self) -> float:
        return min(self.single_errors_deg)


def _contacts(skill: Skill) -> list:
    return [s for s in skill.segments if s.kind is SegmentKind.contact]


def band_share(
    joint: Skill,
    demonstration: Demonstration,
    truth_t: NDArray[np.float64],
    truth_positions: NDArray[np.float64],
    truth_press: NDArray[np.float64],
) -> float | None:
    """The share of a left-out ``demonstration``'s contact (its own segments, learned as the joint skill's type) whose
    true press ``truth_press`` (N, at ``truth_t`` s and ``truth_positions`` m) lies in the joint skill's bands."""
    own = learn_skill(demonstration, LearnOptions(skill_type=SkillTypeRequest(joint.skill_type.value)))
    pairs = list(zip(_contacts(own), _contacts(joint), strict=False))
    if len(_contacts(own)) != len(_contacts(joint)):
        return None
    runs = []
    for mine, theirs in pairs:
        rows = (truth_t >= mine.t_start) & (truth_t <= mine.t_end)
        runs.append((theirs.force_band, truth_positions[rows], truth_press[rows]))
    return share_in_band(runs)


def task_truth(cases: Sequence[CorpusCase], reference: CorpusCase) -> CorpusCase:
    """The truth of a task learned from ``cases``: ``reference``'s (the part is the same in every trial; the joint
    skill's samples are the reference's) pressing the trials' mean: each segment's press their mean, the true normal
    force at every sample scaled by the same ratio (the trials' plateaus differ by the hand, ±10 %)."""
    segments = [
        replace(segment, force_n=float(np.mean([case.segments[k].force_n for case in cases])))
        for k, segment in enumerate(reference.segments)
    ]
    ratio = segments[0].force_n / reference.segments[0].force_n
    return replace(reference, segments=segments, normal_force_n=reference.normal_force_n * ratio)


def corpus_leave_one_out(
    set_name: str, cases: Sequence[CorpusCase], within: Callable[[CorpusCase, Score], bool]
) -> list[LeftOut]:
    """Leave each of ``cases`` (trials of one task) out in turn and learn from the others; ``within`` says whether a
    score is within the corpus's tolerances."""
    demonstrations = [case.demonstration(read_csv) for case in cases]
    singles = [learn_skill(d) for d in demonstrations]
    scores = [score(skill, case) for skill, case in zip(singles, cases, strict=True)]
    results = []
    for k, case in enumerate(cases):
        others = [i for i in range(len(cases)) if i != k]
        started = time.perf_counter()
        joint = learn_joint_skill([demonstrations[i] for i in others], sources=[cases[i].name for i in others])
        seconds = time.perf_counter() - started
        reference = next(cases[i] for i in others if cases[i].name == joint.demonstration.name)
        truth = task_truth([cases[i] for i in others], reference)
        joint_score = score(joint, truth)
        share = band_share(joint, demonstrations[k], case.t, case.positions, case.normal_force_n)
        results.append(
            LeftOut(
                set_name,
                case.name,
                share,
                joint_score.normal_error_deg,
                [scores[i].normal_error_deg for i in others],
                joint.warnings(),
                [f"{use.source}: {use.misfit.value}" for use in joint.demonstrations or [] if use.misfit is not None],
                seconds,
                within(truth, joint_score),
                tuple(within(cases[i], scores[i]) for i in others),
                tuple(bool(singles[i].warnings()) for i in others),
            )
        )
    return results


def moved_demonstration(
    demonstration: Demonstration, rotation: NDArray[np.float64], translation: NDArray[np.float64]
) -> Demonstration:
    """``demonstration`` moved by ``x' = R x + t``: positions, tool orientations, forces and moments (world)."""
    a = demonstration.arrays()
    tools = rotation @ matrix_from_quaternion(a.orientations)
    wrenches = np.column_stack([a.wrenches[:, :3] @ rotation.T, a.wrenches[:, 3:] @ rotation.T])
    orientations = quaternions_sign_continuous(quaternion_from_matrix(tools))
    positions = a.positions @ rotation.T + translation
    return Demonstration.from_arrays(a.t, positions, orientations, wrenches, demonstration.metadata)


@dataclass(frozen=True)
class KuleuvenTrial:
    """A KU Leuven recording moved onto the reference's placement of the object, and that placement's truth."""

    name: str
    demonstration: Demonstration
    truth: KuleuvenGroundTruth


def kuleuven_trials() -> list[KuleuvenTrial]:
    """The four KU Leuven recordings, each moved from where its registration found the object to where
    `KULEUVEN_REFERENCE`'s did (world_ref from world_i: ``R_ref R_iᵀ``, ``t_ref - R_ref R_iᵀ t_i``)."""
    truths = {name: kuleuven_ground_truth(kuleuven_file(f"{name}.csv")) for name in KULEUVEN_TRIALS}
    ref = truths[KULEUVEN_REFERENCE].registration
    trials = []
    for name, truth in truths.items():
        reg = truth.registration
        rotation = ref.rotation @ reg.rotation.T
        translation = ref.translation_m - rotation @ reg.translation_m
        trials.append(KuleuvenTrial(name, moved_demonstration(truth.demonstration, rotation, translation), truth))
    return trials


def _crease_press(truth: KuleuvenGroundTruth, positions: NDArray, forces: NDArray) -> NDArray[np.float64]:
    """The force (N) with its component along the crease removed: the contact's normal part, in the normal cone."""
    cone = truth.cones_at(positions)
    tangent = np.cross(cone.inward_a, cone.inward_b)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    return np.linalg.norm(forces - np.sum(forces * tangent, axis=1, keepdims=True) * tangent, axis=1)


def _bisector_deg(skill: Skill, truth: KuleuvenGroundTruth) -> float:
    """The median angle (deg) of a skill's CF z from the crease's cone bisector over its contact."""
    return float(np.degrees(np.median(skill_against_object(skill, truth).from_bisector)))


def kuleuven_leave_one_out() -> list[LeftOut]:
    """Leave each KU Leuven recording out in turn and learn from the other three, on the reference's placement.
    CF error: the median angle of CF z from the crease's cone bisector (the cone is ~90° wide; no learned CF z
    leaves it)."""
    trials = kuleuven_trials()
    reference = next(t for t in trials if t.name == KULEUVEN_REFERENCE).truth
    moved_truth = {t.name: _moved_truth(t, reference) for t in trials}
    singles = {t.name: _bisector_deg(learn_skill(t.demonstration), moved_truth[t.name]) for t in trials}
    results = []
    for k, trial in enumerate(trials):
        others = [t for i, t in enumerate(trials) if i != k]
        started = time.perf_counter()
        joint = learn_joint_skill([t.demonstration for t in others], sources=[t.name for t in others])
        seconds = time.perf_counter() - started
        joint_truth = moved_truth[
            next(t.name for t in others if t.demonstration.metadata.name == joint.demonstration.name)
        ]
        a = trial.demonstration.arrays()
        press = _crease_press(reference, a.positions, a.wrenches[:, :3])
        results.append(
            LeftOut(
                "KU Leuven",
                trial.name,
                band_share(joint, trial.demonstration, a.t, a.positions, press),
                _bisector_deg(joint, joint_truth),
                [singles[t.name] for t in others],
                joint.warnings(),
                [f"{use.source}: {use.misfit.value}" for use in joint.demonstrations or [] if use.misfit is not None],
                seconds,
            )
        )
    return results


def _moved_truth(trial: KuleuvenTrial, reference: KuleuvenGroundTruth) -> KuleuvenGroundTruth:
    """The reference's truth with ``trial``'s moved demonstration (`skill_against_object` reads its samples)."""
    return replace(reference, demonstration=trial.demonstration)


@dataclass(frozen=True)
class Executed:
    """A scripted teacher's scenario, its seeds' single-trial skills and the joint one, each executed on the true
    world with the table moved (`EXECUTED_UNKNOWN_OFFSET_M`, the controller not told): true normal force RMS and max
    error (% of the reference), the verdict, and the joint run's share of contact in its band."""

    scenario: str
    single_rms_pct: list[float]
    single_max_pct: list[float]
    single_verdicts: list[str]
    joint_rms_pct: float
    joint_max_pct: float
    joint_verdict: str
    joint_in_band: float | None


EXECUTED_UNKNOWN_OFFSET_M = (0.0, 0.0, 0.02)
"""The work piece 2 cm higher than taught in the executed comparison (the README's tour does the same)."""


def executed_comparison(scenario: str, seeds: Sequence[int], **overrides: object) -> Executed:
    """Record ``scenario`` with each of ``seeds`` (another hand each, the same world), learn each alone and all
    together, and execute every skill with `hybrid_cf` in the taught world (`sim_worker.executor.execute_skill`)."""
    from schemas.execution import EnvironmentChange, ExecutionSettings
    from sim_worker.executor import execute_skill
    from sim_worker.teacher import record_demonstration

    recordings = [record_demonstration(scenario, seed=seed, **overrides) for seed in seeds]
    settings = ExecutionSettings(
        pace="fast", environment=EnvironmentChange(unknown_offset=list(EXECUTED_UNKNOWN_OFFSET_M))
    )
    singles = [
        execute_skill(learn_skill(r.demonstration), r.world_config, settings, demonstration=r.demonstration).metrics
        for r in recordings
    ]
    joint = learn_joint_skill([r.demonstration for r in recordings], sources=[str(seed) for seed in seeds])
    reference = recordings[next(use.index for use in joint.demonstrations or [] if use.reference)]
    run = execute_skill(joint, reference.world_config, settings, demonstration=reference.demonstration).metrics
    return Executed(
        scenario,
        [m.true_force_rms_error_pct or float("nan") for m in singles],
        [m.true_force_max_error_pct or float("nan") for m in singles],
        [m.verdict.verdict.value if m.verdict else "—" for m in singles],
        run.true_force_rms_error_pct or float("nan"),
        run.true_force_max_error_pct or float("nan"),
        run.verdict.verdict.value if run.verdict else "—",
        run.true_force_in_band,
    )


@dataclass(frozen=True)
class CadExecuted:
    """A KU Leuven skill executed on the object's CAD (`experiments.kuleuven_cad.cad_runs`): ``skill`` names it (a
    recording's, or the one learned from all of them), ``runs`` one per CF x-y stiffness."""

    skill: str
    runs: list[CadRun]


def kuleuven_cad_comparison(stiffnesses: tuple[float | None, ...] | None = None) -> list[CadExecuted]:
    """Each KU Leuven recording's own skill and the skill learned from all four together, every one learned on the
    reference's placement of the object (`kuleuven_trials`) and executed on its CAD there, placed in reach as any
    real recording's skill is, once per CF x-y stiffness of ``stiffnesses`` (N/m; None: the default gains'; default
    `experiments.kuleuven_cad.CAD_STIFFNESSES_N_PER_M`)."""
    from experiments.kuleuven_cad import CAD_STIFFNESSES_N_PER_M, cad_runs
    from schemas.execution import ExecutionSettings
    from sim_worker.execution_world import execution_world

    stiffnesses = CAD_STIFFNESSES_N_PER_M if stiffnesses is None else stiffnesses
    trials = kuleuven_trials()
    reference = next(t for t in trials if t.name == KULEUVEN_REFERENCE).truth
    environment = ExecutionSettings().environment

    def on_cad(skill: Skill, trial: KuleuvenTrial) -> list[CadRun]:
        return cad_runs(execution_world(skill, environment), _moved_truth(trial, reference), stiffnesses)

    executed = [CadExecuted(t.name, on_cad(learn_skill(t.demonstration), t)) for t in trials]
    joint = learn_joint_skill([t.demonstration for t in trials], sources=[t.name for t in trials])
    own = next(t for t in trials if t.demonstration.metadata.name == joint.demonstration.name)
    return [*executed, CadExecuted(f"all {len(trials)} together", on_cad(joint, own))]
