"""Experiment campaigns: many diagnoses of simulated runs, their metrics and tables.

A campaign file (YAML, ``schemas/campaign.schema.json``, documented in
``docs/experiments.md``) lists groups of runs: a model, scenarios (a grid of
``NAME:KIND:MAGNITUDE@TIME`` and ``none``) or randomised fault draws, times
filters, particle counts, noise levels and seeds. :func:`load_campaign` reads
and checks it (located one-line errors, like a model) and expands it into
:class:`RunSpec` s; :func:`run_one` simulates one scenario, diagnoses it with
:func:`bgc.diagnose` and measures the result (:mod:`bgc.experiment.metrics`);
:func:`run_campaign` runs the specs on local processes or on an existing Dask
distributed cluster, appends each row to ``runs.csv`` as it completes (an
interrupted campaign resumes from it), shows a progress bar and writes the
tables (:mod:`bgc.output.tables`) and plots at the end.

Every run is independent and seeded by its spec, so the same campaign gives
the same rows on one process, on many, or on a cluster (run times aside).

A campaign never runs away: its runs are counted before anything is expanded
(at most :data:`MAX_RUNS` unless the caller raises the limit), it starts no
more local processes than the runs to do, the cores (:data:`WORKERS_PER_CORE`
each) and the memory hold, its workers end when the campaign's process dies,
and a Dask scheduler that refuses the connection fails at once, one that
does not answer after a timeout (:data:`CONNECT_TIMEOUT` by default). It
never loses a row: ``runs.csv`` is read
line by line, every intact row is kept, and a line it cannot read is set
aside in a new ``runs.unread-N.csv`` beside it.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import io
import json
import math
import multiprocessing
import os
import signal
import socket
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

import jsonschema
import numpy as np

from .. import arguments, pipeline
from ..compiler import load
from ..compiler.validate import strict_validator
from ..errors import (ArgumentTypeError, ArgumentValueError, BgcError, ErrorGroup, ExperimentError, OutputError,
    printable)
from ..kinds import DIRECTIONS, FAULT_KINDS, fault_kind
from ..output.tables import row_label

if TYPE_CHECKING:
    from ..analysis import simulate

#: The columns of ``runs.csv``, in order (docs/experiments.md defines each).
COLUMNS = (
    "id", "index", "group", "model", "scenario", "fault", "kind", "magnitude", "onset", "ambiguous", "filter",
    "particles", "noise", "process_noise", "measurement_noise", "seed", "steps", "status", "failure", "rt",
    "mse", "nmse", "mse_states", "ct", "detected", "detection_time", "delay", "false_alarm", "verdict",
    "diagnosed", "candidates", "right", "in_candidates", "estimate", "low", "high", "est_error", "parameter",
    "parameter_truth", "param_error", "covers", "refine", "separable", "rivals", "separation", "detectability",
    "target", "diagnosed_target", "expected",
)
_INT = {"index", "particles", "seed", "steps"}
_BOOL = {"ambiguous", "detected", "false_alarm", "right", "in_candidates", "covers", "refine", "separable",
         "expected"}
_FLOAT = {"magnitude", "onset", "process_noise", "measurement_noise", "rt", "mse", "nmse", "ct", "detection_time",
          "delay", "estimate", "low", "high", "est_error", "parameter", "parameter_truth", "param_error",
          "separation", "detectability"}
#: Free-text columns: written on one line, neutralised against spreadsheet formulas (:func:`format_cell`).
_TEXT = frozenset(COLUMNS) - _INT - _BOOL - _FLOAT
RUNS = "runs.csv"
#: What the end of a campaign writes beside ``runs.csv`` (:func:`write_outputs`).
TABLES, SUMMARY, PLOTS, REPORT = "tables.md", "summary.json", "plots/", "report.html"
#: Lines of ``runs.csv`` that cannot be read are set aside in ``runs.unread-N.csv`` (N: the first free number).
UNREAD = "runs.unread-{n}.csv"
#: A text cell starting with one of these is a formula to a spreadsheet: ``runs.csv`` writes it after a
#: ``'`` (OWASP's rule against CSV injection), and so a text starting with ``'`` itself, to read back exactly.
_FORMULA = ("=", "+", "-", "@", "\t", "\r", "'")
#: The runs a campaign may plan unless the caller raises the limit (``load_campaign(max_runs=)``,
#: ``bgc experiment --max-runs``): counted before anything is expanded.
MAX_RUNS = 100_000
#: Local worker processes per core, at most: ``run_campaign`` refuses more.
WORKERS_PER_CORE = 4
#: The memory a local worker is assumed to need: fewer workers start when the available memory holds fewer.
#: Measured: a fresh process diagnosing the RO plant (gpf, N = 1000, 300 samples) peaks at 118 MB resident
#: (95 MB of it the imports, shared with the parent after a fork); twice that leaves room for longer runs.
WORKER_MEMORY = 256 * 2**20
#: Seconds to wait for a Dask scheduler (the TCP connection, then its handshake); ``--connect-timeout``.
CONNECT_TIMEOUT = 10.0


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

    @property
    def id(self) -> str:
        """A digest of everything that decides the run's result (a resumed
        campaign reuses a row whose id it plans again)."""
        fields = asdict(self)
        for name in ("index", "model"):  # where the run sits in the plan, how its file is called
            fields.pop(name)
        if not self.refine:  # the runs of campaigns from before the setting keep their ids
            fields.pop("refine")
        fields["model_text"] = hashlib.sha256(self.model_text.encode("utf-8")).hexdigest()
        return hashlib.sha256(json.dumps(fields, sort_keys=True).encode("utf-8")).hexdigest()[:16]

    def identity(self) -> dict[str, Any]:
        """The row's columns that say which run it is."""
        return {"id": self.id, "index": self.index, "group": self.group, "model": self.model,
                "scenario": self.scenario, "fault": self.fault, "kind": self.kind, "magnitude": self.magnitude,
                "onset": self.onset, "ambiguous": self.ambiguous, "filter": self.filter,
                "particles": self.particles, "noise": self.noise, "process_noise": self.process_noise,
                "measurement_noise": self.measurement_noise, "seed": self.seed, "steps": self.steps,
                "parameter_truth": self.parameter_truth, "refine": self.refine}


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
    """A checked campaign: its runs in order and its tables."""

    name: str
    description: str
    source: str
    sha256: str
    specs: tuple[RunSpec, ...]
    tables: tuple[TableSpec, ...]
    groups: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class CampaignStart:
    """What :func:`run_campaign` is about to do, once it has read its folder
    (given to its ``on_start`` before the first run starts).

    Attributes
    ----------
    total, todo, reused
        The campaign's runs, those to run now, those whose rows it reuses.
    quarantined, quarantine
        Lines of ``runs.csv`` that could not be read, and the new file that
        holds them as they were (None when there were none).
    workers
        Local processes to start (0: nothing to run); None on a Dask cluster.
    requested
        The ``workers`` asked for (None: the default, one per core).
    limited_by
        Why fewer processes start than asked for or than the default:
        ``"runs"`` (no more than the runs to do) or ``"memory"`` (the
        available memory, :data:`WORKER_MEMORY` each); None otherwise.
    """

    total: int
    todo: int
    reused: int
    quarantined: int
    quarantine: Path | None
    workers: int | None
    requested: int | None
    limited_by: str | None


