"""``bgc monitor``: diagnose a plant's data as they arrive.

The rows of a CSV (as ``bgc simulate`` writes, or a plant's logger with the
same columns) are read one at a time from standard input or from a file,
which :class:`Follow` keeps reading as another program appends to it; each
row goes to the online diagnoser (:meth:`bgc.api.Session.diagnoser`), whose
events are handed to ``say`` as they happen. At the end of the input (or on
Ctrl-C, or after ``idle`` seconds without a new row) the diagnoser finishes
and the same report as ``bgc diagnose``'s is made.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import IO, Callable

import numpy as np

from . import api
from .errors import DataError, printable
from .runtime import events as ev
from .runtime import runs, track
from .runtime.diagnose import DiagnosisOptions


class Follow:
    """A file read as another program appends to it: :meth:`readline` waits
    for a whole line (polling every ``poll`` seconds) and ends the input
    (returns ``""``) after ``idle`` seconds without a new byte (None: never;
    Ctrl-C ends it then)."""

    def __init__(self, stream: IO[bytes], idle: float | None = None, poll: float = 0.1):
        self.stream, self.idle, self.poll = stream, idle, poll
        self.pending = b""

    def readline(self, limit: int = -1) -> bytes:
        waited = 0.0
        while True:
            chunk = self.stream.readline(limit - len(self.pending) if limit > 0 else -1)
            if chunk:
                waited = 0.0
                self.pending += chunk
                if self.pending.endswith(b"\n") or 0 < limit <= len(self.pending):
                    line, self.pending = self.pending, b""
                    return line
                continue
            if self.idle is not None and waited >= self.idle:
                line, self.pending = self.pending, b""
                return line
            time.sleep(self.poll)
            waited += self.poll


def monitor(model: str, stream: IO, name: str, options: DiagnosisOptions, *, process_noise: float | None = None,
            measurement_noise: float | None = None, generated: str | None = None,
            say: Callable[[str], None] = print, checkpoint: float | None = None,
            progress=None) -> api.DiagnosisReport:
    """Diagnose the rows of ``stream`` (named ``name`` in messages) as they
    arrive; ``say(line)`` gets each event as a line with its time, as it
    happens; ``checkpoint``: while hypotheses are tracked, a diagnosis of
    the data so far every this many time units (a
    :class:`~bgc.runtime.events.Checkpoint` event; as costly as a batch
    diagnosis of the record). Returns the report of the final diagnosis."""
    from .output.events import sentence

    session = api.open(model, process_noise=process_noise, measurement_noise=measurement_noise,
                       generated=generated)
    reader = runs.RowReader(stream, name)
    track.check_run_of(runs.Run(np.zeros(0), {}, {}, {}, {}, reader.header), session.name, name)
    columns = reader.columns
    groups: dict[str, list[tuple[int, str]]] = {p: [] for p in runs.PREFIXES}
    for j, c in enumerate(columns[1:], start=1):
        prefix, _, rest = c.partition(":")
        groups[prefix].append((j, rest))
    d = session.diagnoser(options, inputs=[u for _, u in groups["u"]], sensors=[y for _, y in groups["y"]],
                          source=name, progress=progress)
    rows: list[list[float]] = []
    last_check = None

    def tell(belief_events, time_of) -> None:
        for e in belief_events:
            step = getattr(e, "step", None)
            when = "" if step is None else f"t = {time_of(step):g}: "
            say(f"{when}{printable(sentence(e, time_of))}")

    def time_of(step):
        return None if step is None or step >= len(d.samples) else d.samples[step].t

    guard = _Guard()
    try:
        for values, line in reader:
            t = values[0]
            u = {name_: values[j] for j, name_ in groups["u"]}
            y = {name_: values[j] for j, name_ in groups["y"]}
            with guard:  # a Ctrl-C during a step waits for its end: the record stays whole
                belief = d.step(t, u, y, line)
                rows.append(values)
            tell(belief.events, time_of)
            if checkpoint is not None and belief.phase == "tracking":
                if last_check is None:
                    last_check = belief.time
                elif belief.time - last_check >= checkpoint:
                    last_check = belief.time
                    c = d.checkpoint()
                    tell([ev.Checkpoint(belief.step, c.verdict, c.candidates)], time_of)
    except KeyboardInterrupt:
        say("interrupted: finishing the diagnosis of the data so far")
    finally:
        guard.close()
    if not rows:
        raise DataError(f"{printable(name)}: no data row arrived", None, "give at least one row after the column names")
    run = _run(columns, rows, reader.header, name)
    diagnosis = d.finish(run)
    tell([e for e in diagnosis.events if isinstance(e, ev.Decided)], diagnosis.time_of)
    return session.report(run, diagnosis)


class _Guard:
    """Ctrl-C (SIGINT) while a step runs is held until the step ends, then
    raised as KeyboardInterrupt; between steps (waiting for a row) it is
    raised at once. Only in the main thread (where Python delivers signals)."""

    def __init__(self):
        self.inside = False
        self.pending = False
        self.previous = None
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGINT, self._handle)

    def _handle(self, signum, frame) -> None:
        if self.inside:
            self.pending = True
            return
        raise KeyboardInterrupt

    def __enter__(self):
        self.inside = True
        return self

    def __exit__(self, *exc) -> None:
        self.inside = False
        if self.pending and exc[0] is None:
            self.pending = False
            raise KeyboardInterrupt

    def close(self) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)
            self.previous = None


def _run(columns: list[str], rows: list[list[float]], header, name: str) -> runs.Run:
    """The rows received as a :class:`~bgc.runtime.runs.Run` (for the report's plots and the truth)."""
    data = np.array(rows, dtype=float).reshape(len(rows), len(columns))
    groups: dict[str, dict[str, np.ndarray]] = {p: {} for p in runs.PREFIXES}
    for j, c in enumerate(columns[1:], start=1):
        prefix, _, rest = c.partition(":")
        groups[prefix][rest] = data[:, j]
    return runs.Run(data[:, 0], groups["u"], groups["y"], groups["x"], groups["theta"], tuple(header), name)

