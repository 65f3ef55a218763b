""":func:`open` and :class:`Session`: a compiled model and its generated package, ready to diagnose."""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple


from .. import arguments
from ..ir import NUMBA_PACKAGE
from ..errors import (
    ArgumentTypeError, ArgumentValueError, BgcError, SimulationError, TrackingError, printable,
)
from ..analysis import calibrate as calibration
from ..data import runs
from ..data.columns import ColumnMap, Reading, read_map, unit_seconds
from ..model import package as packages
from ..analysis import track
from ..model import warmup
from ..diagnosis.diagnose import Diagnosis
from ..diagnosis.options import DiagnosisOptions
from ..diagnosis.diagnose import horizon_steps
from ..diagnosis.diagnoser import Diagnoser, mode_hidden
from .limits import (METHODS, MAX_PRIOR_SCALE, check_options,
                     most_steps, with_horizon)
from . import cache
from .folders import _LOCK
from .reports import CalibrationReport, DiagnosisReport
from .calibrate import _check_calibrated, _model_text
from ..model.protocol import nominal_model


def _session_of(func: str, model, process_noise, measurement_noise, generated, say,
                prior_scale: float | None = None, backend: str | None = None,
                work: tuple[int, int | None] | None = None) -> Session:
    """``model`` when it is a :class:`Session` (whose noise levels, prior
    scale and package apply: other ones are refused), else a new session of
    the file (``work``: the run's (particles, steps), for ``auto``)."""
    if not isinstance(model, Session):
        say("compiling the model")
        session = Session(model, process_noise, measurement_noise, generated,
                          1.0 if prior_scale is None else prior_scale, backend, work=work)
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
    model's). A session reads its model through the compile cache
    (:mod:`bgc.api.cache`): ``view``, the compiled model as plain data, and
    the generated package; ``compiled``, every IR, is compiled on first use
    when the cache served the session. Diagnose many runs of one model
    through one session (``bgc.diagnose(session, data=...)``,
    :meth:`diagnoser`).

    >>> import bgc
    >>> session = bgc.open("models/circuit.yaml")
    >>> d = session.diagnoser(particles=200)
    >>> belief = d.step(0.05, y={"e11": 2.45, "f2": 2.49, "f6": 2.47})  # no u: the model's input
    >>> belief.phase, belief.alarm, belief.events
    ('watching', None, (InputFromModel(input='V', reason='absent', step=None),))
    """

    def __init__(self, model: str | Path, process_noise: float | None = None,
                 measurement_noise: float | None = None, generated: str | Path | None = None,
                 prior_scale: float = 1.0, backend: str | None = None, *,
                 work: tuple[int, int | None] | None = None):
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
        if work is not None:
            _check_work(func, work)
        if packages.chosen_by_name(backend):  # refused (numba not installed) before any work
            self.backend = packages.resolve_backend(backend)
        self._opened = cache.open_model(model, self.prior_scale)
        #: the compiled model as plain data (:mod:`bgc.view`): what the runtime reads
        self.view = self._opened.view
        #: the folder of the generated NumPy package (``<model>/numpy_model``): the cache's entry, or a private one
        self.folder = self._opened.folder
        self._compiled = self._opened.compiled
        c = self.view
        numba = Path(generated) / c.model.name / NUMBA_PACKAGE if generated is not None else \
            cache.numba_path(self._opened)
        #: why this backend: asked for by name, BGC_BACKEND, or auto's rule (:func:`bgc.model.package.auto_backend`)
        self.backend, self.backend_reason = choose_backend(
            backend, numba, None if work is None else int(work[0]) * int(work[1] or c.model.settings.steps))
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
                                    "use " + arguments.spelled("backend='numpy'", "--backend numpy")) from None
            self.backend, self.fallback = "numpy", why
            self._load(generated, str(model), custom)
        self.priors = c.priors

    @property
    def compiled(self):
        """Every IR of the model (:class:`bgc.pipeline.Compiled`): compiled
        now when the cache served the session (sympy is imported then).

        Raises
        ------
        ArgumentValueError
            The model file changed since the session was opened.
        """
        with _LOCK:
            if self._compiled is None:
                self._compiled = cache.compiled_again(self.model, self.prior_scale, self.view)
            return self._compiled

    def _load(self, generated, model: str, custom) -> None:
        """Load this session's package of its backend (from ``generated``, or
        for NumPy the compile cache's entry (a private folder when the cache
        could not be used), or, for the compiled package, a folder of bgc's
        cache that lasts, so numba's disk cache stays valid) and warm it up."""
        c = self.view
        if generated is None:
            generated = self.folder if self.backend == "numpy" else cache.numba_folder(self._opened)
        with _LOCK:  # another thread must not see a package half imported
            self.package = packages.load_package(generated, c.model.name, model, custom, self.backend)
            #: (seconds, kernels compiled, kernels loaded from numba's disk cache) of this session's warm-up
            self.warm = warmup.warm_up(self.package)
        if self.backend == "numba":  # auto finds them there next time (cache.kernels_cached)
            cache.mark_warm(Path(generated) / c.model.name / NUMBA_PACKAGE, self.warm[1] + self.warm[2])

    @property
    def name(self) -> str:
        return self.view.model.name

    def model_note(self) -> str:
        """One line on where the compiled model came from: bgc's compile
        cache, or compiled (and kept there, or not), and how long it took."""
        o = self._opened
        if o.compiled is None:
            return f"model {self.name}: read from bgc's compile cache in {o.seconds:.2f} s ({printable(str(o.entry))})"
        kept = f"kept in bgc's compile cache: {printable(str(o.entry))}" if o.entry is not None else \
            "bgc's compile cache not used"
        return f"model {self.name}: compiled in {o.seconds:.1f} s ({kept})"

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
        return f"<bgc.Session of {self.name} ({printable(self.view.model.display_source)})>"

    def _repr_html_(self) -> str:
        """A notebook's view: the model's name and file, elements, bonds and
        states, sensors, inputs, parameters and fault candidates
        (:func:`bgc.output.summary.model_html`)."""
        from ..output import summary

        return summary.model_html(self)

    def reading(self, columns=None, func: str = "bgc.Session.reading") -> Reading:
        """What a reader of this model's run files is told
        (:class:`~bgc.data.columns.Reading`): the column map ``columns`` (a
        map file's path, a :class:`~bgc.data.columns.ColumnMap`, or None:
        none), the columns the model reads, and its time unit (ISO
        timestamps are converted to it)."""
        return reading_of(self.view, columns, func)

    def read_run(self, data, columns=None, func: str = "bgc.Session.read_run") -> runs.Run:
        """A recorded run of this model: ``data`` a run file (read through the
        column map ``columns``, :meth:`reading`) or a
        :class:`~bgc.data.runs.Run` (checked), refused when its header names
        another model."""
        if isinstance(data, runs.Run):
            if columns is not None:
                raise ArgumentValueError(f"{func}: columns= with a Run: a column map is for a file", None,
                                         "name the Run's columns as bgc does (u:NAME, y:NAME), or give the file")
            run = runs.check_run(data)
        else:
            run = runs.read_run(data, self.reading(columns, func))
        track.check_run_of(run, self.view.model.name)
        return run

    def options(self, options: DiagnosisOptions | None = None, *, filter: str = "gpf", particles: int = 1000,
                seed: int = 0, func: str = "bgc.Session.diagnoser") -> DiagnosisOptions:
        """``options`` (checked; default: built from ``filter``, ``particles``
        and ``seed``) with the detector's horizon filled in (the model's run
        length when None)."""
        if options is None:
            arguments.choice(func, "filter", filter, METHODS)
            arguments.integer(func, "particles", particles, 1, "at least 1 particle is needed", "particles=1000")
            arguments.integer(func, "seed", seed, 0, "is negative", "seed=0")
            options = DiagnosisOptions(filter=filter, particles=particles, seed=seed)
        check_options(options, func)
        return with_horizon(options, self.view.model.settings)

    def diagnoser(self, options: DiagnosisOptions | None = None, *, filter: str | None = None, particles: int = 1000,
                  seed: int = 0, inputs=None, sensors=None, source: str = "<stream>", progress=None,
                  method: str | None = None) -> Diagnoser:
        """An online :class:`~bgc.diagnosis.diagnoser.Diagnoser` of this model:
        ``step(t, u, y)`` per sample, ``finish()`` at the end. ``inputs``,
        ``sensors``: the input and sensor names the data have (default: all
        of the model's sensors, and the inputs the first ``step`` gives);
        ``source``: the data's name in messages; ``filter``: as
        :func:`bgc.diagnose`'s (``method``: its old name, deprecated)."""
        func = "bgc.Session.diagnoser"
        filter = arguments.renamed(func, "filter", filter, "method", method, "gpf")
        opts = self.options(options, filter=filter, particles=particles, seed=seed, func=func)
        arguments.text(func, "source", source)
        arguments.callable_or_none(func, "progress", progress)
        nominal = nominal_model(self.package)
        return Diagnoser(self.package, isolation_signatures(self.view), self.priors, opts,
                         horizon_steps(opts.horizon, nominal.DT, 0), time_unit=self.view.model.settings.time_unit,
                         inputs=inputs, sensors=sensors, source=source, progress=progress,
                         most=most_steps(self.view.numerics, opts))

    def calibrate(self, data, estimate: str | tuple[str, ...] = "noise", *, progress=None,
                  columns=None, input_timing: str | None = None) -> CalibrationReport:
        """Maximum-likelihood estimates, from healthy recordings ``data`` (a
        run file, a :class:`~bgc.data.runs.Run`, or a list or tuple of
        them), of what ``estimate`` names: ``noise`` (every sensor's
        measurement noise and the process-noise level, the default),
        ``measurement_noise``, ``process_noise`` and parameters of the model
        file, as a comma-separated text or a tuple of names
        (:mod:`bgc.analysis.calibrate`). The :class:`CalibrationReport` holds
        the estimates with their 95 % intervals and the calibrated model's
        text; :meth:`CalibrationReport.write` writes it. ``input_timing``:
        what a row's input value is, ``end`` or ``start`` (None: as each
        file's header says, else ``end``; docs/format.md section 9).

        Raises
        ------
        ArgumentTypeError, ArgumentValueError
            ``data`` or ``estimate`` of the wrong type, no data, or a session
            opened with other noise levels than the model file's.
        CalibrationError
            An unknown name to estimate; a likelihood that is not finite at
            the model's values.
        DataError
            A run that cannot be read or is not of this model; a column map
            (``columns``, :meth:`reading`) that cannot be read or does not
            fit the files.
        """
        from ..output import calibrated  # yaml's writer: not needed to diagnose

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
        if input_timing is not None:
            arguments.choice(func, "input_timing", input_timing, runs.TIMINGS)
        say = progress or (lambda text: None)
        c = self.view
        nominal = nominal_model(self.package)
        sensors, process, parameters = calibration.targets(estimate, nominal, [p.name for p in c.model.parameters],
                                                           arguments.spelled(f"{func}: estimate", "--estimate"))
        records, dates, hidden = [], [], False
        for item in items:
            run = self.read_run(item, columns, func)
            hidden = mode_hidden(nominal, runs.input_columns(run), run.source) or hidden
            timing = runs.resolve_timing(run.header, input_timing, run.source,
                                         arguments.spelled("input_timing", "--input-timing"))
            records.append(calibration.record_of(run, nominal, timing))
            dates += [h.split(":", 1)[1].strip() for h in run.header
                      if h.lower().startswith(("date:", "recorded:")) and h.split(":", 1)[1].strip()]
        say(f"calibrating on {len(records)} recording(s)")
        how = (nominal, c.numerics, records, sensors, process, parameters, calibration.wants_initial(estimate),
               tuple(m.numerics for m in c.modes))
        if hidden:  # a mode the data do not give: read from the measurements, in rounds with the calibration
            from .calibrate import read_modes

            result, read = calibration.calibrate_hidden(read_modes, *how, say=say)
        else:
            result, read = calibration.calibrate(*how), ()
        original = _model_text(self.model, c)
        own = {el.name: el.noise for el in c.model.elements if el.noise is not None}
        text = calibrated.calibrated_text(original, c.model.display_source, result, own, tuple(dates))
        _check_calibrated(text, result, c)
        units = {x.name: x.unit for x in (*c.model.parameters, *c.model.measurements, *c.model.inputs)}
        return CalibrationReport(self.model, self.name, tuple(sensors), process, tuple(parameters), result, text,
                                 units, read)

    # ------------------------------------------------------------ what a paper shows of the model
    def equations(self, format: str = "text"):
        """The state and measurement equations (``bgc show equations``):
        ``text`` (the default: one line each), ``latex`` (an ``aligned`` block that
        typesets with amsmath) or ``sympy``: an :class:`Equations` of sympy
        expressions by name (``derivatives[x]`` is dx/dt, ``outputs[y]``
        the measurement), with the parameters' and initial states' values."""
        arguments.choice("bgc.Session.equations", "format", format, ("text", "latex", "sympy"))
        from ..output import render

        ssm = self.compiled.equations
        if format == "text":
            return render.equations_text(ssm)
        if format == "latex":
            return render.equations_latex(ssm)
        return Equations(dict(zip(ssm.states, ssm.rhs)), dict(zip(ssm.outputs, ssm.output_exprs)),
                         dict(zip(ssm.parameters, ssm.parameter_values)), dict(zip(ssm.states, ssm.initial)),
                         tuple(ssm.inputs))

    def tcg(self, simplified: bool = False):
        """The temporal causal graph as a networkx DiGraph (a copy: yours to
        change): nodes are bond efforts and flows (``e4``, ``f4``) with
        their attributes, edges carry ``label`` (``+1``, ``-1``, ``1/C1``,
        ``dt``, ...); ``simplified``: over states, inputs and measurements
        only, its edges the dependencies (no labels)."""
        import networkx as nx

        t = self.compiled.tcg
        return nx.DiGraph(t.simplified if simplified else t.graph)

    def dbn(self, name: str = "nominal"):
        """The two-slice DBN ``name`` (``nominal``, or a fault model such as
        ``R12:abrupt``: :meth:`dbns` lists them; also by the name a diagnosis
        gives it, ``R12_abrupt``, or a sensor's as the model names it,
        ``F12:bias``) as a networkx DiGraph (a
        copy): nodes ``var@t`` and ``var@t+1`` with ``role`` and ``slice``,
        arcs with ``arc`` (persistence, temporal, intra, fault, drift, indicator)."""
        import networkx as nx

        arguments.text("bgc.Session.dbn", "name", name)
        dbns = self.compiled.dbn
        by_hypothesis = {f"{d.parameter}_{d.kind}": d.name for d in dbns.faulty}  # a report's name: R12_abrupt
        try:
            return nx.DiGraph(dbns.get(by_hypothesis.get(name, name)).graph)
        except KeyError as e:
            raise ArgumentValueError(f"bgc.Session.dbn: name={name!r}: {e.args[0]}", None,
                                     "give one of Session.dbns()") from None

    def dbns(self) -> tuple[str, ...]:
        """The DBNs' names: ``nominal``, then one per fault model (``PARAM:KIND``)."""
        d = self.compiled.dbn
        return tuple(x.name for x in (d.nominal, *d.faulty))

    def signatures(self):
        """The TRANSCEND fault signatures as a :class:`~bgc.api.tables.Table`:
        one row per fault and direction (``fault`` such as ``R12+:abrupt``,
        ``parameter``, ``direction`` +1 or -1, ``kind``), a column per
        measurement with its symbols (``+ - 0 ?``: the deviation's
        magnitude, then its derivatives of increasing order, the slope first)
        and ``first``, the measurements expected to deviate first (a list)."""
        from .tables import Table

        s = self.compiled.signatures
        rows = [{"fault": x.name, "parameter": x.parameter, "direction": x.direction, "kind": x.kind,
                 **{m: "".join(sym) for m, sym in zip(s.measurements, x.symbols)}, "first": list(x.first)}
                for x in s.signatures]
        return Table.of(rows, ("fault", "parameter", "direction", "kind", *s.measurements, "first"))

    def report(self, run: runs.Run, diagnosis: Diagnosis, scenario: str | None = None,
               injected=None) -> DiagnosisReport:
        """A :class:`DiagnosisReport` of ``diagnosis`` made on ``run``."""
        return DiagnosisReport(self.name, self.view.model.display_source, run, scenario, injected, self.noise,
                               self.levels, diagnosis.options, diagnosis, self.view.labels)


