"""The decomposed plant a diagnosis runs on (``bgc diagnose --decompose``,
``bgc.diagnose(..., decompose=True)``): the model split at its sensors
(:func:`bgc.pipeline.decompose_model`), each submodel compiled through the
cache as the file ``bgc compile --decompose`` writes, and the plan of which
submodels model each fault (:func:`bgc.diagnosis.decomposed.plan`), with the
whole plant's nominal package (the model without its faults: the
detector's filter). Kept
per process for the model file's text (the last ``KEPT``): a campaign of
many runs splits the plant once. The submodels' packages are the NumPy
ones (their filters are small)."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path

from .. import pipeline
from ..compiler import decompose
from ..diagnosis import decomposed
from ..model.package import load_package
from . import cache

_PLANS: dict = {}
#: At most this many plans are kept per process.
KEPT = 8
_LOCK = threading.Lock()


def open_plan(model: str | os.PathLike, prior_scale: float = 1.0, say=None) -> decomposed.Plan:
    """The :class:`~bgc.diagnosis.decomposed.Plan` of the model file ``model``
    (its faults' priors widened by ``prior_scale``).

    Raises
    ------
    BgcError
        The model's own errors, and those of the decomposition (a model with
        modes, one without sensors: :mod:`bgc.compiler.decompose`).
    """
    text = Path(model).read_bytes()
    key = (os.path.abspath(model), hashlib.sha256(text).hexdigest(), float(prior_scale))
    with _LOCK:
        if key in _PLANS:
            return _PLANS[key]
    if say is not None:
        say("splitting the model at its sensors")
    d = pipeline.decompose_model(model, prior_scale, text=text.decode("utf-8"), parts=False)
    packages = [_package(s.text, f"submodels/{s.name}.yaml", prior_scale) for s in d.decomposition.submodels]
    # the whole plant's nominal filter, the detector's: the model without its faults (one package of a few
    # modules, where the whole plant's fault models are what makes its compilation long)
    whole = _package(decompose.nominal_text(d.raw), f"{d.model.name}_nominal.yaml", prior_scale)
    plan = decomposed.plan(d, packages, whole)
    with _LOCK:
        _PLANS[key] = plan
        while len(_PLANS) > KEPT:  # the oldest plan goes
            _PLANS.pop(next(iter(_PLANS)))
    return plan


def _package(text: str, source: str, prior_scale: float):
    """The generated package of the model file text ``text`` (named ``source``), compiled through the cache."""
    opened = cache.open_text(text, source, prior_scale)
    return load_package(opened.folder, opened.view.model.name, source)
