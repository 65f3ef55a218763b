"""Events (:mod:`bgc.events`) as sentences and as plain data: the one
place they are put into words (the report, ``bgc diagnose``'s and ``bgc
monitor``'s lines). A sentence writes the run's times as the ``clock``
it is given says (:class:`~bgc.data.clock.Clock`: an ISO 8601 timestamp
for a run of absolute times; ``Clock()``, the default, a number); the
plain data keep numbers, in the model's time unit."""

from __future__ import annotations

import dataclasses
import math

from .. import events as ev
from ..kinds import kind_of, releases, switch_held
from ..data.clock import Clock, time_text


def _t(time_of, step, clock: Clock) -> str:
    """The time of step ``step`` in words (``""``: none)."""
    t = time_of(step)
    return "" if t is None else clock.text(t)


def sentence(e, time_of, *, clock: Clock = Clock()) -> str:
    """Event ``e`` in words; ``time_of(step)``: the time of a step (None:
    none), written as ``clock`` says. The event's own time is not in the
    sentence: the report and the monitor put it in front."""
    t = lambda step: _t(time_of, step, clock)  # noqa: E731
    for family in (_data_sentence, _weighing_sentence):
        said = family(e, t, time_of, clock)
        if said is not None:
            return said
    match e:
        case ev.Alarmed(step=k, sensor=s, window=w, statistic=z, threshold=c, onset=o, test=test):
            return f"alarm on {s}: {alarm_text(test, w, z, c)}; estimated onset t = {t(o)}"
        case ev.Degenerate(method=m, ess=e_, particles=n, switched=sw):
            tail = "; diagnosed with cubature Kalman filters (ckf) instead" if sw else \
                "; use --filter ckf (cubature Kalman filters), or more particles"
            return (f"the nominal observer's particle filter ({m}) degenerates (mean effective sample size {e_:.0f} "
                    f"of {n}): a sensor is sharp against the spread the process noise gives the prediction, and its "
                    f"residuals may alarm without a fault" + tail)
        case ev.Switched(to=to):
            return f"diagnosing again with {to}: every step replayed"
        case ev.Isolated(step=k, onset=o, kept=kept, refuted=refuted):
            return (f"isolation from the symbols read from t = {t(o)}: kept "
                    f"{', '.join(kept) or 'none'}; ruled out {len(refuted)} signature(s)")
        case ev.AllTried(why="unexplained"):
            return ("no hypothesis the symbols kept explains the data: the fault models they ruled out are tried "
                    "as well")
        case ev.AllTried():
            return "no fault signature agrees with the observed symbols: every fault model is tried"
        case ev.ReadingFrozen(sensor=y, onset=o, kept=kept):
            head = f"{y} is frozen from t = {t(o)}: no fault of the plant holds a reading still, "
            if kept:
                return head + f"so only {', '.join(kept)} is tried"
            return (head + f"and the model declares no stuck fault of {y}: unexplained (declare stuck among "
                    f"{y}'s kinds in the model's faults to have it diagnosed and sized)")
        case ev.Started(step=k, hypothesis=h, onsets=onsets):
            return f"tracking {h} from {len(onsets)} onset(s), t = {t(min(onsets))} to {t(max(onsets))}"
        case ev.Refined(hypothesis=h, onset=o, first=a, last=b):
            tracked = f"t = {t(a)}" if a == b else f"t = {t(a)} to {t(b)}"
            return (f"{h}: onset refined to t = {t(o)} from the onsets tracked online ({tracked}) by the final "
                    f"weighing of the whole record")
        case ev.Dropped(step=k, hypothesis=h, reason=r, detail=detail):
            return f"{h} dropped ({r}): {detail}"
        case ev.Stopped(hypothesis=h):
            return (f"{h} dropped (inconsistent): every filter of it stopped: far off the data, or another onset of "
                    "it explained the data decisively better")
        case ev.Rescued(hypothesis=h, reason=r, step=k):
            return (f"{h}: its particle filters failed their test ({r}, at t = {t(k)}), its fault model with the "
                    f"magnitude held static passes it")
        case ev.Truncated(hypothesis=h):
            return (f"{h}: its magnitude's posterior may reach past the Kalman filters' last grid; its evidence and "
                    f"interval may be short")
        case ev.AtPriorBound(hypothesis=h, bound=b, value=v) if b == 0:
            return (f"{h}: its magnitude ({v:.4g}) presses against 0, the edge of its prior: the data ask for a "
                    f"change in a direction the model does not list for it")
        case ev.AtPriorBound(hypothesis=h, side=side, bound=b, value=v):
            return (f"{h}: its magnitude ({v:.4g}) presses against the {'upper' if side == 'high' else 'lower'} "
                    f"bound of its prior ({b:.4g}): the fault may be larger than the model's prior allows (widen "
                    f"it with the fault's 'size' or 'rate' in the model, or --prior-scale)")
        case ev.Overruled(hypothesis=h, why=w):
            return (f"{h}: ruled out by the symbols ({w}), but with its magnitude held static it explains the data "
                    f"as well as the others: a candidate all the same")
        case ev.SensorExcluded(sensor=y, finding=f, time=when):
            return (f"sensor {y} taken out of the nominal observer from t = {clock.text(when)} ({f}): monitoring "
                    f"goes on with the other sensors")
        case ev.EpisodeClosed():
            return _episode_sentence(e, clock)
        case ev.Repaired(time=when, episodes=ns, parameters=ps):
            out = ", ".join(ps) if ps else "nothing accommodated"
            return (f"repaired at t = {clock.text(when)}: " + (f"episode(s) {', '.join(map(str, ns))} taken out of the "
                    f"model ({out}); " if ns else "") + "watching on the model as it was")
        case ev.Checkpoint(step=k, verdict=v, candidates=c):
            return f"checkpoint: {v}" + (f": {', '.join(c)}" if c else "")
        case ev.Mismatched():
            return mismatch_sentence(e, time_of, clock=clock)
        case ev.Decided(step=k, verdict=v, candidates=c):
            return f"decided: {v}" + (f": {', '.join(c)}" if c else "")
    return type(e).__name__


