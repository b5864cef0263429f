"""Kalman predictions through the model's own nonlinear right-hand side.

Holds :func:`nonlinear_reason` (why a filter must predict through ``f`` rather than
through its linearisation: a non-smooth term, reduced coordinates that depend on the
state, an operating point that is not an equilibrium), :func:`reference_states` and
:func:`choose_reference` (the measured or estimated state the unobserved directions come
from, with its uncertainty), :func:`lift_matrices` (the full state rebuilt from the
filter's reduced coordinates and that reference), :func:`smoothed_dynamics` (``sign`` and
``Heaviside`` smoothed at the filter's resolution), :func:`nonlinear_prediction` (the
prediction as RK4 sub-steps of the projected dynamics, named assignments of the FDI step)
and :func:`check_nonlinear_filter` (RK4 stable over the ranges, corrected error dynamics
contracting at the operating point).
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.derive.linearisation import equivalent_linear, numeric
from fdigen.derive.nonsmooth import jacobian
from fdigen.design.derived_parameters import rational_form
from fdigen.design.measurements import outputs_in
from fdigen.model.sensor_maps import sensor_maps
from fdigen.design.symbolic import double
from fdigen.errors import DesignError
from fdigen.model.model import Model

#: Entries of the lift below this (relative to the largest) are exact zeros.
_LIFT_ZERO = 1e-12


def nonlinear_reason(model: Model, T: sp.Matrix, drivers=()) -> str | None:
    """Why a filter on ``model`` with reduced coordinates ``z = T x`` needs the nonlinear
    prediction, or ``None`` when its linearisation at the operating point is faithful.

    * the dynamics hold a non-smooth term (a friction sign, a dead band: their linear
      model is only the equivalent describing-function gain, see
      :func:`~fdigen.derive.linearisation.equivalent_linear`);
    * ``T`` depends on the state (a leak, e.g., breaks the symmetry of two chambers):
      the linear filter's coordinates change meaning along a trajectory;
    * ``f(x_0, u_0) != 0``: the operating point is not an equilibrium (a constant load,
      a leak to atmosphere), which the linearisation drops;
    * a *driver* (a measured state the driven sub-model reads as an input, ``drivers``:
      its input names, those of its sensors; given with ``[fdi] nonlinear_drivers``) enters ``f`` other than affinely with a constant gain: the filter
      knows its value every sample, and a linearisation about its operating value drops
      what it knows. A digester's temperature enters the growth rate as ``exp(theta T)``:
      a heater failure took it from 35 to 14 degC, the linear filter of the substrate and
      biomass, blind to the heater, flagged, and the heater was isolated as the feed pump.
    """
    f = model.f()
    if equivalent_linear(f, model) != f:
        return "non-smooth term in the dynamics"
    if T.free_symbols & set(model.x):
        return "reduced coordinates depend on the state"
    inputs = {u.name: u.symbol for u in model.inputs}
    moving = set(model.x) | set(model.u)
    for name in drivers:
        d = inputs.get(name)
        if d is not None and any(sp.diff(fi, d).free_symbols & moving for fi in f):
            return f"driver {name} enters the dynamics nonlinearly"
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name]
                  for s in (*model.states, *model.inputs)})
    try:
        f0 = numeric(f, point).ravel()
    except (TypeError, ValueError):
        return None
    scales = np.array([_scale(model, s) for s in model.states])
    if np.any(np.abs(f0) > 1e-9 * scales):
        return "operating point is not an equilibrium"
    return None


def _scale(model: Model, state) -> float:
    """Size of a state: the span of its range (else limits), else its operating value, else 1."""
    values = model.parameter_values
    for box in (state.range, state.limits):
        if box is not None:
            lo, hi = (float(sp.sympify(b).xreplace(values)) for b in box)
            if hi > lo:
                return hi - lo
    v = abs(float(sp.sympify(model.operating_point[state.name]).xreplace(values)))
    return v if v > 0 else 1.0


def reference_states(model: Model, cfg, signals: dict | None, estimates: dict | None) -> dict:
    """Candidate reference values of each state for the lift, best first.

    Each candidate is ``(expression, reads, sigma)``: ``reads`` the sensors it reads
    (``None`` for the voter, which no single sensor fault drags away), ``sigma`` its
    uncertainty. In order: the measured value of :func:`~fdigen.design.scheduled_prediction.
    schedule_signals` (``sigma`` the sensor's noise, the voter's fused noise), the estimate
    of the re-aligned parity parallel model (``estimates``: state name -> (symbol, sigma);
    it reads every parity sensor, only through its slow re-alignment, frozen at the first
    flag: ``reads`` is the empty set), the operating point (``sigma`` the state's range).
    """
    noise = {o.name: o.noise_std for o in model.outputs}
    voted = [noise[c] for c in (cfg.voter.channels if cfg.voter else ()) if c in noise]
    out = {}
    for s in model.states:
        cands = []
        sig = (signals or {}).get(s.name)
        if sig is not None:
            if sig[1] is None:
                sigma = min(voted) / np.sqrt(len(voted)) if voted else _scale(model, s)
            else:
                gains = {m.output: abs(m.gain) for m in sensor_maps(model).get(s.name, [])}
                sigma = min(noise[o] / gains.get(o, 1.0) for o in sig[1])
            cands.append((sig[0], sig[1], float(sigma)))
        if estimates and s.name in estimates:
            cands.append((*estimates[s.name][:1], frozenset(), float(estimates[s.name][1])))
        cands.append((double(model.operating_point[s.name]), frozenset(), _scale(model, s)))
        out[s.name] = cands
    return out


def choose_reference(kr, references: dict | None) -> tuple[list, np.ndarray]:
    """The reference state ``x_s`` of one filter and its uncertainty: per state the first
    candidate of :func:`reference_states` that reads only the voter or sensors the filter's
    own measurement reads (so the lift adds no sensor fault to its signature)."""
    model = kr.model
    reads = set().union(*(outputs_in(model, m) for m in kr.measurement))
    xs, sigma = [], []
    for s in model.states:
        cands = (references or {}).get(s.name) or [
            (double(model.operating_point[s.name]), frozenset(), _scale(model, s))]
        expr, _, sg = next(c for c in cands if c[1] is None or c[1] <= reads)
        xs.append(expr)
        sigma.append(sg)
    return xs, np.array(sigma, dtype=float)


def lift_matrices(T0: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""The full state rebuilt from reduced coordinates ``z`` and a reference state ``x_s``.

    .. math::

        x(z) = x_s + G\,(z - T_0 x_s) = G z + P x_s,\qquad
        G = W T_0^T (T_0 W T_0^T)^{-1},\quad P = I - G T_0,\quad
        W = \mathrm{diag}(\sigma^2)

    ``T_0 x(z) = z`` exactly (``T_0 G = I``, full row rank) and the directions the filter
    does not see (the kernel of ``T_0``) come from ``x_s``. ``G`` is the best linear
    unbiased correction of ``x_s`` (uncertainty ``sigma`` per state) to the filter's
    coordinates: it moves the least certain states. For the cylinder's ``Pd = Pp - Pn``
    it splits ``Pd`` half and half about the reference common-mode pressure; for the
    leaky chamber's coordinates ``Pp + c x``, ``Pn + c x`` it keeps the voted position
    (20 um) and moves the pressures (500 Pa).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``G`` (n x r) and ``P`` (n x n), to 14 significant digits, entries below ``1e-12``
        of the largest set to 0.
    """
    # uncertainties to 6 digits (equal sizes stay equal: the Riccati solution gives the
    # two chambers' pressures the same sigma up to the last bits)
    W = np.diag(np.array([float(f"{v:.6g}") for v in sigma]) ** 2)
    G = np.linalg.solve(T0 @ W @ T0.T, T0 @ W).T
    P = np.eye(T0.shape[1]) - G @ T0
    for M in (G, P):
        M[np.abs(M) < _LIFT_ZERO * max(1.0, np.abs(M).max())] = 0.0
        # 14 digits: the solve's last-bit noise off (0.5, not 0.49999999999999994)
        M[...] = [[float(f"{v:.14g}") for v in row] for row in M]
    return G, P


def smoothed_dynamics(kr, references: dict | None, h: float) -> sp.Matrix:
    r"""The filter model's ``f`` with its discontinuous switches smoothed at the filter's
    own resolution.

    ``sign(a) -> tanh(a / eps)`` and ``Heaviside(a) -> (1 + tanh(a / eps)) / 2`` (for
    continuous non-smooth terms, ``abs``, ``min``, ``max``, the model's own ``tanh``,
    nothing changes), with ``eps`` the standard deviation of the filter's estimate of
    ``a`` at the operating point,

    .. math::

        \epsilon^2 = \nabla a\, \Sigma\, \nabla a^T,\qquad
        \Sigma = G (I - M C_r) P\, G^T + P_l W P_l^T

    (``P`` the a-priori covariance, ``G``, ``P_l`` the lift, ``W`` the references'
    uncertainty): within ``eps`` the filter cannot tell the sign of ``a``, so an exact
    switch there only injects a force of full size at random (RK4 through a jump), and
    every Jacobian of the smoothed ``f`` exists (no ``DiracDelta``). Where that slope is
    too steep for the RK4 sub-step ``h`` (a damped mode of the Jacobian at the operating
    point with ``|R(lambda h)| > 1``), every ``eps`` is widened by steps of 25 % until it
    is not: the filter cannot follow a switch faster than its step anyway. (For the
    commissioned cylinder with ``sign(xdot)``: R4's ``eps`` = 1.05 mm/s from the filter's
    resolution (with the operating point's references), 2.05 mm/s for RK4 at 0.5 ms.)
    """
    model = kr.model
    f = model.f()
    switches = [n for n in f.atoms(sp.sign, sp.Heaviside) if n.args[0].free_symbols & set(model.x)]
    if not switches:
        return f
    T0 = kr.reduction.T_num
    _, sigma = choose_reference(kr, references)
    G, P = lift_matrices(T0, sigma)
    post = (np.eye(T0.shape[0]) - kr.gain.M @ kr.discrete.C) @ kr.gain.P
    cov = G @ post @ G.T + P @ np.diag(sigma ** 2) @ P.T
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name]
                  for s in (*model.states, *model.inputs)})
    eps = []
    for node in switches:
        arg = node.args[0]
        grad = numeric(jacobian([arg], model.x), point).ravel()
        e = float(np.sqrt(grad @ cov @ grad))
        eps.append(e if e > 0 else 1e-3 * max(_scale(model, s) for s in model.states
                                               if s.symbol in arg.free_symbols))

    def smoothed(scale):
        sub = {}
        for node, e in zip(switches, eps):
            smooth = sp.tanh(node.args[0] / double(e * scale))
            sub[node] = smooth if node.func == sp.sign else (1 + smooth) / 2
        return f.xreplace(sub)

    proj = sp.Matrix(T0)
    scale = 1.0
    for _ in range(60):
        fs = smoothed(scale)
        J = numeric(proj * jacobian(fs, model.x) * sp.Matrix(G), point)
        z = np.linalg.eigvals(J) * h
        amp = np.abs(1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24)
        if not np.any((z.real < 0) & (amp > 1.0 + 1e-9)):
            break
        scale *= 1.25
    return fs


