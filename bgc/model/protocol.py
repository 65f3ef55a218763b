"""What the runtime reads of a generated model, and the conventions of its fault, declared once.

A generated package (``generated/<model>/numpy_model``, or the compiled
``numba_model``) is a Python package whose ``MODELS`` maps ``nominal`` and
each fault model ``PARAM_KIND`` to a module. The runtime reads those modules
through :class:`FaultModel` and the package through :class:`Package` (typing
protocols: a generated module meets them as it is, and a test's stand-in
does too), never as bare modules; the conventions every part of the runtime
shares are here, and only here:

* **The state vector.** A model's states are the plant's physical states
  first, then its fault states (``STATE_KINDS``): a drifting parameter's own
  state (``parameter``) and, last, the fault's magnitude (``bias`` or
  ``slope``: :attr:`bgc.kinds.FaultKind.magnitude`). :func:`state_rows` and
  :func:`magnitude_row` say which rows are which; the nominal model has
  physical states only. A model with modes has one more state before the
  fault states, its mode (kind ``mode``: the mode's number), which the
  model keeps an exact integer and which has no noise, and with a timed
  transition the time spent in the mode (kind ``dwell``): the filters carry
  them as they carry a physical state (:mod:`bgc.compiler.hybrid_codegen`).
* **The onset rule.** A fault with onset k changes its parameter at the
  instant of sample k, as in the thesis's DBN (the parameter of time slice k
  enters y_k and the transition out of slice k) and in the simulator: y_k sees
  the fault, the transition into sample k is nominal. A particle filter
  handed over at an onset applies it with :func:`onset_transition`; the
  cubature Kalman bank of the static posterior and the distinguishability
  prediction apply it to their cells by holding the magnitude
  (:func:`magnitude_row`) at 0 over that one transition. The onset sample
  of a fault that strikes at time t is the first sample at t or later
  (:func:`onset_sample`). A switch's fault (stuck, or turned without a
  command: :func:`placed_within`) is the exception: a switch moves the
  plant's states by a whole mode's difference within a step, and a real one
  fails at any instant, so the filters place its onset anywhere within the
  step before the onset sample, uniformly (the particles at the quantiles
  of that place, :func:`onset_transition`; the cubature Kalman filters'
  points at its middle, with the spread of the quantiles' predictions,
  :meth:`bgc.filters.cubature._Filter._onset_spread`). The simulator and the
  distinguishability prediction keep the rule (the switch at the sample's
  instant), a place the filters' allow.
* **The nominal model** of a package is :func:`nominal_model`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

#: The name of the nominal (fault-free) model in a package's ``MODELS``.
NOMINAL = "nominal"


@runtime_checkable
class FaultModel(Protocol):
    """One generated model module (the nominal model, or a fault model
    ``PARAM_KIND``): its tables and the functions the filters call. Arrays
    of particles are (states, N); ``theta`` the parameters' values."""

    #: The model's name in the package (``nominal``, ``R12_abrupt``) and the plant's.
    NAME: str
    MODEL: str
    STATES: tuple[str, ...]
    #: ``physical`` per plant state, then the fault states' kinds (``parameter``, ``bias``, ``slope``).
    STATE_KINDS: tuple[str, ...]
    INPUTS: tuple[str, ...]
    OUTPUTS: tuple[str, ...]
    PARAMETERS: tuple[str, ...]
    THETA: tuple[float, ...]
    #: The sample period, in the model's time unit.
    DT: float
    X0: Any
    X0_STD: Any
    PROCESS_STD: np.ndarray
    MEASUREMENT_STD: np.ndarray
    PREDICTIVE_STD: np.ndarray
    #: ``parameter``, ``kind``, ``magnitude``, ``target``, ``subject``, ``unit``; None: the nominal model.
    FAULT: Mapping[str, Any] | None
    #: The bounds of the magnitude's uniform prior (a fault model's).
    FAULT_PRIOR: tuple[float, float]

    def inputs(self, t: float): ...

    def predict(self, x: np.ndarray, u, theta, dt: float, out: np.ndarray | None = None) -> np.ndarray: ...

    def transition(self, x: np.ndarray, u, theta, dt: float, rng, out: np.ndarray | None = None) -> np.ndarray: ...

    def observe(self, x: np.ndarray, u, theta, out: np.ndarray | None = None) -> np.ndarray: ...

    def measurement_std(self, x: np.ndarray) -> np.ndarray: ...

    def loglik(self, y, x: np.ndarray, u, theta) -> np.ndarray: ...

    def initial_particles(self, rng, n: int) -> np.ndarray: ...

    def perturb(self, x: np.ndarray, rng) -> np.ndarray: ...


@runtime_checkable
class Package(Protocol):
    """A generated package: its models by name, its filters module (the
    particle filters, ``bgc/filters/particle.py`` as copied) and its kernel."""

    MODELS: Mapping[str, FaultModel]
    filters: Any
    _kernel: Any


def nominal_model(package: Package) -> FaultModel:
    """The package's nominal (fault-free) model."""
    return package.MODELS[NOMINAL]