@dataclass(frozen=True, slots=True)
class CampaignResult:
    """A finished campaign: its rows in run order and what was done.
    ``quarantined`` lines of ``runs.csv`` could not be read and are kept in
    ``quarantine``; ``workers``: the local processes used (None: Dask)."""

    campaign: Campaign
    rows: tuple[dict[str, Any], ...]
    ran: int
    reused: int
    failed: int
    seconds: float
    folder: Path
    quarantined: int = 0
    quarantine: Path | None = None
    workers: int | None = None


@dataclass(frozen=True, slots=True)
class RunsFile:
    """What :func:`read_runs` found in a ``runs.csv``: the rows it read, and
    the lines it could not read (``unread``: their bytes as in the file,
    ``unread_lines``: how many)."""

    rows: tuple[dict[str, Any], ...]
    unread: bytes
    unread_lines: int


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
                "refine": [False],
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
    return Campaign(data["campaign"], data.get("description", ""), str(path), raw.sha256, tuple(specs),
                    tuple(tables), tuple(group_names))


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
    filters x particle counts x refine settings x seeds.

    >>> group_size({"scenarios": ["none", "R1:abrupt:1@2"]}, {"noise": ["model"], "filters": ["gpf", "apf"],
    ...            "particles": [100, 1000], "refine": [False], "seeds": 10})
    80
    """
    scenarios = len(group["scenarios"]) if "scenarios" in group else group["draws"]["count"]
    seeds = settings["seeds"]
    seeds = seeds if isinstance(seeds, int) else len(seeds)
    return (scenarios * len(settings["noise"]) * len(settings["filters"]) * len(settings["particles"])
            * len(settings["refine"]) * seeds)


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
        f"{sizes[big]:,} = scenarios x noise levels x filters x particle counts x refine settings x seeds)",
        raw.loc("groups", big), "make the grid smaller, or raise the limit: bgc experiment --max-runs N, "
        "load_campaign(path, max_runs=N)")


def _group_specs(c: pipeline.Compiled, model_path: Path, group: dict, settings: dict, where: tuple, raw,
                 campaign_seed: int, g_index: int, first_index: int) -> list[RunSpec]:
    from .. import api
    from ..analysis import simulate

    num = c.numerics
    steps = settings["steps"] or c.model.settings.steps
    dt = c.model.settings.dt
    try:
        simulate.check_steps(steps, num, "steps")
        for method in settings["filters"]:  # what the diagnosis of a run this long may take
            api.check_diagnosis_steps(steps, num, max(settings["particles"]), method, "steps")
    except BgcError as exc:
        raise ExperimentError(exc.what, raw.loc(*where, "steps"), exc.fix) from None
    duration = steps * dt
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
        if inj is not None:
            truth_value = inj.value(float(_nominal(c, inj)), duration)
        for noise, process, measurement in noises:
            for method in settings["filters"]:
                for particles, refine in [(p, r) for p in settings["particles"] for r in settings["refine"]]:
                    for seed in run_seeds:
                        out.append(RunSpec(
                            first_index + len(out), group["name"], _display(model_path), c.model.name, text,
                            scenario, inj.parameter if inj else None, inj.kind if inj else None,
                            inj.magnitude if inj else None, inj.time if inj else None,
                            bool(inj and f"{inj.parameter}:{inj.kind}" in ambiguous), truth_value, method,
                            int(particles), noise, process, measurement, int(seed), steps, bool(refine)))
    return out


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


# ------------------------------------------------------------------ one run
_MODEL_FILES: dict[str, str] = {}
_MODEL_DIR: dict[int, str] = {}  # process id -> its private folder (a forked worker makes its own)


def _model_file(spec: RunSpec) -> str:
    """The model's text written once per process into a private folder (a
    worker on another machine has no copy of the campaign's files)."""
    from ..api import private_folder

    with _MODEL_LOCK:  # the threads of a Dask worker share the folder
        return _write_model(spec, private_folder)


