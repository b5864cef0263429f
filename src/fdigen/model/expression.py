"""Parse equation strings into sympy through a whitelist: a model file cannot run code.

The string is read with :func:`ast.parse` in ``eval`` mode and the tree is walked node by
node. Only numbers, known symbols, the arithmetic operators ``+ - * / **``, unary minus and
calls of whitelisted functions are accepted; anything else (attribute access, subscripts,
lambdas, comprehensions, strings, dunder names, keyword arguments...) is refused with an
error that names the construct. Nothing is ever passed to ``eval``, ``exec`` or
``sympy.sympify``.
"""

from __future__ import annotations

import ast
import math
from typing import Mapping

import sympy as sp
from sympy.printing.str import StrPrinter

from fdigen.errors import ModelFileError

#: Functions a model equation may call, with their arity (min, max) and sympy builder.
ALLOWED_FUNCTIONS = {
    "sqrt": ((1, 1), sp.sqrt),
    "exp": ((1, 1), sp.exp),
    "log": ((1, 1), sp.log),
    "sin": ((1, 1), sp.sin),
    "cos": ((1, 1), sp.cos),
    "tan": ((1, 1), sp.tan),
    "asin": ((1, 1), sp.asin),
    "acos": ((1, 1), sp.acos),
    "atan": ((1, 1), sp.atan),
    "atan2": ((2, 2), sp.atan2),
    "sinh": ((1, 1), sp.sinh),
    "cosh": ((1, 1), sp.cosh),
    "tanh": ((1, 1), sp.tanh),
    "abs": ((1, 1), sp.Abs),
    "sign": ((1, 1), sp.sign),
    "min": ((2, 8), sp.Min),
    "max": ((2, 8), sp.Max),
}

#: Limits that keep parsing fast and bounded whatever the input.
MAX_LENGTH = 4000
MAX_DEPTH = 60
MAX_NODES = 2000
MAX_EXPONENT = 64
#: Largest magnitude of a number in a model file (a constant of an expression, a value of
#: a table): the derivations square and multiply them (noise variances, Riccati
#: equations, RK4 polynomials of a mode), so 1e300 overflows where 1e150 does not.
MAX_MAGNITUDE = 1e150


def _refuse(message, source, field, symbol=None):
    raise ModelFileError(message, source=source, field=field, symbol=symbol)


def parse_expression(
    text: str,
    symbols: Mapping[str, sp.Expr],
    *,
    source: str | None = None,
    field: str | None = None,
) -> sp.Expr:
    """Parse one equation string into a sympy expression over known symbols.

    Parameters
    ----------
    text : str
        The right-hand side, e.g. ``"-gamma*A*Pp/Vp*xdot + K*gamma*R*Ts/Vp*v"``.
    symbols : mapping of str to sympy expression
        Every name the expression may use (states, inputs, parameters, definitions).
    source, field : str, optional
        Where the text came from, for the error message.

    Returns
    -------
    sympy.Expr

    Raises
    ------
    ModelFileError
        If the text is not a plain arithmetic expression over known names and whitelisted
        functions. The message names the file, the field and the offending symbol.
    """
    if not isinstance(text, str):
        _refuse(f"expected an equation string, got {type(text).__name__}", source, field)
    if len(text) > MAX_LENGTH:
        _refuse(f"expression longer than {MAX_LENGTH} characters", source, field)
    if "__" in text:
        _refuse("dunder names are not allowed in equations", source, field, "__")
    if not text.isascii():
        # Python's parser folds identifiers to NFKC: '𝐊t' and a full-width 'ｗ' would be
        # read as Kt and w without a word (a declared name is refused the same way)
        import unicodedata

        bad = next(c for c in text if not c.isascii())
        folded = unicodedata.normalize("NFKC", bad)
        _refuse(f"non-ASCII character {bad!r} (U+{ord(bad):04X}"
                + (f", read as {folded!r}" if folded != bad and folded.isascii() else "")
                + "): equations are written in ASCII", source, field, bad)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        _refuse(f"not a valid expression ({exc.msg})", source, field, text.strip()[:40])
    except (RecursionError, MemoryError):
        _refuse(f"expression nested deeper than {MAX_DEPTH} levels", source, field)
    count = sum(1 for _ in ast.walk(tree))
    if count > MAX_NODES:
        _refuse(f"expression has {count} nodes, more than the limit {MAX_NODES}", source, field)
    try:
        result = _Converter(symbols, source, field).convert(tree.body, 0)
    except (ArithmeticError, ValueError, TypeError, RecursionError) as exc:
        if isinstance(exc, ModelFileError):
            raise
        _refuse(f"expression cannot be evaluated ({type(exc).__name__}: {str(exc)[:80]})",
                source, field)
    for number in result.atoms(sp.Number):
        if not math.isfinite(float(number)) and number.is_finite is not False:
            _refuse("a constant is outside the range of a double", source, field,
                    str(number)[:40])
    if result.has(sp.zoo, sp.nan, sp.oo, -sp.oo, sp.I):
        _refuse("expression is not a finite real value (division by zero, log(0), "
                "sqrt of a negative number...)", source, field)
    return result


