"""Stage 3: :class:`~bgc.ir.BondGraph` -> :class:`~bgc.ir.CausalBondGraph` by SCAP.

The sequential causality assignment procedure (SCAP; Karnopp, Margolis and
Rosenberg, *System Dynamics*, ch. 5) gives every bond a causal stroke: which end
imposes the effort and which the flow.

1. Each source gets its required causality (Se imposes effort, Sf flow) and the
   consequences are propagated through junctions, transformers and gyrators.
2. Each storage element still free gets integral causality (C imposes effort,
   I imposes flow), then propagation. A storage element whose causality was
   already forced the other way, or whose integral causality leads to a
   conflict later on, is in derivative causality; this is reported.
3. Each resistor still free gets a causality chosen arbitrarily (the form its law
   is written in, else conductance form ``f = e/R``): these resistors close
   algebraic loops. A choice that leads to a conflict is undone and the other
   one tried (backtracking).
4. Any bond still free (between junctions only) gets a choice likewise.

Constraints propagated: a 0-junction has exactly one bond whose neighbour imposes
the effort; a 1-junction exactly one bond whose neighbour imposes the flow; a
transformer passes causality through (one of its bonds has its effort imposed by
the TF); a gyrator swaps it (both or neither). Elements are visited in sorted
name order, so the result does not depend on the order of the model file.

Examples
--------
>>> from bgc.compiler.load import loads
>>> from bgc.compiler.validate import validate
>>> g = validate(loads('''
... name: rc
... parameters: {R: 1.0, C: 2.0}
... inputs: {V: 1.0}
... elements: {V: {kind: Se}, j: {kind: "1"}, R: {kind: R}, C: {kind: C}}
... bonds: {1: [V, j], 2: [j, R], 3: [j, C]}
... '''))
>>> cbg = assign(g)
>>> [(s.element, s.state, s.integral) for s in cbg.storage]
[('C', 'e3', True)]
>>> cbg.causality(2)
BondCausality(bond=2, effort_by='j', flow_by='R')
"""

from __future__ import annotations


from ..errors import CausalityError, ErrorGroup
from ..ir import BondCausality, BondGraph, CausalBondGraph, Diagnostic, StorageCausality
from ..kinds import element_kind


class _Conflict(Exception):
    def __init__(self, element: str, why: str):
        self.element = element
        self.why = why


class _Solver:
    """Causal constraints of a bond graph and unit propagation over them."""

    def __init__(self, model: BondGraph):
        self.model = model
        self.kind = {el.name: el.kind for el in model.elements}
        self.ends = {b.number: (b.tail, b.head) for b in model.bonds}
        self.ports: dict[str, list[int]] = {el.name: [] for el in model.elements}
        for b in model.bonds:
            self.ports[b.tail].append(b.number)
            self.ports[b.head].append(b.number)
        self.effort_by: dict[int, str] = {}

    def other(self, bond: int, element: str) -> str:
        tail, head = self.ends[bond]
        return head if element == tail else tail

    def snapshot(self) -> dict[int, str]:
        return dict(self.effort_by)

    def restore(self, snap: dict[int, str]) -> None:
        self.effort_by = snap

    def set(self, bond: int, effort_by: str, queue: list[str]) -> None:
        current = self.effort_by.get(bond)
        if current is None:
            self.effort_by[bond] = effort_by
            queue.extend(self.ends[bond])
        elif current != effort_by:
            tail, head = self.ends[bond]
            raise _Conflict(effort_by if effort_by in (tail, head) else tail,
                            f"bond {bond} would need its effort imposed by both {current} and {self.other(bond, current)}")

    def assign(self, bond: int, effort_by: str) -> None:
        """Fix one bond and propagate; raises _Conflict."""
        queue: list[str] = []
        self.set(bond, effort_by, queue)
        self.propagate(queue)

    def propagate(self, queue: list[str]) -> None:
        while queue:
            name = queue.pop()
            kind = element_kind(self.kind[name])
            bonds = self.ports[name]
            if kind.role == "junction":
                self.junction(name, kind.name, kind.common, bonds, queue)
            elif kind.two_port == "transformer":
                a, b = bonds
                for x, y in ((a, b), (b, a)):
                    if x in self.effort_by:
                        by_tf = self.effort_by[x] == name
                        self.set(y, self.other(y, name) if by_tf else name, queue)
            elif kind.two_port == "gyrator":
                a, b = bonds
                for x, y in ((a, b), (b, a)):
                    if x in self.effort_by:
                        by_gy = self.effort_by[x] == name
                        self.set(y, name if by_gy else self.other(y, name), queue)
            elif kind.role == "source":
                bond = bonds[0]
                self.set(bond, name if kind.imposes == "effort" else self.other(bond, name), queue)

    def junction(self, name: str, kind: str, common: str, bonds: list[int], queue: list[str]) -> None:
        # 0-junction (common effort): exactly one bond whose effort comes from
        # outside (the neighbour); 1-junction (common flow): exactly one bond
        # whose effort comes from the junction.
        zero = common == "effort"

        def special(b: int) -> bool:
            by = self.effort_by[b]
            return by != name if zero else by == name

        assigned = [b for b in bonds if b in self.effort_by]
        free = [b for b in bonds if b not in self.effort_by]
        specials = [b for b in assigned if special(b)]
        what = common
        if len(specials) > 1:
            who = sorted(self.other(b, name) for b in specials)
            raise _Conflict(name, f"{kind}-junction {name} gets its {what} imposed by both "
                                  f"{who[0]} and {who[1]}")
        if len(specials) == 1:
            for b in free:
                self.set(b, name if zero else self.other(b, name), queue)
        elif not free:
            raise _Conflict(name, f"{kind}-junction {name} has no bond that imposes its {what}")
        elif len(free) == 1:
            b = free[0]
            self.set(b, self.other(b, name) if zero else name, queue)


