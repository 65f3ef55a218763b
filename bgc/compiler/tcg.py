"""Stage 4: :class:`~bgc.ir.CausalBondGraph` -> :class:`~bgc.ir.TemporalCausalGraph`.

The temporal causal graph (TCG; Mosterman and Biswas, 1999; thesis section
II.3.2) is the signal-flow graph of the causal bond graph. Its nodes are the
effort and flow variables ``e_i``, ``f_i`` (plus one node per named
measurement); an edge ``a -> b`` says that ``a`` appears in the causal relation
that computes ``b``. Edge labels follow the thesis:

* ``=`` junction equalities, ``+1``/``-1`` junction sums;
* ``R`` and ``1/R`` for resistors by causality, ``law`` for nonlinear ones;
* ``dt/C`` and ``dt/I`` for storage in integral causality (temporal edges);
* ``m``, ``1/m`` for TF and GY moduli;
* ``signal`` for the signal links of modulated elements.

Every edge records the component parameters it involves and the qualitative
effect of an increase of each (the sign of the partial derivative of the
relation, variables taken positive), which is what TRANSCEND-style fault
isolation propagates. Every node records its defining relation as a sympy
expression of its predecessors (``definition``; for states ``derivative``), so
the equation stage works from the TCG alone.

The simplified TCG (thesis III.3, Roychoudhury's step ii) keeps only state,
input and measured variables: ``a -> b`` when a path from ``a`` reaches ``b``
through other variables only; it is temporal when the path integrates.
"""

from __future__ import annotations

from dataclasses import dataclass

import networkx as nx
import numpy as np
import sympy

from ..errors import EquationError
from ..ir import CausalBondGraph, Element, TemporalCausalGraph, TcgEdge, effort, flow, sym, var_key
from ..kinds import element_kind
from .expressions import FUNCTIONS


@dataclass(slots=True)
class _Relation:
    """``target = expr`` (or ``d target/dt = expr`` when ``derivative``)."""

    target: str
    expr: sympy.Expr
    relation: str
    element: str
    labels: dict[str, str]
    derivative: bool = False
    #: Known qualitative signs for linear relations: (d target/d source, d target/d parameter);
    #: None: computed from the expression.
    signs: tuple[int, int] | None = None
    #: A storage element in derivative causality: ``target = parameter * d(variable)/dt``
    #: (``expr`` is ``parameter * variable``), the variable the rest of the graph imposes.
    differentiates: str | None = None


