"""Load a generated NumPy package (``generated/<model>/numpy_model``) and run
its filters on a recorded run.

The generated package imports only numpy; it is loaded by path under a private
module name, so several models' packages can be loaded side by side.
"""

from __future__ import annotations

import importlib.util
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np

from ..codegen import PACKAGE
from ..errors import SimulationError
from ..simulate import Run


def load_package(generated_dir: str | Path, model: str, source: str | None = None) -> ModuleType:
    """Import ``<generated_dir>/<model>/numpy_model`` as ``bgc_generated_<model>``
    (``source``: the model file, for the hint when the package is missing)."""
    root = Path(generated_dir) / model / PACKAGE
    init = root / "__init__.py"
    if not init.exists():
        out = "" if Path(generated_dir) == Path("generated") else f" -o {generated_dir}"
        raise SimulationError(f"no generated package at {root}", None,
                              f"run: bgc compile {source or 'MODEL.yaml'}{out}")
    name = f"bgc_generated_{model}"
    if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(init):
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, init, submodule_search_locations=[str(root)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@dataclass(frozen=True, slots=True)
class TrackResult:
    """A filter's estimates over a run: arrays of shape (T, n_x) / (T, n_y) / (T,)."""

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


def run_arrays(run: Run, package: ModuleType, model_name: str) -> tuple[np.ndarray, np.ndarray]:
    """(ys, us) arrays of a recorded run in the model's output and input order."""
    model = package.MODELS[model_name]
    missing = [y for y in model.OUTPUTS if y not in run.measurements]
    if missing:
        raise SimulationError(f"the run has no column y:{missing[0]}", None,
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


def track(run: Run, package: ModuleType, model_name: str = "nominal", method: str = "gpf",
          particles: int = 200, seed: int = 0, start: float | None = None) -> TrackResult:
    """Run the generated GPF or APF of ``model_name`` over the run.

    With ``start`` (a fault model only), the nominal model is tracked up to
    ``start`` and its particles are then lifted into the fault model with a fresh
    prior on the fault magnitude (the thesis's hand-over at detection time);
    the nominal part of the estimates is reported with NaN for the fault states.
    """
    if model_name not in package.MODELS:
        raise SimulationError(f"no generated model '{model_name}'", None,
                              "choose one of: " + ", ".join(package.MODELS))
    model = package.MODELS[model_name]
    cls = {"gpf": package.filters.GenericParticleFilter, "apf": package.filters.AuxiliaryParticleFilter}[method]
    ys, us = run_arrays(run, package, model_name)
    rng = np.random.default_rng(seed)
    T = len(run.time)
    n_x = len(model.STATES)
    split = 0
    if start is not None and model.FAULT is not None:
        split = int(np.searchsorted(run.time, start))
    started = time.perf_counter()
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
        k = out["mean"].shape[1]
        mean[:split, :k], std[:split, :k] = out["mean"], out["std"]
        y_mean[:split], y_std[:split], ess[:split] = out["y_mean"], out["y_std"], out["ess"]
        resampled[:split] = out["resampled"]
        recoveries += pf0.recoveries
        x0 = model.augment(pf0.x[:, package.filters.systematic_resample(pf0.logw, rng)], rng)
    if split < T:
        pf = cls(model, particles, rng, x=x0)
        out = pf.run(ys[split:], us[split:])
        mean[split:], std[split:] = out["mean"], out["std"]
        y_mean[split:], y_std[split:], ess[split:] = out["y_mean"], out["y_std"], out["ess"]
        resampled[split:] = out["resampled"]
        recoveries += pf.recoveries
    seconds = time.perf_counter() - started
    return TrackResult(model_name, method, particles, run.time, tuple(model.STATES), mean, std,
                       tuple(model.OUTPUTS), y_mean, y_std, ess, resampled, recoveries, seconds)

