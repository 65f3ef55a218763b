"""The whole compiler, one line per stage.

>>> from bgc.pipeline import check_model
>>> check_model("models/circuit.yaml").model.name
'circuit'
"""

from __future__ import annotations

from pathlib import Path

from . import causality, load, validate
from .ir import CausalBondGraph


def check_model(path: str | Path) -> CausalBondGraph:
    """Load, validate and assign causality: what ``bgc check`` runs."""
    raw = load.load(path)                    # path -> RawModel
    model = validate.validate(raw)           # RawModel -> BondGraph
    return causality.assign(model)           # BondGraph -> CausalBondGraph
