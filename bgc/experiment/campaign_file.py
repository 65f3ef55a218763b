"""A campaign file read and checked (located one-line errors, like a model) and expanded into the
:class:`RunSpec` s of its runs (:func:`load_campaign`); runs are counted before any is expanded."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jsonschema
import numpy as np

from .. import arguments, pipeline
from ..compiler import load
from ..compiler.validate import signal_given, strict_validator
from ..errors import (ArgumentTypeError, ArgumentValueError, BgcError, ErrorGroup, ExperimentError, printable)
from ..kinds import DIRECTIONS, FAULT_KINDS, fault_kind
from ..output.tables import row_label

if TYPE_CHECKING:
    from ..analysis import simulate



#: The runs a campaign may plan unless the caller raises the limit (``load_campaign(max_runs=)``,
#: ``bgc experiment --max-runs``): counted before anything is expanded.
MAX_RUNS = 100_000


@dataclass(frozen=True, slots=True)
class RunSpec:
    """One run: simulate ``scenario`` of the model (``none``: fault-free) at
    the noise levels (None: the model's) with ``seed``, diagnose it with
    ``filter`` and ``particles``. ``model_text`` travels with the spec, so a
    worker on another machine needs no copy of the model file."""

    index: int
    group: str
    model: str
    model_name: str
    model_text: str
    scenario: str
    fault: str | None
    kind: str | None
    magnitude: float | None
    onset: float | None
    ambiguous: bool
    parameter_truth: float | None
    filter: str
    particles: int
    noise: str
    process_noise: float | None
    measurement_noise: float | None
    seed: int
    steps: int | None
    refine: bool = False
    #: The detector's families of tests (``detect:``; :data:`bgc.diagnosis.detect.TESTS`), the mean test first.
    detectors: tuple[str, ...] = ("mean",)
    #: The scenario read once, when the campaign was loaded (None: fault-free); its text is ``scenario``.
    injection: simulate.FaultInjection | None = field(default=None, compare=False)
    #: Inputs driven otherwise than the model says: (name, :class:`~bgc.ir.Signal`) pairs (``inputs:``).
    inputs: tuple = ()
    #: A model with modes: the group's controlled changes of mode (``MODE@TIME,...``; None: none given).
    modes: str | None = None

    @property
    def id(self) -> str:
        """A digest of everything that decides the run's result (a resumed
        campaign reuses a row whose id it plans again)."""
        fields = asdict(self)
        for name in ("index", "model", "injection"):  # where the run sits in the plan, how its file is called;
            fields.pop(name)  # the scenario's value (its text stands for it)
        if not self.refine:  # the runs of campaigns from before the setting keep their ids
            fields.pop("refine")
        if self.detectors == ("mean",):  # likewise
            fields.pop("detectors")
        if not self.inputs:  # likewise
            fields.pop("inputs")
        if self.modes is None:  # likewise
            fields.pop("modes")
        fields["model_text"] = hashlib.sha256(self.model_text.encode("utf-8")).hexdigest()
        return hashlib.sha256(json.dumps(fields, sort_keys=True).encode("utf-8")).hexdigest()[:16]

    def identity(self) -> dict[str, Any]:
        """The row's columns that say which run it is."""
        return {"id": self.id, "index": self.index, "group": self.group, "model": self.model,
                "scenario": self.scenario, "fault": self.fault, "kind": self.kind, "magnitude": self.magnitude,
                "onset": self.onset, "ambiguous": self.ambiguous, "filter": self.filter,
                "particles": self.particles, "noise": self.noise, "process_noise": self.process_noise,
                "measurement_noise": self.measurement_noise, "seed": self.seed, "steps": self.steps,
                "parameter_truth": self.parameter_truth, "refine": self.refine,
                "detectors": ",".join(self.detectors)}


@dataclass(frozen=True, slots=True)
class Reference:
    """Published numbers beside a table's cells: (row, filter) -> metric -> (mean, sd or None)."""

    source: str
    values: dict[tuple[str, str], dict[str, tuple[float, float | None]]]


