"""A diagnosis as ``report.json``, ``report.md`` and ``report.html``: what was
found, when, how large, how sure, and what was ruled out and why.

The sentences and table cells are made once, as plain text, by the helpers
here (:func:`heading`, :func:`verdict_text`, :func:`detection_lines`,
:func:`hypothesis_rows`, ...); text from outside goes through ``quote``:
:func:`bgc.output.markdown.escape` for Markdown, nothing for the HTML page,
whose template escapes every value (:mod:`bgc.output.html`). The run's
times are written as the diagnosis's :class:`~bgc.data.clock.Clock` says
(ISO 8601 timestamps for a run of absolute times), in the sentences and
tables; ``report.json`` keeps them as numbers in the model's time unit
(``settings.absolute_times``: true when they count from 1970-01-01 UTC)."""

from __future__ import annotations

import json
import math
from typing import Any, Callable, Mapping

from ..diagnosis.fit import CHANGE_LEVEL, LEVEL as FIT_LEVEL
from .. import events as ev
from ..kinds import fault_kind, releases
from . import events, html, plots
from .artifacts import manifest
from .labels import Labels
from .markdown import escape


def _same(text: Any) -> str:
    return str(text)


def _event_time(d, e, clock: events.Clock) -> str:
    """Event ``e``'s time as ``clock`` writes it (the diagnosis's; a misfit
    a monitor said on data its record forgot since: the time it was said;
    "": an event of no time)."""
    said = getattr(e, "said", None)
    if said is not None:
        return clock.text(said)
    step = getattr(e, "step", None)
    return "" if step is None else clock.text(d.time_of(step))


def _when(d, e, clock: events.Clock = events.Clock()) -> str:
    """Event ``e``'s time before its sentence: ``t = ...: `` (:func:`_event_time`)."""
    t = _event_time(d, e, clock)
    return f"t = {t}: " if t else ""


def per_horizon(horizon: float | None, time_word: str) -> str:
    """What the false-alarm probability is per: the horizon (``time_word``: the model's time unit), or the run."""
    return "run" if horizon is None else f"horizon of {horizon:g} {time_word}"


def _per(d, labels: Labels = Labels()) -> str:
    return per_horizon(d.options.horizon, labels.time_word)


def data_lines(d, quote: Callable[[Any], str] = _same, labels: Labels = Labels()) -> list[str]:
    """How the data met the model: per input, where it came from; the sensors used (empty: not known)."""
    if d.data is None:
        return []
    s = d.data
    lines = []
    holds = dict(s.holds)
    for u, src in s.inputs:
        held = f", {holds[u]} hole(s) held at the last value" if holds.get(u) else ""
        timed = ", each row's value set at its time (input timing start)" if src == "data" and s.timing == "start" \
            else ""
        lines.append(f"input u:{quote(u)}: from the " + ("data" if src == "data" else "model's declared input")
                     + timed + held)
    lines.append(f"sensors used: {', '.join(quote(y) for y in s.sensors)}"
                 + (f"; missing from the data: {', '.join(quote(y) for y in s.missing)}" if s.missing else ""))
    for y, stops, longest in s.silences:
        lines.append(f"sensor y:{quote(y)}: silent {stops} time(s) for longer than the gap limit, the longest "
                     f"{longest} step(s) ({longest * s.dt:g} {labels.time_word})")
    if s.unsampled or s.skipped:
        lines.append(f"time grid dt = {s.dt:g}: {s.unsampled} step(s) without a sample ({s.gaps} gap(s) beyond "
                     f"the limit), {s.skipped} sample(s) skipped on a step already taken")
    return lines


def _data_lines(d, labels: Labels) -> list[str]:
    lines = data_lines(d, escape, labels)
    return ["", "## Data", ""] + [f"- {line}" for line in lines] if lines else []


def _t(d, step: int | None) -> float | None:
    return d.time_of(step)


def _tt(d, step: int) -> str:
    """A step's time as the report writes it (:attr:`Diagnosis.clock
    <bgc.diagnosis.values.Diagnosis>`: an ISO 8601 timestamp, or 12
    significant digits)."""
    return d.clock.text(d.time_of(step))


def _time(v: float | None) -> float | None:
    """A time in report.json: 12 significant digits (a Unix time keeps its fraction of a second)."""
    return None if v is None or not math.isfinite(v) else float(events.time_text(v))


