""":func:`analyse`: which faults a model's sensors can detect and tell apart, at three levels, before the plant runs."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

from .. import arguments
from .distinguish import check_prediction
from collections.abc import Mapping

from ..errors import ArgumentTypeError, ArgumentValueError, printable
from ..kinds import fault_parameter


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
    levels: tuple
    structure: object
    steps: int | None
    dt: float
    change: float
    at: float
    noise: tuple[float | None, float | None]
    level: float
    #: Sensor placement (:mod:`bgc.analysis.placement`; None: not asked for)
    placement: object | None = None
    #: Input tests for the faults the quantitative level does not detect: per
    #: fault, (fault, input, signal as written in a model, probability of
    #: detection with it, without it); None: not asked for
    input_tests: tuple | None = None
    #: A model with modes: per mode, its structural and qualitative levels
    #: (``levels`` holds them across the modes; the quantitative level is of
    #: the run through the modes); empty: a model of one mode
    by_mode: Mapping = field(default_factory=dict)
    #: The controlled changes of mode of the quantitative level's run (``MODE@TIME,...``; None: the guards')
    modes: str | None = None
    #: Whether ``steps`` was asked for (else the model's run length)
    steps_given: bool = False

    def get(self, name: str):
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
                "modes": {m: {lv.name: {"detectable": list(lv.detectable), "isolable": [list(r) for r in lv.isolable]}
                              for lv in pair} for m, pair in self.by_mode.items()},
                "placement": None if self.placement is None else _placement_dict(self.placement),
                "input_tests": None if self.input_tests is None else
                [{"fault": f, "input": u, "signal": text, "detected_with": p, "detected_without": p0}
                 for f, u, text, p, p0 in self.input_tests],
                "quantitative": None if self.steps is None else
                {"steps": self.steps, "dt": self.dt, "change": self.change, "at": self.at,
                 "noise": {"process": self.noise[0], "measurement": self.noise[1]}, "level": self.level}}


def _placement_dict(p) -> dict:
    return {"sets": [list(x) for x in p.sets], "cost": p.cost, "more_sets": p.more,
            "candidates": [{"name": c.name, "reads": str(c.expr), "cost": c.cost,
                            "model_text": c.written[1]}  # its expr in a model file (--write names it)
                           | ({"variable": c.variable, "beside": c.beside} if c.beside else {}) for c in p.candidates],
            "detected_now": sorted(p.now[0]), "detected_at_most": sorted(p.reachable[0]),
            "pairs_now": len(p.now[1]), "pairs_at_most": len(p.reachable[1]),
            "qualitative": None if p.reachable_qualitative is None else
            {"detected_now": sorted(p.now_qualitative[0]), "detected_at_most": sorted(p.reachable_qualitative[0]),
             "pairs_now": len(p.now_qualitative[1]), "pairs_at_most": len(p.reachable_qualitative[1])},
            "never_detected": sorted(set(p.faults) - p.reachable[0]),
            "never_told_apart": [[a, b] for a, b in sorted(_untold(p))],
            "quantitative": None if p.checked is None else
            {"now": {"detected": p.checked_now[0], "pairs": p.checked_now[1]},
             "sets": [{"detected": d, "pairs": n} for d, n in p.checked]}}


def _untold(p) -> set:
    """The ordered pairs of detected faults no candidate set tells apart."""
    return {(a, b) for a in p.reachable[0] for b in p.faults if a != b and (a, b) not in p.reachable[1]}


def analyse(model: str | Path, *, quantitative: bool = True, change: float = 0.3, at: float = 0.5,
            process_noise: float | None = None, measurement_noise: float | None = None,
            steps: int | None = None, level: float = 0.95, progress=None, place_sensors: bool = False,
            costs: Mapping[str, float] | None = None, most: int = 2, place_by: str = "qualitative",
            design_inputs: bool = False,
            modes: str | None = None) -> AnalysisReport:
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
        An argument of the wrong type or out of range.
    """
    func = "bgc.analyse"
    arguments.path(func, "model", model)
    arguments.flag(func, "quantitative", quantitative)
    check_prediction(func, change, at, process_noise, measurement_noise, steps, level, progress)
    arguments.flag(func, "place_sensors", place_sensors)
    arguments.flag(func, "design_inputs", design_inputs)
    if design_inputs and not quantitative:
        raise ArgumentValueError(f"{func}: design_inputs=True needs the quantitative level", None,
                                 "leave quantitative=True")
    arguments.integer(func, "most", most, 1, "is below 1", "most=2")
    arguments.choice(func, "place_by", place_by, ("structural", "qualitative"))
    if costs is not None:
        if not isinstance(costs, Mapping):
            raise ArgumentTypeError(f"{func}: costs={arguments.shown(costs)} is not a mapping", None,
                                    "give {variable: cost}, e.g. costs={'e2': 1, 'f1': 3}")
        for name, cost in costs.items():
            arguments.text(func, "a name of costs", name)
            arguments.real(func, f"costs[{name!r}]", cost, 0.0, math.inf, "a cost >= 0, e.g. 1", low_ok=True)
    from ..analysis import isolability
    from ..compiler import load
    from ..pipeline import analysis_model

    say = progress or (lambda text: None)
    arguments.text(func, "modes", modes, optional=True)
    hybrid = load.declares_modes(model)
    if modes is not None and not hybrid:
        raise ArgumentValueError(f"{func}: modes={modes!r}: {model} has no modes", None, "leave modes out")
    say("compiling the model")
    c = analysis_model(model)
    stuck = c.model.modes.stuck if hybrid else ()
    of = {f.parameter: (f.target, f.subject) for f in c.model.faults} | {s.junction: ("switch", s.junction)
                                                                        for s in stuck}
    faults = tuple(sorted(of))
    if not faults:
        raise ArgumentValueError(f"{func}: {c.model.name} declares no fault candidates", None,
                                 "list its faults in the model's faults: section (docs/format.md)")
    say("structural analysis")
    sensors = {f.parameter: f.subject for f in c.model.faults if f.target == "sensor"}
    # a model with modes: a stuck switch in the equations its configurations change, mode by mode
    configs = _stuck_configs(c, stuck) if hybrid else ()
    enters = _stuck_equations(c, configs) if hybrid else {}
    structural, model_ = isolability.structural(c.equations, faults, sensors,  # (the first mode's: the report's)
                                                enters.get(c.modes[0].name) if hybrid else None)
    levels = [structural, isolability.qualitative(c.signatures, faults)]
    by_mode = {}
    if hybrid:  # each mode by itself, and across them
        names = tuple(m.name for m in c.modes)
        by_mode = {m.name: (isolability.structural(m.equations, faults, sensors, enters[m.name])[0],
                            isolability.qualitative(m.signatures, faults)) for m in c.modes}
        levels = [isolability.across([by_mode[m][k] for m in names], names) for k in range(2)]
    settings = None, c.model.settings.dt
    # the quantitative level's prediction, as bgc distinguish takes it (its input tests' and placed sets' too)
    predicting = dict(change=change, at=at, process_noise=process_noise, measurement_noise=measurement_noise,
                      steps=steps, level=level, modes=modes if hybrid else None)
    if quantitative:
        from .distinguish import distinguishability
        from .session import open as open_session

        session = open_session(model)  # compiled once, for every prediction
        say("distinguishability of every fault model")
        r = distinguishability(session, progress=progress, **predicting)
        levels.append(isolability.quantitative(r.distinctions, faults, level))
        settings = r.steps, r.dt
    tests = _input_tests(session, c, faults, r, levels[-1], predicting, say) if design_inputs else None
    placed = None
    if place_sensors:
        say("sensor placement")
        placed = _place_modes(func, c, faults, sensors, enters, configs, costs, most, place_by == "qualitative") \
            if hybrid else _place(func, c, model_, costs, most, place_by == "qualitative")
        if quantitative and placed.sets and placed.sets[0]:
            placed = _check_sets(model, placed, faults, levels[-1], predicting, say)
    return AnalysisReport(c.model.name, str(model), faults, tuple(of[p][0] for p in faults),
                          tuple(of[p][1] for p in faults), tuple(c.equations.outputs), tuple(levels), model_,
                          settings[0], settings[1], change, at, (process_noise, measurement_noise), level, placed, tests,
                          by_mode, modes, steps is not None)