_MODEL_LOCK = threading.Lock()

#: This worker's sessions (bgc.open) by process, model file and noise levels: a campaign worker diagnoses
#: many runs of a few models, each compiled once (the runner's state, outside the diagnosis).
_SESSIONS: dict[tuple, Any] = {}


def _session(spec: RunSpec, process_noise: float | None, measurement_noise: float | None, backend: str = "numpy"):
    """The session of the run's model at these noise levels on ``backend`` in this process, opened once."""
    from .. import api

    key = (os.getpid(), _model_file(spec), process_noise, measurement_noise, backend)
    with _MODEL_LOCK:
        if key not in _SESSIONS:
            if any(k[0] != key[0] for k in _SESSIONS):  # a forked worker: its parent's sessions are not its own
                _SESSIONS.clear()
            _SESSIONS[key] = api.open(key[1], process_noise=process_noise, measurement_noise=measurement_noise,
                                      backend=backend)
        return _SESSIONS[key]


def _write_model(spec: RunSpec, private_folder) -> str:
    pid = os.getpid()
    if pid not in _MODEL_DIR:  # never share the folder a parent process made: workers would race
        _MODEL_FILES.clear()
        _MODEL_DIR[pid] = private_folder("bgc-campaign-")
    digest = hashlib.sha256(spec.model_text.encode("utf-8")).hexdigest()[:16]
    if digest not in _MODEL_FILES:
        path = Path(_MODEL_DIR[pid]) / digest / f"{spec.model_name}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(spec.model_text, encoding="utf-8")
        _MODEL_FILES[digest] = str(path)
    return _MODEL_FILES[digest]


def run_one(spec: RunSpec, backend: str = "numpy") -> dict[str, Any]:
    """Simulate, diagnose and measure one run; a row of ``runs.csv``
    (``backend``: the generated package the filters run on; the row does
    not depend on it).

    It never raises: a run that fails (any exception: a diverging
    simulation, a bug) is a row with ``status`` failed and the error in
    ``failure``, and the campaign goes on.
    """
    from .. import api
    from . import metrics
    from ..analysis import simulate
    from ..diagnosis.options import DiagnosisOptions

    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(spec.identity())
    try:
        options = DiagnosisOptions(method=spec.filter, particles=spec.particles, seed=spec.seed, workers=1,
                                   refine=spec.refine, switch=False)  # a campaign measures the filter it names
        session = _session(spec, spec.process_noise, spec.measurement_noise, backend)
        report = api.diagnose(session, scenario=spec.scenario, seed=spec.seed, steps=spec.steps, options=options)
        d = report.diagnosis
        m = metrics.measure(d, report.run, metrics.Truth(spec.fault, spec.kind, spec.magnitude, spec.onset))
        best = d.best
        row.update(
            status="ok", rt=d.seconds, mse=float(np.mean(list(m.mse.values()))), nmse=m.nmse,
            mse_states=" ".join(f"{k}={v:.6g}" for k, v in m.mse.items()), ct=m.ct, detected=m.detected,
            detection_time=m.detection_time, delay=m.delay, false_alarm=m.false_alarm, verdict=m.verdict,
            diagnosed=m.diagnosed, candidates=" ".join(d.candidates) or None, right=m.right, in_candidates=m.in_candidates,
            estimate=m.estimate, low=m.low, high=m.high, est_error=m.error, covers=m.covers)
        injected = report.injected
        if injected is not None:
            row.update(target=injected.target,
                       expected=simulate.outside_prior(injected, session.compiled.numerics) is None)
        if m.diagnosed != "none" and best is not None:
            row["diagnosed_target"] = best.estimate.target
        if m.right and best is not None and spec.parameter_truth:  # relative: none for a truth of 0
            row["parameter"] = best.estimate.parameter_value
            row["param_error"] = abs(best.estimate.parameter_value - spec.parameter_truth) / abs(spec.parameter_truth)
        if spec.fault is not None:
            row.update(_separation(spec))
    except BgcError as exc:
        row.update(status="failed", failure=exc.line())
    except Exception as exc:  # noqa: BLE001 - a campaign records a failing run and goes on
        row.update(status="failed", failure=printable(f"{type(exc).__name__}: {exc}")[:500])
    return row


def _separation(spec: RunSpec) -> dict[str, Any]:
    """What the data of the run's scenario are predicted to separate
    (:func:`bgc.api.distinguishability`): ``separable`` (no rival in the
    predicted ambiguity group), ``rivals`` (those in it), ``separation``
    (the smallest probability that the data name the truth over a rival) and
    ``detectability`` (the probability that they favour the fault over no
    fault, were its onset and magnitude known: what an ideal detector sees);
    empty when the prediction fails (the diagnosis's row stands). It depends
    on the scenario, noise levels and length only, not on the filter or the
    seed: a process computes it once per scenario."""
    return dict(_prediction(_model_file(spec), spec.scenario, spec.process_noise, spec.measurement_noise,
                            spec.steps))


