"""Data as loggers write them: a column map from a logger's column names to
bgc's, and times as numbers or ISO 8601 timestamps.

A logger names its columns its own way (``time,force_N,vel1_mps``); a run
file of bgc names them ``time``, ``u:NAME``, ``y:NAME`` (:mod:`bgc.data.runs`).
A **column map** is a small YAML file that says which is which, with an
optional scale and offset to the model's units (the value bgc reads is
``scale * logged + offset``), and which columns to leave out::

    time: stamp               # the logger's time column (default: time)
    columns:
      force_N: u:F            # the logger's column: bgc's name
      vel1_mps: y:v1
      load_kN: {name: y:F2, scale: 1000}   # kN -> N
      temp_C: skip            # a column the model does not read

A column the map does not name keeps its name (a file may mix the logger's
columns with bgc's). A time cell is a number in the model's time unit, or
an ISO 8601 timestamp (``2026-03-01T08:00:00.25Z``, ``2026-03-01 09:00:00+01:00``;
without a zone: UTC), read as seconds since 1970-01-01 UTC and converted to
the model's time unit (:data:`SECONDS`).

:class:`Reading` is what a reader of run files is told about the model
(the columns it reads, its time unit) and the map: the reader's errors then
list the columns the model expects and the map line that would fix them.

>>> m = parse_map("columns:\\n  force_N: u:F\\n  load_kN: {name: y:F2, scale: 1000}\\n", "map.yaml")
>>> m.names(["time", "force_N", "load_kN"], Reading())
['time', 'u:F', 'y:F2']
>>> iso_seconds("1970-01-01T00:01:00.5Z")
60.5
"""

from __future__ import annotations

import datetime
import difflib
import math
import stat
from dataclasses import dataclass
from pathlib import Path

import yaml

from ..arguments import spelled
from ..errors import DataError, printable

#: A column map larger than this is refused (a map of a thousand columns is about 40 kB).
MAX_MAP_BYTES = 1_000_000
#: Seconds per unit of time, for the time units a model may declare (``time_unit``) that ISO timestamps
#: convert to; a model without a time unit takes seconds.
SECONDS = {"s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0, "ms": 1e-3, "min": 60.0, "minute": 60.0,
           "minutes": 60.0, "h": 3600.0, "hr": 3600.0, "hour": 3600.0, "hours": 3600.0, "d": 86400.0,
           "day": 86400.0, "days": 86400.0}
#: What a column may be mapped to besides a bgc name: left out.
SKIP = "skip"
#: The prefixes of bgc's column names: inputs, measurements, true states, true parameters.
PREFIXES = ("u", "y", "x", "theta")
#: The column of a run file that holds the plant's mode (a model with modes): the mode's number.
MODE = "mode"
_EPOCH = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)


@dataclass(frozen=True, slots=True)
class Entry:
    """One logger column: its name in the file, bgc's name for it (None:
    left out), ``scale`` and ``offset`` (bgc reads ``scale * logged +
    offset``), and the map file's line that says so."""

    column: str
    name: str | None
    scale: float = 1.0
    offset: float = 0.0
    line: int = 0


@dataclass(frozen=True, slots=True)
class ColumnMap:
    """A logger's columns to bgc's: ``time`` (the logger's time column),
    ``entries`` (the other columns it names), ``source`` (the map file)."""

    time: str = "time"
    entries: tuple[Entry, ...] = ()
    source: str = "<column map>"
    time_line: int = 0

    def entry(self, column: str) -> Entry | None:
        for e in self.entries:
            if e.column == column:
                return e
        return None

    def names(self, columns: list[str], reading: Reading, where: str = "") -> list[str | None]:
        """bgc's name of each of a file's ``columns`` (None: left out),
        the time column first; every column the map names must be there."""
        if self.time not in columns:
            raise DataError(f"{where or 'the data'}: no column {printable(repr(self.time))}, the time column "
                            f"{self.source}" + (f":{self.time_line}" if self.time_line else "") + " names", None,
                            f"the columns are {_listed(columns)}: name one of them under time:")
        for e in self.entries:
            if e.column not in columns:
                raise DataError(f"{self.source}:{e.line}: column {printable(repr(e.column))} is not in "
                                f"{where or 'the data'}", None, f"its columns are {_listed(columns)}: map those")
            if reading.expected and e.name and e.name[:2] in ("u:", "y:") and e.name not in reading.expected:
                kind = "sensor" if e.name.startswith("y:") else "input"
                close = difflib.get_close_matches(e.name, reading.expected, n=1)
                hint = f"did you mean {close[0]}? " if close else ""
                raise DataError(f"{self.source}:{e.line}: column {printable(repr(e.column))} is mapped to "
                                f"{printable(e.name)}, and the model has no {kind} {printable(e.name[2:])}", None,
                                f"{hint}map it to one of {_listed(list(reading.expected))}, or write "
                                f"'{printable(e.column)}: skip'")
        out: list[str | None] = []
        for c in columns:
            if c == self.time:
                out.append("time")
                continue
            e = self.entry(c)
            out.append(c if e is None else e.name)
        return out