def _stuck_configs(c, stuck) -> tuple:
    """Per stuck switch of ``stuck``, (the switch, each mode's configuration
    with it stuck: :func:`bgc.compiler.modes.compile_stuck`), compiled once."""
    from ..compiler.modes import compile_stuck

    return tuple((fault, compile_stuck(c.model, c.modes, fault).configs) for fault in stuck)


def _stuck_equations(c, configs, what=None) -> dict[str, dict[str, frozenset]]:
    """Per mode of the compiled model with modes ``c``, per junction of the
    stuck switches of ``configs`` (:func:`_stuck_configs`): the equations of
    the mode's structural model its stuck configurations (each kind's,
    together) change there (``what``: the function that says it, of the mode
    and the configuration; default
    :func:`bgc.analysis.structure.stuck_equations`)."""
    from ..analysis.structure import stuck_equations

    what = what or stuck_equations
    out: dict[str, dict[str, set]] = {m.name: {} for m in c.modes}
    for fault, each in configs:
        for mode, config in zip(c.modes, each):
            out[mode.name].setdefault(fault.junction, set()).update(what(mode, config))
    return {m: {j: frozenset(e) for j, e in by.items()} for m, by in out.items()}


def _input_tests(session, c, faults, r, quantitative, settings: dict, say) -> tuple:
    """Per fault the quantitative level does not detect, the best input test (:func:`analyse`)."""
    from .distinguish import distinguishability

    missed = [f for f, d in zip(faults, quantitative.detectable) if not d]
    if not missed:
        return ()

    def detection(report, fault):
        return max((d.detectability for d in report.distinctions if fault_parameter(d.truth) == fault), default=0.0)

    before = {f: detection(r, f) for f in missed}
    best: dict = {}
    T = r.steps * r.dt
    for u in c.model.inputs:
        v = u.signal.value
        a = 0.2 * abs(v) if v else 1.0
        for spec in ({"signal": "step", "value": v, "final": v + a, "start": (settings["at"] + 1) / 2 * T},
                     {"signal": "square", "value": v, "amplitude": a, "period": T / 8},
                     {"signal": "sine", "value": v, "amplitude": a, "period": T / 8},
                     {"signal": "prbs", "value": v, "amplitude": a, "period": max(r.dt, T / 60)}):
            say(f"input test: {u.name} {spec['signal']}")
            tried = distinguishability(session, inputs={u.name: spec}, **settings)
            for f in missed:
                p = detection(tried, f)
                if p > best.get(f, (None, None, before[f]))[2]:
                    best[f] = (u.name, _signal_text(spec), p)
    return tuple((f, *best[f], before[f]) if f in best else (f, None, None, before[f], before[f]) for f in missed)


