"""Does the model fit the plant? The test of the data before a fault.

An alarm says that the residuals left what the model predicts. Whether that
is a fault depends on the data before it: a fault is a change, and a change
needs a stretch of data the model explained before it. Data from a plant
whose parameters or noise differ from the model file's disagree with the
model from their first sample; the diagnosis then names whichever fault
model mimics the disagreement best "since the first sample", or an alarm
anywhere at all when the noise is larger than declared. That is a model
that does not fit this plant (a *model mismatch*), and the remedy is to
calibrate it (``bgc calibrate``), not to repair the plant.

**The stretch tested.** The data from the first step up to the earlier of
the detector's change point and the diagnosis's onset (the change point
alone when the verdict is unexplained, its closest model explaining
nothing, though its onset still counts for "too short to tell" below;
the whole record when nothing was detected): the data the verdict says
are fault-free.

**The test.** The nominal cubature Kalman filter (the observer of
``bgc calibrate``, exact on a plant linear in its states) runs over the
stretch; per sensor read, its normalised residuals, white N(0, 1) draws
when the model fits, are summed up as ``bgc calibrate`` sums up the
calibrated model's (:mod:`bgc.filters.residuals`): their mean, against its
standard error 1 / sqrt(n), and their variance, by the chi-square's exact
tail (n - 1 degrees of freedom), each
sensor and test at :data:`LEVEL` over all of them (Bonferroni). On a
model ``bgc calibrate`` wrote, that tail is averaged over what the
calibration's estimates leave on the variance, a log-normal factor
(:func:`residual_sd`: the estimates fitted one recording's noise too). A
variance above 1 counts when the variance without the sensor's farthest
reading is above its own expectation too (one glitch of a reading is not
a model whose noise is too small; :func:`bgc.filters.residuals.failures`).
Only a variance above 1 counts here: residuals narrower than the filter predicts (a
plant quieter than its model, or a filter that spreads its prediction
wider, as it does across the switches of a model with modes) make the
detector more cautious. They can still rank the faults wrongly, a fault
model winning by the narrower spread it predicts: the named fault's
residuals are tested for that (:func:`bgc.diagnosis.finish.quiet_misfit`). Ljung-Box's
whiteness test, which ``bgc calibrate`` adds, is left out of the verdict: on
data of the model itself it fails more often than its level says (a
portmanteau over 20 lags is sensitive to the slight slow wander a
discretised simulation leaves); its statistic stays in the summary
(:attr:`~bgc.diagnosis.values.Fit.innovations`).

**Too short to tell.** When the fault's onset (the earlier of the change
point and the diagnosis's) leaves fewer than :data:`LEAST` samples before
it, their mean and variance say too little to vouch for the model: a fault
since the data's start and a model that does not fit give the same data.
For a drift, the detector's change point alone: a drift's onset is weakly
told by the data, and its most probable one may lie far before the truth;
but a drift named (isolated or ambiguous) whose onset is within the first
:data:`LEAST` samples leaves that few before it too, and the stretch tested
ends there: a drift since the data's start is the shape a model that does
not fit takes (a plant 2 % off its model, a sensor fault on it: "R10
drifts up since t = 1.5" was isolated; tests/test_off_model_fault.py).

**The named fault's noise** (:func:`bgc.diagnosis.finish.noise_misfit`):
when the stretch fits and the diagnosis names a fault, the same variance test
runs on that fault's own residuals after its onset (its static posterior's
most likely cell): a fault model explains a change of the readings, never
noise the model lacks, and a plant noisier than its model whose alarm came
late leaves them too wide while the few samples before the onset did not
show it.

**The verdict** (:mod:`bgc.diagnosis.finish`): when the stretch fails the
test, or is too short, or the named fault's residuals are too wide, the
diagnosis is ``mismatch``. Its candidates are
the faults the diagnosis would have named, kept as possibilities: a fault
that truly starts with the data is one of them.

On bgc's own fault-free runs of six plants (60 seeds each, 300 samples), the
mean and variance tests at this level fail on 3 of 360 runs, all on a mean
(measured: the command in docs/results.md).
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from ..filters.cubature import nominal_track
from ..filters.residuals import failures, finding, summary
from .values import Fit

#: The probability that the test finds a model that fits the plant at fault, over every sensor and test.
LEVEL = 0.001
#: The samples before a fault's onset below which it cannot be told from a model that does not fit.
LEAST = 10
#: The level of the test that the residuals changed at an unexplained alarm's change point (over every
#: sensor and test): a change shown at it keeps the verdict unexplained (:func:`changed`).
CHANGE_LEVEL = 0.05


def fit(nominal, ys: np.ndarray, us: np.ndarray, outputs: tuple[str, ...], end: int, short: bool = False,
        level: float = LEVEL, track=None, skip: tuple[int, int] | None = None) -> Fit:
    """The test of the nominal model ``nominal`` (a generated model) on the
    measurements ``ys`` and inputs ``us`` of steps ``0 .. end - 1``;
    ``short``: the caller's judgement that the data before the fault are
    too few to tell (fewer than :data:`LEAST`); ``track``: the nominal
    cubature Kalman filter's track over them or further
    (:class:`~bgc.filters.cubature.NominalTrack`), when the diagnosis
    computed it already (else it is computed here); ``skip``: steps (first,
    end) left out (a false alarm's window, an excursion the detector's
    budget allows)."""
    end = max(0, min(int(end), len(ys)))
    if track is None or track.z is None or len(track.z) < end:
        track = nominal_track(nominal, ys, us, end)
    z = np.array(track.z, dtype=float)[:end].reshape(end, len(outputs))
    with np.errstate(invalid="ignore"):
        gap = ys[:end] - np.asarray(track.y_mean, dtype=float)[:end].reshape(end, len(outputs))
    if skip is not None:
        z[skip[0]:skip[1]] = np.nan
        gap[skip[0]:skip[1]] = np.nan
    summaries = summary([z], outputs)
    offsets = []
    for j, name in enumerate(outputs):
        read = gap[:, j][np.isfinite(gap[:, j])]
        if len(read) >= 3:
            offsets.append((name, float(read.mean())))
    failed = failures(summaries, level, correlation=False, narrower=False, spread=residual_sd(nominal))
    return Fit(end, LEAST, float(level), summaries, tuple(offsets), tuple(finding(i, t) for i, t in failed),
               bool(short), tuple(t for _, t in failed))


def changed(z: np.ndarray, end: int, outputs: tuple[str, ...], level: float = CHANGE_LEVEL) -> tuple[str, ...]:
    """The sensors whose normalised residuals ``z`` (steps x ``outputs``;
    NaN: not read or left out) changed at step ``end``: the mean after it
    against the mean before (Welch's statistic, (m2 - m1) / sqrt(v1 / n1 +
    v2 / n2)) or the variance (the log of their ratio against its standard
    error sqrt(2 / (n1 - 1) + 2 / (n2 - 1))), each two-sided at ``level``
    over every sensor and test (Bonferroni). A sensor read fewer than 3
    times on either side counts as changed: nothing says it did not."""
    statistics, cut = change_statistics(z, end, level)
    return tuple(outputs[j] for j, value in statistics.items() if not value <= cut)


def change_statistics(z: np.ndarray, end: int, level: float = CHANGE_LEVEL) -> tuple[dict[int, float], float]:
    """Per sensor read in ``z`` (its column), the larger of :func:`changed`'s
    two statistics at step ``end`` (infinite: read fewer than 3 times on a
    side; NaN: not computable, counted changed), and the threshold they are held to at ``level``."""
    read = [j for j in range(z.shape[1]) if np.isfinite(z[:, j]).any()]
    cut = NormalDist().inv_cdf(1 - level / (2 * 2 * max(len(read), 1)))
    out = {}
    for j in read:
        a, b = _sides(z, end, j)
        if len(a) < 3 or len(b) < 3:
            out[j] = np.inf
            continue
        va, vb = float(a.var(ddof=1)), float(b.var(ddof=1))
        mean = abs(b.mean() - a.mean()) / np.sqrt(va / len(a) + vb / len(b))
        spread = abs(np.log(vb / va)) / np.sqrt(2 / (len(a) - 1) + 2 / (len(b) - 1)) if va > 0 and vb > 0 else np.inf
        out[j] = float(np.nan if np.isnan(mean) or np.isnan(spread) else max(mean, spread))  # NaN: changed
    return out, float(cut)


def shifted(z: np.ndarray, level: float) -> tuple[int, ...]:
    """The columns of normalised residuals ``z`` (steps x sensors; NaN: not
    read) whose mean changed somewhere in them, by the CUSUM test of a mean
    shift at an unknown step on residuals (the OLS-residual CUSUM of
    Ploberger and Kraemer, 1992, with a known model's residuals): per sensor, its
    ``n`` readings' partial sums about their mean, ``S_k = sum_{i <= k} (z_i
    - mean)``, their largest ``|S_k|`` over ``sqrt(n)`` times the readings'
    standard deviation; with no change that is the supremum of a Brownian
    bridge's absolute value (Kolmogorov's distribution, its tail
    ``2 sum_j (-1)^(j-1) exp(-2 j^2 x^2)``: :func:`scipy.special.kolmogorov`)
    as ``n`` grows, whatever the mean and the spread, for residuals that are
    white (serially correlated ones, a model whose dynamics do not fit,
    exceed it more often: the rules that follow it, :meth:`bgc.diagnosis.diagnoser.Diagnoser._change`,
    ask more of a change). Each sensor at
    ``level`` over all of them (Bonferroni); a sensor read fewer than
    2 :data:`LEAST` times is not tested. A shift in the middle of a record
    shows here where the record's mean, diluted by the samples before it,
    does not (:func:`fit`)."""
    from scipy.special import kolmogorov

    read = [j for j in range(z.shape[1]) if np.isfinite(z[:, j]).sum() >= 2 * LEAST]
    out = []
    for j in read:
        a = z[:, j][np.isfinite(z[:, j])]
        spread = float(a.std(ddof=1))
        if not spread > 0:
            continue
        statistic = float(np.max(np.abs(np.cumsum(a - a.mean())))) / (math.sqrt(len(a)) * spread)
        if float(kolmogorov(statistic)) < level / len(read):
            out.append(j)
    return tuple(out)


def _sides(z: np.ndarray, end: int, j: int) -> tuple[np.ndarray, np.ndarray]:
    """Sensor ``j``'s residuals read (finite) before step ``end`` and from it on."""
    a, b = z[:end, j], z[end:, j]
    return a[np.isfinite(a)], b[np.isfinite(b)]


