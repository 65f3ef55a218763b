"""A switch fails at any instant: the filters place a switch fault's onset
anywhere within the step before its onset sample.

The onset rule (bgc/model/protocol.py) changes a fault's parameter at the
instant of its onset sample: the transition into the sample nominal, the
sample seeing the fault. For a parameter that is nearly right whenever the
fault strikes within the step before: a step's share of its effect is small.
A switch's is not: the thermostat's valve (tests/data/hybrid/thermostat.yaml)
shut for a whole step of 0.5 min leaves the radiator about 4.5 degrees colder
than open (at 40 degrees), 15 of its sensor's stds. A valve that stuck shut just after a
sample was "unexplained: R_ra_abrupt" on the data with their mode column:
neither onset sample fits it (the one before sees the supply's flow still
running; the one after, the radiator heated by the open valve over the step
before it). The cubature Kalman filters now carry a switch fault's onset
cells through the step at quantiles of the place, the points at its middle
and the quantiles' spread around it (``_Filter._onset_spread``); the particle
filters draw the place per particle (``protocol.onset_transition``,
tests/test_uncommanded.py checks it against the closed form)."""

import numpy as np
import pytest
from scipy.linalg import expm

import bgc
from bgc.filters.cubature import _Filter
from bgc.model.protocol import PLACES, placed_transition

from conftest import session
from hybrid_reference import (THERMO_C_A as C_A, THERMO_C_R as C_R, THERMO_DT as DT, THERMO_R_RA as R_RA,
                              THERMO_MODEL, THERMO_R_V as R_V, THERMO_R_W as R_W, THERMO_T_S as T_S,
                              thermostat_csv, thermostat_run)

MODEL = THERMO_MODEL


def by_hand(x, heating: bool, dt: float) -> np.ndarray:
    """The room and radiator (T_r, T_a) after ``dt`` from ``x``, the valve
    open or shut: the thermostat's linear equations (hybrid_reference.py's
    ``thermostat_run``) by the matrix exponential, the supply as a constant
    input (Van Loan's block)."""
    block = np.zeros((3, 3))
    block[:2, :2] = [[-1 / (R_RA * C_R) - (1 / (R_V * C_R) if heating else 0.0), 1 / (R_RA * C_R)],
                     [1 / (R_RA * C_A), -1 / (R_RA * C_A) - 1 / (R_W * C_A)]]
    block[0, 2] = T_S / (R_V * C_R) if heating else 0.0
    return (expm(block * dt) @ np.append(x, 1.0))[:2]


def test_a_stuck_valves_onset_spreads_the_prediction_over_its_place_in_the_step():
    package = session(MODEL).package
    model = package.MODELS["V_stuck_off"]
    kf = _Filter(model)
    assert kf.within and not _Filter(package.MODELS["R_w_abrupt"]).within
    m = np.zeros((2, kf.n))
    m[:, :2] = [30.0, 19.5]  # heating, the room between its thresholds: no switch of the mode in the step
    m[:, kf.physical.index(model.MODE_ROW)] = 1.0
    draws = [kf.physical.index(int(i)) for i in getattr(model, "_THRESHOLD_ROWS", ())]
    m[:, draws] = 0.5
    fixed = np.asarray(model.X0, dtype=float)[kf.extra][:, None].repeat(2, axis=1)
    fixed[kf.magnitude] = 1.0  # stuck
    u = np.array([T_S, 1.0])
    assert kf._onset_spread(m, fixed, u, slice(0, 0), None) is None  # no cell at its onset
    spread = kf._onset_spread(m, fixed, u, slice(1, 2), None)
    assert np.allclose(spread[0], 0.0)  # the cell not at its onset
    # the place phi of the step after the valve shut, uniform: the radiator's temperature runs between the
    # step heated whole and not heated at all, nearly linearly in phi: a std of the difference / sqrt(12) (the
    # midpoint rule of J points: times sqrt(1 - 1/J^2))
    shut, heated = by_hand(m[1, :2], False, DT), by_hand(m[1, :2], True, DT)
    expected = abs(heated[0] - shut[0]) / np.sqrt(12) * np.sqrt(1 - 1 / PLACES ** 2)
    assert np.sqrt(spread[1, 0, 0]) == pytest.approx(expected, rel=0.05)
    assert np.all(np.linalg.eigvalsh(spread[1]) > -1e-9)
    assert np.allclose(spread[1][~kf.own], 0.0) and np.allclose(spread[1][:, ~kf.own], 0.0)
    # the points at the middle of the step: half of it heated
    middle = by_hand(by_hand(m[1, :2], True, DT / 2), False, DT / 2)
    flat = np.zeros((kf.n_x, 2 * 2 * kf.n))
    X = flat.reshape(kf.n_x, 2, 2 * kf.n)
    kf._points(m, np.zeros((2, kf.n, kf.n)), X)
    kf._predict_points(flat, X, u, fixed, slice(1, 2), None)
    assert X[:2, 1, 0] == pytest.approx(middle, abs=0.02)  # RK4 on the generated model's step
    assert X[:2, 0, 0] == pytest.approx(by_hand(m[0, :2], False, DT), abs=0.02)  # stuck: the step shut


