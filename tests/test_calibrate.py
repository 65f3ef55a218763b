"""Calibration (bgc/analysis/calibrate.py, bgc/output/calibrated.py, bgc
calibrate): maximum-likelihood noise levels and parameters from healthy data,
checked against closed forms on a one-state linear plant, against the truth
of simulated runs of the two tanks, and the calibrated model file: the
user's text with only the values changed, never written over a file bgc did
not write, the original untouched."""

import json
import math
from functools import lru_cache

import numpy as np
import pytest
import yaml

import bgc
from bgc import cli
from bgc.compiler import load, validate
from bgc.errors import ArgumentTypeError, ArgumentValueError, CalibrationError, DataError, OutputError
from bgc.filters import residuals
from bgc.output.calibrated import calibrated_text, number
from bgc.pipeline import compile_model
from bgc.analysis import calibrate as cal
from bgc.data import runs
from bgc.analysis import simulate

from conftest import FAST, MODELS, TEST_MODELS, fast_session

RC = TEST_MODELS / "rc_drain.yaml"
TWO_TANK = MODELS / "two_tank.yaml"


@pytest.fixture(scope="module")
def rc():
    return bgc.open(RC)


@pytest.fixture(scope="module")
def tanks():
    return bgc.open(TWO_TANK)


def rc_run(session, sigma: float, steps: int, seed: int, start: float = 1.0) -> tuple[runs.Run, np.ndarray]:
    """A run of the RC drain made here, not by bgc: the noise-free trajectory
    of the filters' own discretisation (RK4, amplification factor
    1 + z + z^2/2 + z^3/6 + z^4/24 per substep, z = -h / (R C)) from
    ``start`` (the model's initial value is 1.0), sampled from t = dt on (the filter predicts one step before
    its first sample), plus white noise of std ``sigma``. Returns the run and
    the noise-free readings."""
    m = session.package.MODELS["nominal"]
    R, C = 2.0, 0.5  # the model file's values
    h = m.DT / m.SUBSTEPS
    z = -h / (R * C)
    g = (1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24) ** m.SUBSTEPS
    clean = start * g ** np.arange(1, steps + 1)
    y = clean + sigma * np.random.default_rng(seed).standard_normal(steps)
    time = m.DT * np.arange(1, steps + 1)
    run = runs.Run(time, {}, {"e1": y}, {}, {}, ("model rc_drain: made by tests/test_calibrate.py",), "rc.csv")
    return run, clean


@lru_cache(maxsize=None)
def noise_fitted(session, seed: int, steps: int):
    """``rc_run(session, 0.05, steps, seed)`` (the run and its noise-free
    readings) and its calibration of the sensor's noise alone, made once
    per test process for the tests that read it (read them, do not change
    them)."""
    run, clean = rc_run(session, 0.05, steps, seed)
    return run, clean, session.calibrate(run, "measurement_noise")


# ------------------------------------------------------------------- closed forms on a one-state linear plant
@pytest.mark.slow
def test_rc_noise_variance_is_the_mean_squared_residual(rc, seed=1):
    """With no process noise (and so an exactly known initial state, X0_STD
    = 2 x 0), the likelihood of sigma is that of iid N(clean_k, sigma^2): its
    maximum is the mean squared residual from the noise-free trajectory, and
    the log-likelihood falls from there by T d + T (exp(-2 d) - 1) / 2 at
    log sigma = log sigma_hat + d, so the 95 % interval's ends are where that
    fall is chi2(0.95, 1) / 2 (solved here by bisection; near
    sigma_hat exp(+-1.96 / sqrt(2 T)), the curvature's answer). (T = 50:
    the closed form holds at any length; the drain has decayed below the
    noise by the 30th sample.)"""
    T = 50
    run, clean, r = noise_fitted(rc, seed, T)
    e = r.calibration.estimate("noise e1")
    expected = float(np.mean((run.measurements["e1"] - clean) ** 2))
    assert e.value ** 2 == pytest.approx(expected, rel=1e-6)
    assert e.identifiable and not e.at_bound
    def end(sign):
        fall = lambda d: T * d + T * (math.exp(-2 * d) - 1) / 2 - 3.841458820694124 / 2  # noqa: E731
        a, b = 0.0, sign * 1.0
        for _ in range(200):
            a, b = (a, (a + b) / 2) if fall((a + b) / 2) > 0 else ((a + b) / 2, b)
        return (a + b) / 2
    assert e.low == pytest.approx(e.value * math.exp(end(-1)), rel=1e-4)
    assert e.high == pytest.approx(e.value * math.exp(end(1)), rel=1e-4)
    half = 1.959963984540054 / math.sqrt(2 * T)
    assert e.value * math.exp(-half) < e.low and e.value * math.exp(half) < e.high  # the fall is steeper below
    assert e.level == pytest.approx(e.value / 1.0, rel=1e-12)  # its reading at X0 is 1.0: the level is the std
    # the maximum: the likelihood there is that of the iid Gaussian at the mean squared residual
    assert r.calibration.loglik == pytest.approx(-0.5 * T * (math.log(2 * math.pi * expected) + 1), rel=1e-9)


