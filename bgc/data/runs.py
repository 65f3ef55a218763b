r"""Recorded runs: the CSV that ``bgc simulate`` writes and the filters read.

Format: ``#`` comment lines (a header saying which model and fault made the
run), then a CSV table with a ``time`` column and columns prefixed by what they
hold: ``u:NAME`` inputs (held over the step that ends at the row's time;
a header line ``input timing: start`` says they are set at the row's time
instead: :data:`TIMINGS`),
``y:NAME`` measurements, ``x:NAME`` true states, ``theta:NAME`` the true value
of a faulty parameter. A measurement left empty or ``nan`` was not taken.

A run file is data from outside: it is size-checked before it is read (and
must be a regular file: not a FIFO or a device), decoded strictly, and every
problem is a one-line :class:`~bgc.errors.DataError` naming the file and line.
It is read as a stream, one line at a time, into growing NumPy arrays: the
memory a run takes stays near the size of its numbers (8 bytes each), whatever
else the file holds. Its header is a few lines (bgc simulate writes five):
at most ``MAX_COMMENT_LINES`` comment lines of at most ``MAX_COMMENT``
characters, at most ``MAX_BLANK_LINES`` blank lines, at most ``MAX_COLUMNS``
columns and ``MAX_VALUES`` numbers; a line of more than ``MAX_LINE``
characters is refused without being held in memory. A stream read row by
row for as long as it goes on (:class:`RowReader`, a monitor's) has no
bound on its bytes, and its bounds on comment and blank lines hold between
two rows (before the first row, the header's lines count with those after
the column names), the comment lines before the last row but one forgotten.

:func:`check_run` holds what a run must be (times finite and increasing,
columns of numbers as long as the time, no infinite value): the CSV reader
and the Python API (a :class:`Run` built in a script) both use it.

Examples
--------
>>> run = parse_run("# model rc: 2 steps\ntime,y:e3\n0.5,1.25\n1.0,\n", "rc.csv")
>>> run.time.tolist(), run.measurements["e3"].tolist(), run.model, run.source
([0.5, 1.0], [1.25, nan], 'rc', 'rc.csv')
>>> parse_run("time,y:e3\n0.5,inf\n", "rc.csv")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
bgc.errors.DataError: rc.csv:2: inf in column y:e3 is not a finite number (write a finite number, ...)
"""

from __future__ import annotations

import codecs
import csv
import glob
import io
import math
import os
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from ..arguments import spelled
from ..errors import DataError, printable
from .clock import Clock
from .columns import MODE, PREFIXES, Reading, bgc_name, iso_seconds

#: A run file larger than this is refused before it is read (a 300-step run of
#: the RO plant is about 60 kB).
MAX_RUN_BYTES = 256_000_000
#: Longest field: a number's text is far shorter.
MAX_FIELD = 1000
#: Longest line, in characters (a row of 10,000 columns of 25-character numbers
#: is 250,000).
MAX_LINE = MAX_FIELD * 1000
#: Most ``#`` comment lines in a run file: its header (bgc simulate writes 5).
MAX_COMMENT_LINES = 256
#: Longest comment line, in characters (bgc simulate's are under 200, plus the
#: model file's path).
MAX_COMMENT = 10_000
#: Most blank lines in a run file (bgc simulate writes none).
MAX_BLANK_LINES = 1000
#: Most columns of a run file (a model's inputs, sensors, states and a parameter).
MAX_COLUMNS = 10_000
#: Most numbers of a run (rows x columns, each held as 8 bytes, with each row's
#: line number: 128 MB); a run file of ``MAX_RUN_BYTES`` as bgc simulate
#: writes it (about 19 characters a number) holds about 13.5 million.
MAX_VALUES = 16_000_000
#: Numbers parsed (as Python floats, about 32 bytes each) before they are
#: copied into the arrays at once.
_BLOCK = 16384
#: The ``source`` of a :class:`Run` built in Python, when it is given none.
PYTHON_SOURCE = "<Run from Python>"
_FIX = "give a CSV written by bgc simulate"


@dataclass(frozen=True, slots=True)
class Run:
    """A recorded run: columns by prefix, arrays of shape (T,); ``source``:
    where it comes from (the file it was read from, ``scenario PARAM:...``
    for a simulated one), named by every message about its data."""

    time: np.ndarray
    inputs: dict[str, np.ndarray]
    measurements: dict[str, np.ndarray]
    states: dict[str, np.ndarray]
    parameters: dict[str, np.ndarray]
    header: tuple[str, ...]
    source: str = PYTHON_SOURCE
    #: A model with modes: the plant's mode at each sample, as its number (1 for the first mode the model
    #: lists; NaN: not recorded), from a ``mode`` column; None: no such column.
    modes: np.ndarray | None = None

    @property
    def model(self) -> str | None:
        """The model the header says made the run (``model NAME: ...``), if any."""
        for h in self.header:
            if h.startswith("model ") and ":" in h:
                return h.split(":")[0][len("model "):]
        return None



