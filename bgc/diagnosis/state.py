"""A diagnoser's state as plain data: what a restart, a move to another
worker or a test's round trip needs (:meth:`bgc.diagnosis.diagnoser.Diagnoser.to_state`).

A :class:`DiagnoserState` holds arrays, numbers, strings, frozen values of
the diagnosis (its options, the alarm, the isolation, the events) and the
random generators' states (``bit_generator.state``), nothing else: no
module, no function, no open generator. Its parts, one per working part of
the loop: the sampler's place in the data
(:class:`~bgc.data.sampler.SamplerState`), the loop's record
(:class:`LoopState`), the nominal observer (a :class:`FilterState`, or the
cubature Kalman filter's :class:`KalmanState`), the detector's windows
(:class:`DetectorState`) and the trackers of the hypotheses
(:class:`TrackerState`). ``epoch`` counts the steps of the model's grid the
diagnoser has taken: a state is taken up where it stopped.

:meth:`DiagnoserState.to_bytes` writes it as pickle data, and
:meth:`DiagnoserState.from_bytes` reads it back with an unpickler that makes
only the types a state is made of (a state file from elsewhere cannot make
anything else, nor run code).
"""

from __future__ import annotations

import io
import pickle
import time
from dataclasses import dataclass, replace

import numpy as np

from ..data.sampler import Sample, SamplerState
from ..errors import ArgumentValueError
from ..filters.cubature import NominalKalman
from .hidden import DecoderState
from ..filters.registry import filter_class
from .hypothesis import HypothesisTracker, TrackJob
from .options import UNBOUND, DiagnosisOptions
from .values import Detection, Isolation

#: The state's format; a state of another format is refused.
VERSION = 11  # 2: the options' input_timing (2026-12-03); 3: a record with its first steps forgotten; 4: the
# parameters of faults accommodated (2026-12-04); 5: the detector's other families of tests (2026-12-04); 6: their
# residuals in units of the sensors' noise, and what the readings tell (2026-12-04); 7: the pooled test's sums of
# the residuals' predicted correlation (2026-12-04); 8: the options' no_fault (2026-12-04); 9: the drift family's
# Kalman observer beside a particle one, and its rings (2026-12-05); 10: the matched test's whitened innovations
# (2026-12-05); 11: the alarm raised at a change point while watching (2026-12-06)
#: The first bytes of a state file.
MAGIC = b"bgc-diagnoser-state\n"


@dataclass(frozen=True, slots=True)
class FilterState:
    """A particle filter's: its particles ``x`` (n_x, N), log-weights, the
    weights it keeps from step to step (None: none), its generator's state
    and its count of recoveries."""

    x: np.ndarray
    logw: np.ndarray
    w: np.ndarray | None
    rng: dict
    recoveries: int


@dataclass(frozen=True, slots=True)
class KalmanState:
    """The nominal cubature Kalman filter's: its mean and covariance now, and
    per step its state before the step (``means``, ``covs``), the
    log-likelihood of the data before it, and what it predicted and
    estimated (the end's static posteriors start from these)."""

    m: np.ndarray
    P: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    logliks: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    z: np.ndarray
    x_std: np.ndarray


@dataclass(frozen=True, slots=True)
class DetectorState:
    """The windowed Z-test's: the running sums of the residuals and of the
    Monte Carlo shares over its longest window (rows of floats, the newest
    last), and its statistic per step taken (the report draws them)."""

    cumsum: tuple
    mc: tuple
    statistics: np.ndarray
    more: tuple = ()  # the other families' (Families.state); () with the mean test alone


@dataclass(frozen=True, slots=True)
class TrackerState:
    """A hypothesis tracker's: its job, the next step, per onset its
    filter's state, evidence, effective sample size and outputs so far, the
    live onsets, the trace of the best evidence, its consistency tests'
    running sums, the onsets its bank holds together (in order; None: not
    packed) and its seconds so far."""

    job: TrackJob
    k: int
    filters: tuple
    evidence: tuple
    ess: tuple
    live: tuple
    trace: tuple
    out: tuple
    tests: tuple
    bank: tuple | None
    seconds: float


