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

import dataclasses
import math
import os
import re
import signal
import stat
import threading
import time
from pathlib import Path
from typing import IO, Callable

import numpy as np

from .. import api
from ..errors import BgcError, DataError, printable
from .. import events as ev
from ..data import runs
from ..data.sampler import ClockJumped, beyond
from ..diagnosis.hidden import LAG
from ..diagnosis.bridge import bridged
from ..data.columns import MODE, Reading
from ..analysis import track
from ..diagnosis.finish import dated_misfit, forgotten_misfits, with_misfits_said
from ..diagnosis.options import DiagnosisOptions
from ..data.clock import Clock
from . import resume
from .episodes import Episodes, frozen_finding, frozen_unsized, repair_of
from ..model.package import forget_started

#: Rows between two saves of the monitor's state (``--state-every``).
STATE_EVERY = 100
#: The steps of the model's grid the monitor's diagnoser keeps while watching, by default (``--keep``;
#: :attr:`~bgc.diagnosis.options.DiagnosisOptions.keep`): four times the onsets' default reach back.
KEEP_STEPS = 1024


def appeared(path: str, idle: float | None, poll: float = 0.1) -> None:
    """Wait for ``path`` to exist, a file a logger has not created yet
    (``bgc monitor --follow``): polling every ``poll`` seconds, at most
    ``idle`` seconds (None: until it appears, or Ctrl-C). It returns either
    way; opening a file still missing is the caller's error to give."""
    waited = 0.0
    while not os.path.exists(path) and (idle is None or waited < idle):
        time.sleep(poll)
        waited += poll


class Follow:
    """A file read as another program appends to it: :meth:`readline` waits
    for a whole line (polling every ``poll`` seconds) and ends the input
    (returns ``""``) after ``idle`` seconds without a new byte (None: never;
    Ctrl-C ends it then). A last line without its end of line is not read
    (``unfinished`` keeps it: a logger stopped mid-line).

    **Rotation**, as loggers and logrotate do it, is followed (``say`` is
    told each time):

    - *renamed and recreated*: once the old file is read to its end and
      ``path`` names another file, that file is read from its start; while
      ``path`` names no file, the reader waits for one (the wait counts
      towards ``idle``);
    - *copied and truncated*: a file shorter than what was read is read
      again from its start (what the logger wrote between the copy and the
      truncation is in the copy, not here);
    - *several files* (``pattern``: a folder or a glob pattern,
      :func:`bgc.data.runs.run_files`): once a file is read to its end, the
      next one in the order of their names is read from its start, and one
      that appears later is read when its turn comes (with ``idle`` 0 the
      input ends after the last file there is);
    - the new file's header is skipped: its ``#`` comment lines, blank lines
      and a column line equal to the first file's; any other line is a row
      (rows whose times do not go on from the ones read are refused, as in
      one file)."""

    def __init__(self, stream: IO[bytes], idle: float | None = None, poll: float = 0.1, path: str | None = None,
                 say: Callable[[str], None] | None = None, pattern: str | None = None):
        self.stream, self.idle, self.poll, self.path, self.pattern = stream, idle, poll, path, pattern
        self.say = say or (lambda text: None)
        self.pending = b""
        self.unfinished = b""
        self.inode = os.fstat(stream.fileno()).st_ino
        self.names: bytes | None = None  # the first file's column line
        self.skipping = False  # a new file's header lines are skipped
        self.first = path  # the file read first
        self.file_line = 0  # the lines read from the file read now (a header's skipped ones too)
        self.returned = 0  # the lines given to the reader, all files
        #: per file read after the first (or the same path rotated): (the reader's number of its first line
        #: given, its path, that line's number in it), for :meth:`located`
        self.starts: list[tuple[int, str, int]] = []
        self.fresh = False  # a file opened: its first line given starts an entry of starts

    def readline(self, limit: int = -1) -> bytes:
        waited = 0.0
        while True:
            chunk = self.stream.readline(limit - len(self.pending) if limit > 0 else -1)
            if chunk:
                waited = 0.0
                self.pending += chunk
                if self.pending.endswith(b"\n") or 0 < limit <= len(self.pending):
                    line, self.pending = self.pending, b""
                    self.file_line += 1
                    if self._header(line):
                        continue
                    self.returned += 1
                    if self.fresh:
                        self.starts.append((self.returned, str(self.path), self.file_line))
                        self.fresh = False
                    return line
                continue
            if self._rotated():
                waited = 0.0
                continue
            if self.idle is not None and waited >= self.idle:
                self.unfinished, self.pending = self.pending, b""
                return b""
            time.sleep(self.poll)
            waited += self.poll

    def located(self, line: int) -> tuple[str, int] | None:
        """The file and its line of the reader's line ``line`` (its count
        over every file read), None when only one file was read as given."""
        if not self.starts and self.pattern is None:
            return None
        path, base, local = str(self.first), 1, 1
        for given, p, at in self.starts:
            if given <= line:
                path, base, local = p, given, at
        return path, local + line - base

    def _header(self, line: bytes) -> bool:
        """Whether ``line`` is a new file's header line, skipped; the first
        file's column line is noted (the first line that is no comment)."""
        text = line.strip()
        if self.names is None and text and not text.startswith(b"#"):
            self.names = text
        if not self.skipping:
            return False
        if not text or text.startswith(b"#"):
            return True
        self.skipping = False
        return text == self.names

    def _rotated(self) -> bool:
        """At the end of what the file holds: whether it was truncated (read
        again from its start) or another file took its name (read from its
        start once it is there); True when the reading goes on elsewhere."""
        name = printable(self.path or "the followed file")
        if os.fstat(self.stream.fileno()).st_size < self.stream.tell():
            self.stream.seek(0)
            self.pending, self.skipping, self.file_line, self.fresh = b"", True, 0, True
            self.say(f"{name} was truncated (rotated by copy and truncate): reading it again from its start")
            return True
        if self.path is None:
            return False
        later = self._later()
        if later is not None:
            if not self._open(str(later)):
                return False  # not readable yet: tried again after the next poll
            self.say(f"{name} read to its end: reading the next file, {printable(str(later))}")
            return True
        try:
            info = os.stat(self.path)
        except OSError:
            return False  # renamed, not yet recreated: wait for it
        if info.st_ino == self.inode:
            return False
        if not self._open(self.path):
            return False
        self.say(f"{name} was rotated (renamed, and a new file made under its name): reading the new file from "
                 "its start")
        return True

    def _later(self) -> Path | None:
        """The first file of ``pattern`` after the one read, in the order of
        their names (None: none yet, or no pattern; a folder emptied meanwhile
        holds none)."""
        if self.pattern is None:
            return None
        try:
            files = runs.run_files(self.pattern) or []
        except DataError:
            return None
        return next((f for f in files if f > Path(self.path)), None)

    def _open(self, path: str) -> bool:
        """Go on reading from the start of file ``path`` (False: it cannot be opened now)."""
        try:
            fresh = open(path, "rb")
        except OSError:
            return False
        if not stat.S_ISREG(os.fstat(fresh.fileno()).st_mode):
            fresh.close()
            raise DataError(f"{printable(path)} is not a regular file: the rows read so far are diagnosed", None,
                            "follow regular files")
        self.stream.close()
        self.stream, self.inode, self.path = fresh, os.fstat(fresh.fileno()).st_ino, path
        self.pending, self.skipping, self.file_line, self.fresh = b"", True, 0, True
        return True


