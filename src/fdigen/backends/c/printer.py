"""C99 printing of FDI programs: a small C99CodePrinter subclass and the CSE helper.

:func:`print_program` lays a program out as ``const`` locals: one per program assignment
(keeping the design's names: ``s0_k1_Pp``, ``vw1``...) and one per common subexpression,
defined just before its first use.

Common subexpressions are found on the printed form, not with :func:`sympy.cse`:
``sympy.cse`` rewrites ``a/b`` as ``a*(1/b)`` and regroups sums and products, which
changes the rounding of every RK4 stage. The parallel model is unstable once its
realignment is frozen, so such last-bit differences grow until the C and the reference
(:mod:`fdigen.backends.reference`, printed by sympy's NumPy printer from the same trees)
part ways. Here a subexpression is shared only where the printer itself emits it as one
unit (an operand, a denominator, a function argument) at least twice, so the C performs
the reference's operations in the reference's order, each once.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass

import numpy as np
import sympy as sp
from sympy.codegen.ast import float32, real
from sympy.printing.c import C99CodePrinter

from fdigen.design.program import Program

# Identifiers a model symbol must not take as a C local: keywords, <math.h> functions
# (which a printed expression may call) and macros, <stdint.h>/<stddef.h> names.
_MATH_FUNCS = """acos asin atan atan2 cos sin tan acosh asinh atanh cosh sinh tanh exp exp2
expm1 frexp ilogb ldexp log log10 log1p log2 logb modf scalbn scalbln cbrt fabs hypot pow
sqrt erf erfc lgamma tgamma ceil floor nearbyint rint lrint llrint round lround llround
trunc fmod remainder remquo copysign nan nextafter nexttoward fdim fmax fmin fma""".split()
_C_RESERVED = frozenset(
    ["_Bool", "_Complex", "_Imaginary", "bool", "true", "false", "NULL", "offsetof",
     "size_t", "ptrdiff_t", "wchar_t", "int8_t", "int16_t", "int32_t", "int64_t", "uint8_t",
     "uint16_t", "uint32_t", "uint64_t", "intptr_t", "uintptr_t", "intmax_t", "uintmax_t",
     "isfinite", "isinf", "isnan", "isnormal", "signbit", "fpclassify", "isgreater",
     "isgreaterequal", "isless", "islessequal", "islessgreater", "isunordered", "NAN",
     "INFINITY", "HUGE_VAL", "HUGE_VALF", "HUGE_VALL", "errno", "math_errhandling"]
    + _MATH_FUNCS + [f + "f" for f in _MATH_FUNCS] + [f + "l" for f in _MATH_FUNCS])


class FdiCPrinter(C99CodePrinter):
    """C99 printer for ``double`` or ``float`` code.

    Differences from :class:`sympy.printing.c.C99CodePrinter`: constants print as exact
    literals of the target type (17 significant digits for ``double``; the nearest
    ``float``, shortest round-trip digits and an ``f`` suffix for ``float``), no
    non-standard ``M_PI``-style macros, and identifiers that would clash with C keywords,
    ``<math.h>``/``<stdint.h>`` names or ``reserved`` get a trailing underscore.

    Parameters
    ----------
    float_type : {"double", "float"}
    reserved : iterable of str
        Further identifiers the printed code must not use (the enclosing function's
        argument names).
    helper_prefix : str
        ``Max``/``Min`` print as calls of ``<helper_prefix>_max``/``_min``, which the
        generated file defines (recorded in :attr:`helpers`) with ``numpy.maximum``'s
        semantics: NaN if either argument is NaN (C99 ``fmax`` would drop the NaN).
        Where one argument cannot be NaN (a symbol of ``not_nan``), they print as
        ``_max_a``/``_max_b`` (``_min_a``/``_min_b``, first or second argument never NaN):
        a plain comparison the compiler turns into one max/min instruction; where that
        argument is a number, as ``_max_ka``/``_max_kb``: through the select (given the
        number, gcc threads it into a branch). ``Piecewise`` prints as nested calls of
        ``<helper_prefix>_select(c, a, b)`` (``c ? a : b`` as a load from a two-entry
        array, without a branch: the step's instruction count does not depend on the
        data).
    not_nan : iterable of sympy.Symbol
        Symbols that are never NaN (the parameters, checked finite by ``init``, and
        assignments of parameters only).
    """

    def __init__(self, float_type: str = "double", reserved=(), helper_prefix: str = "fdi",
                 not_nan=()):
        if float_type not in ("double", "float"):
            raise ValueError(f"float_type must be 'double' or 'float', got {float_type!r}")
        settings = {"math_macros": {}}
        if float_type == "float":
            settings["type_aliases"] = {real: float32}
            settings["type_literal_suffixes"] = {float32: "f"}
        super().__init__(settings)
        self.float_type = float_type
        self.helper_prefix = helper_prefix
        self.helpers = set()
        self.not_nan = frozenset(not_nan)
        self.reserved_words = set(self.reserved_words) | _C_RESERVED | set(reserved)
        self._temps = {}       # shared subexpression -> C name
        self._counts = None    # Counter of printed units while counting
        self._refs = []        # shared subexpressions referenced by the current print
        self._defining = None  # the shared subexpression being defined
        self._ordered = {}     # (sum, order) -> its terms in print order

    def _as_ordered_terms(self, expr, order=None):
        # the same sums are printed many times while the shared units are counted; their
        # canonical order (a sort by sympy's key) is computed once per printer
        key = (expr, order)
        terms = self._ordered.get(key)
        if terms is None:
            terms = self._ordered[key] = super()._as_ordered_terms(expr, order)
        return list(terms)

    def _print(self, expr, **kwargs):
        if isinstance(expr, sp.Basic) and not expr.is_Atom and expr != self._defining:
            if self._counts is not None:
                self._counts[expr] += 1
            name = self._temps.get(expr)
            if name is not None:
                self._refs.append(expr)
                return name
        return super()._print(expr, **kwargs)

    def parenthesize(self, item, level, strict=False):
        if isinstance(item, sp.Basic) and item in self._temps and item != self._defining:
            return self._print(item)  # a name needs no parentheses
        return super().parenthesize(item, level, strict)

    def print_with(self, expr, temps: dict, defining=None, counts=None) -> tuple[str, list]:
        """Print ``expr``, replacing the units in ``temps`` by their names.

        Parameters
        ----------
        expr : sympy.Expr
        temps : dict of sympy.Expr to str
            Shared subexpressions and their C names.
        defining : sympy.Expr, optional
            The shared subexpression ``expr`` defines (printed in full, not by name).
        counts : collections.Counter, optional
            Incremented for every non-atomic unit printed.

        Returns
        -------
        (str, list)
            The C text, and the shared subexpressions it refers to, in order.
        """
        self._temps, self._counts, self._refs, self._defining = temps, counts, [], defining
        try:
            text = self.doprint(expr)
            return text, self._refs
        finally:
            self._temps, self._counts, self._refs, self._defining = {}, None, [], None

    def _print_Float(self, flt):
        value = float(flt)
        if not math.isfinite(value):
            raise ValueError(f"constant {flt} is not a finite {self.float_type}")
        if self.float_type == "double":
            return super()._print_Float(flt)
        with np.errstate(over="ignore"):
            single = np.float32(value)
        if not np.isfinite(single):
            from fdigen.errors import DesignError

            raise DesignError(f"a constant of the design, {value:.4g}, is beyond the range of "
                              "a C float (3.4e38): the float variant of the core cannot hold "
                              "it; rescale the units of the expression that carries it")
        text = str(single)  # shortest digits that round-trip to this float
        if "." not in text and "e" not in text:
            text += ".0"
        return text + "f"

    def _print_Piecewise(self, expr):
        """``Piecewise((a, c1), (b, c2), ..., (z, True))`` as
        ``select(c1, a, select(c2, b, ... z))``: the first piece whose condition holds, as
        the reference's ``numpy.select``, computed without a branch."""
        if expr.args[-1].cond != True:  # noqa: E712 (sympy's true)
            raise ValueError("a Piecewise needs a last (expr, True) piece to print as C")
        self.helpers.add("select")
        text = self._print(expr.args[-1].expr)
        for piece in reversed(expr.args[:-1]):
            text = (f"{self.helper_prefix}_select({self._print(piece.cond)}, "
                    f"{self._print(piece.expr)}, {text})")
        return text

    def _print_sign(self, expr):
        """``sign(x)`` as C99's ``((x) > 0) - ((x) < 0)``; an ``int``, so the ``float``
        variant casts it (``-Wconversion``: the value -1, 0 or 1 is exact in any type)."""
        text = super()._print_sign(expr)
        return text if self.float_type == "double" else f"((float){text})"

    def _print_Max(self, expr):
        return self._fold(expr, "max")

    def _print_Min(self, expr):
        return self._fold(expr, "min")

    def _never_nan(self, expr) -> bool:
        return bool(expr.is_Number or (expr.free_symbols <= self.not_nan
                                       and not expr.atoms(sp.Function, sp.Piecewise)))

    def _fold(self, expr, op):
        """Left fold of a binary helper over the arguments, in ``expr.args`` order (as
        the reference's ``reduce(numpy.maximum, [...])``); ``op_a``/``op_b`` where the
        first/second argument cannot be NaN."""
        first = expr.args[0]
        text = self._print(first)
        known = self._never_nan(first)
        number = first.is_Number
        for arg in expr.args[1:]:
            name = (f"{op}_a" if known else f"{op}_b" if self._never_nan(arg) else op)
            if name != op and (number if known else arg.is_Number):
                name = f"{op}_k{name[-1]}"
            self.helpers.add(name)
            text = f"{self.helper_prefix}_{name}({text}, {self._print(arg)})"
            known = number = False
        return text

    def literal(self, value: float) -> str:
        """A Python float as a C literal of the real type (exact round trip).

        Parameters
        ----------
        value : float

        Returns
        -------
        str
        """
        return self.doprint(sp.Float(float(value), 17))

    def name(self, symbol: sp.Symbol) -> str:
        """The C identifier of a symbol (reserved names get a trailing underscore)."""
        return self.doprint(symbol)


