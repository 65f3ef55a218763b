"""The cubature Kalman filter bank and the static posterior of a fault
hypothesis (bgc/filters/cubature.py), against references derived here:

- on the two tanks (linear in their states once the fault is fixed), a
  Kalman filter written out in matrices, with the RK4 map of the plant's
  equations derived by hand (the tanks' mass balances), must give the same
  log-likelihoods and states;
- the adaptive grid's posterior and evidence against brute-force quadrature
  on a fine grid of those exact Kalman filters;
- on the RO plant (mildly nonlinear), the posterior mean of the R_pipe bias
  against a particle-filter (pseudo-marginal) grid on the same data.
"""

import dataclasses
import math
import sys

import numpy as np
import pytest

from bgc.filters import cubature as kalman
from bgc.diagnosis import static_posterior
from bgc.filters import quadrature
from bgc.data import runs
from bgc.analysis import simulate
from bgc.model import package as packages
from bgc.analysis import track
from bgc.filters.cubature import cholesky
from bgc.diagnosis.static_posterior import onset_widths
from bgc.diagnosis.options import KalmanOptions

from conftest import ROOT, compiled, fast_session, tank_map

GENERATED = ROOT / "generated"


def data(model: str, scenario: str, seed: int):
    c = compiled(model)
    result = simulate.simulate(c.numerics, simulate.SimulationOptions(
        seed=seed, fault=simulate.parse_fault(scenario, c.numerics) if scenario != "none" else None))
    run = runs.parse_run(simulate.to_csv(result), scenario)
    package = packages.load_package(GENERATED, model)
    ys, us = track.run_arrays(run, package, "nominal")
    return package, ys, us


def kalman_filter(ys, m, P, maps, Q, R):
    """The textbook Kalman filter (predict x' = M x + c + w, observe y = H x +
    v): log p(y_0 .. y_(T-1)), final mean and covariance. ``maps[k]``: (M, c,
    H) of step k."""
    total = 0.0
    for y, (M, c, H) in zip(ys, maps):
        m = M @ m + c
        P = M @ P @ M.T + Q
        S = H @ P @ H.T + R
        v = y - H @ m
        total += -0.5 * (v @ np.linalg.solve(S, v) + np.linalg.slogdet(S)[1] + len(y) * math.log(2 * math.pi))
        K = P @ H.T @ np.linalg.inv(S)
        m = m + K @ v
        P = P - K @ S @ K.T
    return total, m, P


def test_cholesky_of_a_stack_is_numpys():
    rng = np.random.default_rng(0)
    G = rng.standard_normal((40, 6, 6))
    P = G @ G.transpose(0, 2, 1) + 0.1 * np.eye(6)
    L = cholesky(P)
    assert np.allclose(L @ L.transpose(0, 2, 1), P, rtol=1e-12, atol=1e-12)
    assert np.all(np.triu(L, 1) == 0.0) and np.all(np.diagonal(L, axis1=1, axis2=2) > 0)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_cholesky_is_numpys_to_the_bit_and_numpys_fallback_where_lapack_fails(n):
    """The stack's factors, written out for n <= 2 (:func:`cubature._cholesky_2`),
    are np.linalg.cholesky's bit for bit, over covariances of scales 1e-8 to
    1e8; in a stack with a matrix LAPACK refuses, a NaN or an inf, each is
    what NumPy, or else the column-by-column factoring, gives."""
    rng = np.random.default_rng(n)
    G = rng.standard_normal((4000, n, n)) * 10.0 ** rng.uniform(-4, 4, (4000, 1, 1))
    P = G @ G.transpose(0, 2, 1)
    P = np.tril(P) + np.tril(P, -1).transpose(0, 2, 1)  # exactly symmetric
    assert np.array_equal(cholesky(P), np.linalg.cholesky(P))
    assert np.array_equal(cholesky(P[:1]), np.linalg.cholesky(P[:1]))
    for spoilt in (-1.0, np.nan, np.inf):
        for row, col in ((0, 0), (n - 1, 0), (n - 1, n - 1)):
            Q = P[:20].copy()
            Q[2, row, col] = spoilt
            try:
                reference = np.linalg.cholesky(Q)
            except np.linalg.LinAlgError:
                alone = cholesky(np.stack([Q[0], Q[2]]))[1]  # the fallback's factor of that matrix
                assert np.array_equal(cholesky(Q)[2], alone, equal_nan=True)
                continue
            assert np.array_equal(cholesky(Q), reference, equal_nan=True)


def test_a_covariance_made_indefinite_by_rounding_still_factors():
    good = np.array([[4.0, 2.0], [2.0, 3.0]])  # L = [[2, 0], [1, sqrt(2)]]
    bad = np.array([[1.0, 1.0], [1.0, 1.0 - 1e-15]])  # the second pivot is -1e-15: LAPACK refuses it
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(bad)
    L = cholesky(np.stack([good, bad]))
    assert np.all(np.isfinite(L)) and L[1, 1, 1] > 0
    assert np.allclose(L[0], [[2.0, 0.0], [1.0, math.sqrt(2.0)]], rtol=0.0, atol=1e-15)  # the stack's others exact
    assert np.allclose(L[1] @ L[1].T, bad, rtol=0.0, atol=1e-11)  # a nearby matrix's factor


