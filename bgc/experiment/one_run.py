"""One run of a campaign, in a worker: its scenario simulated, diagnosed with :func:`bgc.diagnose`
and measured (:mod:`bgc.experiment.metrics`) into a row (:func:`run_one`)."""

from __future__ import annotations

import functools
import hashlib
import os
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..analysis.distinguish import FALSE_ALARM
from ..errors import (BgcError, printable)
from ..model import DEFAULT_BACKEND

if TYPE_CHECKING:
    pass

from .campaign_file import RunSpec
from .runs_csv import COLUMNS, SEPARATOR, state_cells


# ------------------------------------------------------------------ one run
_MODEL_FILES: dict[str, str] = {}


_MODEL_DIR: dict[int, str] = {}  # process id -> its private folder (a forked worker makes its own)


def model_file(spec: RunSpec) -> str:
    """The model's text written once per process into a private folder (a
    worker on another machine has no copy of the campaign's files)."""
    from ..api.folders import private_folder

    with _MODEL_LOCK:  # the threads of a Dask worker share the folder
        return _write_model(spec, private_folder)


_MODEL_LOCK = threading.Lock()


#: This worker's sessions (bgc.open) by process, model file and noise levels: a campaign worker diagnoses
#: many runs of a few models, each compiled once (the runner's state, outside the diagnosis).
_SESSIONS: dict[tuple, Any] = {}


def _session(spec: RunSpec, process_noise: float | None, measurement_noise: float | None,
             backend: str = DEFAULT_BACKEND):
    """The session of the run's model at these noise levels on ``backend`` in this process, opened once."""
    from .. import api

    key = (os.getpid(), model_file(spec), process_noise, measurement_noise, backend)
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


def run_one(spec: RunSpec, backend: str = DEFAULT_BACKEND) -> dict[str, Any]:
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
        options = DiagnosisOptions(filter=spec.filter, particles=spec.particles, seed=spec.seed, workers=1,
                                   refine=spec.refine, switch=False,  # a campaign measures the filter it names
                                   detectors=spec.detectors)
        session = _session(spec, spec.process_noise, spec.measurement_noise, backend)
        report = api.diagnose(session, scenario=_scenario(spec), seed=spec.seed, steps=spec.steps,
                             options=options, inputs=dict(spec.inputs) or None, modes=spec.modes)
        d = report.diagnosis
        m = metrics.measure(d, report.run, metrics.Truth(spec.fault, spec.kind, spec.magnitude, spec.onset))
        best = d.best
        row.update(
            status="ok", rt=d.seconds, mse=float(np.mean(list(m.mse.values()))), nmse=m.nmse, ct=m.ct,
            detected=m.detected, detection_time=m.detection_time, delay=m.delay, false_alarm=m.false_alarm,
            verdict=m.verdict, diagnosed=m.diagnosed, candidates=SEPARATOR.join(d.candidates) or None,
            right=m.right, in_candidates=m.in_candidates, estimate=m.estimate, low=m.low, high=m.high,
            est_error=m.error, covers=m.covers)
        row.update(state_cells(m.mse))
        injected = report.injected
        if injected is not None:
            row.update(target=injected.target,
                       expected=simulate.outside_prior(injected, session.view.numerics,
                                                         session.view.modules) is None)
        if m.diagnosed != "none" and best is not None:  # where the diagnosed fault's estimate comes from
            row.update(diagnosed_target=best.estimate.target, estimate_method=best.estimate.method)
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
    fault, were its onset and magnitude known: what an ideal detector sees),
    ``ideal_delay`` (the least time from the onset by which any detector
    holding the campaigns' 1 % false-alarm probability per run alarms in half
    of such runs: :meth:`~bgc.analysis.distinguish.Distinction.ideal_delay`;
    none when not even the whole run lets it); empty when the prediction
    fails (the diagnosis's row stands). It depends on the scenario, noise
    levels and length only, not on the filter or the seed: a process
    computes it once per scenario."""
    out = dict(_prediction(model_file(spec), _scenario(spec), spec.process_noise, spec.measurement_noise,
                           spec.steps, spec.modes))
    alarm = out.pop("ideal_alarm", None)  # the time of that sample: its delay from the fault's own time
    if out and spec.onset is not None:
        out["ideal_delay"] = None if alarm is None else max(alarm - spec.onset, 0.0)
    return out


def _scenario(spec: RunSpec):
    """The run's scenario: the value read when the campaign was loaded, or
    its text (a spec made by hand, or one of a campaign from before)."""
    return spec.injection if spec.injection is not None else spec.scenario


@functools.lru_cache(maxsize=64)
def _prediction(model_file: str, scenario, process_noise: float | None, measurement_noise: float | None,
                steps: int | None, modes: str | None = None) -> tuple[tuple[str, Any], ...]:
    from .. import api

    try:
        compiled = next((v for k, v in _SESSIONS.items() if k[:2] == (os.getpid(), model_file)), model_file)
        report = api.distinguishability(compiled, scenario, process_noise=process_noise,  # the run's session
                                        measurement_noise=measurement_noise, steps=steps, modes=modes)
        d = report.distinctions[0]
    except Exception:  # noqa: BLE001 - the prediction is an extra: the diagnosis's row stands without it
        return ()
    late = d.ideal_delay(FALSE_ALARM)  # samples after the onset's; the sample k's time is (k + 1) dt
    return (("separable", d.separable), ("rivals", SEPARATOR.join(d.group) or None),
            ("separation", min((r.probability for r in d.rivals), default=1.0)),
            ("detectability", d.detectability),
            ("ideal_alarm", None if late is None else (d.onset + late + 1) * report.dt))