def build(cbg: CausalBondGraph) -> TemporalCausalGraph:
    """Build the TCG and its simplified form from a causal bond graph.

    Raises
    ------
    EquationError
        A nonlinear law that cannot be put in the causal form SCAP chose.
        (A storage element in derivative causality is kept as a relation
        that differentiates what the graph imposes on it: the equations
        stage resolves it when that is constant, and refuses it otherwise.)
    """
    model = cbg.model
    params = {p.name for p in model.parameters}
    inputs = {i.name for i in model.inputs}
    values = model.parameter_values()
    rels = _relations(cbg)
    variables = {effort(b.number) for b in model.bonds} | {flow(b.number) for b in model.bonds}

    g = nx.DiGraph()
    states = {s.state: s for s in cbg.states}
    for b in model.bonds:
        for name, kind in ((effort(b.number), "effort"), (flow(b.number), "flow")):
            g.add_node(name, kind=kind, bond=b.number, role="algebraic", measured=False)
    by_target = {}
    for r in rels:
        node = g.nodes[r.target]
        by_target[r.target] = r
        node["element"] = r.element
        if r.derivative:
            node["role"] = "state"
            node["derivative"] = r.expr
            node["definition"] = sym(r.target)
        else:
            node["definition"] = r.expr
        if r.differentiates:
            node["differentiates"] = r.differentiates
        if r.relation == "source":
            used = {s.name for s in r.expr.free_symbols}
            if not used & variables:
                node["role"] = "input"
            node["inputs"] = tuple(sorted(used & inputs))
    point = _operating_point(cbg, rels, values)
    for r in rels:
        pnames = tuple(sorted(p.name for p in r.expr.free_symbols if p.name in params))
        for s in sorted(r.expr.free_symbols, key=lambda s: s.name):
            if s.name not in variables:
                continue
            label = r.labels.get(s.name, "signal")
            if r.signs is not None and label != "signal":
                sign = r.signs[0] if r.relation != "sum" else (1 if label == "+1" else -1)
                source_sign = 1 if point.get(s.name, 1.0) >= 0 else -1
                effects = tuple(r.signs[1] * source_sign for _ in pnames)
            else:
                sign = _sign(sympy.diff(r.expr, s), point)
                effects = tuple(_sign(sympy.diff(r.expr, sym(p)), point) for p in pnames)
            g.add_edge(s.name, r.target, label=label,
                       relation=r.relation if s.name in r.labels else "signal",
                       element=r.element, parameters=pnames, effects=effects, sign=sign,
                       temporal=r.derivative)
    for m in model.measurements:
        used = sorted(s.name for s in m.expr.free_symbols if s.name in variables)
        if m.name in variables and m.expr == sym(m.name):
            g.nodes[m.name]["measured"] = True
            g.nodes[m.name]["measurement"] = m.name
            continue
        pnames = tuple(sorted(p.name for p in m.expr.free_symbols if p.name in params))
        g.add_node(m.name, kind="measurement", bond=None, role="measurement", measured=True,
                   measurement=m.name, definition=m.expr, element=None)
        for v in used:
            bare = m.expr == sym(v)
            g.add_edge(v, m.name, label="=" if bare else "signal", relation="measurement", element=None,
                       parameters=pnames, effects=tuple(_sign(sympy.diff(m.expr, sym(p)), point) for p in pnames),
                       sign=_sign(sympy.diff(m.expr, sym(v)), point), temporal=False)
    _node_effects(g, params, point)
    simplified = _simplify(g, states)
    edges = tuple(TcgEdge(u, v, d["label"], d["relation"], d["element"], d["parameters"], d["effects"],
                          d["sign"], d["temporal"]) for u, v, d in sorted(g.edges(data=True), key=_edge_key))
    return TemporalCausalGraph(cbg, nx.freeze(g), nx.freeze(simplified), edges)


def _node_effects(g: nx.DiGraph, params: set[str], point: dict[str, float]) -> None:
    """Give every node the qualitative effect of each parameter of its relation
    (``effects``: sorted (parameter, sign) pairs; the derivative's for a state):
    the sign its in-edges carry, or, for a relation no edge carries a parameter
    on (a source's value), the sign of the partial derivative at the operating
    point. This is where a fault enters the TCG (TRANSCEND's forward
    propagation starts here)."""
    for v, d in g.nodes(data=True):
        expr = d.get("derivative", d.get("definition"))
        if expr is None:
            continue
        effects: dict[str, int | None] = {}
        for _, _, e in g.in_edges(v, data=True):
            effects.update(zip(e["parameters"], e["effects"]))
        for p in sorted(s.name for s in expr.free_symbols if s.name in params and s.name not in effects):
            effects[p] = _sign(sympy.diff(expr, sym(p)), point)
        d["effects"] = tuple(sorted(effects.items()))


def _edge_key(e: tuple) -> tuple:
    return (var_key(e[0]), var_key(e[1]))


def _sign(d: sympy.Expr, point: dict[str, float]) -> int | None:
    """Sign of a partial derivative at the operating point (None: not a number there)."""
    sub = {x: point.get(x.name, 1.0) for x in d.free_symbols}
    try:
        v = float(d.xreplace(sub))
    except (TypeError, ValueError):
        return None
    if v != v:
        return None
    return 0 if v == 0 else (1 if v > 0 else -1)