# The grid posterior against closed forms: a likelihood known in closed form
# (a Gaussian in the magnitude, or in a drift's change) stands in for the
# Kalman filters, so the grid's quadrature, its passes and its handling of
# the prior's bounds are checked alone. References: the truncated normal's
# moments, quantiles and mass, in 800-digit arithmetic (mpmath).

def truncated_normal(mu, sd, a, b, level=0.95):
    """Mean, std, central interval and log of the integral of exp(-(x -
    mu)^2 / (2 sd^2)) over [a, b], from Phi and its inverse."""
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 800  # a bound 30 stds from the peak leaves a mass of 1e-196 to take differences of
    mu, sd, a, b = (mp.mpf(v) for v in (mu, sd, a, b))
    al, be = (a - mu) / sd, (b - mu) / sd
    Z = mp.ncdf(be) - mp.ncdf(al)
    pa, pb = mp.npdf(al), mp.npdf(be)
    mean = mu + sd * (pa - pb) / Z
    var = sd ** 2 * (1 + (al * pa - be * pb) / Z - ((pa - pb) / Z) ** 2)

    def quantile(q):
        return mu + sd * mp.sqrt(2) * mp.erfinv(2 * (mp.ncdf(al) + q * Z) - 1)

    return (float(mean), float(mp.sqrt(var)), float(quantile((1 - level) / 2)), float(quantile((1 + level) / 2)),
            float(mp.log(sd * mp.sqrt(2 * mp.pi) * Z)))


def test_the_quadrature_of_a_row_is_exact_for_gaussians_cut_off_or_not_and_for_exponential_tails():
    # a Gaussian over +-4 stds at spacings from fine to 2 stds, off the points' lattice
    for spacing in (0.25, 1.0, 2.0):
        x = np.arange(-4.0, 4.0 + 1e-9, spacing) + 0.3 * spacing
        _, logm = quadrature.row_quadrature(x, -x ** 2 / 2)
        assert np.log(np.exp(logm).sum()) == pytest.approx(truncated_normal(0, 1, x[0], x[-1])[4], abs=1e-9)
    # the peak between two points of a coarse row (3 points over 6 stds)
    x = np.array([-2.0, 1.0, 4.0])
    _, logm = quadrature.row_quadrature(x, -(x - 0.4) ** 2 / 2)
    assert np.log(np.exp(logm).sum()) == pytest.approx(truncated_normal(0.4, 1, -2, 4)[4], abs=1e-9)
    # cut off by a bound where the density falls by 20 to 500 nats over one interval
    for mu in (2.5, 10.0, 51.0):
        x = np.linspace(1.0, 2.0, 9)
        nodes, logm = quadrature.row_quadrature(x, -(x - mu) ** 2 / (2 * 0.01))
        ref = truncated_normal(mu, 0.1, 1.0, 2.0)
        top = logm.max()
        p = np.exp(logm - top)
        assert top + np.log(p.sum()) == pytest.approx(ref[4], abs=1e-5)  # rounding of log densities of -1e5
        assert (p @ nodes) / p.sum() == pytest.approx(ref[0], abs=1e-3 * ref[1])
    # an exponential tail, 40 nats per interval
    x = np.linspace(0.0, 1.0, 5)
    _, logm = quadrature.row_quadrature(x, -160.0 * x)
    assert np.exp(logm).sum() == pytest.approx((1 - math.exp(-160.0)) / 160.0, rel=1e-9)
    # points outside the prior (-inf) hold no mass, and neither do the intervals reaching them
    x = np.linspace(-4.0, 4.0, 9)
    logd = np.where(x <= 1.0, -x ** 2 / 2, -math.inf)
    _, logm = quadrature.row_quadrature(x, logd)
    assert np.log(np.exp(logm).sum()) == pytest.approx(truncated_normal(0, 1, -4, 1)[4], abs=1e-9)


class FakeFault:
    """A fault model with one physical state and the fault states of its
    kind, for :func:`static_posterior.static_posterior` with :func:`kalman.run_bank`
    replaced by a likelihood in closed form."""

    DT = 0.5
    NAME = "fake"

    def __init__(self, kind, prior):
        self.FAULT = {"kind": kind}
        self.FAULT_PRIOR = prior
        drifts = kind == "incipient"
        self.STATES = ("x", "p", "c") if drifts else ("x", "c")
        self.STATE_KINDS = ("physical", "parameter", "slope") if drifts else ("physical", "magnitude")

    def augment(self, x, rng):
        return np.zeros((len(self.STATES), x.shape[1]))


def synthetic(monkeypatch, loglik):
    """Replace the Kalman filters by ``loglik(onsets, magnitudes)``."""
    def run_bank(model, ys, us, track, onsets, magnitudes, fixed, residuals=False):
        ll = loglik(np.asarray(onsets, dtype=float), np.asarray(magnitudes, dtype=float))
        return kalman.BankResult(ll, None, None, np.zeros((len(ys), len(ll), 1)))
    monkeypatch.setattr(static_posterior, "run_bank", run_bank)


