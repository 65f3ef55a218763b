"""Plant data onto the model's time grid, one sample at a time.

The diagnoser's filters are the model's DBN: one time slice per step of the
model's ``dt`` (``simulation.dt``). Real data are not that regular, so a
:class:`Sampler` places each sample on that grid and says what it did, as
events (:mod:`bgc.events`):

- **Time.** The grid starts at the first sample's time; a sample at time
  ``t`` is the step ``round((t - t0) / dt)``. A step that no sample falls on
  is a step whose measurements are missing: the filters predict across it.
  A run of missing steps longer than ``gap`` (time units; default
  :data:`GAP_STEPS` steps) is a :class:`~bgc.events.Gap` event; one
  beyond :data:`MAX_GAP_STEPS` steps is refused (a clock that jumped). A
  second sample on a step already taken is skipped (the first one of a step
  is used; :class:`~bgc.events.SampleSkipped`, once, with the count
  in the report): to use every sample, give the model a ``dt`` no longer
  than the sampling interval. Times that do not increase, or that are not
  numbers, are refused with the file and line.
- **Inputs.** A ``u:NAME`` column of the data is used; an empty cell holds
  the last value (zero-order hold, :class:`~bgc.events.InputHeld`
  when a hole begins), and before the column's first value, and for an input
  the data have no column for, the model's declared input function is used
  (:class:`~bgc.events.InputFromModel`). An input's value on a row is
  the one applied over the step that ends at the row's time (``timing``
  ``end``, bgc's own files); with ``timing`` ``start`` (a logger that
  writes the value it sets at the row's time, acting until the next row)
  the step that ends at a row's time gets the values the rows before it
  set (the model's before the first row), and the row's own act from the
  next step on: the data's inputs one step later.
- **Sensors.** A model output the data have no ``y:NAME`` column for is
  missing at every step (:class:`~bgc.events.SensorMissing`): the
  diagnosis uses the sensors present. With none present the data are
  refused. A ``y:`` or ``u:`` column the model has no sensor or input of is
  not used (:class:`~bgc.events.ColumnIgnored`). A sensor whose cells stay
  empty for longer than the gap limit while rows still come is an event
  when the limit is passed (:class:`~bgc.events.SensorStopped`) and one
  when it gives samples again (:class:`~bgc.events.SensorResumed`); the
  summary counts, per sensor, its silences and the longest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from ..errors import DataError, printable
from .clock import Clock
from .. import events as ev
from .runs import Run, input_columns, no_mode
from ..model.protocol import FaultModel

#: Missing steps in a row, by default, beyond which a gap is an event.
GAP_STEPS = 10
#: Missing steps in a row beyond which the data are refused (the filters
#: would predict that far without a measurement).
MAX_GAP_STEPS = 100_000


@dataclass(frozen=True, slots=True)
class Sample:
    """Step ``k`` of the model's time grid at time ``t``: inputs ``u``
    (model order) applied over the step that ends at ``t``, measurements
    ``y`` (model order; NaN: not read); ``line``: the data line it came
    from (None: a step with no sample, or a run from Python); ``events``:
    what the data reader did at this step."""

    k: int
    t: float
    u: np.ndarray
    y: np.ndarray
    line: int | None = None
    events: tuple = ()


class Sampler:
    """Rows of plant data in (:meth:`push`), samples on the model's grid out.

    ``model``: the generated nominal model (its ``INPUTS``, ``OUTPUTS``,
    ``DT`` and ``inputs(t)``); ``inputs``, ``sensors``: the input and sensor
    names the data have columns for; ``source``: the data's name for
    messages; ``gap``: the gap limit in time units (None: :data:`GAP_STEPS`
    steps); ``timing``: what a row's input value is, ``end`` or ``start``
    (module docstring)."""

    def __init__(self, model: FaultModel, inputs, sensors, source: str, gap: float | None = None,
                 timing: str = "end", time_unit: str | None = None):
        self.model = model
        self.time_unit = time_unit
        self.timing = timing
        self.dt = float(model.DT)
        self.source = source
        self.data_inputs = tuple(u for u in model.INPUTS if u in set(inputs))
        self.present = tuple(y for y in model.OUTPUTS if y in set(sensors))
        self.ignored = tuple([f"u:{u}" for u in inputs if u not in model.INPUTS]
                             + [f"y:{y}" for y in sensors if y not in model.OUTPUTS])
        if not self.present:
            raise DataError(f"{printable(source)}: the data have none of the model's sensors "
                            f"({', '.join('y:' + printable(y) for y in model.OUTPUTS)})", None,
                            "record at least one of them as a y:NAME column")
        self.gap_steps = GAP_STEPS if gap is None else max(int(math.floor(gap / self.dt + 1e-9)), 0)
        self.t0: float | None = None
        self.last_t = -math.inf
        self.k = -1
        self.held: dict[str, float | None] = {u: None for u in self.data_inputs}  # last recorded value
        self.holding = {u: False for u in self.data_inputs}  # in a hole (its event given)
        self.holds = {u: 0 for u in self.data_inputs}  # holes so far
        self.skipped = 0  # samples on a step already taken
        self.unsampled = 0  # steps with no sample
        self.gaps = 0  # runs of steps with no sample beyond the limit
        self._pending: list = []  # events for the next sample
        self._read = tuple((y, y in self.present) for y in model.OUTPUTS)  # per sensor: whether the data have it
        # per sensor present: the step of its last sample, whether it is in a silence (its event given), the
        # silences so far, the longest (steps)
        self.last_seen = {y: -1 for y in self.present}
        self.silent = {y: False for y in self.present}
        self.stops = {y: 0 for y in self.present}
        self.longest = {y: 0 for y in self.present}

    def state(self) -> "SamplerState":
        """Where the sampler stands, as plain data (:meth:`restore` takes it back)."""
        return SamplerState(self.data_inputs, self.t0, self.last_t, self.k, tuple(self.held.items()),
                            tuple(self.holding.items()), tuple(self.holds.items()), self.skipped, self.unsampled,
                            self.gaps, tuple(self._pending), tuple(self.last_seen.items()),
                            tuple(self.silent.items()), tuple(self.stops.items()), tuple(self.longest.items()))

    def restore(self, state: "SamplerState") -> None:
        """Take up where ``state`` (:meth:`state`) stood."""
        self.data_inputs = tuple(state.data_inputs)
        self.t0, self.last_t, self.k = state.t0, state.last_t, state.k
        self.held, self.holding, self.holds = dict(state.held), dict(state.holding), dict(state.holds)
        self.skipped, self.unsampled, self.gaps = state.skipped, state.unsampled, state.gaps
        self._pending = list(state.pending)
        self.last_seen, self.silent = dict(state.last_seen), dict(state.silent)
        self.stops, self.longest = dict(state.stops), dict(state.longest)

    def start_events(self) -> tuple:
        """The events that hold for the whole run (absent columns)."""
        missing = tuple(ev.SensorMissing(y) for y in self.model.OUTPUTS if y not in self.present)
        missing += tuple(ev.ColumnIgnored(c) for c in self.ignored)
        absent = tuple(ev.InputFromModel(u, "absent") for u in self.model.INPUTS if u not in self.data_inputs)
        return missing + absent

    def push(self, t: float, u: dict[str, float], y: dict[str, float], line: int | None = None,
             room: int | None = None) -> list[Sample]:
        """The samples a data row at time ``t`` gives: the steps with no sample
        before it, then its own (none when it is skipped). ``u``, ``y``: the
        row's cells by input and sensor name (NaN: empty); ``room``: the most
        steps a row after a gap may give (the diagnosis's memory; None: no
        limit but :data:`MAX_GAP_STEPS`), a row beyond it refused as a
        clock that jumped."""
        if not math.isfinite(t) or t <= self.last_t:
            self._refuse(t, line)
        t0 = t if self.t0 is None else self.t0
        k = int(round((t - t0) / self.dt))
        if k <= self.k:  # the step is taken: the first sample of a step is used
            self.last_t = t
            self.skipped += 1
            if self.skipped == 1:
                self._pending.append(ev.SampleSkipped(k, line, t))
            return []
        missing = k - self.k - 1
        if beyond(missing, room):
            error = jumped(self._where(line), self.clock(t).text(t), missing, self.dt, "sample",
                           None if missing > MAX_GAP_STEPS else max(room - 1, 0))
            raise ClockJumped(error.what, error.loc, error.fix)
        self.last_t, self.t0 = t, t0  # the row is taken: a refused one leaves the sampler as it was
        out = []
        first = self.k + 1
        if missing > self.gap_steps:
            self.gaps += 1
        self.unsampled += missing
        for j in range(first, k):
            tj = self.t0 + j * self.dt
            events = (ev.Gap(first, missing),) if j == first and missing > self.gap_steps else ()
            out.append(Sample(j, tj, self._inputs(tj, {}, j, None), np.full(len(self.model.OUTPUTS), np.nan),
                              None, events))
        events: list = [] if self.k >= 0 else list(self.start_events())
        events += self._pending
        self._pending = []
        uk = self._set_before(t, u, k, events) if self.timing == "start" else self._inputs(t, u, k, events)
        self._check_mode(uk, line)
        yk = np.array([float(y.get(name, math.nan)) if read else math.nan for name, read in self._read])
        self._silences(k, yk, events)
        out.append(Sample(k, t, uk, yk, line, tuple(events)))
        self.k = k
        return out

    def _silences(self, k: int, yk: np.ndarray, events: list) -> None:
        """A row's sensors: one empty for longer than the gap limit is
        stopped, one stopped that has a sample again resumes (``events``)."""
        for (name, read), value in zip(self._read, yk):
            if not read:
                continue
            last = self.last_seen[name]
            if math.isfinite(value):
                if self.silent[name]:
                    events.append(ev.SensorResumed(name, last + 1, k))
                    self.silent[name] = False
                self.longest[name] = max(self.longest[name], k - last - 1)
                self.last_seen[name] = k
            elif not self.silent[name] and k - last > self.gap_steps:
                events.append(ev.SensorStopped(name, last + 1, k))
                self.silent[name] = True
                self.stops[name] += 1

    def _where(self, line: int | None) -> str:
        """The data's name and the row's line, for a message."""
        return f"{printable(self.source)}:{line}" if line is not None else printable(self.source)

    def _refuse(self, t: float, line: int | None) -> None:
        """The error for a row whose time is not finite or does not increase."""
        where = self._where(line)
        if not math.isfinite(t):
            raise DataError(f"{where}: time {t!r} is not a finite number", None, "give every row its time")
        clock = self.clock(t)
        raise DataError(f"{where}: time {clock.text(t)} does not increase (the row before has "
                        f"{clock.text(self.last_t)})", None, "sort the rows by time, one row per sample")

    def clock(self, t: float) -> Clock:
        """How the messages write the data's times: as the diagnosis does,
        by the first row's time (``t`` before it: the row's) and the time
        unit (:class:`~bgc.data.clock.Clock`)."""
        return Clock.of([t if self.t0 is None else self.t0], self.time_unit)

    def _check_mode(self, u: np.ndarray, line: int | None) -> None:
        """A model with modes: refuse a row whose mode is not one of the
        model's numbers (1 to its modes; NaN, not said, is taken)."""
        index = getattr(self.model, "MODE_INPUT", None)
        if index is None or not math.isfinite(u[index]):
            return
        if not (1 <= u[index] <= len(self.model.MODES) and u[index] == round(u[index])):
            raise no_mode(self._where(line), float(u[index]), self.model.MODEL, self.model.MODES)

    def row_inputs(self, t: float, row: dict[str, float]) -> np.ndarray:
        """The inputs a row at time ``t`` says (by name): its own values, the
        last one held where a cell is empty, the model's where none was; the
        sampler is left as it was."""
        declared = np.asarray(self.model.inputs(t), dtype=float) if self.model.INPUTS else np.zeros(0)
        u = []
        for i, name in enumerate(self.model.INPUTS):
            value = float(row.get(name, math.nan)) if name in self.data_inputs else math.nan
            held = self.held.get(name) if name in self.data_inputs else None
            u.append(value if math.isfinite(value) else float(declared[i]) if held is None else float(held))
        return np.array(u, dtype=float)

    def _inputs(self, t: float, row: dict[str, float], k: int, events: list | None) -> np.ndarray:
        """The inputs over the step that ends at ``t``: the row's, the last one
        held, or the model's; ``events`` (None: a step with no sample, whose
        holds the gap explains) gets what was done."""
        if not self.model.INPUTS:
            return np.zeros(0)
        declared = None
        u = [0.0] * len(self.model.INPUTS)
        for i, name in enumerate(self.model.INPUTS):
            value = float(row.get(name, math.nan)) if name in self.data_inputs else math.nan
            if math.isfinite(value):
                self.held[name], self.holding[name] = value, False
                u[i] = value
                continue
            if name in self.data_inputs and self.held[name] is not None:
                if events is not None and not self.holding[name]:
                    events.append(ev.InputHeld(name, k, self.held[name]))
                    self.holding[name] = True
                    self.holds[name] += 1
                u[i] = self.held[name]
                continue
            if declared is None:
                declared = np.asarray(self.model.inputs(t - self.dt), dtype=float)
            if name in self.data_inputs and k == 0 and events is not None:
                events.append(ev.InputFromModel(name, "before-data", k))
            u[i] = float(declared[i])
        return np.array(u)

    def _set_before(self, t: float, row: dict[str, float], k: int, events: list) -> np.ndarray:
        """The inputs over the step that ends at ``t`` when a row's values
        are set at its time: the values the rows before set (held; the
        model's before the first row, an ``InputFromModel`` event); the row's
        own are held for the steps after it (an empty cell: the value before
        it goes on, an ``InputHeld`` event when a hole begins)."""
        u = self._inputs(t, {}, k, None)
        for name in self.data_inputs:
            value = float(row.get(name, math.nan))
            if math.isfinite(value):
                self.held[name], self.holding[name] = value, False
            elif self.held[name] is not None and not self.holding[name]:
                events.append(ev.InputHeld(name, k, self.held[name]))
                self.holding[name] = True
                self.holds[name] += 1
        if k == 0:
            events += [ev.InputFromModel(name, "before-data", k) for name in self.data_inputs]
        return u

    def summary(self) -> "DataSummary":
        """What the data gave, per input and sensor, so far."""
        inputs = tuple((u, "data" if u in self.data_inputs else "model") for u in self.model.INPUTS)
        silences = tuple((y, self.stops[y], max(self.longest[y], self.k - self.last_seen[y]
                                                  if self.silent[y] else 0)) for y in self.present if self.stops[y])
        return DataSummary(inputs, tuple((u, self.holds[u]) for u in self.data_inputs), self.present,
                           tuple(y for y in self.model.OUTPUTS if y not in self.present), self.skipped,
                           self.unsampled, self.gaps, self.dt, silences, self.timing)