@dataclass(frozen=True, slots=True)
class Reading:
    """What a reader of run files knows besides the file: the column map
    (None: none), the columns the model reads (``expected``: ``u:NAME`` and
    ``y:NAME``, for the messages), and the seconds in one of the model's
    time units (ISO timestamps are converted to it; None: the model's unit
    is not one of :data:`SECONDS`, and a timestamp is refused); a model
    with modes: their names (``modes``) and the model's (``model``), for a
    mode column's cells."""

    columns: ColumnMap | None = None
    expected: tuple[str, ...] = ()
    seconds_per_unit: float | None = 1.0
    time_unit: str | None = None
    #: a model with modes: its modes' names in order (a mode column's cell is a number from 1 to their count)
    modes: tuple[str, ...] = ()
    model: str = ""

    def unknown_column(self, column: str, columns: list[str], where: str) -> DataError:
        """The error of a column that is neither bgc's nor mapped: the
        columns the model reads, and the map line that would fix it."""
        there = set(columns)
        if self.columns is not None:
            there |= {e.name for e in self.columns.entries if e.name}
        line = f"{column}: {self._free(there)}"
        return DataError(f"{where}: column {printable(repr(column))} is not time, u:NAME, y:NAME, x:NAME or "
                         f"theta:NAME{self._reads()}", None,
                         f"map it in a column map ({spelled('columns=FILE', '--columns FILE')}): under columns:, a line "
                         f"'{printable(line)}', or '{printable(column)}: skip'; docs/format.md, section 9")

    def foreign_columns(self, columns: list[str], where: str) -> DataError:
        """The error of a file without a column map whose time column is not
        ``time`` first, or with several columns that are not bgc's: all of
        them, what the model reads, and the map that would fix them."""
        first = columns[0] if columns and columns[0] != "time" else None
        foreign = [c for c in columns if c != "time" and not bgc_name(c)]
        others = [c for c in foreign if c != first]
        example = []
        if first is not None:
            example.append(f"'time: {printable(first)}'")
        if others:
            example.append(f"under columns: a line per column, e.g. '{printable(others[0])}: "
                           f"{self._free(set(columns))}' or '{printable(others[0])}: skip'")
        return DataError(f"{where}: {len(foreign)} columns are not bgc's ({_listed(foreign)}){self._reads()}", None,
                         f"give a column map with {spelled('columns=FILE', '--columns FILE')} (docs/format.md, section 9): "
                         + " and ".join(example))

    def _free(self, there: set[str]) -> str:
        """The first column the model reads that is not ``there`` (a map line's example target)."""
        return next((c for c in self.expected if c not in there), "u:NAME")

    def _reads(self) -> str:
        return f"; the model reads {_listed(['time', *self.expected])}" if self.expected else ""


def bgc_name(column: str) -> bool:
    """Whether ``column`` is a name of bgc's run files (``u:NAME`` and the like, ``mode``)."""
    prefix, colon, rest = column.partition(":")
    return bool(colon and prefix in PREFIXES and rest) or column == MODE


def _listed(columns) -> str:
    shown = [printable(str(c)) for c in list(columns)[:12]]
    more = len(list(columns)) - len(shown)
    return ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def unit_seconds(time_unit: str | None) -> float | None:
    """Seconds in one ``time_unit`` (a model's; None: seconds), None when bgc does not know the unit."""
    if time_unit is None:
        return 1.0
    return SECONDS.get(time_unit.strip().lower())


def iso_seconds(text: str) -> float | None:
    """Seconds since 1970-01-01 UTC of an ISO 8601 timestamp (a date and a
    time; without a zone: UTC), None when ``text`` is not one."""
    t = text.strip()
    if len(t) < 10 or not t[:4].isdigit() or t[4:5] != "-":
        return None
    try:
        when = datetime.datetime.fromisoformat(t[:-1] + "+00:00" if t[-1:] in ("Z", "z") else t)
    except ValueError:
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.timezone.utc)
    return (when - _EPOCH).total_seconds()


def read_map(path: str | Path) -> ColumnMap:
    """Read a column map file (see the module docstring); every problem is
    one :class:`~bgc.errors.DataError` naming the file and line."""
    name = printable(str(path))
    p = Path(path)
    fix = "give a column map: a YAML file (docs/format.md, section 9)"
    try:
        info = p.stat()
        if not stat.S_ISREG(info.st_mode):
            raise DataError(f"{name}: not a regular file", None, fix)
        if info.st_size > MAX_MAP_BYTES:
            raise DataError(f"{name}: file is {info.st_size} bytes, more than {MAX_MAP_BYTES}", None,
                            "a column map names a logger's columns: keep it small")
        raw = p.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{name}: no such file", None, f"check the path of {spelled('columns=', '--columns')}") from None
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {printable(exc.strerror or str(exc))}", None, fix) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{name}: not UTF-8 text (byte {exc.start})", None, "save the map as UTF-8") from None
    return parse_map(text, name)