#: The samples a diagnoser's record holds at least before the monitor tests the model's fit while watching
#: (the first checkpoint's time, or this, whichever is later): its start from an estimate settles, and the
#: residuals' mean and variance mean something.
FIT_STEPS = 100


def monitor(session: api.Session, stream: IO, name: str, options: DiagnosisOptions, *,
            say: Callable[[str], None] = print, checkpoint: float | None = None,
            progress=None, exclude_faulty: bool = False,
            reading: Reading | None = None, state: str | Path | None = None,
            state_every: int = STATE_EVERY, episodes: bool = False,
            rearm: float | None = None) -> tuple[api.DiagnosisReport, BgcError | None]:
    """Diagnose the rows of ``stream`` (named ``name`` in messages) as they
    arrive, with the model of ``session`` (:func:`bgc.open`); ``say(line)``
    gets each event as a line with its time, as it happens; ``checkpoint``:
    while hypotheses are tracked, a diagnosis of the data so far every this
    many time units (a :class:`~bgc.events.Checkpoint` event; the
    finish of a copy of the diagnoser, :meth:`~bgc.diagnosis.diagnoser.Diagnoser.checkpoint`; the
    first whose verdict is mismatch also says why, its :class:`~bgc.events.Mismatched`). Returns the report of the
    final diagnosis and the error that ended the stream early (None: it
    ended, or Ctrl-C): a malformed row, a followed file replaced by no regular file, the memory
    rule; the rows before it are diagnosed all the same.

    ``exclude_faulty`` (with ``checkpoint``): when a checkpoint isolates a
    sensor fault, that sensor is taken out of the nominal observer (a
    :class:`~bgc.events.SensorExcluded` event) and a new diagnoser
    watches the rows from the next one on with the other sensors (its
    observer starts again from the model's initial state: a sensor fault
    leaves the plant where it was); the report is that diagnoser's, its
    events led by the exclusions.

    ``state``: a folder where the monitor's state is saved every
    ``state_every`` rows and when the input ends (:mod:`bgc.service.resume`);
    a state found there is taken up: the rows of the input up to its last
    row's time are passed over, and the diagnosis goes on as if it had
    never stopped (a state of another model, bgc or options is refused), the
    sensors taken out before taken out again.

    ``episodes`` (with ``checkpoint``): the monitor goes on after a verdict
    and keeps a fault log (:mod:`bgc.service.episodes`): an episode closes at
    a checkpoint that isolates a fault (accommodated in the model watched
    from then on, or its sensor taken out) or ``rearm`` after its alarm
    (re-armed; also, whatever ``rearm``, when its record nears the most the
    diagnosis holds in memory, :data:`FULL_ROOM`); a ``# repaired`` line of
    the stream takes the accommodated faults out again. The report is the
    last diagnoser's, its events led by the fault log."""
    if episodes and checkpoint is None:
        raise BgcError("--episodes are closed at checkpoints: a fault is isolated there", None,
                       "add --checkpoint TIME, e.g. --checkpoint 10")
    try:
        run = _Monitor(session, stream, name, options, say, checkpoint, progress, exclude_faulty, reading,
                       state, state_every, rearm if episodes else None, episodes)
    except BgcError as exc:  # the column names: a folder's first file's
        _located(exc, stream, name)
        raise
    guard = _Guard()
    failure = None
    try:
        for values, line in run.reader:
            run.row(values, line, guard)
    except KeyboardInterrupt:
        say("interrupted: finishing the diagnosis of the data so far")
    except BgcError as exc:  # a bad row, a followed file replaced by no regular file, the memory rule: the rows so far are diagnosed
        _located(exc, stream, name)
        if not run.rows and run.ended is None:
            raise
        failure = exc
        say(f"stopped: {printable(str(exc))}")
    finally:
        guard.close()
        if run.rows:
            run.keep.save(run.rows, run.last_check, run.d, run.excluded)  # where the input ended: a restart goes on from there
    return run.finish(stream), failure


