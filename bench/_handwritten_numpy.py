"""Hand-written bootstrap particle filter of the RO plant, written the natural first way.

Column (a) of bench/filter_speed.py. Particles are an (N, n_x) array, the
derivative unpacks columns and rebuilds its result with ``np.stack``. The
equations are typed in by hand from generated/ro/equations.txt (this module
does not import the generated code); the discretisation is the generated one:
classical RK4 with ``substeps`` substeps per sample, process noise added once
per sample, Gaussian measurement noise, systematic resampling when
ESS < 0.5 N. The noise levels, prior and substeps arrive as numbers in the data
file (taken there from the generated tables, so all filters share them).

Per step it records what the generated GPF records: weighted mean and std of
the state, predicted measurement mean and std, the ESS.
"""

from __future__ import annotations

import numpy as np

STATES = ("f3", "e6", "e13", "f22", "e27")
OUTPUTS = ("F_back", "F_loop", "F_perm", "P_memb")

# parameters theta, from generated/ro/equations.txt
C_k = 565.0
C_memb = 0.6
C_res = 1.5
I_fp = 0.1
I_rp = 2.0
K0 = 12000.0
K_slope = 165.0
R_brine = 220.0
R_fp = 0.1
R_memb = 26.0
R_pipe = 69.0
R_rp = 0.1
k_scale = 3.46
m1 = 1.0
m2 = 1.0
F_back_offset = 0.0  # the sensors' offsets (the bias and drift faults' parameters), 0 in the nominal model
F_loop_offset = 0.0
F_perm_offset = 0.0
P_memb_offset = 0.0
PARAMETERS = {"C_k": C_k, "C_memb": C_memb, "C_res": C_res, "I_fp": I_fp, "I_rp": I_rp, "K0": K0,
              "K_slope": K_slope, "R_brine": R_brine, "R_fp": R_fp, "R_memb": R_memb, "R_pipe": R_pipe,
              "R_rp": R_rp, "k_scale": k_scale, "m1": m1, "m2": m2, "F_back_offset": F_back_offset,
              "F_loop_offset": F_loop_offset, "F_perm_offset": F_perm_offset, "P_memb_offset": P_memb_offset}


def derivative(x, u):
    f3, e6, e13, f22, e27 = x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4]
    tau_fp, tau_rp = u[0], u[1]
    df3 = (-R_fp * f3 - e6 * m1 + tau_fp) / I_fp
    de6 = (f3 * m1 - (-e13 + e6 + f22 * m2) / R_pipe + (e13 - e6) / R_brine) / C_res
    de13 = ((-e13 + e6 + f22 * m2) / R_pipe - 29 * e13 / (R_memb * (29 + (-K0 + e27) / K_slope))
            - (e13 - e6) / R_brine) / C_memb
    df22 = (-R_rp * f22 + tau_rp - m2 * (-e13 + e6 + f22 * m2) / R_pipe) / I_rp
    de27 = k_scale * (0.1 + 6 * k_scale * (e13 - e6) / R_brine) * (-e13 + e6 + f22 * m2) / (C_k * R_pipe)
    return np.stack([df3, de6, de13, df22, de27], axis=1)


def observe(x):
    e6, e13, f22, e27 = x[:, 1], x[:, 2], x[:, 3], x[:, 4]
    F_back = F_back_offset + (e13 - e6) / R_brine
    F_loop = F_loop_offset + (-e13 + e6 + f22 * m2) / R_pipe
    F_perm = F_perm_offset + 29 * e13 / (R_memb * (29 + (-K0 + e27) / K_slope))
    P_memb = P_memb_offset + e13
    return np.stack([F_back, F_loop, F_perm, P_memb], axis=1)


def mismatch(nominal, rng, n=1000):
    """The largest relative difference between this module's equations and the generated
    ``nominal`` module's (generated/ro/numpy_model/nominal.py) at ``n`` random states around
    its X0 (10 prior stds) and random inputs (the default ones times 0.5 to 1.5): derivative,
    observe and one RK4 step. About 1e-15 when the hand-typed equations are the shipped
    model's; the caller passes the module, so this one does not import the generated code.
    """
    if (STATES, OUTPUTS) != (tuple(nominal.STATES), tuple(nominal.OUTPUTS)):
        return np.inf
    if dict(zip(nominal.PARAMETERS, nominal.THETA)) != PARAMETERS:
        return np.inf
    x = nominal.X0 + 10 * nominal.X0_STD * rng.standard_normal((n, len(STATES)))
    u = nominal.inputs(0.0) * rng.uniform(0.5, 1.5, 2)
    theta = nominal.THETA
    pairs = [(derivative(x, u), nominal.derivative(x.T.copy(), u, theta).T),
             (observe(x), nominal.observe(x.T.copy(), u, theta).T),
             (rk4(x, u, nominal.DT, nominal.SUBSTEPS), nominal.predict(x.T.copy(), u, theta, nominal.DT).T)]
    return max(float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12 * np.max(np.abs(b), axis=0)))) for a, b in pairs)


def rk4(x, u, dt, substeps):
    h = dt / substeps
    for _ in range(substeps):
        k1 = derivative(x, u)
        k2 = derivative(x + h / 2 * k1, u)
        k3 = derivative(x + h / 2 * k2, u)
        k4 = derivative(x + h * k3, u)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def systematic_resample(w, rng):
    n = len(w)
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(w)
    cumulative[-1] = 1.0
    return np.searchsorted(cumulative, positions)


def run(ys, us, n, seed, model):
    """Filter the record; model: dict of x0, x0_std, process_std, measurement_std, dt, substeps."""
    rng = np.random.default_rng(seed)
    T = len(ys)
    x = model["x0"] + model["x0_std"] * rng.standard_normal((n, len(STATES)))
    logw = np.full(n, -np.log(n))
    w = np.exp(logw)
    means, stds = np.empty((T, len(STATES))), np.empty((T, len(STATES)))
    y_means, y_stds, ess_all = np.empty((T, len(OUTPUTS))), np.empty((T, len(OUTPUTS))), np.empty(T)
    sigma_y = model["measurement_std"]
    for k in range(T):
        x = rk4(x, us[k], model["dt"], model["substeps"])
        x = x + model["process_std"] * rng.standard_normal((n, len(STATES)))
        yhat = observe(x)
        y_means[k] = w @ yhat
        y_stds[k] = np.sqrt(w @ (yhat - y_means[k]) ** 2 + sigma_y ** 2)
        loglik = -0.5 * np.sum(((ys[k] - yhat) / sigma_y) ** 2, axis=1)
        logw = logw + loglik
        logw = logw - logw.max()
        w = np.exp(logw)
        s = w.sum()
        w = w / s
        logw = logw - np.log(s)
        ess = 1.0 / np.sum(w ** 2)
        if ess < 0.5 * n:
            x = x[systematic_resample(w, rng)]
            logw = np.full(n, -np.log(n))
            w = np.exp(logw)
        means[k] = w @ x
        stds[k] = np.sqrt(w @ (x - means[k]) ** 2)
        ess_all[k] = ess
    return {"mean": means, "std": stds, "y_mean": y_means, "y_std": y_stds, "ess": ess_all}
