"""Parameter values the generated FDI core may run with: the design's checks, re-run.

The generated ``_init`` accepts any parameter within its declared ``bounds``; the gains
(Kalman, realignment) are designed once at the nominal values. A parameter far from
nominal can make the RK4 parallel model or a scheduled Kalman prediction unstable at the
sample time (``M = 0.01 kg`` or ``V0 = 1e-8 m^3`` made the cylinder's filters diverge
within 3-28 samples), after which the residuals are not finite. So the declared bounds
must lie where the design's own stability checks pass. :func:`check_parameters` runs them
at given parameter values, with the design's fixed gains:

* :func:`~fdigen.design.parallel_model.check_parallel_model_step`: every linearised mode
  at the operating point and the range ends inside RK4's stability region at
  ``h = sample_time / substeps``;
* the scheduled-filter check of :func:`~fdigen.design.scheduled_prediction.
  scheduled_transition`: ``rho(A_d(s) (I - M C)) < 1`` over the schedule's clamp box,
  ``A_d(s)`` from the Jacobians at the new parameters, ``M`` and ``A_d0`` nominal.

:func:`unstable_bounds` runs them at each declared bound (one parameter at a time) and at
the corners of the widest bounds (:func:`corner_parameters`); ``scripts/parameter_bounds.py``
computes, by bisection, the bounds where the checks start to fail, from which the built-in
models' bounds are set (so the generated ``_init``, which refuses values outside the
bounds, refuses the unstable ones); ``tests/test_reliability_numeric.py`` checks them.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

from fdigen.design.parallel_model import check_parallel_model_step
from fdigen.design.scheduled_prediction import schedule_signals, scheduled_transition
from fdigen.design.symbolic import real_symbol
from fdigen.errors import DesignError

#: At most this many parameters get their bound corners checked together (2**n checks).
MAX_CORNER_PARAMETERS = 5


def check_parameters(design, values: dict) -> str | None:
    """Run the design's stability checks with the parameters ``values`` (others nominal).

    Parameters
    ----------
    design : FdiDesign
    values : dict of str to float

    Returns
    -------
    str or None
        The first check's failure message, or ``None`` when every check passes.
    """
    model = design.model.with_parameters(**values)
    cfg = design.config
    try:
        check_parallel_model_step(model, cfg)
        scheduled = [kr for kr in design.kalman if kr.schedule == "measured"]
        if scheduled:
            def assign(name, expr):
                return real_symbol(name)

            y_by_name = {o.name: o.symbol for o in model.outputs}
            signals = schedule_signals(assign, model, cfg, y_by_name,
                                       real_symbol("voter_out"))
            for kr in scheduled:
                own = {k: v for k, v in values.items()
                       if k in {q.name for q in kr.model.parameters}}
                kr_p = dataclasses.replace(kr, model=kr.model.with_parameters(**own))
                scheduled_transition(assign, kr_p, signals, cfg.sample_time, {})
    except DesignError as exc:
        return str(exc)
    except (ArithmeticError, ValueError, TypeError) as exc:   # singular at these values
        return f"{type(exc).__name__}: {exc}"
    return None


def corner_parameters(design) -> list[str]:
    """The parameters whose bound corners are checked together: those with the widest
    bounds (ratio high/low, or span relative to the value), then the ``uncertain`` ones,
    at most :data:`MAX_CORNER_PARAMETERS`."""
    def width(q):
        lo, hi = (float(b) for b in q.bounds)
        if lo > 0:
            return math.log(hi / lo)
        return (hi - lo) / max(abs(float(q.value)), 1e-300)

    bounded = [q for q in design.model.parameters if q.bounds is not None]
    wide = sorted((q for q in bounded if width(q) > math.log(10.0)), key=width, reverse=True)
    names = list(dict.fromkeys([*(q.name for q in wide), *(q.name for q in bounded
                                                           if q.uncertain)]))
    return names[:MAX_CORNER_PARAMETERS]


def unstable_bounds(design, corners: bool = True) -> list[tuple[dict, str]]:
    """The declared parameter bounds at which the design's checks fail.

    Each bounded parameter is tried at its low and high bound, the others nominal; then
    (``corners``) every corner of the box of :func:`corner_parameters`.

    Returns
    -------
    list of (dict, str)
        ``(parameter values, failure message)`` per failing point; empty if none fails.
    """
    bounded = {q.name: q.bounds for q in design.model.parameters if q.bounds is not None}
    failures = []
    for name, bounds in bounded.items():
        for b in bounds:
            msg = check_parameters(design, {name: float(b)})
            if msg is not None:
                failures.append(({name: float(b)}, msg))
    names = corner_parameters(design) if corners else []
    if len(names) >= 2:
        for corner in itertools.product(*(bounded[n] for n in names)):
            values = dict(zip(names, map(float, corner)))
            msg = check_parameters(design, values)
            if msg is not None:
                failures.append((values, msg))
    return failures


def stable_limit(design, name: str, side: int, rel_tol: float = 1e-3) -> float:
    """The bound of parameter ``name`` (``side`` 0: low, 1: high) nearest to its declared
    one at which the design's checks still pass (others nominal), by bisection between
    the nominal value and the declared bound (geometric for positive values).

    Returns
    -------
    float
        The declared bound if it passes, else the last passing value found.
    """
    q = next(q for q in design.model.parameters if q.name == name)
    good, bad = float(q.value), float(q.bounds[side])
    if check_parameters(design, {name: bad}) is None:
        return bad
    geometric = good > 0 and bad > 0
    for _ in range(200):
        if abs(bad - good) <= rel_tol * abs(good):
            break
        mid = math.sqrt(good * bad) if geometric else (good + bad) / 2
        if check_parameters(design, {name: mid}) is None:
            good = mid
        else:
            bad = mid
    if good == 0:
        return 0.0
    scale = 10.0 ** (math.floor(math.log10(abs(good))) - 2)    # 3 significant digits,
    step = math.ceil if side == 0 else math.floor              # rounded toward nominal
    return float(f"{step(good / scale) * scale:.3g}")
