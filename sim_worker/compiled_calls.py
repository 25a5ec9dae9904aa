"""Calling compiled (numba) code from a 1 kHz loop without the dispatcher.

A numba dispatcher call types every argument and looks up the overload for those types on every call: ~0.3 µs for a
dozen arrays, ~0.6 µs for PyBullet's nested tuples, as much as the arithmetic it calls. A loop whose arguments keep
their types calls the specialization itself (:func:`compiled_entry`); the contact points' tuple changes type with
their number, so the arm state and contact summary keep one specialization per number (:class:`SensingEntries`).
Both are looked up once per phase, not once per execution: ``numba.typeof`` on PyBullet's nested tuples costs ~0.4 ms,
on a dozen arrays ~0.2 ms, so each is kept by a key that is cheaper to build (~0.2 µs per step of a 12 s execution).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import numba
import numpy as np
from numba.core.dispatcher import Dispatcher

from sim_worker.contact_sensing import COMPILED_CONTACT_COUNTS, point_rows, sample, sense
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


class SensingEntries:
    """The arm state, contact summary and (a sampling sensor) reading of one world's loop (``handles``): its compiled
    ``sense`` (ideal sensor) or ``sample`` (after ``draw()``) for each number of contact points a step has met,
    :attr:`by_count`. Per step a loop calls ``by_count[len(points)]`` when it is set (at most
    :data:`COMPILED_CONTACT_COUNTS` points), else :meth:`first`."""

    _shared: ClassVar[dict[tuple[bool, int], list[Callable[..., bool] | None]]] = {}
    """The specializations of every loop so far, by sensor (ideal or not) and number of queried joints: PyBullet's
    tuples for those have the same numba types in every world (a joint's state, a contact point: fixed fields)."""

    def __init__(self, handles: LoopHandles) -> None:
        self._handles = handles
        empty: list[Callable[..., bool] | None] = [None] * (COMPILED_CONTACT_COUNTS + 1)
        self.by_count = self._shared.setdefault((handles.ideal, len(handles.queried)), empty)
        """``sense(model, states, points, arm, contact)`` or ``sample(..., sensor)``, specialized for this world's
        state tuples and this many points (None: no step met that many yet); shared by the loops of such worlds."""

    def first(self, states: tuple, points: tuple) -> bool:
        """A step's reading from PyBullet's tuples ``states`` and ``points`` when no specialization for this many
        points is kept: it is compiled (or loaded) and kept; more points than compiled for go as rows
        (``point_rows``), whose tuple would compile inside the run. Returns whether the tool touches."""
        handles = self._handles
        read, extra = (sense, ()) if handles.ideal else (sample, (handles.sensor,))
        if len(points) > COMPILED_CONTACT_COUNTS:
            return read(handles.model, states, point_rows(points), handles.arm, handles.contact, *extra)
        arguments = (handles.model, states, points, handles.arm, handles.contact, *extra)
        entry = self.by_count[len(points)] = read.compile(tuple(numba.typeof(arg) for arg in arguments))
        return entry(*arguments)
