"""Structural detectability and isolability of a model's faults, from its
equations' structure alone (which variables each equation holds), as the
Fault Diagnosis Toolbox computes them (Frisk, Krysander and Jung; Krysander,
Aslund and Nyberg 2008 for the overdetermined part).

The structural model is written from the state equations bgc derives
(:class:`~bgc.ir.StateSpaceModel`):

- per state x, its dynamic equation ``dx = f(x, u, theta)`` and its
  differential constraint ``dx = d/dt x`` (the derivative a variable of its
  own, as the toolbox writes dynamic models);
- per sensor y, its measurement equation ``y = h(x, u, theta)``;
- per fault candidate, the equation of its parameter ``v_p = p + f_p``: the
  faulty parameter ``v_p`` is an unknown of its own, in every equation the
  parameter enters, and the fault enters that one equation only. A
  parameter of a bond graph element (a resistance) enters several state
  equations once the bond variables are eliminated; its fault stays one
  fault in one equation, as in the element's constitutive law it came from;
- a switched junction that may stick (a model with modes): its fault
  ``v_K = f_K`` is an unknown in every equation the stuck configuration
  changes in that mode (a state's dynamic equation, a measurement's), and
  the fault enters its own equation only, as a parameter's does; a mode the
  stuck switch leaves as it is holds it in no other equation (there it is
  not detectable).

Unknowns: the states, their derivatives and the faulty parameters. Known:
the inputs and the measurements. A fault is **structurally detectable** when
its equation is in the overdetermined part ``M+`` of the Dulmage-Mendelsohn
decomposition (some redundancy involves it), and fault ``i`` is
**structurally isolable** from fault ``j`` when its equation is in the
overdetermined part of the model without fault ``j``'s equation (a test can
see ``i`` and not ``j``). ``M+`` is found from a maximum matching of
equations to unknowns (networkx's Hopcroft-Karp): the equations reached from
the unmatched ones by alternating paths.

Two equations of one unknown x are a redundancy (a fault in either is seen);
an unknown z only the third holds takes it up (a fault there is not):

>>> m = StructuralModel(("e1", "e2", "e3"), ("x", "z"), {"e1": {"x"}, "e2": {"x"}, "e3": {"z"}}, {"f1": "e1", "f3": "e3"})
>>> sorted(m.overdetermined()), m.detectable("f1"), m.detectable("f3")
(['e1', 'e2'], True, False)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping

import networkx as nx


@dataclass(frozen=True)
class StructuralModel:
    """Equations (names, in order), unknowns, the unknowns each equation holds,
    and each fault's equation; ``known``: the known variables each equation
    holds (inputs, measurements), for the record; ``kind``: what each
    equation is (``dynamic``, ``differential``, ``measurement``, ``fault``)."""

    equations: tuple[str, ...]
    unknowns: tuple[str, ...]
    holds: Mapping[str, frozenset | set]
    faults: Mapping[str, str]
    known: Mapping[str, frozenset | set] = field(default_factory=dict)
    kind: Mapping[str, str] = field(default_factory=dict)

    def overdetermined(self, without: frozenset | set = frozenset()) -> frozenset:
        """``M+`` of the equations but ``without``: the equations reached by
        alternating paths from those a maximum matching leaves unmatched."""
        eqs = [e for e in self.equations if e not in without]
        g = nx.Graph()
        g.add_nodes_from((("e", e) for e in eqs), bipartite=0)
        g.add_nodes_from((("x", x) for x in self.unknowns), bipartite=1)
        g.add_edges_from((("e", e), ("x", x)) for e in eqs for x in self.holds[e])
        mate = nx.bipartite.hopcroft_karp_matching(g, top_nodes=[("e", e) for e in eqs])
        reached = {e for e in eqs if ("e", e) not in mate}
        todo = list(reached)
        while todo:
            e = todo.pop()
            for x in self.holds[e]:
                other = mate.get(("x", x))
                if other is not None and other[1] not in reached:
                    reached.add(other[1])
                    todo.append(other[1])
        return frozenset(reached)

    def detectable(self, fault: str) -> bool:
        """Whether ``fault``'s equation is in the overdetermined part."""
        return self.faults[fault] in self.overdetermined()

    def isolable(self, fault: str, other: str) -> bool:
        """Whether ``fault`` can be told from ``other``: its equation is in
        the overdetermined part of the model without ``other``'s."""
        return self.faults[fault] in self.overdetermined({self.faults[other]})

    def matrix(self) -> tuple[tuple[str, ...], tuple[tuple[bool, ...], ...]]:
        """The faults and the isolability matrix: ``[i][j]`` whether fault i
        is isolable from fault j (the complement of the toolbox's
        ``IsolabilityAnalysis``: there ``[i][j]`` is 1 when i cannot be told from j);
        the diagonal is False, a fault that is not detectable is isolable
        from nothing."""
        names = tuple(self.faults)
        cut = {f: self.overdetermined({self.faults[f]}) for f in names}
        return names, tuple(tuple(i != j and self.faults[i] in cut[j] for j in names) for i in names)


