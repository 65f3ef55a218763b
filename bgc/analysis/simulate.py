"""Truth simulator: the plant with noise and an injected fault, for testing diagnosers.

It integrates the sympy state equations (``sympy.lambdify`` to NumPy; a path
independent of the generated filter code; from a compiled model's view, the
code lambdify printed, kept by the compile cache: :class:`bgc.view.TruthSource`) with classical RK4 on a step
``TRUTH_REFINEMENT`` times finer than the generated filters use, so a filter is
never handed its own discretisation as the truth.

Fault profiles are the fault kinds' own (:mod:`bgc.kinds`; the thesis's abrupt
``p(t) = p + b`` for ``t >= t_f``, eq. II.1, and incipient ``p(t) = p + c (t -
t_f)`` for ``t > t_f``, eq. II.2), evaluated at every integration substep; a
step change takes effect at the start of a substep, so no substep straddles it. Noise (zero-mean Gaussian) has the
absolute levels of the compiled model's :class:`~bgc.ir.Numerics` from the relative levels (process
noise added once per sample period, measurement noise on every sample).

Time grid: row k (k = 1..steps) holds time ``t_k = k dt``, the input held over
``(t_k-1, t_k]`` (zero-order hold of the signal at ``t_k-1``), the noisy
measurements and true states at ``t_k``, and the true value of the faulty
parameter at ``t_k``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..arguments import spelled
from ..compiler.rk4 import rk4_sample
from ..errors import SimulationError, printable
from ..ir import Numerics, Signal
from ..kinds import FAULT_KINDS, fault_kind, kinds_for, releases, stuck_title
from ..data.runs import to_csv as _csv_text

TRUTH_REFINEMENT = 8
#: Longest simulation: the loop is Python, and the arrays grow with it.
MAX_STEPS = 10_000_000
#: Memory the arrays of one simulation may take.
MAX_BYTES = 2_000_000_000


@dataclass(frozen=True, slots=True)
class FaultInjection:
    """``magnitude``: what the fault kind's ``magnitude`` names (a bias b for
    an abrupt fault, a slope c per unit time for an incipient one).
    ``parameter``: the symbol the fault changes (a model parameter, or
    ``<sensor>_offset``, ``<input>_offset``, ``<input>_gain``: see
    :meth:`bgc.kinds.FaultKind.parameter_of`); ``target`` and ``subject``:
    what it strikes, as the model names it."""

    parameter: str
    kind: str
    magnitude: float
    time: float
    target: str = "parameter"
    subject: str = ""
    #: The text it was read from (:func:`parse_fault`; "" when made otherwise).
    source: str = field(default="", compare=False)
    #: An intermittent fault (``NAME:KIND:MAGNITUDE@ON-OFF,ON-OFF,ON``): the spans (on, off) over
    #: which it is present, the last one's off ``inf`` when it stays; the first on is ``time``.
    #: Empty: present from ``time`` on (a permanent fault).
    spans: tuple[tuple[float, float], ...] = ()

    def present(self, t: float) -> bool:
        """Whether the fault is present at time ``t`` (a step kind's value; a
        drift, never intermittent, from ``time``)."""
        if not self.spans:
            return t >= self.time
        return any(on <= t < off for on, off in self.spans)

    def value(self, nominal: float, t: float) -> float:
        if self.spans and not self.present(t):
            return nominal
        return fault_kind(self.kind).value(nominal, self.magnitude, self.time, t)

    @property
    def stuck(self) -> bool:
        """A switched junction's fault, stuck or uncommanded (a model with modes; no magnitude)."""
        return self.target == "switch"

    @property
    def text(self) -> str:
        """The scenario as ``NAME:KIND:MAGNITUDE@TIME``: the text it was read
        from, else made (NAME as the model names what it strikes)."""
        if self.source:
            return self.source
        if self.stuck:
            return f"{self.subject}:{self.kind}@{self.time!r}"
        when = repr(self.time) if not self.spans else ",".join(
            repr(on) if math.isinf(off) else f"{on!r}-{off!r}" for on, off in self.spans)
        return f"{self.subject or self.parameter}:{self.kind}:{self.magnitude!r}@{when}"

    def describe(self) -> str:
        if self.stuck:
            return f"switch {stuck_title(self.subject, self.kind)} {'at' if releases(self.kind) else 'from'} " \
                f"t = {self.time:g}"
        kind = fault_kind(self.kind)
        size = (f"std {kind.noise_factor(self.magnitude):g} times its own (magnitude {self.magnitude:g})"
                if kind.noise else f"{kind.magnitude} {self.magnitude:g}")
        when = f"from t = {self.time:g}" if not self.spans else "intermittent, present " + ", ".join(
            f"from t = {on:g}" if math.isinf(off) else f"t = {on:g} to {off:g}" for on, off in self.spans)
        return f"{self.target + ' ' if self.target != 'parameter' else ''}{self.subject or self.parameter} " \
               f"{self.kind}, {size} {when}"


