"""Hybrid bond graphs: switched junctions, modes, transitions, and each mode's equations.

A 0- or 1-junction marked ``switch: true`` is ON in the modes that list it
and OFF in the others (Mosterman and Biswas's hybrid bond graphs): ON it is an
ordinary junction; OFF a 1-junction forces zero flow on each of its bonds and
a 0-junction zero effort. Each mode is therefore an ordinary bond graph, the
model's with every OFF junction replaced by a zero source on each of its bonds
(:func:`mode_graph`: a flow source of 0 for a 1-junction, an effort source of
0 for a 0-junction), and the stages of the single-mode compiler run on it
unchanged (:func:`compile_modes`): SCAP causality, the TCG and the state
equations per mode. A storage element cut off by an OFF 1-junction keeps its
integral causality with a zero flow (it holds its value); one whose variable
an OFF junction imposes is in derivative causality in that mode (an inertia
on an OFF 1-junction: its flow is 0) and is no state there.

The modes and transitions are read here (:func:`read`, called by stage 2,
:mod:`bgc.compiler.validate`) with located errors for what a person gets
wrong: a mode naming something that is not a switched junction, two modes
alike, a mode no transition reaches from the first, a guard naming an
unknown variable, a reset of something that is not a state (of the mode
entered: :func:`compile_modes`), a guard that holds as soon as the mode it
leaves is entered, a mode with no consistent causality.

>>> from bgc.compiler.load import loads
>>> from bgc.compiler.validate import validate
>>> g = validate(loads('''
... name: relay
... parameters: {R: 1.0, C: 2.0, R_aux: 0.5}
... inputs: {V: 1.0}
... elements: {V: {kind: Se}, j: {kind: "1"}, R: {kind: R}, c: {kind: "0"}, C: {kind: C},
...            k: {kind: "1", switch: true}, R_aux: {kind: R}}
... bonds: {1: [V, j], 2: [j, R], 3: [j, c], 4: [c, C], 5: [c, k], 6: [k, R_aux]}
... modes: {open: {on: []}, closed: {on: [k]}}
... transitions: [{from: open, to: closed, when: e4 > 0.6}, {from: closed, to: open, when: e4 < 0.4}]
... '''))
>>> [(m.name, m.equations.rhs) for m in compile_modes(g)]
[('open', ((V - e4)/(C*R),)), ('closed', ((-e4/R_aux + (V - e4)/R)/C,))]
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any

from ..errors import BgcError, ErrorGroup, ExpressionError, ValidationError
from ..ir import (
    GUARD_OPS, SWITCH_FAULTS, Bond, BondGraph, CausalBondGraph, DbnModel, Element, FaultSignatures, Guard, Mode,
    Modes, Signature, StateSpaceModel, StuckSwitch, TemporalCausalGraph, Transition, effort, flow, sym, var_key,
)
from ..kinds import element_kind
from . import expressions


@dataclass(frozen=True, slots=True)
class ModeModel:
    """One mode of a hybrid bond graph compiled as far as its equations: its
    bond graph (:func:`mode_graph`), causality, TCG, state equations, fault
    signatures and DBNs."""

    name: str
    graph: BondGraph
    causal: CausalBondGraph
    tcg: TemporalCausalGraph
    equations: StateSpaceModel
    #: The TRANSCEND signatures of the model's faults in this mode (a fault whose part an OFF switch
    #: cuts off deviates nothing: it is undetectable in this mode).
    signatures: FaultSignatures
    #: The DBNs of this mode, nominal and one per fault.
    dbn: DbnModel

    @property
    def model(self) -> BondGraph:
        """The mode's bond graph (as :class:`bgc.pipeline.Compiled` names it)."""
        return self.graph


# ------------------------------------------------------------------- reading
_GUARD = re.compile(r"(>=|<=|>|<)")


