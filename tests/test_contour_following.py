"""Contours that hold when the part is not where, or not what, it was taught (``follow_surface_normal``).

Ground truth: the simulator's normal force at the contact (the metrics' TRUE RMS and largest steady error, % of the
reference force), the teacher's world (where the cylinder and the crease really are). The bounds are the acceptance
bounds of the contour work: moved and resized cylinders RMS ≤ 8 %, steady max ≤ 30 %, contact ≥ 99 %; a crease met
2 cm from where it was taught, steady max ≤ 15 %. Each case failed before: the cylinder 8 cm higher ran to `done` at
28.7 % RMS, 8 cm lower found nothing, the late crease peaked at 40 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from experiments.contour_stress import CASES, COLUMNS, CONTOUR, CREASE, StressCase, run_case, stress_skills
from schemas.execution import PHASE_CODES, ExecutionPhase
from schemas.verdict import Verdict

FOLLOWING, PAPER = COLUMNS[0], COLUMNS[1]
_CASES = {c.name: c for c in CASES}


@pytest.fixture(scope="module")
def skills():
    return stress_skills((CONTOUR, CREASE, "slide_flat"))


def _holds(case: StressCase, skills, rms_pct: float = 8.0, max_pct: float = 30.0) -> None:
    m = run_case(case, FOLLOWING, skills).metrics
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.true_force_rms_error_pct <= rms_pct, (case.name, m.true_force_rms_error_pct)
    assert m.true_force_max_error_pct <= max_pct, (case.name, m.true_force_max_error_pct)
    assert m.contact_ratio >= 0.99, (case.name, m.contact_ratio)


@pytest.mark.parametrize("name", ["8 cm higher", "5 cm across +", "radius 6 cm", "radius 12 cm"])
def test_a_contour_follows_a_cylinder_moved_or_resized_without_being_told(skills, name: str):
    _holds(_CASES[name], skills)


def test_the_paper_frames_fail_where_following_holds(skills):
    """The same cylinder 8 cm higher with the taught frames: the force pressed along normals the part no longer has."""
    m = run_case(_CASES["8 cm higher"], PAPER, skills).metrics
    assert m.true_force_rms_error_pct > 20.0 and m.verdict.verdict is Verdict.failed


def test_a_contour_met_elsewhere_on_its_path_is_relocated_by_the_parts_move(skills):
    """8 cm lower, the taught approach meets the cylinder near its crown, the middle of the taught path: the normal it
    presses on says where on the path it is, so the part's move across its axis is measured (along the axis every
    place looks the same: taken as not moved) and the whole contour runs there."""
    m = run_case(_CASES["8 cm lower"], FOLLOWING, skills).metrics
    assert len(m.contour_relocations_m) == 1
    assert any(w.startswith("contour relocated") for w in m.verdict.warnings)  # said, not only done
    # Within the friction cone's reach: the pressing direction says the normal within atan(0.2) = 11°, 1.8 cm of the
    # ball's 9 cm path radius.
    np.testing.assert_allclose(m.contour_relocations_m[0], [0.0, 0.0, -0.08], atol=0.02)
    _holds(_CASES["8 cm lower"], skills)


@pytest.mark.parametrize("name", ["crease 2 cm early", "crease 2 cm late"])
def test_a_crease_is_switched_where_it_is_met(skills, name: str):
    """The switch to the ramp segment follows the tracked normal: it happens where the ramp really is (the teacher's
    crease, moved 2 cm), not at the taught time, and the passage stays within 15 % of the press."""
    case = _CASES[name]
    run = run_case(case, FOLLOWING, skills)
    m = run.metrics
    assert m.phase is ExecutionPhase.done, m.abort_reason
    assert m.true_force_max_error_pct <= 15.0 and m.contact_ratio >= 0.99
    assert m.true_force_rms_error_pct <= 3.0
    tel = run.telemetry
    contact = tel.phase_codes == PHASE_CODES[ExecutionPhase.contact]
    ramp = int(tel.segment_index[contact].max())  # the last contact segment: on the ramp
    switch_x = float(tel.tool_position[np.argmax(contact & (tel.segment_index == ramp)), 0])
    crease_x = run.world.table.center_xy[0] + run.world.ramp.crease_x_m
    taught_x = crease_x - case.world({})["ramp"]["crease_x_m"]
    assert abs(switch_x - crease_x) < 0.01 < abs(switch_x - taught_x), (switch_x, crease_x, taught_x)


def test_following_the_surface_changes_no_slide_that_fits_its_teaching(skills):
    """On the flat table as taught, following the normal costs at most a tenth of a percent of true RMS."""
    flat = StressCase("flat", "the table as taught", "slide_flat")
    paper = run_case(flat, PAPER, skills).metrics
    following = run_case(flat, FOLLOWING, skills).metrics
    assert following.true_force_rms_error_pct <= 1.5
    assert abs(following.true_force_rms_error_pct - paper.true_force_rms_error_pct) <= 0.1


def test_a_stiff_pad_holds_without_chatter_after_an_approach_without_a_35_s_crawl(skills):
    """On 1e6 N/m the touch-down speed falls with sqrt(k) (the impact v sqrt(k m) stays under the press that follows,
    not the contour's first 0.9 N): the approaches take at most 3x the nominal pad's (they took 31 s against 7 s).
    The contact holds without chatter (it peaked at 64 % while Bullet collided the ball with a cylinder by GJK/EPA)."""
    nominal = run_case(_CASES["as taught"], FOLLOWING, skills)
    stiff = run_case(_CASES["pad 1e6 N/m"], FOLLOWING, skills)
    assert stiff.metrics.phase is ExecutionPhase.done
    assert stiff.approach_s <= 3.0 * nominal.approach_s
    assert stiff.metrics.true_force_rms_error_pct <= 8.0 and stiff.metrics.true_force_max_error_pct <= 25.0
