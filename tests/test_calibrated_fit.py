"""A calibrated model's test of fit allows for the calibration's own
uncertainty (issue 48: after calibration, fresh healthy data say "no
fault"). ``bgc calibrate`` fits one recording's noise too: a fresh recording
of the same plant, filtered with the calibrated model, has residuals whose
mean and variance scatter by their sampling error and by what the
estimates' uncertainty leaves (the delta method through the inverse
Hessian, bgc.analysis.calibrate._spread). The calibrated model file carries
it per sensor (``residual_mean_sd``, ``residual_variance_sd``), and the fit
test's standard errors add it (bgc.filters.residuals.failures).

Checked against closed forms on the RC drain of tests/test_calibrate.py
with no process noise: the filter's residuals are then the readings' errors
from the noise-free trajectory over the estimated std, whose log has
variance 1 / (2 T) (the Fisher information of log sigma is 2 T), so the
normalised residuals' variance var(e) / sigma^2 has the standard deviation
2 var(e) / sigma^2 / sqrt(2 T) and their mean mean(e) / sigma the standard
deviation |mean(e)| / sigma / sqrt(2 T)."""

import math
from statistics import NormalDist

import numpy as np
import pytest
import yaml

import bgc
from bgc.data import runs
from bgc.diagnosis.fit import LEVEL, fit, residual_sd
from bgc.filters.residuals import Innovations, failures

from conftest import TEST_MODELS
from test_calibrate import rc_run

RC = TEST_MODELS / "rc_drain.yaml"
T = 50


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The RC drain's sensor noise calibrated on ``rc_run(.., 0.05, T, 4)``:
    (the run, its noise-free readings, the report, the calibrated session)."""
    session = bgc.open(RC)
    run, clean = rc_run(session, 0.05, T, 4)
    report = session.calibrate(run, "measurement_noise")
    path = tmp_path_factory.mktemp("cal") / "rc_cal.yaml"
    path.write_text(report.text, encoding="utf-8")
    return run, clean, report, bgc.open(path)


def test_the_allowance_of_a_noise_estimate_is_its_closed_form(calibrated):
    run, clean, report, _ = calibrated
    e = run.measurements["e1"] - clean
    sigma2 = float(np.mean(e ** 2))  # the estimate (tests/test_calibrate.py's closed form)
    (sensor, mean_sd, variance_sd), = report.calibration.spread
    assert sensor == "e1"
    assert variance_sd == pytest.approx(2 * float(np.var(e)) / sigma2 / math.sqrt(2 * T), rel=1e-3)
    assert mean_sd == pytest.approx(abs(float(np.mean(e))) / math.sqrt(sigma2) / math.sqrt(2 * T), rel=1e-3)


def test_the_calibrated_file_carries_it_and_a_second_calibration_replaces_it(calibrated, tmp_path):
    run, _, report, session = calibrated
    (_, mean_sd, variance_sd), = report.calibration.spread
    entry = yaml.safe_load(report.text)["measurements"]["e1"]
    assert entry["residual_mean_sd"] == pytest.approx(mean_sd, rel=1e-5)
    assert entry["residual_variance_sd"] == pytest.approx(variance_sd, rel=1e-5)
    assert residual_sd(session.package.MODELS["nominal"]) == {"e1": (entry["residual_mean_sd"],
                                                                  entry["residual_variance_sd"])}
    assert "the test of the model's fit allows for it" in report.text
    # calibrated again (on a longer recording): the values are replaced where they stand, not added twice
    again = session.calibrate(rc_run(session, 0.05, 4 * T, 5)[0], "measurement_noise")
    assert again.text.count("residual_mean_sd") == 1 and again.text.count("residual_variance_sd") == 1
    (_, _, shorter), = again.calibration.spread
    assert yaml.safe_load(again.text)["measurements"]["e1"]["residual_variance_sd"] == pytest.approx(shorter, rel=1e-5)
    assert shorter < variance_sd  # four times the samples: about half the allowance
    # a model nobody calibrated has none
    assert residual_sd(bgc.open(RC).package.MODELS["nominal"]) == {}


def cut(tests: int) -> float:
    """The two-sided normal quantile of the fit test at LEVEL over ``tests`` tests (Bonferroni)."""
    return NormalDist().inv_cdf(1 - LEVEL / tests / 2)


@pytest.mark.parametrize("sd", [0.05, 0.2])
def test_the_fit_tests_standard_errors_add_the_allowance(sd):
    n, c = 300, cut(2)
    plain, allowed = math.sqrt(2 / n), math.sqrt(2 / n + sd * sd)
    between = 1 + c * (plain + allowed) / 2  # wider than the plain test allows, within the widened one
    wide = Innovations("y", n, 0.0, between, 0.0, 1, 1.0)
    assert failures([wide], LEVEL, correlation=False, narrower=False) == ((wide, "variance"),)
    assert failures([wide], LEVEL, correlation=False, narrower=False, spread={"y": (0.0, sd)}) == ()
    beyond = Innovations("y", n, 0.0, 1 + 1.01 * c * allowed, 0.0, 1, 1.0)
    assert failures([beyond], LEVEL, correlation=False, narrower=False, spread={"y": (0.0, sd)})
    off = Innovations("y", n, c * (1 / math.sqrt(n) + math.sqrt(1 / n + sd * sd)) / 2, 1.0, 0.0, 1, 1.0)
    assert failures([off], LEVEL, correlation=False, narrower=False) == ((off, "mean"),)
    assert failures([off], LEVEL, correlation=False, narrower=False, spread={"y": (sd, 0.0)}) == ()
    assert failures([off], LEVEL, correlation=False, narrower=False, spread={"other": (sd, sd)})


def test_fresh_data_within_the_allowance_fit_the_calibrated_model(calibrated):
    """A fresh recording whose readings' errors have exactly the variance
    ``ratio`` times the calibrated one's (mean 0): beyond what the plain
    test allows 400 samples, within what it allows with the calibration of
    50 samples beside them."""
    _, _, report, session = calibrated
    nominal = session.package.MODELS["nominal"]
    sigma = float(nominal.MEASUREMENT_STD[0])
    (_, _, variance_sd), = report.calibration.spread
    n = 400
    ratio = 1 + cut(2) * (math.sqrt(2 / n) + math.sqrt(2 / n + variance_sd ** 2)) / 2
    fresh, clean = rc_run(session, 0.0, n, 0)
    draws = np.random.default_rng(11).standard_normal(n)
    errors = (draws - draws.mean()) / draws.std() * sigma * math.sqrt(ratio)
    ys = (clean + errors)[:, None]
    us = np.zeros((n, 0))
    assert fit(nominal, ys, us, ("e1",), n).fits
    nominal.RESIDUAL_SD, kept = {}, nominal.RESIDUAL_SD
    try:
        plain = fit(nominal, ys, us, ("e1",), n)
    finally:
        nominal.RESIDUAL_SD = kept
    assert not plain.fits and plain.failed == ("variance",)
