"""Compiled loops of the numba kernel (``_kernel.py``, its source
``bgc/filters/numba_kernel.py``): the Gaussian log-likelihood over
particles, the generic particle filter's weighing, normalising,
resampling and moments, each a loop over particles in one call, standard
normal draws from a generator's handle (:func:`generator`), the cubature
Kalman filter's arithmetic between the model's calls (points and fault
states, moments, measurement update), a loop over cells, and the static
posterior's quadrature of a grid row. A model's compiled step
(``_jit_<model>.py``) calls these loops too. Imports numpy and numba only;
bgc copies it unchanged into every compiled package (the same file name)."""

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
def cholesky_cells(P, L, pivot):
    """The lower Cholesky factor of every cell's covariance P (n, n, C: the
    cells innermost) into L (n, n, C), column by column, each pivot under
    1e-12 of its diagonal entry raised to that (the NumPy runtime's
    ``cubature.cholesky``, whose LAPACK factor it equals to rounding where P
    is positive definite). Each cell's arithmetic is that of one
    factorisation in the usual order; the loops run over the cells
    innermost, so the compiler makes them vector instructions. ``pivot``
    (C,): scratch."""
    n, _, C = P.shape
    for i in range(n):
        for j in range(i + 1, n):
            Lij = L[i, j]
            for c in range(C):
                Lij[c] = 0.0
    for j in range(n):
        Pjj, Ljj = P[j, j], L[j, j]
        for c in range(C):
            pivot[c] = Pjj[c]
        for k in range(j):
            Ljk = L[j, k]
            for c in range(C):
                pivot[c] -= Ljk[c] * Ljk[c]
        for c in range(C):
            Ljj[c] = np.sqrt(max(pivot[c], 1e-12 * abs(Pjj[c]) + 1e-300))
        for i in range(j + 1, n):
            Lij, Pij = L[i, j], P[i, j]
            for c in range(C):
                Lij[c] = Pij[c]
            for k in range(j):
                Lik, Ljk = L[i, k], L[j, k]
                for c in range(C):
                    Lij[c] -= Lik[c] * Ljk[c]
            for c in range(C):
                Lij[c] /= Ljj[c]


@njit(**JIT)
def cubature_points(m, P, root, X, phys, L, pivot):
    """The cubature points m +- root L e_k of N(m, P) of every cell c (m (n,
    C), P (n, n, C): the cells innermost) into the physical rows ``phys`` of
    X (n_x, 2n C), point p of cell c in column p C + c; root L into L (n, n,
    C). ``pivot`` (C,): scratch."""
    n, C = m.shape
    cholesky_cells(P, L, pivot)
    for i in range(n):
        for k in range(n):
            Lik = L[i, k]
            for c in range(C):
                Lik[c] *= root
    for i in range(n):
        row, mi = X[phys[i]], m[i]
        for k in range(n):
            Lik = L[i, k]
            for c in range(C):
                row[k * C + c] = mi[c] + Lik[c]
                row[(n + k) * C + c] = mi[c] - Lik[c]


@njit(**JIT)
def point_deviations(row, C, inverse, scale, mean, D):
    """The mean over its 2n points of every cell in ``row`` (2n C, point p
    of cell c at p C + c) into ``mean`` (C,), and each point's deviation from
    it times ``scale`` into D (2n, C)."""
    for c in range(C):
        mean[c] = 0.0
    for p in range(D.shape[0]):
        for c in range(C):
            mean[c] += row[p * C + c]
    for c in range(C):
        mean[c] *= inverse
    for p in range(D.shape[0]):
        Dp = D[p]
        for c in range(C):
            Dp[c] = (row[p * C + c] - mean[c]) * scale


@njit(**JIT)
def cubature_moments(X, phys, inverse, scale, Q, mp, Pp, D):
    """Mean (n, C) and covariance (n, n, C) of every cell's predicted points
    (the physical rows ``phys`` of X, 2n points a cell, the cells
    innermost), plus Q; D (n, 2n, C): scratch."""
    n, C = mp.shape
    for i in range(n):
        point_deviations(X[phys[i]], C, inverse, scale, mp[i], D[i])
    for i in range(n):  # each sum once: D[i] D[j] and D[j] D[i] are the same products
        for j in range(i + 1):
            Ppij, Ppji = Pp[i, j], Pp[j, i]
            for c in range(C):
                Ppij[c] = 0.0
            for p in range(2 * n):
                Dip, Djp = D[i, p], D[j, p]
                for c in range(C):
                    Ppij[c] += Dip[c] * Djp[c]
            qij, qji = Q[i, j], Q[j, i]
            for c in range(C):
                s = Ppij[c]
                Ppij[c] = s + qij
                Ppji[c] = s + qji


