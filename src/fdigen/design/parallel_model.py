"""The nonlinear parallel model (RK4) behind the parity residuals.

Holds the stability check of its step (:func:`rk4_amplification`,
:func:`check_parallel_model_step`), the steady-state gain re-aligning it on the
measurements (:func:`realignment_gain`), and its program: :func:`parallel_block`
(compare, re-align, propagate), built from :func:`rk4_step` (one classical Runge-Kutta step
as named assignments) and :func:`clamp_to_limits` (the states' physical limits).
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.derive import precise
from fdigen.derive.kalman import discrete_kalman_gain
from fdigen.derive.linearisation import (LinearModel, discretise_noise, discretise_zoh,
                                         linearise, numeric)
from fdigen.derive.observability import observable_reduction
from fdigen.derive.riccati import state_scales
from fdigen.derive.rk4_stability import (linearised_modes, rk4_amplification,  # noqa: F401
                                         unstable_mode)
from fdigen.design.config import FdiConfig
from fdigen.design.derived_parameters import rational_form
from fdigen.design.symbolic import double, real_symbol
from fdigen.errors import DesignError
from fdigen.model.model import Model


def check_parallel_model_step(model: Model, cfg: FdiConfig) -> None:
    """Refuse a design whose RK4 parallel model is numerically unstable at its step.

    The linearisation's eigenvalues ``lambda`` are evaluated at the operating point and at
    each end of every state's declared ``range`` (one state at a time); with
    ``h = sample_time / substeps`` every mode must satisfy
    ``|R(lambda h)| <= max(1, |e^{lambda h}|)`` (:func:`rk4_amplification`), i.e. RK4 may
    not amplify a mode the plant damps. A stiff model (small mass, small dead volume...)
    at a long step otherwise makes the parallel model, and every residual, diverge.
    The analysis is :mod:`fdigen.derive.rk4_stability`'s, shared with the plant simulator.

    Raises
    ------
    DesignError
        Naming the mode, the point and the number of sub-steps that would be stable.
    """
    mode = unstable_mode(linearised_modes(model), cfg.sample_time, cfg.substeps)
    if mode is None:
        return
    raise DesignError(
        f"{model.source}: fdi.substeps: the RK4 parallel model is unstable at step "
        f"{mode.step:g} s: the linearised mode {mode.lam:.4g} 1/s at {mode.where()} gives "
        f"|R(lambda h)| = {mode.amplification:.3g} > 1; "
        f"use substeps >= {mode.need} (or a shorter sample_time), or check the parameters")


def realignment_gain(model: Model, cfg: FdiConfig, outputs=None):
    """Filter gain ``M`` re-aligning the parallel model on parity outputs.

    A steady-state Kalman gain of the full linearised model measured by ``outputs``
    (default: every parity output), with process noise ``eps^2 Q``
    (``eps = realign_noise_scale``): a low bandwidth that removes slow drift (the
    adiabatic model's common-mode pressure, valve and friction tolerances) while faults,
    much faster, still show in the residuals.
    """
    outputs = tuple(cfg.parity.values()) if outputs is None else tuple(outputs)
    n, p = len(model.states), len(outputs)
    if cfg.realign_noise_scale == 0 or p == 0:
        return np.zeros((n, p)), None
    lin = linearise(model)
    idx = [model.output_index(o) for o in outputs]
    disc = discretise_zoh(lin, cfg.sample_time)
    C = lin.C[idx, :]
    Qc = np.diag([cfg.process_noise[s.name] ** 2 for s in model.states])
    Qd = discretise_noise(lin.A, Qc, cfg.sample_time) * cfg.realign_noise_scale ** 2
    Rd = np.diag([model.outputs[i].noise_std ** 2 for i in idx])
    gain = discrete_kalman_gain(disc.A, C, Qd, Rd, "parallel model realignment",
                                state_scales(model.states))
    return gain.M, gain


def parity_realignment(model: Model, cfg: FdiConfig):
    """The parity residuals' parallel models and their realignment gains.

    ``cfg.realign == "shared"``: one parallel model re-aligned on every parity output,
    ``[(residuals, M, gain)]`` with ``M`` of shape ``(n, p)``. ``"dedicated"``: one
    parallel model per parity residual ``R_i = y_i - h_i(\\hat x_i)``, re-aligned on
    ``y_i`` alone,

    .. math:: \\hat x_i^+ = \\mathrm{RK4}(f(\\hat x_i + g M_i r_i, u)),

    ``M_i`` the steady-state Kalman gain of the linearised model measured by ``y_i`` only
    (:func:`realignment_gain` with ``outputs = (y_i,)``). ``R_i`` then reads the inputs and
    ``y_i`` and no other measurement: its structural support is the model's equations and
    ``y_i``'s sensor equation, exactly what its derived signature
    (:func:`fdigen.design.signatures.structural_signature` of ``(y_i,)``) assumes. A
    sensor ``y_i`` that cannot re-align the model (the pair ``(A, C_i)`` not detectable)
    leaves ``R_i``'s model open loop (``M_i = 0``) rather than borrow another sensor.

    Returns
    -------
    list of (tuple of str, ndarray, KalmanGain or None)
        Per parallel model: the parity residuals it checks, its gain, its Kalman design.
    """
    names = tuple(cfg.parity)
    if cfg.realign == "shared" or len(names) <= 1:
        M, gain = realignment_gain(model, cfg)
        return [(names, M, gain)]
    out = []
    for rname, oname in cfg.parity.items():
        try:
            M, gain = realignment_gain(model, cfg, (oname,))
        except DesignError:
            M, gain = observable_realignment_gain(model, cfg, oname)
        out.append(((rname,), M, gain))
    return out


def observable_realignment_gain(model: Model, cfg: FdiConfig, output: str):
    """Realignment gain on one output whose full pair ``(A, C_i)`` is not detectable.

    The gain is designed on the part observable from ``output``
    (:func:`fdigen.derive.observability.observable_reduction`, ``z = T x``, ``T A = A_r T``,
    ``C_i = C_r T``) and lifted by the pseudo-inverse, ``M = T^+ M_r = T^T (T T^T)^{-1} M_r`` (so ``T M = M_r``:
    the observable coordinates are corrected as the reduced filter would, the unobservable
    ones, which ``y_i`` cannot see, not at all). Returns ``(M, None)`` with ``M = 0`` when
    the reduced pair has no stabilising gain either.
    """
    n = len(model.states)
    try:
        red = observable_reduction(model, (output,))
        T = red.T_num
        disc = discretise_zoh(LinearModel(red.A_num, red.B_num, red.C_num,
                                          np.zeros((red.C_num.shape[0], red.B_num.shape[1])),
                                          red.E_num, np.zeros((red.C_num.shape[0], 0)),
                                          T @ linearise(model).x0, linearise(model).u0,
                                          np.zeros(0)), cfg.sample_time)
        Qc = T @ np.diag([cfg.process_noise[s.name] ** 2 for s in model.states]) @ T.T
        Qd = discretise_noise(red.A_num, Qc, cfg.sample_time) * cfg.realign_noise_scale ** 2
        Rd = np.array([[model.output(output).noise_std ** 2]])
        gain = discrete_kalman_gain(disc.A, disc.C, Qd, Rd,
                                    f"parallel model realignment on {output}",
                                    state_scales(model.states, T))
    except (DesignError, ValueError, np.linalg.LinAlgError):
        return np.zeros((n, 1)), None
    # T^+ M_r = T^T (T T^T)^{-1} M_r, in extended precision (derive.precise): the
    # chamber pressures' gains of the cylinder, opposite by symmetry, stay exactly opposite
    return precise.matmul(T.T, precise.solve(precise.matmul(T, T.T), gain.M)), None


def parity_block_prefix(index: int, residuals) -> str:
    """Name prefix of the ``index``-th parity parallel model (``par`` for the first, whose
    states also stand in for invalid samples; ``par_<residual>`` for the others)."""
    return "par" if index == 0 else f"par_{residuals[0]}"


def parallel_block(assign, model, prefix, checks, realign_M, gate, drivers, dt, substeps,
                    residual, derived, held=None, hold_samples: int = 1):
    r"""A nonlinear parallel model (RK4) of ``model``, compared with measurements.

    ``checks`` lists ``(residual name, measured expression, predicted expression of the
    model's states)``; the residuals are ``measured - predicted`` before the update. The
    state is re-aligned by ``x += gate * M r`` and then propagated by RK4 sub-steps with
    the inputs (and the measured ``drivers``) held, and clamped to its physical limits.
    Each state derivative is evaluated in the form of :func:`rational_form` (one division
    per derivative, parameter-only coefficients from ``derived``).
    Returns the state names and the next-state symbols.

    With ``held`` (a list, extended with ``(state name, next state)`` pairs) the block
    also keeps the mean of each state's correction, ``c_i = (M r)_i``, over the last
    ``hold_samples`` samples (an exponential average, ``a = 1/N_h``) while it is
    re-aligned, and applies it held once frozen:

    .. math:: x_i \leftarrow x_i + g\,c_i + (1 - g)\,\bar c_i,\qquad
              \bar c_i^+ = \bar c_i + g\,a\,(c_i - \bar c_i)

    Before the freeze (``g = 1``) the block is the one above, bit for bit; after it, the
    correction that balanced the model's parameter error keeps balancing it, so the
    frozen model drifts only as the plant leaves the operating point it was balanced at.
    What the realignment absorbed of a fault between its onset and the first flag enters
    the average too, in the proportion of that delay to ``N_h``: a long average (the
    caller's ``N_h`` is ten RMS windows) keeps it small, and a drift detected late is
    partly held (it then shows only as it grows after the freeze).
    """
    xs = [real_symbol(f"{prefix}_{s.name}") for s in model.states]
    state_syms = list(model.x)
    to_block = dict(zip(state_syms, xs))
    to_block.update(drivers)
    res = []
    for rname, measured, predicted in checks:
        res.append(assign(f"r_{rname}", measured - predicted.xreplace(to_block)))
        residual[rname] = res[-1]
    xc = list(xs)
    if np.any(realign_M):
        for i in range(len(xs)):
            corr = sum((double(realign_M[i, j]) * res[j] for j in range(len(res))
                        if realign_M[i, j] != 0), sp.Integer(0))
            if corr == 0:
                continue
            if held is None:
                xc[i] = assign(f"{prefix}c_{model.states[i].name}", xs[i] + gate * corr)
                continue
            c = assign(f"{prefix}d_{model.states[i].name}", corr)
            mean = real_symbol(f"{prefix}_hc_{model.states[i].name}")
            xc[i] = assign(f"{prefix}c_{model.states[i].name}",
                           xs[i] + gate * c + (1 - gate) * mean)
            held.append((f"{prefix}_hc_{model.states[i].name}",
                         assign(f"{prefix}_hc_next_{model.states[i].name}",
                                mean + gate * double(1.0 / hold_samples) * (c - mean))))
    f_expr = [rational_form(e, set(model.p), derived) for e in model.f().xreplace(drivers)]
    h = dt / substeps
    for step in range(substeps):
        xc = rk4_step(assign, f_expr, state_syms, xc, h, f"{prefix}{step}_", model)
        xc = clamp_to_limits(assign, xc, model, f"{prefix}{step}_lim_")
    return [f"{prefix}_{s.name}" for s in model.states], list(xc)


def clamp_to_limits(assign, x, model, tag):
    """Clamp states with physical limits: ``min(max(x, low), high)``."""
    out = []
    for xi, s in zip(x, model.states):
        if s.limits is None:
            out.append(xi)
        else:
            lo, hi = s.limits
            out.append(assign(f"{tag}{s.name}", sp.Min(sp.Max(xi, lo), hi)))
    return out


def rk4_step(assign, f_expr, state_syms, x, h, tag, model):
    """One classical Runge-Kutta step of ``dx/dt = f(x, u)`` as named assignments.

    .. math::

        k_1 = f(x),\\ k_2 = f(x + \\tfrac{h}{2}k_1),\\ k_3 = f(x + \\tfrac{h}{2}k_2),\\
        k_4 = f(x + h k_3),\\ x^+ = x + \\tfrac{h}{6}(k_1 + 2k_2 + 2k_3 + k_4)
    """
    names = [s.name for s in model.states]

    def stage(point, label):
        sub = dict(zip(state_syms, point))
        return [assign(f"{tag}{label}_{names[i]}", f_expr[i].xreplace(sub))
                for i in range(len(point))]

    hh = double(h)
    half = double(h / 2)
    k1 = stage(x, "k1")
    x2 = [assign(f"{tag}x2_{names[i]}", x[i] + half * k1[i]) for i in range(len(x))]
    k2 = stage(x2, "k2")
    x3 = [assign(f"{tag}x3_{names[i]}", x[i] + half * k2[i]) for i in range(len(x))]
    k3 = stage(x3, "k3")
    x4 = [assign(f"{tag}x4_{names[i]}", x[i] + hh * k3[i]) for i in range(len(x))]
    k4 = stage(x4, "k4")
    sixth = double(h / 6)
    # k1 + 2 (k2 + k3) + k4 as named steps: sympy would distribute the numeric factors
    # (h/6 k1 + h/3 k2 + h/3 k3 + h/6 k4: four products where two suffice)
    mid = [assign(f"{tag}k23_{names[i]}", k2[i] + k3[i]) for i in range(len(x))]
    total = [assign(f"{tag}ksum_{names[i]}", k1[i] + 2 * mid[i] + k4[i]) for i in range(len(x))]
    return [assign(f"{tag}next_{names[i]}", x[i] + sixth * total[i]) for i in range(len(x))]
