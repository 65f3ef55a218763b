"""Model-independent numerics of the compiled (numba) packages: the NumPy
kernel's functions, with the loops over particles that a filter step runs
most often compiled by numba.

bgc copies this file unchanged into every ``numba_model`` package it
generates, as ``_kernel.py``, beside a copy of the NumPy kernel as
``kernel.py`` (its source is ``bgc/runtime/filters/kernel.py``); each
compiled model module imports it as ``from . import _kernel``. What is not
redefined here is the NumPy kernel's own function, so the two backends draw
the same random numbers in the same order (``perturb`` draws a block of
particles at a time from the caller's ``np.random.Generator``) and differ in
rounding only: a compiled loop adds the terms of a sum in its own order.

Every compiled function takes C-contiguous float64 arrays (the wrappers copy
what is not) and works in place or into an ``out`` array; none reads a
module-level array (numba would freeze it as a constant), so a package
instance whose noise levels were changed after import computes with the new
ones. Compiled code is cached on disk beside the package (``cache=True``):
the first import of a package compiles, later processes load.
"""

import numpy as np
from numba import njit

from .kernel import (  # noqa: F401  (the NumPy kernel's functions are this kernel's too)
    BLOCK, block_views, gaussian_loglik_each, log_normaliser, perturb, predictive_std, rk4, spans,
)

#: numba options of every compiled kernel: cached on disk; float division by
#: zero gives inf or NaN as in NumPy instead of raising.
JIT = {"cache": True, "error_model": "numpy", "nogil": True}


def contiguous(a):
    """``a`` as a C-contiguous float64 array (``a`` itself when it is one)."""
    if isinstance(a, np.ndarray) and a.dtype == np.float64 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=np.float64)


@njit(**JIT)
def _loglik(y, yhat, rows, weight, constant, out):
    """out[i] = constant + sum_k weight[k] (yhat[rows[k], i] - y[rows[k]])^2."""
    n = yhat.shape[1]
    for i in range(n):
        s = 0.0
        for k in range(rows.shape[0]):
            d = yhat[rows[k], i] - y[rows[k]]
            s += d * d * weight[k]
        out[i] = s + constant


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
    _loglik(y, contiguous(yhat), rows, -0.5 / (kept * kept), log_normaliser(kept), out)
    return out


@njit(**JIT)
def _moments(a, w, mean, std):
    """Weighted mean and std of each row of a (n, N), weights w (N,)."""
    n, count = a.shape
    for j in range(n):
        m = 0.0
        for i in range(count):
            m += a[j, i] * w[i]
        v = 0.0
        for i in range(count):
            d = a[j, i] - m
            v += d * d * w[i]
        mean[j] = m
        std[j] = np.sqrt(max(v, 0.0))


def moments(a, w):
    """Weighted mean and std of each row of a (n, N), weights w (N,) summing to 1."""
    mean, std = np.empty(a.shape[0]), np.empty(a.shape[0])
    _moments(contiguous(a), contiguous(w), mean, std)
    return mean, std
