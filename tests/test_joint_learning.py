"""One skill from several demonstrations (`skills.joint_learning`, issue 42), against the corpus's truth: trials of
one task (`corpus.families.human_trials`: the same part and press, another hand and sensor each)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from corpus.case import CorpusCase
from corpus.families import human_trials, plane_case
from corpus.scoring import score
from experiments.joint_trials import band_share, read_csv
from schemas.demonstration import Demonstration
from schemas.skill import CheckBound, CheckName, LearnOptions, MisfitPolicy, MisfitReason, SegmentKind, Skill
from skills.joint_alignment import warping_path
from skills.joint_learning import JointLearningError, learn_joint_skill
from skills.parameterize import learn_skill
from skills.skill_checks import check_bound

BEFORE = Path(__file__).parent / "data" / "skill_before_joint_learning.json"
"""A skill learned and stored before joint learning existed (commit eb6b496, `plane_case('straight', 0.0, 0)`)."""


@pytest.fixture(scope="module")
def task() -> tuple[list[CorpusCase], list[Demonstration]]:
    """Four trials of one straight stroke on a plane tilted 12°: each alone leans 2-5° off the plane's normal."""
    cases = human_trials("human-straight", 0, 4)
    return cases, [case.demonstration(read_csv) for case in cases]


@pytest.fixture(scope="module")
def joint(task: tuple[list[CorpusCase], list[Demonstration]]) -> Skill:
    """The skill learned from the first three trials."""
    cases, demonstrations = task
    return learn_joint_skill(demonstrations[:3], sources=[case.name for case in cases[:3]])


def test_one_demonstration_learns_exactly_as_one_skill_did() -> None:
    demonstration = plane_case("straight", 0.0, 0).demonstration()
    assert learn_joint_skill([demonstration]).model_dump_json() == learn_skill(demonstration).model_dump_json()


def _same(before: object, now: object, path: str = "") -> None:
    """``now`` holds every value of ``before`` (numbers to 1e-9 relative: another BLAS may round the last bits
    differently); keys ``before`` lacks must be empty (the fields added since)."""
    if isinstance(before, dict):
        assert isinstance(now, dict), path
        for key, value in now.items():
            if key in before:
                _same(before[key], value, f"{path}.{key}")
            else:
                assert value is None, f"{path}.{key} is new and set"
    elif isinstance(before, list):
        assert isinstance(now, list) and len(now) == len(before), path
        for k, (b, n) in enumerate(zip(before, now, strict=True)):
            _same(b, n, f"{path}[{k}]")
    elif isinstance(before, float) and not isinstance(now, bool):
        assert now == pytest.approx(before, rel=1e-9, abs=1e-12), path
    else:
        assert now == before, path


def test_one_demonstration_learns_the_skill_it_learned_before_joint_learning() -> None:
    """The stored skill was learned by the code before joint learning (commit eb6b496) from this demonstration."""
    stored = json.loads(BEFORE.read_text())
    now = json.loads(learn_joint_skill([plane_case("straight", 0.0, 0).demonstration()]).model_dump_json())
    _same(stored, now)


def test_a_skill_stored_before_joint_learning_loads_unchanged() -> None:
    stored = json.loads(BEFORE.read_text())
    skill = Skill.model_validate(stored)
    assert skill.demonstrations is None
    assert all(segment.force_band is None for segment in skill.segments)
    dumped = json.loads(skill.model_dump_json())
    # Every stored value comes back as it was; only the new fields, empty, are added.
    assert {key: dumped[key] for key in stored} | {"segments": None, "checks": None} == stored | {
        "segments": None,
        "checks": None,
    }
    for old, new in zip(stored["segments"], dumped["segments"], strict=True):
        assert {key: new[key] for key in old} == old and new["force_band"] is None
    for old, new in zip(stored["checks"], dumped["checks"], strict=True):
        assert {key: new[key] for key in old} == old and new["demonstration"] is None


def test_the_warping_path_recovers_a_known_time_warp() -> None:
    """A path run at a varying pace against the same path at an even one: matched points lie on the same place."""
    even = np.linspace(0.0, 1.0, 100)
    warped = even**1.7  # slow at first, fast at the end
    path = lambda s: np.column_stack([np.cos(3 * s), np.sin(3 * s), s])  # noqa: E731
    i, j = warping_path(path(even), path(warped))
    assert i[0] == j[0] == 0 and i[-1] == j[-1] == 99
    assert np.max(np.abs(even[i] - warped[j])) < 0.02  # the same place, to its spacing


