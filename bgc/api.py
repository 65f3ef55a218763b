"""The Python API: what the CLI does, for a notebook or a script.

>>> import bgc
>>> report = bgc.diagnose("models/circuit.yaml", scenario="R2:abrupt:0.6@5", seed=1)
>>> report.diagnosis.verdict, report.diagnosis.candidates
('isolated', ('R2_abrupt',))
>>> e = report.diagnosis.estimate
>>> round(e.value, 1), e.low < 0.6 < e.high
(0.6, True)

:func:`diagnose` compiles the model, generates its NumPy package (into a
private folder, or uses the one ``generated`` points at), reads the run (or
simulates ``scenario`` with the truth simulator), and runs
:func:`bgc.diagnosis.diagnose.diagnose`. :mod:`bgc.output.report` turns the
result into ``report.json``, ``report.md``, ``report.html`` and plots:
:meth:`DiagnosisReport.write` writes them, :meth:`DiagnosisReport.figures`
gives the plots as matplotlib figures, and in a notebook a report, a
:class:`Session` and a :class:`CalibrationReport` show a summary
(``_repr_html_``; ``docs/examples/diagnose.ipynb``).

Every public function checks its arguments before any work, as the command
line does, with the same ranges: a wrong type is an
:class:`~bgc.errors.ArgumentTypeError` (also a :class:`TypeError`), a value
out of range an :class:`~bgc.errors.ArgumentValueError` (also a
:class:`ValueError`), each one line naming the function and the argument;
problems of the data (a run file, a :class:`~bgc.data.runs.Run`) are the
runtime's :class:`~bgc.errors.DataError`, naming the run's ``source``.

>>> bgc.diagnose("models/circuit.yaml", scenario="none", seed=-1)
Traceback (most recent call last):
...
bgc.errors.ArgumentValueError: bgc.diagnose: seed=-1 is negative (give an integer >= 0, e.g. seed=0)
"""

from __future__ import annotations

import atexit
import dataclasses
import hashlib
import math
import os
import shutil
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from . import arguments, pipeline
from .compiler.printing import escape
from .errors import (
    ArgumentTypeError, ArgumentValueError, CalibrationError, OutputError, SimulationError, TrackingError, printable,
)
from .ir import NUMBA_PACKAGE, PACKAGE, NoiseLevels, Numerics
from .kinds import DIRECTIONS, fault_kind
from .analysis import distinguish as distinction
from .output import calibrated
from .output.labels import Labels, labels_of
from .analysis import calibrate as calibration
from .diagnosis.options import GridOptions, KalmanOptions
from .experiment import metrics
from .data import runs
from .analysis import simulate
from .model import package as packages
from .analysis import track
from .filters import registry
from .model import warmup
from .diagnosis.diagnose import IDENTIFY, KALMAN_METHOD, PATHS, Diagnosis
from .diagnosis.options import DiagnosisOptions
from .diagnosis.diagnose import diagnose as run_diagnosis
from .data.sampler import grid_steps
from .diagnosis.diagnose import horizon_steps
from .diagnosis.diagnoser import Diagnoser

#: The filters of a diagnosis (``bgc diagnose --filter``).
METHODS = tuple(registry.FILTER_CLASSES)


@dataclass(frozen=True, slots=True)
class DiagnosisReport:
    """A diagnosis and what it was made from: the model file, the run (read or
    simulated), the injected fault of a simulated ``scenario`` (None for data
    from a file or a fault-free scenario), the relative noise levels the
    filters assumed (None: the model's), and the options."""

    model: str
    source: str
    run: runs.Run
    scenario: str | None
    injected: simulate.FaultInjection | None
    noise: tuple[float | None, float | None]
    noise_levels: NoiseLevels
    options: DiagnosisOptions
    diagnosis: Diagnosis
    #: What each variable is and its unit, from the model (:mod:`bgc.output.labels`).
    labels: Labels = Labels()

    def __repr__(self) -> str:  # the run and the diagnosis hold arrays: the verdict is what a reader wants
        d = self.diagnosis
        return (f"<bgc.DiagnosisReport of {self.model}: {d.verdict}"
                + (f": {', '.join(d.candidates)}" if d.candidates else "") + ">")

    def write(self, folder: str | Path) -> Path:
        """Write the report folder ``bgc diagnose -o`` writes into ``folder``
        (report.md, report.json, report.html, the plots, the run when it was
        simulated, manifest.json): a new or empty folder, or one a diagnosis
        report was written to before and nobody changed since. Returns the
        folder.

        Raises
        ------
        ArgumentTypeError
            ``folder`` is not a path.
        OutputError
            ``folder`` is a file, or holds files bgc did not write (or that
            changed since), or another command's report.
        """
        arguments.path("bgc.DiagnosisReport.write", "folder", folder)
        from .output import artifacts, report

        out = Path(folder)
        artifacts.write_folder(out, report.report_files(self))
        return out

    def figures(self) -> dict:
        """The report's plots as live :class:`matplotlib.figure.Figure`
        objects, by the file name :meth:`write` gives each:
        ``measurements.png`` and ``residuals.png``, and ``hypotheses.png``
        and ``estimate.png`` when a fault model was tried. Plain figures,
        not pyplot's: a notebook shows one when it is the cell's value
        (``%matplotlib inline``), ``fig.savefig(...)`` saves it."""
        from .output import plots

        return plots.diagnosis_plots(self)

    def _repr_html_(self) -> str:
        """A notebook's view: the verdict in words, the detection, the
        estimate with its interval and its picture (:func:`bgc.output.summary.diagnosis_html`)."""
        from .output import summary

        return summary.diagnosis_html(self)


