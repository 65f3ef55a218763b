"""Compiled loops of the numba kernel (``_kernel.py``, its source
``bgc/runtime/filters/numba_kernel.py``): the Gaussian log-likelihood over
particles, the generic particle filter's weighing, normalising,
resampling and moments, each a loop over particles in one call, and the
cubature Kalman filter's arithmetic between the model's calls (points,
moments, measurement update), a loop over cells. Imports numpy and numba only; bgc copies it
unchanged into every compiled package (the same file name)."""

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: numba options: cached on disk beside this file; float division by zero gives inf or NaN as in NumPy.
JIT = {"cache": True, "error_model": "numpy", "nogil": True}

_GENERATOR = types.NumPyRandomGeneratorType("generator")
_BIT_GENERATOR = types.NumPyRandomBitGeneratorType("bit_generator")


@intrinsic
def generator(typingctx, handle):
    """numba's ``np.random.Generator`` of a bit generator's handle (uintp
    (6,): its ctypes interface's state address, state, next_uint64,
    next_uint32 and next_double function pointers and bit generator, as
    ``_kernel.generator_handle`` reads them): what numba builds when it is
    handed the Generator itself, without the five ctypes calls of that
    conversion (about 6 us a call, the time of two thousand draws). The
    Python object stays with the caller, who keeps it alive; it is not
    handed back (no parent, no reference count)."""

    def codegen(context, builder, signature, args):
        handle_array = context.make_array(signature.args[0])(context, builder, args[0])

        def item(i):
            return builder.load(cgutils.gep_inbounds(builder, handle_array.data, i))

        bits = cgutils.create_struct_proxy(_BIT_GENERATOR)(context, builder)  # zero-filled: no parent
        bits.state_address = item(0)
        bits.state = item(1)
        bits.fnptr_next_uint64 = item(2)
        bits.fnptr_next_uint32 = item(3)
        bits.fnptr_next_double = item(4)
        bits.bit_generator = item(5)
        made = cgutils.create_struct_proxy(_GENERATOR)(context, builder)  # no meminfo, no parent
        made.bit_generator = bits._getvalue()
        return made._getvalue()

    return _GENERATOR(handle), codegen


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
    in one pass, in its arithmetic: from the shift K (the first particle's
    prediction, 0 where that is not finite), d = yhat - K and r = K - y, the
    predicted measurement's mean K + E[d] and std sqrt(E[d^2] - E[d]^2 +
    ``variance``) over the weights ``w`` before the update, and, when ``rows``
    (the sensors read) is not empty, logw[i] += sum_k weight[k] d[k, i]^2, then
    += sum_k 2 weight[k] r[k] d[k, i], then += constant + sum_k weight[k] r[k]^2
    (a particle at +-inf gets NaN where the NumPy filter's does, and is recovered)."""
    n_y, n = yhat.shape
    shift = np.empty(n_y)
    for j in range(n_y):
        shift[j] = yhat[j, 0] if np.isfinite(yhat[j, 0]) else 0.0
        s1 = 0.0
        for i in range(n):
            s1 += (yhat[j, i] - shift[j]) * w[i]
        s2 = 0.0
        for i in range(n):
            d = yhat[j, i] - shift[j]
            s2 += d * d * w[i]
        y_mean[j] = shift[j] + s1
        y_std[j] = np.sqrt(max(s2 - s1 * s1, 0.0) + variance[j])
    k = rows.shape[0]
    if k == 0:
        return
    linear = np.empty(k)
    dot = 0.0
    for a in range(k):
        r = shift[rows[a]] - y[rows[a]]
        linear[a] = 2.0 * weight[a] * r
        dot += weight[a] * (r * r)
    total = constant + dot
    for i in range(n):
        square = 0.0
        cross = 0.0
        for a in range(k):
            d = yhat[rows[a], i] - shift[rows[a]]
            square += weight[a] * (d * d)
            cross += linear[a] * d
        logw[i] += square
        logw[i] += cross
        logw[i] += total


@njit(**JIT)
def standard_normal(handle, out, start, stop):
    """Standard normal draws from the ``np.random.Generator`` of ``handle``
    (:func:`generator`) into the columns start..stop-1 of ``out`` (rows, N),
    row by row: the numbers, and the generator's state after, of
    ``rng.standard_normal((rows, stop - start))`` (numba's Generator runs
    NumPy's algorithms on the same bit generator)."""
    rng = generator(handle)
    for j in range(out.shape[0]):
        for i in range(start, stop):
            out[j, i] = rng.standard_normal()


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
def finish(x, logw, w, threshold, handle, mean, std):
    """The generic particle filter's end of a step in one call: normalise
    the log-weights in place (their largest finite), the weights into
    ``w``; when the effective sample size is below ``threshold``, resample
    x (n_x, N) in place with a uniform drawn from the Generator of
    ``handle`` (then, and only then, as ``rng.random()``) and reset the
    weights to 1/N; the particles' weighted mean and std into mean, std.
    Gives (ess, resampled)."""
    ess = normalise(logw, w)
    resampled = ess < threshold
    if resampled:
        n_x, n = x.shape
        kept = resample(x, w, generator(handle).random())
        for j in range(n_x):
            for i in range(n):
                x[j, i] = kept[j, i]
        for i in range(n):
            logw[i] = -np.log(n)
            w[i] = 1.0 / n
    moments(x, w, mean, std)
    return ess, resampled


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


@njit(**JIT)
def cholesky_into(P, L):
    """The lower Cholesky factor of one covariance P (n, n) into L, column by
    column, each pivot under 1e-12 of its diagonal entry raised to that (the
    NumPy runtime's ``kalman.cholesky``, whose LAPACK factor it equals to
    rounding where P is positive definite)."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            L[i, j] = 0.0
    for j in range(n):
        pivot = P[j, j]
        for k in range(j):
            pivot -= L[j, k] * L[j, k]
        floor = 1e-12 * abs(P[j, j]) + 1e-300
        L[j, j] = np.sqrt(max(pivot, floor))
        for i in range(j + 1, n):
            s = P[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]


@njit(**JIT)
def cubature_points(m, P, root, X, phys, L):
    """The cubature points m +- root L e_k of N(m, P) of every cell c (m (C,
    n), P (C, n, n)) into the physical rows ``phys`` of X (n_x, C 2n), cell c
    in columns c 2n .. c 2n + 2n - 1; root L into L (C, n, n)."""
    C, n = m.shape
    for c in range(C):
        cholesky_into(P[c], L[c])
        for i in range(n):
            for k in range(n):
                L[c, i, k] *= root
        for i in range(n):
            row = phys[i]
            for k in range(n):
                X[row, c * 2 * n + k] = m[c, i] + L[c, i, k]
                X[row, c * 2 * n + n + k] = m[c, i] - L[c, i, k]


@njit(**JIT)
def cubature_moments(X, phys, inverse, scale, Q, mp, Pp):
    """Mean (C, n) and covariance (C, n, n) of every cell's predicted points
    (the physical rows ``phys`` of X, 2n points a cell), plus Q."""
    C, n = mp.shape
    D = np.empty((n, 2 * n))
    for c in range(C):
        for i in range(n):
            s = 0.0
            for p in range(2 * n):
                s += X[phys[i], c * 2 * n + p]
            mp[c, i] = s * inverse
            for p in range(2 * n):
                D[i, p] = (X[phys[i], c * 2 * n + p] - mp[c, i]) * scale
        for i in range(n):  # each sum once: D[i] D[j] and D[j] D[i] are the same products
            for j in range(i + 1):
                s = 0.0
                for p in range(2 * n):
                    s += D[i, p] * D[j, p]
                Pp[c, i, j] = s + Q[i, j]
                Pp[c, j, i] = s + Q[j, i]


@njit(**JIT)
def cubature_update(Y, rows, y, noise, L, inverse, mp, Pp, loglik, m, P, zk, yh, sd, log_2pi):
    """Every cell's measurement update from its points' measurements Y
    (n_y, C 2n), the sensors read ``rows`` with values y[rows] and noise
    variances ``noise`` (C, k), its points' root L (C, n, n) and prediction
    (mp, Pp): log p(y | the past) into loglik (C,), the mean and covariance
    after it into m, P, the normalised residuals, predicted measurement and
    its std of the sensors read into zk, yh, sd (C, k) (``kalman._Filter.step``)."""
    C, n = mp.shape
    k = rows.shape[0]
    DY = np.empty((k, 2 * n))
    S = np.empty((k, k))
    Ly = np.empty((k, k))
    rhs = np.empty((k, 1 + n))
    for c in range(C):
        for a in range(k):
            s = 0.0
            for p in range(2 * n):
                s += Y[rows[a], c * 2 * n + p]
            yh[c, a] = s * inverse
            for p in range(2 * n):
                DY[a, p] = Y[rows[a], c * 2 * n + p] - yh[c, a]
        for a in range(k):
            for b in range(a + 1):  # each sum once, as above
                s = 0.0
                for p in range(2 * n):
                    s += DY[a, p] * DY[b, p]
                S[a, b] = s * inverse
                S[b, a] = s * inverse
            S[a, a] += noise[c, a]
            rhs[a, 0] = y[rows[a]] - yh[c, a]
            for i in range(n):  # Pxy' = (DY+ - DY-) L' / 2n
                s = 0.0
                for p in range(n):
                    s += (DY[a, p] - DY[a, n + p]) * L[c, i, p]
                rhs[a, 1 + i] = s * inverse
        cholesky_into(S, Ly)
        for a in range(k):  # Ly^-1 rhs by forward substitution, in place
            for r in range(1 + n):
                s = rhs[a, r]
                for b in range(a):
                    s -= Ly[a, b] * rhs[b, r]
                rhs[a, r] = s / Ly[a, a]
        q = 0.0
        logdet = 0.0
        for a in range(k):
            q += rhs[a, 0] * rhs[a, 0]
            logdet += np.log(Ly[a, a])
            sd[c, a] = np.sqrt(S[a, a])
            zk[c, a] = (y[rows[a]] - yh[c, a]) / sd[c, a]
        loglik[c] = -0.5 * (q + 2.0 * logdet + k * log_2pi)
        for i in range(n):
            s = 0.0
            for a in range(k):
                s += rhs[a, 1 + i] * rhs[a, 0]
            m[c, i] = mp[c, i] + s
        for i in range(n):  # Pp - B'B, made symmetric against rounding as the NumPy runtime makes it
            for j in range(i + 1):
                s = 0.0
                for a in range(k):
                    s += rhs[a, 1 + i] * rhs[a, 1 + j]
                v = 0.5 * ((Pp[c, i, j] - s) + (Pp[c, j, i] - s))
                P[c, i, j] = v
                P[c, j, i] = v


@njit(**JIT)
def cubature_predicted(X, phys, inverse, scale, Q, root, mp, Pp, L):
    """:func:`cubature_moments` of the predicted points, then the update's
    points of N(mp, Pp) into the same rows of X (:func:`cubature_points`), in one call."""
    cubature_moments(X, phys, inverse, scale, Q, mp, Pp)
    cubature_points(mp, Pp, root, X, phys, L)