def posterior(model, onsets, hint, hint_onset, T=200):
    track = kalman.NominalTrack(np.zeros((T + 1, 1)), np.zeros((T + 1, 1, 1)), np.zeros(T + 1))
    return static_posterior.static_posterior(model, np.zeros((T, 1)), np.zeros((T, 1)), track, onsets, hint, hint_onset, 0.95)


@pytest.mark.parametrize("mu, sd, hint", [
    (1.0, 0.01, (0.8, 1.2)),       # inside, a wide hint
    (1.0, 0.01, (0.9995, 1.0005)),  # inside, a hint 40 times narrower than the posterior
    (1.0, 1e-4, (0.5, 1.5)),        # inside, a hint 5000 times wider
    (1.125, 0.0025, (0.5, 1.5)),    # halfway between two points of the first grid, 50 stds from each:
    #                                 the interpolated peak lies 1250 above the grid's highest point
    (1.99, 0.01, (1.8, 1.99)),      # cut off by the bound 2 one std from the peak
    (2.05, 0.01, (1.8, 1.99)),      # the likelihood peaks 5 stds beyond the bound
    (2.3, 0.01, (1.8, 1.99)),       # 30 stds beyond: the posterior is an exponential against the bound
    (2.1, 0.05, (2.1, 2.2)),        # a hint wholly beyond the bound
])
@pytest.mark.filterwarnings("error::RuntimeWarning")  # an overflow once leaked to the terminal (inf masses)
def test_the_static_posterior_of_a_bias_is_the_truncated_normal(monkeypatch, mu, sd, hint):
    synthetic(monkeypatch, lambda o, c: -0.5 * ((c - mu) / sd) ** 2)
    p = posterior(FakeFault("abrupt", (0.0, 2.0)), [100], hint, 100)
    mean, std, low, high, log_mass = truncated_normal(mu, sd, 0.0, 2.0)
    assert p.mean == pytest.approx(mean, abs=0.01 * std)
    assert p.change == pytest.approx(p.mean, rel=1e-12)  # a bias is its change
    assert p.std == pytest.approx(std, rel=0.01)
    assert p.low == pytest.approx(low, abs=0.05 * std) and p.high == pytest.approx(high, abs=0.05 * std)
    assert p.log_evidence == pytest.approx(log_mass - math.log(2.0), abs=0.01)
    assert not p.truncated


def test_a_drift_at_its_prior_bound_keeps_the_bound_cell_despite_rounding(monkeypatch):
    """The change c (T - onset) dt divided back by the span can land a hair
    above the slope's bound: that cell is the bound's, not outside the prior.
    The likelihood pins the change 2 % beyond what the bound allows."""
    b, T, dt = 0.05333333333333334, 200, 0.5
    for onset in (158, 159, 161, 170):
        span = (T - onset) * dt
        change, sd = 1.02 * b * span, 0.01 * b * span
        synthetic(monkeypatch, lambda o, c: -0.5 * ((c * (T - o) * dt - change) / sd) ** 2)
        p = posterior(FakeFault("incipient", (0.0, b)), [onset], (0.9 * b, 0.99 * b), onset)
        mean, std, low, high, log_mass = truncated_normal(change / span, sd / span, 0.0, b)
        assert np.isfinite(p.loglik[0][-1]) and p.values[0][-1] == b
        assert p.mean == pytest.approx(mean, abs=0.01 * std)
        assert p.change == pytest.approx(mean * span, abs=0.01 * std * span)
        assert p.high == pytest.approx(high, abs=0.05 * std)
        assert p.log_evidence == pytest.approx(log_mass - math.log(b), abs=0.01)


def test_onsets_weigh_by_their_spans_and_a_late_onset_beyond_the_first_grid_is_kept(monkeypatch):
    """Two onsets with the same likelihood in the slope: the first grid, laid
    in the change of the earlier onset, puts the later onset's cells (half the
    span, twice the slope) beyond the prior; it is moved inside and weighs as
    much. The evidence is the mean of the two onsets' (equal widths) times the
    window's length. The onset is then refined sample by sample between them
    (every sample as likely): the window, 75 to 175, is kept, so each inner
    sample weighs 1 %, the two ends a quarter each (25.5 samples: from 75
    to 100.5, from 149.5 to 175), and the evidence is the same."""
    synthetic(monkeypatch, lambda o, c: -0.5 * ((c - 0.0402) / 1e-4) ** 2)
    p = posterior(FakeFault("incipient", (0.0, 0.04)), [100, 150], (0.035, 0.0399), 100)
    mean, std, low, high, log_mass = truncated_normal(0.0402, 1e-4, 0.0, 0.04)
    assert p.onsets == tuple(range(100, 151))
    want = np.full(51, 0.01)
    want[[0, -1]] = 0.255
    assert p.onset_posterior == pytest.approx(want, abs=1e-3)
    assert p.mean == pytest.approx(mean, abs=0.01 * std)
    assert p.log_evidence == pytest.approx(log_mass + math.log(100.0) - math.log(0.04), abs=0.01)