@dataclass(frozen=True, slots=True)
class SamplerState:
    """A :class:`Sampler`'s place in the data, as plain data: the inputs the
    data give, the first time, the last time taken, the last step, per data
    input the value held, whether it is in a hole and the holes so far, the
    counts of samples skipped, steps without a sample and gaps, and the
    events waiting for the next sample."""

    data_inputs: tuple[str, ...]
    t0: float | None
    last_t: float
    k: int
    held: tuple
    holding: tuple
    holds: tuple
    skipped: int
    unsampled: int
    gaps: int
    pending: tuple
    last_seen: tuple = ()
    silent: tuple = ()
    stops: tuple = ()
    longest: tuple = ()


@dataclass(frozen=True, slots=True)
class DataSummary:
    """How the data met the model: per input, where its values came from
    (``data`` or ``model``), the holes held per data input (count of
    zero-order holds), the sensors present and missing, the samples skipped
    (a step already taken), the steps with no sample and the gaps beyond the
    limit among them, the grid's ``dt``, per sensor that stopped for
    longer than the gap limit (``silences``): its name, how many times, and
    its longest silence in steps, and what a row's input value was read as
    (``timing``: ``end`` or ``start``, :class:`Sampler`)."""

    inputs: tuple[tuple[str, str], ...]
    holds: tuple[tuple[str, int], ...]
    sensors: tuple[str, ...]
    missing: tuple[str, ...]
    skipped: int
    unsampled: int
    gaps: int
    dt: float
    silences: tuple[tuple[str, int, int], ...] = ()
    timing: str = "end"


