"""The diagnosis's steps that need more than one sample: the onsets tried,
the open-loop run of the symbols, the hypotheses' filters over the record
(in parallel), their static posteriors (cubature Kalman filters on a grid),
the weighing, ranking and refining, and the estimates. The diagnoser
(:mod:`bgc.runtime.diagnoser`) calls them; the method is described in
:mod:`bgc.runtime.diagnose`."""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import sys
import time
import zlib
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from ..kinds import fault_kind
from . import identify, kalman
from .detect import Detection, Detector, DetectorOptions
from .hypothesis import FAR, TrackJob, rejection_options, run_job, weighted_quantiles
from .identify import GridOptions
from .isolate import OpenLoop
from .kalman import KalmanOptions, StaticPosterior, onset_widths
from .runs import Run
from .values import DiagnosisOptions, Estimate, Hypothesis


#: The nominal observer degenerates when its mean effective sample size
#: before the alarm is under this share of its particles (a diagnosis note
#: says so).
DEGENERATE = 0.05

#: How a hypothesis's magnitude is identified and the hypotheses weighed:
#: ``kalman``, with the magnitude held static, by cubature Kalman filters on a
#: grid of onsets and magnitudes (:mod:`bgc.runtime.kalman`); ``filter``, by
#: the particle filters' own magnitude state and evidence.
IDENTIFY = ("kalman", "filter")


def _earlier(reach: list[int], tried, search: int) -> tuple[tuple[int, ...], ...]:
    """The onsets of ``reach`` not ``tried`` and before the latest one
    tried, in batches of ``search`` samples back from the earliest tried
    (the gap between the tried ones first: the detector's change point may
    lie far before the others), the nearest batch first.

    >>> _earlier([100, 150, 190, 200, 210, 220], [180, 200, 210, 220], 16)
    ((190,), (150,), (100,))
    >>> _earlier([100, 150, 190, 200, 210, 220], [150, 210, 220], 16)
    ((190, 200), (100,))
    """
    tried = sorted(tried)
    gap = tuple(k for k in reach if tried[0] < k < tried[-1] and k not in tried)
    batches, edge = [gap] if gap else [], tried[0]
    while any(k < edge for k in reach):
        batch = tuple(k for k in reach if edge - search <= k < edge)
        if batch:
            batches.append(batch)
        edge -= search
    return tuple(batches)


@dataclass(frozen=True, slots=True)
class StaticJob:
    """The arguments of :func:`bgc.runtime.kalman.static_posterior` for one
    hypothesis: ``package_name``, the generated package (imported in the
    worker by name), ``name``, its fault model."""

    package_name: str
    name: str
    ys: np.ndarray
    us: np.ndarray
    track: kalman.NominalTrack
    onsets: tuple[int, ...]
    hint: tuple[float, float]
    hint_onset: int
    level: float
    options: KalmanOptions
    earlier: tuple[tuple[int, ...], ...]
    record: bool = False
    refine: bool | None = None
    far: tuple | None = None  # (outputs, rejection, windows) of :func:`_far_off`


def _far_off(outputs: tuple[str, ...], rejection: float, windows: tuple[int, ...]):
    """The consistency test of section 5 at ``FAR`` times its threshold, as a
    predicate of a filter's normalised residuals (steps x outputs): True when
    they are far off the data."""
    def far(z: np.ndarray) -> bool:
        return _first_alarm(z, outputs, rejection, windows, FAR) is not None
    return far


def _static_job(job: StaticJob) -> StaticPosterior:
    """:func:`bgc.runtime.kalman.static_posterior` of one hypothesis (in a
    worker process); with ``record``, its most probable onset's filter too
    (:func:`bgc.runtime.kalman.record_path`); ``seconds``: its time."""
    started = time.perf_counter()
    model = sys.modules[job.package_name].MODELS[job.name]
    far = None if job.far is None else _far_off(*job.far)
    p = kalman.static_posterior(model, job.ys, job.us, job.track, job.onsets, job.hint, job.hint_onset, job.level,
                                job.options, job.earlier, job.refine, far)
    if job.record:
        p = kalman.record_path(model, job.ys, job.us, job.track, p)
    return dataclasses.replace(p, seconds=time.perf_counter() - started)


