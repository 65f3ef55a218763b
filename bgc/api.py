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
:func:`bgc.runtime.diagnose.diagnose`. :mod:`bgc.output.report` turns the
result into ``report.json``, ``report.md`` and plots.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import pipeline
from .compiler.load import MAX_BYTES
from .errors import SimulationError
from .ir import NoiseLevels
from .kinds import DIRECTIONS, fault_kind
from .runtime import distinguish as distinction
from .runtime import metrics, runs, simulate, track
from .runtime.diagnose import Diagnosis, DiagnosisOptions
from .runtime.diagnose import diagnose as run_diagnosis


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


def diagnose(model: str | Path, data: str | Path | runs.Run | None = None, scenario: str | None = None, *,
             method: str = "gpf", particles: int = 1000, seed: int = 0,
             process_noise: float | None = None, measurement_noise: float | None = None,
             steps: int | None = None, generated: str | Path | None = None,
             options: DiagnosisOptions | None = None, progress=None) -> DiagnosisReport:
    """Diagnose ``data`` (a run file or a :class:`~bgc.runtime.runs.Run`) or a
    simulated ``scenario`` (``PARAM:KIND:MAGNITUDE@TIME``, or ``none`` for a
    fault-free run) of ``model``.

    ``process_noise`` and ``measurement_noise`` are relative levels (fractions
    of the signal): a scenario is simulated with them, and the filters assume
    them (default: the model's). ``seed`` seeds the simulation of a scenario
    and, unless ``options`` is given, the filters; ``options`` overrides
    ``method``, ``particles`` and the filters' seed. ``progress(text)`` is
    told what is being done.
    """
    if (data is None) == (scenario is None):
        raise SimulationError("give either data or a scenario", None,
                              "e.g. --data run.csv or --scenario R_pipe:incipient:0.5@165")
    say = progress or (lambda text: None)
    _check_measurement_noise(measurement_noise)
    say("compiling the model")
    c, private = _compiled(model)
    opts = options or DiagnosisOptions(method=method, particles=particles, seed=seed)
    injected = None
    if scenario is not None:
        if scenario.strip().lower() != "none":
            injected = simulate.parse_fault(scenario, c.numerics)
        if steps is not None:
            simulate.check_steps(steps, c.numerics, "--steps")
        say("simulating the scenario")
        result = simulate.simulate(c.numerics, simulate.SimulationOptions(
            steps=steps, process_noise=process_noise, measurement_noise=measurement_noise, seed=seed,
            fault=injected))
        run = runs.parse_run(simulate.to_csv(result), f"scenario {scenario}")
    elif isinstance(data, runs.Run):
        run = data
    else:
        run = runs.read_run(data)
        track.check_run_of(run, c.model.name, str(data))
    levels = c.numerics.noise_at(process_noise, measurement_noise)
    custom = levels if (process_noise, measurement_noise) != (None, None) else None
    with _LOCK:  # another thread must not see a package half imported
        package = track.load_package(generated if generated is not None else private, c.model.name, str(model),
                                     custom)
    return _run(c, run, package, scenario, injected, (process_noise, measurement_noise), levels, opts, say)


def _check_measurement_noise(level: float | None) -> None:
    if level is not None and not level > 0:
        raise SimulationError(f"measurement noise level {level:g}: a noiseless sensor makes the filters' likelihood "
                              "degenerate", None, "give a measurement level above 0, e.g. 0.02")


#: The compile cache, the private folders and the package imports are shared
#: by the threads of a process (a Dask worker runs several tasks at once).
_LOCK = threading.RLock()
#: Compilations of this process by the model file's path and content, each
#: with the private folder its package was written to (removed at exit): a
#: notebook or a campaign worker diagnosing one model many times compiles it
#: and imports its package once.
_COMPILED: dict[tuple[str, str], tuple[pipeline.Compiled, str]] = {}
_FOLDERS: dict[int, str] = {}  # process id -> its private folder (a forked worker makes its own)


def private_folder(prefix: str) -> str:
    """A new temporary folder of this process, removed when it exits: at
    interpreter exit, or at the end of a multiprocessing worker (which skips
    atexit handlers)."""
    from multiprocessing import util

    folder = tempfile.mkdtemp(prefix=prefix)
    atexit.register(shutil.rmtree, folder, True)
    util.Finalize(None, shutil.rmtree, args=(folder, True), exitpriority=0)
    return folder


def _compiled(model: str | Path) -> tuple[pipeline.Compiled, str]:
    with _LOCK:
        return _compile_once(model)


def _compile_once(model: str | Path) -> tuple[pipeline.Compiled, str]:
    digest = ""  # not a regular file: compile_model says what is wrong with the path
    try:
        if Path(model).is_file():
            with open(model, "rb") as f:
                digest = hashlib.sha256(f.read(MAX_BYTES + 1)).hexdigest()
    except OSError:
        pass
    key = (str(model), digest)
    pid = os.getpid()
    if pid not in _FOLDERS:  # first use in this process: a forked child must not share its parent's folder
        _COMPILED.clear()
        _FOLDERS[pid] = private_folder("bgc-")
    if digest and key in _COMPILED:
        return _COMPILED[key]
    c = pipeline.compile_model(model)
    folder = Path(_FOLDERS[pid]) / c.raw.sha256[:16]
    root = folder / c.model.name / "numpy_model"
    if not root.exists():
        root.mkdir(parents=True)
        for rel, text in c.package.files:
            (root / rel).write_text(text, encoding="utf-8")
    if digest:
        _COMPILED[key] = (c, str(folder))
    return c, str(folder)