@dataclass(frozen=True)
class PrintedProgram:
    """A program laid out as C statements (strings, ready for a template).

    Attributes
    ----------
    inputs : dict of str to list of (int, str)
        Per input vector, the ``(index, local name)`` of the elements the program uses.
    unused_inputs : tuple of str
        Input vectors none of whose elements is used (the template casts them to void).
    locals : tuple of (str, str)
        ``(name, C expression)`` in evaluation order: CSE temporaries and assignments.
    unused_locals : tuple of str
        Assignments no output depends on (kept, and cast to void).
    outputs : dict of str to tuple of str
        Per output vector, the C expression of each element.
    """

    inputs: dict
    unused_inputs: tuple
    locals: tuple
    unused_locals: tuple
    outputs: dict


def _worth_sharing(expr) -> bool:
    """Anything but a negated atom (``-x`` costs nothing) or a condition (a relational or
    boolean is not a ``real`` temporary)."""
    if isinstance(expr, (sp.core.relational.Relational, sp.logic.boolalg.Boolean)):
        return False
    return not (expr.is_Mul and len(expr.args) == 2 and expr.args[0] == -1
                and expr.args[1].is_Atom)


def shared_subexpressions(exprs, printer: FdiCPrinter) -> set:
    """The units the printer emits at least twice over ``exprs``, after sharing.

    Starts from every unit printed twice, then repeatedly prints with those shared and
    drops the ones now used only once (the pieces of a larger shared unit), to a fixpoint.

    Parameters
    ----------
    exprs : list of sympy.Expr
    printer : FdiCPrinter

    Returns
    -------
    set of sympy.Expr
    """
    def count(shared):
        counts = Counter()
        temps = dict.fromkeys(shared, "_")
        for e in exprs:
            printer.print_with(e, temps, counts=counts)
        for e in shared:
            printer.print_with(e, temps, defining=e, counts=counts)
        return counts

    shared = {e for e, n in count(set()).items() if n >= 2 and _worth_sharing(e)}
    while True:
        counts = count(shared)
        kept = {e for e in shared if counts[e] >= 2}
        if kept == shared:
            return shared
        shared = kept


