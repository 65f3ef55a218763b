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
"""

from __future__ import annotations

from dataclasses import dataclass
from collections import deque
from math import isfinite, sqrt
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


@dataclass(frozen=True, slots=True)
class DetectorOptions:
    """``false_alarm``: probability of any alarm in a fault-free run of
    ``steps`` steps (all sensors, all windows); ``windows``: window lengths in
    samples."""

    false_alarm: float = 0.01
    windows: tuple[int, ...] = (1, 8, 32)
    steps: int = 300

    def threshold(self, sensors: int) -> float:
        """The |S| above which the detector alarms (see the module docstring)."""
        return union_threshold(self.false_alarm, max(1, self.steps) * max(1, sensors) * len(self.windows))


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

    def __init__(self, sensors: tuple[str, ...], options: DetectorOptions = DetectorOptions()):
        self.sensors = sensors
        self.options = options
        self.threshold = options.threshold(len(sensors))
        self._windows = tuple(int(w) for w in options.windows)
        self._longest = max(self._windows)
        # cumulative sums of z and of the Monte Carlo shares a_k: the last (the newest at -1), as tuples of floats
        zero = (0.0,) * len(sensors)
        self._cumsum = deque([zero], maxlen=self._longest + 1)
        self._mc = deque([zero], maxlen=self._longest + 1)
        self.statistics: list[list[float]] = []  # max over windows of |S|, per sensor and step

    def update(self, z, mc=None) -> Detection | None:
        """Take the normalised residuals of one step (NaN: sensor not read)
        and, from a particle filter, the Monte Carlo std of its prediction in
        units of its predicted std (:func:`monte_carlo_share`; none: an exact
        prediction); return the alarm when this step raises one. ``z``,
        ``mc``: arrays or sequences of floats, one per sensor."""
        k = len(self.statistics)  # steps taken before this one
        c, m = self._cumsum, self._mc
        c_now = _accumulate(c[-1], z)
        m_now = m[-1] if mc is None else _accumulate(m[-1], mc)
        c.append(c_now)
        m.append(m_now)
        best, at, top = -1.0, None, None
        for w in self._windows:
            if w > k + 1:  # longer than the record: no test
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
            grow = np.zeros((len(self.starts), max(self._cumsum.shape[1], 64), len(self.sensors)))
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