@functools.lru_cache(maxsize=64)
def _prediction(model_file: str, scenario: str, process_noise: float | None, measurement_noise: float | None,
                steps: int | None) -> tuple[tuple[str, Any], ...]:
    from .. import api

    try:
        compiled = next((v for k, v in _SESSIONS.items() if k[:2] == (os.getpid(), model_file)), model_file)
        d = api.distinguishability(compiled, scenario, process_noise=process_noise,  # the run's session: compiled
                                   measurement_noise=measurement_noise, steps=steps).distinctions[0]
    except Exception:  # noqa: BLE001 - the prediction is an extra: the diagnosis's row stands without it
        return ()
    return (("separable", d.separable), ("rivals", " ".join(d.group) or None),
            ("separation", min((r.probability for r in d.rivals), default=1.0)),
            ("detectability", d.detectability))


# ------------------------------------------------------------------ rows
def format_value(value: Any) -> str:
    """A value as ``runs.csv`` writes it (before :func:`format_cell`'s guard
    of text cells): a number as its shortest repr, a bool as true/false."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):  # a NumPy float's repr is np.float64(...): print the number
        return "nan" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def format_cell(column: str, value: Any) -> str:
    """The cell of ``column`` in ``runs.csv``. A text cell is one line
    (:func:`bgc.errors.printable`), so each row is one line of the file, and
    one that starts with ``= + - @``, a tab or a carriage return (a formula
    to a spreadsheet: OWASP's CSV-injection rule) is written after a ``'``,
    as is one that starts with ``'`` itself, so that :func:`parse_value`
    reads every one back exactly. Numeric cells are never touched (they may
    be negative).

    >>> format_cell("model", "=cmd|' -C calc'!A0.yaml"), format_cell("magnitude", -0.5)
    ("'=cmd|' -C calc'!A0.yaml", '-0.5')
    >>> parse_value("model", format_cell("model", "'quoted")), parse_value("model", format_cell("model", "-x"))
    ("'quoted", '-x')
    """
    text = format_value(value)
    if column in _TEXT:
        text = printable(text)
        if text.startswith(_FORMULA):
            text = "'" + text
    return text


def parse_value(column: str, text: str) -> Any:
    """A cell of ``runs.csv`` read back (:func:`format_cell` in reverse).

    Raises
    ------
    ValueError
        The cell is not a value of its column.
    """
    if text == "":
        return None
    if column in _INT:
        return int(text)
    if column in _FLOAT:
        return float(text)
    if column in _BOOL:
        low = text.lower()  # a spreadsheet saves TRUE and FALSE
        if low not in ("true", "false"):
            raise ValueError(text)
        return low == "true"
    return text[1:] if text.startswith("'") else text


def csv_header(c: Campaign) -> str:
    from ..output.artifacts import MARK

    buf = io.StringIO()
    buf.write(f"# {MARK} experiment from {printable(c.source)}: campaign {printable(c.name)}, one row per run\n")
    csv.writer(buf, lineterminator="\n").writerow(COLUMNS)
    return buf.getvalue()


def csv_row(row: dict[str, Any]) -> str:
    """One line of ``runs.csv`` (every cell on one line: :func:`format_cell`)."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([format_cell(k, row.get(k)) for k in COLUMNS])
    return buf.getvalue()


def read_runs(path: Path) -> RunsFile:
    """The rows of a ``runs.csv`` bgc wrote, read line by line (bgc writes a
    row per line), and the lines that cannot be read.

    Every intact row is read, whatever surrounds it. A line is unread when
    it is not UTF-8, does not parse as one CSV record of the header's
    columns (an unclosed quote, a cell over the csv module's field limit),
    holds a value its column cannot take, or has no newline at its end (the
    last line of a campaign interrupted while writing it). A byte-order mark
    at the start, Windows line ends, ``TRUE``/``FALSE`` and blank lines (a
    spreadsheet's save) are read. When the header is not a header of
    ``runs.csv`` (of this bgc or of one with fewer columns), no line can be
    read and every line is unread. A missing file has no rows.
    """
    from ..output.artifacts import MARK

    rows: list[dict[str, Any]] = []
    unread: list[bytes] = []
    header: tuple[str, ...] | None = None
    try:
        f = open(path, "rb")
    except OSError:
        return RunsFile((), b"", 0)
    with f:
        for number, raw in enumerate(f):
            data = raw[3:] if number == 0 and raw.startswith(b"\xef\xbb\xbf") else raw
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                unread.append(raw)
                continue
            if not text.strip():
                continue  # a blank line holds nothing
            if not text.endswith("\n"):  # cut short by an interruption
                unread.append(raw)
                continue
            body = text[:-1].removesuffix("\r")
            try:
                records = list(csv.reader([body], strict=True))
            except csv.Error:  # an unclosed quote, a cell over the field limit, ...
                unread.append(raw)
                continue
            if len(records) != 1:
                unread.append(raw)
                continue
            values = records[0]
            if header is None:
                if values and values[0].startswith("#") and MARK in body:  # bgc's comment line
                    continue
                if values and tuple(values) == COLUMNS[:len(values)] and "status" in values:
                    header = tuple(values)
                else:
                    unread.append(raw)
                continue
            if len(values) != len(header):
                unread.append(raw)
                continue
            try:
                row = dict.fromkeys(COLUMNS)
                row.update({k: parse_value(k, v) for k, v in zip(header, values)})
            except ValueError:
                unread.append(raw)
                continue
            row["refine"] = bool(row["refine"])
            rows.append(row)
    return RunsFile(tuple(rows), b"".join(unread), len(unread))


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``runs.csv`` (:func:`read_runs`, without its unread lines)."""
    return list(read_runs(path).rows)


def _set_aside(folder: Path, data: bytes) -> Path:
    """Write the unread lines of ``runs.csv`` into a new file beside it
    (:data:`UNREAD`, the first free number): bgc never overwrites it."""
    from ..output import artifacts

    for n in range(1, 100_000):
        path = folder / UNREAD.format(n=n)
        if path.exists() or path.is_symlink():
            continue
        try:
            return artifacts.write_new(path, data)
        except OutputError:  # made meanwhile by another process: the next number
            continue
    raise ExperimentError(f"{printable(str(folder))} holds too many {UNREAD.format(n='N')} files", None,
                          "move them away, then run the campaign again")


# ------------------------------------------------------------------ running
def cores() -> int:
    """The cores this process may run on (its CPU affinity where the system
    tells it, else every core)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worker_limit() -> int:
    """The most local worker processes a campaign may ask for:
    :data:`WORKERS_PER_CORE` per core."""
    return WORKERS_PER_CORE * cores()


def check_workers(workers: Any, name: str = "workers") -> int | None:
    """``workers`` when it is None (one per core) or an integer from 1 to
    :func:`worker_limit`; ``name`` is how the caller calls it in messages.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        Not an integer (a bool is not one), below 1, or above the limit.
    """
    if workers is None:
        return None
    if not arguments.is_integer(workers):
        raise ArgumentTypeError(f"{name} must be an integer or None, not {type(workers).__name__}", None,
                                "give a number of local processes, e.g. 4")
    limit = worker_limit()
    if workers < 1:
        raise ArgumentValueError(f"{name} is {workers}", None, f"give 1 to {limit} local processes")
    if workers > limit:
        raise ArgumentValueError(
            f"{name} {workers} is more than the limit of {limit} local processes ({WORKERS_PER_CORE} per core, "
            f"{cores()} cores)", None, f"give at most {limit}, or run on a Dask cluster with --scheduler")
    return int(workers)


def _available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux: MemAvailable), or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def local_workers(requested: int | None, todo: int) -> tuple[int, str | None]:
    """How many local processes to start for ``todo`` runs when
    ``requested`` (None: one per core) were asked for, and why fewer
    (``"runs"``, ``"memory"``, or None): never more than the runs to do, nor
    than the available memory holds at :data:`WORKER_MEMORY` each (at least
    one)."""
    if todo <= 0:
        return 0, None
    n = requested or cores()
    why = None
    if n > todo:
        n, why = todo, "runs"
    memory = _available_memory()
    if memory is not None and n > max(memory // WORKER_MEMORY, 1):
        n, why = max(memory // WORKER_MEMORY, 1), "memory"
    return n, why


def _compile_models(specs: list[RunSpec]) -> None:
    """Compile the compiled backend's kernels of every model of ``specs`` once,
    here, into numba's disk cache (bgc's cache folder is named by the model
    text, not its path): the local workers then load them instead of each
    compiling them."""
    from .. import api

    texts = {}
    for spec in specs:
        texts.setdefault(spec.model_text, spec)
    for spec in texts.values():
        api.open(_model_file(spec), backend="numba")


def _local(specs: list[RunSpec], workers: int, backend: str = "numpy") -> Iterator[tuple[RunSpec, dict]]:
    # fork where there is one: workers inherit the loaded modules and run from a
    # notebook or a script without a __main__ guard (spawn re-imports __main__)
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method),
                             initializer=_worker_start, initargs=(os.getpid(),)) as pool:
        futures = {pool.submit(run_one, s, backend): s for s in specs}
        try:
            for f in as_completed(futures):
                spec = futures[f]
                yield spec, _result(f, spec)
        finally:
            for f in futures:
                f.cancel()


