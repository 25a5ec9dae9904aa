"""Calling compiled (numba) code from a 1 kHz loop without the dispatcher.

A numba dispatcher call types every argument and looks up the overload for those types on every call: ~0.3 µs for a
dozen arrays, as much as the arithmetic it calls. A loop whose arguments keep their types calls the specialization
itself (:func:`compiled_entry`; PyBullet is called from compiled code, ``sim_worker.bullet_client``). It is looked
up once per phase, not once per execution: ``numba.typeof`` on a dozen arrays costs ~0.2 ms, so each specialization is
kept by a key that is cheaper to build.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numba.core.dispatcher import Dispatcher

from sim_worker.bullet_client import send_torques_and_step
from sim_worker.contact_sensing import sample, sample_client, sense, sense_client
from sim_worker.world import LoopHandles

_ENTRIES: dict[tuple, Callable[..., object]] = {}
"""Specializations handed out, by dispatcher and :func:`_type_key` of each argument (as many as type combinations)."""
_SCALARS = (bool, int, float)


def _type_key(arg: object) -> object:
    """A key equal for two arguments numba types alike, cheaper than ``numba.typeof`` for what a loop passes: an
    ndarray by the fields its numba type has (dtype, dimensions, layout, writability, alignment), a bool, int or float
    by its Python type (numba types them as boolean, int64, float64; an int beyond 64 bits is not a loop's), anything
    else by its numba type."""
    if type(arg) is np.ndarray:
        flags = arg.flags
        return arg.dtype, arg.ndim, flags.c_contiguous, flags.f_contiguous, flags.writeable, flags.aligned
    if type(arg) in _SCALARS:
        return type(arg)
    return numba.typeof(arg)


def compiled_entry(dispatcher: Dispatcher, args: tuple) -> Callable[..., object]:
    """The compiled specialization of the numba ``dispatcher`` for the types of ``args`` (compiled, or loaded from
    numba's cache, when needed), called without the dispatcher. Only for a caller that passes arguments of exactly
    these types on every call: the specialization reads each as its compiled type. Kept by the arguments' type keys:
    the next phase's lookup costs microseconds, not the typing."""
    key = (dispatcher, *(_type_key(arg) for arg in args))
    entry = _ENTRIES.get(key)
    if entry is None:
        entry = _ENTRIES[key] = dispatcher.compile(tuple(numba.typeof(arg) for arg in args))
    return entry


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
