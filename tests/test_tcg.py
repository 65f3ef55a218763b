"""Tests of :mod:`bgc.tcg` (temporal causal graph).

The expected edges of the circuit are those the thesis lists for its Fig. II.4
(section II.3.2): ``f4 -dt/C1-> e4``, ``f8 -dt/C2-> e8``, ``e10 -dt/L-> f10``,
``e2 -1/R1-> f2``, ``e1 -+1-> e2``, ``e3 --1-> e2``, ``e4 -=-> e3 -=-> e5``
(the thesis draws the last two as a chain; both are equalities of the 0-junction
whose effort bond 4 fixes, so both start at e4). The simplified TCG is the one of
section III.3: ``e8 -dt-> e4``, and the algebraic ``e4 -> f6``, ``e8 -> f6``.

Parameter effects are derived by hand from the relation: the sign of the
target's change when the parameter increases, variables positive. E.g.
``f2 = e2/R1`` gives d f2/d R1 = -e2/R1**2 < 0, so effect -1; ``de4/dt = f4/C1``
gives -1 for C1; ``e11 = R3*f11`` gives +1 for R3.
"""

from __future__ import annotations


import math

import pytest
import sympy


from conftest import ALL_MODELS, ROOT, compiled



def edge(tcg, source: str, target: str):
    """The TcgEdge source -> target (fails the test if there is none)."""
    found = [e for e in tcg.edges if (e.source, e.target) == (source, target)]
    assert len(found) == 1, f"expected exactly one TCG edge {source} -> {target}, found {found}"
    return found[0]


# ------------------------------------------------------- circuit, thesis Fig. II.4
# (source, target, label, temporal, parameters, effects, sign)
THESIS_CIRCUIT_EDGES = [
    # C1 in integral causality imposes e4 on its 0-junction: de4/dt = f4/C1.
    ("f4", "e4", "dt/C1", True, ("C1",), (-1,), 1),
    ("f8", "e8", "dt/C2", True, ("C2",), (-1,), 1),
    # L imposes the flow of its 1-junction: df10/dt = e10/L.
    ("e10", "f10", "dt/L", True, ("L",), (-1,), 1),
    # R1 receives the effort of the first 1-junction: f2 = e2/R1.
    ("e2", "f2", "1/R1", False, ("R1",), (-1,), 1),
    # First 1-junction: e2 = e1 - e3.
    ("e1", "e2", "+1", False, (), (), 1),
    ("e3", "e2", "-1", False, (), (), -1),
    # First 0-junction, determined by bond 4: e3 = e5 = e4.
    ("e4", "e3", "=", False, (), (), 1),
    ("e4", "e5", "=", False, (), (), 1),
]

# Further circuit edges derived by hand from the same causal bond graph (not
# listed in the thesis's text): R2 receives e6 = e5 - e7 and gives f6 = e6/R2;
# L fixes the flow of the last 1-junction, so R3 receives f11 = f10 and gives
# e11 = R3*f11; the second 0-junction is determined by C2 (e7 = e9 = e8).
HAND_CIRCUIT_EDGES = [
    ("e6", "f6", "1/R2", False, ("R2",), (-1,), 1),
    ("e5", "e6", "+1", False, (), (), 1),
    ("e7", "e6", "-1", False, (), (), -1),
    ("f11", "e11", "R3", False, ("R3",), (1,), 1),
    ("f10", "f11", "=", False, (), (), 1),
    ("e8", "e7", "=", False, (), (), 1),
    ("e8", "e9", "=", False, (), (), 1),
    ("e9", "e10", "+1", False, (), (), 1),
    ("e11", "e10", "-1", False, (), (), -1),
]


@pytest.mark.parametrize("source,target,label,temporal,parameters,effects,sign",
                         THESIS_CIRCUIT_EDGES + HAND_CIRCUIT_EDGES)
def test_circuit_tcg_edge(source, target, label, temporal, parameters, effects, sign):
    tcg = compiled("circuit").tcg
    e = edge(tcg, source, target)
    assert (e.label, e.temporal, e.parameters, e.effects, e.sign) == (label, temporal, parameters, effects, sign)
    # the networkx graph carries the same edge data as the edge tuple
    d = tcg.graph.edges[source, target]
    assert (d["label"], d["temporal"], d["parameters"]) == (label, temporal, parameters)


