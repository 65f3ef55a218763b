"""The generated particle filters (generated/circuit/numpy_model/filters.py) against an exact oracle.

The circuit's nominal model is linear-Gaussian: its one-step map ``predict`` is affine
(x -> A x + b), its observation affine (x -> H x + c), the noises Gaussian. So the
Kalman filter written below is the exact posterior, and a particle filter must agree
with it up to Monte-Carlo error.

Monte-Carlo tolerance. At step k a weighted mean over particles with effective sample
size ESS_k adds a fresh error of covariance about P_k / ESS_k (P_k the posterior
covariance), and resampling adds at most P_k / N more (multinomial; systematic is
lower). Earlier errors are not forgotten at once: the filter carries them forward the
way the Kalman filter carries an error in its mean, through F_k = (I - K_k H) A. So the
Monte-Carlo error of the PF mean has covariance about
S_k = F_k S_k-1 F_k' + P_k (1 / ESS_k + 1 / N). With z_k = (pf_k - kf_k) / sqrt(diag S_k),
an unbiased filter has E|z_k| = sqrt(2/pi) ~ 0.8 if this error model is exact; it is an
approximation (it ignores the correlation resampling leaves between particles), so the
tests allow a time average of 2.5 per state, about 3x. A wrong filter is far outside:
the same statistic against a Kalman filter that assumes twice the measurement noise is
above 10, and the tests check it exceeds the tolerance.
"""

import importlib.util
import math
import sys
from functools import lru_cache

import numpy as np
import pytest

from bgc.filters import Filter
from bgc.filters.cubature import CubatureKalmanFilter

from conftest import ROOT

N_PARTICLES = 5000
STEPS = 100
DATA_SEED = 2024
TOLERANCE = 2.5
STD_TOLERANCE = 0.15


def load_package(model):
    d = ROOT / "generated" / model / "numpy_model"
    name = f"_bgc_filters_{model}"
    spec = importlib.util.spec_from_file_location(name, d / "__init__.py", submodule_search_locations=[str(d)])
    pkg = importlib.util.module_from_spec(spec)
    sys.modules[name] = pkg
    spec.loader.exec_module(pkg)
    return pkg


PKG = load_package("circuit")
MODEL = PKG.nominal
FILTERS = PKG.filters
GPF = FILTERS.GenericParticleFilter
APF = FILTERS.AuxiliaryParticleFilter
OPF = FILTERS.OptimalProposalParticleFilter
U = MODEL.inputs(0.0)


# ------------------------------------------------------------------ the oracle
@lru_cache(maxsize=None)
def linear_model():
    """A, b, H, c of the generated model, read off predict/observe at 0 and the unit vectors."""
    n = len(MODEL.STATES)
    basis = np.hstack([np.zeros((n, 1)), np.eye(n)])
    step = MODEL.predict(basis, U, MODEL.THETA, MODEL.DT)
    b = step[:, 0]
    a = step[:, 1:] - b[:, None]
    obs = MODEL.observe(basis, U, MODEL.THETA)
    c = obs[:, 0]
    h = obs[:, 1:] - c[:, None]
    return a, b, h, c