def test_onsets_far_apart_in_mass_do_not_blur_the_interval(monkeypatch):
    """A narrow main onset and a far, wide, improbable one: the interval is
    the main row's (the mixture's quantiles read off each row's own nodes)."""
    rows = {100: (0.0112359, 1e-7, 0.0), 60: (0.005, 1e-3, -14.0)}  # 0.8 % of the mass at 60

    def loglik(o, c):
        mu, sd, base = (np.array([rows[int(k)][j] for k in o]) for j in range(3))
        return base - 0.5 * ((c - mu) / sd) ** 2

    synthetic(monkeypatch, loglik)
    p = posterior(FakeFault("abrupt", (0.0, 0.1)), [60, 100], (0.004, 0.012), 100)
    main = truncated_normal(0.0112359, 1e-7, 0.0, 0.1)
    assert p.high - p.low == pytest.approx(main[3] - main[2], rel=0.05)


def test_the_bank_on_a_linear_plant_is_the_kalman_filter_derived_by_hand():
    """Cells of R12 stepped from different onsets and biases, each against a
    Kalman filter in matrices with the hand-derived RK4 map: the nominal model
    up to the onset, R12 + bias after it. R12 changes at the instant of the
    onset sample (the thesis's DBN, the simulator): the transition into that
    sample is nominal, its measurement F12 = (P1 - P2) / R12 sees the bias."""
    package, ys, us = data("two_tank", "R12:abrupt:0.8@60", seed=4)
    nominal, fault = package.MODELS["nominal"], package.MODELS["R12_abrupt"]
    onsets, biases = [100, 118, 118, 140], [0.5, 0.8, 1.1, 0.8]
    t = kalman.nominal_track(nominal, ys, us, max(onsets))
    r = kalman.run_bank(fault, ys, us, t, onsets, biases, np.zeros(1))
    Q = np.diag(np.asarray(nominal.PROCESS_STD) ** 2)
    R = np.diag(np.asarray(nominal.MEASUREMENT_STD) ** 2)
    for i, (onset, bias) in enumerate(zip(onsets, biases)):
        at_onset = tank_map(2.0)[:2] + tank_map(2.0 + bias)[2:]
        maps = [tank_map(2.0)] * onset + [at_onset] + [tank_map(2.0 + bias)] * (len(ys) - onset - 1)
        ll, m, P = kalman_filter(ys, np.asarray(nominal.X0[:2]), np.diag(np.asarray(nominal.X0_STD) ** 2), maps, Q, R)
        assert r.loglik[i] == pytest.approx(ll, rel=1e-10, abs=1e-8)
        assert np.allclose(r.mean[i], m, rtol=1e-9) and np.allclose(r.cov[i], P, rtol=1e-7, atol=1e-14)
    # the nominal track is the same filter with R12 at its nominal value
    ll, m, P = kalman_filter(ys[:100], np.asarray(nominal.X0[:2]), np.diag(np.asarray(nominal.X0_STD) ** 2),
                             [tank_map(2.0)] * 100, Q, R)
    assert t.loglik[100] == pytest.approx(ll, rel=1e-10) and np.allclose(t.mean[100], m, rtol=1e-9)


def test_unread_sensors_are_left_out_of_the_update():
    package, ys, us = data("two_tank", "none", seed=2)
    ys = ys.copy()
    ys[50:60, 1] = np.nan
    ys[70] = np.nan
    nominal = package.MODELS["nominal"]
    t = kalman.nominal_track(nominal, ys, us, len(ys))
    Q = np.diag(np.asarray(nominal.PROCESS_STD) ** 2)
    total, m, P = 0.0, np.asarray(nominal.X0[:2]), np.diag(np.asarray(nominal.X0_STD) ** 2)
    M, c, H = tank_map(2.0)
    for y in ys:
        seen = np.isfinite(y)
        ll, m, P = kalman_filter([y[seen]], m, P, [(M, c, H[seen])], Q,
                                 np.diag(np.asarray(nominal.MEASUREMENT_STD)[seen] ** 2))
        total += ll if seen.any() else 0.0
    assert t.loglik[-1] == pytest.approx(total, rel=1e-10)