def test_circuit_tcg_integrating_edges_are_exactly_the_three_storage_edges():
    tcg = compiled("circuit").tcg
    temporal = {(e.source, e.target) for e in tcg.edges if e.temporal}
    assert temporal == {("f4", "e4"), ("f8", "e8"), ("e10", "f10")}


def test_circuit_tcg_each_bond_variable_is_computed_once():
    """22 bond variables (11 bonds), every one defined by exactly one relation;
    e1 is the input (defined by the source alone) and has no predecessor."""
    g = compiled("circuit").tcg.graph
    bond_vars = {f"{k}{n}" for n in range(1, 12) for k in "ef"}
    assert {n for n, d in g.nodes(data=True) if d["kind"] in ("effort", "flow")} == bond_vars
    assert all("definition" in g.nodes[v] for v in bond_vars)
    assert g.in_degree("e1") == 0 and g.nodes["e1"]["role"] == "input"
    assert {n for n, d in g.nodes(data=True) if d["role"] == "state"} == {"e4", "e8", "f10"}


def test_circuit_simplified_tcg_has_the_thesis_edges():
    s = compiled("circuit").tcg.simplified
    # Kept variables: input e1, states e4, e8, f10, measured f2, f6, e11.
    assert set(s.nodes) == {"e1", "e4", "e8", "f10", "f2", "f6", "e11"}
    assert s.has_edge("e8", "e4") and s.edges["e8", "e4"]["temporal"] is True
    for a in ("e4", "e8"):
        assert s.has_edge(a, "f6") and s.edges[a, "f6"]["temporal"] is False
    # Hand derivation: f6 = (e4 - e8)/R2 involves R2 only.
    assert s.edges["e4", "f6"]["parameters"] == ("R2",)
    # e8 reaches e4 through e7 -> e6 -> f6 (1/R2) -> f5 -> f4 -> e4 (dt/C1).
    assert set(s.edges["e8", "e4"]["parameters"]) == {"C1", "R2"}
    # f10 does not reach f6 within one step (it only acts on e8 via f9 -> f8).
    assert not s.has_edge("f10", "f6")
    assert not s.has_edge("e1", "e8")  # the input first reaches e4 only


# --------------------------------------------------------------- two-ports
def test_gyrator_edges_of_the_dc_motor():
    """GY_k between the armature (bond 4 in) and the shaft (bond 5 out). Both
    inductances are integral, so the GY receives both flows and imposes both
    efforts: e4 = k*f5 (back emf), e5 = k*f4 (torque)."""
    tcg = compiled("dc_motor").tcg
    for s, t in (("f5", "e4"), ("f4", "e5")):
        e = edge(tcg, s, t)
        assert (e.label, e.relation, e.parameters, e.effects, e.temporal) == ("k", "gyrator", ("k",), (1,), False)
    # a gyrator swaps causality: no effort-to-effort or flow-to-flow edge across it
    assert not tcg.graph.has_edge("e5", "e4") and not tcg.graph.has_edge("f4", "f5")


def test_transformer_edges_of_the_ro_feed_pump():
    """TF_m1 (bond 4 in, bond 5 out): the pump inertia fixes f3 = f4, so the TF
    receives f4 and gives f5 = m1*f4; the reservoir fixes e5 = e6 and the TF gives
    e4 = m1*e5 (TF law e_in = m e_out, f_out = m f_in).

    Effects are signs at the initial operating point (tcg._operating_point):
    d(m1*src)/d m1 = src, so the effect is the sign of the source there. From
    models/ro.yaml: f4 = f3 = I_fp's initial 13.9887 > 0, e5 = e6 = C_res's
    initial -0.39887 < 0 (the reservoir's gauge pressure is slightly negative)."""
    tcg = compiled("ro").tcg
    for s, t, effect in (("f4", "f5", 1), ("e5", "e4", -1)):
        e = edge(tcg, s, t)
        assert (e.label, e.relation, e.parameters, e.temporal) == ("m1", "transformer", ("m1",), False)
        assert e.effects == (effect,)
        assert e.sign == 1  # m1 > 0