@njit(**JIT)
def cubature_update(Y, rows, y, noise, L, inverse, mp, Pp, loglik, m, P, zk, yh, sd, log_2pi):
    """Every cell's measurement update from its points' measurements Y
    (n_y, 2n C, point p of cell c in column p C + c), the sensors read
    ``rows`` with values y[rows] and noise variances ``noise`` (C, k), its
    points' root L (n, n, C) and prediction (mp (n, C), Pp (n, n, C)): log
    p(y | the past) into loglik (C,), the mean (C, n) and covariance (C, n,
    n) after it into m, P, the normalised residuals, predicted measurement
    and its std of the sensors read into zk, yh, sd (C, k)
    (``cubature._Filter.step``). Each cell's arithmetic is that of one filter
    in the usual order, the loops over the cells innermost."""
    n, C = mp.shape
    k = rows.shape[0]
    DY = np.empty((k, 2 * n, C))
    S = np.empty((k, k, C))
    Ly = np.empty((k, k, C))
    rhs = np.empty((k, 1 + n, C))
    yt = np.empty((k, C))
    acc = np.empty(C)
    for a in range(k):
        point_deviations(Y[rows[a]], C, inverse, 1.0, yt[a], DY[a])  # x 1.0: the deviations as they are
    for a in range(k):
        for b in range(a + 1):  # each sum once, as above
            for c in range(C):
                acc[c] = 0.0
            for p in range(2 * n):
                DYap, DYbp = DY[a, p], DY[b, p]
                for c in range(C):
                    acc[c] += DYap[c] * DYbp[c]
            Sab, Sba = S[a, b], S[b, a]
            for c in range(C):
                Sab[c] = acc[c] * inverse
                Sba[c] = acc[c] * inverse
        Saa, ya, yta, r0 = S[a, a], y[rows[a]], yt[a], rhs[a, 0]
        for c in range(C):
            Saa[c] += noise[c, a]
            r0[c] = ya - yta[c]
        for i in range(n):  # Pxy' = (DY+ - DY-) L' / 2n
            for c in range(C):
                acc[c] = 0.0
            for p in range(n):
                plus, minus, Lip = DY[a, p], DY[a, n + p], L[i, p]
                for c in range(C):
                    acc[c] += (plus[c] - minus[c]) * Lip[c]
            ri = rhs[a, 1 + i]
            for c in range(C):
                ri[c] = acc[c] * inverse
    cholesky_cells(S, Ly, acc)
    for a in range(k):  # Ly^-1 rhs by forward substitution, in place
        Lyaa = Ly[a, a]
        for r in range(1 + n):
            ra = rhs[a, r]
            for b in range(a):
                Lyab, rb = Ly[a, b], rhs[b, r]
                for c in range(C):
                    ra[c] -= Lyab[c] * rb[c]
            for c in range(C):
                ra[c] /= Lyaa[c]
    q = np.zeros(C)
    logdet = np.zeros(C)
    for a in range(k):
        ra, Lyaa, Saa, ya, yta = rhs[a, 0], Ly[a, a], S[a, a], y[rows[a]], yt[a]
        for c in range(C):
            q[c] += ra[c] * ra[c]
            logdet[c] += np.log(Lyaa[c])
            s = np.sqrt(Saa[c])
            sd[c, a] = s
            yh[c, a] = yta[c]
            zk[c, a] = (ya - yta[c]) / s
    for c in range(C):
        loglik[c] = -0.5 * (q[c] + 2.0 * logdet[c] + k * log_2pi)
    for i in range(n):
        for c in range(C):
            acc[c] = 0.0
        for a in range(k):
            rai, ra0 = rhs[a, 1 + i], rhs[a, 0]
            for c in range(C):
                acc[c] += rai[c] * ra0[c]
        mpi = mp[i]
        for c in range(C):
            m[c, i] = mpi[c] + acc[c]
    for i in range(n):  # Pp - B'B, made symmetric against rounding as the NumPy runtime makes it
        for j in range(i + 1):
            for c in range(C):
                acc[c] = 0.0
            for a in range(k):
                rai, raj = rhs[a, 1 + i], rhs[a, 1 + j]
                for c in range(C):
                    acc[c] += rai[c] * raj[c]
            Ppij, Ppji = Pp[i, j], Pp[j, i]
            for c in range(C):
                v = 0.5 * ((Ppij[c] - acc[c]) + (Ppji[c] - acc[c]))
                P[c, i, j] = v
                P[c, j, i] = v