#: prctl(2)'s option that has the kernel signal a process when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1


def _worker_start(parent: int) -> None:
    """The initializer of a local worker process: it ends when the campaign's
    process ends, however that ends (a SIGKILL too), instead of waiting for
    work forever. On Linux the kernel sends it SIGTERM when its parent dies
    (``prctl(PR_SET_PDEATHSIG)``); everywhere a daemon thread looks at its
    parent every 0.5 s. Either way it removes its private folders and exits."""
    signal.signal(signal.SIGTERM, _orphaned)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):  # no libc to call: the thread alone
            pass
    if os.getppid() != parent:  # the parent died before the signal was asked for
        _orphaned()
    threading.Thread(target=_watch_parent, args=(parent,), name="bgc-watch-parent", daemon=True).start()


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(0.5)
        if os.getppid() != parent:  # re-parented: the campaign's process has died
            _orphaned()


def _orphaned(*_signal: Any) -> None:
    """End this worker now: its folders removed (the finalizers of
    :func:`bgc.api.private_folder`; a worker skips atexit), no clean-up of
    the pool it served (its parent has gone)."""
    try:
        from multiprocessing import util

        from ..api import remove_private_folders

        remove_private_folders()  # also one made while the signal came, before its finalizer was registered
        util._run_finalizers(0)  # noqa: SLF001 - what multiprocessing runs at a worker's normal end
    except Exception:  # noqa: BLE001 - best effort: the exit below is what matters
        pass
    finally:
        os._exit(1)


