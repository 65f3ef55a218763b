"""Identification by marginal likelihood on a grid: an optional refinement of
the fault magnitude once a hypothesis is isolated (``DiagnosisOptions.refine``).

The hypothesis filter estimates the magnitude as a particle state with a
random walk and Liu and West moves: one filter per onset, cheap, but its
Monte Carlo error is large for a slow drift (on the RO plant's R_pipe drift,
about three times the error the data allow: docs/results.md, section 3).
This refinement evaluates the data's likelihood directly: for each of the
``onsets`` most probable onsets and each of ``points`` magnitudes on a grid
around the filter's interval, a bootstrap particle filter with the magnitude
held fixed gives an unbiased estimate of p(y | onset, magnitude) (the
pseudo-marginal idea of Andrieu, Doucet and Holenstein 2010, evaluated on a
grid instead of by MCMC). Every filter starts from the nominal observer's
cloud before the earliest of those onsets, and the nominal model runs up to
each onset, so all likelihoods cover the same data. The same random numbers
are used for every magnitude at an onset (common random numbers), so that the
grid's likelihoods differ by the magnitude, not by the noise of the estimate.
With a flat prior on the grid, the posterior of the magnitude is the
likelihood summed over the onsets; its mean, std and central interval
replace the filter's estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .options import GridOptions
from ..model.protocol import FaultModel, Package, magnitude_row, nominal_model


@dataclass(frozen=True, slots=True)
class GridPosterior:
    """The grid (``values``), the onsets (steps), log p(y | onset, value) and
    the posterior of the magnitude: mean, std and the central interval of
    probability ``level``."""

    values: np.ndarray
    onsets: tuple[int, ...]
    loglik: np.ndarray
    posterior: np.ndarray
    mean: float
    std: float
    low: float
    high: float
    level: float


def log_sum_exp(a: np.ndarray) -> float:
    """log(sum(exp(a))) of a 1-d array, shifted by its largest entry (-inf
    when empty, or when every entry is -inf). On the few numbers of a bank's
    weights it costs 9 us a call, where scipy.special.logsumexp costs 240 us
    (its array-API dispatch; measured), and the mode decoder
    (:mod:`bgc.diagnosis.hidden`) calls it a hundred thousand times a diagnosis."""
    if not len(a):
        return -math.inf
    m = float(np.max(a))
    return m + math.log(float(np.sum(np.exp(a - m)))) if np.isfinite(m) else m


def _bootstrap(package: Package, model: FaultModel, x: np.ndarray, ys: np.ndarray, us: np.ndarray, rng,
               fixed: tuple[int, float] | None = None) -> tuple[float, np.ndarray]:
    """log p(ys | the cloud x) by a bootstrap filter (its unbiased estimate);
    ``fixed`` (row, value) holds a state at a value. Returns it and the final cloud."""
    theta = model.THETA
    total = 0.0
    n = x.shape[1]
    with np.errstate(all="ignore"):
        for k in range(len(ys)):
            model.transition(x, us[k], theta, model.DT, rng, out=x)
            if fixed is not None:
                x[fixed[0]] = fixed[1]
            ll = model.loglik(ys[k], x, us[k], theta)
            if getattr(model, "PROPOSAL_ROW", None) is not None:  # switches proposed beyond the guards' odds
                ll = ll + x[model.PROPOSAL_ROW]
            ll = np.where(np.isfinite(ll), ll, -np.inf)
            total += log_sum_exp(ll) - math.log(n)
            if not np.isfinite(total):
                return -math.inf, x
            x = x[:, package.filters.systematic_resample(ll, rng)]
    return total, x


def loglik_grid(package: Package, name: str, cloud, ys: np.ndarray, us: np.ndarray, first: int,
                onsets: tuple[int, ...], values: np.ndarray, particles: int, seed) -> np.ndarray:
    """log p(ys[first:] | onset, value) for every onset (steps, each >= first)
    and grid value; ``cloud`` (x, logw): the nominal cloud before ``first``
    (None: the model's prior)."""
    nominal = nominal_model(package)
    model = package.MODELS[name]
    row = magnitude_row(model)
    rng = np.random.default_rng([*seed, 0])
    if cloud is None:
        x = nominal.initial_particles(rng, particles)
    else:
        x = cloud[0][:, package.filters.systematic_resample(cloud[1], rng)]
        if x.shape[1] != particles:
            x = x[:, rng.integers(0, x.shape[1], particles)]
    out = np.full((len(onsets), len(values)), -np.inf)
    done, before = first, 0.0
    for i, onset in enumerate(sorted(onsets)):
        part, x = _bootstrap(package, nominal, x, ys[done:onset], us[done:onset], rng)
        before += part
        done = onset
        for j, value in enumerate(values):
            crn = np.random.default_rng([*seed, 1 + i])  # the same random numbers for every value
            xf = model.augment(x.copy(), crn)
            xf[row] = 0.0  # the transition into the onset sample is nominal; _bootstrap sets the value after it
            part, _ = _bootstrap(package, model, xf, ys[onset:], us[onset:], crn, fixed=(row, float(value)))
            out[i, j] = before + part
    return out


def grid_job(job) -> np.ndarray:
    """:func:`loglik_grid` on a part of the grid (run in a worker process: the
    nominal path is the same in every part, its random numbers being the same)."""
    import sys

    package_name, name, cloud, ys, us, first, onsets, values, particles, seed = job
    return loglik_grid(sys.modules[package_name], name, cloud, ys, us, first, onsets, values, particles, seed)


def refine(package: Package, name: str, cloud, ys: np.ndarray, us: np.ndarray, onsets: tuple[int, ...],
           low: float, high: float, prior: tuple[float, float], level: float, options: GridOptions,
           seed, parts: int = 1, mapper=None, first: int | None = None) -> GridPosterior:
    """The grid posterior of the magnitude of fault model ``name`` (a key of
    ``package.MODELS``), from ``onsets`` (steps) and the filter's interval
    (``low``, ``high``), kept inside the magnitude's ``prior``. The
    likelihoods cover the data from step ``first`` (default: the earliest
    onset; ``cloud`` is the nominal cloud before it). The grid is cut into
    ``parts`` jobs that ``mapper(grid_job, jobs)`` runs (default: here, one
    after the other)."""
    mapper = mapper or (lambda fn, jobs: [fn(j) for j in jobs])
    width = max(high - low, 1e-9 * max(1.0, abs(high)))
    lo, hi = low - options.widen * width, high + options.widen * width
    first = min(onsets) if first is None else first
    for attempt in range(2):
        lo, hi = max(lo, prior[0]), min(hi, prior[1])
        values = np.linspace(lo, hi, options.points)
        chunks = [c for c in np.array_split(values, max(1, parts)) if len(c)]
        jobs = [(package.__name__, name, cloud, ys, us, first, tuple(sorted(onsets)), c, options.particles, seed)
                for c in chunks]
        ll = np.concatenate(mapper(grid_job, jobs), axis=1)
        top = np.max(ll)
        post = np.exp(ll - top).sum(axis=0) if np.isfinite(top) else np.ones(len(values))
        post /= post.sum()
        edge = post[0] > 0.02 and lo > prior[0] or post[-1] > 0.02 and hi < prior[1]
        if attempt == 1 or not edge:
            break
        shift = (hi - lo) / 2.0 * (1 if post[-1] > post[0] else -1)  # the mass is at an end: move that way
        lo, hi = lo + shift, hi + shift
    mean = float(post @ values)
    std = math.sqrt(max(float(post @ (values - mean) ** 2), 0.0))
    tail = (1.0 - level) / 2.0
    c = np.cumsum(post) - 0.5 * post
    q_low, q_high = np.interp([tail, 1.0 - tail], c, values)
    return GridPosterior(values, tuple(sorted(onsets)), ll, post, mean, std, float(q_low), float(q_high), level)


def log_evidence(g: GridPosterior, prior: tuple[float, float], widths=None) -> float:
    """log of the sum over the onsets of ``g`` of width x p(y | onset, fault
    model), with the magnitude static and uniform on ``prior``: the grid's
    likelihoods integrated over the magnitude (the trapezoid rule on the
    grid, whose span holds the likelihood's mass) and divided by the prior's width;
    ``widths``: each onset's prior weight (default 1 each). (The grid need not
    cover the whole prior: where the likelihood is negligible, so is its
    integral.)"""
    if len(g.values) > 1:
        rule = np.full(len(g.values), float(g.values[1] - g.values[0]))
        rule[[0, -1]] /= 2.0
    else:
        rule = np.array([float(prior[1] - prior[0])])
    w = np.ones(len(g.onsets)) if widths is None else np.asarray(widths, dtype=float)
    total = float(np.logaddexp.reduce(g.loglik + np.log(np.outer(w, rule)), axis=None))
    return total - math.log(prior[1] - prior[0])