@dataclass(frozen=True, slots=True)
class SimulationOptions:
    steps: int | None = None
    process_noise: float | None = None
    measurement_noise: float | None = None
    seed: int = 0
    fault: FaultInjection | None = None
    #: recorded input values that drive the plant instead of the model's signals (None: the signals)
    inputs: "InputProfile | None" = None
    #: signals that drive inputs instead of the model's, by input (``bgc simulate --input``)
    signals: tuple[tuple[str, Signal], ...] = ()


@dataclass(frozen=True, slots=True)
class InputProfile:
    """Recorded inputs (``bgc simulate --inputs FILE``): the rows' ``time``
    (increasing) and per input its column (NaN: not recorded), with the run
    files' convention: a row's value is applied over the step that ends at
    its time, and the first row drives the first step (the profile's clock
    is shifted onto the simulation's, so a logger's dates drive it as well).
    On the model's grid (:meth:`held`) a step no row falls on, and an empty
    cell, hold the last value; before an input's first value, and for an
    input the profile lacks, the model's signal drives the plant; a second
    row on one step is not used; after the last row its value is held."""

    time: np.ndarray
    values: dict
    source: str = "<inputs>"

    def held(self, names: tuple[str, ...], steps: int, dt: float) -> np.ndarray:
        """The recorded value of each input (``names``: the model's order) over
        each of ``steps`` steps of ``dt``: (steps, inputs), NaN where the
        model's signal drives it."""
        out = np.full((steps, len(names)), np.nan)
        t = np.asarray(self.time, dtype=float)
        at = np.rint((t - t[0]) / dt).astype(np.int64)
        first = np.r_[True, at[1:] != at[:-1]] & (at < steps)  # the first row of a step, inside the run
        for i, name in enumerate(names):
            if name not in self.values:
                continue
            column = np.asarray(self.values[name], dtype=float)
            rows = first & np.isfinite(column)
            out[at[rows], i] = column[rows]
            last = np.nan
            for k in range(steps):  # the last value held over the steps without one
                if np.isfinite(out[k, i]):
                    last = out[k, i]
                else:
                    out[k, i] = last
        return out

    def describe(self) -> str:
        return (f"inputs: {', '.join('u:' + n for n in self.values)} recorded in {printable(self.source)} "
                "(the first row drives the first step; held over the steps without a value)")


def input_profile(run, input_names: tuple[str, ...]) -> InputProfile:
    """The inputs of a run read from a file (:func:`bgc.data.runs.read_run`)
    as an :class:`InputProfile`, or an error naming the file: it must have a
    ``u:`` column, each an input of the model."""
    if not run.inputs:
        raise SimulationError(f"{printable(run.source)}: no u:NAME column: an input profile records inputs", None,
                              f"give the columns of the model's inputs ({', '.join('u:' + u for u in input_names)})"
                              if input_names else "this model has no input to drive")
    for name in run.inputs:
        if name not in input_names:
            raise SimulationError(f"{printable(run.source)}: u:{printable(name)} is no input of the model", None,
                                  f"its inputs are {', '.join('u:' + u for u in input_names) or 'none'}")
    return InputProfile(run.time, dict(run.inputs), run.source)


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


def noise_free(num: Numerics, options: SimulationOptions) -> SimulationResult:
    """The run ``options`` asks for, fault and all, without process noise: its
    measurements without sensor noise (``clean_measurements``) are the
    plant's own response, the line a noisy run scatters around."""
    return simulate(num, dataclasses.replace(options, process_noise=0.0))


