"""Stage 7: :class:`~bgc.ir.DbnModel` -> :class:`~bgc.ir.Numerics`.

The numbers bgc fixes at compile time for the generated filters.

* **Integration.** The state equations are linearised at the nominal operating
  point (x = X0, u = u(0), theta nominal); with the largest eigenvalue modulus
  ``|lambda|max`` and sample period ``dt``, RK4 takes
  ``SUBSTEPS = ceil(|lambda|max * dt / H_LAMBDA)`` substeps. RK4's stability
  region reaches |h lambda| ~ 2.8 on both axes; ``H_LAMBDA`` of 1.5 keeps a
  margin of almost 2 and a local error of order (h lambda)^5 / 120 < 7 % on the
  fastest mode (which is the most damped one), so a stiff plant gets more
  substeps instead of blowing up silently. That rule bounds the error on the
  fastest mode, not on a slow, lightly damped one that a transient excites (a
  mass on a spring sampled three times a period starts at rest and is pushed
  by a step of force): there the filters' model would drift from the plant by
  several measurement stds, and the detector would alarm on a fault-free run.
  So the substeps are then doubled until the noise-free nominal run's
  outputs move by at most ``ACCURACY`` measurement stds (at the model's
  levels) when the substeps are doubled once more (RK4's error falls 16-fold
  per doubling: the change is 15/16 of the coarser run's error). A plant
  that starts at its equilibrium under constant inputs is not moved by it.
* **Noise.** Levels in the model file are fractions of the signal (thesis
  IV.2). Measurement std of output j: ``r_j * |y_j(X0)|``. Process noise of
  state i: its per-step std ``q_i * s_i * sqrt(min(1, 2 dt / tau_i))``, with
  ``s_i = |X0_i|`` and ``tau_i = 1/|J_ii|`` the state's own time constant
  (the whole horizon when J_ii = 0): a stable state then fluctuates by about
  ``q_i`` of its value, whatever its time constant. A state or output that is
  0 at X0 takes as its size the largest |value| it reaches over the noise-free
  nominal run (over at most ``MAX_NOMINAL_RUN`` samples; 1 only if it stays 0),
  so a plant that starts at rest gets noise in proportion to its signals.
* **Fault priors** come from the fault kind's entry in :mod:`bgc.kinds`:
  abrupt, a bias uniform on [0, 1] x |theta| for an increase, [-0.5, 0] x
  |theta| for a decrease, [-0.5, 1] x |theta| for both; incipient, a slope
  (per unit time) uniform on [0, 4] x |theta| / horizon for an increase,
  [-0.8, 0] x |theta| / horizon for a decrease, [-0.8, 4] x |theta| / horizon
  for both.

Every number is checked finite here: a model whose values overflow (a
parameter of 1e308 with an incipient fault, a process-noise level of 1e308)
is a located error, never an ``inf`` in generated code.
"""

from __future__ import annotations

import math

import numpy as np
import sympy

from ..errors import EquationError
from ..ir import DbnModel, FaultNumerics, Numerics, StateSpaceModel, sym
from ..kinds import element_kind, fault_kind
from .rk4 import rk4_sample

H_LAMBDA = 1.5
#: More RK4 substeps per sample than this is refused: the plant is too stiff for
#: its sample period (the truth simulator takes 8 times as many).
MAX_SUBSTEPS = 200
#: The noise-free nominal run that sizes signals starting at 0 covers at most
#: this many samples (it is a Python loop: a horizon of 1e9 steps must not spin).
MAX_NOMINAL_RUN = 20_000
#: A reading smaller than this fraction of its largest term at the operating point is a
#: cancellation (a net flow at steady state: 0 up to rounding), sized by that term instead.
CANCELLED = 1e-6
#: The filters' RK4 must follow the noise-free nominal run to within this many
#: measurement stds (open loop, at the model's noise levels): a tenth leaves
#: room for data five times less noisy at half a std.
ACCURACY = 0.1


