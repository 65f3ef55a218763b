"""The truth simulator of a model with modes: its automaton over each mode's equations.

The plant's state is every variable that is a state in some mode
(:func:`bgc.compiler.modes.states`). In a mode, its own states follow that
mode's equations (sympy's lambdify, RK4 on a step ``TRUTH_REFINEMENT`` times
finer than a filter's, as :mod:`bgc.analysis.simulate`), and a state that is
idle there (an inertia behind an open switch) takes the value the mode's
equations give it (0). After every integration substep the automaton looks at
the transitions out of the current mode, in the model's order, and takes the
first that fires:

- an **autonomous** one when its guard holds on the noise-free state (a
  guard on a measurement reads its noise-free value); a transition with a
  ``tolerance`` compares ``lhs - rhs`` with a value drawn from
  N(0, tolerance^2) on each visit of its source mode (when the mode is
  entered; the first mode at the start), from its own random stream (the
  seed's, apart from the noise's: a model without tolerances draws nothing);
- a **timed** one when the plant has been in the mode for its ``after``;
- a **controlled** one when the schedule (``bgc simulate --modes``) says so
  at a time reached.

A transition applies its resets (from the values just before it), then the
mode entered; a mode entered whose own guard already holds is left at once,
at most as many times in a row as the model has modes (more is a model that
never settles: an error). Process noise is added once per sample to the
states of the mode the sample ends in; the measurements are those of that
mode. Noise levels are the first mode's (a state idle there: the first mode
it is a state of). The run file gets a ``mode`` column: the number of the
mode (1 for the first listed) at each sample's time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..arguments import spelled
from ..errors import SimulationError, printable
from ..ir import StuckSwitch, sym
from ..kinds import releases
from ..data.runs import to_csv as csv_text
from .simulate import (TRUTH_REFINEMENT, SimulationOptions, SimulationResult, columns as simulation_columns,
                       onset_inside)


#: The switches a run file's header lists (the mode column has them all).
SHOWN = 5


@dataclass(frozen=True, slots=True)
class Switch:
    """One change of mode in a simulated run: when, from, to, and why (``autonomous``, ``timed``, ``controlled``)."""

    time: float
    source: str
    target: str
    kind: str


@dataclass(frozen=True, slots=True)
class HybridRun:
    """A simulated run of a model with modes: the run (as :mod:`bgc.analysis.simulate`
    gives it), each sample's mode number (1 for the first mode) and the switches."""

    result: SimulationResult
    modes: np.ndarray
    mode_names: tuple[str, ...]
    switches: tuple[Switch, ...]


def parse_schedule(text: str | None, names: tuple[str, ...]) -> tuple[tuple[float, str], ...]:
    """``MODE@TIME,MODE@TIME,...`` (``--modes``): the controlled changes, sorted by time."""
    if not text:
        return ()
    out = []
    for part in text.split(","):
        mode, at, when = part.strip().partition("@")
        try:
            t = float(when)
        except ValueError:
            t = math.nan
        flag = spelled("modes", "--modes")
        if not at or not math.isfinite(t) or t < 0:
            raise SimulationError(f"{flag} {printable(part.strip())!r} is not MODE@TIME", None,
                                  f"e.g. {spelled('modes=', '--modes ')}closed@12.5,open@30")
        if mode not in names:
            raise SimulationError(f"{flag} {printable(mode)!r} is no mode of the model", None,
                                  f"its modes: {', '.join(names)}")
        out.append((t, mode))
    return tuple(sorted(out))


def schedule_of(run, model) -> tuple[tuple[float, str], ...]:
    """The controlled changes of mode a recorded run's ``mode`` column says
    (``bgc simulate --inputs FILE`` of a model with modes), on the
    simulation's clock as :class:`~bgc.analysis.simulate.InputProfile` puts
    a row (the first row drives the first step, and its time is that step's
    end): each change into a mode by a controlled transition of ``model``,
    at the time of the first row in the mode (a run file's ``mode`` is the
    mode at the row's time, the changes due then made). A change by an autonomous or timed transition is the plant's own:
    the automaton makes it where its guard or its time says; a change no
    transition allows is an error naming the file and the time."""
    names, dt = model.modes.names, model.settings.dt
    kinds = {(t.source, t.target): t.kind for t in model.modes.transitions}
    t = np.asarray(run.time, dtype=float)
    steps = np.rint((t - t[0]) / dt).astype(np.int64)
    out, current = [], names[0]
    for k, number, when in zip(steps, np.asarray(run.modes, dtype=float), t):
        if not math.isfinite(number) or names[int(number) - 1] == current:
            continue
        target = names[int(number) - 1]
        kind = kinds.get((current, target))
        if kind is None:
            raise SimulationError(f"{printable(run.source)}: its mode goes from {current} to {target} at t = "
                                  f"{when:g}, a change no transition of {model.name} allows", None,
                                  "give a mode column the model's transitions can follow")
        if kind == "controlled":
            out.append((float((k + 1) * dt), target))
        current = target
    return tuple(out)


