"""A calibrated model's test of fit allows for the calibration's own
uncertainty (issue 48: after calibration, fresh healthy data say "no
fault"). ``bgc calibrate`` fits one recording's noise too: a fresh recording
of the same plant, filtered with the calibrated model, has residuals whose
variance scatters by its sampling error and by what the estimates'
uncertainty leaves (the delta method through the inverse Hessian,
bgc.analysis.calibrate._spread). The calibrated model file carries
it per sensor (``residual_variance_sd``), and the fit test averages the
variance's chi-square tail over a log-normal factor of that log-std
(bgc.filters.residuals.failures, variance_z).

Checked against a closed form on the RC drain of tests/test_calibrate.py
with no process noise: the filter's residuals are then the readings' errors
e from the noise-free trajectory over the estimated std, whose log has
variance 1 / (2 T) (the Fisher information of log sigma is 2 T), so the
normalised residuals' variance var(e) / sigma^2, whose derivative in log
sigma is -2 var(e) / sigma^2, has the standard deviation 2 var(e) / sigma^2
/ sqrt(2 T)."""

import math
from statistics import NormalDist

import numpy as np
import pytest
import yaml

import bgc
from bgc.errors import CalibrationError
from bgc.diagnosis.fit import LEVEL, fit, residual_sd
from bgc.filters.residuals import Innovations, failures, largest_square

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
    (sensor, variance_sd), = report.calibration.spread
    assert sensor == "e1"
    assert variance_sd == pytest.approx(2 * float(np.var(e)) / sigma2 / math.sqrt(2 * T), rel=1e-3)


def test_an_initial_state_estimated_beside_it_leaves_the_allowance_and_no_noise_estimated_none(calibrated):
    """The recordings' initial states are not kept in the model file: their
    part of the estimates' covariance is marginalised out, their gradient
    not counted (on the RC drain with no process noise the start is the
    least-squares one, uncorrelated with the noise's log: the allowance is
    the noise's alone). A calibration of parameters alone leaves the
    noise, and its allowance, as they were: none written."""
    _, _, report, _ = calibrated
    session = bgc.open(RC)
    (_, alone), = report.calibration.spread
    started, _ = rc_run(session, 0.05, T, 4, start=0.8)  # the same noise, from 0.8 where the model says 1.0
    (_, with_start), = session.calibrate(started, "measurement_noise,initial").calibration.spread
    assert with_start == pytest.approx(alone, rel=0.05)  # with the start's gradient counted: 0.357 against 0.199
    run = started
    parameters_only = session.calibrate(run, "R")
    assert parameters_only.calibration.spread == () and "residual_variance_sd" not in parameters_only.text


def test_the_calibrated_file_carries_it_and_a_second_calibration_replaces_it(calibrated):
    run, _, report, session = calibrated
    (_, variance_sd), = report.calibration.spread
    entry = yaml.safe_load(report.text)["measurements"]["e1"]
    assert entry["residual_variance_sd"] == pytest.approx(variance_sd, rel=1e-5)
    assert residual_sd(session.package.MODELS["nominal"]) == {"e1": entry["residual_variance_sd"]}
    assert "the test of the model's fit allows for it" in report.text
    # calibrated again (on a longer recording): the value is replaced where it stands, not added twice
    again = session.calibrate(rc_run(session, 0.05, 4 * T, 5)[0], "measurement_noise")
    assert again.text.count("residual_variance_sd:") == 1
    (_, shorter), = again.calibration.spread
    assert yaml.safe_load(again.text)["measurements"]["e1"]["residual_variance_sd"] == pytest.approx(shorter, rel=1e-5)
    assert shorter == pytest.approx(variance_sd / 2, rel=0.15)  # four times the samples: half the allowance
    # a model nobody calibrated has none
    assert residual_sd(bgc.open(RC).package.MODELS["nominal"]) == {}


@pytest.mark.parametrize("spelled", ["e1: {noise: 0.02}", "e1: {}", "e1: {noise: 0.02, }", "e1:",
                                     "e1:\n    noise: 0.02", "e1: {unit: V}", "e1: {noise: 0.02,   # c\n    }"])
