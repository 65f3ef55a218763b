"""What happened during a diagnosis, as data: one frozen value per event.

The diagnoser (:mod:`bgc.diagnosis.diagnoser`) and the data reader
(:mod:`bgc.data.sampler`) emit these; a :class:`~bgc.diagnosis.diagnoser.Belief`
carries the events of its step and a
:class:`~bgc.diagnosis.diagnose.Diagnosis` all of them, in time order. They are
rendered into sentences only by :mod:`bgc.output.events` (the report, the
monitor's lines); tests assert on their fields. ``step`` is a step of the
model's time grid (the diagnosis's ``time[step]`` is its time); ``None``
where the event has no instant (it holds for the whole run).

In loop order: the data (:class:`SensorMissing`, :class:`ColumnIgnored`, :class:`SensorSilent`,
:class:`SensorStopped`, :class:`SensorResumed`, :class:`InputFromModel`, :class:`InputHeld`, :class:`Gap`,
:class:`SampleSkipped`), detection (:class:`Alarmed`, :class:`Degenerate`,
:class:`Switched`), isolation (:class:`Isolated`, :class:`AllTried`),
tracking (:class:`Started`, :class:`Stopped`, :class:`Dropped`, :class:`Rescued`), weighing
(:class:`Truncated`, :class:`AtPriorBound`, :class:`NoLikelihood`, :class:`Misfit`), and the end
(:class:`Refined`, :class:`SensorExcluded`, :class:`Checkpoint`, :class:`Mismatched`, :class:`Decided`);
a monitor's fault log (:class:`EpisodeClosed`, :class:`Repaired`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class SensorMissing:
    """The data have no column for sensor ``sensor``: it is diagnosed
    without (its fault signatures and detection use the other sensors)."""

    sensor: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class ColumnIgnored:
    """The data's column ``column`` (``y:NAME`` or ``u:NAME``) is no sensor
    or input of the model: it is not used (a misspelt name, or a signal the
    model does not have)."""

    column: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class SensorSilent:
    """Sensor ``sensor``'s column has no finite value in the run."""

    sensor: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class SensorStopped:
    """Sensor ``sensor`` has had no sample since step ``since`` (its last
    sample was the step before), longer than the gap limit, while rows
    still come: it is diagnosed without it until it resumes (given at
    ``step``, the first row past the limit)."""

    sensor: str
    since: int
    step: int


@dataclass(frozen=True, slots=True)
class SensorResumed:
    """Sensor ``sensor``, silent since step ``since`` (a
    :class:`SensorStopped`), gives samples again from ``step``."""

    sensor: str
    since: int
    step: int


@dataclass(frozen=True, slots=True)
class InputFromModel:
    """Input ``input`` comes from the model's declared input function:
    ``reason`` ``absent`` (no ``u:`` column in the data) or ``before-data``
    (its column has no value yet at ``step``; from the model until its first
    value)."""

    input: str
    reason: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class InputHeld:
    """Input ``input``'s cell is empty at ``step``: its last recorded value
    ``value`` is held (zero-order hold) until a value arrives."""

    input: str
    step: int
    value: float


@dataclass(frozen=True, slots=True)
class Gap:
    """No sample between ``step`` (the first step without one) and
    ``step + steps - 1``, longer than the gap limit: the filters predict
    across it (their measurements missing)."""

    step: int
    steps: int


@dataclass(frozen=True, slots=True)
class SampleSkipped:
    """The sample of data line ``line`` (time ``time``) falls on step
    ``step`` of the model's time grid, which a sample before it already took:
    it is skipped (the first of a step is used). Emitted once per run;
    ``count`` is how many were skipped by the end (the report's count)."""

    step: int
    line: int | None
    time: float
    count: int = 1


@dataclass(frozen=True, slots=True)
class Alarmed:
    """The detector's alarm: at ``step`` on ``sensor`` (window ``window``
    samples, statistic above ``threshold``); ``onset``: the estimated change
    point; ``test``: the family of tests that fired (``mean``, ``drift``,
    ``variance``, ``frozen``: :class:`bgc.diagnosis.values.Detection`)."""

    step: int
    sensor: str
    window: int
    statistic: float
    threshold: float
    onset: int
    test: str = "mean"