@dataclass(frozen=True, slots=True)
class TableSpec:
    title: str
    groups: tuple[str, ...]
    rows: str
    scenarios: tuple[str, ...] | None
    metrics: tuple[str, ...]
    reference: Reference | None


@dataclass(frozen=True, slots=True)
class Campaign:
    """A checked campaign: its runs in order and its tables; ``states``: its
    models' states, each once in the order met (a column of ``runs.csv`` each)."""

    name: str
    description: str
    source: str
    sha256: str
    specs: tuple[RunSpec, ...]
    tables: tuple[TableSpec, ...]
    groups: tuple[str, ...]
    states: tuple[str, ...] = ()


def schema() -> dict:
    """The campaign file's JSON Schema (packaged; ``schemas/`` holds the published copy)."""
    return json.loads(resources.files("bgc").joinpath("schema/campaign.schema.json").read_text(encoding="utf-8"))


# ------------------------------------------------------------------ loading
def load_campaign(path: str | Path, max_runs: int = MAX_RUNS) -> Campaign:
    """Read, check and expand a campaign file.

    Parameters
    ----------
    path
        The campaign file (YAML).
    max_runs
        The most runs it may plan (default :data:`MAX_RUNS`). They are
        counted from the file, before any model is compiled or any seed,
        draw or run is expanded.

    Raises
    ------
    ErrorGroup, LoadError, ExperimentError
        Located one-line errors: the YAML, the schema, a model (its own
        errors name its file), a scenario, a draw range or a table that does
        not fit the model, more runs than ``max_runs``.
    ArgumentTypeError, ArgumentValueError
        ``max_runs`` is not an integer, or below 1.
    """
    check_count(max_runs, "max_runs")
    raw = load.load(path)
    data = raw.data
    errors: list[BgcError] = []
    if not isinstance(data, dict):
        raise ExperimentError("a campaign must be a mapping", raw.loc(), "start with 'campaign:' and 'groups:'")
    for err in strict_validator(schema(), finite=True).iter_errors(data):
        p = tuple(err.absolute_path)
        what, fix = _schema_message(err, p)
        errors.append(ExperimentError(what, raw.loc(*p), fix))
    if errors:
        raise ErrorGroup(errors)
    base = Path(path).parent
    defaults = {"steps": None, "filters": ["gpf"], "particles": [1000], "noise": ["model"], "seeds": 1,
                "refine": [False], "detect": ["mean"], "inputs": {},
                **data.get("defaults", {})}
    _check_size(data["groups"], defaults, raw, max_runs)
    specs: list[RunSpec] = []
    group_names: list[str] = []
    compiled: dict[Path, pipeline.Compiled] = {}
    for g_index, group in enumerate(data["groups"]):
        where = ("groups", g_index)
        if group["name"] in group_names:
            errors.append(ExperimentError(f"group name '{group['name']}' is used twice", raw.loc(*where, "name"),
                                          "give every group its own name"))
            continue
        group_names.append(group["name"])
        settings = {k: group.get(k, v) for k, v in defaults.items()}
        model_path = (base / group["model"]) if not Path(group["model"]).is_absolute() else Path(group["model"])
        if model_path not in compiled:
            if not model_path.is_file():
                errors.append(ExperimentError(f"model file {printable(str(model_path))} not found",
                                              raw.loc(*where, "model"), "the path is relative to the campaign file"))
                continue
            compiled[model_path] = pipeline.compile_model(model_path)
        c = compiled[model_path]
        if "modes" in group and not c.modes:
            errors.append(ExperimentError(f"modes: {printable(str(model_path))} has no modes", raw.loc(*where, "modes"),
                                          "drop the group's modes"))
            continue
        try:
            specs.extend(_group_specs(c, model_path, group, settings, where, raw, data.get("seed", 0), g_index,
                                      len(specs)))
        except BgcError as exc:
            errors.append(exc)
    seen: dict[str, RunSpec] = {}
    for spec in specs:
        if spec.id in seen:
            g = group_names.index(spec.group)
            errors.append(ExperimentError(
                f"group '{spec.group}' runs '{spec.scenario}' with the same filter, particles, noise and seed as "
                f"group '{seen[spec.id].group}' ('{seen[spec.id].scenario}')", raw.loc("groups", g),
                "list each scenario once (none, None and 'none ' are one scenario)"))
            break
        seen[spec.id] = spec
    tables = []
    for t_index, table in enumerate(data.get("tables", [])):
        try:
            tables.append(_table(table, ("tables", t_index), raw, group_names, specs))
        except BgcError as exc:
            errors.append(exc)
    if errors:
        raise ErrorGroup(errors)
    states = tuple(dict.fromkeys(s for c in compiled.values() for s in c.equations.states))
    return Campaign(data["campaign"], data.get("description", ""), str(path), raw.sha256, tuple(specs),
                    tuple(tables), tuple(group_names), states)


