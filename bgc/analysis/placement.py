"""Sensor placement (``bgc analyse --place-sensors``): the cheapest sets of
sensors to add so that every fault is detected and every pair told apart,
structurally (:mod:`.structure`) and by the signatures (the qualitative
level of :mod:`.isolability`, a sensor's signature the TRANSCEND symbols its
bond variable shows), as far as the candidate sensors can.

The candidates are the bond graph's efforts and flows (each different
expression once, the first bond's name for it; none already measured), and a
second sensor on each measured quantity whose sensor may fail (a sensor fault
declared on it: hardware redundancy, the second reading holds none of the
first's faults; named after the sensor with a prime, ``p'``; on the sensor's
expression when no bond variable equals it, a differential gauge's), or those a
candidates file names, each with a cost (1 by default; a measured quantity
named there is a second sensor on it). A set is
*enough* when the model with those sensors added detects every fault the
model with every candidate added detects, and tells apart every ordered pair
that one tells apart, at both levels: what no candidate can give is not
asked of any set (and is said). The sets are tried by their cost, the fewest sensors first
among equal costs, up to ``most`` sensors; every set of the cheapest cost
that is enough is given (a sensor whose equation holds the same unknowns as
another's, e.g. the effort and the flow of one resistor at a known
resistance, gives the same structure: both sets are listed).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

from .structure import StructuralModel

#: How many cheapest sets are given at most.
MOST_SETS = 12


@dataclass(frozen=True)
class Candidate:
    """A sensor that may be added: the bond variable it reads, its expression
    in the states, inputs and parameters, and its cost."""

    name: str
    expr: object
    cost: float = 1.0
    #: Faults no symbol of ``expr`` holds that change what it reads all the same (a switch that may
    #: stick, in a mode whose stuck configuration changes this variable: :func:`with_sensors`)
    also: frozenset = frozenset()
    #: The bond variable it reads when its name is not that (a second sensor: ``variable``, beside the
    #: sensor ``beside`` that reads it already; the sensor's model text when that is an expression no bond
    #: variable equals, a differential pressure across two tanks)
    variable: str = ""
    beside: str = ""
    #: The temporal causal graph's node whose symbols it shows when that is not ``reads`` (a second
    #: sensor on an expression: its sensor's own measurement node)
    node: str = ""

    @property
    def reads(self) -> str:
        """The bond variable the sensor reads (its model text, for a second sensor on an expression)."""
        return self.variable or self.name

    @property
    def shows(self) -> str:
        """The temporal causal graph's node whose symbols the sensor shows."""
        return self.node or self.reads

    @property
    def written(self) -> tuple[str, str]:
        """(name, model text) of the sensor in a model file: a bond variable's own name, or a second
        sensor's on an expression named after its sensor (``dP_2``)."""
        return (f"{self.beside}_2", self.reads) if self.node else (self.reads, self.reads)


@dataclass(frozen=True)
class Placement:
    """The answer: ``sets`` (each a tuple of candidate names) of the cheapest
    ``cost`` that are enough; what every candidate together gives
    (``reachable``: faults detected and ordered pairs told apart) against the
    model as it is (``now``); the faults and pairs no candidate can give."""

    sets: tuple[tuple[str, ...], ...]
    cost: float | None
    candidates: tuple[Candidate, ...]
    now: tuple[frozenset, frozenset]
    reachable: tuple[frozenset, frozenset]
    faults: tuple[str, ...]
    #: The same at the qualitative level (None: not asked for)
    now_qualitative: tuple[frozenset, frozenset] | None = None
    reachable_qualitative: tuple[frozenset, frozenset] | None = None
    #: Whether more sets of that cost are enough than the MOST_SETS given
    more: bool = False
    #: The quantitative level's check of each set (``bgc distinguish`` of the model with it added:
    #: faults detected, ordered pairs told apart; ``sets`` then ordered by it, most pairs first), and
    #: of the model as it is; None: not checked (no quantitative level, or no set to check)
    checked: tuple[tuple[int, int], ...] | None = None
    checked_now: tuple[int, int] | None = None

    def variables(self, names: Sequence[str]) -> list[str]:
        """The bond variables the candidates ``names`` read (a second sensor's is its measured quantity's;
        on an expression, its model text)."""
        by = {c.name: c for c in self.candidates}
        return [by[n].reads for n in names]

    def written(self, names: Sequence[str]) -> list[tuple[str, str]]:
        """(name, model text) of each of the candidates ``names`` in a model file (:attr:`Candidate.written`)."""
        by = {c.name: c for c in self.candidates}
        return [by[n].written for n in names]


