"""Small sympy helpers shared by the design modules.

Holds :func:`double` (a float as a sympy Float that prints back to the same double),
:func:`doubles` (every floating constant of an expression rounded to a double, so every
backend reads the same bits) and :func:`real_symbol` (the real symbols of the programs).
"""

from __future__ import annotations

import sympy as sp


def double(value) -> sp.Float:
    """A double as a sympy Float that prints back to the same double."""
    return sp.Float(float(value), 17)


def doubles(expr):
    """``expr`` with every floating constant rounded to the nearest double.

    Constants that sympy folds (``h * A0``...) carry more bits than a double; each
    backend would round them on its own (the numpy printer's decimal string, the C
    printer's 17 digits, CasADi's ``float``) and the results could differ in the last
    place. Rounded here, every backend reads the same double.
    """
    return expr.xreplace({c: double(float(c)) for c in expr.atoms(sp.Float)})


def real_symbol(name: str) -> sp.Symbol:
    return sp.Symbol(name, real=True)
