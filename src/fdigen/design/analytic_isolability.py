"""Which structurally isolable fault pairs the model's equations actually separate.

Structural analysis (:mod:`fdigen.design.structure`) assumes generic gains: two faults
entering the same equations are isolable as soon as the graph allows a test that uses
one's equation and not the other's. A user's cart-pole wrote a motor gain fault on the
force ``F`` and a friction fault inside ``Ff = (bc + fric) v``; both reach the plant only
through ``F - Ff``, so their effects on every state differ by a gain and no residual can
tell them apart -- yet ``inspect`` called the pair achievable and advised a sensor.

The test is the rank condition for the linearised model
``dx/dt = A x + E phi``, ``y = C x + F phi`` (Frisk, Krysander and Jung's analytical
isolability; the normal rank evaluated at complex frequencies): ``f_i`` is isolable from
``f_j`` when

.. math::

    \\mathrm{rank} \\begin{bmatrix} sI - A & -E_j & -E_i \\\\ C & F_j & F_i \\end{bmatrix}
    > \\mathrm{rank} \\begin{bmatrix} sI - A & -E_j \\\\ C & F_j \\end{bmatrix}

and detectable when ``rank [sI - A, -E_i; C, F_i] > rank [sI - A; C]``. It is evaluated
at the operating point and at points around it (a fault multiplying a state, a friction
``fric v``, has no effect at a point where ``v = 0``); a pair is separable when the
condition holds at one of them. A pair whose fault columns ``[E_i; F_i]`` and
``[E_j; F_j]`` are parallel at every point cannot be separated by a sensor on a state:
an extra output adds rows to ``C`` only. A sensor on the input as the actuator delivers
it, or on a definition one of the two faults is written in (a load cell on a damper
force), sees a fault itself and can (:mod:`fdigen.design.definition_sensors`).
"""

from __future__ import annotations

import numpy as np
import sympy as sp

#: Points (the operating point and perturbed ones) and frequencies the ranks are taken at.
POINTS = 4
FREQUENCIES = (0.37 + 1.13j, 2.9 + 0.61j)

#: Singular values below this fraction of the largest count as zero (the matrices are
#: equilibrated first: units differ by many orders of magnitude between rows).
RANK_TOL = 1e-8


def _equilibrated(M: np.ndarray) -> np.ndarray:
    """``M`` with rows and columns scaled to unit 2-norm (two sweeps); zero rows and
    columns stay zero."""
    M = np.array(M, dtype=complex)
    for _ in range(2):
        c = np.linalg.norm(M, axis=0)
        M = M / np.where(c > 0, c, 1.0)
        r = np.linalg.norm(M, axis=1)
        M = M / np.where(r > 0, r, 1.0)[:, None]
    return M


def _rank(M: np.ndarray) -> int:
    if M.size == 0:
        return 0
    sv = np.linalg.svd(_equilibrated(M), compute_uv=False)
    return int(np.sum(sv > RANK_TOL * sv[0])) if sv.size and sv[0] > 0 else 0


def _points(model, count: int, seed: int = 0) -> list[dict]:
    """The operating point, then points with every state and input moved by up to 30 %
    of its magnitude (or of its declared range's width), seeded."""
    rng = np.random.default_rng(seed)
    op = dict(model.operating_point)
    out = [op]
    items = [*model.states, *model.inputs]
    for _ in range(count - 1):
        p = {}
        for s in items:
            v = float(op[s.name])
            rng_ = getattr(s, "range", None)
            width = (float(rng_[1]) - float(rng_[0])) if rng_ else 0.0
            scale = max(abs(v), 0.1 * width, 1e-3)
            p[s.name] = v + 0.3 * scale * rng.uniform(-1.0, 1.0)
        out.append(p)
    return out


def _balanced(A, C, G):
    """The same system with its states rescaled (``T^-1 A T``, ``C T``, ``T^-1 E``; the
    ranks are unchanged) so that ``A`` is balanced, and the frequency scale: its spectral
    radius. A cylinder's chamber pressures (1e5 Pa) drive its velocity through a gain of
    3e-4 and are driven by it through 4e6: unbalanced, the position's sensitivity to a
    chamber leak vanished below the rank tolerance at the frequency ``max |A|``."""
    from scipy.linalg import matrix_balance

    n = A.shape[0]
    if n == 0:
        return A, C, G, 1.0
    Ab, T = matrix_balance(A, permute=False)
    d = np.diag(T)
    Cb = C * d[None, :]
    Gb = np.vstack([G[:n] / d[:, None], G[n:]])
    radius = float(np.max(np.abs(np.linalg.eigvals(Ab)))) if np.all(np.isfinite(Ab)) else 0.0
    return Ab, Cb, Gb, radius if radius > 0 else 1.0


