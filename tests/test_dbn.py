"""Tests of :mod:`bgc.dbn`: nominal and faulty two-slice DBNs.

Expected arcs come from the thesis (Fig. III.2 a-c and section III.3 for the
circuit, Fig. IV.5 for RO's incipient R_pipe fault) and, independently of the
TCG path the compiler uses, from the structure of the derived equations: a state
x_j is a parent of x_i@t+1 exactly when x_j appears in dx_i/dt; a fault
parameter is a parent of exactly the states and measurements whose equations
contain it. Which parameters appear where is also derived by hand below for the
circuit and RO.
"""

from __future__ import annotations


import pytest
import sympy

from bgc.kinds import fault_kind

from bgc.compiler import causality, dbn, equations, tcg
from bgc.compiler.load import loads
from bgc.compiler.validate import validate

from conftest import ALL_MODELS, compiled



def arcs(graph, kind: str | None = None) -> set[tuple[str, str]]:
    return {(u, v) for u, v, d in graph.edges(data=True) if kind is None or d["arc"] == kind}


def variable(node: str) -> str:
    return node.rsplit("@", 1)[0]


def node_of(var: str, slice_: int) -> str:
    return f"{var}@t" if slice_ == 0 else f"{var}@t+1"


# ------------------------------------------------------------ circuit, nominal
def test_circuit_nominal_dbn_thesis_arcs():
    """Thesis III.3: f6 is algebraically related to e4 and e8 (intra-slice arcs in
    both slices); the temporal TCG edge e8 -dt-> e4 gives e8@t -> e4@t+1; every
    state persists; the input e1 first reaches e4."""
    g = compiled("circuit").dbn.nominal.graph
    for s in ("t", "t+1"):
        for x in ("e4", "e8"):
            assert g.edges[f"{x}@{s}", f"f6@{s}"]["arc"] == "intra"
    assert g.edges["e8@t", "e4@t+1"]["arc"] == "temporal"
    for x in ("e4", "e8", "f10"):
        assert g.edges[f"{x}@t", f"{x}@t+1"]["arc"] == "persistence"
    assert g.edges["e1@t", "e4@t+1"]["arc"] == "temporal"
    # the input acts on e8 and f10 only through e4: no direct arc
    assert not g.has_edge("e1@t", "e8@t+1") and not g.has_edge("e1@t", "f10@t+1")


def test_circuit_nominal_dbn_measurement_parents_by_hand():
    """f2 = (V - e4)/R1, f6 = (e4 - e8)/R2, e11 = R3*f10 (hand derivation):
    the parents of each measurement in a slice are the variables of its equation."""
    g = compiled("circuit").dbn.nominal.graph
    expected = {"f2": {"e1", "e4"}, "f6": {"e4", "e8"}, "e11": {"f10"}}
    for y, parents in expected.items():
        for s in ("t", "t+1"):
            assert {variable(p) for p in g.predecessors(f"{y}@{s}")} == parents
            assert all(p.endswith(f"@{s}") for p in g.predecessors(f"{y}@{s}"))


def test_circuit_nominal_dbn_node_attributes():
    g = compiled("circuit").dbn.nominal.graph
    roles = {"e4": "state", "e8": "state", "f10": "state", "f2": "measurement", "f6": "measurement",
             "e11": "measurement", "e1": "input"}
    assert set(g.nodes) == {f"{v}@{s}" for v in roles for s in ("t", "t+1")}
    for v, role in roles.items():
        for k, s in ((0, "t"), (1, "t+1")):
            d = g.nodes[f"{v}@{s}"]
            assert (d["role"], d["slice"], d["variable"]) == (role, k, v)
    assert {g.nodes[f"{x}@t"]["element"] for x in ("e4", "e8", "f10")} == {"C1", "C2", "L"}
    assert g.nodes["e1@t"]["signal"] == "V"


@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_dbn_arcs_never_go_back_in_time_and_form_a_dag(name):
    import networkx as nx

    model = compiled(name).dbn
    for d in (model.nominal, *model.faulty):
        g = d.graph
        assert nx.is_directed_acyclic_graph(g), d.name
        for u, v in g.edges:
            assert g.nodes[u]["slice"] <= g.nodes[v]["slice"], (d.name, u, v)
            assert u.endswith("@t" if g.nodes[u]["slice"] == 0 else "@t+1")


