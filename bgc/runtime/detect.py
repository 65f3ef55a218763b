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

**Onset.** At an alarm at step k the change point is estimated by the
generalised likelihood ratio of a mean shift of unknown size, starting at t,
in every sensor's residuals (Basseville and Nikiforov, 1993, ch. 2):

    t_hat = argmax_t  sum_j (z_t,j + ... + z_k,j)^2 / (k - t + 1),   k - L < t <= k,

``L`` the longest window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np


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


@dataclass(frozen=True, slots=True)
class Detection:
    """An alarm: at step ``step`` (index into the run), on ``sensor`` (its
    name) with window ``window`` and statistic ``statistic`` (|S| > threshold);
    ``onset``: the estimated first faulty step."""

    step: int
    sensor: str
    window: int
    statistic: float
    threshold: float
    onset: int


class Detector:
    """The sliding-window Z-test, one step at a time (:meth:`update`)."""

    def __init__(self, sensors: tuple[str, ...], options: DetectorOptions = DetectorOptions()):
        self.sensors = sensors
        self.options = options
        self.threshold = options.threshold(len(sensors))
        self.z: list[np.ndarray] = []
        self._cumsum = [np.zeros(len(sensors))]
        self.statistics: list[np.ndarray] = []  # max over windows of |S|, per sensor and step

    def update(self, z: np.ndarray) -> Detection | None:
        """Take the normalised residuals of one step (NaN: sensor not read);
        return the alarm when this step raises one."""
        z = np.where(np.isfinite(z), z, 0.0)
        self.z.append(z)
        self._cumsum.append(self._cumsum[-1] + z)
        k = len(self.z) - 1
        best = np.zeros(len(self.sensors))
        alarm = None
        for w in self.options.windows:
            if k + 1 < w:
                continue
            s = np.abs(self._cumsum[k + 1] - self._cumsum[k + 1 - w]) / math.sqrt(w)
            best = np.maximum(best, s)
            j = int(np.argmax(s))
            if s[j] > self.threshold and (alarm is None or s[j] / self.threshold > alarm[2] / self.threshold):
                alarm = (j, w, float(s[j]))
        self.statistics.append(best)
        if alarm is None:
            return None
        j, w, s = alarm
        return Detection(k, self.sensors[j], w, s, self.threshold, self.onset(k))

    def onset(self, k: int) -> int:
        """GLR change point of a mean shift ending at step k (see the module docstring)."""
        longest = max(self.options.windows)
        c = np.array(self._cumsum)
        best, at = -1.0, k
        for t in range(max(0, k - longest + 1), k + 1):
            seg = c[k + 1] - c[t]
            score = float(seg @ seg) / (k - t + 1)
            if score > best:
                best, at = score, t
        return at