class _Mode:
    """One mode's numerics on the plant's whole state vector."""

    def __init__(self, mode, every: tuple[str, ...]):
        import sympy

        ssm = mode.equations
        self.name, self.every = mode.name, every
        self.active = np.array([every.index(x) for x in ssm.states], dtype=int)
        idle = [x for x in every if x not in ssm.states]
        self.idle = np.array([every.index(x) for x in idle], dtype=int)
        variables = dict(ssm.variables)
        args = [[sym(x) for x in ssm.states], [sym(u) for u in ssm.inputs], [sym(p) for p in ssm.parameters]]
        self.args = args
        self.f = sympy.lambdify(args, list(ssm.rhs), modules="numpy")
        self.g = sympy.lambdify(args, list(ssm.output_exprs), modules="numpy")
        self.rest = sympy.lambdify(args, [variables[x] for x in idle], modules="numpy")
        self.resolve = {sym(v): e for v, e in variables.items()}

    def settle(self, x: np.ndarray, u, theta) -> np.ndarray:
        """x with its idle states set to what this mode's equations give them."""
        if len(self.idle):
            x = x.copy()
            x[self.idle] = np.asarray(self.rest(list(x[self.active]), u, theta), dtype=float)
        return x

    def rhs(self, x: np.ndarray, u, theta) -> np.ndarray:
        dx = np.zeros(len(x))
        dx[self.active] = np.asarray(self.f(list(x[self.active]), u, theta), dtype=float)
        return dx

    def function(self, expr):
        """``expr`` (bond variables, inputs, parameters) as a function of this mode's (x, u, theta)."""
        import sympy

        return sympy.lambdify(self.args, expr.xreplace(self.resolve), modules="numpy")