def _num(v: float | None) -> float | None:
    if v is None or not math.isfinite(v):
        return None
    return float(f"{v:.6g}")


def _fit_data(d) -> dict[str, Any] | None:
    """The test of the model on the data before the fault (the whole record
    without one; :mod:`bgc.diagnosis.fit`) as report.json holds it."""
    f = d.fit
    if f is None:
        return None
    offsets = dict(f.offsets)
    return {"t_last": _time(_t(d, f.end - 1)) if f.end else None, "samples": f.end, "least": f.least,
            "level": f.level, "short": f.short, "unchanged": f.unchanged, "findings": list(f.findings),
            "sensors": [{"sensor": i.sensor, "samples": i.samples, "mean_std": _num(i.mean),
                         "correlation_time": _num(i.correlation_time), "variance": _num(i.variance),
                         "variance_but_one": _num(i.variance_but_one),
                         "mean_offset": _num(offsets.get(i.sensor))}
                        for i in f.innovations]}


def _drop_reason(d, name: str) -> str | None:
    """The code of the Dropped event of hypothesis ``name`` (bgc.events.DROP_REASONS)."""
    return next((e.reason for e in d.events if type(e).__name__ == "Dropped" and e.hypothesis == name), None)


def report_data(r) -> dict[str, Any]:
    """The report as plain data (what ``report.json`` holds)."""
    d, labels = r.diagnosis, plots.report_labels(r)
    det = d.detection
    return {
        "generated_by": "bgc",
        "model": r.model,
        "source": r.source,
        "data": {"scenario": r.scenario, "steps": int(len(d.time)), "t_first": _time(float(d.time[0])),
                 "t_last": _time(float(d.time[-1])),
                 "stream": None if r.stream is None else {"rows_read": int(r.stream[0]),
                                                          "t_first_read": _time(r.stream[1])},
                 "injected": None if r.injected is None else {
                     "parameter": r.injected.parameter, "kind": r.injected.kind,
                     "magnitude": _num(r.injected.magnitude), "time": _time(r.injected.time)}},
        "settings": {"filter": d.options.filter, "particles": d.options.particles, "seed": d.options.seed,
                     "identify": d.options.identify,
                     "false_alarm_per_horizon": d.options.false_alarm, "rejection": d.options.rejection,
                     "horizon": _num(d.options.horizon) if d.options.horizon is not None else None,
                     "windows": list(d.options.windows), "bayes_factor": d.options.bayes_factor,
                     "isolation_level": d.options.isolation_level, "recheck": d.options.recheck,
                     "no_fault": d.options.no_fault,
                     "interval": d.options.interval, "threshold": _num(d.threshold),
                     "process_noise": r.noise[0], "measurement_noise": r.noise[1],
                     "time_unit": labels.time_unit, "absolute_times": d.clock.absolute,
                     "input_timing": d.options.input_timing or "end",
                     "submodels": list(d.submodels)},
        "verdict": d.verdict,
        "detection": None if det is None else {
            "time": _time(_t(d, det.step)), "sensor": det.sensor, "window": det.window,
            "statistic": _num(det.statistic), "threshold": _num(det.threshold),
            "onset_change_point": _time(_t(d, det.onset_step)), "test": det.test,
            "raised": _time(_t(d, det.raised))},
        "onset": _time(_t(d, d.onset_step)),
        "symbols": [{"sensor": s.sensor, "sign": s.sign, "time": _time(_t(d, s.step)), "window": s.window,
                     "statistic": _num(s.statistic), "slope": s.slope or None,
                     "slope_statistic": _num(s.slope_statistic)} for s in d.symbols],
        "refuted_by_signatures": [{"fault": n, "why": why} for n, why in d.refuted],
        "hypotheses": [_hypothesis_data(d, h, labels) for h in d.hypotheses],
        "diagnosis": list(d.candidates),
        # where the diagnosed fault's estimate comes from: kalman (the magnitude held static on a grid of cubature
        # Kalman filters), filter (the particle filters' own magnitude state) or grid (--refine); None: no estimate
        "estimate_method": None if d.estimate is None else d.estimate.method,
        "in_words": plain_words(d, labels),
        # an ambiguous verdict of a model with modes: candidates another mode's signatures would separate
        "mode_split": None if d.mode_split is None else {
            "modes_seen": list(d.mode_split.seen),
            "pairs": [{"faults": [one, other], "differ_in": list(modes)} for one, other, modes in d.mode_split.pairs]},
        "fit": _fit_data(d),
        "events": [events.record(e, d.time_of, clock=d.clock) for e in d.events],
        "data_semantics": None if d.data is None else {
            "inputs": [{"input": u, "from": src, "holds": dict(d.data.holds).get(u, 0)} for u, src in d.data.inputs],
            "sensors": list(d.data.sensors), "sensors_missing": list(d.data.missing),
            "samples_skipped": d.data.skipped, "steps_without_sample": d.data.unsampled, "gaps": d.data.gaps,
            "sensors_silent": [{"sensor": y, "silences": n, "longest_steps": most}
                               for y, n, most in d.data.silences],
            "dt": d.data.dt},
        "seconds": _num(d.seconds),
    }


