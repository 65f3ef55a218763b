"""Stage 2: :class:`~bgc.ir.RawModel` -> :class:`~bgc.ir.BondGraph`.

First the document is checked against the JSON Schema in
``schemas/bondgraph.schema.json`` (draft 2020-12); then semantic rules that a
schema cannot say are checked: bonds name existing elements, junctions have at
least two bonds, one-ports exactly one, two-ports one bond in and one out, names
are Python identifiers that are not keywords or reserved, expressions use only
declared names, measurements and faults name things that exist, and there is at
least one storage element. All errors are collected and reported together, each
as ``file:line:col: what (how to fix)``.
"""

from __future__ import annotations

import builtins
import json
import keyword
import math
import re
import sys
from functools import lru_cache
from importlib import resources
from typing import Any, Iterable, Iterator

import jsonschema
import yaml
import sympy

from . import expressions, load, modes
from ..errors import BgcError, ErrorGroup, ExpressionError, ValidationError, printable
from ..kinds import ELEMENT_KINDS, element_kind, fault_kind, kinds_for
from ..ir import (
    Bond, BondGraph, Element,
    FaultCandidate, Input, Law, Measurement, Parameter, RawModel, SWITCH_FAULTS, Settings, Signal, effort, flow, sym,
)

#: The JSON Schema of model files ships inside the package (``bgc/schema/``);
#: ``schemas/bondgraph.schema.json`` at the top of the repository is its
#: published copy (a test checks they are identical).
SCHEMA_RESOURCE = ("bgc", "schema/bondgraph.schema.json")
KINDS = tuple(ELEMENT_KINDS)
_BOND_VARIABLE = re.compile(r"^[ef][0-9]+$")
#: Names generated code and expressions use for themselves.
RESERVED = frozenset({
    "np", "numpy", "math", "x", "u", "y", "t", "dt", "theta", "rng", "logw", "N", "self",
    "e", "f", "pi", *expressions.FUNCTIONS,
}) | frozenset(dir(builtins))


@lru_cache(maxsize=1)
def schema() -> dict:
    """The JSON Schema of model files."""
    package, name = SCHEMA_RESOURCE
    return json.loads(resources.files(package).joinpath(name).read_text(encoding="utf-8"))


def validate(raw: RawModel) -> BondGraph:
    """Check a raw model and build the :class:`BondGraph`.

    Raises
    ------
    ErrorGroup
        Every schema and semantic error found, sorted by location.
    """
    return _Validator(raw).run()



