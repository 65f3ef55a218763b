"""The online diagnoser: one sample in, a belief out (the thesis's Fig. II.5).

::

    d = Diagnoser(package, signatures, priors, options, horizon=300)
    for t, u, y in rows:                 # as the data arrive
        belief = d.step(t, u, y)         # phase, alarm, hypotheses, events
    diagnosis = d.finish()               # the static posterior, the ranking, the verdict

A :class:`Diagnoser` is its configuration (:class:`DiagnoserConfig`: the
generated package, the signatures, the priors, the options; it never
changes) and its state, which is plain data: :meth:`Diagnoser.to_state`
gives a :class:`~bgc.diagnosis.state.DiagnoserState` (arrays, numbers,
frozen values, the random generators' states; ``to_bytes`` for a file) and
:meth:`Diagnoser.from_state` makes the diagnoser again from it, in this
process or another: the steps after it give the same numbers as if it had
never stopped.

Each :meth:`Diagnoser.step` places the row on the model's time grid
(:class:`~bgc.data.sampler.Sampler`: gaps, held inputs, missing sensors) and
hands each step to the loop (:class:`~bgc.diagnosis.loop.Loop`: watching,
isolating, tracking; its module docstring says what it keeps). The
fallbacks are policies of the diagnoser that react to the loop's events, not
steps of the loop:

* a particle observer that degenerates (the loop's
  :class:`~bgc.events.Degenerate` event, ``switched``) hands the
  record to a new loop with cubature Kalman filters
  (:class:`~bgc.events.Switched`);
* a verdict "unexplained" after the symbols ruled fault models out is made
  again with every fault model (:class:`~bgc.events.AllTried`);
* a record bounded while watching (``options.keep``) is tested before its
  older half is forgotten (:meth:`Diagnoser._changed_while_watching`): a
  change no test of the detector alarmed on (the nominal observer follows
  the faulty plant, its residuals off by a fraction of their noise) raises
  an alarm at its change point there, before the data that show it are
  forgotten (:class:`~bgc.events.ChangeMissed`, ``watching``).
"""

from __future__ import annotations

import dataclasses
import gc
import math
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..arguments import as_float, is_real, shown
from ..data.runs import Run
from ..data.sampler import Sample, Sampler
from ..errors import ArgumentTypeError, ArgumentValueError, DataError, TrackingError, printable
from .hidden import ONSETS, POOL, REREAD, ModeDecoder, read_again, read_head, read_job, readable
from ..ir import FaultSignatures
from ..model.package import accommodated, forget_started, started_package
from ..model.protocol import Package, nominal_model, state_rows
from ..data.clock import Clock
from .. import events as ev
from .detect import TESTS, Detector, DetectorOptions, change_point
from .finish import misfit_event, ordered
from .fit import LEAST, LEVEL as FIT_LEVEL, change_statistics, fails, fit, misfit_before, shifted
from .isolate import with_returns
from .onsets import log_prior
from .loop import IDENTIFY, KALMAN_METHOD, Loop, LoopConfig, shifted_events
from .options import DiagnosisOptions
from .parallel import parallel_map
from .values import Belief, Detection, Diagnosis

__all__ = ["Diagnoser", "DiagnoserConfig", "IDENTIFY", "KALMAN_METHOD"]


@dataclass(frozen=True, slots=True)
class DiagnoserConfig:
    """A diagnoser's configuration: ``package``, the generated package;
    ``signatures``, ``priors``: the model's fault signatures and each fault
    candidate's prior; ``options``; ``horizon``: the detector's horizon in
    steps; ``time_unit``: the model's (None: none declared), by which the
    run's times are told absolute or not (:attr:`Diagnoser.clock`);
    ``inputs``, ``sensors``: the input and sensor names the data have
    columns for (None: the sensors, all of the model's; the inputs, those the
    first row gives); ``source``: the data's name in messages; ``lazy``:
    leave the hypotheses' tracking to the end (a batch diagnosis: the
    hypotheses run in parallel there); ``every``: try every fault model, those
    the symbols rule out too; ``most``: the most steps it holds (None: no
    limit); ``progress(text)``: told what is done."""

    package: Package
    signatures: FaultSignatures
    priors: Mapping[str, float]
    options: DiagnosisOptions
    horizon: int
    time_unit: str | None
    inputs: tuple[str, ...] | None = None
    sensors: tuple[str, ...] | None = None
    source: str = "<stream>"
    lazy: bool = False
    every: bool = False
    most: int | None = None
    progress: Callable[[str], None] | None = field(default=None, compare=False)

    def say(self, text: str) -> None:
        if self.progress is not None:
            self.progress(text)


#: A forgotten started package's modules are cycles (functions <-> their module's globals) only the
#: cyclic collector frees, and its full passes are rare: left to them, tens of MB pile up over hundreds of
#: cuts. A full collection after every COLLECT_EVERY packages forgotten in this process bounds what waits
#: to that many; one after each would cost a full pass per cut, a pass that takes longer the more else the
#: process holds (0.1 to 0.4 s in a process of the test suite's size, measured).
COLLECT_EVERY = 8
_forgotten = 0


def _collect_forgotten() -> None:
    """Count one forgotten started package; a full collection at every
    :data:`COLLECT_EVERY`-th."""
    global _forgotten
    _forgotten += 1
    if _forgotten >= COLLECT_EVERY:
        _forgotten = 0
        gc.collect()