_FAULT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):([a-z]+):([-+0-9.eE]+)@([0-9.eE+]+)$")
#: An intermittent fault: NAME:KIND:MAGNITUDE@ON-OFF,ON-OFF[,ON] (present over each span, the last
#: one open to the run's end when it has no OFF).
_SPANS = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):([a-z]+):([-+0-9.eE]+)@([0-9.]+-[0-9.]+(?:,[0-9.]+(?:-[0-9.]+)?)*)$")
#: A switched junction stuck from a time on, NAME:stuck_on@TIME or NAME:stuck_off@TIME, or turned so
#: without a command, NAME:uncommanded_on@TIME or NAME:uncommanded_off@TIME (no magnitude).
_STUCK = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):((?:stuck|uncommanded)_(?:on|off))@([0-9.eE+]+)$")


def parse_fault(text: str, num: Numerics, what: str | None = None) -> FaultInjection:
    """``NAME:KIND:MAGNITUDE@TIME``: NAME a parameter (``R_pipe:incipient:0.5@165``),
    a measurement (a sensor fault, ``P_memb:bias:0.3@100``; ``P_memb:stuck:0@100``
    reads 0 from t = 100; ``P_memb:noise:4@100`` has five times its noise from
    t = 100) or an input (an actuator fault, ``u_pump:gain:-0.2@100``). The model need not list the
    fault among its candidates: a plant may fail in ways its model does not
    foresee. ``what`` names the request in messages (default: ``--fault``, or
    ``scenario`` from the Python API: :func:`bgc.arguments.spelled`)."""
    ssm = num.equations
    model = ssm.model
    what = what or spelled("scenario", "--fault")
    stuck = _STUCK.match(text.strip())
    if stuck:
        return _stuck(stuck, text, model, what)
    m = _FAULT.match(text.strip()) or _SPANS.match(text.strip())
    if not m:
        raise SimulationError(f"{what} {text!r} is not NAME:KIND:MAGNITUDE@TIME", None,
                              "e.g. R_pipe:incipient:0.5@165, R_pipe:abrupt:31@165, P_memb:bias:0.3@100, or "
                              "an intermittent R_pipe:abrupt:31@100-140,200-260,300")
    name, kind, mag, time = m.groups()
    spans = _spans(time, text, what) if m.re is _SPANS else ()
    targets = {**{i: "actuator" for i in ssm.inputs}, **{y: "sensor" for y in ssm.outputs},
               **{p.name: "parameter" for p in model.parameters}}
    if name not in targets:
        raise SimulationError(f"{what}: '{name}' is no parameter, measurement or input of {model.name}", None,
                              "parameters: " + ", ".join(p.name for p in model.parameters)
                              + "; measurements: " + ", ".join(ssm.outputs)
                              + ("; inputs: " + ", ".join(ssm.inputs) if ssm.inputs else ""))
    target = targets[name]
    if kind not in FAULT_KINDS or target not in FAULT_KINDS[kind].targets:
        raise SimulationError(f"{what}: {'unknown kind' if kind not in FAULT_KINDS else 'kind'} '{kind}'"
                              f"{'' if kind not in FAULT_KINDS else f' does not apply to {target} {name}'}", None,
                              kinds_for(target))
    if spans and fault_kind(kind).drifts:
        article = "an" if kind[0] in "aeiou" else "a"
        raise SimulationError(f"{what} {text!r}: {article} {kind} fault does not come and go", None,
                              "an intermittent fault is a step: give it a step kind ("
                              + ", ".join(k for k, fk in FAULT_KINDS.items() if target in fk.targets and not fk.drifts)
                              + ")")
    try:
        injection = FaultInjection(fault_kind(kind).parameter_of(name), kind, float(mag),
                                   spans[0][0] if spans else float(time), target, name, text.strip(), spans)
    except ValueError:
        raise SimulationError(f"{what} {text!r}: magnitude and time must be numbers", None,
                              "e.g. R_pipe:abrupt:31@165") from None
    if not (math.isfinite(injection.magnitude) and math.isfinite(injection.time)):
        raise SimulationError(f"{what} {text!r}: magnitude and time must be finite numbers", None,
                              "e.g. R_pipe:abrupt:31@165")
    return injection