def _hypothesis_data(d, h, labels) -> dict[str, Any]:
    """One weighed hypothesis of diagnosis ``d`` as plain data (report.json's ``hypotheses``)."""
    e = h.estimate
    return {
        "model": h.name, "parameter": h.parameter, "kind": h.kind, "signatures": list(h.signatures),
        "onset": _time(_t(d, h.onset_step)), "filter_onset": _time(_t(d, h.start_step)),
        "posterior": _num(h.posterior),
        "log_evidence": _num(h.log_evidence), "static_log_evidence": _num(h.static_log_evidence),
        "dropped": None if h.dropped_step is None else {"time": _time(_t(d, h.dropped_step)), "why": h.reason,
                                                    "reason": _drop_reason(d, h.name)},
        "estimate": {"magnitude": e.magnitude, "value": _num(e.value), "std": _num(e.std),
                     "interval": [_num(e.low), _num(e.high)], "level": e.level,
                     "parameter_value": _num(e.parameter_value), "nominal": _num(e.nominal),
                     "truth": _num(e.truth), "covers_truth": e.covers, "method": e.method,
                     "at_prior_bound": e.bound},
        "target": e.target, "subject": e.subject or e.parameter, "unit": e.unit,
        "magnitude_unit": magnitude_unit(h, labels),
        "ruled_out_by_symbols": h.ruled_out or None,
        "intermittent": _intermittent_data(d, h.intermittent),
        "static_consistency_alarm": None if h.static_alarm is None else {
            "test": h.static_alarm.test, "sensor": h.static_alarm.sensor, "window": h.static_alarm.window,
            "statistic": _num(h.static_alarm.statistic), "threshold": _num(h.static_alarm.threshold)},
        "filter_estimate": None if h.filter_estimate is None else {
            "value": _num(h.filter_estimate.value), "std": _num(h.filter_estimate.std),
            "interval": [_num(h.filter_estimate.low), _num(h.filter_estimate.high)]}}


def _intermittent_data(d, i) -> dict | None:
    """A fault that comes and goes (:class:`~bgc.diagnosis.intermittent.Intermittence`) as plain data."""
    if i is None:
        return None
    t = lambda k: None if k is None else _time(_t(d, k))  # noqa: E731
    return {"magnitude": _num(i.value), "std": _num(i.std), "interval": [_num(i.low), _num(i.high)],
            "level": i.level, "log_evidence": _num(i.log_evidence),
            "mean_samples_present": _num(i.on), "mean_samples_absent": _num(i.off),
            "spans": [{"appeared": t(s.on), "appeared_interval": [t(s.on_low), t(s.on_high)],
                       "went": t(s.off), "went_interval": None if s.off is None else [t(s.off_low), t(s.off_high)]}
                      for s in i.spans]}


def magnitude_unit(h, labels: Labels) -> str | None:
    """The unit of hypothesis ``h``'s fault magnitude: its subject's, per
    unit of time for a drift (None: not declared)."""
    return labels.magnitude_unit(h.estimate.unit, fault_kind(h.kind).drifts)


def plain_words(d, labels: Labels = Labels()) -> list[str]:
    """The verdict's faults in plain words (:func:`~bgc.output.events.fault_sentence`):
    the one isolated, each of an ambiguity group ("either ... or ..."), or
    the one that lasted longest of an unexplained verdict (which does not
    explain the data)."""
    if d.verdict == "no fault" or not d.candidates:
        return []
    by = {h.name: h for h in d.hypotheses}
    words = [comes_and_goes(by[n], d.time_of, labels, d.clock) for n in d.candidates if n in by]
    if d.verdict == "ambiguous":
        return [("either " if i == 0 else "or ") + w for i, w in enumerate(words)] + mode_split_lines(d)
    if d.verdict == "unexplained":
        return [f"closest, but not explaining the data: {w}" for w in words]
    if d.verdict == "mismatch":
        return [f"possibly, on the model as it stands: {w}" for w in words]
    return words


