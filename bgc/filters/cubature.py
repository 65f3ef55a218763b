"""The cubature Kalman filter: one filter of a generated model, and banks of
them over a grid of cells (the static posterior's, :mod:`bgc.diagnosis.static_posterior`).

The cubature Kalman filter (Arasaratnam and Haykin 2009) moves 2 n points
``m +- sqrt(n) L e_i`` (``P = L L'``) through the generated ``predict`` and
``observe``, so it needs no derivatives. On a linear plant its means,
covariances and predictive densities are exactly the Kalman filter's; on a
mildly nonlinear one (the RO plant: the conductivity's equation and the
permeate flow's measurement) they are a close approximation, which the tests
measure against the particle-filter reference (the posterior means of the
R_pipe slope and bias agree within the reference's own Monte Carlo error).

One bank runs every cell (tau, c) of a grid at once: arrays of cells x
points, one call of the model per step for all of them. Before its onset a
cell is the nominal model (its magnitude is held at 0, and so it is for the
transition into the onset sample: the fault changes the parameter at that
sample's instant, which sees it, :func:`bgc.model.protocol.onset_transition`); all cells
start from the nominal filter's state at the earliest onset, so every cell's
likelihood covers the same data, from step 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .particle import FilterRun, StepResult, run_filter
from ..kinds import releases
from ..model.protocol import PHI, FaultModel, magnitude_row, placed_transition, placed_within, state_rows

LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True, slots=True)
class NominalTrack:
    """The nominal model's cubature Kalman filter over a run: before step k,
    the state's mean ``mean[k]`` and covariance ``cov[k]`` (given the data
    of steps 0 .. k-1) and ``loglik[k]``, log p(y_0 .. y_(k-1)); and, as an
    observer, at each step k it took, its predicted measurement's mean
    ``y_mean[k]`` and std ``y_std[k]`` (before it saw y_k) and the
    normalised residuals ``z[k]`` (NaN: not read), and the state's mean and
    std after the step (``x_mean[k]``, ``x_std[k]``)."""

    mean: np.ndarray
    cov: np.ndarray
    loglik: np.ndarray
    y_mean: np.ndarray | None = None
    y_std: np.ndarray | None = None
    z: np.ndarray | None = None
    x_mean: np.ndarray | None = None
    x_std: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class BankResult:
    """What :func:`run_bank` gives: per cell, ``loglik`` (C,), the filter's
    ``mean`` (C, n) and ``cov`` (C, n, n) after the last step, and with
    ``residuals`` the normalised residuals ``z`` (steps, C, n_y; NaN: not
    measured) of each step's predicted measurement and each step's log
    predictive density ``increments`` (steps, C; 0 before the cell's onset,
    where the nominal filter's count); with ``record``, each step's
    predicted measurement mean and std ``y_mean``, ``y_std`` (steps, C, n_y)
    and the state's mean and std after it ``x_mean``, ``x_std`` (steps, C,
    n; NaN before the cell's onset)."""

    loglik: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    z: np.ndarray | None
    increments: np.ndarray | None = None
    y_mean: np.ndarray | None = None
    y_std: np.ndarray | None = None
    x_mean: np.ndarray | None = None
    x_std: np.ndarray | None = None


def cholesky(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack of covariances (..., n, n), by
    NumPy's batched LAPACK call. When a matrix of the stack is not positive
    definite (a pivot zero or negative by rounding, or a matrix that is not
    one), the stack is factored one column at a time for all matrices at once
    instead, each pivot under 1e-12 of its diagonal entry raised to that: the
    result is then the factor of a nearby positive definite matrix, not of
    ``P``.

    A stack of 2 x 2 (or 1 x 1) matrices, the two tanks' and the plants of
    two states, is factored by LAPACK's own arithmetic written out
    (:func:`_cholesky_2`): the same factors to the bit in a few array
    operations, where ``np.linalg.cholesky`` calls LAPACK once per matrix
    (its time grows with the cells of a bank: 60 us for 200, 25 us written
    out, measured); a stack where that meets a pivot LAPACK would refuse
    goes the way above."""
    n = P.shape[-1]
    if 0 < n <= 2 and P.ndim == 3 and P.shape[0] > 8 and P.dtype == np.float64:
        L = _cholesky_2(P)
        if L is not None:
            return L
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    L = np.zeros(P.shape)
    for j in range(n):
        row = L[..., j, :j]
        pivot = P[..., j, j] - np.einsum("...k,...k->...", row, row)
        floor = 1e-12 * np.abs(P[..., j, j]) + 1e-300
        L[..., j, j] = np.sqrt(np.maximum(pivot, floor))
        if j + 1 < n:
            L[..., j + 1:, j] = ((P[..., j + 1:, j] - np.einsum("...ik,...k->...i", L[..., j + 1:, :j], row))
                                 / L[..., j, j][..., None])
    return L


def _cholesky_2(P: np.ndarray) -> np.ndarray | None:
    """The lower Cholesky factors of a stack of 1 x 1 or 2 x 2 matrices (C, n,
    n) as LAPACK's dpotrf computes them (its unblocked dpotf2, and the
    recursive dpotrf2 alike, from the lower triangle): l00 = sqrt(p00), l10 =
    p10 times 1 / l00 (a scaling by the reciprocal, not a division), l11 =
    sqrt(p11 - l10 l10); None when a pivot is not positive (or NaN: where
    LAPACK would fail or give NaN). Equal to NumPy's factors bit for bit
    (tests/test_kalman.py)."""
    p00 = P[:, 0, 0]
    if not (p00 > 0.0).all():
        return None
    L = np.zeros(P.shape)
    l00 = L[:, 0, 0]
    np.sqrt(p00, out=l00)
    if P.shape[-1] == 2:
        l10, l11 = L[:, 1, 0], L[:, 1, 1]
        np.divide(1.0, l00, out=l10)
        l10 *= P[:, 1, 0]
        np.multiply(l10, l10, out=l11)
        np.subtract(P[:, 1, 1], l11, out=l11)
        if not (l11 > 0.0).all():
            return None
        np.sqrt(l11, out=l11)
    return L




class _Filter:
    """The cubature Kalman filter's arithmetic for a model: one step of a
    stack of cells, each with its own mean, covariance and fault states (the
    magnitude last), the cells along the first axis: means (C, n),
    covariances (C, n, n), fault states (f, C). The model sees the points of
    all cells at once, as columns (n_x, C 2n), cell by cell. The measurement
    noise covariance R is the model's MEASUREMENT_STD squared, or, for a
    model whose ``measurement_std`` depends on its fault states (a noise
    fault: ``varies``), each cell's own (:meth:`_cell_noise`)."""

    def __init__(self, model: FaultModel):
        self.model = model
        self.physical, self.extra = state_rows(model)
        #: the magnitude's place among the fault states (the onset rule holds it at 0 over the transition into
        #: the onset sample: :mod:`bgc.model.protocol`); None for the nominal model
        self.magnitude = self.extra.index(magnitude_row(model)) if self.extra else None
        #: an uncommanded change of a switch: its flag, which a mode asking for the switch so clears within
        #: the prediction, for good (bgc.kinds.releases), is read back after each prediction
        self.released = bool(self.extra) and releases((getattr(model, "FAULT", None) or {}).get("kind", ""))
        #: a switch's fault (stuck, or turned without a command): its onset within the step before the onset
        #: sample, at a place the data do not say (:meth:`_onset_spread`)
        self.within = bool(self.extra) and placed_within(model)
        n = len(self.physical)
        self.n, self.n_x = n, len(model.STATES)
        # the physical rows of the points: a slice (a view) when they come first, as generated
        self.rows = slice(0, n) if self.physical == list(range(n)) else self.physical
        self.Q = np.diag(np.asarray(model.PROCESS_STD, dtype=float)[self.physical] ** 2)
        self.R = np.asarray(model.MEASUREMENT_STD, dtype=float) ** 2
        self.varies = np.ndim(model.measurement_std(np.zeros((self.n_x, 1)))) == 2
        self.buffer = np.empty((self.n_x, 0))
        self.root, self.inverse, self.scale = math.sqrt(n), 1.0 / (2 * n), math.sqrt(1.0 / (2 * n))
        self.phys = np.array(self.physical, dtype=np.intp)
        # a model with modes: the mode's rows among the carried ones (and the others'), for _factor
        kinds = getattr(model, "STATE_KINDS", ())
        self.carried = np.array([j for j, i in enumerate(self.physical) if kinds and kinds[i] != "physical"],
                                dtype=np.intp)
        self.uncarried = np.array([j for j in range(n) if j not in set(self.carried.tolist())], dtype=np.intp)
        self.extra_rows = np.array(self.extra, dtype=np.intp)
        self._tiles: dict = {}  # the compiled step's noise variances per cell, per pattern of sensors read
        #: a compiled package's kernel does the step's arithmetic (:meth:`_compiled_step`); asked once, not per step
        self.compiled = hasattr(getattr(model, "_kernel", None), "cubature_update")
        self._seen: dict = {}
        # a model with modes whose guards have a tolerance: the draws placing a switch within its step, the
        # mode's row among the physical ones, and which of those are physical states (:meth:`_switch_spread`)
        self.draws = np.asarray(getattr(model, "_THRESHOLD_ROWS", ()), dtype=np.intp)  # the draws alone
        self.mode = self.physical.index(model.MODE_ROW) if len(self.draws) else None
        #: the physical states' rows among the carried ones (a model with modes: not its mode, its time in it,
        #: its threshold's draws)
        self.own = np.array([not kinds or kinds[i] == "physical" for i in self.physical])

    def _points(self, m: np.ndarray, P: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Write the cubature points m +- sqrt(n) L e_i of N(m, P) of every
        cell into the physical rows of ``X`` (n_x, C, 2n); return sqrt(n) L
        (C, n, n)."""
        n = self.n
        L = self._factor(P)
        L *= self.root
        Lt = L.transpose(1, 0, 2)  # (n, C, n): state, cell, point
        if isinstance(self.rows, slice):  # a view: written in place
            physical = X[self.rows]
            np.add(m.T[:, :, None], Lt, out=physical[:, :, :n])
            np.subtract(m.T[:, :, None], Lt, out=physical[:, :, n:])
        else:
            X[self.rows] = np.concatenate([m.T[:, :, None] + Lt, m.T[:, :, None] - Lt], axis=2)
        return L

    def _factor(self, P: np.ndarray) -> np.ndarray:
        """:func:`cholesky` of the cells' covariances; a model with modes whose
        mode (or time in it) every cell knows (variance exactly 0: the data
        say the mode) has those left out of the factoring, their rows and
        columns of the factor 0 (their covariances with the others are 0 but
        for rounding, which a floored pivot would divide), the rest factored
        as a block by LAPACK."""
        if len(self.carried):
            known = (P[:, self.carried, self.carried] == 0.0).all(axis=0)
            if known.any():
                L = np.zeros(P.shape)
                keep = self.uncarried if known.all() else np.sort(np.concatenate([self.uncarried,
                                                                                   self.carried[~known]]))
                L[:, keep[:, None], keep] = cholesky(P[:, keep[:, None], keep])
                return L
        return cholesky(P)

    def _switch_spread(self, m: np.ndarray, fixed: np.ndarray, u: np.ndarray, onset: slice, dt,
                       moved=None) -> np.ndarray | None:
        """A model with modes whose guards have a tolerance, at a step where
        the data's mode differs from a cell's (a switch the data say happened
        in the step): the covariance (C, n, n) the switch's unknown place
        within the step adds to each cell's prediction, its physical states'
        rows and columns only; None at any other step. The plant's threshold
        is uncertain, so the data's switch lies anywhere on the guard's path
        through the step (the generated ``_fraction``: the place is the
        quantile ``draw`` of the threshold's distribution along it); the
        points all take the median draw (0.5), which alone gives no spread,
        and a cubature point along a draw of the uniform would lie outside
        it. Each cell's mean is carried through the step at the draws' J
        midpoint quantiles (j + 1/2) / J (:data:`~bgc.model.protocol.PHI`), as its
        points are (its fault states, the onset rule), and the second moment
        of those predictions about the median draw's, which the points
        predict, is the spread (the midpoint rule of the uniform draw's
        integral). A cell whose mode is not a number (a filter that
        diverged) switches nothing. The hidden-mode bank's histories
        (:mod:`bgc.diagnosis.hidden`) give each its mode through the input
        too: a history that switches spreads by it as well."""
        if self.mode is None or not np.isfinite(u[self.model.MODE_INPUT]):
            return None
        modes = m[:, self.mode]
        if not (np.isfinite(modes) & (np.rint(modes) != np.rint(u[self.model.MODE_INPUT]))).any():
            return None
        C, J = m.shape[0], len(PHI)
        X = np.empty((self.n_x, C, J + 1))
        X[self.physical] = m.T[:, :, None]
        self._write_fixed(X, fixed, onset, moved)
        X[self.draws] = np.append(PHI, 0.5)  # the quantiles, then the median
        flat = X.reshape(self.n_x, C * (J + 1))
        self.model.predict(flat, u, self.model.THETA, self.model.DT if dt is None else dt, out=flat)
        P = X[self.physical].transpose(1, 0, 2)  # (C, n, J + 1)
        D = P[:, :, :J] - P[:, :, J:]
        D[:, ~self.own] = 0.0  # the mode, its time and the draws: no spread of their own
        D[~np.isfinite(D).all(axis=(1, 2))] = 0.0  # a cell the model cannot carry: none (its filter says so)
        return np.matmul(D, D.transpose(0, 2, 1)) / J

    def _spread(self, m: np.ndarray, fixed: np.ndarray, u: np.ndarray, onset: slice, dt,
                moved=None) -> np.ndarray | None:
        """What the step's prediction spreads by beyond its points (C, n, n):
        a switch the data say happened in the step at a place a tolerance
        leaves unknown (:meth:`_switch_spread`), a switch fault's unknown place
        within the step before its onset sample (:meth:`_onset_spread`); None
        where neither."""
        spread = self._switch_spread(m, fixed, u, onset, dt, moved)
        placed = self._onset_spread(m, fixed, u, onset, dt, moved)
        if placed is None:
            return spread
        return placed if spread is None else spread + placed

    def _onset_spread(self, m: np.ndarray, fixed: np.ndarray, u: np.ndarray, onset: slice, dt,
                      moved=None) -> np.ndarray | None:
        """A switch's fault (stuck, or turned without a command) at the cells
        ``onset``: the covariance (C, n, n) its unknown place within the step
        before the onset sample adds to those cells' predictions, their
        physical states' rows and columns only (0 for the other cells); None
        where no cell is at its onset, for any other fault, and for a fault
        that comes and goes (``moved``); nothing for a cell whose mode the
        data change in the step (:func:`~bgc.model.protocol.placed_apart`: the
        rule). A switch moves the plant's states by a whole mode's difference
        within a step, and a real switch fails at any instant: the part phi of
        the step after it, uniform on (0, 1). The
        points take the middle of the step (:meth:`_predict_points`, phi 1/2);
        each onset cell's mean is carried through the step at the J places of
        :data:`~bgc.model.protocol.PHI` (the midpoint quantiles of phi), and
        the second moment of those predictions about the middle's is the
        spread (the midpoint rule of the uniform's integral)."""
        if not self._placed(onset, moved):
            return None
        C, n, J = m.shape[0], self.n, len(PHI)
        cells = np.arange(C)[onset]
        X = np.empty((self.n_x, len(cells), J + 1))
        X[self.physical] = m[cells].T[:, :, None]
        self._write_fixed(X, fixed[:, cells], slice(0, len(cells)))
        out = np.empty_like(X)
        model, step = self.model, self.model.DT if dt is None else dt
        for q, phi in enumerate(np.append(PHI, 0.5)):  # the places, then the middle
            out[:, :, q] = placed_transition(model, X[:, :, q], u, model.THETA, step, phi,
                                             fixed[self.magnitude, cells])
        P = out[self.physical].transpose(1, 0, 2)  # (cells, n, J + 1)
        D = P[:, :, :J] - P[:, :, J:]
        D[:, ~self.own] = 0.0  # the mode, its time: no spread of their own
        D[~np.isfinite(D).all(axis=(1, 2))] = 0.0  # a cell the model cannot carry: none (its filter says so)
        spread = np.zeros((C, n, n))
        spread[cells] = np.matmul(D, D.transpose(0, 2, 1)) / J
        return spread

    def _placed(self, onset: slice, moved) -> bool:
        """Whether cells ``onset`` are at the onset of a fault placed within
        the step before it (a switch's; not one that comes and goes, ``moved``)."""
        return self.within and moved is None and onset.stop > onset.start

    def _physical(self, X: np.ndarray) -> np.ndarray:
        """The physical rows of the points ``X`` (n_x, C, 2n) as (C, n, 2n)."""
        return X[self.rows].transpose(1, 0, 2)

    def _noise(self, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The measurement noise covariance of the sensors read (a diagonal
        matrix) and the indices of those sensors, per pattern ``seen``."""
        key = seen.tobytes()
        hit = self._seen.get(key)
        if hit is None:
            hit = self._seen[key] = (np.diag(self.R[seen]), np.flatnonzero(seen))
        return hit

    def _cell_noise(self, m: np.ndarray, fixed: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Each cell's measurement noise variances of the sensors ``rows``
        (C, k): the model's ``measurement_std`` at the cell's mean ``m`` (C,
        n) and fault states ``fixed`` (f, C), squared (a noise fault: R with
        its sensor's entry times (1 + b)^2)."""
        x = np.zeros((self.n_x, m.shape[0]))
        x[self.physical] = m.T
        x[self.extra] = fixed
        std = self.model.measurement_std(x)[rows].T
        return std * std

    def step(self, y: np.ndarray, u: np.ndarray, m: np.ndarray, P: np.ndarray, fixed: np.ndarray,
             onset: slice = slice(0, 0), dt: float | None = None, moved: np.ndarray | None = None):
        """One step (predict over ``dt``, default the model's ``DT``, with
        input ``u``, then update with ``y``; NaN: not measured) of every cell: log p(y | the past) (C,), mean (C, n)
        and covariance (C, n, n) after it, normalised residuals (C, n_y),
        and the predicted measurement's mean and std (C, n_y; NaN: not read);
        updates ``fixed`` (a drifting parameter moves). The cells ``onset``
        are at their onset sample: their transition is nominal (magnitude
        zero), their update sees the fault (``track.onset_transition``).
        ``moved`` (C,): each cell's magnitude over the transition, where it
        differs from the one its update sees (``fixed``'s): a fault that
        comes and goes (:mod:`bgc.diagnosis.intermittent`) changes it at a
        sample's instant both ways.

        The deviations of the update's points from their mean are +-sqrt(n) L,
        so the cross covariance is L (DY+ - DY-)' / 2n, DY+- the measurement
        deviations of the + and - points; the gain and the log density come
        from the Cholesky factor of the innovation covariance by forward
        substitution (:func:`lower_solve`)."""
        model, n, C = self.model, self.n, m.shape[0]
        spread = self._spread(m, fixed, u, onset, dt, moved)
        if self.compiled and spread is None:  # a compiled package's kernel (a switch's spread: the step below)
            return self._compiled_step(y, u, m, P, fixed, onset, dt, moved)
        if self.buffer.shape[1] < 2 * n * C:
            self.buffer = np.empty((self.n_x, 2 * n * C))
        flat = self.buffer[:, :2 * n * C]
        X = flat.reshape(self.n_x, C, 2 * n)
        self._points(m, P, X)
        self._predict_points(flat, X, u, fixed, onset, dt, moved)
        Xp = self._physical(X)  # (C, n, 2n)
        mp = np.add.reduce(Xp, axis=2)
        mp *= self.inverse
        D = Xp - mp[:, :, None]
        D *= self.scale  # sqrt(1 / 2n): D D' is the points' covariance
        Pp = np.matmul(D, D.transpose(0, 2, 1))
        Pp += self.Q
        if spread is not None:
            Pp += spread
        seen = np.isfinite(y)
        every = bool(seen.all())
        if not every and not seen.any():
            nan = np.full((C, len(y)), np.nan)
            return np.zeros(C), mp, Pp, nan, nan, nan
        L = self._points(mp, Pp, X)
        if self.extra and onset.stop > onset.start:  # the onset cells see their fault from this sample on
            X[self.extra[self.magnitude], onset] = fixed[self.magnitude][onset][:, None]
        if self.extra and moved is not None:  # the update sees the magnitude of this sample
            X[self.extra[self.magnitude]] = fixed[self.magnitude][:, None]
        R, rows = self._noise(seen)
        Y = model.observe(flat, u, model.THETA)
        if not every:
            Y = Y[rows]
        Y = Y.reshape(-1, C, 2 * n)  # (k, C, 2n)
        yh = np.add.reduce(Y, axis=2)
        yh *= self.inverse
        DY = (Y - yh[:, :, None]).transpose(1, 0, 2)  # (C, k, 2n)
        yh = yh.T  # (C, k)
        Syy = np.matmul(DY, DY.transpose(0, 2, 1))
        Syy *= self.inverse
        if self.varies:  # each cell its own R
            diagonal = np.arange(len(rows))
            Syy[:, diagonal, diagonal] += self._cell_noise(mp, fixed, rows)
        else:
            Syy += R
        return _update(y, rows, every, yh, DY, L, Syy, mp, Pp, self.inverse, cholesky)


    def predicted_measurement(self, m: np.ndarray, P: np.ndarray, u: np.ndarray,
                              dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The predicted measurement one step on from N(``m``, ``P``) over a
        nominal model's physical states (no fault states), by the cubature
        rule of :meth:`step` without its update: mean (n_y,) and covariance
        (n_y, n_y), every sensor's, the measurement noise included. The
        covariance's off-diagonal entries are what the particle filters do
        not give (their predicted std is per sensor): the detector's pooled
        test whitens the residual vector with them (:mod:`bgc.diagnosis.detect`).
        Always the NumPy arithmetic (one cell: a compiled kernel saves
        nothing). A switch within the step whose place a tolerance leaves
        unknown spreads it as it spreads :meth:`step`'s (:meth:`_switch_spread`)."""
        n = self.n
        if self.extra:
            raise ValueError("predicted_measurement: a nominal model's (a fault model has fault states)")
        flat = np.zeros((self.n_x, 2 * n))
        X = flat.reshape(self.n_x, 1, 2 * n)
        m = np.asarray(m, dtype=float)[None]
        spread = self._switch_spread(m, np.zeros((0, 1)), u, slice(0, 0), dt)
        self._points(m, np.asarray(P, dtype=float)[None], X)
        self.model.predict(flat, u, self.model.THETA, self.model.DT if dt is None else dt, out=flat)
        Xp = self._physical(X)[0]  # (n, 2n)
        mp = np.add.reduce(Xp, axis=1) * self.inverse
        D = (Xp - mp[:, None]) * self.scale
        Pp = D @ D.T + self.Q
        if spread is not None:
            Pp += spread[0]
        self._points(mp[None], Pp[None], X)
        Y = np.asarray(self.model.observe(flat, u, self.model.THETA), dtype=float)
        yh = np.add.reduce(Y, axis=1) * self.inverse
        DY = (Y - yh[:, None]) * self.scale
        S = DY @ DY.T
        if self.varies:
            S[np.diag_indices_from(S)] += self._cell_noise(mp[None], np.zeros((0, 1)), np.arange(len(yh)))[0]
        else:
            S[np.diag_indices_from(S)] += self.R
        return yh, S

    def _predict_points(self, flat, X, u, fixed, onset, dt, moved=None):
        """Move every cell's points (``flat`` (n_x, C 2n), ``X`` its (n_x, C,
        2n) view) through the model over one sample, in place: first each
        cell's fixed rows (``fixed``: the magnitude, a drifting parameter)
        written into its points, the magnitude 0 in the cells before their
        onset; after it a drifting parameter read back into ``fixed``."""
        model = self.model
        self._write_fixed(X, fixed, onset, moved)
        placed = self._placed(onset, moved)  # a switch's fault at its onset
        if placed:
            before = X[:, onset].reshape(self.n_x, -1).copy()
        step = model.DT if dt is None else dt
        model.predict(flat, u, model.THETA, step, out=flat)
        if placed:  # the onset cells take the fault from the step's middle (:meth:`_onset_spread`)
            columns = X[:, onset].shape[1:]
            magnitude = np.repeat(fixed[self.magnitude][onset], columns[1])
            X[:, onset] = placed_transition(model, before, u, model.THETA, step, 0.5,
                                            magnitude).reshape(self.n_x, *columns)
        for j, row in enumerate(self.extra):  # a drifting parameter: the same in every point of a cell
            if j == self.magnitude:
                continue
            fixed[j] = X[row, :, 0]
        if self.released:
            self._read_flag(X[self.extra[self.magnitude]], fixed, onset)

    def _write_fixed(self, X, fixed, onset: slice, moved=None) -> None:
        """Each cell's fault states ``fixed`` (f, C) into every column of its
        block of ``X`` (n_x, C, columns): the magnitude 0 in the cells at
        their onset (the onset rule), or each cell's ``moved`` over the
        transition (a fault that comes and goes)."""
        for j, row in enumerate(self.extra):
            X[row] = fixed[j][:, None]
        if self.extra:
            X[self.extra[self.magnitude], onset] = 0.0
            if moved is not None:
                X[self.extra[self.magnitude]] = np.asarray(moved, dtype=float)[:, None]

    def _read_flag(self, flags: np.ndarray, fixed, onset: slice) -> None:
        """An uncommanded change's flag after a prediction (``flags`` (C, 2n):
        each cell's points'; a mode asking for the switch so cleared it) into
        ``fixed``: set where most of a cell's points keep it. Not in the onset
        cells, which take it at the sample (the onset rule; the part of the
        step it held there, :meth:`_onset_spread`, does not clear it)."""
        kept = (np.add.reduce(flags, axis=1) * self.inverse > 0.5).astype(float)
        kept[onset] = fixed[self.magnitude][onset]
        fixed[self.magnitude] = kept

    def _compiled_step(self, y, u, m, P, fixed, onset, dt, moved=None):
        """:meth:`step` with a compiled package's kernel: the arithmetic
        between the model's calls (points and fault states, moments, the
        update) in compiled loops over the cells, one call each side of the
        prediction and one for the update. The points are laid out point by
        point, the cells innermost (point p of cell c in column p C + c), and
        so are the prediction's moments, so that the kernel's loops run over
        the cells in vector instructions. ``moved``: each cell's magnitude
        over the transition, written into its points' magnitude row before
        the prediction, and ``fixed``'s after it, for the update (as
        :meth:`_predict_points` and :meth:`step` do)."""
        model, n, C, kernel = self.model, self.n, m.shape[0], self.model._kernel
        phys = self.phys
        flat = np.empty((self.n_x, 2 * n * C))
        held = kernel.contiguous(fixed)  # a drifting parameter is read back into it
        kernel.cubature_prepare(m, P, self.root, flat, phys, self.extra_rows, held, onset)
        # the points' magnitude row, point by point, the cells innermost (a view: (2n, C))
        magnitudes = flat[self.extra[self.magnitude]].reshape(2 * n, C) if self.extra else None
        if moved is not None:  # the transition sees each cell's magnitude over it (every point of the cell)
            magnitudes[:] = np.asarray(moved, dtype=float)
        model.predict(flat, u, model.THETA, model.DT if dt is None else dt, out=flat)
        mp, Pp, L = kernel.cubature_after(flat, phys, self.extra_rows, held, self.inverse, self.scale, self.Q,
                                          self.root, onset)  # the cells innermost: (n, C), (n, n, C)
        if self.released:
            self._read_flag(magnitudes.T, held, onset)
        if moved is not None:  # the update sees the magnitude of this sample
            magnitudes[:] = held[self.magnitude]
        if held is not fixed:
            fixed[...] = held
        seen = np.isfinite(y)
        if not seen.any():
            nan = np.full((C, len(y)), np.nan)
            return np.zeros(C), np.ascontiguousarray(mp.T), np.ascontiguousarray(Pp.transpose(2, 0, 1)), nan, nan, nan
        _, rows = self._noise(seen)
        if self.varies:
            noise = np.ascontiguousarray(self._cell_noise(mp.T, fixed, rows))
        else:
            key = (seen.tobytes(), C)
            noise = self._tiles.get(key)
            if noise is None:
                noise = self._tiles[key] = np.tile(self.R[rows], (C, 1))
        loglik, m, P, zk, yh, sd = kernel.cubature_update(model.observe(flat, u, model.THETA), rows,
                                                          np.ascontiguousarray(y, dtype=float), noise, L,
                                                          self.inverse, mp, Pp)
        if not seen.all():
            full = [np.full((C, len(y)), np.nan) for _ in range(3)]
            for out, part in zip(full, (zk, yh, sd)):
                out[:, rows] = part
            zk, yh, sd = full
        return loglik, m, P, zk, yh, sd


def lower_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L^-1 b for a stack of lower triangular ``L`` (C, k, k) and right-hand
    sides ``b`` (C, k, r), by forward substitution: k rows of a few array
    operations each, where a batched LAPACK solve of small systems spends
    most of its time per call.

    >>> L = np.array([[[2.0, 0.0], [1.0, 4.0]]]); b = np.array([[[2.0], [9.0]]])
    >>> lower_solve(L, b)[0, :, 0].tolist()
    [1.0, 2.0]
    """
    k = L.shape[-1]
    x = np.empty(b.shape)
    for i in range(k):
        if i > 1:
            np.subtract(b[:, i], np.matmul(L[:, i, None, :i], x[:, :i])[:, 0], out=x[:, i])
        elif i:  # a product of one term: the matrix product's, without its call per cell
            np.subtract(b[:, 1], np.multiply(L[:, 1, 0, None], x[:, 0]), out=x[:, 1])
        else:
            x[:, 0] = b[:, 0]
        x[:, i] /= L[:, i, i, None]
    return x


def run_bank(model: FaultModel, ys: np.ndarray, us: np.ndarray, track: NominalTrack, onsets, magnitudes,
             fixed: np.ndarray, residuals: bool = False, record: bool = False) -> BankResult:
    """Cubature Kalman filters of fault model ``model``, one per cell: cell c
    starts at step ``onsets[c]`` from the nominal filter's state there
    (``track``), with its fault states ``fixed`` (f,: a drifting parameter's
    nominal value, the magnitude last, replaced by ``magnitudes[c]``), and
    runs to the end of ``ys``. Returns each cell's log p(y_0 .. y_(T-1))
    (the nominal filter's before its onset), its state after the last step
    and, with ``residuals``, its normalised residuals and log predictive
    densities (NaN and 0 before its onset); with ``record``, its predicted
    measurements and state estimates at every step (:class:`BankResult`)."""
    kf = _Filter(model)
    onsets = np.asarray(onsets, dtype=int)
    C = len(onsets)
    order = np.argsort(onsets, kind="stable")
    starts = onsets[order]
    state = np.repeat(np.asarray(fixed, dtype=float).reshape(-1, 1), C, axis=1)
    state[kf.magnitude] = np.asarray(magnitudes, dtype=float)[order]
    m = np.empty((C, kf.n))
    P = np.empty((C, kf.n, kf.n))
    total = track.loglik[starts].astype(float)
    T, n_y = ys.shape
    z = np.full((T, C, n_y), np.nan) if residuals else None
    increments = np.zeros((T, C)) if residuals else None
    kept = {name: np.full((T, C, size), np.nan) for name, size in
            (("y_mean", n_y), ("y_std", n_y), ("x_mean", kf.n), ("x_std", kf.n))} if record else {}
    live = 0  # cells 0 .. live - 1 have started
    with np.errstate(all="ignore"):
        for k in range(int(starts[0]) if C else T, T):
            joining = int(np.searchsorted(starts, k, side="right"))
            onset = slice(live, joining)  # the cells whose onset is this step
            if joining > live:
                m[live:joining] = track.mean[k]
                P[live:joining] = track.cov[k]
                live = joining
            ll, m[:live], P[:live], zk, y_mean, y_std = kf.step(ys[k], us[k], m[:live], P[:live], state[:, :live],
                                                                onset)
            total[:live] += ll
            if residuals:
                z[k, :live] = zk
                increments[k, :live] = ll
            if record:
                kept["y_mean"][k, :live], kept["y_std"][k, :live] = y_mean, y_std
                kept["x_mean"][k, :live] = m[:live]
                kept["x_std"][k, :live] = np.sqrt(np.maximum(np.diagonal(P[:live], axis1=1, axis2=2), 0.0))
    total[~np.isfinite(total)] = -math.inf
    back = np.empty(C, dtype=int)
    back[order] = np.arange(C)
    return BankResult(total[back], m[back], P[back], None if z is None else z[:, back],
                      None if increments is None else increments[:, back],
                      **{name: a[:, back] for name, a in kept.items()})


def _side_by_side(kfs: list, blocks: list, y: np.ndarray, u: np.ndarray, m: np.ndarray, P: np.ndarray,
                  fixed: list, onsets: list, state_factor=None):
    """:meth:`_Filter.step` of several models' filters at once, one block of
    cells each (``kfs[i]``'s cells ``blocks[i]``, a slice of the stack; its
    fault states ``fixed[i]``, its onset cells ``onsets[i]``, a slice of its
    block); the filters have the same physical states (the fault models of
    one package) and the NumPy arithmetic (no compiled kernel). Each model
    moves and reads its own points; the arithmetic between those calls is the
    step's, on the whole stack: every operation acts on each cell alone (a
    matrix product of a stack multiplies each matrix by itself, a sum runs
    along a cell's own points), so each cell's numbers are those of its
    model's step, bit for bit (tests/test_kalman.py), for one set of array
    operations instead of one per model. A stack LAPACK refuses to factor is
    factored block by block, as each model's step would. ``state_factor``
    (the stack of state covariances -> their factors): instead of that, where
    each model's own step factors them otherwise (a model with modes,
    :meth:`_Filter._factor`)."""
    kf0 = kfs[0]
    n, C = kf0.n, m.shape[0]

    def factor(P):
        try:
            return np.linalg.cholesky(P)
        except np.linalg.LinAlgError:
            return np.concatenate([cholesky(P[b]) for b in blocks])

    def points(m, P, Xs):  # _Filter._points of every block's points, each into its model's own buffer
        L = (state_factor or factor)(P)
        L *= kf0.root
        Lt = L.transpose(1, 0, 2)
        plus, minus = m.T[:, :, None] + Lt, m.T[:, :, None] - Lt
        for kf, b, X in zip(kfs, blocks, Xs):
            X[kf.rows] = np.concatenate([plus[:, b], minus[:, b]], axis=2)
        return L

    spreads = [kf._spread(m[b], f, u, onset, None) for kf, b, f, onset in zip(kfs, blocks, fixed, onsets)]
    flats = [np.empty((kf.n_x, 2 * n * (b.stop - b.start))) for kf, b in zip(kfs, blocks)]
    Xs = [flat.reshape(kf.n_x, b.stop - b.start, 2 * n) for kf, flat, b in zip(kfs, flats, blocks)]
    points(m, P, Xs)
    physical = np.empty((n, C, 2 * n))
    for kf, b, flat, X, f, onset in zip(kfs, blocks, flats, Xs, fixed, onsets):
        kf._predict_points(flat, X, u, f, onset, None)
        physical[:, b] = X[kf.rows]
    Xp = physical.transpose(1, 0, 2)  # (C, n, 2n)
    mp = np.add.reduce(Xp, axis=2)
    mp *= kf0.inverse
    D = Xp - mp[:, :, None]
    D *= kf0.scale
    Pp = np.matmul(D, D.transpose(0, 2, 1))
    if all(np.array_equal(kf.Q, kf0.Q) for kf in kfs):
        Pp += kf0.Q
    else:
        for kf, b in zip(kfs, blocks):
            Pp[b] += kf.Q
    for b, spread in zip(blocks, spreads):  # a switch within the step at a place the data do not say
        if spread is not None:
            Pp[b] += spread
    seen = np.isfinite(y)
    every = bool(seen.all())
    if not every and not seen.any():
        nan = np.full((C, len(y)), np.nan)
        return np.zeros(C), mp, Pp, nan, nan, nan
    L = points(mp, Pp, Xs)
    _, rows = kf0._noise(seen)
    Y = _observed(kfs, blocks, flats, Xs, fixed, onsets, u, None if every else rows)  # (k, C, 2n)
    yh = np.add.reduce(Y, axis=2)
    yh *= kf0.inverse
    DY = (Y - yh[:, :, None]).transpose(1, 0, 2)  # (C, k, 2n)
    yh = yh.T  # (C, k)
    Syy = np.matmul(DY, DY.transpose(0, 2, 1))
    Syy *= kf0.inverse
    diagonal = np.arange(len(rows))
    for kf, b, f in zip(kfs, blocks, fixed):
        if kf.varies:
            Syy[b, diagonal, diagonal] += kf._cell_noise(mp[b], f, rows)
        else:
            Syy[b] += kf._noise(seen)[0]
    return _update(y, rows, every, yh, DY, L, Syy, mp, Pp, kf0.inverse, factor)


def _observed(kfs: list, blocks: list, flats: list, Xs: list, fixed: list, onsets: list, u: np.ndarray,
              rows: np.ndarray | None) -> np.ndarray:
    """The measurements (k, C, 2n) of every block's update points
    (:func:`_side_by_side`), each model observing its own, the cells at
    their onset given their magnitude first; ``rows``: the sensors read
    (None: every one)."""
    Ys = []
    for kf, b, flat, X, f, onset in zip(kfs, blocks, flats, Xs, fixed, onsets):
        if kf.extra and onset.stop > onset.start:
            X[kf.extra[kf.magnitude], onset] = f[kf.magnitude][onset][:, None]
        Y = kf.model.observe(flat, u, kf.model.THETA)
        if rows is not None:
            Y = Y[rows]
        Ys.append(Y.reshape(-1, b.stop - b.start, X.shape[2]))
    return np.concatenate(Ys, axis=1)


def _update(y, rows, every: bool, yh, DY, L, Syy, mp, Pp, inverse: float, factor):
    """The measurement update of every cell, from the sensors read ``rows``
    of ``y`` (``every``: all of them), the points' predicted measurements'
    mean ``yh`` (C, k) and deviations ``DY`` (C, k, 2n), the points' root
    ``L``, the innovation covariance ``Syy`` and the prediction ``mp``,
    ``Pp``; ``factor``: the Cholesky factoring of ``Syy``. The deviations of
    the points from their mean are +-sqrt(n) L, so the cross covariance is
    L (DY+ - DY-)' / 2n; the gain and the log density come from the factor
    of Syy by forward substitution (:func:`lower_solve`). Returns (loglik
    (C,), m, P, zk, yh, sd (C, n_y; NaN: not read))."""
    C, n = mp.shape
    # [v | Pxy'] (C, k, 1 + n), Pxy' = (DY+ - DY-) L' / 2n
    rhs = np.empty((C, len(rows), 1 + n))
    np.subtract(y[rows], yh, out=rhs[:, :, 0])
    np.matmul(np.subtract(DY[:, :, :n], DY[:, :, n:]), L.transpose(0, 2, 1), out=rhs[:, :, 1:])
    rhs[:, :, 1:] *= inverse
    Ly = factor(Syy)
    solved = lower_solve(Ly, rhs)  # L^-1 [v | Pxy']: a (C, k) and B (C, k, n)
    a, B = solved[:, :, 0], solved[:, :, 1:]
    diagonal = np.diagonal(Ly, axis1=1, axis2=2)
    loglik = np.einsum("ck,ck->c", a, a)
    loglik += 2.0 * np.log(diagonal).sum(axis=1)
    loglik += len(rows) * LOG_2PI
    loglik *= -0.5
    sd = np.sqrt(np.diagonal(Syy, axis1=1, axis2=2))
    zk = rhs[:, :, 0] / sd
    if not every:
        full = [np.full((C, len(y)), np.nan) for _ in range(3)]
        for out, part in zip(full, (zk, yh, sd)):
            out[:, rows] = part
        zk, yh, sd = full
    Bt = B.transpose(0, 2, 1)
    m = mp + np.matmul(Bt, a[:, :, None])[:, :, 0]  # Pxy Syy^-1 v = (L^-1 Pxy')' (L^-1 v)
    P = np.matmul(Bt, B)  # Pxy Syy^-1 Pxy'
    np.subtract(Pp, P, out=P)
    P += P.transpose(0, 2, 1)  # symmetric against rounding
    P *= 0.5
    return loglik, m, P, zk, yh, sd


def run_banks(models: list, ys: np.ndarray, us: np.ndarray, track: NominalTrack, requests: list) -> list[BankResult]:
    """``[run_bank(models[i], ys, us, track, *requests[i], residuals=True) for i
    ...]`` (a request: the cells' onsets, magnitudes and fault states), the
    banks run side by side (:func:`_side_by_side`: the same numbers), for the
    static posteriors of several fault models at once
    (:func:`bgc.diagnosis.static_posterior.static_posteriors`). Each bank's
    cells are sorted by onset as :func:`run_bank` sorts them; at each step the
    stack is every bank's cells started so far. Models of a compiled kernel,
    or of other physical states than the first's, run one at a time."""
    kfs = [_Filter(model) for model in models]
    out: list = [None] * len(models)
    together = []
    for i, kf in enumerate(kfs):
        if kf.compiled or kf.n != kfs[0].n or kf.magnitude is None or not len(requests[i][0]):
            out[i] = run_bank(models[i], ys, us, track, *requests[i], residuals=True)
        else:
            together.append(i)
    if not together:
        return out
    T, n_y = ys.shape
    n = kfs[together[0]].n
    banks = []  # per bank: its order, onsets sorted, cells' states, m, P, totals, z, increments, live
    for i in together:
        onsets, magnitudes, fixed = requests[i]
        kf = kfs[i]
        onsets = np.asarray(onsets, dtype=int)
        C = len(onsets)
        order = np.argsort(onsets, kind="stable")
        starts = onsets[order]
        state = np.repeat(np.asarray(fixed, dtype=float).reshape(-1, 1), C, axis=1)
        state[kf.magnitude] = np.asarray(magnitudes, dtype=float)[order]
        banks.append(dict(order=order, starts=starts, state=state, m=np.empty((C, n)), P=np.empty((C, n, n)),
                          total=track.loglik[starts].astype(float), z=np.full((T, C, n_y), np.nan),
                          increments=np.zeros((T, C)), live=0))
    with np.errstate(all="ignore"):
        for k in range(min(int(b["starts"][0]) for b in banks), T):
            kf_now, blocks, onsets_now, fixed_now, at = [], [], [], [], 0
            for i, b in zip(together, banks):
                live = b["live"]
                joining = int(np.searchsorted(b["starts"], k, side="right"))
                if joining > live:
                    b["m"][live:joining] = track.mean[k]
                    b["P"][live:joining] = track.cov[k]
                    b["live"] = joining
                if not joining:
                    continue
                kf_now.append(kfs[i])
                blocks.append(slice(at, at + joining))
                onsets_now.append(slice(live, joining))
                fixed_now.append(b["state"][:, :joining])
                at += joining
            live_banks = [b for b in banks if b["live"]]
            m = np.concatenate([b["m"][:b["live"]] for b in live_banks])
            P = np.concatenate([b["P"][:b["live"]] for b in live_banks])
            ll, m, P, zk, _, _ = _side_by_side(kf_now, blocks, ys[k], us[k], m, P, fixed_now, onsets_now)
            for b, block in zip(live_banks, blocks):
                live = b["live"]
                b["m"][:live], b["P"][:live] = m[block], P[block]
                b["total"][:live] += ll[block]
                b["z"][k, :live] = zk[block]
                b["increments"][k, :live] = ll[block]
    for i, b in zip(together, banks):
        total = b["total"]
        total[~np.isfinite(total)] = -math.inf
        back = np.empty(len(b["order"]), dtype=int)
        back[b["order"]] = np.arange(len(b["order"]))
        out[i] = BankResult(total[back], b["m"][back], b["P"][back], b["z"][:, back], b["increments"][:, back])
    return out


def run_paths(models: list, ys: np.ndarray, us: np.ndarray, track: NominalTrack, onsets, magnitudes,
              fixed: list) -> list[BankResult]:
    """``[run_bank(models[i], ys, us, track, [onsets[i]], [magnitudes[i]],
    fixed[i], residuals=True, record=True) for i ...]``: one filter per fault
    model (its recorded path, :func:`bgc.diagnosis.static_posterior.record_paths`),
    the same numbers, the filters run side by side (:func:`_side_by_side`):
    a path of one cell spends its step on the array operations' cost per
    call, which the models then share. Models of a compiled kernel, or of
    other physical states than the first's, run one at a time."""
    kfs = [_Filter(model) for model in models]
    alone = [i for i, kf in enumerate(kfs) if kf.compiled or kf.n != kfs[0].n or kf.magnitude is None]
    out: list = [None] * len(models)
    for i in alone:
        out[i] = run_bank(models[i], ys, us, track, [onsets[i]], [magnitudes[i]], fixed[i], residuals=True,
                          record=True)
    together = sorted((i for i in range(len(models)) if i not in alone), key=lambda i: (int(onsets[i]), i))
    if not together:
        return out
    T, n_y = ys.shape
    n = kfs[together[0]].n
    C = len(together)
    m = np.empty((C, n))
    P = np.empty((C, n, n))
    states = []
    for i in together:
        kf = kfs[i]
        state = np.asarray(fixed[i], dtype=float).reshape(-1, 1).copy()
        state[kf.magnitude] = float(magnitudes[i])
        states.append(state)
    starts = [int(onsets[i]) for i in together]
    total = track.loglik[starts].astype(float)
    z = np.full((T, C, n_y), np.nan)
    increments = np.zeros((T, C))
    kept = {name: np.full((T, C, size), np.nan) for name, size in
            (("y_mean", n_y), ("y_std", n_y), ("x_mean", n), ("x_std", n))}
    live = 0
    with np.errstate(all="ignore"):
        for k in range(starts[0], T):
            joining = live
            while joining < C and starts[joining] <= k:
                joining += 1
            fresh = range(live, joining)
            for c in fresh:
                m[c] = track.mean[k]
                P[c] = track.cov[k]
            live = joining
            blocks = [slice(c, c + 1) for c in range(live)]
            onset = [slice(0, 1) if c in fresh else slice(0, 0) for c in range(live)]
            ll, m[:live], P[:live], zk, y_mean, y_std = _side_by_side([kfs[i] for i in together[:live]], blocks,
                                                                      ys[k], us[k], m[:live], P[:live],
                                                                      states[:live], onset)
            total[:live] += ll
            z[k, :live] = zk
            increments[k, :live] = ll
            kept["y_mean"][k, :live], kept["y_std"][k, :live] = y_mean, y_std
            kept["x_mean"][k, :live] = m[:live]
            kept["x_std"][k, :live] = np.sqrt(np.maximum(np.diagonal(P[:live], axis1=1, axis2=2), 0.0))
    total[~np.isfinite(total)] = -math.inf
    for c, i in enumerate(together):
        cell = slice(c, c + 1)
        out[i] = BankResult(total[cell].copy(), m[cell].copy(), P[cell].copy(), z[:, cell].copy(),
                            increments[:, cell].copy(), **{name: a[:, cell].copy() for name, a in kept.items()})
    return out


def nominal_logliks(models: list, ys: np.ndarray, us: np.ndarray) -> np.ndarray:
    """``[NominalKalman(model, n_y)`` stepped over ``ys``, ``us``: its last
    ``logliks`` entry ``for model in models]``: the log-likelihoods of one
    record under several nominal models of the same states (a calibration's
    points: THETA and the noise differ), their filters run side by side
    (:func:`_side_by_side`, one cell each: every model's numbers those of
    its own filter, bit for bit, for one set of array operations a step).
    Models of a compiled kernel, or of other states than the first's, run
    one at a time."""
    kalmans = [NominalKalman(model, ys.shape[1]) for model in models]
    kfs = [k.kf for k in kalmans]
    if len(kfs) < 2 or any(kf.compiled or kf.n != kfs[0].n or kf.extra for kf in kfs):
        for k in kalmans:
            for y, u in zip(ys, us):
                k.step(y, u)
        return np.array([k.logliks[-1] for k in kalmans], dtype=float)
    K = len(kfs)
    blocks = [slice(i, i + 1) for i in range(K)]
    none, onsets = [np.zeros((0, 1))] * K, [slice(0, 0)] * K

    def joined(P):  # each model's own factoring of its known modes (_Filter._factor)
        return np.concatenate([kf._factor(P[b]) for kf, b in zip(kfs, blocks)])

    state_factor = joined if len(kfs[0].carried) else None
    m = np.concatenate([k.m for k in kalmans])
    P = np.concatenate([k.P for k in kalmans])
    total = np.zeros(K)  # NominalKalman's logliks[-1], added to step by step as it adds
    with np.errstate(all="ignore"):
        for y, u in zip(ys, us):
            ll, m, P, _, _, _ = _side_by_side(kfs, blocks, y, u, m, P, none, onsets, state_factor)
            total = total + ll
    return total


class NominalKalman:
    """The nominal model's cubature Kalman filter from its prior (``X0``,
    ``X0_STD``), one step at a time (:meth:`step`); :meth:`track` gives what
    it did so far as a :class:`NominalTrack`."""

    def __init__(self, model: FaultModel, outputs: int):
        self.kf = kf = _Filter(model)
        self.m = np.asarray(model.X0, dtype=float)[None, kf.physical]
        self.P = np.diag(np.asarray(model.X0_STD, dtype=float)[kf.physical] ** 2)[None]
        self.means, self.covs, self.logliks = [self.m[0]], [self.P[0]], [0.0]
        self.y_mean: list = []
        self.y_std: list = []
        self.z: list = []
        self.x_std: list = []
        self.n_y = outputs
        self._none = np.zeros((0, 1))

    def step(self, y: np.ndarray, u: np.ndarray) -> None:
        """Take a step: measurements ``y`` (NaN: not read), inputs ``u``."""
        with np.errstate(all="ignore"):
            ll, m, P, zk, ym, sd = self.kf.step(y, u, self.m, self.P, self._none)
            self.m, self.P = m, P
            self.logliks.append(self.logliks[-1] + ll[0])
            self.means.append(m[0])
            self.covs.append(P[0])
            self.y_mean.append(ym[0])
            self.y_std.append(sd[0])
            self.z.append(zk[0])
            self.x_std.append(np.sqrt(np.maximum(np.diagonal(P[0]), 0.0)))

    def track(self, stop: int | None = None) -> NominalTrack:
        """Its states before steps 0 .. ``stop`` (default: every step taken)
        and what it predicted and estimated at steps 0 .. ``stop`` - 1."""
        stop = len(self.y_mean) if stop is None else stop
        n_y = self.n_y

        def rows(values: list, width: int) -> np.ndarray:
            return np.array(values[:stop], dtype=float).reshape(stop, width)

        n = self.kf.n
        return NominalTrack(np.array(self.means[:stop + 1]), np.array(self.covs[:stop + 1]),
                            np.array(self.logliks[:stop + 1]), rows(self.y_mean, n_y), rows(self.y_std, n_y),
                            rows(self.z, n_y), rows(self.means[1:], n), rows(self.x_std, n))


class CubatureKalmanFilter:
    """The cubature Kalman filter of one generated model behind the filter
    protocol (:class:`bgc.filters.Filter`): ``step(y, u, dt)`` takes
    one sample and gives a :class:`~bgc.filters.particle.StepResult`
    as the particle filters do, from a Gaussian over the model's physical
    states (``mean`` (n,), ``cov`` (n, n)) instead of a cloud. Its ``ess``
    is inf (no particles), it never resamples or recovers, and its
    ``loglik`` is the step's exact log predictive density (0 when no sensor
    was read). The predicted measurement of a sensor not read is NaN: the
    update leaves that sensor out.

    The arithmetic is the banks' (one cell of :func:`run_bank`), so from
    the model's prior its steps are :class:`NominalKalman`'s. A fault
    model's fault states (a drifting parameter, then the magnitude) are not
    estimated: they are held at ``fixed`` (default: their values in ``X0``,
    or the particles' mean), with std 0, as in a cell of the static
    posterior (a drifting parameter moves at its held slope).

    Built as the registry builds every filter, ``CubatureKalmanFilter(model,
    particles, rng, x=None)``: it has no particles and draws no random
    numbers, so ``particles`` and ``rng`` are only kept. From the model's
    prior (``X0``, ``X0_STD``), or from particles ``x`` (n_x, N): their mean
    and covariance, weighted by ``w`` (N, normalised) when given."""

    def __init__(self, model: FaultModel, particles: int | None = None, rng: np.random.Generator | None = None,
                 x: np.ndarray | None = None, fixed: np.ndarray | None = None, w: np.ndarray | None = None):
        self.model, self.particles, self.rng = model, particles, rng
        self.kf = kf = _Filter(model)
        if x is None:
            start = np.asarray(model.X0, dtype=float)
            self.mean = start[kf.physical]
            self.cov = np.diag(np.asarray(model.X0_STD, dtype=float)[kf.physical] ** 2)
        else:
            x = np.asarray(x, dtype=float)
            if w is None:
                start = x.mean(axis=1)
                self.cov = np.atleast_2d(np.cov(x[kf.physical]))
            else:  # a weighted cloud: its weighted moments (the unbiased ones, as np.cov's for equal weights)
                w = np.asarray(w, dtype=float)
                start = x @ w
                d = x[kf.physical] - start[kf.physical][:, None]
                self.cov = np.atleast_2d((d * w) @ d.T / max(1.0 - float(w @ w), 1e-12))
            self.mean = start[kf.physical]
        held = start[kf.extra] if fixed is None else np.asarray(fixed, dtype=float)
        self.fixed = held.reshape(len(kf.extra), 1)  # (f, 1): one cell
        self.recoveries = 0

    def step(self, y: np.ndarray, u: np.ndarray, dt: float | None = None) -> StepResult:
        """One sample: predict over ``dt`` (default ``DT``) with inputs ``u``,
        then update with ``y`` (NaN: not read)."""
        kf = self.kf
        with np.errstate(all="ignore"):
            ll, m, P, _, y_mean, y_std = kf.step(np.asarray(y, dtype=float), u, self.mean[None], self.cov[None],
                                                 self.fixed, dt=dt)
            self.mean, self.cov = m[0], P[0]
            mean = np.empty(kf.n_x)
            std = np.zeros(kf.n_x)
            mean[kf.physical] = self.mean
            mean[kf.extra] = self.fixed[:, 0]
            std[kf.physical] = np.sqrt(np.maximum(np.diagonal(self.cov), 0.0))
        return StepResult(mean, std, y_mean[0], y_std[0], math.inf, False, False, float(ll[0]))

    def run(self, ys: np.ndarray, us: np.ndarray, dt: float | None = None) -> FilterRun:
        """:meth:`step` over a record: ys (T, n_y), us (T, n_u)."""
        return run_filter(self, ys, us, dt)


def nominal_track(model: FaultModel, ys: np.ndarray, us: np.ndarray, stop: int) -> NominalTrack:
    """The nominal model's cubature Kalman filter from its prior (``X0``,
    ``X0_STD``) over steps 0 .. ``stop`` - 1: its state before every step up
    to ``stop``, the log-likelihood of the data before it, and what it
    predicted and estimated at every step it took (:class:`NominalTrack`):
    with ``stop`` the run's length, the nominal observer of ``--filter ckf``
    (exact on a plant linear in its states)."""
    kf = NominalKalman(model, ys.shape[1])
    for k in range(stop):
        kf.step(ys[k], us[k])
    return kf.track(stop)
