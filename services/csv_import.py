"""Importing recorded demonstrations from CSV (any column names, conventions, event-driven logs).

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
4. the steps every importer shares (`services.import_steps.demonstration_from_samples`): an offset given or taken
   over a quiet window, a TOOL-frame wrench rotated into the world, a ``measured-on-tool`` wrench negated, the
   sensor offset fitted over every free-space stretch and subtracted, the result validated.

The options are one `schemas.import_options.CsvImportOptions`. Units are assumed SI already (s, m, N, N·m):
nothing is rescaled. ``services.importing.demonstration_from_file`` imports any demonstration file by what it holds
(CSV, JSON, a ROS 1 or ROS 2 bag).
Every problem raises :class:`CsvImportError` (a ``ValueError``) whose message names the column,
the line and the reason, one problem per line in ``problems``.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from schemas import Demonstration, DemonstrationMetadata, QuaternionOrder, WrenchFrame
from schemas.demonstration import MAX_DEMONSTRATION_SAMPLES
from schemas.import_options import COLUMN_KEYS, CsvImportOptions
from services.import_steps import (
    DemonstrationImportError,
    RecordingSamples,
    demonstration_from_samples,
    sampling_rate_hz,
)
from skills import preprocess


class CsvImportError(DemonstrationImportError):
    """A CSV recording could not be imported (missing column, non-numeric value, NaN, too few rows, ...)."""


MAX_CSV_ROWS = 5 * MAX_DEMONSTRATION_SAMPLES
"""The most data rows a CSV file may have: a file resampled to a fifth of its rate still fits the sample limit.
Counted while a file is read, before anything is parsed (parsing a too-long file in full cost 12.8 s and 2.3 GB
before it was refused)."""
MAX_CSV_BYTES = 400 * MAX_CSV_ROWS
"""The largest CSV file read, bytes (400 bytes per row is twice a 19-column row written at full double precision):
checked from the file's size before it is read."""
READ_CHUNK_BYTES = 1 << 22
"""A CSV file is read in chunks of this many bytes (4 MiB), its lines counted as they come: a file with too many rows
is refused after reading just past the limit, not after reading (let alone parsing) all of it."""


# --------------------------------------------------------------------------- column mapping

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


def _too_many_rows(lines: int, read_in_full: bool = True) -> CsvImportError:
    """The refusal of a CSV text of ``lines`` lines (header included; ``read_in_full`` False: at least that many,
    reading stopped there), more than `MAX_CSV_ROWS` data rows."""
    return CsvImportError(
        f"too many rows: {'' if read_in_full else 'at least '}{lines} lines, at most {MAX_CSV_ROWS} data rows (a "
        f"resampled recording may have at most {MAX_DEMONSTRATION_SAMPLES} samples); cut it into shorter recordings"
    )


def _read_counting_lines(path: Path) -> bytes:
    """Return the bytes of the file at ``path``, read in `READ_CHUNK_BYTES` chunks whose lines are counted as they
    come; raise :class:`CsvImportError` as soon as there are more than `MAX_CSV_ROWS` data rows."""
    chunks, lines = [], 0
    with path.open("rb") as file:
        while chunk := file.read(READ_CHUNK_BYTES):
            lines += chunk.count(b"\n")
            if lines > MAX_CSV_ROWS + 1:
                raise _too_many_rows(lines, read_in_full=False)
            chunks.append(chunk)
    return b"".join(chunks)


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
        size = path.stat().st_size
        if size > MAX_CSV_BYTES:
            raise CsvImportError(
                f"{str(path)!r}: {size / 1e6:.0f} MB, larger than the {MAX_CSV_BYTES / 1e6:.0f} MB a recording of at "
                f"most {MAX_CSV_ROWS} rows can have; cut it into shorter recordings"
            )
        return _read_counting_lines(path).decode("utf-8-sig"), path.name
    except OSError as exc:
        raise CsvImportError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise CsvImportError(f"{str(path)!r} is not a UTF-8 text file") from None


# --------------------------------------------------------------------------- import


def demonstration_from_csv(
    path_or_text: str | os.PathLike[str] | bytes, options: CsvImportOptions | None = None
) -> Demonstration:
    """Import a CSV recording (a path, or the CSV text itself) as a `schemas.Demonstration`.

    ``options`` (`schemas.import_options.CsvImportOptions`, default all defaults):
    ``quaternion_order``: order of the quaternion columns in the file, 'xyzw' (scalar last) or
    'wxyz' (scalar first). Default None: named columns (qx.., tcp_qw.., or ``columns``) say
    which component each is, and an explicit order that contradicts them is an error; numbered
    columns (q0..q3) need the order given.
    ``columns``: a column spec (``"t=time,px=tcp_x,..."``, :meth:`ColumnMap.parse`).
    ``wrench_convention``: 'applied-by-tool' (kept) or 'measured-on-tool' (negated).
    ``wrench_frame``: 'world' (the default: kept) or 'tool' (rotated into the world with the tool
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
    options = options or CsvImportOptions()
    frame, name, dt_s = options.wrench_frame or WrenchFrame.world, options.name, options.dt_s
    columns = ColumnMap.parse(options.columns) if options.columns else None
    rate = sampling_rate_hz(options.rate_hz, dt_s, CsvImportError)
    text, file_name = _text_and_name(path_or_text)
    file_name = file_name or (f"{name}.csv" if name else "inline.csv")
    lines = text.count("\n")  # one pass in C: refuse a too-long text (inline or uploaded) before parsing it
    if lines > MAX_CSV_ROWS + 1:
        raise _too_many_rows(lines)
    table = _read_table(text)
    resolved = resolved_columns(table.header, columns, frame, options.quaternion_order, time_optional=rate is not None)
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
            unmeasured_s=resampled.unmeasured,
        )
    return demonstration_from_samples(
        recording,
        options,
        wrench_frame=frame,
        metadata=DemonstrationMetadata(
            name=name or Path(file_name).stem, source=f"csv:{file_name}", quaternion_order_on_import=order
        ),
        extra={"columns": {k: table.header[j] for k, j in indices.items() if j is not None}, "rows": len(table.rows)},
        notes=notes,
        error=CsvImportError,
    )


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


__all__ = [
    "ColumnMap",
    "CsvImportError",
    "ResolvedColumns",
    "demonstration_from_csv",
    "resolved_columns",
]


CSV_HEADER = ("t", "x", "y", "z", "qx", "qy", "qz", "qw", "fx", "fy", "fz", "mx", "my", "mz")
"""Columns `demonstration_csv_text` writes: the project conventions, which `demonstration_from_csv` reads back."""


def demonstration_csv_text(demonstration: Demonstration) -> str:
    """Return ``demonstration`` as CSV text (s, m, [x, y, z, w], wrench applied by the tool in world, N and N·m).

    Full float precision (``repr``), so importing it again with the defaults gives the same samples.
    """
    a = demonstration.arrays()
    return samples_csv_text(a.t, a.positions, a.orientations, a.wrenches)


def samples_csv_text(
    t: np.ndarray, positions: np.ndarray, orientations: np.ndarray, wrenches: np.ndarray, header: bool = True
) -> str:
    """Samples in the project's conventions as the CSV text of :func:`demonstration_csv_text` (any number of rows;
    ``header``: with the header row, False for a chunk that goes on a text already started)."""
    table = np.column_stack([t, positions, orientations, wrenches])
    rows = [",".join(repr(float(v)) for v in row) + "\n" for row in table]
    return "".join([",".join(CSV_HEADER) + "\n"] * header + rows)