class Diagnoser:
    """The diagnosis of one plant's data, one sample at a time (module
    docstring); built as ``Diagnoser(package, signatures, priors, options,
    horizon, time_unit=..., inputs=..., sensors=..., source=..., lazy=...,
    every=..., progress=..., most=...)`` (the fields of :class:`DiagnoserConfig`)."""

    def __init__(self, package: Package, signatures: FaultSignatures, priors: Mapping[str, float],
                 options: DiagnosisOptions, horizon: int, *, time_unit: str | None = None, inputs=None, sensors=None,
                 source: str = "<stream>", lazy: bool = False, every: bool = False, progress=None,
                 most: int | None = None):
        hidden = inputs is not None and mode_hidden(nominal_model(package), inputs, source)
        config = DiagnoserConfig(package, signatures, priors, options, max(int(horizon), 1), time_unit,
                                 None if inputs is None else tuple(inputs),
                                 None if sensors is None else tuple(sensors), source, lazy, every, most, progress)
        self._open(config, Sampler(nominal_model(package), nominal_model(package).INPUTS if inputs is None else inputs,
                                   nominal_model(package).OUTPUTS if sensors is None else sensors, source,
                                   options.gap, options.input_timing or "end", time_unit))
        if hidden:
            self.hide()
        config.say("tracking the nominal model")

    def _open(self, config: DiagnoserConfig, sampler: Sampler) -> None:
        self.config, self.sampler = config, sampler
        self.nominal = nominal_model(config.package)
        self.loop = Loop(self._loop_config(config.options, config.every, config.lazy))
        self.switched: tuple = ()  # the Degenerate and Switched events of a switch of filter (the policy's)
        self.infer_inputs = config.inputs is None  # the first row says which inputs the data give
        self.finished = False
        self.busy = 0.0  # seconds spent in steps (not waiting for data)
        self.started = time.perf_counter()
        self.decoder: ModeDecoder | None = None  # a hidden mode's reader (the data have no mode column)
        #: where a hidden mode's reader starts when the model's start is not known (means, covariances, weights of its
        #: branches: after a logger's outage, :mod:`bgc.diagnosis.bridge`; None: the package's start)
        self.branches: tuple | None = None
        self.keep = keep_steps(config.options, self.nominal.DT)  # the record kept while watching (None: all)
        self.offset = 0  # the steps of the grid forgotten (step k of the loop is step offset + k of the data)
        #: whether the diagnoses made now try faults that come and go (off while the modes are read again)
        self.intermittent = True

    def hide(self) -> None:
        """Read the mode from the data (they have no mode column): every
        sample goes through a :class:`~bgc.diagnosis.hidden.ModeDecoder` first."""
        self.config.say("the data have no mode column: reading the mode from the measurements")
        self.decoder = ModeDecoder(self.nominal)
        if self.branches is not None:
            self.decoder.start_among(*self.branches)

    def start_among(self, means, covariances, weights) -> None:
        """Where the mode is read from the data (now or from the first row),
        start its reader from these branches (:meth:`ModeDecoder.start_among
        <bgc.diagnosis.hidden.ModeDecoder.start_among>`) instead of the
        package's start; before the first row."""
        self.branches = (means, covariances, weights)
        if self.decoder is not None:
            self.decoder.start_among(means, covariances, weights)

    def _loop_config(self, options: DiagnosisOptions, every: bool, lazy: bool) -> LoopConfig:
        c = self.config
        # a fault accommodated (the package holds it) may go away: its step back is a candidate too
        return LoopConfig(c.package, with_returns(c.signatures, accommodated(c.package)), c.priors, options,
                          c.horizon, self.sampler.present, c.time_unit, lazy, every, c.say)

    @property
    def options(self) -> DiagnosisOptions:
        return self.config.options

    @property
    def source(self) -> str:
        return self.config.source

    @property
    def clock(self) -> Clock:
        """How the record's times are written in words (the loop's:
        :attr:`bgc.diagnosis.loop.Loop.clock`)."""
        return self.loop.clock

    @property
    def detector(self):
        """The detector of the loop that runs now."""
        return self.loop.detector

    @property
    def pf(self):
        """The nominal particle observer of the loop that runs now (None: ``ckf``)."""
        return self.loop.pf

    # -- one row, one sample --------------------------------------------------------------------------------

    def step(self, t: float, u=None, y=None, line: int | None = None) -> Belief:
        """Take a row of data at time ``t``: inputs ``u`` and measurements
        ``y``, each a mapping by name or a sequence in the model's order
        (``INPUTS``, ``OUTPUTS``; NaN: not read; ``u`` None: the model's
        inputs); ``line``: its line in the data, for messages. Returns the
        belief after the last step the row gives (a row may give several:
        the steps of a gap before it; none: a row on a step already taken)."""
        if self.finished:
            raise TrackingError(f"{self.source}: this diagnoser has finished", None,
                                "open another with session.diagnoser() for more data")
        t = _time(t, line)
        u = _named(u, self.nominal.INPUTS, "u", line)
        y = _named(y, self.nominal.OUTPUTS, "y", line)
        if self.infer_inputs:  # the first row says which inputs the data give
            if mode_hidden(self.nominal, u, self.source):
                self.hide()
            self.infer_inputs = False
            self.sampler.data_inputs = tuple(name for name in self.nominal.INPUTS if name in u)
        rows = self.sampler.push(t, u, y, line, self._room())
        said = self._forget_if_full()  # once per row: the steps of a row (a gap's) are counted from one start
        if len(rows) == 1 and not said:  # the usual row: one step, its belief as it is
            return self._decoded(rows[0])
        belief = self._through(rows, self._decoded, said)
        if belief is None:  # a row on a step already taken: the belief stands
            belief = dataclasses.replace(self.loop.belief(len(self.loop.events)), events=tuple(said))
        return belief

    @staticmethod
    def _through(samples, take, said=()) -> Belief | None:
        """``take`` of each of ``samples`` in turn: the belief after the last,
        with every one's events, led by ``said`` (None: no sample)."""
        belief, collected = None, list(said)
        for s in samples:
            belief = take(s)
            collected += belief.events
        return None if belief is None else dataclasses.replace(belief, events=tuple(collected))

    def flush(self) -> Belief | None:
        """With the mode read from the data, take the steps still waiting for
        their mode (each with its likeliest: the data stop here, for now, as
        before a gap the monitor bridges); the belief after them, with their
        events (None: none was waiting)."""
        if self.decoder is None or not self.decoder.waiting:
            return None
        return self._through(self.decoder.flush(), self._take)  # each step's events (a step may switch the loop)

    def _room(self) -> int | None:
        """The most steps the next row may give (a row after a gap gives
        one per step): the most the diagnosis holds in memory less the steps
        it holds (the record's, and those waiting for their mode to be
        read); None: no limit. A row that would pass it is refused whole, as
        a clock that jumped, before any of its steps is taken."""
        most = self.config.most
        if most is None:
            return None
        return most - len(self.loop.samples) - (len(self.decoder.waiting) if self.decoder is not None else 0)

    def take(self, s: Sample) -> Belief:
        """Take one step of the grid (a :class:`~bgc.data.sampler.Sample`);
        with the mode read from the data, the steps whose mode it decided
        (none: the belief stands)."""
        said = self._forget_if_full()
        belief = self._decoded(s)
        return dataclasses.replace(belief, events=(*said, *belief.events)) if said else belief

    def _decoded(self, s: Sample) -> Belief:
        """:meth:`take` without forgetting first (the caller did)."""
        if self.decoder is None:
            return self._take(s)
        started = time.perf_counter()
        decided = self.decoder.push(s)
        self.busy += time.perf_counter() - started
        belief = self._through(decided, self._take)
        return self.loop.belief(len(self.loop.events)) if belief is None else belief

    def _take(self, s: Sample) -> Belief:
        """The loop's step of the grid (a :class:`~bgc.data.sampler.Sample`)."""
        started = time.perf_counter()
        try:
            if self.offset:  # the sampler counts the data's steps, the loop those of the record it keeps
                s = dataclasses.replace(s, k=s.k - self.offset, events=shifted_events(s.events, self.offset))
            most = self.config.most
            if most is not None and len(self.loop.samples) >= most:
                where = self.source if s.line is None else f"{self.source}:{s.line}"
                raise TrackingError(f"{where}: the stream reached {most} steps of the model's grid "
                                    f"(t = {self.clock.text(s.t)}), "
                                    "the most a diagnosis of this model with these options holds in memory (4 GB "
                                    "by bgc.api.limits.diagnosis_memory's rule)", None,
                                    "finish this diagnoser and start another for the rest of the stream, or use "
                                    "fewer particles")
            belief = self.loop.take(s)
            degenerate = next((e for e in belief.events if isinstance(e, ev.Degenerate) and e.switched), None)
            return belief if degenerate is None else self._switch(degenerate, belief)
        finally:
            self.busy += time.perf_counter() - started

    def _forget_if_full(self) -> tuple:
        """Watching, with ``keep`` steps to keep and twice that in the record:
        forget its older half, unless the record shows a change no test
        alarmed on (:meth:`_changed_while_watching`: an alarm at its change
        point instead). Returns the events of that alarm (none: ()), for the
        belief of the step that comes next."""
        loop = self.loop
        if self.keep is not None and len(loop.samples) >= 2 * self.keep and loop.detection is None \
                and not self.switched and not self.finished:
            said = self._changed_while_watching()
            if said and not isinstance(said[0], ev.Mismatched):  # an alarm at a change point: the record stays
                return said
            cut = len(loop.samples) - self.keep
            self._forget(cut)
            # a misfit said (its times its own): its steps those of the record kept
            return tuple(dataclasses.replace(e, step=e.step - cut, last=e.last - cut) for e in said)
        return ()

    def _changed_while_watching(self) -> tuple:
        """The test of the record about to be halved (:meth:`_forget_if_full`):
        when it fails the test of the model's fit (:func:`~bgc.diagnosis.fit.fit`,
        the record's excused window left out) or some sensor's residuals
        shift their mean within it (:func:`~bgc.diagnosis.fit.shifted`, the
        CUSUM test: a change in the middle of the record, which the record's
        mean dilutes), each at the level below, and the record
        shows a change as :meth:`_missed_change` finds one at a diagnosis's
        end (:meth:`_change`: the data before the change point fit, the
        residuals changed there, at the same operating point), the loop is
        made again with an alarm raised at the change point (test
        ``change``, :attr:`Loop.forced`, kept in the diagnoser's state and
        raised again when the diagnosis is made again): the diagnosis goes
        on from there as from any alarm. Returns the events said: a
        :class:`~bgc.events.ChangeMissed` (``watching``) and the new loop's
        from its alarm on, the data's aside (said as they came); () when the
        record passes, or fails without such a change (a model that does
        not fit, said at the end as ever). The record holds ``2 keep``
        steps at each test and the next test comes ``keep`` steps later, so
        every change is tested with at least ``keep`` steps on its one side
        or the other. The two tests, one of which every alarm of this rule
        needs, hold a level of their own (:func:`watch_level`, each; their
        union twice it): they add at most :data:`WATCH_SHARE` of the
        detector's false-alarm budget per horizon. They read the nominal
        cubature Kalman filter's residuals (the end's test's observer), which
        a particle observer does not run: its own residuals screen the record
        first, the same tests at :data:`SCREEN` times the level (a record
        they pass is not tested further: the Kalman track over ``2 keep``
        steps would cost more than the particle filter's steps in between)."""
        loop = self.loop
        if self.decoder is not None:  # (the mode read from the data: no change test, as at the end)
            return ()
        level = watch_level(loop.options.false_alarm, self.keep, self.config.horizon)
        if loop.kf is None and not self._screened(SCREEN * level):  # (the Kalman track costs)
            return ()
        ys, us, track = self._tracked()
        T = len(ys)
        fitted = fit(self.nominal, ys, us, loop.outputs, T, level=level, track=track, skip=loop.excused)
        if fitted.fits and not shifted(_residuals(track.z, loop, T), level):
            return ()
        change = self._change(loop.outputs, (ys, us, track))
        if change is None:
            return self._misfit(fitted, T)
        alarm, moved = change
        o = loop.options
        self.config.say(f"watching: no alarm, but the residuals changed at t = "
                        f"{self.clock.text(self.time_of(alarm.step))}: "
                        "an alarm at that change point")
        again = self.replay(dataclasses.replace(o, switch=False), loop.config.every, forced=alarm)
        if again.detection is None:
            return ()
        first = next((i for i, e in enumerate(again.events) if isinstance(e, ev.Alarmed)), len(again.events))
        again.events.insert(first, ev.ChangeMissed(T - 1, alarm.step, moved, tuple(o.detectors), True, True, False,
                                                   True, level))
        self.loop = again
        told = {e for sample in again.samples for e in sample.events}  # the data's, said as they came
        return tuple(e for e in again.events[first:] if e not in told)

    def _misfit(self, fitted, T: int) -> tuple:
        """The record about to be halved for the first time fails the test
        of the model's fit (``fitted``, at the watching level) with no
        change in it: the model does not fit this plant, said as the data
        come (a :class:`~bgc.events.Mismatched` over the record's ``T``
        steps, what to calibrate, the times and count of the record tested
        its own: the record is halved right after), not left to the
        stream's end. One test per diagnoser (its first record of ``2 keep`` steps; kept
        in its state), as the monitor's checkpoint test of the fit: tested
        at every halving of a stream that runs for months, a healthy plant
        would be said off its model by chance in the end; a misfit that
        begins later is a change, the change test's. () when it passed the
        fit test (the CUSUM test alone flagged it), or on a later record."""
        if fitted.fits or self.offset:
            return ()
        span = (self.time_of(0), self.time_of(T - 1), T)
        self.config.say(f"watching: the model does not fit the record kept (t = {self.clock.text(span[0])} to "
                        f"{self.clock.text(span[1])}), "
                        "with no change in it")
        return (misfit_event(self.config.package, T, fitted, span),)

    def _forget(self, cut: int) -> None:
        """Watching, with ``keep`` steps to keep: forget the record's first
        ``cut`` steps (:meth:`Loop.forget <bgc.diagnosis.loop.Loop.forget>`);
        the models of the record kept start from the nominal observer's
        estimate at its first step (:func:`~bgc.model.package.started_package`)."""
        old = self.config.package
        package = started_package(old, *self.loop.forget(cut))
        forgot = package is not old
        if forgot:
            forget_started(old)
        del old
        self._started(package)
        if forgot:  # after the diagnoser let go of it: the collection frees it too
            _collect_forgotten()
        self.offset += cut
        self.config.say(f"watching: the record keeps the last {self.keep} steps (from t = "
                        f"{self.clock.text(self.loop.samples[0].t)})")

    def _started(self, package) -> None:
        """Run on ``package`` (a started package) from now on."""
        self.config = dataclasses.replace(self.config, package=package)
        self.nominal = nominal_model(package)
        if hasattr(self, "loop"):
            self.loop.config = dataclasses.replace(self.loop.config, package=package)
            self.loop.nominal = self.nominal

    def again(self, package: Package | None = None, sensors=None) -> Diagnoser:
        """A new diagnoser of this one's configuration, for the rows after
        the last one this one took: on ``package`` (a started package of this
        one's, :func:`~bgc.model.package.started_package`: a fault
        accommodated, a start elsewhere; None: this one's) and with
        ``sensors`` (None: this one's)."""
        c = self.config
        return Diagnoser(c.package if package is None else package, c.signatures, c.priors, c.options, c.horizon,
                         time_unit=c.time_unit, inputs=c.inputs, sensors=c.sensors if sensors is None else sensors,
                         source=c.source,
                         lazy=c.lazy, every=c.every, progress=c.progress, most=c.most)

    def time_of(self, step: int) -> float:
        """The time of step ``step`` of the grid."""
        return self.loop.samples[step].t

    def belief(self) -> Belief:
        """The belief after the last step taken (every event so far)."""
        return self.loop.belief()

    def arrays(self) -> dict[str, np.ndarray]:
        """The record and the nominal observer's arrays (steps x ...)."""
        return self.loop.arrays()

    # -- the policies ---------------------------------------------------------------------------------------

    def _switch(self, degenerate: ev.Degenerate, belief: Belief | None = None) -> Belief | None:
        """The policy for a degenerate particle observer (the loop's
        ``Degenerate`` event with ``switched``): the record goes to a new loop
        with cubature Kalman filters (a ``Switched`` event), which takes
        every sample so far. The belief of the step: this step's events of
        the old loop (its alarm aside: the new loop's stands), then the new
        loop's, those of the data already said aside."""
        switched = ev.Switched(KALMAN_METHOD, "degenerate", degenerate.step)
        self.switched = (degenerate, switched)
        o = self.config.options
        self.loop = self.replay(dataclasses.replace(o, filter=KALMAN_METHOD, rank=False, refine=False),
                                self.loop.config.every)
        if belief is None:
            return None
        inner = self.loop.belief()
        told = {e for sample in self.loop.samples for e in sample.events}  # the data's, said as they came
        mine = tuple(e for e in belief.events if not isinstance(e, ev.Alarmed)) + (switched,)
        return dataclasses.replace(inner, events=mine + tuple(e for e in inner.events if e not in told))

    def replay(self, options: DiagnosisOptions, every: bool, lazy: bool | None = None, after=None,
               forced=None) -> Loop:
        """A loop with ``options`` that has taken every step of the record of
        the loop that runs now, its data events with them (``lazy``: None,
        the configuration's; ``after``: a false alarm, a
        :class:`~bgc.diagnosis.detect.Detection`: its detector armed from the
        next step and the alarm's window left out of the test of the
        model's fit, :attr:`Loop.watch_from`, :attr:`Loop.excused`;
        ``forced``: an alarm, a ``Detection``, raised at its step unless the
        detector alarmed first, :attr:`Loop.forced`)."""
        loop = Loop(self._loop_config(options, every, self.config.lazy if lazy is None else lazy))
        loop.forced = forced
        _armed_after(loop, after)
        for s in self.loop.samples:
            loop.take(s)
        return loop

    def _after_false_alarm(self, d: Diagnosis, truth: Run | None) -> Diagnosis:
        """A diagnosis whose alarm was a false one (:meth:`_false_alarm`) is
        made again with the detector armed anew after the alarm (its window
        left out of the test of the model's fit: an excursion the
        detector's budget allows): the fault's alarm, symbols and onsets
        are then its own, and every fault model is weighed from there, not
        only those the false alarm's symbols kept. The diagnosis made again
        is the verdict when it names a fault that explains the whole record
        better than the first one's (:meth:`_support`: a fault that truly
        began at the first alarm and showed only now and then, at an input's
        transients or coming and going, explains the first alarm's samples
        too), and a :class:`~bgc.events.FalseAlarm` says so. An alarm on one
        reading after which the data stay quiet to their end was a glitch of
        that reading (:class:`~bgc.events.Glitch`): the diagnosis made again,
        which raises no alarm, is the verdict (no fault, or the model's
        mismatch when the rest of the data do not fit it), unless a fault
        model the first one weighed explains the samples after that reading
        (:meth:`_explained_after`). Made once (not again on the diagnosis
        made again); on a model whose mode the data do not give as well (a
        reading off at a switch its guard made within a step, then a fault):
        the two diagnoses compare on the nominal model's reading of the
        modes, and the one chosen has its faults' modes read again from
        their onsets (:meth:`_reread`), from after the false alarm when it
        is the diagnosis made again (the alarm armed past, its
        :class:`~bgc.events.FalseAlarm` kept)."""
        self.false_alarm = None  # (the alarm and its FalseAlarm, when the diagnosis made again is the verdict)
        told = self._false_alarm(d)
        if told is None:
            return d
        first = d.detection
        self.config.say(f"the alarm at t = {self.clock.text(self.loop.samples[first.step].t)} may be a false one: "
                        f"watching again "
                        f"from the next sample")
        options = dataclasses.replace(self.loop.options, switch=False)  # the filters as they ended (as _retry)
        redone = self._finished(self.replay(options, self.loop.config.every, after=first),
                                lambda: self.replay(options, True, after=first), truth)
        until, name, glitch = told
        if glitch and redone.detection is None:  # one reading, quiet after it: a glitch
            if self._explained_after(d, first.step):  # unless a fault weighed explains what follows it
                return d
            said = ev.Glitch(first.step, first.sensor, float(first.statistic), len(self.loop.samples) - 1)
            return dataclasses.replace(redone, events=ordered([*redone.events, said]))
        if redone.detection is None or not self._support(redone) > self._support(d):
            return d
        again = redone.detection
        if until is None:
            until = again.step if again.onset_step is None else again.onset_step
        name = name if redone.candidates[:1] == (name,) else ""  # a fault the diagnosis made again does not name
        said = ev.FalseAlarm(first.step, first.sensor, first.test, first.step + 1, until, name)
        self.false_alarm = (first, said)  # the modes read again (_reread) are watched from after it too
        return dataclasses.replace(redone, events=ordered([*redone.events, said]))

    def _explained_after(self, d: Diagnosis, step: int) -> bool:
        """Whether a fault model diagnosis ``d`` weighed explains the data
        after step ``step`` (an alarm on one reading) decisively better than
        no fault: its residuals at its static posterior's most likely cell
        (its Kalman filter's predicted means and stds, from its start) are
        likelier over the samples after ``step`` than the nominal cubature
        Kalman filter's, by more than the verdict's Bayes factor. A step of a
        part that the nominal observer absorbs into its states leaves a
        spike at its onset and a small shift after it, which the test of the
        model's fit over a short stretch does not see; the fault's own model
        does. A glitch's reading explains nothing after it (a sensor's
        offset held from it is worse than none there)."""
        from ..filters.cubature import nominal_track
        from .hypothesis import log_density

        a = self.loop.arrays()
        ys, T = a["ys"].copy(), len(a["ys"])
        if step + 1 >= T or d.detection is None:
            return False
        # no fault with the reading left out: an observer that took it in carries it into the samples after
        ys[step, list(self.loop.outputs).index(d.detection.sensor)] = np.nan
        track = nominal_track(self.loop.nominal, ys, a["us"], T)
        null = log_density(track.z[:T], track.y_std[:T])
        bound = math.log(self.loop.options.bayes_factor)
        for h in d.hypotheses:
            # the nominal's where the hypothesis has no residual: before its start, or none at all (no finite cell)
            own, z = null.copy(), np.asarray(h.z, dtype=float)[:T - h.start_step]
            read = h.start_step + np.flatnonzero(np.isfinite(z).any(axis=1))
            own[read] = log_density(z, np.asarray(h.y_std, dtype=float)[:len(z)])[read - h.start_step]
            if float(np.sum(own[step + 1:] - null[step + 1:])) > bound:
                return True
        return False

    def _support(self, d: Diagnosis) -> float:
        """How well diagnosis ``d``'s verdict explains the whole record: its
        first candidate's log prior plus its log evidence (its static
        posterior's, or coming and going, its intermittent one's with its
        share of the prior, whichever is larger), on the scale every
        diagnosis of the record shares (the onsets' likelihood summed over
        the samples they stand for); -inf when it names no fault (a verdict
        ``unexplained``, ``mismatch`` or ``no fault``, or no fault holding a
        share beside the faults named: a :class:`~bgc.events.NoFault`)."""
        from .intermittent import SHARE

        if d.verdict not in ("isolated", "ambiguous") or not d.candidates \
                or any(isinstance(e, ev.NoFault) for e in d.events):  # no fault still in play
            return -math.inf
        h = next((h for h in d.hypotheses if h.name == d.candidates[0]), None)
        if h is None:
            return -math.inf
        evidence = h.static.log_evidence if h.static is not None else -math.inf
        if h.intermittent is not None:
            evidence = max(evidence, h.intermittent.log_evidence + math.log(SHARE))
        return log_prior(self.config.priors, h.parameter) + evidence

    def _false_alarm(self, d: Diagnosis) -> tuple[int | None, str, bool] | None:
        """Whether the alarm of diagnosis ``d`` may be a false one, a fault
        beginning later: (the step the model's residuals stay within its
        noise until, the fault model that explains the data from there, or
        None and "": until the diagnosis made again alarms; and whether it
        was a glitch, one reading off and the residuals quiet after it to
        the data's end), or None. Either a fault the verdict names (or keeps as a possibility)
        was dated anew (:class:`~bgc.events.Redated`,
        :mod:`bgc.diagnosis.later`) after the alarm, or the nominal
        observer's residuals after it stay within the model's noise (the
        test of the model's fit, :mod:`bgc.diagnosis.fit`) until the
        windowed mean test, armed anew from the next step with the
        detector's windows and budget, alarms again, or to the data's end
        when the alarm was one reading (the mean test's one-sample window);
        the quiet stretch at least the detector's longest window each way,
        or between an alarm on one reading and the next alarm the detector's
        next window (:func:`quiet_enough`). Not an alarm of the
        frozen-reading test (a frozen sensor's residuals are quiet), nor of
        the change test (raised at a change point after the record showed
        the change), nor on a diagnosis made again (the detector armed anew once)."""
        first = d.detection
        if first is None or self.loop.watch_from or first.test in ("frozen", "change"):
            return None
        o, present = self.loop.options, self.loop.present
        longest = max(o.windows)
        moved = [e for e in d.events if isinstance(e, ev.Redated) and e.alarmed is not None and e.alarmed < e.onset
                 and e.hypothesis in d.candidates and e.onset - first.step - 1 >= longest]
        if moved:
            return moved[0].onset, moved[0].hypothesis, False
        sensors = tuple(y for y, read in zip(self.loop.outputs, present) if read)
        z = np.asarray(d.nominal_z, dtype=float)[first.step + 1:][:, present]
        detector = Detector(sensors, DetectorOptions(o.false_alarm, o.windows, self.loop.horizon))
        again = next((a for a in map(detector.update, z) if a is not None), None)
        if again is None and (first.test != "mean" or first.window != 1):  # quiet after more than one reading
            return None
        quiet = z if again is None else z[:again.onset_step if again.onset_step is not None else again.step]
        if len(quiet) < quiet_enough(first, o.windows, again is not None) or fails(self.nominal, quiet, sensors):
            return None
        return None, "", again is None  # quiet to where the diagnosis made again alarms, or to the end

    def _finished(self, loop: Loop, again: Callable[[], Loop], truth: Run | None) -> Diagnosis:
        """The diagnosis of ``loop`` (it has taken the record), by the policy
        for an unexplained verdict: made again on the loop ``again`` builds
        (every fault model weighed) when :meth:`_retry` says so; faults that
        come and go tried as :attr:`intermittent` says."""
        d = loop.finish(self.sampler.summary(), truth, self.intermittent)
        if self._retry(d, loop):
            d = again().finish(self.sampler.summary(), truth, self.intermittent)
        return d

    def _retry(self, d: Diagnosis, loop: Loop | None = None) -> bool:
        """Whether an unexplained verdict (of ``loop``, None: the loop that
        runs now) is to be made again with every fault model: some the
        symbols ruled out were not weighed (step 6b did not run: no
        hypothesis the symbols kept survived its filters). A mismatch made
        of an unexplained alarm that saw no change
        (:attr:`~bgc.diagnosis.values.Fit.unchanged`) too: a fault model the
        symbols ruled out may explain the change all the same."""
        loop = self.loop if loop is None else loop
        unexplained = d.verdict == "unexplained" or (d.verdict == "mismatch" and d.fit is not None and d.fit.unchanged)
        if not unexplained or loop.config.every or loop.isolation is None:
            return False
        untried = set(loop.isolation.untried(self.config.package)) - {h.name for h in d.hypotheses}  # 6b's weighed
        if untried:
            self.config.say("no hypothesis the symbols kept explains the data: trying those they ruled out")
            return True
        return False

    # -- the end --------------------------------------------------------------------------------------------

    def finish(self, truth: Run | None = None) -> Diagnosis:
        """The diagnosis of the record (the stream ends here); ``truth``: the
        run, when it records the true fault (its parameter columns)."""
        if not self.finished:  # the diagnosis's seconds: its steps' and its end's, not the waits for data
            if self.decoder is not None:  # the samples still waiting, with their likeliest modes
                for s in self.decoder.flush():
                    self._take(s)
            self.finished = True
            self.started = time.perf_counter() - self.busy
        if not self.loop.samples:
            raise TrackingError(f"{self.source}: no sample to diagnose", None, "give at least one row of data")
        sys.modules.setdefault(self.config.package.__name__, self.config.package)  # a started package, for the workers
        if not self.switched and self.loop.detection is None:  # degenerate over a run without an alarm
            degenerate = self.loop.degenerate()
            if degenerate is not None:
                self.loop.events.append(degenerate)
                if degenerate.switched:
                    self._switch(degenerate)
        if self.decoder is None:
            diagnosis = self._first(truth)
        else:  # faults that come and go tried once the modes are read, on the reading chosen (_reread)
            diagnosis = self._first(truth, intermittent=False)
            if self.loop.detection is not None and (diagnosis.detection is None or diagnosis.verdict == "no fault"):
                # an alarm the trial bears on all the same: a glitch's test reads the faults it dates anew
                diagnosis = self._first(truth)
            if diagnosis.detection is not None and diagnosis.verdict != "no fault":
                # (no fault after the alarm: the nominal reading stands; a fault model's own reading would be
                # weighed against no fault on that fault's modes, not on the nominal's)
                diagnosis = self._reread(diagnosis, truth)
        if self.switched:
            diagnosis = dataclasses.replace(diagnosis, events=ordered(list(self.switched) + list(diagnosis.events)))
        return dataclasses.replace(diagnosis, seconds=time.perf_counter() - self.started)

    def _first(self, truth: Run | None, intermittent: bool = True) -> Diagnosis:
        """The diagnosis of the record as the loop took it: the loop's (made
        again with every fault model when unexplained, :meth:`_retry`; an
        alarm the record's test raised while watching raised again), after a
        false alarm (:meth:`_after_false_alarm`), and of a change the
        detector missed (:meth:`_missed_change`); ``intermittent`` False:
        faults that come and go not tried (:attr:`intermittent`, for its
        course)."""
        self.intermittent = intermittent
        try:
            diagnosis = self._finished(self.loop, lambda: self.replay(
                dataclasses.replace(self.loop.options, switch=False), True, forced=self.loop.forced), truth)
            diagnosis = self._after_false_alarm(diagnosis, truth)
            return self._missed_change(diagnosis, truth)
        finally:
            self.intermittent = True

    def _missed_change(self, d: Diagnosis, truth: Run | None) -> Diagnosis:
        """A mismatch without an alarm that is a change the detector missed rather than a model that does not fit:
        the whole record fails the test of the model, but the data before the residuals' change point
        (the generalised likelihood ratio's of a mean shift over the record, every sensor; at least
        :data:`~bgc.diagnosis.fit.LEAST` samples each side) pass it, some sensor read on both sides has
        residuals that differ after it from before beyond chance (:func:`~bgc.diagnosis.fit.changed`),
        the data before it are decisively likelier under the model than like those after it
        (:func:`~bgc.diagnosis.fit.misfit_before` under minus the log of the options' ``bayes_factor``:
        a few samples before a change point at a record's start cannot vouch for the model), and the
        inputs after it stay within the
        range they had before, the modes among those seen before (a model whose misfit only a new
        operating point excites, a capacitance off that an input step shows, passes the other tests: it
        stays a mismatch). Not after an alarm (a false one, or a glitch, made again), nor when the
        inputs read with the other timing explain the misfit. The diagnosis is then made again with
        every test of the detector's bank (unless they all ran), and is that one when it names a fault
        (isolated or ambiguous). When no test of the bank alarms (a change the observer follows, its
        residuals off by a fraction of their noise for long: no window of any test reaches its
        threshold; a bank that alarmed and named no fault judged the misfit itself), the diagnosis is
        made from an alarm raised at the change point (test ``change``, the statistic of
        :func:`~bgc.diagnosis.fit.changed`; an unexplained verdict made again with every fault model,
        :meth:`_retry`): its verdict stands when it names a fault whose residuals pass the test of the
        model's fit (:meth:`_explains`), or finds none that explains the change (unexplained: the plant
        changed, the model fitted it before). A :class:`~bgc.events.ChangeMissed` says which."""
        o, loop = self.loop.options, self.loop
        if (d.verdict != "mismatch" or d.detection is not None or loop.detection is not None
                or self.decoder is not None
                or any(isinstance(e, ev.Mismatched) and e.timing is not None for e in d.events)):
            return d
        change = self._change(d.outputs)
        if change is None:
            return d
        alarm, moved = change
        found, at, made = "", alarm.step, None
        rerun = set(o.detectors) != set(TESTS)  # (the bank ran already: the same diagnosis again)
        if rerun:
            self.config.say(f"no alarm, but the residuals changed at t = {d.clock.text(d.time[at])}: diagnosing again "
                            "with every test of the detector's bank")
            options = dataclasses.replace(o, detectors=TESTS, switch=False)
            made = self.replay(options, loop.config.every).finish(self.sampler.summary(), truth)
            found = "bank" if made.detection is not None and made.verdict in ("isolated", "ambiguous") else ""
        if made is None or made.detection is None:  # (a bank that alarmed and named no fault judged the misfit)
            self.config.say(f"diagnosing from an alarm at the change point, t = {d.clock.text(d.time[at])}")
            options, every = dataclasses.replace(o, switch=False), loop.config.every
            made = self._finished(self.replay(options, every, forced=alarm),
                                  lambda: self.replay(options, True, forced=alarm), truth)
            if made.detection is not None and (made.verdict == "unexplained" or (
                    made.verdict in ("isolated", "ambiguous") and self._explains(made))):
                found = "change"
        said = ev.ChangeMissed(len(d.time) - 1, at, moved, tuple(o.detectors), bool(found), found == "change", rerun)
        chosen = made if found else d
        return dataclasses.replace(chosen, events=ordered([*chosen.events, said]))

    def _explains(self, d: Diagnosis) -> bool:
        """Whether a fault that diagnosis ``d`` names (from an alarm at the
        change point) explains the record: its static posterior's residuals
        from its most likely onset pass the test of the model's fit, mean and
        variance (:mod:`bgc.diagnosis.fit`; the windowed tests of its filters
        are as weak as the detector's were, which saw nothing); a fault the
        particle filters sized (no static posterior) is taken as named."""
        tested = [h for h in d.hypotheses if h.name in d.candidates]
        for h in tested:
            p = h.static
            if p is None or p.residuals is None or p.best is None:
                return True
            z = np.asarray(p.residuals, dtype=float)[int(p.best[0]):]
            if not fails(self.nominal, z, d.outputs):
                return True
        return False

    def _screened(self, level: float) -> bool:
        """Whether a particle observer's own residuals over the record flag
        it (:meth:`_changed_while_watching`'s screen): its fit test's
        failures or the CUSUM test's shift at ``level``."""
        loop = self.loop
        z = _residuals(loop.z, loop, len(loop.samples))
        return bool(fails(self.nominal, z, loop.outputs, level)) or bool(shifted(z, level))

    def _tracked(self) -> tuple:
        """The record's measurements and inputs (steps x ...) and the
        nominal cubature Kalman filter's track over it (the Kalman observer's
        own, else computed)."""
        from ..filters.cubature import nominal_track

        loop = self.loop
        record = loop.arrays()
        ys, us = record["ys"], record["us"]
        return ys, us, loop.kf.track() if loop.kf is not None else nominal_track(self.nominal, ys, us, len(ys))

    def _change(self, outputs: tuple[str, ...], tracked=None) -> tuple[Detection, tuple[str, ...]] | None:
        """The change of :meth:`_missed_change` in the record, as an alarm
        at its change point (test ``change``: the sensor whose residuals
        changed most, the statistic of :func:`~bgc.diagnosis.fit.changed`,
        its window the samples from there to the end) and the sensors whose
        residuals changed; None where there is none (the rules of :meth:`_missed_change`).
        ``outputs``: the record's sensors; ``tracked``: :meth:`_tracked`'s
        (the record and the nominal Kalman track), when the caller has it."""
        loop = self.loop
        ys, us, track = self._tracked() if tracked is None else tracked
        T = len(ys)
        z = _residuals(track.z, loop, T)
        cumsum = np.concatenate([np.zeros((1, z.shape[1])), np.cumsum(np.nan_to_num(z), axis=0)])
        at = change_point(cumsum, T - 1, T)
        if at < LEAST or T - at < LEAST or not fit(self.nominal, ys, us, outputs, at, track=track).fits:
            return None
        both = [j for j in range(z.shape[1]) if (np.isfinite(z[:at, j]).sum() >= LEAST
                                                  and np.isfinite(z[at:, j]).sum() >= LEAST)]
        statistics, cut = change_statistics(z[:, both], at) if both else ({}, np.inf)
        moved = tuple(outputs[both[i]] for i, value in statistics.items() if not value <= cut)
        # the data before the change point vouch for the model only where they are decisively (the Bayes factor)
        # likelier under it than like the data after it: a few samples before a misfit's start (the observer's
        # first steps, a record's first after it was halved) cannot tell a change from a model that never fitted
        if not moved or not misfit_before(z, at) < -math.log(loop.options.bayes_factor) \
                or _new_point(self.nominal, us, at):
            return None
        i = max(statistics, key=lambda i: np.nan_to_num(statistics[i], nan=np.inf))
        return Detection(at, outputs[both[i]], T - at, statistics[i], cut, at, "change"), moved

    def _reread(self, d: Diagnosis, truth: Run | None) -> Diagnosis:
        """The policy for a hidden mode read with the nominal model: a fault
        may move the switches (a guard crossed early), and then the faulty
        plant's modes are not those the nominal model reads. The :data:`POOL`
        hypotheses the diagnosis weighed likeliest (the verdict's candidates
        first) read the modes with their own equations at the onset and size
        that make the data likeliest with the modes hidden (:func:`~bgc.diagnosis.hidden.read_fault`);
        the :data:`REREAD` likeliest so (the nominal reading's weighing alone
        is no ranking here: its misread switches weigh against the very fault
        that moved them), and the twin of a candidate that is a switch's fault
        (:func:`_twin`), take their readings, and the diagnosis is made again
        on each reading that differs (:meth:`_on_readings`: one weighed out
        by the Bayes factor is not); a hypothesis that a diagnosis made again isolates, or
        names ambiguous with its twin alone (the two the same plant on that
        reading), explains the data with the modes it reads itself. One such,
        or several whose diagnoses agree: that diagnosis is the verdict; none,
        or several that disagree: ``d`` stands, the readings said
        (:class:`~bgc.events.ModesReread`). ``d`` did not try faults that
        come and go (a reading is likely to be chosen over it): when it
        stands, it is made again with them tried (:meth:`_first`), as the
        diagnoses on the readings tried them (a fault that persists from
        after every onset tried is dated anew by their banks,
        :func:`~bgc.diagnosis.later.redated`)."""
        ranked = sorted(d.hypotheses, key=lambda h: (h.name not in d.candidates, -h.posterior, -h.log_evidence))
        weighed = [h for h in ranked if math.isfinite(h.estimate.value)][:POOL]
        if not weighed:
            return self._first(truth)
        index = self.nominal.MODE_INPUT
        read = np.array([s.u[index] for s in self.loop.samples])
        raw = [_unread(s, index) for s in self.loop.samples]
        pooled = {h.name for h in weighed}
        twins = [h for h in ranked if h.name in map(_twin, d.candidates) and h.name not in pooled
                 and math.isfinite(h.estimate.value)]  # a candidate switch fault's twin, read too
        readings = self._fault_readings(weighed + twins, raw)
        names = sorted(readings, key=lambda name: -readings[name][2])[:REREAD]
        names += [twin for twin in map(_twin, d.candidates) if twin in readings and twin not in names]
        said, explained = self._on_readings(d, names, readings, raw, read, truth)
        _, false = self.false_alarm or (None, None)
        # one reading that explains the data, or several whose diagnoses agree (a stuck switch's and its
        # twin's: each reads the other's modes, and both come out as the same pair)
        agree = all((e.verdict, set(e.candidates)) == (explained[0][0].verdict, set(explained[0][0].candidates))
                    for e, _, _ in explained)
        chosen, moved, _ = explained[0] if explained and agree else (d, False, "")
        if not moved:  # d stands: made again with faults that come and go tried
            chosen = self._first(truth)
        kept = [false] if false is not None and moved else []  # the false alarm, said again
        return dataclasses.replace(chosen, events=ordered(list(chosen.events) + kept + said))

    def _on_readings(self, d: Diagnosis, names: list[str], readings: dict, raw: list[Sample], read: np.ndarray,
                     truth: Run | None) -> tuple[list, list]:
        """The diagnosis made again on the readings of hypotheses ``names``
        (the likeliest first; ``readings``: :meth:`_fault_readings`'s) of
        the samples ``raw`` whose nominal reading is ``read``, on each that
        differs (``d`` on one that does not). When the likeliest reading
        explains the data, a reading under which the data are less likely
        than under it by more than the log of the options' Bayes factor (each
        at its likeliest onset and size: a profile likelihood, compared as
        the weighing compares evidence) is weighed out, neither compared nor
        diagnosed again, unless its hypothesis is one of ``d``'s candidates
        or their twins. Returns the readings' events and the diagnoses that
        explain the data with the modes their hypothesis reads (each with
        whether its modes differ, and the hypothesis)."""
        index = self.nominal.MODE_INPUT
        said, explained = [], []
        first, _ = self.false_alarm or (None, None)
        best, cut = names[0], math.log(self.loop.options.bayes_factor)
        kept = set(d.candidates) | set(map(_twin, d.candidates))
        for name in names:
            onset, start, loglik, head = readings[name]
            below = readings[best][2] - loglik
            if explained and explained[0][2] == best and name not in kept and below > cut:
                # decisively less likely with its own modes than the likeliest, which explains the data: weighed out
                said.append(ev.ModesReread(len(read) - 1, name, 0, False, best, float(below)))
                continue
            samples = read_again(self.config.package.MODELS[name], raw, (onset, start), head)
            changed = int(np.sum(np.array([s.u[index] for s in samples]) != read))
            again = d if not changed else self._made_on(samples, first, truth)
            explains = (again.verdict == "isolated" and again.candidates == (name,)) or (
                again.verdict == "ambiguous" and set(again.candidates) == {name, _twin(name)})
            said.append(ev.ModesReread(len(read) - 1, name, changed, explains))
            if explains:
                explained.append((again, bool(changed), name))
        return said, explained

    def _fault_readings(self, hyps: list, raw: list[Sample]) -> dict:
        """Where each hypothesis of ``hyps`` reads the modes of the samples
        ``raw`` (mode NaN) with its fault model: the onset (within ONSETS
        samples before its diagnosis's to 2 after) and size that make the
        data likeliest with the modes hidden (:func:`~bgc.diagnosis.hidden.read_fault`, its
        diagnosis's estimate a hint), the readings on the options' worker
        processes (:func:`~bgc.diagnosis.parallel.parallel_map`). By name:
        (the onset, its fault states there, the log-likelihood of the data
        so, the nominal reading before the onsets, shared by the hypotheses
        read from the same first onset)."""
        heads: dict = {}
        jobs = []
        for h in hyps:
            onset, value = h.static.best if h.static is not None and h.static.best else (h.onset_step, h.estimate.value)
            model = self.config.package.MODELS[h.name]
            onsets = [k for k in range(onset - ONSETS, onset + 3) if 0 <= k < len(raw)]
            nominal = np.asarray(self.loop.x_mean[max(onsets[0] - 1, 0)], dtype=float)[:, None]
            _, extra = state_rows(model)
            start = np.asarray(model.augment(nominal, np.random.default_rng(0)), dtype=float)[extra, 0]
            if onsets[0] not in heads:  # the nominal reading before an onset, shared by the hypotheses from it
                heads[onsets[0]] = read_head(self.nominal, raw, onsets[0], self.branches)
            jobs.append((self.config.package.__name__, h.name, raw, onsets, start, value, heads[onsets[0]]))
        self.config.say(f"reading the modes again with the equations of {', '.join(h.name for h in hyps)}")
        readings = {}
        for job, (onset, size, loglik) in zip(jobs, parallel_map(read_job, jobs, self.options.workers)):
            _, name, _, _, start, _, head = job
            start = start.copy()
            start[-1] = size
            readings[name] = (onset, start, loglik, head)
        return readings

    def _made_on(self, samples: list[Sample], after, truth: Run | None) -> Diagnosis:
        """The diagnosis made again on ``samples`` (another reading of the
        modes; ``after``: a false alarm, :meth:`_loop_of`), by the policy the
        first one had: unexplained, made again with every fault model
        (:meth:`_retry`). A fault moves the switches, and the symbols read
        over a switch the fault moved can rule that fault out (a thermostat's
        wall losing more heat keeps its heater on longer, and the radiator's
        temperature reads above the nominal's, where the fault's own
        signature says below)."""
        return self._finished(self._loop_of(samples, after),
                              lambda: self._loop_of(samples, after, every=True, switch=False), truth)

    def _loop_of(self, samples: list[Sample], after=None, every: bool | None = None, switch: bool = True) -> Loop:
        """A loop of this diagnoser's options that has taken ``samples``
        (``after``: a false alarm, as :meth:`replay` takes it: the options'
        switch off, as the diagnosis made again after it had them; ``every``:
        every fault model weighed, None: as this diagnoser's loop; ``switch``
        False: the options' switch off)."""
        options = self.loop.options if after is None and switch else dataclasses.replace(self.loop.options,
                                                                                         switch=False)
        every = self.loop.config.every if every is None else every
        loop = Loop(self._loop_config(options, every, self.config.lazy))
        _armed_after(loop, after)
        for s in samples:
            loop.take(s)
        return loop

    def checkpoint(self) -> Diagnosis:
        """The diagnosis of the data so far, the stream going on: the
        :meth:`finish` of a copy of this diagnoser, made from its state (the
        hypotheses it tracks online are not tracked again)."""
        return Diagnoser.from_state(self.config, self.to_state()).finish()

    # -- the state ------------------------------------------------------------------------------------------

    def to_state(self):
        """This diagnoser's state as plain data (a
        :class:`~bgc.diagnosis.state.DiagnoserState`; ``to_bytes`` for a file)."""
        from .state import diagnoser_state

        return diagnoser_state(self)

    @classmethod
    def from_state(cls, config: DiagnoserConfig, state) -> Diagnoser:
        """The diagnoser of ``config`` in ``state`` (from :meth:`to_state`, or
        :meth:`~bgc.diagnosis.state.DiagnoserState.from_bytes`): the steps
        after it give the numbers the diagnoser that saved it would have."""
        from .state import restore_diagnoser

        return restore_diagnoser(cls, config, state)


