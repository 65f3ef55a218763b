"""A model split into minimal submodels, each with the measurements it needs
read as inputs (issue 49: reduced-order filters; the thesis's future
direction V.2 (ii); Roychoudhury, Biswas and Koutsoukos's factored DBNs, and
Alonso-Gonzalez, Moya and Biswas's possible conflicts, which cut a model the
same way).

A sensor that reads one bond variable tells more than its reading: a
pressure sensor on a bond of a 0-junction gives the effort of every bond of
that junction, a flow sensor on a 1-junction the flow of every bond of it.
The junction (with the same-kind junctions bonded to it: one common effort
or flow) is a **cut**: the rest of the plant sees it as a source of the
measured value. A sensor on a bond no such junction holds (an effort across
a resistor of a 1-junction) cuts the bond itself, through a two-port
junction of the measured kind put in its middle (the half at the bond's
head keeps its number: a storage there keeps its state's name).

The **submodel of a sensor** is the bond graph reached from its cut without
crossing another sensor's cut; each other cut it touches becomes an effort
source (a 0-junction's cut) or a flow source (a 1-junction's) of that
sensor's reading, an input of the submodel. It predicts its own sensor (the
redundancy that makes a residual), and its states are only the storages
between its neighbouring cuts: a chain of n measured tanks gives n submodels
of one state each. Two sensors on one cut share one submodel (the first by
name is the reading the neighbours take). A sensor of an expression over several
bonds (``f3 * R10``) cuts nothing; it is predicted by the first submodel
holding all its bonds, or by one of its own reached from them.

Each submodel is written as a model file of its own (:attr:`Submodel.text`):
the whole model's parameters, inputs and elements it holds, with their
faults; the storages start from the whole model's initial state; a read
sensor is a constant input at the whole model's reading at the initial
state (for a reading that starts at 0, its value of largest magnitude over
the nominal run), the point the submodel's scales and priors are taken at.
A fault of a sensor read as an input becomes a fault of that input (a bias
or a drift of the reading is one of the value delivered: an actuator's). Noise levels are fractions of a
signal's scale, and a submodel's scales need not be the whole plant's: each
storage's and each sensor's level is written so that its absolute std is
the whole model's, each storage's raised by the noise its read sensors
carry into it (``dt |df/dy| sigma``: the reading's std times the state's
sensitivity to it and the sample period, the input held over a sample). The
file says what its filter assumes.

A law that reads a bond variable a sensor measures beyond the submodel's
cuts reads the sensor instead.

A model with modes, or an element whose law reads a bond variable outside
its submodel (a modulated source), is refused with a located error.

>>> from bgc.pipeline import compile_model
>>> c = compile_model("models/two_tank.yaml")
>>> d = decompose(c.raw, c.numerics)
>>> [(s.name, s.outputs, s.reads) for s in d.submodels]
[('two_tank_F10', ('F10',), ('F12',)), ('two_tank_F12', ('F12',), ('F10', 'F20')), ('two_tank_F20', ('F20',), ('F12',))]
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np
import sympy
import yaml

from ..errors import CodegenError
from ..ir import Numerics, RawModel, sym
from . import numerics
from ..kinds import element_kind

_BOND_VARIABLE = re.compile(r"([ef])([0-9]+)")
#: The longest name a model file may give (docs/format.md).
LONGEST = 64
#: The fault kinds of a sensor that stay faults of the reading when it is read as an input (an actuator's).
_AS_INPUT = ("bias", "drift")


@dataclass(frozen=True)
class _Whole:
    """What a submodel is written from: the whole model's file and its numbers."""

    raw: RawModel
    numerics: Numerics

    @property
    def equations(self):
        return self.numerics.dbn.equations

    @property
    def model(self):
        return self.equations.model