@pytest.mark.slow
def test_rc_initial_state_is_the_least_squares_start(rc):
    """A recording that starts at 0.8, not at the model's 1.0, with no
    process noise: the readings are x0 g^k plus white noise, so the
    maximum-likelihood start is the least-squares x0 = sum y_k g^k / sum
    g^2k, the noise variance the mean squared residual from x0 g^k, and (the
    start's and the std's estimates uncorrelated at the maximum: a mean and
    a variance) the start's interval x0 +- 1.96 sigma / sqrt(sum g^2k). The
    model file keeps its initial value. (T = 50 samples: the start's
    information, sum g^2k, is all in the first 30.)"""
    T = 50
    run, clean = rc_run(rc, 0.05, T, 3, start=0.8)
    report = rc.calibrate(run, "measurement_noise,initial")
    c = report.calibration
    g = clean / 0.8  # g^k, k = 1 .. T
    y = run.measurements["e1"]
    x0 = float(y @ g / (g @ g))
    sigma = math.sqrt(float(np.mean((y - x0 * g) ** 2)))
    e = c.estimate("initial e1")
    assert e.kind == "initial" and e.identifiable and e.start == 1.0
    assert e.value == pytest.approx(x0, rel=1e-6) and abs(e.value - 0.8) < e.high - e.low
    half = 1.959963984540054 * sigma / math.sqrt(float(g @ g))
    assert e.low == pytest.approx(x0 - half, rel=1e-4) and e.high == pytest.approx(x0 + half, rel=1e-4)
    assert c.estimate("noise e1").value == pytest.approx(sigma, rel=1e-6)
    assert "initial: 1.0" in report.text  # the model's start is kept: the estimate describes the recording
    # without it, the model's start is taken as known, and its error as noise: the mean squared residual
    # from 1.0 g^k
    wrong = rc.calibrate(run, "measurement_noise").calibration.estimate("noise e1").value
    assert wrong == pytest.approx(math.sqrt(float(np.mean((y - g) ** 2))), rel=1e-6) and wrong > 1.1 * sigma


@pytest.mark.slow
def test_rc_several_recordings_with_gaps_and_missing_cells(rc):
    """Two recordings, one with a gap of 10 rows and empty cells: the data
    meet the model's time grid as in a diagnosis (the filter predicts across
    the gap, a cell not read adds no term), so the maximum is the mean
    squared residual over the samples read, the trajectory taken at each
    sample's step of the grid."""
    first, clean1 = rc_run(rc, 0.05, 75, 8)
    second, clean2 = rc_run(rc, 0.05, 60, 9)
    keep = np.ones(60, dtype=bool)
    keep[20:30] = False  # a gap
    y2 = second.measurements["e1"].copy()
    y2[[5, 35, 36]] = np.nan  # cells not read
    second = runs.Run(second.time[keep], {}, {"e1": y2[keep]}, {}, {}, second.header, "rc2.csv")
    r = rc.calibrate([first, second], "measurement_noise")
    residuals = np.concatenate([first.measurements["e1"] - clean1, (y2 - clean2)[keep]])
    expected = float(np.nanmean(residuals ** 2))
    assert r.calibration.samples == 75 + 50 - 3
    assert r.calibration.estimate("noise e1").value ** 2 == pytest.approx(expected, rel=1e-6)
    assert r.calibration.sources == ("rc.csv", "rc2.csv") and "from rc.csv, rc2.csv" in r.text


@pytest.mark.slow
def test_rc_process_noise_the_data_do_not_show_is_zero(rc):
    """Asked for the process level too, on data without process noise: its
    likelihood is highest at 0, so it is 0 with a one-sided interval, and
    the sensor's noise is the closed form again (the trajectory is then
    known exactly). (100 samples: the data show no process noise, its
    interval's upper end is still well under 0.05.)"""
    run, clean = rc_run(rc, 0.05, 100, 1)
    r = rc.calibrate(run)  # noise: the sensor's and the process level
    p = r.calibration.estimate("process noise")
    assert p.value == 0 and p.low == 0 and p.at_bound and 0 < p.high < 0.05
    e = r.calibration.estimate("noise e1")
    assert e.value ** 2 == pytest.approx(float(np.mean((run.measurements["e1"] - clean) ** 2)), rel=1e-6)
    assert "process_noise: 0.0\n" in r.text and "the data show none" in r.text


@pytest.mark.slow
def test_rc_sensor_noise_swamped_by_process_noise_is_named(tmp_path):
    """A sensor whose noise (0.0005) is tiny beside the process noise it
    reads (a std of about 0.05): its likelihood is flat toward 0, so it is
    named as not identifiable (not an error, not a spurious estimate), and
    the process level is estimated with it held (150 steps: each of the
    fit's some 200 likelihoods runs a Kalman filter over them)."""
    text = RC.read_text(encoding="utf-8").replace("process_noise: 0", "process_noise: 0.05")
    path = tmp_path / "rc_noisy_plant.yaml"
    path.write_text(text.replace("e1: {noise: 0.02}", "e1: {noise: 0.0005}"), encoding="utf-8")
    session = bgc.open(path)
    result = simulate.simulate(session.compiled.numerics, simulate.SimulationOptions(steps=150, seed=6))
    c = session.calibrate(runs.parse_run(simulate.to_csv(result), "r.csv")).calibration
    e = c.estimate("noise e1")
    assert not e.identifiable and e.why.startswith("the likelihood is nearly flat") and e.level == 0.0005
    p = c.estimate("process noise")
    assert p.identifiable and p.low < 0.05 < p.high


