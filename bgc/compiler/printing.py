"""Strict NumPy printer and deterministic common-subexpression elimination.

:class:`StrictNumPyPrinter` is sympy's NumPy printer with three changes: it
raises (:class:`~bgc.errors.CodegenError`) on anything it cannot print instead
of emitting a comment, it prints ``np.`` rather than ``numpy.``, and it prints
floats with ``repr`` (shortest round-trip form) so generated numbers equal the
model's exactly. :func:`cse_block` numbers CSE temporaries ``_c0, _c1, ...`` in
the order sympy returns them, which depends only on the expressions.

Examples
--------
>>> import sympy
>>> x, y = sympy.symbols("x y")
>>> print(print_expr(sympy.sqrt(x) * sympy.Max(x, y, 0.1)))
np.sqrt(x)*np.maximum(0.1, np.maximum(x, y))
>>> lines, outs = cse_block([(x + y) ** 2, sympy.exp(x + y)])
>>> lines, outs
(['_c0 = x + y'], ['_c0**2', 'np.exp(_c0)'])
"""

from __future__ import annotations

import functools
import math
from typing import Sequence

import sympy
from sympy.printing.codeprinter import PrintMethodNotImplementedError
from sympy.printing.numpy import NumPyPrinter

from ..errors import CodegenError, printable


class StrictNumPyPrinter(NumPyPrinter):
    """NumPy code printer that refuses what it cannot print."""

    def __init__(self) -> None:
        super().__init__({"fully_qualified_modules": True, "strict": True, "allow_unknown_functions": False})
        #: Names bound to arrays (one value per particle); products put their
        #: scalar factors first, in one parenthesised group, so Python folds them
        #: into one float before a single array operation.
        self.arrays: frozenset[str] = frozenset()

    def _print_Mul(self, expr: sympy.Mul) -> str:
        if not self.arrays:
            return super()._print_Mul(expr)
        scalars, arrays = [], []
        for a in expr.args:
            (arrays if any(s.name in self.arrays for s in a.free_symbols) else scalars).append(a)
        if not scalars or not arrays or (len(scalars) == 1 and scalars[0] == -1):
            return super()._print_Mul(expr)
        coefficient = sympy.Mul(*scalars)
        rest = sympy.Mul(*arrays)
        rest_text = self._print(rest)
        if isinstance(rest, sympy.Add):
            rest_text = f"({rest_text})"
        return f"({self._print(coefficient)})*{rest_text}"

    def _print_Add(self, expr: sympy.Add, order: str | None = None) -> str:
        """As sympy prints it, except with arrays: the terms without arrays come
        first (Python adds them as floats, then one array operation adds their
        sum), and then an array term without a minus sign comes first: ``e6 - e13``
        (one array operation), not ``-e13 + e6`` (two)."""
        if not self.arrays:
            return super()._print_Add(expr, order)
        from sympy.printing.precedence import precedence

        ordered = self._as_ordered_terms(expr, order=None)
        scalar = [t for t in ordered if not any(s.name in self.arrays for s in t.free_symbols)]
        terms = scalar + [t for t in ordered if t not in scalar]
        printed = [self._print(t) for t in terms]
        first = 0 if scalar else next((i for i, t in enumerate(printed) if not t.startswith("-")), 0)
        order_ = [first] + [i for i in range(len(terms)) if i != first]
        parts: list[str] = []
        for i in order_:
            text = printed[i]
            sign = "+"
            if text.startswith("-"):
                sign, text = "-", text[1:]
            if precedence(terms[i]) < precedence(expr) or isinstance(terms[i], sympy.Add):
                text = f"({text})"
            parts += [sign, text]
        head = parts.pop(0)
        return ("" if head == "+" else head) + " ".join(parts)

    def _module_format(self, fqn: str, register: bool = True) -> str:
        text = super()._module_format(fqn, register)
        return "np." + text[len("numpy."):] if text.startswith("numpy.") else text

    def _print_Float(self, expr: sympy.Float) -> str:
        return repr(float(expr))

    def _print_Pow(self, expr: sympy.Pow, rational: bool = False) -> str:
        """A whole-number exponent prints as the integer it is, a reciprocal as
        a division: ``1/L``, not ``L**(-1.0)``; ``x**2``, not ``x**2.0``. (sympy's
        NumPy printer makes negative integer exponents floats, for integer
        arrays; every array here holds floats.)"""
        e = expr.exp
        if e.is_number and e.is_real and float(e).is_integer() and abs(float(e)) <= 64:
            expr = sympy.Pow(expr.base, sympy.Integer(int(e)), evaluate=False)
            return self._hprint_Pow(expr, rational=rational, sqrt=self._module + ".sqrt")
        return super()._print_Pow(expr, rational)

    def _print_Abs(self, expr: sympy.Abs) -> str:
        return f"np.abs({self._print(expr.args[0])})"

    def _print_Min(self, expr: sympy.Min) -> str:
        return self._nested("np.minimum", expr.args)

    def _print_Max(self, expr: sympy.Max) -> str:
        return self._nested("np.maximum", expr.args)

    def _nested(self, fn: str, args: Sequence[sympy.Expr]) -> str:
        args = list(args)
        text = self._print(args[-1])
        for a in reversed(args[:-1]):
            text = f"{fn}({self._print(a)}, {text})"
        return text

    def _print_Symbol(self, expr: sympy.Symbol) -> str:
        name = expr.name
        if not name.isidentifier():
            raise CodegenError(f"symbol '{name}' is not a Python identifier", None, "rename it in the model")
        return name


