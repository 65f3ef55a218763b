"""The end of a diagnosis (steps 4 to 8 of :mod:`bgc.diagnosis.diagnose`),
as values: :func:`finish` takes the loop's :class:`Record` (what the end
needs of the data and of the nominal observer) and its :class:`Setting`
(the package, priors and options), and gives the :class:`Diagnosis`. Its
parts take hypotheses (frozen :class:`~bgc.diagnosis.values.Hypothesis`
values, each with its :class:`~bgc.diagnosis.values.Drop` or none) and
return them with the events they decided: the hypotheses' filters over the
record and their static posteriors (:func:`tracked`), the fault models the
symbols ruled out (:func:`rechecked`), then the weighing, ranking, refining
and the verdict (:func:`bgc.diagnosis.weigh.weighed`). The work on worker
processes is one parallel map per round (:func:`bgc.diagnosis.parallel.parallel_map`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from ..data.runs import Run
from ..data.sampler import DataSummary
from ..filters import cubature as kalman
from ..filters.residuals import failures, finding, summary
from ..kinds import fault_kind
from ..model.protocol import Package, nominal_model
from ..data.clock import Clock
from .. import events as ev
from .estimate import estimate_of
from .fit import LEAST, changed, fit, misfit_before, residual_sd, timing_told
from .hypothesis import hypothesis_job, log_density, run_job
from .intermittent import revised
from .onsets import earlier_onsets, onset_weights
from .options import DiagnosisOptions
from .parallel import parallel_map
from .static import StaticJob, kalman_hypotheses, read_alarm, replaced_sensor, run_statics, static_alarm
from .static_posterior import EDGE, EXTEND
from .values import Detection, Diagnosis, Drop, Fit, Hypothesis, Isolation, StaticPosterior
from .weigh import weighed


@dataclass(frozen=True, slots=True)
class Record:
    """What the end of a diagnosis needs of the loop (``Loop.record``):
    the data on the model's grid (``time``, ``ys``, ``us``; ``present``: per
    sensor, whether the data have a column for it), the nominal observer's
    predicted measurements, residuals and state estimates per step, the
    detector's statistics (steps x outputs, NaN where none) and threshold,
    the alarm and the isolation (None before them), the loop's events, how
    the data met the model (``data``), the nominal clouds of the last
    ``history`` steps before the alarm (``clouds``), the cubature Kalman
    observer's track (``observer``, method ``ckf``) and, for the hypotheses
    tracked online, their trackers' results (``tracked``: name -> (per onset
    its filter's output, the trace of the best running evidence)).
    ``clock``: how the record's times are written in words (a
    :class:`~bgc.data.clock.Clock` of ``time`` and the model's time
    unit), by every sentence the end makes and by the diagnosis."""

    model: str
    time: np.ndarray
    ys: np.ndarray
    us: np.ndarray
    outputs: tuple[str, ...]
    states: tuple[str, ...]
    present: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    z: np.ndarray
    x_mean: np.ndarray
    x_std: np.ndarray
    statistics: np.ndarray
    threshold: float
    detection: Detection | None
    isolation: Isolation | None
    events: tuple
    data: DataSummary | None
    clock: Clock
    clouds: Mapping = field(default_factory=dict)
    observer: kalman.NominalTrack | None = None
    tracked: Mapping = field(default_factory=dict)
    #: steps (first, end) the test of the model's fit leaves out: a false alarm's window (None: none)
    excused: tuple[int, int] | None = None


@dataclass(frozen=True, slots=True)
class Setting:
    """What the end takes of the diagnoser's configuration: the generated
    package, each fault candidate's prior, the options, the detector's
    horizon in steps, ``say(text)``, told what is being done, and
    ``intermittent``: whether faults that come and go are tried
    (:func:`~bgc.diagnosis.intermittent.revised`; off for a diagnosis on a
    reading of hidden modes that may not be the one chosen)."""

    package: Package
    priors: Mapping[str, float]
    options: DiagnosisOptions
    horizon: int
    say: Callable[[str], None] = field(default=lambda text: None, compare=False)
    intermittent: bool = True

    @property
    def ckf(self) -> bool:
        """Whether the hypotheses are weighed by cubature Kalman filters alone (``--filter ckf``)."""
        return self.options.filter == "ckf"


def finish(r: Record, s: Setting, truth: Run | None = None, memo: dict | None = None) -> Diagnosis:
    """The diagnosis of record ``r`` (``truth``: the run, when it records
    the true fault); its ``seconds`` are the caller's to fill in. ``memo``:
    where steps 4 to 6b of the same record and setting, but for
    ``intermittent``, which they do not read, were kept (the hypotheses
    tracked and rechecked), taken from there, else kept there."""
    T = len(r.time)
    common = dict(model=r.model, time=r.time, outputs=r.outputs, states=r.states, nominal_y_mean=r.y_mean,
                  nominal_y_std=r.y_std, nominal_z=r.z, nominal_x_mean=r.x_mean, nominal_x_std=r.x_std,
                  statistics=r.statistics, threshold=r.threshold, options=s.options, data=r.data, seconds=0.0,
                  clock=r.clock)
    # a sensor never read (its column empty or nan throughout) tells nothing: the diagnosis says so
    silent = [ev.SensorSilent(y) for j, y in enumerate(r.outputs)
              if r.present[j] and not np.isfinite(r.ys[:, j]).any()]
    if r.detection is None:
        verdict, candidates, judged, fitted = judged_fit(r, s, (), "no fault", (), None, r.observer)
        events = list(r.events) + silent + judged + [ev.Decided(T - 1, verdict, candidates)]
        return Diagnosis(verdict=verdict, detection=None, onset_step=None, symbols=(), refuted=(), hypotheses=(),
                         candidates=candidates, events=ordered(events), fit=fitted, **common)
    iso = r.isolation
    if memo is not None and "tracked" in memo:
        hyps, posteriors, observer, rescued, more, static = memo["tracked"]
    else:
        hyps, posteriors, observer, rescued = tracked(r, s, truth)
        more, static = rechecked(r, s, truth, hyps, posteriors, observer)
        if memo is not None:
            memo["tracked"] = (hyps, posteriors, observer, rescued, more, static)
    weighing_posteriors = {**posteriors, **static}
    null = nominal_evidence(r, s, observer) if weighing_posteriors and s.options.no_fault else None
    hyps, verdict, candidates, weighing = weighed(hyps + more, weighing_posteriors, r, s, null)
    # no fault holding a share (and the setting's leave): faults that come and go
    if s.intermittent and not any(isinstance(e, ev.NoFault) for e in weighing):
        hyps, verdict, candidates, tried = revised(hyps, verdict, candidates, r, s, observer)
        weighing = redone(weighing, tried, hyps)
    events = list(r.events) + silent + rescued + weighing
    best_onset = None if verdict == "no fault" else \
        next((h.onset_step for h in hyps if candidates and h.name == candidates[0]), iso.onset)
    s.say(f"done: {verdict}" + (f", {', '.join(candidates)}" if candidates else ""))
    events += refined(r.events, candidates, best_onset, T - 1)
    verdict, candidates, judged, fitted = judged_fit(r, s, hyps, verdict, candidates, best_onset,
                                                     observer or r.observer)
    events += judged
    events.append(ev.Decided(T - 1, verdict, candidates))
    final = [e for e in events if not isinstance(e, ev.Stopped)]  # the online drops: decided anew above
    return Diagnosis(verdict=verdict, detection=r.detection, onset_step=best_onset, symbols=iso.symbols,
                     refuted=iso.refuted, hypotheses=hyps, candidates=candidates, events=ordered(final), fit=fitted,
                     **common)


def redone(weighing: list, tried: list, hyps) -> list:
    """The weighing's events and those of the tries of faults that come and
    go (``tried``): a hypothesis dated anew (a ``Redated`` event) is told
    truncated as its new static posterior is, not as its first one was."""
    again = {e.hypothesis for e in tried if isinstance(e, ev.Redated)}
    kept = [e for e in weighing if not (isinstance(e, ev.Truncated) and e.hypothesis in again)]
    return kept + tried + [ev.Truncated(h.name) for h in hyps if h.name in again and h.static.truncated]


def judged_fit(r: Record, s: Setting, hyps, verdict: str, candidates: tuple[str, ...], onset: int | None,
               track: kalman.NominalTrack | None = None, quieter: bool = True):
    """The test of the model on the data the verdict says are fault-free
    (:mod:`bgc.diagnosis.fit`): before the earlier of the change point and
    the onset ``onset`` of the fault named (the change point alone when the
    verdict is unexplained: its closest model explains nothing, though the
    data before its onset are still the fewest that must vouch for the
    model; the whole record without an alarm, or when the verdict after one
    is no fault). A model that
    fails it, or data too short before an alarm to tell, make the verdict
    ``mismatch``, the faults it named kept as possibilities. Returns (the
    verdict, its candidates, the events, the :class:`~bgc.diagnosis.fit.Fit`). ``track``: the nominal
    cubature Kalman filter's, when the diagnosis ran it. ``quieter``: test a plant quieter than its model
    (:func:`quiet_misfit`; not on submodels, whose residuals are narrow by design)."""
    T = len(r.time)
    quiet = r.detection is None or verdict == "no fault"  # no fault, after an alarm too: the whole record
    if quiet:
        end = T
    else:  # an unexplained verdict's closest model explains nothing: its onset does not end the stretch
        named = onset if verdict in ("isolated", "ambiguous") else None
        end = min(k for k in (r.detection.onset_step, named, r.detection.step) if k is not None)
    by = {h.name: h for h in hyps}
    short = not quiet and _too_short(r, by, verdict, candidates, end, onset)
    nominal = nominal_model(s.package)
    fitted = fit(nominal, r.ys, r.us, r.outputs, end, short, track=track, skip=r.excused)
    if verdict == "unexplained" and fitted.fits and end < T:
        fitted, end = unchanged_misfit(r, nominal, fitted, end, track)
    if fitted.fits and verdict in ("isolated", "ambiguous") and candidates and candidates[0] in by:
        fitted = noise_misfit(fitted, by[candidates[0]], r.outputs, residual_sd(nominal))
        if quieter and fitted.fits:
            fitted, candidates = quiet_misfit(fitted, by[candidates[0]], hyps, candidates, r, s, nominal)
    # an alarm, or a misfit, that the inputs read with the other timing explain (docs/format.md, section 9)
    timing = None if r.data is None or (fitted.fits and r.detection is None) else timing_told(
        nominal, r.ys, r.us, r.outputs,
        [j for j, (_, where) in enumerate(r.data.inputs) if where == "data"], r.data.timing,
        factor=s.options.bayes_factor, track=track)
    if timing is not None and not timing[1] and fitted.fits:
        timing = None  # likelier read the other way but not fitted: a fault's effects that begin at an input's
        # change (a stuck switch at a command) look so too, and the verdict's own stretch fits: it stands
    if fitted.fits and timing is None:
        return verdict, candidates, [], fitted
    possible = candidates if verdict in ("isolated", "ambiguous") else ()
    parameters = [by[n].parameter for n in possible if n in by and by[n].estimate.target == "parameter"]
    estimate = _to_calibrate(s.package, parameters, short or "mean" in fitted.failed)
    event = ev.Mismatched(T - 1, max(end - 1, 0), fitted.findings, short, LEAST, possible, estimate,
                          *(timing or (None, False, 0.0)))
    s.say("the model does not fit these data" + ("" if not possible else f"; possibly {', '.join(possible)}"))
    return "mismatch", possible, [event], fitted


def _to_calibrate(package, parameters: list, every: bool) -> tuple[str, ...]:
    """What a calibration should estimate (``bgc calibrate --estimate``'s
    words): the noise, the ``parameters`` of the faults kept as
    possibilities, or, with none and ``every`` (a misfit of the residuals'
    mean, or too few data to tell), every parameter a fault is declared on."""
    if not parameters and every:
        parameters = [m.FAULT["parameter"] for m in package.MODELS.values()
                      if getattr(m, "FAULT", None) and m.FAULT.get("target") == "parameter"]
    return tuple(dict.fromkeys(["noise", *parameters]))


def misfit_event(package, T: int, fitted: Fit, span: tuple | None = None) -> ev.Mismatched:
    """A record of ``T`` steps that fails the test of the model's fit
    (``fitted``) with no fault in view (a monitor's watching test,
    :meth:`bgc.diagnosis.diagnoser.Diagnoser._misfit`): its
    :class:`~bgc.events.Mismatched`, what to calibrate as
    :func:`judged_fit` would say of the same record; ``span``: the
    record's first and last times and its samples (it is then halved)."""
    return ev.Mismatched(T - 1, T - 1, fitted.findings, False, LEAST, (),
                         _to_calibrate(package, [], "mean" in fitted.failed), span=span)


