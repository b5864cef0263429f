"""Effect families of mechanical and pneumatic plants (registered with
:mod:`fdigen.discover.effects`; roles from :mod:`fdigen.discover.roles`): friction, loads
and drag of a motion, leaks of gas chambers, dead bands of actuators. The table of
:mod:`fdigen.discover.effects` lists their terms.
"""

from __future__ import annotations

from fdigen.discover.effects import EffectParameter, LibraryEffect, register_family
from fdigen.model.model import Model

#: A friction or load force of a motion may reach this share of the largest force term of
#: its balance (:attr:`fdigen.discover.roles.Motion.drive`).
DRIVE_SHARE = 0.1


def _motion_effects(model: Model) -> list[LibraryEffect]:
    """Friction and load effects of every motion (force/torque balance) of the model."""
    from fdigen.discover.roles import motions

    found = motions(model)
    out = []
    for mo in found:
        sfx = f"_{mo.velocity}" if len(found) > 1 else ""
        F, unit, what = ("T", "N m", "torque") if mo.rotational else ("F", "N", "force")
        v, inertia, size = mo.velocity, mo.inertia, mo.force
        # a bound of the force the balance can apply too: a hydraulic axis's friction
        # was capped at 100 N (its mass and speed range) where the piston pushes 25 kN
        hi = _round3(max(1000.0 / 30.0 * size, DRIVE_SHARE * mo.drive))
        c, s, load = f"{F}c{sfx}", (f"Tst{sfx}" if mo.rotational else f"Fs{sfx}"), \
            f"{F}load{sfx}"
        # a velocity in mm/s or rpm: the SI force moves it at c F/I
        k, ks = ("", {}) if mo.scale == 1.0 else ("k_si*", {"k_si": mo.scale})
        out.append(LibraryEffect(
            f"coulomb_friction{sfx}",
            f"Coulomb (dry) friction {what} opposing the motion of {v}, smoothed sign",
            (EffectParameter(c, unit, (0.0, hi), size, f"Coulomb friction {what}"),),
            states={v: f"-{k}{c}/{inertia}*tanh({v}/v_eps)"},
            constants={"v_eps": mo.v_eps, **ks}, family="motion"))
        out.append(LibraryEffect(
            f"stribeck_friction{sfx}",
            f"static-friction excess near zero {v} (Stribeck), decaying with ({v}/v_s)^2",
            (EffectParameter(s, unit, (0.0, hi), size,
                             f"Stribeck (static minus Coulomb) friction {what}"),),
            states={v: f"-{k}{s}/{inertia}*exp(-({v}/v_s)**2)*tanh({v}/v_eps)"},
            constants={"v_s": mo.v_stribeck, "v_eps": mo.v_eps, **ks}, family="motion"))
        out.append(LibraryEffect(
            f"external_load{sfx}", f"constant external {what} opposing positive {v}",
            (EffectParameter(load, unit, (-2 * hi, 2 * hi), _round2(2.0 / 3.0 * size),
                             f"constant external load {what}"),),
            states={v: f"-{k}{load}/{inertia}"}, constants=ks, family="motion"))
        # a fan's or a pump's aerodynamic drag, cd v|v|: a user's fan rig, without it,
        # got a negative load and a viscous damping 9.8 times its datasheet value
        amp = mo.amplitude
        if amp > 0:
            cd = f"Cd{sfx}"
            out.append(LibraryEffect(
                f"quadratic_drag{sfx}",
                f"drag {what} growing with the square of {v} (fan, pump, air or fluid "
                "drag), opposing the motion",
                (EffectParameter(cd, f"{unit} per ({v} unit)^2", (0.0, hi / amp ** 2),
                                 float(f"{size / amp ** 2:.3g}"),
                                 f"quadratic drag coefficient ({what} per squared {v})"),),
                states={v: f"-{k}{cd}/{inertia}*{v}*abs({v})"}, constants=ks,
                family="motion"))
    return out


def _chamber_effects(model: Model) -> list[LibraryEffect]:
    """Leaks of every gas chamber to ambient, and across every pair of chambers."""
    from fdigen.discover.roles import chambers

    found = chambers(model)
    out = []
    for ch in found:
        sfx = f"_{ch.suffix}" if ch.suffix else ""
        P, g, amb = ch.pressure, ch.gain, ch.ambient
        out.append(LibraryEffect(
            f"leak{sfx}",
            f"gas leak from chamber {P} to ambient (laminar, mass flow Cl{sfx}*({P} - {amb}))",
            (EffectParameter(f"Cl{sfx}", "kg/(s Pa)", (0.0, 1e-8), 2e-11,
                             f"leak conductance {P}"),),
            states={P: f"-({g})*Cl{sfx}*({P} - {amb})"}, family="chamber"))
    for k, a in enumerate(found):
        for b in found[k + 1:]:
            sfx = "" if len(found) == 2 else f"_{a.suffix}{b.suffix}"
            pa, pb = a.pressure, b.pressure
            out.append(LibraryEffect(
                f"cross_leak{sfx}", f"leak between chambers {pa} and {pb}, mass flow "
                f"Ci{sfx}*({pa} - {pb}) from {pa} to {pb}",
                (EffectParameter(f"Ci{sfx}", "kg/(s Pa)", (0.0, 1e-7), 3e-9,
                                 "seal leak conductance between the chambers"),),
                states={pa: f"-({a.gain})*Ci{sfx}*({pa} - {pb})",
                        pb: f"({b.gain})*Ci{sfx}*({pa} - {pb})"}, family="chamber"))
    return out


def _deadband_effects(model: Model) -> list[LibraryEffect]:
    """A dead band of every actuator input that enters its equations affinely."""
    from fdigen.discover.roles import actuators

    found = actuators(model)
    out = []
    for ac in found:
        sfx = f"_{ac.input}" if len(found) > 1 else ""
        name = ("valve_deadband" if ac.drives_chamber else "actuator_deadband") + sfx
        u, db = ac.input, f"db{sfx}"
        out.append(LibraryEffect(
            name, f"dead band of input {u}: the plant sees {u} - clip({u}, -{db}, {db})",
            (EffectParameter(db, ac.unit, (0.0, _round3(0.2 * ac.span)), _round2(0.005 * ac.span),
                             f"dead band half-width of {u}"),),
            states={x: f"{'' if neg else '-'}({gain})*min(max({u}, -{db}), {db})"
                    for x, (gain, neg) in ac.gains.items()}, family="deadband"))
    return out


def _round2(v: float) -> float:
    return float(f"{v:.2g}")


def _round3(v: float) -> float:
    return float(f"{v:.3g}")


register_family("motion", _motion_effects)
register_family("chamber", _chamber_effects)
register_family("deadband", _deadband_effects)
