"""Calibration: noise levels and nominal values estimated from healthy data.

A diagnoser is only as good as its nominal model. From one or more
fault-free recordings, :func:`calibrate` finds the maximum-likelihood
values of each sensor's measurement-noise std, the process-noise level
(``simulation.process_noise``) and the parameters the user names, with a 95 %
interval for each, and names those the data cannot tell.

**The likelihood.** The recordings are independent runs of the nominal
model, each from its prior (``X0``, ``X0_STD``). The log-likelihood of a run
is the sum over its samples of the log predictive density of each sample
given the ones before: the prediction-error decomposition of a state-space
model's likelihood (Schweppe 1965; Harvey 1989, section 3.4), computed by the
nominal model's cubature Kalman filter (Arasaratnam and Haykin 2009;
:class:`bgc.filters.cubature.NominalKalman`, the ``--filter ckf`` observer).
On a plant linear in its states (the circuit, the two tanks) that filter is
the Kalman filter and the likelihood is exact; on the RO plant it is a close
approximation. Steps without a sample are predicted across (they add no
term), a sensor not read on a row is left out of that row's term, and the
data meet the model's time grid as they do in a diagnosis
(:mod:`bgc.data.sampler`).

**What changes with what.** The generated model reads its parameters from
``THETA`` and its noise from ``PROCESS_STD``, ``MEASUREMENT_STD`` and
``X0_STD`` (twice the process std, as bgc compiles it), all passed to the
filter through the module: a likelihood evaluation runs the filter on a copy
of the module's namespace with those four replaced, nothing is recompiled.
A sensor's noise is estimated as its absolute std (its relative level, the
model file's ``noise``, is that std over the sensor's nominal reading); the
process noise as the model's relative level ``q``, whose absolute stds are
the compiler's (:meth:`bgc.ir.Numerics.noise_at`): ``q`` times each state's
size times ``sqrt(min(1, 2 dt / tau))``, ``tau`` the state's own time
constant, which follows the estimated parameters (the Jacobian's diagonal of
the generated ``derivative``, by central differences). The process noise
keeps the model's shape across states: one level is estimated, as the model
file declares one.

**The optimiser** is SciPy's L-BFGS-B (Byrd et al. 1995) on the negative
log-likelihood, in the logarithms of the stds, of the process level and of
the parameters (a parameter whose nominal value is 0 in its own units),
followed by up to three Newton steps with the numerical Hessian. The
**interval** of each estimate ends where the log-likelihood has fallen by
chi2(0.95, 1) / 2 = 1.92 from its maximum, walking along the estimate while
the others follow their conditional best to first order (the direction of
the inverse Hessian's column; :func:`_interval_ends`): on a quadratic
log-likelihood that is the curvature's ``z +- 1.96 sd``, and where the
likelihood is lopsided (a std near 0) it follows the likelihood. An
estimate is **not identifiable** when the Hessian is near singular along a
direction it takes part in, when its correlation with another estimate is
above 0.99 in magnitude (parameters that enter only as a product), or when
its interval spans more than a factor of 100 (a flat likelihood): it is
named, keeps the model's value, and the others are estimated again with it
held there. Of a flat direction or of correlated estimates one is held at a
time (the one most in the direction, or in the most correlated pairs), and
the others estimated again: they then tell the combination the data see,
carrying the held one's error (holding them all left the combination at the
model's value, and the calibrated model no more fitting the plant than the
model file: a user told again to calibrate what had just been calibrated). A
process level whose likelihood is highest at 0 (it falls 1000 times below its
start) is 0, with a one-sided bound (Self and Liang 1987). Where the optimiser
stops short of a maximum it is started again from there; where none is found,
a :class:`~bgc.errors.CalibrationError` says so.

**The innovations** of the calibrated model on the data (the normalised
residuals of the nominal filter, which are white N(0, 1) when the model
fits) are summed up per sensor: their mean, variance and the Ljung-Box
portmanteau statistic (Ljung and Box 1978) over ``lags`` lags with its
chi-square p-value.
"""

from __future__ import annotations

import math
import time
import types
from dataclasses import dataclass

from typing import Sequence

import numpy as np

from ..arguments import spelled
from ..errors import CalibrationError, printable
from ..ir import Numerics
from ..data import sampler as data_grid
from ..filters import residuals
from ..filters.residuals import Innovations, innovations
from ..filters.cubature import NominalKalman, nominal_logliks
from ..data.runs import Run, header_timing, input_columns
from ..model.protocol import FaultModel

#: The ``--estimate`` words that name noise (a parameter's name names itself).
NOISE_WORDS = ("noise", "measurement_noise", "process_noise")
#: The ``--estimate`` word that asks for each recording's initial state.
INITIAL_WORD = "initial"
#: The probability of a finding (:attr:`Calibration.findings`) when the model fits, over all sensors and tests.
FIT_LEVEL = 0.01
#: The start of the process level when the model declares none (0 has no logarithm).
PROCESS_START = 0.01
#: Largest |correlation| between two estimates for both to be identifiable.
MAX_CORRELATION = 0.99
#: Largest ratio high / low of an interval (log coordinates) for an identifiable estimate.
MAX_SPAN = 100.0
#: Eigenvalues of the Hessian under this share of the largest are a flat direction.
FLAT = 1e-9
#: Directions of the Hessian under this share of the largest eigenvalue are not asked for a small Newton
#: step at the maximum (an estimate the data barely tell; the identifiability test names it).
FLAT_STEP = 1e-6
#: The 95 % point of the standard normal.
Z95 = 1.959963984540054
#: A process level that falls this far (a logarithm: 1000 times) below its start is taken as 0.
ZERO_FALL = math.log(1e3)
#: The fall of the log-likelihood that ends a 95 % interval (the chi-square quantile of 0.95 with one degree
#: of freedom, halved).
DROP95 = 3.841458820694124 / 2
#: How close (relative) the fall at an interval's end comes to ``DROP95``.
DROP_TOL = 1e-3
#: The fall of the log-likelihood that ends the interval of a level estimated at 0 (the chi-square
#: quantile of 0.90 with one degree of freedom, halved: a one-sided 95 % bound at the boundary).
ZERO_DROP = 2.705543454095404 / 2
#: The length of the optimiser's first step (its objective is scaled to that gradient at the start).
FIRST_STEP = 0.1
#: Starts of the optimiser from where it stopped, when that is not a maximum.
RESTARTS = 2
#: How far (in the optimiser's coordinates) an estimate may move from its start.
REACH = 15.0