def test_three_trials_of_a_line_find_the_plane_that_each_alone_leans_off(
    task: tuple[list[CorpusCase], list[Demonstration]], joint: Skill
) -> None:
    cases, demonstrations = task
    singles = [
        score(learn_skill(d), case).normal_error_deg for d, case in zip(demonstrations[:3], cases[:3], strict=True)
    ]
    reference = next(case for case in cases if case.name == joint.demonstration.name)
    together = score(joint, reference)
    assert min(singles) > 2.0  # each alone: the hand's lean about the line
    assert together.type_right and together.strokes_right
    assert together.normal_error_deg < 1.0
    uses = joint.demonstrations
    assert uses is not None and [use.source for use in uses] == [case.name for case in cases[:3]]
    assert all(use.misfit is None and use.weight == pytest.approx(1 / 3) for use in uses)
    assert all(use.share_in_band is not None and use.share_in_band >= 0.9 for use in uses)
    names = {check.name for check in joint.checks}
    assert CheckName.demonstration_in_band in names and CheckName.demonstration_normal in names
    band = next(s for s in joint.segments if s.kind is SegmentKind.contact).force_band
    assert band is not None and band.demonstrations == 3
    plateau = np.mean([case.segments[0].force_n for case in cases[:3]])
    middle = slice(len(band.mean_n) // 4, 3 * len(band.mean_n) // 4)
    assert np.all(np.asarray(band.lower_n)[middle] < plateau) and np.all(np.asarray(band.upper_n)[middle] > plateau)


def test_a_left_out_trial_presses_within_the_learned_band(
    task: tuple[list[CorpusCase], list[Demonstration]], joint: Skill
) -> None:
    cases, demonstrations = task
    left_out = cases[3]
    share = band_share(joint, demonstrations[3], left_out.t, left_out.positions, left_out.normal_force_n)
    assert share is not None and share >= 0.9


def test_each_demonstration_is_judged_against_the_skill_learned_without_it(
    task: tuple[list[CorpusCase], list[Demonstration]],
) -> None:
    # One of four trials pressed 1.5 times as hard (its wrench scaled; the others ±10 % of one another). Judged
    # against a band it is part of, it widens the band to hold itself; against the band of the other three it is
    # outside, and they, each against the band of the rest (the hard one among them), are inside.
    cases, demonstrations = task
    a = demonstrations[1].arrays()
    harder = Demonstration.from_arrays(a.t, a.positions, a.orientations, 1.5 * a.wrenches, demonstrations[1].metadata)
    sources = [case.name for case in cases]
    skill = learn_joint_skill([demonstrations[0], harder, *demonstrations[2:]], sources=sources)
    in_band = {c.demonstration: c for c in skill.checks if c.name is CheckName.demonstration_in_band}
    assert sorted(in_band) == [0, 1, 2, 3]
    assert not in_band[1].passed and in_band[1].value < 0.5 and sources[1] in in_band[1].message
    assert all(in_band[k].passed for k in (0, 2, 3))
    uses = skill.demonstrations or []
    assert [use.share_in_band for use in uses] == [in_band[k].value for k in range(4)]
    for check in in_band.values():  # the side the dashboard shows (check_bound) is the side the check passed on
        at_least = check_bound(check) is CheckBound.at_least
        assert check.passed == (check.value >= check.limit if at_least else check.value <= check.limit), check


def test_two_demonstrations_are_not_judged_by_a_band_of_one(
    task: tuple[list[CorpusCase], list[Demonstration]],
) -> None:
    # Left out in turn, each of two leaves a band of ONE demonstration: no spread across demonstrations to predict
    # another's press with, so no band check; their CF z is still held against the other's.
    cases, demonstrations = task
    skill = learn_joint_skill(demonstrations[:2], sources=[case.name for case in cases[:2]])
    names = [c.name for c in skill.checks]
    assert CheckName.demonstration_in_band not in names and names.count(CheckName.demonstration_normal) == 2
    assert all(use.share_in_band is None and use.normal_angle_deg is not None for use in skill.demonstrations or [])


def test_a_trial_of_another_task_is_named_and_not_averaged_in(
    task: tuple[list[CorpusCase], list[Demonstration]], joint: Skill
) -> None:
    cases, demonstrations = task
    other = human_trials("human-cylinder", 0, 1)[0]  # a contour across a cylinder, 9 cm away
    sources = [case.name for case in cases[:3]] + [other.name]
    mixed = learn_joint_skill([*demonstrations[:3], other.demonstration(read_csv)], sources=sources)
    uses = mixed.demonstrations
    assert uses is not None and uses[3].misfit in (MisfitReason.another_place, MisfitReason.another_surface)
    assert uses[3].weight == 0.0 and uses[3].reason
    assert [s.model_dump() for s in mixed.segments] == [s.model_dump() for s in joint.segments]

    with pytest.raises(JointLearningError) as refused:
        learn_joint_skill(
            [*demonstrations[:3], other.demonstration(read_csv)],
            LearnOptions(misfit=MisfitPolicy.refuse),
            sources=sources,
        )
    assert refused.value.field == "demonstrations" and other.name in refused.value.reason


def test_a_demonstration_without_contact_is_named_not_learnable(
    task: tuple[list[CorpusCase], list[Demonstration]], joint: Skill
) -> None:
    cases, demonstrations = task
    a = demonstrations[0].arrays()
    in_the_air = Demonstration.from_arrays(a.t, a.positions, a.orientations, np.zeros_like(a.wrenches))
    sources = [*(case.name for case in cases[:3]), "in-the-air"]
    skill = learn_joint_skill([*demonstrations[:3], in_the_air], sources=sources)
    use = (skill.demonstrations or [])[3]
    assert use.misfit is MisfitReason.not_learnable and use.weight == 0.0 and "wrenches" in (use.reason or "")
    assert [s.model_dump() for s in skill.segments] == [s.model_dump() for s in joint.segments]


def test_one_demonstration_left_with_the_others_left_out_is_not_judged_against_nothing(
    task: tuple[list[CorpusCase], list[Demonstration]],
) -> None:
    # Two given, one not learnable: the joint skill is the other's alone, with no others to judge it against.
    cases, demonstrations = task
    a = demonstrations[0].arrays()
    in_the_air = Demonstration.from_arrays(a.t, a.positions, a.orientations, np.zeros_like(a.wrenches))
    skill = learn_joint_skill([demonstrations[1], in_the_air], sources=[cases[1].name, "in-the-air"])
    uses = skill.demonstrations or []
    assert uses[0].weight == 1.0 and uses[1].misfit is MisfitReason.not_learnable
    assert uses[0].share_in_band is None and uses[0].normal_angle_deg is None
    names = {check.name for check in skill.checks}
    assert CheckName.demonstration_in_band not in names and CheckName.demonstration_normal not in names