@dataclass(frozen=True, slots=True)
class LoopState:
    """The loop's: its options (a switch of filter runs another loop with
    other options), ``every``, ``lazy``; the phase, the alarm, the isolation
    and the events so far; the record of the samples (time, inputs,
    measurements, their lines, their data events) and of the nominal
    observer (its predictions, residuals and state estimates, its log
    densities); the observer itself; the effective sample sizes before the
    alarm; the detector; the nominal clouds kept (step, particles,
    log-weights); the trackers, each one's nominal density before its first
    onset, and the hypotheses whose stop is said."""

    options: DiagnosisOptions
    every: bool
    lazy: bool
    phase: str
    detection: Detection | None
    isolation: Isolation | None
    events: tuple
    time: np.ndarray
    us: np.ndarray
    ys: np.ndarray
    lines: np.ndarray
    sample_events: tuple
    y_mean: np.ndarray
    y_std: np.ndarray
    z: np.ndarray
    x_mean: np.ndarray
    x_std: np.ndarray
    density: np.ndarray
    observer: FilterState | KalmanState
    ess: float
    ess_sum: float
    ess_steps: int
    detector: DetectorState
    clouds: tuple
    trackers: tuple
    before: tuple
    reported: tuple
    #: the drift family's Kalman observer beside a particle one (mean, covariance; None: none)
    companion: tuple | None = None
    #: the alarm raised at a change point the record's test found while watching (``Loop.forced``; None: none)
    forced: Detection | None = None


@dataclass(frozen=True, slots=True)
class DiagnoserState:
    """A diagnoser's state (module docstring): the format's ``version``, the
    plant's model, ``epoch`` (the steps taken, those forgotten too), the sampler's place, the loop
    that runs now, the events of a switch of filter (empty: none), whether
    the inputs are still to be read from the first row, the seconds spent in
    steps and whether it has finished."""

    version: int
    model: str
    epoch: int
    sampler: SamplerState
    loop: LoopState
    switched: tuple
    infer_inputs: bool
    busy: float
    finished: bool
    #: the mode read from the data (:class:`~bgc.diagnosis.hidden.DecoderState`; None: the data say it)
    decoder: DecoderState | None = None
    #: the steps of the data's grid forgotten before the record kept (``options.keep``)
    offset: int = 0
    #: where the models of the record start (mean, std; None: the model's X0)
    start: tuple | None = None
    #: the parameters at other values than the model's ((name, value), ...: faults accommodated)
    theta: tuple = ()
    #: where the reader of a hidden mode starts, not made yet (its first row to come after an outage:
    #: :attr:`~bgc.diagnosis.diagnoser.Diagnoser.branches`; None: the package's start)
    branches: tuple | None = None

    def to_bytes(self) -> bytes:
        """The state as bytes (:meth:`from_bytes` reads them)."""
        return MAGIC + pickle.dumps(self, protocol=5)

    @classmethod
    def from_bytes(cls, data: bytes) -> DiagnoserState:
        """A state from :meth:`to_bytes`'s bytes; only the types a state is
        made of are made (anything else is refused, one line)."""
        if not isinstance(data, (bytes, bytearray, memoryview)) or not bytes(data[:len(MAGIC)]) == MAGIC:
            raise ArgumentValueError("DiagnoserState.from_bytes: these bytes are not a diagnoser's state", None,
                                     "give the bytes of DiagnoserState.to_bytes()")
        try:
            state = _Unpickler(io.BytesIO(bytes(data[len(MAGIC):]))).load()
        except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError) as exc:
            raise ArgumentValueError(f"DiagnoserState.from_bytes: the state cannot be read ({exc})", None,
                                     "give the bytes of DiagnoserState.to_bytes(), whole") from None
        if not isinstance(state, DiagnoserState) or state.version != VERSION:
            raise ArgumentValueError("DiagnoserState.from_bytes: a state of another format", None,
                                     f"give a state of format {VERSION} (this bgc's)")
        return state


#: The modules whose classes a state may hold.
_MODULES = ("bgc.diagnosis.state", "bgc.diagnosis.values", "bgc.events", "bgc.diagnosis.options",
            "bgc.diagnosis.hypothesis", "bgc.diagnosis.detect", "bgc.data.sampler")
