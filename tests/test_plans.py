"""Phase-plan time warping: the same path, slowed where it must be (execution/plans.py)."""

import numpy as np
import pytest

from execution.plans import CREASE_HOLD_DISTANCE_M, crease_speed_caps, slowed_times

DT = 1e-3


def test_a_path_capped_at_half_its_speed_takes_twice_as_long_and_never_exceeds_the_cap() -> None:
    speed = np.full(1001, 0.1)  # 1 s at 10 cm/s
    times = slowed_times(speed, np.full(1001, 0.05), DT)
    assert times[0] == 0.0 and times[-1] == pytest.approx(1.0, abs=DT)
    assert times.size == pytest.approx(2001, abs=2)
    arc = 0.1 * times  # the path position of each new step
    assert np.diff(arc).max() / DT <= 0.05 + 1e-9
    assert np.all(np.diff(times) > 0)


def test_an_uncapped_path_is_sampled_unchanged() -> None:
    speed = np.linspace(0.0, 0.2, 500)
    np.testing.assert_allclose(slowed_times(speed, np.full(500, np.inf), DT), np.arange(500) * DT)


def test_the_crease_cap_holds_the_crease_speed_near_the_end_and_lets_go_farther_away() -> None:
    arc = np.linspace(0.0, 0.1, 1001)  # 10 cm of path
    cap = crease_speed_caps(arc, 0.015, towards_end=True)
    near = arc[-1] - arc <= CREASE_HOLD_DISTANCE_M
    np.testing.assert_allclose(cap[near], 0.015)
    assert np.all(np.diff(cap) <= 0) and cap[0] > 0.1
    np.testing.assert_allclose(crease_speed_caps(arc, 0.015, towards_end=False), cap[::-1])
