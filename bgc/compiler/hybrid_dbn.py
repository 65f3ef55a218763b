"""The two-slice DBN of a model with modes, the mode a node of it
(:func:`across_modes`; ``bgc show dbn`` of such a model without ``--mode``).

Each mode has its own DBNs (:mod:`bgc.compiler.dbn` on the mode's
equations). Across the modes, the DBN is their union, with the mode as a
discrete node in both slices:

* ``mode@t -> mode@t+1`` (``persistence``): the mode stays unless a
  transition fires;
* ``mode@t -> x@t+1`` (``mode``) for every state whose equation is not the
  same in every mode (it differs, or the state is idle in some mode: the
  mode picks the equations the step integrates);
* ``mode@t+1 -> y@t+1`` (``mode``) for every measurement whose expression is
  not the same in every mode;
* what makes the mode change, into ``mode@t+1``: the variables an autonomous
  transition's guard reads (``guard``, from slice t+1: the guard is looked at
  on the state the step reaches), the ``mode`` input the data give for a
  controlled one (``command``), and the time in the mode, ``dwell`` (a node
  of role ``mode`` too), for a timed one (``timer``);
* ``mode@t+1 -> x@t+1`` (``reset``) for a state a transition resets;
* an arc of the modes' DBNs that holds in some modes only keeps the list of
  those modes (attribute ``modes``); one that holds in every mode has none;
* the zero sources an OFF junction leaves in a mode's bond graph
  (:func:`bgc.compiler.modes.mode_graph`) are not drawn: the mode stands for
  them.

A stuck switch's DBN (``J:stuck_on``, ``J:stuck_off``) is the nominal one
with the fault's indicator ``D_J_stuck_on`` (persisting from slice to
slice) and a ``fault`` arc from it into every state whose equation, and
every measurement whose expression, differs between a mode and the
configuration the plant runs in with the switch stuck in that mode
(:func:`bgc.compiler.modes.compile_stuck`), naming those modes. An
uncommanded change of a switch (``J:uncommanded_on``, ``J:uncommanded_off``)
has the same arcs and one more, ``mode@t+1 -> D@t+1`` (``release``): a mode
that asks for the switch where the fault put it clears the indicator (the
controller's next command of the switch ends the fault).
"""

from __future__ import annotations

import functools

import networkx as nx
import sympy

from ..ir import SWITCH_FAULTS, Dbn, StuckSwitch, sym
from .dbn import measurement_id, node
from .modes import zero_sources

#: The mode's node, and the time in the mode (a timed transition).
MODE, DWELL = "mode", "dwell"


def across_modes(model, modes: tuple, name: str = "nominal") -> Dbn:
    """The DBN ``name`` (``nominal``, ``PARAM:KIND`` as
    :meth:`bgc.ir.DbnModel.get` takes it, or a switch's ``J:stuck_on``,
    ``J:stuck_off``, ``J:uncommanded_on``, ``J:uncommanded_off``) of the model with modes ``model`` across its compiled
    ``modes`` (:class:`bgc.compiler.modes.ModeModel`), the mode a node
    (module docstring). Raises KeyError for a name no mode has."""
    fault = stuck_switch(model, name)
    if fault is not None:
        return _stuck(model, modes, fault)
    dbns = [m.dbn.get(name) for m in modes]
    g = nx.DiGraph()
    held: dict[tuple[str, str], list[str]] = {}
    for m, d in zip(modes, dbns):
        # the zero sources an OFF junction leaves (mode_graph) are the mode's doing: the mode node stands for them
        zero = set(zero_sources(m.graph))
        kept = {n for n, attrs in d.graph.nodes(data=True) if attrs.get("element") not in zero}
        for n in kept:
            if n not in g:
                g.add_node(n, **d.graph.nodes[n])
        for a, b, arc in d.graph.edges(data="arc"):
            if a in kept and b in kept:
                g.add_edge(a, b, arc=arc)
                held.setdefault((a, b), []).append(m.name)
    every = [m.name for m in modes]
    for (a, b), names in held.items():
        if names != every:
            g.edges[a, b]["modes"] = ",".join(names)
    for k in (0, 1):
        g.add_node(node(MODE, k), variable=MODE, slice=k, role="mode", element=None)
    g.add_edge(node(MODE, 0), node(MODE, 1), arc="persistence")
    states = sorted({x for m in modes for x in m.equations.states})
    for x in states:
        if len({_text(_equation(m.equations, x)) for m in modes}) > 1:
            g.add_edge(node(MODE, 0), node(x, 1), arc="mode")
    first = modes[0].equations
    for i, y in enumerate(first.outputs):
        if len({_text(_output(m.equations, i)) for m in modes}) > 1:
            g.add_edge(node(MODE, 1), node(measurement_id(y, tuple(states)), 1), arc="mode")
    by_name = {m.name: m for m in modes}
    for t in model.modes.transitions:
        if t.guard is not None:
            s = by_name[t.source].equations
            resolve = {sym(v): e for v, e in s.variables}
            for v in sorted({v.name for side in (t.guard.lhs, t.guard.rhs)
                             for v in sympy.sympify(side).xreplace(resolve).free_symbols}):
                if v in states or node(v, 1) in g:
                    g.add_edge(node(v, 1), node(MODE, 1), arc="guard")
        elif t.after is not None:
            for k in (0, 1):
                g.add_node(node(DWELL, k), variable=DWELL, slice=k, role="mode", element=None)
            g.add_edge(node(DWELL, 0), node(DWELL, 1), arc="persistence")
            g.add_edge(node(MODE, 0), node(DWELL, 1), arc="timer")
            g.add_edge(node(DWELL, 1), node(MODE, 1), arc="timer")
        else:
            for k in (0, 1):
                g.add_node(node("mode_input", k), variable="mode (data)", slice=k, role="input", element=None)
            g.add_edge(node("mode_input", 1), node(MODE, 1), arc="command")
        for state, _ in t.resets:
            g.add_edge(node(MODE, 1), node(state, 1), arc="reset")
    d0 = dbns[0]
    return Dbn(d0.name, d0.parameter, d0.kind, nx.freeze(g))


