"""Warnings about a design that do not stop it: faults no residual detects, derived
thresholds without a key, parallel models open loop on an unstable plant, an operating
point outside its ranges or away from an equilibrium (printed by ``fdigen build`` and
``fdigen inspect``)."""

from __future__ import annotations


def refusal_warning(design) -> tuple:
    """The refusal ``fdigen commission`` wrote into the model file (``[fdi] refused``),
    to be said before anything else."""
    from fdigen.design.config import refused_text

    return (refused_text(design.config.refused),) if design.config.refused else ()


def unkeyed_warning(design) -> tuple:
    """A warning naming the derived residuals whose thresholds carry no residual key
    (:mod:`fdigen.design.residual_identity`), or nothing."""
    if not design.unkeyed_thresholds:
        return ()
    return (f"the thresholds of derived residuals {', '.join(design.unkeyed_thresholds)} "
            "carry no residual key ([fdi.residual_keys]): nothing tells which residual they "
            "were written for; `fdigen tune --model FILE --write` designs them and writes "
            "the keys",)


def detection_warnings(design) -> tuple:
    """Warnings for faults no residual can detect, or nothing.

    The measurement-validity flags ``nf_<y>`` raise only on an invalid sample (NaN, out of
    range), never on a fault's effect: a design whose only residuals are those flags
    detects nothing, and a fault whose signature holds only those flags is never detected.
    """
    ev = design.evaluation
    validity = {f"nf_{o.name}" for o in design.model.outputs}
    detecting = [i for i, n in enumerate(ev.residuals) if n not in validity]
    if not detecting:
        return ("no residual can detect any fault: the model declares no residual "
                "([fdi.parity] or [fdi.kalman]) and none could be derived; the core has only "
                "the sensors' validity flags nf_* (NaN or out of range); declare "
                "[fdi.parity] or [fdi.kalman] residuals",)
    mask = sum(1 << i for i in detecting)
    silent = [f for f, m in zip(ev.fault_names, ev.fault_masks) if not m & mask]
    if not silent:
        return ()
    return (f"no residual detects {', '.join(silent)} (an all-zero row of the signature "
            "table, the sensors' validity flags aside): the fault moves no output a "
            "residual watches, or its term has no effect on the model; check its target and "
            "term, or declare a residual on an output it moves",)


def operating_point_warnings(design) -> tuple:
    """Warnings for an operating point outside the declared state ranges, or far from an
    equilibrium of its own inputs: the linearisation, the Kalman filters' models and the
    parallel models' start are all taken there (a user's press: 3 bar against a range of
    5-150 bar and a spring needing 30, said nowhere).

    The distance to the equilibrium is one Newton step,
    :math:`\\Delta x = -A^{+} f(x_0, u_0)` with :math:`A = \\partial f/\\partial x` there
    (least squares: an integrator's row is zero); a state whose step exceeds
    :data:`EQUILIBRIUM_SHARE` of its range is named (the press: 18 %; published operating
    points rounded to a few digits, a quadruple tank's or a greenhouse's: 5 % and less),
    and so is one that no step can stop (an integrator fed a non-zero rate)."""
    import numpy as np
    import sympy as sp

    from fdigen.derive.linearisation import numeric

    model = design.model
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name]
                  for s in (*model.states, *model.inputs)})
    out, far = [], []
    horizon = design.config.window * design.config.sample_time
    try:
        f = model.f()
        rates = numeric(f, point).ravel()
        A = numeric(f.jacobian(sp.Matrix([s.symbol for s in model.states])), point)
        step = np.linalg.lstsq(A, -rates, rcond=None)[0]
        unmet = np.abs(A @ step + rates) > 1e-6 * np.maximum(np.abs(rates), 1e-300)
    except (TypeError, ValueError, np.linalg.LinAlgError):
        rates = None
    for i, s in enumerate(model.states):
        if not s.range:
            continue
        lo, hi = (float(v) for v in s.range)
        x0 = float(model.operating_point[s.name])
        if not lo <= x0 <= hi:
            out.append(f"the operating point's {s.name} = {x0:g} lies outside its declared "
                       f"range [{lo:g}, {hi:g}]: the linearisation, the filters and the "
                       "parallel models are taken there; one of the two is in other units "
                       "or wrong")
        if rates is None or not hi > lo or not np.isfinite(step[i]):
            continue
        if unmet[i]:
            # an integrator fed a rate: named when it moves 1 % of its range in a window
            # (a round-off rate of 1e-13 on a motor's current is no finding)
            if abs(rates[i]) * horizon > 0.01 * (hi - lo):
                far.append(f"d{s.name}/dt = {rates[i]:.3g} with no equilibrium near")
        elif abs(step[i]) > EQUILIBRIUM_SHARE * (hi - lo):
            far.append(f"{s.name} = {x0:g}, its equilibrium near {x0 + step[i]:.4g}")
    out.extend(inputs_outside(model))
    if far:
        out.append("the operating point is not an equilibrium of its own inputs ("
                   + "; ".join(far) + f"; more than {100 * EQUILIBRIUM_SHARE:g} % of the "
                   "range away): the linearisation and the Kalman filters' models are "
                   "taken at a point the plant does not stay at; set the [operating_point] "
                   "to a steady state of the inputs given there")
    return tuple(out)