#: Of NumPy and the standard library, what arrays and the frozen values are made with.
_ALLOWED = {("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "_reconstruct"),
            ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "scalar"),
            ("numpy._core.multiarray", "scalar"), ("numpy", "bool_"), ("builtins", "set"),
            ("builtins", "frozenset"), ("builtins", "slice"), ("copyreg", "_reconstructor"),
            ("builtins", "object"), ("builtins", "float"), ("builtins", "int"),
            ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
            ("bgc.diagnosis.hidden", "DecoderState"), ("bgc.diagnosis.intermittent", "Intermittence"),
            ("bgc.diagnosis.intermittent", "Span")}


class _Unpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) in _ALLOWED or (module in _MODULES and not name.startswith("_")):
            obj = super().find_class(module, name)
            if module in _MODULES and not isinstance(obj, type):
                raise pickle.UnpicklingError(f"{module}.{name} is not a value of a state")
            return obj
        raise pickle.UnpicklingError(f"{module}.{name} is not part of a diagnoser's state")


# ------------------------------------------------------------------------------------------- taking it

def diagnoser_state(d) -> DiagnoserState:
    """The state of diagnoser ``d``."""
    return DiagnoserState(VERSION, d.nominal.MODEL, d.offset + len(d.loop.samples), d.sampler.state(),
                          loop_state(d.loop), tuple(d.switched), d.infer_inputs, d.busy, d.finished,
                          None if d.decoder is None else d.decoder.state(), d.offset, *package_state(d.config.package),
                          d.branches if d.decoder is None else None)


def package_state(package) -> tuple:
    """A started package's start (mean, std; None: X0) and parameters
    changed (sorted (name, value) pairs), from which
    :func:`~bgc.model.package.started_package` makes it again."""
    from ..model.package import STARTED_AT, STARTED_THETA

    start = getattr(package, STARTED_AT, None)
    theta = getattr(package, STARTED_THETA, None) or {}
    return (None if start is None else (start[0].copy(), start[1].copy())), tuple(sorted(theta.items()))


def loop_state(loop) -> LoopState:
    """The state of a :class:`~bgc.diagnosis.loop.Loop`."""
    T, n_y, n_x = len(loop.samples), len(loop.outputs), len(loop.nominal.STATES)

    def rows(values: list, width: int) -> np.ndarray:
        return np.array(values, dtype=float).reshape(T, width)

    samples = loop.samples
    observer = kalman_state(loop.kf) if loop.kf is not None else filter_state(loop.pf)
    c = loop.config
    return LoopState(
        c.options, c.every, c.lazy, loop.phase, loop.detection, loop.isolation, tuple(loop.events),
        np.array([s.t for s in samples], dtype=float), rows([s.u for s in samples], len(loop.nominal.INPUTS)),
        rows([s.y for s in samples], n_y), np.array([-1 if s.line is None else s.line for s in samples], dtype=int),
        tuple((s.k, s.events) for s in samples if s.events), rows(loop.y_mean, n_y), rows(loop.y_std, n_y),
        rows(loop.z, n_y), rows(loop.x_mean, n_x), rows(loop.x_std, n_x), np.array(loop.density, dtype=float),
        observer, loop.ess, loop.ess_sum, loop.ess_steps, detector_state(loop.detector),
        tuple((k, x.copy(), logw.copy()) for k, (x, logw) in loop.clouds.items()),
        tuple((name, tracker_state(t)) for name, t in loop.trackers.items()), tuple(loop.before.items()),
        tuple(sorted(loop.reported)),
        None if loop.companion is None else (loop.companion.mean.copy(), loop.companion.cov.copy()), loop.forced)


def filter_state(pf) -> FilterState:
    """The state of a particle filter (any of ``bgc/filters/particle.py``'s)."""
    return FilterState(pf.x.copy(), pf.logw.copy(), None if pf.w is None else pf.w.copy(),
                       pf.rng.bit_generator.state, pf.recoveries)


