"""Safe expression parser: text from a model file -> sympy expression.

Model files hold expressions (a modulated resistance, an orifice law, a
measurement). They are never given to ``eval``, ``exec``, ``sympify`` or
``parse_expr`` (the sympy functions call ``eval``). Instead the text is parsed by
:func:`ast.parse` in ``eval`` mode and the tree is walked against a whitelist:

* numbers (int and float literals; no complex, no booleans);
* declared names (the caller says which);
* ``+ - * / **`` and unary ``-``/``+``;
* calls of a fixed set of functions: ``exp log sqrt abs tanh sign min max sin cos``.

Everything else (attributes, subscripts, lambdas, comprehensions, keywords,
strings, comparisons) is refused with a located error. Sizes are bounded so no
input can make the parser or sympy run away: text length, nesting depth, literal
length, and powers whose value would be astronomically large; every constant
subexpression must be a finite real number (not ``exp(1000)``, ``log(0)``, ``sqrt(-1)``).

Examples
--------
>>> parse("cd*sqrt(abs(e))*sign(e)", {"cd", "e"})
cd*sqrt(Abs(e))*sign(e)
>>> parse("-(a + 2)/b**2", {"a", "b"})
(-a - 2)/b**2
>>> parse("__import__('os')", {"a"})
Traceback (most recent call last):
...
bgc.errors.ExpressionError: '__import__' is not a function bgc knows (use one of: abs, cos, exp, log, max, min, sign, sin, sqrt, tanh)
"""

from __future__ import annotations

import ast
import math
from typing import Callable, Collection, Mapping

import sympy

from ..errors import ExpressionError, SourceLoc
from ..ir import sym

#: The functions an expression may call, with their arity (None: two or more).
FUNCTIONS: Mapping[str, tuple[Callable[..., sympy.Expr], int | None]] = {
    "exp": (sympy.exp, 1),
    "log": (sympy.log, 1),
    "sqrt": (sympy.sqrt, 1),
    "abs": (sympy.Abs, 1),
    "tanh": (sympy.tanh, 1),
    "sign": (sympy.sign, 1),
    "sin": (sympy.sin, 1),
    "cos": (sympy.cos, 1),
    "min": (sympy.Min, None),
    "max": (sympy.Max, None),
}
MAX_LENGTH = 2000
MAX_DEPTH = 40
MAX_LITERAL_DIGITS = 24
MAX_EXPONENT = 64.0

_ALLOWED = "numbers, declared names, + - * / **, unary -, and the functions " + ", ".join(sorted(FUNCTIONS))


def parse(text: str, names: Collection[str], loc: SourceLoc | None = None,
          where: str = "") -> sympy.Expr:
    """Parse ``text`` into a sympy expression using only ``names``.

    Parameters
    ----------
    text
        The expression as written in the model file.
    names
        The names the expression may use (parameters, inputs, bond variables...).
    loc
        Where the expression stands, for error messages.
    where
        What the expression is, prefixed to error messages (e.g. ``"law of R_o"``).

    Raises
    ------
    ExpressionError
        Anything outside the whitelist, an undefined name, or input too large.
    """
    return _Parser(names, loc, where).parse(text)


def free_names(expr: sympy.Expr) -> tuple[str, ...]:
    """Sorted names of the free symbols of an expression."""
    return tuple(sorted(s.name for s in expr.free_symbols))