@dataclass(frozen=True)
class Submodel:
    """One submodel: its ``name`` (the model's, ``_`` and its first
    sensor), the sensors it predicts (``outputs``), the sensors it reads as
    inputs (``reads``), the plant's inputs it reads (``inputs``), the whole
    model's elements it holds, the fault subjects of the whole model it can
    see (``faults``: parameters, its sensors, its inputs, and the sensors
    it reads whose kinds an input takes) and its model file (``text``)."""

    name: str
    outputs: tuple[str, ...]
    reads: tuple[str, ...]
    inputs: tuple[str, ...]
    elements: tuple[str, ...]
    faults: tuple[str, ...]
    text: str
    #: Each sensor read -> the input it is in the submodel (its own name, or ``<name>_reading``).
    read_as: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class Decomposition:
    """The submodels of ``model``, in the order of its sensors."""

    model: str
    submodels: tuple[Submodel, ...]

    def touching(self, subject: str) -> tuple[str, ...]:
        """The submodels a fault of ``subject`` (a parameter, sensor or
        input of the whole model) can move: those holding it, and those
        reading it when it is a sensor (whatever its fault: a frozen reading
        moves them too, though only its own submodel models it)."""
        return tuple(s.name for s in self.submodels if subject in s.faults or subject in s.reads)


def decompose(raw: RawModel, num: Numerics) -> Decomposition:
    """The submodels of the model read as ``raw`` and compiled as far as its
    numbers ``num`` (:func:`bgc.compiler.numerics.derive`; module docstring).

    Raises
    ------
    CodegenError
        The model has modes; an element reads a bond variable outside its
        submodel; a submodel does not compile (its message names it).
    """
    c = _Whole(raw, num)
    model = c.model
    refuse_modes(model)
    if not model.measurements:
        raise CodegenError(f"model {model.name} has no sensors: --decompose cuts a model at its sensors",
                           model.source, "add a measurement, or drop --decompose")
    storages = {el.name for el in model.elements if element_kind(el.kind).role == "storage"}
    uncut: set[str] = set()
    while True:  # a submodel without a storage (a static relation among readings): its sensors cut nothing
        graph = _Graph(model, uncut)
        subs = _split(model, graph)
        static = next((sensors for sensors, nodes, _, _ in subs if not nodes & storages), None)
        if static is None:
            break
        if set(static) <= uncut:  # cut nothing already: its part of the plant holds no storage at all
            m = next(m for m in model.measurements if m.name == static[0])
            raise CodegenError(f"--decompose: the part of the plant sensor {static[0]} reads holds no storage "
                               "element, so it has no submodel", m.loc, "drop --decompose")
        uncut |= set(static)
    return Decomposition(model.name, tuple(_submodel(c, graph, *s) for s in subs))


def nominal_text(raw: RawModel) -> str:
    """The whole model's file without its faults (the model read as
    ``raw``): the plant's nominal filter, which the decomposed diagnosis's
    detector runs on (:mod:`bgc.diagnosis.decomposed`), generated without
    the fault models that make the whole plant's package large."""
    data = {key: value for key, value in raw.data.items() if key != "faults"}
    head = (f"# {data.get('name', 'the model')} ({raw.path}) without its faults, written by bgc for the "
            "decomposed diagnosis's detector.\n")
    return _text(head, data)


def refuse_modes(model) -> None:
    """The one-line error for a model with modes (--decompose takes a model of one mode)."""
    if model.modes is not None:
        raise CodegenError(f"model {model.name} has modes: --decompose takes a model of one mode", model.source,
                           "drop --decompose")


def _split(model, graph: "_Graph") -> list[list]:
    """Each submodel as [its sensors, its nodes, its bonds, its boundary]."""
    subs = []
    placed: set[str] = set()
    for key, sensors in graph.cut_groups().items():
        nodes, inside, boundary = graph.reach(key)
        subs.append([sensors, nodes, inside, boundary])
        placed.update(sensors)
    for m in model.measurements:  # the sensors of an expression: the first submodel holding its bonds, or its own
        if m.name in placed:
            continue
        bonds = _bonds_of(m.expr)
        home = next((s for s in subs if bonds <= s[2]), None)
        if home is not None:
            home[0] = home[0] + (m.name,)
            continue
        ends = frozenset(n for k in bonds for n in graph.bonds[k])
        nodes, inside, boundary = graph.reach(None, ends)
        subs.append([(m.name,), nodes, inside, boundary])
    return subs