def check_count(value: Any, name: str) -> int:
    """``value`` when it is an integer of at least 1 (``max_runs``).

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        Not an integer (a bool is not one), or below 1.
    """
    if not arguments.is_integer(value):
        raise ArgumentTypeError(f"{name} must be an integer, not {type(value).__name__}", None,
                                f"give {name}=N with N >= 1")
    if value < 1:
        raise ArgumentValueError(f"{name} is {value}", None, "give an integer >= 1")
    return int(value)


def group_size(group: dict, settings: dict) -> int:
    """The runs a group of a schema-valid campaign file plans, counted
    without expanding anything: scenarios (or draws) x noise levels x
    filters x particle counts x refine settings x detectors x seeds.

    >>> group_size({"scenarios": ["none", "R1:abrupt:1@2"]}, {"noise": ["model"], "filters": ["gpf", "apf"],
    ...            "particles": [100, 1000], "refine": [False], "detect": ["mean", "all"], "seeds": 10})
    160
    """
    scenarios = len(group["scenarios"]) if "scenarios" in group else group["draws"]["count"]
    seeds = settings["seeds"]
    seeds = seeds if isinstance(seeds, int) else len(seeds)
    return (scenarios * len(settings["noise"]) * len(settings["filters"]) * len(settings["particles"])
            * len(settings["refine"]) * len(settings.get("detect", ["mean"])) * seeds)


def _check_size(groups: list[dict], defaults: dict, raw, max_runs: int) -> None:
    """Refuse a campaign of more than ``max_runs`` runs, before any is expanded."""
    sizes = [group_size(g, {k: g.get(k, v) for k, v in defaults.items()}) for g in groups]
    total = sum(sizes)
    if total <= max_runs:
        return
    big = max(range(len(sizes)), key=sizes.__getitem__)
    name = printable(str(groups[big].get("name")))
    raise ExperimentError(
        f"the campaign plans {total:,} runs, more than the limit of {max_runs:,} (group '{name}' alone: "
        f"{sizes[big]:,} = scenarios x noise levels x filters x particle counts x refine settings x detectors x "
        f"seeds)",
        raw.loc("groups", big), "make the grid smaller, or raise the limit: bgc experiment --max-runs N, "
        "load_campaign(path, max_runs=N)")