class _Parser:
    def __init__(self, names: Collection[str], loc: SourceLoc | None, where: str):
        self.names = names
        self.loc = loc
        self.where = where

    def fail(self, what: str, fix: str | None = None) -> ExpressionError:
        return ExpressionError(f"{self.where}: {what}" if self.where else what, self.loc, fix)

    def parse(self, text: str) -> sympy.Expr:
        if isinstance(text, bool) or not isinstance(text, (str, int, float)):
            raise self.fail(f"expected an expression, got {type(text).__name__}",
                            "write a number or a formula as text")
        text = str(text)
        if len(text) > MAX_LENGTH:
            raise self.fail(f"expression is {len(text)} characters long, more than {MAX_LENGTH}",
                            "split it with intermediate parameters")
        if not text.strip():
            raise self.fail("expression is empty", "write a number or a formula")
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError as exc:
            raise self.fail(f"cannot parse '{_short(text)}': {exc.msg}",
                            "write a formula with " + _ALLOWED) from None
        except (RecursionError, MemoryError, ValueError):
            raise self.fail("expression is nested too deeply",
                            f"use at most {MAX_DEPTH} levels of nesting") from None
        return self.walk(tree.body, 0)

    def walk(self, node: ast.AST, depth: int) -> sympy.Expr:
        expr = self.build(node, depth)
        if expr.is_number:
            # Bound every constant subexpression as it is built, so no later step
            # (a float(), an is_zero) asks sympy for a value like exp(exp(exp(100))).
            try:
                value = float(expr)
            except (TypeError, ValueError, OverflowError):  # complex (sqrt(-1)) or infinite (log(0))
                raise self.fail(f"'{_short(str(expr))}' is not a finite real number",
                                "check the arguments of log, sqrt and powers") from None
            if not math.isfinite(value):
                raise self.fail("number is out of range", "rescale the formula")
        return expr

    def build(self, node: ast.AST, depth: int) -> sympy.Expr:
        if depth > MAX_DEPTH:
            raise self.fail("expression is nested too deeply", f"use at most {MAX_DEPTH} levels of nesting")
        d = depth + 1
        if isinstance(node, ast.Constant):
            return self.number(node.value)
        if isinstance(node, ast.Name):
            if node.id not in self.names:
                known = ", ".join(sorted(self.names)[:12])
                more = ", ..." if len(self.names) > 12 else ""
                raise self.fail(f"undefined name '{node.id}'",
                                f"declare it, or use one of: {known}{more}" if known else "declare it")
            return sym(node.id)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            operand = self.walk(node.operand, d)
            return -operand if isinstance(node.op, ast.USub) else operand
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub, ast.Mult, ast.Div)):
            # a flat chain a + b - c + ... (or a * b / c ...) is one level of nesting however
            # long it is: its left spine is walked in a loop, not recursively
            group = (ast.Add, ast.Sub) if isinstance(node.op, (ast.Add, ast.Sub)) else (ast.Mult, ast.Div)
            chain = []
            while isinstance(node, ast.BinOp) and isinstance(node.op, group):
                chain.append((node.op, node.right))
                node = node.left
            result = self.walk(node, d)
            for op, right_node in reversed(chain):
                right = self.walk(right_node, d)
                if isinstance(op, ast.Add):
                    result = result + right
                elif isinstance(op, ast.Sub):
                    result = result - right
                elif isinstance(op, ast.Mult):
                    result = result * right
                else:
                    if right.is_zero:
                        raise self.fail("division by zero", "fix the denominator")
                    result = result / right
            return result
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
            return self.power(self.walk(node.left, d), self.walk(node.right, d))
        if isinstance(node, ast.Call):
            return self.call(node, d)
        raise self.fail(f"{_describe(node)} is not allowed", "use only " + _ALLOWED)

    def number(self, value: object) -> sympy.Expr:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(f"{type(value).__name__} literal {value!r:.40} is not allowed",
                            "use only " + _ALLOWED)
        if isinstance(value, int):
            if len(str(abs(value))) > MAX_LITERAL_DIGITS:
                raise self.fail(f"integer literal with more than {MAX_LITERAL_DIGITS} digits",
                                "write it in floating point, e.g. 1.5e30")
            return sympy.Integer(value)
        if not math.isfinite(value):
            raise self.fail("number is out of range", "write a finite number")
        return sympy.Float(value)

    def power(self, base: sympy.Expr, exponent: sympy.Expr) -> sympy.Expr:
        if exponent.is_number:
            e = float(exponent)
            if abs(e) > MAX_EXPONENT:
                raise self.fail(f"exponent {_short(str(exponent))} is too large (at most {MAX_EXPONENT:g})",
                                "rescale the formula")
            if base.is_number:
                try:
                    value = float(base) ** e
                except (OverflowError, ZeroDivisionError, ValueError):
                    raise self.fail("power of numbers is out of range", "rescale the formula") from None
                if isinstance(value, complex) or not math.isfinite(value):
                    raise self.fail("power of numbers is out of range", "rescale the formula")
        elif base.is_number and abs(float(base)) > 1e6:
            raise self.fail("a large number raised to a variable power", "rescale the formula")
        return sympy.Pow(base, exponent)

    def call(self, node: ast.Call, depth: int) -> sympy.Expr:
        if not isinstance(node.func, ast.Name):
            raise self.fail(f"{_describe(node.func)} cannot be called", "call one of: " + ", ".join(sorted(FUNCTIONS)))
        name = node.func.id
        if name not in FUNCTIONS:
            raise self.fail(f"'{name}' is not a function bgc knows",
                            "use one of: " + ", ".join(sorted(FUNCTIONS)))
        if node.keywords:
            raise self.fail(f"keyword arguments in a call of {name}", f"call {name}(x) without keywords")
        function, arity = FUNCTIONS[name]
        if any(isinstance(a, ast.Starred) for a in node.args):
            raise self.fail(f"starred arguments in a call of {name}", "pass plain arguments")
        n = len(node.args)
        if (arity is None and n < 2) or (arity is not None and n != arity):
            want = "two or more arguments" if arity is None else f"{arity} argument"
            raise self.fail(f"{name} takes {want}, got {n}", f"call {name} with {want}")
        args = [self.walk(a, depth) for a in node.args]
        try:
            return function(*args)
        except (ValueError, TypeError) as exc:  # e.g. Max of an argument sympy knows is not real
            raise self.fail(f"cannot take {name} here: {_short(str(exc), 80)}",
                            f"give {name} real arguments") from None


def _short(text: str, n: int = 40) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _describe(node: ast.AST) -> str:
    names = {
        ast.Attribute: "attribute access", ast.Subscript: "subscript", ast.Lambda: "lambda",
        ast.ListComp: "list comprehension", ast.GeneratorExp: "generator expression",
        ast.SetComp: "set comprehension", ast.DictComp: "dict comprehension",
        ast.Compare: "comparison", ast.BoolOp: "boolean operator", ast.IfExp: "conditional expression",
        ast.List: "list", ast.Tuple: "tuple", ast.Dict: "dict", ast.Set: "set",
        ast.JoinedStr: "f-string", ast.NamedExpr: "assignment expression", ast.Starred: "starred expression",
        ast.Await: "await", ast.Yield: "yield", ast.YieldFrom: "yield",
    }
    for cls, text in names.items():
        if isinstance(node, cls):
            return text
    if isinstance(node, ast.BinOp):
        return f"operator {type(node.op).__name__}"
    if isinstance(node, ast.UnaryOp):
        return f"unary operator {type(node.op).__name__}"
    return type(node).__name__