#: What a row's input value is (:class:`~bgc.diagnosis.options.DiagnosisOptions`' ``input_timing``):
#: ``end``, the value held over the step that ends at the row's time (bgc's own files, the default), or
#: ``start``, the value set at the row's time and acting until the next row (what many loggers write).
TIMINGS = ("end", "start")
#: The header line (``# input timing: start``) by which a run file says its inputs' timing.
TIMING_LINE = "input timing"


def header_timing(header: tuple[str, ...], source: str) -> str | None:
    """The inputs' timing a run's header states (an ``input timing: end``
    or ``input timing: start`` line), None when it states none; a line that
    states another is a one-line :class:`~bgc.errors.DataError`."""
    said = None
    for h in header:
        key, colon, value = h.partition(":")
        if not colon or key.strip().lower() != TIMING_LINE:
            continue
        value = value.strip().lower()
        if value not in TIMINGS or (said is not None and value != said):
            raise DataError(f"{printable(source)}: its header line '# {printable(h)}' is not one input timing of "
                            f"{', '.join(TIMINGS)}", None,
                            "write '# input timing: end' (each value held over the step that ends at its row's "
                            "time) or '# input timing: start' (set at its row's time), once")
        said = value
    return said


def resolve_timing(header: tuple[str, ...], given: str | None, source: str, flag: str) -> str:
    """The inputs' timing of a run: ``given`` (the option, ``flag`` its name
    in messages) or what its header says (:func:`header_timing`), else
    ``end``; the two disagreeing is a one-line :class:`~bgc.errors.DataError`."""
    said = header_timing(header, source)
    if given is not None and said is not None and given != said:
        raise DataError(f"{printable(source)}: its header says 'input timing: {said}', and {flag} says {given}",
                        None, f"drop {flag} (the header says it), or correct the header's line")
    return given or said or "end"


def input_columns(run: Run) -> dict[str, np.ndarray]:
    """A run's inputs by name, its ``mode`` column among them when it has one
    (a model with modes reads it as its last input, ``mode``)."""
    return dict(run.inputs) | ({MODE: run.modes} if run.modes is not None else {})

def to_csv(header: tuple[str, ...], columns: list[tuple[str, np.ndarray]]) -> str:
    """The CSV text of a run: ``# `` header lines (kept on one line each), then
    the columns (name, values) with every number as its shortest repr."""
    buf = io.StringIO()
    for line in header:
        buf.write(f"# {printable(line)}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([name for name, _ in columns])
    data = np.column_stack([np.asarray(v, dtype=float) for _, v in columns])
    for row in data:
        w.writerow([repr(float(v)) for v in row])
    return buf.getvalue()


def run_csv(run: Run) -> str:
    """A run as CSV text again (what :func:`parse_run` reads back)."""
    columns = [("time", run.time)] + ([("mode", run.modes)] if run.modes is not None else [])
    for prefix, group in (("u", run.inputs), ("y", run.measurements), ("x", run.states), ("theta", run.parameters)):
        columns += [(f"{prefix}:{name}", values) for name, values in group.items()]
    return to_csv(run.header, columns)


def open_stream(path: str):
    """A run file or a named pipe, opened for reading (not a device that never ends)."""
    try:
        mode = os.stat(path).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISFIFO(mode)):
            raise DataError(f"{printable(path)} is not a regular file or a pipe", None,
                            "give a run file, a named pipe, or - for standard input")
        return open(path, "rb")
    except OSError as exc:
        raise DataError(f"{printable(path)}: {printable(exc.strerror or str(exc))}", None,
                        "give a run file, or - for standard input") from None


def run_files(path: str | Path) -> list[Path] | None:
    """The files ``path`` names when it names several: a folder (its
    ``*.csv`` files) or a glob pattern (``logs/2026-03-*.csv``), the
    regular files sorted by name (a logger's daily files named by date sort
    in time order; :func:`read_run` orders them by their times); None when
    it names one file (an existing file whose name holds a ``*`` is that
    file)."""
    p = Path(path)
    if p.is_dir():
        files = sorted(f for f in p.glob("*.csv") if f.is_file())
    elif not p.exists() and glob.has_magic(str(path)):
        files = sorted(Path(f) for f in glob.glob(str(path)) if Path(f).is_file())
    else:
        return None
    if not files:
        raise DataError(f"{printable(str(path))}: no run file " + ("in the folder (*.csv)" if p.is_dir() else
                        "matches the pattern"), None, "give a run file, a folder of them, or a pattern that matches")
    return files


