"""Stage 6: :class:`~bgc.ir.StateSpaceModel` -> :class:`~bgc.ir.FaultSignatures`.

TRANSCEND's fault signatures (Mosterman and Biswas, 1999; thesis section
II.3.3), by forward propagation on the temporal causal graph.

A fault is a parameter ``P``, a direction (``+``: it increases, ``-``: it
decreases) and a kind. Its deviation enters the TCG at the relations that hold
``P`` (each node's ``effects``: the sign of the relation's change when ``P``
increases, at the operating point): an algebraic relation changes at once
(derivative order 0), a state's derivative changes, so the state itself moves
from order 1. A drifting fault kind (incipient) changes ``P`` continuously from
zero, which moves every entry one order up. From there the deviations
propagate, order by order: along an algebraic edge within the same order
(times the edge's sign), along an integrating edge (``dt/C``, ``dt/I``) into the
next order. Contributions of opposite signs to one variable at one order
make it ambiguous (``?``); a sign the TCG cannot determine is ``?`` too.

As in TRANSCEND, the fault strikes a plant at steady state: a relation's
direct change from a parameter (``R f``) enters at one order only, its other
variables' nominal trends being zero; and a variable that is 0 at the
operating point (a capacitor's current at rest) counts as positive, so a
capacitance or inertance fault has the signature it shows once the plant
moves (at rest it changes nothing).

A sensor fault deviates its own measurement and nothing else: an offset as
its sign says (a drift one order up), a stuck reading ``?`` at order 0 (off
the plant either way, or not at all), a noise burst ``?`` at every order (it
moves no mean: any symbol its residual shows is consistent with it).

The signature of a fault at a measurement is its symbols at orders 0, 1, ...:
``+``, ``-``, ``0``, ``?``. TRANSCEND's (magnitude, slope) pair is orders 0
and 1 for an abrupt fault; the first non-zero order says how soon the
measurement deviates (a jump, a bend, ...), and the measurements with the
lowest first order deviate first. :attr:`FaultSignatures.orders` is the
lowest order up to which the signatures separate every pair of faults that
the full signatures separate.

Two lists say what the sensors cannot tell apart:

* ``ambiguity``: faults with identical signatures at every measurement
  (qualitatively indistinguishable: TRANSCEND keeps them together);
* ``structural``: fault parameters that enter the model only as one
  combination (their gradients of every state derivative and measurement
  are parallel, e.g. a product ``R*C``): a change of one is, to first order,
  exactly the change of the other, so no filter can separate them.

Faults whose every symbol is 0 are ``undetectable`` with these sensors.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import networkx as nx
import numpy as np
import sympy

from ..ir import FaultSignatures, Signature, StateSpaceModel, sym, var_key
from ..kinds import DIRECTIONS, fault_kind


def derive(ssm: StateSpaceModel, extra: tuple[str, ...] = (), reads: dict[str, str] | None = None) -> FaultSignatures:
    """Signatures of every fault candidate, direction and kind of the model;
    ``extra``: bond variables read as if a sensor were on each (after the
    model's, in this order: what a sensor added there would show; ``bgc
    analyse --place-sensors``); ``reads``: the bond variable of an extra
    column named otherwise (a second sensor on a measured quantity, which
    none of the first sensor's faults moves)."""
    tcg = ssm.tcg
    g = tcg.graph
    model = ssm.model
    measured = _measured_nodes(g, ssm.outputs) | {v: (reads or {}).get(v, v) for v in extra}
    columns = tuple(ssm.outputs) + tuple(extra)
    depth = len(ssm.states) + 2  # a path through every integrator, plus a drift's order
    algebraic = nx.DiGraph()
    algebraic.add_nodes_from(g.nodes)
    algebraic.add_edges_from((u, v) for u, v, d in g.edges(data=True) if not d["temporal"])
    values = dict(ssm.variables)
    merged = any(d.get("differentiates") and values.get(v, 0) != 0  # storages joined to others (a varying constraint)
                 for v, d in g.nodes(data=True))
    plan = _plan(g, _order(algebraic))
    entries, jobs = [], []  # per signature: (fault, direction, kind, own symbols or the index of its propagation)
    for fault in model.faults:
        for kind in fault.kinds:
            shift = int(fault_kind(kind).drifts)
            for direction in (1,) if fault_kind(kind).replaces or fault_kind(kind).noise \
                    else DIRECTIONS[fault.direction]:
                if fault.target == "sensor":  # its own reading, and nothing else
                    own = _own(direction, shift, depth)
                    if fault_kind(kind).replaces:  # a stuck reading: off the plant either way, or not at all
                        own = ("?",) + ("0",) * depth
                    if fault_kind(kind).noise:  # a noise burst moves no mean: any symbol, at every order
                        own = ("?",) * (depth + 1)
                    entries.append((fault, direction, kind,
                                    tuple(own if m == fault.subject else ("0",) * (depth + 1) for m in columns)))
                else:
                    effects = _actuator_effects(g, model, fault, kind) if fault.target == "actuator" else None
                    seeds = _seeds(g, fault.parameter, direction, shift, depth, effects)
                    if merged:  # storages merged (a varying derivative causality): the TCG's forward
                        # propagation does not follow them yet; any symbol, at every order (none is ruled out)
                        entries.append((fault, direction, kind, tuple(("?",) * (depth + 1) for _ in columns)))
                        continue
                    entries.append((fault, direction, kind, len(jobs)))
                    jobs.append(seeds)
    dev = _propagate(plan, jobs, depth)
    signatures = []
    for fault, direction, kind, symbols in entries:
        if isinstance(symbols, int):
            symbols = tuple(tuple(_SYMBOLS[c] for c in dev[plan.index[measured[m]], :, symbols]) for m in columns)
        signatures.append(Signature(fault.parameter, direction, kind, symbols, _first(columns, symbols)))
    full = {s.name: (s.symbols, s.first) for s in signatures}
    groups = _groups(full)
    orders = next(k for k in range(depth + 1)
                  if _groups({n: tuple(m[: k + 1] for m in sym_) for n, (sym_, _) in full.items()}) == groups)
    undetectable = tuple(s.name for s in signatures if all(c == "0" for m in s.symbols for c in m))
    return FaultSignatures(ssm, columns, orders, tuple(signatures),
                           tuple(g_ for g_ in groups if len(g_) > 1), _structural(ssm), undetectable)


def _measured_nodes(g: nx.DiGraph, outputs: tuple[str, ...]) -> dict[str, str]:
    """The TCG node of each measurement (a bond variable measured directly, or its own node)."""
    out = {}
    for n, d in g.nodes(data=True):
        if d.get("measurement") in outputs:
            out[d["measurement"]] = n
    return out


def _order(algebraic: nx.DiGraph) -> list[list[str]]:
    """The algebraic relations in causal order: groups of nodes, a group being
    one variable or the members of an algebraic loop."""
    cond = nx.condensation(algebraic)
    return [sorted(cond.nodes[c]["members"], key=var_key)
            for c in nx.lexicographical_topological_sort(cond, key=lambda c: var_key(min(
                cond.nodes[c]["members"], key=var_key)))]


def qsum(a: str, b: str) -> str:
    """Qualitative sum of two symbols: ``+`` and ``-`` make ``?``.

    >>> qsum("+", "0"), qsum("+", "+"), qsum("+", "-"), qsum("?", "0")
    ('+', '+', '?', '?')
    """
    if a == "0":
        return b
    if b == "0" or a == b:
        return a
    return "?"


def qmul(sign: int | None, a: str) -> str:
    """A symbol times an edge's sign (None: undetermined)."""
    if a == "0" or sign == 0:
        return "0"
    if sign is None or a == "?":
        return "?"
    return a if sign > 0 else {"+": "-", "-": "+"}[a]


def _own(direction: int, shift: int, depth: int) -> tuple[str, ...]:
    """A sensor fault's symbols at its own measurement: the offset's sign at
    order 0 (a bias jumps) or 1 (a drift bends)."""
    out = ["0"] * (depth + 1)
    if shift <= depth:
        out[shift] = "+" if direction > 0 else "-"
    return tuple(out)


def _actuator_effects(g: nx.DiGraph, model, fault, kind: str) -> dict[str, int | None]:
    """Where an actuator fault enters the TCG: the sources that impose its
    input, with the sign of what they impose when the input's offset (or
    gain) increases, at the nominal parameters and inputs (None when that
    sign depends on the plant's variables or is not a number)."""
    u = sym(fault.subject)
    point = {sym(p.name): sympy.Float(p.value) for p in model.parameters}
    point.update({sym(i.name): sympy.Float(i.signal.at(0.0)) for i in model.inputs})
    out: dict[str, int | None] = {}
    for n, d in g.nodes(data=True):
        if fault.subject not in d.get("inputs", ()):
            continue
        slope = sympy.diff(d["definition"], u)
        if fault_kind(kind).suffix == "gain":
            slope = slope * u
        value = sympy.sympify(slope.xreplace(point))
        out[n] = int(sympy.sign(value)) if value.is_number and value.is_finite and value.is_real else None
    return out


#: The qualitative symbols as bits: + and - are one bit each, ? both, so that the qualitative sum
#: (:func:`qsum`) is a bitwise or.
_SYMBOLS = ("0", "+", "-", "?")
_CODE = {c: i for i, c in enumerate(_SYMBOLS)}
#: :func:`qmul` as a table, by an edge's sign: positive, negative, undetermined (None), zero.
_TIMES = {1: np.array([0, 1, 2, 3], np.uint8), -1: np.array([0, 2, 1, 3], np.uint8),
          None: np.array([0, 3, 3, 3], np.uint8), 0: np.array([0, 0, 0, 0], np.uint8)}


def _sign(sign) -> int | None:
    return None if sign is None else (0 if sign == 0 else (1 if sign > 0 else -1))


@dataclass(frozen=True)
class _Plan:
    """The TCG as :func:`_propagate` sweeps it, read once per model: each
    node's row (``index``), the temporal edges (tails, heads, signs), and
    per algebraic group (one variable or the members of a loop, in causal
    order) its non-state members' rows, each with its algebraic in-edges
    (tail's row, sign), and how many sweeps it takes."""

    index: dict
    temporal: tuple[np.ndarray, np.ndarray, tuple]
    groups: tuple


def _plan(g: nx.DiGraph, order: list[list[str]]) -> _Plan:
    index = {n: i for i, n in enumerate(g.nodes)}
    edges = [(index[u], index[v], _sign(d["sign"])) for u, v, d in g.edges(data=True) if d["temporal"]]
    temporal = (np.array([e[0] for e in edges], dtype=np.intp), np.array([e[1] for e in edges], dtype=np.intp),
                tuple(e[2] for e in edges))
    groups = []
    for group in order:
        members = tuple((index[v], tuple((index[u], _sign(d["sign"])) for u, _, d in g.in_edges(v, data=True)
                                         if not d["temporal"]))
                        for v in group if g.nodes[v]["role"] != "state")
        # a loop is swept until nothing changes (symbols only move up to '?')
        groups.append((members, 2 * len(group) + 1 if len(group) > 1 else 1))
    return _Plan(index, temporal, tuple(groups))


def _seeds(g: nx.DiGraph, parameter: str, direction: int, shift: int, depth: int,
           effects: dict[str, int | None] | None = None) -> dict[tuple[str, int], str]:
    """Where one fault enters the TCG: (node, order) -> symbol; ``effects``:
    where it enters (node -> sign), when not at the nodes that hold the
    parameter."""
    seeds: dict[tuple[str, int], str] = {}
    for n, d in g.nodes(data=True):
        effect = dict(d.get("effects", ())).get(parameter, 0) if effects is None else effects.get(n, 0)
        if effect == 0:
            continue
        k = shift + (1 if d["role"] == "state" else 0)
        if k <= depth:
            seeds[(n, k)] = qmul(effect, "+" if direction > 0 else "-")
    return seeds


def _propagate(plan: _Plan, jobs: list[dict[tuple[str, int], str]], depth: int) -> np.ndarray:
    """Symbols (codes of :data:`_SYMBOLS`) of every node at orders 0..depth
    for each fault's seeds (:func:`_seeds`), all faults at once: nodes x
    orders x faults. At each order: the seeds, what the integrators carry
    from the order below, then the algebraic relations in causal order (a
    node's symbol is its seed plus the sum over its in-edges)."""
    rows = len(plan.index)
    seed = np.zeros((rows, depth + 1, len(jobs)), np.uint8)
    for j, seeds in enumerate(jobs):
        for (n, k), s in seeds.items():
            seed[plan.index[n], k, j] |= _CODE[s]
    dev = np.zeros_like(seed)
    tails, heads, signs = plan.temporal
    for k in range(depth + 1):
        dev[:, k] |= seed[:, k]
        if k > 0:
            for t, h, sign in zip(tails, heads, signs):
                dev[h, k] |= _TIMES[sign][dev[t, k - 1]]
        for members, sweeps in plan.groups:
            for _ in range(sweeps):
                for v, ins in members:
                    total = seed[v, k].copy()
                    for u, sign in ins:
                        total |= _TIMES[sign][dev[u, k]]
                    dev[v, k] = total
    return dev


def _first(outputs: tuple[str, ...], symbols: tuple[tuple[str, ...], ...]) -> tuple[str, ...]:
    """The measurements whose first non-zero symbol comes at the lowest order."""
    first = {m: next((k for k, c in enumerate(s) if c != "0"), None) for m, s in zip(outputs, symbols)}
    seen = [k for k in first.values() if k is not None]
    if not seen:
        return ()
    return tuple(m for m in outputs if first[m] == min(seen))


def _groups(signatures: dict) -> tuple[tuple[str, ...], ...]:
    """Fault names grouped by equal signatures, each group and the list sorted."""
    by: dict = {}
    for name, key in signatures.items():
        by.setdefault(key, []).append(name)
    return tuple(sorted(tuple(sorted(v)) for v in by.values()))


def _structural(ssm: StateSpaceModel) -> tuple[tuple[str, ...], ...]:
    """Groups of fault parameters whose gradients of every state derivative
    and measurement are parallel (every 2 x 2 minor cancels to 0): they enter
    the model as one combination."""
    exprs = list(ssm.rhs) + list(ssm.output_exprs)
    params = sorted({f.parameter for f in ssm.model.faults})
    holds = [e.free_symbols for e in exprs]
    zero = sympy.Integer(0)
    grad = {p: [sympy.diff(e, sym(p)) if sym(p) in fs else zero for e, fs in zip(exprs, holds)] for p in params}
    constants = {sym(x) for x in ssm.parameters}
    linked = nx.Graph()
    linked.add_nodes_from(params)
    for p, q in itertools.combinations(params, 2):
        a, b = grad[p], grad[q]
        if any((x == 0) != (y == 0) for x, y in zip(a, b)):
            continue
        rows = [i for i, x in enumerate(a) if x != 0]
        if not rows or any(sympy.cancel(a[i] * b[j] - a[j] * b[i]) != 0 for i, j in itertools.combinations(rows, 2)):
            continue
        if sympy.cancel(a[rows[0]] / b[rows[0]]).free_symbols <= constants:  # the same constant ratio everywhere
            linked.add_edge(p, q)
    return tuple(sorted(tuple(sorted(c)) for c in nx.connected_components(linked) if len(c) > 1))