def dated_misfit(e: ev.Mismatched, time_of) -> ev.Mismatched:
    """Misfit ``e`` said as the data came (a diagnoser's watching test, a
    monitor's checkpoint), with the time it was said and the times of the
    data it was said on (``time_of``: the diagnoser's then): its sentence and
    time stay right once the record forgets them."""
    first, last, count = e.span if e.span is not None else (time_of(0), time_of(e.last), e.last + 1)
    return replace(e, said=float(time_of(e.step)), span=(float(first), float(last), int(count)))


def forgotten_misfits(said, d: Diagnosis) -> list[ev.Mismatched]:
    """The misfits ``said`` as the data came (:func:`dated_misfit`) on data
    the record of diagnosis ``d`` no longer holds (from before its first
    step): those its events are led by. Those said on data it still holds
    are its own test's to say again."""
    first = float(d.time[0]) if len(d.time) else math.inf
    return [e for e in said if e.span[0] < first]


def with_misfits_said(d: Diagnosis, said) -> Diagnosis:
    """Diagnosis ``d`` with the misfits ``said`` as the data came on data
    its record forgot since (:func:`forgotten_misfits`) leading its events;
    and a verdict that names faults made ``mismatch``, the faults kept as
    possibilities, when one of those misfits was said on data most of which
    precede the fault's onset (its span's first half, at least): the model
    was found not to fit the plant before the fault, on data the end's test
    of the fit before the onset no longer reads (a record bounded while
    watching keeps its last part only). A fault over less than half of those
    data would have had to move them twice as far as their misfit, within
    the detector's reach, and it raised no alarm before the misfit was
    said. Only a misfit said on data that reach into the record kept
    counts so (a halving's test, a checkpoint's since): one said long before
    (a monitor that ran on for months) is in the events, the end's test on
    the newer data is the verdict's. The last such misfit carries the
    possibilities."""
    lead = forgotten_misfits(said, d)
    if not lead:
        return d
    verdict, events = d.verdict, list(d.events)
    if d.verdict in ("isolated", "ambiguous") and d.onset_step is not None:
        onset = float(d.time[min(d.onset_step, len(d.time) - 1)])
        first = float(d.time[0])  # a misfit said on data that reach into the record kept: not one long gone
        before = [i for i, e in enumerate(lead)
                  if onset - e.span[0] >= 0.5 * (e.span[1] - e.span[0]) and e.span[1] >= first]
        if before:
            verdict = "mismatch"
            lead[before[-1]] = replace(lead[before[-1]], possible=tuple(d.candidates))
            events = [replace(e, verdict=verdict) if isinstance(e, ev.Decided) else e for e in events]
    return replace(d, verdict=verdict, events=(*lead, *events))