def read_run(path: str | Path, reading: Reading | None = None) -> Run:
    """Read a run file (see the module docstring for the checks); ``reading``:
    the column map and what the model reads (:class:`~bgc.data.columns.Reading`).
    A folder or a glob pattern (:func:`run_files`) is read as one run, its
    files in time order (by each one's first time; :func:`join_runs`)."""
    files = run_files(path)
    if files is not None:  # in time order: by each file's first time (names need not sort so: log.2, log.1)
        return join_runs(sorted((read_run(f, reading) for f in files), key=lambda r: float(r.time[0])),
                         printable(str(path)), None if reading is None else reading.time_unit)
    name = printable(str(path))
    p = Path(path)
    try:
        info = p.stat()
    except FileNotFoundError:
        raise DataError(f"{name}: no such file", None, _FIX) from None
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {exc.strerror}", None, _FIX) from None
    if not stat.S_ISREG(info.st_mode):
        raise DataError(f"{name}: not a regular file", None, "give a CSV file written by bgc simulate")
    if info.st_size > MAX_RUN_BYTES:
        raise DataError(f"{name}: file is {info.st_size} bytes, more than {MAX_RUN_BYTES}", None,
                        "split the run into shorter records")
    try:
        with open(p, "rb") as f:
            return _parse(f, name, reading)
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {exc.strerror}", None, _FIX) from None


def join_runs(parts: list[Run], source: str, time_unit: str | None = None) -> Run:
    """Runs read from consecutive files (a logger's daily files) as one run
    named ``source``: the same columns in each (each its own header: the
    first's is kept, and a file that states another input timing is
    refused), each file's rows going on in time from the one before's;
    every mistake a one-line :class:`~bgc.errors.DataError` naming the file
    (its times written by the model's ``time_unit``, :class:`~bgc.data.clock.Clock`)."""
    first = parts[0]
    clock = Clock.of(first.time[:1], time_unit)

    def columns(r: Run) -> tuple:
        return (tuple(r.inputs), tuple(r.measurements), tuple(r.states), tuple(r.parameters), r.modes is None)

    for before, r in zip(parts, parts[1:]):
        if columns(r) != columns(first):
            raise DataError(f"{r.source}: its columns differ from {first.source}'s", None,
                            "give files of one logger, with the same columns")
        if header_timing(r.header, r.source) != header_timing(first.header, first.source):
            raise DataError(f"{r.source}: its header states another input timing than {first.source}'s", None,
                            "give files of one logger, with one input timing")
        if not r.time[0] > before.time[-1]:
            raise DataError(f"{r.source}: its first time {clock.text(r.time[0])} does not go on from the last time "
                            f"of {before.source} ({clock.text(before.time[-1])})", None,
                            "name the files so that they sort in time order; files that overlap are not one run")
    if sum(len(r.time) * (1 + len(r.inputs) + len(r.measurements) + len(r.states) + len(r.parameters))
           for r in parts) > MAX_VALUES:
        raise DataError(f"{source}: more than {MAX_VALUES} numbers in its files together", None,
                        "give fewer files at once")

    def joined(group: str) -> dict[str, np.ndarray]:
        return {k: np.concatenate([getattr(r, group)[k] for r in parts]) for k in getattr(first, group)}

    modes = None if first.modes is None else np.concatenate([r.modes for r in parts])
    return Run(np.concatenate([r.time for r in parts]), joined("inputs"), joined("measurements"), joined("states"),
               joined("parameters"), first.header, source, modes)


def parse_run(text: str, name: str = "<csv>", reading: Reading | None = None) -> Run:
    """Parse the text of a run file; ``name`` (the run's ``source``) is used in errors."""
    return _parse(io.StringIO(text, newline="\n"), name, reading)