def second(sensor: str) -> str:
    """The name of a second sensor beside ``sensor``."""
    return sensor + "'"


def candidates(ssm, measured_exprs: Sequence, costs: Mapping[str, float] | None = None,
               faulty: Sequence[str] = (), declared: Mapping[str, str] | None = None) -> tuple[Candidate, ...]:
    """Every bond variable of ``ssm`` with an expression of its own that no
    sensor reads already (``measured_exprs``: the sensors' expressions
    without their offsets, in the order of ``ssm.outputs``), then a second
    sensor on the quantity of each sensor of ``faulty`` (those a sensor
    fault is declared on), or the variables ``costs`` names with their
    costs (a measured one: a second sensor on it); of variables with one
    expression, the cheapest (then the first bond's; for a second sensor,
    the variable its sensor's model text names, ``declared``, when it is one). A
    sensor of ``faulty`` whose expression no bond variable has (its model text an
    expression: a differential pressure across two tanks) gets a second sensor on
    that expression without a costs file; with one, a sensor ``costs`` names
    gets a second sensor on its model text at that cost (unless a bond
    variable it names is cheaper): the way to price one on an expression."""
    declared = declared or {}
    seen = {str(e): name for name, e in zip(ssm.outputs, measured_exprs)}
    best: dict[str, Candidate] = {}
    twins: dict[str, Candidate] = {}
    for name, expr in ssm.variables:
        if (costs is not None and name not in costs) or not expr.free_symbols:
            continue
        cost = 1.0 if costs is None else float(costs[name])
        sensor = seen.get(str(expr))
        if sensor is None:
            c = Candidate(name, expr, cost)
            if str(expr) not in best or c.cost < best[str(expr)].cost:
                best[str(expr)] = c
        elif costs is not None or sensor in faulty:
            c = Candidate(second(sensor), expr, cost, variable=name, beside=sensor)
            if sensor not in twins or c.cost < twins[sensor].cost or \
                    (c.cost == twins[sensor].cost and name == declared.get(sensor)):
                twins[sensor] = c
    for sensor, expr in zip(ssm.outputs, measured_exprs):
        if not expr.free_symbols:
            continue
        if costs is None:  # beside a sensor of faulty without a twin on a bond variable
            cost, wanted = 1.0, sensor in faulty and sensor not in twins
        else:  # priced by its name, below a twin on a bond variable
            cost = float(costs.get(sensor, math.inf))
            wanted = cost < (twins[sensor].cost if sensor in twins else math.inf)
        if wanted:
            twins[sensor] = Candidate(second(sensor), expr, cost, variable=declared.get(sensor, str(expr)),
                                      beside=sensor, node=sensor)
    return tuple(best.values()) + tuple(twins[s] for s in ssm.outputs if s in twins)


def with_sensors(model: StructuralModel, ssm, added: Sequence[Candidate]) -> StructuralModel:
    """``model`` with a measurement equation per added sensor."""
    states = set(ssm.states)
    faulty = {e: next(iter(model.holds[e])) for e in model.faults.values()}  # fault equation -> its v_p
    by_parameter = {v[2:]: v for v in faulty.values()}
    holds, kind, known = dict(model.holds), dict(model.kind), dict(model.known)
    equations = list(model.equations)
    for c in added:
        names = {s.name for s in c.expr.free_symbols}
        e = f"meas_added_{c.name}"
        equations.append(e)
        holds[e] = frozenset({x for x in states if x in names} | {v for p, v in by_parameter.items() if p in names}
                             | {by_parameter[p] for p in c.also if p in by_parameter})
        known[e], kind[e] = frozenset(names & set(ssm.inputs)) | {c.name}, "measurement"
    return replace(model, equations=tuple(equations), holds=holds, kind=kind, known=known)


