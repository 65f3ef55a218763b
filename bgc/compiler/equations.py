"""Stage 5: :class:`~bgc.ir.TemporalCausalGraph` -> :class:`~bgc.ir.StateSpaceModel`.

Derives ``dx/dt = f(x, u, theta)`` and ``y = h(x, u, theta)`` with sympy from the
causal relations the TCG carries (each node's ``definition``). States are the
co-energy variables of the storage elements in integral causality (``e`` of a
C, ``f`` of an I), as in the thesis; parameters stay symbols so fault models can
replace them.

The algebraic relations are ordered by causality (a topological order of the
TCG without its integrating edges) and substituted in that order, so the cost
grows with the size of the graph, not with a generic symbolic solve. A cycle of
algebraic relations (an algebraic loop, closed by a resistor SCAP assigned
arbitrarily) is solved symbolically: a linear loop by Gaussian elimination on
its few unknowns, a nonlinear one by ``sympy.solve`` when that gives a unique
solution; otherwise a located error names the loop.

The expressions solved here never come from model text directly: they are built
by the safe parser (:mod:`bgc.expressions`) and by the causal relations.
"""

from __future__ import annotations

import networkx as nx
import sympy
from sympy.solvers.solveset import NonlinearError

from ..errors import EquationError
from ..ir import StateSpaceModel, TemporalCausalGraph, sym, var_key
from ..kinds import fault_kind


def derive(tcg: TemporalCausalGraph) -> StateSpaceModel:
    """Derive the state and measurement equations (a storage element in
    derivative causality whose imposed variable moves with the states is
    merged with the storages that fix it: :func:`_derivative_causality`).

    Raises
    ------
    EquationError
        An algebraic loop without a unique symbolic solution; a storage
        element in derivative causality that cannot be resolved.
    """
    g = tcg.graph
    model = tcg.model
    states = tuple(sorted((n for n, d in g.nodes(data=True) if d["role"] == "state"), key=var_key))
    variables = [n for n, d in g.nodes(data=True) if d["kind"] != "measurement"]
    state_set = set(states)
    algebraic = nx.DiGraph()
    algebraic.add_nodes_from(v for v in variables if v not in state_set)
    for u, v, d in g.edges(data=True):
        if not d["temporal"] and v in algebraic and u in algebraic:
            algebraic.add_edge(u, v)

    signals = state_set | set(variables) | {i.name for i in model.inputs}  # what varies in time
    resolved: dict[sympy.Symbol, sympy.Expr] = {sym(x): sym(x) for x in states}
    rates: dict[str, sympy.Symbol] = {}  # per state, the symbol of its rate, once a derivative causality needs it
    loops: list[tuple[str, ...]] = []
    condensed = nx.condensation(algebraic)
    order = nx.lexicographical_topological_sort(
        condensed, key=lambda c: var_key(min(condensed.nodes[c]["members"], key=var_key)))
    for comp in order:
        members = sorted(condensed.nodes[comp]["members"], key=var_key)
        if len(members) == 1 and not algebraic.has_edge(members[0], members[0]):
            v = members[0]
            if "definition" not in g.nodes[v]:
                raise EquationError(f"variable {v} is computed by no element", model.source,
                                    "check the causality of the bonds around it")
            resolved[sym(v)] = _substitute(g.nodes[v]["definition"], resolved)
            if "differentiates" in g.nodes[v]:
                resolved[sym(v)] = _derivative_causality(model, g, v, resolved, signals, states, rates)
            continue
        loops.append(tuple(members))
        resolved.update(_solve_loop(tcg, members, resolved))
        for v in members:  # a storage in derivative causality inside the loop: its derivative is not taken there
            if "differentiates" in g.nodes[v]:
                imposed = resolved[sym(g.nodes[v]["differentiates"])]
                if {x.name for x in imposed.free_symbols} & signals:
                    el = model.element(g.nodes[v]["element"])
                    raise EquationError(f"{el.kind} element {el.name} is in derivative causality inside an "
                                        f"algebraic loop ({', '.join(members)}); bgc cannot derive equations "
                                        "for it yet", el.loc,
                                        "merge it with the storage element that fixes it, or add a resistor in between")
                resolved[sym(v)] = sympy.Integer(0)  # what it follows is constant: idle

    rhs = tuple(_substitute(g.nodes[x]["derivative"], resolved) for x in states)
    outputs = []
    for m in model.measurements:
        outputs.append(_substitute(m.expr, resolved))
    if rates:  # derivative causality: the states' rates appear on both sides, solve for them
        solved = _solve_rates(model, g, states, rhs, rates)
        rhs = tuple(solved[x] for x in states)
        into = {rates[x]: solved[x] for x in states if x in rates}
        outputs = [sympy.factor_terms(sympy.cancel(e.xreplace(into))) if e.free_symbols & set(into) else e
                   for e in outputs]
        resolved = {k: (e.xreplace(into) if e.free_symbols & set(into) else e) for k, e in resolved.items()}
    storage = {s.state: s.element for s in tcg.causal.states}
    initial = tuple(model.element(storage[x]).initial or 0.0 for x in states)
    bond_vars = [(v, resolved[sym(v)]) for v in variables]
    added, rhs, outputs, bond_vars = _fault_symbols(model, rhs, outputs, bond_vars)
    bond_vars = tuple(sorted(bond_vars, key=lambda p: var_key(p[0])))
    return StateSpaceModel(
        tcg=tcg,
        states=states,
        state_elements=tuple(storage[x] for x in states),
        inputs=tuple(i.name for i in model.inputs),
        parameters=tuple(p.name for p in model.parameters) + tuple(name for name, _ in added),
        parameter_values=tuple(p.value for p in model.parameters) + tuple(value for _, value in added),
        outputs=tuple(m.name for m in model.measurements),
        rhs=rhs,
        output_exprs=tuple(outputs),
        variables=bond_vars,
        initial=initial,
        loops=tuple(loops),
    )