def simulate(hybrid, numerics: tuple, options: SimulationOptions,
             schedule: tuple[tuple[float, str], ...] = ()) -> HybridRun:
    """Simulate the plant of a model with modes (``hybrid``: a
    :class:`bgc.pipeline.Hybrid`; ``numerics``: each mode's
    :class:`~bgc.ir.Numerics`, in the model's order) from its first mode,
    the controlled changes of ``schedule`` ((time, mode) pairs) included."""
    from ..compiler.modes import states as every_state

    model = hybrid.model
    names = model.modes.names
    fault = options.fault
    if fault is not None and not fault.stuck and (fault.target == "actuator" or fault.kind in ("stuck", "noise")):
        raise SimulationError(f"--fault {fault.text}: a model with modes takes parameter faults, sensor "
                              "biases and drifts, and stuck switches so far", None, "inject one of those")
    configs = _stuck_configurations(hybrid, fault)
    every = every_state(hybrid.modes + configs)
    modes = {m.name: _Mode(m, every) for m in hybrid.modes}
    first = hybrid.modes[0].equations
    steps, dt = options.steps or model.settings.steps, model.settings.dt
    onset_inside(fault, steps, dt)
    substeps = max(n.substeps for n in numerics) * TRUTH_REFINEMENT
    h = dt / substeps
    process, measurement = _noise(hybrid, numerics, every, options)
    theta0 = np.array(first.parameter_values, dtype=float)
    changed = fault is not None and not fault.stuck
    index = first.parameters.index(fault.parameter) if changed and fault.parameter in first.parameters else None
    # a sensor's fault the model does not list has no symbol in its equations: added to the reading here
    read = first.outputs.index(fault.subject) if changed and index is None else None
    signal_of = {i.name: i.signal for i in model.inputs} | dict(options.signals)

    def theta_at(t: float) -> list:
        if index is None:
            return theta0.tolist()
        th = theta0.copy()
        th[index] = fault.value(theta0[index], t)
        return th.tolist()

    initial = {s: v for m in hybrid.modes for s, v in zip(m.equations.states, m.equations.initial)}
    x = modes[names[0]].settle(np.array([initial[s] for s in every], dtype=float),
                               [signal_of[i.name].at(0.0) for i in model.inputs], theta_at(0.0))
    automaton = _Automaton(model, modes, *_transitions(model, modes), list(schedule), theta_at, names[0],
                           np.random.default_rng((options.seed, THRESHOLD_STREAM)))
    if configs:  # from the onset, each mode's configuration with the switch stuck
        after = {m.name: _Mode(c, every) for m, c in zip(hybrid.modes, configs)}
        automaton.stuck = (after, *_transitions(model, after), fault.time)
        if releases(fault.kind):  # an uncommanded change: until a mode asks for the switch so
            switch = StuckSwitch(fault.subject, fault.kind, 0.0, None)
            automaton.release = frozenset(switch.releasing(model.modes.modes))
    rng = np.random.default_rng(options.seed)
    times = dt * np.arange(1, steps + 1)
    out_x, out_y = np.empty((steps, len(every))), np.empty((steps, len(first.outputs)))
    out_u, out_m = np.empty((steps, len(first.inputs))), np.empty(steps, dtype=int)
    recorded = options.inputs.held(tuple(i.name for i in model.inputs), steps, dt) if options.inputs else None
    for k in range(steps):
        u = [signal_of[i.name].at(k * dt) for i in model.inputs]
        if recorded is not None:  # a recorded value where the profile has one
            u = [v if math.isnan(r) else float(r) for v, r in zip(u, recorded[k])]
        for s in range(substeps):
            x = automaton.advance(x, u, k * dt + s * h, h)
        x = automaton.advance(x, u, times[k], 0.0)  # the row holds the state after the changes due at its time
        mode = automaton.modes[automaton.current]
        x[mode.active] += process[mode.active] * rng.standard_normal(len(mode.active))
        x = mode.settle(x, u, theta_at(times[k]))
        if not np.all(np.isfinite(x)):
            raise SimulationError(f"the simulation of {model.name} diverged at t = {times[k]:g}", model.source,
                                  "reduce the fault magnitude or the noise, or check the model's values")
        out_x[k], out_u[k], out_m[k] = x, u, names.index(automaton.current) + 1
        out_y[k] = np.asarray(mode.g(list(x[mode.active]), u, theta_at(times[k])), dtype=float)
        if read is not None:
            out_y[k, read] += fault.value(0.0, times[k])
    param = np.array([fault.value(theta0[index], t) for t in times]) if index is not None else \
        np.array([fault.value(0.0, t) for t in times]) if read is not None else None
    noisy = out_y + measurement * rng.standard_normal(out_y.shape)
    switches = tuple(automaton.switches)
    result = SimulationResult(model.name, model.display_source, times, tuple(first.inputs), out_u,
                              tuple(first.outputs), noisy, out_y, every, out_x, fault, param,
                              _header(model, options, steps, substeps, names, switches))
    return HybridRun(result, out_m, names, switches)


def _stuck_configurations(hybrid, fault) -> tuple:
    """Per mode, the configuration the plant runs in with the switch of
    ``fault`` stuck (:func:`bgc.compiler.modes.compile_stuck`); empty for
    any other fault."""
    if fault is None or not fault.stuck:
        return ()
    from ..compiler.modes import compile_stuck

    switches = hybrid.model.modes.switches
    if fault.subject not in switches:
        raise SimulationError(f"{fault.text}: '{fault.subject}' is no switched junction of {hybrid.model.name}", None,
                              f"its switched junctions: {', '.join(switches)}")

    return compile_stuck(hybrid.model, hybrid.modes, StuckSwitch(fault.subject, fault.kind, 0.0, None)).configs


def _header(model, options: SimulationOptions, steps: int, substeps: int, names: tuple[str, ...],
            switches: tuple[Switch, ...]) -> tuple[str, ...]:
    """The run file's header: the model, the integration, the fault, the noise, the modes and switches."""
    settings, fault = model.settings, options.fault
    process = options.process_noise if options.process_noise is not None else settings.process_noise
    measurement = options.measurement_noise if options.measurement_noise is not None else "per model"
    listed = "".join(f", {w.source} -> {w.target} at {w.time:g} ({w.kind})" for w in switches[:SHOWN])
    return (f"generated by bgc simulate from {model.display_source}",
            f"model {model.name}: {steps} steps of dt = {settings.dt:g}; truth by RK4 with {substeps} substeps per "
            f"step ({TRUTH_REFINEMENT}x finer than the generated filters), each mode's equations",
            "fault: " + (fault.describe() if fault else "none"),
            f"noise: process {process:g}, measurement {measurement} (fractions of the signal, the first mode's "
            f"scales); seed {options.seed}",
            "modes: " + ", ".join(f"{i + 1} {n}" for i, n in enumerate(names)) + f"; {len(switches)} switches"
            + listed + (", ..." if len(switches) > SHOWN else ""),
            *((options.inputs.describe(),) if options.inputs is not None else ()),
            "columns: time; mode: the mode's number at time; u:* inputs; y:* noisy measurements; x:* true states; "
            "theta:* true value of the faulty parameter")