def diagnose(model: str | Path | Session, data: str | Path | runs.Run | None = None, scenario: str | None = None, *,
             method: str = "gpf", particles: int = 1000, seed: int = 0,
             process_noise: float | None = None, measurement_noise: float | None = None,
             steps: int | None = None, generated: str | Path | None = None,
             options: DiagnosisOptions | None = None, progress=None,
             prior_scale: float | None = None, backend: str | None = None) -> DiagnosisReport:
    """Diagnose ``data`` (a run file or a :class:`~bgc.data.runs.Run`) or a
    simulated ``scenario`` (``NAME:KIND:MAGNITUDE@TIME``, or ``none`` for a
    fault-free run) of ``model``.

    Parameters
    ----------
    model : str, os.PathLike or Session
        The model file (YAML), or a :class:`Session` of it (:func:`open`:
        compiled once for many diagnoses; its noise levels then apply, and
        ``process_noise``, ``measurement_noise`` and ``generated`` must be
        left out or be the session's).
    data : str, os.PathLike or Run, optional
        A recorded run: a CSV as ``bgc simulate`` writes, or a
        :class:`~bgc.data.runs.Run` (checked as a file's would be, by
        :func:`bgc.data.runs.check_run`). Either ``data`` or ``scenario``.
    scenario : str, optional
        A fault to simulate, its onset inside the run (0 < TIME < the last
        sample's time), or ``none``.
    method : {"gpf", "apf", "opf", "ckf"}
        The filter (``bgc diagnose --filter``).
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
    options : DiagnosisOptions, optional
        Overrides ``method``, ``particles`` and the filters' seed.
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
        A malformed scenario, or its onset outside the run.
    TrackingError
        A request beyond the memory (too many steps or particles).
    BgcError
        The model's own errors (load, validation, ...).
    """
    func = "bgc.diagnose"
    if not isinstance(model, Session):
        arguments.path(func, "model", model)
    if data is not None and not isinstance(data, (str, os.PathLike, runs.Run)):
        raise ArgumentTypeError(f"{func}: data={arguments.shown(data)} is not a path or a Run", None,
                                "give a run file's path or a bgc.data.runs.Run")
    arguments.text(func, "scenario", scenario, optional=True)
    if (data is None) == (scenario is None):
        both = "both" if data is not None else "neither"
        raise ArgumentValueError(f"{func}: give either data or a scenario, not {both}", None,
                                 "e.g. data='run.csv' or scenario='R_pipe:incipient:0.5@165'")
    arguments.choice(func, "method", method, METHODS)
    arguments.integer(func, "particles", particles, 1, "at least 1 particle is needed", "particles=1000")
    arguments.integer(func, "seed", seed, 0, "is negative", "seed=0")
    arguments.noise_levels(func, process_noise, measurement_noise)
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
    session = _session_of(func, model, process_noise, measurement_noise, generated, say, prior_scale, backend)
    opts = options or DiagnosisOptions(method=method, particles=particles, seed=seed)
    if scenario is not None:
        run, injected = _scenario_run(session, scenario, steps, seed, opts, say)
    else:
        run, injected = _recorded_run(session, data, opts), None
    return _run(session.compiled, run, session.package, scenario, injected, session.noise, session.levels, opts,
                say)


def _scenario_run(session: Session, scenario: str, steps: int | None, seed: int, opts: DiagnosisOptions,
                  say) -> tuple[runs.Run, simulate.FaultInjection | None]:
    """The run of a simulated scenario at the session's noise levels, checked
    (its onset inside the run, its length within the diagnosis's memory)."""
    c = session.compiled
    T = steps or c.model.settings.steps
    where = "--steps" if steps is not None else f"{printable(c.model.source)}: simulation.steps"
    simulate.check_steps(T, c.numerics, where)
    injected = None
    if scenario.strip().lower() != "none":
        injected = simulate.parse_fault(scenario, c.numerics)
        last = T * c.model.settings.dt
        if not 0 < injected.time < last:
            raise SimulationError(f"scenario {printable(scenario.strip())}: onset {injected.time:g} is outside the "
                                  f"run (0 to {last:g})", None, "choose an onset inside the run, or more --steps")
    check_diagnosis_steps(T, c.numerics, opts.particles, opts.method, where, opts.history)
    say("simulating the scenario")
    process_noise, measurement_noise = session.noise
    result = simulate.simulate(c.numerics, simulate.SimulationOptions(
        steps=steps, process_noise=process_noise, measurement_noise=measurement_noise, seed=seed, fault=injected))
    return runs.parse_run(simulate.to_csv(result), f"scenario {scenario.strip()}"), injected


