"""Diagnosis: is the plant faulty, which fault, when, how large, how sure.

The architecture of the thesis (Fig. II.5, sections II.3.3, II.4 and IV.2.1),
with the onset, not the detection time, as the hand-over:

1. **Track** the plant with the nominal observer (a generated particle
   filter), one step at a time, keeping its particle clouds of the last
   ``history`` steps.
2. **Detect** with the sliding-window Z-test on its normalised residuals
   (:mod:`bgc.runtime.detect`), and estimate the onset.
3. **Isolate qualitatively**: stop the observer, run its cloud at the onset
   open loop, read each sensor's magnitude and slope symbols (window tests
   against the open-loop particle paths) and keep the faults whose TRANSCEND
   signatures agree (:mod:`bgc.runtime.isolate`).
4. **Isolate and identify quantitatively**: for each remaining (parameter,
   kind), the generated fault-model filter starts at the onset from the
   nominal cloud of that time, lifted into the fault model with the fault
   magnitude drawn from its prior, and runs to the end of the data, estimating
   the magnitude jointly with the state. The fault changes the parameter at
   the instant of the onset sample (the thesis's DBN, the simulator): the
   transition into that sample is nominal, the sample sees the fault
   (:func:`~bgc.runtime.track.onset_transition`). One hypothesis's filters run in
   lockstep over its onsets (an onset whose running evidence falls ``PRUNE``
   behind the best one's is pruned); the hypotheses run in parallel
   processes.
5. **Drop** every hypothesis whose filter cannot follow the data: the same
   windowed Z-test runs on each filter's own normalised residuals, with a
   probability ``rejection`` of rejecting a filter of the true hypothesis
   over the run. A filter whose statistic goes beyond ``FAR`` (2) times the
   threshold is far off the data: it stops there and its onset is out, so
   the work on wrong hypotheses and onsets ends early (a filter just over the
   threshold runs on: at low noise the right model is sometimes just off the
   truth). A hypothesis is dropped when the filter of its most probable onset
   is rejected, or when every onset's filter stopped. (A hypothesis whose
   every onset has been rejected runs on to the end all the same: at low
   noise the right one sometimes is, and its estimate over the whole run is
   still the best there is, reported with the verdict ``unexplained``.)
6. **Weigh and identify with the magnitude held static** (``identify =
   "kalman"``, the default): each hypothesis its filters keep gets the
   posterior of its onset and magnitude under the fault model as the thesis
   states it (a constant bias, or a constant slope, from an onset on), from
   cubature Kalman filters run over a grid of onsets and magnitudes
   (:mod:`bgc.runtime.kalman`; exact on plants linear in their states once
   the fault is fixed, a close approximation on mildly nonlinear ones). Its
   evidence, the likelihood integrated over the magnitude's prior and the
   onsets, times the candidate's prior, weighs the hypotheses; its
   posterior mean and central interval are the estimate. These jobs start as
   soon as a hypothesis's filters are done. With ``identify = "filter"`` (the
   thesis's method) the weights are the filters' own evidence instead: the
   product of each filter's one-step predictive densities (their Gaussian
   approximation, mean and std of the predicted measurement), over a common
   span (the nominal filter's densities before a later onset), summed over
   the onsets tried, each weighed by the samples it stands for (a stopped
   onset counts zero), times the candidate's prior; and the estimate is the
   filters' magnitude state (below). Either way a survivor less probable
   than the best by a Bayes factor above ``bayes_factor`` is dropped too. The
   survivors are the diagnosis; when several survive, they form an ambiguity
   group, ranked by probability, each with its estimate.
7. **Rank** (``rank``, with ``identify = "filter"`` only, off by default):
   when several survive, weigh them anew by the evidence of their models with
   the magnitude held static from particle filters on a grid, and drop those
   the Bayes factor rules out.
8. **Refine** (``refine``, off by default): each survivor's magnitude by
   the particle filters' marginal likelihood on a grid (:mod:`bgc.runtime.identify`).

The onset is a parameter too: each hypothesis is tried from the detector's
change point and, for a drift, from a grid of earlier steps (``spacing``
apart, back to ``search`` steps before the alarm, and coarser further back;
the grid is extended back by ``search`` steps at a time, up to ``history``,
while the drift's onset posterior piles up at its earliest onset; a step
change is tried from the ``near`` samples before the change point to 2 after
it, and no later than the sample after the alarm), and the
onsets are weighed like the hypotheses, each by the span of time it stands
for (its prior: uniform in time); a slow drift is detected long after it
began, and starting its filter late biases the slope.

**The filters' identification.** In the fault-model filters the fault
magnitude (a bias for an abrupt fault, a slope for an incipient one) is a
state of the fault model, with a small random walk
(per step std: a fraction of |theta| for a bias, of the prior's width for a
slope; :mod:`bgc.kinds`). After every step its particles get Liu and West's
(2001) kernel move with shrinkage ``shrinkage`` (a = 0.98, a discount of
about 0.99): the weighted mean and variance are kept, and the particles that
resampling duplicated become distinct again, so the cloud does not collapse
onto a few values while the data narrow the magnitude down. The clouds at the
last step of every onset's filter, weighed by the onset's posterior
probability, form a mixture that gives the estimate (its weighted mean) and a
central interval (weighted quantiles): the onset is averaged over, not fixed at
its most probable value. The band plotted over time is the most probable
onset's weighted mean plus or minus the normal quantile times its weighted std.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import sys
import time
import zlib
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from statistics import NormalDist
from types import ModuleType

import numpy as np

from ..errors import TrackingError
from ..ir import FaultSignatures
from ..kinds import fault_kind
from . import identify, kalman
from .detect import Detection, Detector, DetectorBank, DetectorOptions, monte_carlo_share
from .identify import GridOptions
from .kalman import EDGE, EXTEND, KalmanOptions, StaticPosterior, onset_widths
from .isolate import OpenLoop, Symbol, hypotheses, observed_symbols
from .runs import Run
from .track import check_particles, filter_class, onset_transition, run_arrays


@dataclass(frozen=True, slots=True)
class DiagnosisOptions:
    """``false_alarm``: the detector's probability of any alarm in a
    fault-free run; ``rejection``: the probability of dropping the true
    hypothesis over the run; ``windows``: the Z-tests' window lengths;
    ``search``: how far before the detection a drift's onset is looked for
    first, and by how much further back each time its onset posterior piles
    up at the earliest onset tried, up to ``history`` (the nominal clouds are
    kept that far back); ``spacing``: steps between the onsets a drift's
    particle filters are tried from near the alarm (further back, 1/16 of the
    distance to it; the detector's estimate is always one); None: 8 with
    ``identify = "kalman"`` (the Kalman filters search the onset on their own
    grid, ``kalman.spacing``, and the particle filters only need to follow
    the data), 4 with ``identify = "filter"`` (which places the onset better
    there); ``near``: samples
    before the detector's change point a step change is tried from; ``symbol_steps``: open-loop
    steps read for the symbols after the detection (a slope needs samples
    after the magnitude is seen); ``interval``: probability of the reported interval;
    ``particles``: 1000 by default: with 200, the RO plant's fault magnitude
    scatters about twice as far as the filter's own interval says (Monte
    Carlo error), with 1000 the intervals cover (measured in docs/diagnosis.md).
    ``bayes_factor``: a surviving hypothesis this many times less probable
    than the best is dropped (100: "decisive" on Jeffreys' scale);
    ``workers``: parallel processes for the hypothesis filters (1: in this
    process). ``identify``: ``kalman`` (the hypotheses weighed and the
    magnitude sized with the magnitude held static, by cubature Kalman filters
    on a grid: ``kalman`` holds their options) or ``filter`` (by the particle
    filters' magnitude state and evidence: the thesis's method). ``rank``: weigh the survivors anew by the evidence of their
    models with the magnitude held static (on the grid ``rank_grid``; see
    :func:`_ranked`): off by default; it took 1.1 to 1.7 times as long on
    the sweep's drifts and was right about as often (docs/diagnosis.md,
    section 5).
    ``refine``: replace each surviving hypothesis's estimate by the
    grid posterior of :mod:`bgc.runtime.identify` (``grid``): about three times
    slower on the RO drift, and since the estimate averages over the onsets only
    a little more accurate there (docs/results.md, section 3).
    ``switch``: when the nominal observer of a particle filter degenerates
    (its mean effective sample size before the alarm under ``DEGENERATE`` of
    its particles, a step it had to recover counting 0), diagnose again with
    cubature Kalman filters alone (``method`` ``ckf``), with a note (a
    campaign comparing filters turns it off). ``method``: ``gpf``, ``apf``,
    ``opf`` (particle filters, section 4 of the module docstring) or ``ckf``
    (no particles: the nominal observer is the cubature Kalman filter, and
    every hypothesis the symbols keep goes to the static posterior of step 6
    directly, its consistency test dropping those that fail;
    ``particles`` then only sizes the open-loop cloud of the symbols)."""

    method: str = "gpf"
    particles: int = 1000
    seed: int = 0
    false_alarm: float = 0.01
    rejection: float = 0.001
    windows: tuple[int, ...] = (1, 8, 32)
    history: int = 256
    search: int = 64
    spacing: int | None = None
    near: int = 4
    symbol_steps: int = 32
    interval: float = 0.95
    bayes_factor: float = 100.0
    shrinkage: float = 0.98
    workers: int = 2
    identify: str = "kalman"
    kalman: KalmanOptions = KalmanOptions()
    rank: bool = False
    refine: bool = False
    grid: GridOptions = GridOptions()
    rank_grid: GridOptions = GridOptions(points=11)
    switch: bool = True


@dataclass(frozen=True, slots=True)
class Estimate:
    """The fault magnitude at the end of the run: ``magnitude`` names it (bias
    or slope), ``value`` its mean, ``low`` and ``high`` the interval of
    probability ``level``; ``parameter_value``: the faulty parameter's value
    (nominal + bias, or at the last step for a drift); ``truth`` when the
    run records it."""

    parameter: str
    kind: str
    magnitude: str
    value: float
    std: float
    low: float
    high: float
    level: float
    parameter_value: float
    nominal: float
    truth: float | None = None
    method: str = "filter"

    @property
    def covers(self) -> bool | None:
        return None if self.truth is None else bool(self.low <= self.truth <= self.high)

    @property
    def relative_error(self) -> float | None:
        return None if self.truth is None else abs(self.value - self.truth) / abs(self.truth or 1.0)


@dataclass(frozen=True, slots=True)
class Hypothesis:
    """One fault model: its filters from every onset tried (``onsets``, with
    their posterior probabilities), and from the most probable one
    (``start``) its per-step predicted measurements, normalised residuals,
    state estimates (mean, std of the plant's states) and magnitude (mean,
    interval), when it was dropped and why (None: it
    survived), its log evidence (over the onsets) and posterior probability
    among the hypotheses. With the magnitude held static (``identify =
    "kalman"``, or ``rank``): ``static_log_evidence``, the evidence of its
    model with the magnitude held static (None: not computed); ``static``,
    its static posterior (Kalman filters); ``estimate`` is then the static
    posterior's and ``filter_estimate`` the particle filters' own;
    ``static_alarm``: the first alarm of the consistency test on the static
    posterior's most likely cell (None: it passed, or was not run)."""

    name: str
    parameter: str
    kind: str
    signatures: tuple[str, ...]
    start: int
    onsets: tuple[int, ...]
    onset_posterior: tuple[float, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    z: np.ndarray
    x_mean: np.ndarray
    x_std: np.ndarray
    magnitude: np.ndarray
    magnitude_band: np.ndarray
    dropped: int | None
    reason: str
    log_evidence: float
    posterior: float
    estimate: Estimate
    seconds: float
    static_log_evidence: float | None = None
    static: StaticPosterior | None = None
    filter_estimate: Estimate | None = None
    static_alarm: Detection | None = None

    @property
    def onset(self) -> int:
        """The most probable onset: the static posterior's when there is one, else the filters'."""
        return self.static.onset if self.static is not None and math.isfinite(self.static.log_evidence) else self.start


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """What :func:`diagnose` found. ``verdict``: ``no fault``, ``isolated``
    (one hypothesis survives), ``ambiguous`` (several do: ``candidates``, best
    first) or ``unexplained`` (none does; ``candidates`` then holds the one
    that lasted longest). Steps are indices into the run; ``nominal_x_mean``
    and ``nominal_x_std`` are the nominal observer's state estimates (steps x
    ``states``)."""

    model: str
    time: np.ndarray
    outputs: tuple[str, ...]
    states: tuple[str, ...]
    verdict: str
    detection: Detection | None
    onset: int | None
    symbols: tuple[Symbol, ...]
    refuted: tuple[tuple[str, str], ...]
    hypotheses: tuple[Hypothesis, ...]
    candidates: tuple[str, ...]
    nominal_y_mean: np.ndarray
    nominal_y_std: np.ndarray
    nominal_z: np.ndarray
    nominal_x_mean: np.ndarray
    nominal_x_std: np.ndarray
    statistics: np.ndarray
    threshold: float
    options: DiagnosisOptions
    seconds: float
    notes: tuple[str, ...] = field(default=())

    @property
    def best(self) -> Hypothesis | None:
        if not self.candidates:
            return None
        return next(h for h in self.hypotheses if h.name == self.candidates[0])

    @property
    def estimate(self) -> Estimate | None:
        return self.best.estimate if self.best is not None else None

    def time_of(self, step: int | None) -> float | None:
        return None if step is None else float(self.time[step])

    def state_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The state estimate (mean, std; steps x ``states``) the diagnosis
        stands for: the nominal observer's, then from its onset on the
        filter of the diagnosed hypothesis (``candidates[0]``)."""
        mean, std = self.nominal_x_mean.copy(), self.nominal_x_std.copy()
        best = self.best
        if best is not None:
            mean[best.start:], std[best.start:] = best.x_mean, best.x_std
        return mean, std


def diagnose(run: Run, package: ModuleType, signatures: FaultSignatures, priors: dict[str, float],
             options: DiagnosisOptions = DiagnosisOptions(), progress=None, every: bool = False) -> Diagnosis:
    """Diagnose a recorded run with a generated package and the model's signatures.

    ``priors``: each fault candidate's prior probability (the model's
    ``faults: ... prior``); ``progress(text)``, when given, is told what is
    being done. ``every``: try every fault model, those the symbols rule out
    too. When none of the hypotheses the symbols keep explains the data
    ("unexplained") and they ruled some fault model out, the diagnosis is
    made again that way: the symbols are a filter read off a few samples
    against signatures of a plant at steady state (a fast transient can
    settle before the slope is read), not the decision.
    """
    started = time.perf_counter()
    say = progress or (lambda text: None)
    nominal = package.MODELS["nominal"]
    check_particles(options.particles, package, "nominal")
    ckf = options.method == KALMAN_METHOD
    pf_class = filter_class(package, "gpf" if ckf else options.method)  # ckf: the open-loop cloud's filter
    if options.identify not in IDENTIFY:
        raise TrackingError(f"unknown identification {options.identify!r}", None, f"use {' or '.join(IDENTIFY)}")
    if ckf and (options.refine or options.rank):
        raise TrackingError("--refine and --rank weigh particle filters on a grid", None,
                            "use them with --filter gpf, apf or opf; ckf computes the static posterior already")
    ys, us = run_arrays(run, package, "nominal")
    T, n_y = ys.shape
    outputs = tuple(nominal.OUTPUTS)
    rng = np.random.default_rng([options.seed, 0])
    pf = None if ckf else pf_class(nominal, options.particles, rng)
    observer = kalman.nominal_track(nominal, ys, us, T) if ckf else None
    detector = Detector(outputs, DetectorOptions(options.false_alarm, options.windows, T))
    clouds: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # step -> cloud after that step
    y_mean = np.full((T, n_y), np.nan)
    y_std = np.full((T, n_y), np.nan)
    z = np.full((T, n_y), np.nan)
    x_mean = np.full((T, len(nominal.STATES)), np.nan)
    x_std = np.full((T, len(nominal.STATES)), np.nan)
    detection = None
    ess = float(options.particles)  # of the weights that predict the next step
    ess_sum, ess_steps = 0.0, 0
    say("tracking the nominal model")
    with np.errstate(all="ignore"):
        for k in range(T):
            if ckf:  # the cubature Kalman filter has run: its predictions are exact, no Monte Carlo allowance
                y_mean[k], y_std[k], z[k] = observer.y_mean[k], observer.y_std[k], observer.z[k]
                x_mean[k], x_std[k] = observer.x_mean[k], observer.x_std[k]
                if detection is None:
                    detection = detector.update(z[k])
                    if detection is not None:
                        say(f"fault detected at t = {run.time[k]:g} on {detection.sensor}")
                continue
            r = pf.step(ys[k], us[k])
            y_mean[k], y_std[k] = r.y_mean, r.y_std
            x_mean[k], x_std[k] = r.mean, r.std
            z[k] = (ys[k] - r.y_mean) / r.y_std
            if detection is None:
                clouds[k] = (pf.x.copy(), pf.logw.copy())
                clouds.pop(k - options.history - 1, None)
                detection = detector.update(z[k], monte_carlo_share(r.y_std, nominal.MEASUREMENT_STD, ess,
                                                                    options.particles))
                if detection is not None:
                    say(f"fault detected at t = {run.time[k]:g} on {detection.sensor}")
            ess = r.ess
            if detection is None or k < detection.step:  # before the alarm: a fault degenerates it too
                ess_sum += 0.0 if r.recovered else r.ess
                ess_steps += 1
    statistics = np.array(detector.statistics + [np.full(n_y, np.nan)] * (T - len(detector.statistics)))
    common = dict(model=nominal.MODEL, time=run.time, outputs=outputs, states=tuple(nominal.STATES),
                  nominal_y_mean=y_mean, nominal_y_std=y_std, nominal_z=z, nominal_x_mean=x_mean,
                  nominal_x_std=x_std, statistics=statistics, threshold=detector.threshold,
                  options=options)
    # a sensor never read (its column empty or nan throughout) tells nothing: the diagnosis says so
    notes = [f"sensor y:{y} has no sample in the run ({run.source}): every value of its column is empty or nan, "
             "so nothing is diagnosed from it" for j, y in enumerate(outputs) if not np.isfinite(ys[:, j]).any()]
    mean_ess = ess_sum / max(ess_steps, 1)
    if not ckf and mean_ess < DEGENERATE * options.particles:
        degenerate = (f"the nominal observer's particle filter ({options.method}) degenerates (mean effective "
                      f"sample size {mean_ess:.0f} of {options.particles}): a sensor is sharp against the spread "
                      f"the process noise gives the prediction, and its residuals may alarm without a fault")
        if options.switch:
            say("the particle filter degenerates: diagnosing again with cubature Kalman filters")
            again = diagnose(run, package, signatures, priors,
                             dataclasses.replace(options, method=KALMAN_METHOD, rank=False, refine=False), progress,
                             every)
            return dataclasses.replace(again, notes=(degenerate + "; diagnosed with cubature Kalman filters "
                                                     "(ckf) instead",) + again.notes,
                                       seconds=time.perf_counter() - started)
        notes.append(degenerate + "; use --filter ckf (cubature Kalman filters), or more particles")
    if detection is None:
        return Diagnosis(verdict="no fault", detection=None, onset=None, symbols=(), refuted=(), hypotheses=(),
                         candidates=(), seconds=time.perf_counter() - started, notes=tuple(notes), **common)
    # onsets tried: for a drift, the detector's estimate and a grid back to `search` steps
    # before the alarm (extended below); for a step change (its change point is sharp), the
    # samples around the detector's estimate
    spacing = options.spacing or (8 if options.identify == "kalman" else 4)
    reach = drift_onsets(detection.step, detection.onset, spacing, options.history)
    grid = [k for k in reach if k >= detection.step - options.search or detection.onset - 1 <= k <= detection.onset]
    near = {k for k in range(detection.onset - options.near, detection.onset + 3)
            if 0 <= k <= detection.step + 1 and k < T}
    onsets = {True: grid, False: sorted(near)}
    # the Kalman filters' onsets: a drift's on a grid of their own (they are cheaper than particle filters)
    kalman_reach = drift_onsets(detection.step, detection.onset, options.kalman.spacing, options.history)
    kalman_onsets = {True: [k for k in kalman_reach
                           if k >= detection.step - options.search or detection.onset - 1 <= k <= detection.onset],
                     False: sorted(near)}
    # 3. qualitative isolation on the open-loop nominal prediction from the detector's onset
    say("reading the symbols of the deviating sensors")
    onset = detection.onset
    steps = min(T - onset, detection.step - onset + 1 + options.symbol_steps)
    cloud = _gaussian_cloud(observer, onset, options) if ckf else _cloud(clouds, onset)
    seen = observed_symbols(_open_loop(package, pf_class, nominal, cloud, ys, us, onset, steps, options), outputs,
                            options.windows)
    keep, dropped = hypotheses(signatures, seen)
    if every and dropped:
        notes.append("no hypothesis the symbols kept explains the data: the fault models they ruled out are "
                     "tried as well")
        keep = list(signatures.signatures)
    elif not keep:
        notes.append("no fault signature agrees with the observed symbols: every fault model is tried")
        keep = list(signatures.signatures)
    refuted = tuple((s.name, why) for s, why in dropped)
    models: dict[str, list[str]] = {}
    for s in keep:
        models.setdefault(f"{s.parameter}_{s.kind}", []).append(s.name)
    names = [n for n in sorted(models) if n in package.MODELS]
    drifts = {name: fault_kind(package.MODELS[name].FAULT["kind"]).drifts for name in names}
    if ckf:  # 4-6. every hypothesis with its magnitude held static, by cubature Kalman filters alone
        hyps, posteriors = _kalman_hypotheses(names, models, package, run, ys, us, observer, kalman_onsets,
                                              kalman_reach, drifts, options, say)
    else:
        # 4. every fault-model filter from every onset tried: one job per hypothesis, in parallel
        starts_of = {name: onsets[drifts[name]] for name in names}
        nominal_density = _log_density(z, y_std)
        say(f"tracking {len(names)} fault hypotheses ({', '.join(names)}) from "
            f"{sum(len(starts_of[n]) for n in names)} onsets and hypotheses "
            f"(t = {run.time[min(min(s) for s in onsets.values())]:g} to {run.time[detection.step]:g})")
        # (name, onset) -> its filter's output; its evidence over the data from step 0 (from `first` below)
        results: dict[tuple[str, int], dict] = {}
        best_of: dict[str, np.ndarray] = {}  # per hypothesis and step, the best running evidence over [0, step]

        def job(name: str, starts: list[int]) -> tuple:
            return _hypothesis_job(name, starts, package, clouds, ys, us, nominal_density, outputs, options,
                                   best_of.get(name))

        def arrived(name: str, starts: list[int], res: dict, trace: np.ndarray) -> list[int]:
            """Take a batch of hypothesis ``name``'s onsets; the earlier onsets to try next (none: done)."""
            f = min(starts)
            before = float(nominal_density[:f].sum())  # the nominal observer's densities before the batch
            for rel, o in res.items():
                o["from"] = f
                o["evidence"] += before
                results[(name, rel + f)] = o
            full = np.full(T, -math.inf)
            full[f:] = trace + before
            best_of[name] = np.maximum(best_of.get(name, full), full)
            # a drift whose onsets' posterior piles up at the earliest one tried began earlier:
            # its grid is extended back by `search` steps (up to `history` before the alarm)
            tried = starts_of[name]
            more = next(iter(_earlier(reach, tried, options.search)), ())
            if not (drifts[name] and more) or options.identify == "kalman":  # the Kalman filters reach back instead
                return []
            w, log_evidence = _onset_weights(tried, [results[(name, s)]["evidence"] for s in tried])
            if not (math.isfinite(log_evidence) and w[:EDGE].sum() >= EXTEND):
                return []
            starts_of[name] = sorted([*more, *tried])
            say(f"looking for earlier onsets of {name}")
            return list(more)

        def assemble(name: str) -> dict:
            """Hypothesis ``name`` from its filters' results: its most probable onset, whether it is
            dropped and why, its onset posterior, evidence and estimate."""
            module = package.MODELS[name]
            starts = starts_of[name]
            evidence = np.array([results[(name, start)]["evidence"] for start in starts])  # stopped, pruned: -inf
            dropped_at, reason = None, ""
            if np.isfinite(evidence).any():
                start = starts[int(np.argmax(evidence))]
                every = ""
            else:  # every onset's filter was stopped or pruned: dropped when the last one was
                start = max(starts, key=lambda s: (results[(name, s)]["last"] >= 0,
                                                   s + results[(name, s)]["last"], results[(name, s)]["partial"]))
                every = f", from every onset tried ({len(starts)})" if len(starts) > 1 else ""
            if results[(name, start)]["rejected"] is not None:  # the best onset's filter failed its test
                k, a = results[(name, start)]["rejected"]
                dropped_at = start + k
                reason = (f"its residual of {a.sensor} over {a.window} sample(s) reached {a.statistic:.1f} "
                          f"(threshold {a.threshold:.1f})" + every)
            elif not np.isfinite(evidence).any():  # pruned onsets only (a filter never started)
                dropped_at = start + max(results[(name, start)]["last"], 0)
                reason = "another onset of it explained the data decisively better, and that one failed" + every
            out = results[(name, start)]
            zh = (ys[start:] - out["y_mean"]) / out["y_std"]
            onset_weights, log_evidence = _onset_weights(starts, evidence)
            return dict(name=name, parameter=module.FAULT["parameter"], kind=module.FAULT["kind"],
                        signatures=tuple(models[name]), start=start, onsets=tuple(starts),
                        onset_posterior=tuple(float(w) for w in onset_weights),
                        y_mean=out["y_mean"], y_std=out["y_std"], z=zh,
                        x_mean=out["mean"][:, :len(nominal.STATES)], x_std=out["std"][:, :len(nominal.STATES)],
                        magnitude=out["magnitude"], magnitude_band=out["band"], dropped=dropped_at, reason=reason,
                        log_evidence=log_evidence,
                        seconds=sum({results[(name, s)]["from"]: results[(name, s)]["seconds"] for s in starts}.values()),
                        estimate=_estimate(module, out, run, options.interval,
                                           [(w, results[(name, s)]) for w, s in zip(onset_weights, starts)]))

        # 6. (identify="kalman") each hypothesis its filters keep, as soon as they are done: its onset and
        # magnitude with the magnitude held static, by cubature Kalman filters on a grid, from the nominal
        # cubature Kalman filter's state at each onset (computed while the first filters run)
        posteriors: dict[str, StaticPosterior] = {}
        track: list = []

        def idle() -> None:
            if options.identify == "kalman":
                track.append(kalman.nominal_track(nominal, ys, us, max(max(s) for s in kalman_onsets.values())))

        def static_job(name: str, h: dict) -> StaticJob:
            tried = kalman_onsets[drifts[name]]
            earlier = _earlier(kalman_reach, tried, options.search) if drifts[name] else ()
            return StaticJob(package.__name__, name, ys, us, track[0], tuple(tried),
                             (h["estimate"].low, h["estimate"].high), h["start"], options.interval, options.kalman,
                             earlier)

        def done(name: str):
            if options.identify != "kalman":
                return None
            h = assemble(name)
            if h["dropped"] is not None:
                return None
            return _static_job, static_job(name, h)

        def landed(name: str, posterior: StaticPosterior) -> None:
            posteriors[name] = posterior

        _run_batches({name: starts_of[name] for name in names}, job, arrived, options.workers,
                     lambda starts: sum(T - s for s in starts), idle, done, landed)  # cost: filter steps, if none stops
        first = min(min(s) for s in starts_of.values())
        for o in results.values():  # the common span starts at `first`
            o["evidence"] -= float(nominal_density[:first].sum())
        # 5. evidence over a common span (the nominal filter's before each onset), consistency, estimates
        hyps = [assemble(name) for name in names]
        if options.identify == "kalman" and not posteriors:
            # none passed its particle filters' test: each whose most probable onset's filter still ran to the
            # end (only just off the data: a drift's filters start on a coarser grid of onsets than its Kalman
            # filters') is tested as its fault model states it, the magnitude held static
            if not track:
                idle()
            for h in hyps:
                if not math.isfinite(results[(h["name"], h["start"])]["evidence"]):
                    continue
                say(f"testing {h['name']} with its magnitude held static")
                p = _static_job(static_job(h["name"], h))
                if math.isfinite(p.log_evidence) and _static_alarm(p, outputs, options) is None:
                    posteriors[h["name"]] = p
                    notes.append(f"{h['name']}: its particle filters failed their test ({h['reason']}, at "
                                 f"t = {run.time[h['dropped']]:g}), its fault model with the magnitude held static "
                                 f"passes it")
                    h["dropped"], h["reason"] = None, ""
    evidence_of = {h["name"]: h["log_evidence"] for h in hyps}  # the filters' (a magnitude with a random walk)
    static = False
    if posteriors:  # 6. the survivors weighed with their magnitudes held static
        if any(math.isfinite(p.log_evidence) for p in posteriors.values()):
            static = True
            for h in hyps:
                p = posteriors.get(h["name"])
                h["static"] = p
                h["static_log_evidence"] = None if p is None else p.log_evidence
                evidence_of[h["name"]] = -math.inf if p is None else p.log_evidence
                if p is not None and math.isfinite(p.log_evidence):
                    if not ckf:  # the particle filters' own estimate, beside the static one
                        h["filter_estimate"] = h["estimate"]
                    h["estimate"] = static_estimate(h["estimate"], p)
                    if p.truncated:
                        notes.append(f"{h['name']}: its magnitude's posterior may reach past the Kalman filters' "
                                     f"last grid; its evidence and interval may be short")
                elif p is not None and h["dropped"] is None:
                    h["dropped"] = T - 1
                    h["reason"] = ("with its magnitude held static, its cubature Kalman filters found no finite "
                                   "likelihood at any onset and magnitude of their grid")
        elif not ckf:
            notes.append("the cubature Kalman filters found no finite likelihood: the particle filters' evidence "
                         "and estimates are reported")
        else:
            notes.append("the cubature Kalman filters found no finite likelihood for any hypothesis")
    if ckf:  # a hypothesis its consistency test dropped weighs nothing, as one its particle filters drop
        evidence_of.update({h["name"]: -math.inf for h in hyps if h["dropped"] is not None})
    weights = np.array([math.log(max(priors.get(h["parameter"], 0.01), 1e-300)) + evidence_of[h["name"]]
                        for h in hyps])
    if np.isfinite(weights).any():
        weights = np.exp(weights - weights.max())
        weights = weights / weights.sum()
    else:  # none survives (or none was tried)
        weights = np.zeros(len(hyps))
    top = max(weights) if len(weights) else 0.0
    for h, w in zip(hyps, weights):  # 6. decisively less probable than the best: dropped as well
        if h["dropped"] is None and w < top / options.bayes_factor:
            h["dropped"] = T - 1
            h["reason"] = (("with the magnitudes held static, " if static else "")
                           + f"the data favour another hypothesis by a Bayes factor above {options.bayes_factor:g} "
                           f"(posterior {w:.2g})")
    grids: dict[str, identify.GridPosterior] = {}
    if options.rank and not static and sum(h["dropped"] is None for h in hyps) > 1:  # 7. the survivors by their static evidence
        say(f"weighing {', '.join(h['name'] for h in hyps if h['dropped'] is None)} with their magnitudes held "
            f"static, on a grid")
        weights = _ranked(hyps, weights, priors, package, clouds, ys, us, options, grids)
    hypothesis_list = tuple(Hypothesis(posterior=float(w), **h) for h, w in zip(hyps, weights))
    survivors = sorted((h for h in hypothesis_list if h.dropped is None), key=lambda h: -h.posterior)
    if len(survivors) == 1:
        verdict, candidates = "isolated", (survivors[0].name,)
    elif survivors:
        verdict, candidates = "ambiguous", tuple(h.name for h in survivors)
    elif hypothesis_list:
        last = max(hypothesis_list, key=lambda h: (h.dropped, h.posterior))
        verdict, candidates = "unexplained", (last.name,)
    else:
        verdict, candidates = "unexplained", ()
    if options.refine and verdict in ("isolated", "ambiguous"):  # 8. the survivors' magnitudes on a grid
        say(f"refining the magnitude of {', '.join(candidates)} on a grid")
        reuse = grids if options.rank_grid == options.grid else {}  # the ranking's grids, when as fine
        hypothesis_list = tuple(_refined(h, reuse.get(h.name), package, clouds, ys, us, options)
                                if h.name in candidates else h for h in hypothesis_list)
    hypothesis_list = tuple(_checked(h, outputs, options) if h.name in candidates and static else h
                            for h in hypothesis_list)
    for h in hypothesis_list:
        if h.static_alarm is not None:
            a, (start, value) = h.static_alarm, h.static.best
            notes.append(f"{h.name} with its {h.estimate.magnitude} held at its most probable value {value:.4g} "
                         f"from t = {run.time[start]:g}: its residual of {a.sensor} over {a.window} sample(s) reached "
                         f"{a.statistic:.1f} (threshold {a.threshold:.1f}); the fault model as stated, or the "
                         f"Kalman filters' Gaussian approximation, does not quite hold on these data")
    untried = {f"{sig.parameter}_{sig.kind}" for sig, _ in dropped} - set(models)
    if verdict == "unexplained" and not every and untried & set(package.MODELS):
        say("no hypothesis the symbols kept explains the data: trying those they ruled out")
        again = diagnose(run, package, signatures, priors, dataclasses.replace(options, switch=False), progress,
                         every=True)
        return dataclasses.replace(again, seconds=time.perf_counter() - started)
    best_onset = next((h.onset for h in hypothesis_list if candidates and h.name == candidates[0]), onset)
    say(f"done: {verdict}" + (f", {', '.join(candidates)}" if candidates else ""))
    return Diagnosis(verdict=verdict, detection=detection, onset=best_onset, symbols=seen, refuted=refuted,
                     hypotheses=hypothesis_list, candidates=candidates, seconds=time.perf_counter() - started,
                     notes=tuple(notes), **common)


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