def parse_map(text: str, name: str = "<column map>") -> ColumnMap:
    """A column map from its YAML ``text`` (``name``: named by its errors)."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        raise DataError(f"{name}:{mark.line + 1 if mark else 1}: YAML syntax error: "
                        f"{printable(str(exc.problem or exc.context))}", None, "fix the YAML at this line") from None
    except (yaml.YAMLError, ValueError) as exc:
        raise DataError(f"{name}: not YAML: {printable(str(exc))[:80]}", None, "fix the YAML") from None
    example = "write e.g. 'columns: {force_N: u:F}'"
    if node is None:
        raise DataError(f"{name}: the column map is empty", None, example)
    if not isinstance(node, yaml.MappingNode):
        raise DataError(f"{name}:{node.start_mark.line + 1}: a column map is a mapping with time: and columns:",
                        None, example)
    time, time_line, entries = "time", 0, []
    for key, value in node.value:
        at = f"{name}:{key.start_mark.line + 1}"
        k = key.value if isinstance(key, yaml.ScalarNode) else None
        if k == "time":
            if not isinstance(value, yaml.ScalarNode) or not value.value.strip():
                raise DataError(f"{at}: time: names the logger's time column", None, "write e.g. 'time: stamp'")
            time, time_line = value.value, key.start_mark.line + 1
        elif k == "columns":
            if not isinstance(value, yaml.MappingNode):
                raise DataError(f"{at}: columns: maps each logger column to bgc's name", None, example)
            entries = [_entry(c, v, name) for c, v in value.value]
        else:
            raise DataError(f"{at}: unknown key {printable(repr(k))[:60]}", None, "a column map has time: and columns:")
    seen: dict[str, int] = {}
    targets: dict[str, int] = {}
    for e in entries:
        if e.column in seen or e.column == time:
            raise DataError(f"{name}:{e.line}: column {printable(repr(e.column))} is mapped twice"
                            + (" (it is the time column)" if e.column == time else f" (line {seen[e.column]})"),
                            None, "map each column once")
        seen[e.column] = e.line
        if e.name is not None:
            if e.name in targets:
                raise DataError(f"{name}:{e.line}: two columns map to {printable(e.name)} (line {targets[e.name]})",
                                None, "map one logger column to each of bgc's names")
            targets[e.name] = e.line
    return ColumnMap(time, tuple(entries), name, time_line)


def _entry(key, value, name: str) -> Entry:
    line = key.start_mark.line + 1
    at = f"{name}:{line}"
    if not isinstance(key, yaml.ScalarNode) or not key.value:
        raise DataError(f"{at}: a logger column's name is text", None, "write e.g. 'force_N: u:F'")
    column = key.value
    scale, offset = 1.0, 0.0
    if isinstance(value, yaml.ScalarNode):
        target = value.value
    elif isinstance(value, yaml.MappingNode):
        fields = {k.value: v for k, v in value.value if isinstance(k, yaml.ScalarNode)}
        unknown = sorted(set(fields) - {"name", "scale", "offset"})
        if unknown:
            raise DataError(f"{at}: unknown key {printable(repr(unknown[0]))[:60]} of column "
                            f"{printable(repr(column))}", None, "a column takes name, scale and offset")
        if "name" not in fields or not isinstance(fields["name"], yaml.ScalarNode):
            raise DataError(f"{at}: column {printable(repr(column))} has no name:", None,
                            f"write e.g. '{printable(column)}: {{name: y:F2, scale: 1000}}'")
        target = fields["name"].value
        scale = _number(fields.get("scale"), 1.0, f"{at}: scale of {printable(repr(column))}")
        offset = _number(fields.get("offset"), 0.0, f"{at}: offset of {printable(repr(column))}")
        if scale == 0:
            raise DataError(f"{at}: scale of {printable(repr(column))} is 0", None, "give the factor to the "
                            "model's unit (e.g. 1000 for kN -> N)")
    else:
        raise DataError(f"{at}: column {printable(repr(column))} maps to bgc's name or skip", None,
                        "write e.g. 'force_N: u:F'")
    if target == SKIP:
        return Entry(column, None, line=line)
    prefix, colon, rest = target.partition(":")
    if not (colon and prefix in ("u", "y") and rest):
        raise DataError(f"{at}: {printable(repr(target))[:60]} is not u:NAME, y:NAME or skip", None,
                        "map an input to u:NAME and a sensor to y:NAME (the model's names)")
    return Entry(column, target, scale, offset, line)


def _number(node, default: float, what: str) -> float:
    if node is None:
        return default
    try:
        value = float(node.value) if isinstance(node, yaml.ScalarNode) else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise DataError(f"{what} is not a finite number", None, "give a number, e.g. 1000")
    return value