def _recorded_run(session: Session, data, opts: DiagnosisOptions) -> runs.Run:
    """A recorded run (a file or a Run), checked: of this model, its grid
    within the diagnosis's memory."""
    c = session.compiled
    run = runs.check_run(data) if isinstance(data, runs.Run) else runs.read_run(data)
    track.check_run_of(run, c.model.name)
    grid = grid_steps(run.time, c.model.settings.dt)  # the model's time grid: a gap's steps count too
    check_diagnosis_steps(grid, c.numerics, opts.particles, opts.method,
                          f"{printable(run.source)}: {len(run.time)} samples"
                          + (f" over {grid} steps of dt" if grid != len(run.time) else ""), opts.history)
    return run


def _session_of(func: str, model, process_noise, measurement_noise, generated, say,
                prior_scale: float | None = None, backend: str | None = None) -> Session:
    """``model`` when it is a :class:`Session` (whose noise levels, prior
    scale and package apply: other ones are refused), else a new session of
    the file."""
    if not isinstance(model, Session):
        say("compiling the model")
        session = Session(model, process_noise, measurement_noise, generated,
                          1.0 if prior_scale is None else prior_scale, backend)
        note = session.backend_note()
        if note:
            say(note)
        return session
    if (process_noise, measurement_noise) not in ((None, None), model.noise) or generated is not None \
            or prior_scale not in (None, model.prior_scale) or backend not in (None, "auto", model.backend):
        raise ArgumentValueError(f"{func}: noise levels, prior_scale, backend or generated= with a Session: the session's "
                                 "apply", None, "open a session with them: bgc.open(model, process_noise=..., ...)")
    return model