def _signal_text(spec: dict) -> str:
    """A signal as a model's ``inputs`` section and ``--input`` write it."""
    return "{" + ", ".join(f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}" for k, v in spec.items()) + "}"


def _check_sets(model, placed, faults, now, settings: dict, say):
    """``placed`` checked at the quantitative level: each set's sensors
    added to the model (:func:`with_sensors`, a file in a folder of bgc's
    own, removed after) and the faults detected and ordered pairs told
    apart by :func:`distinguishability` at the analysis's ``settings``
    (``now``: the model's own quantitative level), the sets ordered by it
    (:func:`bgc.analysis.placement.checked`)."""
    import tempfile

    from ..analysis import isolability, placement
    from .distinguish import distinguishability

    counts = []
    with tempfile.TemporaryDirectory(prefix="bgc-placed-") as folder:
        for i, names in enumerate(placed.sets, start=1):
            say(f"sensor placement: set {i} of {len(placed.sets)} checked by bgc distinguish ({', '.join(names)})")
            path = with_sensors(model, placed.written(names), Path(folder) / f"placed_{i}.yaml")
            r = distinguishability(path, **settings)
            lv = isolability.quantitative(r.distinctions, faults, settings["level"])
            counts.append((sum(lv.detectable), len(lv.pairs())))
    return placement.checked(placed, counts, (sum(now.detectable), len(now.pairs())))