def _data_sentence(e, t, time_of, clock: Clock) -> str | None:
    """:func:`sentence` of an event of the data (sensors, inputs, modes, the
    time grid; ``t``: a step's time as text, ``clock``: how a time is
    written); None for another event."""
    match e:
        case ev.SensorMissing(sensor=s):
            return f"the data have no column y:{s}: diagnosed with the other sensors"
        case ev.ColumnIgnored(column=c):
            return f"the data's column {c} is no sensor or input of the model: not used"
        case ev.SensorSilent(sensor=s):
            return f"sensor y:{s} has no sample in the run: every value of its column is empty or nan, so nothing " \
                   "is diagnosed from it"
        case ev.SensorStopped(sensor=y, since=k):
            return (f"sensor y:{y} has no sample since t = {t(k)}, longer than the gap limit: diagnosed with the "
                    f"other sensors until it resumes")
        case ev.SensorResumed(sensor=y, since=k, step=j):
            return f"sensor y:{y} gives samples again after {j - k} step(s) without one (from t = {t(k)})"
        case ev.InputFromModel(input=u, reason="absent"):
            return f"the data have no column u:{u}: the model's declared input is used"
        case ev.InputFromModel(input=u):
            return f"input u:{u} has no value yet: the model's declared input is used until its first value"
        case ev.ModeHidden(lag=lag):
            return ("the data have no mode column: the mode is read from the measurements by a bank of Kalman filters "
                    f"over the modes' histories, each sample's decided once the data settle it (at most {lag} samples "
                    "later)")
        case ev.ModeRead(source=a, target=b, share=w):
            tail = "" if w >= 0.999 else f" (the likeliest history's, weight {w:.2f}: the data did not settle it)"
            return f"the mode read from the data changes from {a} to {b}" + tail
        case ev.ModesReread(hypothesis=h, changed=n, explains=yes, below=other, by=nats):
            if other:
                amount = f"{nats:,.0f}" if nats >= 10 else f"{nats:.2g}"
                return (f"the modes read again with {h}'s own equations (its onset and size) make the data {amount} "
                        f"nats less likely than {other}'s own reading, which explains them: beyond the Bayes factor, "
                        "weighed out (not diagnosed again)")
            head = f"the modes read again with {h}'s own equations (its onset and size): "
            moved = f"{n} sample(s)' mode differ from the nominal model's reading" if n else "the same modes"
            return head + moved + ("; with them it explains the data" if yes else "; it does not explain the data")
        case ev.InputHeld(input=u, step=k, value=v):
            return f"input u:{u} is empty: its last value {v:g} is held until a value arrives"
        case ev.Bridged(began=a, time=b, steps=n, ran=r, settled=settled, modes=modes):
            if settled:
                start = (f"anywhere on the course the model settles into in {r} steps at this row's inputs" if r
                         else "anywhere its estimates before the gap were" + ("" if modes else " in this row's mode"))
                if modes:
                    start += ", the mode " + ("one of " if len(modes) > 1 else "") + ", ".join(modes)
            else:
                start = (f"where the model takes its last estimate in {r} steps at this row's inputs" if r
                         else "from its last estimate")
            return (f"no data from t = {clock.text(a)} to t = {clock.text(b)} ({n} steps, more than the diagnosis "
                    f"holds): watching again from this row, the observer started {start}, its spread widened")
        case ev.Gap(step=k, steps=n):
            return f"no sample for {n} steps from t = {t(k)} to t = {t(k + n - 1)}: the filters predict across the gap"
        case ev.SampleSkipped(step=k, line=line, time=when):
            where = f" (line {line})" if line is not None else ""
            return (f"the sample at t = {clock.text(when)}{where} falls on a step of the model's grid a sample "
                    f"already took (t = {t(k)}): skipped; give the model a dt no longer than the sampling interval to "
                    "use every one")
    return None


