"""Experiment campaigns: many diagnoses of simulated runs, their metrics and tables.

A campaign file (YAML, ``schemas/campaign.schema.json``, documented in
``docs/experiments.md``) lists groups of runs: a model, scenarios (a grid of
``PARAM:KIND:MAGNITUDE@TIME`` and ``none``) or randomised fault draws, times
filters, particle counts, noise levels and seeds. :func:`load_campaign` reads
and checks it (located one-line errors, like a model) and expands it into
:class:`RunSpec` s; :func:`run_one` simulates one scenario, diagnoses it with
:func:`bgc.diagnose` and measures the result (:mod:`bgc.runtime.metrics`);
:func:`run_campaign` runs the specs on local processes or on an existing Dask
distributed cluster, appends each row to ``runs.csv`` as it completes (an
interrupted campaign resumes from it), shows a progress bar and writes the
tables (:mod:`bgc.output.tables`) and plots at the end.

Every run is independent and seeded by its spec, so the same campaign gives
the same rows on one process, on many, or on a cluster (run times aside).
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
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator

import jsonschema
import numpy as np

from . import pipeline
from .compiler import load
from .errors import BgcError, ExperimentError, ErrorGroup, printable
from .kinds import DIRECTIONS, FAULT_KINDS, fault_kind
from .output.tables import row_label

#: The columns of ``runs.csv``, in order (docs/experiments.md defines each).
COLUMNS = (
    "id", "index", "group", "model", "scenario", "fault", "kind", "magnitude", "onset", "ambiguous", "filter",
    "particles", "noise", "process_noise", "measurement_noise", "seed", "steps", "status", "failure", "rt",
    "mse", "nmse", "mse_states", "ct", "detected", "detection_time", "delay", "false_alarm", "verdict",
    "diagnosed", "candidates", "right", "in_candidates", "estimate", "low", "high", "est_error", "parameter",
    "parameter_truth", "param_error", "covers", "refine", "separable", "rivals", "separation", "detectability",
)
_INT = {"index", "particles", "seed", "steps"}
_BOOL = {"ambiguous", "detected", "false_alarm", "right", "in_candidates", "covers", "refine", "separable"}
_FLOAT = {"magnitude", "onset", "process_noise", "measurement_noise", "rt", "mse", "nmse", "ct", "detection_time",
          "delay", "estimate", "low", "high", "est_error", "parameter", "parameter_truth", "param_error",
          "separation", "detectability"}
RUNS = "runs.csv"


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
class CampaignResult:
    campaign: Campaign
    rows: tuple[dict[str, Any], ...]
    ran: int
    reused: int
    failed: int
    seconds: float
    folder: Path


def schema() -> dict:
    """The campaign file's JSON Schema (packaged; ``schemas/`` holds the published copy)."""
    return json.loads(resources.files("bgc").joinpath("schema/campaign.schema.json").read_text(encoding="utf-8"))


# ------------------------------------------------------------------ loading
def load_campaign(path: str | Path) -> Campaign:
    """Read, check and expand a campaign file.

    Raises
    ------
    ErrorGroup, LoadError, ExperimentError
        Located one-line errors: the YAML, the schema, a model (its own
        errors name its file), a scenario, a draw range or a table that does
        not fit the model.
    """
    raw = load.load(path)
    data = raw.data
    errors: list[BgcError] = []
    if not isinstance(data, dict):
        raise ExperimentError("a campaign must be a mapping", raw.loc(), "start with 'campaign:' and 'groups:'")
    for err in jsonschema.Draft202012Validator(schema()).iter_errors(data):
        p = tuple(err.absolute_path)
        what, fix = _schema_message(err, p)
        errors.append(ExperimentError(what, raw.loc(*p), fix))
    if errors:
        raise ErrorGroup(errors)
    base = Path(path).parent
    defaults = {"steps": None, "filters": ["gpf"], "particles": [1000], "noise": ["model"], "seeds": 1,
                "refine": [False],
                **data.get("defaults", {})}
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