def _operating_point(cbg: CausalBondGraph, rels: list[_Relation], values: dict[str, float]) -> dict[str, float]:
    """Values of parameters, inputs (at t = 0) and every variable at the initial
    state, for the signs of the qualitative effects. Variables that are zero,
    in an algebraic loop or not finite are left out (read as +1, TRANSCEND's
    convention for magnitudes)."""
    model = cbg.model
    point = dict(values)
    for i in model.inputs:
        point[i.name] = i.signal.value
    for st in cbg.states:
        point[st.state] = model.element(st.element).initial or 0.0
    algebraic = {r.target: r for r in rels if not r.derivative}
    deps = nx.DiGraph()
    deps.add_nodes_from(algebraic)
    for t, r in algebraic.items():
        for x in r.expr.free_symbols:
            if x.name in algebraic:
                deps.add_edge(x.name, t)
    known = dict(point)
    for t in _topo(deps):
        expr = algebraic[t].expr
        if all(x.name in known for x in expr.free_symbols):
            args = {x: known[x.name] for x in expr.free_symbols}
            try:
                v = float(expr.xreplace(args))
            except (TypeError, ValueError, ZeroDivisionError):
                continue
            scale = max((abs(a) for a in args.values()), default=1.0)
            if v == v and abs(v) != float("inf"):
                # a value lost in the rounding of its inputs is zero, not a sign
                known[t] = 0.0 if abs(v) <= 1e-9 * max(scale, 1.0) else v
    return {k: v for k, v in known.items() if v != 0.0}


def _topo(g: nx.DiGraph) -> list[str]:
    """Nodes in dependency order (the members of a cycle, i.e. an algebraic loop,
    together; their values stay unknown)."""
    order: list[str] = []
    cond = nx.condensation(g)
    for c in nx.lexicographical_topological_sort(cond, key=str):
        order.extend(sorted(cond.nodes[c]["members"]))
    return order


def _simplify(g: nx.DiGraph, states: dict) -> nx.DiGraph:
    """Edges between kept variables (states, inputs, measured): ``a -> b`` when a
    path leads from ``a`` to ``b`` without passing through a state or an input
    (a measured algebraic variable is recorded and passed through). The edge is
    temporal when the path ends with an integrating edge, and carries the
    parameters of every edge on such paths."""
    keep = [n for n, d in g.nodes(data=True) if d["role"] in ("state", "input") or d["measured"]]
    keep_set = set(keep)
    barrier = {n for n in keep if g.nodes[n]["role"] in ("state", "input")}
    s = nx.DiGraph()
    for n in keep:
        s.add_node(n, **{k: v for k, v in g.nodes[n].items() if k in ("kind", "role", "measured", "bond")})
    for a in keep:
        # Nodes reachable from a through non-barrier nodes (a itself excluded).
        inner = {a}
        stack = [a]
        while stack:
            node = stack.pop()
            for nxt in g.successors(node):
                if nxt not in inner and nxt not in barrier:
                    inner.add(nxt)
                    stack.append(nxt)
        targets = {v for u in inner for v in g.successors(u) if v in keep_set and v != a}
        for b in targets:
            # Nodes of inner that reach b (backwards within inner).
            back = {b}
            stack = [b]
            while stack:
                node = stack.pop()
                for prev in g.predecessors(node):
                    if prev in inner and prev not in back:
                        back.add(prev)
                        if prev != a:  # a path leaves a once and never passes it again
                            stack.append(prev)
            params: set[str] = set()
            temporal = False
            for u in back:
                if u == b:
                    continue
                for v in g.successors(u):
                    if v in back and v != a:
                        d = g.edges[u, v]
                        params.update(d["parameters"])
                        temporal = temporal or (v == b and d["temporal"])
            s.add_edge(a, b, temporal=temporal, parameters=tuple(sorted(params)))
    return s


def _relations(cbg: CausalBondGraph) -> list[_Relation]:
    model = cbg.model
    ports: dict[str, list] = {el.name: [] for el in model.elements}
    for b in model.bonds:
        ports[b.tail].append(b)
        ports[b.head].append(b)
    by = {c.bond: c.effort_by for c in cbg.bonds}
    out: list[_Relation] = []
    for el in model.elements:
        bonds = ports[el.name]
        kind = element_kind(el.kind)
        if kind.role == "junction":
            out.extend(_junction(el, bonds, by))
        elif kind.role == "source":
            b = bonds[0].number
            out.append(_Relation(effort(b) if kind.imposes == "effort" else flow(b), el.source, "source", el.name, {}))
        elif kind.role == "storage":
            out.append(_storage(el, bonds[0].number, by))
        elif kind.role == "resistor":
            out.append(_resistor(el, bonds[0].number, by, model.parameter_values()))
        else:
            out.extend(_two_port(el, bonds, by))
    return out