def _bonds_of(expr) -> frozenset:
    return _bonds_of_names({s.name for s in getattr(expr, "free_symbols", ())})


def _bonds_of_names(names) -> frozenset:
    return frozenset(int(h.group(2)) for h in map(_BOND_VARIABLE.fullmatch, names) if h)


class _Graph:
    """The bond graph as nodes and bonds, each sensor's cut found, bonds a
    sensor cuts split by a two-port junction (its second half numbered
    after the model's last bond)."""

    def __init__(self, model, uncut: set[str] = frozenset()):
        self.model = model
        self.uncut = uncut
        self.kind = {el.name: el.kind for el in model.elements}
        self.bonds = {b.number: (b.tail, b.head) for b in model.bonds}
        self.virtual: dict[str, str] = {}  # two-port junction -> the measured variable it cuts
        self.cut_of: dict[str, Any] = {}   # node -> its cut's key
        self.reading: dict[Any, str] = {}  # cut key -> the sensor its neighbours read
        self.measured: dict[Any, str] = {}  # cut key -> "e" or "f"
        self.next_bond = max(self.bonds, default=0) + 1
        self.links: dict | None = None  # :meth:`reach`'s adjacency, once the cuts are made

    def _adjacent(self, signals: bool = False) -> dict[str, list[tuple[int, str, bool]]]:
        """Each node's bonds and the nodes at their other ends (and False);
        with ``signals``, also an element's signal links: the ends of each
        bond whose variable its law reads (and True; one way: what it reads
        moves it)."""
        adj: dict[str, list[tuple[int, str, bool]]] = {n: [] for n in self.kind}
        for k, (t, h) in self.bonds.items():
            adj[t].append((k, h, False))
            adj[h].append((k, t, False))
        if signals:
            for el in self.model.elements:
                for k in sorted(_bonds_of_names(_free_names(el))):
                    adj[el.name] += [(k, n, True) for n in self.bonds[k] if n != el.name]
        return adj

    def cut_groups(self) -> dict[Any, tuple[str, ...]]:
        """Each cut's key -> the sensors on it, in the model's order."""
        starts = []  # per sensor that cuts: (sensor, "e" or "f", its junction)
        for m in self.model.measurements:
            s = m.expr
            hit = _BOND_VARIABLE.fullmatch(s.name) if isinstance(s, sympy.Symbol) else None
            if hit is None or m.name in self.uncut:
                continue
            var, k = hit.group(1), int(hit.group(2))
            junction = "0" if var == "e" else "1"
            t, h = self.bonds[k]
            start = next((n for n in (t, h) if self.kind[n] == junction), None)
            if start is None:  # the bond itself is cut: a two-port junction in its middle
                start = f"{var}{k}_cut"
                while start in self.kind:
                    start += "_"
                self.kind[start] = junction
                self.virtual[start] = f"{var}{k}"
                self.bonds[k] = (start, h)  # the head's half keeps the number (a storage's bond: its state's name)
                self.bonds[self.next_bond] = (t, start)
                self.next_bond += 1
            starts.append((m.name, var, start))
        adj = self._adjacent()  # the bonds as cut (a two-port junction joins no other of its kind)
        groups: dict[Any, tuple[str, ...]] = {}
        for name, var, start in starts:
            if start in self.cut_of:
                groups[self.cut_of[start]] += (name,)
                continue
            members, todo = {start}, [start]
            while todo:  # the same-kind junctions bonded to it share its effort (flow)
                n = todo.pop()
                for _, o, _ in adj[n]:
                    if o not in members and self.kind[o] == self.kind[start]:
                        members.add(o)
                        todo.append(o)
            key = frozenset(members)
            for n in members:
                self.cut_of[n] = key
            self.reading[key] = name
            self.measured[key] = var
            groups[key] = (name,)
        return groups

    def reach(self, key, seeds: Iterable[str] = ()) -> tuple[frozenset, frozenset, tuple]:
        """The nodes reached from cut ``key`` (or from ``seeds``, their cuts
        kept whole) without crossing another cut; the bonds among them; the
        bonds to another cut, as (bond, the node inside, the cut's key)."""
        start = set(key) if key is not None else set()
        for n in seeds:
            start |= set(self.cut_of.get(n, {n}))
        own = {self.cut_of[n] for n in start if n in self.cut_of}
        if self.links is None:  # the bonds and signal links as cut, the same for every submodel
            self.links = self._adjacent(signals=True)
        adj = self.links
        nodes, todo, boundary = set(start), list(start), []
        while todo:
            n = todo.pop()
            for k, o, signal in adj[n]:
                if o in nodes:
                    continue
                if signal and any(e in self.cut_of and self.cut_of[e] not in own for e in self.bonds[k]):
                    continue  # a law reads a measured bond of another cut: refused by the caller, by name
                cut = self.cut_of.get(o)
                if cut is not None and cut not in own:
                    if not signal:  # a power bond to another cut
                        boundary.append((k, n, cut))
                    continue
                nodes.add(o)
                todo.append(o)
        inside = frozenset(k for k, (t, h) in self.bonds.items() if t in nodes and h in nodes)
        return frozenset(nodes), inside, tuple(sorted(set(boundary), key=lambda b: b[0]))


