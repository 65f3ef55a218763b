"""The strict NumPy printer and deterministic CSE (bgc.printing).

Printed text is checked by running it: evaluated with nothing but ``np`` and the
expression's own symbols in scope, on arrays, against numbers computed without
the printer (numpy directly, or sympy's own evaluation).
"""

import ast
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import sympy
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bgc.errors import CodegenError
from bgc.compiler.printing import cse_block, print_expr

from conftest import ROOT

x, y, z, w = sympy.symbols("x y z w")
RNG = np.random.default_rng(7)
#: Positive sample points (log and sqrt are real there), vectorised like particles.
POINTS = {s: RNG.uniform(0.2, 3.0, 40) for s in ("x", "y", "z", "w")}


def run_printed(text, points=POINTS):
    """Evaluate printed code with only ``np`` and the symbols in scope (no builtins)."""
    return eval(compile(text, "<printed>", "eval"), {"__builtins__": {}, "np": np}, dict(points))


def names_used(text):
    """Top-level names the printed code refers to (module names like ``np`` included)."""
    return {n.id for n in ast.walk(ast.parse(text, mode="eval")) if isinstance(n, ast.Name)}


# ------------------------------------------------------------- refusals
@pytest.mark.parametrize("expr", [
    sympy.Function("foo")(x),
    sympy.Function("valve")(x, y) + 1,
    sympy.Integral(x, (x, 0, 1)),
    sympy.Integral(x * y, (x, 0, z)) * y,
    sympy.Derivative(sympy.Function("f")(x), x),
    sympy.zoo * x,             # sympy's printer raises KeyError for it
    sympy.erf(x),              # sympy prints math.erf: not numpy, not vectorised
    sympy.gamma(x),            # math.gamma
    sympy.Sum(y * z, (z, 1, 3)) + x,  # builtins.sum(...)
    sympy.Lambda(x, x + 1),    # Lambda(x_NNN, ...): an undefined name
], ids=["unknown-function", "unknown-function-in-sum", "integral", "integral-in-product", "derivative", "zoo",
        "erf", "gamma", "Sum", "Lambda"])
def test_strict_printer_refuses_what_it_cannot_print(expr):
    with pytest.raises(CodegenError) as info:
        print_expr(expr)
    message = info.value.line()
    assert "cannot generate NumPy code" in message and "\n" not in message


def test_symbol_that_is_not_an_identifier_is_refused_with_its_own_message():
    with pytest.raises(CodegenError) as info:
        print_expr(sympy.Symbol("a b") + x)
    assert "not a Python identifier" in info.value.line()


@pytest.mark.parametrize("expr", [
    sympy.exp(x) + sympy.log(y) + sympy.sqrt(z) + sympy.Abs(x - y),
    sympy.tanh(x) + sympy.sign(x - y) + sympy.sin(z) * sympy.cos(w),
    sympy.Max(x, y, 0.5) - sympy.Min(x, z, w),
    sympy.pi * x + sympy.E ** y,
    x ** sympy.Rational(1, 3) + x ** sympy.Float(-1.5) + 1 / sympy.sqrt(y),
], ids=["exp-log-sqrt-abs", "tanh-sign-sin-cos", "min-max", "pi-e", "powers"])
def test_model_functions_print_to_numpy_only_code_that_computes_the_same(expr):
    """What a model file may use (bgc.expressions.FUNCTIONS) needs nothing but np and the symbols."""
    text = print_expr(expr)
    assert names_used(text) <= {"np"} | {s.name for s in expr.free_symbols}, text
    got = np.broadcast_to(run_printed(text), (40,))
    syms = sorted(expr.free_symbols, key=str)
    ref = sympy.lambdify(syms, expr, modules="numpy")(*(POINTS[s.name] for s in syms))
    np.testing.assert_allclose(got, ref, rtol=1e-13)


# ----------------------------------------------------------- np. prefix
def test_functions_are_printed_with_the_np_prefix():
    text = print_expr(sympy.exp(x) + sympy.sqrt(y) + sympy.log(z) + sympy.tanh(w) + sympy.Max(x, y) + sympy.pi
                      + sympy.Abs(x - w))
    for fn in ("np.exp(", "np.sqrt(", "np.log(", "np.tanh(", "np.maximum(", "np.pi", "np.abs("):
        assert fn in text, text
    assert "numpy." not in text and "math." not in text
    assert names_used(text) == {"np", "x", "y", "z", "w"}


# ------------------------------------------------------- float round trip
EXACT = [0.1, 1.0 / 3.0, -2.5e-10, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308,
         123456789.12345678, 0.30000000000000004, -7.0, 6.02214076e23]


