"""A stuck switch's fault model, generated, followed by the filters and
weighed by the diagnosis.

The relay of docs/examples/relay.yaml, which lists ``K: {kinds: [stuck_on,
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

import io
import math
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
#: The relay, its switches K and S listed as stuck switches (K: stuck_on, stuck_off; S: stuck_off).
RELAY = ROOT / "docs" / "examples" / "relay.yaml"
R_S, L, C, R_LOAD, R_AUX, V = 0.5, 0.2, 2.0, 10.0, 0.5, 8.0
DT, STEPS, NOISE = 0.01, 300, 0.01
COMMAND, STUCK = 1.0, 0.5  # the operator closes K; K stuck OFF before it


def _plant(closed: bool, r_aux: float = R_AUX):
    def f(t, x):
        i, v = x
        load = v / R_LOAD + (v / r_aux if closed else 0.0)
        return [(V - R_S * i - v) / L, (i - load) / C]
    return f


def _run(seed: int = 5, pieces=((0.0, False, R_AUX),), command=COMMAND) -> tuple[str, np.ndarray]:
    """The run file's text (mode column: open, then closed from ``command``;
    ``command`` a list of (time, mode number) for another schedule) and the
    true states from rest: ``pieces`` (from time, relay closed, R_aux) of
    the plant's own equations, solved piece by piece (default: K never
    closes, stuck OFF, so the open equations all along)."""
    times = DT * np.arange(1, STEPS + 1)
    schedule = [(0.0, 1), (command, 2)] if isinstance(command, float) else list(command)
    truth = np.empty((STEPS, 2))
    x = [0.0, 0.0]
    for k, (start, closed, r_aux) in enumerate(pieces):
        end = pieces[k + 1][0] if k + 1 < len(pieces) else times[-1] + DT
        inside = (times >= start - 1e-9) & (times < end - 1e-9)
        sol = solve_ivp(_plant(closed, r_aux), (start, end), x, dense_output=True, rtol=1e-10, atol=1e-12)
        truth[inside] = sol.sol(times[inside]).T
        x = list(sol.sol(end))
    rng = np.random.default_rng(seed)
    ys = truth + NOISE * rng.standard_normal(truth.shape)
    lines = ["time,mode,u:V,y:i_L,y:v_C"]
    for t, (i, v) in zip(times, ys):
        mode = [m for at, m in schedule if t >= at - 1e-9][-1]
        lines.append(f"{t:.10g},{mode},{V},{float(i)!r},{float(v)!r}")
    return "\n".join(lines) + "\n", truth


@pytest.fixture(scope="module")
def relay():
    session = bgc.open(RELAY, backend="numpy")
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


# ------------------------------------------------------------------ the diagnosis weighs them
def _diagnose(session, text: str):
    return bgc.diagnose(session, runs.parse_run(text, "relay_stuck.csv"), particles=300, seed=2).diagnosis


def test_a_relay_that_stuck_open_before_it_was_closed_is_named(relay):
    """K stuck OFF at 0.5 s, the operator closing it at 1 s (the data's mode
    column): isolated as K stuck OFF, its onset at the latest the last
    sample before the command (before it, a stuck-open relay changes
    nothing: every onset there explains the data alike). One seeded run (a
    second seed ran the same path); a campaign of stuck relays over seeds:
    bench/stuck_switches.py."""
    session, _, _ = relay
    text, _ = _run(5)
    d = _diagnose(session, text)
    assert d.verdict == "isolated" and d.candidates == ("K_stuck_off",), (d.verdict, d.candidates)
    assert d.time_of(d.onset_step) <= COMMAND + 1e-9
    assert d.detection.step >= int(round(COMMAND / DT)) - 1
    e = d.best.estimate
    assert e.target == "switch" and e.magnitude == "switch" and e.value == 1.0


def test_a_relay_that_stuck_closed_is_named_when_the_operator_opens_it(relay):
    """Closed at 0.5 s (it closes), commanded open at 1.5 s; K stuck ON from
    1.2 s, so the plant stays closed: K stuck ON, not a parametric fault
    (the relay's loads would have to change just as the mode does)."""
    session, _, _ = relay
    text, _ = _run(7, pieces=((0.0, False, R_AUX), (0.5, True, R_AUX)), command=[(0.0, 1), (0.5, 2), (1.5, 1)])
    d = _diagnose(session, text)
    assert d.verdict == "isolated" and d.candidates == ("K_stuck_on",), (d.verdict, d.candidates)
    assert 1.2 - 1e-9 <= d.time_of(d.onset_step) <= 1.5 + 1e-9


@pytest.mark.slow
def test_a_load_that_changes_behind_a_closed_relay_is_not_called_a_stuck_switch(relay):
    """R_aux 0.5 -> 0.9 ohm at 1.5 s, the relay closed at 0.5 s as commanded
    and closed since: R_aux's step, sized, though the stuck switches are
    weighed too (K stuck OFF would be R_aux infinite)."""
    session, _, _ = relay
    text, _ = _run(8, pieces=((0.0, False, R_AUX), (0.5, True, R_AUX), (1.5, True, 0.9)), command=0.5)
    d = _diagnose(session, text)
    assert d.verdict == "isolated" and d.candidates == ("R_aux_abrupt",), (d.verdict, d.candidates)
    assert abs(d.best.estimate.value - 0.4) < 0.04
    assert any(h.name == "K_stuck_off" for h in d.hypotheses)  # weighed, and out


def test_a_relay_that_moves_as_commanded_raises_no_alarm(relay):
    """Closed at 0.5 s, open at 1.5 s, closed at 2.2 s, as the mode column
    says: no fault."""
    session, _, _ = relay
    text, _ = _run(9, pieces=((0.0, False, R_AUX), (0.5, True, R_AUX), (1.5, False, R_AUX), (2.2, True, R_AUX)),
                   command=[(0.0, 1), (0.5, 2), (1.5, 1), (2.2, 2)])
    assert _diagnose(session, text).verdict == "no fault"


@pytest.mark.slow
@pytest.mark.long
def test_a_campaign_counts_a_listed_stuck_relay_named_as_right(relay, tmp_path):
    """bgc's simulator, the relay sticking open at 3 s after the automaton
    closed it (the model lists the stuck switch): the campaign's row says
    the fault was expected and named right (no size: no error)."""
    from bgc.experiment import campaign_file, one_run

    session, _, _ = relay
    path = tmp_path / "campaign.yaml"
    path.write_text(f"campaign: stuck\nseed: 1\ndefaults: {{particles: [200], steps: 600}}\ngroups:\n"
                    f"  - name: stuck\n    model: {session.view.model.source}\n    modes: unpowered@6\n"
                    "    scenarios: ['K:stuck_off@3']\n", encoding="utf-8")
    spec, = campaign_file.load_campaign(path).specs
    row = one_run.run_one(spec, backend="numpy")
    assert row["status"] == "ok", row["failure"]
    assert row["expected"] is True and row["detected"] and row["verdict"] == "isolated"
    assert row["candidates"] == "K_stuck_off" and row["right"] is True and math.isnan(row["est_error"])


@pytest.mark.slow
@pytest.mark.parametrize("model", [RELAY, ROOT / "models" / "ro_hybrid.yaml"])
def test_the_packages_of_a_model_with_modes_pass_pyflakes(model):
    """No unused or undefined names in the generated modules of a model with
    modes, the NumPy and the compiled package: the relay (stuck switches,
    guards without a tolerance) and the autonomous RO (guards with one).
    The modules as bgc's compile cache holds them (what bgc.open loads: the
    compilation's files, written whole, under a key of bgc's code, the
    model's text and the versions it depends on; compiled here when the
    cache lacks them)."""
    from pyflakes.api import check
    from pyflakes.reporter import Reporter

    from bgc.api import cache

    opened = cache.open_model(model)
    if opened.entry is None:  # no cache to write (it compiled): its files
        files = (*opened.compiled.package.files, *opened.compiled.package.numba_files)
    else:
        folder = opened.entry / opened.view.model.name
        files = [(p.name, p.read_text(encoding="utf-8")) for part in ("numpy_model", "numba_model")
                 for p in sorted((folder / part).glob("*.py"))]
    assert len(files) > 20  # each package: its kernel, filters, and a module per mode and fault model
    out, err = io.StringIO(), io.StringIO()
    for name, text in files:
        check(text, name, Reporter(out, err))
    assert out.getvalue() + err.getvalue() == ""


def test_bgc_distinguish_predicts_a_stuck_switch():
    """bgc distinguish of a stuck switch (it used to refuse one in a line:
    its prediction was linear in a fault's size, and a stuck switch has
    none): the switch's own runs are its family (tests/test_stuck_distinguish.py
    checks the numbers against the exact Gaussians)."""
    from conftest import bgc_cli

    r = bgc_cli("distinguish", str(RELAY), "--scenario", "K:stuck_off@1", "--steps", "300")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert "truth: K:stuck_off@1 (K_stuck_off, from sample 99)" in r.stdout
    assert any(line.startswith("K_stuck_on ") for line in r.stdout.splitlines()), r.stdout