def _weighing_sentence(e, t, time_of, clock: Clock) -> str | None:
    """:func:`sentence` of an event of the weighing of the hypotheses and of
    what the verdict was checked against (the verdict's posterior, no fault,
    faults that come and go, a later onset, a false alarm or a glitch, a
    change no test alarmed on, the Kalman observer restarted, a misfit;
    ``t``: a step's time as text, ``clock``: how a time is written); None
    for another event."""
    match e:
        case ev.Uncertain(candidates=c, mass=m, level=lv, kept=k, posteriors=p):
            return (f"{', '.join(c)} hold(s) a posterior of {m:.3g} only, under the {lv:g} a verdict promises: "
                    f"{', '.join(f'{n} ({q:.2g})' for n, q in zip(k, p))} kept as candidates too")
        case ev.NoFault(mass=m, best=b, log_factor=f, level=lv, decided=True):
            return (f"no fault explains the data best: the alarm is one the detector's false-alarm budget allows "
                    f"(no fault holds a posterior of {m:.3g}, at least the {lv:g} a verdict promises"
                    + (f"; the likeliest fault, {b}, is favoured by a Bayes factor of only {math.exp(f):.3g}" if b
                       else "") + ")")
        case ev.NoFault(mass=m, best=b, log_factor=f, level=lv):
            return (f"no fault at all (the alarm a false one) holds a posterior of {m:.3g}: the faults named "
                    f"cannot be promised at {lv:g} without it" + (f" (the likeliest, {b}, is favoured over no fault by "
                                                                   f"a Bayes factor of {math.exp(f):.3g})" if b else ""))
        case ev.IntermittentTried(hypothesis=h, log_factor=f, spans=n, fits=ok):
            return (f"{h} tried as a fault that comes and goes: {n} appearance(s)"
                    + ("" if not math.isfinite(f) else f", its evidence {'above' if f >= 0 else 'below'} the "
                       f"persistent fault's by a log Bayes factor of {abs(f):.3g}")
                    + ("" if ok else "; it fails its fit test too"))
        case ev.Redated(hypothesis=h, was=a, onset=b, log_factor=f, alarmed=k):
            return (f"{h} began after every onset it was tried from: from t = {t(b)} rather than t = {t(a)} ("
                    + (f"the data favour the later onset by a Bayes factor of {math.exp(f):.3g}" if f < 700.0 else
                       "from the onsets tried its model could not follow the data at all")
                    + ")"
                    + (f"; the alarm at t = {t(k)} came before it: a false one" if k is not None and k < b else
                       "; the detector's change point came before it"))
        case ev.FalseAlarm(step=k, sensor=y, test=test, again=a, until=u, hypothesis=h):
            return (f"the alarm at t = {t(k)} on {y} ({test} test) was a false one: the model's residuals stay "
                    f"within its noise from t = {t(a)} to t = {t(u)}"
                    + (f", {h} explaining them from there on" if h else ", where they change again")
                    + "; the diagnosis was made again, the detector armed anew after the alarm")
        case ev.Glitch(step=k, sensor=y, statistic=z, until=u):
            return (f"the alarm at t = {t(k)} was one reading of {y}, {abs(z):.3g} of its stds from the model's "
                    f"prediction, and the model's residuals stay within its noise after it to the data's end "
                    f"(t = {t(k + 1)} to t = {t(u)}): a glitch of that reading, not a fault that persists "
                    f"or comes back; the diagnosis was made again without it")
        case ev.ChangeMissed():
            return _change_missed_sentence(e, t)
        case ev.ObserverRestarted(step=k, times=n):
            return (f"the Kalman observer whose residuals the drift test reads lost its estimate at t = {t(k)} "
                    f"(not finite; restart {n}): it starts again there from the particle observer's cloud, the "
                    "drift test's windows holding that sample held to the threshold of windows with a reading "
                    "missing")
        case ev.Intermittent(hypothesis=h, value=v, low=lo, high=hi, spans=sp, posterior=p):
            spans = [(time_of(a), None if b is None else time_of(b)) for a, b in sp]
            return (f"{h} comes and goes: present {spans_text(spans, clock=clock)}, "
                    f"its magnitude {v:.4g} [{lo:.4g}, {hi:.4g}] (95 %) while present (posterior {p:.3g})")
        case ev.NoLikelihood(fallback=True):
            return ("the cubature Kalman filters found no finite likelihood: the particle filters' evidence and "
                    "estimates are reported")
        case ev.NoLikelihood():
            return "the cubature Kalman filters found no finite likelihood for any hypothesis"
        case ev.Misfit(hypothesis=h, magnitude=m, value=v, start=s, sensor=y, window=w, statistic=z, threshold=c,
                       stretch=stretch):
            held = (f"{switch_held(kind_of(h))} t = {t(s)} (its most probable onset)" if m == "switch" else
                    f"with its {m} held at {v:.4g} from t = {t(s)} (the most probable magnitude and onset; its "
                    f"estimate is the mean over all of them)")
            from ..diagnosis.static import residual_misfit  # (here: the diagnosis's modules load only when told)

            return (f"{h} {held}: {residual_misfit(y, w, z, c, stretch)}; the fault model as stated (or the "
                    f"Kalman filters' Gaussian approximation) does not explain these data: it fails the "
                    f"goodness-of-fit test")
    return None


