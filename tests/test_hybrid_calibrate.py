"""Calibration of a model with modes (bgc/analysis/calibrate.py) on runs of the
independent relay simulator (tests/hybrid_reference.py: solve_ivp with events on
the hand-derived equations), with their mode column."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bgc
from bgc.analysis import calibrate as calibration
from bgc.data import runs
from bgc.errors import DataError
from bgc.model.protocol import nominal_model

from hybrid_reference import V, sampled

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
#: The relay's sensors' noise stds as its generated model has them (1 % of the signals' size: i_L, v_C).
NOISE = (0.10825763, 0.07757651)


def exact_run(r_aux: float, end: float, seed: int, modes: bool = True) -> runs.Run:
    """The exact relay with R_aux = ``r_aux`` from the start, sampled every 0.01 s to ``end`` with the
    model's measurement noise (seeded), with its mode column or without."""
    times, states, numbers, _ = sampled(end, trip=1e9, fault=(0.0, r_aux))
    y = states + np.array(NOISE) * np.random.default_rng(seed).standard_normal(states.shape)
    return runs.Run(times, {"V": np.full(len(times), V)}, {"i_L": y[:, 0], "v_C": y[:, 1]}, {}, {}, ("exact",),
                    f"exact relay, R_aux {r_aux}", numbers.astype(float) if modes else None)


@pytest.mark.slow
def test_a_load_behind_the_relay_is_calibrated_through_its_switches():
    """R_aux carries current only while the relay is closed: the plant's 0.45 ohm (the model
    file says 0.5) is found from 4 s of data holding four closings and openings."""
    run = exact_run(0.45, 4.0, seed=7)
    assert int(np.sum(np.diff(run.modes) != 0)) >= 4
    report = bgc.open(RELAY, backend="numpy").calibrate(run, estimate="R_aux")
    e = report.calibration.estimate("R_aux")
    assert e.identifiable and e.low <= 0.45 <= e.high, (e.value, e.low, e.high)
    assert abs(e.value - 0.45) < 0.01 and e.high < 0.5  # the model file's value is outside the interval
    assert "R_aux: {value: " in report.text


def test_a_state_takes_the_process_noise_of_the_first_mode_it_is_a_state_of():
    """The likelihood's noise at the model's own levels is the generated model's (as the compiler
    set it: the first mode a state belongs to), the mode and the time in it without noise."""
    session = bgc.open(RELAY, backend="numpy")
    nominal = nominal_model(session.package)
    record = calibration.record_of(exact_run(0.5, 0.2, seed=1), nominal)
    assert np.all(record.us[:, nominal.MODE_INPUT] == 1)  # the data's mode column is the mode input
    lik = calibration._Likelihood(nominal, session.view.numerics, [record], ["i_L"], True, [],
                                  modes=tuple(m.numerics for m in session.view.modes))
    module = lik.module(lik.start())
    np.testing.assert_allclose(module.PROCESS_STD, nominal.PROCESS_STD, rtol=1e-12, atol=0)
    np.testing.assert_allclose(module.X0_STD, nominal.X0_STD, rtol=1e-12, atol=0)
    assert np.isfinite(lik(lik.start()))


def test_data_without_the_mode_column_are_refused_in_one_line():
    session = bgc.open(RELAY, backend="numpy")
    with pytest.raises(DataError, match="the data have no mode column") as info:
        session.calibrate(exact_run(0.5, 0.5, seed=1, modes=False))
    assert "calibration with a mode the data do not give is not built yet" in info.value.line()


def test_a_mode_number_the_model_does_not_have_is_refused_in_one_line():
    run = exact_run(0.5, 0.3, seed=1)
    run.modes[10] = 4  # the relay has three modes
    session = bgc.open(RELAY, backend="numpy")
    for call in (lambda: session.calibrate(run), lambda: bgc.diagnose(session, data=run)):
        with pytest.raises(DataError, match=r"mode 4 is no mode of relay_rl \(1 to 3: open, closed, unpowered\)"):
            call()