def _free_names(el) -> set[str]:
    names = set()
    for e in (el.parameter, el.source, el.law.expr if el.law else None):
        if e is not None:
            names |= {s.name for s in e.free_symbols}
    return names


def _submodel(c: _Whole, graph: _Graph, sensors: tuple[str, ...], nodes: frozenset, inside: frozenset,
              boundary: tuple) -> Submodel:
    model, raw = c.model, c.raw.data
    name = _fit(f"{model.name}_{sensors[0]}")
    elements = {el.name: el for el in model.elements}
    measurements = {m.name: m for m in model.measurements}
    parameters = {p.name for p in model.parameters}
    inputs = {i.name for i in model.inputs}
    bond_numbers = {k for k in inside} | {b[0] for b in boundary}
    used: set[str] = set()
    substitute: dict[str, dict[str, str]] = {}  # element -> its law's bond variable -> the sensor that reads it
    for n in sorted(nodes):
        if n in graph.virtual:
            continue
        names = _free_names(elements[n])
        for v in sorted(names, key=lambda v: (len(v), v)):
            hit = _BOND_VARIABLE.fullmatch(v)
            if not hit or int(hit.group(2)) in bond_numbers:
                continue
            k = int(hit.group(2))
            cut = next((graph.cut_of[e] for e in graph.bonds[k] if e in graph.cut_of
                        and graph.measured[graph.cut_of[e]] == hit.group(1)), None)
            if cut is None:
                raise CodegenError(f"--decompose: element {n} reads bond {k}, outside the submodel of sensor "
                                   f"{sensors[0]}", elements[n].loc,
                                   "measure that bond variable, or diagnose the model whole: drop --decompose")
            substitute.setdefault(n, {})[v] = graph.reading[cut]  # a measured variable: the law reads the sensor
        used |= names - set(substitute.get(n, {}))
    for s in sensors:
        used |= {x.name for x in measurements[s].expr.free_symbols}
    reads = tuple(dict.fromkeys([graph.reading[cut] for _, _, cut in boundary]
                                + [r for each in substitute.values() for r in each.values()]))
    taken = parameters | inputs | set(graph.kind) | set(measurements)
    read_as = {r: _input_name(r, taken) for r in reads}
    num = c.numerics
    extremes = None  # a reading that starts at 0: the plant's signed extreme over its nominal run
    at = {}
    for sensor, v in zip(c.equations.outputs, num.y0):
        if v == 0.0 and extremes is None:
            extremes = dict(zip(c.equations.outputs, numerics.nominal_extremes(c.equations, num.substeps)))
        at[sensor] = v if v != 0.0 else extremes[sensor]
    initial = dict(zip(c.equations.state_elements, c.equations.initial))

    data: dict[str, Any] = {"name": name,
                            "description": f"submodel of {model.name} predicting {', '.join(sensors)}"
                                           + (f" from {', '.join(reads)}" if reads else "")}
    if "domain" in raw:
        data["domain"] = raw["domain"]
    data["parameters"] = {p: raw["parameters"][p] for p in raw.get("parameters", {}) if p in used & parameters}
    data["inputs"] = {i: raw["inputs"][i] for i in raw.get("inputs", {}) if i in used & inputs}
    for r in reads:
        m = measurements[r]
        entry: dict[str, Any] = {"signal": "constant", "value": _number(at[r]),
                                 "description": f"sensor {r} of {model.name}, read as an input"}
        if m.unit:
            entry["unit"] = m.unit
        data["inputs"][read_as[r]] = entry
    if not data["inputs"]:
        del data["inputs"]
    if not data["parameters"]:
        del data["parameters"]
    els: dict[str, Any] = {}
    for n in [e.name for e in model.elements if e.name in nodes] + [v for v in graph.virtual if v in nodes]:
        if n in graph.virtual:
            els[n] = {"kind": graph.kind[n], "description": f"where sensor {graph.reading[graph.cut_of[n]]} "
                      f"reads {graph.virtual[n]}"}
            continue
        entry = dict(raw["elements"][n])
        for key in ("value", "law", "parameter"):
            for v, r in substitute.get(n, {}).items():
                if isinstance(entry.get(key), str):
                    entry[key] = re.sub(rf"(?<![\w.]){v}(?![\w.])", read_as[r], entry[key])
        if n in initial:
            entry["initial"] = _number(initial[n])
        els[n] = entry
    data["elements"] = els
    data["bonds"] = _sourced(graph, els, boundary, bond_numbers, read_as)
    data["measurements"] = {s: _entry(raw["measurements"][s]) for s in sensors}
    faults = _faults(raw.get("faults", {}), used & (parameters | inputs) | set(sensors), read_as)
    if faults:
        data["faults"] = faults
    if "simulation" in raw:
        data["simulation"] = dict(raw["simulation"])
    head = (f"# A submodel of {model.name} ({model.display_source}), written by bgc compile --decompose:\n"
            f"# it predicts {', '.join(sensors)}" + (f" and reads {', '.join(reads)} as inputs" if reads else "")
            + ".\n")
    _noise_levels(c, data, read_as, head)
    text = _text(head, data)
    seen = tuple(s for s in faults if s not in read_as.values()) + tuple(r for r in reads if read_as[r] in faults)
    return Submodel(name, tuple(sensors), reads, tuple(sorted(used & inputs)),
                    tuple(n for n in els if n in elements), seen, text, tuple(read_as.items()))