def read(v, data: dict, elements: tuple[Element, ...], bonds: tuple[Bond, ...], names: set[str],
         measurements: dict[str, Any], values: dict[str, float]) -> Modes | None:
    """The model's modes and transitions (None: a model of one mode), its
    errors reported through the validator ``v`` (``v.error``, ``v.expr``,
    ``v.bad``). ``names``: what a guard or a reset may name (bond variables,
    inputs, parameters; measurements are added); ``measurements``: each
    measurement's expression (a guard on one reads its noise-free value);
    ``values``: the parameters' nominal values."""
    switches = tuple(el.name for el in elements if el.switch)
    raw_modes = data.get("modes")
    raw_transitions = data.get("transitions")
    if raw_modes is None:
        for name in switches:
            v.error(f"junction {name} is switched but the model declares no modes", ("elements", name, "switch"),
                    "add a 'modes:' section naming the switched junctions ON in each mode, or drop 'switch: true'",
                    key=True)
        if raw_transitions is not None:
            v.error("the model has transitions but no modes", ("transitions",),
                    "add a 'modes:' section, or remove 'transitions:'", key=True)
        return None
    if not isinstance(raw_modes, dict) or v.bad(("modes",)):
        return None
    if not switches:
        v.error("the model declares modes but none of its junctions is switched", ("modes",),
                "mark the 0- or 1-junctions a mode turns on or off with 'switch: true'", key=True)
        return None
    _switch_kinds(v, elements, bonds)
    before = len(v.errors)
    modes = _modes(v, raw_modes, switches, elements)
    transitions = _transitions(v, raw_transitions, [str(m) for m in raw_modes], names | set(measurements),
                               measurements, elements, bonds)
    if not modes:
        return None
    if len(v.errors) == before:  # a mode or a transition refused would make others look unreachable
        _reachable(v, modes, transitions)
    _no_chatter(v, transitions, measurements, values)
    return Modes(switches, modes, transitions, _stuck(v, data.get("faults") or {}, switches))


def _stuck(v, raw: dict, switches: tuple[str, ...]) -> tuple[StuckSwitch, ...]:
    """The switches the model's ``faults:`` says may stick or move by
    themselves (the validator left them to the modes:
    :meth:`bgc.compiler.validate.Validator.faults`; a switch ON in every mode,
    or OFF in every one, it refuses, so an uncommanded change can always
    happen in some mode)."""
    out = []
    for name in switches:
        spec = raw.get(name)
        if spec is None or v.bad(("faults", name)):
            continue
        kinds = spec.get("kinds", ()) if isinstance(spec, dict) else spec
        prior = float(spec.get("prior", 0.01)) if isinstance(spec, dict) else 0.01
        extra = sorted(set(spec) - {"kinds", "prior", "description"}) if isinstance(spec, dict) else []
        if extra:
            v.error(f"a stuck switch takes no '{extra[0]}'", ("faults", name, extra[0]),
                    "give a switched junction's fault its kinds (stuck_on, stuck_off, uncommanded_on, uncommanded_off) "
                    "and a prior only", key=True)
            continue
        for kind in sorted(kinds):
            if kind in SWITCH_FAULTS:
                out.append(StuckSwitch(name, kind, prior, v.raw.key_loc("faults", name)))
    return tuple(out)


def _switch_kinds(v, elements: tuple[Element, ...], bonds: tuple[Bond, ...]) -> None:
    switched = {el.name for el in elements if el.switch}
    for b in bonds:
        if b.tail in switched and b.head in switched:
            v.error(f"bond {b.number} joins two switched junctions, {b.tail} and {b.head}", ("bonds", str(b.number)),
                    "put a plain junction or an element between them")