def _place_modes(func: str, c, faults, sensors, enters, configs, costs, most: int, qualitative: bool):
    """The placement of the sensors of the compiled model with modes ``c``
    across its modes (:func:`bgc.analysis.placement.place_across`): per mode
    its structural model (its stuck switches in ``enters``; ``configs``:
    their configurations), its candidates (:func:`_mode_candidates`) and,
    ``qualitative``, its signatures read at them (:func:`_mode_signatures`)."""
    from ..analysis import placement, structure

    _known_costs(func, c, costs, {name for m in c.modes for name, _ in m.equations.variables})
    read = _stuck_equations(c, configs, structure.stuck_readings)  # what a sensor reads of a stuck switch
    by_mode = _mode_candidates(c, read, costs)
    parts = [placement.ModePart(structure.of_equations(m.equations, {p: p for p in faults}, sensors,
                                                       enters.get(m.name)), m.equations, by_mode[m.name],
                                _mode_signatures(c, m, mode, by_mode[m.name]) if qualitative else None, m.name)
             for m, mode in zip(c.modes, c.model.modes.modes)]
    return placement.place_across(parts, most)


def _no_offsets(c) -> dict:
    """Each sensor fault's offset parameter of compilation ``c`` at 0: a sensor's expression as a
    second sensor beside it would read it (none of the first one's faults)."""
    import sympy

    return {sympy.Symbol(f.parameter): 0 for f in c.model.faults if f.target == "sensor"}


def _mode_candidates(c, read, costs) -> dict[str, tuple]:
    """Per mode of ``c``, its candidate sensors: every bond variable of some
    mode (those ``costs`` names, when given), in the first mode's order of
    them, with its expression in each mode. In a mode a variable is a
    candidate where it reads something no sensor there reads already, or a
    switch stuck there changes it (``read``: :func:`structure.stuck_readings`
    per mode and junction; it then reads 0 but for the stuck switch, which
    its ``also`` names). Variables that read the same in every mode are one
    candidate (the cheapest, then the first). Then the second sensors
    (:func:`_mode_twins`)."""
    import sympy

    from ..analysis import placement

    offsets = _no_offsets(c)
    exprs = {m.name: dict(m.equations.variables) for m in c.modes}
    measured = {m.name: {str(e.subs(offsets)) for e in m.equations.output_exprs} for m in c.modes}
    order = list(dict.fromkeys(name for m in c.modes for name, _ in m.equations.variables))
    per_name: dict[str, dict[str, placement.Candidate]] = {}
    kept: dict[tuple, str] = {}
    for name in order:
        if costs is not None and name not in costs:
            continue
        cost = 1.0 if costs is None else float(costs[name])
        here = {}
        for mode, expr, also in _in_modes(c, exprs, read, name):
            if expr is not None and expr.free_symbols and str(expr) not in measured[mode]:
                here[mode] = placement.Candidate(name, expr, cost, also)
            elif also and (expr is None or not expr.free_symbols):  # it reads nothing there, but for the stuck switch
                here[mode] = placement.Candidate(name, sympy.Integer(0), cost, also)
        if not here:
            continue
        key = tuple((str(here[m.name].expr), tuple(sorted(here[m.name].also))) if m.name in here else None
                    for m in c.modes)
        if key in kept and per_name[kept[key]][next(iter(here))].cost <= cost:
            continue
        if key in kept:
            del per_name[kept[key]]
        kept[key] = name
        per_name[name] = here
    per_name |= _mode_twins(c, exprs, read, costs)
    return {m.name: tuple(here[m.name] for here in per_name.values() if m.name in here) for m in c.modes}


def _in_modes(c, exprs, read, name: str):
    """Per mode of ``c``: its name, the expression of bond variable ``name``
    there (``exprs``; None: no variable of that mode) and the stuck switches
    that change it there (``read``: :func:`structure.stuck_readings`)."""
    for m in c.modes:
        yield m.name, exprs[m.name].get(name), frozenset(j for j, names in read[m.name].items() if name in names)