def stuck_switch(model, name: str) -> StuckSwitch | None:
    """The switch's fault ``name`` names (``K:stuck_off``,
    ``K:uncommanded_on``): the model's own declaration, or any switched
    junction of it with any of the kinds (a plant may fail in ways its model
    does not list); None for another name."""
    junction, _, kind = name.partition(":")
    if kind not in SWITCH_FAULTS or model.modes is None or junction not in model.modes.switches:
        return None
    return model.modes.stuck_fault(name) or StuckSwitch(junction, kind, 0.01, None)


def _stuck(model, modes: tuple, fault: StuckSwitch) -> Dbn:
    from .modes import compile_stuck

    g = nx.DiGraph(across_modes(model, modes).graph)
    stuck = compile_stuck(model, modes, fault)
    indicator = f"D_{fault.junction}_{fault.kind}"
    for k in (0, 1):
        g.add_node(node(indicator, k), variable=indicator, slice=k, role="fault_indicator", element=fault.junction)
    g.add_edge(node(indicator, 0), node(indicator, 1), arc="persistence")
    if fault.releases:  # a mode asking for the switch where the fault put it ends the fault
        g.add_edge(node(MODE, 1), node(indicator, 1), arc="release",
                   modes=",".join(fault.releasing(model.modes.modes)))
    states = tuple(sorted({x for m in (*modes, *stuck.configs) for x in m.equations.states}))
    changed: dict[tuple[str, str], list[str]] = {}
    for m, config in zip(modes, stuck.configs):
        a, b = m.equations, config.equations
        for x in states:
            if _text(_equation(a, x)) != _text(_equation(b, x)):
                changed.setdefault((node(indicator, 0), node(x, 1)), []).append(m.name)
        for i, y in enumerate(a.outputs):
            if _text(_output(a, i)) != _text(_output(b, i)):
                changed.setdefault((node(indicator, 1), node(measurement_id(y, states), 1)), []).append(m.name)
    for (a, b), names in changed.items():
        variable = b.rsplit("@", 1)[0]
        for k in (0, 1):  # a state only the stuck configurations have
            if node(variable, k) not in g:
                g.add_node(node(variable, k), variable=variable, slice=k, role="state", element=None)
        g.add_edge(a, b, arc="fault", **({"modes": ",".join(names)} if len(names) < len(modes) else {}))
    return Dbn(fault.name, fault.junction, fault.kind, nx.freeze(g))


def _equation(ssm, x: str):
    """A state's derivative in one mode (None: idle there)."""
    return ssm.rhs[ssm.states.index(x)] if x in ssm.states else None


def _output(ssm, i: int):
    return ssm.output_exprs[i]


@functools.lru_cache(maxsize=512)
def _text(expr) -> str:
    """An equation's canonical text, to compare modes' (None: the state is idle), simplified once per
    expression (a stuck switch's DBN compares the modes' equations again)."""
    return "idle" if expr is None else sympy.srepr(sympy.simplify(sympy.sympify(expr)))