def test_the_circuit_model_is_affine():
    """What the oracle rests on: predict and observe are affine maps, to rounding."""
    a, b, h, c = linear_model()
    x = MODEL.X0[:, None] * (1 + np.random.default_rng(3).normal(0, 0.5, (3, 40)))
    np.testing.assert_allclose(MODEL.predict(x, U, MODEL.THETA, MODEL.DT), a @ x + b[:, None], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(MODEL.observe(x, U, MODEL.THETA), h @ x + c[:, None], rtol=1e-13, atol=1e-13)
    assert np.linalg.matrix_rank(h) == 3  # every state is seen: the posterior is proper


def simulate(steps=STEPS, seed=DATA_SEED):
    """Data from the same linear-Gaussian model, with numpy only (no generated sampler)."""
    a, b, h, c = linear_model()
    rng = np.random.default_rng(seed)
    x = MODEL.X0 + MODEL.X0_STD * rng.standard_normal(3)
    ys = np.empty((steps, 3))
    for k in range(steps):
        x = a @ x + b + MODEL.PROCESS_STD * rng.standard_normal(3)
        ys[k] = h @ x + c + MODEL.MEASUREMENT_STD * rng.standard_normal(3)
    return ys, np.tile(U, (steps, 1))


def kalman(ys, measurement_std=None):
    """Exact filter: x_k = A x_k-1 + b + w, y_k = H x_k + c + v; the first y is of x_1 (as the PFs)."""
    a, b, h, c = linear_model()
    q = np.diag(MODEL.PROCESS_STD ** 2)
    r = np.diag((MODEL.MEASUREMENT_STD if measurement_std is None else measurement_std) ** 2)
    m, p = MODEL.X0.copy(), np.diag(MODEL.X0_STD ** 2)
    out = {"mean": [], "cov": [], "gain_map": [], "y_mean": [], "y_std": [], "loglik": []}
    for y in ys:
        m, p = a @ m + b, a @ p @ a.T + q
        s = h @ p @ h.T + r
        k = np.linalg.solve(s, h @ p).T
        out["y_mean"].append(h @ m + c)
        out["y_std"].append(np.sqrt(np.diag(s)))
        v = y - h @ m - c
        out["loglik"].append(-0.5 * (v @ np.linalg.solve(s, v) + np.linalg.slogdet(2 * np.pi * s)[1]))
        m = m + k @ (y - h @ m - c)
        p = (np.eye(3) - k @ h) @ p
        p = 0.5 * (p + p.T)
        out["mean"].append(m)
        out["cov"].append(p)
        out["gain_map"].append((np.eye(3) - k @ h) @ a)
    out = {key: np.array(v) for key, v in out.items()}
    out["std"] = np.sqrt(np.einsum("kii->ki", out["cov"]))
    return out


def mc_std(kf, ess, n=N_PARTICLES):
    """Monte-Carlo std of a PF mean: S_k = F_k S_k-1 F_k' + P_k (1/ESS_k + 1/N) (module docstring)."""
    s = np.zeros((3, 3))
    out = []
    for f, p, e in zip(kf["gain_map"], kf["cov"], ess):
        s = f @ s @ f.T + p * (1.0 / e + 1.0 / n)
        out.append(np.sqrt(np.diag(s)))
    return np.array(out)


@lru_cache(maxsize=None)
def runs():
    ys, us = simulate()
    kf = kalman(ys)
    result = {}
    for cls, seed in ((GPF, 1), (APF, 2), (OPF, 3)):
        result[cls.__name__] = cls(MODEL, N_PARTICLES, np.random.default_rng(seed)).run(ys, us)
    return ys, kf, result


def test_kalman_oracle_is_consistent_with_its_data():
    """The oracle itself: its innovations are standard normal on the data it filters."""
    ys, kf, _ = runs()
    z = (ys - kf["y_mean"]) / kf["y_std"]
    assert abs(z.mean()) < 4 / math.sqrt(z.size) and abs(z.std() - 1) < 4 / math.sqrt(2 * z.size)


@pytest.mark.parametrize("name", ["GenericParticleFilter", "AuxiliaryParticleFilter",
                                  "OptimalProposalParticleFilter"])
def test_particle_filter_agrees_with_the_kalman_filter(name):
    ys, kf, result = runs()
    out = result[name]
    assert out.mean.shape == (STEPS, 3) and np.all(np.isfinite(out.mean))
    s = mc_std(kf, out.ess)
    z = np.abs(out.mean - kf["mean"]) / s
    z_ess = np.abs(out.mean - kf["mean"]) / (kf["std"] / np.sqrt(out.ess[:, None]))
    in_std = np.abs(out.mean - kf["mean"]) / kf["std"]
    ratio = out.std / kf["std"]
    print(f"\n{name}, N = {N_PARTICLES}, {STEPS} steps; ESS mean {out.ess.mean():.0f}, min {out.ess.min():.0f}")
    print(f"  |pf - kf| / MC std (propagated): mean {np.round(z.mean(0), 2)}, max {np.round(z.max(0), 2)}")
    print(f"  |pf - kf| / (kf std / sqrt ESS): mean {np.round(z_ess.mean(0), 2)}, max {np.round(z_ess.max(0), 2)}")
    print(f"  |pf - kf| / kf std:              mean {np.round(in_std.mean(0), 3)}, max {np.round(in_std.max(0), 3)}")
    print(f"  pf std / kf std:                 mean {np.round(ratio.mean(0), 3)}, "
          f"mean |ratio - 1| {np.round(np.abs(ratio - 1).mean(0), 3)}, max {np.round(np.abs(ratio - 1).max(0), 3)}")
    assert np.all(z.mean(axis=0) <= TOLERANCE), z.mean(axis=0)
    assert np.all(np.abs(ratio - 1).mean(axis=0) <= STD_TOLERANCE), np.abs(ratio - 1).mean(axis=0)
    # The tolerance has power: against a Kalman filter that assumes twice the measurement noise it fails.
    wrong = kalman(ys, 2.0 * MODEL.MEASUREMENT_STD)
    assert np.max(np.mean(np.abs(out.mean - wrong["mean"]) / s, axis=0)) > TOLERANCE


@pytest.mark.parametrize("name", ["GenericParticleFilter", "AuxiliaryParticleFilter",
                                  "OptimalProposalParticleFilter"])
def test_predicted_measurement_is_the_one_step_prediction(name):
    """y_mean / y_std are p(y_k | y_1:k-1), before y_k is used: the Kalman innovation mean and std."""
    ys, kf, result = runs()
    out = result[name]
    err = np.abs(out.y_mean - kf["y_mean"]) / kf["y_std"]
    print(f"\n{name}: |y_mean - kf predictive mean| / predictive std: mean {np.round(err.mean(0), 3)}")
    assert np.all(err.mean(axis=0) <= 0.1), err.mean(axis=0)
    np.testing.assert_allclose(out.y_std.mean(0), kf["y_std"].mean(0), rtol=0.05)


def test_auxiliary_filter_is_at_least_nearly_as_efficient_as_the_generic_one():
    """The point of the APF (thesis III.4.2). First-stage weights p(y | mu) with the measurement noise
    alone (ignoring the process noise, 2.5x larger on e4) give the circuit's APF about half the GPF's
    mean ESS and heavy-tailed second-stage weights; this is the test that catches it."""
    _, _, result = runs()
    gpf, apf = result["GenericParticleFilter"].ess, result["AuxiliaryParticleFilter"].ess
    print(f"\nmean ESS: GPF {gpf.mean():.0f}, APF {apf.mean():.0f}; min ESS: GPF {gpf.min():.0f}, APF {apf.min():.0f}")
    assert apf.mean() >= 0.8 * gpf.mean()


# ------------------------------------------------------------ robustness
def y_at_x0():
    return MODEL.observe(MODEL.X0[:, None], U, MODEL.THETA)[:, 0]


@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_far_outlier_keeps_the_estimate_finite(cls):
    """1e6 sigma: every p(y|x) underflows as a number (log p ~ -5e11), though not as a log-weight,
    so the filter need not reset; whatever it does, it returns finite numbers and goes on."""
    f = cls(MODEL, 1000, np.random.default_rng(0))
    r = f.step(y_at_x0() + 1e6 * MODEL.MEASUREMENT_STD, U)
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.std)) and np.isfinite(r.ess)
    assert 1.0 <= r.ess <= 1000.0 + 1e-9
    assert np.all(np.isfinite(f.x)) and np.all(np.isfinite(f.logw))
    r = f.step(y_at_x0(), U)  # and it goes on
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.std))


