"""The hand-written filter of _handwritten_numpy.py compiled with numba: an estimate of the compiled limit.

Column (b) of bench/filter_speed.py; runs in bench/.venvs/numba (numba is not a
project dependency). Same equations (typed in by hand from
generated/ro/equations.txt), same RK4 with ``substeps`` substeps, same noise,
same systematic resampling when ESS < 0.5 N, same per-step outputs; particles
are an (N, n_x) array and every loop over particles is an ``@njit`` loop on
one thread (no ``parallel=True``: BLAS is pinned to one thread for every
column too). ``fastmath=True``: a limit may reassociate. The random draws come
from the same ``np.random.Generator`` (PCG64, ziggurat normals) as the NumPy
columns, passed into the compiled code (numba implements its methods; its
legacy ``np.random.standard_normal`` is 4x slower and would time the generator,
not the filter).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from _handwritten_numpy import (C_k, C_memb, C_res, F_back_offset, F_loop_offset, F_perm_offset, I_fp, I_rp, K0,
                                K_slope, OUTPUTS, P_memb_offset, R_brine, R_fp, R_memb, R_pipe, R_rp, STATES, k_scale,
                                m1, m2)

N_X = len(STATES)
N_Y = len(OUTPUTS)


@njit(inline="always", fastmath=True)
def derivative(f3, e6, e13, f22, e27, tau_fp, tau_rp):
    df3 = (-R_fp * f3 - e6 * m1 + tau_fp) / I_fp
    de6 = (f3 * m1 - (-e13 + e6 + f22 * m2) / R_pipe + (e13 - e6) / R_brine) / C_res
    de13 = ((-e13 + e6 + f22 * m2) / R_pipe - 29 * e13 / (R_memb * (29 + (-K0 + e27) / K_slope))
            - (e13 - e6) / R_brine) / C_memb
    df22 = (-R_rp * f22 + tau_rp - m2 * (-e13 + e6 + f22 * m2) / R_pipe) / I_rp
    de27 = k_scale * (0.1 + 6 * k_scale * (e13 - e6) / R_brine) * (-e13 + e6 + f22 * m2) / (C_k * R_pipe)
    return df3, de6, de13, df22, de27


@njit(inline="always", fastmath=True)
def observe(e6, e13, f22, e27):
    return (F_back_offset + (e13 - e6) / R_brine, F_loop_offset + (-e13 + e6 + f22 * m2) / R_pipe,
            F_perm_offset + 29 * e13 / (R_memb * (29 + (-K0 + e27) / K_slope)), P_memb_offset + e13)


@njit(cache=True, fastmath=True)
def _run(ys, us, n, rng, x0, x0_std, process_std, measurement_std, dt, substeps):
    T = ys.shape[0]
    h = dt / substeps
    x = np.empty((n, N_X))
    for i in range(n):
        for j in range(N_X):
            x[i, j] = x0[j] + x0_std[j] * rng.standard_normal()
    xnew = np.empty((n, N_X))
    yhat = np.empty((n, N_Y))
    logw = np.full(n, -np.log(n))
    w = np.exp(logw)
    means, stds = np.empty((T, N_X)), np.empty((T, N_X))
    y_means, y_stds, ess_all = np.empty((T, N_Y)), np.empty((T, N_Y)), np.empty(T)
    for k in range(T):
        tau_fp, tau_rp = us[k, 0], us[k, 1]
        for i in range(n):
            a, b, c, d, e = x[i, 0], x[i, 1], x[i, 2], x[i, 3], x[i, 4]
            for _ in range(substeps):
                k1 = derivative(a, b, c, d, e, tau_fp, tau_rp)
                k2 = derivative(a + h / 2 * k1[0], b + h / 2 * k1[1], c + h / 2 * k1[2], d + h / 2 * k1[3],
                                e + h / 2 * k1[4], tau_fp, tau_rp)
                k3 = derivative(a + h / 2 * k2[0], b + h / 2 * k2[1], c + h / 2 * k2[2], d + h / 2 * k2[3],
                                e + h / 2 * k2[4], tau_fp, tau_rp)
                k4 = derivative(a + h * k3[0], b + h * k3[1], c + h * k3[2], d + h * k3[3], e + h * k3[4],
                                tau_fp, tau_rp)
                a += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
                b += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
                c += h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
                d += h / 6 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3])
                e += h / 6 * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4])
            x[i, 0] = a + process_std[0] * rng.standard_normal()
            x[i, 1] = b + process_std[1] * rng.standard_normal()
            x[i, 2] = c + process_std[2] * rng.standard_normal()
            x[i, 3] = d + process_std[3] * rng.standard_normal()
            x[i, 4] = e + process_std[4] * rng.standard_normal()
            yy = observe(x[i, 1], x[i, 2], x[i, 3], x[i, 4])
            loglik = 0.0
            for j in range(N_Y):
                yhat[i, j] = yy[j]
                r = (ys[k, j] - yy[j]) / measurement_std[j]
                loglik -= 0.5 * r * r
            logw[i] += loglik
        # predicted measurement with the weights before the update
        for j in range(N_Y):
            m = 0.0
            for i in range(n):
                m += w[i] * yhat[i, j]
            v = 0.0
            for i in range(n):
                v += w[i] * (yhat[i, j] - m) ** 2
            y_means[k, j] = m
            y_stds[k, j] = np.sqrt(v + measurement_std[j] ** 2)
        # normalise, ESS
        mx = logw.max()
        s = 0.0
        for i in range(n):
            w[i] = np.exp(logw[i] - mx)
            s += w[i]
        ls = np.log(s)
        s2 = 0.0
        for i in range(n):
            w[i] /= s
            logw[i] -= mx + ls
            s2 += w[i] * w[i]
        ess = 1.0 / s2
        ess_all[k] = ess
        if ess < 0.5 * n:
            # systematic resampling: one uniform, two pointers
            u0 = rng.random()
            cum = w[0]
            j = 0
            for i in range(n):
                pos = (u0 + i) / n
                while cum < pos and j < n - 1:
                    j += 1
                    cum += w[j]
                for c_ in range(N_X):
                    xnew[i, c_] = x[j, c_]
            x, xnew = xnew, x
            for i in range(n):
                logw[i] = -np.log(n)
                w[i] = 1.0 / n
        for j in range(N_X):
            m = 0.0
            for i in range(n):
                m += w[i] * x[i, j]
            v = 0.0
            for i in range(n):
                v += w[i] * (x[i, j] - m) ** 2
            means[k, j] = m
            stds[k, j] = np.sqrt(v)
    return means, stds, y_means, y_stds, ess_all


def run(ys, us, n, seed, model):
    means, stds, y_means, y_stds, ess = _run(np.ascontiguousarray(ys), np.ascontiguousarray(us), n,
                                             np.random.default_rng(seed),
                                             model["x0"], model["x0_std"], model["process_std"],
                                             model["measurement_std"], float(model["dt"]), int(model["substeps"]))
    return {"mean": means, "std": stds, "y_mean": y_means, "y_std": y_stds, "ess": ess}
