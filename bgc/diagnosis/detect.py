"""Fault detection: a Z-test on the nominal observer's normalised residuals.

The nominal observer (a generated particle filter) predicts each measurement
before it sees it: mean ``y_mean`` and std ``y_std`` (measurement noise plus
the particle spread). Without a fault the normalised residuals

    z_k,j = (y_k,j - y_mean_k,j) / y_std_k,j

are close to independent N(0, 1) draws (tested: white, unit variance). The
detector tests their mean over sliding windows: for each sensor j, each
window length W of :attr:`DetectorOptions.windows` and each step k,

    S_k,j,W = (z_k-W+1,j + ... + z_k,j) / sqrt(W)   ~ N(0, 1) without a fault,

and raises an alarm at the first k with |S| > c. Short windows catch a jump at
once, long ones a slow drift that no single sample shows.

**Threshold from a false-alarm rate per run.** A per-sample test at 2.576
alarms on 1 % of samples: on every 300-step run of a 4-sensor plant. The
target here is the probability ``alpha`` of any alarm in a fault-free run of
``T`` steps, over ``n_y`` sensors and ``n_W`` window lengths. With ``m = T n_y
n_W`` tests, the union (Bonferroni) bound gives

    c = Phi^-1(1 - alpha / (2 m)),

so that P(any alarm | no fault) <= m * 2 (1 - Phi(c)) = alpha. Overlapping
windows and the sensors are positively correlated, so the real rate is below
alpha (the bound is conservative, never optimistic). The threshold depends
only on alpha, T, n_y and the windows, not on the noise level: the residuals
are normalised by the observer's own predicted std.

**Monte Carlo allowance.** A particle filter's predicted mean is itself an
estimate: over the cloud that predicts step k its error has a variance of
about ``v_p (1/ESS + 1/N)``, ``v_p = y_std^2 - r^2`` the particles' share of
the predicted variance, ``ESS`` the effective sample size of the weights that
predict it (the last step's, before any resampling) and ``1/N`` the
resampling's own noise (the Monte Carlo variance the filters are tested
against, ``tests/test_filters.py``). The auxiliary filter adds the process
noise seen through the outputs analytically, so for it ``v_p`` overstates the
particles' share: the allowance errs on the safe side. In units of ``y_std``
its std is

    a_k,j = sqrt(v_p (1/ESS_k-1 + 1/N)) / y_std_k,j.

It is small (0.074 on average on the circuit at N = 1000), but the errors of
successive predictions share ancestors, so they do not average out over a
window, and they add to the innovations, which are independent of them. With
the errors fully correlated inside a window (the worst case) the window sum
has variance at most ``W + (a_k-W+1 + ... + a_k)^2``, and the detector tests

    S_k,j,W = (z_k-W+1,j + ... + z_k,j) / sqrt(W + (a_k-W+1,j + ... + a_k,j)^2).

On 500 fault-free runs of the linear circuit at 1 % per run, white N(0, 1)
residuals and the exact observer (a Kalman filter) alarm on 0.4 % of them; the
generic particle filter at N = 1000 on 1.2 % without the allowance and 0.4 %
with it (auxiliary: 0.6 % and 0.2 %; ``bench/residual_calibration.py``).

**Onset.** At an alarm at step k the change point is estimated by the
generalised likelihood ratio of a mean shift of unknown size, starting at t,
in every sensor's residuals (Basseville and Nikiforov, 1993, ch. 2):

    t_hat = argmax_t  sum_j (z_t,j + ... + z_k,j)^2 / (k - t + 1),   k - L < t <= k,

``L`` the longest window.

**A bank of tests** (``DetectorOptions.tests``; ``--detect``). The mean test
is always on; five families may join it, and the families share the
false-alarm probability ``alpha`` equally (``alpha / F`` each, ``F`` the
families on), each holding its share by the union bound over its own tests
(steps x sensors x windows), so that the detector's whole false-alarm
probability per horizon stays at most ``alpha``:

(The drift family's share on an exact observer's residuals is held by a
tighter bound, below.)

* ``drift``: a slow drift moves each residual too little for a 32-sample
  mean. Ramp-weighted sums over the last ``W`` samples (``W`` in
  :data:`DRIFT_RAMPS`), the generalised likelihood ratio of a drift from
  ``k - W + 1`` on (a ramp in the residual: a filter that cannot follow it),

      S = (1 z_k-W+1 + 2 z_k-W+2 + ... + W z_k) / sqrt(W (W + 1) (2 W + 1) / 6),

  and plain sums over the long windows :data:`DRIFT_MEANS` (a filter that
  follows a drift leaves a small constant offset in its residuals), both
  N(0, 1) without a fault, with the Monte Carlo allowance of the mean test
  in the ramp's weights. At an alarm, the onset is the change point of a
  ramp (of a mean shift for a long mean) over the longest window.
  The allowance takes a particle filter's prediction errors as fully
  correlated over the window, which a long window pays dearly for: at
  ``a = 0.074`` (the circuit's average at 1000 particles) a 256-sample
  ramp's ``(sum_i i a)^2`` is 5.9e6 against its ``sum_i i^2`` of 5.6e6, the
  statistic's std 1.43 times the innovations'. So beside a particle
  observer the diagnoser runs the nominal model's cubature Kalman filter
  while it watches, which has no Monte Carlo error, and the drift family
  tests its normalised residuals instead (:meth:`Detector.update`'s
  ``exact``, called exact here: no Monte Carlo error), with no allowance;
  not for a model with modes (a Kalman filter does not follow a hidden
  mode), whose drift family tests the particle observer's as above. On a
  linear plant those residuals are white N(0, 1); on a nonlinear one the
  cubature rule approximates them (the two tanks and RO: within the
  family's share on fault-free runs, docs/results.md section 49).
  On an exact observer's residuals (that companion, or the Kalman observer
  itself, ``--filter ckf``) the family's threshold comes from a tighter
  bound than the union over steps: a long window's statistic moves little
  from one step to the next (the 256-sample ramp's lag-one correlation is
  0.994), so most of its looks repeat the one before. Each sensor's and
  window's statistic over the horizon is a stationary N(0, 1) sequence of
  known lag-one correlation rho (:func:`lag_one`), and by the
  Hunter-Worsley bound along its chain of steps

      P(any |S_t| > c) <= 2 Psi(c) + (T - 1) 2 P(S > c, S' <= c),
      P(S > c, S' <= c) = 2 T(c, sqrt((1 - rho) / (1 + rho)))

  (``T(h, a)`` Owen's function), summed over sensors and windows
  (:func:`chain_threshold`), on ``1 - DRIFT_GAPPED`` (0.9) of the family's
  share: 4.84 instead of 5.05 for three sensors over 300 steps at a share
  of 0.2 % (five families on; 4.87 and 5.08 with all six). It holds for the whole series of residuals, so it is the
  threshold of a window read whole, which is the value the whole series
  takes there (the samples not read, drawn anew and independent of the
  rest, would not change it); a window with a sample not read (its term 0)
  is held to the union bound over every step, sensor and window on the
  other 0.1 of the share (5.47 there), so a sensor read every other step
  is still tested, later. The two parts' sum is the share.
* ``variance``: a burst of noise raises the residuals' variance, a frozen
  sensor lowers it (the filter follows the stuck reading and the residual
  keeps only what the prediction wanders). Over ``W`` samples (``W`` in
  :data:`VARIANCE_WINDOWS`) the centred sum of squares
  ``Q = sum (z - mean z)^2`` is chi-square with ``W - 1`` degrees of freedom
  without a fault (the centring leaves out an offset, the Monte Carlo error
  common to the window too); the test alarms above its ``1 - p`` quantile,
  ``p = alpha / F / (2 T n_y n_W)``. Its lower tail is tested on the residual
  in units of the sensor's own noise, ``e = (y - mean) / r``: ``z`` has too
  little variance wherever the prediction's std overstates its error (a
  filter's first steps, from a wide initial spread), but ``e`` never has
  less than the sensor's noise gives it. With independent innovations of
  variances ``s_k^2 >= r^2``, its centred sum of squares is a sum of
  chi-square terms weighted by the eigenvalues of ``D^1/2 C D^1/2`` (``C``
  the centring, ``D`` the variances over ``r^2``), each at least ``C``'s
  (Ostrowski): it is stochastically larger than chi-square with ``W - 1``
  degrees of freedom, and the ``p`` quantile of that law bounds its lower
  tail. The onset is the change point of the mean and variance together
  (the likelihood ratio ``m (v + mu^2 - 1 - log v)`` of the ``m`` samples
  from ``t``, ``mu`` their mean and ``v`` their mean square about it, of
  ``z`` or of ``e``, the series that alarmed): a bias or a stuck sensor can
  reach the variance test first, and its onset is where the mean stepped.
* ``frozen``: a sensor whose reading repeats to the last digit. A reading is
  the plant's value plus the sensor's noise, at least N(0, r^2) (``r`` the
  model's std), independent of the past, so the chance that it falls in the
  previous reading's bin of width ``q`` (the data's resolution) is at most
  ``rho = q / (sqrt(2 pi) r)``, and ``n`` repeats in a row at most
  ``rho^n``; the test alarms when ``rho^n <= alpha / F / (T n_y)``. ``q`` is
  bounded by the smallest change seen between two readings of the sensor of
  the same decimal exponent as the one repeated (every change is a multiple
  of the resolution, and a logger writing significant digits has a coarser
  one for larger values; on full-precision data a repeat is all but
  impossible and two repeats alarm). A reading that repeats by the data's
  habit (a logger writing each value twice, a historian's compression) is
  no independent draw: the run must also be longer than twice the longest
  run of repeats seen before. The onset is the step of the first repeat. A
  sensor whose noise is smaller than the model says fails the variance test
  as well: the model does not fit it.
* ``pooled``: a fault that moves several sensors a little each, none of
  them past the mean test's threshold. Over ``W`` samples (``W`` in
  :data:`POOLED_WINDOWS`) the sum of the residual vectors ``s`` (the
  sensors read in the window) has covariance ``sum_k C_k`` without a fault,
  ``C_k`` the correlation matrix of step k's residuals as the observer
  predicts it (the predicted measurement's covariance, the cubature rule
  from the observer's mean and covariance before the step,
  :meth:`bgc.filters.cubature._Filter.predicted_measurement`: a particle
  filter gives each sensor's std only); a sensor not read at a step has its
  row and column of ``C_k`` zero. The particle filter's Monte Carlo error
  adds a vector whose entries have std at most ``A_j = sum_k a_k,j``
  whatever their correlation, so its covariance is at most ``df diag(A^2)``
  (for any v, ``v' Cov v <= (sum_j |v_j| A_j)^2 <= df sum_j v_j^2 A_j^2``,
  Cauchy-Schwarz; ``df`` the sensors read). With ``M = sum_k C_k + df
  diag(A^2)``, the statistic ``s' M^-1 s`` is then at most chi-square
  with ``df`` degrees of freedom (a Gaussian whose covariance is at most
  ``M``: the weights of its chi-square terms are at most 1): the
  generalised likelihood ratio of a mean shift of unknown size and
  direction, which alarms above the chi-square's ``1 - p`` quantile, ``p =
  alpha / F / (T n_W)`` (one test per step and window, all sensors at
  once). The windows that hold a step whose correlation was not given (a
  caller without it, a cloud unsure of its mode) are not tested; the
  windows after it are. A caller that never gives one spends the family's
  share of the budget for nothing: ask for ``pooled`` only where the
  correlation comes (the diagnoser's loop gives it). The onset is the change point of that shift over
  the longest window (``argmax_t s_t' M_t^-1 s_t``, the sums from t); the
  alarm names the sensor with the largest share ``s_j^2 / M_jj``.

The variance test's lower tail is left to sensors whose readings are finer
than a quarter of their noise (``q <= r / 4``): coarser readings repeat by
themselves, and their residuals move in steps the chi-square does not
describe. Its upper tail is widened by the window's Monte Carlo share,
``(1 + max a_k^2)`` times the quantile (a prediction error that varies
within the window adds up to ``a_k^2`` to each residual's variance; the
bound of a sum of weighted chi-squares, Ostrowski, as for the lower tail).

* ``matched``: a fault of the model's list, by its own response. Over
  ``W`` samples (``W`` in :data:`bgc.diagnosis.matched.MATCHED_WINDOWS`) and
  per fault model, the projection of the exact observer's innovations,
  whitened by the Cholesky factor of their predicted covariance
  (:meth:`Detector.update`'s ``whitened``), on the fault model's whitened
  unit response from the window's start (its kernel,
  :func:`bgc.diagnosis.matched.kernels`), over the response's norm: the
  generalised likelihood ratio of that fault, of unknown size, from the
  window's start (Willsky and Jones 1976). N(0, 1) without a fault whatever
  the kernel, so the family holds its share by the chain bound over each
  kernel's steps (its lag-one correlation on white innovations is the sum of
  its neighbouring products), the union bound over the kernels
  (:meth:`DetectorOptions.matched_threshold`); a window holding a step not
  read whole is not tested. The onset is the change point of the fault
  models' responses: the start and the model whose response projects most
  of the innovations. Only beside an exact observer and with every sensor
  read (the caller gives no kernels otherwise: the family's share is spent
  on nothing, as the pooled test's without correlations).

When several families alarm at one step, the alarm is the one furthest past
its own level (the log of its p-value over its level). The alarm names the
family (:class:`~bgc.diagnosis.values.Detection`'s ``test``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from collections import deque
import functools
import math
from math import erfc, isfinite, log, pi, sqrt
from statistics import NormalDist

import numpy as np

from .values import Detection


def monte_carlo_share(y_std: np.ndarray, measurement_std: np.ndarray, ess, particles: int) -> np.ndarray:
    """a_k: the Monte Carlo std of a particle filter's predicted measurement
    mean, in units of its predicted std ``y_std`` (module docstring); ``ess``:
    the effective sample size of the weights that made the prediction (a
    number, or an array that broadcasts against ``y_std``)."""
    y_std = np.asarray(y_std, dtype=float)
    spread = np.maximum(y_std * y_std - np.asarray(measurement_std, dtype=float) ** 2, 0.0)
    inverse = 1.0 / np.maximum(np.asarray(ess, dtype=float), 1.0) + 1.0 / max(int(particles), 1)
    return np.sqrt(spread * inverse) / y_std


def union_threshold(alpha: float, tests: int) -> float:
    """The two-sided Z threshold c with P(any |Z| > c) <= alpha over ``tests``
    N(0, 1) tests, whatever their correlation (the union bound):
    c = Phi^-1(1 - alpha / (2 tests))."""
    return NormalDist().inv_cdf(1.0 - alpha / (2.0 * max(1, tests)))


def chain_threshold(alpha: float, steps: int, correlations: tuple[float, ...]) -> float:
    """The Z threshold c with P(any |X_t| > c) <= alpha over ``steps``
    steps of stationary N(0, 1) sequences, one per lag-one correlation in
    ``correlations``: the Hunter-Worsley bound along each sequence's chain of
    steps (the union of the events minus each one's overlap with the step
    before), P <= sum over the sequences of
    ``2 Psi(c) + (steps - 1) 4 T(c, sqrt((1 - rho) / (1 + rho)))``, where
    ``P(X > c, X' <= c) = 2 T(c, a)`` for a standard normal pair of
    correlation rho (T: Owen's function) and both signs count. At most the
    union bound's threshold, whatever the correlations."""
    return _chain_threshold(float(alpha), max(1, int(steps)), tuple(float(r) for r in correlations))


# The chi-square's quantiles and log tails, as scipy.stats.chi2 computes them inside its support
# (scipy.special's functions, the same expressions): scipy.stats costs a second to import in every
# process that would otherwise need it for these alone.
def chi2_ppf(p, df):
    """The chi-square's quantile of ``p`` with ``df`` degrees of freedom."""
    from scipy.special import gammaincinv

    return 2 * gammaincinv(np.asarray(df) / 2, p)


def chi2_isf(p, df):
    """The chi-square's upper quantile of ``p`` with ``df`` degrees of freedom."""
    from scipy.special import chdtri

    return chdtri(df, p)


def chi2_logcdf(q: float, df) -> float:
    """log P(chi-square with ``df`` degrees of freedom <= ``q``): the log of
    the distribution function below the median, of one less the tail above."""
    from scipy.special import chdtr, chdtrc

    with np.errstate(divide="ignore"):
        if q < float(chi2_ppf(0.5, df)):
            return float(np.log(chdtr(df, q)))
        return float(np.log1p(-chdtrc(df, q)))


def chi2_logsf(q: float, df) -> float:
    """log P(chi-square with ``df`` degrees of freedom > ``q``): the log of
    the tail above the median, of one less the distribution function below."""
    from scipy.special import chdtr, chdtrc

    with np.errstate(divide="ignore"):
        if q > float(chi2_ppf(0.5, df)):
            return float(np.log(chdtrc(df, q)))
        return float(np.log1p(-chdtr(df, q)))


@functools.lru_cache(maxsize=64)
def _chain_threshold(alpha: float, steps: int, correlations: tuple[float, ...]) -> float:
    from scipy.optimize import brentq
    from scipy.special import ndtr, owens_t

    slopes = [sqrt((1.0 - r) / (1.0 + r)) for r in correlations]

    def excess(c: float) -> float:
        return sum(2.0 * ndtr(-c) + (steps - 1) * 4.0 * owens_t(c, a) for a in slopes) - alpha

    high = union_threshold(alpha, steps * len(correlations))
    return float(brentq(excess, 0.0, high + 1e-9, xtol=1e-12, rtol=1e-12)) if excess(high) < 0.0 else high


def lag_one(w: int, ramp: bool) -> float:
    """The correlation of a drift statistic over ``w`` samples with itself one
    step before, on white residuals: ``(w - 1) / w`` for a plain sum, and
    ``sum_(i<w) i (i + 1) / sum_(i<=w) i^2`` for the ramp's weights."""
    if not ramp:
        return (w - 1) / w
    return sum(i * (i + 1) for i in range(1, w)) / sum(i * i for i in range(1, w + 1))


#: The detector's families of tests, in the order an alarm names them on a tie (module docstring).
TESTS = ("mean", "drift", "variance", "frozen", "pooled", "matched")


def tests_named(text: str) -> tuple[str, ...] | None:
    """The families of tests ``text`` names (``--detect``'s and a campaign's
    ``detect:`` form: ``all``, or some of :data:`TESTS` comma-separated), in
    :data:`TESTS`'s order with the mean test always first; None when it names
    none or one bgc does not have.

    >>> tests_named("variance,drift"), tests_named("all"), tests_named("mean"), tests_named("slope")
    (('mean', 'drift', 'variance'), ('mean', 'drift', 'variance', 'frozen', 'pooled', 'matched'), ('mean',), None)
    """
    names = [t.strip() for t in str(text).split(",") if t.strip()]
    if names == ["all"]:
        return TESTS
    if not names or any(t not in TESTS for t in names):
        return None
    return tuple(t for t in TESTS if t in names or t == "mean")


#: The drift family's ramp-weighted windows and its long mean windows (samples).
DRIFT_RAMPS = (32, 128, 256)
DRIFT_MEANS = (128, 256)
#: On an exact observer's residuals, the part of the drift family's share its windows with a sample not read
#: hold (by the union bound); the windows read whole hold the rest by the chain bound.
DRIFT_GAPPED = 0.1
#: The variance family's windows (samples).
VARIANCE_WINDOWS = (8, 32)
#: The pooled test's windows (samples).
POOLED_WINDOWS = (1, 8, 32)


@dataclass(frozen=True, slots=True)
class DetectorOptions:
    """``false_alarm``: probability of any alarm in a fault-free run of
    ``steps`` steps (all sensors, all windows, all tests); ``windows``: the
    mean test's window lengths in samples; ``tests``: the families of tests
    run (:data:`TESTS`; the mean test always), which share ``false_alarm``
    equally (module docstring, "A bank of tests")."""

    false_alarm: float = 0.01
    windows: tuple[int, ...] = (1, 8, 32)
    steps: int = 300
    tests: tuple[str, ...] = ("mean",)

    @property
    def share(self) -> float:
        """Each family's part of the false-alarm probability."""
        return self.false_alarm / max(1, len(self.tests))

    def _tests(self, sensors: int, per_step: int) -> int:
        return max(1, self.steps) * max(1, sensors) * per_step

    def threshold(self, sensors: int) -> float:
        """The |S| above which the mean test alarms (see the module docstring)."""
        return union_threshold(self.share, self._tests(sensors, len(self.windows)))

    def drift_threshold(self, sensors: int, exact: bool = False) -> float:
        """The |S| above which a test of the drift family alarms: by the
        union bound over its steps, sensors and windows; ``exact`` (the
        residuals of an observer with no Monte Carlo error, every window
        tested whole): by the chain bound over each sensor's and window's
        steps (:func:`chain_threshold`), the union bound over those."""
        if not exact:
            return union_threshold(self.share, self._drift_tests(sensors))
        shapes = tuple(lag_one(w, True) for w in DRIFT_RAMPS) + tuple(lag_one(w, False) for w in DRIFT_MEANS)
        return chain_threshold((1.0 - DRIFT_GAPPED) * self.share, self.steps, shapes * max(1, sensors))

    def drift_gapped_threshold(self, sensors: int) -> float:
        """On an exact observer's residuals, the |S| above which a drift
        window with a sample not read alarms: the union bound over every
        step, sensor and window on :data:`DRIFT_GAPPED` of the family's
        share (the chain bound holds the rest)."""
        return union_threshold(DRIFT_GAPPED * self.share, self._drift_tests(sensors))

    def _drift_tests(self, sensors: int) -> int:
        return self._tests(sensors, len(DRIFT_RAMPS) + len(DRIFT_MEANS))

    def variance_level(self, sensors: int) -> float:
        """The probability of each tail of each variance test, each step."""
        return self.share / (2.0 * self._tests(sensors, len(VARIANCE_WINDOWS)))

    def frozen_level(self, sensors: int) -> float:
        """The probability, each step and sensor, at or below which repeated readings alarm."""
        return self.share / self._tests(sensors, 1)

    def pooled_level(self) -> float:
        """The probability of each pooled test (one per step and window: it takes every sensor at once)."""
        return self.share / self._tests(1, len(POOLED_WINDOWS))

    def matched_threshold(self, correlations: tuple[float, ...]) -> float:
        """The |S| above which a matched test alarms: the chain bound over
        each kernel's steps (``correlations``: each kernel's lag-one
        correlation), the union bound over the kernels (:func:`chain_threshold`)."""
        return chain_threshold(self.share, self.steps, correlations)


class Detector:
    """The sliding-window Z-test, one step at a time (:meth:`update`).

    The step's arithmetic is on Python floats: on a few sensors (a bond
    graph's plant has a handful) a dozen scalar operations cost less than the
    NumPy calls on arrays of four numbers that did them (13 -> 5 us on RO per
    sample; the online diagnoser's budget is a fraction of a millisecond).
    Each number is the same IEEE operation in the same order as
    :class:`DetectorBank`'s, so the two agree to the bit (tested). Only the
    cumulative sums of the last ``max(windows) + 1`` steps are kept: the
    windows and the onset's search reach no further back."""

    def __init__(self, sensors: tuple[str, ...], options: DetectorOptions = DetectorOptions(), noise=None,
                 exact: bool = False, kernels=None):
        self.sensors = sensors
        self.options = options
        # the drift, variance and frozen tests (``noise``: the sensors' noise std, which the frozen test needs;
        # ``exact``: the drift family's residuals come from an observer with no Monte Carlo error; ``kernels``:
        # the matched test's, bgc.diagnosis.matched.Kernels over these sensors)
        self.exact = exact
        self.kernels = kernels
        self.more = Families(sensors, options, noise, exact, kernels) if len(options.tests) > 1 else None
        self.threshold = options.threshold(len(sensors))
        self._windows = tuple(int(w) for w in options.windows)
        self._longest = max(self._windows)
        # cumulative sums of z and of the Monte Carlo shares a_k: the last (the newest at -1), as tuples of floats
        zero = (0.0,) * len(sensors)
        self._cumsum = deque([zero], maxlen=self._longest + 1)
        self._mc = deque([zero], maxlen=self._longest + 1)
        self.statistics: list[list[float]] = []  # max over windows of |S|, per sensor and step
        self._noise = noise

    def rearm(self) -> None:
        """Forget the residuals taken so far: every window and test starts
        again with the next step (a false alarm's excursion left behind, as
        a fresh detector would), the steps still counted from the first."""
        self._cumsum = deque([self._cumsum[-1]], maxlen=self._longest + 1)
        self._mc = deque([self._mc[-1]], maxlen=self._longest + 1)
        if self.more is not None:
            self.more = Families(self.sensors, self.options, self._noise, self.exact, self.kernels)

    def update(self, z, mc=None, y=None, spread=None, corr=None, exact=None, whitened=None) -> Detection | None:
        """Take the normalised residuals of one step (NaN: sensor not read)
        and, from a particle filter, the Monte Carlo std of its prediction in
        units of its predicted std (:func:`monte_carlo_share`; none: an exact
        prediction), the readings ``y`` themselves (the frozen test's;
        none: no frozen test this step) and ``spread``, the predicted std over
        the sensor's own noise std (the variance test's lower tail takes the
        residual in units of that noise, ``z * spread``; none: 1) and
        ``corr``, the correlation matrix of the step's residuals as the
        observer predicts them (the pooled test's; none: no pooled test over
        a window holding this step) and ``exact``, the normalised residuals
        of an observer with no Monte Carlo error beside a particle one (the
        drift family's, tested with no allowance; none: ``z`` with ``mc``'s)
        and ``whitened``, that observer's innovations whitened by the
        Cholesky factor of their predicted covariance (the matched test's;
        none, or a value not finite: no matched test over a window holding
        this step); return the alarm when this step raises one. ``z``,
        ``mc``, ``y``, ``spread``, ``exact``, ``whitened``: arrays or
        sequences of floats, one per sensor; ``corr``: sensors x sensors."""
        alarm = self._mean(z, mc)
        if self.more is None:
            return alarm
        found = self.more.update(z, mc, y, spread, corr, exact, whitened)
        if alarm is not None:
            found.insert(0, (alarm, _normal_excess(alarm.statistic, alarm.threshold)))
        if not found:
            return None
        best = min(found, key=lambda pair: pair[1])[0]  # the most significant for its level; a tie: TESTS' order
        if best.test == "mean":
            return best
        k = len(self.statistics) - 1  # the tests count their own steps: a record forgotten shifts this one's
        return dataclasses.replace(best, step=k, onset_step=best.onset_step + k - (self.more.taken - 1))

    def _mean(self, z, mc) -> Detection | None:
        """The mean test's step (the module docstring)."""
        k = len(self.statistics)  # steps taken before this one
        c, m = self._cumsum, self._mc
        c_now = _accumulate(c[-1], z)
        m_now = m[-1] if mc is None else _accumulate(m[-1], mc)
        c.append(c_now)
        m.append(m_now)
        best, at, top = -1.0, None, None
        for w in self._windows:
            if w > len(c) - 1:  # longer than the record (since the detector was armed): no test
                continue
            s = [abs(a - b) / sqrt(w + (d := p - q) * d) for a, b, p, q in zip(c_now, c[-1 - w], m_now, m[-1 - w])]
            top = s if top is None else [x if x >= y else y for x, y in zip(top, s)]
            for j, value in enumerate(s):
                if value > best:  # the largest; on a tie the shortest window, then the first sensor
                    best, at = value, (w, j)
        self.statistics.append([0.0] * len(self.sensors) if top is None else top)
        if at is None or not best > self.threshold:
            return None
        return Detection(k, self.sensors[at[1]], at[0], best, self.threshold, self._onset(k))

    def _onset(self, k: int) -> int:
        """GLR change point of a mean shift ending at step k, the last step
        taken (see the module docstring)."""
        rows = np.array(self._cumsum)  # row i: the sums over the steps before step ``first + i``
        first = k + 1 - (len(rows) - 1)
        return first + change_point(rows, k - first, self._longest)


def _accumulate(sums: tuple[float, ...], values) -> tuple[float, ...]:
    """The running sums ``sums`` plus one row of ``values`` (an array or a
    sequence of numbers), a value that is not finite counting 0."""
    row = values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]
    return tuple([a + (b if isfinite(b) else 0.0) for a, b in zip(sums, row)])


def change_point(cumsum: np.ndarray, k: int, longest: int) -> int:
    """The GLR change point of a mean shift ending at step k (module
    docstring), from the cumulative sums of the residuals (row i: over steps
    0 to i - 1), looked for over the last ``longest`` steps."""
    best, at = -1.0, k
    for t in range(max(0, k - longest + 1), k + 1):
        seg = cumsum[k + 1] - cumsum[t]
        score = float(seg @ seg) / (k - t + 1)
        if score > best:
            best, at = score, t
    return at


class DetectorBank:
    """The sliding-window Z-tests of several filters that step in lockstep
    (one hypothesis's filters from its onsets, :mod:`bgc.diagnosis.diagnose`),
    computed for all of them at once: row ``r`` is a :class:`Detector` with
    ``options[r]`` that starts at step ``starts[r]`` of a record of ``steps``
    steps (room is made as the steps come). Each row gives the same statistics and alarms as that detector
    would (the same arithmetic, element by element); one NumPy call serves all
    rows instead of one per filter, which on a few hundred particles is most
    of a filter step's cost."""

    def __init__(self, sensors: tuple[str, ...], starts, options, steps: int):
        self.sensors = sensors
        self.starts = np.asarray(starts, dtype=int)
        windows = {o.windows for o in options}
        if len(windows) != 1:
            raise ValueError("the rows of a detector bank share their windows")
        self._windows = np.array(windows.pop(), dtype=int)
        self.thresholds = np.array([o.threshold(len(sensors)) for o in options])
        # per row, cumulative sums (index k: over the steps from the row's start to k - 1) of z and of a_k
        self._cumsum = np.zeros((len(self.starts), steps + 1, len(sensors)))
        self._mc = np.zeros_like(self._cumsum)

    def update(self, k: int, rows, z: np.ndarray, mc: np.ndarray, locate=None) -> list[Detection | None]:
        """Take step ``k``'s normalised residuals ``z`` and Monte Carlo shares
        ``mc`` (rows x sensors, NaN: not read) of the rows ``rows`` (each at or
        after its start); per row, its alarm (steps counted from the row's
        start, as its own :class:`Detector` counts them) or None. ``locate``:
        per row, whether an alarm's onset is estimated (default: every row's;
        the estimate is a loop over the longest window, and a filter that
        stays off the data alarms at every step)."""
        rows = np.asarray(rows, dtype=int)
        if k + 1 >= self._cumsum.shape[1]:  # longer than announced: room for as many steps again, and more
            # (at least to step k: a row may start well after the last step taken, k jumps)
            more = max(self._cumsum.shape[1], 64, k + 2 - self._cumsum.shape[1])
            grow = np.zeros((len(self.starts), more, len(self.sensors)))
            self._cumsum = np.concatenate([self._cumsum, grow], axis=1)
            self._mc = np.concatenate([self._mc, grow], axis=1)
        c, m = self._cumsum, self._mc
        c[rows, k + 1] = c[rows, k] + np.where(np.isfinite(z), z, 0.0)
        m[rows, k + 1] = m[rows, k] + np.where(np.isfinite(mc), mc, 0.0)
        taken = k + 1 - self.starts[rows]  # steps each row has taken
        available = self._windows[None, :] <= taken[:, None]  # rows x windows
        prev = np.maximum(k + 1 - self._windows[None, :], self.starts[rows][:, None])
        spread = m[rows, k + 1][:, None, :] - m[rows[:, None], prev]
        s = np.abs(c[rows, k + 1][:, None, :] - c[rows[:, None], prev]) / np.sqrt(
            self._windows[None, :, None] + spread * spread)  # rows x windows x sensors
        s[~available] = -1.0  # windows longer than the row's record: no test
        flat = s.reshape(len(rows), -1)
        best = flat.argmax(axis=1)  # the largest; on a tie the shortest window, then the first sensor
        out: list[Detection | None] = []
        for i, r in enumerate(rows):
            value = flat[i, best[i]]
            if not value > self.thresholds[r]:
                out.append(None)
                continue
            w, j = divmod(int(best[i]), len(self.sensors))
            local = int(taken[i]) - 1
            # the row's own cumulative sums start at its start: its Detector's, step for step
            onset = (change_point(c[r, self.starts[r]:], local, int(self._windows.max()))
                     if locate is None or locate[i] else None)
            out.append(Detection(local, self.sensors[j], int(self._windows[w]), float(value),
                                 float(self.thresholds[r]), onset))
        return out


def _normal_excess(statistic: float, threshold: float) -> float:
    """How far a two-sided Z test is past its level: log(p / p at the threshold), negative past it."""
    return _log_tail(statistic) - _log_tail(threshold)


def _log_tail(z: float) -> float:
    """log P(|Z| > z), Z ~ N(0, 1) (no underflow to log 0 before z = 37)."""
    return log(max(erfc(z / sqrt(2.0)), 1e-300))


class Families:
    """The tests a :class:`Detector` runs beside the mean test when its
    options ask for them (:data:`TESTS`; module docstring, "A bank of
    tests"), one step at a time on Python floats, from running sums over
    their longest window (a bounded record, whatever the stream's length):

    - ``drift``: ramp-weighted sums over :data:`DRIFT_RAMPS` and plain sums
      over :data:`DRIFT_MEANS` of each sensor's normalised residuals;
    - ``variance``: the centred sum of squares over :data:`VARIANCE_WINDOWS`
      against both tails of its chi-square law;
    - ``frozen``: readings repeated to the data's resolution;
    - ``pooled``: the window's sum of the residual vectors, whitened by the
      sum of their predicted correlation matrices, against the chi-square
      law (:data:`POOLED_WINDOWS`).

    :meth:`update` returns the alarms of the step, each with how far it is
    past its level (the log of its p-value over the level's). Every ring of
    running sums starts with two rows of zeros (the sums before the first
    step, and before that), so that a window is tested from the step it
    fits in."""

    def __init__(self, sensors: tuple[str, ...], options: DetectorOptions, noise=None, exact: bool = False,
                 kernels=None):
        unknown = [t for t in options.tests if t not in TESTS]
        if unknown or "mean" not in options.tests:
            raise ValueError(f"detector tests {options.tests!r}: the mean test and some of {TESTS[1:]!r}")
        n = len(sensors)
        self.sensors = sensors
        self.drift = "drift" in options.tests
        self.variance = "variance" in options.tests
        self.noise = None if noise is None else tuple(float(v) for v in np.asarray(noise, dtype=float).reshape(n))
        self.frozen = "frozen" in options.tests and noise is not None
        self.pooled = "pooled" in options.tests
        longest = max(((*DRIFT_RAMPS, *DRIFT_MEANS) if self.drift else ())
                      + (VARIANCE_WINDOWS if self.variance else ()) + (POOLED_WINDOWS if self.pooled else ()) + (1,))
        zero = (0.0,) * n
        # running sums (the newest last) of z, of a_k, of z^2, of the readings taken, of the residual in units of
        # the sensor's own noise, e = (y - mean) / r, and of e^2 (the lower tail's); and the drift family's: of
        # its residuals (z, or an exact observer's: ``update``'s ``exact``), of those sums, of their Monte Carlo
        # shares (none for an exact observer's) and of theirs, and of its readings taken
        self._c, self._a, self._sq, self._n, self._e, self._ee, self._g, self._gg, self._b, self._bb, self._gn = (
            deque([zero, zero], maxlen=longest + 2) for _ in range(11))
        # the pooled test's running sums, one array per step: of z, of a_k, of the predicted correlation
        # matrices (flattened, row by row; a sensor not read: its row and column 0; a step whose correlation
        # was not given: 0) and, last, of the steps whose correlation was not given
        self._p = deque([np.zeros(2 * n + n * n + 1)] * 2, maxlen=longest + 2)
        self.taken = 0
        # per sensor, what its readings tell (when given): the last one, the step its run of repeats began, the
        # run's length, the longest run that ended before, and the smallest change seen per decimal exponent
        self._last = [float("nan")] * n
        self._since = [-1] * n
        self._run = [0] * n
        self._longest = [0] * n
        self._steps: list[dict] = [{} for _ in range(n)]
        # the drift family's residuals are an exact observer's (a Kalman filter's): tested by the chain bound,
        # a window only when every sample of it was read (module docstring, "A bank of tests")
        self.exact = exact
        if self.drift:
            self.drift_threshold = options.drift_threshold(n, exact)
            self.drift_gapped = options.drift_gapped_threshold(n) if exact else self.drift_threshold
        if self.variance:
            level = options.variance_level(n)
            df = np.arange(1, max(VARIANCE_WINDOWS))
            # per degrees of freedom (index df - 1): the bounds of the centred sum of squares
            self._low = tuple(chi2_ppf(level, df).tolist())
            self._high = tuple(chi2_isf(level, df).tolist())
            self._level = level
        if self.frozen:
            self._log_frozen = log(options.frozen_level(n))
        if self.pooled:
            self._pooled_level = options.pooled_level()
            self._pooled_high: dict[int, float] = {}  # per degrees of freedom: the chi-square's upper quantile
        self._matched_setup(kernels if "matched" in options.tests else None, options, n)

    def _matched_setup(self, kernels, options: DetectorOptions, n: int) -> None:
        """The matched test (``kernels``: bgc.diagnosis.matched.Kernels over
        the ``n`` sensors; none: not run): the whitened innovations of the
        last L steps, each row written twice in a ring of 2 L rows so that
        the L rows up to the newest are always one slice, and how many steps
        in a row were read whole."""
        self.kernels = kernels
        if kernels is None:
            return
        if kernels.K.shape[2] != n:
            raise ValueError(f"matched kernels over {kernels.K.shape[2]} sensors for a detector of {n}")
        L = kernels.longest
        self._w = np.zeros((2 * L, n))
        self._at = 0  # the ring's next row
        self._whole = 0
        self._flat = kernels.K.reshape(len(kernels.K), -1)
        self._matched_threshold = options.matched_threshold(kernels.rho)

    def bounds(self, df: int) -> tuple[float, float]:
        """The variance test's bounds on the centred sum of squares of a
        window with ``df + 1`` residuals: its chi-square law's quantiles at
        the test's level, each tail."""
        return self._low[df - 1], self._high[df - 1]

    def resolution(self, j: int, value: float) -> float | None:
        """The bound on sensor j's resolution near ``value``: the smallest
        change seen between two of its readings of that decimal exponent (a
        logger writing significant digits has a coarser step for larger
        values), or of the nearest larger one seen; None: none seen yet."""
        steps, key = self._steps[j], _exponent(value)
        if key in steps:
            return steps[key]
        larger = [k for k in steps if k is not None and (key is None or k > key)]
        return steps[min(larger)] if larger else None

    # -- the state as plain data ---------------------------------------------------------------------------

    def _rings(self) -> tuple:
        return self._c, self._a, self._sq, self._n, self._e, self._ee, self._g, self._gg, self._b, self._bb, self._gn

    def state(self) -> tuple:
        """Everything :meth:`update` carries from step to step, as plain tuples, lists and dicts."""
        rings = tuple(tuple(d) for d in self._rings()) + (tuple(tuple(row.tolist()) for row in self._p),)
        readings = (tuple(self._last), tuple(self._since), tuple(self._run), tuple(self._longest),
                    tuple(dict(s) for s in self._steps))
        matched = () if self.kernels is None else (self._recent().tolist(), self._whole)
        return rings, self.taken, readings, matched

    def restore(self, state: tuple) -> None:
        """Put the tests in ``state`` (:meth:`state`)."""
        rings, taken, readings, matched = state
        if len(rings) != len(self._rings()) + 1 or len(readings) != 5 or bool(matched) != (self.kernels is not None):
            raise ValueError("a detector state of another shape")
        if matched:
            recent, whole = matched
            L = self.kernels.longest
            self._w[:L] = self._w[L:] = np.asarray(recent, dtype=float).reshape(L, -1)
            self._at, self._whole = 0, int(whole)
        self.taken = int(taken)
        for d, rows in zip(self._rings(), rings):
            d.clear()
            d.extend(tuple(float(v) for v in row) for row in rows)
        self._p.clear()
        self._p.extend(np.array(row, dtype=float) for row in rings[-1])
        last, since, run, longest, steps = readings
        self._last, self._since = [float(v) for v in last], [int(v) for v in since]
        self._run, self._longest = [int(v) for v in run], [int(v) for v in longest]
        self._steps = [dict(s) for s in steps]

    # -- one step --------------------------------------------------------------------------------------------

    def update(self, z, mc=None, y=None, spread=None, corr=None, exact=None,
               whitened=None) -> list[tuple[Detection, float]]:
        """Take one step (:meth:`Detector.update`'s arguments); the alarms it
        raises (steps counted by the caller), each with its excess."""
        row = z.tolist() if isinstance(z, np.ndarray) else [float(v) for v in z]
        zs = [v if isfinite(v) else 0.0 for v in row]
        c_now = tuple(a + b for a, b in zip(self._c[-1], zs))
        self._c.append(c_now)
        if mc is None:
            a_now = self._a[-1]
        else:
            a_row = mc.tolist() if isinstance(mc, np.ndarray) else [float(v) for v in mc]
            a_now = tuple(a + (b if isfinite(b) else 0.0) for a, b in zip(self._a[-1], a_row))
        self._a.append(a_now)
        if self.drift:  # the rings only a family that is on reads
            if self.exact and exact is None and mc is not None and any(v != 0.0 for v in a_row if isfinite(v)):
                raise ValueError("a detector told its drift residuals are exact was given Monte Carlo shares and "
                                 "no exact residuals")
            self._drift_sums(row, c_now, a_now, exact)
        if self.variance:
            if spread is None:
                es = zs
            else:
                ratio = spread.tolist() if isinstance(spread, np.ndarray) else [float(v) for v in spread]
                es = [v * (q if isfinite(q) else 1.0) for v, q in zip(zs, ratio)]
            self._sq.append(tuple(a + b * b for a, b in zip(self._sq[-1], zs)))
            self._n.append(tuple(a + (1.0 if isfinite(b) else 0.0) for a, b in zip(self._n[-1], row)))
            self._e.append(tuple(a + b for a, b in zip(self._e[-1], es)))
            self._ee.append(tuple(a + b * b for a, b in zip(self._ee[-1], es)))
        if self.pooled:
            n = len(row)
            values = np.asarray(row, dtype=float)
            seen = np.isfinite(values)
            given = corr is not None and bool(np.isfinite(corr).all())
            block = (np.where(seen[:, None] & seen[None, :], np.asarray(corr, dtype=float).reshape(n, n), 0.0)
                     if given else np.zeros((n, n)))
            share = np.zeros(n) if mc is None else np.asarray(mc, dtype=float)
            self._p.append(self._p[-1] + np.concatenate([np.where(seen, values, 0.0),
                                                         np.where(np.isfinite(share), share, 0.0),
                                                         block.ravel(), [0.0 if given else 1.0]]))
        if self.kernels is not None:
            self._take_whitened(whitened, len(row))
        self.taken += 1
        readings = None if y is None else (y.tolist() if isinstance(y, np.ndarray) else [float(v) for v in y])
        if readings is not None and (self.variance or self.frozen):  # the lower tail's resolution, the repeats
            self._read(readings)
        found: list[tuple[Detection, float]] = []
        if self.drift:
            found += self._drift()
        if self.variance:
            found += self._variances(readings)
        if self.frozen and readings is not None:
            found += self._frozen(readings)
        if self.pooled:
            found += self._pool()
        if self.kernels is not None:
            found += self._matched()
        return found

    def _take_whitened(self, whitened, n: int) -> None:
        """The matched test's step: the whitened innovations into the ring (a
        step not read whole: zeros, and no window holding it is tested)."""
        values = np.full(n, np.nan) if whitened is None else np.asarray(whitened, dtype=float).reshape(n)
        whole = bool(np.isfinite(values).all())
        row = values if whole else np.zeros(n)
        L = self.kernels.longest
        self._w[self._at] = self._w[self._at + L] = row
        self._at = (self._at + 1) % L
        self._whole = self._whole + 1 if whole else 0

    def _recent(self) -> np.ndarray:
        """The whitened innovations of the last L steps (L, n), the newest last."""
        L = self.kernels.longest
        return self._w[self._at:self._at + L]

    def _matched(self) -> list[tuple[Detection, float]]:
        """Every matched kernel over the windows read whole: |S| against the
        family's threshold (module docstring, "A bank of tests")."""
        kernels = self.kernels
        fits = kernels.window <= self._whole
        if not fits.any():
            return []
        recent = self._recent()
        values = np.abs(self._flat @ recent.ravel())  # every kernel (no copy of the kernels), then the fitting
        values[~fits] = 0.0
        index = int(np.argmax(values))
        value, threshold = float(values[index]), self._matched_threshold
        if not value > threshold:
            return []
        w = int(kernels.window[index])
        j = kernels.sensor(index)  # the sensor its fault model moves most (a whitened component mixes them)
        onset = self._matched_onset(recent)
        return [(Detection(0, self.sensors[j], w, value, threshold, onset, "matched"),
                 _normal_excess(value, threshold))]

    def _matched_onset(self, recent: np.ndarray) -> int:
        """The GLR change point of a fault model's response of unknown size,
        the model unknown too: argmax over the onsets t the steps read whole
        reach and the fault models f of (sum_m g_f(m)' e_(t+m))^2 / sum_m
        |g_f(m)|^2 (a window's kernel that alarmed can be another model's
        than the one that fits from the true onset)."""
        g = self.kernels.g  # (faults, L, n)
        L = g.shape[1]
        energy = np.cumsum((g * g).sum(axis=2), axis=1)  # (faults, L): over the first m samples at m - 1
        best, at = -1.0, self.taken - 1
        for m in range(1, min(L, self._whole) + 1):  # (the steps read whole are at most the steps taken)
            dot = np.einsum("fmj,mj->f", g[:, :m], recent[L - m:])
            norm = energy[:, m - 1]
            live = norm > 0.0
            if not live.any():
                continue
            score = float(np.max(dot[live] ** 2 / norm[live]))
            if score > best:
                best, at = score, self.taken - m
        return at

    def _drift_sums(self, row: list[float], c_now: tuple, a_now: tuple, exact) -> None:
        """The drift family's running sums after a step: of ``z`` (``row``;
        its sums ``c_now`` and its shares' ``a_now``), or of an exact
        observer's residuals ``exact`` with no Monte Carlo share."""
        if exact is None:
            g_now, b_now, series = c_now, a_now, row
        else:
            series = exact.tolist() if isinstance(exact, np.ndarray) else [float(v) for v in exact]
            g_now = tuple(a + (b if isfinite(b) else 0.0) for a, b in zip(self._g[-1], series))
            b_now = self._b[-1]
        self._gn.append(tuple(a + (1.0 if isfinite(b) else 0.0) for a, b in zip(self._gn[-1], series)))
        self._g.append(g_now)
        self._b.append(b_now)
        self._gg.append(tuple(a + b for a, b in zip(self._gg[-1], g_now)))
        self._bb.append(tuple(a + b for a, b in zip(self._bb[-1], b_now)))

    def _read(self, readings: list[float]) -> None:
        """Each sensor's reading: its run of repeats and the changes it shows."""
        for j, v in enumerate(readings):
            if not isfinite(v):
                continue
            last = self._last[j]
            if v == last:
                if not self._run[j]:
                    self._since[j] = self.taken - 1  # this step: the first reading that repeats
                self._run[j] += 1
            else:
                if isfinite(last):
                    key = _exponent(max(abs(v), abs(last)))
                    change = abs(v - last)
                    steps = self._steps[j]
                    if change < steps.get(key, math.inf):
                        steps[key] = change
                self._longest[j] = max(self._longest[j], self._run[j])
                self._run[j] = 0
            self._last[j] = v

    def _drift(self) -> list[tuple[Detection, float]]:
        """Every drift window's statistic against its threshold: the
        family's one on a particle observer's residuals; on an exact
        observer's, the chain bound's for a window read whole and the
        gapped windows' own for one with a sample not read (its terms 0)."""
        c, cc, a, aa = self._g, self._gg, self._b, self._bb
        best, at = 0.0, None
        for w in DRIFT_RAMPS:  # sum_i i z_(k-w+i), i = 1..w: w C_k - (D_k-1 - D_k-1-w)
            if w > self.taken:
                continue
            norm = w * (w + 1) * (2 * w + 1) / 6.0
            for j in range(len(self.sensors)):
                ramp = w * c[-1][j] - (cc[-2][j] - cc[-2 - w][j])
                spread = w * a[-1][j] - (aa[-2][j] - aa[-2 - w][j])
                value, threshold = abs(ramp) / sqrt(norm + spread * spread), self._drift_level(j, w)
                if value > threshold:
                    excess = _normal_excess(value, threshold)
                    if at is None or excess < best:
                        best, at = excess, (w, j, "ramp", value, threshold)
        for w in DRIFT_MEANS:
            if w > self.taken:
                continue
            for j in range(len(self.sensors)):
                spread = a[-1][j] - a[-1 - w][j]
                value, threshold = abs(c[-1][j] - c[-1 - w][j]) / sqrt(w + spread * spread), self._drift_level(j, w)
                if value > threshold:
                    excess = _normal_excess(value, threshold)
                    if at is None or excess < best:
                        best, at = excess, (w, j, "mean", value, threshold)
        if at is None:
            return []
        w, j, shape, value, threshold = at
        onset = self._ramp_onset() if shape == "ramp" else self._mean_onset(self._g, max(DRIFT_MEANS))
        return [(Detection(0, self.sensors[j], w, value, threshold, onset, "drift"), best)]

    def _drift_level(self, j: int, w: int) -> float:
        """The threshold of sensor j's drift window of the last ``w`` steps:
        on a particle observer's residuals the family's (a sample not read
        adds 0, and the union bound holds whatever the windows' laws); on
        an exact observer's, the chain bound's when every sample of it was
        read (it is then the value the whole series of residuals takes
        there, the series the bound is for), else the gapped windows' (the
        union bound over every window, on a small part of the share:
        ``DetectorOptions.drift_gapped_threshold``)."""
        if not self.exact or self._gn[-1][j] - self._gn[-1 - w][j] >= w - 0.5:
            return self.drift_threshold
        return self.drift_gapped

    def _variances(self, readings: list[float] | None) -> list[tuple[Detection, float]]:
        """Each window's centred sum of squares against its chi-square law:
        the upper tail on z (the residual in units of its predicted std),
        its bound widened by the window's largest Monte Carlo share; the
        lower on e (in units of the sensor's own noise: a prediction too
        unsure of itself, a filter's start, gives z too little variance, and
        never e, whose noise alone makes it at least chi-square), on sensors
        whose readings are fine against their noise (a resolution of at
        most a quarter of it: coarser readings repeat by themselves)."""
        n = self._n
        worst, at = 0.0, None
        for w in VARIANCE_WINDOWS:
            if w > self.taken:
                continue
            for j in range(len(self.sensors)):
                count = int(round(n[-1][j] - n[-1 - w][j]))
                if count < 2:
                    continue
                low, high = self.bounds(count - 1)
                q = self._centred(self._c, self._sq, j, w, count)
                if q > high:
                    share = max(self._a[-1 - i][j] - self._a[-2 - i][j] for i in range(w))
                    widen, fell = 1.0 + share * share, False  # the window's largest Monte Carlo share
                    if q <= high * widen:
                        continue
                else:
                    if not self._fine(j, readings):
                        continue
                    q = self._centred(self._e, self._ee, j, w, count)
                    if q >= low:
                        continue
                    widen, fell = 1.0, True
                bound = (low if fell else high) * widen
                excess = self._chi2_excess(q / widen, count - 1)
                if excess < worst:
                    worst, at = excess, (w, j, q / (count - 1), bound / (count - 1), fell)
        if at is None:
            return []
        w, j, ratio, bound, fell = at
        onset = self._variance_onset(*((self._e, self._ee) if fell else (self._c, self._sq)))
        return [(Detection(0, self.sensors[j], w, ratio, bound, onset, "variance"), worst)]

    def _fine(self, j: int, readings: list[float] | None) -> bool:
        """Whether sensor j's readings are fine enough for the lower tail (no readings given: taken so)."""
        if readings is None or self.noise is None:
            return True
        v = readings[j]
        q = self.resolution(j, v) if isfinite(v) else None
        return q is not None and q <= 0.25 * self.noise[j]

    @staticmethod
    def _centred(sums: deque, squares: deque, j: int, w: int, count: int) -> float:
        """The centred sum of squares of sensor j's last ``w`` steps (``count`` read) from running sums."""
        s1 = sums[-1][j] - sums[-1 - w][j]
        return max(squares[-1][j] - squares[-1 - w][j] - s1 * s1 / count, 0.0)

    def _chi2_excess(self, q: float, df: int) -> float:
        tail = min(chi2_logcdf(q, df), chi2_logsf(q, df))
        return tail - log(self._level)

    def _frozen(self, readings: list[float]) -> list[tuple[Detection, float]]:
        """A sensor whose reading repeats beyond chance: P(a reading falls in
        its last one's bin of width q | the past) <= q / (sqrt(2 pi) r), and
        longer than twice any run of repeats the data showed before (a logger
        that writes a reading twice, or a historian's compression, repeats
        by habit)."""
        worst, at = 0.0, None
        for j, v in enumerate(readings):
            run = self._run[j]
            if not run or not isfinite(v):
                continue
            q = self.resolution(j, v)
            if q is None:
                continue
            chance = q / (sqrt(2.0 * pi) * self.noise[j])
            if chance >= 1.0:
                continue
            needed = max(int(math.ceil(self._log_frozen / log(chance) - 1e-12)), 2 * self._longest[j] + 1)
            if run < needed:
                continue
            excess = min(run * log(chance) - self._log_frozen, 0.0)
            if at is None or excess < worst:
                worst, at = excess, (j, run, needed)
        if at is None:
            return []
        j, run, needed = at
        return [(Detection(0, self.sensors[j], run + 1, float(run), float(needed), self._since[j], "frozen"),
                 worst)]

    def _scores(self, widths) -> list:
        """Per window of the last ``w`` steps, ``w`` in ``widths``: (w, s' M^-1 s
        or None where M is singular, s, M, keep), ``s`` the residuals' sum
        over the sensors read in it (``keep``, their indices), ``M`` the bound
        on its covariance (the sum of the predicted correlation matrices,
        plus ``df diag(A^2)`` for the particle filter's Monte Carlo error,
        ``A`` the window's sum of shares per sensor, ``df`` the sensors read);
        a window with a step whose correlation was not given, or with no
        sensor read, is left out. The windows
        that take every sensor (the usual case) in one array operation each
        step of the way."""
        n = len(self.sensors)
        d = self._p[-1][None, :] - np.stack([self._p[-1 - w] for w in widths])  # windows x (2n + n^2 + 1)
        s, a, r = d[:, :n], d[:, n:2 * n], d[:, 2 * n:-1].reshape(-1, n, n)
        diagonal = np.arange(n)
        finite = (d[:, -1] == 0.0) & np.isfinite(r).all(axis=(1, 2))  # every step's correlation given
        every = finite & (r[:, diagonal, diagonal] > 0.0).all(axis=1)
        out = []
        if every.any():
            M = r[every]
            M[:, diagonal, diagonal] += n * a[every] ** 2
            S = s[every]
            for (i, w), t in zip(((i, w) for i, w in enumerate(widths) if every[i]), _whitened(S, M)):
                out.append((w, t, S[len(out)], M[len(out)], diagonal))
        for i, w in enumerate(widths):  # a window with a sensor not read in it
            if every[i] or not finite[i]:
                continue
            keep = np.flatnonzero(np.diagonal(r[i]) > 0.0)
            if not len(keep):
                continue
            M = r[i][np.ix_(keep, keep)]
            M[np.diag_indices_from(M)] += len(keep) * a[i, keep] ** 2
            out.append((w, _whitened(s[i, keep][None], M[None])[0], s[i, keep], M, keep))
        return out

    def _pool(self) -> list[tuple[Detection, float]]:
        """The pooled test: over each window of :data:`POOLED_WINDOWS`, the
        sum ``s`` of the residual vectors against its covariance bound ``M``
        (:meth:`_scores`): ``s' M^-1 s`` is at most chi-square with as many
        degrees of freedom as sensors read (module docstring). The alarm
        names the sensor whose own share ``s_j^2 / M_jj`` is the largest."""
        widths = [w for w in POOLED_WINDOWS if w <= self.taken]
        worst, at = 0.0, None
        for w, t, s, M, keep in (self._scores(widths) if widths else ()):
            df = len(keep)
            high = self._pooled_high.get(df)
            if high is None:
                high = self._pooled_high[df] = float(chi2_isf(self._pooled_level, df))
            if t is None or not t > high:
                continue
            excess = chi2_logsf(t, df) - log(self._pooled_level)
            if at is None or excess < worst:
                j = int(keep[np.argmax(s * s / np.diagonal(M))])
                worst, at = excess, (w, j, t, high)
        if at is None:
            return []
        w, j, t, high = at
        return [(Detection(0, self.sensors[j], w, t, high, self._pooled_onset(), "pooled"), worst)]

    # -- the onsets ------------------------------------------------------------------------------------------

    def _local(self, rows: deque) -> tuple[np.ndarray, int]:
        """The ring ``rows`` as an array, and the step its first row ends (-1: before the first)."""
        array = np.array(rows)
        return array, self.taken - len(array)

    def _mean_onset(self, sums: deque, longest: int) -> int:
        cumsum, first = self._local(sums)
        return max(first + 1 + change_point(cumsum, len(cumsum) - 2, min(longest, self.taken)), 0)

    def _ramp_onset(self) -> int:
        """The GLR change point of a ramp from an unknown step, every sensor's
        residuals: argmax_t sum_j R_j(t)^2 / sum_i i^2, R_j(t) = sum_i i z_(t-1+i)."""
        c, _ = self._local(self._g)
        cc, _ = self._local(self._gg)
        last = len(c) - 1
        best, at = -1.0, self.taken - 1
        for n in range(1, min(max(DRIFT_RAMPS), last - 1, self.taken) + 1):
            ramp = n * c[last] - (cc[last - 1] - cc[last - 1 - n])
            score = float(ramp @ ramp) / (n * (n + 1) * (2 * n + 1) / 6.0)
            if score > best:
                best, at = score, self.taken - n
        return at

    def _variance_onset(self, sums: deque, squares: deque) -> int:
        """The GLR change point of the residuals' mean and variance together:
        argmax_t sum_j m (v + mu^2 - 1 - log v) = sum_j (S2 - m - m log v),
        ``mu`` and ``v`` the mean and mean square about it (maximum likelihood)
        of the m samples from t, ``S2`` their sum of squares (of the residuals
        whose running sums are ``sums`` and ``squares``). Without ``mu^2``, a
        step in the mean (a bias, a stuck sensor: the variance test can see
        these first) raises ``v`` of every span that straddles it, and the
        longest such span wins: the onset falls a window early."""
        c, _ = self._local(sums)
        sq, _ = self._local(squares)
        n, _ = self._local(self._n)
        last = len(c) - 1
        best, at = -1.0, self.taken - 1
        for m in range(2, min(max(VARIANCE_WINDOWS), last, self.taken) + 1):
            count = n[last] - n[last - m]
            s1 = c[last] - c[last - m]
            s2 = sq[last] - sq[last - m]
            v = np.maximum(s2 - np.where(count > 0, s1 * s1 / np.maximum(count, 1), 0.0), 0.0) / np.maximum(count, 1)
            v = np.maximum(v, 1e-12)
            score = float(np.sum(np.where(count >= 2, s2 - count - count * np.log(v), 0.0)))
            if score > best:
                best, at = score, self.taken - m
        return at


    def _pooled_onset(self) -> int:
        """The GLR change point of a mean shift of unknown size and
        direction in the residual vector: argmax_t s_t' M_t^-1 s_t, ``s_t``
        the sum of the residual vectors from step t on and ``M_t`` its
        covariance bound (:meth:`_scores`), over the longest pooled window."""
        widths = list(range(1, min(max(POOLED_WINDOWS), len(self._p) - 2, self.taken) + 1))
        best, at = -1.0, self.taken - 1
        for m, score, *_ in sorted(self._scores(widths), key=lambda found: found[0]):
            if score is not None and score > best:
                best, at = score, self.taken - m
        return at


def _whitened(S: np.ndarray, M: np.ndarray) -> list:
    """s' M^-1 s of each row s of ``S`` (k, n) and matrix of ``M`` (k, n, n)
    in one batched solve; None where M is singular (a correlation matrix
    that rounding made so, or a window of one sensor exactly the sum of
    others)."""
    try:
        v = np.linalg.solve(M, S[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        out = []
        for s, m in zip(S, M):
            try:
                out.append(float(s @ np.linalg.solve(m, s)))
            except np.linalg.LinAlgError:
                out.append(None)
        return out
    return np.einsum("ij,ij->i", S, v).tolist()


def _exponent(value: float) -> int | None:
    """The decimal exponent of ``value`` (None for 0): readings of one exponent share a resolution."""
    return None if value == 0.0 else math.floor(math.log10(abs(value)))
