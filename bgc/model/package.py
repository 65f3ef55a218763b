"""Tracking: load a generated package (``generated/<model>/numpy_model``, or
the compiled ``numba_model``: the backend) and run its filters over a
recorded run.

The NumPy package imports only numpy, the compiled one numpy and numba; a
package is loaded by path under a private module name, so several models'
packages can be loaded side by side. The
runtime knows fault kinds from :mod:`bgc.kinds` and the package's ``FAULT``
table, never from the compiler.
"""

from __future__ import annotations

import hashlib
import importlib.util
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np

from ..errors import DataError, TrackingError, printable
from ..ir import PACKAGES, NoiseLevels
from ..kinds import fault_kind
from ..filters import cubature as kalman
from ..data.runs import Run

#: Memory the particle arrays of one filter may take (several state-sized
#: arrays of N particles live at once: the particles, the RK4 stages, weights).
MAX_FILTER_BYTES = 4_000_000_000
#: Arrays of N particles alive at once, counted in rows of n_x: the particles
#: and a resampled copy, weights and log-weights (the RK4 scratch is per block).
_ROWS_ALIVE = 3


#: The backends, in the order ``--backend`` lists them.
BACKENDS = tuple(PACKAGES)


def numba_installed() -> bool:
    """Whether numba can be imported (the ``fast`` extra)."""
    return importlib.util.find_spec("numba") is not None


def resolve_backend(backend: str | None) -> str:
    """The backend to run on: ``backend`` ('numpy' or 'numba'), or for None or
    'auto' the environment's ``BGC_BACKEND`` when set, else numba when it is
    installed, else numpy.

    Raises
    ------
    TrackingError
        An unknown backend, or numba asked for and not installed.
    """
    chosen = backend if backend not in (None, "auto") else _environment_backend() or (
        "numba" if numba_installed() else "numpy")
    if chosen not in PACKAGES:
        raise TrackingError(f"unknown backend {printable(str(chosen))}", None,
                            "use one of: " + ", ".join(BACKENDS) + " (or auto)")
    if chosen == "numba" and not numba_installed():
        raise TrackingError("the numba backend needs numba, which is not installed", None,
                            "pip install 'bgc[fast]', or use --backend numpy")
    return chosen


def _cold(model: ModuleType, steps=("nominal",)) -> bool:
    """Whether numba's disk cache lacks a compiled model's kernels (its
    prediction, or its whole filter step when the model is one of ``steps``,
    :func:`_compiled_step`)."""
    kernels = [model._JIT.predict] + ([model._JIT.generic_step] if _compiled_step(model, steps) else [])
    try:
        return not all(Path(k._cache._cache_file._index_path).exists() for k in kernels)
    except AttributeError:  # another numba's internals: taken for cold
        return True


def _compiled_step(model: ModuleType, steps=("nominal",)) -> bool:
    """Whether warm-up compiles the model's whole generic filter step
    (``_JIT.generic_step``): a model of ``steps``, those that run a generic
    particle filter of their own (a diagnosis's watching filter is the
    nominal model's; a fault model's filters step in banks). Another
    model's is compiled when a filter of it first steps alone."""
    return model.NAME in steps and hasattr(model._JIT, "generic_step")


def _call_kernels(package: ModuleType, model: ModuleType, steps=("nominal",)) -> None:
    """Call a compiled model's kernels (``_JIT.predict``, ``_JIT.observe``: the
    per-particle functions are compiled into them) once on one particle,
    compiling them or loading them from the disk cache; the nominal model's
    whole generic filter step too (:func:`_compiled_step`)."""
    x = np.array(model.X0, dtype=float)[:, None].copy()
    u = model.inputs(0.0)
    model.predict(x, u, model.THETA, model.DT, out=x)
    model.observe(x, u, model.THETA)
    if _compiled_step(model, steps):
        package.filters.GenericParticleFilter(model, 2, np.random.default_rng(0)).step(
            np.full(len(model.OUTPUTS), np.nan), u)