def _too_short(r: Record, by: dict, verdict: str, candidates: tuple[str, ...], end: int, onset: int | None) -> bool:
    """Whether fewer than LEAST samples come before the fault's onset (the
    earlier of ``end``, the stretch tested's, and ``onset``; an unexplained
    verdict's closest onset too: the change it hints at may have begun
    there). A drift's count to the detector's change point (its own onset,
    weakly told by the data, may lie far before it and the truth), unless
    the drift named has its onset within the first LEAST samples: a drift
    since the data's start is what a model that does not fit looks like,
    and the stretch tested ends at its onset (an unexplained verdict's ends
    at the change point, whatever its closest model's onset)."""
    drifts = bool(candidates) and candidates[0] in by and fault_kind(by[candidates[0]].kind).drifts
    first = min(k for k in (end, onset) if k is not None)
    if drifts and (first >= LEAST or verdict == "unexplained"):
        first = r.detection.onset_step
    return first is not None and first < LEAST


def unchanged_misfit(r: Record, nominal, fitted: Fit, end: int,
                     track: kalman.NominalTrack | None) -> tuple[Fit, int]:
    """An unexplained alarm that saw no change: the whole record fails the
    test of the model, no sensor's residuals differ after the alarm's
    change point ``end`` from before it beyond chance
    (:func:`bgc.diagnosis.fit.changed`), and the residuals before it are
    likelier under the distribution of those after it than under the model
    (:func:`bgc.diagnosis.fit.misfit_before` positive: evidence of no change,
    not only no evidence of one, which a few samples before the change point
    cannot give: a fault outside the model from the 15th sample, f6's noise
    2.5 to 3 times its own added, passes the change test). A fault is a
    change; residuals as wide, or as far off, before the change point as
    after it are a model that does not fit from the start, the stretch
    before the change point too short to show it (a plant 1.5 times noisier
    than its model whose pooled test alarmed after 16 samples). Returns (the
    whole record's fit, with that said and ``unchanged`` set, and its end)
    then, else (``fitted``, ``end``) as they were. ``nominal``: the
    generated nominal model."""
    T = len(r.time)
    if track is None or track.z is None or len(track.z) < T:
        track = kalman.nominal_track(nominal, r.ys, r.us, T)
    whole = fit(nominal, r.ys, r.us, r.outputs, T, track=track, skip=r.excused)
    if whole.fits:
        return fitted, end
    z = np.array(track.z, dtype=float)[:T].reshape(T, len(r.outputs))
    if r.excused is not None:
        z[r.excused[0]:r.excused[1]] = np.nan
    if changed(z, end, r.outputs) or not misfit_before(z, end) > 0:
        return fitted, end
    said = (f"no sensor's residuals changed at the alarm's change point (t = {r.clock.text(r.time[end])}) beyond "
            "chance, as wide and as far off before it as after: the alarm saw the misfit, not a fault that began "
            "there")
    return replace(whole, findings=whole.findings + (said,), unchanged=True), T


