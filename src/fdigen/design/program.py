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

    def check_unique_names(self, source=None) -> None:
        """Raise :class:`~fdigen.errors.ModelFileError` if two inputs, or an input and an
        assignment, or two assignments share a name.

        Model names become input symbols (parameters ``p``, raw samples ``u``, ``y``)
        and the program derives its assignments' names from them (``par_x``, ``V_raw``,
        ``yhat_R4``): a model name equal to a derived one would make the generated code
        assign one variable twice (a C "redefinition" error, a silently overwritten
        parameter in Python). :mod:`fdigen.model.names` refuses the usual shapes when the
        file is read; this is the exact check on the program itself.
        """
        from fdigen.errors import ModelFileError

        seen = {}
        entries = [(str(s), f"input vector {vec}") for vec, syms in self.inputs.items()
                   for s in syms]
        entries += [(str(s), "a variable of the generated step") for s, _ in self.assignments]
        for name, role in entries:
            if name in seen:
                raise ModelFileError(
                    f"name used twice in the generated code ({seen[name]} and {role}): "
                    "rename the model symbol", source=source, field="model", symbol=name)
            seen[name] = role

    def inlined(self, name: str) -> list:
        """Output ``name`` with every assignment substituted (for small programs and tests)."""
        subs = {}
        for sym, expr in self.assignments:
            subs[sym] = expr.xreplace(subs)
        return [sp.sympify(e).xreplace(subs) for e in self.outputs[name]]
