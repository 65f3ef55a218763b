"""A compiled model as plain data: what the runtime reads of it, without sympy.

The compiler's IRs (:mod:`bgc.ir`) hold sympy expressions and networkx
graphs; a diagnosis, a stream, a calibration or a simulation of the truth
reads only their plain parts: the model's name, file, settings, parameters,
inputs, sensors and fault candidates with their priors, the state-space
model's names and sizes, the fault signatures, the numbers the compiler
fixed (noise scales, priors, substeps), the labels and units of the reports,
and the state equations as the text sympy's ``lambdify`` printed them (the
truth simulator's own evaluation path, independent of bgc's code
generation). :class:`CompiledView` holds them under the IRs' own names
(``view.model.settings``, ``view.numerics.noise_at(...)``,
``view.signatures.signatures``, ``view.numerics.equations.states``), so a
function of the runtime takes a :class:`~bgc.ir.Numerics` or its view alike;
the methods are the IRs' own functions, not copies.

:func:`bgc.pipeline.view` makes it from a compilation; :func:`to_json` and
:func:`from_json` write and read it (plain JSON: floats by their shortest
exact repr, so a view read back equals the one written, bit for bit). The
compile cache (:mod:`bgc.api.cache`) keeps it beside the generated packages,
and a command served by the cache never imports sympy or the compiler.

Places in the model file (:class:`~bgc.errors.SourceLoc`) are kept as line
and column: the file's path is the one the model is opened by.

>>> from bgc.pipeline import compile_model, view
>>> v = view(compile_model("models/circuit.yaml"))
>>> v.model.name, v.numerics.equations.states, v.numerics.noise_at(0.01, 0.02) == v.numerics.noise_at(0.01, 0.02)
('circuit', ('e4', 'e8', 'f10'), True)
>>> from_json(to_json(v), v.model.source) == v
True
"""

from __future__ import annotations

import importlib
import json
import numbers
from dataclasses import dataclass, fields
from typing import Any

from .errors import SourceLoc
from .ir import (Bond, BondGraph, Dbn, DbnModel, Element, FaultCandidate, FaultNumerics, FaultSignatures, Input,
    Measurement, Numerics, Parameter, Settings, Signal, Signature, StateSpaceModel)
from .output.labels import Labels


def _plain_part(name: str, ir: type, symbolic: tuple[str, ...], doc: str, *, first: tuple[tuple[str, str], ...] = (),
                last: tuple[tuple[str, str], ...] = (), views: dict[str, str] | None = None,
                methods: tuple[str, ...] = ()) -> type:
    """The view of the IR class ``ir``: a frozen dataclass ``name`` of every field of it but the
    ``symbolic`` ones (sympy expressions, graphs), in its order, after the
    fields ``first`` and before ``last`` ((name, type) pairs); ``views``:
    fields that hold views (name -> type); ``methods``: the IR's own methods
    and properties it takes, the same functions. A field added to the IR is
    in its view."""
    from dataclasses import make_dataclass

    kept = [(f.name, (views or {}).get(f.name, f.type)) for f in fields(ir) if f.name not in symbolic]
    namespace = {m: ir.__dict__[m] for m in methods} | {"__doc__": doc, "__module__": __name__}
    return make_dataclass(name, [*first, *kept, *last], frozen=True, slots=True, namespace=namespace)


ElementView = _plain_part("ElementView", Element, ("parameter", "law", "source"),
                          "An :class:`~bgc.ir.Element` without its expressions (parameter, law, source).")

MeasurementView = _plain_part("MeasurementView", Measurement, ("expr",),
                              "A :class:`~bgc.ir.Measurement` without its expression (``text``: as the model "
                              "file writes it).")

ModelView = _plain_part("ModelView", BondGraph, ("modes",), "A :class:`~bgc.ir.BondGraph` whose elements and measurements "
                        "are views, without its modes (a model with modes: :attr:`CompiledView.modes`).",
                        views={"elements": "tuple[ElementView, ...]", "measurements": "tuple[MeasurementView, ...]"},
                        methods=("element", "bond", "bonds_of", "parameter_values", "unit", "display_source"))