def _derivative_causality(model, g, v: str, resolved: dict, signals: set[str], states: tuple[str, ...],
                          rates: dict[str, sympy.Symbol]) -> sympy.Expr:
    """The variable ``v`` a storage element in derivative causality gives:
    the time derivative of its parameter times what the graph imposes on it
    (C: f = d(C e)/dt; I: e = d(I f)/dt).

    - 0 when the imposed variable is constant in time (a switch's zero, a
      source of a constant: the element is idle);
    - when it is a function of the states alone (two capacitors on one
      0-junction, two inertias on one 1-junction: storages joined with
      nothing between them), the chain rule in the states' rates, each a
      symbol of ``rates`` (:func:`_solve_rates` solves for them once every
      state's equation is written): the storages are merged;
    - refused, the element named, when it moves with an input (its
      derivative would need the input's) or with a rate already (a second
      derivative).

    In a mode of a hybrid bond graph (a valve that joins two tanks) the
    merge holds while the mode lasts; what the joined storages hold at the
    switch (the volume shared out: a reset of the transition) is the
    model's to say (docs/format.md section 10).

    ``signals``: the names that vary in time (states, bond variables,
    inputs)."""
    imposed = g.nodes[v]["differentiates"]
    expr = resolved[sym(v)]  # the parameter times the imposed variable, in states, inputs and parameters
    names = {s.name for s in expr.free_symbols}
    if not names & signals:
        return sympy.Integer(0)
    el = model.element(g.nodes[v]["element"])
    moving_inputs = sorted(names & {i.name for i in model.inputs})
    if moving_inputs or names & {r.name for r in rates.values()}:
        why = (f"it moves with input {moving_inputs[0]}, whose derivative bgc does not take" if moving_inputs
               else "its imposed variable moves with another derivative")
        raise EquationError(f"{el.kind} element {el.name} is in derivative causality ({imposed} is imposed on it by "
                            f"the rest of the graph and varies): {why}", el.loc,
                            "merge it with the storage element that fixes it, or add a resistor in between")
    out = sympy.Integer(0)
    for x in states:
        slope = sympy.diff(expr, sym(x))
        if slope != 0:
            rate = rates.setdefault(x, sympy.Symbol(f"_rate_{x}"))
            out += slope * rate
    return out


