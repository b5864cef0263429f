"""Effect families for liquid, thermal and electrical plants (registered with
:mod:`fdigen.discover.effects`; roles from :mod:`fdigen.discover.roles_physics`).

==================  ======================  =================================================
effect              role                    term(s)
==================  ======================  =================================================
leak_sqrt_<h>       liquid level h, area A  ``h += -Kl_<h>*sqrt(max(h, 0))/A`` (orifice)
leak_linear_<h>     liquid level            ``h += -Kll_<h>*h/A`` (laminar seepage)
heat_loss_<T>       thermal node T, cap. C  ``T += -Ll_<T>*(T - T_amb)/C``
flow_loss_<d>       transfer flow d between ``x_i += -kc_<d>*(df_i/dd)*d`` on both states
                    two balances            (clogging of a pipe, fouling of a wall)
gain_loss_<u>       input u driving a level ``x += -kw_<u>*(df/du)*u`` (pump wear,
                    or thermal balance      heater ageing)
resistance_drift_i  current i, inductance   ``i += -dR_<i>*i/L`` (winding heating)
                    L, resistance R fixed
==================  ======================  =================================================

Sizes come from the role: a leak's nominal flow is a tenth of the flow scale at the
operating level, a heat loss a tenth of the node's conductance, losses of a flow or gain
20 %, a resistance drift 10 % of ``R``.
"""

from __future__ import annotations

import math

from fdigen.discover.effects import EffectParameter, LibraryEffect, register_family
from fdigen.model.model import Model


def _g(v: float) -> float:
    return float(f"{v:.2g}")


def _sfx(name: str, many: bool) -> str:
    return f"_{name}" if many else ""


def _unit_of(model: Model, name: str) -> str:
    """The unit a model file gives the state or parameter ``name`` (``""`` if none)."""
    for item in (*model.states, *model.parameters):
        if item.name == name:
            return (item.unit or "").strip()
    return ""


def _flow_units(model: Model, state: str, capacity: str) -> tuple[str, str]:
    """Units of the orifice and laminar leak coefficients of a level ``state`` over a
    capacity (area) ``capacity``, in the model's own units (a tank in cm and cm^2 gets
    ``cm^2*cm^0.5/s``, not the SI ``m^2.5/s``): the flows ``Kl sqrt(h)`` and ``Kll h``
    are ``A dh/dt``."""
    h, a = _unit_of(model, state), _unit_of(model, capacity)
    if not h or not a:
        return "m^2.5/s", "m^2/s"
    if h == "m" and a in ("m^2", "m2", "m**2"):
        return "m^2.5/s", "m^2/s"
    return f"({a})*({h})^0.5/s", f"({a})/s"


def _balance_effects(model: Model) -> list[LibraryEffect]:
    from fdigen.discover.roles_physics import balances

    found = balances(model)
    out = []
    levels = [b for b in found if b.kind == "level"]
    for b in levels:
        h, A, sfx = b.state, b.capacity, f"_{b.state}"
        root = math.sqrt(max(b.value, 1e-9))
        k_sqrt = b.scale / root
        k_lin = b.scale / max(b.value, 1e-9)
        u_sqrt, u_lin = _flow_units(model, h, A)
        out.append(LibraryEffect(
            f"leak_sqrt{sfx}", f"leak of the tank of {h} through an orifice (Torricelli, "
            f"flow Kl{sfx}*sqrt({h}))",
            (EffectParameter(f"Kl{sfx}", u_sqrt, (0.0, _g(10 * k_sqrt)), _g(0.1 * k_sqrt),
                             f"orifice leak coefficient of {h}"),),
            states={h: f"-Kl{sfx}*sqrt(max({h}, 0))/{A}"}, family="liquid"))
        out.append(LibraryEffect(
            f"leak_linear{sfx}", f"laminar seepage of the tank of {h} (flow Kll{sfx}*{h})",
            (EffectParameter(f"Kll{sfx}", u_lin, (0.0, _g(10 * k_lin)), _g(0.1 * k_lin),
                             f"laminar leak coefficient of {h}"),),
            states={h: f"-Kll{sfx}*{h}/{A}"}, family="liquid"))
    for b in (b for b in found if b.kind == "thermal"):
        T, C, sfx = b.state, b.capacity, f"_{b.state}"
        out.append(LibraryEffect(
            f"heat_loss{sfx}", f"extra heat loss of {T} to ambient {b.ambient}" + (
                f" (assumed: {T}'s lower limit; no parameter of its unit is described "
                "as ambient)" if b.assumed else ""),
            (EffectParameter(f"Ll{sfx}", "W/K", (0.0, _g(10 * b.scale)), _g(0.1 * b.scale),
                             f"extra loss conductance of {T}"),),
            states={T: f"-Ll{sfx}*({T} - ({b.ambient}))/{C}"}, family="thermal"))
    return out


def _transfer_effects(model: Model) -> list[LibraryEffect]:
    from fdigen.discover.roles_physics import transfers

    out = []
    for tr in transfers(model):
        d = tr.definition
        out.append(LibraryEffect(
            f"flow_loss_{d}", f"relative loss of the transfer {d} (clogging, fouling)",
            (EffectParameter(f"kc_{d}", "1", (0.0, 0.95), 0.2, f"relative loss of {d}"),),
            states={s: f"-kc_{d}*({g})*{d}" for s, g in tr.gains.items()},
            family="transfer"))
    return out


def _gain_effects(model: Model) -> list[LibraryEffect]:
    from fdigen.discover.roles_physics import driven_inputs

    out = []
    for u, gains in driven_inputs(model):
        out.append(LibraryEffect(
            f"gain_loss_{u}", f"relative loss of the gain of {u} (pump wear, heater ageing)",
            (EffectParameter(f"kw_{u}", "1", (0.0, 0.95), 0.2, f"relative gain loss of {u}"),),
            states={x: f"{'' if neg else '-'}kw_{u}*({g})*{u}" for x, (g, neg) in gains.items()},
            family="gain"))
    return out


def _electrical_effects(model: Model) -> list[LibraryEffect]:
    from fdigen.discover.roles_physics import currents

    out = []
    for i, L, R in currents(model):
        r = next(q.value for q in model.parameters if q.name == R)
        out.append(LibraryEffect(
            f"resistance_drift_{i}", f"drift of the resistance {R} in the balance of {i}",
            (EffectParameter(f"dR_{i}", "Ohm", (_g(-0.5 * r), _g(0.5 * r)), _g(0.1 * r),
                             f"resistance change in the balance of {i}"),),
            states={i: f"-dR_{i}*{i}/{L}"}, family="electrical"))
    return out


register_family("liquid_thermal", _balance_effects)
register_family("transfer", _transfer_effects)
register_family("gain", _gain_effects)
register_family("electrical", _electrical_effects)


def assumed_ambient_notes(effects) -> list[str]:
    """A note per chosen heat loss whose ambient was assumed (the state's lower limit, or
    0): its conductance then also absorbs the difference to the true ambient (a user's
    boiler: 6.02 W/K to 0 degC, its lower limit, for a true 9 W/K to 18 degC), and nothing
    said so but the written model file."""
    out = []
    for e in effects:
        desc = getattr(e, "description", "")
        if e.name.startswith("heat_loss") and "(assumed:" in desc:
            out.append(f"{e.name}: {desc}: its conductance also absorbs the difference to "
                       "the true ambient; declare the ambient (a parameter of the "
                       "temperature's unit whose description says ambient, e.g. T_amb = { "
                       "value = 20, unit = \"degC\", description = \"ambient "
                       "temperature\" }) and discover again")
    return out
