"""A model linearised along its noise-free nominal run: what the predictions
of :mod:`bgc.analysis.distinguish` and the detector's matched test
(:mod:`bgc.diagnosis.matched`) both read.

* :func:`scenario_inputs`: the model's declared inputs over a run;
* :func:`linearised`: the nominal run, its Jacobians ``F`` and ``H`` along
  it (central differences of the generated ``predict`` and ``observe``) and
  its Kalman filter as a :class:`Whitening`;
* :func:`unit_responses`: a fault model's linearised measurement
  deviations for a unit magnitude from each onset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import TrackingError
from .protocol import FaultModel, Package, magnitude_row, nominal_model


@dataclass(frozen=True, slots=True)
class Whitening:
    """The nominal model's Kalman filter along its noise-free run, as a linear
    operator on measurement deviations: per step ``F`` (n, n), ``H`` (n_y, n),
    gain ``K`` (n, n_y) and ``Linv`` (n_y, n_y), the inverse Cholesky factor of
    the innovations' covariance."""

    F: np.ndarray
    H: np.ndarray
    K: np.ndarray
    Linv: np.ndarray

    def apply(self, d: np.ndarray) -> np.ndarray:
        """Whitened innovations (T, n_y, M) of deviations ``d`` (T, n_y, M)
        from the nominal run's measurements."""
        T, n_y, M = d.shape
        x = np.zeros((self.F.shape[1], M))
        out = np.empty_like(d, dtype=float)
        for k in range(T):
            x = self.F[k] @ x
            e = d[k] - self.H[k] @ x
            x += self.K[k] @ e
            out[k] = self.Linv[k] @ e
        return out


def scenario_inputs(package: Package, steps: int, signals: tuple = (), modes: np.ndarray | None = None) -> np.ndarray:
    """The model's default inputs over ``steps`` samples: sample k's step
    holds the input at k dt (as the simulator does); ``signals``: (name,
    :class:`~bgc.ir.Signal`) pairs that drive those inputs instead. A model
    with modes: its mode input (the data's mode column) is ``modes`` (the
    mode's number at each sample, as the truth simulator's run has it), or,
    not given, the mode the noise-free nominal run reaches by its own guards
    and timed transitions (:func:`own_modes`)."""
    nominal = nominal_model(package)
    us = np.array([nominal.inputs(k * nominal.DT) for k in range(steps)], dtype=float).reshape(steps, -1)
    for name, signal in signals:
        us[:, nominal.INPUTS.index(name)] = [signal.at(k * nominal.DT) for k in range(steps)]
    column = getattr(nominal, "MODE_INPUT", None)
    if column is not None:
        us[:, column] = own_modes(nominal, us) if modes is None else np.asarray(modes, dtype=float)
    return us


def own_modes(nominal, us: np.ndarray) -> np.ndarray:
    """The mode (its number) at each sample of the noise-free run of a model
    with modes from ``X0`` under the inputs ``us`` (their mode column not
    read), each step through the mode's guards and timed transitions (the
    generated model's hidden-mode step); a controlled change is not taken."""
    us = np.array(us, dtype=float)
    us[:, nominal.MODE_INPUT] = np.nan
    x = np.asarray(nominal.X0, dtype=float).reshape(-1, 1).copy()
    out = np.empty(len(us))
    with np.errstate(all="ignore"):
        for k in range(len(us)):
            x = nominal.predict(x, us[k], nominal.THETA, nominal.DT)
            out[k] = x[nominal.MODE_ROW, 0]
    return out


def linearised(package: Package, us: np.ndarray) -> tuple:
    """The nominal model's noise-free run for the inputs ``us`` (its states
    before and after each step, its measurements), its Jacobians ``F`` and
    ``H`` along the run, and its Kalman filter as a :class:`Whitening`."""
    nominal = nominal_model(package)
    T = len(us)
    theta = np.asarray(nominal.THETA, dtype=float)
    x = np.asarray(nominal.X0, dtype=float).reshape(-1, 1).copy()
    n = x.shape[0]
    x_before, x_after = np.empty((T, n)), np.empty((T, n))
    y = np.empty((T, len(nominal.OUTPUTS)))
    with np.errstate(all="ignore"):
        for k in range(T):
            x_before[k] = x[:, 0]
            x = nominal.predict(x, us[k], theta, nominal.DT)
            x_after[k] = x[:, 0]
            y[k] = nominal.observe(x, us[k], theta)[:, 0]
    if not (np.all(np.isfinite(x_after)) and np.all(np.isfinite(y))):
        raise TrackingError(f"the noise-free nominal run of {nominal.MODEL} is not finite", None,
                            "check the model's values and inputs")
    scale = scales(nominal, x_before)
    F = jacobian(lambda X, u: nominal.predict(X, u, theta, nominal.DT), x_before, range(n), scale, us)
    H = jacobian(lambda X, u: nominal.observe(X, u, theta), x_after, range(n), scale, us)
    return x_before, x_after, y, F, H, whitening(nominal, F, H)


def typical_size(low: float, high: float) -> float:
    """The mean size |m| of a magnitude m drawn uniformly from its prior
    [low, high]: the size the model's prior expects.

    >>> typical_size(0.0, 2.0), typical_size(-1.0, 2.0)
    (1.0, 0.8333333333333334)
    """
    if low >= 0 or high <= 0:
        return (abs(low) + abs(high)) / 2
    return (low * low + high * high) / (2 * (high - low))


