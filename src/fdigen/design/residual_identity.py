"""What a derived residual is, so that a threshold written for one never applies to another.

The residuals a model file declares (``[fdi.parity]``, ``[fdi.kalman]``, the voter's names)
are what the file says they are: their name is their identity. The residuals the design
derives (``R4``, ``R5``... after the declared ones) are numbered in the order the design
finds them, and that order changes with the model (a fault added, a key switched) and with
fdigen's own search. A threshold written for ``R4`` must not silently apply to whatever
``R4`` is today.

Each derived residual therefore has a *key*, a canonical description of what it computes:

    ``<realisation>: equations [e1, e2] driven by [x<-y, ...], checked on y``
    (``, blind to f`` for an unknown-input decoupled combination)

with the equations and drivers sorted, so the key depends on the residual only, not on the
order it was found in. ``fdigen tune --write`` writes it beside the threshold, in
``[fdi.residual_keys]`` (a separate table: ``[fdi.thresholds]`` stays a table of numbers
and older model files still load). When the model is loaded:

* a key that differs from what the residual now is is refused, naming both (and the
  residual's present name when the design still derives the one it was written for);
* a key for a residual the design does not derive is refused the same way;
* a derived residual's threshold without a key (a hand-written or older file) is accepted
  with a warning (:attr:`fdigen.design.fdi_design.FdiDesign.unkeyed_thresholds`, printed by
  ``fdigen inspect`` and ``fdigen build``): nothing tells what it was written for.
"""

from __future__ import annotations

import re

from fdigen.errors import ModelFileError

#: A decimal number in a key's text (not part of a name: ``y2``, ``R1_3``).
#: sympy's names of the model language's functions, as an earlier fdigen wrote them.
_SYMPY_FUNCTION = re.compile(r"(?<![\w.])(Abs|Min|Max)\(")
_NUMBER = re.compile(r"(?<![\w.])(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?(?![\w.])")


def same_key(a: str, b: str) -> bool:
    """Whether two keys describe the same residual, each number read as the double it
    spells: a key written by an earlier fdigen holds ``273.14999999999998`` where this one
    writes ``273.15`` (the same double; the shortest spelling now), and sympy's ``Abs``,
    ``Min``, ``Max`` where this one writes the model language's ``abs``, ``min``, ``max``."""
    if a == b:
        return True
    if a is None or b is None:
        return False
    def canon(text):
        text = _SYMPY_FUNCTION.sub(lambda m: m.group(1).lower() + "(", text)
        return _NUMBER.sub(lambda m: repr(float(m.group())), text)
    return canon(a) == canon(b)

#: Realisations of a derived residual, by how :func:`fdigen.design.fdi_design` builds it.
REALISATIONS = ("Kalman filter", "parallel model", "decoupled parallel model", "static relation")


def residual_key(extra: dict) -> str:
    """The canonical description of a derived residual (``extra`` as in
    ``FdiDesign.extra_residuals``: ``realisation``, ``equations``, ``drivers``, ``check``,
    ``blind_to``)."""
    drivers = ", ".join(f"{s}<-{o}" for s, o in sorted(extra["drivers"].items()))
    text = (f"{extra['realisation']}: equations [{', '.join(sorted(extra['equations']))}] "
            f"driven by [{drivers}], checked on {extra['check']}")
    if extra.get("blind_to"):
        text += f", blind to {extra['blind_to']}"
    return text


def residual_keys(extras) -> dict:
    """``{name: key}`` of the derived residuals ``extras``."""
    return {e["residual"]: residual_key(e) for e in extras}


def check_residual_keys(extras, keys: dict, thresholds: dict, source: str = "") -> tuple:
    """Refuse a threshold written for another residual; return the unkeyed ones.

    Parameters
    ----------
    extras : sequence of dict
        The derived residuals of the design.
    keys : dict of str to str
        ``[fdi.residual_keys]`` of the model file.
    thresholds : dict of str to float
        ``[fdi.thresholds]`` of the model file.

    Returns
    -------
    tuple of str
        Derived residuals whose threshold the file sets without a key.

    Raises
    ------
    ModelFileError
        ``stale_residuals`` (the names whose thresholds were written for another residual)
        on the error, so ``fdigen tune`` can design them anew.
    """
    now = residual_keys(extras)
    stale = []
    for name, key in keys.items():
        if same_key(now.get(name), key):
            continue
        where = next((n for n, k in now.items() if same_key(k, key)), None)
        also = (f"; this design derives that residual as {where}" if where else
                "; this design no longer derives that residual")
        if name in now:
            stale.append((name, f"the threshold of {name} was written for '{key}', but {name} "
                                f"is now '{now[name]}'{also}"))
        else:
            stale.append((name, f"the threshold of {name} was written for '{key}', and this "
                                f"design derives no {name}{also}"))
    if stale:
        exc = ModelFileError(
            "; ".join(msg for _, msg in stale) + " (`fdigen tune --model FILE --write` "
            "designs the thresholds of the residuals derived now)",
            source=source, field="fdi.residual_keys", symbol=stale[0][0])
        exc.stale_residuals = tuple(n for n, _ in stale)
        raise exc
    return tuple(n for n in now if n in thresholds and n not in keys)
