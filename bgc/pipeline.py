"""The whole compiler, one line per stage.

>>> from bgc.pipeline import compile_model
>>> c = compile_model("models/circuit.yaml")
>>> c.equations.states
('e4', 'e8', 'f10')
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from . import causality, dbn, equations, load, tcg, validate
from .ir import BondGraph, CausalBondGraph, DbnModel, RawModel, StateSpaceModel, TemporalCausalGraph


@dataclass(frozen=True, slots=True)
class Compiled:
    """Every IR of one compilation, in pipeline order."""

    raw: RawModel
    model: BondGraph
    causal: CausalBondGraph
    tcg: TemporalCausalGraph
    equations: StateSpaceModel
    dbn: DbnModel


def check_model(path: str | Path) -> CausalBondGraph:
    """Load, validate and assign causality: what ``bgc check`` runs."""
    raw = load.load(path)                    # path -> RawModel
    model = validate.validate(raw)           # RawModel -> BondGraph
    return causality.assign(model)           # BondGraph -> CausalBondGraph


def compile_model(path: str | Path) -> Compiled:
    """Run every stage up to the DBNs."""
    raw = load.load(path)                    # path -> RawModel
    model = validate.validate(raw)           # RawModel -> BondGraph
    causal = causality.assign(model)         # BondGraph -> CausalBondGraph
    graph = tcg.build(causal)                # CausalBondGraph -> TemporalCausalGraph
    ssm = equations.derive(graph)            # TemporalCausalGraph -> StateSpaceModel
    dbns = dbn.build(ssm)                    # StateSpaceModel -> DbnModel
    return Compiled(raw, model, causal, graph, ssm, dbns)