def derive(dbns: DbnModel, prior_scale: float = 1.0) -> Numerics:
    """Eigenvalues, substeps, noise levels and fault priors at the nominal
    operating point; ``prior_scale`` widens every fault's prior by that
    factor (``--prior-scale``).

    Raises
    ------
    EquationError
        The linearisation is not defined at the initial state (a kink of a
        nonlinear law), the plant is too stiff for its sample period, or a
        number overflows.
    """
    ssm = dbns.equations
    model = ssm.model
    settings = model.settings
    xs = [sym(x) for x in ssm.states]
    sub = {sym(p): v for p, v in zip(ssm.parameters, ssm.parameter_values)}
    u0 = tuple(i.signal.at(0.0) for i in model.inputs)
    sub.update({sym(i.name): v for i, v in zip(model.inputs, u0)})
    sub.update({x: v for x, v in zip(xs, ssm.initial)})
    j = _jacobian(ssm, list(ssm.rhs), xs, sub, [f"d{x}/dt" for x in ssm.states], [None] * len(xs))
    if not np.all(np.isfinite(j)):
        raise EquationError(f"model '{model.name}': the linearisation at the initial state is not finite",
                            settings.loc(""), "check the parameter values and the initial values")
    eig = np.linalg.eigvals(j)
    eig = np.array(sorted(eig, key=lambda z: (round(abs(z), 12), round(z.real, 12), round(z.imag, 12))))
    dt = settings.dt
    fastest = float(max(abs(eig))) if len(eig) else 0.0
    if not math.isfinite(fastest * dt):
        raise EquationError(f"model '{model.name}': the fastest mode times the sample period is not finite "
                            f"(|lambda| dt = {fastest * dt:g})", settings.loc("dt"),
                            "check the parameter values and simulation.dt")
    substeps = max(1, math.ceil(fastest * dt / H_LAMBDA - 1e-12))
    if substeps > MAX_SUBSTEPS:
        raise EquationError(
            f"model '{model.name}' is stiff for its sample period: the fastest mode at the initial state has "
            f"|lambda| = {fastest:.3g}, so RK4 would need {substeps} substeps per sample of {dt:g} "
            f"(at most {MAX_SUBSTEPS})", settings.loc("dt"),
            f"set simulation.dt to at most {MAX_SUBSTEPS * H_LAMBDA / fastest:.3g}, or make the fastest "
            "storage element slower")
    y0 = tuple(float(sympy.N(h.xreplace(sub))) for h in ssm.output_exprs)
    horizon = settings.steps * dt
    x_scale = [abs(v) for v in ssm.initial]
    y_scale = [abs(v) for v in y0]
    first = list(_nominal_run(ssm, substeps))  # sizes signals that start at 0, and the accuracy rule's start
    if not all(x_scale) or not all(y_scale):  # a signal that starts at 0: its size over the nominal run
        x_max, y_max = _nominal_magnitudes(ssm, first)
        x_scale = [v or m or 1.0 for v, m in zip(x_scale, x_max)]
        y_scale = [v or m or 1.0 for v, m in zip(y_scale, y_max)]
    # a reading whose terms cancel at the operating point (a tank's net flow at steady state): the size of
    # its largest term, not the rounding left of the cancellation
    terms = [_largest_term(h, sub) for h in ssm.output_exprs]
    y_scale = [t if s < CANCELLED * t else s for s, t in zip(y_scale, terms)]
    sigma = [m.noise * v for m, v in zip(model.measurements, y_scale)]
    substeps = _accurate_substeps(ssm, substeps, sigma, _outputs(ssm, first))
    own_levels = {el.name: el.noise for el in model.elements if element_kind(el.kind).role == "storage"}
    factor = []
    for i in range(len(xs)):
        tau = 1.0 / abs(j[i, i]) if j[i, i] != 0 else horizon
        factor.append(math.sqrt(min(1.0, 2.0 * dt / tau)))
    h = _jacobian(ssm, list(ssm.output_exprs), xs, sub, [f"measurement {m}" for m in ssm.outputs],
                  [m.loc for m in model.measurements])
    faults = []
    candidates = {f.parameter: f for f in model.faults}
    theta = dict(zip(ssm.parameters, ssm.parameter_values))
    for d in dbns.faulty:
        kind = fault_kind(d.kind)
        c = candidates[d.parameter]
        scale = fault_scale(c, theta[d.parameter], model, y_scale, u0)
        prior = kind.prior_bounds(c.direction, scale, horizon, c.rate if kind.drifts else c.size, prior_scale)
        if kind.replaces:  # a value the reading takes: around the nominal reading
            centre = y0[[m.name for m in model.measurements].index(c.subject)]
            prior = (centre + prior[0], centre + prior[1])
        faults.append(FaultNumerics(d.name, d.parameter, d.kind, theta[d.parameter], prior,
                                    kind.jitter_std(scale, prior), scale))
    num = Numerics(dbns, tuple(complex(z) for z in eig), substeps, u0, y0, tuple(float(v) for v in np.diag(j)),
                   tuple(tuple(float(v) for v in row) for row in h), tuple(float(v) for v in x_scale),
                   tuple(float(v) for v in y_scale), tuple(factor), tuple(own_levels.get(el) for el in ssm.state_elements),
                   tuple(faults))
    _check_finite(num)
    return num