#: The diagnosis method with cubature Kalman filters alone (``--filter ckf``).
KALMAN_METHOD = "ckf"


def _gaussian_cloud(observer: kalman.NominalTrack, onset: int, options: DiagnosisOptions):
    """A cloud of ``options.particles`` equally weighted draws from the
    nominal cubature Kalman filter's state before step ``onset`` (its
    Gaussian), for the open-loop run of the symbols."""
    rng = np.random.default_rng([options.seed, 9997])
    L = kalman.cholesky(observer.cov[onset][None])[0]
    x = observer.mean[onset][:, None] + L @ rng.standard_normal((len(observer.mean[onset]), options.particles))
    return x, np.zeros(options.particles)


def _kalman_hypotheses(names: list[str], models: dict, package, run: Run | None, times, ys, us,
                       observer: kalman.NominalTrack,
                       onsets: dict, reach: list[int], drifts: dict, options: DiagnosisOptions,
                       say) -> tuple[list[dict], dict[str, StaticPosterior]]:
    """``--filter ckf``: each hypothesis's static posterior (:mod:`bgc.runtime.kalman`)
    over its onsets (``onsets[drifts]``; a drift reaching back over
    ``reach``) with its magnitude's whole prior as the first grid's span,
    the jobs on ``options.workers`` processes; then each as the dict
    :func:`diagnose` assembles: its most probable onset's filter (posterior
    mean magnitude) gives the predicted measurements and state estimates, the
    sequential posterior the magnitude over time, and the consistency test
    of the most likely cell (section 5's windowed Z-test) drops it."""
    T = len(ys)
    say(f"weighing {len(names)} fault hypotheses ({', '.join(names)}) with cubature Kalman filters over their "
        f"onsets and magnitudes")
    outputs = tuple(package.MODELS["nominal"].OUTPUTS)
    jobs = []
    for name in names:
        module = package.MODELS[name]
        # a step change too reaches back over the drifts' grid of onsets while its onset posterior piles up
        # at its earliest onset: a plant that answers slowly shows a step long after it
        tried = onsets[drifts[name]]
        earlier = _earlier(reach, tried, options.search)
        a, b = (float(v) for v in module.FAULT_PRIOR)
        jobs.append(StaticJob(package.__name__, name, ys, us, observer, tuple(tried), (a, b), min(tried),
                              options.interval, options.kalman, earlier, record=True, refine=True,
                              far=(outputs, options.rejection, options.windows)))
    posteriors = dict(zip(names, _run_all(jobs, options.workers, _static_job)))
    q = NormalDist().inv_cdf((1.0 + options.interval) / 2.0)
    n = len(package.MODELS["nominal"].STATES)
    hyps = []
    for name in names:
        module, p = package.MODELS[name], posteriors[name]
        parameter, kind_name = module.FAULT["parameter"], module.FAULT["kind"]
        nominal, truth = _truth(module, run)
        nan = math.nan
        estimate = Estimate(parameter, kind_name, fault_kind(kind_name).magnitude, nan, nan, nan, nan,
                            options.interval, nan, nominal, truth, method="kalman")
        h = dict(name=name, parameter=parameter, kind=kind_name, signatures=tuple(models[name]),
                 onsets=p.onsets, onset_posterior=p.onset_posterior, log_evidence=p.log_evidence,
                 seconds=p.seconds, estimate=estimate, dropped=None, reason="")
        if p.path is None:  # no finite likelihood: nothing to show
            start = max(p.onsets)
            empty = np.full((T - start, len(outputs)), np.nan)
            h.update(start=start, y_mean=empty, y_std=empty, z=empty, x_mean=np.full((T - start, n), nan),
                     x_std=np.full((T - start, n), nan), magnitude=np.full(T - start, nan),
                     magnitude_band=np.full((T - start, 2), nan))
        else:
            start, path = p.onset, p.path
            y_mean, y_std = path.y_mean[start:, 0], path.y_std[start:, 0]
            mean, std = p.trace[start:, 0], p.trace[start:, 1]
            h.update(start=start, y_mean=y_mean, y_std=y_std, z=(ys[start:] - y_mean) / y_std,
                     x_mean=path.x_mean[start:, 0, :n], x_std=path.x_std[start:, 0, :n], magnitude=mean,
                     magnitude_band=np.column_stack([mean - q * std, mean + q * std]))
            alarm = _static_alarm(p, outputs, options)
            if alarm is not None:
                h["dropped"] = p.best[0] + alarm.step
                h["why"] = "static-test"
                h["reason"] = (f"with its {estimate.magnitude} held at its most probable value {p.best[1]:.4g} from "
                               f"t = {times[p.best[0]]:g}, its residual of {alarm.sensor} over {alarm.window} "
                               f"sample(s) reached {alarm.statistic:.1f} (threshold {alarm.threshold:.1f})")
        hyps.append(h)
    return hyps, posteriors