def isolation_signatures(view):
    """The signatures a diagnosis matches its symbols against: the model's,
    or, for a model with modes, each mode's (:class:`~bgc.diagnosis.isolate.ModeSignatures`)."""
    if not view.modes:
        return view.signatures
    from ..diagnosis.isolate import ModeSignatures

    return ModeSignatures(tuple(m.signatures for m in view.modes), tuple(m.name for m in view.modes))


def reading_of(view, columns=None, func: str = "bgc.Session.reading") -> Reading:
    """:meth:`Session.reading` of a compiled model's view (:mod:`bgc.view`)."""
    if columns is not None and not isinstance(columns, (str, os.PathLike, ColumnMap)):
        raise ArgumentTypeError(f"{func}: columns={arguments.shown(columns)} is not a path or a ColumnMap", None,
                                "give a column map file's path, e.g. columns='logger.yaml'")
    mapping = read_map(columns) if isinstance(columns, (str, os.PathLike)) else columns
    m = view.model
    expected = tuple([f"u:{u.name}" for u in m.inputs] + [f"y:{y.name}" for y in m.measurements])
    unit = m.settings.time_unit
    modes = tuple(mode.name for mode in view.modes) if view.modes else ()
    return Reading(mapping, expected, unit_seconds(unit), unit, modes, m.name)