def _unread(s: Sample, index: int) -> Sample:
    """Sample ``s`` with its mode (input ``index``) not read: NaN, its
    :class:`~bgc.events.ModeRead` events gone."""
    u = s.u.copy()
    u[index] = np.nan
    return dataclasses.replace(s, u=u, events=tuple(e for e in s.events if not isinstance(e, ev.ModeRead)))


def _twin(name: str) -> str:
    """A switch's fault model that is the same plant as fault model ``name``
    until a mode asks for the switch where the fault put it: a stuck switch's
    and the uncommanded change of the same switch the same way
    (``K_stuck_on`` and ``K_uncommanded_on``); "" for any other."""
    from ..kinds import SWITCH_KINDS, fault_parameter, kind_of

    kind = kind_of(name)
    if kind not in SWITCH_KINDS:
        return ""
    suffix, way = kind.split("_")
    return f"{fault_parameter(name)}_{'stuck' if suffix == 'uncommanded' else 'uncommanded'}_{way}"


def _armed_after(loop: Loop, after) -> None:
    """``loop``'s detector armed from the step after the false alarm
    ``after`` (a :class:`~bgc.diagnosis.detect.Detection`; None: nothing),
    the alarm's window left out of the test of the model's fit
    (:attr:`Loop.watch_from`, :attr:`Loop.excused`)."""
    if after is None:
        return
    loop.watch_from = after.step + 1
    start = after.step - after.window + 1
    loop.excused = (max(min(start, after.onset_step if after.onset_step is not None else start), 0), after.step + 1)