def _gives(model: StructuralModel) -> tuple[frozenset, frozenset]:
    """The faults ``model`` detects and the ordered pairs it tells apart."""
    names, matrix = model.matrix()
    plus = model.overdetermined()
    detected = frozenset(f for f in names if model.faults[f] in plus)
    pairs = frozenset((a, b) for i, a in enumerate(names) for j, b in enumerate(names) if matrix[i][j])
    return detected, pairs


def _enough(model: StructuralModel, target: tuple[frozenset, frozenset]) -> bool:
    """Whether ``model`` gives ``target``, stopping at the first miss."""
    detected, pairs = target
    plus = model.overdetermined()
    if any(model.faults[f] not in plus for f in detected):
        return False
    for b in model.faults:
        need = [a for a in model.faults if (a, b) in pairs]
        if need:
            cut = model.overdetermined({model.faults[b]})
            if any(model.faults[a] not in cut for a in need):
                return False
    return True


def _qualitative(signatures, faults: Sequence[str], columns: Sequence[str]) -> tuple[frozenset, frozenset]:
    """What the signatures read at ``columns`` (measurement names) detect and tell apart."""
    from .isolability import qualitative

    keep = [signatures.measurements.index(c) for c in columns]
    view = replace(signatures, measurements=tuple(columns),
                   signatures=tuple(replace(x, symbols=tuple(x.symbols[k] for k in keep)) for x in signatures.signatures))
    level = qualitative(view, faults)
    return (frozenset(f for f, d in zip(faults, level.detectable) if d),
            frozenset((faults[i], faults[j]) for i, j in level.pairs()))


def checked(p: Placement, counts: Sequence[tuple[int, int]], now: tuple[int, int]) -> Placement:
    """``p`` with the quantitative level's ``counts`` (faults detected,
    ordered pairs told apart) of the model with each of its sets, ``now``
    the model's as it is: the sets ordered by it, the most pairs told apart
    first, then the most faults detected (the cost and the structure being
    equal, what the data are predicted to tell decides; a tie keeps the
    order found)."""
    order = sorted(range(len(p.sets)), key=lambda i: (-counts[i][1], -counts[i][0]))
    return replace(p, sets=tuple(p.sets[i] for i in order), checked=tuple(tuple(counts[i]) for i in order),
                   checked_now=tuple(now))


def _covers(got: tuple[frozenset, frozenset], want: tuple[frozenset, frozenset]) -> bool:
    return want[0] <= got[0] and want[1] <= got[1]


def place(model: StructuralModel, ssm, cands: Sequence[Candidate], most: int = 2, signatures=None) -> Placement:
    """The cheapest sets of at most ``most`` candidates that are enough
    (module docstring); ``signatures``: the signatures read at the model's
    sensors and then at every candidate (:func:`bgc.compiler.signatures.derive`
    with ``extra``), for the qualitative level too (None: structurally only)."""
    now = _gives(model)
    reachable = _gives(with_sensors(model, ssm, cands))
    faults = tuple(model.faults)
    outputs = tuple(ssm.outputs)
    q_now = q_all = None
    if signatures is not None:
        q_now = _qualitative(signatures, faults, outputs)
        q_all = _qualitative(signatures, faults, outputs + tuple(c.name for c in cands))
    if now == reachable and q_now == q_all:
        return Placement(((),), 0.0, tuple(cands), now, reachable, faults, q_now, q_all)

    def enough(s, names) -> bool:
        return _enough(with_sensors(model, ssm, s), reachable) and \
            (q_all is None or _covers(_qualitative(signatures, faults, outputs + names), q_all))

    sets, cost, more = _cheapest(cands, most, enough)
    return Placement(sets, cost, tuple(cands), now, reachable, faults, q_now, q_all, more)


