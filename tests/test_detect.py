"""The detector (bgc.diagnosis.detect): its threshold, its false-alarm rate per
run on white residuals, its detection of a mean shift and its onset."""

import dataclasses
import math

import numpy as np
import pytest

from bgc.diagnosis.detect import Detector, DetectorBank, DetectorOptions, monte_carlo_share
from bgc.diagnosis import detect


def normal_quantile(p: float) -> float:
    """Phi^-1(p) by bisection on erfc (independent of the module's NormalDist)."""
    lo, hi = -10.0, 10.0
    for _ in range(200):
        mid = (lo + hi) / 2
        if 0.5 * math.erfc(-mid / math.sqrt(2)) < p:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def test_threshold_is_the_union_bound_of_a_per_run_false_alarm_rate():
    """alpha = 0.01 over 300 steps, 4 sensors and 3 windows: 3600 tests, each
    two-sided at 0.01 / 3600: c = Phi^-1(1 - 0.01 / 7200) = 4.687."""
    options = DetectorOptions(false_alarm=0.01, windows=(1, 8, 32), steps=300)
    c = options.threshold(4)
    assert c == pytest.approx(normal_quantile(1 - 0.01 / 7200), abs=1e-6)
    assert c == pytest.approx(4.687, abs=1e-3)
    # fewer sensors or steps: a lower threshold; a stricter rate: a higher one
    assert options.threshold(1) < c < DetectorOptions(false_alarm=0.001, steps=300).threshold(4)


@pytest.mark.slow
def test_false_alarms_per_run_stay_below_the_target_on_white_residuals():
    """600 fault-free runs of 300 steps x 4 sensors of N(0, 1) residuals: the
    share of runs with any alarm stays below alpha (the bound is
    conservative), but not by orders of magnitude (the windows are tested)."""
    alpha = 0.05
    rng = np.random.default_rng(7)
    runs, alarms = 600, 0
    for _ in range(runs):
        det = Detector(("a", "b", "c", "d"), DetectorOptions(false_alarm=alpha, steps=300))
        z = rng.standard_normal((300, 4))
        if any(det.update(z[k]) is not None for k in range(300)):
            alarms += 1
    rate = alarms / runs
    sigma = math.sqrt(alpha * (1 - alpha) / runs)
    assert rate <= alpha + 3 * sigma, rate
    assert rate >= alpha / 10, rate


def test_a_jump_is_caught_at_once_and_its_onset_found():
    rng = np.random.default_rng(3)
    z = rng.standard_normal((300, 3))
    z[120:, 1] += 6.0  # a jump of 6 sigma on sensor b at step 120
    det = Detector(("a", "b", "c"), DetectorOptions(steps=300))
    alarm = next(a for k in range(300) if (a := det.update(z[k])) is not None)
    assert alarm.sensor == "b" and 120 <= alarm.step <= 122 and abs(alarm.onset_step - 120) <= 1


def test_a_small_persistent_shift_is_caught_by_a_long_window_and_its_onset_found():
    """A shift of 1.5 sigma is invisible in one sample (the threshold is 4.6)
    but not in 32: 32 x 1.5 / sqrt(32) = 8.5 (about 10 samples reach 4.6)."""
    rng = np.random.default_rng(11)
    z = rng.standard_normal((300, 3))
    z[150:, 0] += 1.5
    det = Detector(("a", "b", "c"), DetectorOptions(steps=300))
    alarm = next(a for k in range(300) if (a := det.update(z[k])) is not None)
    assert alarm.sensor == "a" and alarm.window > 1 and 150 <= alarm.step <= 180
    assert abs(alarm.onset_step - 150) <= 10


def test_missing_samples_do_not_alarm():
    det = Detector(("a",), DetectorOptions(steps=10))
    assert all(det.update(np.array([np.nan])) is None for _ in range(10))


def test_monte_carlo_share_by_hand():
    """y_std 2, measurement std 1.2: the particles' share of the variance is
    4 - 1.44 = 2.56; ESS 100 of N = 1000: 2.56 (1/100 + 1/1000) = 0.02816,
    whose root over y_std is 0.16781 / 2 = 0.083905."""
    a = monte_carlo_share(np.array([2.0, 1.0]), np.array([1.2, 1.0]), 100.0, 1000)
    assert a[0] == pytest.approx(math.sqrt(0.02816) / 2, rel=1e-12)
    assert a[0] == pytest.approx(0.083905, abs=1e-6)
    assert a[1] == 0.0  # all measurement noise: no Monte Carlo error