def _group_specs(c: pipeline.Compiled, model_path: Path, group: dict, settings: dict, where: tuple, raw,
                 campaign_seed: int, g_index: int, first_index: int) -> list[RunSpec]:
    from .runtime import simulate

    num = c.numerics
    steps = settings["steps"] or c.model.settings.steps
    dt = c.model.settings.dt
    try:
        simulate.check_steps(steps, num, "steps")
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
            if inj.parameter not in candidates or inj.kind not in candidates[inj.parameter].kinds:
                raise ExperimentError(f"scenario '{text}': {inj.parameter}:{inj.kind} is not a fault candidate of "
                                      f"{c.model.name}", raw.loc(*where, "scenarios", i),
                                      "candidates: " + ", ".join(f"{f.parameter}:{k}" for f in c.model.faults
                                                                 for k in f.kinds))
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
        faults = draws.get("faults", sorted(candidates))
        for i, name in enumerate(faults):
            if name not in candidates:
                raise ExperimentError(f"'{name}' is not a fault candidate of {c.model.name}",
                                      raw.loc(*dwhere, "faults", i), "candidates: " + ", ".join(sorted(candidates)))
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
            nominal = prior[(p, k)].nominal
            size = sign * change * abs(nominal)
            magnitude = size / duration if fault_kind(k).drifts else size  # a drift: that change per run length
            b_lo, b_hi = prior[(p, k)].prior
            if not b_lo <= magnitude <= b_hi:
                raise ExperimentError(f"a draw of {p}:{k} with change {sign * change:.3g} lies outside the prior of "
                                      f"its fault model ({b_lo:.4g} to {b_hi:.4g})", raw.loc(*dwhere, "change"),
                                      "draw smaller changes (the filters cannot estimate what their prior excludes)")
            text = f"{p}:{k}:{magnitude:.6g}@{onset:.12g}"
            inj = simulate.parse_fault(text, num)
            run_seeds = [int(np.random.SeedSequence([campaign_seed, g_index, j, s]).generate_state(1)[0])
                         for s in seeds]
            scenarios.append((text, inj, run_seeds))
    text = model_path.read_text(encoding="utf-8")
    out = []
    for scenario, inj, run_seeds in scenarios:
        truth_value = None
        if inj is not None:
            truth_value = inj.value(float(_nominal(c, inj.parameter)), duration)
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


def _nominal(c: pipeline.Compiled, parameter: str) -> float:
    for f in c.numerics.faults:
        if f.parameter == parameter:
            return f.nominal
    raise KeyError(parameter)


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
    from .api import private_folder

    with _MODEL_LOCK:  # the threads of a Dask worker share the folder
        return _write_model(spec, private_folder)


_MODEL_LOCK = threading.Lock()


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


