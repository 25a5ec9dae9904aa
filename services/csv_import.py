"""Importing recorded demonstrations: CSV (any column names, conventions, event-driven logs) and JSON.

The result is always a validated `schemas.Demonstration` in the project's conventions
(docs/CONVENTIONS.md): SI units, uniform strictly increasing time, scalar-last unit sign-continuous
quaternions, and the wrench the tool APPLIES to the environment at the tool point in the WORLD
frame. Steps of :func:`demonstration_from_csv`, in order:

1. read the table (standard ``csv`` module; ``,`` ``;`` tab or whitespace separated, one header
   row, ``#`` comment lines and blank lines skipped) and map its columns (:class:`ColumnMap`);
2. quaternions to scalar-last (``quaternion_order``), norms checked, renormalized;
3. time: per channel group (pose, wrench) keep the real measurements of an event-driven log and
   resample onto one uniform grid (`skills.preprocess.resampled_recording`); a file WITHOUT a
   time column is a fixed-rate recording: its rows are the samples, ``t = row * dt`` from 0,
   with the rate given (``rate_hz`` or ``dt_s``), nothing resampled;
4. an offset the user gave (``force_offset``) or named by a quiet window (``tare_window_s``) is
   subtracted from the file's own wrench columns;
5. a TOOL-frame wrench is rotated into the world with the (interpolated) tool orientation;
6. a ``measured-on-tool`` wrench is negated (``applied-by-tool``);
7. otherwise ``tare``: contact is found from force and kinematics (`skills.contact`) and the
   sensor offset is fitted in the sensor (tool) frame over every free-space stretch, with the
   hand's push on the arm (`skills.tare`), and subtracted.

Units are assumed SI already (s, m, N, N·m): nothing is rescaled.
Every problem raises :class:`CsvImportError` (a ``ValueError``) whose message names the column,
the line and the reason, one problem per line in ``problems``.
"""

from __future__ import annotations

import csv
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from schemas import Demonstration, DemonstrationMetadata, QuaternionOrder, WrenchConvention, WrenchFrame
from schemas.demonstration import MAX_DEMONSTRATION_SAMPLES, MIN_DEMONSTRATION_SAMPLES
from skills import preprocess
from skills import tare as tare_module
from skills.contact import analyse_contact

MAX_PROBLEMS_LISTED = 10
"""At most this many problems are listed in one error (the count of the rest is given)."""


class DemonstrationImportError(ValueError):
    """A demonstration file could not be imported; ``problems`` holds one human-readable line per problem."""

    def __init__(self, problems: str | Iterable[str]) -> None:
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        if len(self.problems) > MAX_PROBLEMS_LISTED:
            more = len(self.problems) - MAX_PROBLEMS_LISTED
            self.problems = [*self.problems[:MAX_PROBLEMS_LISTED], f"... and {more} more problems"]
        super().__init__("\n".join(self.problems))


class CsvImportError(DemonstrationImportError):
    """A CSV recording could not be imported (missing column, non-numeric value, NaN, too few rows, ...)."""


# --------------------------------------------------------------------------- column mapping

