"""``sympy.lambdify`` that never pastes a model's names into the Python source it runs.

:func:`sympy.lambdify` prints an expression as Python source and ``exec``-s it. Every
symbol is printed by its *name*, and names come from model files (states, parameters,
residuals, voter channels...): a residual named ``r[__import__('os').system(...)]`` would
be code. :func:`safe_lambdify` prints every symbol through a table of generated names
instead, so the source holds only generated identifiers, numbers and the printer's own
function names, whatever the model's names are (safe by construction, independent of the
name checks of the model reader):

* the function's arguments are fresh symbols ``_a0, _a1, ...`` (nested like ``args``);
* the first statements bind each argument to a generated local ``_v<k> = _a<i>``;
* the expressions are printed unchanged (same tree, same term order: only the text of a
  symbol changes), each symbol as its ``_v<k>``;
* a symbol that is neither an argument nor assigned by ``cse``, or an undefined function
  (printed by its name), is refused with ``ValueError``.
"""

from __future__ import annotations

import sympy as sp
from sympy.core.function import AppliedUndef
from sympy.printing.numpy import NumPyPrinter
from sympy.printing.pycode import MpmathPrinter

_PRINTERS = {"numpy": NumPyPrinter, "mpmath": MpmathPrinter}
_SETTINGS = {"fully_qualified_modules": False, "inline": True,
             "allow_unknown_functions": True, "user_functions": {}}


class _Arg(sp.Symbol):
    """A generated argument: never equal to a model symbol, even one named ``_a0``."""


def _structure(args, counter):
    """Fresh argument symbols nested like ``args``; the (original, fresh) pairs."""
    if isinstance(args, (list, tuple)):
        out, pairs = [], []
        for a in args:
            fresh, sub = _structure(a, counter)
            out.append(fresh)
            pairs.extend(sub)
        return out, pairs
    if not (isinstance(args, sp.Basic) and args.is_symbol):
        raise ValueError(f"safe_lambdify: argument {type(args).__name__} is not a symbol")
    fresh = _Arg(f"_a{counter[0]}")
    counter[0] += 1
    return fresh, [(args, fresh)]


def _leaves(expr):
    if isinstance(expr, (list, tuple)):
        for e in expr:
            yield from _leaves(e)
    elif isinstance(expr, sp.MatrixBase):
        yield from expr
    else:
        yield sp.sympify(expr)


def _mapping_printer(printer, modules, names):
    """An instance of the printer class whose symbols print as ``names[symbol]``."""
    if printer is None:
        base, settings = _PRINTERS[modules], dict(_SETTINGS)
    else:
        base = printer if isinstance(printer, type) else type(printer)
        settings = {} if isinstance(printer, type) else dict(printer._settings)

    def print_symbol(self, expr, *a, **k):
        try:
            return names[expr]
        except KeyError:
            raise ValueError(f"safe_lambdify: symbol {expr.name!r} is not an argument "
                             "nor an assigned symbol") from None

    cls = type(f"_Safe{base.__name__}", (base,),
               {"_print_Symbol": print_symbol, "_print_Dummy": print_symbol})
    return cls(settings)


def safe_lambdify(args, expr, modules: str = "numpy", *, printer=None, cse=None,
                  **kwargs):
    """:func:`sympy.lambdify` with generated names only (see the module docstring).

    Parameters
    ----------
    args : symbol or (nested) sequence of symbols
        The arguments, as for :func:`sympy.lambdify`.
    expr : sympy expression, Matrix or (nested) sequence of them
    modules : {"numpy", "mpmath"}
    printer : printer class or instance, optional
        Default: the module's printer with lambdify's settings.
    cse : callable, optional
        ``cse(exprs) -> (assignments, exprs)``; the assigned symbols are renamed too.
    **kwargs
        Passed to :func:`sympy.lambdify` (``docstring_limit``...).

    Returns
    -------
    callable
        Called like the function :func:`sympy.lambdify` would return.

    Raises
    ------
    ValueError
        For a free symbol that is no argument, or an undefined function.
    """
    counter = [0]
    fresh_args, pairs = _structure(list(args) if isinstance(args, tuple) else args, counter)
    if not isinstance(args, (list, tuple)):
        fresh_args = [fresh_args]
    names = {fresh: fresh.name for _, fresh in pairs}
    prologue = []
    for original, fresh in pairs:
        if original in names:   # the same symbol passed twice: the first binding holds
            continue
        names[original] = f"_v{len(names)}"
        prologue.append((original, fresh))

    def wrapped_cse(exprs):
        assignments, out = cse(exprs) if cse is not None else ([], exprs)
        assignments = list(assignments)
        for sym, _ in assignments:
            if sym not in names:
                names[sym] = f"_v{len(names)}"
        for e in _leaves([e for _, e in assignments] + [out]):
            if e.atoms(AppliedUndef):
                raise ValueError("safe_lambdify: undefined function "
                                 f"{sorted(str(f.func) for f in e.atoms(AppliedUndef))}")
        return prologue + assignments, out

    pr = _mapping_printer(printer, modules, names)
    kwargs.setdefault("docstring_limit", 0)
    fn = sp.lambdify(fresh_args, expr, modules=modules, printer=pr, cse=wrapped_cse,
                     dummify=False, **kwargs)
    return fn
