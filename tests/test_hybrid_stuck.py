"""A switch that sticks (bgc/compiler/modes.py: compile_stuck, bgc/compiler/hybrid_dbn.py,
bgc/analysis/hybrid.py): the configurations the relay runs in with its relay K or its
contactor S stuck ON or OFF, their DBNs, and the truth simulator, against the relay's
equations derived by hand (tests/hybrid_reference.py) and solve_ivp."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy
from scipy.integrate import solve_ivp

import bgc
from bgc.compiler import modes
from bgc.compiler.hybrid_dbn import across_modes
from bgc.compiler.load import load
from bgc.compiler.validate import validate
from bgc.ir import StuckSwitch

from conftest import bgc_cli
from hybrid_reference import C, R_load, derivative, reference

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
i, v, V, R_s, L, Cs, R_ld, R_aux = sympy.symbols("f3 e6 V R_s L C R_load R_aux")


def with_faults(tmp: Path, lines: str) -> Path:
    """The relay with ``lines`` added to its faults section."""
    text = RELAY.read_text()
    assert "  v_C: [bias]\n" in text
    path = tmp / "relay_rl.yaml"
    path.write_text(text.replace("  v_C: [bias]\n", "  v_C: [bias]\n" + lines))
    return path


@pytest.fixture(scope="module")
def relay():
    model = validate(load(RELAY))
    return model, modes.compile_modes(model)


def test_a_stuck_switch_runs_each_mode_in_a_configuration_derived_by_hand(relay):
    """K stuck OFF: closed runs as open; K stuck ON: open runs as closed, and unpowered (supply
    off) with the relay closed is no declared mode: C dv/dt = -v/R_load - v/R_aux, the coil idle."""
    model, compiled = relay
    off = modes.compile_stuck(model, compiled, StuckSwitch("K", "stuck_off", 0.01, None))
    assert off.same == ("open", "open", "unpowered")
    on = modes.compile_stuck(model, compiled, StuckSwitch("K", "stuck_on", 0.01, None))
    assert on.same == ("closed", "closed", None)
    own = on.configs[2].equations
    assert own.states == ("e6",) and on.configs[2].name == "unpowered with K stuck ON"
    assert sympy.simplify(own.rhs[0] - (-v / R_ld - v / R_aux) / Cs) == 0
    s_off = modes.compile_stuck(model, compiled, StuckSwitch("S", "stuck_off", 0.01, None))
    assert s_off.same == ("unpowered", None, "unpowered")
    assert s_off.configs[1].equations.states == ("e6",)


@pytest.mark.parametrize("name, arcs", [
    ("K:stuck_off", {("D_K_stuck_off@t", "e6@t+1"): "closed"}),
    ("K:stuck_on", {("D_K_stuck_on@t", "e6@t+1"): "open,unpowered"}),
    ("S:stuck_off", {("D_S_stuck_off@t", "f3@t+1"): "open,closed", ("D_S_stuck_off@t", "e6@t+1"): "open,closed",
                     ("D_S_stuck_off@t+1", "i_L@t+1"): "open,closed"}),
    ("S:stuck_on", {("D_S_stuck_on@t", "f3@t+1"): "unpowered", ("D_S_stuck_on@t", "e6@t+1"): "unpowered",
                    ("D_S_stuck_on@t+1", "i_L@t+1"): "unpowered"}),
])
def test_a_stuck_switchs_dbn_has_its_arcs_where_its_configuration_differs(relay, name, arcs):
    """By hand: the relay K carries R_aux's current, so stuck it changes v's equation where the
    mode would have it the other way (OFF: closed; ON: open and unpowered); the contactor S carries
    the coil's current, so stuck it changes i (a state, or idle at 0), v (which i charges) and i_L
    (which reads i) where the mode would have it the other way."""
    model, compiled = relay
    g = across_modes(model, compiled, name).graph
    indicator = f"D_{name.replace(':', '_')}"
    faults = {(a, b): d.get("modes") for a, b, d in g.edges(data=True) if d["arc"] == "fault"}
    assert faults == arcs
    assert g.nodes[f"{indicator}@t"]["role"] == "fault_indicator"
    assert g.edges[f"{indicator}@t", f"{indicator}@t+1"]["arc"] == "persistence"
    assert ("mode@t", "mode@t+1") in g.edges  # the nominal DBN across the modes around it


def test_the_truth_simulator_keeps_a_stuck_relay_open_whatever_its_mode_says():
    """K stuck OFF from 0.5 s (the relay still open then): the plant is the open relay's from the
    start (solve_ivp on its equations), while the automaton closes the relay when v passes 6 and,
    v never falling under 4 again, stays closed."""
    with pytest.warns(bgc.ScenarioWarning, match="lists no fault K:stuck_off among its candidates"):
        sim = bgc.simulate(RELAY, "K:stuck_off@0.5", seed=1, steps=1100, process_noise=0.0)
    t = sim.time
    exact = solve_ivp(lambda _, x: derivative("open", x), (0.0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-11,
                      atol=1e-13).y
    assert np.max(np.abs(sim.run.states["f3"] - exact[0])) < 1e-5
    assert np.max(np.abs(sim.run.states["e6"] - exact[1])) < 1e-5
    assert [(s.source, s.target) for s in sim.switches] == [("open", "closed")]
    assert sim.switches[0].time == pytest.approx(float(t[np.argmax(exact[1] > 6.0)]), abs=0.011)
    assert sim.truth["fault"] == "K:stuck_off"


def test_the_truth_simulator_cuts_the_supply_of_a_stuck_contactor():
    """S stuck OFF from 3 s: until then the relay as solve_ivp has it (tests/hybrid_reference.py);
    from then no current in the coil and v = v(3) exp(-(t - 3) / (R_load C)), the relay open (v
    starts under 6 and falls)."""
    with pytest.warns(bgc.ScenarioWarning, match="lists no fault S:stuck_off among its candidates"):
        sim = bgc.simulate(RELAY, "S:stuck_off@3", seed=2, steps=1100, process_noise=0.0)
    t, x = sim.time, np.column_stack([sim.run.states["f3"], sim.run.states["e6"]])
    _, at = reference(3.0, trip=100.0)
    before = t <= 3.0 - 1e-9
    assert np.max(np.abs(x[before] - np.array([at(s) for s in t[before]]))) < 1e-5
    v3 = at(3.0)[1]
    after = t >= 3.0 + 1e-9
    assert np.max(np.abs(x[after, 0])) == 0.0
    assert np.max(np.abs(x[after, 1] - v3 * np.exp(-(t[after] - 3.0) / (R_load * C)))) < 1e-5


def test_stuck_switches_are_declared_on_switched_junctions_only(tmp_path):
    declared = with_faults(tmp_path, "  K: {kinds: [stuck_on, stuck_off], prior: 0.02}\n  S: [stuck_off]\n")
    model = validate(load(declared))
    assert [(f.name, f.prior) for f in model.modes.stuck] == [("K:stuck_off", 0.02), ("K:stuck_on", 0.02),
                                                                ("S:stuck_off", 0.01)]
    assert all(f.parameter not in ("K", "S") for f in model.faults)  # not a parameter's fault
    done = bgc_cli("check", declared)
    assert done.returncode == 0, done.stderr
    assert "    K stuck OFF: closed runs as open; no effect in open, unpowered" in done.stdout
    assert "    S stuck OFF: open runs as unpowered; closed runs in a configuration of its own; no effect in " \
           "unpowered" in done.stdout
    for lines, said in (("  R_s: [stuck_on]\n", "fault kind 'stuck_on' is a switched junction's, and R_s is none"),
                        ("  K: [stuck_on, bias]\n", "K is a switched junction with other kinds too"),
                        ("  K: {kinds: [stuck_off], size: [0, 1]}\n", "a stuck switch takes no 'size'")):
        folder = tmp_path / str(abs(hash(lines)))
        folder.mkdir()
        done = bgc_cli("check", with_faults(folder, lines))
        assert done.returncode == 1 and said in done.stderr and "Traceback" not in done.stderr, done.stderr
        assert "relay_rl.yaml:" in done.stderr


@pytest.mark.slow
def test_a_stuck_switch_is_asked_for_in_one_line(tmp_path):
    run = tmp_path / "run.csv"
    for model, fault, said in ((RELAY, "R_s:stuck_off@1", "'R_s' is no switched junction of relay_rl"),
                               (ROOT / "models" / "two_tank.yaml", "R12:stuck_on@5",
                                "'R12' is no switched junction of two_tank")):
        done = bgc_cli("simulate", model, "--fault", fault, "-o", run)
        assert done.returncode == 1 and said in done.stderr and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
    made = bgc_cli("simulate", RELAY, "--fault", "K:stuck_on@1", "--steps", "200", "-o", run, "--plot",
                   tmp_path / "run.png")
    assert made.returncode == 0, made.stderr
    assert "fault: switch K stuck ON from t = 1" in made.stdout
    assert "# fault: switch K stuck ON from t = 1" in run.read_text()


@pytest.mark.slow
@pytest.mark.long
def test_a_campaign_runs_a_stuck_relay_and_its_diagnosis_says_unexplained(tmp_path):
    """A model that lists no stuck switch: a run whose relay sticks open at 3 s comes out
    "unexplained" (no fault model explains it), and the campaign counts it as a fault the model
    does not expect (one that lists it: tests/test_stuck_switch.py)."""
    from bgc.experiment import campaign_file, one_run

    path = tmp_path / "campaign.yaml"
    path.write_text(f"campaign: stuck\nseed: 1\ndefaults: {{particles: [200], steps: 600}}\ngroups:\n"
                    f"  - name: stuck\n    model: {RELAY}\n    modes: unpowered@6\n"
                    "    scenarios: ['K:stuck_off@3']\n")
    spec, = campaign_file.load_campaign(path).specs
    with pytest.warns(bgc.ScenarioWarning):
        row = one_run.run_one(spec, backend="numpy")
    assert row["status"] == "ok", row["failure"]
    assert row["detected"] and row["verdict"] == "unexplained" and row["expected"] is False