def comes_and_goes(h, time_of, labels: Labels = Labels(), clock: events.Clock = events.Clock()) -> str:
    """Hypothesis ``h``'s fault in plain words: since its onset, or, a
    fault that comes and goes (``h.intermittent``), while present and over
    which spans (its times as ``clock`` writes them)."""
    i = h.intermittent
    if i is None:
        return events.fault_sentence(h.estimate, time_of(h.onset_step), labels.per_time, clock=clock)
    spans = [(time_of(s.on), None if s.off is None else time_of(s.off)) for s in i.spans]
    return (f"{events.fault_sentence(h.estimate, None, labels.per_time, clock=clock)}, a fault that comes and goes: "
            f"present {events.spans_text(spans, clock=clock)}")


def mode_split_lines(d) -> list[str]:
    """For an ambiguous verdict of a model with modes: the candidates whose
    signatures are alike in the modes the plant was in from the onset on
    but differ in another mode, which data reaching a switch to it may
    separate (:class:`~bgc.diagnosis.values.ModeSplit`)."""
    split = d.mode_split
    if split is None:
        return []
    seen = ", ".join(split.seen)
    return [f"{one} and {other} show the same signature in {'mode' if len(split.seen) == 1 else 'modes'} {seen}, "
            f"where the plant was from the onset on; they differ in {' and '.join(modes)}: data that reach a "
            f"switch to {'it' if len(modes) == 1 else 'one of them'} may separate them"
            for one, other, modes in split.pairs]


def heading(r, quote: Callable[[Any], str] = _same) -> tuple[str, str, str]:
    """The report's title (the model and its file), what the data are
    (samples on the grid's steps) and how they were filtered (the filter, the noise)."""
    d = r.diagnosis
    title = f"Diagnosis of {quote(r.model)} ({quote(r.source)})"
    span = f"t = {_tt(d, 0)} to {_tt(d, len(d.time) - 1)}"
    rows = len(r.run.time)
    count = (f"{rows} samples" if rows == len(d.time) else
             f"{rows} samples on {len(d.time)} steps of the model's time grid")
    kept = ("" if r.stream is None or r.stream[0] <= rows else  # a monitor's: the record kept, not the stream
            f": the record the monitor kept of the {r.stream[0]} rows it read from "
            f"t = {d.clock.text(r.stream[1])} on")
    scenario = f"simulated scenario {quote(r.scenario)}, " if r.scenario else ""
    data = f"Data: {scenario}{count} ({span}){kept}."
    noise = ("the model's noise levels" if r.noise == (None, None) else
             f"relative noise levels process {r.noise[0] if r.noise[0] is not None else 'per model'}, "
             f"measurement {r.noise[1] if r.noise[1] is not None else 'per model'}")
    how = {"kalman": "magnitudes and hypotheses weighed with the magnitude held static (cubature Kalman filters "
                     "on a grid of onsets and magnitudes)",
           "filter": "magnitudes from the particle filters' own magnitude state"}[d.options.identify]
    if d.submodels:
        how = (f"Filter: CKF on the model's {len(d.submodels)} submodels (cubature Kalman filters: each "
               f"submodel's nominal observer, and every hypothesis with its magnitude held static on a grid of "
               f"onsets and magnitudes, on the submodels it touches); {noise}.")
    elif d.options.filter == "ckf":
        how = (f"Filter: CKF (cubature Kalman filters: the nominal observer, and every hypothesis with its "
               f"magnitude held static on a grid of onsets and magnitudes); {noise}.")
    else:
        how = (f"Filter: {d.options.filter.upper()}, {d.options.particles} particles, seed {d.options.seed}; "
               f"{noise}; {how}.")
    return title, data, how


def decomposed_text(d) -> str:
    """What a decomposed diagnosis weighed in place of the signatures' isolation."""
    return (f"The plant was diagnosed on its {len(d.submodels)} submodels (as bgc compile --decompose splits it), "
            "no signatures read: every fault that can move the submodel of the sensor that alarmed "
            f"({d.detection.sensor}) was weighed on the submodels it touches.")


