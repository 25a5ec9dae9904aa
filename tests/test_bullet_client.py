"""PyBullet's C API called from compiled code (``sim_worker.bullet_client``) reads and does exactly what its Python
functions do: the same joint states and contact points to the bit, the same physics step, and a clear error (not a
crash) once the client is gone. Real PyBullet worlds throughout."""

from __future__ import annotations

import logging

import numpy as np
import pybullet
import pytest

from schemas.world import WorldConfig
from sim_worker import bullet_client
from sim_worker.bullet_client import (
    CONTACT_ROW,
    JOINT_ROW,
    VERIFIED_PYBULLET_VERSIONS,
    BulletClient,
    client_slot,
    compiled_path_refusal,
    contact_bodies,
    contact_rows_from_points,
    installed_pybullet_version,
    located_client_table,
    read_contact_rows,
    read_joint_rows,
    send_torques_and_step,
)
from sim_worker.robot_model import N_JOINTS, TOOL_LINK
from sim_worker.sensor import WRIST_SENSOR
from sim_worker.world import SimWorld


def pressed_on_the_table(world: SimWorld) -> None:
    """Step ``world`` with the tool pushed down (torques along the Jacobian's transpose) until it touches."""
    for _ in range(4000):
        if world.in_contact():
            return
        jacobian = world.jacobian()
        world.step(jacobian[:3].T @ [0.0, 0.0, -40.0] + world.gravity_coriolis_torques())
    raise AssertionError("the tool never touched the table")


@pytest.mark.parametrize("config", [WorldConfig(), WorldConfig(sensor=WRIST_SENSOR)], ids=["ideal", "wrist"])
def test_joint_and_contact_rows_are_pybullets_own_numbers(config: WorldConfig) -> None:
    with SimWorld(config) as world:
        pressed_on_the_table(world)
        bullet = world.loop_handles().bullet
        assert bullet.compiled  # PyBullet's Linux wheels keep the client table's symbol
        assert bullet.queried == list(range(N_JOINTS)) + ([TOOL_LINK] if config.sensor is WRIST_SENSOR else [])
        states = pybullet.getJointStates(bullet.body, bullet.queried, bullet.client_id)
        rows = np.zeros((len(bullet.queried), JOINT_ROW))
        read_joint_rows(bullet.ids, rows)
        np.testing.assert_array_equal(rows, [(s[0], s[1], *s[2], s[3]) for s in states])
        points = pybullet.getContactPoints(bullet.body, -1, TOOL_LINK, -2, bullet.client_id)
        assert len(points) >= 1
        contact = read_contact_rows(bullet.ids).copy()
        expected = contact_rows_from_points(points)
        assert contact.shape == (len(points), CONTACT_ROW)
        np.testing.assert_array_equal(contact, expected)  # the ints too, as they lie in the C struct
        assert list(contact_bodies(contact)) == [p[2] for p in points] == [world.bodies["table"]] * len(points)
        with pytest.raises(ValueError, match="joint rows"):  # never written beyond the array it is given
            read_joint_rows(bullet.ids, rows[:-1])
        with pytest.raises(ValueError, match="torques"):
            send_torques_and_step(bullet.ids, np.zeros(N_JOINTS - 1))
        # The Python fallback fills the same rows.
        slow = BulletClient(bullet.client_id, bullet.body, bullet.queried, bullet.link, compiled=False)
        assert not slow.compiled
        np.testing.assert_array_equal(slow.read_joints(), rows)
        np.testing.assert_array_equal(slow.read_contacts(), contact)


def test_a_step_through_the_c_api_is_pybullets_step() -> None:
    """The same torques, sent and stepped through the C API in one world and through PyBullet's Python functions in
    another: the same states, bit for bit, for 200 steps."""
    with SimWorld() as compiled, SimWorld() as python:
        fast = compiled.loop_handles().bullet
        torques = np.array([0.0, 30.0, 0.0, -20.0, 0.0, 10.0, 0.0]) + compiled.gravity_coriolis_torques()
        for _ in range(200):
            send_torques_and_step(fast.ids, torques)
            pybullet.setJointMotorControlArray(python.robot, list(range(N_JOINTS)), pybullet.TORQUE_CONTROL,
                                               forces=torques.tolist(), physicsClientId=python.client_id)  # fmt: skip
            pybullet.stepSimulation(python.client_id)
        a = pybullet.getJointStates(compiled.robot, list(range(N_JOINTS)), compiled.client_id)
        b = pybullet.getJointStates(python.robot, list(range(N_JOINTS)), python.client_id)
        assert a == b
        assert abs(a[1][0] - pybullet.getJointState(python.robot, 1, physicsClientId=python.client_id)[0]) == 0.0
        assert a[1][1] != 0.0  # it moved


def test_a_closed_client_is_an_error_not_a_crash() -> None:
    world = SimWorld()
    bullet = world.loop_handles().bullet
    rows = bullet.joint_rows.copy()
    world.close()
    for call in (lambda: read_joint_rows(bullet.ids, rows), lambda: read_contact_rows(bullet.ids),
                 lambda: send_torques_and_step(bullet.ids, np.zeros(N_JOINTS))):  # fmt: skip
        with pytest.raises(RuntimeError, match="physics client is not connected"):
            call()
    assert client_slot(bullet.client_id) == 0  # no handle there any more
    assert client_slot(1023) == 0  # never connected
    assert client_slot(1024) == client_slot(-1) == 0  # beyond PyBullet's table: not read


def test_the_installed_pybullet_is_a_release_whose_layouts_were_verified() -> None:
    """The compiled path reads PyBullet's C structs with the layouts of the releases checked: installing another one
    (pyproject.toml pins the same) must fail here, and the loop run through the Python API."""
    assert installed_pybullet_version() in VERIFIED_PYBULLET_VERSIONS
    assert compiled_path_refusal() is None
    assert located_client_table(installed_pybullet_version()) == bullet_client._client_table()


def test_an_unverified_release_runs_the_python_path_said_in_one_log_line(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A pybullet release nobody checked the struct layouts of: every world's loop calls PyBullet through Python (and
    reads the same numbers), and one warning, for the process, names the version and why."""
    refusal = located_client_table("3.2.6")
    assert refusal == "pybullet 3.2.6 is not a release whose C struct layouts were verified (3.2.7)"
    monkeypatch.setattr(bullet_client, "installed_pybullet_version", lambda: "3.2.6")
    bullet_client._client_table.cache_clear()
    try:
        with caplog.at_level(logging.WARNING, logger=bullet_client.__name__), SimWorld() as one, SimWorld() as two:
            clients = [one.loop_handles().bullet, two.loop_handles().bullet]
            assert [client.compiled for client in clients] == [False, False]
            assert compiled_path_refusal() is not None
            np.testing.assert_array_equal(clients[0].read_joints(), clients[1].read_joints())
    finally:
        bullet_client._client_table.cache_clear()  # the next test checks the installed release again
    warnings = [record.getMessage() for record in caplog.records if record.name == bullet_client.__name__]
    assert len(warnings) == 1
    assert "pybullet 3.2.6 is not a release whose C struct layouts were verified" in warnings[0]