def fault_scale(c, nominal: float, model, y_scale, u0) -> float:
    """The size a fault's prior is written in units of: a parameter's
    |nominal|, a sensor's nominal reading (its size over the nominal run when
    it reads 0 at the start), an input's |value at t = 0| (else its largest
    value, else 1), 1 for a factor (a gain, a noise std's multiplier)."""
    if fault_kind(c.kinds[0]).factor:
        return 1.0
    if c.target == "sensor":
        return float(y_scale[[m.name for m in model.measurements].index(c.subject)])
    if c.target == "actuator" and fault_kind(c.kinds[0]).suffix == "offset":
        i = [x.name for x in model.inputs].index(c.subject)
        signal = model.inputs[i].signal
        return abs(u0[i]) or max(abs(signal.value), abs(signal.final or 0.0)) or 1.0
    return abs(nominal) or 1.0


def _largest_term(h, point: dict) -> float:
    """The largest magnitude among the additive terms of the measurement
    expression ``h`` at ``point`` (0 when none is a finite number)."""
    best = 0.0
    for term in sympy.Add.make_args(sympy.expand(h)):
        try:
            v = complex(sympy.N(term.xreplace(point)))
        except (TypeError, ValueError):
            continue
        if v.imag == 0 and math.isfinite(v.real):
            best = max(best, abs(v.real))
    return best