def _heading(r) -> list[str]:
    """The report's first lines: the model, the data (samples on the grid's steps), the filter and noise."""
    title, data, how = heading(r, escape)
    return [f"# {title}", "", data, how, ""]


def verdict_text(d) -> str:
    """The verdict as the report's headline: ``'Fault isolated: R2_abrupt.'``."""
    unsure = any(isinstance(e, ev.NoFault) and not e.decided for e in d.events)
    return {"no fault": "No fault detected." if d.detection is None else
                        "No fault: the alarm is one the detector's false-alarm budget allows.",
            "isolated": f"Fault isolated: {d.candidates[0] if d.candidates else ''}.",
            "ambiguous": ("An alarm the data cannot tell from a false one: " + ", ".join(d.candidates)
                          + ", or no fault." if unsure else
                          "Fault detected; the data cannot separate: " + ", ".join(d.candidates) + "."),
            "unexplained": "Fault detected, but no fault model explains the data"
                           + (f" (the one that lasted longest: {d.candidates[0]})" if d.candidates else "")
                           + ".",
            "mismatch": ("The model does not fit these data as their inputs were read: read them with "
                         f"--input-timing {_timing(d)}" if _timing(d) else
                         "The model does not fit this plant: calibrate it")
                        + (f" (a fault is possible too: {', '.join(d.candidates)})" if d.candidates else "")
                        + "."}[d.verdict]


def _timing(d) -> str | None:
    """The other input timing a mismatch names (:class:`~bgc.events.Mismatched`), if any."""
    return next((e.timing for e in d.events if isinstance(e, ev.Mismatched) and e.timing is not None), None)


def verdict_definition(verdict: str, settings: Mapping[str, Any]) -> str:
    """What a verdict means, in one sentence, with the levels the diagnosis
    used (``settings``: report.json's; :mod:`bgc.diagnosis.finish`)."""
    level = f"{100 * settings['isolation_level']:g} %"
    factor = f"{settings['bayes_factor']:g}"
    per = per_horizon(settings["horizon"], Labels(time_unit=settings.get("time_unit")).time_word)
    return {
        "no fault": (f"no fault: no window of the nominal observer's normalised residuals crossed the detection "
                     f"threshold, set for a false-alarm probability of {settings['false_alarm_per_horizon']:g} "
                     f"per {per}; or one did, but the nominal model passes the fault models' test of their fit "
                     f"over the whole record and no fault holds at least {level} of the posterior beside every "
                     f"fault model (each fault's prior spread over the {per}'s steps as its onset's): a false "
                     f"alarm the budget allows."),
        "isolated": (f"isolated: one fault model explains the data and every other is ruled out (by its "
                     f"signature, by a failed test of its fit, or by being at least {factor} times less "
                     f"probable); it holds at least {level} of the posterior."),
        "ambiguous": (f"ambiguous: a fault was detected and several fault models explain the data: none of them is "
                      f"ruled out, and only together do they hold {level} of the posterior (the data cannot "
                      f"separate them)."),
        "unexplained": ("unexplained: a fault was detected but no fault model explains the data: every one was "
                        "ruled out by its signature, failed a test of its fit, or was outweighed; the fault lies "
                        "outside the model's fault candidates or beyond the sizes their priors allow."),
        "mismatch": ("mismatch: the model does not fit this plant: the nominal Kalman filter's normalised "
                     "residuals over the data before the fault (the whole record without an alarm) are not N(0, 1) "
                     f"(their mean, or a variance above 1, each sensor tested at a joint level of {FIT_LEVEL:g}), "
                     "or an alarm comes too soon after the data's start to tell a fault from a model that does not "
                     "fit, or the whole record fits only with the data's inputs read one step off (the other input "
                     "timing); the faults named are possibilities, and the model needs calibrating (bgc calibrate) "
                     "or the inputs reading with the other timing (--input-timing)."),
    }[verdict]


def no_detection_text(d, labels: Labels = Labels()) -> str:
    """Why the verdict is no fault: the threshold no window passed."""
    tests = d.options.detectors
    more = "" if len(tests) == 1 else (f"; nor did the {', '.join(tests[1:])} test{'s' if len(tests) > 2 else ''} "
                                        "alarm, which share that probability")
    return (f"No window of the nominal observer's normalised residuals passed the threshold "
            f"{d.threshold:.2f} (a false-alarm probability of {d.options.false_alarm:g} per {_per(d, labels)}, "
            f"windows {', '.join(map(str, d.options.windows))} samples{more}).")


