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
@pytest.mark.long
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


def test_a_switched_plants_likelihood_at_several_points_at_once_is_each_points_to_the_bit():
    """The filters of several calibration points run side by side
    (:meth:`_Likelihood.many`) on a plant whose mode the data say: each
    model factors its known mode's rows out of its covariance as its own
    filter does, so each point's likelihood is the one it has alone."""
    session = bgc.open(RELAY, backend="numpy")
    nominal = nominal_model(session.package)
    record = calibration.record_of(exact_run(0.45, 4.0, seed=7), nominal)  # four closings
    lik = calibration._Likelihood(nominal, session.view.numerics, [record], ["i_L"], True, ["R_aux"],
                                  modes=tuple(m.numerics for m in session.view.modes))
    z0 = lik.start()
    zs = [z0, z0 + [0.1, 0.0, 0.0], z0 + [0.0, -0.2, 0.05], z0 + [0.0, 0.0, -0.1]]
    one_by_one = [lik(z) for z in zs]
    assert all(np.isfinite(one_by_one)) and len(set(one_by_one)) == len(zs), one_by_one
    assert lik.many(zs) == one_by_one


def test_data_without_the_mode_column_of_a_controlled_switch_are_refused_in_one_line():
    """The relay's supply is switched from outside (a controlled transition):
    only the data can say when, so its data without a mode column cannot be
    calibrated on."""
    session = bgc.open(RELAY, backend="numpy")
    with pytest.raises(DataError, match="the data have no mode column") as info:
        session.calibrate(exact_run(0.5, 0.5, seed=1, modes=False))
    assert "cannot be read from the measurements: its transitions open -> unpowered, closed -> unpowered are " \
        "controlled (set from outside)" in info.value.line() and "\n" not in info.value.line()


@pytest.mark.slow
@pytest.mark.long
def test_a_plant_that_switches_by_itself_is_calibrated_without_its_mode_column(tmp_path, monkeypatch):
    """The level plant (a pump switched by the tank's pressure: autonomous
    transitions) by solve_ivp on its hand-derived equations
    (tests/hybrid_reference.py), its R_out 1.65 where the model file says
    1.5, 240 samples and 7 switches (seed 4), logged without the mode
    column: the modes are read from the measurements by the model, then by
    the calibrated one (bgc.analysis.calibrate.calibrate_hidden). The
    estimate is the one the same data with their mode column give (to 5e-4,
    a tenth of its interval), its interval holds 1.65, every switch is read,
    each within a sample and a half of solve_ivp's crossing; and the
    command says how the modes were read. The calibration without the mode
    column checked is the command's own (``bgc calibrate`` on those 240
    samples, its report taken where the command asks bgc.Session.calibrate
    for it): one calibration, not the same one twice."""
    from hybrid_reference import LEVEL_DT, level_csv, level_run

    from conftest import FAST, bgc_cli

    level = ROOT / "docs" / "examples" / "level.yaml"
    session = bgc.open(level, backend=FAST)
    times, modes, y_p, y_q, switches = level_run(4, fault=(0.0, "R_out", 1.65), steps=240)
    given = level_csv(tmp_path / "given.csv", times, modes, y_p, y_q, True)
    hidden = level_csv(tmp_path / "hidden.csv", times, modes, y_p, y_q, False)
    truth = session.calibrate(str(given), "R_out")
    assert truth.modes_read == ()
    expected = truth.calibration.estimate("R_out").value
    made, calibrate = [], bgc.Session.calibrate

    def kept(*args, **kwargs):  # the command's calibration, as it returns it to the command
        made.append(calibrate(*args, **kwargs))
        return made[-1]

    with monkeypatch.context() as patch:
        patch.setattr(bgc.Session, "calibrate", kept)
        out = bgc_cli("calibrate", str(level), "--data", str(hidden), "--estimate", "R_out", "--backend", FAST,
                      "-o", str(tmp_path / "cal.yaml"))
    assert out.returncode == 0, out.stderr
    (report,) = made
    e = report.calibration.estimate("R_out")
    assert abs(e.value - expected) < 5e-4 and e.low <= 1.65 <= e.high, (e.value, expected, e.low, e.high)
    # at a maximum by the gradient and the Hessian, with the mode column and without; on seed 5 L-BFGS-B's own
    # line search ends "abnormally" at the maximum (a likelihood that moves in steps where a switch moves
    # within its period), and the fit is converged all the same (it was "did not converge")
    assert truth.calibration.converged and report.calibration.converged, (truth.calibration.message,
                                                                          report.calibration.message)
    times5, modes5, p5, q5, _ = level_run(5, fault=(0.0, "R_out", 1.65), steps=240)
    five = session.calibrate(str(level_csv(tmp_path / "five.csv", times5, modes5, p5, q5, True)), "R_out")
    e5 = five.calibration.estimate("R_out")
    assert five.calibration.converged and e5.low <= 1.65 <= e5.high, (five.calibration.message, e5.value)
    (read,) = report.modes_read
    assert len(read.switches) == len(switches) and 1 <= read.rounds <= calibration.ROUNDS
    assert all(abs(t - s) <= 1.5 * LEVEL_DT for (t, _, _), s in zip(read.switches, switches)), read.switches
    said = [line for line in out.stdout.splitlines() if "modes read from" in line]
    count = sum(1 for s in switches if s <= times[-1])
    assert len(said) == 1 and f": {count} switch(es), {read.rounds} round(s)" in said[0], (count, out.stdout)