def _cheapest(cands: Sequence[Candidate], most: int, enough) -> tuple[tuple, float | None, bool]:
    """The cheapest sets of at most ``most`` of ``cands`` that are
    ``enough(set, names)``: tried by their cost, the fewest sensors first
    among equal costs, up to ``MOST_SETS`` of them; (the sets' names, their
    cost (None: none), whether more of that cost are enough)."""
    subsets = sorted((s for k in range(1, most + 1) for s in itertools.combinations(cands, k)),
                     key=lambda s: (sum(c.cost for c in s), len(s)))
    found, cost = [], None
    for s in subsets:
        total = sum(c.cost for c in s)
        if cost is not None and total > cost:
            break
        names = tuple(c.name for c in s)
        if any(set(f) <= set(names) for f in found):  # a set that holds one found already is not the cheapest
            continue
        if enough(s, names):
            if len(found) == MOST_SETS:
                return tuple(found), cost, True
            found.append(names)
            cost = total
    return tuple(found), cost, False


@dataclass(frozen=True)
class ModePart:
    """One mode of a model with modes, for :func:`place_across`: its
    structural model, state equations, candidate sensors (a bond variable
    that reads nothing in the mode, its junction OFF, is none there) and,
    for the qualitative level, the signatures read at its sensors and then
    at each of its candidates (None: structurally only)."""

    model: StructuralModel
    ssm: object
    candidates: tuple[Candidate, ...]
    signatures: object = None
    #: The mode's name (what a candidate reads there is shown with it)
    mode: str = ""


def _across(parts: Sequence[ModePart], names: Sequence[str], qualitative: bool,
            structural: tuple[frozenset, frozenset] | None = None) -> tuple:
    """What the sensors ``names`` added give across the modes: (structural,
    qualitative or None), each (faults detected, ordered pairs told apart),
    a fault detected and a pair told apart when some mode does it (the data
    are read in every mode the plant visits). ``structural``: a structural
    target; when the set misses it, its qualitative level is not worked
    out (None)."""
    s_det, s_pairs, q_det, q_pairs = set(), set(), set(), set()
    for part in parts:
        added = [c for c in part.candidates if c.name in names]
        detected, pairs = _gives(with_sensors(part.model, part.ssm, added))
        s_det |= detected
        s_pairs |= pairs
    got = (frozenset(s_det), frozenset(s_pairs))
    if not qualitative or (structural is not None and not _covers(got, structural)):
        return got, None
    for part in parts:
        added = [c.name for c in part.candidates if c.name in names]
        detected, pairs = _qualitative(part.signatures, tuple(part.model.faults), tuple(part.ssm.outputs) + tuple(added))
        q_det |= detected
        q_pairs |= pairs
    return got, (frozenset(q_det), frozenset(q_pairs))


def place_across(parts: Sequence[ModePart], most: int = 2) -> Placement:
    """:func:`place` for a model with modes: a sensor reads its bond variable
    in every mode where its part lists it, and a set is enough when, across
    the modes (:func:`_across`), it gives what every candidate together
    gives, at the structural level and, when the parts carry signatures, the
    qualitative one. A candidate's expression shown is its own where it is
    the same in every mode that lists it, else each mode's, named."""
    qualitative = all(p.signatures is not None for p in parts)
    reads: dict[str, list] = {}
    for part in parts:
        for c in part.candidates:
            reads.setdefault(c.name, []).append((part.mode, c))
    every = []
    for name, seen in reads.items():
        shown = {str(c.expr) for _, c in seen}
        expr = seen[0][1].expr if len(shown) == 1 else "; ".join(f"{c.expr} in {mode}" for mode, c in seen)
        every.append(Candidate(name, expr, min(c.cost for _, c in seen), variable=seen[0][1].variable,
                               beside=seen[0][1].beside, node=seen[0][1].node))
    every = tuple(every)
    now, q_now = _across(parts, (), qualitative)
    reachable, q_all = _across(parts, tuple(reads), qualitative)
    faults = tuple(parts[0].model.faults)
    if now == reachable and q_now == q_all:
        return Placement(((),), 0.0, every, now, reachable, faults, q_now, q_all)

    def enough(s, names) -> bool:
        got, q_got = _across(parts, names, qualitative, reachable)
        return _covers(got, reachable) and (not qualitative or (q_got is not None and _covers(q_got, q_all)))

    sets, cost, more = _cheapest(every, most, enough)
    return Placement(sets, cost, every, now, reachable, faults, q_now, q_all, more)
