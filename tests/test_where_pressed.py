"""Verdicts that know where the tool pressed (``skills.pressed_normals``, ``execution.metrics.surfaces_pressed``).

Ground truth: the judge of ``experiments.verdict_truth``, which places the tool's POSITIONS on the exact shapes of the
world that ran (the verdict compares the simulator's contact normals with the skill's taught frames): which body each
contact segment pressed on, and how much of a contour's taught region (angles about the body's own axis) it covered.
Before, a removed ramp, a cylinder swapped for the block and a cylinder moved 5 cm under a following contour all
passed their verdict.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from execution.executor import follows_surface
from experiments.verdict_truth import PERTURBATIONS, Fault, Judgement, run_judged, taught
from schemas.execution import ExecutionPhase, ExecutionSettings
from schemas.skill import SegmentKind
from schemas.verdict import VerdictCheckName
from sim_worker.execution_world import execution_world
from sim_worker.executor import run_skill
from skills import pressed_normals
from skills.frames import matrix_from_axis_angle

# --------------------------------------------------------------------------------------------------- pure geometry


def _arc(low_deg: float, high_deg: float, n: int = 101) -> np.ndarray:
    """Unit normals (into the surface) of a cylinder about world y, from ``low_deg`` to ``high_deg`` about its axis."""
    a = np.radians(np.linspace(low_deg, high_deg, n))
    return np.column_stack([-np.sin(a), np.zeros(n), -np.cos(a)])


def test_a_contours_region_is_the_span_of_its_normals_about_their_axis_wherever_the_part_stands() -> None:
    taught = _arc(-50.0, 50.0)
    plane = pressed_normals.turn_plane(taught)
    assert plane is not None and abs(plane.axis[1]) == pytest.approx(1.0)
    low, high = pressed_normals.span_deg(plane, taught, trim_pct=0.0)  # taught: whole
    assert high - low == pytest.approx(100.0)
    covered = pressed_normals.region_coverage
    assert covered((low, high), pressed_normals.span_deg(plane, _arc(-50, 50))) == pytest.approx(0.96)  # pressed:
    # 2nd to 98th percentile
    shifted = pressed_normals.span_deg(plane, _arc(-70.0, 30.0))  # the cylinder moved: 20° of the region lost
    assert covered((low, high), shifted) == pytest.approx(0.78)  # (the pressed span trimmed: 28 + 50 of 100)
    assert pressed_normals.turn_plane(_arc(-4.0, 4.0)) is None  # no turn: no region along it


def test_a_crease_turns_as_taught_on_a_tilted_part_more_on_a_steeper_one_and_not_at_all_without_it() -> None:
    table = np.array([0.0, 0.0, -1.0])
    ramp = matrix_from_axis_angle((0.0, 1.0, 0.0), math.radians(20.0)) @ table
    tilt = matrix_from_axis_angle((1.0, 0.0, 0.0), math.radians(12.0))
    steeper = matrix_from_axis_angle((0.0, 1.0, 0.0), math.radians(30.0)) @ table
    turn = pressed_normals.crease_turn_deg
    assert turn(table, ramp, table, ramp) == pytest.approx(20.0)
    assert turn(tilt @ table, tilt @ ramp, table, ramp) == pytest.approx(20.0, abs=1.0)
    assert turn(table, steeper, table, ramp) == pytest.approx(30.0)
    assert turn(table, table, table, ramp) == pytest.approx(0.0, abs=1e-9)


# --------------------------------------------------------------------------------------------------- PyBullet runs


@pytest.fixture(scope="module")
def teachings():
    return {s: taught(s) for s in ("slide_flat", "slide_two_planes", "contour_cylinder")}


def _judged(name: str, scenario: str, follow: bool, teachings) -> Judgement:
    case = next(p for p in PERTURBATIONS if p.name == name and p.scenario == scenario and not p.held_out)
    return run_judged(case, follow, teachings)


def _failed(j: Judgement) -> set[VerdictCheckName]:
    return j.failed_checks


@pytest.mark.parametrize("follow", [False, True])
def test_a_missing_ramp_fails_its_verdict_naming_the_crease_it_never_met(teachings, follow: bool) -> None:
    j = _judged("ramp missing", "slide_two_planes", follow, teachings)
    assert Fault.wrong_body in j.faults  # the judge: segment 2's ramp is not there
    assert not j.verdict_passed and VerdictCheckName.surface_pressed in _failed(j), j.metrics.verdict.reasons
    ramp = next(s for s in j.metrics.surfaces_pressed if s.crease_deg is not None)
    assert ramp.crease_deg == pytest.approx(20.0, abs=2.0) and abs(ramp.crease_turn_deg) < 3.0
    if follow:  # the extension past the taught crease ran out and no surface turned the normal later either
        assert VerdictCheckName.next_surface in _failed(j)
        assert any(r.startswith("next surface not found") for r in j.metrics.verdict.reasons)


def test_the_ramp_as_taught_turns_the_normal_by_its_crease_and_passes(teachings) -> None:
    j = _judged("as taught", "slide_two_planes", True, teachings)
    assert j.job_done and j.verdict_passed, j.metrics.verdict.reasons
    ramp = next(s for s in j.metrics.surfaces_pressed if s.crease_deg is not None)
    assert ramp.crease_turn_deg == pytest.approx(ramp.crease_deg, abs=3.0) and ramp.next_surface_found


@pytest.mark.parametrize(
    ("name", "fault"), [("swapped for the block", Fault.wrong_body), ("5 cm across", Fault.region)]
)
def test_a_following_contour_on_another_part_or_another_place_fails_on_the_region_it_covered(teachings, name, fault):
    j = _judged(name, "contour_cylinder", True, teachings)
    assert fault in j.faults, j.faults  # the judge, from positions on the true cylinder
    assert not j.verdict_passed and VerdictCheckName.region_covered in _failed(j), j.metrics.verdict.reasons
    contour = j.metrics.surfaces_pressed[0]
    assert contour.region_coverage < 0.85


def test_a_contour_as_taught_covers_its_region_and_a_confirmed_relocation_finds_the_part(teachings) -> None:
    as_taught = _judged("as taught", "contour_cylinder", True, teachings)
    assert as_taught.job_done and as_taught.verdict_passed, as_taught.metrics.verdict.reasons
    assert as_taught.metrics.surfaces_pressed[0].region_coverage >= 0.9
    assert as_taught.metrics.contour_relocations_m == []
    lower = _judged("8 cm lower", "contour_cylinder", True, teachings)  # met near its crown: relocated, confirmed
    assert lower.job_done and lower.verdict_passed, (lower.faults, lower.metrics.verdict.reasons)
    (move,) = lower.metrics.contour_relocations_m
    assert move[2] == pytest.approx(-0.08, abs=0.01)
    assert lower.metrics.surfaces_pressed[0].region_coverage >= 0.9


def test_the_touch_down_is_reported_against_the_press_that_followed_and_the_force_asked_at_contact(teachings):
    m = _judged("as taught", "contour_cylinder", False, teachings).metrics
    # The contour's profile asks 0.7 N at contact and presses 10 N 0.1 s later: the impact is judged against the press.
    assert m.touchdown_peak_ratio <= 1.5 and m.touchdown_contact_force_ratio > 5.0
    check = next(c for c in m.verdict.checks if c.name is VerdictCheckName.touchdown)
    assert check.passed and "the press that followed" in check.message and "force asked at contact" in check.message


def test_a_way_out_into_the_part_is_an_exit_collision_not_a_touch_down(teachings) -> None:
    skill = teachings["slide_flat"].skill
    last = skill.segments[-1]
    assert last.kind is SegmentKind.free
    # Its way out dives 5 cm (3 cm into the table, after the 2 cm lift-off), slowly: the guard stops it at the touch.
    down = np.asarray(last.position_dmp.start) - np.array([0.0, 0.0, 0.05])
    slow = 5.0 * last.position_dmp.duration_s
    dmp = last.position_dmp.model_copy(update={"goal": down.tolist(), "duration_s": slow})
    diving = skill.model_copy(
        update={"segments": [*skill.segments[:-1], last.model_copy(update={"position_dmp": dmp})]}
    )
    settings = ExecutionSettings()
    result = run_skill(execution_world(diving, settings.environment, scenario="slide_flat"), settings)
    m = result.metrics
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.exit_collision_n is not None and m.exit_collision_n > 1.0
    assert m.peak_force_n < 40.0  # stopped by the guard, not pressed into the table
    failed = {c.name for c in m.verdict.checks if not c.passed and not c.warning_only}
    assert failed == {VerdictCheckName.exit_collision}, m.verdict.reasons
    assert m.touchdown_peak_ratio <= 1.5


def test_a_verdict_on_a_work_piece_rebuilt_from_the_skill_says_it_confirms_the_skill_with_itself(teachings):
    skill = teachings["slide_flat"].skill
    settings = ExecutionSettings(environment={"work_piece": "rebuilt"})
    m = run_skill(execution_world(skill, settings.environment), settings).metrics
    judged_on = next(c for c in m.verdict.checks if c.name is VerdictCheckName.judged_on)
    assert judged_on.warning_only and "rebuilt" in judged_on.message and judged_on.message in m.verdict.warnings


def test_slides_follow_the_surface_by_default_contours_keep_their_frames(teachings) -> None:
    slide, contour = teachings["slide_flat"].skill, teachings["contour_cylinder"].skill
    assert follows_surface(slide, ExecutionSettings()) and not follows_surface(contour, ExecutionSettings())
    assert not follows_surface(slide, ExecutionSettings(follow_surface_normal=False))
    assert follows_surface(contour, ExecutionSettings(follow_surface_normal=True))
    assert not follows_surface(slide, ExecutionSettings(controller="impedance"))
