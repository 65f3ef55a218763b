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

from typing import Sequence

import sympy
from sympy.printing.codeprinter import PrintMethodNotImplementedError
from sympy.printing.numpy import NumPyPrinter

from .errors import CodegenError


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

    def _module_format(self, fqn: str, register: bool = True) -> str:
        text = super()._module_format(fqn, register)
        return "np." + text[len("numpy."):] if text.startswith("numpy.") else text

    def _print_Float(self, expr: sympy.Float) -> str:
        return repr(float(expr))

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


def cse_block(exprs: Sequence[sympy.Expr], prefix: str = "_c",
              arrays: frozenset[str] = frozenset()) -> tuple[list[str], list[str]]:
    """CSE over ``exprs``: (assignment lines, printed reduced expressions).

    With ``arrays`` (the names that hold one value per particle), every product
    prints its scalar factors as one group, computed in Python floats before a
    single array operation.
    """
    exprs = list(exprs)
    symbols = sympy.numbered_symbols(prefix)
    replacements, reduced = sympy.cse(exprs, symbols=symbols, order="canonical")
    temps = frozenset(s.name for s, _ in replacements)
    arrays_now = set(arrays)
    lines = []
    for s, e in replacements:
        lines.append(f"{s.name} = {print_expr(e, temps, frozenset(arrays_now))}")
        if any(x.name in arrays_now for x in e.free_symbols):
            arrays_now.add(s.name)
    return lines, [print_expr(e, temps, frozenset(arrays_now)) for e in reduced]
