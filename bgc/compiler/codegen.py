"""Stage 8: :class:`~bgc.ir.DbnModel` and :class:`~bgc.ir.Numerics` ->
:class:`~bgc.ir.GeneratedPackage` (the NumPy package's modules as text).

A pure function: the same DBNs and numbers always give the same bytes. One
module per model (``nominal`` and one per fault model: its DBN's augmented
state, thesis Fig. III.2), the filters (a fixed Python file), the kernel and
``__init__``. Math goes through one strict printer (:mod:`bgc.compiler.printing`),
numbers through :func:`~bgc.compiler.printing.print_number` (finite, shortest
repr), and every piece of model text (the file name, the description) through
:func:`~bgc.compiler.printing.escape`: nothing a model file holds can change the
statements of the generated code.

Names inside generated functions: a function binds its own working names
(``_dx``, ``_A``, ``_y``, CSE temporaries ``_c0`` ...) before it unpacks the
model's names, and every name of its own starts with ``_`` (which no model name
may) or is reserved by validation (``x``, ``u``, ``theta``, ``np``), so a
parameter called ``out``, ``linear`` or ``A`` cannot shadow anything.
"""

from __future__ import annotations

import sympy

from ..ir import DbnModel, GeneratedPackage, Numerics, Signal, sym
from ..kinds import fault_kind
from .numerics import ACCURACY, H_LAMBDA
from .printing import cse_block, escape, print_expr, print_number, split_linear

def module_name(dbn_name: str) -> str:
    """Python module (and file stem) of a model: ``'R_pipe:incipient'`` -> ``'R_pipe_incipient'``."""
    return dbn_name.replace(":", "_")


def generate(dbns: DbnModel, num: Numerics) -> GeneratedPackage:
    """The generated NumPy package: one module per model, the filters, the
    kernel and ``__init__``.

    Raises
    ------
    CodegenError
        An expression or a number that NumPy code cannot hold.
    """
    ssm = dbns.equations
    model = ssm.model
    env = _env()
    common = {"source": escape(model.display_source), "model": escape(model.name),
              "description": escape(model.description, newlines=True)}
    files: dict[str, str] = {}
    modules = []
    for d in (dbns.nominal, *dbns.faulty):
        name = module_name(d.name)
        modules.append(name)
        ctx = _model_context(dbns, num, d)
        files[f"{name}.py"] = env.get_template("model.py.j2").render(**common, **ctx)
    files["filters.py"] = env.get_template("filters.py.j2").render(**common)
    files["_kernel.py"] = env.get_template("kernel.py.j2").render(**common)
    files["__init__.py"] = env.get_template("package_init.py.j2").render(**common, modules=modules)
    return GeneratedPackage(num, tuple(sorted(files.items())), tuple(modules))


def _env():
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("bgc", "templates"),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )


def _tuple(items) -> str:
    items = list(items)
    if not items:
        return "()"
    return "(" + ", ".join(items) + ("," if len(items) == 1 else "") + ")"


def _floats(values, what: str, where: str) -> str:
    return "[" + ", ".join(print_number(v, what, where) for v in values) + "]"


def _slice(r: range, n: int) -> str:
    """Index text for rows/columns ``r`` of n: nothing when it is all of them."""
    return "" if (r.start, r.stop) == (0, n) else f"[{r.start}:{r.stop}]"


def input_code(signal: Signal, where: str) -> str:
    """The input signal as Python source in ``t``."""
    v = print_number(signal.value, "an input value", where)
    if signal.kind == "constant":
        return v
    start = print_number(signal.start or 0.0, "an input start", where)
    if signal.kind == "step":
        return f"({v} if t < {start} else {print_number(signal.final, 'an input value', where)})"
    return f"({v} if t < {start} else {v} + {print_number(signal.slope, 'an input slope', where)} * (t - {start}))"