def scales(model: FaultModel, points: np.ndarray) -> np.ndarray:
    """Central-difference steps per physical state: 1e-6 of the state's size
    (its largest value on the run, its initial spread or its process std)."""
    size = np.maximum.reduce([np.abs(points).max(axis=0), np.asarray(model.X0_STD, dtype=float)[: points.shape[1]],
                              np.asarray(model.PROCESS_STD, dtype=float)[: points.shape[1]]])
    return 1e-6 * np.where(size > 0, size, 1.0)


def jacobian(fn, points: np.ndarray, rows, steps: np.ndarray, us: np.ndarray) -> np.ndarray:
    """Central differences (T, n_out, len(rows)) of ``fn(X, u)`` ((n_s, M) ->
    (n_out, M)) at ``points`` (T, n_s) with respect to the state ``rows``
    (steps ``steps`` per row), the input of point k being ``us[k]``; one call
    of ``fn`` per distinct input."""
    rows = list(rows)
    T, n_s = points.shape
    r = len(rows)
    out = None
    _, first, inverse = np.unique(us, axis=0, return_index=True, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    for g, at in enumerate(first):
        ks = np.flatnonzero(inverse == g)
        X = np.repeat(points[ks].T[:, :, None], 2 * r, axis=2)  # (n_s, |ks|, 2r)
        for i, row in enumerate(rows):
            X[row, :, i] += steps[i]
            X[row, :, r + i] -= steps[i]
        with np.errstate(all="ignore"):
            Y = np.asarray(fn(X.reshape(n_s, -1), us[at]), dtype=float).reshape(-1, len(ks), 2 * r)
        if out is None:
            out = np.empty((T, Y.shape[0], r))
        out[ks] = ((Y[:, :, :r] - Y[:, :, r:]) / (2.0 * np.asarray(steps)[None, None, :])).transpose(1, 0, 2)
    return out


def noise(model: FaultModel, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The covariances of a model's first ``n`` (physical) states' initial
    spread and process noise, and of its measurement noise."""
    return (np.diag(np.asarray(model.X0_STD, dtype=float)[:n] ** 2),
            np.diag(np.asarray(model.PROCESS_STD, dtype=float)[:n] ** 2),
            np.diag(np.asarray(model.MEASUREMENT_STD, dtype=float) ** 2))


def whitening(model: FaultModel, F: np.ndarray, H: np.ndarray) -> Whitening:
    """The nominal Kalman filter's gains and innovation factors along the run."""
    T, n_y, n = H.shape
    P, Q, R = noise(model, n)
    K = np.empty((T, n, n_y))
    Linv = np.empty((T, n_y, n_y))
    eye = np.eye(n)
    for k in range(T):
        P = F[k] @ P @ F[k].T + Q
        S = H[k] @ P @ H[k].T + R
        try:
            L = np.linalg.cholesky(0.5 * (S + S.T))
        except np.linalg.LinAlgError:
            raise TrackingError(f"{model.MODEL}: the measurements' predicted covariance is singular or not finite "
                                f"at step {k}", None, "give every sensor a measurement noise above 0, and check the "
                                "model's values") from None
        Linv[k] = np.linalg.inv(L)
        gain = P @ H[k].T @ Linv[k].T @ Linv[k]
        A = eye - gain @ H[k]
        P = A @ P @ A.T + gain @ R @ gain.T  # Joseph form: stays symmetric and positive
        K[k] = gain
    return Whitening(F, H, K, Linv)


def unit_responses(model: FaultModel, F: np.ndarray, H: np.ndarray, x_before: np.ndarray, x_after: np.ndarray,
                    us: np.ndarray, onsets: np.ndarray) -> np.ndarray:
    """Fault model ``model``'s linearised measurement deviations (T, n_y,
    onsets) for a unit magnitude from each onset: its fault states (a
    drifting parameter, the magnitude last) at their nominal values, the
    magnitude 1 at the onset sample."""
    T, n = x_before.shape
    theta = np.asarray(model.THETA, dtype=float)
    fixed = np.asarray(model.X0, dtype=float)[n:]
    nf = len(fixed)
    prior = np.abs(np.asarray(model.FAULT_PRIOR, dtype=float))
    # central-difference steps: 1e-6 of each fault state's size. A drifting state whose nominal value is 0 (a
    # sensor's or an actuator's offset) takes the size of what the drift can reach over the run: a step of 1e-6
    # of nothing would be lost in the reading it is added to, and the drift's response would come out 0
    reach = float(prior.max()) * T * float(model.DT)
    steps = np.array([1e-6 * max(abs(v) if v != 0 else reach, 1e-12) for v in fixed[:-1]] +
                     [1e-6 * max(prior.max(), 1e-12)])
    before = np.hstack([x_before, np.tile(fixed, (T, 1))])
    after = np.hstack([x_after, np.tile(fixed, (T, 1))])
    rows = range(n, n + nf)
    Fz_f = jacobian(lambda X, u: model.predict(X, u, theta, model.DT), before, rows, steps, us)  # (T, n+nf, nf)
    Hz_f = jacobian(lambda X, u: model.observe(X, u, theta), after, rows, steps, us)  # (T, n_y, nf)
    n_y = H.shape[1]
    D = np.zeros((n + nf, len(onsets)))
    G = np.zeros((T, n_y, len(onsets)))
    where = {int(t): j for j, t in enumerate(onsets)}
    for k in range(T):
        physical = F[k] @ D[:n] + Fz_f[k, :n] @ D[n:]
        D[n:] = Fz_f[k, n:] @ D[n:]
        D[:n] = physical
        j = where.get(k)
        if j is not None:  # the onset sample: the states so far are nominal, the magnitude is 1
            D[:, j] = 0.0
            D[magnitude_row(model), j] = 1.0
        G[k] = H[k] @ D[:n] + Hz_f[k] @ D[n:]
    return G