def noise_misfit(fitted: Fit, h: Hypothesis, outputs: tuple[str, ...], spread=None) -> Fit:
    """``fitted`` with the test of the named fault's own residuals after its
    onset (its static posterior's most likely cell, :mod:`bgc.diagnosis.fit`'s
    variance test, a variance above 1 only): a fault model explains a change
    of what the sensors read, never noise the model lacks; a plant noisier
    than its model, whose alarm came late, leaves the named fault's
    residuals too wide (a variance of 2.2 for sensors 1.5 times noisier),
    while the data before the onset were too few to show it. Its findings
    are added to the fit's: the verdict is ``mismatch``. ``spread``: a
    calibrated model's allowance (:func:`bgc.diagnosis.fit.residual_sd`)."""
    p = h.static
    if h.intermittent is not None:  # a fault that comes and goes: its residuals switched at its spans
        z = np.asarray(h.intermittent.z, dtype=float)[h.intermittent.spans[0].on:]
    elif p is None or p.residuals is None or p.best is None:
        return fitted
    else:
        z = np.asarray(p.residuals, dtype=float)[int(p.best[0]):]
    summaries = summary([z], outputs)
    wide = [(i, test) for i, test in failures(summaries, fitted.level, correlation=False, narrower=False,
                                              spread=spread) if test == "variance"]
    if not wide:
        return fitted
    said = tuple(f"with {h.name}, {finding(i, test)}" for i, test in wide)
    return replace(fitted, findings=fitted.findings + said, failed=fitted.failed + tuple(t for _, t in wide))