def _checked(h: Hypothesis, outputs, options: DiagnosisOptions) -> Hypothesis:
    """``h`` with the consistency test of its static model: the windowed
    Z-test of section 5 (a probability ``rejection`` of an alarm on the true
    model over the run) on the normalised residuals of its static
    posterior's most likely cell, from that cell's onset; its first alarm,
    or None."""
    alarm = None if h.static is None else _static_alarm(h.static, outputs, options)
    return h if alarm is None else dataclasses.replace(h, static_alarm=alarm)


def _static_alarm(p: StaticPosterior, outputs, options: DiagnosisOptions) -> Detection | None:
    """The first alarm of the windowed Z-test of section 5 on the normalised
    residuals of static posterior ``p``'s most likely cell, from that cell's
    onset (None: it passes, or ``p`` has no such cell)."""
    if p.residuals is None or p.best is None:
        return None
    return _first_alarm(p.residuals[p.best[0]:], outputs, options.rejection, options.windows)


def _first_alarm(z: np.ndarray, outputs: tuple[str, ...], rejection: float, windows: tuple[int, ...],
                 scale: float = 1.0) -> Detection | None:
    """The first alarm of the windowed Z-test of section 5 (probability
    ``rejection`` over the steps of ``z``, its threshold times ``scale``) on
    the normalised residuals ``z`` (steps x outputs); None: they pass."""
    test = Detector(outputs, DetectorOptions(rejection, windows, len(z)))
    test.threshold *= scale
    for zk in z:
        alarm = test.update(zk)
        if alarm is not None:
            return alarm
    return None


def static_estimate(e: Estimate, p: StaticPosterior) -> Estimate:
    """``e`` with the static posterior's mean, std and interval of the
    magnitude, and the parameter's value at the last step (nominal plus the
    posterior mean of its change)."""
    return dataclasses.replace(e, value=p.mean, std=p.std, low=p.low, high=p.high,
                               parameter_value=e.nominal + p.change, method="kalman")


#: A drift's onsets are tried every ``spacing`` samples back from the alarm,
#: and further back every 1/16 of the distance to the alarm (when larger): the
#: error of a drift's onset matters relative to how long it ran before the
#: alarm (a slope fitted over d samples from an onset d/32 off is off by about
#: 3 %), so a far onset needs a coarser grid only. (With 1/8, the circuit's and
#: the two tanks' drifts of the sweep were diagnosed a quarter faster, but 2
#: and 3 fewer right: bench/drift_isolation.py.)
ONSET_GROWTH = 1.0 / 16.0