@pytest.mark.slow
def test_rc_product_of_parameters_is_not_identifiable(rc):
    """R and C enter the drain only as R C: one of them (C, listed later) is
    named as not identifiable and keeps the model's value, and R is
    estimated with it held: it tells the product (the data's R C is the
    model's, 1, so R's interval holds 2), and the noise is then near the
    closed form (the mean squared error from the noise-free trajectory, on
    50 samples). Holding both left the product at the model's value
    whatever the data said."""
    run, clean = rc_run(rc, 0.05, 50, 3)
    r = rc.calibrate(run, "measurement_noise,R,C")
    c = r.calibration
    held = c.estimate("C")
    assert not held.identifiable and held.value == held.start
    # the product R C: a direction the likelihood is flat along, or the two estimates correlated (which of the two
    # the curvature at the optimum shows is a matter of its last digits; both hold C and estimate R)
    assert ("correlated" in held.why or "flat along it and R together" in held.why) \
        and "R estimated with it held, carrying its error" in held.why, held.why
    free = c.estimate("R")
    assert free.identifiable and free.low < 2.0 < free.high
    noise = c.estimate("noise e1")
    assert noise.value ** 2 == pytest.approx(float(np.mean((run.measurements["e1"] - clean) ** 2)), rel=0.01)
    # the calibrated text keeps C as written, says why, writes R and the noise
    assert "C: 0.5     # capacity" in r.text and "R: 2.0     # resistance" not in r.text
    assert "C kept at the model's 0.5: the data (rc.csv) cannot identify it" in r.text
    read = validate.validate(load.loads(r.text, "x.yaml"))
    assert read.measurements[0].noise == float(number(noise.level))


def test_of_correlated_estimates_one_is_held_and_the_others_estimated_again():
    # the covariance of four estimates: a and b correlated 0.999 (the data tell a + b), c and d free; the
    # Hessian its inverse: one of a, b held (b, listed later, on the tie), the rest estimated again
    from bgc.analysis.calibrate import _unidentifiable

    cov = np.eye(4)
    cov[0, 1] = cov[1, 0] = 0.999
    why = _unidentifiable(["a", "b", "c", "d"], np.linalg.inv(cov), [True] * 4)
    assert list(why) == ["b"] and why["b"].startswith("correlated +0.999 with a") and "a estimated" in why["b"]
    # a, b and c all tied to one another (each in two pairs): the later listed; then a flat direction of a and
    # d: the one most along it
    cov = np.array([[1, 0.995, 0.995, 0], [0.995, 1, 0.995, 0], [0.995, 0.995, 1, 0], [0, 0, 0, 1.0]])
    assert list(_unidentifiable(["a", "b", "c", "d"], np.linalg.inv(cov), [True] * 4)) == ["c"]
    H = np.diag([1.0, 1.0, 1.0, 1.0])
    v = np.array([0.6, 0.0, 0.0, 0.8])  # H singular along v: d the most in it
    H -= np.outer(v, v)
    why = _unidentifiable(["a", "b", "c", "d"], H, [True] * 4)
    assert list(why) == ["d"] and why["d"] == ("the likelihood is flat along it and a together (a estimated with "
                                               "it held, carrying its error)")


# ------------------------------------------------------------------- the two tanks, simulated at known levels
def tank_run(session, process: float, measurement: float, steps: int, seed: int) -> runs.Run:
    result = simulate.simulate(session.compiled.numerics, simulate.SimulationOptions(
        steps=steps, process_noise=process, measurement_noise=measurement, seed=seed))
    return runs.parse_run(simulate.to_csv(result), f"tanks-{seed}.csv")


def test_the_optimiser_given_its_differences_together_takes_the_path_it_takes_alone():
    """_fit of a likelihood that evaluates several points together (L-BFGS-B
    given the value with its forward differences from one call:
    ``_with_differences``) ends where the same likelihood evaluated one
    point at a time ends (SciPy taking the differences itself): the same
    maximum, log-likelihood, Hessian, message and evaluations, to the bit; on
    a function that is not quadratic and is -inf over part of the search
    (where the objective is ``high``), so a wrong step, bound or order of
    the differences moves the path."""
    class Alone:
        def __init__(self):
            self.evaluations = 0

        def __call__(self, z):
            self.evaluations += 1
            z = np.asarray(z, dtype=float)
            if z[0] > 2.2:
                return -math.inf
            return -float(3.0 * (z[0] - 1.3) ** 2 + 0.5 * (z[1] + 2.0) ** 4 + 0.2 * math.sin(z[0] * z[1]))

    class Together(Alone):
        def many(self, zs):
            return [self(z) for z in zs]

    alone, together = Alone(), Together()
    a = cal._fit(alone, np.array([0.5, 0.0]))
    b = cal._fit(together, np.array([0.5, 0.0]))
    assert np.array_equal(a[0], b[0]) and a[1] == b[1] and np.array_equal(a[2], b[2]), (a, b)
    assert a[3:] == b[3:] and a[3] and alone.evaluations == together.evaluations, (a[3:], b[3:])