COLUMN_KEYS = ("t", "px", "py", "pz", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz")
"""Keys of a column spec: time (s); position (m); quaternion components; force (N); moment (N·m)."""

_AXES = ("x", "y", "z")
_WORLD_SUFFIXES = ("w", "world", "base")
_TOOL_SUFFIXES = ("tcp", "tool", "ee", "sensor")


def _wrench_candidates(key: str, wrench_frame: WrenchFrame | None) -> list[str]:
    """Wrench header names for ``key`` with a frame suffix/prefix of ``wrench_frame`` (None: without one)."""
    axis = key[1]
    prefixes = ["f", "force_", "f_", "wrench_f"] if key[0] == "f" else ["m", "t", "torque_", "moment_", "tau_", "m_"]
    generic = [f"{p}{axis}" for p in prefixes]
    if wrench_frame is None:
        return generic
    suffixes = _WORLD_SUFFIXES if wrench_frame == WrenchFrame.world else _TOOL_SUFFIXES
    return [f"{name}_{suffix}" for suffix in suffixes for name in generic] + [
        f"{suffix}_{name}" for suffix in suffixes for name in generic
    ]


def _candidates(key: str, wrench_frame: WrenchFrame) -> list[str]:
    """Header names (normalized, see :func:`_normalized`) recognized for ``key``, best first."""
    if key == "t":
        return ["t", "time", "timestamp", "time_s", "t_s", "stamp", "seconds", "sec", "time_sec"]
    axis = key[1]
    if key[0] == "p":
        return [f"p{axis}", axis, f"pos_{axis}", f"position_{axis}", f"p_{axis}", f"tcp_{axis}", f"ee_{axis}",
                f"tool_{axis}", f"{axis}_m"]  # fmt: skip
    if key[0] == "q":
        return [f"q{axis}", f"q_{axis}", f"quat_{axis}", f"quaternion_{axis}", f"orientation_{axis}",
                f"tcp_q{axis}", f"ee_q{axis}", f"tool_q{axis}"]  # fmt: skip
    return _wrench_candidates(key, wrench_frame) + _wrench_candidates(key, None)


def _normalized(header_name: str) -> str:
    """Lower case, units in brackets removed, separators made ``_``: ``'Fx [N]'`` -> ``'fx'``."""
    name = re.sub(r"[\[(].*?[\])]", "", header_name.strip().lower())
    return re.sub(r"[^0-9a-z]+", "_", name).strip("_")


@dataclass(frozen=True)
class ColumnMap:
    """Which header column holds which quantity; a None field is recognized from common names.

    Keys (:data:`COLUMN_KEYS`): ``t`` time (s); ``px, py, pz`` tool point position (m);
    ``qx, qy, qz, qw`` orientation quaternion components (whatever their order in the file);
    ``fx, fy, fz`` force (N); ``mx, my, mz`` moment (N·m). The moment columns may be absent
    altogether (zero moments are used and a note says so).
    """

    t: str | None = None
    px: str | None = None
    py: str | None = None
    pz: str | None = None
    qx: str | None = None
    qy: str | None = None
    qz: str | None = None
    qw: str | None = None
    fx: str | None = None
    fy: str | None = None
    fz: str | None = None
    mx: str | None = None
    my: str | None = None
    mz: str | None = None

    @classmethod
    def parse(cls, spec: str) -> ColumnMap:
        """Parse ``"t=time,px=tcp_x,..."`` (``key=column`` pairs, comma separated; unnamed keys auto-detected)."""
        values: dict[str, str] = {}
        problems = []
        for item in filter(None, (part.strip() for part in spec.split(","))):
            key, sep, column = (part.strip() for part in item.partition("="))
            if not sep or not column:
                problems.append(f"--columns: {item!r} is not key=column (e.g. t=time,px=tcp_x)")
            elif key not in COLUMN_KEYS:
                problems.append(f"--columns: unknown key {key!r}; keys are {', '.join(COLUMN_KEYS)}")
            elif key in values:
                problems.append(f"--columns: key {key!r} given twice")
            else:
                values[key] = column
        if problems:
            raise CsvImportError(problems)
        return cls(**values)

    def given(self) -> dict[str, str]:
        """The keys that name a column explicitly."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


_NUMBERED_QUATERNION = re.compile(r"^(q|quat|quaternion|orientation|rot|tcp_q|ee_q|tool_q)_?([0-4])$")
_QUATERNION_KEYS = ("qx", "qy", "qz", "qw")


@dataclass(frozen=True)
class ResolvedColumns:
    """Where each quantity is in the header and how the quaternion columns are ordered."""

    indices: dict[str, int | None]
    """Header index of every key of :data:`COLUMN_KEYS`; None only for absent moment columns, and for an
    absent time column when it was allowed (``time_optional``: the rows are samples at a given rate)."""
    quaternion_order: QuaternionOrder
    """Order of the four quaternion columns as they appear in the file, left to right."""


def _numbered_quaternion_columns(header: list[str]) -> list[int] | None:
    """Four columns named like q0..q3 / q1..q4 / quat_0.. (same prefix, consecutive numbers), in number order."""
    sets: dict[str, dict[int, int]] = {}
    for j, name in enumerate(header):
        match = _NUMBERED_QUATERNION.match(_normalized(name))
        if match:
            sets.setdefault(match[1], {})[int(match[2])] = j
    for numbered in sets.values():
        for first in (0, 1):
            if all(first + i in numbered for i in range(4)):
                return [numbered[first + i] for i in range(4)]
    return None


def _quaternion_columns(
    found: dict[str, int | None], given: dict[str, str], header: list[str], order: QuaternionOrder | None
) -> QuaternionOrder:
    """Complete the quaternion keys of ``found`` in place; return the order of the columns in the file.

    Named columns (qx.., tcp_qw.., or --columns) decide which column is which component, and
    their left-to-right order in the file is the recorded order; an explicit ``order`` that
    contradicts them is an error (mislabelled file? name the columns with --columns). Numbered
    columns (q0..q3) carry no component names: ``order`` must be given.
    """
    named = {key: found[key] for key in _QUATERNION_KEYS if found[key] is not None}
    if len(named) == 4:
        by_position = "".join(key[1] for key in sorted(named, key=lambda k: named[k]))
        in_file = QuaternionOrder(by_position) if by_position in ("xyzw", "wxyz") else None
        if order is not None and in_file is not None and order != in_file:
            names = ", ".join(header[named[k]] for k in sorted(named, key=lambda k: named[k]))
            raise CsvImportError(
                f"quaternion order: the columns {names} are named in {in_file.value} order, but "
                f"quaternion_order={order.value!r} was given; drop the option, or map the columns with --columns"
            )
        return in_file or order or QuaternionOrder.xyzw
    if named or any(key in given for key in _QUATERNION_KEYS):
        return order or QuaternionOrder.xyzw  # the missing ones are reported as missing columns
    numbered = _numbered_quaternion_columns(header)
    if numbered is None:
        return order or QuaternionOrder.xyzw
    if order is None:
        names = ", ".join(header[j] for j in numbered)
        raise CsvImportError(
            f"quaternion columns {names} are numbered, not named: give their order with "
            "quaternion_order='wxyz' (scalar first) or 'xyzw' (scalar last), --quaternion-order on the command line"
        )
    for key, j in zip(("q" + c for c in order.value), numbered, strict=True):
        found[key] = j
    return order


def resolved_columns(
    header: list[str],
    columns: ColumnMap | None = None,
    wrench_frame: WrenchFrame = WrenchFrame.world,
    quaternion_order: QuaternionOrder | None = None,
    time_optional: bool = False,
) -> ResolvedColumns:
    """Find every key of :data:`COLUMN_KEYS` in ``header`` (``columns`` first, then common names).

    ``quaternion_order`` None: taken from the quaternion column names. ``time_optional``: a
    missing time column is not an error (its index is None; the caller knows the sampling rate).
    Raises :class:`CsvImportError` listing every missing column with the names looked for.
    """
    given = (columns or ColumnMap()).given()
    exact = {name.strip(): j for j, name in enumerate(header)}
    by_normal: dict[str, int] = {}
    for j, name in enumerate(header):
        by_normal.setdefault(_normalized(name), j)
    found: dict[str, int | None] = {}
    problems = []
    for key in COLUMN_KEYS:
        if key in given:
            name = given[key]
            j = exact.get(name, by_normal.get(_normalized(name)))
            if j is None:
                problems.append(f"column {name!r} given for {key} is not in the header ({', '.join(header)})")
            found[key] = j
            continue
        candidates = _candidates(key, wrench_frame)
        found[key] = next((by_normal[c] for c in candidates if c in by_normal), None)
    if problems:
        raise CsvImportError(problems)
    order = _quaternion_columns(found, given, header, quaternion_order)
    moments = [found[k] for k in ("mx", "my", "mz")]
    for key in COLUMN_KEYS:
        if found[key] is not None or (key[0] == "m" and all(m is None for m in moments)):
            continue
        if key == "t":
            if not time_optional:
                problems.append(
                    f"missing column for t (time): none of {', '.join(_candidates('t', wrench_frame)[:6])}, ... "
                    "in the header; name it with --columns t=<column>, or, if the rows are samples at a fixed rate, "
                    "pass --rate HZ or --dt SECONDS (API form fields rate, dt)"
                )
            continue
        if key[0] in "fm":
            shown = _wrench_candidates(key, None)[:3] + _wrench_candidates(key, wrench_frame)[:2]
        else:
            shown = _candidates(key, wrench_frame)[:6]
        problem = f"missing column for {key}: none of {', '.join(shown)}, ... in the header"
        other = WrenchFrame.tool if wrench_frame == WrenchFrame.world else WrenchFrame.world
        if key[0] in "fm" and any(c in by_normal for c in _wrench_candidates(key, other)):
            problem += f" (the file has a {other.value}-frame wrench: pass wrench_frame={other.value!r})"
        problems.append(problem + f"; name it with --columns {key}=<column>")
    problems.extend(_unit_problems(header, found))
    if problems:
        raise CsvImportError(problems)
    return ResolvedColumns(indices=found, quaternion_order=order)


SI_UNITS: dict[str, frozenset[str]] = {
    "t": frozenset({"s", "sec", "second", "seconds"}),
    "p": frozenset({"m", "meter", "meters", "metre", "metres"}),
    "q": frozenset({"", "-", "1"}),
    "f": frozenset({"n", "newton", "newtons"}),
    "m": frozenset({"nm", "n.m", "n·m", "n*m", "n m", "newton metre", "newton meter"}),
}
"""Units a column may declare in brackets (``x [m]``), by the first letter of its key; anything else is refused."""


def _unit_problems(header: list[str], found: dict[str, int | None]) -> list[str]:
    """One problem per used column whose header names a unit that is not SI (``x [mm]``, ``Fx (kN)``): nothing
    is rescaled on import, so a file in millimetres would be learned 1000 times too large."""
    problems = []
    for key, j in found.items():
        if j is None:
            continue
        unit = re.search(r"[\[(]\s*(.*?)\s*[\])]", header[j])
        if unit is not None and unit[1].lower() not in SI_UNITS[key[0]]:
            wanted = {"t": "s", "p": "m", "q": "none", "f": "N", "m": "N·m"}[key[0]]
            problems.append(
                f"column {header[j]!r} ({key}): unit {unit[1]!r}; the importer takes SI units only ({wanted}) and "
                "rescales nothing: convert the file"
            )
    return problems


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class _Table:
    header: list[str]
    rows: list[list[str]]
    lines: list[int]
    """1-based line number in the file of each data row."""


def _read_table(text: str) -> _Table:
    """Split CSV ``text`` into header and data rows (strings), keeping each row's line number."""
    numbered = [
        (k + 1, line) for k, line in enumerate(text.splitlines()) if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise CsvImportError("the file is empty: expected a header row and data rows")
    header_line = numbered[0][1]
    delimiter = next((d for d in (",", ";", "\t") if d in header_line), None)
    if delimiter is None:
        split = [line.split() for _, line in numbered]
    else:
        try:
            split = list(csv.reader((line for _, line in numbered), delimiter=delimiter, skipinitialspace=True))
        except csv.Error as exc:  # e.g. a field longer than the csv module's limit (131 072 characters)
            raise CsvImportError(f"the file is not a readable CSV table: {exc}") from None
    header = [name.strip() for name in split[0]]
    if all(_is_number(name) for name in header):
        raise CsvImportError("the first row holds numbers, not column names: a header row is required")
    rows, lines, problems = [], [], []
    for (line_number, _), row in zip(numbered[1:], split[1:], strict=True):
        if len(row) != len(header):
            problems.append(f"line {line_number}: {len(row)} fields, the header has {len(header)}")
        rows.append(row)
        lines.append(line_number)
    if problems:
        raise CsvImportError(problems)
    return _Table(header=header, rows=rows, lines=lines)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _numeric_columns(table: _Table, indices: dict[str, int | None]) -> dict[str, np.ndarray]:
    """Return each mapped column as floats; problems name the column, the line and the value."""
    values: dict[str, np.ndarray] = {}
    problems = []
    for key, j in indices.items():
        if j is None:
            continue
        name = table.header[j]
        cells = [row[j].strip() for row in table.rows]
        try:
            column = np.array(cells, dtype=float)
        except ValueError:
            k = next(k for k, cell in enumerate(cells) if not _is_number(cell))
            shown = repr(cells[k]) if cells[k] else "an empty value"
            problems.append(f"column {name!r} ({key}), line {table.lines[k]}: {shown} is not a number")
            continue
        bad = np.flatnonzero(~np.isfinite(column))
        if bad.size:
            k = int(bad[0])
            problems.append(
                f"column {name!r} ({key}), line {table.lines[k]}: {cells[k]!r} is not finite (NaN or inf)"
                + (f"; {bad.size} such values" if bad.size > 1 else "")
            )
        values[key] = column
    if problems:
        raise CsvImportError(problems)
    return values


def _text_and_name(path_or_text: str | os.PathLike[str] | bytes) -> tuple[str, str | None]:
    """Return the CSV text and the file name (None for text given inline)."""
    if isinstance(path_or_text, bytes):
        try:
            return path_or_text.decode("utf-8-sig"), None
        except UnicodeDecodeError:
            raise CsvImportError("the upload is not UTF-8 text") from None
    if isinstance(path_or_text, str) and ("\n" in path_or_text or not path_or_text.strip()):
        return path_or_text, None
    path = Path(path_or_text)
    try:
        return path.read_text(encoding="utf-8-sig"), path.name
    except OSError as exc:
        raise CsvImportError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise CsvImportError(f"{str(path)!r} is not a UTF-8 text file") from None


# --------------------------------------------------------------------------- import

MAX_RATE_HZ = 100_000.0
"""Highest sampling or resampling rate accepted, Hz (a ``dt`` down to 10 µs)."""
RATE_DT_AGREEMENT = 1e-6
"""Relative tolerance within which a rate and a dt given together count as the same (``rate * dt == 1``)."""


def sampling_rate_hz(rate_hz: float | None = None, dt_s: float | None = None) -> float | None:
    """Return the rate (Hz) given as ``rate_hz`` or as a time step ``dt_s`` (s), or None if neither is given.

    Both may be given if they agree (``rate_hz * dt_s`` = 1 within :data:`RATE_DT_AGREEMENT`).
    Raises :class:`CsvImportError` for a value that is not a positive finite number, a rate above
    :data:`MAX_RATE_HZ` (a dt below its inverse), or a rate and a dt that disagree.
    """
    problems = []
    if rate_hz is not None and not (np.isfinite(rate_hz) and 0 < rate_hz <= MAX_RATE_HZ):
        problems.append(f"rate: {rate_hz} Hz is not a rate in (0, {MAX_RATE_HZ:g}] Hz")
    if dt_s is not None and not (np.isfinite(dt_s) and dt_s >= 1.0 / MAX_RATE_HZ):
        problems.append(f"dt: {dt_s} s is not a positive time step of at least {1.0 / MAX_RATE_HZ:g} s")
    if problems:
        raise CsvImportError(problems)
    if rate_hz is not None and dt_s is not None:
        if abs(rate_hz * dt_s - 1.0) > RATE_DT_AGREEMENT:
            raise CsvImportError(
                f"rate and dt disagree: rate {rate_hz:g} Hz is a step of {1.0 / rate_hz:g} s, dt {dt_s:g} s "
                f"is {1.0 / dt_s:g} Hz; give one of them"
            )
        return float(rate_hz)
    if dt_s is not None:
        return 1.0 / float(dt_s)
    return None if rate_hz is None else float(rate_hz)


def demonstration_from_csv(
    path_or_text: str | os.PathLike[str] | bytes,
    columns: ColumnMap | None = None,
    quaternion_order: QuaternionOrder | str | None = None,
    wrench_convention: WrenchConvention | str = WrenchConvention.applied_by_tool,
    wrench_frame: WrenchFrame | str = WrenchFrame.world,
    rate_hz: float | None = None,
    tare: bool = True,
    name: str | None = None,
    dt_s: float | None = None,
    tare_window_s: tuple[float, float] | None = None,
    force_offset: Sequence[float] | None = None,
) -> Demonstration:
    """Import a CSV recording (a path, or the CSV text itself) as a `schemas.Demonstration`.

    ``quaternion_order``: order of the quaternion columns in the file, 'xyzw' (scalar last) or
    'wxyz' (scalar first). Default None: named columns (qx.., tcp_qw.., or ``columns``) say
    which component each is, and an explicit order that contradicts them is an error; numbered
    columns (q0..q3) need the order given.
    ``wrench_convention``: 'applied-by-tool' (kept) or 'measured-on-tool' (negated).
    ``wrench_frame``: 'world' (kept) or 'tool' (rotated into the world with the tool
    orientation; the point stays the tool point).
    ``rate_hz`` (Hz) or ``dt_s`` (s, the same as ``rate_hz=1/dt_s``; both may be given if they
    agree): with a time column, the uniform rate to resample to (default: the fastest channel
    group's median update rate, 200 Hz for the KU Leuven logs). Without a time column (none of
    the recognised names and none given in ``columns``) the file is a fixed-rate recording: the
    rows are the samples, ``t = row * dt`` from 0, nothing is resampled; the rate must then be
    given (else :class:`CsvImportError` naming the missing time column).
    ``tare``: subtract the sensor offset, estimated in the sensor (tool) frame over every
    free-space stretch (`skills.tare`), if the recording has enough free space.
    ``tare_window_s`` ``(t0, t1)`` s: instead, the median wrench of the file's rows in that window
    (nothing touching the tool there) is the offset, in the file's own frame and sign.
    ``force_offset``: instead, this offset (3 forces, N, or 6 with moments, N·m), as the file reads
    it with nothing touching the tool (its own frame and sign).
    ``name``: metadata name (default: the file stem; 'inline' for CSV text).

    Metadata records the conventions on import, the resampled rate (None for a fixed-rate file), the removed offset
    (as the file reads it, in ``force_offset_frame``), and in ``extra``: ``import_notes`` (one line
    per thing done), ``columns`` (key -> header name used), ``rows`` and ``tare`` (how the offset
    was found: method, free-space stretches, samples).
    Raises :class:`CsvImportError` naming the column/line/field and the reason.
    """
    try:
        requested_order = None if quaternion_order is None else QuaternionOrder(quaternion_order)
        convention = WrenchConvention(wrench_convention)
        frame = WrenchFrame(wrench_frame)
    except ValueError as exc:
        raise CsvImportError(str(exc)) from None
    rate = sampling_rate_hz(rate_hz, dt_s)
    text, file_name = _text_and_name(path_or_text)
    file_name = file_name or (f"{name}.csv" if name else "inline.csv")
    table = _read_table(text)
    resolved = resolved_columns(table.header, columns, frame, requested_order, time_optional=rate is not None)
    indices, order = resolved.indices, resolved.quaternion_order
    values = _numeric_columns(table, indices)
    if len(table.rows) < 2:
        raise CsvImportError(f"too few rows: {len(table.rows)} data row(s); a recording needs many samples over time")

    positions = np.column_stack([values[k] for k in ("px", "py", "pz")])
    q_file = np.column_stack([values["q" + component] for component in order.value])  # in the file's order
    orientations = preprocess.quaternions_scalar_last(q_file, order.value)
    _check_quaternions(orientations, table, indices)
    notes = []
    if indices["mx"] is None:
        wrench = np.column_stack([values[k] for k in ("fx", "fy", "fz")] + [np.zeros(len(table.rows))] * 3)
        notes.append("no moment columns: moments set to zero")
    else:
        wrench = np.column_stack([values[k] for k in ("fx", "fy", "fz", "mx", "my", "mz")])

    if indices["t"] is None:  # a fixed-rate recording: every row is a sample, nothing to resample
        assert rate is not None  # resolved_columns refuses a missing time column without a rate
        recording = _fixed_rate_recording(positions, orientations, wrench, dt_s if dt_s is not None else 1.0 / rate)
    else:
        t = values["t"]
        if np.ptp(t) <= 0:
            raise CsvImportError(f"column {table.header[indices['t']]!r} (t): all time stamps are equal ({t[0]:g} s)")
        try:
            resampled = preprocess.resampled_recording(
                t, positions, orientations, wrench, rate, max_samples=MAX_DEMONSTRATION_SAMPLES
            )
        except preprocess.TooManySamples as exc:
            raise CsvImportError(f"{'rate' if rate is not None else 'resampling'}: {exc}") from None
        except ValueError as exc:
            raise CsvImportError(f"resampling: {exc}") from None
        recording = RecordingSamples(
            t=resampled.t,
            positions=resampled.positions,
            orientations=resampled.orientations,
            wrenches=resampled.wrenches,
            rate_hz=resampled.rate_hz,
            notes=resampled.notes,
        )
    return demonstration_from_samples(
        recording,
        wrench_frame=frame,
        wrench_convention=convention,
        tare=tare,
        tare_window_s=tare_window_s,
        force_offset=force_offset,
        metadata=DemonstrationMetadata(
            name=name or Path(file_name).stem, source=f"csv:{file_name}", quaternion_order_on_import=order
        ),
        extra={"columns": {k: table.header[j] for k, j in indices.items() if j is not None}, "rows": len(table.rows)},
        notes=notes,
        error=CsvImportError,
    )


def demonstration_from_samples(
    recording: RecordingSamples,
    *,
    wrench_frame: WrenchFrame,
    wrench_convention: WrenchConvention,
    tare: bool,
    tare_window_s: tuple[float, float] | None,
    force_offset: Sequence[float] | None,
    metadata: DemonstrationMetadata,
    extra: dict[str, object] | None = None,
    notes: Sequence[str] = (),
    error: type[DemonstrationImportError] = DemonstrationImportError,
) -> Demonstration:
    """The shared last steps of every importer (CSV, ROS 2 bags): a recording on its time grid -> a validated
    `schemas.Demonstration` in the project's conventions.

    ``recording`` holds the file's wrench in ``wrench_frame`` and ``wrench_convention`` at the tool point
    (N, N·m). In order: a given offset (``force_offset``) or a quiet window's median (``tare_window_s``,
    s) is subtracted in the file's own frame and sign; a TOOL-frame wrench is rotated into the world with
    the tool orientation; a ``measured-on-tool`` wrench is negated; otherwise with ``tare`` the sensor
    offset is fitted in the tool frame over every free-space stretch and removed. ``metadata`` gives the
    name, source and quaternion order; the conventions, rate, offset and ``extra`` (plus ``import_notes``:
    ``recording.notes``, then ``notes``, then one line per step, and ``tare``) are filled in here.
    Every problem raises ``error`` (naming the option or field and the reason).
    """
    frame, convention = wrench_frame, wrench_convention
    notes = [*recording.notes, *notes]
    wrenches = recording.wrenches
    given = _given_offset(recording, tare_window_s, force_offset, error)
    if given is not None:
        wrenches = wrenches - given.offset
    if frame == WrenchFrame.tool:
        wrenches = preprocess.wrenches_tool_to_world(wrenches, recording.orientations)
        notes.append("wrench given in the tool frame: rotated into the world with the interpolated tool orientation")
    if convention == WrenchConvention.measured_on_tool:
        wrenches = preprocess.wrenches_applied_by_tool(wrenches)
        notes.append("wrench measured on the tool: negated to the wrench the tool applies")
    notes.extend(_direction_hint(wrenches, convention))
    offset, offset_frame, tare_report = None, None, {"method": "none"}
    if given is not None:
        offset, offset_frame, tare_report = given.offset, frame.value, {"method": given.method}
        notes.append(given.note)
    elif tare:
        estimate = _free_space_offset(recording, wrenches)
        if estimate is None:
            notes.append(
                f"no free-space part of at least {tare_module.MIN_FREE_S} s found: no sensor offset removed "
                "(--tare-window or --force-offset set one)"
            )
        else:
            wrenches = tare_module.wrenches_without_offset(recording.orientations, wrenches, estimate.wrench)
            sign = -1.0 if convention == WrenchConvention.measured_on_tool else 1.0
            offset, offset_frame = sign * estimate.wrench, "tool"
            where = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in estimate.stretches[:6])
            more = f" and {len(estimate.stretches) - 6} more" if len(estimate.stretches) > 6 else ""
            force = ", ".join(f"{v:+.2f}" for v in offset[:3])
            notes.append(
                f"sensor offset removed: [{force}] N in the sensor (tool) frame as the file reads it, fitted over "
                f"{estimate.samples} free-space samples ({where}{more}) with the hand's push on the arm "
                f"(damping {estimate.arm_damping_n_s_m:.1f} N·s/m, mass {estimate.arm_mass_kg:.1f} kg, "
                f"friction {estimate.arm_friction_n:.1f} N)"
            )
            tare_report = {
                "method": "free-space fit",
                "stretches_s": [list(s) for s in estimate.stretches],
                "samples": estimate.samples,
                "arm_damping_n_s_m": estimate.arm_damping_n_s_m,
                "arm_mass_kg": estimate.arm_mass_kg,
                "arm_friction_n": estimate.arm_friction_n,
            }
    else:
        notes.append("tare off: no sensor offset removed")
    if recording.t.size < MIN_DEMONSTRATION_SAMPLES:
        remedy = "record longer" if recording.fixed_rate else "record longer, or pass a higher rate"
        raise error(
            f"too few samples: {recording.t.size} at {recording.rate_hz:g} Hz over {np.ptp(recording.t):.3g} s, "
            f"at least {MIN_DEMONSTRATION_SAMPLES} are needed ({remedy})"
        )
    metadata = metadata.model_copy(
        update={
            "wrench_convention_on_import": convention,
            "wrench_frame_on_import": frame,
            "resampled_rate_hz": None if recording.fixed_rate else recording.rate_hz,
            "force_offset_removed": None if offset is None else offset.tolist(),
            "force_offset_frame": offset_frame,
            "extra": {**metadata.extra, "import_notes": notes, **(extra or {}), "tare": tare_report},
        }
    )
    try:
        return Demonstration.from_arrays(recording.t, recording.positions, recording.orientations, wrenches, metadata)
    except ValidationError as exc:
        raise error(validation_problems(exc)) from None


@dataclass(frozen=True)
class _GivenOffset:
    """An offset the user gave (or a window they named), in the file's frame and sign: (6,) N, N·m."""

    offset: np.ndarray
    method: str
    note: str


def _given_offset(
    recording: RecordingSamples,
    tare_window_s: tuple[float, float] | None,
    force_offset: Sequence[float] | None,
    error: type[DemonstrationImportError],
) -> _GivenOffset | None:
    """Return the offset the options ask for (``--force-offset`` or ``--tare-window``), or None; else ``error``."""
    if tare_window_s is not None and force_offset is not None:
        raise error("tare: give either a tare window or a force offset, not both")
    if force_offset is not None:
        values = np.asarray(force_offset, dtype=float)
        if values.shape not in ((3,), (6,)) or not np.all(np.isfinite(values)):
            raise error(f"force offset: 3 forces (N) or 6 values with moments (N·m) are needed, got {values}")
        offset = np.concatenate([values, np.zeros(6 - values.size)])
        shown = ", ".join(f"{v:+.2f}" for v in offset[:3])
        return _GivenOffset(offset, "given", f"sensor offset removed as given: [{shown}] N in the file's frame")
    if tare_window_s is None:
        return None
    t0, t1 = (float(v) for v in tare_window_s)
    inside = (recording.t >= t0) & (recording.t <= t1)
    if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0) or inside.sum() < 2:
        raise error(
            f"tare window: {t0:g}-{t1:g} s holds {int(inside.sum())} samples; the recording runs "
            f"{recording.t[0]:g}-{recording.t[-1]:g} s and the window needs at least 2 of them"
        )
    offset = np.median(recording.wrenches[inside], axis=0)
    shown = ", ".join(f"{v:+.2f}" for v in offset[:3])
    note = f"sensor offset removed: [{shown}] N, median of the file's wrench over the tare window {t0:g}-{t1:g} s"
    return _GivenOffset(offset, "window", note)


