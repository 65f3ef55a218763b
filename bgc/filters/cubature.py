"""Static fault posteriors by a bank of cubature Kalman filters.

A fault hypothesis with its onset ``tau`` and magnitude ``c`` (a bias, or a
slope) held fixed is a state-space model with additive Gaussian noise: the
generated model's noise-free step (RK4) plus process noise, and its noise-free
measurement plus measurement noise. The likelihood of the data under it,
p(y | hypothesis, tau, c), is what the Bayes classifier and the posterior of
the magnitude need. A particle filter estimates it without bias but with a
Monte Carlo error that needs thousands of particles per (tau, c) to be small
(the pseudo-marginal reference of ``bench/magnitude_reference.py``). A Kalman
filter gives it exactly, with no random numbers, when the plant is linear in
its states once tau and c are fixed (the circuit and the two tanks are).

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
sample's instant, which sees it, ``track.onset_transition``); all cells
start from the nominal filter's state at the earliest onset, so every cell's
likelihood covers the same data, from step 0.

The grid is adaptive in the magnitude. For a drift it is laid out in the
change the parameter reaches by the end of the run, ``c (T - tau) dt``,
which the data pin down much better than the slope (an earlier onset with a
smaller slope reaches the same change): one grid of changes serves every
onset. It starts on the particle filters' interval, widened; it is moved
while the posterior leans on an end and narrowed while its spacing is coarse
against the posterior's std. The evidence of the hypothesis, p(y |
hypothesis), is the sum over the onsets (each weighed by the span of time it
stands for: a uniform prior in time) of the likelihood integrated over the
magnitude's uniform prior (:func:`row_quadrature`: the log likelihood
interpolated by parabolas between the grid's points, exact for a Gaussian
posterior whether or not a bound of the prior cuts it off); it covers the
data from step 0, so hypotheses compare like for like.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from ..errors import ArgumentValueError
from ..kinds import fault_kind
from .particle import FilterRun, StepResult, run_filter

LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True, slots=True)
class KalmanOptions:
    """``spacing``: samples between a drift's onsets near the alarm (further
    back, 1/16 of the distance to it); ``first_points``, ``points``:
    magnitudes on the first pass of the grid
    and on the others; ``keep``: after a pass, the onsets holding less than
    this share of the best onset's mass are left out of the next; ``relay``:
    only onsets holding at least this share of it are laid anew; ``widen``: the first pass
    spans the hint interval widened by this fraction of its width on each
    side; ``passes``: at most this many passes. After a pass whose posterior
    peaks at an end of the grid, the grid reaches its span further that way;
    after one whose ends hold more than ``edge`` of the peak density, or
    whose spacing is coarse (the posterior's std under ``resolution``
    spacings), it spans 4 stds either side of the posterior's mean; else the
    pass is the last."""

    spacing: int = 4
    first_points: int = 9
    points: int = 9
    keep: float = 1e-4
    relay: float = 1e-3
    widen: float = 0.5
    passes: int = 4
    resolution: float = 0.8
    edge: float = 1e-3

    def __post_init__(self):
        if self.first_points < 3 or self.points < 3 or self.passes < 1 or self.spacing < 1:
            raise ArgumentValueError("KalmanOptions: a row needs at least 3 points (first_points, points), passes "
                                     "and spacing at least 1", None, "e.g. KalmanOptions(points=9)")


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
class StaticPosterior:
    """The posterior of a hypothesis's onset and magnitude, with the magnitude
    held static. ``onsets`` (steps) with their prior ``widths``; ``values``
    (onsets x points): the magnitude of each cell; ``loglik``: log p(y |
    onset, magnitude) over the whole run; ``log_evidence``: log p(y |
    hypothesis) (the onset's prior up to the factor common to every
    hypothesis); the magnitude's posterior ``mean``, ``std`` and central
    interval (``low``, ``high``) of probability ``level``; ``change``: the
    posterior mean of the parameter's change at the last step (the bias, or
    slope x time since the onset); ``onset_posterior`` (the mass of each
    onset of the grid) and the most probable ``onset`` (the largest mass per
    sample the onset stands for); ``passes``: grids computed; ``best``: the
    most likely cell (onset, magnitude) and ``residuals`` (steps x outputs):
    its normalised residuals (NaN before its onset), for a consistency test
    of the static model; ``truncated``: the posterior may reach past the
    grid's last pass (a row still holds mass at an end short of a bound of
    the prior); ``trace`` (steps x 2): the magnitude's posterior mean and
    std given the data up to each step, over the last pass's cells (point
    masses: a picture of how the data narrowed it down, limited to the span
    of the final grid); ``path``: when asked for (:func:`record_path`), one
    filter's run at the most probable onset with the posterior mean
    magnitude; ``seconds``: the time it took (set by its caller). ``values``
    and ``loglik`` are object arrays of rows when the onsets' rows differ in
    length."""

    name: str
    onsets: tuple[int, ...]
    widths: tuple[float, ...]
    values: np.ndarray
    loglik: np.ndarray
    log_evidence: float
    mean: float
    std: float
    low: float
    high: float
    level: float
    change: float
    onset: int
    onset_posterior: tuple[float, ...]
    passes: int
    best: tuple[int, float] | None = None
    residuals: np.ndarray | None = None
    truncated: bool = False
    trace: np.ndarray | None = None
    path: "BankResult | None" = None
    seconds: float = 0.0


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


def _rows(model: ModuleType) -> tuple[list[int], list[int]]:
    """The physical states' rows and the fault states' rows (a drifting
    parameter, then the magnitude last) of a generated model."""
    kinds = getattr(model, "STATE_KINDS", ("physical",) * len(model.STATES))
    physical = [i for i, k in enumerate(kinds) if k == "physical"]
    return physical, [i for i, k in enumerate(kinds) if k != "physical"]


def cholesky(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack of covariances (..., n, n), by
    NumPy's batched LAPACK call. When a matrix of the stack is not positive
    definite (a pivot zero or negative by rounding, or a matrix that is not
    one), the stack is factored one column at a time for all matrices at once
    instead, each pivot under 1e-12 of its diagonal entry raised to that: the
    result is then the factor of a nearby positive definite matrix, not of
    ``P``."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    n = P.shape[-1]
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


class _Filter:
    """The cubature Kalman filter's arithmetic for a model: one step of a
    stack of cells, each with its own mean, covariance and fault states (the
    magnitude last), the cells along the first axis: means (C, n),
    covariances (C, n, n), fault states (f, C). The model sees the points of
    all cells at once, as columns (n_x, C 2n), cell by cell. The measurement
    noise covariance R is the model's MEASUREMENT_STD squared, or, for a
    model whose ``measurement_std`` depends on its fault states (a noise
    fault: ``varies``), each cell's own (:meth:`_cell_noise`)."""

    def __init__(self, model: ModuleType):
        self.model = model
        self.physical, self.extra = _rows(model)
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
        self.extra_rows = np.array(self.extra, dtype=np.intp)
        self._tiles: dict = {}  # the compiled step's noise variances per cell, per pattern of sensors read
        self._seen: dict = {}

    def _points(self, m: np.ndarray, P: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Write the cubature points m +- sqrt(n) L e_i of N(m, P) of every
        cell into the physical rows of ``X`` (n_x, C, 2n); return sqrt(n) L
        (C, n, n)."""
        n = self.n
        L = cholesky(P)
        L *= self.root
        Lt = L.transpose(1, 0, 2)  # (n, C, n): state, cell, point
        if isinstance(self.rows, slice):  # a view: written in place
            physical = X[self.rows]
            np.add(m.T[:, :, None], Lt, out=physical[:, :, :n])
            np.subtract(m.T[:, :, None], Lt, out=physical[:, :, n:])
        else:
            X[self.rows] = np.concatenate([m.T[:, :, None] + Lt, m.T[:, :, None] - Lt], axis=2)
        return L

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
             onset: slice = slice(0, 0), dt: float | None = None):
        """One step (predict over ``dt``, default the model's ``DT``, with
        input ``u``, then update with ``y``; NaN: not measured) of every cell: log p(y | the past) (C,), mean (C, n)
        and covariance (C, n, n) after it, normalised residuals (C, n_y),
        and the predicted measurement's mean and std (C, n_y; NaN: not read);
        updates ``fixed`` (a drifting parameter moves). The cells ``onset``
        are at their onset sample: their transition is nominal (magnitude
        zero), their update sees the fault (``track.onset_transition``).

        The deviations of the update's points from their mean are +-sqrt(n) L,
        so the cross covariance is L (DY+ - DY-)' / 2n, DY+- the measurement
        deviations of the + and - points; the gain and the log density come
        from the Cholesky factor of the innovation covariance by forward
        substitution (:func:`lower_solve`)."""
        model, n, C = self.model, self.n, m.shape[0]
        if hasattr(getattr(model, "_kernel", None), "cubature_update"):  # a compiled package's kernel
            return self._compiled_step(y, u, m, P, fixed, onset, dt)
        if self.buffer.shape[1] < 2 * n * C:
            self.buffer = np.empty((self.n_x, 2 * n * C))
        flat = self.buffer[:, :2 * n * C]
        X = flat.reshape(self.n_x, C, 2 * n)
        self._points(m, P, X)
        self._predict_points(flat, X, u, fixed, onset, dt)
        Xp = self._physical(X)  # (C, n, 2n)
        mp = np.add.reduce(Xp, axis=2)
        mp *= self.inverse
        D = Xp - mp[:, :, None]
        D *= self.scale  # sqrt(1 / 2n): D D' is the points' covariance
        Pp = np.matmul(D, D.transpose(0, 2, 1))
        Pp += self.Q
        seen = np.isfinite(y)
        every = bool(seen.all())
        if not every and not seen.any():
            nan = np.full((C, len(y)), np.nan)
            return np.zeros(C), mp, Pp, nan, nan, nan
        L = self._points(mp, Pp, X)
        if self.extra and onset.stop > onset.start:  # the onset cells see their fault from this sample on
            X[self.extra[-1], onset] = fixed[-1][onset][:, None]
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
        # [v | Pxy'] (C, k, 1 + n), Pxy' = (DY+ - DY-) L' / 2n
        rhs = np.empty((C, len(rows), 1 + n))
        np.subtract(y[rows], yh, out=rhs[:, :, 0])
        np.matmul(np.subtract(DY[:, :, :n], DY[:, :, n:]), L.transpose(0, 2, 1), out=rhs[:, :, 1:])
        rhs[:, :, 1:] *= self.inverse
        Ly = cholesky(Syy)
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


    def _predict_points(self, flat, X, u, fixed, onset, dt):
        """Move every cell's points (``flat`` (n_x, C 2n), ``X`` its (n_x, C,
        2n) view) through the model over one sample, in place: first each
        cell's fixed rows (``fixed``: the magnitude, a drifting parameter)
        written into its points, the magnitude 0 in the cells before their
        onset; after it a drifting parameter read back into ``fixed``."""
        model = self.model
        for j, row in enumerate(self.extra):
            X[row] = fixed[j][:, None]
        if self.extra:
            X[self.extra[-1], onset] = 0.0
        model.predict(flat, u, model.THETA, model.DT if dt is None else dt, out=flat)
        for j, row in enumerate(self.extra[:-1]):  # a drifting parameter: the same in every point of a cell
            fixed[j] = X[row, :, 0]

    def _compiled_step(self, y, u, m, P, fixed, onset, dt):
        """:meth:`step` with a compiled package's kernel: the arithmetic
        between the model's calls (points and fault states, moments, the
        update) in compiled loops over the cells, one call each side of the
        prediction and one for the update. The points are laid out point by
        point, the cells innermost (point p of cell c in column p C + c), and
        so are the prediction's moments, so that the kernel's loops run over
        the cells in vector instructions."""
        model, n, C, kernel = self.model, self.n, m.shape[0], self.model._kernel
        phys = self.phys
        flat = np.empty((self.n_x, 2 * n * C))
        held = kernel.contiguous(fixed)  # a drifting parameter is read back into it
        kernel.cubature_prepare(m, P, self.root, flat, phys, self.extra_rows, held, onset)
        model.predict(flat, u, model.THETA, model.DT if dt is None else dt, out=flat)
        mp, Pp, L = kernel.cubature_after(flat, phys, self.extra_rows, held, self.inverse, self.scale, self.Q,
                                          self.root, onset)  # the cells innermost: (n, C), (n, n, C)
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
        if i:
            np.subtract(b[:, i], np.matmul(L[:, i, None, :i], x[:, :i])[:, 0], out=x[:, i])
        else:
            x[:, 0] = b[:, 0]
        x[:, i] /= L[:, i, i, None]
    return x


def run_bank(model: ModuleType, ys: np.ndarray, us: np.ndarray, track: NominalTrack, onsets, magnitudes,
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
    state[-1] = np.asarray(magnitudes, dtype=float)[order]
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


class NominalKalman:
    """The nominal model's cubature Kalman filter from its prior (``X0``,
    ``X0_STD``), one step at a time (:meth:`step`); :meth:`track` gives what
    it did so far as a :class:`NominalTrack`."""

    def __init__(self, model: ModuleType, outputs: int):
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
    and covariance."""

    def __init__(self, model: ModuleType, particles: int | None = None, rng: np.random.Generator | None = None,
                 x: np.ndarray | None = None, fixed: np.ndarray | None = None):
        self.model, self.particles, self.rng = model, particles, rng
        self.kf = kf = _Filter(model)
        if x is None:
            start = np.asarray(model.X0, dtype=float)
            self.mean = start[kf.physical]
            self.cov = np.diag(np.asarray(model.X0_STD, dtype=float)[kf.physical] ** 2)
        else:
            x = np.asarray(x, dtype=float)
            start = x.mean(axis=1)
            self.mean = start[kf.physical]
            self.cov = np.atleast_2d(np.cov(x[kf.physical]))
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


