"""C99 printing of FDI programs: a small C99CodePrinter subclass and the CSE helper.

:func:`print_program` runs :func:`sympy.cse` over a program's assignment and output
expressions, then lays out one ``const`` local per common subexpression (placed just before
its first use) and per program assignment, so the generated code keeps the program's own
names (``s0_k1_Pp``, ``vw1``...) and evaluates each subexpression once.
"""

from __future__ import annotations

import math
import re
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
    """

    def __init__(self, float_type: str = "double", reserved=()):
        if float_type not in ("double", "float"):
            raise ValueError(f"float_type must be 'double' or 'float', got {float_type!r}")
        settings = {"math_macros": {}}
        if float_type == "float":
            settings["type_aliases"] = {real: float32}
            settings["type_literal_suffixes"] = {float32: "f"}
        super().__init__(settings)
        self.float_type = float_type
        self.reserved_words = set(self.reserved_words) | _C_RESERVED | set(reserved)

    def _print_Float(self, flt):
        value = float(flt)
        if not math.isfinite(value):
            raise ValueError(f"constant {flt} is not a finite {self.float_type}")
        if self.float_type == "double":
            return super()._print_Float(flt)
        single = np.float32(value)
        if not np.isfinite(single):
            raise ValueError(f"constant {flt} overflows float")
        text = str(single)  # shortest digits that round-trip to this float
        if "." not in text and "e" not in text:
            text += ".0"
        return text + "f"

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
    exprs = [e for _, e in program.assignments] + [e for _, vec in outputs for e in vec]
    known = {s.name for s in program.free_inputs()} | {s.name for s in assigned}
    temps = sp.numbered_symbols(_temp_prefix(known), real=True)
    reps, reduced = sp.cse(exprs, symbols=temps, order="canonical")
    rep_expr = dict(reps)
    rep_order = {s: i for i, (s, _) in enumerate(reps)}

    lines, emitted = [], set()

    def need(expr):
        for t in sorted(expr.free_symbols & rep_expr.keys(), key=rep_order.__getitem__):
            if t not in emitted:
                need(rep_expr[t])
                lines.append((t, rep_expr[t]))
                emitted.add(t)

    for (sym, _), expr in zip(program.assignments, reduced):
        need(expr)
        lines.append((sym, expr))
    out_exprs = reduced[len(assigned):]
    for expr in out_exprs:
        need(expr)

    used = set().union(*(e.free_symbols for _, e in lines), *(e.free_symbols for e in out_exprs))
    names = {}
    for sym in program.free_inputs() + [s for s, _ in lines]:
        c_name = printer.name(sym)
        if names.setdefault(c_name, sym) != sym:
            raise ValueError(f"symbols {names[c_name]} and {sym} both print as {c_name!r} in C")
    inputs = {vec: [(i, printer.name(s)) for i, s in enumerate(syms) if s in used]
              for vec, syms in program.inputs.items()}
    printed_outputs, k = {}, 0
    for name, vec in outputs:
        printed_outputs[name] = tuple(printer.doprint(e) for e in out_exprs[k:k + len(vec)])
        k += len(vec)
    return PrintedProgram(
        inputs=inputs,
        unused_inputs=tuple(v for v, used_elems in inputs.items() if not used_elems),
        locals=tuple((printer.name(s), printer.doprint(e)) for s, e in lines),
        unused_locals=tuple(printer.name(s) for s in assigned if s not in used),
        outputs=printed_outputs)