def quiet_misfit(fitted: Fit, h: Hypothesis, hyps, candidates: tuple[str, ...], r: Record, s: Setting,
                 nominal) -> tuple[Fit, tuple[str, ...]]:
    """``fitted`` and ``candidates`` with the test of a plant quieter than its
    model: the named fault ``h``'s residuals after its onset (its static
    posterior's most likely cell) narrower than the model's noise on some
    sensor (the variance test below 1, at the fit's level, a calibrated
    model's allowance added as :func:`noise_misfit` adds it), and a rival
    that passes the consistency test with its magnitude held static (a
    candidate, or dropped by the Bayes factor alone) whose residuals are smaller (the sum of their squares, over the
    steps both have from the later onset on). The likelihood of a fault
    model is its residuals' fit and the spread it predicts; ``h`` wins by
    the spread alone, a spread these data do not have: its parameter makes
    a sensor's predicted spread smaller (F12 = (P1 - P2)/R12 reads the
    levels' process noise less as R12 grows). On the two tanks without
    process noise (measurement noise 1.3 times the model's) every R10 and
    R20 drift was "isolated: R12_incipient", posterior 1. Then the ranking
    rests on noise the model states wrongly: the verdict is ``mismatch``,
    ``h`` and the rivals that fit better the possibilities, and the user is
    told to calibrate the noise. Not for a model with modes (its filters
    spread their predictions wider across switches on purpose)."""
    kinds = getattr(nominal, "STATE_KINDS", ())
    p = h.static
    if "mode" in kinds or p is None or p.residuals is None or p.best is None or h.intermittent is not None:
        return fitted, candidates
    start = int(p.best[0])
    z = np.asarray(p.residuals, dtype=float)
    # a sensor whose reading the named fault replaces (a stuck one: its residuals the reading less the value it
    # holds, 0 once frozen) is narrow by the fault itself, not by a quieter plant
    replaced = replaced_sensor(h.kind, h.estimate.subject)
    narrow = [(i, test) for i, test in failures(summary([z[start:]], r.outputs), fitted.level, correlation=False,
                                                spread=residual_sd(nominal))
              if test == "variance" and i.variance < 1.0 and i.sensor != replaced]
    if not narrow:
        return fitted, candidates
    better = []
    for g in hyps:
        q = g.static
        if g.name == h.name or q is None or q.residuals is None or q.best is None or g.intermittent is not None \
                or not (g.drop is None or g.drop.code == "bayes-factor") \
                or static_alarm(q, r.outputs, s.options) is not None:
            continue
        w = np.asarray(q.residuals, dtype=float)
        k = max(start, int(q.best[0]))
        both = np.isfinite(z[k:]) & np.isfinite(w[k:])
        mine, theirs = float(np.sum(z[k:][both] ** 2)), float(np.sum(w[k:][both] ** 2))
        if theirs < mine:
            better.append((g.name, theirs, mine, k))
    if not better:
        return fitted, candidates
    # one finding, the named fault's own after its onset ("with NAME ...": output.events.mismatch_sentence)
    said = ("; ".join([f"with {h.name} from its onset (t = {r.clock.text(r.time[start])}), {finding(i, test)}: the "
                       "plant is quieter than the model says" for i, test in narrow]
                      + [f"{name} fits the data better (the sum of its squared residuals {theirs:.1f} against "
                         f"{mine:.1f} from t = {r.clock.text(r.time[k])}) and loses to {h.name} only by the spread the "
                         "model predicts, which these data do not have" for name, theirs, mine, k in better]),)
    rivals = tuple(name for name, *_ in better if name not in candidates)
    return replace(fitted, findings=fitted.findings + said, failed=fitted.failed + ("variance",)), \
        candidates + rivals


def refined(told, candidates, onset: int | None, step: int) -> list:
    """A :class:`~bgc.events.Refined` event when the verdict's onset lies
    outside the onsets its first candidate was tracked from online (the
    events ``told`` so far), so that the events and the verdict tell one story."""
    started = [e.onsets for e in told if isinstance(e, ev.Started) and candidates and e.hypothesis == candidates[0]]
    onsets = started[-1] if started else ()
    if onset is None or not onsets or min(onsets) <= onset <= max(onsets):
        return []
    return [ev.Refined(step, candidates[0], onset, min(onsets), max(onsets))]


def tracked(r: Record, s: Setting, truth: Run | None):
    """Steps 4 to 6: each hypothesis the symbols kept, with its particle
    filters and (``identify = "kalman"``) the static posterior of each one
    its filters keep; or, ``ckf``, its static posterior alone. Returns
    (hypotheses, static posteriors by name, the nominal cubature Kalman
    filter's track when one was computed, the events of a rescue)."""
    iso, o = r.isolation, s.options
    if s.ckf:  # 4-6. every hypothesis with its magnitude held static, by cubature Kalman filters alone
        hyps, posteriors = kalman_hypotheses(iso.names, iso.models, s.package, truth, r.time, r.ys, r.us, r.observer,
                                             iso.kalman_onsets, iso.kalman_reach, iso.drifts, o, s.say, clock=r.clock)
        return hyps, posteriors, r.observer, []
    results, starts_of = _filters(r, s)
    hyps = tuple(_assemble(name, starts_of[name], results, r, s, truth) for name in iso.names)
    if o.identify != "kalman":
        return hyps, {}, None, []
    # 6. each hypothesis its filters keep: its onset and magnitude with the magnitude held static, by cubature
    # Kalman filters on a grid of onsets and magnitudes, from the nominal cubature Kalman filter's state
    observer = _nominal_track(r, s)
    kept = [h for h in hyps if h.drop is None]
    again = [h for h in hyps if _retried(h, kept, results, r)]
    if again:
        s.say(f"testing {', '.join(h.name for h in again)} with the magnitude held static")
    landed = run_statics([_static_job(h, r, s, observer) for h in kept + again], o.workers)
    posteriors = {h.name: p for h, p in zip(kept, landed)}
    hyps, rescued, events = _rescued(hyps, dict(zip((h.name for h in again), landed[len(kept):])), r, s)
    return hyps, {**posteriors, **rescued}, observer, events