def quiet_enough(first, windows: tuple[int, ...], again: bool) -> int:
    """The fewest samples of a quiet stretch after alarm ``first`` that make
    it a false one (:meth:`Diagnoser._false_alarm`), with the detector's
    ``windows``: the longest window (quiet to the data's end after one
    reading, a glitch, or after a longer window's alarm), or between an
    alarm on one reading (the mean test's one-sample window) and the next
    alarm (``again``) the next window after the shortest. One reading off
    is the false alarm the budget allows most often, and the diagnosis made
    again is the verdict only when it explains the whole record better
    (:meth:`Diagnoser._support`): a guard crossed within a step on a plant
    whose mode the data do not give leaves one such reading at the switch,
    and a fault a few tens of samples later would otherwise be sized from
    the switch, where it had not begun."""
    ordered_windows = sorted(set(windows))
    if again and first.test == "mean" and first.window == ordered_windows[0] == 1 and len(ordered_windows) > 1:
        return ordered_windows[1]
    return ordered_windows[-1]


def _residuals(values, loop: Loop, T: int) -> np.ndarray:
    """Normalised residuals ``values`` (a track's or an observer's, per
    step) over the record's ``T`` steps (steps x sensors), NaN where a
    sensor has no column."""
    z = np.array(values, dtype=float)[:T].reshape(T, len(loop.outputs))
    z[:, ~loop.present] = np.nan
    return z