def _located(exc: BgcError, stream, name: str) -> None:
    """Error ``exc`` about line N of the input ``name`` (``NAME:N: ...``)
    made to name the file and its line instead, where ``stream`` read
    several files one after the other (:meth:`Follow.located`)."""
    match = re.match(rf"{re.escape(printable(name))}:(\d+): ", exc.what)
    where = stream.located(int(match.group(1))) if match and hasattr(stream, "located") else None
    if where is not None:
        exc.what = f"{printable(where[0])}:{where[1]}: {exc.what[match.end():]}"
        exc.args = (exc.line(),)


class _Monitor:
    """One run of :func:`monitor` (its arguments): the diagnoser watching
    now, the rows of its record, what was told, the sensors taken out, the
    fault log (with ``episodes``) and the state on disk; :meth:`row` takes
    each row of the input, :meth:`finish` makes the report."""

    def __init__(self, session, stream, name, options, say, checkpoint, progress, exclude_faulty, reading,
                 state, state_every, rearm, episodes: bool):
        self.session, self.name, self.say, self.checkpoint = session, name, say, checkpoint
        self.progress, self.exclude_faulty = progress, exclude_faulty
        self.reader = runs.RowReader(stream, name, reading or session.reading())
        track.check_run_of(runs.Run(np.zeros(0), {}, {}, {}, {}, self.reader.header), session.name, name)
        self.columns = self.reader.columns
        self.groups: dict[str, list[tuple[int, str]]] = {p: [] for p in runs.PREFIXES}
        for j, c in enumerate(self.columns[1:], start=1):
            prefix, _, rest = c.partition(":")
            if c == MODE:  # a model with modes reads the mode column as its last input, mode
                prefix, rest = "u", MODE
            self.groups[prefix].append((j, rest))
        self.sensors = [y for _, y in self.groups["y"]]
        timing = runs.resolve_timing(self.reader.header, options.input_timing, name, "--input-timing")
        if timing != (options.input_timing or "end"):  # the header's word (None stays None: the default)
            options = dataclasses.replace(options, input_timing=timing)
        if options.keep is None:  # a stream may not end: the record kept while watching is bounded
            options = dataclasses.replace(options, keep=KEEP_STEPS * session.package.MODELS["nominal"].DT)
        self.options = options
        self.d = self._diagnoser()
        self.rows: list[list[float]] = []
        self.forgot = 0  # the steps the diagnoser forgot when the rows and what was told were last cut to its record
        self.last_check = None
        self.told: set = set()
        #: the finding of a checkpoint whose verdict is mismatch was said (once per diagnoser)
        self.mismatch_said = False
        #: every misfit said as the data came (:class:`~bgc.events.Mismatched`, dated: its ``said`` and ``span``
        #: times), for the report of a record that forgot the data it was said on (:meth:`finish`), and the state:
        #: the diagnoser's that watches now (they weigh on its verdict), and those of the diagnosers before it
        self.misfits: list[ev.Mismatched] = []
        self.earlier_misfits: list[ev.Mismatched] = []
        #: the steps of a diagnoser's record at which its fit is tested while watching (:meth:`_fits`)
        self.fit_steps = None if checkpoint is None else max(
            FIT_STEPS, int(round(checkpoint / float(session.package.MODELS["nominal"].DT))))
        self.excluded: list[ev.SensorExcluded] = []
        self.bridges: list[ev.Bridged] = []  # the gaps longer than the diagnosis holds, bridged while watching
        self.hidden_said: set = set()  # the data have no mode column: said once
        self.taken_out: set[str] = set()
        self.log = Episodes(session.package, rearm, exclude_faulty, session.view.labels.per_time) if episodes else None
        self.keep = _Keeper(session, options, checkpoint, self.columns, state, state_every, exclude_faulty, reading,
                            self.log, (self.earlier_misfits, self.misfits), self.bridges)
        self.after_saved = 0  # a restart's comment lines after its last saved row, taken before it
        self.saved = self.keep.load()
        #: (diagnoser, rows, its misfits said) of the episode closed or repaired last, until the next row
        self.ended = None
        self.rows_time = None  # the last row's time
        #: the latest time a line said: a line found later of an earlier time is dated by it, its own time in it
        self.latest = -math.inf
        if self.saved is not None:
            self._resume(self.saved)

    def _diagnoser(self):
        """A new diagnoser of the model as the file has it, watching :attr:`sensors`."""
        return self.session.diagnoser(self.options, inputs=[u for _, u in self.groups["u"]], sensors=self.sensors,
                                      source=self.name, progress=self.progress)

    def _resume(self, saved) -> None:
        """Take up a state saved before a restart."""
        self.excluded = [ev.SensorExcluded(*e) for e in saved.excluded]
        self.bridges[:] = saved.bridged
        self.earlier_misfits[:], self.misfits[:] = saved.misfits
        if self.log is not None and saved.episodes is not None:
            self.log.restore(saved.episodes)
            # the comment lines are counted afresh in this reading of the input: those of the rows it reads
            # again are taken, and after the last of them the repairs taken before the restart (none when the
            # input reads no row again: a pipe of the new rows only, every comment line in it new)
            self.after_saved, self.log.remarks = self.log.remarks - self.log.at_row, 0
        self.taken_out = {e.sensor for e in self.excluded} | (set() if self.log is None else self.log.sensors_out())
        if self.taken_out:  # the diagnoser the state is of watches the other sensors
            self.sensors = [y for y in self.sensors if y not in self.taken_out]
            self.d = self._diagnoser()
        self.d = type(self.d).from_state(self.d.config, saved.diagnoser)
        if self.d.decoder is not None:  # said before the restart: "the data have no mode column"
            self.hidden_said.add(ev.ModeHidden(LAG))
        self.rows, self.last_check = [list(r) for r in saved.rows], saved.last_check
        self.mismatch_said = bool(self.misfits)  # said before the restart: not again by this diagnoser
        self.told.update(self.d.loop.events, self.d.switched, [] if self.log is None else self.log.log)  # said before
        self.forgot = self.d.offset
        self.rows_time = self.latest = saved.last_time
        self.keep.stream = saved.stream
        self.say(f"resumed from {printable(str(self.keep.where))}: {self.keep.stream[0]} rows read, to t = "
                 f"{self.clock.text(saved.last_time)} (the record the diagnosis keeps: the last {len(self.rows)}); "
                 "the input's rows after it are read on")

    @property
    def clock(self) -> Clock:
        """How the monitor's lines write the stream's times: the
        :class:`~bgc.data.clock.Clock` of the first row's time (read in
        all, kept across a restart) and the model's time unit."""
        first = self.keep.stream[1]
        return Clock.of([] if first is None else [first], self.session.view.labels.time_unit)

    def time_of(self, step):
        return self.d.time_of(step)

    def tell(self, events, time_of=None, final: bool = False) -> None:
        """Say ``events`` as lines, each with its time (``time_of``: of a step; default the diagnoser's);
        a misfit said as the data come (not ``final``: the end's) is kept, dated (:attr:`misfits`). The lines'
        times never go back: an event of a time before a line said already (a hypothesis the end's weighing
        dropped) is dated by the latest time said (``final``: the latest of the end's events, the record's
        end), its own time written after it."""
        from ..output.events import sentence

        time_of, clock = time_of or self.time_of, self.clock

        def at(e):  # an event's own time (a misfit said before: when it was said); None: none
            if isinstance(e, ev.Bridged):  # the row after the gap
                return e.time
            step, said = getattr(e, "step", None), getattr(e, "said", None)
            return said if said is not None else None if step is None else float(time_of(step))

        if final:  # what only the end says, said at the end: no line dated before one said already
            self.latest = max([self.latest, *(t for t in map(at, events) if t is not None)])
        for e in events:
            self.told.add(e)
            if isinstance(e, ev.Mismatched) and not final:
                self.misfits.append(dated_misfit(e, time_of))
            if isinstance(e, ev.SensorMissing) and e.sensor in self.taken_out:
                continue  # taken out by the monitor, not missing from the data: said by its SensorExcluded
            if isinstance(e, ev.ModeHidden) and e in self.hidden_said:
                continue  # said by the diagnoser before (one after a gap bridged says it again)
            if isinstance(e, ev.ModeHidden):
                self.hidden_said.add(e)
            t, text = at(e), printable(sentence(e, time_of, clock=clock))
            if t is not None and t < self.latest:  # found after a line dated later was said: said now, dated within
                text, t = f"{text}, at t = {clock.text(t)}", self.latest
            if t is not None:
                self.latest = max(self.latest, t)
            self.say(f"{'' if t is None else f't = {clock.text(t)}: '}{text}")

    def _afresh(self) -> None:
        """A new diagnoser took over (an episode closed, a repair): its record starts empty."""
        self.rows, self.last_check, self.forgot, self.told = [], None, 0, set()
        self.mismatch_said = False
        self._misfits_earlier()

    def _misfits_earlier(self) -> None:
        """The misfits said so far are an earlier diagnoser's: in the report, not on the next one's verdict."""
        self.earlier_misfits.extend(self.misfits)
        self.misfits.clear()

    # -- a row -------------------------------------------------------------------------------------------------

    def row(self, values, line, guard) -> None:
        """Take one row of the input (``guard``: Ctrl-C waits for the end of its step)."""
        t = values[0]
        if self.saved is not None and t <= self.saved.last_time:
            self.keep.same(values, line, self.name, self.clock)  # diagnosed before the restart: the same row as then
            if self.log is not None:  # and the repairs before it taken then: those after the last one saved too
                self.log.remarks = self.reader.lines.comments + self.after_saved
            return
        u = {name_: values[j] for j, name_ in self.groups["u"]}
        y = {name_: values[j] for j, name_ in self.groups["y"]}
        if self.log is not None:
            self._repairs(t)
            self.log.at_row = self.log.remarks
        with guard:  # a Ctrl-C during a step waits for its end: the record stays whole
            if self.d.sampler.k < 0 and self.rows_time is not None and self._beyond(t):
                self._bridge(None, t, u)  # a new diagnoser (an episode closed, a repair) meets the gap: bridged too
            before = self._taken()
            try:
                belief = self.d.step(t, u, y, line)
            except ClockJumped as jump:  # a gap longer than the diagnosis holds: bridged when watching
                self._bridge(jump, t, u)
                before = self._taken()
                belief = self.d.step(t, u, y, line)
            self.rows.append(values)
            read, first = self.keep.stream
            self.keep.stream = (read + 1, t if first is None else first)  # counted once taken, as its row is
            self.rows_time, self.ended = t, None
            if self.d.offset != self.forgot:  # the diagnoser forgot its record's first steps: the rows before go too
                self.rows, self.told = _kept(self.rows, self.told, self.d, self.d.offset - self.forgot)
                self.forgot = self.d.offset
        said = self.mismatch_said  # a misfit said already (a checkpoint's): the watching test's not said again
        self.tell([e for e in belief.events if not (said and isinstance(e, ev.Mismatched))])
        if any(isinstance(e, ev.Mismatched) for e in belief.events):  # and one said here: not again at a checkpoint
            self.mismatch_said = True
        if self.log is not None:
            self.log.watch(belief, self.d)
        self._fits(belief, before)
        self._checkpoint(belief, t)
        self.keep.every(self.rows, self.last_check, self.d, self.excluded)  # after the checkpoint: its time is saved

    def _gap(self, t: float) -> int:
        """The steps with no row between the last row taken and time ``t``."""
        return int(round((t - self.rows_time) / float(self.d.nominal.DT))) - 1

    def _beyond(self, t: float) -> bool:
        """Whether a row of time ``t`` comes after a gap a diagnoser that
        took no row yet could not take (:meth:`_bridge`)."""
        return beyond(self._gap(t), self.d._room())

    def _bridge(self, jump: ClockJumped | None, t: float, u: dict) -> None:
        """The row of time ``t`` (inputs ``u``) comes after a gap longer
        than the diagnosis holds (``jump``, the refusal; None: met by a
        diagnoser that took no row yet, an episode's or a repair's): while
        watching, a new diagnoser takes it as its first
        (:mod:`bgc.diagnosis.bridge`); with an episode in progress
        (``--episodes``) the episode is closed first on the rows before the
        gap; an alarm in progress without episodes stops the monitor with
        ``jump`` (its diagnosis: the rows before the gap). The gap's steps
        are counted from the last row's time either way (a restart from a
        state saved between the two meets the same)."""
        waited = self.d.flush()  # the steps waiting for their modes: taken, the data stop here
        if waited is not None:
            self.tell(waited.events)
            if self.log is not None:
                self.log.watch(waited, self.d)
        belief = self.d.belief()
        if belief.phase != "watching":
            if self.log is None:
                raise DataError(jump.what, jump.loc, "an alarm was in progress: the report is the diagnosis of the "
                                "rows before the gap; with episodes (--episodes) the monitor closes the episode there "
                                "and goes on after the gap")
            c = self.d.checkpoint()
            self.tell([ev.Checkpoint(belief.step, c.verdict, c.candidates)])
            self._close(c, belief.time, self.rows_time, "gap")
        if self.rows:  # their report, should the row after the gap fail
            self.ended = (self.d, self.rows, list(self.misfits))
        self.d, said = bridged(self.d, t, u, self.rows_time, self._gap(t))
        self.bridges.append(said)
        self.tell([said])
        self._afresh()

    def _repairs(self, t: float) -> None:
        """The stream's comment lines read since the last row: a repair takes
        effect before the row of time ``t`` (the row is the repaired plant's)."""
        for text in self.reader.lines.since(self.log.remarks):
            self.log.remarks += 1
            which = repair_of(text)
            if which is None:
                continue
            self.ended = (self.d, self.rows, list(self.misfits)) if self.rows else self.ended
            self.d, done = self.log.repaired(self.d, t, which)
            self.tell([done])
            self._afresh()
            if self.rows_time is not None:  # decided: kept across a kill
                self.keep.save(self.rows, self.last_check, self.d, self.excluded, self.rows_time)

    def _taken(self) -> int:
        """The steps the diagnoser has taken (those it forgot too)."""
        return self.d.offset + len(self.d.loop.samples)

    def _fits(self, belief, before: int) -> None:
        """While watching, once per diagnoser: when its record reaches one
        ``checkpoint`` of steps and :data:`FIT_STEPS` (the row that takes it
        there, ``before`` the steps taken before the row), the test of the model's fit on that
        record (the diagnosis of the data so far: with no alarm, the fit of
        the whole record, :mod:`bgc.diagnosis.fit`); a model that does not
        fit is said as the data come, not only after an alarm. One test per
        diagnoser holds the fit test's level (a test at every checkpoint of a
        stream that runs for months would find a misfit by chance); a
        restart past that point does not test again (the steps count from
        the diagnoser's first)."""
        if self.checkpoint is None or belief.phase != "watching" or self.mismatch_said:
            return
        if not before < self.fit_steps <= self._taken():
            return
        c = self.d.checkpoint()
        missed = any(isinstance(e, ev.ChangeMissed) and e.found for e in c.events)
        if c.verdict == "mismatch" or missed:  # a misfit, or a change the detector missed (said, not hidden)
            self.mismatch_said = True
            self.tell([ev.Checkpoint(belief.step, c.verdict, c.candidates)]
                      + [e for e in c.events if isinstance(e, (ev.Mismatched, ev.ChangeMissed))])

    def _checkpoint(self, belief, t: float) -> None:
        """While hypotheses are tracked, every ``checkpoint``: the diagnosis of
        the data so far; an episode it decides is closed (or one whose record
        is nearly full), a faulty sensor taken out."""
        if self.checkpoint is None:
            return
        full = self.log is not None and self.log.alarm is not None and _nearly_full(self.d)
        if belief.phase != "tracking" and not full:
            return
        if self.last_check is None and not full:
            self.last_check = belief.time
            return
        if not full and belief.time - self.last_check < self.checkpoint:
            return
        self.last_check = belief.time
        c = self.d.checkpoint()
        self.tell([ev.Checkpoint(belief.step, c.verdict, c.candidates)])
        if c.verdict == "mismatch" and not self.mismatch_said:  # why, and what to do, as the data come: once
            self.mismatch_said = True
            self.tell([e for e in c.events if isinstance(e, ev.Mismatched)])
        if self.log is not None and (full or self.log.due(c, belief.time)):
            self._close(c, belief.time, t, "memory" if full else None)
        elif self.exclude_faulty and self.log is None:
            faulty = _faulty_sensor(c, self.sensors)
            if faulty is not None:
                self._exclude(c, faulty, belief.time)

    def _close(self, c, now: float, t: float, forced: str | None = None) -> None:
        """Close the open episode on checkpoint diagnosis ``c`` at time ``now``
        (the row of time ``t``; ``forced``: why before its checkpoint decides
        it, :meth:`Episodes.close <bgc.service.episodes.Episodes.close>`): a
        new diagnoser watches from the next row."""
        self.ended = (self.d, self.rows, list(self.misfits))  # its report, should the stream end before the next row
        self.d, self.sensors, closed = self.log.close(c, self.d, now, self.sensors, forced)
        if closed.action == "sensor out":
            self.taken_out.add(closed.parameter)
        self.tell([closed])
        self._afresh()
        self.keep.save(self.rows, self.last_check, self.d, self.excluded, t)  # decided: kept across a kill

    def _exclude(self, c, faulty: str, now: float) -> None:
        """Take sensor ``faulty``, isolated as faulty by checkpoint diagnosis
        ``c`` at time ``now``, out of the nominal observer: a new diagnoser
        watches the other sensors from the next row."""
        from ..output.events import fault_sentence

        finding = (frozen_finding(faulty) if c.estimate is None or c.verdict != "isolated"
                   else fault_sentence(c.estimate, c.onset, self.session.view.labels.per_time, clock=c.clock))
        out = ev.SensorExcluded(faulty, finding, now)
        self.excluded.append(out)
        self.taken_out.add(faulty)
        self.tell([out])
        self.sensors = [y for y in self.sensors if y != faulty]
        forget_started(self.d.config.package)  # a record that forgot its start: its package goes
        self.d = self._diagnoser()
        self.rows, self.last_check, self.forgot = [], None, 0
        self.mismatch_said = False
        self._misfits_earlier()

    # -- the end -----------------------------------------------------------------------------------------------

    def finish(self, stream) -> api.DiagnosisReport:
        """The report of the rows the last diagnoser took (the closed episode's when the input ended on it)."""
        d, rows = self.d, self.rows
        current, earlier = self.misfits, self.earlier_misfits
        if not rows and self.ended is not None:  # the stream ended as an episode closed: the report is the closed one's
            d, rows, current = self.ended
            earlier = [m for m in self.earlier_misfits if m not in current]
        if getattr(stream, "unfinished", b""):
            self.say(f"the input ended in the middle of a line ({len(stream.unfinished)} bytes without an end of "
                     "line): that line is not read")
        if not rows:
            if self.excluded:
                raise DataError(f"{printable(self.name)}: no data row arrived after sensor {self.excluded[-1].sensor} "
                                "was taken out of the nominal observer", None,
                                "let more rows arrive, or drop --exclude-faulty-sensor")
            raise DataError(f"{printable(self.name)}: no data row arrived", None,
                            "give at least one row after the column names")
        cols = self.columns
        run = runs.run_of(cols, np.array(rows, dtype=float).reshape(len(rows), len(cols)), self.reader.header,
                          self.name)
        # led by the misfits said on data the record forgot (this diagnoser's weigh on its verdict), and those
        # of the diagnosers before it
        diagnosis = with_misfits_said(d.finish(run), current)
        if earlier:
            diagnosis = dataclasses.replace(diagnosis, events=(*earlier, *diagnosis.events))
        told = self.told
        told.update(earlier)
        if self.excluded or self.taken_out:
            diagnosis = _with_exclusions(diagnosis, self.excluded, self.taken_out)
            told.update(self.excluded)
        told.update(forgotten_misfits(current, diagnosis))  # said as the data came (one given possibilities: anew)
        if self.bridges:
            diagnosis = dataclasses.replace(diagnosis, events=(*self.bridges, *diagnosis.events))
            told.update(self.bridges)
        if self.log is not None and self.log.log:  # the fault log leads the events
            diagnosis = dataclasses.replace(diagnosis, events=tuple(self.log.log) + tuple(diagnosis.events))
            told.update(self.log.log)
        gone = {e.hypothesis for e in told if isinstance(e, (ev.Dropped, ev.Stopped))}  # dropped online: said
        self.tell([e for e in diagnosis.events if e not in told and not isinstance(e, (ev.Started, ev.Isolated))
                   and not (isinstance(e, ev.Dropped) and e.hypothesis in gone)],
                  diagnosis.time_of, final=True)  # what only the end says: the weighing's drops, the verdict
        return dataclasses.replace(self.session.report(run, diagnosis), stream=self.keep.stream)