def drift_onsets(step: int, change_point: int, spacing: int, history: int) -> list[int]:
    """The onsets a drift is tried from: the detector's change point and the
    sample before it (the change point is the first sample that deviates; a
    fault that acts through the dynamics began a sample earlier: the
    transition out of its onset sample moves the next one), and from the
    alarm (``step``) back to ``history`` samples before it (not before the
    first sample), ``spacing`` apart, or 1/16 of the distance back
    (:data:`ONSET_GROWTH`) where that is larger."""
    out, d = {change_point, max(change_point - 1, 0)}, 0
    while step - d >= 0 and d <= history:
        out.add(step - d)
        d += max(spacing, int(d * ONSET_GROWTH))
    return sorted(out)


def hypothesis_job(name: str, starts: list[int], package, clouds: dict, ys, us, nominal_density, outputs,
                   options: DiagnosisOptions, horizon: int, best: np.ndarray | None = None) -> tuple:
    """The arguments of :func:`~bgc.runtime.hypothesis.run_job` for
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
    """Hypothesis ``name``'s :class:`~bgc.runtime.hypothesis.TrackJob` from
    the onsets ``starts`` (steps of the record; the job counts them from the
    earliest), with the nominal clouds before them."""
    f = min(starts)
    return TrackJob(name, package.__name__, options.method, options.particles, f, tuple(s - f for s in starts),
                    {s - f: hypothesis_seed(options.seed, name, s) for s in starts},
                    {s - f: _cloud(clouds, s) for s in starts},
                    {s - f: rejection_options(options.rejection, options.windows, horizon, s) for s in starts},
                    options.interval, options.shrinkage, tuple(outputs), bar)


def _onset_weights(starts: list[int], evidence) -> tuple[np.ndarray, float]:
    """A hypothesis's onset posterior (each onset's evidence times its width,
    normalised; zeros when no onset has evidence) and its log evidence (the
    log of that sum; -inf when none has), from its onsets' evidences over a
    common span."""
    e = np.asarray(evidence, dtype=float)
    if not np.isfinite(e).any():
        return np.zeros(len(starts)), -math.inf
    w = onset_widths(starts) * np.exp(e - e.max())
    return w / w.sum(), float(e.max() + math.log(w.sum()))


def hypothesis_seed(seed: int, name: str, onset: int) -> list[int]:
    """The seed of hypothesis ``name``'s filter from ``onset``: fixed by the
    name (a CRC-32 of it, the same in every process), so that a hypothesis gets
    the same random numbers whichever other hypotheses the symbols keep."""
    return [seed, 1, zlib.crc32(name.encode()), onset]


def _top_onsets(onsets, posterior, start: int, count: int) -> tuple[int, ...]:
    """The ``count`` most probable of a hypothesis's onsets (those with a posterior)."""
    order = np.argsort(posterior)[::-1][:count]
    return tuple(sorted(onsets[i] for i in order if posterior[i] > 0)) or (start,)


def _grid(package, name: str, estimate: Estimate, clouds: dict, ys, us, onsets, options: DiagnosisOptions, seed,
          first: int | None = None, grid: GridOptions | None = None) -> identify.GridPosterior:
    """The grid posterior of hypothesis ``name``'s magnitude (:func:`bgc.runtime.identify.refine`) on
    ``grid`` (default: ``options.grid``), over the data from ``first`` (default: the earliest onset)."""
    first = min(onsets) if first is None else first
    return identify.refine(package, name, _cloud(clouds, first), ys, us, onsets,
                           estimate.low, estimate.high, tuple(package.MODELS[name].FAULT_PRIOR), options.interval,
                           grid or options.grid, seed, parts=max(1, options.workers),
                           mapper=lambda fn, jobs: _run_all(jobs, options.workers, fn), first=first)