# --------------------------------------------- every model: relations consistent
@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_every_edge_source_appears_in_the_relation_of_its_target(name):
    """For each edge a -> b, the relation defining b (``derivative`` for the
    integrating edge into a state, else ``definition``) contains a; and, the other
    way round, every bond variable in a relation has its edge."""
    g = compiled(name).tcg.graph
    variables = {n for n, d in g.nodes(data=True) if d["kind"] in ("effort", "flow")}
    for a, b, d in g.edges(data=True):
        node = g.nodes[b]
        if d["temporal"]:
            assert node["role"] == "state", f"integrating edge {a} -> {b} into a non-state"
            relation = node["derivative"]
        else:
            relation = node["definition"]
        assert sympy.Symbol(a) in relation.free_symbols, f"{a} -> {b}: {a} not in {b}'s relation {relation}"
    for b, node in g.nodes(data=True):
        relation = node.get("derivative", node.get("definition"))
        if relation is None:
            continue
        used = {s.name for s in relation.free_symbols} & variables
        assert used == set(g.predecessors(b)), f"{b}: relation {relation} vs predecessors {set(g.predecessors(b))}"


@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_edge_labels_match_their_relation(name):
    """Each label says what the relation does with the source, read off the
    target's relation independently: '=' target == source; '+1'/'-1' the
    coefficient of the source in a junction sum; '1/P'/'P' a resistor or two-port
    coefficient; 'dt/...' an integration. The edge's parameters are those of the
    relation, and its sign that of the partial derivative for linear relations."""
    c = compiled(name)
    g = c.tcg.graph
    params = {p.name for p in c.model.parameters}
    for e in c.tcg.edges:
        node = g.nodes[e.target]
        rel = node["derivative"] if e.temporal else node["definition"]
        src = sympy.Symbol(e.source)
        assert e.parameters == tuple(sorted(s.name for s in rel.free_symbols if s.name in params)), e
        slope = sympy.diff(rel, src)
        if e.label == "=":
            assert sympy.simplify(rel - src) == 0, e
        elif e.label in ("+1", "-1"):
            assert slope == int(e.label), e
        elif e.label.startswith("dt/"):
            assert e.temporal and e.relation == "integral" and rel.is_polynomial(src), e
        elif e.label.startswith("1/") and e.relation in ("resistive", "transformer", "gyrator"):
            p = sympy.Symbol(e.label[2:])
            if p.name in params:
                assert sympy.simplify(rel - src / p) == 0, e
        elif e.label in params:
            assert sympy.simplify(rel - sympy.Symbol(e.label) * src) == 0, e
        if not {s.name for s in slope.free_symbols} - params:
            # linear in the source with a constant coefficient: the sign is that of
            # the coefficient at nominal parameter values
            values = {sympy.Symbol(p.name): p.value for p in c.model.parameters}
            coeff = float(slope.subs(values))
            assert e.sign == (coeff > 0) - (coeff < 0), e


def test_resistor_loop_tcg_has_a_cycle_of_algebraic_edges():
    """The loop closed by the arbitrary resistor is a directed cycle of algebraic
    edges through the node voltage e4 and R2's current f4 (by hand: e4 -> f4 ->
    ... -> e4 whatever the arbitrary choice)."""
    import networkx as nx

    g = compiled("resistor_loop").tcg.graph
    algebraic = nx.DiGraph([(u, v) for u, v, d in g.edges(data=True) if not d["temporal"]])
    cycles = [set(c) for c in nx.simple_cycles(algebraic)]
    assert cycles and any({"e4", "f4"} <= c for c in cycles)
    # in the circuit (no algebraic loop) there is none
    g2 = compiled("circuit").tcg.graph
    assert nx.is_directed_acyclic_graph(nx.DiGraph([(u, v) for u, v, d in g2.edges(data=True) if not d["temporal"]]))


def test_ro_membrane_edge_signs_hold_at_the_operating_point():
    """f16 = e16/MR_memb with MR_memb > 0 wherever the plant operates (K near
    K0 = 12000; MR_memb > 0 for K > K0 - 29*K_slope = 7215). By hand: d f16/d e16 =
    1/MR_memb > 0 and d f16/d R_memb = -f16/R_memb < 0. (Evaluating e27 at +1, as
    an earlier tcg._sign did, makes MR_memb negative and flips both signs.)"""
    e = edge(compiled("ro").tcg, "e16", "f16")
    assert e.sign == 1
    assert dict(zip(e.parameters, e.effects))["R_memb"] == -1
    # K (e27) up: MR_memb up, permeate down
    k = edge(compiled("ro").tcg, "e27", "f16")
    assert k.sign == -1


