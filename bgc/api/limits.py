"""What a diagnosis may take (memory, steps, times) and the checks of its options, before any work."""

from __future__ import annotations

from ..filters import registry
import dataclasses
import math


from .. import arguments
from ..errors import (
    ArgumentTypeError, ArgumentValueError, TrackingError,
)
from ..data.runs import TIMINGS
from ..ir import Numerics
from ..view import NumericsView
from ..diagnosis.options import GridOptions, KalmanOptions
from ..diagnosis.diagnose import IDENTIFY, KALMAN_METHOD, PATHS
from ..diagnosis.options import DiagnosisOptions
from ..diagnosis.detect import TESTS


#: The longest detector horizon or gap limit (time units) the options take.
MAX_TIME = 1e12


#: The most a prior may be widened (``prior_scale``).
MAX_PRIOR_SCALE = 1e6


#: Memory a diagnosis may take by the rule of :func:`diagnosis_memory`.
MAX_DIAGNOSIS_BYTES = 4_000_000_000


#: The rule's rows per fault model and step (see :func:`diagnosis_memory`).
_HYPOTHESIS_ROWS = 128


#: The rule's particle filters alive at once (a hypothesis's onsets, in lockstep).
_FILTERS_ALIVE = 64


def diagnosis_memory(steps: int, num: Numerics, particles: int = 1000, method: str = "gpf",
                     history: int = DiagnosisOptions().history) -> tuple[int, int]:
    """The memory a diagnosis of ``steps`` samples may take, by a rule that
    bounds what tracemalloc measured: (bytes that do not grow with the run,
    bytes per step).

    Measured peaks (the circuit and the RO plant, 400 and 1600 steps, an
    abrupt fault and a drift at 15 % of the run, gpf with 200 and 1000
    particles, ckf, one process) grew by 9 to 62 kB a step: the nominal
    observer's histories, the open-loop particle paths the symbols are read
    from (up to ``PATHS`` particles, over the steps from the onset to the
    alarm), and per fault model its filters' estimates from each onset tried
    and the Kalman grid's residuals (steps x cells x sensors). The rule
    counts, in 8-byte numbers per step: the run and the nominal histories
    (6 n_y + 2 n_x + n_u + 4), three copies of the open-loop paths (3 n_y
    min(particles, PATHS)), and per fault model ``_HYPOTHESIS_ROWS`` (128)
    rows of n_x + n_y + 4 numbers, with 150 bytes of Python objects: 2.2 to
    20 times the growth measured (closest: the circuit's drift with 200
    particles, where every fault model was tried: 62 kB measured, 138 kB by
    the rule; farthest: the RO plant's abrupt fault, two hypotheses: 9 kB
    measured, 179 kB by the rule), since every fault model may be tried.
    What does not grow with the run, for particle filters: the nominal
    clouds kept ``history`` steps back for the hand-over, and
    ``_FILTERS_ALIVE`` (64) filters of the hypotheses, each of particles x
    (n_x + 3) numbers (the circuit with 20,000 particles over 400 steps:
    167 MB measured, 390 MB by the rule).

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range.
    """
    func = "bgc.api.limits.diagnosis_memory"
    arguments.integer(func, "steps", steps, 1, "give at least 1", "steps=300")
    if not isinstance(num, (Numerics, NumericsView)):
        raise ArgumentTypeError(f"{func}: num={arguments.shown(num)} is not a Numerics", None,
                                "give the compiled model's numerics (pipeline.compile_model(path).numerics)")
    arguments.integer(func, "particles", particles, 1, "at least 1 particle is needed", "particles=1000")
    arguments.choice(func, "method", method, METHODS)
    arguments.integer(func, "history", history, 1, "give at least 1", "history=256")
    steps, particles, history = int(steps), int(particles), int(history)  # NumPy integers would wrap around
    ssm = num.equations
    n, n_y, n_u, n_f = len(ssm.states), len(ssm.outputs), len(ssm.inputs), len(num.faults)
    per_step = 8 * (6 * n_y + 2 * n + n_u + 4 + 3 * n_y * min(particles, PATHS)
                    + n_f * _HYPOTHESIS_ROWS * (n + n_y + 4)) + 150
    fixed = 0 if method == KALMAN_METHOD else 8 * particles * ((n + 1) * (history + 1) + (n + 3) * _FILTERS_ALIVE)
    return fixed, per_step


