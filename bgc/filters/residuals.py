"""The normalised residuals of a nominal filter, tested: are they the white
N(0, 1) draws they are when the model fits the plant?

Per sensor, over the samples read: their mean (0 when the model fits; its
standard error sqrt(tau / n), ``tau`` their integrated autocorrelation time,
1 for white residuals and never taken below it: :func:`correlation_time`),
their variance (1; a chi-square over n - 1 degrees of freedom, tested by its
exact tail: :func:`variance_z`) and the Ljung-Box
portmanteau statistic (Ljung and Box 1978) over ``lags`` lags, chi-square
with ``lags`` degrees of freedom when they are white. ``bgc calibrate``
reports them for the calibrated model (:mod:`bgc.analysis.calibrate`), and
the diagnosis for the model as written over the data before a fault
(:mod:`bgc.diagnosis.fit`): both say what fails in the same sentences
(:func:`findings`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Mapping, Sequence

import numpy as np


@dataclass(frozen=True, slots=True)
class Innovations:
    """A sensor's normalised residuals under the calibrated model over every
    recording: ``samples`` read, their ``mean`` and ``variance`` (0 and 1
    when the model fits), the Ljung-Box statistic ``ljung_box`` over
    ``lags`` lags and its p-value (small: the residuals are correlated, the
    model misses a dynamic); ``variance_but_one``: their variance without
    the one farthest from their mean (a glitch of one reading raises the
    variance; a model whose noise is too small raises both);
    ``correlation_time``: their integrated autocorrelation time
    (:func:`correlation_time`), by which the variance of their mean exceeds
    1 / n."""

    sensor: str
    samples: int
    mean: float
    variance: float
    ljung_box: float
    lags: int
    p_value: float
    variance_but_one: float = math.nan
    correlation_time: float = 1.0


def autocorrelations(z: Sequence[np.ndarray], lags: int) -> tuple[np.ndarray, int]:
    """The sample autocorrelation r_k = sum (z_t - m)(z_t+k - m) / sum (z_t
    - m)^2 at lags 1 .. ``lags`` of the residual series ``z`` (one per
    recording, NaN: not read; pairs are taken within a recording, both read;
    ``m`` the mean of every sample read), and ``n`` the samples read: (r, n)
    (r NaN when fewer than 3)."""
    parts = [np.asarray(a, dtype=float) for a in z]
    values = np.concatenate([a[np.isfinite(a)] for a in parts]) if parts else np.zeros(0)
    n = len(values)
    if n < 3:
        return np.full(lags, math.nan), n
    mean = float(values.mean())
    denom = float(((values - mean) ** 2).sum())
    r = np.zeros(lags)
    for k in range(1, lags + 1):
        s = 0.0
        for a in parts:
            if len(a) > k:
                prod = (a[:-k] - mean) * (a[k:] - mean)
                s += float(prod[np.isfinite(prod)].sum())
        r[k - 1] = s / denom if denom > 0 else 0.0
    return r, n


def ljung_box(z: Sequence[np.ndarray], lags: int) -> tuple[float, int]:
    """The Ljung-Box statistic Q = n (n + 2) sum_k r_k^2 / (n - k) over lags
    1 .. ``lags`` of the residual series ``z`` (:func:`autocorrelations`),
    with n the samples read: (Q, n)."""
    r, n = autocorrelations(z, lags)
    if n < 3:
        return math.nan, n
    return n * (n + 2) * float(sum(r[k - 1] ** 2 / (n - k) for k in range(1, lags + 1))), n


#: :func:`correlation_time`'s window: its sum of autocorrelations stops at the first lag at least this many
#: times the time summed so far (Sokal's rule), and at :data:`LONGEST_LAG` or a tenth of the samples.
SOKAL = 5
LONGEST_LAG = 50


def correlation_time(z: Sequence[np.ndarray]) -> float:
    """The integrated autocorrelation time of the residual series ``z`` (one
    per recording, NaN: not read), over each recording's readings in the
    order read (a sensor read every tenth step: its successive readings,
    whose correlation is what widens their mean), each recording's straight
    line through them taken off (a slow change of the mean, a drift the
    model misses, is what the mean test looks for, not noise that widens
    its standard error: left in, it would read as a long correlation and
    hide itself), tau = 1 + 2 sum_(k=1..M) r_k, the window M the first lag
    at least :data:`SOKAL` times tau so far (Sokal's rule; at most :data:`LONGEST_LAG` lags or a
    tenth of the samples): the factor by which the variance of their mean
    exceeds 1 / n. White residuals have 1; a filter whose first, heavily
    weighted samples over-correct (a plant that starts nearer the model's
    initial state than its spread says), or a calibrated model a little
    off, leaves residuals correlated over a few steps, their mean scattered
    wider than 1 / sqrt(n). (1 for fewer than 10 samples: no lag is tried.)

    >>> round(correlation_time([np.array([1.0, -1.0] * 50)]), 6)  # alternating: its mean cancels at once
    -0.98
    """
    parts = [_detrended(a[np.isfinite(a)]) for a in (np.asarray(b, dtype=float) for b in z)]  # each one's readings
    n = sum(len(a) for a in parts)
    lags = min(LONGEST_LAG, n // 10)
    if lags < 1:
        return 1.0
    r, _ = autocorrelations(parts, lags)
    tau = 1.0
    for k in range(1, lags + 1):
        tau += 2.0 * float(r[k - 1])
        if k >= SOKAL * tau:
            break
    return tau


def lag_one_time(z: np.ndarray) -> float:
    """The correlation time of an AR(1) process with the lag-1
    autocorrelation ``r`` of the residuals ``z`` (one series, NaN: not
    read; their straight line taken off, as :func:`correlation_time` takes
    it), (1 + r) / (1 - r), ``r`` clipped to [0, 0.99]; 1 for fewer than 10
    readings. A floor for :func:`correlation_time`, whose sum over many lags
    scatters widely on a few hundred samples, where ``r`` alone does not.

    >>> round(lag_one_time(np.array([1.0, 1.0, 1.0, -1.0, -1.0, -1.0] * 20)), 2)  # r about 1/3: (4/3)/(2/3)
    2.04
    >>> lag_one_time(np.array([1.0, -1.0] * 50))  # alternating: r < 0, clipped to 0
    1.0
    """
    read = np.asarray(z, dtype=float)
    read = read[np.isfinite(read)]
    if len(read) < 10:
        return 1.0
    r = float(autocorrelations([_detrended(read)], 1)[0][0])
    r = min(max(r, 0.0), 0.99) if math.isfinite(r) else 0.0
    return (1.0 + r) / (1.0 - r)


def _detrended(x: np.ndarray) -> np.ndarray:
    """``x`` less its least-squares straight line over its positions (less
    its mean when it has fewer than 3 values)."""
    if len(x) < 3:
        return x - x.mean() if len(x) else x
    t = np.arange(len(x), dtype=float) - (len(x) - 1) / 2.0
    return x - x.mean() - t * float(t @ x) / float(t @ t)


def innovations(filters: Sequence, outputs: Sequence[str]) -> tuple[Innovations, ...]:
    """Per sensor read, the summary of the normalised residuals of the
    nominal Kalman filters ``filters`` (:class:`~bgc.filters.cubature.NominalKalman`,
    one per recording) (:func:`summary`)."""
    return summary([np.array(kf.z, dtype=float).reshape(len(kf.z), len(outputs)) for kf in filters], outputs)


def summary(zs: Sequence[np.ndarray], outputs: Sequence[str]) -> tuple[Innovations, ...]:
    """Per sensor read, the summary of its normalised residuals ``zs`` (one
    array of steps x ``outputs`` per recording; NaN: not read): an
    :class:`Innovations` (none for a sensor read fewer than 3 times)."""
    from scipy.special import chdtrc  # chi-square's survival function (scipy.stats costs a second to import)

    out = []
    for j, name in enumerate(outputs):
        series = [z[:, j] for z in zs]
        read = np.concatenate([s[np.isfinite(s)] for s in series])
        if len(read) < 3:
            continue
        lags = int(max(1, min(20, len(read) // 5)))
        q, n = ljung_box(series, lags)
        rest = np.delete(read, int(np.argmax(np.abs(read - read.mean()))))
        out.append(Innovations(name, n, float(read.mean()), float(read.var()), float(q), lags,
                               float(chdtrc(lags, q)), float(rest.var()), correlation_time(series)))
    return tuple(out)


@functools.lru_cache(maxsize=256)
def largest_square(n: int) -> float:
    """The expected largest of ``n`` squared independent N(0, 1) draws,
    the integral of 1 - F(x)^n over x >= 0 (F: chi-square's with one degree
    of freedom): about 2 ln n - ln ln n for large ``n``."""
    from scipy.integrate import quad
    from scipy.special import erfc

    def above(x: float) -> float:
        return -math.expm1(n * math.log1p(-float(erfc(math.sqrt(x / 2))))) if x > 0 else 1.0

    peak = 2 * math.log(max(n, 2))
    return float(quad(above, 0, peak)[0] + quad(above, peak, math.inf)[0])


#: Gauss-Hermite nodes and weights (probabilists', normalised) over which :func:`variance_z` averages the
#: chi-square's tail across a calibrated model's log-normal error of its variance.
_HERMITE = 40


@functools.lru_cache(maxsize=1)
def _hermite() -> tuple[np.ndarray, np.ndarray]:
    nodes, weights = np.polynomial.hermite_e.hermegauss(_HERMITE)
    return nodes, weights / weights.sum()


def variance_z(variance: float, dof: int, sd: float = 0.0, expected: float = 1.0) -> float:
    """How far ``variance``, the mean of ``dof`` squared N(0, ``expected``)
    draws when the model fits (a chi-square over its degrees of freedom),
    lies from ``expected``, in standard normal units: the normal quantile
    of its exact tail probability, above (positive) or below (negative).
    The variance's own scale, (variance - expected) / sqrt(2 / dof), leaves
    the chi-square's skew in: at 300 samples and 3.76 standard errors it
    rejects a fitting model's variance above 1 2.8 times as often as the
    normal tail says and below 1 a fifth as often (at 45 samples, 7 times
    and almost never). ``sd``: the standard deviation of the expectation's
    own error, relative (a calibrated model's residual variance,
    :func:`failures`): its estimates are normal in the noises' logs (the
    likelihood's curvature is taken there), so the factor they leave on
    the variance is log-normal, of log-std ``sd``; the tail is averaged
    over it (Gauss-Hermite, :data:`_HERMITE` nodes; adaptive quadrature
    with a breakpoint at the tail's step where the chi-square is the
    narrower, sd sqrt(dof / 2) above 1/2, a long record of a calibrated
    model).

    >>> round(variance_z(1.0, 10 ** 6), 2)
    0.0
    """
    from scipy.special import chdtr, chdtrc, ndtri

    dof = max(int(dof), 1)
    ratio = max(variance / expected, 0.0) * dof
    above = _averaged(chdtrc, dof, ratio, sd)
    if above < 0.5:
        return float(-ndtri(max(above, 1e-300)))
    below = _averaged(chdtr, dof, ratio, sd)
    return float(ndtri(max(min(below, 0.5), 1e-300)))


def _averaged(tail, dof: int, ratio: float, sd: float) -> float:
    """E[tail(dof, ratio / exp(sd Z))], Z ~ N(0, 1): a chi-square's tail at
    ``ratio`` whose scale is off by a log-normal factor (:func:`variance_z`)."""
    if not sd > 0:
        return float(tail(dof, ratio))
    if sd * math.sqrt(dof / 2.0) <= 0.5:
        nodes, weights = _hermite()
        return float(np.sum(weights * tail(dof, ratio * np.exp(-np.minimum(sd * nodes, 700.0)))))
    from scipy.integrate import quad

    def f(x: float) -> float:
        return float(tail(dof, ratio * math.exp(min(-sd * x, 700.0)))) * math.exp(-0.5 * x * x) / math.sqrt(2 * math.pi)

    step = math.log(ratio / dof) / sd if ratio > 0 else -math.inf  # where the factor brings ratio to dof
    points = [step] if -12.0 < step < 12.0 else None
    return float(quad(f, -12.0, 12.0, points=points, limit=200, epsabs=1e-15, epsrel=1e-10)[0])


def _whole(i: Innovations, sd: float = 0.0) -> float:
    """:func:`variance_z` of sensor ``i``'s variance, n - 1 degrees of freedom about their mean."""
    n = i.samples
    return variance_z(i.variance * n / max(n - 1, 1), n - 1, sd)