@pytest.mark.parametrize("value", EXACT)
def test_float_constants_round_trip_exactly(value):
    text = print_expr(sympy.Float(value))
    assert float(eval(text, {"__builtins__": {}})) == value
    assert text == repr(value)


@settings(max_examples=300)
@given(st.floats(allow_nan=False, allow_infinity=False))
def test_any_finite_float_round_trips_exactly_inside_an_expression(value):
    # v * x at x = 1 is v exactly; v + x at x = 0 is v exactly.
    prod = eval(print_expr(sympy.Float(value) * x), {"__builtins__": {}}, {"x": 1.0})
    total = eval(print_expr(sympy.Float(value) + x), {"__builtins__": {}}, {"x": 0.0})
    assert prod == value and total == value


def test_high_precision_float_is_rounded_to_the_nearest_double():
    text = print_expr(sympy.Float("0.1000000000000000000000000001", 40))
    assert text == "0.1"


# ---------------------------------------------------------- Min / Max
def _minmax_calls(text):
    calls = [n for n in ast.walk(ast.parse(text, mode="eval"))
             if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in ("maximum", "minimum")]
    return calls


@pytest.mark.parametrize("args", [(x, y), (x, y, z), (x, y, z, w, sympy.Float(1.25)), (x, sympy.Integer(2))])
@pytest.mark.parametrize("kind", ["Max", "Min"])
def test_min_max_nest_binary_numpy_calls(kind, args):
    expr = getattr(sympy, kind)(*args)
    text = print_expr(expr)
    calls = _minmax_calls(text)
    # np.maximum(a, b, c) would treat c as the `out` argument: every call must be binary.
    assert len(calls) == len(expr.args) - 1
    assert all(len(c.args) == 2 and not c.keywords for c in calls)
    values = [np.broadcast_to(run_printed(print_expr(a)), (40,)) for a in args]
    reduce = np.maximum.reduce if kind == "Max" else np.minimum.reduce
    np.testing.assert_array_equal(run_printed(text), reduce(values))


def test_mixed_min_max_nesting_evaluates_like_numpy():
    expr = sympy.Max(x, sympy.Min(y, z, sympy.Float(0.7)), sympy.Min(w, sympy.Max(x, z)) - 1)
    text = print_expr(expr)
    X, Y, Z, W = (POINTS[k] for k in "xyzw")
    ref = np.maximum(X, np.maximum(np.minimum(Y, np.minimum(Z, 0.7)), np.minimum(W, np.maximum(X, Z)) - 1))
    np.testing.assert_array_equal(run_printed(text), ref)


def test_single_argument_max_is_the_argument():
    assert print_expr(sympy.Max(x)) == "x"


# ------------------------------------------------------------------ CSE
#: Expressions with shared subexpressions, as source so a fresh interpreter builds the same ones.
CSE_EXPRS_SOURCE = textwrap.dedent("""
    import sympy
    R_pipe, C_res, e6, e13, f22, m2, tau_fp = sympy.symbols("R_pipe C_res e6 e13 f22 m2 tau_fp")
    flow = (e13 - e6) / R_pipe
    head = tau_fp - C_res * f22
    EXPRS = [
        (flow + f22 * m2 / R_pipe) ** 2 + sympy.exp(flow),
        sympy.sqrt(flow ** 2 + 1) * head / C_res,
        sympy.Max(flow, 0) * sympy.log(head + 3) + e13 * R_pipe * C_res,
        head * sympy.exp(flow) - sympy.Min(R_pipe, C_res, e13),
    ]
""")


def _cse_exprs():
    namespace = {}
    exec(CSE_EXPRS_SOURCE, namespace)
    return namespace["EXPRS"]


EXPRS = _cse_exprs()

CSE_SCRIPT = CSE_EXPRS_SOURCE + textwrap.dedent("""
    from bgc.pipeline import compile_model
    from bgc.compiler.printing import cse_block
    print(repr(cse_block(EXPRS)))
    for name in ("ro", "circuit"):
        ssm = compile_model({root!r} + "/models/" + name + ".yaml").equations
        print(repr(cse_block(list(ssm.rhs))))
        print(repr(cse_block(list(ssm.output_exprs))))
""")