def _integer(checker, value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _finite_number(checker, value) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return isinstance(value, int) or math.isfinite(value)


def strict_validator(data_schema: dict, finite: bool = False) -> jsonschema.protocols.Validator:
    """A JSON Schema (2020-12) validator for data read from YAML, stricter
    than the standard's types: an ``integer`` is an integer as written
    (``3.0`` is a number, not an integer: it would reach ``range()`` or a
    seed), and with ``finite`` a ``number`` is finite (``.nan`` and ``.inf``
    pass every bound otherwise).

    >>> strict_validator({"type": "integer"}).is_valid(3.0), strict_validator({"type": "number"}, True).is_valid(float("nan"))
    (False, False)
    """
    checker = jsonschema.Draft202012Validator.TYPE_CHECKER.redefine("integer", _integer)
    if finite:
        checker = checker.redefine("number", _finite_number)
    cls = jsonschema.validators.extend(jsonschema.Draft202012Validator, type_checker=checker)
    return cls(data_schema)

#: What each kind of input signal needs besides its value (docs/format.md, inputs).
SIGNAL_NEEDS = {"constant": (), "step": ("final", "start"), "ramp": ("slope",), "sine": ("amplitude", "period"),
                "square": ("amplitude", "period"), "prbs": ("amplitude", "period"),
                "chirp": ("amplitude", "f0", "f1", "duration")}
#: What a kind of signal may also be given (a default otherwise).
SIGNAL_OPTIONS = {"square": ("duty",), "prbs": ("seed",)}
#: Every field of a signal.
SIGNAL_FIELDS = ("value", "start", "final", "slope", "amplitude", "period", "duty", "seed", "f0", "f1", "duration")


def _element_fault_fix(element, pnames: set[str], kinds) -> str:
    """How to name the fault of an element: by the parameters its own
    parameter or law is written in (``spring2: {parameter: 1/k2}`` -> ``k2``)."""
    used = set()
    for expr in (element.parameter, element.source):
        if expr is not None:
            used |= {str(x) for x in expr.free_symbols}
    if element.law is not None:
        used |= {str(x) for x in getattr(element.law.expr, "free_symbols", ())}
    names = sorted(used & pnames)
    shown = "[" + ", ".join(map(str, kinds)) + "]" if isinstance(kinds, list) else \
        kinds if isinstance(kinds, str) else "[abrupt]"
    if not names and element.kind in ("0", "1"):
        return "a junction has no parameter: name a parameter of an element (a fault is on a declared parameter)"
    if not names:
        return (f"a fault is on a declared parameter: give {element.name}'s value a parameter under "
                f"'parameters' and name that")
    written = f" (its parameter is {element.parameter})" if element.parameter is not None else ""
    return f"a fault is on a parameter{written}: write '{names[0]}: {shown}'" + (
        f" (or another of {', '.join(names)})" if len(names) > 1 else "")


def _signal_range(kind: str, spec: dict) -> str | None:
    """What is out of range in an input signal's fields (None: nothing)."""
    for key in ("period", "duration"):
        if key in spec and not spec[key] > 0:
            return f"a {kind} signal's {key} must be above 0, not {spec[key]!r}"
    for key in ("f0", "f1"):
        if key in spec and not spec[key] >= 0:
            return f"a chirp's {key} is a frequency, 0 or above, not {spec[key]!r}"
    if "duty" in spec and not 0 < spec["duty"] < 1:
        return f"a square signal's duty is the fraction of a period it is high, between 0 and 1, not {spec['duty']!r}"
    if "seed" in spec and not (isinstance(spec["seed"], int) and not isinstance(spec["seed"], bool)
                               and 1 <= spec["seed"] <= 511):
        return f"a prbs signal's seed starts its shift register: an integer from 1 to 511, not {spec['seed']!r}"
    return None


def input_signal(spec: dict) -> Signal | tuple[str, str]:
    """The signal an input's mapping declares (the schema passed), or what
    is wrong with it and the fix: (what, fix)."""
    kind = spec.get("signal", "constant")
    missing = [k for k in SIGNAL_NEEDS[kind] if k not in spec]
    if missing:
        return f"a {kind} signal needs {', '.join(missing)}", f"add {', '.join(k + ': <number>' for k in missing)}"
    unused = sorted(k for k in spec if k in SIGNAL_FIELDS and k not in SIGNAL_NEEDS[kind]
                    and k not in SIGNAL_OPTIONS.get(kind, ()) and k not in ("value", "start"))
    if unused:
        return (f"a {kind} signal takes no {', '.join(unused)}",
                f"remove {', '.join(unused)}, or choose the signal that takes it (docs/format.md, inputs)")
    wrong = _signal_range(kind, spec)
    if wrong:
        return wrong, "see docs/format.md, inputs"
    number = lambda key: float(spec[key]) if key in spec else None  # noqa: E731
    return Signal(kind, float(spec["value"]), final=number("final"),
                  start=float(spec.get("start", 0.0)) if kind != "constant" else None,
                  slope=number("slope"), amplitude=number("amplitude"), period=number("period"),
                  duty=float(spec.get("duty", 0.5)) if kind == "square" else None,
                  seed=int(spec.get("seed", 1)) if kind == "prbs" else None,
                  f0=number("f0"), f1=number("f1"), duration=number("duration"))


def signal_option(text: str, inputs: tuple[str, ...], where: str = "--input") -> tuple[str, Signal]:
    """An input's signal given outside the model file, ``NAME=SPEC`` with SPEC
    written as in the model's ``inputs`` section (a number, or a flow
    mapping: ``u={signal: sine, value: 1, amplitude: 0.5, period: 4}``),
    checked by the same schema and rules; ``inputs``: the model's inputs.
    Raises :class:`~bgc.errors.BgcError` naming ``where`` and the fix."""
    name, eq, body = str(text).partition("=")
    name = name.strip()
    example = _signal_example(name or (inputs[0] if inputs else "u"), where)
    if not eq or not body.strip():
        raise BgcError(f"{where} {printable(text)!r} is not NAME=SIGNAL", None, f"write e.g. {example}")
    if name not in inputs:
        signal_given(name, None, inputs, where)  # the error
    try:
        spec = yaml.safe_load(body)
    except yaml.YAMLError as e:
        raise BgcError(f"{where} {printable(name)}: the signal is not YAML ({printable(str(e).splitlines()[0])})",
                       None, f"write e.g. {example}") from None
    return name, signal_given(name, spec, inputs, where)


def _signal_example(name: str, where: str) -> str:
    """A signal written for input ``name`` as the place ``where`` takes it: ``--input NAME=...`` or ``NAME: ...``."""
    return (f"{where} {name}=" if where.startswith("--") else f"{name}: ") \
        + "{signal: sine, value: 1, amplitude: 0.5, period: 4}"


def signal_given(name: str, spec: Any, inputs: tuple[str, ...], where: str = "inputs") -> Signal:
    """Input ``name``'s signal given as data (a number, a mapping as in the
    model's ``inputs`` section, or a :class:`~bgc.ir.Signal`), checked as
    the model's are; errors name ``where``."""
    example = _signal_example(name, where)
    if name not in inputs:
        raise BgcError(f"{where}: {printable(str(name))!r} is not an input of the model", None,
                       f"its inputs: {', '.join(inputs) or 'none'}")
    if isinstance(spec, Signal):
        return spec
    if not isinstance(spec, dict):
        spec = {"value": spec}
    validator = strict_validator(schema()["$defs"]["input"] | {"$defs": schema()["$defs"]}, finite=True)
    errors = sorted(validator.iter_errors(spec), key=lambda e: list(e.absolute_path))
    if errors:
        where_ = ".".join(str(p) for p in errors[0].absolute_path) or "the signal"
        raise BgcError(f"{where} {printable(name)}: {printable(where_)}: {printable(errors[0].message)}", None,
                       f"write e.g. {example} (docs/format.md, inputs)")
    signal = input_signal(spec)
    if isinstance(signal, tuple):
        raise BgcError(f"{where} {printable(name)}: {signal[0]}", None, signal[1])
    return signal


class _Validator:
    def __init__(self, raw: RawModel):
        self.raw = raw
        self.errors: list[BgcError] = []
        self.bad_paths: set[tuple] = set()
        self.dropped_ends: set[str] = set()  # elements at the end of a bond refused with an error

    # ------------------------------------------------------------------ helpers
    def error(self, what: str, path: tuple, fix: str | None = None, key: bool = False) -> None:
        loc = self.raw.key_loc(*path) if key else self.raw.loc(*path)
        self.errors.append(ValidationError(what, loc, fix))

    def bad(self, path: tuple) -> bool:
        """Whether the schema found an error in the node at ``path``, inside it or around it."""
        # a root-level error (an unknown section) does not make every node bad
        return any((p and path[: len(p)] == p) or p[: len(path)] == path for p in self.bad_paths)

    def expr(self, text: Any, names: Iterable[str], path: tuple, where: str) -> sympy.Expr | None:
        try:
            return expressions.parse(text, frozenset(names), self.raw.loc(*path), where)
        except ExpressionError as exc:
            self.errors.append(exc)
            return None

    # -------------------------------------------------------------------- run
    def run(self) -> BondGraph:
        data = self.raw.data
        if not isinstance(data, dict):
            raise ErrorGroup([ValidationError("the model must be a mapping of sections", self.raw.loc(),
                                              "start with 'name:', 'elements:' and 'bonds:'")])
        self.check_schema(data)
        if any(not isinstance(data.get(k), dict) for k in ("elements", "bonds")) or not isinstance(data.get("name"), str):
            raise ErrorGroup(self.errors)
        model = self.build(data)
        if self.errors:
            raise ErrorGroup(self.errors)
        return model

    def check_schema(self, data: dict) -> None:
        validator = strict_validator(schema())
        # .inf, .nan, 1.0e+400 and integers beyond the float range pass "type: number" (and
        # .nan every bound): they are refused here, at each number of the model.
        non_finite = dict(_non_finite(data))
        unknown: set[tuple] = set()  # keys the schema refuses as unknown: nothing under them is checked
        for err in validator.iter_errors(data):
            path = tuple(err.absolute_path)
            if "propertyNames" in err.absolute_schema_path:
                path = path + (err.instance,)  # the offending key itself
            self.bad_paths.add(path)
            if path in non_finite:
                if err.validator in _RANGE or (err.validator == "type" and _wants_number(err.validator_value)):
                    continue  # said below: the number is not finite
                del non_finite[path]  # e.g. 'name: .inf': the schema says better what is wrong
            what, fix, key = _schema_message(err, path)
            where = path
            if err.validator == "additionalProperties" and isinstance(err.instance, dict):
                extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
                unknown.update(path + (k,) for k in extra)
                if extra:  # point at the unknown key, not at the mapping holding it
                    where, key = path + (extra[0],), True
            self.error(what, where, fix, key=key)
        for path, what in non_finite.items():
            if any(path[:i] in unknown for i in range(1, len(path) + 1)):
                continue
            self.bad_paths.add(path)
            self.error(f"{_where(path)} is {what}", path,
                       "write a finite number, at most 1.8e308 in magnitude")

    # ------------------------------------------------------------------ build
    def build(self, data: dict) -> BondGraph:
        if keyword.iskeyword(data["name"]) or keyword.issoftkeyword(data["name"]):
            self.error(f"model name '{data['name']}' is a Python keyword", ("name",), "rename the model")
        parameters = self.parameters(_section(data, "parameters"))
        inputs = self.inputs(_section(data, "inputs"))
        for name in sorted({p.name for p in parameters} & {i.name for i in inputs}):
            self.error(f"'{name}' is both a parameter and an input", ("inputs", name),
                       "rename one of them", key=True)
        # A parameter or input refused above still counts as declared, so its error is
        # reported once and not again at every use (no model is built when errors exist).
        pnames = {str(k) for k in _section(data, "parameters")}
        inames = {str(k) for k in _section(data, "inputs")}
        bonds = self.bonds(data["bonds"])
        raw_elements = data["elements"]
        variables = {n for b in bonds for n in (effort(b.number), flow(b.number))}
        elements = self.elements(raw_elements, bonds, pnames, inames, variables,
                                 {p.name: p.value for p in parameters})
        self.topology(elements, bonds)
        settings = self.settings(_section(data, "simulation"))
        measurements = self.measurements(_section(data, "measurements"), pnames | inames | variables,
                                         variables, pnames | inames, settings.measurement_noise)
        faults = self.faults(_section(data, "faults"), pnames, measurements, inames,
                             pnames | inames | {str(m) for m in _section(data, "measurements")}, elements)
        hybrid = modes.read(self, data, elements, bonds, pnames | inames | variables,
                            {m.name: m.expr for m in measurements}, {p.name: p.value for p in parameters})
        return BondGraph(
            name=data["name"],
            description=str(data.get("description", "")),
            source=self.raw.path,
            parameters=parameters,
            elements=elements,
            bonds=bonds,
            inputs=inputs,
            measurements=measurements,
            faults=faults,
            settings=settings,
            source_sha256=self.raw.sha256,
            domain=data.get("domain"),
            modes=hybrid,
        )

    def name_ok(self, name: str, path: tuple, what: str) -> bool:
        if not isinstance(name, str) or not name.isidentifier():
            self.error(f"{what} name '{name}' is not a Python identifier", path,
                       "use letters, digits and underscores, not starting with a digit", key=True)
            return False
        if keyword.iskeyword(name) or keyword.issoftkeyword(name):
            self.error(f"{what} name '{name}' is a Python keyword", path, "rename it, e.g. " + name + "_", key=True)
            return False
        if name in RESERVED or name.startswith(("_", "delta_")):
            self.error(f"{what} name '{name}' is reserved for generated code", path,
                       "rename it, e.g. " + name.strip("_") + "_1", key=True)
            return False
        return True

    def expression_name_ok(self, name: str, path: tuple, what: str) -> bool:
        """A name expressions use (parameter, input): an identifier, and not a bond variable."""
        if not self.name_ok(name, path, what):
            return False
        if _BOND_VARIABLE.match(name):
            self.error(f"{what} name '{name}' looks like a bond variable", path,
                       "names e<N> and f<N> are the efforts and flows of bonds: rename it", key=True)
            return False
        return True

    def parameters(self, raw: dict) -> tuple[Parameter, ...]:
        out = []
        for name in sorted(raw):
            path = ("parameters", name)
            if self.bad(path) or not self.expression_name_ok(name, path, "parameter"):
                continue
            spec = raw[name]
            if isinstance(spec, dict):
                out.append(Parameter(name, float(spec["value"]), spec.get("unit"), spec.get("description"),
                                     self.raw.key_loc(*path)))
            else:
                out.append(Parameter(name, float(spec), None, None, self.raw.key_loc(*path)))
        return tuple(out)

    def inputs(self, raw: dict) -> tuple[Input, ...]:
        out = []
        for name in sorted(raw):
            path = ("inputs", name)
            if self.bad(path) or not self.expression_name_ok(name, path, "input"):
                continue
            spec = raw[name]
            if not isinstance(spec, dict):
                spec = {"value": spec}
            signal = input_signal(spec)
            if isinstance(signal, tuple):
                self.error(f"input {name}: {signal[0]}", path, signal[1])
                continue
            out.append(Input(name, signal, spec.get("unit"), spec.get("description"), self.raw.key_loc(*path)))
        return tuple(out)

    def bonds(self, raw: dict) -> tuple[Bond, ...]:
        out = []
        for key in sorted(raw, key=lambda k: (len(k), k)):
            path = ("bonds", key)
            if self.bad(path):
                if isinstance(raw[key], list):  # its ends lose a bond: do not also report their port counts
                    self.dropped_ends.update(end for end in raw[key] if isinstance(end, str))
                continue
            tail, head = raw[key]
            number = int(key)
            if tail == head:
                self.error(f"bond {number} connects {tail} to itself", path, "a bond joins two different elements")
                self.dropped_ends.add(tail)
                continue
            out.append(Bond(number, tail, head, self.raw.key_loc(*path)))
        return tuple(out)

    def elements(self, raw: dict, bonds: tuple[Bond, ...], pnames: set[str], inames: set[str],
                 variables: set[str], pvalues: dict[str, float] | None = None) -> tuple[Element, ...]:
        out = []
        ports = _ports(bonds)
        for name in sorted(raw):
            path = ("elements", name)
            if self.bad(path) or not self.name_ok(name, path, "element"):
                continue
            spec = raw[name]
            kind = spec["kind"]
            if not isinstance(kind, str):  # the schema lets 0 and 1 through (and 1.0, which equals 1)
                if isinstance(kind, int) and not isinstance(kind, bool):
                    kind = str(kind)
                else:
                    self.error(f"element kind {kind!r} of {name} is not a kind name", path + ("kind",),
                               f"write kind: \"{int(kind)}\" for a junction" if kind in (0, 1) else
                               "valid kinds: " + ", ".join(KINDS))
                    continue
            keys = element_kind(kind).keys
            role = element_kind(kind).role
            extra = sorted(set(spec) - {"kind", "description"} - keys)
            if extra:
                allowed = sorted(keys | {"kind", "description"})
                self.error(f"element {name} of kind {kind} has no key '{extra[0]}'", path + (extra[0],),
                           f"keys of {_article(kind)}: {', '.join(allowed)}", key=True)
                continue
            mine = ports.get(name, [])
            own = {}
            if len(mine) == 1:
                own = {"e": effort(mine[0].number), "f": flow(mine[0].number)}
            parameter = law = source = None
            loc = self.raw.key_loc(*path)
            if role == "source":
                text = spec.get("value", name if name in inames else None)
                if text is None:
                    self.error(f"source {name} has no value", path,
                               f"add 'value: <expression>' or declare an input named {name}")
                    continue
                names = pnames | inames | variables
                source = self.expr(text, names, path + ("value",), f"value of {name}")
                if source is None or not self.unmodulated(name, kind, source, variables, path + ("value",)):
                    continue
            elif role == "junction":
                pass
            elif "law" in spec:
                if own:  # else keep the element without its law: the port-count rule reports it
                    law = self.law(name, spec["law"], own, pnames | variables | inames, path + ("law",))
                    if law is None or not self.unmodulated(name, kind, law.expr,
                                                           (variables | inames) - set(own.values()), path + ("law",)):
                        continue
            else:
                text = spec.get("parameter", name if name in pnames else None)
                if text is None:
                    self.error(f"element {name} has no parameter", path,
                               f"declare a parameter named {name} or add 'parameter: <expression>'")
                    continue
                parameter = self.expr(text, pnames | variables | inames, path + ("parameter",),
                                      f"parameter of {name}")
                if parameter is None or not self.unmodulated(name, kind, parameter, variables | inames,
                                                             path + ("parameter",)):
                    continue
                if parameter.is_number and float(parameter) == 0.0:
                    self.error(f"element {name} has a zero parameter", path + ("parameter",),
                               "a zero coefficient removes the element: give a non-zero value")
                    continue
                at = {s: pvalues[s.name] for s in parameter.free_symbols if pvalues and s.name in pvalues}
                if at and len(at) == len(parameter.free_symbols):  # parameters only: its nominal value
                    try:
                        nominal = complex(sympy.N(parameter.xreplace(at)))
                    except (TypeError, ValueError):
                        nominal = complex("nan")
                    where = path + ("parameter",) if "parameter" in spec else ("parameters", str(parameter))
                    if not (math.isfinite(nominal.real) and math.isfinite(nominal.imag) and nominal.imag == 0):
                        self.error(f"parameter of {name} is not a finite real number at the nominal parameter "
                                   "values", where, "rescale the expression or the parameters",
                                   key=where[0] == "parameters")
                        continue
                    if nominal.real == 0.0:
                        self.error(f"the parameter of {element_kind(kind).title} {name} is 0 at the nominal "
                                   "values", where, f"give {name} a non-zero {_coefficient(kind)}; 0 removes the "
                                   "element or divides by zero", key=where[0] == "parameters")
                        continue
            initial = spec.get("initial")
            noise = spec.get("noise")
            out.append(Element(name, kind, parameter, law, source,
                               float(initial) if initial is not None else (0.0 if role == "storage" else None),
                               spec.get("description"), loc, float(noise) if noise is not None else None,
                               spec.get("quantity"), bool(spec.get("switch", False))))
        return tuple(out)

    def unmodulated(self, name: str, kind: str, expr: sympy.Expr, variables: set[str], path: tuple) -> bool:
        """Check that only a modulated kind (MSe, MR, ...) depends on the signals
        ``variables`` (bond variables, and inputs for non-sources)."""
        used = sorted({s.name for s in expr.free_symbols} & variables)
        if not used or element_kind(kind).modulated:
            return True
        modulated = [k for k, v in ELEMENT_KINDS.items() if v.modulated and v.base == kind]
        fix = (f"use kind {modulated[0]} for a modulated element" if modulated
               else f"a {kind} element is never modulated: use parameters only")
        what = "bond variable" if _BOND_VARIABLE.match(used[0]) else "input"
        self.error(f"{kind} element {name} depends on {what} {used[0]}", path, fix)
        return False

    def law(self, name: str, text: str, own: dict[str, str], names: set[str], path: tuple) -> Law | None:
        if text.count("=") != 1:
            self.error(f"law of {name} must have the form 'f = <expression of e>' or 'e = <expression of f>'", path,
                       "write exactly one '='")
            return None
        lhs, rhs = (s.strip() for s in text.split("="))
        if lhs not in ("e", "f"):
            self.error(f"law of {name} gives '{lhs}', not e or f", path, "write 'f = ...' or 'e = ...'")
            return None
        other = "f" if lhs == "e" else "e"
        expr = self.expr(rhs, names | {other}, path, f"law of {name}")
        if expr is None:
            return None
        expr = expr.xreplace({sym(other): sym(own[other])})
        return Law(own[lhs], expr, text, self.raw.loc(*path))

    def topology(self, elements: tuple[Element, ...], bonds: tuple[Bond, ...]) -> None:
        declared = set(self.raw.data["elements"])
        for b in bonds:
            for end in (b.tail, b.head):
                if end not in declared:
                    close = _closest(end, declared)
                    self.error(f"bond {b.number} names unknown element '{end}'", ("bonds", str(b.number)),
                               f"did you mean '{close}'?" if close else "declare it under 'elements'")
        ports_of = _ports(bonds)
        for el in elements:
            mine = ports_of.get(el.name, [])
            ports = element_kind(el.kind).ports
            path = ("elements", el.name)
            if el.name in self.dropped_ends:
                continue
            if ports is None and len(mine) < 2:
                self.error(f"junction {el.name} has {_bonds(len(mine))}, needs at least 2",
                           path, "connect it or remove it", key=True)
            elif ports == 1 and len(mine) != 1:
                self.error(f"{el.kind} element {el.name} has {_bonds(len(mine))}, needs exactly 1", path,
                           "a one-port element sits at the end of one bond: add a 0- or 1-junction", key=True)
            elif ports == 2:
                if len(mine) != 2:
                    self.error(f"{el.kind} element {el.name} has {_bonds(len(mine))}, needs exactly 2", path,
                               "a two-port has one bond in and one bond out", key=True)
                elif sum(b.head == el.name for b in mine) != 1:
                    self.error(f"{el.kind} element {el.name} needs one bond in and one bond out", path,
                               "reverse one of its bonds so power passes through it", key=True)
        if not any(element_kind(el.kind).role == "storage" for el in elements) and not self.errors:
            self.error("the model has no storage element (C or I)", ("elements",),
                       "a dynamic model needs at least one C or I", key=True)

    def measurements(self, raw: dict, names: set[str], variables: set[str],
                     declared: set[str], default_noise: float) -> tuple[Measurement, ...]:
        out = []
        for name in sorted(raw):
            path = ("measurements", name)
            if self.bad(path):
                continue
            spec = raw[name] or {}
            if "expr" in spec:
                if not self.name_ok(name, path, "measurement"):
                    continue
                if _BOND_VARIABLE.match(name) and str(spec["expr"]).strip() != name:
                    self.error(f"measurement name '{name}' is the name of a bond variable, but its expression is "
                               f"{str(spec['expr'])[:40]!r}", path,
                               f"rename the measurement (e.g. y_{name}), or measure {name} itself with '{name}:'",
                               key=True)
                    continue
                if name in declared:
                    self.error(f"measurement name '{name}' is already a parameter or input", path,
                               "rename the measurement", key=True)
                    continue
                text = spec["expr"]
            elif name in variables:
                text = name
            else:
                self.error(f"measurement '{name}' is not a bond variable of this model", path,
                           "name an existing e<N>/f<N> or give 'expr: <expression>'", key=True)
                continue
            expr = self.expr(text, names, path + ("expr",), f"measurement {name}")
            if expr is None:
                continue
            if not (expr.free_symbols & {sym(v) for v in variables}):
                self.error(f"measurement {name} does not depend on any bond variable", path,
                           "measure an effort or flow (e<N>, f<N>)", key=True)
                continue
            out.append(Measurement(name, expr, str(text), float(spec.get("noise", default_noise)), spec.get("unit"),
                                   spec.get("description"), self.raw.key_loc(*path),
                                   float(spec.get("residual_variance_sd", 0.0))))
        return tuple(out)

    def faults(self, raw: dict, pnames: set[str], measurements: tuple[Measurement, ...],
               inames: set[str], taken: set[str], elements=()) -> tuple[FaultCandidate, ...]:
        """The fault candidates: each entry names a parameter, a measurement
        (a sensor fault) or an input (an actuator fault), and expands into
        one candidate per symbol its kinds change (an input's ``bias`` and
        ``gain`` change two)."""
        targets = {**{n: "actuator" for n in inames}, **{m.name: "sensor" for m in measurements},
                   **{n: "parameter" for n in pnames}}
        out = []
        for name in sorted(raw):
            path = ("faults", name)
            if self.bad(path):
                continue
            target = targets.get(name)
            spec = raw[name]
            kinds = spec.get("kinds", ()) if isinstance(spec, dict) else spec
            switch = next((el for el in elements if el.name == name and el.switch), None)
            if switch is not None and all(k in SWITCH_FAULTS for k in kinds):
                continue  # a stuck switch: read with the modes (bgc.compiler.modes)
            stuck = [k for k in kinds if k in SWITCH_FAULTS]
            if stuck:
                self.error(f"fault kind '{stuck[0]}' is a switched junction's, and {name} is "
                           f"{'a switched junction with other kinds too' if switch else 'none'}", path + ("kinds",),
                           "give stuck_on, stuck_off, uncommanded_on and uncommanded_off to a junction with "
                           "'switch: true', and to nothing else")
                continue
            if target is None:
                element = next((el for el in elements if el.name == name), None)
                if element is not None:
                    self.error(f"fault names '{name}', an element ({element.kind}), not a parameter", path,
                               _element_fault_fix(element, pnames, raw[name]), key=True)
                    continue
                close = _closest(name, set(targets))
                self.error(f"fault names '{name}', which is no parameter, measurement or input", path,
                           f"did you mean '{close}'?" if close else
                           "a fault is on a declared parameter, a measurement (a sensor) or an input (an actuator)",
                           key=True)
                continue
            if not isinstance(spec, dict):
                spec = {"kinds": spec}
            wrong = [k for k in spec["kinds"] if target not in fault_kind(k).targets]
            if wrong:
                self.error(f"fault kind '{wrong[0]}' does not apply to {target} {name}", path + ("kinds",),
                           kinds_for(target))
                continue
            size, rate = (self._range(spec, key, path) for key in ("size", "rate"))
            direction = spec.get("direction") or _direction_of(size, rate)
            if not self._agrees(direction, size, rate, path):
                continue
            by: dict[str, list[str]] = {}
            for k in sorted(spec["kinds"]):
                by.setdefault(fault_kind(k).parameter_of(name), []).append(k)
            for parameter, kinds in sorted(by.items()):
                if parameter != name and parameter in taken:
                    self.error(f"'{parameter}' is already declared, and the {target} fault of {name} needs the name",
                               path, f"rename the parameter, input or measurement called {parameter}", key=True)
                    continue
                out.append(FaultCandidate(parameter, tuple(kinds), direction, float(spec.get("prior", 0.01)),
                                          self.raw.key_loc(*path), target, name, size, rate))
        return tuple(out)

    def _range(self, spec: dict, key: str, path: tuple) -> tuple[float, float] | None:
        if key not in spec:
            return None
        lo, hi = (float(v) for v in spec[key])
        if not lo < hi:
            self.error(f"{_where(path + (key,))} is [{lo:g}, {hi:g}]: its low bound is not below its high bound",
                       path + (key,), "write [low, high] with low < high, e.g. [0, 1.0] for up to +100 %")
            return None
        return lo, hi

    def _agrees(self, direction: str, size, rate, path: tuple) -> bool:
        """The declared bounds allow the direction's sign of change."""
        for key, bounds in (("size", size), ("rate", rate)):
            if bounds is None:
                continue
            if (direction == "increase" and bounds[0] < 0) or (direction == "decrease" and bounds[1] > 0):
                self.error(f"{_where(path + (key,))} [{bounds[0]:g}, {bounds[1]:g}] allows changes against the "
                           f"fault's direction ({direction})", path + (key,),
                           "make the bounds agree with 'direction', or drop 'direction' (it follows the bounds)")
                return False
        return True

    def settings(self, raw: dict) -> Settings:
        section = ("simulation",) if "simulation" in self.raw.data else ("name",)
        places = [("", self.raw.key_loc(*section))]
        if self.bad(("simulation",)):
            return Settings(locations=tuple(places))
        places += [(k, self.raw.key_loc("simulation", k)) for k in sorted(raw)]
        base = Settings()
        return Settings(dt=float(raw.get("dt", base.dt)), steps=int(raw.get("steps", base.steps)),
                        process_noise=float(raw.get("process_noise", base.process_noise)),
                        measurement_noise=float(raw.get("measurement_noise", base.measurement_noise)),
                        locations=tuple(places), time_unit=raw.get("time_unit"))


def _direction_of(size, rate) -> str:
    """The direction the declared bounds imply (``both`` when none are declared)."""
    bounds = [b for b in (size, rate) if b is not None]
    if bounds and all(lo >= 0 for lo, _ in bounds):
        return "increase"
    if bounds and all(hi <= 0 for _, hi in bounds):
        return "decrease"
    return "both"


def _section(data: dict, key: str) -> dict:
    """A section of the model, or nothing if it is absent or not a mapping (the schema reports that)."""
    value = data.get(key)
    return value if isinstance(value, dict) else {}


def _bonds(n: int) -> str:
    return f"{n} bond" if n == 1 else f"{n} bonds"


def _ports(bonds: Iterable[Bond]) -> dict[str, list[Bond]]:
    """Element name -> its bonds, in bond order."""
    out: dict[str, list[Bond]] = {}
    for b in bonds:
        out.setdefault(b.tail, []).append(b)
        out.setdefault(b.head, []).append(b)
    return out


def _closest(name: str, options: Iterable[str]) -> str | None:
    import difflib

    match = difflib.get_close_matches(name, sorted(options), n=1, cutoff=0.6)
    return match[0] if match else None


#: Bound keywords of the schema, with how a fix states them.
_RANGE = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}


