"""Model-independent numerics of the generated models of a package (NumPy
only): in-place RK4, process noise, Gaussian log-likelihood and weighted
moments, on blocks of particles.

bgc copies this file unchanged into every package it generates, as
``_kernel.py`` (its source is ``bgc/filters/kernel.py``); each model
module imports it as ``from . import _kernel``.

Work is done on blocks of BLOCK to 2 * BLOCK particles (a run of N particles is
split evenly into max(1, N // BLOCK) blocks), in scratch arrays that are made
once per thread and block width and then reused: no large array is allocated
and freed per step (that costs page faults: the allocator hands big buffers
back to the system), temporaries stay in cache, and memory beyond the particle
array stays a few blocks. Scratch arrays are per thread, so filters may run in
several threads at once. rk4, perturb, moments and the filters' weighing share
one scratch buffer ("state"): what they leave in it is not valid after they
return. BLOCK balances the cost of a NumPy call (fewer, longer blocks are
faster) against that scratch memory (five state-sized blocks for RK4).
"""

import threading

import numpy as np

BLOCK = 6144

_scratch = threading.local()


def spans(n):
    """range(n) split into max(1, n // BLOCK) blocks whose sizes differ by at
    most one: ([(start, stop)], largest size)."""
    count = max(1, n // BLOCK)
    size, extra = divmod(n, count)
    parts, start = [], 0
    for i in range(count):
        stop = start + size + (i < extra)
        parts.append((start, stop))
        start = stop
    return parts, size + (extra > 0)


def block_views(name, count, rows, width):
    """A contiguous scratch array of shape (count, rows, width) of this thread:
    a view of one flat buffer per ``name``, made once and reused from call to
    call (contents undefined)."""
    views = getattr(_scratch, "views", None)
    if views is None:
        views = _scratch.views = {}
        _scratch.flat = {}
    key = (name, count, rows, width)
    view = views.get(key)
    if view is None:
        size = count * rows * width
        flat = _scratch.flat.get(name)
        if flat is None or flat.shape[0] < size:
            flat = _scratch.flat[name] = np.empty(size)
            for k in [k for k in views if k[0] == name]:
                del views[k]
        if len(views) > 64:
            views.clear()
        view = views[key] = flat[:size].reshape(count, rows, width)
    return view


def rk4(derivative, x, u, theta, dt, substeps, out=None, linear=None):
    """State after dt by classical RK4 with ``substeps`` substeps, for every
    particle (column) of x; ``out`` may be ``x`` itself (in place).
    ``derivative(x, u, theta, out, linear)`` writes dx/dt into ``out``;
    ``linear`` is handed through (the model's A, b, looked up once per call)."""
    if out is None:
        out = x.copy()
    elif out is not x:
        out[...] = x
    h = dt / substeps
    n_x, n = out.shape
    parts, _ = spans(n)
    weights = np.array([h / 6.0, h / 3.0, h / 3.0, h / 6.0])
    for start, stop in parts:
        w = stop - start
        ks = block_views("state", 5, n_x, w)
        k1, k2, k3, k4, s = ks
        stages = ks[:4].reshape(4, n_x * w)
        step = s.reshape(n_x * w)
        xb = out[:, start:stop]
        for _ in range(substeps):
            derivative(xb, u, theta, k1, linear)
            np.multiply(k1, 0.5 * h, out=s)
            s += xb
            derivative(s, u, theta, k2, linear)
            np.multiply(k2, 0.5 * h, out=s)
            s += xb
            derivative(s, u, theta, k3, linear)
            np.multiply(k3, h, out=s)
            s += xb
            derivative(s, u, theta, k4, linear)
            np.matmul(weights, stages, out=step)  # h/6 (k1 + 2 k2 + 2 k3 + k4)
            xb += s
    return out


def normal_into(rng, out, start=0, stop=None):
    """Standard normal draws from ``rng`` into the columns start..stop-1 of
    ``out`` (rows, N), row by row: ``rng.standard_normal(out=...)`` of those
    columns (a compiled kernel draws the same numbers faster)."""
    stop = out.shape[1] if stop is None else stop
    if start == 0 and stop == out.shape[1]:
        rng.standard_normal(out=out)
    else:
        out[:, start:stop] = rng.standard_normal((out.shape[0], stop - start))


def perturb(x, std, rng, normal=normal_into):
    """x += std[:, None] * N(0, 1), in place, drawing one block at a time
    (``normal``: what draws a block, :func:`normal_into` or a compiled
    kernel's, which draws the same numbers)."""
    n_x, n = x.shape
    scale = np.asarray(std, dtype=float)[:, None]
    parts, _ = spans(n)
    for start, stop in parts:
        buf = block_views("state", 1, n_x, stop - start)[0]  # contiguous, as rng needs
        normal(rng, buf)
        buf *= scale
        x[:, start:stop] += buf
    return x


def gaussian_loglik(y, yhat, std):
    """sum_j log N(y_j; yhat_j, std_j^2) for every particle (column of yhat),
    one block of particles at a time; NaN entries of y are not used. The terms
    are added output by output, in order, with elementwise operations: every
    column's sum is the same whatever the array's layout (a BLAS product may
    add them in another order for another layout or CPU). ``std``: (n_y,),
    or (n_y, N), a std per particle (a noise fault's model:
    :func:`gaussian_loglik_each`)."""
    y = np.asarray(y, dtype=float)
    std = np.asarray(std, dtype=float)
    seen = np.isfinite(y)
    if not seen.all():
        y, yhat, std = y[seen], yhat[seen], std[seen]
    if std.ndim == 2:
        return gaussian_loglik_each(y, yhat, std)
    n_y, n = yhat.shape
    weight = -0.5 / (std * std)
    total = np.empty(n)
    parts, _ = spans(n)
    column = y[:, None]
    for start, stop in parts:
        d = block_views("loglik", 1, n_y, stop - start)[0]
        np.subtract(yhat[:, start:stop], column, out=d)
        d *= d
        block = total[start:stop]
        block[:] = 0.0
        for j in range(n_y):
            d[j] *= weight[j]
            block += d[j]
    total += log_normaliser(std)
    return total


def gaussian_loglik_each(y, yhat, std):
    """gaussian_loglik with a std per particle, ``std`` (n_y, N) (every
    entry of y used): sum_j -(y_j - yhat_j)^2 / (2 std_j^2) - log std_j -
    log(2 pi) / 2, added output by output, in order."""
    n_y, n = yhat.shape
    total = np.full(n, -0.5 * n_y * np.log(2.0 * np.pi))
    for j in range(n_y):
        d = (yhat[j] - y[j]) / std[j]
        d *= d
        d *= -0.5
        total += d
        total -= np.log(std[j])
    return total


def predictive_std(observe, m, u, theta, process_std, measurement_std, fallback):
    """Std of the one-step predictive of y given noise-free predictions around
    the states ``m`` (n_x, F), one column per filter: the measurement noise
    plus the process noise seen through the outputs,

        sqrt(r_j^2 + sum_i ((h_j(m + q_i e_i) - h_j(m - q_i e_i)) / 2)^2),

    q_i the process std of state i: central differences over one std, the
    exact diag(H Q H') when h is linear, and the output's own slope where the
    plant runs now (a Jacobian at X0 misses the noise a product of states
    passes on when X0 is at rest). ``measurement_std``: (n_y,), or (n_y, F)
    one per column of m (a noise fault's model). (F, n_y); ``fallback``
    where that is not a number."""
    n_x, count = m.shape
    q = np.asarray(process_std, dtype=float)[:, None]
    x = np.repeat(m[:, :, None], 2 * n_x, axis=2)  # (n_x, F, 2 n_x): + q_i e_i, then - q_i e_i
    i = np.arange(n_x)
    x[i, :, i] += q
    x[i, :, n_x + i] -= q
    y = observe(x.reshape(n_x, count * 2 * n_x), u, theta).reshape(-1, count, 2, n_x)
    half = y[:, :, 0] - y[:, :, 1]
    half *= 0.5
    half *= half
    r = np.asarray(measurement_std, dtype=float)
    noise = r * r if r.ndim == 2 else (r * r)[:, None]
    std = np.sqrt(half.sum(axis=2) + noise).T
    bad = ~np.isfinite(std)
    if bad.any():
        std[bad] = np.broadcast_to(np.asarray(fallback, dtype=float), std.shape)[bad]
    return std


def log_normaliser(std):
    """log of the normalising constant of independent Gaussians of these stds:
    -n/2 log(2 pi) - sum(log std)."""
    return float(-0.5 * len(std) * np.log(2.0 * np.pi) - np.sum(np.log(std)))


def moments(a, w):
    """Weighted mean and std of each row of a (n, N), weights w (N,) summing to 1,
    centred one block of particles at a time."""
    mean = a @ w
    var = np.zeros(a.shape[0])
    parts, _ = spans(a.shape[1])
    column = mean[:, None]
    for start, stop in parts:
        d = block_views("state", 1, a.shape[0], stop - start)[0]
        np.subtract(a[:, start:stop], column, out=d)
        d *= d
        var += d @ w[start:stop]
    return mean, np.sqrt(np.maximum(var, 0.0))