@dataclass(frozen=True, slots=True)
class TruthSource:
    """The state equations as sympy's ``lambdify`` printed them for the truth
    simulator (:func:`bgc.compiler.numerics.truth_source`): the source of
    dx/dt and of y as functions of (x, u, theta) lists, the global names the
    code reads (name, module, attribute; or name, ``float``/``complex``,
    repr) and whether Python floats give the same numbers as NumPy scalars
    (:func:`bgc.compiler.numerics.float_safe`).

    The text is bgc's own output, written by bgc into its own cache; it is
    executed (:meth:`functions`) in a namespace of exactly the objects it
    names from numpy and builtins, as lambdify executed it: nothing of a
    model file is executed (its names are checked identifiers, its
    expressions were parsed into sympy and printed back)."""

    rhs: str
    outputs: str
    names: tuple[tuple[str, str, str], ...]
    float_safe: bool

    def functions(self):
        """(dx/dt, y): the functions lambdify made, made again from its text."""
        namespace: dict[str, Any] = {}
        for name, module, attribute in self.names:
            if module in ("float", "complex"):
                namespace[name] = {"float": float, "complex": complex}[module](attribute)
                continue
            if module not in TRUTH_MODULES:
                raise ValueError(f"the truth's code names {module}, not one of {', '.join(TRUTH_MODULES)}")
            m = importlib.import_module(module)
            namespace[name] = m if attribute == "" else getattr(m, attribute)
        made = []
        for text in (self.rhs, self.outputs):
            scope: dict[str, Any] = {}
            exec(compile(text, "<bgc truth simulator>", "exec"), dict(namespace), scope)  # noqa: S102 - bgc's own text
            (fn,) = scope.values()
            made.append(fn)
        return tuple(made)


#: What :class:`TruthSource` code may read (the namespace of lambdify's ``numpy`` module).
TRUTH_MODULES = ("numpy", "numpy.linalg", "builtins")


EquationsView = _plain_part(
    "EquationsView", StateSpaceModel, ("tcg", "rhs", "output_exprs", "variables"),
    "A :class:`~bgc.ir.StateSpaceModel`'s names, values and sizes, its model's view (``model``), and ``truth``: "
    "the equations as lambdify printed them (None: the truth needs sympy, "
    ":func:`bgc.compiler.numerics.truth_source`).",
    first=(("model", "ModelView"),), last=(("truth", "TruthSource | None"),))

SignaturesView = _plain_part("SignaturesView", FaultSignatures, ("equations",),
                             "The plain part of :class:`~bgc.ir.FaultSignatures`: all of it but the equations.",
                             methods=("get",))

NumericsView = _plain_part("NumericsView", Numerics, ("dbn",),
                           "The plain part of :class:`~bgc.ir.Numerics`: every number, the equations' view.",
                           first=(("equations", "EquationsView"),), methods=("noise", "fault", "noise_at"))

DbnView = _plain_part("DbnView", Dbn, ("graph",), "A :class:`~bgc.ir.Dbn`'s name, the parameter its fault changes and the "
                      "fault kind, without its graph.")

DbnModelView = _plain_part("DbnModelView", DbnModel, (), "The names of a :class:`~bgc.ir.DbnModel`'s DBNs (:meth:`get` finds one "
                           "as it does).", views={"nominal": "DbnView", "faulty": "tuple[DbnView, ...]"},
                           methods=("get",))


def plain(view: type, ir, **given):
    """The view ``view`` of the IR value ``ir``: its fields taken from
    ``ir``, but those ``given``."""
    return view(**{f.name: given[f.name] if f.name in given else getattr(ir, f.name) for f in fields(view)})


@dataclass(frozen=True, slots=True)
class ModeView:
    """One mode of a model with modes: its name, its states, its fault
    signatures (TRANSCEND's, on that mode's temporal causal graph) and its
    numbers (noise, scales: what calibration reads; their ``equations``
    link to the model's view, whose model and settings every mode shares)."""

    name: str
    states: tuple[str, ...]
    signatures: SignaturesView
    numerics: NumericsView