def _filters(r: Record, s: Setting) -> tuple[dict, dict]:
    """Every hypothesis's particle filters over the record (those the loop
    tracked online are done; the others, and a drift's earlier onsets, run
    in rounds on ``workers`` processes), each onset's evidence over a common
    span: (outputs by (name, onset), onsets tried by name)."""
    iso, o, T = r.isolation, s.options, len(r.time)
    starts_of = {name: list(iso.starts_of[name]) for name in iso.names}
    s.say(f"tracking {len(iso.names)} fault hypotheses ({', '.join(iso.names)}) from "
          f"{sum(len(starts_of[n]) for n in iso.names)} onsets and hypotheses "
          f"(t = {r.clock.text(r.time[min((min(v) for v in starts_of.values()), default=iso.onset)])} to "
          f"{r.clock.text(r.time[r.detection.step])})")
    density = log_density(r.z, r.y_std)  # the nominal observer's, per step
    results: dict[tuple[str, int], dict] = {}
    best_of: dict[str, np.ndarray] = {}  # per hypothesis and step, the best running evidence over [0, step]
    batches = {name: starts_of[name] for name in iso.names}
    if r.tracked:  # tracked online: their first batches are done
        taken = {name: _arrived(name, batches[name], *r.tracked[name], starts_of, results, best_of, density, r, s)
                 for name in iso.names}
        batches = {name: more for name, more in taken.items() if more}
    while batches:  # a round of batches (the longest first), then the earlier onsets they ask for
        names = sorted(batches, key=lambda name: -sum(T - k for k in batches[name]))
        jobs = [hypothesis_job(name, batches[name], s.package, r.clouds, r.ys, r.us, density, r.outputs, o,
                               s.horizon, best_of.get(name)) for name in names]
        landed = parallel_map(run_job, jobs, o.workers)
        taken = {name: _arrived(name, batches[name], res, trace, starts_of, results, best_of, density, r, s)
                 for name, (res, trace) in zip(names, landed)}
        batches = {name: more for name, more in taken.items() if more}
    first = min((min(v) for v in starts_of.values()), default=iso.onset)  # none: a frozen sensor not declared
    for out in results.values():  # the common span starts at `first`
        out["evidence"] -= float(density[:first].sum())
    return results, starts_of


def _arrived(name: str, batch: list[int], res: dict, trace: np.ndarray, starts_of: dict, results: dict,
             best_of: dict, density: np.ndarray, r: Record, s: Setting) -> list[int]:
    """Take a batch of hypothesis ``name``'s onsets (``res``: per onset,
    counted from the batch's earliest, its filter's output; ``trace``: the
    best running evidence per step) into ``results`` and ``best_of``;
    return the earlier onsets to try next (none: done). A drift whose
    onsets' posterior piles up at the earliest one tried began earlier: with
    ``identify = "filter"`` its grid is extended back by ``search`` steps
    (up to ``history`` before the alarm; the Kalman filters reach back on
    their own)."""
    iso, o = r.isolation, s.options
    f = min(batch)
    before = float(density[:f].sum())  # the nominal observer's densities before the batch
    for rel, out in res.items():
        out["from"] = f
        out["evidence"] += before
        results[(name, rel + f)] = out
    full = np.full(len(r.time), -math.inf)
    full[f:] = trace + before
    best_of[name] = np.maximum(best_of.get(name, full), full)
    tried = starts_of[name]
    more = next(iter(earlier_onsets(iso.reach, tried, o.search)), ())
    if not (iso.drifts[name] and more) or o.identify == "kalman":
        return []
    w, log_evidence = onset_weights(tried, [results[(name, k)]["evidence"] for k in tried])
    if not (math.isfinite(log_evidence) and w[:EDGE].sum() >= EXTEND):
        return []
    starts_of[name] = sorted([*more, *tried])
    s.say(f"looking for earlier onsets of {name}")
    return list(more)