@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_all_weights_underflowing_is_recovered(cls):
    """A measurement so far off that every log-likelihood is -inf: weights reset, no NaN."""
    f = cls(MODEL, 1000, np.random.default_rng(0))
    with np.errstate(over="ignore", invalid="ignore"):
        r = f.step(y_at_x0() + 1e200, U)
    assert r.recovered and f.recoveries >= 1
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.std)) and r.ess == pytest.approx(1000)
    np.testing.assert_allclose(f.logw, -np.log(1000))
    assert np.all(np.isfinite(f.x))
    r = f.step(y_at_x0(), U)
    assert not r.recovered and np.all(np.isfinite(r.mean))


@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
@pytest.mark.parametrize("broken", ["some", "all"])
def test_nan_particles_are_recovered(cls, broken):
    f = cls(MODEL, 1000, np.random.default_rng(0))
    if broken == "some":
        f.x[:, :25] = np.nan
        f.x[1, 25:30] = np.inf
    else:
        f.x[:] = np.nan
    with np.errstate(invalid="ignore"):
        r = f.step(y_at_x0(), U)
    assert r.recovered and f.recoveries >= 1
    assert np.all(np.isfinite(f.x)) and np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.std))
    # The replacement particles are plausible: near the operating point.
    assert np.all(np.abs(r.mean - MODEL.X0) < 5 * MODEL.X0_STD + 3 * MODEL.PROCESS_STD)