# ------------------------------------- DBN structure = equation structure
def equation_structure(ssm):
    """Arcs the derived equations imply: (x_j@t, x_i@t+1) for x_j in dx_i/dt,
    (u@t, x_i@t+1) for an input u in dx_i/dt, (v@s, y@s) for v in y's equation."""
    inputs = {sympy.Symbol(u) for u in ssm.inputs}
    states = {sympy.Symbol(x) for x in ssm.states}
    temporal = {(f"{j.name}@t", f"{x}@t+1") for x, rhs in zip(ssm.states, ssm.rhs)
                for j in rhs.free_symbols & states if j.name != x}
    input_arcs = {(u.name, f"{x}@t+1") for x, rhs in zip(ssm.states, ssm.rhs) for u in rhs.free_symbols & inputs}
    intra = {(v.name, y) for y, expr in zip(ssm.outputs, ssm.output_exprs)
             for v in expr.free_symbols & (states | inputs)}
    return temporal, input_arcs, intra


@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_inter_slice_state_arcs_equal_the_equation_dependencies(name):
    c = compiled(name)
    g = c.dbn.nominal.graph
    temporal, _, _ = equation_structure(c.equations)
    states = set(c.equations.states)
    got = {(u, v) for u, v in arcs(g, "temporal") if variable(u) in states}
    assert got == temporal
    assert arcs(g, "persistence") == {(f"{x}@t", f"{x}@t+1") for x in states}


@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_input_and_measurement_arcs_equal_the_equation_dependencies(name):
    """Input nodes are named by their bond variable and carry the input's name in
    ``signal``; measurement parents are the states and inputs of its equation."""
    c = compiled(name)
    g = c.dbn.nominal.graph
    _, input_arcs, intra = equation_structure(c.equations)
    signal = {variable(n): d["signal"] for n, d in g.nodes(data=True) if d["role"] == "input"}
    states = set(c.equations.states)
    got_inputs = {(signal[variable(u)], v) for u, v in arcs(g, "temporal") if variable(u) not in states}
    assert got_inputs == input_arcs
    got_intra = set()
    for u, v in arcs(g, "intra"):
        assert u[-2:] == v[-2:], (u, v)  # same slice
        src = variable(u)
        got_intra.add((signal.get(src, src), variable(v)))
        assert (u.replace("@t+1", "@t"), v.replace("@t+1", "@t")) in arcs(g, "intra")  # both slices
    assert got_intra == intra


# ------------------------------------------------------------ faulty DBNs
def test_circuit_abrupt_r2_dbn():
    """Fig. III.2 (c): R2 becomes R2 + delta_R2 with delta_R2(t+1) = delta_R2(t).
    By hand, R2 appears in de4/dt and de8/dt (the R2 current leaves C1 and enters
    C2) and in f6 = (e4 - e8)/R2, nowhere else."""
    d = compiled("circuit").dbn.get("R2:abrupt")
    g = d.graph
    assert (d.parameter, d.kind) == ("R2", "abrupt")
    assert g.edges["delta_R2@t", "delta_R2@t+1"]["arc"] == "persistence"
    children = {v for u, v in arcs(g, "fault")}
    assert {u for u, v in arcs(g, "fault")} == {"delta_R2@t", "delta_R2@t+1"}
    assert children == {"e4@t+1", "e8@t+1", "f6@t", "f6@t+1"}
    assert g.edges["D_R2@t", "D_R2@t+1"]["arc"] == "persistence"
    for s, k in (("t", 0), ("t+1", 1)):
        assert g.edges[f"D_R2@{s}", f"delta_R2@{s}"]["arc"] == "indicator"
        assert (g.nodes[f"D_R2@{s}"]["role"], g.nodes[f"D_R2@{s}"]["slice"]) == ("fault_indicator", k)
        assert (g.nodes[f"delta_R2@{s}"]["role"], g.nodes[f"delta_R2@{s}"]["slice"]) == ("fault_bias", k)
    # the nominal DBN is kept whole, and no parameter node exists for an abrupt fault
    assert arcs(compiled("circuit").dbn.nominal.graph) <= arcs(g)
    assert "R2@t" not in g


def test_circuit_incipient_c1_dbn():
    """Fig. III.2 (b): C1(t+1) = C1(t) + delta_C1(t), delta_C1(t+1) = delta_C1(t).
    By hand C1 appears only in de4/dt = (i1 - i2)/C1 and in no measurement."""
    d = compiled("circuit").dbn.get("C1:incipient")
    g = d.graph
    assert g.edges["C1@t", "C1@t+1"]["arc"] == "persistence"
    assert g.edges["delta_C1@t", "C1@t+1"]["arc"] == "drift"
    assert g.edges["delta_C1@t", "delta_C1@t+1"]["arc"] == "persistence"
    assert g.edges["D_C1@t", "D_C1@t+1"]["arc"] == "persistence"
    assert arcs(g, "fault") == {("C1@t", "e4@t+1")}
    for s, k in (("t", 0), ("t+1", 1)):
        assert (g.nodes[f"C1@{s}"]["role"], g.nodes[f"C1@{s}"]["slice"]) == ("fault_parameter", k)
        assert g.nodes[f"delta_C1@{s}"]["role"] == "fault_slope"
        assert g.nodes[f"D_C1@{s}"]["role"] == "fault_indicator"


