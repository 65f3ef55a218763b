"""Several generated models side by side, as one: the submodels a fault touches.

A plant split at its sensors (:mod:`bgc.compiler.decompose`) is a set of
submodels, each predicting its own sensors from the plant's inputs and its
neighbours' readings. Given the readings, the submodels are independent: their
states, process noise and measurement noise are their own, so the likelihood
of their data given the readings is the product of theirs. A fault of the whole plant moves the
submodels it touches, each through its own fault model of it: a parameter's
through the same change in every submodel that holds it, a sensor's bias
through its own submodel's reading and, with the opposite sign, through the
input its neighbours read it as (they read what the sensor says, the true
value plus the bias, so the plant they see is the reading minus it).

:class:`Joined` is those models as one :class:`~bgc.model.protocol.FaultModel`:
its state the parts' physical states one after the other, then the fault's
states once (a drifting parameter, the magnitude last), shared by every part;
its inputs and outputs the parts' one after the other. Its filters are the
filters of a block-diagonal plant whose blocks share one fault: the cubature
Kalman filters of the static posterior run on it unchanged
(:mod:`bgc.diagnosis.decomposed`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .protocol import FaultModel, state_rows


class Joined:
    """The models ``models`` (each a part's nominal model or its fault
    model of one fault) as one model named ``name``. ``signs``: per part,
    how its fault's magnitude reads the shared one (+1; -1 for a sensor's
    bias or drift read as an input by a neighbour; 0 for a part modelled
    nominal); ``inputs``: per part, its inputs' columns' names in the joined
    input vector (each part's inputs one after the other: its own names,
    prefixed by the part's). ``fault``, ``prior``: the whole plant's fault
    (``FAULT``) and the bounds of its magnitude's prior (``FAULT_PRIOR``);
    None for a nominal model. The fault's own states (and its parameter's
    nominal value, for :func:`~bgc.diagnosis.estimate.truth_of`) are those of
    the first part whose sign is +1 (the one holding the fault's subject)."""

    def __init__(self, name: str, models: Sequence[FaultModel], signs: Sequence[int] | None = None,
                 fault: Mapping[str, Any] | None = None, prior: tuple[float, float] | None = None,
                 model: str | None = None):
        models = list(models)
        signs = [0] * len(models) if signs is None else [int(s) for s in signs]
        if not models or len(signs) != len(models):
            raise ValueError("Joined: one sign per model, at least one model")
        dts = {float(m.DT) for m in models}
        if len(dts) != 1:
            raise ValueError(f"Joined: the parts' sample periods differ ({sorted(dts)})")
        self._models, self._signs = models, signs
        rows = [state_rows(m) for m in models]
        faulted = [i for i, s in enumerate(signs) if s != 0]
        if bool(faulted) != (fault is not None):
            raise ValueError("Joined: a fault model has a fault and at least one part that models it")
        for i, (physical, extra) in enumerate(rows):
            if (signs[i] != 0) != bool(extra):
                raise ValueError(f"Joined: part {models[i].NAME} of {name}: its sign says whether it has fault states")
        self._ref = next((i for i in faulted if signs[i] > 0), faulted[0] if faulted else None)
        ref = None if self._ref is None else models[self._ref]
        extra_ref = [] if ref is None else rows[self._ref][1]
        if any(len(rows[i][1]) != len(extra_ref) for i in faulted):
            raise ValueError(f"Joined: the parts of {name} model its fault with different states")
        # the joined rows of each part's physical states, then the shared fault rows
        self._phys: list[np.ndarray] = []
        states: list[str] = []
        kinds: list[str] = []
        process: list[float] = []
        x0: list[float] = []
        x0_std: list[float] = []
        for m, (physical, _) in zip(models, rows):
            self._phys.append(np.arange(len(states), len(states) + len(physical)))
            part_kinds = getattr(m, "STATE_KINDS", ("physical",) * len(m.STATES))
            states += [m.STATES[i] for i in physical]
            kinds += [part_kinds[i] for i in physical]
            process += [float(np.asarray(m.PROCESS_STD, dtype=float)[i]) for i in physical]
            x0 += [float(np.asarray(m.X0, dtype=float)[i]) for i in physical]
            x0_std += [float(np.asarray(m.X0_STD, dtype=float)[i]) for i in physical]
        self._fault_rows = np.arange(len(states), len(states) + len(extra_ref))
        if ref is not None:
            ref_kinds = getattr(ref, "STATE_KINDS", ())
            states += [ref.STATES[i] for i in extra_ref]
            kinds += [ref_kinds[i] for i in extra_ref]
            process += [float(np.asarray(ref.PROCESS_STD, dtype=float)[i]) for i in extra_ref]
            x0 += [float(np.asarray(ref.X0, dtype=float)[i]) for i in extra_ref]
            x0_std += [float(np.asarray(ref.X0_STD, dtype=float)[i]) for i in extra_ref]
        self._local = rows
        self.NAME = name
        self.MODEL = model or models[0].MODEL
        self.STATES = tuple(states)
        self.STATE_KINDS = tuple(kinds)
        self._u: list[slice] = []
        self._y: list[slice] = []
        inputs: list[str] = []
        outputs: list[str] = []
        for m in models:
            self._u.append(slice(len(inputs), len(inputs) + len(m.INPUTS)))
            inputs += [f"{m.MODEL}:{u}" for u in m.INPUTS]
            self._y.append(slice(len(outputs), len(outputs) + len(m.OUTPUTS)))
            outputs += list(m.OUTPUTS)
        self.INPUTS = tuple(inputs)
        self.OUTPUTS = tuple(outputs)
        # a calibration's allowance on each sensor's residual variance (bgc.diagnosis.fit.residual_sd)
        self.RESIDUAL_VARIANCE_SD = {y: v for m in models for y, v in
                                     (getattr(m, "RESIDUAL_VARIANCE_SD", None) or {}).items()}
        if len(set(outputs)) != len(outputs):
            raise ValueError(f"Joined: a sensor of {name} is predicted by two parts")
        if ref is not None:
            self.PARAMETERS, self.THETA = tuple(ref.PARAMETERS), tuple(ref.THETA)
        else:
            pairs = dict(p for m in models for p in zip(m.PARAMETERS, m.THETA))
            self.PARAMETERS, self.THETA = tuple(pairs), tuple(pairs.values())
        self.DT = dts.pop()
        self.X0 = np.array(x0)
        self.X0_STD = np.array(x0_std)
        self.PROCESS_STD = np.array(process)
        self.MEASUREMENT_STD = np.concatenate([np.asarray(m.MEASUREMENT_STD, dtype=float) for m in models])
        self.PREDICTIVE_STD = np.concatenate([np.asarray(m.PREDICTIVE_STD, dtype=float) for m in models])
        self.FAULT = None if fault is None else dict(fault)
        self.FAULT_PRIOR = None if prior is None else (float(prior[0]), float(prior[1]))
        self._varies = any(np.ndim(m.measurement_std(np.zeros((len(m.STATES), 1)))) == 2 for m in models)

    # -- the parts' states from the joined ones, and back ----------------------------------------------------

    def _part(self, i: int, x: np.ndarray) -> np.ndarray:
        """Part ``i``'s state (its n_x, N) from the joined ``x`` (n_x, N): its
        physical rows, and its fault rows the shared ones times its sign."""
        m = self._models[i]
        physical, extra = self._local[i]
        xi = np.empty((len(m.STATES), x.shape[1]))
        xi[physical] = x[self._phys[i]]
        if extra:
            xi[extra] = self._signs[i] * x[self._fault_rows]
        return xi

    def _scatter(self, states: list[np.ndarray], into: np.ndarray) -> np.ndarray:
        """Each part's state (``states``, in order) written into the joined
        ``into``: its physical rows, and the fault rows from the first
        holding part (divided by its sign)."""
        for i, xi in enumerate(states):
            physical, extra = self._local[i]
            into[self._phys[i]] = xi[physical]
            if i == self._ref:
                into[self._fault_rows] = xi[extra] / self._signs[i]
        return into

    @staticmethod
    def _columns(x) -> tuple[np.ndarray, bool]:
        x = np.asarray(x, dtype=float)
        return (x.reshape(-1, 1), True) if x.ndim == 1 else (x, False)

    # -- the FaultModel protocol ------------------------------------------------------------------------------

    def inputs(self, t: float) -> np.ndarray:
        return np.concatenate([np.asarray(m.inputs(t), dtype=float) for m in self._models])

    def predict(self, x, u, theta, dt, out=None):
        """Each part's noise-free step on its rows (``theta``: each part's
        own are used); the fault rows as the first holding part moves them."""
        return self._step(x, u, dt, out, None)

    def transition(self, x, u, theta, dt, rng, out=None):
        """Each part's step with its process noise; the fault rows as the
        first holding part draws them."""
        return self._step(x, u, dt, out, rng)

    def _step(self, x, u, dt, out, rng):
        X, flat = self._columns(x)
        u = np.asarray(u, dtype=float)
        moved = []  # every part moved from the state before the step, then written back (``out`` may be ``x``)
        for i, m in enumerate(self._models):
            xi = self._part(i, X)
            if rng is None:
                m.predict(xi, u[..., self._u[i]], m.THETA, dt, out=xi)
            else:
                m.transition(xi, u[..., self._u[i]], m.THETA, dt, rng, out=xi)
            moved.append(xi)
        result = self._scatter(moved, np.empty_like(X) if out is None else np.asarray(out).reshape(X.shape))
        if out is not None:
            return out
        return result[:, 0] if flat else result

    def perturb(self, x, rng):
        """Process noise added in place, each part's on its rows (the fault
        rows' by the first holding part)."""
        X, _ = self._columns(x)
        self._scatter([m.perturb(self._part(i, X), rng) for i, m in enumerate(self._models)], X)
        return x

    def observe(self, x, u, theta, out=None):
        X, flat = self._columns(x)
        u = np.asarray(u, dtype=float)
        y = np.concatenate([np.asarray(m.observe(self._part(i, X), u[..., self._u[i]], m.THETA), dtype=float)
                            .reshape(len(m.OUTPUTS), X.shape[1]) for i, m in enumerate(self._models)])
        y = y[:, 0] if flat else y
        if out is not None:
            out[...] = y
            return out
        return y

    def measurement_std(self, x):
        X, _ = self._columns(x)
        stds = [np.asarray(m.measurement_std(self._part(i, X)), dtype=float) for i, m in enumerate(self._models)]
        if not self._varies:
            return np.concatenate(stds)
        return np.concatenate([s if s.ndim == 2 else np.repeat(s[:, None], X.shape[1], axis=1) for s in stds])

    def loglik(self, y, x, u, theta):
        X, _ = self._columns(x)
        y = np.asarray(y, dtype=float)
        u = np.asarray(u, dtype=float)
        total = np.zeros(X.shape[1])
        for i, m in enumerate(self._models):
            total += m.loglik(y[self._y[i]], self._part(i, X), u[..., self._u[i]], m.THETA)
        return total

    def initial_particles(self, rng, n: int) -> np.ndarray:
        return self._scatter([m.initial_particles(rng, n) for m in self._models], np.empty((len(self.STATES), n)))

    def augment(self, x_nominal, rng) -> np.ndarray:
        """Nominal states (the joined physical rows, N) lifted into this
        model's: the fault rows as the first holding part lifts its own."""
        xn = np.asarray(x_nominal, dtype=float)
        x = np.empty((len(self.STATES), xn.shape[1]))
        n = len(self.STATES) - len(self._fault_rows)
        x[:n] = xn[:n]
        if self._ref is not None:
            i = self._ref
            lifted = self._models[i].augment(xn[self._phys[i]], rng)
            x[self._fault_rows] = lifted[self._local[i][1]] / self._signs[i]
        return x

    def __repr__(self) -> str:
        return f"Joined({self.NAME!r}, parts={[m.MODEL for m in self._models]})"