_PRINTER = StrictNumPyPrinter()


def print_expr(expr: sympy.Expr, names: frozenset[str] | None = None,
               arrays: frozenset[str] = frozenset()) -> str:
    """NumPy source text of one expression; raises CodegenError when impossible.

    The text is checked: it may use only ``np.<function>``, the expression's
    own symbols and ``names`` (e.g. CSE temporaries), so nothing that would need
    another import (``math.erf``, ``builtins.sum``) or an undefined name
    (``Lambda``) reaches a generated module.
    """
    try:
        _PRINTER.arrays = arrays
        text = _PRINTER.doprint(expr)
    except PrintMethodNotImplementedError as exc:
        raise CodegenError(f"cannot generate NumPy code for {sympy.sstr(expr)[:60]}: {str(exc).splitlines()[0]}",
                           None, "use only the functions bgc documents") from None
    except CodegenError:
        raise
    except Exception as exc:  # sympy's printers raise KeyError etc. for e.g. zoo
        raise CodegenError(f"cannot generate NumPy code for {sympy.sstr(expr)[:60]}: {type(exc).__name__}",
                           None, "use only the functions bgc documents") from None
    finally:
        _PRINTER.arrays = frozenset()
    allowed = {s.name for s in expr.free_symbols} | set(names or ())
    _check_numpy_only(text, allowed, expr)
    return text


def _check_numpy_only(text: str, allowed: set[str], expr: sympy.Expr) -> None:
    import ast

    def fail(what: str) -> CodegenError:
        return CodegenError(f"cannot generate NumPy code for {sympy.sstr(expr)[:60]}: it would need {what}",
                            None, "use only the functions bgc documents")

    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError:
        raise fail("text that does not parse") from None
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            base = node
            while isinstance(base, ast.Attribute):
                base = base.value
            if not (isinstance(base, ast.Name) and base.id == "np"):
                raise fail(f"'{ast.unparse(node)}'")
        elif isinstance(node, ast.Name) and node.id != "np" and node.id not in allowed:
            raise fail(f"the name '{node.id}'")


def split_linear(expr: sympy.Expr, states: Sequence[str], arrays: frozenset[str]
                 ) -> tuple[dict[int, sympy.Expr], sympy.Expr, sympy.Expr]:
    """Split ``expr`` into ``sum_j A_j * states[j] + b + rest``: ``A_j`` and ``b``
    depend on no array, ``rest`` holds the terms that are not linear in one
    state with a scalar coefficient. Scalar factors of sums are distributed
    first, so ``(x1 - x2)/C`` gives two linear terms.

    Examples
    --------
    >>> x1, x2, c, k = sympy.symbols("x1 x2 c k")
    >>> split_linear((x1 - x2) / c + k * x1 * x2 + 3, ["x1", "x2"], frozenset({"x1", "x2"}))
    ({0: 1/c, 1: -1/c}, 3, k*x1*x2)
    """
    index = {name: i for i, name in enumerate(states)}

    def is_array(e: sympy.Expr) -> bool:
        return any(s.name in arrays for s in e.free_symbols)

    def distribute(e: sympy.Expr) -> list[sympy.Expr]:
        if isinstance(e, sympy.Add):
            return [t for a in e.args for t in distribute(a)]
        if isinstance(e, sympy.Mul):
            sums = [a for a in e.args if isinstance(a, sympy.Add) and is_array(a)]
            others = [a for a in e.args if not (isinstance(a, sympy.Add) and is_array(a))]
            if len(sums) == 1 and not any(is_array(a) for a in others):
                c = sympy.Mul(*others)
                return [t for a in sums[0].args for t in distribute(c * a)]
        return [e]

    coefficients: dict[int, sympy.Expr] = {}
    constant, rest = sympy.Integer(0), sympy.Integer(0)
    for term in distribute(expr):
        if not is_array(term):
            constant += term
            continue
        c, r = term.as_independent(*[sympy.Symbol(a) for a in sorted(arrays)], as_Add=False)
        if isinstance(r, sympy.Symbol) and r.name in index and not is_array(c):
            coefficients[index[r.name]] = coefficients.get(index[r.name], sympy.Integer(0)) + c
        else:
            rest += term
    return coefficients, constant, rest