def _kalman_hypotheses(names: list[str], models: dict, package, run: Run, ys, us, observer: kalman.NominalTrack,
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
                h["reason"] = (f"with its {estimate.magnitude} held at its most probable value {p.best[1]:.4g} from "
                               f"t = {run.time[p.best[0]]:g}, its residual of {alarm.sensor} over {alarm.window} "
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


def _hypothesis_job(name: str, starts: list[int], package, clouds: dict, ys, us, nominal_density, outputs,
                    options: DiagnosisOptions, best: np.ndarray | None = None) -> tuple:
    """The job of :func:`_run_hypothesis` for hypothesis ``name`` from the
    onsets ``starts``; ``best``: per step, the best running evidence of its
    onsets tried before (over the data from step 0), which its new onsets
    must keep within ``PRUNE`` of as well."""
    T = len(ys)
    f = min(starts)
    bar = None if best is None else best[f:] - float(nominal_density[:f].sum())
    return (name, package.__name__, options.method, options.particles,
            {s - f: hypothesis_seed(options.seed, name, s) for s in starts},
            {s - f: _cloud(clouds, s) for s in starts}, ys[f:], us[f:], [s - f for s in starts], options.interval,
            options.shrinkage, {s - f: DetectorOptions(options.rejection, options.windows, T - s) for s in starts},
            outputs, nominal_density[f:], bar)


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


def _log_density(z: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Per step, the Gaussian log density of the measurements (normalised
    residuals ``z``, predicted stds ``std``) up to a constant; unread sensors
    count 0."""
    return np.where(np.isfinite(z), -0.5 * z ** 2 - np.log(std), 0.0).sum(axis=1)


def _weighted_quantiles(values: np.ndarray, logw: np.ndarray, qs) -> np.ndarray:
    w = np.exp(logw - logw.max())
    order = np.argsort(values)
    c = np.cumsum(w[order])
    c /= c[-1]
    return np.interp(qs, c - 0.5 * w[order] / w.sum(), values[order])


#: Open-loop particle paths kept for the symbols' null distribution: enough for
#: the variance of a statistic to within a few per cent, whatever N.
PATHS = 4000


#: A hypothesis filter whose consistency statistic exceeds this many times the
#: threshold is stopped (its onset is out of the evidence).
FAR = 2.0


#: Onsets of a hypothesis whose running log evidence falls this far behind
#: the best onset's are pruned: a Bayes factor of e^10 (22026), so such an
#: onset would weigh under 5e-5 in the onset mixture of the estimate. Against
#: e^20 it gives the same RO drift slopes in a quarter less time
#: (bench/onset_pruning.py; docs/diagnosis.md, section 4).
PRUNE = 10.0


def _run_hypothesis(job) -> tuple[dict[int, dict], np.ndarray]:
    """One hypothesis's filters from every onset, run in lockstep (in a worker
    process): per onset, its arrays, its rejection, and its running log
    evidence over [the hypothesis's first onset, T) (the nominal observer's
    density before its onset); and per step the best running evidence of the
    onsets still live whose filters pass their tests (the trace a later batch
    of onsets is pruned against). A started filter whose evidence falls
    ``PRUNE`` behind that best is pruned (it stops); a filter that failed
    its consistency test prunes none that passes it, only others that failed
    too; an onset is not pruned before its filter starts. Each filter has
    its own random numbers: a filter that runs gives the same numbers
    whichever others run beside it."""
    import sys

    (name, package_name, method, particles, seeds, clouds, ys, us, starts, level, shrinkage, rejection, outputs,
     nominal_density, bar) = job
    package = sys.modules[package_name]
    module = package.MODELS[name]
    cls = filter_class(package, method)
    started = time.perf_counter()
    T = len(ys)  # steps from the first onset
    n_y, n_x = ys.shape[1], len(module.STATES)
    k_mag = n_x - 1
    tail = (1.0 - level) / 2.0
    out: dict[int, dict] = {}
    filters: dict[int, object] = {}  # onset -> its particle filter
    evidence = {s: 0.0 for s in starts}
    ess = {s: float(particles) for s in starts}  # of the weights that predict each filter's next step
    live = set(starts)
    trace = np.full(T, -math.inf)  # per step, the best running evidence of the live onsets
    for s in starts:
        span = T - s
        out[s] = {"y_mean": np.full((span, n_y), np.nan), "y_std": np.full((span, n_y), np.nan),
                  "magnitude": np.full(span, np.nan), "band": np.full((span, 2), np.nan),
                  "mean": np.full((span, n_x), np.nan), "std": np.full((span, n_x), np.nan),
                  "rejected": None, "stopped": False, "pruned": False, "last": -1, "final_std": math.nan,
                  "parameter_value": math.nan}
    row = {s: r for r, s in enumerate(starts)}
    bank = package.filters.FilterBank(module)  # the running filters, stepped together
    tests = DetectorBank(outputs, starts, [rejection[s] for s in starts], T)
    with np.errstate(all="ignore"):
        for k in range(min(starts), T):
            for s in sorted(live):
                if k < s:  # not started: the nominal observer's density
                    evidence[s] += float(nominal_density[k])
                elif s not in filters:
                    rng = np.random.default_rng(seeds[s])
                    x0 = None
                    if clouds[s] is not None:
                        x0 = module.augment(clouds[s][0][:, package.filters.systematic_resample(clouds[s][1], rng)],
                                            rng)
                    filters[s] = cls(module, particles, rng, x=x0)
            running = [s for s in sorted(live) if k >= s]
            if running:  # else every filter left has a later onset (the earlier ones stopped or pruned)
                pfs = [filters[s] for s in running if s < k]
                results = bank.step(pfs, ys[k], us[k])
                _shrink_together(bank, pfs, k_mag, shrinkage, [r.resampled for r in results])
                if running[-1] == k:  # a filter at its onset sample: the transition into it is nominal
                    pf = filters[k]
                    onset_transition(module, pf.x, us[k], pf.theta)
                    results.append(pf.step(ys[k], us[k], predicted=True))
                    _shrink_together(None, [pf], k_mag, shrinkage, [results[-1].resampled])
                y_mean = np.empty((len(running), n_y))
                y_std = np.empty((len(running), n_y))
                before = np.empty((len(running), 1))  # the ESS of the weights that predicted this step
                for i, s in enumerate(running):
                    o = out[s]
                    r = results[i]
                    j = k - s
                    o["y_mean"][j], o["y_std"][j] = r.y_mean, r.y_std
                    o["mean"][j], o["std"][j] = r.mean, r.std
                    o["magnitude"][j] = r.mean[k_mag]
                    o["last"] = j
                    y_mean[i], y_std[i] = r.y_mean, r.y_std
                    before[i] = ess[s]
                    ess[s] = r.ess
                # the filters' densities and consistency tests, all at once
                zk = (ys[k] - y_mean) / y_std
                density = _log_density(zk, y_std)
                alarms = tests.update(k, [row[s] for s in running], zk,
                                     monte_carlo_share(y_std, module.MEASUREMENT_STD, before, particles),
                                     [out[s]["rejected"] is None for s in running])  # the first alarm's onset only
                for i, s in enumerate(running):
                    evidence[s] += float(density[i])
                    alarm = alarms[i]
                    if alarm is not None and out[s]["rejected"] is None:
                        out[s]["rejected"] = (k - s, alarm)
                    if alarm is not None and alarm.statistic > FAR * alarm.threshold:
                        # far off the data: a wrong hypothesis or onset, stopped here (a filter only just
                        # over the threshold may be the right one with a model slightly off the truth)
                        out[s]["stopped"] = True
                        live.discard(s)
            # the bar of a filter that passes its test: the best live onset whose filter passes it too
            # (one that failed explains nothing, however well it did so far); of a filter that failed
            # it, the best live onset; an onset not started yet is not pruned (its fault has not been
            # tried on the data)
            best = max((evidence[s] for s in live if out[s]["rejected"] is None), default=-math.inf)
            trace[k] = best
            if bar is not None:  # onsets of this hypothesis tried before
                best = max(best, float(bar[k]))
            best_any = max(best, max((evidence[s] for s in live), default=-math.inf))
            for s in sorted(live):
                if k >= s and evidence[s] < (best if out[s]["rejected"] is None else best_any) - PRUNE:
                    out[s]["pruned"] = True
                    live.discard(s)
            if not live:
                break
    for s in starts:
        o = out[s]
        o["evidence"] = evidence[s] if s in live else -math.inf
        o["partial"] = evidence[s]  # up to where its filter stopped
        if s not in filters or o["last"] < 0:
            continue
        pf = filters[s]
        last = o["last"]
        o["band"][last] = _weighted_quantiles(pf.x[k_mag], pf.logw, [tail, 1.0 - tail])
        sd = o["std"][:, k_mag]
        o["band"][:last] = o["magnitude"][:last, None] + NormalDist().inv_cdf(1.0 - tail) * np.outer(sd[:last], [-1, 1])
        o["final_std"] = float(o["std"][last, k_mag])
        w = np.exp(pf.logw - pf.logw.max())
        o["parameter_value"] = float(w @ module.parameter_value(pf.x, pf.theta) / w.sum())
        o["final"] = (pf.x[k_mag].copy(), pf.logw.copy())  # the magnitude's last cloud
    out_seconds = time.perf_counter() - started
    for o in out.values():
        o["seconds"] = out_seconds
    return out, trace


def _shrink_together(bank, pfs: list, row: int, a: float, resampled: list[bool]) -> None:
    """The kernel move of the magnitude (state ``row``) of each filter of
    ``pfs`` just stepped by ``bank``: in the bank's arrays when it holds them,
    else (or with no bank) filter by filter."""
    if a >= 1.0 or not pfs:
        return
    rngs = [pf.rng for pf in pfs]
    if bank is not None and bank.packed:
        _kernel_shrinkage(bank.x[row].reshape(len(pfs), -1), bank.logw, a, rngs, np.array(resampled))
        return
    for pf, r in zip(pfs, resampled):
        _kernel_shrinkage(pf.x[row][None], pf.logw[None], a, [pf.rng], np.array([r]))


def _kernel_shrinkage(theta: np.ndarray, logw: np.ndarray, a: float, rngs: list, uniform: np.ndarray) -> None:
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
            more = arrived(name, starts, *_run_hypothesis(job(name, starts)))
            if more:
                queue.append((name, more))
                continue
            follow = done(name)
            if follow is not None:
                landed(name, follow[0](follow[1]))
        return
    waiting = [(name, (_run_hypothesis, job(name, batches[name])), batches[name]) for name in order]
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
                    waiting.insert(0, (name, (_run_hypothesis, job(name, more)), more))
                    continue
                follow = done(name)
                if follow is not None:  # after the first batches still waiting: they may lead to follow-ups
                    waiting.append((name, follow, None))


def _run_all(jobs: list, workers: int, fn=None) -> list:
    """``fn`` (default: one hypothesis's filters) over the jobs, on ``workers`` forked processes."""
    fn = fn or _run_hypothesis
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
    low, high = _weighted_quantiles(values, logw, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return mean, std, float(low), float(high)


def _truth(module, run: Run) -> tuple[float, float | None]:
    """The nominal value of fault model ``module``'s parameter and, when the
    run records it, its true magnitude (None when the run's fault is not of
    this model's kind: a parameter still moving at the end drifts, one that
    stopped stepped)."""
    p = module.FAULT["parameter"]
    kind = fault_kind(module.FAULT["kind"])
    nominal = dict(zip(module.PARAMETERS, module.THETA))[p]
    recorded = run.parameters.get(p)
    if recorded is None or len(recorded) < 2 or bool(recorded[-1] != recorded[-2]) != kind.drifts:
        return nominal, None
    if kind.drifts:
        return nominal, float((recorded[-1] - recorded[-2]) / (run.time[-1] - run.time[-2]))
    return nominal, float(recorded[-1] - nominal)


def _estimate(module, out: dict, run: Run, level: float, onsets=()) -> Estimate:
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