def spans_text(spans, *, clock: Clock = Clock()) -> str:
    """The spans a fault was present over, in words, its times as ``clock``
    writes them: ``t = 6.05 to 14.1 and from t = 22``."""
    return " and ".join("at an onset not known" if on is None else
                        f"t = {clock.text(on)} to {clock.text(off)}" if off is not None else
                        f"from t = {clock.text(on)}"
                        for on, off in spans) or "not known"


def _change_missed_sentence(e: ev.ChangeMissed, t) -> str:
    """:func:`sentence` of a change no test alarmed on (``t``: a step's time as text)."""
    tests = e.tests
    if e.watching:  # the record kept while watching, tested before its older half is forgotten
        return (f"the record kept while watching fails the test of the model or its residuals' mean shifts within it "
                f"(the CUSUM test), yet the model fits it before "
                f"t = {t(e.change)} and {', '.join(e.sensors)}'s residuals changed there: a change the "
                f"{', '.join(tests)} test{'s' if len(tests) > 1 else ''} did not alarm on; an alarm is raised at that "
                "change point, and the diagnosis goes on from there")
    bank = "every test of the detector's bank (--detect all), which "
    if not e.bank:  # the bank had run: only the diagnosis from the change point
        bank = "an alarm raised at that change point, and its verdict stands" if e.found else \
            "an alarm raised at that change point, which named no fault: the model's misfit stands"
    elif e.found and not e.at_change:
        bank += "alarmed and named a fault"
    elif e.found:
        bank += "named no fault; it was then made from an alarm raised at that change point, and its verdict stands"
    else:
        bank += ("named no fault, nor did the diagnosis from an alarm raised at that change point: the model's "
                 "misfit stands")
    return (f"no alarm, yet the model fits the data before t = {t(e.change)} and {', '.join(e.sensors)}'s residuals "
            f"changed there: a change the {', '.join(tests)} test{'s' if len(tests) > 1 else ''} did not alarm on, "
            f"not a model that does not fit from the start; the diagnosis was made again with {bank}")


