"""A straight-line program: the backend-neutral form of one FDI step.

Every backend (the sympy/numpy reference, CasADi, C) evaluates the same ordered list of
assignments ``symbol = expression`` and then the named outputs. Keeping intermediate
results (RK4 stages, innovations, voter weights) as named assignments avoids expression
blow-up and lets every printer emit readable code.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp


@dataclass(frozen=True)
class Program:
    """Ordered assignments and named output vectors.

    Attributes
    ----------
    inputs : dict of str to tuple of sympy.Symbol
        Named input vectors (``z``, ``u``, ``y``, ``p``, ``mode``), in argument order.
    assignments : tuple of (sympy.Symbol, sympy.Expr)
        Evaluated in order; each may use inputs and earlier assignments.
    outputs : dict of str to tuple of sympy.Expr
        Named output vectors (``z_next``, ``r``, ``aux``).
    """

    inputs: dict
    assignments: tuple
    outputs: dict

    def free_inputs(self):
        """Every input symbol, in argument order."""
        return [s for vec in self.inputs.values() for s in vec]

    def check_closed(self) -> None:
        """Raise ``ValueError`` if an expression uses a symbol that is not defined before."""
        known = set(self.free_inputs())
        for sym, expr in self.assignments:
            missing = expr.free_symbols - known
            if missing:
                raise ValueError(f"assignment {sym} uses undefined {sorted(map(str, missing))}")
            known.add(sym)
        for name, vec in self.outputs.items():
            for expr in vec:
                missing = sp.sympify(expr).free_symbols - known
                if missing:
                    raise ValueError(f"output {name} uses undefined {sorted(map(str, missing))}")

    def inlined(self, name: str) -> list:
        """Output ``name`` with every assignment substituted (for small programs and tests)."""
        subs = {}
        for sym, expr in self.assignments:
            subs[sym] = expr.xreplace(subs)
        return [sp.sympify(e).xreplace(subs) for e in self.outputs[name]]