@pytest.mark.parametrize("dt", [0.5, 0.25])
def test_the_protocol_filter_holds_a_fault_and_steps_over_its_interval_as_derived_by_hand(dt):
    """CubatureKalmanFilter (the filter protocol's step) of R12_abrupt with
    the bias held at 0.8 from the start, some sensors unread, over an
    interval dt: the textbook Kalman filter with the hand-derived RK4 map of
    R12 = 2.8 over dt. Its state holds the bias (std 0)."""
    package, ys, us = data("two_tank", "R12:abrupt:0.8@0", seed=4)
    ys = ys[:80].copy()
    ys[20:30, 1] = np.nan
    ys[40] = np.nan
    fault = package.MODELS["R12_abrupt"]
    f = kalman.CubatureKalmanFilter(fault, 100, np.random.default_rng(0), fixed=np.array([0.8]))
    steps = [f.step(y, u, dt) for y, u in zip(ys, us)]
    Q = np.diag(np.asarray(fault.PROCESS_STD[:2]) ** 2)
    total, m, P = 0.0, np.asarray(fault.X0[:2]), np.diag(np.asarray(fault.X0_STD[:2]) ** 2)
    M, c, H = tank_map(2.8, dt)
    for y, s in zip(ys, steps):
        seen = np.isfinite(y)
        ll, m, P = kalman_filter([y[seen]], m, P, [(M, c, H[seen])], Q,
                                 np.diag(np.asarray(fault.MEASUREMENT_STD)[seen] ** 2))
        ll = ll if seen.any() else 0.0
        total += ll
        assert s.loglik == pytest.approx(ll, rel=1e-10, abs=1e-10)
        np.testing.assert_allclose(s.mean[:2], m, rtol=1e-9)
        np.testing.assert_allclose(s.std[:2], np.sqrt(np.diag(P)), rtol=1e-7)
        assert s.mean[2] == 0.8 and s.std[2] == 0.0
    assert np.allclose(f.cov, P, rtol=1e-7, atol=1e-14)


def test_the_protocol_filter_from_the_prior_is_the_nominal_observer_bit_for_bit():
    """The diagnosis's ckf observer (NominalKalman) and the protocol's filter
    are one arithmetic: the same numbers to the last bit."""
    package, ys, us = data("ro", "R_pipe:abrupt:31@165", seed=1)
    ys = ys[:200].copy()
    ys[30, 0] = np.nan
    ys[31] = np.nan
    nominal = package.MODELS["nominal"]
    t = kalman.nominal_track(nominal, ys, us, len(ys))
    out = kalman.CubatureKalmanFilter(nominal).run(ys, us)
    for key in ("y_mean", "y_std", "x_mean", "x_std"):
        got = out.mean if key == "x_mean" else out.std if key == "x_std" else getattr(out, key)
        assert got.tobytes() == getattr(t, key).tobytes(), key


def exact_grid(package, name, ys, us, onsets, values):
    """log p(y | onset, magnitude) by the bank on every cell of a rectangular grid."""
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, max(onsets))
    fault = package.MODELS[name]
    O, V = np.meshgrid(onsets, values, indexing="ij")
    fixed = np.zeros(len([k for k in fault.STATE_KINDS if k != "physical"]))
    if len(fixed) == 2:
        fixed[0] = dict(zip(fault.PARAMETERS, fault.THETA))[fault.FAULT["parameter"]]
    return kalman.run_bank(fault, ys, us, t, O.ravel(), V.ravel(), fixed).loglik.reshape(O.shape), t


#: A case of the test below that ran the drift's path of its R10 case again (the same refinement of onsets
#: and passes, on a narrower window): bench/full_cases.py grid-cases runs it with the two kept.
MORE_GRID_CASES = [("R12:incipient:0.01@60", "R12_incipient", list(range(88, 152, 4)), np.linspace(0.002, 0.03, 701), 7)]