def _new_point(nominal, us: np.ndarray, at: int) -> bool:
    """Whether the inputs ``us`` (steps x inputs) from step ``at`` on leave
    the range they had before it, or a mode column (the model's
    ``MODE_INPUT``) reads a mode not read before it: a new operating point,
    where a model's misfit that it alone excites cannot be told from a fault."""
    with np.errstate(all="ignore"):
        low, high = np.nanmin(us[:at], axis=0), np.nanmax(us[:at], axis=0)
        slack = 1e-9 * np.maximum(np.abs(low), np.abs(high)) + 1e-12
        if np.any((us[at:] < low - slack) | (us[at:] > high + slack)):
            return True
    column = getattr(nominal, "MODE_INPUT", None)
    if column is None:
        return False
    seen = set(us[:at, column][np.isfinite(us[:at, column])].tolist())
    return any(m not in seen for m in us[at:, column][np.isfinite(us[at:, column])].tolist())


def _time(t, line) -> float:
    """A row's time: a real number (NaN and the rest are the sampler's to refuse, with the line)."""
    if not is_real(t):
        where = "" if line is None else f" (line {line})"
        raise ArgumentTypeError(f"Diagnoser.step: t={shown(t)}{where} is not a number", None,
                                "give the row's time as a float")
    return as_float(t)