@dataclass(frozen=True, slots=True)
class Degenerate:
    """The nominal particle observer degenerates: mean effective sample
    size ``ess`` of ``particles`` before the alarm (or over the run);
    ``switched``: the diagnosis went on with cubature Kalman filters."""

    method: str
    ess: float
    particles: int
    switched: bool
    step: int | None = None


@dataclass(frozen=True, slots=True)
class Switched:
    """From ``step`` on, the diagnosis is made again with filter ``to``
    (every step replayed) because of ``why`` (``degenerate``)."""

    to: str
    why: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class Isolated:
    """The qualitative isolation at ``step``: the symbols read from
    ``onset`` on kept the fault models ``kept``; ``refuted``: (signature,
    why) pairs."""

    step: int
    onset: int
    kept: tuple[str, ...]
    refuted: tuple[tuple[str, str], ...]


@dataclass(frozen=True, slots=True)
class AllTried:
    """Every fault model is tried, not only those the symbols kept:
    ``why`` ``no-signature`` (no signature agrees with the symbols) or
    ``unexplained`` (none of those kept explains the data: the diagnosis is
    made again with all of them)."""

    why: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class ReadingFrozen:
    """The detector saw ``sensor`` frozen from ``onset`` (its reading
    repeated to the last digit beyond chance: :class:`Alarmed`'s ``test``
    ``frozen``): no fault of the plant does that, so only the sensor's
    ``stuck`` fault models (``kept``; none: the model declares none, and the
    verdict is unexplained) are tried."""

    step: int
    sensor: str
    onset: int
    kept: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Started:
    """Hypothesis ``hypothesis``'s filters start tracking, from the onsets
    ``onsets`` (steps)."""

    step: int
    hypothesis: str
    onsets: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class Refined:
    """The verdict's onset ``onset`` (a step) of hypothesis ``hypothesis``
    lies outside the onsets its filters tracked online (``first`` to
    ``last``, its :class:`Started` event): the final weighing of the whole
    record placed it there."""

    step: int
    hypothesis: str
    onset: int
    first: int
    last: int


@dataclass(frozen=True, slots=True)
class Dropped:
    """Hypothesis ``hypothesis`` is dropped at ``step``: ``reason`` is one of
    :data:`DROP_REASONS`, ``detail`` says more (a sentence of the runtime's
    numbers)."""

    step: int
    hypothesis: str
    reason: str
    detail: str


@dataclass(frozen=True, slots=True)
class Stopped:
    """Every filter of hypothesis ``hypothesis`` stopped at ``step`` while the
    online diagnoser tracked it (far off the data, or another onset of it
    explained the data decisively better): said as the data come; the end of
    the diagnosis decides its drop (a :class:`Dropped`)."""

    step: int
    hypothesis: str


#: Why a hypothesis is dropped: its filter's residuals failed the
#: consistency test (``inconsistent``); another onset explained the data far
#: better and failed (``pruned``); the data favour another hypothesis by the
#: Bayes factor (``bayes-factor``); with its magnitude held static, no finite
#: likelihood (``no-likelihood``) or its residuals failed the test
#: (``static-test``).
DROP_REASONS = ("inconsistent", "pruned", "bayes-factor", "no-likelihood", "static-test", "wrong-direction")


@dataclass(frozen=True, slots=True)
class Rescued:
    """Hypothesis ``hypothesis``'s particle filters failed their test
    (``reason``, at ``step``), but its fault model with the magnitude held
    static passes it: it is kept."""

    hypothesis: str
    reason: str
    step: int | None


@dataclass(frozen=True, slots=True)
class Truncated:
    """Hypothesis ``hypothesis``'s magnitude posterior may reach past the
    Kalman filters' last grid: its evidence and interval may be short."""

    hypothesis: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class AtPriorBound:
    """Hypothesis ``hypothesis``'s magnitude presses against ``side``
    (``low`` or ``high``) of its prior, at ``bound``: its interval is the
    prior's edge, not the data's. At the bound of no change (``bound`` 0)
    the data ask for a change in a direction the model does not list; at
    the other, the fault may be larger than the prior allows."""

    hypothesis: str
    side: str
    bound: float
    value: float
    step: int | None = None


