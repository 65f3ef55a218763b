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

import dataclasses
import io
import math
from collections.abc import Callable, Iterable
from pathlib import Path

from .. import arguments
from ..api.reports import DiagnosisReport
from ..api.session import Session, open as open_session
from ..api.simulate import Simulation
from ..data import runs
from ..diagnosis.options import DiagnosisOptions
from ..errors import ArgumentTypeError, ArgumentValueError, DataError, printable
from .monitor import STATE_EVERY

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
        memory (without ``episodes``): the rows before it are diagnosed, their
        report is the exception's ``report``; a malformed first row (no row
        before it) raises without one.
    """
    func = "bgc.monitor"
    if not isinstance(model, Session):
        arguments.path(func, "model", model)
    for name, value in (("checkpoint", checkpoint), ("rearm", rearm), ("keep", keep)):
        if value is not None:
            arguments.real(func, name, value, 0.0, math.inf, f"a time above 0 in the model's unit, e.g. {name}=10")
    if state is not None:
        arguments.path(func, "state", state)
    arguments.integer(func, "state_every", state_every, 1, "is below 1", f"state_every={STATE_EVERY}")
    if state is None and state_every != STATE_EVERY:
        raise ArgumentValueError(f"{func}: state_every without a state folder", None,
                                 "give state='monitor-state', or drop state_every")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if episodes and checkpoint is None:
        raise ArgumentValueError(f"{func}: episodes=True without a checkpoint: a fault is isolated there", None,
                                 "give checkpoint=10, e.g.")
    if rearm is not None and not episodes:
        raise ArgumentValueError(f"{func}: rearm applies to episodes", None, "give episodes=True, or drop rearm")
    if exclude_faulty_sensor and checkpoint is None:
        raise ArgumentValueError(f"{func}: exclude_faulty_sensor acts at checkpoints", None, "give checkpoint=10, e.g.")
    options = _options(func, options, keep, filter=filter, particles=particles, seed=seed)
    session = model if isinstance(model, Session) else open_session(
        model, process_noise=process_noise, measurement_noise=measurement_noise)
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


__all__ = ["monitor"]