@pytest.mark.parametrize("seed, onset", [(395222144, 53.0)])
def test_a_valve_stuck_just_after_a_sample_is_isolated(tmp_path, seed, onset):
    # the valve shut from the sample at t = 53 on (the step after it shut whole), heating: by the onset rule
    # neither sample 53 nor 53.5 fits it
    run = thermostat_run(seed, 200, (onset, "V", 0.0))
    assert run[1][int(round(onset / DT)) - 1] == 1.0  # heating at the sample
    path = thermostat_csv(tmp_path / "stuck.csv", *run, with_mode=True)
    d = bgc.diagnose(session(MODEL), path).diagnosis
    assert (d.verdict, d.candidates) == ("isolated", ("V_stuck_off",)), (d.verdict, d.candidates)
    assert onset <= d.onset <= onset + DT


def _thermostat_arrays(tmp_path, seed: int = 395222144, onset: float = 53.0):
    """The thermostat's run with its valve stuck shut from ``onset``, as the
    filters take it: measurements (model order) and inputs (T_s, the mode)."""
    package = session(MODEL).package
    nominal = package.MODELS["nominal"]
    times, modes, readings = thermostat_run(seed, 200, (onset, "V", 0.0))
    order = [("T_rad", "T_room", "q_s").index(name) for name in nominal.OUTPUTS]
    return package, readings[:, order], np.column_stack([np.full(len(times), T_S), modes]), modes


def test_the_filters_side_by_side_spread_a_switch_faults_onset_as_each_alone(tmp_path):
    """run_paths (every hypothesis's recorded path at once) gives a switch
    fault's filter, at its onset too, what run_bank of that model alone
    gives: the onset's spread in both. (To rounding, not bit for bit as on
    a plant without modes: a model with modes factors its covariances with
    the mode's rows apart, and the two paths floor an entry of 1e-300
    differently.)"""
    from bgc.diagnosis import static_posterior
    from bgc.filters import cubature as kalman

    package, ys, us, modes = _thermostat_arrays(tmp_path)
    t = kalman.nominal_track(package.MODELS["nominal"], ys, us, len(ys))
    models = [package.MODELS["V_stuck_off"], package.MODELS["R_w_abrupt"]]
    onsets = [106, 90]  # the valve's at t = 53.5, in heating
    assert modes[105] == 1.0 and modes[106] == 1.0
    magnitudes = [1.0, -0.5]
    fixed = [static_posterior.fault_start(m, t, o) for m, o in zip(models, onsets)]
    together = kalman.run_paths(models, ys, us, t, onsets, magnitudes, fixed)
    for m, o, c, f, r in zip(models, onsets, magnitudes, fixed, together):
        alone = kalman.run_bank(m, ys, us, t, [o], [c], f, residuals=True, record=True)
        for field in ("loglik", "mean", "cov", "z", "y_mean", "y_std", "x_mean", "x_std"):
            a, b = getattr(alone, field), getattr(r, field)
            assert a.shape == b.shape, (m.NAME, field)
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12, equal_nan=True, err_msg=f"{m.NAME} {field}")
    # the valve's onset spread its prediction: the radiator's predicted std at the onset sample is wider than the
    # other fault's at the same sample (its onset long before)
    rad = list(package.MODELS["nominal"].OUTPUTS).index("T_rad")
    assert together[0].y_std[106, 0, rad] > 2 * together[1].y_std[106, 0, rad]


def test_a_switch_the_data_give_in_the_onset_step_keeps_the_rule():
    """Where the data's mode changes in the step into the onset sample, the
    generated step places that switch within the step it is given, so a step
    split at the fault's place would move the switch into its first part:
    such a cell keeps the onset rule (the step without the fault), and its
    onset adds no spread."""
    package = session(MODEL).package
    model = package.MODELS["V_stuck_off"]
    kf = _Filter(model)
    m = np.zeros((1, kf.n))
    m[0, :2] = [30.0, 18.05]  # idle, the room just over its lower threshold
    m[0, kf.physical.index(model.MODE_ROW)] = 2.0
    draws = [kf.physical.index(int(i)) for i in getattr(model, "_THRESHOLD_ROWS", ())]
    m[0, draws] = 0.5
    fixed = np.asarray(model.X0, dtype=float)[kf.extra][:, None].copy()
    fixed[kf.magnitude] = 1.0
    u = np.array([T_S, 1.0])  # the data: heating at the sample
    X = np.zeros((kf.n_x, 1))
    X[kf.physical, 0] = m[0]
    X[kf.extra, 0] = fixed[:, 0]
    X[kf.extra[kf.magnitude]] = 0.0
    rule = model.predict(X.copy(), u, model.THETA, DT)
    placed = placed_transition(model, X, u, model.THETA, DT, 0.5, np.ones(1))
    np.testing.assert_array_equal(placed[kf.physical], rule[kf.physical])
    spread = kf._onset_spread(m, fixed, u, slice(0, 1), None)
    assert np.allclose(spread, 0.0)