class _Converter:
    """Walk a Python AST and build the sympy expression, refusing anything not whitelisted."""

    _binops = {
        ast.Add: lambda a, b: a + b,
        ast.Sub: lambda a, b: a - b,
        ast.Mult: lambda a, b: a * b,
        ast.Div: lambda a, b: a / b,
    }

    def __init__(self, symbols, source, field):
        self.symbols = symbols
        self.source = source
        self.field = field

    def refuse(self, message, symbol=None):
        _refuse(message, self.source, self.field, symbol)

    def convert(self, node, depth):
        if depth > MAX_DEPTH:
            self.refuse(f"expression nested deeper than {MAX_DEPTH} levels")
        if isinstance(node, ast.Constant):
            return self._constant(node)
        if isinstance(node, ast.Name):
            return self._name(node.id)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            operand = self.convert(node.operand, depth + 1)
            return -operand if isinstance(node.op, ast.USub) else operand
        if isinstance(node, ast.BinOp):
            return self._binop(node, depth)
        if isinstance(node, ast.Call):
            return self._call(node, depth)
        hint = (": write a condition with max(), min(), abs() or sign() (a check valve's "
                "flow: k*sqrt(max(dp, 0)))" if isinstance(node, (ast.IfExp, ast.Compare,
                                                                  ast.BoolOp)) else "")
        self.refuse(f"construct '{type(node).__name__}' is not allowed in an equation{hint}",
                    _describe(node))

    def _constant(self, node):
        value = node.value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.refuse(f"only real numbers are allowed, not {type(value).__name__}",
                        repr(value)[:40])
        if isinstance(value, int):
            if abs(value) > 10**15:
                self.refuse("integer constant too large", str(value)[:40])
            return sp.Integer(value)
        if not math.isfinite(value):
            self.refuse("constant is not finite", repr(value))
        if abs(value) > MAX_MAGNITUDE:
            self.refuse(f"constant beyond {MAX_MAGNITUDE:g} (the derivations would overflow "
                        "a double)", repr(value))
        return sp.Float(value, 17)

    def _name(self, name):
        if name.startswith("_"):
            self.refuse("names starting with '_' are not allowed", name)
        if name not in self.symbols:
            if name == "pi":        # the constant (no model can declare a `pi`: reserved)
                return sp.Float(math.pi, 17)
            self.refuse("undefined symbol", name)
        return self.symbols[name]

    def _binop(self, node, depth):
        # a flat sum or product is one level, however many terms: the parser chains
        # them to the left (a 70-term sum was refused as "nested deeper than 60"); the
        # chain is walked in a loop, so its length costs no recursion
        chain = next((ops for ops in ((ast.Add, ast.Sub), (ast.Mult, ast.Div))
                      if isinstance(node.op, ops)), None)
        if chain is not None:
            links = []
            while isinstance(node, ast.BinOp) and isinstance(node.op, chain):
                links.append(node)
                node = node.left
            result = self.convert(node, depth + 1)
            for link in reversed(links):
                result = self._binops[type(link.op)](result,
                                                     self.convert(link.right, depth + 1))
            return result
        left = self.convert(node.left, depth + 1)
        if isinstance(node.op, ast.Pow):
            right = self.convert(node.right, depth + 1)
            if right.is_number and (not right.is_real or abs(float(right)) > MAX_EXPONENT):
                self.refuse(f"exponent {right} is outside [-{MAX_EXPONENT}, {MAX_EXPONENT}]",
                            str(right)[:40])
            if left.is_number and right.is_number:
                self._check_magnitude(left, right)
            return sp.Pow(left, right)
        op = self._binops.get(type(node.op))
        if op is None:
            hint = (" ('^' is not a power here: write a**2 for a squared)"
                    if isinstance(node.op, ast.BitXor) else "")
            self.refuse(f"operator '{type(node.op).__name__}' is not allowed{hint}",
                        type(node.op).__name__)
        return op(left, self.convert(node.right, depth + 1))

    def _check_magnitude(self, base, exponent):
        """Refuse a constant power whose value would exceed the range of a double."""
        try:
            b = abs(complex(base))
            e = float(exponent)
        except (TypeError, ValueError, OverflowError):
            self.refuse("constant power is not a real number", f"{base}**{exponent}"[:40])
        if b == 0 or b == 1:
            return
        if not math.isfinite(b) or abs(e * math.log10(b)) > 300:
            self.refuse("constant power outside the range of a double",
                        f"{base}**{exponent}"[:40])

    def _call(self, node, depth):
        if not isinstance(node.func, ast.Name):
            self.refuse("only calls of whitelisted functions by plain name are allowed",
                        _describe(node.func))
        name = node.func.id
        if name not in ALLOWED_FUNCTIONS:
            self.refuse(f"unknown function (allowed: {', '.join(sorted(ALLOWED_FUNCTIONS))})",
                        name)
        if node.keywords:
            self.refuse("keyword arguments are not allowed", name)
        (lo, hi), builder = ALLOWED_FUNCTIONS[name]
        if not lo <= len(node.args) <= hi:
            self.refuse(f"function takes {lo}..{hi} arguments, got {len(node.args)}", name)
        if any(isinstance(a, ast.Starred) for a in node.args):
            self.refuse("starred arguments are not allowed", name)
        args = [self.convert(a, depth + 1) for a in node.args]
        return builder(*args)


