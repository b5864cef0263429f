"""Kalman predictions scheduled on the measured state.

Holds :func:`schedule_signals` (the measured value of each state: the voter's output or a
validated sensor, clamped to the state's limits), :func:`scheduled_transition` (the
discrete prediction matrices re-evaluated at those signals, corrected to second order
around the operating point) and the check that the scheduled filter stays stable over its
whole schedule.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.derive import precise
from fdigen.design.config import FdiConfig
from fdigen.design.measurements import outputs_in
from fdigen.design.observers import KalmanResidual, filter_label
from fdigen.design.submodel import direct_sensors, state_from_sensor
from fdigen.design.symbolic import double
from fdigen.errors import DesignError
from fdigen.model.model import Model
from fdigen.safe_lambdify import safe_lambdify


def schedule_signals(assign, model: Model, cfg: FdiConfig, y_by_name: dict, voter_out) -> dict:
    """The measured value of each state, for scheduled Kalman predictions.

    A state measured directly by a sensor compared in the voter takes the voter's output
    (which a faulty or lost sensor cannot drag away), another directly measured state its
    (validated) sensor; either is clamped to the state's physical limits. States measured
    by no sensor are absent (their entries stay at the operating point).

    Returns
    -------
    dict of str to (sympy.Symbol, frozenset of str or None)
        State name -> (symbol of the assignment ``sched_<state>``, the sensor it reads, or
        ``None`` for the voter, which no single sensor fault drags away).
    """
    direct = direct_sensors(model)
    voted = set(cfg.voter.channels) if cfg.voter else set()
    out = {}
    for s in model.states:
        sensors = direct.get(s.name, [])
        if not sensors:
            continue
        if voter_out is not None and voted & set(sensors):
            chan = next(c for c in sensors if c in voted)
            value, reads = state_from_sensor(model, s.name, chan, voter_out), None
        else:
            value = state_from_sensor(model, s.name, sensors[0], y_by_name[sensors[0]])
            reads = frozenset([sensors[0]])
        if s.limits is not None:
            value = sp.Min(sp.Max(value, s.limits[0]), s.limits[1])
        out[s.name] = (assign(f"sched_{s.name}", value), reads)
    return out


def scheduled_transition(assign, kr: KalmanResidual, signals: dict, dt: float,
                         shared: dict | None = None):
    r"""Discrete prediction matrices of a Kalman filter re-evaluated at the measured state.

    The reduced Jacobians ``A_r(s)``, ``B_r(s)`` (symbolic in the states left free by the
    symbolic operating point) are evaluated at the measured states ``s`` and the
    zero-order-hold matrices of the operating point corrected to second order:

    .. math::

        A_d(s) = A_{d,0} + h\,(A_r(s) - A_{r,0}) + \tfrac{h^2}{2}\,(A_r(s)^2 - A_{r,0}^2),

        B_d(s) = B_{d,0} + h\,(B_r(s) - B_{r,0})
                 + \tfrac{h^2}{2}\,(A_r(s) B_r(s) - A_{r,0} B_{r,0})

    exact at the operating point (``A_d(s_0) = A_{d,0} = e^{A_{r,0} h}``), and the Taylor
    expansion of ``e^{A_r(s) h}`` to the same order elsewhere. The gain stays the
    steady-state gain of the operating point. For the pneumatic cylinder the chamber
    stiffness ``A gamma (P_p/V_p + P_n/V_n)`` and the valve gain ``K R T_s gamma
    (1/V_p + 1/V_n)`` vary by tens of per cent over the stroke; a filter fixed at
    mid-stroke mistakes that for a fault near the end stops.

    A filter is scheduled only on the voter and on the sensors its own measurement reads
    (``signals``, see :func:`schedule_signals`), so scheduling adds no sensor fault to its
    signature: the cylinder's position filter R4 follows the voted position only, the
    pressure filter R5 the measured pressures and the voted position. Other states stay
    at their operating values.

    Each scheduled Jacobian entry that is a quotient is evaluated as its numerator times
    the reciprocal of its denominator, one named reciprocal ``sched_inv<k>`` per distinct
    denominator (the cylinder's entries all divide by the same ``V_p V_n`` polynomial: one
    division per sample instead of three). ``shared`` (expression -> symbol, one dict for
    all the filters of a program) makes every distinct expression one assignment: R5's
    valve-gain entry and its ``B_d`` are R4's, computed once.

    Returns
    -------
    (sympy.Matrix, sympy.Matrix)
        ``A_d``, ``B_d``: numbers where nothing is scheduled, else symbols of named
        assignments.

    Raises
    ------
    DesignError
        If the reduced coordinates depend on the state (the filter's state would change
        meaning along the schedule).
    """
    red = kr.reduction
    model = kr.model
    values = model.parameter_values
    state_syms = {s.symbol: s.name for s in model.states}
    if red.T.free_symbols & set(state_syms):
        raise DesignError(f"Kalman filter {kr.residual}: cannot schedule its prediction, the "
                          "reduced coordinates depend on the state "
                          f"({', '.join(sorted(str(s) for s in red.T.free_symbols))})")
    sub = {}
    reads = set().union(*(outputs_in(model, m) for m in kr.measurement))
    for sym, name in state_syms.items():
        if name in signals and (signals[name][1] is None or signals[name][1] <= reads):
            sub[sym] = signals[name][0]
        else:
            sub[sym] = double(model.operating_point[name])
    Ar = red.A_r.xreplace(values).xreplace(sub)
    Br = red.B_r.xreplace(values).xreplace(sub)
    n, m = Br.shape
    h = dt
    A0, B0 = red.A_num, red.B_num
    A0sq, AB0 = precise.matmul(A0, A0), precise.matmul(A0, B0)   # same bits on every CPU
    _check_scheduled_filter(kr, [sym for sym in sub if not sub[sym].is_Number],
                            {sym: v for sym, v in sub.items() if v.is_Number}, values, h)
    tag = kr.residual

    shared = {} if shared is None else shared

    def once(name, expr):
        if expr not in shared:
            shared[expr] = assign(name, expr)
        return shared[expr]

    def entry(expr, name):
        expr = sp.sympify(expr)
        if not expr.free_symbols:
            return double(expr)
        num, den = sp.fraction(expr)
        if den.free_symbols:
            n_inv = sum(1 for v in shared.values() if v.name.startswith("sched_inv"))
            expr = num * once(f"sched_inv{n_inv}", 1 / den)
        return once(name, expr)

    a = sp.Matrix(n, n, lambda i, j: entry(Ar[i, j], f"{tag}_Ar{i}{j}"))
    b = sp.Matrix(n, m, lambda i, j: entry(Br[i, j], f"{tag}_Br{i}{j}"))
    def corrected(name, d0, first, first0, second, second0):
        """``d0 + h (first - first0) + h^2/2 (second - second0)``, or ``d0`` unscheduled."""
        if not (first.free_symbols or second.free_symbols):
            return double(d0)
        return once(name, double(d0) + double(h) * (first - double(first0))
                    + double(h * h / 2) * (second - double(second0)))

    Ad = sp.Matrix(n, n, lambda i, j: corrected(
        f"{tag}_Ad{i}{j}", kr.discrete.A[i, j], a[i, j], A0[i, j],
        sum((a[i, k] * a[k, j] for k in range(n)), sp.Integer(0)), A0sq[i, j]))
    Bd = sp.Matrix(n, m, lambda i, j: corrected(
        f"{tag}_Bd{i}{j}", kr.discrete.B[i, j], b[i, j], B0[i, j],
        sum((a[i, k] * b[k, j] for k in range(n)), sp.Integer(0)), AB0[i, j]))
    return Ad, Bd


def _check_scheduled_filter(kr: KalmanResidual, scheduled: list, fixed: dict, values: dict,
                            h: float, points: int = 7) -> None:
    r"""Refuse a scheduled prediction whose filter is unstable somewhere on its schedule.

    ``scheduled`` lists the state symbols the prediction follows, ``fixed`` maps the others
    to their operating values. Over a grid of ``points`` values per scheduled state
    spanning the clamp of its signal (the state's ``limits``, else its ``range``), the
    frozen-schedule error dynamics of the filter with its fixed gain ``M`` must be stable:

    .. math:: \rho\big(A_d(s)\,(I - M C_r)\big) < 1

    (``A_d(s)`` as in :func:`scheduled_transition`). A stiff corner of the schedule (a
    tiny dead volume at an end stop) otherwise makes the second-order correction, and the
    filter, diverge.

    Raises
    ------
    DesignError
        Naming the filter, the worst point and its spectral radius.
    """
    if not scheduled:
        return
    red, model = kr.reduction, kr.model
    syms = list(scheduled)
    axes = []
    for sym in syms:
        state = next(s for s in model.states if s.symbol == sym)
        box = state.limits if state.limits is not None else state.range
        if box is None:
            raise DesignError(f"Kalman filter {kr.residual}: cannot schedule on state "
                              f"'{state.name}', which has neither limits nor a range")
        lo, hi = (float(sp.sympify(b).xreplace(values)) for b in box)
        axes.append(np.linspace(lo, hi, points))
    A_of = safe_lambdify(syms, red.A_r.xreplace(values).xreplace(fixed), "numpy")
    A0, Ad0 = red.A_num, kr.discrete.A
    A0sq = A0 @ A0
    closed = np.eye(A0.shape[0]) - kr.gain.M @ kr.discrete.C
    worst = (-np.inf, None)
    with np.errstate(all="ignore"):
        for point in np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(syms), -1).T:
            A = np.array(A_of(*point), dtype=float)
            Ad = Ad0 + h * (A - A0) + h * h / 2 * (A @ A - A0sq)
            rho = np.max(np.abs(np.linalg.eigvals(Ad @ closed))) if np.all(
                np.isfinite(Ad)) else np.inf
            if not rho <= worst[0]:       # a NaN radius counts as the worst
                worst = (rho, point)
    rho, point = worst
    if not rho < 1.0:
        at = ", ".join(f"{s} = {v:.4g}" for s, v in zip(syms, point))
        raise DesignError(
            f"{model.source}: {_schedule_field(model, kr)}: the scheduled prediction "
            f"is unstable at {at} (spectral radius of A_d(s)(I - M C) {rho:.4g} >= 1; "
            "the model is too stiff there for the sample time); use "
            "schedule = \"operating_point\" or a shorter sample_time")


def _schedule_field(model, kr) -> str:
    """``fdi.kalman.R4.schedule`` for a declared filter, else the derived residual's label
    (:func:`~fdigen.design.observers.filter_label`) and "schedule"."""
    label = filter_label(model, kr)
    return f"{label}.schedule" if label.startswith("fdi.kalman.") else f"{label}, schedule"