def test_the_points_of_a_difference_evaluated_together_give_each_points_likelihood_bit_for_bit(tanks):
    """The likelihood at several points at once (a gradient's, a Hessian's:
    :meth:`_Likelihood.many`, the filters run side by side) is the
    likelihood at each point alone, to the bit: over two recordings, one
    with readings missing and a row with none, the sensors' noise, the
    process level, a parameter and the initial states all moved; so the
    calibration's optimiser takes the same path as it did one point at a
    time."""
    from bgc.model.protocol import nominal_model

    nominal = nominal_model(tanks.package)
    first = cal.record_of(tank_run(tanks, 0.02, 0.01, 60, seed=5), nominal)
    ys = first.ys.copy()
    ys[10, 0] = ys[20:25, 1] = np.nan
    ys[30] = np.nan
    second = cal.Record("gaps.csv", ys, first.us, first.ts)
    lik = cal._Likelihood(nominal, tanks.view.numerics, [first, second], list(nominal.OUTPUTS), True, ["R12"],
                          initial=[(0, 0), (1, 1)])
    z0 = lik.start()
    rng = np.random.default_rng(3)
    zs = [z0] + [z0 + 0.05 * rng.standard_normal(len(z0)) for _ in range(4)]
    one_by_one = [lik(z) for z in zs]
    assert lik.many(zs) == one_by_one and len(set(one_by_one)) == len(zs), one_by_one
    assert lik.evaluations == 2 * len(zs)


@pytest.mark.slow
def test_two_tank_noise_levels_near_the_truth(tanks):
    """Data simulated (RK4 with 8 substeps, not the filter's own step) at a
    process level of 0.01 and a sensor level of 0.03, unlike the model's 0.03
    and 0.02: each sensor's estimated level is within 5 standard errors of
    the ideal estimator (a std from T samples of known mean: relative error
    1 / sqrt(2 T)) of the truth, the process level within 4 standard errors
    of it (its interval's), and
    the calibrated file compiles to the estimated absolute stds."""
    T = 400
    run = tank_run(tanks, 0.01, 0.03, T, 11)
    r = fast_session("two_tank").calibrate(run)  # numba when installed: the same estimates, 5x faster
    c = r.calibration
    tolerance = 5 / math.sqrt(2 * T)
    for s in ("F10", "F12", "F20"):
        e = c.estimate(f"noise {s}")
        assert abs(e.level / 0.03 - 1) < tolerance, (s, e.level)
    p = c.estimate("process noise")
    # within 4 of its own standard errors (the interval is +-1.96 of them in log q) and not a vague one
    sd = math.log(p.high / p.low) / (2 * 1.96)
    assert abs(math.log(p.value / 0.01)) < 4 * sd and p.high / p.low < 2.5, (p.value, p.low, p.high)
    assert c.loglik > c.start_loglik
    for i in c.innovations:  # the calibrated model explains the data: white N(0, 1) innovations
        assert abs(i.mean) < 4 / math.sqrt(i.samples) and abs(i.variance - 1) < 5 * math.sqrt(2 / i.samples)
        assert i.p_value > 1e-3
    # the file: the compiler's absolute stds of the calibrated levels are the estimated ones
    numerics = compile_from_text(r.text).numerics
    for j, s in enumerate(("F10", "F12", "F20")):
        assert numerics.noise.measurement[j] == pytest.approx(c.estimate(f"noise {s}").value, rel=1e-5)
    assert numerics.equations.model.settings.process_noise == pytest.approx(p.value, rel=1e-5)


