"""The effect library: small symbolic terms a nominal model may lack.

Each library effect is declared by the *role* of the equation it belongs to, not by a
model's names, and instantiated per model by :mod:`fdigen.discover.roles`, which finds
the roles structurally (and by the units the model file declares):

==================  =========================  ============================================
effect              role                       term(s) (cylinder instance)
==================  =========================  ============================================
coulomb_friction    motion (velocity state v,  ``v += -Fc/I*tanh(v/v_eps)``, ``v_eps`` =
                    inertia I)                 1/60 of the speed amplitude (0.005 m/s)
stribeck_friction   motion                     ``v += -Fs/I*exp(-(v/v_s)**2)*tanh(v/v_eps)``,
                                               ``v_s`` = 1/15 of the amplitude (0.02 m/s)
external_load       motion                     ``v += -Fload/I``
quadratic_drag      motion                     ``v += -Cd/I*v*abs(v)``
leak_<c>            gas chamber (pressure P,   ``P += -g*Cl_<c>*(P - P_amb)``, ``g`` the
                    mass-flow gain g, ambient  chamber's mass-flow-to-dP/dt factor
                    = its lower limit)         (``R*Ts*gamma/Vp``)
cross_leak          two gas chambers           ``P1 += -g1*Ci*(P1 - P2)``, ``P2 += g2*Ci*(P1 - P2)``
valve_deadband      actuator input u (valve:   ``x_i += -b_i*min(max(u, -db), db)`` for every
                    it drives a chamber)       equation affine in u with gain ``b_i``
sensor_offset_<y>   output that alone          ``y += off_<y>``
                    measures a state
input_offset_<u>    measured input u           ``x_i += f_i(u + off_<u>) - f_i(u)``, the same
                                               in outputs (:mod:`.effects_sensors`)
==================  =========================  ============================================

Rotational motion (a velocity in rad/s) names the parameters as torques (``Tc``, ``Tst``,
``Tload``, unit N m); an input that drives no chamber gets ``actuator_deadband``. Sizes
come from the model too: the friction and load sizes from the viscous force at the speed
amplitude (cylinder 100 N s/m x 0.3 m/s = 30 N), the dead band from the input range.
An effect *needs* the model symbols its strings name (its own parameters and constants
excepted) and the equations/outputs it adds to; an effect whose needs are not all in a
model is not applicable to that model. New effects are added with :func:`register` (a
fixed effect) or :func:`register_family` (instantiated per model, e.g. from a role)
without touching the search.
"""

from __future__ import annotations

import ast
import dataclasses
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
    switch : tuple or None
        A clipping or switching effect's knot: ``(kind, signal, parameter, side)``, the
        term acting where ``signal`` (an ``"output"``, ``"input"`` or ``"state"`` of that
        name) is ``"above"`` or ``"below"`` the level ``parameter``
        (:func:`fdigen.discover.fit_checks.switch_refusal` checks the log visits it).
    """

    name: str
    description: str
    parameters: tuple[EffectParameter, ...]
    states: Mapping[str, str] = field(default_factory=dict)
    outputs: Mapping[str, str] = field(default_factory=dict)
    constants: Mapping[str, float] = field(default_factory=dict)
    family: str = ""
    switch: tuple | None = None

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
        out.extend(e for e in map(_short_parameter_names, make(model))
                   if e.applicable(model))
    return out


def _short_parameter_names(effect: LibraryEffect) -> LibraryEffect:
    """``effect`` with each parameter name longer than a model name may be (a family's
    ``off_<u>`` of a 32-character input) shortened to its first characters and a digest
    of the whole, in its terms too: the written model parses back (it was refused after
    the whole search, naming discover's own file)."""
    import hashlib

    from fdigen.model.names import MAX_NAME_LENGTH

    long = [p.name for p in effect.parameters if len(p.name) > MAX_NAME_LENGTH]
    if not long:
        return effect
    new = {}
    for name in long:
        digest = hashlib.sha256(name.encode()).hexdigest()[:6]
        new[name] = name[:MAX_NAME_LENGTH - 7].rstrip("_") + "_" + digest

    def renamed(text):
        return re.sub(r"\b(" + "|".join(map(re.escape, long)) + r")\b",
                      lambda m: new[m.group(1)], text)
    return dataclasses.replace(
        effect, parameters=tuple(dataclasses.replace(p, name=new.get(p.name, p.name),
                                                     description=renamed(p.description))
                                 for p in effect.parameters),
        states={k: renamed(v) for k, v in effect.states.items()},
        outputs={k: renamed(v) for k, v in effect.outputs.items()},
        switch=None if effect.switch is None else tuple(
            new.get(x, x) if isinstance(x, str) else x for x in effect.switch))


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
    raise FdigenError(f"unknown effect '{name}' (library, with each parameter in the model's "
                      "own units: " + ", ".join(effect_summary(e) for e in
                                                sorted(candidates, key=lambda e: e.name))
                      + ")")


def effect_summary(effect: LibraryEffect) -> str:
    """``leak_sqrt_h (Kl_h in cm^2.5/s, nominal 0.0012)``: an effect with its first
    parameter in the model's own units (a leak of a level in cm takes cm^2.5/s, in m
    m^2.5/s: the same number is not the same leak)."""
    p = effect.parameters[0]
    return f"{effect.name} ({p.name} in {p.unit or '1'}, nominal {p.nominal:g})"


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


# -- the built-in library: one family per role, each in its own module ---------------------
# (registered in this order: mechanical and pneumatic roles, sensor offsets, then the
# liquid, thermal and electrical roles)
from fdigen.discover import effects_mechanical  # noqa: E402,F401
from fdigen.discover import effects_sensors  # noqa: E402,F401
from fdigen.discover import effects_physics  # noqa: E402,F401
from fdigen.discover.effects_mechanical import DRIVE_SHARE  # noqa: E402,F401 (re-exported)