@dataclass(frozen=True, slots=True)
class Record:
    """One recording on the model's time grid: measurements ``ys`` (T,
    n_y; NaN: not read) and inputs ``us`` (T, n_u) at times ``ts`` (T,);
    ``source``: its name (the file)."""

    source: str
    ys: np.ndarray
    us: np.ndarray
    ts: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class Estimate:
    """One estimated quantity: ``kind`` ``measurement_noise`` (``subject``: a
    sensor; ``value`` its absolute std, ``level`` the model file's relative
    ``noise``), ``process_noise`` (``subject`` ``process``; ``value`` and
    ``level`` the relative level ``simulation.process_noise``) or
    ``parameter`` (``subject``: its name; ``value``, ``level``: its value)
    or ``initial`` (``subject``: a state, ``STATE of SOURCE`` over several
    recordings; ``value``, ``level``: its value at the recording's start).
    ``low``, ``high``: the 95 % interval of ``value`` (``level_low``,
    ``level_high`` of ``level``); ``start``: the model's value. Not
    ``identifiable``: ``why`` says why, and ``value`` is the model's."""

    kind: str
    subject: str
    value: float
    low: float
    high: float
    level: float
    level_low: float
    level_high: float
    start: float
    start_level: float
    identifiable: bool = True
    why: str | None = None
    at_bound: bool = False

    @property
    def name(self) -> str:
        """``noise F10``, ``process noise`` or the parameter's name."""
        return {"measurement_noise": f"noise {self.subject}", "process_noise": "process noise",
                "initial": f"initial {self.subject}"}.get(self.kind, self.subject)


@dataclass(frozen=True, slots=True)
class Calibration:
    """What :func:`calibrate` found: the ``estimates`` (in the order asked:
    sensors, process, parameters), the log-likelihood of the data at the
    model's values (``start_loglik``) and at the estimates (``loglik``), the
    correlation matrix of the identifiable estimates (``correlation``, in the
    order of ``correlated``), the ``innovations`` per sensor, the
    recordings' ``sources`` and ``samples`` (rows read), whether the
    fit ``converged`` (a maximum by the gradient and the Hessian, whatever
    the optimiser's own flag) and the optimiser's ``message``, the likelihood
    ``evaluations`` and the ``seconds`` it took; ``residuals``: per
    recording, the calibrated model's normalised residuals (steps, sensors
    ``outputs``; NaN: not read), what the innovations sum up, at the
    recording's ``times`` (steps,); ``spread``: per sensor, the standard
    deviation the estimates' uncertainty leaves on a fresh
    recording's residual variance (:func:`_spread`; the model file's
    ``residual_variance_sd``)."""

    estimates: tuple[Estimate, ...]
    loglik: float
    start_loglik: float
    correlated: tuple[str, ...]
    correlation: tuple[tuple[float, ...], ...]
    innovations: tuple[Innovations, ...]
    sources: tuple[str, ...]
    samples: int
    converged: bool
    message: str
    evaluations: int
    seconds: float
    outputs: tuple[str, ...] = ()
    residuals: tuple[np.ndarray, ...] = ()
    times: tuple[np.ndarray, ...] = ()
    spread: tuple[tuple[str, float], ...] = ()

    @property
    def findings(self) -> tuple[str, ...]:
        """What the innovations say is wrong with the calibrated model, one
        sentence per sensor that fails a test at ``FIT_LEVEL`` over every
        sensor and test (:func:`bgc.filters.residuals.findings`: residuals
        correlated, off 0, or of another variance than 1); empty when the
        model explains the data."""
        return residuals.findings(self.innovations, FIT_LEVEL)

    @property
    def verdict(self) -> str:
        """One line: "the model explains this data", or its findings."""
        return "; ".join(self.findings) or "the model explains this data"

    def estimate(self, name: str) -> Estimate:
        """The estimate called ``name`` (``noise F10``, ``process noise``, a parameter)."""
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)


def targets(words: str | Sequence[str], model: FaultModel, parameters: Sequence[str],
            where: str = "--estimate") -> tuple[tuple[str, ...], bool, tuple[str, ...]]:
    """What ``--estimate`` asks for: (the sensors whose noise, whether the
    process level, the parameters), from words ``noise`` (every sensor's
    noise and the process level), ``measurement_noise``, ``process_noise``
    and parameter names (of the model file's ``parameters``), separated by
    commas; the word ``initial`` (each recording's initial state) is read by
    :func:`wants_initial`.

    Raises
    ------
    CalibrationError
        An unknown word, a repeated one, or none.
    """
    items = [w.strip() for w in (words.split(",") if isinstance(words, str) else words)]
    if not items or any(not w for w in items):
        raise CalibrationError(f"{where} {printable(repr(','.join(items)))}: an empty name", None,
                               f"e.g. {spelled('estimate=', '--estimate ')}noise,R1 (names separated by commas)")
    sensors: tuple[str, ...] = ()
    process = False
    chosen: list[str] = []
    for w in items:
        if w in ("noise", "measurement_noise"):
            sensors = tuple(model.OUTPUTS)
        if w in ("noise", "process_noise"):
            process = True
        if w in NOISE_WORDS or w == INITIAL_WORD:
            continue
        if w not in parameters:
            raise CalibrationError(
                f"{where} {printable(w)}: not a parameter of {model.MODEL}", None,
                f"give noise, measurement_noise, process_noise, initial or parameters of the model file "
                f"({', '.join(parameters) or 'it declares none'})")
        if w in chosen:
            raise CalibrationError(f"{where} {printable(w)}: named twice", None, "name each parameter once")
        chosen.append(w)
    return sensors, process, tuple(chosen)


def wants_initial(words: str | Sequence[str]) -> bool:
    """Whether ``--estimate`` asks for the recordings' initial states (the word ``initial``)."""
    return INITIAL_WORD in [w.strip() for w in (words.split(",") if isinstance(words, str) else words)]


def record_of(run: Run, model: FaultModel, timing: str | None = None) -> Record:
    """A checked run (:func:`bgc.data.runs.check_run`) on the model's time
    grid, as a diagnosis reads it (:class:`bgc.data.sampler.Sampler`: gaps
    predicted across, empty input cells held, absent sensors missing); its
    inputs' ``timing`` ``end`` or ``start`` (None: as its header says,
    :func:`bgc.data.runs.header_timing`, else ``end``)."""
    sampler = data_grid.Sampler(model, tuple(input_columns(run)), tuple(run.measurements), run.source, None,
                                timing or header_timing(run.header, run.source) or "end")
    ys, us, ts = [], [], []
    for s in data_grid.samples(run, sampler):
        ys.append(s.y)
        us.append(s.u)
        ts.append(s.t)
    n_u = len(model.INPUTS)
    return Record(run.source, np.array(ys, dtype=float).reshape(len(ys), len(model.OUTPUTS)),
                  np.array(us, dtype=float).reshape(len(us), n_u), np.array(ts, dtype=float))


