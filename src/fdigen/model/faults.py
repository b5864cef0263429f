"""Read the ``[faults.<name>]`` tables of a model file into :class:`~fdigen.model.model.Fault`.

Two forms are accepted. The single form names one ``target`` and one ``term``::

    [faults.leak_p]
    location = "plant", mode = "additive", target = "Pp", term = "-k*leak_p*Pp", class = "..."

The several-terms form lists ``(target, term)`` pairs; each target is a state (the term is
added to its derivative), an output (added to the measurement) or an input (added to the
input), and the fault stays one fault (one column of ``E = df/dphi``, ``F = dh/dphi``)::

    [faults.clog12]
    class = "plant"
    terms = [{target = "h1", term = "-clog12*q12/A1"}, {target = "h2", term = "clog12*q12/A2"}]

A fault's symbol may also be written in ``[definitions]`` (``q12 = "(1 - clog12)*..."``);
such a fault needs no term. ``location`` may be omitted in every form: it is ``plant``
when a term targets a state or a definition carries the fault, else ``sensor`` when every
term targets an output, else ``actuator`` (a term on an input).
"""

from __future__ import annotations

import sympy as sp

from fdigen.errors import ModelFileError
from fdigen.model.expression import parse_expression
from fdigen.model.numbers import number_problem
from fdigen.model.model import Fault

_KEYS = {"location", "mode", "target", "term", "terms", "class", "description", "test_size",
         "test_rate"}


def parse_faults(raw: dict, symbols: dict, kinds: dict, in_definitions: set,
                 source: str) -> list[Fault]:
    """Parse every fault table.

    Parameters
    ----------
    raw : dict
        The ``[faults]`` table (fault name -> table).
    symbols : dict
        Every name a term may use (parameters, states, inputs, definitions, faults).
    kinds : dict
        Target name -> ``"state"``, ``"output"`` or ``"input"``.
    in_definitions : set of str
        Fault names that appear in ``[definitions]``.
    source : str
        The model file, for error messages.
    """
    return [_fault(name, spec, symbols, kinds, in_definitions, source)
            for name, spec in raw.items()]


def _err(message, source, fld, symbol):
    return ModelFileError(message, source=source, field=fld, symbol=symbol)


def _fault(name, spec, symbols, kinds, in_definitions, source):
    fld = f"faults.{name}"
    if not isinstance(spec, dict):
        raise _err("must be a table {...}", source, fld, name)
    extra = set(spec) - _KEYS
    if extra:
        raise _err(f"unknown key (allowed: {', '.join(sorted(_KEYS))})", source, fld,
                   sorted(extra)[0])
    for key in ("mode", "class", "location", "description"):
        if key in spec and not isinstance(spec[key], str):
            raise _err(f"'{key}' must be text", source, f"{fld}.{key}", name)
    if not isinstance(spec.get("class"), str):
        raise _err("missing or non-text 'class'", source, f"{fld}.class", name)
    target = spec.get("target")
    if isinstance(target, list) and "terms" not in spec:
        raise _err("'target' names one target; for a fault entering several equations "
                   "write terms = [{target = \"...\", term = \"...\"}, ...]", source,
                   f"{fld}.target", name)
    pairs = []
    if "terms" in spec:
        if "target" in spec or "term" in spec:
            raise _err("give either 'target' and 'term' or 'terms', not both", source,
                       f"{fld}.terms", name)
        items = spec["terms"]
        if not isinstance(items, list) or not items:
            raise _err("'terms' must be a non-empty list of {target = ..., term = ...}",
                       source, f"{fld}.terms", name)
        for k, item in enumerate(items):
            tfld = f"{fld}.terms[{k}]"
            if not isinstance(item, dict) or set(item) != {"target", "term"}:
                raise _err("each entry is {target = \"...\", term = \"...\"}", source, tfld,
                           name)
            if not all(isinstance(item[key], str) for key in ("target", "term")):
                raise _err("'target' and 'term' must be text", source, tfld, name)
            pairs.append((item["target"], parse_expression(item["term"], symbols,
                                                           source=source,
                                                           field=tfld + ".term")))
    elif "target" in spec or "term" in spec or name not in in_definitions:
        for key in ("target", "term"):
            if not isinstance(spec.get(key), str):
                raise _err(f"missing or non-text '{key}'", source, f"{fld}.{key}", name)
        pairs.append((spec["target"], parse_expression(spec["term"], symbols, source=source,
                                                       field=fld + ".term")))
    location = spec.get("location")
    if location is None:       # inferred from what the terms target (module docstring)
        found = {kinds.get(t) for t, _ in pairs}
        location = ("plant" if "state" in found or name in in_definitions or not pairs
                    else "sensor" if found == {"output"} else "actuator")
    test_size = spec.get("test_size", 0.0)
    problem = number_problem(test_size)
    if problem:
        raise _err(problem, source, f"{fld}.test_size", name)
    if "test_size" in spec and float(test_size) == 0.0:
        raise _err("test_size = 0 is no fault: the campaigns of tune and commission run each "
                   "fault at its test size (and at fractions and multiples of it); give the "
                   "size the design must detect, in the fault symbol's units",
                   source, f"{fld}.test_size", name)
    test_rate = spec.get("test_rate")
    problem = None if test_rate is None else number_problem(test_rate)
    if problem:
        raise _err(problem + " (units per second)", source, f"{fld}.test_rate", name)
    single = "terms" not in spec and len(pairs) == 1
    target, term = pairs[0] if pairs else ("", sp.Integer(0))
    return Fault(name, location, str(spec.get("mode", "additive")), target, term,
                 spec["class"], str(spec.get("description", "")), float(test_size),
                 terms=() if single else tuple(pairs),
                 test_rate=None if test_rate is None else float(test_rate))
