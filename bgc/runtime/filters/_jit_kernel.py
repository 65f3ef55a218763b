"""Compiled loops of the numba kernel (``_kernel.py``, its source
``bgc/runtime/filters/numba_kernel.py``): the Gaussian log-likelihood over
particles. Imports numpy and numba only; bgc copies it
unchanged into every compiled package (the same file name)."""

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