def _ranked(hyps: list[dict], weights: np.ndarray, priors: dict[str, float], package, clouds: dict, ys, us,
            options: DiagnosisOptions, grids: dict) -> np.ndarray:
    """The survivors' posterior weighed anew by the evidence of their static
    models: the magnitude held at each value of a grid, uniform on its prior,
    integrated (:func:`bgc.runtime.identify.log_evidence`); the onsets, each
    hypothesis's most probable ones, each weighed by the span of samples it
    stands for (:func:`onset_widths`; those not on the grid counted through
    the filters' onset posterior: the grid's sum divided by the share of the
    onset posterior it covers).
    Every grid covers the data from the earliest of those onsets, from the
    same nominal cloud and with the same random numbers before each onset, so
    the evidences compare like for like. The survivors share the posterior
    mass they had; one less probable than the best by more than the Bayes
    factor is dropped. Fills ``grids`` (name -> grid posterior)."""
    alive = [i for i, h in enumerate(hyps) if h["dropped"] is None]
    chosen = {i: _top_onsets(hyps[i]["onsets"], hyps[i]["onset_posterior"], hyps[i]["start"],
                             options.rank_grid.onsets) for i in alive}
    first = min(min(o) for o in chosen.values())
    log_w = []
    for i in alive:
        h = hyps[i]
        g = _grid(package, h["name"], h["estimate"], clouds, ys, us, chosen[i], options, [options.seed, 8], first,
                  options.rank_grid)
        grids[h["name"]] = g
        posterior = dict(zip(h["onsets"], h["onset_posterior"]))
        width = dict(zip(h["onsets"], onset_widths(h["onsets"])))
        covered = sum(posterior.get(s, 0.0) for s in g.onsets) or 1.0
        evidence = identify.log_evidence(g, tuple(package.MODELS[h["name"]].FAULT_PRIOR),
                                         [width[s] for s in g.onsets]) - math.log(covered)
        h["static_log_evidence"] = evidence
        log_w.append(math.log(max(priors.get(h["parameter"], 0.01), 1e-300)) + evidence)
    log_w = np.array(log_w)
    weights = weights.copy()
    if np.isfinite(log_w).any():
        share = np.exp(log_w - log_w.max())
        weights[alive] = weights[alive].sum() * share / share.sum()
    top = max(weights[alive])
    for i in alive:
        if weights[i] < top / options.bayes_factor:
            hyps[i]["dropped"] = len(ys) - 1
            hyps[i]["reason"] = (f"with the magnitudes held static, the data favour another hypothesis by a Bayes "
                                 f"factor above {options.bayes_factor:g} (posterior {weights[i] / weights.sum():.2g})")
    return weights


def _refined(h: Hypothesis, g: identify.GridPosterior | None, package, clouds: dict, ys, us,
             options: DiagnosisOptions) -> Hypothesis:
    """``h`` with its estimate from the grid posterior (:mod:`bgc.runtime.identify`): ``g``, or computed here."""
    module = package.MODELS[h.name]
    e = h.estimate
    if g is None:
        onsets = _top_onsets(h.onsets, h.onset_posterior, h.start, options.grid.onsets)
        g = _grid(package, h.name, e, clouds, ys, us, onsets, options, [options.seed, 7, sum(map(ord, h.name))])
    if fault_kind(h.kind).drifts:  # the parameter at the last step: nominal + slope x time since the onset
        joint = np.exp(g.loglik - np.max(g.loglik))
        joint /= joint.sum()
        spans = np.array([(len(ys) - t) * module.DT for t in g.onsets])
        value = float(e.nominal + np.sum(joint * np.outer(spans, g.values)))
    else:
        value = e.nominal + g.mean
    estimate = dataclasses.replace(e, value=g.mean, std=g.std, low=g.low, high=g.high, parameter_value=value,
                                   method="grid")
    return dataclasses.replace(h, estimate=estimate)


def _cloud(clouds: dict, start: int):
    """The nominal cloud after the step before ``start`` (None: start at the model's prior)."""
    before = [k for k in clouds if k < start]
    return clouds[max(before)] if before else None


