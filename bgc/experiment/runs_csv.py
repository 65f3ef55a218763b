"""``runs.csv``: one row per run, appended as each completes; read back line by line, every intact
row kept and a line that cannot be read set aside in ``runs.unread-N.csv`` (never a row lost)."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import (ExperimentError, OutputError,
    printable)

if TYPE_CHECKING:
    pass

from .campaign_file import Campaign


#: The columns of ``runs.csv``, in order (docs/experiments.md defines each).
COLUMNS = (
    "id", "index", "group", "model", "scenario", "fault", "kind", "magnitude", "onset", "ambiguous", "filter",
    "particles", "noise", "process_noise", "measurement_noise", "seed", "steps", "status", "failure", "rt",
    "mse", "nmse", "mse_states", "ct", "detected", "detection_time", "delay", "false_alarm", "verdict",
    "diagnosed", "candidates", "right", "in_candidates", "estimate", "low", "high", "est_error", "parameter",
    "parameter_truth", "param_error", "covers", "refine", "separable", "rivals", "separation", "detectability",
    "target", "diagnosed_target", "expected",
)


_INT = {"index", "particles", "seed", "steps"}


_BOOL = {"ambiguous", "detected", "false_alarm", "right", "in_candidates", "covers", "refine", "separable",
         "expected"}


_FLOAT = {"magnitude", "onset", "process_noise", "measurement_noise", "rt", "mse", "nmse", "ct", "detection_time",
          "delay", "estimate", "low", "high", "est_error", "parameter", "parameter_truth", "param_error",
          "separation", "detectability"}


#: Free-text columns: written on one line, neutralised against spreadsheet formulas (:func:`format_cell`).
_TEXT = frozenset(COLUMNS) - _INT - _BOOL - _FLOAT


RUNS = "runs.csv"


#: Lines of ``runs.csv`` that cannot be read are set aside in ``runs.unread-N.csv`` (N: the first free number).
UNREAD = "runs.unread-{n}.csv"


#: A text cell starting with one of these is a formula to a spreadsheet: ``runs.csv`` writes it after a
#: ``'`` (OWASP's rule against CSV injection), and so a text starting with ``'`` itself, to read back exactly.
_FORMULA = ("=", "+", "-", "@", "\t", "\r", "'")


@dataclass(frozen=True, slots=True)
class RunsFile:
    """What :func:`read_runs` found in a ``runs.csv``: the rows it read, and
    the lines it could not read (``unread``: their bytes as in the file,
    ``unread_lines``: how many)."""

    rows: tuple[dict[str, Any], ...]
    unread: bytes
    unread_lines: int


# ------------------------------------------------------------------ rows
def format_value(value: Any) -> str:
    """A value as ``runs.csv`` writes it (before :func:`format_cell`'s guard
    of text cells): a number as its shortest repr, a bool as true/false."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):  # a NumPy float's repr is np.float64(...): print the number
        return "nan" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def format_cell(column: str, value: Any) -> str:
    """The cell of ``column`` in ``runs.csv``. A text cell is one line
    (:func:`bgc.errors.printable`), so each row is one line of the file, and
    one that starts with ``= + - @``, a tab or a carriage return (a formula
    to a spreadsheet: OWASP's CSV-injection rule) is written after a ``'``,
    as is one that starts with ``'`` itself, so that :func:`parse_value`
    reads every one back exactly. Numeric cells are never touched (they may
    be negative).

    >>> format_cell("model", "=cmd|' -C calc'!A0.yaml"), format_cell("magnitude", -0.5)
    ("'=cmd|' -C calc'!A0.yaml", '-0.5')
    >>> parse_value("model", format_cell("model", "'quoted")), parse_value("model", format_cell("model", "-x"))
    ("'quoted", '-x')
    """
    text = format_value(value)
    if column in _TEXT:
        text = printable(text)
        if text.startswith(_FORMULA):
            text = "'" + text
    return text


