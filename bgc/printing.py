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

    def _module_format(self, fqn: str, register: bool = True) -> str:
        text = super()._module_format(fqn, register)
        return "np." + text[len("numpy."):] if text.startswith("numpy.") else text

    def _print_Float(self, expr: sympy.Float) -> str:
        return repr(float(expr))

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


def print_expr(expr: sympy.Expr) -> str:
    """NumPy source text of one expression; raises CodegenError when impossible."""
    try:
        return _PRINTER.doprint(expr)
    except PrintMethodNotImplementedError as exc:
        raise CodegenError(f"cannot generate NumPy code for {sympy.sstr(expr)[:60]}: {str(exc).splitlines()[0]}",
                           None, "use only the functions bgc documents") from None


def cse_block(exprs: Sequence[sympy.Expr], prefix: str = "_c") -> tuple[list[str], list[str]]:
    """CSE over ``exprs``: (assignment lines, printed reduced expressions)."""
    symbols = sympy.numbered_symbols(prefix)
    replacements, reduced = sympy.cse(list(exprs), symbols=symbols, order="canonical")
    lines = [f"{s.name} = {print_expr(e)}" for s, e in replacements]
    return lines, [print_expr(e) for e in reduced]