def _group_specs(c: pipeline.Compiled, model_path: Path, group: dict, settings: dict, where: tuple, raw,
                 campaign_seed: int, g_index: int, first_index: int) -> list[RunSpec]:
    from ..api import limits as api_limits
    from ..analysis import hybrid, simulate

    num = c.numerics
    steps = settings["steps"] or c.model.settings.steps
    dt = c.model.settings.dt
    try:
        simulate.check_steps(steps, num, "steps")
        for method in settings["filters"]:  # what the diagnosis of a run this long may take
            api_limits.check_diagnosis_steps(steps, num, max(settings["particles"]), method, "steps")
    except BgcError as exc:
        raise ExperimentError(exc.what, raw.loc(*where, "steps"), exc.fix) from None
    duration = steps * dt
    signals = _signals(c, group, settings, where, raw)
    detect = _detect(group, settings, where, raw)
    modes = group.get("modes")
    if modes is not None:
        try:
            hybrid.parse_schedule(modes, tuple(m.name for m in c.modes))
        except BgcError as exc:
            raise ExperimentError(exc.what.replace("--modes", "modes:"), raw.loc(*where, "modes"), exc.fix) from None
    seeds = settings["seeds"]
    seeds = list(range(seeds)) if isinstance(seeds, int) else list(seeds)
    noises = []
    for i, n in enumerate(settings["noise"]):
        noises.append(("model", None, None) if n == "model" else (n["name"], float(n["process"]), float(n["measurement"])))
    if len({n[0] for n in noises}) != len(noises):
        raise ExperimentError("two noise levels have the same name", raw.loc(*where, "noise"),
                              "name each noise level once")
    ambiguous = {name.replace("+", "").replace("-", "") for grp in c.signatures.ambiguity for name in grp}
    candidates = {f.parameter: f for f in c.model.faults}
    scenarios: list[tuple[str, simulate.FaultInjection | None, list[int]]] = []
    if "scenarios" in group:
        for i, text in enumerate(group["scenarios"]):
            if text.strip().lower() == "none":
                scenarios.append(("none", None, seeds))
                continue
            try:
                inj = simulate.parse_fault(text, num)
            except BgcError as exc:
                raise ExperimentError(exc.what.replace("--fault", "scenario"), raw.loc(*where, "scenarios", i),
                                      exc.fix) from None
            # a fault the model does not list is a scenario too: its verdict should be "unexplained"
            if not 0 < inj.time < duration:
                raise ExperimentError(f"scenario '{text}': onset {inj.time:g} is outside the run (0 to {duration:g})",
                                      raw.loc(*where, "scenarios", i), "choose an onset inside the run")
            scenarios.append((text.strip(), inj, seeds))
    else:
        draws = group["draws"]
        dwhere = where + ("draws",)
        lo, hi = draws["change"]
        o_lo, o_hi = draws["onset"]
        if not 0 < lo <= hi:
            raise ExperimentError(f"change range [{lo}, {hi}] is empty or starts at 0", raw.loc(*dwhere, "change"),
                                  "give 0 < low <= high, e.g. [0.2, 0.5]")
        if not 0 < o_lo <= o_hi < 1:
            raise ExperimentError(f"onset range [{o_lo}, {o_hi}] is not inside the run", raw.loc(*dwhere, "onset"),
                                  "give fractions of the run, 0 < low <= high < 1, e.g. [0.3, 0.6]")
        named: dict[str, list[str]] = {}  # a candidate's name in the model (a sensor: F12), or its symbol (F12_offset)
        for f in c.model.faults:
            named.setdefault(f.name, []).append(f.parameter)
            named.setdefault(f.parameter, [f.parameter])
        faults = []
        for i, name in enumerate(draws.get("faults", sorted(candidates))):
            if name not in named:
                raise ExperimentError(f"'{name}' is not a fault candidate of {c.model.name}",
                                      raw.loc(*dwhere, "faults", i),
                                      "candidates: " + ", ".join(sorted({f.name for f in c.model.faults})))
            faults += [p for p in named[name] if p not in faults]
        kinds = draws.get("kinds", list(FAULT_KINDS))
        pool = [(p, k) for p in faults for k in candidates[p].kinds if k in kinds]
        if not pool:
            raise ExperimentError("no fault candidate has these kinds", raw.loc(*dwhere, "kinds"),
                                  "list kinds the faults declare")
        prior = {(f.parameter, f.kind): f for f in num.faults}
        rng = np.random.default_rng([campaign_seed, g_index])
        for j in range(draws["count"]):
            p, k = pool[int(rng.integers(len(pool)))]
            sign = int(rng.choice(DIRECTIONS[candidates[p].direction]))
            change = float(rng.uniform(lo, hi))
            onset = min(max(round(float(rng.uniform(o_lo, o_hi)) * steps), 1), steps - 1) * dt  # a sample inside
            magnitude = simulate.change_magnitude(num, f"{p}:{k}", sign * change, duration)  # a drift: per run
            b_lo, b_hi = prior[(p, k)].prior
            if not b_lo <= magnitude <= b_hi:
                raise ExperimentError(f"a draw of {p}:{k} with change {sign * change:.3g} lies outside the prior of "
                                      f"its fault model ({b_lo:.4g} to {b_hi:.4g})", raw.loc(*dwhere, "change"),
                                      "draw smaller changes (the filters cannot estimate what their prior excludes)")
            text = f"{candidates[p].name}:{k}:{magnitude:.6g}@{onset:.12g}"
            inj = simulate.parse_fault(text, num)
            run_seeds = [int(np.random.SeedSequence([campaign_seed, g_index, j, s]).generate_state(1)[0])
                         for s in seeds]
            scenarios.append((text, inj, run_seeds))
    text = model_path.read_text(encoding="utf-8")
    out = []
    for scenario, inj, run_seeds in scenarios:
        truth_value = None
        if inj is not None and not inj.stuck:  # (a stuck switch has no value to estimate)
            truth_value = inj.value(float(_nominal(c, inj)), duration)
        for noise, process, measurement in noises:
            for method in settings["filters"]:
                for particles, refine, tests in [(p, r, d) for p in settings["particles"] for r in settings["refine"]
                                                 for d in detect]:
                    for seed in run_seeds:
                        out.append(RunSpec(
                            first_index + len(out), group["name"], _display(model_path), c.model.name, text,
                            scenario, inj.parameter if inj else None, inj.kind if inj else None,
                            inj.magnitude if inj else None, inj.time if inj else None,
                            bool(inj and f"{inj.parameter}:{inj.kind}" in ambiguous), truth_value, method,
                            int(particles), noise, process, measurement, int(seed), steps, bool(refine), tests,
                            inj, signals, modes))
    return out