def _spans(text: str, whole: str, what: str) -> tuple[tuple[float, float], ...]:
    """The spans (on, off) of an intermittent fault's ``ON-OFF,ON-OFF[,ON]``:
    increasing times, the last span open (off ``inf``) when it has no OFF."""
    times: list[float] = []
    parts = text.split(",")
    for i, part in enumerate(parts):
        pair = part.split("-")
        if len(pair) == 1 and i < len(parts) - 1:
            raise SimulationError(f"{what} {whole!r}: '{part}' is not ON-OFF", None,
                                  "only the last span may have no end: e.g. R_pipe:abrupt:31@100-140,200-260,300")
        try:
            times += [float(v) for v in pair]
        except ValueError:
            raise SimulationError(f"{what} {whole!r}: '{part}' is not ON-OFF with numbers", None,
                                  "e.g. R_pipe:abrupt:31@100-140,200-260,300") from None
    if not all(math.isfinite(v) for v in times) or any(b <= a for a, b in zip(times, times[1:])):
        raise SimulationError(f"{what} {whole!r}: the times of an intermittent fault must increase", None,
                              "each span ON-OFF after the last, e.g. R_pipe:abrupt:31@100-140,200-260,300")
    times += [math.inf] if len(times) % 2 else []
    return tuple(zip(times[::2], times[1::2]))


def _stuck(m, text: str, model, what: str) -> FaultInjection:
    """``J:stuck_on@TIME``, ``J:stuck_off@TIME``, ``J:uncommanded_on@TIME`` or
    ``J:uncommanded_off@TIME``: a switched junction of a model with modes."""
    name, kind, time = m.groups()
    from ..compiler.modes import switches_of

    switches = switches_of(model)  # (a compiled model's view keeps its first mode's elements, not its modes)
    if name not in switches:
        raise SimulationError(f"{what}: '{name}' is no switched junction of {model.name}", None,
                              f"its switched junctions: {', '.join(switches)}" if switches else
                              "stuck_on, stuck_off, uncommanded_on and uncommanded_off are a switched junction's "
                              "faults, in a model with modes")
    try:
        onset = float(time)
    except ValueError:
        onset = math.nan
    if not math.isfinite(onset):
        raise SimulationError(f"{what} {text!r}: the time must be a finite number", None, f"e.g. {name}:{kind}@10")
    return FaultInjection(name, kind, math.nan, onset, "switch", name, text.strip())


def parse_scenario(scenario, num: Numerics, what: str | None = None) -> FaultInjection | None:
    """A scenario as a value, read once at the edge: ``none`` (fault-free:
    None), ``NAME:KIND:MAGNITUDE@TIME`` (:func:`parse_fault`), or a
    :class:`FaultInjection` already read, as it is."""
    if isinstance(scenario, FaultInjection):
        return scenario
    if scenario.strip().lower() == "none":
        return None
    return parse_fault(scenario, num, what)


def change_magnitude(num: Numerics, fault: str, change: float, span: float) -> float:
    """The magnitude of fault model ``fault`` (``PARAM:KIND``) that changes
    what it strikes by ``change`` (signed) times its scale (a parameter's
    |nominal|, a sensor's nominal reading, ...), a drift over ``span`` time
    units after the onset; a stuck reading that far off the sensor's nominal
    reading."""
    f = num.fault(fault)
    kind = fault_kind(f.kind)
    magnitude = kind.magnitude_for(change * f.scale, span)
    if kind.replaces:
        subject = next(c.subject for c in num.equations.model.faults if c.parameter == f.parameter)
        magnitude += num.y0[num.equations.outputs.index(subject)]
    return magnitude


def outside_prior(injection: FaultInjection, num: Numerics, modules: tuple[str, ...] | None = None) -> str | None:
    """Why the model's diagnoser would not expect this fault: not among its
    candidates, or a magnitude outside the candidate's prior; None when it
    would. ``modules``: the generated modules' names (a compiled model's
    view's), which say whether a stuck switch is a candidate (a view's
    model keeps no modes; without either, one is taken as listed)."""
    name = f"{injection.parameter}:{injection.kind}"
    if injection.stuck:
        if modules is not None:
            listed = f"{injection.parameter}_{injection.kind}" in modules
        else:
            modes = getattr(num.equations.model, "modes", None)
            listed = modes is None or modes.stuck_fault(name) is not None
        return None if listed else (f"the model lists no fault {name} among its candidates: its diagnoser should "
                                    "find it unexplained")
    try:
        f = num.fault(name)
    except KeyError:
        return (f"the model lists no fault {injection.subject or injection.parameter}:{injection.kind} "
                f"among its candidates: its diagnoser should find it unexplained")
    lo, hi = f.prior
    if lo <= injection.magnitude <= hi:
        return None
    what = fault_kind(injection.kind).magnitude + (" per unit time" if fault_kind(injection.kind).drifts else "")
    return (f"{what} {injection.magnitude:g} is outside the prior of {name} in the model ({lo:.4g} to {hi:.4g}): "
            "its diagnoser may size it wrong (widen it with the fault's 'size' or 'rate' in the model, "
            f"or {spelled('prior_scale', '--prior-scale')})")