def _episode_sentence(e: ev.EpisodeClosed, clock: Clock) -> str:
    """:func:`sentence` of an episode closed: its verdict, and what the
    monitor did (its times as ``clock`` writes them)."""
    n, a, y, when, v, c, o, f = e.number, e.alarm, e.sensor, e.time, e.verdict, e.candidates, e.began, e.finding
    act, p, x, k, spans, why = e.action, e.parameter, e.value, e.appearance, e.present, e.reason
    what = f"{v}: {', '.join(c)}" if c else v
    since = "" if o is None else f", onset t = {clock.text(o)}"
    if act == "ended":
        did = (f"the fault of {p} went away without a repair (intermittent: present {spans_text(spans, clock=clock)}): "
               f"the model watched from now on has {p} = {x:.6g}, its value in the model file")
    elif act == "accommodated" and k > 1:
        did = (f"the intermittent fault of {p} is back (appearance {k}; present {spans_text(spans, clock=clock)}): "
               f"accommodated, the model watched from now on has {p} = {x:.6g}")
    elif act == "accommodated":
        did = f"accommodated: the model watched from now on has {p} = {x:.6g}"
    elif act == "sensor out":
        did = f"sensor {p} taken out of the nominal observer"
    elif act == "repaired":
        did = "closed by the repair"
    elif act == "not accommodated":
        did = "not accommodated (no parameter of the model holds it): watching again on the model as it was"
    else:
        did = _REARMED.get(why, "not decided") + ": watching again on the model as it was"
    return (f"episode {n} closed at t = {clock.text(when)} (alarm at t = {clock.text(a)} on {y}{since}): "
            f"{what}" + (f" ({f})" if f else "") + f"; {did}")


#: Why an episode was closed re-armed (:attr:`bgc.events.EpisodeClosed.reason`), in words.
_REARMED = {
    "glitch": "the alarm was one reading off, the data within the model's noise after it (a glitch of that reading)",
    "false alarm": "no fault explains the data better than chance (a false alarm the detector's budget allows)",
    "memory": "not decided before its record reached the most this diagnosis holds in memory",
    "gap": "not decided before a gap in the data longer than the diagnosis holds",
}


def mismatch_sentence(e: ev.Mismatched, time_of, *, clock: Clock = Clock()) -> str:
    """A :class:`~bgc.events.Mismatched` in words: why the model does not
    fit (or may not), the faults kept as possibilities, and what to
    calibrate (its times as ``clock`` writes them)."""
    samples = e.last + 1
    read = {"start": "set at each row's time, acting until the next row",
            "end": "held over the step that ends at each row's time"}
    again = (f"diagnose again with --input-timing {e.timing} (or the run file's header line "
             f"'# input timing: {e.timing}')")
    if e.timing is not None and e.timing_fits:
        why = (f"the model fits the whole record with the data's inputs read as {read[e.timing]}, and not as they "
               f"were read: the data seem to follow that timing, and what the alarm saw was the inputs read one "
               f"step off; {again}")
        return why + (f"; possibly a fault all the same: {', '.join(e.possible)}" if e.possible else "")
    if e.timing is not None:  # likelier read the other way, and not fitted either way: the timing and more
        return (f"the model does not fit this plant, with the data's inputs read either way, and the record is "
                f"{_times(e.timing_ratio)} times likelier with them read as {read[e.timing]}: {again}, and "
                f"calibrate the model on healthy data whose file says '# input timing: {e.timing}' (bgc calibrate "
                f"MODEL --data FILE --estimate {','.join(e.estimate)})"
                + (f"; possibly a fault all the same: {', '.join(e.possible)}" if e.possible else ""))
    if e.short:
        why = (f"the model may not fit this plant: the fault's onset leaves {samples} sample(s) before it, fewer than "
               f"the {e.least} that would show the model fitted the plant before a fault; a fault since the data's "
               f"start and a model that does not fit give the same data")
    else:  # a record tested while watching, halved since, carries its own times (span)
        first, last, count = e.span or (time_of(0), time_of(e.last), samples)
        span = "the whole record" if e.last == e.step else "the data before the fault"
        # a finding of the named fault's own residuals after its onset ("with NAME ...") is not the span's
        before = [f for f in e.findings if not f.startswith("with ")]
        said = [f for f in e.findings if f.startswith("with ")]
        if before:
            said.insert(0, f"over {span} (t = {'' if first is None else clock.text(first)} to "
                           f"{'' if last is None else clock.text(last)}, {count} samples) " + "; ".join(before))
        why = "the model does not fit this plant: " + "; ".join(said)
    if e.possible:
        why += f"; possibly a fault all the same: {', '.join(e.possible)}"
    words = ",".join(e.estimate)
    return why + f"; calibrate the model on healthy data (bgc calibrate MODEL --data FILE --estimate {words})"