@pytest.mark.parametrize("case", ["underflow", "nan"])
@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_one_bad_step_counts_one_recovery(cls, case):
    f = cls(MODEL, 1000, np.random.default_rng(0))
    y = y_at_x0()
    if case == "underflow":
        y = y + 1e200
    else:
        f.x[:, :25] = np.nan
    with np.errstate(over="ignore", invalid="ignore"):
        r = f.step(y, U)
    assert r.recovered
    assert f.recoveries == 1


# ------------------------------------------------------- missing measurements
@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_missing_measurement_skips_the_update(cls):
    f = cls(MODEL, 2000, np.random.default_rng(4), threshold=0.0)  # never resample after the update
    ys, us = simulate(3, seed=5)
    first = f.step(ys[0], us[0])
    assert first.ess < 0.9 * 2000  # the weights are not uniform, so "unchanged" says something
    before = f.logw.copy()
    x_before = f.x.copy()
    r = f.step(np.full(3, np.nan), us[1])
    np.testing.assert_allclose(f.logw, before, rtol=0, atol=1e-12)
    assert r.ess == pytest.approx(first.ess, rel=1e-12) and not r.resampled and not r.recovered
    assert not np.array_equal(f.x, x_before)  # the particles still moved (prediction)
    assert np.all(np.isfinite(r.mean))
    # With the default threshold a missing measurement resamples only if the ESS is already low.
    g = cls(MODEL, 2000, np.random.default_rng(4))
    g.step(ys[0], us[0])
    ess = FILTERS.normalise(g.logw)[1]
    r = g.step(np.full(3, np.nan), us[1])
    assert r.ess == pytest.approx(ess, rel=1e-12) and r.resampled == (ess < 0.5 * 2000)


def with_observe(patch):
    """MODEL with observe() followed by patch(yhat) (a copy of the module's namespace)."""
    import types

    m = types.SimpleNamespace(**{k: getattr(MODEL, k) for k in dir(MODEL) if not k.startswith("__")})

    def observe(x, u, theta, out=None):
        yhat = MODEL.observe(x, u, theta, out=out)
        patch(yhat)
        return yhat

    m.observe = observe
    return m