def _call_kernel_loops(model: ModuleType) -> None:
    """Call the compiled kernel's loops (``model._kernel._JIT``: the Gaussian
    log-likelihood, the generic filter's weighing, normalising, resampling,
    draws and moments, the cubature Kalman filter's steps, the static
    posterior's quadrature) once each."""
    kernel = model._kernel
    kernel.gaussian_loglik(np.zeros(1), np.zeros((1, 1)), np.ones(1))
    logw, w, yhat = np.zeros(2), np.full(2, 0.5), np.zeros((1, 2))
    kernel.weigh(yhat, np.zeros(1), np.ones(1), logw, w)
    kernel.resample(yhat, kernel.normalise(logw)[2], 0.5)
    kernel.moments(yhat, w)
    kernel.normal_into(np.random.default_rng(0), np.empty((1, 2)))  # compiled draws (a Generator)
    kernel.finish(yhat, np.zeros(2), 3.0, np.random.default_rng(0))  # resampling: ESS 2 < 3
    kalman.CubatureKalmanFilter(model).step(np.full(len(model.OUTPUTS), 0.0), model.inputs(0.0))
    kalman.row_quadrature(np.arange(3.0), np.zeros(3), kernel)


def _compile_some(args: tuple[str, list[str], tuple[str, ...]]) -> set[tuple[str, str]]:
    """In a forked worker: compile the kernels of the models ``names`` of the
    package ``sys.modules[package]`` into numba's disk cache (the name
    ``None``: the compiled kernel's loops; the whole steps of ``steps``); which kernels this process
    compiled (:func:`_kernels`' keys: a loop of the kernel that another
    worker's model step compiled too is named by both)."""
    package, steps = sys.modules[args[0]], args[2]
    kernels = _kernels(package, steps)
    before = _misses(kernels.values())
    for name in args[1]:
        if name is None:
            _call_kernel_loops(next(iter(package.MODELS.values())))
        else:
            _call_kernels(package, package.MODELS[name], steps)
    return {key for key, after, was in zip(kernels, _misses(kernels.values()), before) if after > was}


#: The compiled kernel's loops that warm-up compiles (``_kernel._JIT``'s).
KERNEL_LOOPS = ("loglik", "weigh", "normalise", "resample", "finish", "moments", "standard_normal",
                "cubature_prepare", "cubature_after", "cubature_update", "row_quadrature")


def _kernels(package: ModuleType, steps=("nominal",)) -> dict[tuple[str, str], object]:
    """The numba dispatchers warm-up compiles, by (model, function) (the
    kernel's loops by ('', loop)): every model's predict and observe, the
    generic steps of :func:`_compiled_step`, the kernel's :data:`KERNEL_LOOPS`."""
    found = {}
    for name, m in package.MODELS.items():
        found[name, "predict"], found[name, "observe"] = m._JIT.predict, m._JIT.observe
        if _compiled_step(m, steps):
            found[name, "generic_step"] = m._JIT.generic_step
    jit = next(iter(package.MODELS.values()))._kernel._JIT
    return found | {("", loop): getattr(jit, loop) for loop in KERNEL_LOOPS}


def _misses(dispatchers) -> list[int]:
    """How often each numba dispatcher missed its disk cache (compiled)."""
    return [sum(k.stats.cache_misses.values()) for k in dispatchers]


def _environment_backend() -> str | None:
    """``BGC_BACKEND`` when it names a backend (empty or 'auto': None)."""
    import os

    chosen = os.environ.get("BGC_BACKEND", "").strip()
    return None if chosen in ("", "auto") else chosen


def chosen_by_name(backend: str | None) -> bool:
    """Whether ``backend`` (or, for None / 'auto', ``BGC_BACKEND``) names a backend: a
    backend asked for by name is used or refused; one chosen by what is installed
    falls back to NumPy when the compiled package cannot be had."""
    return backend not in (None, "auto") or _environment_backend() is not None


