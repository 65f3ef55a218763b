"""The end of a diagnosis (steps 4 to 8 of :mod:`bgc.diagnosis.diagnose`):
the hypotheses' filters over the record, their static posteriors, the
weighing, ranking, refining, and the verdict, from a
:class:`~bgc.diagnosis.diagnoser.Diagnoser`'s record."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ..kinds import fault_kind
from . import events as ev
from ..filters import cubature as kalman
from .hypothesis import log_density
from .static_posterior import EDGE, EXTEND
from .values import StaticPosterior
from ..data.runs import Run
from .values import Diagnosis, Hypothesis
from .estimate import estimate_of, pressed
from .hypothesis import hypothesis_job
from .onsets import earlier_onsets, onset_weights
from .parallel import run_batches
from .rank import ranked, refined
from .static import StaticJob, checked, kalman_hypotheses, misfit_reason, run_static, static_alarm, static_estimate


def decide(d, truth: Run | None) -> Diagnosis:
    """The diagnosis of diagnoser ``d``'s record (``truth``: the run, when it
    records the true fault)."""
    a = d.arrays()
    T = len(a["time"])
    statistics = np.array(d.detector.statistics + [np.full(len(d.detector.sensors), np.nan)]
                          * (T - len(d.detector.statistics)))
    if len(d.detector.sensors) < len(d.outputs):  # sensors the data lack: no statistic
        full = np.full((T, len(d.outputs)), np.nan)
        full[:, d._present] = statistics.reshape(T, -1)
        statistics = full
    common = dict(model=d.nominal.MODEL, time=a["time"], outputs=d.outputs, states=tuple(d.nominal.STATES),
                  nominal_y_mean=a["y_mean"], nominal_y_std=a["y_std"], nominal_z=a["z"],
                  nominal_x_mean=a["x_mean"], nominal_x_std=a["x_std"], statistics=statistics,
                  threshold=d.detector.threshold, options=d.options, data=d.sampler.summary())
    # a sensor never read (its column empty or nan throughout) tells nothing: the diagnosis says so
    silent = [ev.SensorSilent(y) for j, y in enumerate(d.outputs)
              if y in d.sampler.present and not np.isfinite(a["ys"][:, j]).any()]
    if d.detection is None:
        events = list(d.events) + silent + [ev.Decided(T - 1, "no fault", ())]
        return Diagnosis(verdict="no fault", detection=None, onset=None, symbols=(), refuted=(), hypotheses=(),
                         candidates=(), seconds=time.perf_counter() - d.started, events=_ordered(events), **common)
    if d.isolation is None:  # the data ended before the symbols' samples were in
        d._isolate()
    iso = d.isolation
    events = list(d.events) + silent
    observer = d.kf.track() if d.ckf else None
    hyps, posteriors, whys, observer = _hypotheses(d, a, iso, observer, truth, events)
    _recheck(d, a, iso, observer, truth, hyps, posteriors, whys, events)
    return _weigh(d, a, iso, hyps, posteriors, whys, events, common)


def _recheck(d, a: dict, iso, observer, truth, hyps: list[dict], posteriors: dict, whys: dict,
             events: list) -> None:
    """Step 6b: the fault models the symbols ruled out, weighed too before a
    verdict names a fault (``DiagnosisOptions.recheck``; ``identify =
    "kalman"``, while a hypothesis the symbols kept survives its filters):
    each one's static posterior over its onsets and its whole prior (as
    ``--filter ckf`` weighs every hypothesis), added to ``hyps`` and
    ``posteriors`` (so that its evidence counts in the posterior, and its
    consistency test and the Bayes factor can drop it). The symbols are read
    on a short open-loop window after a late alarm, and a slope or a
    higher-order symbol can mislead where the fault began long before it (a
    slow drift at high noise): a fault model they ruled out that explains
    the data within the Bayes factor is then a candidate (an ``Overruled``
    event), rather than a verdict resting on the symbols alone."""
    o = d.options
    untried = iso.untried(d.package)
    if not (o.recheck and o.identify == "kalman" and untried and any(h["dropped"] is None for h in hyps)
            and any(math.isfinite(p.log_evidence) for p in posteriors.values())):
        return
    if observer is None:  # the particle filters' diagnosis, none of whose hypotheses reached a static posterior
        observer = _nominal_track(d, a, iso)
    models: dict[str, list[str]] = {}
    why_of: dict[str, str] = {}
    for (signature, why), name in zip(iso.refuted, iso.ruled_out):
        models.setdefault(name, []).append(signature)
        why_of.setdefault(name, f"{signature}: {why}")
    drifts = {name: fault_kind(d.package.MODELS[name].FAULT["kind"]).drifts for name in untried}
    d.say(f"weighing the {len(untried)} fault models the symbols ruled out too")
    more, static = kalman_hypotheses(untried, models, d.package, truth, a["time"], a["ys"], a["us"], observer,
                                     iso.kalman_onsets, iso.kalman_reach, drifts, o, d.say)
    for h in more:
        if "why" in h:
            whys[h["name"]] = h.pop("why")
        h["ruled_out"] = why_of[h["name"]]
    hyps.extend(more)
    posteriors.update(static)


def _hypotheses(d, a: dict, iso, observer, truth, events: list):
    """Steps 4 to 6: each hypothesis's filters, or (ckf) its static posterior
    alone; (hypothesis dicts, static posteriors, drop reasons by name, the
    nominal cubature Kalman filter's track when one was computed)."""
    if d.ckf:  # 4-6. every hypothesis with its magnitude held static, by cubature Kalman filters alone
        hyps, posteriors = kalman_hypotheses(iso.names, iso.models, d.package, truth, a["time"], a["ys"], a["us"],
                                             observer, iso.kalman_onsets, iso.kalman_reach, iso.drifts, d.options,
                                             d.say)
        return hyps, posteriors, {h["name"]: h.pop("why") for h in hyps if "why" in h}, observer
    work = _Tracking(d, a, iso, truth)
    hyps = work.run()
    if d.options.identify == "kalman" and not work.posteriors:
        work.rescue(hyps, events)
    return hyps, work.posteriors, work.whys, (work.track[0] if work.track else None)


def _nominal_track(d, a: dict, iso) -> kalman.NominalTrack:
    """The nominal cubature Kalman filter over the record up to the latest
    onset a static posterior starts from (the particle filters' diagnosis)."""
    return kalman.nominal_track(d.nominal, a["ys"], a["us"], max(max(s) for s in iso.kalman_onsets.values()))


class _Tracking:
    """Steps 4 to 6 with particle filters: every hypothesis's filters over
    the record (those the diagnoser tracked online are done; the others, and
    a drift's earlier onsets, run on ``workers`` processes), each one's
    evidence over a common span, and (``identify = "kalman"``) the static
    posterior of each one its filters keep."""

    def __init__(self, d, a: dict, iso, truth):
        self.d, self.a, self.iso, self.truth, self.o = d, a, iso, truth, d.options
        self.T = len(a["time"])
        self.starts_of = {name: list(iso.starts_of[name]) for name in iso.names}
        self.density = log_density(a["z"], a["y_std"])  # the nominal observer's, per step
        self.results: dict[tuple[str, int], dict] = {}  # (name, onset) -> its filter's output
        self.best_of: dict[str, np.ndarray] = {}  # per hypothesis and step, the best running evidence over [0, step]
        self.posteriors: dict[str, StaticPosterior] = {}
        self.track: list = []  # the nominal cubature Kalman filter's states, once computed
        self.whys: dict[str, str] = {}

    def run(self) -> list[dict]:
        d, a, T = self.d, self.a, self.T
        names = self.iso.names
        d.say(f"tracking {len(names)} fault hypotheses ({', '.join(names)}) from "
              f"{sum(len(self.starts_of[n]) for n in names)} onsets and hypotheses "
              f"(t = {a['time'][min((min(s) for s in self.starts_of.values()), default=self.iso.onset)]:g} to "
              f"{a['time'][d.detection.step]:g})")
        batches = {name: self.starts_of[name] for name in names}
        if d.trackers:  # tracked online: their first batches are done
            batches = self._tracked()
        if batches:
            run_batches(batches, self.job, self.arrived, self.o.workers, lambda starts: sum(T - s for s in starts),
                        self.idle, self.done, self.landed)  # cost: filter steps, if none stops
        first = min(min(s) for s in self.starts_of.values())
        for out in self.results.values():  # the common span starts at `first`
            out["evidence"] -= float(self.density[:first].sum())
        # 5. evidence over a common span (the nominal filter's before each onset), consistency, estimates
        return [self.assemble(name) for name in names]

    def _tracked(self) -> dict[str, list[int]]:
        """The online trackers' results taken; the further batches they ask for."""
        self.idle()
        follow = {}
        for name in self.iso.names:
            tracker = self.d.trackers[name]
            more = self.arrived(name, self.starts_of[name], *tracker.result(self.T - tracker.job.first))
            if more:
                follow[name] = more
                continue
            step = self.done(name)
            if step is not None:
                self.landed(name, step[0](step[1]))
        return follow

    def job(self, name: str, starts: list[int]) -> tuple:
        return hypothesis_job(name, starts, self.d.package, self.d.clouds, self.a["ys"], self.a["us"], self.density,
                              self.d.outputs, self.o, self.d.horizon, self.best_of.get(name))

    def arrived(self, name: str, starts: list[int], res: dict, trace: np.ndarray) -> list[int]:
        """Take a batch of hypothesis ``name``'s onsets; the earlier onsets to try next (none: done)."""
        f = min(starts)
        before = float(self.density[:f].sum())  # the nominal observer's densities before the batch
        for rel, out in res.items():
            out["from"] = f
            out["evidence"] += before
            self.results[(name, rel + f)] = out
        full = np.full(self.T, -math.inf)
        full[f:] = trace + before
        self.best_of[name] = np.maximum(self.best_of.get(name, full), full)
        # a drift whose onsets' posterior piles up at the earliest one tried began earlier:
        # its grid is extended back by `search` steps (up to `history` before the alarm)
        tried = self.starts_of[name]
        more = next(iter(earlier_onsets(self.iso.reach, tried, self.o.search)), ())
        if not (self.iso.drifts[name] and more) or self.o.identify == "kalman":  # the Kalman filters reach back
            return []
        w, log_evidence = onset_weights(tried, [self.results[(name, s)]["evidence"] for s in tried])
        if not (math.isfinite(log_evidence) and w[:EDGE].sum() >= EXTEND):
            return []
        self.starts_of[name] = sorted([*more, *tried])
        self.d.say(f"looking for earlier onsets of {name}")
        return list(more)

    def assemble(self, name: str) -> dict:
        return _assemble(name, self.d, self.a, self.iso, self.starts_of[name], self.results, self.truth, self.whys)

    # 6. (identify="kalman") each hypothesis its filters keep, as soon as they are done: its onset and
    # magnitude with the magnitude held static, by cubature Kalman filters on a grid, from the nominal
    # cubature Kalman filter's state at each onset (computed while the first filters run)

    def idle(self) -> None:
        if self.o.identify == "kalman" and not self.track:
            self.track.append(_nominal_track(self.d, self.a, self.iso))

    def static_job(self, name: str, h: dict) -> StaticJob:
        drifts = self.iso.drifts[name]
        tried = self.iso.kalman_onsets[drifts]
        earlier = earlier_onsets(self.iso.kalman_reach, tried, self.o.search)
        return StaticJob(self.d.package.__name__, name, self.a["ys"], self.a["us"], self.track[0], tuple(tried),
                         (h["estimate"].low, h["estimate"].high), h["start"], self.o.interval, self.o.kalman, earlier)

    def done(self, name: str):
        if self.o.identify != "kalman":
            return None
        h = self.assemble(name)
        if h["dropped"] is not None:
            return None
        return run_static, self.static_job(name, h)

    def landed(self, name: str, posterior: StaticPosterior) -> None:
        self.posteriors[name] = posterior

    def rescue(self, hyps: list[dict], events: list) -> None:
        """None passed its particle filters' test: each whose most probable
        onset's filter still ran to the end (only just off the data: a drift's
        filters start on a coarser grid of onsets than its Kalman filters') is
        tested as its fault model states it, the magnitude held static."""
        self.idle()
        for h in hyps:
            if not math.isfinite(self.results[(h["name"], h["start"])]["evidence"]):
                continue
            self.d.say(f"testing {h['name']} with its magnitude held static")
            p = run_static(self.static_job(h["name"], h))
            if math.isfinite(p.log_evidence) and static_alarm(p, self.d.outputs, self.o) is None:
                self.posteriors[h["name"]] = p
                events.append(ev.Rescued(h["name"], h["reason"], h["dropped"]))
                h["dropped"], h["reason"] = None, ""
                self.whys.pop(h["name"], None)


def _assemble(name: str, d, a: dict, iso, starts: list[int], results: dict, truth, whys: dict) -> dict:
    """Hypothesis ``name`` from its filters' results: its most probable onset, whether it is
    dropped and why, its onset posterior, evidence and estimate."""
    module = d.package.MODELS[name]
    evidence = np.array([results[(name, start)]["evidence"] for start in starts])  # stopped, pruned: -inf
    dropped_at, reason = None, ""
    if np.isfinite(evidence).any():
        start = starts[int(np.argmax(evidence))]
        every = ""
    else:  # every onset's filter was stopped or pruned: dropped when the last one was
        start = max(starts, key=lambda s: (results[(name, s)]["last"] >= 0,
                                           s + results[(name, s)]["last"], results[(name, s)]["partial"]))
        every = f", from every onset tried ({len(starts)})" if len(starts) > 1 else ""
    if results[(name, start)]["rejected"] is not None:  # the best onset's filter failed its test
        k, alarm = results[(name, start)]["rejected"]
        dropped_at = start + k
        reason = (f"its residual of {alarm.sensor} over {alarm.window} sample(s) reached {alarm.statistic:.1f} "
                  f"(threshold {alarm.threshold:.1f})" + every)
        whys[name] = "inconsistent"
    elif not np.isfinite(evidence).any():  # pruned onsets only (a filter never started)
        dropped_at = start + max(results[(name, start)]["last"], 0)
        reason = "another onset of it explained the data decisively better, and that one failed" + every
        whys[name] = "pruned"
    out = results[(name, start)]
    zh = (a["ys"][start:] - out["y_mean"]) / out["y_std"]
    weights, log_evidence = onset_weights(starts, evidence)
    n = len(d.nominal.STATES)
    return dict(name=name, parameter=module.FAULT["parameter"], kind=module.FAULT["kind"],
                signatures=tuple(iso.models[name]), start=start, onsets=tuple(starts),
                onset_posterior=tuple(float(w) for w in weights),
                y_mean=out["y_mean"], y_std=out["y_std"], z=zh, x_mean=out["mean"][:, :n], x_std=out["std"][:, :n],
                magnitude=out["magnitude"], magnitude_band=out["band"], dropped=dropped_at, reason=reason,
                log_evidence=log_evidence,
                seconds=sum({results[(name, s)]["from"]: results[(name, s)]["seconds"] for s in starts}.values()),
                estimate=estimate_of(module, out, truth, d.options.interval,
                                         [(w, results[(name, s)]) for w, s in zip(weights, starts)]))


def _weigh(d, a: dict, iso, hyps: list[dict], posteriors: dict, whys: dict, events: list, common: dict) -> Diagnosis:
    """Steps 6 to 8: the hypotheses weighed (with their magnitudes held
    static where their static posteriors are), dropped by the Bayes factor,
    ranked and refined; the verdict."""
    o, T = d.options, len(a["time"])
    evidence_of, static = _static_evidence(d, hyps, posteriors, whys, events, T)
    weights = _posterior(d, hyps, evidence_of, whys, static, T)
    grids: dict = {}
    if o.rank and not static and sum(h["dropped"] is None for h in hyps) > 1:  # 7. by their static evidence
        d.say(f"weighing {', '.join(h['name'] for h in hyps if h['dropped'] is None)} with their magnitudes held "
              f"static, on a grid")
        alive = {h["name"] for h in hyps if h["dropped"] is None}
        weights = ranked(hyps, weights, d.priors, d.package, d.clouds, a["ys"], a["us"], o, grids)
        whys.update({h["name"]: "bayes-factor" for h in hyps if h["name"] in alive and h["dropped"] is not None})
    hypothesis_list = tuple(Hypothesis(posterior=float(w), **h) for h, w in zip(hyps, weights))
    verdict, candidates = _verdict(hypothesis_list)
    if o.refine and verdict in ("isolated", "ambiguous"):  # 8. the survivors' magnitudes on a grid
        d.say(f"refining the magnitude of {', '.join(candidates)} on a grid")
        reuse = grids if o.rank_grid == o.grid else {}  # the ranking's grids, when as fine
        hypothesis_list = tuple(refined(h, reuse.get(h.name), d.package, d.clouds, a["ys"], a["us"], o)
                                if h.name in candidates else h for h in hypothesis_list)
    hypothesis_list = tuple(checked(h, d.outputs, o) if h.name in candidates and static else h
                            for h in hypothesis_list)
    hypothesis_list = _misfits(hypothesis_list, lambda k: float(a["time"][k]), whys)
    hypothesis_list = _at_bounds(d, hypothesis_list, T, whys, events, lambda h: h.dropped is None)
    hypothesis_list = _credible(hypothesis_list, o.isolation_level, whys, events, T)
    verdict, candidates = _verdict(hypothesis_list)
    if verdict == "unexplained":  # the one that lasted longest says so too
        hypothesis_list = _at_bounds(d, hypothesis_list, T, whys, events, lambda h: h.name in candidates)
    for h in hypothesis_list:
        if h.ruled_out and h.name in candidates and verdict != "unexplained":
            events.append(ev.Overruled(h.name, h.ruled_out, T - 1))
            if h.static is not None and h.static.truncated:
                events.append(ev.Truncated(h.name))
        if h.static_alarm is not None:
            alarm, (start, value) = h.static_alarm, h.static.best
            events.append(ev.Misfit(h.name, h.estimate.magnitude, value, start, alarm.sensor, alarm.window,
                                    alarm.statistic, alarm.threshold))
        if h.dropped is not None:
            events.append(ev.Dropped(h.dropped, h.name, whys.get(h.name, "inconsistent"), h.reason))
    best_onset = next((h.onset for h in hypothesis_list if candidates and h.name == candidates[0]), iso.onset)
    d.say(f"done: {verdict}" + (f", {', '.join(candidates)}" if candidates else ""))
    events.append(ev.Decided(T - 1, verdict, candidates))
    final = [e for e in events if not (isinstance(e, ev.Dropped) and e.detail == STOPPED)]  # given anew above
    return Diagnosis(verdict=verdict, detection=d.detection, onset=best_onset, symbols=iso.symbols,
                     refuted=iso.refuted, hypotheses=hypothesis_list, candidates=candidates,
                     seconds=time.perf_counter() - d.started, events=_ordered(final), **common)


def _misfits(hypotheses: tuple[Hypothesis, ...], time_of, whys: dict) -> tuple[Hypothesis, ...]:
    """The goodness-of-fit test of a survivor: its fault model with the
    magnitude held at its most probable value from its most probable onset
    (the static posterior's best cell) must pass the consistency test of the
    hypothesis filters (section 5: the windowed Z-test of its normalised
    residuals, a probability ``rejection`` of an alarm on the true model).
    A survivor that fails it is dropped (``static-test``): it does not
    explain the data, and a fault the model does not list ends "unexplained"
    instead of named as the candidate that mimics it best. (Its Misfit
    event says by how much.)"""
    out = []
    for h in hypotheses:
        if h.static_alarm is not None and h.dropped is None:
            alarm, (start, value) = h.static_alarm, h.static.best
            whys[h.name] = "static-test"
            h = replace(h, dropped=start + alarm.step,
                        reason=misfit_reason(h.estimate.magnitude, value, time_of(start), alarm))
        out.append(h)
    return tuple(out)


def _at_bounds(d, hypotheses: tuple[Hypothesis, ...], T: int, whys: dict, events: list,
               which) -> tuple[Hypothesis, ...]:
    """The hypotheses ``which`` picks whose magnitude presses against a
    bound of its prior (:func:`~bgc.diagnosis.estimate.pressed`) say so (an
    event; the estimate's ``bound``). A survivor pressed against 0, its
    prior's edge of no change, is dropped: the data ask for a change its
    model does not allow (a fault in a direction the model does not list),
    and an alarm it sizes as nothing is not explained by it."""
    out = []
    for h in hypotheses:
        if which(h) and h.estimate.bound is None:
            prior = tuple(float(v) for v in d.package.MODELS[h.name].FAULT_PRIOR)
            side = pressed(h.estimate, prior)
            if side is not None:
                bound = prior[0 if side == "low" else 1]
                events.append(ev.AtPriorBound(h.name, side, bound, h.estimate.value, T - 1))
                h = replace(h, estimate=replace(h.estimate, bound=side))
                if bound == 0 and h.dropped is None and not fault_kind(h.kind).replaces:
                    whys[h.name] = "wrong-direction"
                    h = replace(h, dropped=T - 1, reason=(
                        "its magnitude presses against 0, the edge of its prior: the data ask for a change in a "
                        "direction its model does not list"))
        out.append(h)
    return tuple(out)


def _credible(hypotheses: tuple[Hypothesis, ...], level: float, whys: dict, events: list,
              T: int) -> tuple[Hypothesis, ...]:
    """The candidates of a verdict hold a posterior of at least ``level``
    together (a credible set): the survivors' posterior, relative to that
    of the hypotheses still in the running (the survivors and those the
    Bayes factor dropped; a hypothesis that fails a test of its fit is out
    of it), is at least ``level``, or the most probable of those the Bayes
    factor dropped are kept as candidates too until it is (an ``Uncertain``
    event). Many rivals each just under the Bayes factor can together hold
    more than 1 - ``level``: then "isolated" would promise more than the
    posterior does."""
    survivors = [h for h in hypotheses if h.dropped is None]
    outvoted = sorted((h for h in hypotheses if h.dropped is not None and whys.get(h.name) == "bayes-factor"),
                      key=lambda h: -h.posterior)
    mass = sum(h.posterior for h in survivors)
    total = mass + sum(h.posterior for h in outvoted)
    if not survivors or total <= 0 or mass >= level * total:
        return hypotheses
    alone, kept = mass / total, []
    for h in outvoted:
        if mass >= level * total:
            break
        kept.append(h)
        mass += h.posterior
    events.append(ev.Uncertain(tuple(h.name for h in sorted(survivors, key=lambda h: -h.posterior)), alone, level,
                               tuple(h.name for h in kept), tuple(h.posterior / total for h in kept), T - 1))
    names = {h.name for h in kept}
    for name in names:
        whys.pop(name, None)
    return tuple(replace(h, dropped=None, reason="") if h.name in names else h for h in hypotheses)


def _static_evidence(d, hyps: list[dict], posteriors: dict, whys: dict, events: list,
                     T: int) -> tuple[dict[str, float], bool]:
    """Step 6: each hypothesis's log evidence, with its magnitude held static
    where its static posterior has one (its estimate then the static one);
    and whether the static posteriors weigh the hypotheses."""
    evidence_of = {h["name"]: h["log_evidence"] for h in hyps}  # the filters' (a magnitude with a random walk)
    static = False
    if posteriors and not any(math.isfinite(p.log_evidence) for p in posteriors.values()):
        events.append(ev.NoLikelihood(not d.ckf))
    elif posteriors:  # the survivors weighed with their magnitudes held static
        static = True
        for h in hyps:
            p = posteriors.get(h["name"])
            h["static"] = p
            h["static_log_evidence"] = None if p is None else p.log_evidence
            evidence_of[h["name"]] = -math.inf if p is None else p.log_evidence
            if p is not None and math.isfinite(p.log_evidence):
                if not d.ckf:  # the particle filters' own estimate, beside the static one
                    h["filter_estimate"] = h["estimate"]
                h["estimate"] = static_estimate(h["estimate"], p)
                if p.truncated and not h.get("ruled_out"):  # step 6b's: said only of a candidate (_weigh)
                    events.append(ev.Truncated(h["name"]))
            elif p is not None and h["dropped"] is None:
                h["dropped"] = T - 1
                whys[h["name"]] = "no-likelihood"
                h["reason"] = ("with its magnitude held static, its cubature Kalman filters found no finite "
                               "likelihood at any onset and magnitude of their grid")
    # a hypothesis its static consistency test dropped (with --filter ckf, or weighed at step 6b) weighs
    # nothing, as one its particle filters drop
    evidence_of.update({h["name"]: -math.inf for h in hyps
                        if h["dropped"] is not None and (d.ckf or h.get("ruled_out"))})
    return evidence_of, static


def _posterior(d, hyps: list[dict], evidence_of: dict, whys: dict, static: bool, T: int) -> np.ndarray:
    """The hypotheses' posterior (evidence times prior, normalised); a
    survivor decisively less probable than the best (the Bayes factor) is
    dropped."""
    o = d.options
    weights = np.array([math.log(max(d.priors.get(h["parameter"], 0.01), 1e-300)) + evidence_of[h["name"]]
                        for h in hyps])
    if np.isfinite(weights).any():
        weights = np.exp(weights - weights.max())
        weights = weights / weights.sum()
    else:  # none survives (or none was tried)
        weights = np.zeros(len(hyps))
    top = max(weights) if len(weights) else 0.0
    for h, w in zip(hyps, weights):
        if h["dropped"] is None and w < top / o.bayes_factor:
            h["dropped"] = T - 1
            whys[h["name"]] = "bayes-factor"
            h["reason"] = (("with the magnitudes held static, " if static else "")
                           + f"the data favour another hypothesis by a Bayes factor above {o.bayes_factor:g} "
                           f"(posterior {w:.2g})")
    return weights


def _verdict(hypotheses: tuple[Hypothesis, ...]) -> tuple[str, tuple[str, ...]]:
    """isolated (one survivor), ambiguous (several, best first), or
    unexplained (none: the one that lasted longest)."""
    survivors = sorted((h for h in hypotheses if h.dropped is None), key=lambda h: -h.posterior)
    if len(survivors) == 1:
        return "isolated", (survivors[0].name,)
    if survivors:
        return "ambiguous", tuple(h.name for h in survivors)
    if hypotheses:
        return "unexplained", (max(hypotheses, key=lambda h: (h.dropped, h.posterior)).name,)
    return "unexplained", ()


#: The detail of the Dropped event the online tracking gives when every filter of a hypothesis stopped.
STOPPED = ("every filter of it stopped: far off the data, or another onset of it explained the data "
           "decisively better")


def _ordered(events: list) -> tuple:
    """Events in time order (those without a step first), stable."""
    return tuple(sorted(events, key=lambda e: -1 if e.step is None else e.step))