def test_gpf_update_ignores_a_broken_output_that_is_not_measured():
    """One particle's prediction of an output is inf while that output is not
    measured this step: the measured outputs still weigh every particle."""
    def patch(yhat):
        yhat[1, 0] = np.inf

    f = GPF(with_observe(patch), 1000, np.random.default_rng(0), threshold=0.0)
    y = y_at_x0() + 0.3 * MODEL.MEASUREMENT_STD
    y[1] = np.nan
    before = f.logw.copy()
    with np.errstate(invalid="ignore"):
        r = f.step(y, U)
    assert not r.recovered and f.recoveries == 0
    want, ess = FILTERS.normalise(before + manual_loglik(y, f.x))
    np.testing.assert_allclose(f.logw, want, rtol=0, atol=1e-10)
    assert r.ess == pytest.approx(ess, rel=1e-10)


@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_a_particle_whose_likelihood_is_nan_gets_no_weight(cls):
    """A particle whose prediction of a measured output is NaN (its state finite)
    is impossible, not a reason to throw the step's measurement away."""
    def patch(yhat):
        yhat[0, 0] = np.nan

    f = cls(with_observe(patch), 1000, np.random.default_rng(1), threshold=0.0)
    with np.errstate(invalid="ignore"):
        r = f.step(y_at_x0(), U)
    assert not r.recovered and f.recoveries == 0
    assert f.logw[0] == -np.inf and np.all(np.isfinite(f.logw[1:]))
    assert r.ess < 0.99 * 1000 and np.all(np.isfinite(r.mean))


@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_predicted_measurement_does_not_depend_on_how_far_y_is(cls):
    """The predicted measurement is a moment of the particles before the update
    (for the APF: before its first-stage selection, which y steers): an outlier
    in y (here up to 1e10 std away) does not change it."""
    ref = cls(MODEL, 500, np.random.default_rng(2)).step(y_at_x0(), U)
    for offset in (1e3, 1e6, 1e8):
        y = y_at_x0().copy()
        y[0] += offset
        with np.errstate(over="ignore", invalid="ignore"):
            r = cls(MODEL, 500, np.random.default_rng(2)).step(y, U)
        np.testing.assert_allclose(r.y_mean, ref.y_mean, rtol=1e-12)
        np.testing.assert_allclose(r.y_std, ref.y_std, rtol=1e-9)


def test_systematic_resample_accepts_float32_log_weights():
    logw = np.log(np.random.default_rng(3).dirichlet(np.ones(10)))
    a = FILTERS.systematic_resample(logw, np.random.default_rng(4))
    b = FILTERS.systematic_resample(logw.astype(np.float32), np.random.default_rng(4))
    assert b.shape == (10,) and np.count_nonzero(a != b) <= 1
    counts = FILTERS.offspring_counts(np.full(10, 0.1, dtype=np.float32), np.random.default_rng(5))
    assert counts.sum() == 10 and np.all(counts == 1)


def manual_loglik(y, x, std=None):
    """log prod_j N(y_j; h_j(x), sigma_j^2) over the finite y_j only, written out."""
    std = MODEL.MEASUREMENT_STD if std is None else std
    h = MODEL.observe(x, U, MODEL.THETA)
    total = np.zeros(x.shape[1])
    for j in range(len(y)):
        if math.isfinite(y[j]):
            sigma = std[j]
            total += -0.5 * math.log(2 * math.pi * sigma ** 2) - 0.5 * ((h[j] - y[j]) / sigma) ** 2
    return total


@pytest.mark.parametrize("missing", [(), (1,), (0, 2)])
def test_loglik_uses_only_the_finite_measurements(missing):
    x = MODEL.initial_particles(np.random.default_rng(6), 200)
    y = y_at_x0() + np.array([0.03, -0.07, 0.02])
    y[list(missing)] = np.nan
    np.testing.assert_allclose(MODEL.loglik(y, x, U, MODEL.THETA), manual_loglik(y, x), rtol=1e-12)
    np.testing.assert_allclose(MODEL.loglik_predictive(y, x, U, MODEL.THETA),
                               manual_loglik(y, x, MODEL.PREDICTIVE_STD), rtol=1e-12)