def nominal_track(model: ModuleType, ys: np.ndarray, us: np.ndarray, stop: int) -> NominalTrack:
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


def onset_widths(onsets, ends: tuple[float, float] | None = None) -> np.ndarray:
    """How many samples each onset of a sorted grid stands for: the span
    between the midpoints to its neighbours (1 for consecutive samples). The
    onset's prior is uniform in time, so an onset's prior weight is its width:
    a hypothesis's evidence is the sum over its onsets of width x likelihood,
    up to a factor (the length of the window the onset may lie in) common to
    every hypothesis. The first and last onsets reach half a spacing beyond
    themselves, or to ``ends`` when given (a grid refined inside keeps the
    window of the grid it refines: :func:`grid_ends`)."""
    s = np.asarray(onsets, dtype=float)
    lo, hi = grid_ends(s) if ends is None else ends
    return np.diff(np.concatenate([[lo], (s[1:] + s[:-1]) / 2.0, [hi]]))


def grid_ends(onsets) -> tuple[float, float]:
    """Where the window of a sorted grid of onsets starts and ends: half a
    spacing beyond its first and last onsets (half a sample for one onset)."""
    s = np.asarray(onsets, dtype=float)
    if len(s) == 1:
        return float(s[0]) - 0.5, float(s[0]) + 0.5
    return float(s[0] - (s[1] - s[0]) / 2.0), float(s[-1] + (s[-1] - s[-2]) / 2.0)


