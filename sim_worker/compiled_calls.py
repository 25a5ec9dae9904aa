"""The PyBullet calls of a 1 kHz loop from compiled code (``sim_worker.bullet_client``), each as its compiled
specialization (``skills.compiled.compiled_entry``: no dispatcher per call), or through PyBullet's Python API where
its client cannot be reached from compiled code.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sim_worker.bullet_client import send_torques_and_step
from sim_worker.contact_sensing import sample, sample_client, sense, sense_client
from sim_worker.world import LoopHandles
from skills.compiled import compiled_entry


def state_reader(handles: LoopHandles) -> Callable[..., bool]:
    """The call that brings a loop's arm state, contact summary and (a sampling sensor) reading up to date from the
    state PyBullet's client holds: ``read(ids, model, joint_rows, arm, contact)`` for the ideal sensor, else
    ``read(..., sensor)`` (after ``draw()``), ``ids`` and ``joint_rows`` the :class:`BulletClient`'s; returns whether
    the tool touches. The compiled ``sense_client`` / ``sample_client`` (PyBullet's C API), or where PyBullet's client
    cannot be reached from compiled code the same through its Python API."""
    bullet = handles.bullet
    if bullet.compiled:
        sensor = () if handles.ideal else (handles.sensor,)
        arguments = (bullet.ids, handles.model, bullet.joint_rows, handles.arm, handles.contact, *sensor)
        return compiled_entry(sense_client if handles.ideal else sample_client, arguments)

    def read(_ids: np.ndarray, model: np.ndarray, _rows: np.ndarray, *buffers: np.ndarray) -> bool:
        return (sense if handles.ideal else sample)(model, bullet.read_joints(), bullet.read_contacts(), *buffers)

    return read


def stepper(handles: LoopHandles) -> Callable[[np.ndarray, np.ndarray], None]:
    """The call that sends a loop's torques and steps the physics, ``advance(ids, torques)`` (``ids`` the
    :class:`BulletClient`'s, ``torques`` (7,) N·m): the compiled ``send_torques_and_step``, or its Python API
    equivalent (:func:`state_reader`)."""
    bullet = handles.bullet
    if bullet.compiled:  # the torques' type: a C-contiguous float64 vector, as the torque limits and the law's output
        return compiled_entry(send_torques_and_step, (bullet.ids, handles.torque_limits))

    def advance(_ids: np.ndarray, torques: np.ndarray) -> None:
        bullet.send_torques_and_step(torques)

    return advance