def test_partially_missing_measurement_updates_with_the_finite_entries():
    f = GPF(MODEL, 2000, np.random.default_rng(7), threshold=0.0)
    before = f.logw.copy()
    y = y_at_x0() + np.array([0.03, np.nan, 0.02])
    r = f.step(y, U)
    want, ess = FILTERS.normalise(before + manual_loglik(y, f.x))
    np.testing.assert_allclose(f.logw, want, rtol=0, atol=1e-10)
    assert r.ess == pytest.approx(ess, rel=1e-10) and not r.recovered
    # And differs from ignoring the measurement, or from using a made-up value for the missing one.
    assert not np.allclose(f.logw, before)
    filled = y.copy()
    filled[1] = y_at_x0()[1]
    assert not np.allclose(FILTERS.normalise(before + manual_loglik(filled, f.x))[0], f.logw)


# ------------------------------------------------------ resampling, weights
def weight_cases():
    rng = np.random.default_rng(8)
    cases = [np.full(10, 0.1), rng.dirichlet(np.ones(7)), rng.dirichlet(np.full(500, 0.05)),
             rng.dirichlet(np.full(1000, 5.0))]
    one = np.zeros(50)
    one[17] = 1.0
    cases.append(one)
    sparse = rng.dirichlet(np.ones(40))
    sparse[::3] = 0.0
    cases.append(sparse / sparse.sum())
    return cases


@pytest.mark.parametrize("w", weight_cases(), ids=["uniform", "dirichlet7", "spiky500", "flat1000", "one", "zeros"])
def test_systematic_resample_counts_are_floor_or_ceil_of_n_w(w):
    n = len(w)
    with np.errstate(divide="ignore"):
        logw = np.log(w) + 123.0  # unnormalised log-weights are accepted
    for seed in range(20):
        ancestors = FILTERS.systematic_resample(logw, np.random.default_rng(seed))
        assert ancestors.shape == (n,) and ancestors.min() >= 0 and ancestors.max() < n
        assert np.all(np.diff(ancestors) >= 0)
        counts = np.bincount(ancestors, minlength=n)
        assert np.all(np.abs(counts - n * w) < 1 + 1e-9), np.abs(counts - n * w).max()
        assert np.all(counts[w == 0] == 0)


def test_systematic_resample_equals_the_search_definition():
    """Ancestor j is the first i with c_i >= (j + U) / N (c the normalised
    cumulative weights, U the one uniform draw): the textbook definition by
    binary search, written here, against the generated O(N) counting version."""
    rng = np.random.default_rng(21)
    for n in (1, 2, 7, 200, 10_001):
        for _ in range(5):
            w = rng.dirichlet(np.full(n, 0.3)) if n > 1 else np.ones(1)
            u = np.random.default_rng(n).random()
            c = np.cumsum(w) / w.sum()
            want = np.minimum(np.searchsorted(c, (np.arange(n) + u) / n), n - 1)
            got = FILTERS.systematic_resample(np.log(w), np.random.default_rng(n))
            # the two may part only where a position meets a cumulative weight to rounding
            assert np.count_nonzero(got != want) <= 1, (n, np.flatnonzero(got != want)[:5])


@pytest.mark.parametrize("chunk", [1, 7, 8192])
def test_offspring_counts_in_place_equal_the_counts_of_the_search_definition(chunk):
    """The in-place counts (computed a chunk at a time in the weights' own
    memory) are the bincount of the ancestors of the search definition."""
    rng = np.random.default_rng(5)
    for n in (1, 3, 50, 1001):
        w = rng.dirichlet(np.full(n, 0.5)) if n > 1 else np.ones(1)
        if n > 4:
            w[::4] = 0.0  # some particles cannot be drawn
        w /= w.sum()
        u = np.random.default_rng(n + chunk).random()
        want = np.bincount(np.minimum(np.searchsorted(np.cumsum(w), (np.arange(n) + u) / n), n - 1), minlength=n)
        kept = w.copy()
        apart = FILTERS.offspring_counts(kept, np.random.default_rng(n + chunk), chunk=chunk)
        assert np.array_equal(kept, w)  # without overwrite the weights are left alone
        inplace = FILTERS.offspring_counts(w, np.random.default_rng(n + chunk), overwrite=True, chunk=chunk)
        assert apart.dtype == inplace.dtype == np.intp
        assert apart.sum() == n and np.array_equal(apart, inplace)
        assert np.count_nonzero(apart != want) <= 2  # a position on a cumulative weight, to rounding


