"""What a number on a plot or in a report is: each variable's meaning and
unit, read from the model, so that every picture and table says it the same
way (``e6: pressure at C_res [Pa]``, ``time [s]``).

Parameters, measurements and inputs declare their units in the model file.
A state is the co-energy variable of a storage element (a C's effort, an
I's flow; Karnopp, Margolis and Rosenberg, *System Dynamics*, ch. 4); the
model's ``domain`` (:data:`bgc.kinds.DOMAINS`) or the element's own
``quantity`` says what it is. Its unit is read off the bond graph: the bonds
that junctions join share one unit of effort and one of flow (a 0-junction's
efforts are equal and its flows add up, a 1-junction's the other way round),
while a transformer or gyrator may change both. So an effort or flow source
driven by a declared input, or a sensor reading one bond variable, gives
the unit of every effort (or flow) of its part of the graph; two different
units declared in one part give none. Nothing is guessed: what the model
does not declare is shown without a unit.

>>> from bgc.compiler.load import load
>>> from bgc.compiler.validate import validate
>>> labels = labels_of(validate(load("models/circuit.yaml")))
>>> labels.axis("e4"), labels.axis("f10"), labels.axis("f2"), labels.time
('e4: voltage at C1 [V]', 'f10: current through L [A]', 'f2 [A]', 'time [s]')
>>> Labels().axis("e4"), Labels().time, Labels().per_time, Labels().time_word
('e4', 'time', 'per unit time', 'time units')
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ..ir import BondGraph, Element
from ..kinds import DOMAINS, GENERIC, element_kind

_BOND_VARIABLE = re.compile(r"^([ef])([0-9]+)$")


def with_unit(text: str, unit: str | None) -> str:
    """``text [unit]``, or ``text`` when there is no unit."""
    return f"{text} [{unit}]" if unit else text


@dataclass(frozen=True, slots=True)
class Labels:
    """The model's time unit, the units of its variables (parameters,
    measurements, inputs, and the states whose unit the model implies) and
    the meaning of its states, by name. The empty ``Labels()`` labels
    every variable by its name alone."""

    time_unit: str | None = None
    units: tuple[tuple[str, str], ...] = ()
    meanings: tuple[tuple[str, str], ...] = ()
    #: A model with modes: the modes' names, in the order of their numbers (a run's mode column).
    modes: tuple[str, ...] = ()

    def unit(self, name: str) -> str | None:
        """The unit of variable ``name`` (None: not declared)."""
        return dict(self.units).get(name)

    def axis(self, name: str) -> str:
        """An axis label: the name, what it is when it is a state, and its unit."""
        meaning = dict(self.meanings).get(name)
        return with_unit(f"{name}: {meaning}" if meaning else name, self.unit(name))

    @property
    def time(self) -> str:
        """The time axis: ``time [s]``, or ``time`` without a declared unit."""
        return with_unit("time", self.time_unit)

    @property
    def time_word(self) -> str:
        """A span's unit after its number: ``s``, or ``time units`` without a declared time unit."""
        return self.time_unit or "time units"

    @property
    def per_time(self) -> str:
        """``per s``, or ``per unit time`` without a declared time unit."""
        return f"per {self.time_unit}" if self.time_unit else "per unit time"

    def magnitude_unit(self, unit: str | None, drifts: bool) -> str | None:
        """The unit of a fault magnitude of a quantity in ``unit``: the unit
        itself for a step, per unit of time for a drift's slope."""
        if not drifts:
            return unit
        if unit:
            return f"{unit}/{self.time_unit}" if self.time_unit else f"{unit} per unit time"
        return self.per_time if self.time_unit else None


def labels_of(model: BondGraph) -> Labels:
    """The labels of model ``model``'s variables (module docstring)."""
    units = {x.name: x.unit for x in (*model.parameters, *model.measurements, *model.inputs) if x.unit}
    implied = bond_units(model)
    meanings = {}
    for el in model.elements:
        variable = element_kind(el.kind).state_variable
        if variable is None:
            continue
        name = f"{variable}{model.bonds_of(el.name)[0].number}"
        meanings[name] = state_meaning(model, el)
        if name in implied:
            units.setdefault(name, implied[name])
    return Labels(model.settings.time_unit, tuple(sorted(units.items())), tuple(sorted(meanings.items())),
                  model.modes.names if getattr(model, "modes", None) is not None else ())


def state_meaning(model: BondGraph, el: Element) -> str:
    """What storage element ``el``'s state is: ``pressure at C_res`` (a C's
    effort), ``volume flow through I_fp`` (an I's flow); the element's own
    ``quantity``, else the model's domain's effort or flow, else ``effort`` or ``flow``."""
    domain = DOMAINS.get(model.domain or "", GENERIC)
    effort = element_kind(el.kind).state_variable == "e"
    quantity = el.quantity or (domain.effort if effort else domain.flow)
    return f"{quantity} {'at' if effort else 'through'} {el.name}"


def bond_units(model: BondGraph) -> dict[str, str]:
    """The unit of each bond variable (``e6``, ``f10``) that the model's
    declarations imply (module docstring); the others are left out."""
    part = _parts(model)
    said: dict[tuple[int, str], set[str]] = {}
    for variable, unit in _declared(model):
        m = _BOND_VARIABLE.match(variable)
        if m and int(m.group(2)) in part:
            said.setdefault((part[int(m.group(2))], m.group(1)), set()).add(unit)
    out = {}
    for b in model.bonds:
        for v in "ef":
            units = said.get((part[b.number], v), set())
            if len(units) == 1:
                out[f"{v}{b.number}"] = next(iter(units))
    return out


def _declared(model: BondGraph) -> list[tuple[str, str]]:
    """(bond variable, unit) pairs the model declares: a source's variable
    when it imposes a declared input or parameter as it is, a sensor's
    variable when it reads one bond variable as it is."""
    import sympy

    out = []
    for el in model.elements:
        kind = element_kind(el.kind)
        if kind.role == "source" and isinstance(el.source, sympy.Symbol) and model.unit(el.source.name):
            bond = model.bonds_of(el.name)[0].number
            out.append((f"{'e' if kind.imposes == 'effort' else 'f'}{bond}", model.unit(el.source.name)))
    for m in model.measurements:
        if isinstance(m.expr, sympy.Symbol) and m.unit:
            out.append((m.expr.name, m.unit))
    return out


def _parts(model: BondGraph) -> dict[int, int]:
    """Bond number -> the part of the graph it belongs to: bonds joined by a
    junction are in one part (one-port elements have one bond; two-ports separate)."""
    parent = {b.number: b.number for b in model.bonds}

    def root(n: int) -> int:
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    for el in model.elements:
        if element_kind(el.kind).role == "junction":
            bonds = [b.number for b in model.bonds_of(el.name)]
            for n in bonds[1:]:
                parent[root(n)] = root(bonds[0])
    return {n: root(n) for n in parent}