def _noise(hybrid, numerics: tuple, every: tuple[str, ...], options: SimulationOptions):
    """Process stds per state of the plant (each from the first mode it is a
    state of) and measurement stds (the first mode's)."""
    levels = [n.noise_at(options.process_noise, options.measurement_noise) for n in numerics]
    process = np.zeros(len(every))
    for i, s in enumerate(every):
        for mode, level in zip(hybrid.modes, levels):
            if s in mode.equations.states:
                process[i] = level.process[mode.equations.states.index(s)]
                break
    return process, np.array(levels[0].measurement)


def _transitions(model, modes: dict) -> tuple[list, list]:
    """Each transition's guard (lhs - rhs as a function of its source mode's
    (x, u, theta)) or None, and its resets ((state, function) pairs)."""
    guards, resets = [], []
    for t in model.modes.transitions:
        source = modes[t.source]
        guards.append(None if t.guard is None else source.function(t.guard.lhs - t.guard.rhs))
        resets.append([(state, source.function(expr)) for state, expr in t.resets])
    return guards, resets


#: Bisections of a substep to find where a guard starts to hold (2^-50 of a substep).
BISECTIONS = 50
#: The random stream of the thresholds drawn for transitions with a tolerance (with the seed).
THRESHOLD_STREAM = 46


