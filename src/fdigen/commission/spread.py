"""The parameter spread of commissioning's campaigns: each calibrated parameter's own.

A calibration on one log gives each uncertain parameter an interval; the campaigns that
design and check the thresholds spread each parameter by its own interval times
``sigmas``, at least a floor (the rig drifts between runs) and at most
:data:`MAX_TOLERANCE`.
"""

from __future__ import annotations

import math

#: The widest relative spread a campaign (and a parameter's ``tolerance``) takes: an offset
#: calibrated near 0 (-0.087 +- 0.10) gave +-355 %, a ``tolerance`` the model file refuses
#: (attack round 3: the commissioned file could not be read back).
MAX_TOLERANCE = 0.9


def campaign_tolerance(params: dict, std: dict, sigmas: float, floor: float,
                       floors: dict | None = None) -> float:
    """Largest relative spread of the campaign: ``max(sigmas * max_k std_k/|theta_k|,
    floor)`` (the spread of the uncertain parameters the calibration gave no interval)."""
    return float(max([*campaign_tolerances(params, std, sigmas, floor, floors).values(),
                      floor]))


def campaign_tolerances(params: dict, std: dict, sigmas: float, floor: float,
                        floors: dict | None = None) -> dict:
    """Each calibrated parameter's own spread,
    ``min(max(sigmas * std_k/|theta_k|, floor_k), MAX_TOLERANCE)``, with ``floor_k`` the
    parameter's entry of ``floors`` (a ``tolerance`` its model file declares below
    ``floor``), else ``floor``.

    One spread for all (the largest) put a heat loss known to +-34 % on an outflow
    coefficient known to 0.15 %: the level residual's threshold went to 1.6 times its
    sensor's span and the design was refused.
    """
    floors = floors or {}
    return {k: float(min(max(sigmas * abs(std[k] / params[k]), floors.get(k, floor)),
                         MAX_TOLERANCE))
            for k in std      # None: held at its datasheet value (no interval)
            if k in params and params[k] and std[k] is not None and math.isfinite(std[k])}


def spreads_without_interval(model, params: dict, per: dict) -> dict:
    """The campaign's spread of each uncertain parameter of ``model`` in ``params`` that
    ``per`` (the spreads from the log's intervals) lacks, with where it comes from:
    ``name -> (spread, "its declared tolerance" or "tune's default tolerance")``.

    A value without an interval of the log's (its search bound decided it, the log does
    not determine it, or it is held on a direction the log cannot see) is spread by its
    declared tolerance, else tune's 10 %. The largest of the others' intervals, spread on
    each alone, put a building zone's slab capacity and conductances +-80.9 % apart and
    the room threshold above its sensor's span.
    """
    from fdigen.tune import TuneSettings

    return {q.name: (float(min(q.tolerance or TuneSettings.tolerance, MAX_TOLERANCE)),
                     "its declared tolerance" if q.tolerance else "tune's default tolerance")
            for q in model.parameters
            if q.uncertain and q.name in params and q.name not in per}


def conditional_or_marginal(std: dict, conditional: dict) -> dict:
    """Each parameter's interval for the campaign: its conditional one (the others at
    their estimates, :func:`fdigen.discover.sensitivity.conditional_deviations`) where
    finite and not wider than the marginal one, else the marginal one (``None``, held at
    its datasheet value, stays ``None``)."""
    out = {}
    for k, sd in std.items():
        c = conditional.get(k)
        if sd is None or c is None or not math.isfinite(c) or \
                (sd is not None and math.isfinite(sd) and c > sd):
            out[k] = sd
        else:
            out[k] = float(c)
    return out


def floor_bound(params: dict, std: dict, sigmas: float, floor: float,
                floors: dict | None = None) -> dict:
    """``{"floor": floor, "names": {name: relative sigmas-interval}}`` of the calibrated
    parameters whose campaign spread is the floor, at least twice their own interval
    (:func:`campaign_tolerances`); a parameter with its own declared floor is not
    listed."""
    floors = floors or {}
    names = {}
    for k, sd in std.items():
        v = params.get(k)
        if k in floors or not v or sd is None or not math.isfinite(sd) or sd <= 0:
            continue          # (0: no interval known, not an exact value)
        own = sigmas * abs(sd / v)
        if own * 2 <= floor:
            names[k] = float(own)
    return {"floor": float(floor), "names": names}


def declared_floors(model, floor: float) -> dict:
    """The parameters whose model file declares a ``tolerance`` below ``floor``: their
    own floor. A user's water rig declared +-1 % on its orifices and pump gain, and the
    campaign spread them +-5 % without a word."""
    return {q.name: float(q.tolerance) for q in model.parameters
            if q.uncertain and q.tolerance is not None and 0 < q.tolerance < floor}


def spread_text(per: dict, floors: dict, floor: float, without: dict | None = None) -> str:
    """``Kq +-5 % (floor, --min-tolerance), a1 +-1 % (its declared tolerance), ...``: which
    spreads the calibration set and which a floor did; ``without`` (name -> where its
    spread comes from) the parameters the log gave no interval."""
    without = without or {}

    def one(k, v):
        if k in without:
            return f"{k} +-{100 * v:.3g} % (no interval of the log's: {without[k]})"
        own = floors.get(k)
        if own is not None and abs(v - own) <= 1e-12:
            return f"{k} +-{100 * v:.3g} % (its declared tolerance, the floor)"
        if own is None and abs(v - floor) <= 1e-12:
            return f"{k} +-{100 * v:.3g} % (the floor, --min-tolerance)"
        return f"{k} +-{100 * v:.3g} %"

    return ", ".join(one(k, v) for k, v in sorted(per.items()))


def wide_intervals(params: dict, std: dict, sigmas: float) -> list[str]:
    """A warning per calibrated parameter whose spread is capped at :data:`MAX_TOLERANCE`."""
    out = []
    for k, v in params.items():
        s = std.get(k)
        if v and s is not None and math.isfinite(s) and sigmas * abs(s / v) > MAX_TOLERANCE:
            out.append(f"{k} calibrated to {v:.4g} +- {s:.2g}: {sigmas:g} sigma is "
                       f"+-{100 * sigmas * abs(s / v):.3g} % of the value, so the campaigns "
                       f"spread it +-{100 * MAX_TOLERANCE:g} %: the log hardly determines it")
    return out


def round_up(value: float, digits: int = 3) -> float:
    """``value`` rounded up to ``digits`` significant digits (a spread never understated)."""
    if value <= 0:
        return 0.0
    scale = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return float(f"{math.ceil(value / scale - 1e-9) * scale:.{digits}g}")