def _solve_rates(model, g, states: tuple[str, ...], rhs: tuple, rates: dict[str, sympy.Symbol]) -> dict[str, sympy.Expr]:
    """The states' rates from ``rhs``, where a derivative causality put
    some of them on the right (``dx/dt = f(x, u, dx/dt)``, linear in the
    rates): the linear system solved symbolically; a located error when it
    is not linear or has no unique solution."""
    unknowns = [rates.get(x, sympy.Symbol(f"_rate_{x}")) for x in states]
    eqs = [u - e for u, e in zip(unknowns, rhs)]
    joined = sorted(g.nodes[v]["element"] for v, d in g.nodes(data=True) if d.get("differentiates"))
    where = f"the storage elements in derivative causality ({', '.join(joined)}) and the states they follow"
    try:
        A, b = sympy.linear_eq_to_matrix(eqs, unknowns)
    except NonlinearError:
        raise EquationError(f"{where}: their equations are not linear in the states' rates", model.source,
                            "add a resistor between the storage elements") from None
    # over the field of fractions of the symbols (sympy's generic det and simplify stall on a few merged storages)
    from sympy.polys.matrices import DomainMatrix

    n = len(unknowns)
    both = DomainMatrix.from_Matrix(A.row_join(b)).to_field()  # one domain for both sides
    dA, db = both.extract(list(range(n)), list(range(n))), both.extract(list(range(n)), [n])
    if dA.det() == dA.domain.zero:
        raise EquationError(f"{where}: the states' rates have no unique solution", model.source,
                            "add a resistor between the storage elements")
    sol = dA.lu_solve(db).to_Matrix()
    return {x: sympy.factor_terms(sympy.cancel(sol[i])) for i, x in enumerate(states)}


def _fault_symbols(model, rhs, outputs, bond_vars):
    """Add the symbols of the model's sensor and actuator faults (sorted by
    name, after the model's parameters, each at its nominal value): a sensor's
    offset is added to its reading; an input ``u`` with an offset or a gain
    becomes ``gain * u + offset`` wherever the plant sees it (the recorded
    input stays the command); a stuck sensor's value enters no equation here
    (its fault model replaces the reading by it: codegen, dbn), nor does a
    noise fault's factor (it scales the sensor's noise std, not its reading:
    the fault model's ``measurement_std``). Nothing changes for a model
    without them."""
    added = sorted({(f.parameter, fault_kind(f.kinds[0]).nominal) for f in model.faults if f.target != "parameter"})
    if not added:
        return (), rhs, outputs, bond_vars
    names = {name for name, _ in added}
    delivered = {}
    for i in model.inputs:
        gain, offset = f"{i.name}_gain", f"{i.name}_offset"
        if gain in names or offset in names:
            u = sym(i.name)
            delivered[u] = (sym(gain) * u if gain in names else u) + (sym(offset) if offset in names else 0)
    rhs = tuple(e.xreplace(delivered) for e in rhs)
    outputs = [e.xreplace(delivered) for e in outputs]
    bond_vars = [(v, e.xreplace(delivered)) for v, e in bond_vars]
    offsets = {f.subject: sym(f.parameter) for f in model.faults
               if f.target == "sensor" and fault_kind(f.kinds[0]).suffix == "offset"}
    outputs = [e + offsets[m.name] if m.name in offsets else e for m, e in zip(model.measurements, outputs)]
    return tuple(added), rhs, outputs, bond_vars


def _substitute(expr: sympy.Expr, resolved: dict[sympy.Symbol, sympy.Expr]) -> sympy.Expr:
    sub = {s: resolved[s] for s in expr.free_symbols if s in resolved and resolved[s] is not s}
    return expr.xreplace(sub) if sub else expr


def _solve_loop(tcg: TemporalCausalGraph, members: list[str],
                resolved: dict[sympy.Symbol, sympy.Expr]) -> dict[sympy.Symbol, sympy.Expr]:
    g = tcg.graph
    unknowns = [sym(v) for v in members]
    eqs = [sym(v) - _substitute(g.nodes[v]["definition"], resolved) for v in members]
    elements = sorted({g.nodes[v].get("element") or "?" for v in members})
    where = f"algebraic loop through {', '.join(members)} (elements {', '.join(elements)})"
    try:
        a, b = sympy.linear_eq_to_matrix(eqs, unknowns)
    except NonlinearError:
        try:
            solutions = sympy.solve(eqs, unknowns, dict=True)
        except (NotImplementedError, ValueError, TypeError):
            raise EquationError(f"{where} is nonlinear and bgc cannot solve it", tcg.model.source,
                                "break the loop, e.g. add a small storage element (C or I) in it") from None
        if len(solutions) != 1 or set(solutions[0]) != set(unknowns):
            raise EquationError(f"{where} has {len(solutions)} symbolic solutions", tcg.model.source,
                                "break the loop, e.g. add a small storage element (C or I) in it") from None
        return {u: solutions[0][u] for u in unknowns}
    if a.det() == 0:
        raise EquationError(f"{where} is singular", tcg.model.source,
                            "the loop's resistors fix no unique values: check the model")
    x = a.LUsolve(b)
    return {u: sympy.factor_terms(sympy.cancel(x[i])) for i, u in enumerate(unknowns)}
