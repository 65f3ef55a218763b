"""Steps 7 and 8: the survivors weighed anew by the evidence of their
models with the magnitude held static on a particle-filter grid
(:func:`ranked`), and their magnitudes refined on a grid (:func:`refined`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..kinds import fault_kind
from . import identify
from .options import GridOptions
from .static_posterior import onset_widths
from .values import Drop, Estimate, Hypothesis
from .options import DiagnosisOptions, processes
from .onsets import log_prior, top_onsets
from .openloop import cloud_before
from .parallel import parallel_map


def grid_posterior(package, name: str, estimate: Estimate, clouds: dict, ys, us, onsets, options: DiagnosisOptions, seed,
          first: int | None = None, grid: GridOptions | None = None) -> identify.GridPosterior:
    """The grid posterior of hypothesis ``name``'s magnitude (:func:`bgc.diagnosis.identify.refine`) on
    ``grid`` (default: ``options.grid``), over the data from ``first`` (default: the earliest onset)."""
    first = min(onsets) if first is None else first
    return identify.refine(package, name, cloud_before(clouds, first), ys, us, onsets,
                           estimate.low, estimate.high, tuple(package.MODELS[name].FAULT_PRIOR), options.interval,
                           grid or options.grid, seed, parts=max(1, processes(options.workers)),
                           mapper=lambda fn, jobs: parallel_map(fn, jobs, options.workers), first=first)


def ranked(hyps: tuple[Hypothesis, ...], weights: np.ndarray, priors: dict[str, float], package, clouds: dict, ys,
           us, options: DiagnosisOptions) -> tuple[tuple[Hypothesis, ...], np.ndarray, dict]:
    """The survivors' posterior weighed anew by the evidence of their static
    models: the magnitude held at each value of a grid, uniform on its prior,
    integrated (:func:`bgc.diagnosis.identify.log_evidence`); the onsets, each
    hypothesis's most probable ones, each weighed by the span of samples it
    stands for (:func:`onset_widths`; those not on the grid counted through
    the filters' onset posterior: the grid's sum divided by the share of the
    onset posterior it covers).
    Every grid covers the data from the earliest of those onsets, from the
    same nominal cloud and with the same random numbers before each onset, so
    the evidences compare like for like. The survivors share the posterior
    mass they had; one less probable than the best by more than the Bayes
    factor is dropped (``bayes-factor``). Returns the hypotheses (each
    survivor with its ``static_log_evidence``), the weights and the grid
    posteriors by name."""
    alive = [i for i, h in enumerate(hyps) if h.drop is None]
    chosen = {i: top_onsets(hyps[i].onset_steps, hyps[i].onset_posterior, hyps[i].start_step,
                            options.rank_grid.onsets)
              for i in alive}
    first = min(min(o) for o in chosen.values())
    out, log_w, grids = list(hyps), [], {}
    for i in alive:
        h = hyps[i]
        if fault_kind(h.kind).discrete:  # no size to hold on a grid: its filters' evidence over its onsets
            out[i] = dataclasses.replace(h, static_log_evidence=h.log_evidence)
            log_w.append(log_prior(priors, h.parameter) + h.log_evidence)
            continue
        g = grid_posterior(package, h.name, h.estimate, clouds, ys, us, chosen[i], options, [options.seed, 8], first,
                           options.rank_grid)
        grids[h.name] = g
        posterior = dict(zip(h.onset_steps, h.onset_posterior))
        width = dict(zip(h.onset_steps, onset_widths(h.onset_steps)))
        covered = sum(posterior.get(s, 0.0) for s in g.onsets) or 1.0
        evidence = identify.log_evidence(g, tuple(package.MODELS[h.name].FAULT_PRIOR),
                                         [width[s] for s in g.onsets]) - math.log(covered)
        out[i] = dataclasses.replace(h, static_log_evidence=evidence)
        log_w.append(log_prior(priors, h.parameter) + evidence)
    log_w = np.array(log_w)
    weights = weights.copy()
    if np.isfinite(log_w).any():
        share = np.exp(log_w - log_w.max())
        weights[alive] = weights[alive].sum() * share / share.sum()
    top = max(weights[alive])
    for i in alive:
        if weights[i] < top / options.bayes_factor:
            out[i] = dataclasses.replace(out[i], drop=Drop(
                "bayes-factor", len(ys) - 1, f"with the magnitudes held static, the data favour another hypothesis by "
                f"a Bayes factor above {options.bayes_factor:g} (posterior {weights[i] / weights.sum():.2g})"))
    return tuple(out), weights, grids


def refined(h: Hypothesis, g: identify.GridPosterior | None, package, clouds: dict, ys, us,
             options: DiagnosisOptions) -> Hypothesis:
    """``h`` with its estimate from the grid posterior (:mod:`bgc.diagnosis.identify`): ``g``, or computed here."""
    module = package.MODELS[h.name]
    e = h.estimate
    if g is None:
        onsets = top_onsets(h.onset_steps, h.onset_posterior, h.start_step, options.grid.onsets)
        g = grid_posterior(package, h.name, e, clouds, ys, us, onsets, options, [options.seed, 7, sum(map(ord, h.name))])
    kind = fault_kind(h.kind)
    if kind.drifts:  # the parameter at the last step: nominal + its change since the onset
        joint = np.exp(g.loglik - np.max(g.loglik))
        joint /= joint.sum()
        spans = np.array([(len(ys) - t) * module.DT for t in g.onsets])
        value = float(e.nominal + np.sum(joint * kind.change(g.values[None, :], spans[:, None])))
    else:
        value = e.nominal + kind.change(g.mean, 0.0)
    estimate = dataclasses.replace(e, value=g.mean, std=g.std, low=g.low, high=g.high, parameter_value=value,
                                   method="grid")
    return dataclasses.replace(h, estimate=estimate)