class _Lines:
    """The lines of a run file that hold CSV (column names, then rows), one
    at a time from ``stream`` (bytes, decoded strictly, or text), each at
    most ``MAX_LINE`` characters; the ``#`` comment lines go to ``header``
    and blank lines are skipped, both counted and bounded. ``number`` is the
    number of the line last read (from 1)."""

    def __init__(self, stream: IO, name: str, endless: bool = False):
        self.stream = stream
        self.name = name
        #: a stream read for as long as it goes on (a monitor's): no bound on the bytes read, and the bounds on
        #: comment and blank lines hold between two rows, not over the whole stream (:attr:`header`)
        self.endless = endless
        self.number = 0
        self.offset = 0  # bytes (characters, for text) read so far
        #: the comment lines read (endless: those since the row before the last one; :meth:`since`)
        self.header: list[str] = []
        self.dropped = 0  # comment lines no longer held (endless)
        self._mark = 0  # the comment lines read when the last row came (endless)
        self.named = False  # whether the column names were read
        self.blank = 0
        self.length = 0  # of the line last returned
        self.ended = True  # whether it had its end of line (the last line of a file may not: still being written)

    def __iter__(self):
        return self

    def __next__(self) -> str:
        while True:
            raw = self.stream.readline(MAX_LINE + 1)
            if not raw:
                raise StopIteration
            self.number += 1
            if len(raw) > MAX_LINE and raw[-1:] not in ("\n", b"\n"):
                raise self.error(f"line is {self._rest(raw)} characters long", "give one sample per line, "
                                 "numbers only")
            start = self.offset
            self.offset += len(raw)
            if self.offset > MAX_RUN_BYTES and not self.endless:
                raise DataError(f"{self.name}: more than {MAX_RUN_BYTES} bytes", None,
                                "split the run into shorter records")
            if isinstance(raw, bytes):
                try:
                    line = raw.decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise self.error(f"not UTF-8 text (byte {start + exc.start} is 0x{raw[exc.start]:02x})", _FIX) \
                        from None
            else:
                line = raw
            if self.number == 1 and line.startswith("\ufeff"):  # a byte-order mark, as a spreadsheet saves it
                line = line[1:]
            if line.startswith("#"):
                if self.comments - (self._mark if self.endless else 0) == MAX_COMMENT_LINES:
                    raise self.error(f"more than {MAX_COMMENT_LINES} comment lines", "a run's header is a few "
                                     "# lines (bgc simulate writes 5): remove the others")
                text = line.rstrip("\r\n")
                if len(text) > MAX_COMMENT:
                    raise self.error(f"a comment line of {len(text)} characters, more than {MAX_COMMENT}",
                                     "keep each # line of the header short")
                self.header.append(text[2:] if text.startswith("# ") else text[1:])
            elif not line.strip():
                self.blank += 1
                if self.blank > MAX_BLANK_LINES:
                    raise self.error(f"more than {MAX_BLANK_LINES} blank lines", "remove the blank lines")
            else:
                self.length = len(line)
                self.ended = line.endswith("\n")
                if self.endless and self.named:  # a row: the comment lines before the last one were read with it
                    cut = self._mark - self.dropped
                    del self.header[:cut]
                    self.dropped += cut
                    self._mark, self.blank = self.comments, 0
                self.named = True  # (the first line that is no comment: the column names)
                return line

    def miscounted(self, fields: int, width: int) -> DataError:
        """The error for a row of ``fields`` fields where the columns are
        ``width``: the line last read; one without its end of line (the
        file's last, a row the logger was still writing) says so."""
        if fields < width and not self.ended:
            return self.error(f"{fields} fields, expected {width}: the file's last line, without its end of line "
                              "(a row the logger was still writing?)", "read the file once the row is complete, or "
                              "follow it as it grows: bgc monitor --follow takes each row when its line ends")
        return self.error(f"{fields} fields, expected {width}", "give every row one value per column")

    @property
    def comments(self) -> int:
        """The comment lines read so far (those forgotten too)."""
        return self.dropped + len(self.header)

    def since(self, count: int) -> list[str]:
        """The comment lines read after the first ``count`` of them (endless:
        those still held, every one since the row before the last)."""
        return self.header[max(count - self.dropped, 0):]

    def take_back(self) -> None:
        """The last comment line read, as if it had not been read (a row
        refused after it: the line is read again before the next one)."""
        self.header.pop()
        self._mark = min(self._mark, self.comments)

    def _rest(self, head) -> int:
        """The length in characters of a line too long to keep: ``head`` and
        the rest of it, read in blocks and counted, not kept."""
        decoder = codecs.getincrementaldecoder("utf-8")("replace") if isinstance(head, bytes) else None
        count = len(decoder.decode(head)) if decoder else len(head)
        while True:
            block = self.stream.readline(MAX_LINE)
            if not block:
                break
            ends = block[-1:] in ("\n", b"\n")
            if ends:
                block = block[:-1]
            count += len(decoder.decode(block)) if decoder else len(block)
            if ends or count > MAX_RUN_BYTES:  # a stream without an end of line ends the count too
                break
        return count

    def error(self, what: str, fix: str) -> DataError:
        return DataError(f"{self.name}:{self.number}: {what}", None, fix)


