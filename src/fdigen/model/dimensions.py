"""Physical dimension of a model file's unit string, so roles go by dimension, not spelling.

``"cm"``, ``"m"`` and ``"mm"`` are all a length; ``"cm^2"``, ``"m2"`` and ``"m**2"`` an
area; ``"L/min"`` and ``"m^3/s"`` a volume flow. The unit text is parsed by the model
files' whitelist parser (:func:`fdigen.model.expression.parse_expression`: nothing is
evaluated), each name looked up in :mod:`sympy.physics.units` (SI prefixes included),
and the dimension read from sympy's SI dimension system:

.. math:: [u] = \\prod_b b^{e_b}, \\quad b \\in \\{L, M, T, \\Theta, I, N, J\\}

Unknown names (``"V"`` of a level read in volts is known: a voltage) or text that is not
a product of powers give ``None``: no dimension, no role by dimension.
"""

from __future__ import annotations

import re
from functools import lru_cache

import sympy as sp

#: Spellings sympy.physics.units does not know by these names.
_ALIASES = {"min": "minute", "degC": "kelvin", "°C": "kelvin", "C": "kelvin",
            "Ohm": "ohm", "Ω": "ohm", "l": "liter", "1": None, "rad": None, "": None,
            "rev": None, "rpm": "hertz"}    # turns are dimensionless; rpm is 1/time


def _quantity(name: str):
    import sympy.physics.units as u

    if name in _ALIASES:
        alias = _ALIASES[name]
        return sp.Integer(1) if alias is None else getattr(u, alias)
    q = getattr(u, name, None)
    if isinstance(q, u.Quantity):
        return q
    return None


@lru_cache(maxsize=256)
def dimension(unit: str) -> tuple | None:
    """Sorted ``((base dimension, exponent), ...)`` of ``unit``, or ``None`` if unknown.

    Parameters
    ----------
    unit : str
        A unit as model files write it (``"cm^2"``, ``"m^3/s"``, ``"kg/(s Pa)"``).
    """
    from sympy.physics.units.systems.si import SI, dimsys_SI

    from fdigen.errors import FdigenError
    from fdigen.model.expression import parse_expression

    text = unit.strip().replace("°C", "degC")
    # a percentage is a ratio: a command logged in V for a model's "%" is another
    # quantity (a user's heater: healthy log read as a dead element, safety_stop)
    if text in ("", "1", "-", "%", "‰", "ppm", "percent", "pct", "permille"):
        return ()
    # a space between factors is a product: "kg/(s Pa)" -> "kg/(s*Pa)"
    text = re.sub(r"(?<=[\w)])\s+(?=[\w(])", "*", text).replace("^", "**")
    text = re.sub(r"(?<=[A-Za-z])(\d+(?:\.\d+)?)\b", r"**\1", text)  # m2 -> m**2
    names = set(re.findall(r"[A-Za-zΩ_]\w*", text))
    quantities = {}
    for n in names:
        q = _quantity(n)
        if q is None:
            return None
        quantities[n] = q
    syms = {n: sp.Symbol(n, positive=True) for n in names}
    try:
        expr = parse_expression(text, syms, source="unit", field=unit)
    except (FdigenError, ValueError, TypeError):
        return None
    expr = expr.xreplace({syms[n]: q for n, q in quantities.items()})
    dim = SI.get_dimensional_expr(expr)
    deps = dimsys_SI.get_dimensional_dependencies(dim)
    return tuple(sorted((str(k.name), str(sp.nsimplify(v))) for k, v in deps.items()
                        if v != 0))


def same_dimension(unit: str, reference: str) -> bool:
    """Whether ``unit`` has the dimension of ``reference`` (both known)."""
    a, b = dimension(unit), dimension(reference)
    return a is not None and a == b