def inputs_outside(model) -> list:
    """An input whose operating value lies outside its declared range, or outside the
    limits of the controller that drives it: the loop cannot hold the plant there (a
    user's pump needed 24.23 V from a 24 V supply; the healthy loop saturated in 51 % of
    its samples and the thresholds were designed on it, said nowhere)."""
    from fdigen.model.simulation_spec import simulation_spec

    out = []
    try:
        limits = {c.input: c.limits for c in simulation_spec(model).controllers
                  if c.limits is not None}
    except Exception:   # noqa: BLE001 - no [simulation]: no controller limits
        limits = {}
    for v in model.inputs:
        u0 = float(model.operating_point[v.name])
        for what, bounds in (("declared range", v.range),
                             ("controller's limits", limits.get(v.name))):
            if bounds and not float(bounds[0]) <= u0 <= float(bounds[1]):
                out.append(f"the operating point's input {v.name} = {u0:.6g} lies outside "
                           f"its {what} [{float(bounds[0]):g}, {float(bounds[1]):g}]: the "
                           "loop cannot hold the plant at its operating point (it saturates, "
                           "and the thresholds are designed on the saturated loop); widen the "
                           "range or the supply, or move the operating point")
                break
    return out


#: An operating point this share of a state's range away from its equilibrium is named.
EQUILIBRIUM_SHARE = 0.1


def open_loop_warnings(design) -> tuple:
    """A warning when the design's parallel models run open loop (``[fdi]
    realign_noise_scale = 0``) on a plant with an unstable mode at the operating point:
    they diverge from the plant, and no threshold holds (a user's magnetic levitation rig:
    tune ended in "cannot write threshold inf")."""
    from fdigen.derive.linearisation import growth_rate

    parallel = design.config.parity or any(
        e.get("realisation", "").endswith("parallel model") for e in design.extra_residuals)
    if not parallel or design.config.realign_noise_scale > 0:
        return ()
    worst = growth_rate(design.model)
    if worst <= 0:
        return ()
    return (f"the plant is unstable open loop at the operating point (an eigenvalue with "
            f"real part {worst:.3g} 1/s) and the parallel models run open loop ([fdi] "
            "realign_noise_scale = 0): they diverge from the plant within seconds of any "
            "error; set a positive realign_noise_scale (0.1) so each is re-aligned on its "
            "own sensor",)



#: Most corners of the declared ranges :func:`domain_warnings` evaluates an expression at
#: (``2^k`` for the ``k`` states and inputs it reads; beyond, the first ``2^10``).
MAX_CORNERS = 1024


def domain_warnings(design) -> tuple:
    """Each state equation and output that is not a finite real number at a corner of the
    declared ranges of the states and inputs it reads (a division by an input whose range
    reaches 0, a ``sqrt`` or ``log`` of a difference that turns negative there), with the
    corner and the fix.

    A user's solar collector divided by the irradiance ``G`` (range [0, 1000] W/m^2):
    ``inspect`` said nothing, and ``simulate`` then stopped at t = 0, at night. The
    equations are evaluated with the parameters' values (faults at zero) at every corner
    of the box of the ranges of the variables each reads; a state or input without a
    declared range is held at its operating value.
    """
    import itertools

    import numpy as np
    import sympy as sp

    from fdigen.safe_lambdify import safe_lambdify

    model = design.model
    op = {s.symbol: float(model.operating_point[s.name])
          for s in (*model.states, *model.inputs)}
    ranged = {s.symbol: tuple(float(v) for v in s.range)
              for s in (*model.states, *model.inputs) if s.range}
    pars = dict(model.parameter_values)
    exprs = [(f"d{s.name}/dt", e) for s, e in zip(model.states, model.f())]
    exprs += [(f"output {o.name}", e) for o, e in zip(model.outputs, model.h())]
    out = []
    for label, expr in exprs:
        expr = sp.sympify(expr.xreplace(pars))    # (a parameter alone: a float)
        syms = sorted((s for s in expr.free_symbols if s in ranged), key=str)
        if not syms:
            continue
        corners = list(itertools.islice(
            itertools.product(*(ranged[s] for s in syms)), MAX_CORNERS))
        try:
            fn = safe_lambdify(syms, expr.xreplace({s: v for s, v in op.items()
                                                     if s not in ranged}))
            columns = [np.array(col, dtype=float) for col in zip(*corners)]
            with np.errstate(all="ignore"):    # numpy: a division by 0 is inf, not raised
                values = np.broadcast_to(np.asarray(fn(*columns), dtype=complex),
                                         (len(corners),))
        except (TypeError, ValueError, ZeroDivisionError, OverflowError):
            continue
        bad = [c for c, v in zip(corners, values)
               if not (np.isfinite(v.real) and abs(v.imag) <= 1e-12 * max(1, abs(v.real)))]
        if bad:
            corner = ", ".join(f"{s} = {v:g}" for s, v in zip(syms, bad[0]))
            out.append(f"{label} is not a finite real number at {corner} (a corner of the "
                       f"declared ranges; {len(bad)} of {len(corners)} corners): a division "
                       "by zero, a sqrt or log of a negative number, or an overflow there; "
                       "guard it "
                       "(max(G, 1e-3), max(h, 0)) or narrow the range, or the simulation "
                       "and the filters stop where the plant goes")
    return tuple(out)


