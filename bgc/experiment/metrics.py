"""How well a diagnosis did against the truth of a simulated run: the numbers
a campaign (:mod:`bgc.experiment.campaign`) records for every run.

The thesis's metrics (Weng 2013, section IV.2.2) with their definitions made
precise, and the diagnosis metrics besides them:

- ``mse``: per state, the mean over the run's steps of the squared error of
  the state estimate the diagnosis stands for (the nominal observer's, then
  from the diagnosed hypothesis's onset that hypothesis's filter: see
  :meth:`~bgc.diagnosis.diagnose.Diagnosis.state_estimate`) against the true
  state; ``nmse`` the same divided by the mean square of the true state (a
  relative error that does not depend on units).
- ``ct``, the time to convergence: the thesis calls a filter converged when
  the true state lies within about one standard deviation of the estimate. A
  single step's test flickers, so the test is the normalised estimation error
  squared (NEES, Bar-Shalom, Li and Kirubarajan 2001, section 5.4) averaged
  over a trailing window of ``window`` steps and all states: converged at the
  end of a window when that average is below the chi-square bound
  ``chi2_q(window n) / (window n)`` (``q`` = 0.999; the Wilson-Hilferty
  approximation of the quantile). ``ct`` is the time from which every later
  window passes, counted from the start of the run (the thesis's convention)
  and looked for after the fault's onset in a faulty run; None when the last
  window fails.
- detection: ``delay`` from the fault's onset to the alarm (time units);
  ``false_alarm`` when an alarm comes before the onset or in a fault-free run.
- isolation: the diagnosed fault model (``candidates[0]``), ``right`` when it
  is the injected parameter and kind, ``in_candidates`` when the injected one
  is among the surviving candidates (an ambiguous verdict).
- identification: for the right hypothesis, the estimate of the magnitude
  (bias or slope), its ``error`` relative to the truth and whether the
  reported interval ``covers`` it.

>>> import numpy as np
>>> x = np.zeros((40, 2)); sd = np.ones((40, 2))
>>> # errors of 3 std until step 9: a window of 5 holding two of them fails
>>> # (NEES 18/5 = 3.6 > chi2_0.999(10)/10 = 2.96), the last is [8, 13)
>>> convergence_step(x + 3.0 * (np.arange(40) < 10)[:, None], x, sd, 0, window=5)
13
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from ..diagnosis.diagnose import Diagnosis
from ..data.runs import Run
from ..model.protocol import onset_sample

#: Trailing window and quantile of the convergence test.
CT_WINDOW = 10
CT_QUANTILE = 0.999


@dataclass(frozen=True, slots=True)
class Truth:
    """The injected fault of a simulated run (None fields: fault-free)."""

    parameter: str | None = None
    kind: str | None = None
    magnitude: float | None = None
    onset: float | None = None

    @property
    def name(self) -> str:
        return "none" if self.parameter is None else f"{self.parameter}_{self.kind}"


@dataclass(frozen=True, slots=True)
class RunMetrics:
    """The metrics of one run (see the module docstring); times in the run's units."""

    mse: dict[str, float]
    nmse: float
    ct: float | None
    detected: bool
    detection_time: float | None
    delay: float | None
    false_alarm: bool
    verdict: str
    diagnosed: str
    right: bool | None
    in_candidates: bool | None
    estimate: float | None
    low: float | None
    high: float | None
    error: float | None
    covers: bool | None


def chi2_quantile(q: float, dof: int) -> float:
    """Wilson and Hilferty's (1931) approximation of the chi-square quantile
    (relative error below 1 % from 10 degrees of freedom).

    >>> round(chi2_quantile(0.999, 40), 1), round(chi2_quantile(0.95, 10), 1)  # tables: 73.40, 18.31
    (73.5, 18.3)
    """
    z = NormalDist().inv_cdf(q)
    h = 2.0 / (9.0 * dof)
    return dof * (1.0 - h + z * math.sqrt(h)) ** 3


def convergence_step(mean: np.ndarray, truth: np.ndarray, std: np.ndarray, start: int,
                     window: int = CT_WINDOW, quantile: float = CT_QUANTILE) -> int | None:
    """The first step from ``start`` on from which every trailing window of
    ``window`` steps passes the NEES test (module docstring); None when the
    last window fails. Steps are rows of ``mean``, ``truth``, ``std``."""
    e = ((mean - truth) / np.where(std > 0, std, np.nan)) ** 2
    n = e.shape[1]
    per_step = e.mean(axis=1)
    bad = ~np.isfinite(per_step)  # a zero or missing std, a missing estimate: that window fails
    T = len(per_step)
    if T - start < window:
        return None
    c = np.concatenate([[0.0], np.cumsum(np.where(bad, 0.0, per_step))])
    nb = np.concatenate([[0], np.cumsum(bad)])
    ends = np.arange(start + window, T + 1)  # window [end - window, end)
    average = (c[ends] - c[ends - window]) / window
    bound = chi2_quantile(quantile, window * n) / (window * n)
    failed = np.nonzero((average > bound) | (nb[ends] - nb[ends - window] > 0))[0]
    if len(failed) == 0:
        return start
    last = int(ends[failed[-1]])  # the last failing window ends before this step
    return None if last >= T else last


def measure(d: Diagnosis, run: Run, truth: Truth) -> RunMetrics:
    """The metrics of ``d``, a diagnosis of the simulated ``run`` whose injected
    fault is ``truth``."""
    mean, std = d.state_estimate()
    # the plant's states (a model with modes: not its mode and the time in it, which the data give)
    rows = [i for i, s in enumerate(d.states) if s in run.states]
    states = [d.states[i] for i in rows]
    mean, std = mean[:, rows], std[:, rows]
    true = np.column_stack([run.states[s] for s in states])
    mse = {s: float(np.mean((mean[:, i] - true[:, i]) ** 2)) for i, s in enumerate(states)}
    nmse = float(np.mean([mse[s] / max(float(np.mean(true[:, i] ** 2)), 1e-300) for i, s in enumerate(states)]))
    onset_step = 0 if truth.onset is None else onset_sample(run.time, truth.onset)
    ct_step = convergence_step(mean, true, std, min(onset_step, len(run.time) - 1))
    detected = d.detection is not None
    # the change test's alarm was raised at the end of the record it tested (its step: the change point it found then)
    t_alarm = None if not detected else d.time_of(d.detection.raised)
    false_alarm = detected and (truth.onset is None or t_alarm < truth.onset)
    delay = t_alarm - truth.onset if detected and truth.onset is not None and not false_alarm else None
    # an 'unexplained' verdict has no survivor: nothing is diagnosed
    diagnosed = d.candidates[0] if d.candidates and d.verdict in ("isolated", "ambiguous") else "none"
    right = in_candidates = estimate = low = high = error = covers = None
    if truth.parameter is not None:
        right = diagnosed == truth.name
        in_candidates = diagnosed != "none" and truth.name in d.candidates
        if right:
            e = d.estimate
            estimate, low, high = e.value, e.low, e.high
            # relative to the truth; none for a truth of 0 (a sensor stuck at 0): the interval says then
            error = abs(e.value - truth.magnitude) / abs(truth.magnitude) if truth.magnitude else None
            covers = bool(low <= truth.magnitude <= high)
    return RunMetrics(mse, nmse, None if ct_step is None else float(run.time[ct_step]), detected, t_alarm, delay,
                      bool(false_alarm), d.verdict, diagnosed, right, in_candidates, estimate, low, high, error,
                      covers)