def misfit_before(z: np.ndarray, end: int) -> float:
    """The log of how much likelier the normalised residuals ``z`` (steps
    x sensors; NaN: not read or left out) before step ``end`` are under the
    distribution of those after it (per sensor, the normal of their mean
    and variance) than under the model's N(0, 1), summed over the sensors
    read on both sides: positive when the data before the change point
    look like the data after it (a misfit throughout), negative when they
    look like the model (a change at the change point that
    :func:`changed`, with few samples before it, may be too weak to show)."""
    total = 0.0
    for j in range(z.shape[1]):
        a, b = _sides(z, end, j)
        if len(a) < 1 or len(b) < 3:
            continue
        m, v = float(b.mean()), float(b.var())
        if not v > 0:
            return -np.inf
        total += float(np.sum(-0.5 * np.log(v) - 0.5 * (a - m) ** 2 / v + 0.5 * a ** 2))
    return total


def fails(nominal, z: np.ndarray, outputs: tuple[str, ...], level: float = LEVEL) -> list:
    """The failures (index, test) of the test of ``nominal``'s fit, every
    test but the residuals' correlation and a variance too small, at
    ``level`` on normalised residuals ``z`` (steps x ``outputs``; NaN: not
    read), a calibrated model's allowance with them (:func:`residual_sd`):
    the test :func:`fit` holds a record to, on residuals already in hand."""
    return failures(summary([z], outputs), level, correlation=False, narrower=False, spread=residual_sd(nominal))