def _check_finite(num: Numerics) -> None:
    """Every number generated code will hold is finite: else a located error
    naming the first one that is not, at the element, measurement, input or
    fault it belongs to."""
    ssm = num.equations
    model = ssm.model
    settings = model.settings
    storage = [model.element(el) for el in ssm.state_elements]
    noise = num.noise
    per_state = [
        ("size", num.x_scale, "give its 'initial' value a smaller magnitude"),
        ("process-noise std", noise.process,
         "use a smaller process-noise level (simulation.process_noise or the element's 'noise')"),
    ]
    for what, values, fix in per_state:
        for el, x, v in zip(storage, ssm.states, values):
            if not math.isfinite(v):
                raise EquationError(f"state {x} of {el.name}: its {what} is {v!r}, not a finite number", el.loc, fix)
    per_output = [
        ("value at the initial state", num.y0, "rescale the parameters or the initial values"),
        ("size", num.y_scale, "rescale the parameters or the measurement expression"),
        ("noise std", noise.measurement, "use a smaller noise level"),
        ("one-step predictive std", noise.predictive, "use smaller noise levels"),
        ("sensitivity to the states", [max((abs(v) for v in row), default=0.0) for row in num.output_jacobian],
         "rescale the parameters or the measurement expression"),
    ]
    for what, values, fix in per_output:
        for m, v in zip(model.measurements, values):
            if not math.isfinite(v):
                raise EquationError(f"measurement {m.name}: its {what} is {v!r}, not a finite number", m.loc, fix)
    for i, v in zip(model.inputs, num.u0):
        if not math.isfinite(v):
            raise EquationError(f"input {i.name} is {v!r} at t = 0", i.loc, "rescale the input")
    horizon = settings.steps * settings.dt
    for f in num.faults:
        c = next(c for c in model.faults if c.parameter == f.parameter)
        magnitude = fault_kind(f.kind).magnitude
        scale = (f"its scale {f.scale:g} / horizon, the horizon being steps x dt = {horizon:g}"
                 if fault_kind(f.kind).drifts else f"its scale {f.scale:g}")
        if not (all(math.isfinite(v) for v in f.prior) and math.isfinite(f.jitter)) or f.prior[0] == f.prior[1]:
            what = {"parameter": f"give {c.name} a nominal value of moderate magnitude",
                    "sensor": f"rescale the model so that {c.name} reads a value of moderate magnitude",
                    "actuator": f"give input {c.name} a value of moderate magnitude"}[c.target]
            raise EquationError(f"fault {f.name}: the prior of its {magnitude} ({f.prior[0]:g} to {f.prior[1]:g}, "
                                f"in units of {scale}) is not a finite, non-empty range", c.loc,
                                what + (" and the run a longer horizon" if fault_kind(f.kind).drifts else ""))


class _NoDerivative(Exception):
    def __init__(self, row: int, column: int):
        self.row, self.column = row, column


def _jacobian(ssm: StateSpaceModel, exprs: list[sympy.Expr], xs: list[sympy.Symbol], point: dict,
              names: list[str], locs: list) -> np.ndarray:
    """:func:`jacobian_at`, with its error located: at ``locs[i]`` of the row,
    else at the element whose own law has the kink."""
    try:
        return jacobian_at(exprs, xs, point)
    except _NoDerivative as k:
        loc = locs[k.row] or _kink(ssm, point) or ssm.model.settings.loc("")
        raise EquationError(
            f"{names[k.row]} has no finite derivative with respect to {xs[k.column]} at the initial state: "
            "the linearisation that sets the integration step and the noise levels is not defined there", loc,
            "start the states where the nonlinear laws are smooth, e.g. away from sqrt(abs(e)) at e = 0") from None


def _kink(ssm: StateSpaceModel, point: dict):
    """Where the element whose law (or modulated value) has no finite
    derivative at the operating point is written, or None."""
    values = dict(point)
    for v, e in ssm.variables:
        try:
            values[sym(v)] = float(e.xreplace(point))
        except (TypeError, ValueError):
            pass
    bond_variables = {sym(v) for v, _ in ssm.variables}
    for el in ssm.model.elements:
        own = [(el.law.expr, el.law.loc)] if el.law is not None else []
        own += [(e, el.loc) for e in (el.parameter, el.source) if e is not None]
        for e, loc in own:
            if not all(s in values for s in e.free_symbols):
                continue
            signals = sorted((s for s in e.free_symbols if s in bond_variables), key=lambda s: s.name)
            try:
                jacobian_at([e], signals, values)
            except _NoDerivative:
                return loc
    return None