class Session:
    """A compiled model and its generated package, ready to diagnose: made
    by :func:`open`. ``model``: the model file; ``noise``: the relative
    (process, measurement) noise levels the filters assume (None: the
    model's). A session holds its own compilation and package (in a private
    folder removed at exit); nothing is cached between sessions: diagnose
    many runs of one model through one session (``bgc.diagnose(session,
    data=...)``, :meth:`diagnoser`).

    >>> import bgc
    >>> session = bgc.open("models/circuit.yaml")
    >>> d = session.diagnoser(particles=200)
    >>> belief = d.step(0.05, y={"e11": 2.45, "f2": 2.49, "f6": 2.47})  # no u: the model's input
    >>> belief.phase, belief.alarm, belief.events
    ('watching', None, (InputFromModel(input='V', reason='absent', step=None),))
    """

    def __init__(self, model: str | Path, process_noise: float | None = None,
                 measurement_noise: float | None = None, generated: str | Path | None = None,
                 prior_scale: float = 1.0, backend: str | None = None):
        func = "bgc.open"
        arguments.path(func, "model", model)
        arguments.noise_levels(func, process_noise, measurement_noise)
        arguments.path(func, "generated", generated, optional=True)
        arguments.real(func, "prior_scale", prior_scale, 0.0, MAX_PRIOR_SCALE,
                       f"a factor above 0 and below {MAX_PRIOR_SCALE:g}, e.g. prior_scale=2")
        if generated is not None and prior_scale != 1.0:
            raise ArgumentValueError(f"{func}: prior_scale={prior_scale:g} with generated=: that package carries the "
                                     "priors it was compiled with", None,
                                     "drop generated= (a package is generated with the widened priors), or the "
                                     "prior scale")
        self.model = str(model)
        self.noise = (process_noise, measurement_noise)
        self.prior_scale = float(prior_scale)
        if backend is not None:
            arguments.choice(func, "backend", backend, (*packages.BACKENDS, "auto"))
        self.backend = packages.resolve_backend(backend)
        self.compiled, self.folder = _compiled(model, self.prior_scale)  # this session's own compilation and folder
        c = self.compiled
        levels = c.numerics.noise_at(process_noise, measurement_noise)
        self.levels = levels
        custom = levels if (process_noise, measurement_noise) != (None, None) else None
        #: why the compiled backend, chosen by what is installed, could not be had (None: it was not needed)
        self.fallback: str | None = None
        try:
            self._load(generated, str(model), custom)
        except Exception as exc:  # noqa: BLE001 - whatever keeps the compiled package from working
            if self.backend == "numpy":
                raise
            why = printable(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)[:200]
            if packages.chosen_by_name(backend):
                raise TrackingError(f"the numba backend cannot run {printable(str(model))}: {why}", None,
                                    "use --backend numpy (backend='numpy')") from None
            self.backend, self.fallback = "numpy", why
            self._load(generated, str(model), custom)
        self.priors = {f.parameter: f.prior for f in c.model.faults}

    def _load(self, generated, model: str, custom) -> None:
        """Load this session's package of its backend (from ``generated``, or a
        private folder for NumPy, or, for the compiled package, a folder of
        bgc's cache that lasts, so numba's disk cache stays valid) and warm it up."""
        c = self.compiled
        if generated is None:
            generated = self.folder if self.backend == "numpy" else _lasting_folder(c)
        with _LOCK:  # another thread must not see a package half imported
            self.package = packages.load_package(generated, c.model.name, model, custom, self.backend)
            #: (seconds, kernels compiled, kernels loaded from numba's disk cache) of this session's warm-up
            self.warm = warmup.warm_up(self.package)

    @property
    def name(self) -> str:
        return self.compiled.model.name

    def backend_note(self) -> str | None:
        """One line on the compiled backend's warm-up (None on the NumPy
        backend): kernels compiled, or loaded from numba's disk cache, and how
        long it took; or why it could not be had (``auto`` fell back to NumPy)."""
        seconds, compiled, loaded = self.warm
        if self.fallback is not None:
            return f"numba backend unavailable ({self.fallback}): running on numpy"
        if self.backend != "numba":
            return None
        if compiled:
            return (f"numba backend: {compiled} kernels compiled in {seconds:.1f} s (kept in numba's disk cache: "
                    "later runs load them)")
        if loaded:
            return f"numba backend: {loaded} kernels loaded from numba's disk cache in {seconds:.1f} s"
        return "numba backend: kernels compiled before in this process"

    def __repr__(self) -> str:
        return f"<bgc.Session of {self.name} ({printable(self.compiled.model.display_source)})>"

    def _repr_html_(self) -> str:
        """A notebook's view: the model's name and file, elements, bonds and
        states, sensors, inputs, parameters and fault candidates
        (:func:`bgc.output.summary.model_html`)."""
        from .output import summary

        return summary.model_html(self)

    def options(self, options: DiagnosisOptions | None = None, *, method: str = "gpf", particles: int = 1000,
                seed: int = 0, func: str = "bgc.Session.diagnoser") -> DiagnosisOptions:
        """``options`` (checked; default: built from ``method``, ``particles``
        and ``seed``) with the detector's horizon filled in (the model's run
        length when None)."""
        if options is None:
            arguments.choice(func, "method", method, METHODS)
            arguments.integer(func, "particles", particles, 1, "at least 1 particle is needed", "particles=1000")
            arguments.integer(func, "seed", seed, 0, "is negative", "seed=0")
            options = DiagnosisOptions(method=method, particles=particles, seed=seed)
        check_options(options, func)
        return with_horizon(options, self.compiled.model.settings)

    def diagnoser(self, options: DiagnosisOptions | None = None, *, method: str = "gpf", particles: int = 1000,
                  seed: int = 0, inputs=None, sensors=None, source: str = "<stream>", progress=None) -> Diagnoser:
        """An online :class:`~bgc.diagnosis.diagnoser.Diagnoser` of this model:
        ``step(t, u, y)`` per sample, ``finish()`` at the end. ``inputs``,
        ``sensors``: the input and sensor names the data have (default: all
        of the model's sensors, and the inputs the first ``step`` gives);
        ``source``: the data's name in messages."""
        func = "bgc.Session.diagnoser"
        opts = self.options(options, method=method, particles=particles, seed=seed, func=func)
        arguments.text(func, "source", source)
        arguments.callable_or_none(func, "progress", progress)
        nominal = self.package.MODELS["nominal"]
        return Diagnoser(self.package, self.compiled.signatures, self.priors, opts,
                         horizon_steps(opts.horizon, nominal.DT, 0), inputs=inputs, sensors=sensors, source=source,
                         progress=progress, most=most_steps(self.compiled.numerics, opts))

    def calibrate(self, data, estimate: str | tuple[str, ...] = "noise", *, progress=None) -> CalibrationReport:
        """Maximum-likelihood estimates, from healthy recordings ``data`` (a
        run file, a :class:`~bgc.data.runs.Run`, or a list or tuple of
        them), of what ``estimate`` names: ``noise`` (every sensor's
        measurement noise and the process-noise level, the default),
        ``measurement_noise``, ``process_noise`` and parameters of the model
        file, as a comma-separated text or a tuple of names
        (:mod:`bgc.analysis.calibrate`). The :class:`CalibrationReport` holds
        the estimates with their 95 % intervals and the calibrated model's
        text; :meth:`CalibrationReport.write` writes it.

        Raises
        ------
        ArgumentTypeError, ArgumentValueError
            ``data`` or ``estimate`` of the wrong type, no data, or a session
            opened with other noise levels than the model file's.
        CalibrationError
            An unknown name to estimate; a likelihood that is not finite at
            the model's values.
        DataError
            A run that cannot be read or is not of this model.
        """
        func = "bgc.Session.calibrate"
        if self.noise != (None, None):
            raise ArgumentValueError(f"{func}: a session opened with noise levels calibrates from the model file's "
                                     "own", None, "open the session without them: bgc.open(model)")
        items = list(data) if isinstance(data, (list, tuple)) else [data]
        if not items:
            raise ArgumentValueError(f"{func}: data=[] holds no recording", None, "give a run file or a list of them")
        for item in items:
            if not isinstance(item, (str, os.PathLike, runs.Run)):
                raise ArgumentTypeError(f"{func}: data={arguments.shown(item)} is not a path or a Run", None,
                                        "give a run file's path, a bgc.data.runs.Run, or a list of them")
        if isinstance(estimate, tuple):
            for word in estimate:
                arguments.text(func, "estimate", word)
        else:
            arguments.text(func, "estimate", estimate)
        arguments.callable_or_none(func, "progress", progress)
        say = progress or (lambda text: None)
        c = self.compiled
        nominal = self.package.MODELS["nominal"]
        sensors, process, parameters = calibration.targets(estimate, nominal, [p.name for p in c.model.parameters],
                                                           "--estimate" if isinstance(estimate, str) else "estimate")
        records, dates = [], []
        for item in items:
            run = runs.check_run(item) if isinstance(item, runs.Run) else runs.read_run(item)
            track.check_run_of(run, c.model.name)
            records.append(calibration.record_of(run, nominal))
            dates += [h.split(":", 1)[1].strip() for h in run.header
                      if h.lower().startswith(("date:", "recorded:")) and h.split(":", 1)[1].strip()]
        say(f"calibrating on {len(records)} recording(s)")
        result = calibration.calibrate(nominal, c.numerics, records, sensors, process, parameters,
                                       calibration.wants_initial(estimate))
        original = _model_text(self.model, c)
        own = {el.name: el.noise for el in c.model.elements if el.noise is not None}
        text = calibrated.calibrated_text(original, c.model.display_source, result, own, tuple(dates))
        _check_calibrated(text, result, c)
        units = {x.name: x.unit for x in (*c.model.parameters, *c.model.measurements, *c.model.inputs)}
        return CalibrationReport(self.model, self.name, tuple(sensors), process, tuple(parameters), result, text,
                                 units)

    def report(self, run: runs.Run, diagnosis: Diagnosis, scenario: str | None = None,
               injected=None) -> DiagnosisReport:
        """A :class:`DiagnosisReport` of ``diagnosis`` made on ``run``."""
        return DiagnosisReport(self.name, self.compiled.model.display_source, run, scenario, injected, self.noise,
                               self.levels, diagnosis.options, diagnosis, labels_of(self.compiled.model))


