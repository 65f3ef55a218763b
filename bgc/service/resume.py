"""The monitor's state on disk (``bgc monitor --state DIR``): a restart
takes the diagnosis up where the saved state left it.

One file, ``DIR/monitor.state``, replaced whole each time it is saved (a
new file beside it, flushed to the disk, then renamed over it: a kill at any
moment leaves the last whole state). It holds, after the first line
:data:`MAGIC`:

- one line of JSON, the header: the format, what the state is valid for (the
  identity: bgc's version and the digest of its code, the model file's
  digest, the noise levels, the prior scale, the backend, the diagnosis's
  options, the checkpoint period, the data's columns) and where the input
  stands (the rows taken, the last row's time, the last checkpoint's time);
- the rows taken so far, as a NumPy array file (``allow_pickle=False``):
  the final report is made of them, also when the files they came from are
  gone;
- the diagnoser's state (:meth:`~bgc.diagnosis.state.DiagnoserState.to_bytes`,
  read back by an unpickler that makes nothing but a state's types).

A state whose identity differs from the monitor's now, of another format,
or not whole is refused in one line, never replaced: the user removes it or
gives another folder.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import BgcError, printable

#: The first line of a state file.
MAGIC = b"bgc-monitor-state\n"
#: The file's format; another is refused.
FORMAT = 1
#: The state file's name in the folder.
NAME = "monitor.state"
#: Where a new state is written before it replaces the old one.
PARTIAL = ".monitor.state.partial"


@dataclasses.dataclass(frozen=True)
class Saved:
    """A state read back: where the input stood, the rows taken, the diagnoser's state."""

    rows: np.ndarray
    last_time: float
    last_check: float | None
    diagnoser: object  # a DiagnoserState


def identity(session, options, checkpoint: float | None, columns: list[str]) -> dict:
    """What a state is valid for: the same bgc, model, noise, prior scale,
    backend, options, checkpoint period and columns."""
    from ..api.cache import code_digest

    text = Path(session.model).read_bytes() if Path(session.model).is_file() else str(session.model).encode()
    return {"bgc": __version__, "code": code_digest(), "model": hashlib.sha256(text).hexdigest(),
            "noise": [None if n is None else float(n) for n in session.noise], "prior_scale": session.prior_scale,
            "backend": session.backend, "options": _plain(dataclasses.asdict(options)),
            "checkpoint": checkpoint, "columns": list(columns)}


def _plain(value):
    """``value`` with tuples as lists and numbers as JSON has them (what a header read back holds)."""
    return json.loads(json.dumps(value, default=repr))


def folder(path: str | Path) -> Path:
    """The state folder, made when missing; refused when it is no folder."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise BgcError(f"--state {printable(str(p))}: not a folder", None,
                       "give a folder for the monitor's state (it is made when missing)")
    p.mkdir(parents=True, exist_ok=True)
    for name in (NAME, PARTIAL):
        f = p / name
        if f.exists() and (not f.is_file() or f.stat().st_size and _head(f) != MAGIC):
            raise BgcError(f"--state {printable(str(p))}: {name} there is not a state bgc wrote", None,
                           "give another folder (bgc does not replace a file it did not write)")
    return p


def _head(path: Path) -> bytes:
    with open(path, "rb") as f:
        return f.read(len(MAGIC))


def save(where: Path, ident: dict, rows: list, last_time: float, last_check: float | None, d) -> None:
    """Write the state of diagnoser ``d`` after ``rows``, atomically."""
    header = {"format": FORMAT, "identity": ident, "rows": len(rows), "last_time": last_time,
              "last_check": last_check}
    table = io.BytesIO()
    width = len(ident["columns"])
    np.save(table, np.asarray(rows, dtype=float).reshape(len(rows), width), allow_pickle=False)
    data = b"".join([MAGIC, json.dumps(header).encode("utf-8"), b"\n", table.getvalue(), d.to_state().to_bytes()])
    tmp = where / PARTIAL
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, where / NAME)
    try:  # the rename itself on the disk
        fd = os.open(where, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass


def load(where: Path, ident: dict) -> Saved | None:
    """The state saved in folder ``where`` (None: none yet), checked
    against the monitor's ``ident``; refused in one line when it is not
    this monitor's or not whole."""
    from ..diagnosis.state import DiagnoserState

    path = where / NAME
    if not path.exists():
        return None
    data = path.read_bytes()
    fix = f"start afresh with another --state folder, or move {path.name} away"
    if not data.startswith(MAGIC):
        raise BgcError(f"{printable(str(path))}: not a state bgc wrote", None, fix)
    try:
        head, _, rest = data[len(MAGIC):].partition(b"\n")
        header = json.loads(head.decode("utf-8"))
        table = io.BytesIO(rest)
        rows = np.load(table, allow_pickle=False)
        state = DiagnoserState.from_bytes(rest[table.tell():])
    except (ValueError, UnicodeDecodeError, OSError, BgcError) as exc:
        raise BgcError(f"{printable(str(path))}: the state cannot be read ({printable(str(exc).splitlines()[0])})",
                       None, fix) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise BgcError(f"{printable(str(path))}: a state of another format", None, fix)
    saved = header.get("identity", {})
    differ = [k for k in ident if saved.get(k) != ident[k]]
    if differ:
        raise BgcError(f"{printable(str(path))}: the state was saved with another {_what(differ[0])}", None,
                       f"monitor with the {_what(differ[0])} it was saved with, or {fix}")
    if rows.ndim != 2 or rows.shape != (header.get("rows"), len(ident["columns"])):
        raise BgcError(f"{printable(str(path))}: the state's rows are not whole", None, fix)
    return Saved(rows, float(header["last_time"]), header.get("last_check"), state)


def _what(key: str) -> str:
    return {"bgc": "bgc version", "code": "bgc (its code differs)", "model": "model file", "noise": "noise levels",
            "prior_scale": "prior scale", "backend": "backend", "options": "options",
            "checkpoint": "--checkpoint", "columns": "data columns"}.get(key, key)