def _where(path: tuple) -> str:
    return ".".join(str(p) for p in path) or "the model"


def _schema_message(err: jsonschema.ValidationError, path: tuple) -> tuple[str, str, bool]:
    """Turn a jsonschema error into (what, fix, point at key): every message has a fix."""
    where = _where(path)
    v = err.validator
    if v == "additionalProperties":
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        allowed = ", ".join(sorted(err.schema.get("properties", {})))
        prose = " " in str(extra[0]) and str(extra[0]).isprintable()  # text cut at a comma
        if path == ():
            return (f"unknown section {extra[0]!r}", f"sections are: {allowed}" if not prose else
                    "quote the description: in {...} a comma ends the text and starts a new key", False)
        kind = err.instance.get("kind")
        if len(path) == 2 and path[0] == "elements" and isinstance(kind, (str, int)) and str(kind) in KINDS \
                and not prose:  # the keys this element's kind takes, not every element's
            keys = sorted(element_kind(str(kind)).keys | {"kind", "description"})
            return (f"element {path[1]} of kind {kind} has no key {extra[0]!r}",
                    f"keys of {_article(str(kind))}: {', '.join(keys)}", False)
        if prose and "description" in err.schema.get("properties", {}):
            return (f"unknown key {extra[0]!r} in {where}",
                    "quote the description, e.g. description: \"a, b\": in {...} a comma ends the text and "
                    "starts a new key", False)
        return (f"unknown key {extra[0]!r} in {where}", f"allowed keys: {allowed}", False)
    if v == "required":
        missing = err.message.split("'")[1] if "'" in err.message else err.message
        return (f"{where} is missing '{missing}'", f"add '{missing}: ...'", False)
    if v == "enum":
        options = [str(o) for o in err.validator_value]
        options = sorted(dict.fromkeys(options))
        if path and path[-1] == "kind":
            return (f"unknown element kind '{err.instance}' in {where}", "valid kinds: " + ", ".join(KINDS), False)
        return (f"'{err.instance}' is not valid for {where}", "choose one of: " + ", ".join(options), False)
    if v == "type":
        want = [err.validator_value] if isinstance(err.validator_value, str) else list(err.validator_value)
        if want == ["null"]:  # a measurement: empty or a mapping
            return (f"{where} must be empty or a mapping, not {_json_type(err.instance)}",
                    f"write '{path[-1]}:' alone or '{path[-1]}: {{expr: ..., noise: ...}}'", False)
        fix = _type_fix(want, err.instance, path)
        if want == ["string"] and path and path[-1] == "description" and isinstance(err.instance, (dict, list)):
            fix = "quote it: YAML reads text in {...} or [...], or with ': ' inside, as a mapping or list"
        return (f"{where} must be {_article(' or '.join(want))}, not {_json_type(err.instance)}", fix, False)
    if v == "pattern":
        if path[:1] == ("bonds",) and len(path) == 2:
            return (f"bond number '{err.instance}' is not a positive integer", "number bonds 1, 2, 3, ...", True)
        return (f"name '{err.instance}' in {'.'.join(str(p) for p in path[:-1]) or 'the model'} is not a Python identifier",
                "use letters, digits and underscores, not starting with a digit", True)
    if v == "maxLength":
        return (f"name '{str(err.instance)[:20]}...' is too long", "use at most 64 characters", True)
    if v in ("minItems", "maxItems"):
        options = err.schema.get("items", {}).get("enum")
        if options:  # fault kinds
            return (f"{where} is empty", "list at least one of: " + ", ".join(options), False)
        if path[-1:] in (("size",), ("rate",)):
            return (f"{where} must list two numbers [low, high]", "write [low, high], e.g. [0, 1.0]", False)
        return (f"{where} must list exactly two elements [from, to]", "write [tail, head]", False)
    if v == "uniqueItems":
        items = [json.dumps(i) if not isinstance(i, str) else i for i in err.instance]
        twice = next((i for n, i in enumerate(items) if i in items[:n]), "an item")
        what = "kind" if path[:1] == ("faults",) else "item"
        return (f"{where} lists '{twice}' more than once", f"list each {what} once", False)
    if v == "minProperties":
        return (f"{where} is empty", "add at least one entry", False)
    if v in _RANGE:
        if _is_sensor_noise(path):
            return (f"{where} must be positive, not {err.instance}", "give a positive noise level such as 0.02: "
                    "zero sensor noise makes the filter's likelihood degenerate", False)
        bounds = " and ".join(f"{op} {_number(err.schema[k])}" for k, op in _RANGE.items() if k in err.schema)
        kind = "a whole number" if err.schema.get("type") == "integer" else "a number"
        return (f"{where} is out of range: {err.message}", f"use {kind} {bounds}", False)
    return (f"{where}: {err.message}", "see docs/format.md for what this place takes", False)