def _modes(v, raw: dict, switches: tuple[str, ...], elements: tuple[Element, ...]) -> tuple[Mode, ...]:
    out, seen = [], {}
    everything = {el.name for el in elements}
    for name, spec in raw.items():
        path = ("modes", name)
        if v.bad(path) or not isinstance(spec, dict):
            continue
        on, wrong = [], False
        for i, junction in enumerate(spec.get("on", [])):
            if junction in switches:
                on.append(junction)
            elif junction in everything:
                wrong = True
                v.error(f"mode {name} turns on {junction}, which is not a switched junction", path + ("on", i),
                        f"add 'switch: true' to junction {junction}" if element_kind(
                            next(el.kind for el in elements if el.name == junction)).role == "junction"
                        else f"a mode turns on switched junctions only: {', '.join(switches)}")
            else:
                wrong = True
                close = _closest(junction, switches)
                v.error(f"mode {name} turns on unknown junction '{junction}'", path + ("on", i),
                        f"did you mean '{close}'?" if close else f"the switched junctions: {', '.join(switches)}")
        key = frozenset(on)
        if wrong:
            continue
        if key in seen:
            v.error(f"modes {seen[key]} and {name} turn on the same junctions", path,
                    "two modes must differ in at least one switch: merge them or change one", key=True)
            continue
        seen[key] = name
        out.append(Mode(str(name), tuple(sorted(on)), spec.get("description"), v.raw.key_loc(*path)))
    for junction in switches:
        states = {junction in m.on for m in out}
        if len(out) == len(raw) and len(states) == 1 and len(seen) == len(out):
            v.error(f"switched junction {junction} is {'ON' if True in states else 'OFF'} in every mode",
                    ("elements", junction, "switch"),
                    "drop 'switch: true' (it never switches), or turn it on in some modes and off in others", key=True)
    return tuple(out)


def _transitions(v, raw: list | None, modes: list[str], names: set[str], measurements: dict[str, Any],
                 elements: tuple[Element, ...], bonds: tuple[Bond, ...]) -> tuple[Transition, ...]:
    if raw is None:
        v.error("the model has modes but no transitions", ("modes",),
                "add 'transitions:', each '{from: MODE, to: MODE}' with 'when: <guard>' (autonomous), "
                "'after: <time>' (a schedule), or neither (the data say the mode)", key=True)
        return ()
    if not isinstance(raw, list) or v.bad(("transitions",)):
        return ()
    states = _storage_states(elements, bonds)
    out = []
    for i, spec in enumerate(raw):
        path = ("transitions", i)
        if v.bad(path) or not isinstance(spec, dict):
            continue
        ends = []
        for key in ("from", "to"):
            mode = spec[key]
            if mode not in modes:
                close = _closest(mode, modes)
                v.error(f"transition {i + 1} goes {key} unknown mode '{mode}'", path + (key,),
                        f"did you mean '{close}'?" if close else f"the modes: {', '.join(modes)}")
            ends.append(mode)
        if ends[0] == ends[1] and ends[0] in modes:
            v.error(f"transition {i + 1} goes from mode {ends[0]} to itself", path + ("to",),
                    "a transition changes the mode: give another 'to'")
            continue
        if "when" in spec and "after" in spec:
            v.error(f"transition {i + 1} has both 'when' and 'after'", path + ("after",),
                    "a transition is autonomous (when) or timed (after): split it into two", key=True)
            continue
        if "tolerance" in spec and "when" not in spec:
            v.error(f"transition {i + 1} has a tolerance but no guard", path + ("tolerance",),
                    "a tolerance is the spread of a guard's threshold: give 'when', or drop 'tolerance'", key=True)
            continue
        guard = _guard(v, spec["when"], names, measurements, path + ("when",), i) if "when" in spec else None
        resets = _resets(v, spec.get("reset", {}), names, states, path + ("reset",), i)
        if ends[0] not in modes or ends[1] not in modes or ("when" in spec and guard is None) or resets is None:
            continue
        out.append(Transition(ends[0], ends[1], guard, float(spec["after"]) if "after" in spec else None, resets,
                              spec.get("description"), v.raw.loc(*path), float(spec.get("tolerance", 0.0))))
    return tuple(out)