def _assemble(name: str, starts: list[int], results: dict, r: Record, s: Setting, truth: Run | None) -> Hypothesis:
    """Hypothesis ``name`` from its filters' outputs: its most probable
    onset, its drop (its best onset's filter failed its test:
    ``inconsistent``; every onset pruned: ``pruned``), its onset posterior,
    evidence and estimate."""
    module = s.package.MODELS[name]
    evidence = np.array([results[(name, start)]["evidence"] for start in starts])  # stopped, pruned: -inf
    every = ""
    if np.isfinite(evidence).any():
        start = starts[int(np.argmax(evidence))]
    else:  # every onset's filter was stopped or pruned: dropped when the last one was
        start = max(starts, key=lambda k: (results[(name, k)]["last"] >= 0, k + results[(name, k)]["last"],
                                           results[(name, k)]["partial"]))
        every = f", from every onset tried ({len(starts)})" if len(starts) > 1 else ""
    out = results[(name, start)]
    drop = None
    if out["rejected"] is not None:  # the best onset's filter failed its test
        k, alarm = out["rejected"]
        drop = Drop("inconsistent", start + k,
                    f"its residual of {alarm.sensor} over {alarm.window} sample(s) reached {alarm.statistic:.1f} "
                    f"(threshold {alarm.threshold:.1f})" + every)
    elif not np.isfinite(evidence).any():  # pruned onsets only (a filter never started)
        drop = Drop("pruned", start + max(out["last"], 0),
                    "another onset of it explained the data decisively better, and that one failed" + every)
    weights, log_evidence = onset_weights(starts, evidence)
    n = len(r.states)
    return Hypothesis(name=name, parameter=module.FAULT["parameter"], kind=module.FAULT["kind"],
                      signatures=tuple(r.isolation.models[name]), start_step=start, onset_steps=tuple(starts),
                      onset_posterior=tuple(float(w) for w in weights), y_mean=out["y_mean"], y_std=out["y_std"],
                      z=(r.ys[start:] - out["y_mean"]) / out["y_std"], x_mean=out["mean"][:, :n],
                      x_std=out["std"][:, :n], magnitude=out["magnitude"], magnitude_band=out["band"], drop=drop,
                      log_evidence=log_evidence,
                      seconds=sum({results[(name, k)]["from"]: results[(name, k)]["seconds"] for k in starts}.values()),
                      estimate=estimate_of(module, out, truth, s.options.interval,
                                           [(w, results[(name, k)]) for w, k in zip(weights, starts)]))


def _static_job(h: Hypothesis, r: Record, s: Setting, observer: kalman.NominalTrack) -> StaticJob:
    """The static posterior's job of hypothesis ``h``: over its Kalman
    filters' onsets (a drift's grid, or the steps near the change point),
    its grid first spanning its particle filters' interval."""
    iso, o = r.isolation, s.options
    tried = iso.kalman_onsets[iso.drifts[h.name]]
    earlier = earlier_onsets(iso.kalman_reach, tried, o.search)
    return StaticJob(s.package.__name__, h.name, r.ys, r.us, observer, tuple(tried), (h.estimate.low, h.estimate.high),
                     h.start_step, o.interval, o.kalman, earlier)


def _retried(h: Hypothesis, kept: list[Hypothesis], results: dict, r: Record) -> bool:
    """Whether hypothesis ``h``, dropped by its particle filters' test, is
    tested again as its fault model states it, the magnitude held static
    (:func:`_rescued`):

    - a drift its particle filters' test dropped while another drift passed
      (one of ``kept``) or none did, whether its filters ran to the end or
      stopped: a
      drift's particle filters start on a coarser grid of onsets than its
      Kalman filters, and reach back no further than ``search`` steps
      before the alarm (``identify = "kalman"``); a drift that began before
      them carries the change it had made by then, which a filter whose
      parameter starts at the model's value cannot follow, and it fails
      wherever they start, while its Kalman filters reach back to its
      onset. Otherwise the drift whose filters happened to pass is named in
      its place (two tanks whose R12 drifted from t = 150, found 50 to 65 s
      later: named R10's drift, posterior 0.999). Where only steps passed,
      the drifts are not tested again (a step that explains a record is no
      drift's stand-in: the drift moves on; and each test costs a static
      posterior);
    - any other whose most probable onset's filter still ran to the end
      (only off the data by the test's margin, not stopped): when no
      hypothesis passed its particle filters' test (``kept`` empty), and
      when others did, one the test dropped (``inconsistent``; a drift not
      where only steps passed, as above). That test
      is one window's statistic past its threshold at the rejection level,
      which the true fault's filters cross too now and then over a long
      record; dropped for good, it left the fault that passed isolated with
      a tight interval, though the data favoured the dropped one by a Bayes
      factor of 1e16 (two tanks, R12 +0.6 from t = 150, bgc's simulation
      of seed 6: R12's filter past its threshold on one sample of F20, 4.0
      against 3.9, 220 samples after the onset; "isolated: R10_abrupt");
    - a step whose every filter stopped, when no step passed and its Kalman
      filters' onsets reach later than its particle filters' (the alarm three
      or more samples after the change point): the change point fell before
      the step's onset and every filter started before it stopped, where its
      Kalman filters try every sample up to the alarm (the circuit's R2 step
      whose alarm came on its first sample, the change point 13 samples
      earlier: "unexplained"). Where a step passed, its onsets were not all
      before the change (each test costs a static posterior: tested wherever
      the filters stopped, bench/retried_steps.py took a quarter more CPU
      for the same verdicts).
    Its static posterior's consistency test and the Bayes factor decide."""
    drifts = r.isolation.drifts
    if h.drop is None:
        return False
    if h.drop.code == "inconsistent" and drifts[h.name] and (not kept or any(drifts[k.name] for k in kept)):
        return True
    if drifts[h.name] and kept and not any(drifts[k.name] for k in kept):
        return False  # only steps passed: a drift is not tested again (above)
    ran = math.isfinite(results[(h.name, h.start_step)]["evidence"])
    if not ran and not drifts[h.name] and h.drop.code == "inconsistent" and all(drifts[k.name] for k in kept):
        # a step whose every filter stopped, no step kept, where its Kalman filters reach later onsets (above)
        return max(r.isolation.kalman_onsets[False]) > max(r.isolation.starts_of[h.name])
    return ran and (not kept or h.drop.code == "inconsistent")