def test_window_statistic_widens_by_the_monte_carlo_share_by_hand():
    """z = 1 and a = 0.25 on every step: after 8 steps the 8-sample window is
    8 / sqrt(8 + (8 x 0.25)^2) = 8 / sqrt(12) = 2.3094, the one-sample window
    1 / sqrt(1 + 0.0625) = 0.9701; without the shares 8 / sqrt(8) = 2.8284."""
    for mc, want in ((np.array([0.25]), 8 / math.sqrt(12)), (None, math.sqrt(8))):
        det = Detector(("a",), DetectorOptions(windows=(1, 8), steps=8))
        for _ in range(8):
            det.update(np.array([1.0]), mc)
        assert det.statistics[-1][0] == pytest.approx(want, rel=1e-12)
    det = Detector(("a",), DetectorOptions(windows=(1,), steps=1))
    det.update(np.array([1.0]), np.array([0.25]))
    assert det.statistics[-1][0] == pytest.approx(1 / math.sqrt(1.0625), rel=1e-12)


@pytest.mark.slow
def test_the_allowance_keeps_the_rate_when_the_prediction_has_a_slow_monte_carlo_error():
    """Residuals = white N(0, 1) + a slowly varying prediction error of std
    0.15 (AR(1), coefficient 0.97: ancestors shared over tens of steps). A
    32-sample window sum then has variance about 32 + 0.0225 x 759 = 49
    instead of 32 (759: the sum of 0.97^|i-j| over the window's pairs):
    alarms well above the target without the allowance, below it with the
    allowance (which takes the error as fully correlated: 32 + 0.0225 x 1024)."""
    alpha, runs, sd, rho = 0.05, 400, 0.15, 0.97
    rng = np.random.default_rng(21)
    plain = allowed = 0
    for _ in range(runs):
        e = np.empty((300, 2))
        e[0] = sd * rng.standard_normal(2)
        for k in range(1, 300):
            e[k] = rho * e[k - 1] + sd * math.sqrt(1 - rho * rho) * rng.standard_normal(2)
        z = rng.standard_normal((300, 2)) + e
        a = np.full(2, sd)
        d1 = Detector(("a", "b"), DetectorOptions(false_alarm=alpha, steps=300))
        d2 = Detector(("a", "b"), DetectorOptions(false_alarm=alpha, steps=300))
        plain += any(d1.update(z[k]) is not None for k in range(300))
        allowed += any(d2.update(z[k], a) is not None for k in range(300))
    sigma = math.sqrt(alpha * (1 - alpha) / runs)
    assert plain / runs > alpha + 3 * sigma, plain
    assert allowed / runs <= alpha + 3 * sigma, allowed