def _guard(v, text: str, names: set[str], measurements: dict[str, Any], path: tuple, i: int) -> Guard | None:
    parts = _GUARD.split(text)
    loc = v.raw.loc(*path)
    if len(parts) != 3:
        v.error(f"the guard of transition {i + 1}, {text!r}, is not one comparison", path,
                "write 'LHS OP RHS' with one of " + " ".join(GUARD_OPS) + ", e.g. 'P_memb > 28.677'")
        return None
    sides = []
    for side in (parts[0], parts[2]):
        try:
            expr = expressions.parse(side.strip(), frozenset(names), loc, f"guard of transition {i + 1}")
        except ExpressionError as exc:
            v.errors.append(exc)
            return None
        sides.append(expr.xreplace({sym(m): e for m, e in measurements.items()}))
    if not (sides[0] - sides[1]).free_symbols:
        v.error(f"the guard of transition {i + 1}, {text!r}, names no variable", path,
                "compare a state, a measurement or an input with a value")
        return None
    return Guard(sides[0], parts[1], sides[1], text.strip(), loc)


def _resets(v, raw: dict, names: set[str], states: dict[str, str], path: tuple,
            i: int) -> tuple[tuple[str, Any], ...] | None:
    out, ok = [], True
    for state, text in raw.items():
        where = path + (state,)
        if state not in states:
            listed = ", ".join(f"{s} ({el})" for s, el in sorted(states.items(), key=lambda p: var_key(p[0])))
            v.error(f"transition {i + 1} resets '{state}', which is not a state", where,
                    f"reset a storage element's variable: {listed}", key=True)
            ok = False
            continue
        try:
            expr = expressions.parse(text, frozenset(names), v.raw.loc(*where), f"reset of {state}")
        except ExpressionError as exc:
            v.errors.append(exc)
            ok = False
            continue
        out.append((state, expr))
    return tuple(out) if ok else None


def _storage_states(elements: tuple[Element, ...], bonds: tuple[Bond, ...]) -> dict[str, str]:
    """The variable each storage element would integrate -> the element (e of a C, f of an I)."""
    out = {}
    for el in elements:
        kind = element_kind(el.kind)
        if kind.role != "storage":
            continue
        mine = [b for b in bonds if el.name in (b.tail, b.head)]
        if len(mine) == 1:
            out[effort(mine[0].number) if kind.state_variable == "e" else flow(mine[0].number)] = el.name
    return out


def _reachable(v, modes: tuple[Mode, ...], transitions: tuple[Transition, ...]) -> None:
    reached, frontier = {modes[0].name}, [modes[0].name]
    while frontier:
        here = frontier.pop()
        for t in transitions:
            if t.source == here and t.target not in reached:
                reached.add(t.target)
                frontier.append(t.target)
    for m in modes[1:]:
        if m.name not in reached:
            v.error(f"mode {m.name} is reached by no transition from the first mode, {modes[0].name}",
                    ("modes", m.name), "add a transition into it, or remove it (the first mode listed is the "
                    "plant's mode at time 0)", key=True)


def _threshold(guard: Guard, values: dict[str, float]) -> tuple[str, str, float] | None:
    """(variable, op, number) of a guard that compares one variable with a
    constant (either way round), else None."""
    import sympy

    lhs, rhs, op = guard.lhs, guard.rhs, guard.op
    at = {sym(k): val for k, val in values.items()}
    if isinstance(rhs, sympy.Symbol) and not isinstance(lhs, sympy.Symbol):
        lhs, rhs, op = rhs, lhs, {">": "<", "<": ">", ">=": "<=", "<=": ">="}[op]
    if not isinstance(lhs, sympy.Symbol) or lhs.name in values:
        return None
    try:
        number = float(rhs.xreplace(at))
    except (TypeError, ValueError):
        return None
    return (lhs.name, op, number) if math.isfinite(number) else None