@dataclass(frozen=True, slots=True)
class CalibrationReport:
    """A calibration (:meth:`Session.calibrate`): the model file, the
    model's name, the sensors whose noise, whether the process level and
    which parameters were estimated, the :class:`~bgc.analysis.calibrate.Calibration`
    (estimates, intervals, innovations) and ``text``, the calibrated model
    file (the user's text with the estimates in place, comments kept)."""

    model: str
    name: str
    sensors: tuple[str, ...]
    process: bool
    parameters: tuple[str, ...]
    calibration: calibration.Calibration
    text: str
    units: Mapping[str, str | None] = field(default_factory=dict)

    def _repr_html_(self) -> str:
        """A notebook's view: whether the model fits the data, the estimates
        with their intervals and their picture (:func:`bgc.output.summary.calibration_html`)."""
        from .output import summary

        return summary.calibration_html(self)

    def write_report(self, folder: str | Path) -> Path:
        """Write the calibration report into ``folder`` (report.md,
        report.html, report.json, estimates.png, residuals.png, autocorrelation.png;
        docs/calibrate.md, "The report"): a new or empty folder, or one a
        calibration report was written to before and nobody changed since.

        Raises
        ------
        OutputError
            ``folder`` is a file, or holds files bgc did not write.
        """
        arguments.path("bgc.CalibrationReport.write_report", "folder", folder)
        from .output import artifacts, calibration_report

        out = Path(folder)
        artifacts.write_folder(out, calibration_report.report_files(self))
        return out

    def write(self, path: str | Path) -> Path:
        """Write the calibrated model to ``path`` (a new file, or one bgc
        wrote and nobody changed since: never the model file, a data file
        or another file bgc did not write).

        Raises
        ------
        OutputError
            ``path`` is the model file or a data file, or exists and bgc did
            not write it (or it changed since).
        """
        arguments.path("bgc.CalibrationReport.write", "path", path)
        check_calibration_output(path, self.model, self.calibration.sources)
        from .output import artifacts

        return artifacts.write_file(Path(path), self.text)


def check_calibration_output(path: str | Path, model: str | Path, data=()) -> None:
    """Refuse, before any work, a calibrated model's path that is the model
    file, one of the ``data`` files, a folder, or an existing file bgc did
    not write (or that changed since): what :meth:`CalibrationReport.write`
    would refuse.

    Raises
    ------
    OutputError
        The path cannot take the calibrated model.
    """
    from .output import artifacts

    out = Path(path)
    where = printable(str(out))
    for other, what in [(model, "the model file")] + [(d, "a data file") for d in data]:
        try:
            same = out.exists() and Path(other).exists() and out.samefile(other)
        except (OSError, TypeError):
            same = False
        if same:
            raise OutputError(f"{where} is {what}: a calibration never replaces it", None,
                              "write the calibrated model to a new file, e.g. -o calibrated.yaml")
    artifacts.check_writable(out, "the calibrated model")


def _model_text(path: str, c: pipeline.Compiled) -> str:
    """The model file's text, as it was compiled (its hash checked)."""
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{printable(path)}: cannot read the model file again ({exc})", None,
                               "check the path") from None
    if hashlib.sha256(text.encode("utf-8")).hexdigest() != c.raw.sha256:
        raise CalibrationError(f"{printable(path)} changed since it was compiled", None,
                               "open the model again (bgc.open) and calibrate")
    return text


def _check_calibrated(text: str, result: calibration.Calibration, c: pipeline.Compiled) -> None:
    """The calibrated text reads back, by bgc's own reader and validator,
    with every estimate as written (else a bug: InternalError)."""
    from .compiler import load, validate
    from .errors import BgcError, InternalError
    from .output.calibrated import number

    try:
        model = validate.validate(load.loads(text, c.model.source))
    except BgcError as exc:
        raise InternalError(f"the calibrated model does not read back: {exc.line()}") from None
    params = {p.name: p.value for p in model.parameters}
    sensors = {m.name: m.noise for m in model.measurements}
    for e in result.estimates:
        if not e.identifiable or e.kind == "initial":  # a recording's start: reported, not written
            continue
        got = {"measurement_noise": lambda: sensors[e.subject], "process_noise": lambda: model.settings.process_noise,
               "parameter": lambda: params[e.subject]}[e.kind]()
        want = float(number(e.level if e.kind != "parameter" else e.value))
        if got != want:
            raise InternalError(f"the calibrated model reads {e.name} as {got!r}, not {want!r}")