def choose_backend(backend: str | None, numba: Path, work: int | None) -> tuple[str, str]:
    """The backend to run on and why: ``backend`` when it names one (or
    ``BGC_BACKEND`` does: :func:`bgc.model.package.resolve_backend`), else
    ``auto``'s rule (:func:`bgc.model.package.auto_backend`) for ``work``
    particle-steps, the kernels of the compiled package folder ``numba``
    (``.../<model>/numba_model``) in numba's disk cache or not
    (:func:`bgc.api.cache.kernels_cached`).

    Raises
    ------
    TrackingError
        An unknown backend, or numba asked for and not installed.
    """
    if packages.chosen_by_name(backend):
        return packages.resolve_backend(backend), ("asked for" if backend not in (None, "auto") else "BGC_BACKEND")
    return packages.auto_backend(work, packages.numba_installed() and cache.kernels_cached(numba))


def _check_work(func: str, work) -> None:
    """Refuse a ``work`` that is not (particles, steps or None), each an integer >= 1."""
    if not isinstance(work, tuple) or len(work) != 2:
        raise ArgumentTypeError(f"{func}: work={arguments.shown(work)} is not a (particles, steps) tuple", None,
                                "e.g. work=(1000, 300), or work=(1000, None) for the model's run length")
    arguments.integer(func, "work[0]", work[0], 1, "at least 1 particle is needed", "work=(1000, 300)")
    if work[1] is not None:
        arguments.integer(func, "work[1]", work[1], 1, "give at least 1 step", "work=(1000, 300)")