def _no_chatter(v, transitions: tuple[Transition, ...], measurements: dict[str, Any],
                values: dict[str, float]) -> None:
    """A guard that holds as soon as the transition before it entered its
    mode: both compare the same variable with a number, and the values just
    past the first threshold satisfy the second (no hysteresis)."""
    told = set()
    for t in transitions:
        first = _threshold(t.guard, values) if t.guard else None
        if first is None:
            continue
        for u in transitions:
            second = _threshold(u.guard, values) if u.guard and u.source == t.target else None
            if second is None or second[0] != first[0] or (id(u), id(t)) in told:
                continue
            _, op1, c1 = first
            _, op2, c2 = second
            rising = op1 in (">", ">=")  # entered with the variable just above c1 (else just below)
            holds = (c2 <= c1 if op2 in (">", ">=") else c2 > c1) if rising else \
                    (c2 < c1 if op2 in (">", ">=") else c2 >= c1)
            if rising and op1 == ">=" and op2 == ">" and c2 == c1:
                holds = False  # entered at c1 exactly: > c1 waits
            spread = 4.0 * (t.tolerance + u.tolerance)
            if not holds and spread > 0 and abs(c2 - c1) < spread:
                told.add((id(t), id(u)))
                v.errors.append(ValidationError(
                    f"the thresholds of {t.source} -> {t.target} ({t.guard.text}) and {u.source} -> {u.target} "
                    f"({u.guard.text}) are {abs(c2 - c1):g} apart, under 4 times their tolerances ({spread:g}): a "
                    f"drawn threshold could make the plant switch again at once", u.guard.loc,
                    "leave a wider gap between the thresholds, or give smaller tolerances"))
            if holds:
                told.add((id(t), id(u)))
                v.errors.append(ValidationError(
                    f"the guard of {u.source} -> {u.target} ({u.guard.text}) holds as soon as {t.source} -> "
                    f"{t.target} ({t.guard.text}) enters {t.target}: the plant would switch again at once",
                    u.guard.loc, f"leave a gap between the two thresholds (hysteresis): a value just "
                    f"{'above' if rising else 'below'} {c1:g} must not satisfy {u.guard.text}"))


def no_hysteresis(transitions: tuple[Transition, ...], values: dict[str, float]) -> tuple[str, ...]:
    """The warnings of guards with no gap: a transition and one out of the
    mode it enters that compare the same variable with the same number the
    other way (``e8 > 21``, then ``e8 < 21``). Not an error (the plant must
    cross back first: :func:`_no_chatter` refuses a guard that holds at
    once), but an ideal comparator: with any noise on the variable near the
    threshold the plant switches back and forth from step to step."""
    out, told = [], set()
    for t in transitions:
        first = _threshold(t.guard, values) if t.guard and not t.tolerance else None
        if first is None:
            continue
        for u in transitions:
            second = _threshold(u.guard, values) if u.guard and u.source == t.target and u.target == t.source \
                and not u.tolerance else None
            if second is None or second[0] != first[0] or second[2] != first[2] or \
                    (first[1][0] == second[1][0]) or frozenset((id(t), id(u))) in told:  # the same way round
                continue
            told.add(frozenset((id(t), id(u))))
            out.append(f"{t.source} -> {t.target} ({t.guard.text}) and {u.source} -> {u.target} ({u.guard.text}) "
                       f"switch at the same value, {first[2]:g}: no hysteresis, so noise near it switches the "
                       "plant back and forth (give the thresholds a gap)")
    return tuple(out)


def _closest(name, options) -> str | None:
    """Stage 2's nearest name (:mod:`bgc.compiler.validate` reads the modes: it is loaded by then)."""
    from .validate import _closest as closest

    return closest(str(name), options)


# ------------------------------------------------------------------ per mode
#: What names the zero source of an OFF junction on one of its bonds: ``<junction>_off<bond>``.
_OFF = "_off"
#: The description of the zero source an OFF junction leaves in a mode's bond graph.
_OFF_TEXT = " OFF in mode "