def warm_up(package: ModuleType, workers: int | None = None, steps=("nominal",)) -> tuple[float, int, int]:
    """Compile (or load from numba's disk cache) every compiled kernel of a
    numba package (:func:`_kernels`) by one call of each model's transition
    and observation on one particle, the whole generic filter step of the
    models ``steps`` (those whose own filters will run; default the nominal
    model, a diagnosis's watching filter) and the kernel's loops: (seconds, kernels compiled, kernels loaded from
    the cache; each kernel counted once). A NumPy package: (0, 0, 0). When
    the cache is cold the models and the kernel's loops are compiled on
    ``workers`` forked processes (default: the cores, at most 4), one task
    each, into the disk cache first, then loaded here; forked workers of
    this process inherit what is loaded."""
    import os
    import threading

    models = list(package.MODELS.values())
    if not hasattr(models[0], "_JIT"):
        return 0.0, 0, 0
    t0 = time.perf_counter()
    kernels = _kernels(package, steps)
    misses = _misses(kernels.values())
    hits = [sum(k.stats.cache_hits.values()) for k in kernels.values()]
    cold = [name for name, m in package.MODELS.items() if _cold(m, steps)]
    if cold:  # the kernel's loops too (the longest task, so first), in one task each: the pool balances them
        cold.insert(0, None)
    workers = min(workers or len(os.sched_getaffinity(0)) or 1, 4, len(cold))
    elsewhere = set()
    # forked compilers: only from a process with one thread (a thread holding numba's compiler lock at the
    # fork would leave the child waiting for it) that may have children (a Dask worker is a daemon)
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods() \
            and not multiprocessing.current_process().daemon and threading.active_count() == 1:
        tasks = [(package.__name__, [name], tuple(steps)) for name in cold]
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork")) as pool:
            elsewhere = set().union(*pool.map(_compile_some, tasks))
    for m in models:
        _call_kernels(package, m, steps)
    _call_kernel_loops(models[0])
    here = {key for key, after, was in zip(kernels, _misses(kernels.values()), misses) if after > was}
    loaded = {key for key, k, was in zip(kernels, kernels.values(), hits) if sum(k.stats.cache_hits.values()) > was}
    return time.perf_counter() - t0, len(here | elsewhere), len(loaded - elsewhere - here)