def check_jumps(time, dt: float, source: str, time_unit: str | None = None) -> None:
    """Refuse a recorded run (times ``time``, increasing, on a grid of
    ``dt``) with a gap of more than :data:`MAX_GAP_STEPS` steps, as a
    :class:`Sampler` refuses its row (a clock that jumped), naming the data
    row after it and its time (``time_unit``: the model's, by which it is
    written, :class:`~bgc.data.clock.Clock`), before any work on the run."""
    t = np.asarray(time, dtype=float)
    if len(t) < 2:
        return
    missing = np.rint(np.diff(t) / dt) - 1
    if not missing.max() > MAX_GAP_STEPS:
        return
    k = int(np.argmax(missing > MAX_GAP_STEPS)) + 1
    raise jumped(f"{printable(source)}, data row {k + 1}", Clock.of(t[:1], time_unit).text(t[k]), missing[k - 1], dt,
                 "row")


class ClockJumped(DataError):
    """:func:`jumped`'s refusal of a row by :meth:`Sampler.push` (a gap
    :func:`beyond` what the diagnosis takes): a monitor watching bridges it
    (:mod:`bgc.diagnosis.bridge`)."""


def beyond(missing: int, room: int | None) -> bool:
    """Whether a row after ``missing`` steps with no sample is refused: more
    than :data:`MAX_GAP_STEPS` (a clock that jumped), or than ``room``, the
    steps the diagnosis can still hold (None: no limit) less the row's own."""
    return missing > MAX_GAP_STEPS or (missing > 0 and room is not None and missing + 1 > room)


