"""One fault hypothesis tracked on the data: its filters from every onset
tried, in lockstep, one sample at a time.

A :class:`HypothesisTracker` is made from a :class:`TrackJob` (everything it
needs, picklable: a worker process can run it) and stepped by
:meth:`HypothesisTracker.step` with the data of each step from its earliest
onset on; :meth:`HypothesisTracker.result` gives, per onset, its filter's
arrays, whether its consistency test rejected it, and its running log
evidence. The batch diagnosis runs a tracker over the whole record in a
worker (:func:`run_job`); the online diagnoser steps it as samples arrive.
Either way the numbers are the same: each filter has its own random numbers
and the loop body is one.

Per step: the onsets not started yet add the nominal observer's density; a
filter at its onset sample starts from the nominal cloud before it
(:func:`~bgc.model.protocol.onset_transition`: the transition into the onset
sample is nominal, the sample sees the fault); the filters step together (a
``FilterBank``); the magnitude gets Liu and West's kernel move; each filter's
normalised residuals feed its consistency test (a windowed Z-test,
:class:`~bgc.diagnosis.detect.DetectorBank`). A filter far off the data
(statistic above ``FAR`` times the threshold) stops; a started filter whose
evidence falls ``PRUNE`` behind the best live onset's is pruned (one that
failed its test prunes none that passes it).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from ..kinds import fault_kind
from .detect import DetectorBank, DetectorOptions, monte_carlo_share
from ..filters.registry import filter_class
from ..model.protocol import magnitude_row, onset_transition
from .onsets import hypothesis_seed
from .openloop import cloud_before
from .options import DiagnosisOptions

#: A hypothesis filter whose consistency statistic exceeds this many times the
#: threshold is stopped (its onset is out of the evidence).
FAR = 2.0

#: Onsets of a hypothesis whose running log evidence falls this far behind
#: the best onset's are pruned: a Bayes factor of e^10 (22026), so such an
#: onset would weigh under 5e-5 in the onset mixture of the estimate. Against
#: e^20 it gives the same RO drift slopes in a quarter less time
#: (bench/onset_pruning.py; docs/diagnosis.md, section 4).
PRUNE = 10.0


@dataclass(frozen=True, slots=True)
class TrackJob:
    """What hypothesis ``name``'s tracker needs, steps counted from its
    earliest onset ``first``: the generated package (imported by name), the
    filter ``method`` and ``particles``; per relative onset its seed, its
    nominal cloud (None: the model's prior) and its consistency test's
    options; the interval ``level``, the kernel ``shrinkage``, the sensors
    ``outputs``; ``bar``: per step, the best running evidence of onsets of
    this hypothesis tried before (None: none)."""

    name: str
    package_name: str
    method: str
    particles: int
    first: int
    starts: tuple[int, ...]
    seeds: dict
    clouds: dict
    rejection: dict
    level: float
    shrinkage: float
    outputs: tuple[str, ...]
    bar: np.ndarray | None = None


class HypothesisTracker:
    """Hypothesis ``job.name``'s filters from every onset (module docstring).
    Steps are relative to ``job.first``; :meth:`step` takes them in order."""

    def __init__(self, job: TrackJob):
        self.job = job
        package = sys.modules[job.package_name]
        self.package = package
        self.module = module = package.MODELS[job.name]
        self.cls = filter_class(package, job.method)
        self.started = time.perf_counter()
        n_y, n_x = len(job.outputs), len(module.STATES)
        self.n_y, self.n_x, self.k_mag = n_y, n_x, magnitude_row(module)
        self.filters: dict[int, object] = {}  # onset -> its particle filter
        self.evidence = {s: 0.0 for s in job.starts}
        self.ess = {s: float(job.particles) for s in job.starts}  # of the weights that predict the next step
        self.live = set(job.starts)
        self.k = 0  # the next step
        self._trace: list[float] = []  # per step, the best running evidence of the live onsets
        self.out: dict[int, dict] = {s: {"y_mean": [], "y_std": [], "magnitude": [], "mean": [], "std": [],
                                         "rejected": None, "stopped": False, "pruned": False, "last": -1}
                                     for s in job.starts}
        self.row = {s: r for r, s in enumerate(job.starts)}
        self.bank = package.filters.FilterBank(module)  # the running filters, stepped together
        self.tests = DetectorBank(job.outputs, job.starts, [job.rejection[s] for s in job.starts], 0)

    @property
    def done(self) -> bool:
        """Every onset's filter stopped or pruned."""
        return not self.live

    def step(self, y: np.ndarray, u: np.ndarray, nominal_density: float) -> None:
        """Take step ``self.k`` (relative to the earliest onset): measurements
        ``y``, inputs ``u``, the nominal observer's log density of ``y``."""
        k = self.k
        self.k += 1
        if not self.live:
            return
        with np.errstate(all="ignore"):
            self._step(k, y, u, nominal_density)

    def _step(self, k: int, y: np.ndarray, u: np.ndarray, nominal_density: float) -> None:
        job, module = self.job, self.module
        out, filters, evidence, live = self.out, self.filters, self.evidence, self.live
        for s in sorted(live):
            if k < s:  # not started: the nominal observer's density
                evidence[s] += float(nominal_density)
            elif s not in filters:
                rng = np.random.default_rng(job.seeds[s])
                x0 = None
                if job.clouds[s] is not None:
                    cloud = job.clouds[s]
                    x0 = module.augment(cloud[0][:, self.package.filters.systematic_resample(cloud[1], rng)], rng)
                filters[s] = self.cls(module, job.particles, rng, x=x0)
        running = [s for s in sorted(live) if k >= s]
        if running:  # else every filter left has a later onset (the earlier ones stopped or pruned)
            self._step_filters(k, running, y, u)
        # the bar of a filter that passes its test: the best live onset whose filter passes it too
        # (one that failed explains nothing, however well it did so far); of a filter that failed
        # it, the best live onset; an onset not started yet is not pruned (its fault has not been
        # tried on the data)
        best = max((evidence[s] for s in live if out[s]["rejected"] is None), default=-math.inf)
        self._trace.append(best)
        if job.bar is not None:  # onsets of this hypothesis tried before
            best = max(best, float(job.bar[k]))
        best_any = max(best, max((evidence[s] for s in live), default=-math.inf))
        for s in sorted(live):
            if k >= s and evidence[s] < (best if out[s]["rejected"] is None else best_any) - PRUNE:
                out[s]["pruned"] = True
                live.discard(s)

    def _step_filters(self, k: int, running: list[int], y, u) -> None:
        job, module, out, filters = self.job, self.module, self.out, self.filters
        pfs = [filters[s] for s in running if s < k]
        results = self.bank.step(pfs, y, u)
        _shrink_together(self.bank, pfs, self.k_mag, job.shrinkage, [r.resampled for r in results])
        if running[-1] == k:  # a filter at its onset sample: the transition into it is nominal
            pf = filters[k]
            onset_transition(module, pf.x, u, pf.theta)
            results.append(pf.step(y, u, predicted=True))
            _shrink_together(None, [pf], self.k_mag, job.shrinkage, [results[-1].resampled])
        y_mean = np.empty((len(running), self.n_y))
        y_std = np.empty((len(running), self.n_y))
        before = np.empty((len(running), 1))  # the ESS of the weights that predicted this step
        for i, s in enumerate(running):
            o, r = out[s], results[i]
            o["y_mean"].append(r.y_mean)
            o["y_std"].append(r.y_std)
            o["mean"].append(r.mean)
            o["std"].append(r.std)
            o["magnitude"].append(r.mean[self.k_mag])
            o["last"] = k - s
            y_mean[i], y_std[i] = r.y_mean, r.y_std
            before[i] = self.ess[s]
            self.ess[s] = r.ess
        # the filters' densities and consistency tests, all at once
        zk = (y - y_mean) / y_std
        density = log_density(zk, y_std)
        alarms = self.tests.update(k, [self.row[s] for s in running], zk,
                                   monte_carlo_share(y_std, _noise_std(module, results), before, job.particles),
                                   [out[s]["rejected"] is None for s in running])  # the first alarm's onset only
        for i, s in enumerate(running):
            self.evidence[s] += float(density[i])
            alarm = alarms[i]
            if alarm is not None and out[s]["rejected"] is None:
                out[s]["rejected"] = (k - s, alarm)
            if alarm is not None and alarm.statistic > FAR * alarm.threshold:
                # far off the data: a wrong hypothesis or onset, stopped here (a filter only just
                # over the threshold may be the right one with a model slightly off the truth)
                out[s]["stopped"] = True
                self.live.discard(s)

    def result(self, length: int) -> tuple[dict[int, dict], np.ndarray]:
        """Per onset, its filter's output over the ``length`` steps from the
        earliest onset (arrays from its onset, NaN where it did not run), its
        rejection (relative step, alarm) or None, its evidence (-inf: stopped
        or pruned), and the per-step trace of the best running evidence."""
        job, module = self.job, self.module
        tail = (1.0 - job.level) / 2.0
        results: dict[int, dict] = {}
        for s in job.starts:
            o = self.out[s]
            span = length - s
            r = {"rejected": o["rejected"], "stopped": o["stopped"], "pruned": o["pruned"], "last": o["last"],
                 "final_std": math.nan, "parameter_value": math.nan,
                 "evidence": self.evidence[s] if s in self.live else -math.inf,
                 "partial": self.evidence[s]}  # up to where its filter stopped
            r["y_mean"] = _padded(o["y_mean"], span, self.n_y)
            r["y_std"] = _padded(o["y_std"], span, self.n_y)
            r["mean"] = _padded(o["mean"], span, self.n_x)
            r["std"] = _padded(o["std"], span, self.n_x)
            r["magnitude"] = _padded(o["magnitude"], span, None)
            r["band"] = np.full((span, 2), np.nan)
            results[s] = r
            if s not in self.filters or o["last"] < 0:
                continue
            pf = self.filters[s]
            last = o["last"]
            r["band"][last] = weighted_quantiles(pf.x[self.k_mag], pf.logw, [tail, 1.0 - tail])
            sd = r["std"][:, self.k_mag]
            r["band"][:last] = r["magnitude"][:last, None] + NormalDist().inv_cdf(1.0 - tail) * np.outer(
                sd[:last], [-1, 1])
            r["final_std"] = float(r["std"][last, self.k_mag])
            w = np.exp(pf.logw - pf.logw.max())
            r["parameter_value"] = float(w @ module.parameter_value(pf.x, pf.theta) / w.sum())
            r["final"] = (pf.x[self.k_mag].copy(), pf.logw.copy())  # the magnitude's last cloud
        seconds = time.perf_counter() - self.started
        for r in results.values():
            r["seconds"] = seconds
        trace = np.full(length, -math.inf)
        trace[:len(self._trace)] = self._trace[:length]
        return results, trace


def run_job(args: tuple) -> tuple[dict[int, dict], np.ndarray]:
    """A tracker over its whole record (in a worker process): ``args`` is
    (job, ys, us, nominal_density), the arrays from the job's earliest onset."""
    job, ys, us, nominal_density = args
    tracker = HypothesisTracker(job)
    with np.errstate(all="ignore"):
        for k in range(len(ys)):
            tracker.step(ys[k], us[k], nominal_density[k])
            if tracker.done:
                break
    return tracker.result(len(ys))


def rejection_options(rejection: float, windows: tuple[int, ...], horizon: int, onset: int) -> DetectorOptions:
    """The consistency test of a filter from step ``onset``: probability
    ``rejection`` of rejecting the true hypothesis over what remains of the
    detector's horizon (``horizon`` steps; horizons tile the time from the
    first sample) in which the onset falls."""
    return DetectorOptions(rejection, windows, horizon - onset % horizon)


def _padded(rows: list, span: int, width: int | None) -> np.ndarray:
    shape = (span,) if width is None else (span, width)
    a = np.full(shape, np.nan)
    if rows:
        a[:min(len(rows), span)] = np.asarray(rows[:span], dtype=float)
    return a


def _noise_std(module, results: list) -> np.ndarray:
    """The measurement noise std in each running filter's predicted
    measurement, for its Monte Carlo share: MEASUREMENT_STD (n_y,), or for a
    noise fault's model its ``measurement_std`` at each filter's mean state
    (F, n_y) (only then are the means gathered: this runs every step)."""
    if not fault_kind(module.FAULT["kind"]).noise:
        return module.MEASUREMENT_STD
    return module.measurement_std(np.array([r.mean for r in results]).T).T


def log_density(z: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Per step, the Gaussian log density of the measurements (normalised
    residuals ``z``, predicted stds ``std``) up to a constant; unread sensors
    count 0."""
    return np.where(np.isfinite(z), -0.5 * z ** 2 - np.log(std), 0.0).sum(axis=-1)


def weighted_quantiles(values: np.ndarray, logw: np.ndarray, qs) -> np.ndarray:
    """The quantiles ``qs`` of weighted particles (log weights ``logw``)."""
    w = np.exp(logw - logw.max())
    order = np.argsort(values)
    c = np.cumsum(w[order])
    c /= c[-1]
    return np.interp(qs, c - 0.5 * w[order] / w.sum(), values[order])


def _shrink_together(bank, pfs: list, row: int, a: float, resampled: list[bool]) -> None:
    """The kernel move of the magnitude (state ``row``) of each filter of
    ``pfs`` just stepped by ``bank``: in the bank's arrays when it holds them,
    else (or with no bank) filter by filter."""
    if a >= 1.0 or not pfs:
        return
    rngs = [pf.rng for pf in pfs]
    if bank is not None and bank.packed:
        kernel_shrinkage(bank.x[row].reshape(len(pfs), -1), bank.logw, a, rngs, np.array(resampled))
        return
    for pf, r in zip(pfs, resampled):
        kernel_shrinkage(pf.x[row][None], pf.logw[None], a, [pf.rng], np.array([r]))


def kernel_shrinkage(theta: np.ndarray, logw: np.ndarray, a: float, rngs: list, uniform: np.ndarray) -> None:
    """Liu and West's (2001) kernel move of a static parameter's particles, in
    place: theta <- a theta + (1 - a) mean + sqrt(1 - a^2) std N(0, 1), which
    keeps the weighted mean and variance and gives particles that resampling
    duplicated distinct values again (so the cloud does not collapse onto a
    few values of the magnitude). One row per filter: ``theta`` and ``logw``
    (F, N), each filter's generator in ``rngs``; ``uniform`` (F,): the
    filters whose weights are all equal (just resampled), the others' weights
    come from ``logw``. Every sum over particles is made per row by the same
    call as for a lone row, so a filter's numbers do not depend on the others."""
    w = np.full(logw.shape, 1.0 / logw.shape[1])
    if not uniform.all():
        weighted = ~uniform
        v = logw[weighted]
        v -= v.max(axis=1)[:, None]
        np.exp(v, out=v)
        v /= v.sum(axis=1)[:, None]
        w[weighted] = v
    mean = _row_dots(w, theta)
    d = theta - mean[:, None]
    d *= d
    std = np.sqrt(np.maximum(_row_dots(w, d), 0.0))
    move = np.empty(theta.shape)
    for f, rng in enumerate(rngs):
        rng.standard_normal(out=move[f])
    move *= (math.sqrt(1.0 - a * a) * std)[:, None]
    move += ((1.0 - a) * mean)[:, None]
    theta *= a
    theta += move


def _row_dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F,): the dot product of each row of a with the same row of b (F, N)."""
    return np.matmul(a[:, None, :], b[:, :, None])[:, 0, 0]


def hypothesis_job(name: str, starts: list[int], package, clouds: dict, ys, us, nominal_density, outputs,
                   options: DiagnosisOptions, horizon: int, best: np.ndarray | None = None) -> tuple:
    """The arguments of :func:`~bgc.diagnosis.hypothesis.run_job` for
    hypothesis ``name`` from the onsets ``starts`` over the record ``ys``,
    ``us`` (the whole of it); ``best``: per step, the best running evidence
    of its onsets tried before (over the data from step 0), which its new
    onsets must keep within ``PRUNE`` of as well."""
    f = min(starts)
    return (track_job(name, starts, package, clouds, options, outputs, horizon,
                      None if best is None else best[f:] - float(nominal_density[:f].sum())),
            ys[f:], us[f:], nominal_density[f:])


def track_job(name: str, starts, package, clouds: dict, options: DiagnosisOptions, outputs, horizon: int,
              bar: np.ndarray | None = None) -> TrackJob:
    """Hypothesis ``name``'s :class:`~bgc.diagnosis.hypothesis.TrackJob` from
    the onsets ``starts`` (steps of the record; the job counts them from the
    earliest), with the nominal clouds before them."""
    f = min(starts)
    return TrackJob(name, package.__name__, options.filter, options.particles, f, tuple(s - f for s in starts),
                    {s - f: hypothesis_seed(options.seed, name, s) for s in starts},
                    {s - f: cloud_before(clouds, s) for s in starts},
                    {s - f: rejection_options(options.rejection, options.windows, horizon, s) for s in starts},
                    options.interval, _shrinkage(package.MODELS[name], options.shrinkage), tuple(outputs), bar)


def _shrinkage(model, shrinkage: float) -> float:
    """The kernel shrinkage of a fault model's magnitude: none (1) for a flag
    (:attr:`bgc.kinds.FaultKind.discrete`: 0 or 1, which a kernel move would
    spread between them where the particles disagree, an uncommanded switch
    cleared in some)."""
    return 1.0 if fault_kind(model.FAULT["kind"]).discrete else shrinkage