def kalman_state(kf: NominalKalman) -> KalmanState:
    """The state of the nominal cubature Kalman filter."""
    n, n_y, T = kf.kf.n, kf.n_y, len(kf.y_mean)
    return KalmanState(kf.m.copy(), kf.P.copy(), np.array(kf.means, dtype=float).reshape(T + 1, n),
                       np.array(kf.covs, dtype=float).reshape(T + 1, n, n), np.array(kf.logliks, dtype=float),
                       np.array(kf.y_mean, dtype=float).reshape(T, n_y), np.array(kf.y_std, dtype=float).reshape(T, n_y),
                       np.array(kf.z, dtype=float).reshape(T, n_y), np.array(kf.x_std, dtype=float).reshape(T, n))


def detector_state(detector) -> DetectorState:
    """The state of a :class:`~bgc.diagnosis.detect.Detector`."""
    width = len(detector.sensors)
    return DetectorState(tuple(detector._cumsum), tuple(detector._mc),
                         np.array(detector.statistics, dtype=float).reshape(len(detector.statistics), width),
                         () if detector.more is None else detector.more.state())


def tracker_state(t: HypothesisTracker) -> TrackerState:
    """The state of a :class:`~bgc.diagnosis.hypothesis.HypothesisTracker`."""
    out = tuple((s, {key: (tuple(np.array(v, dtype=float) for v in value) if isinstance(value, list) else value)
                     for key, value in o.items()}) for s, o in t.out.items())
    bank = None
    if t.bank.packed and len(t.bank.filters) > 1:
        onset_of = {id(pf): s for s, pf in t.filters.items()}
        bank = tuple(onset_of[id(pf)] for pf in t.bank.filters)
    return TrackerState(t.job, t.k, tuple((s, filter_state(pf)) for s, pf in t.filters.items()),
                        tuple(t.evidence.items()), tuple(t.ess.items()), tuple(sorted(t.live)), tuple(t._trace),
                        out, (t.tests._cumsum.copy(), t.tests._mc.copy()), bank, time.perf_counter() - t.started)


# ------------------------------------------------------------------------------------------ taking it up

def restore_diagnoser(cls, config, state: DiagnoserState):
    """A diagnoser of class ``cls`` and configuration ``config`` in ``state``."""
    from ..model.package import started_package
    from ..model.protocol import nominal_model
    from ..data.sampler import Sampler

    if not isinstance(state, DiagnoserState):
        raise ArgumentValueError(f"Diagnoser.from_state: state={type(state).__name__} is not a DiagnoserState", None,
                                 "give what Diagnoser.to_state() or DiagnoserState.from_bytes() returned")
    nominal = nominal_model(config.package)
    if state.version != VERSION or state.model != nominal.MODEL:
        raise ArgumentValueError(f"Diagnoser.from_state: a state of model {state.model!r} (format {state.version}), "
                                 f"not of {nominal.MODEL!r}", None, "take it up with the model it was made with")
    d = cls.__new__(cls)
    d._open(config, Sampler(nominal, nominal.INPUTS if config.inputs is None else config.inputs,
                            nominal.OUTPUTS if config.sensors is None else config.sensors, config.source,
                            config.options.gap, config.options.input_timing or "end", config.time_unit))
    d.sampler.restore(state.sampler)
    d.offset = state.offset
    if state.start is not None or state.theta:  # a record started elsewhere, faults accommodated: its models'
        start = (None, None) if state.start is None else (np.array(state.start[0], dtype=float),
                                                           np.array(state.start[1], dtype=float))
        d._started(started_package(config.package, *start, theta={k: float(v) for k, v in state.theta}))
    # the options that change no number (the processes the hypotheses run on) are this run's
    options = replace(state.loop.options, **{k: getattr(config.options, k) for k in UNBOUND})
    d.loop = restore_loop(d._loop_config(options, state.loop.every, state.loop.lazy), state.loop)
    d.switched, d.infer_inputs, d.busy, d.finished = tuple(state.switched), state.infer_inputs, state.busy, \
        state.finished
    decoder = getattr(state, "decoder", None)
    if decoder is not None:
        d.hide()
        d.decoder.restore(decoder)
    else:  # (a state before the field: None)
        d.branches = getattr(state, "branches", None)
    return d