def _is_sensor_noise(path: tuple) -> bool:
    """A measurement noise level: zero would make the filter's likelihood degenerate."""
    return (len(path) == 3 and path[0] == "measurements" and path[2] == "noise") \
        or path == ("simulation", "measurement_noise")


def _wants_number(types: str | list) -> bool:
    return bool({"number", "integer"} & ({types} if isinstance(types, str) else set(types)))


def _type_fix(want: list[str], value: Any, path: tuple) -> str:
    """How to write a value of one of the types ``want``."""
    if _wants_number(want):
        if isinstance(value, str):
            number = _number_text(value)
            if number is not None:
                return number
            if path[:1] == ("parameters",):
                return "write a number such as 1.5; a formula goes in an element's 'parameter'"
        return "write a whole number such as 300" if want == ["integer"] else "write a number such as 1.5"
    if "string" in want:
        return "write text; quote it if YAML would read it as something else"
    if "array" in want:
        if path[:1] == ("bonds",):
            return "write [tail, head]"
        if path[:1] == ("faults",):
            return "write a list such as [abrupt] or [abrupt, incipient]"
        return "write a list [a, b, ...]"
    if "object" in want:
        return "write a mapping: 'key: value' entries, indented or in {braces}"
    return "see docs/format.md for what this place takes"