def _mode_twins(c, exprs, read, costs) -> dict[str, dict]:
    """Per second sensor of a model with modes (:func:`bgc.analysis.placement.candidates`'
    rule: beside a sensor a fault is declared on, or on a measured variable ``costs``
    names: the sensor's own, or one that reads the same in every mode), per mode where
    it reads something (or a stuck switch changes it), its candidate: a sensor whose
    model text is one bond variable, read again; one whose text is an expression no
    bond variable equals, that expression (each mode's, without a costs file: it
    prices bond variables), changed by the stuck switches that change any of its
    variables."""
    from ..analysis import placement

    faulty = {f.subject for f in c.model.faults if f.target == "sensor"}
    offsets = _no_offsets(c)
    twins: dict[str, dict] = {}
    for sensor in c.model.measurements:
        name = sensor.text.strip()
        priced = costs is not None and sensor.name in costs  # a second sensor beside it, at that cost
        if (priced or (costs is None and sensor.name in faulty)) and not any(name in exprs[m.name] for m in c.modes):
            here = _expression_twin(c, read, sensor, offsets, float(costs[sensor.name]) if priced else 1.0)
            if here:
                twins[placement.second(sensor.name)] = here
            continue
        priced_here = costs
        if priced and (name not in costs or float(costs[sensor.name]) < float(costs[name])):
            priced_here = {**costs, name: costs[sensor.name]}  # its name prices its own quantity (its model text)
        if costs is not None:  # the cheapest variable it names that reads the sensor's quantity in every mode
            same = [v for v in priced_here if v == name or all(str(exprs[m.name].get(v)) ==
                                                               str(exprs[m.name].get(name)) for m in c.modes)]
            name = min(same, key=lambda v: (float(priced_here[v]), v != name), default=None)
        if name is None or (costs is None and sensor.name not in faulty):
            continue
        cost = 1.0 if costs is None else float(priced_here[name])
        here = {}
        for mode, expr, also in _in_modes(c, exprs, read, name):
            if expr is not None and (expr.free_symbols or also):
                here[mode] = placement.Candidate(placement.second(sensor.name), expr, cost, also, name, sensor.name)
        if here:
            twins[placement.second(sensor.name)] = here
    return twins


def _expression_twin(c, read, sensor, offsets, cost: float = 1.0) -> dict:
    """Per mode of ``c`` where ``sensor`` (its model text an expression) reads
    something or a stuck switch changes one of its variables, the second
    sensor on that expression, of ``cost`` (:func:`_mode_twins`)."""
    from ..analysis import placement

    variables = {s.name for s in sensor.expr.free_symbols}
    here = {}
    for m in c.modes:
        expr = m.equations.output_exprs[list(m.equations.outputs).index(sensor.name)].subs(offsets)
        also = frozenset(j for j, names in read[m.name].items() if variables & set(names))
        if expr.free_symbols or also:
            here[m.name] = placement.Candidate(placement.second(sensor.name), expr, cost, also,
                                               variable=sensor.text.strip(), beside=sensor.name, node=sensor.name)
    return here


def _mode_signatures(c, m, mode, cands):
    """The signatures of mode ``m`` (its model's ``mode``) read at its
    sensors and then at each candidate of ``cands``: a bond variable's own
    symbols (:func:`bgc.compiler.signatures.derive`), one that reads 0 in the
    mode "0" for every fault but a stuck switch's, and the stuck switches'
    (:func:`bgc.compiler.modes.stuck_signatures`)."""
    from ..compiler import signatures
    from ..compiler.modes import stuck_signatures

    ssm = m.equations
    live = tuple(x.name for x in cands if x.expr.free_symbols)
    zero = tuple(x.name for x in cands if not x.expr.free_symbols)
    every = signatures.derive(ssm, live, {x.name: x.shows for x in cands})
    nothing = ("0",) * (len(ssm.states) + 3)  # as deep as derive's: every integrator, a drift's order, and the value
    columns = tuple(ssm.outputs) + live + zero
    own = tuple(dataclasses.replace(s, symbols=s.symbols + (nothing,) * len(zero)) for s in every.signatures)
    return dataclasses.replace(every, measurements=columns,
                               signatures=own + tuple(stuck_signatures(c.model, mode, ssm, columns)))


