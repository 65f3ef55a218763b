"""Model-independent numerics of the compiled (numba) packages: the NumPy
kernel's functions, with the Gaussian log-likelihood, the weighted moments
and the generic particle filter's weighing, normalising and resampling
compiled by numba.

bgc copies this file unchanged into every ``numba_model`` package it
generates, as ``_kernel.py``, beside a copy of the NumPy kernel as
``kernel.py`` (its source is ``bgc/filters/kernel.py``); each
compiled model module imports it as ``from . import _kernel``. What is not
redefined here is the NumPy kernel's own function. The two backends draw
the same random numbers in the same order from the caller's
``np.random.Generator`` (``perturb`` a block of particles at a time; here
the draws are made by numba's implementation of the Generator, NumPy's
algorithms on the same bit generator) and differ in rounding only: a
compiled loop adds the terms of a sum in its own order.

The compiled functions live in modules of their own (``_jit_kernel.py``
here, ``_jit_<model>.py`` beside each model module), loaded by
:func:`load_jit`. Each takes C-contiguous float64 arrays (the wrappers copy
what is not) and works in place or into an ``out`` array; none reads a
module-level array (numba would freeze it as a constant), so a package
instance whose noise levels were changed after import computes with the new
ones. Compiled code is cached on disk beside the package (``cache=True``):
the first process to call a kernel compiles it, later processes load it.
"""

import hashlib
import importlib.util
import os
import sys
import threading

import numpy as np

from . import kernel as _numpy
from .kernel import BLOCK, block_views, gaussian_loglik_each, log_normaliser, predictive_std, rk4, spans

#: The kernel's functions: the NumPy kernel's, but the compiled ones defined here; ``weigh``,
#: ``normalise`` and ``resample`` are the generic particle filter's steps, which the filters take
#: from a kernel that has them, and the ``cubature_*`` functions the cubature Kalman filter's
#: (``bgc.filters.cubature`` takes them from a compiled package's kernel).
__all__ = ["BLOCK", "block_views", "contiguous", "cubature_after", "cubature_prepare",
           "cubature_update", "draw", "finish", "gauss_terms", "generator_handle", "gaussian_loglik", "gaussian_loglik_each", "load_jit",
           "log_normaliser", "LOG_2PI", "moments", "NO_NOISE", "normal_into", "normalise", "perturb", "predictive_std", "resample", "rk4", "row_quadrature", "spans",
           "step_handle", "weigh"]
#: The prediction's noise when there is none (a compiled kernel takes an array all the same).
NO_NOISE = np.empty((0, 0))
#: Up to this many particles the moments are one compiled pass; beyond, NumPy's (a long sum is faster
#: in BLAS than in a loop that must add in order).
SHORT = 4096

def _shared_lock():
    """One lock for every copy of this kernel in the process (each package
    instance imports its own ``_kernel``), kept under a fixed name in
    ``sys.modules``, and made afresh in a forked child."""
    holder = sys.modules.get("bgc_jit_lock")
    if holder is None:
        import types

        fresh = types.ModuleType("bgc_jit_lock")
        fresh.lock = threading.Lock()
        holder = sys.modules.setdefault("bgc_jit_lock", fresh)  # atomic: one holder wins
        if holder is fresh:
            os.register_at_fork(after_in_child=lambda: setattr(fresh, "lock", threading.Lock()))
    return holder


def load_jit(near, file, kernel_jit=None):
    """The module of compiled kernels ``file`` beside ``near`` (a module's
    ``__file__``), imported once per process under a name made from its
    path: numba's disk cache keeps the name of the module a kernel was
    compiled in, so every instance of a package (another noise level, or
    the package imported under another name) must use the one module of the
    file, whose name a later process gives it again. ``kernel_jit``: this
    kernel's compiled module, set as the new module's ``_kernel_jit``
    before it runs (a model's compiled step calls the kernel's loops)."""
    path = os.path.realpath(os.path.join(os.path.dirname(os.path.abspath(near)), file))
    name = "bgc_jit_" + hashlib.sha256(path.encode("utf-8")).hexdigest()[:16] + "_" + file[:-3].lstrip("_")
    with _shared_lock().lock:
        module = sys.modules.get(name)
        if module is None:
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            if kernel_jit is not None:
                module._kernel_jit = kernel_jit
            spec.loader.exec_module(module)
            sys.modules[name] = module
    return module


#: The compiled loops of this kernel (``_jit_kernel.py``, numba).
_JIT = load_jit(__file__, "_jit_kernel.py")


def contiguous(a):
    """``a`` as a C-contiguous float64 array (``a`` itself when it is one)."""
    if isinstance(a, np.ndarray) and a.dtype == np.float64 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=np.float64)