def check_steps(steps: int, num: Numerics, where: str) -> None:
    """Refuse, before any work, a run longer than MAX_STEPS or whose arrays
    would take more than MAX_BYTES."""
    ssm = num.equations
    width = 2 * len(ssm.outputs) + len(ssm.states) + len(ssm.inputs) + 2
    if steps < 1:
        raise SimulationError(f"{where}: {steps} steps", None, f"simulate at least 1 step, e.g. {spelled('steps=300', '--steps 300')}")
    if steps > MAX_STEPS or steps * width * 8 > MAX_BYTES:
        raise SimulationError(f"{where}: {steps} steps is more than bgc simulates in one run "
                              f"(at most {min(MAX_STEPS, MAX_BYTES // (width * 8))} for this model)", None,
                              f"simulate fewer steps, e.g. {spelled('steps=300', '--steps 300')}")


def onset_inside(fault: FaultInjection | None, steps: int, dt: float) -> None:
    """Refuse a fault whose onset is outside a run of ``steps`` samples of ``dt`` (one from the start is
    a plant as it came, not a fault)."""
    if fault is not None and not 0 <= fault.time < steps * dt:
        raise SimulationError(f"{spelled('scenario', '--fault')} {fault.text}: "
                              f"onset {fault.time:g} is outside the run (0 to {steps * dt:g})", None,
                              f"choose an onset inside the run, or more {spelled('steps', '--steps')}")