def _free_space_offset(recording: RecordingSamples, wrenches: np.ndarray) -> tare_module.SensorOffset | None:
    """Estimate the sensor offset over the free-space stretches of an (untared) world-frame applied wrench."""
    t = recording.t
    if t.size < MIN_DEMONSTRATION_SAMPLES:
        return None
    contact = analyse_contact(t, recording.positions, wrenches[:, :3])
    if not contact.intervals:
        return None
    free = tare_module.free_space_mask(contact.rate_hz, contact.in_contact)
    return tare_module.sensor_offset_in_free_space(t, recording.positions, recording.orientations, wrenches, free)


@dataclass(frozen=True)
class RecordingSamples:
    """A recording on its uniform time grid (what the steps after the time step need): ``t`` (N,) s, ``positions``
    (N, 3) m, ``orientations`` (N, 4), ``wrenches`` (N, 6) N and N·m as the file holds them, ``rate_hz``, the
    notes of the time step."""

    t: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    """Unit, scalar-last, sign-continuous."""
    wrenches: np.ndarray
    rate_hz: float
    notes: list[str]
    fixed_rate: bool = False
    """True: the rows were taken as samples at a given rate (no time column), not resampled."""


def _fixed_rate_recording(
    positions: np.ndarray, orientations: np.ndarray, wrenches: np.ndarray, dt_s: float
) -> RecordingSamples:
    """The rows of a file without a time column as samples ``dt_s`` apart: ``t = row * dt_s`` from 0.

    Every row is a measurement (a value repeated over rows is the robot holding still, not an
    event-log repeat), so none is dropped and nothing is resampled.
    """
    rate_hz = 1.0 / dt_s
    return RecordingSamples(
        t=np.arange(positions.shape[0]) * dt_s,
        positions=positions,
        orientations=preprocess.quaternions_unit_continuous(orientations),
        wrenches=wrenches,
        rate_hz=rate_hz,
        notes=[f"no time column: rows taken as samples at {rate_hz:g} Hz (dt {dt_s:g} s)"],
        fixed_rate=True,
    )