#: An episode's record within this many steps of the most the diagnosis holds in memory
#: (:attr:`~bgc.diagnosis.diagnoser.DiagnoserConfig.most`) is closed, not decided: the next rows could
#: not be taken (a row after a gap brings several steps; a longer gap is the memory rule's error).
FULL_ROOM = 64


def _nearly_full(d) -> bool:
    """Whether diagnoser ``d``'s record is within :data:`FULL_ROOM` steps
    of the most it may hold, or past half of it when that is less than
    2 :data:`FULL_ROOM` (an episode never decided would otherwise stop the
    monitor with the memory rule's error)."""
    most = d.config.most
    return most is not None and len(d.loop.samples) >= max(most - FULL_ROOM, most // 2)


def _kept(rows: list, told: set, d, cut: int) -> tuple[list, set]:
    """The rows of the steps diagnoser ``d`` keeps in its record, and the
    events told with their steps ``cut`` earlier (those of the steps it
    forgot left out): the report and the state hold what the record does."""
    first = d.loop.samples[0].t - 0.5 * d.nominal.DT
    moved = (ev.shifted(e, cut) for e in told)
    return [r for r in rows if r[0] >= first], {e for e in moved if e is not None}


class _Keeper:
    """The monitor's state on disk, when a folder is given (:mod:`bgc.service.resume`)."""

    def __init__(self, session, options, checkpoint, columns, where, every: int, exclude_faulty: bool, reading=None,
                 log: Episodes | None = None, misfits: list | None = None, bridges: list | None = None):
        self.where = None if where is None else resume.folder(where)
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise BgcError(f"--state-every {every!r}: give the rows between saves, an integer >= 1", None,
                           f"e.g. --state-every {STATE_EVERY}")
        self.ident = None if where is None else resume.identity(session, options, checkpoint, columns,
                                                                 exclude_faulty, reading, log is not None,
                                                                 None if log is None else log.rearm)
        self.log = log
        #: the monitor's lists of the misfits said so far: (the earlier diagnosers', the one watching now's)
        self.misfits = ([], []) if misfits is None else misfits
        self.bridges = [] if bridges is None else bridges  # the monitor's list of the gaps bridged
        self.period, self.count = every, 0
        self.before: dict = {}
        self.stream: tuple = (0, None)  # the rows read in all and the first one's time, saved with the state

    def load(self):
        saved = None if self.where is None else resume.load(self.where, self.ident)
        if saved is not None:
            self.before = {float(r[0]): r for r in saved.rows}
        return saved

    def same(self, values, line, name: str, clock: Clock) -> None:
        """Refuse a row passed over on a restart that differs from the row of
        that time the state was saved with (when it holds one; ``clock``:
        how the message writes its time)."""
        then = self.before.get(float(values[0]))
        if then is not None and not np.array_equal(np.asarray(values, dtype=float), then, equal_nan=True):
            raise DataError(f"{printable(name)}:{line}: the row of t = {clock.text(values[0])} differs from the one "
                            f"the state in {printable(str(self.where))} was saved with", None,
                            "give the input the monitor read before the restart, or start afresh with another "
                            "--state folder")

    def every(self, rows: list, last_check, d, excluded: list) -> None:
        self.count += 1
        if self.where is not None and self.count % self.period == 0 and rows:
            self.save(rows, last_check, d, excluded)

    def save(self, rows: list, last_check, d, excluded: list, last_time: float | None = None) -> None:
        """Save the state after ``rows`` (the last row's time ``last_time``
        when no row is left: a diagnoser opened by an episode's close)."""
        if self.where is not None:
            resume.save(self.where, self.ident, rows, rows[-1][0] if rows else last_time, last_check, d,
                        tuple((e.sensor, e.finding, e.time, e.step) for e in excluded),
                        None if self.log is None else self.log.plain(), self.stream, self.misfits,
                        tuple(self.bridges))


def _with_exclusions(diagnosis, excluded: list, taken_out: set[str]):
    """The last diagnoser's diagnosis with the monitor's exclusions: its
    events led by them, and the sensors taken out not said missing from the
    data (they were in it)."""
    data = diagnosis.data and dataclasses.replace(
        diagnosis.data, missing=tuple(m for m in diagnosis.data.missing if m not in taken_out))
    events = tuple(e for e in diagnosis.events if not (isinstance(e, ev.SensorMissing) and e.sensor in taken_out))
    return dataclasses.replace(diagnosis, data=data, events=tuple(excluded) + events)


def _faulty_sensor(c, sensors: list[str]) -> str | None:
    """The sensor a checkpoint's diagnosis ``c`` isolated a fault of, when
    another sensor is left to watch with; else None."""
    e = c.estimate
    frozen = frozen_unsized(c)  # off all the same
    if frozen is not None:
        return frozen if frozen in sensors and len(sensors) > 1 else None
    if c.verdict != "isolated" or e is None or e.target != "sensor" or len(sensors) < 2:
        return None
    return e.subject if e.subject in sensors else None


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