def open(model: str | Path, *, process_noise: float | None = None, measurement_noise: float | None = None,
         generated: str | Path | None = None, prior_scale: float = 1.0, backend: str | None = None,
         work: tuple[int, int | None] | None = None) -> Session:
    """Compile ``model`` and load its generated package: a :class:`Session`
    whose :meth:`Session.diagnoser` diagnoses a stream one sample at a time,
    and which :func:`diagnose` and :func:`distinguishability` take in place of
    the model file (compiled once for many runs, and kept in bgc's compile
    cache for the next session: :mod:`bgc.api.cache`). ``process_noise``,
    ``measurement_noise``: the relative noise levels the filters assume
    (default: the model's); ``generated``: the folder ``bgc compile -o``
    wrote (default: a private one); ``prior_scale``: widens every fault's
    prior of its magnitude by that factor (``--prior-scale``); ``backend``:
    'numpy', 'numba' (the compiled package, the ``fast`` extra) or None /
    'auto' (the environment's ``BGC_BACKEND`` first, else
    :func:`bgc.model.package.auto_backend`: numba when installed and its
    kernels for this model are in numba's disk cache and ``work`` repays
    loading them, or ``work`` repays compiling them); ``work``: the
    (particles, steps) a diagnosis of the session is expected to run (steps
    None: the model's run length; None: not known, numba only when its
    kernels are cached)."""
    return Session(model, process_noise, measurement_noise, generated, prior_scale, backend, work=work)