def detection_lines(d, labels: Labels = Labels()) -> list[str]:
    """The alarm, and the change point and onset it led to (empty: no alarm)."""
    det = d.detection
    if det is None:
        return []
    if det.test == "mean":
        seen = (f"sensor {det.sensor}, window of {det.window} sample(s), |Z| = {det.statistic:.2f} > "
                f"{det.threshold:.2f}")
    else:
        said = events.alarm_text(det.test, det.window, det.statistic, det.threshold)
        seen = f"sensor {det.sensor}, the {det.test} test: {said}"
    tests = d.options.detectors
    shared = "" if len(tests) == 1 else f", shared by the tests {', '.join(tests)}"
    if det.test == "change":  # no test alarmed: the record's misfit, found at its end to begin there
        watched = next((e for e in d.events if isinstance(e, ev.ChangeMissed) and e.watching), None)
        whole = ("the data's end: the model does not fit the whole record" if watched is None else
                 f"t = {_tt(d, det.raised)}: the record kept while watching up to there fails the test of the model "
                 "or shows a shift of its residuals' mean (the CUSUM test)")
        level = FIT_LEVEL if watched is None or watched.level is None else watched.level
        first = (f"alarm at {whole} (the test of the model, level "
                 f"{level:.3g}) but fits it before t = {_tt(d, det.step)}; sensor {det.sensor}: "
                 f"{events.change_text(det.window, det.statistic, det.threshold)}, at level {CHANGE_LEVEL:g} over "
                 "every sensor and test")
    else:
        first = (f"alarm at t = {_tt(d, det.step)}: {seen} (false-alarm probability {d.options.false_alarm:g} per "
                 f"{_per(d, labels)}{shared})")
    return [first,
            f"change point of the residuals: t = {_tt(d, det.onset_step)}; onset of the diagnosis: "
            + ("none (no fault)" if d.onset_step is None else f"t = {_tt(d, d.onset_step)}")]


#: The columns of :func:`hypothesis_rows`.
HYPOTHESIS_COLUMNS = ("hypothesis", "onset", "posterior", "estimate", "interval", "dropped", "why")


def hypothesis_rows(d, labels: Labels = Labels()) -> list[tuple[str, ...]]:
    """A row per fault model tried, most probable first (:data:`HYPOTHESIS_COLUMNS`;
    the estimate and its interval in the magnitude's unit; ``why`` is the
    model's text, empty when it survived)."""
    rows = []
    for h in sorted(d.hypotheses, key=lambda h: -h.posterior):
        e = h.estimate
        unit = f" {u}" if (u := magnitude_unit(h, labels)) else ""
        truth = f" (true {e.truth:.4g})" if e.truth is not None else ""
        stuck = e.magnitude == "switch"  # a stuck switch: no size
        rows.append((h.name, _tt(d, h.onset_step), f"{h.posterior:.3g}",
                     _stuck_text(e) if stuck else f"{e.magnitude} {e.value:.4g}{unit}{truth}",
                     "-" if stuck else f"[{e.low:.4g}, {e.high:.4g}]{unit}",
                     "-" if h.dropped_step is None else f"t = {_tt(d, h.dropped_step)}",
                     h.reason))
    return rows


def _stuck_text(e) -> str:
    """A switch's fault in words: ``K stuck OFF``, ``K turned ON without a command``."""
    from ..kinds import stuck_title

    return stuck_title(e.subject or e.parameter, e.kind)


