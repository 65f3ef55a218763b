"""A hypothesis's estimate of its fault magnitude (:func:`estimate_of`):
the mixture over its onsets of its filters' last clouds
(:func:`onset_mixture`), with the truth when the run records it
(:func:`truth_of`)."""

from __future__ import annotations

import math

import numpy as np

from ..kinds import fault_kind
from .hypothesis import weighted_quantiles
from ..data.runs import Run
from .values import Estimate


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


def truth_of(module, run: Run | None) -> tuple[float, float | None]:
    """The nominal value of fault model ``module``'s parameter and, when the
    run records it, its true magnitude (None when the run's fault is not of
    this model's kind: a parameter still moving at the end drifts, one that
    stopped stepped)."""
    p = module.FAULT["parameter"]
    kind = fault_kind(module.FAULT["kind"])
    if kind.discrete:  # a stuck switch: its flag, nominal 0; a run records no flag
        return 0.0, None
    nominal = dict(zip(module.PARAMETERS, module.THETA))[p]
    if run is None:
        return nominal, None
    return nominal, kind.truth(run.time, run.parameters.get(p), nominal)


def estimate_of(module, out: dict, run: Run | None, level: float, onsets=()) -> Estimate:
    """The magnitude's estimate: averaged over the onsets tried, each weighed
    by its posterior probability (``onsets``: (weight, filter output) pairs;
    the mixture of their last clouds gives the mean, std and interval), or
    when no onset has a weight (a dropped hypothesis), its filter ``out``'s."""
    p, kind_name = module.FAULT["parameter"], module.FAULT["kind"]
    kind = fault_kind(kind_name)
    nominal, truth = truth_of(module, run)
    mixture = [(w, o) for w, o in onsets if w > 0 and "final" in o]
    if mixture:
        value, std, low, high = onset_mixture([(w, *o["final"]) for w, o in mixture], level)
        total = float(sum(w for w, _ in mixture))
        parameter_value = float(sum(w * o["parameter_value"] for w, o in mixture) / total)
        return Estimate(p, kind_name, kind.magnitude, value, std, low, high, level, parameter_value, nominal, truth,
                        **struck(module))
    last = out["last"]
    return Estimate(p, kind_name, kind.magnitude, float(out["magnitude"][last]), out["final_std"],
                    float(out["band"][last, 0]), float(out["band"][last, 1]), level, out["parameter_value"],
                    nominal, truth, **struck(module))


def struck(module) -> dict:
    """What fault model ``module``'s fault strikes, for its :class:`Estimate`
    (``target``, ``subject``, ``unit``; a package generated before sensor
    and actuator faults existed strikes its parameter)."""
    fault = module.FAULT
    return {"target": fault.get("target", "parameter"), "subject": fault.get("subject", fault["parameter"]),
            "unit": fault.get("unit")}


#: How near a prior's bound an interval's end must come, as a fraction of the prior's width, to press on it.
NEAR_BOUND = 0.02


def pressed(estimate: Estimate, prior: tuple[float, float]) -> str | None:
    """``high`` or ``low`` when the estimate presses against that bound of
    the prior: its interval narrower than half the prior and reaching within
    ``NEAR_BOUND`` of its width of the bound (or past it: a random walk may
    carry particles beyond); None otherwise, or for an estimate without a
    number.

    >>> e = Estimate("R", "abrupt", "bias", 0.99, 0.005, 0.98, 1.0, 0.95, 1.99, 1.0)
    >>> pressed(e, (0.0, 1.0)), pressed(e, (0.0, 2.0))
    ('high', None)
    """
    lo, hi = prior
    width = hi - lo
    if not (math.isfinite(estimate.low) and math.isfinite(estimate.high) and width > 0):
        return None
    if estimate.high - estimate.low >= 0.5 * width:
        return None
    if estimate.high >= hi - NEAR_BOUND * width:
        return "high"
    if estimate.low <= lo + NEAR_BOUND * width:
        return "low"
    return None
