"""Stage 6: :class:`~bgc.ir.StateSpaceModel` -> :class:`~bgc.ir.DbnModel`.

Two-slice dynamic Bayesian networks (2TBN) built from the simplified TCG as in
Roychoudhury (2009) and the thesis (sections III.2 and III.3):

* every state ``X`` has nodes ``X@t`` and ``X@t+1`` and a persistence arc;
* a temporal (integrating) path ``X_j -> X_i`` in the TCG gives the inter-slice
  arc ``X_j@t -> X_i@t+1``; an input ``U`` gives ``U@t -> X@t+1`` for the first
  states it reaches;
* a measurement ``Y`` algebraically related to a state or input gets intra-slice
  arcs in both slices.

One faulty DBN per fault candidate and kind (thesis Fig. III.2 b, c; Fig. IV.5):

* abrupt fault of parameter ``P``: a persistent bias node ``delta_P``
  (``delta_P(t+1) = delta_P(t)``) replaces ``P`` by ``P + delta_P`` in every
  relation; it is a parent of every state and measurement whose equation
  involves ``P``;
* incipient fault: ``P`` itself becomes a random variable with a persistent drift
  ``delta_P``: ``P(t+1) = P(t) + delta_P(t)``, and ``P`` replaces every
  occurrence of the nominal parameter.
* sensor and actuator faults are faults of the symbol the compiler adds
  (``<sensor>_offset``, ``<input>_offset``, ``<input>_gain``), as above; a
  stuck sensor's value ``<sensor>_stuck`` replaces the sensor's reading: the
  measurement node loses its parents in the plant and has the fault node
  alone (section III.3's measurement fault, with the reading cut off); a
  noise fault's factor ``<sensor>_noise`` scales the std of the sensor's
  noise: its node is a parent of the measurement node only, which keeps its
  parents in the plant (section III.3's E_i -> M_i arc: M_i's variance is
  small while E_i is false, much larger once it is true).

A discrete fault-indicator node ``D_P`` (persistent) is the parent of the fault
node, as in the thesis's Fig. III.1. A step fault that comes and goes
(:func:`intermittent`) has its indicator a two-state Markov chain instead
(``switching`` from slice to slice), a parent of everything the fault's
magnitude reaches: the fault acts as ``D_P * delta_P``.
"""

from __future__ import annotations

import networkx as nx

from ..ir import Dbn, DbnModel, StateSpaceModel, sym
from ..kinds import comes_and_goes, fault_kind


def node(variable: str, slice_: int) -> str:
    """Node id of a variable in slice 0 (``t``) or 1 (``t+1``): ``node('e4', 1) == 'e4@t+1'``."""
    return f"{variable}@t" if slice_ == 0 else f"{variable}@t+1"


def measurement_id(name: str, states: tuple[str, ...]) -> str:
    """Variable id of a measurement's node: its name, or ``y_<name>`` when the
    measurement is named like the state it reads (``e3`` measured directly)."""
    return f"y_{name}" if name in states else name


def build(ssm: StateSpaceModel) -> DbnModel:
    """The nominal DBN and one faulty DBN per fault candidate and kind."""
    nominal = _nominal(ssm)
    faulty = []
    for fault in ssm.model.faults:
        for kind in fault.kinds:
            faulty.append(_faulty(ssm, nominal, fault.parameter, kind))
    return DbnModel(ssm, Dbn("nominal", None, None, nx.freeze(nominal)), tuple(faulty))


def fault_outputs(ssm: StateSpaceModel, parameter: str, kind: str) -> tuple:
    """The measurement equations of a fault model: the nominal ones, except
    that a kind that ``replaces`` the reading (a stuck sensor) reads its
    parameter instead (the fault's subject is the measurement)."""
    if not fault_kind(kind).replaces:
        return ssm.output_exprs
    subject = next(f.subject for f in ssm.model.faults if f.parameter == parameter)
    return tuple(sym(parameter) if y == subject else e for y, e in zip(ssm.outputs, ssm.output_exprs))


def noisy_sensor(ssm: StateSpaceModel, parameter: str, kind: str) -> str | None:
    """The sensor whose noise std a noise fault of ``parameter`` scales (its
    parameter enters no equation, so no expression names the measurement it
    strikes); None for any other kind."""
    if not fault_kind(kind).noise:
        return None
    return next(f.subject for f in ssm.model.faults if f.parameter == parameter)


