"""The whole compiler, one line per stage, from a model file to its generated package.

Every stage is one module of :mod:`bgc.compiler` with one public function from
one intermediate representation (:mod:`bgc.ir`) to the next; :class:`Compiled`
keeps every IR. ``bgc check`` runs the same chain as ``bgc compile`` (a model
that checks is a model that compiles); only the writing differs.

>>> from bgc.pipeline import compile_model
>>> c = compile_model("models/circuit.yaml")
>>> c.equations.states
('e4', 'e8', 'f10')
>>> c.package.modules[:2]
('nominal', 'C1_abrupt')

:func:`view` gives what the runtime reads of a compilation as plain data
(:mod:`bgc.view`), which the compile cache keeps (:mod:`bgc.api.cache`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from .compiler import causality, codegen, dbn, equations, load, numerics, signatures, tcg, validate
from .ir import (
    BondGraph, CausalBondGraph, DbnModel, FaultSignatures, GeneratedPackage, Numerics, RawModel,
    StateSpaceModel, TemporalCausalGraph,
)

if TYPE_CHECKING:
    from .view import CompiledView


@dataclass(frozen=True, slots=True)
class Compiled:
    """Every IR of one compilation, in pipeline order."""

    raw: RawModel
    model: BondGraph
    causal: CausalBondGraph
    tcg: TemporalCausalGraph
    equations: StateSpaceModel
    signatures: FaultSignatures
    dbn: DbnModel
    numerics: Numerics
    package: GeneratedPackage


def compile_model(path: str | Path, prior_scale: float = 1.0, *, text: str | None = None) -> Compiled:
    """Run every stage, from the model file to the generated package (in
    memory); ``prior_scale`` widens every fault's prior (``--prior-scale``);
    ``text``: the file's text when it has been read (the compile cache
    compiles the text it hashed), else the file is read."""
    raw = load.load(path) if text is None else load.loads(text, str(path))  # path -> RawModel
    model = validate.validate(raw)               # RawModel -> BondGraph
    causal = causality.assign(model)             # BondGraph -> CausalBondGraph
    graph = tcg.build(causal)                    # CausalBondGraph -> TemporalCausalGraph
    ssm = equations.derive(graph)                # TemporalCausalGraph -> StateSpaceModel
    sigs = signatures.derive(ssm)                # StateSpaceModel -> FaultSignatures
    dbns = dbn.build(ssm)                        # StateSpaceModel -> DbnModel
    num = numerics.derive(dbns, prior_scale)     # DbnModel -> Numerics
    package = codegen.generate(dbns, num)        # DbnModel, Numerics -> GeneratedPackage
    return Compiled(raw, model, causal, graph, ssm, sigs, dbns, num, package)


def assign_causality(path: str | Path) -> CausalBondGraph:
    """Only as far as causality: what ``bgc show causality`` prints, also for a
    model a later stage refuses (it shows why)."""
    return causality.assign(validate.validate(load.load(path)))


def generated_files(c: Compiled) -> dict[str, str]:
    """The text files of ``generated/<model>/``: every IR's dump, the package, the manifest."""
    from .output import artifacts

    return artifacts.folder_files(c.dbn, c.signatures, c.package)


def pictures(c: Compiled, engine: str = "auto") -> dict[str, bytes]:
    """The SVG pictures of ``generated/<model>/`` (TCG and every DBN), each
    sealed (the folder's manifest lists them without a hash)."""
    from .output import artifacts, draw

    return {name: artifacts.seal(data) for name, data in draw.pictures(c.dbn, engine).items()}


def view(c: Compiled) -> CompiledView:
    """What the runtime reads of ``c``, as plain data (:mod:`bgc.view`):
    the IRs' plain fields, the reports' labels, and the state equations as
    sympy's lambdify prints them for the truth simulator."""
    from .view import (CompiledView, DbnModelView, DbnView, ElementView, EquationsView, MeasurementView, ModelView,
        NumericsView, SignaturesView, TruthSource, plain)
    from .output.labels import labels_of

    m, ssm = c.model, c.equations
    model = plain(ModelView, m, elements=tuple(plain(ElementView, e) for e in m.elements),
                  measurements=tuple(plain(MeasurementView, y) for y in m.measurements))
    truth = numerics.truth_source(ssm)
    equations = plain(EquationsView, ssm, model=model,
                      truth=None if truth is None else TruthSource(*truth, numerics.float_safe(ssm)))
    dbns = plain(DbnModelView, c.dbn, equations=equations, nominal=plain(DbnView, c.dbn.nominal),
                 faulty=tuple(plain(DbnView, d) for d in c.dbn.faulty))
    return CompiledView(model, equations, plain(SignaturesView, c.signatures), dbns,
                        plain(NumericsView, c.numerics, equations=equations), labels_of(m), c.package.modules)