def test_written_into_every_spelling_of_a_measurement(calibrated, tmp_path, spelled):
    """The measurement as a flow mapping (empty, or with a trailing comma),
    with no fields, or as a block mapping: the calibrated text reads back
    (bgc's own reader, the estimates as written) with the noise and the
    allowance in it."""
    run, _, report, _ = calibrated
    text = RC.read_text(encoding="utf-8").replace("  e1: {noise: 0.02}", "  " + spelled.replace("\\n", "\n"))
    assert text != RC.read_text(encoding="utf-8") or spelled == "e1: {noise: 0.02}"
    path = tmp_path / "rc.yaml"
    path.write_text(text, encoding="utf-8")
    out = bgc.open(path).calibrate(run, "measurement_noise")
    entry = yaml.safe_load(out.text)["measurements"]["e1"]
    (_, variance_sd), = out.calibration.spread
    assert entry["noise"] == pytest.approx(out.calibration.estimate("noise e1").level, rel=1e-5)
    assert entry["residual_variance_sd"] == pytest.approx(variance_sd, rel=1e-5)


def test_a_sensor_the_data_never_read_keeps_its_noise_and_gets_no_allowance(calibrated, tmp_path, recwarn):
    run, _, _, _ = calibrated
    path = tmp_path / "two.yaml"
    path.write_text(RC.read_text(encoding="utf-8").replace("  e1: {noise: 0.02}\n", "  e1: {noise: 0.02}\n"
                                                           "  f2: {noise: 0.02}\n"), encoding="utf-8")
    out = bgc.open(path).calibrate(run, "noise")
    kept = out.calibration.estimate("noise f2")
    assert not kept.identifiable and kept.why == "no sample of it in the data"
    assert [s for s, _ in out.calibration.spread] == ["e1"]
    assert "residual_variance_sd" not in str(yaml.safe_load(out.text)["measurements"]["f2"])
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def cut(tests: int) -> float:
    """The two-sided normal quantile of the fit test at LEVEL over ``tests`` tests (Bonferroni)."""
    return NormalDist().inv_cdf(1 - LEVEL / tests / 2)


def exact_tail(n: int, variance: float, sd: float, above: bool = True) -> float:
    """The probability that ``n`` N(0, 1) residuals, their variance about
    their mean (n - 1 degrees of freedom), show a variance beyond
    ``variance`` (above it, or below it without ``above``) when their
    model's variance is itself off by a log-normal factor of log-std ``sd``
    (a calibration's error, normal in the noise's log): scipy.stats' chi-square
    averaged over that factor by adaptive quadrature."""
    from scipy.integrate import quad
    from scipy.stats import chi2, norm

    tail = chi2.sf if above else chi2.cdf
    if sd == 0:
        return float(tail(n * variance, n - 1))
    return float(quad(lambda x: tail(n * variance / math.exp(sd * x), n - 1) * norm.pdf(x), -12, 12,
                      epsabs=1e-13, limit=200)[0])


def threshold(n: int, sd: float, narrower: bool) -> float:
    """The variance at which ``failures`` starts to fail a sensor of ``n``
    residuals (above 1, or below it with ``narrower``), by bisection; the
    variance without the farthest reading left unset (NaN), the mean 0."""
    def fails(v: float) -> bool:
        i = Innovations("y", n, 0.0, v, 0.0, 1, 1.0)
        return bool(failures([i], LEVEL, correlation=False, narrower=narrower, spread={"y": sd}))

    lo, hi = (1.0, 50.0) if not narrower else (1e-9, 1.0)
    for _ in range(80):
        mid = (lo + hi) / 2
        if fails(mid) == narrower:  # a failure below 1: the threshold is above mid; above 1: below it
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


