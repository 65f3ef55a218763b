"""Hybrid bond graphs (bgc/compiler/modes.py): switched junctions, modes,
transitions, and each mode's causality and equations, against equations
derived by hand for a small switched circuit (tests/data/hybrid/relay_rl.yaml).
The located errors of what a person gets wrong are files of
tests/data/invalid/hybrid_*.yaml, checked by tests/test_validate.py."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import sympy

from bgc.compiler import causality, modes
from bgc.compiler.load import load, loads
from bgc.compiler.validate import validate
from bgc.errors import BgcError
from bgc.ir import sym
from bgc import pipeline

from conftest import bgc_cli

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"

i, v, V, R_s, L, C, R_load, R_aux, offset = sympy.symbols("f3 e6 V R_s L C R_load R_aux v_C_offset")


@pytest.fixture(scope="module")
def relay():
    model = validate(load(RELAY))
    return model, {m.name: m for m in modes.compile_modes(model)}


def test_the_model_file_gives_the_switches_the_modes_and_the_transitions(relay):
    model, _ = relay
    hybrid = model.modes
    assert hybrid.switches == ("K", "S")
    assert hybrid.names == ("open", "closed", "unpowered") and hybrid.initial == "open"
    assert [(m.name, m.on) for m in hybrid.modes] == [("open", ("S",)), ("closed", ("K", "S")), ("unpowered", ())]
    kinds = [(t.source, t.target, t.kind) for t in hybrid.transitions]
    assert kinds == [("open", "closed", "autonomous"), ("closed", "open", "autonomous"),
                     ("open", "unpowered", "controlled"), ("closed", "unpowered", "controlled"),
                     ("unpowered", "open", "timed")]
    up, down, _, _, back = hybrid.transitions
    # a guard on a measurement reads its noise-free value: v_C = e6
    assert (up.guard.lhs, up.guard.op, up.guard.rhs) == (v, ">", 6)
    assert up.guard.holds(6.01, 6.0) and not up.guard.holds(6.0, 6.0) and down.guard.holds(3.9, 4.0)
    assert back.after == 5.0 and back.resets == (("f3", sympy.Integer(0)),)


def test_an_off_junction_is_a_zero_source_on_each_of_its_bonds(relay):
    model, _ = relay
    g = modes.mode_graph(model, "open")  # K is OFF: bonds 9 and 10 end at zero flow sources
    assert [b.number for b in g.bonds] == [b.number for b in model.bonds]
    ends = {b.number: (b.tail, b.head) for b in g.bonds}
    assert ends[9] == ("J_c", "K_off9") and ends[10] == ("K_off10", "R_aux")
    zero = {el.name: (el.kind, el.source) for el in g.elements if el.name.startswith("K_off")}
    assert zero == {"K_off9": ("Sf", 0), "K_off10": ("Sf", 0)}
    assert "K" not in {el.name for el in g.elements} and "S" in {el.name for el in g.elements}


def _same(a, b) -> bool:
    return sympy.simplify(a - b) == 0


def test_each_modes_equations_are_those_derived_by_hand(relay):
    """By hand (i the coil's current f3, v the capacitor's voltage e6):
    supply on: L di/dt = V - R_s i - v; relay open: C dv/dt = i - v/R_load;
    relay closed: C dv/dt = i - v/R_load - v/R_aux; supply off: the coil's
    current is no state (0), C dv/dt = -v/R_load; the sensors read v and i
    (0 with the supply off), v_C plus the offset of its bias fault
    (v_C_offset, 0 when healthy)."""
    _, compiled = relay
    open_, closed, unpowered = compiled["open"].equations, compiled["closed"].equations, compiled["unpowered"].equations
    assert open_.states == closed.states == ("f3", "e6") and unpowered.states == ("e6",)
    di = (V - R_s * i - v) / L
    for eq, dv in ((open_, (i - v / R_load) / C), (closed, (i - v / R_load - v / R_aux) / C)):
        assert _same(eq.rhs[0], di) and _same(eq.rhs[1], dv)
        assert dict(zip(eq.outputs, eq.output_exprs)) == {"i_L": i, "v_C": v + offset}
    assert _same(unpowered.rhs[0], -v / (R_load * C))
    assert dict(zip(unpowered.outputs, unpowered.output_exprs)) == {"i_L": 0, "v_C": v + offset}
    assert modes.states(tuple(compiled.values())) == ("f3", "e6")


def test_an_idle_storage_element_is_no_state_and_the_causality_changes_are_listed(relay):
    _, compiled = relay
    coil = {s.element: s.integral for s in compiled["unpowered"].causal.storage}
    assert coil == {"C": True, "L": False}
    assert modes.causality_changes(compiled["open"], compiled["unpowered"]) == ["L leaves integral causality (no state)"]
    assert modes.causality_changes(compiled["unpowered"], compiled["open"]) == [
        "L enters integral causality (a state again)"]
    assert modes.causality_changes(compiled["open"], compiled["closed"]) == []


def test_bgc_check_lists_the_modes_their_states_and_the_transitions():
    done = bgc_cli("check", "tests/data/hybrid/relay_rl.yaml")
    assert done.returncode == 0 and done.stderr == ""
    out = done.stdout
    assert "  switched junctions: K, S" in out
    assert "    open: on S; states f3, e6 (supply on, relay open)" in out
    assert "    unpowered: on none; states e6 (supply off)\n      derivative causality: L (I, bond 3)" in out
    assert "    open -> closed: when v_C > 6" in out and "    open -> unpowered: controlled (the data say the mode)\n" \
           "      causality: L leaves integral causality (no state)" in out
    assert "    unpowered -> open: after 5; reset f3 := 0" in out


def test_a_relay_with_no_gap_between_its_thresholds_is_warned_of_and_one_with_a_gap_is_not(tmp_path):
    assert "  warnings: none" in bgc_cli("check", RELAY).stdout  # v_C > 6, then v_C < 4: a gap of 2
    for back in ("v_C < 6", "6 >= v_C"):  # the same value the other way round, however written
        path = tmp_path / "relay.yaml"
        path.write_text(RELAY.read_text(encoding="utf-8").replace('"v_C < 4"', f'"{back}"'), encoding="utf-8")
        done = bgc_cli("check", path)
        assert done.returncode == 0, done.stderr
        assert ("  warnings: 1\n    warning: open -> closed (v_C > 6) and closed -> open "
                f"({back}) switch at the same value, 6: no hysteresis") in done.stdout, done.stdout


@pytest.mark.slow
def test_bgc_diagnoses_a_run_of_a_model_with_modes_and_refuses_what_is_not_built_in_one_line(tmp_path):
    run = bgc_cli("simulate", "tests/data/hybrid/relay_rl.yaml", "--steps", "200", "-o", tmp_path / "r.csv")
    assert run.returncode == 0, run.stderr
    done = bgc_cli("diagnose", "tests/data/hybrid/relay_rl.yaml", "--data", tmp_path / "r.csv", "-o", tmp_path / "d",
                   "--backend", "numpy")
    assert done.returncode == 0 and "relay_rl: no fault" in done.stdout, done.stderr
    rows = [line.split(",") for line in (tmp_path / "r.csv").read_text().splitlines() if line and line[0] != "#"]
    drop = rows[0].index("mode")  # the run without its mode column
    (tmp_path / "plain.csv").write_text("\n".join(",".join(r[:drop] + r[drop + 1:]) for r in rows) + "\n")
    refused = bgc_cli("calibrate", "tests/data/hybrid/relay_rl.yaml", "--data", tmp_path / "plain.csv", "-o",
                      tmp_path / "c.yaml")
    assert refused.returncode == 1 and len(refused.stderr.strip().splitlines()) == 1, refused.stderr
    assert "the data have no mode column" in refused.stderr and "Traceback" not in refused.stderr


def test_a_stage_of_one_mode_is_shown_with_mode():
    done = bgc_cli("show", "equations", "tests/data/hybrid/relay_rl.yaml", "--mode", "closed")
    assert done.returncode == 0, done.stderr
    assert "R_aux" in done.stdout and "de6/dt" in done.stdout.replace(" ", "")
    graph = bgc_cli("show", "bondgraph", "tests/data/hybrid/relay_rl.yaml", "--mode", "open").stdout
    assert "# mode open: switched junctions ON: S; OFF: K (each OFF junction a zero source on each of its bonds)" \
        in graph
    assert "  K_off9  Sf   flow source (K OFF in mode open)" in graph and "  S       1    1-junction (switched: ON)" in graph
    missing = bgc_cli("show", "equations", "tests/data/hybrid/relay_rl.yaml")
    assert missing.returncode == 1 and "choose one with --mode: open, closed, unpowered" in missing.stderr
    wrong = bgc_cli("show", "causality", "models/two_tank.yaml", "--mode", "open")
    assert wrong.returncode == 1 and "has no modes" in wrong.stderr


def test_a_storage_element_held_by_a_varying_source_is_still_refused_and_named(tmp_path):
    """Derivative causality is resolved only where the imposed variable is
    constant (an idle element); docs/examples/deriv.yaml's capacitor, fixed
    by an input, is refused with its place."""
    with pytest.raises(BgcError, match=r"deriv.yaml:7:55: C element C is in derivative causality \(e3 is imposed"):
        pipeline.compile_model(ROOT / "docs" / "examples" / "deriv.yaml")


def test_a_storage_element_fixed_by_a_constant_source_is_idle(tmp_path):
    """An inertia whose flow a constant flow source imposes gives no effort
    (I d(const)/dt = 0): the model compiles, the inertia adds no state."""
    path = tmp_path / "held.yaml"
    path.write_text("name: held\nparameters: {R: 1.0, C: 2.0, I: 0.5}\ninputs: {V: 1.0}\n"
                    "elements: {V: {kind: Se}, j: {kind: '1'}, R: {kind: R}, C: {kind: C},\n"
                    "           q: {kind: Sf, value: 0.25}, k: {kind: '1'}, I: {kind: I}, n: {kind: '0'}}\n"
                    "bonds: {1: [V, j], 2: [j, R], 3: [j, n], 4: [n, C], 5: [q, k], 6: [k, I], 7: [k, n]}\n",
                    encoding="utf-8")
    c = pipeline.compile_model(path)
    assert c.equations.states == ("e4",)
    variables = dict(c.equations.variables)
    assert variables["e6"] == 0 and float(variables["f6"]) == 0.25
    assert _same(c.equations.rhs[0], ((sym("V") - sym("e4")) / sym("R") + sympy.Rational(1, 4)) / sym("C"))


def test_a_switch_changes_the_signatures_and_the_dbns(relay):
    """By hand: R_aux enters the equations only with the relay closed (C dv/dt
    gains -v/R_aux), so in 'open' its fault deviates nothing (undetectable)
    and its DBN has no fault arc into a state; in 'closed' a rise of R_aux
    lowers the current it draws, so v rises in slope (0+ on v_C, like a rise
    of R_load, with which it then enters as one conductance 1/R_aux +
    1/R_load: one ambiguity group)."""
    _, compiled = relay
    open_, closed = compiled["open"].signatures, compiled["closed"].signatures
    sig = {mode: {x.name: dict(zip(s.measurements, ("".join(c[:2]) for c in x.symbols))) for x in s.signatures}
           for mode, s in (("open", open_), ("closed", closed))}
    assert sig["open"]["R_aux+:abrupt"] == {"i_L": "00", "v_C": "00"} and "R_aux+:abrupt" in open_.undetectable
    assert sig["closed"]["R_aux+:abrupt"]["v_C"] == "0+" and not closed.undetectable
    assert ("R_aux+:abrupt", "R_load+:abrupt") in [tuple(g) for g in closed.ambiguity]
    arcs = {mode: {(u, v) for u, v, d in compiled[mode].dbn.get("R_aux:abrupt").graph.edges(data=True)
                   if d["arc"] == "fault"} for mode in ("open", "closed")}
    assert arcs == {"open": set(), "closed": {("delta_R_aux@t", "e6@t+1")}}


def test_the_dbn_across_the_modes_has_the_mode_as_a_node(relay):
    """By hand, from the relay's equations: the coil's current is a state only with the supply on
    (idle, 0, unpowered) and C dv/dt gains -v/R_aux with the relay closed, so the mode picks both
    states' equations; i_L reads f3, which is 0 unpowered, and v_C reads e6 in every mode. The
    guards read v_C = e6 (after the step), the timed return needs the time in the mode, the
    operator's trips the data's mode, and the return resets f3. The supply's arcs (V into the
    current, the current into v) hold with the supply on only; R_aux's fault reaches v only closed.
    The zero sources an OFF junction leaves are not nodes."""
    from bgc.compiler.hybrid_dbn import across_modes

    model, compiled = relay
    ordered = tuple(compiled[name] for name in model.modes.names)
    g = across_modes(model, ordered).graph
    arcs = {(a, b): (k, g.edges[a, b].get("modes")) for a, b, k in g.edges(data="arc")}
    assert {n for n in g if g.nodes[n]["role"] == "input"} == {"e1@t", "e1@t+1", "mode_input@t", "mode_input@t+1"}
    assert {n for n in g if g.nodes[n]["role"] == "mode"} == {"mode@t", "mode@t+1", "dwell@t", "dwell@t+1"}
    mode_arcs = {(a, b) for (a, b), (k, _) in arcs.items() if k in ("mode", "guard", "command", "timer", "reset")}
    assert mode_arcs == {("mode@t", "f3@t+1"), ("mode@t", "e6@t+1"), ("mode@t+1", "i_L@t+1"),
                         ("e6@t+1", "mode@t+1"), ("mode_input@t+1", "mode@t+1"), ("mode@t", "dwell@t+1"),
                         ("dwell@t+1", "mode@t+1"), ("mode@t+1", "f3@t+1")}
    assert arcs[("mode@t+1", "f3@t+1")] == ("reset", None) and arcs[("e6@t+1", "mode@t+1")] == ("guard", None)
    assert arcs[("e1@t", "f3@t+1")] == ("temporal", "open,closed")
    assert arcs[("f3@t", "e6@t+1")] == ("temporal", "open,closed")
    assert arcs[("e6@t", "e6@t+1")] == ("persistence", None)
    fault = across_modes(model, ordered, "R_aux:abrupt").graph
    assert fault.edges["delta_R_aux@t", "e6@t+1"] == {"arc": "fault", "modes": "closed"}


def test_bgc_show_dbn_draws_the_dbn_across_the_modes(tmp_path):
    done = bgc_cli("show", "dbn", "tests/data/hybrid/relay_rl.yaml")
    assert done.returncode == 0, done.stderr
    assert re.search(r"^node mode@t\+1 +mode$", done.stdout, re.M)
    assert re.search(r"^arc +e1@t -> f3@t\+1 +temporal \(in open, closed\)$", done.stdout, re.M)
    dot = bgc_cli("show", "dbn", "tests/data/hybrid/relay_rl.yaml", "--format", "dot").stdout
    assert '"mode@t" -> "f3@t+1" [color="#208040"];' in dot and 'tooltip="in open,closed"' in dot
    picture = tmp_path / "relay-dbn.png"
    drawn = bgc_cli("show", "dbn", "tests/data/hybrid/relay_rl.yaml", "--format", "png", "-o", picture,
                    "--engine", "matplotlib")
    assert drawn.returncode == 0 and picture.stat().st_size > 20_000


#: Two effort sources and two resistors on a 1-junction J, and an inertia L joined to J through a
#: switched 0-junction SW: with SW ON, L fixes J's flow, and both resistors take it (resistance form,
#: e = R f); with SW OFF (zero effort on its bonds), J's flow is fixed by one resistor in conductance form
#: (f = e / R), either one: an algebraic loop.
LOOP_SWITCH = """\
name: loop_switch
parameters: {R1: 1.0, R2: 2.0, L: 0.5}
inputs: {V1: 1.0, V2: 0.5}
elements:
  V1: {kind: Se}
  V2: {kind: Se}
  J: {kind: "1"}
  R1: {kind: R}
  R2: {kind: R}
  SW: {kind: "0", switch: true}
  L: {kind: I, initial: 0.0}
