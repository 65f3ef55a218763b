"""Steps 6 to 8 and the verdict, as pure functions of hypotheses: each
takes frozen :class:`~bgc.diagnosis.values.Hypothesis` values and returns
them (with the :class:`~bgc.diagnosis.values.Drop` it decided, or none) and
the events it decided. :func:`weighed` runs them in order: the static
evidence (:func:`static_evidence`), the posterior and the Bayes factor
(:func:`posterior`), the ranking and refining (options), the goodness of fit
(:func:`misfits`), the prior's bounds (:func:`at_bounds`), the credible set
(:func:`credible`), and the verdict (:func:`verdict`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..data.clock import Clock
from ..kinds import fault_kind
from .. import events as ev
from .estimate import pressed
from .onsets import log_prior
from .rank import ranked, refined
from .static import STRETCH, checked, misfit_reason, static_estimate
from .values import Drop, Hypothesis


def weighed(hyps: tuple[Hypothesis, ...], posteriors: dict, r, s, null: float | None = None) \
        -> tuple[tuple[Hypothesis, ...], str, tuple[str, ...], list]:
    """Steps 6 to 8 on record ``r`` (a :class:`~bgc.diagnosis.finish.Record`)
    with setting ``s``: the hypotheses weighed (with their magnitudes held
    static where their static posteriors are), dropped by the Bayes factor,
    ranked and refined, tested, and the verdict. ``null``: log p(data | no
    fault), the nominal model's likelihood of the whole record, when it
    passes the hypotheses' consistency test there (None: no fault is not
    weighed): weighed beside the faults with static posteriors
    (:func:`posterior`, :func:`no_fault`). Returns (the hypotheses, the
    verdict, its candidates, the events)."""
    o, T = s.options, len(r.time)
    hyps, evidence_of, static, events = static_evidence(hyps, posteriors, s.ckf, T)
    hyps, weights, p0 = posterior(hyps, evidence_of, s.priors, o.bayes_factor, static, T,
                                  null if static else None, s.horizon)
    grids: dict = {}
    if o.rank and not static and sum(h.drop is None for h in hyps) > 1:  # 7. by their static evidence
        s.say(f"weighing {', '.join(h.name for h in hyps if h.drop is None)} with their magnitudes held static, "
              f"on a grid")
        hyps, weights, grids = ranked(hyps, weights, s.priors, s.package, r.clouds, r.ys, r.us, o)
    hyps = tuple(replace(h, posterior=float(w)) for h, w in zip(hyps, weights))
    decided, candidates = verdict(hyps)
    if o.refine and decided in ("isolated", "ambiguous"):  # 8. the survivors' magnitudes on a grid
        s.say(f"refining the magnitude of {', '.join(candidates)} on a grid")
        reuse = grids if o.rank_grid == o.grid else {}  # the ranking's grids, when as fine
        hyps = tuple(refined(h, reuse.get(h.name), s.package, r.clouds, r.ys, r.us, o)
                     if h.name in candidates and not fault_kind(h.kind).discrete else h for h in hyps)
    hyps = tuple(checked(h, r.outputs, o) if h.name in candidates and static else h for h in hyps)
    hyps = misfits(hyps, lambda k: float(r.time[k]), r.clock)
    prior_of = {h.name: tuple(float(v) for v in s.package.MODELS[h.name].FAULT_PRIOR) for h in hyps}
    hyps, more = at_bounds(hyps, prior_of, T, lambda h: h.drop is None)
    events += more
    hyps, more = credible(hyps, o.isolation_level, T)
    events += more
    decided, candidates = verdict(hyps)
    if decided == "unexplained":  # the one that lasted longest says so too
        hyps, more = at_bounds(hyps, prior_of, T, lambda h: h.name in candidates)
        events += more
    if p0 is not None:
        decided, candidates, more = no_fault(hyps, decided, candidates, p0, o.isolation_level, T, o.bayes_factor)
        events += more
    return hyps, decided, candidates, events + notes(hyps, decided, candidates, T)


def static_evidence(hyps: tuple[Hypothesis, ...], posteriors: dict, ckf: bool, T: int):
    """Step 6: each hypothesis's log evidence, with its magnitude held
    static where its static posterior has one (its estimate then the static
    one, the particle filters' own kept beside it); a hypothesis whose
    static posterior found no finite likelihood is dropped
    (``no-likelihood``). Returns (hypotheses, log evidence by name, whether
    the static posteriors weigh the hypotheses, events)."""
    evidence_of = {h.name: h.log_evidence for h in hyps}  # the filters' (a magnitude with a random walk)
    events: list = []
    static = False
    out = list(hyps)
    if posteriors and not any(math.isfinite(p.log_evidence) for p in posteriors.values()):
        events.append(ev.NoLikelihood(not ckf))
    elif posteriors:  # the survivors weighed with their magnitudes held static
        static = True
        for i, h in enumerate(hyps):
            p = posteriors.get(h.name)
            h = replace(h, static=p, static_log_evidence=None if p is None else p.log_evidence)
            evidence_of[h.name] = -math.inf if p is None else p.log_evidence
            if p is not None and math.isfinite(p.log_evidence):
                if not ckf:  # the particle filters' own estimate, beside the static one
                    h = replace(h, filter_estimate=h.estimate)
                h = replace(h, estimate=static_estimate(h.estimate, p))
                if p.truncated and not h.ruled_out:  # step 6b's: said only of a candidate (notes)
                    events.append(ev.Truncated(h.name))
            elif p is not None and h.drop is None:
                h = replace(h, drop=Drop("no-likelihood", T - 1, "with its magnitude held static, its cubature "
                                         "Kalman filters found no finite likelihood at any onset and magnitude of "
                                         "their grid"))
            out[i] = h
    # a hypothesis its static consistency test dropped (with --filter ckf, or weighed at step 6b) weighs
    # nothing, as one its particle filters drop
    evidence_of.update({h.name: -math.inf for h in out if h.drop is not None and (ckf or h.ruled_out)})
    return tuple(out), evidence_of, static, events


def posterior(hyps: tuple[Hypothesis, ...], evidence_of: dict, priors: dict, bayes_factor: float, static: bool,
              T: int, null: float | None = None, horizon: int = 1) -> tuple[tuple[Hypothesis, ...], np.ndarray,
                                                                          float | None]:
    """The hypotheses' posterior (evidence times prior, normalised); a
    survivor decisively less probable than the best (the Bayes factor) is
    dropped (``bayes-factor``). With ``null`` (log p(data | no fault)), no
    fault is weighed too. A fault's prior p is the probability that it
    happens within a ``horizon`` of steps, so that it begins at a given step
    with probability p / horizon; its static evidence sums its likelihood
    over its onsets each weighed by the steps it stands for
    (:func:`bgc.diagnosis.static_posterior.onset_widths`), so its weight is
    p / horizon times that; no fault's is its likelihood (the probability
    that no fault begins within the record is a factor common to both, for
    one fault at a time). Returns (the hypotheses, their posteriors, no
    fault's posterior: None when not weighed)."""
    shift = 0.0 if null is None else math.log(max(int(horizon), 1))
    logs = [log_prior(priors, h.parameter) - shift + evidence_of[h.name] for h in hyps]
    every = np.array(logs + ([] if null is None else [null]), dtype=float)
    if np.isfinite(every).any():
        every = np.exp(every - every.max())
        every = every / every.sum()
    else:  # none survives (or none was tried)
        every = np.zeros(len(every))
    weights = every[:len(hyps)]
    p0 = None if null is None else float(every[-1])
    top = max(every) if len(every) else 0.0
    favoured = "no fault" if p0 is not None and p0 >= top else "another hypothesis"
    out = tuple(replace(h, drop=Drop("bayes-factor", T - 1, (
        ("with the magnitudes held static, " if static else "")
        + f"the data favour {favoured} by a Bayes factor above {bayes_factor:g} (posterior {w:.2g})")))
                if h.drop is None and w < top / bayes_factor else h for h, w in zip(hyps, weights))
    return out, weights, p0


def no_fault(hyps: tuple[Hypothesis, ...], decided: str, candidates: tuple[str, ...], p0: float, level: float,
             T: int, bayes_factor: float = math.inf) -> tuple[str, tuple[str, ...], list]:
    """The verdict with no fault weighed (its posterior ``p0``, beside the
    hypotheses' own): its share of the posterior of it and every fault
    weighed, whatever dropped them (a fault that failed its fit test but
    explains the data far better than no fault still says the data are not
    the nominal model's). A share of at least ``level`` is the verdict "no
    fault" (the alarm a false one); over 1 - ``level``, "isolated" cannot be
    promised and is "ambiguous", and a verdict says it with a
    :class:`~bgc.events.NoFault` event. An "unexplained" verdict every
    fault of which is at least ``bayes_factor`` times less probable than no
    fault is "no fault" too (many faults each far less probable can hold
    more than 1 - ``level`` together, but none explains the data). Returns
    (the verdict, its candidates, the events)."""
    weighed_ = [h for h in hyps if math.isfinite(h.posterior)]
    total = p0 + sum(h.posterior for h in weighed_)
    mass = p0 / total if total > 0 and math.isfinite(total) else 0.0
    outweighed = decided == "unexplained" and p0 > 0 and all(h.posterior * bayes_factor <= p0 for h in weighed_)
    if mass <= 1.0 - level and not outweighed:
        return decided, candidates, []
    best = max(weighed_, key=lambda h: h.posterior, default=None)
    factor = math.log(best.posterior / p0) if best is not None and best.posterior > 0 and p0 > 0 else -math.inf
    name = None if best is None else best.name
    if mass >= level or outweighed:
        return "no fault", (), [ev.NoFault(mass, name, factor, level, True, T - 1)]
    return ("ambiguous" if decided == "isolated" else decided), candidates, [
        ev.NoFault(mass, name, factor, level, False, T - 1)]


def misfits(hyps: tuple[Hypothesis, ...], time_of, clock: Clock = Clock()) -> tuple[Hypothesis, ...]:
    """The goodness-of-fit test of a survivor: its fault model with the
    magnitude held at its most probable value from its most probable onset
    (the static posterior's best cell) must pass the consistency test of the
    hypothesis filters (section 5: the windowed Z-test of its normalised
    residuals, a probability ``rejection`` of an alarm on the true model).
    A survivor that fails it is dropped (``static-test``): it does not
    explain the data, and a fault the model does not list ends "unexplained"
    instead of named as the candidate that mimics it best. (Its Misfit
    event says by how much; ``clock``: how its onset's time is written.)"""
    out = []
    for h in hyps:
        if h.static_alarm is not None and h.drop is None:
            alarm, (start, value) = h.static_alarm, h.static.best
            h = replace(h, drop=Drop("static-test", start + alarm.step,
                                     misfit_reason(h.estimate.magnitude, value, time_of(start), alarm,
                                                   h.estimate.kind, clock)))
        out.append(h)
    return tuple(out)


def at_bounds(hyps: tuple[Hypothesis, ...], prior_of: dict, T: int, which) -> tuple[tuple[Hypothesis, ...], list]:
    """The hypotheses ``which`` picks whose magnitude presses against a
    bound of its prior (``prior_of[name]``; :func:`~bgc.diagnosis.estimate.pressed`)
    say so (an event; the estimate's ``bound``). A survivor pressed against
    0, its prior's edge of no change, is dropped (``wrong-direction``): the
    data ask for a change its model does not allow (a fault in a direction
    the model does not list), and an alarm it sizes as nothing is not
    explained by it."""
    out, events = [], []
    for h in hyps:
        if which(h) and h.estimate.bound is None:
            prior = prior_of[h.name]
            side = pressed(h.estimate, prior)
            if side is not None:
                bound = prior[0 if side == "low" else 1]
                events.append(ev.AtPriorBound(h.name, side, bound, h.estimate.value, T - 1))
                h = replace(h, estimate=replace(h.estimate, bound=side))
                if bound == 0 and h.drop is None and not fault_kind(h.kind).replaces:
                    h = replace(h, drop=Drop("wrong-direction", T - 1, (
                        "its magnitude presses against 0, the edge of its prior: the data ask for a change in a "
                        "direction its model does not list")))
        out.append(h)
    return tuple(out), events


def credible(hyps: tuple[Hypothesis, ...], level: float, T: int) -> tuple[tuple[Hypothesis, ...], list]:
    """The candidates of a verdict hold a posterior of at least ``level``
    together (a credible set): the survivors' posterior, relative to that
    of the hypotheses still in the running (the survivors and those the
    Bayes factor dropped; a hypothesis that fails a test of its fit is out
    of it), is at least ``level``, or the most probable of those the Bayes
    factor dropped are kept as candidates too until it is (an ``Uncertain``
    event). Many rivals each just under the Bayes factor can together hold
    more than 1 - ``level``: then "isolated" would promise more than the
    posterior does."""
    survivors = [h for h in hyps if h.drop is None]
    outvoted = sorted((h for h in hyps if h.drop is not None and h.drop.code == "bayes-factor"),
                      key=lambda h: -h.posterior)
    mass = sum(h.posterior for h in survivors)
    total = mass + sum(h.posterior for h in outvoted)
    if not survivors or total <= 0 or mass >= level * total:
        return hyps, []
    alone, kept = mass / total, []
    for h in outvoted:
        if mass >= level * total:
            break
        kept.append(h)
        mass += h.posterior
    event = ev.Uncertain(tuple(h.name for h in sorted(survivors, key=lambda h: -h.posterior)), alone, level,
                         tuple(h.name for h in kept), tuple(h.posterior / total for h in kept), T - 1)
    names = {h.name for h in kept}
    return tuple(replace(h, drop=None) if h.name in names else h for h in hyps), [event]


def verdict(hyps: tuple[Hypothesis, ...]) -> tuple[str, tuple[str, ...]]:
    """isolated (one survivor), ambiguous (several, best first), or
    unexplained (none: the one that lasted longest)."""
    survivors = sorted((h for h in hyps if h.drop is None), key=lambda h: -h.posterior)
    if len(survivors) == 1:
        return "isolated", (survivors[0].name,)
    if survivors:
        return "ambiguous", tuple(h.name for h in survivors)
    if hyps:
        return "unexplained", (max(hyps, key=lambda h: (h.dropped_step, h.posterior)).name,)
    return "unexplained", ()


def notes(hyps: tuple[Hypothesis, ...], decided: str, candidates: tuple[str, ...], T: int) -> list:
    """The events the weighing's outcome says of each hypothesis: a fault
    model the symbols ruled out that is a candidate all the same
    (``Overruled``, and ``Truncated`` when its grid may be short), a
    survivor that failed its fit test (``Misfit``), and every drop
    (``Dropped``)."""
    events = []
    for h in hyps:
        if h.ruled_out and h.name in candidates and decided != "unexplained":
            events.append(ev.Overruled(h.name, h.ruled_out, T - 1))
            if h.static is not None and h.static.truncated:
                events.append(ev.Truncated(h.name))
        if h.static_alarm is not None:
            alarm, (start, value) = h.static_alarm, h.static.best
            events.append(ev.Misfit(h.name, h.estimate.magnitude, value, start, alarm.sensor, alarm.window,
                                    alarm.statistic, alarm.threshold, stretch=alarm.test == STRETCH))
        if h.drop is not None:
            events.append(ev.Dropped(h.drop.step, h.name, h.drop.code, h.drop.reason))
    return events
