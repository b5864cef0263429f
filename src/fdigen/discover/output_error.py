"""Output-error calibration over a whole log: simulation from estimated initial states.

What is minimised
-----------------
The model (with any library effects switched on) is simulated from initial states
``x0`` (hidden states included) driven by the measured inputs, held over each sample,
RK4 with ``n_sub`` sub-steps, states clamped to their limits:

.. math::

    \\hat\\theta, \\hat x_0 = \\arg\\min \\; \\frac12 \\sum_k \\sum_j
    \\left(\\frac{y_j[k] - h_j(x(t_k; \\theta, x_0), u[k], \\theta)}{\\sigma_j}\\right)^2
    + \\frac12 \\sum_i \\left(\\frac{\\theta_i - \\theta_i^{0}}{\\theta_i^{0}}\\right)^2

over the parameters' bounds and the states' limits. The second term is a weak prior (one
datasheet value per standard deviation): it decides only the directions the log cannot
(a hidden state's scale), which :func:`identifiability` reports. Solved by **multiple
shooting** (Bock): the log is cut into segments, each starts from its own state node,
continuity of the nodes is an equality constraint, CasADi's ``nlpsol`` with IPOPT and
exact derivatives. Multiple shooting keeps a long or stiff log well conditioned; at the
solution the trajectory is one continuous free-run simulation.

``sigma_j`` is the output's noise level (the model file's ``noise_std``, else from the
log's successive differences). The reported error is always the **free-run** RMS: the
model simulated once over the whole log from its estimated initial state, never
re-initialised.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from fdigen.discover.gauss_newton import GAUSS_NEWTON_ITERATIONS, gauss_newton_hessian
from fdigen.discover.noise import noise_level
from fdigen.discover.sensitivity import (null_directions, parameter_deviations,
                                         sensitivity)
from fdigen.errors import FdigenError

__all__ = ["OutputErrorModel", "OutputErrorFit", "build_model", "simulate", "noise_level",
           "initial_state", "fit_output_error", "check_length", "null_directions"]


@dataclass
class OutputErrorModel:
    """A model (and effects) as CasADi functions for simulation and fitting.

    Attributes
    ----------
    names : list of str
        Parameter names, in the order of the parameter vector.
    values : dict
        Default value of every parameter (effects' at their nominal size).
    step : casadi.Function
        ``(x, u, p) -> x_next``: one sample, RK4 with ``n_sub`` sub-steps, clamped.
    out : casadi.Function
        ``(x, u, p) -> y``.
    lo, hi : numpy.ndarray
        State limits used by the clamp.
    """

    names: list
    values: dict
    step: ca.Function
    out: ca.Function
    lo: np.ndarray
    hi: np.ndarray
    n_sub: int
    dt: float
    nx: int = 0
    ny: int = 0


def _limits(model):
    lo, hi = [], []
    pv = model.parameter_values
    for s in model.states:
        # no limits: a quantity whose range is non-negative stays non-negative
        a = 0.0 if s.range and float(s.range[0]) >= 0 else -np.inf
        b = np.inf
        if s.limits:
            a, b = (_num(v, pv) for v in s.limits)
        lo.append(a)
        hi.append(b)
    lo, hi = np.array(lo, float), np.array(hi, float)
    lo, hi = np.where(np.isnan(lo), -np.inf, lo), np.where(np.isnan(hi), np.inf, hi)
    # sqrt at a hard zero has an infinite slope: keep the clamp a hair above it
    lo = np.where(lo == 0.0, 1e-9, lo)
    return lo, hi


def _num(v, pv):
    """A limit as a number (a limit may name parameters: ``"Hmax"``)."""
    try:
        return float(v.xreplace(pv)) if hasattr(v, "xreplace") else float(v)
    except (TypeError, ValueError):
        return float("nan")


def build_model(model, effects=(), dt: float = 1.0, n_sub: int = 2) -> OutputErrorModel:
    """CasADi step and output functions of ``model`` plus ``effects``.

    Parameters
    ----------
    model : fdigen.model.model.Model
    effects : sequence of LibraryEffect
    dt : float
        Sample time [s] (inputs held over it).
    n_sub : int
        RK4 sub-steps per sample.
    """
    import sympy as sp

    from fdigen.backends.casadi_backend.convert import sympy_to_casadi

    f = list(model.f())
    h = list(model.h())
    extra = []
    for e in effects:
        for target, term in e.terms(model).items():
            term = model.expand(term)
            if target in {s.name for s in model.states}:
                k = model.state_index(target)
                f[k] = f[k] + term
            else:
                k = model.output_index(target)
                h[k] = h[k] + term
        extra.extend(e.parameters)
    names = [q.name for q in model.parameters] + [p.name for p in extra]
    values = {q.name: float(q.value) for q in model.parameters}
    values.update({p.name: float(p.nominal) for p in extra})
    nx, nu, nq = len(model.states), len(model.inputs), len(names)
    X, U, P = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("p", nq)
    mapping = {s.symbol: X[i] for i, s in enumerate(model.states)}
    mapping.update({s.symbol: U[i] for i, s in enumerate(model.inputs)})
    mapping.update({sp.Symbol(n, real=True): P[i] for i, n in enumerate(names)})
    for q in model.parameters:
        mapping[q.symbol] = P[names.index(q.name)]
    memo = {}
    fx = ca.vertcat(*[sympy_to_casadi(e, mapping, memo=memo) for e in f])
    hx = ca.vertcat(*[sympy_to_casadi(e, mapping, memo=memo) for e in h])
    lo, hi = _limits(model)
    fun = ca.Function("f", [X, U, P], [fx])
    clamp = (lambda z: ca.fmin(ca.fmax(z, ca.DM(lo)), ca.DM(hi)))
    h_sub = dt / n_sub
    z = X
    for _ in range(n_sub):
        k1 = fun(clamp(z), U, P)
        k2 = fun(clamp(z + h_sub / 2 * k1), U, P)
        k3 = fun(clamp(z + h_sub / 2 * k2), U, P)
        k4 = fun(clamp(z + h_sub * k3), U, P)
        z = clamp(z + h_sub / 6 * (k1 + 2 * k2 + 2 * k3 + k4))
    step = ca.Function("step", [X, U, P], [z])
    out = ca.Function("out", [X, U, P], [hx])
    return OutputErrorModel(names, values, step, out, lo, hi, n_sub, dt, nx, len(h))


def simulate(om: OutputErrorModel, x0, u, params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Free-run simulation: states (K, nx) and outputs (K, ny) from ``x0`` at sample 0."""
    p = np.array([float(params.get(n, om.values[n])) for n in om.names])
    u = np.asarray(u, float)
    K = len(u)
    sim = om.step.mapaccum(K - 1)
    xs = np.asarray(sim(np.asarray(x0, float), u[:-1].T, np.tile(p[:, None], (1, K - 1))))
    X = np.column_stack([np.asarray(x0, float), xs]).T
    Y = np.asarray(om.out.map(K)(X.T, u.T, np.tile(p[:, None], (1, K)))).T
    return X, Y


@dataclass
class OutputErrorFit:
    """Result of :func:`fit_output_error`.

    Attributes
    ----------
    params : dict
        Every parameter value (free ones estimated).
    free : list of str
    x0 : numpy.ndarray
        Estimated initial state.
    Y : numpy.ndarray
        Free-run simulated outputs (K, ny).
    rms : numpy.ndarray
        Free-run RMS error per output.
    sse : float
        Sum of squared output errors (unweighted, all outputs).
    n : int
        Number of output samples.
    J : numpy.ndarray
        Jacobian of the free-run outputs w.r.t. ``log`` of the free parameters (columns)
        and the initial state (last ``nx`` columns), weighted by ``1/sigma``.
    """

    params: dict
    free: list
    x0: np.ndarray
    Y: np.ndarray
    rms: np.ndarray
    sse: float
    n: int
    std: dict = field(default_factory=dict)
    conditional_std: dict = field(default_factory=dict)
    J: np.ndarray = field(default=None, repr=False)
    success: bool = True
    effects: tuple = ()
    held: dict = field(default_factory=dict)
    null_directions: list = field(default_factory=list)


def initial_state(model, om: OutputErrorModel, u, y, params) -> np.ndarray:
    """A start for ``x0``: measured states from the first samples, hidden states at the
    steady state of the first input with the measured ones held (scipy root search)."""
    from scipy.optimize import least_squares

    from fdigen.discover.locate import measured_states, state_values

    meas = measured_states(model)
    x = np.array([0.5 * (a + b) if np.isfinite(a) and np.isfinite(b) else 1.0
                  for a, b in zip(om.lo, om.hi)])
    for s in model.states:
        if s.range:
            i = model.state_index(s.name)
            x[i] = 0.5 * (float(s.range[0]) + float(s.range[1]))
    for i, js in meas.items():   # through the sensors' inverse maps (y = kc*x: volts)
        x[i] = float(np.mean(state_values(model, js, np.asarray(y)[:3])))
    hidden = [i for i in range(om.nx) if i not in meas]
    if hidden:
        p = np.array([float(params.get(n, om.values[n])) for n in om.names])
        u0 = np.asarray(u, float)[: max(3, len(u) // 20)].mean(axis=0)

        def resid(z):
            xx = x.copy()
            xx[hidden] = z
            nxt = np.asarray(om.step(xx, u0, p)).ravel()
            return (nxt - xx)[hidden] / om.dt

        lo = np.maximum(om.lo[hidden], 1e-9)
        hi = om.hi[hidden]
        z0 = np.clip(x[hidden], lo + 1e-6, np.where(np.isfinite(hi), hi - 1e-6, np.inf))
        try:
            sol = least_squares(resid, z0, bounds=(lo, hi))
            x[hidden] = sol.x
        except ValueError:
            pass
    return np.clip(x, om.lo, om.hi)


#: Largest ``|lambda| h`` of an RK4 sub-step in the output-error simulation: the one-step
#: error of RK4 there is 4e-4 of the mode's own decay (R(-0.5) = 0.60677, e^-0.5 = 0.60653).
ACCURATE_STEP = 0.5


def accurate_substeps(model, dt: float, cap: int = 64) -> int:
    r"""RK4 sub-steps per sample that integrate the model *accurately*, not just stably.

    .. math:: N = \min(\max(\lceil \lambda_{max}\, dt / 0.5 \rceil, 2), 64)

    with ``lambda_max`` the largest ``|eig(df/dx)|`` at the operating point and each end
    of every state's range (:func:`fdigen.derive.rk4_stability.linearised_modes`). With a
    fixed 2 sub-steps a DC motor's electrical mode (``Ra/La`` = 400 1/s) at 10 ms ran at
    ``lambda h = 2``: stable, 2.5x off its decay per sub-step, and that discretisation error
    was what a library effect (a dead band) then "explained" on a healthy log.
    """
    from fdigen.derive.rk4_stability import linearised_modes

    lam = max((abs(v) for m in linearised_modes(model).modes for v in m), default=0.0)
    if not np.isfinite(lam):
        return 2
    return int(min(max(int(np.ceil(lam * dt / ACCURATE_STEP)), 2), cap))


def fit_output_error(model, t, u, y, free, bounds: dict, *, effects=(), start=None,
                     sigma=None, segment: int | None = None, n_sub: int | None = None,
                     max_iter: int = 300, hold: dict | None = None,
                     report: bool = True, restart_if=None) -> OutputErrorFit:
    """Fit ``free`` parameters and the initial state by output error (multiple shooting).

    Parameters
    ----------
    model : Model
    t, u, y : numpy.ndarray
        The log: time (K,), inputs (K, nu), outputs (K, ny).
    free : sequence of str
        Parameters to estimate (model and effect parameters).
    bounds : dict
        Name -> (low, high); every free parameter must have finite positive-width bounds.
    effects : sequence of LibraryEffect
    start : dict, optional
        Starting values (default: the model's and the effects' nominal values).
    sigma : numpy.ndarray, optional
        Noise level per output (default :func:`noise_level`).
    segment : int, optional
        Samples per shooting segment (default ``max(16, K // 16)``).
    n_sub : int, optional
        RK4 sub-steps per sample (default :func:`accurate_substeps`).
    hold : dict, optional
        Parameters to hold (name -> value) instead of searching the base model's blind
        directions (pass a previous fit's ``held``).
    report : bool
        Compute the sensitivity, intervals and blind directions of the result.
    restart_if : callable, optional
        ``restart_if(sse)``, with ``sse`` the free-run sum of squares where a stalled
        Gauss-Newton phase stopped: restart with the exact Hessian only when it returns
        True (default: always). A screening fit restarts only a candidate that already
        improves the fit: the exact Hessian's second derivatives through every simulated
        step cost several times a Gauss-Newton iteration on a long log.
    """
    t = np.asarray(t, float)
    if n_sub is None:
        n_sub = accurate_substeps(model, float(np.median(np.diff(np.asarray(t, float)))))
    u = np.atleast_2d(np.asarray(u, float))
    y = np.atleast_2d(np.asarray(y, float))
    K = len(t)
    dt = float(np.median(np.diff(t)))
    om = build_model(model, effects, dt, n_sub)
    vals = dict(om.values)
    vals.update(start or {})
    free = list(free)
    sig = np.asarray(sigma if sigma is not None else noise_level(y), float)
    p0 = np.array([vals[n] for n in free])
    ref = np.where(np.abs(p0) > 0, np.abs(p0), 1.0)
    lo = np.array([bounds[n][0] for n in free], float)
    hi = np.array([bounds[n][1] for n in free], float)
    p0 = np.clip(p0, lo, hi)
    x0 = initial_state(model, om, u, y, vals)
    # the base model's blind directions (a hidden state's scale) at the start; effect
    # parameters are left out: an effect not yet active at the start is blind too
    own = [n for n in free if n in {q.name for q in model.parameters}]
    held, nulls = {}, []
    if hold is None:
        base = build_model(model, (), dt, n_sub) if effects else om
        nulls = null_directions(sensitivity(base, x0, u, vals, own, sig), own, om.nx)
    else:
        held = {n: vals[n] for n in hold if n in free}
    for d in nulls:  # hold the parameter that moves most along a direction the log
        cand = [n for n in free if n in d and n not in held]  # model parameters first
        top = max((abs(d[n]) for n in cand), default=0.0)
        name = next((n for n in cand if abs(d[n]) >= 0.99 * top), None)
        if name is not None:
            held[name] = vals[name]
    if held:
        keep = [i for i, n in enumerate(free) if n not in held]
        free, p0, ref, lo, hi = ([free[i] for i in keep], p0[keep], ref[keep], lo[keep],
                                 hi[keep])
    L = int(segment or max(16, K // 16))
    starts = list(range(0, K - 1, L))
    # single-shooting simulation as the start of every node (a continuous trajectory)
    Xs, _ = simulate(om, x0, u, vals)
    xscale = np.array([max(np.nanmax(np.abs(Xs[:, i])), 1e-6) for i in range(om.nx)])

    q = ca.MX.sym("q", len(free))
    nodes = [ca.MX.sym(f"s{k}", om.nx) for k in range(len(starts))]
    pfull = []
    for n in om.names:
        pfull.append(q[free.index(n)] * ref[free.index(n)] if n in free else vals[n])
    pvec = ca.vertcat(*pfull)
    cost, g, weighted = 0, [], []
    for k, a in enumerate(starts):
        b = min(a + L, K - 1)
        n = b - a
        xs = om.step.mapaccum(n)(nodes[k] * xscale, u[a:b].T, ca.repmat(pvec, 1, n))
        traj = ca.horzcat(nodes[k] * xscale, xs)  # samples a..b
        upto = n + 1 if b == K - 1 else n  # the node of the next segment owns sample b
        yh = om.out.map(upto)(traj[:, :upto], u[a:a + upto].T, ca.repmat(pvec, 1, upto))
        r = (ca.DM(y[a:a + upto].T) - yh) / ca.DM(np.tile(sig[:, None], (1, upto)))
        cost = cost + 0.5 * ca.sumsqr(r)
        weighted.append(ca.vec(r))
        if k + 1 < len(starts):
            g.append(xs[:, -1] / xscale - nodes[k + 1])
    deviation = q - ca.DM(np.array([vals[n] for n in free]) / ref)
    prior = 0.5 * ca.sumsqr(deviation)
    w = ca.vertcat(q, *nodes)
    nlp = {"x": w, "f": cost + prior, "g": ca.vertcat(*g) if g else ca.MX(0, 1)}
    # show_eval_warnings off: a trial point where the model is not real ("nlp_g failed:
    # NaN detected") is IPOPT's to step back from, not the user's to read (a user's ball
    # screw printed it ten times on the terminal)
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.max_iter": max_iter,
            "ipopt.tol": 1e-6, "ipopt.sb": "yes", "show_eval_warnings": False}
    w0 = np.concatenate([p0 / ref] + [Xs[a] / xscale for a in starts])
    slo, shi = om.lo / xscale, om.hi / xscale
    lbw = np.concatenate([lo / ref] + [slo] * len(starts))
    ubw = np.concatenate([hi / ref] + [shi] * len(starts))
    ng = om.nx * (len(starts) - 1)
    bounds_ = {"lbx": lbw, "ubx": ubw, "lbg": np.zeros(ng), "ubg": np.zeros(ng)}
    # Gauss-Newton first (first derivatives only); where it stalls (a large or
    # non-smooth misfit: a saturation, an overflow), the exact Hessian from the same
    # start (from where Gauss-Newton stopped it took longer: 13 min for one candidate
    # on a 6000-sample log)
    solver = ca.nlpsol("oe_gn", "ipopt", nlp, {
        **opts, "ipopt.max_iter": min(max_iter, GAUSS_NEWTON_ITERATIONS),
        "hess_lag": gauss_newton_hessian(ca.vertcat(*weighted, deviation), w, ng)})
    sol = solver(x0=w0, **bounds_)
    ok = solver.stats().get("success", False)
    # the solver's point: parameters, initial state, and its single-shooting free run
    run = None if (not ok and restart_if is None) else \
        _free_run(om, sol, free, ref, vals, xscale, u)
    if not ok and (run is None or restart_if(float(np.nansum((y - run[2]) ** 2)))):
        solver = ca.nlpsol("oe", "ipopt", nlp, opts)
        sol = solver(x0=w0, **bounds_)
        ok = solver.stats().get("success", False)
        run = _free_run(om, sol, free, ref, vals, xscale, u)
    est, x0_hat, Y = run
    res = y - Y
    rms = np.sqrt(np.nanmean(res ** 2, axis=0))
    J = sensitivity(om, x0_hat, u, est, free, sig) if report else None
    fit = OutputErrorFit(est, free, x0_hat, Y, rms, float(np.nansum(res ** 2)), res.size,
                         J=J, success=bool(ok) and bool(np.all(np.isfinite(Y))),
                         effects=tuple(effects))
    fit.held = held
    if not report:
        return fit
    fit.std, fit.conditional_std = parameter_deviations(fit, sig, residuals=res)
    # blind directions: the base model's at the start (those held), then the final fit's
    fit.null_directions = nulls + null_directions(
        sensitivity(om, x0_hat, u, est, free, sig), free, om.nx, rtol=1e-6)
    return fit


def _free_run(om, sol, free, ref, vals, xscale, u) -> tuple:
    """The parameters, initial state and single-shooting simulated outputs at a solver's
    point (the free run every reported error is measured on)."""
    w = np.asarray(sol["x"]).ravel()
    est = dict(vals)
    est.update({n: float(w[i] * ref[i]) for i, n in enumerate(free)})
    x0_hat = w[len(free):len(free) + om.nx] * xscale
    _, Y = simulate(om, x0_hat, u, est)
    return est, x0_hat, Y


def check_length(K: int, n_unknown: int, dt: float = 1.0) -> None:
    """Refuse a log too short for an output-error fit (names the minimum length)."""
    need = max(30, 10 * n_unknown)
    if K < need:
        raise FdigenError(f"the log holds {K} samples: an output-error fit of {n_unknown} "
                          f"unknowns (parameters and initial states) needs at least "
                          f"{need} samples ({need * dt:g} s at {dt:g} s)")