def _named(values, names, what: str, line) -> dict[str, float]:
    """A row's cells by name: from a mapping (each key one of ``names``), or
    a sequence in ``names``' order (None: none); each a real number or NaN
    (not read), never infinite."""
    if values is None:
        return {}
    if type(values) in (list, tuple) and len(values) == len(names) and all(type(v) is float for v in values):
        return _floats(values, names, what, line)  # the usual row: floats in the model's order
    where = "" if line is None else f" (line {line})"
    if isinstance(values, Mapping):
        unknown = [k for k in values if k not in names]
        if unknown:
            raise ArgumentValueError(f"Diagnoser.step: {what} has {shown(unknown[0])}{where}, not one of the model's "
                                     f"{'inputs' if what == 'u' else 'sensors'} ({', '.join(names) or 'none'})", None,
                                     "use the model's names (bgc show equations MODEL lists them)")
        pairs = list(values.items())
    else:
        if isinstance(values, (str, bytes)) or not hasattr(values, "__len__"):
            raise ArgumentTypeError(f"Diagnoser.step: {what}={shown(values)}{where} is not a mapping or a sequence",
                                    None, "give a dict by name, or one value per name in the model's order")
        cells = list(np.asarray(values, dtype=object).reshape(-1)) if len(values) else []
        if len(cells) != len(names):
            raise ArgumentValueError(f"Diagnoser.step: {what} has {len(cells)} values{where} for {len(names)} names "
                                     f"({', '.join(names)})", None,
                                     "give one value per name, in the model's order, or a mapping by name")
        pairs = list(zip(names, cells))
    out = {}
    for name, v in pairs:
        if not is_real(v) or math.isinf(as_float(v)):
            raise ArgumentValueError(f"Diagnoser.step: {what}[{name}]={shown(v)}{where} is not a finite number", None,
                                     "give a float, or NaN for a value not read")
        out[str(name)] = as_float(v)
    return out