@njit(**JIT)
def quadrature_interpolant(lg, i, t, wild):
    """``quadrature.row_quadrature``'s interpolant of the log density ``lg`` (a
    row) on interval i at t in [0, 1], in its arithmetic: the mean of the
    parabolas through the three points either side (a neighbour missing,
    -inf, or lying more than ``wild`` (|l1 - l0| + 1) below: the other one,
    else the line), -inf when an end of the interval is not finite."""
    l0, l1 = lg[i], lg[i + 1]
    if not (np.isfinite(l0) and np.isfinite(l1)):
        return -np.inf
    lm = lg[i - 1] if i > 0 else -np.inf
    lp = lg[i + 2] if i + 2 < lg.shape[0] else -np.inf
    own = wild * (abs(l1 - l0) + 1.0)
    has_left = np.isfinite(lm) and not (l0 - lm > own)
    has_right = np.isfinite(lp) and not (l1 - lp > own)
    left = l0 + (l1 - lm) / 2.0 * t + (l1 - 2.0 * l0 + lm) / 2.0 * t * t
    right = l0 + (l1 - l0) * t + (lp - 2.0 * l1 + l0) / 2.0 * (t * t - t)
    if has_left and has_right:
        return (left + right) / 2.0
    if has_left:
        return left
    if has_right:
        return right
    return l0 + (l1 - l0) * t


@njit(**JIT)
def row_quadrature(v, lg, nodes, weights, panel_range, most_panels, wild):
    """``quadrature.row_quadrature`` of a row of at least two points, ``v``
    evenly spaced and rising, in its arithmetic: the panels per interval
    from the interpolant's largest range over 9 probes of an interval whose
    probes are all finite, then Gauss-Legendre ``nodes`` and ``weights`` (on
    [0, 1]) on every panel of every interval: (nodes, log masses)."""
    n = v.shape[0]
    h = (v[n - 1] - v[0]) / (n - 1)
    spread = 0.0
    for i in range(n - 1):
        low, high, ok = np.inf, -np.inf, True
        for k in range(9):
            value = quadrature_interpolant(lg, i, k / 8.0, wild)
            if not np.isfinite(value):
                ok = False
                break
            low, high = min(low, value), max(high, value)
        if ok:
            spread = max(spread, high - low)
    panels = int(min(max(np.ceil(spread / panel_range), 1.0), most_panels))
    g = nodes.shape[0]
    per = panels * g
    ts, logw = np.empty(per), np.empty(per)
    for p in range(panels):
        for q in range(g):
            ts[p * g + q] = (p + nodes[q]) / panels
            logw[p * g + q] = np.log(weights[q] / panels * h)
    x, logm = np.empty((n - 1) * per), np.empty((n - 1) * per)
    for i in range(n - 1):
        for j in range(per):
            x[i * per + j] = v[i] + h * ts[j]
            logm[i * per + j] = quadrature_interpolant(lg, i, ts[j], wild) + logw[j]
    return x, logm


@njit(**JIT)
def cubature_prepare(m, P, root, X, phys, L, extra, fixed, onset_start, onset_stop):
    """:func:`cubature_points` of every cell (m (C, n), P (C, n, n), each
    cell's own row, turned here to the cells innermost), then each cell's
    fault states ``fixed`` (f, C; the magnitude last) into the rows
    ``extra`` of its points, the magnitude 0 in the cells onset_start ..
    onset_stop - 1 (at their onset: a nominal transition)
    (``cubature._Filter._predict_points``); X (n_x, 2n C), point p of cell c
    in column p C + c; L (n, n, C)."""
    C, n = m.shape
    mt = np.empty((n, C))
    Pt = np.empty((n, n, C))
    for c in range(C):
        for i in range(n):
            mt[i, c] = m[c, i]
            for j in range(n):
                Pt[i, j, c] = P[c, i, j]
    cubature_points(mt, Pt, root, X, phys, L, np.empty(C))
    f = extra.shape[0]
    for j in range(f):
        row, fj = X[extra[j]], fixed[j]
        for p in range(2 * n):
            for c in range(C):
                row[p * C + c] = fj[c]
        if j == f - 1:
            for p in range(2 * n):
                for c in range(onset_start, onset_stop):
                    row[p * C + c] = 0.0


@njit(**JIT)
def cubature_after(X, phys, extra, fixed, inverse, scale, Q, root, mp, Pp, L, onset_start, onset_stop):
    """After the prediction of the points X (n_x, 2n C, point p of cell c
    in column p C + c): a drifting parameter (the rows ``extra`` but the
    last) read back into ``fixed`` from each cell's first point,
    :func:`cubature_moments` (mp (n, C), Pp (n, n, C)), the update's points
    of N(mp, Pp) into the same rows (root chol(Pp) into L (n, n, C)), and the
    cells at their onset given their magnitude in the update's points
    (``cubature._Filter._compiled_step``)."""
    n, C = mp.shape
    f = extra.shape[0]
    for j in range(f - 1):
        row, fj = X[extra[j]], fixed[j]
        for c in range(C):
            fj[c] = row[c]
    cubature_moments(X, phys, inverse, scale, Q, mp, Pp, np.empty((n, 2 * n, C)))
    cubature_points(mp, Pp, root, X, phys, L, np.empty(C))
    if f > 0:
        row, fj = X[extra[f - 1]], fixed[f - 1]
        for p in range(2 * n):
            for c in range(onset_start, onset_stop):
                row[p * C + c] = fj[c]