class RowReader:
    """The rows of a run as they arrive on ``stream`` (a file another
    program appends to, a pipe): the column names are read and checked
    first (``columns``; ``header``: the ``#`` lines before them), then each
    iteration gives one row's numbers (empty or nan: NaN) and its line
    number; a malformed row is a :class:`~bgc.errors.DataError` naming the
    line. Whether the times increase is the reader's caller's to check (the
    diagnoser's :class:`~bgc.data.sampler.Sampler`)."""

    def __init__(self, stream: IO, name: str, reading: Reading | None = None):
        self.name = name
        self.lines = _Lines(stream, name, endless=True)
        self.reader = csv.reader(self.lines)
        self.layout = _columns(self.reader, self.lines, name, reading or Reading())
        #: bgc's names of the columns each row gives, ``time`` first
        self.columns = self.layout.names
        self.header = tuple(self.lines.header)

    def __iter__(self):
        layout, lines = self.layout, self.lines
        while True:
            fields = _next(self.reader, lines)
            if fields is None:
                return
            if len(fields) != layout.width:
                raise lines.miscounted(len(fields), layout.width)
            if lines.length > MAX_FIELD:
                _fields(fields, lines)
            values = layout.row(fields, lines)
            for v, c in zip(values, self.columns):
                if math.isinf(v):
                    raise lines.error(f"{v} in column {printable(c)} is not a finite number",
                                      "write finite numbers (empty or nan: not measured)")
            yield layout.scaled(values), lines.number

    @property
    def model(self) -> str | None:
        """The model the header says made the run (``model NAME: ...``), if any."""
        return Run(np.zeros(0), {}, {}, {}, {}, self.header).model


@dataclass(frozen=True, slots=True)
class _Layout:
    """How a file's fields become a run's columns: bgc's ``names`` (``time``
    first), the file's field ``index`` of each, the file's ``width``, each
    column's ``scale`` and ``offset`` (a column map's), the seconds in one of
    the model's time units (ISO timestamps; None: a unit bgc does not know)."""

    names: list[str]
    index: list[int]
    width: int
    scale: np.ndarray
    offset: np.ndarray
    seconds_per_unit: float | None = 1.0
    time_unit: str | None = None
    #: whether a scale or an offset is not 1 or 0 (decided once, not per row)
    scaling: bool = False
    #: the file's column names, as its header line has them
    header: tuple[str, ...] = ()

    def row(self, fields: list[str], lines: _Lines) -> list[float]:
        """One row's numbers (its fields as the file has them), in bgc's column order, unscaled."""
        if tuple(fields) == self.header:
            raise lines.error("the column names again, within the file (a logger that restarted and wrote its "
                              "header anew?): a file has one header line",
                              "delete that line, or start a new file there (a folder of a logger's files reads "
                              "as one run, each file with its header)")
        out = [_number(fields[j], c, lines) for j, c in zip(self.index[1:], self.names[1:])]
        return [self.time(fields[self.index[0]], lines), *out]

    def time(self, text: str, lines: _Lines) -> float:
        """A time cell: a number, or an ISO 8601 timestamp in the model's unit."""
        seconds = iso_seconds(text)
        if seconds is None:
            return _number(text, "time", lines)
        if self.seconds_per_unit is None:
            raise lines.error(f"an ISO time, and the model's time unit {printable(repr(self.time_unit))} is not one "
                              "bgc converts to", "declare time_unit: s (or ms, min, h, day) in the model, or give "
                              "times as numbers")
        return seconds / self.seconds_per_unit

    def scaled(self, values: list[float]) -> list[float]:
        if not self.scaling:
            return values
        return [float(v * a + b) for v, a, b in zip(values, self.scale, self.offset)]