def assign(model: BondGraph, previous: CausalBondGraph | None = None) -> CausalBondGraph:
    """Run SCAP on a validated bond graph; ``previous``: the causality of
    the mode a hybrid bond graph switches from (its other switches' states),
    whose strokes the resistors and free bonds keep where they can (MoTHS'
    incremental reassignment, HSCAP: after the sources, and the storage
    elements' integral causality, a bond that keeps its two ends keeps its
    stroke unless the switch forces it to move; from scratch, a resistor
    forced into resistance form in one mode would flip back to its preferred
    conductance form in the next).

    Raises
    ------
    ErrorGroup
        Causal conflicts among sources (e.g. two effort sources on one
        0-junction), each naming the elements involved.
    """
    solver = _Solver(model)
    errors: list[CausalityError] = []
    elements = sorted(model.elements, key=lambda el: el.name)

    # 1. Sources.
    kinds = {el.name: element_kind(el.kind) for el in elements}
    for el in elements:
        if kinds[el.name].role == "source":
            bond = solver.ports[el.name][0]
            snap = solver.snapshot()
            try:
                want = el.name if kinds[el.name].imposes == "effort" else solver.other(bond, el.name)
                solver.assign(bond, want)
            except _Conflict as c:
                solver.restore(snap)
                errors.append(CausalityError(f"causal conflict: {c.why}", el.loc,
                                             f"source {el.name} cannot impose its "
                                             f"{kinds[el.name].imposes} there; "
                                             "remove or move one of the sources"))
    if errors:
        raise ErrorGroup(errors)

    # 2-4. Storage elements (integral preferred), then resistors (conductance
    # form, or the form their law is written in), then any free bond; each choice
    # is propagated, and a choice that leads to a dead end later is undone
    # (depth-first search), so SCAP fails only when no assignment exists.
    decisions: list[tuple[int, str, str | None]] = []
    for el in elements:
        if kinds[el.name].role == "storage":  # integral causality: impose its own variable
            bond = solver.ports[el.name][0]
            own = kinds[el.name].imposes == "effort"
            decisions.append((bond, el.name if own else solver.other(bond, el.name), None))
    before = {c.bond: c.effort_by for c in previous.bonds} if previous is not None else {}

    def kept(bond: int, prefer: str) -> str:
        """The previous mode's stroke of ``bond`` when its ends are the same, else ``prefer``."""
        return before[bond] if before.get(bond) in solver.ends[bond] else prefer

    for el in elements:
        if kinds[el.name].role == "resistor":
            bond = solver.ports[el.name][0]
            prefer = solver.other(bond, el.name)  # conductance form f = e/R
            if el.law is not None and el.law.output.startswith("e"):
                prefer = el.name
            decisions.append((bond, kept(bond, prefer), el.name))
    for b in sorted(solver.ends):
        decisions.append((b, kept(b, solver.ends[b][0]), None))
    after_sources = solver.snapshot()
    arbitrary: list[str] = []
    if not _search(solver, decisions, arbitrary):
        raise ErrorGroup([CausalityError("no consistent causal assignment exists for the free bonds",
                                         model.source, "check the junction structure")])
    arbitrary = [r for r in arbitrary if _really_free(solver, after_sources, decisions, r)]
    storage: list[StorageCausality] = []
    diagnostics: list[Diagnostic] = []
    for el in elements:
        kind = kinds[el.name]
        if kind.role != "storage":
            continue
        bond = solver.ports[el.name][0]
        integral_by = el.name if kind.imposes == "effort" else solver.other(bond, el.name)
        integral = solver.effort_by[bond] == integral_by
        storage.append(StorageCausality(el.name, el.kind, bond, integral))
        if not integral:
            diagnostics.append(Diagnostic(
                "warning", f"{el.kind} element {el.name} is in derivative causality: its "
                           f"{kind.imposes} is fixed by the rest of the graph "
                           "and it adds no state", el.name))
    for name in arbitrary:
        diagnostics.append(Diagnostic("note", f"resistor {name} was assigned causality arbitrarily: "
                                               "it closes an algebraic loop", name))
    for el in elements:
        if kinds[el.name].role in ("resistor", "storage") and model.bonds_of(el.name)[0].tail == el.name:
            diagnostics.append(Diagnostic(
                "warning", f"the bond of {el.kind} element {el.name} points out of it: its law reads with the "
                           "opposite sign (a negative resistance or capacitance); reverse the bond", el.name))
        if kinds[el.name].role == "source" and model.bonds_of(el.name)[0].head == el.name:
            diagnostics.append(Diagnostic(
                "warning", f"the bond of source {el.name} points into it: it absorbs the power it imposes; "
                           "reverse the bond if that is not intended", el.name))

    causal = tuple(
        BondCausality(b.number, solver.effort_by[b.number], b.other(solver.effort_by[b.number]))
        for b in model.bonds
    )
    return CausalBondGraph(model, causal, tuple(storage), tuple(sorted(arbitrary)), tuple(diagnostics))


