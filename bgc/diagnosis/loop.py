"""The online loop of one diagnosis: one step of the model's grid in, a
belief out (the thesis's Fig. II.5); :class:`Loop` is the loop of
:class:`~bgc.diagnosis.diagnoser.Diagnoser`, which feeds it the samples and
applies the fallback policies to the events it emits.

For every step (a :class:`~bgc.data.sampler.Sample`):

1. **watching**: the nominal observer (a particle filter, or the cubature
   Kalman filter with ``method = "ckf"``) predicts the sample and the
   windowed Z-test (:class:`~bgc.diagnosis.detect.Detector`) tests its
   normalised residual; the nominal clouds of the last ``history`` steps are
   kept (a bounded ring). An alarm (an :class:`~bgc.events.Alarmed`
   event) moves to
2. **isolating**: once ``symbol_steps`` samples past the alarm are in, the
   symbols are read on the open-loop run from the estimated onset and the
   signatures keep the hypotheses (:class:`~bgc.events.Isolated`).
3. **tracking**: each kept hypothesis's filters start from their onsets in
   the past (catching up on the samples kept) and follow each new sample
   (:class:`~bgc.diagnosis.hypothesis.HypothesisTracker`;
   :class:`~bgc.events.Started`, and
   :class:`~bgc.events.Stopped` when all of a hypothesis's filters
   stop). A batch diagnosis (``lazy``) leaves the tracking to the end.
4. :meth:`Loop.finish` hands its :class:`~bgc.diagnosis.finish.Record` to
   :func:`bgc.diagnosis.finish.finish`: the static posteriors, the weighing,
   the verdict.

A particle observer that degenerates (its mean effective sample size before
the alarm under ``DEGENERATE`` of its particles) is a decision of the loop:
a :class:`~bgc.events.Degenerate` event, whose ``switched`` says
whether the options ask for the switch to cubature Kalman filters; the loop
stops there and the diagnoser's policy reacts (a new loop on the record).

What the loop keeps, and for how long: the record of the samples and of the
nominal observer's predictions, residuals and state estimates, and the
detector's statistics, from the first sample on (the end of a diagnosis
weighs every hypothesis over the whole record and the report draws it),
unless the diagnoser bounds it (``options.keep``: while watching,
:meth:`Loop.forget` drops the older half once it holds twice ``keep``
steps, and the record's steps are counted from the first one kept); the
nominal clouds of the last ``history`` steps before the alarm (the onsets
are looked for no further back); the detector's sums over its longest
window; the trackers' filters and outputs from their onsets on. Its state
is plain data (:func:`bgc.diagnosis.state.loop_state`,
:class:`~bgc.diagnosis.state.LoopState`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..arguments import spelled
from ..data.sampler import DataSummary, Sample
from ..filters.cubature import CubatureKalmanFilter, NominalKalman, _Filter as CubatureRule, lower_solve
from ..filters.registry import check_particles, filter_class
from ..ir import FaultSignatures
from ..kinds import fault_kind
from ..model.protocol import Package, nominal_model
from ..data.clock import Clock
from .. import events as ev
from .detect import Detector, DetectorOptions, monte_carlo_share
from .finish import Record, Setting, finish
from .hypothesis import HypothesisTracker, log_density, track_job, weighted_quantiles
from .isolate import ModeSignatures, hypotheses as signature_hypotheses
from .isolate import observed_symbols
from .onsets import drift_onsets, log_prior
from .openloop import cloud_before, gaussian_cloud, open_loop
from .options import DiagnosisOptions
from .values import Belief, Diagnosis, Isolation, Live
from ..data.runs import Run
from ..errors import TrackingError

#: The nominal observer degenerates when its mean effective sample size
#: before the alarm is under this share of its particles (an event says so).
DEGENERATE = 0.05

#: The diagnosis method with cubature Kalman filters alone (``--filter ckf``).
KALMAN_METHOD = "ckf"

#: How a hypothesis's magnitude is identified and the hypotheses weighed:
#: ``kalman``, with the magnitude held static, by cubature Kalman filters on a
#: grid of onsets and magnitudes (:mod:`bgc.diagnosis.static_posterior`); ``filter``, by
#: the particle filters' own magnitude state and evidence.
IDENTIFY = ("kalman", "filter")


@dataclass(frozen=True, slots=True)
class LoopConfig:
    """What a loop is made with and never changes: the generated package,
    the model's fault signatures, each fault candidate's prior, the options,
    the detector's horizon in steps, the sensors the data have a column for
    (``present``), the model's ``time_unit`` (None: none declared), ``lazy``
    (leave the hypotheses' tracking to the end: a batch diagnosis),
    ``every`` (try every fault model, those the symbols rule out too) and
    ``say(text)``, told what is done."""

    package: Package
    signatures: FaultSignatures
    priors: Mapping[str, float]
    options: DiagnosisOptions
    horizon: int
    present: tuple[str, ...]
    time_unit: str | None
    lazy: bool = False
    every: bool = False
    say: Callable[[str], None] = field(default=lambda text: None, compare=False)

    @property
    def ckf(self) -> bool:
        return self.options.filter == KALMAN_METHOD


class Loop:
    """The online loop over one configuration (module docstring). Its
    working parts (the observer, the detector, the trackers) each give their
    state as plain data and are made again from it (:meth:`state`,
    :meth:`from_state`)."""

    def __init__(self, config: LoopConfig):
        o = config.options
        self.config = config
        self.nominal = nominal = nominal_model(config.package)
        check_particles(o.particles, config.package, "nominal")
        if o.identify not in IDENTIFY:
            raise TrackingError(f"unknown identification {o.identify!r}", None, f"use {' or '.join(IDENTIFY)}")
        if config.ckf and (o.refine or o.rank):
            raise TrackingError(f"{spelled('refine and rank', '--refine and --rank')} weigh particle filters on a grid",
                                None, f"use them with {spelled('filter=', '--filter ')}gpf, apf or opf; ckf computes "
                                "the static posterior already")
        self.outputs = tuple(nominal.OUTPUTS)
        self.horizon = max(int(config.horizon), 1)
        self.pf_class = filter_class(config.package, "gpf" if config.ckf else o.filter)  # ckf: the open loop's
        self.present = np.array([y in config.present for y in self.outputs])
        self.noise = np.asarray(nominal.MEASUREMENT_STD, dtype=float)  # the sensors' own noise std
        self._observers(config)
        # the pooled test's predicted correlation of the residuals (a particle filter gives each sensor's std only)
        self.rule = None if "pooled" not in o.detectors else (self.kf.kf if self.kf is not None
                                                               else CubatureRule(nominal))
        if self.rule is not None:  # the kind of each of the rule's states (a mode must be known to it)
            kinds = getattr(nominal, "STATE_KINDS", ("physical",) * len(nominal.STATES))
            self._kinds = [kinds[i] for i in self.rule.physical]
        if self.pf is not None:  # what its first step would make, made before the data come
            self.pf.prepare(self.present)
        # the record (what the end needs), from the first sample on
        self.samples: list[Sample] = []
        self.y_mean: list = []
        self.y_std: list = []
        self.z: list = []
        self.x_mean: list = []
        self.x_std: list = []
        self.density: list[float] = []  # the nominal observer's log density per step (eager tracking)
        self.clouds: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # step -> nominal cloud after it (a ring)
        self.ess = float(o.particles)  # of the weights that predict the next step
        self.ess_sum, self.ess_steps = 0.0, 0
        self.phase = "watching"
        self.detection = None
        self.isolation: Isolation | None = None
        self.events: list = []
        self.trackers: dict[str, HypothesisTracker] = {}
        self.before: dict[str, float] = {}  # per tracker, the nominal log density before its first onset
        self.reported: set[str] = set()  # hypotheses whose Stopped event is out
        #: the detector is re-armed at this step and raises no alarm before it (0: from the first sample; a
        #: diagnosis made again after a false alarm, :meth:`bgc.diagnosis.diagnoser.Diagnoser.finish`)
        self.watch_from = 0
        #: steps (first, end) the test of the model's fit leaves out: a false alarm's window (None: none)
        self.excused: tuple[int, int] | None = None
        #: a cache, not the loop's state: steps 4 to 6b of the last record finished, with what it was
        self._memo: tuple = (None, {})
        #: an alarm raised at its step whatever the detector says (None: none): a change of the residuals found
        #: over the whole record that no test alarmed on (:meth:`bgc.diagnosis.diagnoser.Diagnoser._missed_change`),
        #: or over the record kept while watching (:meth:`~bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching`)
        self.forced = None

    def _observers(self, config: LoopConfig) -> None:
        """The nominal observer (a particle filter, or with ``ckf`` the
        Kalman filter), the drift family's Kalman observer beside a particle
        one (no Monte Carlo error: bgc.diagnosis.detect, "A bank of tests";
        not for a model with modes, which a Kalman filter does not follow),
        and the detector."""
        o, nominal = config.options, self.nominal
        self.pf = None if config.ckf else self.pf_class(nominal, o.particles, np.random.default_rng([o.seed, 0]))
        self.kf = NominalKalman(nominal, len(self.outputs)) if config.ckf else None
        wanted = "drift" in o.detectors or "matched" in o.detectors  # the families that read an exact observer
        self.companion = CubatureKalmanFilter(nominal) if self.pf is not None and wanted else None
        if self.companion is not None and len(self.companion.kf.carried):  # a mode (and its dwell) carried
            self.companion = None
        # the drift family's residuals are exact from a Kalman observer of a model without modes, or the companion
        exact = self.companion is not None or (self.kf is not None and not len(self.kf.kf.carried))
        # the matched test's kernels: the fault models' responses as that observer sees them, over every sensor
        # (bgc.diagnosis.matched; none for a model with modes, or with a sensor the data do not have)
        kernels = None
        if "matched" in o.detectors and exact and bool(self.present.all()):
            from .matched import kernels as matched_kernels

            kernels = matched_kernels(config.package)
        self.matched = kernels is not None
        self.detector = Detector(tuple(y for y in self.outputs if y in config.present),
                                 DetectorOptions(o.false_alarm, o.windows, self.horizon, o.detectors),
                                 self.noise[self.present], exact=exact, kernels=kernels)

    @property
    def options(self) -> DiagnosisOptions:
        return self.config.options

    # -- one step -------------------------------------------------------------------------------------------

    def take(self, s: Sample) -> Belief:
        """Take one step of the grid; the belief after it, with its events."""
        mark = len(self.events)
        self.events += s.events
        self.samples.append(s)
        self._observe(s)
        if self.phase == "isolating" and s.k >= self.detection.step + self.options.symbol_steps:
            self.isolate()
        elif self.phase == "tracking" and not self.config.lazy:
            self._track(s)
        return self.belief(mark)

    def _observe(self, s: Sample) -> None:
        """The nominal observer's step, and the detector's while watching."""
        k, o = s.k, self.options
        mc = detection = exact = whitened = None
        with np.errstate(all="ignore"):  # one context for the step's arithmetic (NaN: a sensor not read)
            corr = self._correlation(s.u) if self.rule is not None and self.detection is None else None
            predicted = self._exact_prediction(s.u) if self.matched and self.detection is None else None
            if self.kf is not None:
                self.kf.step(s.y, s.u)
                ym, sd, zk = self.kf.y_mean[-1], self.kf.y_std[-1], self.kf.z[-1]
                xm, xs = self.kf.means[-1], self.kf.x_std[-1]  # the state after the step
            else:
                r = self.pf.step(s.y, s.u)
                ym, sd, xm, xs = r.y_mean, r.y_std, r.mean, r.std
                zk = (s.y - r.y_mean) / r.y_std
                if self.detection is None:
                    mc = monte_carlo_share(r.y_std, self.nominal.MEASUREMENT_STD, self.ess, o.particles)
            if self.companion is not None and self.detection is None:  # the drift family's, while watching
                c = self.companion.step(s.y, s.u)
                exact = ((s.y - c.y_mean) / c.y_std)[self.present]
                if not (np.isfinite(self.companion.mean).all() and np.isfinite(self.companion.cov).all()):
                    exact = self._restart_companion(k)
                    predicted = None
            if predicted is not None:
                whitened = _whiten(np.asarray(s.y, dtype=float) - predicted[0], predicted[1])
            self.y_mean.append(ym)
            self.y_std.append(sd)
            self.z.append(zk)
            self.x_mean.append(xm)
            self.x_std.append(xs)
            if not self.config.lazy:
                self.density.append(float(log_density(np.asarray(zk)[None], np.asarray(sd)[None])[0]))
            if self.detection is None:
                if self.pf is not None:
                    self.clouds[k] = (self.pf.x.copy(), self.pf.logw.copy())
                    self.clouds.pop(k - o.history - 1, None)
                present = self.present
                if k == self.watch_from and k:
                    self.detector.rearm()
                detection = self.detector.update(np.asarray(zk)[present], None if mc is None else mc[present],
                                                 np.asarray(s.y, dtype=float)[present],
                                                 (np.asarray(sd, dtype=float) / self.noise)[present],
                                                 None if corr is None else corr[np.ix_(present, present)], exact,
                                                 whitened)
        if detection is not None and k < self.watch_from:  # before the detector was armed: not an alarm
            detection = None
        if self.detection is None and self.forced is not None and k == self.forced.step:
            detection = detection or self.forced
        if detection is not None:
            # an onset older than the clouds and the record kept (a drift test's window reaches 256 steps back)
            earliest = max(detection.step - o.history, 0)
            if detection.onset_step is not None and detection.onset_step < earliest:
                detection = dataclasses.replace(detection, onset_step=earliest)
            self._alarm(detection)
        if self.pf is not None:
            self.ess = r.ess
            if self.detection is None or k < self.detection.step:  # before the alarm: a fault degenerates it too
                self.ess_sum += 0.0 if r.recovered else r.ess
                self.ess_steps += 1

    def _exact_prediction(self, u) -> tuple[np.ndarray, np.ndarray] | None:
        """The next measurement's mean and covariance as the exact observer
        (the Kalman filter, or the companion beside a particle filter)
        predicts it before its step: the matched test whitens the step's
        innovations with it (:meth:`bgc.filters.cubature._Filter.predicted_measurement`,
        the rule of the observer's own step)."""
        if self.kf is not None:
            return self.kf.kf.predicted_measurement(self.kf.m[0], self.kf.P[0], u)
        return self.companion.kf.predicted_measurement(self.companion.mean, self.companion.cov, u)

    def _restart_companion(self, k: int) -> np.ndarray:
        """The drift family's Kalman observer lost its estimate at step ``k``
        (not finite): start it again from the particle observer's cloud after
        the step (its weighted mean and covariance), say so
        (:class:`~bgc.events.ObserverRestarted`), and return the step's
        residuals for the drift test: none (NaN: a window holding the step is
        a window with a reading missing)."""
        self.companion = CubatureKalmanFilter(self.nominal, x=self.pf.x, w=self.pf._weights())
        times = 1 + sum(isinstance(e, ev.ObserverRestarted) for e in self.events)
        self.events.append(ev.ObserverRestarted(k, times))
        return np.full(int(np.count_nonzero(self.present)), np.nan)

    def _correlation(self, u) -> np.ndarray | None:
        """The correlation matrix of the next step's residuals as the
        nominal observer predicts them, before it takes the step: the
        cubature rule from its mean and covariance (a particle filter's
        weighted cloud; :meth:`bgc.filters.cubature._Filter.predicted_measurement`).
        None where the rule does not apply: a mode the cloud is unsure of (a
        discrete state has no cubature points; a carried state the cloud
        agrees on, its dwell in the mode, is held exactly, one it does not,
        a guard's threshold, is spread as the cloud spreads it), a
        covariance not finite."""
        rule = self.rule
        if self.kf is not None:
            m, P = self.kf.m[0], self.kf.P[0]
            if any(P[j, j] != 0.0 for j in rule.carried if self._kinds[j] == "mode"):
                return None
        else:
            x = self.pf.x[rule.physical]
            w = self.pf._weights()  # the cloud's normalised weights after the last step
            m = x @ w
            # a carried row every particle agrees on (the mode, its dwell): exactly that value (the weights'
            # sum rounds), and no spread; the mode itself must be agreed on
            agreed = [j for j in rule.carried if (x[j] == x[j, 0]).all()]
            if any(self._kinds[j] == "mode" for j in rule.carried if j not in agreed):
                return None
            m[agreed] = x[agreed, 0]
            d = x - m[:, None]
            d[agreed] = 0.0
            P = (d * w) @ d.T
        _, S = rule.predicted_measurement(m, P, u)
        std = np.sqrt(np.diagonal(S))
        if not (np.isfinite(S).all() and (std > 0).all()):
            return None
        return S / np.outer(std, std)

    @property
    def clock(self) -> Clock:
        """How the record's times are written in words: the
        :class:`~bgc.data.clock.Clock` of its first time and the model's
        time unit (a record not begun: numbers)."""
        return Clock.of([s.t for s in self.samples[:1]], self.config.time_unit)

    def _alarm(self, detection) -> None:
        self.detection = detection
        self.config.say(f"fault detected at t = {self.clock.text(self.samples[detection.step].t)} on "
                        f"{detection.sensor}")
        self.events.append(ev.Alarmed(detection.step, detection.sensor, detection.window, detection.statistic,
                                      detection.threshold, detection.onset_step, detection.test))
        degenerate = self.degenerate()
        if degenerate is not None:
            self.events.append(degenerate)
            if degenerate.switched:  # the diagnoser's policy takes the record to cubature Kalman filters
                return
        self.phase = "isolating"

    def degenerate(self) -> ev.Degenerate | None:
        """The decision that the particle observer degenerated before the
        alarm (or, with none, over the run so far): its event (``switched``:
        the options ask for the switch to cubature Kalman filters), or None."""
        o = self.options
        if self.pf is None or not self.ess_steps:  # an alarm on the first sample: nothing says it degenerates
            return None
        mean_ess = self.ess_sum / self.ess_steps
        if mean_ess >= DEGENERATE * o.particles:
            return None
        if o.switch:
            self.config.say("the particle filter degenerates: diagnosing again with cubature Kalman filters")
        return ev.Degenerate(o.filter, mean_ess, o.particles, o.switch, self.samples[-1].k)

    # -- a bounded record -----------------------------------------------------------------------------------

    def forget(self, cut: int) -> tuple[np.ndarray, np.ndarray]:
        """Forget the first ``cut`` steps of the record while watching (no
        alarm, no hypothesis: nothing looks back that far): the record, the
        nominal observer's estimates, the detector's statistics, the clouds
        and the data events kept are those of the steps from ``cut`` on,
        which become steps 0, 1, ... (the windows' sums and the observer
        itself go on as they were). Returns the nominal observer's state
        before the first step kept (its mean and std), where the models of
        the record kept start (:func:`bgc.model.package.started_package`)."""
        if self.phase != "watching" or self.detection is not None or not 0 < cut < len(self.samples):
            raise TrackingError(f"Loop.forget({cut}): only steps of a record being watched can be forgotten", None,
                                "forget fewer steps than the record holds, before an alarm")
        if self.kf is not None:  # its state before step cut, then every list from there
            kf = self.kf
            start = kf.means[cut], np.sqrt(np.maximum(np.diagonal(kf.covs[cut]), 0.0))
            kf.means, kf.covs = kf.means[cut:], kf.covs[cut:]
            kf.logliks = [v - kf.logliks[cut] for v in kf.logliks[cut:]]
            kf.y_mean, kf.y_std, kf.z, kf.x_std = kf.y_mean[cut:], kf.y_std[cut:], kf.z[cut:], kf.x_std[cut:]
        else:  # the particle observer's estimate after step cut - 1
            start = self.x_mean[cut - 1], self.x_std[cut - 1]
        self.samples = [dataclasses.replace(s, k=s.k - cut, events=shifted_events(s.events, cut))
                        for s in self.samples[cut:]]
        self.y_mean, self.y_std, self.z = self.y_mean[cut:], self.y_std[cut:], self.z[cut:]
        self.x_mean, self.x_std, self.density = self.x_mean[cut:], self.x_std[cut:], self.density[cut:]
        self.detector.statistics = self.detector.statistics[cut:]
        self.clouds = {k - cut: cloud for k, cloud in self.clouds.items() if k >= cut}
        self.events = list(shifted_events(self.events, cut))
        return np.asarray(start[0], dtype=float).copy(), np.asarray(start[1], dtype=float).copy()

    # -- isolation and tracking -----------------------------------------------------------------------------

    def arrays(self) -> dict[str, np.ndarray]:
        """The record and the nominal observer's arrays (steps x ...)."""
        T, n_y, n_x = len(self.samples), len(self.outputs), len(self.nominal.STATES)

        def rows(values: list, width: int) -> np.ndarray:
            return np.array(values, dtype=float).reshape(T, width)

        ys = np.array([s.y for s in self.samples], dtype=float).reshape(T, n_y)
        us = np.array([s.u for s in self.samples], dtype=float).reshape(T, len(self.nominal.INPUTS))
        return dict(time=np.array([s.t for s in self.samples], dtype=float), ys=ys, us=us,
                    y_mean=rows(self.y_mean, n_y), y_std=rows(self.y_std, n_y), z=rows(self.z, n_y),
                    x_mean=rows(self.x_mean, n_x), x_std=rows(self.x_std, n_x))

    def isolate(self) -> None:
        """The symbols on the open-loop run from the onset, the hypotheses
        they keep, and (online) their trackers."""
        a = self.arrays()
        observer = self.kf.track() if self.kf is not None else None
        self.isolation = iso = isolate(self.config, self.pf_class, self.detection, self.clouds, a["ys"], a["us"],
                                       observer)
        step = len(self.samples) - 1
        self.events.append(ev.Isolated(step, iso.onset, tuple(iso.names), iso.refuted))
        self.events += iso.events
        self.phase = "tracking"
        if self.kf is not None:  # no filter tracks a hypothesis: the static posteriors at the end weigh them all
            return
        self.events += [ev.Started(step, name, tuple(iso.starts_of[name])) for name in iso.names]
        if self.config.lazy:
            return
        density = np.array(self.density)
        for name in iso.names:
            job = track_job(name, iso.starts_of[name], self.config.package, self.clouds, self.options, self.outputs,
                            self.horizon)
            tracker = self.trackers[name] = HypothesisTracker(job)
            self.before[name] = float(density[:job.first].sum())  # the nominal density before its first onset
            for k in range(job.first, len(self.samples)):  # catch up on the samples kept
                tracker.step(a["ys"][k], a["us"][k], density[k])
                if tracker.done:
                    self._stopped(name, k)
                    break

    def _track(self, s: Sample) -> None:
        for name, tracker in self.trackers.items():
            if not tracker.done:
                tracker.step(s.y, s.u, self.density[s.k])
            if tracker.done:
                self._stopped(name, s.k)

    def _stopped(self, name: str, k: int) -> None:
        if name not in self.reported:
            self.reported.add(name)
            self.events.append(ev.Stopped(k, name))

    def belief(self, mark: int = 0) -> Belief:
        """The belief after the last step taken (the events from ``mark`` on)."""
        k = len(self.samples) - 1
        return Belief(k, self.samples[k].t if self.samples else math.nan, self.phase, self.detection,
                      self.live(), tuple(self.events[mark:]))

    def live(self) -> tuple[Live, ...]:
        """The hypotheses tracked, best first: their posterior from the
        filters' running evidence (over the data from step 0) and priors."""
        if not self.trackers:
            return ()
        rows = [self._live_row(name, tracker) for name, tracker in self.trackers.items()]
        logw = np.array([r[1] for r in rows])
        w = np.exp(logw - logw.max()) if np.isfinite(logw).any() else np.zeros(len(rows))
        w = w / w.sum() if w.sum() > 0 else w
        live = [Live(r[0], float(p), r[2], r[3], r[4], r[5], r[6]) for r, p in zip(rows, w)]
        return tuple(sorted(live, key=lambda h: -h.posterior))

    def _live_row(self, name: str, tracker: HypothesisTracker) -> tuple:
        """(name, log weight, onset, value, low, high, rejected) of one tracked hypothesis."""
        tail = (1.0 - self.options.interval) / 2.0
        evidence = {s: e for s, e in tracker.evidence.items() if s in tracker.live}
        if not evidence:
            return name, -math.inf, tracker.job.first, math.nan, math.nan, math.nan, True
        best = max(evidence, key=evidence.get)
        prior = log_prior(self.config.priors, tracker.module.FAULT["parameter"])
        pf = tracker.filters.get(best)
        value = low = high = math.nan
        if pf is not None:
            theta = pf.x[tracker.k_mag]
            w = np.exp(pf.logw - pf.logw.max())
            value = float(w @ theta / w.sum())
            low, high = (float(v) for v in weighted_quantiles(theta, pf.logw, [tail, 1.0 - tail]))
        return (name, prior + self.before[name] + evidence[best], tracker.job.first + best, value, low, high,
                tracker.out[best]["rejected"] is not None)

    # -- the end --------------------------------------------------------------------------------------------

    def record(self, data: DataSummary | None) -> Record:
        """What the end needs (:class:`~bgc.diagnosis.finish.Record`);
        ``data``: how the data met the model."""
        a = self.arrays()
        T = len(a["time"])
        statistics = np.array(self.detector.statistics + [np.full(len(self.detector.sensors), np.nan)]
                              * (T - len(self.detector.statistics)))
        if len(self.detector.sensors) < len(self.outputs):  # sensors the data lack: no statistic
            full = np.full((T, len(self.outputs)), np.nan)
            full[:, self.present] = statistics.reshape(T, -1)
            statistics = full
        tracked = {name: t.result(T - t.job.first) for name, t in self.trackers.items()}
        return Record(self.nominal.MODEL, a["time"], a["ys"], a["us"], self.outputs, tuple(self.nominal.STATES),
                      self.present, a["y_mean"], a["y_std"], a["z"], a["x_mean"], a["x_std"], statistics,
                      self.detector.threshold, self.detection, self.isolation, tuple(self.events), data,
                      self.clock, self.clouds, self.kf.track() if self.kf is not None else None, tracked, self.excused)

    def finish(self, data: DataSummary | None, truth: Run | None = None, intermittent: bool = True) -> Diagnosis:
        """The diagnosis of the record (its ``seconds`` are the caller's;
        ``intermittent``: whether faults that come and go are tried, :class:`~bgc.diagnosis.finish.Setting`)."""
        if self.detection is not None and self.isolation is None:  # the data ended before the symbols' samples
            self.isolate()
        c = self.config
        record = self.record(data)
        # the record's steps 4 to 6b, kept for a diagnosis of the same record asked again (faults that come and
        # go tried then, which those steps do not read): the same samples, alarm, symbols, armed detector, truth
        key = (len(self.samples), id(self.samples[-1]) if self.samples else None, id(self.detection),
               id(self.isolation), self.watch_from, self.excused, id(truth))
        if self._memo[0] != key:
            self._memo = (key, {})
        d = finish(record, Setting(c.package, c.priors, c.options, self.horizon, c.say, intermittent), truth,
                   self._memo[1])
        if d.verdict == "ambiguous" and isinstance(c.signatures, ModeSignatures) and d.onset_step is not None:
            # which other mode's signatures would separate the candidates, over the modes since the onset
            mode = nominal_model(c.package).MODE_INPUT
            split = c.signatures.split(d.candidates, record.us[d.onset_step:, mode])
            if split is not None:
                d = dataclasses.replace(d, mode_split=split)
        return d


def isolate(config: LoopConfig, pf_class, detection, clouds: dict, ys: np.ndarray, us: np.ndarray,
            observer) -> Isolation:
    """Step 3 of the method on a record: the onsets each hypothesis is tried
    from, the symbols read on the open-loop nominal prediction from the
    detector's onset, and the fault models they keep."""
    o, T, package = config.options, len(ys), config.package
    reach, near, kalman_reach, onsets, kalman_onsets = onsets_tried(o, detection, T)
    config.say("reading the symbols of the deviating sensors")
    onset = detection.onset_step
    steps = min(T - onset, detection.step - onset + 1 + o.symbol_steps)
    cloud = gaussian_cloud(observer, onset, o) if config.ckf else cloud_before(clouds, onset)
    seen = observed_symbols(open_loop(package, pf_class, nominal_model(package), cloud, ys, us, onset, steps, o),
                            tuple(nominal_model(package).OUTPUTS), o.windows)
    if isinstance(config.signatures, ModeSignatures):  # a model with modes: those the symbols were read in
        mode = nominal_model(package).MODE_INPUT
        keep, dropped = config.signatures.hypotheses(seen, us[onset:onset + steps, mode])
    else:
        keep, dropped = signature_hypotheses(config.signatures, seen)
    events = []
    if config.every and dropped:
        events.append(ev.AllTried("unexplained", T - 1))
        keep = list(config.signatures.signatures)
    elif not keep:
        events.append(ev.AllTried("no-signature", T - 1))
        keep = list(config.signatures.signatures)
    excluded: tuple[str, ...] = ()
    frozen = frozen_sensor(detection)
    if frozen is not None:  # a reading held still: its sensor's stuck fault and nothing else, whatever the symbols
        keep = [s for s in config.signatures.signatures if s.parameter == f"{frozen}_stuck"]
        kept = {f"{s.parameter}_{s.kind}" for s in keep}
        excluded = tuple(sorted(n for n in package.MODELS if n != "nominal" and n not in kept))
        events = [ev.ReadingFrozen(T - 1, frozen, detection.onset_step, tuple(sorted(kept)))]
        # its onset is the first reading that repeats, to the sample: the stuck fault is tried from there only
        # (its model reads the held value with the sensor's noise, so the readings just before, as near it,
        # would draw the onset earlier: the repeats themselves say where it is)
        reach = kalman_reach = [detection.onset_step]
        onsets = kalman_onsets = {True: reach, False: reach}
    models: dict[str, list[str]] = {}
    for s in keep:
        models.setdefault(f"{s.parameter}_{s.kind}", []).append(s.name)
    names = [n for n in sorted(models) if n in package.MODELS]
    # whether each is tried from a drift's onsets back from the alarm (a drift, a burst of noise)
    drifts = {name: fault_kind(package.MODELS[name].FAULT["kind"]).searched_back for name in names}
    return Isolation(onset, seen, tuple((s.name, why) for s, why in dropped),
                     tuple(f"{s.parameter}_{s.kind}" for s, _ in dropped), models, names, drifts,
                     {name: onsets[drifts[name]] for name in names}, reach, kalman_onsets, kalman_reach,
                     tuple(events), excluded)


def frozen_sensor(detection) -> str | None:
    """The sensor the detector saw frozen: its reading repeated to the last
    digit beyond chance (the ``frozen`` test, :mod:`bgc.diagnosis.detect`);
    None for every other alarm (a variance that fell is evidence too, but a
    reading quantised coarser than the model thinks, or a noise that shrank,
    lowers it as well: the fault models decide)."""
    return detection.sensor if detection.test == "frozen" else None


def onsets_tried(o: DiagnosisOptions, detection, T: int):
    """The onsets tried: (a drift's reach for the particle filters, the steps
    near the change point, a drift's reach for the Kalman filters, the
    particle filters' onsets and the Kalman filters' by whether the fault is
    looked for back from the alarm)."""
    spacing = o.spacing or (8 if o.identify == "kalman" else 4)

    def first_tried(reach: list[int]) -> list[int]:  # a drift's onsets near the alarm, and the change point
        return [k for k in reach if k >= detection.step - o.search or detection.onset_step - 1 <= k <= detection.onset_step]

    reach = drift_onsets(detection.step, detection.onset_step, spacing, o.history)
    near = {k for k in range(detection.onset_step - o.near, detection.onset_step + 3) if 0 <= k <= detection.step + 1 and k < T}
    kalman_reach = drift_onsets(detection.step, detection.onset_step, o.kalman.spacing, o.history)
    # a step's Kalman onsets reach the alarm: a change point that falls early leaves the true onset after it
    late = {k for k in range(detection.onset_step + 3, detection.step + 1) if k < T}
    kalman_onsets = {True: first_tried(kalman_reach), False: sorted(near | late)}
    onsets = {True: first_tried(reach), False: sorted(near)}
    return reach, near, kalman_reach, onsets, kalman_onsets


def shifted_events(events, cut: int) -> tuple:
    """Data events with their steps ``cut`` earlier, those before the record kept left out."""
    moved = (ev.shifted(e, cut) for e in events)
    return tuple(e for e in moved if e is not None)


def _whiten(e: np.ndarray, S: np.ndarray) -> np.ndarray | None:
    """Innovations ``e`` whitened by the lower Cholesky factor of their
    covariance ``S``: L^-1 e, white N(0, I) on an exact observer without a
    fault; None when a sensor was not read or ``S`` is not positive definite."""
    if not (np.isfinite(e).all() and np.isfinite(S).all()):
        return None
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None
    return lower_solve(L[None], e[None, :, None])[0, :, 0]
