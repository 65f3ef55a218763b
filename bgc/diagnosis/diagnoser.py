"""The online diagnoser: one sample in, a belief out (the thesis's Fig. II.5).

::

    d = Diagnoser(package, signatures, priors, options, horizon=300)
    for t, u, y in rows:                 # as the data arrive
        belief = d.step(t, u, y)         # phase, alarm, hypotheses, events
    diagnosis = d.finish()               # the static posterior, the ranking, the verdict

Each :meth:`Diagnoser.step` places the row on the model's time grid
(:class:`~bgc.data.sampler.Sampler`: gaps, held inputs, missing sensors),
then for every step it gives:

1. **watching**: the nominal observer (a particle filter, or the cubature
   Kalman filter with ``method = "ckf"``) predicts the sample and the
   windowed Z-test (:class:`~bgc.diagnosis.detect.Detector`) tests its
   normalised residual; the nominal clouds of the last ``history`` steps are
   kept. An alarm (an :class:`~bgc.diagnosis.events.Alarmed` event) moves to
2. **isolating**: once ``symbol_steps`` samples past the alarm are in, the
   symbols are read on the open-loop run from the estimated onset and the
   signatures keep the hypotheses (:class:`~bgc.diagnosis.events.Isolated`).
3. **tracking**: each kept hypothesis's filters start from their onsets in
   the past (catching up on the samples kept) and follow each new sample
   (:class:`~bgc.diagnosis.hypothesis.HypothesisTracker`;
   :class:`~bgc.diagnosis.events.Started`, and
   :class:`~bgc.diagnosis.events.Dropped` when all of a hypothesis's filters
   stop). A batch diagnosis (``lazy``) leaves the tracking to
   :meth:`finish`, which runs the hypotheses on worker processes.
4. :meth:`finish` (or, online, :meth:`checkpoint` at any time) does what
   needs the whole record: the static posterior of each surviving
   hypothesis over onsets and magnitudes, the weighing, ranking, refining,
   and the verdict (:class:`~bgc.diagnosis.events.Decided`).

The fallbacks are decisions of the loop too: a particle observer that
degenerates before the alarm (or over a run without one) hands the record to
a cubature Kalman diagnoser (:class:`~bgc.diagnosis.events.Switched`), and a
verdict "unexplained" after the symbols ruled fault models out is made again
with every fault model (:class:`~bgc.diagnosis.events.AllTried`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping

import numpy as np

from ..arguments import as_float, is_real, shown
from ..errors import ArgumentTypeError, ArgumentValueError, TrackingError
from ..ir import FaultSignatures
from ..kinds import fault_kind
from . import events as ev
from ..filters import cubature as kalman
from ..data.sampler import Sample, Sampler
from .detect import Detector, DetectorOptions, monte_carlo_share
from .hypothesis import HypothesisTracker, log_density, weighted_quantiles
from .isolate import hypotheses as signature_hypotheses
from .isolate import observed_symbols
from ..data.runs import Run
from ..filters.registry import check_particles, filter_class
from .values import Belief, Diagnosis, Live
from .options import DiagnosisOptions
from .finish import STOPPED, _ordered, decide
from .hypothesis import track_job
from .onsets import drift_onsets
from .openloop import cloud_before, gaussian_cloud, open_loop
from .values import Isolation
from ..model.protocol import Package, nominal_model

#: The nominal observer degenerates when its mean effective sample size
#: before the alarm is under this share of its particles (an event says so).
DEGENERATE = 0.05

#: The diagnosis method with cubature Kalman filters alone (``--filter ckf``).
KALMAN_METHOD = "ckf"

#: How a hypothesis's magnitude is identified and the hypotheses weighed:
#: ``kalman``, with the magnitude held static, by cubature Kalman filters on a
#: grid of onsets and magnitudes (:mod:`bgc.filters.cubature`); ``filter``, by
#: the particle filters' own magnitude state and evidence.
IDENTIFY = ("kalman", "filter")


class Diagnoser:
    """The diagnosis of one plant's data, one sample at a time (module docstring).

    ``package``: the generated package; ``signatures``, ``priors``: the
    model's fault signatures and each fault candidate's prior;
    ``horizon``: the detector's horizon in steps (``options.horizon`` in
    steps of the model's ``dt``); ``inputs``, ``sensors``: the input and
    sensor names the data have columns for (default: the sensors, all of the
    model's; the inputs, those the first row of :meth:`step` gives, none
    when it gives ``u=None``);
    ``source``: the data's name in messages; ``lazy``: leave the hypotheses'
    tracking to :meth:`finish` (a batch diagnosis: the record is complete and
    the hypotheses run in parallel there); ``every``: try every fault model,
    those the symbols rule out too; ``progress(text)``: told what is done."""

    def __init__(self, package: Package, signatures: FaultSignatures, priors: dict[str, float],
                 options: DiagnosisOptions, horizon: int, *, inputs=None, sensors=None, source: str = "<stream>",
                 lazy: bool = False, every: bool = False, progress=None, most: int | None = None):
        self.started = time.perf_counter()
        self.package, self.signatures, self.priors = package, signatures, priors
        self.options, self.horizon, self.lazy, self.every = options, max(int(horizon), 1), lazy, every
        self.say = progress or (lambda text: None)
        self.nominal = nominal = nominal_model(package)
        check_particles(options.particles, package, "nominal")
        if options.identify not in IDENTIFY:
            raise TrackingError(f"unknown identification {options.identify!r}", None, f"use {' or '.join(IDENTIFY)}")
        self.ckf = ckf = options.method == KALMAN_METHOD
        if ckf and (options.refine or options.rank):
            raise TrackingError("--refine and --rank weigh particle filters on a grid", None,
                                "use them with --filter gpf, apf or opf; ckf computes the static posterior already")
        self.pf_class = filter_class(package, "gpf" if ckf else options.method)  # ckf: the open-loop cloud's filter
        self.outputs = tuple(nominal.OUTPUTS)
        self.sampler = Sampler(nominal, nominal.INPUTS if inputs is None else inputs,
                               nominal.OUTPUTS if sensors is None else sensors, source, options.gap)
        self.source = source
        self.most = most
        self._infer_inputs = inputs is None
        self.finished = False
        self.busy = 0.0  # seconds spent in steps (not waiting for data)
        rng = np.random.default_rng([options.seed, 0])
        self.pf = None if ckf else self.pf_class(nominal, options.particles, rng)
        self.kf = kalman.NominalKalman(nominal, len(self.outputs)) if ckf else None
        # sensors the data have no column for take no part in the detector's count of tests
        present = tuple(y for y in self.outputs if y in self.sampler.present)
        self.detector = Detector(present, DetectorOptions(options.false_alarm, options.windows, self.horizon))
        self._present = np.array([y in self.sampler.present for y in self.outputs])
        if self.pf is not None:  # what its first step would make, made before the data come
            self.pf.prepare(self._present)
        self.samples: list[Sample] = []
        self.y_mean: list = []
        self.y_std: list = []
        self.z: list = []
        self.x_mean: list = []
        self.x_std: list = []
        self.clouds: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # step -> nominal cloud after it
        self.ess = float(options.particles)  # of the weights that predict the next step
        self.ess_sum, self.ess_steps = 0.0, 0
        self.detection = None
        self.phase = "watching"
        self.events: list = []
        self.inner: Diagnoser | None = None  # the diagnoser the record was handed to (a switch of filter)
        self.isolation: Isolation | None = None
        self.trackers: dict[str, HypothesisTracker] = {}
        self._before: dict[str, float] = {}  # per tracker, the nominal log density before its first onset
        self.reported: set[str] = set()  # hypotheses whose Dropped event is out
        self.density: list[float] = []  # the nominal observer's log density per step (eager tracking)
        self.say("tracking the nominal model")

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
        y = _named(y, self.outputs, "y", line)
        if self._infer_inputs:  # the first row says which inputs the data give
            self._infer_inputs = False
            self.sampler.data_inputs = tuple(name for name in self.nominal.INPUTS if name in u)
        rows = self.sampler.push(t, u, y, line)
        if len(rows) == 1:  # the usual row: one step, its belief as it is
            return self.take(rows[0])
        belief = None
        collected: list = []
        for s in rows:
            belief = self.take(s)
            collected += belief.events
        if belief is None:  # a row on a step already taken: the belief stands
            return self.belief(len(self.events))
        return dataclasses.replace(belief, events=tuple(collected))

    def take(self, s: Sample) -> Belief:
        """Take one step of the grid (a :class:`~bgc.data.sampler.Sample`)."""
        started = time.perf_counter()
        try:
            return self._take(s)
        finally:
            self.busy += time.perf_counter() - started

    def _take(self, s: Sample) -> Belief:
        if self.most is not None and len(self.samples) >= self.most:
            where = self.source if s.line is None else f"{self.source}:{s.line}"
            raise TrackingError(f"{where}: the stream reached {self.most} steps of the model's grid (t = {s.t:.12g}), "
                                "the most a diagnosis of this model with these options holds in memory (4 GB by "
                                "bgc.api.diagnosis_memory's rule)", None,
                                "finish this diagnoser and start another for the rest of the stream, or use fewer "
                                "particles")
        if self.inner is not None:
            self.samples.append(s)
            return self.inner.take(s)
        mark = len(self.events)
        self.events += s.events
        self.samples.append(s)
        self._observe(s)
        if self.inner is not None:  # the observer degenerated at this alarm: the record went to a ckf diagnoser
            inner = self.inner.belief()
            mine = tuple(e for e in self.events[mark:] if not isinstance(e, ev.Alarmed))  # the ckf's alarm stands
            told = {e for sample in self.samples for e in sample.events}  # the data's, said as they came
            return dataclasses.replace(inner, events=mine + tuple(e for e in inner.events if e not in told))
        if self.phase == "isolating" and s.k >= self.detection.step + self.options.symbol_steps:
            self._isolate()
        elif self.phase == "tracking" and not self.lazy:
            self._track(s)
        return self.belief(mark)

    def _observe(self, s: Sample) -> None:
        """The nominal observer's step, and the detector's while watching."""
        k, o = s.k, self.options
        mc = detection = None
        with np.errstate(all="ignore"):  # one context for the step's arithmetic (NaN: a sensor not read)
            if self.ckf:
                self.kf.step(s.y, s.u)
                ym, sd, zk = self.kf.y_mean[-1], self.kf.y_std[-1], self.kf.z[-1]
                xm, xs = self.kf.means[-1], self.kf.x_std[-1]  # the state after the step
            else:
                r = self.pf.step(s.y, s.u)
                ym, sd, xm, xs = r.y_mean, r.y_std, r.mean, r.std
                zk = (s.y - r.y_mean) / r.y_std
                if self.detection is None:
                    mc = monte_carlo_share(r.y_std, self.nominal.MEASUREMENT_STD, self.ess, o.particles)
            self.y_mean.append(ym)
            self.y_std.append(sd)
            self.z.append(zk)
            self.x_mean.append(xm)
            self.x_std.append(xs)
            if not self.lazy:
                self.density.append(float(log_density(np.asarray(zk)[None], np.asarray(sd)[None])[0]))
            if self.detection is None:
                if not self.ckf:
                    self.clouds[k] = (self.pf.x.copy(), self.pf.logw.copy())
                    self.clouds.pop(k - o.history - 1, None)
                present = self._present
                detection = self.detector.update(np.asarray(zk)[present], None if mc is None else mc[present])
        if detection is not None:
            self._alarm(detection)
        if not self.ckf:
            self.ess = r.ess
            if self.detection is None or k < self.detection.step:  # before the alarm: a fault degenerates it too
                self.ess_sum += 0.0 if r.recovered else r.ess
                self.ess_steps += 1

    def _alarm(self, detection) -> None:
        self.detection = detection
        self.say(f"fault detected at t = {self.samples[detection.step].t:g} on {detection.sensor}")
        self.events.append(ev.Alarmed(detection.step, detection.sensor, detection.window, detection.statistic,
                                      detection.threshold, detection.onset))
        if not self.ckf and self._degenerate():
            return
        self.phase = "isolating"

    def _degenerate(self) -> bool:
        """Whether the particle observer degenerated before the alarm (or over
        the run): an event, and with ``switch`` the record handed to a
        cubature Kalman diagnoser (True)."""
        o = self.options
        if not self.ess_steps:  # an alarm on the first sample: nothing says the filter degenerates
            return False
        mean_ess = self.ess_sum / self.ess_steps
        if mean_ess >= DEGENERATE * o.particles:
            return False
        step = self.samples[-1].k
        if not o.switch:
            self.events.append(ev.Degenerate(o.method, mean_ess, o.particles, False, step))
            return False
        self.say("the particle filter degenerates: diagnosing again with cubature Kalman filters")
        self.events += [ev.Degenerate(o.method, mean_ess, o.particles, True, step),
                        ev.Switched(KALMAN_METHOD, "degenerate", step)]
        self.inner = self.replay(dataclasses.replace(o, method=KALMAN_METHOD, rank=False, refine=False), self.every)
        return True

    def replay(self, options: DiagnosisOptions, every: bool, lazy: bool | None = None) -> Diagnoser:
        """A diagnoser with ``options`` that has taken every step of this one's
        record, its data events with them (``lazy``: None, this one's)."""
        d = Diagnoser(self.package, self.signatures, self.priors, options, self.horizon,
                      inputs=self.sampler.data_inputs, sensors=self.sampler.present, source=self.source,
                      lazy=self.lazy if lazy is None else lazy, every=every, progress=self.say)
        d.sampler = self.sampler  # the data were read once: their summary is this one's
        for s in self.samples:
            d.take(s)
        return d

    # -- isolation and tracking -----------------------------------------------------------------------------

    def _record(self) -> tuple[np.ndarray, np.ndarray]:
        ys = np.array([s.y for s in self.samples], dtype=float).reshape(len(self.samples), len(self.outputs))
        us = np.array([s.u for s in self.samples], dtype=float).reshape(len(self.samples), len(self.nominal.INPUTS))
        return ys, us

    def _isolate(self) -> None:
        """The symbols on the open-loop run from the onset, the hypotheses
        they keep, and (online) their trackers."""
        ys, us = self._record()
        observer = self.kf.track() if self.ckf else None
        self.isolation = iso = isolate(self, ys, us, observer)
        step = len(self.samples) - 1
        self.events.append(ev.Isolated(step, iso.onset, tuple(iso.names), iso.refuted))
        self.events += iso.events
        self.phase = "tracking"
        if self.ckf:  # no filter tracks a hypothesis: the static posteriors at the end weigh them all
            return
        self.events += [ev.Started(step, name, tuple(iso.starts_of[name])) for name in iso.names]
        if self.lazy:
            return
        density = np.array(self.density)
        for name in iso.names:
            job = track_job(name, iso.starts_of[name], self.package, self.clouds, self.options, self.outputs,
                                  self.horizon)
            tracker = self.trackers[name] = HypothesisTracker(job)
            self._before[name] = float(density[:job.first].sum())  # the nominal density before its first onset
            for k in range(job.first, len(self.samples)):  # catch up on the samples kept
                tracker.step(ys[k], us[k], density[k])
                if tracker.done:
                    self.reported.add(name)
                    self.events.append(ev.Dropped(k, name, "inconsistent", STOPPED))
                    break

    def _track(self, s: Sample) -> None:
        for name, tracker in self.trackers.items():
            if not tracker.done:
                tracker.step(s.y, s.u, self.density[s.k])
            if tracker.done and name not in self.reported:
                self.reported.add(name)
                self.events.append(ev.Dropped(s.k, name, "inconsistent", STOPPED))

    def belief(self, mark: int = 0) -> Belief:
        """The belief after the last step taken (the events from ``mark`` on)."""
        if self.inner is not None:
            return self.inner.belief()
        k = len(self.samples) - 1
        return Belief(k, self.samples[k].t if self.samples else math.nan, self.phase, self.detection,
                      self._live(), tuple(self.events[mark:]))

    def _live(self) -> tuple[Live, ...]:
        """The hypotheses tracked, best first: their posterior from the
        filters' running evidence (over the data from step 0) and priors."""
        if not self.trackers:
            return ()
        tail = (1.0 - self.options.interval) / 2.0
        rows = []
        for name, tracker in self.trackers.items():
            before = self._before[name]
            evidence = {s: e for s, e in tracker.evidence.items() if s in tracker.live}
            if not evidence:
                rows.append((name, -math.inf, tracker.job.first, math.nan, math.nan, math.nan, True))
                continue
            best = max(evidence, key=evidence.get)
            prior = math.log(max(self.priors.get(tracker.module.FAULT["parameter"], 0.01), 1e-300))
            pf = tracker.filters.get(best)
            value = low = high = math.nan
            if pf is not None:
                theta = pf.x[tracker.k_mag]
                w = np.exp(pf.logw - pf.logw.max())
                value = float(w @ theta / w.sum())
                low, high = (float(v) for v in weighted_quantiles(theta, pf.logw, [tail, 1.0 - tail]))
            rows.append((name, prior + before + evidence[best], tracker.job.first + best, value, low, high,
                         tracker.out[best]["rejected"] is not None))
        logw = np.array([r[1] for r in rows])
        w = np.exp(logw - logw.max()) if np.isfinite(logw).any() else np.zeros(len(rows))
        w = w / w.sum() if w.sum() > 0 else w
        live = [Live(r[0], float(p), r[2], r[3], r[4], r[5], r[6]) for r, p in zip(rows, w)]
        return tuple(sorted(live, key=lambda h: -h.posterior))

    # -- the end --------------------------------------------------------------------------------------------

    def finish(self, truth: Run | None = None) -> Diagnosis:
        """The diagnosis of the record (the stream ends here); ``truth``: the
        run, when it records the true fault (its parameter columns)."""
        if not self.finished:  # the diagnosis's seconds: its steps' and its end's, not the waits for data
            self.finished = True
            self.started = time.perf_counter() - self.busy
        if self.inner is not None:  # it took every sample, with its data events
            d = self.inner.finish(truth)
            mine = [e for e in self.events if isinstance(e, (ev.Degenerate, ev.Switched))]
            return dataclasses.replace(d, events=_ordered(mine + list(d.events)),
                                       seconds=time.perf_counter() - self.started)
        if not self.samples:
            raise TrackingError(f"{self.source}: no sample to diagnose", None, "give at least one row of data")
        if not self.ckf and self.detection is None and self._degenerate():
            return self.finish(truth)
        diagnosis = decide(self, truth)
        if self._retry(diagnosis):
            again = self.replay(dataclasses.replace(self.options, switch=False), True).finish(truth)
            return dataclasses.replace(again, seconds=time.perf_counter() - self.started)
        return diagnosis

    def checkpoint(self) -> Diagnosis:
        """The diagnosis of the data so far, the stream going on: the
        :meth:`finish` of a copy of this diagnoser's record (as costly as a
        batch diagnosis of it)."""
        return self.replay(self.options, self.every, lazy=True).finish()

    def _retry(self, d: Diagnosis) -> bool:
        """Whether an unexplained verdict is to be made again with every fault
        model: some the symbols ruled out were not weighed (step 6b did not
        run: no hypothesis the symbols kept survived its filters)."""
        if d.verdict != "unexplained" or self.every or self.isolation is None:
            return False
        untried = set(self.isolation.untried(self.package)) - {h.name for h in d.hypotheses}  # step 6b's weighed
        if untried:
            self.say("no hypothesis the symbols kept explains the data: trying those they ruled out")
            return True
        return False

    def arrays(self) -> dict[str, np.ndarray]:
        """The record and the nominal observer's arrays (steps x ...)."""
        T, n_y, n_x = len(self.samples), len(self.outputs), len(self.nominal.STATES)

        def rows(values: list, width: int) -> np.ndarray:
            return np.array(values, dtype=float).reshape(T, width)

        ys, us = self._record()
        return dict(time=np.array([s.t for s in self.samples], dtype=float), ys=ys, us=us,
                    y_mean=rows(self.y_mean, n_y), y_std=rows(self.y_std, n_y), z=rows(self.z, n_y),
                    x_mean=rows(self.x_mean, n_x), x_std=rows(self.x_std, n_x))


def isolate(d: Diagnoser, ys: np.ndarray, us: np.ndarray, observer) -> Isolation:
    """Step 3 of the method on diagnoser ``d``'s record: the onsets each
    hypothesis is tried from, the symbols read on the open-loop nominal
    prediction from the detector's onset, and the fault models they keep."""
    o, detection, T = d.options, d.detection, len(ys)
    spacing = o.spacing or (8 if o.identify == "kalman" else 4)
    def first_tried(reach: list[int]) -> list[int]:  # a drift's onsets near the alarm, and the change point
        return [k for k in reach if k >= detection.step - o.search or detection.onset - 1 <= k <= detection.onset]

    reach = drift_onsets(detection.step, detection.onset, spacing, o.history)
    near = {k for k in range(detection.onset - o.near, detection.onset + 3) if 0 <= k <= detection.step + 1 and k < T}
    kalman_reach = drift_onsets(detection.step, detection.onset, o.kalman.spacing, o.history)
    kalman_onsets = {True: first_tried(kalman_reach), False: sorted(near)}
    d.say("reading the symbols of the deviating sensors")
    onset = detection.onset
    steps = min(T - onset, detection.step - onset + 1 + o.symbol_steps)
    cloud = gaussian_cloud(observer, onset, o) if d.ckf else cloud_before(d.clouds, onset)
    seen = observed_symbols(open_loop(d.package, d.pf_class, d.nominal, cloud, ys, us, onset, steps, o),
                            d.outputs, o.windows)
    keep, dropped = signature_hypotheses(d.signatures, seen)
    events = []
    if d.every and dropped:
        events.append(ev.AllTried("unexplained", T - 1))
        keep = list(d.signatures.signatures)
    elif not keep:
        events.append(ev.AllTried("no-signature", T - 1))
        keep = list(d.signatures.signatures)
    models: dict[str, list[str]] = {}
    for s in keep:
        models.setdefault(f"{s.parameter}_{s.kind}", []).append(s.name)
    names = [n for n in sorted(models) if n in d.package.MODELS]
    # whether each is tried from a drift's onsets back from the alarm (a drift, a burst of noise)
    drifts = {name: fault_kind(d.package.MODELS[name].FAULT["kind"]).searched_back for name in names}
    onsets = {True: first_tried(reach), False: sorted(near)}
    return Isolation(onset, seen, tuple((s.name, why) for s, why in dropped),
                           tuple(f"{s.parameter}_{s.kind}" for s, _ in dropped), models, names, drifts,
                           {name: onsets[drifts[name]] for name in names}, reach, kalman_onsets, kalman_reach,
                           tuple(events))


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