def _pname(el: Element) -> str:
    p = el.parameter
    return p.name if isinstance(p, sympy.Symbol) else el.name


def _junction(el: Element, bonds: list, by: dict[int, str]) -> list[_Relation]:
    name = el.name
    sign = {b.number: (1 if b.head == name else -1) for b in bonds}
    if element_kind(el.kind).common == "effort":
        det = next(b.number for b in bonds if by[b.number] != name)
        same, summed = effort, flow
    else:
        det = next(b.number for b in bonds if by[b.number] == name)
        same, summed = flow, effort
    rels = []
    others = [b.number for b in bonds if b.number != det]
    for b in others:
        rels.append(_Relation(same(b), sym(same(det)), "equality", name, {same(det): "="}, signs=(1, 0)))
    terms = {summed(b): -sign[b] * sign[det] for b in others}
    expr = sympy.Add(*(c * sym(v) for v, c in terms.items()))
    rels.append(_Relation(summed(det), expr, "sum", name, {v: ("+1" if c > 0 else "-1") for v, c in terms.items()},
                          signs=(1, 0)))
    return rels


def _storage(el: Element, b: int, by: dict[int, str]) -> _Relation:
    own = element_kind(el.kind).imposes == "effort"  # C: integrates its flow into its effort
    integral = (by[b] == el.name) == own
    p = _pname(el)
    if not integral:  # C: f = C de/dt of the effort imposed on it; I: e = I df/dt of the flow
        imposed, target = (effort(b), flow(b)) if own else (flow(b), effort(b))
        return _Relation(target, el.parameter * sym(imposed), "derivative", el.name, {imposed: f"{p} d/dt"},
                         differentiates=imposed)
    signs = (1, -1) if isinstance(el.parameter, sympy.Symbol) else None
    if own:
        return _Relation(effort(b), sym(flow(b)) / el.parameter, "integral", el.name, {flow(b): f"dt/{p}"}, True, signs)
    return _Relation(flow(b), sym(effort(b)) / el.parameter, "integral", el.name, {effort(b): f"dt/{p}"}, True, signs)


def _resistor(el: Element, b: int, by: dict[int, str], values: dict[str, float]) -> _Relation:
    e, f = effort(b), flow(b)
    gives_effort = by[b] == el.name
    target, source = (e, f) if gives_effort else (f, e)
    if el.law is None:
        p = _pname(el)
        plain = isinstance(el.parameter, sympy.Symbol)
        if gives_effort:
            return _Relation(e, el.parameter * sym(f), "resistive", el.name, {f: p}, signs=(1, 1) if plain else None)
        return _Relation(f, sym(e) / el.parameter, "resistive", el.name, {e: f"1/{p}"},
                         signs=(1, -1) if plain else None)
    law = el.law
    if law.output == target:
        expr = law.expr
    else:
        expr = _invert(el, law.expr, source, target, values)
    return _Relation(target, expr, "law", el.name, {source: "law"})


#: Values of the wanted variable at which an inverse is checked (both signs, several scales).
_INVERSE_SAMPLES = (-7.0, -2.0, -0.5, -0.05, 0.05, 0.5, 2.0, 7.0)