def check_diagnosis_steps(steps: int, num: Numerics, particles: int = 1000, method: str = "gpf",
                          where: str = "--steps", history: int = DiagnosisOptions().history) -> None:
    """Refuse, before any work, a diagnosis of ``steps`` samples with
    ``particles`` particles and the filter ``method`` whose memory, by the
    rule of :func:`diagnosis_memory`, would pass ``MAX_DIAGNOSIS_BYTES``
    (4 GB): a :class:`~bgc.errors.TrackingError` giving the most steps (or
    particles) this model allows. ``where`` names the request (``--steps``,
    a run file). A campaign calls it for each group's steps with its most
    particles and each filter.

    Raises
    ------
    TrackingError
        The request is beyond the memory.
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range (:func:`diagnosis_memory`).
    """
    arguments.text("bgc.api.limits.check_diagnosis_steps", "where", where)
    fixed, per_step = diagnosis_memory(steps, num, particles, method, history)
    name = num.equations.model.name
    if fixed > MAX_DIAGNOSIS_BYTES:
        unit = fixed // int(particles)
        raise TrackingError(f"{particles} particles: a diagnosis of {name} keeps {history + 1} clouds of them, "
                            f"about {fixed / 1e9:.3g} GB", None,
                            f"use at most {MAX_DIAGNOSIS_BYTES // 2 // unit} particles for this model")
    need = fixed + steps * per_step
    if need > MAX_DIAGNOSIS_BYTES:
        most = (MAX_DIAGNOSIS_BYTES - fixed) // per_step
        raise TrackingError(f"{where}: a diagnosis of {steps} steps of {name} may take about {need / 1e9:.3g} GB "
                            f"(at most {most} steps for this model with {method}"
                            f"{'' if method == KALMAN_METHOD else f' and {particles} particles'})", None,
                            "diagnose a shorter run")