def identification_lines(d, labels: Labels = Labels()) -> list[tuple[str, str | None]]:
    """Per candidate of an isolated or ambiguous verdict: its estimate with
    interval in its unit (and truth, when known), and the particle filters'
    own estimate (None: none)."""
    if d.best is None or d.verdict not in ("isolated", "ambiguous"):
        return []
    out = []
    for name in d.candidates:
        h = next(x for x in d.hypotheses if x.name == name)
        e = h.estimate
        if e.magnitude == "switch":  # no size: its onset alone
            out.append((f"{name}: {_stuck_text(e)}, at t = {_tt(d, h.onset_step)} (it shows at once, its mode "
                        f"asking for the other state, until a mode asks for it so; weighed over its onsets by "
                        f"cubature Kalman filters)" if releases(e.kind) else
                        f"{name}: {_stuck_text(e)}, at the latest from t = {_tt(d, h.onset_step)} (a stuck switch "
                        f"shows only when a mode asks it to move; weighed over its onsets by cubature Kalman "
                        f"filters)", None))
            continue
        what = (f"{e.parameter} = {e.nominal:g} + bias" if e.magnitude == "bias"
                else f"slope of {e.parameter} ({labels.per_time})")
        unit = f" {u}" if (u := magnitude_unit(h, labels)) else ""
        truth = ""
        if e.truth is not None:
            truth = (f"; truth {e.truth:.4g}, error {100 * e.relative_error:.1f} %, "
                     f"{'inside' if e.covers else 'outside'} the interval")
        at_end = f" {e.unit}" if e.unit else ""
        line = (f"{name}: {what}: {e.magnitude} {e.value:.4g} +- {e.std:.2g}{unit}, "
                f"{100 * e.level:.0f} % interval [{e.low:.4g}, {e.high:.4g}]{unit}, {e.parameter} at the "
                f"end {e.parameter_value:.4g}{at_end}, onset t = {_tt(d, h.onset_step)}{truth}"
                + {"grid": " (grid posterior of the particle filters' marginal likelihood)",
                   "kalman": " (with the magnitude held static: cubature Kalman filters on a grid)",
                   "filter": ""}[e.method])
        f = h.filter_estimate
        sub = None if f is None else (f"the particle filters' own estimate (a magnitude with a random walk): "
                                      f"{f.value:.4g} +- {f.std:.2g}, [{f.low:.4g}, {f.high:.4g}]{unit}")
        out.append((line, sub))
    return out


def symbol_text(d, s) -> str:
    """An observed deviation (a symbol) in words."""
    return (f"{s.sensor} {s.sign} at t = {_tt(d, s.step)} ({s.window}-sample window, Z {s.statistic:.1f}), "
            f"slope {s.slope or 'not significant'} (Z {s.slope_statistic:.1f})")


def signature_rows(d) -> list[tuple[str, str, str]]:
    """The fault signatures against the observed symbols: (signature,
    ``kept`` or ``ruled out``, why), those the symbols kept first."""
    refuted = dict(d.refuted)
    kept = [(sig, "kept", "agrees with every observed symbol")
            for h in d.hypotheses for sig in h.signatures if sig not in refuted]
    return list(dict.fromkeys(kept)) + [(n, "ruled out", why) for n, why in d.refuted]


def report_markdown(r) -> str:
    """The report for people: ``report.md``."""
    d, labels = r.diagnosis, plots.report_labels(r)
    det = d.detection
    lines = _heading(r)
    lines += ["## Verdict", "", f"**{verdict_text(d)[:-1]}.**", ""]
    words = plain_words(d, labels)
    lines += [f"- {escape(line)}" for line in words] + ([""] if words else [])
    if det is None:
        lines += [no_detection_text(d, labels), ""]
    else:
        lines += ["## Detection", ""] + [f"- {line}" for line in detection_lines(d, labels)] + [""]
        if d.submodels:
            lines += ["## Isolation on the submodels", "", decomposed_text(d)]
        elif d.symbols:
            lines += ["## Qualitative isolation (TRANSCEND signatures)", "",
                      "Observed deviations: " + "; ".join(symbol_text(d, s) for s in d.symbols) + "."]
        else:
            lines += ["## Qualitative isolation (TRANSCEND signatures)", "",
                      "No sensor deviated significantly from the open-loop nominal prediction."]
        if d.refuted:
            lines += ["", "Ruled out by their signatures:", ""]
            lines += [f"- {escape(n)}: {escape(why)}" for n, why in d.refuted]
        lines += ["", "## Fault-model filters", "",
                  "| hypothesis | onset | posterior | estimate | interval | dropped | why |",
                  "|---|---|---|---|---|---|---|"]
        for row in hypothesis_rows(d, labels):
            lines.append("| " + " | ".join(row[:-1]) + f" | {escape(row[-1]) or '-'} |")
        found = identification_lines(d, labels)
        if found:
            lines += ["", "## Identification", ""]
            for line, sub in found:
                lines.append(f"- {line}")
                if sub is not None:
                    lines.append(f"  - {sub}")
    lines += _data_lines(d, labels)
    if d.events:
        lines += ["", "## Events", ""] + [
            f"- {_when(d, e, d.clock)}{escape(events.sentence(e, d.time_of, clock=d.clock))}" for e in d.events]
    lines += ["", f"Diagnosis computed in {d.seconds:.2f} s.", ""]
    return "\n".join(lines)


