"""Each hypothesis with its magnitude held static (step 6): the jobs of
:func:`bgc.diagnosis.static_posterior.static_posterior` (:class:`StaticJob`,
:func:`run_static`), the hypotheses of ``--filter ckf`` from them alone
(:func:`kalman_hypotheses`), the consistency test of the most likely cell
(:func:`static_alarm`, :func:`checked`) and the estimate
(:func:`static_estimate`)."""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from ..kinds import fault_kind, switch_held
from ..filters import cubature as kalman
from . import static_posterior
from .detect import Detector, DetectorOptions
from .values import Detection
from .hypothesis import FAR
from .values import StaticPosterior
from .options import KalmanOptions
from ..data.runs import Run
from .values import Drop, Estimate, Hypothesis
from .options import DiagnosisOptions, processes
from .estimate import struck, truth_of
from .onsets import earlier_onsets
from .parallel import parallel_map
from ..model.protocol import nominal_model
from ..filters.residuals import lag_one_time, summary
from ..data.clock import Clock
from .fit import LEVEL


@dataclass(frozen=True, slots=True)
class StaticJob:
    """The arguments of :func:`bgc.diagnosis.static_posterior.static_posterior` for one
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
    far: tuple | None = None  # (outputs, rejection, windows) of :func:`far_off`


def far_off(outputs: tuple[str, ...], rejection: float, windows: tuple[int, ...]):
    """The consistency test of section 5 at ``FAR`` times its threshold, as a
    predicate of a filter's normalised residuals (steps x outputs): True when
    they are far off the data."""
    def far(z: np.ndarray) -> bool:
        return first_alarm(z, outputs, rejection, windows, FAR) is not None
    return far


def run_static(job: StaticJob) -> StaticPosterior:
    """:func:`bgc.diagnosis.static_posterior.static_posterior` of one hypothesis (in a
    worker process); with ``record``, its most probable onset's filter too
    (:func:`bgc.diagnosis.static_posterior.record_path`); ``seconds``: its time."""
    started = time.perf_counter()
    model = sys.modules[job.package_name].MODELS[job.name]
    far = None if job.far is None else far_off(*job.far)
    p = static_posterior.static_posterior(model, job.ys, job.us, job.track, job.onsets, job.hint, job.hint_onset, job.level,
                                job.options, job.earlier, job.refine, far)
    if job.record:
        p = static_posterior.record_path(model, job.ys, job.us, job.track, p)
    return dataclasses.replace(p, seconds=time.perf_counter() - started)


def run_statics(jobs: list[StaticJob], workers: int | None) -> list[StaticPosterior]:
    """``[run_static(job) for job in jobs]``: on ``workers`` processes
    (:func:`parallel_map`) when there are more than one, else in this
    process with the searches side by side
    (:func:`bgc.diagnosis.static_posterior.static_posteriors`; the jobs of one
    record, the same numbers), their paths recorded together
    (:func:`bgc.diagnosis.static_posterior.record_paths`); ``seconds``: each
    one's share of the time. ``workers`` None: the environment's
    (:func:`bgc.diagnosis.options.processes`)."""
    workers = processes(workers)
    first = jobs[0] if jobs else None
    if workers > 1 or len(jobs) <= 1 or any(job.ys is not first.ys or job.us is not first.us
                                            or job.track is not first.track for job in jobs):
        return parallel_map(run_static, jobs, workers)
    started = time.perf_counter()
    models = [sys.modules[job.package_name].MODELS[job.name] for job in jobs]
    done = static_posterior.static_posteriors(
        models, first.ys, first.us, first.track,
        [(job.onsets, job.hint, job.hint_onset, job.level, job.options, job.earlier, job.refine,
          None if job.far is None else far_off(*job.far)) for job in jobs])
    recorded = [i for i, job in enumerate(jobs) if job.record]
    for i, p in zip(recorded, static_posterior.record_paths([models[i] for i in recorded], first.ys, first.us,
                                                            first.track, [done[i] for i in recorded])):
        done[i] = p
    share = (time.perf_counter() - started) / len(jobs)
    return [dataclasses.replace(p, seconds=share) for p in done]


def kalman_hypotheses(names: list[str], models: dict, package, run: Run | None, times, ys, us,
                      observer: kalman.NominalTrack, onsets: dict, reach: list[int], drifts: dict,
                      options: DiagnosisOptions, say, *, clock: Clock) \
        -> tuple[tuple[Hypothesis, ...], dict[str, StaticPosterior]]:
    """``--filter ckf``: each hypothesis's static posterior (:mod:`bgc.diagnosis.static_posterior`)
    over its onsets (``onsets[drifts]``; a drift reaching back over
    ``reach``) with its magnitude's whole prior as the first grid's span,
    the jobs on ``options.workers`` processes; then each as a
    :class:`Hypothesis` (:func:`kalman_hypothesis`; ``clock``: how the
    record's ``times`` are written). Returns the hypotheses and their static
    posteriors by name."""
    say(f"weighing {len(names)} fault hypotheses ({', '.join(names)}) with cubature Kalman filters over their "
        f"onsets and magnitudes")
    outputs = tuple(nominal_model(package).OUTPUTS)
    jobs = []
    for name in names:
        module = package.MODELS[name]
        # a step change too reaches back over the drifts' grid of onsets while its onset posterior piles up
        # at its earliest onset: a plant that answers slowly shows a step long after it
        tried = onsets[drifts[name]]
        earlier = earlier_onsets(reach, tried, options.search)
        a, b = (float(v) for v in module.FAULT_PRIOR)
        jobs.append(StaticJob(package.__name__, name, ys, us, observer, tuple(tried), (a, b), min(tried),
                              options.interval, options.kalman, earlier, record=True, refine=True,
                              far=(outputs, options.rejection, options.windows)))
    posteriors = dict(zip(names, run_statics(jobs, options.workers)))
    hyps = tuple(kalman_hypothesis(name, tuple(models[name]), package, posteriors[name], run, times, ys, options,
                                   clock=clock) for name in names)
    return hyps, posteriors


def kalman_hypothesis(name: str, signatures: tuple[str, ...], package, p: StaticPosterior, run: Run | None, times,
                      ys, options: DiagnosisOptions, *, clock: Clock) -> Hypothesis:
    """Hypothesis ``name`` from its static posterior ``p`` alone: its most
    probable onset's filter (posterior mean magnitude) gives the predicted
    measurements and state estimates, the sequential posterior the magnitude
    over time, and the consistency test of the most likely cell (section 5's
    windowed Z-test) drops it (``static-test``, the reason's onset written as
    ``clock`` writes ``times``). Its estimate is filled in when it is
    weighed (:func:`static_estimate`)."""
    T = len(ys)
    module = package.MODELS[name]
    outputs = tuple(nominal_model(package).OUTPUTS)
    n = len(nominal_model(package).STATES)
    parameter, kind_name = module.FAULT["parameter"], module.FAULT["kind"]
    nominal, truth = truth_of(module, run)
    nan = math.nan
    estimate = Estimate(parameter, kind_name, fault_kind(kind_name).magnitude, nan, nan, nan, nan,
                        options.interval, nan, nominal, truth, method="kalman", **struck(module))
    common = dict(name=name, parameter=parameter, kind=kind_name, signatures=signatures, onset_steps=p.onsets,
                  onset_posterior=p.onset_posterior, log_evidence=p.log_evidence, seconds=p.seconds,
                  estimate=estimate)
    if p.path is None:  # no finite likelihood: nothing to show
        start = max(p.onsets)
        empty = np.full((T - start, len(outputs)), np.nan)
        return Hypothesis(start_step=start, y_mean=empty, y_std=empty, z=empty, x_mean=np.full((T - start, n), nan),
                          x_std=np.full((T - start, n), nan), magnitude=np.full(T - start, nan),
                          magnitude_band=np.full((T - start, 2), nan), **common)
    q = NormalDist().inv_cdf((1.0 + options.interval) / 2.0)
    start, path = p.onset, p.path
    y_mean, y_std = path.y_mean[start:, 0], path.y_std[start:, 0]
    mean, std = p.trace[start:, 0], p.trace[start:, 1]
    alarm = static_alarm(p, outputs, options)
    drop = None if alarm is None else Drop("static-test", p.best[0] + alarm.step,
                                           misfit_reason(estimate.magnitude, p.best[1], times[p.best[0]], alarm,
                                                         estimate.kind, clock))
    return Hypothesis(start_step=start, y_mean=y_mean, y_std=y_std, z=(ys[start:] - y_mean) / y_std,
                      x_mean=path.x_mean[start:, 0, :n], x_std=path.x_std[start:, 0, :n], magnitude=mean,
                      magnitude_band=np.column_stack([mean - q * std, mean + q * std]), drop=drop, **common)


def residual_misfit(sensor: str, window: int, statistic: float, threshold: float, stretch: bool) -> str:
    """How a fault model's residuals of ``sensor`` failed its consistency
    test: a window of the windowed test, or (``stretch``) the mean over the
    whole stretch from its onset (:func:`stretch_alarm`)."""
    if stretch:
        return (f"its residuals of {sensor} over the {window} sample(s) from its onset have a mean {statistic:.1f} "
                f"standard errors off 0 (threshold {threshold:.1f}): a small misfit at every step")
    return f"its residual of {sensor} over {window} sample(s) reached {statistic:.1f} (threshold {threshold:.1f})"


def misfit_reason(magnitude: str, value: float, start: float, alarm: Detection, kind: str = "",
                  clock: Clock = Clock()) -> str:
    """Why a fault model with its magnitude held static fails the consistency
    test (``kind``: its fault's; ``start``: the time of its onset, written
    as ``clock`` says: a caller that gives no clock has it as a number)."""
    if magnitude == "switch":  # no size
        held = f"{switch_held(kind)} t = {clock.text(start)} (its most probable onset)"
    else:
        held = (f"with its {magnitude} held at {value:.4g} from t = {clock.text(start)} (the most probable "
                "magnitude and onset; its estimate is the mean over all of them)")
    return f"{held}, {residual_misfit(alarm.sensor, alarm.window, alarm.statistic, alarm.threshold, alarm.test == STRETCH)}"


def checked(h: Hypothesis, outputs, options: DiagnosisOptions) -> Hypothesis:
    """``h`` with the consistency test of its static model: the windowed
    Z-test of section 5 (a probability ``rejection`` of an alarm on the true
    model over the run) on the normalised residuals of its static
    posterior's most likely cell, from that cell's onset; its first alarm,
    or None. One not dropped that passes it takes :func:`stretch_alarm`
    too: the mean of those residuals over the whole stretch."""
    alarm = None if h.static is None else static_alarm(h.static, outputs, options)
    if alarm is None and h.drop is None:
        alarm = stretch_alarm(h.static, outputs, replaced_sensor(h.kind, h.estimate.subject))
    return h if alarm is None else dataclasses.replace(h, static_alarm=alarm)


#: The test :func:`mean_alarm`'s alarms name (a :class:`Detection`'s ``test``): a mean over a whole stretch.
STRETCH = "stretch"
#: The fewest readings of a sensor :func:`mean_alarm` tests.
LEAST_READINGS = 10


def mean_alarm(z: np.ndarray, outputs: tuple[str, ...], level: float = LEVEL) -> Detection | None:
    """A mean of the normalised residuals ``z`` (steps x outputs, NaN: not
    read) off 0 against their own spread: per sensor read at least
    :data:`LEAST_READINGS` times, Student's t of their mean with n - 1
    degrees of freedom, its standard error their unbiased variance times
    their correlation time (:func:`held_correlation_time`, at least 1) over
    n, at ``level`` over the sensors and two tests (as the test of the model
    before a fault counts them, :mod:`bgc.diagnosis.fit`), two-sided. The
    sensor most off, as a :class:`Detection` at the last step (its window the
    readings, its statistic |t| and its threshold the quantile); None when
    every sensor passes."""
    from scipy.special import stdtrit

    z = np.asarray(z, dtype=float).reshape(len(z), len(outputs))
    summaries = [i for i in summary([z], outputs) if i.samples >= LEAST_READINGS and i.variance > 0]
    if not summaries:
        return None
    alpha = level / (2 * len(summaries))
    t, cut = {}, {}
    for i in summaries:
        n = i.samples
        tau = held_correlation_time(z[:, outputs.index(i.sensor)], i.correlation_time)
        t[i.sensor] = abs(i.mean) / math.sqrt(i.variance * n / (n - 1) * tau / n)
        cut[i.sensor] = float(stdtrit(n - 1, 1.0 - alpha / 2))
    worst = max(summaries, key=lambda i: t[i.sensor] / cut[i.sensor])
    if t[worst.sensor] <= cut[worst.sensor]:
        return None
    return Detection(len(z) - 1, worst.sensor, worst.samples, t[worst.sensor], cut[worst.sensor], None, STRETCH)


def held_correlation_time(z: np.ndarray, tau: float) -> float:
    """The correlation time :func:`mean_alarm` takes for the residuals ``z``
    of one sensor (NaN: not read), their integrated autocorrelation time
    ``tau`` (:func:`bgc.filters.residuals.correlation_time`) given: at least
    1, and at least the AR(1) process's of their lag-1 autocorrelation
    (:func:`bgc.filters.residuals.lag_one_time`). Sokal's windowed sum
    scatters widely over a few hundred samples (its lags' noise adds up) and
    a mean tested against a correlation time read short fails too often:
    residuals correlated 0.8 from step to step failed the test 53 times as
    often as the level's share says over 296 samples, 0.5: 14 times (6000
    draws each); with the AR(1) floor 7 and 1 times, at a cost of 1 % of the
    power against an offset of 0.3 of their spread (docs/results.md §81; the rates at 500
    draws: tests/test_stretch_misfit.py)."""
    return max(tau, lag_one_time(z), 1.0)


def replaced_sensor(kind: str, subject: str | None) -> str | None:
    """The sensor whose reading a fault of ``kind`` on ``subject`` replaces
    (a stuck sensor's), None for any other fault."""
    return subject if fault_kind(kind).replaces else None


def stretch_alarm(p: StaticPosterior | None, outputs: tuple[str, ...], replaced: str | None = None) \
        -> Detection | None:
    """:func:`mean_alarm` on the normalised residuals of a static
    posterior ``p``'s most likely cell, over the whole stretch from that
    cell's onset (None: it passes, or ``p`` has no such cell); ``replaced``:
    the sensor whose reading the fault replaces (a stuck one's), left out.

    The windowed test (:func:`static_alarm`) is built to alarm within a
    horizon: its longest window is 32 samples, its threshold the union
    bound's over every step. A fault model that mimics a fault outside the
    model leaves a small misfit at every step that no window reaches: a heat
    loss of a thermal plant's first body that a bias of its temperature
    sensor mimics left the bias's residuals 0.36 to 0.46 of their spread off
    0 on all three sensors for 296 samples (6 to 8 standard errors), its
    windows below their threshold (tests/test_stretch_misfit.py, a plant
    simulated by solve_ivp). Over the stretch such a mean is many standard
    errors off 0; a true fault's is a t statistic.

    A noise fault (the ``noise`` kind: a sensor's spread widened by 1 + b)
    needs it most: its magnitude is fitted to the spread of its sensor's
    residuals, so the windowed test, which measures a mean in units of that
    spread, is blunted exactly where the fault model is wrong: a drift or a
    step the model does not name moves the residuals' mean and widens their
    spread, and a noise fault widened enough passes it, to be named for a
    change it cannot make (a burst of noise moves no mean;
    tests/test_noise_fault.py)."""
    if p is None or p.residuals is None or p.best is None:
        return None
    z = np.array(p.residuals, dtype=float)[int(p.best[0]):]
    if replaced in outputs:  # the reading less the value it holds: 0 once frozen, no noise to test a mean against
        z[:, outputs.index(replaced)] = np.nan
    return mean_alarm(z, outputs)


def static_alarm(p: StaticPosterior, outputs, options: DiagnosisOptions) -> Detection | None:
    """The first alarm of the windowed Z-test of section 5 on the normalised
    residuals of static posterior ``p``'s most likely cell, from that cell's
    onset (None: it passes, or ``p`` has no such cell)."""
    if p.residuals is None or p.best is None:
        return None
    return first_alarm(p.residuals[p.best[0]:], outputs, options.rejection, options.windows)


def read_alarm(z: np.ndarray, outputs: tuple[str, ...], present, rejection: float, windows: tuple[int, ...]) \
        -> Detection | None:
    """:func:`first_alarm` on the sensors the data have (``present``: per
    output of ``outputs``, whether it is read) of the normalised residuals
    ``z`` (steps x outputs)."""
    present = np.asarray(present, dtype=bool)
    return first_alarm(np.asarray(z, dtype=float)[:, present], tuple(y for y, here in zip(outputs, present) if here),
                       rejection, windows)


def first_alarm(z: np.ndarray, outputs: tuple[str, ...], rejection: float, windows: tuple[int, ...],
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