def _open_loop(package, cls, nominal, cloud, ys, us, onset, steps, options) -> OpenLoop:
    """The nominal model run open loop from the cloud before the onset (the
    observer stopped): the data's deviations from its mean prediction and
    each particle's path (see :class:`bgc.runtime.isolate.OpenLoop`)."""
    rng = np.random.default_rng([options.seed, 9999])
    x = None if cloud is None else cloud[0][:, package.filters.systematic_resample(cloud[1], rng)]
    pf = cls(nominal, options.particles, rng, x=x)
    blind = np.full(ys.shape[1], np.nan)
    deviation = np.empty((steps, ys.shape[1]))
    # the paths kept: all of them up to PATHS, else PATHS drawn at random (memory: steps x sensors x PATHS)
    kept = (slice(None) if options.particles <= PATHS
            else np.sort(np.random.default_rng([options.seed, 9998]).choice(options.particles, PATHS, replace=False)))
    paths = np.empty((steps, ys.shape[1], min(options.particles, PATHS)))
    with np.errstate(all="ignore"):
        for t in range(steps):
            r = pf.step(blind, us[onset + t])  # no measurement: no weighing, no resampling
            deviation[t] = ys[onset + t] - r.y_mean
            paths[t] = nominal.observe(pf.x[:, kept], us[onset + t], pf.theta) - r.y_mean[:, None]
    return OpenLoop(onset, deviation, paths, np.asarray(nominal.MEASUREMENT_STD, dtype=float))


#: Open-loop particle paths kept for the symbols' null distribution: enough for
#: the variance of a statistic to within a few per cent, whatever N.
PATHS = 4000
def _run_batches(batches: dict[str, list[int]], job, arrived, workers: int, cost, idle=None, done=None,
                 landed=None) -> None:
    """Run each hypothesis's first batch of onsets (``batches``: name ->
    onsets), and each further batch ``arrived(name, onsets, results, trace)``
    asks for once the one before it is back, until none is asked for; then
    the follow-up job ``done(name)`` gives ((function, argument), or None),
    whose result goes to ``landed(name, result)``. ``idle()`` runs here once
    the first batches are out. With ``workers`` > 1 the jobs run on that many
    forked processes, and a hypothesis's next batch starts as soon as its
    own last one is back and a worker is free, before the first batches still
    waiting (it lies on the longest chain of work), while other hypotheses'
    batches still run; the first batches start longest first (``cost(onsets)``:
    a batch's work); a follow-up waits behind every first batch (a first
    batch may lead to a follow-up of its own: the chains of work end
    together). A hypothesis's jobs depend on its own results only, so the
    results do not depend on ``workers``."""
    idle = idle or (lambda: None)
    done = done or (lambda name: None)
    order = sorted(batches, key=lambda name: -cost(batches[name]))
    if workers <= 1 or len(batches) <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        idle()
        queue = [(name, batches[name]) for name in order]
        while queue:
            name, starts = queue.pop(0)
            more = arrived(name, starts, *run_job(job(name, starts)))
            if more:
                queue.append((name, more))
                continue
            follow = done(name)
            if follow is not None:
                landed(name, follow[0](follow[1]))
        return
    waiting = [(name, (run_job, job(name, batches[name])), batches[name]) for name in order]
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork")) as pool:
        running: dict = {}
        first = True
        while waiting or running:
            while waiting and len(running) < workers:  # one job per worker: a later job can go first
                name, (fn, arg), starts = waiting.pop(0)
                running[pool.submit(fn, arg)] = (name, starts)
            if first:
                idle()
                first = False
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in sorted(finished, key=lambda f: running[f][0]):
                name, starts = running.pop(future)
                if starts is None:  # a follow-up
                    landed(name, future.result())
                    continue
                more = arrived(name, starts, *future.result())
                if more:  # on the longest path: before the first batches still waiting
                    waiting.insert(0, (name, (run_job, job(name, more)), more))
                    continue
                follow = done(name)
                if follow is not None:  # after the first batches still waiting: they may lead to follow-ups
                    waiting.append((name, follow, None))


def _run_all(jobs: list, workers: int, fn=None) -> list:
    """``fn`` (default: one hypothesis's filters) over the jobs, on ``workers`` forked processes."""
    fn = fn or run_job
    if workers <= 1 or len(jobs) <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        return [fn(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)),
                             mp_context=multiprocessing.get_context("fork")) as pool:
        return list(pool.map(fn, jobs))