def test_monte_carlo_share_takes_an_effective_sample_size_per_step():
    """An array of ESS (one per step) gives, row by row, what the scalar call gives."""
    y_std = np.array([[2.0, 1.5], [2.0, 1.5]])
    r = np.array([1.2, 1.0])
    a = monte_carlo_share(y_std, r, np.array([[100.0], [10.0]]), 1000)
    np.testing.assert_allclose(a[0], monte_carlo_share(y_std[0], r, 100.0, 1000), rtol=1e-15)
    np.testing.assert_allclose(a[1], monte_carlo_share(y_std[1], r, 10.0, 1000), rtol=1e-15)
    assert a[0, 0] == pytest.approx(0.083905, abs=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_detector_bank_gives_each_row_what_its_own_detector_gives(seed):
    """Rows that start at different steps, with their own thresholds (records
    of different lengths), residuals with jumps, NaNs and Monte Carlo shares,
    joining and leaving: every row's alarms (step, sensor, window, statistic,
    threshold, onset) are those of a Detector fed the same numbers alone (a
    row not located: the same alarms without their onset)."""
    rng = np.random.default_rng(seed)
    sensors = ("a", "b", "c")
    T, starts = 120, [0, 3, 10, 41, 90]
    options = [DetectorOptions(0.001 * (1 + i), (1, 8, 32), T - s) for i, s in enumerate(starts)]
    bank = DetectorBank(sensors, starts, options, T)
    alone = [Detector(sensors, o) for o in options]
    alarms = 0
    for k in range(T):
        rows = [r for r, s in enumerate(starts) if s <= k and not (r == 1 and k > 60)]  # row 1 leaves at 61
        z = rng.standard_normal((len(rows), 3)) + (3.5 if k > 70 else 0.0) * (rng.random((len(rows), 3)) < 0.3)
        z[rng.random(z.shape) < 0.05] = np.nan
        mc = 0.1 * rng.random(z.shape)
        locate = [r != 2 for r in rows]  # row 2's alarms come without their onset
        got = bank.update(k, rows, z, mc, locate)
        for i, r in enumerate(rows):
            want = alone[r].update(z[i], mc[i])
            if want is not None and not locate[i]:
                want = dataclasses.replace(want, onset_step=None)
            assert got[i] == want, (k, r)
            alarms += want is not None
    assert alarms > 10


def test_a_detector_bank_announced_short_takes_a_row_that_starts_far_past_its_room():
    """A bank made with room for no step (the trackers' own) whose rows
    step at 0 to 59 and then a row that starts at step 139 (an onset tried
    well after the first): it makes room up to that step (it once grew by
    its own size only and failed with an IndexError at step 139 of 130; a
    sweep's run at commit b99c47d, its room 65 steps), and that row alarms
    as its own detector."""
    rng = np.random.default_rng(0)
    sensors = ("a", "b", "c")
    starts = [0, 139]
    options = [DetectorOptions(0.01, (1, 8, 32), 300)] * 2
    bank = DetectorBank(sensors, starts, options, 0)
    alone = Detector(sensors, options[1])
    for k in range(60):  # room for 65 steps made at step 0
        bank.update(k, [0], rng.standard_normal((1, 3)), np.zeros((1, 3)))
    for k in range(139, 160):
        z = rng.standard_normal((1, 3)) + (6.0 if k >= 150 else 0.0)
        got = bank.update(k, [1], z, np.zeros((1, 3)))
        assert got[0] == alone.update(z[0], np.zeros(3)), k
    assert got[0] is not None


@pytest.mark.parametrize("windows", [(1, 8, 32), (32, 1, 8), (5,)])
def test_the_statistics_are_the_window_sums_computed_directly(windows):
    """Every step's statistic, per sensor the largest over the windows that
    fit in the record of |sum z| / sqrt(W + (sum a)^2), against the window
    sums taken afresh from the residuals (no running sums); NaN counts 0; a
    record shorter than every window tests nothing (0). Longer runs than the
    detector keeps sums for (the longest window's reach): 200 steps."""
    rng = np.random.default_rng(5)
    T, n = 200, 3
    z = rng.standard_normal((T, n)) + 0.3
    z[rng.random(z.shape) < 0.1] = np.nan
    a = 0.2 * rng.random((T, n))
    det = Detector(("a", "b", "c"), DetectorOptions(windows=windows, steps=T))
    for k in range(T):
        det.update(z[k], a[k])
        zs, as_ = np.nan_to_num(z[: k + 1]), a[: k + 1]
        fits = [w for w in windows if w <= k + 1]
        want = (np.max([np.abs(zs[-w:].sum(axis=0)) / np.sqrt(w + as_[-w:].sum(axis=0) ** 2) for w in fits], axis=0)
                if fits else np.zeros(n))
        np.testing.assert_allclose(det.statistics[k], want, rtol=1e-11, atol=1e-13)


def test_the_chi_squares_quantiles_and_log_tails_are_scipy_stats_own():
    """The detector's chi-square quantiles and log tails (scipy.special's
    functions, so that a diagnosis does not import scipy.stats, a second in
    every process) give scipy.stats.chi2's numbers to the bit, on both sides
    of the median where its log tails switch between log and log1p."""
    from scipy.stats import chi2

    df = np.arange(1, 256)
    for level in (1e-3, 2.5e-5, 0.01 / 7):
        assert np.array_equal(detect.chi2_ppf(level, df), chi2.ppf(level, df))
        assert np.array_equal(detect.chi2_isf(level, df), chi2.isf(level, df))
    for q in (0.0, 1e-9, 0.3, 0.99, 1.0, 4.0, 31.0, 120.0, 900.0):
        for k in (1, 2, 5, 31, 64):
            assert detect.chi2_logcdf(q, k) == float(chi2.logcdf(q, k)), (q, k)
            assert detect.chi2_logsf(q, k) == float(chi2.logsf(q, k)), (q, k)
