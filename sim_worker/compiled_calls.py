"""Calling compiled (numba) code from a 1 kHz loop without the dispatcher.

A numba dispatcher call types every argument and looks up the overload for those types on every call: ~0.3 µs for a
dozen arrays, ~0.6 µs for PyBullet's nested tuples, as much as the arithmetic it calls. A loop whose arguments keep
their types calls the specialization itself (:func:`compiled_entry`); the contact points' tuple changes type with
their number, so the arm state and contact summary keep one specialization per number (:class:`SensingEntries`).
"""

from __future__ import annotations

from collections.abc import Callable

import numba
from numba.core.dispatcher import Dispatcher

from sim_worker.contact_sensing import COMPILED_CONTACT_COUNTS, point_rows, sample, sense
from sim_worker.world import LoopHandles


def compiled_entry(dispatcher: Dispatcher, args: tuple) -> Callable[..., object]:
    """The compiled specialization of the numba ``dispatcher`` for the types of ``args`` (compiled, or loaded from
    numba's cache, when needed), called without the dispatcher. Only for a caller that passes arguments of exactly
    these types on every call: the specialization reads each as its compiled type."""
    return dispatcher.compile(tuple(numba.typeof(arg) for arg in args))


class SensingEntries:
    """The arm state, contact summary and (a sampling sensor) reading of one world's loop (``handles``): its compiled
    ``sense`` (ideal sensor) or ``sample`` (after ``draw()``) for each number of contact points a step has met,
    :attr:`by_count`. Per step a loop calls ``by_count[len(points)]`` when it is set (at most
    :data:`COMPILED_CONTACT_COUNTS` points), else :meth:`first`."""

    def __init__(self, handles: LoopHandles) -> None:
        self._handles = handles
        self.by_count: list[Callable[..., bool] | None] = [None] * (COMPILED_CONTACT_COUNTS + 1)
        """``sense(model, states, points, arm, contact)`` or ``sample(..., sensor)``, specialized for this world's
        state tuples and this many points (None: no step met that many yet)."""

    def first(self, states: tuple, points: tuple) -> bool:
        """A step's reading from PyBullet's tuples ``states`` and ``points`` when no specialization for this many
        points is kept: it is compiled (or loaded) and kept; more points than compiled for go as rows
        (``point_rows``), whose tuple would compile inside the run. Returns whether the tool touches."""
        handles = self._handles
        read, extra = (sense, ()) if handles.ideal else (sample, (handles.sensor,))
        if len(points) > COMPILED_CONTACT_COUNTS:
            return read(handles.model, states, point_rows(points), handles.arm, handles.contact, *extra)
        arguments = (handles.model, states, points, handles.arm, handles.contact, *extra)
        entry = self.by_count[len(points)] = compiled_entry(read, arguments)
        return entry(*arguments)