def parameter_bound_warnings(design) -> tuple:
    """Each parameter whose declared ``bounds`` reach a value where a state equation or
    output is not a finite real number at the operating point (a division by it), with
    the bound and the equation.

    The bounds are what the generated C's parameter check accepts: a motor's inductance
    with bounds [0, 1] was accepted at 0 by ``<m>_init`` (status OK), its filters' state
    was NaN from the first sample and a healthy log ended in ``safety_stop`` (attack
    round 13); ``inspect`` said nothing.
    """
    import numpy as np
    import sympy as sp

    model = design.model
    point = {s.symbol: float(model.operating_point[s.name])
             for s in (*model.states, *model.inputs)}
    exprs = [(f"d{s.name}/dt", e) for s, e in zip(model.states, model.f())]
    exprs += [(f"output {o.name}", e) for o, e in zip(model.outputs, model.h())]
    values = dict(model.parameter_values)
    out = []
    for q in model.parameters:
        if q.bounds is None:
            continue
        for bound in (float(q.bounds[0]), float(q.bounds[1])):
            at = {**values, q.symbol: sp.Float(bound)}
            for label, expr in exprs:
                if q.symbol not in expr.free_symbols:
                    continue
                try:
                    v = complex(sp.sympify(expr).xreplace(at).xreplace(point).evalf())
                    ok = np.isfinite(v.real) and abs(v.imag) <= 1e-12 * max(1, abs(v.real))
                except (TypeError, ValueError, ZeroDivisionError, OverflowError):
                    ok = False
                if not ok:
                    out.append(f"parameter {q.name}'s bounds [{q.bounds[0]:g}, "
                               f"{q.bounds[1]:g}] reach {bound:g}, where {label} is not a "
                               "finite real number at the operating point (a division by "
                               "it, or a root or log of a negative number): the generated "
                               "C's parameter check accepts that value, and the core's "
                               "state is then NaN from the first sample; narrow the bounds "
                               "to what the parameter can be")
                    break
            else:
                continue
            break
    return tuple(out)


def unread_sensor_warnings(design) -> tuple:
    """A warning naming the outputs no residual compares, is driven by, or votes on:
    their only watch is the validity flag ``nf_<y>`` (NaN or out of range). A user's
    coolant loop measured its return temperature and no residual read it, said nowhere;
    a residual on it adds sensitivity to what moves it (``[fdi.kalman]`` or
    ``[fdi.parity]``), or the sensor is not needed."""
    import re

    cfg = design.config
    validity = {f"nf_{o.name}" for o in design.model.outputs}
    if all(n in validity for n in design.evaluation.residuals):
        return ()           # no residual at all: detection_warnings says so
    texts = [*cfg.parity.values(), *(m for k in cfg.kalman for m in k.measurement)]
    for e in design.extra_residuals:
        texts.append(str(e.get("check") or ""))
        texts.extend(str(v) for v in (e.get("drivers") or {}).values())
    if cfg.voter is not None:
        texts.extend(cfg.voter.channels)
    words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", " ".join(texts)))
    unread = [o.name for o in design.model.outputs if o.name not in words]
    if not unread:
        return ()
    return (f"no residual reads sensor{'s' if len(unread) > 1 else ''} {', '.join(unread)} "
            "(only the validity flag nf_* watches it: NaN or out of range): a fault of "
            "what it measures shows in it only if a residual compares it; declare one "
            "([fdi.kalman] measurement or [fdi.parity]), or it is not needed",)