def simulate(num: Numerics, options: SimulationOptions) -> SimulationResult:
    """Simulate the plant of ``num`` (its equations, at its noise scales)."""
    ssm = num.equations
    model = ssm.model
    steps = options.steps or model.settings.steps
    check_steps(steps, num, spelled("steps", "--steps") if options.steps else f"{model.source}: simulation.steps")
    dt = model.settings.dt
    fault = options.fault
    if fault is not None and fault.stuck:
        raise SimulationError(f"{spelled('scenario', '--fault')} {fault.text}: '{fault.subject}' is no switched "
                              f"junction of {model.name}", None,
                              "stuck_on, stuck_off, uncommanded_on and uncommanded_off are a switched junction's "
                              "faults, in a model with modes")
    onset_inside(fault, steps, dt)
    noise = num.noise_at(options.process_noise, options.measurement_noise)
    substeps = num.substeps * TRUTH_REFINEMENT
    h = dt / substeps
    f, g, floats = truth_functions(ssm)
    theta0 = np.array(ssm.parameter_values, dtype=float)
    target = index = column = nominal = kind = None
    if fault is not None:  # what it changes: a parameter (index), an input or a sensor's reading (column)
        target, kind = fault.target, fault_kind(fault.kind)
        if target == "parameter":
            index = ssm.parameters.index(fault.parameter)
            nominal = theta0[index]
        else:
            column = (ssm.inputs if target == "actuator" else ssm.outputs).index(fault.subject)
            nominal = kind.nominal
    steps_at_substeps = fault is not None and not kind.drifts

    def when(t: float, interval_start: float | None) -> float:
        """A step change takes effect at the start of an integration substep
        (``interval_start``), so no substep straddles the discontinuity; a
        drift is continuous and evaluated at t."""
        return interval_start if (steps_at_substeps and interval_start is not None) else t

    def theta_at(t: float, interval_start: float | None = None) -> np.ndarray:
        """Parameters at time t."""
        if target != "parameter":
            return theta0
        th = theta0.copy()
        th[index] = fault.value(theta0[index], when(t, interval_start))
        return th

    def delivered(u: np.ndarray, t: float, interval_start: float | None = None) -> np.ndarray:
        """What the actuators deliver for the command u: an actuator fault's
        gain times it plus its offset; the command is what the run records."""
        if target != "actuator":
            return u
        v = u.copy()
        level = fault.value(nominal, when(t, interval_start))
        v[column] = level * u[column] if kind.suffix == "gain" else u[column] + level
        return v

    def evaluate(fn, x, u, theta):
        """fn on Python floats when that gives the same numbers (float_safe),
        a few times faster than on NumPy scalars; else, or when Python
        raises (a division by zero, an overflow: NumPy gives inf or NaN and
        the run stops as diverged), on NumPy scalars."""
        if floats:
            try:
                return np.array(fn(x.tolist(), u.tolist(), theta.tolist()), dtype=float)
            except (ZeroDivisionError, OverflowError):
                pass
        return np.array(fn(x, u, theta), dtype=float)

    def rhs(x, u, t, t_sub):
        return evaluate(f, x, delivered(u, t, t_sub), theta_at(t, t_sub))

    theta_list = theta0.tolist()

    def rhs_floats(x: list, u: np.ndarray, ul: list, t: float, t_sub: float) -> list:
        """:func:`rhs` on Python floats (``x``, and ``ul``: ``u`` as a list),
        the parameters and what the actuators deliver made as :func:`theta_at`
        and :func:`delivered` make them (the same operations on the same
        values); raises as ``f`` does."""
        theta = theta_list
        if target == "parameter":
            theta = theta_list.copy()
            theta[index] = float(fault.value(theta0[index], when(t, t_sub)))
        elif target == "actuator":
            ul = ul.copy()
            level = fault.value(nominal, when(t, t_sub))
            ul[column] = float(level * u[column] if kind.suffix == "gain" else u[column] + level)
        return [float(v) for v in f(x, ul, theta)]

    def sample_floats(x: np.ndarray, u: np.ndarray, t0: float) -> np.ndarray | None:
        """:func:`bgc.compiler.rk4.rk4_sample` of :func:`rhs` over one sample
        on Python floats: the same IEEE operations in the same order as its
        NumPy arrays (x + (0.5 h) k1, then x + (h / 6) (((k1 + 2 k2) + 2 k3)
        + k4)), so the same numbers, without NumPy's cost per operation on
        arrays of a few states (measured: the truth of a run 3x faster). None
        when ``f`` raises on Python floats (a division by zero, an overflow):
        the caller takes the sample again the NumPy way, which evaluates that
        substep on NumPy scalars (:func:`evaluate`)."""
        ul = u.tolist()
        xl = x.tolist()
        half, sixth = 0.5 * h, h / 6.0
        try:
            for s in range(substeps):
                t = t0 + s * h
                k1 = rhs_floats(xl, u, ul, t, t)
                k2 = rhs_floats([a + half * b for a, b in zip(xl, k1)], u, ul, t + 0.5 * h, t)
                k3 = rhs_floats([a + half * b for a, b in zip(xl, k2)], u, ul, t + 0.5 * h, t)
                k4 = rhs_floats([a + h * b for a, b in zip(xl, k3)], u, ul, t + h, t)
                xl = [a + sixth * (((b1 + 2.0 * b2) + 2.0 * b3) + b4) for a, b1, b2, b3, b4 in zip(xl, k1, k2, k3, k4)]
        except (ZeroDivisionError, OverflowError):
            return None
        return np.array(xl, dtype=float)

    rng = np.random.default_rng(options.seed)
    x = np.array(ssm.initial, dtype=float)
    proc = np.array(noise.process)
    meas = np.array(noise.measurement)
    T = steps
    states = np.empty((T, len(ssm.states)))
    clean = np.empty((T, len(ssm.outputs)))
    inputs = np.empty((T, len(ssm.inputs)))
    times = dt * np.arange(1, T + 1)
    param = np.empty(T) if fault else None
    recorded = options.inputs.held(tuple(ssm.inputs), T, dt) if options.inputs is not None else None
    signal_of = {i.name: i.signal for i in model.inputs} | dict(options.signals)
    for k in range(T):
        t0 = k * dt
        u = np.array([signal_of[i.name].at(t0) for i in model.inputs], dtype=float)
        if recorded is not None:
            u = np.where(np.isnan(recorded[k]), u, recorded[k])
        stepped = sample_floats(x, u, t0) if floats else None
        if stepped is None:
            stepped = rk4_sample(lambda x, t, t_sub: rhs(x, u, t, t_sub), x, t0, h, substeps)  # noqa: B023
        x = stepped
        x = x + proc * rng.standard_normal(len(ssm.states))
        if not np.all(np.isfinite(x)):
            raise SimulationError(f"the simulation of {model.name} diverged at t = {times[k]:g}", model.source,
                                  "reduce the fault magnitude or the noise, or check the model's values")
        tk = times[k]
        states[k] = x
        inputs[k] = u
        clean[k] = evaluate(g, x, delivered(u, tk), theta_at(tk))
        if fault:
            param[k] = fault.value(nominal, tk)
    if target == "sensor" and not kind.replaces and not kind.noise:  # the sensor's offset on its reading
        clean[:, column] += param
    draws = rng.standard_normal(clean.shape)
    if target == "sensor" and kind.noise:  # a noise burst: the sensor's noise std times its factor
        draws[:, column] *= kind.noise_factor(param - nominal)
    noisy = clean + meas * draws
    if target == "sensor" and kind.replaces:  # a stuck sensor reads its value, noise and all
        stuck = np.array([fault.present(t) for t in times])
        clean[stuck, column] = noisy[stuck, column] = fault.magnitude
    src = model.display_source
    settings = model.settings
    header = (
        f"generated by bgc simulate from {src}",
        f"model {model.name}: {steps} steps of dt = {dt:g}; truth by RK4 with {substeps} substeps per step "
        f"({TRUTH_REFINEMENT}x finer than the generated filters)",
        "fault: " + (fault.describe() if fault else "none"),
        f"noise: process {options.process_noise if options.process_noise is not None else settings.process_noise:g}, "
        f"measurement {options.measurement_noise if options.measurement_noise is not None else 'per model'} "
        f"(fractions of the signal); seed {options.seed}",
        "columns: time; u:* inputs held over the step ending at time; y:* noisy measurements; "
        "x:* true states; theta:* true value of the faulty parameter (a sensor's or input's offset, "
        "an input's gain, a sensor's noise factor)",
    ) + ((options.inputs.describe(),) if options.inputs is not None else ()) + tuple(
        f"input u:{name}: {signal.text} (instead of the model's)" for name, signal in options.signals)
    return SimulationResult(model.name, src, times, tuple(ssm.inputs), inputs, tuple(ssm.outputs), noisy, clean,
                            tuple(ssm.states), states, fault, param, header)