def _times(c: float, x):
    """``c * x`` with ``c`` a double; ``x`` itself for 1 and ``-x`` for -1 (exact in IEEE
    arithmetic, one multiplication less per use)."""
    if c == 1.0:
        return x
    if c == -1.0:
        return -x
    return double(c) * x


def nonlinear_prediction(assign, kr, references: dict | None, f: sp.Matrix, u_block: list,
                         zplus: list, dt: float, substeps: int, derived) -> list:
    r"""The prediction ``z^-[k+1]`` of a Kalman filter through the model's own ``f``.

    .. math::

        \dot z = T_0\, f\big(\mathrm{clamp}(G z + P x_s),\ u[k]\big),\qquad
        z^-[k+1] = \mathrm{RK4}^{\,s}\big(z^+[k]\big)

    integrated over the sample time by ``substeps`` classical Runge-Kutta steps (those
    :func:`check_nonlinear_filter` found stable) with the input held (as the parity
    parallel models); ``f`` is the filter model's dynamics from :func:`smoothed_dynamics`. ``T_0`` is the coordinate change at the
    operating point (numeric, so a reduction whose coordinates depend on the state gets
    fixed coordinates), ``x_s`` the reference state of :func:`choose_reference` (the
    voted or the filter's own measured states, else the re-aligned parallel model's
    estimate, which follows the slow common-mode drift of the chamber pressures a
    position filter cannot see, else the operating point), ``G``, ``P`` the
    :func:`lift_matrices` for its uncertainty. The lifted state is clamped to its physical
    limits before ``f`` is evaluated. Non-smooth terms are evaluated as the model writes
    them (a friction ``tanh`` is not replaced by its describing gain), discontinuous
    switches smoothed at the filter's resolution (:func:`smoothed_dynamics`); the
    correction keeps the steady-state gain of the (equivalent) linearisation.

    Returns
    -------
    list of sympy.Symbol
        The next filter state, one named assignment per coordinate.
    """
    model, red = kr.model, kr.reduction
    tag = f"{kr.residual}_nl"
    T0 = red.T_num
    xs, sigma = choose_reference(kr, references)
    G, P = lift_matrices(T0, sigma)
    n, r = G.shape
    base = []
    for i, s in enumerate(model.states):
        expr = sum((_times(P[i, j], xs[j]) for j in range(n) if P[i, j] != 0), sp.Integer(0))
        base.append(assign(f"{tag}_base_{s.name}", expr) if expr.free_symbols else
                    double(expr))
    sub_u = dict(zip(model.u, u_block))
    f_expr = [rational_form(e, set(model.p), derived) for e in f.xreplace(sub_u)]
    x_syms = list(model.x)
    names = [s.name for s in model.states]

    def rhs(z, label):
        x = []
        for i, s in enumerate(model.states):
            xi = base[i] + sum((_times(G[i, j], z[j]) for j in range(r) if G[i, j] != 0),
                               sp.Integer(0))
            if s.limits is not None:
                xi = sp.Min(sp.Max(xi, s.limits[0]), s.limits[1])
            x.append(assign(f"{tag}{label}_x_{names[i]}", xi) if not (
                xi.is_Symbol or xi.is_Number) else xi)
        fx = [assign(f"{tag}{label}_f_{names[i]}", f_expr[i].xreplace(dict(zip(x_syms, x))))
              for i in range(n)]
        return [assign(f"{tag}{label}_dz{k}", sum((_times(T0[k, i], fx[i]) for i in range(n)
                                                    if T0[k, i] != 0), sp.Integer(0)))
                for k in range(r)]

    h = dt / substeps
    z = list(zplus)
    for step in range(substeps):
        k1 = rhs(z, f"{step}k1")
        k2 = rhs([z[k] + double(h / 2) * k1[k] for k in range(r)], f"{step}k2")
        k3 = rhs([z[k] + double(h / 2) * k2[k] for k in range(r)], f"{step}k3")
        k4 = rhs([z[k] + double(h) * k3[k] for k in range(r)], f"{step}k4")
        z = [assign(f"{tag}{step}_z{k}", z[k] + double(h / 6) * (k1[k] + 2 * (k2[k] + k3[k])
                                                                   + k4[k]))
             for k in range(r)]
    return z