def open(model: str | Path, *, process_noise: float | None = None, measurement_noise: float | None = None,
         generated: str | Path | None = None, prior_scale: float = 1.0, backend: str | None = None) -> Session:
    """Compile ``model`` and load its generated package: a :class:`Session`
    whose :meth:`Session.diagnoser` diagnoses a stream one sample at a time,
    and which :func:`diagnose` and :func:`distinguishability` take in place of
    the model file (compiled once for many runs; nothing is cached between
    sessions). ``process_noise``,
    ``measurement_noise``: the relative noise levels the filters assume
    (default: the model's); ``generated``: the folder ``bgc compile -o``
    wrote (default: a private one); ``prior_scale``: widens every fault's
    prior of its magnitude by that factor (``--prior-scale``); ``backend``:
    'numpy', 'numba' (the compiled package, the ``fast`` extra) or None /
    'auto' (numba when installed; the environment's ``BGC_BACKEND`` first)."""
    return Session(model, process_noise, measurement_noise, generated, prior_scale, backend)


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
    func = "bgc.api.diagnosis_memory"
    arguments.integer(func, "steps", steps, 1, "give at least 1", "steps=300")
    if not isinstance(num, Numerics):
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
    arguments.text("bgc.api.check_diagnosis_steps", "where", where)
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


def check_options(options: DiagnosisOptions, func: str = "bgc.diagnose") -> None:
    """Refuse options a diagnosis cannot take, as :func:`diagnose` does its
    arguments (``func`` names the function in the message).

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        A field of the wrong type or out of range.
    """
    if not isinstance(options, DiagnosisOptions):
        raise ArgumentTypeError(f"{func}: options={arguments.shown(options)} is not a DiagnosisOptions", None,
                                "give bgc.diagnosis.diagnose.DiagnosisOptions(...) or None")
    o = "options."
    arguments.choice(func, o + "method", options.method, METHODS)
    arguments.integer(func, o + "particles", options.particles, None, "", "particles=1000")
    if options.particles < 1:  # bgc diagnose hands --particles over in the options: the runtime's words
        raise ArgumentValueError(f"--particles {options.particles}: at least 1 particle is needed", None,
                                 "e.g. --particles 200, or DiagnosisOptions(particles=200)")
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
    for name in ("history", "search", "symbol_steps", "workers"):
        arguments.integer(func, o + name, getattr(options, name), 1, "give at least 1", f"{name}=1")
    arguments.integer(func, o + "near", options.near, 0, "is negative", "near=4")
    if options.spacing is not None:
        arguments.integer(func, o + "spacing", options.spacing, 1, "give at least 1", "spacing=4")
    arguments.choice(func, o + "identify", options.identify, IDENTIFY)
    for name in ("horizon", "gap"):
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


#: The compile cache, the private folders and the package imports are shared
#: by the threads of a process (a Dask worker runs several tasks at once).
_LOCK = threading.RLock()


def private_folder(prefix: str) -> str:
    """A new temporary folder of this process, removed when it exits: at
    interpreter exit, or at the end of a multiprocessing worker (which skips
    atexit handlers).

    Raises
    ------
    ArgumentTypeError
        ``prefix`` is not a string.
    """
    import secrets
    from multiprocessing import util

    arguments.text("bgc.api.private_folder", "prefix", prefix)

    base = tempfile.gettempdir()
    with _FOLDER_LOCK:  # an orphaned campaign worker removes its folders under it (remove_private_folders)
        for _ in range(100):
            folder = os.path.join(base, prefix + secrets.token_hex(6))
            # named before it is made: a worker ended between the two (SIGTERM when its campaign dies)
            # removes it all the same
            _FOLDERS.append((os.getpid(), folder))
            try:
                os.mkdir(folder, 0o700)  # as tempfile.mkdtemp: a new folder, this user's only
            except FileExistsError:
                _FOLDERS.pop()
                continue
            break
        else:
            raise FileExistsError(f"no free name for a private folder in {base}")
        atexit.register(shutil.rmtree, folder, True)
        util.Finalize(None, shutil.rmtree, args=(folder, True), exitpriority=0)
    return folder


#: The private folders of this process and of the process it was forked from: (pid, path).
_FOLDERS: list[tuple[int, str]] = []
_FOLDER_LOCK = threading.RLock()


def _new_folder_lock() -> None:  # a forked child starts with its own lock, free, whoever held its parent's
    global _FOLDER_LOCK
    _FOLDER_LOCK = threading.RLock()


os.register_at_fork(after_in_child=_new_folder_lock)


def remove_private_folders() -> None:
    """Remove this process's private folders now (a campaign worker whose
    campaign has died, ending at once: :func:`bgc.experiment.campaign._orphaned`).
    Under the lock :func:`private_folder` takes, so no folder is being made
    meanwhile; a folder named but not yet made is simply absent."""
    with _FOLDER_LOCK:
        for pid, folder in _FOLDERS:
            if pid == os.getpid():
                shutil.rmtree(folder, True)