def check_options(options: DiagnosisOptions, func: str = "bgc.diagnose", o: str = "options.") -> None:
    """Refuse options a diagnosis cannot take, as :func:`diagnose` does its
    arguments (``func`` names the function in the message).

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        A field of the wrong type or out of range.
    """
    if not isinstance(options, DiagnosisOptions):
        raise ArgumentTypeError(f"{func}: options={arguments.shown(options)} is not a DiagnosisOptions", None,
                                "give bgc.DiagnosisOptions(...) or None")
    arguments.choice(func, o + "filter", options.filter, METHODS)
    arguments.integer(func, o + "particles", options.particles, None, "", "particles=1000")
    if options.particles < 1:  # bgc diagnose hands --particles over in the options: the option's name there
        raise ArgumentValueError(f"{arguments.spelled(f'{func}: {o}particles=', '--particles ')}"
                                 f"{options.particles}: at least 1 particle is needed", None,
                                 f"e.g. {arguments.spelled('DiagnosisOptions(particles=200)', '--particles 200')}")
    arguments.integer(func, o + "seed", options.seed, 0, "is negative", "seed=0")
    for name in ("false_alarm", "rejection", "interval"):
        arguments.real(func, o + name, getattr(options, name), 0.0, 1.0, "a probability strictly between 0 and 1")
    arguments.real(func, o + "shrinkage", options.shrinkage, 0.0, 1.0, "a number between 0 and 1", high_ok=True)
    arguments.real(func, o + "bayes_factor", options.bayes_factor, 1.0, math.inf, "a number >= 1", low_ok=True)
    windows = options.windows
    if not isinstance(windows, tuple) or not windows:
        raise ArgumentTypeError(f"{func}: options.windows={arguments.shown(windows)} is not a non-empty tuple of "
                                "integers",
                                None, "e.g. windows=(1, 8, 32)")
    for w in windows:
        arguments.integer(func, o + "windows", w, 1, "a window holds at least 1 sample", "windows=(1, 8, 32)")
    detectors = options.detectors
    if not isinstance(detectors, tuple) or not all(isinstance(t, str) for t in detectors):
        raise ArgumentTypeError(f"{func}: options.detectors={arguments.shown(detectors)} is not a tuple of names",
                                None, "e.g. detectors=('mean', 'drift', 'variance', 'frozen')")
    wrong = [t for t in detectors if t not in TESTS] + (["(no mean)"] if "mean" not in detectors else []) \
        + (["(one twice)"] if len(set(detectors)) < len(detectors) else [])
    if wrong:
        raise ArgumentValueError(f"{arguments.spelled(f'{func}: {o}detectors', '--detect')}: "
                                 f"{', '.join(map(str, wrong))} is not a family of the detector's tests", None,
                                 f"give the mean test and any of {', '.join(TESTS[1:])}, each once "
                                 f"(e.g. {arguments.spelled(repr(TESTS), ','.join(TESTS))})")
    for name in ("history", "search", "symbol_steps") + (("workers",) if options.workers is not None else ()):
        arguments.integer(func, o + name, getattr(options, name), 1, "give at least 1", f"{name}=1")
    arguments.integer(func, o + "near", options.near, 0, "is negative", "near=4")
    if options.spacing is not None:
        arguments.integer(func, o + "spacing", options.spacing, 1, "give at least 1", "spacing=4")
    arguments.choice(func, o + "identify", options.identify, IDENTIFY)
    if options.filter == KALMAN_METHOD and options.identify == "filter":
        raise ArgumentValueError(f"{arguments.spelled(f'{func}: {o}identify', '--identify')}='filter' with "
                                 f"{arguments.spelled('filter', '--filter')}='ckf': a cubature Kalman filter has no "
                                 "particle filter of the magnitude to identify with", None,
                                 "ckf's estimate is the static posterior's: identify='kalman' (the default), or a "
                                 "particle filter, filter='gpf', 'apf' or 'opf'")
    if options.input_timing is not None:
        arguments.choice(func, o + "input_timing", options.input_timing, TIMINGS)
    for name in ("horizon", "gap", "keep"):
        if getattr(options, name) is not None:
            arguments.real(func, o + name, getattr(options, name), 0.0, MAX_TIME, "a time above 0 (the model's "
                           "time unit), at most 1e12", high_ok=True)
    for name in ("rank", "refine", "switch"):
        if not isinstance(getattr(options, name), bool):
            raise ArgumentTypeError(f"{func}: options.{name}={arguments.shown(getattr(options, name))} is not True "
                                    "or False",
                                    None, f"give {name}=True or {name}=False")
    for name, kind in (("kalman", KalmanOptions), ("grid", GridOptions),
                       ("rank_grid", GridOptions)):
        if not isinstance(getattr(options, name), kind):
            raise ArgumentTypeError(f"{func}: options.{name}={arguments.shown(getattr(options, name))} is not a "
                                    f"{kind.__name__}", None, f"give {kind.__name__}(...)")


def most_steps(num: Numerics, options: DiagnosisOptions) -> int:
    """The most steps a diagnosis of ``options`` may hold by the rule of
    :func:`check_diagnosis_steps` (a stream is stopped there)."""
    fixed, per_step = diagnosis_memory(1, num, options.particles, options.filter, options.history)
    return max(int((MAX_DIAGNOSIS_BYTES - fixed) // max(per_step, 1)), 1)


def with_horizon(options: DiagnosisOptions, settings) -> DiagnosisOptions:
    """``options`` with the detector's horizon filled in when None: the
    model's declared run length (``simulation.steps`` x ``dt``)."""
    if options.horizon is not None:
        return options
    return dataclasses.replace(options, horizon=settings.steps * settings.dt)


#: The filters of a diagnosis (``bgc diagnose --filter``).
METHODS = tuple(registry.FILTER_CLASSES)
