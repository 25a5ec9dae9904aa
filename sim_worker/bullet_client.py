"""A control loop's PyBullet calls made from compiled code, through PyBullet's C API on the client its Python module
opened: the joint states, the contact points, the torque command and the physics step with no Python object per step.

PyBullet's Python functions are thin wrappers around its C API (``b3*``, exported by the same shared library): each one
looks its client up in a table (``sPhysicsClients1``, by ``physicsClientId``), makes the same ``b3*`` calls as below,
and builds Python tuples of the results (``getJointStates`` of 8 joints: 88 Python objects; ``stepSimulation``: a
tuple of dicts of solver statistics), which the loop then read back into arrays. Here the same ``b3*`` calls, in the
same order with the same arguments (pybullet 3.2.7's ``pybullet.c``), write straight into the loop's arrays: the
physics and every number read are the same, bit for bit (tests/test_bullet_client.py).

The table is a static array of PyBullet's module, not exported: its address is found in the library's ELF symbol table
(PyBullet's Linux wheels keep it) relative to the exported functions (every one used must give the same load address),
and the client found there is checked against the Python module's own answer (``b3GetNumBodies``). Where this cannot be
done (another platform, a stripped build) the same functions run through PyBullet's Python API (:class:`BulletClient`
``compiled`` False): slower, same results.

Only on the pybullet releases whose layouts below were checked against their ``pybullet.c`` and headers
(:data:`VERIFIED_PYBULLET_VERSIONS`): any other release runs the Python API, said once in one log line when the first
client is made (:func:`compiled_path_refusal`).

Layouts (pybullet 3.2.7, x86-64): ``b3JointSensorState`` 9 doubles (position, velocity, the reaction force and
moment (6), the motor torque), a :data:`JOINT_ROW` row; ``b3ContactPointData`` 176 bytes, five ints then 19 doubles,
read as a :data:`CONTACT_ROW` row of 22 doubles of which the first 3 hold the ints.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.metadata
import logging
import struct
from collections.abc import Sequence
from pathlib import Path

import llvmlite.binding as llvm
import numba
import numpy as np
import pybullet
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

VERIFIED_PYBULLET_VERSIONS = frozenset({"3.2.7"})
"""The pybullet releases whose C structs (:data:`JOINT_ROW`, :data:`CONTACT_ROW`), status codes and client table were
checked against their source: the compiled path runs only on these (pyproject.toml pins the same)."""

JOINT_ROW = 9
"""Doubles per joint in joint rows (``b3JointSensorState``): position rad, velocity rad/s, reaction force N and moment
N·m (6, the joint frame), applied motor torque N·m."""
CONTACT_ROW = 22
"""Doubles per contact point in contact rows (``b3ContactPointData``, 176 bytes): columns 0-2 hold its five ints
(flags, body A and B, link A and B); the fields below are in the world frame, m and N."""
CONTACT_ON_A, CONTACT_ON_B, CONTACT_NORMAL_ON_B = slice(3, 6), slice(6, 9), slice(9, 12)
CONTACT_DISTANCE, CONTACT_NORMAL_FORCE, CONTACT_FRICTION_1, CONTACT_FRICTION_2 = 12, 13, 14, 15
CONTACT_FRICTION_DIRECTION_1, CONTACT_FRICTION_DIRECTION_2 = slice(16, 19), slice(19, 22)

_STATE_COMPLETED, _STEP_COMPLETED, _CONTACTS_COMPLETED = 21, 26, 39  # EnumSharedMemoryServerStatus
_TORQUE_CONTROL = 1  # CONTROL_MODE_TORQUE

# The ids array of a BulletClient (int64): where PyBullet keeps the client's handle, the body, the tool link, the
# number of joints read, the joints read, the velocity indices of the 7 torque-controlled joints, and two slots the
# contact query writes its b3ContactInformation into (the number of points, the address of the first).
_SLOT, _BODY, _LINK, _COUNT, _JOINTS = 0, 1, 2, 3, 4
_TORQUE_JOINTS = 7

_FUNCTIONS = {
    "b3CanSubmitCommand": types.int32(types.intp),
    "b3GetNumBodies": types.int32(types.intp),
    "b3SubmitClientCommandAndWaitStatus": types.intp(types.intp, types.intp),
    "b3GetStatusType": types.int32(types.intp),
    "b3RequestActualStateCommandInit": types.intp(types.intp, types.int32),
    "b3GetJointState": types.int32(types.intp, types.intp, types.int32, types.intp),
    "b3InitRequestContactPointInformation": types.intp(types.intp),
    "b3SetContactFilterBodyA": types.void(types.intp, types.int32),
    "b3SetContactFilterLinkA": types.void(types.intp, types.int32),
    "b3GetContactPointInformation": types.void(types.intp, types.intp),
    "b3JointControlCommandInit2": types.intp(types.intp, types.int32, types.int32),
    "b3JointControlSetDesiredForceTorque": types.int32(types.intp, types.int32, types.float64),
    "b3InitStepSimulationCommand": types.intp(types.intp),
}
"""The C functions called, with their signatures (handles and pointers as intp)."""


@functools.cache
def _library() -> ctypes.CDLL | None:
    """PyBullet's shared library (the one its module was loaded from), its functions made known to the JIT linker by
    name (numba's cached code names them, so each process registers their addresses before any is loaded); None when
    one is missing."""
    try:
        library = ctypes.CDLL(pybullet.__file__)
        for name in _FUNCTIONS:
            llvm.add_symbol(name, ctypes.cast(getattr(library, name), ctypes.c_void_p).value)
    except (OSError, AttributeError):  # not a loadable file, or a build without one of them
        return None
    return library


_library()


def _external(name: str) -> types.ExternalFunction:
    """The C function ``name`` of :data:`_FUNCTIONS` as compiled code calls it (by name: linked when loaded)."""
    return types.ExternalFunction(name, _FUNCTIONS[name])


_can_submit = _external("b3CanSubmitCommand")
_submit = _external("b3SubmitClientCommandAndWaitStatus")
_status_type = _external("b3GetStatusType")
_request_state = _external("b3RequestActualStateCommandInit")
_joint_state = _external("b3GetJointState")
_request_contacts = _external("b3InitRequestContactPointInformation")
_filter_body = _external("b3SetContactFilterBodyA")
_filter_link = _external("b3SetContactFilterLinkA")
_contact_information = _external("b3GetContactPointInformation")
_control_command = _external("b3JointControlCommandInit2")
_set_torque = _external("b3JointControlSetDesiredForceTorque")
_step_command = _external("b3InitStepSimulationCommand")


_ELF_SECTION = np.dtype(
    [("name", "<u4"), ("type", "<u4"), ("flags", "<u8"), ("addr", "<u8"), ("offset", "<u8"), ("size", "<u8"),
     ("link", "<u4"), ("info", "<u4"), ("align", "<u8"), ("entsize", "<u8")]
)  # fmt: skip
"""An ELF64 section header (``Elf64_Shdr``)."""
_ELF_SYMBOL = np.dtype(
    [("name", "<u4"), ("info", "u1"), ("other", "u1"), ("shndx", "<u2"), ("value", "<u8"), ("size", "<u8")]
)
"""An ELF64 symbol (``Elf64_Sym``)."""


def _elf_symbols(path: str, names: Sequence[str]) -> dict[str, tuple[int, int]]:
    """The value (the address relative to the library's load address) and size (bytes) of each symbol of ``names``
    found in the ELF symbol table (``.symtab``) of the shared library at ``path``; none when it is not an ELF64 file or
    has no symbol table."""
    with open(path, "rb") as file:
        header = file.read(64)
        if header[:5] != b"\x7fELF\x02":
            return {}
        (section_offset,) = struct.unpack_from("<Q", header, 0x28)
        entry_size, entries = struct.unpack_from("<HH", header, 0x3A)
        file.seek(section_offset)
        sections = np.frombuffer(file.read(entry_size * entries), dtype=_ELF_SECTION)
        tables = sections[sections["type"] == 2]  # SHT_SYMTAB
        if len(tables) == 0:
            return {}
        table, strings = tables[0], sections[int(tables[0]["link"])]
        file.seek(int(table["offset"]))
        symbols = np.frombuffer(file.read(int(table["size"])), dtype=_ELF_SYMBOL)
        file.seek(int(strings["offset"]))
        text = file.read(int(strings["size"]))
    found = {}
    for name in names:
        key = b"\0" + name.encode() + b"\0"
        at = text.find(key)
        while at >= 0 and name not in found:
            hits = symbols[symbols["name"] == at + 1]
            if len(hits):
                found[name] = (int(hits[0]["value"]), int(hits[0]["size"]))
            at = text.find(key, at + 1)
    return found


_TABLE = "sPhysicsClients1"


def installed_pybullet_version() -> str:
    """The version of the pybullet distribution installed (as its metadata says, e.g. ``"3.2.7"``)."""
    return importlib.metadata.version("pybullet")


def located_client_table(version: str) -> tuple[int, int] | str:
    """The address of PyBullet's table of client handles (``sPhysicsClients1``, one pointer per client id) in this
    process and its number of entries, for pybullet ``version``; else why the compiled path cannot use it. The
    library's load address is taken from every C function used (its address in the process less its value in the
    file): they must all agree, or the file on disk is not the library loaded."""
    if version not in VERIFIED_PYBULLET_VERSIONS:
        verified = ", ".join(sorted(VERIFIED_PYBULLET_VERSIONS))
        return f"pybullet {version} is not a release whose C struct layouts were verified ({verified})"
    library = _library()
    path = pybullet.__file__
    if library is None or not Path(path).is_file():
        return f"PyBullet's shared library {path} cannot be loaded with all of its C functions"
    symbols = _elf_symbols(path, [_TABLE, *_FUNCTIONS])
    if len(symbols) != len(_FUNCTIONS) + 1:
        return f"PyBullet's shared library {path} has no symbol table naming {_TABLE} (a stripped build)"
    bases = {ctypes.cast(getattr(library, name), ctypes.c_void_p).value - symbols[name][0] for name in _FUNCTIONS}
    if len(bases) != 1:
        return f"PyBullet's shared library {path} on disk is not the one loaded"
    value, size = symbols[_TABLE]
    return bases.pop() + value, size // 8


@functools.cache
def _client_table() -> tuple[int, int] | str:
    """:func:`located_client_table` for the pybullet installed, checked once per process; a refusal is logged once
    (a warning)."""
    located = located_client_table(installed_pybullet_version())
    if isinstance(located, str):
        logger.warning("The control loop calls PyBullet through its Python API (slower, same results): %s", located)
    return located


def compiled_path_refusal() -> str | None:
    """Why the control loop calls PyBullet through its Python API in this process (None: it calls the C API from
    compiled code)."""
    located = _client_table()
    return located if isinstance(located, str) else None


def client_slot(client_id: int) -> int:
    """The address where PyBullet keeps the handle of its Python client ``client_id`` (read on every compiled call, as
    PyBullet's own functions read it: 0 once the client disconnects); 0 when it cannot be found or the handle found
    does not answer as the client (its number of bodies)."""
    located = _client_table()
    if isinstance(located, str):
        return 0
    table, entries = located
    if not 0 <= client_id < entries:
        return 0
    slot = table + 8 * client_id
    handle = ctypes.c_int64.from_address(slot).value
    library = _library()
    if handle == 0 or library is None or not library.b3CanSubmitCommand(ctypes.c_void_p(handle)):
        return 0
    if library.b3GetNumBodies(ctypes.c_void_p(handle)) != pybullet.getNumBodies(physicsClientId=client_id):
        return 0
    return slot


@intrinsic
def _address_at(typingctx, address):  # pragma: no cover - compiled
    """The 64-bit integer (an address) stored at ``address``."""

    def codegen(context, builder, signature, args):
        return builder.load(builder.inttoptr(args[0], ir.IntType(64).as_pointer()))

    return types.intp(types.intp), codegen


@intrinsic
def _int32_at(typingctx, address):  # pragma: no cover - compiled
    """The C int stored at ``address``."""

    def codegen(context, builder, signature, args):
        return builder.load(builder.inttoptr(args[0], ir.IntType(32).as_pointer()))

    return types.int32(types.intp), codegen


@intrinsic
def _doubles_at(typingctx, address):  # pragma: no cover - compiled
    """``address`` as a pointer to doubles (for ``numba.carray``)."""

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], ir.DoubleType().as_pointer())

    return types.CPointer(types.float64)(types.intp), codegen


@numba.njit(cache=True)
def _handle(ids):  # pragma: no cover - compiled
    """The client's handle, checked as PyBullet's functions check it (``getPhysicsClient``)."""
    handle = _address_at(ids[_SLOT])
    if handle == 0 or _can_submit(handle) == 0:
        raise RuntimeError("PyBullet: the world's physics client is not connected")
    return handle


@numba.njit(cache=True)
def read_joint_rows(ids, rows):  # pragma: no cover - compiled
    """The joints' states into ``rows`` (n, :data:`JOINT_ROW`), C-contiguous, n the joints read: ``getJointStates``'
    C calls (``b3RequestActualStateCommandInit``, ``b3GetJointState`` per joint) writing into the rows themselves."""
    if rows.shape[0] != ids[_COUNT] or rows.shape[1] != JOINT_ROW or not rows.flags.c_contiguous:
        raise ValueError("joint rows: expected a C-contiguous (joints read, 9) array")
    handle = _handle(ids)
    status = _submit(handle, _request_state(handle, ids[_BODY]))
    if _status_type(status) != _STATE_COMPLETED:
        raise RuntimeError("PyBullet: getJointStates failed")
    at = rows.ctypes.data
    for j in range(ids[_COUNT]):
        if _joint_state(handle, status, ids[_JOINTS + j], at + 8 * JOINT_ROW * j) == 0:
            raise RuntimeError("PyBullet: getJointStates failed")


@numba.njit(cache=True)
def read_contact_rows(ids):  # pragma: no cover - compiled
    """The tool's contact points (body A the arm, link A the tool, any body and link B) as contact rows (m,
    :data:`CONTACT_ROW`): ``getContactPoints``' C calls; a view of PyBullet's own memory, valid until the client's next
    command."""
    handle = _handle(ids)
    command = _request_contacts(handle)
    _filter_body(command, ids[_BODY])
    _filter_link(command, ids[_LINK])
    if _status_type(_submit(handle, command)) != _CONTACTS_COMPLETED:
        raise RuntimeError("PyBullet: getContactPoints failed")
    information = ids.ctypes.data + 8 * (ids.shape[0] - 2)
    _contact_information(handle, information)
    count = _int32_at(information)
    return numba.carray(_doubles_at(_address_at(information + 8)), (count, CONTACT_ROW))


@numba.njit(cache=True)
def send_torques_and_step(ids, torques):  # pragma: no cover - compiled
    """``setJointMotorControlArray`` in TORQUE_CONTROL with ``torques`` (7,) N·m, then ``stepSimulation``: their C
    calls (one torque command by velocity index, one physics step)."""
    if torques.shape[0] != _TORQUE_JOINTS:
        raise ValueError("torques: expected 7 joint torques (N·m)")
    handle = _handle(ids)
    command = _control_command(handle, ids[_BODY], _TORQUE_CONTROL)
    dofs = _JOINTS + ids[_COUNT]
    for j in range(_TORQUE_JOINTS):
        _set_torque(command, ids[dofs + j], torques[j])
    _submit(handle, command)
    if _status_type(_submit(handle, _step_command(handle))) != _STEP_COMPLETED:
        raise RuntimeError("PyBullet: stepSimulation failed")


class BulletClient:
    """One world's arm as a control loop queries and drives it: ``queried`` the joints read (joint rows, in this
    order), the first 7 torque-controlled, ``link`` the tool link whose contacts are read. With ``compiled`` (the
    default where :func:`client_slot` finds the client) the queries are the compiled functions above, callable from
    other compiled code with :attr:`ids`; else PyBullet's Python functions filling the same rows."""

    def __init__(self, client_id: int, body: int, queried: Sequence[int], link: int, compiled: bool = True) -> None:
        self.client_id, self.body, self.link = client_id, body, link
        self.queried = list(queried)
        slot = client_slot(client_id) if compiled else 0
        self.compiled = slot != 0
        """Whether the queries run as compiled C calls (else through PyBullet's Python API)."""
        if compiled and not self.compiled and compiled_path_refusal() is None:  # a refusal was logged once
            logger.warning("PyBullet's client %d does not answer from its table: this loop calls PyBullet through "
                           "Python (slower, same results)", client_id)  # fmt: skip
        dofs = [pybullet.getJointInfo(body, j, physicsClientId=client_id)[4] for j in self.queried[:_TORQUE_JOINTS]]
        self.ids = np.array([slot, body, link, len(self.queried), *self.queried, *dofs, 0, 0], dtype=np.int64)
        """The ids the compiled functions take (layout ``_SLOT`` ...; the last two slots their scratch space)."""
        self.joint_rows = np.zeros((len(self.queried), JOINT_ROW))
        """The joint rows of the last :meth:`read_joints` (the same array every read)."""

    def read_joints(self) -> NDArray[np.float64]:
        """This state's joint rows (:attr:`joint_rows`, overwritten in place)."""
        if self.compiled:
            read_joint_rows(self.ids, self.joint_rows)
        else:
            states = pybullet.getJointStates(self.body, self.queried, self.client_id)
            self.joint_rows[:] = [(s[0], s[1], *s[2], s[3]) for s in states]
        return self.joint_rows

    def read_contacts(self) -> NDArray[np.float64]:
        """This state's contact rows of the tool (m, :data:`CONTACT_ROW`), an array of its own."""
        if self.compiled:
            return read_contact_rows(self.ids).copy()
        points = pybullet.getContactPoints(self.body, -1, self.link, -2, self.client_id)
        return contact_rows_from_points(points)

    def send_torques_and_step(self, torques: NDArray[np.float64]) -> None:
        """The torque command (7,) N·m and one physics step."""
        if self.compiled:
            send_torques_and_step(self.ids, torques)
        else:
            joints = self.queried[:_TORQUE_JOINTS]
            pybullet.setJointMotorControlArray(self.body, joints, pybullet.TORQUE_CONTROL, forces=torques.tolist(),
                                               physicsClientId=self.client_id)  # fmt: skip
            pybullet.stepSimulation(self.client_id)


def contact_rows_from_points(points: Sequence[tuple] | None) -> NDArray[np.float64]:
    """``getContactPoints``' tuples as contact rows (m, :data:`CONTACT_ROW`; the ints as they lie in the C struct)."""
    rows = np.zeros((len(points or ()), CONTACT_ROW))
    for row, c in zip(rows, points or (), strict=True):
        row.view(np.int32)[:5] = c[:5]
        row[3:] = (*c[5], *c[6], *c[7], c[8], c[9], c[10], c[12], *c[11], *c[13])
    return rows


def contact_bodies(rows: NDArray[np.float64]) -> NDArray[np.int32]:
    """The body B (the environment's body id) of each contact row (m,)."""
    return np.ascontiguousarray(rows).view(np.int32).reshape(len(rows), 2 * CONTACT_ROW)[:, 2]