def run_one(spec: RunSpec) -> dict[str, Any]:
    """Simulate, diagnose and measure one run; a row of ``runs.csv``.

    It never raises: a run that fails (any exception: a diverging
    simulation, a bug) is a row with ``status`` failed and the error in
    ``failure``, and the campaign goes on.
    """
    from . import api
    from .runtime import metrics
    from .runtime.diagnose import DiagnosisOptions

    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(spec.identity())
    try:
        options = DiagnosisOptions(method=spec.filter, particles=spec.particles, seed=spec.seed, workers=1,
                                   refine=spec.refine, switch=False)  # a campaign measures the filter it names
        report = api.diagnose(_model_file(spec), scenario=spec.scenario, seed=spec.seed,
                              process_noise=spec.process_noise, measurement_noise=spec.measurement_noise,
                              steps=spec.steps, options=options)
        d = report.diagnosis
        m = metrics.measure(d, report.run, metrics.Truth(spec.fault, spec.kind, spec.magnitude, spec.onset))
        best = d.best
        row.update(
            status="ok", rt=d.seconds, mse=float(np.mean(list(m.mse.values()))), nmse=m.nmse,
            mse_states=" ".join(f"{k}={v:.6g}" for k, v in m.mse.items()), ct=m.ct, detected=m.detected,
            detection_time=m.detection_time, delay=m.delay, false_alarm=m.false_alarm, verdict=m.verdict,
            diagnosed=m.diagnosed, candidates=" ".join(d.candidates) or None, right=m.right, in_candidates=m.in_candidates,
            estimate=m.estimate, low=m.low, high=m.high, est_error=m.error, covers=m.covers)
        if m.right and best is not None and spec.parameter_truth is not None:
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
    from . import api

    try:
        d = api.distinguishability(model_file, scenario, process_noise=process_noise,
                                   measurement_noise=measurement_noise, steps=steps).distinctions[0]
    except Exception:  # noqa: BLE001 - the prediction is an extra: the diagnosis's row stands without it
        return ()
    return (("separable", d.separable), ("rivals", " ".join(d.group) or None),
            ("separation", min((r.probability for r in d.rivals), default=1.0)),
            ("detectability", d.detectability))


# ------------------------------------------------------------------ rows
def format_value(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):  # a NumPy float's repr is np.float64(...): print the number
        return "nan" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def parse_value(column: str, text: str) -> Any:
    if text == "":
        return None
    if column in _INT:
        return int(text)
    if column in _FLOAT:
        return float(text)
    if column in _BOOL:
        if text not in ("true", "false"):
            raise ValueError(text)
        return text == "true"
    return text


def csv_header(c: Campaign) -> str:
    from .output.artifacts import MARK

    buf = io.StringIO()
    buf.write(f"# {MARK} experiment from {printable(c.source)}: campaign {c.name}, one row per run\n")
    csv.writer(buf, lineterminator="\n").writerow(COLUMNS)
    return buf.getvalue()