def gaussian_loglik(y, yhat, std):
    """sum_j log N(y_j; yhat_j, std_j^2) for every particle (column of yhat);
    NaN entries of y are not used. ``std``: (n_y,), or (n_y, N), a std per
    particle (the NumPy kernel's :func:`gaussian_loglik_each`)."""
    y = np.asarray(y, dtype=float)
    std = np.asarray(std, dtype=float)
    seen = np.isfinite(y)
    if std.ndim == 2:
        return gaussian_loglik_each(y[seen], yhat[seen], std[seen])
    rows = np.flatnonzero(seen)
    kept = std[rows]
    out = np.empty(yhat.shape[1])
    _JIT.loglik(contiguous(y), contiguous(yhat), rows, -0.5 / (kept * kept), log_normaliser(kept), out)
    return out


def moments(a, w):
    """Weighted mean and std of each row of a (n, N), weights w (N,) summing to 1."""
    if a.shape[1] > SHORT:
        return _numpy.moments(a, w)
    mean, std = np.empty(a.shape[0]), np.empty(a.shape[0])
    _JIT.moments(contiguous(a), contiguous(w), mean, std)
    return mean, std


def weigh(yhat, y, std, logw, w, gauss=None):
    """The generic filter's weighing in one compiled pass: add log p(y | x) to
    ``logw`` in place (nothing when ``y`` is None; NaN entries not used) and
    give the predicted measurement's mean and std over the weights ``w``
    before the update, measurement noise ``std`` (n_y,) included. ``gauss``:
    :func:`gauss_terms` of ``y``'s pattern of sensors read and ``std``, when
    the caller keeps them."""
    n_y = yhat.shape[0]
    y_mean, y_std = np.empty(n_y), np.empty(n_y)
    if y is None:
        rows, weight, constant, variance, y = _NONE_READ + (std * std, np.empty(n_y))
    else:
        rows, weight, constant, variance = gauss_terms(np.isfinite(y), std) if gauss is None else gauss
    _JIT.weigh(contiguous(yhat), contiguous(y), rows, weight, constant, variance, logw, contiguous(w), y_mean,
               y_std)
    return y_mean, y_std


#: :func:`gauss_terms` of no sensor read, without the variance.
_NONE_READ = (np.empty(0, np.intp), np.empty(0), 0.0)


def gauss_terms(seen, std):
    """What :func:`weigh` needs of a pattern ``seen`` of sensors read (bool
    (n_y,)) and the noise std (n_y,): (the rows read, -1 / (2 std^2) of them,
    the sum of their log normalisers, std^2 of every sensor)."""
    rows = np.flatnonzero(seen)
    kept = std[rows]
    return rows, -0.5 / (kept * kept), log_normaliser(kept), std * std


def normalise(logw):
    """Normalise the log-weights in place: (logw, the effective sample size, the weights exp(logw))."""
    w = np.empty(logw.shape[0])
    ess = _JIT.normalise(logw, w)
    return logw, ess, w


def resample(x, w, uniform):
    """The particles x (n_x, N) resampled systematically from the weights ``w``
    with the uniform draw ``uniform``: a new array."""
    return _JIT.resample(contiguous(x), contiguous(w), float(uniform))


def draw(rng, rows, n):
    """Standard normal draws (rows, n) from ``rng``, in the order the NumPy
    kernel's :func:`perturb` draws them (a block of particles at a time),
    drawn by compiled code (numba's ``np.random.Generator``: NumPy's
    algorithm on the same bit generator, the same numbers, three times
    faster than NumPy's own loop on short arrays)."""
    out = np.empty((rows, n))
    for start, stop in spans(n)[0]:
        normal_into(rng, out, start, stop)
    return out


#: Generators' handles (:func:`generator_handle`) by id, each with its generator (kept alive with it).
_HANDLES = {}
#: Most generators whose handles are kept; beyond, the store is emptied and refilled.
_HANDLES_KEPT = 256


def generator_handle(rng):
    """What compiled code needs of the ``np.random.Generator`` ``rng`` to draw
    from it (its bit generator's ctypes interface: state, function
    pointers; uintp (6,)), read once per generator and kept; None for
    anything but a Generator (drawn by NumPy)."""
    kept = _HANDLES.get(id(rng))
    if kept is not None and kept[0] is rng:
        return kept[1]
    if not isinstance(rng, np.random.Generator):
        return None
    import ctypes

    face = rng.bit_generator.ctypes
    address = lambda f: ctypes.cast(f, ctypes.c_void_p).value  # noqa: E731
    handle = np.array([face.state_address, face.state.value, address(face.next_uint64),
                       address(face.next_uint32), address(face.next_double), face.bit_generator.value],
                      dtype=np.uintp)
    if len(_HANDLES) >= _HANDLES_KEPT:
        _HANDLES.clear()
    _HANDLES[id(rng)] = (rng, handle)
    return handle


def normal_into(rng, out, start=0, stop=None):
    """Standard normal draws from ``rng`` into the columns start..stop-1 of
    ``out`` (rows, N), as ``rng.standard_normal(out=...)`` of those columns
    would make them (compiled for an ``np.random.Generator``; any other
    generator is drawn by the generator itself)."""
    stop = out.shape[1] if stop is None else stop
    handle = generator_handle(rng)
    if handle is not None and out.dtype == np.float64 and out.flags.c_contiguous:
        _JIT.standard_normal(handle, out, start, stop)
    else:
        _numpy.normal_into(rng, out, start, stop)