def of_equations(ssm, faults: Mapping[str, str], sensors: Mapping[str, str] | None = None,
                 enters: Mapping[str, Iterable[str]] | None = None) -> StructuralModel:
    """The structural model of the state equations ``ssm``
    (:class:`~bgc.ir.StateSpaceModel`) with ``faults``: each fault's name ->
    the parameter its fault changes (module docstring). ``sensors``: the
    parameter of a sensor's fault -> the sensor; the fault is in that
    sensor's measurement equation also where its parameter is not (a stuck
    reading, a noise burst: the generated fault model replaces or widens the
    reading). ``enters``: a parameter no equation holds (a switched junction
    that may stick) -> the equations it is in (``dyn_<state>``,
    ``meas_<sensor>``: :func:`stuck_equations`)."""
    states, inputs, outputs = tuple(ssm.states), set(ssm.inputs), tuple(ssm.outputs)
    parameters = sorted(set(faults.values()))
    faulty = {p: f"v_{p}" for p in parameters}

    def variables(expr) -> tuple[set, set]:
        names = {s.name for s in expr.free_symbols}
        return ({x for x in states if x in names} | {faulty[p] for p in parameters if p in names},
                names & inputs)

    extra: dict[str, set] = {}
    for p, names in (enters or {}).items():
        for e in names if p in faulty else ():
            extra.setdefault(e, set()).add(faulty[p])
    equations, holds, known, kind = [], {}, {}, {}
    for x, rhs in zip(states, ssm.rhs):
        unknown, given = variables(rhs)
        e, d = f"dyn_{x}", f"diff_{x}"
        unknown |= extra.get(e, set())
        equations += [e, d]
        holds[e], known[e], kind[e] = frozenset(unknown | {f"d{x}"}), frozenset(given), "dynamic"
        holds[d], known[d], kind[d] = frozenset({f"d{x}", x}), frozenset(), "differential"
    for y, h in zip(outputs, ssm.output_exprs):
        unknown, given = variables(h)
        unknown |= {faulty[p] for p, sensor in (sensors or {}).items() if sensor == y and p in faulty}
        e = f"meas_{y}"
        unknown |= extra.get(e, set())
        equations.append(e)
        holds[e], known[e], kind[e] = frozenset(unknown), frozenset(given | {y}), "measurement"
    for p in parameters:
        e = f"fault_{p}"
        equations.append(e)
        holds[e], known[e], kind[e] = frozenset({faulty[p]}), frozenset(), "fault"
    unknowns = (*states, *(f"d{x}" for x in states), *(faulty[p] for p in parameters))
    return StructuralModel(tuple(equations), unknowns, holds, {f: f"fault_{p}" for f, p in faults.items()},
                           known, kind)


def stuck_equations(mode, config) -> frozenset:
    """The equations of mode ``mode``'s structural model (a
    :class:`~bgc.compiler.modes.ModeModel`) a stuck switch changes when it
    runs the plant in configuration ``config`` there: the dynamic equation
    of every state of the mode that is no state of the configuration or
    whose right-hand side differs, and the measurement equation of every
    sensor whose expression differs (none when the configuration is the
    mode's own)."""
    if config is mode:
        return frozenset()
    a, b = mode.equations, config.equations
    rhs = dict(zip(b.states, b.rhs))
    out = {f"dyn_{x}" for x, f in zip(a.states, a.rhs) if _changed(f, rhs.get(x))}
    read = dict(zip(b.outputs, b.output_exprs))
    out |= {f"meas_{y}" for y, h in zip(a.outputs, a.output_exprs) if _changed(h, read.get(y))}
    return frozenset(out)


def _changed(expr, other) -> bool:
    """Whether ``other`` (None: there is none) is not the same expression as ``expr``."""
    import sympy

    return other is None or (expr != other and sympy.simplify(expr - other) != 0)


def stuck_readings(mode, config) -> frozenset:
    """The bond variables of mode ``mode`` whose value a stuck switch
    changes when it runs the plant in configuration ``config`` there (their
    expression differs, or the configuration has none): what a sensor
    placed on one of them would read of the stuck switch (none when the
    configuration is the mode's own)."""
    if config is mode:
        return frozenset()
    other = dict(config.equations.variables)
    return frozenset(name for name, expr in mode.equations.variables if _changed(expr, other.get(name)))