def test_cse_lines_define_temporaries_in_order_and_reproduce_the_expressions():
    lines, outs = cse_block(EXPRS)
    assert lines, "these expressions share subexpressions; CSE must find some"
    names = [line.split(" = ")[0] for line in lines]
    assert names == [f"_c{i}" for i in range(len(lines))]
    # Each temporary is used only after it is defined.
    for i, line in enumerate(lines):
        assert names_used(line.split(" = ", 1)[1]) & set(names[i:]) == set()
    scope = {str(s): RNG.uniform(0.5, 2.0, 30) for s in set().union(*(e.free_symbols for e in EXPRS))}
    env = {"np": np, **scope}
    for line in lines:
        name, text = line.split(" = ", 1)
        env[name] = eval(text, {"__builtins__": {}}, env)
    for e, text in zip(EXPRS, outs):
        syms = sorted(e.free_symbols, key=str)
        ref = sympy.lambdify(syms, e, modules="numpy")(*(scope[str(s)] for s in syms))
        np.testing.assert_allclose(np.broadcast_to(eval(text, {"__builtins__": {}}, env), (30,)), ref, rtol=1e-12)


def test_cse_is_the_same_twice_in_one_process():
    assert cse_block(_cse_exprs()) == cse_block(_cse_exprs())


def test_cse_prefix_is_used_and_model_names_are_never_reused():
    c0 = sympy.Symbol("_c0")  # a name the model cannot declare, but the printer must not clobber it anyway
    lines, outs = cse_block([(x + y) ** 2 * c0, sympy.exp(x + y) + c0])
    assert lines == ["_c1 = x + y"] and outs == ["_c0*_c1**2", "_c0 + np.exp(_c1)"]
    lines, _ = cse_block([(x + y) ** 2, sympy.exp(x + y)], prefix="_t")
    assert lines == ["_t0 = x + y"]


@pytest.mark.process  # fresh interpreters: the hash seed is chosen at start
@pytest.mark.long
def test_cse_numbering_does_not_depend_on_the_hash_seed():
    """Same CSE text in fresh interpreters with different PYTHONHASHSEED (set/dict order changes)."""
    from conftest import compiled

    expected = [repr(cse_block(EXPRS))]
    for name in ("ro", "circuit"):
        ssm = compiled(name).equations  # this process's
        expected += [repr(cse_block(list(ssm.rhs))), repr(cse_block(list(ssm.output_exprs)))]
    script = CSE_SCRIPT.format(root=str(ROOT))
    procs = {seed: subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, text=True,
                                    env={**os.environ, "PYTHONHASHSEED": seed},
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for seed in ("0", "4242")}
    for seed, proc in procs.items():
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert out.splitlines() == expected, f"PYTHONHASHSEED={seed}"


# ------------------------------------------------- fewer array operations
from bgc.compiler.printing import array_op_count, fewer_array_ops  # noqa: E402

a, b = sympy.symbols("a b")          # arrays (one value per particle)
p, q, r = sympy.symbols("p q r")     # parameters (scalars)
ARR = frozenset({"a", "b"})
#: Arrays and parameters at sample points; parameters positive and away from 0.
SCALARS = {"p": 1.7, "q": 0.6, "r": 2.3}
ARRAYS = {"a": RNG.uniform(-3.0, 3.0, 40), "b": RNG.uniform(0.5, 3.0, 40)}


@pytest.mark.parametrize("expr, fewer", [
    # (a - q)/p + 29 in a denominator: 1/p factors out and joins the product's scalar
    (b / (29 + (a - q) / p), True),
    (r * b / (p + a / q), True),
    (a / p + b / p + q, True),
    # the common factor r does not divide safely (r = 0 would make r*(a + q/r) NaN): unchanged
    (q + r * (a - b), False),
    (a * b + p, False),
    (a - b, False),
])
def test_fewer_array_ops_is_equal_and_never_costs_more(expr, fewer):
    new = fewer_array_ops(expr, ARR)
    assert sympy.simplify(new - expr) == 0
    before, after = array_op_count(expr, ARR), array_op_count(new, ARR)
    assert (after < before) if fewer else (new == expr and after == before), (print_expr(new, arrays=ARR), before, after)
    # the printed text computes the same numbers as sympy's own evaluation of the original
    got = run_printed(print_expr(new, arrays=ARR), {**ARRAYS, **SCALARS})
    want = sympy.lambdify([a, b, p, q, r], expr, "numpy")(ARRAYS["a"], ARRAYS["b"], *SCALARS.values())
    np.testing.assert_allclose(np.broadcast_to(got, (40,)), np.broadcast_to(want, (40,)), rtol=1e-12)


