"""Model-independent numerics of the compiled (numba) packages: the NumPy
kernel's functions, with the Gaussian log-likelihood compiled by numba (the
weighted moments stay NumPy's: a long sum is faster in BLAS than in a loop
that must add in order).

bgc copies this file unchanged into every ``numba_model`` package it
generates, as ``_kernel.py``, beside a copy of the NumPy kernel as
``kernel.py`` (its source is ``bgc/runtime/filters/kernel.py``); each
compiled model module imports it as ``from . import _kernel``. What is not
redefined here is the NumPy kernel's own function, so the two backends draw
the same random numbers in the same order (``perturb`` draws a block of
particles at a time from the caller's ``np.random.Generator``) and differ in
rounding only: a compiled loop adds the terms of a sum in its own order.

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

from .kernel import (
    BLOCK, block_views, gaussian_loglik_each, log_normaliser, moments, perturb, predictive_std, rk4, spans,
)

#: The kernel's functions: the NumPy kernel's, but the compiled ones defined here.
__all__ = ["BLOCK", "block_views", "contiguous", "gaussian_loglik", "gaussian_loglik_each", "load_jit",
           "log_normaliser", "moments", "perturb", "predictive_std", "rk4", "spans"]

_LOCK = threading.Lock()


def load_jit(near, file):
    """The module of compiled kernels ``file`` beside ``near`` (a module's
    ``__file__``), imported once per process under a name made from its
    path: numba's disk cache keeps the name of the module a kernel was
    compiled in, so every instance of a package (another noise level, or
    the package imported under another name) must use the one module of the
    file, whose name a later process gives it again."""
    path = os.path.realpath(os.path.join(os.path.dirname(os.path.abspath(near)), file))
    name = "bgc_jit_" + hashlib.sha256(path.encode("utf-8")).hexdigest()[:16] + "_" + file[:-3].lstrip("_")
    with _LOCK:
        module = sys.modules.get(name)
        if module is None:
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
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
    _JIT.loglik(y, contiguous(yhat), rows, -0.5 / (kept * kept), log_normaliser(kept), out)
    return out