UPWARD_FORCE_HINT = 0.5
"""World z of the stronger half of the forces' mean direction above which the import notes ask to check the sign."""


def _direction_hint(wrenches: np.ndarray, convention: WrenchConvention) -> list[str]:
    """A note when the applied force points mostly UP in the world: pressing on a table or a part points down.

    Not an error (a wall or a ceiling is possible), but a reaction imported as applied-by-tool
    looks exactly like this.
    """
    forces = wrenches[:, :3]
    magnitude = np.linalg.norm(forces, axis=1)
    strong = forces[magnitude >= np.median(magnitude)].mean(axis=0)
    if np.linalg.norm(strong) == 0 or strong[2] / np.linalg.norm(strong) <= UPWARD_FORCE_HINT:
        return []
    flip = "measured-on-tool" if convention == WrenchConvention.applied_by_tool else "applied-by-tool"
    return [
        f"check the wrench sign: the applied force points mostly UP in the world (mean direction z = "
        f"{strong[2] / np.linalg.norm(strong):+.2f}); if the file holds the other convention pass --wrench {flip}"
    ]


def _check_quaternions(q: np.ndarray, table: _Table, indices: dict[str, int | None]) -> None:
    """Reject quaternions whose norm is far from 1 (wrong columns), naming the columns and the first line."""
    deviation = preprocess.quaternion_norm_deviations(q)
    bad = np.flatnonzero(deviation > preprocess.MAX_QUATERNION_NORM_DEVIATION)
    if bad.size:
        k = int(bad[0])
        names = ", ".join(table.header[indices[key]] for key in ("qx", "qy", "qz", "qw"))  # type: ignore[index]
        raise CsvImportError(
            f"quaternion ({names}), line {table.lines[k]}: norm {np.linalg.norm(q[k]):.4g} is not 1 "
            f"(tolerance {preprocess.MAX_QUATERNION_NORM_DEVIATION}); {bad.size} such rows: check the columns"
        )