def load_package(generated_dir: str | Path, model: str, source: str | None = None,
                 noise: NoiseLevels | None = None, backend: str = "numpy") -> ModuleType:
    """Import ``<generated_dir>/<model>/numpy_model`` (``backend`` 'numba':
    ``numba_model``) as ``bgc_generated_<model>_<folder hash>``
    (``source``: the model file, for the hint when the package is missing).

    With ``noise`` (absolute stds, e.g. :meth:`bgc.ir.Numerics.noise_at` of
    other relative levels), a separate instance of the package is loaded
    whose models use those process, measurement and predictive stds (their
    fault states keep theirs, and the initial spread ``X0_STD`` stays the
    compiled one): the filters then match data simulated at other noise levels.
    """
    root = Path(generated_dir) / model / PACKAGES[backend]
    init = root / "__init__.py"
    if not init.exists():
        if (Path(generated_dir) / PACKAGES[backend] / "__init__.py").exists():  # the model's own folder, not the root
            raise TrackingError(
                f"{printable(str(generated_dir))} is the folder of one model's package", None,
                f"point --generated at the folder bgc compile -o wrote: {printable(str(Path(generated_dir).parent))}")
        out = "" if Path(generated_dir) == Path("generated") else f" -o {printable(str(generated_dir))}"
        raise TrackingError(
            f"no generated package at {printable(str(root))}", None,
            f"run: bgc compile {printable(source or 'MODEL.yaml')}{out} (it writes both backends' packages), or "
            "point --generated at the folder bgc compile -o wrote")
    # one name per folder: two sessions of a model (another folder, another text) never share a module
    name = f"bgc_generated_{model}_{hashlib.sha256(str(root.resolve()).encode()).hexdigest()[:12]}"
    if noise is not None:
        key = hashlib.sha256(repr((noise.process, noise.measurement, noise.predictive)).encode()).hexdigest()[:16]
        name = f"{name}_noise_{key}"
    if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(init):
        return sys.modules[name]
    for old in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
        del sys.modules[old]  # another folder's package of that name: none of its modules may be reused
    spec = importlib.util.spec_from_file_location(name, init, submodule_search_locations=[str(root)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    if noise is not None:
        for m in module.MODELS.values():
            n = len(noise.process)
            if len(m.MEASUREMENT_STD) != len(noise.measurement) or len(m.PROCESS_STD) < n:
                raise TrackingError(f"the package at {printable(str(root))} does not have this model's states and "
                                    "sensors", None, f"run: bgc compile {printable(source or 'MODEL.yaml')}")
            m.PROCESS_STD[:n] = noise.process
            m.MEASUREMENT_STD[:] = noise.measurement
            m.PREDICTIVE_STD[:] = noise.predictive
    return module


@dataclass(frozen=True, slots=True)
class TrackResult:
    """A filter's estimates over a run: arrays of shape (T, n_x) / (T, n_y) / (T,).

    Before a hand-over (``start``) the fault states are NaN.
    """

    model: str
    method: str
    particles: int
    time: np.ndarray
    state_names: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    output_names: tuple[str, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    recoveries: int
    seconds: float
    fault: dict | None = None

    def rmse(self, run: Run) -> dict[str, float]:
        """Root-mean-square error of each state estimate against the run's truth
        (the states and faulty parameter it records), over the steps where
        the estimate is defined."""
        out = {}
        for k, x in enumerate(self.state_names):
            truth = run.states.get(x, run.parameters.get(x))
            if truth is not None:
                ok = np.isfinite(self.mean[:, k]) & np.isfinite(truth)
                if ok.any():
                    out[x] = float(np.sqrt(np.mean((self.mean[ok, k] - truth[ok]) ** 2)))
        return out


@dataclass(frozen=True, slots=True)
class FaultEstimate:
    """The fault magnitude a fault-model filter ends with: ``what`` it is
    (``R2 = 2 + delta`` or ``slope of R2``), its value and std at the last
    step, and the truth when the run records it."""

    parameter: str
    kind: str
    what: str
    value: float
    std: float
    time: float
    truth: float | None

    @property
    def relative_error(self) -> float | None:
        if self.truth is None:
            return None
        return abs(self.value - self.truth) / abs(self.truth or 1.0)


def fault_estimate(result: TrackResult, package: ModuleType, run: Run,
                   per_time: str = "per unit time") -> FaultEstimate | None:
    """The fault estimate of a fault-model track (None for the nominal model):
    a bias as the parameter's value (nominal + bias), a slope as it is
    (``per_time``: how its rate is named, e.g. "per s" in the model's time unit)."""
    fault = result.fault
    if not fault:
        return None
    module = package.MODELS[result.model]
    p = fault["parameter"]
    kind = fault_kind(fault["kind"])
    nominal = dict(zip(module.PARAMETERS, module.THETA))[p]
    k = result.state_names.index(f"delta_{p}")
    mean, std = float(result.mean[-1, k]), float(result.std[-1, k])
    truth = run.parameters.get(p)
    if kind.drifts:
        value, what = mean, f"{kind.magnitude} of {p} ({per_time})"
        true_value = None
        if truth is not None and len(truth) > 1:
            true_value = float((truth[-1] - truth[-2]) / (run.time[-1] - run.time[-2]))
    else:
        value, what = nominal + mean, f"{p} = {nominal:g} + delta"
        true_value = float(truth[-1]) if truth is not None else None
    return FaultEstimate(p, kind.name, what, value, std, float(result.time[-1]), true_value)


def onset_transition(model: ModuleType, x: np.ndarray, u: np.ndarray, theta) -> np.ndarray:
    """The noise-free transition into a fault's onset sample, in place on a
    fault model's particles ``x``: the dynamics that lead to the sample are
    nominal, the sample sees the fault. A fault with onset k changes the
    parameter at the instant of sample k: as in the thesis's DBN (the
    parameter of time slice k enters y_k and the transition out of slice k)
    and in the simulator, y_k sees the new value and the states move from
    step k on. So the magnitude state (the last: a bias, or a drift's slope)
    is held at zero for this one transition, then restored; a drifting
    parameter's own state stays at its nominal value. The filter's step then
    adds the process noise and weighs the particles with the fault in
    (``step(y, u, predicted=True)``)."""
    row = len(model.STATES) - 1
    magnitude = x[row].copy()
    x[row] = 0.0
    model.predict(x, u, theta, model.DT, out=x)
    x[row] = magnitude
    return x


#: The filters by their short names, one entry each; every one meets the
#: filter protocol (:class:`bgc.filters.Filter`). A particle filter
#: is named by its class in a generated package's ``filters`` module (every
#: package has its copy of ``bgc/filters/particle.py``), a filter of
#: bgc's runtime by its class.
FILTER_CLASSES = {"gpf": "GenericParticleFilter", "apf": "AuxiliaryParticleFilter",
                  "opf": "OptimalProposalParticleFilter", "ckf": kalman.CubatureKalmanFilter}


def filter_class(package: ModuleType, method: str):
    """The filter class of ``method`` (gpf, apf, opf or ckf), a particle
    filter's from ``package``; built as ``cls(model, particles, rng, x=None)``."""
    if method not in FILTER_CLASSES:
        raise TrackingError(f"unknown filter {method!r}", None, "use " + ", ".join(FILTER_CLASSES))
    cls = FILTER_CLASSES[method]
    return getattr(package.filters, cls) if isinstance(cls, str) else cls


def run_arrays(run: Run, package: ModuleType, model_name: str) -> tuple[np.ndarray, np.ndarray]:
    """(ys, us) arrays of a recorded run in the model's output and input order."""
    model = package.MODELS[model_name]
    missing = [y for y in model.OUTPUTS if y not in run.measurements]
    if missing:
        raise DataError(f"{printable(run.source)}: the run has no column y:{printable(missing[0])}", None,
                        "record it with bgc simulate for the same model")
    ys = np.column_stack([run.measurements[y] for y in model.OUTPUTS])
    if model.INPUTS:
        us = np.column_stack([run.inputs[u] if u in run.inputs else np.full(len(run.time), np.nan)
                              for u in model.INPUTS])
        if np.isnan(us).any():
            us = np.array([model.inputs(t - model.DT) for t in run.time])
    else:
        us = np.zeros((len(run.time), 0))
    return ys, us


def check_particles(particles: int, package: ModuleType, model_name: str) -> None:
    """Refuse, before any work, a particle count below 1 or whose arrays
    would take more than MAX_FILTER_BYTES."""
    n_x = len(package.MODELS[model_name].STATES)
    if particles < 1:
        raise TrackingError(f"--particles {particles}: at least 1 particle is needed", None, "e.g. --particles 200")
    need = int(particles) * (_ROWS_ALIVE * n_x + 3) * 8
    if need > MAX_FILTER_BYTES:
        most = MAX_FILTER_BYTES // ((_ROWS_ALIVE * n_x + 3) * 8)
        raise TrackingError(f"--particles {particles} would take about {need / 1e9:.3g} GB", None,
                            f"use at most {most} particles for this model")


def check_run_of(run: Run, model: str, where: str | None = None) -> None:
    """Refuse a run whose header says another model made it (``where``: the
    run's file; by default its ``source``)."""
    where = run.source if where is None else where
    recorded = run.model
    if recorded is not None and recorded != model:
        raise DataError(f"{printable(where)} is a run of model {printable(repr(recorded))}, not of {model!r}", None,
                        "filter it with the model the run was made with")


def check_request(run: Run, package: ModuleType, model_name: str, particles: int, start: float | None,
                  columns: bool = True) -> None:
    """Refuse a filter request that cannot run, before any work: a model the
    package lacks, no sensors, a hand-over without a fault model or outside
    the run, too many particles, and (``columns``) a run without the model's
    measurements (a diagnosis takes one: it uses the sensors present).
    Whether the run is of this model at all is :func:`check_run_of`, which
    callers ask first."""
    name = package.MODELS["nominal"].MODEL
    if model_name not in package.MODELS:
        raise TrackingError(f"no generated model {printable(repr(model_name))}", None,
                            "choose one of: " + ", ".join(package.MODELS))
    if not package.MODELS[model_name].OUTPUTS:
        raise TrackingError(f"{name} has no measurements, so there is nothing to filter", None,
                            "declare the plant's sensors under 'measurements'")
    if start is not None and package.MODELS[model_name].FAULT is None:
        raise TrackingError("--start hands over to a fault model", None, "give --fault PARAM:KIND with --start")
    if start is not None and not (run.time[0] <= start <= run.time[-1]):
        raise TrackingError(f"--start {start:g} is outside the run ({run.time[0]:g} to {run.time[-1]:g}) of "
                            f"{printable(run.source)}", None,
                            "hand over at a time inside the run")
    check_particles(particles, package, model_name)
    if columns:
        run_arrays(run, package, model_name)


@np.errstate(all="ignore")  # particles outside a law's domain are weighted out and counted
def track(run: Run, package: ModuleType, model_name: str = "nominal", method: str = "gpf",
          particles: int = 200, seed: int = 0, start: float | None = None) -> TrackResult:
    """Run the filter ``method`` (:data:`FILTER_CLASSES`) of ``model_name`` over the run.

    With ``start`` (a fault model only), the nominal model is tracked up to
    ``start`` and its particles are then lifted into the fault model with a fresh
    prior on the fault magnitude (the thesis's hand-over at detection time);
    the nominal part of the estimates is reported with NaN for the fault states.
    """
    if model_name not in package.MODELS:
        raise TrackingError(f"no generated model {printable(repr(model_name))}", None,
                            "choose one of: " + ", ".join(package.MODELS))
    check_particles(particles, package, model_name)
    model = package.MODELS[model_name]
    cls = filter_class(package, method)
    if start is not None and cls is kalman.CubatureKalmanFilter:
        raise TrackingError("--start hands a particle cloud over to a fault model; ckf has none", None,
                            "use --method gpf, apf or opf with --start")
    ys, us = run_arrays(run, package, model_name)
    rng = np.random.default_rng(seed)
    split = 0
    if start is not None and model.FAULT is not None:
        split = int(np.searchsorted(run.time, start))
    started = time.perf_counter()
    T = len(run.time)
    n_x = len(model.STATES)
    mean = np.full((T, n_x), np.nan)
    std = np.full((T, n_x), np.nan)
    y_mean = np.empty((T, ys.shape[1]))
    y_std = np.empty((T, ys.shape[1]))
    ess = np.empty(T)
    resampled = np.zeros(T, bool)
    recoveries = 0
    x0 = None
    if split > 0:
        nominal = package.MODELS["nominal"]
        pf0 = cls(nominal, particles, rng)
        out = pf0.run(ys[:split], us[:split])
        k = out.mean.shape[1]
        mean[:split, :k], std[:split, :k] = out.mean, out.std
        y_mean[:split], y_std[:split], ess[:split] = out.y_mean, out.y_std, out.ess
        resampled[:split] = out.resampled
        recoveries += pf0.recoveries
        x0 = model.augment(pf0.x[:, package.filters.systematic_resample(pf0.logw, rng)], rng)
    if split < T:
        pf = cls(model, particles, rng, x=x0)
        if x0 is not None:  # handed over at the fault's onset: its sample sees the fault, the transition is nominal
            onset_transition(model, pf.x, us[split], pf.theta)
            r = pf.step(ys[split], us[split], predicted=True)
            mean[split], std[split], y_mean[split], y_std[split] = r.mean, r.std, r.y_mean, r.y_std
            ess[split], resampled[split] = r.ess, r.resampled
            split += 1
        out = pf.run(ys[split:], us[split:])
        mean[split:], std[split:] = out.mean, out.std
        y_mean[split:], y_std[split:], ess[split:] = out.y_mean, out.y_std, out.ess
        resampled[split:] = out.resampled
        recoveries += pf.recoveries
    seconds = time.perf_counter() - started
    return TrackResult(model_name, method, particles, run.time, tuple(model.STATES), mean, std,
                       tuple(model.OUTPUTS), y_mean, y_std, ess, resampled, recoveries, seconds,
                       dict(model.FAULT) if model.FAULT else None)
