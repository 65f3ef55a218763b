"""The monitor's state on disk (``bgc monitor --state DIR``): a restart
takes the diagnosis up where the saved state left it.

One file, ``DIR/monitor.state``, replaced whole each time it is saved (a
new file beside it, flushed to the disk, then renamed over it: a kill at any
moment leaves the last whole state). It holds, after the first line
:data:`MAGIC`:

- one line of JSON, the header: the format, what the state is valid for (the
  identity: bgc's version and the digest of its code, the model file's
  digest, the noise levels, the prior scale, the diagnosis's options but the
  processes it runs on (neither those nor the backend change a number), the
  checkpoint period, whether faulty sensors are taken out, the data's
  columns) and where the input stands (the rows taken, the last
  row's time, the last checkpoint's time, the sensors taken out so far);
- the rows the diagnoser took (since the last sensor was taken out), as a NumPy array file (``allow_pickle=False``):
  the final report is made of them, also when the files they came from are
  gone;
- the misfits the monitor said as the data came (dated: said at, the data's
  times), in the header, for the report of a record that forgot their data;
- the diagnoser's state (:meth:`~bgc.diagnosis.state.DiagnoserState.to_bytes`,
  read back by an unpickler that makes nothing but a state's types).

The header holds the SHA-256 of itself and the payload: a state whose
identity differs from the monitor's now, of another format, or changed or
cut anywhere is refused in one line, never replaced: the user removes it or
gives another folder.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import stat
from pathlib import Path

import numpy as np

from .. import __version__
from .. import events as ev
from ..diagnosis.options import UNBOUND
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
    #: the sensors the monitor took out before (``--exclude-faulty-sensor``): (sensor, finding, time, step)
    excluded: tuple = ()
    #: the fault log and the faults accommodated (``--episodes``: :meth:`bgc.service.episodes.Episodes.plain`)
    episodes: dict | None = None
    #: the stream's rows read to here, in all, and the first one's time (the report says them)
    stream: tuple = (0, None)
    #: the misfits said as the data came (:class:`~bgc.events.Mismatched`, dated: ``said`` and ``span``): those
    #: of the diagnosers before the one saved, and the saved one's
    misfits: tuple = ((), ())
    #: the gaps bridged so far (:class:`~bgc.events.Bridged`: began, time, steps, ran, settled, modes)
    bridged: tuple = ()


def identity(session, options, checkpoint: float | None, columns: list[str], exclude_faulty: bool = False,
             reading=None, episodes: bool = False, rearm: float | None = None) -> dict:
    """What a state is valid for: the same bgc, model, noise (a relative
    level of 1 is the model's), prior scale, options, checkpoint period,
    exclusion of faulty sensors, episodes and their re-arming, columns and
    what the column map does (``reading``'s, :func:`_mapping`). The
    backend is not part of it: both give the same numbers (their packages
    are checked against each other); nor are the processes the hypotheses
    run on (:data:`bgc.diagnosis.options.UNBOUND`)."""
    from ..api.cache import code_digest

    text = Path(session.model).read_bytes() if Path(session.model).is_file() else str(session.model).encode()
    return {"bgc": __version__, "code": code_digest(), "model": hashlib.sha256(text).hexdigest(),
            "noise": [1.0 if n is None else float(n) for n in session.noise], "prior_scale": session.prior_scale,
            "options": _plain({k: v for k, v in dataclasses.asdict(options).items() if k not in UNBOUND}),
            "column_map": hashlib.sha256(repr(_mapping(getattr(reading, "columns", None))).encode()).hexdigest(),
            "checkpoint": checkpoint, "exclude_faulty": bool(exclude_faulty), "episodes": bool(episodes),
            "rearm": rearm, "columns": list(columns)}


def _mapping(columns) -> tuple | None:
    """What a column map (:class:`~bgc.data.columns.ColumnMap`; None: none)
    does to the data: its time column and, per logger column, bgc's name,
    scale and offset; not where its file is or on which lines it says so (a
    comment added, ``0.00100`` for ``0.001``: the same map)."""
    if columns is None:
        return None
    return columns.time, tuple(sorted((e.column, e.name or "", e.scale, e.offset) for e in columns.entries))


def _plain(value):
    """``value`` with tuples as lists and numbers as JSON has them (what a header read back holds)."""
    return json.loads(json.dumps(value, default=repr))


def folder(path: str | Path) -> Path:
    """The state folder, made when missing; refused when it is no folder,
    or when a file of the state's names there is not one bgc wrote (a link
    included: bgc writes no file through a link)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise BgcError(f"--state {printable(str(p))}: not a folder", None,
                       "give a folder for the monitor's state (it is made when missing)")
    p.mkdir(parents=True, exist_ok=True)
    for name in (NAME, PARTIAL):
        f = p / name
        try:
            info = os.lstat(f)
        except FileNotFoundError:
            continue
        if not stat.S_ISREG(info.st_mode) or (info.st_size and _head(f) != MAGIC):
            raise BgcError(f"--state {printable(str(p))}: {name} there is not a state bgc wrote", None,
                           "give another folder (bgc does not replace a file it did not write)")
    return p


def _head(path: Path) -> bytes:
    with open(path, "rb") as f:
        return f.read(len(MAGIC))


def save(where: Path, ident: dict, rows: list, last_time: float, last_check: float | None, d,
         excluded: tuple = (), episodes: dict | None = None, stream: tuple = (0, None), misfits=((), ()),
         bridged: tuple = ()) -> None:
    """Write the state of diagnoser ``d`` after ``rows``, atomically
    (``excluded``: the sensors taken out before; ``episodes``: the fault
    log; ``stream``: the rows read in all and the first one's time;
    ``misfits``: those said so far, the earlier diagnosers' and the saved one's;
    ``bridged``: the gaps bridged so far;
    :class:`Saved`): a new
    file, made afresh (never through a link), flushed to the disk, renamed
    over the last state."""
    table = io.BytesIO()
    width = len(ident["columns"])
    np.save(table, np.asarray(rows, dtype=float).reshape(len(rows), width), allow_pickle=False)
    payload = table.getvalue() + d.to_state().to_bytes()
    header = {"format": FORMAT, "identity": ident, "rows": len(rows), "last_time": last_time,
              "last_check": last_check, "excluded": [list(e) for e in excluded], "episodes": episodes,
              "stream": list(stream), "misfits": [[_plain(dataclasses.asdict(m)) for m in part] for part in misfits],
              "bridged": [[e.began, e.time, e.steps, e.ran, e.settled, list(e.modes)] for e in bridged]}
    header["sha256"] = _digest(header, payload)
    data = b"".join([MAGIC, json.dumps(header).encode("utf-8"), b"\n", payload])
    tmp = where / PARTIAL
    try:
        info = os.lstat(tmp)
        if stat.S_ISREG(info.st_mode) and (not info.st_size or _head(tmp) == MAGIC):
            os.unlink(tmp)  # a save a kill cut short: bgc's own
    except FileNotFoundError:
        pass
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o644)
    with os.fdopen(fd, "wb") as f:
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
    this monitor's, or not whole (its checksum)."""
    from ..diagnosis.state import DiagnoserState

    path = where / NAME
    if not os.path.lexists(path):
        return None
    data = path.read_bytes()
    fix = f"start afresh with another --state folder, or move {path.name} away"
    where_ = printable(str(path))
    if not data.startswith(MAGIC):
        raise BgcError(f"{where_}: not a state bgc wrote", None, fix)
    head, newline, payload = data[len(MAGIC):].partition(b"\n")
    try:
        header = json.loads(head.decode("utf-8")) if newline else None
    except (ValueError, UnicodeDecodeError):
        header = None
    keys = {"format", "identity", "rows", "last_time", "sha256"}
    if not isinstance(header, dict) or not keys <= set(header) or not isinstance(header["identity"], dict):
        raise BgcError(f"{where_}: the state's header cannot be read", None, fix)
    if header["format"] != FORMAT:
        raise BgcError(f"{where_}: a state of another format", None, fix)
    if _digest(header, payload) != header["sha256"]:
        raise BgcError(f"{where_}: the state is not whole (its checksum differs)", None, fix)
    saved = header["identity"]
    differ = [k for k in ident if saved.get(k) != ident[k]]
    if differ:
        raise BgcError(f"{where_}: the state was saved with another {_what(differ[0])}", None,
                       f"monitor with the {_what(differ[0])} it was saved with, or {fix}")
    try:
        table = io.BytesIO(payload)
        rows = np.load(table, allow_pickle=False)
        state = DiagnoserState.from_bytes(payload[table.tell():])
        excluded = tuple((str(a), str(b), float(c), None if k is None else int(k))
                         for a, b, c, k in header.get("excluded", ()))
        last_time, last_check = float(header["last_time"]), header.get("last_check")
        read, first = header.get("stream", (0, None))
        stream = (int(read), None if first is None else float(first))
        earlier, now = header.get("misfits", ((), ()))
        misfits = (tuple(_misfit(m) for m in earlier), tuple(_misfit(m) for m in now))
        bridged = tuple(ev.Bridged(float(a), float(b), int(n), int(r), bool(rest[0]) if rest else False,
                                   tuple(rest[1]) if len(rest) > 1 else ())
                        for a, b, n, r, *rest in header.get("bridged", ()))
    except (ValueError, TypeError, EOFError, OSError, BgcError) as exc:
        raise BgcError(f"{where_}: the state cannot be read ({printable(str(exc).splitlines()[0])})", None,
                       fix) from None
    if rows.ndim != 2 or rows.shape != (header["rows"], len(ident["columns"])):
        raise BgcError(f"{where_}: the state's rows are not whole", None, fix)
    episodes = header.get("episodes")
    if episodes is not None and not isinstance(episodes, dict):
        raise BgcError(f"{where_}: the state's fault log cannot be read", None, fix)
    return Saved(rows, last_time, last_check if last_check is None else float(last_check), state, excluded,
                 episodes, stream, misfits, bridged)


