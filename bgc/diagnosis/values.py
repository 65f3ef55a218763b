"""The values the diagnosis hands over, as frozen dataclasses: an alarm
(:class:`Detection`), a symbol read (:class:`Symbol`), the static
posterior of a hypothesis, each hypothesis's estimate and record, the
diagnosis, and (online) the belief after each sample (:class:`Belief`).
They import no algorithm: the parts of the loop import them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..data.sampler import DataSummary
from ..filters.cubature import BankResult
from ..filters.residuals import Innovations
from ..data.clock import Clock
from .options import DiagnosisOptions


@dataclass(frozen=True, slots=True)
class Estimate:
    """The fault magnitude at the end of the run: ``magnitude`` names it (bias
    or slope), ``value`` its mean, ``low`` and ``high`` the interval of
    probability ``level``; ``parameter_value``: the faulty parameter's value
    (nominal + bias, or at the last step for a drift); ``truth`` when the
    run records it."""

    parameter: str
    kind: str
    magnitude: str
    value: float
    std: float
    low: float
    high: float
    level: float
    parameter_value: float
    nominal: float
    truth: float | None = None
    method: str = "filter"
    #: ``low`` or ``high`` when the interval presses against that bound of the prior
    #: (:func:`bgc.diagnosis.estimate.pressed`): the bound, not the data, limits it.
    bound: str | None = None
    #: What the fault strikes (``parameter``, ``sensor``, ``actuator``), its name in the
    #: model, and its unit (None: none declared, or a gain).
    target: str = "parameter"
    subject: str = ""
    unit: str | None = None

    @property
    def covers(self) -> bool | None:
        return None if self.truth is None else bool(self.low <= self.truth <= self.high)

    @property
    def relative_error(self) -> float | None:
        return None if self.truth is None else abs(self.value - self.truth) / abs(self.truth or 1.0)


@dataclass(frozen=True, slots=True)
class Drop:
    """Why a hypothesis is out, decided once where it is decided: ``code``
    (one of :data:`bgc.events.DROP_REASONS`), the ``step`` it is
    dropped at, and ``reason``, a sentence of the runtime's numbers."""

    code: str
    step: int
    reason: str


