"""``bgc.monitor``: ``bgc monitor`` from Python, its fault log in the report
(the service wing's door, as :mod:`bgc.experiment.public` is the campaigns').

>>> import bgc
>>> sim = bgc.simulate("models/circuit.yaml", "R2:abrupt:1.2@2-8,12", seed=2, steps=340)
>>> report = bgc.monitor("models/circuit.yaml", sim, checkpoint=1, episodes=True, particles=300)
>>> [(e.action, e.parameter) for e in report.fault_log]
[('accommodated', 'R2'), ('ended', 'R2'), ('accommodated', 'R2')]
>>> report.intermittent["R2"]["spans"]
((2.0, 8.0), (12.0, None))
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import io
import math
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

from .. import arguments
from ..api.reports import DiagnosisReport
from ..api.session import Session, open as open_session
from ..api.simulate import Simulation
from ..data import runs
from ..diagnosis.options import DiagnosisOptions
from ..errors import ArgumentTypeError, ArgumentValueError, DataError, printable
from .monitor import STATE_EVERY

#: The event lines a :class:`Monitor` keeps for :attr:`Monitor.events` (the last ones).
EVENTS_KEPT = 10_000
#: The filters' settings :func:`monitor` takes by name, at their defaults.
_DEFAULT = DiagnosisOptions()


class _Lines:
    """An iterable of text lines (or a :class:`Simulation`'s run file) as the
    byte stream the monitor reads, one line per read: a generator's lines
    are diagnosed as it yields them."""

    def __init__(self, lines: Iterable[str]):
        self._lines = iter(lines)

    def readline(self, limit: int = -1) -> bytes:
        for line in self._lines:
            return (line if line.endswith("\n") else line + "\n").encode("utf-8")
        return b""


def monitor(model: str | Path | Session, data, *, checkpoint: float | None = None, episodes: bool = False,
            rearm: float | None = None, exclude_faulty_sensor: bool = False, keep: float | None = None,
            state: str | Path | None = None, state_every: int = STATE_EVERY, filter: str = _DEFAULT.filter,
            particles: int = _DEFAULT.particles, seed: int = _DEFAULT.seed, process_noise: float | None = None,
            measurement_noise: float | None = None,
            options: DiagnosisOptions | None = None, events: Callable[[str], None] | None = None) -> DiagnosisReport:
    """Diagnose ``data`` row by row as ``bgc monitor`` does (its commands'
    options by their names; docs/commands.md, "Diagnose a stream"), and
    return the report of the data's end.

    Parameters
    ----------
    model : str, os.PathLike or Session
        The model file, or a :class:`Session` of it (its noise levels apply).
    data : str, os.PathLike, Simulation or iterable of str
        A run file (a logger's CSV), a folder or a glob pattern of daily
        files (read in the order of their names), a :class:`Simulation`,
        or the CSV's lines as they come (a generator: each row is diagnosed
        as it is yielded; the first line the column names).
    checkpoint : float, optional
        While hypotheses are tracked, a diagnosis of the data so far every
        this long (the model's time unit).
    episodes : bool
        With ``checkpoint``: go on after a verdict and keep a fault log (a
        fault isolated is accommodated, a fault accommodated that goes away
        is named gone: an intermittent one). ``rearm``: close an episode not
        decided this long after its alarm. The log is the report's
        :attr:`DiagnosisReport.fault_log`.
    exclude_faulty_sensor : bool
        With ``checkpoint``: take a sensor isolated as faulty out.
    keep : float, optional
        While watching, the record kept (default: 1024 steps).
    state : str or os.PathLike, optional
        A folder the monitor's state is saved in every ``state_every`` rows;
        a state found there is taken up (a restart goes on where it stopped).
    filter, particles, seed, options
        The filters, as for :func:`diagnose` (``options``: all of them; then
        ``filter``, ``particles`` and ``seed`` are refused, and ``keep``, when
        given, replaces the options' own).
    process_noise, measurement_noise : float, optional
        Relative noise levels the filters assume (default: the model's).
    events : callable, optional
        ``events(line)`` gets each event as the monitor prints it, as it happens.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range.
    DataError, BgcError
        A malformed row, or the stream past what the diagnosis may hold in
        memory (without ``episodes``; a gap longer than that while watching is
        bridged, and with an alarm in progress refused): the rows before it
        are diagnosed, their report is the exception's ``report``; a
        malformed first row (no row before it) raises without one.
    """
    func = "bgc.monitor"
    if state is not None:
        arguments.path(func, "state", state)
    arguments.integer(func, "state_every", state_every, 1, "is below 1", f"state_every={STATE_EVERY}")
    if state is None and state_every != STATE_EVERY:
        raise ArgumentValueError(f"{func}: state_every without a state folder", None,
                                 "give state='monitor-state', or drop state_every")
    session, options = _checked(func, model, checkpoint, episodes, rearm, exclude_faulty_sensor, keep,
                                process_noise, measurement_noise, options, filter=filter, particles=particles,
                                seed=seed)
    stream, name = _stream(func, data)
    from . import monitor as service

    try:
        report, failure = service.monitor(session, stream, name, options, say=events or (lambda line: None),
                                          checkpoint=checkpoint, exclude_faulty=exclude_faulty_sensor,
                                          state=state, state_every=state_every, episodes=episodes, rearm=rearm)
    finally:
        if hasattr(stream, "close"):
            stream.close()
    if failure is not None:
        failure.report = report
        raise failure
    return report


class Monitor:
    """``bgc monitor`` stepped from Python: the rows fed one at a time
    (:meth:`feed`), the events as they happen and the fault log as it grows,
    a repair said from Python (:meth:`repaired`), and the report of the rows
    so far (:meth:`report`). The same diagnosis as :func:`monitor` of the same
    rows, event for event (its arguments by the same names; no state folder:
    a program that steps the monitor keeps it alive itself).

    ``columns``: the run file's column names (``time`` first; a model with
    modes may have ``mode``), as a list or as the CSV's header line; ``name``:
    the rows' source in messages. The inputs' timing is the options' (a run
    file's header could say it: ``options=DiagnosisOptions(input_timing=...)``).
    For example::

        m = bgc.Monitor("models/circuit.yaml", ["time", "u:V", "y:f2", "y:f6", "y:e11"],
                        checkpoint=1, episodes=True)
        for t, v, f2, f6, e11 in rows:           # the plant's rows as they come
            for line in m.feed([t, v, f2, f6, e11]):
                print(line)                          # "t = 2: alarm on f6: ...", an episode closed
        m.repaired("R2")                             # the operator's word, before the next row
        m.fault_log                                  # EpisodeClosed and Repaired events so far
    """

    def __init__(self, model: str | Path | Session, columns: str | Iterable[str], *, checkpoint: float | None = None,
                 episodes: bool = False, rearm: float | None = None, exclude_faulty_sensor: bool = False,
                 keep: float | None = None, filter: str = _DEFAULT.filter, particles: int = _DEFAULT.particles,
                 seed: int = _DEFAULT.seed, process_noise: float | None = None, measurement_noise: float | None = None,
                 options: DiagnosisOptions | None = None, name: str = "<rows>"):
        func = "bgc.Monitor"
        names = list(columns) if isinstance(columns, Iterable) and not isinstance(columns, (str, bytes)) else None
        if isinstance(columns, str):
            header = columns.rstrip("\r\n")
        elif names is not None and all(isinstance(c, str) for c in names):
            header = ",".join(names)
        else:
            raise ArgumentTypeError(f"{func}: columns is {type(columns).__name__}", None,
                                    "give the column names, ['time', 'u:V', 'y:v_C'], or the CSV's header line")
        session, options = _checked(func, model, checkpoint, episodes, rearm, exclude_faulty_sensor, keep,
                                    process_noise, measurement_noise, options, filter=filter, particles=particles,
                                    seed=seed)
        from . import monitor as service

        self._queue: collections.deque[bytes] = collections.deque([(header + "\n").encode("utf-8")])
        self._stream = _Queue(self._queue)
        self._said: collections.deque[str] = collections.deque(maxlen=EVENTS_KEPT)
        self._count = 0  # the event lines said so far
        self._run = service._Monitor(session, self._stream, name, options, self._say, checkpoint, None,
                                     exclude_faulty_sensor, None, None, STATE_EVERY, rearm if episodes else None,
                                     episodes)
        self._rows = iter(self._run.reader)
        self._pending: tuple[str, ...] | None = None  # a repair said since the last row
        self._report: DiagnosisReport | None = None

    @property
    def columns(self) -> tuple[str, ...]:
        """bgc's names of the columns each row gives, ``time`` first."""
        return tuple(self._run.columns)

    def feed(self, row) -> tuple[str, ...]:
        """Take one row: a CSV line, or its numbers in :attr:`columns`' order
        (a sequence), or by column name (a mapping with ``time``; another
        column left out: not measured). Returns the event lines the row made
        (an alarm, a checkpoint's verdict, an episode closed), as ``bgc
        monitor`` prints them. A malformed row, or one whose time is not after
        the last row's, is a one-line DataError naming it, and the monitor
        goes on with the next row (a repair said before it still waits)."""
        func = "bgc.Monitor.feed"
        if self._report is not None:
            raise ArgumentValueError(f"{func}: the monitor has made its report", None,
                                     "open a new bgc.Monitor for more rows")
        line = self._line(func, row)
        self._queue.clear()
        if self._pending is not None:
            self._queue.append(_repair_line(self._pending))
        self._queue.append((line + "\n").encode("utf-8"))
        run, lines = self._run, self._run.reader.lines
        try:
            values, number = next(self._rows)
            t, last = values[0], run.rows_time
            if not math.isfinite(t) or (last is not None and not t > last):
                raise DataError(f"{printable(run.name)}:{number}: time {t!r} is not after the last row's "
                                f"({last!r})" if last is not None else f"{printable(run.name)}:{number}: time {t!r} "
                                "is not a number", None, "feed the rows in the order of their times")
        except DataError:  # the row is refused (a repair read with it waits for the next: not yet taken)
            if self._pending is not None and lines.header and lines.header[-1].startswith("repaired"):
                lines.take_back()
            self._queue.clear()
            self._rows = iter(run.reader)
            raise
        start = self._count
        run.row(values, number, contextlib.nullcontext())
        self._pending = None
        made = self._count - start
        return tuple(self._said)[-made:] if made else ()

    def _say(self, line: str) -> None:
        self._said.append(line)
        self._count += 1

    def _line(self, func: str, row) -> str:
        """A row as a CSV line (module :meth:`feed`'s three forms), its numbers checked."""
        if isinstance(row, str):
            line = row.rstrip("\r\n")
            if line.startswith("#") or not line.strip():
                raise ArgumentValueError(f"{func}: a comment or blank line is no row", None,
                                         "give a data row (say a repair with Monitor.repaired)")
            return line
        if isinstance(row, Mapping):
            unknown = sorted(set(row) - set(self._run.columns))
            if unknown:
                raise ArgumentValueError(f"{func}: no column {unknown[0]!r}", None,
                                         "name the columns: " + ", ".join(self._run.columns))
            if "time" not in row:
                raise ArgumentValueError(f"{func}: the row has no time", None, "give row['time']")
            values = [row.get(c) for c in self._run.columns]
        elif isinstance(row, Iterable) and not isinstance(row, (bytes, bytearray)):
            values = list(row)
        else:
            raise ArgumentTypeError(f"{func}: row is {type(row).__name__}", None,
                                    "give a CSV line, a sequence of numbers, or a mapping of column to number")
        try:
            return ",".join("" if isinstance(row, Mapping) and v is None else repr(float(v)) for v in values)
        except (TypeError, ValueError):
            raise ArgumentTypeError(f"{func}: the row holds something that is not a number", None,
                                    "give numbers (NaN: not measured)") from None

    def repaired(self, *parameters: str) -> None:
        """The operator says the plant was repaired (all the faults
        accommodated, or those of ``parameters``): it takes effect before the
        next row, as a ``# repaired`` line of the stream does (with
        ``episodes``: a monitor without them accommodates nothing)."""
        func = "bgc.Monitor.repaired"
        if self._run.log is None:
            raise ArgumentValueError(f"{func}: a monitor without episodes accommodates no fault to repair", None,
                                     "open the monitor with episodes=True")
        if not all(isinstance(p, str) and p.isidentifier() and len(p) <= 200 for p in parameters):
            raise ArgumentValueError(f"{func}: parameters are the model's names", None,
                                     "give names, e.g. m.repaired('R2'), or none for every fault accommodated")
        self._pending = tuple(sorted(set(self._pending or ()) | set(parameters))) \
            if parameters and self._pending != () else ()

    @property
    def events(self) -> tuple[str, ...]:
        """The event lines said so far, in order: the last ``EVENTS_KEPT`` of
        them (a monitor that runs for months keeps a bounded memory; the fault
        log keeps every episode)."""
        return tuple(self._said)

    @property
    def fault_log(self) -> tuple:
        """The closed episodes and repairs so far (with ``episodes``; else empty):
        :class:`~bgc.events.EpisodeClosed` and :class:`~bgc.events.Repaired`."""
        return tuple(self._run.log.log) if self._run.log is not None else ()

    def report(self) -> DiagnosisReport:
        """The report of the rows so far, as :func:`monitor` returns it at the
        data's end; the monitor takes no row after it (a second call gives the
        same report). A repair said after the last row is refused: it takes
        effect at a row."""
        if self._report is None:
            if self._pending is not None:
                raise ArgumentValueError("bgc.Monitor.report: a repair was said after the last row", None,
                                         "feed the row after the repair first: the repair takes effect at it")
            self._report = self._run.finish(self._stream)
        return self._report


def _repair_line(parameters: tuple[str, ...]) -> bytes:
    """The stream's comment line of a repair (:func:`bgc.service.episodes.repair_of` reads it)."""
    return f"# repaired{': ' + ', '.join(parameters) if parameters else ''}\n".encode("utf-8")


class _Queue:
    """The byte stream of a :class:`Monitor`: the lines fed, one per read (none: the end, for now)."""

    def __init__(self, queue):
        self._queue = queue

    def readline(self, limit: int = -1) -> bytes:
        return self._queue.popleft() if self._queue else b""


def _checked(func: str, model, checkpoint, episodes: bool, rearm, exclude_faulty_sensor: bool, keep, process_noise,
             measurement_noise, options, **filters) -> tuple[Session, DiagnosisOptions]:
    """The session and the diagnosis options of :func:`monitor` and
    :class:`Monitor`, their arguments checked (one-line errors naming them)."""
    if not isinstance(model, Session):
        arguments.path(func, "model", model)
    for name, value in (("checkpoint", checkpoint), ("rearm", rearm), ("keep", keep)):
        if value is not None:
            arguments.real(func, name, value, 0.0, math.inf, f"a time above 0 in the model's unit, e.g. {name}=10")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if episodes and checkpoint is None:
        raise ArgumentValueError(f"{func}: episodes=True without a checkpoint: a fault is isolated there", None,
                                 "give checkpoint=10, e.g.")
    if rearm is not None and not episodes:
        raise ArgumentValueError(f"{func}: rearm applies to episodes", None, "give episodes=True, or drop rearm")
    if exclude_faulty_sensor and checkpoint is None:
        raise ArgumentValueError(f"{func}: exclude_faulty_sensor acts at checkpoints", None, "give checkpoint=10, e.g.")
    options = _options(func, options, keep, **filters)
    session = model if isinstance(model, Session) else open_session(
        model, process_noise=process_noise, measurement_noise=measurement_noise)
    return session, options


def _options(func: str, options: DiagnosisOptions | None, keep: float | None, **filters) -> DiagnosisOptions:
    """The diagnosis options of :func:`monitor`: ``options``, or made of
    ``filters`` (``filter``, ``particles``, ``seed``), with ``keep``."""
    if options is None:
        arguments.integer(func, "particles", filters["particles"], 1, "is below 1", f"particles={_DEFAULT.particles}")
        arguments.integer(func, "seed", filters["seed"], 0, "is negative", f"seed={_DEFAULT.seed}")
        return DiagnosisOptions(**filters, keep=keep)
    if not isinstance(options, DiagnosisOptions):
        raise ArgumentTypeError(f"{func}: options is {type(options).__name__}, not DiagnosisOptions", None,
                                "give bgc.DiagnosisOptions(...), or leave options out")
    given = [name for name, value in filters.items() if value != getattr(_DEFAULT, name)]
    if given:
        raise ArgumentValueError(f"{func}: {given[0]} beside options: options holds the filters' settings", None,
                                 f"give DiagnosisOptions({given[0]}=...), or leave options out")
    return options if keep is None else dataclasses.replace(options, keep=keep)


def _stream(func: str, data):
    """(the byte stream the monitor reads, its name in messages) of ``data``."""
    if isinstance(data, Simulation):
        return _Lines(io.StringIO(runs.run_csv(data.run))), f"simulation of {data.scenario}"
    if isinstance(data, str) and "\n" in data:
        raise ArgumentTypeError(f"{func}: data is the CSV's text, not a path", None,
                                "give its lines, data=text.splitlines(keepends=True), or write it to a file")
    if isinstance(data, (str, Path)):
        from .monitor import Follow

        try:
            files = runs.run_files(str(data))
        except OSError as exc:
            raise DataError(f"{func}: data {printable(str(data))!r} cannot be read ({exc.strerror})", None,
                            "give a run file's path, a folder or a glob pattern of run files") from None
        if files is not None:  # a folder or a pattern: the files one after the other
            return Follow(runs.open_stream(str(files[0])), 0, path=str(files[0]), say=lambda line: None,
                          pattern=str(data)), str(data)
        return runs.open_stream(str(data)), str(data)
    if isinstance(data, (bytes, bytearray)) or not isinstance(data, Iterable):
        raise ArgumentTypeError(f"{func}: data is {type(data).__name__}", None,
                                "give a run file's path, a Simulation, or the CSV's lines (an iterable of str)")
    return _Lines(data), "<lines>"


__all__ = ["monitor", "Monitor"]