@dataclass(frozen=True, slots=True)
class CompiledView:
    """What the runtime reads of a :class:`bgc.pipeline.Compiled`, as plain
    data: the model, its equations, signatures, DBNs' names and numbers
    under the IRs' names, the reports' labels, and the generated modules."""

    model: ModelView
    equations: EquationsView
    signatures: SignaturesView
    dbn: DbnModelView
    numerics: NumericsView
    labels: Labels
    modules: tuple[str, ...]
    #: A model with modes: each mode, in the model's order (its number is its place, from 1); the
    #: equations, signatures, DBNs and numerics above are then the first mode's. Empty: a model of one mode.
    modes: tuple[ModeView, ...] = ()

    @property
    def priors(self) -> dict[str, float]:
        """Each fault candidate's prior probability, by the parameter its fault changes."""
        return {f.parameter: f.prior for f in self.model.faults}


#: Every type a view holds, by the name :func:`to_json` writes (nothing else is read back).
_TYPES = {cls.__name__: cls for cls in (
    CompiledView, ModeView, ModelView, ElementView, MeasurementView, EquationsView, TruthSource, SignaturesView, DbnModelView,
    DbnView, NumericsView, Parameter, Bond, Input, Signal, FaultCandidate, Settings, Signature, FaultNumerics, Labels)}

#: The version of the JSON layout (a reader refuses another).
FORMAT = 1

#: Fields that refer back to a value written elsewhere in the view (the one
#: model, the one equations' view): left out of the JSON, linked on reading.
_LINKS = {("EquationsView", "model"), ("NumericsView", "equations"), ("DbnModelView", "equations")}


def to_json(view: CompiledView) -> str:
    """``view`` as JSON text: each value by its type's name and fields,
    tuples as lists, complex numbers as [re, im], places in the model file
    as [line, col] (the file is the model's own)."""
    source = view.model.source

    def plain(value):
        if isinstance(value, SourceLoc):
            return {"@": "loc", "at": [value.line, value.col]} if value.file == source else \
                {"@": "loc", "at": [value.line, value.col], "file": value.file}
        if type(value).__name__ in _TYPES and type(value) is _TYPES[type(value).__name__]:
            name = type(value).__name__
            return {"@": name, **{f.name: plain(getattr(value, f.name)) for f in fields(value)
                                  if (name, f.name) not in _LINKS}}
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        if isinstance(value, numbers.Complex) and not isinstance(value, numbers.Real):
            value = complex(value)
            return {"@": "complex", "at": [value.real, value.imag]}
        if isinstance(value, bool) or value is None or isinstance(value, str):
            return value
        if isinstance(value, numbers.Integral):
            return int(value)
        if isinstance(value, numbers.Real):
            return float(value)
        raise TypeError(f"a compiled model's view holds no {type(value).__name__}")

    return json.dumps({"format": FORMAT, "view": plain(view)}, allow_nan=True, ensure_ascii=True,
                      separators=(",", ":"))


def from_json(text: str, source: str) -> CompiledView:
    """The view :func:`to_json` wrote, its model file at ``source`` (the path
    the model is opened by, in its places and messages).

    Raises
    ------
    ValueError
        Not a view of this layout (another format, an unknown type).
    """
    data = json.loads(text)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError("not a compiled model's view of this bgc")

    def back(value):
        if isinstance(value, list):
            return tuple(back(v) for v in value)
        if not isinstance(value, dict):
            return value
        kind = value.get("@")
        if kind == "loc":
            line, col = value["at"]
            return SourceLoc(value.get("file", source), line, col)
        if kind == "complex":
            re_, im = value["at"]
            return complex(re_, im)
        if kind not in _TYPES:
            raise ValueError(f"a compiled model's view holds no {kind!r}")
        linked = {f: None for k, f in _LINKS if k == kind}
        return _TYPES[kind](**linked, **{k: back(v) for k, v in value.items() if k != "@" and k not in linked})

    view = back(data["view"])
    if not isinstance(view, CompiledView):
        raise ValueError("not a compiled model's view")
    return _with_source(view, source)


def _with_source(view: CompiledView, source: str) -> CompiledView:
    """``view`` with its model file at ``source`` (the model, its equations,
    numerics and DBNs' names refer to the one model value)."""
    from dataclasses import replace

    model = replace(view.model, source=source)
    equations = replace(view.equations, model=model)
    modes = tuple(replace(m, numerics=replace(m.numerics, equations=equations)) for m in view.modes)
    return replace(view, model=model, equations=equations, numerics=replace(view.numerics, equations=equations),
                   dbn=replace(view.dbn, equations=equations), modes=modes)