#: At most this many RK4 sub-steps per sample for a nonlinear prediction.
MAX_SUBSTEPS = 16


def check_nonlinear_filter(kr, references: dict | None, f: sp.Matrix, dt: float,
                           substeps: int, points: int = 4) -> int:
    r"""The RK4 sub-steps a nonlinear prediction needs; refuse one that cannot be made
    stable, or whose corrected error dynamics do not contract at the operating point.

    ``J(x, u)`` is the exact Jacobian of the projected dynamics ``T_0 f(G z + P x_s)``
    (``f`` the filter model's dynamics as :func:`smoothed_dynamics` gives them, the
    derivative as written: a friction ``tanh``'s full slope at zero speed), and
    ``R(Z) = I + Z + Z^2/2 + Z^3/6 + Z^4/24`` one RK4 step.

    * *Integration*: on a grid of ``points`` values per state and input across its
      ``range`` (else ``limits``), every eigenvalue ``lambda`` of ``J`` with a negative
      real part must satisfy ``|R(lambda h)| <= 1``, ``h = dt / s``: RK4 amplifies no
      mode the model damps (the check of the parity parallel models, here with the steep
      non-smooth slopes the equivalent linearisation hides). ``s`` is the smallest number
      of sub-steps from ``substeps`` (the parity models') up to :data:`MAX_SUBSTEPS` that
      passes: a stiff corner of the ranges (a small chamber at an end stop) costs this
      filter more evaluations of ``f`` instead of refusing the design.
    * *Correction*: at the operating point the frozen error dynamics with the
      steady-state gain ``M`` contract, ``rho(R(hJ)^s (I - M C_r)) < 1``. Away from
      equilibrium a frozen Jacobian has growing modes no trajectory shows (the chamber
      pressure ``dPn/dt = gamma A Pn xdot / Vn`` frozen at a speed grows at
      ``gamma A xdot / Vn``, while along the motion it only follows ``Vn^-gamma``), so
      the box is used for the integration check only; the filter's behaviour along
      trajectories is measured (tests/test_nonlinear_prediction.py).

    Returns
    -------
    int
        The sub-steps ``s`` of the prediction.

    Raises
    ------
    DesignError
        Naming the filter, the point, the mode or radius, and the remedy.
    """
    model, red = kr.model, kr.reduction
    T0 = red.T_num
    G, _ = lift_matrices(T0, choose_reference(kr, references)[1])
    values = model.parameter_values
    J = (sp.Matrix(T0) * jacobian(f, model.x) * sp.Matrix(G)).xreplace(values)
    variables = (*model.states, *model.inputs)
    syms = [v.symbol for v in variables]
    J_of = sp.lambdify(syms, J, "numpy")
    op = np.array([float(sp.sympify(model.operating_point[v.name]).xreplace(values))
                   for v in variables])
    axes = []
    for k, v in enumerate(variables):
        box = v.range if v.range is not None else getattr(v, "limits", None)
        if box is None:
            axes.append(op[k:k + 1])
            continue
        lo, hi = (float(sp.sympify(b).xreplace(values)) for b in box)
        axes.append(np.unique(np.append(np.linspace(lo, hi, points), op[k])))
    eye = np.eye(T0.shape[0])

    def jac(point):
        Jp = np.array(J_of(*point), dtype=float)
        return Jp if np.all(np.isfinite(Jp)) else None

    def at(point):
        return ", ".join(f"{s} = {v:.4g}" for s, v in zip(syms, point))

    def unstable(lam, s):
        z = lam * dt / s
        amp = np.abs(1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24)
        return (lam.real < 0) & (amp > 1.0 + 1e-9)

    with np.errstate(all="ignore"):
        grid = np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(syms), -1).T
        damped, where = [], []
        for point in grid:
            Jp = jac(point)
            if Jp is not None:
                lam = np.linalg.eigvals(Jp)
                damped.append(lam)
                where.append(np.repeat(point[None, :], len(lam), axis=0))
        damped = np.concatenate(damped) if damped else np.zeros(0, complex)
        where = np.concatenate(where) if where else np.zeros((0, len(syms)))
        s = substeps
        while s < MAX_SUBSTEPS and np.any(unstable(damped, s)):
            s += 1
        bad = unstable(damped, s)
        if np.any(bad):
            k = int(np.argmax(np.where(bad, np.abs(damped), -1.0)))
            from fdigen.design.observers import filter_label

            raise DesignError(
                f"{model.source}: {filter_label(model, kr)}: the nonlinear prediction's RK4 "
                f"is unstable even at {MAX_SUBSTEPS} sub-steps of {dt / s:g} s at "
                f"{at(where[k])} (mode {complex(damped[k]):.4g} 1/s); shorten "
                "fdi.sample_time or check the parameters")
        closed = eye - kr.gain.M @ kr.discrete.C
        Jp = jac(op)
        if Jp is None:
            return s
        Z = dt / s * Jp
        R = eye + Z @ (eye + Z @ (eye / 2 + Z @ (eye / 6 + Z / 24)))
        rho = float(np.max(np.abs(np.linalg.eigvals(
            np.linalg.matrix_power(R, s) @ closed))))
    if not rho < 1.0:
        from fdigen.design.observers import filter_label

        raise DesignError(
            f"{model.source}: {filter_label(model, kr)}: the nonlinear prediction's "
            f"corrected error dynamics do not contract at {at(op)} (spectral radius "
            f"{rho:.4g} >= 1): the operating point's steady-state gain does not hold "
            "the filter there")
    return s