def input_signals(func: str, inputs: Mapping[str, Any] | None, model) -> tuple:
    """The ``inputs`` argument as (name, :class:`~bgc.ir.Signal`) pairs, in
    the model's order of inputs, or an argument error naming ``func``."""
    if inputs is None:
        return ()
    if not isinstance(inputs, Mapping):
        raise ArgumentTypeError(f"{func}: inputs={inputs!r} is not a mapping", None,
                                "give e.g. inputs={'u': {'signal': 'sine', 'value': 1, 'amplitude': 0.5, 'period': 4}}")
    from ..compiler.validate import signal_given  # not at import: a cache hit needs no compiler

    names = tuple(u.name for u in model.inputs)
    try:
        given = {name: signal_given(name, spec, names, f"{func}: inputs") for name, spec in inputs.items()}
    except BgcError as e:
        raise ArgumentValueError(e.what, None, e.fix) from None
    return tuple((name, given[name]) for name in names if name in given)


def scenario_of(func: str, scenario, num, modules: tuple[str, ...] | None = None):
    """``scenario`` (text or a :class:`~bgc.analysis.simulate.FaultInjection`)
    read once at the API's edge (:func:`bgc.analysis.simulate.parse_scenario`):
    a malformed one is an :class:`~bgc.errors.ArgumentValueError` naming
    ``func``'s argument (from the command line: the option, as typed). A
    fault outside the model's candidates or its prior is a
    :class:`ScenarioWarning` (Python's :mod:`warnings`)."""
    from ..analysis import simulate

    try:
        injected = simulate.parse_scenario(scenario, num, arguments.spelled(f"{func}: scenario", "--scenario"))
    except SimulationError as e:
        if arguments.DOOR.get() == "cli":
            raise
        raise ArgumentValueError(e.what, e.loc, e.fix) from None
    if injected is not None:
        why = simulate.outside_prior(injected, num, modules)
        if why is not None and arguments.DOOR.get() != "cli":  # the command line says it its own way
            warnings.warn(f"{func}: scenario {injected.text}: {why}", ScenarioWarning, stacklevel=3)
    return injected


class Equations(NamedTuple):
    """A model's equations as sympy expressions (:meth:`Session.equations`)."""

    derivatives: dict
    outputs: dict
    parameters: dict
    initial: dict
    inputs: tuple


class ScenarioWarning(UserWarning):
    """A scenario the model's diagnoser would not expect: a fault outside
    its candidates, or a magnitude outside the candidate's prior."""