def fault_directions(model, points: int = POINTS):
    """``(A, C, G)`` at each point: the Jacobians and the fault columns ``G = [-E; F]``
    (one column per fault); points where they are not finite are skipped."""
    from fdigen.derive.linearisation import (numeric, operating_point_substitution,
                                             symbolic_jacobians)

    jac = symbolic_jacobians(model)
    out = []
    for p in _points(model, points):
        subs = operating_point_substitution(model, p)
        try:
            A, C, E, F = (numeric(m, subs) for m in (jac.A, jac.C, jac.E, jac.F))
        except (TypeError, ValueError, ZeroDivisionError):
            continue
        if all(np.all(np.isfinite(m)) for m in (A, C, E, F)):
            out.append((A, C, np.vstack([-E, F])))
    return out


def _lie_jacobians(model, points: int, faults: list | None = None):
    """``(J_x, [J_phi_j])`` at each point of :func:`_points`: the sensitivities of the
    output derivatives ``y, dy/dt, .., d^n y/dt^n`` to the state and to each fault and its
    derivatives (:func:`fdigen.derive.lie_derivatives.lie_series`, order ``n``); None
    when the series outgrows its budget (the linearisation's test is then used)."""
    from fdigen.derive.lie_derivatives import lie_series
    from fdigen.derive.lie_numeric import SeriesTooLarge, lie_values
    from fdigen.safe_lambdify import safe_lambdify

    n = len(model.states)
    try:
        fast = lie_values(model, _points(model, points), n, faults)
    except SeriesTooLarge:      # not the symbolic series either: it grows as fast
        return None
    if fast is not None:
        return [_stacked(*v, n, len(model.outputs)) for v in fast
                if v is not None and _finite(v)]
    series = lie_series(model, order=n, faults=faults)
    if not series.complete:
        return None
    exprs = [*series.gradients, *(b for blocks in series.fault_blocks for b in blocks)]
    try:
        evaluate = safe_lambdify([*model.x, *model.u], exprs, "numpy", cse=sp.cse)
    except (ValueError, TypeError, NameError):   # a symbol without a value
        return None
    out = []
    for point in _points(model, points):
        try:
            with np.errstate(all="ignore"):
                vals = [np.broadcast_to(np.asarray(v, dtype=float), e.shape)
                        for v, e in zip(evaluate(*(float(point[s.name]) for s in
                                                   (*model.states, *model.inputs))), exprs)]
        except (TypeError, ValueError, ZeroDivisionError, OverflowError):
            continue
        rest = iter(vals[n + 1:])
        values = (vals[:n + 1], [[next(rest) for _ in range(k + 1)] for k in range(n + 1)])
        if _finite(values):
            out.append(_stacked(*values, n, len(model.outputs)))
    return out


def _finite(values) -> bool:
    grads, blocks = values
    return all(np.all(np.isfinite(g)) for g in grads) and all(
        np.all(np.isfinite(b)) for row in blocks for b in row)


def _stacked(grads, blocks, n: int, p: int):
    """``(J_x, [J_phi_j])`` from the gradients and fault blocks of orders ``0..n``."""
    Jx = np.vstack(grads)
    nf = blocks[0][0].shape[1]
    Jf = np.zeros(((n + 1) * p, (n + 1) * nf))   # columns: (m, fault), m-major
    for k in range(n + 1):
        for m in range(k + 1):
            Jf[k * p:(k + 1) * p, m * nf:(m + 1) * nf] = blocks[k][m]
    return Jx, [Jf[:, [m * nf + j for m in range(n + 1)]] for j in range(nf)]


def analytic_isolability(model, points: int = POINTS, at=None,
                         needed: set | None = None) -> dict | None:
    """``{(fi, fj): bool}`` like :func:`~fdigen.design.structure.isolability`, by the
    rank test of the module at the operating point and around it; None when the model
    cannot be evaluated at any of them (the structural answer then stands).

    The test is taken on the output derivatives (:func:`_lie_jacobians`): ``f_i`` is
    isolable from ``f_j`` when

    .. math:: \\mathrm{rank}\\,[J_x, J_j, J_i] > \\mathrm{rank}\\,[J_x, J_j]

    with ``J_x`` the sensitivities of ``y .. y^{(n)}`` to the state and ``J_j`` to ``f_j``
    and its derivatives: for a linear model the Toeplitz form of the system-matrix test,
    and for a nonlinear one the same in any coordinates of the states (at a point away
    from equilibrium the linearisation's ``A`` is not: a mixing tank written with a salt
    mass instead of a concentration lost leak/level-sensor isolability). Where the series
    outgrows its budget, the system-matrix test of the linearisation (``at``:
    :func:`fault_directions` already evaluated) is used.

    With ``needed`` (ordered pairs), only those are answered (:func:`_needed_only`).
    """
    if needed is not None:
        return _needed_only(model, points, at, needed)
    return _lie_isolability(model, points, at, None)


