""":func:`diagnose`: a run file, a :class:`~bgc.data.runs.Run` or a simulated scenario diagnosed."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any


from .. import arguments
from ..errors import (
    ArgumentTypeError, ArgumentValueError, printable,
)
from ..data import runs
from ..analysis import simulate
from ..analysis import track
from ..diagnosis.options import DiagnosisOptions
from ..diagnosis.decomposed import Plan, diagnose as diagnose_decomposed
from ..diagnosis.diagnose import IDENTIFY, diagnose as run_diagnosis
from ..data.sampler import check_jumps, grid_steps
from .limits import (METHODS, check_diagnosis_steps, check_options,
                     with_horizon)
from .reports import DiagnosisReport
from .session import Session, _session_of, input_signals, isolation_signatures
from .simulate import Simulation, _schedule, checked_scenario, simulated_run


def diagnose(model: str | Path | Session, data: str | Path | runs.Run | None = None,
             scenario: str | simulate.FaultInjection | None = None, *,
             filter: str | None = None, particles: int = 1000, seed: int = 0, identify: str = "kalman",
             process_noise: float | None = None, measurement_noise: float | None = None,
             steps: int | None = None, generated: str | Path | None = None,
             options: DiagnosisOptions | None = None, progress=None,
             prior_scale: float | None = None, backend: str | None = None, columns=None,
             inputs: Mapping[str, Any] | None = None, method: str | None = None,
             modes: str | None = None, decompose: bool = False) -> DiagnosisReport:
    """Diagnose ``data`` (a run file, a :class:`~bgc.data.runs.Run` or a :class:`Simulation`) or a
    simulated ``scenario`` (``NAME:KIND:MAGNITUDE@TIME``, or ``none`` for a
    fault-free run) of ``model``.

    Parameters
    ----------
    model : str, os.PathLike or Session
        The model file (YAML), or a :class:`Session` of it (:func:`open`:
        compiled once for many diagnoses; its noise levels then apply, and
        ``process_noise``, ``measurement_noise`` and ``generated`` must be
        left out or be the session's).
    data : str, os.PathLike, Run or Simulation, optional
        A recorded run: a CSV as ``bgc simulate`` writes, a
        :class:`~bgc.data.runs.Run` (checked as a file's would be, by
        :func:`bgc.data.runs.check_run`), or a :class:`Simulation`
        (:func:`bgc.simulate`; its truth goes into the report). Either
        ``data`` or ``scenario``.
    scenario : str or FaultInjection, optional
        A fault to simulate, its onset inside the run (0 < TIME < the last
        sample's time), or ``none``; or the scenario already read
        (:func:`bgc.analysis.simulate.parse_scenario`).
    filter : {"gpf", "apf", "opf", "ckf"}
        The filter (``bgc diagnose --filter``; a campaign's ``filters``):
        a particle filter (the thesis's generic, auxiliary and optimal
        proposal ones, default ``gpf``) or cubature Kalman filters.
    particles : int
        Particles of each filter, at least 1.
    seed : int
        Seeds the simulation of a scenario and, unless ``options`` is given,
        the filters; an integer >= 0.
    process_noise, measurement_noise : float, optional
        Relative noise levels (fractions of the signal), at most 1e6: a
        scenario is simulated with them, and the filters assume them
        (default: the model's). The process level may be 0, the measurement
        level must be above 0.
    steps : int, optional
        With a scenario: the samples to simulate (default: the model's),
        within what the diagnosis may take (:func:`check_diagnosis_steps`).
    generated : str or os.PathLike, optional
        The folder ``bgc compile -o`` wrote the package to (default: a
        private one generated for this call).
    identify : {"kalman", "filter"}
        Where the fault's size (and the hypotheses' weights) come from
        (``--identify``): ``kalman`` (default) holds the magnitude static
        on a grid of cubature Kalman filters, whatever the filter;
        ``filter`` takes the particle filters' own magnitude state (the
        thesis's method; not with ``filter="ckf"``). Each estimate says
        which (:attr:`Estimate.method`; ``estimate_method`` in report.json):
        compare filters with ``identify="filter"``.
    options : DiagnosisOptions, optional
        Overrides ``filter``, ``particles``, ``identify`` and the filters' seed.
    progress : callable, optional
        ``progress(text)`` is told what is being done.
    prior_scale : float, optional
        Widens every fault's prior of its magnitude by this factor
        (``--prior-scale``; default 1: the model's priors).
    backend : {"numpy", "numba", "auto"}, optional
        The generated package the filters run on (``--backend``): the NumPy
        package, or the compiled one (numba, the ``fast`` extra); None or
        "auto": numba when it is installed (the environment's
        ``BGC_BACKEND`` first). The diagnosis does not depend on it.
    columns : str, os.PathLike or ColumnMap, optional
        With a run file: a column map from the logger's column names to
        bgc's, with scales and offsets (``--columns``; a YAML file,
        :mod:`bgc.data.columns`). A time column of ISO 8601 timestamps is
        read with or without one.
    inputs : mapping, optional
        With a scenario: inputs driven otherwise than the model says, by
        name: a number, a mapping written as in the model's ``inputs``
        section (``{"signal": "sine", "value": 1, "amplitude": 0.5,
        "period": 4}``) or a :class:`~bgc.ir.Signal` (``bgc simulate
        --input``).
    modes : str, optional
        With a scenario of a model with modes: the controlled changes of
        mode over the simulated run, ``MODE@TIME,...`` as ``bgc simulate
        --modes`` takes them (the run starts in the first mode; the
        autonomous and timed changes happen by themselves).
    decompose : bool
        Diagnose on the model's submodels (``bgc diagnose --decompose``,
        :mod:`bgc.diagnosis.decomposed`): the plant split at its sensors as
        ``bgc compile --decompose`` splits it, each fault weighed on the
        submodels it touches, by cubature Kalman filters (``filter`` "ckf"
        or left out; the submodels carry the model's own noise levels, so
        ``process_noise``, ``measurement_noise`` and ``generated`` are left
        out). The diagnosis lists the sensors as the submodels predict them.

    Returns
    -------
    DiagnosisReport

    Raises
    ------
    ArgumentTypeError
        An argument of the wrong type (``particles=100.5``, ``scenario=5``,
        ``options={}``; a bool is not an integer here).
    ArgumentValueError
        An argument out of range (``seed=-1``, ``process_noise=-1.0``), both
        or neither of ``data`` and ``scenario``, ``steps`` with ``data``.
    DataError
        The run cannot be read, is not of this model or is malformed (named
        by its file and line, or its ``source``).
    SimulationError
        The simulated plant diverges (a malformed scenario, or one whose
        onset is outside the run, is an ArgumentValueError).
    TrackingError
        A request beyond the memory (too many steps or particles).
    BgcError
        The model's own errors (load, validation, ...).
    """
    func = "bgc.diagnose"
    if not isinstance(model, Session):
        arguments.path(func, "model", model)
    if data is not None and not isinstance(data, (str, os.PathLike, runs.Run, Simulation)):
        raise ArgumentTypeError(f"{func}: data={arguments.shown(data)} is not a path, a Run or a Simulation", None,
                                "give a run file's path, a bgc.data.runs.Run or what bgc.simulate returned")
    simulated = data if isinstance(data, Simulation) else None
    if simulated is not None:  # its truth goes with it into the report
        data = simulated.run
    if not isinstance(scenario, simulate.FaultInjection):
        arguments.text(func, "scenario", scenario, optional=True)
    if (data is None) == (scenario is None):
        both = "both" if data is not None else "neither"
        raise ArgumentValueError(f"{func}: give either data or a scenario, not {both}", None,
                                 "e.g. data='run.csv' or scenario='R_pipe:incipient:0.5@165'")
    arguments.flag(func, "decompose", decompose)
    if decompose:
        filter = _decomposed_filter(func, filter, method, process_noise, measurement_noise, generated)
    filter = arguments.renamed(func, "filter", filter, "method", method, "gpf")
    arguments.choice(func, "filter", filter, METHODS)
    arguments.choice(func, "identify", identify, IDENTIFY)
    arguments.integer(func, "particles", particles, 1, "at least 1 particle is needed", "particles=1000")
    arguments.integer(func, "seed", seed, 0, "is negative", "seed=0")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if columns is not None and data is None:
        raise ArgumentValueError(f"{func}: columns= without data: a column map is for a run file", None,
                                 "give data='run.csv' with it, or leave columns out")
    if inputs is not None and scenario is None:
        raise ArgumentValueError(f"{func}: inputs= with data: a recorded run has its own inputs", None,
                                 "give inputs with a scenario only")
    if modes is not None:
        arguments.text(func, "modes", modes)
        if scenario is None:
            raise ArgumentValueError(f"{func}: modes= with data: a recorded run has its own mode column", None,
                                     "give modes with a scenario only")
    if steps is not None:
        arguments.integer(func, "steps", steps, 1, "simulate at least 1 step", "steps=300")
        if data is not None:
            raise ArgumentValueError(f"{func}: steps={steps} with data: a recorded run has its own length", None,
                                     "give steps with a scenario only")
    arguments.path(func, "generated", generated, optional=True)
    if options is not None:
        check_options(options, func)
    arguments.callable_or_none(func, "progress", progress)
    say = progress or (lambda text: None)
    if options is None:
        options = DiagnosisOptions(filter=filter, particles=particles, seed=seed, identify=identify)
        check_options(options, func, "")  # made of the arguments: their names
    opts = options
    length = steps if scenario is not None else (len(data.time) or None) if isinstance(data, runs.Run) else None
    work = (opts.particles, length)  # auto's estimate (a run file's length: the model's)
    session = _session_of(func, model, process_noise, measurement_noise, generated, say, prior_scale, backend, work)
    plan = _decomposed_plan(func, session, opts, say) if decompose else None  # refused before any simulation
    if scenario is not None:
        signals = input_signals(func, inputs, session.view.model)
        if modes is not None and not session.view.modes:
            raise ArgumentValueError(f"{func}: modes={modes!r}, and the model has no modes", None, "drop modes=")
        schedule = _schedule(func, modes, tuple(m.name for m in session.view.modes)) if modes else ()
        run, injected = _scenario_run(session, scenario, steps, seed, opts, say, signals, schedule)
    else:
        run, injected = _recorded_run(session, session.read_run(data, columns, func), opts), None
    if isinstance(scenario, simulate.FaultInjection):
        scenario = scenario.text
    if simulated is not None:
        scenario, injected = simulated.scenario, simulated.fault
    return _run(session.view, run, plan if decompose else session.package, scenario, injected, session.noise,
                session.levels, opts, say)


def _decomposed_plan(func: str, session: Session, opts: DiagnosisOptions, say) -> Plan:
    """The submodels of ``session``'s model (:func:`bgc.api.decomposed.open_plan`), the session's
    noise levels and the options a decomposed diagnosis cannot take refused."""
    if session.noise != (None, None):
        raise ArgumentValueError(f"{func}: decompose=True with a session of other noise levels: the "
                                 "submodels carry the model's own", None, "open the session without them")
    if opts.rank or opts.refine:
        raise ArgumentValueError(f"{func}: decompose=True with {'rank' if opts.rank else 'refine'}: the "
                                 "submodels are weighed by cubature Kalman filters alone", None,
                                 "leave options.rank and options.refine (--rank, --refine) off")
    if tuple(opts.detectors) != ("mean",):
        raise ArgumentValueError(f"{func}: decompose=True with the detectors {', '.join(opts.detectors)}: the "
                                 "submodels are watched by the mean test alone", None,
                                 "leave options.detectors (--detect) at mean")
    from .decomposed import open_plan  # the compiler splits the model: imported only when asked for

    return open_plan(session.model, session.prior_scale, say)


def _decomposed_filter(func: str, filter, method, process_noise, measurement_noise, generated) -> str:
    """The filter of a decomposed diagnosis: ckf, the only one; the arguments it cannot take refused."""
    chosen = filter if filter is not None else method  # options.filter: replaced by ckf
    if chosen not in (None, "ckf"):
        raise ArgumentValueError(f"{func}: decompose=True with filter={chosen!r}: the submodels are weighed by "
                                 "cubature Kalman filters", None, "use filter='ckf', or leave filter out")
    for name, value in (("process_noise", process_noise), ("measurement_noise", measurement_noise),
                        ("generated", generated)):
        if value is not None:
            raise ArgumentValueError(f"{func}: decompose=True with {name}=: the submodels carry the model's own "
                                     "noise levels and are compiled from it", None, f"drop {name}=")
    return "ckf"


def _scenario_run(session: Session, scenario, steps: int | None, seed: int, opts: DiagnosisOptions,
                  say, signals: tuple = (), schedule: tuple = ()) -> tuple[runs.Run, simulate.FaultInjection | None]:
    """The run of a simulated scenario at the session's noise levels (its
    inputs driven by ``signals`` where given; a model with modes through
    the controlled changes ``schedule``), checked (its onset inside the
    run, its length within the diagnosis's memory)."""
    c = session.view
    injected, where = checked_scenario("bgc.diagnose", c, scenario, steps)
    check_diagnosis_steps(steps or c.model.settings.steps, c.numerics, opts.particles, opts.filter, where,
                          opts.history)
    say("simulating the scenario")
    text = scenario.strip() if isinstance(scenario, str) else scenario.text
    return simulated_run(c, injected, text, steps, seed, session.noise, signals, schedule), injected


def _recorded_run(session: Session, run: runs.Run, opts: DiagnosisOptions) -> runs.Run:
    """A recorded run (read by :meth:`Session.read_run`), checked: its grid
    within the diagnosis's memory."""
    c = session.view
    check_jumps(run.time, c.model.settings.dt, run.source, c.model.settings.time_unit)  # before the memory rule
    grid = grid_steps(run.time, c.model.settings.dt)  # the model's time grid: a gap's steps count too
    check_diagnosis_steps(grid, c.numerics, opts.particles, opts.filter,
                          f"{printable(run.source)}: {len(run.time)} samples"
                          + (f" over {grid} steps of dt" if grid != len(run.time) else ""), opts.history)
    return run


def _run(c, run, package, scenario, injected, noise, levels, opts, say) -> DiagnosisReport:
    """The diagnosis of ``run`` with ``package`` (a :class:`~bgc.diagnosis.decomposed.Plan`: on the submodels)."""
    if not isinstance(package, Plan):
        track.check_request(run, package, "nominal", opts.particles, None, columns=False)
    opts = with_horizon(opts, c.model.settings)
    if scenario is not None and opts.input_timing == "start":
        raise ArgumentValueError(f"{arguments.spelled('bgc.diagnose: options.input_timing', '--input-timing')}="
                                 "start with a simulated scenario: bgc simulate's inputs are held over the step "
                                 "that ends at each row's time", None, "drop it, or give it with data")
    timing = runs.resolve_timing(run.header, opts.input_timing, run.source,
                                 arguments.spelled("options.input_timing", "--input-timing"))
    if timing != (opts.input_timing or "end"):  # the header's word (None stays None: the default, as a stream's)
        opts = dataclasses.replace(opts, input_timing=timing)
    if isinstance(package, Plan):  # decompose=True: on the submodels
        result = diagnose_decomposed(run, package, dataclasses.replace(opts, filter="ckf"), say)
    else:
        result = run_diagnosis(run, package, isolation_signatures(c), c.priors, opts, say,
                               time_unit=c.model.settings.time_unit)
    return DiagnosisReport(c.model.name, c.model.display_source, run, scenario, injected, noise, levels, opts,
                           result, c.labels)