def scheduler_endpoint(address: str) -> tuple[str, int] | None:
    """(host, port) of a Dask scheduler address reached over TCP
    (``tcp://``, ``tls://`` or a bare ``host:port``), None for another
    transport (``inproc://``, ``ucx://``, ...).

    >>> scheduler_endpoint("tcp://10.0.0.5:8786"), scheduler_endpoint("[::1]:9000"), scheduler_endpoint("ucx://h:1")
    (('10.0.0.5', 8786), ('::1', 9000), None)

    Raises
    ------
    ExperimentError
        The address has no host or no port, or its port is not a number
        from 1 to 65535.
    """
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme.lower() not in ("tcp", "tls"):
        return None
    rest = rest.split("/", 1)[0]
    if rest.startswith("["):  # [IPv6]:port
        host, _, tail = rest[1:].partition("]")
        port_text = tail[1:] if tail.startswith(":") else ""
    elif rest.count(":") == 1:
        host, port_text = rest.split(":")
    else:
        host, port_text = rest, ""
    fix = "give tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786 (a scheduler listens on port 8786 unless told otherwise)"
    if not host:
        raise ExperimentError(f"scheduler address {printable(address)} names no host", None, fix)
    if not port_text:
        raise ExperimentError(f"scheduler address {printable(address)} names no port", None, fix)
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ExperimentError(f"scheduler address {printable(address)}: port '{printable(port_text)}' is not a "
                              "number from 1 to 65535", None, fix)
    return host, int(port_text)