def _floats(values, names, what: str, line) -> dict[str, float]:
    """:func:`_named` of a sequence of floats, one per name in ``names``'
    order: each finite or NaN, else the same one-line error."""
    out = dict(zip(names, values))
    for name, v in out.items():
        if math.isinf(v):
            where = "" if line is None else f" (line {line})"
            raise ArgumentValueError(f"Diagnoser.step: {what}[{name}]={shown(v)}{where} is not a finite number", None,
                                     "give a float, or NaN for a value not read")
    return out


def mode_given(nominal, inputs, source: str, what: str = "diagnosing") -> None:
    """Refuse data of a model with modes that do not say the mode (no
    ``mode`` column), for ``what`` (calibration): it follows the mode the
    data give."""
    index = getattr(nominal, "MODE_INPUT", None)
    if index is not None and nominal.INPUTS[index] not in set(inputs):
        raise DataError(f"{printable(source)}: the data have no mode column, and {nominal.MODEL} has modes", None,
                        "record the plant's mode as a column 'mode' (each mode's number, 1 for the first the model "
                        f"lists): {what} with a mode the data do not give is not built yet")


def mode_hidden(nominal, inputs, source: str) -> bool:
    """Whether the data of a model with modes do not say the mode (no
    ``mode`` column), so that the diagnosis reads it from the measurements
    (:mod:`bgc.diagnosis.hidden`); refused in one line when a transition is
    controlled (only the data can say when it happens)."""
    index = getattr(nominal, "MODE_INPUT", None)
    if index is None or nominal.INPUTS[index] in set(inputs):
        return False
    why = readable(nominal)
    if why is not None:
        raise DataError(f"{printable(source)}: the data have no mode column, and the mode of {nominal.MODEL} cannot "
                        f"be read from the measurements: {why}", None,
                        "record the plant's mode as a column 'mode' (each mode's number, 1 for the first the model "
                        "lists)")
    return True



