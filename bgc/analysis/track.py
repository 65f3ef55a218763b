"""``bgc filter``: one generated filter over a recorded run (the nominal
model, or a fault model handed over at an onset), its estimates and, for a
fault model, its fault estimate."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..data.columns import MODE
from ..data.runs import Run, input_columns
from ..errors import DataError, TrackingError, printable
from ..filters.cubature import CubatureKalmanFilter
from ..filters.particle import mode_probabilities
from ..filters.registry import check_particles, filter_class
from ..kinds import fault_kind
from ..model.protocol import onset_transition
from ..model.protocol import Package, nominal_model


@dataclass(frozen=True, slots=True)
class TrackResult:
    """A filter's estimates over a run: arrays of shape (T, n_x) / (T, n_y) / (T,).

    Before a hand-over (``start``) the fault states are NaN. A particle
    filter of a model with modes: ``modes``, each mode's probability per step
    (T, number of modes), else None.
    """

    model: str
    method: str
    particles: int
    time: np.ndarray
    state_names: tuple[str, ...]
    mean: np.ndarray
    std: np.ndarray
    output_names: tuple[str, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    recoveries: int
    seconds: float
    fault: dict | None = None
    modes: np.ndarray | None = None

    def mode_agreement(self, run: Run) -> float | None:
        """The fraction of samples whose most probable mode is the run's
        (its mode column; None without one, or without mode probabilities)."""
        if self.modes is None or run.modes is None:
            return None
        return float(np.mean(np.argmax(self.modes, axis=1) + 1 == np.rint(run.modes)))

    def rmse(self, run: Run) -> dict[str, float]:
        """Root-mean-square error of each state estimate against the run's truth
        (the states and faulty parameter it records), over the steps where
        the estimate is defined."""
        out = {}
        for k, x in enumerate(self.state_names):
            truth = run.states.get(x, run.parameters.get(x))
            if truth is not None:
                ok = np.isfinite(self.mean[:, k]) & np.isfinite(truth)
                if ok.any():
                    out[x] = float(np.sqrt(np.mean((self.mean[ok, k] - truth[ok]) ** 2)))
        return out


@dataclass(frozen=True, slots=True)
class FaultEstimate:
    """The fault magnitude a fault-model filter ends with: ``what`` it is
    (``R2 = 2 + delta`` or ``slope of R2``), its value and std at the last
    step, and the truth when the run records it."""

    parameter: str
    kind: str
    what: str
    value: float
    std: float
    time: float
    truth: float | None

    @property
    def relative_error(self) -> float | None:
        if self.truth is None:
            return None
        return abs(self.value - self.truth) / abs(self.truth or 1.0)


def fault_estimate(result: TrackResult, package: Package, run: Run,
                   per_time: str = "per unit time") -> FaultEstimate | None:
    """The fault estimate of a fault-model track (None for the nominal model
    and a stuck switch's, which has no size):
    a bias as the parameter's value (nominal + bias), a slope as it is
    (``per_time``: how its rate is named, e.g. "per s" in the model's time unit)."""
    fault = result.fault
    if not fault or fault_kind(fault["kind"]).discrete:  # a stuck switch: no size to estimate
        return None
    module = package.MODELS[result.model]
    p = fault["parameter"]
    kind = fault_kind(fault["kind"])
    nominal = dict(zip(module.PARAMETERS, module.THETA))[p]
    k = result.state_names.index(f"delta_{p}")
    mean, std = float(result.mean[-1, k]), float(result.std[-1, k])
    truth = run.parameters.get(p)
    if kind.drifts:
        value, what = mean, f"{kind.magnitude} of {p} ({per_time})"
        true_value = None
        if truth is not None and len(truth) > 1:
            true_value = float((truth[-1] - truth[-2]) / (run.time[-1] - run.time[-2]))
    else:
        value, what = nominal + mean, f"{p} = {nominal:g} + delta"
        true_value = float(truth[-1]) if truth is not None else None
    return FaultEstimate(p, kind.name, what, value, std, float(result.time[-1]), true_value)


def run_arrays(run: Run, package: Package, model_name: str, hidden_mode: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(ys, us) arrays of a recorded run in the model's output and input order
    (``hidden_mode``: a model with modes follows its guards as if the run had no mode column)."""
    model = package.MODELS[model_name]
    missing = [y for y in model.OUTPUTS if y not in run.measurements]
    if missing:
        raise DataError(f"{printable(run.source)}: the run has no column y:{printable(missing[0])}", None,
                        "record it with bgc simulate for the same model")
    ys = np.column_stack([run.measurements[y] for y in model.OUTPUTS])
    if not model.INPUTS:
        return ys, np.zeros((len(run.time), 0))
    given = input_columns(run)
    us = np.column_stack([given[u] if u in given else np.full(len(run.time), np.nan) for u in model.INPUTS])
    # a model with modes: its last input is the mode, the run's mode column (NaN: not given, each particle's stays)
    plant = [i for i, u in enumerate(model.INPUTS) if not (u == MODE and i == getattr(model, "MODE_INPUT", None))]
    if np.isnan(us[:, plant]).any():
        us[:, plant] = np.array([model.inputs(t - model.DT) for t in run.time])[:, plant]
    if hidden_mode and len(plant) < us.shape[1]:
        us[:, model.MODE_INPUT] = np.nan
    return ys, us


def check_run_of(run: Run, model: str, where: str | None = None) -> None:
    """Refuse a run whose header says another model made it (``where``: the
    run's file; by default its ``source``)."""
    where = run.source if where is None else where
    recorded = run.model
    if recorded is not None and recorded != model:
        raise DataError(f"{printable(where)} is a run of model {printable(repr(recorded))}, not of {model!r}", None,
                        "filter it with the model the run was made with")


def check_request(run: Run, package: Package, model_name: str, particles: int, start: float | None,
                  columns: bool = True) -> None:
    """Refuse a filter request that cannot run, before any work: a model the
    package lacks, no sensors, a hand-over without a fault model or outside
    the run, too many particles, and (``columns``) a run without the model's
    measurements (a diagnosis takes one: it uses the sensors present).
    Whether the run is of this model at all is :func:`check_run_of`, which
    callers ask first."""
    name = nominal_model(package).MODEL
    if model_name not in package.MODELS:
        raise TrackingError(f"no generated model {printable(repr(model_name))}", None,
                            "choose one of: " + ", ".join(package.MODELS))
    if not package.MODELS[model_name].OUTPUTS:
        raise TrackingError(f"{name} has no measurements, so there is nothing to filter", None,
                            "declare the plant's sensors under 'measurements'")
    if start is not None and package.MODELS[model_name].FAULT is None:
        raise TrackingError("--start hands over to a fault model", None, "give --fault PARAM:KIND with --start")
    if start is not None and not (run.time[0] <= start <= run.time[-1]):
        raise TrackingError(f"--start {start:g} is outside the run ({run.time[0]:g} to {run.time[-1]:g}) of "
                            f"{printable(run.source)}", None,
                            "hand over at a time inside the run")
    check_particles(particles, package, model_name)
    if columns:
        run_arrays(run, package, model_name)


@np.errstate(all="ignore")  # particles outside a law's domain are weighted out and counted
def track(run: Run, package: Package, model_name: str = "nominal", method: str = "gpf",
          particles: int = 200, seed: int = 0, start: float | None = None, hidden_mode: bool = False) -> TrackResult:
    """Run the filter ``method`` (:data:`FILTER_CLASSES`) of ``model_name`` over the run.

    With ``start`` (a fault model only), the nominal model is tracked up to
    ``start`` and its particles are then lifted into the fault model with a fresh
    prior on the fault magnitude (the thesis's hand-over at detection time);
    the nominal part of the estimates is reported with NaN for the fault states.
    ``hidden_mode``: a model with modes follows its guards and timed
    transitions by itself, the run's mode column left for the comparison
    (:meth:`TrackResult.mode_agreement`).
    """
    if model_name not in package.MODELS:
        raise TrackingError(f"no generated model {printable(repr(model_name))}", None,
                            "choose one of: " + ", ".join(package.MODELS))
    check_particles(particles, package, model_name)
    model = package.MODELS[model_name]
    cls = filter_class(package, method)
    if start is not None and cls is CubatureKalmanFilter:
        raise TrackingError("--start hands a particle cloud over to a fault model; ckf has none", None,
                            "use --filter gpf, apf or opf with --start")
    ys, us = run_arrays(run, package, model_name, hidden_mode)
    rng = np.random.default_rng(seed)
    split = 0
    if start is not None and model.FAULT is not None:
        split = int(np.searchsorted(run.time, start))
    started = time.perf_counter()
    T = len(run.time)
    n_x = len(model.STATES)
    mean = np.full((T, n_x), np.nan)
    std = np.full((T, n_x), np.nan)
    y_mean = np.empty((T, ys.shape[1]))
    y_std = np.empty((T, ys.shape[1]))
    ess = np.empty(T)
    resampled = np.zeros(T, bool)
    count = len(getattr(model, "MODES", ())) if cls is not CubatureKalmanFilter else 0
    modes = np.full((T, count), np.nan) if count else None
    recoveries = 0
    x0 = None
    if split > 0:
        nominal = nominal_model(package)
        pf0 = cls(nominal, particles, rng)
        out = pf0.run(ys[:split], us[:split])
        k = out.mean.shape[1]
        mean[:split, :k], std[:split, :k] = out.mean, out.std
        y_mean[:split], y_std[:split], ess[:split] = out.y_mean, out.y_std, out.ess
        resampled[:split] = out.resampled
        if count:
            modes[:split] = out.modes
        recoveries += pf0.recoveries
        x0 = model.augment(pf0.x[:, package.filters.systematic_resample(pf0.logw, rng)], rng)
    if split < T:
        pf = cls(model, particles, rng, x=x0)
        if x0 is not None:  # handed over at the fault's onset: its sample sees the fault, the transition is nominal
            onset_transition(model, pf.x, us[split], pf.theta)
            r = pf.step(ys[split], us[split], predicted=True)
            mean[split], std[split], y_mean[split], y_std[split] = r.mean, r.std, r.y_mean, r.y_std
            ess[split], resampled[split] = r.ess, r.resampled
            if count:
                modes[split] = mode_probabilities(model, pf.x, pf.logw)
            split += 1
        out = pf.run(ys[split:], us[split:])
        mean[split:], std[split:] = out.mean, out.std
        y_mean[split:], y_std[split:], ess[split:] = out.y_mean, out.y_std, out.ess
        resampled[split:] = out.resampled
        if count:
            modes[split:] = out.modes
        recoveries += pf.recoveries
    seconds = time.perf_counter() - started
    return TrackResult(model_name, method, particles, run.time, tuple(model.STATES), mean, std,
                       tuple(model.OUTPUTS), y_mean, y_std, ess, resampled, recoveries, seconds,
                       dict(model.FAULT) if model.FAULT else None, modes)