@functools.lru_cache(maxsize=4096)
def array_op_count(expr: sympy.Expr, arrays: frozenset[str]) -> int:
    """Number of NumPy operations on arrays the printed ``expr`` performs: the
    operators and calls whose operands include an array name.

    Kept per expression: :func:`fewer_array_ops` counts an expression again
    for every candidate of every enclosing sum, and printing and parsing it is
    most of that rewrite's time."""
    import ast

    tree = ast.parse(print_expr(expr, arrays=arrays), mode="eval")

    def has_array(node: ast.AST) -> bool:
        return any(isinstance(n, ast.Name) and n.id in arrays for n in ast.walk(node))

    return sum(1 for n in ast.walk(tree) if isinstance(n, (ast.BinOp, ast.UnaryOp, ast.Call)) and has_array(n))


def _divides_safely(c: sympy.Expr) -> bool:
    """True when dividing by ``c`` adds no singularity: ``c`` is a product of
    negative powers (of parameters or their sums) and nonzero numbers, e.g. 1/K
    or 2/(R1*C1), so that ``t / c`` only multiplies ``t``."""
    if not c.free_symbols:
        return False
    for f in (c.args if isinstance(c, sympy.Mul) else (c,)):
        if f.is_Number and f != 0:
            continue
        if isinstance(f, sympy.Pow) and f.exp.is_number and f.exp.is_negative:
            continue
        return False
    return True


def fewer_array_ops(expr: sympy.Expr, arrays: frozenset[str]) -> sympy.Expr:
    """An equal expression that costs fewer array operations, or ``expr``.

    A sum over arrays ``c*x + c*y*z + k`` (scalars c, k) becomes
    ``c*(x + y*z + k/c)`` when c divides safely (see :func:`_divides_safely`),
    scalar factors of inner sums being distributed first: the common factor
    then joins the scalar factors of the enclosing product, which Python folds
    into one float. The whole rewrite is kept only if :func:`array_op_count`
    of the expression drops.

    Examples
    --------
    >>> e13, e27, K0, Ks = sympy.symbols("e13 e27 K0 K_slope")
    >>> e = e13 / (29 + (e27 - K0) / Ks)
    >>> print(print_expr(fewer_array_ops(e, frozenset({"e13", "e27"})), arrays=frozenset({"e13", "e27"})))
    (K_slope)*e13/(-K0 + 29*K_slope + e27)
    """

    def is_array(e: sympy.Expr) -> bool:
        return any(s.name in arrays for s in e.free_symbols)

    def rewrite(e: sympy.Expr) -> sympy.Expr:
        if not e.args or not is_array(e):
            return e
        e = e.func(*[rewrite(a) for a in e.args])
        if not isinstance(e, sympy.Add):
            return e
        terms: list[sympy.Expr] = []
        for t in e.args:
            if isinstance(t, sympy.Mul):
                inner = [a for a in t.args if isinstance(a, sympy.Add) and is_array(a)]
                rest = [a for a in t.args if not (isinstance(a, sympy.Add) and is_array(a))]
                if len(inner) == 1 and not any(is_array(a) for a in rest):
                    terms += [sympy.Mul(*rest) * a for a in inner[0].args]
                    continue
            terms.append(t)
        symbols = [sympy.Symbol(a) for a in sorted(arrays)]
        split = [t.as_independent(*symbols, as_Add=False) if is_array(t) else (t, None) for t in terms]
        best, best_cost = e, array_op_count(e, arrays)
        seen: set[sympy.Expr] = set()
        for c, m in split:
            if m is None or c in seen or not _divides_safely(c):
                continue
            seen.add(c)
            inner = sympy.Add(*[(cc / c) * (mm if mm is not None else 1) for cc, mm in split])
            candidate = sympy.Mul(c, inner)
            cost = array_op_count(candidate, arrays)
            if cost < best_cost or (cost == best_cost and best is e):
                # a tie here is kept: the factor may join an enclosing product
                best, best_cost = candidate, cost
        return best

    out = rewrite(expr)
    return out if array_op_count(out, arrays) < array_op_count(expr, arrays) else expr