def mode_graph(model: BondGraph, mode: str, on: tuple[str, ...] | None = None) -> BondGraph:
    """The ordinary bond graph of ``model`` in ``mode``: each switched
    junction OFF in it removed, and each of its bonds ending instead at a
    source of zero (flow for a 1-junction, effort for a 0-junction), named
    ``<junction>_off<bond>``; the bonds keep their numbers and directions,
    so the variables (e<N>, f<N>) are the same in every mode. ``on``: the
    switched junctions ON instead of the mode's (a stuck switch's
    configuration, ``mode`` then names it)."""
    import sympy

    modes = model.modes
    on = set(modes.mode(mode).on if on is None else on)
    off = {name for name in modes.switches if name not in on}
    taken = {el.name for el in model.elements}
    elements = [el for el in model.elements if el.name not in off]
    bonds = []
    for b in model.bonds:
        tail, head = b.tail, b.head
        for end in (b.tail, b.head):
            if end not in off:
                continue
            kind = "Sf" if model.element(end).kind == "1" else "Se"
            name = f"{end}{_OFF}{b.number}"
            while name in taken:
                name += "_"
            taken.add(name)
            elements.append(Element(name, kind, None, None, sympy.Integer(0), None,
                                    f"{end}{_OFF_TEXT}{mode}", model.element(end).loc))
            tail, head = (name, head) if end == b.tail else (tail, name)
        bonds.append(dataclasses.replace(b, tail=tail, head=head))
    return dataclasses.replace(model, elements=tuple(sorted(elements, key=lambda el: el.name)), bonds=tuple(bonds))


def switches_of(graph) -> tuple[str, ...]:
    """The switched junctions of a model with modes, from its bond graph, or
    from one mode's (:func:`mode_graph`) or its view, which keep elements
    only: the junctions switched ON there, and those OFF there, as the
    zero sources they left. Empty for a model of one mode."""
    modes = getattr(graph, "modes", None)
    if modes is not None:
        return modes.switches
    return tuple(sorted({el.name for el in graph.elements if el.switch}
                        | {el.description.split(_OFF_TEXT)[0] for el in graph.elements
                           if el.kind in ("Se", "Sf") and _OFF_TEXT in (el.description or "")}))


def zero_sources(graph: BondGraph) -> dict[str, str]:
    """The zero sources of a mode's bond graph (:func:`mode_graph`), each
    with the OFF junction it stands for; empty for a model of one mode."""
    if graph.modes is None:
        return {}
    present = {el.name for el in graph.elements}
    off = [j for j in graph.modes.switches if j not in present]
    return {el.name: j for el in graph.elements for j in off
            if re.fullmatch(rf"{re.escape(j)}{_OFF}\d+_*", el.name)}


def compile_modes(model: BondGraph) -> tuple[ModeModel, ...]:
    """Every mode of a hybrid bond graph, as far as its state equations
    (SCAP causality, the TCG, the equations of :mod:`bgc.compiler.equations`,
    on :func:`mode_graph`), in the model's order. Errors of a mode's stages
    are the stages' own, prefixed with the mode; a reset of a state that is
    no state of the mode it enters is refused here."""
    done, found = {}, {}
    for mode, parent in _reached(model):  # each mode's causality kept from the mode it is first entered from
        try:
            previous = done[parent].causal if parent in done else None
            done[mode.name] = _compile_graph(model, mode.name, mode_graph(model, mode.name), previous)
        except _Refused as exc:
            for kind, what, loc, fix in exc.found:
                found.setdefault((kind, what, loc or mode.loc, fix), []).append(mode.name)
    out = [done[m.name] for m in model.modes.modes if m.name in done]
    if found:
        raise ErrorGroup([kind(f"in mode{'s' if len(names) > 1 else ''} {', '.join(names)}: {what}", loc, fix)
                          for (kind, what, loc, fix), names in found.items()])
    errors = []
    states = {m.name: set(m.equations.states) for m in out}
    for i, t in enumerate(model.modes.transitions):
        for state, _ in t.resets:
            if state not in states[t.target]:
                errors.append(ValidationError(
                    f"transition {t.source} -> {t.target} resets {state}, which is no state in mode {t.target}",
                    t.loc, f"the states of {t.target}: {', '.join(sorted(states[t.target], key=var_key)) or 'none'}"))
    if errors:
        raise ErrorGroup(errors)
    return _with_stuck(model, tuple(out))


