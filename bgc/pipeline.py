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

from .compiler import (causality, codegen, dbn, decompose, equations, hybrid_codegen, load, modes, numerics,
                       signatures, tcg, validate)
from .errors import CodegenError
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
    #: A model with modes: each mode compiled (:class:`bgc.compiler.modes.ModeModel`); the stages above are
    #: then the first mode's, and the package is the one across the modes. Empty: a model of one mode.
    modes: tuple[modes.ModeModel, ...] = ()
    #: Each mode's numerics (the first is ``numerics``).
    mode_numerics: tuple[Numerics, ...] = ()


@dataclass(frozen=True, slots=True)
class Hybrid:
    """A hybrid bond graph (a model with modes) compiled as far as each
    mode's state equations (:func:`bgc.compiler.modes.compile_modes`)."""

    raw: RawModel
    model: BondGraph
    modes: tuple[modes.ModeModel, ...]

    def mode(self, name: str | None) -> modes.ModeModel:
        """The compiled mode ``name``; a one-line error names the modes when it is not one."""
        for m in self.modes:
            if m.name == name:
                return m
        raise unknown_mode(self.model, name)

    def numerics(self, prior_scale: float = 1.0) -> tuple[Numerics, ...]:
        """Each mode's numbers (noise scales, priors, substeps), in the model's order: what the simulator takes."""
        return tuple(numerics.derive(m.dbn, prior_scale) for m in self.modes)


def unknown_mode(model: BondGraph, name: str | None) -> CodegenError:
    """The one-line error for ``--mode NAME`` that names no mode of ``model``
    (None: not given, and the model has modes), or given for a model without modes."""
    if model.modes is None:
        return CodegenError(f"model {model.name} has no modes", model.source, "drop --mode")
    names = ", ".join(model.modes.names)
    what = f"has no mode {name!r}" if name else f"has modes ({names})"
    return CodegenError(f"model {model.name} {what}", model.source, f"choose one with --mode: {names}")


def compile_model(path: str | Path, prior_scale: float = 1.0, *, text: str | None = None) -> Compiled:
    """Run every stage, from the model file to the generated package (in
    memory); ``prior_scale`` widens every fault's prior (``--prior-scale``);
    ``text``: the file's text when it has been read (the compile cache
    compiles the text it hashed), else the file is read. A model with modes
    is compiled in every mode (:attr:`Compiled.modes`), its package across
    the modes (:mod:`bgc.compiler.hybrid_codegen`)."""
    raw = load.load(path) if text is None else load.loads(text, str(path))  # path -> RawModel
    model = validate.validate(raw)               # RawModel -> BondGraph
    if model.modes is not None:                  # every stage of each mode, the package across them
        each = modes.compile_modes(model)
        nums = tuple(numerics.derive(m.dbn, prior_scale) for m in each)
        first = each[0]
        return Compiled(raw, model, first.causal, first.tcg, first.equations, first.signatures, first.dbn, nums[0],
                        hybrid_codegen.generate(model, each, nums), each, nums)
    causal = causality.assign(model)             # BondGraph -> CausalBondGraph
    graph = tcg.build(causal)                    # CausalBondGraph -> TemporalCausalGraph
    ssm = equations.derive(graph)                # TemporalCausalGraph -> StateSpaceModel
    sigs = signatures.derive(ssm)                # StateSpaceModel -> FaultSignatures
    dbns = dbn.build(ssm)                        # StateSpaceModel -> DbnModel
    num = numerics.derive(dbns, prior_scale)     # DbnModel -> Numerics
    package = codegen.generate(dbns, num)        # DbnModel, Numerics -> GeneratedPackage
    return Compiled(raw, model, causal, graph, ssm, sigs, dbns, num, package)


@dataclass(frozen=True, slots=True)
class Analysed:
    """A model of one mode compiled as far as its signatures: what
    ``bgc analyse``'s structural and qualitative levels read (no package is
    generated: on a large plant that is most of a compilation)."""

    raw: RawModel
    model: BondGraph
    equations: StateSpaceModel
    signatures: FaultSignatures
    modes: tuple = ()


def analysis_model(path: str | Path) -> Analysed | Compiled:
    """What ``bgc analyse`` reads of a model: its stages as far as the
    signatures (:class:`Analysed`), or every stage of a model with modes
    (:func:`compile_model`: each mode's signatures)."""
    if load.declares_modes(path):  # validated once, by compile_model
        return compile_model(path)
    raw = load.load(path)
    model = validate.validate(raw)
    ssm = equations.derive(tcg.build(causality.assign(model)))
    return Analysed(raw, model, ssm, signatures.derive(ssm))


@dataclass(frozen=True, slots=True)
class Decomposed:
    """A model split into submodels (``bgc compile --decompose``): the
    whole model's file, IR and numbers, its :class:`~bgc.compiler.decompose.Decomposition`,
    and each submodel compiled (``parts``, in the same order)."""

    raw: RawModel
    model: BondGraph
    numerics: Numerics
    decomposition: decompose.Decomposition
    parts: tuple[Compiled, ...]