def validation_problems(exc: ValidationError) -> list[str]:
    """One line per pydantic validation error: ``field.path: message``."""
    problems = []
    for error in exc.errors():
        location = ".".join(str(part) for part in error["loc"]) or "demonstration"
        message = error["msg"].removeprefix("Value error, ")
        problems.append(f"{location}: {message}")
    return problems


def demonstration_from_json(path_or_text: str | os.PathLike[str] | bytes) -> Demonstration:
    """Load a `schemas.Demonstration` from a JSON file (or JSON text); the data must already follow the conventions.

    Raises :class:`DemonstrationImportError` with one line per problem (unreadable file,
    invalid JSON, or each failing field with its path, e.g. ``orientations: quaternion at sample 3 ...``).
    """
    if isinstance(path_or_text, bytes):
        text = path_or_text.decode("utf-8-sig")
    elif isinstance(path_or_text, str) and path_or_text.lstrip().startswith("{"):
        text = path_or_text
    else:
        path = Path(path_or_text)
        try:
            text = path.read_text(encoding="utf-8-sig")
        except OSError as exc:
            raise DemonstrationImportError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
        except UnicodeDecodeError:
            raise DemonstrationImportError(f"{str(path)!r} is not a UTF-8 text file") from None
    try:
        return Demonstration.model_validate_json(text)
    except ValidationError as exc:
        raise DemonstrationImportError(validation_problems(exc)) from None