@pytest.mark.slow
@pytest.mark.parametrize("scenario, name, onsets, values, seed", [
    ("R12:abrupt:0.8@60", "R12_abrupt", list(range(110, 126)), np.linspace(0.3, 1.5, 1201), 7),
    # a wide window of onsets, each with a narrow likelihood in the slope: a first grid coarse against
    # every onset's peak must not leave out the onsets whose peaks fall between its points
    ("R10:incipient:0.013333@60", "R10_incipient", list(range(79, 144, 4)), np.linspace(0.006, 0.022, 801), 0),
])
def test_the_adaptive_grid_integrates_like_a_fine_brute_force_grid(scenario, name, onsets, values, seed):
    """Posterior mean, std, interval and evidence of the adaptive grid (a few
    dozen cells, started from a poor hint) against quadrature on a grid of
    ~10000 cells over the same onsets with the same weights (a drift's onsets
    are refined sample by sample where its posterior is: the onsets the
    adaptive grid ends with), with the magnitude uniform on its prior. The
    fine grid's spacing is at most a ninth of the posterior's std (measured:
    0.11 and 0.07 std for the drifts, 0.1 for the step): its mean, std and
    evidence are those of a grid twice as fine to 1e-5, its interval's ends
    to 0.003 std, against the tolerance of 0.05 std."""
    package, ys, us = data("two_tank", scenario, seed=seed)
    fault = package.MODELS[name]
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, max(onsets))
    truth = float(scenario.split(":")[2].split("@")[0])
    p = static_posterior.static_posterior(fault, ys, us, t, onsets, (1.3 * truth, 1.9 * truth), onsets[len(onsets) // 2], 0.95)
    assert p.onsets[0] >= onsets[0] and p.onsets[-1] <= onsets[-1]
    assert sum(p.widths) <= onset_widths(onsets).sum() + 1e-9  # the window kept (less the onsets left out)
    ll, _ = exact_grid(package, name, ys, us, list(p.onsets), values)
    a, b = fault.FAULT_PRIOR
    w = np.asarray(p.widths)[:, None] * np.exp(ll - ll.max())
    h = values[1] - values[0]
    post = w.sum(axis=0)
    evidence = ll.max() + math.log(post.sum() * h) - math.log(b - a)
    post /= post.sum()
    mean = post @ values
    sd = math.sqrt(post @ (values - mean) ** 2)
    cdf = np.cumsum(post) - post / 2.0  # the mass up to each point of the fine grid
    low, high = np.interp([0.025, 0.975], cdf, values)
    assert post[0] < 1e-6 and post[-1] < 1e-6  # the brute-force grid holds the posterior
    assert p.mean == pytest.approx(mean, abs=0.01 * sd)
    assert p.std == pytest.approx(sd, rel=0.01)
    assert p.low == pytest.approx(low, abs=0.05 * sd) and p.high == pytest.approx(high, abs=0.05 * sd)
    assert p.log_evidence == pytest.approx(evidence, abs=0.01)
    assert p.passes <= (6 if "incipient" in name else 3)  # a drift: and a round of the onset's refinement


def test_a_drift_that_began_before_the_onsets_tried_reaches_back():
    """A slow drift from t = 20 (step 40) with onsets tried from step 150 on:
    the onset posterior piles up at the earliest ones, so earlier batches are
    added until it does not; the onset and the slope are found."""
    package, ys, us = data("two_tank", "R12:incipient:0.006@20", seed=3)
    fault = package.MODELS["R12_incipient"]
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, 200)
    tried = list(range(150, 201, 4))
    earlier = tuple(tuple(range(s, s + 32, 8)) for s in (118, 86, 54, 22))
    alone = static_posterior.static_posterior(fault, ys, us, t, tried, (0.005, 0.02), 150, 0.95)
    far = static_posterior.static_posterior(fault, ys, us, t, tried, (0.005, 0.02), 150, 0.95, earlier=earlier)
    assert alone.onset <= 154 and sum(alone.onset_posterior[:2]) > 0.05
    assert min(far.onsets) < 60 and abs(far.onset - 40) <= 16
    assert far.low <= 0.006 <= far.high
    assert far.log_evidence > alone.log_evidence + 5


@pytest.mark.slow
def test_on_the_ro_plant_the_bias_agrees_with_a_particle_filter_reference():
    """R_pipe 69 -> 100 at t = 165: the cubature filters' posterior mean of the
    bias against a grid posterior of bootstrap particle filters (2000
    particles, the pseudo-marginal likelihood) on the same data, within a
    third of the posterior's std (the reference's own Monte Carlo scatter is
    about a sixth). The reference's grid is 1.0 apart (was 0.5): the
    posterior's std is 1.6, and a sum over points 0.6 std apart gives a
    Gaussian's mean exactly but for the filters' scatter (measured: the
    reference's mean 30.73 on this grid, 30.95 on the finer one, the
    cubature filters' 30.69)."""
    package, ys, us = data("ro", "R_pipe:abrupt:31@165", seed=102)
    nominal, fault = package.MODELS["nominal"], package.MODELS["R_pipe_abrupt"]
    onset, values = 164, np.arange(25.0, 37.01, 1.0)
    rng = np.random.default_rng(5)
    n = 2000

    def bootstrap(model, x, ys, us, fix=None):
        total = 0.0
        for y, u in zip(ys, us):
            model.transition(x, u, model.THETA, model.DT, rng, out=x)
            if fix is not None:
                x[-1] = fix
            ll = model.loglik(y, x, u, model.THETA)
            top = ll.max()
            w = np.exp(ll - top)
            total += top + math.log(w.mean())
            x = x[:, np.minimum(np.searchsorted(np.cumsum(w / w.sum()), (rng.random() + np.arange(n)) / n), n - 1)]
        return total, x

    _, x = bootstrap(nominal, nominal.initial_particles(rng, n), ys[:onset], us[:onset])
    ll = []
    for v in values:
        xf = fault.augment(x.copy(), rng)
        xf[-1] = v
        ll.append(bootstrap(fault, xf, ys[onset:], us[onset:], fix=v)[0])
    post = np.exp(np.array(ll) - max(ll))
    post /= post.sum()
    mean = post @ values
    t = kalman.nominal_track(nominal, ys, us, onset)
    p = static_posterior.static_posterior(fault, ys, us, t, [onset], (26.0, 36.0), onset, 0.95, KalmanOptions())
    assert abs(p.mean - mean) < p.std / 3, (p.mean, mean, p.std)


def test_the_residuals_of_the_most_probable_cell_are_white_for_the_true_model_and_not_for_a_wrong_one():
    """The consistency test of the static model (bgc.diagnosis.static.checked)
    reads the most probable cell's normalised residuals: on the true
    hypothesis they are N(0, 1) and pass the windowed Z-test; a hypothesis
    that cannot produce the data (a capacitance step: it does not move the
    tanks' steady state) leaves a bias that fails it."""
    from bgc.diagnosis.detect import Detector, DetectorOptions

    package, ys, us = data("two_tank", "R12:abrupt:0.8@60", seed=11)
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, 125)
    onsets = list(range(114, 125))

    def alarm(name, hint):
        p = static_posterior.static_posterior(package.MODELS[name], ys, us, t, onsets, hint, 119, 0.95)
        z = p.residuals[p.best[0]:]
        assert np.all(np.isnan(p.residuals[:p.best[0]]))
        test = Detector(tuple(package.MODELS["nominal"].OUTPUTS), DetectorOptions(0.001, (1, 8, 32), len(z)))
        return z, next((a for a in map(test.update, z) if a is not None), None)

    z, a = alarm("R12_abrupt", (0.6, 1.0))
    assert a is None and abs(np.nanmean(z)) < 0.1 and 0.8 < np.nanstd(z) < 1.2
    _, a = alarm("C1_abrupt", (-1.0, 1.0))
    assert a is not None