def _rescued(hyps: tuple[Hypothesis, ...], static: Mapping[str, StaticPosterior], r: Record, s: Setting):
    """The hypotheses tested again with the magnitude held static
    (:func:`_retried`; ``static``: their static posteriors by name): each
    whose static posterior passes the consistency test is kept (a
    ``Rescued`` event). Returns (hypotheses, the static posteriors of those
    kept by name, events)."""
    posteriors, events, out = {}, [], []
    for h in hyps:
        p = static.get(h.name)
        if p is not None and math.isfinite(p.log_evidence) and static_alarm(p, r.outputs, s.options) is None:
            posteriors[h.name] = p
            events.append(ev.Rescued(h.name, h.reason, h.dropped_step))
            h = replace(h, drop=None)
        out.append(h)
    return tuple(out), posteriors, events


def rechecked(r: Record, s: Setting, truth: Run | None, hyps: tuple[Hypothesis, ...],
              posteriors: Mapping[str, StaticPosterior], observer: kalman.NominalTrack | None):
    """Step 6b: the fault models the symbols ruled out, weighed too before a
    verdict names a fault (``DiagnosisOptions.recheck``; ``identify =
    "kalman"``, while a hypothesis the symbols kept survives its filters):
    each one's static posterior over its onsets and its whole prior (as
    ``--filter ckf`` weighs every hypothesis), so that its evidence counts
    in the posterior, and its consistency test and the Bayes factor can drop
    it. The symbols are read on a short open-loop window after a late alarm,
    and a slope or a higher-order symbol can mislead where the fault began
    long before it (a slow drift at high noise): a fault model they ruled out
    that explains the data within the Bayes factor is then a candidate (an
    ``Overruled`` event), rather than a verdict resting on the symbols
    alone. Returns (the hypotheses added, each with the signature and symbol
    that ruled it out, and their static posteriors by name)."""
    iso, o = r.isolation, s.options
    untried = iso.untried(s.package)
    if not (o.recheck and o.identify == "kalman" and untried and any(h.drop is None for h in hyps)
            and any(math.isfinite(p.log_evidence) for p in posteriors.values())):
        return (), {}
    if observer is None:  # the particle filters' diagnosis, none of whose hypotheses reached a static posterior
        observer = _nominal_track(r, s)
    models: dict[str, list[str]] = {}
    why_of: dict[str, str] = {}
    for (signature, why), name in zip(iso.refuted, iso.ruled_out):
        models.setdefault(name, []).append(signature)
        why_of.setdefault(name, f"{signature}: {why}")
    drifts = {name: fault_kind(s.package.MODELS[name].FAULT["kind"]).drifts for name in untried}
    s.say(f"weighing the {len(untried)} fault models the symbols ruled out too")
    more, static = kalman_hypotheses(untried, models, s.package, truth, r.time, r.ys, r.us, observer,
                                     iso.kalman_onsets, iso.kalman_reach, drifts, o, s.say, clock=r.clock)
    return tuple(replace(h, ruled_out=why_of[h.name]) for h in more), static


def _nominal_track(r: Record, s: Setting) -> kalman.NominalTrack:
    """The nominal cubature Kalman filter over the whole record (the
    particle filters' diagnosis): the static posteriors start from its state
    at their onsets, and no fault is weighed by its likelihood of the record
    (:func:`nominal_evidence`)."""
    return kalman.nominal_track(nominal_model(s.package), r.ys, r.us, len(r.time))


def nominal_evidence(r: Record, s: Setting, track: kalman.NominalTrack | None) -> float | None:
    """log p(data | no fault): the nominal cubature Kalman filter's
    log-likelihood of the whole record (``track``'s, when it covers it), the
    same filter the static posteriors' cells follow before their onsets, so
    that no fault and the faults are weighed like for like; None where the
    nominal model fails the consistency test the hypotheses pass (the
    windowed Z-test at ``rejection`` over its normalised residuals, the
    sensors the data have, a false alarm's window left out: ``r.excused``):
    the alarm is then no false one, and no fault is not weighed
    (:func:`bgc.diagnosis.weigh.no_fault`)."""
    T = len(r.time)
    if track is None or len(track.loglik) <= T or track.z is None or len(track.z) < T:
        track = kalman.nominal_track(nominal_model(s.package), r.ys, r.us, T)
    value = float(track.loglik[T])
    if not math.isfinite(value):
        return None
    z = np.array(track.z, dtype=float)[:T]
    if r.excused is not None:  # a false alarm's window: an excursion the detector's budget allows
        z[r.excused[0]:r.excused[1]] = np.nan
    if read_alarm(z, r.outputs, r.present, s.options.rejection, s.options.windows) is not None:
        return None
    return value


def ordered(events: list) -> tuple:
    """Events in time order (those without a step first), stable."""
    return tuple(sorted(events, key=lambda e: -1 if e.step is None else e.step))