def _temp_prefix(names: set) -> str:
    prefix = "cse"
    while any(re.fullmatch(re.escape(prefix) + r"\d+", n) for n in names):
        prefix += "_"
    return prefix


def print_program(program: Program, printer: FdiCPrinter, output_names) -> PrintedProgram:
    """Common-subexpression elimination and C printing of a straight-line program.

    Parameters
    ----------
    program : Program
        Its ``inputs`` become array arguments, its assignments ``const`` locals.
    printer : FdiCPrinter
    output_names : sequence of str
        The output vectors to print, in order.

    Returns
    -------
    PrintedProgram

    Raises
    ------
    ValueError
        If two symbols would get the same C identifier.
    """
    assigned = [s for s, _ in program.assignments]
    outputs = [(name, [sp.sympify(e) for e in program.outputs[name]]) for name in output_names]
    out_exprs = [e for _, vec in outputs for e in vec]
    exprs = [e for _, e in program.assignments] + out_exprs

    names = {}
    for sym in program.free_inputs() + assigned:
        c_name = printer.name(sym)
        if names.setdefault(c_name, sym) != sym:
            raise ValueError(f"symbols {names[c_name]} and {sym} both print as {c_name!r} in C")
    prefix = _temp_prefix(set(names) | {s.name for s in program.free_inputs() + assigned})
    shared = shared_subexpressions(exprs, printer)
    # provisional names in order of first print; renumbered in definition order below
    temps = {}
    for e in exprs:
        _, refs = printer.print_with(e, {t: "_" for t in shared})
        for t in refs:
            temps.setdefault(t, f"{prefix}{len(temps)}")
    for t in sorted(shared - temps.keys(), key=sp.default_sort_key):
        temps[t] = f"{prefix}{len(temps)}"

    lines, defined = [], set()

    def define(refs):
        for t in refs:
            if t not in defined:
                defined.add(t)
                text, inner = printer.print_with(t, temps, defining=t)
                define(inner)
                lines.append((temps[t], text))

    for sym, expr in program.assignments:
        text, refs = printer.print_with(expr, temps)
        define(refs)
        lines.append((printer.name(sym), text))
    printed_outputs = {}
    for name, vec in outputs:
        texts = []
        for expr in vec:
            text, refs = printer.print_with(expr, temps)
            define(refs)
            texts.append(text)
        printed_outputs[name] = texts

    order = {name: f"{prefix}{i}" for i, name in
             enumerate(n for n, _ in lines if n in set(temps.values()))}
    rename = re.compile(r"\b" + re.escape(prefix) + r"\d+\b")

    def renumber(text):
        return rename.sub(lambda m: order[m.group(0)], text)

    used = set().union(*(e.free_symbols for e in exprs))
    inputs = {vec: [(i, printer.name(s)) for i, s in enumerate(syms) if s in used]
              for vec, syms in program.inputs.items()}
    return PrintedProgram(
        inputs=inputs,
        unused_inputs=tuple(v for v, used_elems in inputs.items() if not used_elems),
        locals=tuple((renumber(n), renumber(t)) for n, t in lines),
        unused_locals=tuple(printer.name(s) for s in assigned if s not in used),
        outputs={k: tuple(renumber(t) for t in v) for k, v in printed_outputs.items()})