def _unpack(names: list[str], sources: dict[str, str], used: set[str]) -> list[str]:
    """``name = source`` for the names an expression block uses, in ``names`` order."""
    return [f"{n} = {sources[n]}" for n in names if n in used]


def _used(exprs) -> set[str]:
    return {s.name for e in exprs for s in e.free_symbols}


def _model_context(dbns: DbnModel, num: Numerics, d) -> dict:
    """What model.py.j2 lays out for the DBN ``d``: strings only."""
    ssm = dbns.equations
    model = ssm.model
    where = model.source
    noise = num.noise
    states = list(ssm.states)
    kinds = ["physical"] * len(states)
    rhs = list(ssm.rhs)
    proc = list(noise.process)
    x0 = list(ssm.initial)
    x0_std = [2.0 * s for s in proc]
    # Where each name the expressions use comes from, in unpacking order:
    # states and inputs by index, parameters from theta; a fault model then
    # replaces its parameter.
    sources = {x: f"x[{i}]" for i, x in enumerate(states)}
    sources.update({u: f"u[{i}]" for i, u in enumerate(ssm.inputs)})
    sources.update({p: f"theta[{i}]" for i, p in enumerate(ssm.parameters)})
    fault_ctx = None
    if d.parameter is not None:
        p = d.parameter
        kind = fault_kind(d.kind)
        fn = num.fault(d.name)
        delta = f"delta_{p}"
        n_physical = len(states)
        theta_index = ssm.parameters.index(p)
        if kind.drifts:  # P is a state drifting at the slope delta_P
            states += [p, delta]
            kinds += ["parameter", kind.magnitude]
            rhs += [sym(delta), sympy.Integer(0)]
            proc += [0.0, fn.jitter]
            x0 += [fn.nominal, 0.0]
            x0_std += [0.0, 0.0]
            sources[p] = f"x[{n_physical}]"
            note = f"{p}(t+dt) = {p}(t) + {delta} * dt, {delta} persistent"
            value = f"x[{n_physical}]"
        else:  # P + delta_P, the bias persistent
            states.append(delta)
            kinds.append(kind.magnitude)
            rhs.append(sympy.Integer(0))
            proc.append(fn.jitter)
            x0.append(0.0)
            x0_std.append(0.0)
            sources[p] = f"theta[{theta_index}] + x[{n_physical}]"
            note = f"{p} + {delta}, {delta} persistent"
            value = f"theta[{theta_index}] + x[{n_physical}]"
        lo, hi = fn.prior
        fault_ctx = {
            "parameter": p, "kind": d.kind, "note": note,
            "prior_note": f"{kind.magnitude} {delta}{' (per unit time)' if kind.drifts else ''} on [{lo:g}, {hi:g}]",
            "prior_low": print_number(lo, "a prior bound", where), "prior_high": print_number(hi, "a prior bound", where),
            "magnitude_index": len(states) - 1, "n_physical": n_physical,
            "lift": ([f"x[{n_physical}] = THETA[{theta_index}]"] if kind.drifts else []),
            "value": value,
        }
    order = states + list(ssm.inputs) + list(ssm.parameters)
    order = list(dict.fromkeys(order))
    # Arrays: the states, and a fault parameter replaced by a state expression.
    arrays = frozenset(states) | ({d.parameter} if d.parameter is not None else frozenset())
    splits = [split_linear(f, states, arrays) for f in rhs]
    # The matrix product covers the smallest block of rows and columns that
    # holds every nonzero of A; rows outside it are written whole.
    nz = [(i, j) for i, (a, _, _) in enumerate(splits) for j, c in a.items() if c != 0]
    rows = range(min(i for i, _ in nz), max(i for i, _ in nz) + 1) if nz else range(0)
    cols = range(min(j for _, j in nz), max(j for _, j in nz) + 1) if nz else range(0)
    exprs, targets = [], []
    for i, (_, b, r) in enumerate(splits):
        if i in rows:
            if r != 0:
                exprs.append(r)
                targets.append(f"_dx[{i}] += ")
        else:
            exprs.append(r + b)
            targets.append(f"_dx[{i}] = ")
    rhs_lines, rhs_out = cse_block(exprs, arrays=arrays)
    rhs_assign = [t + (e if e != "0" else "0.0") for t, e in zip(targets, rhs_out)]
    a_exprs = [splits[i][0].get(j, sympy.Integer(0)) for i in rows for j in cols]
    b_exprs = [splits[i][1] for i in rows]
    linear_rows = [", ".join(print_expr(splits[i][0].get(j, sympy.Integer(0))) for j in cols) for i in rows]
    linear_b = ", ".join(print_expr(e) for e in b_exprs)
    has_b = any(e != 0 for e in b_exprs)
    out_lines, out_out = cse_block(list(ssm.output_exprs), arrays=arrays)
    title = (f"Nominal model of {model.name}." if d.parameter is None
             else f"Model of {model.name} with an {d.kind} fault of {d.parameter}.")
    eig = [complex(round(z.real, 10), round(z.imag, 10)) for z in num.eigenvalues]
    return {
        "title": escape(title), "name": module_name(d.name),
        "states": states, "inputs": list(ssm.inputs), "outputs": list(ssm.outputs),
        "states_tuple": _tuple(repr(s) for s in states), "state_kinds_tuple": _tuple(repr(k) for k in kinds),
        "inputs_tuple": _tuple(repr(s) for s in ssm.inputs), "outputs_tuple": _tuple(repr(s) for s in ssm.outputs),
        "parameters_tuple": _tuple(repr(s) for s in ssm.parameters),
        "theta_tuple": _tuple(print_number(v, "a parameter value", where) for v in ssm.parameter_values),
        "dt": print_number(model.settings.dt, "simulation.dt", where), "substeps": num.substeps,
        "eigenvalues_tuple": _tuple(f"({print_number(z.real, 'an eigenvalue', where)}, "
                                    f"{print_number(z.imag, 'an eigenvalue', where)})" for z in eig),
        "method_note": (f"RK4, {num.substeps} substep(s) per sample of {model.settings.dt:g}: largest "
                        f"|eigenvalue| of the nominal linearisation {max(abs(z) for z in num.eigenvalues):.4g}, "
                        f"|lambda| h <= {H_LAMBDA:g}; the noise-free nominal run within {ACCURACY:g} measurement "
                        f"std of one twice as fine."),
        "x0": _floats(x0, "an initial value", where), "x0_std": _floats(x0_std, "an initial std", where),
        "process_std": _floats(proc, "a process-noise std", where),
        "measurement_std": _floats(noise.measurement, "a measurement-noise std", where),
        "predictive_std": _floats(noise.predictive, "a predictive std", where),
        "fault": fault_ctx,
        "fault_dict": (repr({"parameter": d.parameter, "kind": d.kind, "magnitude": fault_kind(d.kind).magnitude})
                       if d.parameter else "None"),
        "input_exprs": [input_code(i.signal, where) for i in model.inputs],
        "unpack": _unpack(order, sources, _used(exprs)), "rhs_cse": rhs_lines, "rhs_assign": rhs_assign,
        "linear_rows": linear_rows, "linear_b": linear_b,
        "linear_unpack": _unpack(order, sources, _used(a_exprs + b_exprs)),
        "has_linear": bool(nz), "has_b": has_b, "linear_note": (
            f"rows {rows.start}..{rows.stop - 1}, columns {cols.start}..{cols.stop - 1}" if nz else ""),
        "x_cols": "x" + _slice(cols, len(states)), "dx_rows": "_dx" + _slice(rows, len(states)),
        "unpack_out": _unpack(order, sources, _used(ssm.output_exprs)), "out_cse": out_lines,
        "out_assign": [f"_y[{i}] = {e}" for i, e in enumerate(out_out)],
    }