def _compiled(model: str | Path, prior_scale: float = 1.0) -> tuple[pipeline.Compiled, str]:
    """Compile ``model`` (its priors widened by ``prior_scale``) and write
    its generated package into a new private folder of this process: (the
    compiled model, the folder). Nothing is kept between calls: a
    :class:`Session` holds what one model needs."""
    c = pipeline.compile_model(model, prior_scale)
    folder = private_folder("bgc-")
    root = Path(folder) / c.model.name / PACKAGE
    root.mkdir(parents=True)
    for rel, text in c.package.files:
        (root / rel).write_text(text, encoding="utf-8")
    return c, folder


def cache_root() -> Path:
    """bgc's own cache folder: ``BGC_CACHE_DIR``, else ``$XDG_CACHE_HOME/bgc``, else ``~/.cache/bgc``."""
    if os.environ.get("BGC_CACHE_DIR"):
        return Path(os.environ["BGC_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bgc"


def _lasting_folder(c: pipeline.Compiled) -> str:
    """A folder that holds ``c``'s compiled (numba) package and lasts from
    run to run, so numba's disk cache beside it stays valid: under
    :func:`cache_root`, named by the package's digest (the same model text
    always meets the same folder, another one never; the path of the model
    file, in the package's comments only, is left out). Written once, whole,
    by renaming a finished private folder into place (processes racing to
    write it: one wins, the others' copies are dropped)."""
    # the package's text but the model file's path (in its comments): the same model text met at another
    # path (a campaign worker's private copy) finds the same folder and its compiled kernels
    source = escape(c.model.display_source)
    digest = hashlib.sha256(repr([(rel, text.replace(source, "")) for rel, text in c.package.numba_files]).encode()
                            ).hexdigest()[:20]
    root = cache_root() / "packages" / f"{c.model.name}-{digest}"
    if (root / c.model.name / NUMBA_PACKAGE / "__init__.py").exists():
        return str(root)
    root.parent.mkdir(parents=True, exist_ok=True)
    fresh = Path(tempfile.mkdtemp(prefix=f".{root.name}-", dir=root.parent))
    package = fresh / c.model.name / NUMBA_PACKAGE
    package.mkdir(parents=True)
    for rel, text in c.package.numba_files:
        (package / rel).write_text(text, encoding="utf-8")
    try:
        os.rename(fresh, root)
    except OSError:  # another process put it there first
        shutil.rmtree(fresh, ignore_errors=True)
    return str(root)


def _run(c, run, package, scenario, injected, noise, levels, opts, say) -> DiagnosisReport:
    track.check_request(run, package, "nominal", opts.particles, None, columns=False)
    opts = with_horizon(opts, c.model.settings)
    priors = {f.parameter: f.prior for f in c.model.faults}
    result = run_diagnosis(run, package, c.signatures, priors, opts, say)
    return DiagnosisReport(c.model.name, c.model.display_source, run, scenario, injected, noise, levels, opts,
                           result, labels_of(c.model))


def most_steps(num: Numerics, options: DiagnosisOptions) -> int:
    """The most steps a diagnosis of ``options`` may hold by the rule of
    :func:`check_diagnosis_steps` (a stream is stopped there)."""
    fixed, per_step = diagnosis_memory(1, num, options.particles, options.method, options.history)
    return max(int((MAX_DIAGNOSIS_BYTES - fixed) // max(per_step, 1)), 1)


def with_horizon(options: DiagnosisOptions, settings) -> DiagnosisOptions:
    """``options`` with the detector's horizon filled in when None: the
    model's declared run length (``simulation.steps`` x ``dt``)."""
    if options.horizon is not None:
        return options
    return dataclasses.replace(options, horizon=settings.steps * settings.dt)


@dataclass(frozen=True, slots=True)
class DistinguishabilityReport:
    """What the data of a model's scenarios are predicted to tell apart
    (:mod:`bgc.analysis.distinguish`): one :class:`Distinction` per scenario,
    over ``steps`` samples at the relative noise levels ``noise`` (None: the
    model's); ``scenario`` when one was asked for, else every fault
    candidate, kind and direction at a relative ``change`` of its parameter
    (a drift reaches it at the end of the run) from the fraction ``at`` of
    the run."""

    model: str
    source: str
    steps: int
    dt: float
    noise: tuple[float | None, float | None]
    scenario: str | None
    change: float | None
    at: float | None
    distinctions: tuple[distinction.Distinction, ...]
    #: Why the model's diagnoser would not expect the scenario's fault (outside its prior), or None.
    warning: str | None = None


def distinguishability(model: str | Path | Session, scenario: str | None = None, *, change: float = 0.3,
                       at: float = 0.5,
                       process_noise: float | None = None, measurement_noise: float | None = None,
                       steps: int | None = None, level: float = distinction.LEVEL,
                       progress=None) -> DistinguishabilityReport:
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
    arguments.text(func, "scenario", scenario, optional=True)
    arguments.real(func, "change", change, 0.0, math.inf, "a relative change above 0, e.g. change=0.3")
    arguments.real(func, "at", at, 0.0, 1.0, "a fraction of the run between 0 and 1, e.g. at=0.5")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if steps is not None:
        arguments.integer(func, "steps", steps, 1, "simulate at least 1 step", "steps=300")
    arguments.real(func, "level", level, 0.0, 1.0, "a probability between 0 and 1, e.g. level=0.95")
    arguments.callable_or_none(func, "progress", progress)
    say = progress or (lambda text: None)
    if isinstance(model, Session):
        c, private = model.compiled, model.folder
    else:
        say("compiling the model")
        c, private = _compiled(model)
    num = c.numerics
    if steps is not None:
        simulate.check_steps(steps, num, "--steps")
    T = steps or c.model.settings.steps
    dt = c.model.settings.dt
    where = "--steps" if steps is not None else f"{printable(c.model.source)}: simulation.steps"
    distinction.check_steps(T, num, where)
    if scenario is None and not int(at * T) < T - 1:
        raise SimulationError(f"change {change:g} at {at:g} of the run", None,
                              "give a change above 0 and an onset inside the run, a fraction between 0 and 1")
    if not num.faults:
        raise SimulationError(f"{c.model.name} declares no fault candidates", None,
                              "list the faults to tell apart under 'faults' in the model file")
    times = dt * np.arange(1, T + 1)
    if scenario is not None:
        if scenario.strip().lower() == "none":
            raise SimulationError("a fault-free scenario has no fault to tell apart", None,
                                  "give a fault, e.g. R_pipe:incipient:0.5@165, or no scenario for every candidate")
        inj = simulate.parse_fault(scenario, num)
        if all(f.name != f"{inj.parameter}:{inj.kind}" for f in num.faults):
            raise SimulationError(f"{inj.subject or inj.parameter}:{inj.kind} is not a fault candidate of "
                                  f"{c.model.name}: no fault model to tell apart from the others (its diagnosis "
                                  "should end unexplained)", None,
                                  "candidates: " + ", ".join(f"{f.parameter}:{f.kind}" for f in num.faults))
        if not 0 < inj.time <= times[-1]:
            raise SimulationError(f"onset {inj.time:g} is outside the run (0 to {times[-1]:g})", None,
                                  "choose an onset inside the run, or more --steps")
        injected = [inj]
    else:
        injected = []
        for f in num.faults:
            onset = int(at * T)
            candidate = next(x for x in c.model.faults if x.parameter == f.parameter)
            for sign in (1,) if fault_kind(f.kind).replaces else DIRECTIONS[candidate.direction]:
                magnitude = simulate.change_magnitude(num, f.name, sign * change, (T - 1 - onset) * dt)  # at the end
                injected.append(simulate.FaultInjection(f.parameter, f.kind, magnitude, float(times[onset])))
    levels = num.noise_at(process_noise, measurement_noise)
    custom = levels if (process_noise, measurement_noise) != (None, None) else None
    need = distinction.memory(T, *(len(x) for x in (num.equations.states, num.equations.outputs,
                                                     num.equations.inputs, num.faults)))
    with _LOCK:
        package = packages.load_package(private, c.model.name, str(model), custom)
        families = _families(package, T, need, say)
    priors = {f.parameter: f.prior for f in c.model.faults}
    out = []
    for i, inj in enumerate(injected, start=1):
        say(f"scenario {i} of {len(injected)}: {inj.parameter}:{inj.kind}:{inj.magnitude:.4g}@{inj.time:g}")
        onset = metrics.sample_at(times, inj.time)
        out.append(distinction.distinguish(families, f"{inj.parameter}_{inj.kind}", inj.magnitude, onset, priors,
                                           level))
    warning = simulate.outside_prior(injected[0], num) if scenario is not None else None
    return DistinguishabilityReport(c.model.name, c.model.display_source, T, dt, (process_noise, measurement_noise),
                                    scenario, None if scenario else change, None if scenario else at, tuple(out),
                                    warning)


#: Prepared families by package (its module name tells the noise levels) and
#: run length; the latest few are kept (a campaign worker meets a few models),
#: as many as fit, with the next one, in ``distinguish.MAX_BYTES``.
_FAMILIES: dict[tuple[str, str, int], distinction.Families] = {}
_FAMILIES_KEPT = 4


def _families(package, steps: int, need: int = 0, progress=None) -> distinction.Families:
    """The families of ``package`` over ``steps`` samples, prepared once;
    ``need``: the bytes a new preparation is expected to take (older
    families are let go until it fits)."""
    key = (package.__name__, str(getattr(package, "__file__", "")), steps)
    if key not in _FAMILIES:
        while _FAMILIES and (len(_FAMILIES) >= _FAMILIES_KEPT
                             or sum(map(_nbytes, _FAMILIES.values())) + need > distinction.MAX_BYTES):
            _FAMILIES.pop(next(iter(_FAMILIES)))
        _FAMILIES[key] = distinction.prepare(package, distinction.scenario_inputs(package, steps), progress)
    return _FAMILIES[key]


def _nbytes(families: distinction.Families) -> int:
    """The bytes of a family's arrays."""
    w = families.whitening
    arrays = (families.us, families.x_before, families.x_after, families.y, w.F, w.H, w.K, w.Linv,
              *families.responses)
    return sum(a.nbytes for a in arrays)
