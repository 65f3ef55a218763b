"""Recorded runs: the CSV that ``bgc simulate`` writes and the filters read.

Format: ``#`` comment lines (a header saying which model and fault made the
run), then a CSV table with a ``time`` column and columns prefixed by what they
hold: ``u:NAME`` inputs (held over the step that ends at the row's time),
``y:NAME`` measurements, ``x:NAME`` true states, ``theta:NAME`` the true value
of a faulty parameter. A measurement left empty or ``nan`` was not taken.

A run file is data from outside: it is size-checked before it is read (and
must be a regular file: not a FIFO or a device), decoded strictly, and every
problem is a one-line :class:`~bgc.errors.DataError` naming the file and line.
"""

from __future__ import annotations

import csv
import io
import math
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError, printable

#: A run file larger than this is refused before it is read (a 300-step run of
#: the RO plant is about 60 kB).
MAX_RUN_BYTES = 256_000_000
#: Longest field: a number's text is far shorter.
MAX_FIELD = 1000
PREFIXES = ("u", "y", "x", "theta")


@dataclass(frozen=True, slots=True)
class Run:
    """A run read back from CSV: columns by prefix, arrays of shape (T,)."""

    time: np.ndarray
    inputs: dict[str, np.ndarray]
    measurements: dict[str, np.ndarray]
    states: dict[str, np.ndarray]
    parameters: dict[str, np.ndarray]
    header: tuple[str, ...]

    @property
    def model(self) -> str | None:
        """The model the header says made the run (``model NAME: ...``), if any."""
        for h in self.header:
            if h.startswith("model ") and ":" in h:
                return h.split(":")[0][len("model "):]
        return None


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
    columns = [("time", run.time)]
    for prefix, group in (("u", run.inputs), ("y", run.measurements), ("x", run.states), ("theta", run.parameters)):
        columns += [(f"{prefix}:{name}", values) for name, values in group.items()]
    return to_csv(run.header, columns)


def read_run(path: str | Path) -> Run:
    """Read a run file (see the module docstring for the checks)."""
    name = printable(str(path))
    p = Path(path)
    try:
        info = p.stat()
    except FileNotFoundError:
        raise DataError(f"{name}: no such file", None, "give a CSV written by bgc simulate") from None
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {exc.strerror}", None, "give a CSV written by bgc simulate") from None
    if not stat.S_ISREG(info.st_mode):
        raise DataError(f"{name}: not a regular file", None, "give a CSV file written by bgc simulate")
    if info.st_size > MAX_RUN_BYTES:
        raise DataError(f"{name}: file is {info.st_size} bytes, more than {MAX_RUN_BYTES}", None,
                        "split the run into shorter records")
    try:
        with open(p, "rb") as f:
            raw = f.read(MAX_RUN_BYTES + 1)
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {exc.strerror}", None, "give a CSV written by bgc simulate") from None
    if len(raw) > MAX_RUN_BYTES:
        raise DataError(f"{name}: file is more than {MAX_RUN_BYTES} bytes", None, "split the run into shorter records")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise DataError(f"{name}:{line}: not UTF-8 text (byte {exc.start} is 0x{raw[exc.start]:02x})", None,
                        "give a CSV written by bgc simulate") from None
    return parse_run(text, name)


def parse_run(text: str, name: str = "<csv>") -> Run:
    """Parse the text of a run file; ``name`` is used in errors."""
    header: list[str] = []
    body: list[tuple[int, str]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if line.startswith("#"):
            header.append(line[2:] if line.startswith("# ") else line[1:])
        elif line.strip():
            body.append((number, line))
    if not body:
        raise DataError(f"{name}: no data", None, "write it with bgc simulate")
    first_line, first = body[0]
    cols = _row(first, name, first_line)
    if not cols or cols[0] != "time":
        raise DataError(f"{name}:{first_line}: the first column must be 'time', not {printable(repr(cols[0]))}"
                        if cols else f"{name}:{first_line}: no column names", None,
                        "write the run with bgc simulate")
    seen: set[str] = set()
    for c in cols:
        if c in seen:
            raise DataError(f"{name}:{first_line}: column {printable(repr(c))} appears twice", None,
                            "give each column once")
        seen.add(c)
        prefix, colon, rest = c.partition(":")
        if c != "time" and not (colon and prefix in PREFIXES and rest):
            raise DataError(f"{name}:{first_line}: column {printable(repr(c))} is not time, u:NAME, y:NAME, x:NAME "
                            "or theta:NAME", None, "name the columns as bgc simulate does")
    if len(body) < 2:
        raise DataError(f"{name}: the run has no data rows, only column names", None, "record at least one sample")
    data = np.empty((len(body) - 1, len(cols)))
    for i, (number, line) in enumerate(body[1:]):
        fields = _row(line, name, number)
        if len(fields) != len(cols):
            raise DataError(f"{name}:{number}: {len(fields)} fields, expected {len(cols)}", None,
                            "give every row one value per column")
        for j, v in enumerate(fields):
            try:
                data[i, j] = float(v) if v.strip() else math.nan
            except ValueError:
                raise DataError(f"{name}:{number}: {printable(repr(v[:40]))} in column {printable(cols[j])} is not "
                                "a number", None, "write numbers only (empty or nan: not measured)") from None
    t = data[:, 0]
    if not np.all(np.isfinite(t)):
        raise DataError(f"{name}: a time value is not a finite number", None, "give every row its time")
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        k = int(np.argmax(np.diff(t) <= 0)) + 1
        raise DataError(f"{name}:{body[k + 1][0]}: time {t[k]:g} does not increase", None,
                        "sort the rows by time, one row per sample")
    groups: dict[str, dict[str, np.ndarray]] = {p: {} for p in PREFIXES}
    for j, c in enumerate(cols[1:], start=1):
        prefix, _, rest = c.partition(":")
        groups[prefix][rest] = data[:, j]
    return Run(t, groups["u"], groups["y"], groups["x"], groups["theta"], tuple(header))


def _row(line: str, name: str, number: int) -> list[str]:
    if len(line) > MAX_FIELD * 1000:
        raise DataError(f"{name}:{number}: line is {len(line)} characters long", None,
                        "give one sample per line, numbers only")
    try:
        fields = next(csv.reader([line]))
    except csv.Error as exc:
        raise DataError(f"{name}:{number}: not CSV: {printable(str(exc))}", None, "write the run with bgc simulate") \
            from None
    for f in fields:
        if len(f) > MAX_FIELD:
            raise DataError(f"{name}:{number}: a field of {len(f)} characters", None,
                            "a field holds one number or one column name")
    return fields
