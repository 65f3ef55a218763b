"""Compiled loops of the numba kernel (``_kernel.py``, its source
``bgc/runtime/filters/numba_kernel.py``): the Gaussian log-likelihood over
particles, and the generic particle filter's weighing, normalising,
resampling and moments, each a loop over particles in one call. Imports numpy and numba only; bgc copies it
unchanged into every compiled package (the same file name)."""

import numpy as np
from numba import njit

#: numba options: cached on disk beside this file; float division by zero gives inf or NaN as in NumPy.
JIT = {"cache": True, "error_model": "numpy", "nogil": True}


@njit(**JIT)
def loglik(y, yhat, rows, weight, constant, out):
    """out[i] = constant + sum_k weight[k] (yhat[rows[k], i] - y[rows[k]])^2."""
    n = yhat.shape[1]
    for i in range(n):
        s = 0.0
        for k in range(rows.shape[0]):
            d = yhat[rows[k], i] - y[rows[k]]
            s += d * d * weight[k]
        out[i] = s + constant


@njit(**JIT)
def weigh(yhat, y, rows, weight, constant, variance, logw, w, y_mean, y_std):
    """The generic particle filter's weighing (``particle.GenericParticleFilter._weigh``)
    in one pass: the predicted measurement's mean and std over the weights
    ``w`` before the update (moments taken from the first particle's
    prediction, as there), ``variance`` the measurement noise's, and, when
    ``rows`` is not empty, logw[i] += constant + sum_k weight[k] (yhat[rows[k], i] - y[rows[k]])^2."""
    n_y, n = yhat.shape
    for j in range(n_y):
        shift = yhat[j, 0]
        if not np.isfinite(shift):
            shift = 0.0
        s1 = 0.0
        for i in range(n):
            s1 += (yhat[j, i] - shift) * w[i]
        s2 = 0.0
        for i in range(n):
            d = yhat[j, i] - shift
            s2 += d * d * w[i]
        y_mean[j] = shift + s1
        y_std[j] = np.sqrt(max(s2 - s1 * s1, 0.0) + variance[j])
    if rows.shape[0] == 0:
        return
    for i in range(n):
        s = 0.0
        for k in range(rows.shape[0]):
            d = yhat[rows[k], i] - y[rows[k]]
            s += d * d * weight[k]
        logw[i] += s + constant


@njit(**JIT)
def normalise(logw, w):
    """Normalise the log-weights in place, the weights exp(logw) into ``w``;
    the effective sample size 1 / sum(w^2) (``particle._normalise``)."""
    n = logw.shape[0]
    top = -np.inf
    for i in range(n):
        if logw[i] > top:
            top = logw[i]
    total = 0.0
    for i in range(n):
        w[i] = np.exp(logw[i] - top)
        total += w[i]
    squares = 0.0
    for i in range(n):
        w[i] /= total
        squares += w[i] * w[i]
    shift = top + np.log(total)
    for i in range(n):
        logw[i] -= shift
    return 1.0 / squares


@njit(**JIT)
def resample(x, w, uniform):
    """The particles after systematic resampling with the uniform draw
    ``uniform``: column i of x repeated as often as ``particle.offspring_counts``
    says (the same arithmetic), in a new array."""
    n_x, n = x.shape
    out = np.empty((n_x, n))
    total = 0.0
    for i in range(n):
        total += w[i]
    scale = n / total
    cumulative = 0.0
    before = -1.0
    at = 0
    for i in range(n):
        cumulative += w[i]
        k = float(n - 1) if i == n - 1 else min(np.floor(cumulative * scale - uniform), float(n - 1))
        for _ in range(int(k - before)):
            for j in range(n_x):
                out[j, at] = x[j, i]
            at += 1
        before = k
    return out


@njit(**JIT)
def moments(a, w, mean, std):
    """Weighted mean and std of each row of a (rows, N), weights w (N,)."""
    rows, n = a.shape
    for j in range(rows):
        m = 0.0
        for i in range(n):
            m += a[j, i] * w[i]
        v = 0.0
        for i in range(n):
            d = a[j, i] - m
            v += d * d * w[i]
        mean[j] = m
        std[j] = np.sqrt(max(v, 0.0))