def jumped(where: str, when: str, missing: float, dt: float, before: str, room: int | None = None) -> DataError:
    """The refusal of a row ``where`` (its time written ``when``) after
    ``missing`` steps of ``dt`` with no sample, from the ``before`` (sample
    or row) before it: more than :data:`MAX_GAP_STEPS` (a clock that
    jumped), or than ``room``, the steps the diagnosis can still hold."""
    many = f"{int(missing)}" if missing < 1e15 else f"{float(missing):.3g}"
    most = f"more than {MAX_GAP_STEPS}" if room is None else \
        f"more than the {room} the diagnosis can still hold in memory"
    return DataError(f"{where}: time {when} is {many} steps of dt = {dt:g} after the {before} before it, {most}", None,
                     "check the time column (a clock that jumped?), or split the data at the gap")


def grid_steps(time, dt: float) -> int:
    """The steps of the model's time grid (of ``dt``) that samples at ``time``
    (increasing) cover: the first to the last, the steps between them too."""
    t = np.asarray(time, dtype=float)
    return int(round((t[-1] - t[0]) / dt)) + 1 if len(t) else 0


def samples(run: Run, sampler: Sampler) -> Iterator[Sample]:
    """The samples of a recorded run on the model's grid: its rows fed to
    ``sampler`` (a :class:`Sampler` of the run's columns; the run is checked
    already, :func:`bgc.data.runs.check_run`)."""
    given = input_columns(run)
    cols_u = [(u, np.asarray(given[u], dtype=float)) for u in sampler.data_inputs]
    cols_y = [(y, np.asarray(run.measurements[y], dtype=float)) for y in sampler.present]
    for i, t in enumerate(np.asarray(run.time, dtype=float)):
        yield from sampler.push(float(t), {u: c[i] for u, c in cols_u}, {y: c[i] for y, c in cols_y})