def onset_mixture(parts, level: float) -> tuple[float, float, float, float]:
    """Mean, std and central interval of probability ``level`` of a mixture of
    weighted particle clouds: ``parts`` holds (weight, values, log-weights)
    per onset; each cloud's weights are normalised, then scaled by the onset's
    weight (the weights need not sum to 1)."""
    total = float(sum(w for w, _, _ in parts))
    values = np.concatenate([np.asarray(v, dtype=float) for _, v, _ in parts])
    logw = np.concatenate([np.asarray(lw, dtype=float) - np.logaddexp.reduce(lw) + math.log(w / total)
                           for w, _, lw in parts])
    weights = np.exp(logw - logw.max())
    weights /= weights.sum()
    mean = float(weights @ values)
    std = math.sqrt(max(float(weights @ (values - mean) ** 2), 0.0))
    low, high = weighted_quantiles(values, logw, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return mean, std, float(low), float(high)


def _truth(module, run: Run | None) -> tuple[float, float | None]:
    """The nominal value of fault model ``module``'s parameter and, when the
    run records it, its true magnitude (None when the run's fault is not of
    this model's kind: a parameter still moving at the end drifts, one that
    stopped stepped)."""
    p = module.FAULT["parameter"]
    kind = fault_kind(module.FAULT["kind"])
    nominal = dict(zip(module.PARAMETERS, module.THETA))[p]
    recorded = None if run is None else run.parameters.get(p)
    if recorded is None or len(recorded) < 2 or bool(recorded[-1] != recorded[-2]) != kind.drifts:
        return nominal, None
    if kind.drifts:
        return nominal, float((recorded[-1] - recorded[-2]) / (run.time[-1] - run.time[-2]))
    return nominal, float(recorded[-1] - nominal)


def _estimate(module, out: dict, run: Run | None, level: float, onsets=()) -> Estimate:
    """The magnitude's estimate: averaged over the onsets tried, each weighed
    by its posterior probability (``onsets``: (weight, filter output) pairs;
    the mixture of their last clouds gives the mean, std and interval), or
    when no onset has a weight (a dropped hypothesis), its filter ``out``'s."""
    p, kind_name = module.FAULT["parameter"], module.FAULT["kind"]
    kind = fault_kind(kind_name)
    nominal, truth = _truth(module, run)
    mixture = [(w, o) for w, o in onsets if w > 0 and "final" in o]
    if mixture:
        value, std, low, high = onset_mixture([(w, *o["final"]) for w, o in mixture], level)
        total = float(sum(w for w, _ in mixture))
        parameter_value = float(sum(w * o["parameter_value"] for w, o in mixture) / total)
        return Estimate(p, kind_name, kind.magnitude, value, std, low, high, level, parameter_value, nominal, truth)
    last = out["last"]
    return Estimate(p, kind_name, kind.magnitude, float(out["magnitude"][last]), out["final_std"],
                    float(out["band"][last, 0]), float(out["band"][last, 1]), level, out["parameter_value"],
                    nominal, truth)


@dataclass(frozen=True, slots=True)
class Isolation:
    """What the qualitative isolation found (step 3): the ``onset`` the
    symbols were read from, the ``symbols``, the signatures they ``refuted``
    ((name, why)) and the fault models of those (``ruled_out``), the
    signatures kept per fault model (``models``), the fault models tried
    (``names``) and whether each drifts, each one's onsets for the particle
    filters (``starts_of``; a drift's reach back over ``reach``) and for the
    Kalman filters (``kalman_onsets`` by drift, over ``kalman_reach``), and
    the events of the isolation."""

    onset: int
    symbols: tuple
    refuted: tuple[tuple[str, str], ...]
    ruled_out: tuple[str, ...]
    models: dict
    names: list
    drifts: dict
    starts_of: dict
    reach: list
    kalman_onsets: dict
    kalman_reach: list
    events: tuple = ()