def test_ro_storage_effect_is_not_decided_by_rounding_noise():
    """At the YAML's initial state the feed pump is at steady state: by hand
    e3 = 1 - 0.1*13.98906 - 1.0*(-0.398906) = 0 exactly. A zero variable is read as
    +1 (tcg._operating_point's docstring), so d(e3/I_fp)/d I_fp = -e3/I_fp**2
    gives effect -1, as for every other storage element of the models."""
    from fractions import Fraction

    assert Fraction("1") - Fraction("0.1") * Fraction("13.98906") + Fraction("0.398906") == 0
    e = edge(compiled("ro").tcg, "e3", "f3")
    assert e.effects == (-1,)


# ------------------------------------------------------- inverting nonlinear laws
LAWS = ROOT / "tests" / "data" / "laws"


@pytest.mark.parametrize("name, message", [
    ("orifice_inverted", "law of Rt (f = g0*sqrt(abs(e))*sign(e)) must be inverted"),
    ("lambertw", "uses a function bgc cannot evaluate"),
    ("unsolvable", "bgc cannot solve it for e"),
])
def test_a_law_without_a_usable_inverse_is_a_located_one_line_error(name, message):
    from bgc.errors import EquationError
    from bgc.pipeline import compile_model

    with pytest.raises(EquationError) as info:
        compile_model(LAWS / f"{name}.yaml")
    line = info.value.line()
    assert "\n" not in line and message in line
    assert line.startswith(f"{LAWS / name}.yaml:9:22: ") or line.startswith(f"tests/data/laws/{name}.yaml:9:22: ")
    assert line.endswith("(write the law as 'e = <expression of f>')")


def test_sign_losing_inverse_that_sympy_offers_is_refused():
    """For f = a*sqrt(|e|)*sign(e) sympy (plain symbols) offers e = f**2/a**2,
    right for f > 0 only; the numerical check on both signs refuses it."""
    from types import SimpleNamespace

    from bgc.errors import EquationError
    from bgc.compiler.tcg import _invert

    e, f, a = sympy.symbols("e3 f3 a")
    el = SimpleNamespace(name="Rt", law=SimpleNamespace(text="f = a*sqrt(abs(e))*sign(e)", loc="x.yaml:1:1"))
    with pytest.raises(EquationError):
        _invert(el, a * sympy.sqrt(sympy.Abs(e)) * sympy.sign(e), "f3", "e3", {"a": 2.0})
    # a law with a real inverse on its whole range passes: e = a*atanh(f/g0)
    g0 = sympy.Symbol("g0")
    inv = _invert(el, g0 * sympy.tanh(e / a), "f3", "e3", {"a": 2.0, "g0": 0.5})
    for v in (-0.4, -0.1, 0.2, 0.45):
        assert float(inv.subs({f: v, a: 2.0, g0: 0.5})) == pytest.approx(2.0 * math.atanh(v / 0.5), rel=1e-12)


def test_tanh_law_inverted_gives_the_hand_derived_state_equation():
    """Se F -> 1-junction -> I m and R with f = g0*tanh(e/a): the R needs e = a*atanh(f/g0),
    so dp/dt = F - a*atanh(f2/g0) with f2 = p/m; by hand at f2 = 0.1: (0.2 - 2*atanh(0.2))/1."""
    from bgc.pipeline import compile_model

    ssm = compile_model(LAWS / "tanh_inverted.yaml").equations
    rhs = ssm.rhs[0].subs({sympy.Symbol(n): v for n, v in zip(ssm.parameters, ssm.parameter_values)})
    rhs = rhs.subs({sympy.Symbol("F"): 0.2, sympy.Symbol(ssm.states[0]): 0.1})
    assert float(rhs) == pytest.approx(0.2 - 2.0 * math.atanh(0.1 / 0.5), rel=1e-12)


def test_nonlinear_algebraic_loop_sympy_cannot_solve_is_one_line():
    from bgc.errors import EquationError
    from bgc.pipeline import compile_model

    with pytest.raises(EquationError) as info:
        compile_model(LAWS / "nonlinear_loop.yaml")
    assert "is nonlinear and bgc cannot solve it" in info.value.line() and "\n" not in info.value.line()