def cse_block(exprs: Sequence[sympy.Expr], prefix: str = "_c",
              arrays: frozenset[str] = frozenset()) -> tuple[list[str], list[str]]:
    """CSE over ``exprs``: (assignment lines, printed reduced expressions).

    With ``arrays`` (the names that hold one value per particle), every product
    prints its scalar factors as one group, computed in Python floats before a
    single array operation.

    The text depends only on the arguments (sympy's expressions compare
    equal only when they are the same tree, a Float's precision and a
    symbol's assumptions included), so it is kept for the compilations of a
    process that print the same expressions again (a model compiled again,
    each of its fault models' blocks that are the nominal's): :func:`fewer_array_ops`
    and sympy's CSE are most of a compilation's time (measured: 7.5 s of the
    9.3 s they took over the compiler's tests went to blocks printed before).
    ``_cse_text.cache_clear()`` forgets them (a test that a compilation is a
    pure function of the model)."""
    lines, printed = _cse_text(tuple(exprs), prefix, frozenset(arrays))
    return list(lines), list(printed)


@functools.lru_cache(maxsize=512)
def _cse_text(exprs: tuple[sympy.Expr, ...], prefix: str, arrays: frozenset[str]) -> tuple[tuple[str, ...],
                                                                                           tuple[str, ...]]:
    """:func:`cse_block`'s text, as tuples."""
    exprs = [fewer_array_ops(e, arrays) for e in exprs] if arrays else list(exprs)
    symbols = sympy.numbered_symbols(prefix)
    replacements, reduced = sympy.cse(exprs, symbols=symbols, order="canonical")
    temps = frozenset(s.name for s, _ in replacements)
    arrays_now = set(arrays)
    lines = []
    for s, e in replacements:
        lines.append(f"{s.name} = {print_expr(e, temps, frozenset(arrays_now))}")
        if any(x.name in arrays_now for x in e.free_symbols):
            arrays_now.add(s.name)
    return tuple(lines), tuple(print_expr(e, temps, frozenset(arrays_now)) for e in reduced)


def escape(text: str, newlines: bool = False) -> str:
    r"""Model text as it may stand in generated source: inside a (non-raw)
    string literal, triple-quoted or not, it reads back as ``text``, and in a
    ``#`` comment it stays on its line.

    Backslashes and double quotes are escaped; every character that is not
    printable (control characters, NUL, line and paragraph separators, lone
    surrogates, ANSI escapes) becomes its Python escape sequence, newlines
    included unless ``newlines`` (a docstring keeps the description's line
    breaks). The one function through which model text reaches generated code.

    Examples
    --------
    >>> print(escape('end" + 1\\c\nimport os'))
    end\" + 1\\c\nimport os
    >>> escape("two\nlines", newlines=True) == "two\nlines"
    True
    >>> print(escape("\x1b[31m\ud800"))
    \x1b[31m\ud800
    """
    quoted = text.replace("\\", "\\\\").replace('"', '\\"')
    if newlines:
        return "\n".join(printable(line) for line in quoted.split("\n"))
    return printable(quoted)


#: A number printed into generated code may differ from bgc's float by at most
#: this many units in the last place (the rounding of one operation), if that
#: gives a shorter repr (0.02 *
#: 363.7155 is 7.274310000000001 in floating point: it prints as 7.27431).
ROUNDING_ULPS = 1


def print_number(value: float, what: str = "a number", where: str | None = None) -> str:
    """The shortest repr of a float within ROUNDING_ULPS of ``value`` (the
    rounding of bgc's own arithmetic, not a change of value); a number that is
    not finite is a :class:`~bgc.errors.CodegenError` naming ``what``.

    Examples
    --------
    >>> print_number(0.02 * 363.7155), print_number(0.1 + 0.2), print_number(1e-300)
    ('7.27431', '0.3', '1e-300')
    >>> print_number(float("inf"), "a process-noise std")
    Traceback (most recent call last):
    ...
    bgc.errors.CodegenError: a process-noise std is inf, not a finite number (rescale the model's values)
    """
    v = float(value)
    if not math.isfinite(v):
        raise CodegenError(f"{what} is {v!r}, not a finite number", where, "rescale the model's values")
    if v == 0.0:
        return "0.0"
    tolerance = ROUNDING_ULPS * math.ulp(v)
    for digits in range(1, 18):
        text = repr(float(f"{v:.{digits}g}"))
        if abs(float(text) - v) <= tolerance:
            return text
    return repr(v)