def _lie_isolability(model, points: int, at, faults: list | None) -> dict | None:
    """The test of :func:`analytic_isolability` for the faults at the indices ``faults``
    (default: all)."""
    names = [f.name for k, f in enumerate(model.faults) if faults is None or k in faults]
    lie = _lie_jacobians(model, points, faults)
    if lie is None:
        return _linearised_isolability(model, points, at)
    if not lie:
        return None
    ranks = [(_rank(Jx), [_rank(np.hstack([Jx, c])) for c in cols]) for Jx, cols in lie]
    # generic ranks: the largest over the points. A point where fault j's block loses rank
    # (a damper leak at a point where the damper's speed is nearly 0) would call every
    # fault isolable from j; it is not where the generic answer is read
    generic_x = max(r for r, _ in ranks)
    generic = [max(w[j] for _, w in ranks) for j in range(len(names))]
    out = {}
    for (Jx, cols), (base, with_j) in zip(lie, ranks):
        for i, fi in enumerate(names):
            if base == generic_x:
                out[(fi, fi)] = out.get((fi, fi), False) or with_j[i] > base
            for j, fj in enumerate(names):
                out.setdefault((fi, fj), False)
                if i != j and not out[(fi, fj)] and with_j[j] == generic[j]:
                    out[(fi, fj)] = _rank(np.hstack([Jx, cols[j], cols[i]])) > with_j[j]
    for i, fi in enumerate(names):
        out.setdefault((fi, fi), False)
    return out


def _needed_only(model, points: int, at, needed: set) -> dict | None:
    """:func:`analytic_isolability` for the pairs ``needed`` only. At an operating point
    that is an equilibrium the linearisation's test is the coordinate-free one (the
    change of variables' Jacobian is a similarity there): the pairs it separates there are
    settled, and the output derivatives are formed for the faults of the others only (the
    cylinder's derivation spent 2 s on them for all nine faults)."""
    settled = {}
    if _at_equilibrium(model):
        settled = {pair: True for pair, ok in
                   (_linearised_isolability(model, 1, None) or {}).items()
                   if ok and pair in needed}
    rest = set(needed) - set(settled)
    if not rest:
        return settled
    keep = {f for pair in rest for f in pair}
    found = _lie_isolability(model, points, at, [k for k, f in enumerate(model.faults)
                                                 if f.name in keep])
    if found is None:
        return None if not settled else {**settled}
    return {**settled, **{pair: found.get(pair, False) for pair in rest}}


def _at_equilibrium(model) -> bool:
    """``f(x0, u0) = 0`` at the operating point, to within 1e-9 of each state's scale
    per sample time."""
    from fdigen.derive.linearisation import numeric, operating_point_substitution

    try:
        f0 = numeric(model.f(), operating_point_substitution(model)).ravel()
    except (TypeError, ValueError, ZeroDivisionError):
        return False
    dt = float(model.fdi.get("sample_time", 1.0)) if model.fdi else 1.0
    for s, v in zip(model.states, f0):
        x0 = float(model.operating_point[s.name])
        width = float(s.range[1]) - float(s.range[0]) if s.range else 0.0
        if not np.isfinite(v) or abs(v) * dt > 1e-9 * max(abs(x0), width, 1e-12):
            return False
    return True


def _linearised_isolability(model, points: int, at) -> dict | None:
    """The system-matrix rank test of the module docstring on the linearisation."""
    names = [f.name for f in model.faults]
    at = fault_directions(model, points) if at is None else at
    if not at:
        return None
    n = len(model.states)
    out = {}
    for A, C, G in at:
        A, C, G, scale = _balanced(A, C, G)
        for s in FREQUENCIES:
            X = np.vstack([s * scale * np.eye(n) - A, C])
            base = _rank(X)
            with_j = [_rank(np.hstack([X, G[:, [j]]])) for j in range(len(names))]
            for i, fi in enumerate(names):
                out[(fi, fi)] = out.get((fi, fi), False) or with_j[i] > base
                for j, fj in enumerate(names):
                    if i != j and not out.get((fi, fj), False):
                        out[(fi, fj)] = _rank(np.hstack([X, G[:, [j, i]]])) > with_j[j]
    return out


def parallel_pairs(model, points: int = POINTS, at=None) -> set:
    """Unordered pairs of faults with an effect whose columns ``[E; F]`` are parallel at
    every point: no sensor on a state separates them (the module docstring)."""
    names = [f.name for f in model.faults]
    at = fault_directions(model, points) if at is None else at
    if not at:
        return set()
    out = set()
    for i, fi in enumerate(names):
        for j in range(i + 1, len(names)):
            if all(_rank(G[:, [i, j]]) <= 1 for _, _, G in at) and all(
                    any(np.any(G[:, [k]] != 0) for _, _, G in at) for k in (i, j)):
                out.add(frozenset((fi, names[j])))
    return out


def achievable_isolability(model, structural: dict, at=None) -> tuple[dict, list]:
    """The structural isolability ``structural`` with the pairs the rank test refuses at
    every point taken out (the test only removes: a pair structure cannot separate stays
    inseparable, even where a fault has no effect at some point and the rank test there
    would call it separable).

    Returns
    -------
    (dict, list)
        The isolability, and the ordered pairs taken out.
    """
    analytic = analytic_isolability(model, at=at,
                                    needed={pair for pair, ok in structural.items() if ok})
    if analytic is None:
        return dict(structural), []
    out, removed = {}, []
    for pair, ok in structural.items():
        out[pair] = bool(ok and analytic.get(pair, True))
        if ok and not out[pair]:
            removed.append(pair)
    return out, sorted(removed)