def test_array_op_count_counts_operations_on_arrays_only():
    assert array_op_count(a * (p + q) / r, ARR) == 1           # the scalar group is folded in Python
    assert array_op_count(-a + b, ARR) == 1                    # printed b - a
    assert array_op_count(sympy.exp(a) + p * b, ARR) == 3
    assert array_op_count(p * q, ARR) == 0


def test_fewer_array_ops_adds_no_singularity_at_a_zero_parameter():
    """Only factors that are negative powers are pulled out of sums: where a
    parameter is 0, the rewritten expression is as finite as the original."""
    cases = [q + r * (a - b), b / (29 + (a - q) / p), a / p + b * q + r, (a + b * r) * (p * a + q)]
    for expr in cases:
        new = fewer_array_ops(expr, ARR)
        for zero in ("q", "r"):
            point = {**ARRAYS, **SCALARS, zero: 0.0}
            with np.errstate(all="ignore"):
                old_v = np.broadcast_to(run_printed(print_expr(expr, arrays=ARR), point), (40,))
                new_v = np.broadcast_to(run_printed(print_expr(new, arrays=ARR), point), (40,))
            assert np.array_equal(np.isfinite(old_v), np.isfinite(new_v)), (expr, zero)
            np.testing.assert_allclose(new_v[np.isfinite(old_v)], old_v[np.isfinite(old_v)], rtol=1e-12)


@pytest.mark.parametrize("expr, text", [
    (-a + b, "b - a"),                        # not -a + b: one array operation, not two
    (-a + b + p * a, "(p)*a - a + b"),
    (-a - b, "-a - b"),                       # no positive term: the minus stays first
    (p - a * b, "p - a*b"),                   # scalar terms first
    (-p + q + a, "-p + q + a"),               # Python adds the floats, then one array operation
    (-(a + b) ** 2 + b, "b - (a + b)**2"),
])
def test_sums_over_arrays_print_scalars_then_a_positive_array_term_first(expr, text):
    assert print_expr(expr, arrays=ARR) == text
    np.testing.assert_allclose(run_printed(text, {**ARRAYS, **SCALARS}),
                               sympy.lambdify([a, b, p, q], expr, "numpy")(ARRAYS["a"], ARRAYS["b"], SCALARS["p"],
                                                                           SCALARS["q"]), rtol=1e-12)


_ATOMS = st.sampled_from([a, b, p, q, r, sympy.Integer(2), sympy.Rational(1, 3), sympy.Float(0.5)])


def _combine(children):
    return st.one_of(
        st.builds(lambda u, v: u + v, children, children),
        st.builds(lambda u, v: u - v, children, children),
        st.builds(lambda u, v: u * v, children, children),
        st.builds(lambda u, v: u / v, children, children),
        st.builds(lambda u: 1 / (1 + u ** 2), children),
        st.builds(lambda u, s: u / s, children, st.sampled_from([p, q, r])),       # divisions by a parameter:
        st.builds(lambda u, v, s: u + (v - s) / s, children, children, st.sampled_from([p, q])),  # what gets factored
    )


@settings(max_examples=150, deadline=None)
@given(st.recursive(_ATOMS, _combine, max_leaves=8))
def test_fewer_array_ops_on_random_expressions(expr):
    """On random sums, products and quotients of arrays and parameters: the
    rewrite never costs more array operations, and it computes the same numbers
    wherever the original is finite (parameters at positive values)."""
    assume(not expr.has(sympy.zoo, sympy.nan, sympy.oo))  # a literal division by zero: refused upstream
    new = fewer_array_ops(expr, ARR)
    assert array_op_count(new, ARR) <= array_op_count(expr, ARR)
    def value(e, at):  # Python floats raise where NumPy gives inf: both count as "not finite"
        try:
            with np.errstate(all="ignore"):
                return np.broadcast_to(np.asarray(run_printed(print_expr(e, arrays=ARR), at), dtype=float), (40,))
        except (ZeroDivisionError, OverflowError):
            return np.full(40, np.nan)

    point = {**ARRAYS, **SCALARS}
    old_v, new_v = value(expr, point), value(new, point)
    ok = np.isfinite(old_v) & (np.abs(old_v) < 1e12)
    np.testing.assert_allclose(new_v[ok], old_v[ok], rtol=1e-8, atol=1e-12)
    # and no new singularity where a parameter is 0 (only negative powers are factored out)
    for zero in ("q", "r"):
        at_zero = {**point, zero: 0.0}
        old_z, new_z = value(expr, at_zero), value(new, at_zero)
        fine = np.isfinite(old_z) & (np.abs(old_z) < 1e12)
        assert np.all(np.isfinite(new_z[fine])), (expr, new, zero)