class _Likelihood:
    """The log-likelihood of the records as a function of the optimiser's
    coordinates ``z``: the sensors' log stds, the log process level, the
    parameters (log |value|, or the value when the model's is 0), then the
    ``initial`` states asked for, pairs (recording, physical state), each as
    its value over the state's size. ``level``: the process level when it is
    held at another value than the model's (0: the data show none)."""

    def __init__(self, model: FaultModel, numerics: Numerics, records: Sequence[Record],
                 sensors: Sequence[str], process: bool, parameters: Sequence[str], level: float | None = None,
                 initial: Sequence[tuple[int, int]] = (), modes: Sequence[Numerics] = ()):
        self.model, self.numerics, self.records = model, numerics, tuple(records)
        self.initial = tuple(initial)
        self.sensor_rows = [list(model.OUTPUTS).index(s) for s in sensors]
        self.process = process
        self.param_rows = [list(model.PARAMETERS).index(p) for p in parameters]
        self.theta0 = np.asarray(model.THETA, dtype=float)
        self.sigma0 = np.asarray(model.MEASUREMENT_STD, dtype=float)
        self.fixed_level = level  # a process level held (None: the model's)
        self.level0 = float(numerics.equations.model.settings.process_noise if level is None else level)
        self.signs = [float(np.sign(self.theta0[i])) for i in self.param_rows]  # 0: linear coordinate
        self.physical = [i for i, k in enumerate(getattr(model, "STATE_KINDS", ("physical",) * len(model.STATES)))
                         if k == "physical"]
        self.u0 = np.asarray(model.inputs(0.0), dtype=float)
        self.sources = _sources_of(model, numerics, self.physical, tuple(modes))
        self.factor0 = self._factors(self.theta0)
        self.x0 = np.asarray(model.X0, dtype=float)
        scale = dict(zip(self.physical, (nums.x_scale[k] for _, nums, k in self.sources)))
        self.x_size = np.array([_state_size(self.x0[i], scale.get(i, 0.0)) for i in range(len(self.x0))])
        self.evaluations = 0

    def start(self) -> np.ndarray:
        """The model's own values in the optimiser's coordinates."""
        z = [math.log(self.sigma0[j]) for j in self.sensor_rows]
        if self.process:
            z.append(math.log(self.level0 if self.level0 > 0 else PROCESS_START))
        for i, s in zip(self.param_rows, self.signs):
            z.append(math.log(abs(self.theta0[i])) if s else float(self.theta0[i]))
        z += [self.x0[i] / self.x_size[i] for _, i in self.initial]
        return np.array(z, dtype=float)

    def starts(self, z: np.ndarray) -> list[np.ndarray]:
        """Each record's initial state at ``z`` (the model's ``X0`` where not estimated)."""
        out = [self.x0.copy() for _ in self.records]
        tail = len(z) - len(self.initial)
        for v, (r, i) in zip(z[tail:], self.initial):
            out[r][i] = v * self.x_size[i]
        return out

    def values(self, z: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """(measurement stds, process level, THETA) at ``z``."""
        sigma = self.sigma0.copy()
        k = len(self.sensor_rows)
        sigma[self.sensor_rows] = np.exp(z[:k])
        level = self.level0
        if self.process:
            level = float(math.exp(z[k]))
            k += 1
        theta = self.theta0.copy()
        for j, (i, s) in enumerate(zip(self.param_rows, self.signs)):
            theta[i] = s * math.exp(z[k + j]) if s else z[k + j]
        return sigma, level, theta

    def _factors(self, theta: np.ndarray) -> np.ndarray:
        """Each physical state's ``sqrt(min(1, 2 dt / tau))`` at ``theta``,
        ``tau`` = 1 / |d(dx_i/dt)/dx_i| at X0 and the inputs at t = 0 (central
        differences of the generated ``derivative``; the run's length when
        it is 0), as the compiler sets the process noise's shape."""
        dt = float(self.model.DT)
        horizon = self.numerics.equations.model.settings.steps * dt
        out = []
        for m, _, i in self.sources:  # a model with modes: the state in the first mode it is one of
            x0 = np.asarray(m.X0, dtype=float)
            u0 = self.u0 if m is self.model else np.asarray(m.inputs(0.0), dtype=float)
            h = 1e-6 * max(abs(x0[i]), 1e-3)
            x = np.repeat(x0[:, None], 2, axis=1)
            x[i, 0] += h
            x[i, 1] -= h
            d = np.asarray(m.derivative(x, u0, tuple(theta)), dtype=float)
            j = (d[i, 0] - d[i, 1]) / (2 * h)
            tau = 1.0 / abs(j) if j != 0 and math.isfinite(j) else horizon
            out.append(math.sqrt(min(1.0, 2.0 * dt / tau)))
        return np.array(out)

    def module(self, z: np.ndarray) -> FaultModel:
        """A copy of the nominal module's namespace with THETA and the noise at ``z``."""
        sigma, level, theta = self.values(z)
        ns = types.ModuleType(self.model.__name__)
        ns.__dict__.update(vars(self.model))
        at = level if self.process else self.fixed_level
        levels = {id(nums): nums.noise_at(at).process for _, nums, _ in self.sources}
        process = np.array([levels[id(nums)][k] for _, nums, k in self.sources], dtype=float)
        if self.param_rows:
            process = process * self._factors(theta) / self.factor0
        std = np.asarray(self.model.PROCESS_STD, dtype=float).copy()
        std[self.physical] = process
        x0_std = np.asarray(self.model.X0_STD, dtype=float).copy()
        x0_std[self.physical] = 2.0 * process  # as bgc compiles X0_STD
        ns.THETA = tuple(float(v) for v in theta)
        ns.MEASUREMENT_STD = sigma
        ns.PROCESS_STD = std
        ns.X0_STD = x0_std
        return ns

    def record_models(self, z: np.ndarray) -> list[FaultModel]:
        """Per record, :meth:`module` at ``z`` starting where that record starts (:meth:`starts`)."""
        ns = self.module(z)
        out = []
        for x0 in self.starts(z):
            one = types.ModuleType(ns.__name__)
            one.__dict__.update(vars(ns))
            one.X0 = x0
            out.append(one)
        return out

    def filters(self, z: np.ndarray) -> list[NominalKalman]:
        """The nominal filter run over each record at ``z``."""
        out = []
        for r, model in zip(self.records, self.record_models(z)):
            kf = NominalKalman(model, r.ys.shape[1])
            for k in range(len(r.ys)):
                kf.step(r.ys[k], r.us[k])
            out.append(kf)
        return out

    def __call__(self, z: np.ndarray) -> float:
        """The log-likelihood at ``z`` (-inf where the filter fails)."""
        self.evaluations += 1
        with np.errstate(all="ignore"):
            total = float(sum(kf.logliks[-1] for kf in self.filters(np.asarray(z, dtype=float))))
        return total if math.isfinite(total) else -math.inf

    def many(self, zs: Sequence[np.ndarray]) -> list[float]:
        """``[self(z) for z in zs]``, the same numbers bit for bit, the filters
        of all the points run side by side over each record
        (:func:`bgc.filters.cubature.nominal_logliks`): a finite difference's
        points, or a gradient's with the point itself, for about the cost of
        one or two filters instead of one each (on the NumPy backend; a
        compiled one's run one at a time)."""
        zs = [np.asarray(z, dtype=float) for z in zs]
        if len(zs) < 2:
            return [self(z) for z in zs]
        self.evaluations += len(zs)
        with np.errstate(all="ignore"):  # as __call__ builds its models (filters())
            models = [self.record_models(z) for z in zs]  # per point, per record
            per_record = [nominal_logliks([m[r] for m in models], record.ys, record.us)
                          for r, record in enumerate(self.records)]
            out = []
            for i in range(len(zs)):
                total = float(sum(lls[i] for lls in per_record))
                out.append(total if math.isfinite(total) else -math.inf)
        return out


def _sources_of(model: FaultModel, numerics: Numerics, physical: list[int],
                modes: tuple[Numerics, ...]) -> list[tuple[FaultModel, Numerics, int]]:
    """Per physical state of ``model`` (rows ``physical``): the module, the
    numerics and the row its noise and time constant come from: its own,
    or, for a model with modes (``modes``: each mode's numerics), the first
    mode it is a state of, as the compiler sets a state's noise
    (:mod:`bgc.compiler.hybrid_codegen`): that mode's generated module
    (``_MODULES``) and the state's row in it (``_ROWS``)."""
    if not modes:
        return [(model, numerics, i) for i in physical]
    out = []
    for i in physical:
        mode = next(j for j, rows in enumerate(model._ROWS) if i in rows)
        out.append((model._MODULES[mode], modes[mode], int(list(model._ROWS[mode]).index(i))))
    return out


class _Negated:
    """``-lik``, for the finite differences (of a :class:`_Likelihood`, its
    points evaluated together: :meth:`_Likelihood.many`)."""

    def __init__(self, lik):
        self.lik = lik

    def __call__(self, v) -> float:
        return -self.lik(v)

    def many(self, vs) -> list[float]:
        return [-value for value in _many(self.lik, vs)]


def _many(f, points: list) -> list[float]:
    """``[f(p) for p in points]``, by ``f.many`` where ``f`` has it (the same numbers, together)."""
    together = getattr(f, "many", None)
    return list(together(points)) if together is not None else [f(p) for p in points]


def _unit(p: int, i: int, h: float) -> np.ndarray:
    e = np.zeros(p)
    e[i] = h
    return e


def _hessian(f, z: np.ndarray, h: np.ndarray, f0: float) -> tuple[np.ndarray, np.ndarray]:
    """The gradient and Hessian of ``f`` at ``z`` by central differences of
    steps ``h`` (every point of the differences evaluated together: :func:`_many`)."""
    p = len(z)
    g = np.zeros(p)
    H = np.zeros((p, p))
    pairs = [(i, j) for i in range(p) for j in range(i + 1, p)]
    points = [z + sign * _unit(p, i, h[i]) for i in range(p) for sign in (1.0, -1.0)]
    for i, j in pairs:
        ei, ej = _unit(p, i, h[i]), _unit(p, j, h[j])
        points += [z + ei + ej, z + ei - ej, z - ei + ej, z - ei - ej]
    values = _many(f, points)
    plus, minus = np.array(values[0:2 * p:2]), np.array(values[1:2 * p:2])
    for i in range(p):
        g[i] = (plus[i] - minus[i]) / (2 * h[i])
        H[i, i] = (plus[i] - 2 * f0 + minus[i]) / h[i] ** 2
    for k, (i, j) in enumerate(pairs):
        a, b, c, d = values[2 * p + 4 * k:2 * p + 4 * k + 4]
        H[i, j] = H[j, i] = (a - b - c + d) / (4 * h[i] * h[j])
    return g, H


def _gradient(f, z: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The gradient of ``f`` at ``z`` by central differences of steps ``h``
    (the points evaluated together: :func:`_many`)."""
    p = len(z)
    values = _many(f, [z + sign * _unit(p, i, h[i]) for i in range(p) for sign in (1.0, -1.0)])
    g = np.zeros(p)
    for i in range(p):
        g[i] = (values[2 * i] - values[2 * i + 1]) / (2 * h[i])
    return g


def _steps(z: np.ndarray) -> np.ndarray:
    """Finite-difference steps: 1e-4 in a logarithm, 1e-4 x max(1, |z|) in a value."""
    return 1e-4 * np.maximum(1.0, np.abs(z))


def _fit(lik: _Likelihood, z0: np.ndarray, stop=None) -> tuple[np.ndarray, float, np.ndarray, bool, str]:
    """The maximum of ``lik`` from ``z0``: (z, log-likelihood, Hessian of the
    negative log-likelihood there, converged, the optimiser's message).

    L-BFGS-B's first step is the whole gradient: the objective is scaled so
    that its gradient at the start has the length ``FIRST_STEP`` (a model far
    off the data has a steep likelihood, and a first step of several units of
    a logarithm leaves the region where the filter's likelihood is finite).
    Where the optimiser stops short of a maximum (the Hessian not positive
    definite, a gradient not small), it is started again from there, up to
    ``RESTARTS`` times, unless ``stop(z)`` says the caller takes it from
    there (a level that heads for 0)."""
    from scipy.optimize import minimize

    if len(z0) == 0:
        return z0, lik(z0), np.zeros((0, 0)), True, "nothing to estimate"
    neg = _Negated(lik)  # the negative log-likelihood, for the differences
    bounds = [(v - REACH, v + REACH) for v in z0]
    z = z0
    for _ in range(RESTARTS + 1):
        g = _gradient(neg, z, _steps(z))
        scale = max(float(np.linalg.norm(g)) / FIRST_STEP, 1e-300) if np.all(np.isfinite(g)) else 1.0
        high = abs(lik(z)) / scale + 1e6  # what a non-finite likelihood costs: above any value seen from here

        def scaled(value, scale=scale, high=high):  # a log-likelihood as the optimiser's objective
            return -value / scale if math.isfinite(value) else high

        def objective(v, scaled=scaled):
            return scaled(lik(v))

        def enough(intermediate_result):  # the caller takes it from there (SciPy >= 1.11 stops on StopIteration)
            if stop is not None and stop(intermediate_result.x):
                raise StopIteration

        options = {"maxiter": 1000, "ftol": 1e-12, "gtol": 1e-9, "maxfun": 20000}
        if getattr(lik, "many", None) is not None:  # the value and its forward differences evaluated together
            # SciPy counts each difference point against maxfun when it takes the differences itself, one
            # evaluation per call here: the same limit is maxfun // (n + 1) calls (k (n + 1) > maxfun iff
            # k > maxfun // (n + 1))
            together = dict(options, maxfun=options["maxfun"] // (len(z) + 1))
            res = minimize(_with_differences(lik, scaled, bounds), z, jac=True, method="L-BFGS-B",
                           bounds=bounds, callback=enough, options=together)
        else:
            res = minimize(objective, z, method="L-BFGS-B", bounds=bounds, callback=enough, options=options)
        z, best = np.asarray(res.x, dtype=float), lik(np.asarray(res.x, dtype=float))
        g, H = _hessian(neg, z, _steps(z), -best)
        for _ in range(3):  # Newton steps (the Hessian kept): the optimiser stops on a relative change
            try:
                step = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                break
            if not np.all(np.isfinite(step)) or np.max(np.abs(step)) > 1.0 or np.any(np.linalg.eigvalsh(H) <= 0):
                break
            trial = z + step
            value = lik(trial)
            if not (math.isfinite(value) and value >= best):
                break
            z, best = trial, value
            if np.max(np.abs(step)) < 1e-10:
                break
            g = _gradient(neg, z, _steps(z))
        inside = np.array([lo + 1e-7 < v < hi - 1e-7 for v, (lo, hi) in zip(z, bounds)])
        if _at_maximum(g[inside], H[np.ix_(inside, inside)]):
            # a maximum by its own test, whatever the optimiser's flag (a likelihood through a model's switches
            # is not smooth at the finite differences' scale, and L-BFGS-B's line search can end "abnormally"
            # on it at a maximum)
            said = str(res.message)
            return z, best, H, True, said if res.success else (
                f"{said}; at a maximum by the gradient and the Hessian (a Newton step under 0.01)")
        if stop is not None and stop(z):
            return z, best, H, bool(res.success), str(res.message)
    return z, best, H, False, f"no maximum reached after {RESTARTS + 1} starts ({res.message})"


#: L-BFGS-B's finite-difference step (SciPy's ``eps`` default), which :func:`_with_differences` takes.
_LBFGSB_STEP = 1e-8


def _with_differences(lik: _Likelihood, objective, bounds: list):
    """The objective of :func:`_fit`'s L-BFGS-B (``objective`` of the
    likelihood's value: -lik scaled, a fixed high value where it is not
    finite) with its gradient: the forward
    differences L-BFGS-B takes without a gradient (SciPy's
    ``approx_derivative``, its step and bounds), the point and the
    difference points evaluated together (:meth:`_Likelihood.many`) instead
    of the point first and then each difference point; the same numbers."""
    from scipy.optimize._numdiff import approx_derivative

    lower, upper = np.array([b[0] for b in bounds]), np.array([b[1] for b in bounds])

    def both(v: np.ndarray) -> tuple[float, np.ndarray]:
        v = np.asarray(v, dtype=float)
        points: list = []
        approx_derivative(lambda x: points.append(np.array(x, dtype=float)) or 0.0, v, method="2-point",
                          abs_step=_LBFGSB_STEP, bounds=(lower, upper), f0=0.0)
        values = iter(lik.many([v] + points))
        f0 = objective(next(values))
        g = approx_derivative(lambda x: objective(next(values)), v, method="2-point", abs_step=_LBFGSB_STEP,
                              bounds=(lower, upper), f0=f0)
        return f0, np.asarray(g, dtype=float)

    return both


def _at_maximum(g: np.ndarray, H: np.ndarray) -> bool:
    """Whether the negative log-likelihood's gradient ``g`` and Hessian ``H``
    (over the coordinates not at an end of their range) say a minimum: no
    direction of negative curvature beyond rounding, and a Newton step
    (where the curvature is positive) under 0.01 of a unit of the
    coordinates."""
    if len(g) == 0:
        return True
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
        return False
    w, V = np.linalg.eigh(H)
    top = max(float(np.max(np.abs(w))), 1e-300)
    if np.any(w < -1e-6 * top):
        return False
    along = V.T @ g
    curved = w > FLAT_STEP * top  # along a nearly flat direction the step says nothing (that estimate is vague)
    return bool(np.all(np.abs(along[curved] / w[curved]) < 1e-2))


def _unidentifiable(names: Sequence[str], H: np.ndarray, logs: Sequence[bool]) -> dict[str, str]:
    """The estimates to hold at the model's values before the others are
    estimated again, each with why. Of a flat or negative direction of the
    Hessian ``H`` (the flattest), or of estimates correlated above
    ``MAX_CORRELATION`` (parameters that enter only as a product), one alone:
    the one most in that direction (of the correlated ones, the one in the
    most such pairs), the later listed on a tie; the others of the direction
    or the pairs are then estimated with it held, which tells their
    combination, and they carry its error (holding them all would leave the
    combination at the model's value, a model that still does not fit the
    plant). Every estimate whose interval spans more than a factor
    ``MAX_SPAN`` (a coordinate in ``logs``; a flat likelihood of its own)."""
    why: dict[str, str] = {}
    p = len(names)
    if p == 0:
        return why

    def last_largest(values: np.ndarray) -> int:  # the later index on a tie (to 1e-9)
        top = float(np.max(values))
        return int(np.flatnonzero(values >= top - 1e-9 * max(abs(top), 1.0))[-1])

    w, V = np.linalg.eigh(H)
    top = max(float(np.max(np.abs(w))), 1e-300)
    if w[0] <= FLAT * top:
        along = np.abs(V[:, 0])
        i = last_largest(along)
        others = [names[j] for j in np.flatnonzero(along > 0.2) if j != i]
        return {names[i]: "the likelihood is flat along it" + (
            f" and {', '.join(others)} together ({', '.join(others)} estimated with it held, carrying its "
            "error)" if others else "")}
    cov = np.linalg.inv(H)
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    tied = (np.abs(corr) > MAX_CORRELATION) & ~np.eye(p, dtype=bool)
    if tied.any():
        i = last_largest(tied.sum(axis=1).astype(float))
        others = [names[j] for j in np.flatnonzero(tied[i])]
        j = int(np.flatnonzero(tied[i])[np.argmax(np.abs(corr[i, tied[i]]))])
        return {names[i]: f"correlated {corr[i, j]:+.3f} with {names[j]}: the data tell only a combination "
                          f"({', '.join(others)} estimated with it held, carrying its error)"}
    for i in range(p):
        if logs[i] and 2 * Z95 * sd[i] > math.log(MAX_SPAN):
            span = 2 * Z95 * sd[i]
            why[names[i]] = ("the likelihood is nearly flat: its 95 % interval spans a factor of "
                             + (f"{math.exp(span):.3g}" if span < 690 else "more than 1e300"))
    return why


def calibrate(model: FaultModel, numerics: Numerics, records: Sequence[Record], sensors: Sequence[str],
              process: bool, parameters: Sequence[str], initial: bool = False,
              modes: Sequence[Numerics] = ()) -> Calibration:
    """:func:`calibrated`'s calibration alone."""
    return calibrated(model, numerics, records, sensors, process, parameters, initial, modes)[0]


@dataclass(frozen=True, slots=True)
class ModesRead:
    """The modes of a recording without a mode column, read from its
    measurements (:func:`calibrate_hidden`): its name, the switches read by
    the calibrated model (time, from, to: the modes' numbers), the rounds of
    reading and calibrating, and the samples whose mode the calibrated
    model reads otherwise than the model the last calibration ran on."""

    source: str
    switches: tuple[tuple[float, int, int], ...]
    rounds: int
    moved: int


#: The most rounds of reading the modes and calibrating on them (:func:`calibrate_hidden`).
ROUNDS = 3


def _switches(model: FaultModel, record: Record) -> tuple[tuple[float, int, int], ...]:
    """The changes of a record's mode input: (time, from, to)."""
    modes = record.us[:, model.MODE_INPUT]
    ts = record.ts if record.ts is not None else (np.arange(len(modes)) + 1) * float(model.DT)
    return tuple((float(ts[k]), int(modes[k - 1]), int(modes[k])) for k in range(1, len(modes))
                 if modes[k] != modes[k - 1])


def calibrate_hidden(read_modes, model: FaultModel, numerics: Numerics, records: Sequence[Record],
                     sensors: Sequence[str], process: bool, parameters: Sequence[str], initial: bool = False,
                     modes: Sequence[Numerics] = (), say=lambda text: None) -> tuple[Calibration, tuple[ModesRead, ...]]:
    """:func:`calibrate` on records of a model with modes some of which have
    no mode column (their mode input NaN; a controlled transition, which
    only the data can say, is refused by the caller). Their modes are read
    from the measurements by the model at its file's values
    (``read_modes(model, record)``: the record with its mode input filled;
    the diagnosis's reader, :func:`bgc.api.calibrate.read_modes`), the model
    is calibrated on that reading, and the calibrated model (from the
    initial state it estimates, when asked) reads them again: the estimates
    with the modes held, then the modes with the estimates held (a
    hard-decision expectation-maximisation). The rounds stop when the new
    reading is the one the calibration ran on, every sample's mode the same
    (a switch moved by a single sample moves the estimates: on the level
    plant, R_out 1.6412 from the model file's reading, 1.6492 from the
    calibrated model's, the latter the estimate with the plant's own modes),
    else after :data:`ROUNDS` calibrations; a later round whose optimiser
    fails (a :class:`~bgc.errors.CalibrationError`) keeps the round before.
    (A round whose optimiser ends without its convergence test, as it does
    on a model with modes, whose likelihood moves in steps where a switch
    moves within its sample period, stands: with the plant's own modes the
    same calibration ends so too, at the same estimate.) Returns the calibration and, per
    record read, its reading by the calibrated model."""
    hidden = [bool(np.isnan(r.us[:, model.MODE_INPUT]).any()) for r in records]
    read = [read_modes(model, r) if h else r for r, h in zip(records, hidden)]
    result, rounds = None, 0
    while True:
        rounds += 1
        say(f"calibrating on the modes read from the data, round {rounds}: "
            + ", ".join(f"{len(_switches(model, r))} switch(es)" for r, h in zip(read, hidden) if h))
        try:
            now, current, starts = calibrated(model, numerics, read, sensors, process, parameters, initial, modes)
        except CalibrationError:
            if result is None:
                raise
            rounds -= 1  # the round before stands
            break
        result, used = now, read
        again = []
        for r, h, x0 in zip(records, hidden, starts):
            if h:
                current.X0 = x0  # the calibrated model from where it estimates this recording starts
            again.append(read_modes(current, r) if h else r)
        moved = [int(np.sum(a.us[:, model.MODE_INPUT] != b.us[:, model.MODE_INPUT])) for a, b in zip(again, used)]
        read = again
        if not any(moved) or rounds == ROUNDS:
            break
    told = tuple(ModesRead(r.source, _switches(model, a), rounds, m)
                 for r, a, m, h in zip(records, again, moved, hidden) if h)
    return result, told


def calibrated(model: FaultModel, numerics: Numerics, records: Sequence[Record], sensors: Sequence[str],
               process: bool, parameters: Sequence[str], initial: bool = False,
               modes: Sequence[Numerics] = ()) -> tuple[Calibration, FaultModel, list[np.ndarray]]:
    """Maximum-likelihood estimates of the noise of ``sensors``, of the
    process level (``process``) and of ``parameters`` of the nominal model
    ``model`` (its generated module; ``numerics``: its compiled numbers) from
    the ``records``, with their 95 % intervals (see the module docstring);
    with ``initial``, each record's initial physical state too (estimates
    ``initial STATE``, or ``initial STATE of SOURCE`` over several records).
    A model with modes gives each mode's numerics (``modes``, in the model's
    order; ``numerics`` is then the first mode's) and records whose inputs
    end with the mode's number (the data's mode column): its filter follows
    the data's mode, and a state's process noise is that of the first mode
    it is a state of, at each level tried.

    Raises
    ------
    CalibrationError
        No record, or the likelihood is not finite at the model's values.
    """
    start_time = time.perf_counter()
    if not records:
        raise CalibrationError("no data to calibrate on", None, "give at least one healthy recording")
    outputs = list(model.OUTPUTS)
    read = {s for r in records for j, s in enumerate(outputs) if np.isfinite(r.ys[:, j]).any()}
    silent = tuple(s for s in sensors if s not in read)
    asked = [s for s in sensors if s in read]
    held: dict[str, str] = {f"noise {s}": "no sample of it in the data" for s in silent}
    settings = numerics.equations.model.settings
    y_scale = np.asarray(numerics.y_scale, dtype=float)
    zero = False  # the process level's likelihood is highest at 0: held there
    start_loglik = _Likelihood(model, numerics, records, [], False, [], modes=modes)(np.zeros(0))  # model's values
    evaluations = 1
    states = [i for i, k in enumerate(getattr(model, "STATE_KINDS", ("physical",) * len(model.STATES)))
              if k == "physical"] if initial else []
    starts = {(r, i): (f"initial {model.STATES[i]}" + (f" of {records[r].source}" if len(records) > 1 else ""))
              for r in range(len(records)) for i in states}
    while True:
        free_params = [p for p in parameters if p not in held]
        free_sensors = [s for s in asked if f"noise {s}" not in held]
        free_process = process and "process noise" not in held and not zero
        free_starts = [pair for pair, name in starts.items() if name not in held]
        lik = _Likelihood(model, numerics, records, free_sensors, free_process, free_params, 0.0 if zero else None,
                          free_starts, modes)
        z0 = lik.start()
        if not math.isfinite(lik(z0)):
            raise CalibrationError(f"the model's likelihood of the data ({', '.join(map(printable, _sources(records)))})"
                                   " is not finite at its own values", None,
                                   "check that the data are of this model and its units")
        k = len(free_sensors)  # the process level's coordinate

        def heads_for_zero(z, k=k, z0=z0, free=free_process):
            return bool(free and z[k] < z0[k] - ZERO_FALL)

        z, best, H, converged, message = _fit(lik, z0, heads_for_zero)
        evaluations += lik.evaluations
        if heads_for_zero(z):
            zero = True
            continue
        if not converged and message.startswith("no maximum"):
            raise CalibrationError(f"the likelihood of {', '.join(map(printable, _sources(records)))} has no "
                                   f"maximum the optimiser could find ({message})", None,
                                   "estimate fewer quantities (--estimate), or start from closer values in the "
                                   "model file")
        names = [f"noise {s}" for s in free_sensors]
        names += ["process noise"] if lik.process else []
        names += free_params
        logs = [True] * (len(names) - len(free_params)) + [bool(s) for s in lik.signs]
        names += [starts[pair] for pair in free_starts]
        logs += [False] * len(free_starts)
        why = _unidentifiable(names, H, logs)
        if not why:
            break
        held.update(why)
    sigma, level, theta = lik.values(z)
    cov = np.linalg.inv(H) if len(z) else np.zeros((0, 0))
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    before = lik.evaluations
    z_low, z_high = _interval_ends(lik, z, best, cov)
    evaluations += lik.evaluations - before
    with np.errstate(over="ignore"):
        lo, hi = lik.values(z_low), lik.values(z_high)
    estimates = []
    k = 0
    for s in sensors:
        j = outputs.index(s)
        scale = _reading_scale(model, lik, theta, j, y_scale[j])
        start_sigma = float(model.MEASUREMENT_STD[j])
        if f"noise {s}" in held:
            estimates.append(Estimate("measurement_noise", s, start_sigma, math.nan, math.nan,
                                      float(start_sigma / y_scale[j]), math.nan, math.nan, start_sigma,
                                      float(start_sigma / y_scale[j]), False, held[f"noise {s}"]))
            continue
        v, a, b = float(sigma[j]), float(lo[0][j]), float(hi[0][j])
        estimates.append(Estimate("measurement_noise", s, v, a, b, v / scale, a / scale, b / scale, start_sigma,
                                  float(start_sigma / y_scale[j]), at_bound=_at_bound(z[k], z0[k])))
        k += 1
    if process:
        q0 = float(settings.process_noise)
        if zero:
            upper = _zero_upper(model, numerics, records, free_sensors, free_params, z, best, free_starts, modes)
            estimates.append(Estimate("process_noise", "process", 0.0, 0.0, upper, 0.0, 0.0, upper, q0, q0,
                                      at_bound=True))
        elif "process noise" in held:
            estimates.append(Estimate("process_noise", "process", q0, math.nan, math.nan, q0, math.nan, math.nan,
                                      q0, q0, False, held["process noise"]))
        else:
            estimates.append(Estimate("process_noise", "process", level, lo[1], hi[1], level, lo[1], hi[1], q0, q0,
                                      at_bound=_at_bound(z[k], z0[k])))
            k += 1
    index = list(model.PARAMETERS)
    for p in parameters:
        i = index.index(p)
        t0 = float(model.THETA[i])
        if p in held:
            estimates.append(Estimate("parameter", p, t0, math.nan, math.nan, t0, math.nan, math.nan, t0, t0, False,
                                      held[p]))
            continue
        v, a, b = float(theta[i]), float(lo[2][i]), float(hi[2][i])
        a, b = min(a, b), max(a, b)
        estimates.append(Estimate("parameter", p, v, a, b, v, a, b, t0, t0, at_bound=_at_bound(z[k], z0[k])))
        k += 1
    estimates += _start_estimates(lik, starts, held, z, z0, z_low, z_high, k)
    corr = cov / np.outer(sd, sd) if len(z) else cov
    filters = lik.filters(z)
    zs = _normalised(filters, len(outputs))
    spread = _spread(lik, z, cov, outputs, zs)
    return (Calibration(tuple(estimates), float(best), float(start_loglik), tuple(names),
                       tuple(tuple(float(c) for c in row) for row in corr), innovations(filters, outputs),
                       _sources(records), sum(int(np.isfinite(r.ys).any(axis=1).sum()) for r in records),
                       converged, message, evaluations, time.perf_counter() - start_time, tuple(outputs),
                       tuple(zs),
                       tuple(np.asarray(r.ts if r.ts is not None else np.arange(len(r.ys)), dtype=float)
                             for r in records), tuple((s, spread[s]) for s in outputs if s in spread)),
            lik.module(z), lik.starts(z))


def _normalised(filters: Sequence[NominalKalman], sensors: int) -> list[np.ndarray]:
    """Per recording, the normalised residuals of its nominal filter (steps x ``sensors``; NaN: not read)."""
    return [np.array(kf.z, dtype=float).reshape(len(kf.z), sensors) for kf in filters]


def _spread(lik: _Likelihood, z: np.ndarray, cov: np.ndarray, outputs: Sequence[str],
            zs: Sequence[np.ndarray]) -> dict[str, float]:
    """Per sensor read, the standard deviation of its normalised residuals'
    variance that the estimates' own uncertainty leaves on a fresh
    recording (the delta method: the variance over the recordings,
    differentiated by central differences in the coordinates of ``z``,
    through ``cov``, the inverse Hessian of the negative log-likelihood).
    A calibration fits one recording's noise too: the calibrated model
    predicts a fresh recording's residual variance as 1, off by this. Every
    estimate the model file keeps: the noise levels, whose errors scale
    every residual alike, and the parameters, whose errors correlated with
    them move the variance the other way too (the noise block alone
    overstates it by up to 1.8 times on the circuit off its model,
    bench/calibration_spread.py); not the recordings' initial states, which
    the model file does not keep (their block of ``cov`` marginalised
    out). No allowance on the residuals' mean: its derivative in a noise
    level is 0 on fresh data, and what a parameter's error moves depends
    on the stretch tested (a transient diluted over a longer one). ``zs``:
    the residuals at ``z`` (:func:`_normalised`), which say the sensors read."""
    k = len(z) - len(lik.initial)
    if not k or not (lik.sensor_rows or lik.process):
        return {}
    read = [j for j in range(len(outputs)) if any(np.isfinite(r[:, j]).sum() >= 3 for r in zs)]

    def variances(point: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            rs = np.concatenate(_normalised(lik.filters(point), len(outputs)))
        return np.array([np.var(rs[np.isfinite(rs[:, j]), j]) for j in read])

    h = _steps(z)
    grads = np.zeros((len(read), k))
    for i in range(k):
        e = np.zeros(len(z))
        e[i] = h[i]
        grads[:, i] = (variances(z + e) - variances(z - e)) / (2 * h[i])
    block = np.asarray(cov, dtype=float)[:k, :k]
    out = {}
    for g, j in zip(grads, read):
        if np.all(np.isfinite(g)):
            out[outputs[j]] = float(np.sqrt(max(float(g @ block @ g), 0.0)))
    return out


def _start_estimates(lik: _Likelihood, starts: dict[tuple[int, int], str], held: dict[str, str], z: np.ndarray,
                     z0: np.ndarray, z_low: np.ndarray, z_high: np.ndarray, k: int) -> list[Estimate]:
    """The estimates of the recordings' initial states ``starts`` ((record,
    state) -> name), the free ones from coordinate ``k`` of ``z`` on (in
    units of each state's size), those ``held`` at the model's ``X0``."""
    out = []
    for (_, i), name in starts.items():
        subject = name.removeprefix("initial ")
        start = float(lik.x0[i])
        if name in held:
            out.append(Estimate("initial", subject, start, math.nan, math.nan, start, math.nan, math.nan, start,
                                start, False, held[name]))
            continue
        size = lik.x_size[i]
        v, a, b = float(z[k] * size), float(z_low[k] * size), float(z_high[k] * size)
        out.append(Estimate("initial", subject, v, a, b, v, a, b, start, start, at_bound=_at_bound(z[k], z0[k])))
        k += 1
    return out


def _interval_ends(lik: _Likelihood, z: np.ndarray, best: float, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ends of each estimate's 95 % interval in the optimiser's
    coordinates: where the log-likelihood has fallen by ``DROP95`` from
    ``best``, walking from the maximum ``z`` along estimate i while the
    others follow their best values to first order (the direction
    ``cov[:, i]``, the path of the profile likelihood of a quadratic
    log-likelihood; Venzon and Moolgavkar 1988 walk the exact profile). On a
    quadratic log-likelihood these are the curvature's ``z +- 1.96 sd``;
    where it is not (a std near 0, whose likelihood is flat below and steep
    above) they follow the likelihood itself. An end the fall does not reach
    within ``REACH`` is infinite (a std's interval then starts at 0)."""
    low, high = z.copy(), z.copy()
    for i in range(len(z)):
        sd = math.sqrt(max(float(cov[i, i]), 0.0))
        if not sd > 0:
            continue
        d = cov[:, i] / sd  # one sd of estimate i, the others at their conditional best (to first order)
        for sign, out in ((-1.0, low), (1.0, high)):
            def fall(t, sign=sign, d=d):
                value = lik(z + sign * t * d)
                return best - value if math.isfinite(value) else math.inf
            out[i] = z[i] + sign * sd * _crossing(fall, REACH / sd)
    return low, high


def _crossing(fall, limit: float) -> float:
    """The t in (0, ``limit``] where ``fall(t)`` (0 at t = 0, rising)
    reaches ``DROP95``, within ``DROP_TOL``; infinite when it stays below up
    to ``limit``. Starts at the curvature's answer ``Z95`` and scales t by
    the square root of the ratio to ``DROP95`` (exact for a parabola); then
    Brent's method in the bracket."""
    from scipy.optimize import brentq

    below, above = 0.0, math.inf
    t = min(Z95, limit)
    for _ in range(4):
        f = fall(t)
        if abs(f / DROP95 - 1) < DROP_TOL:
            return t
        if f < DROP95:
            below = t
            if t >= limit:
                return math.inf
            t = min(limit, t * min(4.0, max(1.05, math.sqrt(DROP95 / max(f, 1e-12)))))
        else:
            above = t
            t = t * min(0.95, max(0.25, math.sqrt(DROP95 / f))) if math.isfinite(f) else 0.5 * (below + t)
        if math.isfinite(above):  # keep within the bracket
            t = min(max(t, below + 0.1 * (above - below)), above - 0.1 * (above - below))
    while not math.isfinite(above):  # still no end above: go on out, doubling
        t = min(limit, 2 * below)
        if fall(t) >= DROP95:
            above = t
        elif t >= limit:
            return math.inf
        else:
            below = t
    g = lambda t: min(fall(t), 1e6) - DROP95  # noqa: E731 - a filter that fails is far beyond the end
    return float(brentq(g, below, above, rtol=1e-6, xtol=1e-6 * above))


def _zero_upper(model: FaultModel, numerics: Numerics, records: Sequence[Record], sensors: Sequence[str],
                parameters: Sequence[str], z: np.ndarray, best: float, initial: Sequence[tuple[int, int]] = (),
                modes: Sequence[Numerics] = ()) -> float:
    """The upper end of the process level's 95 % interval when its
    likelihood is highest at 0 (the other estimates ``z`` held): the level
    where the log-likelihood has fallen by ``ZERO_DROP`` from ``best`` (a
    one-sided bound at the edge of the parameter space, Self and Liang
    1987); NaN when it does not fall that far below ``MAX_SPAN`` times the
    model's level."""
    from scipy.optimize import brentq

    lik = _Likelihood(model, numerics, records, sensors, True, parameters, initial=initial, modes=modes)
    k = len(sensors)
    start = float(lik.start()[k])

    def drop(log_level: float) -> float:
        return lik(np.concatenate([z[:k], [log_level], z[k:]])) - (best - ZERO_DROP)

    low, high = start - 3 * ZERO_FALL, start + math.log(MAX_SPAN)
    if not (drop(low) > 0 > drop(high)):
        return math.nan
    return float(math.exp(brentq(drop, low, high, xtol=1e-6)))


def _state_size(x0: float, scale: float) -> float:
    """The size an initial state is measured in: its model value's magnitude, the compiler's size of the
    state, or 1, whichever is largest but not 0."""
    size = max(abs(float(x0)), abs(float(scale)))
    return size if size > 0 and math.isfinite(size) else 1.0


def _at_bound(z: float, start: float) -> bool:
    """Whether an estimate stopped at the end of the range searched (``REACH`` from its start)."""
    return bool(abs(float(z) - float(start)) >= REACH - 1e-6)


def _sources(records: Sequence[Record]) -> tuple[str, ...]:
    return tuple(r.source for r in records)


def _reading_scale(model: FaultModel, lik: _Likelihood, theta: np.ndarray, j: int, nominal: float) -> float:
    """The size a sensor's relative noise level multiplies at ``theta``: its
    reading at X0 and the inputs at t = 0, as the compiler sets it
    (``nominal``, the compiled one, when the reading there is 0: the
    compiler then sizes it over the nominal run)."""
    x = np.asarray(model.X0, dtype=float)[:, None]
    at_start = float(np.asarray(model.observe(x, lik.u0, tuple(lik.theta0)))[j, 0])
    y = float(np.asarray(model.observe(x, lik.u0, tuple(theta)))[j, 0])
    return abs(y) if at_start != 0 and y != 0 and math.isfinite(y) else nominal