def _run(c, run, package, scenario, injected, noise, levels, opts, say) -> DiagnosisReport:
    track.check_request(run, package, "nominal", opts.particles, None)
    priors = {f.parameter: f.prior for f in c.model.faults}
    result = run_diagnosis(run, package, c.signatures, priors, opts, say)
    return DiagnosisReport(c.model.name, c.model.display_source, run, scenario, injected, noise, levels, opts,
                           result)


@dataclass(frozen=True, slots=True)
class DistinguishabilityReport:
    """What the data of a model's scenarios are predicted to tell apart
    (:mod:`bgc.runtime.distinguish`): one :class:`Distinction` per scenario,
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


def distinguishability(model: str | Path, scenario: str | None = None, *, change: float = 0.3, at: float = 0.5,
                       process_noise: float | None = None, measurement_noise: float | None = None,
                       steps: int | None = None, level: float = distinction.LEVEL) -> DistinguishabilityReport:
    """Predict which fault hypotheses the data of ``scenario``
    (``PARAM:KIND:MAGNITUDE@TIME``) of ``model`` can tell apart, at the given
    relative noise levels (default: the model's), before any data are seen;
    without a scenario, for every fault candidate, kind and direction at a
    relative ``change`` from the fraction ``at`` of the run."""
    _check_measurement_noise(measurement_noise)
    c, private = _compiled(model)
    num = c.numerics
    if steps is not None:
        simulate.check_steps(steps, num, "--steps")
    T = steps or c.model.settings.steps
    dt = c.model.settings.dt
    if scenario is None and not (0.0 < change and 0.0 < at and int(at * T) < T - 1):
        raise SimulationError(f"change {change:g} at {at:g} of the run", None,
                              "give a change above 0 and an onset inside the run, a fraction between 0 and 1")
    if not num.faults:
        raise SimulationError(f"{c.model.name} declares no fault candidates", None,
                              "list the faults to tell apart under 'faults' in the model file")
    levels = num.noise_at(process_noise, measurement_noise)
    custom = levels if (process_noise, measurement_noise) != (None, None) else None
    with _LOCK:
        package = track.load_package(private, c.model.name, str(model), custom)
        families = _families(package, T)
    priors = {f.parameter: f.prior for f in c.model.faults}
    times = dt * np.arange(1, T + 1)
    if scenario is not None:
        if scenario.strip().lower() == "none":
            raise SimulationError("a fault-free scenario has no fault to tell apart", None,
                                  "give a fault, e.g. R_pipe:incipient:0.5@165, or no scenario for every candidate")
        inj = simulate.parse_fault(scenario, num)
        if f"{inj.parameter}_{inj.kind}" not in package.MODELS:
            raise SimulationError(f"{inj.parameter}:{inj.kind} is not a fault candidate of {c.model.name}", None,
                                  "candidates: " + ", ".join(f"{f.parameter}:{f.kind}" for f in num.faults))
        if not 0 < inj.time <= times[-1]:
            raise SimulationError(f"onset {inj.time:g} is outside the run (0 to {times[-1]:g})", None,
                                  "choose an onset inside the run, or more --steps")
        injected = [inj]
    else:
        injected = []
        for f in num.faults:
            onset = int(at * T)
            for sign in DIRECTIONS[next(x.direction for x in c.model.faults if x.parameter == f.parameter)]:
                size = sign * change * abs(f.nominal)
                drifts = fault_kind(f.kind).drifts  # a drift reaches the change at the last sample
                injected.append(simulate.FaultInjection(f.parameter, f.kind,
                                                        size / ((T - 1 - onset) * dt) if drifts else size,
                                                        float(times[onset])))
    out = []
    for inj in injected:
        onset = metrics.sample_at(times, inj.time)
        out.append(distinction.distinguish(families, f"{inj.parameter}_{inj.kind}", inj.magnitude, onset, priors,
                                           level))
    return DistinguishabilityReport(c.model.name, c.model.display_source, T, dt, (process_noise, measurement_noise),
                                    scenario, None if scenario else change, None if scenario else at, tuple(out))


#: Prepared families by package (its module name tells the noise levels) and
#: run length; the latest few are kept (a campaign worker meets a few models).
_FAMILIES: dict[tuple[str, str, int], distinction.Families] = {}
_FAMILIES_KEPT = 4


def _families(package, steps: int) -> distinction.Families:
    key = (package.__name__, str(getattr(package, "__file__", "")), steps)
    if key not in _FAMILIES:
        if len(_FAMILIES) >= _FAMILIES_KEPT:
            _FAMILIES.pop(next(iter(_FAMILIES)))
        _FAMILIES[key] = distinction.prepare(package, distinction.scenario_inputs(package, steps))
    return _FAMILIES[key]