def jacobian_at(exprs: list[sympy.Expr], xs: list[sympy.Symbol], point: dict) -> np.ndarray:
    """d exprs / d xs at ``point`` (a float for every free symbol), as a float array.

    The symbols are taken as real while differentiating, so |x| and sign(x)
    have their real derivatives (sign(x), 0 away from 0). An entry that is not a
    finite number there, at the kink of a nonlinear law (sqrt(abs(e)) at e = 0),
    raises ``_NoDerivative``: the linearisation, and with it the integration
    step and the noise levels, is not defined at that initial state.
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
                raise _NoDerivative(i, k)
            out[i, k] = v.real
    return out


#: lambdified(): the last few models' functions, by identity (a simulation per
#: run of a campaign would otherwise lambdify the same equations each time)
_LAMBDIFIED: list[tuple] = []


def lambdified(ssm: StateSpaceModel):
    """(dx/dt, y) of ``ssm`` as NumPy functions of (x, u, theta) lists, by sympy's
    lambdify: an evaluation path independent of bgc's own code generation."""
    for known, f, g in _LAMBDIFIED:
        if known is ssm:
            return f, g
    args = [[sym(x) for x in ssm.states], [sym(u) for u in ssm.inputs], [sym(p) for p in ssm.parameters]]
    f = sympy.lambdify(args, list(ssm.rhs), modules="numpy", cse=True)
    g = sympy.lambdify(args, list(ssm.output_exprs), modules="numpy", cse=True)
    _LAMBDIFIED.insert(0, (ssm, f, g))
    del _LAMBDIFIED[8:]
    return f, g


#: The modules whose objects sympy's lambdify code may read by a global name
#: (its namespace for ``modules="numpy"``: numpy, numpy.linalg, builtins).
TRUTH_MODULES = ("numpy", "numpy.linalg", "builtins")


def truth_source(ssm: StateSpaceModel) -> tuple[str, str, tuple[tuple[str, str, str], ...]] | None:
    """What :func:`lambdified` made, as text: (the source sympy's lambdify
    printed for dx/dt, for y, and each global name that code reads, as
    (name, module, attribute) of :data:`TRUTH_MODULES`, or (name, ``float``
    or ``complex``, the number's repr) for a constant such as lambdify's
    ``I``). Executed in a namespace of exactly those objects
    (:meth:`bgc.view.TruthSource.functions`) it is the same code on
    the same objects, so the same numbers, without sympy. None when the code
    reads an object that is none of those (then the truth needs sympy)."""
    import importlib
    import inspect

    names: dict[str, tuple[str, str, str]] = {}
    sources = []
    for fn in lambdified(ssm):
        sources.append(_numbered(inspect.getsource(fn)))
        for name in _names_read(fn.__code__):
            if name not in fn.__globals__:  # an attribute's name (numpy.exp's exp), or a builtin
                continue
            value = fn.__globals__[name]
            if type(value) in (float, complex):
                names[name] = (name, type(value).__name__, repr(value))
                continue
            found = None
            for module in TRUTH_MODULES:
                m = importlib.import_module(module)
                if value is m:
                    found = (name, module, "")
                elif getattr(m, name, None) is value:
                    found = (name, module, name)
                else:
                    found = next(((name, module, a) for a, v in vars(m).items() if v is value and not a.startswith("_")),
                                 None)
                if found:
                    break
            if found is None:
                return None
            names[name] = found
    return sources[0], sources[1], tuple(sorted(names.values()))


def _numbered(text: str) -> str:
    """lambdify's source with its argument names (``_Dummy_<counter>``, a
    counter of the process) numbered from 0 in order of appearance: the same
    equations always give the same text."""
    import re

    found: dict[str, str] = {}
    return re.sub(r"\b_Dummy_[0-9]+\b", lambda m: found.setdefault(m.group(0), f"_Dummy_{len(found)}"), text)


def _names_read(code) -> set[str]:
    """Every name a code object (and the code nested in it) reads or calls."""
    out = set(code.co_names)
    for const in code.co_consts:
        if hasattr(const, "co_names"):
            out |= _names_read(const)
    return out


def float_safe(ssm: StateSpaceModel) -> bool:
    """Whether the lambdified functions of ``ssm`` give the same numbers on
    Python floats as on NumPy scalars: true when every power has an integer
    exponent (a negative float to a fractional power is complex in Python,
    NaN in NumPy). +, -, *, / and integer powers are the same IEEE operations
    either way, and NumPy functions of a Python float are the same ufuncs; a
    division by zero or an overflow raises on Python floats instead, which
    the caller answers by evaluating on NumPy scalars."""
    return all(p.exp.is_Integer for e in (*ssm.rhs, *ssm.output_exprs) for p in e.atoms(sympy.Pow))