def _columns(reader, lines: _Lines, name: str, reading: Reading) -> _Layout:
    """The column names, checked: ``time`` (first, unless a column map names
    the logger's), each once, each prefixed or mapped."""
    cols = _next(reader, lines)
    if cols is None:
        raise DataError(f"{name}: no data", None, "write it with bgc simulate")
    first_line = lines.number
    _fields(cols, lines)
    where = f"{name}:{first_line}"
    sep = next((c for c in ";\t|" if c in cols[0]), None) if len(cols) == 1 else None  # one column of it all
    if sep is not None:
        raise DataError(f"{where}: the column names are separated by {sep!r}, not by commas: bgc reads "
                        "comma-separated files (a decimal point, not a comma)", None,
                        "export the logger's file with commas between the fields and points in the numbers")
    mapping = reading.columns
    if mapping is None and cols and sum(c != "time" and not bgc_name(c) for c in cols) > 1:
        raise reading.foreign_columns(cols, where)
    if mapping is None and (not cols or cols[0] != "time"):
        raise DataError(f"{where}: the first column must be 'time', not {printable(repr(cols[0]))}"
                        if cols else f"{where}: no column names", None,
                        "name it time, or give a column map whose time: names the logger's time column "
                        f"({spelled('columns=FILE', '--columns FILE')}; docs/format.md, section 9)"
                        if cols else "write the run with bgc simulate")
    if len(cols) > MAX_COLUMNS:
        raise DataError(f"{where}: {len(cols)} columns, more than {MAX_COLUMNS}", None,
                        "give the model's inputs, sensors, states and parameters only")
    seen: set[str] = set()
    for c in cols:
        if c in seen:
            raise DataError(f"{where}: column {printable(repr(c))} appears twice", None, "give each column once")
        seen.add(c)
    names = mapping.names(cols, reading, where) if mapping is not None else list(cols)
    out: list[str] = []
    index: list[int] = []
    scale: list[float] = []
    offset: list[float] = []
    taken: dict[str, str] = {}
    for j, (c, n) in enumerate(zip(cols, names)):
        if n is None:
            continue
        if n != "time" and not bgc_name(n):
            raise reading.unknown_column(c, cols, where)
        if n in taken:
            raise DataError(f"{where}: columns {printable(repr(taken[n]))} and {printable(repr(c))} are both "
                            f"{printable(n)}", None, "map one logger column to each of bgc's names")
        taken[n] = c
        entry = mapping.entry(c) if mapping is not None else None
        at = 0 if n == "time" else len(out) + 1
        out.insert(at, n)
        index.insert(at, j)
        scale.insert(at, entry.scale if entry is not None else 1.0)
        offset.insert(at, entry.offset if entry is not None else 0.0)
    scales, offsets = np.array(scale), np.array(offset)
    return _Layout(out, index, len(cols), scales, offsets, reading.seconds_per_unit, reading.time_unit,
                   bool(np.any(scales != 1.0) or np.any(offsets != 0.0)), tuple(cols))