def _misfit(plain: dict):
    """A misfit said (:class:`~bgc.events.Mismatched`) from the header's plain data; a
    ValueError or TypeError when it is not one."""
    from ..events import Mismatched

    if not isinstance(plain, dict) or not isinstance(plain.get("span"), list) or plain.get("said") is None:
        raise ValueError("a misfit said cannot be read")
    return Mismatched(**{k: tuple(tuple(x) if isinstance(x, list) else x for x in v) if isinstance(v, list) else v
                         for k, v in plain.items()})


def _digest(header: dict, payload: bytes) -> str:
    """The SHA-256 of the header (but its own digest) and the payload: a state changed anywhere is refused."""
    rest = {k: v for k, v in header.items() if k != "sha256"}
    return hashlib.sha256(json.dumps(rest).encode("utf-8") + b"\n" + payload).hexdigest()


def _what(key: str) -> str:
    return {"bgc": "bgc version", "code": "bgc (its code differs)", "model": "model file", "noise": "noise levels",
            "prior_scale": "prior scale", "column_map": "column map (--columns)", "options": "options",
            "checkpoint": "--checkpoint", "exclude_faulty": "--exclude-faulty-sensor", "episodes": "--episodes",
            "rearm": "--rearm",
            "columns": "data columns"}.get(key, key)