def step_handle(x, rng):
    """The handle (:func:`generator_handle`) with which one compiled call
    makes a particle filter's step, or its end, on particles x: None when
    ``rng`` is no ``np.random.Generator``, x no C-contiguous float64 array or
    more than SHORT particles (the caller takes the separate steps)."""
    if x.dtype != np.float64 or not x.flags.c_contiguous or x.shape[1] > SHORT:
        return None
    return generator_handle(rng)


def finish(x, logw, threshold, rng):
    """The generic particle filter's end of a step in one compiled call:
    normalise ``logw`` in place, resample x (n_x, N) in place by
    :func:`resample` when the effective sample size is below ``threshold``
    (its uniform drawn from ``rng`` then only, as the NumPy filter draws
    it), and the particles' weighted moments: (logw, ess, resampled, the
    weights, mean, std). None where :func:`step_handle` is (the caller takes
    the separate steps)."""
    handle = step_handle(x, rng)
    if handle is None:
        return None
    w, mean, std = np.empty(logw.shape[0]), np.empty(x.shape[0]), np.empty(x.shape[0])
    ess, resampled = _JIT.finish(x, logw, w, float(threshold), handle, mean, std)
    return logw, ess, resampled, w, mean, std


def perturb(x, std, rng):
    """x += std[:, None] * N(0, 1), in place: the NumPy kernel's
    :func:`perturb` (the same numbers, the same arithmetic), its blocks
    drawn by :func:`normal_into`."""
    return _numpy.perturb(x, std, rng, normal_into)


#: log(2 pi), of the Gaussian log densities.
LOG_2PI = float(np.log(2.0 * np.pi))


def cubature_prepare(m, P, root, X, phys, extra, fixed, onset):
    """The cubature points m +- root chol(P) e_k of every cell (m (C, n), P
    (C, n, n)) into the physical rows ``phys`` of X (n_x, 2n C,
    C-contiguous, point p of cell c in column p C + c: the cells innermost,
    so the compiled loops over them are vector instructions), and each
    cell's fault states ``fixed`` (f, C; the magnitude last) into its
    points' rows ``extra``, the magnitude 0 in the cells of the slice
    ``onset`` (at their onset)."""
    n = m.shape[1]
    _JIT.cubature_prepare(contiguous(m), contiguous(P), float(root), X, phys, np.empty((n, n, m.shape[0])), extra,
                          contiguous(fixed), onset.start, onset.stop)


def cubature_after(X, phys, extra, fixed, inverse, scale, Q, root, onset):
    """After the prediction of the points X (:func:`cubature_prepare`'s
    layout): a drifting parameter read back into ``fixed`` (f, C,
    C-contiguous: in place), the predicted points' mean (n, C) and
    covariance (n, n, C, plus Q) and the update's points of that Gaussian in
    the same rows (mp, Pp, root chol(Pp), the cells innermost), and the cells
    of the slice ``onset`` given their magnitude in the update's points."""
    n = len(phys)
    C = X.shape[1] // (2 * n)
    mp, Pp, L = np.empty((n, C)), np.empty((n, n, C)), np.empty((n, n, C))
    _JIT.cubature_after(X, phys, extra, fixed, float(inverse), float(scale), Q, float(root), mp, Pp, L,
                        onset.start, onset.stop)
    return mp, Pp, L


def cubature_update(Y, rows, y, noise, L, inverse, mp, Pp):
    """Every cell's measurement update (the cubature Kalman filter's, from its
    points' measurements Y (n_y, 2n C) of the sensors ``rows`` read, y, their
    noise variances per cell (C, k), the points' root L and the prediction
    mp, Pp, as :func:`cubature_after` gives them): (loglik (C,), m (C, n),
    P (C, n, n), zk, yh, sd (C, k))."""
    n, C = mp.shape
    k = len(rows)
    loglik, m, P = np.empty(C), np.empty((C, n)), np.empty((C, n, n))
    zk, yh, sd = np.empty((C, k)), np.empty((C, k)), np.empty((C, k))
    _JIT.cubature_update(Y, rows, y, noise, L, float(inverse), mp, Pp, loglik, m, P, zk, yh, sd, LOG_2PI)
    return loglik, m, P, zk, yh, sd


def row_quadrature(values, logd, nodes, weights, panel_range, most_panels, wild):
    """``bgc.filters.quadrature.row_quadrature`` compiled, for a row of at least
    two rising points (the caller handles the rest), with its constants
    (Gauss-Legendre nodes and weights on [0, 1], the largest log range of a
    panel, the most panels, the neighbour a parabola ignores): (nodes, log
    masses)."""
    return _JIT.row_quadrature(contiguous(values), contiguous(logd), nodes, weights, float(panel_range),
                               int(most_panels), float(wild))