def _search(solver: _Solver, decisions: list[tuple[int, str, str | None]], arbitrary: list[str]) -> bool:
    """Depth-first search over the free bonds in ``decisions`` order, preferred
    choice first, undoing choices that lead to a conflict (iterative: no
    recursion limit on large graphs). ``arbitrary`` collects the resistors chosen."""
    stack: list[tuple[int, int, dict[int, str]]] = []
    i, alt = 0, 0
    while True:
        while i < len(decisions) and decisions[i][0] in solver.effort_by:
            i += 1
        if i == len(decisions):
            return True
        bond, prefer, resistor = decisions[i]
        placed = False
        while alt < 2:
            snap = solver.snapshot()
            try:
                solver.assign(bond, prefer if alt == 0 else solver.other(bond, prefer))
            except _Conflict:
                solver.restore(snap)
                alt += 1
                continue
            stack.append((i, alt, snap))
            if resistor is not None:
                arbitrary.append(resistor)
            placed = True
            break
        if placed:
            i, alt = i + 1, 0
            continue
        if not stack:
            return False
        i, alt, snap = stack.pop()
        if decisions[i][2] is not None:
            arbitrary.pop()
        solver.restore(snap)
        alt += 1


def _really_free(solver: _Solver, after_sources: dict[int, str],
                 decisions: list[tuple[int, str, str | None]], resistor: str) -> bool:
    """Whether the resistor's causality was a real choice: with the sources and
    storage elements as chosen, its other causality also completes the graph.
    (The search can pick a resistor's preferred form, fail later and flip it;
    then it was forced, not arbitrary.)"""
    final = solver.snapshot()
    bond = solver.ports[resistor][0]
    try:
        solver.restore(dict(after_sources))
        for name, kind in sorted(solver.kind.items()):
            b = solver.ports[name][0] if element_kind(kind).role == "storage" else None
            if b is not None and b not in solver.effort_by:
                solver.assign(b, final[b])
        if bond in solver.effort_by:  # forced by the sources and storage alone
            return False
        solver.assign(bond, solver.other(bond, final[bond]))
        return _search(solver, decisions, [])
    except _Conflict:
        return False
    finally:
        solver.restore(final)


def check_assignment(model: BondGraph, effort_by: dict[int, str]) -> list[str]:
    """Every causal rule a complete assignment breaks (empty when valid).

    Independent of the solver; used by tests and by ``bgc show causality``.
    """
    problems = []
    ports: dict[str, list[int]] = {el.name: [] for el in model.elements}
    ends = {b.number: b for b in model.bonds}
    for b in model.bonds:
        ports[b.tail].append(b.number)
        ports[b.head].append(b.number)
    for el in model.elements:
        bonds = ports[el.name]
        by_me = [effort_by[b] == el.name for b in bonds]
        kind = element_kind(el.kind)
        if kind.role == "source" and kind.imposes == "effort" and not by_me[0]:
            problems.append(f"{el.name} must impose effort")
        if kind.role == "source" and kind.imposes == "flow" and by_me[0]:
            problems.append(f"{el.name} must impose flow")
        if kind.common == "effort" and sum(not m for m in by_me) != 1:
            problems.append(f"0-junction {el.name} needs exactly one effort-imposing bond")
        if kind.common == "flow" and sum(by_me) != 1:
            problems.append(f"1-junction {el.name} needs exactly one flow-imposing bond")
        if kind.two_port == "transformer" and sum(by_me) != 1:
            problems.append(f"transformer {el.name} must pass causality through")
        if kind.two_port == "gyrator" and sum(by_me) not in (0, 2):
            problems.append(f"gyrator {el.name} must swap causality")
    for number, b in ends.items():
        if effort_by[number] not in (b.tail, b.head):
            problems.append(f"bond {number} has no valid causal stroke")
    return problems

