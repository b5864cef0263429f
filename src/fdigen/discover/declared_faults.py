"""A discovered effect that is one of the model's own declared faults.

A healthy commissioning log that a library effect explains the way a declared fault
would (a user's two tanks: ``leak_sqrt_h1``, the shape of the model's ``leak1``) says one
of two things: the rig has that fault, or the log shows an effect the library cannot
tell from it. Either way a plant fault must not become part of the healthy model: the
commissioned design would then read it as normal (a sensor's offset or an actuator's gain
found this way is this rig's calibration, and its fault is measured from it).

The test is exact and symbolic. An effect of one parameter ``theta`` whose terms are
linear in it adds ``theta g_k(x, u)`` to equation or output ``k``; a declared fault
``phi`` changes them by ``c_k(x, u) = d f_k / d phi`` at ``phi = 0`` (every other fault
at zero, definitions and actuator substitutions included). They are the same when they
reach the same equations and outputs and ``g_k = r c_k`` with one constant ``r`` of the
parameters; the effect's size is then the fault's ``phi = r theta``. A plant fault's
size of the opposite sign to its test size (a negative load, a leak that fills the
tank) is the fault's shape, not the fault: it is said, and not withheld.
"""

from __future__ import annotations

import sympy as sp

from fdigen.discover.effects import LibraryEffect, _model_symbols
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model


def declared_fault_of(model: Model, effect: LibraryEffect, value: float) -> dict | None:
    """The declared fault ``effect`` (its parameter at ``value``) is the same as, or
    ``None``: ``{"effect", "fault", "size", "test_size", "times_test_size"}``."""
    if len(effect.parameters) != 1:
        return None
    theta = sp.Symbol(effect.parameters[0].name, real=True)
    syms = {**_model_symbols(model), theta.name: theta}
    g = {}
    for target in (*effect.states, *effect.outputs):
        expr = model.expand(parse_expression(effect.text(target), syms, source="library",
                                             field=effect.name))
        if sp.diff(expr, theta, 2) != 0:
            return None
        g[target] = sp.diff(expr, theta)
    f_with, h_with = model.f(with_faults=True), model.h(with_faults=True)
    zero = {f.symbol: 0 for f in model.faults}
    for fault in model.faults:
        c = {}
        for rows, items in ((f_with, model.states), (h_with, model.outputs)):
            for k, item in enumerate(items):
                d = sp.diff(rows[k], fault.symbol).xreplace(zero)
                if d != 0:
                    c[item.name] = d
        if set(c) != set(g):
            continue
        first = next(iter(g))
        ratio = sp.simplify(g[first] / c[first])
        if not ratio.free_symbols <= set(model.p):
            continue
        if any(sp.simplify(g[t] - ratio * c[t]) != 0 for t in g):
            continue
        size = float(ratio.xreplace(model.parameter_values)) * float(value)
        test = float(fault.test_size) if fault.test_size else None
        return {"effect": effect.name, "fault": fault.name, "location": fault.location,
                "size": size, "test_size": test,
                "times_test_size": abs(size / test) if test else None}
    return None


def effects_as_declared_faults(model: Model, effects, params: dict,
                               warnings: list) -> list[dict]:
    """Every chosen effect (library effects: the output-error loop's own instances are
    not in :func:`~fdigen.discover.effects.library`) that is a declared fault, each warned
    of."""
    out = []
    for effect in effects:
        name = effect.name
        if len(effect.parameters) != 1 or effect.parameters[0].name not in params:
            continue
        same = declared_fault_of(model, effect, params[effect.parameters[0].name])
        if same is None:
            continue
        if same["location"] == "plant" and same["test_size"] and \
                same["size"] * same["test_size"] < 0:
            # a negative load, a leak that fills: the fault's shape, not the fault (a fan's
            # quadratic drag, linearised, read as a load of -0.0123 N m against +0.03)
            warnings.append(f"{name} has the shape of the model's fault {same['fault']} "
                            f"but the opposite sign (size {same['size']:.4g} against a "
                            f"test size of {same['test_size']:.4g}): not that fault; an "
                            "effect of this rig the library describes by its shape")
            continue
        out.append(same)
        times = (f", {same['times_test_size']:.3g}x its test size"
                 if same["times_test_size"] is not None else "")
        if same["location"] == "plant":
            what = (f"the log shows the rig with that fault, or an effect the library "
                    f"cannot tell from it; a healthy model with it would read "
                    f"{same['fault']} as normal (commission does not commit it)")
        elif is_fault_sized(same):
            what = (f"as large as the fault the design must detect: the log's "
                    f"{same['location']} reads like a faulty one, or the effect stands in "
                    "for one the library lacks; a commissioned model with it would read "
                    f"{same['fault']} as normal (commission does not commit it: if the "
                    f"{same['location']} really is this far off, recalibrate it, or write "
                    "the offset into its map yourself)")
        else:
            what = (f"a commissioned model takes it as this rig's calibration of its "
                    f"{same['location']}, and measures {same['fault']} from it")
        warnings.append(f"{name} is the model's own fault {same['fault']} (size "
                        f"{same['size']:.4g}{times}): {what}")
    return out


def is_fault_sized(found: dict) -> bool:
    """Whether a sensor's or an actuator's effect is at least its declared fault's test
    size: the fault the design exists to detect, not a calibration of this rig."""
    return found.get("times_test_size") is not None and found["times_test_size"] >= 1.0


def withheld(found: list[dict]) -> list[dict]:
    """The declared faults commission does not commit: those of the plant (a leak, a
    clogging), and a sensor's offset or an actuator's gain at least as large as its
    fault's test size. Smaller ones are calibrations of this rig and are committed. A
    user's water rig (a 2 s transmitter lag and a leak the model lacked) got level
    offsets of -0.51 mA, 1.7x its sensor fault's test size, written into the sensor's map:
    the design would then have read that fault as healthy."""
    return [f for f in found if f["location"] == "plant" or is_fault_sized(f)]