def _invert(el: Element, expr: sympy.Expr, given: str, wanted: str, values: dict[str, float]) -> sympy.Expr:
    """Solve ``given = expr(wanted)`` for ``wanted`` (a law written in the other causality).

    sympy's candidates are checked numerically, not trusted: at the nominal
    parameter values (other variables of an MR law at 0.7), a candidate must
    give back every sample of the wanted variable from the law's value there,
    as a real number, and be printable as NumPy code. Exactly one must pass
    (sympy offers e.g. f**2/a**2 for the orifice f = a*sqrt(|e|)*sign(e), which
    loses the sign, or the complex roots of a cubic).
    """
    fix = f"write the law as '{wanted[0]} = <expression of {given[0]}>'"
    head = f"law of {el.name} ({el.law.text}) must be inverted for the causality SCAP chose"
    w = sympy.Dummy(wanted)
    try:
        candidates = sympy.solve(sympy.Eq(sym(given), expr.xreplace({sym(wanted): w})), w)
    except (NotImplementedError, ValueError, TypeError):
        raise EquationError(f"{head}, and bgc cannot solve it for {wanted[0]}", el.law.loc, fix) from None
    point = {s: values.get(s.name, 0.7) for s in expr.free_symbols if s.name not in (wanted, given)}
    checked = []
    for c in candidates:
        good = 0
        for v in _INVERSE_SAMPLES:
            try:
                g = complex(sympy.N(expr.xreplace({**point, sym(wanted): v})))
                if not np.isfinite(g) or abs(g.imag) > 1e-12 * max(1.0, abs(g.real)):
                    continue  # the law is not defined there
                back = complex(sympy.N(c.xreplace({**point, sym(given): g.real})))
            except (TypeError, ValueError, ZeroDivisionError):
                back = complex("nan")
            if not (np.isfinite(back) and abs(back.imag) <= 1e-9 * max(1.0, abs(back.real))
                    and abs(back.real - v) <= 1e-7 * max(1.0, abs(v))):
                break
            good += 1
        else:
            if good:
                checked.append(c)
    if len(checked) != 1:
        found = f"sympy gives {len(candidates)} solution(s) for {wanted[0]}, {len(checked)} of them a real inverse"
        raise EquationError(f"{head}, and {found}", el.law.loc, fix)
    if not _evaluable(checked[0]):
        raise EquationError(f"{head}, and its inverse {sympy.sstr(checked[0])[:50]} uses a function bgc cannot "
                            "evaluate", el.law.loc, fix) from None
    return checked[0]


#: The sympy functions generated code evaluates: those model expressions may call.
_EVALUABLE = frozenset(f for f, _ in FUNCTIONS.values())


def _evaluable(expr: sympy.Expr) -> bool:
    """Whether ``expr`` uses only arithmetic and the functions of model expressions
    (sympy's inverse of a law may bring LambertW or Piecewise)."""
    if expr.has(sympy.Piecewise, sympy.I, sympy.zoo, sympy.nan, sympy.oo):
        return False
    return all(f.func in _EVALUABLE for f in expr.atoms(sympy.Function))


def _two_port(el: Element, bonds: list, by: dict[int, str]) -> list[_Relation]:
    bin_ = next(b.number for b in bonds if b.head == el.name)
    bout = next(b.number for b in bonds if b.tail == el.name)
    m = el.parameter
    p = _pname(el)
    if element_kind(el.kind).two_port == "transformer":
        if by[bin_] == el.name:   # TF imposes e_in: e_in = m e_out, f_out = m f_in
            return [_Relation(effort(bin_), m * sym(effort(bout)), "transformer", el.name, {effort(bout): p}),
                    _Relation(flow(bout), m * sym(flow(bin_)), "transformer", el.name, {flow(bin_): p})]
        return [_Relation(effort(bout), sym(effort(bin_)) / m, "transformer", el.name, {effort(bin_): f"1/{p}"}),
                _Relation(flow(bin_), sym(flow(bout)) / m, "transformer", el.name, {flow(bout): f"1/{p}"})]
    if by[bin_] == el.name:       # GY imposes both efforts: e_in = r f_out, e_out = r f_in
        return [_Relation(effort(bin_), m * sym(flow(bout)), "gyrator", el.name, {flow(bout): p}),
                _Relation(effort(bout), m * sym(flow(bin_)), "gyrator", el.name, {flow(bin_): p})]
    return [_Relation(flow(bout), sym(effort(bin_)) / m, "gyrator", el.name, {effort(bin_): f"1/{p}"}),
            _Relation(flow(bin_), sym(effort(bout)) / m, "gyrator", el.name, {effort(bout): f"1/{p}"})]