@dataclass(frozen=True, slots=True)
class NoLikelihood:
    """The cubature Kalman filters found no finite likelihood for any
    hypothesis; ``fallback``: the particle filters' evidence is reported
    instead (False: nothing is)."""

    fallback: bool
    step: int | None = None


@dataclass(frozen=True, slots=True)
class Misfit:
    """Hypothesis ``hypothesis`` with its ``magnitude`` held at its most
    probable value ``value`` from step ``start``: its residual of ``sensor``
    over ``window`` samples reached ``statistic`` (threshold
    ``threshold``); ``stretch``: the mean of its residuals over the whole
    stretch from its onset, ``statistic`` standard errors off 0
    (:func:`bgc.diagnosis.static.stretch_alarm`)."""

    hypothesis: str
    magnitude: str
    value: float
    start: int
    sensor: str
    window: int
    statistic: float
    threshold: float
    step: int | None = None
    stretch: bool = False


@dataclass(frozen=True, slots=True)
class Overruled:
    """Hypothesis ``hypothesis`` was ruled out by the symbols (``why``: the
    signature and the symbol), but with its magnitude held static it
    explains the data as well as the others (within the Bayes factor, and
    its consistency test passes): it is a candidate all the same."""

    hypothesis: str
    why: str
    step: int | None = None


@dataclass(frozen=True, slots=True)
class Uncertain:
    """The survivors of the Bayes factor (``candidates``) hold a posterior
    of ``mass`` only, under the ``level`` a verdict promises
    (``DiagnosisOptions.isolation_level``): the most probable hypotheses it
    had dropped, ``kept`` (posteriors ``posteriors``), are candidates too."""

    candidates: tuple[str, ...]
    mass: float
    level: float
    kept: tuple[str, ...]
    posteriors: tuple[float, ...]
    step: int | None = None


@dataclass(frozen=True, slots=True)
class NoFault:
    """After an alarm, no fault at all (the alarm one of the false alarms
    the detector's budget allows) weighed beside the faults: the nominal
    model passes the consistency test of the hypotheses over the whole
    record, and holds ``mass`` of the posterior of it and every fault
    weighed; ``best`` (None: none was weighed) is the likeliest fault, the
    data favouring it over no fault by the log Bayes factor ``log_factor``
    (each fault's prior spread over the horizon's steps as its onset's).
    ``decided``: no fault holds the ``level`` a verdict promises and is the
    verdict; else the faults named cannot be promised without it."""

    mass: float
    best: str | None
    log_factor: float
    level: float
    decided: bool
    step: int | None = None


@dataclass(frozen=True, slots=True)
class IntermittentTried:
    """Fault model ``hypothesis`` was tried as a fault that comes and goes
    (:mod:`bgc.diagnosis.intermittent`): its intermittent hypothesis's log
    evidence exceeds its persistent one's by ``log_factor`` (before their
    priors), with ``spans`` appearances; ``fits``: it passed its fit test."""

    step: int
    hypothesis: str
    log_factor: float
    spans: int
    fits: bool


@dataclass(frozen=True, slots=True)
class Redated:
    """Fault model ``hypothesis`` began after every onset it was tried from
    (:mod:`bgc.diagnosis.later`): its most probable onset moved from step
    ``was`` to step ``onset``, its evidence from there larger by the log
    Bayes factor ``log_factor``; ``alarmed``: the alarm's step (before
    ``onset``: a false alarm came before the fault)."""

    step: int
    hypothesis: str
    was: int
    onset: int
    log_factor: float
    alarmed: int | None = None