#: A particle observer's residuals screen the record kept while watching at this many times the watching
#: level before its Kalman track is computed (:meth:`Diagnoser._changed_while_watching`).
SCREEN = 10
#: The share of the detector's false-alarm budget per horizon the test of the record kept while watching
#: may take (:func:`watch_level`).
WATCH_SHARE = 0.05


def watch_level(false_alarm: float, keep: int, horizon: int) -> float:
    """The level of each of the two tests of the record kept while
    watching (the model's fit and the CUSUM test of a shift,
    :meth:`Diagnoser._changed_while_watching`): one pair every ``keep``
    steps is ``horizon / keep`` pairs per horizon (``horizon`` in steps), so
    a level of ``WATCH_SHARE * false_alarm * keep / horizon / 2`` holds them
    to :data:`WATCH_SHARE` of the detector's budget ``false_alarm`` per
    horizon (the union bound); never above the fit test's own level
    (:data:`~bgc.diagnosis.fit.LEVEL`). With bgc's defaults (1 % per
    horizon, a monitor's 1024 steps kept) that is LEVEL for a horizon up to
    256 steps; over a horizon of 300 steps, 0.00085."""
    return min(FIT_LEVEL, WATCH_SHARE * false_alarm * keep / max(horizon, 1) / 2)


def keep_steps(options: DiagnosisOptions, dt: float) -> int | None:
    """The steps of the record a diagnoser keeps while watching
    (``options.keep``, a time, in steps of ``dt``; None: every step), at
    least the nominal clouds' ``history`` and the longest window of the
    detector: an alarm's onsets are looked for no further back."""
    if options.keep is None:
        return None
    return max(math.ceil(options.keep / dt - 1e-9), options.history + max(options.windows))