def _reached(model: BondGraph) -> list:
    """The modes in the order the automaton first reaches them from the
    first (breadth first, transitions in the model's order), each with the
    mode it is first entered from (None for the first; a mode no transition
    reaches, which validation refuses, last with None)."""
    modes = {m.name: m for m in model.modes.modes}
    first = model.modes.modes[0].name
    order, parent, queue = [first], {first: None}, [first]
    while queue:
        here = queue.pop(0)
        for t in model.modes.transitions:
            if t.source == here and t.target not in parent:
                parent[t.target] = here
                order.append(t.target)
                queue.append(t.target)
    order += [m.name for m in model.modes.modes if m.name not in parent]
    return [(modes[n], parent.get(n)) for n in order]


def _with_stuck(model: BondGraph, compiled: tuple[ModeModel, ...]) -> tuple[ModeModel, ...]:
    """Each mode's signatures with those of the switches that may stick: in a
    mode whose configuration the stuck switch leaves as it is, nothing
    deviates ("0" everywhere: a deviation seen there rules it out); in the
    others every sensor may deviate either way ("?": which way a switch's
    flow or effort moves them depends on where the plant stands, so the
    symbols cannot rule it out there; the data weigh it). One with no
    effect in a mode is listed among the mode's undetectable faults."""
    if not model.modes.stuck:
        return compiled
    added = [stuck_signatures(model, mode, m.equations, m.equations.outputs)
             for m, mode in zip(compiled, model.modes.modes)]
    return tuple(dataclasses.replace(m, signatures=dataclasses.replace(
        m.signatures, signatures=m.signatures.signatures + tuple(more),
        undetectable=m.signatures.undetectable + tuple(s.name for s in more if not s.first)))
        for m, more in zip(compiled, added))


def stuck_signatures(model: BondGraph, mode, ssm, columns: tuple[str, ...]) -> list[Signature]:
    """The signatures of ``model``'s switches that may stick in mode
    ``mode`` (its state equations ``ssm``), read at ``columns`` (its sensors,
    and bond variables a sensor placed would read): "0" everywhere where
    the stuck configuration is the mode's own, else "?" (:func:`_with_stuck`)."""
    depth = len(ssm.states) + 2  # as signatures.derive: through every integrator, plus a drift's order
    out = []
    for fault in model.modes.stuck:
        symbol = "0" if fault.on(mode.on) == tuple(sorted(mode.on)) else "?"  # the mode's own configuration
        out.append(Signature(fault.junction, 1 if fault.state == "ON" else -1, fault.kind,
                             tuple((symbol,) * (depth + 1) for _ in columns), tuple(columns) if symbol == "?" else ()))
    return out


class _Refused(Exception):
    """A configuration's stages refused it: (kind, what, where, fix) of each error, zero sources named."""

    def __init__(self, found: list):
        super().__init__(found)
        self.found = found


def _compile_graph(model: BondGraph, name: str, graph: BondGraph,
                   previous: CausalBondGraph | None = None) -> ModeModel:
    """One configuration of the switches (``graph``: :func:`mode_graph`) as
    far as its equations, signatures and DBNs, called ``name``; its
    causality kept from ``previous`` where it can (:func:`causality.assign
    <bgc.compiler.causality.assign>`). Raises
    :class:`_Refused` with its stages' errors, the zero sources named as
    the junctions OFF they stand for."""
    from . import causality, dbn, equations, signatures, tcg

    own = {el.name for el in model.elements}
    off = {zero: f"{junction} (OFF)" for zero, junction in zero_sources(graph).items()}
    try:
        causal = causality.assign(graph, previous)
        causal = dataclasses.replace(causal, diagnostics=tuple(d for d in causal.diagnostics if d.element in own))
        temporal = tcg.build(causal)
        ssm = equations.derive(temporal)
        sigs, dbns = signatures.derive(ssm), dbn.build(ssm)
    except BgcError as exc:
        found = []
        for e in getattr(exc, "errors", (exc,)):
            if any(f"source {zero} " in f"{e.what} {e.fix or ''} " for zero in off):
                continue  # the same conflict is told at the model's own element
            found.append((type(e), _named(e.what, off), e.loc, _named(e.fix or "", off) or None))
        raise _Refused(found) from None
    return ModeModel(name, graph, causal, temporal, ssm, sigs, dbns)