def _parse(stream: IO, name: str, reading: Reading | None = None) -> Run:
    """A run from the lines of ``stream`` (one csv reader over them, the rows
    into growing arrays), checked by :func:`check_run`."""
    lines = _Lines(stream, name)
    reader = csv.reader(lines)
    layout = _columns(reader, lines, name, reading or Reading())
    cols = layout.names
    width = len(cols)
    most = MAX_VALUES // (width + 1)  # the rows' numbers and their line numbers
    rows = max(1, _BLOCK // width)  # a block's rows
    data = np.empty((min(rows, most), width))
    numbers = np.empty(len(data), dtype=np.int64)
    n = 0
    block: list[list[float]] = []  # rows waiting to be copied into the arrays, with their line numbers
    at: list[int] = []
    plain = layout.index == list(range(layout.width))
    try:
        for fields in reader:
            if len(fields) != layout.width:
                raise lines.miscounted(len(fields), layout.width)
            if lines.length > MAX_FIELD:
                _fields(fields, lines)
            picked = fields if plain else [fields[j] for j in layout.index]
            try:
                if "_" in "".join(picked):  # float() reads 1_0 as 10: a number of Python's, not of a run file
                    raise ValueError
                block.append([float(v) for v in picked])
            except ValueError:
                block.append(layout.row(fields, lines))
            at.append(lines.number)
            if len(block) == rows:
                data, numbers, n = _store(data, numbers, n, block, at, most, lines)
    except csv.Error as exc:
        raise lines.error(f"not CSV: {printable(str(exc))}", "write the run with bgc simulate") from None
    data, numbers, n = _store(data, numbers, n, block, at, most, lines)
    if n == 0:
        raise DataError(f"{name}: the run has no data rows, only column names", None, "record at least one sample")
    data.resize((n, width), refcheck=False)
    numbers.resize(n, refcheck=False)
    if layout.scaling:
        data *= layout.scale
        data += layout.offset
    run = check_run(run_of(cols, data, tuple(lines.header), name), numbers, layout.time_unit)
    if reading is not None and reading.modes and run.modes is not None:
        beyond = np.isfinite(run.modes) & (run.modes > len(reading.modes))
        if beyond.any():
            k = int(np.argmax(beyond))
            raise no_mode(f"{name}:{int(numbers[k])}", float(run.modes[k]), reading.model, reading.modes)
    return run


def no_mode(where: str, mode: float, model: str, modes) -> DataError:
    """The error of a row whose mode (a number) is none of ``model``'s ``modes`` (their names, in order)."""
    return DataError(f"{where}: mode {mode:g} is no mode of {model} (1 to {len(modes)}: {', '.join(modes)})", None,
                     "give each row's mode as its number in the model's order, 1 for the first")


def run_of(columns: list[str], data: np.ndarray, header: tuple[str, ...], name: str) -> Run:
    """The run of a table whose columns (``time`` first, then prefixed
    names) are those of ``data`` (rows x columns)."""
    groups: dict[str, dict[str, np.ndarray]] = {p: {} for p in PREFIXES}
    modes = None
    for j, c in enumerate(columns[1:], start=1):
        if c == MODE:
            modes = data[:, j]
            continue
        prefix, _, rest = c.partition(":")
        groups[prefix][rest] = data[:, j]
    return Run(data[:, 0], groups["u"], groups["y"], groups["x"], groups["theta"], header, name, modes)


def _store(data: np.ndarray, numbers: np.ndarray, n: int, block: list, at: list, most: int,
           lines: _Lines) -> tuple[np.ndarray, np.ndarray, int]:
    """Copy the rows of ``block`` (their line numbers ``at``) into the arrays
    after their first ``n`` rows, growing them (in place, by a quarter) up
    to ``most`` rows; ``block`` and ``at`` are emptied."""
    end = n + len(block)
    if end > len(data):
        if end > most:
            width = data.shape[1]
            raise DataError(f"{lines.name}:{at[most - n]}: more than {most} rows of {width} column"
                            f"{'s' if width > 1 else ''} ({MAX_VALUES} numbers)", None,
                            "split the run into shorter records")
        grown = min(max(len(data) + len(data) // 4, end), most)  # a quarter more: little unused at the end
        data.resize((grown, data.shape[1]), refcheck=False)
        numbers.resize(grown, refcheck=False)
    if block:
        data[n:end] = block
        numbers[n:end] = at
    block.clear()
    at.clear()
    return data, numbers, end


def _next(reader, lines: _Lines) -> list[str] | None:
    """The reader's next row (None at the end), a CSV error located."""
    try:
        return next(reader)
    except StopIteration:
        return None
    except csv.Error as exc:
        raise lines.error(f"not CSV: {printable(str(exc))}", "write the run with bgc simulate") from None


def _fields(fields: list[str], lines: _Lines) -> None:
    longest = max(map(len, fields), default=0)
    if longest > MAX_FIELD:
        raise lines.error(f"a field of {longest} characters", "a field holds one number or one column name")


#: What loggers and spreadsheets write in a cell for a reading not taken (compared without case or spaces),
#: read as an empty cell: NaN.
MISSING = frozenset({"na", "n/a", "#n/a", "nan", "null", "none", "-", "--", "---"})


def _number(text: str, column: str, lines: _Lines) -> float:
    """A cell's number: empty, or one of :data:`MISSING`, is NaN (not measured)."""
    if not text.strip() or text.strip().lower() in MISSING:
        return math.nan
    try:
        if "_" in text:
            raise ValueError
        return float(text)
    except ValueError:
        raise lines.error(f"{printable(repr(text[:40]))} in column {printable(column)} is not a number",
                          "write numbers only (empty, nan or NA: not measured)") from None


def check_run(run: Run, lines: np.ndarray | None = None, time_unit: str | None = None) -> Run:
    """``run`` as the runtime takes it, or a :class:`~bgc.errors.DataError`
    naming its ``source`` (and with ``lines``, the line number of each row
    in its file, the line): at least one row; the time finite and strictly
    increasing; each column of ``inputs``, ``measurements``, ``states`` and
    ``parameters`` a 1-D array of numbers (integers or floats) as long as
    the time, finite or NaN (not measured: an infinite value is an error);
    names non-empty text; ``header`` lines of text, bounded as a file's.
    Returns the run with every array as float64 (no copy when it is one).
    ``time_unit``: the model's, by which an error writes the times as the
    diagnosis does (:class:`~bgc.data.clock.Clock`: a logger's absolute
    times as ISO 8601).

    >>> t = np.array([0.1, 0.2, 0.2])
    >>> check_run(Run(t, {}, {"f2": np.ones(3)}, {}, {}, ()))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bgc.errors.DataError: <Run from Python>, index 2: time 0.2 does not increase (the row before has 0.2) (...)
    """
    source = printable(run.source) if isinstance(run, Run) and isinstance(run.source, str) else PYTHON_SOURCE
    if not isinstance(run, Run):
        raise DataError(f"{source}: a {type(run).__name__}, not a bgc.data.runs.Run", None,
                        "build a Run, or read one with bgc.data.runs.read_run")

    def at(k: int) -> str:
        return f"{source}:{int(lines[k])}" if lines is not None else f"{source}, index {k}"

    header = run.header
    if not isinstance(header, (tuple, list)) or not all(isinstance(h, str) for h in header):
        raise DataError(f"{source}: the header is not a tuple of text lines", None, "give header=('model NAME: ...',)")
    if len(header) > MAX_COMMENT_LINES or any(len(h) > MAX_COMMENT for h in header):
        raise DataError(f"{source}: the header has more than {MAX_COMMENT_LINES} lines or a line of more than "
                        f"{MAX_COMMENT} characters", None, "keep the header to a few short lines")
    t = _array(run.time, "time", None, source)
    T = len(t)
    if T == 0:
        raise DataError(f"{source}: the run has no data rows, only column names", None, "record at least one sample")
    bad = ~np.isfinite(t)
    if bad.any():
        k = int(np.argmax(bad))
        raise DataError(f"{at(k)}: time {float(t[k])!r} is not a finite number", None, "give every row its time")
    if T > 1:
        step = np.diff(t)
        if not np.all(step > 0):
            k = int(np.argmax(step <= 0)) + 1
            clock = Clock.of(t[:1], time_unit)
            raise DataError(f"{at(k)}: time {clock.text(t[k])} does not increase (the row before has "
                            f"{clock.text(t[k - 1])})", None, "sort the rows by time, one row per sample")
    groups = []
    for prefix, group in (("u", run.inputs), ("y", run.measurements), ("x", run.states), ("theta", run.parameters)):
        if not isinstance(group, Mapping):
            raise DataError(f"{source}: the {prefix}:* columns are a {type(group).__name__}, not a dict of name to "
                            "array", None, f"give e.g. {{'NAME': values}} for the {prefix}:NAME columns")
        out = {}
        for key, values in group.items():
            if not isinstance(key, str) or not key:
                raise DataError(f"{source}: column name {printable(repr(key))[:60]} under {prefix}:* is not a "
                                "non-empty text", None, "name each column by text, e.g. 'f2'")
            column = f"{prefix}:{key}"
            v = _array(values, column, T, source)
            infinite = np.isinf(v)
            if infinite.any():
                k = int(np.argmax(infinite))
                raise DataError(f"{at(k)}: {float(v[k])!r} in column {printable(column)} is not a finite number", None,
                                "write a finite number, or leave the cell empty or nan where the sensor was not read")
            out[key] = v
        groups.append(out)
    modes = None
    if run.modes is not None:
        modes = _array(run.modes, MODE, T, source)
        wrong = np.isfinite(modes) & ((modes < 1) | (modes != np.round(modes))) | np.isinf(modes)
        if wrong.any():
            k = int(np.argmax(wrong))
            raise DataError(f"{at(k)}: {float(modes[k])!r} in column mode is not a mode's number", None,
                            "write the mode's number: 1 for the first mode the model lists, 2 for the second, ...")
    return Run(t, *groups, tuple(header), run.source if isinstance(run.source, str) else source, modes)


def _array(values, column: str, length: int | None, source: str) -> np.ndarray:
    """A column as a 1-D float64 array, or an error naming it."""
    try:
        a = np.asarray(values)
    except (TypeError, ValueError) as exc:  # ragged nested sequences, objects NumPy refuses
        raise DataError(f"{source}: column {printable(column)} is not an array of numbers "
                        f"({printable(str(exc))[:80]})", None, "give a 1-D NumPy array of floats") from None
    if a.dtype.kind not in "iuf":
        raise DataError(f"{source}: column {printable(column)} holds {a.dtype} values, not numbers", None,
                        "give a 1-D NumPy array of floats, NaN where not measured")
    if a.ndim != 1:
        raise DataError(f"{source}: column {printable(column)} has shape {a.shape}, not one value per row", None,
                        "give a 1-D array, one value per time")
    if length is not None and len(a) != length:
        raise DataError(f"{source}: column {printable(column)} has {len(a)} values, the time {length}", None,
                        "give each column one value per time")
    return a.astype(float, copy=False)
