"""The detector (bgc.runtime.detect): its threshold, its false-alarm rate per
run on white residuals, its detection of a mean shift and its onset."""

import math

import numpy as np
import pytest

from bgc.runtime.detect import Detector, DetectorOptions


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
    assert alarm.sensor == "b" and 120 <= alarm.step <= 122 and abs(alarm.onset - 120) <= 1


def test_a_small_persistent_shift_is_caught_by_a_long_window_and_its_onset_found():
    """A shift of 1.5 sigma is invisible in one sample (the threshold is 4.6)
    but not in 32: 32 x 1.5 / sqrt(32) = 8.5 (about 10 samples reach 4.6)."""
    rng = np.random.default_rng(11)
    z = rng.standard_normal((300, 3))
    z[150:, 0] += 1.5
    det = Detector(("a", "b", "c"), DetectorOptions(steps=300))
    alarm = next(a for k in range(300) if (a := det.update(z[k])) is not None)
    assert alarm.sensor == "a" and alarm.window > 1 and 150 <= alarm.step <= 180
    assert abs(alarm.onset - 150) <= 10


def test_missing_samples_do_not_alarm():
    det = Detector(("a",), DetectorOptions(steps=10))
    assert all(det.update(np.array([np.nan])) is None for _ in range(10))
