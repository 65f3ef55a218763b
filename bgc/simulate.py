"""Truth simulator: the plant with noise and an injected fault, for testing diagnosers.

It integrates the sympy state equations (``sympy.lambdify`` to NumPy; a path
independent of the generated filter code) with classical RK4 on a step
``TRUTH_REFINEMENT`` times finer than the generated filters use, so a filter is
never handed its own discretisation as the truth.

Fault profiles follow the thesis: abrupt (eq. II.1) ``p(t) = p + b`` for
``t >= t_f``; incipient (eq. II.2) ``p(t) = p + c (t - t_f)`` for ``t > t_f``,
evaluated at every integration substep. Noise (zero-mean Gaussian) has the
absolute levels :mod:`bgc.modelspec` derives from the relative levels (process
noise added once per sample period, measurement noise on every sample).

Time grid: row k (k = 1..steps) holds time ``t_k = k dt``, the input held over
``(t_k-1, t_k]`` (zero-order hold of the signal at ``t_k-1``), the noisy
measurements and true states at ``t_k``, and the true value of the faulty
parameter at ``t_k``.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass

import numpy as np

from . import modelspec
from .errors import SimulationError
from .ir import FAULT_KINDS, StateSpaceModel, sym

TRUTH_REFINEMENT = 8


@dataclass(frozen=True, slots=True)
class FaultInjection:
    """``magnitude``: bias b (abrupt) or slope c per unit time (incipient)."""

    parameter: str
    kind: str
    magnitude: float
    time: float

    def value(self, nominal: float, t: float) -> float:
        if self.kind == "abrupt":
            return nominal + self.magnitude if t >= self.time else nominal
        return nominal + self.magnitude * (t - self.time) if t > self.time else nominal

    def describe(self) -> str:
        what = "bias" if self.kind == "abrupt" else "slope"
        return f"{self.parameter} {self.kind}, {what} {self.magnitude:g} from t = {self.time:g}"


@dataclass(frozen=True, slots=True)
class SimulationOptions:
    steps: int | None = None
    process_noise: float | None = None
    measurement_noise: float | None = None
    seed: int = 0
    fault: FaultInjection | None = None


@dataclass(frozen=True, slots=True)
class SimulationResult:
    model: str
    source: str
    time: np.ndarray
    input_names: tuple[str, ...]
    inputs: np.ndarray
    output_names: tuple[str, ...]
    measurements: np.ndarray
    clean_measurements: np.ndarray
    state_names: tuple[str, ...]
    states: np.ndarray
    fault: FaultInjection | None
    parameter: np.ndarray | None
    header: tuple[str, ...]


_FAULT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):([a-z]+):([-+0-9.eE]+)@([0-9.eE+]+)$")


def parse_fault(text: str, ssm: StateSpaceModel) -> FaultInjection:
    """``PARAM:KIND:MAGNITUDE@TIME``, e.g. ``R_pipe:incipient:0.5@165``."""
    m = _FAULT.match(text.strip())
    if not m:
        raise SimulationError(f"--fault '{text}' is not PARAM:KIND:MAGNITUDE@TIME", None,
                              "e.g. R_pipe:incipient:0.5@165 or R_pipe:abrupt:31@165")
    name, kind, mag, time = m.groups()
    if name not in ssm.parameters:
        raise SimulationError(f"--fault: '{name}' is not a parameter of {ssm.model.name}", None,
                              "parameters: " + ", ".join(ssm.parameters))
    if kind not in FAULT_KINDS:
        raise SimulationError(f"--fault: unknown kind '{kind}'", None, "kinds: " + ", ".join(FAULT_KINDS))
    try:
        injection = FaultInjection(name, kind, float(mag), float(time))
    except ValueError:
        raise SimulationError(f"--fault '{text}': magnitude and time must be numbers", None,
                              "e.g. R_pipe:abrupt:31@165") from None
    if not (math.isfinite(injection.magnitude) and math.isfinite(injection.time)):
        raise SimulationError(f"--fault '{text}': magnitude and time must be finite numbers", None,
                              "e.g. R_pipe:abrupt:31@165")
    return injection


def simulate(ssm: StateSpaceModel, options: SimulationOptions) -> SimulationResult:
    model = ssm.model
    steps = options.steps or model.settings.steps
    dt = model.settings.dt
    num = modelspec.numerics(ssm, options.process_noise, options.measurement_noise)
    substeps = num.substeps * TRUTH_REFINEMENT
    h = dt / substeps
    xs = [sym(x) for x in ssm.states]
    us = [sym(u) for u in ssm.inputs]
    f, g = modelspec.lambdified(ssm)
    theta0 = np.array(ssm.parameter_values, dtype=float)
    fault = options.fault
    index = ssm.parameters.index(fault.parameter) if fault else None

    def theta_at(t: float, interval_start: float | None = None) -> np.ndarray:
        """Parameters at time t. An abrupt change takes effect at the start of an
        integration substep (``interval_start``), so no substep straddles the
        discontinuity; an incipient one is continuous and evaluated at t."""
        if fault is None:
            return theta0
        th = theta0.copy()
        when = interval_start if (fault.kind == "abrupt" and interval_start is not None) else t
        th[index] = fault.value(theta0[index], when)
        return th

    def rhs(x, u, t, t_sub):
        return np.array(f(x, u, theta_at(t, t_sub)), dtype=float)

    rng = np.random.default_rng(options.seed)
    x = np.array(ssm.initial, dtype=float)
    proc = np.array(num.process_std)
    meas = np.array(num.measurement_std)
    T = steps
    states = np.empty((T, len(xs)))
    clean = np.empty((T, len(ssm.outputs)))
    inputs = np.empty((T, len(us)))
    times = dt * np.arange(1, T + 1)
    param = np.empty(T) if fault else None
    for k in range(T):
        t0 = k * dt
        u = np.array([modelspec.input_value(i.signal, t0) for i in model.inputs], dtype=float)
        x = modelspec.rk4_sample(lambda x, t, t_sub: rhs(x, u, t, t_sub), x, t0, h, substeps)  # noqa: B023
        x = x + proc * rng.standard_normal(len(xs))
        if not np.all(np.isfinite(x)):
            raise SimulationError(f"the simulation of {model.name} diverged at t = {times[k]:g}", model.source,
                                  "reduce the fault magnitude or the noise, or check the model's values")
        tk = times[k]
        states[k] = x
        inputs[k] = u
        clean[k] = np.array(g(x, u, theta_at(tk)), dtype=float)
        if fault:
            param[k] = theta_at(tk)[index]
    noisy = clean + meas * rng.standard_normal(clean.shape)
    from .codegen import display_source

    src = display_source(model.source)
    header = (
        f"generated by bgc simulate from {src}",
        f"model {model.name}: {steps} steps of dt = {dt:g}; truth by RK4 with {substeps} substeps per step "
        f"({TRUTH_REFINEMENT}x finer than the generated filters)",
        "fault: " + (fault.describe() if fault else "none"),
        f"noise: process {options.process_noise if options.process_noise is not None else model.settings.process_noise:g}, "
        f"measurement {options.measurement_noise if options.measurement_noise is not None else 'per model'} "
        f"(fractions of the signal); seed {options.seed}",
        "columns: time; u:* inputs held over the step ending at time; y:* noisy measurements; "
        "x:* true states; theta:* true value of the faulty parameter",
    )
    return SimulationResult(model.name, src, times, tuple(ssm.inputs), inputs, tuple(ssm.outputs), noisy, clean,
                            tuple(ssm.states), states, fault, param, header)


def to_csv(r: SimulationResult) -> str:
    buf = io.StringIO()
    for line in r.header:
        buf.write(f"# {line}\n")
    w = csv.writer(buf, lineterminator="\n")
    cols = ["time"] + [f"u:{n}" for n in r.input_names] + [f"y:{n}" for n in r.output_names]
    cols += [f"x:{n}" for n in r.state_names]
    if r.fault:
        cols.append(f"theta:{r.fault.parameter}")
    w.writerow(cols)
    for k in range(len(r.time)):
        row = [r.time[k], *r.inputs[k], *r.measurements[k], *r.states[k]]
        if r.fault:
            row.append(r.parameter[k])
        w.writerow([repr(float(v)) for v in row])
    return buf.getvalue()


@dataclass(frozen=True, slots=True)
class Run:
    """A run read back from CSV: columns by prefix."""

    time: np.ndarray
    inputs: dict[str, np.ndarray]
    measurements: dict[str, np.ndarray]
    states: dict[str, np.ndarray]
    parameters: dict[str, np.ndarray]
    header: tuple[str, ...]


def read_csv(text: str, name: str = "<csv>") -> Run:
    lines = text.splitlines()
    header = tuple(l[2:] for l in lines if l.startswith("# "))
    body = [l for l in lines if not l.startswith("#")]
    if not body:
        raise SimulationError(f"{name}: no data", None, "write it with bgc simulate")
    rows = list(csv.reader(body))
    cols = rows[0]
    try:
        data = np.array([[float(v) for v in r] for r in rows[1:]], dtype=float)
    except ValueError as exc:
        raise SimulationError(f"{name}: not numeric: {exc}", None, "write it with bgc simulate") from None
    if data.ndim != 2 or data.shape[1] != len(cols) or cols[0] != "time":
        raise SimulationError(f"{name}: malformed columns", None, "write it with bgc simulate")
    groups: dict[str, dict[str, np.ndarray]] = {"u": {}, "y": {}, "x": {}, "theta": {}}
    for i, c in enumerate(cols[1:], start=1):
        prefix, _, rest = c.partition(":")
        if prefix in groups:
            groups[prefix][rest] = data[:, i]
    return Run(data[:, 0], groups["u"], groups["y"], groups["x"], groups["theta"], header)