def _wider(i: Innovations, cut: float, sd: float = 0.0, whole: float | None = None) -> bool:
    """Whether sensor ``i``'s residuals are wider than N(0, 1) at the
    one-sided normal quantile ``cut``: their variance, n - 1 degrees of
    freedom about their mean (:func:`variance_z`), and their variance
    without their farthest reading too, against its own expectation (n -
    E[the largest square]) / (n - 1): a glitch of one reading, however
    far, does not make the model's noise too small; a noise too small
    widens every reading. Requiring both, the test's size is at most the
    first one's. ``sd``: a standard deviation the variance has beside its
    sampling error (a calibrated model's, :func:`failures`); ``whole``: the
    first test's statistic, when the caller has it (:func:`_whole`)."""
    n = i.samples
    if not (_whole(i, sd) if whole is None else whole) > cut:
        return False
    if not math.isfinite(i.variance_but_one) or n < 4:
        return True
    expected = (n - largest_square(n)) / (n - 1)
    return variance_z(i.variance_but_one, n - 2, sd, expected) > cut


def failures(summaries: Sequence[Innovations], level: float, correlation: bool = True,
             narrower: bool = True, spread: Mapping[str, float] | None = None
             ) -> tuple[tuple[Innovations, str], ...]:
    """The sensors of ``summaries`` that fail a test at ``level`` over every
    sensor and test (Bonferroni), each with the first test it fails:
    ``correlated`` (Ljung-Box; not tried without ``correlation``), ``mean``
    (off 0, against its standard error sqrt(tau / n), ``tau`` their
    correlation time, at least 1) or ``variance`` (off 1, by the
    chi-square's exact tail, :func:`variance_z`; above 1 only when their
    variance without their farthest reading is too, :func:`_wider`; without
    ``narrower``, only a variance above 1). ``spread``: per sensor, the
    standard deviation a calibrated model's estimates add to the
    variance's sampling error, a log-normal factor (:func:`variance_z`; the model file's
    ``residual_variance_sd``, written by ``bgc calibrate``: its estimates
    fitted one recording's noise too, and a fresh recording's residual
    variance scatters by both)."""
    if not summaries:
        return ()
    alpha = level / ((3 if correlation else 2) * len(summaries))
    cut = NormalDist().inv_cdf(1.0 - alpha / 2)
    out = []
    for i in summaries:
        v = float((spread or {}).get(i.sensor, 0.0))
        if correlation and i.p_value < alpha:
            out.append((i, "correlated"))
        elif abs(i.mean) * math.sqrt(i.samples / max(i.correlation_time, 1.0)) > cut:
            out.append((i, "mean"))
        elif _wider(i, cut, v, whole := _whole(i, v)) or (narrower and -whole > cut):
            out.append((i, "variance"))
    return tuple(out)


def finding(i: Innovations, test: str) -> str:
    """The sentence of sensor ``i`` failing ``test`` (:func:`failures`)."""
    if test == "correlated":
        p = f"p = {i.p_value:.2g}" if i.p_value > 0 else "p < 1e-300"
        return f"sensor {i.sensor}'s residuals are correlated (Ljung-Box {p}): the model misses a dynamic"
    if test == "mean":
        return (f"sensor {i.sensor}'s residuals average {i.mean:+.3g} stds, not 0: the model misses an offset or a "
                "slow change of that reading")
    rest = f" ({i.variance_but_one:.3g} without its farthest reading)" if math.isfinite(i.variance_but_one) else ""
    return (f"sensor {i.sensor}'s residuals have variance {i.variance:.3g}{rest}, not 1: the model's noise does "
            "not fit that reading")


def findings(summaries: Sequence[Innovations], level: float, correlation: bool = True,
             narrower: bool = True) -> tuple[str, ...]:
    """One sentence per sensor of ``summaries`` that fails a test at
    ``level`` (:func:`failures`, :func:`finding`); empty when every sensor
    passes."""
    return tuple(finding(i, test) for i, test in failures(summaries, level, correlation, narrower))
