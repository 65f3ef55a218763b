"""Numbers bgc fixes at compile time for the generated filters.

* **Integration.** The state equations are linearised at the nominal operating
  point (x = X0, u = u(0), theta nominal); with the largest eigenvalue modulus
  ``|lambda|max`` and sample period ``dt``, RK4 takes
  ``SUBSTEPS = ceil(|lambda|max * dt / H_LAMBDA)`` substeps. RK4's stability
  region reaches |h lambda| ~ 2.8 on both axes; ``H_LAMBDA = 1.5`` keeps a
  margin of almost 2 and a local error of order (h lambda)^5 / 120 < 7 % on the
  fastest mode (which is the most damped one), so a stiff plant gets more
  substeps instead of blowing up silently.
* **Noise.** Levels in the model file are fractions of the signal (thesis
  IV.2). Measurement std of output j: ``r_j * |y_j(X0)|``. Process noise of
  state i: its per-step std ``q_i * s_i * sqrt(min(1, 2 dt / tau_i))``, with
  ``s_i = |X0_i|`` and ``tau_i = 1/|J_ii|`` the state's own time constant
  (the whole horizon when J_ii = 0): a stable state then fluctuates by about
  ``q_i`` of its value, whatever its time constant. A state or output that is
  0 at X0 takes as its size the largest |value| it reaches over the noise-free
  nominal run (1 only if it stays 0), so a plant that starts at rest gets
  noise in proportion to its signals.
* **Fault priors.** Abrupt: the bias is uniform on [0, 1] x |theta| for an
  increase, [-0.5, 0] x |theta| for a decrease, [-0.5, 1] x |theta| for both.
  Incipient: the slope (per unit time) is uniform on [0, 4] x |theta| / horizon
  for an increase, [-0.8, 0] x |theta| / horizon for a decrease (the parameter
  stays positive over the horizon), [-0.8, 4] x |theta| / horizon for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import sympy

from .errors import EquationError
from .ir import StateSpaceModel, sym

H_LAMBDA = 1.5
#: More RK4 substeps per sample than this is refused: the plant is too stiff for
#: its sample period (the truth simulator takes 8 times as many).
MAX_SUBSTEPS = 200
#: Per-step random-walk std of the fault magnitude state, as a fraction of |theta|
#: (abrupt bias) or of the slope prior's width (incipient slope).
FAULT_JITTER = 0.004
SLOPE_JITTER = 0.01


@dataclass(frozen=True, slots=True)
class Numerics:
    eigenvalues: tuple[complex, ...]
    substeps: int
    u0: tuple[float, ...]
    y0: tuple[float, ...]
    process_std: tuple[float, ...]
    measurement_std: tuple[float, ...]
    jacobian_diag: tuple[float, ...]
    predictive_std: tuple[float, ...]


def input_value(signal, t: float) -> float:
    if signal.kind == "constant" or t < (signal.start or 0.0):
        return signal.value
    if signal.kind == "step":
        return signal.final
    return signal.value + signal.slope * (t - signal.start)


def input_code(signal) -> str:
    """The input signal as Python source in ``t``."""
    v = repr(float(signal.value))
    if signal.kind == "constant":
        return v
    start = repr(float(signal.start or 0.0))
    if signal.kind == "step":
        return f"({v} if t < {start} else {repr(float(signal.final))})"
    return f"({v} if t < {start} else {v} + {repr(float(signal.slope))} * (t - {start}))"


def jacobian_at(exprs: list[sympy.Expr], xs: list[sympy.Symbol], point: dict, names: list[str],
                source: str) -> np.ndarray:
    """d exprs / d xs at ``point`` (a float for every free symbol), as a float array.

    The symbols are taken as real while differentiating, so |x| and sign(x)
    have their real derivatives (sign(x), 0 away from 0). An entry that is not a
    finite number there, at the kink of a nonlinear law (sqrt(abs(e)) at e = 0),
    is a user error: the linearisation, and with it the integration step and
    the noise levels, is not defined at that initial state.
    """
    real = {s: sympy.Dummy(s.name, real=True) for e in exprs for s in e.free_symbols}
    at = {real[s]: v for s, v in point.items() if s in real}
    out = np.zeros((len(exprs), len(xs)))
    for i, e in enumerate(exprs):
        er = e.xreplace(real)
        for k, x in enumerate(xs):
            if x not in e.free_symbols:
                continue
            d = sympy.diff(er, real[x]).xreplace(at)
            try:
                v = complex(sympy.N(d))
            except (TypeError, ValueError):
                v = complex("nan")
            if not (np.isfinite(v) and abs(v.imag) <= 1e-12 * max(1.0, abs(v.real))):
                raise EquationError(
                    f"{names[i]} has no finite derivative with respect to {x} at the initial state: "
                    "the linearisation that sets the integration step and the noise levels is not "
                    "defined there", source,
                    "start the states where the nonlinear laws are smooth, e.g. away from sqrt(abs(e)) at e = 0")
            out[i, k] = v.real
    return out


def numerics(ssm: StateSpaceModel, process_noise: float | None = None,
             measurement_noise: float | None = None) -> Numerics:
    """Eigenvalues, substeps and absolute noise levels at the nominal operating point.

    ``process_noise`` replaces the model's default process-noise level (a
    fraction) and scales the levels storage elements set themselves by the same
    ratio; ``measurement_noise`` replaces every measurement's level.
    """
    model = ssm.model
    xs = [sym(x) for x in ssm.states]
    sub = {sym(p): v for p, v in zip(ssm.parameters, ssm.parameter_values)}
    u0 = tuple(input_value(i.signal, 0.0) for i in model.inputs)
    sub.update({sym(i.name): v for i, v in zip(model.inputs, u0)})
    sub.update({x: v for x, v in zip(xs, ssm.initial)})
    j = jacobian_at(list(ssm.rhs), xs, sub, [f"d{x}/dt" for x in ssm.states], model.source)
    eig = np.linalg.eigvals(j)
    eig = np.array(sorted(eig, key=lambda z: (round(abs(z), 12), round(z.real, 12), round(z.imag, 12))))
    dt = model.settings.dt
    fastest = float(max(abs(eig))) if len(eig) else 0.0
    substeps = max(1, math.ceil(fastest * dt / H_LAMBDA - 1e-12))
    if substeps > MAX_SUBSTEPS:
        raise EquationError(
            f"model '{model.name}' is stiff for its sample period: the fastest mode at the initial state has "
            f"|lambda| = {fastest:.3g}, so RK4 would need {substeps} substeps per sample of {dt:g} "
            f"(at most {MAX_SUBSTEPS})", model.source,
            f"set simulation.dt to at most {MAX_SUBSTEPS * H_LAMBDA / fastest:.3g}, or make the fastest "
            "storage element slower")
    y0 = tuple(float(sympy.N(h.xreplace(sub))) for h in ssm.output_exprs)
    horizon = model.settings.steps * dt
    x_scale = [abs(v) for v in ssm.initial]
    y_scale = [abs(v) for v in y0]
    if not all(x_scale) or not all(y_scale):  # a signal that starts at 0: its size over the nominal run
        x_max, y_max = _nominal_magnitudes(ssm, substeps)
        x_scale = [v or m or 1.0 for v, m in zip(x_scale, x_max)]
        y_scale = [v or m or 1.0 for v, m in zip(y_scale, y_max)]
    storage_noise = {el.name: el.noise for el in model.elements if el.kind in ("C", "I")}
    process = []
    for i, (x, el) in enumerate(zip(ssm.states, ssm.state_elements)):
        q = storage_noise.get(el)
        default = model.settings.process_noise
        if q is None:
            q = default if process_noise is None else process_noise
        elif process_noise is not None:
            q = q * (process_noise / default if default else 1.0)
        s = x_scale[i]
        tau = 1.0 / abs(j[i, i]) if j[i, i] != 0 else horizon
        process.append(q * s * math.sqrt(min(1.0, 2.0 * dt / tau)))
    meas = tuple((m.noise if measurement_noise is None else measurement_noise) * y
                 for m, y in zip(model.measurements, y_scale))
    h = jacobian_at(list(ssm.output_exprs), xs, sub, [f"measurement {m}" for m in ssm.outputs], model.source)
    spread = (h ** 2) @ (np.array(process) ** 2) if len(xs) else np.zeros(len(meas))
    predictive = tuple(float(np.sqrt(m * m + v)) for m, v in zip(meas, spread))
    return Numerics(tuple(complex(z) for z in eig), substeps, u0, y0, tuple(process), meas,
                    tuple(float(v) for v in np.diag(j)), predictive)


def lambdified(ssm: StateSpaceModel):
    """(dx/dt, y) of ``ssm`` as NumPy functions of (x, u, theta) lists, by sympy's
    lambdify: an evaluation path independent of bgc's own code generation."""
    args = [[sym(x) for x in ssm.states], [sym(u) for u in ssm.inputs], [sym(p) for p in ssm.parameters]]
    return (sympy.lambdify(args, list(ssm.rhs), modules="numpy", cse=True),
            sympy.lambdify(args, list(ssm.output_exprs), modules="numpy", cse=True))