@dataclass(frozen=True, slots=True)
class FalseAlarm:
    """The alarm at ``step`` (on ``sensor``, by the ``test``) was a false
    one: the nominal model's residuals stay within its noise from step
    ``again`` to step ``until`` (they pass the test of its fit), where the
    data change again (fault model ``hypothesis`` explains them from there,
    a :class:`Redated` of the first diagnosis; "": the detector armed anew
    alarms there); the diagnosis was made again with the detector armed
    anew from step ``again``."""

    step: int
    sensor: str
    test: str
    again: int
    until: int
    hypothesis: str = ""


@dataclass(frozen=True, slots=True)
class Glitch:
    """The alarm at ``step`` was one reading of ``sensor``, ``statistic``
    of its residual's stds from the model's prediction, and the nominal
    model's residuals stay within its noise from the next step to the
    data's last, ``until``: a glitch of that reading (a spike of the
    sensor's line, a logger's slip), not a fault of the plant or a sensor
    that persists or comes back. The diagnosis was made again with the
    detector armed anew after it, the reading left out of the test of the
    model's fit, and raised no alarm."""

    step: int
    sensor: str
    statistic: float
    until: int


@dataclass(frozen=True, slots=True)
class ChangeMissed:
    """No alarm was raised, yet the whole record fails the test of the
    model while the data before step ``change`` pass it and the residuals
    of ``sensors`` differ after it from before (:func:`bgc.diagnosis.fit.changed`;
    the data before it likelier under the model than like those after it,
    :func:`bgc.diagnosis.fit.misfit_before`): a change the detector's tests
    ``tests`` did not alarm on (a slow drift), not a model that does not fit
    from the start. The diagnosis was made again with every test of the
    detector's bank, and when that named no fault, from an alarm raised at
    the change point; ``found``: whether one of them named a fault or found
    none that explains the change (its verdict is then the diagnosis's; if
    not, the model's misfit stands); ``at_change``: the one from the change
    point; ``bank``: whether the bank's diagnosis was made (not when every
    test of it had run); ``watching``: found while watching, in a record
    bounded by ``keep`` about to be halved (:meth:`bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching`:
    the record failed the test of the model's fit or the CUSUM test of a
    shift of its residuals' mean, each at ``level``,
    :func:`bgc.diagnosis.diagnoser.watch_level`; None: the fit test's own):
    the record's test at step ``step``, and the diagnosis goes on from an
    alarm raised at the change point (``found`` and ``at_change``)."""

    step: int
    change: int
    sensors: tuple[str, ...]
    tests: tuple[str, ...]
    found: bool
    at_change: bool = False
    bank: bool = True
    watching: bool = False
    level: float | None = None


@dataclass(frozen=True, slots=True)
class ObserverRestarted:
    """The Kalman observer run beside the particle one, whose residuals the
    drift test reads (:mod:`bgc.diagnosis.detect`, "A bank of tests"), lost
    its estimate at step ``step`` (its mean or covariance no longer finite:
    a plant far off its model, a state driven where the model has no
    numbers): it starts again there from the particle observer's cloud (its
    mean and covariance), and the drift test's windows holding that step are
    held to the threshold of windows with a reading missing. ``times``: how
    often it has restarted so far in this diagnosis."""

    step: int
    times: int


@dataclass(frozen=True, slots=True)
class Intermittent:
    """The verdict names ``hypothesis`` a fault that comes and goes: its
    magnitude while present ``value`` (interval ``low`` .. ``high``), and
    the ``spans`` it was present over, (appearance, going away) steps of
    the time grid (None: still present at the end); ``posterior``: its
    share of the posterior (intermittent and persistent together)."""

    step: int
    hypothesis: str
    value: float
    low: float
    high: float
    spans: tuple
    posterior: float


@dataclass(frozen=True, slots=True)
class SensorExcluded:
    """Sensor ``sensor``'s fault was isolated (``finding``, in words, at a
    checkpoint at time ``time``): the monitor took it out of the nominal
    observer and goes on watching with the other sensors (``bgc monitor
    --exclude-faulty-sensor``); the diagnosis after it starts there."""

    sensor: str
    finding: str
    time: float
    step: int | None = None