def _sourced(graph: _Graph, els: dict, boundary: tuple, bond_numbers: set[int], read_as: dict[str, str]) -> dict:
    """The submodel's bonds, each bond to another cut ending at a source of
    that cut's reading (added to ``els``; the bond keeps its direction)."""
    sources = {}
    for k, inner, cut in boundary:
        src = _fit(f"{graph.reading[cut]}_at_{k}")
        while src in els or src in graph.kind:
            src += "_"
        sources[k] = (src, inner)
        els[src] = {"kind": "Se" if graph.measured[cut] == "e" else "Sf", "value": read_as[graph.reading[cut]],
                    "description": f"sensor {graph.reading[cut]}'s reading"}
    bonds = {}
    for k in sorted(bond_numbers):
        t, h = graph.bonds[k]
        if k in sources:
            src, inner = sources[k]
            t, h = (inner, src) if t == inner else (src, inner)
        bonds[str(k)] = [t, h]
    return bonds


def _faults(declared: dict, kept: set[str], read_as: dict[str, str]) -> dict:
    """The model file's faults a submodel keeps: those of ``kept``
    (its parameters, inputs and sensors), and of each sensor it reads the
    kinds an input takes, as that input's."""
    faults = {}
    for subject, entry in declared.items():
        if subject in kept:
            faults[subject] = entry
        elif subject in read_as:
            kinds = entry if isinstance(entry, list) else entry.get("kinds", [])
            taken = [k for k in kinds if k in _AS_INPUT]
            if taken:
                faults[read_as[subject]] = taken if isinstance(entry, list) else {**entry, "kinds": taken}
    return faults