def _nominal_run(ssm: StateSpaceModel, substeps: int):
    """(x, y) at each sample of the noise-free nominal run (RK4 with
    ``substeps`` substeps per sample, the model's inputs held over each
    sample as the filters hold them, at most MAX_NOMINAL_RUN samples of the
    horizon); it stops where the run leaves the finite numbers."""
    model = ssm.model
    f, g = lambdified(ssm)
    theta = list(ssm.parameter_values)
    dt = model.settings.dt
    x = np.array(ssm.initial, dtype=float)
    for k in range(min(model.settings.steps, MAX_NOMINAL_RUN)):
        u = [i.signal.at(k * dt) for i in model.inputs]
        with np.errstate(all="ignore"):
            x = rk4_sample(lambda x, t, t_sub: np.array(f(list(x), u, theta), dtype=float),  # noqa: B023
                           x, k * dt, dt / substeps, substeps)
            if not np.all(np.isfinite(x)):
                return
            y = np.array(g(list(x), u, theta), dtype=float) if ssm.output_exprs else np.zeros(0)
        yield x, y


def _outputs(ssm: StateSpaceModel, run: list) -> np.ndarray:
    """y(t_k) of a run of :func:`_nominal_run`, one row per sample."""
    return np.array([y for _, y in run]).reshape(len(run), len(ssm.output_exprs))


def _accurate_substeps(ssm: StateSpaceModel, substeps: int, sigma: list[float], y: np.ndarray) -> int:
    """``substeps`` doubled until the nominal run's outputs (``y``: at
    ``substeps``) change by at most ``ACCURACY`` x ``sigma`` (each output's
    measurement std; an output with none is not looked at) when they are
    doubled again (up to MAX_SUBSTEPS)."""
    scale = np.array([1.0 / s if s > 0 and math.isfinite(s) else 0.0 for s in sigma])
    if not scale.any():
        return substeps
    while 2 * substeps <= MAX_SUBSTEPS:
        finer = _outputs(ssm, list(_nominal_run(ssm, 2 * substeps)))
        n = min(len(y), len(finer))
        if n == 0:
            break
        with np.errstate(all="ignore"):
            error = np.abs(y[:n] - finer[:n]) * scale * (16.0 / 15.0)
        worst = float(np.max(np.where(np.isfinite(error), error, 0.0)))
        if worst <= ACCURACY:
            break
        substeps, y = 2 * substeps, finer
    return substeps


def nominal_extremes(ssm: StateSpaceModel, substeps: int) -> list[float]:
    """Per measurement, its value of largest magnitude over the noise-free
    nominal run, with its sign (0 where it stays 0)."""
    return [float(v) for v in _output_extremes(ssm, _nominal_run(ssm, substeps))]


def _output_extremes(ssm: StateSpaceModel, run) -> np.ndarray:
    """Per measurement, its value of largest magnitude over ``run`` (pairs
    (x, y) of :func:`_nominal_run`), signed; 0 where it stays 0 or is never
    a finite number."""
    out = np.zeros(len(ssm.output_exprs))
    for _, y in run:
        with np.errstate(invalid="ignore"):
            out = np.where(np.isfinite(y) & (np.abs(y) > np.abs(out)), y, out)
    return out


def _nominal_magnitudes(ssm: StateSpaceModel, run: list) -> tuple[list[float], list[float]]:
    """max |x_i(t)| and max |y_j(t)| over a run of :func:`_nominal_run`; 0
    where a signal stays 0 or the run leaves the finite numbers."""
    x_max = np.abs(np.array(ssm.initial, dtype=float))
    for x, _ in run:
        x_max = np.maximum(x_max, np.abs(x))
    y_max = np.abs(_output_extremes(ssm, run))
    return [float(v) for v in x_max], [float(v) for v in y_max]