#: A drift's onsets reach further back (the next batch of ``earlier``) while
#: the onset posterior puts at least ``EXTEND`` on its ``EDGE`` earliest onsets.
EXTEND = 0.05
EDGE = 2

#: exp of a log mass above this is taken relative to the largest (exp overflows past 709)
_SAFE_EXP = 300.0


def _overflow_shift(peak: float) -> float:
    """What to subtract from log masses whose largest is ``peak`` before exp:
    0, unless ``peak`` exceeds ``_SAFE_EXP``."""
    return peak if peak > _SAFE_EXP else 0.0

#: Gauss-Legendre nodes and weights on [0, 1], for each interval of a row
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(8)
_GL_NODES, _GL_WEIGHTS = (_GL_NODES + 1.0) / 2.0, _GL_WEIGHTS / 2.0
#: the most the log density may change over one Gauss-Legendre panel (8 nodes
#: integrate exp(-8 t) on [0, 1] to about 1e-10); a steeper interval is split
_PANEL_RANGE = 8.0
#: the most Gauss-Legendre panels an interval is split into
_MOST_PANELS = 256


#: How many times an interval's own change of log density (plus 1) a neighbour may lie below it and
#: still shape the interval's parabola (:func:`row_quadrature`)
_WILD = 1e6


def row_quadrature(values: np.ndarray, logd: np.ndarray, kernel=None) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes and the log of their masses for a density known by
    its log ``logd`` at the evenly spaced points ``values`` (-inf: outside
    the prior).

    Between two points the log density is the mean of the parabolas through
    the three points on either side (one of them at an end of the row; the
    line between the two when neither exists), integrated by Gauss-Legendre
    panels, an interval split into as many as keep the log density's range
    on each under ``_PANEL_RANGE``. The rule is exact for a Gaussian at any
    spacing, cut off by a bound of the prior or not, and for an exponential
    tail (the trapezoid rule, exact for a smooth density that vanishes at
    both ends, is off by a factor of about half the log density's fall over
    one interval where a bound cuts a steep density off); a peak that lies
    between two points is found. An interval with an end outside the prior
    holds no mass. A row of one point (or of zero width) is a point mass.
    ``kernel``: a generated package's kernel; a compiled one's
    ``row_quadrature`` does the same arithmetic in one call.

    >>> x, logm = row_quadrature(np.linspace(-4.0, 4.0, 9), -np.linspace(-4.0, 4.0, 9) ** 2 / 2)
    >>> round(float(np.exp(logm).sum()), 6) == round(math.sqrt(2 * math.pi) * math.erf(4 / math.sqrt(2)), 6)
    True
    """
    v = np.asarray(values, dtype=float)
    lg = np.asarray(logd, dtype=float)
    if len(v) < 2 or not v[-1] > v[0]:
        return v[:1].copy(), lg[:1].copy()
    if hasattr(kernel, "row_quadrature"):
        return kernel.row_quadrature(v, lg, _GL_NODES, _GL_WEIGHTS, _PANEL_RANGE, _MOST_PANELS, _WILD)
    h = (v[-1] - v[0]) / (len(v) - 1)
    l0, l1 = lg[:-1, None], lg[1:, None]
    lm = np.concatenate([[-math.inf], lg[:-2]])[:, None]  # the point before each interval
    lp = np.concatenate([lg[2:], [-math.inf]])[:, None]  # the point after it

    def interpolant(t: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            left = l0 + (l1 - lm) / 2.0 * t + (l1 - 2.0 * l0 + lm) / 2.0 * t * t
            right = l0 + (l1 - l0) * t + (lp - 2.0 * l1 + l0) / 2.0 * (t * t - t)
            line = l0 + (l1 - l0) * t
            # a neighbour that lies below the interval by over _WILD times the interval's own change (a
            # grid cell whose model diverged: -2e18 beside -4e3) shapes no parabola: through it the
            # parabola would bend far above the interval's points
            own = _WILD * (np.abs(l1 - l0) + 1.0)
            has_left, has_right = np.isfinite(lm) & ~(l0 - lm > own), np.isfinite(lp) & ~(l1 - lp > own)
            out = np.where(has_left & has_right, (left + right) / 2.0,
                           np.where(has_left, left, np.where(has_right, right, line)))
        return np.where(np.isfinite(l0) & np.isfinite(l1), out, -math.inf)

    probe = interpolant(np.linspace(0.0, 1.0, 9)[None, :])
    ok = np.isfinite(probe).all(axis=1)
    spread = float(np.max(np.ptp(probe[ok], axis=1))) if ok.any() else 0.0
    panels = int(min(max(math.ceil(spread / _PANEL_RANGE), 1), _MOST_PANELS))
    t = ((np.arange(panels)[:, None] + _GL_NODES[None, :]) / panels).ravel()[None, :]
    w = np.tile(_GL_WEIGHTS / panels, panels)[None, :]
    with np.errstate(divide="ignore"):
        logm = interpolant(t) + np.log(w * h)
    return (v[:-1, None] + h * t).ravel(), logm.ravel()


@dataclass(frozen=True, slots=True)
class _Grid:
    """One pass: per onset (rows) an evenly spaced grid of changes, the
    cells' magnitudes and log likelihoods (rows x points; object arrays of
    rows when the rows differ in length), and each row's posterior mass
    ``mass`` (its onset's prior weight times the likelihood integrated over
    the magnitude by :func:`row_quadrature`), scaled by exp(-``top``)."""

    changes: np.ndarray
    magnitudes: np.ndarray
    loglik: np.ndarray
    mass: np.ndarray
    top: float


def _row_key(onset, changes: tuple[float, float], count: int) -> tuple:
    """The key of a grid row in the cache of :func:`_grid`: (onset, low, high, count)."""
    return int(onset), float(changes[0]), float(changes[1]), int(count)


def _grid(model, ys, us, track, onsets, widths, spans, ranges, count, prior, start, cache: dict) -> _Grid:
    """Row i: ``count`` changes over ``ranges[i]`` (low, high) at onset
    ``onsets[i]``, whose prior weight is ``widths[i]``; ``cache``: rows
    computed before, by (onset, low, high, count): their log likelihoods,
    normalised residuals (steps x count x outputs) and log predictive
    densities (steps x count). A magnitude outside the
    ``prior`` (beyond rounding) has no likelihood."""
    a, b = prior
    changes = np.array([np.linspace(lo, hi, count) if hi > lo else np.full(count, lo) for lo, hi in ranges])
    magnitudes = changes / spans[:, None]
    tolerance = _rounding(a, b)
    inside = (magnitudes >= a - tolerance) & (magnitudes <= b + tolerance)
    magnitudes = np.where(inside, np.clip(magnitudes, a, b), magnitudes)  # a bound reached by rounding is the bound
    keys = [_row_key(o, r, count) for o, r in zip(onsets, ranges)]
    new = [i for i, key in enumerate(keys) if key not in cache]
    if new:
        r = run_bank(model, ys, us, track, np.repeat(onsets[new], count), magnitudes[new].ravel(), start,
                     residuals=True)
        z = r.z.reshape(len(ys), len(new), count, -1).transpose(1, 0, 2, 3)  # (rows, steps, count, outputs)
        increments = (np.zeros((len(new), len(ys), count)) if r.increments is None
                      else r.increments.reshape(len(ys), len(new), count).transpose(1, 0, 2))
        for i, row, zr, inc in zip(new, r.loglik.reshape(len(new), count), z, increments):
            cache[keys[i]] = (row, zr, inc)
    loglik = np.where(inside, np.array([cache[key][0] for key in keys]), -math.inf)
    top = float(np.max(loglik))
    if not math.isfinite(top):
        return _Grid(changes, magnitudes, loglik, np.zeros(len(loglik)), top)
    kernel = getattr(model, "_kernel", None)  # a compiled one's quadrature is compiled
    logm = [row_quadrature(m, ll - top, kernel)[1] for m, ll in zip(magnitudes, loglik)]
    # the interpolant may rise far above the highest point of a row too coarse for its peak:
    # the masses are then scaled down with ``top`` raised, so that none overflows
    shift = _overflow_shift(max((float(np.max(q)) for q in logm if np.isfinite(q).any()), default=0.0))
    mass = np.array([w * np.exp(q - shift).sum() for w, q in zip(widths, logm)])
    return _Grid(changes, magnitudes, loglik, mass, top + shift)


def _next_range(changes: np.ndarray, logd: np.ndarray, bounds: tuple[float, float],
                options: KalmanOptions, kernel=None) -> tuple[tuple[float, float] | None, float]:
    """The range of changes of one onset's next pass from its row of a grid:
    ``logd``, the log density at its points (-inf outside the prior); None:
    the row is fine. ``bounds``: the changes its prior allows. Also the log
    of the row's mass (:func:`row_quadrature`, which finds a peak between two
    points of a coarse row), +inf when the peak lies beyond the row.

    A row wholly outside the prior is moved inside it, its mass unknown (+inf).
    A row whose highest point is its first or last inside the prior, short of
    a bound, reaches further that way (to where the parabola through its
    three points nearest the end puts the peak, else a span further). A row
    whose end short of a bound holds more than ``edge`` of the peak density
    is laid over 4 stds either side of the peak (the parabola's vertex and
    std when it is concave: exact for a Gaussian however narrow the row,
    else 4 times wider); a coarse one (std under ``resolution`` spacings)
    over 4 stds either side of its mean, or, pressed against a bound, over 10
    stds from the bound (an exponential's density falls to 5e-5 there, a
    half-Gaussian's to 1e-7)."""
    vmin, vmax = bounds
    if not np.isfinite(logd).any():  # wholly beyond a bound (a late onset's share of a common first grid): moved inside
        lo, hi = float(changes[0]), float(changes[-1])
        tolerance = _rounding(vmin, vmax)
        outside = hi < vmin - tolerance or lo > vmax + tolerance
        return (_inside(lo, hi, vmin, vmax), math.inf) if outside else (None, -math.inf)
    first, last, open_low, open_high = _ends(changes, logd, bounds)
    lo, hi = float(changes[first]), float(changes[last])
    top_at = int(np.argmax(logd))
    spacing = float(changes[1] - changes[0]) if len(changes) > 1 else 0.0
    vertex = sd_parabola = None
    if last - first >= 2:  # the parabola through the three points around the highest
        k = min(max(top_at, first + 1), last - 1)
        l0, l1, l2 = logd[k - 1:k + 2] - logd[top_at]
        bend = l0 - 2.0 * l1 + l2
        if bend < 0.0:
            vertex = float(changes[k] + spacing * (l0 - l2) / (2.0 * bend))
            sd_parabola = spacing / math.sqrt(-bend)
    at_low, at_high = top_at == first and open_low, top_at == last and open_high
    if at_low or at_high:  # the peak lies beyond an end
        if vertex is not None and (vertex < lo if at_low else vertex > hi):
            return _inside(vertex - 4.0 * sd_parabola, vertex + 4.0 * sd_parabola, vmin, vmax), math.inf
        span = max(hi - lo, spacing)
        return ((max(lo - span, vmin), hi) if at_low else (lo, min(hi + span, vmax))), math.inf
    x, logm = row_quadrature(changes, logd, kernel)
    peak = float(np.max(logm))
    m = np.exp(logm - peak)
    mass = peak + math.log(m.sum())
    p = m / m.sum()
    mean = float(p @ x)
    sd = math.sqrt(max(float(p @ (x - mean) ** 2), 0.0))
    edge = _holds_mass(logd, first, last, open_low, open_high, options.edge)
    if edge:  # the density reaches past an end: from the parabola when it tells, else 4 times wider
        if vertex is not None and lo - (hi - lo) <= vertex <= hi + (hi - lo):
            mean, sd = vertex, max(sd, sd_parabola)
        else:
            sd = max(sd, hi - lo)
    elif sd >= options.resolution * spacing:
        return None, mass
    if top_at in (first, last) and not edge:  # pressed against a bound: a fall like an exponential's, 10 stds
        new = (max(hi - 10.0 * sd, vmin), hi) if top_at == last else (lo, min(lo + 10.0 * sd, vmax))
    else:
        new = _inside(mean - 4.0 * sd, mean + 4.0 * sd, vmin, vmax)
    return (None if np.allclose(new, (lo, hi), rtol=1e-9, atol=0.0) else new), mass


def _inside(lo: float, hi: float, vmin: float, vmax: float) -> tuple[float, float]:
    """(lo, hi) cut to the prior's (vmin, vmax); a range beyond a bound (the
    likelihood peaks outside the prior) keeps its width against that bound."""
    width = min(hi - lo, vmax - vmin)
    if hi <= vmin:
        return vmin, vmin + width
    if lo >= vmax:
        return vmax - width, vmax
    return max(lo, vmin), min(hi, vmax)


#: At most this many rounds of a drift's onset refinement (:func:`static_posterior`).
REFINE_ROUNDS = 6


def static_posterior(model: ModuleType, ys: np.ndarray, us: np.ndarray, track: NominalTrack, onsets,
                     hint: tuple[float, float], hint_onset: int, level: float,
                     options: KalmanOptions = KalmanOptions(), earlier=(), refine: bool | None = None,
                     far=None) -> StaticPosterior:
    """The posterior of fault model ``model``'s onset (one of ``onsets``,
    each weighed by the span of samples it stands for, :func:`onset_widths`)
    and magnitude (uniform on the model's ``FAULT_PRIOR``), from cubature
    Kalman filters on a grid adapted to it. ``hint``: an interval of the
    magnitude where the posterior is expected (the particle filters'
    interval) when the onset is ``hint_onset``; ``track``: the nominal filter
    over the run up to the latest onset; ``earlier``: batches of earlier
    onsets the fault reaches back to, one batch at a time, while its onset
    posterior piles up at its earliest onsets (``EXTEND`` on the ``EDGE``
    earliest); ``refine``: whether the onset is refined sample by sample
    around the most probable one (below; None: for a drift only); ``far``:
    a test of the most likely cell's normalised residuals (steps x outputs,
    from its onset) after each pass: when it says the cell is far off the
    data, the model is (its best fit fails, the grid only refines it) and no
    further pass is made (``StaticPosterior.passes`` tells how many were).

    The first pass lays one grid of ``first_points`` changes over the hint,
    widened (and moved inside the prior when it lies beyond a bound), at
    every onset; after it each onset's row is laid anew on its own
    (:func:`_next_range`), up to ``passes`` passes; onsets holding under
    ``keep`` of the best one's mass are left out of the next pass."""
    T = len(ys)
    kind = fault_kind(model.FAULT["kind"])
    drifts = kind.drifts
    prior = tuple(float(v) for v in model.FAULT_PRIOR)
    a, b = prior
    batches = [sorted(int(o) for o in batch) for batch in earlier]

    def span(o) -> np.ndarray:  # a cell's variable: the parameter's change by the last step (bias, slope x time)
        o = np.asarray(o, dtype=float)
        return kind.change(np.ones(o.shape), (T - o) * model.DT)

    current = np.asarray(sorted(int(o) for o in onsets))
    tried = current.tolist()
    width_of = dict(zip(tried, onset_widths(tried).tolist()))  # an onset's prior weight: its span in the grid tried
    spans = span(current)
    scale = float(kind.change(1.0, (T - hint_onset) * model.DT))
    lo, hi = sorted((hint[0] * scale, hint[1] * scale))
    vmin, vmax = float(np.min(a * spans)), float(np.max(b * spans))
    width = max(hi - lo, 1e-6 * max(abs(lo), abs(hi), vmax - vmin))
    lo, hi = _inside(lo - options.widen * width, hi + options.widen * width, vmin, vmax)
    ranges = {int(o): (lo, hi) for o in current}
    counts = {int(o): options.first_points for o in current}
    start = fault_start(model, track, int(current[0]))
    kernel = getattr(model, "_kernel", None)  # the quadrature's (compiled in a compiled package)
    cache: dict = {}
    passes = 0
    g = None
    rounds = 0  # of a drift's onset refinement, below
    ends = None  # the window of the onsets' grid before it was refined
    given_up = False  # the best fit is far off the data (``far``): no further pass
    while True:
        for turn in range(options.passes):
            passes += 1
            spans = span(current)
            groups = {}  # rows of one point count are one grid
            for i, o in enumerate(current.tolist()):
                groups.setdefault(counts[o], []).append(i)
            widths = np.array([width_of[o] for o in current.tolist()])
            parts = {c: _grid(model, ys, us, track, current[rows], widths[rows], spans[rows],
                              [ranges[current[i]] for i in rows], c, prior, start, cache)
                     for c, rows in groups.items()}
            g = _merge(current, groups, parts)
            if not math.isfinite(g.top) or turn == options.passes - 1:
                break
            if far is not None:
                row = int(np.argmax([np.max(ll) for ll in g.loglik]))
                o = int(current[row])
                key = _row_key(o, ranges[o], counts[o])
                if far(cache[key][1][o:, int(np.argmax(g.loglik[row]))]):
                    given_up = True
                    break
            following, mass = [], np.empty(len(current))  # log of each onset's mass, as far as its row tells
            for i in range(len(current)):
                bounds = tuple(sorted((a * spans[i], b * spans[i])))
                f, mass[i] = _next_range(g.changes[i], g.loglik[i], bounds, options, kernel)
                following.append(f)
                mass[i] += math.log(widths[i] / spans[i])
            told = np.isfinite(mass)
            best = mass[told].max() if told.any() else math.inf
            # onsets the posterior leaves out are left out (a coarse row's mass as its quadrature tells: a
            # peak may lie between its points); rows are laid anew only where the posterior's mass is
            kept = ~told & (mass > 0) | told & (mass >= math.log(options.keep) + best)
            relaid = [i for i, f in enumerate(following)
                      if f is not None and kept[i] and not (told[i] and mass[i] < math.log(options.relay) + best)]
            if not relaid and kept.all():
                break
            for i in relaid:
                ranges[int(current[i])], counts[int(current[i])] = following[i], options.points
            current = current[kept]
        if g is None or not math.isfinite(g.top) or given_up:
            break
        share = dict(zip(current.tolist(), g.mass))
        if not (batches and sum(share.get(o, 0.0) for o in tried[:EDGE]) / sum(share.values()) >= EXTEND):
            # a fault's magnitude given its onset is much sharper than the onset grid: every sample from
            # the most probable onset's neighbour before it in the grid tried to the one after it is tried
            # too (for a drift, those left out by an earlier pass as well), so the onset is marginalised
            # sample by sample where the posterior is (it is a whole number of samples); again while the
            # most probable onset moves to an end of what was tried
            if not (drifts if refine is None else refine) or rounds == REFINE_ROUNDS:
                break
            best = max(share, key=lambda o: share[o] / width_of[o])
            before = [o for o in tried if o < best]
            after = [o for o in tried if o > best]
            fill = [o for o in range(before[-1] if before else best, (after[0] if after else best) + 1)
                    if o not in (share if drifts else tried)]
            if not fill:
                break
            rounds += 1
            if ends is None:  # the refined grid keeps the window of the grid it refines (the evidence's factor)
                ends = grid_ends(tried)
            tried = sorted(set(fill) | set(tried))
            width_of = dict(zip(tried, onset_widths(tried, ends).tolist()))
            for o in fill:
                ranges[o], counts[o] = ranges[best], counts[best]
            current = np.asarray(sorted(set(fill) | set(current.tolist())))
            continue
        batch = batches.pop(0)  # a drift that began earlier: reach further back, from the earliest onset's grid
        tried = sorted(set(batch) | set(tried))
        width_of = dict(zip(tried, onset_widths(tried).tolist()))
        ends = None
        for o in batch:
            ranges[o], counts[o] = ranges[int(current[0])], counts[int(current[0])]
        current = np.asarray(sorted(set(batch) | set(current.tolist())))
    name = getattr(model, "NAME", "")
    widths = [width_of[int(o)] for o in current]

    def none_told() -> StaticPosterior:
        """What the grid cannot tell: no likelihood (log evidence -inf), no estimate."""
        nan = math.nan
        return StaticPosterior(name, tuple(int(o) for o in current), tuple(widths), np.zeros((len(current), 0)),
                               np.zeros((len(current), 0)), -math.inf, nan, nan, nan, nan, level, nan,
                               int(current[0]), tuple(0.0 for _ in current), passes)

    if g is None or not math.isfinite(g.top):
        return none_told()
    spans = span(current)
    nodes, changes, logm, rows = [], [], [], []
    for i, (m, ll) in enumerate(zip(g.magnitudes, g.loglik)):
        x, lm = row_quadrature(m, ll - g.top, kernel)
        nodes.append(x)
        changes.append(x * spans[i])
        logm.append(lm + math.log(widths[i]))
        rows.append(np.full(len(x), i))
    x, c, row_of = np.concatenate(nodes), np.concatenate(changes), np.concatenate(rows)
    every = np.concatenate(logm)
    shift = _overflow_shift(float(np.max(every)))  # see _grid
    mass = np.exp(every - shift)
    total = float(mass.sum())
    # the grid's points hold no mass: the quadrature's interpolant rose far above its points (a row whose
    # next point is extreme, e.g. -2e18 where a magnitude made the model diverge, bends the parabola
    # through it upwards: tests/test_kalman.py, the strict xfail) and the shift left every mass at 0
    if not total > 0.0:
        return none_told()
    log_evidence = g.top + shift + math.log(total) - math.log(b - a)
    p = mass / total
    mean = float(p @ x)
    std = math.sqrt(max(float(p @ (x - mean) ** 2), 0.0))
    order = np.argsort(x, kind="stable")
    cdf = np.cumsum(p[order]) - p[order] / 2.0
    low, high = (float(q) for q in np.interp([(1.0 - level) / 2.0, (1.0 + level) / 2.0], cdf, x[order]))
    onset_posterior = np.bincount(row_of, weights=p, minlength=len(current))
    row = int(np.argmax([np.max(ll) for ll in g.loglik]))  # the most likely cell, and its residuals
    col = int(np.argmax(g.loglik[row]))
    best = (int(current[row]), float(g.magnitudes[row][col]))
    key = {int(o): _row_key(o, ranges[int(o)], counts[int(o)]) for o in current}
    residuals = cache[key[best[0]]][1][:, col]
    trace = _trace(track, current, widths, g, [cache[key[int(o)]][2] for o in current])
    return StaticPosterior(name, tuple(int(o) for o in current), tuple(float(w) for w in widths),
                           g.magnitudes, g.loglik, log_evidence, mean, std, low, high, level, float(p @ c),
                           int(current[int(np.argmax(onset_posterior / np.asarray(widths)))]),
                           tuple(float(q) for q in onset_posterior), passes, best, residuals,
                           _truncated(g, prior, options), trace)


def fault_start(model: ModuleType, track: NominalTrack, onset: int) -> np.ndarray:
    """The fault states a cell of ``model`` starts with (a drifting
    parameter's nominal value; the magnitude, last, is the cell's own)."""
    _, extra = _rows(model)
    return model.augment(track.mean[onset][:, None], np.random.default_rng(0))[extra, 0]


def _trace(track: NominalTrack, onsets, widths, g: _Grid, increments: list) -> np.ndarray:
    """(steps x 2): the magnitude's posterior mean and std given the data up
    to each step, over the cells of grid ``g`` (row i at ``onsets[i]``, its
    prior weight ``widths[i]``, its cells' log predictive densities
    ``increments[i]``, steps x cells), each cell a point mass of its row's
    spacing: before a cell's onset its likelihood is the nominal filter's."""
    T = len(increments[0])
    logs, values, weights = [], [], []
    for o, w, m, ll, inc in zip(onsets, widths, g.magnitudes, g.loglik, increments):
        o = int(o)
        m = np.asarray(m, dtype=float)
        spacing = float(abs(m[-1] - m[0]) / (len(m) - 1)) if len(m) > 1 and m[-1] != m[0] else 1.0
        cum = np.empty((T, len(m)))
        cum[:o] = track.loglik[1:o + 1, None]
        cum[o:] = track.loglik[o] + np.cumsum(inc[o:], axis=0)
        cum[:, ~np.isfinite(np.asarray(ll, dtype=float))] = -math.inf  # outside the prior
        logs.append(cum)
        values.append(m)
        weights.append(np.full(len(m), w * spacing))
    L, v, w = np.concatenate(logs, axis=1), np.concatenate(values), np.concatenate(weights)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.exp(L - np.max(L, axis=1, keepdims=True)) * w
        p /= p.sum(axis=1, keepdims=True)
        mean = p @ v
        std = np.sqrt(np.maximum(p @ (v * v) - mean * mean, 0.0))
    return np.column_stack([mean, std])


def record_path(model: ModuleType, ys: np.ndarray, us: np.ndarray, track: NominalTrack,
                p: StaticPosterior) -> StaticPosterior:
    """``p`` with its ``path``: the filter of its most probable onset with
    its posterior mean magnitude, its predictions and estimates recorded."""
    if not math.isfinite(p.log_evidence):
        return p
    r = run_bank(model, ys, us, track, [p.onset], [p.mean], fault_start(model, track, p.onset), residuals=True,
                 record=True)
    return dataclasses.replace(p, path=r)


def _truncated(g: _Grid, prior: tuple[float, float], options: KalmanOptions) -> bool:
    """Whether a row holding at least ``relay`` of the posterior's mass still
    has its highest point, or more than ``edge`` of it, at an end short of a
    bound of the prior after the last pass: its posterior may reach past the
    grid."""
    share = g.mass / g.mass.sum()
    return any(_holds_mass(ll, *_ends(m, ll, prior), options.edge)
               for m, ll, s in zip(g.magnitudes, g.loglik, share)
               if s >= options.relay and np.isfinite(ll).sum() >= 2)


def _rounding(lo: float, hi: float) -> float:
    """How far a value may lie beyond a bound of (``lo``, ``hi``) by rounding alone."""
    return 1e-9 * max(abs(lo), abs(hi), hi - lo)


def _ends(values: np.ndarray, logd: np.ndarray, bounds: tuple[float, float]) -> tuple[int, int, bool, bool]:
    """The first and last points of a row inside the prior (finite
    ``logd``; there is one at least), and whether each lies short of its
    bound of ``bounds`` (by more than rounding)."""
    finite = np.flatnonzero(np.isfinite(logd))
    first, last = int(finite[0]), int(finite[-1])
    vmin, vmax = bounds
    tolerance = _rounding(vmin, vmax)
    return first, last, bool(values[first] > vmin + tolerance), bool(values[last] < vmax - tolerance)


def _holds_mass(logd: np.ndarray, first: int, last: int, open_low: bool, open_high: bool, edge: float) -> bool:
    """Whether an end of a row short of a bound (``open_low``,
    ``open_high``) holds more than ``edge`` of the row's peak density: the
    density reaches past the row."""
    d_first, d_last = np.exp(logd[[first, last]] - np.max(logd))
    return bool(d_first > edge and open_low or d_last > edge and open_high)


def _merge(onsets: np.ndarray, groups: dict, parts: dict) -> _Grid:
    """The grids of ``parts`` (point count -> grid of the rows ``groups[count]``)
    as one, row i for onset i, on a common scale. Rows may differ in length:
    the arrays are object arrays of rows then."""
    top = max(part.top for part in parts.values())
    rows = [None] * len(onsets)
    for c, idx in groups.items():
        part = parts[c]
        scale = math.exp(part.top - top) if math.isfinite(part.top) else 0.0
        for k, i in enumerate(idx):
            rows[i] = (part.changes[k], part.magnitudes[k], part.loglik[k], part.mass[k] * scale)
    mass = np.array([r[3] for r in rows])
    if len({len(r[0]) for r in rows}) == 1:
        changes, magnitudes, loglik = (np.array([r[j] for r in rows]) for j in range(3))
    else:
        changes, magnitudes, loglik = (_ragged([r[j] for r in rows]) for j in range(3))
    return _Grid(changes, magnitudes, loglik, mass, top)


def _ragged(rows: list) -> np.ndarray:
    """An object array of the arrays ``rows`` (NumPy would broadcast rows of one length into 2-D)."""
    out = np.empty(len(rows), dtype=object)
    for i, r in enumerate(rows):
        out[i] = r
    return out