def residual_sd(nominal) -> dict[str, float]:
    """Per sensor, the standard deviation a calibration's estimates
    leave on the normalised residuals' variance on other data: the
    generated model's ``RESIDUAL_VARIANCE_SD`` (the model file's
    ``residual_variance_sd``, written by ``bgc calibrate``; a model with
    modes: its first mode's module's; a decomposed plant: its parts'); none
    for a model nobody calibrated."""
    return dict(getattr(nominal, "RESIDUAL_VARIANCE_SD", None) or {})


def reread(us: np.ndarray, columns: list[int], timing: str) -> np.ndarray:
    """The inputs ``us`` (steps x inputs) with ``columns`` (the data's own)
    read with the other input timing: ``timing`` ``start`` (a row's value
    set at its time) makes each value act one step later than read as
    ``end`` (held over the step that ends at the row's time), ``end`` one
    step earlier; the value at the edge is held."""
    out = np.array(us, dtype=float, copy=True)
    if timing == "start":
        out[1:, columns] = us[:-1, columns]
    else:
        out[:-1, columns] = us[1:, columns]
    return out


def timing_told(nominal, ys: np.ndarray, us: np.ndarray, outputs: tuple[str, ...], columns: list[int],
                timing: str, level: float = LEVEL, factor: float = 100.0,
                track=None) -> tuple[str, bool, float] | None:
    """The other input timing (``start`` for ``end``, and back) when the
    data say their inputs follow it: inputs of the data (``columns``) that
    change, the whole record failing :func:`fit` with the inputs read as
    ``timing``, and the nominal cubature Kalman filter finding the record at
    least ``factor`` times likelier with them read the other way (one step
    later or earlier: :func:`reread`); two readings of one model, weighed as
    the diagnosis weighs its hypotheses (``bayes_factor``). Returns (the
    other timing, whether the model fits the whole record read that way,
    the log of the likelihood ratio), or None. A plant whose response to an
    input change shows within a step (a motor's current, a sensor that reads
    the input itself) leaves a residual spike at each change when the timing
    is misread, and nowhere else."""
    columns = [j for j in columns if np.any(np.diff(us[:, j]) != 0)]
    T = len(ys)
    if not columns or T < LEAST:
        return None
    if track is None or track.z is None or len(track.z) < T:
        track = nominal_track(nominal, ys, us, T)
    if fit(nominal, ys, us, outputs, T, level=level, track=track).fits:
        return None
    other = "start" if timing == "end" else "end"
    alternative = nominal_track(nominal, ys, reread(us, columns, other), T)
    ratio = float(alternative.loglik[T] - track.loglik[T])
    if not ratio >= np.log(factor):
        return None
    return other, fit(nominal, ys, None, outputs, T, level=level, track=alternative).fits, ratio