def _times(log_ratio: float) -> str:
    """A likelihood ratio from its log, as a sentence prints it (1e+300 and up: 'more than 1e300')."""
    return f"{math.exp(log_ratio):.3g}" if log_ratio < 690 else "more than 1e300"


#: The fields of events that hold steps of the time grid besides ``step``: in :func:`record` each is a
#: time, its step beside it as ``<name>_step`` (times in the model's unit wherever a value is public).
STEP_FIELDS = frozenset({"since", "onset", "onsets", "first", "last", "start", "was", "alarmed", "again",
                         "until", "change"})
#: The fields of events that hold a time (in the model's unit) itself: written with 12 significant digits, as
#: every time of a record is (a logger's Unix seconds keep their fraction), not a value's 6.
TIME_FIELDS = frozenset({"time", "alarm", "began"})


def record(e, time_of, *, clock: Clock = Clock()) -> dict:
    """Event ``e`` as plain data: its type, time, fields and sentence (a
    field holding a step, :data:`STEP_FIELDS`, as a time, with
    ``<name>_step`` its step). The times are numbers in the model's time
    unit; the sentence writes them as ``clock`` says."""
    out = {"event": type(e).__name__, "time": None}

    def when(step):
        t = time_of(step)
        return None if t is None or not math.isfinite(t) else float(time_text(t))

    step = getattr(e, "step", None)
    said = getattr(e, "said", None)  # a misfit a monitor said on data its record forgot: its steps are the record's then
    if said is not None:
        out["time"] = float(time_text(said))
    elif isinstance(e, ev.Bridged):  # the row after the gap
        out["time"] = float(time_text(e.time))
    elif step is not None:
        out["time"] = when(step)
    for f in dataclasses.fields(e):
        v = getattr(e, f.name)
        if said is not None and f.name in STEP_FIELDS | {"step"}:
            v = None
        elif f.name == "said" and v is not None:
            v = float(time_text(v))
        elif f.name == "span" and v is not None:
            v = [float(time_text(v[0])), float(time_text(v[1])), int(v[2])]
        elif f.name in STEP_FIELDS and v is not None:
            out[f"{f.name}_step"] = list(v) if isinstance(v, tuple) else v
            v = [when(k) for k in v] if isinstance(v, tuple) else when(v)
        elif isinstance(v, float) and f.name in TIME_FIELDS:
            v = float(time_text(v)) if math.isfinite(v) else None
        elif isinstance(v, float):
            v = float(f"{v:.6g}") if math.isfinite(v) else None
        elif isinstance(v, tuple):
            v = [list(x) if isinstance(x, tuple) else x for x in v]
        out[f.name] = v
    out["text"] = sentence(e, time_of, clock=clock)
    return out


#: Events the command line prints after a diagnosis (the others are in the report).
NOTABLE = (ev.SensorMissing, ev.ColumnIgnored, ev.SensorSilent, ev.SensorStopped, ev.SensorResumed,
           ev.InputFromModel, ev.ModeHidden, ev.ModesReread, ev.InputHeld, ev.Gap, ev.SampleSkipped, ev.Degenerate,
           ev.AllTried, ev.ReadingFrozen, ev.Rescued, ev.Truncated, ev.AtPriorBound, ev.NoLikelihood, ev.Misfit, ev.SensorExcluded,
           ev.Bridged,
           ev.EpisodeClosed, ev.Repaired, ev.Overruled, ev.Uncertain, ev.NoFault, ev.Redated, ev.FalseAlarm, ev.Glitch,
           ev.ChangeMissed, ev.Mismatched, ev.ObserverRestarted)


