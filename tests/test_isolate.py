"""Qualitative isolation (bgc.runtime.isolate): observed symbols from
open-loop residuals, and their agreement with the circuit's signatures (see
tests/test_signatures.py for the signatures derived by hand)."""

import numpy as np

from bgc.runtime.isolate import Symbol, consistent, first_symbol, hypotheses, observed_symbols, threshold

from conftest import compiled


def test_a_sensor_that_leaves_its_band_gives_its_sign_and_step():
    rng = np.random.default_rng(5)
    r = 0.5 * rng.standard_normal((30, 3))
    r[4:, 1] -= 8.0   # sensor b drops far below the nominal prediction from row 4
    r[10:, 2] += 8.0  # sensor c rises from row 10
    seen = observed_symbols(r, ("a", "b", "c"), onset=100)
    assert [(s.sensor, s.sign, s.step) for s in seen] == [("b", "-", 104), ("c", "+", 110)]


def test_correlated_drift_within_the_band_gives_no_symbol():
    """Open-loop residuals wander (the truth's process noise persists), so they
    are tested one sample at a time: a long excursion at 2 sigma is no symbol."""
    r = np.full((40, 2), 2.0)
    assert observed_symbols(r, ("a", "b"), onset=0) == ()
    assert threshold(0.01, 2, 40) > 3.5


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