def restore_loop(config, s: LoopState):
    """A :class:`~bgc.diagnosis.loop.Loop` of ``config`` in state ``s``."""
    from .loop import Loop

    loop = Loop(config)
    events = dict(s.sample_events)
    loop.samples = [Sample(k, float(t), u, y, None if line < 0 else int(line), events.get(k, ()))
                    for k, (t, u, y, line) in enumerate(zip(s.time, s.us, s.ys, s.lines))]
    loop.y_mean, loop.y_std, loop.z = list(s.y_mean), list(s.y_std), list(s.z)
    loop.x_mean, loop.x_std = list(s.x_mean), list(s.x_std)
    loop.density = [float(v) for v in s.density]
    if loop.kf is not None:
        restore_kalman(loop.kf, s.observer)
    else:
        set_filter(loop.pf, s.observer)
    loop.ess, loop.ess_sum, loop.ess_steps = s.ess, s.ess_sum, s.ess_steps
    restore_detector(loop.detector, s.detector)
    if (loop.companion is None) != (s.companion is None):
        raise ArgumentValueError("Diagnoser.from_state: a state with the drift family's Kalman observer "
                                 f"{'missing' if s.companion is None else 'where none is'}", None,
                                 "take it up with the options it was made with")
    if loop.companion is not None:
        loop.companion.mean, loop.companion.cov = s.companion[0].copy(), s.companion[1].copy()
    loop.clouds = {k: (x.copy(), logw.copy()) for k, x, logw in s.clouds}
    loop.phase, loop.detection, loop.isolation, loop.events = s.phase, s.detection, s.isolation, list(s.events)
    loop.forced = s.forced
    loop.trackers = {name: restore_tracker(t) for name, t in s.trackers}
    loop.before, loop.reported = dict(s.before), set(s.reported)
    return loop


def set_filter(pf, s: FilterState) -> None:
    """Put a particle filter in state ``s`` (its generator object kept: a
    compiled kernel's handle of it stays valid)."""
    pf.x, pf.logw = s.x.copy(), s.logw.copy()
    pf.w = None if s.w is None else s.w.copy()
    pf.rng.bit_generator.state = s.rng
    pf.recoveries = s.recoveries


def restore_kalman(kf: NominalKalman, s: KalmanState) -> None:
    """Put the nominal cubature Kalman filter in state ``s``."""
    kf.m, kf.P = s.m.copy(), s.P.copy()
    kf.means, kf.covs, kf.logliks = list(s.means), list(s.covs), [float(v) for v in s.logliks]
    kf.y_mean, kf.y_std, kf.z, kf.x_std = list(s.y_mean), list(s.y_std), list(s.z), list(s.x_std)


def restore_detector(detector, s: DetectorState) -> None:
    """Put a :class:`~bgc.diagnosis.detect.Detector` in state ``s``."""
    detector._cumsum.clear()
    detector._cumsum.extend(tuple(row) for row in s.cumsum)
    detector._mc.clear()
    detector._mc.extend(tuple(row) for row in s.mc)
    detector.statistics = [list(map(float, row)) for row in s.statistics]
    if detector.more is not None:
        detector.more.restore(s.more)


def restore_tracker(s: TrackerState) -> HypothesisTracker:
    """A :class:`~bgc.diagnosis.hypothesis.HypothesisTracker` in state ``s``."""
    t = HypothesisTracker(s.job)
    t.k = s.k
    cls = filter_class(t.package, s.job.method)
    for onset, fs in s.filters:
        pf = cls(t.module, s.job.particles, np.random.default_rng(), x=fs.x)
        set_filter(pf, fs)
        t.filters[onset] = pf
    t.evidence, t.ess, t.live = dict(s.evidence), dict(s.ess), set(s.live)
    t._trace = list(s.trace)
    t.out = {onset: {key: (list(value) if isinstance(value, tuple) and key in _ROWS else value)
                     for key, value in o.items()} for onset, o in s.out}
    t.tests._cumsum, t.tests._mc = s.tests[0].copy(), s.tests[1].copy()
    if s.bank is not None:  # the filters packed together again, in the same order: the same memory layout
        t.bank.filters = [t.filters[onset] for onset in s.bank]
        t.bank._pack()
    t.started = time.perf_counter() - s.seconds
    return t


#: A tracker's outputs kept per step (lists of arrays, one per step).
_ROWS = ("y_mean", "y_std", "magnitude", "mean", "std")
