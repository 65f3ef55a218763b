"""Warm-up of a compiled (numba) package: its kernels compiled, or loaded
from numba's disk cache, before the data come (:func:`warm_up`)."""

from __future__ import annotations

import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..filters import cubature, quadrature
from .protocol import FaultModel, Package


def _cold(model: FaultModel, steps=("nominal",)) -> bool:
    """Whether numba's disk cache lacks a compiled model's kernels (its
    prediction, or its whole filter step when the model is one of ``steps``,
    :func:`_compiled_step`)."""
    kernels = [model._JIT.predict] + ([model._JIT.generic_step] if _compiled_step(model, steps) else [])
    try:
        return not all(Path(k._cache._cache_file._index_path).exists() for k in kernels)
    except AttributeError:  # another numba's internals: taken for cold
        return True


def _compiled_step(model: FaultModel, steps=("nominal",)) -> bool:
    """Whether warm-up compiles the model's whole generic filter step
    (``_JIT.generic_step``): a model of ``steps``, those that run a generic
    particle filter of their own (a diagnosis's watching filter is the
    nominal model's; a fault model's filters step in banks). Another
    model's is compiled when a filter of it first steps alone."""
    return model.NAME in steps and hasattr(model._JIT, "generic_step")


def _call_kernels(package: Package, model: FaultModel, steps=("nominal",)) -> None:
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


def _call_kernel_loops(model: FaultModel) -> None:
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
    cubature.CubatureKalmanFilter(model).step(np.full(len(model.OUTPUTS), 0.0), model.inputs(0.0))
    quadrature.row_quadrature(np.arange(3.0), np.zeros(3), kernel)


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


def _kernels(package: Package, steps=("nominal",)) -> dict[tuple[str, str], object]:
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


def warm_up(package: Package, workers: int | None = None, steps=("nominal",)) -> tuple[float, int, int]:
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