def truth_functions(ssm) -> tuple:
    """(dx/dt, y, whether they give the same numbers on Python floats as on
    NumPy scalars) of the state equations ``ssm``: sympy's lambdify of a
    compilation's :class:`~bgc.ir.StateSpaceModel`, or the same code made
    again from the text a view keeps (:class:`bgc.view.TruthSource`,
    without sympy)."""
    truth = getattr(ssm, "truth", None)
    if truth is not None:
        return (*_made(truth), truth.float_safe)
    from ..compiler.numerics import lambdified

    return (*lambdified(ssm), float_safe(ssm))


@functools.lru_cache(maxsize=8)
def _made(truth) -> tuple:
    return truth.functions()


def float_safe(ssm) -> bool:
    """:func:`bgc.compiler.numerics.float_safe` of a compilation's equations."""
    from ..compiler import numerics

    return numerics.float_safe(ssm)


def to_csv(r: SimulationResult) -> str:
    """The run as the CSV text :func:`bgc.data.runs.read_run` reads."""
    return _csv_text(r.header, columns(r))


def columns(r: SimulationResult) -> list[tuple[str, np.ndarray]]:
    """A run's columns as a run file has them: ``time``, ``u:``, ``y:``, ``x:``, ``theta:``."""
    columns = [("time", r.time)]
    columns += [(f"u:{n}", r.inputs[:, j]) for j, n in enumerate(r.input_names)]
    columns += [(f"y:{n}", r.measurements[:, j]) for j, n in enumerate(r.output_names)]
    columns += [(f"x:{n}", r.states[:, j]) for j, n in enumerate(r.state_names)]
    if r.fault and r.parameter is not None:  # (a stuck switch changes no parameter)
        columns.append((f"theta:{r.fault.parameter}", r.parameter))
    return columns