def rk4_sample(rhs, x: np.ndarray, t0: float, h: float, substeps: int) -> np.ndarray:
    """x after ``substeps`` classical RK4 steps of length h from t0, one state
    vector; ``rhs(x, t, t_sub)`` is dx/dt at time t within the substep that
    starts at t_sub."""
    for s in range(substeps):
        t = t0 + s * h
        k1 = rhs(x, t, t)
        k2 = rhs(x + 0.5 * h * k1, t + 0.5 * h, t)
        k3 = rhs(x + 0.5 * h * k2, t + 0.5 * h, t)
        k4 = rhs(x + h * k3, t + h, t)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def _nominal_magnitudes(ssm: StateSpaceModel, substeps: int) -> tuple[list[float], list[float]]:
    """max |x_i(t)| and max |y_j(t)| over the noise-free nominal run (RK4 with
    ``substeps`` substeps per sample, the model's inputs and horizon); 0 where
    a signal stays 0 or the run leaves the finite numbers."""
    model = ssm.model
    f, g = lambdified(ssm)
    theta = list(ssm.parameter_values)
    dt = model.settings.dt
    x = np.array(ssm.initial, dtype=float)
    x_max = np.abs(x)
    y_max = np.zeros(len(ssm.output_exprs))
    with np.errstate(all="ignore"):
        for k in range(model.settings.steps):
            u = [input_value(i.signal, k * dt) for i in model.inputs]
            x = rk4_sample(lambda x, t, t_sub: np.array(f(list(x), u, theta), dtype=float),  # noqa: B023
                           x, k * dt, dt / substeps, substeps)
            if not np.all(np.isfinite(x)):
                break
            x_max = np.maximum(x_max, np.abs(x))
            y = np.abs(np.array(g(list(x), u, theta), dtype=float)) if len(y_max) else y_max
            y_max = np.where(np.isfinite(y), np.maximum(y_max, y), y_max)
    return [float(v) for v in x_max], [float(v) for v in y_max]


def fault_prior(kind: str, direction: str, value: float, horizon: float) -> tuple[float, float]:
    a = abs(value) or 1.0
    if kind == "abrupt":
        lo, hi = {"increase": (0.0, 1.0), "decrease": (-0.5, 0.0), "both": (-0.5, 1.0)}[direction]
        return lo * a, hi * a
    # slopes that change the parameter by up to +400 % or -80 % over the horizon
    # (a decreasing parameter stays positive)
    lo, hi = {"increase": (0.0, 4.0), "decrease": (-0.8, 0.0), "both": (-0.8, 4.0)}[direction]
    return lo * a / horizon, hi * a / horizon