def decompose_model(path: str | Path, prior_scale: float = 1.0, *, text: str | None = None,
                    parts: bool = True) -> Decomposed:
    """The model split into minimal submodels, each compiled with its own
    faults (:mod:`bgc.compiler.decompose`): the whole model is compiled as
    far as its numbers only (no fault model of the whole plant is
    generated), each submodel to its package (``parts`` False: none, the
    caller compiles them, through the cache). A submodel's errors name it
    as ``submodels/<name>.yaml``, the file ``bgc compile --decompose``
    writes."""
    raw = load.load(path) if text is None else load.loads(text, str(path))
    model = validate.validate(raw)
    decompose.refuse_modes(model)
    ssm = equations.derive(tcg.build(causality.assign(model)))
    num = numerics.derive(dbn.build(ssm), prior_scale)
    d = decompose.decompose(raw, num)
    compiled = tuple(compile_model(f"submodels/{s.name}.yaml", prior_scale, text=s.text) for s in d.submodels) \
        if parts else ()
    return Decomposed(raw, model, num, d, compiled)


def check_model(path: str | Path) -> Compiled | Hybrid:
    """What ``bgc check`` checks: every stage of a model of one mode
    (:func:`compile_model`), or each mode's causality and equations of a
    model with modes (:class:`Hybrid`)."""
    if not load.declares_modes(path):  # validated once, by compile_model
        return compile_model(path)
    raw = load.load(path)
    model = validate.validate(raw)
    return Hybrid(raw, model, modes.compile_modes(model))


def assign_causality(path: str | Path, mode: str | None = None) -> CausalBondGraph:
    """Only as far as causality: what ``bgc show causality`` prints, also for a
    model a later stage refuses (it shows why); of mode ``mode`` for a model
    with modes (which must name one)."""
    model = validate.validate(load.load(path))
    if (model.modes is None) != (mode is None) or (mode is not None and mode not in model.modes.names):
        raise unknown_mode(model, mode)
    return causality.assign(model if mode is None else modes.mode_graph(model, mode))


def generated_files(c: Compiled) -> dict[str, str]:
    """The text files of ``generated/<model>/``: every IR's dump (of each
    mode, under ``modes/<mode>/``, for a model with modes), the package, the
    manifest."""
    from .output import artifacts

    if c.modes:
        return artifacts.hybrid_folder_files(c.model, c.modes, c.package, c.mode_numerics)
    return artifacts.folder_files(c.dbn, c.signatures, c.package)


def decomposed_files(d: Decomposed) -> dict[str, str]:
    """The text files of ``generated/<model>/`` written by ``bgc compile
    --decompose``: the decomposition, each submodel's file and folder under
    ``submodels/``, the manifest."""
    from .output import artifacts

    return artifacts.decomposed_folder_files(d.model, d.decomposition, d.parts)


def decomposed_pictures(d: Decomposed, engine: str = "auto") -> dict[str, bytes]:
    """The SVG pictures of each submodel, under ``submodels/<name>/``."""
    return {f"submodels/{s.name}/{name}": data for s, part in zip(d.decomposition.submodels, d.parts)
            for name, data in pictures(part, engine).items()}


def pictures(c: Compiled, engine: str = "auto") -> dict[str, bytes]:
    """The SVG pictures of ``generated/<model>/`` (TCG and every DBN, of
    each mode for a model with modes), each sealed (the folder's manifest
    lists them without a hash)."""
    from .output import artifacts, draw

    if c.modes:
        return {f"modes/{m.name}/{name}": artifacts.seal(data) for m in c.modes
                for name, data in draw.pictures(m.dbn, engine).items()}
    return {name: artifacts.seal(data) for name, data in draw.pictures(c.dbn, engine).items()}


def view(c: Compiled) -> CompiledView:
    """What the runtime reads of ``c``, as plain data (:mod:`bgc.view`):
    the IRs' plain fields, the reports' labels, and the state equations as
    sympy's lambdify prints them for the truth simulator."""
    from .view import (CompiledView, DbnModelView, DbnView, ElementView, EquationsView, MeasurementView, ModeView,
        ModelView, NumericsView, SignaturesView, TruthSource, plain)
    from .output.labels import labels_of

    m, ssm = c.model, c.equations
    model = plain(ModelView, m, elements=tuple(plain(ElementView, e) for e in m.elements),
                  measurements=tuple(plain(MeasurementView, y) for y in m.measurements))
    truth = numerics.truth_source(ssm)
    equations = plain(EquationsView, ssm, model=model,
                      truth=None if truth is None else TruthSource(*truth, numerics.float_safe(ssm)))
    dbns = plain(DbnModelView, c.dbn, equations=equations, nominal=plain(DbnView, c.dbn.nominal),
                 faulty=tuple(plain(DbnView, d) for d in c.dbn.faulty))
    # each mode's numbers link to the one equations' view, as they read back (bgc.view._with_source): what they
    # are asked of it is the model (its settings and sensors), the same in every mode
    each = tuple(ModeView(mode.name, mode.equations.states, plain(SignaturesView, mode.signatures),
                          plain(NumericsView, nums, equations=equations))
                 for mode, nums in zip(c.modes, c.mode_numerics))
    return CompiledView(model, equations, plain(SignaturesView, c.signatures), dbns,
                        plain(NumericsView, c.numerics, equations=equations), labels_of(m), c.package.modules, each)
