"""Calling compiled (numba) code from a 1 kHz loop without the dispatcher.

A numba dispatcher call types every argument and looks up the overload for those types on every call: ~0.3 µs for a
dozen arrays, as much as the arithmetic it calls. A loop whose arguments keep their types calls the specialization
itself (:func:`compiled_entry`). It is looked up once per phase, not once per execution: ``numba.typeof`` on a dozen
arrays costs ~0.2 ms, so each specialization is kept by a key that is cheaper to build.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numba.core.dispatcher import Dispatcher

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