def test_replicate_row_by_row_beyond_two_blocks_equals_np_repeat():
    """Beyond two blocks the filter resamples row by row in place; the result is
    np.repeat of the columns all the same."""
    from bgc.model.package import load_package

    pkg = load_package(ROOT / "generated", "ro")
    m = pkg.MODELS["nominal"]
    n = 2 * pkg._kernel.BLOCK + 5
    f = pkg.filters.GenericParticleFilter(m, n, np.random.default_rng(2))
    x = f.x.copy()
    counts = np.random.default_rng(3).multinomial(n, np.full(n, 1.0 / n))
    out = f._replicate(f.x, counts)
    assert out is f.x  # in place
    assert np.array_equal(out, np.repeat(x, counts, axis=1))


def test_systematic_resample_is_unbiased():
    w = np.array([0.05, 0.4, 0.15, 0.3, 0.1])
    draws = 4000
    rng = np.random.default_rng(9)
    total = np.zeros(5)
    for _ in range(draws):
        total += np.bincount(FILTERS.systematic_resample(np.log(w), rng), minlength=5)
    # Each count is floor or ceil of 5 w_i, so its std is at most 1/2.
    assert np.all(np.abs(total / draws - 5 * w) <= 4 * 0.5 / math.sqrt(draws))


@pytest.mark.parametrize("offset", [0.0, 800.0, -800.0])
def test_normalise_gives_weights_summing_to_one_and_the_ess(offset):
    rng = np.random.default_rng(10)
    logw = rng.normal(0, 3, 300) + offset
    logw[:5] = -np.inf
    out, ess = FILTERS.normalise(logw)
    finite = np.isfinite(logw)
    assert math.fsum(np.exp(out)) == pytest.approx(1.0, abs=1e-12)
    shift = out[finite] - logw[finite]
    np.testing.assert_allclose(shift, shift[0], rtol=0, atol=1e-9)  # ratios kept
    assert np.all(out[~finite] == -np.inf)
    top = max(logw)
    w = [math.exp(v - top) for v in logw]
    s = math.fsum(w)
    assert ess == pytest.approx(1.0 / math.fsum((v / s) ** 2 for v in w), rel=1e-12)
    assert FILTERS.normalise(np.full(64, offset))[1] == pytest.approx(64.0, rel=1e-12)
    one = np.full(64, -np.inf)
    one[3] = offset
    assert FILTERS.normalise(one)[1] == pytest.approx(1.0, rel=1e-12)


# ------------------------------------------------------------ step == run
@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_stepping_equals_run(cls):
    ys, us = simulate(30, seed=11)
    ys[7] = np.nan
    ys[12, 1] = np.nan
    a = cls(MODEL, 500, np.random.default_rng(12))
    out = a.run(ys, us)
    b = cls(MODEL, 500, np.random.default_rng(12))
    steps = [b.step(y, u) for y, u in zip(ys, us)]
    for key in ("mean", "std", "y_mean", "y_std", "ess", "resampled", "recovered"):
        got = np.array([getattr(s, key) for s in steps])
        assert got.tobytes() == getattr(out, key).astype(got.dtype).tobytes(), key
    assert np.array_equal(a.x, b.x) and np.array_equal(a.logw, b.logw)


