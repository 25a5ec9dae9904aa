"""Reading PyBullet's result tuples from compiled code through CPython's C API, by the tuple's address.

A compiled (numba) function that takes a Python tuple as an argument unboxes all of it into a native tuple on every
call, and compiles once per tuple type: ``getJointStates`` of 7 joints is 70 floats of which a control step needs
14 (~0.4 µs per step), and ``getContactPoints`` changes type with the number of points (one compilation, ~12 MB of a
worker's memory, per number). Passed as its address instead (``id(t)``: CPython's object address), the tuple is read
in place, only the floats the step needs, for any length, by one compiled function.

Contract: the caller holds a reference to the tuple for the whole call (a local variable does; the address of a
temporary, ``f(id(g()))``, dangles as soon as ``id`` returns), and the call runs with the GIL held (numba's default). A
read that does not match the tuple's layout cannot crash or return garbage silently: an index out of range or a value of
another type makes CPython's ``PyTuple_GetItem`` / ``PyFloat_AsDouble`` set an exception (their results, 0 and -1.0,
pass through the reads below), and CPython raises it as a ``SystemError`` ("returned a result with an exception set")
when the compiled function returns to Python.
"""

from __future__ import annotations

import numba
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic


def _python_object(context, builder, address):  # pragma: no cover - compiled
    """The ``PyObject *`` at ``address`` (an intp) in LLVM IR."""
    return builder.inttoptr(address, context.get_python_api(builder).pyobj)


@intrinsic
def _tuple_item(typingctx, address, index):  # pragma: no cover - compiled
    """``PyTuple_GetItem(address, index)``: the item's address (a borrowed reference), 0 with an exception set for
    an index out of range or a non-tuple."""

    def codegen(context, builder, signature, args):
        pyapi = context.get_python_api(builder)
        function = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(pyapi.pyobj, [pyapi.pyobj, pyapi.py_ssize_t]), "PyTuple_GetItem"
        )
        item = builder.call(function, [_python_object(context, builder, args[0]), args[1]])
        return builder.ptrtoint(item, context.get_value_type(types.intp))

    return types.intp(types.intp, types.intp), codegen


@intrinsic
def _tuple_size(typingctx, address):  # pragma: no cover - compiled
    """``PyTuple_Size(address)``: -1 with an exception set for a non-tuple."""

    def codegen(context, builder, signature, args):
        return context.get_python_api(builder).tuple_size(_python_object(context, builder, args[0]))

    return types.intp(types.intp), codegen


@intrinsic
def float_at(typingctx, address):  # pragma: no cover - compiled
    """The float at ``address`` (``PyFloat_AsDouble``: an int or any object with ``__float__`` converts; -1.0 with an
    exception set for another object or address 0)."""

    def codegen(context, builder, signature, args):
        return context.get_python_api(builder).float_as_double(_python_object(context, builder, args[0]))

    return types.float64(types.intp), codegen


@numba.njit(inline="always")
def tuple_item(address, index):  # pragma: no cover - compiled
    """The address of item ``index`` of the tuple at ``address``; 0 for address 0 (a failed read before: its
    exception stays set), so that nested reads never dereference nothing."""
    if address == 0:
        return 0
    return _tuple_item(address, index)


@numba.njit(inline="always")
def tuple_length(address):  # pragma: no cover - compiled
    """The length of the tuple at ``address``; 0 for address 0, -1 with an exception set for a non-tuple."""
    if address == 0:
        return 0
    return _tuple_size(address)


@numba.njit(inline="always")
def tuple_float(address, index):  # pragma: no cover - compiled
    """Item ``index`` of the tuple at ``address`` as a float."""
    return float_at(tuple_item(address, index))


@numba.njit(inline="always")
def tuple_vector3(address, index):  # pragma: no cover - compiled
    """Item ``index`` of the tuple at ``address``, itself a tuple of 3 floats (a PyBullet vector), as 3 floats."""
    vector = tuple_item(address, index)
    return tuple_float(vector, 0), tuple_float(vector, 1), tuple_float(vector, 2)