def _number_text(text: str) -> str | None:
    """The fix for a number written as text (quoted), or None if ``text`` is no number."""
    if len(text) > 40 or not _reads_as_number(text.strip()):
        return None
    return f"write {text.strip()} without quotes"


def _reads_as_number(text: str) -> bool:
    """Whether bgc's YAML reader reads ``text``, unquoted, as a finite number."""
    value = load.scalar_value(text)
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _number(value: Any) -> str:
    return str(int(value)) if isinstance(value, float) and value.is_integer() else str(value)


def _non_finite(data: Any) -> Iterator[tuple[tuple, str]]:
    """(path, what it is) of every number of ``data`` that is not a finite float, in file order."""
    stack: list[tuple[tuple, Any]] = [((), data)]
    while stack:  # no recursion: the loader accepts deeper nesting than Python's stack
        path, value = stack.pop()
        if isinstance(value, dict):
            stack.extend(reversed([(path + (k,), v) for k, v in value.items()]))
        elif isinstance(value, list):
            stack.extend(reversed([(path + (i,), v) for i, v in enumerate(value)]))
        elif isinstance(value, float) and math.isnan(value):
            yield path, "NaN (.nan), not a finite number"
        elif isinstance(value, float) and math.isinf(value):
            yield path, f"{'' if value > 0 else 'minus '}infinite, not a finite number"
        elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > sys.float_info.max:
            yield path, "too large to be a floating-point number"


def _coefficient(kind: str) -> str:
    """What the parameter of a linear element is called in a fix."""
    return {"resistor": "resistance", "storage": "capacitance or inertance",
            "two_port": "modulus"}.get(element_kind(kind).role, "value")


def _article(word: str) -> str:
    """``a`` or ``an`` before a word, or an element kind read letter by letter (an R, an MSe, a C)."""
    return ("an " if word[:1] in "aeiouAEFHILMNORSX" else "a ") + word


def _json_type(value: Any) -> str:
    if value is None:
        return "empty"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return f"text '{value[:30]}'"
    if isinstance(value, list):
        return "a list"
    return "a mapping"