@dataclass(frozen=True, slots=True)
class Bridged:
    """No row from time ``began`` to time ``time`` (``steps`` steps with no
    sample): more than the diagnosis holds in memory, or a clock that
    jumped. The monitor was watching: a new diagnoser takes the row of time
    ``time`` as its first, its observer started from the last estimate run
    on ``ran`` steps by the model with that row's inputs, its spread widened
    (:mod:`bgc.diagnosis.bridge`); a model whose state holds its mode
    (``settled``): anywhere on the course the model settles into, the mode
    read from the data starting among ``modes``, those the course visits;
    where ``ran`` is 0 (the data set the mode, or no eigenvalue is stable)
    anywhere the observer's estimates before the gap were (in the row's mode,
    where the data give it; ``modes`` empty)."""

    began: float
    time: float
    steps: int
    ran: int
    settled: bool = False
    modes: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class EpisodeClosed:
    """Fault episode ``number`` of a monitor's stream (``bgc monitor
    --episodes``), closed at time ``time`` by a checkpoint's diagnosis: the
    alarm at ``alarm`` on sensor ``sensor``, the verdict ``verdict`` and its
    ``candidates``, the time the fault began (``began``: its onset; None: none) and in words
    ``finding`` (its estimate and interval; empty: none), and what the monitor
    did: ``action`` ``accommodated`` (the fault is part of the model watched
    from then on: ``parameter`` at ``value``), ``ended`` (a fault
    accommodated went away by itself, without a repair: ``parameter`` back at
    its value in the model file, ``value``; an intermittent fault), ``sensor out`` (sensor
    ``parameter`` taken out of the nominal observer), ``not accommodated``
    (isolated, but no parameter holds it), ``re-armed`` (the episode not
    decided) or ``repaired`` (a repair came first, verdict ``undecided``).
    The fault log of a monitor is its episodes."""

    number: int
    alarm: float
    sensor: str
    time: float
    verdict: str
    candidates: tuple[str, ...]
    began: float | None
    finding: str
    action: str
    parameter: str | None = None
    value: float | None = None
    step: int | None = None
    #: A fault of a parameter (accommodated, or ``ended``): its appearance's number (2 and on: it
    #: came back), and the spans it was present over, as the episodes tell ((onset, end or None), ...).
    appearance: int = 0
    present: tuple = ()
    #: An episode ``re-armed``: why (``rearm``: not isolated when ``--rearm`` had passed since its alarm;
    #: ``memory``: its record neared the most the diagnosis holds in memory, a fault never decided; ``gap``:
    #: not decided before a gap longer than the diagnosis holds (:class:`Bridged`); ``no
    #: estimate``: isolated without an estimate to accommodate; ``false alarm``: the checkpoint's verdict
    #: after the alarm is no fault, :class:`NoFault`; ``glitch``: no fault, the alarm one reading off and
    #: the data quiet after it, :class:`Glitch`; empty: the other actions).
    reason: str = ""


@dataclass(frozen=True, slots=True)
class Repaired:
    """The plant was said repaired at time ``time`` (a ``# repaired`` line of
    the stream, or :meth:`bgc.service.episodes.Episodes.repaired`): the
    faults of episodes ``episodes`` accommodated until then are taken out
    of the model (``parameters``, back at their values in the model file)
    and the monitor watches on the model as it was."""

    time: float
    episodes: tuple[int, ...]
    parameters: tuple[str, ...]
    step: int | None = None


@dataclass(frozen=True, slots=True)
class Checkpoint:
    """A diagnosis of the data so far, made online at ``step``."""

    step: int
    verdict: str
    candidates: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class ModeHidden:
    """The data have no mode column, and the model has modes: the mode is
    read from the measurements (:mod:`bgc.diagnosis.hidden`), each sample's
    decided at most ``lag`` steps after it."""

    lag: int
    step: int | None = None


@dataclass(frozen=True, slots=True)
class ModeRead:
    """The mode read from the data changes at ``step`` from ``source`` to
    ``target``; ``share``: the weight of the histories that agreed when it was
    decided (under 1: the likeliest, decided when the sample had waited the
    longest it may)."""

    step: int
    source: str
    target: str
    share: float