@dataclass(frozen=True, slots=True)
class StuckModel:
    """A stuck switch compiled: per mode of the model (its order), the
    configuration the plant runs in with the switch stuck (``configs``: a
    declared mode's own compiled model when the configuration is that
    mode's, else one of its own, named ``<mode> with <J> stuck ON/OFF``) and
    the declared mode it is (``same``: None for a configuration no mode has)."""

    fault: StuckSwitch
    configs: tuple[ModeModel, ...]
    same: tuple[str | None, ...]


def compile_stuck(model: BondGraph, compiled: tuple[ModeModel, ...], fault: StuckSwitch) -> StuckModel:
    """The configurations of ``model`` with the switch of ``fault`` stuck,
    per mode (:class:`StuckModel`); a configuration whose causality or
    equations fail is an error naming the fault and the mode."""
    declared = {tuple(sorted(m.on)): m.name for m in model.modes.modes}
    by_name = {m.name: m for m in compiled}
    configs, same, made = [], [], {}
    for mode in model.modes.modes:
        on = fault.on(mode.on)
        if on in declared:
            configs.append(by_name[declared[on]])
            same.append(declared[on])
            continue
        if on not in made:
            name = f"{mode.name} with {fault.title}"
            try:
                made[on] = _compile_graph(model, name, mode_graph(model, mode.name, on), by_name[mode.name].causal)
            except _Refused as exc:
                raise ErrorGroup([kind(f"with {fault.title} in mode {mode.name}: {what}", loc or fault.loc, fix)
                                  for kind, what, loc, fix in exc.found]) from None
        configs.append(made[on])
        same.append(None)
    return StuckModel(fault, tuple(configs), tuple(same))


def _named(text: str, off: dict[str, str]) -> str:
    """``text`` with the zero sources of :func:`mode_graph` named as the junction OFF they stand for."""
    for name in sorted(off, key=len, reverse=True):
        text = re.sub(rf"\b{re.escape(name)}\b", off[name], text)
    return text


def states(modes: tuple[ModeModel, ...]) -> tuple[str, ...]:
    """The states of a hybrid model: every variable that is a state in some mode."""
    return tuple(sorted({x for m in modes for x in m.equations.states}, key=var_key))


def causality_changes(a: ModeModel, b: ModeModel) -> list[str]:
    """What changes from mode ``a`` to mode ``b``: the bonds whose causal
    stroke moves (bonds of a switched junction aside, whose ends differ), and
    the storage elements that enter or leave integral causality."""
    out = []
    strokes_a = {c.bond: c.effort_by for c in a.causal.bonds}
    for c in b.causal.bonds:
        before = strokes_a.get(c.bond)
        if before is not None and before != c.effort_by and {before, c.effort_by} <= \
                {el.name for el in a.graph.elements} & {el.name for el in b.graph.elements}:
            out.append(f"bond {c.bond}: effort now from {c.effort_by} (was {before})")
    integral_a = {s.element: s.integral for s in a.causal.storage}
    for s in b.causal.storage:
        if integral_a.get(s.element) is not None and integral_a[s.element] != s.integral:
            out.append(f"{s.element} {'enters' if s.integral else 'leaves'} integral causality "
                       f"({'a state again' if s.integral else 'no state'})")
    return out