bonds:
  1: [V1, J]
  2: [J, R1]
  3: [J, R2]
  4: [J, V2]
  5: [J, SW]
  6: [SW, L]
measurements:
  i: {expr: f6}
modes:
  with_l: {on: [SW]}
  without_l: {on: []}
transitions:
  - {from: with_l, to: without_l}
  - {from: without_l, to: with_l}
"""


def test_a_mode_keeps_the_causal_strokes_of_the_mode_it_is_entered_from():
    """Hybrid SCAP (MoTHS): without L, one resistor must turn to conductance form. From scratch SCAP
    takes its preferred one (R1, the first), which moves bond 2 although nothing forces it; reassigned
    from the mode with L, R1 keeps the resistance form it had there (bond 2's effort from R1) and the
    loop is closed by R2 (bond 3's effort now from J). The equations are the same: with SW OFF, L's
    effort is 0 (di/dt = 0: it holds its current), and J's flow is (V1 - V2) / (R1 + R2)."""
    m = validate(loads(LOOP_SWITCH, "loop_switch.yaml"))
    with_l, without_l = modes.compile_modes(m)
    strokes = {x.name: {c.bond: c.effort_by for c in x.causal.bonds} for x in (with_l, without_l)}
    assert strokes["with_l"][2] == "R1" and strokes["with_l"][3] == "R2"  # both forced: resistance form
    assert strokes["without_l"][2] == "R1" and strokes["without_l"][3] == "J"
    assert modes.causality_changes(with_l, without_l) == ["bond 3: effort now from J (was R2)"]
    scratch = causality.assign(without_l.graph)  # what SCAP alone gives: R1's bond moves instead
    assert {c.bond: c.effort_by for c in scratch.bonds}[2] == "J"
    assert sympy.simplify(without_l.equations.rhs[0]) == 0
    V1, V2, R1, R2 = sympy.symbols("V1 V2 R1 R2")
    f2 = dict(without_l.equations.variables)["f2"]
    assert sympy.simplify(f2 - (V1 - V2) / (R1 + R2)) == 0


VALVE = Path(__file__).resolve().parent.parent / "docs" / "examples" / "valve_tanks.yaml"


def test_a_valve_that_joins_two_tanks_merges_them_while_it_is_open():
    """Shut: C1 de2/dt = f_in - e2/R1 and C2 de6/dt = -e6/R2. Open (no resistance between the tanks):
    one pressure, (C1 + C2) de2/dt = f_in - e2/R1 - e2/R2, and tank 2 reads it (P2 = e2)."""
    m = validate(load(VALVE))
    shut, opened = modes.compile_modes(m)
    C1, C2, R1, R2, f_in, e2, e6 = sympy.symbols("C1 C2 R1 R2 f_in e2 e6")
    assert shut.equations.states == ("e2", "e6") and opened.equations.states == ("e2",)
    assert sympy.simplify(shut.equations.rhs[0] - (f_in - e2 / R1) / C1) == 0
    assert sympy.simplify(shut.equations.rhs[1] + e6 / (R2 * C2)) == 0
    assert sympy.simplify(opened.equations.rhs[0] - (f_in - e2 / R1 - e2 / R2) / (C1 + C2)) == 0
    assert dict(zip(opened.equations.outputs, opened.equations.output_exprs))["P2"] == e2


def _valve_run(r2_after: float, onset: float, seed: int):
    """The valve tanks simulated by solve_ivp on the equations above, the valve opening at 20, 60 and
    shutting at 40, 80 (the volume shared out on opening, tank 2 left at the common pressure on
    shutting), R2 = r2_after from ``onset``; the readings with the model's noise."""
    import numpy as np
    from scipy.integrate import solve_ivp

    from bgc.data import runs

    C1, C2, R1, f_in = 2.0, 1.0, 4.0, 1.0

    def r2(t):
        return r2_after if t >= onset else 3.0

    def shut(t, x):
        return [(f_in - x[0] / R1) / C1, -x[1] / (r2(t) * C2)]

    def opened(t, x):
        return [(f_in - x[0] / R1 - x[0] / r2(t)) / (C1 + C2)]

    t = np.arange(1, 201) * 0.5
    e2, e6, mode = np.zeros(t.size), np.zeros(t.size), np.zeros(t.size)
    x = [4.0, 0.0]
    edges = [0.0, 20.0, 40.0, 60.0, 80.0, 100.5]
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        inside = (t >= a) & (t < b)
        if i % 2:  # open: the volume shared out
            x = [(C1 * x[0] + C2 * x[1]) / (C1 + C2)] * 2
            sol = solve_ivp(opened, (a, b), [x[0]], t_eval=np.r_[t[inside], b], max_step=0.05, rtol=1e-10,
                            atol=1e-12)
            e2[inside] = e6[inside] = sol.y[0][:-1]
            x = [sol.y[0][-1]] * 2
        else:
            sol = solve_ivp(shut, (a, b), x, t_eval=np.r_[t[inside], b], max_step=0.05, rtol=1e-10, atol=1e-12)
            e2[inside], e6[inside] = sol.y[0][:-1], sol.y[1][:-1]
            x = [sol.y[0][-1], sol.y[1][-1]]
        mode[inside] = 2 if i % 2 else 1
    c = pipeline.compile_model(VALVE)
    std = dict(zip(c.equations.outputs, c.numerics.noise.measurement))
    rng = np.random.default_rng(seed)
    ys = {"P1": e2 + rng.normal(0, std["P1"], t.size), "P2": e6 + rng.normal(0, std["P2"], t.size)}
    return runs.Run(t, {"f_in": np.full(t.size, f_in)}, ys, {}, {}, (), modes=mode)


def test_the_valve_tanks_diagnosed_on_data_from_their_hand_derived_equations():
    """Healthy: no fault. Tank 2's outlet R2 from 3 to 4.5 at t = 30 (the valve open): R2 isolated and
    sized, through the switches."""
    import bgc

    assert bgc.diagnose(VALVE, _valve_run(3.0, 30.0, 1)).diagnosis.verdict == "no fault"
    d = bgc.diagnose(VALVE, _valve_run(4.5, 30.0, 2)).diagnosis
    assert d.verdict == "isolated" and d.candidates == ("R2_abrupt",), (d.verdict, d.candidates)
    best = next(h for h in d.hypotheses if h.name == "R2_abrupt")
    assert best.estimate.low <= 1.5 <= best.estimate.high