def _known_costs(func: str, c, costs, names: set) -> None:
    """A one-line error when ``costs`` names what is neither a bond variable
    of ``c`` (its ``names``) nor one of its sensors (whose name prices a
    second sensor beside it: the only way to price one on a sensor whose
    model text is an expression no bond variable carries)."""
    sensors = {m.name for m in c.model.measurements}
    unknown = sorted(set(costs or ()) - names - sensors)
    if unknown:
        raise ArgumentValueError(f"{func}: costs names {unknown[0]!r}, neither a bond variable nor a sensor of "
                                 f"{c.model.name}", None, f"name efforts and flows of its bonds, e.g. "
                                 f"{sorted(names)[0]}, or a sensor, for a second sensor beside it")


def _place(func: str, c, model_, costs, most: int, qualitative: bool):
    """The placement of compilation ``c``'s sensors (:func:`analyse`)."""
    from ..analysis import placement

    _known_costs(func, c, costs, {name for name, _ in c.equations.variables})
    from ..compiler import signatures

    offsets = _no_offsets(c)
    measured = [e.subs(offsets) for e in c.equations.output_exprs]
    faulty = {f.subject for f in c.model.faults if f.target == "sensor"}  # a second sensor beside each of these
    cands = placement.candidates(c.equations, measured, costs, tuple(faulty),
                                 {m.name: m.text.strip() for m in c.model.measurements})
    every = signatures.derive(c.equations, tuple(x.name for x in cands), {x.name: x.shows for x in cands}) \
        if qualitative else None  # each one's symbols
    return placement.place(model_, c.equations, cands, most, every)


def with_sensors(model: str | Path, sensors, out: str | Path) -> Path:
    """Write ``model`` with measurements of the bond variables ``sensors``
    added (each named after its variable, or ``<variable>_sensor`` when that
    name is taken; its noise the model's default; an item may also be a pair
    (name, model text): a second sensor on an expression, ``("dP_2", "e2 -
    e10")``, :meth:`bgc.analysis.placement.Placement.written`) to the new file ``out``,
    never the model itself; the text is the model's, with a line per sensor
    and a comment above it, and reads back (checked). Returns ``out``."""
    from ..compiler import load, validate
    from ..output import artifacts
    from ..output.calibrated import TextChange, edit_text

    func = "bgc.analyse.with_sensors"
    arguments.path(func, "model", model)
    arguments.path(func, "out", out)
    target = Path(out)
    try:
        same = target.exists() and target.samefile(model)
    except OSError:
        same = False
    if same:
        raise ArgumentValueError(f"{func}: out={str(out)!r} is the model file: it is never replaced", None,
                                 "write the model with its sensors to a new file")
    artifacts.check_writable(target, "the model with its sensors")
    text = Path(model).read_text(encoding="utf-8")
    bg = validate.validate(load.loads(text, str(model)))
    taken = {m.name for m in bg.measurements} | {p.name for p in bg.parameters} | {u.name for u in bg.inputs}
    changes = []
    pairs = [(v, v) if isinstance(v, str) else tuple(v) for v in sensors]
    for wanted, v in pairs:
        name = wanted if wanted not in taken else f"{wanted}_sensor"
        taken.add(name)
        changes.append(TextChange(("measurements", name), f"{{expr: {v}}}",
                                  f"# bgc analyse --place-sensors: a sensor added on {v}"))
    out_text = edit_text(text, changes)
    added = {m.name for m in validate.validate(load.loads(out_text, str(out))).measurements} - \
        {m.name for m in bg.measurements}
    if len(added) != len(changes):
        from ..errors import InternalError

        raise InternalError(f"the model with its sensors does not read back with them ({sorted(added)})")
    head = (f"# {artifacts.MARK} analyse --place-sensors from {printable(str(model))}: "
            f"{', '.join(v for _, v in pairs)} added\n")
    artifacts.write_file(target, head + out_text)
    return target