def _text(head: str, data: dict) -> str:
    """The submodel's file: ``head`` (comment lines), then ``data`` as YAML,
    a line per element, bond and measurement (adding a key to one of them
    moves no line)."""
    return head + yaml.safe_dump(data, sort_keys=False, width=120, allow_unicode=True, default_flow_style=None)


def _fit(name: str) -> str:
    """``name`` within the 64 characters a model's names may have (a hash
    of the rest keeps it unique)."""
    if len(name) <= LONGEST:
        return name
    return f"{name[:LONGEST - 9]}_{hashlib.sha256(name.encode()).hexdigest()[:8]}"


def _entry(entry) -> dict:
    """A measurement's entry of the model file as a mapping (written ``F: f3`` or ``f2:`` alone)."""
    return {} if entry is None else {"expr": entry} if isinstance(entry, str) else dict(entry)


def _input_name(sensor: str, taken: set[str]) -> str:
    """The input a sensor's reading is in a submodel: its own name, unless
    that names a bond variable (a sensor called ``e11``) or something else."""
    name = sensor if not _BOND_VARIABLE.fullmatch(sensor) else _fit(f"{sensor}_reading")
    while name != sensor and name in taken:
        name += "_"
    return name


def _noise_levels(c: _Whole, data: dict, read_as: dict[str, str], head: str) -> None:
    """Write each storage's and each sensor's noise level (in place) so that
    the submodel's absolute noise stds are the whole model's, each storage's
    raised by the noise its read sensors carry into it (module docstring):
    the levels are fractions of a signal's scale, and a submodel's scales
    (from its own nominal run) need not be the whole plant's."""
    from . import causality, dbn, equations, load, tcg, validate

    sub = validate.validate(load.loads(_text(head, data), f"submodels/{data['name']}.yaml"))
    ssm = equations.derive(tcg.build(causality.assign(sub)))
    num = numerics.derive(dbn.build(ssm))
    whole = c.numerics
    noise = whole.noise
    sigma = dict(zip(c.equations.outputs, noise.measurement))
    own = dict(zip(c.equations.state_elements, noise.process))
    point = {sym(p): v for p, v in zip(ssm.parameters, ssm.parameter_values)}
    point.update({sym(i.name): v for i, v in zip(sub.inputs, num.u0)})
    point.update({sym(x): v for x, v in zip(ssm.states, ssm.initial)})
    dt = sub.settings.dt
    slopes = numerics.jacobian_at(list(ssm.rhs), [sym(a) for a in read_as.values()], point)  # d rates / d readings
    for i, el in enumerate(ssm.state_elements):
        extra = math.sqrt(sum((slopes[i, k] * sigma[r] * dt) ** 2 for k, r in enumerate(read_as)))
        scale = num.x_scale[i] * num.process_factor[i]
        data["elements"][el]["noise"] = _number(float(np.hypot(own[el], extra)) / scale)
    for name, scale in zip(ssm.outputs, num.y_scale):
        entry = _entry(data["measurements"][name])
        data["measurements"][name] = {**entry, "noise": _number(sigma[name] / scale)}


def _number(v: float) -> float:
    """``v`` to 10 significant digits (the file stays readable, the value exact enough)."""
    return float(f"{float(v):.10g}")