def notes(events, time_of, *, clock: Clock = Clock()) -> list[str]:
    """The :data:`NOTABLE` events among ``events`` in words (their times as
    ``clock`` writes them), for the command line: two or more :class:`~bgc.events.Overruled` are one
    sentence naming them all, in the place of the first (the report keeps
    one sentence each, with the symbol that ruled each out), and so are two
    or more :class:`~bgc.events.ObserverRestarted`, and two or more
    :class:`~bgc.events.InputHeld` of one input (a logger that writes an
    input when it changes holds it at every change)."""
    overruled = [e.hypothesis for e in events if isinstance(e, ev.Overruled)]
    restarts = [e for e in events if isinstance(e, ev.ObserverRestarted)]
    held: dict[str, list] = {}
    for e in events:
        if isinstance(e, ev.InputHeld):
            held.setdefault(e.input, []).append(e)
    out, said = [], False
    for e in events:
        if not isinstance(e, NOTABLE):
            continue
        if isinstance(e, ev.InputHeld) and len(held[e.input]) > 1:
            runs = held[e.input]
            if e is runs[0]:  # one line for the input, in the place of its first hold
                out.append(f"input u:{e.input} is empty {len(runs)} times, from t = "
                           f"{_t(time_of, runs[0].step, clock)} to "
                           f"t = {_t(time_of, runs[-1].step, clock)}: each time its last value is held until a value "
                           "arrives (a logger that writes it when it changes; the report lists each)")
            continue
        if isinstance(e, ev.ObserverRestarted) and len(restarts) > 1:
            if e is restarts[0]:  # one line for them all, in the place of the first
                out.append(f"the Kalman observer whose residuals the drift test reads lost its estimate "
                           f"{len(restarts)} times, from t = {_t(time_of, restarts[0].step, clock)} to t = "
                           f"{_t(time_of, restarts[-1].step, clock)}, and started again each time from the particle "
                           "observer's cloud (the report lists each)")
            continue
        if isinstance(e, ev.Overruled) and len(overruled) > 1:
            if not said:
                out.append(f"{', '.join(overruled)}: ruled out by the symbols, but with their magnitudes held static "
                           f"they explain the data as well as the others: candidates all the same (the report says "
                           f"which symbol ruled out each)")
                said = True
            continue
        out.append(sentence(e, time_of, clock=clock))
    return out


