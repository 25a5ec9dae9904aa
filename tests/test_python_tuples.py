"""PyBullet's result tuples read in place by compiled code (``sim_worker.python_tuples``): the contact summary of any
number of points is the same, to the bit, as the same sum in Python over the tuples; a tuple that does not have the
layout read raises (CPython's ``SystemError`` naming the cause), never a silent value."""

from __future__ import annotations

import numpy as np
import pybullet
import pytest

from sim_worker.arm_model import N_JOINTS, read_arm
from sim_worker.contact_sensing import CONTACT_DISTANCE_M, _contact_summary
from sim_worker.world import SimWorld
from sim_worker.world_config import WorldConfig
from skills.control import ROBOT_POSITION, ROBOT_STATE_SIZE


def _point(rng: np.random.Generator) -> tuple:
    """A contact point laid out as ``getContactPoints`` returns it (ints, floats and 3-vectors as tuples)."""
    v = lambda: tuple(rng.normal(size=3).tolist())  # noqa: E731
    return (0, 1, 2, -1, 3, v(), v(), v(), float(rng.normal()) * 1e-3, abs(float(rng.normal())) * 5,
            float(rng.normal()), v(), float(rng.normal()), v())  # fmt: skip


def _summary_in_python(points: tuple, tool_point: np.ndarray) -> tuple[list[float], bool]:
    """The contact summary summed in Python over the tuples, in the compiled sum's order: the applied wrench (6), the
    normal force and its unit normal (4); whether the tool touches."""
    px, py, pz = tool_point.tolist()
    f, m, normal = [0.0] * 3, [0.0] * 3, [0.0] * 3
    touching = False
    for c in points:
        fn, f1, f2, n, d1, d2, r = c[9], c[10], c[12], c[7], c[11], c[13], c[5]
        touching = touching or c[8] <= CONTACT_DISTANCE_M or fn > 0.0
        a = [-(fn * n[i] + f1 * d1[i] + f2 * d2[i]) for i in range(3)]
        rx, ry, rz = r[0] - px, r[1] - py, r[2] - pz
        f = [f[i] + a[i] for i in range(3)]
        m = [m[0] + (ry * a[2] - rz * a[1]), m[1] + (rz * a[0] - rx * a[2]), m[2] + (rx * a[1] - ry * a[0])]
        normal = [normal[i] - fn * n[i] for i in range(3)]
    norm = float(np.sqrt(sum(x * x for x in normal)))
    unit = [x / norm for x in normal] if norm > 0.0 else [0.0] * 3
    return [*f, *m, norm if norm > 0.0 else 0.0, *unit], touching


@pytest.mark.parametrize("count", [0, 1, 3, 17])
def test_the_contact_summary_of_any_number_of_points_is_the_python_sum_to_the_bit(count: int) -> None:
    rng = np.random.default_rng(count)
    arm = rng.normal(size=64)
    points = tuple(_point(rng) for _ in range(count))
    summary = np.full(10, np.nan)
    touching = _contact_summary(id(points), arm, summary)
    expected, expected_touching = _summary_in_python(points, arm[ROBOT_POSITION])
    assert touching == expected_touching == (count > 0)
    assert summary.tolist() == expected  # to the bit
    if count:
        assert summary[6] > 0.0 and np.isclose(np.linalg.norm(summary[7:10]), 1.0)


@pytest.mark.parametrize(
    ("damage", "cause"),
    [
        (lambda p: p[:9], "bad argument"),  # a point cut short: its normal force missing
        (lambda p: (*p[:9], "5.0", *p[10:]), "must be real number, not str"),  # a string for the normal force
        (lambda p: (*p[:7], (0.0, 1.0), *p[8:]), "bad argument"),  # a 2-vector for the normal
    ],
    ids=["short point", "string", "short vector"],
)
def test_a_contact_point_of_another_layout_raises_and_names_the_cause(damage, cause: str) -> None:
    rng = np.random.default_rng(1)
    points = (_point(rng), damage(_point(rng)))
    with pytest.raises(SystemError, match="returned a result with an exception set") as raised:
        _contact_summary(id(points), np.zeros(64), np.zeros(10))
    assert cause in str(raised.value.__cause__)


def test_the_arm_read_in_place_is_the_arm_pybullet_reports() -> None:
    """The joint states read in place (positions, velocities; with the tool joint, its reaction) are PyBullet's
    floats, whatever else the tuples hold; a list instead of the tuple raises."""
    with SimWorld(WorldConfig()) as world:
        handles = world.loop_handles()
        q = np.linspace(-0.5, 0.5, N_JOINTS)
        world.set_joint_positions(q, 0.1 * q)
        states = pybullet.getJointStates(handles.body, [*range(N_JOINTS), N_JOINTS], handles.client)
        buffer = handles.arm.copy()
        read_arm(handles.model, id(states), buffer)
        assert buffer[:N_JOINTS].tolist() == [s[0] for s in states[:N_JOINTS]] == q.tolist()
        assert buffer[N_JOINTS : 2 * N_JOINTS].tolist() == [s[1] for s in states[:N_JOINTS]]
        np.testing.assert_array_equal(buffer[:ROBOT_STATE_SIZE], world.robot_state())  # the model on them
        listed = list(states)  # held while read: the address of a temporary would dangle
        with pytest.raises(SystemError):
            read_arm(handles.model, id(listed), buffer)