def sized_models(package: Package) -> list[str]:
    """The names of the package's fault models that have a size to weigh and
    estimate (sorted): all but the nominal model and a stuck switch's (whose
    magnitude is a flag: :attr:`bgc.kinds.FaultKind.discrete`)."""
    from ..kinds import fault_kind

    return [name for name in sorted(package.MODELS) if name != NOMINAL
            and not fault_kind(package.MODELS[name].FAULT["kind"]).discrete]


def stuck_models(package: Package) -> list[str]:
    """The names of the package's stuck switches' fault models (sorted): the
    rest of :func:`sized_models`'s, their magnitude a flag
    (:attr:`bgc.kinds.FaultKind.discrete`)."""
    sized = set(sized_models(package))
    return [name for name in sorted(package.MODELS) if name != NOMINAL and name not in sized]


#: The kinds of states the filters carry as the plant's (the rest are a fault model's fault states).
CARRIED = ("physical", "mode", "dwell", "threshold")


def state_rows(model: FaultModel) -> tuple[list[int], list[int]]:
    """The physical states' rows (the mode's among them) and the fault
    states' rows (a drifting parameter, then the magnitude last) of a
    generated model."""
    kinds = getattr(model, "STATE_KINDS", ("physical",) * len(model.STATES))
    physical = [i for i, k in enumerate(kinds) if k in CARRIED]
    return physical, [i for i, k in enumerate(kinds) if k not in CARRIED]


def magnitude_row(model: FaultModel) -> int:
    """The row of a fault model's magnitude state (a bias, or a drift's
    slope): its last."""
    return len(model.STATES) - 1


#: The places within the step before its onset sample at which a switch's fault is tried
#: (:func:`onset_transition`; the cubature Kalman filters' spread, bgc.filters.cubature), and those
#: places as the part phi of the step after the fault: the midpoint quantiles (j + 1/2) / J of the uniform.
PLACES = 16
PHI = (np.arange(PLACES) + 0.5) / PLACES


def placed_within(model: FaultModel) -> bool:
    """Whether fault model ``model``'s onset is placed within the step
    before its onset sample (a switch's fault: module docstring)."""
    from ..kinds import fault_kind

    fault = getattr(model, "FAULT", None)
    return bool(fault) and fault_kind(fault["kind"]).discrete


def placed_apart(model: FaultModel, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Per column of ``x`` (a fault model's particles or points at their
    onset), whether the data's mode (``u``'s mode input) differs from the
    column's, a switch the data give within the step: the generated step
    places that switch within the step it is given, so a step split at the
    fault's place would move it into the first part; such a column keeps the
    onset rule (the two events within one step, their order not told)."""
    row, column = getattr(model, "MODE_ROW", None), getattr(model, "MODE_INPUT", None)
    if row is None or column is None or not np.isfinite(u[column]):
        return np.zeros(x.shape[1], dtype=bool)
    return np.rint(np.asarray(x[row], dtype=float)) != np.rint(u[column])


def placed_transition(model: FaultModel, x: np.ndarray, u: np.ndarray, theta, dt: float, phi: float,
                      magnitude: np.ndarray) -> np.ndarray:
    """Columns ``x`` of a fault model's states (their magnitude 0) at their
    onset carried through a step of ``dt`` whose last part ``phi`` has the
    fault, its ``magnitude`` (one per column) from there; a column whose
    mode the data change in the step (:func:`placed_apart`) by the onset
    rule, the whole step without it. A new array."""
    x = np.array(x, dtype=float)
    apart = placed_apart(model, x, u)
    whole = model.predict(x[:, apart], u, theta, dt) if apart.any() else None
    model.predict(x, u, theta, (1.0 - phi) * dt, out=x)
    x[magnitude_row(model)] = magnitude
    model.predict(x, u, theta, phi * dt, out=x)
    if whole is not None:
        x[:, apart] = whole
    return x


def onset_transition(model: FaultModel, x: np.ndarray, u: np.ndarray, theta) -> np.ndarray:
    """The noise-free transition into a fault's onset sample, in place on a
    fault model's particles ``x`` (the onset rule, module docstring): the
    magnitude state is held at zero for this one transition, then restored;
    a drifting parameter's own state stays at its nominal value. A switch's
    fault (:func:`placed_within`) strikes within the step instead: particle
    i from the part (i mod J + 1/2) / J of the step before the sample, J =
    :data:`PLACES` (the place's uniform distribution, stratified over the
    particles), but for a particle whose mode the data change in the step
    (:func:`placed_apart`: the rule). The filter's step then adds the
    process noise and weighs the particles with the fault in (``step(y, u,
    predicted=True)``)."""
    row = magnitude_row(model)
    magnitude = x[row].copy()
    x[row] = 0.0
    if not placed_within(model):
        model.predict(x, u, theta, model.DT, out=x)
    else:
        share = PHI[np.arange(x.shape[1]) % PLACES]
        for phi in np.unique(share):
            columns = np.flatnonzero(share == phi)
            x[:, columns] = placed_transition(model, x[:, columns], u, theta, model.DT, phi, magnitude[columns])
    x[row] = magnitude
    return x


def onset_sample(times, t: float) -> int:
    """The onset sample of a fault that strikes at time ``t`` (the onset
    rule): the first sample whose time is ``t`` or later, to rounding."""
    return int(np.searchsorted(times, t - 1e-9 * max(1.0, abs(t))))
