"""One diagnosis from the submodels of a plant split at its sensors (issue 49,
point 4: the thesis's future direction V.2 (ii), reduced-order filters).

``bgc compile --decompose`` (:mod:`bgc.compiler.decompose`) cuts a plant
into submodels, each predicting its own sensors from the plant's inputs and
its neighbours' readings. Given the readings, the submodels are independent,
so a hypothesis is weighed by the product of the submodels' likelihoods,
each given the readings it takes, and a fault changes only the factors of
the submodels it touches (:mod:`bgc.model.joined`):

    log L(H) = log p(y_T | readings, H) + sum over the submodels s not in T of log p(y_s | readings, no fault),

T the submodels that model fault H. It is a composite likelihood, not the
joint one: a reading is data in its own submodel and an input of its
neighbours', so the Bayes factors between hypotheses are the composite's
(a fault touching more submodels collects more factors), and the verdict
rests on the fit tests as much as on them. The diagnosis is the method of
``--filter ckf`` (:mod:`bgc.diagnosis.diagnose`) on these factors:

1. **Track and detect.** The detector (the windowed Z-test, its
   false-alarm probability over all the plant's sensors) runs on the
   normalised residuals of the whole plant's nominal cubature Kalman filter
   (the model without its faults, :attr:`Plan.whole`: one filter, cheap
   beside the submodels' fault models), as the whole plant's diagnosis
   does, so both alarm on the same data at the same sample. A submodel's
   residuals are wider than the whole plant's (it reads its neighbours'
   noisy readings as inputs, and its process noise holds their noise): on
   them alone a fault the whole plant sees can go unseen (the leak of a
   chain of 32 tanks, bench/decomposed_diagnosis.py). Each submodel's
   nominal cubature Kalman filter runs over its data too (its own sensors;
   the readings it takes as inputs held over a sample at the mean of the
   sample's two readings): the weighing's nominal tracks, and the
   detector's residuals when there is no whole plant's package.
2. **Candidates.** The faults that touch the submodel of the sensor that
   alarmed (those that can move it: structurally, no other fault can), each
   tried from the onsets the whole plant's diagnosis tries.
3. **Weigh.** Each candidate's static posterior (onset and magnitude, the
   magnitude shared by every submodel it touches) by cubature Kalman filters
   on its submodels joined (:class:`~bgc.model.joined.Joined`), its evidence
   completed by the nominal likelihood of the others; no fault by the sum of
   the nominal ones. Its consistency test reads its submodels' residuals and
   the untouched submodels' nominal ones: a fault must explain every sensor,
   within every window and over the whole stretch from its onset
   (:func:`stretch_tested`: a submodel's residuals are wide, and a fault
   outside the model that a local one mimics misfits a little at each step).
4. **Verdict**, as the whole plant's (:func:`bgc.diagnosis.weigh.weighed`:
   the Bayes factor, the goodness of fit, the credible set, no fault), and
   the test of the model on the data before the fault
   (:func:`bgc.diagnosis.finish.judged_fit`).

The cost of a hypothesis grows with the submodels it touches, not with the
plant: on a chain of tanks, a pipe touches two one-state submodels whatever
the chain's length.

What it does not do: the qualitative isolation (TRANSCEND's symbols are the
whole plant's; the evidence of every fault touching the alarm decides
instead), the detector's families other than the mean test's, particle
filters, ranking and refining on their grids, models with modes (refused by
the decomposition), the data's events (gaps, held inputs) and summary in
the report, and parallel workers (the hypotheses are weighed one after
another: each is small). A fault of a read sensor other than its bias or
drift (its stuck reading, its noise) is modelled by its own submodel only:
its neighbours count as fault-free, and their residuals enter its
consistency test. At a bias's onset sample a neighbour's held reading
carries half the bias (the mean of the sample's two readings) where its
model applies none.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from statistics import NormalDist

import numpy as np

from .. import events as ev
from ..data.runs import Run, input_columns
from ..data.sampler import Sampler, samples
from ..errors import DataError
from ..filters import cubature as kalman
from ..filters.cubature import NominalTrack
from ..kinds import fault_kind
from ..model.joined import Joined
from ..model.protocol import NOMINAL, Package, nominal_model
from ..data.clock import Clock
from . import static_posterior
from ..filters.residuals import summary
from .detect import Detector, DetectorOptions
from .fit import LEVEL
from .finish import Record, Setting, judged_fit, nominal_evidence, ordered
from .loop import onsets_tried
from .onsets import earlier_onsets
from .options import DiagnosisOptions
from .static import far_off, kalman_hypothesis
from .values import Detection, Diagnosis, Hypothesis, Isolation, StaticPosterior
from .weigh import weighed


@dataclass(frozen=True)
class Part:
    """One submodel as the diagnosis reads it: its ``name``, its generated
    ``package``, the plant's ``inputs`` it reads and the sensors it reads as
    inputs (``read_as``: (sensor, its input's name))."""

    name: str
    package: Package
    inputs: tuple[str, ...]
    read_as: tuple[tuple[str, str], ...] = ()

    @property
    def nominal(self):
        return nominal_model(self.package)


@dataclass(frozen=True)
class Fault:
    """A fault model of the whole plant: its ``name`` (``PARAMETER_KIND``),
    its ``prior`` bounds (the whole model's), the submodels that model it
    (``models``: (part index, the part's fault model's name, sign)) and those
    it can move (``touching``: part indices)."""

    name: str
    parameter: str
    kind: str
    prior: tuple[float, float]
    models: tuple[tuple[int, str, int], ...]
    touching: tuple[int, ...]


@dataclass(frozen=True)
class Plan:
    """A decomposed plant ready to diagnose: its ``model``'s name, its
    ``parts``, its faults by name and each fault's prior probability by
    parameter (``priors``); ``steps``: the model's run length (the
    detector's horizon when the options name none); ``time_unit``: the
    model's (None: none declared), by which a run's times are told absolute
    or not (:class:`~bgc.data.clock.Clock`)."""

    model: str
    parts: tuple[Part, ...]
    faults: Mapping[str, Fault]
    priors: Mapping[str, float]
    steps: int
    time_unit: str | None
    #: the whole plant's nominal package (the model without its faults), whose filter the detector reads;
    #: None: the submodels' filters' residuals side by side instead
    whole: Package | None = None


def plan(decomposed, packages: list[Package], whole: Package | None = None) -> Plan:
    """The :class:`Plan` of a decomposed model (:func:`bgc.pipeline.decompose_model`)
    whose submodels' packages are ``packages`` (in its order), ``whole``
    the whole plant's nominal package (:attr:`Plan.whole`)."""
    d = decomposed.decomposition
    parts = tuple(Part(s.name, p, s.inputs, s.read_as) for s, p in zip(d.submodels, packages))
    index = {s.name: i for i, s in enumerate(d.submodels)}
    bounds = {(f.parameter, f.kind): tuple(float(v) for v in f.prior) for f in decomposed.numerics.faults}
    faults: dict[str, Fault] = {}
    for c in decomposed.model.faults:
        touching = tuple(index[name] for name in d.touching(c.subject))
        for kind in c.kinds:
            name = f"{c.parameter}_{kind}"
            models = []
            for i in touching:
                part = parts[i]
                read = dict(part.read_as)
                if c.target == "sensor" and c.subject in read:  # a neighbour's reading: its input's fault,
                    own = f"{read[c.subject]}{c.parameter[len(c.subject):]}_{kind}"  # of the opposite sign
                    if own in part.package.MODELS:
                        models.append((i, own, -1))
                elif name in part.package.MODELS:
                    models.append((i, name, 1))
            if models and (c.parameter, kind) in bounds:
                faults[name] = Fault(name, c.parameter, kind, bounds[(c.parameter, kind)], tuple(models), touching)
    priors = {c.parameter: c.prior for c in decomposed.model.faults}
    return Plan(decomposed.model.name, parts, faults, priors, int(decomposed.model.settings.steps),
                decomposed.model.settings.time_unit, whole)


# -- the data ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Data:
    """Each part's data on the model's grid: the times, and per part its
    measurements and inputs (steps x columns)."""

    time: np.ndarray
    ys: tuple[np.ndarray, ...]
    us: tuple[np.ndarray, ...]


def held(y: np.ndarray) -> np.ndarray:
    """A reading read as an input: held over the sample that ends at each
    row at the mean of that row's reading and the one before (the first:
    its own), a missing reading replaced by the last one read."""
    y = np.asarray(y, dtype=float).copy()
    finite = np.isfinite(y)
    if not finite.any():
        return y
    last = np.maximum.accumulate(np.where(finite, np.arange(len(y)), -1))
    first = int(np.argmax(finite))
    y = np.where(last >= 0, y[np.maximum(last, 0)], y[first])
    return np.concatenate([y[:1], 0.5 * (y[1:] + y[:-1])])


def _data(run: Run, p: Plan, options: DiagnosisOptions) -> _Data:
    """Each part's measurements and inputs on the model's grid, through the
    :class:`~bgc.data.sampler.Sampler` as the whole plant's diagnosis reads
    them (its gaps, its held inputs)."""
    given = input_columns(run)
    timing = options.input_timing or "end"
    times, ys, us = None, [], []
    for part in p.parts:
        missing = [s for s, _ in part.read_as if s not in run.measurements]
        if missing:
            raise DataError(f"{run.source}: the data have no column y:{missing[0]}, which submodel {part.name} "
                            f"reads as an input", None, "a decomposed diagnosis needs every sensor a submodel reads; "
                            "diagnose the whole plant instead")
        inputs = {u: given[u] for u in part.inputs if u in given}
        for sensor, name in part.read_as:
            reading = held(run.measurements[sensor])
            if not np.isfinite(reading).any():
                raise DataError(f"{run.source}: column y:{sensor}, which submodel {part.name} reads as an input, "
                                "has no reading", None, "a decomposed diagnosis needs every sensor a submodel "
                                "reads; diagnose the whole plant instead")
            # a reading is a measurement at its row's time, whatever the inputs' timing: the mean over the
            # sample that ends at a row, at that row (end), or at the row before, where a start row's value acts
            inputs[name] = np.append(reading[1:], reading[-1]) if timing == "start" else reading
        t, y, u = _sampled(run, part.nominal, inputs, timing, options)
        if times is None:
            times = t
        ys.append(y)
        us.append(u)
    return _Data(times, tuple(ys), tuple(us))


def _sampled(run: Run, nominal, inputs: dict, timing: str, options: DiagnosisOptions):
    """The measurements of ``nominal``'s sensors in ``run`` and the input
    columns ``inputs`` on the model's grid, through the
    :class:`~bgc.data.sampler.Sampler` (its gaps, its held inputs): (times,
    ys, us)."""
    outputs = tuple(nominal.OUTPUTS)
    mine = Run(run.time, inputs, {y: run.measurements[y] for y in outputs if y in run.measurements}, {}, {}, (),
               run.source)
    sampler = Sampler(nominal, tuple(inputs), tuple(mine.measurements), run.source, options.gap, timing)
    rows = list(samples(mine, sampler))
    return (np.array([s.t for s in rows]),
            np.array([s.y for s in rows], dtype=float).reshape(len(rows), len(outputs)),
            np.array([s.u for s in rows], dtype=float).reshape(len(rows), len(nominal.INPUTS)))


def _plant(run: Run, nominal, options: DiagnosisOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The whole plant's measurements and inputs on the model's grid, for its
    nominal filter ``nominal``, as :func:`_data` reads each part's: (times, ys, us)."""
    given = input_columns(run)
    return _sampled(run, nominal, {u: given[u] for u in nominal.INPUTS if u in given},
                    options.input_timing or "end", options)


# -- the nominal tracks side by side -------------------------------------------------------------------------


def stacked(tracks: list[NominalTrack]) -> NominalTrack:
    """The nominal tracks of independent parts as one: states one after the
    other (block-diagonal covariances), log-likelihoods summed, the
    measurements' columns one after the other."""
    T1 = min(len(t.loglik) for t in tracks)
    n = sum(t.mean.shape[1] for t in tracks)
    cov = np.zeros((T1, n, n))
    at = 0
    for t in tracks:
        k = t.mean.shape[1]
        cov[:, at:at + k, at:at + k] = t.cov[:T1]
        at += k

    def side(field: str):
        arrays = [getattr(t, field) for t in tracks]
        if any(a is None for a in arrays):
            return None
        steps = min(len(a) for a in arrays)
        return np.concatenate([np.asarray(a)[:steps].reshape(steps, -1) for a in arrays], axis=1)

    return NominalTrack(np.concatenate([t.mean[:T1] for t in tracks], axis=1), cov,
                        np.sum([t.loglik[:T1] for t in tracks], axis=0), side("y_mean"), side("y_std"), side("z"),
                        side("x_mean"), side("x_std"))


# -- the diagnosis -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _View:
    """The package the weighing reads: the joined models by name."""

    MODELS: Mapping
    __name__: str = "decomposed"


def diagnose(run: Run, p: Plan, options: DiagnosisOptions = DiagnosisOptions(), progress=None,
             every: bool = False) -> Diagnosis:
    """The diagnosis of ``run`` on the decomposed plant ``p`` (module
    docstring). ``every``: weigh every fault of the plant, not only those
    touching the alarm. ``options.horizon``: None for the model's run
    length. The returned :class:`~bgc.diagnosis.values.Diagnosis` lists the
    sensors as the parts predict them, one part after the other."""
    started = time.perf_counter()
    say: Callable[[str], None] = progress or (lambda text: None)
    o = options
    data = _data(run, p, o)
    T = len(data.time)
    clock = Clock.of(data.time, p.time_unit)
    say(f"tracking {len(p.parts)} submodels with their nominal cubature Kalman filters")
    tracks = [kalman.nominal_track(part.nominal, y, u, T) for part, y, u in zip(p.parts, data.ys, data.us)]
    nominal = Joined(f"{p.model}:{NOMINAL}", [part.nominal for part in p.parts], model=p.model)
    whole = stacked(tracks)
    ys, us = np.concatenate(data.ys, axis=1), np.concatenate(data.us, axis=1)
    outputs = tuple(nominal.OUTPUTS)
    present = np.array([y in run.measurements for y in outputs])
    horizon = max(int(round(o.horizon / nominal.DT)) if o.horizon is not None else p.steps, 1)
    z = np.asarray(whole.z, dtype=float)[:T]
    shown = None  # the residuals the report draws under the detector's statistics: its filter's
    if p.whole is not None:  # the detector on the whole plant's nominal filter, as the whole plant's diagnosis
        plant = nominal_model(p.whole)
        times, plant_ys, plant_us = _plant(run, plant, o)
        if len(times) == T and np.array_equal(times, data.time) and set(plant.OUTPUTS) == set(outputs):
            say("watching with the whole plant's nominal cubature Kalman filter")
            plant_track = kalman.nominal_track(plant, plant_ys, plant_us, T)
            column = [list(plant.OUTPUTS).index(y) for y in outputs]  # in the parts' order

            def ordered_as_parts(values):
                return np.asarray(values, dtype=float)[:T][:, column]

            z = ordered_as_parts(plant_track.z)
            shown = (ordered_as_parts(plant_track.y_mean), ordered_as_parts(plant_track.y_std), z)
    detection, statistics, threshold = _detect(z, outputs, present, horizon, o)
    views: dict = {NOMINAL: nominal}
    isolation, hyps, posteriors = None, (), {}
    if detection is not None:
        say(f"alarm at t = {clock.text(data.time[detection.step])} on {detection.sensor}")
        isolation, posteriors, joined = _weigh(p, detection, data, tracks, whole, o, every, say)
        views.update(joined)
        hyps = tuple(kalman_hypothesis(name, (), _View(views), posteriors[name], run, data.time, ys, o, clock=clock)
                     for name in isolation.names)
    record = Record(p.model, data.time, ys, us, outputs, tuple(nominal.STATES), present,
                    np.asarray(whole.y_mean)[:T], np.asarray(whole.y_std)[:T], np.asarray(whole.z)[:T],
                    np.asarray(whole.x_mean)[:T], np.asarray(whole.x_std)[:T], statistics, threshold, detection,
                    isolation, (), None, clock, observer=whole)
    d = _decided(record, Setting(_View(views), p.priors, o, horizon, say), hyps, posteriors, shown)
    return replace(d, seconds=time.perf_counter() - started, submodels=tuple(part.name for part in p.parts))


def _detect(z: np.ndarray, outputs: tuple[str, ...], present: np.ndarray, horizon: int, o: DiagnosisOptions):
    """Step 1's detector over the parts' normalised residuals side by side
    (``z``, steps x sensors): (the first alarm or None, the statistics per
    step and sensor (NaN: none), the threshold)."""
    T = len(z)
    detector = Detector(tuple(y for y, here in zip(outputs, present) if here),
                        DetectorOptions(o.false_alarm, o.windows, horizon, ("mean",)))
    detection = None
    for k in range(T):
        with np.errstate(all="ignore"):
            detection = detector.update(z[k][present])
        if detection is not None:
            earliest = max(detection.step - o.history, 0)
            if detection.onset_step is not None and detection.onset_step < earliest:
                detection = replace(detection, onset_step=earliest)
            break
    statistics = np.full((T, len(outputs)), np.nan)
    rows = np.asarray(detector.statistics, dtype=float).reshape(len(detector.statistics), -1)
    statistics[:len(rows)][:, present] = rows
    return detection, statistics, detector.threshold


def _decided(r: Record, s: Setting, hyps: tuple, posteriors: dict, shown=None) -> Diagnosis:
    """Step 4: the hypotheses weighed and the verdict, and the test of the
    model on the data the verdict says are fault-free, as the whole plant's
    diagnosis decides them (:func:`bgc.diagnosis.finish.finish`), on the
    submodels' nominal filters (``r``). ``shown``: the nominal predictions'
    mean and std and the normalised residuals the diagnosis reports (its
    pictures draw them under the detector's statistics): the whole plant's
    filter's, which the detector read (None: ``r``'s)."""
    T = len(r.time)
    y_mean, y_std, z = shown if shown is not None else (r.y_mean, r.y_std, r.z)
    common = dict(model=r.model, time=r.time, outputs=r.outputs, states=r.states, nominal_y_mean=y_mean,
                  nominal_y_std=y_std, nominal_z=z, nominal_x_mean=r.x_mean, nominal_x_std=r.x_std,
                  statistics=r.statistics, threshold=r.threshold, options=s.options, data=None, seconds=0.0,
                  clock=r.clock)
    if r.detection is None:
        verdict, candidates, judged, fitted = judged_fit(r, s, (), "no fault", (), None, r.observer)
        return Diagnosis(verdict=verdict, detection=None, onset_step=None, symbols=(), refuted=(), hypotheses=(),
                         candidates=candidates, events=ordered(judged + [ev.Decided(T - 1, verdict, candidates)]),
                         fit=fitted, **common)
    null = nominal_evidence(r, s, r.observer) if s.options.no_fault else None
    hyps = tuple(stretch_tested(h, posteriors.get(h.name), r.outputs) for h in hyps)
    hyps, verdict, candidates, events = weighed(hyps, posteriors, r, s, null)
    best_onset = None if verdict == "no fault" else \
        next((h.onset_step for h in hyps if candidates and h.name == candidates[0]), r.detection.onset_step)
    verdict, candidates, judged, fitted = judged_fit(r, s, hyps, verdict, candidates, best_onset, r.observer,
                                                     quieter=False)  # a submodel's residuals are narrow by design
    events = events + judged + [ev.Decided(T - 1, verdict, candidates)]
    s.say(f"done: {verdict}" + (f", {', '.join(candidates)}" if candidates else ""))
    return Diagnosis(verdict=verdict, detection=r.detection, onset_step=best_onset, symbols=(), refuted=(),
                     hypotheses=hyps, candidates=candidates, events=ordered(events), fit=fitted, **common)


def stretch_tested(h: Hypothesis, p: StaticPosterior | None, outputs: tuple[str, ...],
                   level: float = LEVEL) -> Hypothesis:
    """``h`` (not dropped yet) with a misfit (its ``static_alarm``) when the
    normalised residuals of its static posterior ``p``'s most likely cell,
    over the whole stretch from that cell's onset, have a mean off 0 on some
    sensor: beyond their standard error, their own spread over the square
    root of their count (a t-test), at ``level`` over every sensor (and two
    tests, as the test of the model before a fault counts them,
    :mod:`bgc.diagnosis.fit`). A variance above 1 is noise the model lacks,
    which the test of the verdict's fit says ("mismatch",
    :func:`bgc.diagnosis.finish.noise_misfit`).

    A submodel's residuals are narrow (its process noise holds its
    neighbours' readings' noise, and the filter predicts wider than the
    data spread), so the windowed test of the whole plant's diagnosis,
    built to alarm within a horizon, misses a fault that misfits a little
    at every step: a leak of the middle tank of a chain, which the tank's
    sensor bias mimics in its own submodel, leaves its neighbours' residuals
    5 to 11 of their standard errors off 0 over the stretch, where the true
    fault's stay within 2.6 (chains of 8 and 16 tanks, bench/decomposed_diagnosis.py;
    their lag-1 autocorrelation is -0.06, so the t-test errs on the safe side)."""
    if h.drop is not None or h.static_alarm is not None or p is None or p.residuals is None or p.best is None:
        return h  # one the windowed test dropped already, or without a most likely cell
    z = np.asarray(p.residuals, dtype=float)[int(p.best[0]):]
    summaries = [i for i in summary([z], outputs) if i.variance > 0]
    if not summaries:
        return h
    cut = NormalDist().inv_cdf(1.0 - level / (2 * len(summaries)) / 2)
    t = {i.sensor: abs(i.mean) / math.sqrt(i.variance / i.samples) for i in summaries}
    worst = max(summaries, key=lambda i: t[i.sensor])
    if t[worst.sensor] <= cut:
        return h
    return replace(h, static_alarm=Detection(len(z) - 1, worst.sensor, worst.samples, t[worst.sensor], cut, None,
                                             "mean"))


def _weigh(p: Plan, detection, data: _Data, tracks, whole: NominalTrack, o: DiagnosisOptions, every: bool, say):
    """Steps 2 and 3: the candidates, their onsets, each one's static
    posterior on its submodels joined, completed to the whole plant.
    Returns (the isolation, the posteriors by name, the joined models by name)."""
    T = len(data.time)
    owner = {y: i for i, part in enumerate(p.parts) for y in part.nominal.OUTPUTS}
    alarmed = owner[detection.sensor]
    names = sorted(f.name for f in p.faults.values() if every or alarmed in f.touching)
    names = [n for n in names if not fault_kind(p.faults[n].kind).discrete]
    reach, _, kalman_reach, _, kalman_onsets = onsets_tried(o, detection, T)
    drifts = {n: fault_kind(p.faults[n].kind).searched_back for n in names}
    nulls = [float(t.loglik[T]) for t in tracks]
    say(f"weighing {len(names)} fault hypotheses ({', '.join(names)}) on the submodels each touches")
    posteriors, joined = {}, {}
    for name in names:
        f = p.faults[name]
        members = [i for i, _, _ in f.models]
        model = Joined(name, [p.parts[i].package.MODELS[m] for i, m, _ in f.models], [s for _, _, s in f.models],
                       _fault(p, f), f.prior, model=p.model)
        ys = np.concatenate([data.ys[i] for i in members], axis=1)
        us = np.concatenate([data.us[i] for i in members], axis=1)
        track = stacked([tracks[i] for i in members])
        tried = kalman_onsets[drifts[name]]
        started = time.perf_counter()
        post = static_posterior.static_posterior(
            model, ys, us, track, tuple(tried), f.prior, min(tried), o.interval, o.kalman,
            earlier_onsets(kalman_reach, tried, o.search), True, far_off(tuple(model.OUTPUTS), o.rejection, o.windows))
        post = static_posterior.record_path(model, ys, us, track, post)
        others = sum(v for i, v in enumerate(nulls) if i not in members)
        posteriors[name] = _completed(post, members, p, whole, others, time.perf_counter() - started)
        joined[name] = model
    isolation = Isolation(detection.onset_step, (), (), (), {n: [] for n in names}, names, drifts, {}, reach,
                          kalman_onsets, kalman_reach)
    return isolation, posteriors, joined


def _columns(p: Plan, members: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The stacked columns of the sensors and of the physical states of the parts ``members``, in their order."""
    n_y = [len(part.nominal.OUTPUTS) for part in p.parts]
    n_x = [len(part.nominal.STATES) for part in p.parts]
    y_at, x_at = np.cumsum([0] + n_y), np.cumsum([0] + n_x)
    return (np.concatenate([np.arange(y_at[i], y_at[i] + n_y[i]) for i in members]),
            np.concatenate([np.arange(x_at[i], x_at[i] + n_x[i]) for i in members]))


def _completed(post: StaticPosterior, members: list[int], p: Plan, whole: NominalTrack, others: float,
               seconds: float) -> StaticPosterior:
    """A static posterior on the parts ``members`` made the whole plant's:
    its likelihoods times the nominal likelihood of the other parts
    (``others``, their log), its residuals and its filter's predictions and
    estimates the nominal filters' on the other parts' sensors and states
    (fault-free there, by the hypothesis)."""
    y_cols, x_cols = _columns(p, members)
    T = len(whole.z)
    n_x = whole.mean.shape[1]

    def sensors(mine, nominal):
        out = np.array(nominal[:T], dtype=float)
        out[:, y_cols] = mine
        return out

    residuals = None if post.residuals is None else sensors(post.residuals, whole.z)
    path = post.path
    if path is not None:
        def states(mine, nominal):  # (T, 1, n_joined): the joined physical rows, then the fault rows
            out = np.empty((T, 1, n_x + mine.shape[2] - len(x_cols)))
            out[:, 0, :n_x] = np.asarray(nominal, dtype=float)[:T]
            out[:, 0, x_cols] = mine[:, 0, :len(x_cols)]
            out[:, 0, n_x:] = mine[:, 0, len(x_cols):]
            return out

        path = replace(path, loglik=path.loglik + others, z=sensors(path.z[:, 0], whole.z)[:, None],
                       y_mean=sensors(path.y_mean[:, 0], whole.y_mean)[:, None],
                       y_std=sensors(path.y_std[:, 0], whole.y_std)[:, None],
                       x_mean=states(path.x_mean, whole.x_mean), x_std=states(path.x_std, whole.x_std))
    return replace(post, loglik=post.loglik + others, log_evidence=post.log_evidence + others, residuals=residuals,
                   path=path, seconds=seconds)


def _fault(p: Plan, f: Fault) -> dict:
    """The whole plant's ``FAULT`` of ``f``: its holding part's, under the whole plant's name."""
    i, m, sign = next((x for x in f.models if x[2] > 0), f.models[0])
    fault = dict(p.parts[i].package.MODELS[m].FAULT)
    if sign < 0:
        fault["target"] = "sensor"
    fault["parameter"] = f.parameter
    return fault