@pytest.mark.parametrize("n", [45, 300, 20000])
@pytest.mark.parametrize("sd", [0.0, 0.05, 0.2])
def test_the_variance_test_has_its_size_on_either_side(n, sd):
    # each tail of the variance test rejects a fitting model as often as its level says (LEVEL over two
    # tests, two-sided), against the chi-square's exact tail: the variance's own scale rejected 2.8 (n = 300)
    # to 7 (n = 45) times as often above 1 and a fifth as often or less below it
    alpha = LEVEL / 2 / 2
    above = exact_tail(n, threshold(n, sd, narrower=False), sd)
    below = exact_tail(n, threshold(n, sd, narrower=True), sd, above=False)
    assert above == pytest.approx(alpha, rel=0.01)
    assert below == pytest.approx(alpha, rel=0.01)


def test_the_fit_tests_standard_errors_add_the_allowance():
    n, sd = 300, 0.1
    between = (threshold(n, 0.0, False) + threshold(n, sd, False)) / 2  # beyond the plain test, within the widened
    wide = Innovations("y", n, 0.0, between, 0.0, 1, 1.0)
    assert failures([wide], LEVEL, correlation=False, narrower=False) == ((wide, "variance"),)
    assert failures([wide], LEVEL, correlation=False, narrower=False, spread={"y": sd}) == ()
    assert failures([wide], LEVEL, correlation=False, narrower=False, spread={"other": sd})
    # the variance without the farthest reading: against its own expectation (n - E[the largest square]) / (n -
    # 1), the same allowance beside it; a glitch leaves it there however far the one reading was
    expected = (n - largest_square(n)) / (n - 1)
    far = 1.5 * threshold(n, sd, False)
    glitch = Innovations("y", n, 0.0, far, 0.0, 1, 1.0, expected)
    assert failures([glitch], LEVEL, correlation=False, narrower=False, spread={"y": sd}) == ()
    noisy = Innovations("y", n, 0.0, far, 0.0, 1, 1.0, expected * far)
    assert failures([noisy], LEVEL, correlation=False, narrower=False, spread={"y": sd}) == ((noisy, "variance"),)
    # the mean's test takes no allowance
    c = cut(2)
    off = Innovations("y", n, 1.01 * c / math.sqrt(n), 1.0, 0.0, 1, 1.0)
    assert failures([off], LEVEL, correlation=False, narrower=False, spread={"y": sd}) == ((off, "mean"),)


def test_fresh_data_within_the_allowance_fit_the_calibrated_model(calibrated):
    """A fresh recording whose readings' errors have exactly the variance
    ``ratio`` times the calibrated one's (mean 0): beyond what the plain
    test allows 400 samples, within what it allows with the calibration of
    50 samples beside them."""
    _, _, report, session = calibrated
    nominal = session.package.MODELS["nominal"]
    sigma = float(nominal.MEASUREMENT_STD[0])
    (_, variance_sd), = report.calibration.spread
    n = 400
    ratio = (threshold(n, 0.0, False) + threshold(n, variance_sd, False)) / 2
    fresh, clean = rc_run(session, 0.0, n, 0)
    draws = np.random.default_rng(11).standard_normal(n)
    errors = (draws - draws.mean()) / draws.std() * sigma * math.sqrt(ratio)
    ys = (clean + errors)[:, None]
    us = np.zeros((n, 0))
    assert fit(nominal, ys, us, ("e1",), n).fits
    nominal.RESIDUAL_VARIANCE_SD, kept = {}, nominal.RESIDUAL_VARIANCE_SD
    try:
        plain = fit(nominal, ys, us, ("e1",), n)
    finally:
        nominal.RESIDUAL_VARIANCE_SD = kept
    assert not plain.fits and plain.failed == ("variance",)


def test_a_measurement_given_through_an_alias_is_refused_not_changed_everywhere(calibrated, tmp_path):
    """``e1: &m {unit: V}`` and another sensor ``f2: *m``: adding the noise
    and the allowance to the anchor's mapping would change f2 too; the
    calibration is refused in one line, as a value given through an alias is."""
    run, _, _, _ = calibrated
    path = tmp_path / "alias.yaml"
    path.write_text(RC.read_text(encoding="utf-8").replace("  e1: {noise: 0.02}\n", "  e1: &m {unit: V}\n  f2: *m\n"),
                    encoding="utf-8")
    with pytest.raises(CalibrationError, match="alias"):
        bgc.open(path).calibrate(run, "measurement_noise")