@pytest.mark.parametrize("cls", [GPF, APF, OPF], ids=["GPF", "APF", "OPF"])
def test_a_step_on_particles_predicted_outside_is_the_same_step(cls):
    """step(predicted=True) after model.predict is step(): the same particles,
    weights and predicted measurement (the caller only moved the integration)."""
    ys, us = simulate(steps=3)
    a = cls(MODEL, 500, np.random.default_rng(9))
    b = cls(MODEL, 500, np.random.default_rng(9))
    for y, u in zip(ys, us):
        ra = a.step(y, u)
        MODEL.predict(b.x, u, MODEL.THETA, MODEL.DT, out=b.x)
        rb = b.step(y, u, predicted=True)
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.logw, b.logw)
        np.testing.assert_array_equal(ra.y_mean, rb.y_mean)
        np.testing.assert_array_equal(ra.y_std, rb.y_std)


# ------------------------------------------------------------ one protocol
@pytest.mark.parametrize("cls", [GPF, APF, OPF, CubatureKalmanFilter], ids=["GPF", "APF", "OPF", "CKF"])
def test_every_filter_meets_the_protocol_and_steps_one_sample(cls):
    """Built alike (model, particles, rng), stepped alike: one sample in, a
    StepResult out (state (n_x,), predicted measurement (n_y,)); run() is the
    same steps in order."""
    ys, us = simulate(5, seed=4)
    f = cls(MODEL, 300, np.random.default_rng(5))
    assert isinstance(f, Filter) and f.model is MODEL and f.recoveries == 0
    r = f.step(ys[0], us[0])
    assert type(r).__name__ == "StepResult"
    assert r.mean.shape == r.std.shape == (3,) and r.y_mean.shape == r.y_std.shape == (3,)
    assert np.isfinite(r.mean).all() and r.ess > 0 and not r.recovered
    out = cls(MODEL, 300, np.random.default_rng(5)).run(ys[:1], us[:1])
    np.testing.assert_array_equal(out.mean[0], r.mean)
    np.testing.assert_array_equal(out.y_std[0], r.y_std)


def test_the_cubature_kalman_filter_is_the_exact_kalman_filter_on_the_linear_circuit():
    """On an affine plant the cubature rule is exact: the CKF's means, stds,
    predicted measurements and log predictive densities are the oracle's
    (to rounding); it has no particles (ESS inf) and never resamples."""
    ys, kf, _ = runs()
    f = CubatureKalmanFilter(MODEL, N_PARTICLES, np.random.default_rng(0))
    steps = [f.step(y, U) for y in ys]
    for key in ("mean", "std", "y_mean", "y_std"):
        np.testing.assert_allclose(np.array([getattr(s, key) for s in steps]), kf[key], rtol=1e-9, err_msg=key)
    np.testing.assert_allclose([s.loglik for s in steps], kf["loglik"], rtol=1e-9)
    np.testing.assert_allclose(f.cov, kf["cov"][-1], rtol=1e-9, atol=1e-12 * np.abs(kf["cov"][-1]).max())
    assert all(s.ess == math.inf and not s.resampled and not s.recovered for s in steps)
    # the comparison has power: against the oracle with twice the measurement noise it fails
    wrong = kalman(ys, 2.0 * MODEL.MEASUREMENT_STD)
    assert not np.allclose(np.array([s.mean for s in steps]), wrong["mean"], rtol=1e-3)


def test_the_cubature_kalman_filter_predicts_over_the_interval_it_is_given():
    """dt: a step without measurements moves the mean by the model's own
    (affine) step over dt, and adds nothing to the log-likelihood."""
    f = CubatureKalmanFilter(MODEL)
    f.mean = m = MODEL.X0 * np.array([1.3, 0.6, 1.1])  # off the equilibrium X0, so the state moves
    r = f.step(np.full(3, np.nan), U, dt=MODEL.DT / 2)
    np.testing.assert_allclose(r.mean, MODEL.predict(m[:, None], U, MODEL.THETA, MODEL.DT / 2)[:, 0], rtol=1e-12)
    assert r.loglik == 0.0 and np.isnan(r.y_mean).all()
    assert not np.allclose(r.mean, MODEL.predict(m[:, None], U, MODEL.THETA, MODEL.DT)[:, 0], rtol=1e-6)