def test_circuit_has_one_faulty_dbn_per_candidate_and_kind():
    model = compiled("circuit").dbn
    expected = {f"{p}:{k}" for p in ("R1", "R2", "R3", "C1", "C2", "L") for k in ("abrupt", "incipient")}
    # models/circuit.yaml's sensor faults (f2, f6, e11: bias, drift) and the source's bias
    expected |= {f"{y}_offset:{k}" for y in ("f2", "f6", "e11") for k in ("bias", "drift")} | {"V_offset:bias"}
    assert {d.name for d in model.faulty} == expected


@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_fault_arcs_reach_exactly_the_equations_containing_the_parameter(name):
    c = compiled(name)
    ssm = c.equations
    for d in c.dbn.faulty:
        if fault_kind(d.kind).noise or fault_kind(d.kind).replaces:  # in no equation: its arcs go to its sensor's
            continue  # measurement nodes only (tests/test_noise_fault.py, tests/test_sensor_faults.py)
        p = sympy.Symbol(d.parameter)
        carrier = d.parameter if d.kind in ("incipient", "drift") else f"delta_{d.parameter}"
        expected = {(f"{carrier}@t", f"{x}@t+1") for x, rhs in zip(ssm.states, ssm.rhs) if p in rhs.free_symbols}
        expected |= {(f"{carrier}@{s}", f"{y}@{s}") for y, e in zip(ssm.outputs, ssm.output_exprs)
                     if p in e.free_symbols for s in ("t", "t+1")}
        assert arcs(d.graph, "fault") == expected, d.name
        assert expected, f"{d.name}: a fault candidate that acts on nothing"


def test_ro_incipient_r_pipe_dbn_matches_thesis_fig_iv5():
    """Fig. IV.5: R_pipe is a parent of f22, e6, e13 and e27 in t+1 (the pipe
    flow q_pipe = (m2*f22 + e6 - e13)/R_pipe drives all four; by hand it does not
    enter df3/dt = (tau_fp - R_fp*f3 - m1*e6)/I_fp). Of the measurements (P_memb
    = e13, F_perm = e13/MR_memb, F_loop = q_pipe, F_back = (e13 - e6)/R_brine)
    only the loop flow F_loop contains R_pipe, in both slices."""
    g = compiled("ro").dbn.get("R_pipe:incipient").graph
    assert set(g.successors("R_pipe@t")) == {"f22@t+1", "e6@t+1", "e13@t+1", "e27@t+1", "R_pipe@t+1", "F_loop@t"}
    assert set(g.successors("R_pipe@t+1")) == {"F_loop@t+1"}
    measurements = {n for n, d in g.nodes(data=True) if d["role"] == "measurement"}
    assert {variable(m) for m in measurements} == {"P_memb", "F_perm", "F_loop", "F_back"}
    assert {variable(m) for m in measurements for u in g.predecessors(m) if variable(u) == "R_pipe"} == {"F_loop"}
    assert set(g.predecessors("R_pipe@t+1")) == {"R_pipe@t", "delta_R_pipe@t"}


# ------------------------------------------------- a state measured directly
# Regression: in bgc/dbn.py at HEAD the measurement node of ``e3`` reused the
# state's node id ``e3@t``, so add_node overwrote role 'state' with 'measurement'
# and element 'C' with None, leaving the DBN without its state.
RC_MEASURING_ITS_STATE = """
name: rc
parameters: {R: 1.0, C: 2.0}
inputs: {V: 1.0}
elements: {Vs: {kind: Se, value: V}, j: {kind: "1"}, R: {kind: R}, C: {kind: C}}
bonds: {1: [Vs, j], 2: [j, R], 3: [j, C]}
measurements: {e3: , f2: }
"""


def test_measuring_a_state_directly_keeps_the_state_node():
    ssm = equations.derive(tcg.build(causality.assign(validate(loads(RC_MEASURING_ITS_STATE)))))
    assert ssm.states == ("e3",) and "e3" in ssm.outputs
    g = dbn.build(ssm).nominal.graph
    # the state must stay a state (with its element) and still be observed
    assert g.nodes["e3@t"]["role"] == "state"
    assert g.nodes["e3@t"]["element"] == "C"
    observed = [n for n, d in g.nodes(data=True) if d["role"] == "measurement" and d["variable"] == "e3"]
    assert sorted(g.nodes[n]["slice"] for n in observed) == [0, 1], "the measurement of e3 has no node of its own"
    for n in observed:  # observed from the state of its own slice
        assert g.has_edge(node_of("e3", g.nodes[n]["slice"]), n)
