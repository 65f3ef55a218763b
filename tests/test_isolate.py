"""Qualitative isolation (bgc.diagnosis.isolate): magnitude and slope symbols
from window tests on open-loop deviations, tested against the particle paths'
own spread, and their agreement with the circuit's signatures (see
tests/test_signatures.py for the signatures derived by hand)."""

import numpy as np
import pytest

from bgc.diagnosis.isolate import OpenLoop, consistent, expected_slope, first_symbol, hypotheses, observed_symbols, slope_z, threshold, window_z
from bgc.diagnosis.values import Symbol

from conftest import compiled


def white(deviation, noise, particles=400):
    """An open loop whose paths do not spread: only white measurement noise."""
    return OpenLoop(100, deviation, np.zeros(deviation.shape + (particles,)), np.full(deviation.shape[1], noise))


def test_window_z_of_white_noise_is_the_window_sum_over_its_std():
    """Hand value: 8 samples of 1.5 with noise std 0.5 sum to 12, whose std is
    0.5 sqrt(8): Z = 12 / (0.5 sqrt 8) = 8.485."""
    run = white(np.full((10, 1), 1.5), 0.5)
    z = window_z(run, (8,))[8]
    assert np.isnan(z[:7]).all() and z[7:, 0] == pytest.approx(12 / (0.5 * np.sqrt(8)))


def test_a_sensor_that_leaves_its_band_gives_its_sign_step_and_window():
    rng = np.random.default_rng(5)
    d = 0.5 * rng.standard_normal((60, 3))
    d[4:, 1] -= 8.0   # sensor b drops far below the nominal prediction from row 4: one sample shows it
    d[10:, 2] += 0.6  # sensor c rises a little from row 10: only a long window shows it
    seen = observed_symbols(white(d, 0.5), ("a", "b", "c"))
    assert [(s.sensor, s.sign, s.step) for s in seen[:1]] == [("b", "-", 104)]
    (c,) = [s for s in seen if s.sensor == "c"]
    assert c.sign == "+" and c.window == 32 and 110 < c.step < 142
    assert all(s.sensor != "a" for s in seen)


def test_a_deviation_the_nominal_paths_also_show_is_no_symbol():
    """The paths carry the plant's persistent deviations (each particle a
    constant offset of std 2): a long excursion at 2 is within them, though
    the white measurement noise alone would call it a deviation."""
    rng = np.random.default_rng(1)
    d = np.full((40, 1), 2.0)
    offsets = 2.0 * rng.standard_normal(2000)
    run = OpenLoop(0, d, np.broadcast_to(offsets, (40, 1, 2000)).copy(), np.array([0.1]))
    assert observed_symbols(run, ("a",)) == ()
    assert observed_symbols(white(d, 0.1), ("a",))[0].sign == "+"
    assert threshold(0.01, 1, 40, 3) > 3.5


def test_a_jump_that_decays_has_the_slope_of_its_recovery():
    """Jump of +3 at row 5 that decays by a factor 0.9 per sample, noise 0.1:
    magnitude + at row 5 (one sample), slope - over the 8 samples after it."""
    t = np.arange(40)
    d = np.where(t >= 5, 3.0 * 0.9 ** (t - 5), 0.0)[:, None]
    (s,) = observed_symbols(white(d, 0.1), ("a",))
    assert (s.sign, s.step, s.window, s.slope) == ("+", 105, 1, "-")
    assert slope_z(white(d, 0.1), 0, 35, 8) is None  # not 8 samples left


def test_expected_slope_by_hand():
    assert expected_slope(("+", "-", "+")) == "-"  # a jump, then the transient back
    assert expected_slope(("0", "-", "+")) == "-"  # first seen at order 1: it grows as it moved
    assert expected_slope(("+", "0", "-")) == "-"  # flat after the jump, then bends down
    assert expected_slope(("+", "?", "-")) == "?"
    assert expected_slope(("0", "0", "0")) == "0"


def test_first_symbol():
    assert first_symbol(("0", "0", "-", "+")) == "-" and first_symbol(("0", "0")) == "0"


def test_circuit_symbols_against_signatures():
    """R2+ abrupt: f6 falls first (signature f6 -+-); L+ abrupt cannot move f2
    (its f2 signature is 0 at every order shown) but moves e11 first, down."""
    s = compiled("circuit").signatures
    m = s.measurements
    r2 = s.get("R2+:abrupt")
    assert consistent(r2, m, (Symbol("f6", "-", 5, -9.0),)) is None
    assert consistent(r2, m, (Symbol("f6", "+", 5, 9.0),)) == "f6 deviated +, R2+:abrupt predicts -"
    ell = s.get("L+:abrupt")
    assert all(c == "0" for c in dict(zip(m, ell.symbols))["f2"][:3])
    assert consistent(ell, m, (Symbol("e11", "-", 5, -9.0),)) is None
    keep, dropped = hypotheses(s, (Symbol("f6", "-", 5, -9.0), Symbol("e11", "-", 6, -9.0)))
    names = {x.name for x in keep}
    assert "R2+:abrupt" in names and "R1-:abrupt" not in names
    assert dropped and all(why for _, why in dropped)


def test_the_slope_separates_a_step_from_a_drift_of_the_same_resistor():
    """R1 up (circuit): f2 = (Ve - e4) / R1. A step of R1 makes f2 jump down;
    C1 then gets less current, e4 falls and f2 recovers: signature -+- (down,
    then rising). A drift of R1 moves f2 from zero at order 1: 0-+ (falling).
    f2 seen down and rising fits the step only; down and falling, the drift
    only."""
    s = compiled("circuit").signatures
    m = s.measurements
    step, drift = s.get("R1+:abrupt"), s.get("R1+:incipient")
    rising, falling = Symbol("f2", "-", 5, -9.0, 1, "+", 5.0), Symbol("f2", "-", 5, -9.0, 1, "-", -5.0)
    assert consistent(step, m, (rising,)) is None
    assert consistent(drift, m, (rising,)) == "f2's slope is +, R1+:incipient predicts -"
    assert consistent(drift, m, (falling,)) is None
    assert consistent(step, m, (falling,)) == "f2's slope is -, R1+:abrupt predicts +"
    assert consistent(drift, m, (Symbol("f2", "-", 5, -9.0, 1, "", 0.5),)) is None  # no slope seen: no verdict