@pytest.mark.slow
def test_a_hypothesis_whose_likelihood_peaks_outside_its_prior_gets_its_grid_against_the_bound():
    """R2 may only rise (models/circuit.yaml); data of R1 falling pull R2's
    drift towards a fall. The grid then stays inside the prior, against its
    bound 0, and the posterior is finite there (this sweep run once crashed:
    a grid laid wholly beyond the bound). On the compiled backend when numba
    is installed (the same diagnosis, tests/test_backend.py checks it;
    faster with 500 particles on every hypothesis)."""
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions

    d = bgc.diagnose(fast_session("circuit"), scenario="R1:incipient:-0.0208821@5.85", seed=2922547472,
                     options=DiagnosisOptions(seed=2922547472, particles=500, workers=1)).diagnosis
    assert d.candidates[0] == "R1_incipient"
    h = next(h for h in d.hypotheses if h.name == "R2_incipient")
    p = h.static
    assert p is not None and math.isfinite(p.log_evidence) and p.residuals is not None
    assert 0.0 <= p.low <= p.mean <= p.high
    assert all(np.all(np.diff(v) >= 0) and v[0] >= 0.0 for v in p.values)


def test_a_cell_of_a_parameter_no_sensor_sees_is_the_nominal_filter_up_to_its_onset_sample():
    """A fault with onset k changes the parameter at the instant of sample k:
    the transition into sample k is nominal. The orifice tanks' outlet pipe
    R20 enters no measurement (F_orifice = cd sqrt(P1 - P2), P2), so a cell
    of any bias whose onset is k explains y_0 .. y_k exactly as the nominal
    filter does (before: its transition into k had the bias)."""
    from conftest import session

    s = session("orifice_tanks")  # compiled once per test session
    c, package = s.compiled, packages.load_package(s.folder, "orifice_tanks")
    result = simulate.simulate(c.numerics, simulate.SimulationOptions(seed=3, steps=60))
    ys, us = track.run_arrays(runs.parse_run(simulate.to_csv(result), "none"), package, "nominal")
    nominal, fault = package.MODELS["nominal"], package.MODELS["R20_abrupt"]
    t = kalman.nominal_track(nominal, ys, us, 41)
    for k in (30, 40):
        r = kalman.run_bank(fault, ys[:k + 1], us, t, [k, k, k - 1], [0.9, -0.9, 0.9], np.zeros(1))
        assert r.loglik[0] == pytest.approx(t.loglik[k + 1], rel=1e-12)
        assert r.loglik[1] == pytest.approx(t.loglik[k + 1], rel=1e-12)
        assert abs(r.loglik[2] - t.loglik[k + 1]) > 1e-6  # from k - 1 on, the transition into k has the bias
        np.testing.assert_allclose(r.mean[0], t.mean[k + 1], rtol=1e-12)


@pytest.mark.parametrize("model, scenario", [("two_tank", "R12:incipient:0.006@20"), ("ro", "R_pipe:abrupt:30@165")])
def test_paths_side_by_side_are_each_models_path_alone_bit_for_bit(model, scenario):
    """run_paths (the recorded paths of every hypothesis of a diagnosis at
    once, static_posterior.record_paths) gives each fault model's filter
    exactly what run_bank of that model alone gives: every step's log
    density, state, residuals and predictions, with onsets joining at
    different steps, a drifting parameter (the two tanks' drifts) and
    sensors not read at some steps; a path the prior tells nothing about
    (log evidence -inf) is left without one."""
    package, ys, us = data(model, scenario, seed=2)
    ys = ys.copy()
    ys[100:110, 0] = np.nan  # one sensor not read
    ys[120:122] = np.nan  # none read
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, len(ys))
    models = [m for name, m in package.MODELS.items() if name != "nominal"][:8]  # drifts and steps
    onsets = [int(o) for o in np.random.default_rng(0).integers(60, len(ys) - 5, len(models))]
    magnitudes = [float(np.mean(m.FAULT_PRIOR)) for m in models]
    fixed = [static_posterior.fault_start(m, t, o) for m, o in zip(models, onsets)]
    together = kalman.run_paths(models, ys, us, t, onsets, magnitudes, fixed)
    for m, o, c, f, r in zip(models, onsets, magnitudes, fixed, together):
        alone = kalman.run_bank(m, ys, us, t, [o], [c], f, residuals=True, record=True)
        for field in ("loglik", "mean", "cov", "z", "increments", "y_mean", "y_std", "x_mean", "x_std"):
            a, b = getattr(alone, field), getattr(r, field)
            assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), (m.NAME, field)
    posteriors = [static_posterior._none_told(m.NAME, np.array([o]), [1.0], 0.95, 1) for m, o in zip(models, onsets)]
    told = [dataclasses.replace(p, log_evidence=0.0, onset=o, mean=c)
            for p, o, c in zip(posteriors[:2], onsets, magnitudes)]
    recorded = static_posterior.record_paths(models, ys, us, t, told + posteriors[2:])
    assert all(p.path is None for p in recorded[2:])
    for m, p, q in zip(models, told, recorded):
        np.testing.assert_array_equal(static_posterior.record_path(m, ys, us, t, p).path.x_mean, q.path.x_mean)


