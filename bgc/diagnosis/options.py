"""The diagnosis's options, as frozen dataclasses: the whole loop's
(:class:`DiagnosisOptions`, stage by stage: :data:`STAGES`) and those of
its parts that have their own (the static posterior's grid,
:class:`KalmanOptions`; the particle filters' grid, :class:`GridOptions`)."""

from __future__ import annotations

import os
import warnings
from dataclasses import InitVar, dataclass

from ..errors import ArgumentValueError, printable


@dataclass(frozen=True, slots=True)
class KalmanOptions:
    """``spacing``: samples between a drift's onsets near the alarm (further
    back, 1/16 of the distance to it); ``first_points``, ``points``:
    magnitudes on the first pass of the grid
    and on the others; ``keep``: after a pass, the onsets holding less than
    this share of the best onset's mass are left out of the next; ``relay``:
    only onsets holding at least this share of it are laid anew; ``widen``: the first pass
    spans the hint interval widened by this fraction of its width on each
    side; ``passes``: at most this many passes. After a pass whose posterior
    peaks at an end of the grid, the grid reaches its span further that way;
    after one whose ends hold more than ``edge`` of the peak density, or
    whose spacing is coarse (the posterior's std under ``resolution``
    spacings), it spans 4 stds either side of the posterior's mean; else the
    pass is the last."""

    spacing: int = 4
    first_points: int = 9
    points: int = 9
    keep: float = 1e-4
    relay: float = 1e-3
    widen: float = 0.5
    passes: int = 4
    resolution: float = 0.8
    edge: float = 1e-3

    def __post_init__(self):
        if self.first_points < 3 or self.points < 3 or self.passes < 1 or self.spacing < 1:
            raise ArgumentValueError("KalmanOptions: a row needs at least 3 points (first_points, points), passes "
                                     "and spacing at least 1", None, "e.g. KalmanOptions(points=9)")


@dataclass(frozen=True, slots=True)
class GridOptions:
    """``points`` magnitudes on the grid, ``onsets`` onsets (the most probable
    ones of the hypothesis), ``particles`` per filter, ``widen``: the grid
    spans the filter's interval widened by this fraction of its width on each
    side (and once more if the posterior piles up at an end)."""

    points: int = 21
    onsets: int = 3
    particles: int = 500
    widen: float = 0.2



#: The environment variable that sets the processes a diagnosis runs on when no one says
#: (DiagnosisOptions.workers, bgc diagnose's and bgc monitor's --workers).
WORKERS_ENV = "BGC_WORKERS"
#: The processes without it: one per core of a 2-core machine.
WORKERS = 2


def processes(workers: int | None) -> int:
    """``workers`` (:attr:`DiagnosisOptions.workers`), or when None
    :func:`default_workers`: the processes the work runs on."""
    return workers if workers is not None else default_workers()


def default_workers() -> int:
    """The environment's ``BGC_WORKERS``, else :data:`WORKERS` (2): the
    processes a diagnosis weighs its hypotheses on when no one says. A machine
    whose cores are already busy (a shared server, a cluster's job given one
    core, a test suite running on every core) gains nothing from more
    processes and pays for starting them: 1 there. A value that is not a
    whole number >= 1 is an :class:`~bgc.errors.ArgumentValueError` naming
    the variable."""
    text = os.environ.get(WORKERS_ENV, "").strip()
    if not text:
        return WORKERS
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise ArgumentValueError(f"{WORKERS_ENV}={printable(text)!r} in the environment: not a number of processes",
                                 None, f"set {WORKERS_ENV} to an integer >= 1, or unset it ({WORKERS} processes), "
                                       "or give the number of processes (--workers N, workers=N)")
    return value