#: The pictures of a diagnosis (:func:`bgc.output.plots.diagnosis_figures`) and what each shows.
DETECTION_PICTURES = {
    "measurements.png": "the measurements and the nominal observer's predictions (band: +-2 std; dashed: onset, "
                        "red: detection)",
    "residuals.png": "each sensor's normalised residual and its largest windowed |Z| against the threshold"}
HYPOTHESIS_PICTURES = {"hypotheses.png": "the most probable fault models' predicted measurements from their "
                                         "onsets, the others' in grey (dotted: dropped, X: where)"}
ESTIMATE_PICTURES = {"estimate.png": "the fault magnitude over time, its interval, and the truth when the run "
                                     "records it"}


def _g(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def report_html(r, data: Mapping[str, Any], pictures: Mapping[str, bytes]) -> str:
    """The report as one self-contained page, ``report.html``: the verdict in
    plain words and what it means, then detection, isolation, every fault
    model, the estimate and the events; from ``data`` (:func:`report_data`)
    and the same sentences as :func:`report_markdown`, with ``pictures``
    (:func:`bgc.output.plots.diagnosis_figures`) embedded."""
    d, labels = r.diagnosis, plots.report_labels(r)
    title, data_line, filter_line = heading(r)
    symbols = html.table(
        ("sensor", "deviation", "seen at t", "window (samples)", "Z", "slope", "slope Z"),
        [(s["sensor"], s["sign"], _tt(d, symbol.step), s["window"],
          _g(s["statistic"], ".1f"), s["slope"] or "not significant", _g(s["slope_statistic"], ".1f"))
         for symbol, s in zip(d.symbols, data["symbols"])])  # (the times unrounded: report.json's have 12 digits)
    signatures = signature_rows(d)
    return html.page(
        "diagnosis.html.j2", r.source, title=title, data_line=data_line, filter_line=filter_line,
        verdict=data["verdict"], verdict_class="v-" + data["verdict"].replace(" ", "-"), headline=verdict_text(d),
        definition=verdict_definition(data["verdict"], data["settings"]), words=data["in_words"],
        detection=detection_lines(d, labels), no_detection=no_detection_text(d, labels),
        detection_pictures=html.pictures(pictures, DETECTION_PICTURES),
        isolation=d.detection is not None, symbols=symbols if symbols.rows else None,
        decomposed=decomposed_text(d) if d.submodels and d.detection is not None else None,
        signatures=html.table(("signature", "outcome", "why"), signatures) if signatures else None,
        hypotheses=html.table(HYPOTHESIS_COLUMNS, [(*row[:-1], row[-1] or "-")
                                                   for row in hypothesis_rows(d, labels)])
        if d.hypotheses else None,
        hypothesis_pictures=html.pictures(pictures, HYPOTHESIS_PICTURES),
        identification=identification_lines(d, labels),
        estimate_pictures=html.pictures(pictures, ESTIMATE_PICTURES),
        data_lines=data_lines(d, labels=labels),
        events=html.table(("t", "event"), [(_event_time(d, e, d.clock), row["text"])
                                           for e, row in zip(d.events, data["events"])]) if data["events"] else None,
        seconds=f"{d.seconds:.2f}")


def report_files(r, command: str = "diagnose") -> dict[str, str | bytes]:
    """Every file of the report folder of diagnosis report ``r`` (what ``bgc
    diagnose -o``, ``bgc monitor -o`` and :meth:`bgc.api.DiagnosisReport.write`
    write): report.json, report.md, report.html, the pictures
    (:func:`bgc.output.plots.diagnosis_figures`), the run as ``run.csv`` when
    it was simulated (a scenario), and the manifest of ``command``, last."""
    from ..data import runs

    data = report_data(r)
    pictures = plots.diagnosis_figures(r)
    files: dict[str, str | bytes] = {
        "report.json": json.dumps(data, indent=2, sort_keys=True) + "\n",
        "report.md": report_markdown(r),
        "report.html": report_html(r, data, pictures),
        **pictures,
    }
    if r.scenario is not None:
        files["run.csv"] = runs.run_csv(r.run)
    files["manifest.json"] = manifest(files, command, model=r.model)
    return files