def parse_value(column: str, text: str) -> Any:
    """A cell of ``runs.csv`` read back (:func:`format_cell` in reverse).

    Raises
    ------
    ValueError
        The cell is not a value of its column.
    """
    if text == "":
        return None
    if column in _INT:
        return int(text)
    if column in _FLOAT:
        return float(text)
    if column in _BOOL:
        low = text.lower()  # a spreadsheet saves TRUE and FALSE
        if low not in ("true", "false"):
            raise ValueError(text)
        return low == "true"
    return text[1:] if text.startswith("'") else text


def csv_header(c: Campaign) -> str:
    from ..output.artifacts import MARK

    buf = io.StringIO()
    buf.write(f"# {MARK} experiment from {printable(c.source)}: campaign {printable(c.name)}, one row per run\n")
    csv.writer(buf, lineterminator="\n").writerow(COLUMNS)
    return buf.getvalue()


def csv_row(row: dict[str, Any]) -> str:
    """One line of ``runs.csv`` (every cell on one line: :func:`format_cell`)."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([format_cell(k, row.get(k)) for k in COLUMNS])
    return buf.getvalue()


def read_runs(path: Path) -> RunsFile:
    """The rows of a ``runs.csv`` bgc wrote, read line by line (bgc writes a
    row per line), and the lines that cannot be read.

    Every intact row is read, whatever surrounds it. A line is unread when
    it is not UTF-8, does not parse as one CSV record of the header's
    columns (an unclosed quote, a cell over the csv module's field limit),
    holds a value its column cannot take, or has no newline at its end (the
    last line of a campaign interrupted while writing it). A byte-order mark
    at the start, Windows line ends, ``TRUE``/``FALSE`` and blank lines (a
    spreadsheet's save) are read. When the header is not a header of
    ``runs.csv`` (of this bgc or of one with fewer columns), no line can be
    read and every line is unread. A missing file has no rows.
    """
    from ..output.artifacts import MARK

    rows: list[dict[str, Any]] = []
    unread: list[bytes] = []
    header: tuple[str, ...] | None = None
    try:
        f = open(path, "rb")
    except OSError:
        return RunsFile((), b"", 0)
    with f:
        for number, raw in enumerate(f):
            data = raw[3:] if number == 0 and raw.startswith(b"\xef\xbb\xbf") else raw
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                unread.append(raw)
                continue
            if not text.strip():
                continue  # a blank line holds nothing
            if not text.endswith("\n"):  # cut short by an interruption
                unread.append(raw)
                continue
            body = text[:-1].removesuffix("\r")
            try:
                records = list(csv.reader([body], strict=True))
            except csv.Error:  # an unclosed quote, a cell over the field limit, ...
                unread.append(raw)
                continue
            if len(records) != 1:
                unread.append(raw)
                continue
            values = records[0]
            if header is None:
                if values and values[0].startswith("#") and MARK in body:  # bgc's comment line
                    continue
                if values and tuple(values) == COLUMNS[:len(values)] and "status" in values:
                    header = tuple(values)
                else:
                    unread.append(raw)
                continue
            if len(values) != len(header):
                unread.append(raw)
                continue
            try:
                row = dict.fromkeys(COLUMNS)
                row.update({k: parse_value(k, v) for k, v in zip(header, values)})
            except ValueError:
                unread.append(raw)
                continue
            row["refine"] = bool(row["refine"])
            rows.append(row)
    return RunsFile(tuple(rows), b"".join(unread), len(unread))


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``runs.csv`` (:func:`read_runs`, without its unread lines)."""
    return list(read_runs(path).rows)


def set_aside(folder: Path, data: bytes) -> Path:
    """Write the unread lines of ``runs.csv`` into a new file beside it
    (:data:`UNREAD`, the first free number): bgc never overwrites it."""
    from ..output import artifacts

    for n in range(1, 100_000):
        path = folder / UNREAD.format(n=n)
        if path.exists() or path.is_symlink():
            continue
        try:
            return artifacts.write_new(path, data)
        except OutputError:  # made meanwhile by another process: the next number
            continue
    raise ExperimentError(f"{printable(str(folder))} holds too many {UNREAD.format(n='N')} files", None,
                          "move them away, then run the campaign again")