def check_scheduler(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Fail fast when no Dask scheduler answers at ``address``: one TCP
    connection to its host and port (a refused connection fails at once;
    Dask's client would retry it for its whole timeout), then Dask's
    handshake (a server that takes the connection but never answers holds
    Dask's client forever, one that answers something else can crash it),
    each within ``timeout`` seconds. Addresses of other transports than
    TCP and TLS are left to Dask.

    Raises
    ------
    ExperimentError
        The address is malformed, the host is unknown, refuses the
        connection, does not answer in time or is no Dask scheduler.
    """
    endpoint = scheduler_endpoint(address)
    if endpoint is None:
        return
    _tcp_probe(address, endpoint, timeout)
    _handshake_probe(address, timeout)


def _tcp_probe(address: str, endpoint: tuple[str, int], timeout: float) -> None:
    host, port = endpoint
    where = f"the Dask scheduler at {printable(address)}"
    start = "start one (dask scheduler; dask worker ADDRESS) or check the address and port"
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return
    except ConnectionRefusedError:
        raise ExperimentError(f"cannot reach {where}: connection refused (nothing listens at port {port})", None,
                              start) from None
    except socket.gaierror as exc:
        raise ExperimentError(f"cannot reach {where}: unknown host '{printable(host)}' ({printable(str(exc))})",
                              None, "check the host name") from None
    except (TimeoutError, socket.timeout):
        raise ExperimentError(f"cannot reach {where}: no answer within {timeout:g} s", None,
                              "check the address, the network and firewalls, or wait longer with "
                              "--connect-timeout SECONDS") from None
    except OSError as exc:
        raise ExperimentError(f"cannot reach {where}: {printable(exc.strerror or str(exc))}", None, start) from None


def _handshake_probe(address: str, timeout: float) -> None:
    """Dask's handshake with the scheduler, given up after ``timeout``
    seconds (in a thread of its own: the caller may be inside an event loop,
    as in a notebook)."""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    failure: list[BaseException] = []

    async def probe() -> None:
        comm = await asyncio.wait_for(connect(address, timeout=timeout, **Security().get_connection_args("client")),
                                      timeout)
        await comm.close()

    def run() -> None:
        try:
            asyncio.run(probe())
        except BaseException as exc:  # noqa: BLE001 - any failure means no scheduler: said below
            failure.append(exc)

    thread = threading.Thread(target=run, name="bgc-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout + 5.0)
    where = f"the Dask scheduler at {printable(address)}"
    if thread.is_alive() or (failure and isinstance(failure[0], (TimeoutError, asyncio.TimeoutError))):
        raise ExperimentError(f"cannot reach {where}: the server takes the connection but does not answer within "
                              f"{timeout:g} s", None, "check that it is the address dask scheduler prints, or wait "
                              "longer with --connect-timeout SECONDS")
    if failure:
        exc = failure[0]
        said = "not Dask's protocol" if isinstance(exc, MemoryError) else f"{type(exc).__name__}: {exc}"
        raise ExperimentError(f"cannot reach {where}: {printable(said)[:300]}", None,
                              "check that it is the address dask scheduler prints")


def _dask(specs: list[RunSpec], address: str, timeout: float, backend: str = "numpy"
          ) -> Iterator[tuple[RunSpec, dict]]:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:  # pragma: no cover - a dependency of bgc
        raise ExperimentError("--scheduler needs dask.distributed", None, "pip install 'dask[distributed]'") from None
    check_scheduler(address, timeout)
    try:
        client = Client(address, timeout=timeout)
    except Exception as exc:  # noqa: BLE001 - whatever Dask raises, the scheduler is out of reach
        raise ExperimentError(f"cannot reach the Dask scheduler at {printable(address)}: {printable(str(exc))}",
                              None, "start one (dask scheduler; dask worker ADDRESS), check the address, or wait "
                              "longer with --connect-timeout SECONDS") from None
    try:
        futures = client.map(run_one, specs, backend=backend, key=[f"bgc-run-{s.id}-{s.index}" for s in specs],
                             pure=False)
        by_key = {f.key: s for f, s in zip(futures, specs)}
        try:
            for f in dask_completed(futures):
                spec = by_key[f.key]
                yield spec, _result(f, spec)
        finally:
            client.cancel(futures)
    finally:
        client.close()


def _result(future, spec: RunSpec) -> dict[str, Any]:
    """A future's row; a worker that died or a task the engine lost is a failed run."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001
        row = dict.fromkeys(COLUMNS)
        row.update(spec.identity())
        row.update(status="failed", failure=printable(f"{type(exc).__name__}: {exc}")[:500])
        return row


def check_timeout(value: Any, name: str = "connect_timeout") -> float:
    """``value`` as seconds when it is a finite number above 0.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        Not a number (a bool is not one), or not finite and above 0.
    """
    if not arguments.is_real(value):
        raise ArgumentTypeError(f"{name} must be a number of seconds, not {type(value).__name__}", None,
                                f"give {name}={CONNECT_TIMEOUT:g}")
    seconds = arguments.as_float(value)
    if not (math.isfinite(seconds) and seconds > 0):
        raise ArgumentValueError(f"{name} is {printable(str(value))[:40]}", None,
                                 "give a finite number of seconds above 0")
    return seconds


def _check_arguments(c: Any, out: Any, scheduler: Any, progress: Any, outputs: Any, on_start: Any) -> None:
    if not isinstance(c, Campaign):
        raise ArgumentTypeError(f"the campaign must be a Campaign, not {type(c).__name__}", None,
                                "read it with bgc.experiment.campaign.load_campaign(path)")
    if not isinstance(out, (str, os.PathLike)) or not str(out):
        raise ArgumentTypeError(f"out must be a folder path, not {type(out).__name__}", None,
                                "give a str or pathlib.Path")
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise ArgumentTypeError(f"scheduler must be an address (str) or None, not {type(scheduler).__name__}",
                                None, "e.g. scheduler='tcp://10.0.0.5:8786'")
    if progress is not None and not isinstance(progress, (bool, np.bool_)):
        raise ArgumentTypeError(f"progress must be True, False or None, not {type(progress).__name__}", None,
                                "None: a progress bar when stderr is a terminal")
    if not isinstance(outputs, (bool, np.bool_)):
        raise ArgumentTypeError(f"outputs must be True or False, not {type(outputs).__name__}", None,
                                "True: write the tables and plots at the end")
    if on_start is not None and not callable(on_start):
        raise ArgumentTypeError(f"on_start must be callable or None, not {type(on_start).__name__}", None,
                                "give a function of one CampaignStart")


def run_campaign(c: Campaign, out: str | Path, scheduler: str | None = None, workers: int | None = None,
                 progress: bool | None = None, outputs: bool = True, connect_timeout: float = CONNECT_TIMEOUT,
                 on_start: Callable[[CampaignStart], None] | None = None, backend: str = "numpy") -> CampaignResult:
    """Run the campaign's runs not yet in ``out/runs.csv`` (a failed one is run
    again), append each row as it completes, then write the tables and plots.

    Parameters
    ----------
    c
        The campaign (:func:`load_campaign`).
    out
        Its folder: empty, or one this campaign wrote before (it resumes).
        The lines of its ``runs.csv`` that cannot be read are kept in a new
        ``runs.unread-N.csv`` (:func:`read_runs`).
    scheduler
        A Dask distributed scheduler's address; None: local processes.
    workers
        Local processes (None: one per core), at most :func:`worker_limit`;
        no more start than the runs to do or the memory holds
        (:func:`local_workers`). Not used with ``scheduler``.
    progress
        A progress bar on stderr (None: when stderr is a terminal).
    outputs
        Write ``tables.md``, ``report.html``, ``summary.json`` and the plots at the end.
    connect_timeout
        Seconds to wait for the scheduler (:func:`check_scheduler`, then
        Dask's handshake).
    backend
        The generated package the runs' filters use ('numpy', 'numba', or
        'auto': each worker's choice, numba where it is installed); the rows
        do not depend on it. With 'numba' and local workers, the models'
        kernels are compiled here first, once.
    on_start
        Called with a :class:`CampaignStart` once the folder is read, before
        the first run.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range.
    ExperimentError, OutputError
        The folder holds another campaign or files bgc did not write; the
        scheduler cannot be reached.
    """
    from ..output import artifacts

    _check_arguments(c, out, scheduler, progress, outputs, on_start)
    workers = check_workers(workers)
    connect_timeout = check_timeout(connect_timeout)
    started = time.perf_counter()
    folder = Path(out)
    previous = artifacts.read_manifest(folder) if folder.is_dir() else None
    if previous is not None and previous.get("campaign") != c.name:
        what = (f"campaign '{printable(str(previous.get('campaign')))}'" if previous.get("campaign")
                else "another bgc output (not a campaign)")
        raise ExperimentError(f"{printable(str(folder))} holds {what}", None, "choose another -o folder")
    # what the end writes is checked now, before any run (a tables.md the user edited, a link in plots/)
    outputs_now = {RUNS, TABLES, REPORT, SUMMARY} | {p for p in (previous or {}).get("files", {})
                                             if isinstance(p, str) and p.startswith(PLOTS)}
    artifacts.check_folder(folder, outputs_now, "experiment", adopt=(RUNS,))
    done, quarantine, unread = _finished(c, folder) if previous is not None else ({}, None, 0)
    todo = [s for s in c.specs if s.id not in done]
    rows_text = csv_header(c) + "".join(csv_row(r) for r in sorted(done.values(), key=lambda r: r["index"]))
    artifacts.write_folder(folder, {RUNS: rows_text, artifacts.MANIFEST: artifacts.manifest(
        {RUNS: rows_text}, "experiment", growing=(RUNS,), campaign=c.name, source=c.source)},
        adopt=(RUNS,) if previous is not None else ())
    n_workers, why = (None, None) if scheduler else local_workers(workers, len(todo))
    if on_start is not None:
        on_start(CampaignStart(len(c.specs), len(todo), len(done), unread, quarantine, n_workers, workers, why))
    by_id = {s.id: s for s in c.specs}
    rows = {k: {**v, **by_id[k].identity()} for k, v in done.items()}  # where it sits now, its model's path now
    failed = 0
    if todo:
        show = sys.stderr.isatty() if progress is None else bool(progress)
        bar = _bar(len(c.specs), len(done), c.name, show)
        if backend == "numba" and not scheduler:
            _compile_models(todo)
        source = (_dask(todo, scheduler, connect_timeout, backend) if scheduler
                  else _local(todo, n_workers, backend))
        try:
            with artifacts.GrowingFile(folder / RUNS) as runs_file:
                for spec, row in source:
                    rows[spec.id] = row
                    runs_file.append(csv_row(row))
                    failed += row["status"] != "ok"
                    bar.update(1)
                    bar.set_postfix(failed=failed, refresh=False)
        finally:
            bar.close()
    ordered = tuple(sorted(rows.values(), key=lambda r: r["index"]))
    result = CampaignResult(c, ordered, len(todo), len(done), failed, time.perf_counter() - started, folder,
                            unread, quarantine, n_workers)
    if outputs:
        write_outputs(result)
    return result


def _finished(c: Campaign, folder: Path) -> tuple[dict[str, dict[str, Any]], Path | None, int]:
    """The rows of the campaign's runs that finished in its folder before, by
    run id (the first of each), and the lines of its ``runs.csv`` that cannot
    be read: set aside in a new file (its path and their count) before the
    file is written again."""
    runs_path = folder / RUNS
    if runs_path.exists() and (runs_path.is_symlink() or not runs_path.is_file()):
        raise ExperimentError(f"{printable(str(runs_path))} is not a regular file bgc wrote", None,
                              "move it away, or choose another -o folder")
    found = read_runs(runs_path)
    quarantine = _set_aside(folder, found.unread) if found.unread_lines else None
    ids = {s.id for s in c.specs}
    done: dict[str, dict[str, Any]] = {}
    for row in found.rows:
        if row["status"] == "ok" and row["id"] in ids and row["id"] not in done:
            done[row["id"]] = row
    return done, quarantine, found.unread_lines


def _bar(total: int, initial: int, name: str, show: bool):
    from tqdm import tqdm

    tqdm.monitor_interval = 0  # no monitor thread in a process that forks workers
    return tqdm(total=total, initial=initial, desc=name, unit="run", disable=not show, dynamic_ncols=True,
                smoothing=0.1)


def write_outputs(result: CampaignResult) -> list[Path]:
    """``runs.csv`` (in run order), ``tables.md``, ``report.html`` (the tables and the plots in one
    self-contained page), ``summary.json`` and the plots."""
    from ..output import artifacts, plots, tables

    c = result.campaign
    files: dict[str, str | bytes] = {RUNS: csv_header(c) + "".join(csv_row(r) for r in result.rows)}
    files[TABLES] = tables.campaign_markdown(c, result.rows)
    files[SUMMARY] = tables.campaign_json(c, result.rows)
    figures = plots.campaign_figures(result.rows)
    files[REPORT] = tables.campaign_html(c, result.rows, figures)
    for name, data in figures.items():
        files[PLOTS + name] = data
    files[artifacts.MANIFEST] = artifacts.manifest(files, "experiment", campaign=c.name, source=c.source)
    return artifacts.write_folder(result.folder, files)


__all__ = ["COLUMNS", "CONNECT_TIMEOUT", "MAX_RUNS", "WORKERS_PER_CORE", "Campaign", "CampaignResult",
           "CampaignStart", "RunSpec", "RunsFile", "check_scheduler", "check_workers", "load_campaign",
           "local_workers", "read_rows", "read_runs", "run_campaign", "run_one", "schema", "worker_limit",
           "write_outputs"]