def _describe(node):
    """A short text naming an AST node, for error messages."""
    try:
        return ast.unparse(node)[:40]
    except Exception:  # pragma: no cover - unparse handles every node we meet
        return type(node).__name__


class _ShortFloatPrinter(StrPrinter):
    """sympy's text, each number written as the shortest decimal of its double, and the
    model language's ``abs``, ``min``, ``max`` (sympy's ``Abs``, ``Min``, ``Max``) and
    ``exp(1)`` (sympy's ``E``), so that :func:`parse_expression` reads the text back."""

    def _print_Float(self, expr):
        value = float(expr)
        if expr._prec < 53 or not math.isfinite(value):    # a number rounded for reading
            return super()._print_Float(expr)
        return repr(value)

    def _print_Abs(self, expr):
        return f"abs({self._print(expr.args[0])})"

    def _print_Min(self, expr):
        return f"min({', '.join(self._print(a) for a in expr.args)})"

    def _print_Max(self, expr):
        return f"max({', '.join(self._print(a) for a in expr.args)})"

    def _print_Exp1(self, expr):
        # sympy's ``E`` would read back as a model's own symbol E (a Young's modulus)
        return "exp(1)"


def expression_text(expr) -> str:
    """The text of a parsed expression as its author wrote the numbers.

    A model's ``273.15`` is parsed as the double nearest to it, kept with 17 significant
    digits (``sp.Float(value, 17)``) so that no derivation rounds it; sympy's own text then
    shows its binary expansion, ``273.14999999999998``. Here every number is the shortest
    decimal that reads back as the same double (``repr(float)``): ``273.15``. Functions
    carry the model language's names: the text is model-file text (a derived residual's
    check through an inverted sensor map, ``sqrt(max(0, ...))``, is parsed again).
    """
    return _ShortFloatPrinter().doprint(sp.sympify(expr))