@dataclass(frozen=True, slots=True)
class Hypothesis:
    """One fault model: its filters from every onset tried (``onset_steps``, with
    their posterior probabilities), and from the most probable one
    (``start_step``) its per-step predicted measurements, normalised residuals,
    state estimates (mean, std of the plant's states) and magnitude (mean,
    interval), its ``drop`` (a :class:`Drop`; None: it survived;
    ``dropped_step`` and ``reason`` read it), its log evidence (over the onsets)
    and posterior probability among the hypotheses (0 until it is weighed).
    With the magnitude held static (``identify =
    "kalman"``, or ``rank``): ``static_log_evidence``, the evidence of its
    model with the magnitude held static (None: not computed); ``static``,
    its static posterior (Kalman filters); ``estimate`` is then the static
    posterior's and ``filter_estimate`` the particle filters' own;
    ``static_alarm``: the first alarm of the consistency test on the static
    posterior's most likely cell (None: it passed, or was not run).
    ``ruled_out``: the signature and symbol that ruled it out ("" when the
    symbols kept it); it was weighed by its static posterior alone (step 6b,
    ``recheck``). ``start_step``, ``onset_steps``, ``dropped_step`` and
    ``onset_step`` are steps of the run's time grid (:meth:`Diagnosis.time_of` gives their
    times; :meth:`bgc.DiagnosisReport.table` lists each hypothesis with
    times in the model's unit)."""

    name: str
    parameter: str
    kind: str
    signatures: tuple[str, ...]
    start_step: int
    onset_steps: tuple[int, ...]
    onset_posterior: tuple[float, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    z: np.ndarray
    x_mean: np.ndarray
    x_std: np.ndarray
    magnitude: np.ndarray
    magnitude_band: np.ndarray
    log_evidence: float
    estimate: Estimate
    seconds: float
    posterior: float = 0.0
    drop: Drop | None = None
    static_log_evidence: float | None = None
    static: StaticPosterior | None = None
    filter_estimate: Estimate | None = None
    static_alarm: Detection | None = None
    ruled_out: str = ""
    #: a fault that comes and goes: its :class:`~bgc.diagnosis.intermittent.Intermittence` (None: persistent)
    intermittent: Any = None

    def __repr__(self) -> str:  # its arrays would flood a notebook: what a reader wants
        return (f"<Hypothesis {self.name}: posterior {self.posterior:.3g}, {self.estimate.magnitude} "
                f"{self.estimate.value:.4g} [{self.estimate.low:.4g}, {self.estimate.high:.4g}] "
                f"({self.estimate.method}){'' if self.drop is None else ', dropped: ' + self.drop.code}>")

    @property
    def dropped_step(self) -> int | None:
        """The step it was dropped at (None: it survived)."""
        return None if self.drop is None else self.drop.step

    @property
    def reason(self) -> str:
        """Why it was dropped ("" when it survived)."""
        return "" if self.drop is None else self.drop.reason

    @property
    def onset_step(self) -> int:
        """The most probable onset, a step of the run's time grid: the static
        posterior's when there is one, else the filters'."""
        return self.static.onset if self.static is not None and math.isfinite(self.static.log_evidence) else self.start_step


@dataclass(frozen=True, slots=True)
class ModeSplit:
    """Fault models of an ambiguous verdict of a model with modes that show
    the same signature in every mode the plant was in from the onset on
    (``seen``: those modes' names) but not in others: ``pairs`` holds (one
    model, the other, the modes whose signatures differ for them). Data that
    reach a switch to one of those modes may separate them
    (:meth:`bgc.diagnosis.isolate.ModeSignatures.split`)."""

    seen: tuple[str, ...]
    pairs: tuple[tuple[str, str, tuple[str, ...]], ...]


@dataclass(frozen=True, slots=True)
class Fit:
    """The test of the model on steps ``0 .. end - 1`` (the data before the
    fault, or the whole record): per sensor read, the summary of the
    nominal Kalman filter's normalised residuals (``innovations``) and their
    mean offset in the sensor's unit (``offsets``, y - predicted, by sensor
    name); ``findings``, a sentence per sensor that fails at ``level``
    (:func:`bgc.filters.residuals.findings`), and the test each failed
    (``failed``: ``mean`` or ``variance``); ``short``: fewer than ``least``
    samples before an alarm's onset, too few to tell. ``fits``: neither.
    ``unchanged``: an unexplained alarm's whole record, tested because its
    residuals showed no change at the change point
    (:func:`bgc.diagnosis.finish.unchanged_misfit`)."""

    end: int
    least: int
    level: float
    innovations: tuple[Innovations, ...]
    offsets: tuple[tuple[str, float], ...]
    findings: tuple[str, ...]
    short: bool
    failed: tuple[str, ...] = ()
    unchanged: bool = False

    @property
    def fits(self) -> bool:
        return not self.findings and not self.short


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """What :func:`diagnose` found. ``verdict``: ``no fault``, ``mismatch``, ``isolated``
    (one hypothesis survives), ``ambiguous`` (several do: ``candidates``, best
    first) or ``unexplained`` (none does; ``candidates`` then holds the one
    that lasted longest). Steps are steps of the model's time grid
    (``time[step]``: one per sample, and one per step the data have no
    sample for, :mod:`bgc.data.sampler`); ``nominal_x_mean`` and
    ``nominal_x_std`` are the nominal observer's state estimates (steps x
    ``states``). ``events``: what happened, in time order
    (:mod:`bgc.events`); ``data``: how the data met the model (per
    input, data or model; sensors present; samples skipped; gaps);
    ``fit``: the test of the model on the data before the fault (the whole
    record without one; :mod:`bgc.diagnosis.fit`), whose failure makes the
    verdict ``mismatch`` (the model does not fit this plant; ``candidates``
    then hold the faults the diagnosis would have named, as possibilities);
    ``mode_split``: for an ambiguous verdict of a model with modes, the
    candidates another mode may separate (a :class:`ModeSplit`; None: none,
    or no modes); ``submodels``: the submodels a decomposed diagnosis ran
    on (:mod:`bgc.diagnosis.decomposed`; empty: the whole plant);
    ``clock``: how its times are written in words (a
    :class:`~bgc.data.clock.Clock` of ``time`` and the model's time unit:
    ISO 8601 timestamps for a run of absolute times), by its sentences, its
    report and the command line."""

    model: str
    time: np.ndarray
    outputs: tuple[str, ...]
    states: tuple[str, ...]
    verdict: str
    detection: Detection | None
    onset_step: int | None
    symbols: tuple[Symbol, ...]
    refuted: tuple[tuple[str, str], ...]
    hypotheses: tuple[Hypothesis, ...]
    candidates: tuple[str, ...]
    nominal_y_mean: np.ndarray
    nominal_y_std: np.ndarray
    nominal_z: np.ndarray
    nominal_x_mean: np.ndarray
    nominal_x_std: np.ndarray
    statistics: np.ndarray
    threshold: float
    options: DiagnosisOptions
    seconds: float
    clock: Clock
    events: tuple = field(default=())
    data: DataSummary | None = None
    mode_split: ModeSplit | None = None
    fit: Fit | None = None
    submodels: tuple[str, ...] = ()

    def __repr__(self) -> str:  # its arrays would flood a notebook: what a reader wants
        onset = "" if self.onset is None else f", onset t = {self.clock.text(self.onset)}"
        return (f"<Diagnosis of {self.model}: {self.verdict}"
                + (f": {', '.join(self.candidates)}" if self.candidates else "")
                + f"{onset}, {len(self.hypotheses)} hypotheses, {len(self.time)} steps>")

    @property
    def best(self) -> Hypothesis | None:
        if not self.candidates:
            return None
        return next(h for h in self.hypotheses if h.name == self.candidates[0])

    @property
    def estimate(self) -> Estimate | None:
        return self.best.estimate if self.best is not None else None

    @property
    def onset(self) -> float | None:
        """The diagnosed fault's onset, in the model's time unit (None: no
        fault); ``onset_step`` is its step of the time grid."""
        return self.time_of(self.onset_step)

    def time_of(self, step: int | None) -> float | None:
        return None if step is None else float(self.time[step])

    def state_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The state estimate (mean, std; steps x ``states``) the diagnosis
        stands for: the nominal observer's, then from its onset on the
        filter of the diagnosed hypothesis (``candidates[0]``)."""
        mean, std = self.nominal_x_mean.copy(), self.nominal_x_std.copy()
        best = self.best
        if best is not None:
            mean[best.start_step:], std[best.start_step:] = best.x_mean, best.x_std
        return mean, std


#: The diagnoser's phases, in loop order: the nominal observer watches the
#: data (no alarm yet); after an alarm it waits for the samples the symbols
#: read (isolating); the hypotheses' filters follow the data (tracking); the
#: diagnosis is made (decided).
PHASES = ("watching", "isolating", "tracking", "decided")


@dataclass(frozen=True, slots=True)
class Live:
    """A hypothesis being tracked: its posterior among those tracked (from
    the filters' running evidence and the priors), its most probable onset
    (step) and that filter's running estimate of the magnitude (mean, with
    the central interval of the diagnosis's level; NaN before it starts)."""

    name: str
    posterior: float
    onset: int
    value: float
    low: float
    high: float
    rejected: bool


@dataclass(frozen=True, slots=True)
class Belief:
    """What the diagnoser believes after a sample: at ``step`` (time
    ``time``), the ``phase`` (:data:`PHASES`), the ``alarm`` (None before
    one), the hypotheses tracked (best first; empty before tracking, or while
    the batch diagnosis leaves the tracking to :meth:`finish`), and the
    events of this step. ``verdict`` and ``candidates``: once decided."""

    step: int
    time: float
    phase: str
    alarm: Detection | None
    hypotheses: tuple[Live, ...]
    events: tuple
    verdict: str | None = None
    candidates: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class Isolation:
    """What the qualitative isolation found (step 3): the ``onset`` the
    symbols were read from, the ``symbols``, the signatures they ``refuted``
    ((name, why)) and the fault models of those (``ruled_out``), the
    signatures kept per fault model (``models``), the fault models tried
    (``names``) and whether each is tried from a drift's onsets (``drifts``:
    a drift, or a burst of noise, :attr:`bgc.kinds.FaultKind.searched_back`), each one's onsets for the particle
    filters (``starts_of``; a drift's reach back over ``reach``) and for the
    Kalman filters (``kalman_onsets`` by drift, over ``kalman_reach``), and
    the events of the isolation; ``excluded``: the fault models the
    detector's test rules out whatever the symbols (a frozen reading: every
    fault but its sensor's ``stuck``), never weighed."""

    onset: int
    symbols: tuple
    refuted: tuple[tuple[str, str], ...]
    ruled_out: tuple[str, ...]
    models: dict
    names: list
    drifts: dict
    starts_of: dict
    reach: list
    kalman_onsets: dict
    kalman_reach: list
    events: tuple = ()
    excluded: tuple[str, ...] = ()

    def untried(self, package) -> list[str]:
        """The fault models of ``package`` the symbols ruled out and that
        are not tried (sorted), those the detector's test excludes left out."""
        return sorted({n for n in self.ruled_out if n in package.MODELS} - set(self.names) - set(self.excluded))


@dataclass(frozen=True, slots=True)
class Detection:
    """An alarm: at step ``step`` (index into the run), on ``sensor`` (its
    name) with window ``window`` and statistic ``statistic`` (``|S| > threshold``);
    ``onset_step``: the estimated first faulty step (None: not estimated, see
    :meth:`DetectorBank.update`); ``test``: the family of tests that fired
    (:data:`bgc.diagnosis.detect.TESTS`: ``mean``, ``drift``, ``variance``,
    ``frozen``, ``pooled``, ``matched``; and ``change``, an alarm raised at
    the end of a record no test alarmed on, at the change point found then,
    :meth:`bgc.diagnosis.diagnoser.Diagnoser._missed_change`, or of the
    record kept while watching, :meth:`~bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching`:
    its statistic the change test's, its window the samples from there to
    that end (:attr:`raised`); for
    ``variance`` the statistic is the window's variance
    ratio and the threshold the bound it crossed, for ``frozen`` the
    statistic is the readings repeated and the threshold the repeats that
    alarm)."""

    step: int
    sensor: str
    window: int
    statistic: float
    threshold: float
    onset_step: int | None
    test: str = "mean"

    @property
    def raised(self) -> int:
        """The step at which the alarm was raised: ``step``, but for the
        ``change`` test the end of the record it tested (``step + window - 1``)."""
        return self.step + self.window - 1 if self.test == "change" else self.step


@dataclass(frozen=True, slots=True)
class Symbol:
    """A sensor's observed deviation: magnitude ``sign`` (+ or -) seen at
    ``step`` by a window of ``window`` samples (``statistic``: its Z), and
    ``slope`` (+, -, or "" when not significant; ``slope_statistic``: its Z)."""

    sensor: str
    sign: str
    step: int
    statistic: float
    window: int = 1
    slope: str = ""
    slope_statistic: float = 0.0


@dataclass(frozen=True, slots=True)
class StaticPosterior:
    """The posterior of a hypothesis's onset and magnitude, with the magnitude
    held static. ``onsets`` (steps) with their prior ``widths``; ``values``
    (onsets x points): the magnitude of each cell; ``loglik``: log p(y |
    onset, magnitude) over the whole run; ``log_evidence``: log p(y |
    hypothesis) (the onset's prior up to the factor common to every
    hypothesis); the magnitude's posterior ``mean``, ``std`` and central
    interval (``low``, ``high``) of probability ``level``; ``change``: the
    posterior mean of the parameter's change at the last step (the bias, or
    slope x time since the onset); ``onset_posterior`` (the mass of each
    onset of the grid) and the most probable ``onset`` (the largest mass per
    sample the onset stands for); ``passes``: grids computed; ``best``: the
    most likely cell (onset, magnitude) and ``residuals`` (steps x outputs):
    its normalised residuals (NaN before its onset), for a consistency test
    of the static model; ``truncated``: the posterior may reach past the
    grid's last pass (a row still holds mass at an end short of a bound of
    the prior); ``trace`` (steps x 2): the magnitude's posterior mean and
    std given the data up to each step, over the last pass's cells (point
    masses: a picture of how the data narrowed it down, limited to the span
    of the final grid); ``path``: when asked for (:func:`record_path`), one
    filter's run at the most probable onset with the posterior mean
    magnitude; ``seconds``: the time it took (set by its caller). ``values``
    and ``loglik`` are object arrays of rows when the onsets' rows differ in
    length."""

    name: str
    onsets: tuple[int, ...]
    widths: tuple[float, ...]
    values: np.ndarray
    loglik: np.ndarray
    log_evidence: float
    mean: float
    std: float
    low: float
    high: float
    level: float
    change: float
    onset: int
    onset_posterior: tuple[float, ...]
    passes: int
    best: tuple[int, float] | None = None
    residuals: np.ndarray | None = None
    truncated: bool = False
    trace: np.ndarray | None = None
    path: "BankResult | None" = None
    seconds: float = 0.0
