"""The values the diagnosis hands over, as frozen dataclasses: its options,
each hypothesis's estimate and record, the diagnosis, and (online) the belief
after each sample (:class:`Belief`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .detect import Detection
from .identify import GridOptions
from .isolate import Symbol
from ..data.sampler import DataSummary
from ..filters.cubature import KalmanOptions, StaticPosterior


@dataclass(frozen=True, slots=True)
class DiagnosisOptions:
    """The diagnosis's options, stage by stage (:data:`STAGES`; the loop of
    :mod:`bgc.diagnosis.diagnoser`).

    **Filters** (the nominal observer and the hypotheses' filters):
    ``method``: ``gpf``, ``apf``, ``opf`` (particle filters) or ``ckf`` (no
    particles: the nominal observer is the cubature Kalman filter, and every
    hypothesis the symbols keep goes to the static posterior directly, its
    consistency test dropping those that fail; ``particles`` then only sizes
    the open-loop cloud of the symbols); ``particles``: 1000 by default (with
    200, the RO plant's fault magnitude scatters about twice as far as the
    filter's own interval says); ``seed``; ``shrinkage``: Liu and West's
    kernel shrinkage of the magnitude's particles; ``switch``: when the
    nominal particle observer degenerates (its mean effective sample size
    before the alarm under ``DEGENERATE`` of its particles), diagnose with
    ``ckf`` instead (a ``Switched`` event; a campaign comparing filters turns
    it off); ``workers``: processes for the hypotheses' filters in a batch
    diagnosis (1: in this process).

    **Data** (:mod:`bgc.data.sampler`): ``gap``: missing samples in a row
    longer than this (time units; None: ``GAP_STEPS`` steps) are a ``Gap``
    event.

    **Detection** (:mod:`bgc.diagnosis.detect`): ``false_alarm``: the
    probability of any alarm over a fault-free ``horizon``; ``horizon``: the
    monitoring horizon in the model's time unit (None: the model's declared
    run length, ``simulation.steps`` x ``dt``, filled in by :func:`bgc.open`
    and :func:`bgc.diagnose`; the record's length for the runtime's own
    :func:`~bgc.diagnosis.diagnose.diagnose`): the same detector for a file of
    any length and for a stream; ``windows``: the Z-tests' window lengths.

    **Isolation** (:mod:`bgc.diagnosis.isolate`, :mod:`bgc.diagnosis.onsets`):
    ``symbol_steps``: open-loop steps read for the symbols after the alarm
    (a slope needs samples after the magnitude is seen); ``history``: how far
    back the nominal clouds are kept (and a drift's onset is looked for);
    ``search``: how far before the alarm a drift's onset is looked for
    first, and by how much further back each time its onset posterior piles
    up at the earliest onset tried; ``spacing``: steps between the onsets a
    drift's particle filters are tried from near the alarm (further back,
    1/16 of the distance to it; None: 8 with ``identify = "kalman"``, 4 with
    ``"filter"``); ``near``: samples before the detector's change point a
    step change is tried from.

    **Tracking** (:mod:`bgc.diagnosis.hypothesis`): ``rejection``: the
    probability of dropping the true hypothesis over what remains of the
    horizon after its onset.

    **Weighing** (:mod:`bgc.diagnosis.finish`, :mod:`bgc.diagnosis.static`,
    :mod:`bgc.diagnosis.rank`): ``identify``: ``kalman`` (the hypotheses
    weighed and the magnitude sized with the magnitude held static, by
    cubature Kalman filters on a grid: ``kalman`` holds their options) or
    ``filter`` (by the particle filters' magnitude state and evidence: the
    thesis's method); ``bayes_factor``: a survivor this many times less
    probable than the best is dropped (100: "decisive" on Jeffreys' scale);
    ``isolation_level``: the posterior the candidates of a verdict must
    hold together (0.95): where the survivors of the Bayes factor hold less,
    the most probable of the hypotheses it dropped are kept as candidates
    too, until they do (an ``Uncertain`` event), so that "isolated" names a
    fault with at least this posterior; ``recheck``: the fault models the
    symbols ruled out are weighed too, by their static posteriors (``identify
    = "kalman"``), and one that explains the data is a candidate all the
    same (an ``Overruled`` event): symbols read after a late alarm can
    mislead;
    ``interval``: the probability of the reported interval; ``rank``: weigh
    the survivors anew by the evidence of their models with the magnitude
    held static on a particle-filter grid ``rank_grid`` (``identify =
    "filter"`` only; off by default); ``refine``: each survivor's estimate
    from the particle filters' marginal likelihood on ``grid`` (about three
    times slower; off by default)."""

    method: str = "gpf"
    particles: int = 1000
    seed: int = 0
    false_alarm: float = 0.01
    rejection: float = 0.001
    windows: tuple[int, ...] = (1, 8, 32)
    history: int = 256
    search: int = 64
    spacing: int | None = None
    near: int = 4
    symbol_steps: int = 32
    interval: float = 0.95
    bayes_factor: float = 100.0
    isolation_level: float = 0.95
    recheck: bool = True
    shrinkage: float = 0.98
    workers: int = 2
    identify: str = "kalman"
    kalman: KalmanOptions = KalmanOptions()
    rank: bool = False
    refine: bool = False
    grid: GridOptions = GridOptions()
    rank_grid: GridOptions = GridOptions(points=11)
    switch: bool = True
    horizon: float | None = None
    gap: float | None = None


#: The options of each stage of the loop (every field of DiagnosisOptions in one).
STAGES = {
    "filters": ("method", "particles", "seed", "shrinkage", "switch", "workers"),
    "data": ("gap",),
    "detection": ("false_alarm", "horizon", "windows"),
    "isolation": ("symbol_steps", "history", "search", "spacing", "near"),
    "tracking": ("rejection",),
    "weighing": ("identify", "kalman", "bayes_factor", "isolation_level", "recheck", "interval", "rank", "rank_grid", "refine", "grid"),
}


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
class Hypothesis:
    """One fault model: its filters from every onset tried (``onsets``, with
    their posterior probabilities), and from the most probable one
    (``start``) its per-step predicted measurements, normalised residuals,
    state estimates (mean, std of the plant's states) and magnitude (mean,
    interval), when it was dropped and why (None: it
    survived), its log evidence (over the onsets) and posterior probability
    among the hypotheses. With the magnitude held static (``identify =
    "kalman"``, or ``rank``): ``static_log_evidence``, the evidence of its
    model with the magnitude held static (None: not computed); ``static``,
    its static posterior (Kalman filters); ``estimate`` is then the static
    posterior's and ``filter_estimate`` the particle filters' own;
    ``static_alarm``: the first alarm of the consistency test on the static
    posterior's most likely cell (None: it passed, or was not run).
    ``ruled_out``: the signature and symbol that ruled it out ("" when the
    symbols kept it); it was weighed by its static posterior alone (step 6b,
    ``recheck``)."""

    name: str
    parameter: str
    kind: str
    signatures: tuple[str, ...]
    start: int
    onsets: tuple[int, ...]
    onset_posterior: tuple[float, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    z: np.ndarray
    x_mean: np.ndarray
    x_std: np.ndarray
    magnitude: np.ndarray
    magnitude_band: np.ndarray
    dropped: int | None
    reason: str
    log_evidence: float
    posterior: float
    estimate: Estimate
    seconds: float
    static_log_evidence: float | None = None
    static: StaticPosterior | None = None
    filter_estimate: Estimate | None = None
    static_alarm: Detection | None = None
    ruled_out: str = ""

    @property
    def onset(self) -> int:
        """The most probable onset: the static posterior's when there is one, else the filters'."""
        return self.static.onset if self.static is not None and math.isfinite(self.static.log_evidence) else self.start


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """What :func:`diagnose` found. ``verdict``: ``no fault``, ``isolated``
    (one hypothesis survives), ``ambiguous`` (several do: ``candidates``, best
    first) or ``unexplained`` (none does; ``candidates`` then holds the one
    that lasted longest). Steps are steps of the model's time grid
    (``time[step]``: one per sample, and one per step the data have no
    sample for, :mod:`bgc.data.sampler`); ``nominal_x_mean`` and
    ``nominal_x_std`` are the nominal observer's state estimates (steps x
    ``states``). ``events``: what happened, in time order
    (:mod:`bgc.diagnosis.events`); ``data``: how the data met the model (per
    input, data or model; sensors present; samples skipped; gaps)."""

    model: str
    time: np.ndarray
    outputs: tuple[str, ...]
    states: tuple[str, ...]
    verdict: str
    detection: Detection | None
    onset: int | None
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
    events: tuple = field(default=())
    data: DataSummary | None = None

    @property
    def best(self) -> Hypothesis | None:
        if not self.candidates:
            return None
        return next(h for h in self.hypotheses if h.name == self.candidates[0])

    @property
    def estimate(self) -> Estimate | None:
        return self.best.estimate if self.best is not None else None

    def time_of(self, step: int | None) -> float | None:
        return None if step is None else float(self.time[step])

    def state_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The state estimate (mean, std; steps x ``states``) the diagnosis
        stands for: the nominal observer's, then from its onset on the
        filter of the diagnosed hypothesis (``candidates[0]``)."""
        mean, std = self.nominal_x_mean.copy(), self.nominal_x_std.copy()
        best = self.best
        if best is not None:
            mean[best.start:], std[best.start:] = best.x_mean, best.x_std
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
    the events of the isolation."""

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

    def untried(self, package) -> list[str]:
        """The fault models of ``package`` the symbols ruled out and that
        are not tried (sorted)."""
        return sorted({n for n in self.ruled_out if n in package.MODELS} - set(self.names))
