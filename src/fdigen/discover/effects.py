"""The effect library: small symbolic terms a nominal model may lack.

Each library effect is written once, as model-file-style strings (the same whitelist
parser as the model file, :func:`fdigen.model.expression.parse_expression`, never
``eval``), over the model's own symbols, the effect's parameter(s) and fixed constants:

==================  ==========  ===============================================================
effect              parameter   term(s)
==================  ==========  ===============================================================
coulomb_friction    Fc [N]      ``xdot += -Fc/M*tanh(xdot/v_eps)``, ``v_eps = 0.005`` m/s
stribeck_friction   Fs [N]      ``xdot += -Fs/M*exp(-(xdot/v_s)**2)*tanh(xdot/v_eps)``,
                                ``v_s = 0.02`` m/s (the static-friction excess over Coulomb)
external_load       Fload [N]   ``xdot += -Fload/M``
leak_p              Cl_p        ``Pp += -gamma*R*Ts/Vp*Cl_p*(Pp - Patm)`` [kg/(s Pa)]
leak_n              Cl_n        ``Pn += -gamma*R*Ts/Vn*Cl_n*(Pn - Patm)``
cross_leak          Ci          ``Pp += -gamma*R*Ts/Vp*Ci*(Pp - Pn)``,
                                ``Pn += gamma*R*Ts/Vn*Ci*(Pp - Pn)`` (mass flow p -> n)
valve_deadband      db [V]      ``v -> v - clip(v, -db, db)``: ``Pp += -K*gamma*R*Ts/Vp*c``,
                                ``Pn += K*gamma*R*Ts/Vn*c`` with ``c = min(max(v, -db), db)``
sensor_offset_<y>   off_<y>     ``y += off_<y>`` for every output ``y`` that alone measures a
                                state (a family: one instance per such output)
==================  ==========  ===============================================================

An effect *needs* the model symbols its strings name (its own parameters and constants
excepted) and the equations/outputs it adds to; an effect whose needs are not all in a
model is not applicable to that model (the library is generic: nothing here is searched
by name). New effects are added with :func:`register` (or :func:`register_family` for a
family instantiated per model) without touching the search.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from typing import Callable, Mapping

import sympy as sp

from fdigen.errors import FdigenError
from fdigen.model.expression import ALLOWED_FUNCTIONS, parse_expression
from fdigen.model.model import Model


@dataclass(frozen=True)
class EffectParameter:
    """The parameter of a library effect.

    Attributes
    ----------
    name : str
        Symbol of the parameter in the terms (and in the augmented model file).
    unit : str
    bounds : tuple of float
        Physical range (the search never leaves it).
    nominal : float
        A size that matters (start of the search; default of ``simulate --effect``).
    description : str
    """

    name: str
    unit: str
    bounds: tuple[float, float]
    nominal: float
    description: str = ""


@dataclass(frozen=True)
class LibraryEffect:
    """One effect of the library: terms added to state equations and/or outputs.

    Attributes
    ----------
    name : str
        Unique name (``coulomb_friction``, ``sensor_offset_pp``...).
    description : str
    parameters : tuple of EffectParameter
    states : mapping of str to str
        State name -> term added to that state's equation ``dx_i/dt = f_i + term``.
    outputs : mapping of str to str
        Output name -> term added to that output ``y_j = h_j + term``.
    constants : mapping of str to float
        Fixed numbers named in the terms (written as literals into a model file).
    family : str
        The family an instance belongs to (``sensor_offset``), or ``""``.
    """

    name: str
    description: str
    parameters: tuple[EffectParameter, ...]
    states: Mapping[str, str] = field(default_factory=dict)
    outputs: Mapping[str, str] = field(default_factory=dict)
    constants: Mapping[str, float] = field(default_factory=dict)
    family: str = ""

    # -- what it needs ---------------------------------------------------------------------
    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def needs(self) -> frozenset[str]:
        """Model symbols the effect needs: names in its terms and the targets."""
        own = set(self.parameter_names) | set(self.constants)
        names = set(self.states) | set(self.outputs)
        for text in [*self.states.values(), *self.outputs.values()]:
            names |= _names(text) - own
        return frozenset(names)

    def applicable(self, model: Model) -> bool:
        """Whether every symbol the effect needs is in ``model`` (and no name clashes)."""
        syms = _model_symbols(model)
        if not self.needs <= set(syms) | {o.name for o in model.outputs}:
            return False
        if any(t not in {s.name for s in model.states} for t in self.states):
            return False
        if any(t not in {o.name for o in model.outputs} for t in self.outputs):
            return False
        taken = set(syms) | {o.name for o in model.outputs} | {f.name for f in model.faults}
        return not (set(self.parameter_names) & taken)

    # -- terms -----------------------------------------------------------------------------
    def text(self, target: str) -> str:
        """The term added to ``target`` as model-file text, constants written as numbers."""
        raw = self.states.get(target, self.outputs.get(target))
        if raw is None:
            raise FdigenError(f"effect '{self.name}' has no term for '{target}'")
        for cname, value in self.constants.items():
            raw = re.sub(rf"\b{re.escape(cname)}\b", repr(float(value)), raw)
        return raw

    def terms(self, model: Model) -> dict[str, sp.Expr]:
        """Target (state or output name) -> parsed term over the model's symbols.

        Terms keep the model's definitions (``Vp``) as symbols, like ``model.dynamics``;
        apply ``model.expand`` before evaluating them.
        """
        if not self.applicable(model):
            raise FdigenError(f"effect '{self.name}' is not applicable to model "
                              f"'{model.name}' (needs {', '.join(sorted(self.needs))})")
        syms = _model_symbols(model)
        syms.update({p.name: sp.Symbol(p.name, real=True) for p in self.parameters})
        out = {}
        for target in [*self.states, *self.outputs]:
            out[target] = parse_expression(self.text(target), syms,
                                           source=f"effect {self.name}", field=target)
        return out

    def footprint(self, model: Model) -> frozenset[str]:
        """State equations the effect changes, directly or through a measured state.

        A state term changes its own equation; an output offset on an output that measures
        state ``s`` changes every equation whose right-hand side depends on ``s`` (the
        equation error evaluates the model on the measured states).
        """
        eqs = set(self.states)
        rhs = model.f()
        for oname in self.outputs:
            expr = model.expand(model.output(oname).expr)
            for s in model.states:
                if expr.has(s.symbol):
                    for i, st in enumerate(model.states):
                        if rhs[i].has(s.symbol):
                            eqs.add(st.name)
        return frozenset(eqs)

    def plant_effects(self, model: Model, values: Mapping[str, float] | None = None):
        """The :class:`fdigen.sim.plant.Effect` list that switches this effect on.

        Parameters
        ----------
        values : mapping, optional
            Parameter name -> value; default each parameter's ``nominal``.
        """
        from fdigen.sim.plant import Effect

        vals = {p.name: float(p.nominal) for p in self.parameters}
        vals.update({k: float(v) for k, v in (values or {}).items()})
        unknown = set(vals) - set(self.parameter_names)
        if unknown:
            raise FdigenError(f"effect '{self.name}' has no parameter "
                              f"'{sorted(unknown)[0]}' (has {', '.join(self.parameter_names)})")
        return tuple(Effect(self.name, target, term, dict(vals))
                     for target, term in self.terms(model).items())


# -- registry ------------------------------------------------------------------------------

_EFFECTS: dict[str, LibraryEffect] = {}
_FAMILIES: dict[str, Callable[[Model], list[LibraryEffect]]] = {}


def register(effect: LibraryEffect) -> LibraryEffect:
    """Add an effect to the library (the search picks it up without other changes)."""
    for text in [*effect.states.values(), *effect.outputs.values()]:
        _names(text)  # syntax check now, not at search time
    if effect.name in _EFFECTS:
        raise FdigenError(f"effect '{effect.name}' is already registered")
    _EFFECTS[effect.name] = effect
    return effect


def unregister(name: str) -> None:
    """Remove an effect or a family from the library (no error if absent)."""
    _EFFECTS.pop(name, None)
    _FAMILIES.pop(name, None)


def register_family(name: str, make: Callable[[Model], list[LibraryEffect]]) -> None:
    """Add a family: ``make(model)`` returns its instances for that model."""
    if name in _FAMILIES:
        raise FdigenError(f"effect family '{name}' is already registered")
    _FAMILIES[name] = make


def library(model: Model | None = None) -> list[LibraryEffect]:
    """The library: every registered effect, or only those applicable to ``model``.

    Without a model, families are not instantiated (they depend on the model).
    """
    if model is None:
        return list(_EFFECTS.values())
    out = [e for e in _EFFECTS.values() if e.applicable(model)]
    for make in _FAMILIES.values():
        out.extend(e for e in make(model) if e.applicable(model))
    return out


def get_effect(name: str, model: Model | None = None) -> LibraryEffect:
    """The library effect called ``name`` (applicable to ``model`` if given)."""
    candidates = library(model) if model is not None else list(_EFFECTS.values())
    for e in candidates:
        if e.name == name:
            return e
    known = sorted(e.name for e in candidates)
    if model is not None and name in _EFFECTS:
        raise FdigenError(f"effect '{name}' is not applicable to model '{model.name}' "
                          f"(needs {', '.join(sorted(_EFFECTS[name].needs))}); applicable: "
                          f"{', '.join(known)}")
    if name in _FAMILIES:
        inst = sorted(e.name for e in candidates if e.family == name)
        raise FdigenError(f"'{name}' is a family of effects: name an instance "
                          f"({', '.join(inst) or 'none applicable'})")
    raise FdigenError(f"unknown effect '{name}' (library: {', '.join(known)})")


# -- helpers -------------------------------------------------------------------------------

def _names(text: str) -> set[str]:
    """Identifiers a term string uses (function names excluded); checks the syntax."""
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise FdigenError(f"effect term {text!r} is not an expression ({exc.msg})")
    funcs = {n.func.id for n in ast.walk(tree)
             if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    bad = funcs - set(ALLOWED_FUNCTIONS)
    if bad:
        raise FdigenError(f"effect term {text!r} calls unknown function '{sorted(bad)[0]}'")
    return {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} - funcs


def _model_symbols(model: Model) -> dict[str, sp.Symbol]:
    syms = {}
    for item in [*model.parameters, *model.states, *model.inputs]:
        syms[item.name] = item.symbol
    for name, _ in model.definitions:
        syms[name] = sp.Symbol(name, real=True)
    return syms


# -- the built-in library ------------------------------------------------------------------

#: Smoothing velocity of the friction sign [m/s]: sharp against the rig's speeds (|xdot| up
#: to 0.3 m/s), wider than the noise of the reconstructed velocity (about 2 mm/s). The term
#: is stiff near zero velocity (slope Fc/(M*v_eps), 2300 1/s for Fc = 35 N, M = 3 kg):
#: the augmented model file raises the parallel model's RK4 sub-steps to keep
#: dt/substeps times the stiffness below 1.5 (see :mod:`fdigen.discover.augment`).
V_EPS = 0.005
#: Stribeck velocity [m/s] of the static-friction excess.
V_STRIBECK = 0.02

register(LibraryEffect(
    "coulomb_friction", "Coulomb (dry) friction force opposing the motion, smoothed sign",
    (EffectParameter("Fc", "N", (0.0, 1000.0), 30.0, "Coulomb friction force"),),
    states={"xdot": "-Fc/M*tanh(xdot/v_eps)"}, constants={"v_eps": V_EPS}))

register(LibraryEffect(
    "stribeck_friction",
    "static-friction excess near zero velocity (Stribeck), decaying with (xdot/v_s)^2",
    (EffectParameter("Fs", "N", (0.0, 1000.0), 30.0,
                     "Stribeck (static minus Coulomb) friction force"),),
    states={"xdot": "-Fs/M*exp(-(xdot/v_s)**2)*tanh(xdot/v_eps)"},
    constants={"v_s": V_STRIBECK, "v_eps": V_EPS}))

register(LibraryEffect(
    "external_load", "constant external force on the piston (positive pushes it back)",
    (EffectParameter("Fload", "N", (-2000.0, 2000.0), 20.0, "constant external load"),),
    states={"xdot": "-Fload/M"}))

register(LibraryEffect(
    "leak_p", "air leak from chamber p to atmosphere (laminar, mass flow Cl_p*(Pp - Patm))",
    (EffectParameter("Cl_p", "kg/(s Pa)", (0.0, 1e-8), 2e-11, "leak conductance p"),),
    states={"Pp": "-gamma*R*Ts/Vp*Cl_p*(Pp - Patm)"}))

register(LibraryEffect(
    "leak_n", "air leak from chamber n to atmosphere (laminar, mass flow Cl_n*(Pn - Patm))",
    (EffectParameter("Cl_n", "kg/(s Pa)", (0.0, 1e-8), 2e-11, "leak conductance n"),),
    states={"Pn": "-gamma*R*Ts/Vn*Cl_n*(Pn - Patm)"}))

register(LibraryEffect(
    "cross_leak", "leak across the piston seal, mass flow Ci*(Pp - Pn) from p to n",
    (EffectParameter("Ci", "kg/(s Pa)", (0.0, 1e-7), 3e-9, "piston seal leak conductance"),),
    states={"Pp": "-gamma*R*Ts/Vp*Ci*(Pp - Pn)", "Pn": "gamma*R*Ts/Vn*Ci*(Pp - Pn)"}))

register(LibraryEffect(
    "valve_deadband", "servo valve dead band: the valve sees v - clip(v, -db, db)",
    (EffectParameter("db", "V", (0.0, 2.0), 0.05, "valve dead band half-width"),),
    states={"Pp": "-K*gamma*R*Ts/Vp*min(max(v, -db), db)",
            "Pn": "K*gamma*R*Ts/Vn*min(max(v, -db), db)"}))


def _sensor_offsets(model: Model) -> list[LibraryEffect]:
    """One ``sensor_offset_<y>`` per output that is the only measurement of a state.

    Offsets of redundant sensors (two outputs measuring the same state) show as the
    difference of the two sensors, which the FDI's voter watches; from the equations they
    are not identifiable, so they are not in the library.
    """
    by_state: dict[str, list] = {}
    for o in model.outputs:
        expr = model.expand(o.expr)
        for s in model.states:
            if expr == s.symbol:
                by_state.setdefault(s.name, []).append(o)
    out = []
    for sname, outs in by_state.items():
        if len(outs) != 1:
            continue
        o = outs[0]
        state = model.states[model.state_index(sname)]
        lo, hi = state.range or (-1.0, 1.0)
        span = float(hi - lo)
        out.append(LibraryEffect(
            f"sensor_offset_{o.name}", f"constant offset of sensor {o.name}",
            (EffectParameter(f"off_{o.name}", o.unit, (-span, span), 0.05 * span,
                             f"offset of sensor {o.name}"),),
            outputs={o.name: f"off_{o.name}"}, family="sensor_offset"))
    return out


register_family("sensor_offset", _sensor_offsets)