@pytest.mark.slow
def test_static_posteriors_side_by_side_are_each_models_alone_bit_for_bit():
    """static_posteriors (every hypothesis's adaptive grid at once, the banks
    of each pass run as one stack by run_banks) gives each fault model the
    static posterior static_posterior gives it alone: its grid, log
    likelihoods, evidence, estimate, residuals and trace, with searches that
    take different numbers of passes, reach back and refine (drifts)."""
    package, ys, us = data("two_tank", "R12:incipient:0.006@20", seed=3)
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, 200)
    tried = tuple(range(150, 201, 10))
    earlier = (tuple(range(118, 150, 8)),)
    models = [package.MODELS[name] for name in ("R12_incipient", "R10_abrupt", "F12_offset_bias", "C1_abrupt")]
    arguments = [(tried, tuple(float(v) for v in m.FAULT_PRIOR), 150, 0.95, KalmanOptions(), earlier, True, None)
                 for m in models]
    together = static_posterior.static_posteriors(models, ys, us, t, arguments)
    assert len({p.passes for p in together}) > 1
    for m, a, p in zip(models, arguments, together):
        alone = static_posterior.static_posterior(m, ys, us, t, *a)
        for field in ("onsets", "widths", "log_evidence", "mean", "std", "low", "high", "change", "onset",
                      "onset_posterior", "passes", "best", "truncated"):
            assert getattr(alone, field) == getattr(p, field), (m.NAME, field)
        for field in ("values", "loglik", "residuals", "trace"):
            a_, b_ = getattr(alone, field), getattr(p, field)
            assert (a_ is None and b_ is None) or all(
                np.array_equal(np.asarray(x, dtype=float), np.asarray(y, dtype=float), equal_nan=True)
                for x, y in zip(a_, b_)), (m.NAME, field)


def test_the_row_quadrature_does_not_rise_far_above_its_points_next_to_an_extreme_one():
    """A row of log densities as the compiled backend's grid gave for the DC
    motor's b_incipient: sound points, then a cell whose model diverged
    (-1.96e18), then points outside the prior. The parabola through the
    extreme point bent the interpolant of the interval before it up to about
    1e17 (the grid's log evidence came out at 4.5e19 on the NumPy backend;
    on the compiled one its mass underflowed to 0 and the static posterior
    failed); a neighbour that far below shapes no parabola, and the interval
    stays below its left end. The peak between the two highest points may
    still rise above them (a row too coarse for its peak), by what the
    parabolas through sound points say."""
    from bgc.filters.quadrature import row_quadrature

    values = np.linspace(-3.1e-4, 1.56e-3, 9)
    logd = np.array([-np.inf, -8977.98, -5050.65, -4153.61, -4374.58, -8682.57, -1.95757e18, -np.inf, -np.inf])
    _, logm = row_quadrature(values, logd + 4153.61)
    per_interval = logm.reshape(len(values) - 1, -1).max(axis=1)
    assert per_interval[4] < -4374.58 + 4153.61  # between -221 and -4529, next to the extreme point
    assert np.max(logm) < 500.0  # the coarse peak between 0 and -221: the parabolas' own rise


def test_a_grid_whose_points_hold_no_mass_tells_nothing_instead_of_failing(monkeypatch):
    """Should the final quadrature's masses all vanish (every mass below the
    shift), the static posterior says it cannot tell (log evidence -inf, no
    estimate) instead of raising math.log's domain error."""
    synthetic(monkeypatch, lambda onsets, c: -0.5 * ((c - 1.0) / 0.1) ** 2)
    real = static_posterior.overflow_shift

    def shift(peak):  # the grid's passes as usual; the final sum's masses all 0
        return math.inf if sys._getframe(1).f_code.co_name == "posterior" else real(peak)
    monkeypatch.setattr(static_posterior, "overflow_shift", shift)
    p = posterior(FakeFault("abrupt", (0.0, 2.0)), [100], (0.8, 1.2), 100)
    assert p.log_evidence == -math.inf and math.isnan(p.mean)
