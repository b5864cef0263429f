"""The structural checks of a :class:`~fdigen.model.model.Model`, run as it is made.

Names are identifiers, unique across kinds; one equation per state; every free symbol of
every expression is declared; fault locations, modes and targets exist; the operating
point names every state and input and nothing else. Each failure is a
:class:`~fdigen.errors.ModelFileError` naming the field.
"""

from __future__ import annotations

import sympy as sp

from fdigen.errors import ModelFileError

FAULT_LOCATIONS = ("actuator", "plant", "sensor")
FAULT_MODES = ("additive", "multiplicative")


def validate_model(model) -> None:
    """Check a model's structure; raise :class:`ModelFileError` naming the problem.

    Checks: names are identifiers and unique across kinds, one equation per state, every
    free symbol of every expression is declared, fault locations/modes/targets exist.
    """
    src = model.source
    if not model.name.isidentifier():
        raise ModelFileError("model name must be a C identifier", src, "name", model.name)
    seen = {}
    kinds = [("states", model.states), ("inputs", model.inputs), ("outputs", model.outputs),
             ("parameters", model.parameters), ("faults", model.faults)]
    for kind, items in kinds:
        for item in items:
            if not item.name.isidentifier() or item.name.startswith("_"):
                raise ModelFileError("not a valid name", src, kind, item.name)
            if item.name in seen:
                raise ModelFileError(f"duplicated symbol (already in {seen[item.name]})",
                                     src, kind, item.name)
            seen[item.name] = kind
    for name, _ in model.definitions:
        if name in seen:
            raise ModelFileError(f"duplicated symbol (already in {seen[name]})",
                                 src, "definitions", name)
        seen[name] = "definitions"
    if not model.states:
        raise ModelFileError("a model needs at least one state", src, "states")
    if len(model.dynamics) != len(model.states):
        raise ModelFileError(
            f"{len(model.states)} states but {len(model.dynamics)} equations", src, "dynamics")

    known = {sp.Symbol(n, real=True) for n in seen if seen[n] != "outputs"}
    for (name, expr), _ in zip(model.definitions, range(len(model.definitions))):
        _check_free(expr, known, src, f"definitions.{name}")
    for state, expr in zip(model.states, model.dynamics):
        _check_free(expr, known - set(model.f_sym), src, f"dynamics.{state.name}")
    for out in model.outputs:
        _check_free(out.expr, known - set(model.f_sym), src, f"outputs.{out.name}")
    for fault in model.faults:
        fld = f"faults.{fault.name}"
        if fault.location not in FAULT_LOCATIONS:
            raise ModelFileError(f"location must be one of {FAULT_LOCATIONS}", src,
                                 fld + ".location", fault.location)
        if fault.mode not in FAULT_MODES:
            raise ModelFileError(f"mode must be one of {FAULT_MODES}", src, fld + ".mode",
                                 fault.mode)
        targets = {"actuator": [s.name for s in model.inputs],
                   "plant": [s.name for s in model.states],
                   "sensor": [o.name for o in model.outputs]}[fault.location]
        if not fault.multi:
            if fault.target not in targets:
                hint = ""
                if fault.location == "sensor" and fault.target in {s.name for s in
                                                                   model.inputs}:
                    # a current sensor logged as the plant's input: the plant receives
                    # the reading minus the sensor's error
                    hint = (f"; {fault.target} is an input: the sensor that measures it is "
                            "a fault on what the plant receives, location = \"actuator\" "
                            f"with the error's opposite (an offset: term = \"-{fault.name}\")")
                raise ModelFileError(f"a {fault.location} fault must target one of {targets}"
                                     + hint, src, fld + ".target", fault.target)
            _check_free(fault.term, known, src, fld + ".term")
            if fault.symbol not in fault.term.free_symbols:
                raise ModelFileError("the fault term must contain the fault's own symbol",
                                     src, fld + ".term", fault.name)
            continue
        for k, (target, term) in enumerate(fault.terms):
            tfld = f"{fld}.terms[{k}]"
            if model.target_kind(target) is None:
                every = [s.name for s in (*model.states, *model.outputs, *model.inputs)]
                raise ModelFileError(f"a fault term must target a state, output or input "
                                     f"({', '.join(every)})", src, tfld + ".target", target)
            _check_free(term, known, src, tfld + ".term")
        in_defs = any(fault.symbol in e.free_symbols for _, e in model.definitions)
        if not in_defs and not any(fault.symbol in t.free_symbols for _, t in fault.terms):
            raise ModelFileError("the fault's own symbol appears in none of its terms nor in "
                                 "the definitions", src, fld + ".terms", fault.name)
    names = {s.name for s in model.states} | {s.name for s in model.inputs}
    for key in model.operating_point:
        if key not in names:
            raise ModelFileError("operating point names an unknown state or input", src,
                                 "operating_point", key)
    for key in names:
        if key not in model.operating_point:
            raise ModelFileError("operating point misses a value", src, "operating_point", key)


def _check_free(expr, known, src, fld):
    extra = expr.free_symbols - known
    if extra:
        raise ModelFileError("undefined symbol", src, fld, sorted(str(s) for s in extra)[0])