@dataclass(frozen=True, slots=True)
class DiagnosisOptions:
    """The diagnosis's options, stage by stage (:data:`STAGES`; the loop of
    :mod:`bgc.diagnosis.diagnoser`).

    **Filters** (the nominal observer and the hypotheses' filters):
    ``filter``: ``gpf``, ``apf``, ``opf`` (particle filters) or ``ckf`` (no
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
    diagnosis (1: in this process; None, the default: the environment's
    ``BGC_WORKERS`` when the work starts, else 2: :func:`processes`).

    **Data** (:mod:`bgc.data.sampler`): ``gap``: missing samples in a row
    longer than this (time units; None: ``GAP_STEPS`` steps) are a ``Gap``
    event; ``input_timing``: what a row's input value is, ``end`` (held over
    the step that ends at the row's time: bgc's own files) or ``start`` (set
    at the row's time, acting until the next row: what many loggers write);
    None: as the data's header says (an ``input timing:`` line), else ``end``;
    ``keep``: while watching (before an alarm), the record a diagnoser
    keeps, in the model's time unit (None: every sample from the first, a
    batch diagnosis's record; ``bgc monitor`` keeps a bounded one): once it
    holds twice this, its older half is forgotten and the models of the rest
    start from the nominal observer's estimate there
    (:meth:`bgc.diagnosis.diagnoser.Diagnoser.step`); at least ``history``
    plus the longest window, in steps.

    **Detection** (:mod:`bgc.diagnosis.detect`): ``false_alarm``: the
    probability of any alarm over a fault-free ``horizon``; ``horizon``: the
    monitoring horizon in the model's time unit (None: the model's declared
    run length, ``simulation.steps`` x ``dt``, filled in by :func:`bgc.open`
    and :func:`bgc.diagnose`; the record's length for the runtime's own
    :func:`~bgc.diagnosis.diagnose.diagnose`): the same detector for a file of
    any length and for a stream; ``windows``: the Z-tests' window lengths;
    ``detectors``: the families of tests the detector runs, sharing
    ``false_alarm`` (``mean`` always; ``drift``, ``variance``, ``frozen``:
    :mod:`bgc.diagnosis.detect`, "A bank of tests").

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
    mislead; ``no_fault``: after an alarm, no fault (the alarm a false one)
    is weighed beside the faults (:func:`bgc.diagnosis.weigh.no_fault`;
    ``identify = "kalman"`` or ``filter = "ckf"``): "no fault" when it holds
    ``isolation_level``, never "isolated" while it holds more than 1 -
    ``isolation_level`` (False: the faults alone, as the thesis weighs them);
    ``interval``: the probability of the reported interval; ``rank``: weigh
    the survivors anew by the evidence of their models with the magnitude
    held static on a particle-filter grid ``rank_grid`` (``identify =
    "filter"`` only; off by default); ``refine``: each survivor's estimate
    from the particle filters' marginal likelihood on ``grid`` (about three
    times slower; off by default)."""

    filter: str = "gpf"
    particles: int = 1000
    seed: int = 0
    false_alarm: float = 0.01
    rejection: float = 0.001
    windows: tuple[int, ...] = (1, 8, 32)
    detectors: tuple[str, ...] = ("mean",)
    history: int = 256
    search: int = 64
    spacing: int | None = None
    near: int = 4
    symbol_steps: int = 32
    interval: float = 0.95
    bayes_factor: float = 100.0
    isolation_level: float = 0.95
    recheck: bool = True
    no_fault: bool = True
    shrinkage: float = 0.98
    workers: int | None = None
    identify: str = "kalman"
    kalman: KalmanOptions = KalmanOptions()
    rank: bool = False
    refine: bool = False
    grid: GridOptions = GridOptions()
    rank_grid: GridOptions = GridOptions(points=11)
    switch: bool = True
    horizon: float | None = None
    gap: float | None = None
    input_timing: str | None = None
    keep: float | None = None
    #: The filter's old name (``method=``): accepted with a :class:`DeprecationWarning` (read ``filter``).
    method: InitVar[str | None] = None

    def __post_init__(self, method: str | None) -> None:
        if method is not None:
            warnings.warn("DiagnosisOptions(method=...) is deprecated: the filter is named filter= (as --filter and "
                          "a campaign's filters:)", DeprecationWarning, stacklevel=3)
            object.__setattr__(self, "filter", method)


#: The options that change no number of a diagnosis (the processes its hypotheses run on): a saved
#: diagnoser's state and a monitor's hold to none of them (bgc.diagnosis.state, bgc.service.resume).
UNBOUND = ("workers",)

#: The options of each stage of the loop (every field of DiagnosisOptions in one).
STAGES = {
    "filters": ("filter", "particles", "seed", "shrinkage", "switch", "workers"),
    "data": ("gap", "input_timing", "keep"),
    "detection": ("false_alarm", "horizon", "windows", "detectors"),
    "isolation": ("symbol_steps", "history", "search", "spacing", "near"),
    "tracking": ("rejection",),
    "weighing": ("identify", "kalman", "bayes_factor", "isolation_level", "recheck", "no_fault", "interval", "rank", "rank_grid", "refine", "grid"),
}