def _detect(group: dict, settings: dict, where: tuple, raw) -> list[tuple[str, ...]]:
    """A group's ``detect`` (its own, else the defaults'): each item's
    families of tests (:func:`bgc.diagnosis.detect.tests_named`; the schema
    admits only names bgc has), two items naming the same families refused."""
    from ..diagnosis.detect import tests_named

    out: list[tuple[str, ...]] = []
    for i, item in enumerate(settings["detect"]):
        tests = tests_named(item)
        if tests in out:
            at = raw.loc(*where, "detect", i) if "detect" in group else raw.loc("defaults", "detect", i)
            raise ExperimentError(f"detect: '{printable(item)}' names the same tests as an item before it "
                                  f"({', '.join(tests)}; the mean test is always run)", at, "list each set once")
        out.append(tests)
    return out


def _signals(c: pipeline.Compiled, group: dict, settings: dict, where: tuple, raw) -> tuple:
    """A group's ``inputs`` (its own, else the defaults'): (name,
    :class:`~bgc.ir.Signal`) pairs in the model's order, checked as the
    model's signals are."""
    names = tuple(u.name for u in c.model.inputs)
    at = where + ("inputs",) if "inputs" in group else ("defaults", "inputs")
    out = {}
    for name, spec in settings["inputs"].items():
        try:
            out[name] = signal_given(name, spec, names, "inputs")
        except BgcError as exc:
            raise ExperimentError(exc.what, raw.loc(*at, name), exc.fix) from None
    return tuple((name, out[name]) for name in names if name in out)