def _nominal(ssm: StateSpaceModel) -> nx.DiGraph:
    s = ssm.tcg.simplified
    g = nx.DiGraph()
    roles = {n: d["role"] for n, d in s.nodes(data=True)}
    elements = dict(zip(ssm.states, ssm.state_elements))
    for x in ssm.states:
        for k in (0, 1):
            g.add_node(node(x, k), variable=x, slice=k, role="state", element=elements[x])
        g.add_edge(node(x, 0), node(x, 1), arc="persistence")
    tg = ssm.tcg.graph
    for n, role in roles.items():
        if role == "input":
            for k in (0, 1):
                g.add_node(node(n, k), variable=n, slice=k, role="input",
                           element=tg.nodes[n].get("element"), signal=",".join(tg.nodes[n].get("inputs", ())))
    outputs = set(ssm.outputs)
    for name in ssm.outputs:
        for k in (0, 1):
            g.add_node(node(measurement_id(name, ssm.states), k), variable=name, slice=k, role="measurement",
                       element=None)
        if name in elements:  # a state measured directly
            for k in (0, 1):
                g.add_edge(node(name, k), node(measurement_id(name, ssm.states), k), arc="intra")
    for a, b, d in s.edges(data=True):
        if roles[a] not in ("state", "input"):
            continue
        if roles.get(b) == "state" and d["temporal"]:
            g.add_edge(node(a, 0), node(b, 1), arc="temporal")
        elif b in outputs and not d["temporal"]:
            for k in (0, 1):
                g.add_edge(node(a, k), node(measurement_id(b, ssm.states), k), arc="intra")
    return g


def _faulty(ssm: StateSpaceModel, nominal: nx.DiGraph, parameter: str, kind: str) -> Dbn:
    g = nx.DiGraph(nominal)
    drifts = fault_kind(kind).drifts
    p = sym(parameter)
    d = f"D_{parameter}"
    delta = f"delta_{parameter}"
    for k in (0, 1):
        g.add_node(node(d, k), variable=d, slice=k, role="fault_indicator", element=None)
        g.add_node(node(delta, k), variable=delta, slice=k,
                   role=f"fault_{fault_kind(kind).magnitude}", element=None)
        g.add_edge(node(d, k), node(delta, k), arc="indicator")
    g.add_edge(node(d, 0), node(d, 1), arc="persistence")
    g.add_edge(node(delta, 0), node(delta, 1), arc="persistence")
    if not drifts:  # P + delta_P
        carrier = delta
    else:  # P itself drifts at the slope delta_P
        carrier = parameter
        for k in (0, 1):
            g.add_node(node(parameter, k), variable=parameter, slice=k, role="fault_parameter", element=None)
        g.add_edge(node(parameter, 0), node(parameter, 1), arc="persistence")
        g.add_edge(node(delta, 0), node(parameter, 1), arc="drift")
    for x, rhs in zip(ssm.states, ssm.rhs):
        if p in rhs.free_symbols:
            g.add_edge(node(carrier, 0), node(x, 1), arc="fault")
    noisy = noisy_sensor(ssm, parameter, kind)
    for y, expr in zip(ssm.outputs, fault_outputs(ssm, parameter, kind)):
        if p in expr.free_symbols or y == noisy:
            for k in (0, 1):
                m = node(measurement_id(y, ssm.states), k)
                if fault_kind(kind).replaces:  # the reading no longer depends on the plant
                    g.remove_edges_from([(u, m) for u in list(g.predecessors(m))])
                g.add_edge(node(carrier, k), m, arc="fault")
    return Dbn(f"{parameter}:{kind}", parameter, kind, nx.freeze(g))


def intermittent(d: Dbn) -> Dbn:
    """Faulty DBN ``d`` of a step fault as one that comes and goes
    (``PARAM:KIND:intermittent``): its indicator ``D_P`` is no longer
    persistent but switches between present and absent from slice to slice
    (a ``switching`` arc, with unknown rates), and is a parent of every node
    its magnitude ``delta_P`` reaches, the fault acting as ``D_P *
    delta_P`` (:mod:`bgc.diagnosis.intermittent`). KeyError for the nominal
    DBN or a kind that cannot come and go (a drift, a stuck reading or switch)."""
    if d.kind is None or d.parameter is None or not comes_and_goes(d.kind):
        raise KeyError(f"{d.name} is no step fault: only a step (abrupt, bias, gain, noise) comes and goes")
    g = nx.DiGraph(d.graph)
    indicator, delta = f"D_{d.parameter}", f"delta_{d.parameter}"
    g.edges[node(indicator, 0), node(indicator, 1)]["arc"] = "switching"
    for k in (0, 1):
        for child in d.graph.successors(node(delta, k)):
            if d.graph.edges[node(delta, k), child]["arc"] == "fault":
                g.add_edge(node(indicator, k), child, arc="fault")
    return Dbn(f"{d.name}:intermittent", d.parameter, d.kind, nx.freeze(g))