def csv_row(row: dict[str, Any]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([format_value(row.get(k)) for k in COLUMNS])
    return buf.getvalue()


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``runs.csv`` bgc wrote; a last line cut short by an
    interruption, or any line that does not parse, is skipped (it is run again)."""
    out = []
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return out
    # a line without its newline was cut by an interruption: run again
    lines = [ln for ln in text.splitlines(keepends=True) if not ln.startswith("#") and ln.endswith("\n")]
    if not lines:
        return out
    reader = csv.reader(lines)
    header = tuple(next(reader, None) or ())
    if not header or COLUMNS[: len(header)] != header:  # a file of this version, or of one with fewer columns
        return out
    for values in reader:
        if len(values) != len(header):
            continue
        try:
            row = dict.fromkeys(COLUMNS)
            row.update({k: parse_value(k, v) for k, v in zip(header, values)})
            row["refine"] = bool(row["refine"])
            out.append(row)
        except ValueError:
            continue
    return out


# ------------------------------------------------------------------ running
def _local(specs: list[RunSpec], workers: int) -> Iterator[tuple[RunSpec, dict]]:
    # fork where there is one: workers inherit the loaded modules and run from a
    # notebook or a script without a __main__ guard (spawn re-imports __main__)
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method)) as pool:
        futures = {pool.submit(run_one, s): s for s in specs}
        try:
            for f in as_completed(futures):
                spec = futures[f]
                yield spec, _result(f, spec)
        finally:
            for f in futures:
                f.cancel()


def _dask(specs: list[RunSpec], address: str) -> Iterator[tuple[RunSpec, dict]]:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:  # pragma: no cover - a dependency of bgc
        raise ExperimentError("--scheduler needs dask.distributed", None, "pip install 'dask[distributed]'") from None
    try:
        client = Client(address, timeout=30)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ExperimentError(f"cannot reach the Dask scheduler at {printable(address)}: {exc}", None,
                              "start one (dask scheduler; dask worker ADDRESS) or check the address") from None
    try:
        futures = client.map(run_one, specs, key=[f"bgc-run-{s.id}-{s.index}" for s in specs], pure=False)
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


def run_campaign(c: Campaign, out: str | Path, scheduler: str | None = None, workers: int | None = None,
                 progress: bool | None = None, outputs: bool = True) -> CampaignResult:
    """Run the campaign's runs not yet in ``out/runs.csv`` (a failed one is run
    again) on ``workers`` local processes (default: every core) or on the
    Dask cluster at ``scheduler``; append each row as it completes, then write
    the tables and plots (``outputs``).

    ``progress``: a progress bar on stderr (None: when stderr is a terminal).
    """
    from .output import artifacts

    started = time.perf_counter()
    folder = Path(out)
    previous = artifacts.read_manifest(folder) if folder.is_dir() else None
    if previous is not None and previous.get("campaign") != c.name:
        what = (f"campaign '{printable(str(previous.get('campaign')))}'" if previous.get("campaign")
                else "another bgc output (not a campaign)")
        raise ExperimentError(f"{printable(str(folder))} holds {what}", None, "choose another -o folder")
    ids = {s.id for s in c.specs}
    done = {}
    if previous is not None:
        for row in read_rows(folder / RUNS):
            if row["status"] == "ok" and row["id"] in ids:
                done[row["id"]] = row
    todo = [s for s in c.specs if s.id not in done]
    rows_text = csv_header(c) + "".join(csv_row(r) for r in sorted(done.values(), key=lambda r: r["index"]))
    artifacts.write_folder(folder, {RUNS: rows_text, artifacts.MANIFEST: artifacts.manifest(
        {RUNS: rows_text}, campaign=c.name, source=c.source)})
    by_id = {s.id: s for s in c.specs}
    rows = {k: {**v, **by_id[k].identity()} for k, v in done.items()}  # where it sits now, its model's path now
    failed = 0
    if todo:
        show = sys.stderr.isatty() if progress is None else progress
        bar = _bar(len(c.specs), len(done), c.name, show)
        source = _dask(todo, scheduler) if scheduler else _local(todo, workers or os.cpu_count() or 1)
        try:
            for spec, row in source:
                rows[spec.id] = row
                artifacts.append_text(folder / RUNS, csv_row(row))
                failed += row["status"] != "ok"
                bar.update(1)
                bar.set_postfix(failed=failed, refresh=False)
        finally:
            bar.close()
    ordered = tuple(sorted(rows.values(), key=lambda r: r["index"]))
    result = CampaignResult(c, ordered, len(todo), len(done), failed, time.perf_counter() - started, folder)
    if outputs:
        write_outputs(result)
    return result


def _bar(total: int, initial: int, name: str, show: bool):
    from tqdm import tqdm

    tqdm.monitor_interval = 0  # no monitor thread in a process that forks workers
    return tqdm(total=total, initial=initial, desc=name, unit="run", disable=not show, dynamic_ncols=True,
                smoothing=0.1)


def write_outputs(result: CampaignResult) -> list[Path]:
    """``runs.csv`` (in run order), ``tables.md``, ``summary.json`` and the plots."""
    from .output import artifacts, plots, tables

    c = result.campaign
    files: dict[str, str | bytes] = {RUNS: csv_header(c) + "".join(csv_row(r) for r in result.rows)}
    files["tables.md"] = tables.campaign_markdown(c, result.rows)
    files["summary.json"] = tables.campaign_json(c, result.rows)
    for name, data in plots.campaign_figures(result.rows).items():
        files[f"plots/{name}"] = data
    files[artifacts.MANIFEST] = artifacts.manifest(files, campaign=c.name, source=c.source)
    return artifacts.write_folder(result.folder, files)


__all__ = ["COLUMNS", "Campaign", "CampaignResult", "RunSpec", "load_campaign", "run_campaign", "run_one",
           "read_rows", "write_outputs", "schema"]