def _nominal(c: pipeline.Compiled, inj: simulate.FaultInjection) -> float:
    """The nominal value of what the injected fault changes: the parameter's,
    or a sensor's or actuator's fault symbol's (also when the model does not
    list the fault)."""
    values = dict(zip(c.equations.parameters, c.equations.parameter_values))
    if inj.parameter in values:
        return values[inj.parameter]
    return fault_kind(inj.kind).nominal


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _table(table: dict, where: tuple, raw, group_names: list[str], specs: list[RunSpec]) -> TableSpec:
    for i, g in enumerate(table["groups"]):
        if g not in group_names:
            raise ExperimentError(f"table '{table['title']}' names no group '{g}'", raw.loc(*where, "groups", i),
                                  "groups: " + ", ".join(group_names))
    rows = table.get("rows", "scenario")
    ref = None
    if "reference" in table:
        labels = {row_label(s.identity(), rows) for s in specs if s.group in table["groups"]}
        values: dict[tuple[str, str], dict[str, tuple[float, float | None]]] = {}
        for i, v in enumerate(table["reference"]["values"]):
            if str(v["row"]) not in labels:
                raise ExperimentError(f"reference row '{v['row']}' is not a row of table '{table['title']}'",
                                      raw.loc(*where, "reference", "values", i, "row"),
                                      "rows: " + ", ".join(sorted(labels)))
            cell = {}
            for k, x in v.items():
                if k in ("row", "filter"):
                    continue
                if k not in table["metrics"]:
                    raise ExperimentError(f"reference metric '{k}' is not a metric of table '{table['title']}'",
                                          raw.loc(*where, "reference", "values", i, k),
                                          "metrics: " + ", ".join(table["metrics"]))
                cell[k] = (float(x[0]), float(x[1])) if isinstance(x, list) else (float(x), None)
            values[(str(v["row"]), v["filter"])] = cell
        ref = Reference(table["reference"]["source"], values)
    return TableSpec(table["title"], tuple(table["groups"]), rows, tuple(table["scenarios"]) if "scenarios" in table
                     else None, tuple(table["metrics"]), ref)


def _schema_message(err: jsonschema.ValidationError, path: tuple) -> tuple[str, str]:
    where = ".".join(str(p) for p in path) or "the campaign"
    v = err.validator
    if v == "additionalProperties":
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        return (f"unknown key '{extra[0] if extra else '?'}' in {where}",
                "allowed keys: " + ", ".join(sorted(err.schema.get("properties", {}))))
    if v == "required":
        missing = err.message.split("'")[1] if "'" in err.message else err.message
        return f"{where} is missing '{missing}'", f"add '{missing}: ...' (docs/experiments.md)"
    if v == "enum":
        return (f"'{err.instance}' is not valid for {where}",
                "choose one of: " + ", ".join(str(o) for o in err.validator_value))
    if v == "type":
        want = err.validator_value if isinstance(err.validator_value, str) else " or ".join(err.validator_value)
        return f"{where} must be {want}, not {type(err.instance).__name__}", f"write {want} here"
    if v == "oneOf" and path and isinstance(path[-1], int) and len(path) == 2 and path[0] == "groups":
        return (f"{where} must give either 'scenarios' or 'draws'",
                "a group is a grid of scenarios or randomised draws, not both")
    if v == "oneOf" and err.context:  # say what is wrong with the form it comes nearest to
        # the branch that got furthest into the value is the form meant
        sub = max(err.context, key=lambda e: (len(e.absolute_path), e.validator not in ("const", "type")))
        return _schema_message(sub, tuple(sub.absolute_path))
    if v == "oneOf":
        return f"{where} has no valid form", "see docs/experiments.md for what it may be"
    if v == "pattern":
        return f"name '{err.instance}' in {where} has characters a name may not have", "use letters, digits, _ . + -"
    if v in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        return f"{where} is {err.instance}, out of range ({err.message.split(' is ')[-1]})", "choose a value in range"
    if v in ("minItems", "maxItems"):
        return f"{where} has {len(err.instance)} items ({err.message.split(' is ')[-1]})", "change the list's length"
    if v == "uniqueItems":
        return f"{where} lists an item twice", "list each item once"
    return f"{where}: {err.message[:200]}", "see docs/experiments.md"