@dataclass(frozen=True, slots=True)
class ModesReread:
    """The mode hidden: the modes read again from the data with fault model
    ``hypothesis``'s own equations (at the onset and size that make the data
    likeliest with the modes hidden, near the diagnosis's): ``changed``
    samples' modes differ from the nominal model's reading; ``explains``:
    whether the diagnosis with them isolates ``hypothesis`` (the verdict then
    stands on them); ``below``: the hypothesis whose own reading makes the
    data decisively likelier (by ``by`` nats, more than the log of the
    options' Bayes factor) and explains them, this one then weighed out:
    its modes not compared with the nominal reading (``changed`` 0 then
    says nothing) nor the diagnosis made again on them ("": not weighed out)."""

    step: int
    hypothesis: str
    changed: int
    explains: bool
    below: str = ""
    by: float = 0.0


@dataclass(frozen=True, slots=True)
class Mismatched:
    """The model does not fit this plant (:mod:`bgc.diagnosis.fit`): the
    data the verdict says are fault-free, steps 0 to ``last``, fail the
    test of the model (``findings``: a sentence per sensor; one that starts
    ``with NAME`` is of the named fault's own residuals after its onset),
    or (``short``)
    are fewer than ``least`` samples, too few to tell a fault since the
    data's start from a model that does not fit. ``possible``: the faults
    the diagnosis would have named, kept as possibilities; ``estimate``:
    what to calibrate (``bgc calibrate --estimate``'s words); ``timing``:
    the other input timing (``start`` or ``end``) when the whole record is
    decisively likelier with the data's inputs read that way
    (:func:`bgc.diagnosis.fit.timing_told`), None otherwise;
    ``timing_fits``: whether the model then fits it; ``timing_ratio``: the
    log of that likelihood ratio; ``span``: the first and last times of the
    data tested and their samples, when those are not the record's steps 0
    to ``last`` (a monitor's record tested while watching, then halved);
    ``said``: the time it was said as the data came (a bounded record's
    test while watching, a monitor's checkpoint), when the record has since
    forgotten those data and the final diagnosis keeps it: ``step`` and
    ``last`` then count the steps of the record as it was, and ``span``
    holds the times; None otherwise."""

    step: int
    last: int
    findings: tuple[str, ...]
    short: bool
    least: int
    possible: tuple[str, ...]
    estimate: tuple[str, ...]
    timing: str | None = None
    timing_fits: bool = False
    timing_ratio: float = 0.0
    span: tuple | None = None
    said: float | None = None


@dataclass(frozen=True, slots=True)
class Decided:
    """The final verdict, at the last step."""

    step: int
    verdict: str
    candidates: tuple[str, ...]


Event = (SensorMissing | ColumnIgnored | SensorSilent | SensorStopped | SensorResumed | InputFromModel | InputHeld
         | Gap | SampleSkipped | Alarmed | Degenerate | Switched | Isolated | AllTried | ReadingFrozen | Started
         | Refined | Dropped
         | Rescued | Truncated | NoLikelihood | Misfit | AtPriorBound | Overruled | Uncertain | NoFault | IntermittentTried | Intermittent
         | Redated | FalseAlarm | Glitch | ChangeMissed | SensorExcluded | Bridged
         | EpisodeClosed | Repaired | Checkpoint | ModeHidden | ModeRead | ModesReread | Mismatched | Decided)


def shifted(event, by: int):
    """Data event ``event`` (of the rows, while watching) with its steps
    ``by`` earlier: the diagnoser forgot ``by`` steps of its record
    (:meth:`bgc.diagnosis.diagnoser.Diagnoser.step`); None when its step
    falls before the record kept (a ``since`` before it is its first step)."""
    step = getattr(event, "step", None)
    if step is None or not by:
        return event
    if step - by < 0:
        return None
    changes = {"step": step - by}
    since = getattr(event, "since", None)
    if since is not None:
        changes["since"] = max(since - by, 0)
    return dataclasses.replace(event, **changes)
