"""A stuck switch's fault model, generated and followed by the filters.

The relay of docs/examples/relay.yaml with ``K: {kinds: [stuck_on,
stuck_off]}`` and ``S: [stuck_off]``: its package has a model per stuck
switch, ``K_stuck_off`` and so on, whose flag (0 before the onset, 1 from it)
runs each mode in the configuration the stuck switch makes. The data come
from solve_ivp on the relay's equations derived by hand (below), not from
bgc's simulator: the operator closes the relay K at t = 1 s (the data's mode
column says closed from then), but K stuck OFF at t = 0.5 s, so the plant
goes on in its open configuration.

The relay's equations by hand (i = f3 the inductor's current, v = e6 the
capacitor's voltage; the supply S ON in modes open and closed):

    L di/dt = V - R_s i - v
    C dv/dt = i - v / R_load             (K open)
    C dv/dt = i - v / R_load - v / R_aux (K closed)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import bgc
from bgc.analysis import track
from bgc.data import runs
from bgc.diagnosis.static_posterior import fault_start
from bgc.filters.cubature import nominal_track, run_bank
from bgc.model.protocol import magnitude_row, nominal_model, sized_models

ROOT = Path(__file__).resolve().parents[1]
R_S, L, C, R_LOAD, R_AUX, V = 0.5, 0.2, 2.0, 10.0, 0.5, 8.0
DT, STEPS, NOISE = 0.01, 300, 0.01
COMMAND, STUCK = 1.0, 0.5  # the operator closes K; K stuck OFF before it


def _model(tmp_path: Path) -> Path:
    text = (ROOT / "docs" / "examples" / "relay.yaml").read_text(encoding="utf-8")
    assert "  v_C: [bias]\n" in text
    text = text.replace("  v_C: [bias]\n", "  v_C: [bias]\n  K: {kinds: [stuck_on, stuck_off]}\n  S: [stuck_off]\n")
    path = tmp_path / "relay_stuck.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _plant(closed: bool):
    def f(t, x):
        i, v = x
        load = v / R_LOAD + (v / R_AUX if closed else 0.0)
        return [(V - R_S * i - v) / L, (i - load) / C]
    return f


def _run(seed: int = 5) -> tuple[str, np.ndarray]:
    """The run file's text (mode column: open, then closed from COMMAND) and
    the true states: K never closes (stuck OFF), so the open equations all
    along, from rest."""
    times = DT * np.arange(1, STEPS + 1)
    sol = solve_ivp(_plant(closed=False), (0.0, times[-1]), [0.0, 0.0], t_eval=times, rtol=1e-10, atol=1e-12)
    truth = sol.y.T
    rng = np.random.default_rng(seed)
    ys = truth + NOISE * rng.standard_normal(truth.shape)
    lines = ["time,mode,u:V,y:i_L,y:v_C"]
    for t, (i, v) in zip(times, ys):
        mode = 2 if t >= COMMAND - 1e-9 else 1
        lines.append(f"{t:.10g},{mode},{V},{float(i)!r},{float(v)!r}")
    return "\n".join(lines) + "\n", truth


@pytest.fixture(scope="module")
def relay(tmp_path_factory):
    path = _model(tmp_path_factory.mktemp("stuck"))
    session = bgc.open(path, backend="numpy")
    text, truth = _run()
    return session, runs.parse_run(text, "relay_stuck.csv"), truth


def test_each_stuck_switch_has_a_fault_model_whose_flag_picks_the_configuration(relay):
    """One model per stuck switch and kind, its magnitude a flag of prior 1;
    the configurations it runs each mode in, by the hand derivation: K stuck
    OFF runs closed as open; K stuck ON runs open as closed and unpowered in
    a configuration no mode has (the supply off, the relay closed); S stuck
    OFF runs open as unpowered and closed in one of its own."""
    session, _, _ = relay
    package = session.package
    for name in ("K_stuck_off", "K_stuck_on", "S_stuck_off"):
        m = package.MODELS[name]
        assert m.FAULT["kind"] == name[2:] and m.FAULT["target"] == "switch"
        assert m.STATES[magnitude_row(m)] == f"{name[0]}_stuck" and m.STATE_KINDS[-1] == "switch"
        assert tuple(m.FAULT_PRIOR) == (1.0, 1.0)
    assert list(package.MODELS["K_stuck_off"]._STUCK) == [0, 0, 2]
    on = package.MODELS["K_stuck_on"]
    assert list(on._STUCK[:2]) == [1, 1] and on._STUCK[2] == 3 and len(on._MODULES) == 4
    s = package.MODELS["S_stuck_off"]
    assert s._STUCK[0] == 2 and s._STUCK[1] == 3 and s._STUCK[2] == 2
    # the sized fault models leave the stuck switches out (bgc distinguish weighs sizes)
    assert sized_models(package) == ["R_aux_abrupt", "R_load_abrupt", "v_C_offset_bias"]


def test_the_stuck_models_cubature_filters_explain_the_data_and_the_nominals_do_not(relay):
    """Cubature Kalman filters (no random numbers) of K stuck OFF from every
    onset up to the command: their likelihoods are the same whatever the
    onset before the command (stuck OFF changes nothing while K is meant to
    be open), their residuals after the command centred, and the
    likelihood beats the nominal filter's and K stuck ON's by far; the
    nominal filter's residual of v_C after the command is far off (it
    expects R_aux to load the capacitor)."""
    session, run, _ = relay
    package = session.package
    nominal = nominal_model(package)
    ys, us = track.run_arrays(run, package, "nominal")
    T = len(ys)
    base = nominal_track(nominal, ys, us, T)
    stuck = package.MODELS["K_stuck_off"]
    command = int(np.searchsorted(run.time, COMMAND - 1e-9))
    onsets = [10, 40, command - 1]
    bank = run_bank(stuck, ys, us, base, onsets, np.ones(len(onsets)), fault_start(stuck, base, onsets[0]),
                    residuals=True)
    assert np.ptp(bank.loglik) < 1e-6 * abs(bank.loglik[0])
    # a few samples after the command, the filters settled: centred, and no wider than the model's noise
    # says (narrower: the plant here has no process noise, the model declares some)
    z = bank.z[command + 5:, 0]
    assert abs(np.nanmean(z)) < 0.2 and np.nanvar(z) < 1.4
    assert bank.loglik[0] - float(base.loglik[T]) > 1000.0
    k_on = package.MODELS["K_stuck_on"]
    other = run_bank(k_on, ys, us, base, onsets[:1], np.ones(1), fault_start(k_on, base, onsets[0]))
    assert bank.loglik[0] - other.loglik[0] > 1000.0
    v = list(nominal.OUTPUTS).index("v_C")
    nominal_z = (ys[command + 5:, v] - base.y_mean[command + 5:, v]) / base.y_std[command + 5:, v]
    assert abs(np.mean(nominal_z)) > 5.0


def test_bgc_filter_follows_a_stuck_switch_from_its_onset(relay):
    """The particle filter of K stuck OFF handed over at the onset tracks the
    true states (solve_ivp's) to within a few noise stds after the command,
    where the nominal filter is far off."""
    session, run, truth = relay
    package = session.package
    after = run.time >= COMMAND + 0.2
    errors = {}
    for name, start in (("nominal", None), ("K_stuck_off", STUCK)):
        r = track.track(run, package, name, "gpf", 300, 1, start)
        v = r.state_names.index("e6")
        errors[name] = float(np.sqrt(np.mean((r.mean[after, v] - truth[after, 1]) ** 2)))
        assert track.fault_estimate(r, package, run) is None  # no size: nothing to estimate
    assert errors["K_stuck_off"] < 3 * NOISE, errors
    assert errors["nominal"] > 30 * NOISE, errors