def demonstration_from_file(path: str | os.PathLike[str], **csv_options: object) -> Demonstration:
    """Import ``path`` by its suffix: ``.json`` via :func:`demonstration_from_json`, anything else as CSV."""
    if Path(path).suffix.lower() == ".json":
        return demonstration_from_json(path)
    return demonstration_from_csv(path, **csv_options)  # type: ignore[arg-type]


__all__ = [
    "COLUMN_KEYS",
    "ColumnMap",
    "CsvImportError",
    "DemonstrationImportError",
    "RecordingSamples",
    "ResolvedColumns",
    "demonstration_from_csv",
    "demonstration_from_file",
    "demonstration_from_json",
    "demonstration_from_samples",
    "resolved_columns",
    "sampling_rate_hz",
    "validation_problems",
]


CSV_HEADER = ("t", "x", "y", "z", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz")
"""Columns `demonstration_csv_text` writes: the project conventions, which `demonstration_from_csv` reads back."""


def demonstration_csv_text(demonstration: Demonstration) -> str:
    """Return ``demonstration`` as CSV text (s, m, [x, y, z, w], wrench applied by the tool in world, N and N·m).

    Full float precision (``repr``), so importing it again with the defaults gives the same samples.
    """
    a = demonstration.arrays()
    return samples_csv_text(a.t, a.positions, a.orientations, a.wrenches)


def samples_csv_text(t: np.ndarray, positions: np.ndarray, orientations: np.ndarray, wrenches: np.ndarray) -> str:
    """Samples in the project's conventions as the CSV text of :func:`demonstration_csv_text` (any number of rows)."""
    table = np.column_stack([t, positions, orientations, wrenches])
    rows = (",".join(repr(float(v)) for v in row) for row in table)
    return "\n".join([",".join(CSV_HEADER), *rows]) + "\n"
