""":func:`distinguishability`: which faults a scenario's data can tell apart, before any data."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .. import arguments
from ..errors import (
    ArgumentValueError, SimulationError, printable,
)
from ..kinds import DIRECTIONS, fault_kind
from ..analysis import distinguish as distinction
from ..analysis import hybrid, simulate
from ..model import linear
from ..model import package as packages
from . import cache
from .folders import _LOCK
from ..diagnosis.options import DiagnosisOptions
from .limits import check_options
from .reports import DistinguishabilityReport
from .session import Session, input_signals, scenario_of
from .simulate import _schedule
from .session import open as open_session
from ..model.protocol import nominal_model, onset_sample


def check_prediction(func: str, change, at, process_noise, measurement_noise, steps, level, progress) -> None:
    """The arguments of a prediction over every fault candidate, checked as
    :func:`distinguishability` checks them (also :func:`bgc.analyse`'s)."""
    arguments.real(func, "change", change, 0.0, math.inf, "a relative change above 0, e.g. change=0.3")
    arguments.real(func, "at", at, 0.0, 1.0, "a fraction of the run between 0 and 1, e.g. at=0.5")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if steps is not None:
        arguments.integer(func, "steps", steps, 1, "simulate at least 1 step", "steps=300")
    arguments.real(func, "level", level, 0.0, 1.0, "a probability between 0 and 1, e.g. level=0.95")
    arguments.callable_or_none(func, "progress", progress)


def distinguishability(model: str | Path | Session, scenario: str | simulate.FaultInjection | None = None, *,
                       change: float = 0.3,
                       at: float = 0.5,
                       process_noise: float | None = None, measurement_noise: float | None = None,
                       steps: int | None = None, level: float = distinction.LEVEL,
                       progress=None, detector_runs: int = 0, seed: int = 0,
                       inputs: Mapping[str, Any] | None = None,
                       modes: str | None = None, detectors: tuple[str, ...] = ("mean",)) -> DistinguishabilityReport:
    """Predict which fault hypotheses the data of ``scenario``
    (``NAME:KIND:MAGNITUDE@TIME``) of ``model`` can tell apart, at the given
    relative noise levels (default: the model's), before any data are seen;
    without a scenario, for every fault candidate, kind and direction at a
    relative ``change`` from the fraction ``at`` of the run.

    Parameters
    ----------
    model : str or os.PathLike
        The model file (YAML).
    scenario : str, optional
        One fault, its onset inside the run (0 < TIME <= the last sample's).
    change : float
        Without a scenario: the relative change of each parameter, above 0.
    at : float
        Without a scenario: the onset as a fraction of the run, between 0
        and 1 (and before the last two samples).
    process_noise, measurement_noise : float, optional
        Relative noise levels, as for :func:`diagnose`.
    steps : int, optional
        Samples of the run (default: the model's), within what a prediction
        may take (:func:`bgc.analysis.distinguish.check_steps`, 2 GB).
    level : float
        The probability under which a rival is in the predicted ambiguity
        group, between 0 and 1.
    progress : callable, optional
        ``progress(text)`` is told what is being done (preparing the
        families, fault model i of n, scenario i of n).
    detector_runs : int
        With a scenario: also measure how often bgc's own detector (the
        diagnosis's, at its false-alarm rate) alarms on it, over this many
        simulated runs (seeds ``seed``, ``seed + 1``, ...;
        :mod:`bgc.api.detection`); 0: not measured. The report's
        ``detector`` then holds the rate and its 95 % interval beside the
        ideal detector's probability.
    seed : int
        The first seed of those runs.
    detectors : tuple of str
        The detector's tests on those runs (:attr:`DiagnosisOptions.detectors`:
        the mean test alone by default, or with ``drift``, ``variance``,
        ``frozen``).
    inputs : mapping, optional
        Inputs driven otherwise than the model says, by name: a number, a
        mapping written as in the model's ``inputs`` section (``{"signal":
        "sine", "value": 1, "amplitude": 0.5, "period": 4}``) or a
        :class:`~bgc.ir.Signal`: an input test the plant would run.
    modes : str, optional
        A model with modes: the controlled changes of mode over the run,
        ``MODE@TIME,...`` as ``bgc simulate --modes`` takes them. The run
        starts in the first mode and goes through the automaton as the
        noise-free plant does (its guards and timed transitions, and these
        changes); each fault's response is linearised with the mode held to
        that run (a fault that moves a switch's time is not followed).

    Returns
    -------
    DistinguishabilityReport

    Raises
    ------
    ArgumentTypeError
        An argument of the wrong type.
    ArgumentValueError
        An argument out of range.
    SimulationError
        A malformed scenario, not a fault candidate, its onset outside the
        run; ``at`` too late in the run; a model without fault candidates.
    TrackingError
        A run too long for the memory (the message gives the most steps).
    """
    func = "bgc.distinguishability"
    if not isinstance(model, Session):  # a session: its compilation (the noise levels are this call's)
        arguments.path(func, "model", model)
    if not isinstance(scenario, simulate.FaultInjection):
        arguments.text(func, "scenario", scenario, optional=True)
    check_prediction(func, change, at, process_noise, measurement_noise, steps, level, progress)
    arguments.integer(func, "detector_runs", detector_runs, 0, "is negative", "detector_runs=50")
    arguments.integer(func, "seed", seed, 0, "is negative", "seed=0")
    detecting = DiagnosisOptions(workers=1, detectors=detectors)
    check_options(detecting, func, "")
    if detector_runs and scenario is None:
        raise ArgumentValueError(f"{func}: detector_runs={detector_runs} without a scenario", None,
                                 "give a scenario, e.g. scenario='R12:abrupt:0.3@75'")
    say = progress or (lambda text: None)
    if isinstance(model, Session):
        c, private = model.view, model.folder
    else:
        say("compiling the model")
        opened = cache.open_model(model)
        c, private = opened.view, opened.folder
    arguments.text(func, "modes", modes, optional=True)
    if modes is not None and not c.modes:
        raise ArgumentValueError(f"{func}: modes={modes!r}: {c.model.name} has no modes", None, "leave modes out")
    schedule = _schedule(func, modes, tuple(m.name for m in c.modes)) if modes else ()
    num = c.numerics
    signals = input_signals(func, inputs, c.model)
    if steps is not None:
        simulate.check_steps(steps, num, arguments.spelled(f"{func}: steps={steps}", "--steps"))
    T = steps or c.model.settings.steps
    dt = c.model.settings.dt
    where = arguments.spelled(f"{func}: steps", "--steps") if steps is not None else \
        f"{printable(c.model.source)}: simulation.steps"
    stuck = _stuck_candidates(c)
    distinction.check_steps(T, num, where, len(stuck))
    if scenario is None and not int(at * T) < T - 1:
        raise SimulationError(f"change {change:g} at {at:g} of the run", None,
                              "give a change above 0 and an onset inside the run, a fraction between 0 and 1")
    if not num.faults and not stuck:
        raise SimulationError(f"{c.model.name} declares no fault candidates", None,
                              "list the faults to tell apart under 'faults' in the model file")
    times = dt * np.arange(1, T + 1)
    first = False  # an intermittent fault cut to its first appearance
    if scenario is not None:
        inj = scenario_of(func, scenario, num)
        if inj is None:
            raise SimulationError("a fault-free scenario has no fault to tell apart", None,
                                  "give a fault, e.g. R_pipe:incipient:0.5@165, or no scenario for every candidate")
        listed = [f"{f.parameter}:{f.kind}" for f in num.faults] + [s.name for s in stuck]
        if f"{inj.subject if inj.stuck else inj.parameter}:{inj.kind}" not in listed:
            raise SimulationError(f"{inj.subject or inj.parameter}:{inj.kind} is not a fault candidate of "
                                  f"{c.model.name}: no fault model to tell apart from the others (its diagnosis "
                                  "should end unexplained)", None, "candidates: " + ", ".join(listed))
        if not 0 < inj.time <= times[-1]:
            raise SimulationError(f"onset {inj.time:g} is outside the run (0 to {times[-1]:g})", None,
                                  f"choose an onset inside the run, or more {arguments.spelled('steps', '--steps')}")
        injected = [inj]
        first = bool(inj.spans and inj.spans[0][1] < times[-1])
        if first:  # intermittent: its first appearance, as the monitor meets it
            T = max(int(np.sum(times < inj.spans[0][1] - 1e-9 * dt)), onset_sample(times, inj.time) + 2)
            times = times[:T]
    else:
        injected = _every_candidate(c, stuck, change, times[int(at * T)], T - 1 - int(at * T))
    levels = num.noise_at(process_noise, measurement_noise)
    custom = levels if (process_noise, measurement_noise) != (None, None) else None
    need = distinction.memory(T, *(len(x) for x in (num.equations.states, num.equations.outputs,
                                                     num.equations.inputs, num.faults)), len(stuck))
    # a model with modes: the modes of the noise-free plant's run through its automaton and the schedule
    column = _automaton_modes(func, c, T, schedule, signals) if c.modes else None
    with _LOCK:
        package = packages.load_package(private, c.model.name, str(model), custom)
        families = _families(package, T, need, say, signals, schedule, column)
    priors = {f.parameter: f.prior for f in c.model.faults} | {s.junction: s.prior for s in stuck}
    out = []
    for i, inj in enumerate(injected, start=1):
        say(f"scenario {i} of {len(injected)}: " + (inj.describe() if inj.stuck else
                                                   f"{inj.parameter}:{inj.kind}:{inj.magnitude:.4g}@{inj.time:g}"))
        onset = onset_sample(times, inj.time)
        # a stuck switch: the truth runs through the modes the faulty plant itself takes (its guards see it)
        own = _stuck_inputs(func, c, families, T, schedule, signals, inj) if inj.stuck else None
        out.append(distinction.distinguish(families, f"{inj.subject if inj.stuck else inj.parameter}_{inj.kind}",
                                           1.0 if inj.stuck else inj.magnitude, onset, priors, level, own))
    warning = simulate.outside_prior(injected[0], num) if scenario is not None else None
    rate = _detector_rate(model, injected[0], T, detector_runs, seed, detecting, (process_noise, measurement_noise),
                          progress, signals, schedule) if detector_runs else None
    return DistinguishabilityReport(c.model.name, c.model.display_source, T, dt, (process_noise, measurement_noise),
                                    scenario if isinstance(scenario, str) or scenario is None else scenario.text,
                                    None if scenario else change, None if scenario else at, tuple(out),
                                    warning, rate, signals, (modes or "") if c.modes else None,
                                    first, c.model.settings.time_unit)



def _detector_rate(model, injection, steps: int, runs: int, seed: int, options: DiagnosisOptions, noise: tuple,
                   progress, signals, schedule: tuple = ()):
    """bgc's detector on ``runs`` simulated runs of ``injection``
    (:func:`bgc.api.detection.detector_rate`), on ``model`` opened at the
    noise levels ``noise`` (a session at them: itself)."""
    from .detection import detector_rate

    session = model if isinstance(model, Session) and model.noise == noise else \
        open_session(model.model if isinstance(model, Session) else model, process_noise=noise[0],
                     measurement_noise=noise[1])
    return detector_rate(session, injection, steps, runs, seed, options=options, progress=progress, signals=signals,
                         schedule=schedule)


#: Prepared families by package (its module name tells the noise levels) and
#: run length; the latest few are kept (a campaign worker meets a few models),
#: as many as fit, with the next one, in ``distinguish.MAX_BYTES``.
_FAMILIES: dict[tuple, distinction.Families] = {}


_FAMILIES_KEPT = 4


def _every_candidate(c, stuck, change: float, onset: float, samples: int) -> list:
    """A scenario of each fault candidate of compiled model ``c`` from time
    ``onset``: a relative ``change`` of its scale, each direction the model
    gives it (a drift reaching it ``samples`` samples later, at the run's
    end), and each stuck switch of ``stuck`` (no size)."""
    num, dt, out = c.numerics, c.model.settings.dt, []
    for f in num.faults:
        candidate = next(x for x in c.model.faults if x.parameter == f.parameter)
        for sign in (1,) if fault_kind(f.kind).replaces else DIRECTIONS[candidate.direction]:
            magnitude = simulate.change_magnitude(num, f.name, sign * change, samples * dt)
            out.append(simulate.FaultInjection(f.parameter, f.kind, magnitude, float(onset)))
    return out + [simulate.FaultInjection(s.junction, s.kind, math.nan, float(onset), "switch", s.junction)
                  for s in stuck]


def _stuck_candidates(c) -> tuple:
    """The stuck switches the compiled model ``c`` lists among its fault
    candidates (:class:`bgc.ir.StuckSwitch`; none for a model without modes)."""
    from .simulate import _checked

    return _checked(c)[0].model.modes.stuck if c.modes else ()


def _stuck_inputs(func: str, c, families: distinction.Families, steps: int, schedule: tuple, signals: tuple,
                  injection) -> np.ndarray:
    """The inputs of the families with the mode column of the noise-free
    plant's run with the stuck switch ``injection`` (the same controlled
    changes; its guards see what the stuck switch makes: a relay welded
    shut keeps the voltage under the guard that would have opened it)."""
    us = np.array(families.us, dtype=float)
    column = getattr(nominal_model(families.package), "MODE_INPUT", None)
    if column is not None:
        us[:, column] = _automaton_modes(func, c, steps, schedule, signals, injection)
    return us


def _automaton_modes(func: str, c, steps: int, schedule: tuple, signals: tuple, fault=None) -> np.ndarray:
    """The mode's number at each of ``steps`` samples of the noise-free run
    of the model with modes ``c`` through its automaton (its guards, timed
    transitions and the controlled changes ``schedule``; ``fault``: with
    that fault), as the truth simulator runs it; a change the model does not
    allow is a one-line error."""
    from .simulate import _checked

    h, nums = _checked(c)
    options = simulate.SimulationOptions(steps=steps, process_noise=0.0, measurement_noise=0.0, seed=0,
                                         signals=signals, fault=fault)
    try:
        return np.asarray(hybrid.simulate(h, nums, options, schedule).modes, dtype=float)
    except SimulationError as exc:
        raise ArgumentValueError(f"{func}: {exc.what}", None, exc.fix) from None


def _families(package, steps: int, need: int = 0, progress=None, signals: tuple = (),
              schedule: tuple = (), modes: np.ndarray | None = None) -> distinction.Families:
    """The families of ``package`` over ``steps`` samples (``signals``: the
    inputs driven otherwise than the model says; a model with modes:
    ``modes``, the mode at each sample, from the controlled changes
    ``schedule``), prepared once; ``need``: the bytes a new preparation is
    expected to take (older families are let go until it fits)."""
    key = (package.__name__, str(getattr(package, "__file__", "")), steps, signals, schedule)
    if key not in _FAMILIES:
        while _FAMILIES and (len(_FAMILIES) >= _FAMILIES_KEPT
                             or sum(map(_nbytes, _FAMILIES.values())) + need > distinction.MAX_BYTES):
            _FAMILIES.pop(next(iter(_FAMILIES)))
        _FAMILIES[key] = distinction.prepare(package, linear.scenario_inputs(package, steps, signals, modes),
                                             progress)
    return _FAMILIES[key]


def _nbytes(families: distinction.Families) -> int:
    """The bytes of a family's arrays."""
    w = families.whitening
    arrays = (families.us, families.x_before, families.x_after, families.y, w.F, w.H, w.K, w.Linv,
              *families.responses)
    return sum(a.nbytes for a in arrays)