def compile_from_text(text: str):
    """The compiled model of a calibrated text (written to a temporary file)."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "calibrated.yaml"
        path.write_text(text, encoding="utf-8")
        return compile_model(path)


@pytest.mark.slow
@pytest.mark.long
def test_two_tank_parameter_interval_covers_the_truth(tanks, tmp_path):
    """A model whose R12 is 20 % off (2.4, the plant's is 2.0): calibrated on
    healthy data of the plant, R12's 95 % interval holds the truth and not
    the model's value."""
    off = TWO_TANK.read_text(encoding="utf-8").replace("R12: {value: 2.0,", "R12: {value: 2.4,")
    assert "R12: {value: 2.4," in off
    path = tmp_path / "two_tank_off.yaml"
    path.write_text(off, encoding="utf-8")
    run = tank_run(tanks, None, None, 300, 5)  # the plant at the model's noise levels
    r = bgc.open(path, backend=FAST).calibrate(run, "noise,R12")  # numba when installed: its kernels kept
    e = r.calibration.estimate("R12")
    assert e.identifiable and e.start == 2.4
    assert e.low < 2.0 < e.high < 2.4, (e.low, e.high)
    # a model this far off has a steep likelihood at its values: the optimiser still reaches the maximum (its
    # first step, the whole gradient, once left the region where the likelihood is finite, and the noise was
    # then held as "flat"), where every estimate is identifiable
    for x in r.calibration.estimates:
        assert x.identifiable, (x.name, x.why)
    assert r.calibration.converged and r.calibration.loglik > r.calibration.start_loglik + 100
    assert "# bgc calibrate: R12 " in r.text and "(was 2.4)" in r.text


# ------------------------------------------------------------------- the calibrated file
def test_text_edit_keeps_the_layout_and_adds_missing_keys():
    """Only value tokens change; a measurement without ``noise`` (an empty
    entry, a flow mapping, a block mapping) gets one, a model without
    ``simulation.process_noise`` gets it; comments survive; the result reads
    back with the values written."""
    text = ("# my plant\n"
            "name: rc_drain\n"
            "parameters: {R: 2.0, C: 0.5}   # both\n"
            "elements:\n"
            "  C: {kind: C, initial: 1.0, noise: 0.002}\n"
            "  j: {kind: \"1\"}\n"
            "  R: {kind: R}\n"
            "bonds: {1: [j, C], 2: [j, R]}\n"
            "measurements:\n"
            "  e1:\n"
            "  f1: {unit: A}\n"
            "  f2:\n"
            "    unit: A   # current\n"
            "simulation:\n"
            "  dt: 0.1\n")
    def est(kind, subject, value, level):
        return cal.Estimate(kind, subject, value, value * 0.9, value * 1.1, level, level * 0.9, level * 1.1,
                            1.0, 0.02)
    estimates = (est("measurement_noise", "e1", 0.03, 0.03), est("measurement_noise", "f1", 0.02, 0.04),
                 est("measurement_noise", "f2", 0.02, 0.05),
                 cal.Estimate("process_noise", "process", 0.06, 0.05, 0.07, 0.06, 0.05, 0.07, 0.03, 0.03),
                 est("parameter", "R", 2.5, 2.5),
                 cal.Estimate("parameter", "C", 0.5, math.nan, math.nan, 0.5, math.nan, math.nan, 0.5, 0.5, False,
                              "correlated +0.999 with R"))
    c = cal.Calibration(estimates, 0.0, -1.0, (), (), (), ("healthy.csv",), 10, True, "", 1, 0.1)
    out = calibrated_text(text, "plant.yaml", c, {"C": 0.002})
    assert out.startswith("# generated by bgc calibrate from plant.yaml on healthy.csv\n# my plant\n")
    assert "parameters: {R: 2.5, C: 0.5}   # both\n" in out
    assert "  e1: {noise: 0.03}\n" in out
    assert "  f1: {unit: A, noise: 0.04}\n" in out
    assert "    unit: A   # current\n" in out and "    noise: 0.05\n" in out
    assert "  C: {kind: C, initial: 1.0, noise: 0.004}\n" in out  # its own level scaled as the process level
    assert "simulation: {process_noise: 0.06}" not in out and "  process_noise: 0.06\n" in out
    assert "C kept at the model's 0.5" in out and "correlated +0.999 with R" in out
    data = yaml.safe_load(out)
    assert data["measurements"]["f2"] == {"unit": "A", "noise": 0.05}
    assert data["parameters"] == {"R": 2.5, "C": 0.5}
    assert data["elements"]["C"]["noise"] == 0.004
    # every comment of the original is still there, and every line of it but the changed ones
    changed = {"parameters: {R: 2.0, C: 0.5}   # both", "  e1:", "  f1: {unit: A}",
               "  C: {kind: C, initial: 1.0, noise: 0.002}"}
    assert all(line in out.split("\n") for line in text.split("\n") if line not in changed)


def test_text_edit_without_a_simulation_section():
    text = "name: m\nparameters:\n  R: 1.0\n"
    e = cal.Estimate("process_noise", "process", 0.01, 0.009, 0.011, 0.01, 0.009, 0.011, 0.03, 0.03)
    c = cal.Calibration((e,), 0.0, 0.0, (), (), (), ("a.csv", "b.csv"), 10, True, "", 1, 0.1)
    out = calibrated_text(text, "m.yaml", c, {}, ("2026-11-26",))
    assert yaml.safe_load(out)["simulation"] == {"process_noise": 0.01}
    assert "from a.csv, b.csv (recorded 2026-11-26) (was 0.03)" in out


def test_a_value_given_through_an_alias_is_refused():
    text = "name: m\nparameters:\n  R: &r 1.0\n  C: *r\n"
    e = cal.Estimate("parameter", "C", 2.0, 1.9, 2.1, 2.0, 1.9, 2.1, 1.0, 1.0)
    c = cal.Calibration((e,), 0.0, 0.0, (), (), (), ("a.csv",), 10, True, "", 1, 0.1)
    with pytest.raises(CalibrationError, match="parameters.C is written through a YAML alias"):
        calibrated_text(text, "m.yaml", c, {})


def test_writes_a_new_file_and_never_one_bgc_did_not_write(rc, tmp_path, monkeypatch, capsys):
    model = tmp_path / "rc.yaml"
    original = RC.read_bytes()
    model.write_bytes(original)
    run, _ = rc_run(rc, 0.05, 50, 4)
    data = tmp_path / "healthy.csv"
    data.write_text(runs.run_csv(run), encoding="utf-8")
    theirs = tmp_path / "theirs.yaml"
    theirs.write_text("name: theirs\n", encoding="utf-8")
    report = bgc.open(model).calibrate([str(data)], "measurement_noise")
    for path in (model, data, theirs):
        before = path.read_bytes()
        with pytest.raises(OutputError) as info:
            report.write(path)
        assert "\n" not in info.value.line()
        assert path.read_bytes() == before
    out = tmp_path / "calibrated.yaml"
    report.write(out)
    report.write(out)  # bgc's own file, unchanged since: replaced
    assert model.read_bytes() == original
    assert bgc.open(out).compiled.model.name == "rc_drain"  # a model like any other
    out.write_text(out.read_text(encoding="utf-8") + "# mine now\n", encoding="utf-8")
    with pytest.raises(OutputError, match="changed after bgc wrote it"):
        report.write(out)
    # the command line: the same refusal, one line, exit 1, before any work, and the model untouched
    def no_work(*args, **kwargs):
        raise AssertionError("calibrated before the output was checked")

    monkeypatch.setattr(bgc.api.Session, "calibrate", no_work)
    for path, message in ((theirs, "exists and bgc did not write it"), (model, "is the model file"),
                          (data, "is a data file"), (tmp_path, "is a folder")):
        status = cli.main(["calibrate", str(model), "--data", str(data), "--estimate", "measurement_noise",
                           "-o", str(path)])
        err = capsys.readouterr().err
        assert status == 1 and err.count("\n") == 1 and message in err, err
    assert theirs.read_text(encoding="utf-8") == "name: theirs\n"
    assert model.read_bytes() == original


@pytest.mark.slow
def test_cli_writes_the_calibrated_model(rc, tmp_path, capsys):
    run, _ = rc_run(rc, 0.05, 50, 6)
    data = tmp_path / "healthy.csv"
    data.write_text(runs.run_csv(run), encoding="utf-8")
    out = tmp_path / "cal.yaml"
    assert cli.main(["calibrate", str(RC), "--data", str(data), "--estimate", "measurement_noise",
                     "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "noise e1:" in printed and "Ljung-Box" in printed
    assert printed.rstrip().endswith("the model explains this data")
    text = out.read_text(encoding="utf-8")
    assert text.startswith("# generated by bgc calibrate from ") and "  e1: {noise: " in text
    # the report, beside it by default
    folder = tmp_path / "cal-report"
    assert f"report in {folder}" in printed
    assert sorted(p.name for p in folder.iterdir()) == ["autocorrelation.png", "estimates.png", "manifest.json",
                                                        "report.html", "report.json", "report.md", "residuals.png"]
    data_json = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    written = yaml.safe_load(text)["measurements"]["e1"]["noise"]
    (e,) = data_json["estimates"]
    assert e["name"] == "noise e1" and e["level"] == pytest.approx(written, rel=1e-5) and e["identifiable"]
    assert e["low"] < e["value"] < e["high"]
    assert data_json["verdict"] == "the model explains this data" and data_json["samples"] == 50
    md = (folder / "report.md").read_text(encoding="utf-8")
    assert "**The model explains this data.**" in md and "| e1 | 50 |" in md
    for name in ("estimates.png", "residuals.png", "autocorrelation.png"):
        assert (folder / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # again into the same folder: bgc's own, replaced; a folder of someone else's files: refused before any work
    assert cli.main(["calibrate", str(RC), "--data", str(data), "--estimate", "measurement_noise",
                     "-o", str(out)]) == 0
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine", encoding="utf-8")
    out2 = tmp_path / "cal2.yaml"
    capsys.readouterr()
    assert cli.main(["calibrate", str(RC), "--data", str(data), "--estimate", "measurement_noise",
                     "-o", str(out2), "--report", str(theirs)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds no bgc manifest.json" in err and not out2.exists()
    assert sorted(p.name for p in theirs.iterdir()) == ["notes.txt"]


@pytest.mark.slow
def test_report_autocorrelation_is_the_sample_autocorrelation(rc):
    """The autocorrelation pictured is, on one recording read throughout,
    the textbook sample autocorrelation sum (z_t - m)(z_t+k - m) / sum (z_t
    - m)^2 (here by numpy.correlate), and the Ljung-Box statistic is
    n (n + 2) sum_k r_k^2 / (n - k) over it. (The recording and calibration
    of test_rc_noise_variance_is_the_mean_squared_residual[1]: these are
    identities of whatever residuals the calibration leaves.)"""
    from bgc.output.calibration_report import autocorrelation

    c = noise_fitted(rc, 1, 50)[2].calibration
    z = c.residuals[0][:, 0]
    d = z - z.mean()
    full = np.correlate(d, d, mode="full")[len(d) - 1:] / (d @ d)
    rho = autocorrelation(c, 0, 20)
    assert np.allclose(rho, full[1:21], rtol=1e-10, atol=1e-14)
    (i,) = c.innovations
    n = len(z)
    q = n * (n + 2) * sum(full[k] ** 2 / (n - k) for k in range(1, i.lags + 1))
    assert i.ljung_box == pytest.approx(q, rel=1e-10)


@pytest.mark.parametrize("estimate, named", [
    ("noise,R9", "--estimate R9: not a parameter of rc_drain"),
    ("noise,,R", "--estimate 'noise,,R': an empty name"),
    ("", "--estimate '': an empty name"),
    ("R,R", "--estimate R: named twice"),
    ("e1", "--estimate e1: not a parameter of rc_drain"),
])
def test_bad_estimate_is_one_line(rc, tmp_path, capsys, estimate, named):
    run, _ = rc_run(rc, 0.05, 50, 7)
    data = tmp_path / "healthy.csv"
    data.write_text(runs.run_csv(run), encoding="utf-8")
    out = tmp_path / "cal.yaml"
    assert cli.main(["calibrate", str(RC), "--data", str(data), "--estimate", estimate, "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(named) and "Traceback" not in err, err
    assert not out.exists()
    with pytest.raises(CalibrationError):
        rc.calibrate(run, estimate)


def test_arguments_are_checked(rc):
    run, _ = rc_run(rc, 0.05, 20, 1)
    with pytest.raises(ArgumentValueError, match="a session opened with noise levels"):
        bgc.open(RC, measurement_noise=0.05).calibrate(run)
    with pytest.raises(ArgumentValueError, match="data=\\[\\] holds no recording"):
        rc.calibrate([])
    with pytest.raises(ArgumentTypeError, match="data=5 is not a path or a Run"):
        rc.calibrate(5)


def test_data_of_another_model_is_refused(rc, tanks):
    run = tank_run(tanks, None, None, 20, 1)
    with pytest.raises(DataError, match="is a run of model 'two_tank', not of 'rc_drain'"):
        rc.calibrate(run)


# ------------------------------------------------------------------- innovations
@pytest.mark.slow
@pytest.mark.long
def test_innovations_tell_a_model_that_misses_the_plant(rc, tmp_path):
    """The innovations of the calibrated model: white on data of the model's
    own plant; correlated (a tiny Ljung-Box p-value) and off 0 when the
    model's time constant is 1.5 times the plant's and only the noise is
    calibrated."""
    run, _ = rc_run(rc, 0.01, 200, 11)  # (seed 10 draws noise of mean -3.6 standard errors: a finding)
    fitted = rc.calibrate(run, "measurement_noise").calibration
    fits = fitted.innovations[0]
    assert fits.sensor == "e1" and fits.samples == 200 and fits.lags == 20
    assert fits.p_value > 1e-3 and abs(fits.mean) < 4 / math.sqrt(200)
    assert fitted.verdict == "the model explains this data"
    slow = tmp_path / "rc_slow.yaml"
    slow.write_text(RC.read_text(encoding="utf-8").replace("R: 2.0 ", "R: 3.0 "), encoding="utf-8")
    missed = bgc.open(slow).calibrate(run, "measurement_noise").calibration
    misses = missed.innovations[0]
    assert missed.findings == ("sensor e1's residuals are correlated (Ljung-Box p < 1e-300): the model misses a "
                               "dynamic",)
    # the model drains slower: it predicts high, the innovations (data minus prediction) are negative
    assert misses.p_value < 1e-6 and misses.mean < -4 / math.sqrt(200)


def test_ljung_box_against_its_formula_and_its_power():
    """Q = n (n + 2) sum_k r_k^2 / (n - k) (computed here with np.correlate);
    white noise passes, an AR(1) of coefficient 0.5 fails."""
    rng = np.random.default_rng(0)
    white = rng.standard_normal(500)
    a = white - white.mean()
    n, h = len(a), 10
    acf = np.correlate(a, a, "full")[n - 1:] / np.dot(a, a)
    expected = n * (n + 2) * sum(acf[k] ** 2 / (n - k) for k in range(1, h + 1))
    q, count = residuals.ljung_box([white], h)
    assert count == n and q == pytest.approx(expected, rel=1e-12)
    from scipy.stats import chi2

    assert chi2.sf(q, h) > 0.01
    ar = np.zeros(500)
    for t in range(1, 500):
        ar[t] = 0.5 * ar[t - 1] + white[t]
    assert chi2.sf(residuals.ljung_box([ar], h)[0], h) < 1e-10
    # a missing sample (NaN) breaks only the pairs it is in
    holed = white.copy()
    holed[100] = np.nan
    q_holed, count = residuals.ljung_box([holed], h)
    assert count == n - 1 and abs(q_holed - q) < 0.1 * q


def _ar1(rng, phi: float, n: int, draws: int) -> np.ndarray:
    """``draws`` stationary AR(1) series of coefficient ``phi`` and unit variance, ``n`` samples each."""
    e = rng.standard_normal((draws, n + 100))
    x = np.zeros_like(e)
    for t in range(1, n + 100):
        x[:, t] = phi * x[:, t - 1] + e[:, t]
    return x[:, 100:] * math.sqrt(1.0 - phi * phi)


def test_the_mean_test_holds_its_level_on_residuals_correlated_from_step_to_step():
    """The mean of n residuals correlated as an AR(1) of coefficient phi has
    variance (1 + phi) / (1 - phi) / n, not 1 / n: the correlation time is
    that ratio, and the mean test widened by it holds its level, where the
    white-noise standard error fails it three to four times as often (more
    than 2.5 times here: 1500 runs hold the rate within about 15 %)."""
    from dataclasses import replace
    from statistics import NormalDist

    rng = np.random.default_rng(5)
    long = _ar1(rng, 0.5, 20000, 1)[0]
    assert residuals.correlation_time([long]) == pytest.approx(3.0, rel=0.1)
    # read every other step: successive readings correlate by phi^2, their mean by (1 + phi^2) / (1 - phi^2)
    every_other = long.copy()
    every_other[1::2] = np.nan
    assert residuals.correlation_time([every_other]) == pytest.approx(1.25 / 0.75, rel=0.1)
    # a slow drift of the mean is what the mean test looks for: the correlation time is the noise's about the
    # recording's line, and a drift from the middle of the record to 1.2 stds still fails the test (its mean 5.2
    # white standard errors); counted as a correlation, it would widen its own standard error and pass
    white = rng.standard_normal(300)
    ramp = np.linspace(0.0, 0.6, 300)
    assert residuals.correlation_time([white + ramp]) == pytest.approx(residuals.correlation_time([white]), abs=1e-9)

    def failed_mean(draws) -> int:
        return sum([t for _, t in residuals.failures(residuals.summary([x[:, None]], ("y",)), 0.001,
                                                     correlation=False, narrower=False)] == ["mean"] for x in draws)

    late = np.concatenate([np.zeros(150), np.linspace(0.0, 1.2, 150)])
    drifts = [x - x.mean() + late for x in rng.standard_normal((40, 300))]
    assert failed_mean(drifts) >= 36
    import unittest.mock

    with unittest.mock.patch.object(residuals, "_detrended", lambda x: x - x.mean()):
        assert failed_mean(drifts) <= 10  # without the line: the drift hides itself
    assert residuals.correlation_time([rng.standard_normal(20000)]) == pytest.approx(1.0, abs=0.1)
    level, draws = 0.05, 1500
    nominal = 2 * (1 - NormalDist().cdf(NormalDist().inv_cdf(1 - level / 4)))  # the mean's share, two-sided

    def rate(x: np.ndarray, widen: bool) -> float:
        failed = 0
        for row in x:
            s = residuals.summary([row[:, None]], ("y",))
            if not widen:
                s = (replace(s[0], correlation_time=1.0),)
            failed += any(t == "mean" for _, t in residuals.failures(s, level, correlation=False, narrower=False))
        return failed / len(x)

    correlated = _ar1(rng, 0.3, 300, draws)
    assert rate(correlated, widen=False) > 2.5 * nominal  # 1 / sqrt(n) is too small for them
    assert rate(correlated, widen=True) < 2 * nominal
    white = rng.standard_normal((draws, 300))
    assert 0.4 * nominal < rate(white, widen=True) < 1.5 * nominal  # on white residuals it costs little


def test_a_maximum_by_its_own_test_is_converged_whatever_the_optimisers_flag(monkeypatch):
    """L-BFGS-B's line search can end "abnormally" on a likelihood that is not
    smooth at the finite differences' scale (a model's switches) while at its
    maximum: the fit is converged when the gradient and the Hessian say a
    maximum (a Newton step under 0.01), the optimiser's message kept; and not
    when they do not, whatever the optimiser says."""
    import scipy.optimize
    from types import SimpleNamespace

    def lik(z):  # a concave quadratic, its maximum at (1, -2)
        return -float(3.0 * (z[0] - 1.0) ** 2 + 0.5 * (z[1] + 2.0) ** 2 + 0.2 * (z[0] - 1.0) * (z[1] + 2.0))

    def stops_at(x):
        def minimize(fun, x0, **kwargs):
            return SimpleNamespace(x=np.asarray(x, dtype=float), success=False,
                                   message="ABNORMAL_TERMINATION_IN_LNSRCH")
        return minimize

    monkeypatch.setattr(scipy.optimize, "minimize", stops_at([1.0, -2.0]))
    z, best, H, converged, message = cal._fit(lik, np.array([0.5, 0.0]))
    assert converged and message.startswith("ABNORMAL_TERMINATION_IN_LNSRCH; at a maximum")
    assert z == pytest.approx([1.0, -2.0], abs=1e-6)
    assert np.allclose(H, [[6.0, 0.2], [0.2, 1.0]], rtol=1e-3)  # the negative log-likelihood's, by hand
    # stopped short of the maximum (a Newton step of 0.3): not converged, whatever the flag
    monkeypatch.setattr(scipy.optimize, "minimize", stops_at([1.3, -2.0]))
    monkeypatch.setattr(cal, "_gradient", lambda f, z, h: np.array([1.8, 0.06]))  # the gradient at (1.3, -2)
    monkeypatch.setattr(cal, "_hessian", lambda f, z, h, value: (np.array([1.8, 0.06]),
                                                                np.array([[6.0, 0.2], [0.2, 1.0]])))
    *_, converged, message = cal._fit(lambda z: lik(np.asarray(z)) if np.all(np.abs(np.asarray(z) - [1.3, -2.0]) < 1e-9)
                                      else -math.inf, np.array([0.5, 0.0]))
    assert not converged and message.startswith("no maximum reached")
