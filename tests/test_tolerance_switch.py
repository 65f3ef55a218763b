"""A guard with a tolerance (the plant's threshold uncertain, drawn anew at
each visit of the mode): the data say a switch happened within a step, and
where within it depends on the threshold, which the filters do not know. The
Kalman filters' points all take the threshold distribution's median, so
their prediction at that step had no spread for it, and the residuals of
healthy data at the switches were 4 to 6 stds wide: a thermostat of 35
switches in 600 samples came out "mismatch" on bgc's own simulation of its
own model. The prediction now spreads by the switch's place
(bgc.filters.cubature._Filter._switch_spread).

The plant is simulated by tests/hybrid_reference.py, not by bgc: a room
heated by a radiator whose valve opens when the room falls under 18 and
shuts over 21, each threshold drawn N(0, 0.15^2) per visit, integrated by
solve_ivp with the switch as an event on the equations derived by hand
(tests/data/hybrid/thermostat.yaml's comment), heat disturbances held over
each step."""

from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.filters.cubature import _Filter, nominal_track

from conftest import session
from hybrid_reference import THERMO_DT, THERMO_MODEL, THERMO_T_S, thermostat_csv, thermostat_run

MODEL = THERMO_MODEL
T_S, DT = THERMO_T_S, THERMO_DT


def write(path: Path, seed: int, modes: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plant's run (:func:`hybrid_reference.thermostat_run`'s arrays, returned) as a run file (without
    ``modes``, no mode column: the mode read from the data)."""
    t, mode, y = thermostat_run(seed)
    thermostat_csv(path, t, mode, y, modes)
    return t, mode, y


@pytest.mark.parametrize("seed", [0, 1])
def test_a_thermostat_whose_thresholds_are_uncertain_fits_its_model_through_its_switches(tmp_path, seed):
    path = tmp_path / "thermostat.csv"
    t, mode, y = write(path, seed)
    s = session(MODEL)
    nominal = s.package.MODELS["nominal"]
    us = np.column_stack([np.full(len(t), T_S), mode])
    order = [("T_rad", "T_room", "q_s").index(name) for name in nominal.OUTPUTS]
    track = nominal_track(nominal, y[:, order], us, len(t))
    z = np.asarray(track.z, dtype=float).reshape(len(t), len(order))
    switched = np.flatnonzero(mode[1:] != mode[:-1]) + 1
    assert len(switched) >= 20
    # the residuals where the valve moved within the step: N(0, 1) draws, their mean square near 1 (35 or so
    # draws: under 2.5 for every sensor; the median's prediction alone gave 12.5 to 27.4 on T_rad and q_s)
    assert (z[switched] ** 2).mean(axis=0).max() < 2.5, (z[switched] ** 2).mean(axis=0)
    d = bgc.diagnose(s, path).diagnosis
    assert d.verdict == "no fault", (d.verdict, d.candidates)


def test_the_spread_is_the_switchs_alone():
    nominal = session(MODEL).package.MODELS["nominal"]
    kf = _Filter(nominal)
    m = np.zeros((2, kf.n))
    m[:, :2] = [[25.0, 17.95], [25.0, 17.95]]  # just under the low threshold, idle: the valve opens in the step
    m[:, kf.mode] = 2.0
    m[:, [kf.physical.index(int(i)) for i in kf.draws]] = 0.5
    fixed = np.asarray(nominal.X0, dtype=float)[kf.extra][:, None].repeat(2, axis=1)
    u = np.array([T_S, 2.0])
    assert kf._switch_spread(m, fixed, u, slice(0, 0), None) is None  # the data's mode is the cells': no switch
    u[1] = 1.0
    spread = kf._switch_spread(m, fixed, u, slice(0, 0), None)
    assert spread.shape == (2, kf.n, kf.n) and np.allclose(spread[0], spread[1])
    assert spread[0, 0, 0] > 0  # the radiator's temperature: heated for an unknown part of the step
    assert np.allclose(spread[0][~kf.own], 0.0) and np.allclose(spread[0][:, ~kf.own], 0.0)
    assert np.all(np.linalg.eigvalsh(spread[0]) > -1e-12)
    # the largest spread the step allows: heating for none of it against all of it, T_r's rate (T_s - T_r) /
    # (R_v C_r) = 25 over half a step each way, a uniform place: std about 25 * 0.5 / sqrt(12)
    assert np.sqrt(spread[0, 0, 0]) < 25 * DT / np.sqrt(12) * 1.2
    # the predicted measurement the pooled test whitens with spreads the same way at the switch
    P = np.diag([0.01, 0.01] + [0.0] * (kf.n - 2))
    _, still = kf.predicted_measurement(m[0], P, np.array([T_S, 2.0]))
    _, switching = kf.predicted_measurement(m[0], P, np.array([T_S, 1.0]))
    rad = nominal.OUTPUTS.index("T_rad")
    assert switching[rad, rad] > still[rad, rad] + 0.5 * spread[0, 0, 0]



def test_without_its_mode_column_too(tmp_path):
    # the mode read from the data: each history of the hidden-mode bank that switches at a sample spreads by it
    path = tmp_path / "thermostat.csv"
    write(path, 2, modes=False)
    d = bgc.diagnose(session(MODEL), path).diagnosis
    assert d.verdict == "no fault", d.verdict
