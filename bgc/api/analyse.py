""":func:`analyse`: which faults a model's sensors can detect and tell apart, at three levels, before the plant runs."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from .. import arguments
from ..analysis import isolability
from ..errors import ArgumentValueError


@dataclass(frozen=True)
class AnalysisReport:
    """Detectability and isolability of a model's faults (one per fault
    candidate's parameter, ``faults``; ``targets``: parameter, sensor or
    actuator; ``subjects``: the element, sensor or input it is of) at the
    levels of :mod:`bgc.analysis.isolability`, in ``levels``; the
    quantitative level's settings: ``steps`` samples of ``dt``, a relative
    ``change`` of each fault's scale from the fraction ``at`` of the run,
    the relative ``noise`` levels (None: the model's) and the probability
    ``level``. ``structure``: the structural model (its equations, the
    unknowns each holds, each fault's equation)."""

    model: str
    source: str
    faults: tuple[str, ...]
    targets: tuple[str, ...]
    subjects: tuple[str, ...]
    sensors: tuple[str, ...]
    levels: tuple[isolability.Level, ...]
    structure: object
    steps: int | None
    dt: float
    change: float
    at: float
    noise: tuple[float | None, float | None]
    level: float

    def get(self, name: str) -> isolability.Level:
        """The level called ``name`` (structural, qualitative, quantitative)."""
        for lv in self.levels:
            if lv.name == name:
                return lv
        raise KeyError(name)

    def more(self, name: str, than: str) -> tuple[tuple[str, str], ...]:
        """The pairs (fault, fault it is told from) level ``name`` tells
        apart and level ``than`` does not."""
        a, b = self.get(name).pairs(), self.get(than).pairs()
        return tuple((self.faults[i], self.faults[j]) for i, j in sorted(a - b))

    def to_dict(self) -> dict:
        """The report as plain data (``analysis.json``)."""
        s = self.structure
        return {"model": self.model, "source": self.source,
                "faults": [{"name": f, "target": t, "subject": u}
                           for f, t, u in zip(self.faults, self.targets, self.subjects)],
                "sensors": list(self.sensors),
                "levels": {lv.name: {"detectable": list(lv.detectable),
                                     "isolable": [list(r) for r in lv.isolable],
                                     "classes": [list(c) for c in lv.classes(self.faults)],
                                     "why": [{"fault": self.faults[i], "from": None if i == j else self.faults[j],
                                              "why": w} for (i, j), w in sorted(lv.why.items())]}
                           for lv in self.levels},
                "structural_model": {"equations": [{"name": e, "kind": s.kind[e], "unknowns": sorted(s.holds[e]),
                                                    "known": sorted(s.known[e])} for e in s.equations],
                                     "faults": dict(s.faults)},
                "quantitative": None if self.steps is None else
                {"steps": self.steps, "dt": self.dt, "change": self.change, "at": self.at,
                 "noise": {"process": self.noise[0], "measurement": self.noise[1]}, "level": self.level}}


def analyse(model: str | Path, *, quantitative: bool = True, change: float = 0.3, at: float = 0.5,
            process_noise: float | None = None, measurement_noise: float | None = None,
            steps: int | None = None, level: float = 0.95, progress=None) -> AnalysisReport:
    """Detectability and isolability of every fault candidate of ``model``
    (a model file of one mode) at three levels side by side: structural
    (the equations' structure, as the Fault Diagnosis Toolbox computes it),
    qualitative (the TRANSCEND signatures, as bgc's isolation reads them)
    and, unless ``quantitative`` is False, quantitative
    (:func:`distinguishability` of every fault model at a relative
    ``change`` from the fraction ``at`` of the run, at the noise levels
    given or the model's, over ``steps`` samples or the model's run, at
    probability ``level``). :mod:`bgc.analysis.isolability` says what each
    level means.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range; a model with modes
        (not built yet: each mode's model is analysed by itself).
    """
    func = "bgc.analyse"
    arguments.path(func, "model", model)
    arguments.flag(func, "quantitative", quantitative)
    arguments.real(func, "change", change, 0.0, math.inf, "a relative change above 0, e.g. change=0.3")
    arguments.real(func, "at", at, 0.0, 1.0, "a fraction of the run between 0 and 1, e.g. at=0.5")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if steps is not None:
        arguments.integer(func, "steps", steps, 1, "simulate at least 1 step", "steps=300")
    arguments.real(func, "level", level, 0.0, 1.0, "a probability between 0 and 1, e.g. level=0.95")
    arguments.callable_or_none(func, "progress", progress)
    from ..compiler import load
    from ..pipeline import compile_model

    say = progress or (lambda text: None)
    if load.declares_modes(model):
        raise ArgumentValueError(f"{func}: {model} has modes: analysing a model with modes is not built yet", None,
                                 "analyse a model of each mode by itself")
    say("compiling the model")
    c = compile_model(model)
    faults = tuple(sorted({f.parameter for f in c.model.faults}))
    if not faults:
        raise ArgumentValueError(f"{func}: {c.model.name} declares no fault candidates", None,
                                 "list its faults in the model's faults: section (docs/format.md)")
    of = {f.parameter: f for f in c.model.faults}
    say("structural analysis")
    structural, model_ = isolability.structural(c.equations, faults)
    levels = [structural, isolability.qualitative(c.signatures, faults)]
    settings = None, c.model.settings.dt
    if quantitative:
        from .distinguish import distinguishability

        say("distinguishability of every fault model")
        r = distinguishability(model, change=change, at=at, process_noise=process_noise,
                               measurement_noise=measurement_noise, steps=steps, level=level, progress=progress)
        levels.append(isolability.quantitative(r.distinctions, faults, level))
        settings = r.steps, r.dt
    return AnalysisReport(c.model.name, str(model), faults, tuple(of[p].target for p in faults),
                          tuple(of[p].subject for p in faults), tuple(c.equations.outputs), tuple(levels), model_,
                          settings[0], settings[1], change, at, (process_noise, measurement_noise), level)