def fault_sentence(e, since, per_time: str = "per unit time", *, clock: Clock = Clock()) -> str:
    """What a fault estimate ``e`` (:class:`~bgc.diagnosis.values.Estimate`)
    says in plain words: which kind of thing failed (a sensor, an actuator,
    a part of the plant), how and how much, ``since`` the onset's time
    (None: not known). A magnitude that presses against its prior's bound
    says "or more". ``per_time``: a drift's rate is so much ``per s``
    (:attr:`bgc.output.labels.Labels.per_time`); ``clock``: how ``since``
    is written (:class:`~bgc.data.clock.Clock`; the default: as a number).

    >>> from bgc.diagnosis.values import Estimate
    >>> e = Estimate("P_offset", "bias", "bias", 3.1, 0.1, 2.9, 3.3, 0.95, 3.1, 0.0,
    ...              target="sensor", subject="P", unit="bar")
    >>> fault_sentence(e, 140.0)
    'sensor P reads 3.1 bar high since t = 140'
    >>> fault_sentence(e, 1772433060.5, clock=Clock.of([1772433000.5], "s"))
    'sensor P reads 3.1 bar high since t = 2026-03-02T06:31:00.5Z'
    >>> e = Estimate("R", "abrupt", "bias", 2.0, 0.1, 1.9, 2.0, 0.95, 4.0, 2.0, bound="high", subject="R", unit="ohm")
    >>> print(fault_sentence(e, None))
    parameter R rose by 2 ohm (+100 %), or more: the model's prior ends there
    >>> e = Estimate("F12_noise", "noise", "bias", 4.0, 0.3, 3.4, 4.6, 0.95, 5.0, 1.0, target="sensor", subject="F12")
    >>> fault_sentence(e, 60.0)
    "sensor F12's noise is 5 times its own since t = 60"
    >>> e = Estimate("K", "stuck_off", "switch", 1.0, 0.0, 1.0, 1.0, 0.95, 1.0, 0.0, target="switch", subject="K")
    >>> fault_sentence(e, 0.99)
    'switch K is stuck OFF, at the latest since t = 0.99'
    >>> fault_sentence(dataclasses.replace(e, kind="uncommanded_on"), 0.99)
    'switch K turned ON without a command at t = 0.99'
    """
    from ..kinds import fault_kind, stuck_state

    v = e.value
    if not math.isfinite(v):
        return f"{e.target} {e.subject or e.parameter}: {e.kind} of unknown size"
    size = f"{abs(v):.4g}" + (f" {e.unit}" if e.unit else "")
    rate = f"{size} {per_time}"
    up = v >= 0
    name = e.subject or e.parameter
    match (e.target, e.kind):
        case ("sensor", "bias"):
            text = f"sensor {name} reads {size} {'high' if up else 'low'}"
        case ("sensor", "stuck"):
            text = f"sensor {name} is stuck at {v:.4g}" + (f" {e.unit}" if e.unit else "")
        case ("sensor", "drift"):
            text = f"sensor {name}'s reading drifts {'up' if up else 'down'} by {rate}"
        case ("sensor", "noise"):
            text = f"sensor {name}'s noise is {fault_kind(e.kind).noise_factor(v):.3g} times its own"
        case ("actuator", "gain"):
            text = f"actuator {name} delivers {100 * abs(v):.3g} % {'more' if up else 'less'} than commanded"
        case ("actuator", "bias"):
            text = f"actuator {name} delivers {size} {'more' if up else 'less'} than commanded"
        case ("actuator", "drift"):
            text = f"actuator {name}'s output drifts {'up' if up else 'down'} by {rate} from the command"
        case ("switch", kind) if releases(kind):
            text = f"switch {name} turned {stuck_state(kind)} without a command"
        case ("switch", _):
            text = f"switch {name} is stuck {stuck_state(e.kind)}"
        case (_, "incipient"):
            text = f"parameter {name} drifts {'up' if up else 'down'} by {rate}"
        case _:
            percent = f" ({100 * v / abs(e.nominal):+.3g} %)" if e.nominal else ""
            text = f"parameter {name} {'rose' if up else 'fell'} by {size}{percent}"
    if since is not None and math.isfinite(since) and e.target == "switch" and releases(e.kind):
        text += f" at t = {clock.text(since)}"  # (it shows at once: the mode asks for the other state)
    elif since is not None and math.isfinite(since):
        # a stuck switch shows only when a mode asks it to move: it stuck at that latest
        text += f"{', at the latest' if e.target == 'switch' else ''} since t = {clock.text(since)}"
    if e.bound is not None:
        text += ", or more: the model's prior ends there"
    return text


def change_text(window: int, statistic: float, threshold: float) -> str:
    """What the change test saw at its change point (the ``change`` alarm,
    :meth:`bgc.diagnosis.diagnoser.Diagnoser._missed_change`)."""
    return (f"its residuals from there on differ from those before by {statistic:.1f} (Welch's statistic over the "
            f"record's {window} last sample(s), or their variances' ratio; threshold {threshold:.1f})")


def alarm_text(test: str, window: int, statistic: float, threshold: float) -> str:
    """What the detector's test ``test`` saw (:class:`bgc.diagnosis.values.Detection`)."""
    if test == "drift":
        return (f"the drift test's statistic over {window} sample(s) reached {statistic:.1f} (threshold "
                f"{threshold:.1f})")
    if test == "variance" and statistic > threshold:
        return (f"the variance of its residual over {window} sample(s) rose to {statistic:.3g} times the predicted "
                f"(bound {threshold:.3g})")
    if test == "variance":
        return (f"the variance of its residual over {window} sample(s) fell to {statistic:.3g} times its sensor's "
                f"noise variance (bound {threshold:.3g}): a reading that no longer moves")
    if test == "pooled":
        return (f"the pooled test of every sensor's residuals over {window} sample(s) reached {statistic:.1f} "
                f"(chi-square, threshold {threshold:.1f}; this sensor's share the largest)")
    if test == "matched":
        return (f"the matched test of a fault model's response over {window} sample(s) reached {statistic:.1f} "
                f"(threshold {threshold:.1f}; the sensor that model moves most)")
    if test == "change":
        return ("found over the record at its end (the whole record, or the one kept while watching), no test "
                "having alarmed while it ran: "
                + change_text(window, statistic, threshold))
    if test == "frozen":
        return (f"its reading repeated {statistic:.0f} times to the last digit (a frozen sensor; "
                f"{threshold:.0f} repeats alarm at the data's resolution)")
    return f"its residual over {window} sample(s) reached {statistic:.1f} (threshold {threshold:.1f})"
