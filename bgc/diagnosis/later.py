"""A fault that began after its alarm: a false alarm, then the fault.

The detector's alarm starts the isolation, and a step fault's onsets are
tried around the alarm's change point (a few samples before it to a couple
after). When the alarm was a false one (the detector's budget allows about
one per horizon) and a fault began later, every fault model is fitted from
onsets where there was no fault yet: the one that explains the data best is
named, but dated from the alarm, its magnitude an average over the quiet
samples before its true onset and the samples after it (a burst of noise
four times a sensor's, from 60 samples after a false alarm, was sized 2.9
to 3.7 against the 3.5 to 4.6 of its true onset).

Such a fit leaves residuals that wander after the onset tried (too quiet,
then too large, or of one sign and then the other), which sends the fault to
:func:`bgc.diagnosis.intermittent.revised`; its bank of cubature Kalman
filters there also weighs the fault *persisting* from any sample after the
bank's start (the appearance weighed as a persistent onset, never going
away). :func:`redated` reads that persistent fault's onset posterior (the
bank's forward-backward smoothing, :func:`onset_posterior`): when the bank
finds the persistent fault likelier than the static posterior did over the
onsets tried, and puts at least :data:`LATER` of its onset's probability
after the latest onset tried (the bank run from there alone: its evidence
over the whole bank's), and the nominal observer's residuals pass the fit
test from the sample after the alarm to that onset's interval (the alarm an
excursion of one window, not a fault present until then: one present, gone
and back is the intermittent trial's), the fault's static posterior is computed again
over the onsets the bank points to (its central interval of probability
0.99, every sample of it, refined sample by sample), and it replaces the
hypothesis's when its evidence is the larger: its onset, magnitude,
interval, residuals and fit test are then those of the fault from that
onset (it must pass that test, and be decisively likelier than no fault at
all, by the Bayes factor the verdict uses, or the hypothesis stays as it
was). A :class:`~bgc.events.Redated` event says so, the alarm before it
named a false one.

Only step faults (those :func:`bgc.kinds.comes_and_goes` lists) are dated
anew this way: a drift's onsets already reach far back from its alarm, and
one that began after a false alarm is not tried later.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .. import events as ev
from ..filters.cubature import NominalTrack
from ..model.protocol import FaultModel
from .onsets import log_prior
from .intermittent import _bank, _evidence, _interval, _smoothed, top_cell
from .static import (StaticJob, kalman_hypothesis, read_alarm, replaced_sensor, stretch_alarm, run_static, static_alarm,
                     static_estimate)
from .values import Hypothesis

__all__ = ["LATER", "MOST", "onset_posterior", "redated"]

#: The share of the persistent fault's onset posterior that must lie after the latest onset tried.
LATER = 0.95

#: At most this many onsets in the new static posterior's first grid (evenly spread over the interval;
#: the static posterior refines around the likely ones sample by sample).
MOST = 48


def onset_posterior(model: FaultModel, ys, us, track: NominalTrack, start: int, magnitudes, fixed) \
        -> tuple[np.ndarray, float]:
    """Fault model ``model``, persisting once it appeared, appearing at a
    sample from step ``start`` on: per step, the posterior probability that
    it appeared there (zeros before ``start``, and everywhere when no cell
    has a finite likelihood), and the log evidence of that hypothesis
    (:func:`bgc.diagnosis.intermittent._evidence`: the magnitude's uniform
    prior integrated over ``magnitudes``, on the persistent fault's scale).
    Its bank (:func:`bgc.diagnosis.intermittent._bank`) with endless mean
    durations, each magnitude weighed by its likelihood, smoothed backward."""
    T = len(ys)
    lo, hi = (float(v) for v in model.FAULT_PRIOR)
    p = _bank(model, ys, us, track, start, magnitudes, [math.inf], [math.inf], fixed, keep=True)
    evidence = _evidence(np.asarray(magnitudes, dtype=float), p.loglik, lo, hi)
    w = np.exp(p.loglik - top_cell(p.loglik))
    w = np.where(np.isfinite(w), w, 0.0)
    if not w.sum() > 0:
        return np.zeros(T), -math.inf
    _, appear, _ = _smoothed(p, w / w.sum(), start, T)
    total = appear.sum()
    return (appear / total if total > 0 else appear), evidence


def redated(hyps: tuple[Hypothesis, ...], found: dict, r, s, observer: NominalTrack, fixed_of: dict) \
        -> tuple[tuple[Hypothesis, ...], list]:
    """The hypotheses with those of ``found`` (their intermittent trials,
    by name: their banks' persistent reference) that began after every
    onset tried dated anew (module doc); ``fixed_of``: per name, the fault
    model's fixed augmented states the bank ran with. Returns (the
    hypotheses, the :class:`~bgc.events.Redated` events)."""
    out, events = [], []
    for h in hyps:
        i = found.get(h.name)
        new = None if i is None else _later(h, i, r, s, observer, fixed_of[h.name])
        if new is not None:
            events.append(ev.Redated(len(r.time) - 1, h.name, h.onset_step, new.onset_step,
                                     new.static.log_evidence - _static_evidence(h),
                                     None if r.detection is None else r.detection.step))
            h = new
        out.append(h)
    return tuple(out), events


def _static_evidence(h: Hypothesis) -> float:
    """``h``'s static evidence (-inf: none)."""
    return h.static.log_evidence if h.static is not None else -math.inf


def _quiet_before(r, s, observer: NominalTrack, onset: int) -> bool:
    """Whether the nominal observer's residuals pass the fit test (section
    5's windowed Z-test) from the sample after the alarm up to ``onset``:
    the alarm one excursion, the plant healthy until the later onset (a
    fault present before it, gone and back, is the intermittent trial's)."""
    first = (r.detection.step if r.detection is not None else 0) + 1
    if observer.z is None or onset <= first:
        return True
    return read_alarm(observer.z[first:onset], r.outputs, r.present, s.options.rejection, s.options.windows) is None


def _later(h: Hypothesis, i, r, s, observer: NominalTrack, fixed) -> Hypothesis | None:
    """Hypothesis ``h`` from the onsets its bank's persistent fault (of
    intermittent trial ``i``) points to, after every onset it was tried
    from; None when the bank does not point there or the new static
    posterior is not the likelier."""
    before = _static_evidence(h)
    if i.grid is None or not i.persistent_evidence > before:
        return None
    model = s.package.MODELS[h.name]
    tried = h.static.onsets if h.static is not None else h.onset_steps
    after = int(max(tried)) + 1
    T = len(r.ys)
    if after >= T:
        return None
    # the fault persisting from after every onset tried: its share of the persistent fault's posterior (the
    # bank from there, the same grid: a pass over the samples after them alone), and where it appeared
    appear, evidence = onset_posterior(model, r.ys, r.us, observer, after, i.grid, fixed)
    if not evidence - i.persistent_evidence >= math.log(LATER):
        return None
    best, lo, hi = _interval(appear, after, T, 0.99)
    if not _quiet_before(r, s, observer, lo):
        return None
    onsets = np.arange(max(lo - 1, after), min(hi + 2, T))
    if len(onsets) > MOST:
        onsets = np.unique(np.linspace(onsets[0], onsets[-1], MOST).round().astype(int))
    o = s.options
    s.say(f"{h.name}: its fault likelier from later onsets (t = {r.clock.text(r.time[lo])} to "
          f"{r.clock.text(r.time[hi])}); weighing it from there")
    grid = (float(i.grid[0]), float(i.grid[-1]))  # the magnitudes the bank found the fault at
    p = run_static(StaticJob(s.package.__name__, h.name, r.ys, r.us, observer, tuple(int(k) for k in onsets), grid,
                             int(best), o.interval, o.kalman, (), record=True, refine=True,
                             far=(tuple(r.outputs), o.rejection, o.windows)))
    alarm = static_alarm(p, tuple(r.outputs), o)
    if alarm is None:  # and its mean over the whole stretch
        alarm = stretch_alarm(p, tuple(r.outputs), replaced_sensor(model.FAULT["kind"], model.FAULT.get("subject")))
    if not (math.isfinite(p.log_evidence) and p.log_evidence > before) or alarm is not None:
        return None  # not the likelier, or it fails its fit test from there: the hypothesis stays as it was
    # and decisively likelier than no fault at all (weighed as the verdict weighs them, its prior spread over the
    # horizon): a fault from the record's last samples explains nothing, and costs nothing either
    null = float(observer.loglik[T]) if len(observer.loglik) > T else -math.inf
    if not log_prior(s.priors, h.parameter, s.horizon) + p.log_evidence > null + math.log(o.bayes_factor):
        return None
    k = kalman_hypothesis(h.name, h.signatures, s.package, p, None, r.time, r.ys, o, clock=r.clock)
    return replace(h, start_step=k.start_step, onset_steps=k.onset_steps, onset_posterior=k.onset_posterior,
                   y_mean=k.y_mean, y_std=k.y_std, z=k.z, x_mean=k.x_mean, x_std=k.x_std, magnitude=k.magnitude,
                   magnitude_band=k.magnitude_band, log_evidence=p.log_evidence, static=p,
                   static_log_evidence=p.log_evidence, estimate=static_estimate(h.estimate, p), filter_estimate=None,
                   drop=None, static_alarm=None)