def idle_fault_warnings(design) -> tuple:
    """A warning naming the faults with no first-order effect at the operating point that
    only Kalman residuals watch, or nothing.

    A multiplicative fault on a quantity that is zero there (an actuator gain at
    ``u = 0``, a damper at rest) has every derivative
    :math:`\\partial f/\\partial \\phi`, :math:`\\partial h/\\partial \\phi` zero at the
    point, where the linearised analysis is taken: the filters' signatures, what a filter
    sees once settled (:mod:`fdigen.design.settled_response`) and the sensitivities are
    silent about it, and nothing said so (a user's quarter car: the warning that a
    constant actuator-gain loss is seen only while the filter settles came with the
    operating point at ``u = 1 V`` and vanished at ``u = 0``; the campaign detected the
    loss in 0 of 4 runs either way)."""
    import sympy as sp

    model = design.model
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name]
                  for s in (*model.states, *model.inputs)})
    point.update({f.symbol: 0 for f in model.faults})
    names = {s.symbol: s.name for s in (*model.states, *model.inputs)}
    exprs = [*model.f(with_faults=True), *model.h(with_faults=True)]
    # residuals the linear analysis stands for: the Kalman filters' (a parity residual's
    # parallel model runs the nonlinear equations: a valve fault at v = 0 is seen as soon
    # as the valve moves, as on the cylinder)
    linear = {kr.residual for kr in design.kalman}
    idle = []
    for fault in model.faults:
        if not design.signature_table.get(fault.name, set()) <= linear:
            continue
        slopes = [d for d in (sp.diff(e, fault.symbol) for e in exprs) if d != 0]
        if not slopes:
            continue                       # no effect anywhere: detection_warnings
        try:
            values = [complex(sp.sympify(d.xreplace(point)).evalf()) for d in slopes]
        except (TypeError, ValueError):
            continue
        if any(v != 0 for v in values):
            continue
        zero = sorted({names[s] for d in slopes for s in d.free_symbols
                       if s in names and point[s] == 0})
        idle.append(f"{fault.name} (its terms read {', '.join(zero)} = 0 there)" if zero
                    else f"{fault.name} (its terms cancel there)")
    if not idle:
        return ()
    return (f"no first-order effect at the operating point: {'; '.join(idle)}. The "
            "linearised analysis is taken there (the filters' signatures, what a filter "
            "sees once settled, the sensitivities) and rates nothing of these faults; "
            "whether a residual flags them rests on how far the plant moves from that "
            "point. `fdigen tune` measures it; an [operating_point] where they act lets "
            "the linear analysis rate them",)


def linear_driver_warnings(design) -> tuple:
    """A warning naming the Kalman residuals that read a driver (a measured state the
    sub-model takes as an input) through a nonlinearity of ``f`` and still predict with
    the linearisation at the operating point, or nothing.

    A fault that moves the driver across its range moves such a residual outside the
    fault's signature: a user's hydraulic press had a chamber leak isolated as the valve
    spool (the accumulator filter, driven by the chamber pressure through
    ``Kv u sqrt(p_acc - p_A)``, flagged at 89 bar and 8 V, both inside the declared
    ranges); with ``[fdi] nonlinear_drivers = true`` the filter predicts through ``f`` and
    the leak stayed "leak or spool"."""
    from fdigen.design.nonlinear_prediction import nonlinear_reason

    if design.config.nonlinear_drivers:
        return ()
    named = []
    for kr in design.kalman:
        if kr.schedule == "nonlinear" or not kr.drivers:
            continue
        try:
            reason = nonlinear_reason(kr.model, kr.reduction.T, tuple(kr.drivers.values()))
        except Exception:  # noqa: BLE001 - a diagnostic never breaks a design's report
            continue
        if reason is not None:
            named.append(f"{kr.residual} (driven by {', '.join(sorted(kr.drivers))})")
    if not named:
        return ()
    return ("Kalman residuals whose drivers enter the dynamics through a nonlinearity, "
            "predicted with the linearisation at the operating point: "
            + "; ".join(named) + ". A fault that takes the plant away from that point "
            "(its inputs, the drivers or the filter's own states: the press's leak moved "
            "the valve command from 2.2 to 8 V and the accumulator from 100 to 89 bar) "
            "can raise them outside the fault's signature and complete a wrong class; "
            "[fdi] nonlinear_drivers = true predicts through the model's own equations "
            "(`fdigen tune` then measures its thresholds)",)