class _Automaton:
    """The plant between two sample times: the current mode, when it was
    entered, the state ``x`` at time ``t`` under inputs ``u``; :meth:`advance`
    integrates over a substep, stopping at each change of mode where it
    happens (a guard's crossing found by bisection of the step, a timed or
    scheduled change at its time) and going on in the mode entered."""

    def __init__(self, model, modes: dict, guards: list, resets: list, pending: list, theta_at, current: str,
                 rng: np.random.Generator):
        self.model, self.modes, self.guards, self.resets = model, modes, guards, resets
        self.pending, self.theta_at = pending, theta_at
        self.switches: list[Switch] = []
        self.current, self.entered = current, 0.0
        self.t, self.x, self.u = 0.0, None, None
        #: each guard's threshold on this visit of its source mode (lhs - rhs is compared with it)
        self.rng, self.offsets = rng, [0.0] * len(model.modes.transitions)
        self._draw(current)
        #: a stuck switch: (each mode's configuration with it, their guards, their resets, the onset), taken
        #: in place of the modes' at the onset
        self.stuck = None
        #: an uncommanded change of a switch: the modes that ask for the switch where the fault puts it,
        #: whose entry ends the fault (the modes' own configurations back); at the onset in one of them,
        #: the fault changes nothing
        self.release: frozenset[str] | None = None
        self.nominal = (modes, guards, resets)

    def _draw(self, mode: str) -> None:
        """The thresholds of the transitions out of ``mode`` with a tolerance, for the visit it starts."""
        for j, tr in enumerate(self.model.modes.transitions):
            if tr.source == mode and tr.tolerance > 0:
                self.offsets[j] = tr.tolerance * float(self.rng.standard_normal())

    def step(self, x: np.ndarray, span: float) -> np.ndarray:
        """One RK4 step of ``span`` in the current mode from ``x`` at ``self.t``."""
        mode, u, th = self.modes[self.current], self.u, self.theta_at(self.t)
        k1 = mode.rhs(x, u, th)
        k2 = mode.rhs(x + 0.5 * span * k1, u, th)
        k3 = mode.rhs(x + 0.5 * span * k2, u, th)
        k4 = mode.rhs(x + span * k3, u, th)
        return mode.settle(x + (span / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4), u, th)

    def holds(self, j: int, x: np.ndarray, t: float) -> bool:
        mode = self.modes[self.current]
        value = float(self.guards[j](list(x[mode.active]), self.u, self.theta_at(t)))
        return self.model.modes.transitions[j].guard.holds(value, self.offsets[j])

    def advance(self, x: np.ndarray, u, t: float, h: float) -> np.ndarray:
        """The state ``x`` at time ``t`` under inputs ``u`` carried over ``h``
        (0: only the changes due at ``t``), through the changes of mode on the way."""
        self.x, self.u, self.t = x, u, t
        if self.stuck is not None and t >= self.stuck[3] - 1e-12:  # the switch sticks: the configurations from now
            if self.release is None or self.current not in self.release:
                self.modes, self.guards, self.resets = self.stuck[:3]
                self.x = self.modes[self.current].settle(self.x, u, self.theta_at(t))
            else:  # an uncommanded change to where the mode has the switch already: no change, no fault
                self.release = None
            self.stuck = None
        remaining, zero = h, 0
        while True:
            fired = self._due(0.0)  # what holds at once (a guard on entering a mode, a time reached)
            if fired is not None:
                zero += 1
                if zero > len(self.modes):
                    raise SimulationError(f"the modes of {self.model.name} switch more than {len(self.modes)} times "
                                          f"at t = {self.t:g}: the guards hold in a cycle", self.model.source,
                                          "leave gaps between the guards' thresholds")
                self._switch(fired)
                continue
            if remaining <= 0.0:
                return self.x
            new = self.step(self.x, remaining)
            fired, span = self._first(new, remaining)
            if fired is None:
                self.x, self.t = new, self.t + remaining
                return self.x
            self.x = self.step(self.x, span) if span > 0.0 else self.x
            self.t += span
            remaining -= span
            self._switch(fired)
            zero = 0

    def _due(self, span: float) -> int | None:
        """The first transition out of the current mode that fires at ``self.t + span`` without integrating."""
        t = self.t + span
        for j, tr in enumerate(self.model.modes.transitions):
            if tr.source != self.current:
                continue
            if tr.kind == "autonomous" and span == 0.0 and self.holds(j, self.x, t):
                return j
            if tr.kind == "timed" and t - self.entered >= tr.after - 1e-9 * max(1.0, tr.after):
                return j
            if tr.kind == "controlled" and self.pending and self.pending[0][0] <= t + 1e-12 \
                    and self.pending[0][1] == tr.target:
                return j
        if self.pending and self.pending[0][0] <= t + 1e-12:
            raise SimulationError(f"{spelled('modes', '--modes')} asks for {self.pending[0][1]} at "
                                  f"{self.pending[0][0]:g}, and the model "
                                  f"has no controlled transition from {self.current} to it", self.model.source,
                                  "schedule only the controlled transitions the model declares")
        return None

    def _first(self, new: np.ndarray, remaining: float) -> tuple[int | None, float]:
        """The first transition that fires within the next ``remaining``
        (``new``: the state at its end) and how far into it: a timed or
        scheduled change at its time, a guard where it starts to hold."""
        best, at = None, remaining
        for j, tr in enumerate(self.model.modes.transitions):
            if tr.source != self.current:
                continue
            if tr.kind == "timed":
                when = self.entered + tr.after - self.t
            elif tr.kind == "controlled":
                when = self.pending[0][0] - self.t if self.pending and self.pending[0][1] == tr.target else math.inf
            else:
                when = self._crossing(j, new, remaining)
            if when < at or (best is None and when <= at):
                best, at = j, max(when, 0.0)
        if best is None and self.pending and self.pending[0][0] - self.t <= remaining:
            return None, remaining  # a schedule the model cannot follow: told when its time is reached (_due)
        return best, at

    def _crossing(self, j: int, new: np.ndarray, remaining: float) -> float:
        """Where in the step guard ``j`` starts to hold (inf: not in it)."""
        if not self.holds(j, new, self.t + remaining):
            return math.inf
        lo, hi = 0.0, remaining
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            if self.holds(j, self.step(self.x, mid), self.t + mid):
                hi = mid
            else:
                lo = mid
        return hi

    def _switch(self, j: int) -> None:
        tr = self.model.modes.transitions[j]
        mode = self.modes[self.current]
        th = self.theta_at(self.t)
        values = [(state, float(fn(list(self.x[mode.active]), self.u, th))) for state, fn in self.resets[j]]
        x = self.x.copy()
        for state, value in values:
            x[mode.every.index(state)] = value
        if tr.kind == "controlled":
            self.pending.pop(0)
        if self.release is not None and self.stuck is None and tr.target in self.release:
            self.modes, self.guards, self.resets = self.nominal  # commanded as the fault put it: over
            self.release = None
        self.x = self.modes[tr.target].settle(x, self.u, th)
        self.switches.append(Switch(self.t, self.current, tr.target, tr.kind))
        self.current, self.entered = tr.target, self.t
        self._draw(tr.target)


def to_csv(run: HybridRun) -> str:
    """The run as CSV: ``time``, ``mode`` (the mode's number), then the columns of :func:`bgc.analysis.simulate.to_csv`."""
    columns = simulation_columns(run.result)
    return csv_text(run.result.header, [columns[0], ("mode", run.modes), *columns[1:]])
